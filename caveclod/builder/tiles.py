"""Tiles of a build: which positions may move, level by level.

After Hoppe's block-based construction for large terrains (Hoppe 1998,
*Smooth view-dependent level-of-detail control and its application to
terrain rendering*): a grid of ``g x g`` cells (``g`` a power of two) lies
over the two longest axes of the mesh's bounding box, and each face belongs
to the cell holding its centroid. Level ``L`` groups the cells ``2**L x
2**L`` into tiles; a position lies *inside* a tile when every face around
it is in that tile, and on a *border* otherwise. At each level every tile
is simplified on its own with its borders fixed (until about four times
as many positions are left inside as lie on its border), so tiles can be
simplified at once on several threads and none depends on how the others
went: the result is the same whatever the number of workers. The next level merges
the tiles 2 x 2 and frees the borders between them; the last level is one
tile, the whole mesh, with no border.

Collapses keep a face in its tile (a face only ever takes a new corner that
is inside its own tile), so a border drawn from the source's faces stays
valid however far the tiles were simplified.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..errors import InputError

TILE_FACES = 1 << 16
"""Faces per tile the automatic grid aims at (4 x 4 tiles for the 1M-triangle terrains)."""


def positions_left_to_merge(inside: int) -> int:
    """Positions a tile of ``inside`` movable positions leaves to the next level.

    A tile simplified to nothing inside its fixed border ends as a few
    positions each joined to hundreds of border positions: fans that cost
    most to check and re-measure, and long thin faces. The last collapses
    wait for the merge, where the border moves too. Measured on the 1M-triangle
    terrains (faces a converged camera draws at 1 px, and build time): at
    about the border's length (4 sqrt(k) for a square tile) the first
    level's time halved, but the smooth terrain drew 26 % more faces than a
    single build; at 16 sqrt(k) (6 % of a 62k-position tile) 4-7 % more on
    both terrains (benchmarks/build.py), for most of the time saved.
    """
    return int(16.0 * math.sqrt(inside))


MAX_TILES = 4096
"""Most tiles per side ``--tiles`` accepts."""


def check_tiles(tiles) -> None:
    """Refuse a tile count the build cannot use (None: chosen by size)."""
    if tiles is not None and (not isinstance(tiles, (int, np.integer)) or tiles < 1 or tiles & (tiles - 1)
                              or tiles > MAX_TILES):
        raise InputError(f"--tiles must be a power of two from 1 to {MAX_TILES} (tiles per side), got {tiles!r}")


def tiles_per_side(n_faces: int, tiles: int | None = None) -> int:
    """Cells per side: ``tiles`` if given (checked by :func:`check_tiles`),
    else the least power of two whose square holds ``n_faces`` at about
    :data:`TILE_FACES` each (1, no tiling, up to twice that)."""
    check_tiles(tiles)
    if tiles is not None:
        return int(tiles)
    g = 1
    while g * g * TILE_FACES * 2 < n_faces:
        g *= 2
    return g


@dataclass
class TileGrid:
    """A build's grid of cells.

    Attributes:
        per_side: g, cells per side (a power of two).
        face_cell: (p, 2) int32 cell (column, row) of each face.
    """

    per_side: int
    face_cell: np.ndarray

    @property
    def levels(self) -> int:
        """Levels of merging: log2(g) + 1 (the last one is the whole mesh)."""
        return self.per_side.bit_length()

    def tiles_at(self, level: int) -> int:
        """Tiles per side at ``level``."""
        return self.per_side >> level

    def face_tiles(self, level: int) -> np.ndarray:
        """(p,) int32 tile of each face at ``level``, row-major over its tiles."""
        side = self.tiles_at(level)
        c = self.face_cell >> level
        return (c[:, 1] * side + c[:, 0]).astype(np.int32)

    def regions(self, level: int, face_pos: np.ndarray, live: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Positions that may move at ``level``, tile by tile.

        Args:
            face_pos: (p, 3) int32 the source's faces over positions (a
                position's faces never leave their tiles, so the source's
                faces say which tiles a position touches).
            live: (e,) bool positions still in the mesh.
        Returns:
            ``(regions, border)``: one ascending int32 array of live inside
            positions per non-empty tile, in tile order; ``border`` (e,)
            bool, positions touching more than one tile.
        """
        e = len(live)
        if self.tiles_at(level) == 1:         # one tile: every live position is inside, none on a border
            inside = np.flatnonzero(live).astype(np.int32)
            return ([inside] if len(inside) else []), np.zeros(e, bool)
        lo, hi = self._tiles_around(level, face_pos, e)
        border = (hi >= 0) & (lo != hi)
        inside = np.flatnonzero((lo == hi) & live).astype(np.int32)
        tile = lo[inside]
        order = np.argsort(tile, kind="stable")          # tile order, ascending positions within
        inside, tile = inside[order], tile[order]
        cuts = np.flatnonzero(np.diff(tile)) + 1
        return [r for r in np.split(inside, cuts) if len(r)], border

    def members(self, level: int, face_pos: np.ndarray) -> tuple[dict, dict]:
        """Each tile's faces and inside positions at ``level``, whether still in the mesh or not.

        Returns ``(faces, positions)``: tile number -> ascending int32 ids,
        for the tiles that have faces (positions: those whose every face is
        in the tile).
        """
        lo, hi = self._tiles_around(level, face_pos, int(face_pos.max(initial=-1)) + 1)
        face_tile = self.face_tiles(level)
        inside = np.flatnonzero((lo == hi) & (hi >= 0)).astype(np.int32)
        return _group(face_tile, np.arange(len(face_tile), dtype=np.int32)), _group(lo[inside], inside)

    def _tiles_around(self, level: int, face_pos: np.ndarray, e: int) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) (e,) int32: the lowest and highest tile at ``level`` of
        the faces around each position (hi -1: no face)."""
        lo = np.full(e, np.iinfo(np.int32).max, np.int32)
        hi = np.full(e, -1, np.int32)
        _tile_range(self.face_cell, np.ascontiguousarray(face_pos, np.int32), level, self.tiles_at(level), lo, hi)
        return lo, hi


def _group(keys: np.ndarray, ids: np.ndarray) -> dict:
    """key -> ascending ``ids`` with that key (``ids`` ascending)."""
    order = np.argsort(keys, kind="stable")
    keys, ids = keys[order], ids[order]
    cuts = np.flatnonzero(np.diff(keys)) + 1
    return {int(g[0]): i for g, i in zip(np.split(keys, cuts), np.split(ids, cuts)) if len(g)}


@nb.njit(cache=True, nogil=True)
def _tile_range(face_cell, face_pos, level, side, lo, hi):
    """Lowest and highest tile (``lo``, ``hi`` (e,) int32, updated in place) of the faces
    around each position at ``level`` (tiles of ``side`` per side; no per-corner temporaries)."""
    for f in range(face_pos.shape[0]):
        t = (face_cell[f, 1] >> level) * side + (face_cell[f, 0] >> level)
        for k in range(3):
            x = face_pos[f, k]
            if t < lo[x]:
                lo[x] = t
            if t > hi[x]:
                hi[x] = t


def tile_grid(positions: np.ndarray, face_pos: np.ndarray, per_side: int) -> TileGrid:
    """Cells of ``per_side`` x ``per_side`` over ``positions`` (e, 3)'s two longest
    axes; each face of ``face_pos`` (p, 3) int32 goes to its centroid's cell."""
    p = len(face_pos)
    if per_side == 1 or p == 0:
        return TileGrid(per_side, np.zeros((p, 2), np.int32))
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    axes = np.argsort(hi - lo)[::-1][:2].astype(np.int64)
    span = np.maximum((hi - lo)[axes], np.finfo(np.float64).tiny)
    return TileGrid(per_side, _face_cells(np.asarray(positions, np.float64), face_pos, axes, lo[axes], span, per_side))


@nb.njit(cache=True, nogil=True)
def _face_cells(P, face_pos, axes, lo, span, per_side):
    """(p, 2) int32 cell of each face's centroid along ``axes`` (2,)."""
    out = np.empty((face_pos.shape[0], 2), np.int32)
    for f in range(face_pos.shape[0]):
        for j in range(2):
            a = axes[j]
            c = (P[face_pos[f, 0], a] + P[face_pos[f, 1], a] + P[face_pos[f, 2], a]) / 3.0
            k = int((c - lo[j]) / span[j] * per_side)
            out[f, j] = min(max(k, 0), per_side - 1)
    return out
