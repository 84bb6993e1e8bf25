"""Parts that vanish: whole connected parts hidden while they are smaller than the
tolerance or wholly outside the view.

A *part* is a connected component of the base mesh (faces joined through
shared root nodes). Half-edge collapses only merge the two ends of an edge,
so a part's subtree never reaches another part: no split of one part forces
a split in another, and a part can be hidden or shown without touching the
rest of the camera's state.

A visible part is to be hidden when the bounding sphere of its original
positions (centre ``c``, radius ``r``) projects smaller than the tolerance,

    (|c - eye| - r) - 2 r kappa / tol > 0

(its diameter ``2 r`` seen at its nearest distance is under ``tol`` pixels:
the node test's arithmetic with an error of ``2 r``, Kram & Shaw section 3),
or, with culling on, when the sphere lies wholly outside a frustum plane.
It is hidden at once, however refined: its active faces are removed, the
nodes below its roots made inactive and its roots marked HIDDEN. A hidden
part is shown again at its base mesh (roots active, base faces back) as
soon as it is to be drawn. Both tests are the node test's, so their
answers carry the same expiries on the camera's travelled distance and
turned angle (``odo``) as the active list's entries: a camera at rest reads
two floats per part.

Hiding a part at once, rather than waiting for its nodes to collapse, keeps
the outcome free of history: node spheres are looser than the part's (each
collapse grows its node's sphere), so a part outside the frustum can have
nodes whose spheres reach into it and that keep refining.

Hiding runs after an update's refinement pass and showing before it (a
part that comes back is refined in the same update). Hidden nodes keep
their active-list entries until the next pass drops them, marked RECHECK so
that their stale expiries are never trusted (a shown root, or a node split
into again before the pass reaches its entry).
"""

import math

import numba as nb
import numpy as np

from .refine import (ACTIVE, DAMAGED, FOREVER, IN_LIST, NEED_RECORDS, NEVER, OK, P_EYE, P_KAPPA, P_PRUNE, P_TOL,
                     RECHECK, SPLIT, STATE_MASK, _add_face, _expiry, _remove_face, node_position, sphere_planes)
from .facemap import fm_get
from .nodestate import ns_get, ns_set, ns_update
from .unionfind import find

HIDDEN = 3            # node state of a hidden part's roots (STATE_MASK's free value)


@nb.njit(cache=True, nogil=True)
def label_parts(face_nodes, n_nodes):
    """Connected components of the base mesh through shared nodes.

    Args:
        face_nodes: (k, 3) int32 the nodes of each base face, numbered
            0 .. n_nodes-1 (the base mesh's own numbering: ids index scratch
            arrays of n_nodes).

    Returns:
        (k,) int32 part of each base face, numbered 0.. in order of each
        part's first face.
    """
    up = np.arange(n_nodes).astype(np.int32)      # union-find over nodes
    for i in range(face_nodes.shape[0]):
        a = find(up, face_nodes[i, 0])
        for k in range(1, 3):
            b = find(up, face_nodes[i, k])
            if a != b:
                if a < b:
                    up[b] = a
                else:
                    up[a] = b
                    a = b
    label = np.full(n_nodes, -1, np.int32)
    out = np.empty(face_nodes.shape[0], np.int32)
    m = 0
    for i in range(face_nodes.shape[0]):
        root = find(up, face_nodes[i, 0])
        if label[root] < 0:
            label[root] = m
            m += 1
        out[i] = label[root]
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def part_test(k, sphere, vp):
    """Whether part ``k`` is to be drawn for the view ``vp`` (the module doc),
    and for how long the answer holds: returns (visible, tmargin, rmargin,
    dist) as :func:`caveclod.kernels.refine.test_node` does, for
    :func:`caveclod.kernels.refine._expiry`.

    The node test's arithmetic on the part's sphere with an error of its
    diameter: hidden when wholly outside a frustum plane (culling on), or
    when ``2 r kappa / tol - (|c - eye| - r) <= 0``.
    """
    if vp[P_PRUNE] == 0.0:
        return True, FOREVER, FOREVER, 0.0
    cx, cy, cz, r = sphere[k, 0], sphere[k, 1], sphere[k, 2], sphere[k, 3]
    dx, dy, dz = cx - vp[P_EYE], cy - vp[P_EYE + 1], cz - vp[P_EYE + 2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    outside, inside = sphere_planes(cx, cy, cz, r, vp)
    if outside > 0.0:
        return False, 0.0, outside, length
    if vp[P_TOL] <= 0.0:
        return True, FOREVER, inside, length
    dist = length - r
    s = 2.0 * r * vp[P_KAPPA] / vp[P_TOL] - dist
    if dist <= 0.0 or s > 0.0:
        return True, max(s, 0.0), inside, length
    return False, -s, 0.0, length


@nb.njit(cache=True, nogil=True, inline="always")
def _part_expiry(odo, k, sphere, vp, expire, ptexp, paexp):
    """Test part ``k``, store when its answer expires, return whether it is visible."""
    visible, tm, rm, dist = part_test(k, sphere, vp)
    if expire:
        ptexp[k], paexp[k] = _expiry(odo, tm, rm, dist, visible, FOREVER, FOREVER)
    else:
        ptexp[k], paexp[k] = NEVER, NEVER
    return visible


@nb.njit(cache=True, nogil=True)
def show_parts(e, npos, mat, fsgid, pos_vstart, vertex_sgid, base_faces, base_nodes, base_nbrs,
               sphere, root_start, roots, face_start, faces, hidden, ptexp, paexp,
               state, face_map, off, cnt, cap, rec_tri, rec_nbr, rec_face, dirty,
               active, texp, aexp, n_active, vp, odo, expire, todo, need, shown):
    """Show the hidden parts that are no longer small (before a pass).

    ``faces`` lists rows of the base arrays (``base_faces``, ``base_nodes``
    (k, 3), ``base_nbrs`` (k, 3)) part by part (CSR ``face_start``), ``roots``
    the part's root nodes (CSR ``root_start``). ``hidden`` (m,) uint8 and
    ``ptexp``, ``paexp`` (m,) float64 (when each part's answer expires, on
    the travelled distance and the turned angle) are the camera's part
    state; ``todo`` (m,) int32 is scratch; ``shown`` (1,) int64 counts the
    parts shown.

    First the parts to show are found and the room they need counted, so
    that a frame in which many parts come back grows the arrays once:
    returns (NEED_RECORDS, 0) with ``need`` (materials + 1,) int64 holding
    the records each material needs and, last, the list entries (grow, call
    again: nothing was changed but expiries), else shows them
    all and returns (OK, -1), or (DAMAGED, face) for a base face whose
    corner has no vertex of its group.
    """
    t, a = odo[0], odo[1]
    n = n_active[0]
    q = 0
    for k in range(hidden.shape[0]):
        if hidden[k] == 0 or (expire and t < ptexp[k] and a < paexp[k]):
            continue
        visible, _, _, _ = part_test(k, sphere, vp)
        if visible:                      # its expiries are stored once it is shown (this call may stop short)
            todo[q] = k
            q += 1
        else:
            _part_expiry(odo, k, sphere, vp, expire, ptexp, paexp)
    if q == 0:
        return OK, -1
    need[:] = 0
    for j in range(q):
        k = todo[j]
        for i in range(face_start[k], face_start[k + 1]):
            need[mat[base_faces[faces[i]]]] += 1
        for i in range(root_start[k], root_start[k + 1]):
            if (ns_get(state, roots[i]) & IN_LIST) == 0:      # a listed root keeps its entry
                need[need.shape[0] - 1] += 1
    short = n + need[need.shape[0] - 1] > active.shape[0]
    for s in range(cnt.shape[0]):
        short = short or cnt[s] + need[s] > cap[s]
    if short:
        return NEED_RECORDS, 0
    for j in range(q):
        k = todo[j]
        for i in range(face_start[k], face_start[k + 1]):
            f = base_faces[faces[i]]
            b = faces[i]
            if not _add_face(f, node_position(e, npos, base_nodes[b, 0]), node_position(e, npos, base_nodes[b, 1]),
                             node_position(e, npos, base_nodes[b, 2]), base_nbrs[b, 0], base_nbrs[b, 1],
                             base_nbrs[b, 2], 0, mat, fsgid, pos_vstart, vertex_sgid, face_map, off, cnt,
                             rec_tri, rec_nbr, rec_face, dirty):
                n_active[0] = n
                return DAMAGED, f
        for i in range(root_start[k], root_start[k + 1]):
            x = roots[i]
            if ns_get(state, x) & IN_LIST:
                ns_update(state, x, STATE_MASK, ACTIVE | RECHECK)
            else:
                ns_set(state, x, ACTIVE | IN_LIST)
                active[n] = x
                texp[n] = NEVER
                aexp[n] = NEVER
                n += 1
        hidden[k] = 0
        _part_expiry(odo, k, sphere, vp, expire, ptexp, paexp)
        shown[0] += 1
    n_active[0] = n
    return OK, -1


@nb.njit(cache=True, nogil=True)
def hide_parts(e, links, base_faces, mat, sphere, root_start, roots, face_start, faces, hidden, ptexp, paexp,
               state, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty, vp, odo, expire, hid):
    """Hide the visible parts that are not to be drawn (after a pass), whatever their refinement.

    Arrays as :func:`show_parts`, with ``e`` and ``links`` (the node rows of
    :mod:`caveclod.kernels.refine`); ``hid`` (1,) int64 counts the parts
    hidden. Returns the earliest expiries of all parts' answers (distance,
    angle): until the camera passes one, no part can change and neither
    this nor :func:`show_parts` need be called (each call costs more in
    numba's dispatch of its 24 to 37 arguments than a converged camera's
    whole pass). A part's active faces are its base faces and the two faces of
    each split node (faces are made by splits only), so a walk down from
    its roots through the split nodes removes them all and makes every node
    below the roots inactive. A node that keeps an active-list entry is
    marked RECHECK: the pass drops the entry, or, if the part comes back
    and the node is split into again first, evaluates it afresh.
    """
    t, a = odo[0], odo[1]
    stack = np.empty(256, np.int32)
    for k in range(hidden.shape[0]):
        if hidden[k] != 0 or (expire and t < ptexp[k] and a < paexp[k]):
            continue
        if _part_expiry(odo, k, sphere, vp, expire, ptexp, paexp):
            continue
        sp = 0
        for i in range(root_start[k], root_start[k + 1]):
            if sp + 2 > stack.shape[0]:
                stack = _grown(stack)
            stack[sp] = roots[i]
            sp += 1
        while sp > 0:
            sp -= 1
            x = stack[sp]
            st = ns_get(state, x)
            if x >= e and (st & STATE_MASK) == SPLIT:
                j = x - e
                for q in range(2, 4):
                    f = links[j, q]
                    if f >= 0 and fm_get(face_map, f) >= 0:
                        _remove_face(f, mat, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty)
                if sp + 2 > stack.shape[0]:
                    stack = _grown(stack)
                stack[sp] = links[j, 0]
                stack[sp + 1] = links[j, 1]
                sp += 2
            listed = st & IN_LIST
            ns_set(state, x, (listed | RECHECK) if listed else 0)        # INACTIVE
        for i in range(face_start[k], face_start[k + 1]):
            f = base_faces[faces[i]]
            if fm_get(face_map, f) >= 0:
                _remove_face(f, mat, face_map, off, cnt, rec_tri, rec_nbr, rec_face, dirty)
        for i in range(root_start[k], root_start[k + 1]):
            x = roots[i]
            ns_update(state, x, 0xFF & ~IN_LIST, HIDDEN)
        hidden[k] = 1
        hid[0] += 1
    due_t, due_a = FOREVER, FOREVER
    for k in range(hidden.shape[0]):
        due_t = min(due_t, ptexp[k])
        due_a = min(due_a, paexp[k])
    return due_t, due_a


@nb.njit(cache=True, nogil=True, inline="always")
def _grown(stack):
    bigger = np.empty(2 * stack.shape[0], np.int32)
    bigger[:stack.shape[0]] = stack
    return bigger


@nb.njit(cache=True, nogil=True)
def spread_parts(parent, node_part):
    """Give every node the part of its root, in place.

    Args:
        parent: (n,) int32 node parents (-1 for roots; a parent's id is
            always larger, which :func:`caveclod.meshcheck.check_mesh` proves,
            so one pass from the top down reaches every node after its parent).
        node_part: (n,) int32, the part of each root on entry (-1 for a root
            in no base face); the part of every node on return. Leaves are
            nodes 0 .. e-1, so ``node_part[:e]`` is each position's part.
    """
    for x in range(parent.shape[0] - 1, -1, -1):
        p = parent[x]
        if p >= 0:
            node_part[x] = node_part[p]


@nb.njit(cache=True, nogil=True)
def part_spheres(vertex_positions, pos_vstart, part, m):
    """Bounding sphere of each part's original positions.

    Args:
        vertex_positions: (d, 3) float32 vertex buffer; position ``x`` is
            ``vertex_positions[pos_vstart[x]]`` (no copy of the positions).
        pos_vstart: (e+1,) int32 first vertex of each position.
        part: (>= e,) int32 part of each position (:func:`spread_parts`), -1: none.
        m: number of parts.

    Returns:
        (m, 4) float64: centre (the middle of the part's box) and radius (the
        farthest position's distance from it).
    """
    e = pos_vstart.shape[0] - 1
    lo = np.full((m, 3), np.inf)
    hi = np.full((m, 3), -np.inf)
    for x in range(e):
        k = part[x]
        if k < 0:
            continue
        v = pos_vstart[x]
        for j in range(3):
            c = np.float64(vertex_positions[v, j])
            lo[k, j] = min(lo[k, j], c)
            hi[k, j] = max(hi[k, j], c)
    out = np.zeros((m, 4))
    for k in range(m):
        for j in range(3):
            out[k, j] = 0.5 * (lo[k, j] + hi[k, j])
    for x in range(e):
        k = part[x]
        if k < 0:
            continue
        v = pos_vstart[x]
        dx = np.float64(vertex_positions[v, 0]) - out[k, 0]
        dy = np.float64(vertex_positions[v, 1]) - out[k, 1]
        dz = np.float64(vertex_positions[v, 2]) - out[k, 2]
        out[k, 3] = max(out[k, 3], math.sqrt(dx * dx + dy * dy + dz * dz))
    return out
