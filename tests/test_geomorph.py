"""Geomorphs: morph targets from the hierarchy, the client's ramps, and the renderer drawing them.

The property that matters: at the instant of a frame that splits, the
surface drawn with the new vertices at their ramps' start is the surface
drawn just before (the split does not show), and once every ramp is over the
surface is exactly the mesh the server sent.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import caveclod
from caveclod.client.geomorph import Geomorphs, pixels_per_unit
from caveclod.kernels.nearest import build_bvh, nearest_dist2
from caveclod.refine.morphtargets import morph_targets
from caveclod.wire import Surface

import meshes

# Random flights: a rough terrain, and a debris field whose small parts vanish and come back.
_RANDOM_MESHES = {name: caveclod.build(name, size=size) for name, size in (("rough", 24), ("debris", 2))}
_RANDOM_TARGETS = {name: morph_targets(mesh) for name, mesh in _RANDOM_MESHES.items()}

SAMPLES = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]], np.float64) / np.array([[3], [6], [6], [6]])


def _keyframe(cam) -> list:
    """Every buffer whole, as the server sends a keyframe (and tells the camera it went out)."""
    out = [Surface(m, int(cam.cnt[m]), np.arange(cam.cnt[m]), cam.index_buffer(m).copy())
           for m in range(cam.n_materials)]
    cam.mark_sent()
    return out


def _drawn(cam, morphs, now):
    """(V (d, 3) float64 drawn positions, T (k, 3) int64 drawn triangles) of the camera at ``now``."""
    if morphs is None:
        tris = [np.asarray(t, np.int64).reshape(-1, 3) for t in cam.triangles().values()]
        return np.asarray(cam.mesh.vertex_positions, np.float64), np.concatenate(tris)
    tris = np.concatenate([morphs.display(m).astype(np.int64) for m in range(morphs.materials)])
    return morphs.drawn_positions(now), tris


def _distance(a, b) -> float:
    """Largest distance from sample points of surface ``a`` to surface ``b``."""
    (Va, Ta), (Vb, Tb) = a, b
    pts = np.einsum("sc,kcd->ksd", SAMPLES, Va[Ta]).reshape(-1, 3)
    return float(np.sqrt(nearest_dist2(pts, Vb, Tb, *build_bvh(Vb, Tb)).max()))


def _zoom(mesh, k: int, frames: int):
    """Views flying straight down towards the mesh: refinement only splits."""
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    ext = float(np.linalg.norm(hi - lo))
    for f in range(frames):
        eye = centre + np.array([0.3, -0.4, 1.0]) * ext * (3.0 - 2.6 * f / frames)
        yield caveclod.View(eye=tuple(eye), target=tuple(centre), up=(0.0, 0.0, 1.0), width=640, height=480,
                            tolerance_px=2.0, cull=False)


def _surfaces(delta) -> list:
    return [Surface(m, d.count, d.slots, d.tris) for m, d in delta.surfaces.items()]


def _mesh(source):
    if source == "sphere":
        return caveclod.build(meshes.uv_sphere(count=(48, 24)))
    return caveclod.build(source, size=48)


@pytest.mark.parametrize("source", ["rough", "scan", "sphere"])
def test_a_split_starts_inside_the_surface_drawn_before_and_ends_at_the_mesh_sent(source):
    mesh = _mesh(source)
    ext = float(np.linalg.norm(np.ptp(mesh.vertex_positions, axis=0)))
    cam = mesh.new_camera()
    morphs = Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration=0.5)
    morphs.apply(_keyframe(cam), True, 0.0)
    grown = 0
    for f, view in enumerate(_zoom(mesh, 0, 24)):
        now = f * 0.1                                   # a frame every 0.1 s: several morphs overlap
        morphs.tick(now)
        before = _drawn(cam, morphs, now)
        morphs.apply(_surfaces(cam.update(view)), False, now)
        after = _drawn(cam, morphs, now)
        grown += len(morphs.active)
        # The new triangles lie in the old surface at the frame's instant, and the old in the new.
        assert _distance(after, before) <= 1e-5 * ext and _distance(before, after) <= 1e-5 * ext, f
    assert grown > 100, "the zoom must split"
    # Every morph over: the drawn surface is the mesh the server sent, vertex for vertex.
    morphs.tick(now + 0.5)
    assert not morphs.active
    for m in range(cam.n_materials):
        assert np.array_equal(morphs.display(m), cam.index_buffer(m))
    assert np.array_equal(morphs.drawn_positions(now + 0.5), mesh.vertex_positions.astype(np.float64))


def test_morphs_at_a_speed_last_their_path_on_screen():
    """With a speed, a morph takes its path's length on screen (from the camera look_from gave, at
    the nearer end) over the speed, at most the duration; the new surface still starts in the old one,
    and once the longest morph is over the display is the mesh sent."""
    mesh = _mesh("rough")
    ext = float(np.linalg.norm(np.ptp(mesh.vertex_positions, axis=0)))
    cam = mesh.new_camera()
    duration, speed = 1.5, 30.0          # some paths longer than 45 px, whose morphs the duration caps
    morphs = Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration, speed=speed)
    morphs.apply(_keyframe(cam), True, 0.0)
    spans = []
    for f, view in enumerate(_zoom(mesh, 0, 24)):
        now = f * 0.1
        kappa = pixels_per_unit(view.height, view.fov_y)
        morphs.tick(now)
        before = _drawn(cam, morphs, now)
        started = {p: morphs.point_at(p, now) for p in morphs.active}
        morphs.look_from(view.eye, kappa)
        morphs.apply(_surfaces(cam.update(view)), False, now)
        assert _distance(_drawn(cam, morphs, now), before) <= 1e-5 * ext, f
        for p, m in morphs.active.items():
            if m.t0 != now or m.start is None or p in started:
                continue
            a = morphs.point_at(m.start, now)
            b = morphs.positions[morphs._members[morphs._start[p]]].astype(np.float64)
            eye = np.asarray(view.eye, np.float64)
            pixels = np.linalg.norm(b - a) * kappa / min(np.linalg.norm(a - eye), np.linalg.norm(b - eye))
            assert m.span == pytest.approx(min(duration, max(pixels / speed, 1e-3)), rel=1e-9)
            spans.append(m.span)
    assert len(spans) > 100 and min(spans) < duration / 2 and max(spans) == duration, "morphs of many lengths"
    end = max(m.t0 + m.span for m in morphs.active.values())
    morphs.tick(end)
    assert not morphs.active
    for m in range(cam.n_materials):
        assert np.array_equal(morphs.display(m), cam.index_buffer(m))
    with pytest.raises(ValueError, match="speed"):
        Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration, speed=0.0)


@pytest.mark.parametrize("source", ["rough", "scan"])
def test_a_flight_with_collapses_jumps_less_and_ends_at_the_mesh_sent(source):
    """Splits and collapses: the display is always made of valid triangles, the morphs' copy of the
    buffers is the camera's, the surface jumps far less at frames than without morphs, and when the
    morphs are over the display is the camera's buffers exactly."""
    from caveclod.paths import flyover
    mesh = _mesh(source)
    lo, hi = mesh.bounds()
    jumps = {}
    for duration in (None, 0.3):
        cam = mesh.new_camera()
        morphs = None if duration is None else Geomorphs(mesh.vertex_positions, morph_targets(mesh),
                                                         cam.n_materials, duration)
        if morphs is not None:
            morphs.apply(_keyframe(cam), True, 0.0)
        worst = []
        for f in range(90):
            now = f / 30
            # prune=False: the scan's small pieces would vanish whole (unmorphed, under the tolerance or
            # out of view), and this measure of jumps counts the whole mesh, seen or not.
            view = caveclod.View.from_pose(flyover(lo, hi, 0, f / 1.5), tolerance_px=2.0, prune=False)
            if morphs is not None:
                morphs.tick(now)
            before = _drawn(cam, morphs, now)
            delta = cam.update(view)
            if morphs is not None:
                morphs.apply(_surfaces(delta), False, now)
                for m in range(cam.n_materials):
                    assert np.array_equal(morphs.rows[m], cam.index_buffer(m))
                    shown = morphs.display(m)
                    assert len(shown) >= cam.cnt[m] and (shown < len(mesh.vertex_positions)).all()
            after = _drawn(cam, morphs, now)
            worst.append(max(_distance(after, before), _distance(before, after)))
        jumps[duration] = np.asarray(worst)
        if morphs is not None:
            morphs.tick(now + duration)
            assert not morphs.active
            for m in range(cam.n_materials):
                assert np.array_equal(morphs.display(m), cam.index_buffer(m))
    plain, morphed = jumps[None], jumps[0.3]
    assert plain.max() > 0, "the flight must change the mesh"
    assert morphed.max() <= 0.5 * plain.max() and np.percentile(morphed, 90) <= 0.5 * np.percentile(plain, 90)


def _pieces(surfaces: list, rng) -> list:
    """``surfaces`` cut into row ranges, as a frame larger than a part arrives (caveclod.frames.frame_parts):
    each piece a Surface of its own with the buffer's count."""
    out = []
    for s in surfaces:
        k = len(s.slots)
        cuts = sorted(set(rng.integers(0, k + 1, 2).tolist()) | {0, k}) if k else [0, 0]
        for a, b in zip(cuts[:-1], cuts[1:]):
            out.append(Surface(s.material, s.count, np.asarray(s.slots)[a:b], np.asarray(s.tris)[a:b]))
    return out


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_frames_cut_into_parts_morph_as_whole_frames(seed):
    """A frame (a keyframe above all) larger than a frame part reaches the client as several pieces of
    one material's buffer: fed the pieces, the geomorphs draw what they draw fed the whole surfaces, step
    for step. (Fed a keyframe in pieces, each piece used to replace the material's buffer: a 4-camera
    flight over a 500,000-triangle mesh with 8 materials drew a GPU buffer unlike the client's.)"""
    from caveclod.paths import flyover
    rng = np.random.default_rng(seed)
    mesh = _RANDOM_MESHES["rough"]
    lo, hi = mesh.bounds()
    targets = _RANDOM_TARGETS["rough"]
    cam = mesh.new_camera()
    whole = Geomorphs(mesh.vertex_positions, targets, cam.n_materials, 0.3)
    cut = Geomorphs(mesh.vertex_positions, targets, cam.n_materials, 0.3)
    for f in range(40):
        now = f / 30
        view = caveclod.View.from_pose(flyover(lo, hi, 0, f / 3), width=320, height=240, tolerance_px=0.5)
        delta = cam.update(view)
        key = f in (0, 25)
        surfaces = _keyframe(cam) if key else _surfaces(delta)
        for morphs, feed in ((whole, surfaces), (cut, _pieces(surfaces, rng))):
            morphs.apply(feed, key, now)
        for m in range(cam.n_materials):
            assert np.array_equal(cut.rows[m], cam.index_buffer(m)), (f, m)
            assert np.array_equal(cut.display(m), whole.display(m)), (f, m)
        (va, pa), (vb, pb) = whole.moving(now), cut.moving(now)
        assert np.array_equal(va, vb) and np.array_equal(pa, pb), f
        assert (len(cut.active), cut.snaps) == (len(whole.active), whole.snaps), f


def test_refcounts_follow_the_camera_and_keyframes_start_over():
    from caveclod.paths import flyover
    mesh = caveclod.build("rough", size=32)
    cam = mesh.new_camera()
    morphs = Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration=0.2)
    morphs.apply(_keyframe(cam), True, 0.0)
    lo, hi = mesh.bounds()
    for f in range(60):                                 # splits and collapses
        view = caveclod.View.from_pose(flyover(lo, hi, 0, f / 2), tolerance_px=1.0)
        morphs.apply(_surfaces(cam.update(view)), False, f / 30)
        used = np.concatenate([t.reshape(-1) for t in cam.triangles().values()]).astype(np.int64)
        assert np.array_equal(morphs.point_refs, np.bincount(morphs.point[used], minlength=len(morphs.point_refs)))
    assert morphs.active, "a flight at 30 Hz with 0.2 s morphs has some under way"
    ch = morphs.apply(_keyframe(cam), True, 2.0)        # a keyframe: the camera starts over
    assert ch.reset and not morphs.active
    for m in range(cam.n_materials):
        assert np.array_equal(morphs.display(m), cam.index_buffer(m))
    moved, where = morphs.moving(2.0)                   # what moved goes home
    assert np.array_equal(where, mesh.vertex_positions[moved])
    assert len(morphs.moving(2.5)[0]) == 0


def test_a_sessions_first_refinement_is_shown_at_once_not_grown_out_of_the_base_mesh():
    """A session's first keyframe goes out before the camera's first pose (the base mesh); the frame
    answering that pose holds the whole first refinement. Morphed, every render's first half second
    was drawn from the base mesh (found by a sweep of textured meshes: each patch one smeared
    triangle for 15 frames). It is shown as it is; the frames after it morph as before."""
    from caveclod.paths import flyover
    mesh = caveclod.build("rough", size=32)
    cam = mesh.new_camera()
    morphs = Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration=0.5)
    morphs.apply(_keyframe(cam), True, 0.0, posed=False)           # the base mesh, before any pose
    lo, hi = mesh.bounds()
    first = _surfaces(cam.update(caveclod.View.from_pose(flyover(lo, hi, 0, 0.0), tolerance_px=1.0)))
    assert sum(len(s.slots) for s in first) > 100
    ch = morphs.apply(first, False, 0.02)
    assert ch.reset and not morphs.active
    for m in range(cam.n_materials):
        assert np.array_equal(morphs.display(m), cam.index_buffer(m))
    moving = 0
    for f in range(1, 30):                                          # then a flight morphs as before
        view = caveclod.View.from_pose(flyover(lo, hi, 0, f / 2), tolerance_px=1.0)
        ch = morphs.apply(_surfaces(cam.update(view)), False, 0.02 + f / 30)
        assert not ch.reset
        moving += bool(morphs.active)
    assert moving > 10
    posed = Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration=0.5)
    posed.apply(_keyframe(cam), True, 0.0)                          # a keyframe that answered a pose
    view = caveclod.View.from_pose(flyover(lo, hi, 0, 40.0), tolerance_px=1.0)
    assert not posed.apply(_surfaces(cam.update(view)), False, 0.02).reset and posed.active


def test_bad_input_is_refused():
    p = np.zeros((4, 3), np.float32)
    with pytest.raises(ValueError, match="positive duration"):
        Geomorphs(p, np.arange(4), 1, 0.0)
    with pytest.raises(ValueError, match="indices into the vertex buffer"):
        Geomorphs(p, np.array([0, 1, 2, 9]), 1, 0.5)


# -- the renderer -------------------------------------------------------------------------

def test_the_renderer_draws_the_display_and_the_moving_positions(gl):
    """Mid-morph the camera's positions on the GPU are the morphs'; once the morphs are over, the image is
    the image of a renderer without geomorphs, pixel for pixel."""
    from caveclod.render import Renderer, Vertices
    mesh = caveclod.build("rough", size=32)
    lo, hi = mesh.bounds()
    verts = Vertices(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs)
    cam = mesh.new_camera()
    morphs = Geomorphs(mesh.vertex_positions, morph_targets(mesh), cam.n_materials, duration=1.0)
    centre = (lo + hi) / 2
    pose = (tuple(centre + (hi - lo) * [0.2, -0.9, 0.9]), tuple(centre), (0.0, 0.0, 1.0))
    with Renderer(160, 120, verts, mesh.materials, bounds=(lo, hi), ctx=gl, morph=True) as r, \
            Renderer(160, 120, verts, mesh.materials, bounds=(lo, hi), ctx=gl) as plain:
        first = _keyframe(cam)
        for target in (r, plain):
            for s in first:
                target.apply(0, s.material, s.count, s.tris, s.slots)
        morphs.apply(first, True, 0.0)
        surfaces = _surfaces(cam.update(caveclod.View.from_pose(pose, width=160, height=120, tolerance_px=0.5)))
        for s in surfaces:
            plain.apply(0, s.material, s.count, s.tris, s.slots)
        images = []
        for t, ch in ((10.0, morphs.apply(surfaces, False, 10.0)), (10.5, None), (11.0, None)):
            ch = ch if ch is not None else morphs.tick(t)
            for m, count, slots, tris in ch.writes:
                r.apply(0, m, count, tris, slots)
            r.write_positions(0, *morphs.moving(t))
            assert np.array_equal(r.camera_positions(0), morphs.drawn_positions(t).astype(np.float32))
            for m in range(cam.n_materials):
                assert np.array_equal(r.index_buffer(0, m), morphs.display(m))
            images.append(r.render([pose]))
        start, middle, done = images
        want = plain.render([pose])
        assert np.array_equal(done, want)
        assert not np.array_equal(middle, want) and not np.array_equal(middle, start)
    with pytest.raises(ValueError, match="morph=True"):
        with Renderer(16, 16, verts, mesh.materials, bounds=(lo, hi), ctx=gl) as plain:
            plain.write_positions(0, [0], [[0, 0, 0]])


@settings(max_examples=20, deadline=None)
@given(name=st.sampled_from(sorted(_RANDOM_MESHES)), seed=st.integers(0, 2**31),
       duration=st.sampled_from([0.05, 0.2, 0.7]), step=st.sampled_from([1 / 30, 0.1, 0.4]),
       keyframe_at=st.integers(-1, 25))
def test_random_flights_keep_the_display_valid_and_end_at_the_mesh_sent(name, seed, duration, step, keyframe_at):
    """Random jumps of the eye (splits, collapses, cascades, points coming back, whole parts
    vanishing and coming back), random clocks and a keyframe somewhere: the display is always valid
    triangles over the buffer with the camera's buffers inside it, and once the morphs are over it is
    the camera's buffers exactly."""
    rng = np.random.default_rng(seed)
    mesh = _RANDOM_MESHES[name]
    lo, hi = mesh.bounds()
    cam = mesh.new_camera()
    morphs = Geomorphs(mesh.vertex_positions, _RANDOM_TARGETS[name], cam.n_materials, duration)
    morphs.apply(_keyframe(cam), True, 0.0)
    now = 0.0
    for f in range(30):
        now += step * rng.uniform(0.5, 1.5)
        eye = lo + (hi - lo) * rng.uniform([-0.2, -0.2, 0.3], [1.2, 1.2, 2.0])
        view = caveclod.View(eye=tuple(eye), target=tuple(lo + (hi - lo) * rng.uniform(0, 1, 3)),
                             up=(0.0, 0.0, 1.0), width=320, height=240, tolerance_px=float(rng.choice([0.5, 2, 8])))
        delta = cam.update(view)
        if f == keyframe_at:
            morphs.apply(_keyframe(cam), True, now)
        else:
            morphs.apply(_surfaces(delta), False, now)
        morphs.moving(now)
        for m in range(cam.n_materials):
            assert np.array_equal(morphs.rows[m], cam.index_buffer(m))
            shown = morphs.display(m)
            assert len(shown) >= cam.cnt[m] and (shown < len(mesh.vertex_positions)).all()
    morphs.tick(now + duration)
    assert not morphs.active
    for m in range(cam.n_materials):
        assert np.array_equal(morphs.display(m), cam.index_buffer(m))
    moved, where = morphs.moving(now + duration)
    assert np.array_equal(where, mesh.vertex_positions[moved])
