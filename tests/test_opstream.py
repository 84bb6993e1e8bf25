"""The op-stream frame encoding (FRAME_ENCODING_OPS): the compiled encoder, the
numpy decoder, the compiled decoder (the load generator's) and a slow,
obviously-correct reference decoder agree; real
refinement deltas round-trip; a damaged stream is an error, never a wrong buffer.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import caveclod
from caveclod import opstream
from caveclod.kernels import opstream as op_kernel
from caveclod.paths import pose
from caveclod.server.held import HeldBuffers

import meshes
from fuzzing import damage


# -- a reference decoder: one write at a time, as the proto's comment reads --------------

def reference_decode(ops: bytes, old: np.ndarray, count: int, n_vertices: int):
    """The proto's SurfaceDelta.ops rules, a varint and a write at a time."""
    data, pos = bytes(ops), 0

    def varint():
        nonlocal pos
        value = shift = 0
        while True:
            if pos >= len(data) or shift > 56:
                raise opstream.OpStreamError("cut off")
            b = data[pos]
            pos += 1
            value |= (b & 0x7F) << shift
            shift += 7
            if b < 0x80:
                return value

    def unzigzag(z):
        return z >> 1 if z % 2 == 0 else -(z >> 1) - 1

    n = varint()
    headers = [varint() for _ in range(n)]
    slots, tris, last, prev_slot = [], [], 0, -1
    for i, h in enumerate(headers):
        kind, slot = h & 15, prev_slot + (h >> 4) + 1
        prev_slot = slot
        if kind == 0:
            tri = []
            for _ in range(3):
                last += unzigzag(varint())
                tri.append(last)
        elif kind == 1:
            tri = list(old[len(old) - 1 - varint()])
        elif kind <= 4:
            tri = list(old[slot])
            tri[kind - 2] = int(old[slot][kind - 2]) + unzigzag(varint())
        elif kind <= 13:
            e, p = divmod(kind - 5, 3)
            assert i > 0 and headers[i - 1] & 15 == 0, "EDGE after a NEW"
            prev = tris[-1]
            last += unzigzag(varint())
            tri = [0, 0, 0]
            tri[p], tri[(p + 1) % 3], tri[(p + 2) % 3] = prev[(e + 1) % 3], prev[e], last
        else:
            raise opstream.OpStreamError("kind")
        assert 0 <= slot < count and all(0 <= v < n_vertices for v in tri)
        slots.append(slot)
        tris.append([int(v) for v in tri])
    assert pos == len(data), "trailing bytes"
    return np.array(slots, np.uint32), np.array(tris, np.uint32).reshape(-1, 3)


def compiled_decode(ops: bytes, old: np.ndarray, count: int, n_vertices: int):
    """The compiled decoder alone: a stream it refuses raises OpStreamError (without the words)."""
    status, slots, tris = op_kernel.decode(np.frombuffer(bytes(ops), np.uint8), old, count, n_vertices)
    if status != op_kernel.DECODE_OK:
        raise opstream.OpStreamError("refused by the compiled decoder")
    return slots, tris


def with_kernel(ops: bytes, old: np.ndarray, count: int, n_vertices: int):
    """opstream.decode as the load generator runs it: the compiled decoder turned on."""
    with opstream.compiled_decoding() as compiled:
        assert compiled
        return opstream.decode(ops, old, count, n_vertices)


# Long and short streams' numpy paths, the kernel, and the kernel behind decode().
DECODERS = (opstream._decode_vectorized, opstream._decode_small, compiled_decode, with_kernel)


def _apply(old: np.ndarray, count: int, slots, tris) -> np.ndarray:
    new = np.zeros((count, 3), np.uint32)
    keep = min(len(old), count)
    new[:keep] = old[:keep]
    new[slots] = tris
    return new


def _round_trip(old: np.ndarray, new: np.ndarray, n_vertices: int) -> bytes:
    """Encode old -> new with the kernel; check both decoders and the held copy; return the stream."""
    held = HeldBuffers(1)
    held.replace(0, old)
    rows = max(len(old), len(new))
    pad = np.zeros((rows, 3), np.uint32)
    pad[:len(old)] = old
    changed = np.flatnonzero((pad[:len(new)] != new).any(axis=1) | (np.arange(len(new)) >= len(old)))
    slots = changed.astype(np.uint32)
    ops = held.encode(0, len(new), slots, new[slots])
    np.testing.assert_array_equal(held.buffer(0), new)
    for decode in DECODERS + (reference_decode,):
        s, t = decode(ops, old, len(new), n_vertices)
        np.testing.assert_array_equal(s, slots)
        np.testing.assert_array_equal(_apply(old, len(new), s, t), new)
    return ops


# -- edits that look like refinement: moves into holes, re-pointed corners, split pairs ---

@st.composite
def refinement_edits(draw):
    n_vertices = draw(st.sampled_from([8, 300, 70_000, 5_000_000]))
    count = draw(st.integers(0, 60))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    old = rng.integers(0, n_vertices, size=(count, 3)).astype(np.uint32)
    new = [list(t) for t in old]
    for _ in range(draw(st.integers(0, 25))):
        op = draw(st.sampled_from(["remove", "corner", "pair", "new"]))
        if op == "remove" and new:
            i = int(rng.integers(len(new)))
            new[i] = new[-1]
            new.pop()
        elif op == "corner" and new:
            new[int(rng.integers(len(new)))][int(rng.integers(3))] = int(rng.integers(n_vertices))
        elif op == "pair":
            t, u, a, b = (int(v) for v in rng.integers(0, n_vertices, 4))
            first = [t, u, a]
            second = [u, t, b]
            r = int(rng.integers(3))
            new += [first[r:] + first[:r], second[-r:] + second[:-r] if r else second]
        else:
            new.append([int(v) for v in rng.integers(0, n_vertices, 3)])
    return old, np.array(new, np.uint32).reshape(-1, 3), n_vertices


@settings(max_examples=300, deadline=None)
@given(refinement_edits())
def test_kernel_encoder_numpy_decoder_and_reference_agree(edit):
    old, new, n_vertices = edit
    _round_trip(old, new, n_vertices)


def test_each_kind_is_chosen_where_it_is_cheapest():
    old = np.array([[10, 11, 12], [20, 21, 22], [30, 31, 32], [40, 41, 42]], np.uint32)
    new = np.array([[40, 41, 42],            # slot 0: the last triangle moved into a hole: COPY
                    [20, 99, 22],            # slot 1: one corner re-pointed: CORNER 1
                    [30, 31, 32],            # unchanged
                    [7, 8, 9],               # slot 3: NEW
                    [9, 8, 5]], np.uint32)   # slot 4: on edge (8, 9) of the previous: EDGE
    ops = _round_trip(old, new, 100)
    values = opstream.read_varints(ops)
    kinds = [int(h) & 15 for h in values[1:1 + int(values[0])]]
    assert kinds == [1, 3, 0, 5 + 3 * 1 + 0]
    assert len(ops) < 12 * 4


def test_real_refinement_deltas_round_trip_and_are_small(terrain_path):
    """A flyover of four cameras on the test terrain and a scan with seams: every delta's
    op stream decodes to the server's buffer (numpy and compiled alike), at well under
    RAW's 16 bytes a write."""
    sources = [caveclod.load(terrain_path), caveclod.build(meshes.holey_scan(seed=3, n=40))]
    for mesh in sources:
        lo, hi = mesh.bounds()
        ops_bytes = writes = 0
        for c in range(4):
            cam = mesh.new_camera()
            held = HeldBuffers(cam.n_materials)
            client = {m: cam.index_buffer(m).copy() for m in range(cam.n_materials)}
            for m, buf in client.items():
                held.replace(m, buf)
            for f in range(120):
                p = pose("flyover", lo, hi, c, f / 10)
                delta = cam.update(caveclod.View(eye=p.eye, target=p.target, up=p.up, width=800, height=600))
                for m, d in delta.surfaces.items():
                    ops = held.encode(m, d.count, d.slots, d.tris)
                    slots, tris = opstream.decode(ops, client[m], d.count, mesh.n_vertices)
                    compiled = compiled_decode(ops, client[m], d.count, mesh.n_vertices)
                    np.testing.assert_array_equal(compiled[0], slots)
                    np.testing.assert_array_equal(compiled[1], tris)
                    client[m] = _apply(client[m], d.count, slots, tris)
                    np.testing.assert_array_equal(client[m], cam.index_buffer(m))
                    ops_bytes += len(ops)
                    writes += len(d.slots)
        assert writes > 500
        assert ops_bytes / writes < 8, f"{ops_bytes / writes:.1f} bytes a write"


@pytest.mark.parametrize("seed", range(4))
def test_a_damaged_stream_is_an_error_or_a_checked_buffer_never_a_crash(seed):
    """Bit flips, cuts, inserted and deleted bytes: decode raises OpStreamError, or
    returns writes inside the buffer and the vertex range (the CRC then judges them)."""
    rng = np.random.default_rng(seed)
    old = rng.integers(0, 500, size=(40, 3)).astype(np.uint32)
    new = old.copy().tolist()
    for _ in range(8):
        i = int(rng.integers(len(new)))
        new[i] = new[-1]
        new.pop()
        new[int(rng.integers(len(new)))][int(rng.integers(3))] = int(rng.integers(500))
        new += [[1, 2, 3], [3, 2, 4]]
    new = np.array(new, np.uint32)
    ops = _round_trip(old, new, 500)
    errors = 0
    for trial in range(400):
        data = damage(ops, rng, trial)
        results = []
        for decode in DECODERS:
            try:
                results.append(decode(bytes(data), old, len(new), 500))
            except opstream.OpStreamError as exc:
                assert str(exc) and "\n" not in str(exc)
                results.append(None)
        assert len({r is None for r in results}) == 1, "the decoders disagree on a damaged stream"
        if results[0] is None:
            errors += 1
            continue
        for slots, tris in results:
            assert slots.dtype == np.uint32 and tris.dtype == np.uint32 and tris.shape == (len(slots), 3)
            assert (np.diff(slots.astype(np.int64)) > 0).all() and (len(slots) == 0 or slots[-1] < len(new))
            assert (tris < 500).all()
        for slots, tris in results[1:]:
            np.testing.assert_array_equal(results[0][0], slots)
            np.testing.assert_array_equal(results[0][1], tris)
    assert errors > 200


@pytest.mark.parametrize("data, count, words", [
    (b"", 10, "empty"),
    (b"\x85", 10, "cut off"),
    (b"\x05\x00", 10, "announces 5 writes"),
    (b"\x01\x0e\x00", 10, "kind 14"),
    (b"\x01\x00\x00\x00", 10, "need 3 payload"),
    (b"\x01\x01\x0a", 10, "COPY from 10"),
    (b"\x01\xa2\x01\x00", 11, "CORNER write to slot 10"),
    (b"\x01\x00\x00", 12, "not every new slot"),
    (b"\x01\xb0\x01\x00\x00\x00", 10, "slot gap of 11"),
    (b"\x01\x00\x02\x02\x7f", 10, "vertex index -62"),
    (b"\x01\x05\x00", 10, "EDGE write that does not follow a NEW"),
    (b"\x01" + b"\xff" * 10 + b"\x00", 10, "varint of"),
])
@pytest.mark.parametrize("decode", [d for d in DECODERS if d is not compiled_decode])
def test_malformed_streams_say_what_is_wrong(data, count, words, decode):
    old = np.arange(30, dtype=np.uint32).reshape(10, 3)
    with pytest.raises(opstream.OpStreamError, match=words):
        decode(data, old, count, 64)
    with pytest.raises(opstream.OpStreamError):
        compiled_decode(data, old, count, 64)
