"""The client library's failover, without a balancer: the stream's server is
replaced by another one (a proxy switched over), so a resume reaches a server
that does not know the token and starts a fresh session. The full picture,
through nginx with replicas killed and drained, is tests/test_deploy_failover.py.
"""

from __future__ import annotations

import asyncio
import time

import grpc
import pytest

from service import proxy_to


def _fly_until_failover(s, proxy, other_port, lo, hi, poses_after: int) -> list:
    """20 frames, then the proxy is switched to ``other_port`` and cut, ``poses_after`` more poses
    are sent (lost with the broken stream) and frames read until the fresh session answers a pose.
    Returns the FrameUpdates of the fresh session."""
    from caveclod.paths import circle
    for i in range(20):
        s.send_pose(0, *circle(lo, hi, 0, i / 30))
        assert s.next_frame(timeout=10) is not None
    proxy.target = other_port
    proxy.cut()
    for i in range(poses_after):
        s.send_pose(0, *circle(lo, hi, 0, (20 + i) / 30))
    after = []
    for _ in range(30):
        frame = s.next_frame(timeout=10)
        assert frame is not None
        if s.protocol.failovers:                    # SessionInfo came first: a frame of the fresh session
            after.append(frame)
            if 0 in frame.cameras and frame.cameras[0].pose_seq:
                return after
    raise AssertionError("the fresh session answered no pose")


@pytest.mark.parametrize("poses_after", [0, 5])
def test_a_resume_that_finds_another_server_goes_on_as_a_fresh_session(make_server, tmp_path, poses_after):
    """The viewer's camera may be still (no pose after the break): the library
    sends its latest pose to the fresh session, numbered on from the old one, so the
    picture comes back without the caller doing anything."""
    from caveclod.client import Client
    a, b = make_server(), make_server()
    with proxy_to(a.port) as proxy, Client(f"127.0.0.1:{proxy.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", width=640, height=360) as s:
            lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
            old_token = s.protocol.token
            after = _fly_until_failover(s, proxy, b.port, lo, hi, poses_after)
            p = s.protocol
            assert p.failovers == 1 and p.resumes == 0 and not s.info.resumed
            assert s.info.vertex_buffer_cached                  # the buffer it holds is offered by hash
            assert p.token != old_token and list(b.sessions.sessions) == [p.token]
            assert after[0].frame_seq == 1 and after[0].cameras[0].keyframe     # the fresh session's keyframe
            # The latest pose again, numbered on from the old session's (never back: an
            # asyncio client may have sent poses on the new stream before its SessionInfo).
            assert after[-1].cameras[0].pose_seq == p.pose_seq > 1
            assert p.divergences == 0 and p.bad_frames == 0
            mirror = b.sessions.sessions[p.token].cams[0].triangles()
            assert sorted(mirror) == sorted(s.triangles(0))


def _answered(session, seconds: float = 10.0) -> bool:
    """Read frames until one answers the session's last pose (True), or ``seconds`` pass (False)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        f = session.next_frame(timeout=max(deadline - time.monotonic(), 0.01))
        if f is not None and f.pose_seq >= session.protocol.pose_seq:
            return True
    return False


def test_the_affinity_key_stays_with_the_session_across_streams(make_server, tmp_path, monkeypatch):
    """Every Session call of a session carries the same x-caveclod-session key; sessions differ."""
    from caveclod.client import Client
    from caveclod.client.protocol import AFFINITY_HEADER
    seen = []

    class Recorder(grpc.aio.ServerInterceptor):
        async def intercept_service(self, continuation, details):
            if details.method.endswith("/Session"):
                seen.append(dict(details.invocation_metadata).get(AFFINITY_HEADER))
            return await continuation(details)

    real = grpc.aio.server
    monkeypatch.setattr(grpc.aio, "server", lambda interceptors=(), **kw: real(
        interceptors=[*interceptors, Recorder()], **kw))
    server = make_server(transport="grpc")                    # the interceptor above is grpc.aio's
    with proxy_to(server.port) as proxy, Client(f"127.0.0.1:{proxy.port}", cache_dir=tmp_path) as client:
        s1 = client.session("terrain", width=64, height=64)
        s1.send_pose(0, (0, 0, 60), (20, 20, 0))
        _answered(s1)                                           # not only the keyframe: the pose's frame
        proxy.cut()                                             # s1 resumes on a new stream
        s1.send_pose(0, (1, 0, 60), (20, 20, 0))
        assert _answered(s1) and s1.protocol.resumes == 1
        s2 = client.session("terrain", width=64, height=64)
        s1.close()
        s2.close()
    key1, key2 = s1.protocol.affinity_key, s2.protocol.affinity_key
    assert seen == [key1, key1, key2] and key1 != key2 and len(key1) == 32


def test_a_stream_reset_by_a_balancer_is_retried_a_server_error_is_not():
    from caveclod.client.session import LOCAL_WRITE_RACE, retriable
    assert retriable(grpc.StatusCode.UNAVAILABLE, "failed to connect")
    assert retriable(grpc.StatusCode.INTERNAL, "Stream removed (RST_STREAM (Received RST_STREAM with error code 2))")
    assert not retriable(grpc.StatusCode.INTERNAL, "Unexpected <class 'RuntimeError'>: a server bug")
    assert not retriable(grpc.StatusCode.INVALID_ARGUMENT, "RST_STREAM")
    assert retriable(grpc.StatusCode.INTERNAL, LOCAL_WRITE_RACE)     # grpc.aio's own, see below
    assert not retriable(grpc.StatusCode.INTERNAL, LOCAL_WRITE_RACE + ": a server saying so")
    assert not retriable(grpc.StatusCode.RESOURCE_EXHAUSTED, "")


async def _open_and_fly(client, frames: int):
    """An asyncio session on the test terrain, ``frames`` poses along a circle flown, each answered."""
    from caveclod.paths import circle
    s = await client.session("terrain", width=640, height=360)
    lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
    for i in range(frames):
        s.send_pose(0, *circle(lo, hi, 0, i / 30))
        assert await s.next_frame(timeout=10) is not None
    return s


def test_the_asyncio_client_fails_over_too(make_server, tmp_path):
    from caveclod.client.aio import AsyncClient
    a, b = make_server(), make_server()

    async def main():
        with proxy_to(a.port) as proxy:
            async with AsyncClient(f"127.0.0.1:{proxy.port}", cache_dir=tmp_path) as client:
                s = await _open_and_fly(client, 10)
                proxy.target = b.port
                proxy.cut()
                frames = []
                for _ in range(20):                           # the camera is still: no pose from here on
                    f = await s.next_frame(timeout=10)
                    assert f is not None
                    frames.append(f)
                    if s.protocol.failovers and 0 in f.cameras and f.cameras[0].pose_seq:
                        break
                await s.close()
                return s, frames

    s, frames = asyncio.run(main())
    assert s.protocol.failovers == 1 and s.info.vertex_buffer_cached and s.protocol.divergences == 0
    assert frames[-1].cameras[0].pose_seq == s.protocol.pose_seq > 1   # the latest pose, sent again, numbered on


def test_the_asyncio_client_resumes_after_a_write_that_raced_the_streams_end(make_server, tmp_path):
    """grpc.aio ends a call whose write fails in the core (the stream was reset under it: a replica
    died or drained) with its own INTERNAL "Internal error from Core", and the server's status is
    lost. The client resumes with its token: the session and its index buffers go on, and a
    frame lost with the old stream is made good by a keyframe, not counted as a bad frame."""
    from caveclod.client.aio import AsyncClient
    from caveclod.client.session import LOCAL_WRITE_RACE
    from caveclod.paths import circle
    server = make_server()

    async def main():
        async with AsyncClient(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
            s = await _open_and_fly(client, 5)
            lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
            call = s._stream.call

            async def raced_read():        # what grpc.aio's reader sees after such a write
                call.cancel()
                raise grpc.aio.AioRpcError(grpc.StatusCode.INTERNAL, grpc.aio.Metadata(), grpc.aio.Metadata(),
                                           details=LOCAL_WRITE_RACE)
            call.read = raced_read
            s.send_pose(0, *circle(lo, hi, 0, 5 / 30))
            # The frame for that pose goes out on the old stream and is lost with it: the resume
            # says so (last_frame_seq behind), and the server keyframes, numbered on from its own.
            session = next(iter(server.sessions.sessions.values()))
            for _ in range(200):
                if session.frame_seq > s.protocol.last_applied:
                    break
                await asyncio.sleep(0.01)
            assert session.frame_seq > s.protocol.last_applied
            for _ in range(20):
                f = await s.next_frame(timeout=10)
                assert f is not None
                if s.protocol.resumes and 0 in f.cameras and f.cameras[0].pose_seq:
                    break
            await s.close()
            return s

    s = asyncio.run(main())
    assert s.protocol.resumes == 1 and s.protocol.failovers == 0 and s.info.resumed
    assert s.protocol.divergences == 0 and s.protocol.bad_frames == 0
