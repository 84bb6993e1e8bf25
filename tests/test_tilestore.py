"""First-level tiles made by separate jobs, then merged: the same mesh as one process makes.

The merge reads each tile's rows from a file written by another process
(here: by a build over fresh arrays, as a pod would), so a row a tile
changes but does not write would make the merged mesh differ; the digests
below compare every array of the two meshes. Also: retried jobs, missing
tiles, tiles of another input, damaged files, the command line.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import caveclod
from caveclod.builder.builtin import range_scan, rough_terrain
from caveclod.builder.hierarchy import build_static_mesh, build_tile_job
from caveclod.builder.tilestore import TileStore, parse_job
from caveclod.errors import InputError

from test_cli import assert_refused, run
from test_tiles import digest

SOURCES = {"rough": lambda seed=7: rough_terrain(96, seed=seed),   # holes, rough relief, materials
           "scan": lambda seed=3: range_scan(64, seed=seed)}       # open borders, normal seams, surface groups


def jobs(make, path, count, tiles=4) -> list[dict]:
    """Run ``count`` tile jobs, each on a source of its own (as separate pods would load it)."""
    return [build_tile_job(make(), TileStore(path, job=(i, count)), tiles=tiles, workers=1) for i in range(count)]


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_jobs_then_merge_give_the_mesh_of_one_process(name, tmp_path):
    make = SOURCES[name]
    single = build_static_mesh(make(), tiles=4, workers=2)
    reports = jobs(make, tmp_path, 3)
    written = sum(r["tiles_written"] for r in reports)
    assert written == len(TileStore(tmp_path).present()) > 8
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]
    merged = build_static_mesh(make(), tiles=4, workers=2, store=TileStore(tmp_path))
    assert merged.info["tiles_read"] == written and merged.info["tiles_made"] == 0
    assert digest(merged) == digest(single)
    # A tile whose job never finished: the merge makes it itself, to the same mesh.
    os.remove(TileStore(tmp_path).file(TileStore(tmp_path).present()[1]))
    merged = build_static_mesh(make(), tiles=4, workers=1, store=TileStore(tmp_path))
    assert (merged.info["tiles_read"], merged.info["tiles_made"]) == (written - 1, 1)
    assert digest(merged) == digest(single)


def test_a_retried_job_keeps_the_tiles_it_wrote(tmp_path):
    make = SOURCES["rough"]
    first = build_tile_job(make(), TileStore(tmp_path, job=(1, 2)), tiles=4)
    mine = TileStore(tmp_path).present()
    assert first["tiles_written"] == len(mine) and all(t % 2 == 1 for t in mine)
    stamps = {t: os.stat(TileStore(tmp_path).file(t)).st_mtime_ns for t in mine}
    os.remove(TileStore(tmp_path).file(mine[0]))                 # the try that died before this one
    again = build_tile_job(make(), TileStore(tmp_path, job=(1, 2)), tiles=4)
    assert (again["tiles_written"], again["tiles_found"]) == (1, len(mine) - 1)
    assert all(os.stat(TileStore(tmp_path).file(t)).st_mtime_ns == stamps[t] for t in mine[1:])


def test_tiles_of_another_input_or_damaged_are_refused(tmp_path):
    jobs(SOURCES["rough"], tmp_path, 1)
    with pytest.raises(InputError, match="another input"):
        build_static_mesh(SOURCES["rough"](seed=8), tiles=4, store=TileStore(tmp_path))
    with pytest.raises(InputError, match="another input"):          # the same input, another grid
        build_static_mesh(SOURCES["rough"](), tiles=2, store=TileStore(tmp_path))
    store = TileStore(tmp_path)
    path = store.file(store.present()[0])
    path.write_bytes(path.read_bytes()[:1000])                       # cut short
    with pytest.raises(InputError, match="cannot be read"):
        build_static_mesh(SOURCES["rough"](), tiles=4, store=TileStore(tmp_path))
    np.savez(path, F=np.zeros(3))                                    # not a tile file
    with pytest.raises(InputError, match="not a caveclod tile file"):
        build_static_mesh(SOURCES["rough"](), tiles=4, store=TileStore(tmp_path))


def test_a_mesh_of_one_tile_leaves_it_all_to_the_merge(tmp_path):
    make = SOURCES["scan"]
    (report,) = jobs(make, tmp_path, 1, tiles=1)
    assert report["tiles_written"] == 0 and report["tiles_per_side"] == 1
    merged = build_static_mesh(make(), tiles=1, store=TileStore(tmp_path))
    assert digest(merged) == digest(build_static_mesh(make(), tiles=1))


def test_job_numbers():
    assert parse_job("3/8") == (3, 8) and parse_job(" 0 / 1 ") == (0, 1)
    for bad in ("8/8", "-1/8", "1", "a/b", "1/0", ""):
        with pytest.raises(InputError, match="I/N"):
            parse_job(bad)


def test_command_line_jobs_and_merge(tmp_path):
    tiles = tmp_path / "tiles"
    common = ("rough", "--size", 120, "--tiles", 2, "--quiet", "--json")
    for i in range(2):
        proc = run("build", *common, "--tiles-dir", tiles, "--tile-job", f"{i}/2")
        assert proc.returncode == 0, proc.stderr
        assert json.loads(proc.stdout)["tiles_written"] == 2
    proc = run("build", *common, "--tiles-dir", tiles, "-o", tmp_path / "merged.cvc")
    assert proc.returncode == 0, proc.stderr
    merged = json.loads(proc.stdout)
    assert merged["tiles_read"] == 4
    one = caveclod.build("rough", size=120, tiles=2)
    assert merged["content_hash"] == one.content_hash
    assert_refused(run("build", *common, "--tile-job", "0/2"), "--tiles-dir")
    assert_refused(run("build", *common, "--tiles-dir", tiles, "--tile-job", "2/2"), "I/N")
    assert_refused(run("build", *common, "--tiles-dir", tiles, "--tile-job", "0/2", "-o", tmp_path / "x.cvc"),
                   "no -o")
    assert_refused(run("build", *common), "-o")
    assert_refused(run("build", "rough", "--size", 100, "--tiles", 2, "--quiet", "--tiles-dir", tiles, "-o",
                       tmp_path / "y.cvc"),
                   "another input")
