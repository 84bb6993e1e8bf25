"""The vertex cache of cache mode, checked against slow references (tests/cachereference.py).

* The three strategies choose exactly the slots the plain-Python reference
  chooses, on random frames (hypothesis) and on real refinement walks.
* ActiveVertices' added/removed sets equal set differences of the whole
  index buffers.
* A CachedCamera's triangles equal a resident camera's when its cache is
  large enough; rewritten into slot numbers they name the same vertices;
  every slot a triangle uses holds its vertex on a client that applied only
  the writes; a client never holds more than N vertices.
* A cache smaller than one frame's vertices coarsens that camera (raised
  tolerance, vertices within N, a valid mesh) and relaxes again; a cache
  smaller than the base mesh is refused with a message that says what to ask.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import caveclod
from caveclod import paths
from caveclod.errors import InputError
from caveclod.refine.activevertices import ActiveVertices
from caveclod.refine.cachedcamera import CachedCamera
from caveclod.refine.vertexcache import STRATEGIES, VertexCache, check_options, vertex_keys

from cachereference import ReferenceCache, active_vertices

STRATEGY_NAMES = sorted(STRATEGIES)


@pytest.fixture(scope="module")
def terrain():
    return caveclod.build("default", size=40)


@pytest.fixture(scope="module")
def scan():
    """An object with seams, holes and three materials (vertices shared unevenly by faces)."""
    return caveclod.build("scan", size=32)


def walk(mesh, frames: int, path: str = "flyover", camera: int = 0, seconds: float = 6.0, tolerance: float = 1.0):
    """Views along a caveclod.paths path: ``frames`` poses over ``seconds``."""
    lo, hi = mesh.bounds()
    return [caveclod.View.from_pose(paths.pose(path, lo, hi, camera, seconds * i / frames), width=640, height=360,
                                    tolerance_px=tolerance) for i in range(frames)]


# -- the cache alone: fast kernels against the reference --------------------------------------

def _frames(draw, d, n, frames):
    """Active sets of successive frames, each at most n of d vertices, changing a little or a lot."""
    active = set()
    out = []
    for _ in range(frames):
        keep = draw(st.floats(0.0, 1.0))
        kept = {v for v in active if draw(st.floats(0.0, 1.0)) < keep} if active else set()
        room = n - len(kept)
        new = draw(st.lists(st.integers(0, d - 1), max_size=room))
        active = kept | (set(new) - kept)
        while len(active) > n:
            active.pop()
        out.append(active)
    return out


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data(), strategy=st.sampled_from(STRATEGY_NAMES), d=st.integers(4, 60), n=st.integers(1, 30),
       fraction=st.sampled_from([0.0, 0.1, 0.3, 0.75]), seed=st.integers(0, 2**16))
def test_strategies_choose_the_reference_slots(data, strategy, d, n, fraction, seed):
    n = min(n, d)
    rng = np.random.default_rng(seed)
    keys = rng.integers(0, 4, d).astype(np.float32)            # few distinct keys: ties decide too
    keys[rng.random(d) < 0.2] = np.inf
    pq = fraction if strategy == "lru_pq" else None
    fast = VertexCache(n, d, strategy, pq, keys)
    ref = ReferenceCache(n, strategy, pq or 0.0, keys)
    before = set()
    for i, active in enumerate(_frames(data.draw, d, n, data.draw(st.integers(1, 12)))):
        added, removed = sorted(active - before), sorted(before - active)
        slots, vertices, hits = fast.update(np.array(added, np.int32), np.array(removed, np.int32))
        want = ref.update(added, removed)
        assert dict(zip(slots.tolist(), vertices.tolist())) == want, f"frame {i}: other slots written"
        assert hits == len(added) - len(want)
        assert fast.slot_vertex.tolist() == [-1 if v is None else v for v in ref.slot_vertex]
        fast.validate()
        assert fast.n_active == len(active) <= n
        before = active
        if data.draw(st.booleans()) and data.draw(st.booleans()):
            fast.forget_inactive()
            ref.forget_inactive()


def test_lru_evicts_the_longest_inactive_and_fa_the_first():
    """By hand: slots 0-3; vertices 10, 11, 12, 13 cached, then 12 and 10 leave (in that order of frames)."""
    for strategy, victim in (("lru", 2), ("fa", 0)):
        c = VertexCache(4, 20, strategy)
        c.update(np.array([10, 11, 12, 13]), np.array([], np.int32))
        c.update(np.array([], np.int32), np.array([12]))         # slot 2 goes inactive first
        c.update(np.array([], np.int32), np.array([10]))         # then slot 0
        slots, vertices, hits = c.update(np.array([15]), np.array([], np.int32))
        assert (slots.tolist(), vertices.tolist(), hits) == ([victim], [15], 0), strategy
        slots, vertices, hits = c.update(np.array([10 if victim == 2 else 12]), np.array([], np.int32))
        assert len(slots) == 0 and hits == 1, f"{strategy}: a still-cached vertex comes back without a write"


def test_lru_pq_evicts_the_finest_detail_among_the_oldest():
    keys = np.array([5.0, 1.0, 9.0, 0.5, 3.0, 2.0], np.float32)
    c = VertexCache(5, 6, "lru_pq", 0.4, keys)             # queue of 2
    c.update(np.arange(5), np.array([], np.int32))
    c.update(np.array([], np.int32), np.array([0, 1, 2, 3]))   # inactive, oldest first: 0, 1, 2, 3
    slots, _, _ = c.update(np.array([5]), np.array([], np.int32))
    # The queue takes slots 0 and 1 (keys 5 and 1): vertex 1's slot goes, though 0 is older.
    assert slots.tolist() == [1]
    c.validate()


def test_a_full_cache_refuses_more_vertices():
    c = VertexCache(2, 5, "lru")
    c.update(np.array([0, 1]), np.array([], np.int32))
    with pytest.raises(caveclod.CaveclodError, match="overflowed"):
        c.update(np.array([2]), np.array([], np.int32))


@pytest.mark.parametrize("args, message", [
    ((0,), "cache_vertices is 0"),
    ((-3,), "cache_vertices is -3"),
    ((2.5,), "whole number"),
    ((True,), "whole number"),
    ((10, "mru"), "unknown cache strategy 'mru'; choose one of fa, lru, lru_pq"),
    ((10, "lru", 0.1), "applies to the lru_pq strategy only"),
    ((10, "lru_pq", 1.0), r"in \[0, 1\), got 1.0"),
    ((10, "lru_pq", -0.1), r"in \[0, 1\)"),
    ((10, "lru_pq", float("nan")), r"in \[0, 1\)"),
    ((10, "lru_pq", "lots"), "must be a number"),
])
def test_bad_options_say_what_to_give(args, message):
    with pytest.raises(InputError, match=message):
        check_options(*args)


def test_default_pq_fraction_is_the_papers():
    assert check_options(100, "lru_pq") == (100, "lru_pq", 0.1)
    assert check_options(100, "lru") == (100, "lru", None)
    assert VertexCache(100, 10, "lru_pq", None, np.zeros(10, np.float32)).pq_capacity == 10


def test_vertex_keys_are_the_error_of_the_split_that_brings_the_position(scan):
    """Slowly: walk each position's chain of stationary children up to its top node."""
    a = {k: np.asarray(v) for k, v in scan.arrays.items()}
    e = scan.n_positions
    keys = vertex_keys(scan)
    parent = a["node_parent"]
    node_pos = lambda x: x if x < e else int(a["node_position"][x - e])      # noqa: E731
    want = {}
    for p in range(e):
        x = p                                    # leaf p carries position p
        while parent[x] >= 0 and node_pos(parent[x]) == p:
            x = parent[x]
        want[p] = math.inf if parent[x] < 0 else float(a["node_bound"][parent[x] - e, 4])
    pos = scan.vertex_position_ids
    assert all(keys[v] == np.float32(want[int(pos[v])]) for v in range(scan.n_vertices))
    assert np.isinf(keys).sum() >= 3 and np.isfinite(keys).any()


# -- active vertices ----------------------------------------------------------------------------

@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), steps=st.integers(1, 15))
def test_active_vertices_on_random_deltas(seed, steps):
    """Overwrites, truncations and growth at random, a vertex often both leaving and coming back in one delta."""
    from caveclod.refine.camera import Delta, SurfaceDelta
    rng = np.random.default_rng(seed)
    d = int(rng.integers(3, 30))
    buffers = {m: rng.integers(0, d, (int(rng.integers(0, 8)), 3)).astype(np.uint32) for m in range(2)}
    av = ActiveVertices(d, buffers)
    before = active_vertices(buffers)
    for _ in range(steps):
        delta = Delta()
        for m in range(2):
            if rng.random() < 0.3:
                continue
            old, new = len(buffers[m]), int(rng.integers(0, 10))
            must = np.arange(old, new)
            extra = rng.choice(new, size=int(rng.integers(0, new + 1)), replace=False) if new else np.zeros(0, int)
            slots = np.union1d(must, extra).astype(np.uint32)
            tris = rng.integers(0, d, (len(slots), 3)).astype(np.uint32)
            delta.surfaces[m] = SurfaceDelta(slots, tris, new)
        delta.apply(buffers)
        added, removed = av.apply(delta)
        now = active_vertices(buffers)
        assert (added.tolist(), removed.tolist()) == (sorted(now - before), sorted(before - now))
        assert av.count == len(now) and not av._mark.any()
        before = now


@pytest.mark.parametrize("mesh_name", ["terrain", "scan"])
def test_active_vertices_equal_set_differences(mesh_name, request):
    mesh = request.getfixturevalue(mesh_name)
    cam = mesh.new_camera()
    av = ActiveVertices(mesh.n_vertices, cam.triangles())
    before = active_vertices(cam.triangles())
    assert set(av.vertices().tolist()) == before and av.count == len(before)
    views = walk(mesh, 40, "line" if mesh_name == "scan" else "flyover", seconds=40.0)
    views += walk(mesh, 10, "circle", tolerance=0.3)
    for i, view in enumerate(views):
        added, removed = av.apply(cam.update(view))
        now = active_vertices(cam.triangles())
        assert set(added.tolist()) == now - before, f"step {i}: added"
        assert set(removed.tolist()) == before - now, f"step {i}: removed"
        assert av.count == len(now) and set(av.vertices().tolist()) == now
        for m in range(cam.n_materials):
            assert np.array_equal(av.buffer(m), cam.index_buffer(m))
        before = now


# -- a camera in cache mode ---------------------------------------------------------------------

class Client:
    """What a client in cache mode holds: N slots written only by the frames, and slot index buffers."""

    def __init__(self, n):
        self.slots = np.full(n, -1, np.int64)               # the vertex each slot holds (its attributes, in effect)
        self.buffers = {}

    def apply(self, cd):
        self.slots[cd.slots] = cd.vertices
        for m, d in cd.surfaces.items():
            old = self.buffers.get(m, np.zeros((0, 3), np.uint32))
            new = np.zeros((d.count, 3), np.uint32)
            new[: min(len(old), d.count)] = old[: d.count]
            new[np.asarray(d.slots, np.int64)] = d.tris
            self.buffers[m] = new

    def reset(self):
        self.slots[:] = -1
        self.buffers = {}

    def triangles(self):
        """{material: (k, 3) vertex ids} the client draws; -1 where a slot holds nothing."""
        return {m: self.slots[b] for m, b in self.buffers.items() if len(b)}


def _same(got: dict, want: dict) -> bool:
    got = {m: t for m, t in got.items() if len(t)}
    return sorted(got) == sorted(want) and all(np.array_equal(got[m], want[m]) for m in want)


@pytest.mark.parametrize("strategy", STRATEGY_NAMES)
@pytest.mark.parametrize("mesh_name, path", [("terrain", "flyover"), ("scan", "rotate")])
def test_cached_camera_equals_resident_and_the_reference(strategy, mesh_name, path, request):
    mesh = request.getfixturevalue(mesh_name)
    resident = mesh.new_camera()
    views = walk(mesh, 60, path, seconds=12.0)
    peak = max(len(active_vertices(resident.triangles())), 1)
    for v in views:                                     # the walk's largest vertex count, from a dry run
        resident.update(v)
        peak = max(peak, len(active_vertices(resident.triangles())))
    n = peak + peak // 8
    resident = mesh.new_camera()
    keys = vertex_keys(mesh)
    cc = CachedCamera(mesh.new_camera(), n, strategy, keys=keys)
    ref = ReferenceCache(n, strategy, 0.1, keys)
    client = Client(n)
    before = active_vertices(resident.triangles())
    ref.update(before, set())
    client.apply(cc.keyframe())
    inserted = 0
    for i, view in enumerate(views):
        resident.update(view)
        cd = cc.update(view)
        now = active_vertices(resident.triangles())
        assert _same(cc.camera.triangles(), resident.triangles()), f"frame {i}: other triangles than resident"
        assert dict(zip(cd.slots.tolist(), cd.vertices.tolist())) == ref.update(now - before, before - now), \
            f"frame {i}: other slots than the reference"
        assert (set(cd.added.tolist()), set(cd.removed.tolist())) == (now - before, before - now)
        assert (cd.updates, cd.tolerance_px) == (1, 1.0)
        client.apply(cd)
        assert _same(client.triangles(), resident.triangles()), f"frame {i}: the client draws other vertices"
        assert (client.slots >= 0).sum() <= n
        inserted += cd.inserted
        cc.cache.validate()
        before = now
    assert inserted > 0 and cc.cache.inserted == inserted + len(active_vertices(mesh.new_camera().triangles()))
    # A keyframe after the walk: the client empties its slots and gets the active vertices back.
    client.reset()
    cd = cc.keyframe()
    assert len(cd.slots) == len(before) == cc.cache.n_held
    client.apply(cd)
    assert _same(client.triangles(), resident.triangles())


def test_slot_buffers_are_the_index_buffers_in_slot_numbers(terrain):
    cc = CachedCamera(terrain.new_camera(), 4000, "lru_pq")
    for view in walk(terrain, 10):
        cc.update(view)
    for m in range(cc.camera.n_materials):
        assert np.array_equal(cc.cache.slot_vertex[cc.slot_buffer(m)], cc.camera.index_buffer(m))


@pytest.mark.parametrize("strategy", STRATEGY_NAMES)
def test_a_frame_too_big_for_the_cache_coarsens_that_camera(terrain, strategy):
    """Down close (many vertices), then far out and back: the LOD fits, the
    tolerance rises above 1 px and comes back to it, the mesh stays valid."""
    base = len(active_vertices(terrain.new_camera().triangles()))
    lo, hi = terrain.bounds()
    centre = (lo + hi) / 2
    size = float(hi[0] - lo[0])

    def view(height):
        eye = (centre[0] - 0.3 * size, centre[1], hi[2] + height * size)
        return caveclod.View(eye=eye, target=tuple(centre), up=(0, 0, 1), width=640, height=360, tolerance_px=1.0)

    resident = terrain.new_camera()
    resident.update(view(0.05))
    need = len(active_vertices(resident.triangles()))
    n = base + (need - base) // 3
    cc = CachedCamera(terrain.new_camera(), n, strategy)
    client = Client(n)
    client.apply(cc.keyframe())
    tolerances = []
    far = terrain.new_camera()
    far.update(view(40.0))
    assert len(active_vertices(far.triangles())) < n, "far away, the camera's own tolerance fits"
    # The tolerance falls by a fifth a frame once the view fits: 24 frames far away bring back
    # 1 px from up to 1.25 ** 39 (the close view took 331 px on this build).
    heights = [0.05] * 4 + [0.05 * 1.5 ** k for k in range(1, 16)] + [40.0] * 24
    for i, h in enumerate(heights):
        cd = cc.update(view(h), relax=True)
        client.apply(cd)
        tolerances.append(cd.tolerance_px)
        assert cc.active.count <= n and (client.slots >= 0).sum() <= n
        assert _same(client.triangles(), cc.camera.triangles()), f"frame {i}"
        cc.camera.validate()
        cc.cache.validate()
    assert tolerances[0] > 1.0 and cd.updates == 1, f"the close view was coarsened: {tolerances}"
    assert tolerances[-1] == 1.0, f"far away the camera is back at its own tolerance: {tolerances}"
    # Still, a view re-sent without relaxing converges: no operation, nothing written.
    cc.update(view(0.05))
    for _ in range(3):
        cd = cc.update(view(0.05), relax=False)
    assert cd.delta.operations == 0 and cd.inserted == 0 and cd.tolerance_px > 1.0


def test_a_camera_held_at_the_limit_does_not_refit_every_frame(terrain):
    """Close down and creeping along: the view never fits. A lower step is
    tried at most once in RELAX_WAIT new poses (each failed try costs a
    refit, several updates), not at every pose; the tolerance stays raised."""
    from caveclod.refine import cachedcamera
    lo, hi = terrain.bounds()
    centre = (lo + hi) / 2
    size = float(hi[0] - lo[0])

    def view(i):
        eye = (centre[0] - 0.3 * size + 0.001 * size * i, centre[1], hi[2] + 0.05 * size)
        return caveclod.View(eye=eye, target=tuple(centre), up=(0, 0, 1), width=640, height=360, tolerance_px=1.0)

    base = len(active_vertices(terrain.new_camera().triangles()))
    resident = terrain.new_camera()
    resident.update(view(0))
    n = base + (len(active_vertices(resident.triangles())) - base) // 3
    cc = CachedCamera(terrain.new_camera(), n, "lru")
    client = Client(n)
    client.apply(cc.keyframe())
    client.apply(cc.update(view(0)))                 # fitted once: the tolerance is raised
    frames = 3 * cachedcamera.RELAX_WAIT
    refits = 0
    for i in range(1, frames + 1):
        cd = cc.update(view(i), relax=True)
        client.apply(cd)
        refits += cd.updates > 1
        assert cd.tolerance_px > 1.0 and cc.active.count <= n
        assert _same(client.triangles(), cc.camera.triangles()), f"frame {i}"
    assert refits <= frames // cachedcamera.RELAX_WAIT + 1, f"{refits} refits in {frames} frames"


def test_a_cache_smaller_than_the_base_mesh_is_refused(terrain):
    base = len(active_vertices(terrain.new_camera().triangles()))
    with pytest.raises(InputError, match=f"base mesh alone uses {base} vertices; ask for at least {base} slots"):
        CachedCamera(terrain.new_camera(), base - 1, "lru")
    CachedCamera(terrain.new_camera(), base, "fa")          # exactly enough is enough


def test_a_zero_tolerance_camera_fits_too(scan):
    """0 px asks for every visible vertex; the first raise leaves 0."""
    n = len(active_vertices(scan.new_camera().triangles())) + 20
    cc = CachedCamera(scan.new_camera(), n, "lru")
    for view in walk(scan, 5, "line", tolerance=0.0):
        cd = cc.update(view)
        assert cc.active.count <= n and cd.tolerance_px > 0.0


def test_the_ceiling_view_works_at_huge_extents(tmp_path):
    """At the ceiling a cached camera looks away from the mesh from outside it; its eye
    and target stay apart where one unit is below the coordinates' precision (1e16 m)."""
    rng = np.random.default_rng(3)
    path = tmp_path / "huge.npy"
    np.save(path, rng.normal(0.0, 1.0, (24, 24)).cumsum(0).cumsum(1))
    mesh = caveclod.build(str(path), cell_size=1e15, z_scale=1e14)
    lo, hi = mesh.bounds()
    assert float(np.abs(np.concatenate([lo, hi])).max()) > 1e16
    base = len(active_vertices(mesh.new_camera().triangles()))
    cc = CachedCamera(mesh.new_camera(), base, "lru")
    centre = (lo + hi) / 2
    eye = (float(centre[0]), float(centre[1]), float(hi[2]) + 1e14)
    view = caveclod.View(eye=eye, target=tuple(map(float, centre)), up=(0, 1, 0), width=640, height=360,
                         tolerance_px=0.01)
    delta = cc.update(view)
    assert cc.active.count <= base and delta.tolerance_px > 0.01


def test_a_camera_at_the_ceiling_draws_the_base_mesh_not_nothing(terrain):
    """At the ceiling a cached camera shows the base mesh, which fits; with parts hidden below
    the tolerance (the default) every part was hidden at 1e30 px, and a session drew nothing
    at all for 300 poses (a sweep of the client library: 200 slots, a 30-vertex base mesh)."""
    from caveclod.refine.cachedcamera import CEILING_PX
    base_cam = terrain.new_camera()
    base = len(active_vertices(base_cam.triangles()))
    base_faces = sum(len(t) for t in base_cam.triangles().values())
    cc = CachedCamera(terrain.new_camera(), base, "lru")
    lo, hi = terrain.bounds()
    centre = (lo + hi) / 2
    view = caveclod.View(eye=(float(centre[0]), float(centre[1]), float(hi[2]) + 1.0),
                         target=tuple(map(float, centre)), up=(0, 1, 0), width=640, height=360,
                         tolerance_px=0.01, prune=True)
    delta = cc.update(view)
    assert delta.tolerance_px >= CEILING_PX                  # nothing finer fits in the base's slots
    drawn = sum(len(cc.slot_buffer(m)) for m in range(terrain.n_materials))
    assert drawn == base_faces > 0
