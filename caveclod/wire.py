"""The caveclod.v1 codec: numpy arrays <-> protobuf messages.

The only module that knows both (DESIGN.md section 6): the server and the
client library build and read every message through it. It imports numpy and
the generated ``caveclod.v1`` stubs only, so the thin client can use it.

Arrays travel as little-endian ``bytes`` (see the proto's Conventions):

* a SurfaceDelta carries ``slots`` (k,) and ``tris`` (k, 3) uint32, or, when
  the k slots are consecutive, ``first_slot`` and no slot array;
* a frame whose array data exceed ``max_chunk_bytes`` is split into parts
  (:func:`frame_parts`); so is the vertex payload (:func:`vertex_chunks`);
* the vertex payload is PLANAR: one contiguous block per attribute;
* in cache mode a camera's VertexWrites carry ``slots`` (or ``first_slot``)
  and k vertices as a PLANAR payload of their own (:class:`SlotWrites`);
  the checksums both ends compute are in :mod:`caveclod.checksums`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, NamedTuple

import numpy as np
from google.protobuf.message import DecodeError

from . import opstream
from .checksums import buffer_crc32, payload_crc32  # noqa: F401  (the codec's checksums, re-exported)
from .v1 import caveclod_pb2 as pb

MAX_CHUNK_BYTES = 1 << 20          # 1 MiB of array data per VertexChunk or Frame part
U32 = np.dtype("<u4")


class WireError(ValueError):
    """A message that cannot be decoded or applied; the text is one line."""


def _bytes_of(a: np.ndarray) -> np.ndarray:
    """The bytes of a little-endian array as a flat uint8 view (no copy for contiguous input)."""
    return np.ascontiguousarray(a).reshape(-1).view(np.uint8)


# -- small messages -----------------------------------------------------------------

def vec3(v) -> pb.Vec3:
    """A Vec3 from three numbers."""
    x, y, z = (float(c) for c in v)
    return pb.Vec3(x=x, y=y, z=z)


def from_vec3(v: pb.Vec3) -> tuple[float, float, float]:
    """(x, y, z) of a Vec3."""
    return (v.x, v.y, v.z)


OPTION_DEFAULTS = {"fov_y": 60.0, "tolerance_px": 1.0, "cull": True, "backface": False}
_OPTION_FIELDS = (("fov_y", "fov_y_deg"), ("tolerance_px", "tolerance_px"), ("cull", "cull"),
                  ("backface", "backface"), ("max_ops", "max_ops"), ("max_faces", "max_faces"))


def options_to_dict(msg: pb.RefineOptions) -> dict:
    """RefineOptions as ``{width, height, fov_y, tolerance_px, cull, backface, max_ops, max_faces}``.

    Unset optional fields are ``None`` (the receiver fills in defaults);
    nothing is validated here.
    """
    out = {"width": msg.viewport_width, "height": msg.viewport_height}
    for key, name in _OPTION_FIELDS:
        out[key] = getattr(msg, name) if msg.HasField(name) else None
    return out


def options_from_dict(options: dict) -> pb.RefineOptions:
    """The inverse of :func:`options_to_dict`; ``None`` (or a missing key) leaves a field unset."""
    msg = pb.RefineOptions(viewport_width=int(options.get("width") or 0),
                           viewport_height=int(options.get("height") or 0))
    for key, name in _OPTION_FIELDS:
        value = options.get(key)
        if value is not None:
            setattr(msg, name, value)
    return msg


CACHE_STRATEGIES = {"fa": pb.CACHE_STRATEGY_FA, "lru": pb.CACHE_STRATEGY_LRU, "lru_pq": pb.CACHE_STRATEGY_LRU_PQ}
_STRATEGY_NAMES = {v: k for k, v in CACHE_STRATEGIES.items()}


def cache_options(msg: pb.Open) -> dict | None:
    """Open's cache-mode fields as ``{vertices, strategy, pq_fraction}``, or
    None when ``cache_vertices`` is unset (a resident vertex buffer).

    ``strategy`` is a name (``fa``, ``lru``, ``lru_pq``) or None when
    unspecified; ``pq_fraction`` None when unset. Nothing else is validated
    here, except what only the wire can get wrong: a strategy or fraction
    without ``cache_vertices``, or a strategy number this codec does not know
    (WireError).
    """
    if not msg.HasField("cache_vertices"):
        if msg.cache_strategy or msg.HasField("cache_pq_fraction"):
            raise WireError("Open sets a cache strategy or priority-queue fraction but no cache_vertices; "
                            "set cache_vertices to a slot count, or leave all three unset for a resident vertex buffer")
        return None
    if msg.cache_strategy and msg.cache_strategy not in _STRATEGY_NAMES:
        raise WireError(f"Open.cache_strategy {msg.cache_strategy} is unknown; use one of "
                        f"{', '.join(pb.CacheStrategy.Name(v) for v in _STRATEGY_NAMES)}")
    return {"vertices": msg.cache_vertices, "strategy": _STRATEGY_NAMES.get(msg.cache_strategy),
            "pq_fraction": msg.cache_pq_fraction if msg.HasField("cache_pq_fraction") else None}


def set_cache_options(msg: pb.Open, cache: dict | None) -> None:
    """The inverse of :func:`cache_options`: set Open's cache fields from the dict (None: leave them unset)."""
    if cache is None or cache.get("vertices") is None:
        return
    msg.cache_vertices = int(cache["vertices"])
    if cache.get("strategy") is not None:
        msg.cache_strategy = CACHE_STRATEGIES[cache["strategy"]] if isinstance(cache["strategy"], str) \
            else int(cache["strategy"])
    if cache.get("pq_fraction") is not None:
        msg.cache_pq_fraction = float(cache["pq_fraction"])


def strategy_name(value: int) -> str | None:
    """``fa``, ``lru`` or ``lru_pq`` for a CacheStrategy number (None: unspecified or unknown)."""
    return _STRATEGY_NAMES.get(value)


def parse_client_message(data: bytes) -> pb.ClientMessage | WireError:
    """Decode a ClientMessage; garbage gives a WireError *returned*, not raised.

    The server uses this as its request deserializer: gRPC turns a raised
    exception into INTERNAL, while a returned error lets the servicer end the
    stream with INVALID_ARGUMENT and a message saying what was wrong.
    """
    try:
        return pb.ClientMessage.FromString(data)
    except (DecodeError, RuntimeError, ValueError) as exc:
        return WireError(f"undecodable ClientMessage of {len(data)} bytes ({exc}); send caveclod.v1 messages")


def parse_list_request(data: bytes) -> pb.ListMeshesRequest | WireError:
    """Decode a ListMeshesRequest the same way (see :func:`parse_client_message`)."""
    try:
        return pb.ListMeshesRequest.FromString(data)
    except (DecodeError, RuntimeError, ValueError) as exc:
        return WireError(f"undecodable ListMeshesRequest of {len(data)} bytes ({exc})")


# -- surface deltas ------------------------------------------------------------------

@dataclass
class Surface:
    """Slot writes of one (camera, material) index buffer.

    Attributes:
        material: material id.
        count: triangles in the buffer after the writes.
        slots: (k,) uint32 slots written, ascending and unique.
        tris: (k, 3) uint32 vertex-buffer indices written to them.
        crc32: CRC-32 of the whole buffer after the frame, or None.
        ops: the same writes as an op stream (FRAME_ENCODING_OPS,
            :mod:`caveclod.opstream`), sent instead of slots and tris, or None.
    """

    material: int
    count: int
    slots: np.ndarray
    tris: np.ndarray
    crc32: int | None = None
    ops: bytes | None = None

    @property
    def wire_bytes(self) -> int:
        """Bytes of array data this surface puts in a part."""
        if self.ops is not None:
            return len(self.ops)
        return len(self.slots) * (12 if _is_run(self.slots) else 16)


def encode_surface(s: Surface) -> pb.SurfaceDelta:
    """A SurfaceDelta message; consecutive slots travel as ``first_slot``, an op stream as ``ops``."""
    if s.ops is not None:
        msg = pb.SurfaceDelta(material=int(s.material), count=int(s.count), ops=s.ops)
        if s.crc32 is not None:
            msg.crc32 = int(s.crc32)
        return msg
    msg = pb.SurfaceDelta(material=int(s.material), count=int(s.count),
                          tris=np.ascontiguousarray(s.tris, dtype=U32).tobytes())
    k = len(s.slots)
    if k and int(s.slots[-1]) - int(s.slots[0]) == k - 1:     # ascending and unique: a run
        msg.first_slot = int(s.slots[0])
    elif k:
        msg.slots = np.ascontiguousarray(s.slots, dtype=U32).tobytes()
    if s.crc32 is not None:
        msg.crc32 = int(s.crc32)
    return msg


def decode_surface(msg: pb.SurfaceDelta, n_vertices: int, held=None) -> Surface:
    """A Surface from a SurfaceDelta, checked as the proto requires.

    ``held(material)`` gives the (old_count, 3) uint32 buffer the client
    holds before this delta; an op stream (``ops``) is decoded against it
    (:func:`caveclod.opstream.decode`). Raises WireError for arrays of a
    wrong length, slots that are not ascending, unique and < count, vertex
    indices >= ``n_vertices``, or an op stream that does not decode.
    """
    if msg.ops:
        if msg.slots or msg.tris:
            raise WireError(f"material {msg.material}: a SurfaceDelta with both ops and slots or tris")
        if held is None:
            raise WireError(f"material {msg.material}: an op stream, but no buffer to decode it against")
        old = held(msg.material)
        try:
            slots, tris = opstream.decode(msg.ops, old, msg.count, n_vertices)
        except opstream.OpStreamError as exc:
            raise WireError(f"material {msg.material}: {exc}") from None
        return Surface(msg.material, msg.count, slots, tris, msg.crc32 if msg.HasField("crc32") else None)
    if len(msg.tris) % 12:
        raise WireError(f"material {msg.material}: tris has {len(msg.tris)} bytes, not whole (k, 3) uint32 rows")
    tris = np.frombuffer(msg.tris, dtype=U32).reshape(-1, 3)
    k = len(tris)
    if msg.slots:
        if len(msg.slots) != 4 * k:
            raise WireError(f"material {msg.material}: {len(msg.slots)} bytes of slots for {k} triangles")
        slots = np.frombuffer(msg.slots, dtype=U32)
        if k > 1 and not (np.diff(slots.astype(np.int64)) > 0).all():
            raise WireError(f"material {msg.material}: slots are not ascending and unique")
    else:
        if msg.first_slot + k > msg.count:
            raise WireError(f"material {msg.material}: slots {msg.first_slot}..{msg.first_slot + k - 1} "
                            f"past the count {msg.count}")
        slots = np.arange(msg.first_slot, msg.first_slot + k, dtype=U32)
    if k and int(slots[-1]) >= msg.count:
        raise WireError(f"material {msg.material}: slot {int(slots[-1])} past the count {msg.count}")
    if k and int(tris.max()) >= n_vertices:
        raise WireError(f"material {msg.material}: vertex index {int(tris.max())} past the "
                        f"{n_vertices} vertices of the vertex buffer")
    return Surface(msg.material, msg.count, slots, tris, msg.crc32 if msg.HasField("crc32") else None)


# -- vertex slot writes (cache mode) -----------------------------------------------------

@dataclass
class SlotWrites:
    """Vertices written into one camera's cache slots.

    Attributes:
        slots: (k,) uint32 slots written, ascending and unique.
        blocks: the vertices' attributes: one (k, c) array per attribute of
            the VertexFormat, in its order (positions, normals, uvs[, colours]).
        checksum: the camera's slots checksum after the frame
            (:class:`caveclod.checksums.SlotChecksum`).
    """

    slots: np.ndarray
    blocks: list
    checksum: int = 0

    @property
    def row_bytes(self) -> int:
        """Bytes of one vertex's attributes."""
        return int(sum(b.shape[1] * b.dtype.itemsize for b in self.blocks))

    def piece(self, start: int, stop: int) -> "SlotWrites":
        return SlotWrites(self.slots[start:stop], [b[start:stop] for b in self.blocks], self.checksum)


def encode_slot_writes(w: SlotWrites) -> pb.VertexWrites:
    """A VertexWrites message: the k vertices as a PLANAR payload; consecutive slots as ``first_slot``."""
    msg = pb.VertexWrites(data=b"".join(_bytes_of(b).tobytes() for b in w.blocks), slots_checksum=int(w.checksum))
    k = len(w.slots)
    if k and int(w.slots[-1]) - int(w.slots[0]) == k - 1:
        msg.first_slot = int(w.slots[0])
    elif k:
        msg.slots = np.ascontiguousarray(w.slots, dtype=U32).tobytes()
    return msg


def decode_slot_writes(msg: pb.VertexWrites, fmt: pb.VertexFormat, n_slots: int) -> SlotWrites:
    """A SlotWrites from a VertexWrites, checked as the proto requires.

    Attribute blocks are views of ``msg.data`` laid out as ``fmt`` lists the
    attributes. Raises WireError for data that are not whole vertices,
    slots that are not ascending and unique, or a slot >= ``n_slots``.
    """
    widths = []
    for a in fmt.attributes:
        if a.type not in _SCALARS:
            raise WireError(f"vertex attribute {a.semantic} has unknown scalar type {a.type}; upgrade the client")
        widths.append((_SCALARS[a.type], a.components))
    row = sum(t.itemsize * c for t, c in widths)
    if row == 0 or len(msg.data) % row:
        raise WireError(f"vertex writes: {len(msg.data)} bytes of data are not whole {row}-byte vertices")
    k = len(msg.data) // row
    if msg.slots:
        if len(msg.slots) != 4 * k:
            raise WireError(f"vertex writes: {len(msg.slots)} bytes of slots for {k} vertices")
        slots = np.frombuffer(msg.slots, dtype=U32)
        if k > 1 and not (np.diff(slots.astype(np.int64)) > 0).all():
            raise WireError("vertex writes: slots are not ascending and unique")
    else:
        slots = np.arange(msg.first_slot, msg.first_slot + k, dtype=np.int64).astype(U32)
    if k and int(slots[-1]) >= n_slots:
        raise WireError(f"vertex writes: slot {int(slots[-1])} past the {n_slots} slots of the cache")
    blocks, offset = [], 0
    for dtype, c in widths:
        blocks.append(np.frombuffer(msg.data, dtype=dtype, count=k * c, offset=offset).reshape(k, c))
        offset += k * c * dtype.itemsize
    return SlotWrites(slots, blocks, msg.slots_checksum)


# -- frames --------------------------------------------------------------------------

@dataclass
class CameraFrameData:
    """One camera's share of a frame, before splitting into parts.

    Attributes:
        camera: camera index.
        pose_seq: pose the camera is refined for (0: none).
        keyframe: ``surfaces`` hold every material's full buffer.
        surfaces: the Surfaces written.
        stats: CameraStats fields (splits, collapses, update_us, active_faces,
            budget_exhausted, pose_age_us; in cache mode also cache_hits,
            cache_inserts, cache_tolerance_px, updates) of the frame's
            update, or None.
        vertices: cache mode: the :class:`SlotWrites`, or None.
    """

    camera: int
    pose_seq: int
    keyframe: bool = False
    surfaces: list = field(default_factory=list)
    stats: dict | None = None
    vertices: SlotWrites | None = None


def frame_parts(frame_seq: int, pose_seq: int, poses_superseded: int, cameras: list,
                max_bytes: int = MAX_CHUNK_BYTES) -> list[pb.ServerMessage]:
    """The ServerMessages of one frame: parts with at most ``max_bytes`` of array data.

    ``cameras`` is a list of :class:`CameraFrameData`. A surface larger than
    the room left in a part is cut into row ranges; every piece carries the
    buffer's count and CRC, so each applies on its own (resize, then write).
    A camera's stats go in the first part that carries it, its keyframe flag
    in every such part. In cache mode a camera's vertex writes come before
    its surfaces, cut into row ranges the same way (each piece carries the
    checksum). Every frame has at least one part.
    """
    parts: list[pb.Frame] = []
    room = 0

    def new_part() -> pb.Frame:
        nonlocal room
        parts.append(pb.Frame(frame_seq=frame_seq, pose_seq=pose_seq,
                              poses_superseded=poses_superseded if not parts else 0))
        room = max_bytes
        return parts[-1]

    if max_bytes < 16:
        raise ValueError(f"max_bytes must hold at least one triangle (16 bytes), got {max_bytes}")
    part = new_part()
    for cam in cameras:
        entry, carried = None, False
        w = cam.vertices
        if w is not None:
            start, k = 0, len(w.slots)
            per_row = w.row_bytes + (0 if _is_run(w.slots) else 4)
            if per_row > max_bytes:
                raise ValueError(f"max_bytes must hold at least one vertex ({per_row} bytes), got {max_bytes}")
            while True:
                rows = min(k - start, room // per_row)
                if rows == 0 and k - start > 0:
                    part, entry = new_part(), None
                    continue
                if entry is None:
                    entry, carried = _camera_entry(part, cam, with_stats=not carried), True
                piece = w.piece(start, start + rows)
                entry.vertices.CopyFrom(encode_slot_writes(piece))
                room -= rows * per_row
                start += rows
                if start >= k:
                    break
        for s in cam.surfaces:
            if s.ops is not None:                # an op stream is not cut: it goes whole in one part
                if len(s.ops) > room and room < max_bytes:
                    part, entry = new_part(), None
                if entry is None:
                    entry, carried = _camera_entry(part, cam, with_stats=not carried), True
                entry.surfaces.append(encode_surface(s))
                room -= len(s.ops)
                continue
            start, k = 0, len(s.slots)
            while True:
                rows = min(k - start, room // (12 if _is_run(s.slots) else 16))
                if rows == 0 and k - start > 0:          # no room for a single row: next part
                    part, entry = new_part(), None
                    continue
                if entry is None:
                    entry, carried = _camera_entry(part, cam, with_stats=not carried), True
                piece = Surface(s.material, s.count, s.slots[start:start + rows], s.tris[start:start + rows], s.crc32)
                entry.surfaces.append(encode_surface(piece))
                room -= rows * (12 if _is_run(piece.slots) else 16)
                start += rows
                if start >= k:
                    break
        if not carried:                   # no surfaces: the answered pose and stats only
            _camera_entry(part, cam, with_stats=True)
    for p in parts[:-1]:
        p.continued = True
    return [pb.ServerMessage(frame=p) for p in parts]


def _is_run(slots: np.ndarray) -> bool:
    return len(slots) == 0 or int(slots[-1]) - int(slots[0]) == len(slots) - 1


def _camera_entry(part: pb.Frame, cam: CameraFrameData, with_stats: bool) -> pb.CameraFrame:
    entry = part.cameras.add(camera=cam.camera, pose_seq=cam.pose_seq, keyframe=cam.keyframe)
    if with_stats and cam.stats is not None:
        entry.stats.CopyFrom(pb.CameraStats(**cam.stats))
    return entry


# -- the vertex buffer -----------------------------------------------------------------

class VertexBlock(NamedTuple):
    """One attribute of the planar payload: its semantic, scalar type and data (d, c)."""

    semantic: int
    data: np.ndarray


def vertex_blocks(positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray,
                  colors: np.ndarray) -> list[VertexBlock]:
    """The planar payload's blocks in proto order; colours only when present.

    Args: positions (d, 3) float32, normals (d, 3) float32, uvs (d, 2)
    float32, colors (d, 4) uint8 or (0, 4).
    """
    blocks = [VertexBlock(pb.ATTRIBUTE_SEMANTIC_POSITION, positions),
              VertexBlock(pb.ATTRIBUTE_SEMANTIC_NORMAL, normals),
              VertexBlock(pb.ATTRIBUTE_SEMANTIC_TEXCOORD, uvs)]
    if len(colors):
        blocks.append(VertexBlock(pb.ATTRIBUTE_SEMANTIC_COLOR, colors))
    return blocks


_SCALARS = {pb.SCALAR_TYPE_FLOAT32: np.dtype("<f4"), pb.SCALAR_TYPE_UINT8: np.dtype("u1")}


def vertex_format(blocks: list[VertexBlock]) -> pb.VertexFormat:
    """The PLANAR VertexFormat describing ``blocks`` laid end to end."""
    d = len(blocks[0].data)
    fmt = pb.VertexFormat(layout=pb.VERTEX_LAYOUT_PLANAR, vertex_count=d)
    offset = 0
    for b in blocks:
        kind = pb.SCALAR_TYPE_UINT8 if b.data.dtype == np.uint8 else pb.SCALAR_TYPE_FLOAT32
        components = b.data.shape[1]
        stride = components * _SCALARS[kind].itemsize
        fmt.attributes.add(semantic=b.semantic, type=kind, components=components,
                           normalized=kind == pb.SCALAR_TYPE_UINT8, offset=offset, stride=stride)
        offset += d * stride
    fmt.payload_bytes = offset
    return fmt


def vertex_chunks(blocks: list[VertexBlock], max_bytes: int = MAX_CHUNK_BYTES) -> Iterator[pb.ServerMessage]:
    """VertexChunk messages of the payload, each at most ``max_bytes``, in order.

    Reads the blocks (memory-mapped, typically) a chunk at a time; the
    payload is never assembled in memory as a whole.
    """
    views = [_bytes_of(b.data) for b in blocks]
    total = sum(len(v) for v in views)
    offset = 0
    pending: list[np.ndarray] = []
    filled = 0
    for v in views:
        start = 0
        while start < len(v):
            take = min(len(v) - start, max_bytes - filled)
            pending.append(v[start:start + take])
            filled += take
            start += take
            if filled == max_bytes:
                yield _chunk(offset, total, pending)
                offset += filled
                pending, filled = [], 0
    if filled or total == 0:
        yield _chunk(offset, total, pending)


def _chunk(offset: int, total: int, pieces: list) -> pb.ServerMessage:
    data = b"".join(p.tobytes() for p in pieces)
    return pb.ServerMessage(vertex_chunk=pb.VertexChunk(offset=offset, total=total, data=data))


def read_vertex_payload(fmt: pb.VertexFormat, payload) -> dict:
    """{semantic name: (d, c) array view} of a payload laid out as ``fmt`` says.

    Names are "position", "normal", "texcoord", "color". Raises WireError for
    a layout other than PLANAR or INTERLEAVED, an unknown scalar type, or
    attributes that reach past the payload.
    """
    if fmt.layout not in (pb.VERTEX_LAYOUT_PLANAR, pb.VERTEX_LAYOUT_INTERLEAVED):
        raise WireError(f"unknown vertex layout {fmt.layout}; this client reads caveclod.v1 PLANAR and "
                        "INTERLEAVED payloads, upgrade it")
    d = fmt.vertex_count
    buf = memoryview(payload)
    out = {}
    for a in fmt.attributes:
        if a.type not in _SCALARS:
            raise WireError(f"vertex attribute {a.semantic} has unknown scalar type {a.type}; upgrade the client")
        dtype = _SCALARS[a.type]
        width = a.components * dtype.itemsize
        end = a.offset + (d - 1) * a.stride + width if d else a.offset
        if end > len(buf) or a.stride < width:
            raise WireError(f"vertex attribute {a.semantic} reaches past the {len(buf)}-byte payload")
        name = pb.AttributeSemantic.Name(a.semantic).removeprefix("ATTRIBUTE_SEMANTIC_").lower()
        out[name] = np.ndarray((d, a.components), dtype=dtype, buffer=buf, offset=a.offset,
                               strides=(a.stride, dtype.itemsize))
    return out


# -- meshes ----------------------------------------------------------------------------

def mesh_info(name: str, *, faces: int, vertices: int, positions: int, nodes: int, base_faces: int,
              surface_group_ids: int, materials: list, bounds, content_hash: str,
              vertex_buffer_hash: str) -> pb.MeshInfo:
    """A MeshInfo; ``materials`` are names in id order, ``bounds`` (lo, hi) (3,) arrays."""
    lo, hi = bounds
    info = pb.MeshInfo(name=name, faces=faces, vertices=vertices, positions=positions, nodes=nodes,
                       base_faces=base_faces, surface_group_ids=surface_group_ids, bounds_min=vec3(lo),
                       bounds_max=vec3(hi), content_hash=content_hash, vertex_buffer_hash=vertex_buffer_hash)
    for i, m in enumerate(materials):
        info.materials.add(id=i, name=str(m))
    return info


def session_info(*, token: str, resumed: bool, mesh: pb.MeshInfo, vertex_format: pb.VertexFormat,
                 vertex_buffer_cached: bool, vertex_payload_crc32: int, view_options: dict, budgets: tuple,
                 cameras: int, ack_window: int, resume_ttl_s: int, last_frame_seq: int,
                 last_pose_seq: int, cache: dict | None = None,
                 frame_encoding: int = pb.FRAME_ENCODING_RAW) -> pb.ServerMessage:
    """The SessionInfo ServerMessage; ``view_options`` are View keywords, ``budgets`` (max_ops, max_faces),
    ``cache`` the cache mode in use ``{vertices, strategy, pq_fraction}`` or None."""
    max_ops, max_faces = budgets
    options = options_from_dict({**view_options, "max_ops": max_ops, "max_faces": max_faces})
    info = pb.SessionInfo(
        session_token=token, resumed=resumed, mesh=mesh, vertex_format=vertex_format,
        vertex_buffer_cached=vertex_buffer_cached, vertex_payload_crc32=vertex_payload_crc32, options=options,
        cameras=cameras, ack_window=ack_window, resume_ttl_s=resume_ttl_s, last_frame_seq=last_frame_seq,
        last_pose_seq=last_pose_seq, max_chunk_bytes=MAX_CHUNK_BYTES, frame_encoding=frame_encoding)
    if cache is not None:
        info.cache_vertices = int(cache["vertices"])
        info.cache_strategy = CACHE_STRATEGIES[cache["strategy"]]
        info.cache_pq_fraction = float(cache["pq_fraction"] or 0.0)
    return pb.ServerMessage(session_info=info)
