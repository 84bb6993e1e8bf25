"""The client's side of a caveclod.v1 session, without any I/O ("sans-IO").

:class:`SessionProtocol` turns ServerMessages into updated index buffers and
says what to send back (acks, keyframe requests); it numbers poses and
times each pose -> frame by pose_seq; it remembers what a resume needs.
The blocking (:mod:`.session`) and asyncio (:mod:`.aio`) APIs drive it over
a gRPC stream, so both behave exactly alike.

In cache mode (``cache_mode``: the proto's Open.cache_vertices) there is no
vertex buffer: each camera has N slots (:class:`.slots.SlotBuffer`) that the
frames write, the index buffers hold slot numbers, and every frame is
checked for slots checksums and for triangles that use a slot holding no
vertex (a bad frame: a keyframe is asked for).
"""

from __future__ import annotations

import secrets
import time
import zlib
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .. import opstream, vertexpack, wire
from ..v1 import caveclod_pb2 as pb
from .buffers import IndexBuffers
from .cache import VertexBufferCache
from .slots import SlotBuffer

CLIENT_NAME = "caveclod-client/0.1"
# Call metadata sent on every Session call of a session, its first Open and
# every resume: a random key of the session, so that a balancer that hashes
# on it (deploy/nginx/caveclod.conf.template) sends a resume to the replica
# that holds the session. The session token cannot serve: the replica that
# opens a session makes it, after the balancer has chosen that replica.
AFFINITY_HEADER = "x-caveclod-session"
FRAME_ENCODINGS = {"ops": pb.FRAME_ENCODING_OPS, "linked": pb.FRAME_ENCODING_OPS_LINKED, "raw": pb.FRAME_ENCODING_RAW}
VERTEX_ENCODINGS = {"packed": pb.VERTEX_ENCODING_PACKED, "float32": pb.VERTEX_ENCODING_FLOAT32}
# Links of the vertex buffers this process reads linked op streams for, by hash
# (oldest first): a load test's hundred sessions of one mesh build them once.
_LINKS: dict = {}
LINKS_KEPT = 4


class ProtocolError(Exception):
    """The server broke caveclod.v1 in a way no keyframe repairs (one line)."""


@dataclass
class VertexBuffer:
    """The mesh's vertex buffer, resident for the whole session.

    Attributes:
        hash: its vertex_buffer_hash.
        payload: the planar payload, read-only: a memoryview of the
            downloaded (or decoded) bytes, or bytes.
        positions: (d, 3) float32 view. normals: (d, 3) float32.
        uvs: (d, 2) float32. colors: (d, 4) uint8, or None.
        morph_targets: (d,) uint32 geomorph targets (each vertex's own index
            where it has none), or None when not asked for or not sent.
    """

    hash: str
    payload: bytes | memoryview
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    colors: np.ndarray | None
    morph_targets: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return len(self.positions)

    @cached_property
    def links(self) -> opstream.Links:
        """What FRAME_ENCODING_OPS_LINKED streams are read with: made once per buffer
        (hash), shared by the sessions of this process that hold it; ProtocolError
        without morph targets."""
        if self.morph_targets is None:
            raise ProtocolError("the server sends FRAME_ENCODING_OPS_LINKED frames, but the vertex buffer came "
                                "without morph targets; open with frame_encoding 'ops'")
        links = _LINKS.get(self.hash)
        if links is None or links.n_vertices != self.n_vertices:
            links = _LINKS[self.hash] = opstream.Links(self.morph_targets)
            while len(_LINKS) > LINKS_KEPT:
                del _LINKS[next(iter(_LINKS))]
        return links


@dataclass
class CameraUpdate:
    """What one frame did to one camera.

    Attributes:
        pose_seq: the pose the camera is now refined for (0: none).
        keyframe: the frame replaced the camera's buffers.
        latency: seconds from sending pose_seq to this frame, when this
            frame is the first to answer it; else None.
        stats: CameraStats of the server's update, or None.
        triangles_written: slot writes applied.
        vertices_written: cache mode: vertices written into slots.
        vertex_bytes: cache mode: bytes of the VertexWrites (slots and data).
        surfaces: the :class:`caveclod.wire.Surface` writes applied to the
            camera's buffers, in order (after emptying them, on a keyframe):
            a renderer applies the same to its GPU buffers to mirror them.
        vertex_writes: cache mode: the decoded :class:`caveclod.wire.SlotWrites`,
            in the order applied (before the surfaces; a keyframe empties
            every slot first).
    """

    pose_seq: int
    keyframe: bool = False
    latency: float | None = None
    stats: pb.CameraStats | None = None
    triangles_written: int = 0
    vertices_written: int = 0
    vertex_bytes: int = 0
    surfaces: list = field(default_factory=list)
    vertex_writes: list = field(default_factory=list)


@dataclass
class FrameUpdate:
    """A frame applied in full (all its parts).

    Attributes:
        frame_seq: its number.
        pose_seq: the highest pose_seq the server had received when it made
            the frame: every pose up to it is answered or superseded.
        cameras: {camera: CameraUpdate} for the cameras it carried.
        nbytes: serialized bytes of its parts.
        parts: how many Frame messages it came in.
        diverged: cameras whose buffers failed a CRC check (a keyframe is asked for).
        bad: cameras whose deltas could not be applied (a keyframe is asked for).
    """

    frame_seq: int
    pose_seq: int = 0
    cameras: dict = field(default_factory=dict)
    nbytes: int = 0
    parts: int = 0
    diverged: list = field(default_factory=list)
    bad: list = field(default_factory=list)


UINT32_MAX = 2 ** 32 - 1
"""The largest count a uint32 field of Open carries: a larger one raised protobuf's bare "Value out
of range" (a traceback in render, view and loadtest)."""

MAX_CACHE_VERTICES = UINT32_MAX
"""The most slots Open.cache_vertices carries; a larger count is sent as this, and the server clamps
it to the mesh's vertex count as it clamps any count above that."""


def _whole(value) -> bool:
    """Whether ``value`` is a whole number as the protocol's counts and camera numbers take it: an
    int or numpy integer, not a bool (True would pass as camera 1)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


class SessionProtocol:
    """One session's client state across its streams.

    Args:
        mesh: mesh name. cameras: camera count.
        options: RefineOptions as a dict (see :func:`caveclod.wire.options_to_dict`).
        cache: vertex buffer cache, or None for none.
        ack_window: the window asked for (0: the server's default).
        client: name sent in Open.
        cache_mode: ``{vertices, strategy, pq_fraction}`` to ask for cache
            mode (strategy a name, or None for the server's default), or None
            for a resident vertex buffer.
        frame_encoding: ``"ops"`` (op streams, under a third of the bytes; the
            default), ``"linked"`` (op streams that also name vertices by their
            morph targets, a third smaller again; asks for the morph targets,
            about a byte a vertex more to download) or ``"raw"`` (uint32
            arrays) to ask for in Open.
        vertex_encoding: ``"packed"`` (the vertex buffer downloads quantized
            and deflated, 1-7 bytes a vertex; the default) or ``"float32"``
            (32 bytes a vertex, exact). Cache mode ignores it.
        position_bits: bits per position component when packed (8 to 24;
            None: the server's 20).
        morph_targets: packed only: ask for each vertex's geomorph target
            (:attr:`VertexBuffer.morph_targets`), for a renderer that morphs.
    """

    def __init__(self, mesh: str, cameras: int, options: dict, *, cache: VertexBufferCache | None = None,
                 ack_window: int = 0, client: str = CLIENT_NAME, cache_mode: dict | None = None,
                 frame_encoding: str = "ops", vertex_encoding: str = "packed", position_bits: int | None = None,
                 morph_targets: bool = False):
        # Checked here, named: protobuf's own refusal of -1 said "Value out of range: -1" only.
        if not _whole(cameras) or cameras < 1:
            raise ValueError(f"cameras must be a whole number from 1, got {cameras!r}")
        slots = (cache_mode or {}).get("vertices")
        if slots is not None and (not _whole(slots) or slots < 1):
            raise ValueError(f"cache_vertices must be a whole number from 1 (slots per camera), got {slots!r}")
        if slots is not None and slots > MAX_CACHE_VERTICES:
            cache_mode = {**cache_mode, "vertices": MAX_CACHE_VERTICES}
        if frame_encoding not in FRAME_ENCODINGS:
            raise ValueError(f"frame_encoding {frame_encoding!r}: use one of {', '.join(FRAME_ENCODINGS)}")
        if vertex_encoding not in VERTEX_ENCODINGS:
            raise ValueError(f"vertex_encoding {vertex_encoding!r}: use one of {', '.join(VERTEX_ENCODINGS)}")
        if position_bits is not None:
            vertexpack.check_position_bits(position_bits)
        self.frame_encoding, self.vertex_encoding, self.position_bits = frame_encoding, vertex_encoding, position_bits
        self.morph_targets = (bool(morph_targets) or frame_encoding == "linked") and vertex_encoding == "packed"
        self.mesh, self.n_cameras, self.options = mesh, cameras, dict(options)
        if not _whole(ack_window) or ack_window < 0:
            raise ValueError(f"ack_window must be a whole number from 0 (0: the server's default), got {ack_window!r}")
        # The server clamps a request to 1..32; past UINT32_MAX the wire cannot carry it.
        self.cache, self.ack_window, self.client = cache, min(int(ack_window), UINT32_MAX), client
        self.cache_mode = dict(cache_mode) if cache_mode is not None else None
        self.slots: list[SlotBuffer] | None = None     # cache mode: each camera's slots
        self.info: pb.SessionInfo | None = None
        self.ready = False               # this stream's SessionInfo and vertex buffer have arrived
        self.token = ""
        self.vertex: VertexBuffer | None = None
        self.buffers: IndexBuffers | None = None
        self.last_applied = 0            # frame_seq of the last frame applied in full
        self.last_acked = 0              # frame_seq of the last Ack sent
        self._ack_due = 0                # an ack waiting for the next pose to carry it (acks_on_poses)
        self.pose_seq = 0                # last pose_seq sent
        self.divergences = 0             # CRC mismatches found
        self.bad_frames = 0
        self.resumes = 0
        self.epoch = 0                   # +1 whenever the index buffers start over (a new session)
        self.failovers = 0               # broken streams that came back as a fresh session (replica gone, or expired)
        self.affinity_key = secrets.token_hex(16)
        self._known_hash = ""            # vertex_buffer_hash to offer in Open
        self._offered = None             # (hash, (payload, crc)) the cache gave when it was offered
        self._chunks: bytearray | None = None
        self._sent: list[dict] = [{} for _ in range(cameras)]      # camera -> {pose_seq: send time}
        self._answered = [0] * cameras
        self._latest: list[tuple | None] = [None] * cameras        # (eye, target, up) last sent
        self._asked: set[int] = set()    # cameras with a keyframe request outstanding
        self._frame: FrameUpdate | None = None                      # the frame whose parts are arriving
        self._crcs: dict = {}
        self._sums: dict = {}            # cache mode: camera -> slots checksum the frame announced
        self._used: dict = {}            # cache mode: camera -> slot arrays the frame's triangles use
        self._untrusted: set[int] = set()

    # -- what to send ------------------------------------------------------------------
    def metadata(self, base: tuple = ()) -> tuple:
        """Call metadata of this session's Session calls: ``base`` plus the affinity key."""
        return (*base, (AFFINITY_HEADER, self.affinity_key))

    def offer_vertex_buffer(self, vertex_buffer_hash: str, content_hash: str = "") -> bool:
        """Offer a cached buffer in the next Open when the cache holds ``vertex_buffer_hash``
        (MeshInfo's; when the buffer travels packed, the key of its decoded form, which with
        morph targets takes MeshInfo's ``content_hash`` too)."""
        if self.vertex_encoding == "packed" and vertex_buffer_hash and self.cache_mode is None:
            vertex_buffer_hash = vertexpack.packed_hash(vertex_buffer_hash,
                                                        self.position_bits or vertexpack.DEFAULT_POSITION_BITS,
                                                        self.morph_targets, content_hash)
        if self.vertex is not None and self.vertex.hash == vertex_buffer_hash:
            self._known_hash = vertex_buffer_hash
        elif self.cache is not None and vertex_buffer_hash:
            # The payload is kept from the offer to the SessionInfo: looked up again then, it
            # could be gone (other sessions' downloads pushed it out of the cache's memory and
            # its file had been deleted), and the server, told we hold it, sends none.
            found = self.cache.lookup(vertex_buffer_hash)
            if found is not None:
                self._known_hash, self._offered = vertex_buffer_hash, (vertex_buffer_hash, found)
        return bool(self._known_hash)

    def open_message(self) -> pb.ClientMessage:
        """Open for a new session, or for a resume once a token is known."""
        if self.vertex is not None:
            self._known_hash = self.vertex.hash
        self.ready = False
        msg = pb.Open(mesh=self.mesh, options=wire.options_from_dict(self.options), cameras=self.n_cameras,
                      vertex_buffer_hash=self._known_hash, resume_token=self.token, last_frame_seq=self.last_applied,
                      ack_window=self.ack_window, client=self.client,
                      frame_encoding=FRAME_ENCODINGS[self.frame_encoding],
                      vertex_encoding=VERTEX_ENCODINGS[self.vertex_encoding], morph_targets=self.morph_targets)
        if self.position_bits is not None:
            msg.position_bits = self.position_bits
        wire.set_cache_options(msg, self.cache_mode)
        return pb.ClientMessage(open=msg)

    def pose_message(self, camera: int, eye, target, up, now: float | None = None) -> pb.ClientMessage:
        """A CameraPose with the next pose_seq; its send time is kept for the latency."""
        # Everything checked before anything changes: a pose refused here was kept as the camera's
        # latest and resent on a resume, where its error came out of next_frame and the session
        # did not recover (and a refused pose used up a pose_seq).
        if not _whole(camera):
            raise TypeError(f"camera must be an int (0..{self.n_cameras - 1}), got {camera!r}")
        if not 0 <= camera < self.n_cameras:
            raise ValueError(f"camera {camera} out of range 0..{self.n_cameras - 1}")
        vectors = dict(eye=wire.vec3(eye), target=wire.vec3(target), up=wire.vec3(up))
        camera = int(camera)
        self.pose_seq += 1
        self._sent[camera][self.pose_seq] = time.perf_counter() if now is None else now
        self._latest[camera] = (eye, target, up)
        pose = pb.CameraPose(camera=camera, pose_seq=self.pose_seq, **vectors)
        if self._ack_due > self.last_acked:        # the pose carries the ack (SessionInfo.acks_on_poses)
            pose.ack_frame_seq = self.last_acked = self._ack_due
        return pb.ClientMessage(pose=pose)

    def keyframe_message(self, camera: int | None, reason: int, detail: str = "") -> pb.ClientMessage:
        """A KeyframeRequest for ``camera`` (None: all); remembered so it is not repeated."""
        if camera is not None and (not _whole(camera) or not 0 <= camera < self.n_cameras):
            # Sent, a camera out of range ended the whole session (INVALID_ARGUMENT, raised later by
            # next_frame); -1 was protobuf's bare "Value out of range".
            raise ValueError(f"camera {camera!r} is not one of this session's 0..{self.n_cameras - 1}")
        req = pb.KeyframeRequest(reason=reason, frame_seq=self.last_applied, detail=detail[:200])
        if camera is None:
            self._asked.update(range(self.n_cameras))
        else:
            req.camera = camera
            self._asked.add(camera)
        return pb.ClientMessage(keyframe_request=req)

    def close_message(self, reason: str = "") -> pb.ClientMessage:
        return pb.ClientMessage(close=pb.Close(reason=reason))

    # -- what arrives ------------------------------------------------------------------
    def receive(self, msg: pb.ServerMessage) -> tuple[list[pb.ClientMessage], FrameUpdate | None]:
        """Handle one ServerMessage: (messages to send back, the frame it completed or None)."""
        kind = msg.WhichOneof("kind")
        if kind == "session_info":
            return self._session_info(msg.session_info), None
        if kind == "vertex_chunk":
            self._vertex_chunk(msg.vertex_chunk)
            return [], None
        if kind == "frame":
            return self._frame_part(msg.frame, msg.ByteSize())
        raise ProtocolError("a ServerMessage with nothing set; the server speaks another protocol version")

    def _session_info(self, info: pb.SessionInfo) -> list[pb.ClientMessage]:
        if info.vertex_format.layout not in (pb.VERTEX_LAYOUT_PLANAR, pb.VERTEX_LAYOUT_INTERLEAVED):
            raise ProtocolError(f"vertex layout {info.vertex_format.layout} is unknown to this client; upgrade it")
        if (self.cache_mode is not None) != (info.cache_vertices > 0):
            raise ProtocolError("this client asked for cache mode and the server answered without it (a server "
                                "older than cache mode); upgrade the server" if self.cache_mode is not None else
                                "the server answered with cache mode, which this client did not ask for")
        resumed = info.resumed and self.info is not None
        if self.info is not None:
            self.resumes += resumed
            self.failovers += not resumed
        self.info, self.token = info, info.session_token
        materials = len(info.mesh.materials)
        if not resumed:
            # A new session (the first, or a failover: the old one expired or its
            # replica is gone): start from nothing. Poses keep numbering upward: an
            # asyncio client may have sent some on the new stream before this
            # SessionInfo, and restarting from 1 would go back past them.
            self.buffers = IndexBuffers(self.n_cameras, materials)
            self.epoch += 1
            self.last_applied = 0
            self._asked.clear()
            self._answered = [0] * self.n_cameras
            self._sent = [{} for _ in range(self.n_cameras)]
            if info.cache_vertices:
                try:
                    self.slots = [SlotBuffer(info.cache_vertices, info.vertex_format) for _ in range(self.n_cameras)]
                except wire.WireError as exc:
                    raise ProtocolError(str(exc)) from None
        elif info.last_frame_seq > self.last_applied:
            # Frames went out on the broken stream that never arrived: the server
            # sends a keyframe of every camera, numbered on from its last frame.
            self.last_applied = info.last_frame_seq
        self.last_acked = self.last_applied   # the server restarts its window at every SessionInfo
        self._ack_due = 0
        self._frame = None
        self.pose_seq = max(self.pose_seq, info.last_pose_seq)
        out = []
        if info.cache_vertices:
            self.ready = True                  # no vertex buffer: frames follow at once
        elif info.vertex_buffer_cached:
            self._use_cached(info)
        else:
            self._chunks = bytearray()
            if self._download_bytes() == 0:
                self._finish_vertex_buffer()
        self._offered = None                   # used or not, the offer is answered: let its bytes go
        # Poses in flight when the stream broke are lost: send each camera's latest
        # again. A fresh session has none of them: send every camera's latest.
        for c, pose in enumerate(self._latest):
            if pose is not None and (not resumed or (self._sent[c] and max(self._sent[c]) > info.last_pose_seq)):
                self._sent[c].clear()
                out.append(self.pose_message(c, *pose))
        return out

    def _buffer_key(self) -> str:
        """The vertex buffer's cache key: MeshInfo's, or VertexPacking's when it travels packed."""
        info = self.info
        return info.vertex_packing.vertex_buffer_hash if info.HasField("vertex_packing") else \
            info.mesh.vertex_buffer_hash

    def _download_bytes(self) -> int:
        """Bytes the VertexChunks carry in all."""
        info = self.info
        return info.vertex_packing.packed_bytes if info.HasField("vertex_packing") else \
            info.vertex_format.payload_bytes

    def _use_cached(self, info: pb.SessionInfo) -> None:
        key = self._buffer_key()
        if self.vertex is not None and self.vertex.hash == key:
            payload, crc = self.vertex.payload, zlib.crc32(self.vertex.payload)
        elif self._offered is not None and self._offered[0] == key:
            payload, crc = self._offered[1]
        else:
            payload, crc = (self.cache.lookup(key) if self.cache is not None else None) or (None, None)
        if payload is None or crc != info.vertex_payload_crc32:
            if self.cache is not None:
                self.cache.discard(key)
            raise ProtocolError(f"the server took vertex buffer {key} as cached, but this client does not hold it "
                                "intact; open the session again without a cached buffer")
        self._set_vertex(key, payload)

    def _vertex_chunk(self, chunk: pb.VertexChunk) -> None:
        if self._chunks is None or chunk.offset != len(self._chunks) or chunk.total != self._download_bytes():
            raise ProtocolError(f"vertex chunk at offset {chunk.offset} out of order (expected "
                                f"{0 if self._chunks is None else len(self._chunks)})")
        self._chunks += chunk.data
        if len(self._chunks) >= chunk.total:
            self._finish_vertex_buffer()

    def _finish_vertex_buffer(self) -> None:
        payload = memoryview(self._chunks).toreadonly()     # the downloaded bytes themselves, not a copy
        self._chunks = None
        if self.info.HasField("vertex_packing"):
            payload = self._unpack(payload)
        crc = zlib.crc32(payload)
        if crc != self.info.vertex_payload_crc32:
            raise ProtocolError("the vertex buffer's CRC-32 differs from SessionInfo.vertex_payload_crc32; "
                                + ("it was damaged in transit, open the session again"
                                   if not self.info.HasField("vertex_packing") else
                                   "this client decodes packed buffers unlike the server: report it, and open "
                                   "with vertex_encoding float32 meanwhile"))
        key = self._buffer_key()
        self._set_vertex(key, payload)
        if self.cache is not None:
            self.cache.put(key, payload, crc)

    def _unpack(self, packed: bytes) -> memoryview:
        """The PLANAR payload decoded from the packed download (caveclod.vertexpack; read-only)."""
        if zlib.crc32(packed) != self.info.vertex_packing.packed_crc32:
            raise ProtocolError("the packed vertex buffer's CRC-32 differs from VertexPacking.packed_crc32; it was "
                                "damaged in transit, open the session again")
        try:
            packing = vertexpack.from_message(self.info.vertex_packing, self.info.vertex_format)
            return vertexpack.unpack_payload(packing, packed)
        except wire.WireError as exc:
            raise ProtocolError(str(exc)) from None

    def _set_vertex(self, key: str, payload: bytes) -> None:
        try:
            arrays = wire.read_vertex_payload(self.info.vertex_format, payload)
        except wire.WireError as exc:
            raise ProtocolError(str(exc)) from None
        morph = arrays.get("morph_target")
        self.vertex = VertexBuffer(key, payload, arrays["position"], arrays["normal"], arrays["texcoord"],
                                   arrays.get("color"), None if morph is None else morph.reshape(-1))
        self.ready = True

    def _frame_part(self, frame: pb.Frame, nbytes: int) -> tuple[list, FrameUpdate | None]:
        if not self.ready:
            raise ProtocolError("a Frame before the vertex buffer was complete")
        now = time.perf_counter()
        out: list[pb.ClientMessage] = []
        if self._frame is None:                           # the first part of a frame
            if frame.frame_seq != self.last_applied + 1:
                out.append(self.keyframe_message(None, pb.KEYFRAME_REASON_BAD_FRAME,
                                                 f"frame {frame.frame_seq} after {self.last_applied}"))
                self.bad_frames += 1
            self._frame = FrameUpdate(frame.frame_seq, frame.pose_seq)
            self._crcs, self._sums, self._used, self._untrusted = {}, {}, {}, set()
        elif frame.frame_seq != self._frame.frame_seq:
            raise ProtocolError(f"part of frame {frame.frame_seq} inside frame {self._frame.frame_seq}")
        update = self._frame
        update.parts += 1
        update.nbytes += nbytes
        for cf in frame.cameras:
            self._camera_part(cf, update, now, out)
        if frame.continued:
            return out, None
        self._frame = None
        self._check_crcs(update, out)
        self.last_applied = update.frame_seq
        # Ack every half window (every frame for a window of 1): the server
        # never waits, and the stream carries half as many acks. A server
        # that reads acks on poses gets them with the next pose, and a plain
        # Ack only when one more frame without a pose would fill the window.
        unacked = update.frame_seq - self.last_acked
        if unacked >= max(1, self.info.ack_window // 2):
            if self.info.acks_on_poses and unacked < self.info.ack_window - 1:
                self._ack_due = update.frame_seq
            else:
                out.append(pb.ClientMessage(ack=pb.Ack(frame_seq=update.frame_seq)))
                self.last_acked = update.frame_seq
        return out, update

    def _camera_part(self, cf: pb.CameraFrame, update: FrameUpdate, now: float, out: list) -> None:
        c = cf.camera
        if c >= self.n_cameras:
            raise ProtocolError(f"a frame for camera {c}; the session has {self.n_cameras}")
        cam = update.cameras.get(c)
        if cam is None:
            cam = update.cameras[c] = CameraUpdate(cf.pose_seq, keyframe=cf.keyframe)
            if cf.keyframe:
                self.buffers.reset(c)          # the keyframe replaces everything the camera held
                if self.slots is not None:
                    self.slots[c].reset()
                self._asked.discard(c)
            if cf.pose_seq > self._answered[c]:
                self._answered[c] = cf.pose_seq
                sent = self._sent[c].pop(cf.pose_seq, None)
                for seq in [s for s in self._sent[c] if s < cf.pose_seq]:
                    del self._sent[c][seq]     # superseded: never answered
                cam.latency = None if sent is None else now - sent
        if cf.HasField("stats"):
            cam.stats = cf.stats
        if c in self._untrusted:
            return
        try:
            if cf.HasField("vertices"):
                if self.slots is None:
                    raise wire.WireError("vertex writes in a session without cache mode")
                writes = wire.decode_slot_writes(cf.vertices, self.info.vertex_format, self.info.cache_vertices)
                self.slots[c].write(writes)
                self._sums[c] = writes.checksum
                cam.vertices_written += len(writes.slots)
                cam.vertex_bytes += cf.vertices.ByteSize()
                cam.vertex_writes.append(writes)
            n = self.info.cache_vertices or self.vertex.n_vertices
            buffers = self.buffers
            links = self.vertex.links if self.info.frame_encoding == pb.FRAME_ENCODING_OPS_LINKED else None

            def held(m: int) -> np.ndarray:       # what an op stream is read against
                if m >= buffers.materials:
                    raise wire.WireError(f"material {m} out of range: the mesh has {buffers.materials} materials")
                return buffers.buffer(c, m)

            for sd in cf.surfaces:
                surface = wire.decode_surface(sd, n, held, links)
                self.buffers.apply(c, surface)
                cam.surfaces.append(surface)
                cam.triangles_written += len(surface.slots)
                if self.slots is not None:
                    self._used.setdefault(c, []).append(surface.tris)
                if surface.crc32 is not None:
                    self._crcs[c, surface.material] = surface.crc32
        except wire.WireError as exc:
            self._bad(c, update, out, str(exc))

    def _bad(self, c: int, update: FrameUpdate, out: list, detail: str) -> None:
        """Camera ``c``'s frame could not be applied: distrust it until a keyframe comes."""
        self._untrusted.add(c)
        update.bad.append(c)
        self.bad_frames += 1
        if c not in self._asked:
            out.append(self.keyframe_message(c, pb.KEYFRAME_REASON_BAD_FRAME, detail))

    def _check_crcs(self, update: FrameUpdate, out: list) -> None:
        """Compare every buffer the frame touched with its CRC (cache mode: and
        every slot set with its checksum, every slot a written triangle uses
        with what the slots hold); ask a keyframe on a mismatch."""
        for c, used in sorted(self._used.items()):
            if c in self._untrusted:
                continue
            missing = self.slots[c].unheld(np.concatenate(used)) if used else ()
            if len(missing):
                self._bad(c, update, out, f"triangles use slot {int(missing[0])}, which holds no vertex "
                                          f"({len(missing)} such slots)")
        for c, value in sorted(self._sums.items()):
            if c in self._untrusted or c in self._asked or c in update.diverged:
                continue
            mine = self.slots[c].checksum.value
            if mine != value:
                self.divergences += 1
                update.diverged.append(c)
                out.append(self.keyframe_message(c, pb.KEYFRAME_REASON_CHECKSUM_MISMATCH,
                                                 f"vertex slots: checksum 0x{mine:08x}, server 0x{value:08x}"))
        for (c, m), crc in sorted(self._crcs.items()):
            if c in self._untrusted or c in self._asked or c in update.diverged:
                continue
            mine = self.buffers.crc32(c, m)
            if mine != crc:
                self.divergences += 1
                update.diverged.append(c)
                out.append(self.keyframe_message(c, pb.KEYFRAME_REASON_CHECKSUM_MISMATCH,
                                                 f"material {m}: crc 0x{mine:08x}, server 0x{crc:08x}"))
