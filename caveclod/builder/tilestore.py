"""Blocks of a tiled build made by separate processes or machines, kept as files, then merged.

A tiled build (:mod:`caveclod.builder.tiles`) simplifies every tile of a
level on its own, its border fixed, then merges tiles 2 x 2. A *block* is
a tile of some level with every finer tile inside it: everything a block
needs up to its own level lies inside it. This module lets separate
processes, for instance the pods of a Kubernetes Indexed Job writing to a
shared volume (``deploy/k8s/build-*``), each make some blocks through every
level up to theirs, and one last process (the merge) read them all and
make the levels above::

    caveclod build INPUT --tiles-dir DIR --tile-job I/N     # N jobs, I = 0 .. N-1, anywhere
    caveclod build INPUT --tiles-dir DIR -o OUT.cvc           # the merge: reads DIR's blocks

The blocks are the tiles of the coarsest level that has at least N of
them, below the last level (:func:`block_level`); job I makes blocks I,
I + N, ... (numbered row-major). The merge writes the same mesh as
``caveclod build INPUT -o OUT.cvc`` would, whatever N (every array equal,
so the same content hash; only the build report in the header differs:
``tests/test_tilestore.py``). A job retried after a failure keeps the
blocks it finished; a merge missing a block names the job to run again.

**What a block writes.** A tile changes only rows it owns
(docs/tiled-build.md, "Why it is safe to run tiles at once"), and a
block's tiles only rows of the block: of its faces, the corners,
neighbours, life, creator, rotation and carried-point list; of its inside
positions, their face, quadric, current node, carried-point row and leaf
parent; of border positions, the face kept at them where that face is one
of its own (only the block owning it may replace it); and the rows of the
nodes it made. A job numbers nodes as one process would if its own blocks
were the whole mesh (level after level, tile after tile), and the file
says where each tile's nodes start (``segments``); the merge, which knows
every tile's count, moves each tile's nodes to where one process would
have put them, renumbering every node id in the rows with them.

**What it does not change.** Every job still loads the whole input and
prepares it (normals, topology, surface groups): a job needs the memory of
the whole build (``caveclod.builder.memory``), not of its blocks. Jobs
that read only their block's window of the input (out of core) are the
step this layout leaves room for.

**Matching.** Each file records a fingerprint of everything the blocks
read (the positions, faces and surface groups after preparation, the
grid) and of the code that simplifies (the kernels' and the build's
source): a block made from another input, other options or another
version is refused by name, with what to do.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from .version import add_sources

FORMAT = 1
"""Version of the tile files' layout."""

_CODE = ("kernels/simplify.py", "kernels/carried.py", "kernels/surfacegap.py", "kernels/bounds.py",
         "kernels/distance.py", "kernels/fans.py", "kernels/borrow.py", "builder/hierarchy.py", "builder/tiles.py",
         "builder/tilestore.py")
"""Sources whose change may change a tile (they go into the fingerprint)."""

_NAME = re.compile(r"^tile-L(\d+)-(\d+)\.npz$")


def parse_job(text: str) -> tuple[int, int]:
    """``"I/N"`` -> (I, N), 0 <= I < N, or an :class:`InputError` saying what is expected."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not m or not 0 <= int(m.group(1)) < int(m.group(2)):
        raise InputError(f"--tile-job must be I/N with 0 <= I < N (this job's index and the number of jobs, e.g. "
                         f"0/8; in a Kubernetes Indexed Job, the completion index), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def fingerprint(arrays, per_side: int) -> str:
    """Hex digest of ``arrays`` (what the blocks read), the grid and the simplifying code."""
    h = hashlib.blake2b(digest_size=16)
    h.update(f"caveclod tiles {FORMAT} {per_side}".encode())
    add_sources(h, _CODE)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def block_level(grid, jobs: int) -> int | None:
    """The level whose tiles (*blocks*) the jobs share out: the coarsest
    with at least ``jobs`` tiles, below the last (one tile, the merge's);
    None for a grid of one tile."""
    if grid.levels < 2:
        return None
    k = 0
    while k + 1 < grid.levels - 1 and grid.tiles_at(k + 1) ** 2 >= jobs:
        k += 1
    return k


def block_of(tiles: np.ndarray, side: int, up: int) -> np.ndarray:
    """The tiles ``up`` levels above ``tiles`` (numbered row-major over ``side`` per side) that hold them."""
    tiles = np.asarray(tiles, np.int64)
    return ((tiles // side) >> up) * (side >> up) + ((tiles % side) >> up)


@dataclass
class TileStore:
    """A directory of tile jobs' blocks for one input.

    Attributes:
        path: the directory.
        key: :func:`fingerprint` of the input the tiles belong to.
        job: (index, count) when this process is one of ``count`` tile
            jobs (it makes the blocks whose number modulo ``count`` is
            ``index``, then stops), None for the merge.
        loaded, made: block numbers read from files (for a job: written by
            an earlier try) and made here.
        level: the blocks' level, once a job has chosen it.
    """

    path: Path
    key: str = ""
    job: tuple[int, int] | None = None
    loaded: list = field(default_factory=list)
    made: list = field(default_factory=list)
    level: int | None = None

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if self.path.exists() and not self.path.is_dir():
            # Found before the blocks are made, not when the first is written (a FileExistsError then).
            raise InputError(f"--tiles-dir {self.path} is a file, not a directory: give a directory (it is made "
                             "if missing)")
        if self.job is not None:
            # A job writes: found here, not after its blocks' work (a read-only volume said only
            # "Read-only file system", naming a temp file, once everything was made).
            try:
                self.path.mkdir(parents=True, exist_ok=True)
                writable = os.access(self.path, os.W_OK | os.X_OK)
                why = "it cannot be written here"
            except OSError as exc:
                writable, why = False, exc.strerror
            if not writable:
                raise InputError(f"--tiles-dir {self.path}: {why}; a tile job writes its blocks there: give a "
                                 "writable directory (on a shared volume, mounted read-write)")

    def mine(self, block: int) -> bool:
        """Whether this process makes ``block``."""
        return self.job is None or block % self.job[1] == self.job[0]

    def file(self, block: int, level: int) -> Path:
        return self.path / f"tile-L{level}-{block:05d}.npz"

    def present(self) -> list[tuple[int, int]]:
        """(level, block) of each tile file in the directory (not checked)."""
        if not self.path.is_dir():
            return []
        return sorted((int(m.group(1)), int(m.group(2))) for m in map(_NAME.match, os.listdir(self.path)) if m)

    def finished(self, block: int, level: int) -> bool:
        """Whether ``block``'s file is there, whole and from this input (a retried job keeps it).

        Read whole to check its CRC-32s: a damaged block was kept by every
        retry while the merge refused it, so retrying the job (what a
        Kubernetes Job does) never mended it. A damaged one is made again.
        """
        path = self.file(block, level)
        if not path.exists():
            return False
        try:
            with zipfile.ZipFile(path) as z:
                if z.testzip() is not None:
                    return False
        except (OSError, EOFError, zipfile.BadZipFile):
            return False
        self.meta(block, level)
        return True

    def meta(self, block: int, level: int) -> dict:
        """A block file's header, checked against this input: an
        :class:`InputError` naming the file if it is damaged, not a tile file
        or made from another input, options, grid or code."""
        path = self.file(block, level)
        with self._open(path) as z:
            try:
                meta = json.loads(str(z["meta"]))
                meta["segments"] = z["segments"] if "segments" in z.files else None
            except (KeyError, ValueError):
                raise InputError(f"{path} is not a caveclod tile file; delete it or point --tiles-dir "
                                 "elsewhere") from None
            except (OSError, EOFError, zipfile.BadZipFile) as exc:      # a damaged byte: a bad CRC-32
                raise InputError(f"tile file {path} is damaged ({exc}); run its tile job again (it makes a "
                                 "damaged block anew)") from None
        if meta.get("format") != FORMAT or meta.get("key") != self.key:
            raise InputError(f"tile file {path} was made from another input, other build options or another "
                             "caveclod version; run the tile jobs again with the same input, options and image as "
                             "the merge (after emptying the directory)")
        if meta.get("block") != block or meta.get("level") != level or meta["segments"] is None:
            raise InputError(f"tile file {path} does not hold block {block} of level {level}; delete it and run "
                             "its tile job again")
        return meta

    def rows(self, block: int, level: int):
        """A block file's rows, read one array at a time when asked for
        (``rows[name]``; checked by :meth:`meta` first): a context manager."""
        return self._open(self.file(block, level))

    @staticmethod
    def _open(path: Path):
        try:
            return np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise InputError(f"tile file {path} cannot be read ({exc}); delete it and run its tile job "
                             "again") from None

    def write_block(self, block: int, level: int, rows: dict) -> Path:
        """Write a block's rows (:func:`block_rows`: name -> a function
        making the array) atomically: a job killed mid-write leaves no file a
        merge could take for whole. One array is made and written at a time
        (a quarter of a 33.5M-triangle terrain's block is 1.2 GB in all)."""
        meta = {"format": FORMAT, "key": self.key, "block": int(block), "level": int(level),
                "jobs": int(self.job[1]) if self.job else 1}
        path = self.file(block, level)
        # A name of its own: the pid alone is 1 in every container, and two pods of one index
        # (a retry beside a job thought lost) wrote the same temp file.
        tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as z:   # what np.load reads
                for name, make in {"meta": lambda: np.array(json.dumps(meta)), **rows}.items():
                    with z.open(f"{name}.npy", "w", force_zip64=True) as f:
                        np.lib.format.write_array(f, make(), allow_pickle=False)
            os.replace(tmp, path)
        except BaseException as exc:          # Ctrl-C and bugs too: no half file left beside the blocks
            # (as StaticMesh.save does; on a read-only file system the unlink fails too, and its
            # error hid the write's)
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
            if isinstance(exc, OSError):
                raise InputError(f"cannot write tile file {path}: {exc.strerror}; check that --tiles-dir is a "
                                 "writable directory with room (tiles take about 140 bytes per input triangle)") \
                    from None
            raise
        return path


SEGMENT = ("level", "tile", "start", "made", "passes")
"""Columns of a block's ``segments`` (s, 5) int64: one row per tile of the
block that made nodes at a level, with the first of the job's own node
numbers it used (its nodes come in that order in the file's node rows)."""


def _row_arrays(st) -> tuple:
    """(name, array, rows by, holds node ids) of every array a block writes
    and the merge scatters: one table for both, so the two cannot drift.
    ``rows by``: "faces", "positions" (inside ones), "kept" (border
    positions whose kept face is the block's) or "nodes" (internal nodes;
    the arrays indexed by node id are viewed from row e)."""
    pt_head, pt = st.pt
    e = len(st.P)
    return (("F", st.F, "faces", False), ("N", st.N, "faces", False), ("alive", st.alive, "faces", False),
            ("creator", st.creator, "faces", True), ("rotation", st.rotation, "faces", False),
            ("pt_head", pt_head, "faces", False),
            ("Q", st.Q, "positions", False), ("cur_node", st.cur_node, "positions", True),
            ("pt", pt, "positions", False), ("leaf_parent", st.parent, "positions", True),
            ("vface", st.vface, "positions", False), ("vface_kept", st.vface, "kept", False),
            ("child", st.child, "nodes", True), ("npos", st.npos, "nodes", False),
            ("nfaces", st.nfaces, "nodes", False), ("nfn", st.nfn, "nodes", False),
            ("sphere", st.sphere, "nodes", False), ("err", st.err, "nodes", False), ("ring", st.ring, "nodes", False),
            ("node_parent", st.parent[e:], "nodes", True), ("cone", st.cone, "nodes", False))


def block_rows(st, face_tile: np.ndarray, block: int, faces: np.ndarray, positions: np.ndarray,
               segments: list) -> dict:
    """What block ``block`` changed in the build's arrays ``st`` (a
    ``_CollapseState``) through every level up to its own, as name -> a
    function that gathers the rows (made while writing): its faces' rows
    (``faces`` (f,) int32; ``face_tile`` (p,) every face's block), its
    inside positions' (``positions`` (k,) int32), the kept faces of border
    positions that are its own, and its nodes' rows, segment by segment
    (``segments``: tuples of :data:`SEGMENT`)."""
    corners = np.unique(st.face_pos[faces])
    kept = corners[(st.vface[corners] >= 0) & (face_tile[np.maximum(st.vface[corners], 0)] == block)]
    seg = np.array(segments, np.int64).reshape(-1, len(SEGMENT))
    nodes = np.concatenate([np.arange(s, s + n) for s, n in zip(seg[:, 2], seg[:, 3])] or [np.zeros(0, np.int64)])
    ids = {"faces": faces, "positions": positions, "kept": kept, "nodes": nodes}
    rows = {"segments": lambda: seg, **{by: (lambda i=i: i) for by, i in ids.items() if by != "nodes"}}
    rows.update({name: (lambda a=a, i=ids[by]: a[i]) for name, a, by, _ in _row_arrays(st)})
    return rows


def read_blocks(store: TileStore, st, grid, e: int) -> tuple[int, int, int]:
    """The merge: scatter every block of the directory into ``st``, nodes
    renumbered as one process numbers them; returns (the next level to
    build, nodes made, passes made); (0, 0, 0) for a grid of one tile, whose
    jobs write nothing.

    One process numbers a level's nodes tile after tile, levels one after
    another; a job numbered only its own blocks' tiles so. Each tile's
    nodes move to where one process would have put them, every node id in
    the rows with them.
    """
    files = store.present()
    if not files:
        if block_level(grid, 1) is None:
            return 0, 0, 0                    # one tile: the jobs left it all to the merge
        raise InputError(f"{store.path} holds no blocks of tiles: run the tile jobs (--tile-job I/N, --tiles-dir "
                         f"{store.path}) with the same input and options first, or build without --tiles-dir")
    levels = {lv for lv, _ in files}
    if len(levels) > 1:
        raise InputError(f"{store.path} holds tiles of jobs run with different numbers of jobs (blocks of levels "
                         f"{sorted(levels)}); empty it and run the tile jobs again")
    (level,) = levels
    have = {b for _, b in files}
    metas = {b: store.meta(b, level) for b in sorted(have)}            # each from this input and grid
    expected = set(np.unique(grid.face_tiles(level)).tolist()) if level < grid.levels - 1 else set()
    if have - expected:
        raise InputError(f"{store.path} holds blocks this grid does not have; empty it and run the tile jobs again")
    missing = sorted(expected - have)
    if missing:
        jobs = next(iter(metas.values()))["jobs"]
        who = sorted({b % jobs for b in missing})
        raise InputError(f"{len(missing)} of {len(expected)} blocks are missing from {store.path} (made by tile jobs "
                         f"{', '.join(f'{j}/{jobs}' for j in who[:10])}{' ...' if len(who) > 10 else ''}); run those "
                         "jobs again: the merge needs every job's tiles")
    # Global numbering: levels in order, tiles in order within a level.
    seg = np.concatenate([np.c_[m["segments"], np.full(len(m["segments"]), b)] for b, m in metas.items()])
    order = np.lexsort((seg[:, 1], seg[:, 0]))
    starts = np.zeros(len(seg), np.int64)
    starts[order] = np.concatenate([[0], np.cumsum(seg[order, 3])[:-1]])
    m = int(seg[:, 3].sum())
    passes = sum(int(seg[seg[:, 0] == lv, 4].max(initial=0)) for lv in range(level + 1))
    for b in metas:
        mine = seg[:, 5] == b
        try:
            with store.rows(b, level) as rows:
                _scatter(st, rows, seg[mine], starts[mine], e)
        except (OSError, EOFError, zipfile.BadZipFile) as exc:        # a damaged byte: a bad CRC-32
            jobs = metas[b]["jobs"]
            raise InputError(f"tile file {store.file(b, level)} is damaged ({exc}); run tile job {b % jobs}/{jobs} "
                             "again (it makes a damaged block anew)") from None
        except (ValueError, IndexError, KeyError) as exc:
            raise InputError(f"tile file {store.file(b, level)} does not fit this input ({exc}); delete the tiles "
                             "and run the tile jobs again") from None
        store.loaded.append(b)
    return level + 1, m, passes


def _renumber(ids: np.ndarray, local: np.ndarray, made: np.ndarray, start: np.ndarray, e: int) -> np.ndarray:
    """Node ids ``ids`` from a job's numbering to the merge's: a node x >= e
    of the job's segment j (``local[j] <= x - e < local[j] + made[j]``)
    becomes ``e + start[j] + (x - e - local[j])``; leaves and -1 stay."""
    out = np.array(ids, np.int64)
    node = out >= e
    x = out[node] - e
    j = np.searchsorted(local, x, side="right") - 1
    if len(x) and (j.min() < 0 or (x >= local[j] + made[j]).any()):
        raise ValueError("a node id outside the block's segments")
    out[node] = e + start[j] + (x - local[j])
    return out.astype(ids.dtype)


def _scatter(st, rows: dict, seg: np.ndarray, start: np.ndarray, e: int) -> None:
    """Put a block's rows (``rows[name]``: an array) into ``st``; ``seg`` (s, 6)
    its segments (and block), ``start`` (s,) each segment's first node in the
    merge's numbering."""
    # Tiles that made no node start where the next one does: leave them out
    # of the lookup, which would otherwise find them for the next one's nodes.
    some = np.flatnonzero(seg[:, 3] > 0)
    by_local = some[np.argsort(seg[some, 2], kind="stable")]
    local, made, first = seg[by_local, 2], seg[by_local, 3], start[by_local]
    renumber = lambda ids: _renumber(ids, local, made, first, e)       # noqa: E731
    ids = {by: rows[by] for by in ("faces", "positions", "kept")}
    for by, n in (("faces", len(st.alive)), ("positions", len(st.vface)), ("kept", len(st.vface))):
        if len(ids[by]) and (ids[by].min() < 0 or ids[by].max() >= n):
            raise ValueError(f"{by}: an id outside the input")
    if len(start) and int((start + seg[:, 3]).max()) > len(st.child):
        raise ValueError("more nodes than the input has positions")
    total = int(seg[:, 3].sum())
    ends = np.cumsum(seg[:, 3])
    # One array read at a time (``rows`` reads from the file when indexed):
    # the merge holds the build's arrays and one row array of a block.
    for name, target, by, holds_nodes in _row_arrays(st):
        values = renumber(rows[name]) if holds_nodes else rows[name]
        if by != "nodes":
            target[ids[by]] = values
            continue
        if len(values) != total:
            raise ValueError(f"{name}: {len(values)} rows for {total} nodes")
        # Node rows come in the file's segment order; each segment moves to its start.
        for n, s, end in zip(seg[:, 3].tolist(), start.tolist(), ends.tolist()):
            target[s:s + n] = values[end - n:end]
