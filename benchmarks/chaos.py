"""Chaos: a storm of abrupt disconnects against one server, and replicas killed and drained behind nginx.

    python benchmarks/chaos.py [--disconnects 1000] [--wave 100] [--quick] [--skip storm,failover]

**Storm.** One ``caveclod serve`` (127.0.0.1, port 0, ``--resume-ttl 2``)
serves the default terrain (``--size``, 131,072 triangles by default). A few
honest sessions (``--survivors``, :class:`caveclod.client.Client`, 30 Hz
along the flyover, 640x360) fly from start to end. Waves of ``--wave``
sessions, in client processes of at most ``--per-process`` sessions each
(the asyncio client, a connection per session), Open, get ``--frames``
frames, and then vanish mid-stream without a Close, in turns:

* ``kill``: the client process is SIGKILLed while its sessions still send
  poses and read frames (the kernel closes its connections: the server sees
  them drop, with frames in flight);
* ``cancel``: the client process cancels every stream without a Close
  (RST_STREAM on a connection that stays up, as an app dropping a session
  would), and is then SIGKILLed.

(``--mode close``, a control: the sessions Close properly.) A wave starts
once at most ``--overlap`` earlier waves' sessions are still held (resumable
until the TTL), so every wave meets the same number of held sessions. The
first ``--warmup-waves`` waves are not counted: once their sessions are
freed, the server's RSS, private RSS (RssAnon), threads and open
descriptors (/proc/PID/status, medians over ``--settle`` seconds) are the
baseline. Then waves until ``--disconnects`` sessions have vanished, and the
same figures once they are freed. Pass:

* the storm's sessions are freed: ``caveclod_sessions_active`` back to the
  survivors and ``caveclod_sessions_resumable`` to 0 within
  ``--resume-ttl`` + ``--slack`` seconds of the last client's death, and the
  server counts each of them as ended (``caveclod_session_ends_total``);
* threads and RSS back within 10 % of the baseline;
* the survivors: 0 divergences, 0 bad frames, no error, never resumed; when
  they have closed, the server holds no session; SIGTERM then drains it, exit 0.

Also reported: the peaks, and each figure's least-squares trend over the
waves' starts (MiB per 100 disconnects): a leak grows with every wave, an
allocator's high-water mark does not. Memory a session frees only through
Python's cyclic garbage collector comes back when a full collection runs, so
the figure after the storm depends on when one last ran.

**Failover.** Three replicas (``--drain-seconds``, ``--max-sessions 32``)
behind nginx, configured from deploy/nginx/caveclod.conf.template
(tests/failover.py), under ``caveclod loadtest`` (``--failover-sessions``
sessions, 640x360, 30 Hz, flyover) and ``--failover-viewers``
:class:`caveclod.client.Client` viewers through nginx. Each ``--cycles``
cycle (20 s): at 4 s the replica holding the most sessions is SIGKILLed and
at 8 s restarted on its port; at 12 s the busiest of the other two is
drained (SIGTERM) and restarted on its port once it has exited. The clients
must resume or fail over by themselves. Reported: sessions lost (ended with
an error) and moved (resumes, failovers), errors, divergences, p50/p99
pose -> frame latency, each viewer's longest wait for a frame, and what each
replica logged. Pass: no divergence, no error, no session lost, drained
replicas exit 0.

Writes ``benchmarks/results/chaos.json`` (a section skipped with ``--skip``
keeps its earlier figures) and ``chaos.png``; ``--logs DIR`` keeps every
server's, nginx's and the clients' logs. ``--quick``: 100 disconnects in
waves of 25, one failover cycle. Every process started is stopped by its
pid in a ``finally``; every loop is bounded in count and time.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import itertools
import json
import os
import random
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
CACHE = RESULTS / "vertex-cache"
RATE = 30.0                    # poses a second of every flying session
sys.path.insert(0, str(ROOT / "tests"))      # tests/service.py, tests/failover.py (before benchmarks/service.py)


def _bench_service():
    """benchmarks/service.py under another name (tests/service.py is ``service`` here)."""
    spec = importlib.util.spec_from_file_location("bench_service", ROOT / "benchmarks" / "service.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# -- the server, seen from outside ----------------------------------------------------------
def proc_status(pid: int) -> dict:
    """RSS, private RSS, file-backed RSS (MiB), threads and open descriptors of a process, from /proc."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "RssAnon", "RssFile"):
            out[{"VmRSS": "rss_mib", "RssAnon": "anon_mib", "RssFile": "file_mib"}[key]] = \
                round(int(value.split()[0]) / 1024, 2)
        elif key == "Threads":
            out["threads"] = int(value)
    out["fds"] = len(os.listdir(f"/proc/{pid}/fd"))
    return out


def scrape(port: int) -> dict:
    """The server's Prometheus metrics: {name{labels}: value}."""
    from urllib.request import urlopen
    text = urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            out[name] = float(value)
    return out


def session_ends(m: dict) -> dict:
    """caveclod_session_ends_total by reason."""
    prefix = 'caveclod_session_ends_total{reason="'
    return {k[len(prefix):-2]: int(v) for k, v in m.items() if k.startswith(prefix)}


def metrics_port(replica) -> int:
    """The metrics port a replica (tests/failover.Replica started with --metrics-port 0) logged."""
    from service import wait_until
    assert wait_until(lambda: replica.events("server.metrics"), timeout=30), "no server.metrics event"
    return replica.events("server.metrics")[0]["port"]


class Sampler:
    """Samples a server (its /proc status and metrics) every ``period`` s in a thread, for at most
    ``limit_s`` seconds; ``events`` gets (t, label) marks from the caller."""

    def __init__(self, pid: int, port: int, t0: float, period: float = 0.5, limit_s: float = 3600.0):
        self.pid, self.port, self.t0, self.period, self.limit_s = pid, port, t0, period, limit_s
        self.samples: list = []
        self.events: list = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def sample(self) -> dict | None:
        try:
            m = scrape(self.port)
            s = {"t": round(time.monotonic() - self.t0, 2), **proc_status(self.pid),
                 "sessions_active": int(m["caveclod_sessions_active"]),
                 "sessions_resumable": int(m["caveclod_sessions_resumable"]),
                 "camera_state_mib": round(m["caveclod_camera_state_bytes"] / 2**20, 2),
                 "frames": int(m["caveclod_frames_total"]), "ends": session_ends(m)}
        except (OSError, KeyError, ValueError):
            return None
        return s

    def _run(self) -> None:
        for _ in range(int(self.limit_s / self.period) + 1):
            if self._stop.wait(self.period):
                return
            s = self.sample()
            if s is not None:
                self.samples.append(s)

    def mark(self, label: str) -> float:
        t = round(time.monotonic() - self.t0, 2)
        self.events.append((t, label))
        return t

    def window(self, since: float) -> list:
        """Samples taken at or after ``since`` (seconds from t0)."""
        return [s for s in self.samples if s["t"] >= since]

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)


def medians(samples: list, keys=("rss_mib", "anon_mib", "file_mib", "threads", "fds", "camera_state_mib")) -> dict:
    return {k: round(statistics.median(s[k] for s in samples), 2) for k in keys} if samples else {}


# -- honest clients -------------------------------------------------------------------------
class Survivor:
    """One honest session (the blocking :class:`caveclod.client.Client`) flying the flyover at 30 Hz
    until told to stop; keeps its frames' times and pose -> frame latencies."""

    def __init__(self, index: int, target: str, width: int = 640, height: int = 360):
        from caveclod.client import Client
        self.index, self.error = index, None
        self.client = Client(target, cache_dir=CACHE)
        try:
            mesh = self.client.list_meshes()[0]
            self.lo = (mesh.bounds_min.x, mesh.bounds_min.y, mesh.bounds_min.z)
            self.hi = (mesh.bounds_max.x, mesh.bounds_max.y, mesh.bounds_max.z)
            self.session = self.client.session(mesh.name, width=width, height=height, tolerance_px=1.0)
        except BaseException:
            self.client.close()
            raise
        self.times: list = []           # monotonic time of each frame
        self.tokens: list = []          # the session token it came on
        self.latencies: list = []       # seconds
        self.thread = None

    def start(self, stop: threading.Event, limit_s: float) -> None:
        self.thread = threading.Thread(target=self._fly, args=(stop, limit_s), daemon=True)
        self.thread.start()

    def _fly(self, stop: threading.Event, limit_s: float) -> None:
        from caveclod.paths import flyover
        s, period = self.session, 1.0 / RATE
        t0 = tick = time.monotonic()
        try:
            for _ in range(int(limit_s * RATE) + 2):          # bounded: a tick lasts a period or more
                now = time.monotonic()
                if stop.is_set() or now - t0 >= limit_s:
                    break
                s.send_pose(0, *flyover(self.lo, self.hi, self.index, now - t0))
                tick = max(tick + period, now)                # ticks missed (a failover) are skipped
                for _ in range(100):                          # frames until the next tick
                    f = s.next_frame(timeout=max(tick - time.monotonic(), 0.001))
                    if f is None:
                        break
                    self.times.append(time.monotonic())
                    self.tokens.append(s.protocol.token)
                    self.latencies += [c.latency for c in f.cameras.values() if c.latency is not None]
        except BaseException as exc:          # noqa: BLE001 - reported with the survivor's figures
            self.error = exc

    def gap_ms(self, since: float = 0.0) -> float:
        """The longest wait between two frames after ``since`` (monotonic), ms."""
        times = [t for t in self.times if t >= since]
        return round(1e3 * max((b - a for a, b in itertools.pairwise(times)), default=0.0), 1)

    def result(self, warmup: float = 1.0) -> dict:
        p = self.session.protocol
        lat = np.asarray(self.latencies[int(warmup * RATE):]) * 1e3
        return {"index": self.index, "frames": len(self.times), "divergences": p.divergences,
                "bad_frames": p.bad_frames, "resumes": p.resumes, "failovers": p.failovers,
                "sessions": len(dict.fromkeys(self.tokens)), "error": None if self.error is None else repr(self.error),
                "p50_ms": round(float(np.percentile(lat, 50)), 2) if len(lat) else None,
                "p99_ms": round(float(np.percentile(lat, 99)), 2) if len(lat) else None,
                "longest_gap_ms": self.gap_ms()}

    def close(self) -> None:
        try:
            self.session.close(timeout=2.0)
        except Exception:                     # noqa: BLE001, S110 - best effort: the figures are taken
            pass
        self.client.close()


def survivors_ok(rows: list) -> bool:
    return all(r["divergences"] == 0 and r["bad_frames"] == 0 and r["error"] is None for r in rows)


# -- the storm's client processes -----------------------------------------------------------
async def _storm_client(a: dict) -> None:
    """Internal (``--storm-client JSON``): open ``sessions`` sessions (a connection each), get ``frames``
    frames on each; with mode ``cancel``, cancel every stream without a Close; print {"ready": n, ...}
    (one line); then keep flying (mode ``kill``) or wait, until killed (bounded by ``linger_s``)."""
    from caveclod.client.aio import AsyncClient
    from caveclod.client.cache import VertexBufferCache
    from caveclod.paths import flyover
    cache = VertexBufferCache(a["cache_dir"])            # one copy of the vertex buffer for every session
    clients = [AsyncClient(a["target"], cache_dir=False) for _ in range(a["sessions"])]
    for c in clients:
        c.cache = cache
    mesh = (await clients[0].list_meshes())[0]
    lo = (mesh.bounds_min.x, mesh.bounds_min.y, mesh.bounds_min.z)
    hi = (mesh.bounds_max.x, mesh.bounds_max.y, mesh.bounds_max.z)
    t0 = time.monotonic()

    async def one(i: int):
        s = await clients[i].session(mesh.name, width=a["width"], height=a["height"], tolerance_px=1.0,
                                     timeout=60.0)
        got = 0
        for _ in range(10 * a["frames"]):                # lockstep: a pose, its frame
            s.send_pose(0, *flyover(lo, hi, a["first"] + i, time.monotonic() - t0))
            if await s.next_frame(timeout=5.0) is not None:
                got += 1
            if got >= a["frames"]:
                break
        return s, got

    results = await asyncio.gather(*(one(i) for i in range(a["sessions"])), return_exceptions=True)
    sessions = [r[0] for r in results if not isinstance(r, BaseException) and r[1] > 0]
    failed = sorted({repr(r)[:200] for r in results if isinstance(r, BaseException)})
    if a["mode"] == "cancel":
        for s in sessions:
            s.drop()                                     # RST_STREAM, no Close; the connection stays up
    elif a["mode"] == "close":                           # the control: an honest Close, then the kill
        await asyncio.gather(*(s.close(timeout=10.0) for s in sessions), return_exceptions=True)
    # One line only: the parent waits for it on the pipe's descriptor.
    print(json.dumps({"ready": len(sessions), "failed": len(results) - len(sessions), "why": failed}), flush=True)
    if a["mode"] in ("cancel", "close"):
        await asyncio.sleep(a["linger_s"])
        return

    async def keep_flying(i: int, s) -> None:            # mid-stream when the kill comes
        for _ in range(int(a["linger_s"] * 10)):
            s.send_pose(0, *flyover(lo, hi, a["first"] + i, time.monotonic() - t0))
            try:
                await s.next_frame(timeout=0.1)
            except Exception:                            # noqa: BLE001 - the session is gone: stop
                return

    await asyncio.gather(*(keep_flying(i, s) for i, s in enumerate(sessions)))


def storm_wave(target: str, sessions: int, per_process: int, mode: str, first: int, frames: int,
               width: int, height: int, workdir: Path, timeout: float = 90.0) -> dict:
    """One wave: client processes open ``sessions`` sessions, get frames, vanish (``mode``); returns
    what was ready, failed and when. The processes are SIGKILLed by pid in a ``finally``."""
    from service import readline_within, stop_process
    procs, ready, failed, why = [], 0, 0, []
    t_start = time.monotonic()
    try:
        for k, first_k in enumerate(range(first, first + sessions, per_process)):
            n = min(per_process, first + sessions - first_k)
            a = {"target": target, "sessions": n, "frames": frames, "mode": mode, "first": first_k,
                 "cache_dir": str(CACHE), "width": width, "height": height, "linger_s": timeout}
            with open(workdir / f"storm-{first}-{k}.log", "w") as err:
                procs.append(subprocess.Popen([sys.executable, __file__, "--storm-client", json.dumps(a)],
                                              stdout=subprocess.PIPE, stderr=err, text=True, cwd=ROOT))
        deadline = time.monotonic() + timeout
        for p in procs:
            line = readline_within(p.stdout, max(deadline - time.monotonic(), 0.1))
            if not line:
                failed += per_process
                why.append("no ready line in time")
                continue
            r = json.loads(line)
            ready, failed, why = ready + r["ready"], failed + r["failed"], why + r["why"]
        t_ready = time.monotonic()
        time.sleep(random.uniform(0.05, 0.2))          # mid-stream: poses and frames in flight
        t_gone = time.monotonic()
    finally:
        for p in procs:
            stop_process(p, signal.SIGKILL)
    return {"mode": mode, "sessions": sessions, "ready": ready, "failed": failed, "why": sorted(set(why))[:5],
            "processes": len(procs), "t_start": t_start, "t_ready": t_ready, "t_gone": t_gone}


def wait_freed(sampler: Sampler, survivors: int, limit_s: float) -> float | None:
    """Seconds until the server holds only the survivors' sessions (None: not within ``limit_s``)."""
    t0 = time.monotonic()
    for _ in range(int(limit_s / 0.1) + 1):
        s = sampler.sample()
        if s is not None and s["sessions_active"] == survivors and s["sessions_resumable"] == 0:
            return round(time.monotonic() - t0, 2)
        if time.monotonic() - t0 > limit_s:
            return None
        time.sleep(0.1)
    return None


def _brief(samples: list) -> str:
    if not samples:
        return ""
    s = samples[-1]
    return (f"RSS {s['rss_mib']:.0f} MiB (private {s['anon_mib']:.0f}), {s['threads']} threads, {s['fds']} fds, "
            f"sessions {s['sessions_active']} + {s['sessions_resumable']} resumable")


def run_waves(args, target: str, workdir: Path, sampler: Sampler, t0: float, disconnects: int, first: int,
              what: str) -> list:
    """Waves of ``args.wave`` sessions (kill and cancel in turn under ``--mode mixed``), ``args.pause`` apart,
    until ``disconnects`` sessions have vanished; their records, times in seconds from ``t0``."""
    waves, done = [], 0
    for k in range(2 * (disconnects // max(args.wave, 1)) + 2):       # bounded: refusals repeat a wave
        if done >= disconnects:
            break
        n = min(args.wave, disconnects - done)
        # At most --overlap earlier waves still held (resumable until the TTL): the storm's high-water mark
        # of sessions is the same in every wave, the warm-up's included.
        for _ in range(int((args.resume_ttl + 30) / 0.1)):
            s = sampler.sample()
            if s is not None and s["sessions_active"] + s["sessions_resumable"] - args.survivors \
                    <= args.overlap * args.wave:
                break
            time.sleep(0.1)
        mode = ("kill", "cancel")[k % 2] if args.mode == "mixed" else args.mode
        before = sampler.sample() or {}
        w = storm_wave(target, n, args.per_process, mode, first, args.frames, 640, 360, workdir)
        w["before"] = {k: before.get(k) for k in ("rss_mib", "anon_mib", "threads", "fds", "sessions_active",
                                                  "sessions_resumable")}
        w["disconnects_before"] = done
        first += n
        done += w["ready"]
        w.update({key: round(w[key] - t0, 2) for key in ("t_start", "t_ready", "t_gone")})
        waves.append(w)
        print(f"{what}: wave {len(waves)} ({mode}): {w['ready']} sessions gone, {w['failed']} failed "
              f"{w['why']}  ({done}/{disconnects}); server: {_brief(sampler.samples[-1:])}",
              file=sys.stderr)
        time.sleep(args.pause)
    return waves


def storm(args, mesh: Path, workdir: Path) -> dict:
    from failover import Replica
    from service import stop_process
    survivors_n = args.survivors
    max_sessions = survivors_n + (args.overlap + 2) * args.wave + 8    # a wave, --overlap held ones, slack
    saved = dict(os.environ)
    os.environ.update(dict(kv.split("=", 1) for kv in args.server_env))      # e.g. glibc malloc tunables
    try:
        server = Replica(mesh, workdir, "storm-server", "--resume-ttl", str(args.resume_ttl), "--max-sessions",
                         str(max_sessions), "--metrics-port", "0", "--metrics-host", "127.0.0.1")
    finally:
        os.environ.clear()
        os.environ.update(saved)
    target = f"127.0.0.1:{server.port}"
    sampler, survivors, stop = None, [], threading.Event()
    out = {"mesh": mesh.name, "resume_ttl_s": args.resume_ttl, "slack_s": args.slack, "wave": args.wave,
           "disconnects_asked": args.disconnects, "survivors": survivors_n, "max_sessions": max_sessions,
           "frames_before_vanishing": args.frames, "server_env": args.server_env, "per_process": args.per_process}
    try:
        t0 = time.monotonic()
        sampler = Sampler(server.proc.pid, metrics_port(server), t0, period=args.period, limit_s=1800)
        for i in range(survivors_n):
            survivors.append(Survivor(i, target))
        for v in survivors:
            v.start(stop, limit_s=1800)
        sampler.mark("survivors flying")
        # Warm-up: --warmup-waves waves like the storm's (the server's allocator reaches the storm's
        # high-water mark), not counted; once their sessions are freed, the baseline.
        first = 100_000
        warm = run_waves(args, target, workdir, sampler, t0, args.warmup_waves * args.wave, first, "warm-up")
        sampler.mark("warm-up waves gone")
        out["warmup_waves"] = warm
        out["warmup_freed_s"] = wait_freed(sampler, survivors_n, args.resume_ttl + 30)
        time.sleep(args.settle)
        t_base = sampler.mark("baseline")
        time.sleep(args.settle)
        base_samples = sampler.window(t_base)
        out["baseline"] = medians(base_samples)
        ends0 = base_samples[-1]["ends"] if base_samples else {}
        print(f"storm: baseline {out['baseline']}", file=sys.stderr)
        # The storm.
        waves = run_waves(args, target, workdir, sampler, t0, args.disconnects, 0, "storm")
        t_last = t0 + waves[-1]["t_gone"] if waves else time.monotonic()      # the last client killed
        sampler.mark("last wave gone")
        freed = wait_freed(sampler, survivors_n, args.resume_ttl + args.slack + 30)
        freed_since_last = None if freed is None else round(time.monotonic() - t_last, 2)
        sampler.mark("storm freed")
        time.sleep(args.settle)
        t_after = sampler.mark("after")
        time.sleep(args.settle)
        after_samples = sampler.window(t_after)
        out["after"] = medians(after_samples)
        ends1 = after_samples[-1]["ends"] if after_samples else {}
        stop.set()
        for v in survivors:
            v.thread.join(30)
        rows = [v.result() for v in survivors]
        for v in survivors:
            v.close()
        survivors = []
        final = wait_freed(sampler, 0, 10)           # the survivors closed: nothing held at all
        sampler.stop()
        storm_samples = [s for s in sampler.samples if s["t"] >= t_base]
        peak = {k: max(s[k] for s in storm_samples) for k in ("rss_mib", "anon_mib", "threads", "fds",
                                                              "sessions_active", "sessions_resumable")}
        ends = {r: ends1.get(r, 0) - ends0.get(r, 0) for r in set(ends0) | set(ends1)}
        base, after = out["baseline"], out["after"]
        ratio = {k: round(after[k] / base[k], 3) for k in ("rss_mib", "anon_mib", "threads", "fds")}
        disconnects = sum(w["ready"] for w in waves)
        # A leak grows the server with every wave; the allocator's high-water mark does not.
        trend = {}
        if len(waves) >= 3:
            x = np.array([w["disconnects_before"] for w in waves], float)
            for key in ("rss_mib", "anon_mib", "threads", "fds"):
                y = np.array([w["before"][key] for w in waves], float)
                trend[f"{key}_per_100_disconnects"] = round(100 * float(np.polyfit(x, y, 1)[0]), 3)
        checks = {
            "sessions_freed_within_ttl_plus_slack": freed is not None and freed_since_last
            <= args.resume_ttl + args.slack,
            "every_vanished_session_ended": sum(ends.values()) == disconnects,
            "threads_within_10pct": ratio["threads"] <= 1.10,
            "rss_within_10pct": ratio["rss_mib"] <= 1.10,
            "survivors_no_divergence_no_error": survivors_ok(rows),
            "survivors_never_resumed": all(r["resumes"] == 0 and r["failovers"] == 0 for r in rows),
            "nothing_held_after_survivors_closed": final is not None,
            "disconnects_reached": disconnects >= args.disconnects,
        }
        out.update({
            "disconnects": disconnects, "waves": waves, "refused_or_failed_opens": sum(w["failed"] for w in waves),
            "storm_seconds": round(waves[-1]["t_gone"] - waves[0]["t_start"], 1) if waves else 0.0,
            "freed_s_after_last_disconnect": freed_since_last, "ended_by_reason": ends,
            "peak": peak, "after_over_baseline": ratio,
            "trend_at_wave_starts": trend, "survivor_sessions": rows, "checks": checks,
            "pass": all(checks.values()), "events": sampler.events,
            "samples": [{k: v for k, v in s.items() if k != "ends"} for s in sampler.samples],
            "server_exit": None})
        out["server_exit"] = stop_process(server.proc, signal.SIGTERM)
        out["checks"]["server_drained_exit_0"] = out["server_exit"] == 0
        out["pass"] = all(out["checks"].values())
        return out
    finally:
        stop.set()
        for v in survivors:
            v.close()
        if sampler is not None:
            sampler.stop()
        stop_process(server.proc)


# -- replicas behind nginx ------------------------------------------------------------------
class Fleet:
    """Named replicas (a, b, c) on fixed ports once started; restarts keep the port. Every process
    ever started is kept in ``all`` to be stopped by pid."""

    def __init__(self, mesh: Path, workdir: Path, names, args: list):
        self.mesh, self.workdir, self.args = mesh, workdir, args
        self.current: dict = {}
        self.ports: dict = {}
        self.metrics: dict = {}
        self.generation: dict = {}
        self.all: list = []
        for name in names:
            self.start(name)

    def start(self, name: str) -> None:
        from failover import Replica
        gen = self.generation.get(name, 0) + 1
        extra = ["--port", str(self.ports[name])] if name in self.ports else []
        last = None
        for _ in range(10):                              # the port may take a moment to be free again
            try:
                r = Replica(self.mesh, self.workdir, f"{name}{gen}", *self.args, "--metrics-port", "0",
                            "--metrics-host", "127.0.0.1", *extra)
                break
            except AssertionError as exc:
                last = exc
                time.sleep(0.5)
        else:
            raise AssertionError(f"replica {name} did not restart: {last}")
        self.all.append(r)
        self.current[name], self.generation[name] = r, gen
        self.ports.setdefault(name, r.port)
        self.metrics[name] = metrics_port(r)

    def sessions(self) -> dict:
        """{name: sessions_active} of the replicas that answer."""
        out = {}
        for name, r in self.current.items():
            if r.proc.poll() is not None:
                continue
            try:
                out[name] = int(scrape(self.metrics[name])["caveclod_sessions_active"])
            except (OSError, KeyError, ValueError):
                continue
        return out

    def busiest(self, among) -> str:
        s = self.sessions()
        return max(among, key=lambda n: s.get(n, -1))

    def stop_all(self) -> None:
        from service import stop_process
        for r in self.all:
            stop_process(r.proc)


def failover(args, mesh: Path, workdir: Path) -> dict:
    from failover import Balancer, nginx_binary
    nginx = nginx_binary()
    if nginx is None:
        return {"skipped": "nginx is not installed (apt-get install nginx-light)"}
    fleet = balancer = loadtest = None
    viewers, stop, timeline, series, drains = [], threading.Event(), [], [], []
    cycle_s, tail_s = 20.0, 6.0
    duration = args.cycles * cycle_s + tail_s
    try:
        fleet = Fleet(mesh, workdir, ("a", "b", "c"), ["--drain-seconds", str(args.drain_seconds),
                                                        "--max-sessions", "32", "--resume-ttl", "10"])
        balancer = Balancer(nginx, [fleet.current[n] for n in ("a", "b", "c")])
        target = f"127.0.0.1:{balancer.port}"
        t0 = time.monotonic()

        def mark(label: str) -> None:
            timeline.append((round(time.monotonic() - t0, 2), label))
            print(f"failover: {timeline[-1][0]:6.2f} s  {label}", file=sys.stderr)

        def watch() -> None:                 # sessions per replica, every 0.25 s
            for _ in range(int((duration + 120) / 0.25)):
                if stop.wait(0.25):
                    return
                series.append((round(time.monotonic() - t0, 2), fleet.sessions()))

        threading.Thread(target=watch, daemon=True).start()
        cmd = [sys.executable, "-m", "caveclod.cli", "loadtest", "--target", target, "--sessions",
               str(args.failover_sessions), "--cameras", "1", "--duration", str(duration + 8), "--rate", str(RATE),
               "--trajectory", "flyover", "--tolerance", "1", "--width", "640", "--height", "360", "--json",
               "--cache-dir", str(CACHE)]
        with open(workdir / "loadtest.log", "w") as err:
            loadtest = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, cwd=ROOT)
        mark("loadtest started")
        for i in range(args.failover_viewers):
            viewers.append(Survivor(i, target))
        for v in viewers:
            v.start(stop, limit_s=duration + 30)
        total = args.failover_sessions + args.failover_viewers
        for _ in range(80):                                 # until every session is open (at most 8 s)
            if sum(fleet.sessions().values()) >= total:
                break
            time.sleep(0.1)
        mark(f"sessions open: {fleet.sessions()}")
        base = time.monotonic()

        def at(seconds: float) -> None:
            time.sleep(max(base + seconds - time.monotonic(), 0.0))

        for c in range(args.cycles):
            start = c * cycle_s
            at(start + 4)
            victim = fleet.busiest("abc")
            mark(f"SIGKILL {victim} (sessions {fleet.sessions()})")
            os.kill(fleet.current[victim].proc.pid, signal.SIGKILL)
            fleet.current[victim].proc.wait(10)
            at(start + 8)
            fleet.start(victim)
            mark(f"{victim} restarted")
            at(start + 12)
            drained = fleet.busiest([n for n in "abc" if n != victim])
            mark(f"SIGTERM {drained} (drain {args.drain_seconds} s; sessions {fleet.sessions()})")
            r = fleet.current[drained]
            os.kill(r.proc.pid, signal.SIGTERM)
            try:
                status = r.proc.wait(args.drain_seconds + 15)
            except subprocess.TimeoutExpired:
                os.kill(r.proc.pid, signal.SIGKILL)
                r.proc.wait(10)
                status = "did not exit"
            drains.append(status)
            mark(f"{drained} exited {status}")
            fleet.start(drained)
            mark(f"{drained} restarted")
        at(args.cycles * cycle_s + tail_s)
        mark("schedule done")
        out, _ = loadtest.communicate(timeout=duration + 120)
        lt = json.loads(out)
        mark("loadtest done")
        stop.set()
        for v in viewers:
            v.thread.join(30)
        rows = [v.result() for v in viewers]
        replicas = {}
        for r in fleet.all:
            ended: dict = {}
            for e in r.events("session.ended"):
                ended[e.get("reason")] = ended.get(e.get("reason"), 0) + 1
            replicas[r.name] = {"port": r.port, "opened": len(r.events("session.opened")),
                                "resumed": len(r.events("session.resumed")), "ended": ended,
                                "exit": r.proc.poll()}
        lost = sum(lt["errors"].values()) + sum(r["error"] is not None for r in rows)
        checks = {"no_divergence": lt["divergences"] == 0 and lt["bad_frames"] == 0 and survivors_ok(rows),
                  "no_error": not lt["errors"] and all(r["error"] is None for r in rows),
                  "no_session_lost": lost == 0,
                  "drained_replicas_exited_0": all(d == 0 for d in drains),
                  "sessions_moved": lt["failovers"] + lt["resumes"] + sum(r["failovers"] + r["resumes"]
                                                                          for r in rows) > 0}
        return {"replicas": 3, "cycles": args.cycles, "drain_seconds": args.drain_seconds,
                "loadtest_sessions": args.failover_sessions, "viewers": args.failover_viewers,
                "loadtest": {k: lt[k] for k in ("sessions", "frames", "frames_per_second", "latency_ms",
                                                "divergences", "bad_frames", "resumes", "failovers", "errors",
                                                "keyframes", "duration_s")},
                "sessions_lost": lost,
                "sessions_failed_over": lt["failovers"] + sum(r["failovers"] for r in rows),
                "sessions_resumed": lt["resumes"] + sum(r["resumes"] for r in rows),
                "viewer_sessions": rows, "replica_logs": replicas, "timeline": timeline,
                "sessions_per_replica": series, "checks": checks, "pass": all(checks.values())}
    finally:
        stop.set()
        for v in viewers:
            v.close()
        from service import stop_process
        if loadtest is not None:
            stop_process(loadtest)
        if balancer is not None:
            for name in ("access.log", "error.log"):
                if (balancer.dir / name).exists():
                    shutil.copy(balancer.dir / name, workdir / f"nginx-{name}")
            balancer.stop()
        if fleet is not None:
            fleet.stop_all()


# -- the plot -------------------------------------------------------------------------------
def plot(out: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(14, 8))
    (ax, bx), (cx, dx) = axes
    st = out.get("storm") or {}
    if st.get("samples"):
        s = st["samples"]
        t = [x["t"] for x in s]
        for a in (ax, bx, cx):
            for w in st.get("warmup_waves", []):
                a.axvspan(w["t_start"], w["t_gone"], color="grey", alpha=0.12, lw=0)
            for w in st.get("waves", []):
                a.axvspan(w["t_start"], w["t_gone"], color={"kill": "C1", "cancel": "C4"}.get(w["mode"], "C2"),
                          alpha=0.12, lw=0)
            for te, label in st.get("events", []):
                if label in ("baseline", "after", "last wave gone"):
                    a.axvline(te, color="grey", ls="--", lw=0.8)
                    a.text(te, 1.0, " " + label, transform=a.get_xaxis_transform(), fontsize=6, rotation=90,
                           va="top", color="grey")
        ax.plot(t, [x["rss_mib"] for x in s], label="RSS")
        ax.plot(t, [x["anon_mib"] for x in s], label="private (RssAnon)")
        for key, colour in (("rss_mib", "C0"), ("anon_mib", "C1")):
            ax.axhline(st["baseline"][key] * 1.1, color=colour, ls=":", lw=0.8)
        ax.set_ylabel("server memory (MiB)")
        ax.legend(fontsize=7, loc="upper left")
        ax.set_title(f"storm: {st.get('disconnects')} sessions vanished, waves of {st.get('wave')} (grey: warm-up, "
                     "orange: SIGKILL, purple: cancelled)", fontsize=9)
        bx.plot(t, [x["threads"] for x in s], label="threads")
        bx.plot(t, [x["fds"] for x in s], label="open descriptors")
        bx.axhline(st["baseline"]["threads"] * 1.1, color="C0", ls=":", lw=0.8)
        bx.set_ylabel("count")
        bx.legend(fontsize=7, loc="upper left")
        bx.set_title("server threads and descriptors (dotted: baseline +10 %)", fontsize=9)
        cx.plot(t, [x["sessions_active"] for x in s], label="sessions_active")
        cx.plot(t, [x["sessions_resumable"] for x in s], label="sessions_resumable")
        cx.set_ylabel("sessions")
        cx.set_xlabel("seconds")
        c2 = cx.twinx()
        c2.plot(t, [x["camera_state_mib"] for x in s], color="C2", lw=0.8, label="camera state MiB")
        c2.set_ylabel("camera state (MiB)")
        cx.legend(fontsize=7, loc="upper left")
        c2.legend(fontsize=7, loc="upper right")
        cx.set_title(f"sessions (resume TTL {st.get('resume_ttl_s')} s; survivors {st.get('survivors')})", fontsize=9)
        for a in (ax, bx):
            a.set_xlabel("seconds")
            a.grid(alpha=0.3)
        cx.grid(alpha=0.3)
    fo = out.get("failover") or {}
    if fo.get("sessions_per_replica"):
        series = fo["sessions_per_replica"]
        t = [x[0] for x in series]
        for k, name in enumerate("abc"):
            dx.plot(t, [x[1].get(name, np.nan) for x in series], label=f"replica {name}", color=f"C{k}")
        for te, label in fo["timeline"]:
            if label.startswith(("SIGKILL", "SIGTERM")):
                dx.axvline(te, color="red" if label.startswith("SIGKILL") else "orange", ls="--", lw=0.9)
                dx.text(te, dx.get_ylim()[1] * 0.95 if dx.get_ylim()[1] > 0 else 1, " " + label.split(" (")[0],
                        fontsize=7, rotation=90, va="top")
            elif label.endswith("restarted"):
                dx.axvline(te, color="green", ls=":", lw=0.9)
        lt = fo["loadtest"]
        dx.set_title(f"3 replicas behind nginx: {lt['sessions']} loadtest sessions + {fo['viewers']} viewers; "
                     f"p99 {lt['latency_ms']['p99']} ms, failovers {fo['sessions_failed_over']}, "
                     f"lost {fo['sessions_lost']}", fontsize=9)
        dx.set_xlabel("seconds (red: SIGKILL, orange: SIGTERM, green: restarted)")
        dx.set_ylabel("sessions_active per replica")
        dx.legend(fontsize=7, loc="upper left")
        dx.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    if len(sys.argv) == 3 and sys.argv[1] == "--storm-client":
        asyncio.run(_storm_client(json.loads(sys.argv[2])))
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--disconnects", type=int, default=1000, help="abrupt disconnects of the storm (default 1000)")
    ap.add_argument("--wave", type=int, default=100, help="sessions that vanish together (default 100)")
    ap.add_argument("--per-process", type=int, default=50, help="sessions per client process (default 50)")
    ap.add_argument("--mode", choices=("mixed", "kill", "cancel", "close"), default="mixed",
                    help="how sessions vanish: SIGKILLed processes, cancelled streams, or waves of each in turn "
                         "(default); close: a control, sessions that Close properly")
    ap.add_argument("--warmup-waves", type=int, default=3,
                    help="waves before the baseline, not counted (default 3: the storm's high-water mark)")
    ap.add_argument("--overlap", type=int, default=1,
                    help="a wave starts once at most this many earlier waves' sessions are still held (default 1)")
    ap.add_argument("--frames", type=int, default=3, help="frames each storm session gets first (default 3)")
    ap.add_argument("--survivors", type=int, default=4, help="honest sessions flying throughout (default 4)")
    ap.add_argument("--resume-ttl", type=int, default=2, help="the server's --resume-ttl (default 2 s)")
    ap.add_argument("--slack", type=float, default=5.0,
                    help="seconds past the TTL within which the storm's sessions must be freed (default 5)")
    ap.add_argument("--pause", type=float, default=0.5, help="seconds between waves (default 0.5)")
    ap.add_argument("--settle", type=float, default=3.0,
                    help="seconds to wait, then to sample, for the baseline and the after figures (default 3)")
    ap.add_argument("--period", type=float, default=0.5, help="seconds between samples of the server (default 0.5)")
    ap.add_argument("--server-env", action="append", default=[], metavar="NAME=VALUE",
                    help="environment of the storm's server (repeatable), e.g. MALLOC_ARENA_MAX=2")
    ap.add_argument("--size", type=int, default=256, help="default terrain size (256: 131,072 triangles)")
    ap.add_argument("--cycles", type=int, default=2, help="failover: kill+drain cycles (default 2)")
    ap.add_argument("--failover-sessions", type=int, default=16, help="failover: loadtest sessions (default 16)")
    ap.add_argument("--failover-viewers", type=int, default=4, help="failover: Client viewers (default 4)")
    ap.add_argument("--drain-seconds", type=float, default=2.0, help="failover: the replicas' --drain-seconds")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: 100 disconnects in waves of 25, one failover cycle, 8 loadtest sessions")
    ap.add_argument("--skip", default="", help="comma-separated sections to skip: storm,failover")
    ap.add_argument("--logs", metavar="DIR", help="copy the servers', nginx's and the clients' logs to DIR")
    ap.add_argument("--out", default=str(RESULTS / "chaos.json"), help="the JSON report (default results/chaos.json)")
    args = ap.parse_args()
    if args.quick:
        args.disconnects, args.wave, args.per_process = 100, 25, 25
        args.cycles, args.failover_sessions, args.failover_viewers = 1, 8, 2
    skip = set(filter(None, args.skip.split(",")))
    mesh = _bench_service().mesh_path(args.size)
    path = Path(args.out)
    report = json.loads(path.read_text()) if skip and path.exists() else {}
    report.update({"mesh": f"default --size {args.size}", "machine_cores": os.cpu_count(), "quick": args.quick})
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="caveclod-chaos-") as tmp:
        workdir = Path(tmp)
        os.chmod(workdir, 0o755)
        if "storm" not in skip:
            report["storm"] = storm(args, mesh, workdir)
            st = report["storm"]
            print(f"storm: {st['disconnects']} disconnects in {len(st['waves'])} waves ({st['storm_seconds']} s); "
                  f"freed {st['freed_s_after_last_disconnect']} s after the last; baseline {st['baseline']}; "
                  f"after {st['after']}; peak {st['peak']}; ended {st['ended_by_reason']}; survivors "
                  f"{st['survivor_sessions']}", file=sys.stderr)
            for name, ok in st["checks"].items():
                print(f"storm: {'PASS' if ok else 'FAIL'} {name}", file=sys.stderr)
        if "failover" not in skip:
            report["failover"] = failover(args, mesh, workdir)
            fo = report["failover"]
            if "skipped" not in fo:
                print(f"failover: loadtest {fo['loadtest']}; lost {fo['sessions_lost']}, failed over "
                      f"{fo['sessions_failed_over']}, resumed {fo['sessions_resumed']}; viewers "
                      f"{fo['viewer_sessions']}; replicas {fo['replica_logs']}", file=sys.stderr)
                for name, ok in fo["checks"].items():
                    print(f"failover: {'PASS' if ok else 'FAIL'} {name}", file=sys.stderr)
        if args.logs:                                   # the servers', nginx's and the clients' logs
            shutil.copytree(workdir, args.logs, dirs_exist_ok=True)
    report["wall_s"] = round(time.monotonic() - t0, 1)
    report["pass"] = all(report[k].get("pass", True) for k in ("storm", "failover") if k in report)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1) + "\n")
    plot(report, path.with_suffix(".png"))
    print(f"chaos: {'PASS' if report['pass'] else 'FAIL'} ({report['wall_s']} s; {path})", file=sys.stderr)
    return 0 if report["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
