"""Quantized glTF (KHR_mesh_quantization, KHR_texture_transform): read at its true values.

``tests/data/sphere-gltfpack.glb`` is ``gltfpack 0.22 -i sphere.glb -o
sphere-gltfpack.glb`` (npm's gltfpack, default options: positions uint16
with the node's transform, texture coordinates normalized uint16 with a
texture transform); ``sphere.glb`` is its input, written by trimesh.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from caveclod.builder.gltfquant import dequantized_gltf
from caveclod.builder.meshfile import load_mesh_file
from caveclod.errors import InputError
from fuzzsources import quantized_quad_glb

DATA = Path(__file__).parent / "data"


def _by_position(source):
    """(positions, uvs) of each vertex, sorted by position."""
    p = source.positions[source.vertex_position]
    order = np.lexsort(np.round(p, 4).T)
    return p[order], source.vertex_uv[order]


def test_gltfpacks_output_reads_as_its_input():
    plain, packed = load_mesh_file(DATA / "sphere.glb"), load_mesh_file(DATA / "sphere-gltfpack.glb")
    assert len(plain.faces) == len(packed.faces) == 320
    p0, uv0 = _by_position(plain)
    p1, uv1 = _by_position(packed)
    extent = np.ptp(p0, axis=0).max()
    assert np.abs(p0 - p1).max() <= extent * 2.0 ** -13          # 14-bit positions by default
    # texture coordinates: 12 bits by default, over the chart's range (the transform scales them back)
    assert np.abs(uv0 - uv1).max() <= 2.0 ** -11
    assert uv1.min() > -1e-3 and uv1.max() < 1.001                # not 0 .. 65535, as trimesh alone reads them


def test_a_plain_file_is_read_as_it_is():
    assert dequantized_gltf(DATA / "sphere.glb", "glb") is None
    assert dequantized_gltf(DATA / "sphere-gltfpack.glb", "glb") is not None


# ------------------------------------------------------------------ hand-made files


def _quad(path: Path, **options) -> Path:
    path.write_bytes(quantized_quad_glb(**options))
    return path


def _uv_at(source, x, y):
    """The glTF texture coordinates of the vertex at (x, y): trimesh turns v to 1 - v (its origin
    is the image's bottom left, glTF's the top left), so this turns it back."""
    p = source.positions[source.vertex_position]
    at = np.flatnonzero((np.abs(p[:, 0] - x) < 1e-6) & (np.abs(p[:, 1] - y) < 1e-6))
    u, v = source.vertex_uv[at[0]]
    return np.array([u, 1.0 - v])


@pytest.mark.parametrize("uv_type, top", [(5123, 65535), (5121, 255), (5122, 32767), (5120, 127)])
def test_normalized_texture_coordinates_are_dequantized(tmp_path, uv_type, top):
    uv = np.array([[0, 0], [top, 0], [top, top], [0, top // 2]])
    source = load_mesh_file(_quad(tmp_path / "q.glb", uv_type=uv_type, uv=uv))
    assert np.allclose(source.positions[:, :2].max(axis=0), [1.0, 1.0])       # the node's scale applied
    assert np.allclose(_uv_at(source, 1, 1), [1.0, 1.0])
    assert np.allclose(_uv_at(source, 0, 1), [0.0, (top // 2) / top])


def test_a_signed_minimum_clamps_to_minus_one(tmp_path):
    uv = np.array([[-32768, 0], [32767, 0], [32767, 32767], [0, 32767]])
    source = load_mesh_file(_quad(tmp_path / "q.glb", uv_type=5122, uv=uv))
    assert np.allclose(_uv_at(source, 0, 0), [-1.0, 0.0])


def test_the_texture_transform_is_baked_in(tmp_path):
    t = {"offset": [0.25, -0.5], "rotation": math.pi / 2, "scale": [2.0, 4.0]}
    source = load_mesh_file(_quad(tmp_path / "q.glb", transform=t))
    # (u, v) -> (cos r sx u + sin r sy v + ox, -sin r sx u + cos r sy v + oy)
    for (x, y), (u, v) in {(0, 0): (0, 0), (1, 0): (1, 0), (1, 1): (1, 1), (0, 1): (0, 1)}.items():
        expected = [4.0 * v + 0.25, -2.0 * u - 0.5]
        assert np.allclose(_uv_at(source, x, y), expected, atol=1e-6)


def test_an_interleaved_attribute_is_read_with_its_stride(tmp_path):
    source = load_mesh_file(_quad(tmp_path / "q.glb", stride=12))
    assert np.allclose(_uv_at(source, 1, 0), [1.0, 0.0]) and np.allclose(_uv_at(source, 0, 1), [0.0, 1.0])


def test_an_accessor_past_its_buffer_is_refused_as_damaged(tmp_path):
    with pytest.raises(InputError, match="quantized vertex attributes do not decode"):
        load_mesh_file(_quad(tmp_path / "q.glb", broken=True))
