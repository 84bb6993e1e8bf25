"""``caveclod loadtest``: many windowless sessions flying camera paths against a server.

Each session runs on one asyncio event loop (:mod:`.aio`): a task sends
every camera's pose at ``--rate`` Hz along ``--trajectory``
(:mod:`caveclod.paths`; camera k of session s flies path camera
``s * cameras + k``, so sessions spread over the mesh), another applies the
frames, which verifies every CRC-32 and acks. Pose -> frame latency is timed
by pose_seq from the send to the arrival of the first frame that answers it,
so it includes both ends' queueing. A progress line goes to stderr every
second.

Figures (``--json`` prints them as one object): ``sessions``, ``frames``,
``frames_per_second``, ``latency_ms`` (p50, p95, p99, max; poses answered
after the first ``--warmup`` seconds, while cameras refine up from the base
mesh, are not timed), ``bytes_per_frame``
(all frames), ``bytes_per_changed_triangle`` (delta frames: their bytes over
the triangles they write; keyframes left out; ``_steady``: after the
warm-up only), ``divergences`` (CRC
mismatches), ``resumes`` and ``failovers`` (broken streams resumed with
their token, and answered by a fresh session because the replica was gone),
``errors`` (streams that ended with a status, by code), and the
load generator's own CPU. Exit status 1 when there are divergences or errors.

In cache mode (``--cache-vertices N``, ``--cache-strategy S``) the figures
add ``vertices_inserted`` (vertices written into slots, keyframes included),
``vertex_bytes_per_frame`` (bytes of VertexWrites per frame),
``cache_hit_rate`` (of the vertices that became active, the share still in
a slot: CameraStats.cache_hits over hits + inserts) and
``cache_tolerance_px_max`` (the most a camera was coarsened to fit).
"""

from __future__ import annotations

import asyncio
import importlib.util
import json
import math
import os
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field

import grpc
import numpy as np

from .. import opstream
from ..errors import InputError
from ..vertexpack import check_position_bits
from ..paths import pose as path_pose
from .aio import AsyncClient, AsyncSession
from .session import SessionEnded

TAIL_SECONDS = 1.0       # after the last pose: time for the last frames to arrive


@dataclass
class Tally:
    """What the sessions saw, summed."""

    frames: int = 0
    delta_frames: int = 0
    keyframes: int = 0
    bytes: int = 0
    delta_bytes: int = 0
    delta_triangles: int = 0
    steady_bytes: int = 0            # delta frames after the warm-up
    steady_triangles: int = 0
    poses_sent: int = 0
    latencies: list = field(default_factory=list)     # seconds
    errors: Counter = field(default_factory=Counter)
    divergences: int = 0
    bad_frames: int = 0
    resumes: int = 0
    failovers: int = 0          # broken streams answered by a fresh session (a replica gone)
    vertices_inserted: int = 0       # cache mode: vertex slot writes received
    vertex_bytes: int = 0
    cache_hits: int = 0
    cache_inserts: int = 0
    cache_tolerance_max: float = 0.0

    def merge(self, other: dict) -> None:
        """Add another process's tally (:meth:`as_dict`) to this one."""
        for name, value in other.items():
            if name == "latencies":
                self.latencies.extend(value)
            elif name == "errors":
                self.errors.update(value)
            elif name == "cache_tolerance_max":
                self.cache_tolerance_max = max(self.cache_tolerance_max, value)
            else:
                setattr(self, name, getattr(self, name) + value)

    def as_dict(self) -> dict:
        out = dict(self.__dict__)
        out["errors"] = dict(self.errors)
        return out


async def _fly(session: AsyncSession, index: int, args, lo, hi, t0: float, tally: Tally) -> None:
    """Send poses at args.rate until args.duration seconds after t0."""
    period = 1.0 / args.rate
    tick = index / max(args.sessions, 1) * period        # stagger the sessions (of every process) over a period
    while tick < args.duration:
        delay = t0 + tick - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        elif delay < -period:                            # late (a slow open): skip the missed ticks, no burst
            tick += (-delay // period) * period
        for c in range(args.cameras):
            eye, target, up = path_pose(args.trajectory, lo, hi, index * args.cameras + c, tick)
            session.send_pose(c, eye, target, up)
            tally.poses_sent += 1
        tick += period


def count_frame(tally: Tally, frame, steady: bool) -> None:
    """Add one applied frame (:class:`~.protocol.FrameUpdate`) to ``tally``; ``steady``: after the warm-up."""
    tally.frames += 1
    tally.bytes += frame.nbytes
    keyframe = False
    written = 0
    for cam in frame.cameras.values():
        keyframe |= cam.keyframe
        written += cam.triangles_written
        tally.vertices_inserted += cam.vertices_written
        tally.vertex_bytes += cam.vertex_bytes
        if cam.stats is not None:
            tally.cache_hits += cam.stats.cache_hits
            tally.cache_inserts += cam.stats.cache_inserts
            tally.cache_tolerance_max = max(tally.cache_tolerance_max, cam.stats.cache_tolerance_px)
        if steady and cam.latency is not None:
            tally.latencies.append(cam.latency)
    if keyframe:
        tally.keyframes += 1
    else:
        tally.delta_frames += 1
        tally.delta_bytes += frame.nbytes
        tally.delta_triangles += written
        if steady:
            tally.steady_bytes += frame.nbytes
            tally.steady_triangles += written


async def _receive(session: AsyncSession, until: float, timed_from: float, tally: Tally) -> None:
    """Apply frames until ``until`` (perf_counter), recording what they cost.

    At ``until`` the session sends Close; the server then ends the stream,
    which ends this loop (no timer per frame: at hundreds of frames a second
    they cost the generator more than the frames). Latencies are recorded
    from ``timed_from`` on: the first poses refine every camera up from the
    base mesh, which is not the steady state.
    """
    loop = asyncio.get_running_loop()
    closing = loop.call_later(max(until - time.perf_counter(), 0.0), session.begin_close, "loadtest done")
    try:
        while True:
            try:
                frame = await session.next_frame()
            except SessionEnded as end:
                if end.code is None:          # our Close, answered
                    return
                raise
            count_frame(tally, frame, time.perf_counter() >= timed_from)
    finally:
        closing.cancel()


async def _one(client: AsyncClient, index: int, args, mesh, tally: Tally, t0: float) -> None:
    lo = (mesh.bounds_min.x, mesh.bounds_min.y, mesh.bounds_min.z)
    hi = (mesh.bounds_max.x, mesh.bounds_max.y, mesh.bounds_max.z)
    session = None
    try:
        session = await client.session(mesh.name, cameras=args.cameras, width=args.width, height=args.height,
                                       fov_y=args.fov, tolerance_px=args.tolerance,
                                       cache_vertices=args.cache_vertices, cache_strategy=args.cache_strategy,
                                       cache_pq_fraction=args.cache_pq_fraction,
                                       frame_encoding=getattr(args, "frame_encoding", "linked"),
                                       vertex_encoding=getattr(args, "vertex_encoding", "packed"),
                                       position_bits=getattr(args, "position_bits", None),
                                       prune=False if getattr(args, "no_prune", False) else None,
                                       strict_bound=True if getattr(args, "strict_bound", False) else None)
        flying = asyncio.ensure_future(_fly(session, index, args, lo, hi, t0, tally))
        try:
            await _receive(session, t0 + args.duration + TAIL_SECONDS, t0 + args.warmup, tally)
        finally:
            flying.cancel()
    except SessionEnded as exc:
        count_error(tally, index, exc)
    finally:
        if session is not None:
            count_protocol(tally, session.protocol)


def count_error(tally: Tally, index: int, end: SessionEnded) -> None:
    """Count a session that ended with an error (by its code); print the first of each kind,
    so that a refusal says why."""
    code = end.code.name if end.code is not None else "ENDED"
    if not tally.errors[code]:
        print(f"loadtest: session {index}: {end}", file=sys.stderr, flush=True)
    tally.errors[code] += 1


def count_protocol(tally: Tally, protocol) -> None:
    """Add what a session's :class:`~.protocol.SessionProtocol` counted over its streams."""
    tally.divergences += protocol.divergences
    tally.bad_frames += protocol.bad_frames
    tally.resumes += protocol.resumes
    tally.failovers += protocol.failovers


def choose_mesh(meshes: list, name: str | None):
    """The MeshInfo named ``name`` (None: the first) of ``meshes``; InputError naming those served."""
    names = [m.name for m in meshes]
    if name is not None and name not in names:
        raise InputError(f"the server has no mesh {name!r}; it serves {', '.join(names)}")
    return meshes[names.index(name)] if name else meshes[0]


def start_time(args) -> float:
    """``t0`` (perf_counter) of every session of every process: ``--start-at``, or after the time to open them all."""
    return getattr(args, "start_at", None) or time.perf_counter() + 0.5 + 0.02 * args.sessions


def connection_count(args, sessions: int) -> int:
    """Connections this process's ``sessions`` share: ``--connections``, else one a session (as viewers have,
    and a server of several processes spreads connections, not streams)."""
    return max(1, min(getattr(args, "connections", None) or sessions, sessions))


async def report_progress(tally: Tally, args, t0: float) -> None:
    """A progress line on stderr every second (the first process's)."""
    while True:
        await asyncio.sleep(1.0)
        lat = np.asarray(tally.latencies[-2000:]) * 1e3
        p50, p99 = (np.percentile(lat, [50, 99]) if len(lat) else (float("nan"),) * 2)
        print(f"loadtest: {time.perf_counter() - t0:5.1f}/{args.duration:.0f} s  frames {tally.frames}  "
              f"latency p50 {p50:.1f} ms p99 {p99:.1f} ms  divergences {tally.divergences}  "
              f"errors {sum(tally.errors.values())}", file=sys.stderr, flush=True)


async def fly(args, shard: tuple = (0, 1)) -> tuple:
    """Fly this process's share of the sessions: those whose index is
    ``shard[0]`` modulo ``shard[1]``. Returns (tally, mesh name, mesh faces,
    CPU seconds, wall seconds); ``t0`` is shared through ``args.start_at``."""
    with opstream.compiled_decoding(decoder(args) == "compiled"):    # compiled before the CPU clock starts
        return await _fly_share(args, shard)


async def _fly_share(args, shard: tuple) -> tuple:
    if transport(args) == "h2":
        from .h2load import fly_h2           # h2 only where it is used: the thin client imports none of it
        return await fly_h2(args, shard)
    token = args.token or os.environ.get("CAVECLOD_TOKEN")
    client = AsyncClient(args.target, token=token, tls_ca=args.tls_ca, cache_dir=args.cache_dir)
    tally = Tally()
    try:
        mesh = choose_mesh(await client.list_meshes(), args.mesh)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        t0 = start_time(args)
        progress = asyncio.ensure_future(report_progress(tally, args, t0)) if shard[0] == 0 else None
        mine = range(shard[0], args.sessions, shard[1])
        connections = connection_count(args, len(mine))
        clients = [client] + [AsyncClient(args.target, token=token, tls_ca=args.tls_ca, cache_dir=args.cache_dir)
                              for _ in range(connections - 1)]
        try:
            await asyncio.gather(*(_one(clients[k % connections], i, args, mesh, tally, t0)
                                   for k, i in enumerate(mine)))
        finally:
            if progress is not None:
                progress.cancel()
            for c in clients[1:]:
                await c.close()
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    finally:
        await client.close()
    return tally, mesh.name, mesh.faces, cpu, wall


def decoder(args) -> str:
    """The op-stream decoder ``args.decoder`` names: ``compiled`` (a numba kernel,
    :func:`caveclod.opstream.compiled_decoding`) or ``numpy``; ``auto`` is compiled
    where numba is installed. InputError for compiled asked for where numba is missing."""
    chosen = getattr(args, "decoder", "numpy")
    installed = importlib.util.find_spec("numba") is not None
    if chosen == "compiled" and not installed:
        raise InputError("--decoder compiled needs numba: pip install 'caveclod[build]' (or use --decoder numpy)")
    return "compiled" if chosen != "numpy" and installed else "numpy"


def transport(args) -> str:
    """The transport ``args.transport`` names: ``auto`` is h2 (:mod:`.h2wire`) where the hpack library
    is installed and the connection is plaintext, else grpc. InputError for h2 asked for where it cannot be."""
    chosen = getattr(args, "transport", "grpc")
    installed = importlib.util.find_spec("hpack") is not None
    if chosen == "auto":
        return "h2" if installed and not args.tls_ca else "grpc"
    if chosen == "h2" and not installed:
        raise InputError("--transport h2 needs the hpack library: pip install 'caveclod[loadtest]' (or use "
                         "--transport grpc)")
    if chosen == "h2" and args.tls_ca:
        raise InputError("--transport h2 speaks plaintext HTTP/2 only; use --transport grpc with --tls-ca")
    return chosen


def _fly_shards(args) -> tuple:
    """Run ``args.processes`` processes of ``caveclod loadtest --shard I/N``; their merged tally."""
    start_at = time.perf_counter() + 1.5 + 0.02 * args.sessions     # processes start, then open their sessions
    procs = []
    for i in range(args.processes):
        cmd = [sys.executable, "-m", "caveclod.cli", "loadtest", *_argv(args), "--shard", f"{i}/{args.processes}",
               "--start-at", repr(start_at)]
        procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True))
    tally, name, faces, cpu, wall = Tally(), None, 0, 0.0, 0.0
    for proc in procs:
        out, _ = proc.communicate(timeout=args.duration + 300)
        if proc.returncode not in (0, 1) or not out.strip():
            raise InputError(f"a loadtest process ended with status {proc.returncode}; its stderr says why")
        part = json.loads(out)
        tally.merge(part["tally"])
        name, faces = part["mesh"], part["mesh_faces"]
        cpu += part["cpu_seconds"]
        wall = max(wall, part["wall_seconds"])
    return tally, name, faces, cpu, wall


def _argv(args) -> list:
    """The options of ``args`` that a shard process runs with (everything but output and processes)."""
    out = []
    for name in ("target", "mesh", "sessions", "connections", "cameras", "duration", "warmup", "rate", "trajectory",
                 "tolerance", "width", "height", "fov", "token", "tls_ca", "cache_dir", "cache_vertices",
                 "cache_strategy", "cache_pq_fraction", "frame_encoding", "decoder", "vertex_encoding", "position_bits",
                 "transport"):
        value = getattr(args, name, None)
        if value is not None:
            out += ["--" + name.replace("_", "-"), str(value)]
    for flag in ("no_prune", "strict_bound"):       # switches: there, or not
        if getattr(args, flag, False):
            out.append("--" + flag.replace("_", "-"))
    return out


def report(args, tally: Tally, mesh: str, faces: int, cpu: float, wall: float) -> dict:
    """The figures of a finished load test."""
    lat = np.asarray(tally.latencies) * 1e3
    pct = {k: round(float(np.percentile(lat, q)), 2) if len(lat) else None
           for k, q in (("p50", 50), ("p95", 95), ("p99", 99))}
    pct["max"] = round(float(lat.max()), 2) if len(lat) else None
    cache = {}
    if args.cache_vertices is not None:
        activated = tally.cache_hits + tally.cache_inserts
        cache = {"cache_vertices": args.cache_vertices, "cache_strategy": args.cache_strategy or "lru",
                 "vertices_inserted": tally.vertices_inserted,
                 "vertex_bytes_per_frame": round(tally.vertex_bytes / tally.frames, 1) if tally.frames else None,
                 "cache_hit_rate": round(tally.cache_hits / activated, 4) if activated else None,
                 "cache_tolerance_px_max": tally.cache_tolerance_max}
    return {
        "target": args.target, "mesh": mesh, "mesh_faces": faces, "sessions": args.sessions,
        "cameras": args.cameras, "duration_s": args.duration, "warmup_s": args.warmup, "rate_hz": args.rate, "trajectory": args.trajectory,
        "viewport": [args.width, args.height], "fov_y": args.fov, "tolerance_px": args.tolerance,
        "prune": not getattr(args, "no_prune", False), "strict_bound": bool(getattr(args, "strict_bound", False)),
        "frame_encoding": getattr(args, "frame_encoding", "linked"),
        "vertex_encoding": getattr(args, "vertex_encoding", "packed"), "processes": getattr(args, "processes", 1),
        "transport": transport(args), "decoder": decoder(args),
        "connections": getattr(args, "connections", None) or args.sessions,
        "frames": tally.frames, "frames_per_second": round(tally.frames / args.duration, 1),
        "keyframes": tally.keyframes, "poses_sent": tally.poses_sent, "poses_timed": len(lat),
        "latency_ms": pct,
        "bytes_per_frame": round(tally.bytes / tally.frames, 1) if tally.frames else None,
        "bytes_per_changed_triangle": round(tally.delta_bytes / tally.delta_triangles, 2)
        if tally.delta_triangles else None,
        "bytes_per_changed_triangle_steady": round(tally.steady_bytes / tally.steady_triangles, 2)
        if tally.steady_triangles else None,
        "divergences": tally.divergences, "bad_frames": tally.bad_frames, "resumes": tally.resumes,
        "failovers": tally.failovers,
        "errors": dict(tally.errors), **cache,
        "client_cpu_seconds": round(cpu, 2), "client_cpu_cores": round(cpu / wall, 2),
        "client_cpu_ms_per_frame": round(1e3 * cpu / tally.frames, 3) if tally.frames else None,
        "latencies_ms": lat.round(3).tolist(),
    }


async def run(args) -> dict:
    """Run the load test of ``args`` (the ``caveclod loadtest`` options) in this process; returns the figures."""
    return report(args, *await fly(args))


def main(args) -> int:
    """``caveclod loadtest``: run, report, and exit 1 on divergences or errors."""
    for name in ("sessions", "cameras"):
        if getattr(args, name) < 1:
            print(f"caveclod: error: --{name} must be at least 1", file=sys.stderr)
            return 2
    # Written so that NaN fails (it passed "<= 0": a traceback, or "duration_s": NaN in the JSON).
    if not (0 < args.duration < math.inf and 0 < args.rate < math.inf and 0 <= args.warmup < math.inf):
        print("caveclod: error: --duration and --rate must be positive, --warmup at least 0, all finite",
              file=sys.stderr)
        return 2
    if args.cache_vertices is None and (args.cache_strategy is not None or args.cache_pq_fraction is not None):
        print("caveclod: error: --cache-strategy and --cache-pq-fraction need --cache-vertices N (slots per camera)",
              file=sys.stderr)
        return 2
    if getattr(args, "position_bits", None) is not None:
        try:
            check_position_bits(args.position_bits)
        except ValueError as exc:
            print(f"caveclod: error: --{str(exc).replace('_', '-')}", file=sys.stderr)
            return 2
    if args.cache_vertices is not None and args.cache_vertices < 1:
        print(f"caveclod: error: --cache-vertices must be at least 1 (slots per camera), got {args.cache_vertices}",
              file=sys.stderr)
        return 2
    try:
        transport(args)
        decoder(args)
    except InputError as exc:
        print(f"caveclod: error: {exc}", file=sys.stderr)
        return 2
    processes = getattr(args, "processes", 1)
    if processes < 1:
        print(f"caveclod: error: --processes must be at least 1, got {processes}", file=sys.stderr)
        return 2
    shard = getattr(args, "shard", None)
    try:
        if shard is not None:         # one process of several: print the raw tally for the parent to merge
            i, n = (int(v) for v in shard.split("/"))
            tally, mesh, faces, cpu, wall = asyncio.run(fly(args, (i, n)))
            print(json.dumps({"tally": tally.as_dict(), "mesh": mesh, "mesh_faces": faces, "cpu_seconds": cpu,
                              "wall_seconds": wall}))
            return 0
        if processes > 1:
            figures = report(args, *_fly_shards(args))
        else:
            figures = asyncio.run(run(args))
    except grpc.RpcError as exc:      # ListMeshes failed: no session could start
        print(f"caveclod: error: {args.target}: {exc.code().name}: {exc.details()}", file=sys.stderr)
        return 1
    latencies = figures["latencies_ms"] if args.samples else figures.pop("latencies_ms")
    if args.plot:
        plot_latency(latencies, figures, args.plot)
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key:<28} {value}")
    if not figures["frames"]:
        # Every session's first frame is its keyframe: none at all is a server that did not answer
        # (a run that counted 1,444 poses and no frame used to exit 0, as if measured), or one
        # that refused every session, whose errors are then named, not blamed on its silence.
        why = ("every session ended with an error (" + ", ".join(f"{n} {code}" for code, n in
                                                                 figures["errors"].items())
               + "; the first is said above)" if figures["errors"] else
               "the server did not answer; check its log and load")
        print(f"caveclod: error: {args.target}: no frame came in {args.duration:g} s ({figures['poses_sent']:,} "
              f"poses sent): {why}", file=sys.stderr)
        return 1
    return 1 if figures["divergences"] or figures["errors"] else 0


def draw_latency_cdf(ax, latencies_ms) -> None:
    """Draw the CDF of pose -> frame latencies (ms) on a matplotlib ``ax``, p50 and p99 marked."""
    lat = np.sort(np.asarray(latencies_ms))
    if len(lat):
        ax.plot(lat, np.arange(1, len(lat) + 1) / len(lat))
        for q in (50, 99):
            v = np.percentile(lat, q)
            ax.axvline(v, ls="--", lw=0.8, color="grey")
            ax.text(v, 0.05 + 0.1 * (q == 99), f" p{q} {v:.1f} ms", fontsize=8)
    ax.set_xlabel("pose -> frame latency (ms)")
    ax.set_ylabel("fraction of poses")
    ax.grid(alpha=0.3)


def plot_latency(latencies_ms: list, report: dict, path: str) -> None:
    """A CDF of pose -> frame latency, as a PNG (needs matplotlib: the ``bench`` extra)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    draw_latency_cdf(ax, latencies_ms)
    ax.set_title(f"{report['sessions']} sessions x {report['cameras']} camera(s) at {report['rate_hz']:g} Hz, "
                 f"{report['mesh_faces']:,} triangles", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
