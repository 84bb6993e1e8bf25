"""A camera's state byte per node, held only where the camera has nodes.

Refinement keeps a byte of flags per node (:mod:`caveclod.kernels.refine`:
ACTIVE or SPLIT, IN_LIST, QUEUED, RECHECK; HIDDEN for a hidden part's
roots). Most nodes of a large mesh are INACTIVE with no flag, byte 0, so a
byte for every node of the mesh (n bytes: 1 MB a camera at 1M triangles,
about 200 MB at 200M) is mostly zeros (issue 16).

This table holds the bytes in *blocks* of 16 consecutive nodes, and only
the blocks with a non-zero byte: the open-addressing table of
:mod:`caveclod.kernels.facemap`, a row per block (block id, then its 16
bytes as four int32 words), at most half full. A camera's nodes cluster in
id order (siblings, a level's nodes of one region, the positions of a
terrain's rows), so a block holds about four of them on the terrains: a
20-byte row for four held nodes, 10 to 20 bytes a node with the table
half to a quarter full, against 16 to 32 with a row per node, and
neighbours share a row. A block whose bytes all become 0 gives its row
back. A lookup is still a probe into a table larger than the cache, so a
pass does not read the byte of every active-list entry (see the set at
the end of this module).

A camera holding much of the mesh would need more bytes for the table than
a byte a node, so it is *dense* then: every block's four words, the byte per
node of before. Both forms end with a row that counts the blocks in use, so
the kernels can tell a table that must grow before it fills
(:func:`ns_room`) and the camera which form is smaller, without a scan.

The functions are compiled as calls, not inlined into the refinement
kernels: inlined at their thirty-odd call sites they made the kernels'
first compile three times as long (204 s against 68 s on a loaded machine;
a server's first session waits for it), and as calls they cost no
measurable time (interleaved runs of the rough flyover).

Layout, int32 both (one array type, so the refinement kernels compile
once): hash ``(cap + 1, 5)``, rows ``0 .. cap-1`` (block, w0, w1, w2, w3)
or all -1, row ``cap`` (blocks, 0, 0, 0, 0), ``cap`` a power of two; dense
``(4 blocks + 1, 1)``, the words of every block in order, the last the count.
Node ``x`` is block ``x >> 4``, word ``(x >> 2) & 3``, bits ``8 (x & 3) ..``.
"""

import numba as nb
import numpy as np

from .facemap import EMPTY, probe, remove_row

# A node's byte (the refinement kernels' rules, caveclod.kernels.refine).
INACTIVE, ACTIVE, SPLIT = 0, 1, 2
STATE_MASK, IN_LIST, QUEUED, RECHECK = 3, 4, 8, 16

BLOCK = 16                    # nodes a block
WORDS = 4                     # int32 words a block
MIN_ROWS = 16


def table_rows(blocks: int) -> int:
    """Rows of a hash table for ``blocks`` blocks: a power of two >= 2 x blocks."""
    return max(MIN_ROWS, 1 << (2 * blocks - 1).bit_length()) if blocks > 0 else MIN_ROWS


def most_hashed_blocks(n_nodes: int) -> int:
    """The most blocks for which a hash table is smaller than the dense form."""
    blocks = MIN_ROWS // 2        # tables hold half their rows, a power of two
    while hash_is_smaller(2 * blocks, n_nodes):
        blocks *= 2
    return blocks


def n_blocks(n_nodes: int) -> int:
    return (n_nodes + BLOCK - 1) // BLOCK


def hash_is_smaller(blocks: int, n_nodes: int) -> bool:
    """Whether a hash table for ``blocks`` takes fewer bytes than the dense form."""
    return (table_rows(blocks) + 1) * (WORDS + 1) < WORDS * n_blocks(n_nodes) + 1


def new_node_states(blocks: int, n_nodes: int) -> np.ndarray:
    """An empty table (every node's byte 0) with room for ``blocks`` blocks on a
    hierarchy of ``n_nodes``: hash, or dense when that is no larger."""
    if not hash_is_smaller(blocks, n_nodes):
        return np.zeros((WORDS * n_blocks(n_nodes) + 1, 1), np.int32)
    cap = table_rows(blocks)
    t = np.full((cap + 1, WORDS + 1), EMPTY, np.int32)
    t[cap] = 0
    return t


def is_dense(t: np.ndarray) -> bool:
    return t.shape[1] == 1


def ns_count(t: np.ndarray) -> int:
    """Blocks with a non-zero byte."""
    return int(t[-1, 0])


@nb.njit(cache=True, nogil=True)
def ns_get(t, x):
    """The byte of node ``x`` (0 when it has none)."""
    sh = (x & 3) << 3
    if t.shape[1] == 1:
        return (t[x >> 2, 0] >> sh) & 0xFF
    b = x >> 4
    i = probe(t, b, t.shape[0] - 2)
    if t[i, 0] != b:
        return 0
    return (t[i, 1 + ((x >> 2) & 3)] >> sh) & 0xFF


@nb.njit(cache=True, nogil=True)
def ns_update(t, x, clear, add):
    """Node ``x``'s byte becomes ``(byte & ~clear) | add``: one probe.

    A byte that becomes non-zero in a block without a row takes one; the
    caller made sure there is room (:func:`ns_room`). A block whose bytes
    all become 0 gives its row back."""
    last = t.shape[0] - 1
    sh = (x & 3) << 3
    keep = 0xFFFFFFFF & ~(0xFF << sh)      # the word's other bytes (no sign bits above them)
    if t.shape[1] == 1:
        w = x >> 2
        old = (t[w, 0] >> sh) & 0xFF
        new = ((old & ~clear) | add) & 0xFF
        if new == old:
            return
        t[w, 0] = (t[w, 0] & keep) | (new << sh)
        if old == 0 or new == 0:
            b = WORDS * (x >> 4)
            others = 0
            for k in range(WORDS):
                if b + k != w:
                    others |= t[b + k, 0]
            if others == 0 and (t[w, 0] & keep) == 0:      # the block was, or is now, empty
                t[last, 0] += 1 if old == 0 else -1
        return
    mask = last - 1
    b = x >> 4
    c = 1 + ((x >> 2) & 3)
    i = probe(t, b, mask)
    if t[i, 0] == b:
        new = (((t[i, c] >> sh) & 0xFF & ~clear) | add) & 0xFF
        t[i, c] = (t[i, c] & keep) | (new << sh)
        if new == 0 and (t[i, 1] | t[i, 2] | t[i, 3] | t[i, 4]) == 0:
            remove_row(t, i, mask)
            t[last, 0] -= 1
        return
    new = add & 0xFF
    if new != 0:
        t[i, 0] = b
        for k in range(1, WORDS + 1):
            t[i, k] = 0
        t[i, c] = new << sh
        t[last, 0] += 1


@nb.njit(cache=True, nogil=True)
def ns_set(t, x, v):
    """Node ``x``'s byte becomes ``v``."""
    ns_update(t, x, 0xFF, v)


@nb.njit(cache=True, nogil=True)
def ns_room(t, k):
    """Whether ``k`` more blocks can take a row (a hash table stays at most half full)."""
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
def _copy_block(new, b, words):
    for k in range(WORDS):
        word = words[k]
        for j in range(4):
            v = (word >> (8 * j)) & 0xFF
            if v != 0:
                ns_set(new, BLOCK * b + 4 * k + j, v)


@nb.njit(cache=True, nogil=True)
def ns_copy(old, new):
    """Put every non-zero byte of table ``old`` into the empty table ``new`` (either form)."""
    if old.shape[1] == 1:
        for b in range((old.shape[0] - 1) // WORDS):
            _copy_block(new, b, old[WORDS * b:WORDS * b + WORDS, 0])
        return
    for i in range(old.shape[0] - 1):
        if old[i, 0] != EMPTY:
            _copy_block(new, old[i, 0], old[i, 1:])


def ns_dense(t: np.ndarray, n_nodes: int) -> np.ndarray:
    """(n_nodes,) uint8 every node's byte (for checks: O(mesh))."""
    if is_dense(t):
        words = t[:-1, 0]
    else:
        words = np.zeros(WORDS * n_blocks(n_nodes), np.int32)
        used = t[:-1, 0] != EMPTY
        rows = (WORDS * t[:-1, 0][used])[:, None] + np.arange(WORDS)
        words[rows] = t[:-1, 1:][used]
    # Node x is byte x % 4 of word x // 4 counted from the low end: the
    # words' little-endian bytes, in node order.
    return words.astype("<i4").view(np.uint8)[:n_nodes].copy()


def ns_items(t: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """((k,) int32 nodes in id order, (k,) uint8 their bytes): every non-zero byte."""
    if is_dense(t):
        b = ns_dense(t, n_nodes)
        nodes = np.flatnonzero(b).astype(np.int32)
        return nodes, b[nodes]
    used = t[:-1, 0] != EMPTY
    blocks = t[:-1, 0][used]
    order = np.argsort(blocks)
    raw = t[:-1, 1:][used][order].astype("<i4").view(np.uint8).reshape(-1, BLOCK)
    nodes = (BLOCK * blocks[order].astype(np.int64))[:, None] + np.arange(BLOCK)
    keep = raw != 0
    return nodes[keep].astype(np.int32), raw[keep]


def resized(t: np.ndarray, blocks: int, n_nodes: int) -> np.ndarray:
    """A copy of ``t`` in the form and size that suit ``blocks`` blocks."""
    new = new_node_states(blocks, n_nodes)
    ns_copy(t, new)
    return new


# ---------------------------------------------------------------- listed nodes changed since their check

# A pass reads the node byte of each active-list entry to drop the entries
# of nodes no longer active and to evaluate those marked RECHECK; with the
# bytes in a hash table that is a cache miss per entry. Instead a camera
# keeps this small set of the listed nodes whose byte changed since their
# entry was last checked (split, collapsed away, marked RECHECK), and a pass
# reads the byte only of an entry in the set (``caveclod.kernels.refine``,
# "Clean lists"). A (rows + 1, 1) int32 table of the same kind, the
# last row the count, or OVERFLOW when more changed than it holds at half
# full (then every entry is checked until a pass has checked them all).
CHANGED_ROWS = 4096           # at most 16 KB
OVERFLOW = -1


def new_changed_set(entries: int, overflowed: bool = False) -> np.ndarray:
    """An empty set for an active list of ``entries``: rows for an eighth of them (at most
    CHANGED_ROWS), so a camera's bytes follow its list. ``overflowed``: replacing a set whose
    notes are dropped, so every entry is suspect until a pass has checked them all."""
    rows = min(CHANGED_ROWS, table_rows(entries // 16))
    c = np.full((rows + 1, 1), EMPTY, np.int32)
    c[rows, 0] = OVERFLOW if overflowed else 0
    return c


@nb.njit(cache=True, nogil=True)
def cs_suspect(c, x):
    """Whether the entry of listed node ``x`` must have its byte read: in the set, or the set overflowed."""
    k = c[c.shape[0] - 1, 0]
    if k == 0:
        return False
    if k < 0:
        return True
    i = probe(c, x, c.shape[0] - 2)
    return c[i, 0] == x


@nb.njit(cache=True, nogil=True)
def cs_note(c, state, x):
    """Listed node ``x``'s byte changed (node ``x`` without an entry needs no note)."""
    last = c.shape[0] - 1
    k = c[last, 0]
    if k < 0 or (ns_get(state, x) & IN_LIST) == 0:
        return
    i = probe(c, x, last - 1)
    if c[i, 0] == x:
        return
    if 2 * (k + 1) > last:
        c[last, 0] = OVERFLOW
        return
    c[i, 0] = x
    c[last, 0] = k + 1


@nb.njit(cache=True, nogil=True)
def cs_settle(c, state):
    """After a whole pass: keep only the nodes whose entries are still stale (listed, and not
    active or marked RECHECK). Returns False, with the set emptied, when it had overflowed (the
    list must then be checked whole)."""
    last = c.shape[0] - 1
    k = c[last, 0]
    if k == 0:
        return True
    keep = np.empty(max(k, 0), np.int32)
    m = 0
    for i in range(last):
        x = c[i, 0]
        if x == EMPTY:
            continue
        c[i, 0] = EMPTY
        if k > 0:
            st = ns_get(state, x)
            if (st & IN_LIST) != 0 and ((st & STATE_MASK) != ACTIVE or (st & RECHECK) != 0):
                keep[m] = x
                m += 1
    c[last, 0] = 0
    for j in range(m):
        cs_note(c, state, keep[j])
    return k > 0
