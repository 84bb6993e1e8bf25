"""Heightfield triangulation, material seams, loaders and the default terrain."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from caveclod.builder import terrain
from caveclod.errors import InputError
from caveclod.builder.builtin import LAKE_LEVEL, TERRAIN_EXTENT, default_heights, default_terrain
from caveclod.builder.landcover import MATERIALS, classify_terrain, coherent_classes
from caveclod.builder.terrain import TILE_SIZES, heightfield_to_source, load_heightfield, load_material_map
from fuzzsources import build_here as build_cli     # a build as the source fuzzer runs it, in-process

ROCK = MATERIALS.index("rock")
WATER = MATERIALS.index("water")


# ---------------------------------------------------------------- helpers


def face_normals(source):
    """(p, 3) unit normals of the faces."""
    p = source.positions[source.face_positions]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1)[:, None]


def interior_dihedrals(source):
    """Angle (degrees) between the normals of the two faces of each interior edge."""
    fp = source.face_positions
    edges = np.concatenate([fp[:, [0, 1]], fp[:, [1, 2]], fp[:, [2, 0]]])
    face = np.tile(np.arange(len(fp)), 3)
    key = edges.min(axis=1) * len(source.positions) + edges.max(axis=1)
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    shared = key[1:] == key[:-1]
    assert np.bincount(np.unique(key, return_counts=True)[1]).size <= 3  # manifold: <= 2 faces per edge
    n = face_normals(source)
    cos = np.einsum("ij,ij->i", n[face[:-1][shared]], n[face[1:][shared]])
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def vertices_per_position(source):
    return np.bincount(source.vertex_position, minlength=len(source.positions))


def sample_of_position(source, cell_size, cols):
    """Flat sample id (row * cols + col) of every position."""
    col = np.rint(source.positions[:, 0] / cell_size).astype(np.int64)
    row = np.rint(source.positions[:, 1] / cell_size).astype(np.int64)
    return row * cols + col


def materials_around_samples(cell_class, kept):
    """(rows, cols) number of distinct classes among the kept cells around each sample."""
    rows, cols = cell_class.shape[0] + 1, cell_class.shape[1] + 1
    seen = [np.zeros((rows, cols), bool) for _ in range(int(cell_class.max()) + 1)]
    for m, grid in enumerate(seen):
        cells = kept & (cell_class == m)
        for dr in (0, 1):
            for dc in (0, 1):
                grid[dr:rows - 1 + dr, dc:cols - 1 + dc] |= cells
    return sum(g.astype(int) for g in seen)


def check_dtypes(source):
    assert source.positions.dtype == np.float64 and source.positions.shape[1] == 3
    assert source.faces.dtype == np.int32          # half of int64: a terrain's faces live all build
    assert source.face_material.dtype == np.int32
    assert source.vertex_position.dtype == np.int64
    assert source.vertex_uv.dtype == np.float32
    assert source.vertex_normal is None and source.vertex_color is None


def assert_one_line_input_error(excinfo):
    message = str(excinfo.value)
    assert message and "\n" not in message


rng = np.random.default_rng(0)


# ---------------------------------------------------------------- triangulation


@pytest.mark.parametrize("shape", [(2, 2), (2, 7), (5, 3), (17, 11)])
def test_two_triangles_per_cell(shape):
    heights = rng.normal(size=shape)
    source = heightfield_to_source(heights, cell_size=2.5, z_scale=3.0)
    rows, cols = shape
    assert len(source.faces) == 2 * (rows - 1) * (cols - 1)
    assert len(source.positions) == rows * cols
    check_dtypes(source)


def test_positions_are_the_scaled_grid():
    heights = rng.normal(size=(4, 6))
    source = heightfield_to_source(heights, cell_size=2.0, z_scale=0.5,
                                   materials=np.zeros((3, 5), int))
    sample = sample_of_position(source, 2.0, 6)
    row, col = np.divmod(sample, 6)
    np.testing.assert_array_equal(source.positions[:, 0], col * 2.0)
    np.testing.assert_array_equal(source.positions[:, 1], row * 2.0)
    np.testing.assert_array_equal(source.positions[:, 2], heights.ravel()[sample] * 0.5)
    assert sorted(sample) == list(range(24))


def test_faces_are_counter_clockwise_from_above():
    heights = rng.normal(scale=5.0, size=(20, 30))  # rough, but never overhanging
    source = heightfield_to_source(heights)
    assert (face_normals(source)[:, 2] > 0).all()


def test_both_triangles_of_a_cell_share_its_material():
    classes = rng.integers(0, 4, size=(6, 8))
    source = heightfield_to_source(rng.normal(size=(7, 9)), materials=classes)
    fm = source.face_material
    assert (fm[0::2] == fm[1::2]).all()
    names = np.array(source.materials)[fm[0::2]]
    np.testing.assert_array_equal(names, np.array(MATERIALS)[classes.ravel()])


# ---------------------------------------------------------------- materials and seams


def assert_seams_where_materials_meet(source, cell_class, kept, cell_size):
    """Every position has one vertex per distinct material of its kept cells."""
    rows, cols = cell_class.shape[0] + 1, cell_class.shape[1] + 1
    around = materials_around_samples(cell_class, kept).ravel()
    sample = sample_of_position(source, cell_size, cols)
    np.testing.assert_array_equal(vertices_per_position(source), around[sample])
    # ... and the vertices of a position all differ in UV: a real texture seam.
    uv_keys = {(int(p), tuple(uv)) for p, uv in zip(source.vertex_position, source.vertex_uv.tolist())}
    assert len(uv_keys) == len(source.vertex_position)


def test_uv_seams_exactly_where_materials_meet():
    classes = rng.integers(0, 4, size=(9, 12))
    classes[:4, :5] = 1  # a uniform patch whose inner samples must not split
    source = heightfield_to_source(rng.normal(size=(10, 13)), cell_size=3.0, materials=classes)
    assert_seams_where_materials_meet(source, classes, np.ones_like(classes, bool), 3.0)
    counts = vertices_per_position(source)
    assert counts.max() >= 2 and (counts == 1).any()


def test_uvs_tile_each_material_at_its_own_scale():
    classes = np.array([[0, 1, 2, 3], [3, 2, 1, 0]])
    source = heightfield_to_source(np.zeros((3, 5)), cell_size=7.0, materials=classes)
    sizes = [TILE_SIZES[name] for name in source.materials]
    assert len(set(sizes)) == len(sizes)
    corners = source.faces
    p = source.positions[source.vertex_position[corners]]
    uv = source.vertex_uv[corners].astype(np.float64)
    tile = np.array(sizes)[source.face_material][:, None]
    for a, b in ((0, 1), (1, 2)):
        np.testing.assert_allclose(uv[:, b] - uv[:, a], (p[:, b, :2] - p[:, a, :2]) / tile, atol=1e-5)


def test_a_map_of_thousands_of_classes_builds_with_usable_uvs():
    """A tile of 11 * 1.5 ** id units made a 64-class map's UVs near 0 for most vertices, and past
    1,750 classes the sizes reached infinity, where the build never ended."""
    from caveclod.builder.terrain import _tile_sizes
    sizes = _tile_sizes([f"class {k}" for k in range(65535)] + ["grass"] * 3)
    assert len(set(sizes.tolist())) == len(sizes) and np.isfinite(sizes).all()
    assert 8.0 <= sizes.min() and sizes.max() <= 88.0
    classes = (np.arange(48 * 48).reshape(48, 48) * 7) % 2000
    source = heightfield_to_source(rng.normal(size=(49, 49)), cell_size=1.0, materials=classes)
    assert len(source.materials) == 2000
    assert_seams_where_materials_meet(source, classes, np.ones_like(classes, bool), 1.0)
    uv = np.abs(source.vertex_uv).max(axis=1)
    assert np.count_nonzero(uv < 1e-4) <= 1, "UVs collapsed to the corner"


def test_repeated_or_unknown_names_still_make_seams():
    classes = rng.integers(0, 5, size=(7, 7))
    names = ["grass", "grass", "lava", "mud", "grass"]
    source = heightfield_to_source(rng.normal(size=(8, 8)), materials=classes, material_names=names)
    assert source.materials == names
    assert_seams_where_materials_meet(source, classes, np.ones_like(classes, bool), 1.0)


def test_per_sample_map_uses_the_lower_left_sample():
    per_sample = rng.integers(0, 3, size=(6, 5))
    source = heightfield_to_source(rng.normal(size=(6, 5)), materials=per_sample)
    names = np.array(source.materials)[source.face_material[0::2]]
    np.testing.assert_array_equal(names, np.array(MATERIALS)[per_sample[:-1, :-1].ravel()])


def test_material_ids_are_compacted_to_the_classes_present():
    classes = np.where(rng.random((5, 5)) < 0.5, 2, 7)
    names = [f"m{i}" for i in range(8)]
    source = heightfield_to_source(rng.normal(size=(6, 6)), materials=classes, material_names=names)
    assert source.materials == ["m2", "m7"]
    assert set(source.face_material.tolist()) == {0, 1}
    expected = np.where(classes.ravel() == 2, 0, 1)
    np.testing.assert_array_equal(source.face_material[0::2], expected)


def test_default_names_beyond_the_four_classes():
    classes = np.array([[1, 5]])
    source = heightfield_to_source(np.zeros((2, 3)), materials=classes)
    assert source.materials == ["grass", "material 5"]


def test_float_map_with_whole_numbers_is_accepted():
    source = heightfield_to_source(np.zeros((3, 3)), materials=np.array([[0.0, 2.0], [2.0, 0.0]]))
    assert source.materials == ["water", "rock"]


@settings(max_examples=60, deadline=None)
@given(
    heights=hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=2, max_side=9),
                       elements=st.one_of(st.floats(-100, 100), st.just(np.nan))),
    data=st.data(),
)
def test_seams_and_holes_on_random_grids(heights, data):
    rows, cols = heights.shape
    classes = data.draw(hnp.arrays(np.int64, (rows - 1, cols - 1), elements=st.integers(0, 5)))
    finite = np.isfinite(heights)
    kept = finite[:-1, :-1] & finite[1:, :-1] & finite[:-1, 1:] & finite[1:, 1:]
    if not kept.any():
        with pytest.raises(InputError):
            heightfield_to_source(heights, materials=classes)
        return
    source = heightfield_to_source(heights, cell_size=1.5, materials=classes)
    check_dtypes(source)
    assert len(source.faces) == 2 * kept.sum()
    assert len(source.materials) == len(np.unique(classes[kept]))
    assert_seams_where_materials_meet(source, np.where(kept, classes, 0), kept, 1.5)
    assert (face_normals(source)[:, 2] > 0).all()


# ---------------------------------------------------------------- NaN holes


def test_cells_touching_nan_are_dropped():
    heights = rng.normal(size=(5, 5))
    heights[2, 2] = np.nan   # an inner sample: its 4 cells go
    heights[0, 4] = np.nan   # a corner sample: its 1 cell goes
    source = heightfield_to_source(heights)
    assert len(source.faces) == 2 * (16 - 5)
    assert len(source.positions) == 25 - 2  # the NaN samples had no cell left
    assert np.isfinite(source.positions).all()
    assert "dropped 5 cells touching NaN samples" in source.notes


def test_no_note_without_holes():
    assert heightfield_to_source(np.zeros((3, 3))).notes == []


def test_unused_positions_are_removed():
    heights = np.zeros((4, 4))
    heights[1, :] = np.nan  # cuts the first cell row off; row 0 samples lose every cell
    source = heightfield_to_source(heights)
    assert len(source.faces) == 2 * 3 and len(source.positions) == 8
    assert (source.positions[:, 1] >= 2.0).all()


def test_negative_ids_only_matter_on_kept_cells():
    heights = np.zeros((3, 3))
    heights[0, 0] = np.nan
    classes = np.array([[-1, 1], [1, 1]])  # -1 marks the hole
    assert len(heightfield_to_source(heights, materials=classes).faces) == 6
    with pytest.raises(InputError) as excinfo:
        heightfield_to_source(np.zeros((3, 3)), materials=classes)
    assert_one_line_input_error(excinfo)


# ---------------------------------------------------------------- bad inputs


@pytest.mark.parametrize("heights, kwargs, words", [
    (np.full((4, 4), np.nan), {}, "NaN"),
    (np.array([[np.nan, 1.0, np.nan], [1.0, np.nan, 1.0]]), {}, "finite"),
    (np.zeros(5), {}, "2-D"),
    (np.zeros((2, 3, 3)), {}, "2-D"),
    (np.zeros((1, 9)), {}, "2x2"),
    (np.zeros((9, 1)), {}, "2x2"),
    (np.array([[0.0, np.inf], [0.0, 0.0]]), {}, "infinity"),
    (np.array([[0.0, -np.inf], [0.0, 0.0]]), {}, "infinity"),
    (np.array([["a", "b"], ["c", "d"]]), {}, "numbers"),
    (np.zeros((3, 3)), {"cell_size": 0.0}, "cell_size"),
    (np.zeros((3, 3)), {"cell_size": -1.0}, "cell_size"),
    (np.zeros((3, 3)), {"cell_size": np.nan}, "cell_size"),
    (np.zeros((3, 3)), {"cell_size": np.inf}, "cell_size"),
    (np.zeros((3, 3)), {"cell_size": "big"}, "cell_size"),
    (np.zeros((3, 3)), {"z_scale": 0.0}, "z_scale"),
    (np.zeros((3, 3)), {"z_scale": -2.0}, "z_scale"),
    (np.zeros((3, 3)), {"z_scale": np.inf}, "z_scale"),
    (np.zeros((3, 3)), {"materials": np.zeros((3, 2), int)}, "shape"),
    (np.zeros((3, 3)), {"materials": np.zeros((4, 4), int)}, "shape"),
    (np.zeros((3, 3)), {"materials": np.zeros(4, int)}, "2-D"),
    (np.zeros((3, 3)), {"materials": np.array([[0, 1], [-3, 0]])}, "negative"),
    (np.zeros((3, 3)), {"materials": np.array([[0.5, 1], [1, 0]])}, "integer"),
    (np.zeros((3, 3)), {"materials": np.array([["a", "b"], ["c", "d"]])}, "integer"),
    (np.zeros((3, 3)), {"materials": np.array([[0, 4], [1, 0]]), "material_names": ["a", "b"]}, "names"),
    (np.zeros((3, 3)), {"material_names": ["only", "three", "names"]}, "names"),
])
def test_bad_input_raises_one_line_input_error(heights, kwargs, words):
    with pytest.raises(InputError) as excinfo:
        heightfield_to_source(heights, **kwargs)
    assert_one_line_input_error(excinfo)
    assert words.lower() in str(excinfo.value).lower()


def test_classify_rejects_bad_scales():
    with pytest.raises(InputError) as excinfo:
        classify_terrain(np.zeros((3, 3)), 0.0, 1.0)
    assert_one_line_input_error(excinfo)


# ---------------------------------------------------------------- loaders


def test_png_16bit_round_trip(tmp_path):
    from PIL import Image

    heights = rng.integers(0, 65536, size=(33, 47)).astype(np.uint16)
    path = tmp_path / "dem.png"
    Image.fromarray(heights).save(path)
    with Image.open(path) as image:
        assert image.mode.startswith("I")  # really 16-bit on disk, not 8
    loaded = load_heightfield(path)
    assert loaded.dtype == np.float64 and loaded.shape == (33, 47)
    np.testing.assert_array_equal(loaded, heights)


def test_png_8bit_is_accepted(tmp_path):
    from PIL import Image

    heights = rng.integers(0, 256, size=(8, 9)).astype(np.uint8)
    Image.fromarray(heights).save(tmp_path / "dem8.png")
    np.testing.assert_array_equal(load_heightfield(tmp_path / "dem8.png"), heights)


def test_colour_png_is_refused(tmp_path):
    from PIL import Image

    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(InputError) as excinfo:
        load_heightfield(tmp_path / "rgb.png")
    assert_one_line_input_error(excinfo)
    assert "greyscale" in str(excinfo.value)


@pytest.mark.parametrize("dtype", [np.uint16, np.uint8, np.float32])
def test_tiff_round_trip(tmp_path, dtype):
    import tifffile

    heights = (rng.random((21, 13)) * 1000).astype(dtype)
    for name in ("dem.tif", "dem.tiff"):
        tifffile.imwrite(tmp_path / name, heights)
        loaded = load_heightfield(tmp_path / name)
        assert loaded.dtype == np.float64
        np.testing.assert_array_equal(loaded, heights.astype(np.float64))


def test_npy_round_trip_keeps_nan(tmp_path):
    heights = rng.normal(size=(6, 7))
    heights[3, 3] = np.nan
    np.save(tmp_path / "dem.npy", heights)
    np.testing.assert_array_equal(load_heightfield(tmp_path / "dem.npy"), heights)


def test_material_map_round_trip(tmp_path):
    classes = rng.integers(0, 4, size=(5, 6))
    np.save(tmp_path / "classes.npy", classes)
    loaded = load_material_map(tmp_path / "classes.npy")
    assert loaded.dtype.kind == "i"
    np.testing.assert_array_equal(loaded, classes)
    source = heightfield_to_source(np.zeros((6, 7)), materials=loaded)
    assert len(source.faces) == 60


@pytest.mark.parametrize("name, content", [
    ("dem.npy", np.zeros((2, 3, 4))),   # not 2-D
    ("dem.npy", np.array(["a", "b"])),  # not numbers
    ("dem.txt", None),                  # unknown type
    ("missing.npy", None),              # not there
])
def test_unreadable_heightfields(tmp_path, name, content):
    path = tmp_path / name
    if content is not None:
        np.save(path, content)
    elif name.endswith(".txt"):
        path.write_text("1 2\n3 4\n")
    with pytest.raises(InputError) as excinfo:
        load_heightfield(path)
    assert_one_line_input_error(excinfo)


def test_corrupt_png_is_an_input_error(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(InputError) as excinfo:
        load_heightfield(tmp_path / "bad.png")
    assert_one_line_input_error(excinfo)


def test_fractional_material_map_is_refused(tmp_path):
    np.save(tmp_path / "classes.npy", np.array([[0.25, 1.0]]))
    with pytest.raises(InputError) as excinfo:
        load_material_map(tmp_path / "classes.npy")
    assert_one_line_input_error(excinfo)


# ---------------------------------------------------------------- classification


def test_classify_water_rock_snow_grass():
    heights = np.array([
        [0.0, 0.0, 10.0, 10.0, 10.0, 10.0],
        [0.0, 0.0, 10.0, 10.0, 80.0, 80.0],
        [5.0, 5.0, 10.0, 10.0, 80.0, 80.0],
        [5.0, 5.0, 10.0, 90.0, 80.0, 80.0],
    ])
    classes = classify_terrain(heights, 10.0, 1.0)
    assert classes.shape == (3, 5) and classes.dtype == np.int32
    names = np.array(MATERIALS)[classes]
    assert names[0, 0] == "water"        # flat at the lowest level
    assert names[1, 0] == "grass"        # 5 m over 10 m cells: gentle, low
    assert names[0, 3] == "rock"         # 70 m rise over 10 m
    assert names[1, 4] == "snow"         # flat at 80 m of a 0..90 range
    assert names[2, 3] == "rock"         # steep outranks high


def test_classify_thresholds_and_holes():
    heights = np.array([[0.0, 1.0, 2.0], [0.0, 1.0, np.nan]])
    classes = classify_terrain(heights, 100.0, 1.0, water_level=1.0, snow_level=1e9)
    assert classes[0, 0] == WATER and classes[0, 1] == -1
    assert classify_terrain(heights, 1.0, 1.0, rock_slope_deg=10.0)[0, 0] == ROCK


def test_without_a_map_the_terrain_is_classified_into_coherent_regions():
    heights, _ = default_heights(32)
    source = heightfield_to_source(heights, cell_size=TERRAIN_EXTENT / 32)
    names = np.array(source.materials)[source.face_material[0::2]]
    classes = coherent_classes(classify_terrain(heights, TERRAIN_EXTENT / 32, 1.0))
    np.testing.assert_array_equal(names, np.array(MATERIALS)[classes.ravel()])


# ---------------------------------------------------------------- default terrain


def test_default_heights_are_seeded():
    a_heights, a_classes = default_heights(64, seed=3)
    b_heights, b_classes = default_heights(64, seed=3)
    np.testing.assert_array_equal(a_heights, b_heights)
    np.testing.assert_array_equal(a_classes, b_classes)
    assert not np.array_equal(a_heights, default_heights(64, seed=4)[0])


def test_default_heights_shape_and_range():
    heights, classes = default_heights(64)
    assert heights.shape == (65, 65) and heights.dtype == np.float64
    assert classes.shape == (64, 64) and classes.dtype == np.int32
    assert heights.min() == LAKE_LEVEL
    assert 1000.0 < heights.max() < 2000.0


def test_default_heights_are_the_same_landscape_at_every_size():
    coarse, _ = default_heights(64)
    fine, _ = default_heights(256)
    np.testing.assert_allclose(fine[::4, ::4], coarse, atol=1e-6)


def test_default_terrain_has_all_four_classes():
    source = default_terrain(128)
    assert sorted(source.materials) == sorted(MATERIALS)
    assert set(source.face_material.tolist()) == set(range(4))
    assert len(source.faces) == 2 * 128 * 128
    check_dtypes(source)


def test_lakes_are_flat_water_and_the_cliff_face_is_rock():
    heights, classes = default_heights(128)
    corners = np.stack([heights[:-1, :-1], heights[:-1, 1:], heights[1:, :-1], heights[1:, 1:]])
    water = classes == WATER
    assert water.sum() > 100
    assert (corners[:, water] == LAKE_LEVEL).all()  # one flat surface
    rise = corners.max(axis=0) - corners.min(axis=0)
    assert (classes[rise > 150.0] == ROCK).all()    # the cliff jumps > 150 m in one cell


@pytest.mark.parametrize("size", [64, 256])
def test_cliff_crease_and_smooth_elsewhere(size):
    dihedral = interior_dihedrals(default_terrain(size))
    assert len(dihedral) == 3 * size * size - 2 * size
    assert dihedral.max() > 45.0                 # the cliff's top edge: a crease
    assert (dihedral < 20.0).mean() > 0.99       # crease-angle normals stay smooth elsewhere


def test_default_size_is_checked():
    for size in (0, -3, 2.5, True):
        with pytest.raises(InputError):
            default_heights(size)


@pytest.mark.slow
def test_full_size_default_terrain():
    source = default_terrain(1024)
    assert len(source.faces) == 2_097_152
    assert len(source.positions) == 1025 * 1025


# --------------------------------------------------------------------------
# no-data samples of real elevation data


def _dem(seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(0, 5, (20, 20)).cumsum(axis=0) + 500).astype(np.int16)


def test_srtm_voids_in_int16_tiffs_become_holes(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    dem = _dem()
    dem[5:8, 5:8] = terrain.SRTM_VOID
    tifffile.imwrite(tmp_path / "srtm.tif", dem)
    heights = terrain.load_heightfield(tmp_path / "srtm.tif")
    assert np.isnan(heights).sum() == 9
    assert np.nanmin(heights) > 0


def test_gdal_nodata_tag_is_honoured(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    dem = _dem().astype(np.float32)
    dem[2:4, 10:12] = -9999.0
    tifffile.imwrite(tmp_path / "geo.tif", dem, extratags=[(42113, "s", 0, "-9999", True)])
    assert np.isnan(terrain.load_heightfield(tmp_path / "geo.tif")).sum() == 4


def test_explicit_nodata_value(tmp_path):
    dem = _dem().astype(np.float64)
    dem[0, :3] = 0.0
    np.save(tmp_path / "dem.npy", dem)
    assert not np.isnan(terrain.load_heightfield(tmp_path / "dem.npy")).any()
    assert np.isnan(terrain.load_heightfield(tmp_path / "dem.npy", nodata=0.0)).sum() == 3


# ---------------------------------------------------------------- what float32 cannot hold (issue 17, item 4)


@pytest.mark.parametrize("heights, kwargs, words", [
    (np.full((3, 3), 3.4e38), {}, "9 heightfield samples"),
    (np.array([[0.0, 1e300], [0.0, 0.0]]), {"z_scale": 1e10}, "1 heightfield samples"),   # overflows float64
    (np.ones((3, 3)), {"z_scale": 1e38}, "smaller --z-scale"),
    (np.zeros((3, 3)), {"cell_size": 1e38}, "smaller --cell-size"),
    (np.zeros((3, 3)), {"cell_size": 1e-39}, "larger --cell-size"),
])
def test_heights_and_grids_float32_cannot_hold_are_refused(heights, kwargs, words):
    with pytest.raises(InputError) as excinfo:
        heightfield_to_source(heights, **kwargs)
    assert_one_line_input_error(excinfo)
    assert words in str(excinfo.value), str(excinfo.value)


def test_heights_within_the_limit_build(tmp_path, capsys):
    np.save(tmp_path / "high.npy", np.array([[0.0, 4e18], [-4e18, 1.0]]))
    code, err = build_cli(capsys, tmp_path / "high.npy")
    assert code == 0, err


@pytest.mark.parametrize("grid, options, words", [
    (np.full((8, 8), 3.4e38, np.float32), [], "64 heightfield samples"),
    (np.where(np.eye(8) > 0, 3.4e38, 0.0), [], "8 heightfield samples"),
    (np.random.default_rng(1).random((8, 8)), ["--z-scale=1e38"], "--z-scale"),
    (np.random.default_rng(1).random((8, 8)), ["--cell-size=1e38"], "--cell-size"),
    (np.random.default_rng(1).random((8, 8)), ["--cell-size=1e-39"], "--cell-size"),
    (np.random.default_rng(1).random((8, 8)), ["--cell-size=0"], "--cell-size"),
    (np.random.default_rng(1).random((8, 8)), ["--cell-size=-1"], "--cell-size"),
    (np.random.default_rng(1).random((8, 8)), ["--cell-size=nan"], "--cell-size"),
    (np.random.default_rng(1).random((8, 8)), ["--cell-size=inf"], "--cell-size"),
    (np.random.default_rng(1).random((8, 8)), ["--z-scale=-inf"], "--z-scale"),
    (np.random.default_rng(1).random((8, 8)), ["--z-scale=0"], "--z-scale"),
])
def test_the_cli_refuses_them_in_one_line_without_warnings(tmp_path, capsys, grid, options, words):
    np.save(tmp_path / "dem.npy", grid)
    code, err = build_cli(capsys, tmp_path / "dem.npy", *options)
    assert code == 2 and words in err, err


def test_signalling_nans_are_holes_without_warnings(tmp_path, capsys):
    """Bit rot can leave signalling NaNs (exponent all ones, top mantissa bit
    clear); converting them to float64 or computing with them warns."""
    grid = np.zeros((6, 6), np.float32)
    grid.view(np.uint32)[2, 2] = 0x7F800001                  # a signalling NaN
    np.save(tmp_path / "snan32.npy", grid)
    grid64 = np.zeros((6, 6))
    grid64.view(np.uint64)[2, 2] = 0x7FF0000000000001
    np.save(tmp_path / "snan64.npy", grid64)
    for name in ("snan32.npy", "snan64.npy"):
        assert np.isnan(load_heightfield(tmp_path / name)).sum() == 1
        code, err = build_cli(capsys, tmp_path / name)
        assert code == 0, err


def test_heights_beyond_float64_are_refused_without_warnings(tmp_path, capsys):
    grid = np.zeros((4, 4), np.longdouble)
    grid[1, 1] = np.finfo(np.longdouble).max
    np.save(tmp_path / "long.npy", grid)
    code, err = build_cli(capsys, tmp_path / "long.npy")
    assert code == 2 and ("infinity" in err or "beyond" in err), err


def test_a_png_beyond_pillows_pixel_limit_is_refused(tmp_path, capsys):
    """A damaged header claiming 10000 x 10000 pixels: Pillow would only warn
    (a DecompressionBombWarning on stderr); the build refuses it."""
    import struct
    import zlib
    from PIL import Image
    Image.fromarray(np.zeros((8, 8), np.uint16)).save(tmp_path / "dem.png")
    data = bytearray((tmp_path / "dem.png").read_bytes())
    struct.pack_into(">II", data, 16, 10000, 10000)           # IHDR width, height
    struct.pack_into(">I", data, 29, zlib.crc32(bytes(data[12:29])))
    (tmp_path / "dem.png").write_bytes(bytes(data))
    code, err = build_cli(capsys, tmp_path / "dem.png")
    assert code == 2 and "89,478,485 pixels" in err, err


def test_what_tifffile_logs_while_reading_is_silenced(tmp_path, caplog, capsys):
    """A TIFF whose RowsPerStrip disagrees with its one strip: tifffile logs
    (and reads it anyway); the user sees nothing."""
    tifffile = pytest.importorskip("tifffile")
    tifffile.imwrite(tmp_path / "dem.tif", np.zeros((8, 8), np.float32))
    with tifffile.TiffFile(tmp_path / "dem.tif") as tif:
        offset = tif.pages[0].tags["RowsPerStrip"].valueoffset
    data = bytearray((tmp_path / "dem.tif").read_bytes())
    data[offset:offset + 4] = (2).to_bytes(4, "little")
    (tmp_path / "dem.tif").write_bytes(bytes(data))
    with caplog.at_level("DEBUG"):
        try:
            load_heightfield(tmp_path / "dem.tif")
        except InputError:
            pass
    assert not [r for r in caplog.records if r.name.startswith("tifffile")], caplog.text
    build_cli(capsys, tmp_path / "dem.tif")


def test_a_float16_material_map_is_checked_without_warnings(tmp_path, capsys):
    np.save(tmp_path / "dem.npy", np.zeros((4, 4)))
    np.save(tmp_path / "classes.npy", np.full((3, 3), 2, np.float16))
    code, err = build_cli(capsys, tmp_path / "dem.npy", f"--materials={tmp_path / 'classes.npy'}")
    assert code == 0, err


def test_a_tiff_missing_strips_or_tiles_is_refused(tmp_path, capsys):
    """A tiled TIFF whose ImageLength says 100,000 rows but which holds two
    tiles: tifffile fills the 12,498 missing ones with zeros, and the build of
    that plain ran past the fuzzer's 20 s; it is refused as damaged."""
    tifffile = pytest.importorskip("tifffile")
    tifffile.imwrite(tmp_path / "dem.tif", np.ones((16, 18), np.float32), tile=(16, 16))
    with tifffile.TiffFile(tmp_path / "dem.tif") as tif:
        tag = tif.pages[0].tags["ImageLength"]
        assert tag.dtype == 4 and tag.count == 1                 # one LONG, stored in the entry
    data = bytearray((tmp_path / "dem.tif").read_bytes())
    data[tag.valueoffset:tag.valueoffset + 4] = (100000).to_bytes(4, "little")
    (tmp_path / "dem.tif").write_bytes(bytes(data))
    code, err = build_cli(capsys, tmp_path / "dem.tif")
    assert code == 2 and "damaged" in err and "strips or tiles" in err, err
