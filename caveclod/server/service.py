"""The caveclod.v1.Lod servicer: gRPC streams in, Session calls out.

Thin by design: the rules live in :mod:`.session` and :mod:`.registry`, the
encoding in :mod:`caveclod.wire`. A Session stream runs on one thread of the
server's pool (the session's worker: it refines and writes) plus a reader
thread of its own, so that poses and acks arrive while a frame is made.
"""

from __future__ import annotations

import threading

import grpc

from .. import wire
from ..v1 import caveclod_pb2 as pb
from . import logs
from .session import CLOSED, End, Refused

SERVICE = "caveclod.v1.Lod"
HALF_CLOSE_SECONDS = 0.25


class LodService:
    """Session and ListMeshes over the server's Sessions and Catalogue."""

    def __init__(self, sessions, catalogue, metrics):
        self.sessions, self.catalogue, self.metrics = sessions, catalogue, metrics

    def ListMeshes(self, request, context):
        if isinstance(request, wire.WireError):
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(request))
        if self.sessions.draining:
            context.abort(grpc.StatusCode.UNAVAILABLE, "the server is shutting down; ask another replica")
        return self.catalogue.listing()

    def Session(self, requests, context):
        first = next(requests, None)
        if first is None:
            return
        if isinstance(first, wire.WireError):
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(first))
        if first.WhichOneof("kind") != "open":
            context.abort(grpc.StatusCode.INVALID_ARGUMENT,
                          f"the first message must be Open, got {first.WhichOneof('kind') or 'an empty message'}")
        try:
            session, generation, resumed = self.sessions.open(first.open)
        except Refused as r:
            logs.event("session.refused", code=r.code.name, message=r.message, peer=context.peer())
            context.abort(r.code, r.message)
        logs.event("session.resumed" if resumed else "session.opened", **session.describe(), peer=context.peer())

        stopped = threading.Event()

        def on_done():
            stopped.set()
            with session.cond:
                session.cond.notify_all()

        context.add_callback(on_done)
        threading.Thread(target=_read, args=(requests, stopped, session, generation), daemon=True,
                         name=f"reader-{session.token[:8]}").start()
        end = End(grpc.StatusCode.CANCELLED, "the stream broke", False)
        try:
            yield from self._start(session, first.open, resumed)
            while True:
                out = session.next_frame(generation, stopped.is_set)
                if isinstance(out, End):
                    end = out
                    break
                self.metrics.frame_sent(sum(part.ByteSize() for part in out))   # counted as handed to gRPC
                yield from out
        finally:
            self.sessions.stream_ended(session, generation, end)
        if end.code not in (grpc.StatusCode.OK, grpc.StatusCode.CANCELLED):
            context.abort(end.code, end.message)

    def _start(self, session, opened: pb.Open, resumed: bool):
        """SessionInfo, then the vertex chunks unless the client holds the buffer."""
        served = session.served
        cached = opened.vertex_buffer_hash == served.mesh.vertex_buffer_hash
        info = wire.session_info(
            token=session.token, resumed=resumed, mesh=served.info, vertex_format=served.vertex_format,
            vertex_buffer_cached=cached, vertex_payload_crc32=served.payload_crc32,
            view_options=session.view_options, budgets=session.budgets, cameras=session.n_cameras,
            ack_window=session.ack_window, resume_ttl_s=self.sessions.config.resume_ttl,
            last_frame_seq=session.frame_seq if resumed else 0,
            last_pose_seq=session.last_pose_seq if resumed else 0)
        self.metrics.bytes_out(info.ByteSize())
        yield info
        if not cached:
            for chunk in served.vertex_chunks():
                self.metrics.bytes_out(chunk.ByteSize())
                yield chunk


def _read(requests, stopped: threading.Event, session, generation: int) -> None:
    """The stream's reader: hands each client message to the session.

    A bad message ends the stream (and the session) with the Refused code;
    a half-close is a Close; a broken stream just stops the loop (the
    writer learns of it from the RPC's done callback, which sets
    ``stopped``). gRPC may end the request iterator of a broken call just
    as it ends one that was half-closed, and report the cancellation a
    moment later: a half-close is one that no cancellation follows within
    HALF_CLOSE_SECONDS.
    """
    try:
        for msg in requests:
            if isinstance(msg, wire.WireError):
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT, str(msg))
            if msg.WhichOneof("kind") == "keyframe_request":
                logs.event("keyframe.requested", **session.describe(),
                           reason=pb.KeyframeReason.Name(msg.keyframe_request.reason)
                           if msg.keyframe_request.reason in pb.KeyframeReason.values() else msg.keyframe_request.reason,
                           detail=msg.keyframe_request.detail[:200])
            if not session.accept(msg, generation):
                return
        if not stopped.wait(HALF_CLOSE_SECONDS):
            session.finish(CLOSED, generation)
    except Refused as r:
        session.finish(End(r.code, r.message, True), generation)
    except grpc.RpcError:
        pass                               # the stream broke or was cancelled


def add_to_server(service: LodService, server: grpc.Server) -> None:
    """Register the Lod methods, with request deserializers that never raise.

    gRPC turns a deserializer's exception into INTERNAL; ours return a
    WireError instead, which the handlers end with INVALID_ARGUMENT.
    """
    handlers = {
        "Session": grpc.stream_stream_rpc_method_handler(
            service.Session, request_deserializer=wire.parse_client_message,
            response_serializer=pb.ServerMessage.SerializeToString),
        "ListMeshes": grpc.unary_unary_rpc_method_handler(
            service.ListMeshes, request_deserializer=wire.parse_list_request,
            response_serializer=pb.ListMeshesResponse.SerializeToString),
    }
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE, handlers),))
