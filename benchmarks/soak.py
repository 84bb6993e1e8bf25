"""Soak: one server, S one-camera sessions at 30 Hz for M minutes; memory, threads and latency over time.

    python benchmarks/soak.py [--minutes 30] [--sessions 32] [--sample 5]
    python benchmarks/soak.py --minutes 2 --sessions 8           # a short run, to try it
    python benchmarks/soak.py --websocket --out results/soak_web.json  # the same over the browser's WebSocket
    python benchmarks/soak.py --transport h2 --out results/soak_h2.json  # serve --transport h2

One ``caveclod serve`` (127.0.0.1, port 0) serves the 1M-triangle default
terrain (``--size 708``, built once into benchmarks/results/ and reused, as
benchmarks/service.py does). A load generator process (this file's
``--driver`` mode: the asyncio client library, sessions sharing
``--connections`` connections) flies S sessions of one camera each along
the flyover at 30 poses a second, 1280x720, 60 degrees, 1 px, op streams,
applying and CRC-checking every frame, for ``--minutes``. Every ``--sample``
seconds: the server's RSS, private RSS (RssAnon), threads and descriptors
(/proc/PID), its ``caveclod_sessions_active`` and ``caveclod_frames_total``
(Prometheus), and the generator's frames, errors, divergences, resumes and
the p50/p99 pose -> frame latency of the poses answered in that window.

**Warm-up**: the first 10 % of the run, and at least one lap of the flyover
(60 s: the cameras touch the pages of the mapped mesh they fly over once a
lap), unless ``--warmup S``. After it, the server's RSS is fitted by least
squares: its slope (MiB an hour) and the fitted growth over the rest of the
run, in % of the fitted value at the warm-up's end; also the growth between
the medians of the first and the last three samples.

Pass: RSS growth after the warm-up <= 2 % (both the fitted and the
end-to-end figure), 0 errors, 0 divergences (and 0 bad frames), every
session flying to the end.

Writes ``benchmarks/results/soak.json`` and ``soak.png`` (``--out``
elsewhere). Every process started is stopped by its pid in a ``finally``;
every loop is bounded in count and time.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from chaos import CACHE, RESULTS, ROOT, Sampler, _bench_service, metrics_port

LAP_S = 60.0            # caveclod.paths.flyover's seconds_per_lap


# -- the load generator (--driver) ------------------------------------------------------------
class WebSocketSession:
    """A session over ``serve --web-port``'s WebSocket (what the browser viewer speaks), with the
    three calls of the asyncio client's sessions that the soak uses: ``send_pose``, ``next_frame``
    (SessionEnded at the end: code None when closed normally) and ``begin_close``."""

    def __init__(self, ws, protocol):
        self.ws, self.protocol = ws, protocol
        self._writes: set = set()

    @classmethod
    async def open(cls, http, url: str, mesh: str, options: dict) -> "WebSocketSession":
        from caveclod.client import SessionProtocol
        protocol = SessionProtocol(mesh, 1, options)
        session = cls(await http.ws_connect(url, protocols=["caveclod.v1"], max_msg_size=0), protocol)
        session._send(protocol.open_message())
        while not protocol.ready:
            await session._receive()
        return session

    def _send(self, msg) -> None:
        write = asyncio.ensure_future(self.ws.send_bytes(msg.SerializeToString()))
        self._writes.add(write)                  # kept until done: a task with no reference may vanish
        write.add_done_callback(self._writes.discard)

    def send_pose(self, camera: int, eye, target, up) -> None:
        self._send(self.protocol.pose_message(camera, eye, target, up))

    def begin_close(self, reason: str = "") -> None:
        self._send(self.protocol.close_message(reason))

    async def _receive(self):
        """One server message handled; the frame it completed, or None."""
        import aiohttp
        import grpc

        from caveclod.client.session import SessionEnded
        from caveclod.v1 import caveclod_pb2 as pb
        msg = await self.ws.receive()
        if msg.type != aiohttp.WSMsgType.BINARY:
            raise SessionEnded(grpc.StatusCode.UNAVAILABLE, f"the WebSocket closed ({self.ws.close_code}) "
                                                            "without a status")
        reply = pb.ServerMessage.FromString(msg.data)
        if reply.WhichOneof("kind") == "status":
            code = next(c for c in grpc.StatusCode if c.value[0] == reply.status.code)
            raise SessionEnded(None if code == grpc.StatusCode.OK else code, reply.status.message)
        out, update = self.protocol.receive(reply)
        for m in out:
            self._send(m)
        return update

    async def next_frame(self):
        while True:
            update = await self._receive()
            if update is not None:
                return update


async def _driver(a: dict) -> None:
    """Fly ``sessions`` sessions for ``duration`` s; print a JSON line every ``sample`` s and a final one."""
    from caveclod.client.aio import AsyncClient
    from caveclod.client.cache import VertexBufferCache
    from caveclod.client.session import SessionEnded
    from caveclod.paths import pose as path_pose
    n, rate, duration = a["sessions"], a["rate"], a["duration"]
    cache = VertexBufferCache(a["cache_dir"])             # one copy of the vertex buffer for every session
    clients = [AsyncClient(a["target"], cache_dir=False) for _ in range(max(1, min(a["connections"], n)))]
    for c in clients:
        c.cache = cache
    mesh = (await clients[0].list_meshes())[0]
    lo = (mesh.bounds_min.x, mesh.bounds_min.y, mesh.bounds_min.z)
    hi = (mesh.bounds_max.x, mesh.bounds_max.y, mesh.bounds_max.z)
    http = None
    if a.get("websocket"):
        import aiohttp
        http = aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0))
        options = {"width": a["width"], "height": a["height"], "fov_y": a["fov"], "tolerance_px": a["tolerance"],
                   "cull": None, "backface": None, "max_ops": None, "max_faces": None}
        sessions = await asyncio.gather(*(WebSocketSession.open(http, a["websocket"], mesh.name, options)
                                          for _ in range(n)))
    else:
        sessions = await asyncio.gather(*(clients[i % len(clients)].session(
            mesh.name, width=a["width"], height=a["height"], fov_y=a["fov"], tolerance_px=a["tolerance"],
            timeout=120.0) for i in range(n)))
    frames, poses, errors, window, chunks, finished = [0], [0], Counter(), [], [], [0]
    cpu0 = time.process_time()
    t0 = time.perf_counter() + 0.5
    print(json.dumps({"started": True, "sessions": n, "mesh": mesh.name, "faces": mesh.faces}), flush=True)

    async def fly(i: int, s) -> None:
        try:
            await _fly(i, s)
        except Exception as exc:                          # noqa: BLE001 - counted: the soak must have none
            errors[f"poses: {type(exc).__name__}"] += 1

    async def _fly(i: int, s) -> None:
        period = 1.0 / rate
        tick = i / n * period                             # the sessions staggered over a period
        while tick < duration:
            delay = t0 + tick - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            elif delay < -period:                         # late: skip the missed ticks, no burst
                tick += (-delay // period) * period
            s.send_pose(0, *path_pose("flyover", lo, hi, i, tick))
            poses[0] += 1
            tick += period

    async def receive(s) -> None:
        loop = asyncio.get_running_loop()
        closing = loop.call_later(max(t0 + duration + 1.0 - time.perf_counter(), 0.0), s.begin_close, "soak done")
        try:
            while True:
                try:
                    f = await s.next_frame()
                except SessionEnded as end:
                    if end.code is not None:
                        errors[end.code.name] += 1
                    else:
                        finished[0] += 1
                    return
                frames[0] += 1
                window.extend(c.latency for c in f.cameras.values() if c.latency is not None)
        except Exception as exc:                          # noqa: BLE001 - counted: the soak must have none
            errors[type(exc).__name__] += 1
        finally:
            closing.cancel()

    def counters() -> dict:
        return {"frames": frames[0], "poses": poses[0], "errors": dict(errors),
                "divergences": sum(s.protocol.divergences for s in sessions),
                "bad_frames": sum(s.protocol.bad_frames for s in sessions),
                "resumes": sum(s.protocol.resumes for s in sessions),
                "failovers": sum(s.protocol.failovers for s in sessions),
                "cpu_s": round(time.process_time() - cpu0, 2)}

    async def report() -> None:
        for _ in range(int((duration + 60) / a["sample"]) + 1):
            await asyncio.sleep(a["sample"])
            lat = np.asarray(window, np.float32) * 1e3
            window.clear()
            chunks.append((time.perf_counter() - t0, lat))
            w = {"n": len(lat)}
            if len(lat):
                w.update({"p50": round(float(np.percentile(lat, 50)), 2), "p99": round(float(np.percentile(lat, 99)), 2),
                          "max": round(float(lat.max()), 2)})
            print(json.dumps({"t": round(time.perf_counter() - t0, 2), "window": w, **counters()}), flush=True)

    reporter = asyncio.ensure_future(report())
    flights = [asyncio.ensure_future(fly(i, s)) for i, s in enumerate(sessions)]
    await asyncio.gather(*(receive(s) for s in sessions))
    for f in flights:
        f.cancel()
    reporter.cancel()
    # The pose -> frame latencies after the warm-up, over the whole run (windows ending after it).
    kept = [lat for t, lat in chunks if t - a["sample"] >= a["warmup"]]
    lat = np.concatenate(kept) if kept else np.zeros(0, np.float32)
    pct = {k: round(float(np.percentile(lat, q)), 2) if len(lat) else None
           for k, q in (("p50", 50), ("p95", 95), ("p99", 99), ("p999", 99.9))}
    pct["max"] = round(float(lat.max()), 2) if len(lat) else None
    print(json.dumps({"final": True, "latency_ms_after_warmup": pct, "poses_timed": len(lat),
                      "sessions_finished": finished[0], "wall_s": round(time.perf_counter() - t0, 1),
                      **counters()}), flush=True)
    for c in clients:
        await c.close()
    if http is not None:
        await http.close()


# -- the soak ---------------------------------------------------------------------------------
def fit(ts: list, ys: list) -> dict:
    """Least squares y = a + b t over the samples: slope per hour, fitted and end-to-end growth in %."""
    t, y = np.asarray(ts, float), np.asarray(ys, float)
    if len(t) < 3 or t[-1] <= t[0]:
        return {}
    b, a = np.polyfit(t, y, 1)
    start = a + b * t[0]
    first, last = float(np.median(y[:3])), float(np.median(y[-3:]))
    return {"start": round(first, 2), "end": round(last, 2), "slope_per_hour": round(float(b) * 3600, 2),
            "growth_pct_fit": round(100 * float(b) * (t[-1] - t[0]) / start, 3),
            "growth_pct_end_to_end": round(100 * (last - first) / first, 3),
            "min": round(float(y.min()), 2), "max": round(float(y.max()), 2)}


def soak(args, mesh: Path, workdir: Path) -> dict:
    from failover import Replica
    from service import stop_process
    duration = 60.0 * args.minutes
    warmup = args.warmup if args.warmup is not None else max(0.1 * duration, min(LAP_S, 0.5 * duration))
    server = Replica(mesh, workdir, "soak-server", "--max-sessions", str(max(32, args.sessions)), "--metrics-port",
                     "0", "--metrics-host", "127.0.0.1", "--transport", args.transport,
                     *(("--web-port", "0") if args.websocket else ()))
    driver = sampler = None
    lines: list = []
    try:
        t0 = time.monotonic()
        sampler = Sampler(server.proc.pid, metrics_port(server), t0, period=args.sample, limit_s=duration + 600)
        a = {"target": f"127.0.0.1:{server.port}", "sessions": args.sessions, "rate": args.rate,
             "duration": duration, "sample": args.sample, "warmup": warmup, "connections": args.connections,
             "cache_dir": str(CACHE), "width": 1280, "height": 720, "fov": 60.0, "tolerance": 1.0,
             "websocket": f"ws://127.0.0.1:{server.web_port}/v1/session" if args.websocket else None}
        with open(workdir / "driver.log", "w") as err:
            driver = subprocess.Popen([sys.executable, __file__, "--driver", json.dumps(a)], stdout=subprocess.PIPE,
                                      stderr=err, text=True, cwd=ROOT)

        def read() -> None:                              # ends when the driver's stdout closes
            for line in driver.stdout:
                try:
                    lines.append((time.monotonic() - t0, json.loads(line)))
                except ValueError:
                    continue
                if "window" in lines[-1][1]:
                    _, d = lines[-1]
                    w = d["window"]
                    print(f"soak: {d['t']:7.1f}/{duration:.0f} s  frames {d['frames']}  p50 {w.get('p50')} ms  "
                          f"p99 {w.get('p99')} ms  divergences {d['divergences']}  errors {d['errors']}  server: "
                          f"{_brief(sampler)}", file=sys.stderr, flush=True)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        status = driver.wait(timeout=duration + 300)
        reader.join(30)
        t_end = time.monotonic() - t0
        sampler.stop()
        err_tail = (workdir / "driver.log").read_text()[-2000:]
        started = next((t for t, d in lines if d.get("started")), None)
        head = next((d for _, d in lines if d.get("started")), {})
        final = next((d for _, d in lines if d.get("final")), None)
        if started is None or final is None:
            raise RuntimeError(f"the load generator ended ({status}) without its figures: {err_tail}")
        fly0 = started + 0.5                              # the driver's t0 in our clock (within a few ms)
        windows = [{"t": round(fly0 + d["t"], 2), **d["window"], "frames": d["frames"], "errors": d["errors"],
                    "divergences": d["divergences"], "resumes": d["resumes"]} for _, d in lines if "window" in d]
        flying = [s for s in sampler.samples if fly0 + warmup <= s["t"] <= fly0 + duration]
        all_flying = [s for s in sampler.samples if fly0 <= s["t"] <= fly0 + duration]
        out = {"minutes": args.minutes, "sessions": args.sessions, "rate_hz": args.rate, "sample_s": args.sample,
               "transport": "websocket" if args.websocket else "grpc", "server_transport": args.transport,
               "connections": args.connections, "warmup_s": round(warmup, 1), "mesh": f"{head.get('mesh', mesh.stem)} ({head.get('faces', 0):,} triangles)",
               "viewport": [1280, 720], "fov_y": 60.0, "tolerance_px": 1.0, "trajectory": "flyover",
               "driver_exit": status, "fly_start_s": round(fly0, 2)}
        ts = [s["t"] for s in flying]
        out["rss_mib"] = fit(ts, [s["rss_mib"] for s in flying])
        out["private_rss_mib"] = fit(ts, [s["anon_mib"] for s in flying])
        out["file_rss_mib"] = fit(ts, [s["file_mib"] for s in flying])
        out["threads"] = {"after_warmup": [min(s["threads"] for s in flying), max(s["threads"] for s in flying)]
                          if flying else None, "whole_run": [min(s["threads"] for s in all_flying),
                                                             max(s["threads"] for s in all_flying)]
                          if all_flying else None}
        out["fds"] = [min(s["fds"] for s in flying), max(s["fds"] for s in flying)] if flying else None
        out["sessions_active"] = [min(s["sessions_active"] for s in flying),
                                  max(s["sessions_active"] for s in flying)] if flying else None
        frames_server = [s["frames"] for s in flying]
        out["server_frames_per_second"] = round((frames_server[-1] - frames_server[0]) / (ts[-1] - ts[0]), 1) \
            if len(flying) >= 2 and ts[-1] > ts[0] else None
        w_after = [w for w in windows if w["t"] - args.sample >= fly0 + warmup and w.get("n")]
        out["latency_ms"] = {"after_warmup": final["latency_ms_after_warmup"], "poses_timed": final["poses_timed"],
                             "window_p99_max": max((w["p99"] for w in w_after), default=None),
                             "window_p50_median": round(float(np.median([w["p50"] for w in w_after])), 2)
                             if w_after else None}
        out.update({k: final[k] for k in ("frames", "poses", "errors", "divergences", "bad_frames", "resumes",
                                          "failovers", "sessions_finished")})
        out["client_cpu_cores"] = round(final["cpu_s"] / max(final["wall_s"], 1e-9), 2)
        rss = out["rss_mib"]
        checks = {"rss_growth_after_warmup_le_2pct": bool(rss) and rss["growth_pct_fit"] <= 2.0
                  and rss["growth_pct_end_to_end"] <= 2.0,
                  "no_errors": not final["errors"] and status == 0,
                  "no_divergences": final["divergences"] == 0 and final["bad_frames"] == 0,
                  "every_session_flew_to_the_end": final["sessions_finished"] == args.sessions}
        out.update({"checks": checks, "pass": all(checks.values()), "windows": windows,
                    "samples": [{k: v for k, v in s.items() if k != "ends"} for s in sampler.samples],
                    "wall_s": round(t_end, 1)})
        out["server_exit"] = stop_process(server.proc, signal.SIGTERM)
        return out
    finally:
        if driver is not None:
            stop_process(driver)
        if sampler is not None:
            sampler.stop()
        stop_process(server.proc)


def _brief(sampler) -> str:
    if sampler is None or not sampler.samples:
        return ""
    s = sampler.samples[-1]
    return (f"RSS {s['rss_mib']:.1f} MiB (private {s['anon_mib']:.1f}), {s['threads']} threads, "
            f"{s['sessions_active']} sessions")


def plot(out: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx, cx) = plt.subplots(3, 1, figsize=(11, 10), sharex=True)
    s = out["samples"]
    t = np.array([x["t"] for x in s]) / 60
    fly0, warm = out["fly_start_s"] / 60, (out["fly_start_s"] + out["warmup_s"]) / 60
    end = (out["fly_start_s"] + 60 * out["minutes"]) / 60
    for a in (ax, bx, cx):
        a.axvspan(fly0, warm, color="grey", alpha=0.12, lw=0)
        a.axvline(end, color="grey", ls="--", lw=0.8)
        a.grid(alpha=0.3)
    ax.plot(t, [x["rss_mib"] for x in s], label="RSS")
    ax.plot(t, [x["anon_mib"] for x in s], label="private (RssAnon)")
    ax.plot(t, [x["file_mib"] for x in s], label="file-backed (the mapped mesh, libraries)", lw=0.8)
    rss = out["rss_mib"]
    if rss:
        ts = np.array([warm, end])
        slope = rss["slope_per_hour"] / 60
        y0 = rss["start"]
        ax.plot(ts, y0 + slope * (ts - warm), "k:", lw=1,
                label=f"RSS fit: {rss['slope_per_hour']:+.1f} MiB/h, {rss['growth_pct_fit']:+.2f} % after warm-up")
    ax.set_ylabel("server memory (MiB)")
    ax.legend(fontsize=7, loc="center right")
    ax.set_title(f"soak: {out['sessions']} one-camera sessions at {out['rate_hz']:g} Hz for {out['minutes']:g} min, "
                 f"{out['mesh']} (grey: warm-up); {'PASS' if out['pass'] else 'FAIL'}", fontsize=9)
    bx.plot(t, [x["threads"] for x in s], label="threads")
    bx.plot(t, [x["fds"] for x in s], label="open descriptors")
    bx.plot(t, [x["sessions_active"] for x in s], label="sessions_active")
    bx.set_ylabel("count")
    bx.set_ylim(bottom=0)
    bx.legend(fontsize=7, loc="center right")
    w = [x for x in out["windows"] if x.get("n")]
    tw = np.array([x["t"] for x in w]) / 60
    cx.plot(tw, [x["p50"] for x in w], label="p50")
    cx.plot(tw, [x["p99"] for x in w], label="p99")
    cx.plot(tw, [x["max"] for x in w], lw=0.6, alpha=0.6, label="max")
    cx.set_yscale("log")
    cx.set_ylabel(f"pose -> frame latency per {out['sample_s']:g} s window (ms)")
    cx.set_xlabel("minutes")
    cx.legend(fontsize=7, loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    if len(sys.argv) == 3 and sys.argv[1] == "--driver":
        asyncio.run(_driver(json.loads(sys.argv[2])))
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0, help="minutes of flight (default 30)")
    ap.add_argument("--sessions", type=int, default=32, help="one-camera sessions (default 32)")
    ap.add_argument("--rate", type=float, default=30.0, help="poses a second per session (default 30)")
    ap.add_argument("--sample", type=float, default=5.0, help="seconds between samples (default 5)")
    ap.add_argument("--warmup", type=float, default=None,
                    help="seconds of warm-up left out of the RSS fit (default: 10 %% of the run, at least a "
                         "60 s lap of the flyover)")
    ap.add_argument("--connections", type=int, default=4,
                    help="connections the sessions share (default 4, as benchmarks/service.py)")
    ap.add_argument("--size", type=int, default=708, help="default terrain size (708: 1,002,528 triangles)")
    ap.add_argument("--websocket", action="store_true",
                    help="fly the sessions over the browser's WebSocket (serve --web-port), one connection each")
    ap.add_argument("--transport", choices=("grpc", "h2"), default="grpc",
                    help="the server's (caveclod serve --transport; default grpc)")
    ap.add_argument("--out", default=str(RESULTS / "soak.json"), help="the JSON report (default results/soak.json)")
    args = ap.parse_args()
    if args.minutes <= 0 or args.sessions < 1 or args.sample <= 0:
        ap.error("--minutes and --sample must be positive, --sessions at least 1")
    mesh = _bench_service().mesh_path(args.size)
    path = Path(args.out)
    with tempfile.TemporaryDirectory(prefix="caveclod-soak-") as tmp:
        out = soak(args, mesh, Path(tmp))
    out.update({"mesh_file": f"default --size {args.size}", "machine_cores": os.cpu_count()})
    RESULTS.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    plot(out, path.with_suffix(".png"))
    rss, prv = out["rss_mib"], out["private_rss_mib"]
    print(f"soak: {out['sessions']} sessions, {out['minutes']:g} min (warm-up {out['warmup_s']} s): RSS "
          f"{rss.get('start')} -> {rss.get('end')} MiB, {rss.get('growth_pct_fit')} % fitted "
          f"({rss.get('growth_pct_end_to_end')} % end to end), {rss.get('slope_per_hour')} MiB/h; private "
          f"{prv.get('start')} -> {prv.get('end')} MiB ({prv.get('slope_per_hour')} MiB/h); threads "
          f"{out['threads']}; latency {out['latency_ms']}; frames {out['frames']}, errors {out['errors']}, "
          f"divergences {out['divergences']}, bad frames {out['bad_frames']}, resumes {out['resumes']}",
          file=sys.stderr)
    for name, ok in out["checks"].items():
        print(f"soak: {'PASS' if ok else 'FAIL'} {name}", file=sys.stderr)
    print(f"soak: {'PASS' if out['pass'] else 'FAIL'} ({path})", file=sys.stderr)
    return 0 if out["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
