"""The packed vertex download (VERTEX_ENCODING_PACKED): the numpy codec against a slow
reference decoder written from the proto's text, its error bounds on realistic meshes and
random input, and damage that is always an error, never a wrong buffer.
"""

from __future__ import annotations

import math
import struct
import zlib

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

import caveclod
from caveclod import vertexpack, wire
from caveclod.v1 import caveclod_pb2 as pb

import meshes


# -- a reference decoder: a value at a time, as the proto's VertexPacking comment reads ---

def reference_decode(msg: pb.VertexPacking, vertex_format: pb.VertexFormat, packed: bytes) -> bytes:
    """The decoded PLANAR payload, following VertexPacking's numbered steps literally."""
    d = vertex_format.vertex_count
    has_color = any(a.semantic == pb.ATTRIBUTE_SEMANTIC_COLOR for a in vertex_format.attributes)
    has_morph = any(a.semantic == pb.ATTRIBUTE_SEMANTIC_MORPH_TARGET for a in vertex_format.attributes)
    k = 7 + 4 * has_color + has_morph
    raw = zlib.decompress(packed)
    assert len(raw) == 4 * d * k
    streams = []
    for s in range(k):
        q, out = 0, []
        for i in range(d):
            z = sum(raw[4 * d * s + j * d + i] << (8 * j) for j in range(4))
            delta = (z >> 1) ^ -(z & 1)
            q += delta
            out.append(q)
        streams.append(out)

    def f32(values):
        return struct.pack(f"<{len(values)}f", *values)

    o = (msg.position_origin.x, msg.position_origin.y, msg.position_origin.z)
    pos = [o[c] + streams[c][i] * msg.position_step for i in range(d) for c in range(3)]
    s = 2.0 ** (msg.normal_bits - 1) - 1
    nrm = []
    for i in range(d):
        x, y = streams[3][i] / s, streams[4][i] / s
        z = 1 - abs(x) - abs(y)
        t = max(-z, 0.0)
        x = x - t if x >= 0 else x + t
        y = y - t if y >= 0 else y + t
        n = math.sqrt(x * x + y * y + z * z)
        nrm += [x / n, y / n, z / n]
    uv = [streams[5 + c][i] * msg.texcoord_step for i in range(d) for c in range(2)]
    out = f32(pos) + f32(nrm) + f32(uv)
    if has_color:
        out += bytes(streams[7 + c][i] for i in range(d) for c in range(4))
    if has_morph:
        out += struct.pack(f"<{d}I", *(streams[k - 1][i] + i for i in range(d)))
    return out


def _format(positions, normals, uvs, colors) -> pb.VertexFormat:
    return wire.vertex_format(wire.vertex_blocks(positions, normals, uvs, colors))


def _random_buffer(seed: int, d: int, *, offset=0.0, extent=1.0, uv_scale=1.0, colors=False):
    rng = np.random.default_rng(seed)
    p = (offset + rng.random((d, 3)) * extent).astype(np.float32)
    n = rng.normal(size=(d, 3))
    n[: d // 8] = np.eye(3)[rng.integers(0, 3, d // 8)] * rng.choice([-1, 1], (d // 8, 1))   # axis normals
    n = (n / np.linalg.norm(n, axis=1)[:, None]).astype(np.float32)
    uv = ((rng.random((d, 2)) - 0.25) * uv_scale).astype(np.float32)
    c = rng.integers(0, 256, (d, 4), dtype=np.uint8) if colors else np.zeros((0, 4), np.uint8)
    return p, n, uv, c


def _check_bounds(packed: vertexpack.Packed, p, n, uv, c, decoded) -> None:
    """Each decoded attribute within what its quantization allows; the reported errors true."""
    step = packed.packing.position_step
    p64 = np.asarray(p, np.float64)
    ulp = np.spacing(np.abs(p64).max(axis=0).astype(np.float32)).astype(np.float64)
    assert (np.abs(decoded["position"] - p64) <= step / 2 + ulp + 1e-12).all()
    dist = np.sqrt(((decoded["position"].astype(np.float64) - p64) ** 2).sum(axis=1))
    assert dist.max(initial=0.0) == pytest.approx(packed.max_position_error, rel=1e-9, abs=1e-30)
    # 12-bit octahedral normals: within 0.06 degrees; unit length to float32.
    cos = np.clip((decoded["normal"].astype(np.float64) * n).sum(axis=1), -1, 1)
    assert np.degrees(np.arccos(cos)).max(initial=0.0) <= 0.06
    assert packed.max_normal_degrees <= 0.06
    assert np.allclose(np.linalg.norm(decoded["normal"], axis=1), 1.0, atol=2e-7)
    tstep = packed.packing.texcoord_step
    assert (np.abs(decoded["texcoord"] - np.asarray(uv, np.float64))
            <= tstep / 2 + np.spacing(np.abs(uv).astype(np.float32)) + 1e-12).all()
    if len(c):
        assert np.array_equal(decoded["color"], c)
    else:
        assert "color" not in decoded


# -- the codec ------------------------------------------------------------------------------

@pytest.mark.parametrize("colors, morph", [(False, False), (True, False), (False, True), (True, True)])
def test_the_numpy_decoder_gives_the_reference_decoders_bytes(colors, morph):
    p, n, uv, c = _random_buffer(3, 300, offset=-40.0, extent=90.0, uv_scale=7.0, colors=colors)
    targets = np.maximum(np.arange(300) - np.random.default_rng(4).integers(0, 30, 300), 0) if morph else None
    packed = vertexpack.pack(p, n, uv, c, position_bits=17, morph_targets=targets)
    msg = vertexpack.to_message(packed, "ab" * 16, "cd" * 32)
    fmt = vertexpack.vertex_format(wire.vertex_blocks(p, n, uv, c), morph)
    mine = vertexpack.planar_payload(vertexpack.unpack(vertexpack.from_message(msg, fmt), packed.data))
    assert mine == reference_decode(msg, fmt, packed.data)
    assert zlib.crc32(mine) == packed.decoded_crc32
    assert msg.packed_bytes == len(packed.data) and msg.packed_crc32 == zlib.crc32(packed.data)
    assert msg.vertex_buffer_hash == vertexpack.packed_hash("ab" * 16, 17, morph, "cd" * 32)
    if morph:
        decoded = vertexpack.unpack(vertexpack.from_message(msg, fmt), packed.data)
        assert np.array_equal(decoded["morph_target"].reshape(-1), targets)
        assert vertexpack.packed_hash("ab" * 16, 17, True, "cd" * 32) != vertexpack.packed_hash("ab" * 16, 17)
        # The targets come from the hierarchy: another build of the same vertices, another key.
        assert vertexpack.packed_hash("ab" * 16, 17, True, "cd" * 32) != vertexpack.packed_hash("ab" * 16, 17, True,
                                                                                              "ef" * 32)


@pytest.mark.parametrize("source", ["rough", "scan", "sphere", "holey"])
def test_realistic_meshes_pack_small_and_decode_within_their_bounds(source):
    if source in ("rough", "scan"):
        mesh = caveclod.build(source, size=64)
    else:
        mesh = caveclod.build(meshes.uv_sphere() if source == "sphere" else meshes.holey_scan())
    p, n, uv, c = mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors
    for bits in (12, 20, 24):
        packed = vertexpack.pack(p, n, uv, c, bits)
        decoded = vertexpack.unpack(packed.packing, packed.data)
        _check_bounds(packed, p, np.asarray(n, np.float64) / np.linalg.norm(n, axis=1)[:, None], uv, c, decoded)
        assert len(packed.data) <= 12 * len(p), "well under float32's 32 bytes a vertex"
    # More bits: a smaller error.
    errors = [vertexpack.pack(p, n, uv, c, b).max_position_error for b in (12, 16, 20)]
    assert errors[0] > errors[1] > errors[2]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), d=st.integers(0, 64), bits=st.integers(8, 24),
       offset=st.sampled_from([0.0, -1e3, 5e6]), extent=st.sampled_from([0.0, 1e-3, 1.0, 1e4]),
       uv_scale=st.sampled_from([0.0, 1.0, 900.0, 1e6, 1e30, 3.4e38]), colors=st.booleans())
@example(seed=0, d=1, bits=8, offset=0.0, extent=0.0, uv_scale=0.0, colors=False)   # one vertex, no extent
def test_any_buffer_round_trips_within_its_quantization(seed, d, bits, offset, extent, uv_scale, colors):
    p, n, uv, c = _random_buffer(seed, d, offset=offset, extent=extent, uv_scale=uv_scale, colors=colors)
    packed = vertexpack.pack(p, n, uv, c, bits)
    decoded = vertexpack.unpack(packed.packing, packed.data)
    assert zlib.crc32(vertexpack.planar_payload(decoded)) == packed.decoded_crc32
    if d:
        _check_bounds(packed, p, n.astype(np.float64), uv, c, decoded)


def test_texcoords_up_to_float32s_largest_pack_without_overflow():
    """A damaged file's texcoords can reach float32's range, which the build accepts: once packing
    failed past about 3e26 (q beyond int64; the fuzzer's Draco seeds found it)."""
    import warnings
    top = float(np.finfo(np.float32).max)
    uv = np.array([[top, -top], [3.1179412e38, 0.5], [1e27, -1e-3], [0.0, 1.0]], np.float32)
    p = np.zeros((4, 3), np.float32)
    n = np.tile(np.float32([0, 0, 1]), (4, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        packed = vertexpack.pack(p, n, uv, None, 20)
        decoded = vertexpack.unpack(packed.packing, packed.data)
    step = packed.packing.texcoord_step
    assert step == 2.0 ** 104
    assert np.isfinite(decoded["texcoord"]).all()
    assert (np.abs(decoded["texcoord"].astype(np.float64) - uv) <= step / 2).all()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), d=st.integers(1, 300), chunk=st.integers(1, 64), colors=st.booleans(),
       morph=st.booleans(), bits=st.integers(8, 24))
def test_packing_in_chunks_gives_the_same_bytes_and_the_decoders_errors(seed, d, chunk, colors, morph, bits):
    p, n, uv, c = _random_buffer(seed, d, offset=-3.0, extent=50.0, uv_scale=3.0, colors=colors)
    targets = np.maximum(np.arange(d) - np.random.default_rng(seed).integers(0, 9, d), 0) if morph else None
    whole = vertexpack.pack(p, n, uv, c, bits, targets, chunk=d)
    parts = vertexpack.pack(p, n, uv, c, bits, targets, chunk=chunk)
    assert parts == whole
    # The CRC and the errors pack reports are those of what the numpy decoder makes of the bytes.
    decoded = vertexpack.unpack(whole.packing, whole.data)
    # ... whatever the decoder's block and its threads (two halves past PARALLEL_UNPACK vertices).
    in_blocks = vertexpack.unpack(whole.packing, whole.data, chunk=chunk)
    saved = vertexpack.PARALLEL_UNPACK
    try:
        vertexpack.PARALLEL_UNPACK = 1
        in_halves = vertexpack.unpack(whole.packing, whole.data, chunk=chunk)
    finally:
        vertexpack.PARALLEL_UNPACK = saved
    for other in (in_blocks, in_halves):
        assert other.keys() == decoded.keys()
        assert all(other[name].dtype == decoded[name].dtype and np.array_equal(other[name], decoded[name])
                   for name in decoded)
    # The payload decoded in place is the arrays' PLANAR payload, and nobody can change it.
    payload = vertexpack.unpack_payload(whole.packing, whole.data, chunk=chunk)
    assert payload.readonly and payload == vertexpack.planar_payload(decoded)
    assert zlib.crc32(vertexpack.planar_payload(decoded)) == whole.decoded_crc32
    err = np.sqrt(((decoded["position"].astype(np.float64) - p.astype(np.float64)) ** 2).sum(axis=1)).max()
    assert whole.max_position_error == float(err)
    n0 = n.astype(np.float64) / np.maximum(np.linalg.norm(n.astype(np.float64), axis=1), 1e-30)[:, None]
    cos = np.clip((n0 * decoded["normal"].astype(np.float64)).sum(axis=1), -1.0, 1.0)
    nonzero = np.abs(n).sum(axis=1) > 0
    assert whole.max_normal_degrees == (float(np.degrees(np.arccos(cos[nonzero])).max()) if nonzero.any() else 0.0)


def test_a_buffer_deflated_in_halves_is_one_stream_with_the_same_payload(monkeypatch):
    mesh = caveclod.build("rough", size=32)
    p, n, uv, c = mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors
    one = vertexpack.pack(p, n, uv, c)
    monkeypatch.setattr(vertexpack, "PARALLEL_DEFLATE_BYTES", 0)      # as a buffer past 32 MiB is
    halves = vertexpack.pack(p, n, uv, c)
    assert halves.data != one.data and zlib.decompress(halves.data) == zlib.decompress(one.data)
    assert (halves.packing, halves.decoded_crc32) == (one.packing, one.decoded_crc32)
    msg = vertexpack.to_message(halves, "cd" * 16)
    fmt = vertexpack.vertex_format(wire.vertex_blocks(p, n, uv, c), False)
    payload = reference_decode(msg, fmt, halves.data)
    assert payload == vertexpack.planar_payload(vertexpack.unpack(halves.packing, halves.data))
    assert zlib.crc32(payload) == halves.decoded_crc32
    assert len(halves.data) <= len(one.data) + 64, "the cut costs a few bytes, not the history"


def test_zero_normals_decode_as_up_and_the_lower_hemisphere_folds_back():
    n = np.array([[0, 0, 0], [0, 0, -1], [0.6, 0, -0.8], [-0.6, 0.8, 0], [0, -0.6, -0.8]], np.float32)
    codes = vertexpack.encode_normals(n)
    back = vertexpack.decode_normals(codes)
    assert np.allclose(back[0], [0, 0, 1])
    assert np.allclose(back[1:], n[1:], atol=1e-3)


def test_position_bits_out_of_range_is_refused_by_name():
    p, n, uv, c = _random_buffer(1, 4)
    for bits in (7, 25):
        with pytest.raises(ValueError, match="position_bits is .*8 to 24"):
            vertexpack.pack(p, n, uv, c, bits)


# -- damage -------------------------------------------------------------------------------

def test_any_damaged_byte_or_cut_is_an_error_never_a_wrong_buffer():
    mesh = caveclod.build("scan", size=24)
    packed = vertexpack.pack(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors)
    data = packed.data
    rng = np.random.default_rng(0)
    for at in sorted(set(rng.integers(0, len(data), 150).tolist()) | {0, 1, len(data) - 1}):
        for flip in (0x01, 0x80, 0xFF):
            bad = bytearray(data)
            bad[at] ^= flip
            with pytest.raises(wire.WireError, match="damaged|inflate"):
                vertexpack.unpack(packed.packing, bytes(bad))
    for cut in (0, 1, len(data) // 2, len(data) - 1):
        with pytest.raises(wire.WireError, match="damaged|inflate"):
            vertexpack.unpack(packed.packing, data[:cut])
    with pytest.raises(wire.WireError, match="inflates to"):
        vertexpack.unpack(packed.packing, data + b"tail")
    other = vertexpack.Packing(**{**packed.packing.__dict__, "vertex_count": packed.packing.vertex_count + 1})
    with pytest.raises(wire.WireError, match="inflates to"):
        vertexpack.unpack(other, data)


def test_a_packing_message_no_server_sends_is_refused():
    fmt = _format(*_random_buffer(2, 3))
    for bad in (pb.VertexPacking(encoding=pb.VERTEX_ENCODING_FLOAT32, position_step=1, texcoord_step=1, normal_bits=12),
                pb.VertexPacking(encoding=pb.VERTEX_ENCODING_PACKED, position_step=0, texcoord_step=1, normal_bits=12),
                pb.VertexPacking(encoding=pb.VERTEX_ENCODING_PACKED, position_step=1, texcoord_step=1, normal_bits=40)):
        with pytest.raises(wire.WireError, match="upgrade"):
            vertexpack.from_message(bad, fmt)
