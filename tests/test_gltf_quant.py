"""Quantized glTF (KHR_mesh_quantization, KHR_texture_transform): read at its true values.

``tests/data/sphere-gltfpack.glb`` is ``gltfpack 0.22 -i sphere.glb -o
sphere-gltfpack.glb`` (npm's gltfpack, default options: positions uint16
with the node's transform, texture coordinates normalized uint16 with a
texture transform, normals normalized int8); ``-c.glb`` adds ``-c``
(EXT_meshopt_compression), ``-cc.glb`` ``-cc`` (and the octahedral
filter on normals), ``-cc-vpf.glb`` ``-cc -vpf -vtf`` (float positions and
texture coordinates through the exponential filter), ``-cf.glb`` ``-cf``
(compressed, with uncompressed copies in ``-cf.fallback.bin``). ``sphere.glb`` is
their input, an icosphere with normals and texture coordinates written
by trimesh.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from caveclod.builder.gltfquant import dequantized_gltf
from caveclod.builder.meshfile import load_mesh_file
from caveclod.errors import InputError
from fuzzsources import quantized_quad_glb

DATA = Path(__file__).parent / "data"


def _by_position(source):
    """(positions, uvs, normals) of each vertex, sorted by position."""
    p = source.positions[source.vertex_position]
    order = np.lexsort(np.round(p, 3).T)
    return p[order], source.vertex_uv[order], source.vertex_normal[order]


@pytest.mark.parametrize("name", ["sphere-gltfpack", "sphere-gltfpack-c", "sphere-gltfpack-cc",
                                  "sphere-gltfpack-cc-vpf"])
def test_gltfpacks_output_reads_as_its_input(name):
    plain, packed = load_mesh_file(DATA / "sphere.glb"), load_mesh_file(DATA / f"{name}.glb")
    assert len(plain.faces) == len(packed.faces) == 320
    p0, uv0, n0 = _by_position(plain)
    p1, uv1, n1 = _by_position(packed)
    extent = np.ptp(p0, axis=0).max()
    assert np.abs(p0 - p1).max() <= extent * 2.0 ** -13          # 14-bit positions by default
    # texture coordinates: 12 bits by default, over the chart's range (the transform scales them back)
    assert np.abs(uv0 - uv1).max() <= 2.0 ** -11
    assert uv1.min() > -1e-3 and uv1.max() < 1.001                # not 0 .. 65535, as trimesh alone reads them
    assert np.abs(n0 - n1).max() <= 0.02                         # 8-bit normals (octahedral with -cc)


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


@pytest.mark.parametrize("edit, words", [
    (lambda e: e.update(count=10 ** 12), "items of"),
    (lambda e: e.update(byteStride=6), "stride of 6"),
    (lambda e: e.update(byteLength=e["byteLength"] + 10 ** 6), "reaches past its buffer"),
    (lambda e: e.update(mode="POINTS"), "compression mode"),
    (lambda e: e.update(filter="QUATERNION"), "QUATERNION filter on items of 4 bytes"),
])
def test_damaged_compressed_views_are_refused_before_decoding(tmp_path, edit, words):
    data = (DATA / "sphere-gltfpack-c.glb").read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    tree = json.loads(data[20:20 + length])
    ext = [v["extensions"]["EXT_meshopt_compression"] for v in tree["bufferViews"]     # the last: 4-byte normals
           if v.get("extensions", {}).get("EXT_meshopt_compression", {}).get("mode") == "ATTRIBUTES"][-1]
    edit(ext)
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    path = tmp_path / "damaged.glb"
    path.write_bytes(data[:12] + struct.pack("<II", len(text), 0x4E4F534A) + text + data[20 + length:])
    with pytest.raises(InputError, match=words):
        load_mesh_file(path)


def test_garbage_compressed_data_is_an_input_error(tmp_path):
    data = bytearray((DATA / "sphere-gltfpack-c.glb").read_bytes())
    (length,) = struct.unpack_from("<I", data, 12)
    at = 20 + length + 8 + 200                      # inside the compressed streams
    data[at:at + 64] = bytes(range(64))
    (tmp_path / "garbage.glb").write_bytes(bytes(data))
    with pytest.raises(InputError):
        load_mesh_file(tmp_path / "garbage.glb")


def test_an_accessor_past_its_buffer_is_refused_as_damaged(tmp_path):
    with pytest.raises(InputError, match="compressed or quantized glTF buffers do not decode"):
        load_mesh_file(_quad(tmp_path / "q.glb", broken=True))


def test_a_file_with_meshopt_fallbacks_reads_without_the_decoder(monkeypatch):
    """gltfpack -cf keeps uncompressed copies (EXT_meshopt_compression in extensionsUsed only, the
    fallback in sphere-gltfpack-cf.fallback.bin): read from them where meshoptimizer is missing, and
    decoded where it is, the same mesh."""
    import caveclod.builder.gltfquant as gq
    decoded = load_mesh_file(DATA / "sphere-gltfpack-cf.glb")
    real = gq.importlib.util.find_spec
    monkeypatch.setattr(gq.importlib.util, "find_spec", lambda n: None if n == "meshoptimizer" else real(n))
    fallback = load_mesh_file(DATA / "sphere-gltfpack-cf.glb")
    p0, uv0, n0 = _by_position(decoded)
    p1, uv1, n1 = _by_position(fallback)
    assert np.array_equal(p0, p1) and np.array_equal(uv0, uv1) and np.array_equal(n0, n1)
    with pytest.raises(InputError, match="pip install --pre meshoptimizer"):       # no fallback to read
        gq.dequantized_gltf(DATA / "sphere-gltfpack-c.glb", "glb")


# ------------------------------------------------------------------ primitives trimesh leaves out


def _glb(path: Path, primitives: list, positions: np.ndarray, uv: np.ndarray | None = None,
         materials: int = 0) -> Path:
    """A GLB of one mesh: ``primitives`` [(mode, indices or None, with a material)] over shared
    float32 ``positions`` (and texture coordinates)."""
    from caveclod.builder.gltfquant import glb_bytes
    data = bytearray()
    views, accessors = [], []

    def add(array, component, kind):
        array = np.ascontiguousarray(array)
        views.append({"buffer": 0, "byteOffset": len(data), "byteLength": array.nbytes})
        data.extend(array.tobytes() + b"\0" * (-array.nbytes % 4))
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": len(array), "type": kind}
        if kind == "VEC3":
            acc.update(min=array.min(axis=0).tolist(), max=array.max(axis=0).tolist())
        accessors.append(acc)
        return len(accessors) - 1

    attributes = {"POSITION": add(positions.astype("<f4"), 5126, "VEC3")}
    if uv is not None:
        attributes["TEXCOORD_0"] = add(uv.astype("<f4"), 5126, "VEC2")
    prims = []
    for mode, indices, with_material in primitives:
        prim = {"attributes": attributes, "mode": mode}
        if indices is not None:
            prim["indices"] = add(np.asarray(indices, "<u2"), 5123, "SCALAR")
        if with_material:
            prim["material"] = 0
        prims.append(prim)
    tree = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": prims}], "accessors": accessors, "bufferViews": views,
            "buffers": [{"byteLength": len(data)}]}
    if materials:
        tree["materials"] = [{"name": f"m{k}"} for k in range(materials)]
    path.write_bytes(glb_bytes(tree, bytes(data)))
    return path


def _hexagon():
    """(7, 3) a hexagon's centre and corners, z rising with the angle (every position distinct)."""
    angles = np.arange(6) * math.pi / 3
    ring = np.c_[np.cos(angles), np.sin(angles), angles / 10]
    return np.vstack([[0.0, 0.0, 1.0], ring]).astype(np.float32).astype(np.float64)   # as the file holds them


@pytest.mark.parametrize("indexed", [True, False])
def test_a_triangle_fan_is_read_as_its_triangles(tmp_path, indexed):
    """trimesh skips glTF's TRIANGLE_FAN (mode 6) without a word (a file of fans alone read as
    "no geometry"); its triangles are p_i = (v[i+1], v[i+2], v[0]), wound alike."""
    P = _hexagon()
    fan = [0, 1, 2, 3, 4, 5, 6, 1]                          # centre, the ring, closed
    positions = P[fan] if not indexed else P
    source = load_mesh_file(_glb(tmp_path / "fan.glb", [(6, fan if indexed else None, False)], positions))
    got = sorted(tuple(sorted(map(tuple, source.positions[source.vertex_position[f]]))) for f in source.faces)
    expected = sorted(tuple(sorted(map(tuple, P[[0, fan[i + 1], fan[i + 2]]]))) for i in range(6))
    assert got == expected
    normals = np.cross(*(source.positions[source.vertex_position[source.faces[:, k]]]
                         - source.positions[source.vertex_position[source.faces[:, 0]]] for k in (1, 2)))
    assert (normals[:, 2] > 0).all()                        # counter-clockwise seen from +z, as the fan
    mixed = load_mesh_file(_glb(tmp_path / "mixed.glb", [(4, [0, 1, 2], False), (6, fan, False)], P))
    assert len(mixed.faces) == 7


def test_texture_coordinates_on_a_primitive_with_no_material_are_kept(tmp_path):
    """trimesh reads a primitive's texture coordinates only when it has a material: without one
    they came out (0, 0), without a word."""
    P = _hexagon()
    uv = np.c_[np.linspace(0.1, 0.9, 7), np.linspace(0.9, 0.2, 7)]
    source = load_mesh_file(_glb(tmp_path / "bare.glb", [(4, [0, 1, 2, 0, 2, 3], False)], P, uv))
    assert source.vertex_uv is not None
    for v in range(len(source.vertex_position)):
        at = int(np.flatnonzero((P == source.positions[source.vertex_position[v]]).all(axis=1))[0])
        np.testing.assert_allclose(source.vertex_uv[v], [uv[at, 0], 1.0 - uv[at, 1]], atol=1e-6)   # trimesh flips v
