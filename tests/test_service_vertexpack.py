"""The packed vertex download through the service: negotiated at Open, a fraction of the
bytes, positions within the reported error, the same index buffers, cached and checked.
"""

from __future__ import annotations

import zlib

import grpc
import numpy as np
import pytest

from caveclod import vertexpack, wire
from caveclod.client import Client, SessionProtocol
from caveclod.client.protocol import ProtocolError
from caveclod.v1 import caveclod_pb2 as pb

from service import open_message, proxy_to, raw_stream

EYE, TARGET = (-60.0, -60.0, 70.0), (24.0, 24.0, 0.0)


def _pose(session, k: int):
    """Send the flight's ``k``-th pose and read frames until one answers it: (its pose_seq, that frame)."""
    seq = session.send_pose(0, (EYE[0] + 9 * k, EYE[1] + 5 * k, EYE[2] - 6 * k), TARGET)
    for _ in range(200):
        update = session.next_frame(timeout=5)
        assert update is not None, "no frame within 5 s"
        if update.pose_seq >= session.protocol.pose_seq:
            return seq, update
    raise AssertionError(f"pose {seq} not answered within 200 frames")


def _converged(update, seq: int) -> bool:
    """Whether ``update`` carries camera 0's converged update for pose ``seq``: no operation and
    no budget stop, after which the server makes no further update for that pose (the proto's
    "Updates per pose")."""
    cam = update.cameras.get(0)
    stats = None if cam is None or cam.pose_seq != seq else cam.stats
    return stats is not None and not (stats.splits or stats.collapses or stats.budget_exhausted)


def _fly(session, frames=4):
    """Send a few poses, each once the last has been refined to the end; the camera's triangles
    after them. Waiting for the converged update keeps the two sessions' histories equal: a pose
    answered before a convergence update the other session had made starts from another state,
    and may end in another. (Waiting for 0.5 s without a frame instead let a loaded machine, two
    test processes at once, make them differ.)"""
    for k in range(frames):
        seq, update = _pose(session, k)
        for _ in range(400):
            if _converged(update, seq):
                break
            update = session.next_frame(timeout=10)
            assert update is not None, f"pose {seq}: no frame within 10 s before it converged"
        else:
            raise AssertionError(f"pose {seq} did not converge within 400 frames")
    return session.triangles(0)


def test_packed_and_float32_sessions_draw_the_same_buffers_from_a_fraction_of_the_bytes(server):
    with Client(f"127.0.0.1:{server.port}") as client:
        with client.session("terrain", width=640, height=360, vertex_encoding="float32") as exact:
            assert not exact.info.HasField("vertex_packing")
            float_bytes = exact.info.vertex_format.payload_bytes
            want = _fly(exact)
            original = exact.vertex_buffer
        with client.session("terrain", width=640, height=360) as packed:      # packed is the default
            info = packed.info
            assert info.HasField("vertex_packing")
            vp = info.vertex_packing
            assert vp.position_bits == vertexpack.DEFAULT_POSITION_BITS and vp.normal_bits == vertexpack.NORMAL_BITS
            assert vp.vertex_buffer_hash == vertexpack.packed_hash(info.mesh.vertex_buffer_hash, 20)
            assert vp.packed_bytes * 4 < float_bytes, "packed: under a quarter of float32's bytes"
            got = _fly(packed)
            vb = packed.vertex_buffer
            assert vb.hash == vp.vertex_buffer_hash
            assert zlib.crc32(vb.payload) == info.vertex_payload_crc32
    # The index buffers do not depend on how the vertices travelled.
    assert sorted(got) == sorted(want) and all(np.array_equal(got[m], want[m]) for m in want)
    # Positions within the error the server reported (and that error small: 20 bits).
    dist = np.linalg.norm(vb.positions.astype(np.float64) - original.positions, axis=1)
    assert dist.max() == pytest.approx(vp.max_position_error, rel=1e-6)
    extent = np.ptp(original.positions, axis=0).max()
    assert vp.max_position_error <= extent * 2.0 ** -20
    cos = np.clip((vb.normals.astype(np.float64) * original.normals).sum(axis=1), -1, 1)
    assert np.degrees(np.arccos(cos)).max() <= vp.max_normal_degrees + 1e-3 <= 0.07
    assert np.abs(vb.uvs - original.uvs).max() <= vp.texcoord_step


def test_position_bits_are_negotiated_and_checked(server):
    with Client(f"127.0.0.1:{server.port}") as client:
        with client.session("terrain", width=640, height=360, position_bits=12) as coarse:
            assert coarse.info.vertex_packing.position_bits == 12
            err12 = coarse.info.vertex_packing.max_position_error
        with client.session("terrain", width=640, height=360, position_bits=24) as fine:
            assert fine.info.vertex_packing.max_position_error < err12 / 1000
    # The client refuses a bad value itself; a raw Open gets INVALID_ARGUMENT naming the field.
    with pytest.raises(ValueError, match="position_bits is 30"):
        SessionProtocol("terrain", 1, {}, position_bits=30)
    msg = open_message()
    msg.open.vertex_encoding = pb.VERTEX_ENCODING_PACKED
    msg.open.position_bits = 30
    code, details, _ = raw_stream(server.port, [msg])
    assert code == grpc.StatusCode.INVALID_ARGUMENT
    assert "Open.position_bits is 30; use 8 to 24" in details


def test_a_rebuilt_mesh_s_morph_targets_are_not_taken_from_the_cache(make_server, tmp_path):
    """Morph targets come from the hierarchy: the same vertices built again into another hierarchy
    have other targets under another cache key (it takes MeshInfo.content_hash), so a client that
    cached the first build's downloads the second's instead of offering a stale buffer (which the
    server would take, and the session would end with DATA_LOSS)."""
    import caveclod
    from caveclod.builder.builtin import rough_terrain
    from caveclod.refine.morphtargets import morph_targets
    builds = {}
    for tiles in (1, 2):
        (tmp_path / str(tiles)).mkdir()
        builds[tiles] = tmp_path / str(tiles) / "rough.cvc"
        caveclod.build(rough_terrain(40), tiles=tiles).save(builds[tiles])
    one, two = caveclod.load(builds[1]), caveclod.load(builds[2])
    assert one.vertex_buffer_hash == two.vertex_buffer_hash and one.content_hash != two.content_hash
    assert not np.array_equal(morph_targets(one), morph_targets(two)), "the test needs other targets"
    cache = tmp_path / "cache"
    for tiles, mesh, from_cache in ((1, one, False), (2, two, False), (2, two, True)):
        server = make_server(meshes=[builds[tiles]])
        with Client(f"127.0.0.1:{server.port}", cache_dir=cache) as client:
            with client.session("rough", width=640, height=360, morph_targets=True) as s:
                assert s.info.vertex_buffer_cached == from_cache
                assert np.array_equal(s.vertex_buffer.morph_targets, morph_targets(mesh))
                assert _fly(s, 2)
        server.stop()


def test_morph_targets_come_when_asked_for(server):
    from caveclod.refine.morphtargets import morph_targets
    with Client(f"127.0.0.1:{server.port}") as client:
        with client.session("terrain", width=640, height=360) as plain:
            assert plain.vertex_buffer.morph_targets is None
            key = plain.info.vertex_packing.vertex_buffer_hash
            size = plain.info.vertex_packing.packed_bytes
        with client.session("terrain", width=640, height=360, morph_targets=True) as s:
            info = s.info
            semantics = [a.semantic for a in info.vertex_format.attributes]
            assert semantics[-1] == pb.ATTRIBUTE_SEMANTIC_MORPH_TARGET
            want = morph_targets(server.sessions.catalogue.get("terrain").mesh)
            assert np.array_equal(s.vertex_buffer.morph_targets, want)
            assert info.vertex_packing.vertex_buffer_hash == vertexpack.packed_hash(
                info.mesh.vertex_buffer_hash, 20, True, info.mesh.content_hash) != key
            assert size < info.vertex_packing.packed_bytes < size + 4 * len(want), "a few bytes a vertex more"
            assert _fly(s, 2)
        # float32 has no morph targets: asked for, they are not sent.
        with client.session("terrain", width=640, height=360, vertex_encoding="float32", morph_targets=True) as f:
            assert f.vertex_buffer.morph_targets is None and not f.info.HasField("vertex_packing")


def test_cache_mode_ignores_packing(server):
    with Client(f"127.0.0.1:{server.port}") as client:
        with client.session("terrain", width=640, height=360, cache_vertices=2000) as s:
            assert not s.info.HasField("vertex_packing") and s.info.cache_vertices == 2000
            assert _fly(s, 2)


def test_the_decoded_buffer_is_cached_under_its_own_key(server, tmp_path):
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", width=640, height=360) as first:
            key = first.info.vertex_packing.vertex_buffer_hash
            payload = first.vertex_buffer.payload
            assert not first.info.vertex_buffer_cached
    assert [p.name for p in tmp_path.iterdir()] == [key]
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:     # a new client: from disk
        with client.session("terrain", width=640, height=360) as second:
            assert second.info.vertex_buffer_cached and second.vertex_buffer.payload == payload
            _fly(second, 1)
        # Another encoding or precision is another buffer: downloaded, not taken from the cache.
        with client.session("terrain", width=640, height=360, vertex_encoding="float32") as exact:
            assert not exact.info.vertex_buffer_cached
        with client.session("terrain", width=640, height=360, position_bits=16) as coarse:
            assert not coarse.info.vertex_buffer_cached


def test_a_resumed_packed_session_keeps_its_buffer(server):
    with proxy_to(server.port) as proxy, Client(f"127.0.0.1:{proxy.port}") as client:
        with client.session("terrain", width=640, height=360) as s:
            _fly(s, 2)
            held = s.vertex_buffer
            proxy.cut()                       # the network breaks under the stream; the client resumes
            for _ in range(100):
                _pose(s, 0)
                if s.protocol.resumes:
                    break
            assert s.protocol.resumes == 1 and s.info.resumed and s.info.vertex_buffer_cached
            assert s.vertex_buffer.payload == held.payload and s.protocol.divergences == 0


# -- damage, without a server: the client's checks -----------------------------------------

def _packed_session_info(mesh, packed, *, decoded_crc=None):
    fmt = wire.vertex_format(wire.vertex_blocks(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs,
                                                mesh.vertex_colors))
    msg = wire.session_info(token="t", resumed=False, mesh=pb.MeshInfo(name="m", vertex_buffer_hash="ab" * 16),
                            vertex_format=fmt, vertex_buffer_cached=False,
                            vertex_payload_crc32=packed.decoded_crc32 if decoded_crc is None else decoded_crc,
                            view_options={}, budgets=(None, None), cameras=1, ack_window=4, resume_ttl_s=30,
                            last_frame_seq=0, last_pose_seq=0)
    msg.session_info.vertex_packing.CopyFrom(vertexpack.to_message(packed, "ab" * 16))
    return msg


def _chunks(data: bytes):
    return wire.vertex_chunks([wire.VertexBlock(0, np.frombuffer(data, np.uint8))], 1000)


@pytest.fixture(scope="module")
def small_mesh():
    import caveclod
    return caveclod.build("scan", size=24)


def test_a_client_takes_an_intact_packed_buffer(small_mesh):
    packed = vertexpack.pack(small_mesh.vertex_positions, small_mesh.vertex_normals, small_mesh.vertex_uvs,
                             small_mesh.vertex_colors)
    p = SessionProtocol("m", 1, {})
    p.receive(_packed_session_info(small_mesh, packed))
    for chunk in _chunks(packed.data):
        p.receive(chunk)
    assert p.ready and np.abs(p.vertex.positions - small_mesh.vertex_positions).max() <= packed.max_position_error


@pytest.mark.parametrize("damage", ["byte", "decoder"])
def test_a_damaged_packed_buffer_or_a_decoder_that_disagrees_is_a_clear_error(small_mesh, damage):
    packed = vertexpack.pack(small_mesh.vertex_positions, small_mesh.vertex_normals, small_mesh.vertex_uvs,
                             small_mesh.vertex_colors)
    p = SessionProtocol("m", 1, {})
    data = packed.data
    if damage == "byte":
        data = bytearray(data)
        data[len(data) // 2] ^= 0x10
        data = bytes(data)
    p.receive(_packed_session_info(small_mesh, packed, decoded_crc=None if damage == "byte" else 12345))
    with pytest.raises(ProtocolError, match="damaged in transit" if damage == "byte" else "decodes packed buffers "
                       "unlike the server"):
        for chunk in _chunks(data):
            p.receive(chunk)
    assert not p.ready and p.vertex is None

