"""The blocking client: :class:`Client` (a channel) and :class:`Session` (a stream).

    with Client("lod.example.org:50051", token="...", tls=True) as client:
        with client.session("terrain", cameras=1, width=1280, height=720) as s:
            s.vertex_buffer.positions            # (d, 3) float32, downloaded once, cached on disk
            s.send_pose(0, eye=(5000, -2000, 1500), target=(5000, 5000, 300), up=(0, 0, 1))
            frame = s.next_frame(timeout=1.0)    # applied, CRC-checked and acked
            s.buffer(0, material)                # (count, 3) uint32 index buffer to draw

A broken stream is resumed with the session token, with exponential
backoff; behind a balancer whose replica is gone, the session goes on as a
fresh one on another replica (``protocol.failovers``: the vertex buffer is
kept, the cameras' latest poses are sent again, frame 1 is a keyframe). A
checksum mismatch or a bad frame asks for a keyframe. A reader thread per
stream receives messages; they are applied in the caller's thread, in
``next_frame``.
"""

from __future__ import annotations

import math
import os
import queue
import random
import threading
import time
import weakref
from dataclasses import dataclass

import grpc

from ..v1 import caveclod_pb2 as pb
from ..v1 import caveclod_pb2_grpc as pb_grpc
from .cache import VertexBufferCache
from .protocol import FrameUpdate, ProtocolError, SessionProtocol, VertexBuffer

# Keepalive: ping an idle connection every 20 s (the server accepts one per
# 10 s) and give up on it after 10 s without an answer, so a dead server or
# a cut network is noticed and the session resumed (the same settings as
# the server's, see caveclod.server.app.grpc_options); frames are at most a
# few MiB.
CHANNEL_OPTIONS = [
    ("grpc.keepalive_time_ms", 20_000),
    ("grpc.keepalive_timeout_ms", 10_000),
    ("grpc.http2.ping_timeout_ms", 10_000),
    ("grpc.http2.max_pings_without_data", 0),
    ("grpc.http2.min_time_between_pings_ms", 20_000),
    ("grpc.max_receive_message_length", 8 << 20),
    # A connection of its own per Client: gRPC otherwise shares one between
    # channels to the same target in a process, and a server of several
    # processes (caveclod serve --processes) spreads connections, not streams.
    ("grpc.use_local_subchannel_pool", 1),
]
RETRIABLE = (grpc.StatusCode.UNAVAILABLE,)     # a broken connection, a draining or restarting server
# What grpc.aio reports, in place of the server's status, when a write races the stream's end
# (the connection reset, the replica died or drained): the status the server sent is lost.
LOCAL_WRITE_RACE = "Internal error from Core"


def retriable(code: grpc.StatusCode | None, details: str | None) -> bool:
    """Whether a stream that ended with (code, details) is worth opening again.

    UNAVAILABLE: the connection broke, or the server drains or restarts. A
    balancer whose replica dies under a stream resets the stream (nginx:
    RST_STREAM INTERNAL_ERROR), which gRPC reports as INTERNAL "Received
    RST_STREAM": the connection to the balancer is fine, the session's
    replica is not. grpc.aio's own INTERNAL "Internal error from Core" (a
    write that raced the stream's end) hides the server's status: retried,
    and a resume the server refuses then says why. An INTERNAL with a
    server's own message is a bug: not retried.
    """
    if code in RETRIABLE:
        return True
    return code == grpc.StatusCode.INTERNAL and ("RST_STREAM" in (details or "") or details == LOCAL_WRITE_RACE)


def try_resume_again(end: "SessionEnded") -> bool:
    """Whether a resume try that ended with ``end`` is followed by the next try: what
    :func:`retriable` allows, and a try that timed out (a server paused by SIGSTOP, a long GC or
    a migrating VM still holds the session, which ended at the first such try before)."""
    return retriable(end.code, end.details) or end.code == grpc.StatusCode.DEADLINE_EXCEEDED


def _checked_timeout(timeout: float | None) -> float | None:
    """A next_frame timeout: None, or seconds; infinite or beyond what the platform can wait is
    None (1e12 raised OverflowError, inf too); NaN is refused (it waited as None, silently)."""
    if timeout is None:
        return None
    timeout = float(timeout)
    if math.isnan(timeout):
        raise ValueError("timeout must be a number of seconds or None, got nan")
    return None if timeout >= threading.TIMEOUT_MAX else timeout


class SessionEnded(Exception):
    """The session's stream ended for good; ``code`` is its gRPC status (None: closed normally)."""

    def __init__(self, code: grpc.StatusCode | None, details: str):
        super().__init__(f"{code.name}: {details}" if code is not None else details)
        self.code, self.details = code, details


def credentials(tls: bool, tls_ca: bytes | str | os.PathLike | None) -> grpc.ChannelCredentials | None:
    """Channel credentials: None for plaintext; TLS trusting ``tls_ca`` (PEM bytes or a path) or the system roots."""
    if not tls and tls_ca is None:
        return None
    if isinstance(tls_ca, (str, os.PathLike)):
        with open(tls_ca, "rb") as fh:
            tls_ca = fh.read()
    return grpc.ssl_channel_credentials(root_certificates=tls_ca)


def metadata(token: str | None) -> tuple:
    """Call metadata carrying ``authorization: Bearer <token>`` when a token is given."""
    return (("authorization", f"Bearer {token}"),) if token else ()


def refine_options(width: int, height: int, fov_y: float | None, tolerance_px: float | None, cull: bool | None,
                   backface: bool | None, max_ops: int | None, max_faces: int | None,
                   prune: bool | None = None, strict_bound: bool | None = None) -> dict:
    """RefineOptions as the dict :mod:`caveclod.wire` takes (None: the server's default)."""
    return {"width": width, "height": height, "fov_y": fov_y, "tolerance_px": tolerance_px, "cull": cull,
            "backface": backface, "max_ops": max_ops, "max_faces": max_faces, "prune": prune,
            "strict_bound": strict_bound}


def cache_mode(cache_vertices: int | None, cache_strategy: str | None, cache_pq_fraction: float | None) -> dict | None:
    """Cache-mode options as SessionProtocol takes them; None (no cache_vertices): a resident vertex buffer."""
    if cache_vertices is None:
        if cache_strategy is not None or cache_pq_fraction is not None:
            raise ValueError("cache_strategy and cache_pq_fraction need cache_vertices (a slot count)")
        return None
    if cache_strategy is not None and cache_strategy not in ("fa", "lru", "lru_pq"):
        raise ValueError(f"unknown cache strategy {cache_strategy!r}; choose one of fa, lru, lru_pq")
    return {"vertices": cache_vertices, "strategy": cache_strategy, "pq_fraction": cache_pq_fraction}


def backoff(attempt: int, base: float = 0.1, cap: float = 2.0) -> float:
    """Seconds to wait before retry ``attempt`` (0, 1, ...): exponential with jitter."""
    return min(cap, base * 2 ** attempt) * random.uniform(0.5, 1.0)


class Client:
    """A channel to a LOD server.

    Args:
        target: "host:port".
        token: bearer token, sent as ``authorization`` metadata.
        tls: connect with TLS (system roots unless ``tls_ca``).
        tls_ca: PEM CA certificate (bytes or path) to trust; implies TLS.
        cache_dir: vertex buffer cache directory (default
            ``$XDG_CACHE_HOME/caveclod/vertex-buffers``); ``False``: no cache.
        server_name: TLS name to check, when it differs from the target's host.
    """

    def __init__(self, target: str, *, token: str | None = None, tls: bool = False,
                 tls_ca: bytes | str | os.PathLike | None = None, cache_dir=None, server_name: str | None = None):
        creds = credentials(tls, tls_ca)
        options = list(CHANNEL_OPTIONS)
        if server_name:
            options.append(("grpc.ssl_target_name_override", server_name))
        self.channel = grpc.insecure_channel(target, options) if creds is None \
            else grpc.secure_channel(target, creds, options)
        self.stub = pb_grpc.LodStub(self.channel)
        self.metadata = metadata(token)
        self.cache = None if cache_dir is False else VertexBufferCache(cache_dir)

    def list_meshes(self, timeout: float = 10.0) -> list[pb.MeshInfo]:
        """The meshes the server serves (MeshInfo messages, sorted by name)."""
        return list(self.stub.ListMeshes(pb.ListMeshesRequest(), metadata=self.metadata, timeout=timeout).meshes)

    def session(self, mesh: str, cameras: int = 1, *, width: int = 1280, height: int = 720,
                fov_y: float | None = None, tolerance_px: float | None = None, cull: bool | None = None,
                backface: bool | None = None, max_ops: int | None = None, max_faces: int | None = None,
                ack_window: int = 0, retries: int = 12, timeout: float = 120.0, cache_vertices: int | None = None,
                cache_strategy: str | None = None, cache_pq_fraction: float | None = None,
                frame_encoding: str = "ops", vertex_encoding: str = "packed",
                position_bits: int | None = None, morph_targets: bool = False,
                prune: bool | None = None, strict_bound: bool | None = None) -> "Session":
        """Open a session and wait for its vertex buffer (from the cache when it holds it).

        Options left None take the server's defaults (60 degrees, 1 px,
        culling on, no back-face culling, no budgets, parts smaller than the
        tolerance hidden: ``prune``; ``strict_bound`` False). Raises SessionEnded
        when the server refuses (e.g. NOT_FOUND, RESOURCE_EXHAUSTED, or
        INVALID_ARGUMENT for a cache too small for the base mesh).

        Cache mode: ``cache_vertices`` slots per camera instead of the vertex
        buffer (``cache_strategy`` ``fa``, ``lru`` or ``lru_pq``, default
        ``lru``; ``cache_pq_fraction`` for ``lru_pq``, default 0.1). Nothing
        is downloaded up front; :meth:`Session.slots` holds each camera's
        vertices and the index buffers hold slot numbers.

        ``timeout``: seconds to wait for SessionInfo and the vertex buffer. A
        server's first Open waits for its kernels; where numba's cache is
        cold (a new machine without ``python -m caveclod.server.warm``) that
        takes about a minute, hence the default of 120.

        ``retries``: how many times a broken stream is opened again (with the
        session's token, backing off from 0.1 s doubling to 2 s, with jitter)
        before SessionEnded: the default rides out 9-17 s without a replica,
        e.g. a restart behind a balancer.

        ``frame_encoding``: ``"ops"`` (the default) asks for op streams, about
        a third of the bytes of ``"raw"`` uint32 writes; ``"linked"`` for op
        streams that also name vertices by their morph targets, about a third
        fewer bytes again, for a download about a byte a vertex larger (the
        targets come with the packed vertex buffer) and 12 bytes a vertex of
        client memory. A server that cannot grant linked answers ops, one
        older than the encoding asked for answers raw; the client reads
        whichever comes.

        ``vertex_encoding``: ``"packed"`` (the default) downloads the vertex
        buffer quantized and deflated (1-7 bytes a vertex against 32;
        ``position_bits`` per position component, default 20: each position
        moves by at most about extent * 2**-bits, SessionInfo's
        vertex_packing.max_position_error says exactly), ``"float32"`` as
        the mesh holds it. Either way :attr:`Session.vertex_buffer` holds float32.
        ``morph_targets`` (packed only) also downloads each vertex's geomorph
        target, for a renderer that morphs splits and collapses
        (:class:`caveclod.client.geomorph.Geomorphs`).

        ``strict_bound``: every original position in view within the
        tolerance of what is drawn, for 10-33 % more faces on terrains
        (RefineOptions.strict_bound; a server older than the field ignores
        it, and SessionInfo.options then leaves it unset).
        """
        protocol = SessionProtocol(mesh, cameras, refine_options(width, height, fov_y, tolerance_px, cull,
                                                                 backface, max_ops, max_faces, prune, strict_bound),
                                   cache=self.cache, ack_window=ack_window,
                                   cache_mode=cache_mode(cache_vertices, cache_strategy, cache_pq_fraction),
                                   frame_encoding=frame_encoding, vertex_encoding=vertex_encoding,
                                   position_bits=position_bits, morph_targets=morph_targets)
        session = Session(self, protocol, retries)
        session._open(timeout)
        return session

    def close(self) -> None:
        self.channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class _StreamEnd:
    error: grpc.RpcError | None


class _Stream:
    """One gRPC stream of a session: a request queue and a reader thread."""

    def __init__(self, stub, first: pb.ClientMessage, md):
        self.requests: queue.Queue = queue.Queue()
        self.responses: queue.Queue = queue.Queue()
        self.requests.put(first)
        self.call = stub.Session(iter(self.requests.get, None), metadata=md)
        threading.Thread(target=self._read, daemon=True, name="caveclod-client-reader").start()

    def _read(self) -> None:
        try:
            for msg in self.call:
                self.responses.put(msg)
            self.responses.put(_StreamEnd(None))
        except grpc.RpcError as exc:
            self.responses.put(_StreamEnd(exc))

    def send(self, msg: pb.ClientMessage) -> None:
        self.requests.put(msg)

    def end(self) -> None:
        """Half-close our side and cancel the call."""
        self.requests.put(None)
        self.call.cancel()


class SessionState:
    """What the blocking and the asyncio sessions share: sending poses and
    keyframe requests, and reading what the client holds (all through
    ``self.protocol``, a :class:`SessionProtocol`, and ``self._stream``)."""

    protocol: SessionProtocol
    _ended: "SessionEnded | None" = None      # set once the session is over: what ended it

    def _check_open(self) -> None:
        """SessionEnded when the session is over (ended, or closed here): calls after that were
        silent (send_pose returned a pose_seq nothing carried) and next_frame() waited for ever."""
        if self._ended is not None:
            raise SessionEnded(self._ended.code, self._ended.details)
        if self._closed:
            raise SessionEnded(None, "the session was closed (close()); open a new one")

    def _end(self, exc: "SessionEnded", final: bool = True) -> "SessionEnded":
        """Remember that ``exc`` ended the session (later calls raise it again), unless it is not
        ``final``: a try of a resume failing, which the next try may mend (recorded so, a session
        resumed at its second try raised the first try's error on every call); returns it."""
        if final:
            self._ended = exc
        return exc

    def send_pose(self, camera: int, eye, target, up=(0.0, 0.0, 1.0)) -> int:
        """Send a camera's new pose (three 3-vectors, world units); returns its pose_seq."""
        self._check_open()
        msg = self.protocol.pose_message(camera, eye, target, up)
        self._stream.send(msg)
        return msg.pose.pose_seq

    def request_keyframe(self, camera: int | None = None,
                         reason: int = pb.KEYFRAME_REASON_CLIENT_RESET, detail: str = "") -> None:
        """Ask for full buffers of ``camera`` (None: every camera), e.g. after losing a GL context."""
        self._check_open()
        self._stream.send(self.protocol.keyframe_message(camera, reason, detail))

    def _apply(self, msg: pb.ServerMessage) -> FrameUpdate | None:
        """Hand one ServerMessage to the protocol and send what it answers; the
        frame it completed, or None. A message that breaks the protocol ends
        the stream with DATA_LOSS."""
        try:
            out, update = self.protocol.receive(msg)
        except ProtocolError as exc:
            self._stream.end()
            raise self._end(SessionEnded(grpc.StatusCode.DATA_LOSS, str(exc))) from None
        for reply in out:
            self._stream.send(reply)
        return update

    def drop(self) -> None:
        """Cancel the stream without Close (as a crash would); the session stays resumable."""
        self._stream.end()

    # -- what the client holds ---------------------------------------------------------------
    @property
    def info(self) -> pb.SessionInfo:
        return self.protocol.info

    @property
    def vertex_buffer(self) -> VertexBuffer | None:
        """The resident vertex buffer; None in cache mode."""
        return self.protocol.vertex

    def slots(self, camera: int):
        """Cache mode: camera's :class:`~caveclod.client.slots.SlotBuffer` (the vertices its buffers index)."""
        if self.protocol.slots is None:
            raise ValueError("slots() is for cache mode; this session holds the whole vertex buffer (vertex_buffer)")
        return self.protocol.slots[camera]

    @property
    def buffers(self):
        """The :class:`~caveclod.client.buffers.IndexBuffers`."""
        return self.protocol.buffers

    def buffer(self, camera: int, material: int):
        """(count, 3) uint32 index buffer of one (camera, material), to draw."""
        return self.protocol.buffers.buffer(camera, material)

    def triangles(self, camera: int) -> dict:
        """{material: (k, 3) uint32} copies of a camera's non-empty buffers."""
        return self.protocol.buffers.triangles(camera)


class Session(SessionState):
    """A blocking session. Make one with :meth:`Client.session`.

    Attributes:
        protocol: the :class:`SessionProtocol` (info, counters).
        vertex_buffer: the :class:`VertexBuffer`.
    """

    def __init__(self, client: Client, protocol: SessionProtocol, retries: int):
        self.client, self.protocol, self.retries = client, protocol, retries
        self._stream: _Stream | None = None
        self._closed = False
        self._finalizer: weakref.finalize | None = None

    # -- opening and resuming ----------------------------------------------------------
    def _open(self, timeout: float) -> None:
        """Start a stream (new or resumed) and receive until the vertex buffer is complete."""
        if not self.protocol.token and self.client.cache is not None and self.protocol.cache_mode is None:
            try:
                meshes = {m.name: m for m in self.client.list_meshes(timeout=timeout)}
            except grpc.RpcError as exc:
                raise SessionEnded(exc.code(), exc.details()) from None
            if self.protocol.mesh in meshes:
                self.protocol.offer_vertex_buffer(meshes[self.protocol.mesh].vertex_buffer_hash,
                                                 meshes[self.protocol.mesh].content_hash)
        deadline = time.monotonic() + timeout
        self._stream = _Stream(self.client.stub, self.protocol.open_message(),
                               self.protocol.metadata(self.client.metadata))
        # A session dropped without close() ends its stream when it is collected: the reader
        # thread holds the call, which stayed open for the life of the process, and the server
        # kept the session (and one of its --max-sessions slots) attached.
        if self._finalizer is not None:
            self._finalizer.detach()
        self._finalizer = weakref.finalize(self, _Stream.end, self._stream)
        self._finalizer.atexit = False        # at exit the process ends the stream itself
        while not self.protocol.ready:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._stream.end()
                raise SessionEnded(grpc.StatusCode.DEADLINE_EXCEEDED,
                                   f"no SessionInfo and vertex buffer within {timeout} s")
            self._receive(remaining, resume=False)

    def _resume(self, error: grpc.RpcError) -> None:
        """Reopen the stream with the session token, backing off between tries."""
        for attempt in range(self.retries):
            time.sleep(backoff(attempt))
            try:
                self._stream.end()
                self._open(timeout=10.0)
                return
            except SessionEnded as exc:
                if not try_resume_again(exc):
                    raise self._end(exc) from None
                error = exc
        raise self._end(SessionEnded(grpc.StatusCode.UNAVAILABLE,
                                     f"could not resume after {self.retries} tries: {error}"))

    # -- receiving ------------------------------------------------------------------------
    def _receive(self, timeout: float | None, resume: bool = True) -> FrameUpdate | None:
        """Handle one message from the stream; the frame it completed, if any."""
        try:
            item = self._stream.responses.get(timeout=None if timeout is None else max(timeout, 0.0))
        except queue.Empty:
            return None
        if isinstance(item, _StreamEnd):
            if item.error is None:
                self._closed = True
                raise self._end(SessionEnded(None, "the server ended the session"), final=resume)
            code, details = item.error.code(), item.error.details()
            if resume and retriable(code, details) and self.protocol.token and not self._closed:
                self._resume(item.error)
                return None
            raise self._end(SessionEnded(code, details), final=resume)
        return self._apply(item)

    def next_frame(self, timeout: float | None = None) -> FrameUpdate | None:
        """The next frame, applied in full and acked; None when ``timeout`` seconds pass first
        (``timeout=0``: None unless a frame has already arrived).

        Raises SessionEnded when the stream ends and cannot be resumed, and again on every call
        after (and after close()). A timeout that is infinite or longer than the platform can
        wait (``threading.TIMEOUT_MAX``) waits as None does.
        """
        timeout = _checked_timeout(timeout)
        if self._ended is not None:
            self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            # timeout=0 still takes what has already arrived (a render loop polls so).
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            update = self._receive(remaining)
            if update is not None:
                return update
            if deadline is not None and time.monotonic() >= deadline:
                return None

    # -- sending --------------------------------------------------------------------------
    def close(self, reason: str = "", timeout: float = 5.0) -> None:
        """Send Close and wait (up to ``timeout``) for the server to end the stream."""
        if self._closed or self._stream is None:
            return
        if self._ended is not None:
            # Over already (its end was raised to the caller): no stream end is left to wait for,
            # and closing such a session waited out the whole timeout (5 s a `with` block).
            self._closed = True
            self._stream.end()
            return
        self._closed = True
        self._stream.send(self.protocol.close_message(reason))
        self._stream.requests.put(None)
        self._ended = SessionEnded(None, "the session was closed (close()); open a new one")
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                item = self._stream.responses.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                break
            if isinstance(item, _StreamEnd):
                return
        self._stream.call.cancel()

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
