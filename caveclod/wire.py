"""The caveclod.v1 codec: numpy arrays <-> protobuf messages.

The only module that knows both (DESIGN.md section 6): the server and the
client library build and read every message through it. It imports numpy and
the generated ``caveclod.v1`` stubs only, so the thin client can use it.

Arrays travel as little-endian ``bytes`` (see the proto's Conventions):

* a SurfaceDelta carries ``slots`` (k,) and ``tris`` (k, 3) uint32, or, when
  the k slots are consecutive, ``first_slot`` and no slot array; or, under
  FRAME_ENCODING_OPS, an op stream (:mod:`caveclod.opstream`) read against
  the buffer the client holds;
* frames are written as bytes by :mod:`caveclod.frames`, whose types
  (Surface, SlotWrites, CameraFrameData) this module re-exports;
* a frame whose array data exceed ``max_chunk_bytes`` is split into parts
  (:func:`frame_parts`); so is the vertex payload (:func:`vertex_chunks`);
* the vertex payload is PLANAR: one contiguous block per attribute;
* in cache mode a camera's VertexWrites carry ``slots`` (or ``first_slot``)
  and k vertices as a PLANAR payload of their own (:class:`SlotWrites`);
  the checksums both ends compute are in :mod:`caveclod.checksums`.
"""

from __future__ import annotations

from typing import Iterator, NamedTuple

import numpy as np
from google.protobuf.message import DecodeError

from . import opstream
from .checksums import buffer_crc32, payload_crc32  # noqa: F401  (the codec's checksums, re-exported)
# Frames are written as bytes by caveclod.frames; its types are the codec's, re-exported.
from .frames import (MAX_CHUNK_BYTES, U32, CameraFrameData, SlotWrites, Surface,  # noqa: F401
                     frame_parts, is_run, slot_writes_bytes, surface_bytes)
from .v1 import caveclod_pb2 as pb


class WireError(ValueError):
    """A message that cannot be decoded or applied; the text is one line."""


def _bytes_of(a: np.ndarray) -> np.ndarray:
    """The bytes of a little-endian array as a flat uint8 view (no copy for contiguous input)."""
    return np.ascontiguousarray(a).reshape(-1).view(np.uint8)


# -- small messages -----------------------------------------------------------------

def vec3(v) -> pb.Vec3:
    """A Vec3 from three numbers; ValueError saying so for anything else."""
    try:
        x, y, z = (float(c) for c in v)
    except (TypeError, ValueError):
        raise ValueError(f"a point or direction is three numbers (x, y, z), got {v!r}"[:200]) from None
    return pb.Vec3(x=x, y=y, z=z)


def from_vec3(v: pb.Vec3) -> tuple[float, float, float]:
    """(x, y, z) of a Vec3."""
    return (v.x, v.y, v.z)


OPTION_DEFAULTS = {"fov_y": 60.0, "tolerance_px": 1.0, "cull": True, "backface": False, "prune": True,
                   "strict_bound": False}
_OPTION_FIELDS = (("fov_y", "fov_y_deg"), ("tolerance_px", "tolerance_px"), ("cull", "cull"),
                  ("backface", "backface"), ("max_ops", "max_ops"), ("max_faces", "max_faces"), ("prune", "prune"),
                  ("strict_bound", "strict_bound"))


def options_to_dict(msg: pb.RefineOptions) -> dict:
    """RefineOptions as ``{width, height, fov_y, tolerance_px, cull, backface, max_ops, max_faces, prune,
    strict_bound}``.

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

def encode_surface(s: Surface) -> pb.SurfaceDelta:
    """A SurfaceDelta message (what :func:`caveclod.frames.surface_bytes` writes, parsed)."""
    return pb.SurfaceDelta.FromString(surface_bytes(s))


def decode_surface(msg: pb.SurfaceDelta, n_vertices: int, held=None, links=None) -> Surface:
    """A Surface from a SurfaceDelta, checked as the proto requires.

    ``held(material)`` gives the (old_count, 3) uint32 buffer the client
    holds before this delta; an op stream (``ops``) is decoded against it
    (:func:`caveclod.opstream.decode`; with ``links``, a
    :class:`caveclod.opstream.Links` of the vertex buffer, as
    FRAME_ENCODING_OPS_LINKED: :func:`caveclod.opstream.decode_linked`). Raises WireError for arrays of a
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
            if links is None:
                slots, tris = opstream.decode(msg.ops, old, msg.count, n_vertices)
            else:
                slots, tris = opstream.decode_linked(msg.ops, old, msg.count, links)
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

def encode_slot_writes(w: SlotWrites) -> pb.VertexWrites:
    """A VertexWrites message (what :func:`caveclod.frames.slot_writes_bytes` writes, parsed)."""
    return pb.VertexWrites.FromString(slot_writes_bytes(w))


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


_SCALARS = {pb.SCALAR_TYPE_FLOAT32: np.dtype("<f4"), pb.SCALAR_TYPE_UINT8: np.dtype("u1"),
            pb.SCALAR_TYPE_UINT32: np.dtype("<u4")}


def vertex_format(blocks: list[VertexBlock]) -> pb.VertexFormat:
    """The PLANAR VertexFormat describing ``blocks`` laid end to end."""
    d = len(blocks[0].data)
    fmt = pb.VertexFormat(layout=pb.VERTEX_LAYOUT_PLANAR, vertex_count=d)
    offset = 0
    for b in blocks:
        kind = {np.dtype("u1"): pb.SCALAR_TYPE_UINT8, np.dtype("<u4"): pb.SCALAR_TYPE_UINT32}.get(
            b.data.dtype, pb.SCALAR_TYPE_FLOAT32)
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
              vertex_buffer_hash: str, origin=None) -> pb.MeshInfo:
    """A MeshInfo; ``materials`` are names in id order, ``bounds`` (lo, hi) (3,) arrays, ``origin``
    (3,) or None (StaticMesh.origin)."""
    lo, hi = bounds
    info = pb.MeshInfo(name=name, faces=faces, vertices=vertices, positions=positions, nodes=nodes,
                       base_faces=base_faces, surface_group_ids=surface_group_ids, bounds_min=vec3(lo),
                       bounds_max=vec3(hi), content_hash=content_hash, vertex_buffer_hash=vertex_buffer_hash)
    if origin is not None:
        info.origin.CopyFrom(vec3(origin))
    for i, m in enumerate(materials):
        info.materials.add(id=i, name=str(m))
    return info


def session_info(*, token: str, resumed: bool, mesh: pb.MeshInfo, vertex_format: pb.VertexFormat,
                 vertex_buffer_cached: bool, vertex_payload_crc32: int, view_options: dict, budgets: tuple,
                 cameras: int, ack_window: int, resume_ttl_s: int, last_frame_seq: int,
                 last_pose_seq: int, cache: dict | None = None,
                 frame_encoding: int = pb.FRAME_ENCODING_RAW, strict_bound: bool = False) -> pb.ServerMessage:
    """The SessionInfo ServerMessage; ``view_options`` are View keywords, ``budgets`` (max_ops, max_faces),
    ``cache`` the cache mode in use ``{vertices, strategy, pq_fraction}`` or None, ``strict_bound`` the
    cameras' (RefineOptions.strict_bound)."""
    max_ops, max_faces = budgets
    options = options_from_dict({**view_options, "max_ops": max_ops, "max_faces": max_faces,
                                 "strict_bound": bool(strict_bound)})
    info = pb.SessionInfo(
        session_token=token, resumed=resumed, mesh=mesh, vertex_format=vertex_format,
        vertex_buffer_cached=vertex_buffer_cached, vertex_payload_crc32=vertex_payload_crc32, options=options,
        cameras=cameras, ack_window=ack_window, resume_ttl_s=resume_ttl_s, last_frame_seq=last_frame_seq,
        last_pose_seq=last_pose_seq, max_chunk_bytes=MAX_CHUNK_BYTES, frame_encoding=frame_encoding,
        acks_on_poses=True)
    if cache is not None:
        info.cache_vertices = int(cache["vertices"])
        info.cache_strategy = CACHE_STRATEGIES[cache["strategy"]]
        info.cache_pq_fraction = float(cache["pq_fraction"] or 0.0)
    return pb.ServerMessage(session_info=info)
