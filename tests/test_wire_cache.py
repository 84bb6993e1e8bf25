"""Cache mode's codec: slot writes, the slots checksum, frames whose vertex writes come in parts."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from caveclod import checksums, wire
from caveclod.client.buffers import IndexBuffers
from caveclod.client.slots import SlotBuffer
from caveclod.v1 import caveclod_pb2 as pb


def _format(colors: bool) -> pb.VertexFormat:
    d = 10
    blocks = wire.vertex_blocks(np.zeros((d, 3), "<f4"), np.zeros((d, 3), "<f4"), np.zeros((d, 2), "<f4"),
                                np.zeros((d, 4) if colors else (0, 4), np.uint8))
    return wire.vertex_format(blocks)


def _vertices(rng, k, colors):
    blocks = [rng.normal(size=(k, 3)).astype("<f4"), rng.normal(size=(k, 3)).astype("<f4"),
              rng.random((k, 2)).astype("<f4")]
    if colors:
        blocks.append(rng.integers(0, 256, (k, 4), dtype=np.uint8))
    return blocks


@settings(max_examples=50, deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=48), min_size=1, max_size=20).filter(lambda r: len(set(map(len, r))) == 1))
def test_rows_crc32_is_zlib_crc32(rows):
    width = len(rows[0])
    array = np.frombuffer(b"".join(rows), np.uint8).reshape(len(rows), width)
    assert checksums.rows_crc32(array).tolist() == [zlib.crc32(r) for r in rows]


@pytest.mark.parametrize("colors", [False, True])
def test_slots_checksum_is_the_sum_of_per_slot_crcs(colors):
    """Kept up to date write by write, it equals the definition computed from scratch with zlib."""
    rng = np.random.default_rng(4)
    n = 50
    held = {}
    sums = checksums.SlotChecksum(n)
    for _ in range(8):
        slots = np.sort(rng.choice(n, size=int(rng.integers(1, 12)), replace=False)).astype(np.uint32)
        blocks = _vertices(rng, len(slots), colors)
        sums.write(slots, blocks)
        for j, s in enumerate(slots.tolist()):
            held[s] = b"".join(b[j].tobytes() for b in blocks)
        want = sum(zlib.crc32(np.uint32(s).astype("<u4").tobytes() + row) for s, row in held.items()) % 2**32
        assert sums.value == want
    # No slots at all (a cache-mode keyframe of a camera whose parts are all hidden) changes nothing.
    before = sums.value
    sums.write(np.zeros(0, np.uint32), _vertices(rng, 0, colors))
    assert sums.value == before
    sums.reset()
    assert sums.value == 0 and not sums.terms.any()


@pytest.mark.parametrize("colors", [False, True])
def test_slot_writes_round_trip_planar(colors):
    rng = np.random.default_rng(5)
    fmt = _format(colors)
    for slots in (np.array([3, 7, 8, 20], np.uint32), np.arange(10, 16, dtype=np.uint32)):
        w = wire.SlotWrites(slots, _vertices(rng, len(slots), colors), checksum=0xDEADBEEF)
        msg = wire.encode_slot_writes(w)
        k = len(slots)
        assert len(msg.data) == k * (36 if colors else 32)
        # PLANAR: k positions, then k normals, ...
        assert msg.data[: 12 * k] == w.blocks[0].tobytes()
        assert (msg.first_slot, len(msg.slots)) == ((10, 0) if slots[0] == 10 else (0, 4 * k))
        back = wire.decode_slot_writes(pb.VertexWrites.FromString(msg.SerializeToString()), fmt, n_slots=21)
        np.testing.assert_array_equal(back.slots, slots)
        for a, b in zip(back.blocks, w.blocks):
            np.testing.assert_array_equal(a, b)
        assert back.checksum == 0xDEADBEEF


@pytest.mark.parametrize("fields, words", [
    (dict(data=b"\0" * 33), "not whole 32-byte vertices"),
    (dict(data=b"\0" * 64, slots=b"\0" * 4), "4 bytes of slots for 2 vertices"),
    (dict(data=b"\0" * 64, slots=np.array([4, 4], "<u4").tobytes()), "ascending"),
    (dict(data=b"\0" * 64, slots=np.array([4, 30], "<u4").tobytes()), "slot 30 past the 21 slots"),
    (dict(data=b"\0" * 64, first_slot=20), "slot 21 past the 21 slots"),
])
def test_malformed_slot_writes_are_refused(fields, words):
    with pytest.raises(wire.WireError, match=words):
        wire.decode_slot_writes(pb.VertexWrites(**fields), _format(False), n_slots=21)


def test_cache_options_in_open():
    msg = pb.Open()
    assert wire.cache_options(msg) is None
    wire.set_cache_options(msg, {"vertices": 4096, "strategy": "lru_pq", "pq_fraction": 0.25})
    assert wire.cache_options(pb.Open.FromString(msg.SerializeToString())) == \
        {"vertices": 4096, "strategy": "lru_pq", "pq_fraction": 0.25}
    msg = pb.Open(cache_vertices=0)
    assert wire.cache_options(msg) == {"vertices": 0, "strategy": None, "pq_fraction": None}   # 0 is seen, and refused later
    with pytest.raises(wire.WireError, match="no cache_vertices"):
        wire.cache_options(pb.Open(cache_strategy=pb.CACHE_STRATEGY_FA))


def test_a_keyframe_larger_than_a_part_comes_in_pieces_vertices_first():
    """Frame parts of at most max_bytes: each camera's vertex writes before its surfaces, each piece
    with the checksum; applied part by part they give the slots and buffers whole."""
    rng = np.random.default_rng(6)
    fmt = _format(False)
    n = 400
    cams = []
    for c in range(2):
        slots = np.sort(rng.choice(n, size=300, replace=False)).astype(np.uint32)
        blocks = _vertices(rng, 300, False)
        sums = checksums.SlotChecksum(n)
        sums.write(slots, blocks)
        tris = rng.choice(slots, size=(150, 3)).astype(np.uint32)
        surface = wire.Surface(0, 150, np.arange(150, dtype=np.uint32), tris, wire.buffer_crc32(tris))
        cams.append((wire.CameraFrameData(c, 0, keyframe=True, surfaces=[surface],
                                          vertices=wire.SlotWrites(slots, blocks, sums.value)), tris))
    parts = [pb.ServerMessage.FromString(b) for b in wire.frame_parts(1, 0, 0, [cam for cam, _ in cams], max_bytes=2000)]
    assert len(parts) > 10
    slot_buffers = [SlotBuffer(n, fmt) for _ in range(2)]
    buffers = IndexBuffers(2, 1)
    order = []
    for msg in parts:
        assert sum(len(cf.vertices.data) + len(cf.vertices.slots) + sum(len(s.tris) + len(s.slots)
                   for s in cf.surfaces) for cf in msg.frame.cameras) <= 2000
        for cf in msg.frame.cameras:
            if cf.HasField("vertices"):
                order.append((cf.camera, "v"))
                w = wire.decode_slot_writes(cf.vertices, fmt, n)
                assert w.checksum == cams[cf.camera][0].vertices.checksum
                slot_buffers[cf.camera].write(w)
            for sd in cf.surfaces:
                order.append((cf.camera, "s"))
                buffers.apply(cf.camera, wire.decode_surface(sd, n))
    assert order == sorted(order, key=lambda o: (o[0], o[1] == "s")), "a camera's vertices come before its surfaces"
    for c, (cam, tris) in enumerate(cams):
        np.testing.assert_array_equal(buffers.buffer(c, 0), tris)
        assert slot_buffers[c].checksum.value == cam.vertices.checksum
        assert slot_buffers[c].held[tris].all()
        np.testing.assert_array_equal(slot_buffers[c].positions[cam.vertices.slots], cam.vertices.blocks[0])
    with pytest.raises(ValueError, match="at least one vertex"):
        wire.frame_parts(1, 0, 0, [cams[0][0]], max_bytes=30)
