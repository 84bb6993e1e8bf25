"""caveclod.wire: surface deltas, frame parts, the planar vertex payload, options."""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest

from caveclod import wire
from caveclod.client.buffers import IndexBuffers
from caveclod.v1 import caveclod_pb2 as pb


def _surface(rng, material, count, k, run=False):
    slots = np.arange(count - k, count, dtype=np.uint32) if run else \
        np.sort(rng.choice(count, size=k, replace=False)).astype(np.uint32)
    return wire.Surface(material, count, slots, rng.integers(0, 1000, size=(k, 3), dtype=np.uint32))


def test_surface_round_trip_uses_first_slot_for_runs():
    rng = np.random.default_rng(1)
    scattered, run = _surface(rng, 2, 500, 40), _surface(rng, 3, 500, 40, run=True)
    a, b = wire.encode_surface(scattered), wire.encode_surface(run)
    assert len(a.slots) == 160 and a.first_slot == 0
    assert b.slots == b"" and b.first_slot == 460
    for msg, s in ((a, scattered), (b, run)):
        back = wire.decode_surface(pb.SurfaceDelta.FromString(msg.SerializeToString()), n_vertices=1000)
        np.testing.assert_array_equal(back.slots, s.slots)
        np.testing.assert_array_equal(back.tris, s.tris)
        assert back.crc32 is None and back.count == 500
    assert wire.decode_surface(wire.encode_surface(wire.Surface(0, 0, np.zeros(0, np.uint32),
                                                                np.zeros((0, 3), np.uint32), 0)), 10).crc32 == 0


@pytest.mark.parametrize("fields, words", [
    (dict(tris=b"\0" * 13), "whole"),
    (dict(count=5, tris=b"\0" * 24, slots=b"\0" * 4), "slots for 2"),
    (dict(count=5, tris=b"\0" * 24, slots=np.array([3, 3], "<u4").tobytes()), "ascending"),
    (dict(count=5, tris=b"\0" * 24, slots=np.array([3, 1], "<u4").tobytes()), "ascending"),
    (dict(count=3, tris=b"\0" * 24, slots=np.array([1, 3], "<u4").tobytes()), "past the count"),
    (dict(count=3, tris=b"\0" * 24, first_slot=2), "past the count"),
    (dict(count=3, tris=np.array([[0, 1, 10]], "<u4").tobytes()), "vertex index 10"),
])
def test_malformed_surfaces_are_refused(fields, words):
    with pytest.raises(wire.WireError, match=words):
        wire.decode_surface(pb.SurfaceDelta(material=1, **fields), n_vertices=10)


def _apply_parts(parts, buffers, n_vertices):
    keyed = set()
    for msg in parts:
        for cf in msg.frame.cameras:
            if cf.keyframe and cf.camera not in keyed:
                buffers.reset(cf.camera)
                keyed.add(cf.camera)
            for sd in cf.surfaces:
                buffers.apply(cf.camera, wire.decode_surface(sd, n_vertices))


@pytest.mark.parametrize("max_bytes", [16, 100, 1000, 1 << 20])
def test_frame_parts_apply_to_the_same_buffers_whatever_the_split(max_bytes):
    rng = np.random.default_rng(max_bytes)
    before = {m: rng.integers(0, 1000, size=(300, 3), dtype=np.uint32) for m in range(3)}
    cams = []
    for c in range(2):
        surfaces = [_surface(rng, 0, 290, 50), _surface(rng, 1, 320, 20, run=True),
                    wire.Surface(2, 0, np.zeros(0, np.uint32), np.zeros((0, 3), np.uint32))]
        stats = {"splits": 3, "collapses": 4, "update_us": 5, "active_faces": 610, "budget_exhausted": False,
                 "pose_age_us": 7}
        cams.append(wire.CameraFrameData(camera=c, pose_seq=9 + c, surfaces=surfaces, stats=stats))
    cams.append(wire.CameraFrameData(camera=2, pose_seq=4))             # an answered pose, nothing changed
    parts = [pb.ServerMessage.FromString(b) for b in wire.frame_parts(5, 11, 2, cams, max_bytes=max_bytes)]
    frames = [p.frame for p in parts]
    assert all(f.frame_seq == 5 and f.pose_seq == 11 for f in frames)
    assert [f.continued for f in frames] == [True] * (len(frames) - 1) + [False]
    assert frames[0].poses_superseded == 2 and all(f.poses_superseded == 0 for f in frames[1:])
    assert all(sum(len(s.slots) + len(s.tris) for c in f.cameras for s in c.surfaces) <= max_bytes for f in frames)
    stats = [(c.camera, c.stats.splits) for f in frames for c in f.cameras if c.HasField("stats")]
    assert sorted(stats) == [(0, 3), (1, 3)]                            # once per camera, in its first part
    assert any(c.camera == 2 and c.pose_seq == 4 for f in frames for c in f.cameras)
    buffers = IndexBuffers(3, 3)
    for c in range(2):
        for m, b in before.items():
            buffers.apply(c, wire.Surface(m, len(b), np.arange(len(b), dtype=np.uint32), b))
    _apply_parts(parts, buffers, 1000)
    for c, cam in enumerate(cams[:2]):
        for s in cam.surfaces:
            expect = np.zeros((s.count, 3), np.uint32)
            keep = min(s.count, 300)
            expect[:keep] = before[s.material][:keep]
            expect[s.slots] = s.tris
            np.testing.assert_array_equal(buffers.buffer(c, s.material), expect)
    if max_bytes == 1 << 20:
        assert len(parts) == 1


def test_a_keyframe_in_parts_replaces_what_the_client_held():
    rng = np.random.default_rng(4)
    full = {m: rng.integers(0, 1000, size=(n, 3), dtype=np.uint32) for m, n in enumerate((120, 0, 75))}
    surfaces = [wire.Surface(m, len(t), np.arange(len(t), dtype=np.uint32), t, wire.buffer_crc32(t))
                for m, t in full.items()]
    parts = [pb.ServerMessage.FromString(b) for b in
             wire.frame_parts(9, 0, 0, [wire.CameraFrameData(0, 3, keyframe=True, surfaces=surfaces)], max_bytes=600)]
    assert len(parts) > 3 and all(c.keyframe for p in parts for c in p.frame.cameras)
    assert all(s.slots == b"" for p in parts for c in p.frame.cameras for s in c.surfaces)   # runs: no slot arrays
    buffers = IndexBuffers(1, 3)
    for m in range(3):                       # stale contents, longer than the keyframe's buffers
        buffers.apply(0, wire.Surface(m, 200, np.arange(200, dtype=np.uint32), np.ones((200, 3), np.uint32)))
    _apply_parts(parts, buffers, 1000)
    for m, t in full.items():
        np.testing.assert_array_equal(buffers.buffer(0, m), t)
        assert buffers.crc32(0, m) == (zlib.crc32(t.astype("<u4")) if len(t) else 0)


def test_vertex_payload_chunks_and_planar_views():
    rng = np.random.default_rng(2)
    d = 50_000
    pos, nrm = rng.normal(size=(d, 3)).astype("<f4"), rng.normal(size=(d, 3)).astype("<f4")
    uv, rgba = rng.random((d, 2)).astype("<f4"), rng.integers(0, 256, size=(d, 4), dtype=np.uint8)
    for colors in (rgba, np.zeros((0, 4), np.uint8)):
        blocks = wire.vertex_blocks(pos, nrm, uv, colors)
        fmt = wire.vertex_format(blocks)
        assert fmt.layout == pb.VERTEX_LAYOUT_PLANAR and fmt.vertex_count == d
        assert [a.offset for a in fmt.attributes][:3] == [0, 12 * d, 24 * d]
        chunks = [m.vertex_chunk for m in wire.vertex_chunks(blocks, max_bytes=300_000)]
        assert all(len(c.data) <= 300_000 for c in chunks) and chunks[0].offset == 0
        payload = b"".join(c.data for c in chunks)
        assert len(payload) == fmt.payload_bytes == chunks[-1].total == (36 if len(colors) else 32) * d
        assert zlib.crc32(payload) == wire.payload_crc32(b.data for b in blocks)
        arrays = wire.read_vertex_payload(fmt, payload)
        np.testing.assert_array_equal(arrays["position"], pos)
        np.testing.assert_array_equal(arrays["texcoord"], uv)
        assert ("color" in arrays) == bool(len(colors))
    with pytest.raises(wire.WireError, match="past"):
        wire.read_vertex_payload(fmt, payload[:-1])


def test_options_round_trip_keeps_unset_fields_unset():
    full = {"width": 1280, "height": 720, "fov_y": 45.0, "tolerance_px": 0.0, "cull": False, "backface": True,
            "max_ops": 7, "max_faces": 9000, "prune": False, "strict_bound": True}
    assert wire.options_to_dict(wire.options_from_dict(full)) == full
    sparse = wire.options_to_dict(wire.options_from_dict({"width": 64, "height": 32}))
    assert sparse == {"width": 64, "height": 32, "fov_y": None, "tolerance_px": None, "cull": None,
                      "backface": None, "max_ops": None, "max_faces": None, "prune": None, "strict_bound": None}
    assert math.isnan(wire.options_to_dict(wire.options_from_dict({"fov_y": math.nan}))["fov_y"])


def test_garbage_is_returned_as_an_error_not_raised():
    assert isinstance(wire.parse_client_message(b"\xff\xff\xff"), wire.WireError)
    assert isinstance(wire.parse_list_request(b"\x0a\x05ab"), wire.WireError)
    ok = wire.parse_client_message(pb.ClientMessage(ack=pb.Ack(frame_seq=3)).SerializeToString())
    assert ok.ack.frame_seq == 3
