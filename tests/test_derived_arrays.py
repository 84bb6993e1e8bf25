"""Arrays a build stores so that no server derives them when it starts (``staticmesh.DERIVED_ARRAYS``).

Each vertex's position, the faces per material and the connected parts are
what the hierarchy's arrays give; a file from before them gets them derived
when its first camera is made, a file with them is served without deriving
anything, and a file whose stored copy disagrees with the rest is refused
by the structural check (a camera trusting a wrong one would prune the
wrong parts or read a vertex's position out of place).
"""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod import staticmesh
from caveclod.errors import FileFormatError
from caveclod.paths import flyover
from caveclod.refine import parts as parts_module
from caveclod.staticmesh import DERIVED_ARRAYS, PART_ARRAYS, OPTIONAL_ARRAYS, StaticMesh, derived_arrays, load


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The debris field (many parts, many materials) and the rough terrain (holes), built and saved."""
    out = {}
    for name, size in (("debris", 12), ("rough", 64)):
        mesh = caveclod.build(name, size=size)
        path = tmp_path_factory.mktemp("derived") / f"{name}.cvc"
        mesh.save(path)
        out[name] = (mesh, path)
    return out


def _without_derived(mesh: StaticMesh, path) -> StaticMesh:
    """``mesh`` as a file from before the derived arrays was: saved without them, loaded."""
    old = StaticMesh(arrays={k: v for k, v in mesh.arrays.items() if k not in DERIVED_ARRAYS},
                     materials=mesh.materials, info=mesh.info)
    old.save(path)
    return load(path)


def _frames(mesh: StaticMesh, steps: int = 12) -> list:
    """What a camera flying over ``mesh`` draws, step by step (the triangles of each material)."""
    lo, hi = mesh.bounds()
    cam = mesh.new_camera()
    out = []
    for i in range(steps):
        cam.update(caveclod.View.from_pose(flyover(lo, hi, 0, 0.8 * i), tolerance_px=2.0))
        out.append({s: t.copy() for s, t in cam.triangles().items()})
    out.append(cam.hidden_parts)
    return out


@pytest.mark.parametrize("name", ["debris", "rough"])
def test_a_build_stores_what_its_arrays_give(built, name):
    mesh, path = built[name]
    assert set(DERIVED_ARRAYS) <= set(mesh.arrays)
    back = load(path)
    fresh = derived_arrays(back)
    for key in DERIVED_ARRAYS:
        assert np.array_equal(np.asarray(back.arrays[key]), fresh[key]), key
    assert back.derived_bytes == sum(fresh[k].nbytes for k in DERIVED_ARRAYS)
    # The static bytes are the hierarchy's, as before: the derived ones are reported apart.
    assert back.nbytes + back.derived_bytes == sum(a.nbytes for a in back.arrays.values())
    back.verify()                                  # the optional hash covers them


@pytest.mark.parametrize("name", ["debris", "rough"])
def test_a_file_with_them_is_served_without_deriving_and_one_without_draws_the_same(built, name, tmp_path,
                                                                                      monkeypatch):
    mesh, path = built[name]
    old = _without_derived(mesh, tmp_path / "old.cvc")
    want = _frames(old)                            # derived here, once, as before
    assert old.parts().count > 0 and len(old.vertex_position_ids) == old.n_vertices

    def refuse(*args, **kwargs):
        raise AssertionError("derived what the file holds")
    monkeypatch.setattr(staticmesh, "derive_vertex_positions", refuse)
    monkeypatch.setattr(staticmesh, "count_material_faces", refuse)
    monkeypatch.setattr(parts_module, "mesh_parts", refuse)
    new = load(path, check=False)
    got = _frames(new)
    assert len(got) == len(want) and got[-1] == want[-1]
    for a, b in zip(got[:-1], want[:-1]):
        assert a.keys() == b.keys() and all(np.array_equal(a[s], b[s]) for s in a)
    assert not new.vertex_position_ids.flags.writeable and not new.parts().sphere.flags.writeable
    assert [c.tolist() for c in new.material_face_counts()] == [c.tolist() for c in old.material_face_counts()]


def _edited(path, out, name: str, edit) -> None:
    """Copy ``path`` to ``out`` with array ``name``'s bytes changed by ``edit`` (in place, on a copy)."""
    out.write_bytes(path.read_bytes())
    mesh = load(out, check=False)
    at, shape, dtype = mesh.arrays[name].offset, mesh.arrays[name].shape, mesh.arrays[name].dtype
    del mesh
    raw = np.memmap(out, mode="r+", dtype=dtype, offset=at, shape=shape)
    edit(raw)
    raw.flush()
    del raw


@pytest.mark.parametrize("name, edit", [
    ("vertex_position", lambda a: a.__setitem__(len(a) // 2, a[len(a) // 2] + 1)),
    ("material_faces", lambda a: a.__setitem__((0, 0), a[0, 0] - 1)),
    ("part_sphere", lambda a: a.__setitem__((len(a) // 2, 3), a[len(a) // 2, 3] * 0.5)),   # a radius halved
    ("part_roots", lambda a: a.__setitem__(slice(None), a[::-1].copy())),
    ("part_faces", lambda a: a.__setitem__(0, a[1])),
])
def test_a_stored_copy_that_disagrees_is_refused(built, tmp_path, name, edit):
    """A halved part radius would hide a part still in view; a vertex's position off by one would
    draw a corner elsewhere: the check refuses the file, naming the array."""
    _, path = built["debris"]
    out = tmp_path / f"{name}.cvc"
    _edited(path, out, name, edit)
    with pytest.raises(FileFormatError, match=f"{name} is not what the other arrays give") as info:
        load(out)
    assert "\n" not in str(info.value) and "rebuild" in str(info.value)


def test_some_part_arrays_without_the_rest_are_refused(built, tmp_path):
    mesh, _ = built["debris"]
    partial = StaticMesh(arrays={k: v for k, v in mesh.arrays.items() if k != "part_roots"},
                         materials=mesh.materials)
    partial.save(tmp_path / "partial.cvc")
    with pytest.raises(FileFormatError, match="not every part_ array"):
        load(tmp_path / "partial.cvc")


def test_the_derived_arrays_are_optional_arrays():
    """A reader from before them ignores them (optional), and they never enter the content hash."""
    assert set(DERIVED_ARRAYS) <= set(OPTIONAL_ARRAYS) and set(PART_ARRAYS) <= set(DERIVED_ARRAYS)
    assert not set(DERIVED_ARRAYS) & set(staticmesh.ARRAYS)
