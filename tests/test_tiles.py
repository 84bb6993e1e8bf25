"""Tiled builds: tiles simplified in parallel with fixed borders, merged 2 x 2.

The invariants every build keeps (legal collapses, exact full refinement,
crack-free walks, reference agreement, error bounds) run on tiled builds in
test_hierarchy, test_camera, test_reference and test_error_bound; this file
checks what is particular to tiles: the grid, the borders, the numbering of
nodes made tile by tile, and that the file does not depend on the workers.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import caveclod
from caveclod.builder.builtin import range_scan, rough_terrain
from caveclod.builder.hierarchy import build_static_mesh, prepare_source
from caveclod.builder.tiles import positions_left_to_merge, tile_grid, tiles_per_side
from caveclod.errors import InputError
from caveclod.meshcheck import find_problem

from meshes import replay_collapses, tree_depth


def digest(mesh) -> str:
    h = hashlib.sha256()
    for name in sorted(mesh.arrays):
        h.update(name.encode())
        h.update(np.ascontiguousarray(mesh.arrays[name]).tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def rough():
    return rough_terrain(96)          # rough relief, no-data holes, materials


def test_the_same_file_for_one_and_three_workers(rough):
    one = build_static_mesh(rough, tiles=4, workers=1)
    three = build_static_mesh(rough, tiles=4, workers=3)
    assert digest(one) == digest(three)
    assert one.info["tiles"] == 4


def test_a_level_s_tiles_start_largest_first(rough, monkeypatch):
    """So that a level's last tile is a small one and the threads finish together; one worker runs
    them in the order they were handed out."""
    from caveclod.builder import hierarchy
    real, started = hierarchy._collapse_region, []

    def recorded(st, region, base, scratch, *args, **kwargs):
        started.append((len(region), base))
        return real(st, region, base, scratch, *args, **kwargs)

    monkeypatch.setattr(hierarchy, "_collapse_region", recorded)
    mesh = build_static_mesh(rough, tiles=4, workers=1)
    assert len(started) == 16 + 4, "the first level's 16 tiles and the second's 4 (the last runs in halves)"
    for level in (started[:16], started[16:]):
        sizes = [k for k, _ in level]
        assert sizes == sorted(sizes, reverse=True)
        assert sorted(b for _, b in level) != [b for _, b in level] or len(set(sizes)) == 1, \
            "started out of the grid's order (else the test shows nothing)"
    monkeypatch.setattr(hierarchy, "_collapse_region", real)
    assert digest(mesh) == digest(build_static_mesh(rough, tiles=4, workers=3))


def test_ctrl_c_stops_the_tiles_at_work_and_starts_no_more(rough, monkeypatch):
    """A Ctrl-C during a level ended the process only once every tile of the level queued had run
    (11-16 s into a 4.2M-triangle build). The interrupt arrives in the main thread while a tile
    is in its second pass on a worker; that tile must end with that pass and no other tile start."""
    import signal
    import threading
    from caveclod.builder import hierarchy
    real, calls, main = hierarchy._one_pass, [], threading.main_thread()

    def one_pass(st, region, *args):
        if threading.current_thread() is not main and len(region):
            calls.append(st.stop.is_set())
            if len(calls) == 2:
                signal.pthread_kill(main.ident, signal.SIGINT)
                assert st.stop.wait(10), "the interrupt did not reach the build"
        return real(st, region, *args)

    monkeypatch.setattr(hierarchy, "_one_pass", one_pass)
    with pytest.raises(KeyboardInterrupt):
        build_static_mesh(rough, tiles=4, workers=1)
    assert calls == [False, False], f"passes made after the interrupt: {calls.count(True)}"


def test_normals_made_beside_the_topology_are_the_ones_made_after_it(rough):
    """prepare_source makes the faces' normals and corner angles on a second thread while it
    makes the topology; the vertices and normals are those of the one-thread path."""
    from caveclod.builder.normals import add_crease_normals
    scan = range_scan(48)
    for source, angle in ((rough, None), (scan, 30.0), (scan, 0.0)):
        made, topo = prepare_source(source, angle)
        alone = add_crease_normals(source, source.crease_angle if angle is None else angle)
        assert source.vertex_normal is None and made.vertex_normal is not None
        for name in ("faces", "vertex_position", "vertex_normal"):
            assert np.array_equal(getattr(made, name), getattr(alone, name)), name
        assert np.array_equal(topo.nbrs, prepare_source(made)[1].nbrs), "a source with normals: the same topology"


def test_stamps_that_run_out_mid_build_change_nothing(rough, monkeypatch):
    """Each thread's stamps are int32 (kernels/simplify.next_stamp): a thread whose counter starts
    a few stamps short of the limit clears its marks and starts again within the first checks,
    and the file is the same. Without the reset, stamps past int32 would match no mark."""
    from caveclod.builder import hierarchy
    from caveclod.kernels.simplify import STAMP_LIMIT
    plain = build_static_mesh(rough, tiles=4, workers=2)
    real = hierarchy._thread_scratch
    started = []

    def near_the_limit(e):
        mark, counter = real(e)
        counter[0] = STAMP_LIMIT - 5
        started.append(counter)
        return mark, counter

    monkeypatch.setattr(hierarchy, "_thread_scratch", near_the_limit)
    again = build_static_mesh(rough, tiles=4, workers=2)
    assert len(started) == 2 and all(c[0] < STAMP_LIMIT - 5 for c in started), "every thread's stamps started again"
    assert digest(again) == digest(plain)


def test_a_level_of_one_tile_runs_in_halves_with_the_same_file_for_any_workers(rough, monkeypatch):
    """One tile (--tiles 1, or a tiled build's last level): passes cut in two halves made on two
    threads; the cut depends on the mesh only, and the result is as legal, complete and
    simplified as the same level made on one thread."""
    from caveclod.builder import hierarchy
    cuts = []
    real = hierarchy._halves

    def counting(*args):
        halves, cut = real(*args)
        cuts.append((len(halves[0]), len(halves[1]), len(cut)))
        return halves, cut

    monkeypatch.setattr(hierarchy, "_halves", counting)
    one = build_static_mesh(rough, tiles=1, workers=1)
    passes_in_halves = len(cuts)
    three = build_static_mesh(rough, tiles=1, workers=3)
    assert passes_in_halves >= 5 and len(cuts) == 2 * passes_in_halves, cuts
    assert all(a > 0 and b > 0 and c < a + b for a, b, c in cuts), cuts
    assert digest(one) == digest(three)
    assert find_problem(one) is None
    replay_collapses(one, rough)
    parent = np.asarray(one.node_parent)
    assert ((parent == -1) | (parent > np.arange(len(parent)))).all()
    assert np.count_nonzero(parent >= 0) == 2 * one.n_internal
    monkeypatch.setattr(hierarchy, "SPLIT_FROM", 1 << 40)     # every pass over the whole, on one thread
    whole = build_static_mesh(rough, tiles=1, workers=2)
    assert abs(one.n_internal - whole.n_internal) <= 0.01 * whole.n_internal
    assert len(one.base_faces) <= 1.2 * len(whole.base_faces) + 10


def test_the_collapse_kernels_load_before_threads_call_them():
    """Threads calling a numba kernel first at the same moment each compile it, so the build loads
    its collapse kernels on one thread first (hierarchy._load_kernels), with the argument types the
    tiles and halves use: in a fresh process, a tiled build after it adds no compiled signature
    (a warm-up of other types would leave the real one to the threads' race)."""
    import subprocess
    import sys
    code = """
import caveclod.builder.hierarchy as h
from caveclod.builder.builtin import rough_terrain
from caveclod.kernels import simplify as s
kernels = (s.rank_collapses, s.gather_candidates, s.perform_collapses)
real, seen = h._load_kernels, []
def load(*args):
    assert seen or not any(k.signatures for k in kernels), "loaded before the build"
    real(*args)
    seen.append([list(k.signatures) for k in kernels])
h._load_kernels = load
h.build_static_mesh(rough_terrain(48), tiles=2, workers=2)
h.build_static_mesh(rough_terrain(48), tiles=1, workers=2)
after = [list(k.signatures) for k in kernels]
assert seen[0] == after and all(len(x) == 1 for x in after), (seen, after)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]


def test_tiled_build_is_legal_and_complete(rough):
    mesh = build_static_mesh(rough, tiles=4, workers=2)
    assert find_problem(mesh) is None
    replay_collapses(mesh, rough)
    # Every node has a later parent or is a root; internal nodes are numbered without gaps.
    parent = np.asarray(mesh.node_parent)
    ids = np.arange(len(parent))
    assert ((parent == -1) | (parent > ids)).all()
    assert np.count_nonzero(parent >= 0) == 2 * mesh.n_internal


def test_tiles_merge_to_a_base_mesh_like_a_single_build(rough):
    single = build_static_mesh(rough, tiles=1)
    tiled = build_static_mesh(rough, tiles=4)
    assert abs(single.n_internal - tiled.n_internal) <= 0.01 * single.n_internal
    assert len(tiled.base_faces) <= 1.5 * len(single.base_faces) + 20
    # Roots bound the same surface: their errors agree within a factor.
    roots_s = np.asarray(single.node_parent)[single.n_positions:] < 0
    roots_t = np.asarray(tiled.node_parent)[tiled.n_positions:] < 0
    es, et = single.node_error[roots_s].max(), tiled.node_error[roots_t].max()
    assert 0.5 * es <= et <= 2.0 * es, (es, et)
    # Borders fixed for a level add levels to the tree, but not many.
    hs = tree_depth(np.asarray(single.node_parent))
    ht = tree_depth(np.asarray(tiled.node_parent))
    assert ht <= 2 * hs + 10, (hs, ht)


def test_borders_are_the_positions_between_tiles():
    src, _ = prepare_source(rough_terrain(32))
    fp = src.face_positions.astype(np.int32)
    grid = tile_grid(src.positions, fp, 4)
    assert grid.levels == 3
    live = np.ones(len(src.positions), bool)
    for level, count in ((0, 16), (1, 4), (2, 1)):
        regions, border = grid.regions(level, fp, live)
        assert len(regions) <= count
        tiles = grid.face_tiles(level)
        for r in regions:
            # Every face around an inside position is in one tile.
            faces = np.flatnonzero(np.isin(fp, r).any(axis=1))
            assert len(np.unique(tiles[faces])) == 1
            assert not border[r].any()
        inside = np.concatenate(regions)
        assert len(np.unique(inside)) == len(inside), "a position in two tiles"
        # A border position touches faces of two tiles.
        for x in np.flatnonzero(border)[:50]:
            assert len(np.unique(tiles[(fp == x).any(axis=1)])) > 1
    assert not grid.regions(2, fp, live)[1].any(), "the last level has no border"


def test_tiles_too_small_to_hold_a_position_inside():
    """An 80-face icosphere in 8 x 8 tiles: every position touches faces of several tiles, so the
    first levels have nothing to move; the build skips them and still makes the hierarchy."""
    import trimesh
    from caveclod.builder.meshfile import source_from_trimesh
    src = source_from_trimesh(trimesh.creation.icosphere(subdivisions=1))
    src.vertex_normal = None
    grid = tile_grid(src.positions, src.face_positions.astype(np.int32), 8)
    assert not grid.regions(0, src.face_positions.astype(np.int32), np.ones(len(src.positions), bool))[0]
    tiled, single = build_static_mesh(src, tiles=8), build_static_mesh(src, tiles=1)
    replay_collapses(tiled, src)
    assert tiled.n_internal == single.n_internal > 0


def test_a_scan_splits_along_its_longest_axes():
    src, _ = prepare_source(range_scan(48))
    grid = tile_grid(src.positions, src.face_positions.astype(np.int32), 2)
    counts = np.bincount(grid.face_tiles(0), minlength=4)
    assert (counts > 0).sum() >= 3


def test_automatic_grid_and_bad_grids():
    assert tiles_per_side(100_000) == 1
    assert tiles_per_side(1_000_000) == 4
    assert tiles_per_side(200_000_000) == 64
    assert tiles_per_side(10, 8) == 8
    with pytest.raises(InputError, match="power of two"):
        tiles_per_side(10, 3)
    assert positions_left_to_merge(10_000) == 1600
    for bad in dict(tiles=3), dict(tiles=0), dict(workers=0), dict(tiles=2.0):
        with pytest.raises(InputError, match="--tiles|--workers"):
            caveclod.build("default", size=8, **bad)


def test_cli_builds_in_tiles(tmp_path, capsys):
    from caveclod.cli import main
    out = tmp_path / "t.cvc"
    assert main(["build", "rough", "--size", "48", "--tiles", "2", "--workers", "2", "-o", str(out), "--quiet",
                 "--json"]) == 0
    mesh = caveclod.load(out)
    assert mesh.info["tiles"] == 2
    assert main(["build", "default", "--size", "8", "--tiles", "6", "-o", str(out), "--quiet"]) == 2
    assert "power of two" in capsys.readouterr().err
