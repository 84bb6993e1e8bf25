"""The packed vertex download (VERTEX_ENCODING_PACKED): quantize, delta-code, deflate.

A resident-buffer client downloads the whole vertex buffer once: 32 bytes
per vertex as float32 (36 with colours). Packed, the same buffer travels in
1-7 bytes per vertex (benchmarks/vertex_download.py), and the client decodes
it back into the float32 PLANAR payload that ``SessionInfo.vertex_format``
describes, so nothing after the download changes: renderers, caches and
index buffers see float32 attributes as before.

Numpy and zlib only, so the thin client decodes it; the proto's
``VertexPacking`` comment is the specification for other languages (a
browser inflates with ``DecompressionStream("deflate")``). In short:

* positions: ``q = round((p - origin) / step)`` per component, ``step`` the
  largest extent over ``2**position_bits - 1``; decoded ``float32(origin +
  q * step)`` computed in float64.
* normals: octahedral, ``normal_bits`` (12) per component, two components;
  decoded as :func:`decode_normals` says, in float64, then float32.
* texcoords: ``q = round(uv / texcoord_step)``, ``texcoord_step`` a power of
  two (2**-16 unless the coordinates are too large for 24 bits); decoded
  ``float32(q * texcoord_step)``.
* colours: the bytes as they are.
* morph targets (when asked for): ``q = target - i`` for vertex ``i``
  (neighbours, mostly: small numbers); decoded ``q + i``.

Each component of each attribute, in ``vertex_format.attributes`` order,
becomes ``d`` deltas (``q[i] - q[i - 1]``, ``q[-1] = 0``), zigzag-coded into
uint32 and stored as four byte planes (every value's lowest byte, then the
next, ...): a delta of a smooth surface is small, its upper planes all
zeros, and deflate (zlib format, RFC 1950) takes them to almost nothing.

Every decoding step is exact IEEE arithmetic in a fixed order, so every
decoder produces the same bytes: ``SessionInfo.vertex_payload_crc32`` is the
CRC-32 of the *decoded* payload, a check of the decoder as well as of the
transfer (``VertexPacking.packed_crc32`` checks the packed bytes).

What quantizing costs is measured, not assumed: :func:`pack` reports the
largest distance between a decoded position and its original
(``max_position_error``, world units; a viewer adds it to the screen-space
bound at its nearest distance) and the largest normal angle.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from dataclasses import dataclass

import numpy as np

from . import wire
from .v1 import caveclod_pb2 as pb
from .wire import WireError

DEFAULT_POSITION_BITS = 20
MIN_POSITION_BITS, MAX_POSITION_BITS = 8, 24
NORMAL_BITS = 12
TEXCOORD_MAX_EXPONENT = 16          # texcoord_step is at most this fine: 2**-16
TEXCOORD_RANGE_BITS = 24            # |q| of a texcoord stays below 2**24
ZLIB_LEVEL = 6                      # level 9 saved 2-6 % more at 3-8x the time here


@dataclass(frozen=True)
class Packing:
    """What a decoder needs besides the packed bytes (``VertexPacking`` on the wire)."""

    vertex_count: int
    position_bits: int
    position_origin: tuple          # (3,) float64
    position_step: float
    normal_bits: int
    texcoord_step: float
    has_color: bool
    has_morph: bool = False


@dataclass(frozen=True)
class Packed:
    """A packed vertex buffer and what the server says about it."""

    packing: Packing
    data: bytes | np.ndarray        # the deflated streams (VertexChunk data, concatenated); (n,) uint8 when mapped
    decoded_crc32: int              # CRC-32 of the decoded float32 payload
    max_position_error: float       # world units: largest |decoded - original| position
    max_normal_degrees: float       # largest angle between a decoded normal and its original
    packed_crc32: int               # CRC-32 of ``data``


def packed_hash(vertex_buffer_hash: str, position_bits: int, morph: bool = False, content_hash: str = "") -> str:
    """Cache key of the decoded buffer (``VertexPacking.vertex_buffer_hash``).

    The lower-case hex SHA-256 of ``"caveclod.packed.v1:" + vertex_buffer_hash
    + ":" + str(position_bits)`` (+ ``":morph:" + content_hash`` with morph
    targets; UTF-8), so that a client computes it before it opens a session
    and offers a buffer it decoded earlier. Morph targets come from the
    hierarchy, which the vertex buffer's hash does not cover: a mesh built
    again with the same vertices and another hierarchy has other targets,
    and MeshInfo's ``content_hash`` tells them apart.
    """
    text = f"caveclod.packed.v1:{vertex_buffer_hash}:{position_bits}" + (f":morph:{content_hash}" if morph else "")
    return hashlib.sha256(text.encode()).hexdigest()


def check_position_bits(bits: int) -> None:
    if not MIN_POSITION_BITS <= bits <= MAX_POSITION_BITS:
        raise ValueError(f"position_bits is {bits}; use {MIN_POSITION_BITS} to {MAX_POSITION_BITS} "
                         f"(unset: {DEFAULT_POSITION_BITS})")


# -- quantization ------------------------------------------------------------------------

def position_quantization(positions: np.ndarray, bits: int) -> tuple[np.ndarray, float]:
    """(origin (3,) float64, step) for ``positions`` (d, 3) at ``bits`` per component."""
    p = np.asarray(positions, np.float64)
    if len(p) == 0:
        return np.zeros(3), 1.0
    origin = p.min(axis=0)
    extent = float((p.max(axis=0) - origin).max())
    return origin, (extent / ((1 << bits) - 1) if extent > 0 else 1.0)


def texcoord_step(top: float) -> float:
    """The power-of-two step of texcoords whose largest |uv| is ``top``: 2**-16, or coarser when it reaches 2**8."""
    e = TEXCOORD_MAX_EXPONENT
    # Down to 2**104 for float32's largest (2**128 - 2**104, then q = 2**24 - 1 exactly): a floor of
    # 2**64 left texcoords beyond about 3e26 (a damaged file's) with q past int64.
    while e > -128 and top * 2.0 ** e >= 2 ** TEXCOORD_RANGE_BITS:
        e -= 1
    return 2.0 ** -e


def encode_normals(normals: np.ndarray, bits: int = NORMAL_BITS) -> np.ndarray:
    """(d, 3) unit normals -> (d, 2) int64 octahedral codes in [-(2**(bits-1) - 1), 2**(bits-1) - 1].

    A zero normal (a degenerate corner) becomes +z.
    """
    n = np.asarray(normals, np.float64)
    l1 = np.abs(n).sum(axis=1)
    zero = ~(l1 > 0)
    n = n / np.where(zero, 1.0, l1)[:, None]
    n[zero] = (0.0, 0.0, 1.0)
    x, y = n[:, 0].copy(), n[:, 1].copy()
    low = n[:, 2] < 0                    # the lower half folds over the diagonals
    sx = np.where(x[low] >= 0, 1.0, -1.0)
    sy = np.where(y[low] >= 0, 1.0, -1.0)
    x[low], y[low] = (1.0 - np.abs(n[low, 1])) * sx, (1.0 - np.abs(n[low, 0])) * sy
    s = (1 << (bits - 1)) - 1
    return np.rint(np.stack([x, y], axis=1) * s).astype(np.int64)


def decode_normals(codes: np.ndarray, bits: int = NORMAL_BITS) -> np.ndarray:
    """(d, 2) octahedral codes -> (d, 3) float32 unit normals.

    In float64, in this order: ``x = qx / s``, ``y = qy / s`` (``s =
    2**(bits-1) - 1``), ``z = 1 - |x| - |y|``, ``t = max(-z, 0)``, ``x -= t``
    where ``x >= 0`` else ``x += t`` (the same for ``y``), then each of x, y,
    z divided by ``sqrt(x*x + y*y + z*z)``, then rounded to float32.
    """
    s = float((1 << (bits - 1)) - 1)
    q = np.asarray(codes, np.float64)
    x, y = q[:, 0] / s, q[:, 1] / s
    z = 1.0 - np.abs(x) - np.abs(y)
    t = np.maximum(-z, 0.0)
    x = np.where(x >= 0, x - t, x + t)
    y = np.where(y >= 0, y - t, y + t)
    length = np.sqrt(x * x + y * y + z * z)
    return np.stack([x / length, y / length, z / length], axis=1).astype(np.float32)


# -- the byte streams --------------------------------------------------------------------

def _undelta_planes(planes: np.ndarray) -> np.ndarray:
    """(k, 4, n) uint8 byte planes of k streams -> (k, n) int64 running sums of their zigzag deltas
    (the inverse of pack's planes from a start of 0)."""
    zig = planes[:, 3].astype(np.uint32)            # in place, in 32 bits: the fewest passes over memory
    for plane in (2, 1, 0):
        zig <<= 8
        zig |= planes[:, plane]
    delta = zig >> 1
    delta ^= np.uint32(0) - (zig & 1)
    return np.cumsum(delta.view(np.int32), axis=1, dtype=np.int64)


def _columns(positions, normals, uvs, colors, morph, packing: Packing, first: int = 0) -> list[np.ndarray]:
    """The quantized components, stream order: (n,) int64 each (``first``: the index of the first vertex)."""
    qp = np.rint((np.asarray(positions, np.float64) - np.asarray(packing.position_origin))
                 / packing.position_step).astype(np.int64)
    qn = encode_normals(normals, packing.normal_bits)
    qu = np.rint(np.asarray(uvs, np.float64) / packing.texcoord_step).astype(np.int64)
    cols = [qp[:, k] for k in range(3)] + [qn[:, k] for k in range(2)] + [qu[:, k] for k in range(2)]
    if colors is not None:
        qc = np.asarray(colors, np.uint8).astype(np.int64)
        cols += [qc[:, k] for k in range(4)]
    if morph is not None:
        cols.append(np.asarray(morph, np.int64) - np.arange(first, first + len(morph)))
    return cols


def _decoded(cols: list, packing: Packing, first: int = 0) -> dict:
    """{"position", "normal", "texcoord"[, "color"][, "morph_target"]} of the decoded components (n,) int64
    each, stream order, the first being vertex ``first``: the arithmetic every decoder does."""
    origin = np.asarray(packing.position_origin, np.float64)
    out = {
        "position": (origin + np.stack(cols[0:3], axis=1).astype(np.float64) * packing.position_step)
        .astype(np.float32),
        "normal": decode_normals(np.stack(cols[3:5], axis=1), packing.normal_bits),
        "texcoord": (np.stack(cols[5:7], axis=1).astype(np.float64) * packing.texcoord_step).astype(np.float32),
    }
    if packing.has_color:
        out["color"] = np.stack(cols[7:11], axis=1)
    if packing.has_morph:
        out["morph_target"] = cols[-1] + np.arange(first, first + len(cols[-1]))
    return out


def stream_components(has_color: bool, has_morph: bool = False) -> int:
    """Components in the packed streams: 3 position + 2 normal + 2 texcoord (+ 4 colour, + 1 morph target)."""
    return 7 + 4 * has_color + has_morph


# -- pack / unpack ------------------------------------------------------------------------

# Vertices per pass of pack(): numpy's temporaries stay a few MB. Whole-array
# passes took 31 s for 16.8M vertices (a 33.5M-triangle terrain), mostly in
# page faults of 100-400 MB temporaries and in inflating again what was
# just deflated to check it.
PACK_CHUNK = 1 << 17


def pack(positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray, colors: np.ndarray | None,
         position_bits: int = DEFAULT_POSITION_BITS, morph_targets: np.ndarray | None = None,
         chunk: int = PACK_CHUNK) -> Packed:
    """Pack a vertex buffer: positions, normals (d, 3) float32, uvs (d, 2) float32, colors (d, 4) uint8,
    or None or (0, 4) when the mesh has none (as :func:`caveclod.wire.vertex_blocks` takes them), and
    optionally morph targets (d,) (:func:`caveclod.refine.morphtargets.morph_targets`).

    Works ``chunk`` vertices at a time (the same bytes whatever the chunk).
    The decoded payload's CRC-32 and the errors are those of the decoder's
    arithmetic applied to the quantized values as the streams carry them
    (each delta as the int32 it travels as), without inflating the streams
    again.
    """
    check_position_bits(position_bits)
    if colors is not None and not len(colors):
        colors = None
    d = len(positions)
    if morph_targets is not None and d >= 1 << 30:
        # A morph stream's delta could then leave int32: it would travel wrapped.
        raise ValueError(f"{d} vertices: morph targets are packed for fewer than 2**30 vertices")
    chunk = max(int(chunk), 1)
    spans = [(lo, min(d, lo + chunk)) for lo in range(0, d, chunk)]
    if d:
        lows = np.min([np.asarray(positions[lo:hi]).min(axis=0) for lo, hi in spans], axis=0)
        highs = np.max([np.asarray(positions[lo:hi]).max(axis=0) for lo, hi in spans], axis=0)
        origin, step = position_quantization(np.stack([lows, highs]), position_bits)
        top = float(np.max([np.abs(np.asarray(uvs[lo:hi])).max(initial=0.0) for lo, hi in spans]))   # NaN stays NaN
    else:
        origin, step, top = np.zeros(3), 1.0, 0.0
    packing = Packing(vertex_count=d, position_bits=position_bits, position_origin=tuple(float(v) for v in origin),
                      position_step=step, normal_bits=NORMAL_BITS, texcoord_step=texcoord_step(top),
                      has_color=colors is not None, has_morph=morph_targets is not None)
    k = stream_components(packing.has_color, packing.has_morph)
    planes = np.empty((k, 4, d), np.uint8)               # the streams, in their order (module doc)
    decoded = {"position": np.empty((d, 3), np.float32), "normal": np.empty((d, 3), np.float32),
               "texcoord": np.empty((d, 2), np.float32)}
    if packing.has_color:
        decoded["color"] = np.empty((d, 4), np.uint8)
    if packing.has_morph:
        decoded["morph_target"] = np.empty((d, 1), np.uint32)

    def one(span: tuple) -> tuple:
        """Streams and decoded values of vertices lo .. hi; (largest position error, largest normal angle)."""
        lo, hi = span
        first = max(lo - 1, 0)     # the vertex before the block: its values start the block's deltas
        cols = _columns(positions[first:hi], normals[first:hi], uvs[first:hi],
                        None if colors is None else colors[first:hi],
                        None if morph_targets is None else morph_targets[first:hi], packing, first)
        carried = []
        for j, q in enumerate(cols):
            # Each delta as the int32 it travels as; no stream's deltas leave int32 (positions and
            # texcoords keep |q| < 2**25, morph targets < 2**30 vertices), so the value before
            # the block is what a decoder holds there.
            start = q[0] if lo else 0
            wide = (np.diff(q) if lo else np.diff(q, prepend=0)).astype(np.int32).astype(np.int64)
            planes[j, :, lo:hi] = ((wide << 1) ^ (wide >> 31)).astype("<u4").view(np.uint8).reshape(-1, 4).T
            carried.append(start + np.cumsum(wide))          # what a decoder reads back
        part = _decoded(carried, packing, lo)
        for name, values in part.items():
            decoded[name][lo:hi] = values.reshape(decoded[name][lo:hi].shape)
        p = np.asarray(positions[lo:hi], np.float64)
        err = float(np.sqrt(((part["position"].astype(np.float64) - p) ** 2).sum(axis=1)).max())
        n0 = np.asarray(normals[lo:hi], np.float64)
        nonzero = np.abs(n0).sum(axis=1) > 0
        if not nonzero.any():
            return err, 0.0
        n0 = n0 / np.maximum(np.linalg.norm(n0, axis=1), 1e-30)[:, None]
        cos = np.clip((n0 * part["normal"].astype(np.float64)).sum(axis=1), -1.0, 1.0)
        return err, float(np.degrees(np.arccos(cos[nonzero])).max())

    if len(spans) >= 4:           # blocks write disjoint slices; numpy releases the GIL in their passes
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(2, thread_name_prefix="caveclod-pack") as pool:
            found = list(pool.map(one, spans))
    else:
        found = [one(span) for span in spans]
    err = max((e for e, _ in found), default=0.0)
    angle = max((a for _, a in found), default=0.0)
    data = deflate(planes.reshape(-1))
    return Packed(packing, data, wire.payload_crc32(_planar_blocks(decoded)), err, angle,   # not joined
                  zlib.crc32(data))


# Streams of more bytes than this are deflated in two halves on two threads
# (4.5 s on one for the 470 MB of a 16.8M-vertex buffer).
PARALLEL_DEFLATE_BYTES = 32 << 20
WINDOW = 32 << 10                   # deflate's window: the second half starts with the first's last 32 KiB as history


def deflate(raw: np.ndarray, split_bytes: int | None = None) -> bytes:
    """``raw`` (n,) uint8 as one zlib stream (RFC 1950) at ZLIB_LEVEL.

    Past ``split_bytes`` (PARALLEL_DEFLATE_BYTES) the two halves are
    deflated at once, as pigz does: raw deflate, the first half ended by a
    sync flush (an empty stored block: the stream goes on byte-aligned), the
    second primed with the first's last 32 KiB so that its matches may reach
    back across the cut; then zlib's header and the Adler-32 of all of it.
    Any inflater reads it as one stream (browsers' DecompressionStream, zlib).
    """
    split_bytes = PARALLEL_DEFLATE_BYTES if split_bytes is None else split_bytes
    n = len(raw)
    if n <= split_bytes:
        return zlib.compress(raw, ZLIB_LEVEL)
    half = n // 2
    first, second = raw[:half], raw[half:]

    def part(k: int) -> bytes:
        if k == 0:
            c = zlib.compressobj(ZLIB_LEVEL, zlib.DEFLATED, -15)
            return c.compress(first) + c.flush(zlib.Z_SYNC_FLUSH)
        c = zlib.compressobj(ZLIB_LEVEL, zlib.DEFLATED, -15, zdict=first[-WINDOW:].tobytes())
        return c.compress(second) + c.flush(zlib.Z_FINISH)

    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(2, thread_name_prefix="caveclod-deflate") as pool:
        a, b = pool.map(part, (0, 1))
    header = zlib.compress(b"", ZLIB_LEVEL)[:2]          # CMF and FLG of ZLIB_LEVEL's streams
    return header + a + b + zlib.adler32(raw).to_bytes(4, "big")


# Buffers of this many vertices or more are decoded in two halves on two threads.
PARALLEL_UNPACK = 1 << 20


def _planar_views(packing: Packing) -> tuple[np.ndarray, dict]:
    """An uninitialised PLANAR payload for ``packing``'s vertices ((n,) uint8) and its blocks as
    {"position": (d, 3) float32, "normal", "texcoord"[, "color": (d, 4) uint8][, "morph_target": (d, 1)
    uint32]} views, in the payload's order (:func:`_planar_blocks`)."""
    d = packing.vertex_count
    shapes = [("position", 3, "<f4"), ("normal", 3, "<f4"), ("texcoord", 2, "<f4")]
    shapes += [("color", 4, "u1")] * packing.has_color + [("morph_target", 1, "<u4")] * packing.has_morph
    payload = np.empty(sum(d * c * np.dtype(t).itemsize for _, c, t in shapes), np.uint8)
    views, at = {}, 0
    for name, c, t in shapes:
        n = d * c * np.dtype(t).itemsize
        views[name] = payload[at:at + n].view(t).reshape(d, c)
        at += n
    return payload, views


def unpack_payload(packing: Packing, data: bytes, chunk: int = PACK_CHUNK) -> memoryview:
    """The PLANAR float32 payload decoded from the packed bytes, as a read-only memoryview: what
    ``planar_payload(unpack(...))`` holds, decoded in place (a client's vertex buffer; 537 MB at
    16.8M vertices, where joining the arrays took another 1.2 s and as much memory)."""
    payload = _unpack(packing, data, chunk)[0]
    payload.flags.writeable = False
    return memoryview(payload)


def unpack(packing: Packing, data: bytes, chunk: int = PACK_CHUNK) -> dict:
    """{"position", "normal", "texcoord"[, "color"][, "morph_target"]: (d, c) array} decoded from the
    packed bytes (views of one PLANAR payload, :func:`unpack_payload`)."""
    return _unpack(packing, data, chunk)[1]


def _unpack(packing: Packing, data: bytes, chunk: int = PACK_CHUNK) -> tuple[np.ndarray, dict]:
    """(the (n,) uint8 PLANAR payload, {name: (d, c) view of it}) decoded from the packed bytes.

    Decodes ``chunk`` vertices at a time after inflating, past
    PARALLEL_UNPACK vertices in two halves at once (the same arrays
    whatever the chunk and the threads): whole-array passes on one thread
    took 14.5 s for 16.8M vertices.

    Raises WireError when the bytes do not inflate, or inflate to a length
    other than the streams' (damaged or from another format).
    """
    d = packing.vertex_count
    k = stream_components(packing.has_color, packing.has_morph)
    want = 4 * d * k
    try:
        inflater = zlib.decompressobj()
        raw = inflater.decompress(data, want + 1)
        complete = inflater.eof and not inflater.unconsumed_tail and not inflater.unused_data
    except zlib.error as exc:
        raise WireError(f"the packed vertex buffer does not inflate ({exc}); it is damaged: open the session "
                        "again, or ask for vertex_encoding FLOAT32") from None
    if len(raw) != want or not complete:
        raise WireError(f"the packed vertex buffer inflates to {len(raw)}{'' if complete else '+'} bytes where "
                        f"{d} vertices need {want}; it is damaged or from another format: open the session again")
    planes = np.frombuffer(raw, np.uint8).reshape(k, 4, d)
    payload, out = _planar_views(packing)
    chunk = max(int(chunk), 1)

    def blocks(lo: int, hi: int):
        """(first vertex, (k, n) int64 running sums from 0) of each block of vertices lo .. hi."""
        for first in range(lo, hi, chunk):
            yield first, _undelta_planes(planes[:, :, first:min(hi, first + chunk)])

    def decode(lo: int, hi: int, carried: np.ndarray | None) -> None:
        """Decode vertices lo .. hi into ``out``; ``carried`` (k, 1): each component's value before lo,
        None: the sum of the deltas before lo (summed here: the other thread decodes them)."""
        if carried is None:
            carried = sum((cols[:, -1:] for _, cols in blocks(0, lo)), np.zeros((k, 1), np.int64))
        for first, cols in blocks(lo, hi):
            cols += carried
            carried = cols[:, -1:]
            part = _decoded(list(cols), packing, first)
            if packing.has_color and (part["color"].min() < 0 or part["color"].max() > 255):
                raise WireError("the packed vertex buffer's colours fall outside 0..255; it is damaged: open the "
                                "session again")
            if packing.has_morph and (part["morph_target"].min() < 0 or part["morph_target"].max() >= d):
                raise WireError("the packed vertex buffer's morph targets fall outside the buffer; it is damaged: "
                                "open the session again")
            for name, values in part.items():
                view = out[name][first:first + len(values)]
                view[...] = values.reshape(view.shape)

    if d < PARALLEL_UNPACK:
        decode(0, d, np.zeros((k, 1), np.int64))
    else:       # two halves at once (numpy releases the GIL); the second sums the first's deltas itself
        from concurrent.futures import ThreadPoolExecutor
        half = d // 2 // chunk * chunk
        with ThreadPoolExecutor(2, thread_name_prefix="caveclod-unpack") as pool:
            for done in [pool.submit(decode, 0, half, np.zeros((k, 1), np.int64)), pool.submit(decode, half, d, None)]:
                done.result()
    return payload, out


def _planar_blocks(arrays: dict) -> list:
    """The PLANAR payload's blocks of decoded ``arrays``, in order, little-endian and contiguous."""
    parts = [np.ascontiguousarray(arrays["position"], "<f4"), np.ascontiguousarray(arrays["normal"], "<f4"),
             np.ascontiguousarray(arrays["texcoord"], "<f4")]
    if "color" in arrays:
        parts.append(np.ascontiguousarray(arrays["color"], np.uint8))
    if "morph_target" in arrays:
        parts.append(np.ascontiguousarray(arrays["morph_target"], "<u4"))
    return parts


def planar_payload(arrays: dict) -> bytes:
    """The PLANAR float32 payload (caveclod.proto's VertexFormat) of decoded arrays."""
    return b"".join(p.tobytes() for p in _planar_blocks(arrays))


# -- on the wire ---------------------------------------------------------------------------

def to_message(packed: Packed, vertex_buffer_hash: str, content_hash: str = ""):
    """The ``VertexPacking`` message of ``packed``; ``vertex_buffer_hash`` and ``content_hash`` are
    the mesh's (MeshInfo's; the second names the morph targets, :func:`packed_hash`)."""
    p = packed.packing
    x, y, z = p.position_origin
    return pb.VertexPacking(
        encoding=pb.VERTEX_ENCODING_PACKED, packed_bytes=len(packed.data), packed_crc32=packed.packed_crc32,
        vertex_buffer_hash=packed_hash(vertex_buffer_hash, p.position_bits, p.has_morph, content_hash),
        position_bits=p.position_bits,
        position_origin=pb.Vec3(x=x, y=y, z=z), position_step=p.position_step, normal_bits=p.normal_bits,
        texcoord_step=p.texcoord_step, max_position_error=packed.max_position_error,
        max_normal_degrees=packed.max_normal_degrees)


def from_message(msg, vertex_format) -> Packing:
    """The :class:`Packing` a ``VertexPacking`` message and its SessionInfo's ``vertex_format`` describe.

    Raises WireError for an encoding this client does not know or values no
    server sends (a step that is not positive, normal bits out of range).
    """
    if msg.encoding != pb.VERTEX_ENCODING_PACKED:
        raise WireError(f"vertex encoding {msg.encoding} is unknown to this client; upgrade it, or ask for "
                        "vertex_encoding FLOAT32")
    if not (msg.position_step > 0 and msg.texcoord_step > 0 and 2 <= msg.normal_bits <= 16):
        raise WireError(f"VertexPacking with position_step {msg.position_step}, texcoord_step {msg.texcoord_step}, "
                        f"normal_bits {msg.normal_bits}: not a packing a server sends; upgrade the client")
    has_color = any(a.semantic == pb.ATTRIBUTE_SEMANTIC_COLOR for a in vertex_format.attributes)
    has_morph = any(a.semantic == pb.ATTRIBUTE_SEMANTIC_MORPH_TARGET for a in vertex_format.attributes)
    o = msg.position_origin
    return Packing(vertex_count=int(vertex_format.vertex_count), position_bits=msg.position_bits,
                   position_origin=(o.x, o.y, o.z), position_step=msg.position_step, normal_bits=msg.normal_bits,
                   texcoord_step=msg.texcoord_step, has_color=has_color, has_morph=has_morph)


def vertex_format(blocks: list, morph: bool):
    """The VertexFormat of a packed buffer's decoded payload: ``blocks``' (the mesh's float32 planar
    blocks, :func:`caveclod.wire.vertex_blocks`) plus MORPH_TARGET uint32 when ``morph``."""
    if not morph:
        return wire.vertex_format(blocks)
    d = len(blocks[0].data)
    return wire.vertex_format([*blocks, wire.VertexBlock(pb.ATTRIBUTE_SEMANTIC_MORPH_TARGET, np.zeros((d, 1), "<u4"))])


def requested_bits(open_msg) -> int | None:
    """position_bits an Open asks to pack with, or None (FLOAT32, unknown encodings and cache mode).

    Raises ValueError naming the field for position_bits out of range.
    """
    if open_msg.vertex_encoding != pb.VERTEX_ENCODING_PACKED or open_msg.HasField("cache_vertices"):
        return None
    bits = open_msg.position_bits if open_msg.HasField("position_bits") else DEFAULT_POSITION_BITS
    try:
        check_position_bits(bits)
    except ValueError as exc:
        raise ValueError(f"Open.{exc}") from None
    return bits


# -- stored in the .cvc file -------------------------------------------------------------
#
# A build packs the variants most clients ask for and stores them as the
# file's attachments (caveclod.staticmesh), so that a server serves them at
# once: packing takes about 0.5 s per million vertices, which a session
# opened after a restart would otherwise wait (8 s at 16.8M vertices).

STORED_VARIANTS = ((DEFAULT_POSITION_BITS, False), (DEFAULT_POSITION_BITS, True))   # (position_bits, morph)
STORED_FORMAT = "caveclod.packed.v1"      # the format of the streams (module doc), as packed_hash names it


def stored_meta_crc32(meta: dict) -> int:
    """CRC-32 of a stored variant's metadata but ``meta_crc32`` itself (its JSON, keys sorted): a
    header edit or bit flip that leaves valid JSON (a CRC's digit, a step) changes it."""
    rest = {k: v for k, v in meta.items() if k != "meta_crc32"}
    return zlib.crc32(json.dumps(rest, sort_keys=True).encode())


def attachment_name(position_bits: int, morph: bool) -> str:
    """The attachment of the variant packed at ``position_bits`` (with morph targets when ``morph``)."""
    return f"packed-{position_bits}" + ("-morph" if morph else "")


def attach_packed(mesh, variants=STORED_VARIANTS, progress: bool = False) -> None:
    """Pack ``mesh``'s (a :class:`caveclod.StaticMesh`) vertex buffer as each of ``variants``
    [(position_bits, morph)] and keep them in ``mesh.attachments`` (saved with the file);
    ``progress``: a bar on stderr (about 1 s a million vertices a variant)."""
    from .progress import Progress
    from .staticmesh import Attachment
    bar = Progress("packing the vertex downloads", len(variants), enabled=progress)
    targets = None
    for done, (bits, morph) in enumerate(variants):
        if morph and targets is None:
            from .refine.morphtargets import morph_targets
            targets = morph_targets(mesh)
        packed = pack(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors, bits,
                      targets if morph else None)
        p = packed.packing
        meta = {"format": STORED_FORMAT, "vertex_buffer_hash": mesh.vertex_buffer_hash,
                "vertex_count": p.vertex_count, "position_bits": p.position_bits,
                "position_origin": list(p.position_origin), "position_step": p.position_step,
                "normal_bits": p.normal_bits, "texcoord_step": p.texcoord_step, "has_color": p.has_color,
                "has_morph": p.has_morph, "decoded_crc32": packed.decoded_crc32, "packed_crc32": packed.packed_crc32,
                "max_position_error": packed.max_position_error, "max_normal_degrees": packed.max_normal_degrees}
        meta["meta_crc32"] = stored_meta_crc32(meta)
        mesh.attachments[attachment_name(bits, morph)] = Attachment(meta, np.frombuffer(packed.data, np.uint8))
        bar.update(done + 1)
    bar.close()


def stored_packed(mesh, position_bits: int, morph: bool) -> Packed | None:
    """The variant ``mesh`` stores (:func:`attach_packed`), or None where it stores none.

    Reads the packed bytes once to check their CRC. Raises ValueError (what is
    wrong, in a phrase) for a stored variant whose metadata or bytes changed
    (each has its CRC-32), that does not belong to this vertex buffer, or is
    of another format: the caller packs afresh instead.
    """
    att = mesh.attachments.get(attachment_name(position_bits, morph))
    if att is None:
        return None
    m = att.meta
    if m.get("meta_crc32") != stored_meta_crc32(m):
        raise ValueError("its metadata do not match their CRC-32 (damaged)")
    want = {"format": STORED_FORMAT, "vertex_buffer_hash": mesh.vertex_buffer_hash, "vertex_count": mesh.n_vertices,
            "position_bits": position_bits, "has_morph": bool(morph), "normal_bits": NORMAL_BITS}
    wrong = [key for key, value in want.items() if m.get(key) != value or type(m.get(key)) is not type(value)]
    if wrong:
        raise ValueError(f"its {', '.join(wrong)} do not match this mesh and caveclod")
    try:
        origin = tuple(float(v) for v in m["position_origin"])
        numbers = [float(m[k]) for k in ("position_step", "texcoord_step", "max_position_error",
                                         "max_normal_degrees")]
        crcs = [int(m[k]) for k in ("decoded_crc32", "packed_crc32")]
        if not all(0 <= c < 1 << 32 for c in crcs):
            raise ValueError
        has_color = m["has_color"]
    except (KeyError, TypeError, ValueError):
        raise ValueError("its metadata lacks a field or holds one of the wrong type or range") from None
    if len(origin) != 3 or not np.isfinite([*origin, *numbers]).all() or min(numbers[:2]) <= 0 \
            or not isinstance(has_color, bool) or has_color != bool(len(mesh.vertex_colors)):
        raise ValueError("its packing parameters are not ones pack makes for this mesh")
    if zlib.crc32(att.data) != crcs[1]:
        raise ValueError("its bytes do not match their CRC-32 (damaged)")
    packing = Packing(vertex_count=mesh.n_vertices, position_bits=position_bits, position_origin=origin,
                      position_step=numbers[0], normal_bits=NORMAL_BITS, texcoord_step=numbers[1],
                      has_color=has_color, has_morph=bool(morph))
    return Packed(packing, att.data, crcs[0], numbers[2], numbers[3], crcs[1])
