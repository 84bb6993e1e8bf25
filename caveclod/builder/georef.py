"""The grid spacing of georeferenced heightfields, so that a real elevation
model is built at its own scale without ``--cell-size``.

Elevation models say how far apart their samples are: a GeoTIFF in its
``ModelPixelScale`` (or ``ModelTransformation``) tag, in the units of its
coordinate system (metres for a projected one, degrees for a geographic
one), an ESRI ASCII grid in its header's ``cellsize``, and an SRTM
``.hgt`` tile in its name and size (one degree of
latitude and longitude, 1201 or 3601 samples a side). Heights are metres.
Built with a cell size of 1 instead, a 30 m grid would come out thirty
times steeper than it is.

Degrees become metres at the grid's middle latitude on a sphere of the
Earth's mean radius: a sample spacing of ``d`` degrees is ``d * pi / 180 *
R`` metres north-south and that times ``cos(latitude)`` east-west. Over one
degree of latitude the east-west spacing changes by 1-3 % at mid latitudes;
a local flat projection is what a terrain viewer draws anyway.

Where the spacing cannot be read (no tags, a geographic grid with no tie
point to give its latitude, units this module does not know), the build
uses the given ``--cell-size`` or 1 and its report says so.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, replace

import numpy as np

EARTH_RADIUS_M = 6_371_008.8
"""Mean radius of the Earth (IUGG), metres."""

_HGT_NAME = re.compile(r"^([NS])(\d{1,2})([EW])(\d{1,3})", re.IGNORECASE)

# GeoTIFF tag and key numbers (GeoTIFF 1.1, OGC 19-008r4).
_PIXEL_SCALE, _TIEPOINT, _TRANSFORMATION, _GEOKEYS = 33550, 33922, 34264, 34735
_MODEL_TYPE, _RASTER_TYPE, _ANGULAR_UNITS, _LINEAR_UNITS = 1024, 1025, 2054, 3076
_GEOGRAPHIC_TYPE, _PROJECTED_CS = 2048, 3072          # GeographicTypeGeoKey, ProjectedCSTypeGeoKey
_PIXEL_IS_POINT = 2
_PROJECTED, _GEOGRAPHIC = 1, 2
_LINEAR_NAMES = {9001: "metres", 9002: "feet", 9003: "US survey feet"}   # ProjLinearUnitsGeoKey values
_DEGREE, _RADIAN = 9102, 9101
_DEGREES = (9102, 9122)      # degree, and "degree (supplier to define representation)": EPSG:4326's own


@dataclass(frozen=True)
class Spacing:
    """How far apart a grid's samples are, in world units (metres for geographic grids).

    Attributes:
        x: between neighbouring columns.
        y: between neighbouring rows.
        note: where the figures came from, for the build's report.
        origin: for a projected grid that says where it lies, the world (x, y, 0) of its
            south-west sample, which the build puts at (0, 0): the mesh's ``info["origin"]``.
        north_first: the grid's first row is its north edge (False: a GeoTIFF whose
            transformation runs rows northwards).
    """

    x: float
    y: float
    note: str
    origin: tuple[float, float, float] | None = None
    north_first: bool = True


def grid_spacing(path: str | os.PathLike, shape: tuple[int, int]) -> tuple[Spacing | None, str | None]:
    """The sample spacing a heightfield file states, and why none when it states none usable.

    Args:
        path: a ``.tif``/``.tiff``, ``.hgt`` or ``.asc`` heightfield (other types state none).
        shape: (rows, cols) of its grid.

    Returns:
        (spacing or None, a note for the report when the file is georeferenced
        but its spacing was not used, else None).
    """
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext == ".hgt":
        return _hgt_spacing(path, shape)
    if ext in (".tif", ".tiff"):
        return _geotiff_spacing(path, shape)
    if ext == ".asc":
        return _ascii_grid_spacing(path)
    return None, None


def _ascii_grid_spacing(path) -> tuple[Spacing | None, str | None]:
    """An ESRI ASCII grid's ``cellsize`` (or ``dx`` and ``dy``): in its coordinate system's units,
    or, for a geographic grid (:func:`_ascii_grid_is_geographic`), degrees as metres."""
    from .terrain import ascii_grid_header
    header = ascii_grid_header(path)
    dx, dy = header.get("dx", header.get("cellsize")), header.get("dy", header.get("cellsize"))
    if dx is None or dy is None or not (math.isfinite(dx) and math.isfinite(dy) and dx > 0 and dy > 0):
        return None, "the ESRI ASCII grid's header gives no usable cellsize: give --cell-size"
    # The samples are cells: the lower-left corner is half a cell from the south-west sample.
    x0 = header["xllcenter"] if "xllcenter" in header else header.get("xllcorner", math.nan) + dx / 2
    y0 = header["yllcenter"] if "yllcenter" in header else header.get("yllcorner", math.nan) + dy / 2
    geographic = _ascii_grid_is_geographic(path, header, x0, y0, dx, dy)
    if geographic:
        lat = y0 + (header["nrows"] - 1) * dy / 2.0
        if not -90.0 <= lat <= 90.0:
            return None, "the ESRI ASCII grid is geographic but its latitude is out of range: give --cell-size"
        return _degrees_to_metres(dx, dy, lat, f"the ESRI ASCII grid's {dx:.9g} x {dy:.9g} degrees ({geographic})"), \
            None
    origin = (x0, y0, 0.0) if math.isfinite(x0) and math.isfinite(y0) else None
    return Spacing(dx, dy, f"cell size {dx:g} x {dy:g} (in the units of the file's coordinate system) from the "
                           "ESRI ASCII grid's header", origin), None


GEOGRAPHIC_CELL_LIMIT = 0.1
"""An ESRI grid with no .prj whose cells are smaller than this and whose extent lies within
longitudes and latitudes is taken as geographic: no projected DEM has cells of a tenth of a metre
(or foot) placed within 180 units of its coordinate system's origin."""


def _ascii_grid_is_geographic(path, header, x0, y0, dx, dy) -> str | None:
    """Why an ESRI ASCII grid is in degrees (its ``.prj`` beside it says so, or its cells and
    extent look it), or None."""
    prj = os.path.splitext(os.fspath(path))[0] + ".prj"
    try:
        with open(prj, "rb") as f:
            text = f.read(1 << 16).upper()
    except OSError:
        text = None
    if text is not None:
        if b"PROJCS" in text or b"PROJCRS" in text:
            return None
        return "its .prj is geographic" if (b"GEOGCS" in text or b"GEOGCRS" in text) else None
    x1, y1 = x0 + (header["ncols"] - 1) * dx, y0 + (header["nrows"] - 1) * dy
    inside = -180.0 <= x0 and x1 <= 360.0 and -90.0 <= y0 and y1 <= 90.0
    return "no .prj; its cells and extent are those of degrees" if max(dx, dy) < GEOGRAPHIC_CELL_LIMIT and inside \
        else None


def _hgt_spacing(path, shape) -> tuple[Spacing | None, str | None]:
    """An SRTM tile's spacing from its name (``N46E007.hgt``: south-west corner) and side: one
    degree over ``side - 1`` intervals (1201 samples: 3 arc-seconds, 3601: 1)."""
    seconds = 3600.0 / (shape[0] - 1)
    match = _HGT_NAME.match(os.path.basename(os.fspath(path)))
    if not match:
        return None, ("the .hgt file's name does not give its latitude (SRTM tiles are named like N46E007.hgt): "
                      "its spacing is unknown, give --cell-size in metres")
    lat = int(match.group(2)) * (1 if match.group(1).upper() == "N" else -1)
    if not -90 <= lat <= 89:
        return None, (f"the .hgt file's name gives latitude {lat}, outside -90 to 89 (a tile's south edge): its "
                      "spacing is unknown, give --cell-size in metres")
    return _degrees_to_metres(seconds / 3600.0, seconds / 3600.0, lat + 0.5,
                              f"SRTM tile {match.group(0).upper()}, {seconds:g} arc-seconds"), None


def _geotiff_spacing(path, shape) -> tuple[Spacing | None, str | None]:
    """A GeoTIFF's spacing from its ModelPixelScale or ModelTransformation tag."""
    import tifffile

    from .quiet import quiet_reading
    try:
        with quiet_reading("tifffile"), tifffile.TiffFile(path) as tif:
            tags = tif.pages[0].tags
            values = {code: tags[code].value for code in (_PIXEL_SCALE, _TIEPOINT, _TRANSFORMATION, _GEOKEYS)
                      if code in tags}
        # Each tag's numbers as a flat tuple: a damaged file's tag of one value reads as a bare
        # number (len() of it raised TypeError, found by the source fuzzer), of text as a string.
        values = {code: tuple(float(x) for x in np.atleast_1d(np.asarray(v, dtype=np.float64)).ravel())
                  for code, v in values.items()}
    except Exception:   # the pixels were read; damaged tags only cost the spacing
        return None, "the GeoTIFF's georeference tags could not be read: give --cell-size"
    scale = _pixel_scale(values)
    if scale is None:
        return None, None           # a plain TIFF: nothing stated
    sx, sy = scale
    keys = _geokeys(values.get(_GEOKEYS))
    turned = _turned(values)
    if _is_geographic(keys):
        unit = keys.get(_ANGULAR_UNITS, _DEGREE)
        if unit not in _DEGREES + (_RADIAN,):
            return None, f"the GeoTIFF's angular unit (EPSG {unit}) is not degrees or radians: give --cell-size"
        if unit == _RADIAN:
            sx, sy = math.degrees(sx), math.degrees(sy)
        north_first = _north_first(values)
        lat = _middle_latitude(values, shape, sy, unit, north_first)
        if lat is None:
            return None, ("the GeoTIFF is geographic (degrees) but has no tie point to give its latitude: "
                          "give --cell-size")
        spacing = _degrees_to_metres(sx, sy, lat, f"GeoTIFF pixel scale {sx:.9g} x {sy:.9g} degrees")
        return replace(spacing, north_first=north_first, note=spacing.note + turned), None
    units = _LINEAR_NAMES.get(keys.get(_LINEAR_UNITS), "in the units of the file's coordinate system")
    origin, north_first = _projected_origin(values, keys, shape, sx, sy)
    source = "pixel scale" if _PIXEL_SCALE in values else "transformation"
    return Spacing(sx, sy, f"cell size {sx:g} x {sy:g} ({units}) from the GeoTIFF's {source}{turned}", origin,
                   north_first), None


def _is_geographic(keys: dict) -> bool:
    """Whether the GeoKeys put the grid in angles: GTModelTypeGeoKey says geographic, or, with no
    model type, a geographic coordinate system is named and no projected one (GDAL reads such
    files as geographic too)."""
    model = keys.get(_MODEL_TYPE)
    if model is not None:
        return model == _GEOGRAPHIC
    return _GEOGRAPHIC_TYPE in keys and _PROJECTED_CS not in keys


def _turned(values: dict) -> str:
    """A note's tail for a ModelTransformation (with no pixel scale) that rotates or shears the
    grid, else "": the build lays the samples on an axis-aligned grid with the spacing between
    neighbouring samples, and states no origin (the file's corner is not the mesh's (0, 0))."""
    m = values.get(_TRANSFORMATION)
    if _PIXEL_SCALE in values or m is None or len(m) < 8:
        return ""
    a, b, c, d = (float(m[i]) for i in (0, 1, 4, 5))
    if b == 0.0 and c == 0.0:
        return ""
    angle = math.degrees(math.atan2(c, a))
    sheared = abs(a * b + c * d) > 1e-9 * math.hypot(a, c) * math.hypot(b, d)
    return (f"; the transformation {'shears and ' if sheared else ''}rotates the grid by {angle:.4g} degrees in the "
            "file's coordinates: built unrotated, with no origin")


def _projected_origin(values: dict, keys: dict, shape, sx: float, sy: float):
    """(world (x, y, 0) of the south-west sample or None, whether the first row is the north).

    From the first tie point (raster point (i, j) at model (X, Y)) with the pixel scale, or from
    an axis-aligned ModelTransformation. A pixel's sample is its centre (raster point c + 0.5, r +
    0.5) unless the GeoKey GTRasterType says PixelIsPoint."""
    half = 0.0 if keys.get(_RASTER_TYPE) == _PIXEL_IS_POINT else 0.5
    rows = shape[0]
    tie, m = values.get(_TIEPOINT), values.get(_TRANSFORMATION)
    if tie is not None and len(tie) >= 6 and _PIXEL_SCALE in values:
        i, j, x, y = float(tie[0]), float(tie[1]), float(tie[3]), float(tie[4])
        origin, north_first = (x + (half - i) * sx, y - (rows - 1 + half - j) * sy), True
    elif m is not None and len(m) >= 8 and float(m[1]) == 0.0 and float(m[4]) == 0.0 and float(m[5]) != 0.0:
        north_first = _north_first(values)
        south_row = rows - 1 if north_first else 0
        origin = (float(m[3]) + half * float(m[0]), float(m[7]) + (south_row + half) * float(m[5]))
    else:
        return None, True
    if not all(math.isfinite(v) for v in origin):
        return None, north_first
    return (origin[0], origin[1], 0.0), north_first


def _pixel_scale(values: dict) -> tuple[float, float] | None:
    """(x, y) sample spacing from ModelPixelScale, else the columns of ModelTransformation;
    None when neither gives two positive finite numbers."""
    if _PIXEL_SCALE in values and len(values[_PIXEL_SCALE]) >= 2:
        sx, sy = (abs(float(v)) for v in values[_PIXEL_SCALE][:2])
    elif _TRANSFORMATION in values and len(values[_TRANSFORMATION]) >= 8:
        m = [float(v) for v in values[_TRANSFORMATION]]
        sx, sy = math.hypot(m[0], m[4]), math.hypot(m[1], m[5])
    else:
        return None
    if not (math.isfinite(sx) and math.isfinite(sy) and sx > 0.0 and sy > 0.0):
        return None
    return sx, sy


def _geokeys(directory) -> dict[int, int]:
    """Short-valued keys of a GeoKeyDirectory (header of 4, then key, location, count, value)."""
    if directory is None:
        return {}
    d = [int(v) for v in directory]
    keys = {}
    for i in range(4, len(d) - 3, 4):
        if d[i + 1] == 0:          # location 0: the value is in the entry itself
            keys[d[i]] = d[i + 3]
    return keys


def _north_first(values: dict) -> bool:
    """Whether the first row is the north: always with a pixel scale (its y runs south by the
    GeoTIFF spec), with a transformation when its y scale is negative (as GDAL writes them)."""
    m = values.get(_TRANSFORMATION)
    if _PIXEL_SCALE in values or m is None or len(m) < 8:
        return True
    return not float(m[5]) > 0.0


def _middle_latitude(values: dict, shape, sy_degrees: float, unit: int, north_first: bool = True) -> float | None:
    """Latitude (degrees) of the grid's middle, from its first tie point (raster i, j to model x,
    y) or its transformation; rows run south unless ``north_first`` is False."""
    tie = values.get(_TIEPOINT)
    if tie is None or len(tie) < 6:
        t = values.get(_TRANSFORMATION)
        if t is None or len(t) < 8:
            return None
        j, y = 0.0, float(t[7])
    else:
        j, y = float(tie[1]), float(tie[4])
    if unit == _RADIAN:
        y = math.degrees(y)
    lat = y + (1.0 if not north_first else -1.0) * (shape[0] / 2.0 - j) * sy_degrees
    return lat if math.isfinite(lat) and -90.0 <= lat <= 90.0 else None


def _degrees_to_metres(dx: float, dy: float, lat: float, what: str) -> Spacing:
    """A spacing of (dx, dy) degrees as metres at latitude ``lat``."""
    metres = math.pi / 180.0 * EARTH_RADIUS_M
    x = dx * metres * max(math.cos(math.radians(lat)), 1e-6)
    y = dy * metres
    return Spacing(x, y, f"cell size {x:.4g} x {y:.4g} m from {what} at latitude {lat:.2f}")
