"""``--stride K``: a heightfield too large to build here, built from one sample in K a side.

The strided mesh must be the full one's samples, not a resampling: every
position it has is a position of the full-resolution mesh (the same x, y and
height), its south-west sample where the full one's is (so a georeferenced
file's origin holds), its material classes those of the cells it keeps, and
the memory check must name a stride that then fits.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from hypothesis import given, settings
from hypothesis import strategies as st

import caveclod
from caveclod.api import to_source
from caveclod.builder import memory
from caveclod.builder.memory import PEAK_BYTES_PER_TRIANGLE, check_build_memory
from caveclod.builder.terrain import every_kth_sample
from caveclod.cli import main
from caveclod.errors import InputError


def _rough(rows, cols, seed=5) -> np.ndarray:
    """Rough relief with a no-data hole: heights every one distinct."""
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(rows, cols)).cumsum(0).cumsum(1) + rng.permutation(rows * cols).reshape(rows, cols) * 1e-3
    h[rows // 3:rows // 3 + 4, cols // 2:cols // 2 + 3] = np.nan
    return h


@settings(max_examples=200, deadline=None)
@given(rows=st.integers(2, 40), cols=st.integers(2, 40), k=st.integers(1, 12), north_first=st.booleans(),
       per_cell=st.booleans())
def test_every_kth_sample_keeps_the_south_west_sample_and_a_regular_grid(rows, cols, k, north_first, per_cell):
    h = np.arange(rows * cols, dtype=np.float64).reshape(rows, cols)
    classes = (np.arange((rows - 1) * (cols - 1)).reshape(rows - 1, cols - 1) if per_cell
               else np.arange(rows * cols).reshape(rows, cols) + 1000)
    kept_rows, kept_cols = (rows - 1) // k + 1, (cols - 1) // k + 1
    if kept_rows < 2 or kept_cols < 2:
        if k > 1:
            with pytest.raises(InputError, match="fewer than 2 a side"):
                every_kth_sample(h, k, classes, north_first)
        return
    out, m = every_kth_sample(h, k, classes, north_first)
    assert out.shape == (kept_rows, kept_cols)
    south = rows - 1 if north_first else 0
    south_out = kept_rows - 1 if north_first else 0
    assert out[south_out, 0] == h[south, 0]                  # the south-west sample stays
    # The slow way: raster row of each kept row, counted from the south edge.
    for i in range(kept_rows):
        r = (south - (south_out - i) * k) if north_first else i * k
        for j in range(kept_cols):
            assert out[i, j] == h[r, j * k]
            if not per_cell:
                assert m[i, j] == classes[r, j * k]
            elif i < kept_rows - 1 and j < kept_cols - 1:
                assert m[i, j] == classes[r, j * k]          # the original cell at its first corner
    if per_cell:
        assert m.shape == (kept_rows - 1, kept_cols - 1)


def test_a_strided_heightfield_is_the_full_ones_samples(tmp_path):
    """Every position of the strided mesh is one of the full mesh's, at the same place; the
    hole stays a hole; cells are k times as wide; the note says what was done."""
    h = _rough(61, 83)
    path = tmp_path / "dem.npy"
    np.save(path, h)
    full = to_source(str(path), cell_size=2.5)
    for k in (2, 3, 5):
        part = to_source(str(path), cell_size=2.5, stride=k)
        have = {tuple(p) for p in full.positions.tolist()}
        assert all(tuple(p) in have for p in part.positions.tolist())
        assert part.positions[:, :2].min(axis=0).tolist() == [0.0, 0.0]
        assert part.positions[:, 0].max() == ((83 - 1) // k) * k * 2.5
        assert part.positions[:, 1].max() == ((61 - 1) // k) * k * 2.5
        assert not np.isnan(part.positions).any()
        assert any(n.startswith(f"--stride {k}: one sample in {k} a side of the 61 x 83 grid") and
                   f"cells of {2.5 * k:g}" in n for n in part.notes)
        assert len(part.faces) < len(full.faces) / (k * k) * 1.2


def test_an_array_is_strided_like_its_file(tmp_path):
    h = _rough(40, 50)
    np.save(tmp_path / "dem.npy", h)
    a, f = to_source(h, stride=3), to_source(str(tmp_path / "dem.npy"), stride=3)
    assert np.array_equal(a.positions, f.positions) and np.array_equal(a.faces, f.faces)


def test_a_georeferenced_file_keeps_its_origin_and_scales_its_cells(tmp_path):
    """A projected GeoTIFF: the south-west sample is where the file says, strided or not."""
    h = _rough(31, 45).astype(np.float32)
    h[np.isnan(h)] = -9999.0
    path = tmp_path / "dem.tif"
    tifffile.imwrite(path, h, extratags=[(33550, 12, 3, (25.0, 30.0, 0.0)),
                                         (33922, 12, 6, (0.0, 0.0, 0.0, 500000.0, 4100000.0, 0.0)),
                                         (42113, 2, 0, "-9999")])
    full, part = to_source(str(path)), to_source(str(path), stride=4)
    assert part.origin == full.origin and full.origin is not None
    assert part.positions[:, 0].max() == ((45 - 1) // 4) * 4 * 25.0
    assert part.positions[:, 1].max() == ((31 - 1) // 4) * 4 * 30.0
    have = {tuple(p) for p in full.positions.tolist()}
    assert all(tuple(p) in have for p in part.positions.tolist())


def test_a_material_map_is_strided_with_its_cells():
    h = _rough(33, 33)
    h[~np.isfinite(h)] = 0.0
    classes = np.zeros((32, 32), np.int64)
    classes[:, 16:] = 1                      # east half another material
    part = to_source(h, materials=classes, stride=4)
    x = part.positions[:, 0][part.vertex_position]
    for f, material in zip(part.faces, part.face_material):
        centre = x[f].mean()
        assert material == (1 if centre > 16 else 0)    # cell j spans x 4j..4j+4 and takes cell 4j's class


def test_the_memory_check_names_a_stride_that_fits():
    with pytest.raises(InputError) as info:
        check_build_memory(199_960_002, "dem.npy", available=22 << 30, grid_shape=(10_000, 10_000))
    text = str(info.value)
    assert "with --stride 2 (49,980,002 triangles, cells 2 times as wide)" in text
    assert 49_980_002 * PEAK_BYTES_PER_TRIANGLE <= 22 << 30
    with pytest.raises(InputError) as info:           # at stride 2 already: the next that fits
        check_build_memory(49_980_002, "dem.npy", available=5 << 30, grid_shape=(10_000, 10_000), stride=2)
    assert "--stride 4 (12,490,002 triangles" in str(info.value)
    assert 12_490_002 * PEAK_BYTES_PER_TRIANGLE <= 5 << 30 < 2 * 3333 ** 2 * PEAK_BYTES_PER_TRIANGLE   # 3 would not
    with pytest.raises(InputError) as info:           # meshes: no stride to name
        check_build_memory(199_960_002, "scan.ply", available=22 << 30)
    assert "--stride" not in str(info.value)


def test_the_cli_builds_with_the_stride_the_refusal_named(tmp_path, monkeypatch, capsys):
    """Refused with a stride named, then built with it: the file holds the strided grid."""
    h = _rough(121, 121)
    path = tmp_path / "dem.npy"
    np.save(path, h)
    out = tmp_path / "dem.cvc"
    full_triangles = 2 * 120 * 120
    monkeypatch.setattr(memory, "available_bytes", lambda root="/": full_triangles * PEAK_BYTES_PER_TRIANGLE // 3)
    assert main(["build", str(path), "-o", str(out), "--quiet"]) == 2 and not out.exists()
    err = capsys.readouterr().err
    assert "--stride 2 (" in err
    assert main(["build", str(path), "-o", str(out), "--quiet", "--stride", "2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["input_triangles"] < full_triangles / 4 + 1 and report["input_triangles"] > full_triangles / 5
    assert any("--stride 2" in n for n in report["notes"])
    assert caveclod.load(out).n_faces == report["input_triangles"]


@pytest.mark.parametrize("source", ["default", "mesh"])
def test_a_stride_is_refused_where_there_is_no_grid(tmp_path, source):
    if source == "mesh":
        import trimesh
        path = tmp_path / "ball.ply"
        trimesh.creation.icosphere(subdivisions=1).export(path)
        source = str(path)
    with pytest.raises(InputError, match="--stride"):
        caveclod.build(source, stride=2, size=16, packed=False)


@pytest.mark.parametrize("bad", [0, -2, 1.5, True, "2", 5000])
def test_a_bad_stride_is_refused(bad):
    with pytest.raises(InputError, match="--stride must be a whole number"):
        to_source(np.zeros((8, 8)), stride=bad)


def test_a_strided_npy_is_read_without_the_rest_of_it(tmp_path):
    """A .npy is memory-mapped and only the kept samples copied out: numpy's allocations
    (which tracemalloc sees; the mapped file's pages it does not) stay far below the file's
    128 MB (read whole, its float64 copy alone would be 128 MB)."""
    import tracemalloc
    h = np.random.default_rng(2).normal(size=(4001, 4001)).astype(np.float64)
    path = tmp_path / "dem.npy"
    np.save(path, h)
    del h
    np.save(tmp_path / "small.npy", _rough(40, 40))
    to_source(str(tmp_path / "small.npy"), stride=2)          # imports and first calls, not measured
    tracemalloc.start()
    try:
        part = to_source(str(path), stride=16)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(part.faces) == 2 * 250 * 250
    assert peak < 32 << 20, f"{peak / 2**20:.1f} MiB allocated reading a 128 MB file at one sample in 16"


@pytest.mark.parametrize("kind", ["npy", "tif", "hgt", "asc", "png"])
def test_a_grid_too_large_is_refused_before_its_samples_are_read(tmp_path, monkeypatch, kind):
    """Every heightfield format says its shape in its header: the refusal (naming a stride)
    comes before the samples are read, as a grid too large to read would otherwise be."""
    from PIL import Image
    from caveclod.builder import terrain
    side = 121
    h = (np.arange(side * side).reshape(side, side) % 500 + 100).astype(np.int16)
    path = tmp_path / f"dem.{kind}"
    if kind == "npy":
        np.save(path, h)
    elif kind == "tif":
        tifffile.imwrite(path, h)
    elif kind == "hgt":
        h.astype(">i2").tofile(path)
    elif kind == "asc":
        path.write_text(f"ncols {side}\nnrows {side}\nxllcorner 0\nyllcorner 0\ncellsize 30\n"
                        + "\n".join(" ".join(map(str, row)) for row in h) + "\n")
    else:
        Image.fromarray(h.astype(np.uint16)).save(path)
    assert terrain.heightfield_shape(path) == (side, side)
    read = []
    real = terrain._read_grid
    monkeypatch.setattr(terrain, "_read_grid", lambda *a, **k: read.append(1) or real(*a, **k))
    from caveclod.builder import rasterwindow
    real_window = rasterwindow.open_window           # a strided TIFF or ASCII grid is read by window instead

    def window(*a):
        found = real_window(*a)
        if found is not None:
            read.append(1)
        return found
    monkeypatch.setattr(rasterwindow, "open_window", window)
    monkeypatch.setattr(memory, "available_bytes",
                        lambda root="/": 2 * 120 * 120 * PEAK_BYTES_PER_TRIANGLE // 3)
    with pytest.raises(InputError, match=r"--stride 2 \("):
        caveclod.build(str(path), packed=False)
    assert read == []
    assert caveclod.build(str(path), packed=False, stride=2).info["input_triangles"] == 2 * 60 * 60
    assert read == [1]


@pytest.mark.parametrize("stride", ["1", "2"])
def test_an_npy_header_claiming_an_overflowing_shape_is_one_line(tmp_path, capsys, stride):
    """A source fuzzer's find once .npy files were memory-mapped: a header claiming 2**32 x 2**32
    samples was refused (numpy: "array is too big"), but numpy also printed an overflow warning
    on stderr beside the one-line error."""
    from fuzzsources import build_here
    path = tmp_path / "dem.npy"
    np.save(path, np.zeros((4, 4)))
    data = path.read_bytes()
    path.write_bytes(data.replace(b"'shape': (4, 4)", b"'shape': (4294967296, 4294967296)"))
    assert b"4294967296" in path.read_bytes()
    code, err = build_here(capsys, path, f"--stride={stride}")
    assert code == 2 and "cannot read heightfield" in err and "check that the file is intact" in err, err


# -- a TIFF read by window -----------------------------------------------------------------

@settings(max_examples=120, deadline=None)
@given(rows=st.integers(1, 70), cols=st.integers(1, 70), k=st.integers(1, 9), r0=st.integers(0, 8),
       layout=st.sampled_from([{"rowsperstrip": 1}, {"rowsperstrip": 7}, {"rowsperstrip": 500},
                               {"tile": (16, 16)}, {"tile": (32, 48), "compression": "zlib"},
                               {"rowsperstrip": 5, "compression": "zlib", "byteorder": ">"}]),
       dtype=st.sampled_from(["float32", "int16", "uint16", "float64"]))
def test_a_tiff_window_reads_what_the_whole_file_holds(tmp_path_factory, rows, cols, k, r0, layout, dtype):
    """Strips or tiles (padded at the edges), deflate, big-endian: every slice a window reads
    is the whole file's slice, from only the strips or tiles that slice touches."""
    from caveclod.builder.rasterwindow import open_window
    a = (np.random.default_rng(rows * 100 + cols).normal(size=(rows, cols)) * 1000).astype(dtype)
    path = tmp_path_factory.mktemp("win") / "dem.tif"
    tifffile.imwrite(path, a, **layout)
    w = open_window(str(path))
    assert w is not None and w.shape == a.shape and w.dtype == a.dtype.newbyteorder("=")
    got = w[r0::k, ::k]
    assert got.dtype == w.dtype and np.array_equal(got, a[r0::k, ::k])
    rows_per = layout.get("tile", (min(layout.get("rowsperstrip", rows), rows),))[0]
    assert w.chunks_read <= (len(np.unique(np.arange(r0, rows, k) // rows_per)) *
                             (-(-cols // layout["tile"][1]) if "tile" in layout else 1))


def test_a_strided_tiff_is_built_from_its_kept_samples_alone(tmp_path):
    """``--stride`` on a GeoTIFF reads by window: the same mesh as the .npy of the same samples,
    the same no-data holes (GDAL_NODATA), and numpy's allocations (tracemalloc) far below the
    file's 64 MB, which reading it whole allocates (tested: the whole-file reader exceeds it)."""
    import tracemalloc
    from caveclod.builder import terrain
    h = _rough(61, 83).astype(np.float32)
    h[np.isnan(h)] = -9999.0
    tifffile.imwrite(tmp_path / "dem.tif", h, rowsperstrip=1, extratags=[(42113, 2, 0, "-9999", True)])
    g = h.astype(np.float64)
    g[g == -9999.0] = np.nan
    np.save(tmp_path / "dem.npy", g)
    for k in (2, 3, 7):
        a, b = to_source(str(tmp_path / "dem.tif"), stride=k), to_source(str(tmp_path / "dem.npy"), stride=k)
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces)
    big = np.random.default_rng(3).normal(size=(4001, 4001)).astype(np.float32)
    tifffile.imwrite(tmp_path / "big.tif", big, rowsperstrip=1)
    del big
    to_source(str(tmp_path / "dem.tif"), stride=2)          # imports and first calls, not measured
    peaks = {}
    for name, window in (("window", True), ("whole", False)):
        tracemalloc.start()
        try:
            if window:
                part = to_source(str(tmp_path / "big.tif"), stride=16)
            else:
                terrain.read_heightfield(tmp_path / "big.tif")
            peaks[name] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert len(part.faces) == 2 * 250 * 250
    assert peaks["window"] < 24 << 20 < peaks["whole"], {k: f"{v / 2**20:.1f} MiB" for k, v in peaks.items()}


def test_a_tiff_that_cannot_be_read_by_window_is_read_whole(tmp_path):
    """LZW (tifffile needs imagecodecs for it; Pillow's libtiff reads it whole), several bands
    (refused by the whole-file reader, as before), a missing strip (refused, as before)."""
    from PIL import Image
    from caveclod.builder.rasterwindow import open_window
    h = (_rough(40, 50) * 10).astype(np.float32)
    h[np.isnan(h)] = 0.0
    Image.fromarray(h, mode="F").save(tmp_path / "lzw.tif", compression="tiff_lzw")
    np.save(tmp_path / "dem.npy", h.astype(np.float64))
    try:
        import imagecodecs  # noqa: F401
    except ImportError:
        assert open_window(str(tmp_path / "lzw.tif")) is None
    a, b = to_source(str(tmp_path / "lzw.tif"), stride=3), to_source(str(tmp_path / "dem.npy"), stride=3)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces)
    tifffile.imwrite(tmp_path / "rgb.tif", np.zeros((20, 20, 3), np.uint8), photometric="rgb")
    tifffile.imwrite(tmp_path / "stack.tif", np.zeros((2, 20, 20), np.float32))         # two bands as pages
    for name in ("rgb.tif", "stack.tif"):
        assert open_window(str(tmp_path / name)) is None
        with pytest.raises(InputError, match="single-channel 2-D grid"):
            to_source(str(tmp_path / name), stride=2)


def test_a_cloud_optimized_geotiffs_full_resolution_is_read_by_window(tmp_path):
    """A cloud-optimized GeoTIFF: tiles, deflate, overviews as further pages; the window reads
    the full resolution, as the whole-file reader does, from its tiles alone."""
    from caveclod.builder.rasterwindow import open_window
    h = _rough(100, 90).astype(np.float32)
    with tifffile.TiffWriter(tmp_path / "cog.tif") as tif:
        tif.write(h, tile=(32, 32), compression="zlib")
        tif.write(np.ascontiguousarray(h[::2, ::2]), tile=(32, 32), compression="zlib", subfiletype=1)
    w = open_window(str(tmp_path / "cog.tif"))
    assert w is not None and w.shape == h.shape
    np.save(tmp_path / "dem.npy", h.astype(np.float64))
    a, b = to_source(str(tmp_path / "cog.tif"), stride=3), to_source(str(tmp_path / "dem.npy"), stride=3)
    assert np.array_equal(a.positions, b.positions, equal_nan=True) and np.array_equal(a.faces, b.faces)


def test_a_tiff_damaged_past_its_first_strip_is_refused_in_one_line(tmp_path):
    """The window decodes its first strip when it opens; one damaged further on (here a deflate
    strip overwritten, and a file cut short) is found while reading, and refused as the whole-file
    reader refuses a damaged file."""
    h = _rough(60, 40).astype(np.float32)
    tifffile.imwrite(tmp_path / "dem.tif", h, rowsperstrip=4, compression="zlib")
    data = bytearray((tmp_path / "dem.tif").read_bytes())
    with tifffile.TiffFile(tmp_path / "dem.tif") as tif:
        at = tif.pages[0].dataoffsets[-2]
    data[at:at + 8] = b"\xff" * 8
    (tmp_path / "bad.tif").write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"cannot read heightfield .*bad\.tif \(.*\); check that the file is intact"):
        to_source(str(tmp_path / "bad.tif"), stride=2)
    tifffile.imwrite(tmp_path / "plain.tif", h, rowsperstrip=4)
    (tmp_path / "short.tif").write_bytes((tmp_path / "plain.tif").read_bytes()[:-100])
    with pytest.raises(InputError, match="check that the file is intact") as err:
        to_source(str(tmp_path / "short.tif"), stride=2)
    assert "\n" not in str(err.value)


# -- an ESRI ASCII grid parsed a block at a time ------------------------------------------------

@settings(max_examples=150, deadline=None)
@given(rows=st.integers(2, 25), cols=st.integers(2, 25), k=st.integers(1, 6), r0=st.integers(0, 5),
       per_line=st.integers(1, 40), block=st.integers(1, 120), crlf=st.booleans(), seed=st.integers(0, 99))
def test_an_ascii_grid_read_in_blocks_is_its_samples(tmp_path_factory, rows, cols, k, r0, per_line, block, crlf,
                                                     seed):
    """Blocks of any size (numbers cut across them), lines wrapped anywhere, CRLF: every slice is
    the grid's slice, and the whole file reads as it was written."""
    from caveclod.builder import rasterwindow
    rng = np.random.default_rng(seed)
    h = np.round(rng.normal(size=(rows, cols)) * 10 ** rng.integers(0, 5), int(rng.integers(0, 4)))
    h[rng.random(h.shape) < 0.1] = -9999
    tokens = [repr(float(v)) for v in h.ravel()]
    nl = "\r\n" if crlf else "\n"
    body = nl.join(" ".join(tokens[i:i + per_line]) for i in range(0, len(tokens), per_line))
    path = tmp_path_factory.mktemp("asc") / "dem.asc"
    path.write_bytes(f"ncols {cols}{nl}nrows {rows}{nl}xllcorner 0{nl}yllcorner 0{nl}cellsize 2{nl}"
                     f"NODATA_value -9999{nl}{body}{nl}".encode())
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rasterwindow, "ASCII_BLOCK", block)
        w = rasterwindow.AsciiGridWindow(str(path))
        assert w.shape == (rows, cols)
        assert np.array_equal(w[r0::k, ::k], h[r0::k, ::k])
        assert np.array_equal(np.asarray(w), h)


def test_a_strided_ascii_grid_never_holds_its_text(tmp_path):
    """A 4,000 x 4,000 ASCII grid (137 MB of text) at one sample in 8: reading it allocates
    (tracemalloc: numpy's and Python's) under a quarter of the text, which reading the file at
    once held whole, beside every sample as float64 (128 MB) and their concatenation (128 MB more)."""
    import tracemalloc
    from caveclod.builder import terrain
    rows = cols = 4000
    lines = [" ".join(f"{v:.3f}" for v in np.random.default_rng(r).uniform(1000, 2000, cols)).encode()
             for r in range(7)]
    path = tmp_path / "dem.asc"
    with open(path, "wb") as f:
        f.write(f"ncols {cols}\nnrows {rows}\nxllcorner 0\nyllcorner 0\ncellsize 1\n".encode())
        f.write(b"\n".join(lines[r % 7] for r in range(rows)) + b"\n")
    text = path.stat().st_size
    tracemalloc.start()
    try:
        kept, _ = every_kth_sample(terrain.read_heightfield(path, window=True), 8)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert kept.shape == (500, 500)
    assert np.array_equal(kept[-1], np.array(lines[(rows - 1) % 7].split(), float)[::8])     # the southernmost row
    assert peak < text / 4, f"{peak / 2**20:.1f} MiB allocated reading {text / 2**20:.0f} MiB of text at one in 8"
    assert to_source(str(path), stride=8).positions.shape[0] == 500 * 500
