"""The client library used as a program uses it: what a session does once it is over, poses it
refuses, and timeouts. Found by a sweep of the library's API (each failed before its fix)."""

from __future__ import annotations

import asyncio
import math

import pytest

from caveclod.client import Client, SessionEnded
from caveclod.client.aio import AsyncClient

EYE, TARGET = (50.0, -200.0, 300.0), (200.0, 200.0, 0.0)


@pytest.fixture
def session(server, tmp_path):
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        s = client.session("terrain", cameras=2, width=640, height=360)
        try:
            yield s
        finally:
            s.close()


def test_a_closed_session_says_so_instead_of_waiting_for_ever(session):
    """After close(), send_pose returned a pose_seq nothing carried and next_frame() with no
    timeout never returned (15 s and on). (Called with timeouts here, so that a regression fails
    instead of hanging.)"""
    session.send_pose(0, EYE, TARGET)
    assert session.next_frame(timeout=30) is not None
    session.close()
    for call in (lambda: session.send_pose(0, EYE, TARGET), lambda: session.request_keyframe(),
                 lambda: session.next_frame(timeout=5), lambda: session.next_frame(timeout=0)):
        with pytest.raises(SessionEnded, match="closed"):
            call()
    session.close()                                          # twice: nothing


def test_a_session_the_server_ended_raises_again_on_every_call(session):
    session.send_pose(0, (math.nan, 0.0, 0.0), TARGET)      # the server refuses it: INVALID_ARGUMENT
    with pytest.raises(SessionEnded) as first:
        for _ in range(200):
            session.next_frame(timeout=0.5)
    # (With a timeout: were the fix to go, next_frame() with none would wait for ever, not fail.)
    for call in (lambda: session.next_frame(timeout=5), lambda: session.send_pose(0, EYE, TARGET)):
        with pytest.raises(SessionEnded) as again:
            call()
        assert again.value.code == first.value.code and again.value.details == first.value.details


def test_a_pose_refused_here_changes_nothing(session):
    """A refused pose was kept as the camera's latest (resent, and failing, on a resume) and used
    up a pose_seq; bool and float cameras were taken or failed unclearly."""
    seq = session.send_pose(0, EYE, TARGET)
    latest = list(session.protocol._latest)
    for camera, eye, error in [(0, (1.0, 2.0), ValueError), (True, EYE, TypeError), (1.0, EYE, TypeError),
                               (2, EYE, ValueError), (0, "abc", ValueError)]:
        with pytest.raises(error):
            session.send_pose(camera, eye, TARGET)
    assert session.protocol._latest == latest and session.protocol.pose_seq == seq
    assert session.send_pose(1, EYE, TARGET) == seq + 1


def test_next_frame_takes_any_timeout(session):
    """1e12 and inf raised OverflowError; NaN waited silently as None."""
    session.send_pose(0, EYE, TARGET)
    assert session.next_frame(timeout=math.inf) is not None          # waits as None: a frame comes
    session.send_pose(0, TARGET, EYE)
    assert session.next_frame(timeout=1e12) is not None              # beyond threading.TIMEOUT_MAX
    with pytest.raises(ValueError, match="nan"):
        session.next_frame(timeout=math.nan)


def test_async_next_frame_with_no_time_left_takes_what_has_arrived(server, tmp_path):
    """AsyncSession.next_frame(timeout=0) returned None before reading: a render loop polling so
    got no frame at all, where the blocking session's takes what has arrived."""
    async def fly():
        async with AsyncClient(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
            s = await client.session("terrain", width=640, height=360)
            s.send_pose(0, EYE, TARGET)
            got = 0
            for _ in range(400):                             # bounded: 400 polls, 20 s at most
                got += await s.next_frame(timeout=0) is not None
                if got >= 2:
                    break
                await asyncio.sleep(0.05)
            await s.close()
            with pytest.raises(SessionEnded):
                await s.next_frame(timeout=1)
            with pytest.raises(SessionEnded):
                s.send_pose(0, EYE, TARGET)
            return got
    assert asyncio.run(fly()) >= 2


def test_bad_session_arguments_are_named(server, tmp_path):
    """cameras=-1 and cache_vertices=-5 were protobuf's bare "Value out of range: -1"."""
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        for kwargs, name in [({"cameras": -1}, "cameras"), ({"cameras": 0}, "cameras"),
                             ({"cache_vertices": -5}, "cache_vertices")]:
            with pytest.raises(ValueError, match=name):
                client.session("terrain", **kwargs)


def test_a_resume_mended_at_its_second_try_leaves_the_session_open(monkeypatch):
    """A resume's try that failed (UNAVAILABLE: the server still restarting) was recorded as the
    session's end, and the session resumed at the next try then raised it on every call (found
    by a review). Only what ends the session for good is recorded."""
    import queue

    import grpc

    from caveclod.client import session as S

    class Failed(grpc.RpcError):
        def code(self):
            return grpc.StatusCode.UNAVAILABLE

        def details(self):
            return "connect failed"

    opened = []

    class Stream:
        def __init__(self, stub, first, md):
            opened.append(self)
            self.responses, self.requests = queue.Queue(), queue.Queue()
            self.responses.put(S._StreamEnd(Failed()) if len(opened) == 2 else "info")

        def send(self, msg):
            pass

        def end(self):
            pass

    class Protocol:
        token, cache_mode, ready = "t", {}, False

        def open_message(self):
            Protocol.ready = False

        def metadata(self, md):
            return md

        def receive(self, msg):
            Protocol.ready = True
            return [], None

        def pose_message(self, *args):
            return type("M", (), {"pose": type("P", (), {"pose_seq": 7})})

    class FakeClient:
        cache, stub, metadata = None, None, ()

    monkeypatch.setattr(S, "_Stream", Stream)
    monkeypatch.setattr(S, "backoff", lambda attempt: 0.0)
    s = S.Session(FakeClient(), Protocol(), retries=3)
    s._open(1.0)
    s._stream.responses.put(S._StreamEnd(Failed()))          # the stream breaks: resume
    assert s.next_frame(timeout=0.01) is None
    assert len(opened) == 3 and s._ended is None               # try 1 failed, try 2 opened
    assert s.send_pose(0, EYE, TARGET) == 7


def test_a_buffer_offered_from_the_cache_is_kept_until_the_server_takes_it(server, tmp_path, monkeypatch):
    """The buffer was looked up twice, when offered in Open and when SessionInfo said the server took
    it: gone between the two (other sessions' downloads pushed it out of the cache's memory, and its
    file had been deleted), the open ended with DATA_LOSS instead of using what was offered."""
    from caveclod.client.cache import VertexBufferCache
    target = f"127.0.0.1:{server.port}"
    with Client(target, cache_dir=tmp_path) as client:
        client.session("terrain", width=640, height=360).close()          # the buffer is now cached
    real, lookups = VertexBufferCache.lookup, []

    def gone_after_the_offer(self, key):
        lookups.append(key)
        return real(self, key) if len(lookups) == 1 else None
    monkeypatch.setattr(VertexBufferCache, "lookup", gone_after_the_offer)
    with Client(target, cache_dir=tmp_path) as client:
        s = client.session("terrain", width=640, height=360, timeout=30)
        try:
            assert s.info.vertex_buffer_cached and len(lookups) == 1
            s.send_pose(0, EYE, TARGET)
            assert s.next_frame(timeout=20) is not None
        finally:
            s.close()


def test_a_slot_count_past_the_wire_is_sent_as_the_most_it_carries():
    """cache_vertices=2**32 was protobuf's "Value out of range: 4294967296", a traceback in render,
    view and loadtest; the server clamps a count above the mesh's vertices to them anyway."""
    from caveclod.client.protocol import MAX_CACHE_VERTICES, SessionProtocol
    from caveclod.client.session import cache_mode
    for n, sent in ((2 ** 32, MAX_CACHE_VERTICES), (2 ** 70, MAX_CACHE_VERTICES), (500, 500)):
        p = SessionProtocol("m", 1, {}, cache_mode=cache_mode(n, None, None))
        assert p.open_message().open.cache_vertices == sent


def test_session_renderer_takes_every_pose_the_renderer_takes():
    """The README: "a pose is a Pose, a Camera, or a View"; SessionRenderer indexed p[0] and refused
    Cameras and Views (TypeError), and ``from caveclod.render import SessionRenderer`` was an ImportError."""
    import types
    import caveclod
    from caveclod.paths import Pose
    from caveclod.render import Camera, SessionRenderer
    eye, target, up = (1.0, 2.0, 3.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    poses = [Pose(eye, target, up), (eye, target, up), Camera(eye, target, up, 30.0),
             caveclod.View(eye=eye, target=target, up=up, fov_y=30.0)]
    cams = SessionRenderer.views(types.SimpleNamespace(fov_y=50.0), poses)
    assert {(tuple(c.eye), tuple(c.target), tuple(c.up), c.fov_y) for c in cams} == {(eye, target, up, 50.0)}


def test_a_session_that_ended_closes_at_once(server, tmp_path):
    """After next_frame raised the session's end, close() (the end of a `with` block) sent Close on
    the finished stream and waited out its whole timeout, 5 s, for an end already taken."""
    import time
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        s = client.session("terrain", width=640, height=360)
        s.send_pose(0, (0.5, 0.5, 9.0), (0.5, 0.5, 0.0), (0.0, 0.0, 1.0))     # up along the view: refused
        with pytest.raises(SessionEnded, match="parallel"):
            for _ in range(100):                                              # bounded: 100 s at most
                s.next_frame(timeout=1)
        t0 = time.monotonic()
        s.close(timeout=30)
        assert time.monotonic() - t0 < 10, "close() waited for a stream end already taken"


def test_keyframe_requests_and_ack_windows_are_checked_before_they_are_sent(server, tmp_path):
    """request_keyframe(2) on two cameras was sent and ended the whole session (INVALID_ARGUMENT,
    raised later by next_frame); -1 and ack_window=2**32 were protobuf's bare "Value out of range"."""
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        for bad in (-1, 1.5, True):
            with pytest.raises(ValueError, match="ack_window"):
                client.session("terrain", ack_window=bad)
        with client.session("terrain", cameras=2, width=640, height=360, ack_window=2 ** 40) as s:
            assert s.info.ack_window == 32
            for bad in (2, -1, 1.0):
                with pytest.raises(ValueError, match="camera"):
                    s.request_keyframe(bad)
            s.request_keyframe(1)
            s.send_pose(0, EYE, TARGET)
            assert s.next_frame(timeout=20) is not None


def test_an_async_session_of_a_closed_client_says_so(server, tmp_path):
    """After AsyncClient.close(), next_frame raised a bare asyncio.CancelledError, which asyncio.run
    and TaskGroups take for the caller's own cancellation; the blocking client says CANCELLED."""
    async def fly():
        client = AsyncClient(f"127.0.0.1:{server.port}", cache_dir=tmp_path)
        s = await client.session("terrain", width=640, height=360)
        s.send_pose(0, EYE, TARGET)
        assert await s.next_frame(timeout=20) is not None
        await client.close()
        with pytest.raises(SessionEnded, match="client was closed"):
            for _ in range(50):                                  # bounded: 50 s at most
                await s.next_frame(timeout=1)
    asyncio.run(asyncio.wait_for(fly(), 120))


def test_a_resume_try_that_times_out_is_tried_again(monkeypatch):
    """A server paused (SIGSTOP) past a resume try's 10 s still holds the session, but a try that
    timed out (DEADLINE_EXCEEDED) ended the session at once, after one try of twelve."""
    from types import SimpleNamespace

    import grpc

    from caveclod.client import aio as A
    from caveclod.client import session as S
    monkeypatch.setattr(S, "backoff", lambda attempt: 0.0)
    monkeypatch.setattr(A, "backoff", lambda attempt: 0.0)
    late = S.SessionEnded(grpc.StatusCode.DEADLINE_EXCEEDED, "no SessionInfo and vertex buffer within 10.0 s")

    def stand_in(tries):
        def _open(timeout):
            tries.append(timeout)
            if len(tries) == 1:
                raise late
        return SimpleNamespace(retries=3, _stream=SimpleNamespace(end=lambda: None), _open=_open,
                               _end=lambda exc, final=True: exc)
    tries = []
    S.Session._resume(stand_in(tries), None)
    assert len(tries) == 2

    async def resume():
        tries = []
        this = stand_in(tries)
        opened = this._open

        async def _open(timeout):
            opened(timeout)
        this._open = _open
        await A.AsyncSession._resume(this, None)
        return tries
    assert len(asyncio.run(resume())) == 2


def test_a_session_dropped_without_close_frees_its_slot(make_server, tmp_path):
    """The reader thread held the call, so a Session and Client dropped without close() kept their
    stream open for the life of the process, and the server its slot (RESOURCE_EXHAUSTED after)."""
    import gc
    server = make_server(max_sessions=1, resume_ttl=1)

    def forget():
        client = Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path)
        s = client.session("terrain", width=640, height=360)
        s.send_pose(0, EYE, TARGET)
        assert s.next_frame(timeout=20) is not None
    forget()
    gc.collect()
    from service import wait_until
    assert wait_until(lambda: not server.sessions.sessions, timeout=20), "the dropped session kept its slot"
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        client.session("terrain", width=640, height=360).close()
