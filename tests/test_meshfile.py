"""Tests of caveclod.builder.meshfile: mesh files and trimesh objects -> SourceMesh.

Every fixture is written by the test into a temporary directory: small text
files (OBJ, MTL) literally, binary ones (PLY, GLB, STL) through trimesh's
exporters.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from trimesh.visual import ColorVisuals, TextureVisuals

from caveclod.builder import meshfile
from caveclod.errors import InputError
from caveclod.builder.meshfile import load_mesh_file, source_from_trimesh
from caveclod.builder.source import SourceMesh
from fuzzsources import build_here as build_cli     # a build as the source fuzzer runs it, in-process

# --------------------------------------------------------------------------
# fixture makers
# --------------------------------------------------------------------------

CUBE_V = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
"""
CUBE_VT = """\
vt 0 0
vt 1 0
vt 1 1
vt 0 1
"""
CUBE_VN = """\
vn 0 0 -1
vn 0 0 1
vn 0 -1 0
vn 0 1 0
vn -1 0 0
vn 1 0 0
"""
# Six quads, counter-clockwise seen from outside; corners v/vt/vn.
CUBE_FACES = [
    ("red", "1/1/1 4/4/1 3/3/1 2/2/1"),   # z = 0
    ("red", "5/1/2 6/2/2 7/3/2 8/4/2"),   # z = 1
    ("red", "1/1/3 2/2/3 6/3/3 5/4/3"),   # y = 0
    ("blue", "4/1/4 8/4/4 7/3/4 3/2/4"),  # y = 1
    ("blue", "1/1/5 5/2/5 8/3/5 4/4/5"),  # x = 0
    ("blue", "2/1/6 3/2/6 7/3/6 6/4/6"),  # x = 1
]
CUBE_MTL = "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n"


def write_cube_obj(directory: Path, normals: bool = True, name: str = "cube") -> Path:
    """A unit cube OBJ with uv and (optionally) normal seams and two materials."""
    (directory / f"{name}.mtl").write_text(CUBE_MTL)
    lines = [f"mtllib {name}.mtl", CUBE_V, CUBE_VT]
    if normals:
        lines.append(CUBE_VN)
    current = None
    for material, corners in CUBE_FACES:
        if material != current:
            lines.append(f"usemtl {material}")
            current = material
        if not normals:  # "v/vt/vn" -> "v/vt"
            corners = " ".join(c.rsplit("/", 1)[0] for c in corners.split())
        lines.append(f"f {corners}")
    path = directory / f"{name}.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


def write_text(directory: Path, name: str, text: str) -> Path:
    path = directory / name
    path.write_text(text)
    return path


def box_with_vertex_colors() -> trimesh.Trimesh:
    box = trimesh.creation.box()
    rng = np.random.default_rng(7)
    box.visual = ColorVisuals(box, vertex_colors=rng.integers(0, 256, (8, 4), dtype=np.uint8))
    return box


def box_with_uv() -> trimesh.Trimesh:
    box = trimesh.creation.box()
    rng = np.random.default_rng(3)
    box.visual = TextureVisuals(uv=rng.random((8, 2)))
    return box


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------


def check_contract(src: SourceMesh) -> None:
    """The dtypes and invariants SourceMesh promises, beyond validate()."""
    src.validate()
    assert src.positions.dtype == np.float64
    assert src.vertex_position.dtype == np.int64
    assert src.faces.dtype == np.int64
    assert src.face_material.dtype == np.int32
    assert src.faces.shape[1] == 3
    assert 0 <= src.face_material.min() and src.face_material.max() < len(src.materials)
    # exact welding: positions unique
    assert len(np.unique(src.positions, axis=0)) == len(src.positions)
    # every vertex and position is used
    assert len(np.unique(src.faces)) == len(src.vertex_position)
    assert len(np.unique(src.vertex_position)) == len(src.positions)
    # vertices carry distinct attribute rows
    rows = [src.vertex_position[:, None].astype(np.float64)]
    for arr in (src.vertex_normal, src.vertex_uv, src.vertex_color):
        if arr is not None:
            rows.append(arr.astype(np.float64))
    assert len(np.unique(np.hstack(rows), axis=0)) == len(src.vertex_position)
    if src.vertex_normal is not None:
        assert src.vertex_normal.dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(src.vertex_normal, axis=1), 1.0, atol=1e-6)
    if src.vertex_uv is not None:
        assert src.vertex_uv.dtype == np.float32
    if src.vertex_color is not None:
        assert src.vertex_color.dtype == np.uint8
    for note in src.notes:
        assert "\n" not in note and any(ch.isdigit() for ch in note)


def face_geometric_normals(src: SourceMesh) -> np.ndarray:
    """(p, 3) unit normals from the winding of each face."""
    tri = src.positions[src.face_positions]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def signed_volume(src: SourceMesh) -> float:
    tri = src.positions[src.face_positions]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def canonical_triangles(tri: np.ndarray) -> set:
    """Set of triangles (p, 3, 3) as coordinate triples, rotated so the
    smallest corner comes first (same cyclic order = same triangle)."""
    out = set()
    for corners in tri.tolist():
        corners = [tuple(c) for c in corners]
        k = corners.index(min(corners))
        out.add(tuple(corners[k:] + corners[:k]))
    return out


def assert_one_line_error(excinfo, path) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    assert str(path) in message or Path(path).name in message
    assert excinfo.value.__traceback__ is not None  # raised, not returned
    assert excinfo.value.__cause__ is None or isinstance(excinfo.value.__cause__, InputError)
    return message


# --------------------------------------------------------------------------
# OBJ
# --------------------------------------------------------------------------


def test_obj_cube_with_seams_and_two_materials(tmp_path):
    src = load_mesh_file(write_cube_obj(tmp_path))
    check_contract(src)
    assert len(src.positions) == 8
    assert len(src.faces) == 12  # six quads, triangulated
    assert sorted(src.materials) == ["blue", "red"]
    counts = np.bincount(src.face_material, minlength=2)
    assert counts.tolist() == [6, 6]
    # seams survive: each corner has its own normal, so 24 vertices
    assert len(src.vertex_position) == 24
    assert src.vertex_normal is not None and src.vertex_uv is not None
    assert src.vertex_color is None
    # the file's normals are attached to the right faces (outward, per face)
    geometric = face_geometric_normals(src)
    for corner in range(3):
        np.testing.assert_allclose(src.vertex_normal[src.faces[:, corner]], geometric, atol=1e-6)
    # materials go to the right faces: red is z=0, z=1, y=0
    red = src.materials.index("red")
    red_normals = {tuple(np.round(n).astype(int)) for n in geometric[src.face_material == red]}
    assert red_normals == {(0, 0, -1), (0, 0, 1), (0, -1, 0)}
    assert signed_volume(src) == pytest.approx(1.0)
    assert src.notes == []


def test_obj_cube_without_normals_has_none(tmp_path):
    src = load_mesh_file(write_cube_obj(tmp_path, normals=False))
    check_contract(src)
    assert src.vertex_normal is None
    assert src.vertex_uv is not None
    assert len(src.positions) == 8
    # uv seams alone still split vertices
    assert len(src.vertex_position) > len(src.positions)
    assert sorted(src.materials) == ["blue", "red"]


def test_obj_quads_and_pentagon_are_triangulated(tmp_path):
    path = write_text(tmp_path, "poly.obj", (
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 3 0.5 0\n"
        "f 1 2 3 4\nf 2 5 6 3\nf 5 7 6\n"
        "v 0 0 5\nv 1 0 5\nv 1 1 5\nv 0.5 2 5\nv 0 1 5\nf 8 9 10 11 12\n"
    ))
    src = load_mesh_file(path)
    check_contract(src)
    assert src.faces.shape == (2 + 2 + 1 + 3, 3)
    # triangulation keeps the winding: all faces point +z
    np.testing.assert_allclose(face_geometric_normals(src), [[0, 0, 1]] * len(src.faces), atol=1e-12)
    assert len(src.positions) == 12


def test_obj_degenerate_duplicate_unused_and_slivers(tmp_path):
    path = write_text(tmp_path, "dirty.obj", (
        "v 0 0 0\n"      # 1
        "v 1 0 0\n"      # 2
        "v 0 1 0\n"      # 3
        "v 1 0 0\n"      # 4: same coordinates as 2 -> welded
        "v 2 0 0\n"      # 5: collinear with 1 and 2 -> sliver
        "v 9 9 9\n"      # 6: used by no face
        "f 1 2 3\n"      # kept
        "f 2 3 1\n"      # same triangle, rotated: duplicate
        "f 3 1 2\n"      # duplicate again
        "f 1 4 3\n"      # same positions as 1 2 3 after welding: duplicate
        "f 1 3 2\n"      # opposite orientation: kept (double-sided)
        "f 1 2 4\n"      # 2 and 4 weld: degenerate
        "f 1 1 3\n"      # degenerate by index
        "f 1 2 5\n"      # zero area, distinct positions: kept
    ))
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.faces) == 3
    tri = src.positions[src.face_positions]
    assert canonical_triangles(tri) == canonical_triangles(np.array([
        [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
        [[0, 0, 0], [0, 1, 0], [1, 0, 0]],
        [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
    ], dtype=float))
    assert len(src.positions) == 4  # (9, 9, 9) dropped
    assert "dropped 2 degenerate faces (a position used twice after exact welding)" in src.notes
    assert "dropped 3 duplicate faces (same positions in the same order and same material)" in src.notes
    # trimesh's OBJ loader already leaves out (9, 9, 9), which no face names;
    # vertex 4 is left unused by the dropped faces (its position lives on).
    unused = [n for n in src.notes if "no face uses" in n]
    assert unused == ["dropped 1 vertices (0 positions) that no face uses"]


def test_unused_vertices_and_positions_are_dropped():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [9, 9, 9], [1, 0, 0]], dtype=float)
    mesh = trimesh.Trimesh(vertices, [[0, 1, 2], [0, 4, 2]], process=False)
    src = source_from_trimesh(mesh)
    check_contract(src)
    assert len(src.positions) == 3 and len(src.faces) == 1
    assert "dropped 2 vertices (1 positions) that no face uses" in src.notes


def test_obj_same_triangle_in_two_materials_is_kept(tmp_path):
    write_text(tmp_path, "two.mtl", "newmtl a\nKd 1 0 0\nnewmtl b\nKd 0 1 0\n")
    path = write_text(tmp_path, "two.obj", (
        "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
        "usemtl a\nf 1 2 3\nf 1 2 3\nusemtl b\nf 1 2 3\n"
    ))
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.faces) == 2
    assert sorted(src.materials[m] for m in src.face_material) == ["a", "b"]
    assert any("dropped 1 duplicate faces" in n for n in src.notes)


def test_negative_zero_welds_with_positive_zero(tmp_path):
    path = write_text(tmp_path, "zero.obj", (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv -0 -0 -0\nv 0 0 1\n"
        "f 1 2 3\nf 4 3 5\n"
    ))
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.positions) == 4
    assert not np.signbit(src.positions).any()


def test_obj_with_nan_vertex_is_refused(tmp_path):
    path = write_text(tmp_path, "nan.obj", (
        "v 0 0 0\nv nan 0 0\nv 0 1 0\nv 1 1 inf\nf 1 2 3\nf 1 3 4\n"
    ))
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    message = assert_one_line_error(excinfo, path)
    assert "2 vertices" in message and "NaN" in message


def _corners(src: SourceMesh) -> list:
    """Each face as its corners' (position, uv or None), sorted: what a file's faces say,
    whatever order the reader gave vertices and faces."""
    uv = src.vertex_uv
    return sorted(tuple((tuple(src.positions[src.vertex_position[v]]),
                         None if uv is None else tuple(np.round(uv[v], 6))) for v in face)
                  for face in src.faces.tolist())


def _grid_obj(rng, n=6, relative=False, uv_every=1, indent="", sep=" ") -> str:
    """A textured n x n grid written part by part (each quad's 4 vertices, then its 2 faces), the
    way interleaving exporters write; ``relative``: faces name their corners by negative indices;
    quads whose number is not a multiple of ``uv_every`` have no texture coordinates."""
    lines, at = [], 0
    for k in range(n * n):
        i, j = divmod(k, n)
        quad = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]
        for x, y in quad:
            lines.append(f"{indent}v{sep}{x} {y} {rng.random():.6f}")
        for x, y in quad:
            lines.append(f"{indent}vt{sep}{x / n:.6f} {y / n:.6f}")
        textured = k % uv_every == 0
        for tri in ((0, 1, 2), (0, 2, 3)):
            idx = [(c - 4 if relative else at + c + 1) for c in tri]
            corner = (lambda a: f"{a}/{a}") if textured else (lambda a: f"{a}")
            lines.append(f"{indent}f{sep}" + " ".join(corner(a) for a in idx))
        at += 4
    return "\n".join(lines) + "\n"


def test_obj_relative_indices_name_the_vertices_before_the_face(tmp_path):
    """trimesh counts negative indices from the end of the file: an interleaved file's 72 faces
    all named the last quad's vertices (read as 2 faces, 70 dropped as duplicates)."""
    rng = np.random.default_rng(3)
    relative = load_mesh_file(write_text(tmp_path, "rel.obj", _grid_obj(rng, relative=True)))
    absolute = load_mesh_file(write_text(tmp_path, "abs.obj", _grid_obj(np.random.default_rng(3))))
    check_contract(relative)
    assert len(relative.faces) == 72 and _corners(relative) == _corners(absolute)
    assert any("72 of its 72 faces use relative (negative) indices" in n for n in relative.notes)
    assert not any("duplicate" in n for n in relative.notes)


def test_obj_faces_without_texture_coordinates_beside_textured_ones(tmp_path):
    """trimesh drops every texture coordinate of a file where some faces have none: the textured
    faces keep theirs, the others get (0, 0), and the report counts them."""
    rng = np.random.default_rng(4)
    mixed = load_mesh_file(write_text(tmp_path, "mixed.obj", _grid_obj(rng, uv_every=3)))
    full = load_mesh_file(write_text(tmp_path, "full.obj", _grid_obj(np.random.default_rng(4))))
    check_contract(mixed)
    assert mixed.vertex_uv is not None and len(mixed.faces) == 72
    expected = {tuple(p for p, _ in f): f for f in _corners(full)}
    for face in _corners(mixed):
        uvs = [uv for _, uv in face]
        if any(uv != (0.0, 0.0) for uv in uvs):
            assert face == expected[tuple(p for p, _ in face)]        # a textured face, as written
    untextured = sum(all(uv == (0.0, 0.0) for _, uv in f) for f in _corners(mixed))
    assert untextured >= 48 and any("48 of its 72 faces have no texture coordinates" in n for n in mixed.notes)


@pytest.mark.parametrize("indent, sep", [("  ", " "), ("\t", " "), ("", "\t")])
@pytest.mark.parametrize("relative, uv_every", [(False, 1), (True, 3)])
def test_obj_indented_lines_or_a_tab_after_the_keyword(tmp_path, indent, sep, relative, uv_every):
    """trimesh read no geometry ("empty file?") from lines indented or with a tab after their
    keyword; they read as the plain file does, relative indices and untextured faces too."""
    odd = load_mesh_file(write_text(tmp_path, "odd.obj", _grid_obj(np.random.default_rng(5), indent=indent,
                                                                   sep=sep, relative=relative, uv_every=uv_every)))
    plain = load_mesh_file(write_text(tmp_path, "plain.obj", _grid_obj(np.random.default_rng(5),
                                                                       uv_every=uv_every)))
    assert _corners(odd) == _corners(plain) and len(odd.faces) == 72


def test_a_plain_obj_is_read_as_it_is():
    from caveclod.builder.objtext import normalized_obj
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "plain.obj"
        path.write_text(_grid_obj(np.random.default_rng(6)))
        assert normalized_obj(path) == (None, [])


def test_obj_points_only_is_refused(tmp_path):
    path = write_text(tmp_path, "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert "no triangles" in assert_one_line_error(excinfo, path)


def test_all_faces_degenerate_is_refused(tmp_path):
    path = write_text(tmp_path, "flat.obj", "v 0 0 0\nv 1 0 0\nv 0 0 0\nf 1 2 3\n")
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert "degenerate" in assert_one_line_error(excinfo, path)


# --------------------------------------------------------------------------
# PLY, GLB, STL, OFF
# --------------------------------------------------------------------------


def colors_by_position(positions, vertex_position, colors) -> dict:
    return {tuple(positions[p]): tuple(c) for p, c in zip(vertex_position, colors)}


def test_ply_vertex_colors_kept(tmp_path):
    box = box_with_vertex_colors()
    path = tmp_path / "box.ply"
    box.export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.positions) == 8 and len(src.faces) == 12
    assert src.vertex_color is not None and src.vertex_color.shape == (8, 4)
    assert src.vertex_normal is None  # the exporter wrote no normals
    expected = colors_by_position(np.asarray(box.vertices, np.float32).astype(np.float64),
                                  np.arange(8), box.visual.vertex_colors)
    got = colors_by_position(src.positions, src.vertex_position, src.vertex_color)
    assert got == expected
    assert signed_volume(src) == pytest.approx(1.0)


def test_ply_with_normals_keeps_them(tmp_path):
    box = trimesh.creation.box()
    _ = box.vertex_normals  # puts normals in the cache, so the exporter writes them
    path = tmp_path / "box_n.ply"
    box.export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert src.vertex_normal is not None
    # trimesh's smooth box normals point diagonally outwards
    np.testing.assert_allclose(np.abs(src.vertex_normal), 1 / np.sqrt(3), atol=1e-6)


def test_ply_face_colors_become_vertex_colors(tmp_path):
    box = trimesh.creation.box()
    box.visual.face_colors = np.array([[255, 0, 0, 255]] * 6 + [[0, 0, 255, 255]] * 6, np.uint8)
    path = tmp_path / "faces.ply"
    box.export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert src.vertex_color is not None
    corner_colors = src.vertex_color[src.faces]            # (p, 3, 4)
    assert (corner_colors == corner_colors[:, :1]).all()  # flat per face
    assert {tuple(c) for c in corner_colors[:, 0]} == {(255, 0, 0, 255), (0, 0, 255, 255)}
    assert any("face colours of 12 faces" in n for n in src.notes)


def test_glb_roundtrip_keeps_uv(tmp_path):
    box = box_with_uv()
    path = tmp_path / "box.glb"
    box.export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.positions) == 8 and len(src.faces) == 12
    assert src.vertex_uv is not None and src.vertex_normal is None
    expected = {tuple(v): uv for v, uv in zip(box.vertices.tolist(), box.visual.uv)}
    for p, uv in zip(src.vertex_position, src.vertex_uv):
        np.testing.assert_allclose(uv, expected[tuple(src.positions[p])], atol=1e-6)
    assert signed_volume(src) == pytest.approx(1.0)


def test_glb_texture_with_vertex_colors_and_normals(tmp_path):
    box = box_with_uv()
    colors = np.random.default_rng(5).integers(0, 256, (8, 4), dtype=np.uint8)
    box.visual.vertex_attributes["color"] = colors  # glTF COLOR_0 beside a texture
    _ = box.vertex_normals  # cached, so the exporter writes NORMAL
    path = tmp_path / "textured.glb"
    box.export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert src.vertex_normal is not None and src.vertex_uv is not None
    expected = colors_by_position(np.asarray(box.vertices), np.arange(8), colors)
    assert colors_by_position(src.positions, src.vertex_position, src.vertex_color) == expected


@pytest.mark.parametrize("name", ["scan.ply", "scan.obj"])
def test_vertex_colors_beside_texture_coordinates_are_kept(tmp_path, name):
    """Photogrammetry exports carry both; trimesh keeps a PLY's or OBJ's colours in the mesh's
    vertex attributes when it makes a texture visual for the UVs, where they were not looked for
    (dropped without a note)."""
    rng = np.random.default_rng(11)
    grid = trimesh.creation.box().subdivide().subdivide()
    n = len(grid.vertices)
    colors = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    uv = rng.random((n, 2))
    path = tmp_path / name
    if name.endswith(".ply"):
        header = ["ply", "format ascii 1.0", f"element vertex {n}"] + \
            [f"property float {a}" for a in "xyz"] + [f"property uchar {c}" for c in ("red", "green", "blue")] + \
            ["property float s", "property float t", f"element face {len(grid.faces)}",
             "property list uchar int vertex_indices", "end_header"]
        rows = [f"{x:.6f} {y:.6f} {z:.6f} {r} {g} {b} {u:.6f} {v:.6f}"
                for (x, y, z), (r, g, b), (u, v) in zip(grid.vertices, colors, uv)]
        faces = [f"3 {a} {b} {c}" for a, b, c in grid.faces]
    else:
        header = []
        rows = [f"v {x:.6f} {y:.6f} {z:.6f} {r / 255:.6f} {g / 255:.6f} {b / 255:.6f}"
                for (x, y, z), (r, g, b) in zip(grid.vertices, colors)] + [f"vt {u:.6f} {v:.6f}" for u, v in uv]
        faces = [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in grid.faces]
    path.write_text("\n".join(header + rows + faces) + "\n")
    src = load_mesh_file(path)
    check_contract(src)
    assert src.vertex_color is not None and src.vertex_uv is not None
    positions = np.asarray(grid.vertices, np.float32).astype(np.float64).round(6)
    expected = colors_by_position(positions, np.arange(n), np.c_[colors, np.full(n, 255, np.uint8)])
    assert colors_by_position(src.positions.round(6), src.vertex_position, src.vertex_color) == expected


def _two_boxes_glb(path, colours) -> None:
    """Two boxes, each with a PBR material named "Material" of the given base colour (one shared
    object where the colours are the same object)."""
    from trimesh.visual.material import PBRMaterial
    scene = trimesh.Scene()
    materials = {}
    for k, colour in enumerate(colours):
        box = trimesh.creation.box()
        box.apply_translation([3.0 * k, 0.0, 0.0])
        material = materials.setdefault(id(colour), PBRMaterial(name="Material", baseColorFactor=colour))
        box.visual = TextureVisuals(uv=np.random.default_rng(k).random((len(box.vertices), 2)), material=material)
        scene.add_geometry(box, geom_name=f"box{k}")
    scene.export(path)


def test_glb_materials_that_differ_but_share_a_name_stay_apart(tmp_path):
    """glTF names need not be unique: two materials called "Material", red and blue, were one
    material (the blue box drawn with the red one's, no seam); one material two primitives
    share stays one."""
    red, blue = [255, 0, 0, 255], [0, 0, 255, 255]
    _two_boxes_glb(tmp_path / "two.glb", [red, blue])
    src = load_mesh_file(tmp_path / "two.glb")
    check_contract(src)
    assert src.materials == ["Material", "Material #2"]
    assert sorted(np.bincount(src.face_material).tolist()) == [12, 12]
    assert any("'Material'" in n and "shared by materials that differ" in n for n in src.notes)
    _two_boxes_glb(tmp_path / "one.glb", [red, red])
    src = load_mesh_file(tmp_path / "one.glb")
    assert src.materials == ["Material"] and not any("differ" in n for n in src.notes)


def test_glb_scene_transforms_instances_and_mirroring(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box()
    scene.add_geometry(box, geom_name="plain", node_name="a",
                       transform=trimesh.transformations.translation_matrix([5, 0, 0]))
    scene.add_geometry(box.copy(), geom_name="mirrored", node_name="b",
                       transform=np.diag([-2.0, 1.0, 1.0, 1.0]))
    path = tmp_path / "scene.glb"
    scene.export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.faces) == 24 and len(src.positions) == 16
    assert sorted(src.materials) == ["mirrored", "plain"]
    # the mirrored, doubled box still faces outwards: volume 1 + 2
    assert signed_volume(src) == pytest.approx(3.0)
    assert src.positions[:, 0].max() == pytest.approx(5.5)
    assert src.positions[:, 0].min() == pytest.approx(-1.0)


def test_stl_welds_face_soup(tmp_path):
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.positions) == 8 and len(src.vertex_position) == 8 and len(src.faces) == 12
    assert src.vertex_normal is None and src.vertex_uv is None and src.vertex_color is None
    assert signed_volume(src) == pytest.approx(1.0)


def test_ascii_off(tmp_path):
    path = write_text(tmp_path, "tet.off", (
        "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
        "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"
    ))
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.positions) == 4 and len(src.faces) == 4
    assert src.materials == ["tet"]
    assert signed_volume(src) == pytest.approx(1 / 6)


def test_off_export_roundtrip(tmp_path):
    path = tmp_path / "box.off"
    trimesh.creation.box().export(path)
    src = load_mesh_file(path)
    check_contract(src)
    assert len(src.positions) == 8 and len(src.faces) == 12


# --------------------------------------------------------------------------
# unreadable files
# --------------------------------------------------------------------------


def exported_bytes(tmp_path: Path, ext: str) -> bytes:
    path = tmp_path / f"whole.{ext}"
    trimesh.creation.icosphere(subdivisions=2).export(path)
    return path.read_bytes()


@pytest.mark.parametrize("name", ["empty.obj", "empty.stl", "empty.ply", "empty.off", "empty.glb"])
def test_empty_file_is_refused(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"")
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert_one_line_error(excinfo, path)


@pytest.mark.parametrize("ext", ["ply", "stl", "glb"])
def test_truncated_binary_file_is_refused(tmp_path, ext):
    data = exported_bytes(tmp_path, ext)
    assert ext != "ply" or b"binary" in data[:200]
    path = tmp_path / f"truncated.{ext}"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert_one_line_error(excinfo, path)


@pytest.mark.parametrize("ext", ["ply", "stl", "glb", "obj", "off"])
def test_garbage_bytes_are_refused(tmp_path, ext):
    path = tmp_path / f"garbage.{ext}"
    path.write_bytes(np.random.default_rng(1).bytes(777))
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert_one_line_error(excinfo, path)


def test_missing_file_is_refused(tmp_path):
    path = tmp_path / "nowhere" / "missing.obj"
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert "not found" in assert_one_line_error(excinfo, path)


def test_directory_is_refused(tmp_path):
    path = tmp_path / "adir.obj"
    path.mkdir()
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert_one_line_error(excinfo, path)


@pytest.mark.parametrize("name", ["mesh.xyz123", "mesh", "mesh.txt"])
def test_unknown_format_is_refused(tmp_path, name):
    path = write_text(tmp_path, name, "v 0 0 0\n")
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    assert "unknown mesh format" in assert_one_line_error(excinfo, path)


def test_accepts_str_and_pathlike(tmp_path):
    path = write_cube_obj(tmp_path)
    a = load_mesh_file(str(path))
    b = load_mesh_file(path)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.positions, b.positions)


# --------------------------------------------------------------------------
# source_from_trimesh
# --------------------------------------------------------------------------


def tetra(**kwargs) -> trimesh.Trimesh:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return trimesh.Trimesh(vertices, faces, process=False, **kwargs)


def test_trimesh_without_normals_gives_none_and_is_not_modified():
    mesh = tetra()
    before = mesh.vertices.copy()
    src = source_from_trimesh(mesh, name="tet")
    check_contract(src)
    assert src.vertex_normal is None
    assert src.materials == ["tet"]
    assert "vertex_normals" not in mesh._cache  # we did not compute them
    np.testing.assert_array_equal(mesh.vertices, before)


def test_trimesh_normals_are_renormalised_float32():
    normals = np.array([[0, 0, 2.0], [3.0, 0, 0], [0, 1.0, 0], [1, 1, 1.0]])
    src = source_from_trimesh(tetra(vertex_normals=normals))
    check_contract(src)
    assert src.vertex_normal.dtype == np.float32
    expected = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    np.testing.assert_allclose(src.vertex_normal, expected, atol=1e-7)
    assert "renormalised 3 vertex normals that were not unit length" in src.notes


@pytest.mark.parametrize("bad, word", [(0.0, "zero length"), (np.nan, "NaN"), (np.inf, "NaN")])
def test_unusable_normals_are_dropped_with_a_note(bad, word):
    normals = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0], [bad, bad, bad]])
    src = source_from_trimesh(tetra(vertex_normals=normals))
    check_contract(src)
    assert src.vertex_normal is None
    assert any(word in n and "1 " in n for n in src.notes)


def test_nonfinite_uv_is_refused():
    mesh = tetra()
    mesh.visual = TextureVisuals(uv=np.array([[0, 0], [1, 0], [np.nan, 1], [1, 1.0]]))
    with pytest.raises(InputError) as excinfo:
        source_from_trimesh(mesh, name="tet")
    assert "1 vertices" in str(excinfo.value) and "texture" in str(excinfo.value)


def test_identical_vertices_merge_but_seams_stay():
    # vertex 4 repeats vertex 0 exactly (same uv): merged; vertex 5 repeats
    # vertex 0's position with another uv: a seam, kept.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0], [0, 0, 0]], float)
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0, 0], [0.5, 0.5]])
    faces = np.array([[0, 2, 1], [4, 1, 3], [5, 3, 2], [1, 2, 3]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.visual = TextureVisuals(uv=uv)
    src = source_from_trimesh(mesh)
    check_contract(src)
    assert len(src.positions) == 4
    assert len(src.vertex_position) == 5
    assert src.faces[0, 0] == src.faces[1, 0]
    assert src.faces[2, 0] != src.faces[0, 0]
    assert src.vertex_position[src.faces[2, 0]] == src.vertex_position[src.faces[0, 0]]


def test_scene_with_partial_attributes_fills_and_notes():
    textured = tetra()
    textured.visual = TextureVisuals(uv=np.zeros((4, 2)) + 0.25)
    with_normals = tetra(vertex_normals=np.tile([0, 0, 1.0], (4, 1)))
    scene = trimesh.Scene()
    scene.add_geometry(textured, geom_name="t", transform=np.eye(4))
    scene.add_geometry(with_normals, geom_name="n",
                       transform=trimesh.transformations.translation_matrix([3, 0, 0]))
    src = source_from_trimesh(scene)
    check_contract(src)
    assert src.vertex_normal is None
    assert src.vertex_uv is not None
    assert any("only 1 of 2 geometries" in n for n in src.notes)
    assert any("4 vertices without texture coordinates" in n for n in src.notes)


def test_instanced_geometry_shares_one_material():
    scene = trimesh.Scene()
    scene.add_geometry(tetra(), geom_name="tet", node_name="n0")
    for k in (1, 2):  # two more nodes instancing the same geometry
        scene.graph.update(frame_to=f"n{k}", geometry="tet",
                           matrix=trimesh.transformations.translation_matrix([2 * k, 0, 0]))
    assert len(scene.geometry) == 1
    scene.add_geometry(tetra(), geom_name="other", node_name="o",
                       transform=trimesh.transformations.translation_matrix([0, 5, 0]))
    src = source_from_trimesh(scene)
    check_contract(src)
    assert len(src.faces) == 16 and len(src.positions) == 16
    assert sorted(src.materials) == ["other", "tet"]
    assert np.bincount(src.face_material).tolist() in ([12, 4], [4, 12])


def test_normals_follow_non_uniform_scale():
    normals = np.array([[1, 1, 0.0], [1, 1, 0], [1, 1, 0], [1, 1, 0]]) / np.sqrt(2)
    scene = trimesh.Scene()
    scene.add_geometry(tetra(vertex_normals=normals), geom_name="t",
                       transform=np.diag([2.0, 1.0, 1.0, 1.0]))
    src = source_from_trimesh(scene)
    # inverse transpose: (1, 1, 0) under x*2 becomes (0.5, 1, 0), normalised
    expected = np.array([0.5, 1.0, 0.0]) / np.linalg.norm([0.5, 1.0, 0.0])
    np.testing.assert_allclose(src.vertex_normal, np.tile(expected, (len(src.vertex_normal), 1)),
                               atol=1e-6)


def test_not_a_mesh_is_refused():
    with pytest.raises(InputError):
        source_from_trimesh([[0, 0, 0]], name="list")
    with pytest.raises(InputError) as excinfo:
        source_from_trimesh(trimesh.PointCloud(np.random.default_rng(0).random((5, 3))), name="pc")
    assert "no triangles" in str(excinfo.value)


def test_hash_collisions_fall_back_to_exact_grouping(monkeypatch, tmp_path):
    path = write_cube_obj(tmp_path)
    reference = load_mesh_file(path)
    monkeypatch.setattr(meshfile, "_hash_words", lambda words: np.zeros(len(words), np.uint64))
    collided = load_mesh_file(path)
    check_contract(collided)
    for name in ("positions", "vertex_position", "faces", "face_material",
                 "vertex_normal", "vertex_uv"):
        np.testing.assert_array_equal(getattr(collided, name), getattr(reference, name))


def test_group_equal_rows_numbers_by_first_appearance():
    rows = np.array([[3, 1], [2, 2], [3, 1], [0, 0], [2, 2]], dtype=np.int64)
    group, first = meshfile._group_equal_rows(rows)
    assert group.tolist() == [0, 1, 0, 2, 1]
    assert first.tolist() == [0, 1, 3]


def test_clean_mesh_keeps_its_numbering():
    mesh = tetra()
    src = source_from_trimesh(mesh)
    np.testing.assert_array_equal(src.positions, mesh.vertices)
    np.testing.assert_array_equal(src.faces, mesh.faces)
    np.testing.assert_array_equal(src.vertex_position, np.arange(4))


# --------------------------------------------------------------------------
# property: OBJ export/import keeps the triangles
# --------------------------------------------------------------------------

coordinate = st.integers(min_value=-3, max_value=3).map(float)


@st.composite
def small_meshes(draw):
    n = draw(st.integers(min_value=3, max_value=12))
    vertices = draw(st.lists(st.tuples(coordinate, coordinate, coordinate), min_size=n, max_size=n))
    index = st.integers(min_value=0, max_value=n - 1)
    faces = draw(st.lists(st.tuples(index, index, index), min_size=1, max_size=20))
    return np.array(vertices, dtype=float), np.array(faces, dtype=np.int64)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(small_meshes())
def test_obj_roundtrip_keeps_triangles(tmp_path_factory, mesh):
    vertices, faces = mesh
    directory = tmp_path_factory.mktemp("prop")
    path = directory / "random.obj"
    trimesh.Trimesh(vertices, faces, process=False).export(path)

    tri = vertices[faces]
    proper = ~((tri[:, 0] == tri[:, 1]).all(1) | (tri[:, 1] == tri[:, 2]).all(1)
               | (tri[:, 2] == tri[:, 0]).all(1))
    expected = canonical_triangles(tri[proper])
    if not expected:
        with pytest.raises(InputError):
            load_mesh_file(path)
        return
    src = load_mesh_file(path)
    check_contract(src)
    got = src.positions[src.face_positions]
    assert canonical_triangles(got) == expected
    assert len(src.faces) == len(expected)  # duplicates dropped, nothing else
    assert len(src.positions) == len({tuple(v) for v in tri[proper].reshape(-1, 3).tolist()})


# --------------------------------------------------------------------------
# coordinates float32 cannot hold, and what readers print (issue 17, item 4)
# --------------------------------------------------------------------------


@pytest.mark.parametrize("far", ["1e39", "-1e39", "1e30", "4.7e18"])
def test_far_vertices_are_refused_with_their_count(tmp_path, far):
    path = write_text(tmp_path, "far.obj", f"v {far} 0 0\nv 0 1 0\nv 0 0 {far}\nv 1 1 1\nf 1 2 3\nf 2 4 3\n")
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    message = assert_one_line_error(excinfo, path)
    assert "2 vertices" in message and "4.6e+18" in message and "float32" in message


def test_far_vertices_exit_2_in_one_line_without_warnings(tmp_path, capsys):
    """OBJ at 1e39 (beyond float32) and at 1e30 (an extent whose squares overflow float32)."""
    for far in ("1e39", "1e30"):
        path = write_text(tmp_path, "far.obj", f"v {far} 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n")
        code, err = build_cli(capsys, path)
        assert code == 2 and "beyond +-4.6e+18" in err and "Warning" not in err, err


def test_vertices_within_the_limit_build(tmp_path, capsys):
    """Just inside +-2**62 the stored positions and bounds are finite float32."""
    path = write_text(tmp_path, "near.obj", "v 4e18 0 0\nv 0 4e18 0\nv 0 0 -4e18\nv 1 1 1\nf 1 2 3\nf 2 4 3\n")
    code, err = build_cli(capsys, path)
    assert code == 0, err


def test_a_mesh_far_from_the_origin_for_its_size_is_refused(tmp_path, capsys):
    """1 unit of detail 1e9 from the origin: float32 (step 64 there) would
    store every face as a point; the build says so and what to do."""
    path = write_text(tmp_path, "offset.obj", (
        "v 1e9 1e9 1e9\nv 1000000001 1e9 1e9\nv 1e9 1000000001 1e9\nv 1000000001 1000000001 1e9\n"
        "f 1 2 3\nf 2 4 3\n"))
    code, err = build_cli(capsys, path)
    assert code == 2 and "2 of 2 faces" in err and "float32" in err and "--weld" in err, err


def test_near_duplicates_float32_merges_are_refused_then_welded(tmp_path, capsys):
    """Two positions 1e-8 apart near 1: one face collapses in float32; the
    suggested --weld merges them and the mesh builds."""
    path = write_text(tmp_path, "dup.obj", "v 0 0 0\nv 1 0 0\nv 1.00000001 0 0\nv 0 1 0\nf 1 2 4\nf 2 3 4\n")
    code, err = build_cli(capsys, path)
    assert code == 2 and "1 of 2 faces" in err, err
    weld = err.split("--weld ")[1].split()[0]
    code, err = build_cli(capsys, path, f"--weld={weld}")
    assert code == 0, err


@pytest.mark.parametrize("tolerance", ["1e-320", "1e-30"])
def test_weld_finer_than_float64_resolves_is_refused(tmp_path, capsys, tolerance):
    path = write_cube_obj(tmp_path)
    code, err = build_cli(capsys, path, f"--weld={tolerance}")
    assert code == 2 and "finer than float64" in err, err


def test_far_texture_coordinates_are_refused(tmp_path):
    path = write_text(tmp_path, "uv.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1e39 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(InputError) as excinfo:
        load_mesh_file(path)
    message = assert_one_line_error(excinfo, path)
    assert "1 vertices" in message and "texture coordinates" in message and "float32" in message


def test_huge_normals_are_renormalised(tmp_path, capsys):
    """Squaring 1e300 overflows; the directions are still good."""
    path = write_text(tmp_path, "normals.obj", (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1e300\nvn 1e300 0 1e300\nvn 0 1e300 1e300\nf 1//1 2//2 3//3\n"))
    src = load_mesh_file(path)
    check_contract(src)
    half = np.sqrt(0.5)
    np.testing.assert_allclose(src.vertex_normal, [[0, 0, 1], [half, 0, half], [0, half, half]], atol=1e-7)
    assert "renormalised 3 vertex normals" in " ".join(src.notes)
    assert build_cli(capsys, path)[0] == 0


def test_tiny_normals_count_as_zero_length(tmp_path, capsys):
    """Squaring 1e-300 underflows to 0: no division by zero, the normals are dropped with a note."""
    path = write_text(tmp_path, "normals.obj", (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1e-300\nvn 0 0 1\nvn 0 0 1\nf 1//1 2//2 3//3\n"))
    src = load_mesh_file(path)
    assert src.vertex_normal is None and "1 have zero length" in " ".join(src.notes)
    assert build_cli(capsys, path)[0] == 0


def _glb_with_node(tmp_path, **node_fields) -> Path:
    """A box GLB whose scene node carries ``node_fields`` (a matrix, scale, ...)."""
    from fuzzsources import _glb, _glb_chunks
    import json
    data = trimesh.Scene(box_with_uv()).export(file_type="glb")
    doc, binary = _glb_chunks(data)
    doc = json.loads(doc)
    doc["nodes"][-1].update(node_fields)
    path = tmp_path / "node.glb"
    path.write_bytes(_glb(json.dumps(doc).encode(), binary))
    return path


@pytest.mark.parametrize("fields", [{"matrix": [float("nan")] + [0.0] * 15}, {"rotation": [float("nan"), 0, 0, 1]},
                                    {"matrix": [float("inf")] + [0.0] * 15}])
def test_a_nonfinite_node_transform_is_refused_by_name(tmp_path, capsys, fields):
    path = _glb_with_node(tmp_path, **fields)
    code, err = build_cli(capsys, path)
    assert code == 2 and "scene node" in err and "transform" in err, err


def test_a_huge_node_transform_is_refused_without_warnings(tmp_path, capsys):
    path = _glb_with_node(tmp_path, matrix=[1e300] * 16)
    code, err = build_cli(capsys, path)
    assert code == 2 and "vertices have" in err and "coordinates" in err, err


def test_a_singular_node_transform_drops_the_normals(tmp_path):
    box = trimesh.creation.box()
    box.vertex_normals                              # cached: the GLB carries them
    scene = trimesh.Scene()
    scene.add_geometry(box, transform=np.diag([1.0, 1.0, 0.0, 1.0]))
    src = source_from_trimesh(scene)
    assert src.vertex_normal is None
    assert any("singular" in note for note in src.notes)


def test_what_trimesh_logs_while_reading_is_silenced(tmp_path, caplog):
    """A broken ASCII STL makes trimesh log a traceback ('failed to extract
    face_normals'); the user gets the one-line error only."""
    box = trimesh.creation.box()
    text = trimesh.exchange.stl.export_stl_ascii(box)
    path = write_text(tmp_path, "broken.stl", text.replace("facet normal", "facet normal 1,5", 1))
    with caplog.at_level("DEBUG"):
        try:
            load_mesh_file(path)
        except InputError:
            pass
    assert not [r for r in caplog.records if r.name.startswith("trimesh")], caplog.text


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**31), st.integers(1, 300), st.integers(2, 12), st.integers(1, 3))
def test_duplicate_faces_match_an_obvious_reference(seed, p, e, n_materials):
    """The hashing kernel against a dictionary: the first face of each (cyclic rotation, material)
    is kept, a reversed winding is another face; few positions make many repeats."""
    rng = np.random.default_rng(seed)
    faces = np.stack([rng.permutation(e)[:3] for _ in range(p)]) if e >= 3 else np.zeros((0, 3), int)
    material = rng.integers(0, n_materials, len(faces))
    seen, expected = set(), []
    for (a, b, c), m in zip(faces.tolist(), material.tolist()):
        k = min((a, b, c), (b, c, a), (c, a, b)), m
        expected.append(k not in seen)
        seen.add(k)
    assert meshfile._first_of_duplicate_faces(faces, material).tolist() == expected


def test_a_million_copies_of_one_triangle_take_linear_time():
    faces = np.tile([[0, 1, 2], [1, 2, 0], [2, 1, 0]], (400_000, 1))
    keep = meshfile._first_of_duplicate_faces(faces, np.zeros(len(faces), np.int64))
    assert keep.sum() == 2 and keep[0] and keep[2]


@pytest.mark.parametrize("uv, mtl, words", [
    (True, False, "takes them as one material"), (False, False, "names them after its geometries"),
    (True, True, None)])
def test_an_obj_whose_materials_are_not_defined_says_so(tmp_path, uv, mtl, words):
    """Without its .mtl, trimesh reads an OBJ's usemtl materials with texture coordinates as one
    (the seam between them lost): the report says so and what to do."""
    lines = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0"]
    if uv:
        lines += ["vt 0 0", "vt 1 0", "vt 0 1", "vt 1 1"]
    if mtl:
        lines.insert(0, "mtllib m.mtl")
        (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    corner = (lambda i: f"{i}/{i}") if uv else str
    lines += ["usemtl red", f"f {corner(1)} {corner(2)} {corner(3)}", "usemtl blue", f"f {corner(2)} {corner(4)} "
              f"{corner(3)}"]
    (tmp_path / "x.obj").write_text("\n".join(lines) + "\n")
    source = load_mesh_file(tmp_path / "x.obj")
    notes = [n for n in source.notes if "not defined" in n]
    if words is None:
        assert not notes and sorted(source.materials) == ["blue", "red"]
    else:
        assert len(notes) == 1 and words in notes[0] and "2 of its 2 materials (blue, red)" in notes[0]


def test_obj_scan_sees_a_line_at_every_block_boundary(tmp_path, monkeypatch):
    """The scan's patterns start at a newline: a block's first line (left over from the last
    block's cut) went unseen, so a file whose one relative face began a block was read by
    trimesh as it was (found by a review). Every block size finds it now."""
    from caveclod.builder import objtext
    lines = [f"v {i} {i % 3} 0" for i in range(12)] + ["f -3 -2 -1"] + [f"v {i} 1 1" for i in range(6)]
    path = write_text(tmp_path, "one.obj", "\n".join(lines) + "\n")
    for size in range(8, 140, 3):
        monkeypatch.setattr(objtext, "_BLOCK", size)
        text, notes = objtext.normalized_obj(path)
        assert text is not None and any("1 of its 1 faces use relative" in n for n in notes), size
    tabbed = write_text(tmp_path, "tab.obj", "v 0 0 0\n" + "\n".join(lines[1:12]) + "\n\tv 5 5 5\n")
    for size in range(8, 140, 3):
        monkeypatch.setattr(objtext, "_BLOCK", size)
        assert objtext.normalized_obj(tabbed)[0] is not None, size


def test_obj_usemtl_with_a_tab_keeps_its_materials(tmp_path):
    """Lines but geometry kept their tab after the keyword, which trimesh does not read: a file
    rewritten for its tabs lost every material (found by a review)."""
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    text = ("mtllib\tm.mtl\nv\t0 0 0\nv\t1 0 0\nv\t0 1 0\nv\t1 1 0\n"
            "usemtl\tred\nf\t1 2 3\nusemtl\tblue\nf\t2 4 3\n")
    src = load_mesh_file(write_text(tmp_path, "tab.obj", text))
    assert sorted(src.materials) == ["blue", "red"] and len(src.faces) == 2
