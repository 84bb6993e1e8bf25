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
