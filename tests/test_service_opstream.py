"""Op streams through the service: a damaged stream costs a keyframe, never a wrong
buffer; a resume may switch between RAW, OPS and OPS_LINKED; OPS_LINKED is granted
only to clients that hold the morph targets; cache mode carries op streams too."""

from __future__ import annotations

import numpy as np
import pytest

from caveclod.client import SessionProtocol
from caveclod.v1 import caveclod_pb2 as pb

from service import Driver


def _options():
    return {"width": 640, "height": 360, "fov_y": None, "tolerance_px": 1.0, "cull": None, "backface": None,
            "max_ops": None, "max_faces": None}


def _same_as_server(protocol, server) -> None:
    session = server.sessions.sessions[protocol.token]
    for c in range(protocol.n_cameras):
        mirror = session.cams[c].triangles() if not session.cached else \
            {m: b for m in range(session.n_materials) if len(b := session.cached[c].slot_buffer(m))}
        mine = protocol.buffers.triangles(c)
        assert sorted(mine) == sorted(mirror) and all(np.array_equal(mine[m], mirror[m]) for m in mine)
        if session.held is not None:
            for m in mine:
                assert np.array_equal(session.held_buffer(c, m), mine[m])


def _op_stream_sizes(protocol) -> list:
    """The byte counts of the op streams ``protocol`` receives from now on (a list that grows)."""
    sizes = []
    original = protocol.receive

    def record(msg):
        if msg.WhichOneof("kind") == "frame":
            sizes.extend(len(sd.ops) for cf in msg.frame.cameras for sd in cf.surfaces if sd.ops)
        return original(msg)

    protocol.receive = record
    return sizes


def _fly(driver, steps: int, start: int = 0) -> list:
    """Poses along a line over the terrain, each answered before the next; the frames."""
    info = driver.protocol.info
    lo, hi = info.mesh.bounds_min, info.mesh.bounds_max
    frames = []
    for k in range(start, start + steps):
        x = lo.x + (hi.x - lo.x) * (k % 10) / 10
        for c in range(driver.protocol.n_cameras):
            seq = driver.pose(c, (x, lo.y + c, hi.z + 20), ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z))
        while (update := driver.next_frame(timeout=2.0)) is not None:
            frames.append(update)
            if update.pose_seq >= seq:
                break
    while (update := driver.next_frame(timeout=0.4)) is not None:    # convergence frames
        frames.append(update)
    return frames


ENCODINGS = {"raw": pb.FRAME_ENCODING_RAW, "ops": pb.FRAME_ENCODING_OPS, "linked": pb.FRAME_ENCODING_OPS_LINKED}


@pytest.mark.parametrize("encoding", ["ops", "linked"])
@pytest.mark.parametrize("damage", ["flip", "cut", "kind"])
def test_a_damaged_op_stream_asks_for_a_keyframe_and_the_keyframe_repairs(server, damage, encoding):
    protocol = SessionProtocol("terrain", 1, _options(), cache=None, ack_window=1, frame_encoding=encoding)
    original = protocol.receive
    damaged = []

    def damage_one(msg):
        if msg.WhichOneof("kind") == "frame" and not damaged:
            for cf in msg.frame.cameras:
                for sd in cf.surfaces:
                    if len(sd.ops) > 4:
                        ops = bytearray(sd.ops)
                        if damage == "flip":
                            ops[len(ops) // 2] ^= 0x04
                        elif damage == "cut":
                            ops = ops[:-2]
                        else:
                            ops[1] = 0x0F                 # write 0 of kind 15: there is none
                        sd.ops = bytes(ops)
                        damaged.append(msg.frame.frame_seq)
                        break
        return original(msg)

    protocol.receive = damage_one
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        assert protocol.info.frame_encoding == ENCODINGS[encoding]
        frames = _fly(driver, 6)
        assert damaged, "no op stream was sent"
        hit = next(u for u in frames if u.frame_seq == damaged[0])
        assert 0 in hit.bad or 0 in hit.diverged, "a damaged stream must not pass as a good frame"
        assert any(u.cameras.get(0) and u.cameras[0].keyframe for u in frames if u.frame_seq > damaged[0])
        _same_as_server(protocol, server)
        requests = server.metrics.keyframe_requests
        assert requests.labels("bad_frame")._value.get() + requests.labels("checksum_mismatch")._value.get() == 1
    finally:
        driver.close()


@pytest.mark.parametrize("first, then", [("raw", "ops"), ("ops", "raw"), ("raw", "linked"), ("linked", "raw"),
                                         ("ops", "linked"), ("linked", "ops")])
def test_a_resume_may_switch_the_frame_encoding(server, first, then):
    protocol = SessionProtocol("terrain", 2, _options(), cache=None, ack_window=1, frame_encoding=first,
                               morph_targets=True)
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        _fly(driver, 3)
        _same_as_server(protocol, server)
    finally:
        driver.close()
    token = protocol.token
    protocol.frame_encoding = then
    driver = Driver(server.port, protocol)
    try:
        frames = _fly(driver, 5, start=3)
        assert protocol.token == token and protocol.resumes == 1
        assert protocol.info.frame_encoding == ENCODINGS[then]
        if first == "raw":      # the server starts what it holds for each camera from a keyframe
            assert {c for u in frames for c, cam in u.cameras.items() if cam.keyframe} == {0, 1}
        _same_as_server(protocol, server)
        assert protocol.divergences == 0 and protocol.bad_frames == 0
    finally:
        driver.close()


def test_cache_mode_sends_op_streams_of_slot_numbers(server):
    protocol = SessionProtocol("terrain", 1, _options(), cache=None, ack_window=1,
                               cache_mode={"vertices": 2500, "strategy": "lru", "pq_fraction": None})
    sizes = _op_stream_sizes(protocol)
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        _fly(driver, 8)
        assert sizes, "cache mode sent no op stream"
        _same_as_server(protocol, server)
        assert protocol.divergences == 0 and protocol.bad_frames == 0
    finally:
        driver.close()


@pytest.mark.parametrize("ask", [{"vertex_encoding": "float32"},
                                 {"cache_mode": {"vertices": 2500, "strategy": "lru", "pq_fraction": None}}])
def test_linked_op_streams_go_only_to_clients_that_hold_the_morph_targets(server, ask):
    """Without the packed download (no morph targets) or in cache mode (index buffers of
    slot numbers), an Open asking for OPS_LINKED gets OPS, and the frames read right."""
    protocol = SessionProtocol("terrain", 1, _options(), cache=None, ack_window=1, frame_encoding="linked", **ask)
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        assert protocol.info.frame_encoding == pb.FRAME_ENCODING_OPS
        _fly(driver, 4)
        _same_as_server(protocol, server)
        assert protocol.divergences == 0 and protocol.bad_frames == 0
    finally:
        driver.close()


def test_linked_op_streams_are_smaller_and_give_the_same_buffers(server):
    """Two sessions fly the same poses, one OPS and one OPS_LINKED: both end with the
    server's buffers, and the linked streams carry at most 85 % of the ops' bytes (58 % on the
    1M terrain's steady 30 Hz flyover: benchmarks/opstream.py; these are large)."""
    sizes = {}
    for encoding in ("ops", "linked"):
        protocol = SessionProtocol("terrain", 2, _options(), cache=None, ack_window=1, frame_encoding=encoding)
        sizes[encoding] = _op_stream_sizes(protocol)
        driver = Driver(server.port, protocol)
        try:
            driver.next_frame()
            assert protocol.info.frame_encoding == ENCODINGS[encoding]
            _fly(driver, 12)
            _same_as_server(protocol, server)
            assert protocol.divergences == 0 and protocol.bad_frames == 0
        finally:
            driver.close()
    assert len(sizes["linked"]) > 10
    assert sum(sizes["linked"]) <= 0.85 * sum(sizes["ops"]), sizes
