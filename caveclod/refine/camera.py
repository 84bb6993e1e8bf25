"""One camera's refinement state over a shared static mesh (paper 3.4).

Holds only camera-specific data; see :mod:`caveclod.kernels.refine` for the
layout. ``update`` runs the compiled kernel, which releases the GIL, so
cameras updated from different threads refine truly in parallel.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import CaveclodError, InputError
from ..kernels import parts as KP
from ..kernels import refine as K
from ..kernels import nodestate as NS
from ..kernels.facemap import fm_fill, new_face_map
from .view import P_BACKFACE, P_CULL, P_EYE, P_KAPPA, P_PLANES, P_PRUNE, P_TOL, View

UNLIMITED = np.iinfo(np.int64).max
REBASE_TURNS = 100.0        # radians the odometer may turn before expiries are rebased
REBASE_EXTENTS = 100.0      # mesh diagonals it may travel (float32 expiries keep ~1e-5 of it)
NO_RING = np.zeros((0, 2), np.float32)   # a file from before ring bounds: the ring test is off
NO_RING.setflags(write=False)            # read-only like a loaded file's maps: one compiled variant of the kernel
NO_TOPS = np.zeros(0, np.int32)          # no strict bound (StaticMesh.position_tops when there is)
NO_TOPS.setflags(write=False)
SLACK_RECORDS = 256         # room per material kept beyond the need (28 bytes a record: 7 KB at most)


@dataclass
class SurfaceDelta:
    """Slot writes of one material's index buffer.

    Attributes:
        slots: (k,) uint32 slots written, ascending.
        tris: (k, 3) uint32 the three vertex-buffer indices now in each slot.
        count: triangles in the buffer after the writes (it is truncated or
            grown to this length; every slot below it that changed is written).
    """

    slots: np.ndarray
    tris: np.ndarray
    count: int


@dataclass
class Delta:
    """What one :meth:`CameraState.update` changed.

    Attributes:
        surfaces: {material id: SurfaceDelta} for each material that changed.
        splits, collapses: operations made.
        seconds: time the update took.
        budget_exhausted: ``max_ops`` or ``max_faces`` stopped the update
            short: the camera has not converged for its view yet, and later
            updates with the same view go on refining.
        tested: active nodes whose answer was worked out; the others were
            skipped because no motion since could have changed it.
        parts_shown, parts_hidden: whole parts that came back or vanished
            (:mod:`caveclod.kernels.parts`).
    """

    surfaces: dict = field(default_factory=dict)
    splits: int = 0
    collapses: int = 0
    seconds: float = 0.0
    budget_exhausted: bool = False
    tested: int = 0
    parts_shown: int = 0
    parts_hidden: int = 0

    @property
    def operations(self) -> int:
        return self.splits + self.collapses + self.parts_shown + self.parts_hidden

    def apply(self, buffers: dict) -> dict:
        """Apply to ``buffers`` {material: (k, 3) uint32} and return them."""
        for s, d in self.surfaces.items():
            old = buffers.get(s, np.zeros((0, 3), np.uint32))
            new = np.zeros((d.count, 3), np.uint32)
            keep = min(len(old), d.count)
            new[:keep] = old[:keep]
            new[d.slots] = d.tris
            buffers[s] = new
        return buffers


RECORD_ARRAYS = ("rec_tri", "rec_nbr", "rec_face")


class CameraState:
    """Active nodes and faces of one camera, refined incrementally.

    ``mesh.new_camera()`` makes one showing the base mesh. Options:
    ``max_ops`` (operations per update) and ``max_faces`` (active faces)
    bound the work and size of an update; both default to unlimited.
    ``expiries=False`` re-evaluates every active node on every update
    instead of skipping those whose answer cannot have changed (for tests
    and measurements; the results are the same). ``strict_bound=True``
    never shows a node beside a position that was gone when the node's
    error was measured (the mixes of ages that let original positions lie
    up to 1.14 t from what is drawn; docs/error-bounds.md, "The strict
    bound"): more splits, every original position within the tolerance.
    """

    def __init__(self, mesh, max_ops: int | None = None, max_faces: int | None = None, expiries: bool = True,
                 strict_bound: bool = False):
        self.mesh = mesh
        self.strict_bound = bool(strict_bound)
        self.max_ops = UNLIMITED if max_ops is None else int(max_ops)
        # A face budget the mesh cannot reach is no budget (and keeps the
        # single pass with expiries).
        self.max_faces = UNLIMITED if max_faces is None or max_faces >= mesh.n_faces else int(max_faces)
        self.expiries = bool(expiries) and self.max_ops == UNLIMITED and self.max_faces == UNLIMITED
        a = {k: np.asarray(v) for k, v in mesh.arrays.items()}   # plain views of the maps
        self._static = (
            mesh.n_positions, a["node_parent"], a["node_links"], a["node_position"],
            # The strict bound makes the ring test's splits whenever they matter (and more): without it.
            a["node_bound"], a["node_cone"], NO_RING if self.strict_bound else a.get("node_ring", NO_RING),
            a["face_creator"], a["face_rotation"],
            a["face_material"], a["face_sgid"], a["pos_vstart"], a["vertex_sgid"], mesh.vertex_position_ids,
            mesh.position_tops() if self.strict_bound else NO_TOPS,
        )
        self._faces_of_material, base_count = mesh.material_face_counts()
        self.n_materials = len(base_count)
        # Room kept beyond the need (SLACK_RECORDS), less on small meshes, where Equation 1 allows little.
        self._slack = np.minimum(SLACK_RECORDS, self._faces_of_material // 16)
        self.cnt = np.zeros(self.n_materials, np.int64)
        self._layout(np.maximum(base_count + base_count // 4, 4))
        self._sent = np.zeros(self.n_materials, np.int64)   # buffer lengths the last delta announced
        self._add_base(a)
        parts = mesh.parts()
        self._parts_static = (a["base_faces"], a["base_face_nodes"], a["base_face_nbrs"], parts.sphere,
                              parts.root_start, parts.roots, parts.face_start, parts.faces)
        self.part_hidden = np.zeros(parts.count, np.uint8)    # 1 while the part is hidden
        self.part_texp = np.full(parts.count, -np.inf)        # expiries of each part's answer, on odo[0] ...
        self.part_aexp = np.full(parts.count, -np.inf)        # ... and odo[1]
        self._part_counts = np.zeros(2, np.int64)             # parts shown, hidden by this update
        self._parts_due = (-np.inf, -np.inf)                  # earliest part expiries (odo[0], odo[1])
        self._n_hidden = 0                                    # part_hidden.sum(), kept (servers read it every frame)
        self.queue = np.empty(32, np.int32)                # collapse candidates of a pass
        self.fstack = np.empty(32, np.int64)               # a forced split's stack, kept when a pass stops for room
        self.counts = np.zeros(4, np.int64)
        self._resume = np.zeros(6, np.int64)      # where an interrupted pass goes on (its forced split too); clean?
        self._hashed_blocks_max = NS.most_hashed_blocks(mesh.n_nodes)   # beyond: the dense form is smaller
        self.odo = np.zeros(2)                    # distance travelled, angle turned
        self._last_view = None
        lo, hi = mesh.bounds()
        self._rebase_distance = REBASE_EXTENTS * max(float(np.linalg.norm(hi - lo)), 1e-30)

    # -- set-up -------------------------------------------------------------
    def _layout(self, capacity: np.ndarray, old: dict | None = None) -> None:
        """(Re)allocate the record pool with ``capacity`` per material.

        Records move, so the written-slot bits are re-set where the records
        they mark went, and the face map is made afresh for the new pool
        (twice its records, so that it stays at most half full; dense when
        that is smaller) with every moved record's face in it.
        """
        self.cap = np.minimum(capacity.astype(np.int64), self._faces_of_material)
        self.off = np.zeros(self.n_materials, np.int64)
        np.cumsum(self.cap[:-1], out=self.off[1:])
        total = int(self.cap.sum())
        new = {
            "rec_tri": np.zeros((total, 3), np.uint32),
            "rec_nbr": np.full((total, 3), -1, np.int32),
            "rec_face": np.full(total, -1, np.int32),
        }
        dirty = np.zeros((total + 63) // 64, np.uint64)
        self.face_map = new_face_map(total, self.mesh.n_faces)
        if old is not None:
            K.move_records(self.cnt, old["off"], old["rec_tri"], old["rec_nbr"], old["rec_face"], old["dirty"],
                           self.off, new["rec_tri"], new["rec_nbr"], new["rec_face"], dirty, self.face_map)
        for k, v in new.items():
            setattr(self, k, v)
        self.dirty = dirty

    def _relayout(self, capacity: np.ndarray) -> None:
        """Re-lay out the record pool with ``capacity`` per material, keeping every record."""
        old = {k: getattr(self, k) for k in RECORD_ARRAYS}
        old["off"], old["dirty"] = self.off, self.dirty
        self._layout(capacity, old)

    def _grow_records(self, material: int) -> None:
        cap = self.cap.copy()
        # Grow by a quarter: a camera's bytes are what adding a camera costs,
        # so slack is kept small; re-layout is O(active faces) and rare
        # (at least SLACK_RECORDS, or a small material re-lays out the pool
        # a few faces at a time).
        cap[material] = cap[material] + max(cap[material] // 4, self._slack[material], 8)
        self._relayout(cap)

    def _trim(self) -> None:
        """Give back room a pass no longer uses (after a jump to a coarser
        view): what is more than twice the need and SLACK_RECORDS goes, so
        that a camera at rest holds the bytes its active counts call for
        (Equation 1). Run only after an update that changed nothing: a
        moving camera's counts swing, and trimming then grows the arrays
        again a moment later. The absolute slack keeps a camera whose counts
        wobble by a few faces from re-laying out its records back and forth
        (a flyover at 30 Hz did so on a fifth of its updates, 0.6 ms each)."""
        n = int(self.n_active[0])
        if len(self.active) > 2 * n + int(self._slack.sum()):
            size = n + n // 4 + 8
            for name in ("active", "texp", "aexp"):
                setattr(self, name, getattr(self, name)[:size].copy())
            self._size_changed_set()
        wasted = self.cap > 2 * self.cnt + self._slack + 4
        if wasted.any():
            self._relayout(np.where(wasted, self.cnt + self.cnt // 4 + self._slack // 4 + 4, self.cap))
        # The node-state table likewise: a hash table of more than four times
        # the rows the need calls for shrinks to fit it; a dense one becomes a
        # hash table when one for 2.5 times the need would be smaller.
        held = NS.ns_count(self.state)
        want = held + held // 4 + 16
        if NS.is_dense(self.state):
            shrink = 2 * want <= self._hashed_blocks_max
        else:
            shrink = len(self.state) - 1 > 4 * NS.table_rows(want)
        if shrink:
            self.state = NS.resized(self.state, want, self.mesh.n_nodes)

    def _grow_list(self, at_least: int = 0) -> None:
        """Grow the active list by a quarter, or to ``at_least`` entries if that is more."""
        size = max(len(self.active) + len(self.active) // 4, 16, at_least)
        for name, fill in (("active", -1), ("texp", -np.inf), ("aexp", -np.inf)):
            old = getattr(self, name)
            bigger = np.full(size, fill, old.dtype)
            bigger[: self.n_active[0]] = old[: self.n_active[0]]
            setattr(self, name, bigger)
        self._size_changed_set()

    def _size_changed_set(self) -> None:
        """The set of changed listed nodes follows the list's size; its notes are dropped, so
        the next pass checks every entry (kernels/nodestate.py)."""
        self.changed = NS.new_changed_set(len(self.active), overflowed=True)

    def _grow_nodes(self) -> None:
        """Double the node-state table (or make it dense, when that is smaller)."""
        self.state = NS.resized(self.state, 2 * NS.ns_count(self.state) + 16, self.mesh.n_nodes)

    def _grow_queue(self) -> None:
        bigger = np.empty(2 * len(self.queue), np.int32)
        bigger[: len(self.queue)] = self.queue
        self.queue = bigger

    def _grow_stack(self, at_least: int) -> None:
        """Grow the forced-split stack, keeping its entries (the stopped split goes on from them)."""
        bigger = np.empty(max(2 * len(self.fstack), at_least), np.int64)
        bigger[: len(self.fstack)] = self.fstack
        self.fstack = bigger

    def _add_base(self, a: dict) -> None:
        roots = np.flatnonzero(a["node_parent"] < 0).astype(np.int32)
        # The node bytes of what a camera holds: its active and split nodes, in
        # blocks of 16 (a hash table while that is smaller than a byte per node).
        blocks = len(np.unique(roots >> 4))
        self.state = NS.new_node_states(blocks + blocks // 4 + 16, self.mesh.n_nodes)
        NS.ns_fill(self.state, roots, K.ACTIVE | K.IN_LIST)
        size = max(len(roots) + len(roots) // 4, 16)
        self.active = np.empty(size, np.int32)
        self.texp = np.full(size, -np.inf, np.float32)
        self.aexp = np.full(size, -np.inf, np.float32)
        self.active[: len(roots)] = roots
        self.n_active = np.array([len(roots)], np.int64)
        self._size_changed_set()
        faces = a["base_faces"]
        pos = self.mesh.node_positions(a["base_face_nodes"].ravel()).reshape(-1, 3)
        mat = a["face_material"][faces]
        tri = self.mesh.lookup_vertices(np.repeat(a["face_sgid"][faces], 3), pos.ravel()).reshape(-1, 3)
        for s in map(int, np.unique(mat)):        # the materials of base faces (the others start empty)
            pick = np.flatnonzero(mat == s)
            r = int(self.off[s]) + np.arange(len(pick))
            self.cnt[s] = len(pick)
            self.rec_face[r] = faces[pick]
            self.rec_tri[r] = tri[pick]
            self.rec_nbr[r] = a["base_face_nbrs"][pick]
            fm_fill(self.face_map, faces[pick].astype(np.int32), r.astype(np.int32))
            np.bitwise_or.at(self.dirty, r >> 6, np.uint64(1) << (r & 63).astype(np.uint64))

    # -- refinement -----------------------------------------------------------
    def update(self, view: View) -> Delta:
        """Refine incrementally for ``view``; returns the index-buffer delta."""
        if not isinstance(view, View):
            raise InputError(f"update() takes a caveclod.View, got {type(view).__name__}")
        return self.update_params(view.params())

    def update_params(self, vp: np.ndarray) -> Delta:
        """:meth:`update` for a view's kernel parameters (:func:`caveclod.refine.view.view_params`)."""
        t0 = time.perf_counter()
        if not np.isfinite(vp).all():     # a View built around its own checks, or numbers that overflowed
            raise InputError("the view has NaN or infinite numbers; send a finite pose")
        self._advance_odometer(vp)
        self.counts[:] = 0
        self._part_counts[:] = 0
        due_t, due_a = self._parts_due
        parts_due = not self.expiries or self.odo[0] >= due_t or self.odo[1] >= due_a
        if parts_due:
            self._show_parts(vp)
            if self._part_counts[0]:
                self._resume[4] = 0       # node states changed outside a pass: the list is not clean
        if self.max_ops == UNLIMITED and self.max_faces == UNLIMITED:
            self._pass(vp, K.MIXED)
        else:
            # Under a budget a forced split may stop half-way; refining first
            # and coarsening with what is left keeps the next update from
            # collapsing the half-made dependencies again (no oscillation).
            self._pass(vp, K.SPLITS_ONLY)
            if self.counts[0] + self.counts[1] < self.max_ops:
                self._pass(vp, K.COLLAPSES_ONLY)
        if parts_due:
            self._hide_parts(vp)
            if self._part_counts[1]:
                self._resume[4] = 0
        delta = self._collect_delta()
        delta.splits, delta.collapses = int(self.counts[0]), int(self.counts[1])
        delta.parts_shown, delta.parts_hidden = int(self._part_counts[0]), int(self._part_counts[1])
        self._n_hidden += delta.parts_hidden - delta.parts_shown
        if not delta.operations:
            self._trim()              # at rest: a moving camera would only grow again
        delta.budget_exhausted = bool(self.counts[2])
        delta.tested = int(self.counts[3])
        delta.seconds = time.perf_counter() - t0
        return delta

    def _advance_odometer(self, vp: np.ndarray) -> None:
        """Add the eye's travel and the frustum's turn since the last view to
        :attr:`odo` (what the active list's expiries are read against); a
        change of criteria (viewport height, field of view, tolerance,
        culling) expires every entry instead."""
        last = self._last_view
        now = vp.tolist()
        self._last_view = now
        if last is None or any(last[k] != now[k] for k in (P_KAPPA, P_TOL, P_CULL, P_BACKFACE, P_PRUNE)):
            self.texp[:] = -np.inf
            self.part_texp[:] = -np.inf
            self._parts_due = (-np.inf, -np.inf)
            return
        self.odo[0] += math.dist(now[P_EYE:P_EYE + 3], last[P_EYE:P_EYE + 3])
        self.odo[1] += max(math.dist(now[b:b + 3], last[b:b + 3]) for b in range(P_PLANES, P_PLANES + 20, 4))
        if self.odo[0] > self._rebase_distance or self.odo[1] > REBASE_TURNS:
            # float32 expiries lose precision far from zero: count from here.
            n = int(self.n_active[0])
            for exp, base in ((self.texp, self.odo[0]), (self.aexp, self.odo[1])):
                shifted = exp[:n].astype(np.float64) - base
                down = shifted.astype(np.float32)
                up = down.astype(np.float64) > shifted
                down[up] = np.nextafter(down[up], np.float32(-np.inf))
                exp[:n] = down
            self.part_texp -= self.odo[0]         # float64: exact enough as they are
            self.part_aexp -= self.odo[1]
            self._parts_due = (-np.inf, -np.inf)
            self.odo[:] = 0.0

    def _pass(self, vp: np.ndarray, mode: int) -> None:
        """Run one refinement pass to its end, growing arrays when asked."""
        expire = self.expiries and mode == K.MIXED
        try:
            while True:
                status, material = K.adapt(*self._static, self.state, self.face_map, self.off, self.cnt,
                                           self.cap, self.rec_tri, self.rec_nbr, self.rec_face, self.dirty,
                                           self.active, self.texp, self.aexp,
                                           self.n_active, self.queue, self.fstack, self.changed, vp, self.odo,
                                           self.max_ops,
                                           self.max_faces, self.counts, self._resume, mode, expire)
                if status == K.OK:
                    return
                if status == K.NEED_RECORDS:
                    self._grow_records(int(material))
                elif status == K.NEED_LIST:
                    self._grow_list()
                elif status == K.NEED_QUEUE:
                    self._grow_queue()
                elif status == K.NEED_NODES:
                    self._grow_nodes()
                elif status == K.NEED_STACK:
                    self._grow_stack(int(material))
                elif status == K.DAMAGED:
                    raise self.mesh.mark_damaged(f"refinement found an impossible hierarchy at node {int(material)}")
                else:  # pragma: no cover - the kernel has no other status
                    raise CaveclodError(f"refinement kernel returned status {status}")
        finally:
            if self._resume[2]:
                self._abandon_pass()

    def _show_parts(self, vp: np.ndarray) -> None:
        """Bring back the hidden parts the view needs drawn again (grown, or back in view),
        growing the arrays once for all of them when asked."""
        if not len(self.part_hidden):
            return
        e, _, _, npos, _, _, _, _, _, mat, fsgid, pos_vstart, vertex_sgid, _, _ = self._static
        shown = self._part_counts[0:1]
        todo = np.empty(len(self.part_hidden), np.int32)
        need = np.zeros(self.n_materials + 1, np.int64)       # records per material, then list entries
        for _ in range(2):                                    # room is made for all of them at once
            status, what = KP.show_parts(
                e, npos, mat, fsgid, pos_vstart, vertex_sgid, *self._parts_static, self.part_hidden, self.part_texp,
                self.part_aexp, self.state, self.face_map, self.off, self.cnt, self.cap, self.rec_tri, self.rec_nbr,
                self.rec_face, self.dirty, self.active, self.texp, self.aexp, self.n_active, vp, self.odo,
                self.expiries, todo, need, shown)
            if status == K.OK:
                return
            if status == K.NEED_RECORDS:
                self._make_room(need[:-1], int(need[-1]))
            elif status == K.DAMAGED:
                raise self.mesh.mark_damaged(f"base face {int(what)} has a corner without a vertex of its group")
            else:  # pragma: no cover - the kernel has no other status
                raise CaveclodError(f"part kernel returned status {status}")
        raise CaveclodError("showing parts still lacked room after the arrays grew; this is a bug")

    def _make_room(self, records: np.ndarray, entries: int) -> None:
        """Grow the record pool by ``records`` (materials,) and the active list by ``entries``
        beyond what they hold, at once. By half again, not a quarter as a pass grows: parts
        come back in waves as a camera approaches, and each re-layout costs O(records)
        (a dolly towards 5,120 parts re-laid out 33 times at a quarter). A camera at rest
        is trimmed back to its need all the same."""
        want = self.cnt + records
        short = want > self.cap
        if short.any():
            bigger = np.maximum(want + np.maximum(want // 2, self._slack), self.cap + 8)
            self._relayout(np.where(short, bigger, self.cap))
        n = int(self.n_active[0]) + entries
        if n > len(self.active):
            self._grow_list(n + n // 4 + 16)

    def _hide_parts(self, vp: np.ndarray) -> None:
        """Hide the parts the view need not draw (small, or outside it), however refined."""
        if not len(self.part_hidden):
            return
        e, _, links, _, _, _, _, _, _, mat, _, _, _, _, _ = self._static
        base_faces, _, _, sphere, root_start, roots, face_start, faces = self._parts_static
        self._parts_due = KP.hide_parts(
            e, links, base_faces, mat, sphere, root_start, roots, face_start, faces, self.part_hidden,
            self.part_texp, self.part_aexp, self.state, self.face_map, self.off, self.cnt, self.rec_tri, self.rec_nbr,
            self.rec_face, self.dirty, vp, self.odo, self.expiries, self._part_counts[1:2])

    def _abandon_pass(self) -> None:
        """Close an interrupted pass (growth failed): keep the listed nodes.

        Entries before the write position were kept, those from the read
        position on were not reached; what lies between is stale. Waiting
        collapse candidates are dropped.
        """
        i, w, _, q = (int(v) for v in self._resume[:4])
        n = int(self.n_active[0])
        for arr in (self.active, self.texp, self.aexp):
            arr[w: w + n - i] = arr[i:n].copy()
        self.n_active[0] = w + n - i
        NS.ns_clear(self.state, self.queue[:q], K.QUEUED)
        self._resume[:] = 0

    def _collect_delta(self) -> Delta:
        k = int(self.cnt.sum())
        mats = np.empty(k, np.int64)
        slots = np.empty(k, np.uint32)
        tris = np.empty((k, 3), np.uint32)
        k = K.collect_writes(self.off, self.cnt, self.rec_tri, self.dirty, mats, slots, tris)
        mats, slots, tris = mats[:k], slots[:k], tris[:k]
        delta = Delta()
        bounds = np.searchsorted(mats, np.arange(self.n_materials + 1))
        # The materials written or resized (not all 65,536 a file may name): mats is
        # sorted, so a material's writes are bounds[s]..bounds[s + 1].
        for s in np.flatnonzero((bounds[1:] > bounds[:-1]) | (self.cnt != self._sent)).tolist():
            lo, hi = int(bounds[s]), int(bounds[s + 1])
            delta.surfaces[s] = SurfaceDelta(slots[lo:hi], tris[lo:hi], int(self.cnt[s]))
        self._sent[:] = self.cnt
        return delta

    def keyframe(self) -> Delta:
        """A delta that rebuilds every buffer from nothing (for a new client).

        Later deltas go on from it (:meth:`mark_sent`)."""
        delta = Delta()
        for s, tri in self.triangles().items():
            delta.surfaces[s] = SurfaceDelta(np.arange(len(tri), dtype=np.uint32), tri.copy(), len(tri))
        self.mark_sent()
        return delta

    def mark_sent(self) -> None:
        """The client now holds every buffer whole, as it is (a keyframe went out, built
        from :meth:`index_buffer`): later deltas announce each buffer's length from here,
        so a buffer that a hidden part empties is announced even if it held nothing before."""
        self._sent[:] = self.cnt

    def reorder_for_vertex_cache(self, material: int) -> np.ndarray | None:
        """Put one material's index buffer in vertex-cache order (:mod:`caveclod.kernels.cacheorder`);
        returns the order, (count,) int32 (slot j now holds what slot order[j] held), or None when
        nothing moved.

        Moves the material's records (each keeps its corners and neighbour
        links, which name faces) to new slots and repoints their faces. The
        client's copy no longer matches slot by slot, so the caller sends
        the whole buffer next (a keyframe does): no slot is marked written,
        and marks left over in the range are cleared. Copies of the buffer
        kept elsewhere (cache mode's ActiveVertices) follow ``order``.
        """
        from ..kernels.cacheorder import cache_order
        lo, n = int(self.off[material]), int(self.cnt[material])
        if n < 3:
            return None
        rows = slice(lo, lo + n)
        order = cache_order(self.rec_tri[rows])
        for name in RECORD_ARRAYS:
            array = getattr(self, name)
            array[rows] = array[rows][order]
        fm_fill(self.face_map, self.rec_face[rows], np.arange(lo, lo + n, dtype=np.int32))
        marks = np.zeros(len(self.dirty) * 64, np.bool_)      # record r is bit r & 63 of word r >> 6
        marks[rows] = True
        self.dirty &= ~np.packbits(marks, bitorder="little").view("<u8")
        return order

    # -- views of the state -----------------------------------------------------
    def triangles(self) -> dict:
        """{material: (k, 3) uint32 vertex-buffer indices}: the index buffers."""
        return {s: self.rec_tri[int(self.off[s]): int(self.off[s] + self.cnt[s])].copy()
                for s in range(self.n_materials) if self.cnt[s] > 0}

    def index_buffer(self, material: int) -> np.ndarray:
        """(count, 3) uint32 view of one material's index buffer, without a copy.

        This is the server's mirror of a client's buffer (slot k is row k);
        it is only valid until the next :meth:`update`.
        """
        lo = int(self.off[material])
        return self.rec_tri[lo: lo + int(self.cnt[material])]

    def active_faces(self) -> np.ndarray:
        """(k,) int32 ids of the active faces."""
        return np.concatenate([self.rec_face[int(self.off[s]): int(self.off[s] + self.cnt[s])]
                               for s in range(self.n_materials)])

    def active_nodes(self) -> np.ndarray:
        """(k,) int32 ids of the active nodes (the front), sorted."""
        nodes, states = NS.ns_items(self.state, self.mesh.n_nodes)
        return nodes[(states & K.STATE_MASK) == K.ACTIVE]

    def node_states(self) -> np.ndarray:
        """(n,) uint8 every node's state byte (:mod:`caveclod.kernels.refine`), for checks: O(mesh)."""
        return NS.ns_dense(self.state, self.mesh.n_nodes)

    @property
    def n_faces(self) -> int:
        return int(self.cnt.sum())

    @property
    def hidden_parts(self) -> int:
        """Parts hidden for being smaller than the tolerance or outside the view."""
        return self._n_hidden

    @property
    def nbytes(self) -> int:
        """Bytes this camera owns (the static mesh is shared, not counted)."""
        arrays = (self.state, self.face_map, self.rec_tri, self.rec_nbr, self.rec_face, self.dirty, self._slack,
                  self.active, self.texp, self.aexp, self.n_active, self.queue, self.fstack, self.changed,
                  self.off, self.cnt, self.cap, self._sent, self.counts, self._resume, self.odo,
                  self.part_hidden, self.part_texp, self.part_aexp, self._part_counts)
        return int(sum(x.nbytes for x in arrays))

    def validate(self) -> None:
        """Raise ``AssertionError`` naming the first broken invariant.

        Checks the front (every active node's ancestors are split, its
        descendants inactive), that faces are active exactly when their
        creator is split, crack-freeness (every neighbour link is mutual over
        the same edge, and no edge is shared by two faces without a link),
        non-degenerate faces, that the index buffers equal the D3Dindex
        lookup of each face's surface group at its corner positions, and
        with the strict bound that no node stands beside a position gone
        before it was made (:func:`caveclod.refine.measure.mixed_nodes`).
        """
        from .validate import validate_camera
        validate_camera(self)
