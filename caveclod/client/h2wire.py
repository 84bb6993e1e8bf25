"""gRPC over HTTP/2 with the ``h2`` library: many Session streams on one socket, for the load generator.

grpc.aio spends most of a load generator's CPU on its own machinery: an
awaited read and an awaited write per message, and a ``sendmsg`` system
call per message written (``caveclod loadtest`` profiled: 35 % of its CPU
in the write of each pose). This module speaks the same wire protocol
(gRPC's HTTP/2 mapping: a POST per call, each message a 5-byte prefix and
its protobuf bytes, the status in the trailers) from an
:class:`asyncio.Protocol`: a read of the socket is handed to ``h2`` at
once and every message in it is dispatched by a plain call, and whatever
the handlers send (acks, poses of every session due at the same tick) goes
out in one write.

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
import h2.config
import h2.connection
import h2.errors
import h2.events
import h2.exceptions
import h2.settings

# Windows large enough that a vertex buffer (a few MiB) or a burst of frames
# never waits for a WINDOW_UPDATE round trip; h2 sends updates as data is
# acknowledged.
STREAM_WINDOW = 8 << 20
CONNECTION_WINDOW = 64 << 20
MAX_MESSAGE = 64 << 20          # a message larger than this is a broken stream, not an allocation
# Keepalive as the grpc clients' (caveclod.client.session.CHANNEL_OPTIONS): a
# PING after 20 s without a byte from the server, the connection given up
# 10 s later, so that a silent network cut ends in a resume, not a hang.
KEEPALIVE_SECONDS = 20.0
KEEPALIVE_TIMEOUT = 10.0
STATUS_BY_CODE = {code.value[0]: code for code in grpc.StatusCode}


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

    __slots__ = ("conn", "stream_id", "on_message", "on_end", "_buf", "_status", "ended", "_pending")

    def __init__(self, conn: "H2Connection", stream_id: int, on_message: Callable[[bytes], None],
                 on_end: Callable[[grpc.StatusCode, str], None]):
        self.conn, self.stream_id = conn, stream_id
        self.on_message, self.on_end = on_message, on_end
        self._buf = bytearray()
        self._status: tuple | None = None       # (code, details) from headers or trailers
        self.ended = False
        self._pending = bytearray()              # framed messages waiting for flow-control window

    def send(self, message: bytes) -> None:
        """Queue one request message (serialized protobuf); it leaves at the connection's next flush."""
        if self.ended:
            return
        self._pending += b"\x00" + len(message).to_bytes(4, "big") + message
        self.conn._dirty.add(self)

    def close_send(self) -> None:
        """Half-close: no more request messages (gRPC's end of the client stream)."""
        if self.ended:
            return
        self.conn._half_close.add(self)
        self.conn._dirty.add(self)

    def cancel(self) -> None:
        """Reset the stream (CANCEL) and end the call locally as CANCELLED."""
        if self.ended:
            return
        try:
            self.conn.h2.reset_stream(self.stream_id, error_code=h2.errors.ErrorCodes.CANCEL)
        except (h2.exceptions.ProtocolError, h2.exceptions.StreamClosedError):
            pass
        self.conn.flush()
        self._finish(grpc.StatusCode.CANCELLED, "cancelled by the client")

    # -- what the connection hands over --------------------------------------------------
    def _data(self, data: bytes) -> None:
        buf = self._buf
        buf += data
        start = 0
        while len(buf) - start >= 5:
            size = int.from_bytes(buf[start + 1:start + 5], "big")
            if buf[start]:
                self._fail(grpc.StatusCode.INTERNAL, "a compressed message (none was asked for)")
                return
            if size > MAX_MESSAGE:
                self._fail(grpc.StatusCode.RESOURCE_EXHAUSTED, f"a message of {size} bytes (at most {MAX_MESSAGE})")
                return
            if len(buf) - start - 5 < size:
                break
            message = bytes(buf[start + 5:start + 5 + size])
            start += 5 + size
            self.on_message(message)
            if self.ended:
                return
        if start:
            del buf[:start]

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
        if self._buf:
            self._finish(grpc.StatusCode.INTERNAL, f"the stream ended inside a message ({len(self._buf)} bytes)")
        elif self._status is None:
            self._finish(grpc.StatusCode.UNKNOWN, "the stream ended without a grpc-status")
        else:
            self._finish(*self._status)

    def _fail(self, code: grpc.StatusCode, details: str) -> None:
        try:
            self.conn.h2.reset_stream(self.stream_id, error_code=h2.errors.ErrorCodes.CANCEL)
        except (h2.exceptions.ProtocolError, h2.exceptions.StreamClosedError):
            pass
        self._finish(code, details)

    def _finish(self, code: grpc.StatusCode, details: str) -> None:
        if self.ended:
            return
        self.ended = True
        self.conn.calls.pop(self.stream_id, None)
        self.conn._dirty.discard(self)
        self.conn._half_close.discard(self)
        if self.conn.lost is None:       # free our side of the stream too (a no-op when it is closed)
            try:
                self.conn.h2.reset_stream(self.stream_id, error_code=h2.errors.ErrorCodes.NO_ERROR)
            except (h2.exceptions.ProtocolError, h2.exceptions.StreamClosedError):
                pass
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
        config = h2.config.H2Configuration(client_side=True, header_encoding="utf-8",
                                           validate_outbound_headers=False, normalize_outbound_headers=False,
                                           validate_inbound_headers=False, normalize_inbound_headers=False)
        self.h2 = h2.connection.H2Connection(config=config)
        self.transport: asyncio.Transport | None = None
        self.calls: dict[int, H2Call] = {}
        self._dirty: set[H2Call] = set()
        self._half_close: set[H2Call] = set()
        self.lost: str | None = None             # why the connection is gone, once it is
        self._heard = 0.0                        # the loop's time of the last read
        self._spoke_h2 = False                   # the server's SETTINGS arrived
        self._keepalive: asyncio.TimerHandle | None = None
        self.going_away: str | None = None       # why no new call may start (GOAWAY), once so
        self._in_receive = False

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
        self.h2.local_settings = h2.settings.Settings(client=True, initial_values={
            h2.settings.SettingCodes.INITIAL_WINDOW_SIZE: STREAM_WINDOW,
            h2.settings.SettingCodes.ENABLE_PUSH: 0})
        self.h2.initiate_connection()
        self.h2.increment_flow_control_window(CONNECTION_WINDOW - 65535)
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
            self.h2.ping(b"caveclod")
            self.flush()
        self._keepalive = loop.call_later(KEEPALIVE_TIMEOUT / 2, self._check_alive)

    def data_received(self, data: bytes) -> None:
        self._heard = asyncio.get_running_loop().time()
        try:
            events = self.h2.receive_data(data)
        except h2.exceptions.ProtocolError as exc:
            self._lose(f"HTTP/2 protocol error from the server: {exc}")
            self.transport.close()
            return
        self._in_receive = True
        try:
            for event in events:
                self._event(event)
        finally:
            self._in_receive = False
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
        stream_id = self.h2.get_next_available_stream_id()
        call = H2Call(self, stream_id, on_message, on_end)
        if self.lost is not None or self.going_away is not None:
            call._finish(grpc.StatusCode.UNAVAILABLE, self.lost or self.going_away)
            return call
        headers = [(":method", "POST"), (":scheme", "http"), (":path", path), (":authority", self.authority),
                   ("te", "trailers"), ("content-type", "application/grpc"),
                   ("user-agent", "caveclod-loadtest h2")]
        headers += [(k, v) for k, v in metadata]
        try:
            self.h2.send_headers(stream_id, headers)
        except h2.exceptions.TooManyStreamsError:
            call._finish(grpc.StatusCode.UNAVAILABLE, "the server allows no more streams on this connection; "
                         "use more connections (--connections)")
            return call
        self.calls[stream_id] = call
        return call

    def flush(self) -> None:
        """Move the calls' queued messages into HTTP/2 frames (as flow control allows); write them at once."""
        if self.lost is not None:
            return
        if self._dirty:
            for call in list(self._dirty):
                self._send_pending(call)
        out = self.h2.data_to_send()
        if out:
            self.transport.write(out)

    def close(self) -> None:
        """End every call (CANCELLED) and close the socket."""
        if self.transport is not None and self.lost is None:
            try:
                self.h2.close_connection()
                self.transport.write(self.h2.data_to_send())
            except h2.exceptions.ProtocolError:
                pass
            self.transport.close()
        self._lose("the client closed the connection", grpc.StatusCode.CANCELLED)

    # -- internals ----------------------------------------------------------------------------
    def _send_pending(self, call: H2Call) -> None:
        pending = call._pending
        sid = call.stream_id
        try:
            if pending:
                room = min(self.h2.local_flow_control_window(sid), len(pending))
                while room > 0:
                    size = min(room, self.h2.max_outbound_frame_size)
                    self.h2.send_data(sid, bytes(pending[:size]))
                    del pending[:size]
                    room -= size
            if not pending:
                self._dirty.discard(call)
                if call in self._half_close:
                    self._half_close.discard(call)
                    self.h2.end_stream(sid)
        except (h2.exceptions.StreamClosedError, h2.exceptions.ProtocolError):
            pending.clear()
            self._dirty.discard(call)
            self._half_close.discard(call)

    def _event(self, event) -> None:
        sid = getattr(event, "stream_id", None)
        call = self.calls.get(sid) if sid else None
        if isinstance(event, h2.events.DataReceived):
            self.h2.acknowledge_received_data(event.flow_controlled_length, event.stream_id)
            if call is not None:
                call._data(event.data)
        elif isinstance(event, (h2.events.ResponseReceived, h2.events.TrailersReceived)):
            if call is not None:
                call._headers(event.headers)
        elif isinstance(event, h2.events.StreamEnded):
            if call is not None:
                call._stream_ended()
        elif isinstance(event, h2.events.StreamReset):
            if call is not None:
                call._finish(grpc.StatusCode.INTERNAL if event.remote_reset else grpc.StatusCode.CANCELLED,
                             f"Received RST_STREAM with error code {int(event.error_code)}")
        elif isinstance(event, h2.events.WindowUpdated):
            if event.stream_id == 0:
                self._dirty.update(c for c in self.calls.values() if c._pending)
            elif call is not None and call._pending:
                self._dirty.add(call)
        elif isinstance(event, h2.events.RemoteSettingsChanged):
            self._spoke_h2 = True
        elif isinstance(event, h2.events.ConnectionTerminated):
            # GOAWAY: calls up to last_stream_id go on (a draining server
            # finishes them); later ones were never seen, and no new call
            # may start here.
            why = f"the server is going away (GOAWAY, error code {int(event.error_code)})"
            self.going_away = why
            last = event.last_stream_id if event.last_stream_id is not None else 0
            for stream_id, late in list(self.calls.items()):
                if stream_id > last:
                    late._finish(grpc.StatusCode.UNAVAILABLE, why)

    def _lose(self, why: str, code: grpc.StatusCode = grpc.StatusCode.UNAVAILABLE) -> None:
        if self.lost is not None:
            return
        self.lost = why
        if self._keepalive is not None:
            self._keepalive.cancel()
        for call in list(self.calls.values()):
            call._finish(code, why)
