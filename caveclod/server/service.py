"""The caveclod.v1.Lod servicer (grpc.aio): gRPC streams in, Session calls out.

Thin by design: the rules live in :mod:`.session` and :mod:`.registry`, the
encoding in :mod:`caveclod.wire`. Every stream is two coroutines on the
server's event loop: a reader that hands each client message to its
Session, and a writer that waits until the Session says a frame is due and
has it made on a worker thread (refinement and encoding; the kernels
release the GIL, so sessions refine on every core). A frame whose session's
recent frames each took under ``session.CHEAP_SECONDS`` of CPU is made on
the loop itself: the hand-off to a worker (a future, two thread switches,
the GIL changing hands) cost more than such a frame. Why grpc.aio and not
a thread per stream: see the README's "How the server works".
"""

from __future__ import annotations

import asyncio
import threading

import grpc

from .. import wire
from ..v1 import caveclod_pb2 as pb
from . import logs
from .session import CLOSED, End, Refused

SERVICE = "caveclod.v1.Lod"
HALF_CLOSE_SECONDS = 0.25


class LodService:
    """Session and ListMeshes over the server's Sessions and Catalogue.

    ``workers`` runs frames (refinement and encoding) off the event loop.
    """

    def __init__(self, sessions, catalogue, metrics, workers):
        self.sessions, self.catalogue, self.metrics, self.workers = sessions, catalogue, metrics, workers

    async def ListMeshes(self, request, context):
        if isinstance(request, wire.WireError):
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(request))
        if self.sessions.draining:
            await context.abort(grpc.StatusCode.UNAVAILABLE, "the server is shutting down; ask another replica")
        return self.catalogue.listing()

    async def Session(self, requests, context):
        try:
            first = await requests.__anext__()
        except StopAsyncIteration:
            return
        if isinstance(first, wire.WireError):
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(first))
        if first.WhichOneof("kind") != "open":
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT,
                                f"the first message must be Open, got {first.WhichOneof('kind') or 'an empty message'}")
        try:
            # Off the loop: an Open waits for the kernels while the server warms up.
            session, generation, resumed = await asyncio.to_thread(self.sessions.open, first.open)
        except Refused as r:
            logs.event("session.refused", code=r.code.name, message=r.message, peer=context.peer())
            await context.abort(r.code, r.message)
        logs.event("session.resumed" if resumed else "session.opened", **session.describe(), peer=context.peer())

        loop = asyncio.get_running_loop()
        loop_thread = threading.get_ident()
        wake = asyncio.Event()
        stopped = threading.Event()

        def waker():
            # The reader runs on the loop: set the event directly there, and
            # save the self-pipe write that waking the loop from a thread costs.
            if threading.get_ident() == loop_thread:
                wake.set()
            else:
                loop.call_soon_threadsafe(wake.set)

        def on_done(_):
            stopped.set()
            waker()

        context.add_done_callback(on_done)
        with session.cond:
            session.wakers.append(waker)
        reader = asyncio.ensure_future(_read(requests, stopped, session, generation))
        end = End(grpc.StatusCode.CANCELLED, "the stream broke", False)
        try:
            for msg in self._start(session, first.open, resumed):
                await context.write(msg)
            while True:
                wake.clear()                      # before polling: a change after it sets the event again
                due = session.poll(generation, stopped.is_set)
                if isinstance(due, End):
                    end = due
                    break
                if due == float("inf"):
                    await wake.wait()             # a waker (pose, ack, end) or the done callback
                    continue
                if due > 0.0:                     # a convergence update is due then
                    try:
                        await asyncio.wait_for(wake.wait(), due)
                    except asyncio.TimeoutError:
                        pass
                    continue
                if session.cheap:
                    # Handing a frame to a worker costs more than a converged
                    # camera's update: make cheap frames here (module doc).
                    parts = session.make_frame(generation)
                else:
                    parts = await loop.run_in_executor(self.workers, session.make_frame, generation)
                if parts is None:
                    continue
                self.metrics.frame_sent(sum(len(part) for part in parts))   # counted as handed to gRPC
                for part in parts:
                    await context.write(part)
        finally:
            with session.cond:
                session.wakers.remove(waker)
            reader.cancel()
            self.sessions.stream_ended(session, generation, end)
        if end.code not in (grpc.StatusCode.OK, grpc.StatusCode.CANCELLED):
            await context.abort(end.code, end.message)

    def _start(self, session, opened: pb.Open, resumed: bool):
        """SessionInfo, then the vertex chunks unless the client holds the buffer (serialized)."""
        served = session.served
        # In cache mode the client holds slots, never the buffer: no chunks.
        cached = session.cache is None and opened.vertex_buffer_hash == served.mesh.vertex_buffer_hash
        info = wire.session_info(
            token=session.token, resumed=resumed, mesh=served.info, vertex_format=served.vertex_format,
            vertex_buffer_cached=cached, vertex_payload_crc32=served.payload_crc32,
            view_options=session.view_options, budgets=session.budgets, cameras=session.n_cameras,
            ack_window=session.ack_window, resume_ttl_s=self.sessions.config.resume_ttl,
            last_frame_seq=session.frame_seq if resumed else 0,
            last_pose_seq=session.last_pose_seq if resumed else 0, cache=session.cache,
            frame_encoding=session.frame_encoding)
        data = info.SerializeToString()
        self.metrics.bytes_out(len(data))
        yield data
        if not cached and session.cache is None:
            for chunk in served.vertex_chunks():
                data = chunk.SerializeToString()
                self.metrics.bytes_out(len(data))
                yield data


async def _read(requests, stopped: threading.Event, session, generation: int) -> None:
    """The stream's reader: hands each client message to the session.

    A bad message ends the stream (and the session) with the Refused code;
    a half-close is a Close; a broken stream just stops the loop (the
    writer learns of it from the RPC's done callback, which sets
    ``stopped``). The request stream of a broken call may end just as a
    half-closed one does, with the cancellation reported a moment later: a
    half-close is one that no cancellation follows within
    HALF_CLOSE_SECONDS.
    """
    try:
        async for msg in requests:
            if isinstance(msg, wire.WireError):
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT, str(msg))
            if msg.WhichOneof("kind") == "keyframe_request":
                logs.event("keyframe.requested", **session.describe(),
                           reason=pb.KeyframeReason.Name(msg.keyframe_request.reason)
                           if msg.keyframe_request.reason in pb.KeyframeReason.values() else msg.keyframe_request.reason,
                           detail=msg.keyframe_request.detail[:200])
            if not session.accept(msg, generation):
                return
        await asyncio.sleep(HALF_CLOSE_SECONDS)
        if not stopped.is_set():
            session.finish(CLOSED, generation)
    except Refused as r:
        session.finish(End(r.code, r.message, True), generation)
    except (grpc.RpcError, asyncio.CancelledError):
        pass                               # the stream broke or was cancelled


def add_to_server(service: LodService, server) -> None:
    """Register the Lod methods, with request deserializers that never raise.

    gRPC turns a deserializer's exception into INTERNAL; ours return a
    WireError instead, which the handlers end with INVALID_ARGUMENT.
    """
    handlers = {
        "Session": grpc.stream_stream_rpc_method_handler(
            # Replies are serialized ServerMessages already (frames by caveclod.frames).
            service.Session, request_deserializer=wire.parse_client_message, response_serializer=None),
        "ListMeshes": grpc.unary_unary_rpc_method_handler(
            service.ListMeshes, request_deserializer=wire.parse_list_request,
            response_serializer=pb.ListMeshesResponse.SerializeToString),
    }
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE, handlers),))
