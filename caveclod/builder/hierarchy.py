"""Build a :class:`StaticMesh` from a :class:`SourceMesh`.

The pipeline, each step a module of its own::

    normals (crease angle) -> topology -> surface groups -> the file's vertex
        arrays -> leaf bounds -> passes of collapses -> the file's node arrays
"""

from __future__ import annotations

import math
import os
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numba as nb
import numpy as np

from ..errors import InputError
from ..kernels.bounds import empty_cones, empty_spheres
from ..kernels.carried import new_store
from ..kernels.fans import collect_fan
from ..kernels.simplify import gather_candidates, init_leaves, perform_collapses, rank_collapses
from ..kernels.surfacegap import star_lists
from .memory import give_back_freed_memory
from .normals import add_crease_normals, face_weights, smooth_wedges
from .origin import float32_rounding_note
from ..progress import Progress, stage
from .source import SourceMesh
from ..staticmesh import StaticMesh
from .surfaces import RIGID, SurfaceLayout, corner_vertices, layout_surfaces, rigid_positions
from .tiles import positions_left_to_merge, tile_grid, tiles_per_side
from .tilestore import TileStore, block_level, block_of, block_rows, fingerprint, read_blocks
from .version import build_code
from .topology import Topology, count_components, face_neighbours

PASS_FRACTION = 0.5   # share of ranked collapses a pass may make (shallower tree)


def build_static_mesh(source: SourceMesh | Callable[[], SourceMesh], crease_angle: float | None = None,
                      progress: bool = False, tiles: int | None = None, workers: int | None = None,
                      store: TileStore | None = None) -> StaticMesh:
    """Run the whole offline build; see the module docstring.

    ``source``: the mesh, or a function that makes it; then the build
    holds the only reference and drops the mesh once it has made its own
    arrays from it (:func:`caveclod.build` does this: about 20 bytes a
    triangle less at the peak for a heightfield). ``crease_angle`` (degrees) applies where the source has no normals;
    None takes the source's own default (``SourceMesh.crease_angle``).
    ``tiles`` (per side, a power of two; None chooses by size) and
    ``workers`` (threads; None: the cores) are :func:`collapse_all`'s; the
    file does not depend on ``workers``. ``store``: blocks of tiles made
    by tile jobs (:func:`build_tile_job`) are read from it and merged.
    """
    if callable(source):
        source = source()
    t0 = time.perf_counter()                  # the build's seconds, not the input's loading
    source, face_pos, topo, lay, smooth_rigid = _prepare(source, crease_angle, progress)
    # The file's vertex buffer and face attributes do not depend on the hierarchy: made first, so that the
    # source's vertex arrays and the layout's ids (40 bytes a triangle) are gone before the collapses, whose
    # arrays are the build's peak; what replaces them is the file's compact form (22 bytes).
    arrays = vertex_arrays(source, face_pos, lay)
    positions, materials, notes, origin = source.positions, list(source.materials), list(source.notes), source.origin
    del source
    lay = _for_collapses(lay)
    give_back_freed_memory()                  # after each phase: .memory.give_back_freed_memory
    hier = collapse_all(positions, face_pos, topo, lay, progress, tiles=tiles, workers=workers, store=store)
    give_back_freed_memory()
    with ThreadPoolExecutor(1) as side:         # the report's reasons, meanwhile: they only read
        reasons = side.submit(_base_mesh_reasons, hier, face_pos, topo, lay, arrays["face_material"], smooth_rigid)
        arrays.update(node_arrays(positions, hier))
        mesh = StaticMesh(arrays=arrays, materials=materials)
        mesh.store_derived()                  # so that no server derives them when it starts
        reasons = reasons.result()
    mesh.info = {
        "build_seconds": round(time.perf_counter() - t0, 3),
        "input_triangles": len(face_pos),
        "passes": hier.passes,
        "tiles": hier.tiles,
        "surface_groups": lay.n_groups,
        "classes": mesh.class_tally(),
        "base_mesh": reasons,
        "notes": notes,
        "build_code": build_code(),
    }
    if origin is not None:
        mesh.info["origin"] = list(origin)
    if store is not None:
        mesh.info["blocks_read"] = len(store.loaded)
    if mesh.info["base_mesh"]["large"]:
        mesh.info["notes"].append(mesh.info["base_mesh"]["why"])
    del hier, topo, lay, face_pos
    give_back_freed_memory()
    return mesh


def build_tile_job(source: SourceMesh | Callable[[], SourceMesh], store: TileStore,
                   crease_angle: float | None = None, progress: bool = False, tiles: int | None = None,
                   workers: int | None = None) -> dict:
    """Make and write this job's blocks of tiles (``store.job``); see
    :mod:`caveclod.builder.tilestore`. ``source`` as for
    :func:`build_static_mesh`. Returns a report: blocks written,
    blocks found already written (a retried job), the level of the blocks
    (None: a grid of one tile, left to the merge), the grid and the seconds."""
    if callable(source):
        source = source()
    t0 = time.perf_counter()
    source, face_pos, topo, lay, _ = _prepare(source, crease_angle, progress, report=False)
    positions = source.positions              # a job writes no vertex buffer: the rest of the source can go
    del source
    lay = _for_collapses(lay)
    give_back_freed_memory()
    collapse_all(positions, face_pos, topo, lay, progress, tiles=tiles, workers=workers, store=store)
    return {"tiles_dir": str(store.path), "job": list(store.job), "blocks_written": len(store.made),
            "blocks_found": len(store.loaded), "block_level": store.level,
            "tiles_per_side": tiles_per_side(len(face_pos), tiles), "input_triangles": len(face_pos),
            "seconds": round(time.perf_counter() - t0, 3)}


def _prepare(source: SourceMesh, crease_angle, progress, report: bool = True) -> tuple:
    """(source with normals, face_pos (p, 3) int32, topology, surface layout, RIGID positions with
    smooth normals or None), checked. The last is counted where the build makes normals at the
    source's default crease angle (below 180 degrees), for the report (:func:`_base_mesh_reasons`);
    not at all without ``report`` (a tile job writes no report)."""
    source.validate()
    face_pos = source.face_positions.astype(np.int32)       # once: 0.2 s a gather at 2M faces
    _check_float32_positions(source, face_pos)
    stage(f"preparing {len(source.faces):,} triangles: normals, topology, surface groups", progress)
    by_default = report and crease_angle is None and source.vertex_normal is None and source.crease_angle < 180.0
    input_faces = source.faces if by_default else None
    source, topo = prepare_source(source, crease_angle, face_pos)
    source = _as_stored(source)               # normals from the input's own positions, errors on the file's
    lay = layout_surfaces(face_pos, source.faces.astype(np.int32), source.face_material, topo.nbrs,
                          topo.nonmanifold, len(source.positions))
    if max(lay.n_sgids, len(source.materials)) > 65535:
        raise InputError(f"{lay.n_sgids:,} surface group ids and {len(source.materials):,} materials: at most "
                         "65,535 of each fit the .cvc format; merge materials before building")
    smooth_rigid = None
    if input_faces is not None:
        smooth_rigid = rigid_positions(face_pos, smooth_wedges(face_pos, topo.nbrs, input_faces),
                                       source.face_material, topo.nbrs, topo.nonmanifold)
    return source, face_pos, topo, lay, smooth_rigid


@dataclass
class Hierarchy:
    """What :func:`collapse_all` made; node arrays sized for e + m nodes.

    Attributes:
        m: collapses made (internal nodes). passes: passes run.
        parent: (2e,) int32; child, nfaces: (e, 2); nfn: (e, 4); npos: (e,).
        sphere, cone: (e, 4) float64 and err: (e,) float64, internal nodes
            only (node e + i at row i: a leaf's sphere is its position, its
            error 0 and its cone that of its original faces); ring: (e, 2)
            float32 their ring bounds (reach, error:
            :func:`caveclod.kernels.simplify.ring_bound`).
        creator: (p,) int32 node whose split makes each face, -1 for base.
        rotation: (p,) uint8 corner of each such face that its split's first
            node (t for fl, u for fr) takes, as in the source face.
        base: (k,) int32 base faces; base_nodes, base_nbrs: (k, 3) int32.
        tiles: tiles per side of the build's grid (1: none).
    """

    m: int
    passes: int
    parent: np.ndarray
    child: np.ndarray
    npos: np.ndarray
    nfaces: np.ndarray
    nfn: np.ndarray
    sphere: np.ndarray
    cone: np.ndarray
    err: np.ndarray
    ring: np.ndarray
    creator: np.ndarray
    rotation: np.ndarray
    base: np.ndarray
    base_nodes: np.ndarray
    base_nbrs: np.ndarray
    tiles: int = 1


def collapse_all(positions: np.ndarray, face_pos: np.ndarray, topo: Topology, lay, progress: bool,
                 tiles: int | None = None, workers: int | None = None,
                 store: TileStore | None = None) -> Hierarchy | None:
    """Collapse pass after pass until no legal collapse is left.

    With a grid of tiles (:mod:`caveclod.builder.tiles`; ``tiles`` per side,
    None to choose by size), each level's tiles are simplified at once on
    ``workers`` threads (None: the cores, at most 8; the kernels release the
    GIL), their borders fixed, and their nodes numbered in tile order
    afterwards, so the result does not depend on ``workers``. A level of one
    tile (the last, or the only one of a small mesh) runs in halves cut anew
    each pass (:func:`_collapse_whole`).

    ``store`` (:mod:`caveclod.builder.tilestore`): the blocks of tiles
    tile jobs wrote there are read instead of made; for a tile job
    (``store.job``), only that job's blocks are made and written, and None
    returned.
    """
    e, p = len(positions), len(face_pos)
    P = np.ascontiguousarray(positions, dtype=np.float64)
    F = face_pos.copy()                       # faces over positions, collapsed in place
    N = topo.nbrs.copy()
    vface = np.empty(e, np.int32)
    Q = np.zeros((e, 10))
    sphere, cone = empty_spheres(e), empty_cones(e)       # internal nodes only (a leaf's are made when needed)
    err = np.zeros(e)
    ring = np.zeros((e, 2), np.float32)
    # The leaves' quadrics are made on a second thread while this one makes what needs nothing of them:
    # the original surface's stars (for the other direction), the other arrays and the grid (last, as
    # before: made before the arrays, its temporaries left the one-tile build's peak 8 B a triangle higher).
    with ThreadPoolExecutor(1) as side:
        leaves = side.submit(init_leaves, P, F, N, lay.face_group, vface, Q)
        star_start, star_faces = star_lists(face_pos, e)
        st = _CollapseState(
            P=P, F=F, N=N, vface=vface, Q=Q, sphere=sphere, cone=cone, err=err, ring=ring,
            alive=np.ones(p, bool), cur_node=np.arange(e, dtype=np.int32), parent=np.full(2 * e, -1, np.int32),
            child=np.full((e, 2), -1, np.int32), npos=np.full(e, -1, np.int32), nfaces=np.full((e, 2), -1, np.int32),
            nfn=np.full((e, 4), -1, np.int32), creator=np.full(p, -1, np.int32), rotation=np.zeros(p, np.uint8),
            pt=new_store(p, e), lock=np.full(e, -1, np.int32), best_t=np.full(e, -1, np.int32), best_c=np.zeros(e),
            group=lay.face_group, cls=lay.position_class, pg_start=lay.pos_vstart, pg_groups=lay.vertex_group,
            fixed=topo.nonmanifold, face_pos=face_pos, face_nbrs=topo.nbrs, star_start=star_start,
            star_faces=star_faces)
        grid = tile_grid(P, face_pos, tiles_per_side(p, tiles))
        leaves.result()
    workers = max(1, min(os.cpu_count() or 1, 8)) if workers is None else max(1, int(workers))
    if store is not None:
        store.key = fingerprint((P, face_pos, lay.face_group, lay.position_class, lay.pos_vstart, lay.vertex_group,
                                 topo.nonmanifold), grid.per_side)
    scratch: queue.SimpleQueue = queue.SimpleQueue()      # (mark, stamp counter) per thread at work
    for _ in range(workers):
        scratch.put(_thread_scratch(e))
    _load_kernels(st, scratch)

    bar = Progress("collapsing", total=max(int(np.count_nonzero((st.cls != RIGID) & ~topo.nonmanifold)), 1),
                   enabled=progress)
    start, m, passes = 0, 0, 0
    if store is not None and store.job is None:
        start, m, passes = read_blocks(store, st, grid, e)      # (0, 0, 0) for a grid of one tile
        bar.update(m)
    with _pool_stopped_on_interrupt(workers, st.stop) as pool:
        if store is not None and store.job is not None:
            _make_blocks(st, grid, store, topo.nonmanifold, scratch, pool, bar)
            bar.close()
            return None
        for level in range(start, grid.levels):
            regions, border = grid.regions(level, face_pos, vface >= 0)
            if not regions:
                continue                      # every live position on a border: the next level frees some
            st.fixed = topo.nonmanifold | border if level < grid.levels - 1 else topo.nonmanifold
            st.lock.fill(-1)
            bases = m + np.concatenate([[0], np.cumsum([len(r) for r in regions])])
            if grid.tiles_at(level) == 1:
                made, level_passes = _collapse_whole(st, regions[0], int(bases[0]), scratch, pool, workers, bar)
                m += made
                bar.update(m)
            else:
                made, tile_passes = _collapse_tiles(st, regions, bases, scratch, pool, bar, m)
                level_passes = int(tile_passes.max())
                m = _number_nodes(st, e, m, bases[:-1], made)
            passes += level_passes
    bar.close()
    base = np.flatnonzero(st.alive).astype(np.int32)
    return Hierarchy(m=m, passes=passes, parent=st.parent, child=st.child, npos=st.npos, nfaces=st.nfaces,
                     nfn=st.nfn, sphere=sphere, cone=cone, err=err, ring=ring, creator=st.creator,
                     rotation=st.rotation,
                     base=base, base_nodes=st.cur_node[F[base]].astype(np.int32), base_nbrs=N[base].astype(np.int32),
                     tiles=grid.per_side)


@contextmanager
def _pool_stopped_on_interrupt(workers: int, stop: threading.Event):
    """A pool of ``workers`` threads for the collapses that, when the block raises (Ctrl-C), sets
    ``stop`` and drops the tiles not started before waiting for the rest.

    A plain pool's exit waits for every tile queued: the rest of the level,
    so a Ctrl-C in a 4.2M-triangle build ended the process 11-16 s later.
    With ``stop`` set, a tile at work ends after its current pass
    (:func:`_collapse_region`), and the pool ends within one pass.
    """
    pool = ThreadPoolExecutor(workers)
    try:
        yield pool
    except BaseException:
        stop.set()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _thread_scratch(e: int) -> tuple[np.ndarray, np.ndarray]:
    """A thread's (mark (e,) int32, stamp counter (1,) int64): see
    :func:`caveclod.kernels.simplify.next_stamp`."""
    return np.full(e, -1, np.int32), np.zeros(1, np.int64)


def _collapse_tiles(st: _CollapseState, regions, bases, scratch, pool, bar, m) -> tuple[np.ndarray, np.ndarray]:
    """Simplify a level's tiles (``regions``, their nodes numbered from
    ``bases``) at once, each stopping where the merge takes over; returns
    (nodes made, passes), both (t,) int64."""
    # Largest tiles first: the level's last tile then is a small one, and the
    # threads finish together instead of one running a large tile alone
    # (the tiles are independent, so the order changes nothing they make).
    order = sorted(range(len(regions)), key=lambda i: -len(regions[i]))
    jobs = {i: pool.submit(_collapse_region, st, regions[i], int(bases[i]), scratch,
                           keep=positions_left_to_merge(len(regions[i]))) for i in order}
    made, passes = np.zeros(len(regions), np.int64), np.zeros(len(regions), np.int64)
    for i in order:
        made[i], passes[i] = jobs[i].result()
        bar.update(m + int(made.sum()))
    return made, passes


def _make_blocks(st: _CollapseState, grid, store: TileStore, nonmanifold, scratch, pool, bar) -> None:
    """A tile job: simplify this job's blocks (tiles of the level
    :func:`block_level` picks) through every level up to theirs, and write
    each block's rows. Nodes are numbered as if the job's blocks were the
    whole mesh; the merge shifts them (:func:`read_blocks`)."""
    e = len(st.P)
    k = block_level(grid, store.job[1])
    if k is None:
        return                                # one tile: the merge builds it all
    mine = [b for b in np.unique(grid.face_tiles(k)).tolist() if store.mine(b)]
    store.loaded.extend(b for b in mine if store.finished(b, k))          # written by an earlier try
    blocks = [b for b in mine if b not in store.loaded]
    store.level = k
    faces, positions = grid.members(k, st.face_pos)
    bar.label = f"collapsing blocks of tile job {store.job[0]}/{store.job[1]}"
    bar.total = max(sum(len(positions.get(b, ())) for b in blocks), 1)     # each collapse removes one of them
    todo = np.zeros(grid.tiles_at(k) ** 2, bool)
    todo[blocks] = True
    segments: dict[int, list] = {b: [] for b in blocks}
    m = 0
    for level in range(k + 1):
        regions, border = grid.regions(level, st.face_pos, st.vface >= 0)
        tiles = grid.face_tiles(level)[st.vface[[r[0] for r in regions]]] if regions else np.zeros(0, np.int32)
        owner = block_of(tiles, grid.tiles_at(level), k - level)
        mine = [i for i in range(len(regions)) if todo[owner[i]]]
        if not mine:
            continue
        st.fixed = nonmanifold | border
        st.lock.fill(-1)
        regions = [regions[i] for i in mine]
        bases = m + np.concatenate([[0], np.cumsum([len(r) for r in regions])])
        made, passes = _collapse_tiles(st, regions, bases, scratch, pool, bar, m)
        starts = m + np.concatenate([[0], np.cumsum(made)[:-1]])
        for j, i in enumerate(mine):
            segments[int(owner[i])].append((level, int(tiles[i]), int(starts[j]), int(made[j]), int(passes[j])))
        m = _number_nodes(st, e, m, bases[:-1], made)
    face_block = grid.face_tiles(k)
    for b in blocks:
        inside = positions.get(b, np.zeros(0, np.int32))    # none: a block of border positions only
        store.write_block(b, k, block_rows(st, face_block, b, faces[b], inside, segments[b]))
        store.made.append(b)


@dataclass
class _CollapseState:
    """The arrays the collapse kernels share (see :func:`collapse_all`)."""

    P: np.ndarray
    F: np.ndarray
    N: np.ndarray
    vface: np.ndarray
    Q: np.ndarray
    sphere: np.ndarray
    cone: np.ndarray
    err: np.ndarray
    ring: np.ndarray
    alive: np.ndarray
    cur_node: np.ndarray
    parent: np.ndarray
    child: np.ndarray
    npos: np.ndarray
    nfaces: np.ndarray
    nfn: np.ndarray
    creator: np.ndarray
    rotation: np.ndarray
    pt: tuple
    lock: np.ndarray
    best_t: np.ndarray
    best_c: np.ndarray
    group: np.ndarray
    cls: np.ndarray
    pg_start: np.ndarray
    pg_groups: np.ndarray
    fixed: np.ndarray
    face_pos: np.ndarray
    face_nbrs: np.ndarray
    star_start: np.ndarray
    star_faces: np.ndarray
    stop: threading.Event = field(default_factory=threading.Event)
    """Set when the build is interrupted: a tile at work stops after its pass."""


def _collapse_region(st: _CollapseState, region: np.ndarray, base: int, scratch: queue.SimpleQueue,
                     keep: int = 0) -> tuple[int, int]:
    """Collapse inside ``region`` (k,) int32 positions, on this thread, until nothing is left to do.

    Nodes are numbered ``e + base`` on (at most k of them: each collapse
    removes a position of the region). Returns (nodes made, passes). Stops
    once at most ``keep`` of the region's positions are left. (A level of
    one tile runs in halves instead: :func:`_collapse_whole`.)
    """
    held = scratch.get()
    try:
        k = len(region)
        m, pass_id = base, 0
        while not st.stop.is_set():
            before = m
            m = _one_pass(st, region, [region], [held], m, pass_id, None)
            pass_id += 1
            if m == before or k - (m - base) <= keep:
                break
        return m - base, pass_id
    finally:
        scratch.put(held)


def _load_kernels(st: _CollapseState, scratch: queue.SimpleQueue) -> None:
    """Compile (or load from numba's cache) the collapse kernels on this thread, before any
    other thread calls them: a pass over no positions, with the build's own argument types.

    Threads that call a kernel first at the same moment each compile it: the
    halves' first pass, a level's first tiles and the ranking's shares did,
    and a fresh checkout's first tiled build of the rough terrain at 256
    cells took 148 s instead of the 83.5 s it takes once they load first
    (docs/tiled-build.md, "Kernels compile once").
    """
    held = scratch.get()
    try:
        none = np.zeros(0, np.int32)
        _one_pass(st, none, [none], [held], 0, 0, None)
    finally:
        scratch.put(held)


def _one_pass(st: _CollapseState, region: np.ndarray, parts: list, held: list, m: int, pass_id: int,
              pool: ThreadPoolExecutor | None) -> int:
    """One pass over ``region``: rank each of ``parts`` (its shares, one per
    ``held`` scratch; on ``pool`` when given) and make the cheapest
    collapses on this thread, numbered from ``e + m``; returns the new m."""
    k = len(region)
    cost, target, src = np.empty(k), np.empty(k, np.int32), np.empty(k, np.int32)
    args = (st.P, st.F, st.N, st.vface, st.group, st.cls, st.fixed, st.pg_start, st.pg_groups, st.Q, st.lock)
    if pool is not None and len(parts) > 1:
        jobs = [pool.submit(rank_collapses, *args, mark, st.best_t, st.best_c, pass_id, part, counter)
                for part, (mark, counter) in zip(parts, held)]
        for job in jobs:
            job.result()
    else:
        for part, (mark, counter) in zip(parts, held):
            rank_collapses(*args, mark, st.best_t, st.best_c, pass_id, part, counter)
    nc = gather_candidates(st.vface, st.best_t, st.best_c, region, cost, target, src)
    mark, counter = held[0]
    pt_head, pt = st.pt
    return perform_collapses(st.P, st.F, st.N, st.vface, st.alive, st.group, st.cls, st.fixed, st.pg_start,
                             st.pg_groups, st.Q, st.cur_node, st.parent, st.child, st.npos, st.nfaces, st.nfn,
                             st.sphere, st.cone, st.err, st.ring, st.creator, st.rotation, pt_head, pt,
                             st.face_pos, st.face_nbrs, st.star_start, st.star_faces, m, st.lock, mark, pass_id,
                             PASS_FRACTION, cost, target, src, nc, counter)


SPLIT_FROM = 256
"""Live positions from which the whole mesh's level collapses in halves (:func:`_collapse_whole`)."""


def _collapse_whole(st: _CollapseState, region: np.ndarray, base: int, scratch: queue.SimpleQueue,
                    pool: ThreadPoolExecutor | None, workers: int, bar: Progress) -> tuple[int, int]:
    """The level of one tile (the whole mesh, no border) until nothing is left to do; returns (nodes made, passes).

    One thread would make every collapse of this level, and there every
    collapse re-measures hundreds of carried points (the last faces carry
    every removed position). So while at least :data:`SPLIT_FROM` positions
    live, a pass cuts the mesh in two at the median along a direction in the
    plane of the two longest axes of ``region``'s box, turned from pass to
    pass (:data:`GOLDEN_ANGLE`), and makes each half's collapses on its own
    thread, as tiles are: the positions of faces that cross the cut are
    fixed for the pass, so the halves touch disjoint faces and positions,
    and their nodes are numbered half after half (:func:`_move_nodes`).
    The cut depends on the mesh alone, so the result does not depend on
    ``workers``. A pass that makes nothing in halves is followed by a
    whole pass (ranked on every thread, made on one), and the level ends
    when a whole pass makes nothing.
    """
    e = len(st.P)
    box = st.P[region].max(axis=0) - st.P[region].min(axis=0) if len(region) else np.zeros(3)
    axes = np.argsort(box, kind="stable")[::-1][:2]
    nonmanifold = st.fixed
    st.fixed = nonmanifold.copy()             # this level's cuts are set and cleared in it
    held = [scratch.get() for _ in range(workers)]      # as many as the queue holds
    try:
        m, pass_id, split = base, 0, True
        cut = np.zeros(0, np.int32)
        while True:
            # Positions fixed by the last pass's cut rank again (as if they had moved).
            st.lock[cut] = pass_id - 1
            st.fixed[cut] = nonmanifold[cut]
            region = region[st.vface[region] >= 0]
            before = m
            if split and len(region) >= SPLIT_FROM:
                halves, cut = _halves(st.P, axes, pass_id, region, st.F, st.N, st.vface)
                st.fixed[cut] = True
                bases = (m, m + len(halves[0]))
                if pool is not None and workers > 1:
                    jobs = [pool.submit(_one_pass, st, h, [h], [held[i]], b, pass_id, None)
                            for i, (h, b) in enumerate(zip(halves, bases))]
                    ends = [job.result() for job in jobs]
                else:
                    ends = [_one_pass(st, h, [h], held[:1], b, pass_id, None) for h, b in zip(halves, bases)]
                made = ends[0] - bases[0], ends[1] - bases[1]
                # The second half's nodes follow the first's.
                _move_nodes(e, bases[1], m + made[0], made[1], st.child, st.npos, st.nfaces, st.nfn, st.sphere,
                            st.cone, st.err, st.ring, st.parent, st.cur_node, st.creator)
                m += made[0] + made[1]
                split = m > before
            else:
                cut = np.zeros(0, np.int32)
                parts = np.array_split(region, workers) if pool is not None else [region]
                m = _one_pass(st, region, parts, held[:len(parts)], m, pass_id, pool)
                if m == before:
                    return m - base, pass_id + 1
                split = True
            bar.update(bar.done + m - before)
            pass_id += 1
    finally:
        st.fixed = nonmanifold
        for h in held:
            scratch.put(h)


GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
"""How far each pass in halves turns its cut (radians): no two passes cut along the same line, so no
position waits on a cut for pass after pass (a cut that alternated between two fixed lines drew 11 %
more faces at 1 px on the smooth 1M terrain built in one tile)."""


def _halves(P: np.ndarray, axes: np.ndarray, turn: int, live: np.ndarray, F: np.ndarray, N: np.ndarray,
            vface: np.ndarray) -> tuple[list, np.ndarray]:
    """Cut the live positions ``live`` (k,) int32 ascending in two at their median along a direction
    in the plane of ``axes`` (2,), turned ``turn`` times by :data:`GOLDEN_ANGLE`: ``([below, above]
    ascending int32, cut (c,) int32)``, the positions with a neighbour on the other side (the corners
    of the faces that cross the cut) in ``cut`` and in neither half."""
    c, s = math.cos(turn * GOLDEN_ANGLE), math.sin(turn * GOLDEN_ANGLE)
    step = max(1, len(live) // 65536)         # the median of a sample: halves need not be exact
    sample = live[::step]
    at = float(np.median(P[sample, axes[0]] * c + P[sample, axes[1]] * s))
    side = np.empty(len(live), np.int8)
    _sides(P, int(axes[0]), int(axes[1]), c, s, at, F, N, vface, live, side, np.empty(4096, np.int32))
    return [live[side == 0], live[side == 1]], live[side == 2]


@nb.njit(cache=True, nogil=True)
def _sides(P, a0, a1, c, s, at, F, N, vface, live, side, fan):
    """``side`` (k,) int8 of each of ``live`` (k,): 0 below the line ``P[:, a0] c + P[:, a1] s == at``,
    1 above, 2 on the cut (a face around it has a corner on the other side, or its fan does not fit
    ``fan``, the scratch)."""
    for i in range(live.shape[0]):
        v = live[i]
        mine = P[v, a0] * c + P[v, a1] * s >= at
        side[i] = 1 if mine else 0
        nf, _ = collect_fan(F, N, vface[v], v, fan)
        if nf >= fan.shape[0]:
            side[i] = 2
            continue
        for j in range(nf):
            f = fan[j]
            for k in range(3):
                w = F[f, k]
                if (P[w, a0] * c + P[w, a1] * s >= at) != mine:
                    side[i] = 2
            if side[i] == 2:
                break


@nb.njit(cache=True, nogil=True)
def _move_nodes(e, src, dst, k, child, npos, nfaces, nfn, sphere, cone, err, ring, parent, cur_node, creator):
    """Renumber the ``k`` nodes just made at internal rows ``src`` on as rows ``dst`` on (dst <= src).

    Made in the pass just run, nothing is their parent yet; what names them
    is their children's parent, their position's current node and their
    two faces' creator, each changed here, in place of a pass over every id.
    """
    if k == 0 or src == dst:
        return
    for i in range(k):
        a, b = src + i, dst + i
        child[b, 0], child[b, 1] = child[a, 0], child[a, 1]
        npos[b] = npos[a]
        nfaces[b, 0], nfaces[b, 1] = nfaces[a, 0], nfaces[a, 1]
        for j in range(4):
            nfn[b, j] = nfn[a, j]
            sphere[b, j] = sphere[a, j]
            cone[b, j] = cone[a, j]
        err[b] = err[a]
        ring[b, 0], ring[b, 1] = ring[a, 0], ring[a, 1]
        parent[e + b] = parent[e + a]
        for c in range(2):
            parent[child[b, c]] = e + b
            f = nfaces[b, c]
            if f >= 0:
                creator[f] = e + b
        if cur_node[npos[b]] == e + a:
            cur_node[npos[b]] = e + b
    for r in range(dst + k, src + k):        # rows no node occupies now
        parent[e + r] = -1


def _number_nodes(st: _CollapseState, e: int, m: int, bases: np.ndarray, made: np.ndarray) -> int:
    """Number a level's nodes one after another, tile by tile; returns the new m.

    Each tile numbered its nodes from its own base (``bases`` (t,) internal
    ids, ``made`` (t,) nodes each); the gaps between them close here, which
    keeps every parent after its children (a tile's nodes keep their order,
    and tiles follow earlier levels).
    """
    total = int(made.sum())
    span = int(bases[-1] + made[-1]) - m
    starts = m + np.concatenate([[0], np.cumsum(made)[:-1]]).astype(np.int64)    # each tile's first new id
    bases, made = np.asarray(bases, np.int64), np.asarray(made, np.int64)
    # In place and tile by tile: temporaries of a whole level's rows (a sphere
    # and a cone each) were the build's peak.
    for ids in (st.parent, st.child, st.cur_node, st.creator):
        assert ids.flags.c_contiguous                # reshape(-1) is then a view, changed in place
        _renumber_level(ids.reshape(-1), e, m, bases, made, starts)
    for b, k, s in zip(bases.tolist(), made.tolist(), starts.tolist()):
        if k and b != s:                             # s < b: rows move down, never onto rows still to move
            for a in (st.child, st.npos, st.nfaces, st.nfn, st.sphere, st.cone, st.err, st.ring):
                a[s:s + k] = a[b:b + k]
            st.parent[e + s:e + s + k] = st.parent[e + b:e + b + k]
    st.parent[e + m + total: e + m + span] = -1      # rows left behind: no stale parents for later nodes
    return m + total


@nb.njit(cache=True, nogil=True)
def _renumber_level(ids, e, m, bases, made, starts):
    """In place: node ids ``ids`` (k,) made at this level (>= e + m), numbered
    from their tile's base ``bases`` (t,) int64, get their tile's new ``starts``."""
    for i in range(ids.shape[0]):
        x = ids[i] - e
        if x >= m:
            j = np.searchsorted(bases, x, side="right") - 1
            if 0 <= j and x < bases[j] + made[j]:
                ids[i] = e + starts[j] + (x - bases[j])


def _for_collapses(lay: SurfaceLayout) -> SurfaceLayout:
    """``lay`` without what only the vertex buffer needs (``face_sgid``,
    ``vertex_source``, ``vertex_sgid``: None); the collapses read the rest."""
    return replace(lay, face_sgid=None, vertex_source=None, vertex_sgid=None)


def vertex_arrays(source: SourceMesh, face_pos: np.ndarray, lay: SurfaceLayout) -> dict:
    """The ``.cvc`` file's arrays that do not depend on the hierarchy (see
    :data:`caveclod.staticmesh.ARRAYS`): the vertex buffer, its surface
    group ids and materials, the positions' vertex lists and classes, and
    the faces' materials and surface group ids."""
    vsrc = lay.vertex_source
    d = len(vsrc)
    uv = source.vertex_uv[vsrc] if source.vertex_uv is not None else np.zeros((d, 2), np.float32)
    colors = source.vertex_color[vsrc] if source.vertex_color is not None else np.zeros((0, 4), np.uint8)
    vertex_surface = np.empty(d, np.int64)
    corners = corner_vertices(lay.pos_vstart, lay.vertex_sgid, face_pos, lay.face_sgid)
    vertex_surface[corners.ravel()] = np.repeat(source.face_material, 3)
    P = np.asarray(source.positions, dtype=np.float64)
    return {
        "vertex_positions": P[source.vertex_position[vsrc]].astype(np.float32),
        "vertex_normals": source.vertex_normal[vsrc].astype(np.float32),
        "vertex_uvs": uv.astype(np.float32),
        "vertex_colors": colors.astype(np.uint8),
        "vertex_sgid": lay.vertex_sgid.astype(np.uint16),
        "vertex_surface": vertex_surface.astype(np.uint16),
        "pos_vstart": lay.pos_vstart.astype(np.int32),
        "position_class": lay.position_class,
        "face_material": source.face_material.astype(np.uint16),
        "face_sgid": lay.face_sgid.astype(np.uint16),
    }


def node_arrays(positions: np.ndarray, hier: Hierarchy) -> dict:
    """The ``.cvc`` file's arrays of the hierarchy (see
    :data:`caveclod.staticmesh.ARRAYS`): the faces' creators and rotations,
    the nodes' rows and the base mesh. ``positions`` (e, 3) float64."""
    e, m = len(positions), hier.m
    n = e + m
    P = np.asarray(positions, dtype=np.float64)
    return {
        "face_creator": hier.creator,
        "face_rotation": hier.rotation,
        "node_parent": hier.parent[:n].copy(),
        "node_links": np.c_[hier.child[:m], hier.nfaces[:m], hier.nfn[:m]].astype(np.int32),
        "node_position": hier.npos[:m].copy(),
        "node_bound": np.c_[_round_spheres(hier.sphere[:m], P), _round_up(hier.err[:m])],
        "node_cone": _round_cones(hier.cone[:m]),
        "node_ring": _round_rings(hier.ring[:m], hier.sphere[:m], P),
        "base_faces": hier.base,
        "base_face_nodes": hier.base_nodes,
        "base_face_nbrs": hier.base_nbrs,
    }


def _base_mesh_reasons(hier: Hierarchy, face_pos: np.ndarray, topo: Topology, lay, face_material,
                       smooth_rigid: int | None = None) -> dict:
    """What keeps the base mesh from shrinking further, for the report.

    Large means over 1% of the faces or 300, whichever is larger. Every
    piece of the mesh keeps a face; non-manifold positions never move; RIGID
    positions (where seams meet, or end) never float; seams between
    materials may only be slid along, so every material's region keeps
    faces of its own. ``material_border_faces`` counts the base faces with a
    corner on a border between two materials: what a material map costs.
    ``smooth_rigid``: the RIGID positions the mesh would have with smooth
    normals, where the build made normals at the default crease angle
    (None otherwise): on a scan, creases cut by roughness, not by hard edges,
    can make most of them.
    """
    p, e = len(face_pos), len(topo.nonmanifold)
    face_material = np.asarray(face_material, np.int32)
    base = len(hier.base)
    components = int(count_components(topo.nbrs))
    pinned = int(np.count_nonzero(topo.nonmanifold))
    rigid = int(np.count_nonzero(lay.position_class == RIGID))
    nbrs = topo.nbrs
    other = np.where(nbrs >= 0, face_material[np.maximum(nbrs, 0)], -1)
    border = (nbrs >= 0) & (other != np.asarray(face_material)[:, None])
    on_border = np.zeros(e, bool)
    on_border[face_pos[border]] = True
    on_border[np.roll(face_pos, -1, axis=1)[border]] = True
    nodes = hier.base_nodes
    corner_pos = np.where(nodes < e, nodes, hier.npos[np.maximum(nodes - e, 0)])
    material_faces = int(np.count_nonzero(on_border[corner_pos].any(axis=1)))
    large = base > max(0.01 * p, 300)
    reasons = []
    if components > 1:
        reasons.append(f"{components:,} separate pieces, each keeping at least one face (cameras hide a piece "
                       "while it is smaller than their tolerance or out of view)")
    # An edge two faces use in the same direction: faces wound inconsistently (a scan's export, a
    # mirrored part), cut apart like a non-manifold edge; the cause is the file's, and fixable.
    flipped = int(np.count_nonzero((topo.edge_faces == 2) & (topo.nbrs < 0))) // 2
    if flipped:
        reasons.append(f"{flipped:,} edges between faces wound in opposite directions, which split pieces and "
                       "pin positions (orient the faces consistently first: MeshLab's 'Re-Orient all faces "
                       "coherently', trimesh.repair.fix_winding)")
    if pinned:
        reasons.append(f"{pinned:,} non-manifold positions that never move")
    if rigid:
        reasons.append(f"{rigid:,} RIGID positions (where {lay.n_groups:,} surface groups' seams meet) that never move"
                       + _crease_clause(rigid, smooth_rigid))
    if material_faces:
        reasons.append(f"{material_faces:,} base faces ({100 * material_faces / max(base, 1):.0f}% of them) on "
                       "borders between materials, which collapses may only slide along")
    why = f"base mesh is {base:,} faces ({100 * base / p:.1f}% of {p:,})"
    why += ": " + "; ".join(reasons) if reasons else ""
    return {"faces": base, "fraction": round(base / p, 6), "components": components,
            "nonmanifold_positions": pinned, "flipped_edges": flipped, "rigid_positions": rigid,
            "rigid_positions_smooth": smooth_rigid,
            "surface_groups": lay.n_groups,
            "material_border_faces": material_faces, "large": large, "why": why}


CREASE_RIGID_NOTE = 100
"""RIGID positions owed to the default crease angle from which the report names it (and at least half of them)."""


def _crease_clause(rigid: int, smooth_rigid: int | None) -> str:
    """What the base-mesh reason adds when the default crease angle's normal seams make most RIGID positions."""
    if smooth_rigid is None:
        return ""
    owed = rigid - smooth_rigid
    if owed < CREASE_RIGID_NOTE or 2 * owed < rigid:
        return ""
    return (f", {owed:,} of them only because the default crease angle cut normal seams ({smooth_rigid:,} with "
            "smooth normals): if this is a scan or photogrammetry, whose roughness is not hard edges, build "
            "with --crease-angle 180")


def _check_float32_positions(source: SourceMesh, face_pos: np.ndarray) -> None:
    """Refuse a mesh some of whose faces float32 turns into points or lines; note a mesh whose
    positions float32 moves by a visible share of an edge (:mod:`.origin`).

    The .cvc stores positions as float32, whose step near a coordinate x is
    about x * 1.2e-7 (2**-23). A mesh small for its distance from the origin (1 m of
    detail 1e8 m out) or with near-duplicate positions from a text file
    would be stored with faces whose corners coincide: zero-area faces where
    the input has surface, and positions the build tells apart that the file
    cannot. Refused whatever their number: the file could not be what the
    build measured, and only the user knows whether to move or weld the mesh.
    ``face_pos`` (p, 3) int32 is ``source.face_positions``.
    """
    collapsed = _collapse_in_float32(np.asarray(source.positions, dtype=np.float32), face_pos)
    n = int(np.count_nonzero(collapsed))
    if n:
        largest = float(np.abs(source.positions[face_pos[collapsed]]).max())
        step = float(np.spacing(np.float32(largest)))
        raise InputError(f"{n:,} of {len(collapsed):,} faces collapse to a point or a line when their positions are "
                         f"rounded to float32, as the .cvc stores them (float32's step near {largest:.3g} is "
                         f"{step:.3g}); build with --origin auto (positions relative to the mesh's centre), or "
                         f"merge positions that close with --weld {2 * step:.2g}")
    note = float32_rounding_note(source.positions, face_pos)
    if note is not None:
        source.notes.append(note)


def _as_stored(source: SourceMesh) -> SourceMesh:
    """``source`` with its positions rounded to float32, as the .cvc stores them, so that every
    error the build measures is measured on the surface the file holds.

    Measured on the float64 input instead, a mesh far from its origin broke
    its bound: a 50k-triangle grid of 0.5 m cells at UTM coordinates
    (x 500,123 m, float32's step there 3 cm), built without ``--origin``,
    showed 1.37 t at 0.5 px (1.53 t with the strict bound), where the same
    positions rounded first showed 0.96 t. A copy: the caller's arrays are
    not changed. After the normals, which are the input's: made from the
    rounded positions they would differ in their last bits from the same
    mesh's normals built near its origin.
    """
    P = np.asarray(source.positions, dtype=np.float64)
    stored = P.astype(np.float32)
    if np.array_equal(stored, P):
        return source
    return replace(source, positions=stored.astype(np.float64))


@nb.njit(cache=True, nogil=True)
def _collapse_in_float32(P32, face_pos):
    """(p,) bool: faces two of whose corners ``P32`` (e, 3) float32 makes equal."""
    out = np.zeros(face_pos.shape[0], np.bool_)
    for f in range(face_pos.shape[0]):
        for k in range(3):
            a, b = face_pos[f, k], face_pos[f, (k + 1) % 3]
            if P32[a, 0] == P32[b, 0] and P32[a, 1] == P32[b, 1] and P32[a, 2] == P32[b, 2]:
                out[f] = True
    return out


def prepare_source(source: SourceMesh, crease_angle: float | None = None,
                   face_pos: np.ndarray | None = None) -> tuple[SourceMesh, Topology]:
    """The source as the build sees it: with normals, and its topology.

    Returns ``(source_with_normals, topology)``; a source that has normals
    comes back unchanged. ``crease_angle`` None takes the source's default;
    ``face_pos`` (p, 3) int32, ``source.face_positions`` if the caller has it.
    Tests use it to know the exact input corners.
    """
    if face_pos is None:
        face_pos = source.face_positions.astype(np.int32)
    # The faces' normals and corner angles need no topology: made on a second thread meanwhile. That
    # thread makes the short-lived arrays; the topology, which lives through the build, is made here
    # (made there, it left the build's peak 3-4 B a triangle higher).
    with ThreadPoolExecutor(1) as side:
        job = side.submit(face_weights, source.positions, face_pos) if source.vertex_normal is None else None
        topo = face_neighbours(face_pos, len(source.positions))
        weights = None if job is None else job.result()
    if weights is not None:
        angle = source.crease_angle if crease_angle is None else crease_angle
        source = add_crease_normals(source, angle, topo, face_pos, weights)
    return source, topo


def _round_up(x: np.ndarray) -> np.ndarray:
    """float32 copy of ``x`` rounded towards +inf (bounds stay bounds)."""
    y = x.astype(np.float32)
    low = y.astype(np.float64) < x
    y[low] = np.nextafter(y[low], np.float32(np.inf))
    return y


def _centre_pad(P: np.ndarray) -> float:
    """More than a float32 centre's rounding moves it, for positions ``P`` (e, 3)."""
    return 4.0 * float(np.finfo(np.float32).eps) * float(np.abs(P).max(initial=1.0))


def _round_spheres(s: np.ndarray, P: np.ndarray) -> np.ndarray:
    """float32 spheres, radii padded by the rounding of float32 centres."""
    out = s.astype(np.float32)
    out[:, 3] = _round_up(s[:, 3] + _centre_pad(P))
    return out


def _round_rings(ring: np.ndarray, s: np.ndarray, P: np.ndarray) -> np.ndarray:
    """float32 ring bounds (reach, error) for the float32 spheres: the reach
    padded by the rounding of both centres and of the ring node's radius
    (at most the node's radius plus its reach)."""
    out = ring.copy()
    reach = ring[:, 0].astype(np.float64)
    out[:, 0] = _round_up(reach + 2.0 * _centre_pad(P) + 1e-6 * (s[:, 3] + reach))
    return out


def _round_cones(c: np.ndarray) -> np.ndarray:
    out = c.astype(np.float32)
    out[:, 3] = _round_up(np.minimum(c[:, 3] + 1e-6, np.pi))
    return out
