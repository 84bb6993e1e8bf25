"""Renderer-free screen-space error of a camera's LOD mesh.

The refinement promises that the coarse surface a camera shows lies within
``tolerance_px`` pixels of the original, with the pixel size of an
object-space distance ``d`` at distance ``D`` from the eye taken as the
screen-space test takes it (DESIGN.md section 3): ``d * kappa / D``, where
``kappa = viewport_height / (2 tan(fov_y / 2))``.

:func:`pixel_errors` checks that promise from outside: for every original
position inside the view frustum, the exact distance to the nearest triangle
the camera draws (a BVH query over the index buffers' triangles), converted
to pixels. Positions the LOD mesh still uses measure 0. Nothing of the
hierarchy's own bookkeeping is used, only the vertex buffer and the index
buffers a client would hold.
"""

from __future__ import annotations

import numpy as np

from ..kernels.nearest import build_bvh, nearest_dist2
from .view import P_EYE, P_KAPPA, P_PLANES, View


def pixel_errors(mesh, triangles, view: View, points: np.ndarray | None = None) -> np.ndarray:
    """(q,) float64 pixel error of each original position in ``view``'s frustum.

    Args:
        mesh: the :class:`~caveclod.staticmesh.StaticMesh`.
        triangles: the LOD mesh as vertex-buffer indices: a (k, 3) array or
            ``{material: (k, 3)}`` as :meth:`CameraState.triangles` gives.
        view: the view the LOD mesh was refined for.
        points: (q, 3) positions to measure instead of the mesh's own.
    """
    if isinstance(triangles, dict):
        parts = [np.asarray(t).reshape(-1, 3) for t in triangles.values()]
        triangles = np.concatenate(parts) if parts else np.zeros((0, 3), np.int64)
    tri = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    V = np.ascontiguousarray(mesh.vertex_positions, dtype=np.float64)
    P = np.ascontiguousarray(mesh.positions if points is None else points, dtype=np.float64)
    vp = view.params()
    planes = vp[P_PLANES:P_PLANES + 20].reshape(5, 4)
    inside = ((P @ planes[:, :3].T + planes[:, 3]) >= 0.0).all(axis=1)
    P = P[inside]
    if len(P) == 0:
        return np.zeros(0)
    if len(tri) == 0:
        return np.full(len(P), np.inf)
    d2 = nearest_dist2(P, V, tri, *build_bvh(V, tri))
    eye = vp[P_EYE:P_EYE + 3]
    return np.sqrt(d2) * vp[P_KAPPA] / np.maximum(np.linalg.norm(P - eye, axis=1), 1e-300)


def needs_detail(mesh, nodes: np.ndarray, view: View, ring: bool = True) -> np.ndarray:
    """(k,) bool: whether each internal node of ``nodes`` (ids >= ``mesh.n_positions``)
    needs detail for ``view`` by its own test: in the frustum (bounding sphere
    against the five planes), not wholly back-facing (normal cone, when
    enabled), and a screen-space error above the tolerance (its own, or its
    ring bound's at the sphere grown by the reach). The refinement's
    criterion over many nodes at once (``ReferenceCamera.need_refine`` is the
    one-node version, in the same float64 arithmetic). ``ring=False``
    leaves the ring bound out, as a camera with the strict bound does.
    """
    from .view import P_BACKFACE, P_CULL, P_TOL
    p = np.asarray(view.params(), np.float64)
    i = np.asarray(nodes, np.int64) - mesh.n_positions
    sphere = np.asarray(mesh.node_sphere, np.float64)[i]
    cone = np.asarray(mesh.node_cone, np.float64)[i]
    error = np.asarray(mesh.node_error, np.float64)[i]
    cx, cy, cz, r = sphere.T
    need = np.ones(len(i), bool)
    if p[P_CULL] != 0.0:
        for k in range(5):
            nx, ny, nz, d = p[P_PLANES + 4 * k: P_PLANES + 4 * k + 4]
            need &= ~(nx * cx + ny * cy + nz * cz + d < -r)
    dx, dy, dz = cx - p[P_EYE], cy - p[P_EYE + 1], cz - p[P_EYE + 2]
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    if p[P_BACKFACE] != 0.0:
        ax, ay, az, spread = cone.T
        with np.errstate(invalid="ignore", divide="ignore"):
            cosphi = np.clip((ax * dx + ay * dy + az * dz) / length, -1.0, 1.0)
            away = np.arccos(cosphi) + spread + np.arcsin(np.minimum(r / length, 1.0)) < 0.5 * np.pi
        need &= ~((length > r) & (spread < 0.5 * np.pi) & away)
    if p[P_TOL] <= 0.0:
        return need
    dist = length - r
    own = (dist <= 0.0) | (error * p[P_KAPPA] > p[P_TOL] * dist)
    ring = mesh.arrays.get("node_ring") if ring else None
    if ring is not None and len(ring):
        reach, ring_error = np.asarray(ring, np.float64)[i].T
        own |= (ring_error > 0.0) & ((dist - reach <= 0.0) | (ring_error * p[P_KAPPA] > p[P_TOL] * (dist - reach)))
    return need & own


def mixed_nodes(camera) -> np.ndarray:
    """(k,) sorted active internal nodes that stand beside a position collapsed
    away before the node was made: the mixes of ages whose original
    positions the node's error never measured (docs/error-bounds.md). Empty
    for a camera with the strict bound.

    Node ids are in the order the build made them; a position was gone
    before node ``a`` when the parent of its last node
    (:meth:`caveclod.StaticMesh.position_tops`) is older than ``a``.
    """
    mesh = camera.mesh
    e = mesh.n_positions
    tris = [np.asarray(t).reshape(-1, 3) for t in camera.triangles().values()]
    if not tris:
        return np.zeros(0, np.int64)
    pos = mesh.vertex_position_ids[np.concatenate(tris)].astype(np.int64)
    nodes = camera.active_nodes().astype(np.int64)
    node_at = np.full(e, -1, np.int64)
    node_at[mesh.node_positions(nodes)] = nodes
    gone = np.asarray(mesh.node_parent)[mesh.position_tops()[pos]].astype(np.int64)
    gone[gone < 0] = np.iinfo(np.int64).max        # never collapsed away: a root's position
    at = node_at[pos]
    mixed = [at[:, a][(at[:, a] >= e) & (gone[:, b] < at[:, a])] for a in range(3) for b in range(3) if a != b]
    return np.unique(np.concatenate(mixed))


def forced_splits(camera, view: View) -> dict:
    """How much of a camera's mesh its view does not ask for (issue 18's "forced faces").

    A split node whose own test (:func:`needs_detail`) says no is split only
    because a split it does need depends on it (Hoppe's dependencies). Each
    split adds two faces, so ``forced_faces`` = 2 x such nodes: the faces a
    truly selective refinement would not draw. Returns ``split_nodes``,
    ``forced_nodes``, ``faces`` (active), ``forced_faces`` and
    ``forced_share`` (forced faces / faces).
    """
    from ..kernels import refine as K
    split = np.flatnonzero((camera.node_states() & K.STATE_MASK) == K.SPLIT)
    split = split[split >= camera.mesh.n_positions]
    forced = int((~needs_detail(camera.mesh, split, view, ring=not camera.strict_bound)).sum())
    faces = camera.n_faces
    return {"split_nodes": len(split), "forced_nodes": forced, "faces": faces, "forced_faces": 2 * forced,
            "forced_share": 2 * forced / faces if faces else 0.0}


def _lattice(n: int) -> np.ndarray:
    """(k, 3) barycentric points (i, j, l) / n with i + j + l = n, corners left out."""
    pts = [(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)]
    return np.array([p for p in pts if max(p) < n], np.float64) / n


# Barycentric points sampled inside each drawn triangle by :func:`surface_errors`:
# the 18 points of the fifths lattice (12 on the edges, 6 inside), none of them
# a point the build measures (edge midpoints and centroids,
# caveclod.kernels.surfacegap), so that the check is not the build's own.
SURFACE_SAMPLES = _lattice(5)


def original_triangles(mesh) -> np.ndarray:
    """(p, 3) int64 the original surface as vertex-buffer indices: what a camera refined all the way
    (tolerance 0, no culling) draws, which is the source mesh exactly."""
    lo, hi = mesh.bounds()
    cam = mesh.new_camera()
    view = View(eye=tuple(hi + (hi - lo)), target=tuple((lo + hi) / 2), up=(0.0, 0.0, 1.0), tolerance_px=0.0,
                cull=False)
    for _ in range(100):                     # an update converges; the bound is for a damaged hierarchy
        if cam.update(view).operations == 0:
            break
    if cam.n_faces != mesh.n_faces:
        raise AssertionError(f"full refinement drew {cam.n_faces} faces of {mesh.n_faces}")
    return np.concatenate(list(cam.triangles().values())).astype(np.int64)


def surface_errors(mesh, triangles, original, view: View) -> np.ndarray:
    """(q,) float64 pixel distance from points of the drawn surface to the original one: the
    other direction of :func:`pixel_errors` (issue 18's two-sided bound).

    Eighteen points of each drawn triangle (:data:`SURFACE_SAMPLES`) that
    lie in ``view``'s frustum are measured against ``original``, the full
    mesh's triangles as vertex-buffer indices (:func:`original_triangles`),
    and converted to pixels as the screen-space test does.
    A sample, so the largest value is a lower bound of the true maximum.
    """
    if isinstance(triangles, dict):
        parts = [np.asarray(t).reshape(-1, 3) for t in triangles.values()]
        triangles = np.concatenate(parts) if parts else np.zeros((0, 3), np.int64)
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    V = np.asarray(mesh.vertex_positions, np.float64)
    points = np.einsum("sc,kcd->ksd", SURFACE_SAMPLES, V[tri]).reshape(-1, 3)
    return pixel_errors(mesh, original, view, points=points)


def hidden_positions(camera) -> np.ndarray:
    """(e,) bool: the original positions of the parts ``camera`` hides for being
    smaller than the tolerance (:mod:`caveclod.kernels.parts`). :func:`pixel_errors`
    has nothing drawn to measure them against; :func:`hidden_part_pixels` measures them."""
    return _hidden(camera)[1]


def _hidden(camera) -> tuple[np.ndarray, np.ndarray]:
    """((e,) int32 part of each position, (e,) bool: the position's part is hidden)."""
    from .parts import position_part
    part = position_part(camera.mesh)
    return part, (part >= 0) & (camera.part_hidden[np.maximum(part, 0)] != 0)


def hidden_part_pixels(camera, view: View) -> np.ndarray:
    """(h,) float64 the size in pixels of each part ``camera`` hides that has a position in
    ``view``'s frustum, from its original positions.

    Twice the largest distance of a position from the middle of the part's
    box, converted to pixels at that position's own distance from the eye as
    :func:`pixel_errors` converts: every position of the part lies within
    half this many pixels of one point. A part in view is hidden only for
    being small, which promises less than the tolerance; the other hidden
    parts lie wholly outside the frustum, where :func:`pixel_errors`
    measures nothing either.
    """
    part, keep = _hidden(camera)
    k = part[keep]
    P = np.asarray(camera.mesh.positions, np.float64)[keep]
    if len(k) == 0:
        return np.zeros(0)
    ids, k = np.unique(k, return_inverse=True)
    lo = np.full((len(ids), 3), np.inf)
    hi = np.full((len(ids), 3), -np.inf)
    np.minimum.at(lo, k, P)
    np.maximum.at(hi, k, P)
    vp = view.params()
    eye = vp[P_EYE:P_EYE + 3]
    size = 2.0 * np.linalg.norm(P - 0.5 * (lo + hi)[k], axis=1) * vp[P_KAPPA] / np.linalg.norm(P - eye, axis=1)
    out = np.zeros(len(ids))
    np.maximum.at(out, k, size)
    planes = vp[P_PLANES:P_PLANES + 20].reshape(5, 4)
    seen = np.zeros(len(ids), bool)
    np.logical_or.at(seen, k, ((P @ planes[:, :3].T + planes[:, 3]) >= 0.0).all(axis=1))
    return out[seen]
