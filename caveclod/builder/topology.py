"""Edge connectivity of a triangle mesh over welded positions.

Two faces are neighbours across an edge only when the edge is *manifold*:
exactly two faces use it, in opposite directions. Every other edge (used by
one face, by three or more, or twice in the same direction) is a border for
all faces on it; the edges used by more than one face that way are *cut*
edges, and their end positions are never moved by the build (DESIGN.md:
a collapse may not break manifoldness).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..errors import InputError
from ..kernels.fans import collect_fan


@dataclass
class Topology:
    """Face adjacency of a mesh.

    Attributes:
        nbrs: (p, 3) int32, face across edge k (corner k -> k+1), -1 if none.
        edge_faces: (p, 3) uint8, how many faces use edge k of each face (255: 255
            or more; a byte, not an int32, since it lives as long as the build).
        nonmanifold: (e,) bool, positions on a cut edge or whose faces form
            more than one fan (two sheets touching at a point).
        border: (e,) bool, positions on a border or cut edge.
    """

    nbrs: np.ndarray
    edge_faces: np.ndarray
    nonmanifold: np.ndarray
    border: np.ndarray


def face_neighbours(faces: np.ndarray, n_positions: int) -> Topology:
    """Compute :class:`Topology` for ``faces`` (p, 3) of position ids."""
    faces32 = np.ascontiguousarray(faces, dtype=np.int32)
    if 3 * len(faces32) >= 2 ** 31:
        raise InputError(f"{len(faces32):,} faces: the topology numbers half-edges in int32, which holds at most "
                         f"{(2 ** 31 - 1) // 3:,} faces; build the mesh in parts")
    nbrs, edge_faces = _link_edges(faces32, n_positions)
    a = faces32
    b = np.roll(a, -1, axis=1)                       # edge k runs a[:, k] -> b[:, k]
    # Edges used by two or more faces without being a manifold pair are cut.
    cut = (edge_faces >= 2) & (nbrs < 0)
    nonmanifold = np.zeros(n_positions, bool)
    nonmanifold[a[cut]] = True
    nonmanifold[b[cut]] = True
    border = np.zeros(n_positions, bool)
    open_edge = nbrs < 0
    border[a[open_edge]] = True
    border[b[open_edge]] = True
    _mark_multi_fan(faces32, nbrs, nonmanifold)
    return Topology(nbrs, edge_faces, nonmanifold, border)


@nb.njit(cache=True, nogil=True, inline="always")
def _link_pair(faces, nbrs, h, g):
    """Link half-edges h and g (ids 3f + k) if they run in opposite directions."""
    fh, kh, fg, kg = h // 3, h % 3, g // 3, g % 3
    if faces[fh, kh] == faces[fg, (kg + 1) % 3]:
        nbrs[fh, kh] = fg
        nbrs[fg, kg] = fh


@nb.njit(cache=True, nogil=True)
def _link_edges(faces, e):
    """(nbrs, edge_faces), (p, 3) int32 and uint8; see :class:`Topology`.

    Half-edges are bucketed by their lower end (a CSR), each with its upper
    end beside it, so matching an edge scans the few half-edges that start
    at the same position and compares one int32 each (no face lookups).
    Half-edge ids 3f + k are int32: a build refuses more than 715M faces
    long before (its memory check).
    """
    p = faces.shape[0]
    start = np.zeros(e + 1, np.int64)
    for f in range(p):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            start[min(a, b) + 1] += 1
    for x in range(e):
        start[x + 1] += start[x]
    fill = start[:-1].copy()
    bucket = np.empty(3 * p, np.int32)               # half-edge ids 3f + k
    far = np.empty(3 * p, np.int32)                  # the upper end of each
    for f in range(p):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            lo = min(a, b)
            bucket[fill[lo]] = 3 * f + k
            far[fill[lo]] = max(a, b)
            fill[lo] += 1
    nbrs = np.full((p, 3), -1, np.int32)
    edge_faces = np.zeros((p, 3), np.uint8)
    for x in range(e):
        lo, hi_end = start[x], start[x + 1]
        if hi_end - lo > 32:
            # A high-valence position (a fan centre): sort its half-edges by
            # far end so equal edges sit together, instead of a quadratic scan.
            order = np.argsort(far[lo:hi_end], kind="mergesort")
            bucket[lo:hi_end] = bucket[lo:hi_end][order]
            far[lo:hi_end] = far[lo:hi_end][order]
            i = lo
            while i < hi_end:
                j = i
                while j + 1 < hi_end and far[j + 1] == far[i]:
                    j += 1
                count = j - i + 1
                for q in range(i, j + 1):
                    h = bucket[q]
                    edge_faces[h // 3, h % 3] = min(count, 255)
                if count == 2:
                    _link_pair(faces, nbrs, bucket[i], bucket[j])
                i = j + 1
            continue
        for i in range(lo, hi_end):
            hi = far[i]
            count, other = 0, -1
            for j in range(lo, hi_end):
                if far[j] == hi:
                    count += 1
                    if j != i:
                        other = bucket[j]
            h = bucket[i]
            f, k = h // 3, h % 3
            edge_faces[f, k] = min(count, 255)
            if count == 2 and faces[f, k] == faces[other // 3, (other % 3 + 1) % 3]:
                nbrs[f, k] = other // 3               # opposite directions: a manifold pair
    return nbrs, edge_faces


@nb.njit(cache=True, nogil=True)
def _mark_multi_fan(faces, nbrs, nonmanifold):
    """Flag positions whose faces do not form one connected fan."""
    e = nonmanifold.shape[0]
    valence = np.zeros(e, np.int32)
    first = np.full(e, -1, np.int32)
    for f in range(faces.shape[0]):
        for k in range(3):
            x = faces[f, k]
            valence[x] += 1
            if first[x] == -1:
                first[x] = f
    buf = np.empty(valence.max() + 1 if e else 1, np.int32)
    for x in range(e):
        if first[x] == -1 or nonmanifold[x]:
            continue
        n, _ = collect_fan(faces, nbrs, first[x], x, buf)
        if n != valence[x]:
            nonmanifold[x] = True


@nb.njit(cache=True, nogil=True)
def count_components(nbrs):
    """Number of edge-connected pieces of a mesh with face links ``nbrs``.

    Each piece keeps at least one face in the base mesh, so this is one of
    the reasons a base mesh can be large (scans break into many islands).
    """
    p = nbrs.shape[0]
    seen = np.zeros(p, np.bool_)
    stack = np.empty(p, np.int32)
    count = 0
    for seed in range(p):
        if seen[seed]:
            continue
        count += 1
        seen[seed] = True
        stack[0] = seed
        top = 1
        while top > 0:
            top -= 1
            f = stack[top]
            for k in range(3):
                g = nbrs[f, k]
                if g >= 0 and not seen[g]:
                    seen[g] = True
                    stack[top] = g
                    top += 1
    return count
