"""Surface groups, surface group ids, the vertex buffer and FREE/SHARP/RIGID.

Paper section 3.3 and DESIGN.md section 2:

* A *surface group* is a connected set of faces of one material that share
  the same vertex (all attributes) on both ends of every edge joining them.
  Groups are grown face by face and a face is refused when the group already
  has a *different* vertex at one of its positions (a seam that ends inside
  the surface, a UV-sphere pole). So (group, position) -> vertex is unique,
  which is what lets a face be drawn from its group and its nodes alone.
* *Surface group ids* are reused between groups that share no position
  (greedy colouring), keeping the (id, position) -> vertex table small.
* The vertex buffer has one entry per (group, position) pair, sorted by
  position then id, so the table is a CSR: ``pos_vstart[x] : pos_vstart[x+1]``
  are the vertices at position ``x`` and ``vertex_sgid`` names their ids.
* A position on no group boundary is FREE, on one boundary (two boundary
  edges) SHARP, on anything else (corners, crossings, cut edges) RIGID.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..kernels.positions import fill_vertex_positions

FREE, SHARP, RIGID = 0, 1, 2
CLASS_NAMES = ("free", "sharp", "rigid")


@dataclass
class SurfaceLayout:
    """Result of :func:`layout_surfaces`.

    Attributes:
        face_group: (p,) int32 surface group of each face.
        face_sgid: (p,) int32 surface group id (reused) of each face.
        vertex_source: (d,) int64, the source vertex each buffer entry copies.
        vertex_sgid: (d,) int32 surface group id of each buffer entry.
        vertex_group: (d,) int32 surface group of each buffer entry.
        pos_vstart: (e+1,) int64 CSR offsets: vertices of position x.
        position_class: (e,) uint8 FREE/SHARP/RIGID.
        n_groups: number of surface groups; n_sgids: number of distinct ids.
    """

    face_group: np.ndarray
    face_sgid: np.ndarray
    vertex_source: np.ndarray
    vertex_sgid: np.ndarray
    vertex_group: np.ndarray
    pos_vstart: np.ndarray
    position_class: np.ndarray
    n_groups: int
    n_sgids: int


def layout_surfaces(face_pos, face_vertex, face_material, nbrs, nonmanifold, n_positions) -> SurfaceLayout:
    """Group faces, colour groups, lay out the vertex buffer, classify positions.

    Args:
        face_pos: (p, 3) int32 position ids.
        face_vertex: (p, 3) int32 source vertex ids (attribute identity).
        face_material: (p,) int32.
        nbrs: (p, 3) int32 face neighbours (see :mod:`caveclod.builder.topology`).
        nonmanifold: (e,) bool positions that must stay RIGID.
        n_positions: e.
    """
    group = _grow_groups(face_pos, face_vertex, face_material.astype(np.int32), nbrs, n_positions)
    n_groups = int(group.max()) + 1
    # One vertex per (group, position) pair in use, listed by position.
    pos_vstart, pair_group, first = _group_pairs(face_pos, group, n_positions)
    pair_pos = np.zeros(int(pos_vstart[-1]), np.int32)       # the position of each pair (the inverse CSR)
    fill_vertex_positions(pos_vstart, pair_pos)
    sgid_of_group = _colour_groups(pair_group, pair_pos, n_groups, n_positions)
    pair_sgid = sgid_of_group[pair_group]
    order = _by_id_within_position(pos_vstart, pair_sgid)
    cls = _classify(face_pos, group, nbrs, nonmanifold)
    return SurfaceLayout(
        face_group=group,
        face_sgid=sgid_of_group[group],
        vertex_source=face_vertex.ravel()[first[order]].astype(np.int64),
        vertex_sgid=pair_sgid[order],
        vertex_group=pair_group[order],
        pos_vstart=pos_vstart,
        position_class=cls,
        n_groups=n_groups,
        n_sgids=int(sgid_of_group.max()) + 1,
    )


def rigid_positions(face_pos, face_vertex, face_material, nbrs, nonmanifold) -> int:
    """How many positions :func:`layout_surfaces` would make RIGID, arguments as its own (the
    groups and classes alone: no vertex buffer)."""
    group = _grow_groups(face_pos, face_vertex, np.asarray(face_material, np.int32), nbrs, len(nonmanifold))
    return int(np.count_nonzero(_classify(face_pos, group, nbrs, nonmanifold) == RIGID))


@nb.njit(cache=True, nogil=True)
def _group_pairs(face_pos, group, e):
    """The (group, position) pairs in use, as a CSR by position.

    Returns ``(pos_start (e+1,) int64, pair_group (d,) int32, first (d,)
    int64)``: the groups at position x are ``pair_group[pos_start[x]:
    pos_start[x+1]]``, and ``first`` is the first corner (3 f + k) of each
    pair. Linear: a position has a handful of groups, kept in a linked list.
    """
    p = face_pos.shape[0]
    head = np.full(e, -1, np.int64)
    nxt = np.empty(3 * p, np.int64)
    grp = np.empty(3 * p, np.int32)
    src = np.empty(3 * p, np.int64)
    count = np.zeros(e + 1, np.int64)
    n = 0
    for f in range(p):
        g = group[f]
        for k in range(3):
            x = face_pos[f, k]
            i = head[x]
            while i != -1 and grp[i] != g:
                i = nxt[i]
            if i == -1:
                grp[n], src[n], nxt[n] = g, 3 * f + k, head[x]
                head[x] = n
                count[x + 1] += 1
                n += 1
    for x in range(e):
        count[x + 1] += count[x]
    pair_group = np.empty(n, np.int32)
    first = np.empty(n, np.int64)
    for x in range(e):
        o = count[x + 1]
        i = head[x]
        while i != -1:               # the list is newest first: fill backwards
            o -= 1
            pair_group[o] = grp[i]
            first[o] = src[i]
            i = nxt[i]
    return count, pair_group, first


@nb.njit(cache=True, nogil=True)
def _by_id_within_position(pos_start, pair_sgid):
    """(d,) permutation sorting each position's pairs by id (insertion sort)."""
    order = np.arange(pair_sgid.shape[0])
    for x in range(pos_start.shape[0] - 1):
        for i in range(pos_start[x] + 1, pos_start[x + 1]):
            j = i
            while j > pos_start[x] and pair_sgid[order[j - 1]] > pair_sgid[order[j]]:
                order[j - 1], order[j] = order[j], order[j - 1]
                j -= 1
    return order


@nb.njit(cache=True, nogil=True)
def _grow_groups(face_pos, face_vertex, material, nbrs, e):
    """(p,) int32 group per face, grown breadth-first without conflicts."""
    p = face_pos.shape[0]
    group = np.full(p, -1, np.int32)
    owner = np.full(e, -1, np.int32)      # group that last claimed a vertex at x
    claimed = np.empty(e, np.int32)       # the vertex it claimed there
    queue = np.empty(p, np.int32)
    g = 0
    for seed in range(p):
        if group[seed] >= 0:
            continue
        group[seed] = g
        for k in range(3):
            owner[face_pos[seed, k]] = g
            claimed[face_pos[seed, k]] = face_vertex[seed, k]
        head, tail = 0, 1
        queue[0] = seed
        while head < tail:
            f = queue[head]
            head += 1
            for k in range(3):
                h = nbrs[f, k]
                if h < 0 or group[h] >= 0 or material[h] != material[f]:
                    continue
                ok = True
                for c in range(3):
                    x = face_pos[h, c]
                    if owner[x] == g and claimed[x] != face_vertex[h, c]:
                        ok = False
                if not ok:
                    continue
                group[h] = g
                for c in range(3):
                    owner[face_pos[h, c]] = g
                    claimed[face_pos[h, c]] = face_vertex[h, c]
                queue[tail] = h
                tail += 1
        g += 1
    return group


@nb.njit(cache=True, nogil=True)
def _colour_groups(pair_group, pair_pos, n_groups, e):
    """(n_groups,) int32 id per group; groups sharing a position differ.

    ``pair_group``/``pair_pos`` (d,) list the (group, position) pairs in any
    order; both directions are indexed here.
    """
    # CSR position -> groups, and group -> positions.
    pos_count = np.zeros(e + 1, np.int64)
    for i in range(pair_pos.shape[0]):
        pos_count[pair_pos[i] + 1] += 1
    for x in range(e):
        pos_count[x + 1] += pos_count[x]
    fill = pos_count[:-1].copy()
    pos_groups = np.empty(pair_pos.shape[0], np.int32)
    for i in range(pair_pos.shape[0]):
        pos_groups[fill[pair_pos[i]]] = pair_group[i]
        fill[pair_pos[i]] += 1
    grp_start = np.zeros(n_groups + 1, np.int64)
    for i in range(pair_group.shape[0]):
        grp_start[pair_group[i] + 1] += 1
    for g in range(n_groups):
        grp_start[g + 1] += grp_start[g]
    fill = grp_start[:-1].copy()
    grp_pos = np.empty(pair_group.shape[0], np.int32)     # positions of each group (CSR)
    for i in range(pair_group.shape[0]):
        grp_pos[fill[pair_group[i]]] = pair_pos[i]
        fill[pair_group[i]] += 1
    colour = np.full(n_groups, -1, np.int32)
    used_by = np.full(n_groups + 1, -1, np.int32)   # colour c is used near g
    for g in range(n_groups):
        for i in range(grp_start[g], grp_start[g + 1]):
            x = grp_pos[i]
            for j in range(pos_count[x], pos_count[x + 1]):
                c = colour[pos_groups[j]]
                if c >= 0:
                    used_by[c] = g
        c = 0
        while used_by[c] == g:
            c += 1
        colour[g] = c
    return colour


@nb.njit(cache=True, nogil=True)
def _classify(face_pos, group, nbrs, nonmanifold):
    """(e,) uint8 FREE/SHARP/RIGID from boundary edges per position."""
    e = nonmanifold.shape[0]
    count = np.zeros(e, np.int32)
    for f in range(face_pos.shape[0]):
        for k in range(3):
            h = nbrs[f, k]
            boundary = h < 0 or group[h] != group[f]
            if boundary and (h < 0 or f < h):      # count each undirected edge once
                count[face_pos[f, k]] += 1
                count[face_pos[f, (k + 1) % 3]] += 1
    out = np.empty(e, np.uint8)
    for x in range(e):
        if nonmanifold[x]:
            out[x] = 2
        elif count[x] == 0:
            out[x] = 0
        elif count[x] == 2:
            out[x] = 1
        else:
            out[x] = 2
    return out


@nb.njit(cache=True, nogil=True)
def corner_vertices(pos_vstart, vertex_sgid, face_pos, face_sgid):
    """(p, 3) int64 vertex-buffer index of each corner: the D3Dindex lookup.

    ``face_pos`` (p, 3) are position ids, ``face_sgid`` (p,) the faces' ids;
    -1 where a (id, position) pair has no vertex (never, for a valid mesh).
    """
    p = face_pos.shape[0]
    out = np.full((p, 3), -1, np.int64)
    for f in range(p):
        for k in range(3):
            x = face_pos[f, k]
            for i in range(pos_vstart[x], pos_vstart[x + 1]):
                if vertex_sgid[i] == face_sgid[f]:
                    out[f, k] = i
                    break
    return out
