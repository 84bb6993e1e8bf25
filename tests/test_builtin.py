"""The built-in sources: the rough terrain, the range scan and the debris field.

The smooth default terrain has its own tests in test_terrain.py.
"""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod.builder.builtin import ROUGH_CELL, debris_field, range_scan, rough_heights, rough_terrain
from caveclod.builder.topology import count_components, face_neighbours


def slopes_deg(z, cell):
    gy, gx = np.gradient(z, cell)
    s = np.degrees(np.arctan(np.hypot(gx, gy)))
    return s[np.isfinite(s)]


def test_rough_terrain_has_the_traits_of_real_elevation_models():
    z = rough_heights(128)
    assert z.shape == (129, 129)
    relief = np.nanmax(z) - np.nanmin(z)
    assert 200.0 < relief < 1000.0
    s = slopes_deg(z, ROUGH_CELL)
    assert np.median(s) > 15.0 and (s > 35.0).mean() > 0.1      # steep slopes
    assert 0.01 < np.isnan(z).mean() < 0.2                      # no-data holes
    # Detail down to the cell: height differences between neighbours do
    # not vanish at the finest scale, and they grow with distance as fBm does.
    d1 = np.nanmean(np.abs(np.diff(z[:, ::1], axis=1)))
    d8 = np.nanmean(np.abs(z[:, 8:] - z[:, :-8]))
    assert d1 > 1.0 and 3.0 < d8 / d1 < 8.0
    lake = np.nanmin(z)
    assert np.count_nonzero(z == lake) > 50                     # flattened water


def test_rough_terrain_is_seeded():
    np.testing.assert_array_equal(rough_heights(32, seed=3), rough_heights(32, seed=3))
    assert not np.array_equal(rough_heights(32, seed=3), rough_heights(32, seed=4), equal_nan=True)


def test_rough_terrain_base_mesh_is_under_one_percent():
    """The issue's bound, at the built-in's default size and options."""
    mesh = caveclod.build("rough")
    assert mesh.n_faces > 100_000
    assert len(mesh.base_faces) < 0.01 * mesh.n_faces
    assert not mesh.info["base_mesh"]["large"]
    assert mesh.class_tally()["rigid"] < 0.01 * mesh.n_positions


def test_range_scan_is_like_a_real_scan():
    source = range_scan(64)
    topo = face_neighbours(source.face_positions.astype(np.int32), len(source.positions))
    border_edges = int((topo.nbrs < 0).sum())
    assert border_edges > 100                                     # open border and holes
    assert count_components(topo.nbrs) >= 1
    assert len(source.materials) == 3
    # Every chart border is a UV seam: positions with several UVs.
    assert len(source.vertex_position) > 1.05 * len(source.positions)
    # Irregular triangles: some are slivers.
    P = source.positions[source.face_positions]
    e = np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2)
    aspect = e.max(axis=1) / np.maximum(e.min(axis=1), 1e-12)
    assert aspect.max() > 3.0


def test_debris_field_is_many_small_parts_like_real_rubble():
    source = debris_field(8)
    topo = face_neighbours(source.face_positions.astype(np.int32), len(source.positions))
    assert count_components(topo.nbrs) == 160                     # 20 x size separate parts
    assert int((topo.nbrs < 0).sum()) > 100                       # open borders: boulders scanned from above
    assert len(source.vertex_position) > 1.05 * len(source.positions)    # UV seams of the blocks' side charts
    assert len(np.unique(source.face_material)) >= 8
    P = source.positions[source.face_positions]
    edge = np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2)
    assert np.ptp(source.positions[:, 0]) > 200 * np.median(edge)   # a field far wider than its parts' detail
    again = debris_field(8)
    np.testing.assert_array_equal(source.positions, again.positions)          # seeded
    assert not np.array_equal(debris_field(8, seed=1).positions[:10], source.positions[:10])


def test_range_scan_builds_and_refines_fully():
    mesh = caveclod.build("scan", size=32)
    cam = mesh.new_camera()
    view = caveclod.View(eye=(0.0, 4.0, 0.5), target=(0.0, 0.0, 0.0), tolerance_px=0.0, cull=False)
    cam.update(view)
    cam.validate()
    assert cam.n_faces == mesh.n_faces


@pytest.mark.parametrize("name", ["rough", "scan", "debris"])
def test_cli_builds_the_builtins(tmp_path, name):
    from caveclod.cli import main
    out = tmp_path / f"{name}.cvc"
    assert main(["build", name, "-o", str(out), "--size", "24", "--quiet", "--json"]) == 0
    assert caveclod.load(out).n_faces > 0


def test_rough_terrain_mesh_is_a_heightfield_with_holes():
    source = rough_terrain(40)
    assert source.crease_angle == 180.0
    assert any("NaN" in note for note in source.notes)
