"""Triangle order for the GPU's post-transform vertex cache, and its measure.

A keyframe sends a camera's whole index buffers; the client keeps each
triangle in the slot the keyframe gave it until a later frame moves it. In
the order refinement leaves them (splits append, collapses move the last
triangle into the hole) neighbouring triangles sit far apart, and a GPU
transforms most vertices about three times (ACMR 2.7 on the flyover). So the
server puts a buffer in cache order just before it sends a keyframe
(:meth:`caveclod.refine.camera.CameraState.reorder_for_vertex_cache`).

The order is Tipsify's (Sander, Nehab & Barczak, *Fast Triangle Reordering
for Vertex Locality and Reduced Overdraw*, SIGGRAPH 2007): fan out from a
vertex, emitting all its unemitted triangles, then continue from the
candidate vertex that will still be in a FIFO cache of ``cache_size``
entries and has the fewest triangles left, or, at a dead end, from the most
recently touched vertex that has any. Linear time; a triangle's corners are
never rotated (a camera's records keep their neighbour links by corner).

:func:`acmr_fifo` is the average cache miss ratio (vertices transformed per
triangle) of an order in a FIFO cache, as meshoptimizer's
``analyzeVertexCache`` counts it with no warp or primitive-group limits.
"""

from __future__ import annotations

import numba as nb
import numpy as np

CACHE_SIZE = 16     # entries of the FIFO modelled: what meshoptimizer's analyzer assumes


@nb.njit(cache=True, nogil=True)
def tipsify(tris, n_vertices, cache_size):
    """(t,) int32: the order in which to draw triangles ``tris`` (t, 3) int32, vertex ids in
    [0, n_vertices), for a FIFO cache of ``cache_size`` entries."""
    t = tris.shape[0]
    degree = np.zeros(n_vertices + 1, np.int64)
    for f in range(t):
        for k in range(3):
            degree[tris[f, k] + 1] += 1
    start = np.cumsum(degree)                      # CSR: triangles of vertex v at adj[start[v]:start[v + 1]]
    adj = np.empty(3 * t, np.int32)
    fill = start[:-1].copy()
    for f in range(t):
        for k in range(3):
            v = tris[f, k]
            adj[fill[v]] = f
            fill[v] += 1
    live = (start[1:] - start[:-1]).astype(np.int64)   # unemitted triangles of each vertex
    stamp = np.zeros(n_vertices, np.int64)              # when each vertex last entered the cache
    max_degree = 0
    for v in range(n_vertices):
        max_degree = max(max_degree, live[v])
    candidates = np.empty(3 * max_degree, np.int32)
    dead_ends = np.empty(3 * t, np.int32)
    n_dead = 0
    emitted = np.zeros(t, np.bool_)
    order = np.empty(t, np.int32)
    n_out = 0
    clock = cache_size + 1
    cursor = 0
    fan = 0 if n_vertices > 0 else -1
    while fan >= 0:
        n_cand = 0
        for j in range(start[fan], start[fan + 1]):
            f = adj[j]
            if emitted[f]:
                continue
            emitted[f] = True
            order[n_out] = f
            n_out += 1
            for k in range(3):
                v = tris[f, k]
                dead_ends[n_dead] = v
                n_dead += 1
                candidates[n_cand] = v
                n_cand += 1
                live[v] -= 1
                if clock - stamp[v] > cache_size:      # not in the cache: it enters now
                    stamp[v] = clock
                    clock += 1
        # The next fan: a candidate still in the cache after its fan, else the oldest.
        best, best_priority = -1, -1
        for j in range(n_cand):
            v = candidates[j]
            if live[v] > 0:
                priority = 0
                if clock - stamp[v] + 2 * live[v] <= cache_size:
                    priority = clock - stamp[v]
                if priority > best_priority:
                    best, best_priority = v, priority
        if best < 0:                                   # a dead end: the most recent vertex with triangles left
            while n_dead > 0:
                n_dead -= 1
                v = dead_ends[n_dead]
                if live[v] > 0:
                    best = v
                    break
        if best < 0:                                   # none: the next vertex in id order that has any
            while cursor < n_vertices and live[cursor] == 0:
                cursor += 1
            if cursor < n_vertices:
                best = cursor
        fan = best
    return order


@nb.njit(cache=True, nogil=True)
def acmr_fifo(tris, n_vertices, cache_size):
    """Vertices transformed per triangle drawing ``tris`` (t, 3) int in order, through a FIFO
    cache of ``cache_size`` entries (a hit does not refresh an entry)."""
    t = tris.shape[0]
    if t == 0:
        return 0.0
    entered = np.full(n_vertices, -(1 << 40), np.int64)
    inserted = 0
    misses = 0
    for f in range(t):
        for k in range(3):
            v = tris[f, k]
            if inserted - entered[v] > cache_size:      # entered more than cache_size insertions ago
                entered[v] = inserted
                inserted += 1
                misses += 1
    return misses / t


def compact(tris: np.ndarray) -> tuple[np.ndarray, int]:
    """(``tris`` with its vertex ids renumbered 0..u-1 as int32, u): the kernels' arrays
    are then as large as the buffer, not the mesh's vertex buffer."""
    ids, inverse = np.unique(np.asarray(tris).ravel(), return_inverse=True)
    return inverse.reshape(-1, 3).astype(np.int32), len(ids)


def cache_order(tris: np.ndarray, cache_size: int = CACHE_SIZE) -> np.ndarray:
    """(t,) int32 permutation putting the triangles ``tris`` (t, 3) in vertex-cache order."""
    local, n = compact(tris)
    return tipsify(local, n, cache_size)


def acmr(tris: np.ndarray, cache_size: int = CACHE_SIZE) -> float:
    """ACMR of ``tris`` (t, 3) drawn in its order (see :func:`acmr_fifo`)."""
    local, n = compact(tris)
    return float(acmr_fifo(local, n, cache_size))
