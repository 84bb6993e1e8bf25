"""The compact index-buffer delta ("op stream", FRAME_ENCODING_OPS): the encoder.

The format is specified in the proto (``SurfaceDelta.ops``) and in
:mod:`caveclod.opstream`, whose numpy decoder every client can run; this
module is the server's side: one compiled call per (camera, material) delta
that writes the op stream of the slot writes against what the client holds
(the server's copy of it, ``held``) and then applies the writes to that copy.

Why it is small: most writes of a refinement step are not new triangles.
A split re-points the corners of the faces around the split vertex (one
vertex index changes: a CORNER op, 2-3 bytes); a removal moves the buffer's
last triangle into the hole (a COPY of a triangle the client already holds,
2-3 bytes); only the faces a split creates are new, and they come in
pairs that share an edge: the first is NEW (three vertex indices,
delta-coded against the previous vertex written), the second an EDGE of it
(one vertex).
"""

import numba as nb
import numpy as np

# The format's constants, from the module that specifies it: op kinds (CORNER0 + k
# re-points corner k; EDGE0 + 3 e + p is a triangle on edge e of the previous, NEW one),
# header bits, and the limits a decoder enforces.
from ..opstream import COPY, CORNER0, EDGE0, KIND_BITS, MAX_VARINT_BYTES, N_KINDS, NEW

MAX_OP_BYTES = 21                     # worst case of one write: a 6-byte header (a 32-bit gap and 4 kind
                                      # bits) and three 5-byte deltas (33-bit zigzag)


@nb.njit(cache=True, nogil=True, inline="always")
def _put_varint(out, n, value):
    """LEB128: 7 bits a byte, low bits first, the high bit set on all but the last byte."""
    while value >= np.uint64(0x80):
        out[n] = np.uint8((value & np.uint64(0x7F)) | np.uint64(0x80))
        value >>= np.uint64(7)
        n += 1
    out[n] = np.uint8(value)
    return n + 1


@nb.njit(cache=True, nogil=True, inline="always")
def _zigzag(delta):
    """Signed -> unsigned, small magnitudes small: 0, -1, 1, -2 ... -> 0, 1, 2, 3 ..."""
    return np.uint64((delta << 1) ^ (delta >> 63))


@nb.njit(cache=True, nogil=True, inline="always")
def _key(a, b, c):
    """A 64-bit hash of one triangle (equal triangles, equal keys)."""
    return (np.uint64(a) * np.uint64(0x9E3779B97F4A7C15)) ^ (np.uint64(b) * np.uint64(0xC2B2AE3D27D4EB4F)) \
        ^ (np.uint64(c) * np.uint64(0x165667B19E3779F9))


@nb.njit(cache=True, nogil=True)
def encode_and_apply(held, old_count, new_count, slots, tris, out):
    """Write the op stream of one buffer's slot writes, then apply them to ``held``.

    Args:
        held: (capacity, 3) uint32, the client's buffer as the server keeps
            it; rows [0, old_count) are what the client holds now. Capacity
            must be at least ``new_count``.
        old_count, new_count: the buffer's length before and after.
        slots: (k,) uint32 slots written, ascending and unique, < new_count.
        tris: (k, 3) uint32 triangles written to them.
        out: (>= 8 + k * MAX_OP_BYTES,) uint8, where the stream is written.

    Returns:
        the stream's length in bytes.
    """
    k = slots.shape[0]
    # Triangles the client holds that the writes may move: those in written
    # slots and those past the new end (their slots go away).
    n_vac = 0
    for i in range(k):
        if slots[i] < old_count:
            n_vac += 1
    if new_count < old_count:
        n_vac += old_count - new_count
    vac_key = np.empty(n_vac, np.uint64)
    vac_slot = np.empty(n_vac, np.int64)
    j = 0
    for i in range(k):
        s = slots[i]
        if s < old_count:
            vac_key[j] = _key(held[s, 0], held[s, 1], held[s, 2])
            vac_slot[j] = s
            j += 1
    for s in range(new_count, old_count):
        vac_key[j] = _key(held[s, 0], held[s, 1], held[s, 2])
        vac_slot[j] = s
        j += 1
    order = np.argsort(vac_key)
    vac_key = vac_key[order]
    vac_slot = vac_slot[order]

    kinds = np.empty(k, np.uint8)
    arg = np.empty(k, np.int64)          # COPY: the source slot; CORNER, EDGE: the vertex sent
    for i in range(k):
        s = slots[i]
        a, b, c = tris[i, 0], tris[i, 1], tris[i, 2]
        kinds[i] = NEW
        if s < old_count:
            same = (held[s, 0] == a) + (held[s, 1] == b) + (held[s, 2] == c)
            if same == 2:
                corner = 0 if held[s, 0] != a else (1 if held[s, 1] != b else 2)
                kinds[i] = CORNER0 + corner
                arg[i] = tris[i, corner]
                continue
        key = _key(a, b, c)
        p = np.searchsorted(vac_key, key)
        while p < n_vac and vac_key[p] == key:
            src = vac_slot[p]
            if held[src, 0] == a and held[src, 1] == b and held[src, 2] == c:
                kinds[i] = COPY
                arg[i] = src
                break
            p += 1
        if kinds[i] == NEW and i > 0 and kinds[i - 1] == NEW:
            # A split's two faces come as a pair sharing the edge (t, u):
            # the second is the first's edge e, reversed, at corner p.
            for e in range(3):
                x, y = tris[i - 1, e], tris[i - 1, (e + 1) % 3]
                for q in range(3):
                    if tris[i, q] == y and tris[i, (q + 1) % 3] == x:
                        kinds[i] = EDGE0 + 3 * e + q
                        arg[i] = tris[i, (q + 2) % 3]
                        break
                if kinds[i] != NEW:
                    break

    n = _put_varint(out, 0, np.uint64(k))
    prev = -1
    for i in range(k):
        s = np.int64(slots[i])
        n = _put_varint(out, n, (np.uint64(s - prev - 1) << np.uint64(KIND_BITS)) | np.uint64(kinds[i]))
        prev = s
    last = np.int64(0)
    for i in range(k):
        kind = kinds[i]
        if kind == NEW:
            for q in range(3):
                v = np.int64(tris[i, q])
                n = _put_varint(out, n, _zigzag(v - last))
                last = v
        elif kind == COPY:
            n = _put_varint(out, n, np.uint64(old_count - 1 - arg[i]))
        elif kind < EDGE0:
            # A re-pointed corner moves between the two ends of a collapsed
            # edge: nearer the corner's old vertex than the stream's last.
            n = _put_varint(out, n, _zigzag(arg[i] - np.int64(held[slots[i], kind - CORNER0])))
        else:
            v = arg[i]
            n = _put_varint(out, n, _zigzag(v - last))
            last = v

    # The client applies the writes after reading every source: do the same.
    for i in range(k):
        s = slots[i]
        held[s, 0] = tris[i, 0]
        held[s, 1] = tris[i, 1]
        held[s, 2] = tris[i, 2]
    return n


# Status codes of decode: OK, or the first check that failed. The caller then
# runs caveclod.opstream's reference decoder on the same stream for the
# message (errors are rare; the reference names what was wrong in words).
DECODE_OK, DECODE_MALFORMED = 0, 1


@nb.njit(cache=True, nogil=True, inline="always")
def _unzigzag(z):
    return (z >> 1) ^ -(z & 1)


@nb.njit(cache=True, nogil=True)
def decode(ops, old, count, n_vertices):
    """The slot writes of one op stream, read against ``old``: the compiled twin of
    :func:`caveclod.opstream.decode` (same format, same checks).

    Args:
        ops: (m,) uint8, the SurfaceDelta's ``ops``.
        old: (old_count, 3) uint32, the buffer the client holds before it.
        count: the buffer's length after the delta.
        n_vertices: vertex indices must be below it.

    Returns (status, slots (n,) uint32, tris (n, 3) uint32); status is
    DECODE_OK, or DECODE_MALFORMED with empty arrays, for anything the
    reference decoder refuses.
    """
    bad = (DECODE_MALFORMED, np.zeros(0, np.uint32), np.zeros((0, 3), np.uint32))
    # Every varint first (int64: a varint holds at most 63 bits).
    values = np.empty(len(ops), np.int64)
    m = 0
    value = 0
    shift = 0
    for i in range(len(ops)):
        b = np.int64(ops[i])
        if b < 0x80:
            values[m] = value | (b << shift)
            m += 1
            value = 0
            shift = 0
        else:
            value |= (b & 0x7F) << shift
            shift += 7
            if shift >= 7 * MAX_VARINT_BYTES:
                return bad
    if shift or m == 0:
        return bad
    n = values[0]
    if n > m - 1:
        return bad
    old_count = old.shape[0]
    slots = np.empty(n, np.uint32)
    kinds = np.empty(n, np.int64)
    slot = -1
    need = 0
    grown = 0
    for i in range(n):
        h = values[1 + i]
        kind = h & 15
        gap = h >> KIND_BITS
        if kind >= N_KINDS or gap >= count:
            return bad
        slot += gap + 1
        if slot >= count:
            return bad
        slots[i] = slot
        kinds[i] = kind
        need += 3 if kind == NEW else 1
        grown += slot >= old_count
    if count > old_count and grown != count - old_count:
        return bad
    if need != m - 1 - n:
        return bad
    tris = np.empty((n, 3), np.uint32)
    p = 1 + n
    last = 0
    for i in range(n):
        kind = kinds[i]
        if kind == NEW:
            for k in range(3):
                last += _unzigzag(values[p])
                p += 1
                if last < 0 or last >= n_vertices:        # checked per vertex: the sum never overflows
                    return bad
                tris[i, k] = last
        elif kind == COPY:
            r = values[p]
            p += 1
            if r >= old_count:
                return bad
            for k in range(3):
                tris[i, k] = old[old_count - 1 - r, k]
        elif kind < EDGE0:
            s = np.int64(slots[i])
            if s >= old_count:
                return bad
            for k in range(3):
                tris[i, k] = old[s, k]
            k = kind - CORNER0
            v = np.int64(old[s, k]) + _unzigzag(values[p])
            p += 1
            if v < 0 or v >= n_vertices:
                return bad
            tris[i, k] = v
        else:
            if i == 0 or kinds[i - 1] != NEW:
                return bad
            e, q = divmod(kind - EDGE0, 3)
            last += _unzigzag(values[p])
            p += 1
            if last < 0 or last >= n_vertices:
                return bad
            tris[i, q] = tris[i - 1, (e + 1) % 3]
            tris[i, (q + 1) % 3] = tris[i - 1, e]
            tris[i, (q + 2) % 3] = last
    return DECODE_OK, slots, tris
