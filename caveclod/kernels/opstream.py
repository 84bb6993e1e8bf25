"""The compact index-buffer deltas ("op streams", FRAME_ENCODING_OPS and _OPS_LINKED): the
encoders, and compiled twins of the decoders (the load generator's).

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
(one vertex). OPS_LINKED names those vertices by the morph targets and by
the delta's other writes instead (:func:`encode_linked_and_apply`).
"""

import numba as nb
import numpy as np

# The formats' constants, from the module that specifies them: op kinds (CORNER0 + k
# re-points corner k; EDGE0 + 3 e + p is a triangle on edge e of the previous, NEW one;
# OPS_LINKED's SPLIT0, MERGE0, ADJ*), header bits, and the limits a decoder enforces.
from ..opstream import (ADJ, ADJ_TX, ADJ_TY, APPENDED_KINDS, APPENDED_PACK_LIMIT, APPENDED_PER_VARINT, COPY,
                        CORNER0, EDGE0, KIND_BITS, MAX_VARINT_BYTES, MERGE0, N_KINDS, N_LINKED_KINDS, NEW, SPLIT0,
                        Z_CHILD_X, Z_CHILD_Y, Z_DELTA, Z_MODES, Z_WRITE)

APPENDED_BASE = len(APPENDED_KINDS)

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
def _classify(held, old_count, new_count, slots, tris, kinds, arg):
    """Each write's kind against what the client holds: CORNER (one corner
    re-pointed in place; ``arg`` the new vertex), COPY (a triangle the client
    holds at another slot that the writes vacate; ``arg`` its slot) or NEW."""
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


@nb.njit(cache=True, nogil=True, inline="always")
def _put_header(out, n, gap, kind):
    return _put_varint(out, n, (np.uint64(gap) << np.uint64(KIND_BITS)) | np.uint64(kind))


@nb.njit(cache=True, nogil=True, inline="always")
def _put_new(out, n, tris, i, last):
    """NEW's payload: triangle i's three vertices as chained zigzag deltas from ``last``;
    returns (bytes written so far, the new last vertex)."""
    for q in range(3):
        v = np.int64(tris[i, q])
        n = _put_varint(out, n, _zigzag(v - last))
        last = v
    return n, last


@nb.njit(cache=True, nogil=True, inline="always")
def _apply(held, slots, tris):
    """The client applies the writes after reading every source: do the same."""
    for i in range(slots.shape[0]):
        s = slots[i]
        held[s, 0] = tris[i, 0]
        held[s, 1] = tris[i, 1]
        held[s, 2] = tris[i, 2]


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
    kinds = np.empty(k, np.uint8)
    arg = np.empty(k, np.int64)          # COPY: the source slot; CORNER, EDGE: the vertex sent
    _classify(held, old_count, new_count, slots, tris, kinds, arg)
    for i in range(1, k):
        if kinds[i] == NEW and kinds[i - 1] == NEW:
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
        n = _put_header(out, n, s - prev - 1, kinds[i])
        prev = s
    last = np.int64(0)
    for i in range(k):
        kind = kinds[i]
        if kind == NEW:
            n, last = _put_new(out, n, tris, i, last)
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
    _apply(held, slots, tris)
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def _varint_bytes(value):
    """Bytes of ``value`` (>= 0) as a LEB128 varint."""
    n = 1
    while value >= 0x80:
        value >>= 7
        n += 1
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def _bucket(key, shift):
    """Fibonacci hashing: the top bits of key * 2**64 / phi."""
    return np.int64((key * np.uint64(0x9E3779B97F4A7C15)) >> shift)


@nb.njit(cache=True, nogil=True, inline="always")
def _named_before(kinds, j, i):
    """May write i name write j? Base writes anywhere, NEW and ADJ writes before i."""
    return j != i and (j < i or (kinds[j] >= COPY and kinds[j] < ADJ))


@nb.njit(cache=True, nogil=True)
def encode_linked_and_apply(held, old_count, new_count, slots, tris, targets, rank, out):
    """:func:`encode_and_apply` for FRAME_ENCODING_OPS_LINKED.

    A re-pointed corner whose new vertex is a child of the old one (a
    split) becomes SPLIT (its rank among the children); one whose new vertex
    is the old one's target (a collapse), MERGE. A new triangle becomes ADJ
    where another write of the delta holds one of its edges, reversed (the
    faces around a split share edges with the faces it re-points or makes),
    when that is shorter: the nearest such write, and the shortest name of
    the third vertex (ADJ_TX and ADJ_TY name a target of an end of the edge
    by the kind alone).

    Args (besides :func:`encode_and_apply`'s):
        targets: (d,) uint32 morph targets (a vertex's own index without one).
        rank: (d,) uint8 each vertex's place among its target's children
            (:func:`caveclod.opstream.child_ranks`; 255: too far, named
            another way).
    """
    k = slots.shape[0]
    kinds = np.empty(k, np.uint8)
    arg = np.empty(k, np.int64)          # COPY: source slot; CORNER: new vertex; SPLIT: rank; ADJ: first varint
    arg2 = np.zeros(k, np.int64)         # ADJ: second varint
    _classify(held, old_count, new_count, slots, tris, kinds, arg)
    for i in range(k):
        kind = kinds[i]
        if kind >= CORNER0 and kind < CORNER0 + 3:
            c = kind - CORNER0
            o = np.int64(held[slots[i], c])
            w = arg[i]
            if targets[w] == o and w != o and rank[w] < 255:
                kinds[i] = SPLIT0 + c
                arg[i] = np.int64(rank[w])
            elif targets[o] == w and o != w:
                kinds[i] = MERGE0 + c

    # Every write's directed edges (a << 32 | b) and vertices in two small hash
    # tables (open addressing), to find the writes that hold an edge or a vertex
    # of a new triangle: sorting them cost four times the rest of the encoder.
    bits = 4
    while (1 << bits) < 6 * k:
        bits += 1
    mask = (1 << bits) - 1
    shift = np.uint64(64 - bits)
    edge_at = np.full(1 << bits, -1, np.int64)        # 3 j + e of the write holding the edge
    edge_key = np.empty(1 << bits, np.uint64)
    vert_at = np.full(1 << bits, -1, np.int64)        # 3 j + corner of the write holding the vertex
    vert_key = np.empty(1 << bits, np.int64)
    for i in range(k):
        for e in range(3):
            key = (np.uint64(tris[i, e]) << np.uint64(32)) | np.uint64(tris[i, (e + 1) % 3])
            h = _bucket(key, shift)
            while edge_at[h] >= 0:
                h = (h + 1) & mask
            edge_at[h] = 3 * i + e
            edge_key[h] = key
            v = np.int64(tris[i, e])
            h = _bucket(np.uint64(v), shift)
            while vert_at[h] >= 0:
                h = (h + 1) & mask
            vert_at[h] = 3 * i + e
            vert_key[h] = v

    last = np.int64(0)
    for i in range(k):
        if kinds[i] != NEW:
            continue
        a, b, c = np.int64(tris[i, 0]), np.int64(tris[i, 1]), np.int64(tris[i, 2])
        best = _varint_bytes(_zigzag(a - last)) + _varint_bytes(_zigzag(b - a)) + _varint_bytes(_zigzag(c - b))
        h_best = -1
        w_best = 0
        kind_best = ADJ
        for q in range(3):
            y = np.int64(tris[i, q])
            x = np.int64(tris[i, (q + 1) % 3])
            z = np.int64(tris[i, (q + 2) % 3])
            key = (np.uint64(x) << np.uint64(32)) | np.uint64(y)
            p = _bucket(key, shift)
            h = -1
            h_cost = 99
            while edge_at[p] >= 0:                 # the nearest write holding the edge (x, y)
                if edge_key[p] == key:
                    j, e = divmod(edge_at[p], 3)
                    hv = np.int64(_zigzag(j - i)) * 9 + 3 * e + q
                    if _named_before(kinds, j, i) and (h < 0 or hv < h):
                        h, h_cost = hv, _varint_bytes(hv)
                p = (p + 1) & mask
            if h < 0 or h_cost >= best:
                continue
            # The third vertex: the shortest of its names (a target of an end of the
            # edge is named by the kind alone).
            kind = ADJ
            if targets[x] == z and x != z:
                kind, w, w_cost = ADJ_TX, 0, 0
            elif targets[y] == z and y != z:
                kind, w, w_cost = ADJ_TY, 0, 0
            else:
                w = np.int64(_zigzag(z - last)) * Z_MODES + Z_DELTA
                w_cost = _varint_bytes(w)
            rz = np.int64(rank[z])
            if targets[z] == x and z != x and rz < 255 and _varint_bytes(rz * Z_MODES + Z_CHILD_X) < w_cost:
                w = rz * Z_MODES + Z_CHILD_X
                w_cost = _varint_bytes(w)
            if targets[z] == y and z != y and rz < 255 and _varint_bytes(rz * Z_MODES + Z_CHILD_Y) < w_cost:
                w = rz * Z_MODES + Z_CHILD_Y
                w_cost = _varint_bytes(w)
            if w_cost > 1:
                p = _bucket(np.uint64(z), shift)
                while vert_at[p] >= 0:             # the nearest write holding z, if that is shorter
                    if vert_key[p] == z:
                        j, corner = divmod(vert_at[p], 3)
                        wv = (np.int64(_zigzag(j - i)) * 3 + corner) * Z_MODES + Z_WRITE
                        if _named_before(kinds, j, i) and _varint_bytes(wv) < w_cost:
                            w, w_cost = wv, _varint_bytes(wv)
                    p = (p + 1) & mask
            if h_cost + w_cost < best:
                best = h_cost + w_cost
                h_best, w_best, kind_best = h, w, kind
        if h_best >= 0:
            kinds[i] = kind_best
            arg[i] = h_best
            arg2[i] = w_best
            if kind_best == ADJ and w_best % Z_MODES == Z_DELTA:
                q = (h_best % 3 + 2) % 3
                last = np.int64(tris[i, q])
        else:
            last = c

    n = _put_varint(out, 0, np.uint64(k))
    appended = max(new_count - old_count, 0)
    prev = -1
    for i in range(k - appended):
        s = np.int64(slots[i])
        n = _put_header(out, n, s - prev - 1, kinds[i])
        prev = s
    for g in range(k - appended, k, APPENDED_PER_VARINT):
        pack = np.uint64(0)
        scale = np.uint64(1)
        for i in range(g, min(g + APPENDED_PER_VARINT, k)):
            # APPENDED_KINDS: NEW, COPY, ADJ, ADJ_TX, ADJ_TY
            code = 0 if kinds[i] == NEW else (1 if kinds[i] == COPY else kinds[i] - ADJ + 2)
            pack += np.uint64(code) * scale
            scale *= np.uint64(APPENDED_BASE)
        n = _put_varint(out, n, pack)
    last = np.int64(0)
    for i in range(k):
        kind = kinds[i]
        if kind == NEW:
            n, last = _put_new(out, n, tris, i, last)
        elif kind == COPY:
            n = _put_varint(out, n, np.uint64(old_count - 1 - arg[i]))
        elif kind < SPLIT0:
            n = _put_varint(out, n, _zigzag(arg[i] - np.int64(held[slots[i], kind - CORNER0])))
        elif kind < MERGE0:
            n = _put_varint(out, n, np.uint64(arg[i]))
        elif kind >= ADJ:
            n = _put_varint(out, n, np.uint64(arg[i]))
            if kind == ADJ:
                n = _put_varint(out, n, np.uint64(arg2[i]))
                if arg2[i] % Z_MODES == Z_DELTA:
                    last = np.int64(tris[i, (arg[i] % 3 + 2) % 3])
    _apply(held, slots, tris)
    return n


# Status codes of decode: OK, or the first check that failed. The caller then
# runs caveclod.opstream's reference decoder on the same stream for the
# message (errors are rare; the reference names what was wrong in words).
DECODE_OK, DECODE_MALFORMED = 0, 1


@nb.njit(cache=True, nogil=True, inline="always")
def _unzigzag(z):
    return (z >> 1) ^ -(z & 1)


@nb.njit(cache=True, nogil=True, inline="always")
def _read_varints(ops):
    """(values (m,) int64, m): every varint of ``ops`` first (a varint holds at most
    63 bits); m = 0 for an empty stream, -1 for a cut-off or too long varint."""
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
                return values, -1
    if shift:
        return values, -1
    return values, m


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
    values, m = _read_varints(ops)
    if m <= 0:
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


@nb.njit(cache=True, nogil=True)
def decode_linked(ops, old, count, targets, child_start, children):
    """The compiled twin of :func:`caveclod.opstream.decode_linked` (same format,
    same checks): (status, slots (n,) uint32, tris (n, 3) uint32).

    Args:
        ops, old, count: as :func:`decode`.
        targets, child_start, children: :class:`caveclod.opstream.Links`'
            arrays (int64); vertex indices must be below ``len(targets)``.
    """
    bad = (DECODE_MALFORMED, np.zeros(0, np.uint32), np.zeros((0, 3), np.uint32))
    n_vertices = targets.shape[0]
    values, m = _read_varints(ops)
    if m <= 0:
        return bad
    n = values[0]
    old_count = old.shape[0]
    appended = max(count - old_count, 0)       # slots old_count .. count - 1, every one written
    in_place = n - appended
    packs = (appended + APPENDED_PER_VARINT - 1) // APPENDED_PER_VARINT
    if in_place < 0 or in_place + packs > m - 1:
        return bad
    slots = np.empty(n, np.uint32)
    kinds = np.empty(n, np.int64)
    first = np.empty(n, np.int64)
    slot = -1
    for i in range(in_place):
        h = values[1 + i]
        kind = h & 15
        gap = h >> KIND_BITS
        if kind >= N_LINKED_KINDS or gap >= count:
            return bad
        slot += gap + 1
        if slot >= old_count or slot >= count:
            return bad
        slots[i] = slot
        kinds[i] = kind
    for g in range(packs):
        pack = values[1 + in_place + g]
        if pack >= APPENDED_PACK_LIMIT:
            return bad
        for t in range(APPENDED_PER_VARINT):
            i = in_place + APPENDED_PER_VARINT * g + t
            if i < n:
                code = pack % APPENDED_BASE
                kinds[i] = NEW if code == 0 else (COPY if code == 1 else ADJ + code - 2)
                slots[i] = old_count + (i - in_place)
            pack //= APPENDED_BASE
    need = 0
    for i in range(n):
        kind = kinds[i]
        first[i] = 1 + in_place + packs + need
        need += 3 if kind == NEW else (2 if kind == ADJ else (0 if MERGE0 <= kind < ADJ else 1))
    if need != m - 1 - in_place - packs:
        return bad
    tris = np.empty((n, 3), np.uint32)
    done = np.zeros(n, np.bool_)
    for i in range(n):                          # the base writes: from the old buffer
        kind = kinds[i]
        if kind == COPY:
            r = values[first[i]]
            if r >= old_count:
                return bad
            for q in range(3):
                tris[i, q] = old[old_count - 1 - r, q]
        elif kind >= CORNER0 and kind < ADJ:
            s = np.int64(slots[i])
            if s >= old_count:
                return bad
            for q in range(3):
                tris[i, q] = old[s, q]
            if kind < SPLIT0:
                c = kind - CORNER0
                v = np.int64(old[s, c]) + _unzigzag(values[first[i]])
            elif kind < MERGE0:
                c = kind - SPLIT0
                x = np.int64(old[s, c])
                r = values[first[i]]
                if x >= n_vertices or r >= child_start[x + 1] - child_start[x]:
                    return bad
                v = children[child_start[x] + r]
            else:
                c = kind - MERGE0
                x = np.int64(old[s, c])
                if x >= n_vertices:
                    return bad
                v = targets[x]
            if v < 0 or v >= n_vertices:
                return bad
            tris[i, c] = v
        else:
            continue
        done[i] = True
    last = 0
    for i in range(n):                          # then NEW and ADJ, in stream order
        kind = kinds[i]
        p = first[i]
        if kind == NEW:
            for q in range(3):
                last += _unzigzag(values[p + q])
                if last < 0 or last >= n_vertices:
                    return bad
                tris[i, q] = last
        elif kind >= ADJ:
            h = values[p]
            w = values[p + 1] if kind == ADJ else 0
            step = h // 9
            e = (h % 9) // 3
            q = h % 3
            j = i + _unzigzag(step)
            if j < 0 or j >= n or j == i or not done[j]:
                return bad
            x = np.int64(tris[j, e])
            y = np.int64(tris[j, (e + 1) % 3])
            v = w // Z_MODES
            mode = w % Z_MODES
            if kind == ADJ_TX or kind == ADJ_TY:
                z = targets[x if kind == ADJ_TX else y]
            elif mode == Z_DELTA:
                last += _unzigzag(v)
                if last < 0 or last >= n_vertices:
                    return bad
                z = last
            elif mode == Z_CHILD_X or mode == Z_CHILD_Y:
                o = x if mode == Z_CHILD_X else y
                if v >= child_start[o + 1] - child_start[o]:
                    return bad
                z = children[child_start[o] + v]
            else:
                j2 = i + _unzigzag(v // 3)
                if j2 < 0 or j2 >= n or j2 == i or not done[j2]:
                    return bad
                z = np.int64(tris[j2, v % 3])
            tris[i, q] = y
            tris[i, (q + 1) % 3] = x
            tris[i, (q + 2) % 3] = z
        done[i] = True
    return DECODE_OK, slots, tris
