"""Heightfield terrain: loading and triangulation.

A heightfield of ``(rows, cols)`` samples becomes a regular triangle mesh of
``(rows - 1) * (cols - 1)`` cells with two triangles each. In
:func:`heightfield_to_source`, sample ``(r, c)`` sits at ``x = c * cell_x``,
``y = r * cell_y``, ``z = height * z_scale``, so rows grow along +y and
columns along +x; cell ``(r, c)`` spans samples ``(r, c)`` (its lower-left
corner) to ``(r + 1, c + 1)``.

Files and arrays from users are *rasters* (:func:`raster_to_source`): GDAL,
rasterio, SRTM tiles and images store their first row at the top, the
north. Read as rows growing along +y they would be mirrored (x east, y
south, z up is left-handed), so a raster's rows are taken in reverse: its
first row gets the largest y, and the terrain appears as a map shows it.

Every cell carries one material class (both of its triangles share it). The
texture coordinates tile each material at its own scale, so where materials
meet a position has one vertex per material: those texture seams are the
surface-group boundaries of the paper's Three Lakes model (Kram & Shaw,
section 4.1). Without a material map, cells are classed into coherent
land-cover regions (:mod:`caveclod.builder.landcover`).

Normals are left to the build (``vertex_normal`` is None), smooth by default
(``SourceMesh.crease_angle`` is 180): on rough relief a crease angle would cut
normal seams across most cells, and seams are edges the build may not
remove. The built-in terrains live in :mod:`caveclod.builder.builtin`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np

from ..errors import InputError
from .quiet import quiet_reading
from .source import MAX_COORDINATE, SourceMesh

FLOAT32_TINY = float(np.finfo(np.float32).tiny)
"""Smallest normal float32 (about 1.2e-38): the smallest cell size accepted.
Below it the grid's x and y would be float32 subnormals, with fewer than 24
bits, or zero, in the .cvc."""

TILE_SIZES = {"water": 50.0, "grass": 20.0, "rock": 8.0, "snow": 32.0}
"""World units one texture repeat covers, per material name. They differ so
that UVs differ across every material boundary (a texture seam)."""


# --------------------------------------------------------------------------
# loading


SRTM_VOID = -32768   # the no-data value of signed 16-bit elevation grids (SRTM)


def load_heightfield(path: str | os.PathLike, nodata: float | None = None) -> np.ndarray:
    """Read a heightfield file into a (rows, cols) float64 array.

    ``.npy`` (any real 2-D array), ``.png`` (16- or 8-bit greyscale, read with
    Pillow), ``.tif``/``.tiff`` (integer or float greyscale, read with
    tifffile), ``.hgt`` (an SRTM tile: big-endian int16, 1201 or 3601
    samples a side) and ``.asc`` (an ESRI ASCII grid, whose header's
    ``NODATA_value`` marks voids). Values come back as stored (0..65535 for a 16-bit image): pass
    ``z_scale`` to :func:`heightfield_to_source` to turn them into heights.

    Missing samples become NaN (holes): NaN itself, ``nodata`` when given,
    the GeoTIFF ``GDAL_NODATA`` tag's value (compared in the samples' own
    type, as GDAL does), the samples a GeoTIFF's internal mask leaves out
    (:func:`tiff_mask`), and -32768 in signed 16-bit grids (the SRTM void
    marker). Real elevation data marks voids that way; read as heights they
    would be pits kilometres deep.
    """
    return heights_of(read_heightfield(path), path, nodata, valid=tiff_mask(path))


def heightfield_shape(path: str | os.PathLike) -> tuple[int, int] | None:
    """(rows, cols) of a heightfield file from its header alone, or None where the header does not
    say, cannot be read or disagrees with the file (the reader then says what is wrong: a damaged
    header claiming a huge grid must not be refused as too large to build). For refusing a grid
    too large to build before reading its samples; the shape read with the samples is checked again."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    try:
        if ext == ".npy":
            shape = _mapped_npy(path).shape     # refused if the file is short
        elif ext in (".tif", ".tiff"):
            import tifffile
            with quiet_reading("tifffile"), tifffile.TiffFile(path) as tif:
                held, needed = _tiff_chunks(tif.pages[0])
                if held < needed:
                    return None                 # strips or tiles missing: _read_tiff says so
                shape = tuple(n for n in tif.series[0].shape if n != 1)
        elif ext == ".hgt":
            side = _hgt_side(os.path.getsize(path))
            if side is None:
                return None                     # not a square of int16: _read_hgt says so
            shape = (side, side)
        elif ext == ".asc":
            header = ascii_grid_header(path)
            shape = (int(header["nrows"]), int(header["ncols"]))
            if os.path.getsize(path) - header["_data_at"] < 2 * shape[0] * shape[1] - 1:
                return None                     # fewer bytes than samples: _read_ascii_grid says so
        elif ext == ".png":
            from PIL import Image
            with quiet_reading("PIL"), Image.open(path) as image:
                shape = (image.height, image.width)
            if Image.MAX_IMAGE_PIXELS and shape[0] * shape[1] > Image.MAX_IMAGE_PIXELS:
                return None                     # beyond Pillow's limit: _pillow_pixels refuses it
        else:
            return None
    except Exception:       # noqa: BLE001 - any damage: the reader's error says what it is
        return None
    return (int(shape[0]), int(shape[1])) if len(shape) == 2 else None


def _mapped_npy(path: str) -> np.ndarray:
    """A ``.npy`` memory-mapped read-only. A header's shape whose byte count overflows raises
    ValueError; numpy also warns of the overflow on stderr, silenced here (the error says it)."""
    with np.errstate(all="ignore"):
        return np.load(path, allow_pickle=False, mmap_mode="r")


def read_heightfield(path: str | os.PathLike, window: bool = False):
    """A heightfield file's samples as stored (any real dtype), not yet
    :func:`heights_of`: a ``.npy`` memory-mapped, so that its shape is known and
    a part of it (:func:`every_kth_sample`) read without reading the rest.
    ``window``: a TIFF or ESRI ASCII grid that can be read so comes back as a
    :class:`caveclod.builder.rasterwindow.RasterWindow` (a shape, a dtype, and the
    samples of a slice read on demand) for :func:`every_kth_sample`, instead of
    being read whole."""
    if window:                              # a file that is not there: open_window says None, the reader why
        from .rasterwindow import open_window
        lazy = open_window(os.fspath(path))
        if lazy is not None:
            return lazy
    array = _read_grid(path, what="heightfield", mmap=True)
    if array.dtype.kind not in "biuf":
        raise InputError(f"heightfield {path} holds {array.dtype} values; give real numbers")
    return array


def heights_of(array: np.ndarray, path: str | os.PathLike, nodata: float | None = None,
               valid: np.ndarray | None = None) -> np.ndarray:
    """(rows, cols) float64 heights of samples :func:`read_heightfield` read from ``path`` (all
    of them or a part), the file's no-data values NaN (see :func:`load_heightfield`); ``valid``
    (rows, cols) bool, False where the file's mask (:func:`tiff_mask`, sampled alike) says no data."""
    voids = [] if nodata is None else [float(nodata)]
    if os.path.splitext(os.fspath(path))[1].lower() in (".tif", ".tiff"):
        voids += _tiff_nodata(path)
    if array.dtype == np.int16:
        voids.append(SRTM_VOID)
    if os.path.splitext(os.fspath(path))[1].lower() == ".asc":
        nodata_value = ascii_grid_header(path).get("nodata_value")
        if nodata_value is not None:
            voids.append(nodata_value)
    # A mask only where something can be missing: a grid with no no-data value and no mask (most
    # .npy inputs) allocates none and makes no pass over it.
    void = None if valid is None else ~np.asarray(valid, bool)
    for value in voids:
        found = _equals_in_type(array, value)
        void = found if void is None else np.logical_or(void, found, out=void)
    heights = _as_float64(array)
    if not heights.flags.writeable:
        heights = np.array(heights)         # a float64 .npy still mapped: read now, into memory of its own
    if void is not None:
        heights[void] = np.nan
    return heights


def _equals_in_type(array: np.ndarray, value: float) -> np.ndarray:
    """(rows, cols) bool: the samples equal to no-data ``value`` once it is written in the samples'
    own type, as GDAL compares them. A float32 grid cannot hold -9999.9 or -3.402823e+38 exactly:
    its no-data samples hold the nearest float32, which the float64 value never equals (such files
    were refused for heights beyond any terrain, or built with pits). An integer grid's no-data is
    a whole number within its type's range, or matches nothing."""
    dtype = np.asarray(array).dtype
    if dtype.kind == "f":
        with np.errstate(over="ignore"):
            typed = dtype.type(value)
        return np.asarray(array) == typed
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        if not (math.isfinite(value) and value == int(value) and info.min <= value <= info.max):
            return np.zeros(np.shape(array), bool)
        return np.asarray(array) == dtype.type(int(value))
    return np.asarray(array) == value


def _as_float64(array) -> np.ndarray:
    """``array`` as float64 with every NaN a quiet NaN (``array`` itself when
    it already is; never modified).

    A damaged file can hold signalling NaNs (an exponent of all ones with the
    top mantissa bit clear); converting or computing with one raises numpy's
    "invalid value" warning. Converting under ``errstate`` quiets them; a
    float64 input, which is not converted, is quieted in a copy. Long
    doubles beyond float64's range become infinities, refused later.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        out = np.asarray(array, dtype=np.float64)
    nan = np.isnan(out)
    return np.where(nan, np.nan, out) if nan.any() else out


def _tiff_nodata(path) -> list[float]:
    """The GDAL_NODATA value of a GeoTIFF, as a one-item list (or empty)."""
    import tifffile
    try:
        with quiet_reading("tifffile"), tifffile.TiffFile(path) as tif:
            tag = tif.pages[0].tags.get("GDAL_NODATA") or tif.pages[0].tags.get(42113)
            text = None if tag is None else str(tag.value)
    except Exception as exc:  # imread read the pixels, but the tags may still be damaged
        raise InputError(f"cannot read the tags of heightfield {path} ({_describe(exc)}); "
                         "check that the file is intact") from None
    if text is None:
        return []
    try:
        return [float(text.strip().strip("\x00"))]
    except ValueError:
        return []


MASK_FILE_TYPE = 4
"""NewSubfileType of a TIFF page that is the transparency mask of another (TIFF 6.0): GDAL's
internal no-data mask (GDAL_TIFF_INTERNAL_MASK, the default for masks of GeoTIFFs it writes)."""


def tiff_mask(path) -> np.ndarray | None:
    """(rows, cols) bool, True where a GeoTIFF's internal mask says a sample holds data, or None
    (not a TIFF, or no full-resolution mask page of the first page's size).

    GDAL keeps a raster's no-data mask as a further page of the file, often with no GDAL_NODATA
    tag at all: the masked samples hold some value (0, usually), which read as heights would be
    pits or plains. A mask that cannot be decoded is refused: building past it would do that."""
    if os.path.splitext(os.fspath(path))[1].lower() not in (".tif", ".tiff"):
        return None
    import tifffile
    try:
        with quiet_reading("tifffile"), tifffile.TiffFile(path) as tif:
            first = tif.pages[0]
            for page in tif.pages[1:]:
                # A mask of an overview is MASK | REDUCEDIMAGE (5): only the full-resolution one counts.
                if int(page.subfiletype) == MASK_FILE_TYPE and page.shaped[-3:-1] == first.shaped[-3:-1]:
                    return np.asarray(page.asarray()).reshape(first.imagelength, first.imagewidth) != 0
    except Exception as exc:  # noqa: BLE001 - the pixels were read; a mask that is not is refused
        raise InputError(f"cannot read the no-data mask of heightfield {path} ({_describe(exc)}); check that the "
                         "file is intact, or save it with its no-data as a GDAL_NODATA value instead of a mask "
                         "(gdal_translate -b 1 -a_nodata -9999 in.tif out.tif)") from None
    return None


def load_material_map(path: str | os.PathLike) -> np.ndarray:
    """Read a material map into a (rows, cols) or (rows-1, cols-1) int32 array.

    ``.npy`` with integer class ids (floats are accepted when they are whole
    numbers); 8/16-bit greyscale or palette PNG/TIFF work as well. The shape is
    checked against the heightfield by :func:`heightfield_to_source`.
    """
    classes = _integral_classes(_read_grid(path, what="material map", palette=True), f"material map {path}")
    return classes.astype(np.int32)


def _read_grid(path: str | os.PathLike, what: str, palette: bool = False, mmap: bool = False) -> np.ndarray:
    """The 2-D array stored in ``path`` (.npy, .png, .tif/.tiff, .hgt, .asc).

    ``palette``: accept palette PNGs (their indices are classes, not heights).
    ``mmap``: a ``.npy`` memory-mapped read-only, not read (other types are read).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"{what} file {path} " + ("is not a regular file (a directory?)" if os.path.exists(path)
                                                    else "does not exist") + "; check the path")
    ext = os.path.splitext(path)[1].lower()
    try:
        # tifffile logs what it skips in a damaged file; the exception, if
        # any, is what the user needs (see caveclod.builder.quiet).
        with quiet_reading("tifffile", "PIL"):
            if ext == ".npy":
                array = _mapped_npy(path) if mmap else np.load(path, allow_pickle=False)
            elif ext == ".png":
                array = _read_png(path, what, palette)
            elif ext in (".tif", ".tiff"):
                array = _read_tiff(path, what)
            elif ext == ".hgt" and not palette:
                array = _read_hgt(path, what)
            elif ext == ".asc":
                array = _read_ascii_grid(path, what)
            else:
                raise InputError(f"{what} {path}: unknown file type {ext!r}; use .npy, .png, .tif, .tiff or .asc"
                                 + ("" if palette else " (or an SRTM .hgt)"))
    except InputError:
        raise
    except Exception as exc:  # corrupt files surface as many exception types
        raise InputError(f"cannot read {what} {path} ({_describe(exc)}); check that the file is intact") from None
    if array.ndim != 2:
        raise InputError(f"{what} {path} has shape {array.shape}; give a single-channel 2-D grid")
    return array


def _read_png(path: str, what: str, palette: bool) -> np.ndarray:
    """Pixels of a greyscale (or palette) PNG as numbers, 16-bit kept intact.

    Images beyond Pillow's decompression-bomb limit are refused (Pillow only
    warns up to twice the limit, a warning the caller silences).
    """
    # "I;16*" is 16-bit greyscale, "I" the 32-bit mode older Pillows use for it.
    modes = ("L", "I", "F", "P") if palette else ("L", "I", "F")
    return _pillow_pixels(path, what, modes, "save it as 8- or 16-bit greyscale")


def _pillow_pixels(path: str, what: str, modes: tuple, advice: str) -> np.ndarray:
    """The pixels of a greyscale image Pillow opens, refused beyond its decompression-bomb limit (Pillow
    only warns up to twice it, a warning the caller silences) or in a mode not in ``modes`` (nor I;16*)."""
    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS     # None when an application turned the check off
    try:
        image = Image.open(path)
    except Image.DecompressionBombError:
        raise _too_many_pixels(what, path, limit) from None
    with image:
        if limit and image.width * image.height > limit:
            raise _too_many_pixels(what, path, limit)
        if image.mode not in modes and not image.mode.startswith("I;16"):
            raise InputError(f"{what} {path} is a {image.mode} image; {advice}")
        return np.array(image)


def _read_tiff(path: str, what: str) -> np.ndarray:
    """Pixels of a TIFF, its length-1 page or sample axes dropped.

    A file listing fewer strips or tiles than its size needs is refused:
    tifffile would log the fact and fill the missing ones with zeros, reading
    a damaged file as a plain (and a header claiming 100,000 rows as a grid
    that takes minutes to build).
    """
    import tifffile
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        held, needed = _tiff_chunks(page)
        if held < needed:
            raise InputError(f"{what} {path} is damaged: it holds {held} of the {needed} strips or tiles its "
                             f"{page.imagewidth}x{page.imagelength} pixels need; check that the file is intact")
        try:
            array = tif.asarray()
            if array.size == page.imagelength * page.imagewidth:
                return array.reshape(page.imagelength, page.imagewidth)   # one row or column stays a grid
            return np.squeeze(array)
        except (ValueError, ImportError) as exc:
            # tifffile names imagecodecs in a ValueError, or fails importing a codec module of its own.
            if not isinstance(exc, ImportError) and "imagecodecs" not in str(exc):
                raise
            dtype, compression = page.dtype, getattr(page.compression, "name", page.compression)
            if int(getattr(page, "predictor", 1) or 1) > 1:
                compression = f"{compression} (predictor {int(page.predictor)})"
            big_endian = tif.byteorder == ">"
    return _tiff_through_pillow(path, what, dtype, compression, big_endian)


def _tiff_chunks(page) -> tuple[int, int]:
    """(strips or tiles a TIFF page lists with data, strips or tiles its size needs)."""
    n = min(len(page.dataoffsets), len(page.databytecounts))
    held = np.count_nonzero((np.asarray(page.dataoffsets[:n]) > 0) & (np.asarray(page.databytecounts[:n]) > 0))
    return int(held), int(np.prod(page.chunked))


def _tiff_through_pillow(path: str, what: str, dtype, compression, big_endian: bool = False) -> np.ndarray:
    """A TIFF whose compression tifffile decodes only with the imagecodecs package (LZW, the usual
    compression of real elevation GeoTIFFs, zstd, predictors), read through Pillow's libtiff instead,
    as ``dtype`` (tifffile's reading of the header: Pillow widens int16 to int32, which would hide
    SRTM's -32768 voids).

    Refused, saying why: a big-endian file of samples wider than a byte (Pillow 13's libtiff path
    swapped the bytes of float32 and int16 samples that libtiff had already put in this machine's
    order: a terrain read as noise, or flat), and a compression Pillow cannot open either (LERC,
    float64 with a predictor), which would otherwise read as a damaged file."""
    install = ("install the imagecodecs package (pip install imagecodecs), with which tifffile reads it, or save it "
               "little-endian with deflate or LZW (gdal_translate -co COMPRESS=DEFLATE in.tif out.tif)")
    if big_endian and dtype is not None and dtype.itemsize > 1:
        raise InputError(f"{what} {path} is a big-endian TIFF of {dtype} samples compressed with {compression}: "
                         f"without the imagecodecs package only Pillow reads it, and Pillow swaps such samples' "
                         f"bytes (a wrong terrain, not an error), so it is refused; {install}")
    from PIL import UnidentifiedImageError
    try:
        array = _pillow_pixels(path, what, ("F", "I", "L"), f"compressed with {compression}, it must be one band "
                               "of numbers here: save it so, or install the imagecodecs package (pip install "
                               "imagecodecs)")
    except UnidentifiedImageError:
        raise InputError(f"{what} {path} is compressed with {compression}, which neither tifffile without the "
                         f"imagecodecs package nor Pillow decodes; {install}") from None
    if dtype is not None and array.dtype != dtype and np.can_cast(dtype, array.dtype):
        narrowed = array.astype(dtype)
        if np.array_equal(narrowed, array):
            array = narrowed
    return array


def _read_hgt(path: str, what: str) -> np.ndarray:
    """An SRTM ``.hgt`` tile: a square of big-endian int16 samples, rows from north to south,
    as native int16 (so that its -32768 voids are found like any int16 grid's)."""
    size = os.path.getsize(path)
    side = _hgt_side(size)
    if side is None:
        raise InputError(f"{what} {path} holds {size:,} bytes, not a square of 16-bit samples as an SRTM .hgt "
                         "tile does (1201 x 1201 or 3601 x 3601); check that the file is whole")
    return np.fromfile(path, dtype=">i2").reshape(side, side).astype(np.int16)


def _hgt_side(size: int) -> int | None:
    """Samples a side of an SRTM tile of ``size`` bytes (a square of int16, 2 or more a side), else None."""
    side = int(round((size / 2) ** 0.5))
    return side if size % 2 == 0 and side * side * 2 == size and side >= 2 else None


ASCII_GRID_KEYS = ("ncols", "nrows", "xllcorner", "yllcorner", "xllcenter", "yllcenter", "cellsize", "dx", "dy",
                   "nodata_value")
MAX_ASCII_GRID_SAMPLES = 1 << 31


def ascii_grid_header(path) -> dict[str, float]:
    """The header of an ESRI ASCII grid (``.asc``): lower-case keys (``ncols``, ``nrows``,
    ``cellsize`` or ``dx``/``dy``, ``xllcorner``..., ``nodata_value``) and their numbers, plus
    ``_data_at``, the byte offset of the first sample. InputError when it is not one."""
    header: dict[str, float] = {}
    with open(path, "rb") as f:
        while len(header) < len(ASCII_GRID_KEYS):
            at = f.tell()
            line = f.readline(256)
            if at == 0 and line.startswith(b"\xef\xbb\xbf"):
                line = line[3:]                 # a UTF-8 byte order mark, as Windows editors write
            words = line.split()
            key = words[0].decode("ascii", "replace").lower() if words else ""
            if key not in ASCII_GRID_KEYS:     # the samples begin (GDAL writes voids as nan, so not "a letter")
                f.seek(at)
                break
            if len(words) != 2:
                raise InputError(f"heightfield {path}: {line[:60]!r} is not a line of an ESRI ASCII grid's header "
                                 f"(keys {', '.join(ASCII_GRID_KEYS)}); check the file")
            try:
                header[key] = float(words[1])
            except ValueError:
                raise InputError(f"heightfield {path}: the header's {key} is {words[1][:30]!r}, not a number") from None
        header["_data_at"] = f.tell()
    for key in ("ncols", "nrows"):
        value = header.get(key)
        if value is None or value != int(value) or not 2 <= value <= MAX_ASCII_GRID_SAMPLES:
            raise InputError(f"heightfield {path}: an ESRI ASCII grid's header needs {key} (a whole number from 2), "
                             f"got {value}; check the file")
    return header


def _read_ascii_grid(path: str, what: str) -> np.ndarray:
    """An ESRI ASCII grid's samples, (nrows, ncols) float64, rows from north to south, parsed a block
    at a time (:class:`caveclod.builder.rasterwindow.AsciiGridWindow`)."""
    from .rasterwindow import AsciiGridWindow
    return AsciiGridWindow(path, what)[:, :]


def _too_many_pixels(what: str, path: str, limit: int) -> InputError:
    return InputError(f"{what} {path} has more than {limit:,} pixels, Pillow's limit against decompression "
                      "bombs; crop or downsample it (or the file's header is damaged)")


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())


_MAX_CAUSE_CHARS = 200   # longest message quoted from a reader's exception


def _describe(exc: BaseException) -> str:
    """``Type: message`` of an exception, on one line and at most about 200 characters."""
    text = _one_line(exc)
    if len(text) > _MAX_CAUSE_CHARS:
        text = text[:_MAX_CAUSE_CHARS - 3] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _cell_corners(grid: np.ndarray) -> tuple[np.ndarray, ...]:
    """The four (rows-1, cols-1) corner views of every cell, counter-clockwise
    from the lower-left: (r, c), (r, c+1), (r+1, c+1), (r+1, c)."""
    return grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]


def _cell_slope_deg(a, b, c, d, cell: tuple[float, float]) -> np.ndarray:
    """Slope (degrees from horizontal) of each cell's best-fit plane; ``cell`` is (x, y) spacing."""
    gx = ((b - a) + (c - d)) / (2.0 * cell[0])
    gy = ((d - a) + (c - b)) / (2.0 * cell[1])
    return np.degrees(np.arctan(np.hypot(gx, gy)))


# --------------------------------------------------------------------------
# triangulation


def raster_to_source(heights: np.ndarray, cell_size: float | tuple[float, float] = 1.0, z_scale: float = 1.0,
                     materials: np.ndarray | None = None, notes: Sequence[str] = (),
                     north_first: bool = True) -> SourceMesh:
    """:func:`heightfield_to_source` of a raster, whose first row is the north edge.

    The rows of ``heights`` (and of ``materials``) are taken in reverse, so
    that raster row ``r`` of ``rows`` lies at ``y = (rows - 1 - r) * cell_y``
    (see the module's docstring). A per-sample material map gives each cell
    the class of its first sample in raster order (its north-west corner; the
    south-west one where the rows run northwards). ``notes`` (say, where the cell size came from) lead the mesh's notes.
    ``north_first`` False: a raster whose rows run northwards (a GeoTIFF can
    say so), read as :func:`heightfield_to_source` reads rows.
    """
    classes = None if materials is None else np.asarray(materials)
    if classes is not None and classes.ndim == 2:       # other shapes are refused, as they are, below
        if classes.shape == np.shape(heights):
            classes = classes[:-1, :-1]          # per cell, in raster order, before the rows turn
        classes = classes[::-1] if north_first else classes
    if np.ndim(heights) == 2 and north_first:
        heights = np.asarray(heights)[::-1]
    source = heightfield_to_source(heights, cell_size=cell_size, z_scale=z_scale, materials=classes)
    source.notes[:0] = list(notes) + _sentinel_notes(heights)
    return source


def every_kth_sample(heights: np.ndarray, k: int, materials: np.ndarray | None = None,
                     north_first: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Every ``k``-th sample of a raster a side, for a build ``k`` x ``k`` times
    smaller (``caveclod build --stride K``): cells ``k`` times as wide.

    The south-west sample is kept (so a georeferenced file's origin stays
    where it is); up to ``k - 1`` rows at the north and columns at the east
    are dropped, since the grid stays regular. A per-sample ``materials`` map
    (rows, cols) is sampled alike; a per-cell one (rows - 1, cols - 1) gives
    each new cell the class of the original cell at its first corner in
    raster order, as :func:`raster_to_source` does for per-sample maps.
    No-data samples (NaN) that are kept stay holes.

    Args:
        heights: (rows, cols) raster (or a file read by window), first row
            north unless ``north_first`` is False. k: 1 or more (1: returned as given).
    Returns:
        ((rows', cols') heights, the materials map sampled alike or None),
        rows' = (rows - 1) // k + 1, cols' = (cols - 1) // k + 1.
    """
    from .rasterwindow import RasterWindow
    h = heights if isinstance(heights, RasterWindow) else np.asarray(heights)   # a window: only the kept samples read
    if k == 1 or h.ndim != 2:
        return heights, materials
    rows, cols = h.shape
    # North-first rasters keep the last (southernmost) row; rows running northwards keep the first.
    r0 = (rows - 1) % k if north_first else 0
    kept_rows, kept_cols = (rows - 1) // k + 1, (cols - 1) // k + 1
    if kept_rows < 2 or kept_cols < 2:
        raise InputError(f"the heightfield has {rows:,} x {cols:,} samples: one in {k} a side leaves "
                         f"{kept_rows} x {kept_cols}, fewer than 2 a side; give a smaller --stride")
    out = h[r0::k, ::k]
    if materials is not None:
        m = np.asarray(materials)
        if m.ndim == 2 and m.shape == h.shape:
            m = m[r0::k, ::k]
        elif m.ndim == 2 and m.shape == (rows - 1, cols - 1):
            m = m[r0::k, ::k][:kept_rows - 1, :kept_cols - 1]
        materials = np.ascontiguousarray(m)   # other shapes: refused as they are by the triangulation
    return np.ascontiguousarray(out), materials


COMMON_NODATA = (-9999.0, -99999.0, -32767.0, -32768.0, -10000.0, -3.4028234663852886e38)
"""No-data values elevation rasters use when a file does not say which (GDAL's and ArcGIS's
defaults, SRTM's, float32's lowest); NaN and -32768 in int16 grids are holes already."""


def _sentinel_notes(heights) -> list[str]:
    """A note when the lowest samples of a raster hold a common no-data value well below the
    rest: built as heights, they are pits; the note says how to make them holes."""
    h = np.asarray(heights, dtype=np.float64)
    finite = h[np.isfinite(h)]
    if finite.size == 0:
        return []
    low = float(finite.min())
    if low not in COMMON_NODATA:
        return []
    at_low = finite == low
    rest = finite[~at_low]
    if rest.size and float(rest.min()) - low < abs(low) / 2:
        return []                       # the value lies among the heights: it may be one
    return [f"{int(np.count_nonzero(at_low)):,} samples hold {low:g}, a common no-data value, "
            f"{'far ' if rest.size else ''}below the rest: built as heights they are pits; if they mark missing "
            f"data, build with --nodata={low!r}"]


def heightfield_to_source(heights: np.ndarray, cell_size: float | tuple[float, float] = 1.0, z_scale: float = 1.0,
                          materials: np.ndarray | None = None,
                          material_names: Sequence[str] | None = None) -> SourceMesh:
    """Triangulate a heightfield into a validated :class:`SourceMesh`.

    Args:
        heights: (rows, cols) samples, rows, cols >= 2. NaN samples are holes:
            every cell touching one is dropped. Infinite values are an error.
        cell_size: spacing of the samples in world units, one number for
            both axes or (x, y) (a geographic grid's cells are narrower
            east-west than north-south).
        z_scale: world units per height unit.
        materials: class id per cell, (rows-1, cols-1), or per sample,
            (rows, cols), in which case a cell takes the class of its
            lower-left sample ``(r, c)``, kept exactly. Ids must be >= 0 on the
            cells that are kept. None: coherent land-cover classes from
            elevation and slope (:mod:`caveclod.builder.landcover`).
        material_names: name of each class id (indexed by the ids in
            ``materials``). Default: ``landcover.MATERIALS``, then ``"material N"``.

    Returns:
        A mesh with (e, 3) float64 positions (the finite samples some kept
        cell uses), 2 CCW triangles per kept cell split along the
        (r, c)-(r+1, c+1) diagonal, materials renumbered 0..k-1 over the
        classes present, one vertex per (sample, material of an adjacent cell)
        with UV = (x, y) / tile size of the material (see :data:`TILE_SIZES`),
        and no normals or colours.
    """
    h = _checked_heights(heights)
    cell_size = cell_xy(cell_size)
    z_scale = _positive_finite("z_scale", z_scale)
    _refuse_far_grid(h.shape, cell_size)
    _refuse_far_heights(h, z_scale)
    kept = _cells_with_finite_corners(h)
    if materials is None:
        from .landcover import classify_terrain, coherent_classes
        cell_class = coherent_classes(classify_terrain(h, cell_size, z_scale))
    else:
        cell_class = _cell_classes(materials, h.shape)
    if (cell_class[kept] < 0).any():
        raise InputError("the materials map has negative class ids; use ids 0, 1, 2, ... for every cell")

    present, material_of_cell = _compact_classes(cell_class[kept])
    names = _material_names(present, material_names, classified=materials is None)
    rows, cols = h.shape
    cell_r, cell_c = np.nonzero(kept)
    corners = _corner_samples(cell_r, cell_c, cols)
    vertex_sample, vertex_material, corner_vertex = _split_vertices(corners, material_of_cell,
                                                                    rows * cols, len(present))
    sample_ids, vertex_position = _compact_positions(vertex_sample, rows * cols)

    notes = []
    dropped = kept.size - int(np.count_nonzero(kept))
    if dropped:
        notes.append(f"dropped {dropped} cells touching NaN samples")
    source = SourceMesh(
        positions=_sample_positions(h, sample_ids, cell_size, z_scale),
        vertex_position=vertex_position,
        faces=_cell_triangles(corner_vertex),
        face_material=np.repeat(material_of_cell, 2).astype(np.int32),
        materials=names,
        vertex_normal=None,
        vertex_uv=_tiled_uvs(vertex_sample, vertex_material, cols, cell_size, names),
        vertex_color=None,
        notes=notes,
        crease_angle=180.0,
    )
    source.validate()
    return source


def _checked_heights(heights) -> np.ndarray:
    """``heights`` as a (rows, cols) float64 array, rows, cols >= 2, no infinities."""
    try:
        h = _as_float64(heights)
    except (TypeError, ValueError) as exc:
        raise InputError(f"heights must be a 2-D array of numbers ({_one_line(exc)})") from exc
    if h.ndim != 2:
        raise InputError(f"heights must be a 2-D (rows, cols) grid, got shape {h.shape}")
    if h.shape[0] < 2 or h.shape[1] < 2:
        raise InputError(f"heights of shape {h.shape} has no cell; give at least 2x2 samples")
    n_inf = int(np.count_nonzero(np.isinf(h)))
    if n_inf:
        raise InputError(f"{n_inf} height samples hold infinity; replace them with finite values or NaN (a hole)")
    return h


def _positive_finite(name: str, value) -> float:
    """``value`` as a float; InputError unless it is finite and > 0.

    ``name`` is the argument's name (``cell_size``); the message names the
    command line's option (``--cell-size``) too.
    """
    option = "--" + name.replace("_", "-")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} ({option}) must be a positive number, got {value!r}") from None
    if not np.isfinite(value) or value <= 0.0:
        raise InputError(f"{name} ({option}) must be a positive finite number, got {value}")
    return value


def cell_xy(cell_size) -> tuple[float, float]:
    """``cell_size`` (one number, or (x, y)) as an (x, y) pair of positive finite floats; InputError otherwise."""
    if isinstance(cell_size, (tuple, list, np.ndarray)) and len(cell_size) == 2:
        return _positive_finite("cell_size", cell_size[0]), _positive_finite("cell_size", cell_size[1])
    size = _positive_finite("cell_size", cell_size)
    return size, size


def _refuse_far_grid(shape: tuple[int, int], cell: tuple[float, float]) -> None:
    """Refuse an (x, y) cell size whose grid of ``shape`` (rows, cols) samples reaches
    beyond +-MAX_COORDINATE, or whose x and y float32 cannot hold."""
    for samples, size in ((shape[1], cell[0]), (shape[0], cell[1])):
        span = (samples - 1) * size
        if span > MAX_COORDINATE:
            raise InputError(f"the grid spans {span:.3g} ({samples} samples {size:g} apart), beyond "
                             f"+-{MAX_COORDINATE:.2g}, too far for the float32 the .cvc stores positions in; "
                             "give a smaller --cell-size")
        if size < FLOAT32_TINY:
            raise InputError(f"cell_size (--cell-size) {size:g} is below {FLOAT32_TINY:.3g}, the smallest normal "
                             "float32: the .cvc could not tell the grid's samples apart; give a larger --cell-size")


def _refuse_far_heights(h: np.ndarray, z_scale: float) -> None:
    """Refuse samples of (rows, cols) ``h`` whose elevation ``h * z_scale`` is
    beyond +-MAX_COORDINATE (see there). NaN samples (holes) pass."""
    with np.errstate(over="ignore", invalid="ignore"):   # inf and NaN compare as they should
        far = np.abs(h) * z_scale > MAX_COORDINATE
    n_far = int(np.count_nonzero(far))
    if n_far:
        values = np.unique(h[far])
        largest = float(np.abs(values).max())
        one = repr(float(values[0]))       # repr: the exact float, which --nodata must match
        hint = (f"; if {one} marks missing samples (a no-data value), build with --nodata={one}"
                if len(values) == 1 else "")
        raise InputError(f"{n_far} heightfield samples give elevations beyond +-{MAX_COORDINATE:.2g} (the largest: "
                         f"{largest:.3g} x z-scale {z_scale:g}), too far for the float32 the .cvc stores positions "
                         f"in; give a smaller --z-scale or rescale the heights{hint}")


def _cells_with_finite_corners(h: np.ndarray) -> np.ndarray:
    """(rows-1, cols-1) bool: the cells whose four samples are all finite."""
    finite = np.isfinite(h)
    if not finite.any():
        raise InputError("every heightfield sample is missing (NaN, or a no-data value: the file's, or --nodata's); "
                         "give at least one 2x2 block of finite heights")
    a, b, c, d = _cell_corners(finite)
    kept = a & b & c & d
    if not kept.any():
        raise InputError("no cell has four finite samples (NaN holes everywhere); "
                         "give at least one 2x2 block of finite heights")
    return kept


def _cell_classes(materials, shape: tuple[int, int]) -> np.ndarray:
    """Per-cell (rows-1, cols-1) int64 classes from a per-cell or per-sample map."""
    m = _integral_classes(materials, "the materials map")
    rows, cols = shape
    if m.shape == (rows - 1, cols - 1):
        return m
    if m.shape == (rows, cols):
        return m[:-1, :-1]  # the lower-left sample of each cell decides
    raise InputError(f"the materials map has shape {m.shape}; give one class per cell "
                     f"{(rows - 1, cols - 1)} or per sample {(rows, cols)}")


def _integral_classes(materials, what: str) -> np.ndarray:
    """``materials`` as a 2-D int64 array, refusing fractions and non-numbers."""
    m = np.asarray(materials)
    if m.ndim != 2:
        raise InputError(f"{what} must be a 2-D grid of class ids, got shape {m.shape}")
    if m.dtype.kind == "f":
        if not np.isfinite(m).all() or (m != np.round(m)).any():
            raise InputError(f"{what} holds non-integer values; give whole-number class ids")
    elif m.dtype.kind not in "biu":
        raise InputError(f"{what} holds {m.dtype} values; give integer class ids")
    # Compared as Python numbers: numpy would cast the int32 bounds to a
    # float16 map's dtype, where they overflow.
    if m.size and (m.max().item() > np.iinfo(np.int32).max or m.min().item() < np.iinfo(np.int32).min):
        raise InputError(f"{what} has class ids beyond int32; renumber them 0, 1, 2, ...")
    return m.astype(np.int64)


def _compact_classes(kept_classes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The class ids present (sorted) and each kept cell's compact id 0..k-1."""
    present, compact = np.unique(kept_classes, return_inverse=True)
    return present, compact.reshape(-1).astype(np.int64)


def _material_names(present: np.ndarray, material_names, classified: bool) -> list[str]:
    """Names of the present classes, in compact-id order."""
    from .landcover import MATERIALS
    if material_names is None:
        return [MATERIALS[i] if i < len(MATERIALS) else f"material {i}" for i in present.tolist()]
    names = [str(n) for n in material_names]
    needed = len(MATERIALS) if classified else int(present.max()) + 1
    if len(names) < needed:
        raise InputError(f"material_names has {len(names)} names but class ids go up to {needed - 1}; "
                         "give one name per class id")
    return [names[i] for i in present.tolist()]


def _corner_samples(cell_r: np.ndarray, cell_c: np.ndarray, cols: int) -> np.ndarray:
    """(n, 4) int64 flat sample ids of each cell's corners, CCW from lower-left."""
    lower_left = cell_r.astype(np.int64) * cols + cell_c
    return np.stack([lower_left, lower_left + 1, lower_left + cols + 1, lower_left + cols], axis=1)


_DENSE_TABLE_LIMIT = 1 << 26  # (sample, material) entries, 64 MiB of bools


def _split_vertices(corners: np.ndarray, material: np.ndarray, n_samples: int, k: int):
    """One vertex per (sample, material) pair that some cell corner uses.

    Returns (vertex_sample (v,), vertex_material (v,), corner_vertex (n, 4)),
    vertices ordered by sample, then material.
    """
    key = corners * k + material[:, None]
    if n_samples * k <= _DENSE_TABLE_LIMIT:
        # A dense (sample, material) table is linear time, and for a handful of
        # classes smaller than the sort np.unique needs on the 4n keys.
        used = np.zeros(n_samples * k, dtype=bool)
        used[key] = True
        vertex_of_key = np.cumsum(used, dtype=np.int64) - 1
        keys = np.flatnonzero(used)
        corner_vertex = vertex_of_key[key]
    else:  # many classes: the table would be mostly empty
        keys, inverse = np.unique(key, return_inverse=True)
        corner_vertex = inverse.reshape(key.shape).astype(np.int64)
    return keys // k, (keys % k).astype(np.int64), corner_vertex


def _compact_positions(vertex_sample: np.ndarray, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat ids of the used samples (e,) and each vertex's position id (v,)."""
    used = np.zeros(n_samples, dtype=bool)
    used[vertex_sample] = True
    position_of_sample = np.cumsum(used, dtype=np.int64) - 1
    return np.flatnonzero(used), position_of_sample[vertex_sample]


def _sample_positions(h: np.ndarray, sample_ids: np.ndarray, cell: tuple[float, float], z_scale: float) -> np.ndarray:
    """(e, 3) float64 world positions of flat sample ids; ``cell`` is the (x, y) spacing."""
    row, col = np.divmod(sample_ids, h.shape[1])
    return np.stack([col * cell[0], row * cell[1], h.reshape(-1)[sample_ids] * z_scale], axis=1)


def _cell_triangles(corner_vertex: np.ndarray) -> np.ndarray:
    """(2n, 3) int32 faces: cell corners a, b, c, d (CCW) give abc and acd.

    Both are counter-clockwise seen from +z because the corners are; the two
    triangles of a cell are adjacent in the face array.
    """
    faces = np.empty((2 * len(corner_vertex), 3), dtype=np.int32)     # half of int64's bytes, alive all build
    faces[0::2] = corner_vertex[:, [0, 1, 2]]
    faces[1::2] = corner_vertex[:, [0, 2, 3]]
    return faces


def _tiled_uvs(vertex_sample: np.ndarray, vertex_material: np.ndarray, cols: int,
               cell: tuple[float, float], names: list[str]) -> np.ndarray:
    """(v, 2) float32 UVs: (x, y) / tile size of the vertex's material.

    Tile sizes differ between materials, so two vertices of one position get
    different UVs: x / t1 == x / t2 only at x = 0, and the one sample where
    also y = 0 (the grid's corner) touches a single cell.
    """
    tile = _tile_sizes(names)
    row, col = np.divmod(vertex_sample, cols)
    return np.stack([col * (cell[0] / tile[vertex_material]), row * (cell[1] / tile[vertex_material])],
                    axis=1).astype(np.float32)


def _tile_sizes(names: list[str]) -> np.ndarray:
    """(k,) world units per texture repeat, pairwise different.

    Known names use :data:`TILE_SIZES`; other materials, and a known name
    met again, a size from 11 to 88 units picked by their id (11 * 8 **
    frac(id * golden ratio): different for every id, spread over the range).
    A size growing with the id (``11 * 1.5 ** id``, before) made a map of
    64 classes give most vertices UVs near 0, and past 1,750 classes reached
    infinity, where making room for a repeated size never ended.
    """
    sizes: list[float] = []
    taken: set[float] = set()
    for material_id, name in enumerate(names):
        size = TILE_SIZES.get(name)
        if size is None or size in taken:
            size = 11.0 * 8.0 ** math.modf(material_id * GOLDEN_RATIO)[0]
        while size in taken:                  # a known name's size met by chance: the next float up
            size = math.nextafter(size, math.inf)
        taken.add(size)
        sizes.append(size)
    return np.array(sizes)


GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
