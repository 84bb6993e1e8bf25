"""Crease-angle vertex normals for meshes that come without normals.

Faces around a position are split into *wedges* wherever the dihedral angle
across an edge exceeds the crease angle; each wedge gets one normal (the
angle-weighted mean of its face normals). Hard edges thus become normal
discontinuities, the paper's Cliff-model seams. A crease that ends inside the
surface does not split the fan, so each wedge's normal is well defined.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import InputError
from ..kernels.unionfind import find
from .source import SourceMesh
from .topology import Topology, face_neighbours


def face_normals(positions: np.ndarray, face_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (p, 3) float64 and doubled areas (p,) of faces (p, 3).

    Zero-area faces get a zero normal.
    """
    return _face_normals(np.ascontiguousarray(positions, dtype=np.float64),
                         np.ascontiguousarray(face_pos))


@nb.njit(cache=True, nogil=True)
def _face_normals(P, F):
    p = F.shape[0]
    unit = np.zeros((p, 3))
    length = np.empty(p)
    for f in range(p):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        e10, e11, e12 = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
        e20, e21, e22 = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
        n0 = e11 * e22 - e12 * e21
        n1 = e12 * e20 - e10 * e22
        n2 = e10 * e21 - e11 * e20
        ln = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        length[f] = ln
        if ln > 0.0:
            unit[f, 0], unit[f, 1], unit[f, 2] = n0 / ln, n1 / ln, n2 / ln
    return unit, length


def face_weights(positions: np.ndarray, face_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (p, 3) float64, interior angle at each corner (p, 3)
    float64) of faces ``face_pos`` (p, 3): what a vertex normal averages.
    Needs no topology, so a build makes them while it makes the topology."""
    unit, _ = face_normals(positions, face_pos)
    return unit, _corner_angles(positions, face_pos)


def add_crease_normals(source: SourceMesh, crease_angle_deg: float, topo: Topology | None = None,
                       face_pos: np.ndarray | None = None, weights: tuple | None = None) -> SourceMesh:
    """Return ``source`` with vertex normals computed at ``crease_angle_deg``.

    Vertices are split where wedges differ, so the result's vertex ids change;
    UVs and colours of the input vertices are kept. ``topo`` is the mesh's
    :class:`~caveclod.builder.topology.Topology` when the caller already has it,
    ``face_pos`` (p, 3) int32 its ``face_positions`` and ``weights`` its
    :func:`face_weights`.
    """
    if not 0.0 <= crease_angle_deg <= 180.0:
        raise InputError(f"--crease-angle must be between 0 and 180 degrees, got {crease_angle_deg}")
    if face_pos is None:
        face_pos = source.face_positions.astype(np.int32)
    if topo is None:
        topo = face_neighbours(face_pos, len(source.positions))
    unit, corner_w = face_weights(source.positions, face_pos) if weights is None else weights
    wedge = _wedges(face_pos, topo.nbrs, source.faces.astype(np.int32), unit,
                    np.cos(np.radians(crease_angle_deg)))
    faces, old_vertex, normals = _wedge_vertices(wedge, source.faces.astype(np.int64), unit, corner_w)
    return SourceMesh(
        positions=source.positions,
        vertex_position=source.vertex_position[old_vertex],
        faces=faces,
        face_material=source.face_material,
        materials=source.materials,
        vertex_normal=normals,
        vertex_uv=None if source.vertex_uv is None else source.vertex_uv[old_vertex],
        vertex_color=None if source.vertex_color is None else source.vertex_color[old_vertex],
        notes=source.notes + ["computed smooth normals" if crease_angle_deg >= 180.0 else
                              f"computed normals with a {crease_angle_deg:g} degree crease angle"],
        crease_angle=crease_angle_deg,
        origin=source.origin,
    )


def smooth_wedges(face_pos: np.ndarray, nbrs: np.ndarray, face_vertex: np.ndarray) -> np.ndarray:
    """(p, 3) int32 a label per corner, equal where smooth normals (a crease angle of 180 degrees)
    give the corners one vertex: the corners of one input vertex joined across the edges between
    them (``face_pos``, ``nbrs`` as the topology's, ``face_vertex`` (p, 3) the input's vertex ids)."""
    no_crease = -2.0                          # below every cosine: no edge is a crease, nor needs a normal
    return _wedges(face_pos, nbrs, np.asarray(face_vertex, np.int32), np.zeros((len(face_pos), 3)), no_crease)


@nb.njit(cache=True, nogil=True)
def _corner_angles(positions, face_pos):
    """(p, 3) interior angle at each corner, the weight of that face's normal."""
    out = np.empty(face_pos.shape)
    for f in range(face_pos.shape[0]):
        for k in range(3):
            a = face_pos[f, k]
            b = face_pos[f, (k + 1) % 3]
            c = face_pos[f, (k + 2) % 3]
            u0, u1, u2 = positions[b, 0] - positions[a, 0], positions[b, 1] - positions[a, 1], positions[b, 2] - positions[a, 2]
            w0, w1, w2 = positions[c, 0] - positions[a, 0], positions[c, 1] - positions[a, 1], positions[c, 2] - positions[a, 2]
            lu = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
            lw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            cos = (u0 * w0 + u1 * w1 + u2 * w2) / max(lu * lw, 1e-300)
            out[f, k] = np.arccos(min(1.0, max(-1.0, cos)))
    return out


@nb.njit(cache=True, nogil=True)
def _wedges(face_pos, nbrs, face_vertex, unit, cos_crease):
    """(p, 3) wedge label per corner: union corners across smooth edges.

    Corners are only joined when the two faces also share the input vertex
    at that position, so existing UV seams stay seams.
    """
    p = face_pos.shape[0]
    parent = np.empty(3 * p, np.int32)            # corner ids, int32 like the build's face ids
    for c in range(3 * p):
        parent[c] = c
    for f in range(p):
        for k in range(3):
            g = nbrs[f, k]
            if g < f:
                continue
            d = unit[f, 0] * unit[g, 0] + unit[f, 1] * unit[g, 1] + unit[f, 2] * unit[g, 2]
            zero_area = (unit[f, 0] == 0.0 and unit[f, 1] == 0.0 and unit[f, 2] == 0.0) or \
                        (unit[g, 0] == 0.0 and unit[g, 1] == 0.0 and unit[g, 2] == 0.0)
            # A zero-area sliver has no direction: never let it cut a wedge.
            if d < cos_crease and not zero_area:
                continue
            for end in range(2):
                x = face_pos[f, (k + end) % 3]
                cf = (k + end) % 3
                cg = 0 if face_pos[g, 0] == x else (1 if face_pos[g, 1] == x else 2)
                if face_vertex[f, cf] != face_vertex[g, cg]:
                    continue
                ra, rb = find(parent, 3 * f + cf), find(parent, 3 * g + cg)
                if ra != rb:
                    parent[ra] = rb
    out = np.empty((p, 3), np.int32)
    for c in range(3 * p):
        out[c // 3, c % 3] = find(parent, c)
    return out


@nb.njit(cache=True, nogil=True)
def _wedge_vertices(wedge, face_vertex, unit, weight):
    """One new vertex per wedge: (faces (p, 3), old vertex (v,), normals (v, 3)).

    Corners are joined only when they share the input vertex, so a wedge
    belongs to exactly one input vertex and its label alone names the new
    vertex. Normals are the weighted mean of the wedge's face normals; a wedge
    of zero-area faces falls back to +z.
    """
    p = wedge.shape[0]
    # Two passes, so that the per-vertex arrays are sized by the vertices
    # (about p / 2 on a terrain), not by the 3p corners: (3p, 3) float64
    # sums alone were 72 bytes per input triangle.
    label = np.full(3 * p, -1, np.int32)
    faces = np.empty((p, 3), np.int32)             # int32 like every face array of the build: half the bytes
    v = 0
    for f in range(p):
        for k in range(3):
            w = wedge[f, k]
            if label[w] == -1:
                label[w] = v
                v += 1
            faces[f, k] = label[w]
    old = np.empty(v, np.int64)
    acc = np.zeros((v, 3))
    for f in range(p):
        for k in range(3):
            i = faces[f, k]
            old[i] = face_vertex[f, k]
            for j in range(3):
                acc[i, j] += weight[f, k] * unit[f, j]
    normals = np.empty((v, 3), np.float32)
    for i in range(v):
        ln = np.sqrt(acc[i, 0] ** 2 + acc[i, 1] ** 2 + acc[i, 2] ** 2)
        if ln > 0.0:
            for j in range(3):
                normals[i, j] = acc[i, j] / ln
        else:
            normals[i, 0], normals[i, 1], normals[i, 2] = 0.0, 0.0, 1.0
    return faces, old, normals
