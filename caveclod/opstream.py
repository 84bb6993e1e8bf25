"""The compact index-buffer delta ("op stream", FRAME_ENCODING_OPS): the format and its decoder
(and, below, FRAME_ENCODING_OPS_LINKED's: :func:`decode_linked`).

Numpy only, so the thin client runs it (the server's encoder is the compiled
:func:`caveclod.kernels.opstream.encode_and_apply`; a compiled twin of the
decoder, for the load generator, decodes inside
:func:`compiled_decoding`). The proto's
``SurfaceDelta.ops`` comment is the specification for other languages; in
short, a stream of LEB128 varints:

``n`` (the number of slot writes), then ``n`` headers, then the payloads of
the writes, in slot order. A header is ``(gap << 4) | kind``, where ``gap``
is the number of slots skipped since the previous write (the first write's
slot is its gap). Kinds and their payloads, read against the buffer as the
client holds it *before* this delta (``old``, ``old_count`` rows):

* ``0`` NEW: three vertex deltas; the triangle is the three vertices.
* ``1`` COPY: ``r``; the triangle is ``old[old_count - 1 - r]`` (the last
  triangle moved into a hole, mostly).
* ``2 + k`` CORNER (k = 0, 1, 2): one zigzag delta; the triangle is
  ``old[slot]`` with corner ``k`` replaced by ``old[slot][k] + delta``.
* ``5 + 3e + p`` EDGE (e, p = 0, 1, 2): one vertex delta; the previous write
  must be a NEW triangle ``P``; this one has ``P[(e + 1) % 3]`` at corner
  ``p``, ``P[e]`` at corner ``(p + 1) % 3`` (P's edge e, reversed: the
  other face of a split) and the vertex at corner ``(p + 2) % 3``.

Deltas are zigzag-coded (``(d << 1) ^ (d >> 63)``). The vertex deltas of NEW
and EDGE are chained: each vertex is the previous such vertex of the stream
(0 at its start) plus its delta.

Because the headers come first and every kind has a fixed payload length,
a decoder needs no loop per write: numpy reads every varint at once, then
gathers. Anything inconsistent raises :class:`caveclod.wire.WireError`
(the client then asks for a keyframe), never a wrong buffer.
"""

from __future__ import annotations

import contextlib

import numpy as np

NEW, COPY, CORNER0, EDGE0 = 0, 1, 2, 5
KIND_BITS = 4
N_KINDS = EDGE0 + 9                   # kinds 14 and 15 are invalid
PAYLOAD_VARINTS = np.array([3] + [1] * (N_KINDS - 1), np.int64)   # varints each kind's payload holds
MAX_VARINT_BYTES = 9                  # 63 bits: more is malformed
# Streams up to this many bytes (a converged camera's frame: a few dozen
# writes) are decoded by a plain loop: numpy's ~60 calls a stream cost more
# than the loop for them (70 us against about 20 for 16 writes).
SMALL_BYTES = 384


# The compiled decoders (caveclod.kernels.opstream.decode, .decode_linked) inside
# compiled_decoding(); None: the numpy decoders below.
_compiled = None
_compiled_linked = None


@contextlib.contextmanager
def compiled_decoding(on: bool = True):
    """Within the block, this process decodes op streams with the compiled
    kernel (``on``) or with numpy (not ``on``); yields True where the kernel
    is in use. The decoder before comes back at the end.

    The kernel needs numba (``caveclod[build]``); without it numpy decodes
    and this yields False. It compiles (or loads from numba's cache) here,
    not in the first frame. ``caveclod loadtest`` decodes with it: with
    numpy decoding is a quarter of its CPU (16 us a small stream; 2 with
    the kernel). Thin clients keep numpy: no compiler, no start-up cost.
    Both read the same streams the same way; the kernel only says whether
    a stream is well formed, and one it refuses goes through the numpy
    decoder for the error's words.
    """
    global _compiled, _compiled_linked
    before = _compiled, _compiled_linked
    _compiled = _compiled_linked = None
    if on:
        try:
            from .kernels import opstream as kernels
        except ImportError:                  # numba is not installed
            kernels = None
        if kernels is not None:
            empty, none = np.frombuffer(b"\x00", np.uint8), np.zeros((0, 3), np.uint32)
            kernels.decode(empty, none, 0, 1)                                          # compiled here
            kernels.decode_linked(empty, none, 0, *_children(np.zeros(1, np.uint32)))
            _compiled, _compiled_linked = kernels.decode, kernels.decode_linked
    try:
        yield _compiled is not None
    finally:
        _compiled, _compiled_linked = before


class OpStreamError(ValueError):
    """An op stream that does not decode against the buffer it is applied to (one line)."""


def read_varints(data: bytes) -> np.ndarray:
    """Every LEB128 varint of ``data``, at once: (m,) uint64.

    Raises OpStreamError for a truncated last varint or one longer than
    MAX_VARINT_BYTES.
    """
    b = np.frombuffer(data, np.uint8)
    if len(b) == 0:
        return np.zeros(0, np.uint64)
    if b[-1] & 0x80:
        raise OpStreamError(f"the op stream's last varint is cut off ({len(b)} bytes)")
    ends = np.flatnonzero(b < 0x80)                      # the last byte of each varint
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    lengths = ends - starts + 1
    if lengths.max() > MAX_VARINT_BYTES:
        raise OpStreamError(f"a varint of {int(lengths.max())} bytes in the op stream (at most {MAX_VARINT_BYTES})")
    # Byte i of a varint carries bits 7i .. 7i + 6 of its value.
    place = np.arange(len(b), dtype=np.int64) - np.repeat(starts, lengths)
    bits = (b & 0x7F).astype(np.uint64) << (7 * place).astype(np.uint64)
    return np.add.reduceat(bits, starts)


def decode(ops: bytes, old: np.ndarray, count: int, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The slot writes an op stream encodes: (slots (n,) uint32, tris (n, 3) uint32).

    Args:
        ops: the SurfaceDelta's ``ops`` bytes.
        old: (old_count, 3) uint32, the buffer as the client holds it before
            this delta (rows of the previous frame; the delta's own writes
            never read each other).
        count: the SurfaceDelta's count (the buffer's length after).
        n_vertices: vertex indices must be below it.

    Raises OpStreamError naming the first thing wrong: a stream that is cut
    off or too long, an unknown kind, a slot at or past ``count``, a COPY
    from outside ``old``, a CORNER of a slot ``old`` does not have, a vertex
    index out of range.
    """
    if _compiled is not None:
        status, slots, tris = _compiled(np.frombuffer(ops, np.uint8), old, count, n_vertices)
        if status == 0:
            return slots, tris
        # Malformed: the numpy decoders below raise, naming what is wrong.
    if len(ops) <= SMALL_BYTES:
        return _decode_small(ops, old, count, n_vertices)
    return _decode_vectorized(ops, old, count, n_vertices)


def _decode_vectorized(ops: bytes, old: np.ndarray, count: int, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`decode` with numpy and no loop per write (long streams)."""
    values = read_varints(ops)
    if len(values) == 0:
        raise OpStreamError("an empty op stream (it starts with the number of writes)")
    n = int(values[0])
    if n > len(values) - 1:
        raise OpStreamError(f"the op stream announces {n} writes but holds {len(values) - 1} varints")
    headers, payload = values[1:1 + n], values[1 + n:]
    kinds = (headers & np.uint64((1 << KIND_BITS) - 1)).astype(np.int64)
    if n and kinds.max() >= N_KINDS:
        raise OpStreamError(f"op kind {int(kinds.max())} is unknown (0 NEW, 1 COPY, 2-4 CORNER, 5-13 EDGE)")
    gaps = headers >> KIND_BITS
    if n and int(gaps.max()) >= count:
        raise OpStreamError(f"a slot gap of {int(gaps.max())} in a buffer of {count} triangles")
    slots = np.cumsum(gaps.astype(np.int64) + 1) - 1
    if n and int(slots[-1]) >= count:
        raise OpStreamError(f"slot {int(slots[-1])} past the count {count}")
    if count > len(old) and int((slots >= len(old)).sum()) != count - len(old):
        raise OpStreamError(f"the buffer grows from {len(old)} to {count} triangles but not every new slot is written")
    widths = PAYLOAD_VARINTS[kinds]
    if int(widths.sum()) != len(payload):
        raise OpStreamError(f"{n} writes need {int(widths.sum())} payload varints, the stream holds {len(payload)}")
    first = np.cumsum(widths) - widths                   # each write's first payload varint
    old_count = len(old)
    tris = np.empty((n, 3), np.uint32)

    # The chained vertex deltas: every NEW's three and every EDGE's one, in stream order.
    chained = (kinds == NEW) | (kinds >= EDGE0)
    vertices = _vertices(payload[np.repeat(chained, widths)], n_vertices)
    in_chain = np.where(chained, widths, 0)
    where = np.cumsum(in_chain) - in_chain               # each write's first chained vertex

    new = np.flatnonzero(kinds == NEW)
    if len(new):
        tris[new] = vertices[where[new, None] + np.arange(3)]
    edge = np.flatnonzero(kinds >= EDGE0)
    if len(edge):
        if edge[0] == 0 or (kinds[edge - 1] != NEW).any():
            raise OpStreamError("an EDGE write that does not follow a NEW one")
        e, p = np.divmod(kinds[edge] - EDGE0, 3)
        prev = tris[edge - 1]
        rows = np.arange(len(edge))
        tris[edge, p] = prev[rows, (e + 1) % 3]
        tris[edge, (p + 1) % 3] = prev[rows, e]
        tris[edge, (p + 2) % 3] = vertices[where[edge]]
    copy = np.flatnonzero(kinds == COPY)
    if len(copy):
        r = payload[first[copy]]
        if int(r.max()) >= old_count:
            raise OpStreamError(f"a COPY from {int(r.max())} slots before the end of a buffer of {old_count}")
        tris[copy] = old[old_count - 1 - r.astype(np.int64)]
    corner = np.flatnonzero((kinds >= CORNER0) & (kinds < EDGE0))
    if len(corner):
        s = slots[corner]
        if int(s.max()) >= old_count:
            raise OpStreamError(f"a CORNER write to slot {int(s.max())}, which the buffer of {old_count} "
                                "triangles does not hold yet")
        k = kinds[corner] - CORNER0
        tris[corner] = old[s]
        d = payload[first[corner]]
        v = old[s, k].astype(np.int64) + _signed(d)
        if (d >= np.uint64(1 << 34)).any() or int(v.min()) < 0 or int(v.max()) >= n_vertices:
            raise OpStreamError(f"a CORNER write to a vertex outside the vertex buffer's {n_vertices} vertices")
        tris[corner, k] = v
    return slots.astype(np.uint32), tris


def _signed(zigzag: np.ndarray) -> np.ndarray:
    """Zigzag-decoded (n,) uint64 -> int64: 0, 1, 2, 3 ... -> 0, -1, 1, -2 ..."""
    return (zigzag >> np.uint64(1)).astype(np.int64) ^ -(zigzag & np.uint64(1)).astype(np.int64)


def _vertices(deltas: np.ndarray, n_vertices: int) -> np.ndarray:
    """The chained vertex indices of (m,) zigzag deltas, checked to lie in [0, n_vertices)."""
    if len(deltas) and int(deltas.max()) >= 1 << 34:
        raise OpStreamError("a vertex delta too large for any vertex buffer")
    vertices = np.cumsum(_signed(deltas))
    if len(vertices) and (int(vertices.min()) < 0 or int(vertices.max()) >= n_vertices):
        bad = int(vertices.min()) if int(vertices.min()) < 0 else int(vertices.max())
        raise OpStreamError(f"vertex index {bad} outside the vertex buffer's {n_vertices} vertices")
    return vertices


def _decode_small(ops: bytes, old: np.ndarray, count: int, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`decode`, a varint and a write at a time (short streams); the same checks and errors."""
    values = _varint_list(ops)           # every varint first: then the same checks as the numpy path
    n = values[0]
    if n > len(values) - 1:
        raise OpStreamError(f"the op stream announces {n} writes but holds {len(values) - 1} varints")
    old_count = len(old)
    slots, kinds = _headers(values[1:1 + n], count, N_KINDS, "0 NEW, 1 COPY, 2-4 CORNER, 5-13 EDGE")
    if slots and slots[-1] >= count:
        raise OpStreamError(f"slot {slots[-1]} past the count {count}")
    if count > old_count and sum(s >= old_count for s in slots) != count - old_count:
        raise OpStreamError(f"the buffer grows from {old_count} to {count} triangles but not every new slot is written")
    need = sum(3 if k == NEW else 1 for k in kinds)
    if need != len(values) - 1 - n:
        raise OpStreamError(f"{n} writes need {need} payload varints, the stream holds {len(values) - 1 - n}")
    tris = []
    p, last = 1 + n, 0
    for i, (kind, slot) in enumerate(zip(kinds, slots)):
        if kind == NEW:
            tri = []
            for _ in range(3):
                z = values[p]
                p += 1
                last += (z >> 1) ^ -(z & 1)
                tri.append(last)
        elif kind == COPY:
            r = values[p]
            p += 1
            if r >= old_count:
                raise OpStreamError(f"a COPY from {r} slots before the end of a buffer of {old_count}")
            tri = old[old_count - 1 - r].tolist()
        elif kind < EDGE0:
            if slot >= old_count:
                raise OpStreamError(f"a CORNER write to slot {slot}, which the buffer of {old_count} "
                                    "triangles does not hold yet")
            z = values[p]
            p += 1
            tri = old[slot].tolist()
            v = tri[kind - CORNER0] + ((z >> 1) ^ -(z & 1))
            if not 0 <= v < n_vertices:
                raise OpStreamError(f"a CORNER write to a vertex outside the vertex buffer's {n_vertices} vertices")
            tri[kind - CORNER0] = v
        else:
            if i == 0 or kinds[i - 1] != NEW:
                raise OpStreamError("an EDGE write that does not follow a NEW one")
            e, q = divmod(kind - EDGE0, 3)
            z = values[p]
            p += 1
            last += (z >> 1) ^ -(z & 1)
            prev = tris[-1]
            tri = [0, 0, 0]
            tri[q], tri[(q + 1) % 3], tri[(q + 2) % 3] = prev[(e + 1) % 3], prev[e], last
        if kind == NEW and not all(0 <= v < n_vertices for v in tri):
            bad = min(tri) if min(tri) < 0 else max(tri)
            raise OpStreamError(f"vertex index {bad} outside the vertex buffer's {n_vertices} vertices")
        if kind >= EDGE0 and not 0 <= last < n_vertices:
            raise OpStreamError(f"vertex index {last} outside the vertex buffer's {n_vertices} vertices")
        tris.append(tri)
    return np.array(slots, np.uint32), np.array(tris, np.uint32).reshape(-1, 3)


def _headers(headers: list, count: int, n_kinds: int, names: str) -> tuple[list, list]:
    """(slots, kinds) of write headers ``(gap << 4) | kind``; OpStreamError for a kind
    of ``n_kinds`` or more (``names`` says which there are) or a gap past ``count``."""
    slots, kinds, slot = [], [], -1
    for h in headers:
        kind, gap = h & 15, h >> KIND_BITS
        if kind >= n_kinds:
            raise OpStreamError(f"op kind {kind} is unknown ({names})")
        if gap >= count:
            raise OpStreamError(f"a slot gap of {gap} in a buffer of {count} triangles")
        slot += gap + 1
        slots.append(slot)
        kinds.append(kind)
    return slots, kinds


def _varint_list(ops: bytes) -> list:
    """Every LEB128 varint of ``ops`` as Python ints, a byte at a time (short streams);
    raises OpStreamError for an empty stream, a cut-off varint or one too long."""
    values = []
    append = values.append
    value = shift = 0
    for b in bytes(ops):
        if b < 0x80:
            append(value | (b << shift))
            value = shift = 0
            continue
        value |= (b & 0x7F) << shift
        shift += 7
        if shift >= 7 * MAX_VARINT_BYTES:
            raise OpStreamError(f"a varint of more than {MAX_VARINT_BYTES} bytes in the op stream "
                                f"(at most {MAX_VARINT_BYTES})")
    if shift:
        raise OpStreamError(f"the op stream's last varint is cut off ({len(ops)} bytes)")
    if not values:
        raise OpStreamError("an empty op stream (it starts with the number of writes)")
    return values


# -- FRAME_ENCODING_OPS_LINKED: op streams that also read the morph targets ---------------
#
# A split re-points the faces around the split vertex onto a vertex whose
# morph target is the one they leave, and makes two faces on edges of faces
# the same delta writes; a collapse re-points them back onto the target. A
# client that holds the vertex buffer's morph targets (Open.morph_targets)
# can therefore follow names shorter than vertex deltas: "the r-th child of
# the corner's vertex", "its target", "on edge e of write j". The header and
# the kinds 0-4 are OPS's; EDGE's kinds give way to these:
SPLIT0 = 5        # + c: corner c becomes the r-th child of the vertex there (payload r)
MERGE0 = 8        # + c: corner c becomes the target of the vertex there (no payload)
ADJ = 11          # a triangle on an edge of another write of the delta (payload: where, which vertex)
ADJ_TX = 12       # ADJ whose third vertex is the target of the edge's first end x (payload: where)
ADJ_TY = 13       # ... of its second end y (the commonest names: a split's faces reach the vertex split)
N_LINKED_KINDS = 14                   # kinds 14 and 15 are invalid
LINKED_PAYLOAD_VARINTS = (3, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 2, 1, 1)
# How ADJ names its third vertex z (the low part of its second varint, base Z_MODES).
Z_DELTA, Z_CHILD_X, Z_CHILD_Y, Z_WRITE = range(4)
Z_MODES = 4
LINKED_KIND_NAMES = "0 NEW, 1 COPY, 2-4 CORNER, 5-7 SPLIT, 8-10 MERGE, 11-13 ADJ"
# Writes to the slots a buffer grows by need no slot; their kinds (nothing is there to
# re-point) go three to a varint, k0 + 5 k1 + 25 k2, as indices into APPENDED_KINDS.
APPENDED_KINDS = (NEW, COPY, ADJ, ADJ_TX, ADJ_TY)
APPENDED_PER_VARINT = 3
APPENDED_PACK_LIMIT = len(APPENDED_KINDS) ** APPENDED_PER_VARINT


def _children(targets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(targets (d,) uint32, child_start (d + 1,) int32, children (m,) int32): the
    vertices whose target is x, other than x, are children[child_start[x]:child_start[x + 1]],
    ascending. Raises ValueError for targets outside the buffer."""
    t = np.asarray(targets).reshape(-1)
    d = len(t)
    if d and (int(t.min()) < 0 or int(t.max()) >= d):
        raise ValueError(f"morph targets outside the vertex buffer's {d} vertices")
    t = t.astype(np.uint32, copy=False)
    own = t == np.arange(d, dtype=np.uint32)
    order = np.argsort(np.where(own, d, t), kind="stable")     # children grouped by target, ascending
    child_start = np.zeros(d + 1, np.int32)                    # 32 bits: morph targets stay under 2**30 vertices
    np.cumsum(np.bincount(t[~own], minlength=d), out=child_start[1:])
    return t, child_start, order[: int(child_start[-1])].astype(np.int32)


def child_ranks(targets: np.ndarray) -> np.ndarray:
    """(d,) uint8: each vertex's place among its target's children (0 without a
    target), 255 from the 255th on (an encoder names those another way)."""
    t, child_start, children = _children(targets)
    rank = np.zeros(len(t), np.uint8)
    rank[children] = np.minimum(np.arange(len(children)) - child_start[t[children]], 255)
    return rank


class Links:
    """The morph-target relation an OPS_LINKED stream names vertices by.

    ``targets`` (d,) is :attr:`caveclod.client.protocol.VertexBuffer.morph_targets`
    (a vertex's own index where it has none). The *children* of vertex ``x``
    are the other vertices whose target is ``x``, in ascending index order.
    Built once per vertex buffer (an argsort: about 0.04 s a million
    vertices; 12 bytes a vertex).
    """

    def __init__(self, targets: np.ndarray):
        # Its own writable copy of the targets: a view of the downloaded payload is
        # read-only, which the compiled decoder would take as another type to compile.
        self.targets, self.child_start, self.children = _children(np.array(targets, np.uint32))

    @property
    def n_vertices(self) -> int:
        return len(self.targets)

    def child(self, x: int, r: int) -> int:
        """The r-th child of vertex x; OpStreamError where x has no such child."""
        lo, hi = int(self.child_start[x]), int(self.child_start[x + 1])
        if not 0 <= r < hi - lo:
            raise OpStreamError(f"child {r} of vertex {x}, which has {hi - lo} (see the morph targets)")
        return int(self.children[lo + r])


def decode_linked(ops: bytes, old: np.ndarray, count: int, links: Links) -> tuple[np.ndarray, np.ndarray]:
    """The slot writes of an OPS_LINKED stream: (slots (n,) uint32, tris (n, 3) uint32).

    As :func:`decode`, with vertex indices below ``links.n_vertices``. The
    base writes (COPY, CORNER, SPLIT, MERGE) read only ``old``; the NEW and
    ADJ writes are then made in stream order (an ADJ reads the write it
    names, so there is a loop per write: about 2 us each).
    """
    if _compiled_linked is not None:
        status, slots, tris = _compiled_linked(np.frombuffer(ops, np.uint8), old, count, links.targets,
                                               links.child_start, links.children)
        if status == 0:
            return slots, tris
    n_vertices = links.n_vertices
    values = _varint_list(ops)
    n = values[0]
    old_count = len(old)
    appended = max(count - old_count, 0)      # slots old_count .. count - 1, every one written
    in_place = n - appended
    packs = -(-appended // APPENDED_PER_VARINT)
    if in_place < 0:
        raise OpStreamError(f"the buffer grows from {old_count} to {count} triangles but the op stream "
                            f"announces only {n} writes")
    if in_place + packs > len(values) - 1:
        raise OpStreamError(f"the op stream announces {n} writes but holds {len(values) - 1} varints")
    slots, kinds = _headers(values[1:1 + in_place], count, N_LINKED_KINDS, LINKED_KIND_NAMES)
    first, need = [], 0
    if slots and slots[-1] >= min(old_count, count):
        raise OpStreamError(f"slot {slots[-1]} of an in-place write, past the {min(old_count, count)} slots the "
                            "buffer keeps")
    for pack in values[1 + in_place:1 + in_place + packs]:
        if pack >= APPENDED_PACK_LIMIT:
            raise OpStreamError(f"appended writes' kinds {pack} (at most {APPENDED_PACK_LIMIT - 1})")
        for _ in range(min(APPENDED_PER_VARINT, appended - (len(kinds) - in_place))):
            pack, code = divmod(pack, len(APPENDED_KINDS))
            kinds.append(APPENDED_KINDS[code])
    slots += range(old_count, old_count + appended)
    for kind in kinds:
        first.append(1 + in_place + packs + need)
        need += LINKED_PAYLOAD_VARINTS[kind]
    if need != len(values) - 1 - in_place - packs:
        raise OpStreamError(f"{n} writes need {need} payload varints, the stream holds "
                            f"{len(values) - 1 - in_place - packs}")

    def vertex(v):
        if not 0 <= v < n_vertices:
            raise OpStreamError(f"vertex index {v} outside the vertex buffer's {n_vertices} vertices")
        return v

    # The base writes (COPY, CORNER, SPLIT, MERGE) read only the old buffer and the
    # targets, so an ADJ may name them wherever they are; NEW and ADJ only before it.
    tris = [None] * n
    re_pointed = [s for s, k in zip(slots, kinds) if CORNER0 <= k < ADJ]      # one gather for all of them
    if re_pointed and max(re_pointed) >= old_count:
        raise OpStreamError(f"a CORNER, SPLIT or MERGE write to slot {max(re_pointed)}, which the buffer of "
                            f"{old_count} triangles does not hold yet")
    rows = old[re_pointed].tolist()
    at = 0
    for i, kind in enumerate(kinds):                  # the base writes: from the old buffer
        if kind == COPY:
            r = values[first[i]]
            if r >= old_count:
                raise OpStreamError(f"a COPY from {r} slots before the end of a buffer of {old_count}")
            tris[i] = old[old_count - 1 - r].tolist()
        elif CORNER0 <= kind < ADJ:
            tri = rows[at]
            at += 1
            if kind < SPLIT0:
                z = values[first[i]]
                c = kind - CORNER0
                tri[c] = vertex(tri[c] + ((z >> 1) ^ -(z & 1)))
            elif kind < MERGE0:
                c = kind - SPLIT0
                tri[c] = links.child(tri[c], values[first[i]])
            else:
                c = kind - MERGE0
                tri[c] = int(links.targets[tri[c]])
            tris[i] = tri

    def written(j, i):
        """Write j's triangle, named by write i."""
        if not 0 <= j < n or j == i:
            raise OpStreamError(f"write {i} names write {j} of {n}")
        if tris[j] is None:
            raise OpStreamError(f"write {i} names write {j}, a NEW or ADJ write after it")
        return tris[j]

    last = 0
    for i, kind in enumerate(kinds):                  # then NEW and ADJ, in stream order
        p = first[i]
        if kind == NEW:
            tri = []
            for q in range(3):
                z = values[p + q]
                last = vertex(last + ((z >> 1) ^ -(z & 1)))
                tri.append(last)
            tris[i] = tri
        elif kind >= ADJ:
            h = values[p]
            step, ep = divmod(h, 9)
            e, q = divmod(ep, 3)
            prev = written(i + ((step >> 1) ^ -(step & 1)), i)
            x, y = prev[e], prev[(e + 1) % 3]
            v, mode = divmod(values[p + 1], Z_MODES) if kind == ADJ else (0, -1)
            if kind == ADJ_TX or kind == ADJ_TY:
                z = int(links.targets[x if kind == ADJ_TX else y])
            elif mode == Z_DELTA:
                z = last = vertex(last + ((v >> 1) ^ -(v & 1)))
            elif mode == Z_CHILD_X or mode == Z_CHILD_Y:
                z = links.child(x if mode == Z_CHILD_X else y, v)
            else:
                j2, c = divmod(v, 3)
                z = written(i + ((j2 >> 1) ^ -(j2 & 1)), i)[c]
            tri = [0, 0, 0]
            tri[q], tri[(q + 1) % 3], tri[(q + 2) % 3] = y, x, z
            tris[i] = tri
    return np.array(slots, np.uint32), np.array(tris, np.uint32).reshape(-1, 3)
