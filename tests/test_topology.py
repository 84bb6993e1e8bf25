"""The topology kernel against a slow, obviously correct reference.

Random meshes over few positions make every case the kernel separates:
borders, manifold pairs, edges used twice in the same direction, edges of
three or more faces (cut), sheets touching at a point, and positions of
more than 32 half-edges (the sorted path).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from caveclod.builder.builtin import range_scan, rough_terrain
from caveclod.builder.topology import face_neighbours


def reference_topology(faces: np.ndarray, e: int) -> tuple:
    """(nbrs, edge_faces, nonmanifold, border) from a dictionary of edges and a
    walk over each position's faces, as docs and the Topology docstring say."""
    p = len(faces)
    edges = defaultdict(list)
    for f in range(p):
        for k in range(3):
            a, b = int(faces[f, k]), int(faces[f, (k + 1) % 3])
            edges[min(a, b), max(a, b)].append((f, k))
    nbrs = np.full((p, 3), -1, np.int32)
    edge_faces = np.zeros((p, 3), np.uint8)
    for halves in edges.values():
        for f, k in halves:
            edge_faces[f, k] = min(len(halves), 255)
        if len(halves) == 2:
            (f, k), (g, j) = halves
            if faces[f, k] == faces[g, (j + 1) % 3]:            # opposite directions
                nbrs[f, k], nbrs[g, j] = g, f
    nonmanifold = np.zeros(e, bool)
    border = np.zeros(e, bool)
    for f in range(p):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            if nbrs[f, k] < 0:
                border[a] = border[b] = True
                if edge_faces[f, k] >= 2:
                    nonmanifold[a] = nonmanifold[b] = True
    # More than one fan: the faces around x, joined across the edges at x, fall apart.
    around = defaultdict(list)
    for f in range(p):
        for k in range(3):
            around[int(faces[f, k])].append(f)
    for x, fs in around.items():
        reached, todo = {fs[0]}, [fs[0]]
        while todo:
            f = todo.pop()
            for k in range(3):
                if x in (faces[f, k], faces[f, (k + 1) % 3]) and nbrs[f, k] >= 0 and nbrs[f, k] not in reached:
                    reached.add(int(nbrs[f, k]))
                    todo.append(int(nbrs[f, k]))
        if len(reached) != len(fs):
            nonmanifold[x] = True
    return nbrs, edge_faces, nonmanifold, border


def assert_same_topology(faces: np.ndarray, e: int) -> None:
    topo = face_neighbours(faces, e)
    nbrs, edge_faces, nonmanifold, border = reference_topology(faces, e)
    assert np.array_equal(topo.nbrs, nbrs)
    assert np.array_equal(topo.edge_faces, edge_faces)
    assert np.array_equal(topo.nonmanifold, nonmanifold)
    assert np.array_equal(topo.border, border)


@st.composite
def tangled_meshes(draw):
    """(faces (p, 3) int32, e): random triangles over few positions, plus a fan of
    up to 60 faces around position 0 (past the kernel's 32 half-edges)."""
    e = draw(st.integers(4, 14))
    corners = st.lists(st.integers(0, e - 1), min_size=3, max_size=3, unique=True)
    faces = draw(st.lists(corners, min_size=1, max_size=40))
    fan = draw(st.integers(0, 60))
    for i in range(fan):
        a, b = 1 + i % (e - 1), 1 + (i + 1) % (e - 1)
        if a != b:
            faces.append([0, a, b])
    return np.array(faces, np.int32), e


@settings(max_examples=300, deadline=None)
@given(tangled_meshes())
def test_the_kernel_finds_what_the_reference_finds(mesh):
    assert_same_topology(*mesh)


@pytest.mark.parametrize("make", [lambda: rough_terrain(40), lambda: range_scan(40)], ids=["rough", "scan"])
def test_real_like_meshes_match_the_reference(make):
    source = make()                   # no-data holes, open scan borders, islands
    assert_same_topology(source.face_positions.astype(np.int32), len(source.positions))


def test_a_closed_fan_of_many_faces_is_manifold():
    """A cone of 100 faces around its apex: every half-edge at the apex meets its
    twin through the sorted path, nothing is cut."""
    n = 100
    ring = np.arange(1, n + 1)
    faces = np.c_[np.zeros(n, np.int64), ring, np.roll(ring, -1)].astype(np.int32)
    topo = face_neighbours(faces, n + 1)
    assert (topo.nbrs[:, 0] >= 0).all() and (topo.nbrs[:, 2] >= 0).all()
    assert not topo.nonmanifold.any()
    assert_same_topology(faces, n + 1)
