"""Per-camera incremental selective refinement (Hoppe 1997, Kram & Shaw 3.6).

A camera's state is a handful of arrays; the static mesh is only read, so
any number of cameras share it and each kernel call releases the GIL.

Camera state (see :class:`caveclod.refine.camera.CameraState`), sized to fit
the paper's Equation 1 per-camera term ``4n + 4p + 16 + 12 n_a + 36 p_a``:

* ``state``, a byte per node: INACTIVE (below the front), ACTIVE, SPLIT
  (above it), plus the IN_LIST bit while the node has an entry in the active
  list, the QUEUED bit while it waits in the collapse-candidate stack, and
  the RECHECK bit when its entry must be evaluated whatever its expiries.
  Held only for the nodes whose byte is not 0 (a hash table, or while that
  would be larger the dense byte per node of Equation 1's 4n:
  :mod:`caveclod.kernels.nodestate`), so a camera's bytes follow its view,
  not the mesh.
* ``face_map``: the record of each active face, a hash table over the
  active faces only, (c, 2) int32, or while that would be larger (a camera
  holding much of the mesh) the dense (p, 1) array of Equation 1's 4p that
  it replaced (:mod:`caveclod.kernels.facemap`).
* Records of active faces, pooled: material ``s`` owns records
  ``off[s] .. off[s] + cnt[s]`` of a capacity ``cap[s]``, and record
  ``off[s] + k`` *is* slot ``k`` of that material's index buffer: ``tri``
  (3 vertex-buffer indices: the mirror of the client's index buffer; a
  corner's position is ``vpos[tri]``, so corners need no array of their
  own), ``nbr`` (3 neighbour faces, edge k = corner k -> k+1) and ``face``;
  ``dirty`` is a bitset of the records written since the last delta.
  Removing a face moves the material's last record into its slot, so every
  index buffer stays dense.
* The active list: node ids with two float32 *expiries* each (Equation 1's
  12 bytes per active node), see below.

Split of node s into t (stationary) and u (floating), faces fl = (t, u, vl),
fr = (u, t, vr) and recorded neighbours fn = (fl_u, fl_t, fr_u, fr_t); see
:mod:`caveclod.kernels.simplify` for the picture.

One update is one pass over the active list in id order, Hoppe's traversal:
a node that needs detail is split (forcing the splits it depends on); a
stationary child whose sibling is active and whose parent no longer needs
detail collapses the pair when the collapse is legal. Two additions:

* **Collapse candidates.** A collapse can make others possible: its parent's
  (the sibling pair is now complete) and those of the nodes that created the
  four faces it re-links (their neighbours now match what their collapse
  requires). Those nodes are pushed on a stack and tried at once, so after a
  camera jump coarsening converges in an update or two instead of climbing
  one tree level per update. (Splits never make another collapse legal: the
  faces they create were dead when any node that could check them collapsed.)
* **Expiries.** Each kept entry records how far the camera may move before
  the node's answer could change: ``texp`` on the camera's travelled
  distance ``odo[0]`` (sum of eye displacements) and ``aexp`` on its turned
  angle ``odo[1]`` (sum of the largest change of a frustum plane normal). An
  entry whose expiries lie ahead is kept without reading anything else, so
  a converged camera's pass is a sequential scan. Safe because every test
  is Lipschitz in the pose: a node's screen-space test ``err kappa / tol -
  (|c - eye| - r)`` moves by at most the eye's displacement, and a frustum
  plane's ``n . (c - eye) + r`` by at most ``|dn| (D + dT) + dT``; each
  expiry leaves half of the margin to each term. Everything else that
  changes a node's answer is an operation on its neighbourhood, and those
  push collapse candidates; an entry whose node changed state is revisited.
  A stationary child evaluated while its sibling was split carries no
  expiry for its parent's test; when the sibling comes back (a candidate
  push) and the parent still needs detail, the child is marked RECHECK.
  Budgets and changed criteria turn expiries off; back-face answers are
  re-checked every pass.
* **Clean lists.** A pass leaves every listed node active and without
  RECHECK (it drops the others' entries and evaluates the RECHECKed), except
  the nodes an operation changed after the pass had checked their entries.
  Each operation notes the listed nodes it changes (split, collapsed away,
  marked RECHECK) in a small set (:func:`caveclod.kernels.nodestate.cs_note`),
  and the next pass reads the node byte only of entries in that set: the
  node bytes are a hash table (see above), where a read per entry was a
  cache miss (a moving camera's updates were 20-30 % slower). A set that
  overflows, a part shown or hidden, or a budgeted pass makes the next pass
  read every entry's byte, as before.

Guards. numba checks no bounds, so the kernels index only with ids that
:func:`caveclod.meshcheck.check_mesh` proved in range when the mesh was
loaded. What that check cannot prove cheaply is guarded here, off the hot
path (a converged pass's scan is unchanged): a vertex lookup that finds no
vertex of the face's surface group; a face walk round a position that finds
no corner there, reaches an inactive face or does not close within as many
steps as there are records; a forced split whose stack or step count passes
what an acyclic hierarchy can need (4n + 8 entries, 8n + 64 steps: every
dependency goes to a higher node id, so a node is pushed at most once while
unsplit; with the strict bound, whose extra dependencies also go to higher
ids, 64n + 64 and 128n + 256, for fans of many corners). Each stops the
pass with DAMAGED and the node it was working on, which the camera raises
as :class:`caveclod.errors.MeshDamagedError`. The functions that gained early returns for them (:func:`split_node`,
:func:`_move_wedge`, :func:`_add_face`) are inlined by numba: LLVM stopped
inlining them, and calls that pass every array as a struct of its own made
a jump's updates about 10 % slower (inlined: 3 to 7 %; inlining
``collapse_node`` too would save 2 % more for 5 s more of compiling).
"""

import math

import numba as nb
import numpy as np

from .facemap import fm_del, fm_get, fm_set
from .nodestate import (ACTIVE, IN_LIST, INACTIVE, QUEUED, RECHECK, SPLIT, STATE_MASK, cs_note, cs_settle,  # noqa: F401
                        cs_suspect, ns_get, ns_room, ns_update)

OK, NEED_RECORDS, NEED_LIST, NEED_QUEUE = 0, 1, 2, 3
NEED_NODES = 5      # the node-state table is full (after DAMAGED, which kept its number)
NEED_STACK = 6      # the forced-split stack is full
# The static mesh broke a rule no built mesh breaks (a vertex lookup that
# misses, a face walk that does not close, a forced split that does not end):
# the file is damaged. See "Guards" in the module doc.
DAMAGED = 4
MIXED, SPLITS_ONLY, COLLAPSES_ONLY = 0, 1, 2   # what a pass may do

# View parameter layout (caveclod.refine.view).
P_EYE, P_PLANES, P_KAPPA, P_TOL, P_CULL, P_BACKFACE, P_PRUNE = 0, 3, 23, 24, 25, 26, 27

NEVER = -np.inf      # an expiry that has passed: evaluate the entry
FOREVER = np.inf     # an answer no camera motion changes


@nb.njit(cache=True, nogil=True, inline="always")
def lookup_vertex(pos_vstart, vertex_sgid, sgid, x):
    """Vertex-buffer index of (surface group id, position): D3Dindex."""
    for i in range(pos_vstart[x], pos_vstart[x + 1]):
        if vertex_sgid[i] == sgid:
            return i
    return -1


@nb.njit(cache=True, nogil=True, inline="always")
def node_position(e, npos, x):
    return x if x < e else npos[x - e]


@nb.njit(cache=True, nogil=True, inline="always")
def corner_at(rec_tri, vpos, r, x):
    """Corner index (0..2) of record ``r`` that sits at position ``x``, or -1."""
    for k in range(3):
        if vpos[rec_tri[r, k]] == x:
            return k
    return -1


@nb.njit(cache=True, nogil=True, inline="always")
def _replace_nbr(rec_nbr, r, old, new):
    for k in range(3):
        if rec_nbr[r, k] == old:
            rec_nbr[r, k] = new
            return


# ---------------------------------------------------------------- the view test


@nb.njit(cache=True, nogil=True, inline="always")
def sphere_planes(cx, cy, cz, r, vp):
    """The sphere (c, r) against the view frustum's five planes, when culling is on:
    (how far it lies wholly outside a plane, 0 if it does not; the smallest
    margin by which it reaches inside them all, FOREVER with culling off)."""
    inside = FOREVER
    outside = 0.0
    if vp[P_CULL] != 0.0:
        for i in range(5):
            b = P_PLANES + 4 * i
            g = vp[b] * cx + vp[b + 1] * cy + vp[b + 2] * cz + vp[b + 3] + r
            if g < 0.0:
                outside = max(outside, -g)
            elif g < inside:
                inside = g
    return outside, inside


@nb.njit(cache=True, nogil=True)
def test_node(j, bound, cone, ring, vp):
    """Whether internal node ``j`` (index into node arrays) needs detail,
    and for how long the answer holds: returns (need, tmargin, rmargin, dist).

    ``bound[j]`` is (centre xyz, radius, error bound), one row so that the
    test touches one cache line. ``ring[j]`` (reach, error), when ``ring``
    has rows (files from before it have none), is the node's ring bound
    (:func:`caveclod.kernels.simplify.ring_bound`): the node needs detail
    too when that error, at the sphere grown by the reach, is above the
    tolerance, which is when a node beside it may need detail by its own
    test. The answer holds while the eye travels less
    than ``tmargin`` and, for ``rmargin``, while ``dT + dA (dist + dT) <
    rmargin`` (module doc). Margins of 0 say the answer must be re-checked.
    """
    cx, cy, cz, r = bound[j, 0], bound[j, 1], bound[j, 2], bound[j, 3]
    dx, dy, dz = cx - vp[P_EYE], cy - vp[P_EYE + 1], cz - vp[P_EYE + 2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    outside, inside = sphere_planes(cx, cy, cz, r, vp)
    if outside > 0.0:
        return False, 0.0, outside, length          # wholly outside a plane
    if vp[P_BACKFACE] != 0.0:
        if length > r and cone[j, 3] < 0.5 * math.pi:
            # Back-facing when every normal of the cone points away from every
            # direction towards the sphere: angle(axis, view) - spreads > 90 deg
            # measured from the eye, i.e. the cone lies within the far half.
            cosphi = (cone[j, 0] * dx + cone[j, 1] * dy + cone[j, 2] * dz) / length
            phi = math.acos(min(1.0, max(-1.0, cosphi)))
            if phi + cone[j, 3] + math.asin(r / length) < 0.5 * math.pi:
                return False, 0.0, 0.0, length
        inside = 0.0                     # back-face answers are re-checked every pass
    if vp[P_TOL] <= 0.0:
        return True, FOREVER, inside, length
    dist = length - r
    s = bound[j, 4] * vp[P_KAPPA] / vp[P_TOL] - dist
    if dist <= 0.0 or s > 0.0:
        return True, max(s, 0.0), inside, length
    # The ring bound, read only when the node's own test says no.
    if ring.shape[0] and ring[j, 1] > 0.0:
        # Each term falls by at most what the eye travels, so their larger does too (the margins).
        s = max(s, ring[j, 1] * vp[P_KAPPA] / vp[P_TOL] - (dist - ring[j, 0]))
        if s > 0.0:
            return True, s, inside, length
    return False, -s, 0.0, length


@nb.njit(cache=True, nogil=True, inline="always")
def need_refine(j, bound, cone, ring, vp):
    """Whether internal node ``j`` needs detail for the view ``vp``."""
    need, _, _, _ = test_node(j, bound, cone, ring, vp)
    return need


@nb.njit(cache=True, nogil=True, inline="always")
def _expiry(odo, tm, rm, dist, need, te, ae):
    """Tighten (te, ae) by one answer's margins (module doc); returns them.

    A need=True answer holds while every condition holds (take both
    margins); a need=False one while either reason does (take the better)."""
    if need:
        t = min(tm, 0.5 * rm)
        a = FOREVER if rm == FOREVER else odo[1] + 0.5 * rm / (dist + 0.5 * rm + 1e-300)
        return min(te, odo[0] + t), min(ae, a)
    if tm >= rm:
        return min(te, odo[0] + tm), ae
    return min(te, odo[0] + 0.5 * rm), min(ae, odo[1] + 0.5 * rm / (dist + 0.5 * rm + 1e-300))


@nb.njit(cache=True, nogil=True, inline="always")
def _down32(x):
    """``x`` as float32, rounded towards -inf (an expiry never grows)."""
    y = np.float32(x)
    if y > x:
        y = np.nextafter(y, np.float32(-np.inf))
    return y


# ---------------------------------------------------------------- records


@nb.njit(cache=True, nogil=True, inline="always")
def _mark(r, dirty):
    """Record ``r`` (a slot) was written: set its bit in the ``dirty`` bitset."""
    dirty[r >> 6] |= np.uint64(1) << np.uint64(r & 63)


@nb.njit(cache=True, nogil=True, inline="always")
def _move_wedge(fn0, fn2, old, new, fl, fr, fsgid, pos_vstart, vertex_sgid, vpos, face_map, rec_tri, rec_nbr,
                dirty):
    """Move the floating child's wedge of faces from position ``old`` to ``new``.

    The wedge runs from ``fn0`` (fl_u) round ``old`` to ``fn2`` (fr_u); if
    fl_u is absent it is walked back from fr_u to the border instead. A split
    moves it from s to u, a collapse back; the walk never enters fl or fr.
    Returns False when the mesh is damaged (module doc, "Guards").
    """
    steps = rec_tri.shape[0] + 1           # a walk round one position visits each active face once at most
    if fn0 >= 0:
        f = fn0
        while True:
            r = fm_get(face_map, f)
            k = corner_at(rec_tri, vpos, r, old) if r >= 0 else -1
            v = lookup_vertex(pos_vstart, vertex_sgid, fsgid[f], new)
            steps -= 1
            if k < 0 or v < 0 or steps < 0:
                return False
            rec_tri[r, k] = v
            _mark(r, dirty)
            if f == fn2:
                break
            f = rec_nbr[r, k]                # across the outgoing edge at the corner
            if f < 0 or f == fr:
                break
    elif fn2 >= 0:
        f = fn2
        while True:
            r = fm_get(face_map, f)
            k = corner_at(rec_tri, vpos, r, old) if r >= 0 else -1
            v = lookup_vertex(pos_vstart, vertex_sgid, fsgid[f], new)
            steps -= 1
            if k < 0 or v < 0 or steps < 0:
                return False
            rec_tri[r, k] = v
            _mark(r, dirty)
            f = rec_nbr[r, (k + 2) % 3]      # across the incoming edge
            if f < 0 or f == fl:
                break
    return True


@nb.njit(cache=True, nogil=True, inline="always")
def _add_face(f, a, b, c, n0, n1, n2, rot, mat, fsgid, pos_vstart, vertex_sgid, face_map, off, cnt,
              rec_tri, rec_nbr, rec_face, dirty):
    """Append face ``f`` on positions (a, b, c) with neighbours (n0, n1, n2)
    across edges a->b, b->c, c->a, its corners starting at corner ``rot``
    (the source face's order). False (nothing added) when a corner has no
    vertex of the face's surface group: the mesh is damaged."""
    g = fsgid[f]
    va = lookup_vertex(pos_vstart, vertex_sgid, g, a)
    vb = lookup_vertex(pos_vstart, vertex_sgid, g, b)
    vc = lookup_vertex(pos_vstart, vertex_sgid, g, c)
    if va < 0 or vb < 0 or vc < 0:
        return False
    s = mat[f]
    r = off[s] + cnt[s]
    cnt[s] += 1
    fm_set(face_map, f, r)
    rec_face[r] = f
    k0, k1, k2 = rot, (rot + 1) % 3, (rot + 2) % 3
    rec_tri[r, k0], rec_tri[r, k1], rec_tri[r, k2] = va, vb, vc
    rec_nbr[r, k0], rec_nbr[r, k1], rec_nbr[r, k2] = n0, n1, n2
    _mark(r, dirty)
    return True


@nb.njit(cache=True, nogil=True)
def move_records(cnt, old_off, old_tri, old_nbr, old_face, old_dirty, new_off, new_tri, new_nbr, new_face,
                 new_dirty, face_map):
    """Copy each material's ``cnt[s]`` records from ``old_off[s]`` to ``new_off[s]`` of a
    re-laid-out pool, with their written-slot bits; every moved face points at its new record.

    One pass in numba: the same copy as numpy fancy indexing per material took about
    2.5 ms for 16k records, and a camera re-lays out its pool whenever a material grows.
    """
    one = np.uint64(1)
    for s in range(cnt.shape[0]):
        a, b = old_off[s], new_off[s]
        for i in range(cnt[s]):
            r, q = a + i, b + i
            for k in range(3):
                new_tri[q, k] = old_tri[r, k]
                new_nbr[q, k] = old_nbr[r, k]
            f = old_face[r]
            new_face[q] = f
            fm_set(face_map, f, q)
            if (old_dirty[r >> 6] >> np.uint64(r & 63)) & one:
                new_dirty[q >> 6] |= one << np.uint64(q & 63)


@nb.njit(cache=True, nogil=True)
def _remove_face(f, mat, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty):
    """Remove face ``f``; the material's last face fills its slot."""
    s = mat[f]
    r = fm_get(face_map, f)
    last = off[s] + cnt[s] - 1
    if r != last:
        for k in range(3):
            rec_tri[r, k] = rec_tri[last, k]
            rec_nbr[r, k] = rec_nbr[last, k]
        rec_face[r] = rec_face[last]
        fm_set(face_map, rec_face[r], r)
        _mark(r, dirty)
    fm_del(face_map, f)
    cnt[s] -= 1


# ---------------------------------------------------------------- split and collapse


@nb.njit(cache=True, nogil=True, inline="always")
def split_node(x, e, links, npos, rotation, mat, fsgid, pos_vstart, vertex_sgid, vpos, state, face_map, off, cnt,
               rec_tri, rec_nbr, rec_face, dirty):
    """Split active node ``x`` whose required faces are all active.

    The caller has checked legality and capacity (two records). Returns
    False when the mesh turned out damaged (module doc, "Guards"); the
    camera's state is then half-changed and must not be used again.
    """
    j = x - e
    t, u = links[j, 0], links[j, 1]
    fl, fr = links[j, 2], links[j, 3]
    fn0, fn1, fn2, fn3 = links[j, 4], links[j, 5], links[j, 6], links[j, 7]
    px = npos[j]
    pu = node_position(e, npos, u)
    # 1. The floating child's wedge: faces from fl_u round to fr_u move to u.
    if not _move_wedge(fn0, fn2, px, pu, fl, fr, fsgid, pos_vstart, vertex_sgid, vpos, face_map, rec_tri, rec_nbr,
                       dirty):
        return False
    # 2. The two new faces, linked into their neighbours. (The required faces
    # fn* are active: the caller checked; corner_at's -1 says the wiring is not
    # that of a built mesh.)
    if fl >= 0:
        if fn0 >= 0:
            r0 = fm_get(face_map, fn0)
            k = corner_at(rec_tri, vpos, r0, pu)
            if k < 0:
                return False
            vl = vpos[rec_tri[r0, (k + 2) % 3]]
        else:
            r1 = fm_get(face_map, fn1)
            k = corner_at(rec_tri, vpos, r1, px) if fn1 >= 0 else -1
            if k < 0:
                return False
            vl = vpos[rec_tri[r1, (k + 1) % 3]]
        if not _add_face(fl, px, pu, vl, fr, fn0, fn1, rotation[fl], mat, fsgid, pos_vstart, vertex_sgid, face_map,
                         off, cnt, rec_tri, rec_nbr, rec_face, dirty):
            return False
        if fn0 >= 0:
            r0 = fm_get(face_map, fn0)
            k = corner_at(rec_tri, vpos, r0, vl)
            if k < 0:
                return False
            rec_nbr[r0, k] = fl      # edge vl -> u
        if fn1 >= 0:
            r1 = fm_get(face_map, fn1)
            k = corner_at(rec_tri, vpos, r1, px)
            if k < 0:
                return False
            rec_nbr[r1, k] = fl      # edge t -> vl
    if fr >= 0:
        if fn2 >= 0:
            r2 = fm_get(face_map, fn2)
            k = corner_at(rec_tri, vpos, r2, pu)
            if k < 0:
                return False
            vr = vpos[rec_tri[r2, (k + 1) % 3]]
        else:
            r3 = fm_get(face_map, fn3)
            k = corner_at(rec_tri, vpos, r3, px) if fn3 >= 0 else -1
            if k < 0:
                return False
            vr = vpos[rec_tri[r3, (k + 2) % 3]]
        if not _add_face(fr, pu, px, vr, fl, fn3, fn2, rotation[fr], mat, fsgid, pos_vstart, vertex_sgid, face_map,
                         off, cnt, rec_tri, rec_nbr, rec_face, dirty):
            return False
        if fn2 >= 0:
            r2 = fm_get(face_map, fn2)
            k = corner_at(rec_tri, vpos, r2, pu)
            if k < 0:
                return False
            rec_nbr[r2, k] = fr      # edge u -> vr
        if fn3 >= 0:
            r3 = fm_get(face_map, fn3)
            k = corner_at(rec_tri, vpos, r3, vr)
            if k < 0:
                return False
            rec_nbr[r3, k] = fr      # edge vr -> t
    ns_update(state, x, STATE_MASK, SPLIT)
    ns_update(state, t, STATE_MASK, ACTIVE)
    ns_update(state, u, STATE_MASK, ACTIVE)
    return True


@nb.njit(cache=True, nogil=True)
def collapse_legal(x, e, links, rotation, state, face_map, rec_nbr):
    """Hoppe's ecol precondition for undoing the split of ``x``: both
    children active, and fl's neighbours across u->vl and vl->t (fr's across
    t->vr and vr->u) are the faces the split required."""
    j = x - e
    if (ns_get(state, links[j, 0]) & STATE_MASK) != ACTIVE or (ns_get(state, links[j, 1]) & STATE_MASK) != ACTIVE:
        return False
    fl, fr = links[j, 2], links[j, 3]
    if fl >= 0:
        r, k = fm_get(face_map, fl), rotation[fl]
        if rec_nbr[r, (k + 1) % 3] != links[j, 4] or rec_nbr[r, (k + 2) % 3] != links[j, 5]:
            return False
    if fr >= 0:
        r, k = fm_get(face_map, fr), rotation[fr]
        if rec_nbr[r, (k + 1) % 3] != links[j, 7] or rec_nbr[r, (k + 2) % 3] != links[j, 6]:
            return False
    return True


@nb.njit(cache=True, nogil=True)
def collapse_node(x, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid, vpos, state, face_map, off, cnt,
                  rec_tri, rec_nbr, rec_face, dirty):
    """Undo the split of ``x`` (the caller checked :func:`collapse_legal`).

    Returns False when the mesh turned out damaged (module doc, "Guards").
    """
    j = x - e
    t, u = links[j, 0], links[j, 1]
    fl, fr = links[j, 2], links[j, 3]
    fn0, fn1, fn2, fn3 = links[j, 4], links[j, 5], links[j, 6], links[j, 7]
    px = npos[j]
    pu = node_position(e, npos, u)
    if not _move_wedge(fn0, fn2, pu, px, fl, fr, fsgid, pos_vstart, vertex_sgid, vpos, face_map, rec_tri, rec_nbr,
                       dirty):
        return False
    # fl's and fr's recorded neighbours are the required faces (collapse_legal),
    # active in a built mesh: an inactive one (record -1) is damage.
    if fl >= 0:
        if (fn0 >= 0 and fm_get(face_map, fn0) < 0) or (fn1 >= 0 and fm_get(face_map, fn1) < 0):
            return False
        if fn0 >= 0:
            _replace_nbr(rec_nbr, fm_get(face_map, fn0), fl, fn1)
        if fn1 >= 0:
            _replace_nbr(rec_nbr, fm_get(face_map, fn1), fl, fn0)
        _remove_face(fl, mat, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty)
    if fr >= 0:
        if (fn2 >= 0 and fm_get(face_map, fn2) < 0) or (fn3 >= 0 and fm_get(face_map, fn3) < 0):
            return False
        if fn2 >= 0:
            _replace_nbr(rec_nbr, fm_get(face_map, fn2), fr, fn3)
        if fn3 >= 0:
            _replace_nbr(rec_nbr, fm_get(face_map, fn3), fr, fn2)
        _remove_face(fr, mat, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty)
    ns_update(state, x, STATE_MASK, ACTIVE)
    ns_update(state, t, STATE_MASK, 0)
    ns_update(state, u, STATE_MASK, 0)
    return True


@nb.njit(cache=True, nogil=True, inline="always")
def _room_for_split(j, links, mat, cnt, cap):
    """-1 if both new faces fit, else the material that needs room."""
    for side in range(2):
        f = links[j, 2 + side]
        if f >= 0:
            s = mat[f]
            need = 1
            if side == 1 and links[j, 2] >= 0 and mat[links[j, 2]] == s:
                need = 2
            if cnt[s] + need > cap[s]:
                return s
    return -1


# ---------------------------------------------------------------- the strict bound
#
# A camera opened with the strict bound never shows a node beside a position
# that had been collapsed away before the node was made: every position beside
# an active node was in the mesh when the node's collapse measured its error.
# Node ids are in the order the build made them (a node's dependencies and
# parent come later), so "position q was gone before node a" reads
# ``parent[pos_top[q]] < a``: ``pos_top[q]`` is the last node at q (its
# stationary chain's top), whose parent's collapse took q away. A split of y
# brings its floating child's position back; every active node newer than y
# beside it must be split first (pushed on the forced-split stack, like
# Hoppe's dependencies: to newer nodes, so the stack ends). A collapse of x is
# legal only if no position beside x's two was gone before x, and after it the
# parents of x's new neighbours are collapse candidates (a position that
# blocked their collapse may just have gone). docs/error-bounds.md, "The
# strict bound".


@nb.njit(cache=True, nogil=True, inline="always")
def _gone_before(parent, pos_top, q, x):
    """Whether position ``q`` had been collapsed away before node ``x`` was made."""
    g = parent[pos_top[q]]
    return g >= 0 and g < x


@nb.njit(cache=True, nogil=True, inline="always")
def _active_from(c, q, parent, pos_top, state):
    """The active node at position ``q`` at or above node ``c`` of q's chain, or -1."""
    top = pos_top[q]
    while c >= 0:
        if (ns_get(state, c) & STATE_MASK) == ACTIVE:
            return c
        if c == top:
            return -1
        c = parent[c]
    return -1


@nb.njit(cache=True, nogil=True, inline="always")
def _lowest_newer(q, x, e, links, pos_top):
    """The lowest node at position ``q`` newer than ``x``, or -1 (all older).

    Walks down q's chain of stationary children from its last node: the
    nodes newer than a node being split are few, where the walk up from the
    leaf passed every older one, each a lookup in the node-state table."""
    c = pos_top[q]
    if c <= x:
        return -1
    while c >= e:
        t = links[c - e, 0]
        if t <= x:
            break
        c = t
    return c


@nb.njit(cache=True, nogil=True, inline="always")
def _note_blocker(q, x, e, links, parent, pos_top, state, out, n):
    """Add the active node at ``q`` to ``out[:n]`` if it is newer than ``x`` (and not there yet).

    Along q's chain the nodes below the active one are inactive and those
    above it split: it is newer than x unless the lowest node newer than x
    is split."""
    c = _lowest_newer(q, x, e, links, pos_top)
    if c < 0:
        return n                           # every node at q is older than x
    s = ns_get(state, c) & STATE_MASK
    if s == SPLIT:
        return n
    a = c if s == ACTIVE else _active_from(c, q, parent, pos_top, state)
    if a < 0:
        return n
    for i in range(n):
        if out[i] == a:
            return n
    if n >= out.shape[0]:
        return -1
    out[n] = a
    return n + 1


@nb.njit(cache=True, nogil=True)
def split_blockers(x, e, links, npos, parent, pos_top, state, vpos, face_map, rec_tri, rec_nbr, out):
    """The active nodes newer than ``x`` that its split would put beside its
    floating child's position (gone before they were made), for the strict
    bound. In a fixed order: the corners of the wedge that moves to u, as
    :func:`_move_wedge` walks it, then vl and vr.

    Writes them to ``out`` and returns how many; -1 when ``out`` is too small,
    -2 when a walk does not close (damaged: module doc, "Guards").
    """
    j = x - e
    fl, fr = links[j, 2], links[j, 3]
    fn0, fn1, fn2, fn3 = links[j, 4], links[j, 5], links[j, 6], links[j, 7]
    px = npos[j]
    n = 0
    steps = rec_tri.shape[0] + 1
    # From fl_u forward round px to fr_u, or, without fl_u, from fr_u backward to the border.
    forward = fn0 >= 0
    f = fn0 if forward else fn2
    while f >= 0:
        r = fm_get(face_map, f)
        k = corner_at(rec_tri, vpos, r, px) if r >= 0 else -1
        steps -= 1
        if k < 0 or steps < 0:
            return -2
        for d in range(1, 3):
            n = _note_blocker(vpos[rec_tri[r, (k + d) % 3]], x, e, links, parent, pos_top, state, out, n)
            if n < 0:
                return -1
        if forward and f == fn2:
            break
        f = rec_nbr[r, k] if forward else rec_nbr[r, (k + 2) % 3]
        if f == (fr if forward else fl):
            break
    # fl's and fr's third corners border u too (from t's side when u's wedge is empty).
    for side in range(2):
        if links[j, 2 + side] < 0:
            continue
        g, h = (fn0, fn1) if side == 0 else (fn2, fn3)
        if g >= 0:
            r = fm_get(face_map, g)
            k = corner_at(rec_tri, vpos, r, px)
            d = 2 if side == 0 else 1
        elif h >= 0:
            r = fm_get(face_map, h)
            k = corner_at(rec_tri, vpos, r, px)
            d = 1 if side == 0 else 2
        else:
            continue
        if k < 0:
            return -2
        n = _note_blocker(vpos[rec_tri[r, (k + d) % 3]], x, e, links, parent, pos_top, state, out, n)
        if n < 0:
            return -1
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def _fan_start(f0, p, face_map, rec_tri, vpos):
    """Record and corner of face ``f0`` at position ``p`` (-1, -1 if it has none)."""
    r = fm_get(face_map, f0)
    if r < 0:
        return -1, -1
    return r, corner_at(rec_tri, vpos, r, p)


@nb.njit(cache=True, nogil=True, inline="always")
def _fan_next(r, k, way, f0, p, face_map, rec_tri, rec_nbr, vpos):
    """One step round position ``p`` from record ``r`` (corner ``k``): forward (``way`` 0) or
    backward. Returns (the next face, -1 at an open end; its record and its corner at ``p``, -1
    where it has none: damage), records not looked up at an end or back at ``f0``."""
    f = rec_nbr[r, k] if way == 0 else rec_nbr[r, (k + 2) % 3]
    if f < 0 or f == f0:
        return f, -1, -1
    r = fm_get(face_map, f)
    return f, r, (corner_at(rec_tri, vpos, r, p) if r >= 0 else -1)


@nb.njit(cache=True, nogil=True)
def strict_collapse_faces(x, e, links, npos, parent, pos_top, vpos, face_map, rec_tri, rec_nbr):
    """Whether undoing the split of ``x`` keeps the strict bound: no position
    beside x's two (t's and u's) was gone before x was made.

    Returns the faces walked round the two positions (>= 0: legal; the
    candidates the collapse pushes are at most twice as many), -1 when it
    would put x beside such a position, -2 when a walk does not close
    (damaged).
    """
    j = x - e
    fl, fr = links[j, 2], links[j, 3]
    px = npos[j]
    pu = node_position(e, npos, links[j, 1])
    f0 = fl if fl >= 0 else fr
    if f0 < 0:
        return 0
    total = 0
    steps = rec_tri.shape[0] + 1
    for p in (px, pu):
        r0, k0 = _fan_start(f0, p, face_map, rec_tri, vpos)
        if k0 < 0:
            return -2
        for way in range(2):               # forward round p; backward from f0 if the fan is open
            r, k = r0, k0
            f = f0
            while True:
                if way == 0 or f != f0:
                    total += 1
                    if f != fl and f != fr:
                        for d in range(1, 3):
                            q = vpos[rec_tri[r, (k + d) % 3]]
                            if q != px and q != pu and _gone_before(parent, pos_top, q, x):
                                return -1
                f, r, k = _fan_next(r, k, way, f0, p, face_map, rec_tri, rec_nbr, vpos)
                if f < 0 or f == f0:
                    break
                steps -= 1
                if k < 0 or steps < 0:
                    return -2
            if f == f0:
                break                      # a closed fan: walked whole
    return total


@nb.njit(cache=True, nogil=True)
def _push_beside(x, e, parent, links, npos, pos_top, state, vpos, face_map, rec_tri, rec_nbr, queue, q):
    """After the collapse of ``x`` under the strict bound: push the parents of
    the active nodes beside x's position, whose collapse a position just gone
    may have blocked: those newer than x (u's position was gone before x
    only for them). Walks round x from the first of fl_t, fl_u, fr_t, fr_u
    present (forward, then backward if the fan is open). The caller made room
    for twice the faces :func:`strict_collapse_faces` counted."""
    j = x - e
    px = npos[j]
    f0 = -1
    for c in (5, 4, 7, 6):
        if links[j, c] >= 0:
            f0 = links[j, c]
            break
    if f0 < 0:
        return q
    r0, k0 = _fan_start(f0, px, face_map, rec_tri, vpos)
    if k0 < 0:
        return q
    steps = rec_tri.shape[0] + 1
    for way in range(2):
        r, k = r0, k0
        f = f0
        while True:
            if way == 0 or f != f0:
                for d in range(1, 3):
                    c = vpos[rec_tri[r, (k + d) % 3]]
                    # Parents grow up a position's chain, the last node's the largest (a root's:
                    # none). The nodes whose parent is newer than x: the lowest newer node's
                    # stationary child and up, or the last node alone.
                    top = pos_top[c]
                    if top <= x and parent[top] <= x:
                        continue
                    lo = top
                    if top > x:
                        lo = links[_lowest_newer(c, x, e, links, pos_top) - e, 0]
                    s = ns_get(state, lo) & STATE_MASK
                    if s == SPLIT:
                        continue               # the active node is below: its parent is older
                    b = lo if s == ACTIVE else _active_from(lo, c, parent, pos_top, state)
                    if b >= 0 and parent[b] > x:
                        q = _push(parent[b], e, state, queue, q)
            f, r, k = _fan_next(r, k, way, f0, px, face_map, rec_tri, rec_nbr, vpos)
            if f < 0 or f == f0:
                break
            steps -= 1
            if k < 0 or steps < 0:
                return q
        if f == f0:
            break
    return q


# ---------------------------------------------------------------- the active list


@nb.njit(cache=True, nogil=True)
def sort_active(active, texp, aexp, n):
    """Sort ``active[:n]`` (with its expiries) by node id: a sorted run (last
    pass's survivors, written in order) followed by a short tail of nodes
    appended during that pass.

    Sorting the tail and merging is linear; a plain quicksort degrades on
    this nearly sorted input (4 ms instead of 0.1 ms for 11k nodes).
    """
    k = 1
    while k < n and active[k - 1] <= active[k]:
        k += 1
    if k >= n:
        return
    order = np.argsort(active[k:n]) + k
    tail, tail_t, tail_a = active[order], texp[order], aexp[order]
    head, head_t, head_a = active[:k].copy(), texp[:k].copy(), aexp[:k].copy()
    i = j = 0
    for o in range(n):
        if j >= tail.shape[0] or (i < k and head[i] <= tail[j]):
            active[o], texp[o], aexp[o] = head[i], head_t[i], head_a[i]
            i += 1
        else:
            active[o], texp[o], aexp[o] = tail[j], tail_t[j], tail_a[j]
            j += 1


@nb.njit(cache=True, nogil=True, inline="always")
def _append(x, active, texp, aexp, n, state, changed):
    """Give active node ``x`` an entry at the back of the list unless it has one."""
    st = ns_get(state, x)
    if (st & IN_LIST) == 0:
        ns_update(state, x, 0, IN_LIST)
        if st & RECHECK:
            # Marked while it had no entry (then split or collapsed away):
            # the entry's check must see the mark (module doc, "Clean lists").
            cs_note(changed, state, x)
        active[n] = x
        texp[n] = NEVER
        aexp[n] = NEVER
        n += 1
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def _push(c, e, state, queue, q):
    """Push split node ``c`` as a collapse candidate (once)."""
    if c >= e and (ns_get(state, c) & (STATE_MASK | QUEUED)) == SPLIT:
        ns_update(state, c, 0, QUEUED)
        queue[q] = c
        q += 1
    return q


@nb.njit(cache=True, nogil=True, inline="always")
def _push_after_collapse(x, e, parent, links, face_creator, state, queue, q):
    """The candidates a collapse of ``x`` may have made legal (module doc)."""
    if parent[x] >= 0:
        q = _push(parent[x], e, state, queue, q)
    for k in range(4):
        f = links[x - e, 4 + k]
        if f >= 0 and face_creator[f] >= 0:
            q = _push(face_creator[f], e, state, queue, q)
    return q


# ---------------------------------------------------------------- one pass


@nb.njit(cache=True, nogil=True)
def _skip_run(active, texp, aexp, state, changed, odo, i, w, n, expire, clean):
    """Keep entries from ``i`` on whose expiries lie ahead, drop those whose
    node is no longer active, and stop at the first entry to evaluate.

    Returns the new (read, write) positions and the byte of the node to
    evaluate (as read, or ACTIVE for a trusted entry). A tight loop of its own: most
    entries of a moving camera end here, and inside the pass's big loop the
    same work took three times as long. ``clean``: every entry's node is
    known to be active without RECHECK unless it is in ``changed`` (module
    doc, "Clean lists"), so the others' node bytes are not read.
    """
    t, a = odo[0], odo[1]
    trust_all = clean and changed[changed.shape[0] - 1, 0] == 0     # nothing noted: read no byte
    while i < n:
        x = active[i]
        st = ACTIVE
        if not trust_all and (not clean or cs_suspect(changed, x)):
            st = ns_get(state, x)
            if (st & STATE_MASK) != ACTIVE:
                ns_update(state, x, IN_LIST, 0)     # split or collapsed away since
                i += 1
                continue
        te, ae = texp[i], aexp[i]
        if not expire or (st & RECHECK) != 0 or t >= te or a >= ae:
            return i, w, st
        active[w], texp[w], aexp[w] = x, te, ae
        i += 1
        w += 1
    return i, w, ACTIVE



@nb.njit(cache=True, nogil=True)
def adapt(e, parent, links, npos, bound, cone, ring, face_creator, rotation, mat, fsgid, pos_vstart, vertex_sgid,
          vpos, pos_top, state, face_map, off, cnt, cap, rec_tri, rec_nbr, rec_face, dirty,
          active, texp, aexp, n_active, queue, fstack, changed, vp, odo, max_ops, max_faces, counts, resume, mode,
          expire):
    """One pass of incremental selective refinement over the active nodes.

    Splits (forcing the splits a split needs) where the view needs detail and
    collapses sibling pairs whose parent no longer needs it, and the
    candidates each collapse pushes (module doc), while fewer than
    ``max_ops`` operations were made and fewer than ``max_faces`` faces are
    active. ``counts`` (4,) int64 accumulates splits and collapses, its
    third entry is set when a budget stopped the pass short, and its fourth
    counts the entries evaluated (not skipped by their expiries). ``mode`` MIXED
    does both in one pass (Hoppe); SPLITS_ONLY / COLLAPSES_ONLY let a
    budgeted update refine first and coarsen with what budget is left.
    ``expire`` False evaluates every entry and records no expiries (budgets,
    tests of the expiries themselves). ``odo`` (2,) float64 is the camera's
    travelled distance and turned angle. ``pos_top`` (e,) int32: the strict
    bound's last node at each position (below, "the strict bound"), or
    empty for cameras without it.

    Returns (status, material): OK, DAMAGED with the node being split or
    collapsed (the mesh is damaged: module doc, "Guards"; the camera is not
    to be used again), or NEED_RECORDS for that material /
    NEED_LIST / NEED_QUEUE (``queue``, the collapse candidates) / NEED_NODES
    (``state``, before a split) / NEED_STACK (``fstack``, the forced-split
    stack; the material is the entries it needs, or -1 for twice as many):
    grow the arrays and call again, and the call *continues the
    same pass* where this one stopped: ``resume`` (6,) int64 holds the read
    and write positions, a flag, the candidates left in ``queue``, whether
    the list is clean (module doc; the camera clears it when anything else
    changes node states) and the entries of a forced split left in
    ``fstack``, so decisions never depend on how much room the arrays
    happened to have. ``changed`` is the set of
    listed nodes changed since their check
    (:func:`caveclod.kernels.nodestate.cs_note`). (The node being force-split when room
    ran out is visited again, and its forced split goes on from the stack
    it left: started afresh, the strict bound's dependencies, which follow
    the splits already made, came in another order, and under an operation
    budget that made other decisions.)
    """
    n = n_active[0]
    n_faces = 0
    for s in range(cnt.shape[0]):
        n_faces += cnt[s]
    status, need_mat = OK, -1
    q = 0
    clean = expire and resume[4] != 0
    if resume[2]:
        i, w, q = resume[0], resume[1], resume[3]
        resume[2] = 0
        # Candidates left when room ran out go first, as they would have.
        q, n, n_faces, status = _collapse_candidates(
            e, parent, links, npos, bound, cone, ring, face_creator, rotation, mat, fsgid, pos_vstart,
            vertex_sgid, vpos, pos_top, state, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty, active, texp,
            aexp, n, vp, max_ops, counts, queue, changed, q, n_faces)
        if status == DAMAGED:
            need_mat = queue[q]                  # the candidate it was collapsing
    else:
        # Visit nodes in id order: their static rows are then read front to
        # back instead of at random, which halves the cost of a pass.
        sort_active(active, texp, aexp, n)
        i = 0
        w = 0
    stack = fstack
    n_nodes = parent.shape[0]
    max_stack, max_steps = 4 * n_nodes + 8, 8 * n_nodes + 64     # what an acyclic hierarchy can need
    strict = pos_top.shape[0] > 0
    blockers = np.empty(64 if strict else 0, np.int64)
    if strict:
        # Each node also pushes the newer nodes its split would give a gone
        # neighbour, as many as its fan has corners: room for any fan.
        max_stack, max_steps = 64 * n_nodes + 64, 128 * n_nodes + 256
    while status == OK:
        i, w, st = _skip_run(active, texp, aexp, state, changed, odo, i, w, n, expire, clean)
        if i >= n:
            break
        x = active[i]
        i += 1
        if st & RECHECK:
            ns_update(state, x, RECHECK, 0)
        counts[3] += 1
        te, ae = FOREVER, FOREVER
        ops = counts[0] + counts[1]
        if ops >= max_ops:
            counts[2] = 1
            active[w], texp[w], aexp[w] = x, NEVER, NEVER
            w += 1
            continue
        if x >= e and mode != COLLAPSES_ONLY:
            need, tm, rm, dist = test_node(x - e, bound, cone, ring, vp)
            if need:
                # Force the split of x: Hoppe's stack of unmet preconditions (or
                # the stack an interrupted call left, which is x's).
                if resume[5] > 0:
                    sp = resume[5]
                    resume[5] = 0
                else:
                    stack[0] = x
                    sp = 1
                steps = 0
                while sp > 0:
                    y = stack[sp - 1]
                    steps += 1
                    if steps > max_steps:
                        status, need_mat = DAMAGED, y
                        break
                    sy = ns_get(state, y) & STATE_MASK
                    if sy == SPLIT or y < e:
                        sp -= 1
                        continue
                    if sp + 5 > stack.shape[0]:
                        if stack.shape[0] > max_stack:
                            status, need_mat = DAMAGED, y
                        else:
                            status = NEED_STACK
                        break
                    if sy == INACTIVE:
                        stack[sp] = parent[y]
                        sp += 1
                        continue
                    jy = y - e
                    missing = False
                    for k in range(4):
                        f = links[jy, 4 + k]
                        if f >= 0 and fm_get(face_map, f) < 0:
                            stack[sp] = face_creator[f]
                            sp += 1
                            missing = True
                    if missing:
                        continue
                    if strict:
                        nb_ = split_blockers(y, e, links, npos, parent, pos_top, state, vpos, face_map, rec_tri,
                                             rec_nbr, blockers)
                        while nb_ == -1:
                            blockers = np.empty(2 * blockers.shape[0], np.int64)
                            nb_ = split_blockers(y, e, links, npos, parent, pos_top, state, vpos, face_map, rec_tri,
                                                 rec_nbr, blockers)
                        if nb_ == -2:
                            status, need_mat = DAMAGED, y
                            break
                        if nb_ > 0:
                            if sp + nb_ + 5 > stack.shape[0]:
                                if stack.shape[0] > max_stack:
                                    status, need_mat = DAMAGED, y
                                else:
                                    status, need_mat = NEED_STACK, sp + nb_ + 5
                                break
                            for b in range(nb_):
                                stack[sp] = blockers[b]
                                sp += 1
                            continue
                    if counts[0] + counts[1] >= max_ops or n_faces + 2 > max_faces:
                        counts[2] = 1
                        break
                    s_need = _room_for_split(jy, links, mat, cnt, cap)
                    if s_need >= 0:
                        status, need_mat = NEED_RECORDS, s_need
                        break
                    if n + 2 > active.shape[0]:
                        status = NEED_LIST
                        break
                    if not ns_room(state, 2):
                        status = NEED_NODES
                        break
                    if not split_node(y, e, links, npos, rotation, mat, fsgid, pos_vstart, vertex_sgid, vpos,
                                      state, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty):
                        status, need_mat = DAMAGED, y
                        break
                    cs_note(changed, state, y)       # listed y is split now
                    counts[0] += 1
                    n_faces += (links[jy, 2] >= 0) + (links[jy, 3] >= 0)
                    n = _append(links[jy, 0], active, texp, aexp, n, state, changed)
                    n = _append(links[jy, 1], active, texp, aexp, n, state, changed)
                    sp -= 1
                if status != OK:
                    i -= 1                       # x is visited again on resume
                    if status != DAMAGED:
                        resume[5] = sp           # and its forced split goes on from here
                    break
                if (ns_get(state, x) & STATE_MASK) == ACTIVE:      # a budget stopped it
                    active[w], texp[w], aexp[w] = x, NEVER, NEVER
                    w += 1
                else:
                    ns_update(state, x, IN_LIST, 0)
                continue
            te, ae = _expiry(odo, tm, rm, dist, need, te, ae)
        p = parent[x]
        # The stationary child speaks for the pair, and only when its sibling
        # is active too: a collapse needs both, and this halves the
        # (cache-missing) parent tests. The sibling's activation, or a change
        # in the collapse's legality, pushes the parent as a candidate.
        if mode != SPLITS_ONLY and p >= 0 and links[p - e, 0] == x and \
                (ns_get(state, links[p - e, 1]) & STATE_MASK) == ACTIVE:
            need, tm, rm, dist = test_node(p - e, bound, cone, ring, vp)
            if not need:
                walked = 0 if collapse_legal(p, e, links, rotation, state, face_map, rec_nbr) else -1
                if walked == 0 and strict:
                    walked = strict_collapse_faces(p, e, links, npos, parent, pos_top, vpos, face_map, rec_tri,
                                                   rec_nbr)
                    if walked == -2:
                        status, need_mat = DAMAGED, p
                        break
                if walked >= 0:
                    if (ns_get(state, p) & IN_LIST) == 0 and n + 1 > active.shape[0]:
                        i -= 1
                        status = NEED_LIST
                        break
                    if q + 5 + 2 * walked > queue.shape[0]:
                        i -= 1
                        status = NEED_QUEUE
                        break
                    if not collapse_node(p, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid, vpos, state,
                                         face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty):
                        status, need_mat = DAMAGED, p
                        break
                    counts[1] += 1
                    n_faces -= (links[p - e, 2] >= 0) + (links[p - e, 3] >= 0)
                    n = _append(p, active, texp, aexp, n, state, changed)
                    ns_update(state, x, IN_LIST, 0)
                    cs_note(changed, state, links[p - e, 1])     # x's entry is dropped; its sibling's not
                    q = _push_after_collapse(p, e, parent, links, face_creator, state, queue, q)
                    if strict:
                        q = _push_beside(p, e, parent, links, npos, pos_top, state, vpos, face_map, rec_tri, rec_nbr,
                                         queue, q)
                    q, n, n_faces, status = _collapse_candidates(
                        e, parent, links, npos, bound, cone, ring, face_creator, rotation, mat, fsgid, pos_vstart,
                        vertex_sgid, vpos, pos_top, state, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty,
                        active, texp, aexp, n, vp, max_ops, counts, queue, changed, q, n_faces)
                    if status == DAMAGED:
                        need_mat = queue[q]      # the candidate it was collapsing
                    if status != OK:
                        break                    # the queue keeps what is left for the resumed pass
                    continue
                # Illegal now: whatever makes it legal pushes p as a candidate.
            else:
                te, ae = _expiry(odo, tm, rm, dist, need, te, ae)
        if not expire:
            te, ae = NEVER, NEVER
        active[w], texp[w], aexp[w] = x, _down32(te), _down32(ae)
        w += 1
    if status == DAMAGED:
        # Nothing to resume: the camera is not to be used again.
        n_active[0] = n
        return status, need_mat
    if status != OK:
        # Stopped for room: remember where, keep the list as it is.
        resume[0], resume[1], resume[2], resume[3] = i, w, 1, q      # resume[4], clean, holds
        n_active[0] = n
        return status, need_mat
    n_active[0] = w
    # Every entry was checked or trusted; what changed after its check is in
    # ``changed``: the next pass may trust the rest (unless the set overflowed).
    settled = cs_settle(changed, state)
    resume[4] = 1 if expire and settled else 0
    return status, need_mat


@nb.njit(cache=True, nogil=True)
def _collapse_candidates(e, parent, links, npos, bound, cone, ring, face_creator, rotation, mat, fsgid,
                         pos_vstart, vertex_sgid, vpos, pos_top, state, face_map, off, cnt, rec_tri, rec_nbr, rec_face,
                         dirty, active, texp, aexp, n, vp, max_ops, counts, queue, changed, q, n_faces):
    """Try the pushed candidates, last pushed first, until none is left.

    Returns (q, n, n_faces, status): NEED_LIST / NEED_QUEUE when a collapse
    found no room in the list or the queue; the candidates stay in ``queue``
    for the resumed pass.
    """
    while q > 0:
        c = queue[q - 1]
        if (ns_get(state, c) & STATE_MASK) != SPLIT:
            q -= 1
            ns_update(state, c, QUEUED, 0)
            continue
        j = c - e
        t = links[j, 0]
        if (ns_get(state, t) & STATE_MASK) != ACTIVE or (ns_get(state, links[j, 1]) & STATE_MASK) != ACTIVE:
            q -= 1
            ns_update(state, c, QUEUED, 0)
            continue
        if need_refine(j, bound, cone, ring, vp):
            # The view keeps c split; its stationary child's entry may hold no
            # expiry for this test (module doc): have it evaluated next pass.
            ns_update(state, t, 0, RECHECK)
            cs_note(changed, state, t)
            q -= 1
            ns_update(state, c, QUEUED, 0)
            continue
        walked = 0 if collapse_legal(c, e, links, rotation, state, face_map, rec_nbr) else -1
        if walked == 0 and pos_top.shape[0] > 0:
            walked = strict_collapse_faces(c, e, links, npos, parent, pos_top, vpos, face_map, rec_tri, rec_nbr)
            if walked == -2:
                return q - 1, n, n_faces, DAMAGED        # queue[q - 1]: the candidate, for the caller's report
        if walked < 0:
            q -= 1
            ns_update(state, c, QUEUED, 0)
            continue
        if counts[0] + counts[1] >= max_ops:
            counts[2] = 1
            q -= 1
            ns_update(state, c, QUEUED, 0)
            continue
        if (ns_get(state, c) & IN_LIST) == 0 and n + 1 > active.shape[0]:
            return q, n, n_faces, NEED_LIST
        if q - 1 + 5 + 2 * walked > queue.shape[0]:
            return q, n, n_faces, NEED_QUEUE
        q -= 1
        ns_update(state, c, QUEUED, 0)
        if not collapse_node(c, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid, vpos, state, face_map, off, cnt,
                             rec_tri, rec_nbr, rec_face, dirty):
            return q, n, n_faces, DAMAGED
        counts[1] += 1
        cs_note(changed, state, t)
        cs_note(changed, state, links[j, 1])
        n_faces -= (links[j, 2] >= 0) + (links[j, 3] >= 0)
        n = _append(c, active, texp, aexp, n, state, changed)
        q = _push_after_collapse(c, e, parent, links, face_creator, state, queue, q)
        if pos_top.shape[0] > 0:
            q = _push_beside(c, e, parent, links, npos, pos_top, state, vpos, face_map, rec_tri, rec_nbr, queue, q)
    return q, n, n_faces, OK


@nb.njit(cache=True, nogil=True)
def collect_writes(off, cnt, rec_tri, dirty, out_mat, out_slot, out_tri):
    """Gather the slots written since the last call, in (material, slot)
    order, clearing ``dirty``; returns how many.

    ``out_*`` must hold ``cnt.sum()`` entries. Records beyond their
    material's count (removed since) are skipped. The bitset is scanned a
    word (64 records) at a time, so this costs a microsecond per 64k faces
    when little changed.
    """
    k = 0
    s = 0
    for wi in range(dirty.shape[0]):
        word = dirty[wi]
        if word == 0:
            continue
        dirty[wi] = 0
        for b in range(64):
            if (word >> np.uint64(b)) & np.uint64(1) == 0:
                continue
            r = wi * 64 + b
            while s + 1 < off.shape[0] and off[s + 1] <= r:
                s += 1
            slot = r - off[s]
            if slot < cnt[s]:
                out_mat[k] = s
                out_slot[k] = slot
                out_tri[k, 0] = rec_tri[r, 0]
                out_tri[k, 1] = rec_tri[r, 1]
                out_tri[k, 2] = rec_tri[r, 2]
                k += 1
    return k
