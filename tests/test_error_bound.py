"""Error bounds that hold, measured from outside.

For each mesh, cameras at several views refine until they converge; then
:func:`caveclod.refine.measure.pixel_errors` measures, renderer-free, how far
every original position in view lies from the triangles the camera draws,
in pixels. At a tolerance of t pixels the 99th percentile must stay within
t and the maximum within 1.5 t (1.25 t for points of the drawn surface
against the original): on rough terrain with holes, a range scan with an
open border, holes and a cut-up UV atlas, seam meshes, and the smooth
terrain.

The distance kernels behind the measurement (and the build's own error
measurement) are checked against plainly written references first.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import caveclod
from caveclod.builder.builtin import default_terrain, range_scan, rough_terrain
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.kernels.distance import point_segment_dist2, point_triangle_dist2
from caveclod.kernels.nearest import build_bvh, nearest_dist2
from caveclod.paths import circle, flyover, line, rotate
from caveclod.refine.measure import hidden_part_pixels, hidden_positions, pixel_errors

from meshes import holey_scan, noisy_box, uv_sphere

CASES = {
    "rough": lambda: rough_terrain(64),
    "scan": lambda: range_scan(48),
    "holey_scan": lambda: holey_scan(n=32),
    "terrain": lambda: default_terrain(64),
    "uv_sphere": lambda: uv_sphere((40, 20)),
    "noisy_box": noisy_box,
    # Tiled builds: bounds measured and saturated across the tiles' borders too.
    "rough_tiles4": lambda: rough_terrain(64),
    "scan_tiles4": lambda: range_scan(48),
}


@pytest.fixture(scope="module")
def meshes():
    cache = {}

    def get(name):
        if name not in cache:
            tiles = int(name.rsplit("_tiles", 1)[1]) if "_tiles" in name else None
            cache[name] = build_static_mesh(CASES[name](), tiles=tiles)
        return cache[name]
    return get


def views_of(mesh, tolerance):
    """Terrain: the paper's flyovers and the cache paper's paths. Object:
    an orbit at several distances and heights."""
    lo, hi = mesh.bounds()
    ext = hi - lo
    if ext[2] < max(ext[0], ext[1]) / 3:
        poses = [flyover(lo, hi, c, 2.0 * c) for c in range(4)]
        poses += [circle(lo, hi, 0, 5.0), rotate(lo, hi, 1, 2.0), line(lo, hi, 2, 7.0)]
    else:
        c = (lo + hi) / 2
        r = float(np.linalg.norm(ext))
        poses = []
        for k in range(6):
            angle = 0.7 + 0.9 * k
            eye = c + r * (0.5 + 0.35 * k) * np.array([math.cos(angle), math.sin(angle), 0.25 * (k - 2.5)])
            poses.append((tuple(eye), tuple(c), (0.0, 0.0, 1.0)))
    return [caveclod.View.from_pose(p, tolerance_px=tolerance) for p in poses]


def converged(mesh, view, limit=6):
    cam = mesh.new_camera()
    for _ in range(limit):
        if cam.update(view).operations == 0:
            return cam
    raise AssertionError(f"no convergence in {limit} updates")


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("tolerance", [1.0, 3.0])
def test_screen_space_error_stays_within_the_tolerance(meshes, name, tolerance):
    mesh = meshes(name)
    errors = []
    for view in views_of(mesh, tolerance):
        cam = converged(mesh, view)
        # Hidden parts have nothing drawn to measure against; what they promise instead (every
        # position within half the tolerance of one point) is measured on their own positions.
        hidden = hidden_positions(cam)
        errors.append(pixel_errors(mesh, cam.triangles(), view, points=np.asarray(mesh.positions)[~hidden]))
        assert (hidden_part_pixels(cam, view) < tolerance).all()
    px = np.concatenate(errors)
    assert len(px) > 500, "the views see too little of the mesh to say anything"
    assert np.percentile(px, 99) <= tolerance, f"p99 {np.percentile(px, 99):.3f} px at {tolerance} px"
    assert px.max() <= 1.5 * tolerance, f"max {px.max():.3f} px at {tolerance} px"
    assert (px > 0).any(), "nothing was coarsened: the test would not see a bad bound"



@pytest.fixture(scope="module")
def originals(meshes):
    from caveclod.refine.measure import original_triangles
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = original_triangles(meshes(name))
        return cache[name]
    return get


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("tolerance", [1.0, 3.0])
def test_drawn_surface_stays_within_the_tolerance(meshes, originals, name, tolerance):
    """The other direction (issue 18's two-sided bound): points of the drawn triangles (18 a
    triangle, none of them a point the build measured) against the original surface, max within
    1.25 t. Without the build's measure of it (caveclod.kernels.surfacegap) 7 of these 16 cases
    failed 1.5 t, up to 2.7 t."""
    from caveclod.refine.measure import surface_errors
    mesh = meshes(name)
    errors = [surface_errors(mesh, converged(mesh, view).triangles(), originals(name), view)
              for view in views_of(mesh, tolerance)]
    px = np.concatenate(errors)
    assert len(px) > 500, "the views see too little of the mesh to say anything"
    assert np.percentile(px, 99) <= tolerance, f"p99 {np.percentile(px, 99):.3f} px at {tolerance} px"
    # Issue 18's 1.25 t. Before new edges were measured at more than their midpoints
    # (caveclod.kernels.surfacegap.edge_gap2) the scan reached 1.48 t here; now at most 0.98 t.
    assert px.max() <= 1.25 * tolerance, f"max {px.max():.3f} px at {tolerance} px"
    assert (px > 0.1 * tolerance).any(), "the drawn surface lies on the original: the test would not see a bad bound"


def test_a_lost_corner_is_an_error(meshes):
    """A flat rectangle of one material coarsens by sliding its corners
    along the border: the outline moves while every face stays in the plane,
    so the error must come from the border, not the plane."""
    heights = np.zeros((9, 13))
    mesh = build_static_mesh(caveclod.builder.terrain.heightfield_to_source(heights, materials=np.zeros((8, 12))))
    # (prune=False: from 1e6 away the whole rectangle is under a pixel and would vanish.)
    base = converged(mesh, caveclod.View(eye=(6.0, 4.0, 1e6), target=(6.0, 4.0, 0.0), up=(0, 1, 0), prune=False))
    tri = np.concatenate(list(base.triangles().values()))
    P = np.asarray(mesh.positions, np.float64)
    V = np.asarray(mesh.vertex_positions, np.float64)
    gap = np.sqrt(nearest_dist2(P, V, tri.astype(np.int64), *build_bvh(V, tri.astype(np.int64)))).max()
    roots = np.flatnonzero(np.asarray(mesh.node_parent) < 0)
    root_err = np.asarray(mesh.node_error)[roots[roots >= mesh.n_positions] - mesh.n_positions]
    assert gap > 0.5, "the base mesh should have lost some of the outline"
    assert root_err.max() >= gap


@pytest.mark.parametrize("name", ["rough", "scan", "noisy_box"])
def test_node_errors_cover_the_base_mesh(meshes, name):
    """Every original position lies within the largest root error of the base mesh."""
    mesh = meshes(name)
    base = mesh.new_camera()
    tri = np.concatenate(list(base.triangles().values())).astype(np.int64)
    V = np.asarray(mesh.vertex_positions, np.float64)
    d = np.sqrt(nearest_dist2(np.asarray(mesh.positions, np.float64), V, tri, *build_bvh(V, tri)))
    err = np.asarray(mesh.node_error, np.float64)
    roots = np.flatnonzero(np.asarray(mesh.node_parent) < 0)
    internal = roots[roots >= mesh.n_positions] - mesh.n_positions
    assert d.max() <= err[internal].max() * (1 + 1e-6) + 1e-9


def test_errors_grow_up_every_path(meshes):
    """A parent's error bounds its children's (the runtime relies on it)."""
    mesh = meshes("rough")
    e = mesh.n_positions
    parent = np.asarray(mesh.node_parent)
    err = np.r_[np.zeros(e), np.asarray(mesh.node_error, np.float64)]
    child = np.flatnonzero(parent >= 0)
    assert (err[parent[child]] >= err[child]).all()


@pytest.mark.parametrize("name,tiles", [("rough", 1), ("scan", 1), ("rough_tiles4", 4)])
def test_ring_bounds_hold_the_nodes_beside_each_collapse(name, tiles):
    """Replaying the collapses in node order from the full mesh (the order the build made
    them, tile after tile within a level), the nodes beside each new node are its ring:
    their spheres lie in its sphere grown by the ring's reach, and their errors are at
    most the ring's error, which is at most the node's own (saturation), in the file's
    float32 numbers."""
    from caveclod.refine.reference import ACTIVE, ReferenceCamera
    source = (rough_terrain(20) if name.startswith("rough") else range_scan(16))
    mesh = build_static_mesh(source, tiles=tiles)
    e, m = mesh.n_positions, mesh.n_internal
    sphere = np.asarray(mesh.node_sphere, np.float64)
    err = np.asarray(mesh.node_error, np.float64)
    ring = np.asarray(mesh.node_ring, np.float64)
    assert (ring >= 0).all() and (ring[:, 1] <= err * (1 + 2e-6)).all()
    ref = ReferenceCamera(mesh)
    lo, hi = mesh.bounds()
    ref.update(caveclod.View(eye=tuple(hi + (hi - lo)), target=tuple(0.5 * (lo + hi)), tolerance_px=0.0, cull=False))
    assert ref.n_faces() == mesh.n_faces
    scale = float(np.abs(np.asarray(mesh.positions)).max())
    internal_rings = 0
    for j in range(m):
        s = e + j
        assert ref.collapse_legal(s), f"node {s} cannot be collapsed in node order"
        ref.collapse(s)
        p = ref.position(s)
        beside = {q for f in ref.faces_at[p] for q in ref.faces[f]["pos"]} - {p}
        nodes = [x for x, state in ref.state.items() if state == ACTIVE and ref.position(x) in beside]
        assert len(nodes) == len(beside)
        inner = np.array([x - e for x in nodes if x >= e], np.int64)
        if len(inner) == 0:
            continue
        internal_rings += 1
        assert ring[j, 1] >= err[inner].max()
        assert ring[j, 1] <= err[inner].max() * (1 + 2e-6)
        d = np.linalg.norm(sphere[inner, :3] - sphere[j, :3], axis=1) + sphere[inner, 3]
        assert (d <= sphere[j, 3] + ring[j, 0] + 1e-12 * scale).all(), f"node {s}: a ring sphere sticks out"
    assert internal_rings > m // 4, "too few collapses beside internal nodes: the test would see nothing"


def test_ring_test_keeps_coarse_nodes_from_mixing_with_finer_neighbours():
    """The rough terrain at 320 cells and 1 px: without the ring test a node kept coarse
    beside a neighbour its view split (a mesh the build never measured) put an original
    position 1.29 t from the drawn surface; with it every position stays within t."""
    from caveclod.staticmesh import StaticMesh
    mesh = build_static_mesh(rough_terrain(320))
    without = StaticMesh(arrays={k: v for k, v in mesh.arrays.items() if k != "node_ring"}, materials=mesh.materials)
    tolerance = 1.0
    worst = {}
    for label, m in (("with", mesh), ("without", without)):
        px = np.concatenate([pixel_errors(m, converged(m, view).triangles(), view) for view in views_of(m, tolerance)])
        worst[label] = px.max() / tolerance
    assert worst["without"] > 1.1, f"no mix of ages here to catch ({worst}): the test would not see the ring test"
    assert worst["with"] <= 1.0 + 1e-3, worst


# ---------------------------------------------------------------- distance kernels

coord = st.floats(-10, 10, allow_nan=False, width=64)
point3 = st.tuples(coord, coord, coord)


def reference_point_triangle(p, a, b, c) -> float:
    """Nearest point by cases: inside the projection, else the nearest edge."""
    p, a, b, c = (np.asarray(v, float) for v in (p, a, b, c))
    n = np.cross(b - a, c - a)
    edges = min(reference_point_segment(p, a, b), reference_point_segment(p, b, c),
                reference_point_segment(p, c, a))
    if np.dot(n, n) < 1e-18:
        return edges
    q = p - np.dot(p - a, n) / np.dot(n, n) * n             # projection on the plane
    inside = all(np.dot(np.cross(y - x, q - x), n) >= 0 for x, y in ((a, b), (b, c), (c, a)))
    return float(np.dot(p - q, p - q)) if inside else edges


def reference_point_segment(p, a, b) -> float:
    p, a, b = (np.asarray(v, float) for v in (p, a, b))
    ab = b - a
    t = 0.0 if np.dot(ab, ab) == 0 else min(1.0, max(0.0, np.dot(p - a, ab) / np.dot(ab, ab)))
    d = p - (a + t * ab)
    return float(np.dot(d, d))


@settings(max_examples=300, deadline=None)
@given(point3, point3, point3, point3)
def test_point_triangle_distance_matches_the_reference(p, a, b, c):
    got = point_triangle_dist2(*p, *a, *b, *c)
    want = reference_point_triangle(p, a, b, c)
    assert math.isclose(got, want, rel_tol=1e-6, abs_tol=1e-6)


@settings(max_examples=100, deadline=None)
@given(point3, point3, point3)
def test_point_segment_distance_matches_the_reference(p, a, b):
    assert math.isclose(point_segment_dist2(*p, *a, *b), reference_point_segment(p, a, b), rel_tol=1e-9,
                        abs_tol=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_bvh_nearest_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(200, 3)) * [10, 10, 1]
    T = rng.integers(0, 200, (300, 3))
    T = T[(T[:, 0] != T[:, 1]) & (T[:, 1] != T[:, 2]) & (T[:, 0] != T[:, 2])]
    points = rng.normal(size=(100, 3)) * 12
    got = nearest_dist2(points, V, T, *build_bvh(V, T))
    want = [min(point_triangle_dist2(*p, *V[t[0]], *V[t[1]], *V[t[2]]) for t in T) for p in points]
    np.testing.assert_allclose(got, want, rtol=1e-12)


# -- forced splits (issue 18's measure) --------------------------------------------------

def test_needs_detail_is_the_refinement_criterion_over_many_nodes(terrain_path):
    """measure.needs_detail agrees node for node with ReferenceCamera.need_refine (cull and back-face on and off)."""
    from caveclod.refine.measure import needs_detail
    from caveclod.refine.reference import ReferenceCamera
    mesh = caveclod.load(terrain_path)
    lo, hi = mesh.bounds()
    ref = ReferenceCamera(mesh)
    nodes = np.arange(mesh.n_positions, mesh.n_nodes)
    for t in range(4):
        p = flyover(lo, hi, t, 7.0 * t)
        for cull, backface, tol in ((True, False, 1.0), (True, True, 2.0), (False, False, 0.5)):
            view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=800, height=600, tolerance_px=tol,
                                 cull=cull, backface=backface)
            ref.set_view(view)
            got = needs_detail(mesh, nodes, view)
            want = np.array([ref.need_refine(int(x)) for x in nodes])
            assert np.array_equal(got, want), (t, cull, backface, int((got != want).sum()))


def test_forced_splits_counts_what_the_view_does_not_ask_for(terrain_path):
    from caveclod.refine.measure import forced_splits
    mesh = caveclod.load(terrain_path)
    lo, hi = mesh.bounds()
    p = flyover(lo, hi, 0, 3.0)
    cam = mesh.new_camera()
    view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=800, height=600, tolerance_px=1.0)
    cam.update(view)
    r = forced_splits(cam, view)
    assert 0 < r["split_nodes"] and 0 <= r["forced_nodes"] <= r["split_nodes"]
    assert r["faces"] == cam.n_faces and r["forced_faces"] == 2 * r["forced_nodes"]
    # Everything asked for (no culling, tolerance 0): no split is forced.
    everything = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=800, height=600, tolerance_px=0.0,
                               cull=False)
    cam.update(everything)
    assert forced_splits(cam, everything)["forced_nodes"] == 0
    # A view far away asks for nothing: whatever is still split is forced or stuck, and collapses undo it.
    far = caveclod.View(eye=(lo[0], lo[1], hi[2] + 1e7), target=tuple(0.5 * (lo + hi)), up=(0, 1, 0),
                        width=800, height=600, tolerance_px=1.0)
    cam.update(far)
    assert forced_splits(cam, far)["forced_nodes"] == forced_splits(cam, far)["split_nodes"]


def test_surface_errors_measure_the_drawn_surface_against_the_original(terrain_path):
    """The LOD -> original direction: zero on the full mesh; on a coarse camera, the sampled points'
    distances to the original surface, as a brute-force search over every original face finds them."""
    from caveclod.refine.measure import SURFACE_SAMPLES, original_triangles, surface_errors
    from caveclod.refine.view import P_EYE, P_KAPPA
    mesh = caveclod.load(terrain_path)
    lo, hi = mesh.bounds()
    original = original_triangles(mesh)
    assert len(original) == mesh.n_faces
    p = flyover(lo, hi, 1, 4.0)
    view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=640, height=360, tolerance_px=4.0)
    assert surface_errors(mesh, original, original, view).max() < 1e-6
    cam = mesh.new_camera()
    cam.update(view)
    px = surface_errors(mesh, cam.triangles(), original, view)
    assert len(px) > 0 and np.isfinite(px).all() and px.max() > 0
    # Brute force on the samples of a few drawn triangles wholly in view.
    V = np.asarray(mesh.vertex_positions, np.float64)
    vp = view.params()
    planes = vp[3:23].reshape(5, 4)
    lod = np.concatenate(list(cam.triangles().values()))
    samples = np.einsum("sc,kcd->ksd", SURFACE_SAMPLES, V[lod])                      # (k, 18, 3)
    in_view = ((samples @ planes[:, :3].T + planes[:, 3]) >= 0).all(axis=(1, 2))
    chosen = lod[in_view][:8]
    assert len(chosen) == 8
    got = surface_errors(mesh, chosen, original, view)
    want = []
    for q in np.einsum("sc,kcd->ksd", SURFACE_SAMPLES, V[chosen]).reshape(-1, 3):
        d2 = min(point_triangle_dist2(*q, *V[a], *V[b], *V[c]) for a, b, c in original)
        want.append(np.sqrt(d2) * vp[P_KAPPA] / np.linalg.norm(q - vp[P_EYE:P_EYE + 3]))
    assert len(want) == 8 * len(SURFACE_SAMPLES) == 144 and max(want) > 0
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)
