"""A camera's node-state table (caveclod.kernels.nodestate) against a dict, in both forms,
and a camera whose table grows, turns dense and shrinks back as it refines and coarsens."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import caveclod
from caveclod.builder.builtin import default_terrain
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.kernels import nodestate as NS
from caveclod.paths import pose
from caveclod.refine.view import View

N_NODES = 301          # not a multiple of 4: the dense form's last word is part-used
OPS = st.lists(st.tuples(st.integers(0, N_NODES - 1), st.integers(0, 255), st.integers(0, 255)), max_size=400)


@settings(max_examples=200, deadline=None)
@given(ops=OPS, room=st.integers(1, 200), dense=st.booleans())
def test_table_is_a_dict_of_non_zero_bytes(ops, room, dense):
    """Each op clears some bits of a node's byte and sets others; the table must read back what a
    dict of the non-zero bytes holds, count the blocks holding them, and keep a hash table at most
    half full (it is grown, as the camera grows it, whenever an op would need a row it lacks)."""
    t = dense_table() if dense else NS.new_node_states(room, 10**6)
    assert NS.is_dense(t) == dense
    want: dict[int, int] = {}
    for x, clear, add in ops:
        new = ((want.get(x, 0) & ~clear) | add) & 0xFF
        if new and not NS.ns_room(t, 1):
            t = NS.resized(t, 2 * NS.ns_count(t) + 16, 10**6)
        NS.ns_update(t, x, clear, add)
        if new:
            want[x] = new
        else:
            want.pop(x, None)
        assert NS.ns_get(t, x) == new
        assert NS.ns_count(t) == len({y // NS.BLOCK for y in want}), "blocks in use"
        if not NS.is_dense(t):
            assert NS.ns_count(t) <= (len(t) - 1) // 2
    for x in range(N_NODES):
        assert NS.ns_get(t, x) == want.get(x, 0), x
    nodes, vals = NS.ns_items(t, N_NODES)
    assert nodes.tolist() == sorted(want) and vals.tolist() == [want[x] for x in sorted(want)]
    dense_bytes = NS.ns_dense(t, N_NODES)
    assert dense_bytes.tolist() == [want.get(x, 0) for x in range(N_NODES)]
    # Either form copies into the other unchanged.
    for other in (dense_table(), NS.new_node_states(len(want) + 1, 10**6)):
        NS.ns_copy(t, other)
        assert NS.ns_dense(other, N_NODES).tolist() == dense_bytes.tolist()
        assert NS.ns_count(other) == NS.ns_count(t)


def dense_table() -> np.ndarray:
    t = NS.new_node_states(10**6, N_NODES)
    assert NS.is_dense(t) and t.shape == (NS.WORDS * NS.n_blocks(N_NODES) + 1, 1)
    return t


def test_form_follows_size():
    assert NS.new_node_states(100, 10**6).shape == (257, 5)
    assert NS.new_node_states(100, 1000).shape == (4 * 63 + 1, 1)
    assert NS.hash_is_smaller(10, 10**4) and not NS.hash_is_smaller(10**4, 10**4)


def test_camera_table_grows_turns_dense_and_shrinks_back():
    """Refined fully, every node has a byte: the table grows through NEED_NODES and ends dense (a
    byte a node, Equation 1's 4n at most). Seen from afar again it goes back to a hash table of the
    base mesh's size, and the state it holds is the one a fresh camera reaches."""
    mesh = build_static_mesh(default_terrain(96))
    lo, hi = mesh.bounds()
    target = tuple((lo + hi) / 2)
    far = tuple((lo + hi) / 2 + np.array([0.0, 0.0, 1e4 * float(np.linalg.norm(hi - lo))]))
    cam = mesh.new_camera()
    start = cam.state.shape
    assert not NS.is_dense(cam.state)
    cam.update(View(eye=far, target=target, up=(0, 1, 0), tolerance_px=0.0, prune=False))
    cam.validate()
    assert cam.n_faces == mesh.n_faces and NS.is_dense(cam.state)
    assert NS.ns_count(cam.state) == NS.n_blocks(mesh.n_nodes), "every node is active or split"
    assert cam.state.nbytes <= mesh.n_nodes + 64
    coarse = View(eye=far, target=target, up=(0, 1, 0), tolerance_px=1.0, prune=False)
    for _ in range(5):                    # coarsen, then an update with nothing to do trims
        cam.update(coarse)
    cam.validate()
    fresh = mesh.new_camera()
    fresh.update(coarse)
    assert not NS.is_dense(cam.state) and cam.state.shape[0] <= 4 * start[0]
    assert np.array_equal(cam.node_states() & 3, fresh.node_states() & 3)
    assert np.array_equal(cam.active_nodes(), fresh.active_nodes())


@settings(max_examples=100, deadline=None)
@given(notes=st.lists(st.integers(0, N_NODES - 1), max_size=60),
       bytes_after=st.lists(st.sampled_from([0, NS.IN_LIST | NS.ACTIVE, NS.IN_LIST | NS.SPLIT, NS.ACTIVE,
                                             NS.IN_LIST | NS.ACTIVE | NS.RECHECK]), min_size=N_NODES,
                            max_size=N_NODES))
def test_changed_set_notes_listed_nodes_and_keeps_the_stale(notes, bytes_after):
    """The set of listed nodes changed since their check (refine's "Clean lists"): a note of a
    listed node makes its entry suspect, a node without an entry is not noted, more notes than
    half the rows overflow (every entry suspect); settling keeps just the entries still stale
    (listed, and not active or marked RECHECK) and reports an overflow once."""
    t = NS.new_node_states(10**6, N_NODES)                       # dense, every byte 0
    listed = [x for x in range(N_NODES) if x % 3]
    NS.ns_fill(t, np.array(listed, np.int32), NS.IN_LIST | NS.ACTIVE)
    c = NS.new_changed_set(N_NODES)             # 64 rows: 32 notes, then it overflows
    assert len(c) == 65
    rows = len(c) - 1
    assert not any(NS.cs_suspect(c, x) for x in range(N_NODES)), "an empty set suspects nothing"
    for x in notes:
        NS.cs_note(c, t, x)
    want = {x for x in notes if x % 3}
    overflow = 2 * len(want) > rows
    for x in range(N_NODES):
        assert NS.cs_suspect(c, x) == (overflow or x in want), x
    for x in range(N_NODES):
        NS.ns_set(t, x, bytes_after[x])
    assert NS.cs_settle(c, t) == (not overflow)
    stale = set() if overflow else {x for x in want if bytes_after[x] & NS.IN_LIST and
                                    (bytes_after[x] & NS.STATE_MASK != NS.ACTIVE or bytes_after[x] & NS.RECHECK)}
    for x in range(N_NODES):
        assert NS.cs_suspect(c, x) == (x in stale), x


@pytest.mark.parametrize("name", ["rough", "debris", "jumps"])
def test_clean_lists_decide_and_evaluate_as_reading_every_byte(name):
    """A camera that trusts its clean list (reads only the bytes of noted entries) against one
    made to read every entry's byte before each update, as passes did before: the same
    operations, the same entries evaluated (so trust never skips an entry a read would evaluate
    or evaluates one a read would drop) and the same faces, over flights with jumps, part
    hiding and a tolerance change."""
    mesh = caveclod.build("debris", size=2, seed=5) if name == "debris" else caveclod.build(
        "rough" if name == "rough" else "default", size=40)
    lo, hi = mesh.bounds()
    trusting, reading = mesh.new_camera(), mesh.new_camera()
    trusted = 0
    for f in range(120):
        if name == "jumps":                                 # another camera's pose every 4 frames
            p = pose("flyover", lo, hi, (f // 4) % 3, f / 2)
        else:
            t = (f // 40) * 7.0 + (f % 40) / 10.0          # jumps at 40 and 80
            p = pose("flyover" if name == "rough" else "circle", lo, hi, f // 40, t)
        view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=640, height=360,
                             tolerance_px=2.0 if f >= 100 else 0.7)
        trusted += int(trusting._resume[4])
        reading._resume[4] = 0
        a, b = trusting.update(view), reading.update(view)
        assert (a.splits, a.collapses, a.tested) == (b.splits, b.collapses, b.tested), f
        assert (a.parts_shown, a.parts_hidden) == (b.parts_shown, b.parts_hidden), f
        trusting.validate()         # includes what a clean list trusts
        if f % 10 == 9:
            assert np.array_equal(trusting.active_nodes(), reading.active_nodes())
            ta, tb = trusting.triangles(), reading.triangles()
            assert all(np.array_equal(np.sort(ta[m], axis=None), np.sort(tb[m], axis=None)) for m in ta)
    assert trusted > 40, "most passes ran on a clean list"
