"""The other direction of a node's error: how far its coarse faces lie from the original surface.

Carried points (:mod:`caveclod.kernels.carried`) bound the distance from
every original position to the coarse surface. That is one direction only:
between original positions the coarse surface can lie much farther from
the original. A long thin coarse face along the foot of a slope passes
under the slope's original faces, whose corners all lie near some coarse
face (measured on the smooth built-in terrain, benchmarks/error.py: points
of drawn faces up to 4.6 px from the original surface at a tolerance of
1 px, every original position within it).

So every collapse also measures what it made new: each new edge (from t
to u's old ring) at its midpoint and, where a piece of it may hide a
larger gap, at more points (:func:`edge_gap2`), and the centroid of each
face it reshaped (u's faces, whose corner u became t). Each sample walks from a
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
larger (``benchmarks/error.py`` measures the drawn surface at other points),
unless a piece's bound (:func:`_piece_bound2`) rules it out.
"""

import math

import numba as nb
import numpy as np

from .carried import NEXT
from .distance import point_triangle_dist2
from .fans import corner_of

EDGE_HALVINGS = 2
"""How many times :func:`edge_gap2` may halve the pieces of a new edge: at most
1 + 2 + 4 = 7 points measured along it.

The build used to measure a new edge at its midpoint only. On the rough
terrain the largest gaps of drawn edges sat elsewhere (where the nearest
original face changes: a straight coarse edge passing over a ridge peaks
near the ridge, which may be a fifth of the way along), and the drawn
surface reached 1.36-1.40 t at 0.5 and 1 px (benchmarks/error.py,
``--size 256``). Halving up to twice, with the bound of
:func:`_piece_bound2` sparing pieces that cannot exceed the gap found so
far, brought all 12 meshes and tolerances of that benchmark within 1.18 t
(1.23 t with one halving) for 0.5-3 % more faces, and cost 20-25 % more
CPU in the 1M rough terrain's build (6.8 s against 5.5 s). Sampling
without the bound was tried twice before and not kept: long edges about
every original edge length (at most 8 points) and large faces at 3 more
points (rough terrain at 1 px 1.36 -> 1.19 t, builds a quarter slower),
and an odd number of samples an edge up to 7 with walks stopping at the
first point within the error (1.36 -> 1.29 t, the scan at 0.5 px 1.39 ->
1.48 t: 8 of 12 within 1.25 t, 28 % more CPU). Faces' interiors were never
where the largest gap was found (their 6 inner check points against 12 on
edges), so a face is still measured at its centroid only."""

HALVE_ABOVE = 0.5
"""After the first halving, a piece is halved again only if the gap at one of its ends exceeds
this share of the largest gap found so far: an edge whose measured points all lie well within
it is left there (the 1M rough terrain's build: 6.8 s of CPU, 7.2 s halving every piece twice)."""

MAX_STEPS = 4096
"""Most steps of each of a sample's walks, over positions and then faces (a walk
ends sooner where no neighbour is nearer; the distance reached bounds the gap anyway)."""


def star_lists(face_pos: np.ndarray, n_positions: int) -> tuple[np.ndarray, np.ndarray]:
    """The original faces around each position, as CSR lists.

    ``face_pos`` (p, 3) int32 faces over positions. Returns ``(start, faces)``:
    (e + 1,) int32 offsets (int64 from 715M faces on, where 3p passes
    int32) and (3p,) int32 face ids, the faces around position ``x`` being
    ``faces[start[x]:start[x + 1]]``.
    """
    start = np.zeros(n_positions + 1, np.int32 if face_pos.size < 2 ** 31 else np.int64)
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
def nearest_face2(sx, sy, sz, start, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst):
    """(squared distance, face): an original face near sample s and s's squared distance to it,
    which is at least s's gap to the original surface; a face within ``worst`` (squared) of s if
    the walks find one (then not necessarily the nearest), else the nearest they reach.

    Walks from the original position ``start`` over the original mesh's edges
    to the nearest position it can reach, then measures the original faces
    around it and walks across faces' edges while a face is nearer. A walk
    that ends on a face with a border edge may have stopped short of the
    sample at a hole or a border: it starts again from the nearest point
    coarse face ``f`` carries. The face is -1 only if the walk reached a
    position with no face (then the distance is that position's).
    """
    q, d1 = _walk(start, _dist2(start, sx, sy, sz, P), sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces,
                  worst)
    gap, g = _surface_dist2(q, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst)
    if g == -1:
        return d1, -1
    if gap <= worst:
        return gap, g
    if face_nbrs[g, 0] >= 0 and face_nbrs[g, 1] >= 0 and face_nbrs[g, 2] >= 0:
        return gap, g            # nothing stopped the walk: a border edge is what can
    x = pt_head[f]
    q2, d2 = q, d1
    while x != -1:
        d = _dist2(x, sx, sy, sz, P)
        if d < d2:
            q2, d2 = x, d
        x = pt[x, NEXT]
    if q2 != q:
        q2, d2 = _walk(q2, d2, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst)
        gap2, g2 = _surface_dist2(q2, sx, sy, sz, P, face_pos, face_nbrs, star_start, star_faces, worst)
        if g2 != -1 and gap2 < gap:
            gap, g = gap2, g2
    return gap, g


@nb.njit(cache=True, nogil=True)
def sample_gap2(sx, sy, sz, start, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst):
    """Squared distance from sample s to the original surface, if more than
    ``worst`` (squared); ``worst`` otherwise (:func:`nearest_face2`'s walks)."""
    gap = nearest_face2(sx, sy, sz, start, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst)[0]
    return max(gap, worst)


@nb.njit(cache=True, nogil=True, inline="always")
def _along(w, t, x, P):
    """The point a fraction ``w`` of the way from position t to position x."""
    return ((1.0 - w) * P[t, 0] + w * P[x, 0], (1.0 - w) * P[t, 1] + w * P[x, 1],
            (1.0 - w) * P[t, 2] + w * P[x, 2])


@nb.njit(cache=True, nogil=True)
def _piece_bound2(wa, wb, ga, gb, t, x, P, face_pos, star_start, star_faces):
    """Squared upper bound of the gap over the piece [wa, wb] of edge t-x.

    The distance to one original face (a convex set) is a convex function
    along a segment, so over the piece it is at most the larger of its values
    at the piece's ends; the gap is at most the distance to any face. The
    least such bound over the faces found at the ends: ``ga`` and ``gb``, or
    where one is -1 (an end of the edge, an original position) every face
    around that position, which holds it (distance 0 there).
    """
    ax, ay, az = _along(wa, t, x, P)
    bx, by, bz = _along(wb, t, x, P)
    best = np.inf
    for side in range(2):
        g = ga if side == 0 else gb
        if g >= 0:
            best = min(best, max(_tri_dist2(g, ax, ay, az, P, face_pos), _tri_dist2(g, bx, by, bz, P, face_pos)))
            continue
        q = t if side == 0 else x
        ox, oy, oz = (bx, by, bz) if side == 0 else (ax, ay, az)
        for j in range(star_start[q], star_start[q + 1]):
            best = min(best, _tri_dist2(star_faces[j], ox, oy, oz, P, face_pos))
    return best


@nb.njit(cache=True, nogil=True)
def edge_stack():
    """(pieces, faces): empty scratch for :func:`edge_gap2`, made once per caller, not once an edge."""
    return np.empty((EDGE_HALVINGS + 1, 5)), np.empty((EDGE_HALVINGS + 1, 2), np.int64)


@nb.njit(cache=True, nogil=True)
def edge_gap2(t, x, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst, pieces, faces):
    """The larger of ``worst`` and the gap (squared) measured along the edge t-x.

    The midpoint is measured (:func:`nearest_face2`), then the halves on
    either side of a measured point are halved again (at most
    :data:`EDGE_HALVINGS` times) while a half may hide a larger gap: unless
    a half's bound (:func:`_piece_bound2`, from the faces found at its ends)
    is within ``worst``, and, past the first halving, unless the gaps at its
    ends are both within :data:`HALVE_ABOVE` of ``worst`` (it is then far
    from the largest gap). ``f`` is a coarse face with the edge (its carried points restart
    walks stopped by holes); ``pieces`` (k, 5) float64 (ends, halvings,
    squared gaps at the ends) and ``faces`` (k, 2) int64 (the faces at the
    ends; -1 at the edge's own ends), k > :data:`EDGE_HALVINGS`: the stack
    of pieces still to look at.
    """
    pieces[0, 0], pieces[0, 1], pieces[0, 2], pieces[0, 3], pieces[0, 4] = 0.0, 1.0, 0.0, 0.0, 0.0
    faces[0, 0], faces[0, 1] = -1, -1
    n = 1
    while n > 0:
        n -= 1
        wa, wb, depth, da, db = pieces[n, 0], pieces[n, 1], pieces[n, 2], pieces[n, 3], pieces[n, 4]
        ga, gb = faces[n, 0], faces[n, 1]
        if depth > 1 and max(da, db) <= HALVE_ABOVE * HALVE_ABOVE * worst:
            continue
        if depth > 0 and _piece_bound2(wa, wb, ga, gb, t, x, P, face_pos, star_start, star_faces) <= worst:
            continue
        wm = 0.5 * (wa + wb)
        sx, sy, sz = _along(wm, t, x, P)
        start = face_pos[ga, 0] if ga >= 0 else t
        gap, gm = nearest_face2(sx, sy, sz, start, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces,
                                worst)
        worst = max(worst, gap)
        if gm == -1 or depth >= EDGE_HALVINGS:
            continue
        pieces[n, 0], pieces[n, 1], pieces[n, 2], pieces[n, 3], pieces[n, 4] = wm, wb, depth + 1.0, gap, db
        faces[n, 0], faces[n, 1] = gm, gb
        pieces[n + 1, 0], pieces[n + 1, 1], pieces[n + 1, 2], pieces[n + 1, 3], pieces[n + 1, 4] = \
            wa, wm, depth + 1.0, da, gap
        faces[n + 1, 0], faces[n + 1, 1] = ga, gm
        n += 2
    return worst


@nb.njit(cache=True, nogil=True)
def reshaped_gap(t, fan_u, nu, fl, fr, vl, vr, F, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces,
                 mark, stamp, floor, pieces, faces):
    """The largest gap (not squared) of what a collapse onto ``t`` made new, at least ``floor``.

    New are the edges from t to u's old ring (but vl and vr, whose edges to
    t existed: bounded whole, :func:`edge_gap2`) and the interiors of u's
    faces (``fan_u[:nu]``, all but ``fl`` and ``fr`` surviving with t in u's
    place: their centroids, a sample). Every other edge and face keeps the shape it was
    measured with, by the collapse that made it, whose node is a child of
    this one or the current node of a position of the new ring (both feed
    this node's error: children's errors and saturation). ``mark`` (e,)
    int32 with ``stamp`` (never used before) lists each ring position once.
    ``pieces``, ``faces``: :func:`edge_gap2`'s stack (:func:`edge_stack`).
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
            worst = edge_gap2(t, x, f, P, pt_head, pt, face_pos, face_nbrs, star_start, star_faces, worst,
                              pieces, faces)
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
