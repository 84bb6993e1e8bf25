"""The command line: JSON reports, progress on stderr, one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import caveclod

REQUIRED = {"nodes", "faces", "vertices", "positions", "surface_group_ids", "base_faces",
            "static_bytes", "equation1_static_bytes", "build_seconds"}


ROOT = Path(__file__).resolve().parents[1]


def run(*args, **kw):
    # The repository on the path too, so the tests work without an install.
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "caveclod.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300, env=env, **kw)


def assert_refused(proc, *words):
    assert proc.returncode == 2, proc
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("caveclod: error:"), proc.stderr
    assert "Traceback" not in proc.stderr
    for w in words:
        assert w.lower() in lines[0].lower(), lines[0]


def test_build_json_and_inspect(tmp_path):
    out = tmp_path / "t.cvc"
    proc = run("build", "default", "--size", 16, "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert REQUIRED <= set(report)
    assert report["faces"] == 2 * 16 * 16
    # The paper's arrays stay under its Equation 1; the ring bound (8 bytes a node) is not the paper's.
    ring = caveclod.load(out).arrays["node_ring"]
    assert ring.nbytes == 8 * (report["nodes"] - report["positions"])
    assert report["static_bytes"] - ring.nbytes <= report["equation1_static_bytes"]
    assert "collapsing" in proc.stderr, "progress goes to stderr"
    proc = run("inspect", out, "--json", "--verify")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert REQUIRED - {"build_seconds"} <= set(info)
    assert set(info["classes"]) == {"free", "sharp", "rigid"}
    assert sum(info["classes"].values()) == info["positions"]
    for key in ("nodes", "faces", "vertices", "positions", "base_faces", "static_bytes"):
        assert info[key] == report[key]


def test_build_heightfield_with_materials(tmp_path):
    rng = np.random.default_rng(0)
    h = rng.normal(0, 1, (9, 11)).cumsum(axis=0)
    np.save(tmp_path / "h.npy", h)
    np.save(tmp_path / "m.npy", rng.integers(0, 3, (8, 10)))
    proc = run("build", tmp_path / "h.npy", "-o", tmp_path / "h.cvc", "--json", "--quiet",
               "--cell-size", 30, "--z-scale", 2, "--materials", tmp_path / "m.npy")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "", "--quiet prints nothing on stderr"
    assert json.loads(proc.stdout)["faces"] == 2 * 8 * 10


@pytest.mark.parametrize("args,words", [
    (["build", "missing.obj", "-o", "x.cvc"], ["missing.obj"]),
    (["build", "default", "--size", "0", "-o", "x.cvc"], ["size"]),
    (["build", "default", "--size", "16", "--crease-angle", "400", "-o", "x.cvc"], ["crease"]),
    (["inspect", "missing.cvc"], ["missing.cvc"]),
    (["build", "rough", "--size", "16", "--materials", "m.npy", "-o", "x.cvc"], ["--materials", "heightfields"]),
    (["build", "scan.obj", "--cell-size", "30", "--nodata", "0", "-o", "x.cvc"],
     ["--cell-size", "--nodata", "heightfields"]),
])
def test_bad_arguments_are_refused(tmp_path, args, words):
    assert_refused(run(*args, cwd=tmp_path), *words)


def test_garbage_files_are_refused(tmp_path):
    (tmp_path / "junk.obj").write_bytes(b"\x00\xff" * 100)
    assert_refused(run("build", tmp_path / "junk.obj", "-o", tmp_path / "x.cvc"), "junk.obj")
    (tmp_path / "junk.cvc").write_bytes(b"CAVECLOD" + b"\x01\x00\x00\x00" + b"\xff" * 8)
    assert_refused(run("inspect", tmp_path / "junk.cvc"), "junk.cvc")
    (tmp_path / "nan.npy").write_bytes(b"")
    np.save(tmp_path / "nan.npy", np.full((4, 4), np.nan))
    assert_refused(run("build", tmp_path / "nan.npy", "-o", tmp_path / "x.cvc"))


def test_unwritable_output_is_refused(tmp_path):
    proc = run("build", "default", "--size", 8, "-o", tmp_path / "no" / "such" / "dir" / "x.cvc", "--quiet")
    assert_refused(proc, "does not exist", "create it first")


def test_pack_stores_the_downloads_in_a_file_built_without_them(tmp_path):
    import caveclod
    from caveclod import vertexpack
    bare = tmp_path / "old.cvc"
    caveclod.build("rough", size=24, packed=False).save(bare)
    before = caveclod.load(bare)
    proc = run("pack", bare, "--json", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert set(json.loads(proc.stdout)["attachments"]) == {"packed-20", "packed-20-morph"}
    after = caveclod.load(bare)
    assert after.content_hash == before.content_hash and after.vertex_buffer_hash == before.vertex_buffer_hash
    for bits, morph in vertexpack.STORED_VARIANTS:
        assert vertexpack.stored_packed(after, bits, morph) is not None
    assert_refused(run("pack", tmp_path / "missing.cvc"), "missing.cvc")


def test_a_built_file_is_remembered_as_checked_where_serve_looks(tmp_path, monkeypatch):
    """``caveclod build`` runs the structural check on what it wrote and remembers it in serve's
    default --checked-dir, so a first serve starts as a restart does; a changed file is read
    again; CAVECLOD_CHECKED_DIR=none remembers nothing."""
    from caveclod.cli import main
    from caveclod.meshcheck import check_mesh
    from caveclod.staticmesh import load
    checked = tmp_path / "checked"
    monkeypatch.setenv("CAVECLOD_CHECKED_DIR", str(checked))
    out = tmp_path / "t.cvc"
    assert main(["build", "default", "--size", "16", "-o", str(out), "--quiet"]) == 0
    assert len(list(checked.iterdir())) == 1
    assert check_mesh(load(out, check=False), checked_dir=checked) is False      # not read again
    data = bytearray(out.read_bytes())
    out.write_bytes(bytes(data))                                                  # rewritten: ctime moves
    assert check_mesh(load(out, check=False), checked_dir=checked) is True
    monkeypatch.setenv("CAVECLOD_CHECKED_DIR", "none")
    monkeypatch.chdir(tmp_path)                   # a directory named "none" would land here
    assert main(["build", "default", "--size", "16", "-o", str(tmp_path / "u.cvc"), "--quiet"]) == 0
    assert not (tmp_path / "none").exists() and len(list(checked.iterdir())) == 1


def test_python_dash_m_caveclod_is_the_command_line():
    """``python -m caveclod`` (no script on PATH, another interpreter) runs the same commands."""
    proc = subprocess.run([sys.executable, "-m", "caveclod", "build", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "--stride" in proc.stdout, proc.stderr
    proc = subprocess.run([sys.executable, "-m", "caveclod", "build", "no-such-file.obj", "-o", "x.cvc"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "no-such-file.obj" in proc.stderr


# ----------------------------------------------------------------- outputs, names and numbers a sweep found

from caveclod.cli import main as cli_main  # noqa: E402 - the in-process command line, for these tests


@pytest.fixture(scope="module")
def small_cvc(tmp_path_factory):
    path = tmp_path_factory.mktemp("small") / "base.cvc"
    assert cli_main(["build", "default", "--size", "8", "-o", str(path), "--quiet"]) == 0
    return path


def _one_line(capsys, status, *words):
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("caveclod: error:") and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]


def test_outputs_a_build_must_not_write_are_refused_before_it_starts(tmp_path, capsys):
    """-o naming a directory, a device, a FIFO, no file, a missing directory or the input itself:
    /dev/null became a regular file (run as root), `build m.obj -o m.obj` replaced the mesh, and
    a missing directory was found after the whole build."""
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    fifo = tmp_path / "fifo.cvc"
    os.mkfifo(fifo)
    # (Not /dev/null itself: were the check to go, a test run as root would replace the device.)
    for output, words in [(str(tmp_path), "not a regular file"), (str(fifo), "not a regular file"), ("", "names no file"), (".", "names no file"),
                          (str(tmp_path / "nodir" / "x.cvc"), "does not exist"), (str(mesh), "is the input")]:
        _one_line(capsys, cli_main(["build", str(mesh), "-o", output]), *words.split("|"))
    assert mesh.read_text().startswith("v 0 0 0") and fifo.is_fifo()


def test_a_failed_write_leaves_the_old_file_and_no_temp_file(tmp_path, small_cvc, monkeypatch):
    """A build killed while writing left NAME.cvc.tmp (hundreds of MB, a full disk stayed full)."""
    from caveclod import staticmesh
    mesh = caveclod.load(small_cvc)
    out = tmp_path / "old.cvc"
    out.write_bytes(small_cvc.read_bytes())

    def interrupted(name, array):
        raise KeyboardInterrupt
    monkeypatch.setattr(staticmesh, "_as_declared", interrupted)
    with pytest.raises(KeyboardInterrupt):
        mesh.save(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.cvc"]
    assert out.read_bytes() == small_cvc.read_bytes()


def test_a_255_byte_output_name_is_written(tmp_path, small_cvc):
    """The temp file was NAME.tmp, too long for names of 252 to 255 bytes."""
    mesh = caveclod.load(small_cvc)
    out = tmp_path / ("a" * 251 + ".cvc")
    mesh.save(out)
    assert caveclod.load(out).content_hash == mesh.content_hash and len(list(tmp_path.iterdir())) == 1


def test_numbers_and_names_said_in_one_line_not_a_traceback(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    cases = [
        (["build", "default", "--size", "8", "--seed", "-1", "-o", str(tmp_path / "n.cvc")], "--seed"),
        (["build", str(tmp_path / ("b" * 296 + ".obj")), "-o", str(tmp_path / "x.cvc")], "too long"),
        (["build", "default", "--size", "64", "--tiles", "2", "--tiles-dir", str(tmp_path / "afile"),
          "--tile-job", "0/2"], "is a file, not a directory"),
        (["build", "default", "--size", "8", "--tiles-dir", str(tmp_path / "t"), "--tile-job", "-1/2"], "I/N"),
        (["serve", "--port", "-1", "x.cvc"], "--port"),
        (["render", "--target", "127.0.0.1:1", "--fps", "0", "--out", str(tmp_path / "r")], "--fps"),
        (["render", "--target", "127.0.0.1:1", "--fps", "inf", "--out", str(tmp_path / "r")], "--fps"),
        (["render", "--target", "127.0.0.1:1", "--morph-ms", "nan", "--out", str(tmp_path / "r")], "--morph-ms"),
        (["render", "--target", "127.0.0.1:1", "--morph-ms", "inf", "--out", str(tmp_path / "r")], "--morph-ms"),
        (["loadtest", "--target", "127.0.0.1:1", "--rate", "nan"], "finite"),
        (["loadtest", "--target", "127.0.0.1:1", "--duration", "nan"], "finite"),
        (["loadtest", "--target", "127.0.0.1:1", "--warmup", "nan"], "finite"),
        (["serve", "--port", "0", "--metrics-port", "70000", "x.cvc"], "--metrics-port"),
        (["serve", "--port", "0", "--drain-seconds", "nan", "x.cvc"], "finite"),
        (["serve", "--port", "0", "--drain-seconds", "inf", "x.cvc"], "finite"),
        (["serve", "--port", "0", "--processes", "1000", "x.cvc"], "--processes"),
        (["health", "--target", "127.0.0.1:99999"], "port"),
        (["health", "--target", "127.0.0.1:1", "--timeout", "nan"], "--timeout"),
    ]
    for argv, words in cases:
        _one_line(capsys, cli_main(argv), words)


def test_pack_with_an_empty_output_is_refused_not_done_in_place(tmp_path, small_cvc, capsys):
    """``pack X.cvc -o ''`` rewrote X.cvc in place, where ``build -o ''`` is refused."""
    path = tmp_path / "m.cvc"
    path.write_bytes(small_cvc.read_bytes())
    before = path.stat().st_mtime_ns
    _one_line(capsys, cli_main(["pack", str(path), "-o", ""]), "names no file")
    assert path.stat().st_mtime_ns == before


def test_a_fifo_named_as_a_mesh_is_refused_not_waited_on(tmp_path):
    """open() of a FIFO waits for a writer: inspect and pack hung, serve past SIGTERM."""
    fifo = tmp_path / "ff.cvc"
    os.mkfifo(fifo)
    for command in ("inspect", "serve"):
        argv = [command, str(fifo)] + (["--port", "0", "--host", "127.0.0.1"] if command == "serve" else [])
        proc = subprocess.run([sys.executable, "-m", "caveclod.cli", *argv], capture_output=True, text=True,
                              timeout=60)
        assert_refused(proc, "not a regular file")


def test_inspect_verify_checks_the_stored_attachments(tmp_path, small_cvc, capsys):
    """A flipped byte in a stored packed download passed --verify (serve then refused it)."""
    path = tmp_path / "flip.cvc"
    data = bytearray(small_cvc.read_bytes())
    data[-100] ^= 0xFF                                       # inside the last attachment
    path.write_bytes(bytes(data))
    assert caveclod.load(path).attachments
    _one_line(capsys, cli_main(["inspect", "--verify", str(path)]), "attachment", "CRC-32")
    assert cli_main(["inspect", "--verify", str(small_cvc)]) == 0


def test_a_long_name_of_many_bytes_a_character_is_written(tmp_path, small_cvc):
    """The temp name kept 200 characters of the output's name: 'é' * 121 + '.cvc' (246 bytes)
    made a 260-byte temp name, too long, where NAME.tmp had fitted (found by a review)."""
    mesh = caveclod.load(small_cvc)
    out = tmp_path / ("é" * 121 + ".cvc")
    mesh.save(out)
    assert caveclod.load(out).content_hash == mesh.content_hash and len(list(tmp_path.iterdir())) == 1
