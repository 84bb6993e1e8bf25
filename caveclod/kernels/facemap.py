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
def _home(fm, f):
    return ((np.int64(f) * _GOLDEN) >> 7) & (fm.shape[0] - 1)


@nb.njit(cache=True, nogil=True, inline="always")
def _row(fm, f):
    """Row of a table that holds face ``f``, or the empty row where its probe ends."""
    mask = fm.shape[0] - 1
    i = _home(fm, f)
    for _ in range(fm.shape[0]):         # the table is at most half full: a probe ends early
        k = fm[i, 0]
        if k == f or k == EMPTY:
            return i
        i = (i + 1) & mask
    return i


@nb.njit(cache=True, nogil=True, inline="always")
def fm_get(fm, f):
    """Record of face ``f``, or -1 when it is not active."""
    if fm.shape[1] == 1:
        return fm[f, 0]
    i = _row(fm, f)
    return fm[i, 1] if fm[i, 0] == f else -1


@nb.njit(cache=True, nogil=True, inline="always")
def fm_set(fm, f, r):
    """Face ``f`` is at record ``r`` (added, or moved)."""
    if fm.shape[1] == 1:
        fm[f, 0] = r
        return
    i = _row(fm, f)
    fm[i, 0] = f
    fm[i, 1] = r


@nb.njit(cache=True, nogil=True)
def fm_del(fm, f):
    """Face ``f`` is no longer active (nothing happens if it was not)."""
    if fm.shape[1] == 1:
        fm[f, 0] = EMPTY
        return
    i = _row(fm, f)
    if fm[i, 0] != f:
        return
    # Backward-shift deletion: move up each later row of the run whose home
    # is not between the hole and itself, so every face stays reachable.
    mask = fm.shape[0] - 1
    j = i
    while True:
        j = (j + 1) & mask
        k = fm[j, 0]
        if k == EMPTY:
            break
        h = _home(fm, k)
        if (i <= j and (h <= i or h > j)) or (i > j and h <= i and h > j):
            fm[i, 0] = k
            fm[i, 1] = fm[j, 1]
            i = j
    fm[i, 0] = EMPTY
    fm[i, 1] = EMPTY


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
