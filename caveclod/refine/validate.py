"""Plain-numpy invariant checks of a camera state (slow; for tests and debugging)."""

from __future__ import annotations

import numpy as np

from ..kernels import refine as K
from ..kernels.facemap import fm_dense
from ..kernels.parts import HIDDEN


def _fail(msg: str):
    raise AssertionError(f"camera state invalid: {msg}")


def validate_camera(cam) -> None:
    """See :meth:`caveclod.refine.camera.CameraState.validate`."""
    mesh = cam.mesh
    e = mesh.n_positions
    parent = np.asarray(mesh.node_parent)
    byte = cam.node_states()
    state = byte & K.STATE_MASK
    n = len(parent)

    # The front: ancestors of active nodes are split, split nodes' parents split.
    active = np.flatnonzero(state == K.ACTIVE)
    has_p = parent[active] >= 0
    if (state[parent[active][has_p]] != K.SPLIT).any():
        _fail("an active node's parent is not split")
    split = np.flatnonzero(state == K.SPLIT)
    if (split < e).any():
        _fail("a leaf is marked split")
    sp = parent[split]
    if (state[sp[sp >= 0]] != K.SPLIT).any():
        _fail("a split node's parent is not split")
    children = np.asarray(mesh.node_children)
    kids = children[split - e].ravel()
    if (state[kids] == K.INACTIVE).any():
        _fail("a split node has an inactive child")
    roots = np.flatnonzero(parent < 0)
    if (state[roots] == K.INACTIVE).any():
        _fail("a root is inactive")
    # Hidden parts: all their roots HIDDEN, nothing else is.
    parts = mesh.parts()
    part_of_root = np.repeat(np.arange(parts.count), np.diff(parts.root_start))
    hidden_root = state[parts.roots] == HIDDEN
    if not np.array_equal(hidden_root, cam.part_hidden[part_of_root] != 0):
        _fail("a hidden part's root is not hidden, or a visible part's root is")
    if int(np.count_nonzero(state == HIDDEN)) != int(hidden_root.sum()):
        _fail("a node outside the hidden parts' roots is hidden")
    if cam.hidden_parts != int(np.count_nonzero(cam.part_hidden)):
        _fail("the count of hidden parts disagrees with the parts' flags")
    listed = cam.active[: cam.n_active[0]]
    if len(np.unique(listed)) != len(listed):
        _fail("a node is listed twice in the active list")
    if (byte & K.QUEUED).any():
        _fail("a collapse candidate is still marked queued after the pass")
    if not np.array_equal(np.sort(listed[state[listed] == K.ACTIVE]), active):
        _fail("active list does not hold exactly the active nodes")
    if cam._resume[4]:
        # A clean list (kernels/refine.py, "Clean lists"): the next pass trusts every entry
        # outside the set of changed nodes to be active and not marked RECHECK.
        noted = cam.changed[:-1, 0]
        trusted = listed[~np.isin(listed, noted[noted >= 0])]
        if ((byte[trusted] & K.STATE_MASK) != K.ACTIVE).any() or (byte[trusted] & K.RECHECK).any():
            _fail("a clean list trusts an entry whose node is not active, or is marked RECHECK")
    inlist = np.zeros(n, bool)
    inlist[listed] = True
    if not np.array_equal(inlist, (byte & K.IN_LIST) != 0):
        _fail("IN_LIST bits disagree with the active list")

    # Faces: active exactly when their creator is split (base faces: while their part is shown).
    creator = np.asarray(mesh.face_creator)
    want = np.ones(len(creator), bool)
    made = creator >= 0
    want[made] = state[creator[made]] == K.SPLIT
    part_of_face = np.repeat(np.arange(parts.count), np.diff(parts.face_start))
    base = np.asarray(mesh.base_faces)[parts.faces]
    want[base] = cam.part_hidden[part_of_face] == 0
    face_rec = fm_dense(cam.face_map, len(creator))
    indexed = face_rec >= 0
    if not np.array_equal(want, indexed):
        _fail("a face is active while its creator is not split, or the reverse")

    mat = np.asarray(mesh.face_material)
    recs = []
    for s in range(cam.n_materials):
        lo = int(cam.off[s])
        c = int(cam.cnt[s])
        if c > cam.cap[s]:
            _fail(f"material {s} holds more records than its capacity")
        r = np.arange(lo, lo + c)
        faces = cam.rec_face[r]
        if (mat[faces] != s).any():
            _fail(f"a face sits in the index buffer of another material ({s})")
        if not np.array_equal(face_rec[faces], r):
            _fail(f"the face -> record map and the records disagree in material {s}")
        recs.append(r)
    recs = np.concatenate(recs) if recs else np.zeros(0, np.int64)
    faces = cam.rec_face[recs]
    if int(indexed.sum()) != len(recs):
        _fail("the face -> record map holds a face no record holds")
    pos = mesh.vertex_position_ids[cam.rec_tri[recs]].astype(np.int64)
    nbr = cam.rec_nbr[recs]

    if ((pos[:, 0] == pos[:, 1]) | (pos[:, 1] == pos[:, 2]) | (pos[:, 2] == pos[:, 0])).any():
        _fail("a degenerate face (a position used twice)")
    # Index buffers mirror the D3Dindex lookup of each face's group.
    sgid = np.asarray(mesh.face_sgid)[faces]
    try:
        expect = mesh.lookup_vertices(np.repeat(sgid, 3), pos.ravel()).reshape(-1, 3)
    except KeyError:
        _fail("a face sits on a position where its surface group has no vertex")
    if not np.array_equal(expect, cam.rec_tri[recs].astype(np.int64)):
        _fail("an index-buffer entry differs from the lookup of its face's corner")

    # Crack-freeness: links are mutual over the same (reversed) edge ...
    slot_of = {int(f): i for i, f in enumerate(faces)}
    a, b = pos, np.roll(pos, -1, axis=1)
    for i in range(len(faces)):
        for k in range(3):
            g = int(nbr[i, k])
            if g < 0:
                continue
            j = slot_of.get(g)
            if j is None:
                _fail(f"face {faces[i]} links to inactive face {g}")
            hits = np.flatnonzero((a[j] == b[i, k]) & (b[j] == a[i, k]))
            if len(hits) != 1 or nbr[j, hits[0]] != faces[i]:
                _fail(f"faces {faces[i]} and {g} are not linked over a shared edge")
    # ... and no two faces share an edge without a link (that would be a crack).
    open_edges = nbr < 0
    keys = {}
    for i, k in zip(*np.nonzero(open_edges)):
        keys.setdefault((int(a[i, k]), int(b[i, k])), []).append(i)
    for (x, y), items in keys.items():
        if (y, x) in keys and len(items) == 1 and len(keys[(y, x)]) == 1:
            _fail(f"edge {x}-{y} is shared by two faces but not linked: a crack")

    # The strict bound: no active node beside a position gone before it was made.
    if cam.strict_bound:
        from .measure import mixed_nodes
        mixed = mixed_nodes(cam)
        if len(mixed):
            _fail(f"{len(mixed)} active nodes (first {int(mixed[0])}) stand beside a position gone before "
                  "they were made, under the strict bound")
