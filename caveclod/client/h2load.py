"""``caveclod loadtest --transport h2`` (the default where h2 is installed): the flights over :mod:`.h2session`.

The same sessions, paths, rates, checks and figures as the grpc.aio
flights in :mod:`.loadtest`, at a fraction of the CPU: no coroutine per
session, no await per message, and one socket write per connection for
every pose due within ``POSE_BATCH_SECONDS`` of each other (the sessions
keep their own phases over the period; a pose leaves at most that much
later than its tick, and its latency is timed from when it leaves) and for
every ack a read produced.
"""

from __future__ import annotations

import asyncio
import os
import time
from functools import partial

import grpc

from ..paths import pose as path_pose
from .cache import VertexBufferCache
from .h2session import H2Session, H2Target, list_meshes
from .h2wire import CallEnded
from .loadtest import (TAIL_SECONDS, Tally, choose_mesh, connection_count, count_error, count_frame, count_protocol,
                       report_progress, start_time)
from .protocol import SessionProtocol
from .session import SessionEnded, cache_mode, metadata, refine_options

POSE_BATCH_SECONDS = 0.004
CLOSE_SECONDS = 5.0          # after Close: how long the streams may take to end


async def fly_h2(args, shard: tuple) -> tuple:
    """Fly this process's share of the sessions (index ``shard[0]`` modulo ``shard[1]``) over h2.

    Returns (tally, mesh name, mesh faces, CPU seconds, wall seconds), as
    :func:`caveclod.client.loadtest.fly`.
    """
    token = args.token or os.environ.get("CAVECLOD_TOKEN")
    md = metadata(token)
    mine = list(range(shard[0], args.sessions, shard[1]))
    n_conn = connection_count(args, len(mine))
    targets = [H2Target.parse(args.target) for _ in range(n_conn)]
    cache = None if args.cache_dir is False else VertexBufferCache(args.cache_dir)
    loop = asyncio.get_running_loop()
    tally = Tally()
    shown = None
    try:
        try:
            meshes = await list_meshes(targets[0], md)
        except CallEnded as exc:         # as grpc.aio reports it, so that the caller says it alike
            raise grpc.aio.AioRpcError(exc.code, grpc.aio.Metadata(), grpc.aio.Metadata(), exc.details) from None
        mesh = choose_mesh(meshes, args.mesh)
        lo = (mesh.bounds_min.x, mesh.bounds_min.y, mesh.bounds_min.z)
        hi = (mesh.bounds_max.x, mesh.bounds_max.y, mesh.bounds_max.z)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        t0 = start_time(args)
        timed_from = t0 + args.warmup
        shown = asyncio.ensure_future(report_progress(tally, args, t0)) if shard[0] == 0 else None

        def frame(update):
            count_frame(tally, update, time.perf_counter() >= timed_from)

        def ended(index: int, end: SessionEnded) -> None:
            if end.code is not None:         # code None: our Close, answered
                count_error(tally, index, end)

        options = refine_options(args.width, args.height, args.fov, args.tolerance, None, None, None, None,
                                 False if getattr(args, "no_prune", False) else None,
                                 True if getattr(args, "strict_bound", False) else None)
        cached = cache_mode(args.cache_vertices, args.cache_strategy, args.cache_pq_fraction)
        sessions = []
        for k, index in enumerate(mine):
            protocol = SessionProtocol(mesh.name, args.cameras, options, cache=cache, cache_mode=cached,
                                       frame_encoding=getattr(args, "frame_encoding", "linked"),
                                       vertex_encoding=getattr(args, "vertex_encoding", "packed"),
                                       position_bits=getattr(args, "position_bits", None))
            if cache is not None and cached is None:
                protocol.offer_vertex_buffer(mesh.vertex_buffer_hash, mesh.content_hash)
            # Connections hold runs of neighbouring phases, so that the poses a
            # connection sends within a batch share its writes.
            sessions.append(H2Session(targets[k * n_conn // len(mine)], protocol, md, on_frame=frame,
                                      on_end=partial(ended, index)))
        # Each session flies from its first tick after its vertex buffer is
        # ready (send() skips it until then), as the grpc.aio flights do: a
        # server slow to open some does not hold back the others.
        await asyncio.gather(*(s.open() for s in sessions))

        # Poses: each session keeps the phase of the grpc.aio flights (index /
        # sessions of a period); those due within a batch leave together, at
        # the last one's time.
        period = 1.0 / args.rate
        groups: dict[int, list] = {}
        for session, index in zip(sessions, mine):
            phase = index / max(args.sessions, 1) * period
            groups.setdefault(int(phase / POSE_BATCH_SECONDS), []).append((session, index, phase))
        offset = loop.time() - time.perf_counter()          # perf_counter -> the loop's clock

        def send(members: list, at: float, tick: float) -> None:
            """Send the poses of ``members`` for period ``tick`` (seconds from t0); ``at``: the group's phase."""
            late = time.perf_counter() - (t0 + at + tick)
            if late > period:                                # a stall: skip the missed ticks, no burst
                tick += (late // period) * period
            touched = set()
            for session, index, phase in members:
                if tick + phase >= args.duration or session.over or session.closing or not session.ready.done():
                    continue
                for c in range(args.cameras):
                    eye, target, up = path_pose(args.trajectory, lo, hi, index * args.cameras + c, tick + phase)
                    session.send_pose(c, eye, target, up)
                    tally.poses_sent += 1
                touched.add(session.target)
            for target in touched:
                target.flush()
            if tick + period + members[0][2] < args.duration:
                loop.call_at(offset + t0 + at + tick + period, send, members, at, tick + period)

        for members in groups.values():
            at = max(phase for _, _, phase in members)
            loop.call_at(offset + t0 + at, send, members, at, 0.0)

        end = t0 + args.duration + TAIL_SECONDS
        while time.perf_counter() < end and not all(s.over for s in sessions):    # all refused: no wait
            await asyncio.sleep(min(0.1, max(end - time.perf_counter(), 0.0)))
        for index, session in zip(mine, sessions):
            if not session.ready.done():          # never opened: as the grpc.aio flights' open timeout
                ended(index, SessionEnded(grpc.StatusCode.DEADLINE_EXCEEDED,
                                          "no SessionInfo and vertex buffer before the load test ended"))
            session.begin_close("loadtest done")
        for target in targets:
            target.flush()
        deadline = time.perf_counter() + CLOSE_SECONDS
        while any(not s.over for s in sessions) and time.perf_counter() < deadline:
            await asyncio.sleep(0.05)
        for session in sessions:
            if not session.over:
                session.cancel()
            count_protocol(tally, session.protocol)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    finally:
        if shown is not None:
            shown.cancel()
        for target in targets:
            target.close()
    return tally, mesh.name, mesh.faces, cpu, wall

