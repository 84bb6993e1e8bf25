"""The renderer in cache mode: N vertex slots per camera on the GPU, patched in place.

* Fed a CachedCamera's frames (vertex writes into slots, index writes in
  slot numbers), it draws exactly the image a resident renderer draws from
  the same camera's resident deltas, at every frame checked, for each
  strategy; the GPU holds the client's slot buffers and index buffers; it
  uploaded only the vertices written, never the mesh.
* Fed by a real cache-mode client session (the frames' decoded writes), it
  draws what the server's camera shows.
* Bad vertex writes are refused before anything is written.
"""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod import paths
from caveclod.refine.cachedcamera import CachedCamera
from caveclod.render import Renderer, Vertices

W, H = 200, 120


@pytest.fixture(scope="module")
def terrain():
    return caveclod.build("default", size=40)


def _vertices(mesh) -> Vertices:
    return Vertices(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs,
                    mesh.vertex_colors if len(mesh.vertex_colors) else None)


def _attributes(mesh, vertices):
    return [np.asarray(a)[vertices] for a in (mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs)]


def _feed_cached(renderer, camera, mesh, cd, keyframe=False):
    if keyframe:
        renderer.reset(camera)
    renderer.write_vertices(camera, cd.slots, *_attributes(mesh, cd.vertices))
    for m, d in cd.surfaces.items():
        renderer.apply(camera, m, d.count, d.tris, slots=d.slots)


def _feed(renderer, camera, delta):
    for m, d in delta.surfaces.items():
        renderer.apply(camera, m, d.count, d.tris, slots=d.slots)


@pytest.mark.parametrize("strategy", ["fa", "lru", "lru_pq"])
def test_slots_patched_in_place_draw_the_resident_image(gl, terrain, strategy):
    lo, hi = terrain.bounds()
    n = 1800
    resident_cam, cached = terrain.new_camera(), CachedCamera(terrain.new_camera(), n, strategy)
    with Renderer(W, H, _vertices(terrain), terrain.materials, ctx=gl) as resident, \
            Renderer(W, H, None, terrain.materials, ctx=gl, bounds=(lo, hi), cache_vertices=n) as slotted:
        _feed(resident, 0, resident_cam.keyframe())
        _feed_cached(slotted, 0, terrain, cached.keyframe(), keyframe=True)
        written = 0
        for frame in range(60):
            pose = paths.flyover(lo, hi, 0, 0.4 * frame)
            view = caveclod.View.from_pose(pose, width=W, height=H)
            _feed(resident, 0, resident_cam.update(view))
            cd = cached.update(view)
            assert cd.updates == 1, "the cache holds every frame of this flight"
            _feed_cached(slotted, 0, terrain, cd)
            written += cd.inserted
            if frame % 6 == 5:
                np.testing.assert_array_equal(slotted.render([pose]), resident.render([pose]))
                on_gpu = slotted.slot_vertices(0)
                held = np.flatnonzero(cached.cache.slot_vertex >= 0)
                np.testing.assert_array_equal(on_gpu.positions[held],
                                              terrain.vertex_positions[cached.cache.slot_vertex[held]])
                for m in range(cached.camera.n_materials):
                    np.testing.assert_array_equal(slotted.index_buffer(0, m), cached.slot_buffer(m))
        assert written > 0
        base = cached.cache.inserted - written                  # the keyframe's vertices
        assert slotted.stats.vertex_bytes == (base + written) * 32 < terrain.n_vertices * 32
        assert slotted.stats.index_bytes == resident.stats.index_bytes, "the same index writes, in slot numbers"


def test_a_cache_mode_session_renders_what_the_server_shows(gl, server, terrain_path):
    """The renderer fed by the client's decoded frames, exactly as they arrive."""
    from caveclod.client import Client
    mesh = caveclod.load(terrain_path)
    with Client(f"127.0.0.1:{server.port}", cache_dir=False) as client:
        with client.session("terrain", cameras=2, width=W // 2, height=H, cache_vertices=1500,
                            cache_strategy="lru_pq") as s:
            info = s.info
            lo = (info.mesh.bounds_min.x, info.mesh.bounds_min.y, info.mesh.bounds_min.z)
            hi = (info.mesh.bounds_max.x, info.mesh.bounds_max.y, info.mesh.bounds_max.z)
            with Renderer(W, H, None, [m.name for m in info.mesh.materials], ctx=gl, cameras=2, bounds=(lo, hi),
                          cache_vertices=info.cache_vertices) as slotted, \
                    Renderer(W, H, _vertices(mesh), mesh.materials, ctx=gl, cameras=2, bounds=(lo, hi)) as whole:

                def feed(frame):
                    for c, cam in frame.cameras.items():
                        if cam.keyframe:
                            slotted.reset(c)
                        for w in cam.vertex_writes:
                            slotted.write_vertices(c, w.slots, *w.blocks)
                        for sf in cam.surfaces:
                            slotted.apply(c, sf.material, sf.count, sf.tris, slots=sf.slots)

                feed(s.next_frame(timeout=10))
                for i in range(12):
                    poses = [paths.circle(lo, hi, c, 2.0 * i) for c in range(2)]
                    for c in range(2):
                        seq = s.send_pose(c, *poses[c])
                    while (f := s.next_frame(timeout=10)) is not None:
                        feed(f)
                        if f.pose_seq >= seq:
                            break
                while (f := s.next_frame(timeout=0.3)) is not None:
                    feed(f)
                assert s.protocol.divergences == 0 and s.protocol.bad_frames == 0
                session = server.sessions.sessions[s.protocol.token]
                for c in range(2):
                    whole.reset(c)
                    for m, tris in session.cams[c].triangles().items():
                        whole.apply(c, m, len(tris), tris)
                np.testing.assert_array_equal(slotted.render(poses), whole.render(poses))
                assert slotted.stats.vertex_bytes < whole.stats.vertex_bytes


@pytest.mark.parametrize("call, message", [
    (lambda r: r.write_vertices(0, [5], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2))), None),
    (lambda r: r.write_vertices(0, [64], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2))),
     "slot 64 is outside the 64 vertex slots"),
    (lambda r: r.write_vertices(0, [3, 2], np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 2))), "ascending"),
    (lambda r: r.write_vertices(0, [3], np.zeros((1, 3)), np.zeros((1, 2)), np.zeros((1, 2))), r"normal must have shape \(1, 3\)"),
    (lambda r: r.write_vertices(0, [3], np.full((1, 3), np.nan), np.zeros((1, 3)), np.zeros((1, 2))), "NaN"),
    (lambda r: r.write_vertices(0, None, np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 2)), first_slot=63),
     "do not fit 64 slots"),
    (lambda r: r.write_vertices(0, [1], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2)), np.zeros((1, 4))),
     r"need 3 arrays \(positions, normals, uvs\)"),
    (lambda r: r.write_vertices(1, [1], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2))), "camera must be 0 .. 0"),
    (lambda r: r.apply(0, 0, 1, [[0, 1, 64]]), "vertex index 64 is outside the vertex buffer of 64"),
])
def test_bad_vertex_writes_are_refused_and_nothing_is_written(gl, call, message):
    with Renderer(16, 16, None, ["grass"], ctx=gl, bounds=((0, 0, 0), (1, 1, 1)), cache_vertices=64) as r:
        r.write_vertices(0, None, np.ones((64, 3)), np.ones((64, 3)), np.ones((64, 2)))
        before = r.slot_vertices(0)
        if message is None:
            call(r)
            assert r.slot_vertices(0).positions[5].tolist() == [0, 0, 0]
            return
        with pytest.raises(ValueError, match=message):
            call(r)
        after = r.slot_vertices(0)
        for a, b in zip(before, after):
            np.testing.assert_array_equal(a, b)


def test_cache_mode_renderers_are_made_right_or_not_at_all(gl, terrain):
    lo, hi = terrain.bounds()
    with pytest.raises(ValueError, match="pass vertices=None"):
        Renderer(16, 16, _vertices(terrain), ["a"], ctx=gl, bounds=(lo, hi), cache_vertices=10)
    with pytest.raises(ValueError, match="cache mode needs bounds"):
        Renderer(16, 16, None, ["a"], ctx=gl, cache_vertices=10)
    with pytest.raises(ValueError, match="slot count of at least 1"):
        Renderer(16, 16, None, ["a"], ctx=gl, bounds=(lo, hi), cache_vertices=0)
    with Renderer(16, 16, _vertices(terrain), ["a"], ctx=gl) as resident:
        with pytest.raises(ValueError, match="for cache mode"):
            resident.write_vertices(0, [0], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2)))
    with Renderer(16, 16, None, ["a"], ctx=gl, bounds=(lo, hi), cache_vertices=8, colors=True) as coloured:
        coloured.write_vertices(0, [2, 3], np.ones((2, 3)), np.ones((2, 3)), np.ones((2, 2)),
                                np.full((2, 4), 200, np.uint8))
        assert coloured.slot_vertices(0).colors[2:4].tolist() == [[200] * 4] * 2
        assert coloured.stats.vertex_bytes == 2 * 36 and coloured.stats.vertex_writes == 4
