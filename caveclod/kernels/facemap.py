"""A camera's map from active face to its record, sized by what the camera holds.

A dense array (one int32 per face of the mesh) was 4 bytes per face for every
camera whatever it saw: 4 MB on a 1M-triangle mesh, 800 MB at 200M
(issue 16). This map holds only the active faces: an open-addressing hash
table with linear probing, ``(capacity, 2)`` int32 rows of (face, record),
face -1 for an empty row. The camera keeps ``capacity >= 2 x`` its record
pool (:func:`map_capacity`), so the table is never more than half full and a
probe ends within a few rows. Deletion shifts the rows after a removed one
back (no tombstones), so lookups never slow down as faces come and go.

A camera that holds a large share of the mesh would need more bytes for the
table (8 bytes a row, 2 to 4 rows a record) than for the dense array (4
bytes a face of the mesh), so the map is then *dense*: ``(p, 1)`` int32, the record of every face or -1,
Equation 1's 4p, and a camera never holds more than it did before the map.
The same functions serve both forms (one array type, one branch).
"""

import numba as nb
import numpy as np

EMPTY = -1
_GOLDEN = 0x9E3779B1          # Fibonacci hashing: face ids of a region are consecutive


def map_capacity(records: int) -> int:
    """Rows of a map for a pool of ``records``: a power of two >= 2 x records."""
    cap = 16
    while cap < 2 * records:
        cap *= 2
    return cap


def new_face_map(records: int, n_faces: int) -> np.ndarray:
    """An empty map for a pool of ``records`` on a mesh of ``n_faces``: a
    (capacity, 2) int32 table, or (n_faces, 1) dense when that is no larger."""
    cap = map_capacity(records)
    if 2 * cap >= n_faces:                  # 8 bytes a row against 4 a face
        return np.full((n_faces, 1), EMPTY, np.int32)
    return np.full((cap, 2), EMPTY, np.int32)


@nb.njit(cache=True, nogil=True, inline="always")
def home_row(key, mask):
    """The row where a probe for ``key`` starts in a table of ``mask + 1`` rows."""
    return ((np.int64(key) * _GOLDEN) >> 7) & mask


@nb.njit(cache=True, nogil=True, inline="always")
def probe(t, key, mask):
    """Row of rows ``0 .. mask`` of table ``t`` (column 0 the keys) that holds
    ``key``, or the empty row where its probe ends. The table must have an
    empty row (it is kept at most half full)."""
    i = home_row(key, mask)
    for _ in range(mask + 1):
        k = t[i, 0]
        if k == key or k == EMPTY:
            return i
        i = (i + 1) & mask
    return i


@nb.njit(cache=True, nogil=True)
def remove_row(t, i, mask):
    """Empty row ``i`` of rows ``0 .. mask`` of table ``t`` (every column).

    Backward-shift deletion: each later row of the run whose home is not
    between the hole and itself moves up, so every key stays reachable and
    no tombstones slow later probes.
    """
    j = i
    while True:
        j = (j + 1) & mask
        k = t[j, 0]
        if k == EMPTY:
            break
        h = home_row(k, mask)
        if (i <= j and (h <= i or h > j)) or (i > j and h <= i and h > j):
            for c in range(t.shape[1]):
                t[i, c] = t[j, c]
            i = j
    for c in range(t.shape[1]):
        t[i, c] = EMPTY


@nb.njit(cache=True, nogil=True, inline="always")
def fm_get(fm, f):
    """Record of face ``f``, or -1 when it is not active."""
    if fm.shape[1] == 1:
        return fm[f, 0]
    i = probe(fm, f, fm.shape[0] - 1)
    return fm[i, 1] if fm[i, 0] == f else -1


@nb.njit(cache=True, nogil=True, inline="always")
def fm_set(fm, f, r):
    """Face ``f`` is at record ``r`` (added, or moved)."""
    if fm.shape[1] == 1:
        fm[f, 0] = r
        return
    i = probe(fm, f, fm.shape[0] - 1)
    fm[i, 0] = f
    fm[i, 1] = r


@nb.njit(cache=True, nogil=True)
def fm_del(fm, f):
    """Face ``f`` is no longer active (nothing happens if it was not)."""
    if fm.shape[1] == 1:
        fm[f, 0] = EMPTY
        return
    i = probe(fm, f, fm.shape[0] - 1)
    if fm[i, 0] == f:
        remove_row(fm, i, fm.shape[0] - 1)


@nb.njit(cache=True, nogil=True)
def fm_fill(fm, faces, recs):
    """Set ``faces[i]`` at ``recs[i]`` for every i (both (k,))."""
    for i in range(faces.shape[0]):
        fm_set(fm, faces[i], recs[i])


def fm_dense(fm: np.ndarray, n_faces: int) -> np.ndarray:
    """(n_faces,) int32 record of every face, -1 where inactive (for checks, O(mesh))."""
    if fm.shape[1] == 1:
        return fm[:, 0].copy()
    out = np.full(n_faces, -1, np.int32)
    used = fm[:, 0] != EMPTY
    out[fm[used, 0]] = fm[used, 1]
    return out
