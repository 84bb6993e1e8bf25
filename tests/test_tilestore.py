"""Blocks of tiles made by separate jobs, then merged: the same mesh as one process makes.

The merge reads each block's rows from a file written by another process
(here: by a build over fresh arrays, as a pod would), with the job's own
node numbers, so a row a block changes but does not write, or a node id
the merge does not renumber, would make the merged mesh differ; the
digests below compare every array of the two meshes. Also: retried jobs,
missing blocks, tiles of another input, damaged files, the command line.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import caveclod
from caveclod.builder.builtin import range_scan, rough_terrain
from caveclod.builder.hierarchy import build_static_mesh, build_tile_job
from caveclod.builder.tilestore import TileStore, block_level, block_of, parse_job
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
    # 3 jobs share 4 blocks of 2 x 2 tiles (two levels each); 5 jobs the 16 first-level tiles.
    for count, level, blocks in ((3, 1, 4), (5, 0, 16)):
        where = tmp_path / str(count)
        reports = jobs(make, where, count)
        assert {r["block_level"] for r in reports} == {level}
        assert sum(r["blocks_written"] for r in reports) == len(TileStore(where).present()) == blocks
        assert not [f for f in os.listdir(where) if f.endswith(".tmp")]
        merged = build_static_mesh(make(), tiles=4, workers=2, store=TileStore(where))
        assert merged.info["blocks_read"] == blocks
        assert digest(merged) == digest(single), count


def test_blocks_of_border_positions_only(tmp_path):
    """An icosphere in 8 x 8 tiles given to 64 jobs: 18 of its 60 first-level tiles have faces but no
    position inside (every corner touches another tile); their blocks hold faces and no positions."""
    import trimesh
    from caveclod.builder.meshfile import source_from_trimesh

    def make():
        src = source_from_trimesh(trimesh.creation.icosphere(subdivisions=3))
        src.vertex_normal = None
        return src
    reports = jobs(make, tmp_path, 64, tiles=8)
    assert sum(r["blocks_written"] for r in reports) == 60
    merged = build_static_mesh(make(), tiles=8, store=TileStore(tmp_path))
    assert digest(merged) == digest(build_static_mesh(make(), tiles=8))


def test_a_retried_job_keeps_the_blocks_it_wrote(tmp_path):
    make = SOURCES["rough"]
    first = build_tile_job(make(), TileStore(tmp_path, job=(1, 5)), tiles=4)
    mine = TileStore(tmp_path).present()
    assert first["blocks_written"] == len(mine) == 3 and all(b % 5 == 1 for _, b in mine)
    stamps = {b: os.stat(TileStore(tmp_path).file(b, lv)).st_mtime_ns for lv, b in mine}
    os.remove(TileStore(tmp_path).file(mine[0][1], mine[0][0]))        # the try that died before this one
    again = build_tile_job(make(), TileStore(tmp_path, job=(1, 5)), tiles=4)
    assert (again["blocks_written"], again["blocks_found"]) == (1, 2)
    assert all(os.stat(TileStore(tmp_path).file(b, lv)).st_mtime_ns == stamps[b] for lv, b in mine[1:])


def test_a_missing_block_names_its_job(tmp_path):
    make = SOURCES["rough"]
    jobs(make, tmp_path, 5)
    level, block = TileStore(tmp_path).present()[7]
    os.remove(TileStore(tmp_path).file(block, level))
    with pytest.raises(InputError, match=f"jobs {block % 5}/5"):
        build_static_mesh(make(), tiles=4, store=TileStore(tmp_path))


def test_tiles_of_another_input_or_damaged_are_refused(tmp_path):
    with pytest.raises(InputError, match="holds no blocks"):          # the jobs have not run (or wrote elsewhere)
        build_static_mesh(SOURCES["rough"](), tiles=4, store=TileStore(tmp_path / "nowhere"))
    jobs(SOURCES["rough"], tmp_path, 2)
    with pytest.raises(InputError, match="another input"):
        build_static_mesh(SOURCES["rough"](seed=8), tiles=4, store=TileStore(tmp_path))
    with pytest.raises(InputError, match="another input"):          # the same input, another grid
        build_static_mesh(SOURCES["rough"](), tiles=2, store=TileStore(tmp_path))
    with pytest.raises(InputError, match="different numbers of jobs"):
        jobs(SOURCES["rough"], tmp_path, 5)
        build_static_mesh(SOURCES["rough"](), tiles=4, store=TileStore(tmp_path))
    for level, block in TileStore(tmp_path).present():
        if level == 0:
            os.remove(TileStore(tmp_path).file(block, level))
    store = TileStore(tmp_path)
    level, block = store.present()[0]
    path = store.file(block, level)
    path.write_bytes(path.read_bytes()[:1000])                       # cut short
    with pytest.raises(InputError, match="cannot be read"):
        build_static_mesh(SOURCES["rough"](), tiles=4, store=TileStore(tmp_path))
    np.savez(path, F=np.zeros(3))                                    # not a tile file
    with pytest.raises(InputError, match="not a caveclod tile file"):
        build_static_mesh(SOURCES["rough"](), tiles=4, store=TileStore(tmp_path))


def _flip_a_byte_of(path, member: str) -> None:
    """Flip one byte inside ``member`` of a block file (a stored zip: its bytes lie as written)."""
    import zipfile
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    data = bytearray(path.read_bytes())
    at = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra) + info.compress_size // 2
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("member", ["meta.npy", "segments.npy", "F.npy"])
def test_a_damaged_block_is_named_and_its_retried_job_makes_it_anew(tmp_path, member):
    """One flipped byte in a block's header gave a 39-line traceback (zipfile's Bad CRC-32); in its rows,
    "does not fit this input; run the tile jobs again", and the retried job kept the block (its header
    was fine), so no retry mended it."""
    make = SOURCES["rough"]
    jobs(make, tmp_path, 2)
    store = TileStore(tmp_path)
    level, block = store.present()[0]
    _flip_a_byte_of(store.file(block, level), member)
    with pytest.raises(InputError, match=f"is damaged.*run (its tile job|tile job {block % 2}/2) again"):
        build_static_mesh(make(), tiles=4, store=TileStore(tmp_path))
    again = build_tile_job(make(), TileStore(tmp_path, job=(block % 2, 2)), tiles=4, workers=1)
    assert again["blocks_written"] == 1
    merged = build_static_mesh(make(), tiles=4, store=TileStore(tmp_path))
    assert digest(merged) == digest(build_static_mesh(make(), tiles=4))


def test_an_interrupted_write_leaves_no_temp_file_and_temp_names_are_unique(tmp_path, monkeypatch):
    """Ctrl-C (or any error but the file system's) while a block was written left its .tmp file for
    good; and the temp name was the pid alone, 1 in every container, so two pods of one index wrote
    one file."""
    from caveclod.builder import tilestore
    arrays, real_write = [], np.lib.format.write_array

    def interrupted(f, array, **kwargs):
        arrays.append(1)
        if len(arrays) == 3:                 # the temp file is there, half written
            assert [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
            raise KeyboardInterrupt
        return real_write(f, array, **kwargs)
    monkeypatch.setattr(np.lib.format, "write_array", interrupted)
    with pytest.raises(KeyboardInterrupt):
        build_tile_job(SOURCES["rough"](), TileStore(tmp_path, job=(0, 2)), tiles=4, workers=1)
    assert not os.listdir(tmp_path)
    monkeypatch.setattr(np.lib.format, "write_array", real_write)
    temps, real_replace = [], os.replace
    monkeypatch.setattr(tilestore.os, "replace", lambda a, b: temps.append(os.path.basename(a)) or real_replace(a, b))
    store = TileStore(tmp_path, job=(0, 2))
    store.key = "k"
    for _ in range(2):                       # one block, written twice by one pid
        store.write_block(0, 0, {"x": lambda: np.zeros(3)})
    assert len(temps) == 2 and temps[0] != temps[1]


def test_a_job_refuses_a_tiles_dir_it_cannot_write_before_the_work(tmp_path, monkeypatch):
    """A read-only volume failed once every block was made, naming a temp file ("Read-only file
    system") and saying nothing of what to do."""
    real = os.access
    monkeypatch.setattr(os, "access", lambda path, mode, **kw: False if str(path) == str(tmp_path) else
                        real(path, mode, **kw))
    with pytest.raises(InputError, match="--tiles-dir .* cannot be written here.*writable directory"):
        TileStore(tmp_path, job=(0, 2))
    TileStore(tmp_path)                          # the merge only reads


def test_a_mesh_of_one_tile_leaves_it_all_to_the_merge(tmp_path):
    make = SOURCES["scan"]
    (report,) = jobs(make, tmp_path, 1, tiles=1)
    assert report["blocks_written"] == 0 and report["block_level"] is None
    merged = build_static_mesh(make(), tiles=1, store=TileStore(tmp_path))
    assert digest(merged) == digest(build_static_mesh(make(), tiles=1))


def test_block_levels():
    from caveclod.builder.tiles import TileGrid
    grid = TileGrid(8, np.zeros((0, 2), np.int32))                  # 8 x 8 tiles, levels 0 .. 3
    assert [block_level(grid, n) for n in (1, 4, 5, 16, 17, 64, 1000)] == [2, 2, 1, 1, 0, 0, 0]
    assert block_level(TileGrid(1, np.zeros((0, 2), np.int32)), 4) is None
    # Tile (row 5, column 6) of 8 x 8 lies in block (2, 3) of 4 x 4 and (1, 1) of 2 x 2.
    assert block_of(np.array([5 * 8 + 6]), 8, 1).tolist() == [2 * 4 + 3]
    assert block_of(np.array([5 * 8 + 6]), 8, 2).tolist() == [1 * 2 + 1]


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
        assert json.loads(proc.stdout)["blocks_written"] == 2
    proc = run("build", *common, "--tiles-dir", tiles, "-o", tmp_path / "merged.cvc")
    assert proc.returncode == 0, proc.stderr
    merged = json.loads(proc.stdout)
    assert merged["blocks_read"] == 4
    one = caveclod.build("rough", size=120, tiles=2)
    assert merged["content_hash"] == one.content_hash and merged["optional_hash"] == one.optional_hash != ""
    assert_refused(run("build", *common, "--tile-job", "0/2"), "--tiles-dir")
    assert_refused(run("build", *common, "--tiles-dir", tiles, "--tile-job", "2/2"), "I/N")
    assert_refused(run("build", *common, "--tiles-dir", tiles, "--tile-job", "0/2", "-o", tmp_path / "x.cvc"),
                   "no -o")
    assert_refused(run("build", *common), "-o")
    assert_refused(run("build", "rough", "--size", 100, "--tiles", 2, "--quiet", "--tiles-dir", tiles, "-o",
                       tmp_path / "y.cvc"),
                   "another input")
