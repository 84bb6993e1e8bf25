"""Issue 17, item 5: a damaged ``.cvc`` never crashes or hangs caveclod.

Each finding of the fuzzer run is reproduced first (a header key renamed by
one bit, header JSON nested too deep, an array too big for the file, a huge
materials list, bit flips in the index arrays that crashed or hung the
kernels, a broken pipe), then what the structural check
(:mod:`caveclod.meshcheck`) and the kernels' guards promise, and what the
server does with a damaged mesh.
"""

from __future__ import annotations

import json
import random
import struct
import subprocess
import sys
import time
from pathlib import Path

import grpc
import numpy as np
import pytest
from fuzzcvc import (
    CASE_TIMEOUT,
    REFINE_TARGET,
    WARMUP_TIMEOUT,
    Layout,
    judge,
    with_header,
)
from fuzzing import ROOT, CliWorker
from service import WAIT, open_message, pose_message, raw_stream

import caveclod
from caveclod.errors import FileFormatError, MeshDamagedError
from caveclod import meshcheck
from caveclod.meshcheck import find_problem
from caveclod.paths import flyover
from caveclod.staticmesh import StaticMesh, load


def damaged_copy(path: Path, out: Path, edit) -> Path:
    """Write ``edit(bytearray of path, its Layout)`` (which returns the bytes) to ``out``."""
    data = bytearray(Path(path).read_bytes())
    out.write_bytes(bytes(edit(data, Layout.of(bytes(data)))))
    return out


def refused_in_one_line(path: Path, *phrases: str) -> str:
    with pytest.raises(FileFormatError) as info:
        load(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message, message
    for phrase in phrases:
        assert phrase in message, message
    return message


def cli(*args, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "caveclod.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=timeout, check=False)


def assert_one_line_error(proc: subprocess.CompletedProcess, *phrases: str) -> None:
    assert proc.returncode == 2, proc
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("caveclod: error:"), proc.stderr
    for phrase in phrases:
        assert phrase in lines[0], lines[0]


# ------------------------------------------------------------------ the header


def test_a_header_key_renamed_by_one_bit_is_one_line(terrain_path, tmp_path):
    """``nbytes`` -> ``njytes`` (bit 3 of one byte) was a KeyError traceback in inspect."""
    def rename(data, layout):
        at = data.index(b'"nbytes"') + 2
        data[at] ^= 0x08
        return data
    path = damaged_copy(terrain_path, tmp_path / "key.cvc", rename)
    refused_in_one_line(path, "bad offset or byte count", "rebuild it with 'caveclod build'")
    for args in (("inspect", path), ("inspect", "--verify", path)):
        assert_one_line_error(cli(*args), "the file is damaged")


@pytest.mark.parametrize("blob", [b"[" * 100_000 + b"]" * 100_000, b"{" * 50_000], ids=["lists", "objects"])
def test_a_header_nested_too_deep_is_one_line(terrain_path, tmp_path, blob):
    """json.loads raised RecursionError (a traceback) on deeply nested JSON."""
    path = damaged_copy(terrain_path, tmp_path / "deep.cvc", lambda data, layout: with_header(data, layout, blob)[0])
    refused_in_one_line(path, "not JSON")


def test_a_build_report_nested_too_deep_is_refused(terrain_path, tmp_path):
    """JSON that parses but nests 900 deep would overflow the printing of ``inspect``."""
    def deep_info(data, layout):
        header, deep = dict(layout.header), 0
        for _ in range(900):
            deep = [deep]
        header["info"] = {"deep": deep}
        return with_header(data, layout, json.dumps(header).encode())[0]
    refused_in_one_line(damaged_copy(terrain_path, tmp_path / "info.cvc", deep_info), "sane depth")


@pytest.mark.parametrize("origin", [[1, 2], [0, "x", 0], [0, float("nan"), 0], [True, 0, 0], {"x": 1},
                                    [10 ** 400, 2, 3]])
def test_a_build_report_origin_that_is_not_three_numbers_is_refused(terrain_path, tmp_path, origin):
    """The server sends info origin to clients as a Vec3 (MeshInfo.origin)."""
    def bad_origin(data, layout):
        header = dict(layout.header)
        header["info"] = {**header.get("info", {}), "origin": origin}
        return with_header(data, layout, json.dumps(header).encode())[0]
    refused_in_one_line(damaged_copy(terrain_path, tmp_path / "origin.cvc", bad_origin), "origin")


@pytest.mark.parametrize("count", [2 ** 62, 2 ** 31, -1])
def test_an_array_too_big_for_the_file_is_one_line(terrain_path, tmp_path, count):
    """A shape whose bytes overflow was numpy's ``ValueError: array is too big``."""
    def grow(data, layout):
        header = json.loads(json.dumps(layout.header))
        entry = header["arrays"]["node_links"]
        entry["shape"][0] = count
        entry["nbytes"] = count * 32
        return with_header(data, layout, json.dumps(header).encode())[0]
    path = damaged_copy(terrain_path, tmp_path / "big.cvc", grow)
    refused_in_one_line(path, "node_links")


@pytest.mark.parametrize("names, phrase", [
    ([f"m{i}" for i in range(100_000)], "more than the 65536"),
    (["x" * 5000] * 4, "longer than 1024"),
    ([1, 2, 3, 4], "not a list of names"),
    ([], "material beyond the 0 names"),
], ids=["100k names", "a long name", "numbers", "none"])
def test_materials_no_face_can_use_are_refused(terrain_path, tmp_path, names, phrase):
    """100,000 names passed ``--verify`` (the hash covers the arrays only) and cost 20 s of CPU
    before a server's first SessionInfo."""
    def rename(data, layout):
        header = dict(layout.header, materials=names)
        return with_header(data, layout, json.dumps(header).encode())[0]
    refused_in_one_line(damaged_copy(terrain_path, tmp_path / "names.cvc", rename), phrase)


def test_65536_material_names_cost_a_camera_no_time(terrain_path, tmp_path):
    """As many names as face_material can index are a valid file; cameras only pay for the
    materials that have faces (a camera's first update took 17 s)."""
    def rename(data, layout):
        header = dict(layout.header, materials=layout.header["materials"] + [f"m{i}" for i in range(65532)])
        return with_header(data, layout, json.dumps(header).encode())[0]
    mesh = load(damaged_copy(terrain_path, tmp_path / "names.cvc", rename))
    lo, hi = mesh.bounds()
    mesh.new_camera().update(caveclod.View(eye=tuple(hi + 1), target=tuple(lo)))       # kernels loaded
    t0 = time.perf_counter()
    cam = mesh.new_camera()
    for t in (0.0, 10.0):
        cam.update(caveclod.View.from_pose(flyover(lo, hi, 0, t), tolerance_px=0.5))
    cam.keyframe()
    assert time.perf_counter() - t0 < 2.0


# ------------------------------------------------------------------ bit flips in the index arrays


@pytest.fixture(scope="module")
def worker(terrain_path):
    """A CliWorker that survives crashes and hangs, its kernels loaded."""
    with CliWorker() as w:
        assert w.call(REFINE_TARGET, [str(terrain_path)], timeout=WARMUP_TIMEOUT).exit == 0
        yield w


def assert_contract(worker: CliWorker, path: Path, what: str) -> list:
    """``inspect`` and :func:`fuzzcvc.refine_a_little` of ``path`` keep the contract; their exits."""
    exits = []
    for target, args in (("caveclod.cli:main", [["inspect", str(path)]]), (REFINE_TARGET, [str(path)])):
        result = worker.call(target, args, timeout=CASE_TIMEOUT)
        kind, detail = judge(result)
        assert kind is None, f"{what}: {target}: [{kind}] {detail}"
        exits.append(result.exit)
    return exits


# The arrays whose flipped bits the fuzzer run found crashing (SIGSEGV) or hanging a server.
FOUND = ("vertex_sgid", "face_sgid", "base_face_nbrs", "base_face_nodes", "face_creator", "node_links",
         "node_position", "base_faces", "node_parent", "pos_vstart")


def flipped(path: Path, out: Path, at: int, bit: int) -> Path:
    """A copy of ``path`` with bit ``bit`` of byte ``at`` flipped."""
    data = bytearray(path.read_bytes())
    data[at] ^= 1 << bit
    out.write_bytes(bytes(data))
    return out


def swapped(path: Path, out: Path, start: int, row: int, i: int, j: int) -> Path:
    """A copy of ``path`` with rows ``i`` and ``j`` (of ``row`` bytes, from ``start``) swapped."""
    data = bytearray(path.read_bytes())
    a, b = slice(start + i * row, start + (i + 1) * row), slice(start + j * row, start + (j + 1) * row)
    data[a], data[b] = bytes(data[b]), bytes(data[a])
    out.write_bytes(bytes(data))
    return out


@pytest.mark.parametrize("name", FOUND)
def test_bit_flips_in_an_index_array_never_crash_or_hang(worker, terrain_path, tmp_path, name):
    layout = Layout.of(terrain_path.read_bytes())
    start, nbytes, _, _ = layout.arrays[name]
    rng = random.Random(name)
    flips = [(rng.randrange(nbytes), rng.randrange(8)) for _ in range(24)]
    if name == "base_faces":
        flips.append((116, 2))               # hung a kernel at 100 % CPU, ignoring SIGTERM
    for at, bit in flips:
        path = flipped(terrain_path, tmp_path / "flip.cvc", start + at, bit)
        assert_contract(worker, path, f"bit {bit} at byte {at} of {name}")


def test_rows_swapped_in_the_wiring_never_crash_or_hang(worker, terrain_path, tmp_path):
    """Values that stay in range pass the range checks and reach the kernels' guards."""
    layout = Layout.of(terrain_path.read_bytes())
    rng = random.Random(5)
    for name in ("base_face_nbrs", "node_links", "face_sgid", "vertex_sgid"):
        start, nbytes, _, shape = layout.arrays[name]
        for _ in range(10):
            i, j = rng.randrange(shape[0]), rng.randrange(shape[0])
            path = swapped(terrain_path, tmp_path / "swap.cvc", start, nbytes // shape[0], i, j)
            assert_contract(worker, path, f"{name} rows {i} and {j} swapped")


# ------------------------------------------------------------------ the structural check


def arrays_of(path) -> tuple[dict, list]:
    mesh = load(path)
    return {k: np.array(v) for k, v in mesh.arrays.items()}, list(mesh.materials)


def test_a_built_mesh_passes_the_check(terrain_path):
    assert find_problem(load(terrain_path, check=False)) is None
    for name, options in (("rough", {"size": 24, "seed": 3}), ("scan", {"size": 24})):
        assert find_problem(caveclod.build(name, **options)) is None, name


def _first_internal_with(a: dict, column: int) -> int:
    """Index j (into node arrays) of the first internal node whose links column is set."""
    return int(np.flatnonzero(a["node_links"][:, column] >= 0)[0])


def _parent_loop(a):
    a["node_parent"][0] = 0


def _earlier_parent(a):
    e = len(a["pos_vstart"]) - 1
    j = int(np.flatnonzero(a["node_parent"][e:] >= 0)[0])
    a["node_parent"][e + j] = e + j - 1


def _dependency_loop(a):
    # A split that requires a face an earlier split makes: the forced split could loop.
    links, creator = a["node_links"], a["face_creator"]
    e = len(a["pos_vstart"]) - 1
    j = int(np.flatnonzero(links[:, 4] >= 0)[-1])
    earlier = np.flatnonzero((creator >= 0) & (creator < e + j))
    links[j, 4] = earlier[0]


def _face_made_twice(a):
    j = _first_internal_with(a, 3)
    a["node_links"][j, 3] = a["node_links"][j, 2]


def _creator_mismatch(a):
    f = int(np.flatnonzero(a["face_creator"] >= 0)[0])
    a["face_creator"][f] = -1


def _stray_child(a):
    a["node_links"][0, 1] = a["node_links"][1, 1]


def _going_back(a):
    a["pos_vstart"][5] = a["pos_vstart"][7] + 1


def _rotation(a):
    a["face_rotation"][3] = 3


def _class(a):
    a["position_class"][0] = 7


def _base_nbr(a):
    a["base_face_nbrs"][0, 0] = int(np.flatnonzero(a["face_creator"] >= 0)[0])


def _base_corner(a):
    a["base_face_nodes"][0, 0] = 0 if a["node_parent"][0] >= 0 else 1


def _position(a):
    a["node_position"][0] = len(a["pos_vstart"])


def _nan(a):
    a["node_bound"][0, 3] = np.nan


def _huge_radius(a):
    a["node_bound"][-1, 3] = 1e38         # finite, but a cache-mode camera's view from outside it was not


def _ring_nan(a):
    a["node_ring"][0, 1] = np.nan


def _ring_rows(a):
    a["node_ring"] = a["node_ring"][1:]


def _colors(a):
    a["vertex_colors"] = np.zeros((3, 4), np.uint8)


def _material(a):
    a["face_material"][0] = 4


EDITS = {
    "a node its own parent": (_parent_loop, "parent"),
    "an earlier parent": (_earlier_parent, "parent"),
    "a dependency loop": (_dependency_loop, "dependency loop"),
    "a face made twice": (_face_made_twice, "same face twice"),
    "a face without its creator": (_creator_mismatch, "face_creator"),
    "a child of two nodes": (_stray_child, "node_parent does not point back"),
    "pos_vstart going back": (_going_back, "pos_vstart"),
    "face rotation 3": (_rotation, "face_rotation"),
    "position class 7": (_class, "position_class"),
    "a base neighbour made by a split": (_base_nbr, "neighbour is not a base face"),
    "a base corner that is not a root": (_base_corner, "not a root"),
    "a position beyond the last": (_position, "node_position"),
    "a NaN bounding sphere": (_nan, "node_bound holds a sphere"),
    "a radius of 1e38": (_huge_radius, "far beyond the positions"),
    "a NaN ring bound": (_ring_nan, "node_ring holds a reach"),
    "a ring bound short of a row": (_ring_rows, "node_ring has shape"),
    "colours for 3 vertices": (_colors, "vertex_colors has shape"),
    "material 4 of 4 names": (_material, "beyond the 4 names"),
}


@pytest.mark.parametrize("threads", ["one thread", "two threads in blocks"])
@pytest.mark.parametrize("edit", EDITS, ids=list(EDITS))
def test_the_check_names_what_is_wrong(terrain_path, edit, threads, monkeypatch):
    if threads != "one thread":            # the path of meshes past PARALLEL_FACES, in blocks of 7 nodes
        monkeypatch.setattr(meshcheck, "PARALLEL_FACES", 0)
        monkeypatch.setattr(meshcheck, "ROWS", 7)
    change, phrase = EDITS[edit]
    arrays, materials = arrays_of(terrain_path)
    change(arrays)
    problem = find_problem(StaticMesh(arrays=arrays, materials=materials))
    assert problem is not None and phrase in problem, problem


def test_two_threads_in_blocks_pass_a_good_mesh(terrain_path, monkeypatch):
    monkeypatch.setattr(meshcheck, "PARALLEL_FACES", 0)
    monkeypatch.setattr(meshcheck, "ROWS", 5)
    assert find_problem(load(terrain_path, check=False)) is None
    assert find_problem(caveclod.build("rough", size=24, seed=3)) is None


def test_load_refuses_what_the_check_finds_naming_the_file(terrain_path, tmp_path):
    arrays, materials = arrays_of(terrain_path)
    _dependency_loop(arrays)
    path = tmp_path / "loop.cvc"
    StaticMesh(arrays=arrays, materials=materials).save(path)       # its hashes match: --verify alone passes
    refused_in_one_line(path, "dependency loop", "rebuild it with 'caveclod build' or copy it again")
    load(path, check=False).verify()
    assert_one_line_error(cli("inspect", "--verify", path), "dependency loop")


# ------------------------------------------------------------------ the kernels' guards


def damaged_groups(terrain_path, out: Path, region=None) -> Path:
    """A copy whose split-made faces (those of small nodes whose sphere lies in ``region``, an
    (x0, y0, x1, y1) box; all when None) take another surface group: the check cannot see it
    (no ids out of range), a split there finds no vertex of the group at a corner."""
    arrays, materials = arrays_of(terrain_path)
    e = len(arrays["pos_vstart"]) - 1
    creator = arrays["face_creator"]
    made = creator >= 0
    if region is not None:
        x0, y0, x1, y1 = region
        sphere = arrays["node_bound"][np.maximum(creator - e, 0), :4]
        x, y, r = sphere[:, 0], sphere[:, 1], sphere[:, 3]
        made &= (x - r >= x0) & (x + r <= x1) & (y - r >= y0) & (y + r <= y1)
    groups = arrays["face_sgid"]
    groups[made] = np.where(groups[made] == 0, groups.max(), 0)
    StaticMesh(arrays=arrays, materials=materials).save(out)
    return out


def test_a_split_that_meets_damage_raises_mesh_damaged_and_the_mesh_stays_refused(terrain_path, tmp_path):
    mesh = load(damaged_groups(terrain_path, tmp_path / "groups.cvc"))       # passes the check
    lo, hi = mesh.bounds()
    cam = mesh.new_camera()
    with pytest.raises(MeshDamagedError) as info:
        for t in (0.0, 10.0, 20.0):
            cam.update(caveclod.View.from_pose(flyover(lo, hi, 0, t), tolerance_px=0.1))
    message = str(info.value)
    assert "\n" not in message and "groups.cvc" in message and "rebuild it" in message, message
    assert mesh.damaged
    with pytest.raises(MeshDamagedError):
        mesh.new_camera()


def refine_without_the_check(path: str) -> int:
    """A worker target: :func:`fuzzcvc.refine_a_little` with load's structural check switched off
    (for this call only), so that damage reaches the kernels' own guards."""
    from fuzzcvc import refine_a_little

    import caveclod.meshcheck
    check = caveclod.meshcheck.check_mesh
    caveclod.meshcheck.check_mesh = lambda mesh: None
    try:
        return refine_a_little(path)
    finally:
        caveclod.meshcheck.check_mesh = check


def test_the_kernels_stop_what_would_have_spun_for_ever(worker, terrain_path, tmp_path):
    """Bit 2 at byte 116 of base_faces spun a kernel at 100 % CPU, deaf to SIGTERM. The check
    refuses it now; without the check, the kernels' guards stop it: one line, exit 2."""
    start = Layout.of(terrain_path.read_bytes()).arrays["base_faces"][0]
    path = flipped(terrain_path, tmp_path / "spin.cvc", start + 116, 2)
    refused_in_one_line(path, "base")
    result = worker.call("test_meshcheck:refine_without_the_check", [str(path)], timeout=CASE_TIMEOUT)
    assert judge(result) == (None, "") and result.exit == 2, result
    assert "impossible hierarchy" in result.stderr, result.stderr


def test_refine_in_the_worker_says_the_mesh_is_damaged_in_one_line(worker, terrain_path, tmp_path):
    path = damaged_groups(terrain_path, tmp_path / "groups.cvc")
    assert assert_contract(worker, path, "surface groups") == [0, 2]


# ------------------------------------------------------------------ the server


def test_serve_refuses_a_damaged_mesh_at_start_even_beside_a_good_one(terrain_path, tmp_path):
    path = damaged_copy(terrain_path, tmp_path / "bad.cvc", lambda data, layout: data[: len(data) - 100])
    for meshes in ((path,), (terrain_path, path)):
        proc = cli("serve", "--host", "127.0.0.1", "--port", "0", *meshes, timeout=WAIT * 3)
        assert_one_line_error(proc, "bad.cvc", "truncated")


def test_a_mesh_found_damaged_while_refining_ends_its_session_with_data_loss(make_server, terrain_path, tmp_path):
    """DATA_LOSS naming the mesh (not INTERNAL); the good mesh is still served; later Opens of
    the damaged one are refused with DATA_LOSS at once."""
    lo, hi = load(terrain_path).bounds()
    corner = lo + 0.15 * (hi - lo)
    # Damage in the far corner from the server's warm-up (a view from the top corner), which it does not refine.
    damaged = damaged_groups(terrain_path, tmp_path / "damaged.cvc", (lo[0], lo[1], corner[0], corner[1]))
    server = make_server(meshes=[terrain_path, damaged])
    assert not server.catalogue.get("damaged").mesh.damaged, "the warm-up met the damage: move it"
    close = [pose_message(0, 1, (lo[0] - 10.0, lo[1] - 10.0, hi[2]), (corner[0], corner[1], lo[2]))]
    code, details, responses = raw_stream(server.port, [open_message("damaged", tolerance_px=0.1), *close], timeout=WAIT)
    assert code == grpc.StatusCode.DATA_LOSS, (code, details)
    assert "'damaged' is damaged" in details and "rebuild it" in details and "\n" not in details, details
    assert responses and responses[0].WhichOneof("kind") == "session_info"
    code, details, responses = raw_stream(server.port, [open_message("terrain"), *close], timeout=2.0)
    assert code == grpc.StatusCode.DEADLINE_EXCEEDED, (code, details)
    assert any(r.WhichOneof("kind") == "frame" for r in responses)
    code, details, responses = raw_stream(server.port, [open_message("damaged")], timeout=WAIT)
    assert code == grpc.StatusCode.DATA_LOSS and not responses, (code, details)


# ------------------------------------------------------------------ the command line


def test_inspect_into_a_closed_pipe_exits_quietly(terrain_path):
    """``caveclod inspect F | head -2`` printed a BrokenPipeError traceback."""
    proc = subprocess.Popen([sys.executable, "-m", "caveclod.cli", "inspect", str(terrain_path)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()                       # the reader is gone before caveclod writes
    try:
        err = proc.stderr.read()
        assert proc.wait(120) == 141, err
    finally:
        proc.kill()
        proc.wait()
    assert err == "", err


def test_load_names_the_prefix_damage_too(terrain_path, tmp_path):
    path = damaged_copy(terrain_path, tmp_path / "hlen.cvc",
                        lambda data, layout: data[:12] + struct.pack("<I", 2 ** 31) + data[16:])
    refused_in_one_line(path, "header claims")


@pytest.mark.parametrize("array,row", [("node_bound", (0, 3)), ("vertex_positions", (0, 1))])
def test_a_signalling_nan_is_found_without_a_warning(terrain_path, array, row):
    """A poked byte can make a signalling NaN, which numpy warns about when it widens it to
    float64 (the .cvc fuzzer's finding: a RuntimeWarning before the one-line error)."""
    import warnings
    arrays, materials = arrays_of(terrain_path)
    arrays[array] = arrays[array].copy()
    arrays[array].view(np.uint32)[row] = 0x7F8F_FFFF
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        problem = find_problem(StaticMesh(arrays=arrays, materials=materials))
    assert problem is not None, array


# ------------------------------------------------------------------ remembered checks (serve --checked-dir)

def _node_parent_loop_in_place(path: Path) -> None:
    """Rewrite ``path`` in place, same size: node 0 its own parent (the check refuses it)."""
    start, _, dtype, _ = Layout.of(path.read_bytes()).arrays["node_parent"]
    with open(path, "r+b") as fh:
        fh.seek(start)
        fh.write(np.array([0], dtype).tobytes())


def test_a_remembered_check_is_skipped_only_while_the_file_is_unchanged(terrain_path, tmp_path):
    import os
    import shutil
    stamps = tmp_path / "checked"
    path = tmp_path / "terrain.cvc"
    shutil.copyfile(terrain_path, path)
    assert meshcheck.check_mesh(load(path, check=False), stamps) is True       # read, then remembered
    assert meshcheck.check_mesh(load(path, check=False), stamps) is False      # unchanged: not read
    assert meshcheck.check_mesh(load(path, check=False)) is True               # no directory: always read
    # Touched back to its own times: the change time moved, so it is read again.
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert meshcheck.check_mesh(load(path, check=False), stamps) is True
    assert meshcheck.check_mesh(load(path, check=False), stamps) is False
    # Damaged in place (same size, same name): read again, and refused.
    _node_parent_loop_in_place(path)
    with pytest.raises(FileFormatError, match="parent"):
        meshcheck.check_mesh(load(path, check=False), stamps)
    # Replaced by a good copy (another inode): read again.
    shutil.copyfile(terrain_path, tmp_path / "new.cvc")
    os.replace(tmp_path / "new.cvc", path)
    assert meshcheck.check_mesh(load(path, check=False), stamps) is True
    # A stamp of another version of the check, or garbage, is no stamp.
    (stamp,) = stamps.iterdir()
    saved = json.loads(stamp.read_text())
    stamp.write_text(json.dumps({**saved, "check": "0" * 16}))
    assert meshcheck.check_mesh(load(path, check=False), stamps) is True
    stamp.write_text("{not json")
    assert meshcheck.check_mesh(load(path, check=False), stamps) is True
    assert meshcheck.check_mesh(load(path, check=False), stamps) is False


def test_a_directory_that_cannot_be_written_only_costs_the_check(terrain_path, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert meshcheck.check_mesh(load(terrain_path, check=False), blocker / "checked") is True
    assert meshcheck.check_mesh(load(terrain_path, check=False), blocker / "checked") is True


def test_serve_remembers_its_meshes_checks(terrain_path, tmp_path, monkeypatch):
    """Two starts of a server on one file: the first reads it, the second does not."""
    from caveclod.server import logs
    from caveclod.server.app import LodServer
    from caveclod.server.config import ServerConfig
    seen = []
    monkeypatch.setattr(logs, "event", lambda name, **fields: seen.append(fields) if name == "mesh.checked" else None)
    for _ in range(2):
        LodServer(ServerConfig(meshes=[str(terrain_path)], host="127.0.0.1", port=0,
                               checked_dir=str(tmp_path / "checked"))).stop(0)
    assert [f["how"] for f in seen] == ["read", "unchanged since checked"], seen
