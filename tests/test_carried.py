"""Carried points after a whole build: the measured half of every node's error bound.

Each position a collapse removes is carried by one live face, and each
collapse hands the points of the faces it reshaped to faces of its new fan
(:mod:`caveclod.kernels.carried`), the first within the node's error
if any, else the nearest. Whatever face a point ends on, the build's bound
must hold for it: its distance to that face is at most the error of a node
at one of the face's corners (the node that last put it there is that
node or one of its descendants, and errors only grow up the tree). Checked
here from the collapse state the build leaves, against the exact
point-triangle distance, on rough terrain with holes, a range scan (sharp
borders, whose points are measured against boundary edges: a triangle is
never farther than its edges) and a tiled build.
"""

from __future__ import annotations

import numpy as np
import pytest

import caveclod.builder.hierarchy as hierarchy
from caveclod.builder.builtin import range_scan, rough_terrain
from caveclod.kernels.carried import NEXT
from caveclod.kernels.distance import point_triangle_dist2

from meshes import holey_scan


def _build_keeping_state(monkeypatch, source, tiles=None):
    """Build ``source``; returns the collapse state (:class:`hierarchy._CollapseState`) as the build left it."""
    kept = []
    one_pass = hierarchy._one_pass          # called for every pass of every level

    def keeping(st, *args, **kwargs):
        kept.append(st)
        return one_pass(st, *args, **kwargs)

    monkeypatch.setattr(hierarchy, "_one_pass", keeping)
    hierarchy.build_static_mesh(source, tiles=tiles, workers=2)
    assert kept, "the build collapsed nothing"
    return kept[-1]


def _carried(st):
    """{point: face} of every carried point, each walked once (a cycle or a repeat fails)."""
    carried = {}
    for f in np.flatnonzero(st.pt[0] != -1):
        x = int(st.pt[0][f])
        for _ in range(len(st.P) + 1):
            if x == -1:
                break
            assert x not in carried, f"point {x} carried by faces {carried[x]} and {f}"
            carried[x] = int(f)
            x = int(st.pt[1][x, NEXT])
        assert x == -1, f"face {f}'s list of points does not end"
    return carried


@pytest.mark.parametrize("name, source, tiles", [
    ("rough", lambda: rough_terrain(40), None),
    ("rough in 4 x 4 tiles", lambda: rough_terrain(48), 4),
    ("scan", lambda: range_scan(36), None),
    ("holey scan", lambda: holey_scan(n=24), None),
])
def test_every_removed_position_lies_within_its_face_s_bound(monkeypatch, name, source, tiles):
    st = _build_keeping_state(monkeypatch, source(), tiles)
    e = len(st.P)
    carried = _carried(st)
    removed = set(np.flatnonzero(st.cur_node == -1).tolist())
    assert set(carried) == removed, "every removed position is carried, and only those"
    assert all(st.alive[f] for f in set(carried.values())), "points are carried by live faces only"

    def bound(f):
        nodes = st.cur_node[st.F[f]]
        assert (nodes >= 0).all(), f"live face {f} has a removed corner"
        return max(float(st.err[n - e]) if n >= e else 0.0 for n in nodes)

    for x, f in carried.items():
        a, b, c = (st.P[k] for k in st.F[f])
        d = np.sqrt(point_triangle_dist2(*st.P[x], *a, *b, *c))
        slack = bound(f) + 1e-9 * (1.0 + np.abs(st.P).max())
        assert d <= slack, f"{name}: point {x} lies {d:.6g} from face {f}, whose corners' nodes bound {bound(f):.6g}"
    assert len(carried) > e // 2, f"{name}: only {len(carried)} of {e} positions were collapsed"
