"""Nearest-triangle distances through a bounding-volume hierarchy.

A plain median-split BVH over triangle bounding boxes, built and queried in
numba: the renderer-free screen-space error measurement asks, for every
original position in view, how far it lies from the LOD surface.

Layout: node ``i`` has a box ``lo[i]``, ``hi[i]`` (3,) and either two
children ``left[i]``, ``left[i] + 1`` (inner node) or, when ``left[i] == -1``,
the triangles ``order[start[i] : start[i] + count[i]]`` (leaf).
"""

import numba as nb
import numpy as np

from .distance import point_triangle_dist2

LEAF_SIZE = 4


@nb.njit(cache=True, nogil=True)
def build_bvh(V, T):
    """BVH of triangles ``T`` (k, 3) int over vertices ``V`` (n, 3) float64.

    Returns (lo (m, 3), hi (m, 3), left (m,), start (m,), count (m,), order (k,)).
    """
    k = T.shape[0]
    cmin = np.empty((k, 3))
    cmax = np.empty((k, 3))
    cen = np.empty((k, 3))
    for f in range(k):
        for a in range(3):
            x0, x1, x2 = V[T[f, 0], a], V[T[f, 1], a], V[T[f, 2], a]
            cmin[f, a] = min(x0, min(x1, x2))
            cmax[f, a] = max(x0, max(x1, x2))
            cen[f, a] = 0.5 * (cmin[f, a] + cmax[f, a])
    m = max(2 * k, 1)
    lo = np.empty((m, 3))
    hi = np.empty((m, 3))
    left = np.full(m, -1, np.int64)
    start = np.zeros(m, np.int64)
    count = np.zeros(m, np.int64)
    order = np.arange(k)
    stack = np.empty((64, 3), np.int64)        # (node, first, end); depth is O(log k)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, k
    sp = 1
    used = 1
    while sp > 0:
        sp -= 1
        node, a0, a1 = stack[sp, 0], stack[sp, 1], stack[sp, 2]
        for a in range(3):
            lo[node, a] = np.inf
            hi[node, a] = -np.inf
        for i in range(a0, a1):
            f = order[i]
            for a in range(3):
                lo[node, a] = min(lo[node, a], cmin[f, a])
                hi[node, a] = max(hi[node, a], cmax[f, a])
        if a1 - a0 <= LEAF_SIZE:
            start[node], count[node] = a0, a1 - a0
            continue
        # Split the longest axis of the centroids' box at the median.
        axis, best = 0, -1.0
        for a in range(3):
            clo, chi = np.inf, -np.inf
            for i in range(a0, a1):
                c = cen[order[i], a]
                clo = min(clo, c)
                chi = max(chi, c)
            if chi - clo > best:
                axis, best = a, chi - clo
        keys = np.empty(a1 - a0)
        for i in range(a0, a1):
            keys[i - a0] = cen[order[i], axis]
        perm = np.argsort(keys)
        order[a0:a1] = order[a0:a1][perm]
        mid = (a0 + a1) // 2
        left[node] = used
        stack[sp, 0], stack[sp, 1], stack[sp, 2] = used, a0, mid
        stack[sp + 1, 0], stack[sp + 1, 1], stack[sp + 1, 2] = used + 1, mid, a1
        sp += 2
        used += 2
    return lo[:used].copy(), hi[:used].copy(), left[:used].copy(), start[:used].copy(), count[:used].copy(), order


@nb.njit(cache=True, nogil=True, inline="always")
def _box_dist2(lo, hi, i, px, py, pz):
    d = 0.0
    for a, p in ((0, px), (1, py), (2, pz)):
        if p < lo[i, a]:
            d += (lo[i, a] - p) ** 2
        elif p > hi[i, a]:
            d += (p - hi[i, a]) ** 2
    return d


@nb.njit(cache=True, nogil=True)
def nearest_dist2(points, V, T, lo, hi, left, start, count, order):
    """(q,) squared distance from each of ``points`` (q, 3) to the nearest triangle."""
    q = points.shape[0]
    out = np.full(q, np.inf)
    stack = np.empty(256, np.int64)
    for j in range(q):
        px, py, pz = points[j, 0], points[j, 1], points[j, 2]
        best = np.inf
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            i = stack[sp]
            if _box_dist2(lo, hi, i, px, py, pz) >= best:
                continue
            if left[i] == -1:
                for s in range(start[i], start[i] + count[i]):
                    f = order[s]
                    a, b, c = T[f, 0], T[f, 1], T[f, 2]
                    d = point_triangle_dist2(px, py, pz, V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2],
                                             V[c, 0], V[c, 1], V[c, 2])
                    if d < best:
                        best = d
                continue
            # Visit the nearer child first: push it last.
            c0, c1 = left[i], left[i] + 1
            if _box_dist2(lo, hi, c0, px, py, pz) < _box_dist2(lo, hi, c1, px, py, pz):
                c0, c1 = c1, c0
            if sp + 2 > stack.shape[0]:
                bigger = np.empty(2 * stack.shape[0], np.int64)
                bigger[:sp] = stack[:sp]
                stack = bigger
            stack[sp] = c0
            stack[sp + 1] = c1
            sp += 2
        out[j] = best
    return out
