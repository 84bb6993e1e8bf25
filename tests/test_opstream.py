"""The op-stream frame encodings (FRAME_ENCODING_OPS and _OPS_LINKED): the compiled encoders, the
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
from caveclod.server.held import HeldBuffers

import meshes
from flights import flyover_streams
from fuzzing import damage


# -- a reference decoder: one write at a time, as the proto's comment reads --------------

def _varint_reader(ops: bytes):
    """(varint(), at_end()): read the next LEB128 varint of ``ops``; whether all are read."""
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

    return varint, lambda: pos == len(data)


def unzigzag(z):
    return z >> 1 if z % 2 == 0 else -(z >> 1) - 1


def reference_decode(ops: bytes, old: np.ndarray, count: int, n_vertices: int):
    """The proto's SurfaceDelta.ops rules, a varint and a write at a time."""
    varint, at_end = _varint_reader(ops)

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
    assert at_end(), "trailing bytes"
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
        ops_bytes = writes = 0
        for cam, m, d, old, ops, _ in flyover_streams(mesh):
            slots, tris = opstream.decode(ops, old, d.count, mesh.n_vertices)
            compiled = compiled_decode(ops, old, d.count, mesh.n_vertices)
            np.testing.assert_array_equal(compiled[0], slots)
            np.testing.assert_array_equal(compiled[1], tris)
            np.testing.assert_array_equal(_apply(old, d.count, slots, tris), cam.index_buffer(m))
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
    assert _damaged_copies_judged_alike(ops, rng, DECODERS, old, len(new), 500, 500) > 200


def _damaged_copies_judged_alike(ops: bytes, rng, decoders, old: np.ndarray, count: int, last, n_vertices: int) -> int:
    """400 damaged copies of ``ops``, each given to every decoder (``decoder(data, old, count,
    last)``): all refuse it with a one-line OpStreamError, or all return the same writes, inside
    the buffer and below ``n_vertices``. Returns how many were refused."""
    errors = 0
    for trial in range(400):
        data = damage(ops, rng, trial)
        results = []
        for decode in decoders:
            try:
                results.append(decode(bytes(data), old, count, last))
            except opstream.OpStreamError as exc:
                assert str(exc) and "\n" not in str(exc)
                results.append(None)
        assert len({r is None for r in results}) == 1, "the decoders disagree on a damaged stream"
        if results[0] is None:
            errors += 1
            continue
        for slots, tris in results:
            assert slots.dtype == np.uint32 and tris.dtype == np.uint32 and tris.shape == (len(slots), 3)
            assert (np.diff(slots.astype(np.int64)) > 0).all() and (len(slots) == 0 or slots[-1] < count)
            assert (tris < n_vertices).all()
        for slots, tris in results[1:]:
            np.testing.assert_array_equal(results[0][0], slots)
            np.testing.assert_array_equal(results[0][1], tris)
    return errors


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


# -- FRAME_ENCODING_OPS_LINKED --------------------------------------------------------------

def reference_decode_linked(ops: bytes, old: np.ndarray, count: int, targets: np.ndarray):
    """The proto's OPS_LINKED rules, a varint and a write at a time; children found by a scan."""
    varint, at_end = _varint_reader(ops)
    targets = [int(t) for t in targets]

    children = {}
    for y, x in enumerate(targets):        # ascending y: each list in index order
        if x != y:
            children.setdefault(x, []).append(y)

    def child(x, r):
        return children[x][r]

    n = varint()
    grown = max(count - len(old), 0)
    kinds, slots, slot = [], [], -1
    for _ in range(n - grown):
        h = varint()
        slot += (h >> 4) + 1
        kinds.append(h & 15)
        slots.append(slot)
    for g in range(-(-grown // 3)):
        pack = varint()
        for t in range(min(3, grown - 3 * g)):
            kinds.append((0, 1, 11, 12, 13)[pack // 5 ** t % 5])
    slots += range(len(old), len(old) + grown)
    payload = [[varint() for _ in range(opstream.LINKED_PAYLOAD_VARINTS[k])] for k in kinds]
    assert at_end(), "trailing bytes"
    tris = [None] * n
    for i, (k, s, p) in enumerate(zip(kinds, slots, payload)):
        if k == 1:
            tris[i] = [int(v) for v in old[len(old) - 1 - p[0]]]
        elif 2 <= k <= 10:
            tri = [int(v) for v in old[s]]
            c = (k - 2) % 3
            tri[c] = tri[c] + unzigzag(p[0]) if k < 5 else child(tri[c], p[0]) if k < 8 else targets[tri[c]]
            tris[i] = tri
    last = 0
    for i, (k, p) in enumerate(zip(kinds, payload)):
        if k == 0:
            tri = []
            for z in p:
                last += unzigzag(z)
                tri.append(last)
            tris[i] = tri
        elif k >= 11:
            h = p[0]
            prev = tris[i + unzigzag(h // 9)]
            e, q = h % 9 // 3, h % 3
            x, y = prev[e], prev[(e + 1) % 3]
            v, mode = divmod(p[1], 4) if k == 11 else (None, None)
            if k == 12:
                z = targets[x]
            elif k == 13:
                z = targets[y]
            elif mode == 0:
                last += unzigzag(v)
                z = last
            elif mode in (1, 2):
                z = child(x if mode == 1 else y, v)
            else:
                z = tris[i + unzigzag(v // 3)][v % 3]
            tri = [0, 0, 0]
            tri[q], tri[(q + 1) % 3], tri[(q + 2) % 3] = y, x, z
            tris[i] = tri
    assert all(0 <= s < count for s in slots) and all(0 <= v < len(targets) for t in tris for v in t)
    return np.array(slots, np.uint32), np.array(tris, np.uint32).reshape(-1, 3)


def compiled_decode_linked(ops: bytes, old: np.ndarray, count: int, links: opstream.Links):
    status, slots, tris = op_kernel.decode_linked(np.frombuffer(bytes(ops), np.uint8), old, count, links.targets,
                                                  links.child_start, links.children)
    if status != op_kernel.DECODE_OK:
        raise opstream.OpStreamError("refused by the compiled decoder")
    return slots, tris


def linked_with_kernel(ops: bytes, old: np.ndarray, count: int, links: opstream.Links):
    with opstream.compiled_decoding() as compiled:
        assert compiled
        return opstream.decode_linked(ops, old, count, links)


LINKED_DECODERS = (opstream.decode_linked, compiled_decode_linked, linked_with_kernel)


def _linked_round_trip(old: np.ndarray, new: np.ndarray, targets: np.ndarray) -> bytes:
    """Encode old -> new as OPS_LINKED; check every decoder, the reference and the held copy."""
    links = opstream.Links(targets)
    held = HeldBuffers(1, (links.targets, opstream.child_ranks(targets)))
    held.replace(0, old)
    pad = np.zeros((max(len(old), len(new)), 3), np.uint32)
    pad[:len(old)] = old
    slots = np.flatnonzero((pad[:len(new)] != new).any(axis=1) | (np.arange(len(new)) >= len(old))).astype(np.uint32)
    ops = held.encode(0, len(new), slots, new[slots])
    np.testing.assert_array_equal(held.buffer(0), new)
    for decode in LINKED_DECODERS:
        s, t = decode(ops, old, len(new), links)
        np.testing.assert_array_equal(s, slots)
        np.testing.assert_array_equal(_apply(old, len(new), s, t), new)
    s, t = reference_decode_linked(ops, old, len(new), targets)
    np.testing.assert_array_equal(_apply(old, len(new), s, t), new)
    return ops


@st.composite
def linked_edits(draw):
    """A random forest of morph targets, a buffer, and edits that follow it (splits onto a
    child, merges onto the target, faces on the edges of other faces) or not at all."""
    n_vertices = draw(st.sampled_from([6, 40, 3000]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    targets = np.arange(n_vertices, dtype=np.uint32)
    for v in range(1, n_vertices):
        if rng.random() < 0.8:
            targets[v] = rng.integers(0, v)
    children = {x: [] for x in range(n_vertices)}
    for y, x in enumerate(targets.tolist()):
        if x != y:
            children[x].append(y)
    old = rng.integers(0, n_vertices, size=(draw(st.integers(0, 40)), 3)).astype(np.uint32)
    new = [[int(v) for v in t] for t in old]
    for _ in range(draw(st.integers(0, 30))):
        op = draw(st.sampled_from(["remove", "split", "merge", "face", "face", "new", "corner"]))
        if op == "remove" and new:
            i = int(rng.integers(len(new)))
            new[i] = new[-1]
            new.pop()
        elif op in ("split", "merge", "corner") and new:
            t, c = new[int(rng.integers(len(new)))], int(rng.integers(3))
            if op == "split" and children[t[c]]:
                t[c] = children[t[c]][int(rng.integers(len(children[t[c]])))]
            elif op == "merge":
                t[c] = int(targets[t[c]])
            else:
                t[c] = int(rng.integers(n_vertices))
        elif op == "face" and new:
            t = new[int(rng.integers(len(new)))]
            e = int(rng.integers(3))
            x, y = t[e], t[(e + 1) % 3]
            pick = int(rng.integers(4))
            if pick == 0 and children[x]:
                z = children[x][0]
            elif pick == 1:
                z = int(targets[y])
            elif pick == 2:
                z = new[int(rng.integers(len(new)))][int(rng.integers(3))]
            else:
                z = int(rng.integers(n_vertices))
            face = [y, x, z]
            r = int(rng.integers(3))
            new.append(face[r:] + face[:r])
        else:
            new.append([int(v) for v in rng.integers(0, n_vertices, 3)])
    return old, np.array(new, np.uint32).reshape(-1, 3), targets


@settings(max_examples=300, deadline=None)
@given(linked_edits())
def test_linked_encoder_decoders_and_reference_agree(edit):
    old, new, targets = edit
    _linked_round_trip(old, new, targets)


def test_each_linked_kind_is_chosen_where_it_is_cheapest():
    b = 1000                                   # vertex ids far from 0, where chained deltas start
    targets = np.arange(b + 100, dtype=np.uint32)
    targets[[b + 6, b + 7, b + 8]] = [b, b, b + 1]         # children: b -> [b+6, b+7], b+1 -> [b+8]
    old = b + np.array([[0, 1, 2], [3, 4, 5], [6, 1, 2], [10, 11, 12], [13, 14, 3]], np.uint32)
    new = b + np.array([[0, 8, 2],             # slot 0: b+1 -> its child b+8: SPLIT 1 (child 0)
                        [3, 4, 5],             # unchanged
                        [0, 1, 2],             # slot 2: b+6 -> its target b: MERGE 0
                        [13, 14, 3],           # slot 3: the last triangle moved into a hole: COPY
                        [8, 0, 7],             # slot 4: on edge (b, b+8) of slot 0's, with b's child b+7: ADJ
                        [50, 60, 70],          # slot 5, appended: NEW
                        [2, 8, 1]], np.uint32)     # slot 6, appended: on edge (b+8, b+2) of slot 0's, with
                                                   # b+8's target b+1: ADJ_TX
    ops = _linked_round_trip(old, new, targets)
    values = [int(v) for v in opstream.read_varints(ops)]
    assert values[0] == 6
    assert [h & 15 for h in values[1:5]] == [opstream.SPLIT0 + 1, opstream.MERGE0, opstream.COPY, opstream.ADJ]
    assert values[5] == 0 + 5 * 3              # the appended writes' kinds: NEW, ADJ_TX (APPENDED_KINDS 0 and 3)
    payload = values[6:]
    assert payload[:2] == [0, 0]               # SPLIT: child 0; (MERGE: nothing) COPY: the last row
    h, w = payload[2:4]                        # on edge 0 of write 0 (3 back: zigzag 5), b+8 at corner 0; b's child 1
    assert (h // 9, h % 9, w % opstream.Z_MODES, w // opstream.Z_MODES) == (5, 0, opstream.Z_CHILD_X, 1)
    assert payload[4:7] == [2 * (b + 50), 20, 20]   # NEW: chained zigzag deltas
    assert payload[7:] == [9 * 9 + 3 * 1 + 0]       # ADJ_TX: edge 1 of write 0 (5 back: zigzag 9), y at corner 0
    assert len(ops) == 1 + 4 + 1 + 9           # n, four headers, one pack, eight payload varints (one of 2 bytes)


def test_real_refinement_deltas_round_trip_linked_and_are_smaller(terrain_path):
    """The flyover of four cameras on the test terrain and a scan with seams: every
    OPS_LINKED delta decodes to the server's buffer with every decoder, in at most 85 %
    of the OPS bytes (77-81 % here, where a pose moves far and deltas are large; 58 %
    on the 1M terrain's 30 Hz flyover: benchmarks/opstream.py)."""
    from caveclod.refine.morphtargets import morph_targets
    sources = [caveclod.load(terrain_path), caveclod.build(meshes.holey_scan(seed=3, n=40))]
    for mesh in sources:
        links = opstream.Links(morph_targets(mesh))
        ops_bytes = linked_bytes = 0
        for cam, m, d, old, plain, ops in flyover_streams(mesh, links):
            ops_bytes += len(plain)
            linked_bytes += len(ops)
            slots, tris = opstream.decode_linked(ops, old, d.count, links)
            compiled = compiled_decode_linked(ops, old, d.count, links)
            np.testing.assert_array_equal(compiled[0], slots)
            np.testing.assert_array_equal(compiled[1], tris)
            np.testing.assert_array_equal(_apply(old, d.count, slots, tris), cam.index_buffer(m))
        assert ops_bytes > 5000
        assert linked_bytes <= ops_bytes * 0.85, (linked_bytes, ops_bytes)


@pytest.mark.parametrize("seed", range(4))
def test_a_damaged_linked_stream_is_an_error_or_a_checked_buffer_never_a_crash(seed):
    rng = np.random.default_rng(seed)
    targets = np.arange(500, dtype=np.uint32)
    targets[250:] = rng.integers(0, 250, 250)
    old = rng.integers(0, 500, size=(40, 3)).astype(np.uint32)
    new = old.copy().tolist()
    for k in range(8):
        i = int(rng.integers(len(new)))
        new[i] = new[-1]
        new.pop()
        t = new[int(rng.integers(len(new)))]
        t[k % 3] = int(targets[t[k % 3]]) if k % 2 else int(rng.integers(250, 500))
        new += [[t[1], t[0], 300 + k], [t[0], t[1], int(targets[t[0]])]]
    new = np.array(new, np.uint32)
    ops = _linked_round_trip(old, new, targets)
    links = opstream.Links(targets)
    assert _damaged_copies_judged_alike(ops, rng, LINKED_DECODERS, old, len(new), links, 500) > 150


@pytest.mark.parametrize("data, count, words", [
    (b"", 10, "empty"),
    (b"\x05\x00", 10, "announces 5 writes"),
    (b"\x01\x0e", 10, "kind 14"),
    (b"\x00", 11, "announces only 0 writes"),                       # grows by one: one write at least
    (b"\x01\x7d\x00\x00\x00", 11, "at most 124"),                # the appended write's kinds: 125
    (b"\x03\xa0\x01\x00" + b"\x00" * 9, 12, "past the 10 slots"),    # an in-place write to slot 10
    (b"\x01\x05\x0a", 10, "child 10 of vertex 0, which has 10"),   # SPLIT corner 0 of [0, 1, 2]
    (b"\x01\x0b\x00\x00", 10, "names write 0"),                   # an ADJ on its own edge
    (b"\x02\x0b\x00\x12\x00\x00\x00\x00", 10, "after it"),          # an ADJ on a NEW that follows it
    (b"\x01\x0d\x00", 10, "names write 0"),                       # an ADJ_TY on its own edge
    (b"\x01\x08\x00", 10, "need 0 payload varints"),               # MERGE takes none
    (b"\x01\x02\x7f", 10, "vertex index -64"),                     # CORNER 0 of [0, 1, 2] by -64
])
@pytest.mark.parametrize("decode", [opstream.decode_linked, linked_with_kernel])
def test_malformed_linked_streams_say_what_is_wrong(data, count, words, decode):
    targets = np.array([0] + [0] * 10 + list(range(11, 64)), np.uint32)
    links = opstream.Links(targets)
    old = np.arange(30, dtype=np.uint32).reshape(10, 3)
    with pytest.raises(opstream.OpStreamError, match=words):
        decode(data, old, count, links)
    with pytest.raises(opstream.OpStreamError):
        compiled_decode_linked(data, old, count, links)


def test_links_of_a_read_only_download_need_no_second_compilation():
    """A vertex buffer's morph targets are a view of the read-only payload; Links keeps its
    own writable copy, so the load generator's compiled decoder runs the signature
    compiled_decoding() warmed instead of compiling another one inside the timed run."""
    payload = np.array([0, 0, 1, 1, 4], np.uint32).tobytes()
    links = opstream.Links(np.frombuffer(payload, np.uint32))
    assert links.targets.flags.writeable
    with opstream.compiled_decoding():
        before = len(op_kernel.decode_linked.signatures)
        ops = _linked_round_trip(np.array([[0, 1, 4]], np.uint32), np.array([[0, 2, 4], [2, 0, 3]], np.uint32),
                                 links.targets)
        opstream.decode_linked(ops, np.array([[0, 1, 4]], np.uint32), 2, links)
        assert len(op_kernel.decode_linked.signatures) == before
