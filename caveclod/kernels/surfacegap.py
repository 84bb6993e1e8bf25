"""The other direction of a node's error: how far its coarse faces lie from the original surface.

Carried points (:mod:`caveclod.kernels.carried`) bound the distance from
every original position to the coarse surface. That is one direction only:
between original positions the coarse surface can lie much farther from
the original. A long thin coarse face along the foot of a slope passes
under the slope's original faces, whose corners all lie near some coarse
face (measured on the smooth built-in terrain, benchmarks/error.py: points
of drawn faces up to 4.6 px from the original surface at a tolerance of
1 px, every original position within it).

So every collapse also measures what it made new: the midpoint of each
new edge (from t to u's old ring) and the centroid of each face it
reshaped (u's faces, whose corner u became t). Each sample walks from a
near original position over the original mesh's edges to the position
nearest to it, then from the faces around that position across faces'
edges to the nearest original face it can reach; a walk that ends at a
face with a border edge (a hole or a border may have stopped it short)
starts again from the nearest point the reshaped face carries. A distance to part of the original surface is never less
than the distance to all of it, so a measured gap is never too small; it
is too large only where a walk stops at a local minimum (on the built-in
terrains and scan, 99.9 to 100 % of samples of drawn faces measured
exactly, against a BVH). The node's error is the larger of the two
directions, so the runtime's test and the saturation over neighbours carry
both.

Edges and faces a collapse did not change keep the shape they were
measured with, by the collapse that made them; its node is a child of this
one or the current node of a position of the new ring, and both feed this
node's error (children's errors and saturation), so new ones are enough.
The samples are points, not the whole face: between them the gap can be
larger (``benchmarks/error.py`` measures the drawn surface at other points).
"""

import math

import numba as nb
import numpy as np

from .carried import NEXT
from .distance import point_triangle_dist2
from .fans import corner_of

EDGE_SAMPLES = (0.5,)
"""Where along a new edge the build measures it (with each new face's centroid).

Its thirds instead of its midpoint made the 1M terrain's build 1.7 s slower
on one core (12.6 s against 10.9). Sampling long edges about every original
edge length (at most 8 points) and large faces at 3 more points lowered the
largest LOD -> original error of benchmarks/error.py from 1.36 to 1.19 t
on the rough terrain at 1 px (1.14 to 1.12 on the smooth one, 1.25 to 1.18
on the scan) for 0.5-8 % more faces, but made the 1M terrains' builds
2.2-3.9 s slower on one core (a quarter): not kept. Tried again once the
walks stopped at the first point within the error (2026-11-27): an odd
number of samples a new edge, about one every original edge length (the
longest at t) up to 7, and faces whose centroid lies over two such lengths
from its corners measured halfway to each corner too. The rough 256 terrain
at 1 px went from 1.36 to 1.29 t, the scan at 1 px from 1.25 to 1.18, but
the scan at 0.5 px from 1.39 to 1.48 (a different tree), with 0-4 % more
faces: 8 of the 12 pairs within 1.25 t, as before, for 28 % more CPU in the
1M rough terrain's build. Not kept."""

MAX_STEPS = 4096
"""Most steps of each of a sample's walks, over positions and then faces (a walk
ends sooner where no neighbour is nearer; the distance reached bounds the gap anyway)."""


def star_lists(face_pos: np.ndarray, n_positions: int) -> tuple[np.ndarray, np.ndarray]:
    """The original faces around each position, as CSR lists.

    ``face_pos`` (p, 3) int32 faces over positions. Returns ``(start, faces)``:
    (e + 1,) int64 offsets and (3p,) int32 face ids, the faces around
    position ``x`` being ``faces[start[x]:start[x + 1]]``.
    """
    start = np.zeros(n_positions + 1, np.int64)
    faces = np.empty(face_pos.size, np.int32)
    _fill_stars(np.ascontiguousarray(face_pos, dtype=np.int32), start, faces)
    return start, faces


@nb.njit(cache=True, nogil=True)
def _fill_stars(face_pos, start, faces):
    for f in range(face_pos.shape[0]):
        for k in range(3):
            start[face_pos[f, k] + 1] += 1
    for x in range(start.shape[0] - 1):
        start[x + 1] += start[x]
    fill = start[:-1].copy()
    for f in range(face_pos.shape[0]):
        for k in range(3):
            x = face_pos[f, k]
            faces[fill[x]] = f
            fill[x] += 1


@nb.njit(cache=True, nogil=True, inline="always")
def _dist2(q, sx, sy, sz, P):
    dx, dy, dz = P[q, 0] - sx, P[q, 1] - sy, P[q, 2] - sz
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True, inline="always")
def _tri_dist2(g, px, py, pz, P, face_pos):
    a, b, c = face_pos[g, 0], face_pos[g, 1], face_pos[g, 2]
    return point_triangle_dist2(px, py, pz, P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2],
                                P[c, 0], P[c, 1], P[c, 2])


@nb.njit(cache=True, nogil=True)
def _surface_dist2(x, px, py, pz, P, face_pos, face_nbrs, star_start, star_faces, worst):
    """(squared distance, face) from p to the original faces around position
    ``x``, then to faces across their edges while one is nearer (on thin
    faces the nearest face need not touch the nearest position). Stops once
    within ``worst``."""
    best, g = np.inf, -1
    for j in range(star_start[x], star_start[x + 1]):
        d = _tri_dist2(star_faces[j], px, py, pz, P, face_pos)
        if d < best:
            best, g = d, star_faces[j]
            if d <= worst:               # the caller needs no nearer face then
                return best, g
    for _ in range(MAX_STEPS):
        if best <= worst or g == -1:
            break
        nxt = -1
        for k in range(3):
            h = face_nbrs[g, k]
            if h >= 0:
                d = _tri_dist2(h, px, py, pz, P, face_pos)
                if d < best:
                    best, nxt = d, h
        if nxt == -1:
            break
        g = nxt
    return best, g


@nb.njit(cache=True, nogil=True, inline="always")
def _walk(q, d1, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst):
    """Walk from position ``q`` (squared distance ``d1`` to s) to a neighbour
    nearer to s while there is one; returns (position, squared distance).

    Each neighbour of q follows it in one face of its star, or precedes it
    across a border edge. Stops early once within ``worst``: a position
    lies on the original surface, so the sample cannot raise ``worst`` then.
    """
    for _ in range(MAX_STEPS):
        if d1 <= worst:
            break
        at = q
        for j in range(star_start[at], star_start[at + 1]):
            g = star_faces[j]
            k = corner_of(face_pos, g, at)
            r = face_pos[g, (k + 1) % 3]
            d = _dist2(r, sx, sy, sz, P)
            if d < d1:
                q, d1 = r, d
                if d <= worst:
                    return q, d1
            if face_nbrs[g, (k + 2) % 3] == -1:         # the edge prev -> at is a border
                r = face_pos[g, (k + 2) % 3]
                d = _dist2(r, sx, sy, sz, P)
                if d < d1:
                    q, d1 = r, d
                    if d <= worst:
                        return q, d1
        if q == at:
            break
    return q, d1


@nb.njit(cache=True, nogil=True)
def sample_gap2(sx, sy, sz, start, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst):
    """Squared distance from sample s to the original surface, if more than
    ``worst`` (squared); ``worst`` otherwise.

    Walks from the original position ``start`` over the original mesh's edges
    to the nearest position it can reach, then measures the original faces
    around it and walks across faces' edges while a face is nearer. A walk
    that ends on a face with a border edge may have stopped short of the
    sample at a hole or a border: it starts again from the nearest point
    coarse face ``f`` carries.
    """
    q, d1 = _walk(start, _dist2(start, sx, sy, sz, P), sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces,
                  worst)
    if d1 <= worst:
        return worst
    gap, g = _surface_dist2(q, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst)
    gap = min(d1, gap)
    if gap <= worst:
        return worst
    if g >= 0 and face_nbrs[g, 0] >= 0 and face_nbrs[g, 1] >= 0 and face_nbrs[g, 2] >= 0:
        return gap               # nothing stopped the walk: a border edge is what can
    x = pt_head[f]
    q2, d2 = q, d1
    while x != -1:
        d = _dist2(x, sx, sy, sz, P)
        if d < d2:
            q2, d2 = x, d
        x = pt[x, NEXT]
    if q2 != q:
        q2, d2 = _walk(q2, d2, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst)
        gap = min(gap, d2)
        if gap > worst:
            gap = min(gap, _surface_dist2(q2, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst)[0])
    return max(gap, worst)


@nb.njit(cache=True, nogil=True)
def reshaped_gap(t, fan_u, nu, fl, fr, vl, vr, F, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces,
                 mark, stamp, floor):
    """The largest gap (not squared) of what a collapse onto ``t`` made new, at least ``floor``.

    New are the edges from t to u's old ring (but vl and vr, whose edges to
    t existed: :data:`EDGE_SAMPLES` of each) and the interiors of u's faces
    (``fan_u[:nu]``, all but ``fl`` and ``fr`` surviving with t in u's place:
    their centroids). Every other edge and face keeps the shape it was
    measured with, by the collapse that made it, whose node is a child of
    this one or the current node of a position of the new ring (both feed
    this node's error: children's errors and saturation). ``mark`` (e,)
    int64 with ``stamp`` (never used before) lists each ring position once.
    """
    worst = floor * floor
    for i in range(nu):
        f = fan_u[i]
        if f == fl or f == fr:
            continue
        k = corner_of(F, f, t)
        for x in (F[f, (k + 1) % 3], F[f, (k + 2) % 3]):
            if x == vl or x == vr or mark[x] == stamp:
                continue
            mark[x] = stamp
            for w in EDGE_SAMPLES:
                sx = (1.0 - w) * P[t, 0] + w * P[x, 0]
                sy = (1.0 - w) * P[t, 1] + w * P[x, 1]
                sz = (1.0 - w) * P[t, 2] + w * P[x, 2]
                worst = sample_gap2(sx, sy, sz, t if w < 0.5 else x, f, P, pt_head, pt, face_pos, face_nbrs,
                                    star_start, star_faces, worst)
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        sx = (P[a, 0] + P[b, 0] + P[c, 0]) / 3.0
        sy = (P[a, 1] + P[b, 1] + P[c, 1]) / 3.0
        sz = (P[a, 2] + P[b, 2] + P[c, 2]) / 3.0
        q, dq = a, _dist2(a, sx, sy, sz, P)
        for r in (b, c):
            d = _dist2(r, sx, sy, sz, P)
            if d < dq:
                q, dq = r, d
        worst = sample_gap2(sx, sy, sz, q, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst)
    return math.sqrt(worst)
