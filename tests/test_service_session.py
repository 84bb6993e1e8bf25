"""End to end through real sockets: what a client holds equals the server's mirror
after every frame, and equals a core camera fed the same views.

Replay rule (the proto's Lod.Session comment): each CameraFrame that carries
stats is exactly one ``CameraState.update`` with the view of its pose_seq,
and a keyframe then puts every buffer in vertex-cache order
(``CameraState.reorder_for_vertex_cache``).
"""

from __future__ import annotations

import numpy as np
import pytest

import caveclod
from caveclod.client import SessionProtocol
from caveclod.client.cache import VertexBufferCache
from caveclod.v1 import caveclod_pb2 as pb

from service import Driver


def _options(width=640, height=360, tolerance=1.0, max_ops=None, cull=None, strict_bound=None):
    return {"width": width, "height": height, "fov_y": None, "tolerance_px": tolerance, "cull": cull,
            "backface": None, "max_ops": max_ops, "max_faces": None, "strict_bound": strict_bound}


def _mirror(server, token):
    return server.sessions.sessions[token]


def _same(a: dict, b: dict) -> bool:
    return sorted(a) == sorted(b) and all(np.array_equal(a[k], b[k]) for k in a)


def _rows_sorted(buffers: dict) -> dict:
    """{material: the (k, 3) triangles in row order}: the buffers' contents, whatever their slots."""
    return {m: t[np.lexsort(t.T[::-1])] for m, t in buffers.items()}


def _check_frame(driver, server, core, views, update):
    """Replay the frame's updates on the core cameras; compare client, mirror and core."""
    p = driver.protocol
    session = _mirror(server, p.token)
    for c, cam in update.cameras.items():
        if cam.stats is not None:
            delta = core[c].update(views[cam.pose_seq])
            assert (delta.splits, delta.collapses) == (cam.stats.splits, cam.stats.collapses)
        if cam.keyframe:                  # a keyframe's buffers go out in vertex-cache order
            for m in range(core[c].n_materials):
                core[c].reorder_for_vertex_cache(m)
    for c in range(p.n_cameras):
        mirror = session.cams[c].triangles()
        assert _same(p.buffers.triangles(c), mirror), f"frame {update.frame_seq}: camera {c} differs from the mirror"
        assert _same(core[c].triangles(), mirror), f"frame {update.frame_seq}: camera {c} differs from the replay"
        if session.held is not None:      # OPS: what the server takes the client to hold is what it holds
            held = {m: session.held_buffer(c, m) for m in range(p.buffers.materials) if p.buffers.count(c, m)}
            assert _same(held, mirror), f"frame {update.frame_seq}: camera {c}'s held buffers differ"
    assert session.frame_encoding == (pb.FRAME_ENCODING_OPS if p.frame_encoding == "ops" else pb.FRAME_ENCODING_RAW)
    assert p.divergences == 0 and p.bad_frames == 0


def _core_cameras(path, info):
    mesh = caveclod.load(path)
    o = info.options
    budget = dict(max_ops=o.max_ops if o.HasField("max_ops") else None,
                  max_faces=o.max_faces if o.HasField("max_faces") else None,
                  strict_bound=o.HasField("strict_bound") and o.strict_bound)
    return [mesh.new_camera(**budget) for _ in range(info.cameras)]


def _view(info, eye, target):
    o = info.options
    return caveclod.View(eye=eye, target=target, up=(0, 0, 1), fov_y=o.fov_y_deg, width=o.viewport_width,
                         height=o.viewport_height, tolerance_px=o.tolerance_px, cull=o.cull, backface=o.backface)


@pytest.mark.parametrize("tolerance, max_ops, encoding, strict", [(1.0, None, "ops", None), (0.5, 40, "ops", None),
                                                                  (1.0, None, "raw", None), (0.5, None, "ops", True)])
def test_random_walk_client_equals_mirror_equals_core(server, terrain_path, tolerance, max_ops, encoding, strict,
                                                      tmp_path):
    rng = np.random.default_rng(11 if max_ops is None else 12)
    protocol = SessionProtocol("terrain", 3, _options(tolerance=tolerance, max_ops=max_ops, strict_bound=strict),
                               cache=VertexBufferCache(tmp_path), ack_window=1, frame_encoding=encoding)
    driver = Driver(server.port, protocol)
    try:
        update = driver.next_frame(ack=False)
        info = protocol.info
        assert update.frame_seq == 1 and all(c.keyframe for c in update.cameras.values())
        core = _core_cameras(terrain_path, info)
        views = {}
        _check_frame(driver, server, core, views, update)
        driver.ack()
        lo = np.array([info.mesh.bounds_min.x, info.mesh.bounds_min.y, info.mesh.bounds_min.z])
        hi = np.array([info.mesh.bounds_max.x, info.mesh.bounds_max.y, info.mesh.bounds_max.z])
        size = hi - lo
        eyes = [lo + size * [rng.random(), rng.random(), 1.2] for _ in range(3)]
        frames = 0
        for step in range(100):
            moved = [c for c in range(3) if rng.random() < 0.6] or [int(rng.integers(3))]
            for c in moved:
                for _ in range(1 + int(rng.random() < 0.2)):     # now and then a pose superseded at once
                    step_xy = rng.normal(scale=0.08, size=2) * size[:2]
                    eyes[c] = np.clip(eyes[c] + [*step_xy, 0.0], lo + [0, 0, size[2] * 0.3], hi + [0, 0, size[2] * 2])
                    target = lo + size * [rng.random(), rng.random(), 0.3]
                    seq = driver.pose(c, tuple(eyes[c]), tuple(target))
                    views[seq] = _view(info, tuple(eyes[c]), tuple(target))
            latest = protocol.pose_seq
            while True:            # frames until the last pose is answered (or superseded)
                update = driver.next_frame(ack=False)
                assert update is not None, f"step {step}: no frame answered pose {latest}"
                _check_frame(driver, server, core, views, update)
                driver.ack()
                frames += 1
                if update.pose_seq >= latest:
                    break
        while (update := driver.next_frame(timeout=0.5, ack=False)) is not None:   # convergence frames
            _check_frame(driver, server, core, views, update)
            driver.ack()
            frames += 1
        assert frames >= 100
        assert all(cam.n_faces > 0 for cam in core)
        # The session's cameras have the strict bound exactly when asked (SessionInfo says so too).
        assert info.options.strict_bound is bool(strict)
        assert all(cam.strict_bound is bool(strict) for cam in _mirror(server, protocol.token).cams)
        for cam in core:
            cam.validate()          # under the strict bound: no node beside a position gone before it
    finally:
        driver.close()


@pytest.fixture(scope="module")
def big_terrain(tmp_path_factory):
    """224 x 224 cells, 100,352 triangles: a full-detail frame is over 1 MiB."""
    path = tmp_path_factory.mktemp("big") / "big.cvc"
    caveclod.build("default", size=224).save(path)
    return path


def test_frames_over_1_mib_come_in_parts_and_keyframes_replace_buffers(make_server, big_terrain, tmp_path):
    server = make_server(meshes=[big_terrain])
    # RAW: op streams make the whole mesh's delta fit one part (0.5 MB).
    protocol = SessionProtocol("big", 1, _options(tolerance=0.0, cull=False), cache=None, ack_window=1,
                               frame_encoding="raw")
    driver = Driver(server.port, protocol)
    parts = []
    original = protocol.receive

    def counting(msg):                   # record each Frame part as it arrives
        if msg.WhichOneof("kind") == "frame":
            parts.append((msg.frame.frame_seq, msg.frame.continued, msg.ByteSize(),
                          sum(len(s.slots) + len(s.tris) for c in msg.frame.cameras for s in c.surfaces)))
        return original(msg)

    protocol.receive = counting
    try:
        first = driver.next_frame()
        assert first.frame_seq == 1 and first.parts == 1            # the base mesh is small
        info = protocol.info
        core = _core_cameras(big_terrain, info)
        for m in range(core[0].n_materials):          # frame 1, the keyframe of the base mesh
            core[0].reorder_for_vertex_cache(m)
        lo, hi = info.mesh.bounds_min, info.mesh.bounds_max
        eye, target = (lo.x, lo.y, hi.z + 100.0), (hi.x, hi.y, lo.z)
        seq = driver.pose(0, eye, target)
        views = {seq: _view(info, eye, target)}
        update = driver.next_frame(ack=False)
        assert update.parts >= 2, "the full mesh (1.2 MB of indices) must come in several parts"
        _check_frame(driver, server, core, views, update)
        assert sum(len(t) for t in protocol.buffers.triangles(0).values()) == info.mesh.faces
        driver.ack()
        while (update := driver.next_frame(timeout=0.5)) is not None:
            _check_frame(driver, server, core, views, update)
        # A keyframe in several parts: its first part empties the buffers, the rest fill them.
        protocol.buffers.apply(0, __import__("caveclod.wire", fromlist=["Surface"]).Surface(
            0, 3, np.arange(3, dtype=np.uint32), np.zeros((3, 3), np.uint32)))   # junk the keyframe must erase
        driver.send(protocol.keyframe_message(0, pb.KEYFRAME_REASON_CLIENT_RESET))
        update = driver.next_frame(ack=False)
        assert update.cameras[0].keyframe and update.parts >= 2
        _check_frame(driver, server, core, views, update)
        driver.ack()
        assert all(array_bytes <= (1 << 20) for _, _, _, array_bytes in parts)
        assert all(size < 4 << 20 for _, _, size, _ in parts)
        assert [c for _, c, _, _ in parts].count(False) == len({f for f, _, _, _ in parts})  # one last part a frame
    finally:
        driver.close()


def test_a_corrupted_buffer_is_found_by_crc_and_repaired_by_a_keyframe(server, terrain_path, tmp_path):
    protocol = SessionProtocol("terrain", 2, _options(), cache=None, ack_window=1)
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        info = protocol.info
        lo, hi = info.mesh.bounds_min, info.mesh.bounds_max
        for c in range(2):
            driver.pose(c, (lo.x + 5 * c, lo.y, hi.z + 10), ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z))
        while driver.next_frame(timeout=0.5) is not None:
            pass
        for m in range(len(info.mesh.materials)):          # a bit flipped in each of the client's copies
            if protocol.buffers.count(1, m):
                protocol.buffers.buffer(1, m)[0, 0] ^= 1
        seen, x = [], lo.x
        for _ in range(20):        # move camera 1 until a frame touches a corrupted buffer (it checks only those)
            x += (hi.x - lo.x) / 20
            seq = driver.pose(1, (x, hi.y, hi.z + 10), ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z))
            while (update := driver.next_frame(timeout=1.0)) is not None:
                seen.append(update)
                if update.pose_seq >= seq and not update.diverged:
                    break
            if any(c.keyframe for u in seen for c in u.cameras.values()):
                break
        assert any(1 in u.diverged for u in seen), "the CRC check must find the corrupted buffer"
        assert protocol.divergences == 1
        keyframe = next(u for u in seen if any(c.keyframe for c in u.cameras.values()))
        assert keyframe.cameras[1].keyframe and 0 not in keyframe.cameras
        while driver.next_frame(timeout=0.5) is not None:
            pass
        mirror = _mirror(server, protocol.token)
        for c in range(2):
            assert _same(protocol.buffers.triangles(c), mirror.cams[c].triangles())
        assert server.metrics.keyframe_requests.labels("checksum_mismatch")._value.get() == 1
    finally:
        driver.close()


def test_a_second_session_takes_the_vertex_buffer_from_the_cache(server, tmp_path):
    from caveclod.client import Client
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", width=640, height=360) as first:
            assert not first.info.vertex_buffer_cached
            payload = first.vertex_buffer.payload
            assert first.next_frame(timeout=5).frame_seq == 1
        assert [p.name for p in tmp_path.iterdir()] == [first.info.vertex_packing.vertex_buffer_hash]
        sent_before = server.metrics.total("bytes_sent")
        with client.session("terrain", width=640, height=360) as second:
            assert second.info.vertex_buffer_cached
            assert second.vertex_buffer.payload == payload
            assert second.vertex_buffer.positions.shape == (second.info.mesh.vertices, 3)
            assert second.next_frame(timeout=5).frame_seq == 1
        # No chunk travelled: far fewer bytes than the payload.
        assert server.metrics.total("bytes_sent") - sent_before < len(payload) / 2
    # A damaged cache file is detected by its CRC and downloaded again (by a
    # new client: one client's sessions share the copy it holds in memory).
    cache_file = next(tmp_path.iterdir())
    blob = cache_file.read_bytes()
    cache_file.write_bytes(bytes([blob[0] ^ 0xFF]) + blob[1:])
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", width=640, height=360) as third:
            assert not third.info.vertex_buffer_cached
            assert third.vertex_buffer.payload == payload


def test_blocking_and_asyncio_clients_see_the_same_frames(server, tmp_path):
    import asyncio

    from caveclod.client import Client
    from caveclod.client.aio import AsyncClient
    from caveclod.paths import flyover

    def poses(info):
        lo, hi = info.mesh.bounds_min, info.mesh.bounds_max
        return [flyover((lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z), 0, t / 10) for t in range(10)]

    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", width=640, height=360) as s:
            for p in poses(s.info):
                s.send_pose(0, *p)
                while (f := s.next_frame(timeout=2)) is not None and f.pose_seq < s.protocol.pose_seq:
                    pass
            # Converged: 1 s without a frame (a loaded machine makes them slowly).
            while s.next_frame(timeout=1.0) is not None:
                pass
            blocking = s.triangles(0)

    async def run():
        async with AsyncClient(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
            s = await client.session("terrain", width=640, height=360)
            for p in poses(s.info):
                s.send_pose(0, *p)
                while (f := await s.next_frame(timeout=2)) is not None and f.pose_seq < s.protocol.pose_seq:
                    pass
            while await s.next_frame(timeout=1.0) is not None:
                pass
            await s.close()
            return s.triangles(0), s.protocol.divergences

    asynchronous, divergences = asyncio.run(run())
    assert divergences == 0
    # The same triangles; their slots may differ: which poses a busy server
    # answers (latest pose wins) and when it converges set the order of writes.
    assert _same(_rows_sorted(blocking), _rows_sorted(asynchronous))


def test_costly_frames_made_back_to_back_on_workers_arrive_in_order_and_check(server, terrain_path, tmp_path,
                                                                              monkeypatch):
    """Every frame costly (made on a worker), poses always waiting: a frame's successor starts on
    a worker as soon as it is made (``_Stream._make_on_worker``). The frames come in order, every
    CRC holds, and the client ends with the server's buffers."""
    from caveclod.server import service as service_module
    from caveclod.server import session as session_module
    from caveclod.paths import flyover

    monkeypatch.setattr(session_module, "CHEAP_SECONDS", 0.0)         # no frame is cheap
    chained = []
    make = service_module._Stream._make_on_worker

    def counted(self):
        parts, follow = make(self)
        chained.append(follow is not None)
        return parts, follow
    monkeypatch.setattr(service_module._Stream, "_make_on_worker", counted)
    protocol = SessionProtocol("terrain", 1, _options(tolerance=0.5), cache=VertexBufferCache(tmp_path),
                               ack_window=4)
    driver = Driver(server.port, protocol)
    try:
        update = driver.next_frame()
        info = protocol.info
        lo = (info.mesh.bounds_min.x, info.mesh.bounds_min.y, info.mesh.bounds_min.z)
        hi = (info.mesh.bounds_max.x, info.mesh.bounds_max.y, info.mesh.bounds_max.z)
        seqs = [update.frame_seq]
        for i in range(40):                 # far poses, two ahead of what the frames answer
            driver.pose(0, *flyover(lo, hi, 0, 20.0 * (i % 3))[:2])
            if i % 2:
                update = driver.next_frame()
                assert update is not None, f"no frame after pose {i}"
                seqs.append(update.frame_seq)
        while (update := driver.next_frame(timeout=1.0)) is not None:     # the rest, and convergence
            seqs.append(update.frame_seq)
        assert seqs == list(range(1, len(seqs) + 1)), seqs
        assert protocol.divergences == 0 and protocol.bad_frames == 0
        assert _same(protocol.buffers.triangles(0), _mirror(server, protocol.token).cams[0].triangles())
        assert any(chained), "no frame started its successor on a worker"
    finally:
        driver.close()


def test_a_close_read_just_before_the_stream_broke_ends_the_session(make_server):
    """Under load a browser's Close message and its close frame can arrive together: the reader
    takes the Close (the session's end is set) and the stream breaks before the writer ends the
    session. The session then ends as closed, not left for the resume TTL holding its place in
    --max-sessions (it was, until the reaper expired it: the Chromium unload test failed so)."""
    import grpc
    from service import open_message
    from caveclod.server.session import End
    server = make_server(resume_ttl=60)
    server.sessions.ready.wait(30)
    session, generation, resumed = server.sessions.open(open_message().open)
    assert not resumed and session.token in server.sessions.sessions
    assert session.accept(pb.ClientMessage(close=pb.Close(reason="the page was closed")), generation)
    ended = server.metrics.session_ends.labels("closed")
    before = ended._value.get()
    server.sessions.stream_ended(session, generation, End(grpc.StatusCode.CANCELLED, "the stream broke", False))
    assert session.token not in server.sessions.sessions
    assert ended._value.get() == before + 1


def test_a_stream_that_broke_without_a_close_stays_resumable(make_server):
    import grpc
    from service import open_message
    from caveclod.server.session import End
    server = make_server(resume_ttl=60)
    server.sessions.ready.wait(30)
    session, generation, _ = server.sessions.open(open_message().open)
    server.sessions.stream_ended(session, generation, End(grpc.StatusCode.CANCELLED, "the stream broke", False))
    assert session.token in server.sessions.sessions and not session.attached
