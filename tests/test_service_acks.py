"""Acks carried by poses (SessionInfo.acks_on_poses): fewer client messages, the same window."""

from __future__ import annotations

import pytest

from caveclod.client import SessionProtocol

from service import Driver


def _options():
    return {"width": 640, "height": 360, "fov_y": None, "tolerance_px": 1.0, "cull": None, "backface": None,
            "max_ops": None, "max_faces": None}


@pytest.mark.parametrize("server_reads_them", [True, False])
def test_poses_carry_the_acks_only_where_the_server_reads_them(server, server_reads_them):
    protocol = SessionProtocol("terrain", 1, _options(), cache=None, ack_window=4)
    original = protocol.receive

    def as_old_server(msg):          # an older server: SessionInfo without acks_on_poses
        if msg.WhichOneof("kind") == "session_info" and not server_reads_them:
            msg.session_info.acks_on_poses = False
        return original(msg)

    protocol.receive = as_old_server
    sent = []
    driver = Driver(server.port, protocol)
    send = driver.send
    driver.send = lambda m: (sent.append(m), send(m))
    try:
        driver.next_frame()
        assert protocol.info.acks_on_poses == server_reads_them
        lo, hi = protocol.info.mesh.bounds_min, protocol.info.mesh.bounds_max
        frames = 0
        for k in range(40):
            x = lo.x + (hi.x - lo.x) * k / 40
            seq = driver.pose(0, (x, lo.y, hi.z + 20), ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z))
            while (update := driver.next_frame(timeout=2.0)) is not None:
                frames += 1
                if update.pose_seq >= seq:
                    break
        while driver.next_frame(timeout=0.5) is not None:       # convergence frames, no pose to carry acks
            frames += 1
        session = server.sessions.sessions[protocol.token]
        plain = sum(m.WhichOneof("kind") == "ack" for m in sent)
        carried = sum(m.WhichOneof("kind") == "pose" and m.pose.ack_frame_seq > 0 for m in sent)
        assert frames >= 40
        if server_reads_them:
            assert carried >= 15 and plain <= 3, (carried, plain)
        else:
            assert carried == 0 and plain >= 15, (carried, plain)
        # Either way the server's window kept open: every frame made was acked but the last few.
        assert session.frame_seq - session.acked < 4
        assert protocol.divergences == 0 and protocol.bad_frames == 0
    finally:
        driver.close()
