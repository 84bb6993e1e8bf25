"""gRPC over HTTP/2, framed here: many Session streams on one socket, for the load generator.

grpc.aio spends most of a load generator's CPU on its own machinery: an
awaited read and an awaited write per message, and a ``sendmsg`` system
call per message written (``caveclod loadtest`` profiled: 35 % of its CPU
in the write of each pose). This module speaks the same wire protocol
(gRPC's HTTP/2 mapping: a POST per call, each message a 5-byte prefix and
its protobuf bytes, the status in the trailers) from an
:class:`asyncio.Protocol`: a read of the socket is cut into HTTP/2 frames
at once and every message in it is dispatched by a plain call, and
whatever the handlers send (acks, poses of every session due at the same
tick) goes out in one write.

The frames are read and written here, not by the ``h2`` library: a load
test's traffic is DATA frames both ways and the server's WINDOW_UPDATEs,
and h2 spent a fifth of the load generator's CPU on them (an event object
and two state machines per frame, and the ``repr`` of every frame it
receives, made for a logger that drops it). Only what gRPC's client side
needs is spoken (RFC 9113): SETTINGS, DATA, HEADERS and CONTINUATION
(header blocks through ``hpack``, h2's own HPACK codec), WINDOW_UPDATE,
PING, RST_STREAM and GOAWAY; no server push (disabled in our SETTINGS),
priorities ignored. Flow control: the server's windows are kept exactly;
ours are large (STREAM_WINDOW, CONNECTION_WINDOW) and given back once half
of one is used, so a steady stream costs a WINDOW_UPDATE every few
thousand frames.

Plaintext HTTP/2 only (``h2c`` with prior knowledge, as gRPC's insecure
channels): TLS is left to grpc.aio (``caveclod loadtest --transport grpc``).

    conn = await H2Connection.connect("127.0.0.1", 50051)
    call = conn.start_call("/caveclod.v1.Lod/Session", metadata, on_message, on_end)
    call.send(request_bytes); conn.flush()
"""

from __future__ import annotations

import asyncio
import urllib.parse
from typing import Callable

import grpc
import hpack

from ..http2 import (ACK, CANCEL, CONTINUATION, DATA, DEFAULT_WINDOW, END_STREAM, ENHANCE_YOUR_CALM, GOAWAY, HEADERS,
                     INADEQUATE_SECURITY, MAX_STREAM_ID, NO_ERROR, PING, PREFACE, PUSH_PROMISE, REFUSED_STREAM,
                     RST_STREAM, SETTINGS, SETTINGS_ENABLE_PUSH, SETTINGS_INITIAL_WINDOW_SIZE, SETTINGS_MAX_FRAME_SIZE,
                     WINDOW_UPDATE, FrameReader, HeaderBlocks, MessageError, Messages, PeerSettings,
                     ProtocolViolation, data_payload, frame, goaway, header_frames, message, settings_frame,
                     window_update)

# Windows large enough that a vertex buffer (a few MiB) or a burst of frames
# never waits for a WINDOW_UPDATE round trip.
STREAM_WINDOW = 8 << 20
CONNECTION_WINDOW = 64 << 20
# The largest frame the server may send us (advertised in SETTINGS): fewer,
# larger DATA frames for a vertex buffer.
MAX_FRAME = 1 << 20
MAX_MESSAGE = 64 << 20          # a message larger than this is a broken stream, not an allocation
# Keepalive as the grpc clients' (caveclod.client.session.CHANNEL_OPTIONS): a
# PING after 20 s without a byte from the server, the connection given up
# 10 s later, so that a silent network cut ends in a resume, not a hang.
KEEPALIVE_SECONDS = 20.0
KEEPALIVE_TIMEOUT = 10.0
STATUS_BY_CODE = {code.value[0]: code for code in grpc.StatusCode}
# A stream reset's status, as gRPC's HTTP/2 mapping says (others: INTERNAL).
RESET_STATUS = {REFUSED_STREAM: grpc.StatusCode.UNAVAILABLE, CANCEL: grpc.StatusCode.CANCELLED,
                ENHANCE_YOUR_CALM: grpc.StatusCode.RESOURCE_EXHAUSTED,
                INADEQUATE_SECURITY: grpc.StatusCode.PERMISSION_DENIED}


class CallEnded(Exception):
    """A call's end: ``code`` (grpc.StatusCode) and ``details`` as the server or the connection gave them."""

    def __init__(self, code: grpc.StatusCode, details: str):
        super().__init__(f"{code.name}: {details}")
        self.code, self.details = code, details


class H2Call:
    """One gRPC call (an HTTP/2 stream) on an :class:`H2Connection`.

    ``on_message(bytes)`` runs for every response message as it is complete;
    ``on_end(code, details)`` once, when the call ends (OK or not), after
    its last message.
    """

    __slots__ = ("conn", "stream_id", "on_message", "on_end", "_messages", "_status", "ended", "_pending",
                 "send_window", "_unacked", "_half_close", "local_closed", "remote_closed", "_reset")

    def __init__(self, conn: "H2Connection", stream_id: int, on_message: Callable[[bytes], None],
                 on_end: Callable[[grpc.StatusCode, str], None]):
        self.conn, self.stream_id = conn, stream_id
        self.on_message, self.on_end = on_message, on_end
        self._messages = Messages(MAX_MESSAGE)
        self._status: tuple | None = None       # (code, details) from headers or trailers
        self.ended = False
        self._pending = bytearray()              # framed messages waiting for flow-control window
        self.send_window = conn._peer.window     # bytes the server lets us send on this stream
        self._unacked = 0                        # bytes received since our last WINDOW_UPDATE
        self._half_close = False                 # END_STREAM due once _pending is out
        self.local_closed = self.remote_closed = False
        self._reset = False                      # a RST_STREAM went either way

    def send(self, data: bytes) -> None:
        """Queue one request message (serialized protobuf); it leaves at the connection's next flush."""
        if self.ended or self._half_close:
            return
        self._pending += message(data)
        self.conn._dirty.add(self)

    def close_send(self) -> None:
        """Half-close: no more request messages (gRPC's end of the client stream)."""
        if self.ended:
            return
        self._half_close = True
        self.conn._dirty.add(self)

    def cancel(self) -> None:
        """Reset the stream (CANCEL) and end the call locally as CANCELLED."""
        if self.ended:
            return
        self.conn._reset_stream(self, CANCEL)
        self.conn.flush()
        self._finish(grpc.StatusCode.CANCELLED, "cancelled by the client")

    # -- what the connection hands over --------------------------------------------------
    def _data(self, data: bytes) -> None:
        try:
            messages = self._messages.feed(data)
        except MessageError as exc:
            self._fail(grpc.StatusCode.INTERNAL if exc.kind == "compressed" else grpc.StatusCode.RESOURCE_EXHAUSTED,
                       str(exc))
            return
        for one in messages:
            self.on_message(one)
            if self.ended:
                return

    def _headers(self, headers: list) -> None:
        fields = dict(headers)
        status = fields.get(":status")
        if status is not None and status != "200":
            self._status = (_http_status_code(status), f"HTTP status {status} (not a gRPC server?)")
        if "grpc-status" in fields:
            raw = fields["grpc-status"]
            code = STATUS_BY_CODE.get(int(raw), grpc.StatusCode.UNKNOWN) if raw.isdigit() else grpc.StatusCode.UNKNOWN
            self._status = (code, urllib.parse.unquote(fields.get("grpc-message", "")) if raw.isdigit() else
                            f"a grpc-status that is not a number: {raw[:40]!r}")

    def _stream_ended(self) -> None:
        self.remote_closed = True
        if self._messages.partial:
            self._finish(grpc.StatusCode.INTERNAL,
                         f"the stream ended inside a message ({self._messages.partial} bytes)")
        elif self._status is None:
            self._finish(grpc.StatusCode.UNKNOWN, "the stream ended without a grpc-status")
        else:
            self._finish(*self._status)

    def _fail(self, code: grpc.StatusCode, details: str) -> None:
        self.conn._reset_stream(self, CANCEL)
        self._finish(code, details)

    def _finish(self, code: grpc.StatusCode, details: str) -> None:
        if self.ended:
            return
        self.ended = True
        conn = self.conn
        conn.calls.pop(self.stream_id, None)
        conn._dirty.discard(self)
        self._pending.clear()
        if conn.lost is None and not (self.local_closed and self.remote_closed):
            conn._reset_stream(self, NO_ERROR)     # free our side of the stream too
        self.on_end(code, details)


def _http_status_code(status: str) -> grpc.StatusCode:
    """gRPC's mapping of an HTTP status that is not 200 (its http-grpc-status-mapping)."""
    return {"400": grpc.StatusCode.INTERNAL, "401": grpc.StatusCode.UNAUTHENTICATED,
            "403": grpc.StatusCode.PERMISSION_DENIED, "404": grpc.StatusCode.UNIMPLEMENTED,
            "429": grpc.StatusCode.UNAVAILABLE, "502": grpc.StatusCode.UNAVAILABLE,
            "503": grpc.StatusCode.UNAVAILABLE, "504": grpc.StatusCode.UNAVAILABLE}.get(status, grpc.StatusCode.UNKNOWN)


class H2Connection(asyncio.Protocol):
    """One plaintext HTTP/2 connection carrying gRPC calls; make one with :meth:`connect`."""

    def __init__(self, authority: str):
        self.authority = authority
        self.transport: asyncio.Transport | None = None
        self.calls: dict[int, H2Call] = {}
        self._dirty: set[H2Call] = set()
        self._out = bytearray()                  # frames to write at the next flush
        self._reader = FrameReader(MAX_FRAME)
        self._blocks = HeaderBlocks()
        self._encoder, self._decoder = hpack.Encoder(), hpack.Decoder()
        self._next_stream = 1
        self._send_window = DEFAULT_WINDOW       # the connection's window for our DATA (the server's)
        self._peer = PeerSettings()              # the server's SETTINGS
        self._unacked = 0                        # bytes received on the connection since our last WINDOW_UPDATE
        self.lost: str | None = None             # why the connection is gone, once it is
        self._heard = 0.0                        # the loop's time of the last read
        self._spoke_h2 = False                   # the server's SETTINGS arrived
        self._keepalive: asyncio.TimerHandle | None = None
        self.going_away: str | None = None       # why no new call may start (GOAWAY), once so

    @property
    def usable(self) -> bool:
        """Whether a new call may start here."""
        return self.lost is None and self.going_away is None

    @classmethod
    async def connect(cls, host: str, port: int, timeout: float = 10.0) -> "H2Connection":
        """Open a connection (raises CallEnded UNAVAILABLE when nothing answers)."""
        loop = asyncio.get_running_loop()
        try:
            _, conn = await asyncio.wait_for(loop.create_connection(lambda: cls(f"{host}:{port}"), host, port),
                                             timeout)
        except (OSError, asyncio.TimeoutError) as exc:
            raise CallEnded(grpc.StatusCode.UNAVAILABLE, f"cannot connect to {host}:{port}: {exc}") from None
        return conn

    # -- asyncio.Protocol ------------------------------------------------------------------
    def connection_made(self, transport) -> None:
        self.transport = transport
        self._out += PREFACE + settings_frame(((SETTINGS_ENABLE_PUSH, 0), (SETTINGS_INITIAL_WINDOW_SIZE, STREAM_WINDOW),
                                               (SETTINGS_MAX_FRAME_SIZE, MAX_FRAME)))
        self._out += window_update(0, CONNECTION_WINDOW - DEFAULT_WINDOW)
        self.flush()
        loop = asyncio.get_running_loop()
        self._heard = loop.time()
        self._keepalive = loop.call_later(KEEPALIVE_TIMEOUT / 2, self._check_alive)

    def _check_alive(self) -> None:
        if self.lost is not None:
            return
        loop = asyncio.get_running_loop()
        silent = loop.time() - self._heard
        if silent >= KEEPALIVE_SECONDS + KEEPALIVE_TIMEOUT:
            self.transport.abort()
            self._lose(f"no answer from the server for {silent:.0f} s (keepalive); the network or the server is gone")
            return
        if silent >= KEEPALIVE_SECONDS:
            self._out += frame(PING, 0, 0, b"caveclod")
            self.flush()
        self._keepalive = loop.call_later(KEEPALIVE_TIMEOUT / 2, self._check_alive)

    def data_received(self, data: bytes) -> None:
        self._heard = asyncio.get_running_loop().time()
        try:
            for kind, flags, stream_id, payload in self._reader.frames(data):
                if kind == DATA and self._spoke_h2 and self._blocks.open is None:     # the common frame first
                    self._on_data(flags, stream_id, payload)
                else:
                    self._on_frame(kind, flags, stream_id, payload)
                if self.lost is not None:
                    return
        except ProtocolViolation as exc:
            self._lose(f"HTTP/2 protocol error from the server: {exc}")
            self.transport.close()
            return
        except hpack.HPACKError as exc:
            self._lose(f"HTTP/2 protocol error from the server: a header block that does not decode ({exc})")
            self.transport.close()
            return
        self.flush()

    def connection_lost(self, exc) -> None:
        if not self._spoke_h2:
            self._lose("the server closed the connection before speaking HTTP/2: is it a plaintext gRPC server? "
                       "(for TLS use --transport grpc)")
        else:
            self._lose(f"the connection was lost: {exc}" if exc else "the server closed the connection")

    # -- calls ------------------------------------------------------------------------------
    def start_call(self, path: str, metadata, on_message, on_end) -> H2Call:
        """Start a call to ``path`` ("/package.Service/Method") with ``metadata`` ((key, value) pairs).

        The request headers leave at the next :meth:`flush`. On a lost
        connection the call ends at once with UNAVAILABLE.
        """
        stream_id = self._next_stream
        call = H2Call(self, stream_id, on_message, on_end)
        call.local_closed = call.remote_closed = True       # nothing to reset should it end at once
        if self.lost is not None or self.going_away is not None:
            call._finish(grpc.StatusCode.UNAVAILABLE, self.lost or self.going_away)
            return call
        if stream_id > MAX_STREAM_ID:
            self.going_away = "this connection has used every stream id; a new one is opened"
            call._finish(grpc.StatusCode.UNAVAILABLE, self.going_away)
            return call
        if len(self.calls) >= self._peer.streams:
            call._finish(grpc.StatusCode.UNAVAILABLE, "the server allows no more streams on this connection; "
                         "use more connections (--connections)")
            return call
        self._next_stream += 2
        call.local_closed = call.remote_closed = False
        headers = [(":method", "POST"), (":scheme", "http"), (":path", path), (":authority", self.authority),
                   ("te", "trailers"), ("content-type", "application/grpc"),
                   ("user-agent", "caveclod-loadtest h2")]
        headers += [(k, v) for k, v in metadata]
        self._out += header_frames(self._encoder.encode(headers), stream_id, False, self._peer.frame)
        self.calls[stream_id] = call
        return call

    def flush(self) -> None:
        """Move the calls' queued messages into HTTP/2 frames (as flow control allows); write them at once."""
        if self.lost is not None:
            return
        if self._dirty:
            for call in list(self._dirty):
                self._send_pending(call)
        if self._out:
            out, self._out = self._out, bytearray()
            self.transport.write(out)

    def close(self) -> None:
        """End every call (CANCELLED) and close the socket."""
        if self.transport is not None and self.lost is None:
            # last_stream_id 0: a client processes no stream the server starts.
            self.transport.write(bytes(self._out) + goaway(0, NO_ERROR))
            self._out.clear()
            self.transport.close()
        self._lose("the client closed the connection", grpc.StatusCode.CANCELLED)

    # -- internals ----------------------------------------------------------------------------
    def _send_pending(self, call: H2Call) -> None:
        """Frame what ``call`` queued, as far as both windows allow; END_STREAM once it is all out."""
        pending = call._pending
        if call.local_closed or call._reset:
            pending.clear()
            self._dirty.discard(call)
            return
        room = min(self._send_window, call.send_window, len(pending))
        if room > 0:
            sent = 0
            out, sid, limit = self._out, call.stream_id, self._peer.frame
            while sent < room:
                size = min(room - sent, limit)
                last = call._half_close and sent + size == len(pending)
                out += frame(DATA, END_STREAM if last else 0, sid, pending[sent:sent + size])
                sent += size
            del pending[:sent]
            self._send_window -= sent
            call.send_window -= sent
            if call._half_close and not pending:
                call.local_closed = True
        elif call._half_close and not pending:
            self._out += frame(DATA, END_STREAM, call.stream_id)
            call.local_closed = True
        if not pending:
            self._dirty.discard(call)

    def _reset_stream(self, call: H2Call, code: int) -> None:
        """Queue a RST_STREAM of ``call`` (once; not on a lost connection or a stream already reset)."""
        if self.lost is None and not call._reset:
            call._reset = True
            self._out += frame(RST_STREAM, 0, call.stream_id, code.to_bytes(4, "big"))

    def _on_data(self, flags: int, stream_id: int, payload: bytes) -> None:
        if stream_id == 0:
            raise ProtocolViolation("a DATA frame on stream 0")
        counted = len(payload)                   # flow control counts the padding too
        self._unacked += counted
        if self._unacked >= CONNECTION_WINDOW // 2:
            self._out += window_update(0, self._unacked)
            self._unacked = 0
        payload = data_payload(flags, payload)
        call = self.calls.get(stream_id)
        if call is None:
            return                               # a stream we ended: its data is dropped (the window given back)
        call._unacked += counted
        if call._unacked >= STREAM_WINDOW // 2 and not flags & END_STREAM:
            self._out += window_update(stream_id, call._unacked)
            call._unacked = 0
        if payload:
            call._data(payload)
        if flags & END_STREAM and not call.ended:
            call._stream_ended()

    def _on_frame(self, kind: int, flags: int, stream_id: int, payload: bytes) -> None:
        """Every frame but the common DATA: connection state, header blocks, stream ends."""
        if self._blocks.open is not None and kind != CONTINUATION:
            raise ProtocolViolation(f"a frame of type {kind} inside a header block (CONTINUATION expected)")
        if not self._spoke_h2 and kind != SETTINGS:
            raise ProtocolViolation(f"the server's first frame is of type {kind}, not SETTINGS: is it a gRPC "
                                     "server, speaking plaintext HTTP/2?")
        if kind == SETTINGS:
            self._on_settings(flags, stream_id, payload)
        elif kind == DATA:
            self._on_data(flags, stream_id, payload)
        elif kind in (HEADERS, CONTINUATION):
            self._on_headers(kind, flags, stream_id, payload)
        elif kind == WINDOW_UPDATE:
            if len(payload) != 4:
                raise ProtocolViolation(f"a WINDOW_UPDATE of {len(payload)} bytes")
            amount = int.from_bytes(payload, "big") & MAX_STREAM_ID
            if stream_id == 0:
                self._send_window += amount
                self._dirty.update(c for c in self.calls.values() if c._pending)
            elif (call := self.calls.get(stream_id)) is not None:
                call.send_window += amount
                if call._pending:
                    self._dirty.add(call)
        elif kind == PING:
            if len(payload) != 8:
                raise ProtocolViolation(f"a PING of {len(payload)} bytes")
            if not flags & ACK:
                self._out += frame(PING, ACK, 0, payload)
        elif kind == RST_STREAM:
            if len(payload) != 4:
                raise ProtocolViolation(f"a RST_STREAM of {len(payload)} bytes")
            if (call := self.calls.get(stream_id)) is not None:
                call._reset = True
                error = int.from_bytes(payload, "big")
                call._finish(RESET_STATUS.get(error, grpc.StatusCode.INTERNAL),
                             f"Received RST_STREAM with error code {error}")
        elif kind == GOAWAY:
            if len(payload) < 8:
                raise ProtocolViolation(f"a GOAWAY of {len(payload)} bytes")
            # Calls up to last_stream_id go on (a draining server finishes
            # them); later ones were never seen, and no new call may start here.
            last = int.from_bytes(payload[:4], "big") & MAX_STREAM_ID
            why = f"the server is going away (GOAWAY, error code {int.from_bytes(payload[4:8], 'big')})"
            self.going_away = why
            for late_id, late in list(self.calls.items()):
                if late_id > last:
                    late.local_closed = late.remote_closed = True     # never seen: nothing to reset
                    late._finish(grpc.StatusCode.UNAVAILABLE, why)
        elif kind == PUSH_PROMISE:
            raise ProtocolViolation("a PUSH_PROMISE, though our SETTINGS disable server push")
        # PRIORITY and unknown frame types are ignored, as RFC 9113 asks.

    def _on_settings(self, flags: int, stream_id: int, payload: bytes) -> None:
        if stream_id != 0:
            raise ProtocolViolation("a SETTINGS frame on a stream")
        self._spoke_h2 = True
        if flags & ACK:
            return
        delta = self._peer.apply(payload, self._encoder)
        if delta:
            for call in self.calls.values():                 # the change applies to open streams too
                call.send_window += delta
                if delta > 0 and call._pending:
                    self._dirty.add(call)
        self._out += frame(SETTINGS, ACK, 0)

    def _on_headers(self, kind: int, flags: int, stream_id: int, payload: bytes) -> None:
        """A HEADERS frame, or a CONTINUATION of one; a complete block is decoded and handed to its call."""
        block = self._blocks.add(kind, flags, stream_id, payload)
        if block is None:
            return
        # Every block is decoded, a dropped stream's too: HPACK's table is the connection's.
        headers = self._decoder.decode(block[2])
        call = self.calls.get(stream_id)
        if call is None:
            return
        call._headers(headers)
        if block[1] and not call.ended:
            call._stream_ended()

    def _lose(self, why: str, code: grpc.StatusCode = grpc.StatusCode.UNAVAILABLE) -> None:
        if self.lost is not None:
            return
        self.lost = why
        if self._keepalive is not None:
            self._keepalive.cancel()
        for call in list(self.calls.values()):
            call._finish(code, why)
