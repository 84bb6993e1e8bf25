"""Fuzz ``caveclod build`` with mutated mesh files and heightfields.

:func:`fuzz_sources` makes one small, valid input of every kind the build
reads (:func:`make_seeds`: OBJ with an .mtl, ASCII and binary PLY, GLB
(plain, Draco-compressed, quantized and gltfpack -cc's), glTF, ASCII and
binary STL, OFF, .npy heightfields of three dtypes, 16-bit PNG, TIFF (and
an LZW GeoTIFF), a geographic GeoTIFF, an SRTM .hgt tile and an ESRI ASCII
grid), mutates a
copy per case (:func:`mutate`: lines, numbers, indices, header counts and fields, node transforms, bits, bytes,
truncation, and whole-geometry edits: scaled, offset, flattened, snapped,
holed, recast), sometimes with odd numeric options or a (mutated) material
map, and builds it in a :class:`fuzzing.CliWorker`, which survives crashes
and hangs. Seeds are tiny (about 20 to 100 triangles for meshes, 8x8 to
32x32 samples for heightfields) so that a case takes about 10 ms, not the
build of a real mesh.

The contract of a case (:func:`judge`), on top of :func:`fuzzing.cli_contract`:
exit 0, with nothing on stderr, an output that ``caveclod inspect --verify``
accepts and whose stored floats (positions, normals, uvs, bounds, cones) are
all finite; or exit 2 with exactly one ``caveclod: error:`` line. A
traceback, a crash, a hang, any warning on stderr (numpy's RuntimeWarning
from an overflow, say) or any other exit is a finding. Every warning is
shown (Python shows a warning once per line of code by default, which in a
long-lived worker would hide all but the first).

Run it briefly from tests/test_fuzz_sources.py, for long from the command line::

    .venv/bin/python tests/fuzzsources.py --seconds 600 --seed 1 --workdir /tmp/fuzz
"""

from __future__ import annotations

import io
import json
import os
import random
import re
import shutil
import struct
import sys
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fuzzing import Budget, CallResult, CliWorker, FuzzReport, cli_contract, finish, fuzzer_arguments, run_reported

CASE_TIMEOUT = 20.0       # seconds a case may take: a tiny build takes well under one
WARMUP_TIMEOUT = 300.0    # the first call of a fresh worker imports everything and loads the kernels
BUILD_TARGET = "fuzzsources:build_in_worker"
WORKER_MEMORY = 3 << 30   # address space of the worker: a file claiming a huge grid meets MemoryError,
                          # not the machine's other users (an idle worker maps about 0.6 GiB)
MAX_MUTATIONS = 3         # mutations stacked on one case
MAX_FILE_BYTES = 1 << 18  # mutations that grow a file stop here (seeds are a few KiB)

# Values that break numbers: out of float32's or float64's range, special,
# near the build's limits, malformed.
TEXT_NUMBERS = ("1e39", "-1e39", "3.4e38", "3.5e38", "1e30", "4.7e18", "-4.7e18", "1e308", "1e309",
                "1e-320", "1e-45", "nan", "-nan", "inf", "-inf", "Infinity", "0", "-0", "-1",
                "1.00000001", "1e-9", "2147483647", "2147483648", "-2147483649", "18446744073709551616",
                "99999999999999999999999", "0x1F", "1e", "--1", ".", "abc", "", "1,5", "1/2/3", "//")
INDEX_VALUES = ("0", "-1", "-99999", "99999", "2147483648", "-2147483649", "1", "1.5", "a")
FLOAT_VALUES = (float("nan"), float("inf"), float("-inf"), 3.4e38, 1e30, 4.7e18, -1e20, 1e-45, 1e-39,
                0.0, -0.0, 1.0 + 2 ** -20)
DOUBLE_VALUES = FLOAT_VALUES + (1e39, -1e300, 1e308, 5e-324)
INT_VALUES = (-1, 0, 1, 2 ** 31 - 1, -2 ** 31, 99999, 1 << 24)
# Command-line values of the numeric build options, all parseable as floats.
OPTION_VALUES = ("0", "-1", "nan", "inf", "-inf", "1e-320", "1e-39", "1e-30", "1e-9", "0.5", "3", "180",
                 "1e19", "1e38", "1e300")
HEIGHTFIELD_OPTIONS = ("--cell-size", "--z-scale", "--nodata", "--origin", "--stride")
STRIDE_VALUES = ("1", "2", "3", "5", "40", "1000", "0", "-1", "1.5", "99999999999")
MESH_OPTIONS = ("--weld", "--crease-angle", "--origin")
ORIGIN_VALUES = ("auto", "0,0,0", "1e30,0,0", "nan,1,1", "1,2", "-4.7e18,4.7e18,0", "abc", "1e308,-1e308,0")


@dataclass
class Seed:
    """One valid input: ``name`` (its extension picks the reader), its bytes,
    the ``family`` of mutations that fit it, and files that go beside it."""

    kind: str                    # what it is, for the report: "obj", "ply-binary", ...
    name: str
    data: bytes
    family: str                  # text, gltf, glb, ply, stl, npy, png, tiff, hgt or asc
    companions: dict = field(default_factory=dict)   # name -> bytes (an OBJ's .mtl)
    grid_shape: tuple | None = None                  # a heightfield's (rows, cols)

    @property
    def heightfield(self) -> bool:
        return self.family in ("npy", "png", "tiff", "hgt", "asc")


# ------------------------------------------------------------------ seeds


def make_seeds(rng: np.random.Generator) -> list[Seed]:
    """One seed of every kind, drawn from ``rng``. TIFF only where tifffile is
    installed (it is the build's TIFF reader, an optional dependency)."""
    import trimesh
    from trimesh.exchange import off, ply, stl

    sphere = _bumpy_sphere(rng)
    seeds = [
        Seed("obj", "seed.obj", _obj_text(rng).encode(), "text", {"seed.mtl": OBJ_MTL.encode()}),
        Seed("ply-ascii", "seed.ply", ply.export_ply(sphere, encoding="ascii", vertex_normal=True), "text"),
        Seed("ply-binary", "seed.ply", ply.export_ply(sphere, encoding="binary", vertex_normal=True), "ply"),
        Seed("glb", "seed.glb", _two_part_scene(rng).export(file_type="glb"), "glb"),
        Seed("glb-draco", "seed.glb", _draco_glb(_two_part_scene(rng)), "glb"),
        Seed("glb-quantized", "seed.glb", quantized_quad_glb(transform={"offset": [0.1, 0.2], "scale": [2.0, 3.0],
                                                                       "rotation": 0.5}), "glb"),
        # gltfpack -cc's output: EXT_meshopt_compression's codecs and the octahedral filter (tests/data)
        Seed("glb-meshopt", "seed.glb", (Path(__file__).parent / "data" / "sphere-gltfpack-cc.glb").read_bytes(),
             "glb"),
        Seed("gltf", "seed.gltf", _gltf_bytes(_two_part_scene(rng)), "gltf"),
        Seed("stl-ascii", "seed.stl", stl.export_stl_ascii(sphere).encode(), "text"),
        Seed("stl-binary", "seed.stl", stl.export_stl(sphere), "stl"),
        Seed("off", "seed.off", off.export_off(trimesh.Trimesh(sphere.vertices, sphere.faces)).encode(), "text"),
    ]
    grids = [("npy-f32", "seed.npy", "npy", _heights(rng, holes=True).astype(np.float32), _npy_bytes),
             ("npy-f64", "seed.npy", "npy", _heights(rng, holes=True), _npy_bytes),
             ("npy-i16", "seed.npy", "npy", _int16_heights(rng), _npy_bytes),
             ("png16", "seed.png", "png", _uint16_heights(rng), _png_bytes),
             ("hgt", "N46E007.hgt", "hgt", _square(_int16_heights(rng)), _hgt_bytes),
             ("asc", "seed.asc", "asc", _heights(rng, holes=True), _asc_bytes)]
    if _have_tifffile():
        grids.append(("tiff", "seed.tif", "tiff", _heights(rng, holes=True).astype(np.float32), _tiff_bytes))
        grids.append(("geotiff", "seed.tif", "tiff", _heights(rng, holes=True).astype(np.float32), _geotiff_bytes))
        # Strips and tiles, deflated: a strided build reads these by window (caveclod.builder.rasterwindow).
        grids.append(("tiff-strips", "seed.tif", "tiff", _heights(rng, holes=True).astype(np.float32),
                      lambda g: _tiff_bytes(g, rowsperstrip=3, compression="zlib")))
        grids.append(("tiff-tiles", "seed.tif", "tiff", _heights(rng, holes=True).astype(np.float32),
                      lambda g: _tiff_bytes(g, tile=(16, 16))))
    for kind, name, family, grid, encode in grids:
        seeds.append(Seed(kind, name, encode(grid), family, grid_shape=grid.shape))
    if _have_tifffile():    # LZW with a predictor, read through Pillow's libtiff without imagecodecs (tests/data)
        seeds.append(Seed("tiff-lzw", "seed.tif", (Path(__file__).parent / "data" / "dem-lzw-int16-voids.tif")
                          .read_bytes(), "tiff", grid_shape=(48, 64)))
    return seeds


def _draco_glb(scene) -> bytes:
    """``scene`` as a GLB whose geometry is Draco-compressed (KHR_draco_mesh_compression)."""
    from trimesh.exchange.gltf import export_glb
    return export_glb(scene, extension_draco=True)


def quantized_quad_glb(*, uv_type=5123, uv=None, normal=None, transform=None, stride=None, broken=False) -> bytes:
    """A GLB of a two-triangle quad: int16 positions with a node scale, uv (4, 2) stored as ``uv_type``
    normalized, int8 normals, the base colour texture's KHR_texture_transform ``transform``, as
    gltfpack writes them (``stride``: the texture coordinates interleaved; ``broken``: their accessor
    claims more items than its bufferView holds)."""
    pos = np.array([[0, 0, 0], [1000, 0, 0], [1000, 1000, 0], [0, 1000, 0]], "<i2")
    uv = np.array([[0, 0], [65535, 0], [65535, 65535], [0, 65535]]) if uv is None else uv
    dtype = {5121: "<u1", 5123: "<u2", 5120: "<i1", 5122: "<i2"}[uv_type]
    uvb = np.asarray(uv).astype(dtype).tobytes()
    if stride:                                       # interleave padding after each uv
        item = np.dtype(dtype).itemsize * 2
        uvb = b"".join(uvb[i:i + item] + b"\xee" * (stride - item) for i in range(0, len(uvb), item))
    nrm = (np.array([[0, 0, 127]] * 4, "<i1") if normal is None else normal).tobytes()
    idx = np.array([0, 1, 2, 0, 2, 3], "<u2").tobytes()
    parts, views = [pos.tobytes(), uvb, nrm, idx], []
    blob = b""
    for k, part in enumerate(parts):
        blob += b"\0" * (-len(blob) % 4)
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(part)}
        if k == 1 and stride:
            view["byteStride"] = stride
        views.append(view)
        blob += part
    accessors = [
        {"bufferView": 0, "componentType": 5122, "count": 4, "type": "VEC3", "min": [0, 0, 0],
         "max": [1000, 1000, 0]},
        {"bufferView": 1, "componentType": uv_type, "normalized": True, "count": 99 if broken else 4, "type": "VEC2"},
        {"bufferView": 2, "componentType": 5120, "normalized": True, "count": 4, "type": "VEC3"},
        {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
    ]
    texture_info = {"index": 0}
    if transform is not None:
        texture_info["extensions"] = {"KHR_texture_transform": transform}
    tree = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "extensionsUsed": ["KHR_mesh_quantization", "KHR_texture_transform"],
        "extensionsRequired": ["KHR_mesh_quantization"],
        "nodes": [{"mesh": 0, "scale": [0.001, 0.001, 0.001]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1, "NORMAL": 2}, "indices": 3,
                                    "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": texture_info}}],
        "textures": [{}],
        "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(blob)}],
    }
    from caveclod.builder.gltfquant import glb_bytes
    return glb_bytes(tree, blob)


def _have_tifffile() -> bool:
    try:
        import tifffile  # noqa: F401
    except ImportError:
        return False
    return True


def _bumpy_sphere(rng: np.random.Generator):
    """An icosphere of 80 faces with its radius jittered by 10 %, with
    normals and per-vertex colours."""
    import trimesh
    base = trimesh.creation.icosphere(subdivisions=1)
    vertices = base.vertices * (1.0 + 0.1 * rng.random((len(base.vertices), 1)))
    # The sphere's own normals, given rather than left to trimesh (which
    # logs a traceback when scipy is missing).
    return trimesh.Trimesh(vertices, base.faces, vertex_normals=base.vertices, process=False,
                           vertex_colors=rng.integers(0, 256, (len(vertices), 4), dtype=np.uint8))


def _two_part_scene(rng: np.random.Generator):
    """Two geometries with named materials: a textured sphere and a box."""
    import trimesh
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    sphere = trimesh.creation.icosphere(subdivisions=1)
    sphere.vertices *= 1.0 + 0.1 * rng.random((len(sphere.vertices), 1))
    uv = sphere.vertices[:, :2] * 0.5 + 0.5
    sphere.visual = TextureVisuals(uv=uv, material=PBRMaterial(name="stone", baseColorFactor=[200, 180, 160, 255]))
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    box.apply_translation((3.0, 0.0, 0.0))
    box.visual = TextureVisuals(uv=rng.random((len(box.vertices), 2)), material=PBRMaterial(name="metal"))
    scene = trimesh.Scene()
    scene.add_geometry(sphere, geom_name="sphere")
    scene.add_geometry(box, geom_name="box")
    return scene


def _gltf_bytes(scene) -> bytes:
    """A .gltf with its buffer embedded as base64 (one file, JSON text)."""
    from trimesh.exchange.gltf import export_gltf
    files = export_gltf(scene, embed_buffers=True)
    return files["model.gltf"]


OBJ_MTL = "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\nnewmtl green\nKd 0 1 0\n"


def _obj_text(rng: np.random.Generator) -> str:
    """A bumpy n x n grid of vertices with uvs and normals; quads in 'red',
    triangles by negative (relative) indices in 'blue', uv-only quads and a
    pentagon in 'green'."""
    n = int(rng.integers(4, 8))
    lines = ["mtllib seed.mtl", "o grid"]
    z = rng.normal(0.0, 0.2, (n, n))
    for r in range(n):
        for c in range(n):
            lines.append(f"v {c:.6f} {r:.6f} {z[r, c]:.6f}")
    for r in range(n):
        for c in range(n):
            lines.append(f"vt {c / (n - 1):.6f} {r / (n - 1):.6f}")
    for r in range(n):
        for c in range(n):
            normal = np.array([rng.normal(0, 0.1), rng.normal(0, 0.1), 1.0])
            lines.append("vn " + " ".join(f"{x:.6f}" for x in normal / np.linalg.norm(normal)))
    for k in range(5):                              # a pentagon above the grid, vertices n*n+1 ..
        angle = 2 * np.pi * k / 5
        lines.append(f"v {1 + np.cos(angle):.6f} {1 + np.sin(angle):.6f} 2.000000")
    cells = [(r, c) for r in range(n - 1) for c in range(n - 1)]
    total = n * n + 5                               # vertices written so far
    for i, (r, c) in enumerate(cells):
        a, b, d, e = r * n + c + 1, r * n + c + 2, (r + 1) * n + c + 2, (r + 1) * n + c + 1
        part = 3 * i // len(cells)
        if i == 0 or 3 * (i - 1) // len(cells) != part:
            lines.append("usemtl " + ("red", "blue", "green")[part])
        if part == 0:
            lines.append(f"f {a}/{a}/{a} {b}/{b}/{b} {d}/{d}/{d} {e}/{e}/{e}")
        elif part == 1:                             # relative indices: -1 is the last one written
            v = [x - total - 1 for x in (a, b, d, e)]   # n * n + 5 positions
            t = [x - n * n - 1 for x in (a, b, d, e)]   # n * n uvs and normals
            corner = [f"{v[k]}/{t[k]}/{t[k]}" for k in range(4)]
            lines.append(f"f {corner[0]} {corner[1]} {corner[2]}")
            lines.append(f"f {corner[0]} {corner[2]} {corner[3]}")
        else:
            lines.append(f"f {a}/{a} {b}/{b} {d}/{d} {e}/{e}")
    lines.append("f " + " ".join(str(n * n + k + 1) for k in range(5)))
    return "\n".join(lines) + "\n"


def _heights(rng: np.random.Generator, holes: bool) -> np.ndarray:
    """(rows, cols) float64 smooth random relief, 8 to 32 samples a side, with
    a few NaN holes when ``holes``."""
    rows, cols = (int(x) for x in rng.integers(8, 33, 2))
    h = rng.normal(0.0, 1.0, (rows, cols)).cumsum(axis=0).cumsum(axis=1) * 0.3
    if holes:
        h[rng.random((rows, cols)) < 0.05] = np.nan
    return h


def _int16_heights(rng: np.random.Generator) -> np.ndarray:
    """int16 heights in metres with a few -32768 (SRTM void) samples."""
    h = np.nan_to_num(_heights(rng, holes=False)) * 100.0
    grid = np.clip(h, -30000, 30000).astype(np.int16)
    grid[rng.random(grid.shape) < 0.03] = -32768
    return grid


def _square(grid: np.ndarray) -> np.ndarray:
    """The largest square of ``grid`` from its first row and column (an SRTM tile is square)."""
    side = min(grid.shape)
    return grid[:side, :side]


def _asc_bytes(grid: np.ndarray) -> bytes:
    """An ESRI ASCII grid: its header, then the rows (NaN written as the NODATA_value)."""
    rows, cols = grid.shape
    text = [f"ncols {cols}", f"nrows {rows}", "xllcorner 500000", "yllcorner 4100000", "cellsize 25",
            "NODATA_value -9999"]
    text += [" ".join("-9999" if np.isnan(v) else f"{v:.4f}" for v in row) for row in grid]
    return ("\n".join(text) + "\n").encode()


def _hgt_bytes(grid: np.ndarray) -> bytes:
    """An SRTM .hgt tile: big-endian int16 samples, no header."""
    return np.asarray(grid, ">i2").tobytes()


def _geotiff_bytes(grid: np.ndarray) -> bytes:
    """A geographic GeoTIFF: one arc-second samples tied at 7 E, 46 N, with GDAL's no-data tag."""
    arcsec = 1.0 / 3600.0
    keys = (1, 1, 0, 2, 1024, 0, 1, 2, 2054, 0, 1, 9102)    # GTModelType geographic, angular unit degree
    return _tiff_bytes(grid, extratags=[(33550, 12, 3, (arcsec, arcsec, 0.0)),
                                        (33922, 12, 6, (0.0, 0.0, 0.0, 7.0, 46.0, 0.0)),
                                        (34735, 3, len(keys), keys), (42113, 2, 0, "-9999")])


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _uint16_heights(rng: np.random.Generator) -> np.ndarray:
    """Heights spread over the whole uint16 range, as a 16-bit PNG holds them."""
    h = _heights(rng, holes=False)
    return ((h - h.min()) / max(float(np.ptp(h)), 1e-9) * 65535).astype(np.uint16)


def _png_bytes(grid: np.ndarray) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(grid).save(buf, format="PNG")
    return buf.getvalue()


def _tiff_bytes(grid: np.ndarray, **options) -> bytes:
    import tifffile
    buf = io.BytesIO()
    tifffile.imwrite(buf, grid, **options)
    return buf.getvalue()


def _materials_bytes(shape: tuple, rng: random.Random) -> bytes:
    """A material map for a grid of ``shape``: one class per cell or per sample, 0 to 3."""
    rows, cols = shape
    per_cell = rng.random() < 0.5
    classes = np.random.default_rng(rng.randrange(2 ** 32)).integers(0, 4, (rows - per_cell, cols - per_cell))
    return _npy_bytes(classes)


# ------------------------------------------------------------------ mutations


def mutate(seed: Seed, rng: random.Random) -> tuple[bytes, list[str]]:
    """A mutated copy of ``seed.data`` and the mutations made, one string each.

    One to :data:`MAX_MUTATIONS` mutations of the seed's family are stacked;
    one case in twenty is the seed unmutated (the exit 0 path must hold too).
    """
    if rng.random() < 0.05:
        return seed.data, ["none"]
    data, done = seed.data, []
    with quiet_warnings():                          # numpy and Pillow on odd values, in this process
        for _ in range(rng.randint(1, MAX_MUTATIONS)):
            mutator = rng.choice(MUTATORS[seed.family])
            data, what = mutator(data, rng)
            done.append(what)
    return data[:MAX_FILE_BYTES], done


def random_options(seed: Seed, rng: random.Random) -> list[str]:
    """Numeric build options for a case: usually none, sometimes one or two of
    those that apply to the seed's kind, with odd values."""
    if rng.random() < 0.75:
        return []
    names = HEIGHTFIELD_OPTIONS if seed.heightfield else MESH_OPTIONS
    # "--name=value": a value like "-inf" would otherwise read as an option.
    values = {"--origin": ORIGIN_VALUES, "--stride": STRIDE_VALUES}
    return [f"{name}={rng.choice(values.get(name, OPTION_VALUES))}" for name in rng.sample(names, rng.randint(1, 2))]


@dataclass
class Case:
    """One input to build: the (mutated) file, the files beside it, the options."""

    seed: Seed
    data: bytes
    mutations: list
    companions: dict
    options: list

    def describe(self) -> str:
        return f"{self.seed.kind} {' + '.join(self.mutations)} options {self.options}"


MATERIALS_NAME = "materials.npy"


def make_case(seed: Seed, rng: random.Random, directory: Path) -> Case:
    """A mutated copy of ``seed`` with random options. Its companions (an
    OBJ's .mtl) are mutated now and then; a heightfield sometimes gets a
    material map (``--materials``, written into ``directory``), itself
    mutated half of the time."""
    data, mutations = mutate(seed, rng)
    companions, options = dict(seed.companions), random_options(seed, rng)
    for name, content in seed.companions.items():           # an OBJ's .mtl, now and then
        if rng.random() < 0.1:
            companions[name], what = mutate(Seed("companion", name, content, "text"), rng)
            mutations.append(f"{name} " + " + ".join(what))
    if seed.grid_shape is not None and rng.random() < 0.15:
        classes = _materials_bytes(seed.grid_shape, rng)
        if rng.random() < 0.5:
            classes, what = mutate(Seed("materials", MATERIALS_NAME, classes, "npy"), rng)
            mutations.append("materials " + " + ".join(what))
        companions[MATERIALS_NAME] = classes
        options.append(f"--materials={directory / MATERIALS_NAME}")
    return Case(seed, data, mutations, companions, options)


# -- any bytes


def bit_flips(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    if not data:
        return data, "bitflip(empty)"
    out = bytearray(data)
    spots = [rng.randrange(len(out) * 8) for _ in range(rng.randint(1, 8))]
    for bit in spots:
        out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out), f"bitflip{spots}"


def truncate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    cut = rng.randrange(len(data)) if data else 0
    return data[:cut], f"truncate@{cut}"


def poke_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    if not data:
        return data, "poke(empty)"
    out = bytearray(data)
    at, run = rng.randrange(len(out)), rng.randint(1, 8)
    value = rng.choice((0x00, 0xFF, 0x7F, 0x80, rng.randrange(256)))
    out[at:at + run] = bytes([value]) * len(out[at:at + run])
    return bytes(out), f"poke@{at}x{run}={value:#x}"


def splice(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Copy a chunk of the file to another place (inserting it)."""
    if len(data) < 2:
        return data, "splice(short)"
    a = rng.randrange(len(data))
    b = min(len(data), a + rng.randint(1, 256))
    at = rng.randrange(len(data))
    return data[:at] + data[a:b] + data[at:], f"splice[{a}:{b}]@{at}"


def _poke_packed(data: bytes, start: int, rng: random.Random, fmt: str, values, step: int) -> tuple[bytes, str]:
    """Write one of ``values`` packed as ``fmt`` at a ``step``-aligned offset past ``start``."""
    size = struct.calcsize(fmt)
    slots = (len(data) - start - size) // step + 1
    if start < 0 or slots <= 0:
        return data, f"poke-{fmt}(no room)"
    at = start + step * rng.randrange(slots)
    value = rng.choice(values)
    return data[:at] + struct.pack(fmt, value) + data[at + size:], f"poke-{fmt}@{at}={value!r}"


# -- text


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def delete_line(data, rng):
    lines = _lines(data)
    i = rng.randrange(len(lines))
    del lines[i]
    return b"\n".join(lines), f"delete-line {i}"


def duplicate_line(data, rng):
    lines = _lines(data)
    i, times = rng.randrange(len(lines)), rng.choice((1, 1, 2, 50))
    lines[i:i] = [lines[i]] * times
    return b"\n".join(lines), f"duplicate-line {i} x{times}"


def swap_lines(data, rng):
    lines = _lines(data)
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines), f"swap-lines {i} {j}"


def insert_junk_line(data, rng):
    lines = _lines(data)
    i = rng.randrange(len(lines) + 1)
    junk = rng.choice((b"f 1 2", b"f", b"v 1 2", b"vn", b"vt 1", b"usemtl", b"usemtl missing", b"mtllib nothere.mtl",
                       b"o", b"g g g", b"s off", b"f 1/2/3/4 5 6", b"\x00\xff\xfe", b"element vertex 99999",
                       b"3 0 1", b"facet normal 0 0 0", b"endsolid", b"OFF", b"\t\t"))
    lines.insert(i, junk)
    return b"\n".join(lines), f"insert-line {i} {junk!r}"


_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def replace_number(data, rng):
    """Replace one number of the text with a value from :data:`TEXT_NUMBERS`."""
    found = list(_NUMBER.finditer(data[:MAX_FILE_BYTES]))
    if not found:
        return data, "replace-number(none)"
    m = rng.choice(found)
    new = rng.choice(TEXT_NUMBERS).encode()
    return data[:m.start()] + new + data[m.end():], f"number@{m.start()} {m.group().decode()}->{new.decode()}"


def replace_index(data, rng):
    """Replace a number on a face line (OBJ 'f', OFF/PLY index rows) by an
    out-of-range, zero, negative or malformed index."""
    lines = _lines(data)
    rows = [i for i, ln in enumerate(lines) if ln.startswith(b"f ") or re.fullmatch(rb"\s*[34] [\d ]+\s*", ln)]
    if not rows:
        return replace_number(data, rng)
    i = rng.choice(rows)
    found = list(re.finditer(rb"-?\d+", lines[i]))
    if not found:                                    # "f" and no number left (an earlier mutation)
        return replace_number(data, rng)
    m = rng.choice(found[1:] or found)
    new = rng.choice(INDEX_VALUES).encode()
    lines[i] = lines[i][:m.start()] + new + lines[i][m.end():]
    return b"\n".join(lines), f"index line {i} {m.group().decode()}->{new.decode()}"


# -- JSON (glTF, and the JSON chunk of GLB)


def _json_leaves(node, path=(), out=None, limit=2000):
    """Paths of the leaves (numbers, strings, booleans, null) of a JSON value, at most ``limit``."""
    out = [] if out is None else out
    if len(out) >= limit:
        return out
    if isinstance(node, dict):
        for key, value in node.items():
            _json_leaves(value, path + (key,), out, limit)
    elif isinstance(node, list):
        for i, value in enumerate(node[:64]):
            _json_leaves(value, path + (i,), out, limit)
    else:
        out.append(path)
    return out


JSON_VALUES = (-1, 0, 1, 3, 5120, 5126, 2 ** 31, 2 ** 53, 1e39, -1e39, 1e308, "", "abc", "data:,",
               "missing.bin", None, True, [], {}, [1e39, 0, 0], "SCALAR", "VEC3")


def mutate_json_value(doc: dict, rng: random.Random) -> str:
    """Replace one leaf (or delete one key) of ``doc`` in place; returns what was done."""
    leaves = _json_leaves(doc)
    if not leaves:
        return "json(no leaves)"
    path = rng.choice(leaves)
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if isinstance(parent, dict) and rng.random() < 0.2:
        del parent[path[-1]]
        return f"json-del {'/'.join(map(str, path))}"
    value = rng.choice(JSON_VALUES)
    if isinstance(parent[path[-1]], str) and parent[path[-1]].startswith("data:") and rng.random() < 0.5:
        value = parent[path[-1]][: rng.randrange(len(parent[path[-1]]))]     # a truncated data URI
    parent[path[-1]] = value
    return f"json {'/'.join(map(str, path))}={str(value)[:40]}"


def gltf_json(data, rng):
    try:
        doc = json.loads(data)
    except ValueError:
        return replace_number(data, rng)
    what = mutate_json_value(doc, rng)
    return json.dumps(doc).encode(), what


# -- GLB: header, JSON chunk, BIN chunk


def _glb_chunks(data: bytes):
    """(json bytes, bin bytes) of a GLB, or None when the chunk headers do not parse."""
    if len(data) < 20:
        return None
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = data[20:20 + json_len]
    rest = data[20 + json_len:]
    binary = rest[8:8 + struct.unpack_from("<I", rest, 0)[0]] if len(rest) >= 8 else b""
    return doc, binary


def _glb(doc: bytes, binary: bytes) -> bytes:
    doc += b" " * (-len(doc) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<I4s", len(doc), b"JSON") + doc
    if binary:
        body += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def glb_json(data, rng):
    chunks = _glb_chunks(data)
    try:
        doc = json.loads(chunks[0]) if chunks else None
    except ValueError:
        doc = None
    if not isinstance(doc, dict):
        return bit_flips(data, rng)
    what = mutate_json_value(doc, rng)
    return _glb(json.dumps(doc).encode(), chunks[1]), "glb-" + what


def glb_binary_floats(data, rng):
    chunks = _glb_chunks(data)
    if not chunks:
        return poke_bytes(data, rng)
    start = len(data) - len(chunks[1])
    return _poke_packed(data, start, rng, "<f", FLOAT_VALUES, 4)


def glb_lengths(data, rng):
    """Poke the total length or a chunk length of the GLB header."""
    at = rng.choice((8, 12))
    value = rng.choice((0, 1, 2 ** 31, 2 ** 32 - 1, len(data) * 2, max(len(data) - 4, 0)))
    return data[:at] + struct.pack("<I", value) + data[at + 4:], f"glb-length@{at}={value}"


# -- binary PLY: text header, binary body


def _ply_split(data: bytes) -> tuple[bytes, bytes]:
    end = data.find(b"end_header\n")
    if end < 0:
        return data, b""
    end += len(b"end_header\n")
    return data[:end], data[end:]


def ply_header(data, rng):
    """A text mutation of the header only: counts, property types, format."""
    header, body = _ply_split(data)
    edits = (replace_number, replace_number, swap_lines, delete_line, duplicate_line, _ply_type_edit)
    new_header, what = rng.choice(edits)(header, rng)
    return new_header + body, "ply-header " + what


def _ply_type_edit(header, rng):
    types = (b"char", b"uchar", b"short", b"ushort", b"int", b"uint", b"float", b"double", b"int64", b"list")
    found = list(re.finditer(rb"\b(char|uchar|short|ushort|int|uint|float|double)\b", header))
    if not found:
        return header, "type(none)"
    m = rng.choice(found)
    new = rng.choice(types)
    return header[:m.start()] + new + header[m.end():], f"type {m.group().decode()}->{new.decode()}"


def ply_body_floats(data, rng):
    header, _ = _ply_split(data)
    return _poke_packed(data, len(header), rng, "<f", FLOAT_VALUES, 4)


def ply_body_ints(data, rng):
    header, _ = _ply_split(data)
    return _poke_packed(data, len(header), rng, "<i", INT_VALUES, 1)


# -- binary STL: 80-byte header, triangle count, 50-byte records


def stl_count(data, rng):
    n = struct.unpack_from("<I", data, 80)[0] if len(data) >= 84 else 0
    value = rng.choice((0, 1, max(n - 1, 0), n + 1, n * 1000, 2 ** 31, 2 ** 32 - 1)) % 2 ** 32
    return data[:80] + struct.pack("<I", value) + data[84:], f"stl-count {n}->{value}"


def stl_floats(data, rng):
    if len(data) < 134:
        return poke_bytes(data, rng)
    record = rng.randrange((len(data) - 84) // 50)
    at = 84 + 50 * record + 4 * rng.randrange(12)
    value = rng.choice(FLOAT_VALUES)
    return data[:at] + struct.pack("<f", value) + data[at + 4:], f"stl-float@{at}={value!r}"


# -- .npy: magic, version, header dict, data


_NPY_SHAPES = ("(0,)", "(0, 8)", "(8, 0)", "(1, 1)", "(2, 2)", "(1, 9)", "(3,)", "(2, 3, 4)", "(100000, 100000)",
               "(4294967296, 4294967296)", "(-1, 5)", "(5, 5, 1)", "()")
_NPY_DESCRS = ("'<f4'", "'<f8'", "'<i2'", "'>f4'", "'>i2'", "'<u2'", "'|u1'", "'|b1'", "'<c8'", "'<f2'", "'<i8'",
               "'<u8'", "'|O'", "'<U3'", "'|S4'", "'<m8[s]'", "'<M8[s]'", "'|V8'", "'<f16'", "[('a', '<f4')]")


def _npy_split(data: bytes):
    """(header text, offset of the data) of an .npy (version 1), or None."""
    if len(data) < 10 or not data.startswith(b"\x93NUMPY"):
        return None
    length = struct.unpack_from("<H", data, 8)[0]
    return data[10:10 + length], 10 + length


def _npy_with_header(data: bytes, header: bytes, offset: int) -> bytes:
    header = header.rstrip(b" \n")
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return data[:8] + struct.pack("<H", len(header)) + header + data[offset:]


def npy_header(data, rng):
    split = _npy_split(data)
    if split is None:
        return bit_flips(data, rng)
    header, offset = split
    field_ = rng.choice(("shape", "shape", "descr", "descr", "fortran_order"))
    if field_ == "shape":
        new = rng.choice(_NPY_SHAPES)
        header = re.sub(rb"'shape': \([^)]*\)", b"'shape': " + new.encode(), header)
    elif field_ == "descr":
        new = rng.choice(_NPY_DESCRS)
        header = re.sub(rb"'descr': '[^']*'", b"'descr': " + new.encode(), header)
    else:
        new = "True"
        header = header.replace(b"'fortran_order': False", b"'fortran_order': True")
    return _npy_with_header(data, header, offset), f"npy-{field_}={new}"


def npy_values(data, rng):
    """Poke a special value of the array's own dtype at an element."""
    split = _npy_split(data)
    if split is None:
        return poke_bytes(data, rng)
    header, offset = split
    if b"'<f4'" in header:
        return _poke_packed(data, offset, rng, "<f", FLOAT_VALUES, 4)
    if b"'<f8'" in header:
        return _poke_packed(data, offset, rng, "<d", DOUBLE_VALUES, 8)
    if b"'<i2'" in header:
        return _poke_packed(data, offset, rng, "<h", (-32768, 32767, 0, -1), 2)
    return poke_bytes(data, rng)


# -- PNG: signature, chunks with CRCs


def _png_chunks(data: bytes) -> list[list]:
    """[type, payload] of every chunk that parses (at most 256)."""
    chunks, at = [], 8
    while at + 12 <= len(data) and len(chunks) < 256:
        length, kind = struct.unpack_from(">I4s", data, at)
        chunks.append([kind, data[at + 8:at + 8 + length]])
        at += 12 + length
    return chunks


def _png(chunks) -> bytes:
    out = b"\x89PNG\r\n\x1a\n"
    for kind, payload in chunks:
        out += struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))
    return out


def png_header(data, rng):
    """Change the IHDR's size, bit depth, colour type or interlace, with a correct CRC."""
    chunks = _png_chunks(data)
    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        return bit_flips(data, rng)
    ihdr = bytearray(chunks[0][1])
    width, height = struct.unpack_from(">II", ihdr)
    what = rng.choice(("size", "size", "depth", "colour", "interlace"))
    if what == "size":
        width, height = rng.choice(((0, height), (width, 0), (1, 1), (width + 1, height), (width, height * 3),
                                    (10000, 10000), (65535, 65535), (2 ** 31 - 1, 1), (100000, height)))
        width, height = (min(v, 2 ** 32 - 1) for v in (width, height))     # an earlier mutation's huge size, grown
        struct.pack_into(">II", ihdr, 0, width, height)
        new = f"{width}x{height}"
    elif what == "depth":
        ihdr[8] = rng.choice((1, 2, 4, 8, 16, 3, 32))
        new = str(ihdr[8])
    elif what == "colour":
        ihdr[9] = rng.choice((0, 2, 3, 4, 6, 5))
        new = str(ihdr[9])
    else:
        ihdr[12] = 1
        new = "adam7"
    chunks[0][1] = bytes(ihdr)
    return _png(chunks), f"png-{what}={new}"


def png_drop_chunk(data, rng):
    chunks = _png_chunks(data)
    if len(chunks) < 2:
        return truncate(data, rng)
    i = rng.randrange(len(chunks))
    kind = chunks[i][0]
    del chunks[i]
    return _png(chunks), f"png-drop {kind!r}"


def png_pixels(data, rng):
    """Recompress the IDAT with changed filtered bytes (valid zlib, odd pixels)."""
    chunks = _png_chunks(data)
    idat = [c for c in chunks if c[0] == b"IDAT"]
    try:
        raw = bytearray(zlib.decompress(b"".join(c[1] for c in idat)))
    except zlib.error:
        return bit_flips(data, rng)
    if not raw:
        return data, "png-pixels(empty)"
    raw, what = poke_bytes(bytes(raw), rng)
    rest = [c for c in chunks if c[0] != b"IDAT"]
    return _png(rest[:-1] + [[b"IDAT", zlib.compress(raw)]] + rest[-1:]), "png-pixels " + what


# -- TIFF (classic, little-endian, as tifffile writes small files)


_TIFF_TAGS = {256: "width", 257: "length", 258: "bits", 259: "compression", 262: "photometric", 273: "offsets",
              277: "samples", 278: "rows-per-strip", 279: "byte-counts", 284: "planar", 339: "sample-format",
              322: "tile-width", 323: "tile-length"}
_TIFF_VALUES = (0, 1, 2, 3, 5, 7, 8, 16, 32, 64, 65535, 100000, 2 ** 31 - 1, 2 ** 32 - 1)


def _ifd_entries(data) -> list[tuple[int, int, int, int, int]]:
    """(offset, tag, type, count, value or offset) of the first IFD's entries (up to 64) of a
    little-endian TIFF; empty for anything else."""
    if len(data) < 8 or data[:4] != b"II*\0":
        return []
    ifd = struct.unpack_from("<I", data, 4)[0]
    if ifd + 2 > len(data):
        return []
    entries = []
    for i in range(min(struct.unpack_from("<H", data, ifd)[0], 64)):
        at = ifd + 2 + 12 * i
        if at + 12 > len(data):
            break
        entries.append((at, *struct.unpack_from("<HHII", data, at)))
    return entries


def tiff_tag(data, rng):
    """Set the value of one of the first IFD's image-layout tags."""
    entries = [(at, tag, kind) for at, tag, kind, _, _ in _ifd_entries(data) if tag in _TIFF_TAGS and kind in (3, 4)]
    if not entries:
        return bit_flips(data, rng)
    at, tag, kind = rng.choice(entries)
    value = rng.choice(_TIFF_VALUES)
    packed = struct.pack("<HH", min(value, 65535), 0) if kind == 3 else struct.pack("<I", value)
    return data[:at + 8] + packed + data[at + 12:], f"tiff-{_TIFF_TAGS[tag]}={value}"


_GEO_TAGS = {33550: "pixel-scale", 33922: "tiepoint", 34264: "transformation"}
_GEO_VALUES = (0.0, -1.0, 1e-300, 1e300, float("inf"), float("nan"), 91.0, -1e9, 2.0 ** 62)


def geotiff_double(data, rng):
    """Set one double of a GeoTIFF's pixel scale or tie point (a stored, little-endian TIFF)."""
    entries = [(tag, count, offset) for _, tag, kind, count, offset in _ifd_entries(data)
               if tag in _GEO_TAGS and kind == 12 and 0 < count and offset + 8 * count <= len(data)]
    if not entries:
        return tiff_tag(data, rng)
    tag, count, offset = rng.choice(entries)
    k, value = rng.randrange(count), rng.choice(_GEO_VALUES)
    at = offset + 8 * k
    return data[:at] + struct.pack("<d", value) + data[at + 8:], f"geotiff-{_GEO_TAGS[tag]}[{k}]={value}"


def tiff_description(data, rng):
    """Edit the numbers of tifffile's JSON description ('{"shape": [r, c]}'),
    which tifffile reshapes the pixels by."""
    m = re.search(rb'\{"shape": \[[^\]]*\]\}', data)
    if not m:
        return replace_number(data, rng)
    new = rng.choice((b"[0, 0]", b"[1, 64]", b"[64, 1]", b"[99999, 99999]", b"[8, 8, 8]", b"[-1, 8]"))
    text = b'{"shape": ' + new + b"}"
    text = text[:len(m.group())].ljust(len(m.group()), b" ")        # keep every offset in the file valid
    return data[:m.start()] + text + data[m.end():], f"tiff-description {new.decode()}"


# -- geometry: every vertex moved the same way (scaled, offset, flattened, snapped, ...)


def _move(rng: random.Random):
    """A random transformation of (n, 3) float64 vertices, and its name."""
    choice = rng.choice(("scale", "offset", "flatten", "snap", "collapse", "jitter", "shuffle"))
    if choice == "scale":
        f = rng.choice((1e-30, 1e-8, 1e8, 1e12, 4e18, -1.0))
        return (lambda v: v * f), f"scale {f:g}"
    if choice == "offset":
        o = rng.choice((1e7, 1e9, 1e15, -3e18))
        return (lambda v: v + o), f"offset {o:g}"
    if choice == "flatten":
        k = rng.randrange(3)
        return (lambda v: np.where(np.arange(3) == k, 0.0, v)), f"flatten axis {k}"
    if choice == "snap":
        g = rng.choice((0.25, 0.5, 1.0))
        return (lambda v: np.round(v / g) * g), f"snap {g}"
    if choice == "collapse":                        # every vertex onto one point, or onto a line
        return (lambda v: np.where(np.arange(3) == 0, v, v[:1])), "collapse onto a line"
    if choice == "jitter":                          # apart in float64, together in float32
        seed = rng.randrange(2 ** 32)
        return (lambda v: v + np.random.default_rng(seed).random(v.shape) * 1e-12), "jitter 1e-12"
    seed = rng.randrange(2 ** 32)
    return (lambda v: np.random.default_rng(seed).permutation(v)), "shuffle vertices"


_VERTEX_ROW = re.compile(rb"^(\s*(?:v |vertex )?\s*)(\S+)(\s+)(\S+)(\s+)(\S+)(.*)$")


def text_geometry(data, rng):
    """Move every vertex row of a text mesh (OBJ 'v', STL 'vertex', OFF and
    PLY rows of three or more decimals) the same way."""
    lines = _lines(data)
    rows, coords = [], []
    for i, line in enumerate(lines[:20000]):
        m = _VERTEX_ROW.match(line)
        if not m or line.lstrip().startswith((b"vt", b"vn")) or not re.search(rb"[.eE]", line):
            continue
        try:
            coords.append([float(m.group(k)) for k in (2, 4, 6)])
        except ValueError:
            continue
        rows.append((i, m))
    if not rows:
        return replace_number(data, rng)
    move, what = _move(rng)
    with np.errstate(all="ignore"):
        moved = move(np.array(coords))
    for (i, m), xyz in zip(rows, moved):
        lines[i] = (m.group(1) + repr(float(xyz[0])).encode() + m.group(3) + repr(float(xyz[1])).encode()
                    + m.group(5) + repr(float(xyz[2])).encode() + m.group(7))
    return b"\n".join(lines), f"geometry {what} ({len(rows)} rows)"


def stl_geometry(data, rng):
    """Move every vertex of a binary STL the same way (float32, as STL holds them)."""
    n = (len(data) - 84) // 50
    if n <= 0:
        return stl_count(data, rng)
    record = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    tris = np.frombuffer(data[84:84 + 50 * n], dtype=record).copy()
    move, what = _move(rng)
    with np.errstate(all="ignore"):
        tris["v"] = move(tris["v"].reshape(-1, 3).astype(np.float64)).reshape(-1, 3, 3).astype(np.float32)
    return data[:84] + tris.tobytes() + data[84 + 50 * n:], f"stl-geometry {what}"


_NODE_FIELDS = (("translation", [1e9, 0, 0]), ("translation", [4e18, 4e18, 0]), ("scale", [1e20, 1, 1]),
                ("scale", [0, 0, 0]), ("scale", [-1, 1, 1]), ("scale", [1e-30, 1e-30, 1e-30]),
                ("rotation", [0, 0, 0, 0]), ("rotation", [float("nan"), 0, 0, 1]),
                ("matrix", [0] * 16), ("matrix", [1e300] * 16), ("matrix", [float("inf")] + [0] * 15),
                ("children", [0]), ("children", [99]), ("mesh", 99))


def gltf_node(doc: dict, rng: random.Random) -> str:
    """Give a node of ``doc`` an odd transform, a cycle or a missing mesh."""
    nodes = doc.get("nodes")
    if not isinstance(nodes, list) or not nodes or not isinstance(nodes[0], dict):
        return "node(none)"
    i = rng.randrange(len(nodes))
    name, value = rng.choice(_NODE_FIELDS)
    if isinstance(nodes[i], dict):
        nodes[i][name] = value
    return f"node {i} {name}={value}"


def gltf_node_edit(data, rng):
    try:
        doc = json.loads(data)
    except ValueError:
        return replace_number(data, rng)
    return json.dumps(doc).encode(), gltf_node(doc, rng)   # NaN and Infinity written as JSON5-ish tokens


def glb_node_edit(data, rng):
    chunks = _glb_chunks(data)
    try:
        doc = json.loads(chunks[0]) if chunks else None
    except ValueError:
        doc = None
    if not isinstance(doc, dict):
        return bit_flips(data, rng)
    what = gltf_node(doc, rng)
    return _glb(json.dumps(doc).encode(), chunks[1]), "glb-" + what


# -- heightfield grids: decoded, changed as arrays, encoded again


def _grid_edit(grid: np.ndarray, rng: random.Random) -> tuple[np.ndarray, str]:
    """A changed copy of a 2-D grid: values scaled, flattened, holed, spiked,
    reshaped or recast; and what was done."""
    choice = rng.choice(("scale", "constant", "checkerboard", "one block", "all nan", "spike", "shape", "dtype",
                         "tiny steps"))
    g = grid.astype(np.float64)
    if choice == "scale":
        f = rng.choice((1e-300, 1e-30, 1e18, 1e30, -1.0))
        with np.errstate(all="ignore"):
            return g * f, f"scale {f:g}"
    if choice == "constant":
        return np.full_like(g, rng.choice((0.0, 5.0, -1e18))), "constant"
    if choice == "checkerboard":                    # holes such that no 2x2 block is whole
        g[(np.add.outer(np.arange(g.shape[0]), np.arange(g.shape[1])) % 2) == 0] = np.nan
        return g, "checkerboard nan"
    if choice == "one block":
        block = g[:2, :2].copy()
        g[:] = np.nan
        g[:2, :2] = block
        return g, "nan but one 2x2 block"
    if choice == "all nan":
        return np.full_like(g, np.nan), "all nan"
    if choice == "spike":
        r, c = rng.randrange(g.shape[0]), rng.randrange(g.shape[1])
        g[r, c] = rng.choice((1e30, 4.7e18, -4.7e18, 1e6))
        return g, f"spike at {r},{c}"
    if choice == "shape":
        shape = rng.choice(((2, 2), (2, None), (None, 2), (1, None), (None, 1), "T"))
        if shape == "T":
            return grid.T.copy(), "transposed"
        rows = shape[0] or grid.shape[0]
        cols = shape[1] or grid.shape[1]
        return grid[:rows, :cols].copy(), f"cropped to {rows}x{cols}"
    if choice == "dtype":
        dtype = rng.choice((np.float16, np.uint8, np.bool_, np.int64, np.uint64, np.complex64, np.int8))
        with np.errstate(all="ignore"):
            return np.nan_to_num(g).astype(dtype) if np.dtype(dtype).kind in "iub" else g.astype(dtype), \
                f"as {np.dtype(dtype).name}"
    return 1e6 + np.arange(g.size).reshape(g.shape) * 1e-9, "tiny steps at 1e6"


def npy_grid(data, rng):
    try:
        grid = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception:                               # an earlier mutation broke it
        return npy_header(data, rng)
    if grid.ndim != 2 or grid.dtype.kind not in "biuf" or min(grid.shape) < 1:
        return npy_header(data, rng)
    new, what = _grid_edit(grid, rng)
    return _npy_bytes(new), "npy-grid " + what


def png_image(data, rng):
    """Decode the PNG and save its pixels again: changed (see _grid_edit),
    in another mode (8-bit, RGB, palette, with alpha, bilevel) or size."""
    from PIL import Image
    try:
        with quiet_warnings(), Image.open(io.BytesIO(data)) as image:
            grid = np.array(image)
    except Exception:
        return bit_flips(data, rng)
    if grid.ndim != 2 or min(grid.shape) < 1:
        return bit_flips(data, rng)
    mode = rng.choice(("edit", "edit", "L", "RGB", "P", "LA", "1", "I"))
    try:
        if mode == "edit":
            new, what = _grid_edit(grid, rng)
            with np.errstate(all="ignore"):
                image = Image.fromarray(np.clip(np.nan_to_num(new), 0, 65535).astype(np.uint16))
        else:
            image = Image.fromarray(grid).convert(mode)
            what = f"mode {mode}"
        buf = io.BytesIO()
        image.save(buf, format="PNG")
    except Exception:                               # a mode or size PNG cannot hold
        return bit_flips(data, rng)
    return buf.getvalue(), "png-image " + what


_TIFF_LAYOUTS = ({"compression": "zlib"}, {"tile": (16, 16)}, {"photometric": "rgb"}, {"planarconfig": "separate"},
                 {"extratags": [(42113, "s", 0, "-9999", True)]}, {"extratags": [(42113, "s", 0, "nan", True)]},
                 {"extratags": [(42113, "s", 0, "abc", True)]}, {"extratags": [(42113, "s", 0, "1e400", True)]},
                 {"bigtiff": True}, {"pages": 2})


def tiff_image(data, rng):
    """Decode the TIFF and write its pixels again: changed (see _grid_edit) or
    laid out otherwise (compressed, tiled, RGB, two pages, GDAL_NODATA, BigTIFF)."""
    import tifffile
    try:
        with quiet_warnings():
            grid = np.squeeze(tifffile.imread(io.BytesIO(data)))
    except Exception:
        return bit_flips(data, rng)
    if grid.ndim != 2 or min(grid.shape) < 1:
        return bit_flips(data, rng)
    if rng.random() < 0.5:
        new, what = _grid_edit(grid, rng)
        options = {}
    else:
        new, options = grid, dict(rng.choice(_TIFF_LAYOUTS))
        what = ", ".join(f"{k}={v}" for k, v in options.items())
        if options.pop("pages", None):
            new = np.stack([grid, grid])
        if options.get("photometric") == "rgb":
            new = np.stack([grid] * 3, axis=-1)
        if options.get("planarconfig"):
            new = np.stack([grid] * 2)
    try:
        with quiet_warnings():
            return _tiff_bytes(new, **options), "tiff-image " + what
    except Exception:                               # a layout this grid's dtype cannot take
        return bit_flips(data, rng)


def quiet_warnings():
    """Silence the warnings of the fuzzer's own encoders and decoders."""
    from caveclod.builder.quiet import quiet_reading
    return quiet_reading("tifffile", "PIL")


MUTATORS = {
    # Several entries of one mutator make it likelier; every family has truncation and bit flips.
    "text": (delete_line, duplicate_line, swap_lines, insert_junk_line, replace_number, replace_number,
             replace_index, replace_index, text_geometry, text_geometry, truncate, bit_flips),
    "gltf": (gltf_json, gltf_json, gltf_json, gltf_node_edit, gltf_node_edit, replace_number, truncate, bit_flips),
    "glb": (glb_json, glb_json, glb_json, glb_node_edit, glb_node_edit, glb_binary_floats, glb_lengths, truncate,
            bit_flips, poke_bytes),
    "ply": (ply_header, ply_header, ply_body_floats, ply_body_floats, ply_body_ints, truncate, bit_flips,
            poke_bytes),
    "stl": (stl_count, stl_floats, stl_floats, stl_geometry, stl_geometry, truncate, bit_flips, poke_bytes, splice),
    "npy": (npy_header, npy_header, npy_values, npy_values, npy_grid, npy_grid, npy_grid, truncate, bit_flips),
    "png": (png_header, png_header, png_drop_chunk, png_pixels, png_image, png_image, png_image, truncate,
            bit_flips, poke_bytes),
    "tiff": (tiff_tag, tiff_tag, tiff_description, tiff_image, tiff_image, tiff_image, geotiff_double, truncate,
             bit_flips, poke_bytes),
    "hgt": (truncate, truncate, bit_flips, poke_bytes, poke_bytes),
    "asc": (delete_line, duplicate_line, swap_lines, insert_junk_line, replace_number, replace_number, truncate,
            bit_flips),
}


# ------------------------------------------------------------------ the worker's side


def build_in_worker(input_path: str, output_path: str, options: list) -> dict:
    """:func:`build_case` with this process's memory capped (the worker's target)."""
    _limit_memory()
    return build_case(input_path, output_path, options)


def build_case(input_path: str, output_path: str, options: list) -> dict:
    """One case, in this process: ``caveclod build INPUT -o OUTPUT --quiet
    OPTIONS``, then, if it built, ``caveclod inspect OUTPUT --json --verify``
    and a look at the stored floats.

    Every warning is recorded (not only the first of each line of code, as
    Python's default would in a long-lived worker) and printed to stderr at
    the end, whoever else records warnings (pytest does). Exceptions
    propagate: the worker prints their traceback, which is the finding.

    Returns {"build": exit status, "inspect": exit status or None,
    "finite": whether every float array of the output is finite, or None}.
    """
    from caveclod.cli import main
    out = {"build": None, "inspect": None, "finite": None}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out["build"] = _exit_status(main, ["build", input_path, "-o", output_path, "--quiet", *options])
        if out["build"] == 0:
            out["inspect"] = _exit_status(main, ["inspect", output_path, "--json", "--verify"])
        if out["inspect"] == 0:
            out["finite"] = _stored_floats_finite(output_path)
    for w in caught:
        sys.stderr.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line))
    return out


def build_here(capsys, path, *options: str) -> tuple[int, str]:
    """For regression tests: ``caveclod build PATH OPTIONS`` in this process,
    as a case of the fuzzer, with pytest's ``capsys``; returns (exit status,
    stderr) and fails the test unless the case keeps the contract
    (:func:`judge`)."""
    capsys.readouterr()
    value = build_case(str(path), str(Path(path).parent / "out.cvc"), list(options))
    stderr = capsys.readouterr().err
    kind, detail, _ = judge(CallResult(exit=0, stderr=stderr, value=value))
    assert kind is None, f"[{kind}] {detail}"
    return value["build"], stderr


def _exit_status(main, argv: list) -> int:
    """``main(argv)``'s exit status, argparse's SystemExit included."""
    try:
        return int(main(argv))
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)


def _stored_floats_finite(path: str) -> bool:
    """Whether every float array of the .cvc at ``path`` holds finite values only."""
    from caveclod.api import load
    mesh = load(path)
    return all(bool(np.isfinite(a).all()) for a in mesh.arrays.values() if np.asarray(a).dtype.kind == "f")


_memory_limited = False


def _limit_memory() -> None:
    """Cap this worker's address space at :data:`WORKER_MEMORY` (once)."""
    global _memory_limited
    if _memory_limited:
        return
    import resource
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = WORKER_MEMORY if hard == resource.RLIM_INFINITY else min(WORKER_MEMORY, hard)
    if soft == resource.RLIM_INFINITY or soft > cap:
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    _memory_limited = True


# ------------------------------------------------------------------ judging and the loop


def judge(result: CallResult) -> tuple[str | None, str, str]:
    """(finding kind or None, detail, outcome label) of one :func:`build_case` call."""
    stderr = result.stderr.strip()
    if result.exit is None:
        return "hang", f"no answer within {CASE_TIMEOUT:g} s", "hang"
    if result.died:
        return "crash", f"the worker died with status {result.exit}", f"died {result.exit}"
    if not isinstance(result.value, dict):          # an exception escaped build_case
        return cli_contract(result.exit, result.stderr) or "traceback", stderr, "exception"
    code = result.value["build"]
    label = f"exit {code}"
    kind = cli_contract(code, result.stderr)
    if kind:
        return kind, stderr or f"exit {code} with nothing on stderr", label
    if "Warning" in stderr:
        return "wrong", "a warning on stderr: " + stderr, label
    if code == 2:
        lines = stderr.splitlines()
        if len(lines) != 1 or not lines[0].startswith("caveclod: error:"):
            return "wrong", "exit 2 without exactly one 'caveclod: error:' line: " + stderr, label
        return None, "", label
    if stderr:
        return "wrong", "exit 0 with output on stderr: " + stderr, label
    if result.value["inspect"] != 0:
        return "wrong", f"built, but caveclod inspect exits {result.value['inspect']}: {stderr}", label
    if not result.value["finite"]:
        return "wrong", "built a .cvc holding NaN or infinite floats", label
    return None, "", label


def fuzz_sources(budget: Budget, seed: int, report: FuzzReport, workdir: str | os.PathLike,
                 target: str = BUILD_TARGET, kinds: tuple[str, ...] | None = None) -> FuzzReport:
    """Build mutated inputs until ``budget`` runs out; counts and findings go to ``report``.

    Args:
        budget: cases and/or seconds.
        seed: makes the seeds, mutations and options (a case is reproduced by
            the same seed and its case number).
        report: ``cases``, units ``files``, outcomes ``"{kind} exit {code}"``,
            findings (their inputs are kept under ``workdir/findings``).
        workdir: scratch directory (created).
        target: the worker function each case calls, ``module:function``
            taking (input, output, options); tests point it at broken ones.
        kinds: only seeds of these kinds (see :func:`make_seeds`); None: all.
    """
    workdir = Path(workdir)
    casedir, keep = workdir / "case", workdir / "findings"
    rng = random.Random(seed)
    seeds = [s for s in make_seeds(np.random.default_rng(seed)) if kinds is None or s.kind in kinds]
    if not seeds:
        raise ValueError(f"no seed of the kinds {kinds}")
    with CliWorker() as worker:
        number = 0
        while budget.more():
            case = make_case(seeds[number % len(seeds)], rng, casedir)
            _warm_up(worker, target, seeds[0], workdir / "warmup")
            input_path = _write_case(casedir, case)
            result = worker.call(target, [str(input_path), str(casedir / "out.cvc"), case.options],
                                 timeout=CASE_TIMEOUT)
            kind, detail, label = judge(result)
            report.cases += 1
            report.count("files")
            report.outcome(f"{case.seed.kind} {label}")
            if kind:
                kept = _write_case(keep / f"case-{number}", case)
                report.add(kind, f"seed {seed} case {number}: {case.describe()} (input kept as {kept})", detail)
            number += 1
    report.seconds = budget.elapsed()
    return report


def _warm_up(worker: CliWorker, target: str, seed: Seed, directory: Path) -> None:
    """Start a fresh worker with one unmutated build (imports and kernel loading
    take far longer than a case may); a no-op while the worker runs."""
    if worker.proc is not None and worker.proc.poll() is None:
        return
    path = _write_case(directory, Case(seed, seed.data, [], seed.companions, []))
    worker.call(target, [str(path), str(directory / "out.cvc"), []], timeout=WARMUP_TIMEOUT)


def _write_case(directory: Path, case: Case) -> Path:
    """Write the case's input and companions into a clean ``directory``; returns the input's path."""
    shutil.rmtree(directory, ignore_errors=True)
    directory.mkdir(parents=True)
    for name, content in case.companions.items():
        (directory / name).write_bytes(content)
    path = directory / case.seed.name
    path.write_bytes(case.data)
    return path


def main(argv: list[str] | None = None) -> int:
    """Run the fuzzer from the command line; prints the report as JSON."""
    p = fuzzer_arguments("fuzz caveclod build with mutated mesh files and heightfields")
    p.add_argument("--workdir", default="/tmp/caveclod-fuzzsources")
    p.add_argument("--kinds", help="comma-separated seed kinds (default: all)")
    args = p.parse_args(argv)
    report = FuzzReport("sources")
    kinds = tuple(args.kinds.split(",")) if args.kinds else None
    run_reported(report, fuzz_sources, Budget(cases=args.cases, seconds=args.seconds), args.seed, report,
                 args.workdir, kinds=kinds)
    return finish(report, "files", args.out)


if __name__ == "__main__":
    sys.exit(main())
