"""Sessions over :mod:`.h2wire`: the load generator's callback-driven client.

:class:`H2Session` drives the same sans-IO :class:`~.protocol.SessionProtocol`
as the blocking and asyncio clients (so frames are applied, CRC-checked and
acked exactly alike), but nothing awaits per message: the connection calls
:meth:`H2Session._message` for each ServerMessage as it is read, the
protocol's answers are queued on the call, and the connection writes them
with everything else it has at the end of the read. A broken stream is
resumed with the session token, with backoff, on a new connection when the
old one is gone; a pose sent meanwhile is kept by the protocol and sent
again on the new stream.

    target = H2Target("127.0.0.1", 50051)
    session = H2Session(target, protocol, metadata, on_frame=..., on_end=...)
    session.open()                  # then: await session.ready
    session.send_pose(0, eye, target, up); target.flush()
"""

from __future__ import annotations

import asyncio
from typing import Callable

import grpc
from google.protobuf.message import DecodeError

from ..v1 import caveclod_pb2 as pb
from .h2wire import CallEnded, H2Call, H2Connection
from .protocol import FrameUpdate, ProtocolError, SessionProtocol
from .session import SessionEnded, backoff, retriable

SESSION_PATH = "/caveclod.v1.Lod/Session"
LIST_MESHES_PATH = "/caveclod.v1.Lod/ListMeshes"


class H2Target:
    """A server address and its current connection, made again when it is lost or going away."""

    def __init__(self, host: str, port: int):
        self.host, self.port = host, port
        self.conn: H2Connection | None = None
        self._connecting: asyncio.Future | None = None

    @classmethod
    def parse(cls, target: str) -> "H2Target":
        """``host:port`` (``[v6]:port`` for IPv6)."""
        host, sep, port = target.rpartition(":")
        if not sep or not port.isdigit():
            raise ValueError(f"target {target!r}: expected host:port")
        return cls(host.strip("[]") or "127.0.0.1", int(port))

    async def connection(self) -> H2Connection:
        """The connection, opened (once, for every caller waiting) when there is none usable."""
        if self.conn is not None and self.conn.usable:
            return self.conn
        if self._connecting is None:
            self._connecting = asyncio.ensure_future(H2Connection.connect(self.host, self.port))
        try:
            conn = await asyncio.shield(self._connecting)
        finally:
            if self._connecting is not None and self._connecting.done():
                self._connecting = None
        self.conn = conn
        return conn

    def flush(self) -> None:
        """Write what the calls on the connection queued, in one write."""
        if self.conn is not None:
            self.conn.flush()

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()

    async def unary(self, path: str, request: bytes, metadata=(), timeout: float = 10.0) -> bytes:
        """One unary call's reply (serialized); raises CallEnded when it ends without one."""
        conn = await self.connection()
        done: asyncio.Future = asyncio.get_running_loop().create_future()
        reply: list[bytes] = []

        def ended(code, details):
            if not done.done():
                done.set_result((code, details))
        call = conn.start_call(path, metadata, reply.append, ended)
        call.send(request)
        call.close_send()
        conn.flush()
        try:
            code, details = await asyncio.wait_for(done, timeout)
        except asyncio.TimeoutError:
            call.cancel()
            raise CallEnded(grpc.StatusCode.DEADLINE_EXCEEDED, f"no answer to {path} within {timeout} s") from None
        if code != grpc.StatusCode.OK or len(reply) != 1:
            raise CallEnded(code if code != grpc.StatusCode.OK else grpc.StatusCode.INTERNAL,
                            details if code != grpc.StatusCode.OK else f"{len(reply)} replies to a unary call")
        return reply[0]


async def list_meshes(target: H2Target, metadata=(), timeout: float = 10.0) -> list[pb.MeshInfo]:
    """The server's meshes (MeshInfo), as :meth:`caveclod.client.Client.list_meshes`."""
    reply = await target.unary(LIST_MESHES_PATH, pb.ListMeshesRequest().SerializeToString(), metadata, timeout)
    return list(pb.ListMeshesResponse.FromString(reply).meshes)


class H2Session:
    """One caveclod.v1 session on an :class:`H2Target`, driven by callbacks.

    Args:
        target: where to open (and resume) it.
        protocol: its :class:`SessionProtocol`.
        metadata: call metadata ((key, value) pairs, e.g. the token's).
        on_frame: called with every :class:`FrameUpdate` applied in full.
        on_end: called once with a :class:`SessionEnded` (code None: our
            Close was answered) when the session is over for good.
        retries: resume attempts after a stream breaks.
    """

    def __init__(self, target: H2Target, protocol: SessionProtocol, metadata=(), *,
                 on_frame: Callable[[FrameUpdate], None], on_end: Callable[[SessionEnded], None], retries: int = 12):
        self.target, self.protocol, self.retries = target, protocol, retries
        self.metadata = tuple(metadata)
        self.on_frame, self.on_end = on_frame, on_end
        self.call: H2Call | None = None
        self.ready: asyncio.Future = asyncio.get_running_loop().create_future()   # the first SessionInfo and buffer
        self.closing = False
        self.over = False
        self._attempt = 0
        self._broken: tuple | None = None   # (code, details) of a break not yet resumed

    # -- what the user does ------------------------------------------------------------
    async def open(self) -> None:
        """Start the stream (the first Open, or a resume's)."""
        try:
            conn = await self.target.connection()
        except CallEnded as exc:
            self._ended(exc.code, exc.details)
            return
        self.call = conn.start_call(SESSION_PATH, self.protocol.metadata(self.metadata), self._message, self._ended)
        self.call.send(self.protocol.open_message().SerializeToString())
        conn.flush()

    def send_pose(self, camera: int, eye, target, up) -> None:
        """Queue a camera's pose (sent at the target's next flush). While the
        stream is being resumed the protocol keeps it and sends it again."""
        msg = self.protocol.pose_message(camera, eye, target, up)
        if self.call is not None and not self.call.ended and self.protocol.ready:
            self.call.send(msg.SerializeToString())

    def begin_close(self, reason: str = "") -> None:
        """Send Close; the server then ends the stream and ``on_end`` gets code None."""
        if self.closing or self.over:
            return
        self.closing = True
        if self.call is None or self.call.ended:
            # Closed while a resume is due: the break is what ended it (a load test whose
            # server died within the retries' 9-17 s counted no error and exited 0).
            code, details = self._broken or (None, "")
            self._over(SessionEnded(code, f"{details}; not resumed when it was closed" if code else
                                    "closed while not connected"))
            return
        self.call.send(self.protocol.close_message(reason).SerializeToString())
        self.call.close_send()

    def cancel(self) -> None:
        """End the stream without Close (a crash, as the server sees it)."""
        if self.call is not None:
            self.call.cancel()

    # -- what the connection calls -------------------------------------------------------
    def _message(self, data: bytes) -> None:
        try:
            msg = pb.ServerMessage.FromString(data)
        except DecodeError as exc:          # a message that does not parse: the stream is broken
            self.call._fail(grpc.StatusCode.DATA_LOSS, f"a ServerMessage that does not parse: {exc}")
            return
        try:
            out, update = self.protocol.receive(msg)
        except ProtocolError as exc:        # as the library's sessions: the stream ends with DATA_LOSS
            self.call._fail(grpc.StatusCode.DATA_LOSS, str(exc))
            return
        for reply in out:
            self.call.send(reply.SerializeToString())
        if self.protocol.ready:
            self._attempt, self._broken = 0, None
            if not self.ready.done():
                self.ready.set_result(None)
        if update is not None:
            self.on_frame(update)

    def _ended(self, code: grpc.StatusCode, details: str) -> None:
        if self.over:
            return
        if code == grpc.StatusCode.OK:
            self._over(SessionEnded(None, "the server ended the session" if not self.closing else details))
        elif (not self.closing and self.protocol.token and retriable(code, details)
              and self._attempt < self.retries):
            delay = backoff(self._attempt)
            self._attempt += 1
            self._broken = (code, details)
            asyncio.get_running_loop().call_later(delay, lambda: asyncio.ensure_future(self.open()))
        elif self.closing:
            self._over(SessionEnded(None, f"closed ({code.name}: {details})"))
        else:
            self._over(SessionEnded(code, details))

    def _over(self, end: SessionEnded) -> None:
        self.over = True
        if not self.ready.done():
            self.ready.set_exception(end)
            self.ready.exception()          # retrieved: the end is reported through on_end
        self.on_end(end)
