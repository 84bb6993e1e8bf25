"""Geomorph targets: the vertex each vertex-buffer entry grows out of and shrinks into.

Splitting node ``x`` (children ``t`` and ``u``) brings in the position of
``u`` (the leaf at the end of ``u``'s chain of ``t`` children) and moves the
faces of ``x``'s wedge from ``fl_u`` round to ``fr_u`` onto it; each moved
corner takes the vertex of the same surface group at the new position
(:func:`caveclod.kernels.refine.lookup_vertex`). Collapsing ``x`` undoes it.
So the vertex that appears, ``w`` at position ``P_u`` in surface group
``g``, replaces the vertex of group ``g`` at ``x``'s position: that vertex is
``w``'s morph target. A client that starts ``w`` at its target's position
and moves it home over a few frames shows the split as a smooth change of
shape instead of a pop (Hoppe's geomorphs), and the reverse for a collapse;
the targets are static, so they travel once, with the vertex buffer.
"""

from __future__ import annotations

import numpy as np


def morph_targets(mesh) -> np.ndarray:
    """(d,) uint32: each vertex-buffer entry's morph target (its own index where it has none).

    ``mesh`` is a :class:`caveclod.StaticMesh`. A vertex has no target when
    its position is the representative of a root (it is in the base mesh
    and never goes). Where the target position has no vertex of its surface
    group, the position's first vertex is the target: what morphs is the
    position, and all vertices of a position morph together.
    """
    a = mesh.arrays
    e = mesh.n_positions
    parent = np.asarray(a["node_parent"], np.int64)
    links = np.asarray(a["node_links"], np.int64)
    npos = np.asarray(a["node_position"], np.int64)
    n = len(parent)
    nodes = np.arange(n)
    # A node that is its parent's t child keeps its parent's position: climb
    # through those to the node whose split brings the position in (a u child).
    has_parent = parent >= 0
    is_u = np.zeros(n, bool)
    is_u[has_parent] = links[parent[has_parent] - e, 1] == nodes[has_parent]
    up = np.where(has_parent & ~is_u, parent, nodes)
    for _ in range(64):                       # pointer doubling: log2(depth) rounds
        nxt = up[up]
        if np.array_equal(nxt, up):
            break
        up = nxt
    top = up[:e]
    p = parent[top]
    target_pos = np.arange(e)
    inner = p >= 0
    target_pos[inner] = npos[p[inner] - e]    # (a mesh of no collapses has no node_position to read)
    # Each vertex: the vertex of its surface group at the target position.
    vstart = np.asarray(a["pos_vstart"], np.int64)
    sgid = np.asarray(a["vertex_sgid"])
    d = len(sgid)
    own_pos = mesh.vertex_position_ids
    tp = target_pos[own_pos]
    lo, hi = vstart[tp], vstart[tp + 1]
    target = np.arange(d, dtype=np.int64)
    found = tp == own_pos                     # no target: itself
    for k in range(int((hi - lo).max(initial=0))):
        cand = lo + k
        hit = ~found & (cand < hi)
        hit[hit] = sgid[cand[hit]] == sgid[hit]
        target[hit] = cand[hit]
        found |= hit
    # No vertex of its group there (a group the parent's faces never had): the position's first vertex,
    # so that the position still morphs as one (its vertices must move together, or seams would open).
    rest = ~found & (hi > lo)
    target[rest] = lo[rest]
    return target.astype(np.uint32)
