"""The build's measure of the other direction: coarse faces against the original surface.

:mod:`caveclod.kernels.surfacegap` walks from a near original position to
the original faces nearest to a sample. Checked here against an exhaustive
search (a BVH over every original face, itself checked against brute force
in test_error_bound): never below the true distance (a bound must not be
too small), and equal to it for nearly every sample of a drawn coarse face.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import caveclod
from caveclod.builder.builtin import range_scan, rough_terrain
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.builder.topology import face_neighbours
from caveclod.kernels.carried import new_store
from caveclod.kernels.nearest import build_bvh, nearest_dist2
from caveclod.kernels.surfacegap import _piece_bound2, edge_gap2, edge_stack, sample_gap2, star_lists
from caveclod.paths import flyover

from meshes import holey_scan


def _surface(P, FP):
    """(star_start, star_faces, face_nbrs, exact): what sample_gap2 reads, and the exhaustive answer."""
    FP = np.ascontiguousarray(FP, np.int32)
    start, faces = star_lists(FP, len(P))
    T = FP.astype(np.int64)
    bvh = build_bvh(P, T)
    return start, faces, face_neighbours(FP, len(P)).nbrs, lambda S: nearest_dist2(S, P, T, *bvh)


def _gaps(P, FP, S, starts, worst=0.0):
    start, faces, nbrs, _ = _surface(P, FP)
    pt_head, pt = new_store(len(FP), len(P))
    return np.array([sample_gap2(s[0], s[1], s[2], int(q), 0, P, pt_head, pt, np.ascontiguousarray(FP, np.int32),
                                 nbrs, start, faces, worst) for s, q in zip(S, starts)])


def test_star_lists_hold_every_face_around_each_position():
    FP = np.array([[0, 1, 2], [2, 1, 3], [3, 4, 2], [5, 6, 7]], np.int32)
    start, faces = star_lists(FP, 9)
    want = {x: sorted(f for f in range(len(FP)) if x in FP[f]) for x in range(9)}
    assert {x: sorted(faces[start[x]:start[x + 1]].tolist()) for x in range(9)} == want
    assert start[-1] == FP.size


@pytest.mark.parametrize("name, source", [("rough", lambda: rough_terrain(48)), ("scan", lambda: range_scan(40)),
                                          ("holey_scan", lambda: holey_scan(n=24))])
def test_samples_of_drawn_faces_are_measured_exactly_or_larger(name, source):
    """Centroids and edge midpoints of what a coarse camera draws, walked to from a corner: the
    measured distance is never below the exhaustive one and equals it for at least 99 %."""
    src = source()
    mesh = build_static_mesh(src)
    P = np.ascontiguousarray(mesh.positions, np.float64)
    st_ = np.asarray(mesh.pos_vstart)
    vpos = np.repeat(np.arange(len(st_) - 1), np.diff(st_))          # vertex -> position
    FP = np.ascontiguousarray(src.face_positions, np.int32)
    lo, hi = mesh.bounds()
    p = flyover(lo, hi, 1, 3.0)
    cam = mesh.new_camera()
    cam.update(caveclod.View(eye=p.eye, target=p.target, up=p.up, tolerance_px=4.0))
    tris = vpos[np.concatenate([np.asarray(t).reshape(-1, 3) for t in cam.triangles().values()])]
    assert len(tris) < len(FP) // 2, "the camera should draw a coarse mesh"
    S = np.concatenate([P[tris].mean(axis=1), (P[tris] + P[np.roll(tris, 1, axis=1)]).reshape(-1, 3) / 2])
    starts = np.concatenate([tris[:, 0], tris.ravel()])
    got = _gaps(P, FP, S, starts)
    exact = _surface(P, FP)[3](S)
    assert (got >= exact * (1 - 1e-9) - 1e-12).all(), "a measured gap below the true distance"
    same = np.isclose(got, exact, rtol=1e-6, atol=1e-12 * float(np.abs(P).max()) ** 2)
    assert same.mean() >= 0.99, f"{name}: only {same.mean():.3%} measured exactly"
    assert np.sqrt(exact).max() > 0, "the coarse faces lie on the original: nothing to measure"


def test_a_sample_within_worst_stops_early_and_returns_worst():
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float64)
    FP = np.array([[0, 1, 2], [2, 1, 3]], np.int32)
    s = np.array([[0.5, 0.5, 2.0]])
    assert _gaps(P, FP, s, [0])[0] == pytest.approx(4.0)
    assert _gaps(P, FP, s, [0], worst=9.0)[0] == 9.0         # squared: 3 > 2 away


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), holes=st.floats(0.0, 0.3))
def test_never_below_the_true_distance_on_rough_surfaces_with_holes(seed, holes):
    """Random heightfields with random faces removed, samples anywhere near them, walks from any
    position: whatever the walk reaches, the distance is never too small."""
    rng = np.random.default_rng(seed)
    n = 9
    x, y = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64))
    P = np.c_[x.ravel(), y.ravel(), rng.normal(0.0, rng.uniform(0.1, 3.0), n * n)]
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    FP = np.concatenate([np.c_[i, i + 1, i + n + 1], np.c_[i, i + n + 1, i + n]]).astype(np.int32)
    FP = FP[rng.random(len(FP)) >= holes]
    if len(FP) == 0:
        return
    S = rng.uniform([-1, -1, -4], [n, n, 4], (64, 3))
    starts = rng.choice(np.unique(FP), len(S))
    got = _gaps(P, FP, S, starts)
    exact = _surface(P, FP)[3](S)
    assert (got >= exact * (1 - 1e-9) - 1e-12).all()


def _heightfield(z):
    """(P, FP): the grid of heights ``z`` (n, n), one unit apart, two triangles a cell."""
    n = z.shape[0]
    x, y = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64))
    P = np.c_[x.ravel(), y.ravel(), z.ravel()]
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    FP = np.concatenate([np.c_[i, i + 1, i + n + 1], np.c_[i, i + n + 1, i + n]]).astype(np.int32)
    return P, FP


def _edge_gaps(P, FP, edges, worst=0.0):
    start, faces, nbrs, _ = _surface(P, FP)
    pt_head, pt = new_store(len(FP), len(P))
    pieces, ends = edge_stack()
    return np.array([edge_gap2(int(t), int(x), 0, P, pt_head, pt, FP, nbrs, start, faces, worst, pieces, ends)
                     for t, x in edges])


def _along_edges(P, edges, w):
    """(k, len(w), 3) points a fraction w of the way along each edge."""
    a, b = P[edges[:, 0]], P[edges[:, 1]]
    return a[:, None] + np.asarray(w)[None, :, None] * (b - a)[:, None]


def test_a_ridge_near_an_end_of_an_edge_is_found():
    """A straight coarse edge over flat ground passes under a ridge a fifth of the way along: its
    midpoint lies on the original surface (gap 0, all the build used to measure), the largest gap
    sits near the ridge. Regression: the rough terrain drew edges like it at 1.3-1.4 t."""
    z = np.zeros((11, 11))
    z[:, 1:4] = [1.5, 3.0, 1.5]                       # a ridge along x = 2
    P, FP = _heightfield(z)
    edge = np.array([[5 * 11 + 0, 5 * 11 + 10]])      # from (0, 5) to (10, 5), height 0
    dense = np.sqrt(_surface(P, FP)[3](_along_edges(P, edge, np.linspace(0, 1, 401))[0])).max()
    midpoint = np.sqrt(_gaps(P, FP, _along_edges(P, edge, [0.5])[0], edge[:, 0]))[0]
    assert midpoint == pytest.approx(0.0, abs=1e-12)
    got = np.sqrt(_edge_gaps(P, FP, edge))[0]
    assert got >= 0.7 * dense, f"found {got:.3f} of the edge's largest gap {dense:.3f}"


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), holes=st.floats(0.0, 0.3))
def test_edges_are_measured_at_their_quarters_at_least(seed, holes):
    """Random rough heightfields with holes, edges between any two positions: the gap reported
    for an edge is at least the true gap at its quarter, half and three-quarter points (each is
    either measured or covered by a piece's bound), and a piece's bound is at least the true gap
    everywhere on the piece (the convexity it rests on)."""
    rng = np.random.default_rng(seed)
    P, FP = _heightfield(rng.normal(0.0, rng.uniform(0.1, 3.0), (9, 9)))
    FP = FP[rng.random(len(FP)) >= holes]
    if len(FP) == 0:
        return
    used = np.unique(FP)
    edges = rng.choice(used, (24, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    exact = _surface(P, FP)[3]
    got = _edge_gaps(P, FP, edges)
    want = exact(_along_edges(P, edges, [0.25, 0.5, 0.75]).reshape(-1, 3)).reshape(-1, 3).max(axis=1)
    assert (got >= want * (1 - 1e-9) - 1e-12).all()
    start, faces, _, _ = _surface(P, FP)
    w = np.linspace(0.0, 1.0, 33)
    for t, x in edges[:8]:
        wa, wb = np.sort(rng.uniform(0, 1, 2))
        ga = -1 if rng.random() < 0.3 else int(rng.integers(len(FP)))
        gb = -1 if rng.random() < 0.3 else int(rng.integers(len(FP)))
        wa, wb = (0.0 if ga == -1 else wa), (1.0 if gb == -1 else wb)
        bound = _piece_bound2(wa, wb, ga, gb, int(t), int(x), P, FP, start, faces)
        inside = _along_edges(P, np.array([[t, x]]), wa + w * (wb - wa))[0]
        assert bound >= exact(inside).max() * (1 - 1e-9) - 1e-12
