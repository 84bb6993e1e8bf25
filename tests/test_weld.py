"""Welding by tolerance: seams a rounding error apart become one."""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.builder.builtin import default_terrain
from caveclod.builder.weld import weld_positions

from meshes import replay_collapses


def cracked_terrain(gap=1e-6):
    """The default terrain cut in two halves whose shared column is apart by ``gap``."""
    src = default_terrain(16)
    x = src.positions[:, 0]
    mid = np.median(np.unique(x))
    on_seam = np.isclose(x, mid)
    centre_x = src.positions[src.face_positions].mean(axis=1)[:, 0]
    right = centre_x > mid
    # Give the right half its own copy of the seam positions, nudged by gap.
    seam_ids = np.flatnonzero(on_seam)
    copy_of = np.full(len(src.positions), -1)
    copy_of[seam_ids] = len(src.positions) + np.arange(len(seam_ids))
    positions = np.r_[src.positions, src.positions[seam_ids] + [gap, 0, 0]]
    vpos = src.vertex_position.copy()
    faces = src.faces.copy()
    extra_vertices = []
    for f in np.flatnonzero(right):
        for k in range(3):
            v = faces[f, k]
            if copy_of[vpos[v]] >= 0:
                extra_vertices.append(v)
                faces[f, k] = len(vpos) + len(extra_vertices) - 1
    extra = np.array(extra_vertices, dtype=np.int64)
    vpos_all = np.r_[vpos, copy_of[vpos[extra]]]
    uv = np.r_[src.vertex_uv, src.vertex_uv[extra]]
    return caveclod.builder.source.SourceMesh(positions, vpos_all, faces, src.face_material, src.materials,
                                      vertex_uv=uv)


def test_weld_closes_a_crack():
    cracked = cracked_terrain()
    exact = build_static_mesh(cracked)
    welded_source = weld_positions(cracked, 1e-3)
    assert len(welded_source.positions) == len(default_terrain(16).positions)
    assert any("welded" in n for n in welded_source.notes)
    welded = build_static_mesh(welded_source)
    replay_collapses(welded, welded_source)
    # The crack is a border: its positions stay put, so the exact base is larger.
    assert len(welded.base_faces) < len(exact.base_faces)
    assert welded.n_faces == exact.n_faces


def test_weld_drops_faces_it_degenerates():
    src = default_terrain(8)
    with pytest.raises(caveclod.InputError):
        weld_positions(src, 1e9)                 # everything onto one point
    coarse = weld_positions(src, 10_000 / 8 * 1.5)     # neighbouring columns merge
    assert any("degenerate" in n for n in coarse.notes)
    coarse.validate()


@pytest.mark.parametrize("bad", [0, -1, float("nan"), "x"])
def test_bad_tolerance_is_refused(bad):
    with pytest.raises(caveclod.InputError):
        weld_positions(default_terrain(4), bad)
