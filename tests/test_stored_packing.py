"""Packed vertex downloads stored in the ``.cvc`` file by the build: the same bytes as packing
at start, served without packing, and refused (then packed afresh) when damaged or stale.
"""

from __future__ import annotations

import json
import logging
import struct

import numpy as np
import pytest

import caveclod
from caveclod import vertexpack
from caveclod.client import Client
from caveclod.errors import FileFormatError
from caveclod.refine.morphtargets import morph_targets
from caveclod.server.meshes import ServedMesh

import meshes

PREFIX = 16      # magic, version, header length


@pytest.fixture(scope="module")
def rough(tmp_path_factory):
    """A rough terrain with holes (64 x 64 cells), built with its stored variants and saved."""
    path = tmp_path_factory.mktemp("stored") / "rough.cvc"
    caveclod.build("rough", size=64).save(path)
    return path


def _fresh(mesh, bits: int, morph: bool) -> vertexpack.Packed:
    return vertexpack.pack(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors, bits,
                           morph_targets(mesh) if morph else None)


def _same(stored: vertexpack.Packed, fresh: vertexpack.Packed) -> None:
    assert bytes(stored.data) == fresh.data
    assert (stored.packing, stored.decoded_crc32, stored.packed_crc32, stored.max_position_error,
            stored.max_normal_degrees) == (fresh.packing, fresh.decoded_crc32, fresh.packed_crc32,
                                           fresh.max_position_error, fresh.max_normal_degrees)


@pytest.mark.parametrize("source", ["rough", "scan", "holey", "colored"])
def test_a_built_file_stores_what_packing_at_start_would_make(source, tmp_path):
    if source in ("rough", "scan"):
        built = caveclod.build(source, size=48)
    elif source == "holey":
        built = caveclod.build(meshes.holey_scan())
    else:                                   # colours travel in the packed streams too
        src = meshes.uv_sphere()
        src.vertex_color = np.random.default_rng(3).integers(0, 256, (len(src.vertex_position), 4), dtype=np.uint8)
        built = caveclod.build(src)
        assert len(built.vertex_colors)
    assert set(built.attachments) == {"packed-20", "packed-20-morph"}
    built.save(tmp_path / "m.cvc")
    mesh = caveclod.load(tmp_path / "m.cvc")
    assert mesh.summary()["attachments"] == {name: int(a.data.nbytes) for name, a in built.attachments.items()}
    for bits, morph in vertexpack.STORED_VARIANTS:
        stored = vertexpack.stored_packed(mesh, bits, morph)
        _same(stored, _fresh(mesh, bits, morph))
        decoded = vertexpack.unpack(stored.packing, stored.data)
        assert np.array_equal(decoded["position"].shape, mesh.vertex_positions.shape)
    assert vertexpack.stored_packed(mesh, 16, False) is None, "a variant the build did not store"


def test_a_file_without_attachments_loads_and_packs_at_start(tmp_path):
    built = caveclod.build("rough", size=32, packed=False)
    assert built.attachments == {}
    built.save(tmp_path / "bare.cvc")
    mesh = caveclod.load(tmp_path / "bare.cvc")
    assert mesh.attachments == {} and mesh.summary()["attachments"] == {}
    served = ServedMesh("bare", mesh)
    packed = served.packed(20)[0]
    _same(packed, _fresh(mesh, 20, False))
    assert served.stored == set()


def _rewrite_header(path, edit) -> None:
    """Apply ``edit(header)`` to a .cvc file's header JSON in place (its arrays stay where they are)."""
    data = bytearray(path.read_bytes())
    hlen = struct.unpack("<I", data[12:16])[0]
    header = json.loads(bytes(data[PREFIX:PREFIX + hlen]))
    edit(header)
    blob = json.dumps(header, sort_keys=True).encode()
    room = (PREFIX + hlen + 63) // 64 * 64 - PREFIX      # the arrays start at the same offset
    assert len(blob) <= room, "the edit made the header too long for this helper"
    blob += b" " * (hlen - len(blob)) if len(blob) < hlen else b""
    data[12:16] = struct.pack("<I", len(blob))
    data[PREFIX:PREFIX + len(blob)] = blob
    path.write_bytes(bytes(data))


def _copy(src, dst):
    dst.write_bytes(src.read_bytes())
    return dst


def test_damaged_or_stale_stored_bytes_are_refused_and_packed_afresh(rough, tmp_path, caplog):
    fresh = _fresh(caveclod.load(rough), 20, False)
    # One byte of the stored variant flipped: the file loads (the check reads no attachment) ...
    damaged = _copy(rough, tmp_path / "damaged.cvc")
    mesh = caveclod.load(damaged)
    at = int(mesh.attachments["packed-20"].data.offset) + 100
    data = bytearray(damaged.read_bytes())
    data[at] ^= 0x10
    damaged.write_bytes(bytes(data))
    mesh = caveclod.load(damaged)
    with pytest.raises(ValueError, match="CRC-32"):
        vertexpack.stored_packed(mesh, 20, False)
    # ... and a server packs it afresh, saying why.
    served = ServedMesh("damaged", mesh)
    with caplog.at_level(logging.INFO, logger="caveclod.server"):
        _same(served.packed(20)[0], fresh)
    assert served.stored == set()
    refused = [r for r in caplog.records if r.getMessage() == "server.stored_packing_refused"]
    assert len(refused) == 1 and "CRC-32" in refused[0].fields["reason"]
    # The morph variant, intact, still comes from the file.
    served.packed(20, morph=True)
    assert served.stored == {(20, True)}

    # Metadata edited where JSON stays valid (a digit of the decoded payload's CRC): its own CRC says so.
    edited = _copy(rough, tmp_path / "edited.cvc")
    _rewrite_header(edited, lambda h: h["attachments"]["packed-20"]["meta"].update(
        decoded_crc32=h["attachments"]["packed-20"]["meta"]["decoded_crc32"] ^ 1))
    with pytest.raises(ValueError, match="metadata do not match their CRC-32"):
        vertexpack.stored_packed(caveclod.load(edited), 20, False)

    def consistent(**fields):
        """An edit of the metadata that also rewrites its CRC (a tool's bug, not damage)."""
        def edit(h):
            meta = h["attachments"]["packed-20"]["meta"]
            meta.update(fields)
            meta["meta_crc32"] = vertexpack.stored_meta_crc32(meta)
        return edit

    # Metadata that belongs to another vertex buffer.
    stale = _copy(rough, tmp_path / "stale.cvc")
    _rewrite_header(stale, consistent(vertex_buffer_hash="0" * 32))
    with pytest.raises(ValueError, match="vertex_buffer_hash"):
        vertexpack.stored_packed(caveclod.load(stale), 20, False)
    # Fields of the wrong type or out of range.
    for fields in ({"position_step": "big"}, {"decoded_crc32": 1 << 33}, {"packed_crc32": -1}):
        odd = _copy(rough, tmp_path / "odd.cvc")
        _rewrite_header(odd, consistent(**fields))
        with pytest.raises(ValueError, match="wrong type"):
            vertexpack.stored_packed(caveclod.load(odd), 20, False)


def _shift_onto_an_array(h):
    h["attachments"]["packed-20"]["offset"] = h["arrays"]["node_links"]["offset"]


def _past_the_end(h):
    h["attachments"]["packed-20"]["nbytes"] += 1 << 30


@pytest.mark.parametrize("edit, message", [
    (_shift_onto_an_array, "attachment packed-20 and array node_links overlap"),
    (_past_the_end, "truncated"),
    (lambda h: h.update(attachments=[1, 2]), "attachments are not a JSON object"),
    (lambda h: h["attachments"]["packed-20"].update(meta=7), "no metadata object"),
    (lambda h: h["attachments"]["packed-20"].update(offset=3), "bad offset"),
])
def test_a_malformed_attachment_table_is_a_one_line_error(rough, tmp_path, edit, message):
    path = _copy(rough, tmp_path / "bad.cvc")
    _rewrite_header(path, edit)
    with pytest.raises(FileFormatError, match=message) as info:
        caveclod.load(path)
    assert "\n" not in str(info.value) and "bad.cvc" in str(info.value)


def test_a_server_sends_the_stored_variant_and_the_same_buffer_as_one_that_packs(rough, tmp_path, make_server,
                                                                                  caplog):
    bare = caveclod.load(rough)
    bare.attachments = {}
    bare.save(tmp_path / "bare.cvc")
    with caplog.at_level(logging.INFO, logger="caveclod.server"):
        server = make_server(meshes=[rough, tmp_path / "bare.cvc"])
        got = {}
        with Client(f"127.0.0.1:{server.port}") as client:
            for name in ("rough", "bare"):
                for morph in (False, True):
                    with client.session(name, width=640, height=360, morph_targets=morph) as s:
                        got[name, morph] = (s.info.vertex_packing, s.info.vertex_payload_crc32,
                                            s.vertex_buffer.payload)
    for morph in (False, True):
        assert got["rough", morph] == got["bare", morph]
    meshes_ = server.catalogue.meshes
    assert meshes_["rough"].stored == {(20, False), (20, True)} and meshes_["bare"].stored == set()
    packed = {r.fields["mesh"]: r.fields["stored"] for r in caplog.records if r.getMessage() == "server.packed"}
    assert packed == {"rough": True, "bare": False}


def test_a_mesh_the_build_cannot_simplify_stores_its_variants_too():
    """No collapse at all (one triangle): the morph variant's targets are every vertex itself."""
    from caveclod.builder.source import SourceMesh
    src = SourceMesh(positions=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64),
                     vertex_position=np.arange(3), faces=np.array([[0, 1, 2]]), face_material=np.zeros(1, np.int32),
                     materials=["m"])
    mesh = caveclod.build(src)
    assert mesh.n_internal == 0
    morph = vertexpack.stored_packed(mesh, 20, True)
    decoded = vertexpack.unpack(morph.packing, morph.data)
    assert decoded["morph_target"].reshape(-1).tolist() == [0, 1, 2]
