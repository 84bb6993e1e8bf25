"""Small test meshes that behave like real data, and a reference replay.

The meshes imitate what scans and exports contain: UV seams and poles, hard
normal edges, several materials, holes, slivers, duplicate faces and
non-manifold edges. :func:`replay_collapses` is the slow, obviously-correct
reference for the build: it re-applies every recorded collapse to the
original faces with Python sets and checks each step.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import trimesh

from caveclod.errors import InputError
from caveclod.builder.hierarchy import prepare_source
from caveclod.builder.meshfile import source_from_trimesh
from caveclod.builder.source import SourceMesh
from caveclod.builder.surfaces import RIGID, layout_surfaces
from caveclod.builder.terrain import heightfield_to_source


def uv_sphere(count=(24, 12)) -> SourceMesh:
    """trimesh's UV sphere: a UV seam from pole to pole and fan poles."""
    mesh = trimesh.creation.uv_sphere(radius=1.0, count=count)
    uv = np.c_[mesh.vertices[:, 0] * 0.5 + 0.5, mesh.vertices[:, 2] * 0.5 + 0.5]
    # Split a seam: faces whose x is negative get a shifted copy of the UVs.
    faces = mesh.faces.copy()
    verts = mesh.vertices.copy()
    left = verts[faces].mean(axis=1)[:, 0] < 0
    n = len(verts)
    faces[left] += n
    verts2 = np.r_[verts, verts]
    uv2 = np.r_[uv, uv + [0.5, 0.0]]
    m2 = trimesh.Trimesh(verts2, faces, process=False,
                         visual=trimesh.visual.TextureVisuals(uv=uv2))
    return source_from_trimesh(m2)


def noisy_box(seed=0) -> SourceMesh:
    """A subdivided box with hard edges (crease normals), two materials."""
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.box(extents=(2, 1, 1))
    mesh = mesh.subdivide().subdivide()
    mesh.vertices += rng.normal(0, 0.002, mesh.vertices.shape)
    src = source_from_trimesh(mesh)
    src.vertex_normal = None
    centre = src.positions[src.face_positions].mean(axis=1)
    src.face_material = (centre[:, 0] > 0.3).astype(np.int32)
    src.materials = ["left", "right"]
    return src


def holey_scan(seed=0, n=12) -> SourceMesh:
    """A bumpy heightfield with NaN holes, slivers and three materials."""
    rng = np.random.default_rng(seed)
    h = rng.normal(0, 0.05, (n + 1, n + 1)).cumsum(axis=0).cumsum(axis=1) * 0.2
    h[rng.random(h.shape) < 0.04] = np.nan
    classes = rng.integers(0, 3, (n, n))
    classes[: n // 2] = 0                      # big regions plus speckle
    return heightfield_to_source(h, cell_size=1.0, z_scale=1.0, materials=classes)


def random_heightfield(rows: int, cols: int, seed: int, n_classes: int, holes: float) -> SourceMesh | None:
    """A random small terrain with NaN holes and speckled materials; None
    when every cell falls into a hole."""
    rng = np.random.default_rng(seed)
    h = rng.normal(0, 1, (rows, cols)).cumsum(axis=0)
    h[rng.random(h.shape) < holes] = np.nan
    classes = rng.integers(0, n_classes, (rows - 1, cols - 1))
    try:
        return heightfield_to_source(h, materials=classes)
    except InputError:
        return None


def random_scan(seed: int, keep: float) -> SourceMesh | None:
    """A random subset of a noisy icosphere: holes, islands, slivers; two
    materials at random. None when nothing is kept."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    sphere.vertices += rng.normal(0, 0.05, sphere.vertices.shape)
    faces = sphere.faces[rng.random(len(sphere.faces)) < keep]
    if len(faces) == 0:
        return None
    source = source_from_trimesh(trimesh.Trimesh(sphere.vertices, faces, process=False))
    source.face_material = rng.integers(0, 2, len(source.faces)).astype(np.int32)
    source.materials = ["a", "b"]
    return source


def with_bad_topology(src: SourceMesh) -> SourceMesh:
    """Add a non-manifold fin (a third face on one edge) and a sliver."""
    f0 = src.faces[0]
    p = src.positions
    fin = np.array([p[src.vertex_position[f0[0]]], p[src.vertex_position[f0[1]]]]).mean(axis=0) + [0, 0, 0.5]
    positions = np.r_[p, [fin]]
    vpos = np.r_[src.vertex_position, [len(p)]]
    faces = np.r_[src.faces, [[f0[1], f0[0], len(vpos) - 1]]]
    extra = {}
    for name in ("vertex_normal", "vertex_uv", "vertex_color"):
        a = getattr(src, name)
        extra[name] = None if a is None else np.r_[a, a[:1]]
    return SourceMesh(positions, vpos, faces, np.r_[src.face_material, [0]].astype(np.int32),
                      src.materials, notes=list(src.notes), **extra)


def replay_collapses(mesh, source: SourceMesh, crease_angle=None) -> dict:
    """Re-apply the recorded collapses to ``source``'s faces, checking each.

    Asserts: fl/fr hold both children; every face moves onto a position where
    its own surface group has a vertex; no other face degenerates; floating
    children are never RIGID; creators match; what is left is exactly the
    base mesh. Returns a few counts for the caller.
    """
    source, topo = prepare_source(source, crease_angle)
    face_pos = source.face_positions.astype(np.int64)
    lay = layout_surfaces(face_pos.astype(np.int32), source.faces.astype(np.int32),
                          source.face_material, topo.nbrs, topo.nonmanifold, len(source.positions))
    groups_at = defaultdict(set)
    for f, g in enumerate(lay.face_group):
        for x in face_pos[f]:
            groups_at[int(x)].add(int(g))
    e = mesh.n_positions
    corners = [list(map(int, row)) for row in face_pos]   # leaves are positions
    alive = [True] * len(corners)
    faces_of = defaultdict(set)
    for f, row in enumerate(corners):
        for x in row:
            faces_of[x].add(f)
    children, npos, nfaces = mesh.node_children, mesh.node_position, mesh.node_faces
    cls = mesh.position_class
    creator = mesh.face_creator
    for j in range(mesh.n_internal):
        c = e + j
        t, u = map(int, children[j])
        assert mesh.node_parent[t] == c and mesh.node_parent[u] == c
        pos_t = t if t < e else int(npos[t - e])
        pos_u = u if u < e else int(npos[u - e])
        assert int(npos[j]) == pos_t, "a parent sits at its stationary child's position"
        assert cls[pos_u] != RIGID, "a RIGID position never floats"
        for f in nfaces[j]:
            f = int(f)
            if f < 0:
                continue
            assert alive[f] and t in corners[f] and u in corners[f], "fl/fr hold both children"
            assert creator[f] == c
            alive[f] = False
            for x in corners[f]:
                faces_of[x].discard(f)
        moved = faces_of.pop(t, set()) | faces_of.pop(u, set())
        for f in moved:
            corners[f] = [c if x in (t, u) else x for x in corners[f]]
            assert len(set(corners[f])) == 3, f"face {f} degenerated at node {c}"
            assert int(lay.face_group[f]) in groups_at[pos_t], \
                f"node {c} moved face {f} onto a position where its surface group has no vertex"
        faces_of[c] = moved
    base = sorted(f for f in range(len(corners)) if alive[f])
    assert base == sorted(map(int, mesh.base_faces)), "what is left is the base mesh"
    order = np.argsort(mesh.base_faces)
    got = np.asarray(mesh.base_face_nodes)[order]
    want = np.array([corners[f] for f in base]).reshape(-1, 3)
    assert np.array_equal(np.sort(got, axis=1), np.sort(want, axis=1))
    for f in range(len(corners)):
        if alive[f]:
            assert creator[f] == -1
    return {"base": len(base), "collapses": mesh.n_internal}


def tree_depth(parent) -> int:
    """Longest leaf-to-root path; parents have larger ids than their children."""
    depth = np.zeros(len(parent), np.int64)
    for x in range(len(parent) - 1, -1, -1):
        if parent[x] >= 0:
            assert parent[x] > x
            depth[x] = depth[parent[x]] + 1
    return int(depth.max(initial=0))
