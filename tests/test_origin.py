"""Meshes in world coordinates: --origin keeps their detail in the .cvc's float32 positions,
and without it the report says what rounding cost."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import caveclod
from caveclod.builder.meshfile import load_mesh_file
from caveclod.builder.origin import float32_rounding_note, parse_origin
from caveclod.errors import InputError
from fuzzsources import build_here as build_cli

UTM = np.array([500123.25, 4100234.5, 312.0])      # a UTM easting and northing, metres


def _far_sphere(path, radius, subdivisions):
    """An icosphere of ``radius`` metres at a UTM position, written as OBJ (float64 text)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.vertices += UTM
    path.write_text(trimesh.exchange.obj.export_obj(mesh, digits=6))
    return mesh


def test_rounding_a_far_mesh_is_noted_and_auto_keeps_its_detail(tmp_path):
    path = tmp_path / "tank.obj"
    _far_sphere(path, 30.0, 3)                      # 4.5 m edges; float32's step there is 0.25-0.5 m
    plain = caveclod.build(str(path), packed=False)
    assert any("--origin auto" in n and "% of the median edge" in n for n in plain.info["notes"])
    assert "origin" not in plain.info
    moved = caveclod.build(str(path), packed=False, origin="auto")
    assert moved.info["origin"] == [500123.0, 4100234.0, 312.0]
    assert not any("float32" in n for n in moved.info["notes"])
    source = load_mesh_file(path)
    back = np.asarray(moved.positions, np.float64) + moved.info["origin"]
    # the same positions, as the file keeps them: within float32's step at 30 m, not at 4e6 m
    order_s, order_b = np.lexsort(source.positions.T), np.lexsort(back.T)
    assert np.abs(source.positions[order_s] - back[order_b]).max() < 1e-5
    far = np.abs(source.positions[order_s] - np.asarray(plain.positions, np.float64)[np.lexsort(
        np.asarray(plain.positions, np.float64).T)]).max()
    assert far > 0.01                                # what the plain build's file lost


def test_a_fine_far_mesh_is_refused_with_the_way_out(tmp_path, capsys):
    path = tmp_path / "part.obj"
    _far_sphere(path, 2.0, 4)
    status, err = build_cli(capsys, path)
    assert status == 2 and "build with --origin auto" in err
    status, err = build_cli(capsys, path, "--origin", "auto", "--quiet")
    assert status == 0, err
    assert caveclod.load(tmp_path / "out.cvc").info["origin"] == [500123.0, 4100234.0, 312.0]


def test_an_explicit_origin_is_subtracted_exactly(tmp_path):
    path = tmp_path / "tank.obj"
    _far_sphere(path, 30.0, 2)
    mesh = caveclod.build(str(path), packed=False, origin="500000,4100000,0")
    source = load_mesh_file(path)
    assert mesh.info["origin"] == [500000.0, 4100000.0, 0.0]
    expected = np.sort((source.positions - [500000.0, 4100000.0, 0.0]).astype(np.float32), axis=0)
    assert np.array_equal(np.sort(np.asarray(mesh.positions), axis=0), expected)


@pytest.mark.parametrize("value", ["1,2", "nan,0,0", "a,b,c", "auto2", "1,2,3,4", "inf,0,0"])
def test_bad_origins_are_refused(value):
    with pytest.raises(InputError, match="--origin must be"):
        parse_origin(value)


def test_an_origin_that_throws_the_mesh_out_of_range_is_refused(tmp_path):
    path = tmp_path / "tank.obj"
    _far_sphere(path, 30.0, 1)
    with pytest.raises(InputError, match="puts 42 positions beyond"):
        caveclod.build(str(path), packed=False, origin=(1e308, -1e308, 0.0))


def test_meshes_near_their_origin_get_no_note():
    for name in ("default", "scan"):
        assert not any("float32" in n for n in caveclod.build(name, size=32, packed=False).info["notes"])
    p = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert float32_rounding_note(p, np.array([[0, 1, 2]])) is None
    assert float32_rounding_note(p, np.zeros((0, 3), np.int64)) is None


def test_tile_jobs_and_their_merge_carry_the_origin(tmp_path):
    whole = caveclod.build("rough", size=64, tiles=4, packed=False, origin="auto")
    for job in ("0/2", "1/2"):
        caveclod.build_tiles("rough", tmp_path / "tiles", job, size=64, tiles=4, origin="auto")
    merged = caveclod.build("rough", size=64, tiles=4, packed=False, origin="auto", tiles_dir=tmp_path / "tiles")
    assert merged.content_hash == whole.content_hash and merged.info["origin"] == whole.info["origin"]


def test_clients_learn_the_origin_from_list_meshes(tmp_path, make_server, terrain_path):
    from caveclod.client import Client
    path = tmp_path / "tank.obj"
    _far_sphere(path, 30.0, 2)
    caveclod.build(str(path), origin="auto").save(tmp_path / "tank.cvc")
    server = make_server(meshes=[tmp_path / "tank.cvc", terrain_path])
    with Client(f"127.0.0.1:{server.port}", cache_dir=False) as client:
        meshes = {m.name: m for m in client.list_meshes()}
    tank, terrain = meshes["tank"], meshes["terrain"]
    assert tank.HasField("origin") and (tank.origin.x, tank.origin.y, tank.origin.z) == (500123.0, 4100234.0, 312.0)
    assert not terrain.HasField("origin")
    assert tank.bounds_max.x < 40.0               # bounds are in the mesh's own coordinates


def test_the_bound_holds_on_the_positions_the_file_stores(tmp_path):
    """Errors were measured on the float64 input while the file stores float32: a far grid of 0.5 m
    cells (float32's step at x = 500,000 m is 3 cm, its relief centimetres) built without --origin drew
    original positions up to 1.4 t from what cameras showed, the strict bound's included."""
    from caveclod.refine.measure import hidden_positions, pixel_errors
    rng = np.random.default_rng(1)
    n, cell = 80, 0.5
    ys, xs = np.mgrid[0:n, 0:n] * cell
    z = 5 * np.sin(xs / 17.0) + 3 * np.cos(ys / 11.0) + 0.03 * rng.standard_normal(xs.shape)
    V = np.stack([xs, ys, z], -1).reshape(-1, 3) + UTM
    V[:, :2] += rng.uniform(-0.05, 0.05, (len(V), 2))
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    path = tmp_path / "far.obj"
    trimesh.Trimesh(V, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]), process=False).export(path)
    mesh = caveclod.build(str(path), packed=False)
    assert any("--origin auto" in note for note in mesh.info["notes"])
    lo, hi = mesh.bounds()
    centre, ext = (lo + hi) / 2, hi - lo
    worst = 0.0
    for k in range(5):
        angle = 0.7 + 1.1 * k
        eye = centre + np.array([np.cos(angle) * ext[0] * 0.6, np.sin(angle) * ext[1] * 0.6, 12.0 + 5 * k])
        view = caveclod.View(eye=tuple(eye), target=tuple(centre - [0, 0, 5.0]), up=(0, 0, 1), tolerance_px=0.5)
        for strict in (False, True):
            cam = mesh.new_camera(strict_bound=strict)
            for _ in range(10):
                if cam.update(view).operations == 0:
                    break
            px = pixel_errors(mesh, cam.triangles(), view, points=np.asarray(mesh.positions)[~hidden_positions(cam)])
            worst = max(worst, float(px.max()) / 0.5)
    assert worst <= 1.0 + 1e-6, f"an original position drawn {worst:.2f} t away"


def test_an_origin_west_of_greenwich_is_read_as_a_value(tmp_path, capsys):
    """argparse took ``--origin -2700000,...`` (an ECEF point in the Americas) for an option of its own
    and said "expected one argument"; only ``--origin=...`` worked."""
    path = tmp_path / "tank.obj"
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    mesh.vertices += [-2700000.0, -4300000.0, 3800000.0]
    path.write_text(trimesh.exchange.obj.export_obj(mesh, digits=6))
    status, err = build_cli(capsys, path, "--origin", "-2700000,-4300000,3800000", "--quiet")
    assert status == 0, err
    assert caveclod.load(tmp_path / "out.cvc").info["origin"] == [-2700000.0, -4300000.0, 3800000.0]
