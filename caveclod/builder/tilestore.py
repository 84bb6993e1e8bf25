"""First-level tiles of a build, kept as files, so that separate processes or machines can make them.

A tiled build's first level (:mod:`caveclod.builder.tiles`) simplifies
every tile on its own, its border fixed. This module lets each of those
tiles be made by another process, for instance one pod each of a
Kubernetes Indexed Job writing to a shared volume (``deploy/k8s/build-*``),
and the rest of the build (the merges, the file) be made by one last
process that reads them::

    caveclod build INPUT --tiles-dir DIR --tile-job I/N     # N jobs, I = 0 .. N-1, anywhere
    caveclod build INPUT --tiles-dir DIR -o OUT.cvc           # the merge: reads DIR's tiles

The merge writes the same mesh as ``caveclod build INPUT -o OUT.cvc``
would (every array equal, so the same content hash; only the build report
in the header differs: ``tests/test_tilestore.py``). A tile is written by
one job; a job retried after a failure keeps the tiles it finished; tiles
the merge cannot find, it makes itself.

**What a tile writes.** A first-level tile changes only rows it owns
(docs/tiled-build.md, "Why it is safe to run tiles at once"): of its own
faces, the corners, neighbours, life, creator, rotation and carried-point
list; of its inside positions, their face, quadric, current node,
carried-point row and leaf parent; of border positions, the face kept at
them where that face is one of its own (only the tile owning it may
replace it); and the node rows it made, numbered from its own base. The
file holds those rows and where they go; the merge scatters them back and
numbers the nodes as an in-process build does (``_number_nodes``).

**What it does not change.** Every job still loads the whole input and
prepares it (normals, topology, surface groups): a job needs the memory of
the whole build (``caveclod.builder.memory``), not of its tile. What the
jobs share out is the first level's work only: on the 4.2M-triangle
default terrain (8 x 8 tiles, two cores a process) a third of the build
(two jobs of 10 s; the merge then took 16.9 s against 24.7 s for the whole
build in one process). The merge levels run in the last process. Jobs
that go on merging their own tiles (node ids then need numbering the merge
can shift) and tiles made from their own window of the input (out of
core) are the steps this layout leaves room for.

**Matching.** Each file records a fingerprint of everything the first
level reads (the positions, faces and surface groups after preparation,
the grid) and of the code that simplifies (the kernels' and the build's
source): a tile made from another input, other options or another version
is refused by name, with what to do.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

FORMAT = 1
"""Version of the tile files' layout."""

_CODE = ("kernels/simplify.py", "kernels/carried.py", "kernels/surfacegap.py", "kernels/bounds.py",
         "kernels/distance.py", "kernels/fans.py", "builder/hierarchy.py", "builder/tiles.py",
         "builder/tilestore.py")
"""Sources whose change may change a tile (they go into the fingerprint)."""

_NAME = re.compile(r"^tile-(\d+)\.npz$")


def parse_job(text: str) -> tuple[int, int]:
    """``"I/N"`` -> (I, N), 0 <= I < N, or an :class:`InputError` saying what is expected."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not m or not 0 <= int(m.group(1)) < int(m.group(2)):
        raise InputError(f"--tile-job must be I/N with 0 <= I < N (this job's index and the number of jobs, e.g. "
                         f"0/8; in a Kubernetes Indexed Job, the completion index), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def fingerprint(arrays, per_side: int) -> str:
    """Hex digest of ``arrays`` (what the first level reads), the grid and the simplifying code."""
    h = hashlib.blake2b(digest_size=16)
    h.update(f"caveclod tiles {FORMAT} {per_side}".encode())
    root = Path(__file__).resolve().parent.parent
    for name in _CODE:
        h.update(name.encode())
        h.update((root / name).read_bytes())
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


@dataclass
class TileStore:
    """A directory of first-level tiles for one input.

    Attributes:
        path: the directory.
        key: :func:`fingerprint` of the input the tiles belong to.
        job: (index, count) when this process is one of ``count`` tile
            jobs (it makes the tiles whose number modulo ``count`` is
            ``index``, then stops), None for the merge (which makes what it
            cannot read).
        loaded, made: tile numbers read from files and made here.
    """

    path: Path
    key: str = ""
    job: tuple[int, int] | None = None
    loaded: list = field(default_factory=list)
    made: list = field(default_factory=list)

    def mine(self, tile: int) -> bool:
        """Whether this process makes ``tile`` (when not in the directory already)."""
        return self.job is None or tile % self.job[1] == self.job[0]

    def file(self, tile: int) -> Path:
        return self.path / f"tile-{tile:05d}.npz"

    def read(self, tile: int, base: int) -> dict | None:
        """Tile ``tile``'s rows (its nodes numbered from ``base``), or None if it has no file.

        A file of another input, grid or code, or a damaged one, is an
        :class:`InputError` naming it.
        """
        path = self.file(tile)
        try:
            with np.load(path, allow_pickle=False) as z:
                rows = {k: z[k] for k in z.files}
        except FileNotFoundError:
            return None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise InputError(f"tile file {path} cannot be read ({exc}); delete it and run its tile job again "
                             "(or run the merge without it: it makes missing tiles itself)") from None
        try:
            meta = json.loads(str(rows.pop("meta")))
        except (KeyError, ValueError):
            raise InputError(f"{path} is not a caveclod tile file; delete it or point --tiles-dir elsewhere") from None
        if meta.get("format") != FORMAT or meta.get("key") != self.key:
            raise InputError(f"tile file {path} was made from another input, other build options or another "
                             "caveclod version; run the tile jobs again with the same input, options and image as "
                             "the merge (or empty the directory: the merge then makes every tile itself)")
        if meta.get("tile") != tile or meta.get("base") != base:
            raise InputError(f"tile file {path} holds tile {meta.get('tile')} from node {meta.get('base')}, not "
                             f"tile {tile} from node {base}; delete it and run its tile job again")
        rows["made"] = np.int64(meta["made"])
        rows["passes"] = np.int64(meta["passes"])
        return rows

    def write(self, tile: int, base: int, rows: dict) -> Path:
        """Write tile ``tile``'s rows (from :func:`tile_rows`) atomically: a
        job killed mid-write leaves no file a merge could take for whole."""
        self.path.mkdir(parents=True, exist_ok=True)
        meta = {"format": FORMAT, "key": self.key, "tile": int(tile), "base": int(base),
                "made": int(rows["made"]), "passes": int(rows["passes"])}
        body = {k: v for k, v in rows.items() if k not in ("made", "passes")}
        buf = io.BytesIO()
        np.savez(buf, meta=np.array(json.dumps(meta)), **body)
        path = self.file(tile)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            tmp.write_bytes(buf.getbuffer())
            os.replace(tmp, path)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise InputError(f"cannot write tile file {path}: {exc.strerror}; check that --tiles-dir is a writable "
                             "directory with room (tiles take about 140 bytes per input triangle)") from None
        return path

    def present(self) -> list[int]:
        """Tile numbers with a file in the directory (not checked)."""
        if not self.path.is_dir():
            return []
        return sorted(int(m.group(1)) for m in map(_NAME.match, os.listdir(self.path)) if m)


def tile_rows(st, faces: np.ndarray, face_tile: np.ndarray, tile: int, region: np.ndarray, base: int, made: int,
              passes: int, e: int) -> dict:
    """What first-level tile ``tile`` changed in the build's arrays ``st`` (a
    ``_CollapseState``): its faces' rows (``faces`` (f,) int32; ``face_tile``
    (p,) the tile of every face), its inside positions' (``region`` (k,)
    int32), the kept faces of border positions that are its own, and its
    node rows ``base .. base + made``."""
    corners = np.unique(st.face_pos[faces])
    kept = corners[(st.vface[corners] >= 0) & (face_tile[np.maximum(st.vface[corners], 0)] == tile)]
    pt_head, pt = st.pt
    nodes = slice(base, base + made)
    return {
        "faces": faces, "F": st.F[faces], "N": st.N[faces], "alive": st.alive[faces], "creator": st.creator[faces],
        "rotation": st.rotation[faces], "pt_head": pt_head[faces],
        "positions": region, "Q": st.Q[region], "cur_node": st.cur_node[region], "pt": pt[region],
        "leaf_parent": st.parent[region],
        "kept": kept, "vface_kept": st.vface[kept], "vface": st.vface[region],
        "child": st.child[nodes], "npos": st.npos[nodes], "nfaces": st.nfaces[nodes], "nfn": st.nfn[nodes],
        "sphere": st.sphere[nodes], "err": st.err[nodes],
        "node_parent": st.parent[e + base:e + base + made], "cone": st.cone[e + base:e + base + made],
        "made": np.int64(made), "passes": np.int64(passes),
    }


def apply_rows(st, rows: dict, base: int, e: int) -> tuple[int, int]:
    """Scatter a tile's rows (:func:`tile_rows`, or read from its file) into
    ``st``; returns (nodes made, passes)."""
    faces, region, kept = rows["faces"], rows["positions"], rows["kept"]
    made = int(rows["made"])
    n_faces, n_pos = len(st.alive), len(st.vface)
    if (len(faces) and (faces.min() < 0 or faces.max() >= n_faces)) or \
            (len(region) and (region.min() < 0 or region.max() >= n_pos)) or \
            (len(kept) and (kept.min() < 0 or kept.max() >= n_pos)) or not 0 <= base + made <= n_pos:
        raise InputError("a tile file's rows do not fit this input; delete the tiles and run the tile jobs again")
    try:
        _scatter(st, rows, faces, region, kept, base, made, e)
    except (ValueError, IndexError, KeyError) as exc:
        raise InputError(f"a tile file's rows do not fit this input ({exc}); delete the tiles and run the tile jobs "
                         "again") from None
    return made, int(rows["passes"])


def _scatter(st, rows, faces, region, kept, base, made, e) -> None:
    pt_head, pt = st.pt
    st.F[faces], st.N[faces], st.alive[faces] = rows["F"], rows["N"], rows["alive"]
    st.creator[faces], st.rotation[faces], pt_head[faces] = rows["creator"], rows["rotation"], rows["pt_head"]
    st.Q[region], st.cur_node[region], pt[region] = rows["Q"], rows["cur_node"], rows["pt"]
    st.parent[region], st.vface[region] = rows["leaf_parent"], rows["vface"]
    st.vface[kept] = rows["vface_kept"]
    nodes = slice(base, base + made)
    st.child[nodes], st.npos[nodes], st.nfaces[nodes], st.nfn[nodes] = \
        rows["child"], rows["npos"], rows["nfaces"], rows["nfn"]
    st.sphere[nodes], st.err[nodes] = rows["sphere"], rows["err"]
    st.parent[e + base:e + base + made], st.cone[e + base:e + base + made] = rows["node_parent"], rows["cone"]
