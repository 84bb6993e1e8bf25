"""A camera's face -> record map (caveclod.kernels.facemap) against a dict,
and a camera's bytes no longer holding an entry per face of the mesh."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from caveclod.builder.builtin import default_terrain
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.kernels.facemap import fm_del, fm_dense, fm_fill, fm_get, fm_set, map_capacity, new_face_map
from caveclod.kernels.nodestate import is_dense
from caveclod.refine.view import View

OPS = st.lists(st.tuples(st.sampled_from(["set", "del", "get"]), st.integers(0, 300), st.integers(0, 10_000)),
               max_size=400)


@settings(max_examples=200, deadline=None)
@given(ops=OPS, records=st.integers(1, 64), dense=st.booleans())
def test_the_map_answers_as_a_dict_does(ops, records, dense):
    """Sets, moves and deletions in any order, keys clustered (consecutive face
    ids share home rows) and the table at most half full, as a camera keeps it;
    the dense form (a camera holding much of the mesh) alike."""
    fm = np.full((301, 1), -1, np.int32) if dense else new_face_map(records, 10**6)
    assert fm.shape[1] == (1 if dense else 2)
    ref: dict[int, int] = {}
    for op, f, r in ops:
        if op == "set" and (f in ref or len(ref) < records):
            fm_set(fm, f, r)
            ref[f] = r
        elif op == "del":
            fm_del(fm, f)
            ref.pop(f, None)
        assert fm_get(fm, f) == ref.get(f, -1)
    for f in range(301):
        assert fm_get(fm, f) == ref.get(f, -1), f
    dense = fm_dense(fm, 301)
    assert {int(f): int(dense[f]) for f in np.flatnonzero(dense >= 0)} == ref
    assert np.count_nonzero(fm[:, 0] >= 0) == len(ref)


def test_capacity_keeps_the_map_half_empty():
    for records in (1, 15, 16, 17, 1000, 4096):
        cap = map_capacity(records)
        assert cap >= 2 * records and cap & (cap - 1) == 0
    fm = new_face_map(100, 10**6)
    faces = np.arange(5000, 5100, dtype=np.int32)
    fm_fill(fm, faces, faces * 2)
    assert all(fm_get(fm, int(f)) == 2 * f for f in faces)
    for f in faces[::2]:
        fm_del(fm, int(f))
    assert all(fm_get(fm, int(f)) == (-1 if i % 2 == 0 else 2 * f) for i, f in enumerate(faces))
    # The table only where it is the smaller: 8 bytes a row against 4 a face.
    assert new_face_map(100, 100_000).shape == (256, 2)
    assert new_face_map(100, 500).shape == (500, 1)


def test_a_camera_holds_no_entry_per_face_of_the_mesh():
    """Seen from afar (its base mesh), a camera on a 4x larger terrain holds the same bytes:
    the face map follows its records and the node states its nodes, not the mesh."""
    held = {}
    for size in (64, 128):
        mesh = build_static_mesh(default_terrain(size))
        lo, hi = mesh.bounds()
        far = (lo + hi) / 2 + np.array([0.0, 0.0, 1e4 * float(np.linalg.norm(hi - lo))])
        cam = mesh.new_camera()
        cam.update(View(eye=tuple(far), target=tuple((lo + hi) / 2), up=(0, 1, 0), tolerance_px=1.0, prune=False))
        cam.validate()
        assert cam.face_map.nbytes <= 8 * map_capacity(len(cam.rec_face))
        assert cam.face_map.nbytes < mesh.n_faces, "the map is smaller than one byte per face"
        assert not is_dense(cam.state) and cam.state.nbytes < mesh.n_nodes / 4, "node bytes follow the view"
        held[size] = cam.nbytes, cam.n_faces
        # Refined fully, the camera holds every face: the dense form, Equation 1's 4p, is the smaller.
        cam.update(View(eye=tuple(far), target=tuple((lo + hi) / 2), up=(0, 1, 0), tolerance_px=0.0, prune=False))
        cam.validate()
        assert cam.n_faces == mesh.n_faces and cam.face_map.shape == (mesh.n_faces, 1)
    (small, faces_small), (large, faces_large) = held[64], held[128]
    assert abs(large - small) <= 0.1 * small + 64 * abs(faces_large - faces_small), held
