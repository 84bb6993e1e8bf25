"""Coherent land-cover classes for heightfields without a material map, and
smooth normals by default for heightfields (what lets real DEMs coarsen)."""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod.builder.builtin import rough_heights
from caveclod.builder.landcover import MATERIALS, MIN_REGION_CELLS, classify_terrain, coherent_classes
from caveclod.builder.terrain import heightfield_to_source


def regions(classes):
    """[(class, size)] of the 4-connected regions of equal class (holes skipped)."""
    rows, cols = classes.shape
    seen = np.zeros_like(classes, bool)
    out = []
    for r0 in range(rows):
        for c0 in range(cols):
            if seen[r0, c0] or classes[r0, c0] < 0:
                continue
            stack, size = [(r0, c0)], 0
            seen[r0, c0] = True
            while stack:
                r, c = stack.pop()
                size += 1
                for rr, cc in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
                    if 0 <= rr < rows and 0 <= cc < cols and not seen[rr, cc] and classes[rr, cc] == classes[r0, c0]:
                        seen[rr, cc] = True
                        stack.append((rr, cc))
            out.append((int(classes[r0, c0]), size))
    return out


def test_speckle_becomes_regions():
    rng = np.random.default_rng(0)
    classes = np.zeros((60, 60), np.int32)
    classes[:, 30:] = 1
    noisy = classes.copy()
    flip = rng.random(classes.shape) < 0.15
    noisy[flip] = rng.integers(0, 3, flip.sum())
    out = coherent_classes(noisy, min_cells=40)
    assert len(regions(noisy)) > 100
    assert len(regions(out)) == 2
    assert (out == classes).mean() > 0.97


def test_every_region_reaches_the_minimum_unless_holes_enclose_it():
    rough = rough_heights(96)
    raw = classify_terrain(rough, 10.0, 1.0)
    out = coherent_classes(raw)
    assert len(regions(out)) < len(regions(raw)) / 10
    sizes = [size for _, size in regions(out)]
    kept = int((out >= 0).sum())
    small = [s for s in sizes if s < max(MIN_REGION_CELLS, int(0.004 * kept))]
    assert len(small) <= 2                      # islands among holes may stay
    np.testing.assert_array_equal(out < 0, raw < 0)    # holes stay holes, nothing fills them


def test_a_given_material_map_is_kept_exactly():
    rng = np.random.default_rng(1)
    heights = rng.normal(size=(21, 21)).cumsum(axis=0)
    speckle = rng.integers(0, 4, (20, 20))
    source = heightfield_to_source(heights, materials=speckle)
    names = np.array(source.materials)[source.face_material[0::2]]
    np.testing.assert_array_equal(names.reshape(20, 20), np.array(MATERIALS)[speckle])


def test_the_report_says_what_a_material_map_costs():
    rng = np.random.default_rng(2)
    heights = rng.normal(size=(33, 33)).cumsum(axis=0).cumsum(axis=1) * 0.1
    speckle = rng.integers(0, 3, (32, 32))
    mesh = caveclod.build(heights, materials=speckle)
    info = mesh.info["base_mesh"]
    assert info["material_border_faces"] > 0
    assert "between materials" in info["why"]
    assert info["large"]                      # salt and pepper cannot coarsen
    assert info["why"] in mesh.info["notes"]  # a large base mesh is explained in the notes


def test_heightfields_get_smooth_normals_unless_a_crease_angle_is_given():
    heights = rough_heights(48)
    smooth = caveclod.build(heights, cell_size=10.0, materials=np.zeros((48, 48), int))
    creased = caveclod.build(heights, cell_size=10.0, materials=np.zeros((48, 48), int), crease_angle=30.0)
    # One vertex per position when normals are smooth and the material is one.
    assert smooth.n_vertices == smooth.n_positions
    assert creased.n_vertices > 1.2 * creased.n_positions
    assert len(smooth.base_faces) < len(creased.base_faces)
    assert any("smooth normals" in n for n in smooth.info["notes"])


def test_meshes_keep_the_thirty_degree_default():
    import trimesh
    box = trimesh.creation.box().subdivide()
    mesh = caveclod.build(box)
    # A box's 90 degree edges are normal seams: corners have three vertices.
    assert mesh.n_vertices > mesh.n_positions


@pytest.mark.parametrize("angle", [-1.0, 181.0, float("nan")])
def test_bad_crease_angle_is_refused(angle):
    with pytest.raises(caveclod.InputError, match="crease"):
        caveclod.build(np.zeros((4, 4)), crease_angle=angle)
