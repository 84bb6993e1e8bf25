"""Which gRPC server model: measured, not guessed.

    python benchmarks/server_model.py [--sessions 24,40] [--duration 15] [--repeats 3]

Servers of the same sessions (caveclod.server.session and .registry:
the same refinement, the same encoding), differing only in their I/O:

* **aio**: what ``caveclod serve`` runs by default. grpc.aio on one event
  loop, which reads and writes every stream; frames are made on a pool of
  worker threads (quick ones on the loop itself).
* **h2**: ``caveclod serve --transport h2``: the same event loop, workers
  and handlers, with HTTP/2 framed by caveclod (caveclod.server.h2server)
  instead of gRPC's C core.
* **sync**: a grpc.server whose pool thread per stream is the session's
  worker: it waits for work, refines, encodes and writes; a reader thread
  per stream takes poses and acks. Kept here, not in the package, as the
  model measured against.
* **floor**: not a server of sessions but what gRPC alone costs for their
  traffic: a grpc.aio server with one coroutine per stream that answers
  each pose at once with a pre-serialized frame changing nothing (no
  refinement, no encoding, no bookkeeping). The aio server's CPU per frame
  less the floor's is what caveclod's own Python costs. **floor h2**: the
  same over caveclod's HTTP/2.

For each load level, the two run one after the other, ``--repeats`` times
interleaved (sync, aio, sync, aio, ...), so the drift of this shared machine
hits both; medians are reported. Each run is a ``caveclod loadtest``
process of N one-camera sessions at 30 Hz on the 1M-triangle terrain,
against a fresh server process. Writes ``benchmarks/results/server_model.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from service import RESULTS, capacity, mesh_path  # noqa: E402


def serve_sync(argv: list) -> int:
    """Serve like ``caveclod serve ARGS`` (a subset of its options), a thread per stream."""
    import grpc

    from caveclod import wire
    from caveclod.cli import _parser
    from caveclod.server import logs
    from caveclod.server.main import config_from_args
    from caveclod.server.meshes import Catalogue
    from caveclod.server.metrics import Metrics
    from caveclod.server.registry import Sessions
    from caveclod.server.service import SERVICE
    from caveclod.server.session import CLOSED, End, Refused
    from caveclod.v1 import caveclod_pb2 as pb

    args = _parser().parse_args(["serve", *argv])
    logs.configure(args.log_format)
    config = config_from_args(args)
    catalogue, metrics = Catalogue(config.meshes), Metrics()
    sessions = Sessions(config, catalogue, metrics, logs.event)

    def start(session, opened, resumed):
        served = session.served
        cached = opened.vertex_buffer_hash == served.mesh.vertex_buffer_hash
        yield wire.session_info(
            token=session.token, resumed=resumed, mesh=served.info, vertex_format=served.vertex_format,
            vertex_buffer_cached=cached, vertex_payload_crc32=served.payload_crc32,
            view_options=session.view_options, budgets=session.budgets, cameras=session.n_cameras,
            ack_window=session.ack_window, resume_ttl_s=config.resume_ttl, last_frame_seq=0, last_pose_seq=0,
            frame_encoding=session.frame_encoding).SerializeToString()
        if not cached:
            yield from (chunk.SerializeToString() for chunk in served.vertex_chunks())

    def session_rpc(requests, context):
        first = next(requests, None)
        if first is None or isinstance(first, wire.WireError) or first.WhichOneof("kind") != "open":
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, "the first message must be Open")
        try:
            session, generation, resumed = sessions.open(first.open)
        except Refused as r:
            context.abort(r.code, r.message)
        stopped = threading.Event()

        def wake():
            with session.cond:
                session.cond.notify_all()

        def on_done():
            stopped.set()
            wake()

        context.add_callback(on_done)

        def read():
            try:
                for msg in requests:
                    if isinstance(msg, wire.WireError):
                        raise Refused(grpc.StatusCode.INVALID_ARGUMENT, str(msg))
                    if not session.accept(msg, generation):
                        return
                session.finish(CLOSED, generation)
            except Refused as r:
                session.finish(End(r.code, r.message, True), generation)
            except grpc.RpcError:
                pass

        threading.Thread(target=read, daemon=True).start()
        end = End(grpc.StatusCode.CANCELLED, "the stream broke", False)
        try:
            yield from start(session, first.open, resumed)
            while True:
                due = session.poll(generation, stopped.is_set)
                if isinstance(due, End):
                    end = due
                    break
                if due > 0.0:
                    with session.cond:          # a pose, an ack or the end notifies cond
                        session.cond.wait(min(due, 1.0))
                    continue
                parts = session.make_frame(generation)
                if parts is not None:
                    metrics.frame_sent(sum(len(p) for p in parts))
                    yield from parts
        finally:
            sessions.stream_ended(session, generation, end)
        if end.code not in (grpc.StatusCode.OK, grpc.StatusCode.CANCELLED):
            context.abort(end.code, end.message)

    server = grpc.server(ThreadPoolExecutor(max_workers=config.max_sessions + 16),
                         options=[("grpc.max_receive_message_length", 64 * 1024)])
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE, {
        "Session": grpc.stream_stream_rpc_method_handler(
            session_rpc, request_deserializer=wire.parse_client_message, response_serializer=None),
        "ListMeshes": grpc.unary_unary_rpc_method_handler(
            lambda request, context: catalogue.listing(), request_deserializer=wire.parse_list_request,
            response_serializer=pb.ListMeshesResponse.SerializeToString)}),))
    port = server.add_insecure_port(f"{config.host}:{config.port}")
    server.start()
    print(f"listening on {config.host}:{port}", flush=True)
    logs.event("server.metrics", port=metrics.serve(config.metrics_host, config.metrics_port))
    from caveclod.refine.view import View
    for served in catalogue.meshes.values():          # the kernels, as LodServer's warm-up does
        lo, hi = served.info.bounds_min, served.info.bounds_max
        served.mesh.new_camera().update(View(eye=(hi.x, hi.y, hi.z + 1.0), target=(lo.x, lo.y, lo.z)))
        served.payload_crc32
    sessions.ready.set()
    logs.event("server.ready")
    server.wait_for_termination()
    return 0


def serve_floor(argv: list) -> int:
    """gRPC's own cost for the same traffic: a grpc.aio server that answers each pose at once
    with a pre-serialized frame that changes nothing (no refinement, no encoding, one coroutine
    per stream); SessionInfo and the vertex buffer as ``caveclod serve`` sends them."""
    import asyncio
    import os

    import grpc
    import grpc.aio

    from caveclod import frames, wire
    from caveclod.cli import _parser
    from caveclod.server import logs
    from caveclod.server.main import config_from_args
    from caveclod.server.meshes import Catalogue
    from caveclod.server.metrics import Metrics
    from caveclod.server.service import SERVICE
    from caveclod.v1 import caveclod_pb2 as pb

    args = _parser().parse_args(["serve", *argv])
    logs.configure(args.log_format)
    config = config_from_args(args)
    catalogue, metrics = Catalogue(config.meshes), Metrics()
    served = next(iter(catalogue.meshes.values()))
    view = {"fov_y": 60.0, "width": 1280, "height": 720, "tolerance_px": 1.0, "cull": True, "backface": False}

    async def session(requests, context):
        first = await requests.__anext__()
        cached = first.open.vertex_buffer_hash == served.mesh.vertex_buffer_hash
        await context.write(wire.session_info(
            token=os.urandom(8).hex(), resumed=False, mesh=served.info, vertex_format=served.vertex_format,
            vertex_buffer_cached=cached, vertex_payload_crc32=served.payload_crc32, view_options=view,
            budgets=(None, None), cameras=1, ack_window=config.ack_window, resume_ttl_s=config.resume_ttl,
            last_frame_seq=0, last_pose_seq=0, frame_encoding=pb.FRAME_ENCODING_OPS).SerializeToString())
        if not cached:
            for chunk in served.vertex_chunks():
                await context.write(chunk.SerializeToString())
        seq = 0
        async for msg in requests:
            kind = msg.WhichOneof("kind")
            if kind == "pose":
                seq += 1
                part, = frames.frame_parts(seq, msg.pose.pose_seq, 0, [frames.CameraFrameData(0, msg.pose.pose_seq)])
                metrics.frame_sent(len(part))
                await context.write(part)
            elif kind == "close":
                return

    async def list_meshes(request, context):
        return catalogue.listing()

    async def run() -> None:
        if config.transport == "h2":
            from caveclod.server.h2server import H2Server
            server = H2Server(max_receive=64 * 1024)
        else:
            server = grpc.aio.server(options=[("grpc.max_receive_message_length", 64 * 1024)])
        server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE, {
            "Session": grpc.stream_stream_rpc_method_handler(
                session, request_deserializer=pb.ClientMessage.FromString, response_serializer=None),
            "ListMeshes": grpc.unary_unary_rpc_method_handler(
                list_meshes, request_deserializer=pb.ListMeshesRequest.FromString,
                response_serializer=pb.ListMeshesResponse.SerializeToString)}),))
        port = server.add_insecure_port(f"{config.host}:{config.port}")
        await server.start()
        print(f"listening on {config.host}:{port}", flush=True)
        if config.metrics_port is not None:
            logs.event("server.metrics", port=metrics.serve(config.metrics_host, config.metrics_port))
        served.payload_crc32
        logs.event("server.ready")
        await server.wait_for_termination()

    asyncio.run(run())
    return 0


def models(sync: list, floor: list) -> tuple:
    """(name, server command or None for caveclod serve, serve --transport) of each model measured."""
    return (("aio", None, "grpc"), ("h2", None, "h2"), ("sync", sync, "grpc"), ("floor", floor, "grpc"),
            ("floor h2", floor, "h2"))


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--serve-sync":
        return serve_sync(sys.argv[2:])
    if len(sys.argv) > 1 and sys.argv[1] == "--serve-floor":
        return serve_floor(sys.argv[2:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=708)
    ap.add_argument("--sessions", default="24,40", help="load levels, comma-separated")
    ap.add_argument("--duration", type=float, default=15.0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    mesh = mesh_path(args.size)
    sync = [sys.executable, str(Path(__file__).resolve()), "--serve-sync"]
    floor = [sys.executable, str(Path(__file__).resolve()), "--serve-floor"]
    runs = []
    for repeat in range(args.repeats):
        for n in (int(x) for x in args.sessions.split(",")):
            for model, command, transport in models(sync, floor):
                r = capacity(mesh, n, args.duration, command=command, server_transport=transport)
                r.pop("latencies_ms")
                r.update(model=model, repeat=repeat)
                runs.append(r)
                print(f"{model:4s} {n:3d} sessions: p50 {r['latency_ms']['p50']} p99 {r['latency_ms']['p99']} ms  "
                      f"{r['frames_per_second']} frames/s  server cpu {r['server_cpu_cores']} "
                      f"= {r['server_cpu_ms_per_frame']} ms/frame, others {r['other_cpu_cores']} "
                      f"(refine {r['server_refine_cpu_cores']})  loadtest cpu {r['client_cpu_cores']}  "
                      f"errors {r['errors']}", file=sys.stderr, flush=True)
    summary = {}
    for model, _, _ in models(sync, floor):
        for n in sorted({r["sessions"] for r in runs}):
            mine = [r for r in runs if r["model"] == model and r["sessions"] == n]
            med = lambda f: round(statistics.median(f(r) for r in mine), 2)      # noqa: E731
            summary[f"{model} {n}"] = {
                "p50_ms": med(lambda r: r["latency_ms"]["p50"]), "p99_ms": med(lambda r: r["latency_ms"]["p99"]),
                "frames_per_second": med(lambda r: r["frames_per_second"]),
                "server_cpu_cores": med(lambda r: r["server_cpu_cores"]),
                "server_cpu_ms_per_frame": med(lambda r: r["server_cpu_ms_per_frame"]),
                "other_cpu_cores": med(lambda r: r["other_cpu_cores"]),
                "server_refine_cpu_cores": med(lambda r: r["server_refine_cpu_cores"]),
                "loadtest_cpu_cores": med(lambda r: r["client_cpu_cores"]), "runs": len(mine)}
    for key, row in summary.items():
        print(key, row, file=sys.stderr)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "server_model.json").write_text(json.dumps({"summary": summary, "runs": runs}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
