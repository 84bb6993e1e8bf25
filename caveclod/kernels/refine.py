"""Per-camera incremental selective refinement (Hoppe 1997, Kram & Shaw 3.6).

A camera's state is a handful of arrays; the static mesh is only read, so
any number of cameras share it and each kernel call releases the GIL.

Camera state (see :class:`caveclod.refine.camera.CameraState`):

* ``state`` (n,) uint8 per node: INACTIVE (below the front), ACTIVE, SPLIT
  (above it), plus the IN_LIST bit while the node sits in ``active``.
* ``face_rec`` (h, 2) int32: a hash table (open addressing, linear
  probing) from each active face to its record. Sized by the active faces,
  not by the mesh: a dense per-face array was most of a camera's bytes.
* Records of active faces, pooled: material ``s`` owns records
  ``off[s] .. off[s] + cnt[s]`` of a capacity ``cap[s]``, and record
  ``off[s] + k`` *is* slot ``k`` of that material's index buffer: ``pos``
  (3 corner positions), ``nbr`` (3 neighbour faces, edge k = corner k ->
  k+1), ``face``, ``tri`` (3 vertex-buffer indices, the mirror of the
  client's index buffer) and ``dirty`` (slot written since the last delta).
  Removing a face moves the material's last record into its slot, so every
  index buffer stays dense.

Corners store *positions*, not nodes: a stationary child shares its parent's
position, so only the floating child's wedge changes when a node splits.

Split of node s into t (stationary) and u (floating), faces fl = (t, u, vl),
fr = (u, t, vr) and recorded neighbours fn = (fl_u, fl_t, fr_u, fr_t); see
:mod:`caveclod.kernels.simplify` for the picture.
"""

import math

import numba as nb
import numpy as np

from .fans import corner_of, replace_in_row

INACTIVE, ACTIVE, SPLIT = 0, 1, 2
STATE_MASK, IN_LIST = 3, 4

OK, NEED_RECORDS, NEED_LIST, NEED_INDEX = 0, 1, 2, 3
MIXED, SPLITS_ONLY, COLLAPSES_ONLY = 0, 1, 2   # what a pass may do

# View parameter layout (caveclod.refine.view).
P_EYE, P_PLANES, P_KAPPA, P_TOL, P_CULL, P_BACKFACE = 0, 3, 23, 24, 25, 26


@nb.njit(cache=True, nogil=True, inline="always")
def _slot_of(table, f):
    """Where face ``f`` sits in the hash table, or the empty slot it would take."""
    mask = table.shape[0] - 1
    i = (f * 2654435761) & mask               # Knuth's multiplicative hash
    while table[i, 0] != f and table[i, 0] != -1:
        i = (i + 1) & mask
    return i


@nb.njit(cache=True, nogil=True, inline="always")
def _find(table, f):
    """Record of active face ``f``, or -1 if the face is not active."""
    return table[_slot_of(table, f), 1]


@nb.njit(cache=True, nogil=True, inline="always")
def _store(table, f, r):
    i = _slot_of(table, f)
    table[i, 0] = f
    table[i, 1] = r


@nb.njit(cache=True, nogil=True)
def _forget(table, f):
    """Delete ``f``, shifting later entries back (no tombstones)."""
    mask = table.shape[0] - 1
    i = _slot_of(table, f)
    if table[i, 0] == -1:
        return
    j = i
    while True:
        table[i, 0] = -1
        table[i, 1] = -1
        while True:
            j = (j + 1) & mask
            if table[j, 0] == -1:
                return
            home = (table[j, 0] * 2654435761) & mask
            # Move j back to i unless its home lies cyclically in (i, j].
            if (i <= j and (home <= i or home > j)) or (i > j and home <= i and home > j):
                break
        table[i, 0] = table[j, 0]
        table[i, 1] = table[j, 1]
        i = j


@nb.njit(cache=True, nogil=True)
def index_records(off, cnt, rec_face, table):
    """Fill an empty hash ``table`` (-1) with every active face's record."""
    for s in range(cnt.shape[0]):
        for r in range(off[s], off[s] + cnt[s]):
            _store(table, rec_face[r], r)


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


@nb.njit(cache=True, nogil=True)
def need_refine(j, bound, cone, vp):
    """Whether internal node ``j`` (index into node arrays) needs detail.

    ``bound[j]`` is (centre xyz, radius, error bound), one row so that the
    test touches one cache line.
    """
    cx, cy, cz, r = bound[j, 0], bound[j, 1], bound[j, 2], bound[j, 3]
    if vp[P_CULL] != 0.0:
        for i in range(5):
            b = P_PLANES + 4 * i
            if vp[b] * cx + vp[b + 1] * cy + vp[b + 2] * cz + vp[b + 3] < -r:
                return False                 # wholly outside the frustum
    dx, dy, dz = cx - vp[P_EYE], cy - vp[P_EYE + 1], cz - vp[P_EYE + 2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    if vp[P_BACKFACE] != 0.0 and length > r and cone[j, 3] < 0.5 * math.pi:
        # Back-facing when every normal of the cone points away from every
        # direction towards the sphere: angle(axis, view) - spreads > 90 deg
        # measured from the eye, i.e. the cone lies within the far half.
        cosphi = (cone[j, 0] * dx + cone[j, 1] * dy + cone[j, 2] * dz) / length
        phi = math.acos(min(1.0, max(-1.0, cosphi)))
        if phi + cone[j, 3] + math.asin(r / length) < 0.5 * math.pi:
            return False
    if vp[P_TOL] <= 0.0:
        return True
    dist = length - r
    if dist <= 0.0:
        return True
    return bound[j, 4] * vp[P_KAPPA] > vp[P_TOL] * dist


@nb.njit(cache=True, nogil=True)
def _move_wedge(fn0, fn2, old, new, fl, fr, fsgid, pos_vstart, vertex_sgid, face_rec, rec_pos, rec_nbr,
                rec_tri, rec_dirty):
    """Move the floating child's wedge of faces from position ``old`` to ``new``.

    The wedge runs from ``fn0`` (fl_u) round ``old`` to ``fn2`` (fr_u); if
    fl_u is absent it is walked back from fr_u to the border instead. A split
    moves it from s to u, a collapse back; the walk never enters fl or fr.
    """
    if fn0 >= 0:
        f = fn0
        while True:
            r = _find(face_rec, f)
            k = corner_of(rec_pos, r, old)
            rec_pos[r, k] = new
            rec_tri[r, k] = lookup_vertex(pos_vstart, vertex_sgid, fsgid[f], new)
            rec_dirty[r] = 1
            if f == fn2:
                break
            f = rec_nbr[r, k]                # across the outgoing edge at the corner
            if f < 0 or f == fr:
                break
    elif fn2 >= 0:
        f = fn2
        while True:
            r = _find(face_rec, f)
            k = corner_of(rec_pos, r, old)
            rec_pos[r, k] = new
            rec_tri[r, k] = lookup_vertex(pos_vstart, vertex_sgid, fsgid[f], new)
            rec_dirty[r] = 1
            f = rec_nbr[r, (k + 2) % 3]      # across the incoming edge
            if f < 0 or f == fl:
                break


@nb.njit(cache=True, nogil=True)
def split_node(x, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid,
               state, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty):
    """Split active node ``x`` whose required faces are all active.

    The caller has checked legality and capacity (two records).
    """
    j = x - e
    t, u = links[j, 0], links[j, 1]
    fl, fr = links[j, 2], links[j, 3]
    fn0, fn1, fn2, fn3 = links[j, 4], links[j, 5], links[j, 6], links[j, 7]
    px = npos[j]
    pu = node_position(e, npos, u)
    # 1. The floating child's wedge: faces from fl_u round to fr_u move to u.
    _move_wedge(fn0, fn2, px, pu, fl, fr, fsgid, pos_vstart, vertex_sgid, face_rec, rec_pos, rec_nbr,
                rec_tri, rec_dirty)
    # 2. The two new faces, linked into their neighbours.
    if fl >= 0:
        if fn0 >= 0:
            r0 = _find(face_rec, fn0)
            vl = rec_pos[r0, (corner_of(rec_pos, r0, pu) + 2) % 3]
        else:
            r1 = _find(face_rec, fn1)
            vl = rec_pos[r1, (corner_of(rec_pos, r1, px) + 1) % 3]
        _add_face(fl, px, pu, vl, fr, fn0, fn1, mat, fsgid, pos_vstart, vertex_sgid,
                  face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty)
        if fn0 >= 0:
            r0 = _find(face_rec, fn0)
            rec_nbr[r0, corner_of(rec_pos, r0, vl)] = fl      # edge vl -> u
        if fn1 >= 0:
            r1 = _find(face_rec, fn1)
            rec_nbr[r1, corner_of(rec_pos, r1, px)] = fl      # edge t -> vl
    if fr >= 0:
        if fn2 >= 0:
            r2 = _find(face_rec, fn2)
            vr = rec_pos[r2, (corner_of(rec_pos, r2, pu) + 1) % 3]
        else:
            r3 = _find(face_rec, fn3)
            vr = rec_pos[r3, (corner_of(rec_pos, r3, px) + 2) % 3]
        _add_face(fr, pu, px, vr, fl, fn3, fn2, mat, fsgid, pos_vstart, vertex_sgid,
                  face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty)
        if fn2 >= 0:
            r2 = _find(face_rec, fn2)
            rec_nbr[r2, corner_of(rec_pos, r2, pu)] = fr      # edge u -> vr
        if fn3 >= 0:
            r3 = _find(face_rec, fn3)
            rec_nbr[r3, corner_of(rec_pos, r3, vr)] = fr      # edge vr -> t
    state[x] = (state[x] & IN_LIST) | SPLIT
    state[t] = (state[t] & IN_LIST) | ACTIVE
    state[u] = (state[u] & IN_LIST) | ACTIVE


@nb.njit(cache=True, nogil=True)
def _add_face(f, a, b, c, n0, n1, n2, mat, fsgid, pos_vstart, vertex_sgid,
              face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty):
    """Append face ``f`` = (a, b, c) with neighbours (n0, n1, n2)."""
    s = mat[f]
    slot = cnt[s]
    cnt[s] += 1
    r = off[s] + slot
    _store(face_rec, f, r)
    rec_face[r] = f
    rec_pos[r, 0], rec_pos[r, 1], rec_pos[r, 2] = a, b, c
    rec_nbr[r, 0], rec_nbr[r, 1], rec_nbr[r, 2] = n0, n1, n2
    g = fsgid[f]
    rec_tri[r, 0] = lookup_vertex(pos_vstart, vertex_sgid, g, a)
    rec_tri[r, 1] = lookup_vertex(pos_vstart, vertex_sgid, g, b)
    rec_tri[r, 2] = lookup_vertex(pos_vstart, vertex_sgid, g, c)
    rec_dirty[r] = 1


@nb.njit(cache=True, nogil=True)
def _remove_face(f, mat, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty):
    """Remove face ``f``; the material's last face fills its slot."""
    s = mat[f]
    r = _find(face_rec, f)
    last = off[s] + cnt[s] - 1
    if r != last:
        for k in range(3):
            rec_pos[r, k] = rec_pos[last, k]
            rec_nbr[r, k] = rec_nbr[last, k]
            rec_tri[r, k] = rec_tri[last, k]
        rec_face[r] = rec_face[last]
        rec_dirty[r] = 1
        _store(face_rec, rec_face[r], r)
    _forget(face_rec, f)
    cnt[s] -= 1


@nb.njit(cache=True, nogil=True)
def collapse_legal(x, e, links, state, face_rec, rec_nbr):
    """Hoppe's ecol precondition for undoing the split of ``x``."""
    j = x - e
    if (state[links[j, 0]] & STATE_MASK) != ACTIVE or (state[links[j, 1]] & STATE_MASK) != ACTIVE:
        return False
    fl, fr = links[j, 2], links[j, 3]
    if fl >= 0:
        r = _find(face_rec, fl)
        if rec_nbr[r, 1] != links[j, 4] or rec_nbr[r, 2] != links[j, 5]:
            return False
    if fr >= 0:
        r = _find(face_rec, fr)
        if rec_nbr[r, 1] != links[j, 7] or rec_nbr[r, 2] != links[j, 6]:
            return False
    return True


@nb.njit(cache=True, nogil=True)
def collapse_node(x, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid,
                  state, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty):
    """Undo the split of ``x`` (the caller checked :func:`collapse_legal`)."""
    j = x - e
    t, u = links[j, 0], links[j, 1]
    fl, fr = links[j, 2], links[j, 3]
    fn0, fn1, fn2, fn3 = links[j, 4], links[j, 5], links[j, 6], links[j, 7]
    px = npos[j]
    pu = node_position(e, npos, u)
    _move_wedge(fn0, fn2, pu, px, fl, fr, fsgid, pos_vstart, vertex_sgid, face_rec, rec_pos, rec_nbr,
                rec_tri, rec_dirty)
    if fl >= 0:
        if fn0 >= 0:
            replace_in_row(rec_nbr, _find(face_rec, fn0), fl, fn1)
        if fn1 >= 0:
            replace_in_row(rec_nbr, _find(face_rec, fn1), fl, fn0)
        _remove_face(fl, mat, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty)
    if fr >= 0:
        if fn2 >= 0:
            replace_in_row(rec_nbr, _find(face_rec, fn2), fr, fn3)
        if fn3 >= 0:
            replace_in_row(rec_nbr, _find(face_rec, fn3), fr, fn2)
        _remove_face(fr, mat, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty)
    state[x] = (state[x] & IN_LIST) | ACTIVE
    state[t] = state[t] & IN_LIST
    state[u] = state[u] & IN_LIST


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


@nb.njit(cache=True, nogil=True)
def sort_active(active, n):
    """Sort ``active[:n]``: a sorted run (last pass's survivors, written in
    order) followed by a short tail of nodes appended during that pass.

    Sorting the tail and merging is linear; a plain quicksort degrades on
    this nearly sorted input (4 ms instead of 0.1 ms for 11k nodes).
    """
    k = 1
    while k < n and active[k - 1] <= active[k]:
        k += 1
    if k >= n:
        return
    tail = np.sort(active[k:n])
    head = active[:k].copy()
    i = j = 0
    for o in range(n):
        if j >= tail.shape[0] or (i < k and head[i] <= tail[j]):
            active[o] = head[i]
            i += 1
        else:
            active[o] = tail[j]
            j += 1


@nb.njit(cache=True, nogil=True)
def adapt(e, parent, links, npos, bound, cone, face_creator, mat, fsgid,
          pos_vstart, vertex_sgid, state, face_rec, off, cnt, cap, rec_pos, rec_nbr, rec_face,
          rec_tri, rec_dirty, active, n_active, vp, max_ops, max_faces, counts, resume, mode):
    """One pass of incremental selective refinement over the active nodes.

    Splits (forcing the splits a split needs) where the view needs detail and
    collapses sibling pairs whose parent no longer needs it, while fewer than
    ``max_ops`` operations were made and fewer than ``max_faces`` faces are
    active. ``counts`` (2,) int64 accumulates splits and collapses. ``mode``
    MIXED does both in one pass (Hoppe); SPLITS_ONLY / COLLAPSES_ONLY let a
    budgeted update refine first and coarsen with what budget is left.

    Returns (status, material): OK, or NEED_RECORDS for that material /
    NEED_LIST: grow the arrays and call again, and the call *continues the
    same pass* where this one stopped: ``resume`` (3,) int64 holds the read
    and write positions and a flag, so decisions never depend on how much
    room the arrays happened to have. (The node being force-split when room
    ran out is visited again; its forced split restarts and, being
    deterministic, makes the same decisions.)
    """
    n = n_active[0]
    if resume[2]:
        i, w = resume[0], resume[1]
        resume[2] = 0
    else:
        # Visit nodes in id order: their static rows are then read front to
        # back instead of at random, which halves the cost of a pass.
        sort_active(active, n)
        i = 0
        w = 0
    stack = np.empty(256, np.int64)
    n_faces = 0
    for s in range(cnt.shape[0]):
        n_faces += cnt[s]
    status, need_mat = OK, -1
    while i < n:
        x = active[i]
        i += 1
        st = state[x]
        if (st & STATE_MASK) != ACTIVE:
            state[x] = st & ~IN_LIST & 0xFF
            continue
        ops = counts[0] + counts[1]
        if mode != COLLAPSES_ONLY and x >= e and ops < max_ops and need_refine(x - e, bound, cone, vp):
            # Force the split of x: Hoppe's stack of unmet preconditions.
            stack[0] = x
            sp = 1
            while sp > 0:
                y = stack[sp - 1]
                sy = state[y] & STATE_MASK
                if sy == SPLIT or y < e:
                    sp -= 1
                    continue
                if sp + 5 > stack.shape[0]:
                    bigger = np.empty(2 * stack.shape[0], np.int64)
                    bigger[:sp] = stack[:sp]
                    stack = bigger
                if sy == INACTIVE:
                    stack[sp] = parent[y]
                    sp += 1
                    continue
                jy = y - e
                missing = False
                for q in range(4):
                    f = links[jy, 4 + q]
                    if f >= 0 and _find(face_rec, f) < 0:
                        stack[sp] = face_creator[f]
                        sp += 1
                        missing = True
                if missing:
                    continue
                if counts[0] + counts[1] >= max_ops or n_faces + 2 > max_faces:
                    break
                s_need = _room_for_split(jy, links, mat, cnt, cap)
                if s_need >= 0:
                    status, need_mat = NEED_RECORDS, s_need
                    break
                if n + 2 > active.shape[0]:
                    status = NEED_LIST
                    break
                if 2 * (n_faces + 2) > face_rec.shape[0]:   # keep the table at most half full
                    status = NEED_INDEX
                    break
                split_node(y, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid,
                           state, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty)
                counts[0] += 1
                n_faces += (links[jy, 2] >= 0) + (links[jy, 3] >= 0)
                for c in range(2):
                    ch = links[jy, c]
                    if (state[ch] & IN_LIST) == 0:
                        state[ch] |= IN_LIST
                        active[n] = ch
                        n += 1
                sp -= 1
            if status != OK:
                i -= 1                       # x is visited again on resume
                break
            if (state[x] & STATE_MASK) == ACTIVE:
                active[w] = x
                w += 1
            else:
                state[x] = state[x] & ~IN_LIST & 0xFF
            continue
        p = parent[x]
        # The stationary child speaks for the pair, and only when its sibling
        # is active too: a collapse needs both, and this halves the
        # (cache-missing) parent tests.
        if mode != SPLITS_ONLY and p >= 0 and ops < max_ops and links[p - e, 0] == x and \
                (state[links[p - e, 1]] & STATE_MASK) == ACTIVE and \
                not need_refine(p - e, bound, cone, vp) and \
                collapse_legal(p, e, links, state, face_rec, rec_nbr):
            if (state[p] & IN_LIST) == 0 and n + 1 > active.shape[0]:
                i -= 1
                status = NEED_LIST
                break
            jp = p - e
            collapse_node(p, e, links, npos, mat, fsgid, pos_vstart, vertex_sgid,
                          state, face_rec, off, cnt, rec_pos, rec_nbr, rec_face, rec_tri, rec_dirty)
            counts[1] += 1
            n_faces -= (links[jp, 2] >= 0) + (links[jp, 3] >= 0)
            if (state[p] & IN_LIST) == 0:
                state[p] |= IN_LIST
                active[n] = p
                n += 1
            state[x] = state[x] & ~IN_LIST & 0xFF
            continue
        active[w] = x
        w += 1
    if status != OK:
        # Stopped for room: remember where, keep the list as it is.
        resume[0], resume[1], resume[2] = i, w, 1
        n_active[0] = n
        return status, need_mat
    n_active[0] = w
    return status, need_mat


@nb.njit(cache=True, nogil=True)
def collect_writes(off, cnt, rec_tri, rec_dirty, out_mat, out_slot, out_tri):
    """Gather dirty slots of every material (clearing them); returns how many.

    ``out_*`` must hold ``cnt.sum()`` entries.
    """
    k = 0
    for s in range(cnt.shape[0]):
        for slot in range(cnt[s]):
            r = off[s] + slot
            if rec_dirty[r]:
                rec_dirty[r] = 0
                out_mat[k] = s
                out_slot[k] = slot
                out_tri[k, 0] = rec_tri[r, 0]
                out_tri[k, 1] = rec_tri[r, 1]
                out_tri[k, 2] = rec_tri[r, 2]
                k += 1
    return k
