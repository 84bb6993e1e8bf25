"""caveclod.frames writes exactly the bytes protobuf's serializer makes of the same messages."""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings, strategies as st

from caveclod import frames
from caveclod.v1 import caveclod_pb2 as pb

U32 = st.integers(0, 2**32 - 1)
U64 = st.integers(0, 2**64 - 1)


@settings(max_examples=200, deadline=None)
@given(st.fixed_dictionaries({}, optional={
    "splits": U32, "collapses": U32, "update_us": U64, "active_faces": U64, "budget_exhausted": st.booleans(),
    "pose_age_us": U64, "cache_hits": U32, "cache_inserts": U32,
    "cache_tolerance_px": st.floats(allow_nan=False, allow_infinity=False), "updates": U32, "hidden_parts": U32}))
@example({"cache_tolerance_px": -0.0})          # protobuf writes a negative zero (its bits are not zero)
def test_stats_bytes_equal_protobufs(stats):
    assert frames.stats_bytes(stats) == pb.CameraStats(**stats).SerializeToString()


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 300), st.integers(0, 5000), st.integers(0, 40), st.booleans(),
       st.one_of(st.none(), U32), st.one_of(st.none(), st.binary(max_size=40)), st.integers(0, 2**32 - 1))
def test_surface_bytes_equal_protobufs(material, count, k, run, crc, ops, seed):
    rng = np.random.default_rng(seed)
    k = min(k, count)
    slots = (np.arange(count - k, count) if run else np.sort(rng.choice(max(count, 1), k, replace=False))
             ).astype(np.uint32)
    tris = rng.integers(0, 2**32, size=(k, 3), dtype=np.uint64).astype(np.uint32)
    s = frames.Surface(material, count, slots, tris, crc, ops)
    ref = pb.SurfaceDelta(material=material, count=count)
    if ops is not None:
        ref.ops = ops
    else:
        ref.tris = tris.astype("<u4").tobytes()
        if k and frames.is_run(slots):
            ref.first_slot = int(slots[0])
        elif k:
            ref.slots = slots.astype("<u4").tobytes()
    if crc is not None:
        ref.crc32 = crc
    assert frames.surface_bytes(s) == ref.SerializeToString()


def test_frame_parts_are_canonical_protobuf(seed=7):
    """Every part parses, and protobuf writes the parsed message back to the same bytes."""
    rng = np.random.default_rng(seed)
    for max_bytes in (24, 200, 5000, 1 << 20):
        cams = []
        for c in range(3):
            surfaces = [frames.Surface(m, 300, np.sort(rng.choice(300, 30, replace=False)).astype(np.uint32),
                                       rng.integers(0, 900, (30, 3)).astype(np.uint32), int(rng.integers(2**32)))
                        for m in range(2)]
            surfaces.append(frames.Surface(2, 50, np.zeros(0, np.uint32), np.zeros((0, 3), np.uint32), 0,
                                           ops=bytes(rng.integers(0, 256, 12, dtype=np.uint8))))
            writes = frames.SlotWrites(np.arange(5, 9, dtype=np.uint32),
                                       [rng.random((4, 3), dtype=np.float32), rng.random((4, 2), dtype=np.float32)],
                                       int(rng.integers(2**32))) if c == 1 else None
            cams.append(frames.CameraFrameData(c, 10 + c, keyframe=c == 2, surfaces=surfaces, vertices=writes,
                                               stats={"splits": c, "update_us": 1234, "active_faces": 99}))
        cams.append(frames.CameraFrameData(3, 0))
        parts = frames.frame_parts(2**40, 77, 3, cams, max_bytes=max_bytes)
        for i, data in enumerate(parts):
            msg = pb.ServerMessage.FromString(data)
            assert msg.SerializeToString() == data
            assert msg.frame.frame_seq == 2**40 and msg.frame.continued == (i < len(parts) - 1)
