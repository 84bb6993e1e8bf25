"""The caveclod.v1.Lod servicer (grpc.aio): gRPC streams in, Session calls out.

Thin by design: the rules live in :mod:`.session` and :mod:`.registry`, the
encoding in :mod:`caveclod.wire` and :mod:`caveclod.frames`. Every stream is
two coroutines on the server's event loop (:class:`_Stream`): a reader that
hands each client message to its Session and, when the session's recent
frames each took under ``session.CHEAP_SECONDS`` of CPU, makes and writes
the frame that is due right there; and a writer that wakes only for what
the reader does not see (convergence timers, ends) and for costly frames,
which it has made on a worker thread (the kernels release the GIL, so
sessions refine on every core). docs/frame-path.md says why; docs/server.md
why grpc.aio and not a thread per stream.
"""

from __future__ import annotations

import asyncio
import os
import threading

import grpc

from .. import vertexpack, wire
from ..errors import MeshDamagedError
from ..v1 import caveclod_pb2 as pb
from . import logs
from .registry import damaged_message
from .session import CLOSED, End, Refused

SERVICE = "caveclod.v1.Lod"
HALF_CLOSE_SECONDS = 0.25


class StreamBroke(Exception):
    """A write to a stream whose peer has gone: the stream broke, as a grpc.RpcError says."""


async def send(context, message) -> None:
    """``context.write(message)``, a failure that is not gRPC's own error raised as StreamBroke.

    When the client dies while a frame is being written, grpc.aio's write can raise its
    ExecuteBatchError (a cygrpc error, not a grpc.RpcError); caught as a server bug, it ended
    the session as INTERNAL ("session.error" logged, the session discarded) where a broken
    stream leaves it resumable (6 of 96 clients killed mid-frame, in a sweep of SIGKILLed
    clients). What is written is a message already made: its write failing is the stream's
    end, never a fault in making frames."""
    try:
        await context.write(message)
    except (grpc.RpcError, asyncio.CancelledError):
        raise
    except Exception as exc:        # noqa: BLE001 - whatever grpc.aio raises for a dead peer
        raise StreamBroke(repr(exc)[:200]) from exc


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
        # Off the loop: an Open waits for the kernels while the server warms up.
        opening = asyncio.ensure_future(asyncio.to_thread(self._open, first.open))
        try:
            session, generation, resumed, packed = await asyncio.shield(opening)
        except asyncio.CancelledError:
            # The client left (a deadline, a cancel) while its Open waited: the
            # open still finishes in its thread, and must not hold a session
            # no stream will ever end.
            opening.add_done_callback(self._abandoned)
            raise
        except Refused as r:
            logs.event("session.refused", code=r.code.name, message=r.message, peer=context.peer())
            await context.abort(r.code, r.message)
        except Exception as exc:              # noqa: BLE001 - a server bug: INTERNAL, not grpc.aio's UNKNOWN
            logs.event("session.error", error=repr(exc)[:300], peer=context.peer())
            await context.abort(grpc.StatusCode.INTERNAL, f"server error while opening the session: {exc!r}"[:300])
        logs.event("session.resumed" if resumed else "session.opened", **session.describe(), peer=context.peer(),
                   pid=os.getpid())           # which process holds it, under --processes

        stream = _Stream(session, generation, context, self.workers, self.metrics)
        context.add_done_callback(stream.done_callback())
        with session.cond:
            session.wakers.append(stream.waker)
        reader = asyncio.ensure_future(_read(requests, stream))
        end = End(grpc.StatusCode.CANCELLED, "the stream broke", False)
        try:
            for msg in self._start(session, first.open, resumed, packed):
                await send(context, msg)
            end = await stream.write_frames()
        except StreamBroke:
            pass                              # ``end`` stays "the stream broke": the session is resumable
        finally:
            with session.cond:
                session.wakers.remove(stream.waker)
            stream.close()
            reader.cancel()
            self.sessions.stream_ended(session, generation, end)
        if end.code not in (grpc.StatusCode.OK, grpc.StatusCode.CANCELLED):
            await context.abort(end.code, end.message)

    def _open(self, opened: pb.Open) -> tuple:
        """(session, generation, resumed, packed) of an Open, in a thread: ``packed`` is
        ServedMesh.packed's (Packed, VertexPacking, VertexFormat) when the buffer travels packed,
        else None (packing takes about 0.8 s per million vertices, once per mesh and variant)."""
        session, generation, resumed = self.sessions.open(opened)
        bits = vertexpack.requested_bits(opened)       # None in cache mode; its range checked by open
        try:
            packed = None if bits is None or session.cache is not None else \
                session.served.packed(bits, opened.morph_targets)
        except BaseException:
            self.sessions.stream_ended(session, generation, End(grpc.StatusCode.INTERNAL,
                                                                "packing the vertex buffer failed", not resumed))
            raise
        return session, generation, resumed, packed

    def _abandoned(self, opening: asyncio.Future) -> None:
        """An Open whose stream was gone before it finished: end what it opened (a new session
        whose token no client got is dropped; a resumed one stays resumable)."""
        if opening.cancelled() or opening.exception() is not None:
            return
        session, generation, resumed, _ = opening.result()
        self.sessions.stream_ended(session, generation, End(grpc.StatusCode.CANCELLED,
                                                            "the client left before its session opened", not resumed))
        logs.event("session.abandoned", **session.describe(), resumed=resumed)

    def _start(self, session, opened: pb.Open, resumed: bool, packed: tuple | None):
        """SessionInfo, then the vertex chunks unless the client holds the buffer (serialized).

        ``packed``: (Packed, VertexPacking, VertexFormat) when the buffer travels packed."""
        served = session.served
        # In cache mode the client holds slots, never the buffer: no chunks.
        key = served.mesh.vertex_buffer_hash if packed is None else packed[1].vertex_buffer_hash
        cached = session.cache is None and opened.vertex_buffer_hash == key
        info = wire.session_info(
            token=session.token, resumed=resumed, mesh=served.info,
            vertex_format=served.vertex_format if packed is None else packed[2],
            vertex_buffer_cached=cached,
            vertex_payload_crc32=served.payload_crc32 if packed is None else packed[0].decoded_crc32,
            view_options=session.view_options, budgets=session.budgets, cameras=session.n_cameras,
            ack_window=session.ack_window, resume_ttl_s=self.sessions.config.resume_ttl,
            last_frame_seq=session.frame_seq if resumed else 0,
            last_pose_seq=session.last_pose_seq if resumed else 0, cache=session.cache,
            frame_encoding=session.frame_encoding, strict_bound=session.strict_bound)
        if packed is not None:
            info.session_info.vertex_packing.CopyFrom(packed[1])
        data = info.SerializeToString()
        self.metrics.bytes_out(len(data))
        yield data
        if not cached and session.cache is None:
            chunks = served.vertex_chunks() if packed is None else \
                served.packed_chunks(packed[1].position_bits, packed[0].packing.has_morph)
            for chunk in chunks:
                data = chunk.SerializeToString()
                self.metrics.bytes_out(len(data))
                yield data


class _Stream:
    """One Session stream's frame making: who makes the next frame, and when.

    Two coroutines share it. The reader (:func:`_read`) hands each client
    message to the session and then, when the session's frames are cheap
    (:attr:`.session.Session.cheap`: a converged or slowly moving camera),
    makes and writes the frames that are due itself, at once: a pose's
    frame then costs no wake-up of another task, no future and no thread.
    The writer (:meth:`write_frames`, the RPC's own coroutine) sleeps until
    woken by what the reader does not see: a convergence update coming due
    (a timer), the session ended from elsewhere (drain, a resume on another
    stream, the RPC's end), or a frame that is not cheap, which it makes on
    a worker thread while the reader goes on taking poses (latest pose
    wins). ``busy`` says one of the two is making or writing a frame; the
    other then only sets ``again``, and the busy one polls once more before
    it stops. Frames are never written by both at once.
    """

    def __init__(self, session, generation: int, context, workers, metrics):
        self.session, self.generation, self.context = session, generation, context
        self.workers, self.metrics = workers, metrics
        self.loop = asyncio.get_running_loop()
        self.loop_thread = threading.get_ident()
        self.wake = asyncio.Event()
        self.stopped = threading.Event()
        self.busy = self.again = False
        self.timer: asyncio.TimerHandle | None = None

    def waker(self) -> None:
        """Wake the writer (from any thread: the loop's sets the event directly, saving the self-pipe write)."""
        if threading.get_ident() == self.loop_thread:
            self.wake.set()
        else:
            self.loop.call_soon_threadsafe(self.wake.set)

    def done_callback(self):
        """The RPC's done callback, holding no reference to this stream: one that did made a
        cycle (stream -> context -> callback -> stream) that kept an ended session, its camera
        states and held buffers, until a full garbage collection (benchmarks/chaos.py: RSS
        +20 MiB per 100 ended sessions)."""
        stopped, loop, loop_thread, wake = self.stopped, self.loop, self.loop_thread, self.wake

        def done(_context) -> None:
            stopped.set()
            if threading.get_ident() == loop_thread:
                wake.set()
            else:
                loop.call_soon_threadsafe(wake.set)
        return done

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()

    def _arm(self, seconds: float) -> None:
        """Wake the writer in ``seconds`` (a convergence update comes due); one timer a stream."""
        if self.timer is not None:
            self.timer.cancel()
        self.timer = self.loop.call_later(seconds, self.wake.set)

    async def _write(self, parts: list) -> None:
        self.metrics.frame_sent(sum(len(part) for part in parts))   # counted as handed to gRPC
        for part in parts:
            await send(self.context, part)

    async def frames_from_reader(self) -> None:
        """After a client message: make and write the frames now due, if they are cheap."""
        if self.busy:
            self.again = True
            return
        if not self.session.cheap:
            self.wake.set()               # the writer makes it on a worker; the reader reads on
            return
        self.busy = True
        try:
            while True:
                self.again = False
                due = self.session.poll(self.generation, self.stopped.is_set)
                if isinstance(due, End):
                    self.wake.set()       # the writer ends the stream
                    return
                if due > 0.0:
                    if due != float("inf"):
                        self._arm(due)
                    if not self.again:
                        return
                    continue
                if not self.session.cheap:
                    self.wake.set()
                    return
                parts = self.session.make_frame(self.generation)
                if parts is not None:
                    await self._write(parts)
        finally:
            self.busy = False
            if self.again:                # the writer waited for us (a write failed, or we returned early)
                self.wake.set()

    def _make_on_worker(self) -> tuple:
        """On a worker: make a frame; when frames are costly and the next pose is
        already waiting, start its frame on a worker at once. (parts, the next
        frame's concurrent future or None.)

        Started here rather than by the writer once it has the frame, the next
        update does not wait for the event loop to wake and take the frame
        over (two sessions always refining on two cores: 1.67-1.69 cores of
        refinement, 1.60-1.66 when the writer started it). Frames stay in
        order: each starts when the one before it is made, and the writer
        takes them one after another.
        """
        parts = self.session.make_frame(self.generation)
        follow = None
        if parts is not None and not self.session.cheap \
                and self.session.poll(self.generation, self.stopped.is_set) == 0.0:
            try:
                follow = self.workers.submit(self._make_on_worker)
            except RuntimeError:          # the server is stopping (the pool shut down): the writer ends
                pass
        return parts, follow

    async def write_frames(self) -> End:
        """The writer: frames the reader leaves (timers, costly frames) until the stream ends; its End.

        A costly frame's successor, when a pose for it is already waiting,
        is started on a worker as soon as the frame is made
        (:meth:`_make_on_worker`): the session refines its next pose while
        its previous frame goes out.
        """
        session = self.session
        ahead = None                      # the next frame, being made on a worker
        while True:
            if ahead is None:
                self.wake.clear()         # before polling: a change after it sets the event again
                if self.busy:             # the reader is at it: have it look once more when done
                    self.again = True
                    await self.wake.wait()
                    continue
                due = session.poll(self.generation, self.stopped.is_set)
                if isinstance(due, End):
                    return due
                if due > 0.0:
                    if due != float("inf"):
                        self._arm(due)
                    await self.wake.wait()
                    continue
            self.busy = True
            try:
                try:
                    if ahead is None and session.cheap:
                        parts = session.make_frame(self.generation)
                    else:
                        made = ahead if ahead is not None else \
                            self.loop.run_in_executor(self.workers, self._make_on_worker)
                        parts, follow = await made
                        ahead = None if follow is None else asyncio.wrap_future(follow)
                except Exception as exc:           # noqa: BLE001 - a server bug: say so, end this stream only
                    ahead = None
                    return server_bug(session, exc)
                if parts is not None:
                    await self._write(parts)
            finally:
                if ahead is None:
                    self.busy = False


async def _read(requests, stream: _Stream) -> None:
    """The stream's reader: hands each client message to the session, then
    writes the frames that are due when they are cheap (:class:`_Stream`).

    A bad message ends the stream (and the session) with the Refused code;
    a half-close is a Close; a broken stream just stops the loop (the
    writer learns of it from the RPC's done callback, which sets
    ``stopped``). The request stream of a broken call may end just as a
    half-closed one does, with the cancellation reported a moment later: a
    half-close is one that no cancellation follows within
    HALF_CLOSE_SECONDS. A server bug while making a frame ends the stream
    with INTERNAL and is logged.
    """
    session, generation = stream.session, stream.generation
    try:
        async for msg in requests:
            if isinstance(msg, wire.WireError):
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT, str(msg))
            if msg.WhichOneof("kind") == "keyframe_request":
                logs.event("keyframe.requested", **session.describe(),
                           reason=pb.KeyframeReason.Name(msg.keyframe_request.reason)
                           if msg.keyframe_request.reason in pb.KeyframeReason.values() else "other",
                           detail=msg.keyframe_request.detail[:200])
            if not session.accept(msg, generation, wake=False):
                return
            await stream.frames_from_reader()
        await asyncio.sleep(HALF_CLOSE_SECONDS)
        if not stream.stopped.is_set():
            session.finish(CLOSED, generation)
    except Refused as r:
        session.finish(End(r.code, r.message, True), generation)
    except (grpc.RpcError, asyncio.CancelledError, StreamBroke):
        pass                               # the stream broke or was cancelled
    except Exception as exc:               # noqa: BLE001 - a server bug: say so, end this stream only
        if not stream.stopped.is_set() and not stream.context.done():
            session.finish(server_bug(session, exc), generation)


def server_bug(session, exc: Exception) -> End:
    """The End of a stream whose frame making raised ``exc`` (a server bug): logged, INTERNAL
    with a one-line message (repr escapes newlines), and the session discarded.

    Without it an exception in the writer left the RPC as grpc.aio ends it:
    UNKNOWN, which the proto does not document.
    """
    if isinstance(exc, MeshDamagedError):       # the mesh file, not the server: DATA_LOSS naming the mesh
        logs.event("session.mesh_damaged", **session.describe(), error=str(exc)[:300])
        return End(grpc.StatusCode.DATA_LOSS, damaged_message(session.served), True)
    logs.event("session.error", **session.describe(), error=repr(exc)[:300])
    return End(grpc.StatusCode.INTERNAL, f"server error while making a frame: {exc!r}"[:300], True)


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
