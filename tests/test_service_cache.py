"""Cache mode through real sockets (loopback, port 0): the client holds N slots per camera.

For each strategy, at every frame:

* the client draws the triangles resident mode draws: the same triangles in
  the same slots, with the same positions, normals and texture coordinates
  (a core camera replaying the frames' updates is resident mode);
* it holds at most N vertices a camera and never received the vertex buffer;
* every slot its index buffers use holds a vertex, and checksums agree.

Then: a cache too small for a frame coarsens that camera; too small for the
base mesh, or otherwise bad cache options, end the stream with
INVALID_ARGUMENT and a message that says what to send; a tampered vertex
write or a triangle on an empty slot is caught and repaired by a keyframe;
a resume that lost frames gets its slots back in a keyframe.
"""

from __future__ import annotations

import grpc
import numpy as np
import pytest

import caveclod
from caveclod.client import SessionProtocol
from caveclod.v1 import caveclod_pb2 as pb

from cachereference import active_vertices
from service import Driver, open_message, proxy_to, raw_stream

STRATEGIES = ("fa", "lru", "lru_pq")
WIDTH, HEIGHT = 640, 360


def _options(tolerance=1.0, strict_bound=None):
    return {"width": WIDTH, "height": HEIGHT, "fov_y": None, "tolerance_px": tolerance, "cull": None,
            "backface": None, "max_ops": None, "max_faces": None, "strict_bound": strict_bound}


def _walk(mesh, steps: int, seed: int, cameras: int):
    """(camera, eye, target) poses: cameras drifting over the terrain and looking at it, now and then far off."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds()
    size = hi - lo
    eyes = [lo + size * [rng.random(), rng.random(), 0.6] for _ in range(cameras)]
    out = []
    for step in range(steps):
        c = step % cameras
        eyes[c] = np.clip(eyes[c] + [*(rng.normal(scale=0.07, size=2) * size[:2]), 0.0],
                          lo + [0, 0, size[2] * 0.3], hi + [0, 0, size[2] * 2])
        target = lo + size * [rng.random(), rng.random(), 0.2]
        out.append((c, tuple(eyes[c]), tuple(target)))
    return out


def _view(eye, target, tolerance=1.0):
    return caveclod.View(eye=eye, target=target, up=(0, 0, 1), width=WIDTH, height=HEIGHT, tolerance_px=tolerance)


def _peak(mesh, walk, cameras, **options) -> int:
    """The most vertices any camera uses on the walk, each pose refined until still (a dry run)."""
    cams = [mesh.new_camera(**options) for _ in range(cameras)]
    peak = len(active_vertices(cams[0].triangles()))
    for c, eye, target in walk:
        for _ in range(4):
            if cams[c].update(_view(eye, target)).operations == 0:
                break
            peak = max(peak, len(active_vertices(cams[c].triangles())))
    return peak


def _drawn(attributes: dict, buffers: dict) -> dict:
    """{material: {attribute: (k, 3, c)}}: what a renderer draws from index buffers over vertex attributes."""
    return {m: {name: a[np.asarray(t, np.int64)] for name, a in attributes.items()} for m, t in buffers.items() if len(t)}


def _assert_same_drawing(got: dict, want: dict, what: str):
    assert sorted(got) == sorted(want), f"{what}: other materials drawn"
    for m in want:
        for name in want[m]:
            assert np.array_equal(got[m][name], want[m][name]), f"{what}: material {m} {name}s differ"


def _resident_attributes(mesh) -> dict:
    out = {"position": np.asarray(mesh.vertex_positions), "normal": np.asarray(mesh.vertex_normals),
           "texcoord": np.asarray(mesh.vertex_uvs)}
    if len(mesh.vertex_colors):
        out["color"] = np.asarray(mesh.vertex_colors)
    return out


@pytest.mark.parametrize("strategy, strict", [(s, False) for s in STRATEGIES] + [("lru", True)])
def test_cache_mode_draws_what_resident_mode_draws(server, terrain_path, strategy, strict):
    mesh = caveclod.load(terrain_path)
    cameras = 2
    walk = _walk(mesh, 40, seed=3, cameras=cameras)
    n = _peak(mesh, walk, cameras, strict_bound=strict) + 40
    protocol = SessionProtocol("terrain", cameras, _options(strict_bound=strict or None), cache=None, ack_window=1,
                               cache_mode={"vertices": n, "strategy": strategy, "pq_fraction": None})
    kinds = []
    original = protocol.receive

    def record(msg):
        kinds.append(msg.WhichOneof("kind"))
        return original(msg)

    protocol.receive = record
    driver = Driver(server.port, protocol)
    core = [mesh.new_camera(strict_bound=strict) for _ in range(cameras)]
    resident = _resident_attributes(mesh)
    views, written, frames = {}, [np.zeros(n, np.int64) for _ in range(cameras)], 0

    def check(update):
        nonlocal frames
        frames += 1
        for c, cam in update.cameras.items():
            if cam.stats is not None:
                assert cam.stats.updates == 1 and cam.stats.cache_tolerance_px == 1.0, "the cache holds every frame"
                core[c].update(views[cam.pose_seq])
            if cam.keyframe:                # a keyframe's buffers go out in vertex-cache order
                for m in range(core[c].n_materials):
                    core[c].reorder_for_vertex_cache(m)
            for w in cam.vertex_writes:
                written[c][np.asarray(w.slots, np.int64)] += 1
        assert protocol.divergences == 0 and protocol.bad_frames == 0
        for c in range(cameras):
            slots = protocol.slots[c]
            assert len(slots.held) == n and slots.n_held <= n
            buffers = protocol.buffers.triangles(c)
            for m, tris in buffers.items():
                assert slots.held[tris].all(), f"frame {update.frame_seq}: camera {c} uses a slot holding no vertex"
            _assert_same_drawing(_drawn(slots.arrays, buffers), _drawn(resident, core[c].triangles()),
                                 f"frame {update.frame_seq}, camera {c}")

    try:
        first = driver.next_frame()
        info = protocol.info
        assert (info.cache_vertices, wire_strategy(info.cache_strategy)) == (n, strategy)
        assert protocol.vertex is None and "vertex_chunk" not in kinds
        check(first)
        for c, eye, target in walk:
            seq = driver.pose(c, eye, target)
            views[seq] = _view(eye, target)
            while True:
                update = driver.next_frame()
                assert update is not None, f"no frame answered pose {seq}"
                check(update)
                if update.pose_seq >= seq:
                    break
        while (update := driver.next_frame(timeout=0.5)) is not None:      # convergence frames
            check(update)
        assert frames >= len(walk)
        assert any((w > 1).any() for w in written), "the walk must make the strategy overwrite slots"
        assert "vertex_chunk" not in kinds
        session = server.sessions.sessions[protocol.token]
        assert session.cached[0].cache.strategy == strategy
        assert info.options.strict_bound is strict and all(cam.strict_bound is strict for cam in session.cams)
    finally:
        driver.close()


def wire_strategy(value: int) -> str:
    from caveclod import wire
    return wire.strategy_name(value)


def test_a_cache_too_small_for_a_frame_coarsens_that_camera(server, terrain_path):
    """Camera 0 looks down close (too many vertices for its slots), camera 1 far off: only 0 is coarsened."""
    mesh = caveclod.load(terrain_path)
    lo, hi = mesh.bounds()
    centre = tuple((lo + hi) / 2)
    close = ((lo[0] + 0.3 * (hi[0] - lo[0]), centre[1], hi[2] + 0.02 * (hi[0] - lo[0])), centre)
    far = ((centre[0], centre[1] - 50 * (hi[0] - lo[0]), hi[2]), centre)
    probe = mesh.new_camera()
    for _ in range(3):
        probe.update(_view(*close))
    need = len(active_vertices(probe.triangles()))
    base = len(active_vertices(mesh.new_camera().triangles()))
    n = base + (need - base) // 2
    protocol = SessionProtocol("terrain", 2, _options(), cache=None, ack_window=1,
                               cache_mode={"vertices": n, "strategy": "lru", "pq_fraction": None})
    driver = Driver(server.port, protocol)
    attributes = _resident_attributes(mesh)
    try:
        driver.next_frame()
        session = server.sessions.sessions[protocol.token]
        stats = {0: [], 1: []}
        for step in range(6):
            for c, (eye, target) in enumerate((close, far)):
                seq = driver.pose(c, eye, target)
            while (update := driver.next_frame(ack=False)) is not None:
                for c, cam in update.cameras.items():
                    if cam.stats is not None:
                        stats[c].append(cam.stats)
                for c in range(2):
                    held = protocol.slots[c]
                    assert held.n_held <= n and session.cached[c].active.count <= n
                    _assert_same_drawing(_drawn(held.arrays, protocol.buffers.triangles(c)),
                                         _drawn(attributes, session.cams[c].triangles()), f"camera {c}")
                driver.ack()
                if update.pose_seq >= seq:
                    break
        assert protocol.divergences == 0 and protocol.bad_frames == 0
        assert max(s.cache_tolerance_px for s in stats[0]) > 1.0, "the close camera was coarsened"
        assert any(s.updates > 1 for s in stats[0]), "fitting took more than one update"
        assert all(s.cache_tolerance_px == 1.0 and s.updates == 1 for s in stats[1]), "the far camera was not"
    finally:
        driver.close()


def _base_vertices(terrain_path) -> int:
    return len(active_vertices(caveclod.load(terrain_path).new_camera().triangles()))


@pytest.mark.parametrize("fields, message", [
    ({"cache_vertices": 0}, "Open: cache_vertices is 0; give a slot count"),
    ({"cache_strategy": pb.CACHE_STRATEGY_FA}, "sets a cache strategy or priority-queue fraction but no cache_vertices"),
    ({"cache_pq_fraction": 0.2}, "no cache_vertices"),
    ({"cache_vertices": 5000, "cache_strategy": pb.CACHE_STRATEGY_LRU, "cache_pq_fraction": 0.2},
     "applies to the lru_pq strategy only"),
    ({"cache_vertices": 5000, "cache_strategy": pb.CACHE_STRATEGY_LRU_PQ, "cache_pq_fraction": 1.0},
     r"in \[0, 1\), got 1.0"),
    ({"cache_vertices": 5000, "cache_strategy": 9}, "Open.cache_strategy 9 is unknown"),
])
def test_bad_cache_options_end_the_stream_saying_what_to_send(server, fields, message):
    msg = open_message()
    for k, v in fields.items():
        setattr(msg.open, k, v)
    code, details, responses = raw_stream(server.port, [msg])
    assert code == grpc.StatusCode.INVALID_ARGUMENT and not responses
    assert pytest.importorskip("re").search(message, details), details


def test_a_cache_smaller_than_the_base_mesh_is_refused_at_open(server, terrain_path):
    base = _base_vertices(terrain_path)
    msg = open_message()
    msg.open.cache_vertices = base - 1
    code, details, responses = raw_stream(server.port, [msg])
    assert code == grpc.StatusCode.INVALID_ARGUMENT and not responses
    assert details == (f"Open.cache_vertices is {base - 1}, but the base mesh of 'terrain' alone uses {base} "
                       f"vertices; ask for at least {base} slots (several times more keeps detail), or leave "
                       "cache_vertices unset for a resident vertex buffer")
    # The blocking client raises it as SessionEnded; exactly the base mesh's count is enough.
    from caveclod.client import Client, SessionEnded
    with Client(f"127.0.0.1:{server.port}", cache_dir=False) as client:
        with pytest.raises(SessionEnded, match="ask for at least"):
            client.session("terrain", width=WIDTH, height=HEIGHT, cache_vertices=base - 1)
        with client.session("terrain", width=WIDTH, height=HEIGHT, cache_vertices=base, cache_strategy="fa") as s:
            frame = s.next_frame(timeout=10)
            assert frame.cameras[0].vertices_written == base == s.slots(0).n_held
            assert s.vertex_buffer is None and s.info.cache_pq_fraction == 0.0
        # More slots than the mesh has vertices are clamped.
        with client.session("terrain", width=WIDTH, height=HEIGHT, cache_vertices=10**9) as s:
            assert s.info.cache_vertices == s.info.mesh.vertices
            assert s.info.cache_strategy == pb.CACHE_STRATEGY_LRU


def _settle(driver):
    while driver.next_frame(timeout=0.3) is not None:
        pass


def _until_answered(driver, seq) -> list:
    """Frames (acked) until one answers pose ``seq``."""
    frames = []
    while True:
        update = driver.next_frame()
        assert update is not None, f"no frame answered pose {seq}"
        frames.append(update)
        if update.pose_seq >= seq:
            return frames


def _check_mirror(protocol, server):
    session = server.sessions.sessions[protocol.token]
    attributes = _resident_attributes(session.served.mesh)
    for c in range(protocol.n_cameras):
        _assert_same_drawing(_drawn(protocol.slots[c].arrays, protocol.buffers.triangles(c)),
                             _drawn(attributes, session.cams[c].triangles()), f"camera {c}")


def test_a_tampered_vertex_write_is_found_and_repaired_by_a_keyframe(server):
    protocol = SessionProtocol("terrain", 1, _options(), cache=None, ack_window=1,
                               cache_mode={"vertices": 3000, "strategy": "lru_pq", "pq_fraction": 0.25})
    original = protocol.receive
    tampered = []

    def tamper(msg):
        if msg.WhichOneof("kind") == "frame" and not tampered:
            for cf in msg.frame.cameras:
                if cf.HasField("vertices") and len(cf.vertices.data) and msg.frame.frame_seq > 1:
                    data = bytearray(cf.vertices.data)
                    data[0] ^= 0x40                       # a position's bit flipped in transit
                    cf.vertices.data = bytes(data)
                    tampered.append(msg.frame.frame_seq)
        return original(msg)

    protocol.receive = tamper
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        lo, hi = protocol.info.mesh.bounds_min, protocol.info.mesh.bounds_max
        seen = []
        for k in range(10):
            seq = driver.pose(0, (lo.x + k * (hi.x - lo.x) / 10, lo.y, hi.z + 50),
                              ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z))
            seen += _until_answered(driver, seq)
            if any(0 in u.cameras and u.cameras[0].keyframe for u in seen):
                break
        assert tampered and protocol.divergences == 1
        assert any(0 in u.diverged for u in seen) and any(u.cameras.get(0) and u.cameras[0].keyframe for u in seen)
        assert server.metrics.keyframe_requests.labels("checksum_mismatch")._value.get() == 1
        _settle(driver)
        _check_mirror(protocol, server)
    finally:
        driver.close()


def test_a_triangle_on_an_empty_slot_is_a_bad_frame(server):
    protocol = SessionProtocol("terrain", 1, _options(), cache=None, ack_window=1,
                               cache_mode={"vertices": 3000, "strategy": "fa", "pq_fraction": None},
                               frame_encoding="raw")         # the test rewrites raw triangles
    original = protocol.receive
    done = []

    def point_at_an_empty_slot(msg):
        if msg.WhichOneof("kind") == "frame" and msg.frame.frame_seq > 1 and not done:
            for cf in msg.frame.cameras:
                for sd in cf.surfaces:
                    if len(sd.tris):
                        tris = np.frombuffer(sd.tris, "<u4").copy()
                        tris[0] = 2999                    # never written: FA fills the lowest slots first
                        sd.tris = tris.tobytes()
                        done.append(msg.frame.frame_seq)
                        return original(msg)
        return original(msg)

    protocol.receive = point_at_an_empty_slot
    driver = Driver(server.port, protocol)
    try:
        driver.next_frame()
        lo, hi = protocol.info.mesh.bounds_min, protocol.info.mesh.bounds_max
        bad, keyframed = [], False
        for k in range(6):
            seq = driver.pose(0, (lo.x, lo.y + k * (hi.y - lo.y) / 6, hi.z + 50),
                              ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z))
            for update in _until_answered(driver, seq):
                bad += update.bad
                keyframed |= bool(bad) and 0 in update.cameras and update.cameras[0].keyframe
            if keyframed:
                break
        assert done and bad == [0] and protocol.bad_frames == 1
        assert server.metrics.keyframe_requests.labels("bad_frame")._value.get() == 1
        _settle(driver)
        _check_mirror(protocol, server)
    finally:
        driver.close()


@pytest.mark.parametrize("lost", [False, True])
def test_a_resume_keeps_the_slots_or_sends_them_again(server, lost):
    """Without a lost frame the client's slots stay valid; with one, a keyframe refills them."""
    from caveclod.client import Client
    with proxy_to(server.port) as proxy, Client(f"127.0.0.1:{proxy.port}", cache_dir=False) as client:
        with client.session("terrain", cameras=2, width=WIDTH, height=HEIGHT, cache_vertices=2500,
                            cache_strategy="lru_pq", cache_pq_fraction=0.2) as s:
            s.next_frame(timeout=10)
            lo, hi = s.info.mesh.bounds_min, s.info.mesh.bounds_max
            centre = ((lo.x + hi.x) / 2, (lo.y + hi.y) / 2, lo.z)
            for c in range(2):
                s.send_pose(c, (lo.x + c * 100, lo.y, hi.z + 50), centre)
            while s.next_frame(timeout=0.5) is not None:
                pass
            if lost:
                s.protocol.last_applied -= 1     # as if the last frame had gone with the stream
            proxy.cut()
            keyframes = set()
            for k in range(1, 4):
                for c in range(2):
                    s.send_pose(c, (lo.x + k * (hi.x - lo.x) / 4, hi.y - c * 100, hi.z + 50), centre)
                while (f := s.next_frame(timeout=10)) is not None:
                    for c, cam in f.cameras.items():
                        if cam.keyframe:         # the slots were emptied: only this frame's writes are held
                            keyframes.add(c)
                            assert cam.vertices_written == s.slots(c).n_held > 0
                    if f.pose_seq >= s.protocol.pose_seq:
                        break
            while (f := s.next_frame(timeout=0.3)) is not None:
                keyframes |= {c for c, cam in f.cameras.items() if cam.keyframe}
            assert s.protocol.resumes == 1
            assert keyframes == ({0, 1} if lost else set())
            # A lost frame is no bad frame: SessionInfo.last_frame_seq says the keyframes go on from there.
            assert s.protocol.divergences == 0 and s.protocol.bad_frames == 0
            _check_mirror(s.protocol, server)


def test_a_resume_must_keep_the_cache(server):
    from caveclod.client import Client
    with Client(f"127.0.0.1:{server.port}", cache_dir=False) as client:
        s = client.session("terrain", width=WIDTH, height=HEIGHT, cache_vertices=2500)
        try:
            s.next_frame(timeout=10)
            token = s.protocol.token
        finally:
            s.drop()
    msg = open_message()
    msg.open.resume_token = token
    msg.open.cache_vertices = 2400
    code, details, _ = raw_stream(server.port, [msg])
    assert code == grpc.StatusCode.INVALID_ARGUMENT
    assert "resume of a session with cache 2500 slots lru by an Open asking for 2400 slots lru" in details


def test_a_failover_to_another_server_starts_the_slots_afresh(make_server):
    """A resume that reaches a server without the session (its replica gone) gets a
    fresh cache-mode session: the client empties its slots and the fresh session's
    keyframe fills them; what it draws is again the new server's state."""
    from caveclod.client import Client
    from caveclod.paths import circle
    a, b = make_server(), make_server()
    with proxy_to(a.port) as proxy, Client(f"127.0.0.1:{proxy.port}", cache_dir=False) as client:
        with client.session("terrain", cameras=1, width=WIDTH, height=HEIGHT, cache_vertices=2500,
                            cache_strategy="fa") as s:
            lo, hi = s.info.mesh.bounds_min, s.info.mesh.bounds_max
            lo, hi = (lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z)
            for i in range(10):
                s.send_pose(0, *circle(lo, hi, 0, i / 30))
                assert s.next_frame(timeout=10) is not None
            held_before = s.slots(0).n_held
            proxy.target = b.port
            proxy.cut()
            s.send_pose(0, *circle(lo, hi, 0, 11 / 30))
            keyframe = None
            for _ in range(30):                       # bounded: frames until the fresh session answers the pose
                f = s.next_frame(timeout=10)
                assert f is not None
                if s.protocol.failovers and 0 in f.cameras:
                    keyframe = keyframe or (f.cameras[0].keyframe and f.cameras[0].vertices_written)
                    if f.cameras[0].pose_seq:
                        break
            while s.next_frame(timeout=0.3) is not None:
                pass
            assert s.protocol.failovers == 1 and not s.info.resumed and s.info.cache_vertices == 2500
            assert held_before > 0 and keyframe, "the fresh session's keyframe wrote the slots again"
            assert s.slots(0).n_held <= 2500
            assert s.protocol.divergences == 0 and s.protocol.bad_frames == 0
            _check_mirror(s.protocol, b)
