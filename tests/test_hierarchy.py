"""The static CAVECLOD mesh: the build's invariants on realistic meshes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import caveclod
from caveclod.builder.hierarchy import build_static_mesh, prepare_source
from caveclod.builder.surfaces import corner_vertices
from caveclod.builder.builtin import default_terrain, range_scan, rough_heights
from caveclod.builder.source import SourceMesh

from meshes import holey_scan, noisy_box, random_heightfield, random_scan, replay_collapses, uv_sphere, with_bad_topology

CASES = {
    "terrain64": lambda: default_terrain(64),
    "uv_sphere": uv_sphere,
    "noisy_box": noisy_box,
    "holey_scan": holey_scan,
    "bad_topology": lambda: with_bad_topology(holey_scan(seed=3)),
    # Tiled builds: tiles simplified with fixed borders, then merged (caveclod.builder.tiles).
    "terrain64_tiles4": lambda: default_terrain(64),
    "holey_scan_tiles2": holey_scan,
    "noisy_box_tiles4": noisy_box,
}


@pytest.fixture(scope="module", params=sorted(CASES))
def built(request):
    source = CASES[request.param]()
    tiles = int(request.param.rsplit("_tiles", 1)[1]) if "_tiles" in request.param else None
    return request.param, source, build_static_mesh(source, tiles=tiles)


def test_replay_reference(built):
    """Every collapse is legal and every face is made by one split or is base."""
    _, source, mesh = built
    replay_collapses(mesh, source)


def test_every_face_exactly_once(built):
    _, source, mesh = built
    creator = np.asarray(mesh.face_creator)
    made = np.asarray(mesh.node_faces).ravel()
    made = made[made >= 0]
    assert len(made) == len(np.unique(made)), "no face is made by two splits"
    base = np.asarray(mesh.base_faces)
    assert np.array_equal(np.sort(np.r_[made, base]), np.arange(mesh.n_faces))
    assert (creator[base] == -1).all()
    nodes = np.repeat(np.arange(mesh.n_internal) + mesh.n_positions, 2)
    faces = np.asarray(mesh.node_faces).ravel()
    assert np.array_equal(creator[faces[faces >= 0]], nodes[faces >= 0])


def test_vertex_buffer_holds_every_original_corner(built):
    _, source, mesh = built
    src, _ = prepare_source(source)
    face_pos = src.face_positions
    v = corner_vertices(np.asarray(mesh.pos_vstart), np.asarray(mesh.vertex_sgid), face_pos,
                        np.asarray(mesh.face_sgid))
    assert (v >= 0).all()
    np.testing.assert_array_equal(mesh.vertex_positions[v], src.positions[face_pos].astype(np.float32))
    np.testing.assert_array_equal(mesh.vertex_normals[v], src.vertex_normal[src.faces])
    if src.vertex_uv is not None:
        np.testing.assert_array_equal(mesh.vertex_uvs[v], src.vertex_uv[src.faces])
    assert np.array_equal(mesh.vertex_surface[v], np.repeat(src.face_material[:, None], 3, axis=1))
    # ... and nothing else: every buffer entry is some corner.
    assert len(np.unique(v)) == mesh.n_vertices


def test_bounds_are_monotone_up_the_tree(built):
    _, _, mesh = built
    e = mesh.n_positions
    parent = np.asarray(mesh.node_parent)
    inner = np.arange(e, mesh.n_nodes)
    has_parent = parent[inner] >= 0
    c, p = inner[has_parent] - e, parent[inner][has_parent] - e
    err, sph, cone = (np.asarray(a, np.float64) for a in (mesh.node_error, mesh.node_sphere, mesh.node_cone))
    assert (err >= 0).all()
    assert (err[p] >= err[c]).all(), "a parent's error bound is never below a child's"
    scale = float(np.abs(mesh.vertex_positions).max())
    tol = 1e-5 * scale
    d = np.linalg.norm(sph[p, :3] - sph[c, :3], axis=1)
    assert (d + sph[c, 3] <= sph[p, 3] + tol).all(), "spheres nest"
    # atan2 of |a x b| and a.b: arccos is ill-conditioned for near-equal axes.
    angle = np.arctan2(np.linalg.norm(np.cross(cone[p, :3], cone[c, :3]), axis=1),
                       np.einsum("ij,ij->i", cone[p, :3], cone[c, :3]))
    full = cone[p, 3] >= np.pi - 1e-6
    assert (full | (angle + cone[c, 3] <= cone[p, 3] + 1e-5)).all(), "normal cones nest"
    # Leaves' positions lie inside their parents' spheres.
    leaf = np.arange(e)
    lp = parent[leaf]
    ok = lp >= 0
    dl = np.linalg.norm(mesh.positions[leaf[ok]] - sph[lp[ok] - e, :3], axis=1)
    assert (dl <= sph[lp[ok] - e, 3] + tol).all()
    # A leaf's normal cone (made when its collapse needs it, never stored) is its original faces':
    # every such normal lies inside the cone of the leaf's parent.
    from caveclod.refine.measure import original_triangles
    tri = original_triangles(mesh)
    V = np.asarray(mesh.vertex_positions, np.float64)
    n = np.cross(V[tri[:, 1]] - V[tri[:, 0]], V[tri[:, 2]] - V[tri[:, 0]])
    ln = np.linalg.norm(n, axis=1)
    face, corner = np.nonzero(np.broadcast_to((ln > 1e-9 * scale * scale)[:, None], tri.shape))
    owner = parent[np.asarray(mesh.vertex_position_ids)[tri[face, corner]]]
    face, owner = face[owner >= 0], owner[owner >= 0] - e
    unit = n[face] / ln[face, None]
    angle = np.arctan2(np.linalg.norm(np.cross(cone[owner, :3], unit), axis=1),
                       np.einsum("ij,ij->i", cone[owner, :3], unit))
    assert len(face) and ((cone[owner, 3] >= np.pi - 1e-6) | (angle <= cone[owner, 3] + 1e-4)).all(), \
        "a leaf's original faces lie inside its parent's normal cone"


def test_base_mesh_is_small_for_terrain():
    mesh = build_static_mesh(default_terrain(128))
    assert len(mesh.base_faces) <= max(0.01 * mesh.n_faces, 300), len(mesh.base_faces)


def test_base_mesh_is_small_for_closed_mesh():
    import trimesh
    sphere = trimesh.creation.icosphere(subdivisions=4)     # 5120 faces, no seams
    mesh = caveclod.build(sphere)
    assert len(mesh.base_faces) <= max(0.01 * mesh.n_faces, 300)


def test_static_bytes_within_equation1():
    mesh = build_static_mesh(default_terrain(128))
    assert mesh.nbytes <= mesh.equation1_bytes


def test_rigid_positions_at_corners_of_seams():
    """A seam that meets the border or another seam pins RIGID positions."""
    mesh = build_static_mesh(default_terrain(64))
    tally = mesh.class_tally()
    assert tally["rigid"] > 0 and tally["sharp"] > 0 and tally["free"] > tally["sharp"]


def test_nonmanifold_positions_are_rigid():
    src = with_bad_topology(holey_scan(seed=3))
    mesh = build_static_mesh(src)
    fin_edge = src.face_positions[-1][:2]
    assert (np.asarray(mesh.position_class)[fin_edge] == 2).all()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    rows=st.integers(2, 9), cols=st.integers(2, 9), seed=st.integers(0, 10_000),
    n_classes=st.integers(1, 4), holes=st.floats(0, 0.3), tiles=st.sampled_from([1, 2, 4]),
)
def test_property_random_heightfields(rows, cols, seed, n_classes, holes, tiles):
    """Random small terrains with holes and speckled materials, in tiles or not."""
    source = random_heightfield(rows, cols, seed, n_classes, holes)
    if source is None:
        return                                  # everything fell into holes
    mesh = build_static_mesh(source, tiles=tiles)
    replay_collapses(mesh, source)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), keep=st.floats(0.5, 1.0), crease=st.sampled_from([0.0, 30.0, 90.0]),
       tiles=st.sampled_from([1, 4]))
def test_property_random_scans(seed, keep, crease, tiles):
    """Random subsets of a noisy sphere: holes, islands, slivers, crease seams; in tiles or not."""
    source = random_scan(seed, keep)
    if source is None:
        return
    mesh = build_static_mesh(source, crease_angle=crease, tiles=tiles)
    replay_collapses(mesh, source, crease_angle=crease)


def test_save_load_roundtrip_is_memory_mapped(tmp_path):
    mesh = caveclod.build("default", size=32)
    path = tmp_path / "t.cvc"
    mesh.save(path)
    back = caveclod.load(path)
    assert isinstance(back.node_parent, np.memmap), "arrays are mapped, not read"
    for name, arr in mesh.arrays.items():
        np.testing.assert_array_equal(np.asarray(back.arrays[name]), arr, err_msg=name)
    assert back.content_hash == mesh.content_hash and back.vertex_buffer_hash == mesh.vertex_buffer_hash
    back.verify()
    assert back.summary()["nodes"] == mesh.n_nodes


def test_files_from_before_ring_bounds_load_and_refine_without_the_ring_test(tmp_path):
    """A file without the optional node_ring (written before it) loads and verifies with the same content
    hash (the mesh's identity) and no optional hash; a flipped bit in a newer file's ring bounds fails
    verify; a camera on the older file draws what a camera with the ring test off draws, one with the
    ring test at least as much."""
    from caveclod.staticmesh import OPTIONAL_ARRAYS, StaticMesh
    mesh = caveclod.build("rough", size=64)
    assert "node_ring" in mesh.arrays
    # A file of that time had none of the optional arrays (the derived ones came later still).
    old = StaticMesh(arrays={k: v for k, v in mesh.arrays.items() if k not in OPTIONAL_ARRAYS},
                     materials=mesh.materials)
    # The content hash is the mesh's identity, with or without the optional arrays; they have their own.
    assert old.content_hash == mesh.content_hash and old.optional_hash == "" != mesh.optional_hash
    old.save(tmp_path / "old.cvc")
    back = caveclod.load(tmp_path / "old.cvc")
    assert "node_ring" not in back.arrays and back.content_hash == old.content_hash and back.optional_hash == ""
    back.verify()
    mesh.save(tmp_path / "new.cvc")
    new = caveclod.load(tmp_path / "new.cvc")
    assert new.optional_hash == mesh.optional_hash
    new.verify()
    ring = np.memmap(tmp_path / "new.cvc", mode="r+", dtype=np.uint8)   # a flipped bit in the ring bounds
    at = new.arrays["node_ring"].offset
    ring[at] ^= 1
    ring.flush()
    del ring
    with pytest.raises(caveclod.FileFormatError, match="hash mismatch"):
        caveclod.load(tmp_path / "new.cvc").verify()
    lo, hi = mesh.bounds()
    view = caveclod.View(eye=(lo[0], lo[1], hi[2] + 0.3 * (hi[0] - lo[0])), target=tuple(0.5 * (lo + hi)),
                         tolerance_px=0.5)
    faces = {}
    for label, m in (("back", back), ("old", old), ("new", mesh)):
        cam = m.new_camera()
        for _ in range(8):
            if cam.update(view).operations == 0:
                break
        faces[label] = cam.n_faces
    assert faces["back"] == faces["old"] <= faces["new"], faces


def test_a_file_says_which_build_code_made_it(tmp_path):
    """The build report records the build code's digest; a file without it, with another, a damaged
    one or none at all is not one this checkout would make (the benchmarks' caches build again)."""
    from caveclod.builder.version import build_code, made_by_this_code
    mesh = caveclod.build("default", size=16)
    assert mesh.info["build_code"] == build_code() and len(build_code()) == 16
    mesh.save(tmp_path / "now.cvc")
    assert made_by_this_code(tmp_path / "now.cvc")
    mesh.info["build_code"] = "0" * 16
    mesh.save(tmp_path / "other.cvc")
    del mesh.info["build_code"]
    mesh.save(tmp_path / "before.cvc")
    (tmp_path / "damaged.cvc").write_bytes(b"CAVECLOD" + bytes(7))
    for name in ("other", "before", "damaged", "missing"):
        assert not made_by_this_code(tmp_path / f"{name}.cvc"), name


def test_same_input_same_hash():
    a = caveclod.build("default", size=16)
    b = caveclod.build("default", size=16)
    assert a.content_hash == b.content_hash
    c = caveclod.build("default", size=16, seed=8)
    assert c.content_hash != a.content_hash


@pytest.mark.parametrize("damage", ["truncate", "magic", "version", "header"])
def test_damaged_files_are_refused(tmp_path, damage):
    path = tmp_path / "t.cvc"
    caveclod.build("default", size=16).save(path)
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "magic":
        data[:8] = b"NOTACAVE"
    elif damage == "version":
        data[8] = 99
    else:
        data[20:40] = b"\xff" * 20
    path.write_bytes(bytes(data))
    with pytest.raises(caveclod.FileFormatError) as info:
        caveclod.load(path)
    assert "\n" not in str(info.value)


def test_verify_detects_corruption(tmp_path):
    path = tmp_path / "t.cvc"
    caveclod.build("default", size=16).save(path)
    mesh = caveclod.load(path)
    start = mesh.node_bound.offset        # a byte inside an array (padding is not hashed)
    del mesh
    data = bytearray(path.read_bytes())
    data[start + 5] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(caveclod.FileFormatError):
        caveclod.load(path).verify()


def test_large_base_mesh_says_why():
    """A scan broken into many islands cannot shrink below one face each."""
    import trimesh
    from caveclod.builder.meshfile import source_from_trimesh
    pieces = [trimesh.creation.icosphere(subdivisions=0).apply_translation((3 * i, 0, 0)) for i in range(40)]
    mesh = build_static_mesh(source_from_trimesh(trimesh.util.concatenate(pieces)))
    info = mesh.info["base_mesh"]
    assert info["components"] == 40
    assert info["large"] == (len(mesh.base_faces) > 300)
    small = build_static_mesh(default_terrain(32)).info["base_mesh"]
    assert small["components"] == 1 and not small["large"]


def test_inconsistent_winding_is_named_as_the_base_meshs_cause():
    """Faces wound against their neighbours (a scan exported so) cut their shared edges: a grid
    came out as thousands of "separate pieces" with no word of why; the report counts the edges
    and says what to do. A consistently wound mesh reports none."""
    import trimesh
    from caveclod.builder.meshfile import source_from_trimesh
    grid = trimesh.Trimesh(*_grid(12), process=False)
    flip = np.zeros(len(grid.faces), bool)
    flip[::7] = True
    faces = grid.faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    mesh = build_static_mesh(source_from_trimesh(trimesh.Trimesh(grid.vertices, faces, process=False)))
    info = mesh.info["base_mesh"]
    edges = {}
    for f in faces:
        for k in range(3):
            edges.setdefault((f[k], f[(k + 1) % 3]), []).append(1)
    same_direction = sum(len(v) == 2 for v in edges.values())
    assert info["flipped_edges"] == same_direction > 0
    assert "wound in opposite directions" in info["why"]
    plain = build_static_mesh(source_from_trimesh(grid)).info["base_mesh"]
    assert plain["flipped_edges"] == 0 and "wound" not in plain["why"]


def _grid(n: int):
    """(vertices, faces) of an n x n grid of unit cells, two triangles each, wound alike."""
    y, x = np.mgrid[0:n + 1, 0:n + 1]
    vertices = np.c_[x.ravel(), y.ravel(), np.sin(x.ravel()) * 0.1].astype(np.float64)
    a = (y[:-1, :-1] * (n + 1) + x[:-1, :-1]).ravel()
    faces = np.r_[np.c_[a, a + 1, a + n + 2], np.c_[a, a + n + 2, a + n + 1]]
    return vertices, faces


def test_surface_group_ids_differ_at_every_position(built):
    """Reused ids never meet: each position's vertices carry distinct ids, in order."""
    _, _, mesh = built
    start = np.asarray(mesh.pos_vstart)
    sgid = np.asarray(mesh.vertex_sgid).astype(np.int64)
    same_pos = np.repeat(np.arange(mesh.n_positions), np.diff(start))
    nxt = np.arange(1, len(sgid))
    within = same_pos[nxt] == same_pos[nxt - 1]
    assert (sgid[nxt][within] > sgid[nxt - 1][within]).all()


def test_high_valence_fan_links_like_a_small_one():
    """A fan of 2,000 triangles round one centre (a capped cylinder's lid)."""
    import trimesh
    from caveclod.builder.topology import face_neighbours
    cyl = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=1000)
    faces = cyl.faces.astype(np.int32)
    topo = face_neighbours(faces, len(cyl.vertices))
    # Reference: every undirected edge's faces, by dictionary.
    users = {}
    for f, tri in enumerate(faces):
        for k in range(3):
            a, b = int(tri[k]), int(tri[(k + 1) % 3])
            users.setdefault((min(a, b), max(a, b)), []).append((f, k, a < b))
    for (a, b), fs in users.items():
        for f, k, _ in fs:
            assert topo.edge_faces[f, k] == len(fs)
            if len(fs) == 2 and fs[0][2] != fs[1][2]:
                other = fs[1][0] if fs[0][0] == f else fs[0][0]
                assert topo.nbrs[f, k] == other
            else:
                assert topo.nbrs[f, k] == -1
    mesh = caveclod.build(cyl)
    assert len(mesh.base_faces) <= 300


@settings(max_examples=60, deadline=None)
@given(counts=st.lists(st.integers(0, 4), min_size=0, max_size=40))
def test_each_vertex_s_position_is_the_inverse_of_the_csr(counts):
    """The kernel's table against np.repeat, positions without vertices included."""
    from caveclod.kernels.positions import fill_vertex_positions
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    out = np.full(int(start[-1]), -1, np.int32)
    fill_vertex_positions(start, out)
    assert np.array_equal(out, np.repeat(np.arange(len(counts), dtype=np.int32), counts))


def test_a_damaged_csr_writes_nothing_outside_the_table():
    from caveclod.kernels.positions import fill_vertex_positions
    out = np.full(4, -1, np.int32)
    fill_vertex_positions(np.array([0, 3, 1, -5, 2_000_000_000], np.int32), out)    # back, negative, huge
    assert out.tolist() == [3, 3, 3, 3]          # position 3 claims 0 .. 2e9: clipped to the table


def test_a_built_mesh_s_vertex_positions_follow_its_csr():
    mesh = caveclod.build(holey_scan(), packed=False)
    start = np.asarray(mesh.pos_vstart)
    assert np.array_equal(mesh.vertex_position_ids, np.repeat(np.arange(len(start) - 1), np.diff(start)))


def _rough_mesh(n: int) -> SourceMesh:
    """The rough terrain's relief as a plain mesh without normals (a scan or photogrammetry of it): the
    default crease angle for meshes (30 degrees) applies."""
    h = np.nan_to_num(rough_heights(n), nan=0.0)
    k = h.shape[0]
    ys, xs = np.mgrid[0:k, 0:k]
    idx = np.arange(k * k).reshape(k, k)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.r_[np.c_[a, b, d], np.c_[a, d, c]].astype(np.int32)
    return SourceMesh(positions=np.c_[xs.ravel() * 10.0, ys.ravel() * 10.0, h.ravel()],
                      vertex_position=np.arange(k * k), faces=faces, face_material=np.zeros(len(faces), np.int32), materials=["ground"])


def test_report_names_the_crease_angle_when_roughness_pins_the_base_mesh():
    """On rough relief the default 30 degree crease angle cuts normal seams everywhere, and their
    corners never move: the report says so, with the count smooth normals would leave (exactly what a
    build at 180 degrees has), and what to pass."""
    mesh = build_static_mesh(_rough_mesh(48))
    smooth = build_static_mesh(_rough_mesh(48), crease_angle=180.0)
    base = mesh.info["base_mesh"]
    assert base["rigid_positions"] >= 100 and base["large"]
    assert base["rigid_positions_smooth"] == smooth.class_tally()["rigid"] == 0
    assert "--crease-angle 180" in base["why"] and base["why"] in mesh.info["notes"]
    assert len(smooth.base_faces) < len(mesh.base_faces) / 10


@pytest.mark.parametrize("make", [lambda: range_scan(32), lambda: holey_scan(seed=2), noisy_box, uv_sphere,
                                  lambda: with_bad_topology(holey_scan(seed=3)), lambda: random_scan(4, 0.8)])
def test_smooth_normals_rigid_count_is_what_a_smooth_build_makes(make):
    """The report's count of RIGID positions with smooth normals is the smooth build's own, on meshes
    with UV seams, materials, holes, slivers and non-manifold edges (an input vertex shared by faces
    that do not meet around it is two vertices with smooth normals)."""
    def without_normals():
        src = make()
        src.vertex_normal, src.crease_angle = None, 30.0      # heightfields among them: as a mesh's
        return src
    mesh = build_static_mesh(without_normals())
    smooth = build_static_mesh(without_normals(), crease_angle=180.0)
    assert mesh.info["base_mesh"]["rigid_positions_smooth"] == smooth.class_tally()["rigid"]
    assert smooth.info["base_mesh"]["rigid_positions_smooth"] is None      # a crease angle given: not counted


def test_no_crease_count_for_heightfields_or_given_normals():
    assert build_static_mesh(holey_scan(seed=1)).info["base_mesh"]["rigid_positions_smooth"] is None   # smooth already
    src, _ = prepare_source(uv_sphere())                   # with the normals a build gave it
    assert src.vertex_normal is not None
    assert build_static_mesh(src).info["base_mesh"]["rigid_positions_smooth"] is None
