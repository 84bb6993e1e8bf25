"""Welding positions by tolerance, for meshes whose seams do not meet exactly.

Positions are welded exactly by default (DESIGN.md section 2). Scans and
some exporters leave the two sides of a seam a rounding error apart; the mesh
is then cut along the seam, which pins its positions and keeps the base mesh
large. ``caveclod build --weld TOL`` snaps positions to a grid of cell TOL
and merges those that land in the same cell (so positions closer than TOL
usually merge, and those further apart than TOL * sqrt(3) never do).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .source import SourceMesh


def weld_positions(source: SourceMesh, tolerance: float) -> SourceMesh:
    """``source`` with positions within about ``tolerance`` merged.

    Each merged position keeps the coordinates of its first member. Faces
    that collapse onto a position twice, and exact duplicate faces, are
    dropped; vertices whose attributes become identical are merged; unused
    vertices and positions are removed. Every change is noted.
    """
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        tol = float("nan")
    if not np.isfinite(tol) or tol <= 0:
        raise InputError(f"--weld must be a positive distance, got {tolerance!r}")
    _refuse_tolerance_below_resolution(source.positions, tol)
    notes = list(source.notes)
    cells = np.floor(source.positions / tol + 0.5).astype(np.int64)
    _, first, cluster = np.unique(cells, axis=0, return_index=True, return_inverse=True)
    cluster = cluster.ravel()
    merged = len(source.positions) - len(first)
    if merged:
        notes.append(f"welded {merged} positions within {tol:g} of another")
    positions = source.positions[first]
    vertex_position = cluster[source.vertex_position]

    # Vertices that now share a position and every attribute become one.
    vertex_of, keep_vertex = _merge_identical_vertices(source, vertex_position)
    faces = vertex_of[source.faces]
    face_pos = vertex_position[keep_vertex][faces]
    ok = (face_pos[:, 0] != face_pos[:, 1]) & (face_pos[:, 1] != face_pos[:, 2]) & (face_pos[:, 2] != face_pos[:, 0])
    if (~ok).sum():
        notes.append(f"dropped {int((~ok).sum())} faces that welding made degenerate")
    if not ok.any():
        raise InputError(f"welding at {tol:g} leaves no proper triangle; give a smaller --weld")
    ok &= _first_copies(face_pos, source.face_material)
    faces, material = faces[ok], source.face_material[ok]

    used_v = np.zeros(len(keep_vertex), bool)
    used_v[faces] = True
    new_v = np.cumsum(used_v) - 1
    vpos = vertex_position[keep_vertex][used_v]
    used_p = np.zeros(len(positions), bool)
    used_p[vpos] = True
    new_p = np.cumsum(used_p) - 1

    def pick(a):
        return None if a is None else a[keep_vertex][used_v]

    out = SourceMesh(positions=positions[used_p], vertex_position=new_p[vpos].astype(np.int64),
                     faces=new_v[faces].astype(np.int64), face_material=material.astype(np.int32),
                     materials=list(source.materials), vertex_normal=pick(source.vertex_normal),
                     vertex_uv=pick(source.vertex_uv), vertex_color=pick(source.vertex_color), notes=notes,
                     crease_angle=source.crease_angle, origin=source.origin)
    out.validate()
    return out


def _refuse_tolerance_below_resolution(positions: np.ndarray, tol: float) -> None:
    """Refuse a tolerance finer than float64 resolves the (e, 3) ``positions``.

    Grid cells are ``position / tol`` as int64; below ``largest * 2**-52``
    (float64's step at the largest coordinate) that quotient passes 2**52,
    where float64 no longer holds whole numbers exactly, and soon int64's
    range: the cells would mean nothing, and exact welding (no --weld) does
    all a tolerance that fine could.
    """
    largest = float(np.abs(positions).max(initial=0.0))
    finest = largest * 2.0 ** -52
    if tol < finest:
        raise InputError(f"--weld {tol:g} is finer than float64 resolves coordinates up to {largest:.3g}; give at "
                         f"least {finest:.2g}, or leave --weld out to merge only equal positions")


def _merge_identical_vertices(source: SourceMesh, vertex_position: np.ndarray):
    """(vertex -> merged vertex (v,), first vertex of each merged one (k,))."""
    cols = [vertex_position.astype(np.int64)[:, None].view(np.uint8).reshape(len(vertex_position), -1)]
    for a in (source.vertex_normal, source.vertex_uv, source.vertex_color):
        if a is not None:
            a = np.ascontiguousarray(a)
            cols.append(a.view(np.uint8).reshape(len(a), -1))
    rows = np.ascontiguousarray(np.hstack(cols))
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    return inverse.ravel(), first


def _first_copies(face_pos: np.ndarray, material: np.ndarray) -> np.ndarray:
    """(p,) bool: False for a face repeating an earlier one (same positions in
    the same cyclic order, same material)."""
    rot = np.argmin(face_pos, axis=1)
    idx = np.arange(len(face_pos))
    canon = np.stack([face_pos[idx, (rot + k) % 3] for k in range(3)] + [material.astype(np.int64)], axis=1)
    _, first = np.unique(canon, axis=0, return_index=True)
    keep = np.zeros(len(face_pos), bool)
    keep[first] = True
    return keep
