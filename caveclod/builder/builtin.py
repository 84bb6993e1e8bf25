"""The built-in sources: meshes to build with no data to find.

* ``default``: smooth terrain in the spirit of the paper's Three Lakes and
  Cliff models (Kram & Shaw 4.1): lakes with flat water surfaces, hills,
  snowy peaks, and a straight-ish escarpment whose top edge is a sharp crease
  (the one normal seam: its crease angle is 60 degrees), on a fixed 10 km
  square at any resolution.
* ``rough``: terrain with the spectrum of real elevation models: fractal
  detail down to the 10 m cell, ridges and steep slopes, lakes flattened as
  DEMs flatten water, and no-data holes (radar-shadow voids and a jagged
  swath edge), classed like any heightfield without a material map.
* ``scan``: a single-view range scan of a rough object: an open border
  where the scanner's view ends, holes where it was occluded or grazing,
  irregular triangles and slivers, noise, a UV atlas cut into many charts
  and three materials.
* ``debris``: ``20 * size`` separate small parts (boulders, some open;
  seamed blocks; sheets) scattered over a field, one atlas of many charts
  and ten materials: the many-parts meshes that parts vanishing is for.

``caveclod build NAME --size N`` builds one; :data:`BUILTINS` maps the names.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .landcover import MATERIALS, classify_terrain
from .source import SourceMesh
from .terrain import heightfield_to_source

TERRAIN_EXTENT = 10_000.0
"""Side of the default terrain square in metres, whatever its resolution."""

LAKE_LEVEL = 300.0
"""Elevation (m) of every lake surface of the default terrain; the lowest point."""

DEFAULT_CREASE_ANGLE = 60.0
"""The default terrain's crease angle: only the cliff's top edge is sharper."""

ROUGH_CELL = 10.0
"""Cell size (m) of the rough terrain, as in a 10 m elevation model."""


# --------------------------------------------------------------------------
# default terrain



def default_terrain(size: int = 256, seed: int = 7) -> SourceMesh:
    """The built-in terrain as a mesh: ``size`` x ``size`` cells, 2 * size**2
    triangles, on a fixed :data:`TERRAIN_EXTENT` square (cell size extent/size).
    """
    heights, classes = default_heights(size, seed)
    source = heightfield_to_source(heights, cell_size=TERRAIN_EXTENT / size, z_scale=1.0,
                                   materials=classes, material_names=MATERIALS)
    source.crease_angle = DEFAULT_CREASE_ANGLE
    return source


def default_heights(size: int = 256, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Procedural terrain in the spirit of the paper's Three Lakes and Cliff models.

    The landscape is defined on normalised [0, 1]^2 coordinates, so every size
    shows the same terrain, only sampled finer; ``seed`` moves the features a
    little and changes the hills.

    Returns:
        heights: (size+1, size+1) float64 metres (LAKE_LEVEL .. about 1,500).
        classes: (size, size) int32 class per cell into ``MATERIALS``.
    """
    size = _checked_size(size)
    rng = np.random.default_rng(seed)
    layout = _terrain_layout(rng)
    t = np.linspace(0.0, 1.0, size + 1)  # sample coordinates, x and y alike
    u, v = np.meshgrid(t, t)             # u along columns (x), v along rows (y)
    heights = (_rolling_hills(t, layout)
               + _plateau_and_cliff(u, v, layout)
               + _peaks(u, v, t, layout))
    heights = _carve_lakes(heights, u, v, t, layout)
    cell = TERRAIN_EXTENT / size
    # Cell by cell, as designed: smooth relief gives clean regions, and the
    # cliff face is a one-cell band of rock that a majority filter would erase.
    classes = classify_terrain(heights, cell, 1.0)
    return heights, classes


def _checked_size(size) -> int:
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
        raise InputError(f"size must be a positive whole number of cells, got {size!r}")
    return int(size)


# Feature layout in normalised coordinates, before seeded jitter.
_LAKES = ((0.20, 0.24, 0.20), (0.52, 0.13, 0.18), (0.80, 0.33, 0.19))  # (u, v, bowl radius)
_PEAKS = ((0.22, 0.84, 0.090, 680.0), (0.50, 0.90, 0.095, 600.0), (0.78, 0.83, 0.085, 640.0))  # (u, v, sigma, m)
_CLIFF_V = 0.58        # escarpment line at u = 0 ...
_CLIFF_TILT = 0.04     # ... rising this much towards u = 1
_CLIFF_WOBBLE = 0.015  # amplitude of its gentle meander
_CLIFF_HEIGHT = 280.0  # metres from foot to top
_CLIFF_WIDTH = 0.003   # horizontal run of the face (30 m): steep at any resolution
_CLIFF_END = 0.42      # the face turns into a gentle ramp east of here ...
_CLIFF_TAPER = 0.10    # ... over this distance
_RAMP_WIDTH = 0.12     # run of the ramp that replaces the face
_HILL_OCTAVES = ((3, 150.0), (6, 70.0), (12, 28.0), (24, 9.0))  # (lattice cells per side, amplitude m)


def _terrain_layout(rng: np.random.Generator) -> dict:
    """Seeded parameters. All random numbers are drawn here, in a fixed order
    and amount independent of ``size``, so the terrain is scale-invariant."""
    lake_shift = rng.uniform(-0.03, 0.03, size=(len(_LAKES), 2))
    peak_shift = rng.uniform(-0.03, 0.03, size=(len(_PEAKS), 2))
    peak_gain = rng.uniform(0.9, 1.1, size=len(_PEAKS))
    lakes = [(u + du, v + dv, r) for (u, v, r), (du, dv) in zip(_LAKES, lake_shift)]
    peaks = [(u + du, v + dv, s, a * g) for (u, v, s, a), (du, dv), g in zip(_PEAKS, peak_shift, peak_gain)]
    return {
        "lakes": lakes,
        "peaks": peaks,
        "cliff_phase": rng.uniform(0.0, 2.0 * np.pi),
        "hills": [rng.random((f + 1, f + 1)) for f, _ in _HILL_OCTAVES],
        "shore": rng.random((9, 9)),   # lattice that makes lake shores irregular
        "crags": rng.random((7, 7)),   # lattice that makes peaks irregular
    }


def _value_noise(t: np.ndarray, lattice: np.ndarray) -> np.ndarray:
    """Value noise in [0, 1] at the (n, n) grid t x t from an (f+1, f+1) lattice.

    Quintic fade keeps it C2, so triangles stay smooth at every resolution.
    The grid is a tensor product, so interpolate along x for every lattice
    row first, then along y: O(f n + n^2) instead of four n^2 gathers.
    """
    f = lattice.shape[0] - 1
    cell = np.minimum((t * f).astype(np.int64), f - 1)
    frac = t * f - cell
    w = frac ** 3 * (frac * (frac * 6.0 - 15.0) + 10.0)
    along_x = lattice[:, cell] * (1.0 - w) + lattice[:, cell + 1] * w       # (f+1, n)
    return along_x[cell] * (1.0 - w)[:, None] + along_x[cell + 1] * w[:, None]  # (n, n)


def _rolling_hills(t: np.ndarray, layout: dict) -> np.ndarray:
    """Base elevation: fBm value noise, 320..about 620 m, low frequencies only.

    The finest octave (24 lattice cells, 9 m) still spans ~2.7 cells at size
    64, and the amplitudes fall faster than the frequencies rise, so the
    surface stays smooth (small dihedral angles) even at the coarsest size
    we test.
    """
    total = sum(a for _, a in _HILL_OCTAVES)
    noise = sum(a * _value_noise(t, lat) for (_, a), lat in zip(_HILL_OCTAVES, layout["hills"]))
    return LAKE_LEVEL + 20.0 + 300.0 * noise / total


def _plateau_and_cliff(u: np.ndarray, v: np.ndarray, layout: dict) -> np.ndarray:
    """A plateau north of a straight-ish line, reached by a cliff in the west.

    West of _CLIFF_END the step rises linearly over _CLIFF_WIDTH: the profile
    has kinks at foot and top, so the top edge is a sharp crease at every
    resolution. Eastwards the face widens into a smooth ramp, so the cliff ends
    without a wall of creases.
    """
    wobble = _CLIFF_WOBBLE * np.sin(2.0 * np.pi * 1.3 * u + layout["cliff_phase"])
    line = _CLIFF_V + _CLIFF_TILT * u + wobble
    across = v - line  # signed distance north of the line (near enough, it is straight-ish)
    taper = _smoothstep((u - _CLIFF_END) / _CLIFF_TAPER)
    # Interpolate the width geometrically: a linear blend would stay near the
    # wide ramp's width for most of the taper.
    width = _CLIFF_WIDTH * (_RAMP_WIDTH / _CLIFF_WIDTH) ** taper
    rise = np.clip(across / width + 0.5, 0.0, 1.0)
    profile = (1.0 - taper) * rise + taper * _smoothstep(rise)
    return _CLIFF_HEIGHT * profile


def _peaks(u: np.ndarray, v: np.ndarray, t: np.ndarray, layout: dict) -> np.ndarray:
    """Gaussian mountains on the plateau, roughened by low-frequency noise."""
    crags = 0.75 + 0.5 * _value_noise(t, layout["crags"])
    bumps = sum(a * np.exp(-((u - pu) ** 2 + (v - pv) ** 2) / (2.0 * s * s))
                for pu, pv, s, a in layout["peaks"])
    return bumps * crags


def _carve_lakes(heights: np.ndarray, u: np.ndarray, v: np.ndarray, t: np.ndarray,
                 layout: dict) -> np.ndarray:
    """Pull the terrain down into bowls, then flood them to LAKE_LEVEL.

    Each bowl blends the terrain towards a floor just below the lake level, so
    the shore falls where the blend weight is near 1 and its slope is gentle:
    the shore crease (water is flat) stays well under 20 degrees. Clamping to
    the lake level makes every lake one flat surface at exactly LAKE_LEVEL.
    """
    floor = LAKE_LEVEL - 15.0
    shore = 0.7 + 0.6 * _value_noise(t, layout["shore"])  # irregular shorelines
    for lu, lv, radius in layout["lakes"]:
        reach = np.hypot(u - lu, v - lv) / radius * shore
        weight = 1.0 - _smoothstep((reach - 0.3) / 0.7)
        heights = heights * (1.0 - weight) + floor * weight
    return np.maximum(heights, LAKE_LEVEL)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """C1 ramp from 0 (x <= 0) to 1 (x >= 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


# --------------------------------------------------------------------------
# rough terrain

_HURST = 0.9            # fBm roughness: power spectrum ~ k^-(2H+2), fractal dimension 3 - H = 2.1
_RIDGE_SHARE = 0.45     # share of the relief made of sharp ridges (steep slopes)
_RELIEF_PER_KM = 240.0  # metres of relief per km of extent (about 600 m over 2.5 km)
_LAKE_QUANTILE = 0.04   # the lowest 4 % of samples become flat lake surfaces
_VOID_QUANTILE = 0.985  # radar-shadow voids: where a smooth field tops this quantile on steep ground
_SWATH_CUT = 0.18       # the swath edge cuts off about this share of one corner


def rough_terrain(size: int = 256, seed: int = 11) -> SourceMesh:
    """Rough terrain as a mesh: ``size`` x ``size`` 10 m cells with no-data holes.

    Classed like any heightfield without a material map (coherent land-cover
    regions) and, as heightfields are, given smooth normals.
    """
    heights = rough_heights(size, seed)
    return heightfield_to_source(heights, cell_size=ROUGH_CELL, z_scale=1.0)


def rough_heights(size: int = 256, seed: int = 11) -> np.ndarray:
    """(size+1, size+1) float64 metres, NaN where the model has no data.

    Spectral synthesis: fractional Brownian motion with Hurst exponent
    :data:`_HURST` (the range measured on real relief), generated on a grid
    twice as large and cropped so that the FFT's periodicity does not show,
    plus ridged noise (folded fBm) for sharp crests. Relief grows with the
    extent as real relief does. The lowest samples are flattened into lakes;
    voids appear on steep ground and along a jagged swath edge.
    """
    size = _checked_size(size)
    rng = np.random.default_rng(seed)
    n = size + 1
    base = _fbm(2 * n, rng)[:n, :n]
    ridged = 1.0 - np.abs(2.0 * _unit(_fbm(2 * n, rng, hurst=1.1)[:n, :n]) - 1.0)
    z = (1.0 - _RIDGE_SHARE) * _unit(base) + _RIDGE_SHARE * ridged ** 2
    relief = _RELIEF_PER_KM * size * ROUGH_CELL / 1000.0
    z = 200.0 + relief * _unit(z)
    z = np.maximum(z, np.quantile(z, _LAKE_QUANTILE))          # flat lakes at the lowest level
    voids = _unit(_fbm(2 * n, rng, hurst=1.2)[:n, :n])
    gy, gx = np.gradient(z, ROUGH_CELL)
    steep = np.degrees(np.arctan(np.hypot(gx, gy))) > 30.0
    holes = (voids > np.quantile(voids, _VOID_QUANTILE)) & steep
    t = np.linspace(0.0, 1.0, n)
    u, v = np.meshgrid(t, t)
    edge = 0.05 * _unit(_fbm(2 * n, rng, hurst=0.6)[:n, :n])  # jagged
    holes |= (u + v) > 2.0 - 2.0 * _SWATH_CUT + edge
    z[holes] = np.nan
    return z


def _fbm(n: int, rng: np.random.Generator, hurst: float = _HURST) -> np.ndarray:
    """(n, n) fractional Brownian surface by spectral synthesis (amplitude ~ k^-(H+1))."""
    kx = np.fft.fftfreq(n)[:, None]
    ky = np.fft.rfftfreq(n)[None, :]
    k = np.hypot(kx, ky)
    k[0, 0] = np.inf                          # no mean
    spectrum = (rng.normal(size=k.shape) + 1j * rng.normal(size=k.shape)) * k ** -(hurst + 1.0)
    return np.fft.irfft2(spectrum, s=(n, n))


def _unit(a: np.ndarray) -> np.ndarray:
    """``a`` scaled to [0, 1]."""
    lo, hi = np.nanmin(a), np.nanmax(a)
    return (a - lo) / max(hi - lo, 1e-300)


# --------------------------------------------------------------------------
# range scan

_SCAN_GRAZING = 0.2      # faces seen at a cosine under this are not captured
_SCAN_NOISE = 0.0008     # range noise, in units of the object's radius
_SCAN_HOLES = 6          # occlusion holes (discs in the image)
_SCAN_DROPOUT = 0.002    # share of samples lost one by one (specular dropouts)
_SCAN_CHARTS = 6         # the UV atlas cuts the image into charts x charts
_SCAN_MATERIALS = ("stone", "moss", "lichen")


def range_scan(size: int = 128, seed: int = 5) -> SourceMesh:
    """A single-view range scan of a rough boulder: ``size`` x ``size`` samples.

    The scanner looks along -y. Each sample of its image is a point on the
    boulder's visible side; neighbouring samples make two triangles (split
    along a random diagonal, sample positions jittered, so triangles are
    irregular and some are slivers). Faces the scanner sees too obliquely are
    not captured (the open border of the scan), a few discs of the image are
    occluded (holes) and single samples drop out (pinholes, bow-tie
    vertices). UVs come from an atlas of ``_SCAN_CHARTS``^2 charts packed
    apart (a seam at every chart border) and chart groups carry three
    materials. Units: the boulder has a radius of about 1.
    """
    size = _checked_size(size)
    if size < 4:
        raise InputError(f"a range scan needs at least 4 x 4 samples, got --size {size}")
    rng = np.random.default_rng(seed)
    n = size + 1
    t = np.linspace(-0.98, 0.98, n)
    jitter = rng.uniform(-0.3, 0.3, (n, n, 2)) * (t[1] - t[0])
    x = t[None, :] + jitter[..., 0]
    z = t[:, None] + jitter[..., 1]
    rho2 = x * x + z * z
    seen = rho2 < 0.97
    y = np.sqrt(np.clip(1.0 - rho2, 0.0, None))
    d = np.stack([x, y, z], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    points = d * _boulder_radius(d, rng)[..., None]
    points[..., 1] += rng.normal(0.0, _SCAN_NOISE, (n, n))      # range noise along the view
    seen &= rng.random((n, n)) > _SCAN_DROPOUT
    for cx, cz, r in zip(rng.uniform(-0.7, 0.7, _SCAN_HOLES), rng.uniform(-0.7, 0.7, _SCAN_HOLES),
                         rng.uniform(0.04, 0.12, _SCAN_HOLES)):
        seen &= (x - cx) ** 2 + (z - cz) ** 2 > r * r

    # Two triangles per cell of four seen samples, split along a random diagonal.
    ids = np.arange(n * n).reshape(n, n)
    a, b, c, dd = ids[:-1, :-1], ids[:-1, 1:], ids[1:, 1:], ids[1:, :-1]
    ok = seen[:-1, :-1] & seen[:-1, 1:] & seen[1:, 1:] & seen[1:, :-1]
    flip = rng.random(ok.shape) < 0.5
    t1 = np.where(flip[..., None], np.stack([a, b, dd], -1), np.stack([a, b, c], -1))
    t2 = np.where(flip[..., None], np.stack([b, c, dd], -1), np.stack([a, c, dd], -1))
    cells = np.flatnonzero(ok.ravel())
    # Reversed, the image's cells wind counter-clockwise seen from the
    # scanner (+y): outward normals face it.
    faces = np.concatenate([t1.reshape(-1, 3)[cells], t2.reshape(-1, 3)[cells]])[:, ::-1]
    # Faces turned away from the scanner, or seen too obliquely, are not captured.
    P = points.reshape(-1, 3)
    normal = np.cross(P[faces[:, 1]] - P[faces[:, 0]], P[faces[:, 2]] - P[faces[:, 0]])
    length = np.linalg.norm(normal, axis=1)
    faces = faces[normal[:, 1] > _SCAN_GRAZING * np.maximum(length, 1e-300)]

    # Charts of the atlas: one vertex per (sample, chart) so chart borders are seams.
    row, col = np.divmod(faces.min(axis=1), n)
    chart = (row * _SCAN_CHARTS // size) * _SCAN_CHARTS + col * _SCAN_CHARTS // size
    k = _SCAN_CHARTS * _SCAN_CHARTS
    used, vertex = np.unique(faces * k + chart[:, None], return_inverse=True)
    sample, vchart = used // k, used % k
    offset = rng.permutation(k)                      # where each chart sits in the atlas
    srow, scol = np.divmod(sample, n)
    uv = np.stack([(scol / n + offset[vchart] % _SCAN_CHARTS) / _SCAN_CHARTS,
                   (srow / n + offset[vchart] // _SCAN_CHARTS) / _SCAN_CHARTS], axis=1)
    material = (chart * 7 // k) % len(_SCAN_MATERIALS)
    position_ids, vertex_position = np.unique(sample, return_inverse=True)
    source = SourceMesh(positions=P[position_ids], vertex_position=vertex_position.astype(np.int64),
                        faces=vertex.reshape(-1, 3).astype(np.int64), face_material=material.astype(np.int32),
                        materials=list(_SCAN_MATERIALS), vertex_uv=uv.astype(np.float32),
                        notes=[f"range scan: {len(faces):,} faces from {int(seen.sum()):,} of {n * n:,} samples"])
    source.validate()
    return source


def _boulder_radius(d: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Radius of the boulder in unit directions ``d`` (..., 3): lumps and grit."""
    r = np.ones(d.shape[:-1])
    for _ in range(12):                                # lumps
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        r += rng.uniform(-0.12, 0.15) * np.exp((d @ c - 1.0) / rng.uniform(0.05, 0.3))
    for _ in range(40):                                # grit: small bumps
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        r += rng.uniform(-0.008, 0.008) * np.cos(rng.uniform(8.0, 20.0) * (d @ c) + rng.uniform(0, 6.3))
    return r


# --------------------------------------------------------------------------
# debris field

DEBRIS_CREASE_ANGLE = 60.0
"""The debris field's crease angle: boulders' lumps stay smooth, blocks' edges are seams."""

_DEBRIS_PER_SIZE = 20          # parts per unit of --size: 256 gives 5,120 parts
_DEBRIS_SPACING = 8.0          # metres of field per sqrt(part)
_DEBRIS_ATLAS = 64             # charts per side of the shared UV atlas
_ROCKS = ("granite", "basalt", "sandstone", "limestone", "slate")
_BLOCKS = ("concrete", "brick", "rusty_metal", "timber")
_DEBRIS_MATERIALS = _ROCKS + _BLOCKS + ("tarp",)


def debris_field(size: int = 256, seed: int = 13) -> SourceMesh:
    """A field of ``20 * size`` separate small parts: what a scanned quarry, a
    rubble site or a city's street furniture looks like to a mesh builder.

    Boulders (70 %: lumpy icospheres, 80 or 320 faces, radii from 0.1 to 5 m,
    a third scanned from above with their bottoms missing, so open borders),
    blocks (25 %: boxes of 1 to 15 m with hard edges, each side its own UV
    chart, so normal and texture seams) and sheets (5 %: bent open 8 x 8
    grids). Each part has its own charts in one shared atlas (a fragmented
    atlas), one of ten materials, a random orientation, and stands on a
    gently sloping field ``8 sqrt(parts)`` metres across: the extent is
    thousands of times the smallest part.
    """
    size = _checked_size(size)
    rng = np.random.default_rng(seed)
    n = _DEBRIS_PER_SIZE * size
    kind = rng.choice(3, n, p=(0.70, 0.25, 0.05))
    side = _DEBRIS_SPACING * np.sqrt(n)
    where = np.c_[rng.uniform(0, side, n), rng.uniform(0, side, n)]
    where = np.c_[where, 0.02 * where[:, 0] + 0.01 * where[:, 1]]
    pieces = []
    for k, make in ((0, _boulders), (1, _blocks), (2, _sheets)):
        ids = np.flatnonzero(kind == k)
        if len(ids):
            pieces.append(make(ids, where[ids], rng))
    # Concatenate (positions, vertex -> position, faces by vertex, per-vertex uv, face material).
    P, VP, F, UV, M = [], [], [], [], []
    np_, nv = 0, 0
    for pos, vpos, faces, uv, mat in pieces:
        P.append(pos)
        VP.append(vpos + np_)
        F.append(faces + nv)
        UV.append(uv)
        M.append(mat)
        np_ += len(pos)
        nv += len(vpos)
    source = SourceMesh(positions=np.concatenate(P), vertex_position=np.concatenate(VP).astype(np.int64),
                        faces=np.concatenate(F).astype(np.int64), face_material=np.concatenate(M).astype(np.int32),
                        materials=list(_DEBRIS_MATERIALS), vertex_uv=np.concatenate(UV).astype(np.float32),
                        crease_angle=DEBRIS_CREASE_ANGLE,
                        notes=[f"debris field: {n:,} parts ({int((kind == 0).sum()):,} boulders, "
                               f"{int((kind == 1).sum()):,} blocks, {int((kind == 2).sum()):,} sheets)"])
    return _drop_unused(source)


def _rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3, 3) uniformly random rotations (QR of Gaussian matrices, signs fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q *= np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1.0
    return q


def _chart_uv(ids: np.ndarray, local: np.ndarray, charts: int = 1, chart: np.ndarray | None = None) -> np.ndarray:
    """UVs in part ``ids``' own cell of the shared atlas; ``local`` (..., 2) in [0, 1],
    ``chart`` (...) which of the part's ``charts`` sub-cells (side by side)."""
    cell = 1.0 / _DEBRIS_ATLAS
    slot = (ids * 7919) % (_DEBRIS_ATLAS * _DEBRIS_ATLAS)        # scattered over the atlas
    u0, v0 = (slot % _DEBRIS_ATLAS) * cell, (slot // _DEBRIS_ATLAS) * cell
    shape = (-1,) + (1,) * (local.ndim - 2)
    c = 0 if chart is None else chart
    u = u0.reshape(shape) + cell * (c + 0.05 + 0.9 * local[..., 0]) / charts
    v = v0.reshape(shape) + cell * (0.05 + 0.9 * local[..., 1])
    return np.stack([u, v], axis=-1)


def _boulders(ids, where, rng):
    import trimesh
    P, V, F, UV, M = [], [], [], [], []
    fine = rng.random(len(ids)) < 0.5
    for sub, pick in ((1, ~fine), (2, fine)):
        sel = ids[pick]
        if not len(sel):
            continue
        sphere = trimesh.creation.icosphere(subdivisions=sub)
        d = np.asarray(sphere.vertices)                                  # (v, 3) unit directions
        m = len(sel)
        r = np.ones((m, len(d)))
        for _ in range(5):                                               # lumps
            c = rng.normal(size=(m, 3))
            c /= np.linalg.norm(c, axis=1, keepdims=True)
            r += rng.uniform(-0.15, 0.2, (m, 1)) * np.exp((c @ d.T - 1.0) / rng.uniform(0.1, 0.4, (m, 1)))
        radius = np.clip(rng.lognormal(np.log(0.5), 0.7, m), 0.1, 5.0)
        local = d[None] * (r * radius[:, None])[..., None]               # (m, v, 3)
        pos = np.einsum("mij,mvj->mvi", _rotations(m, rng), local) + where[pick][:, None, :]
        pos[..., 2] += 0.6 * radius[:, None]                             # half sunk in the ground
        uv = _chart_uv(sel, 0.5 + 0.5 * d[None, :, :2] * np.ones((m, 1, 1)))
        faces = np.asarray(sphere.faces)
        # A third were scanned from above: faces looking down were never captured.
        normal_z = np.cross(d[faces[:, 1]] - d[faces[:, 0]], d[faces[:, 2]] - d[faces[:, 0]])[:, 2]
        base = len(d) * np.arange(m)[:, None, None]
        all_faces = faces[None] + base                                   # (m, f, 3)
        keep = ~((rng.random(m) < 1 / 3)[:, None] & (normal_z[None] < -0.02))
        done = sum(len(x) for x in P)                                    # one vertex per position
        P.append(pos.reshape(-1, 3))
        V.append(done + np.arange(m * len(d)))
        F.append(done + all_faces[keep])
        UV.append(uv.reshape(-1, 2))
        M.append(np.repeat(rng.integers(0, len(_ROCKS), m), keep.sum(axis=1)))
    return _join(P, V, F, UV, M)


def _blocks(ids, where, rng):
    import trimesh
    box = trimesh.creation.box().subdivide()                               # unit cube, 48 faces
    p = np.asarray(box.vertices)
    faces = np.asarray(box.faces)
    fn = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    axis = np.abs(fn).argmax(axis=1)
    chart = axis * 2 + (fn[np.arange(len(fn)), axis] > 0)                  # six sides, six charts
    # One vertex per (position, side): every box edge is a UV seam.
    used, vertex = np.unique(faces * 6 + chart[:, None], return_inverse=True)
    vpos, vchart = used // 6, used % 6
    vax = vchart // 2
    plane = np.stack([p[vpos, (vax + 1) % 3], p[vpos, (vax + 2) % 3]], axis=1) + 0.5   # (v, 2) in [0, 1]
    m = len(ids)
    dims = rng.uniform(1.0, 15.0, (m, 3)) * rng.uniform(0.3, 1.0, (m, 3))
    yaw = rng.uniform(0, 2 * np.pi, m)
    rot = np.zeros((m, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = \
        np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw), 1.0
    pos = np.einsum("mij,mvj->mvi", rot, p[None] * dims[:, None, :]) + where[:, None, :]
    pos[..., 2] += 0.5 * dims[:, None, 2]                                  # standing on the ground
    uv = _chart_uv(ids, plane[None] * np.ones((m, 1, 1)), charts=6, chart=vchart[None])
    all_faces = vertex.reshape(-1, 3)[None] + len(vpos) * np.arange(m)[:, None, None]
    return _join([pos.reshape(-1, 3)], [(vpos[None] + len(p) * np.arange(m)[:, None]).ravel()],
                 [all_faces.reshape(-1, 3)], [uv.reshape(-1, 2)],
                 [np.repeat(len(_ROCKS) + rng.integers(0, len(_BLOCKS), m), len(faces))])


def _sheets(ids, where, rng):
    m, k = len(ids), 9
    t = np.linspace(0.0, 1.0, k)
    u, v = np.meshgrid(t, t)
    local = np.stack([u.ravel(), v.ravel()], axis=1)                    # (k*k, 2)
    length = rng.uniform(1.0, 6.0, (m, 1))
    bend = rng.uniform(-0.4, 0.4, (m, 1))
    flat = np.stack([(local[None, :, 0] - 0.5) * length, (local[None, :, 1] - 0.5) * length,
                     bend * length * np.sin(np.pi * local[None, :, 0]) + 0.05], axis=-1)
    yaw = rng.uniform(0, 2 * np.pi, m)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    pos = np.stack([c * flat[..., 0] - s * flat[..., 1], s * flat[..., 0] + c * flat[..., 1], flat[..., 2]], -1)
    pos += where[:, None, :]
    ids_grid = np.arange(k * k).reshape(k, k)
    a, b, cc, d = ids_grid[:-1, :-1], ids_grid[:-1, 1:], ids_grid[1:, 1:], ids_grid[1:, :-1]
    faces = np.concatenate([np.stack([a, b, cc], -1).reshape(-1, 3), np.stack([a, cc, d], -1).reshape(-1, 3)])
    all_faces = faces[None] + k * k * np.arange(m)[:, None, None]
    uv = _chart_uv(ids, local[None] * np.ones((m, 1, 1)))
    return _join([pos.reshape(-1, 3)], [np.arange(m * k * k)], [all_faces.reshape(-1, 3)], [uv.reshape(-1, 2)],
                 [np.full(m * len(faces), len(_DEBRIS_MATERIALS) - 1)])


def _join(P, V, F, UV, M):
    """One kind's (positions, vertex -> position, faces, uvs, face materials) from lists of pieces."""
    return (np.concatenate(P), np.concatenate(V), np.concatenate(F), np.concatenate(UV), np.concatenate(M))


def _drop_unused(source: SourceMesh) -> SourceMesh:
    """Keep only the vertices and positions some face uses (open boulders dropped faces)."""
    used_v, faces = np.unique(source.faces, return_inverse=True)
    used_p, vpos = np.unique(source.vertex_position[used_v], return_inverse=True)
    source.positions = np.asarray(source.positions, np.float64)[used_p]
    source.vertex_position = vpos.astype(np.int64)
    source.faces = faces.reshape(-1, 3).astype(np.int64)
    source.vertex_uv = source.vertex_uv[used_v]
    source.validate()
    return source


BUILTINS = {"default": default_terrain, "rough": rough_terrain, "scan": range_scan, "debris": debris_field}
"""Built-in sources by name: ``(size, seed) -> SourceMesh``."""

TERRAINS = ("default", "rough")
"""Built-ins that are heightfields of ``size`` x ``size`` cells: at most two triangles a cell."""
