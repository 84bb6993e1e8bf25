"""Frames as bytes: the ServerMessages of one frame, serialized without protobuf objects.

A server sends hundreds of frames a second, each a handful of small fields
around a few byte arrays; building them as protobuf objects (a Frame, a
CameraFrame, a CameraStats and a SurfaceDelta per material, then
serializing) cost about 40 us a frame, most of it per-field attribute
traffic. This module writes the protobuf wire format directly (varint
fields, length-delimited submessages, fixed32), in field-number order, so
the bytes are exactly what protobuf's own serializer makes of the same
message: ``tests/test_frames.py`` checks that byte for byte, and the client
parses them with the generated ``caveclod.v1`` classes as any message.

Part splitting (frames over ``max_bytes`` of array data) is the proto's:
see :func:`frame_parts`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

MAX_CHUNK_BYTES = 1 << 20          # 1 MiB of array data per VertexChunk or Frame part
U32 = np.dtype("<u4")
_FIXED32 = struct.Struct("<I")
_DOUBLE = struct.Struct("<d")
_SMALL = [bytes((n,)) for n in range(128)]


def varint(n: int) -> bytes:
    """An unsigned LEB128 varint (the protobuf encoding of uint32/uint64/bool/enum)."""
    if n < 128:
        return _SMALL[n]
    out = bytearray()
    while n >= 128:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _len_field(tag: bytes, data: bytes) -> bytes:
    return tag + varint(len(data)) + data


# -- messages --------------------------------------------------------------------------

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
        return len(self.slots) * (12 if is_run(self.slots) else 16)


def _slot_fields(slots: np.ndarray, array_tag: bytes, first_tag: bytes) -> list:
    """The slots written, as fields: a run as its first slot (omitted when 0), else the uint32 array."""
    k = len(slots)
    if k and int(slots[-1]) - int(slots[0]) == k - 1:
        return [first_tag, varint(int(slots[0]))] if int(slots[0]) else []
    return [_len_field(array_tag, np.ascontiguousarray(slots, dtype=U32).tobytes())] if k else []


def is_run(slots: np.ndarray) -> bool:
    """Whether ascending unique ``slots`` are consecutive (sent as ``first_slot``)."""
    return len(slots) == 0 or int(slots[-1]) - int(slots[0]) == len(slots) - 1


def surface_bytes(s: Surface) -> bytes:
    """A SurfaceDelta: the op stream, or slots (``first_slot`` for a run) and tris."""
    out = []
    if s.material:
        out += (b"\x08", varint(int(s.material)))
    if s.count:
        out += (b"\x10", varint(int(s.count)))
    if s.ops is None:
        out += _slot_fields(s.slots, b"\x1a", b"\x20")
        if len(s.slots):
            out.append(_len_field(b"\x2a", np.ascontiguousarray(s.tris, dtype=U32).tobytes()))
    if s.crc32 is not None:
        out += (b"\x35", _FIXED32.pack(int(s.crc32)))
    if s.ops:
        out.append(_len_field(b"\x3a", s.ops))
    return b"".join(out)


# CameraStats fields: (name, tag byte, kind); kind "v" varint, "d" double.
_STATS = (("splits", b"\x08", "v"), ("collapses", b"\x10", "v"), ("update_us", b"\x18", "v"),
          ("active_faces", b"\x20", "v"), ("budget_exhausted", b"\x28", "v"), ("pose_age_us", b"\x30", "v"),
          ("cache_hits", b"\x38", "v"), ("cache_inserts", b"\x40", "v"), ("cache_tolerance_px", b"\x49", "d"),
          ("updates", b"\x50", "v"), ("hidden_parts", b"\x58", "v"))
_STAT_NAMES = {name for name, _, _ in _STATS}
_ZERO_DOUBLE = bytes(8)


def stats_bytes(stats: dict) -> bytes:
    """A CameraStats from its fields (unknown names raise KeyError, as protobuf would)."""
    unknown = set(stats) - _STAT_NAMES
    if unknown:
        raise KeyError(f"CameraStats has no field {sorted(unknown)[0]!r}")
    out = []
    for name, tag, kind in _STATS:
        value = stats.get(name)
        if kind == "v":
            if value:
                out += (tag, varint(int(value)))
        elif value is not None and _DOUBLE.pack(float(value)) != _ZERO_DOUBLE:
            # protobuf leaves out a double only when its bits are zero: -0.0 is written
            out += (tag, _DOUBLE.pack(float(value)))
    return b"".join(out)


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


def slot_writes_bytes(w: SlotWrites) -> bytes:
    """A VertexWrites: the k vertices as a PLANAR payload; consecutive slots as ``first_slot``."""
    out = _slot_fields(w.slots, b"\x0a", b"\x10")
    data = b"".join(np.ascontiguousarray(b).reshape(-1).view(np.uint8).tobytes() for b in w.blocks)
    if data:
        out.append(_len_field(b"\x1a", data))
    if w.checksum:
        out += (b"\x25", _FIXED32.pack(int(w.checksum)))
    return b"".join(out)


# -- frames ------------------------------------------------------------------------------

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


class _Entry:
    """One CameraFrame of a part, as it fills."""

    __slots__ = ("cam", "stats", "surfaces", "vertices")

    def __init__(self, cam: CameraFrameData, with_stats: bool):
        self.cam = cam
        self.stats = stats_bytes(cam.stats) if with_stats and cam.stats is not None else None
        self.surfaces: list[bytes] = []
        self.vertices: bytes | None = None

    def to_bytes(self) -> bytes:
        cam, out = self.cam, []
        if cam.camera:
            out += (b"\x08", varint(int(cam.camera)))
        if cam.pose_seq:
            out += (b"\x10", varint(int(cam.pose_seq)))
        if cam.keyframe:
            out.append(b"\x18\x01")
        out += [_len_field(b"\x22", s) for s in self.surfaces]
        if self.stats is not None:
            out.append(_len_field(b"\x2a", self.stats))
        if self.vertices is not None:
            out.append(_len_field(b"\x32", self.vertices))
        return b"".join(out)


def _part_bytes(frame_seq: int, pose_seq: int, superseded: int, entries: list, continued: bool) -> bytes:
    out = []
    if frame_seq:
        out += (b"\x08", varint(frame_seq))
    if pose_seq:
        out += (b"\x10", varint(pose_seq))
    out += [_len_field(b"\x1a", e.to_bytes()) for e in entries]
    if continued:
        out.append(b"\x20\x01")
    if superseded:
        out += (b"\x28", varint(superseded))
    return _len_field(b"\x1a", b"".join(out))          # ServerMessage.frame


def frame_parts(frame_seq: int, pose_seq: int, poses_superseded: int, cameras: list,
                max_bytes: int = MAX_CHUNK_BYTES) -> list[bytes]:
    """The serialized ServerMessages of one frame: parts with at most ``max_bytes`` of array data.

    ``cameras`` is a list of :class:`CameraFrameData`. A surface larger than
    the room left in a part is cut into row ranges; every piece carries the
    buffer's count and CRC, so each applies on its own (resize, then write).
    An op stream is never cut: it goes whole into a part (the server sends
    one only when it is at most half of ``max_bytes``). A camera's stats go
    in the first part that carries it, its keyframe flag in every such part.
    In cache mode a camera's vertex writes come before its surfaces, cut
    into row ranges the same way (each piece carries the checksum). Every
    frame has at least one part.
    """
    if max_bytes < 16:
        raise ValueError(f"max_bytes must hold at least one triangle (16 bytes), got {max_bytes}")
    parts: list[list] = [[]]
    room = max_bytes

    def new_part() -> list:
        nonlocal room
        parts.append([])
        room = max_bytes
        return parts[-1]

    part = parts[0]
    for cam in cameras:
        entry, carried = None, False

        def open_entry() -> _Entry:
            nonlocal carried
            e = _Entry(cam, with_stats=not carried)
            carried = True
            part.append(e)
            return e

        w = cam.vertices
        if w is not None:
            start, k = 0, len(w.slots)
            per_row = w.row_bytes + (0 if is_run(w.slots) else 4)
            if per_row > max_bytes:
                raise ValueError(f"max_bytes must hold at least one vertex ({per_row} bytes), got {max_bytes}")
            while True:
                rows = min(k - start, room // per_row)
                if rows == 0 and k - start > 0:
                    part, entry = new_part(), None
                    continue
                if entry is None:
                    entry = open_entry()
                entry.vertices = slot_writes_bytes(w.piece(start, start + rows))
                room -= rows * per_row
                start += rows
                if start >= k:
                    break
        for s in cam.surfaces:
            if s.ops is not None:
                if len(s.ops) > room and room < max_bytes:
                    part, entry = new_part(), None
                if entry is None:
                    entry = open_entry()
                entry.surfaces.append(surface_bytes(s))
                room -= len(s.ops)
                continue
            start, k = 0, len(s.slots)
            per_row = 12 if is_run(s.slots) else 16
            while True:
                rows = min(k - start, room // per_row)
                if rows == 0 and k - start > 0:          # no room for a single row: next part
                    part, entry = new_part(), None
                    continue
                if entry is None:
                    entry = open_entry()
                piece = Surface(s.material, s.count, s.slots[start:start + rows], s.tris[start:start + rows], s.crc32)
                entry.surfaces.append(surface_bytes(piece))
                room -= rows * (12 if is_run(piece.slots) else 16)
                start += rows
                if start >= k:
                    break
        if not carried:                   # no surfaces: the answered pose and stats only
            open_entry()
    return [_part_bytes(frame_seq, pose_seq, poses_superseded if i == 0 else 0, entries, i < len(parts) - 1)
            for i, entries in enumerate(parts)]
