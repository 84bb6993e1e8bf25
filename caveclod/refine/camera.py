"""One camera's refinement state over a shared static mesh (paper 3.4).

Holds only camera-specific data; see :mod:`caveclod.kernels.refine` for the
layout. ``update`` runs the compiled kernel, which releases the GIL, so
cameras updated from different threads refine truly in parallel.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import CaveclodError, InputError
from ..kernels import refine as K
from .view import View

UNLIMITED = np.iinfo(np.int64).max


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
    """

    surfaces: dict = field(default_factory=dict)
    splits: int = 0
    collapses: int = 0
    seconds: float = 0.0
    budget_exhausted: bool = False

    @property
    def operations(self) -> int:
        return self.splits + self.collapses

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


def _empty_index(faces: int) -> np.ndarray:
    """An empty face -> record hash table with room for about ``faces``."""
    size = 64
    while size < 4 * faces:
        size *= 2
    return np.full((size, 2), -1, np.int32)


class CameraState:
    """Active nodes and faces of one camera, refined incrementally.

    ``mesh.new_camera()`` makes one showing the base mesh. Options:
    ``max_ops`` (operations per update) and ``max_faces`` (active faces)
    bound the work and size of an update; both default to unlimited.
    """

    def __init__(self, mesh, max_ops: int | None = None, max_faces: int | None = None):
        self.mesh = mesh
        self.max_ops = UNLIMITED if max_ops is None else int(max_ops)
        self.max_faces = UNLIMITED if max_faces is None else int(max_faces)
        a = {k: np.asarray(v) for k, v in mesh.arrays.items()}   # plain views of the maps
        self._static = (
            mesh.n_positions, a["node_parent"], a["node_links"], a["node_position"],
            a["node_bound"], a["node_cone"], a["face_creator"],
            a["face_material"], a["face_sgid"], a["pos_vstart"], a["vertex_sgid"],
        )
        self._e = mesh.n_positions
        n, p = mesh.n_nodes, mesh.n_faces
        self.n_materials = max(mesh.n_materials, int(a["face_material"].max(initial=0)) + 1)
        self.state = np.zeros(n, np.uint8)
        self.face_rec = _empty_index(len(mesh.arrays["base_faces"]))
        base = a["base_faces"]
        base_count = np.bincount(a["face_material"][base], minlength=self.n_materials)
        self.cnt = np.zeros(self.n_materials, np.int64)
        self._layout(np.maximum(base_count + base_count // 2, 64))
        self._sent = np.zeros(self.n_materials, np.int64)   # buffer lengths the last delta announced
        self._add_base(a)
        self.counts = np.zeros(2, np.int64)
        self._resume = np.zeros(3, np.int64)      # where an interrupted pass goes on

    # -- set-up -------------------------------------------------------------
    def _layout(self, capacity: np.ndarray, old: dict | None = None) -> None:
        """(Re)allocate the record pool with ``capacity`` per material."""
        self.cap = capacity.astype(np.int64)
        self.off = np.zeros(self.n_materials, np.int64)
        np.cumsum(self.cap[:-1], out=self.off[1:])
        total = int(self.cap.sum())
        new = {
            "rec_pos": np.zeros((total, 3), np.int32),
            "rec_nbr": np.full((total, 3), -1, np.int32),
            "rec_face": np.full(total, -1, np.int32),
            "rec_tri": np.zeros((total, 3), np.uint32),
            "rec_dirty": np.zeros(total, np.uint8),
        }
        if old is not None:
            for s in range(self.n_materials):
                c = int(self.cnt[s])
                src = slice(int(old["off"][s]), int(old["off"][s]) + c)
                dst = slice(int(self.off[s]), int(self.off[s]) + c)
                for k in new:
                    new[k][dst] = old[k][src]
        for k, v in new.items():
            setattr(self, k, v)
        if old is not None:
            self._reindex(len(self.face_rec))      # records moved

    def _grow_records(self, material: int) -> None:
        old = {k: getattr(self, k) for k in ("rec_pos", "rec_nbr", "rec_face", "rec_tri", "rec_dirty")}
        old["off"] = self.off
        cap = self.cap.copy()
        # Grow by half: a camera's bytes are what adding a camera costs, so
        # slack is kept small; re-layout is O(active faces) and rare.
        cap[material] = max(cap[material] + cap[material] // 2, 64)
        self._layout(cap, old)

    def _reindex(self, size: int) -> None:
        """Rebuild the face -> record hash table with ``size`` slots."""
        self.face_rec = np.full((size, 2), -1, np.int32)
        K.index_records(self.off, self.cnt, self.rec_face, self.face_rec)

    def _grow_list(self) -> None:
        bigger = np.empty(max(len(self.active) + len(self.active) // 2, 64), np.int32)
        bigger[: self.n_active[0]] = self.active[: self.n_active[0]]
        self.active = bigger

    def _add_base(self, a: dict) -> None:
        roots = np.flatnonzero(a["node_parent"] < 0).astype(np.int32)
        self.state[roots] = K.ACTIVE | K.IN_LIST
        self.active = np.empty(max(len(roots) + len(roots) // 2, 64), np.int32)
        self.active[: len(roots)] = roots
        self.n_active = np.array([len(roots)], np.int64)
        faces = a["base_faces"]
        pos = self.mesh.node_positions(a["base_face_nodes"].ravel()).reshape(-1, 3)
        mat = a["face_material"][faces]
        for f, corners, nbrs, s in zip(faces, pos, a["base_face_nbrs"], mat):
            r = int(self.off[s] + self.cnt[s])
            self.cnt[s] += 1
            self.rec_face[r] = f
            self.rec_pos[r] = corners
            self.rec_nbr[r] = nbrs
            self.rec_dirty[r] = 1
        self.rec_tri[:] = 0
        K.index_records(self.off, self.cnt, self.rec_face, self.face_rec)
        for s in range(self.n_materials):
            sl = slice(int(self.off[s]), int(self.off[s] + self.cnt[s]))
            if self.cnt[s]:
                self.rec_tri[sl] = self.mesh.lookup_vertices(
                    np.repeat(a["face_sgid"][self.rec_face[sl]], 3), self.rec_pos[sl].ravel()).reshape(-1, 3)

    # -- refinement -----------------------------------------------------------
    def update(self, view: View) -> Delta:
        """Refine incrementally for ``view``; returns the index-buffer delta."""
        if not isinstance(view, View):
            raise InputError(f"update() takes a caveclod.View, got {type(view).__name__}")
        t0 = time.perf_counter()
        vp = view.params()
        if not np.isfinite(vp).all():     # a View built around its own checks
            raise InputError("the view has NaN or infinite numbers; send a finite pose")
        self.counts[:] = 0
        if self.max_ops == UNLIMITED and self.max_faces == UNLIMITED:
            self._pass(vp, K.MIXED)
        else:
            # Under a budget a forced split may stop half-way; refining first
            # and coarsening with what is left keeps the next update from
            # collapsing the half-made dependencies again (no oscillation).
            self._pass(vp, K.SPLITS_ONLY)
            if self.counts.sum() < self.max_ops:
                self._pass(vp, K.COLLAPSES_ONLY)
        delta = self._collect_delta()
        delta.splits, delta.collapses = int(self.counts[0]), int(self.counts[1])
        delta.budget_exhausted = bool(self.counts.sum() >= self.max_ops or
                                      (self.max_faces != UNLIMITED and self.n_faces + 2 > self.max_faces))
        delta.seconds = time.perf_counter() - t0
        return delta

    def _pass(self, vp: np.ndarray, mode: int) -> None:
        """Run one refinement pass to its end, growing arrays when asked."""
        try:
            while True:
                status, material = K.adapt(*self._static, self.state, self.face_rec, self.off, self.cnt,
                                           self.cap, self.rec_pos, self.rec_nbr, self.rec_face, self.rec_tri,
                                           self.rec_dirty, self.active, self.n_active, vp, self.max_ops,
                                           self.max_faces, self.counts, self._resume, mode)
                if status == K.OK:
                    return
                if status == K.NEED_RECORDS:
                    self._grow_records(int(material))
                elif status == K.NEED_LIST:
                    self._grow_list()
                elif status == K.NEED_INDEX:
                    self._reindex(2 * len(self.face_rec))
                else:  # pragma: no cover - the kernel has no other status
                    raise CaveclodError(f"refinement kernel returned status {status}")
        finally:
            if self._resume[2]:
                self._abandon_pass()

    def _abandon_pass(self) -> None:
        """Close an interrupted pass (growth failed): keep the listed nodes.

        Entries before the write position were kept, those from the read
        position on were not reached; what lies between is stale.
        """
        i, w, _ = self._resume
        n = self.n_active[0]
        self.active[w: w + n - i] = self.active[i:n].copy()
        self.n_active[0] = w + n - i
        self._resume[:] = 0

    def _collect_delta(self) -> Delta:
        total = int(self.cnt.sum())
        mats = np.empty(total, np.int32)
        slots = np.empty(total, np.uint32)
        tris = np.empty((total, 3), np.uint32)
        k = K.collect_writes(self.off, self.cnt, self.rec_tri, self.rec_dirty, mats, slots, tris)
        mats, slots, tris = mats[:k], slots[:k], tris[:k]
        delta = Delta()
        changed = set(np.unique(mats).tolist()) | set(np.flatnonzero(self.cnt != self._sent).tolist())
        for s in sorted(changed):
            pick = mats == s
            delta.surfaces[int(s)] = SurfaceDelta(slots[pick], tris[pick], int(self.cnt[s]))
        self._sent[:] = self.cnt
        return delta

    def keyframe(self) -> Delta:
        """A delta that rebuilds every buffer from nothing (for a new client)."""
        delta = Delta()
        for s, tri in self.triangles().items():
            delta.surfaces[s] = SurfaceDelta(np.arange(len(tri), dtype=np.uint32), tri.copy(), len(tri))
        return delta

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
        return np.flatnonzero((self.state & K.STATE_MASK) == K.ACTIVE).astype(np.int32)

    @property
    def n_faces(self) -> int:
        return int(self.cnt.sum())

    @property
    def nbytes(self) -> int:
        """Bytes this camera owns (the static mesh is shared, not counted)."""
        arrays = (self.state, self.face_rec, self.rec_pos, self.rec_nbr, self.rec_face, self.rec_tri,
                  self.rec_dirty, self.active, self.n_active, self.off, self.cnt, self.cap, self._sent,
                  self.counts, self._resume)
        return int(sum(x.nbytes for x in arrays))

    def validate(self) -> None:
        """Raise ``AssertionError`` naming the first broken invariant.

        Checks the front (every active node's ancestors are split, its
        descendants inactive), that faces are active exactly when their
        creator is split, crack-freeness (every neighbour link is mutual over
        the same edge, and no edge is shared by two faces without a link),
        non-degenerate faces, and that the index buffers equal the D3Dindex
        lookup of each face's surface group at its corner positions.
        """
        from .validate import validate_camera
        validate_camera(self)
