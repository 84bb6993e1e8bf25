"""The public entry points: :func:`build` and :func:`load`."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import InputError
from .builder.source import SourceMesh
from .staticmesh import StaticMesh
from .staticmesh import load as _load_file

HEIGHTFIELD_SUFFIXES = {".npy", ".png", ".tif", ".tiff", ".hgt", ".asc"}
DEFAULT_SIZE = 256


def build(source, *, cell_size: float | None = None, z_scale: float = 1.0, materials=None,
          crease_angle: float | None = None, size: int = DEFAULT_SIZE, seed: int | None = None, nodata: float | None = None,
          weld: float | None = None, progress: bool = False, tiles: int | None = None,
          workers: int | None = None, packed: bool = True, check_memory: bool = True,
          tiles_dir: str | os.PathLike | None = None, origin=None, stride: int = 1) -> StaticMesh:
    """Build the static CAVECLOD mesh of ``source``.

    Args:
        source: a built-in (``"default"``: smooth terrain, ``"rough"``:
            rough terrain with holes, ``"scan"``: a range scan, ``"debris"``:
            a field of many small parts; see
            :mod:`caveclod.builder.builtin`), a path to a
            mesh file (anything trimesh loads) or a heightfield (``.npy``,
            16-bit ``.png``/``.tif``, an SRTM ``.hgt``, an ESRI ``.asc``) or a heightfield
            array, a ``trimesh.Trimesh``/``Scene``, or a
            :class:`~caveclod.builder.source.SourceMesh`. A heightfield is
            a raster: its first row is the north edge (the largest y).
        cell_size, z_scale: heightfield grid spacing and height scale.
            ``cell_size`` None: what a GeoTIFF's or an SRTM tile's
            georeference states (metres for degrees; see
            :mod:`caveclod.builder.georef`), else 1.
        materials: heightfield material map: a path to ``.npy`` or an (r, c)
            / (r-1, c-1) integer array, one class per cell.
        crease_angle: degrees; normals are computed with it where the input
            has none. None: 30 for meshes, smooth (180) for heightfields, the
            built-in terrain's own choice for built-ins.
        size: cells (samples) per side of a built-in (``debris``: 20 x size parts).
        seed: seed of a built-in (None: its own default).
        nodata: heightfield value that marks missing samples (holes); NaN,
            a GeoTIFF's GDAL_NODATA and -32768 in int16 grids always do.
        weld: merge positions closer than about this distance (default:
            weld exactly); see :mod:`caveclod.builder.weld`.
        progress: draw a progress bar on stderr.
        tiles: tiles per side of the build's grid, a power of two (1: one
            tile; None: about 65,536 to 131,072 faces a tile); tiles are
            simplified in parallel with their borders fixed, then merged
            2 x 2 (:mod:`caveclod.builder.tiles`).
        workers: threads the build uses (None: the cores, at most 8); the
            file is the same whatever their number.
        packed: also pack the vertex buffer for download as most clients ask
            for it (the default precision, with and without geomorph
            targets), kept in the mesh's attachments and its file, so that a
            server need not pack it when it starts
            (:func:`caveclod.vertexpack.attach_packed`).
        check_memory: refuse (:class:`InputError`) an input whose build
            would not fit in the memory available
            (:mod:`caveclod.builder.memory`), before the work starts.
        tiles_dir: a directory of blocks of tiles made by
            :func:`build_tiles` jobs, read and merged instead of made (the
            mesh is the same).
        origin: ``"auto"`` or (x, y, z): subtracted from every position
            before the build and recorded as ``info["origin"]``, for meshes
            in world coordinates far from 0, where float32 positions lose
            detail (``"auto"``: the bounding box's centre, rounded; see
            :mod:`caveclod.builder.origin`).
        stride: build a heightfield from every ``stride``-th sample a side
            (cells ``stride`` times as wide, about ``stride**2`` times fewer
            triangles; the south-west sample kept): for rasters whose full
            build would not fit (:func:`caveclod.builder.terrain.every_kth_sample`).
    """
    from .builder.hierarchy import build_static_mesh
    from .builder.tilestore import TileStore
    store = None if tiles_dir is None else TileStore(Path(tiles_dir))
    # The build makes the input itself (a function, not the mesh), so that it holds the only reference and drops
    # it once it has made its own arrays (a heightfield's vertices, faces and UVs: 20 bytes a triangle at the peak).
    mesh = build_static_mesh(lambda: _prepared_source(source, cell_size=cell_size, z_scale=z_scale, materials=materials,
                                                      crease_angle=crease_angle, size=size, seed=seed, nodata=nodata,
                                                      weld=weld, tiles=tiles, workers=workers,
                                                      check_memory=check_memory, origin=origin, stride=stride),
                             crease_angle=crease_angle, progress=progress, tiles=tiles, workers=workers, store=store)
    if packed:
        from .vertexpack import attach_packed
        attach_packed(mesh, progress=progress)
    return mesh


def build_tiles(source, tiles_dir: str | os.PathLike, job: str | tuple[int, int], *, cell_size: float | None = None,
                z_scale: float = 1.0, materials=None, crease_angle: float | None = None, size: int = DEFAULT_SIZE,
                seed: int | None = None, nodata: float | None = None, weld: float | None = None,
                progress: bool = False, tiles: int | None = None, workers: int | None = None,
                check_memory: bool = True, origin=None, stride: int = 1) -> dict:
    """Make one tile job's share of ``source``'s blocks of tiles and write them to ``tiles_dir``.

    ``job``: ``"I/N"`` or (I, N), this job's index and the number of jobs;
    the job makes the blocks whose number modulo N is I, through every
    level up to theirs (blocks already in the directory, from an earlier
    try, are kept). A :func:`build` with the same ``source`` and options
    and ``tiles_dir`` then reads them all, makes the levels above and
    returns the mesh one process would make; see
    :mod:`caveclod.builder.tilestore`. The other arguments are
    :func:`build`'s. Returns a report (blocks written, found, their level,
    seconds).
    """
    from .builder.hierarchy import build_tile_job
    from .builder.tilestore import TileStore, parse_job
    job = parse_job(f"{job[0]}/{job[1]}" if isinstance(job, tuple) else job)
    store = TileStore(Path(tiles_dir), job=job)
    return build_tile_job(lambda: _prepared_source(source, cell_size=cell_size, z_scale=z_scale, materials=materials,
                                                   crease_angle=crease_angle, size=size, seed=seed, nodata=nodata,
                                                   weld=weld, tiles=tiles, workers=workers, check_memory=check_memory,
                                                   origin=origin, stride=stride),
                          store, crease_angle=crease_angle, progress=progress, tiles=tiles, workers=workers)


def _prepared_source(source, *, cell_size, z_scale, materials, crease_angle, size, seed, nodata, weld, tiles, workers,
                     check_memory, origin=None, stride=1) -> SourceMesh:
    """The options checked, then ``source`` as a (welded) :class:`SourceMesh` that fits in memory."""
    from .builder.memory import check_build_memory
    from .builder.tiles import check_tiles
    from .builder.origin import move_to_origin, parse_origin
    _check_options(crease_angle=crease_angle, cell_size=cell_size, z_scale=z_scale)
    parse_origin(origin)
    _check_workers(workers)
    check_tiles(tiles)
    src = to_source(source, cell_size=cell_size, z_scale=z_scale, materials=materials, size=size, seed=seed,
                    nodata=nodata, check_memory=check_memory, stride=stride)
    if check_memory:
        check_build_memory(len(src.faces), _input_name(source, size))
    src = move_to_origin(src, origin)
    if weld is not None:
        from .builder.weld import weld_positions
        src = weld_positions(src, weld)
    return src


def _check_workers(workers) -> None:
    """Refuse a worker count the build cannot use."""
    if workers is not None and (not isinstance(workers, (int, np.integer)) or not 1 <= workers <= 256):
        raise InputError(f"--workers must be a whole number from 1 to 256, got {workers!r}")


def _raster_file_to_source(path: Path, samples, classes, cell_size, z_scale, stride: int = 1,
                           nodata=None) -> SourceMesh:
    """A heightfield file's mesh at the cell size given (``cell_size``), else the one its
    georeference states (and then where it lies: ``origin``), else 1; notes say which.
    ``samples``: :func:`caveclod.builder.terrain.read_heightfield`'s; ``stride``: one sample in
    ``stride`` a side, taken before the rest is read, cells that many times as wide."""
    from .builder import terrain
    from .builder.georef import grid_spacing
    spacing, why_not = grid_spacing(path, samples.shape)
    north_first = spacing is None or spacing.north_first
    origin = None
    if cell_size is not None:
        cell = terrain.cell_xy(cell_size)                 # checked here too: to_source may be called alone
        given = f"{cell[0]:g}" if cell[0] == cell[1] else f"{cell[0]:g} x {cell[1]:g}"
        notes = [] if spacing is None else [f"--cell-size {given} given; the file states "
                                            + spacing.note.replace("cell size ", "", 1)]
    elif spacing is None:
        cell, notes = 1.0, [] if why_not is None else [why_not + "; built with cell size 1"]
    else:
        cell, notes, origin = (spacing.x, spacing.y), [spacing.note], spacing.origin
    if not north_first:
        notes.append("the file's rows run northwards (its transformation says so): read as they are")
    valid = terrain.tiff_mask(path)
    if valid is not None and valid.all():
        valid = None
    if valid is not None:
        notes.append(f"the GeoTIFF's no-data mask leaves out {int(valid.size - np.count_nonzero(valid)):,} of its "
                     f"{valid.size:,} samples: they are holes")
    if stride > 1:
        samples, classes, cell, note = _every_kth(samples, classes, stride, cell, north_first)
        notes.append(note)
        if valid is not None:
            valid = terrain.every_kth_sample(valid, stride, north_first=north_first)[0]
    heights = terrain.heights_of(samples, path, nodata, valid=valid)
    source = terrain.raster_to_source(heights, cell_size=cell, z_scale=z_scale, materials=classes, notes=notes,
                                      north_first=north_first)
    if origin is not None:
        source.origin = origin
        source.notes.append(f"its south-west sample lies at ({origin[0]:.10g}, {origin[1]:.10g}) in the file's "
                            "coordinates (info origin); positions are relative to it")
    return source


def _every_kth(heights, classes, stride: int, cell, north_first: bool = True):
    """(heights, classes, cell size, note) at every ``stride``-th sample a side."""
    from .builder import terrain
    rows, cols = np.shape(heights)
    heights, classes = terrain.every_kth_sample(heights, stride, classes, north_first=north_first)
    cx, cy = terrain.cell_xy(cell)
    note = (f"--stride {stride}: one sample in {stride} a side of the {rows:,} x {cols:,} grid, "
            f"{heights.shape[0]:,} x {heights.shape[1]:,} samples, cells of "
            + (f"{cx * stride:g}" if cx == cy else f"{cx * stride:g} x {cy * stride:g}")
            + " (the south-west sample kept)")
    return heights, classes, (cx * stride, cy * stride), note


def _check_stride(stride) -> int:
    """``stride`` as an int, refused unless a whole number from 1 to 1,024."""
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or not 1 <= stride <= 1024:
        raise InputError(f"--stride must be a whole number from 1 to 1,024 (one sample in K a side of a "
                         f"heightfield), got {stride!r}")
    return int(stride)


def _check_options(crease_angle, cell_size, z_scale) -> None:
    """Refuse bad numeric options before any work is done."""
    for name, value in (("--crease-angle", 0.0 if crease_angle is None else crease_angle),
                        ("--cell-size", 1.0 if cell_size is None else cell_size), ("--z-scale", z_scale)):
        try:
            ok = np.isfinite(float(value))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(f"{name} must be a finite number, got {value!r}")
    if crease_angle is not None and not 0.0 <= float(crease_angle) <= 180.0:
        raise InputError(f"--crease-angle must be between 0 and 180 degrees, got {crease_angle}")


def _refuse_heightfield_options(what: str, cell_size, z_scale, materials, nodata, stride=1) -> None:
    """Options that only heightfields read are refused elsewhere, not silently ignored."""
    given = [name for name, unused in (("--cell-size", cell_size is not None and float(cell_size) != 1.0),
                                       ("--z-scale", float(z_scale) != 1.0),
                                       ("--materials", materials is not None), ("--nodata", nodata is not None),
                                       ("--stride", stride != 1))
             if unused]
    if given:
        raise InputError(f"{', '.join(given)} only apply to heightfields (.npy, .png, .tif, .hgt, .asc), not to "
                         f"{what}; drop them, or give a heightfield")


def load(path: str | os.PathLike) -> StaticMesh:
    """Open a ``.cvc`` file built by :func:`build` (memory-mapped)."""
    return _load_file(path)


def _input_name(source, size) -> str:
    """How a build's error messages name its input."""
    from .builder.builtin import BUILTINS
    if isinstance(source, str) and source in BUILTINS:
        return f"the built-in {source!r} at --size {size}"
    if isinstance(source, (str, os.PathLike)):
        return Path(source).name
    if isinstance(source, np.ndarray):
        return "the heightfield"
    return "the mesh"


def to_source(source, *, cell_size=None, z_scale=1.0, materials=None, size=DEFAULT_SIZE, seed=None,
              nodata=None, check_memory: bool = False, stride: int = 1) -> SourceMesh:
    """Turn any accepted ``source`` into a validated :class:`SourceMesh`.

    ``check_memory``: refuse a heightfield or built-in terrain whose build
    would not fit in memory from its grid's size alone, before its mesh
    (itself about 100 bytes a triangle) is made. ``stride``: a heightfield
    at every ``stride``-th sample a side (:func:`build`).
    """
    from .builder import builtin, meshfile, terrain
    from .builder.memory import check_build_memory, grid_triangles
    stride = _check_stride(stride)

    def check_grid(triangles, shape=None):
        if check_memory:
            check_build_memory(triangles, _input_name(source, size), grid_shape=shape, stride=stride)
    if isinstance(source, SourceMesh):
        _refuse_heightfield_options("a SourceMesh", None, 1.0, None, None, stride)
        source.validate()
        return source
    if isinstance(source, str) and source in builtin.BUILTINS:
        if stride != 1:
            raise InputError(f"--stride applies to heightfield files and arrays, not to the built-in {source!r}: "
                             "give it a smaller --size instead")
        _refuse_heightfield_options(f"the built-in {source!r}", cell_size, z_scale, materials, nodata)
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
            raise InputError(f"--seed must be a whole number from 0, got {seed!r}")
        if not isinstance(size, (int, np.integer)) or not 2 <= size <= 8192:
            raise InputError(f"--size must be an integer between 2 and 8192 cells, got {size!r}")
        if source in builtin.TERRAINS:
            check_grid(grid_triangles((size + 1, size + 1)))
        return builtin.BUILTINS[source](int(size)) if seed is None else builtin.BUILTINS[source](int(size), seed)
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if path.suffix.lower() in HEIGHTFIELD_SUFFIXES:
            shape = terrain.heightfield_shape(path)          # from the header: refused before the samples are read
            if shape is not None:
                check_grid(grid_triangles(shape, stride), shape)
            samples = terrain.read_heightfield(path, window=stride > 1)    # a .npy mapped, TIFF and .asc by window
            check_grid(grid_triangles(samples.shape, stride), samples.shape)
            classes = None
            if materials is not None:
                classes = terrain.load_material_map(materials) if isinstance(materials, (str, os.PathLike)) \
                    else np.asarray(materials)
            return _raster_file_to_source(path, samples, classes, cell_size, z_scale, stride, nodata)
        _refuse_heightfield_options(f"the mesh file {path.name}", cell_size, z_scale, materials, nodata, stride)
        if check_memory:
            from .builder.memory import check_read_memory
            check_read_memory(path, path.name)
        return meshfile.load_mesh_file(path)
    if isinstance(source, np.ndarray):
        check_grid(grid_triangles(source.shape, stride), source.shape)
        heights, classes = source, None if materials is None else np.asarray(materials)
        cell, notes = 1.0 if cell_size is None else cell_size, []
        if stride > 1:
            if source.ndim != 2:
                raise InputError(f"a heightfield is a 2-D array of samples, got shape {source.shape}")
            heights, classes, cell, note = _every_kth(heights, classes, stride, cell)
            notes.append(note)
        return terrain.raster_to_source(heights, cell_size=cell, z_scale=z_scale, materials=classes, notes=notes)
    try:
        import trimesh
    except ImportError:  # pragma: no cover - trimesh is a dependency
        trimesh = None
    if trimesh is not None and isinstance(source, (trimesh.Trimesh, trimesh.Scene)):
        _refuse_heightfield_options(f"a trimesh {type(source).__name__}", None, 1.0, None, None, stride)
        return meshfile.source_from_trimesh(source)
    raise InputError(f"cannot build from a {type(source).__name__}; give a path, 'default', a trimesh mesh or a heightfield array")
