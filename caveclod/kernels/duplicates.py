"""Repeated faces of a mesh being read: one hash a face, then exact comparison within equal hashes.

:func:`caveclod.builder.meshfile._first_of_duplicate_faces` drops a face
that repeats an earlier one (the same positions in the same cyclic order,
the same material). Rows of rotated faces grouped with numpy took about
160 bytes a face, the peak of reading a binary mesh; these kernels take 17
(a hash, the sort's order, the mask).
"""

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, inline="always")
def _rotated(fp, i):
    """Face ``i`` of (p, 3) ``fp`` rotated so that its smallest position comes first."""
    a, b, c = fp[i, 0], fp[i, 1], fp[i, 2]
    if b < a and b <= c:
        return b, c, a
    if c < a and c < b:
        return c, a, b
    return a, b, c


@nb.njit(cache=True, nogil=True)
def rotated_face_hashes(fp, material):
    """(p,) uint64 hash of each face's rotated positions and material (multiply-xorshift)."""
    p = fp.shape[0]
    out = np.empty(p, np.uint64)
    for i in range(p):
        a, b, c = _rotated(fp, i)
        h = np.uint64(0x243F6A8885A308D3)
        for w in (a, b, c, material[i]):
            h ^= np.uint64(w)
            h *= np.uint64(0x9E3779B97F4A7C15)
            h ^= h >> np.uint64(29)
        out[i] = h
    return out


@nb.njit(cache=True, nogil=True)
def keep_first_faces(fp, material, key, order):
    """(p,) bool: True for the first (lowest index) face of each set of equal rotated faces.

    ``order`` sorts ``key`` stably, so a run of equal keys (one face, but for
    repeats and collisions) lists its faces by index: each is compared with
    the run's distinct faces so far and kept if it is new. Linear in a run of
    repeats of one face (a file of a million copies of a triangle).
    """
    p = fp.shape[0]
    keep = np.ones(p, np.bool_)
    distinct = np.empty(64, np.int64)
    lo = 0
    while lo < p:
        hi = lo + 1
        while hi < p and key[order[hi]] == key[order[lo]]:
            hi += 1
        n = 0
        for x in range(lo, hi):
            i = order[x]
            ai, bi, ci = _rotated(fp, i)
            for y in range(n):
                j = distinct[y]
                aj, bj, cj = _rotated(fp, j)
                if aj == ai and bj == bi and cj == ci and material[j] == material[i]:
                    keep[i] = False
                    break
            if keep[i]:
                if n == len(distinct):
                    grown = np.empty(2 * n, np.int64)
                    grown[:n] = distinct
                    distinct = grown
                distinct[n] = i
                n += 1
        lo = hi
    return keep
