"""Material classes of heightfield cells: water, grass, rock, snow.

When a heightfield comes without a material map, every cell is classed from
its elevation and slope (:func:`classify_terrain`). On real elevation data
that alone gives salt-and-pepper: rough relief flips the slope test from
cell to cell, and every speck becomes a surface group of its own whose
border is a texture seam the build may never cross (a third of the positions
of a real 10 m DEM ended up on such seams). :func:`coherent_classes` then
makes regions the way land-cover maps are made: a majority (mode) filter
smooths the borders, and a minimum mapping unit merges regions smaller than
a set area into the class that surrounds them (CORINE Land Cover, for one,
maps nothing under 25 ha). Terrain engines texture land cover as such
patches, one texture (draw batch) per class, which is what the per-material
index buffers of caveclod are.

A material map the user gives is kept exactly; only automatic classes are
made coherent.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import InputError

MATERIALS = ("water", "grass", "rock", "snow")
"""Default class names, indexed by class id (what :func:`classify_terrain` returns)."""

WATER, GRASS, ROCK, SNOW = range(4)

ROCK_SLOPE_DEG = 35.0
"""Cells steeper than this are rock (unless under water)."""

SNOW_FRACTION = 0.8
"""Cells above this fraction of the elevation range are snow (unless steep)."""

MODE_RADIUS = 2
"""The majority filter votes over a (2 r + 1)^2 window of cells."""

MODE_PASSES = 2
"""Times the majority filter runs."""

MIN_REGION_FRACTION = 0.004
"""Minimum mapping unit: regions with fewer cells than this share of all
kept cells (and at least :data:`MIN_REGION_CELLS`) join their surroundings."""

MIN_REGION_CELLS = 16


def classify_terrain(heights: np.ndarray, cell_size: float | tuple[float, float], z_scale: float, *,
                     water_level: float | None = None,
                     snow_level: float | None = None,
                     rock_slope_deg: float = ROCK_SLOPE_DEG) -> np.ndarray:
    """Material class of every cell from its elevation and slope, cell by cell.

    Args:
        heights: (rows, cols) samples; NaN marks holes.
        cell_size, z_scale: as in :func:`caveclod.builder.terrain.heightfield_to_source`.
        water_level: world elevation (``height * z_scale``); a cell whose four
            corners all lie at or below it is water. Default: the lowest
            sample, i.e. water is where the terrain is flat at its lowest level
            (lakes or sea already flattened in the data, as elevation models
            flatten water surfaces).
        snow_level: world elevation above which a cell (mean of its corners) is
            snow. Default: 80 % of the way from the lowest to the highest sample.
        rock_slope_deg: cells steeper than this are rock.

    Returns:
        (rows-1, cols-1) int32 class ids into :data:`MATERIALS`: water, then
        rock where steep, then snow where high, grass otherwise. Cells touching
        a NaN sample get -1. See :func:`coherent_classes` for regions.
    """
    from .terrain import _cell_corners, _cell_slope_deg, _checked_heights, _positive_finite, cell_xy
    h = _checked_heights(heights)
    cell_size = cell_xy(cell_size)
    z_scale = _positive_finite("z_scale", z_scale)
    z = h * z_scale
    finite = z[np.isfinite(z)]
    if finite.size == 0:
        raise InputError("every heightfield sample is NaN; give at least one 2x2 block of finite heights")
    lo, hi = float(finite.min()), float(finite.max())
    if water_level is None:
        water_level = lo
    if snow_level is None:
        snow_level = lo + SNOW_FRACTION * (hi - lo)

    a, b, c, d = _cell_corners(z)
    with np.errstate(invalid="ignore"):
        highest = np.maximum(np.maximum(a, b), np.maximum(c, d))
        mean = (a + b + c + d) / 4.0
        slope = _cell_slope_deg(a, b, c, d, cell_size)
        classes = np.full(a.shape, GRASS, dtype=np.int32)
        # Later assignments win: snow < rock < water in precedence, because
        # steep faces shed snow and a lake surface is flat whatever its height.
        classes[mean > snow_level] = SNOW
        classes[slope > rock_slope_deg] = ROCK
        classes[highest <= water_level] = WATER
    classes[~np.isfinite(mean)] = -1
    return classes


def coherent_classes(classes: np.ndarray, min_cells: int | None = None) -> np.ndarray:
    """Land-cover regions from per-cell classes (see the module docstring).

    Args:
        classes: (rows, cols) int class per cell, -1 for holes (kept as -1).
        min_cells: the minimum mapping unit in cells; default
            :data:`MIN_REGION_FRACTION` of the kept cells.

    Returns:
        (rows, cols) int32: the majority filter applied :data:`MODE_PASSES`
        times, then every 4-connected region smaller than ``min_cells`` given
        to the class most of its border touches (repeated until none is left,
        or only regions enclosed by holes are).
    """
    out = np.ascontiguousarray(classes, dtype=np.int32)
    if out.size == 0 or out.max(initial=-1) < 0:
        return out.copy()
    kept = int(np.count_nonzero(out >= 0))
    if min_cells is None:
        min_cells = max(MIN_REGION_CELLS, int(MIN_REGION_FRACTION * kept))
    for _ in range(MODE_PASSES):
        out = _mode_filter(out, int(out.max()) + 1, MODE_RADIUS)
    return _merge_small_regions(out, int(min_cells))


def _mode_filter(classes: np.ndarray, k: int, radius: int) -> np.ndarray:
    """Each kept cell takes the most common class of its window (ties keep the cell's own)."""
    rows, cols = classes.shape
    w = 2 * radius + 1
    votes = np.empty((k, rows, cols))
    for c in range(k):
        # Window sums from a summed-area table: O(cells) per class.
        mask = np.pad((classes == c).astype(np.float64), radius)
        table = np.zeros((rows + w, cols + w))
        table[1:, 1:] = mask.cumsum(axis=0).cumsum(axis=1)
        votes[c] = table[w:, w:] - table[:-w, w:] - table[w:, :-w] + table[:-w, :-w]
    own = np.clip(classes, 0, None)
    np.put_along_axis(votes, own[None], np.take_along_axis(votes, own[None], axis=0) + 0.5, axis=0)
    out = votes.argmax(axis=0).astype(np.int32)
    out[classes < 0] = -1
    return out


@nb.njit(cache=True, nogil=True)
def _merge_small_regions(classes, min_cells):
    """Give 4-connected regions under ``min_cells`` to their commonest neighbour class."""
    rows, cols = classes.shape
    out = classes.copy()
    k = out.max() + 1
    label = np.empty((rows, cols), np.int64)
    queue = np.empty(rows * cols, np.int64)
    border = np.zeros(k, np.int64)
    for _ in range(20):                      # merges cascade; a few rounds settle them
        changed = False
        label[:] = -1
        for seed in range(rows * cols):
            r0, c0 = seed // cols, seed % cols
            if out[r0, c0] < 0 or label[r0, c0] >= 0:
                continue
            cls = out[r0, c0]
            label[r0, c0] = seed
            head, tail = 0, 1
            queue[0] = seed
            border[:] = 0
            while head < tail:
                cell = queue[head]
                head += 1
                r, c = cell // cols, cell % cols
                for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    rr, cc = r + dr, c + dc
                    if rr < 0 or rr >= rows or cc < 0 or cc >= cols or out[rr, cc] < 0:
                        continue
                    if out[rr, cc] != cls:
                        border[out[rr, cc]] += 1
                    elif label[rr, cc] < 0:
                        label[rr, cc] = seed
                        queue[tail] = rr * cols + cc
                        tail += 1
            if tail >= min_cells:
                continue
            best = -1
            for j in range(k):
                if border[j] > 0 and (best < 0 or border[j] > border[best]):
                    best = j
            if best < 0:
                continue                      # an island among holes: nothing to join
            for i in range(tail):
                out[queue[i] // cols, queue[i] % cols] = best
            changed = True
        if not changed:
            break
    return out
