"""The asyncio client: :class:`AsyncClient` and :class:`AsyncSession` (grpc.aio).

    async with AsyncClient("localhost:50051") as client:
        session = await client.session("terrain", cameras=1, width=1280, height=720)
        session.send_pose(0, eye=(5000, -2000, 1500), target=(5000, 5000, 300), up=(0, 0, 1))
        frame = await session.next_frame(timeout=1.0)
        session.buffer(0, material)          # (count, 3) uint32
        await session.close()

Same protocol object and rules as the blocking client (:mod:`.session`):
frames are applied, CRC-checked and acked in ``next_frame``; a broken
stream is resumed with backoff. Sending is a queue put, so ``send_pose``
never blocks the event loop. Many sessions share one event loop (the load
tester runs hundreds).
"""

from __future__ import annotations

import asyncio
import os
import time

import grpc
import grpc.aio

from ..v1 import caveclod_pb2 as pb
from ..v1 import caveclod_pb2_grpc as pb_grpc
from .cache import VertexBufferCache
from .protocol import FrameUpdate, SessionProtocol
from .session import (CHANNEL_OPTIONS, SessionEnded, SessionState, _checked_timeout, backoff, cache_mode, credentials,
                      metadata, refine_options, retriable, try_resume_again)


class AsyncClient:
    """A grpc.aio channel to a LOD server; arguments as :class:`caveclod.client.Client`."""

    def __init__(self, target: str, *, token: str | None = None, tls: bool = False,
                 tls_ca: bytes | str | os.PathLike | None = None, cache_dir=None, server_name: str | None = None):
        creds = credentials(tls, tls_ca)
        options = list(CHANNEL_OPTIONS)
        if server_name:
            options.append(("grpc.ssl_target_name_override", server_name))
        self.channel = grpc.aio.insecure_channel(target, options) if creds is None \
            else grpc.aio.secure_channel(target, creds, options)
        self.stub = pb_grpc.LodStub(self.channel)
        self.metadata = metadata(token)
        self.cache = None if cache_dir is False else VertexBufferCache(cache_dir)
        self.closed = False

    async def list_meshes(self, timeout: float = 10.0) -> list[pb.MeshInfo]:
        """The meshes the server serves (MeshInfo messages, sorted by name)."""
        reply = await self.stub.ListMeshes(pb.ListMeshesRequest(), metadata=self.metadata, timeout=timeout)
        return list(reply.meshes)

    async def session(self, mesh: str, cameras: int = 1, *, width: int = 1280, height: int = 720,
                      fov_y: float | None = None, tolerance_px: float | None = None, cull: bool | None = None,
                      backface: bool | None = None, max_ops: int | None = None, max_faces: int | None = None,
                      ack_window: int = 0, retries: int = 12, timeout: float = 120.0, cache_vertices: int | None = None,
                      cache_strategy: str | None = None, cache_pq_fraction: float | None = None,
                      frame_encoding: str = "ops", vertex_encoding: str = "packed",
                      position_bits: int | None = None, morph_targets: bool = False,
                      prune: bool | None = None, strict_bound: bool | None = None) -> "AsyncSession":
        """Open a session and wait for its vertex buffer (or, in cache mode,
        its SessionInfo); see :meth:`caveclod.client.Client.session`."""
        protocol = SessionProtocol(mesh, cameras, refine_options(width, height, fov_y, tolerance_px, cull,
                                                                 backface, max_ops, max_faces, prune, strict_bound),
                                   cache=self.cache, ack_window=ack_window,
                                   cache_mode=cache_mode(cache_vertices, cache_strategy, cache_pq_fraction),
                                   frame_encoding=frame_encoding, vertex_encoding=vertex_encoding,
                                   position_bits=position_bits, morph_targets=morph_targets)
        session = AsyncSession(self, protocol, retries)
        await session._open(timeout)
        return session

    async def close(self) -> None:
        self.closed = True                    # its sessions' reads end cancelled: they say why
        await self.channel.close()

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, *exc) -> None:
        await self.close()


class _Stream:
    """One grpc.aio stream: requests from a queue, responses read by the session."""

    def __init__(self, stub, first: pb.ClientMessage, md):
        self.requests: asyncio.Queue = asyncio.Queue()
        self.requests.put_nowait(first)
        self.call = stub.Session(self._requests(), metadata=md)

    async def _requests(self):
        while True:
            msg = await self.requests.get()
            if msg is None:
                return
            yield msg

    def send(self, msg: pb.ClientMessage) -> None:
        self.requests.put_nowait(msg)

    def end(self) -> None:
        self.requests.put_nowait(None)
        self.call.cancel()


class AsyncSession(SessionState):
    """An asyncio session. Make one with :meth:`AsyncClient.session`."""

    def __init__(self, client: AsyncClient, protocol: SessionProtocol, retries: int):
        self.client, self.protocol, self.retries = client, protocol, retries
        self._stream: _Stream | None = None
        self._closed = False
        self._read_task: asyncio.Task | None = None      # a read a timed-out next_frame left running

    async def _open(self, timeout: float) -> None:
        if not self.protocol.token and self.client.cache is not None and self.protocol.cache_mode is None:
            try:
                meshes = {m.name: m for m in await self.client.list_meshes(timeout=timeout)}
            except grpc.RpcError as exc:
                raise SessionEnded(exc.code(), exc.details()) from None
            if self.protocol.mesh in meshes:
                self.protocol.offer_vertex_buffer(meshes[self.protocol.mesh].vertex_buffer_hash,
                                                 meshes[self.protocol.mesh].content_hash)
        self._stream = _Stream(self.client.stub, self.protocol.open_message(),
                               self.protocol.metadata(self.client.metadata))
        async def until_ready():
            while not self.protocol.ready:
                await self._receive(resume=False)

        try:
            await asyncio.wait_for(until_ready(), timeout)
        except asyncio.TimeoutError:
            self._stream.end()
            raise SessionEnded(grpc.StatusCode.DEADLINE_EXCEEDED,
                               f"no SessionInfo and vertex buffer within {timeout} s") from None

    async def _resume(self, error) -> None:
        for attempt in range(self.retries):
            await asyncio.sleep(backoff(attempt))
            try:
                self._stream.end()
                await self._open(timeout=10.0)
                return
            except SessionEnded as exc:
                if not try_resume_again(exc):
                    raise self._end(exc) from None
                error = exc
        raise self._end(SessionEnded(grpc.StatusCode.UNAVAILABLE,
                                     f"could not resume after {self.retries} tries: {error}"))

    async def _receive(self, resume: bool = True) -> FrameUpdate | None:
        try:
            msg = await self._stream.call.read()
        except asyncio.CancelledError:
            if not self.client.closed:
                raise                         # the caller's task was cancelled: theirs to handle
            # grpc.aio cancels the reads of a closed channel: a bare CancelledError looked like the
            # caller's own cancellation to asyncio.run and TaskGroups.
            raise self._end(SessionEnded(grpc.StatusCode.CANCELLED, "the client was closed (AsyncClient.close()); "
                                         "open a new client and session")) from None
        except grpc.RpcError as exc:
            code, details = exc.code(), exc.details()
            if resume and retriable(code, details) and self.protocol.token and not self._closed:
                await self._resume(exc)
                return None
            raise self._end(SessionEnded(code, details), final=resume) from None
        if msg is grpc.aio.EOF:
            code = await self._stream.call.code()
            if code == grpc.StatusCode.OK:
                self._closed = True
                raise self._end(SessionEnded(None, "the server ended the session"), final=resume)
            details = await self._stream.call.details()
            if resume and retriable(code, details) and self.protocol.token and not self._closed:
                await self._resume(details)
                return None
            raise self._end(SessionEnded(code, details), final=resume)
        return self._apply(msg)

    async def next_frame(self, timeout: float | None = None) -> FrameUpdate | None:
        """The next frame, applied in full and acked; None when ``timeout`` seconds pass first.

        A timeout may leave a frame half-received; the next call goes on
        with it. Raises SessionEnded when the stream cannot be resumed.
        Without a timeout no timer is armed (a load generator reads
        thousands of frames a second).
        """
        timeout = _checked_timeout(timeout)
        if self._ended is not None:
            self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            read = self._pending_read()
            if deadline is None:
                update = await read
            else:
                # asyncio.wait, not wait_for: a timeout must not cancel the
                # read itself (grpc.aio would end the call). With no time left
                # it still takes what has already arrived (timeout=0 returned
                # None before reading, so a render loop polling so got nothing).
                remaining = max(deadline - time.monotonic(), 0.0)
                done, _ = await asyncio.wait((read,), timeout=remaining)
                if not done:
                    await asyncio.sleep(0)             # a read whose message is here completes now
                    if not read.done():
                        return None
                update = read.result()
            self._read_task = None
            if update is not None:
                return update

    def _pending_read(self) -> asyncio.Task:
        if self._read_task is None:
            self._read_task = asyncio.ensure_future(self._receive())
        return self._read_task

    def begin_close(self, reason: str = "") -> None:
        """Send Close without waiting: the server then ends the stream, and
        a pending :meth:`next_frame` raises SessionEnded with code None."""
        if self._closed or self._stream is None:
            return
        self._closed = True
        self._stream.send(self.protocol.close_message(reason))
        self._stream.requests.put_nowait(None)

    async def close(self, reason: str = "", timeout: float = 5.0) -> None:
        """Send Close and wait (up to ``timeout``) for the server to end the stream."""
        if self._closed or self._stream is None:
            return
        self.begin_close(reason)
        self._ended = SessionEnded(None, "the session was closed (close()); open a new one")
        async def until_end():
            if self._read_task is not None:
                await asyncio.gather(self._read_task, return_exceptions=True)
            while await self._stream.call.read() is not grpc.aio.EOF:
                pass

        try:
            await asyncio.wait_for(until_end(), timeout)
        except (asyncio.TimeoutError, grpc.RpcError):
            self._stream.call.cancel()
