"""A build that cannot fit in memory is refused before it starts, with the figures and what to do.

The memory available is read the way the kernel and a container's cgroup
state it (fake /proc and /sys trees here); the refusal happens before the
input is turned into a mesh, so a too-large heightfield costs seconds, not
the minutes before an OOM kill.
"""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod.builder import memory
from caveclod.builder.memory import PEAK_BYTES_PER_TRIANGLE, available_bytes, check_build_memory
from caveclod.cli import main
from caveclod.errors import InputError


def _tree(tmp_path, meminfo_kb=None, v2=None, v1=None):
    if meminfo_kb is not None:
        (tmp_path / "proc").mkdir(parents=True)
        (tmp_path / "proc/meminfo").write_text(f"MemTotal:       99999999 kB\nMemFree:  1 kB\n"
                                               f"MemAvailable:   {meminfo_kb} kB\n")
    if v2 is not None:
        d = tmp_path / "sys/fs/cgroup"
        d.mkdir(parents=True)
        (d / "memory.max").write_text(f"{v2[0]}\n")
        (d / "memory.current").write_text(f"{v2[1]}\n")
    if v1 is not None:
        d = tmp_path / "sys/fs/cgroup/memory"
        d.mkdir(parents=True)
        (d / "memory.limit_in_bytes").write_text(f"{v1[0]}\n")
        (d / "memory.usage_in_bytes").write_text(f"{v1[1]}\n")
    return tmp_path


def test_available_memory_is_the_least_of_the_kernel_and_the_container(tmp_path):
    assert available_bytes(_tree(tmp_path / "a", meminfo_kb=1000)) == 1000 * 1024
    assert available_bytes(_tree(tmp_path / "b", meminfo_kb=1000, v2=(500_000, 100_000))) == 400_000
    assert available_bytes(_tree(tmp_path / "c", meminfo_kb=100, v2=(500_000, 100_000))) == 100 * 1024
    assert available_bytes(_tree(tmp_path / "d", meminfo_kb=1000, v2=("max", 5))) == 1000 * 1024
    assert available_bytes(_tree(tmp_path / "e", meminfo_kb=1000, v1=(300_000, 100_000))) == 200_000
    assert available_bytes(_tree(tmp_path / "f", meminfo_kb=1000, v1=(9223372036854771712, 5))) == 1000 * 1024
    assert available_bytes(_tree(tmp_path / "g", v2=(50, 80))) == 0          # over its limit already
    assert available_bytes(tmp_path / "nothing") is None                      # not Linux: nothing checked


def test_this_machine_reports_its_memory():
    got = available_bytes()
    assert got is None or got > 0


def test_a_build_that_does_not_fit_is_refused_with_the_figures():
    check_build_memory(1000, "x", available=1000 * PEAK_BYTES_PER_TRIANGLE)      # fits exactly
    with pytest.raises(InputError) as info:
        check_build_memory(200_000_000, "dem.npy", available=24 << 30)
    text = str(info.value)
    assert "dem.npy: 200,000,000 triangles need about 59.6 GiB" in text
    assert "24.0 GiB are available" in text and "--no-memory-check" in text


def test_a_large_heightfield_is_refused_before_it_becomes_a_mesh(tmp_path, monkeypatch):
    """The check runs on the grid's size, before the source mesh (itself about 100 bytes a
    triangle) is made: with 1 MiB available a 200 x 200 grid is refused, with the check off or
    enough memory it builds."""
    heights = np.random.default_rng(1).normal(size=(200, 200)).astype(np.float32)
    path = tmp_path / "dem.npy"
    np.save(path, heights)
    made = []
    from caveclod.builder import terrain
    real = terrain.heightfield_to_source
    monkeypatch.setattr(terrain, "heightfield_to_source", lambda *a, **k: made.append(1) or real(*a, **k))
    monkeypatch.setattr(memory, "available_bytes", lambda root="/": 1 << 20)
    with pytest.raises(InputError, match=r"dem.npy: 79,202 triangles need about"):
        caveclod.build(str(path), packed=False)
    assert made == []
    out = tmp_path / "dem.cvc"
    assert main(["build", str(path), "-o", str(out), "--quiet"]) == 2 and not out.exists()
    assert main(["build", str(path), "-o", str(out), "--quiet", "--no-memory-check"]) == 0 and out.exists()
    monkeypatch.setattr(memory, "available_bytes", lambda root="/": 1 << 40)
    assert caveclod.build(str(path), packed=False).info["input_triangles"] == 79_202


def test_meshes_and_built_ins_are_checked_too(monkeypatch):
    monkeypatch.setattr(memory, "available_bytes", lambda root="/": 1 << 20)
    with pytest.raises(InputError, match=r"the built-in 'default' at --size 64: 8,192 triangles"):
        caveclod.build("default", size=64, packed=False)
    with pytest.raises(InputError, match=r"the built-in 'default' at --size 8192: 134,217,728 triangles"):
        caveclod.build("default", size=8192, packed=False)         # refused before generating 134M triangles
    import trimesh
    box = trimesh.creation.icosphere(subdivisions=5)               # 20,480 faces
    with pytest.raises(InputError, match=r"the mesh: 20,480 triangles"):
        caveclod.build(box, packed=False)
    assert caveclod.build(box, packed=False, check_memory=False).info["input_triangles"] == 20_480


@pytest.mark.parametrize("kind, writer", [
    ("obj", lambda m, p: m.export(p)), ("off", lambda m, p: m.export(p)), ("glb", lambda m, p: m.export(p)),
    ("ply", lambda m, p: m.export(p, encoding="binary")), ("ply-ascii", lambda m, p: m.export(p, encoding="ascii")),
    ("stl", lambda m, p: m.export(p)),
    ("stl-ascii", lambda m, p: p.write_text(__import__("trimesh").exchange.stl.export_stl_ascii(m)))])
def test_a_mesh_file_too_large_to_read_is_refused_before_reading(tmp_path, monkeypatch, kind, writer):
    """trimesh's readers of text formats hold 600-1,400 bytes a triangle, more than the build: a
    file whose reading would not fit is refused from its size, before it is read."""
    import trimesh
    path = tmp_path / f"part.{kind.split('-')[0]}"
    writer(trimesh.creation.icosphere(subdivisions=3), path)
    assert memory.mesh_file_kind(path) == kind
    need = path.stat().st_size * memory.READ_BYTES_PER_FILE_BYTE[kind]
    read = []
    from caveclod.builder import meshfile
    real = meshfile.load_mesh_file
    monkeypatch.setattr(meshfile, "load_mesh_file", lambda *a: read.append(1) or real(*a))
    monkeypatch.setattr(memory, "available_bytes", lambda root="/": int(need) - 1)
    with pytest.raises(InputError, match=rf"part.{kind.split('-')[0]}: reading this .* {kind.upper()} file"):
        caveclod.build(str(path), packed=False)
    assert read == []
    assert caveclod.build(str(path), packed=False, check_memory=False).info["input_triangles"] == 1280
    monkeypatch.setattr(memory, "available_bytes", lambda root="/": 1 << 40)
    assert caveclod.build(str(path), packed=False).info["input_triangles"] == 1280


def test_the_build_drops_its_input_once_it_has_made_its_own_arrays(monkeypatch):
    """caveclod.build keeps no name on the loaded input: a heightfield's mesh before normals
    (its vertices, faces and UVs, about 20 bytes a triangle) is gone before the collapses start,
    whose arrays are the build's peak."""
    import weakref
    from caveclod import api
    from caveclod.builder import hierarchy
    loaded, seen = [], []
    real_source, real_collapse = api.to_source, hierarchy.collapse_all

    def to_source(*a, **k):
        src = real_source(*a, **k)
        loaded.append((weakref.ref(src), weakref.ref(src.faces)))
        return src

    def collapse_all(*a, **k):
        seen.append([r() is None for r in loaded[0]])
        return real_collapse(*a, **k)

    monkeypatch.setattr(api, "to_source", to_source)
    monkeypatch.setattr(hierarchy, "collapse_all", collapse_all)
    mesh = caveclod.build("rough", size=48, packed=False)
    assert mesh.info["input_triangles"] > 0
    assert seen == [[True, True]], "the loaded input (and its faces) outlived the preparation"


def test_giving_back_freed_memory_is_harmless_without_glibc(monkeypatch):
    import ctypes

    def no_glibc(name, *a, **k):
        raise OSError(f"{name}: cannot open shared object file")

    memory.give_back_freed_memory()                          # glibc here, or nothing to do
    monkeypatch.setattr(memory, "_malloc_trim", None)
    monkeypatch.setattr(ctypes, "CDLL", no_glibc)
    memory.give_back_freed_memory()                          # musl, macOS: a no-op, no error
    assert memory._malloc_trim is False
