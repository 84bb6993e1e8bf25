"""The build: half-edge collapses chosen by quadric error, recorded as nodes.

Error bounds (what the runtime's screen-space test reads) are measured, not
estimated: every position a collapse removes becomes a *carried point* of a
face near it, and every collapse re-measures the points carried by the
faces it reshapes (those of the floating position's fan) against the new
local surface, reassigning each to a face of the new fan (the first within
the error so far, else the nearest: :mod:`caveclod.kernels.carried`). A node's error is
the largest such distance, or its children's, so it bounds the real
distance from the original positions of its region to the coarser surface
(Hoppe's PM residuals, measured exactly instead of sampled). Interior points
are measured against triangles; points that lay on a border or a seam are
measured against the same boundary's new polyline, because sliding along a
border moves the outline even where it moves no surface off its plane.

The runtime shows meshes the build never made: a node kept coarse beside a
neighbour refined further than it was when the node was made. Measured
errors do not cover those, and on rough terrain they exceeded the bound by
up to 1.8x. So errors are *saturated*: a node's error is at least that of
every node its collapse makes adjacent (the ring of the new fan), as terrain
LOD saturates errors over dependencies (Pajarola 1998; Lindstrom & Pascucci
2001). Saturation alone does not make a view that needs a neighbour finer
need this node finer too (each is tested at its own sphere, and the
neighbour's may reach nearer the eye): each node also records its ring
bound (:func:`ring_bound`), and the runtime splits it whenever a neighbour
needs detail by its own test, so the runtime mesh stays one the build
measured but for neighbours split for their own neighbours' sake or forced
(docs/error-bounds.md). The bound
covers both directions: the original positions against the coarse faces
(carried points), and the new edges and faces of each collapse against the
original surface (:mod:`caveclod.kernels.surfacegap`). Measured
renderer-free, both stay near the tolerance: p99 under it, the maximum
within 1.5 times it in tests/test_error_bound.py (benchmarks/error.py has
the figures).

Garland & Heckbert quadrics pick the collapses; Hoppe (1997) says what each
node must remember; Kram & Shaw section 3.3 says which collapses are allowed.
Work proceeds in passes (as meshoptimizer does): each pass ranks the best
legal collapse of every vertex, then performs them cheapest first, skipping
any whose ends an earlier collapse of the same pass moved or grew, and
checking legality again on the current mesh. Passes keep the hierarchy
shallow, which keeps the runtime's forced-split chains short.

Collapse of the floating position ``u`` into the stationary position ``t``::

        vl                      vl
       /  \\                   /  \\
      / fl \\                 /    \\
     t ---- u     ==>        s      (u gone; its faces now use s = t)
      \\ fr /                 \\    /
       \\  /                   \\  /
        vr                      vr

``fl = (t, u, vl)`` holds the directed edge t->u, ``fr = (u, t, vr)`` holds
u->t. Their outer neighbours are recorded per node as ``fn = (fl_u, fl_t,
fr_u, fr_t)``: ``fl_u`` across fl's edge u->vl, ``fl_t`` across vl->t,
``fr_u`` across vr->u and ``fr_t`` across t->vr.
"""

import math

import numba as nb
import numpy as np

from .borrow import borrow
from .bounds import cone_add_cone, quadric_add_plane, quadric_eval, sphere_add_sphere
from .carried import remeasure
from .fans import collect_fan, corner_of, replace_in_row
from .surfacegap import edge_stack, reshaped_gap

FREE, SHARP, RIGID = 0, 1, 2
BOUNDARY_WEIGHT = 4.0   # keep borders and seams in place, relative to area
BUCKETS = 32             # cost slices of a pass, each made in position order


@nb.njit(cache=True, nogil=True)
def init_leaves(P, F, N, fgroup, vface, Q):
    """Per-position quadrics of leaves. A leaf's sphere is its point and its
    normal cone is made when its collapse needs it (:func:`leaf_cone`), so
    neither is stored: see :func:`do_collapse`.

    Args:
        P: (e, 3) float64 positions. F: (p, 3) int32 faces over positions.
        N: (p, 3) int32 neighbours. fgroup: (p,) int32 surface groups.
        vface: (e,) int32 out: one face at each position (-1 if none).
        Q: (e, 10) float64 out.
    """
    e = P.shape[0]
    for x in range(e):
        vface[x] = -1
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        # Scalars, not P[b] - P[a]: that allocated two arrays a face.
        e10, e11, e12 = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
        e20, e21, e22 = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
        n0 = e11 * e22 - e12 * e21
        n1 = e12 * e20 - e10 * e22
        n2 = e10 * e21 - e11 * e20
        ln = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        for k in range(3):
            if vface[F[f, k]] == -1:
                vface[F[f, k]] = f
        if ln == 0.0:
            continue
        n0, n1, n2 = n0 / ln, n1 / ln, n2 / ln
        d = -(n0 * P[a, 0] + n1 * P[a, 1] + n2 * P[a, 2])
        w = 0.5 * ln
        for k in range(3):
            x = F[f, k]
            quadric_add_plane(Q[x], n0, n1, n2, d, w)
            h = N[f, k]
            if h >= 0 and fgroup[h] == fgroup[f]:
                continue
            # Border or seam edge: a plane through the edge, perpendicular
            # to the face, so moving along the edge is free and off it costs.
            xa, xb = F[f, k], F[f, (k + 1) % 3]
            ex, ey, ez = P[xb, 0] - P[xa, 0], P[xb, 1] - P[xa, 1], P[xb, 2] - P[xa, 2]
            m0, m1, m2 = ey * n2 - ez * n1, ez * n0 - ex * n2, ex * n1 - ey * n0
            ml = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
            if ml == 0.0:
                continue
            m0, m1, m2 = m0 / ml, m1 / ml, m2 / ml
            md = -(m0 * P[xa, 0] + m1 * P[xa, 1] + m2 * P[xa, 2])
            wb = BOUNDARY_WEIGHT * (ex * ex + ey * ey + ez * ez)
            quadric_add_plane(Q[xa], m0, m1, m2, md, wb)
            quadric_add_plane(Q[xb], m0, m1, m2, md, wb)


@nb.njit(cache=True, nogil=True, inline="always")
def leaf_cone(x, P, face_pos, star_start, star_faces, c):
    """Write into ``c`` (4,) the normal cone of position ``x``'s faces in the
    original mesh (``face_pos`` (p, 3) int32, ``star_start`` and
    ``star_faces`` its CSR lists: :func:`caveclod.kernels.surfacegap.star_lists`).

    Made when the leaf's collapse needs it rather than kept for every
    position (16 bytes a triangle at the build's peak); the faces come in
    id order, so the cone is the one a pass over all faces would make.
    """
    c[0], c[1], c[2], c[3] = 0.0, 0.0, 1.0, -1.0
    for i in range(star_start[x], star_start[x + 1]):
        f = star_faces[i]
        n0, n1, n2 = _normal(P, face_pos[f, 0], face_pos[f, 1], face_pos[f, 2])
        ln = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if ln == 0.0:
            continue
        n0, n1, n2 = n0 / ln, n1 / ln, n2 / ln
        # Normals already inside the cone need no trigonometry.
        if c[3] < 0.0 or c[3] < math.pi and c[0] * n0 + c[1] * n1 + c[2] * n2 < math.cos(c[3]) - 1e-12:
            cone_add_cone(c, n0, n1, n2, 0.0)


@nb.njit(cache=True, nogil=True, inline="always")
def _has_group(pg_start, pg_groups, x, g):
    for i in range(pg_start[x], pg_start[x + 1]):
        if pg_groups[i] == g:
            return True
    return False


STAMP_LIMIT = 2 ** 31 - 1


@nb.njit(cache=True, nogil=True, inline="always")
def next_stamp(mark, counter):
    """A stamp that no entry of ``mark`` (e,) int32 holds: ``counter`` (1,)
    int64, a thread's for the whole build, plus one. Stamps are int32, 4
    bytes a position for each thread at work where int64 took 8: when they
    run out, ``mark`` is cleared and they start again, which is safe since
    a stamp is compared only within the check that drew it."""
    if counter[0] >= STAMP_LIMIT:
        mark[:] = -1
        counter[0] = 0
    counter[0] += 1
    return counter[0]


@nb.njit(cache=True, nogil=True, inline="always")
def _normal(P, a, b, c):
    e10, e11, e12 = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
    e20, e21, e22 = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
    return (e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20)


@nb.njit(cache=True, nogil=True)
def check_collapse(u, t, P, F, N, vface, fgroup, pclass, fixed, pg_start, pg_groups,
                   fan_u, fan_t, mark, stamp):
    """Whether collapsing position ``u`` into ``t`` is legal (see module doc).

    ``mark`` (e,) int32 and ``stamp`` (never used before) find shared neighbours;
    callers draw stamps with :func:`next_stamp`.
    Returns (legal, fl, fr, nu): ``fan_u[:nu]`` then holds u's faces.
    """
    if pclass[u] == RIGID or fixed[u] or fixed[t]:
        return False, -1, -1, 0
    nu, border_u = collect_fan(F, N, vface[u], u, fan_u)
    nt, border_t = collect_fan(F, N, vface[t], t, fan_t)
    if nu >= fan_u.shape[0] or nt >= fan_t.shape[0]:
        return False, -1, -1, 0
    fl, fr = -1, -1
    for i in range(nu):
        f = fan_u[i]
        ku = corner_of(F, f, u)
        if F[f, (ku + 2) % 3] == t:      # ... t -> u ...
            fl = f
        elif F[f, (ku + 1) % 3] == t:    # ... u -> t ...
            fr = f
    if fl == -1 and fr == -1:
        return False, -1, -1, 0
    interior = fl != -1 and fr != -1
    if interior and border_u and border_t:
        return False, -1, -1, 0              # would pinch the surface into a bow-tie
    if pclass[u] == SHARP:
        # Paper 3.3: a SHARP position only slides along its own boundary.
        if interior and fgroup[fl] == fgroup[fr]:
            return False, -1, -1, 0
    vl, vr = -1, -1
    fn0 = fn1 = fn2 = fn3 = -1
    if fl != -1:
        k = corner_of(F, fl, u)
        vl = F[fl, (k + 1) % 3]
        fn0 = N[fl, k]                    # across u -> vl
        fn1 = N[fl, (k + 1) % 3]          # across vl -> t
        if fn0 == -1 and fn1 == -1:
            return False, -1, -1, 0          # vl would be left without faces
    if fr != -1:
        k = corner_of(F, fr, u)
        vr = F[fr, (k + 2) % 3]
        fn2 = N[fr, (k + 2) % 3]          # across vr -> u
        fn3 = N[fr, (k + 1) % 3]          # across t -> vr
        if fn2 == -1 and fn3 == -1:
            return False, -1, -1, 0
    if vl != -1 and vl == vr:
        return False, -1, -1, 0
    for g in (fn0, fn1, fn2, fn3):
        if g != -1 and (g == fl or g == fr):
            return False, -1, -1, 0
    # The two faces that become neighbours must not be the same triangle.
    if fn0 != -1 and fn1 != -1:
        if F[fn0, 0] + F[fn0, 1] + F[fn0, 2] - u == F[fn1, 0] + F[fn1, 1] + F[fn1, 2] - t:
            return False, -1, -1, 0
    if fn2 != -1 and fn3 != -1:
        if F[fn2, 0] + F[fn2, 1] + F[fn2, 2] - u == F[fn3, 0] + F[fn3, 1] + F[fn3, 2] - t:
            return False, -1, -1, 0
    # Link condition: the only positions next to both u and t are vl and vr.
    for i in range(nt):
        f = fan_t[i]
        for k in range(3):
            mark[F[f, k]] = stamp
    for i in range(nu):
        f = fan_u[i]
        for k in range(3):
            w = F[f, k]
            if w != u and w != t and w != vl and w != vr and mark[w] == stamp:
                return False, -1, -1, 0
    # Surface groups, orientation and degeneracy of every face that moves.
    sx = sy = sz = 0.0
    for i in range(nu):
        f = fan_u[i]
        n = _normal(P, F[f, 0], F[f, 1], F[f, 2])
        sx += n[0]
        sy += n[1]
        sz += n[2]
    for i in range(nu):
        f = fan_u[i]
        if f == fl or f == fr:
            continue
        if not _has_group(pg_start, pg_groups, t, fgroup[f]):
            return False, -1, -1, 0
        k = corner_of(F, f, u)
        a, b = F[f, (k + 1) % 3], F[f, (k + 2) % 3]
        old = _normal(P, u, a, b)
        new = _normal(P, t, a, b)
        new_len2 = new[0] * new[0] + new[1] * new[1] + new[2] * new[2]
        old_len2 = old[0] * old[0] + old[1] * old[1] + old[2] * old[2]
        if new_len2 <= 1e-30 * (old_len2 + 1e-300) or new_len2 == 0.0:
            return False, -1, -1, 0
        ref0, ref1, ref2 = old[0], old[1], old[2]
        if old_len2 == 0.0:               # a sliver: compare with the fan
            ref0, ref1, ref2 = sx, sy, sz
        if ref0 * new[0] + ref1 * new[1] + ref2 * new[2] <= 0.0:
            return False, -1, -1, 0
    return True, fl, fr, nu


@nb.njit(cache=True, nogil=True, inline="always")
def _node_err(err, x, e):
    """Error of node ``x``: 0 for a leaf (an original position), else its row of ``err`` (e,)."""
    return err[x - e] if x >= e else 0.0


@nb.njit(cache=True, nogil=True, inline="always")
def ring_bound(ring, j, reach, error):
    """Record internal node ``j``'s ring bound in ``ring`` (e, 2) float32: (reach, error).

    The ring is the current nodes of the positions around the new node's
    position when it is made (:func:`do_collapse` measures it). Its error is
    the largest of theirs (0 for leaves), its reach how far their spheres
    stick out of the node's final sphere, from its centre (0 at least: a
    leaf's position lies in the sphere already). The runtime splits the node
    when that error, seen at its sphere grown by the reach, is above the
    tolerance: then a ring node that the view needs finer by its own test
    never stands beside it kept coarse, a mix of ages the build never
    measured (docs/error-bounds.md). Both are rounded up on the way to float32.
    """
    # float32 rounds to nearest, within 2**-24 of the value: the factor keeps it above.
    ring[j, 0] = np.float32(max(reach, 0.0) * (1.0 + 1e-6))
    ring[j, 1] = np.float32(error * (1.0 + 1e-6))


@nb.njit(cache=True, nogil=True)
def do_collapse(u, t, fl, fr, P, F, N, vface, alive, Q, cur_node, parent, child, npos,
                nfaces, nfn, sphere, cone, err, creator, rotation, m, e, fan_u, nu, fan_t,
                face_pos, star_start, star_faces, leaf):
    """Perform a legal collapse and record node ``e + m``.

    ``sphere`` (e, 4), ``cone`` (e, 4) and ``err`` (e,) hold internal nodes
    only (node ``e + m`` at row m): a leaf's sphere is its position, its
    error 0 and its cone that of its original faces (made in ``leaf`` (4,)
    from ``face_pos``, ``star_start``, ``star_faces``: :func:`leaf_cone`).
    ``fan_u[:nu]`` are u's faces, as :func:`check_collapse` left them.
    Fills ``fan_t`` with t's new fan and ``rotation`` (p,) uint8 with the
    corner at which fl's (fr's) source face holds t (u): a split makes the
    face from its nodes, and the rotation lets it list its corners in the
    source's order, so that full refinement gives the source faces back
    exactly. Returns ``(node, fan size, error the node has anyway, vl, vr,
    ring error, ring far)``: the error is its children's and its new
    neighbours' (saturation, module doc), to which the caller adds the
    measured distances; vl and vr are the third corners of fl and fr (-1
    where absent); the ring error is the new neighbours' largest, and the
    ring far how far from the node's centre their spheres reach (internal
    neighbours only): :func:`ring_bound`'s.
    """
    s = e + m
    tn, un = cur_node[t], cur_node[u]
    parent[tn] = s
    parent[un] = s
    child[m, 0], child[m, 1] = tn, un
    npos[m] = t
    nfaces[m, 0], nfaces[m, 1] = fl, fr
    fn0 = fn1 = fn2 = fn3 = -1
    vl = vr = -1
    if fl != -1:
        k = corner_of(F, fl, u)
        vl = F[fl, (k + 1) % 3]
        fn0, fn1 = N[fl, k], N[fl, (k + 1) % 3]
    if fr != -1:
        k = corner_of(F, fr, u)
        vr = F[fr, (k + 2) % 3]
        fn2, fn3 = N[fr, (k + 2) % 3], N[fr, (k + 1) % 3]
    nfn[m, 0], nfn[m, 1], nfn[m, 2], nfn[m, 3] = fn0, fn1, fn2, fn3
    # Re-link the outer neighbours of fl and fr to each other.
    if fl != -1:
        if fn0 != -1:
            replace_in_row(N, fn0, fl, fn1)
        if fn1 != -1:
            replace_in_row(N, fn1, fl, fn0)
        alive[fl] = False
        creator[fl] = s
        rotation[fl] = corner_of(F, fl, t)     # fl's corners start at t in the source face
    if fr != -1:
        if fn2 != -1:
            replace_in_row(N, fn2, fr, fn3)
        if fn3 != -1:
            replace_in_row(N, fn3, fr, fn2)
        alive[fr] = False
        creator[fr] = s
        rotation[fr] = corner_of(F, fr, u)     # fr's corners start at u
    for i in range(nu):
        f = fan_u[i]
        if f != fl and f != fr:
            F[f, corner_of(F, f, u)] = t
    # Keep a live face at t, vl and vr.
    keep = -1
    for i in range(nu):
        if fan_u[i] != fl and fan_u[i] != fr:
            keep = fan_u[i]
            break
    for cand in (fn1, fn3, fn0, fn2):
        if keep == -1 and cand != -1:
            keep = cand
    if vface[t] == fl or vface[t] == fr:
        vface[t] = keep
    vface[u] = -1
    if vl != -1 and vface[vl] == fl:
        vface[vl] = fn0 if fn0 != -1 else fn1
    if vr != -1 and vface[vr] == fr:
        vface[vr] = fn2 if fn2 != -1 else fn3
    for j in range(10):
        Q[t, j] += Q[u, j]
    cur_node[t] = s
    cur_node[u] = -1
    # Node bounds: children's, plus the coarse faces around s.
    sp, cn = sphere[m], cone[m]
    sp[3] = cn[3] = -1.0
    for c in (tn, un):
        if c < e:                         # a leaf: its position, its original faces' cone
            sphere_add_sphere(sp, P[c, 0], P[c, 1], P[c, 2], 0.0)
            leaf_cone(c, P, face_pos, star_start, star_faces, leaf)
            cone_add_cone(cn, leaf[0], leaf[1], leaf[2], leaf[3])
        else:
            sphere_add_sphere(sp, sphere[c - e, 0], sphere[c - e, 1], sphere[c - e, 2], sphere[c - e, 3])
            cone_add_cone(cn, cone[c - e, 0], cone[c - e, 1], cone[c - e, 2], cone[c - e, 3])
    nt, open_fan = collect_fan(F, N, vface[t], t, fan_t)
    sphere_add_sphere(sp, P[t, 0], P[t, 1], P[t, 2], 0.0)
    cos_cone = math.cos(cn[3]) if cn[3] < math.pi else -2.0
    for i in range(nt):
        f = fan_t[i]
        k = corner_of(F, f, t)
        # Each ring position is the "next" corner of one fan face; an open
        # fan also ends on the "previous" corner of its first face.
        x = F[f, (k + 1) % 3]
        sphere_add_sphere(sp, P[x, 0], P[x, 1], P[x, 2], 0.0)
        if i == 0 and open_fan:
            x = F[f, (k + 2) % 3]
            sphere_add_sphere(sp, P[x, 0], P[x, 1], P[x, 2], 0.0)
        n = _normal(P, F[f, 0], F[f, 1], F[f, 2])
        ln = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        if ln == 0.0:
            continue
        n0, n1, n2 = n[0] / ln, n[1] / ln, n[2] / ln
        if cn[0] * n0 + cn[1] * n1 + cn[2] * n2 >= cos_cone + 1e-12:
            continue                      # already inside: skip the trigonometry
        cone_add_cone(cn, n0, n1, n2, 0.0)
        cos_cone = math.cos(cn[3]) if cn[3] < math.pi else -2.0
    # The error s has anyway: its children's (monotone up the tree) and its
    # new neighbours' (saturation, module doc).
    inherited = max(_node_err(err, tn, e), _node_err(err, un, e))
    ring_err = ring_far = 0.0
    for i in range(nt):
        f = fan_t[i]
        k = corner_of(F, f, t)
        for q in (F[f, (k + 1) % 3], F[f, (k + 2) % 3]):
            w = cur_node[q] - e
            if w >= 0:                    # an internal node (a leaf's error is 0, its position in sp)
                ring_err = max(ring_err, err[w])
                dx, dy, dz = sphere[w, 0] - sp[0], sphere[w, 1] - sp[1], sphere[w, 2] - sp[2]
                ring_far = max(ring_far, math.sqrt(dx * dx + dy * dy + dz * dz) + sphere[w, 3])
    return s, nt, max(inherited, ring_err), vl, vr, ring_err, ring_far


@nb.njit(cache=True, nogil=True)
def rank_collapses(P, F, N, vface, fgroup, pclass, fixed, pg_start, pg_groups, Q, lock, mark,
                   best_t, best_c, pass_id, region, counter):
    """Rank the cheapest legal collapse of the positions ``region`` (k,) int32.

    Writes ``best_t`` (target t, -1 if none) and ``best_c`` (cost), both (e,),
    for those positions. The ranking is redone only where the last pass moved
    something nearby. Reads the mesh only, so two threads may rank disjoint
    regions at once, each with its own ``mark`` and ``counter``.
    """
    _rank_collapses(P, F, N, vface, fgroup, pclass, fixed, pg_start, pg_groups, Q, lock, mark, best_t, best_c, pass_id,
                    region, counter, np.empty(4096, np.int32), np.empty(4096, np.int32), np.empty(4096, np.int32),
                    np.empty(4096, np.int32), np.empty(4096))


@nb.njit(cache=True, nogil=True)
def _rank_collapses(P, F, N, vface, fgroup, pclass, fixed, pg_start, pg_groups, Q, lock, mark,
                    best_t, best_c, pass_id, region, counter, fan_u, fan_t, ring, cand_t, cand_c):
    """:func:`rank_collapses` with its scratch ((4096,) each), every array
    borrowed (:mod:`caveclod.kernels.borrow`)."""
    P, F, N, vface, fgroup, pclass, fixed, pg_start, pg_groups, Q, lock, mark = (
        borrow(P), borrow(F), borrow(N), borrow(vface), borrow(fgroup), borrow(pclass), borrow(fixed),
        borrow(pg_start), borrow(pg_groups), borrow(Q), borrow(lock), borrow(mark))
    best_t, best_c, region, counter = borrow(best_t), borrow(best_c), borrow(region), borrow(counter)
    fan_u, fan_t, ring, cand_t, cand_c = borrow(fan_u), borrow(fan_t), borrow(ring), borrow(cand_t), borrow(cand_c)
    for r in range(region.shape[0]):
        u = region[r]
        if vface[u] == -1 or pclass[u] == RIGID or fixed[u]:
            continue
        nu, _ = collect_fan(F, N, vface[u], u, ring)
        if nu >= ring.shape[0]:
            best_t[u] = -1
            continue
        stale = pass_id == 0 or lock[u] == pass_id - 1
        for i in range(nu):
            for kk in range(3):
                if lock[F[ring[i], kk]] == pass_id - 1:
                    stale = True
        if stale:
            best_t[u] = -1
            # Neighbour positions of u, each once, with their collapse cost.
            k = 0
            for i in range(nu):
                f = ring[i]
                ku = corner_of(F, f, u)
                for w in (F[f, (ku + 1) % 3], F[f, (ku + 2) % 3]):
                    dup = False
                    for j in range(k):
                        if cand_t[j] == w:
                            dup = True
                            break
                    if not dup and k < cand_t.shape[0]:
                        cand_t[k] = w
                        # (Q_u + Q_w)(p_w): quadrics are linear, so sum the two errors.
                        cand_c[k] = (quadric_eval(Q[u], P[w, 0], P[w, 1], P[w, 2])
                                     + quadric_eval(Q[w], P[w, 0], P[w, 1], P[w, 2]))
                        k += 1
            # Try neighbours cheapest first (selection: k is small).
            for _ in range(k):
                j = 0
                for jj in range(1, k):
                    if cand_c[jj] < cand_c[j]:
                        j = jj
                if cand_c[j] == np.inf:
                    break
                w = cand_t[j]
                ok, _, _, _ = check_collapse(u, w, P, F, N, vface, fgroup, pclass, fixed,
                                          pg_start, pg_groups, fan_u, fan_t, mark, next_stamp(mark, counter))
                if ok:
                    best_t[u] = w
                    best_c[u] = cand_c[j]
                    break
                cand_c[j] = np.inf


@nb.njit(cache=True, nogil=True)
def gather_candidates(vface, best_t, best_c, region, cost, target, src):
    """Collect ranked collapses of the live positions of ``region`` (k,) int32
    into ``cost``, ``target``, ``src`` (>= k,); returns their number."""
    nc = 0
    for r in range(region.shape[0]):
        u = region[r]
        if vface[u] != -1 and best_t[u] >= 0:
            cost[nc] = best_c[u]
            target[nc] = best_t[u]
            src[nc] = u
            nc += 1
    return nc


@nb.njit(cache=True, nogil=True)
def perform_collapses(P, F, N, vface, alive, fgroup, pclass, fixed, pg_start, pg_groups, Q,
                      cur_node, parent, child, npos, nfaces, nfn, sphere, cone, err, ring, creator, rotation,
                      pt_head, pt, face_pos, face_nbrs, star_start, star_faces, m, lock, mark, pass_id, fraction,
                      cost, target, src, nc, counter):
    """Perform the cheapest ranked collapses; returns the new node count m.

    ``pt_head``, ``pt``: the carried points (:mod:`caveclod.kernels.carried`).
    ``face_pos`` (p, 3) int32, the original faces, ``face_nbrs`` (p, 3)
    int32 their neighbours, and ``star_start``, ``star_faces``, the faces
    around each position
    (:func:`caveclod.kernels.surfacegap.star_lists`): the original surface that
    reshaped faces are measured against. ``ring`` (e, 2) float32: each
    node's ring bound (:func:`ring_bound`), internal nodes only.

    At most ``fraction`` of the ranked ones (the cheapest) are tried unless
    none of those could be made. Each is checked again on the current mesh.
    """
    pieces, ends = edge_stack()
    return _perform_collapses(P, F, N, vface, alive, fgroup, pclass, fixed, pg_start, pg_groups, Q, cur_node, parent,
                              child, npos, nfaces, nfn, sphere, cone, err, ring, creator, rotation, pt_head, pt,
                              face_pos, face_nbrs, star_start, star_faces, m, lock, mark, pass_id, fraction, cost,
                              target, src, nc, counter, np.empty(4096, np.int32), np.empty(4096, np.int32),
                              np.empty(4096, np.int32), pieces, ends, np.empty(4))


@nb.njit(cache=True, nogil=True)
def _perform_collapses(P, F, N, vface, alive, fgroup, pclass, fixed, pg_start, pg_groups, Q,
                       cur_node, parent, child, npos, nfaces, nfn, sphere, cone, err, ring, creator, rotation,
                       pt_head, pt, face_pos, face_nbrs, star_start, star_faces, m, lock, mark, pass_id, fraction,
                       cost, target, src, nc, counter, fan_u, fan_t, heads, pieces, ends, leaf):
    """:func:`perform_collapses` with its scratch (``fan_u``, ``fan_t``,
    ``heads`` (4096,) int32, ``pieces``, ``ends`` from :func:`edge_stack`,
    ``leaf`` (4,) a leaf's cone), every array borrowed
    (:mod:`caveclod.kernels.borrow`)."""
    P, F, N, vface, alive, fgroup, pclass, fixed, pg_start, pg_groups, Q = (
        borrow(P), borrow(F), borrow(N), borrow(vface), borrow(alive), borrow(fgroup), borrow(pclass), borrow(fixed),
        borrow(pg_start), borrow(pg_groups), borrow(Q))
    cur_node, parent, child, npos, nfaces, nfn, sphere, cone, err, ring, creator, rotation = (
        borrow(cur_node), borrow(parent), borrow(child), borrow(npos), borrow(nfaces), borrow(nfn), borrow(sphere),
        borrow(cone), borrow(err), borrow(ring), borrow(creator), borrow(rotation))
    pt_head, pt, face_pos, face_nbrs, star_start, star_faces, lock, mark, cost, target, src, counter = (
        borrow(pt_head), borrow(pt), borrow(face_pos), borrow(face_nbrs), borrow(star_start), borrow(star_faces),
        borrow(lock), borrow(mark), borrow(cost), borrow(target), borrow(src), borrow(counter))
    fan_u, fan_t, heads, pieces, ends, leaf = (
        borrow(fan_u), borrow(fan_t), borrow(heads), borrow(pieces), borrow(ends), borrow(leaf))
    e = P.shape[0]
    if nc == 0:
        return m
    # The cheapest ``fraction`` of the ranked collapses are made first (the
    # rest only if none of those could be). They are made in BUCKETS slices
    # of rising cost, each slice in position order: cost order decides who
    # wins where two collapses touch (the hierarchy's quality), and position
    # order walks the mesh arrays front to back instead of jumping at random
    # (pure cost order spent half the build's time in cache misses).
    order = np.argsort(cost[:nc], kind="mergesort")   # stable: ties by position
    limit = max(1, int(nc * fraction))
    buckets = min(BUCKETS, limit)
    for b in range(buckets):
        order[limit * b // buckets: limit * (b + 1) // buckets].sort()
    order[limit:].sort()
    made = 0
    for attempt in range(2):
        lo = 0 if attempt == 0 else limit
        hi = limit if attempt == 0 else nc
        for idx in range(lo, hi):
            i = order[idx]
            u, t = src[i], target[i]
            if lock[u] == pass_id or lock[t] == pass_id:
                continue
            ok, fl, fr, nu = check_collapse(u, t, P, F, N, vface, fgroup, pclass, fixed,
                                        pg_start, pg_groups, fan_u, fan_t, mark, next_stamp(mark, counter))
            if not ok:
                continue
            # Lock both ends: a position moves at most once a pass and nothing
            # collapses onto a position whose quadric changed since ranking.
            lock[u] = pass_id
            lock[t] = pass_id
            # u becomes a carried point; a SHARP u slid along the boundary of
            # fl's group (or fr's, on a border) and is measured against it.
            u_group = -1
            if pclass[u] == SHARP:
                u_group = fgroup[fl] if fl != -1 else fgroup[fr]
            s, nt, inherited, vl, vr, ring_err, ring_far = do_collapse(
                u, t, fl, fr, P, F, N, vface, alive, Q, cur_node, parent, child, npos, nfaces, nfn, sphere, cone, err,
                creator, rotation, m, e, fan_u, nu, fan_t, face_pos, star_start, star_faces, leaf)
            dev = remeasure(u, u_group, fl, fr, fan_u, nu, fan_t, nt, P, F, N, fgroup, alive, pt_head, pt,
                            heads, inherited)
            # Both directions: the original positions to the coarse faces
            # (dev) and the reshaped coarse faces to the original surface.
            stamp = next_stamp(mark, counter)
            err[s - e] = reshaped_gap(t, fan_u, nu, fl, fr, vl, vr, F, P, pt_head, pt, face_pos, face_nbrs,
                                      star_start, star_faces, mark, stamp, dev, pieces, ends)
            # Each point lies within dev of a fan face, and the fan lies in
            # the sphere: growing it by dev makes it hold every point charged
            # to s.
            sphere[s - e, 3] += dev
            ring_bound(ring, s - e, ring_far - sphere[s - e, 3], ring_err)
            m += 1
            made += 1
        if made > 0:
            break
    return m
