"""Compressed glTF geometry: Draco files build; what cannot be decoded is refused by name."""

from __future__ import annotations

import json
import logging
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh
from trimesh.exchange.gltf import export_glb
from trimesh.visual import TextureVisuals

from caveclod.builder import gltfcodecs
from caveclod.builder.gltfquant import glb_bytes
from caveclod.builder.meshfile import load_mesh_file
from caveclod.errors import InputError
from fuzzsources import build_here as build_cli

DATA = Path(__file__).parent / "data"


def _textured_sphere() -> trimesh.Trimesh:
    """An icosphere with a UV seam-free chart (its vertex order), 320 faces."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    uv = np.stack([np.arctan2(mesh.vertices[:, 1], mesh.vertices[:, 0]), mesh.vertices[:, 2]], axis=1)
    mesh.visual = TextureVisuals(uv=(uv * 0.25 + 0.5).astype(np.float64))
    return mesh


def _glb_parts(data: bytes) -> tuple[dict, bytes]:
    """(JSON tree, binary chunk) of a GLB."""
    (json_len,) = struct.unpack_from("<I", data, 12)
    tree = json.loads(data[20:20 + json_len])
    bin_at = 20 + json_len
    (bin_len,) = struct.unpack_from("<I", data, bin_at)
    return tree, data[bin_at + 8:bin_at + 8 + bin_len]


def test_a_draco_glb_builds_as_its_uncompressed_twin(tmp_path):
    mesh = _textured_sphere()
    (tmp_path / "plain.glb").write_bytes(export_glb(trimesh.Scene(mesh)))
    (tmp_path / "draco.glb").write_bytes(export_glb(trimesh.Scene(mesh), extension_draco=True))
    assert "KHR_draco_mesh_compression" in gltfcodecs.required_extensions(tmp_path / "draco.glb", "glb")
    plain, draco = load_mesh_file(tmp_path / "plain.glb"), load_mesh_file(tmp_path / "draco.glb")
    assert len(draco.faces) == len(plain.faces) == 320
    # Draco quantizes positions (trimesh writes 14 bits): within half a step of the extent.
    step = np.ptp(plain.positions, axis=0).max() * 2.0 ** -14
    order_p, order_d = np.lexsort(plain.positions.T), np.lexsort(draco.positions.T)
    assert np.abs(plain.positions[order_p] - draco.positions[order_d]).max() <= step
    assert draco.vertex_uv is not None and len(draco.vertex_uv) == len(plain.vertex_uv)


def test_the_cli_builds_a_draco_glb(tmp_path, capsys):
    (tmp_path / "draco.glb").write_bytes(export_glb(trimesh.Scene(_textured_sphere()), extension_draco=True))
    status, err = build_cli(capsys, tmp_path / "draco.glb", "--quiet")
    assert status == 0, err


def test_damaged_draco_data_is_named_not_called_degenerate(tmp_path, capsys):
    tree, binary = _glb_parts(export_glb(trimesh.Scene(_textured_sphere()), extension_draco=True))
    view = tree["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]["bufferView"]
    at = tree["bufferViews"][view].get("byteOffset", 0)
    broken = binary[:at] + b"\xff" * 16 + binary[at + 16:]          # the Draco header itself
    (tmp_path / "broken.glb").write_bytes(glb_bytes(tree, broken))
    with pytest.raises(InputError, match="compressed with KHR_draco_mesh_compression, and decoding it failed"):
        load_mesh_file(tmp_path / "broken.glb")
    status, err = build_cli(capsys, tmp_path / "broken.glb")
    assert status == 2 and "degenerate" not in err


@pytest.mark.parametrize("name, package, advice", [
    ("draco.glb", "DracoPy", "pip install DracoPy"),
    ("sphere-gltfpack-c.glb", "meshoptimizer", "pip install --pre meshoptimizer")])
def test_without_its_decoder_the_message_says_what_to_install(tmp_path, monkeypatch, name, package, advice):
    (tmp_path / "draco.glb").write_bytes(export_glb(trimesh.Scene(_textured_sphere()), extension_draco=True))
    path = tmp_path / name if name == "draco.glb" else DATA / name
    real = gltfcodecs.importlib.util.find_spec
    monkeypatch.setattr(gltfcodecs.importlib.util, "find_spec", lambda n: None if n == package else real(n))
    with pytest.raises(InputError, match=advice.replace("+", "\\+")):
        load_mesh_file(path)


@pytest.mark.parametrize("data", [b"", b"glTF", b"glTF\x02\0\0\0" + b"\xff" * 12, b"not json"])
def test_unreadable_headers_are_left_to_the_reader(tmp_path, data):
    (tmp_path / "x.glb").write_bytes(data)
    (tmp_path / "x.gltf").write_bytes(data)
    assert gltfcodecs.required_extensions(tmp_path / "x.glb", "glb") == set()
    assert gltfcodecs.required_extensions(tmp_path / "x.gltf", "gltf") == set()


def test_the_watch_leaves_logging_as_it_was(tmp_path):
    (tmp_path / "draco.glb").write_bytes(export_glb(trimesh.Scene(_textured_sphere()), extension_draco=True))
    loggers = [logging.getLogger(n) for n in ("trimesh", "trimesh.util")]
    before = [(lg.level, lg.propagate, list(lg.handlers)) for lg in loggers]
    load_mesh_file(tmp_path / "draco.glb")
    assert [(lg.level, lg.propagate, list(lg.handlers)) for lg in loggers] == before
