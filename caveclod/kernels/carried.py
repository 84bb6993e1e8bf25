"""Carried points: the original positions each face of the build answers for.

Every position a collapse removes becomes a point carried by a face near
it; every collapse re-measures the points carried by the faces it reshapes
(the floating position's fan) against the new surface and hands each to a
face of the new fan. A node's error is at least the largest of those distances (see
:mod:`caveclod.kernels.simplify`).

Which face a point goes to does not matter to the bound (its distance to
that face is what the node's error covers), only to how much later
collapses measure. A point goes to the first face of the new fan within
the error so far, else to its nearest: on the 1M rough terrain the points of
the two vanished faces of each collapse measured 6.6 faces each when they
went to the nearest one. tests/test_carried.py checks the bound for every
point the build leaves.

Storage: per face a linked list of its points (``pt_head`` (p,) int32, the
first point of each face or -1) and per position a row ``pt`` (e, 2) int32:
(next point of the same face, the surface group whose boundary it lay on or
-1 for an interior point). One row per point keeps a visit to one cache
line. (Faces keeping their points' coordinates in
contiguous chunks of a pool measured no faster, and took more memory.)
"""

import math

import numba as nb
import numpy as np

from .distance import point_segment_dist2, point_triangle_dist2

NEXT, GROUP = 0, 1               # columns of ``pt``


def new_store(n_faces: int, n_positions: int):
    """Empty (pt_head, pt) for a build of that size."""
    return np.full(n_faces, -1, np.int32), np.full((n_positions, 2), -1, np.int32)


@nb.njit(cache=True, nogil=True, inline="always")
def _face_dist2(P, F, N, fgroup, f, g, px, py, pz):
    """Squared distance from p to face ``f`` (g < 0), or to its edges on the
    boundary of group g (inf if it has none)."""
    if g < 0:
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        return point_triangle_dist2(px, py, pz, P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2],
                                    P[c, 0], P[c, 1], P[c, 2])
    best = np.inf
    if fgroup[f] != g:
        return best
    for k in range(3):
        h = N[f, k]
        if h >= 0 and fgroup[h] == g:
            continue
        a, b = F[f, k], F[f, (k + 1) % 3]
        d = point_segment_dist2(px, py, pz, P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2])
        if d < best:
            best = d
    return best


@nb.njit(cache=True, nogil=True, inline="always")
def _choose_face(px, py, pz, g, f0, h0, h1, P, F, N, fgroup, alive, fan_t, nt, worst):
    """(face, squared distance) that point p goes to among ``fan_t[:nt]``.

    A point that lay on a boundary of surface group g >= 0 is measured
    against g's boundary edges (or, when the fan has none, the triangles);
    others against the triangles. The point goes to the first face no
    farther from it than ``worst`` (squared; the bound is then unchanged)
    and only otherwise to its nearest face. Its old face ``f0`` comes first
    when it survived (most points stay put for one distance), then ``h0``
    and ``h1`` (-1 for none: the neighbours of a vanished ``f0``, which
    took over its area), then the fan in order.
    """
    if f0 >= 0 and alive[f0]:
        d = _face_dist2(P, F, N, fgroup, f0, g, px, py, pz)
        if d <= worst:
            return f0, d
    for h in (h0, h1):
        if h >= 0 and alive[h]:
            d = _face_dist2(P, F, N, fgroup, h, g, px, py, pz)
            if d <= worst:
                return h, d
    best_f = -1
    best = np.inf
    for i in range(nt):
        f = fan_t[i]
        d = _face_dist2(P, F, N, fgroup, f, g, px, py, pz)
        if d < best:
            best, best_f = d, f
            if d <= worst:
                return best_f, best
    if best_f == -1:                 # no boundary edge of g here: use the triangles
        for i in range(nt):
            f = fan_t[i]
            d = _face_dist2(P, F, N, fgroup, f, -1, px, py, pz)
            if d < best:
                best, best_f = d, f
                if d <= worst:
                    return best_f, best
    return best_f, best


@nb.njit(cache=True, nogil=True, inline="always")
def _place(x, f0, h0, h1, P, F, N, fgroup, alive, fan_t, nt, pt_head, pt, worst):
    """Give point ``x`` (carried by ``f0`` until now, or -1) to a face; returns
    its squared distance to it. ``h0``, ``h1``: faces to try after ``f0``."""
    f, d = _choose_face(P[x, 0], P[x, 1], P[x, 2], pt[x, GROUP], f0, h0, h1, P, F, N, fgroup, alive, fan_t, nt,
                        worst)
    pt[x, NEXT] = pt_head[f]
    pt_head[f] = x
    return d


@nb.njit(cache=True, nogil=True)
def remeasure(u, u_group, fl, fr, fan_u, nu, fan_t, nt, P, F, N, fgroup, alive, pt_head, pt, heads, floor):
    """Re-measure what the collapse of ``u`` disturbed; returns the distance.

    Takes the points of the faces ``fan_u[:nu]`` (u's fan before the
    collapse, fl and fr included) plus position ``u`` itself (a boundary
    point of group ``u_group``, or -1), and gives each to a face of
    ``fan_t[:nt]`` (the new fan, after the collapse). Returns the largest
    distance between a point and its face, at least ``floor`` (the error the
    node has anyway, under which points may stay where they are). ``heads``
    is scratch of ``nu`` entries.
    """
    # Take the lists out first: faces of the new fan receive points while the
    # old lists are still being walked.
    for i in range(nu):
        heads[i] = pt_head[fan_u[i]]
        pt_head[fan_u[i]] = -1
    worst = floor * floor
    pt[u, GROUP] = u_group
    worst = max(worst, _place(u, -1, -1, -1, P, F, N, fgroup, alive, fan_t, nt, pt_head, pt, worst))
    # Points of the vanished faces fl and fr first: they have no face to stay
    # on, and their distances raise the threshold under which the others stay.
    for dead_first in (True, False):
        for i in range(nu):
            f0 = fan_u[i]
            if (f0 == fl or f0 == fr) != dead_first:
                continue
            # A vanished face's area went to its outer neighbours (fl's are
            # across u -> vl and vl -> t, both now faces of t's fan): its
            # points try those first. Its row of N is as it was.
            h0 = h1 = -1
            if dead_first:
                for k in range(3):
                    h = N[f0, k]
                    if h >= 0 and h != fl and h != fr:
                        if h0 == -1:
                            h0 = h
                        else:
                            h1 = h
            x = heads[i]
            while x != -1:
                nxt = pt[x, NEXT]
                d = _place(x, f0, h0, h1, P, F, N, fgroup, alive, fan_t, nt, pt_head, pt, worst)
                if d > worst:
                    worst = d
                x = nxt
    return math.sqrt(worst)
