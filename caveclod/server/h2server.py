"""``caveclod serve --transport h2``: a gRPC server whose HTTP/2 is framed here, on the server's event loop.

grpc.aio's own work for a frame (reading a pose, writing a frame: its
C core, its Cython completion queue and the asyncio glue) was measured at
0.20-0.27 ms of CPU per frame with nothing else to do (README, "Server
model"): most of the server's CPU outside refinement, and the limit of one
process at about 2,000 frames a second. Here the same method handlers run
over an :class:`asyncio.Protocol` per connection that cuts the bytes read
into frames and messages itself (:mod:`caveclod.http2`; header blocks
through ``hpack``) and writes each frame as it is made (the answers a read
calls for, WINDOW_UPDATEs and PINGs, leave together after it).

What it serves: any aio method handler registered the way generated code
registers them (``add_generic_rpc_handlers``, ``add_registered_method_handlers``),
so the Lod service, grpc.health.v1 and reflection run unchanged, and server
interceptors (the bearer-token check). A handler's context offers what
those use: ``write``, ``abort``, ``set_code``/``set_details``, ``peer``,
``invocation_metadata``, ``add_done_callback``, ``done``, ``cancelled``,
``time_remaining``. Deadlines (``grpc-timeout``) end a call with
DEADLINE_EXCEEDED; flow control is kept both ways (a client that reads
slowly holds its stream's writer, nobody else); keepalive pings reap a peer
that went silent, as ``grpc_options`` asks of grpc.aio; ``stop(grace)``
sends GOAWAY, lets calls finish for ``grace`` seconds, then cancels them.

Not served: TLS (use the default transport, grpc.aio, with ``--tls-cert``),
compressed requests (UNIMPLEMENTED: gRPC clients compress only when asked),
HTTP/1.1 and h2c upgrades (gRPC clients speak HTTP/2 with prior knowledge).
"""

from __future__ import annotations

import asyncio
import collections
import inspect
import logging
import socket
import time
import urllib.parse

import grpc
import grpc.aio
import hpack

from .. import http2
from ..http2 import (ACK, CONTINUATION, DATA, DEFAULT_FRAME, DEFAULT_WINDOW, END_STREAM, GOAWAY, HEADERS,
                     MAX_STREAM_ID, PING, PUSH_PROMISE, RST_STREAM, SETTINGS, WINDOW_UPDATE)
from . import logs
from .config import H2_PLAINTEXT_ONLY

STREAM_WINDOW = 1 << 20          # what a client may send on a stream before our WINDOW_UPDATE (poses are ~100 B)
CONNECTION_WINDOW = 16 << 20
MAX_FRAME = DEFAULT_FRAME        # the largest frame a client may send us
MAX_STREAMS = 4096               # concurrent streams a connection may open (SETTINGS_MAX_CONCURRENT_STREAMS)
# Percent-encoding of grpc-message: every byte but printable ASCII other than '%'.
_SAFE = "".join(chr(c) for c in range(0x20, 0x7F) if c != 0x25)
_TIMEOUT_UNITS = {"H": 3600.0, "M": 60.0, "S": 1.0, "m": 1e-3, "u": 1e-6, "n": 1e-9}
_NOT_METADATA = {"te", "content-type", "grpc-timeout", "grpc-encoding", "grpc-accept-encoding"}


def _status_fields(code: grpc.StatusCode, details: str) -> list:
    """The grpc-status and (when there are details) grpc-message header fields of a call's end."""
    fields = [("grpc-status", str(code.value[0]))]
    if details:
        fields.append(("grpc-message", urllib.parse.quote(details, safe=_SAFE)))
    return fields


class AbortError(Exception):
    """Raised by :meth:`Context.abort`: the call ends with ``code`` and ``details``."""

    def __init__(self, code: grpc.StatusCode, details: str):
        super().__init__(details)
        self.code, self.details = code, details


class _CallDetails(grpc.HandlerCallDetails):
    def __init__(self, method: str, invocation_metadata: tuple):
        self.method, self.invocation_metadata = method, invocation_metadata


class Context:
    """What a method handler gets as ``context`` (the subset of grpc.aio.ServicerContext caveclod's
    services, health and reflection use)."""

    __slots__ = ("_call",)

    def __init__(self, call: "_Call"):
        self._call = call

    async def write(self, message) -> None:
        """Send one response message (serialized by the method's serializer; bytes as they are)."""
        await self._call.write(message)

    async def abort(self, code: grpc.StatusCode, details: str = "", trailing_metadata=()) -> None:
        raise AbortError(code, details)

    def set_code(self, code: grpc.StatusCode) -> None:
        self._call.code = code

    def set_details(self, details: str) -> None:
        self._call.details = details

    def code(self) -> grpc.StatusCode | None:
        return self._call.code

    def details(self) -> str | None:
        return self._call.details

    def peer(self) -> str:
        return self._call.conn.peer

    def invocation_metadata(self) -> tuple:
        return self._call.metadata

    def add_done_callback(self, callback) -> None:
        """``callback(context)`` once the call has ended, however it ended."""
        if self._call.finished:
            callback(self)
        else:
            self._call.callbacks.append(callback)

    def done(self) -> bool:
        return self._call.finished or self._call.broken

    def cancelled(self) -> bool:
        return self._call.broken

    def time_remaining(self) -> float | None:
        deadline = self._call.deadline
        return None if deadline is None else max(0.0, deadline - time.monotonic())


class _Requests:
    """The request messages of a call, as an async iterator (deserialized as they arrive).

    A message's bytes are given back to the client's flow-control windows when
    the handler takes it, not when it arrives: a client that sends faster than
    its handler reads waits for its window, as with grpc.aio, instead of
    queueing without bound.
    """

    __slots__ = ("queue", "ended", "waiter", "consumed")

    def __init__(self, consumed):
        self.queue: collections.deque = collections.deque()      # (message, bytes on the wire)
        self.ended = False                 # the client half-closed (END_STREAM)
        self.waiter: asyncio.Future | None = None
        self.consumed = consumed           # consumed(bytes): the window given back

    def put(self, message, nbytes: int) -> None:
        self.queue.append((message, nbytes))
        self._wake()

    def end(self) -> None:
        self.ended = True
        self._wake()

    def _wake(self) -> None:
        if self.waiter is not None and not self.waiter.done():
            self.waiter.set_result(None)

    def __aiter__(self):
        return self

    async def __anext__(self):
        while not self.queue:
            if self.ended:
                raise StopAsyncIteration
            self.waiter = asyncio.get_running_loop().create_future()
            await self.waiter
        message, nbytes = self.queue.popleft()
        self.consumed(nbytes)
        return message


class _Call:
    """One stream: its requests, its writes (within the client's windows) and its end."""

    __slots__ = ("conn", "stream_id", "method", "metadata", "deadline", "requests", "messages", "handler",
                 "context", "code", "details", "callbacks", "headers_sent", "finished", "broken", "reset",
                 "send_window", "unacked", "recv_window", "uncredited", "window_waiter", "task", "deadline_hit")

    def __init__(self, conn: "_Connection", stream_id: int, method: str, metadata: tuple, deadline: float | None):
        self.conn, self.stream_id, self.method, self.metadata = conn, stream_id, method, metadata
        self.deadline = deadline
        self.requests = _Requests(lambda nbytes: conn.credit(self, nbytes))
        self.messages = http2.Messages(conn.server.max_receive)
        self.handler = None                 # the RpcMethodHandler, once resolved
        self.context = Context(self)
        self.code: grpc.StatusCode | None = None
        self.details: str | None = None
        self.callbacks: list = []
        self.headers_sent = False
        self.finished = False               # trailers sent (or the call given up)
        self.broken = False                 # the client reset the stream, or the connection is gone
        self.reset = False                  # a RST_STREAM went either way
        self.send_window = conn.settings.window
        self.unacked = 0                    # bytes consumed since our last WINDOW_UPDATE of this stream
        self.recv_window = STREAM_WINDOW    # what the client may still send on this stream
        self.uncredited = 0                 # bytes received and not yet given back
        self.window_waiter: asyncio.Future | None = None
        self.task: asyncio.Task | None = None
        self.deadline_hit = False

    async def write(self, message) -> None:
        if self.finished or self.broken:
            raise asyncio.CancelledError("the call has ended")
        serializer = self.handler.response_serializer if self.handler is not None else None
        data = http2.message(serializer(message) if serializer is not None else message)
        conn = self.conn
        if not self.headers_sent:
            self.headers_sent = True
            conn.queue_headers(self.stream_id, conn.server.response_headers, False)
        sent = 0
        while sent < len(data):
            room = min(conn.send_window, self.send_window, len(data) - sent)
            if room <= 0:
                conn.flush()
                self.window_waiter = asyncio.get_running_loop().create_future()
                await self.window_waiter       # a WINDOW_UPDATE, or the stream's end
                if self.finished or self.broken:
                    raise asyncio.CancelledError("the call has ended")
                continue
            conn.queue_data(self.stream_id, data[sent:sent + room])
            conn.send_window -= room
            self.send_window -= room
            sent += room
        # Out now, not with the loop iteration's other writes: a frame made
        # right after others would wait for all of them (p50 +4 ms with 8
        # streams on a connection).
        conn.flush()
        if conn.paused is not None:           # the socket's buffer is full: this writer waits, the others go on
            await asyncio.shield(conn.paused)

    def wake_writer(self) -> None:
        if self.window_waiter is not None and not self.window_waiter.done():
            self.window_waiter.set_result(None)

    def break_off(self) -> None:
        """The client reset the stream or the connection is gone: end the handler (no status can be sent)."""
        if self.broken or self.finished:
            return
        self.broken = True
        self.requests.end()
        self.wake_writer()
        if self.task is not None:
            self.task.cancel()

    def finish(self, code: grpc.StatusCode, details: str) -> None:
        """Send the status (trailers; trailers only when nothing was sent) and run the done callbacks."""
        if not self.finished:
            self.finished = True
            conn = self.conn
            if not self.broken and not self.reset and conn.open:
                status = _status_fields(code, details)
                conn.queue_headers(self.stream_id, status if self.headers_sent else
                                   conn.server.response_headers + status, True)
                if not self.requests.ended:      # the client may still be sending: it need not
                    conn.queue_reset(self, http2.NO_ERROR)
            conn.calls.pop(self.stream_id, None)
            if self.uncredited:             # what the handler never took: the connection's window back
                conn.credit(None, self.uncredited)
                self.uncredited = 0
        self.wake_writer()
        callbacks, self.callbacks = self.callbacks, []
        for callback in callbacks:
            try:
                callback(self.context)
            except Exception:           # noqa: BLE001 - a callback's failure must not stop the others
                pass


class _Connection(asyncio.Protocol):
    """One client connection: frames in, calls started, each call's frames written as they are made."""

    def __init__(self, server: "H2Server"):
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.peer = "unknown"
        self.calls: dict[int, _Call] = {}
        self.last_stream = 0
        self.open = True
        self.preface = b""                       # the client's connection preface, until it is whole
        self.reader = http2.FrameReader(MAX_FRAME)
        self.blocks = http2.HeaderBlocks()
        self.encoder, self.decoder = hpack.Encoder(), hpack.Decoder()
        self.send_window = DEFAULT_WINDOW        # the client's connection window for our DATA
        self.settings = http2.PeerSettings()      # the client's SETTINGS: new streams' windows, our frames' limit
        self.unacked = 0                         # bytes consumed since our last connection WINDOW_UPDATE
        self.recv_window = CONNECTION_WINDOW     # what the client may still send on the connection
        self.out = bytearray()
        self.flush_soon: asyncio.Handle | None = None
        self.paused: asyncio.Future | None = None
        self.heard = 0.0
        self.pinged = None                       # when an unanswered keepalive PING went out
        self.keepalive: asyncio.TimerHandle | None = None
        self.going_away = False

    # -- asyncio.Protocol ------------------------------------------------------------------
    def connection_made(self, transport) -> None:
        self.transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
            # asyncio sets TCP_NODELAY only where the socket's proto says TCP, and
            # socket.create_server's says 0: without it Nagle held each frame
            # for the client's delayed ACK (pose -> frame p50 8 ms, not 1).
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        peer = transport.get_extra_info("peername")
        if peer:
            self.peer = f"ipv6:[{peer[0]}]:{peer[1]}" if ":" in peer[0] else f"ipv4:{peer[0]}:{peer[1]}"
        self.server.connections.add(self)
        self.out += http2.settings_frame(((http2.SETTINGS_MAX_CONCURRENT_STREAMS, MAX_STREAMS),
                                          (http2.SETTINGS_INITIAL_WINDOW_SIZE, STREAM_WINDOW),
                                          (http2.SETTINGS_MAX_FRAME_SIZE, MAX_FRAME)))
        self.out += http2.window_update(0, CONNECTION_WINDOW - DEFAULT_WINDOW)
        self.flush()
        loop = asyncio.get_running_loop()
        self.heard = loop.time()
        self.keepalive = loop.call_later(self.server.keepalive_seconds, self._check_alive)

    def data_received(self, data: bytes) -> None:
        self.heard = asyncio.get_running_loop().time()
        self.pinged = None
        if len(self.preface) < len(http2.PREFACE):
            need = len(http2.PREFACE) - len(self.preface)
            self.preface += data[:need]
            data = data[need:]
            if not http2.PREFACE.startswith(self.preface):
                self._give_up(http2.PROTOCOL_ERROR)    # not an HTTP/2 client (HTTP/1.1, TLS to a plaintext port)
                return
        try:
            for kind, flags, stream_id, payload in self.reader.frames(data):
                if kind == DATA and self.blocks.open is None:
                    self._on_data(flags, stream_id, payload)
                else:
                    self._on_frame(kind, flags, stream_id, payload)
                if not self.open:
                    return
        except (http2.ProtocolViolation, hpack.HPACKError):
            self._give_up(http2.PROTOCOL_ERROR)
            return
        except Exception as exc:                 # noqa: BLE001 - a bug of ours: this connection only, not the loop
            logs.event("connection.error", logging.ERROR, peer=self.peer, error=repr(exc)[:300])
            self._give_up(http2.INTERNAL_ERROR)
            return
        self.flush()

    def pause_writing(self) -> None:
        # The socket's buffer is full: DATA writers wait, and so does reading,
        # whose PING and SETTINGS answers would otherwise pile up unbounded.
        if self.paused is None:
            self.paused = asyncio.get_running_loop().create_future()
            if self.open:
                self.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.paused is not None:
            if not self.paused.done():
                self.paused.set_result(None)
            self.paused = None
            if self.open and not self.transport.is_closing():
                self.transport.resume_reading()

    def connection_lost(self, exc) -> None:
        self.open = False
        self.server.connections.discard(self)
        if self.keepalive is not None:
            self.keepalive.cancel()
        self.resume_writing()
        for call in list(self.calls.values()):
            call.break_off()

    # -- writing ---------------------------------------------------------------------------
    def queue_headers(self, stream_id: int, headers: list, end_stream: bool) -> None:
        self.out += http2.header_frames(self.encoder.encode(headers), stream_id, end_stream, self.settings.frame)
        self._schedule_flush()

    def queue_data(self, stream_id: int, data: bytes) -> None:
        limit = self.settings.frame
        for start in range(0, len(data), limit):
            self.out += http2.frame(DATA, 0, stream_id, data[start:start + limit])
        self._schedule_flush()

    def queue_reset(self, call: _Call, code: int) -> None:
        if not call.reset and self.open:
            call.reset = True
            self.out += http2.frame(RST_STREAM, 0, call.stream_id, code.to_bytes(4, "big"))
            self._schedule_flush()

    def _schedule_flush(self) -> None:
        # Everything the streams write in this loop iteration leaves in one write.
        if self.flush_soon is None:
            self.flush_soon = asyncio.get_running_loop().call_soon(self.flush)

    def flush(self) -> None:
        if self.flush_soon is not None:
            self.flush_soon.cancel()
            self.flush_soon = None
        if self.out and self.open:
            out, self.out = self.out, bytearray()
            self.transport.write(out)

    def close_soon(self) -> None:
        """Close after what is buffered is written, or in a second whatever a peer that does not read."""
        self.transport.close()
        asyncio.get_running_loop().call_later(1.0, self.transport.abort)

    def goaway(self) -> None:
        """No new streams (a drain): those open go on."""
        if self.open and not self.going_away:
            self.going_away = True
            self.out += http2.goaway(self.last_stream, http2.NO_ERROR)
            self.flush()

    def _give_up(self, code: int) -> None:
        """A connection error: GOAWAY with ``code``, every call broken off, the socket closed."""
        if self.open:
            self.out += http2.goaway(self.last_stream, code)
            self.flush()
            self.open = False
            self.close_soon()
        for call in list(self.calls.values()):
            call.break_off()

    def _check_alive(self) -> None:
        if not self.open:
            return
        loop = asyncio.get_running_loop()
        server = self.server
        if self.pinged is not None and loop.time() - self.pinged >= server.keepalive_timeout:
            self._give_up(http2.NO_ERROR)            # no answer to our PING: the peer is gone
            self.transport.abort()
            return
        if self.pinged is None and loop.time() - self.heard >= server.keepalive_seconds:
            self.pinged = loop.time()
            self.out += http2.frame(PING, 0, 0, b"caveclod")
            self.flush()
        wait = server.keepalive_timeout if self.pinged is not None else server.keepalive_seconds
        self.keepalive = loop.call_later(max(wait / 2, 0.05), self._check_alive)

    # -- reading ---------------------------------------------------------------------------
    def credit(self, call: _Call | None, nbytes: int) -> None:
        """Give ``nbytes`` back to the client's windows (the connection's, and ``call``'s), in
        WINDOW_UPDATEs of at least half a window."""
        self.unacked += nbytes
        if self.unacked >= CONNECTION_WINDOW // 2:
            self.out += http2.window_update(0, self.unacked)
            self.recv_window += self.unacked
            self.unacked = 0
            self._schedule_flush()
        if call is not None:
            call.uncredited -= nbytes
            call.unacked += nbytes
            if call.unacked >= STREAM_WINDOW // 2 and not call.requests.ended and call.stream_id in self.calls:
                self.out += http2.window_update(call.stream_id, call.unacked)
                call.recv_window += call.unacked
                call.unacked = 0
                self._schedule_flush()

    def _on_data(self, flags: int, stream_id: int, payload: bytes) -> None:
        counted = len(payload)                    # flow control counts the padding too
        if counted > self.recv_window:
            raise http2.ProtocolViolation("DATA past the connection's flow-control window")
        self.recv_window -= counted
        data = http2.data_payload(flags, payload)
        call = self.calls.get(stream_id)
        if call is None:
            if stream_id == 0 or stream_id > self.last_stream:
                raise http2.ProtocolViolation("DATA on a stream never opened")
            self.credit(None, counted)            # a stream that ended: dropped, its window given back
            return
        if counted > call.recv_window:
            self.queue_reset(call, http2.FLOW_CONTROL_ERROR)
            self.credit(None, counted)
            call.break_off()
            return
        call.recv_window -= counted
        call.uncredited += counted
        if counted > len(data):
            self.credit(call, counted - len(data))          # the padding: nobody will consume it
        if data and not call.requests.ended:
            try:
                messages = call.messages.feed(data)
            except http2.MessageError as exc:
                self.refuse(call, grpc.StatusCode.UNIMPLEMENTED if exc.kind == "compressed" else
                            grpc.StatusCode.RESOURCE_EXHAUSTED, f"{exc} (send uncompressed messages of at most "
                            f"{call.messages.max_message} bytes)" if exc.kind == "compressed" else str(exc))
                return
            deserializer = call.handler.request_deserializer if call.handler is not None else None
            for one in messages:
                try:
                    request = deserializer(one) if deserializer is not None else one
                except Exception as exc:          # noqa: BLE001 - this call's bad message, not the connection's
                    self.refuse(call, grpc.StatusCode.INTERNAL, f"a request message that does not "
                                f"deserialize: {type(exc).__name__}: {exc}"[:300])
                    return
                call.requests.put(request, len(one) + 5)
        if flags & END_STREAM:
            if call.messages.partial:
                self.refuse(call, grpc.StatusCode.INTERNAL,
                            f"the request stream ended inside a message ({call.messages.partial} bytes)")
                return
            call.requests.end()

    def refuse(self, call: _Call, code: grpc.StatusCode, details: str) -> None:
        """End a call that cannot go on: its status sent, its handler cancelled."""
        call.finish(code, details)
        if call.task is not None:
            call.task.cancel()

    def _on_frame(self, kind: int, flags: int, stream_id: int, payload: bytes) -> None:
        if self.blocks.open is not None and kind != CONTINUATION:
            raise http2.ProtocolViolation("a frame inside a header block")
        if kind in (HEADERS, CONTINUATION):
            block = self.blocks.add(kind, flags, stream_id, payload)
            if block is not None:
                self._on_headers(*block)
        elif kind == DATA:
            self._on_data(flags, stream_id, payload)
        elif kind == SETTINGS:
            if stream_id:
                raise http2.ProtocolViolation("SETTINGS on a stream")
            if not flags & ACK:
                delta = self.settings.apply(payload, self.encoder)
                if delta:
                    for call in self.calls.values():         # the change applies to open streams too
                        call.send_window += delta
                        call.wake_writer()
                self.out += http2.frame(SETTINGS, ACK, 0)
        elif kind == WINDOW_UPDATE:
            if len(payload) != 4:
                raise http2.ProtocolViolation("a WINDOW_UPDATE not of 4 bytes")
            amount = int.from_bytes(payload, "big") & MAX_STREAM_ID
            if stream_id == 0:
                if amount == 0 or self.send_window + amount > MAX_STREAM_ID:
                    raise http2.ProtocolViolation(f"a connection WINDOW_UPDATE of {amount}")
                self.send_window += amount
                for call in self.calls.values():
                    call.wake_writer()
            elif (call := self.calls.get(stream_id)) is not None:
                if amount == 0 or call.send_window + amount > MAX_STREAM_ID:
                    self.queue_reset(call, http2.PROTOCOL_ERROR if amount == 0 else http2.FLOW_CONTROL_ERROR)
                    call.break_off()
                    return
                call.send_window += amount
                call.wake_writer()
        elif kind == PING:
            if len(payload) != 8:
                raise http2.ProtocolViolation("a PING not of 8 bytes")
            if not flags & ACK:
                self.out += http2.frame(PING, ACK, 0, payload)
        elif kind == RST_STREAM:
            if (call := self.calls.get(stream_id)) is not None:
                call.reset = True
                call.break_off()
        elif kind == GOAWAY:
            self.going_away = True                     # the client opens no more streams here
        elif kind == PUSH_PROMISE:
            raise http2.ProtocolViolation("a PUSH_PROMISE from a client")

    def _on_headers(self, stream_id: int, end_stream: bool, block: bytes) -> None:
        headers = self.decoder.decode(block)      # decoded whatever follows: HPACK's table is the connection's
        if (call := self.calls.get(stream_id)) is not None:
            if end_stream:                         # trailers from a client: the end of its messages
                call.requests.end()
            else:                                  # RFC 9113 8.1: trailers end the stream; else malformed
                self.queue_reset(call, http2.PROTOCOL_ERROR)
                call.break_off()
            return
        if stream_id % 2 == 0:
            raise http2.ProtocolViolation(f"HEADERS opening stream {stream_id}, an even (server) id")
        if stream_id <= self.last_stream:
            return                                 # a stream that ended (we may have reset it): ignored
        self.last_stream = stream_id
        if self.going_away or len(self.calls) >= MAX_STREAMS:
            self.out += http2.frame(RST_STREAM, 0, stream_id, http2.REFUSED_STREAM.to_bytes(4, "big"))
            return
        fields, metadata = {}, []
        for name, value in headers:
            if name.startswith(":") or name in _NOT_METADATA:
                fields[name] = value
            else:
                metadata.append((name, value))
        # gRPC's HTTP/2 mapping: POST only; a content-type other than
        # application/grpc gets HTTP 415, so that an HTTP client that is not
        # gRPC's does not take a 200 for success.
        if fields.get(":method") != "POST":
            self._answer_http(stream_id, end_stream, "405", f"gRPC calls are POST requests, not "
                              f"{fields.get(':method')!r}")
            return
        if not fields.get("content-type", "").startswith("application/grpc"):
            self._answer_http(stream_id, end_stream, "415", f"not a gRPC request (content-type "
                              f"{fields.get('content-type')!r}); send application/grpc")
            return
        deadline = _deadline(fields.get("grpc-timeout"))
        call = _Call(self, stream_id, fields.get(":path", ""), tuple(metadata), deadline)
        self.calls[stream_id] = call
        if end_stream:
            call.requests.end()
        call.task = asyncio.get_running_loop().create_task(self.server.run_call(call))
        # A task cancelled before it starts never runs run_call's finish (a
        # client's RST_STREAM in the same read as its HEADERS): end it here.
        call.task.add_done_callback(lambda _: call.finish(grpc.StatusCode.CANCELLED, "the call was cancelled"))

    def _answer_http(self, stream_id: int, end_stream: bool, status: str, details: str) -> None:
        """End a stream that is not a gRPC call: HTTP ``status``, and UNIMPLEMENTED for gRPC clients."""
        self.queue_headers(stream_id, [(":status", status), ("content-type", "application/grpc"),
                                       *_status_fields(grpc.StatusCode.UNIMPLEMENTED, details)], True)
        if not end_stream:                 # whatever it still sends is dropped (a stream that ended)
            self.out += http2.frame(RST_STREAM, 0, stream_id, http2.NO_ERROR.to_bytes(4, "big"))


def _deadline(timeout: str | None) -> float | None:
    """The monotonic deadline a grpc-timeout header ("100m", "5S", ...) sets; None without one."""
    digits = (timeout or "")[:-1]
    if not timeout or timeout[-1] not in _TIMEOUT_UNITS or not (digits.isascii() and digits.isdigit()) \
            or len(digits) > 8:
        return None
    return time.monotonic() + int(timeout[:-1]) * _TIMEOUT_UNITS[timeout[-1]]


class H2Server(grpc.aio.Server):
    """A gRPC server for aio method handlers over :mod:`caveclod.http2`; used as grpc.aio.server() is.

    Args:
        interceptors: grpc.aio.ServerInterceptor objects, outermost first.
        max_receive: the largest request message accepted (RESOURCE_EXHAUSTED past it).
        keepalive_seconds, keepalive_timeout: PING a connection silent this long, drop it when
            the PING is not answered in the timeout.
        reuse_port: SO_REUSEPORT on the listening sockets (``--processes N``).
    """

    def __init__(self, interceptors=(), *, max_receive: int = 64 * 1024, keepalive_seconds: float = 20.0,
                 keepalive_timeout: float = 10.0, reuse_port: bool = False):
        self.interceptors = list(interceptors)
        self.max_receive = max_receive
        self.keepalive_seconds, self.keepalive_timeout = keepalive_seconds, keepalive_timeout
        self.reuse_port = reuse_port
        self.response_headers = [(":status", "200"), ("content-type", "application/grpc")]
        self._generic: list = []
        self._registered: dict = {}
        self._sockets: list[socket.socket] = []
        self._servers: list = []
        self.connections: set[_Connection] = set()
        self._stopped: asyncio.Event | None = None

    # -- what grpc.aio.Server offers ---------------------------------------------------------
    def add_generic_rpc_handlers(self, generic_rpc_handlers) -> None:
        self._generic.extend(generic_rpc_handlers)

    def add_registered_method_handlers(self, service_name: str, method_handlers: dict) -> None:
        for method, handler in method_handlers.items():
            self._registered[f"/{service_name}/{method}"] = handler

    def add_insecure_port(self, address: str) -> int:
        """Bind ``host:port`` now (``[v6]:port`` for IPv6); the port bound, 0 when it cannot be."""
        host, _, port = address.rpartition(":")
        host = host.strip("[]") or "0.0.0.0"
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            sock = socket.create_server((host, int(port)), family=family, backlog=1024,
                                        reuse_port=self.reuse_port)
        except (OSError, ValueError):
            return 0
        sock.setblocking(False)
        self._sockets.append(sock)
        return sock.getsockname()[1]

    def add_secure_port(self, address: str, server_credentials) -> int:
        raise NotImplementedError(H2_PLAINTEXT_ONLY)         # LodServer refuses the pair before it gets here

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._stopped = asyncio.Event()
        for sock in self._sockets:
            self._servers.append(await loop.create_server(lambda: _Connection(self), sock=sock))

    async def stop(self, grace: float | None) -> None:
        """GOAWAY to every connection; calls get ``grace`` seconds to end, then end UNAVAILABLE."""
        for server in self._servers:
            server.close()
        for conn in list(self.connections):
            conn.goaway()
        deadline = time.monotonic() + (grace or 0.0)
        while time.monotonic() < deadline and any(c.calls for c in self.connections):
            await asyncio.sleep(0.02)
        tasks = [call.task for conn in self.connections for call in conn.calls.values() if call.task is not None]
        for conn in list(self.connections):
            for call in list(conn.calls.values()):
                # A status, not a cut socket: a proxy passes a status on, where a
                # stream cut under it becomes its own error (nginx: INTERNAL, which
                # a client does not retry); UNAVAILABLE tells a client to go on elsewhere.
                conn.refuse(call, grpc.StatusCode.UNAVAILABLE, "the server stopped; connect again (another "
                                                               "replica, or this one once it is back)")
        if tasks:
            await asyncio.wait(tasks, timeout=2.0)
        for conn in list(self.connections):
            conn.flush()
            conn.close_soon()
        if self._stopped is not None:
            self._stopped.set()

    async def wait_for_termination(self, timeout: float | None = None) -> bool:
        if self._stopped is None:
            return True
        try:
            await asyncio.wait_for(self._stopped.wait(), timeout)
            return True
        except asyncio.TimeoutError:
            return False

    # -- calls -----------------------------------------------------------------------------
    async def _handler(self, method: str, metadata: tuple):
        """The method's RpcMethodHandler through the interceptors (None: not served)."""
        async def resolve(details):
            handler = self._registered.get(details.method)
            for generic in self._generic:
                if handler is not None:
                    break
                handler = generic.service(details)
            return handler

        continuation = resolve
        for interceptor in reversed(self.interceptors):
            continuation = _intercepted(interceptor, continuation)
        return await continuation(_CallDetails(method, metadata))

    async def run_call(self, call: _Call) -> None:
        """Run ``call``'s handler to its end and send the status."""
        code, details = grpc.StatusCode.OK, ""
        timer = None
        if call.deadline is not None:
            def expire():
                call.deadline_hit = True
                if call.task is not None:
                    call.task.cancel()
            timer = asyncio.get_running_loop().call_later(max(0.0, call.deadline - time.monotonic()), expire)
        try:
            handler = await self._handler(call.method, call.metadata)
            if handler is None:
                raise AbortError(grpc.StatusCode.UNIMPLEMENTED, f"Method not found: {call.method}")
            call.handler = handler
            # Messages that arrived before the handler was known are deserialized now.
            if handler.request_deserializer is not None and call.requests.queue:
                try:
                    call.requests.queue = collections.deque((handler.request_deserializer(m), n)
                                                            for m, n in call.requests.queue)
                except Exception as exc:     # noqa: BLE001 - as a message that arrives later (_on_data)
                    raise AbortError(grpc.StatusCode.INTERNAL, f"a request message that does not deserialize: "
                                     f"{type(exc).__name__}: {exc}"[:300]) from None
            if handler.request_streaming:
                behaviour = handler.stream_stream if handler.response_streaming else handler.stream_unary
                result = behaviour(call.requests, call.context)
            else:
                request = await _single(call.requests)
                behaviour = handler.unary_stream if handler.response_streaming else handler.unary_unary
                result = behaviour(request, call.context)
            if inspect.isasyncgen(result):
                try:
                    async for response in result:
                        await call.write(response)
                finally:
                    await result.aclose()
            else:
                response = await result
                if not handler.response_streaming and response is not None and call.code in (None,
                                                                                             grpc.StatusCode.OK):
                    await call.write(response)
            code, details = call.code or grpc.StatusCode.OK, call.details or ""
        except AbortError as exc:
            code, details = exc.code, exc.details
        except asyncio.CancelledError:
            if call.deadline_hit:
                code, details = grpc.StatusCode.DEADLINE_EXCEEDED, "Deadline Exceeded"
            else:
                code, details = grpc.StatusCode.CANCELLED, "the call was cancelled"
        except Exception as exc:             # noqa: BLE001 - as grpc.aio: UNKNOWN, naming the exception
            code, details = grpc.StatusCode.UNKNOWN, f"Unexpected {type(exc).__name__}: {exc}"
        finally:
            if timer is not None:
                timer.cancel()
        call.finish(code, details)


async def _single(requests: _Requests):
    """The one request message of a unary-request call."""
    try:
        request = await requests.__anext__()
    except StopAsyncIteration:
        raise AbortError(grpc.StatusCode.INTERNAL, "no request message (a unary call needs one)") from None
    return request


def _intercepted(interceptor, continuation):
    async def call(details):
        return await interceptor.intercept_service(continuation, details)
    return call
