"""Build a :class:`StaticMesh` from a :class:`SourceMesh`.

The pipeline, each step a module of its own::

    normals (crease angle) -> topology -> surface groups & vertex buffer
        -> leaf bounds -> passes of collapses -> static arrays
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .kernels.bounds import empty_cones, empty_spheres
from .kernels.simplify import gather_candidates, init_leaves, perform_collapses, rank_collapses
from .normals import add_crease_normals
from .progress import Progress, stage
from .source import SourceMesh
from .staticmesh import StaticMesh
from .surfaces import RIGID, corner_vertices, layout_surfaces
from .topology import Topology, count_components, face_neighbours

PASS_FRACTION = 0.5   # share of ranked collapses a pass may make (shallower tree)


def build_static_mesh(source: SourceMesh, crease_angle: float = 30.0, progress: bool = False) -> StaticMesh:
    """Run the whole offline build; see the module docstring."""
    t0 = time.perf_counter()
    source.validate()
    stage(f"preparing {len(source.faces):,} triangles: normals, topology, surface groups", progress)
    source, topo = prepare_source(source, crease_angle)
    e, p = len(source.positions), len(source.faces)
    face_pos = source.face_positions.astype(np.int32)
    face_vertex = source.faces.astype(np.int32)
    lay = layout_surfaces(face_pos, face_vertex, source.face_material, topo.nbrs, topo.nonmanifold, e)

    P = np.ascontiguousarray(source.positions, dtype=np.float64)
    F = face_pos.copy()
    N = topo.nbrs.copy()
    vface = np.empty(e, np.int32)
    Q = np.zeros((e, 10))
    sphere, cone = empty_spheres(2 * e), empty_cones(2 * e)
    err = np.zeros(2 * e)
    init_leaves(P, F, N, lay.face_group, vface, Q, sphere, cone)

    alive = np.ones(p, bool)
    cur_node = np.arange(e, dtype=np.int32)
    parent = np.full(2 * e, -1, np.int32)
    child = np.full((e, 2), -1, np.int32)
    npos = np.full(e, -1, np.int32)
    nfaces = np.full((e, 2), -1, np.int32)
    nfn = np.full((e, 4), -1, np.int32)
    creator = np.full(p, -1, np.int32)
    lock = np.full(e, -1, np.int64)
    # Ranking runs on several threads (the kernels release the GIL), each
    # over its own range of positions with its own scratch marks.
    workers = max(1, min(os.cpu_count() or 1, 4))
    bounds_of = np.linspace(0, e, workers + 1).astype(np.int64)
    marks = [np.full(e, -1, np.int64) for _ in range(workers)]
    counters = [np.zeros(1, np.int64) for _ in range(workers)]
    best_t = np.full(e, -1, np.int32)
    best_c = np.zeros(e)
    cost, target, src = np.empty(e), np.empty(e, np.int32), np.empty(e, np.int32)
    pg_start = lay.pos_vstart
    pg_groups = lay.vertex_group
    fixed = topo.nonmanifold.copy()
    movable = int(np.count_nonzero((lay.position_class != RIGID) & ~fixed))

    bar = Progress("collapsing", total=max(movable, 1), enabled=progress)
    m, pass_id = 0, 0
    with ThreadPoolExecutor(workers) as pool:
        while True:
            before = m
            jobs = [pool.submit(rank_collapses, P, F, N, vface, lay.face_group, lay.position_class,
                                fixed, pg_start, pg_groups, Q, lock, marks[i], best_t, best_c,
                                pass_id, bounds_of[i], bounds_of[i + 1], counters[i])
                    for i in range(workers)]
            for job in jobs:
                job.result()
            nc = gather_candidates(vface, best_t, best_c, cost, target, src)
            m = perform_collapses(P, F, N, vface, alive, lay.face_group, lay.position_class, fixed,
                                  pg_start, pg_groups, Q, cur_node, parent, child, npos, nfaces, nfn,
                                  sphere, cone, err, creator, m, lock, marks[0], pass_id,
                                  PASS_FRACTION, cost, target, src, nc, counters[0])
            pass_id += 1
            bar.update(m)
            if m == before:
                break
    bar.close()

    n = e + m
    base = np.flatnonzero(alive).astype(np.int32)
    vsrc = lay.vertex_source
    vpos = source.vertex_position[vsrc]
    d = len(vsrc)
    uv = source.vertex_uv[vsrc] if source.vertex_uv is not None else np.zeros((d, 2), np.float32)
    colors = source.vertex_color[vsrc] if source.vertex_color is not None else np.zeros((0, 4), np.uint8)
    small = np.uint16 if max(lay.n_sgids, len(source.materials)) <= 65535 else np.uint32
    vertex_surface = np.empty(d, np.int64)
    corners = corner_vertices(lay.pos_vstart, lay.vertex_sgid, face_pos, lay.face_sgid)
    vertex_surface[corners.ravel()] = np.repeat(source.face_material, 3)
    arrays = {
        "vertex_positions": P[vpos].astype(np.float32),
        "vertex_normals": source.vertex_normal[vsrc].astype(np.float32),
        "vertex_uvs": uv.astype(np.float32),
        "vertex_colors": colors.astype(np.uint8),
        "vertex_sgid": lay.vertex_sgid.astype(small),
        "vertex_surface": vertex_surface.astype(small),
        "pos_vstart": lay.pos_vstart.astype(np.int32),
        "position_class": lay.position_class,
        "face_material": source.face_material.astype(small),
        "face_sgid": lay.face_sgid.astype(small),
        "face_creator": creator,
        "node_parent": parent[:n].copy(),
        "node_links": np.c_[child[:m], nfaces[:m], nfn[:m]].astype(np.int32),
        "node_position": npos[:m].copy(),
        "node_bound": np.c_[_round_spheres(sphere[e:n], P), _round_up(err[e:n])],
        "node_cone": _round_cones(cone[e:n]),
        "base_faces": base,
        "base_face_nodes": cur_node[F[base]].astype(np.int32),
        "base_face_nbrs": N[base].astype(np.int32),
    }
    mesh = StaticMesh(arrays=arrays, materials=list(source.materials))
    mesh.info = {
        "build_seconds": round(time.perf_counter() - t0, 3),
        "input_triangles": p,
        "passes": pass_id,
        "surface_groups": lay.n_groups,
        "classes": mesh.class_tally(),
        "base_mesh": _base_mesh_reasons(len(base), p, topo),
        "notes": list(source.notes),
    }
    if mesh.info["base_mesh"]["large"]:
        mesh.info["notes"].append(mesh.info["base_mesh"]["why"])
    return mesh


def _base_mesh_reasons(base: int, p: int, topo: Topology) -> dict:
    """What keeps the base mesh from shrinking further, for the report.

    The issue's bound: at most 1% of the faces or 300, whichever is larger.
    Every piece of the mesh keeps a face; non-manifold positions never move;
    RIGID positions (seam corners and crossings) never float.
    """
    components = int(count_components(topo.nbrs))
    pinned = int(np.count_nonzero(topo.nonmanifold))
    large = base > max(0.01 * p, 300)
    why = (f"base mesh is {base:,} faces ({100 * base / p:.1f}% of {p:,}): the mesh has {components:,} "
           f"separate pieces (each keeps at least one face) and {pinned:,} non-manifold positions that never "
           f"move; seam corners (RIGID positions) stay too")
    return {"faces": base, "components": components, "nonmanifold_positions": pinned, "large": large,
            "why": why}


def prepare_source(source: SourceMesh, crease_angle: float = 30.0) -> tuple[SourceMesh, Topology]:
    """The source as the build sees it: with normals, and its topology.

    Returns ``(source_with_normals, topology)``; a source that has normals
    comes back unchanged. Tests use it to know the exact input corners.
    """
    topo = face_neighbours(source.face_positions.astype(np.int32), len(source.positions))
    if source.vertex_normal is None:
        source = add_crease_normals(source, crease_angle, topo)
    return source, topo


def _round_up(x: np.ndarray) -> np.ndarray:
    """float32 copy of ``x`` rounded towards +inf (bounds stay bounds)."""
    y = x.astype(np.float32)
    low = y.astype(np.float64) < x
    y[low] = np.nextafter(y[low], np.float32(np.inf))
    return y


def _round_spheres(s: np.ndarray, P: np.ndarray) -> np.ndarray:
    """float32 spheres, radii padded by the rounding of float32 centres."""
    out = s.astype(np.float32)
    scale = float(np.abs(P).max(initial=1.0))
    pad = 4.0 * np.finfo(np.float32).eps * scale
    out[:, 3] = _round_up(s[:, 3] + pad)
    return out


def _round_cones(c: np.ndarray) -> np.ndarray:
    out = c.astype(np.float32)
    out[:, 3] = _round_up(np.minimum(c[:, 3] + 1e-6, np.pi))
    return out
