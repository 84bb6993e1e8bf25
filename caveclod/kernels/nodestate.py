"""A camera's state byte per node, held only for the nodes that have one.

Refinement keeps a byte of flags per node (:mod:`caveclod.kernels.refine`:
ACTIVE or SPLIT, IN_LIST, QUEUED, RECHECK; HIDDEN for a hidden part's
roots). Most nodes of a large mesh are INACTIVE with no flag, byte 0, so a
byte for every node of the mesh (n bytes: 1 MB a camera at 1M triangles,
about 200 MB at 200M) is mostly zeros (issue 16). This table holds the
non-zero bytes only: the open-addressing table of
:mod:`caveclod.kernels.facemap` with rows (node, byte), at most half full.
A node without a row has byte 0; setting a byte to 0 removes the row.

A camera holding much of the mesh has about as many non-zero bytes as
nodes, and 8 bytes a row (two to four rows a node) would then be more than
a byte a node, so the table is *dense* then: ``(ceil(n / 4) + 1, 1)``
int32, four nodes' bytes a word (node ``x`` in bits ``8 (x % 4) ..``), the
byte per node of before. Both forms end with a row that counts the
non-zero bytes, so the kernels can tell a hash table that must grow before
it fills (:func:`ns_room`) and the camera can tell when the other form would
be smaller without scanning.

Layout: hash ``(cap + 1, 2)`` int32, rows ``0 .. cap-1`` (node, byte) or
(-1, -1), row ``cap`` (count, 0); dense ``(words + 1, 1)`` int32, row
``words`` the count. ``cap`` is a power of two. One array type for both, so
the refinement kernels compile once.
"""

import numba as nb
import numpy as np

from .facemap import EMPTY, probe, remove_row

MIN_ROWS = 16


def table_rows(entries: int) -> int:
    """Rows of a hash table for ``entries`` non-zero bytes: a power of two >= 2 x entries."""
    cap = MIN_ROWS
    while cap < 2 * entries:
        cap *= 2
    return cap


def dense_words(n_nodes: int) -> int:
    return (n_nodes + 3) // 4


def hash_is_smaller(entries: int, n_nodes: int) -> bool:
    """Whether a hash table for ``entries`` takes fewer bytes than the dense form."""
    return 2 * (table_rows(entries) + 1) < dense_words(n_nodes) + 1      # 8 bytes a row, 4 a word


def new_node_states(entries: int, n_nodes: int) -> np.ndarray:
    """An empty table (every node's byte 0) with room for ``entries`` non-zero
    bytes on a hierarchy of ``n_nodes``: hash, or dense when that is no larger."""
    if not hash_is_smaller(entries, n_nodes):
        return np.zeros((dense_words(n_nodes) + 1, 1), np.int32)
    cap = table_rows(entries)
    t = np.full((cap + 1, 2), EMPTY, np.int32)
    t[cap] = 0
    return t


def is_dense(t: np.ndarray) -> bool:
    return t.shape[1] == 1


def ns_count(t: np.ndarray) -> int:
    """Nodes whose byte is not 0."""
    return int(t[-1, 0])


@nb.njit(cache=True, nogil=True, inline="always")
def ns_get(t, x):
    """The byte of node ``x`` (0 when it has none)."""
    if t.shape[1] == 1:
        return (t[x >> 2, 0] >> ((x & 3) << 3)) & 0xFF
    i = probe(t, x, t.shape[0] - 2)
    return t[i, 1] if t[i, 0] == x else 0


@nb.njit(cache=True, nogil=True, inline="always")
def ns_update(t, x, clear, add):
    """Node ``x``'s byte becomes ``(byte & ~clear) | add``: one probe.

    A byte that becomes non-zero takes a row; the caller made sure there is
    room (:func:`ns_room`). One that becomes 0 gives its row back."""
    last = t.shape[0] - 1
    if t.shape[1] == 1:
        w = x >> 2
        sh = (x & 3) << 3
        old = (t[w, 0] >> sh) & 0xFF
        new = ((old & ~clear) | add) & 0xFF
        t[w, 0] = (t[w, 0] & ~(0xFF << sh)) | (new << sh)
        if old == 0 and new != 0:
            t[last, 0] += 1
        elif old != 0 and new == 0:
            t[last, 0] -= 1
        return
    mask = last - 1
    i = probe(t, x, mask)
    if t[i, 0] == x:
        new = ((t[i, 1] & ~clear) | add) & 0xFF
        if new != 0:
            t[i, 1] = new
        else:
            remove_row(t, i, mask)
            t[last, 0] -= 1
    else:
        new = add & 0xFF
        if new != 0:
            t[i, 0] = x
            t[i, 1] = new
            t[last, 0] += 1


@nb.njit(cache=True, nogil=True, inline="always")
def ns_set(t, x, v):
    """Node ``x``'s byte becomes ``v``."""
    ns_update(t, x, 0xFF, v)


@nb.njit(cache=True, nogil=True, inline="always")
def ns_room(t, k):
    """Whether ``k`` more nodes can get a non-zero byte (a hash table stays at most half full)."""
    if t.shape[1] == 1:
        return True
    return t[t.shape[0] - 1, 0] + k <= (t.shape[0] - 1) // 2


@nb.njit(cache=True, nogil=True)
def ns_fill(t, nodes, v):
    """Set the byte of each of ``nodes`` (k,) to ``v`` (room for them all is the caller's)."""
    for i in range(nodes.shape[0]):
        ns_set(t, nodes[i], v)


@nb.njit(cache=True, nogil=True)
def ns_clear(t, nodes, bits):
    """Clear ``bits`` in the byte of each of ``nodes`` (k,)."""
    for i in range(nodes.shape[0]):
        ns_update(t, nodes[i], bits, 0)


@nb.njit(cache=True, nogil=True)
def ns_copy(old, new):
    """Put every non-zero byte of table ``old`` into the empty table ``new`` (either form)."""
    if old.shape[1] == 1:
        for w in range(old.shape[0] - 1):
            word = old[w, 0]
            if word == 0:
                continue
            for k in range(4):
                v = (word >> (8 * k)) & 0xFF
                if v != 0:
                    ns_set(new, 4 * w + k, v)
        return
    for i in range(old.shape[0] - 1):
        if old[i, 0] != EMPTY:
            ns_set(new, old[i, 0], old[i, 1])


def ns_items(t: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """((k,) int32 nodes in id order, (k,) uint8 their bytes): every non-zero byte.
    O(table): the hash rows, or a scan of the dense bytes."""
    if is_dense(t):
        b = ns_dense(t, n_nodes)
        nodes = np.flatnonzero(b).astype(np.int32)
        return nodes, b[nodes]
    used = t[:-1, 0] != EMPTY
    nodes, vals = t[:-1, 0][used], t[:-1, 1][used]
    order = np.argsort(nodes)
    return nodes[order].astype(np.int32), vals[order].astype(np.uint8)


def ns_dense(t: np.ndarray, n_nodes: int) -> np.ndarray:
    """(n_nodes,) uint8 every node's byte (for checks: O(mesh))."""
    if is_dense(t):
        # Node x is byte x % 4 of word x // 4 counted from the low end: the
        # words' little-endian bytes, in node order.
        return t[:-1, 0].astype("<i4").view(np.uint8)[:n_nodes].copy()
    out = np.zeros(n_nodes, np.uint8)
    nodes, vals = ns_items(t, n_nodes)
    out[nodes] = vals
    return out


def resized(t: np.ndarray, entries: int, n_nodes: int) -> np.ndarray:
    """A copy of ``t`` in the form and size that suits ``entries`` non-zero bytes."""
    new = new_node_states(entries, n_nodes)
    ns_copy(t, new)
    return new
