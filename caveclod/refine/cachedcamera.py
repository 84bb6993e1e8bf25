"""A camera in cache mode: its LOD fitted to N vertex slots, its deltas in slot numbers.

A client in cache mode holds N vertex slots, not the vertex buffer
(Lario, Pajarola & Tirado's Cached Geometry Manager). :class:`CachedCamera`
wraps a :class:`~caveclod.refine.camera.CameraState` and turns each update
into what that client needs: the vertices to write into slots (those that
became active and are no longer cached) and the index-buffer slot writes
with slot numbers in place of vertex-buffer indices. Each update's exact
added and removed vertices (:mod:`.activevertices`) drive the cache
(:mod:`.vertexcache`), as the paper's front-framework strategies ask.

When the view asks for more vertices than there are slots, the camera is
coarsened: the tolerance is raised by :data:`RAISE` and the camera updated
again, until its vertices fit; the frame then carries the net change of
those updates. The raised tolerance is kept. An update for a new pose tries
one step lower while the vertices fill at most :data:`RELAX_FILL` of the
slots (so a camera that moves out of the crowded view comes back to its own
tolerance step by step); a try that does not fit is not repeated for
:data:`RELAX_WAIT` poses, so that a camera held at the limit does not refine
and coarsen again every frame. (Each change of tolerance makes the next
update re-evaluate every active node: fitting costs a full pass.) An update
for the same pose never relaxes, so a camera at rest converges. A cache
smaller than the base mesh's vertices is refused when the camera is made.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import CaveclodError, InputError
from .activevertices import ActiveVertices
from .camera import Delta, SurfaceDelta
from .vertexcache import DEFAULT_STRATEGY, VertexCache, check_options
from .view import view_params

RAISE = 1.25               # tolerance factor per fitting step (and per relaxing step)
RELAX_FILL = 0.8           # a raised tolerance is lowered only while the vertices fill at most this share
RELAX_WAIT = 8             # new poses before a lowering that did not fit is tried again
MIN_RAISED_PX = 0.1        # a 0 px tolerance is first raised to this
WILD_PX = 1e6              # past this, no screen tells the difference: jump to CEILING_PX
CEILING_PX = 1e30          # refines nothing: the base mesh, which fits


@dataclass
class CacheDelta:
    """What one :meth:`CachedCamera.update` changed, in the client's terms.

    Attributes:
        surfaces: {material: SurfaceDelta} index-buffer slot writes whose
            triangles are cache slot numbers (k, 3) uint32.
        slots: (k,) uint32 cache slots written, ascending.
        vertices: (k,) int32 the vertex-buffer entries written into them.
        hits: vertices that became active while still in their slot.
        added, removed: (a,), (r,) int32 the vertices that became active,
            inactive (the net change of the frame's updates), ascending.
        tolerance_px: the tolerance the camera is now refined for (above the
            view's when the cache could not hold its LOD); None in a
            keyframe whose camera is at the view's own.
        updates: CameraState updates made (more than 1 when fitting).
        delta: the same change in vertex-buffer indices (a merged
            :class:`~caveclod.refine.camera.Delta`: its operations, time and
            budget flag are those of every update made).
    """

    surfaces: dict = field(default_factory=dict)
    slots: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    hits: int = 0
    added: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    removed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    tolerance_px: float | None = None
    updates: int = 0
    delta: Delta = field(default_factory=Delta)

    @property
    def inserted(self) -> int:
        return len(self.slots)


class CachedCamera:
    """A CameraState whose client holds ``slots`` vertices, chosen by ``strategy``.

    Args:
        camera: the :class:`CameraState` (usually fresh: the base mesh).
        slots: N, the cache's slot count.
        strategy: ``fa``, ``lru`` or ``lru_pq``; pq_fraction: see
            :func:`caveclod.refine.vertexcache.check_options`.
        keys: :func:`~caveclod.refine.vertexcache.vertex_keys` of the mesh
            (computed when not given; a server computes them once per mesh).

    Raises InputError when the camera's current faces (the base mesh, for a
    fresh camera) use more vertices than ``slots``. The base mesh's vertices
    are cached at once: :meth:`keyframe` sends them.
    """

    def __init__(self, camera, slots: int, strategy: str = DEFAULT_STRATEGY, pq_fraction: float | None = None,
                 keys: np.ndarray | None = None):
        slots, strategy, pq_fraction = check_options(slots, strategy, pq_fraction)
        self.camera = camera
        self.mesh = camera.mesh
        self.active = ActiveVertices(self.mesh.n_vertices, camera.triangles())
        if self.active.count > slots:
            raise InputError(f"cache_vertices is {slots}, but the base mesh alone uses {self.active.count} vertices; "
                             f"ask for at least {self.active.count} slots (several times more keeps detail), "
                             "or no cache for a resident vertex buffer")
        if keys is None and strategy == "lru_pq":
            from .vertexcache import vertex_keys
            keys = vertex_keys(self.mesh)
        self.cache = VertexCache(slots, self.mesh.n_vertices, strategy, pq_fraction, keys)
        self.cache.update(self.active.vertices(), np.zeros(0, np.int32))
        self.tolerance: float | None = None      # raised tolerance in use; None: the view's own
        self._reach: tuple | None = None           # see _outside
        self._wait = 0                            # new poses until the next try at a lower tolerance

    @property
    def n_slots(self) -> int:
        return self.cache.n_slots

    # -- updates -----------------------------------------------------------------------
    def update(self, view, relax: bool = True) -> CacheDelta:
        """Refine for ``view`` within the cache; returns the :class:`CacheDelta`.

        ``relax``: a new pose, so try one step below a raised tolerance
        (False for an update that goes on converging for the same pose).
        """
        t0 = time.perf_counter()
        base = float(view.tolerance_px)
        t = self._start(base, relax)
        lowered = self.tolerance is not None and t < self.tolerance
        deltas, events = [], []
        cap = self.mesh.n_nodes + 64            # every fitting update but the last makes an operation
        while True:
            d = self.camera.update_params(self._params(view, t, base))
            deltas.append(d)
            events.append(self.active.apply(d))
            if self.active.count <= self.n_slots:
                break
            if t >= CEILING_PX and d.operations == 0 and not d.budget_exhausted or len(deltas) > cap:
                raise CaveclodError(f"camera could not be coarsened into {self.n_slots} slots "
                                    f"({self.active.count} vertices at {t:g} px); this is a bug")
            t = self._raise(t)
        if lowered and len(deltas) > 1:
            self._wait = RELAX_WAIT                # the lower tolerance did not fit: not again for a while
        self.tolerance = t if t > base else None
        added, removed = _net(events, self.active.refs)
        slots, vertices, hits = self.cache.update(added, removed)
        merged = deltas[0] if len(deltas) == 1 else _merge(self.camera, deltas)
        out = CacheDelta(surfaces=self._in_slots(merged), slots=slots.astype(np.uint32), vertices=vertices,
                         hits=hits, added=added, removed=removed, tolerance_px=t, updates=len(deltas),
                         delta=merged)
        merged.seconds = time.perf_counter() - t0
        return out

    def _start(self, base: float, relax: bool) -> float:
        if self.tolerance is None or self.tolerance <= base:
            return base
        if not relax:
            return self.tolerance
        if self._wait > 0 or self.active.count > RELAX_FILL * self.n_slots:
            self._wait = max(self._wait - 1, 0)
            return self.tolerance
        if self.tolerance >= CEILING_PX:
            return WILD_PX
        lower = self.tolerance / RAISE
        return base if lower <= max(base, MIN_RAISED_PX) else lower

    def _params(self, view, t: float, base: float) -> np.ndarray:
        """The kernels' parameters of ``view`` at tolerance ``t``; at the ceiling, of a view in which
        no node needs detail: the base mesh, which fits.

        A tolerance alone cannot promise that: the kernels refine a node whose bounding sphere
        holds the eye at any tolerance (a camera close to the surface), and a narrow field of view
        multiplies errors past any tolerance. A view from outside every node's bounding sphere,
        turned away from the mesh, with culling on, leaves every node outside its frustum.
        """
        if t < CEILING_PX:
            return (view if t == base else dataclasses.replace(view, tolerance_px=t)).params()
        centre, reach = self._outside()
        f = np.subtract(view.target, view.eye)
        f /= np.abs(f).max()                     # a direction: its norm cannot overflow
        f /= np.linalg.norm(f)
        eye = centre - f * (2.0 * reach + 1.0)
        away = eye - f * (reach + 1.0)          # far enough from the eye to differ at any extent (1 ulp of 1e16 is 2)
        # No part hidden here: at this tolerance every part projects smaller, and a camera drew
        # nothing at all (a sweep: 200 slots for a mesh whose base uses 30, an empty view for
        # 300 poses) where the base mesh, which fits, is what the ceiling promises.
        return view_params(tuple(map(float, eye)), tuple(map(float, away)), view.up, view.fov_y, view.width,
                           view.height, t, True, False, False)

    def _outside(self) -> tuple[np.ndarray, float]:
        """(centre of the mesh's box, R): every node's bounding sphere, and its ring test's,
        lies within R of the centre."""
        if self._reach is None:
            lo, hi = self.mesh.bounds()
            centre = 0.5 * (lo + hi)
            bound = np.asarray(self.mesh.arrays["node_bound"], dtype=np.float64)
            radius = bound[:, 3]
            ring = self.mesh.arrays.get("node_ring")
            if ring is not None and len(ring):             # the ring test's sphere is larger by its reach
                ring = np.asarray(ring, dtype=np.float64)
                radius = radius + np.where(ring[:, 1] > 0.0, ring[:, 0], 0.0)
            reach = float((np.linalg.norm(bound[:, :3] - centre, axis=1) + radius).max(initial=0.0))
            self._reach = (centre, reach)
        return self._reach

    @staticmethod
    def _raise(t: float) -> float:
        t = max(t * RAISE, MIN_RAISED_PX)
        return CEILING_PX if t > WILD_PX else t

    def _in_slots(self, delta: Delta) -> dict:
        """The delta's surfaces with slot numbers for vertex-buffer indices."""
        vs = self.cache.vertex_slot
        return {m: SurfaceDelta(d.slots, vs[d.tris].astype(np.uint32), d.count) for m, d in delta.surfaces.items()}

    def keyframe(self) -> CacheDelta:
        """Everything a client that emptied its slots needs: the active
        vertices in their slots, and every material's whole index buffer (in
        slot numbers). Inactive slots are forgotten, as the client forgets
        them (the strategy starts them over as empty slots)."""
        self.cache.forget_inactive()
        slots, vertices = self.cache.active_slots()
        base = self.camera.keyframe()
        surfaces = {m: SurfaceDelta(d.slots, self.cache.vertex_slot[d.tris].astype(np.uint32), d.count)
                    for m, d in base.surfaces.items()}
        return CacheDelta(surfaces=surfaces, slots=slots.astype(np.uint32), vertices=vertices,
                          tolerance_px=self.tolerance, delta=base)

    def reorder_for_vertex_cache(self, material: int) -> None:
        """Put one material's index buffer in vertex-cache order, the copy of it kept for
        reference counts following (see :meth:`CameraState.reorder_for_vertex_cache`)."""
        order = self.camera.reorder_for_vertex_cache(material)
        if order is not None:
            self.active.reorder(material, order)

    # -- views of the state ------------------------------------------------------------
    def slot_buffer(self, material: int) -> np.ndarray:
        """(count, 3) uint32: the client's index buffer of ``material`` (slot numbers)."""
        return self.cache.vertex_slot[self.camera.index_buffer(material)].astype(np.uint32)

    def slot_triangles(self) -> dict:
        """{material: (k, 3) uint32} every non-empty index buffer, in slot numbers."""
        return {m: self.cache.vertex_slot[t].astype(np.uint32) for m, t in self.camera.triangles().items()}

    @property
    def nbytes(self) -> int:
        """Bytes this camera owns beyond its CameraState: reference counts,
        the index-buffer copy and the cache's maps (the mesh is shared)."""
        return self.active.nbytes + self.cache.nbytes


def _net(events: list, refs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Net (added, removed) vertices over several updates' (added, removed) pairs.

    A vertex's events alternate (added, removed, added, ...); its first one
    says whether it was active before the first update, ``refs`` whether it
    is after the last.
    """
    if len(events) == 1:
        return events[0]
    ids = np.concatenate([a for pair in events for a in pair])
    kind = np.concatenate([np.full(len(a), is_added, bool) for pair in events
                           for a, is_added in zip(pair, (True, False))])
    ids_u, first = np.unique(ids, return_index=True)
    was = ~kind[first]                         # first event a removal: it was active
    now = refs[ids_u] > 0
    return ids_u[~was & now].astype(np.int32), ids_u[was & ~now].astype(np.int32)


def _merge(camera, deltas: list) -> Delta:
    """One Delta equal to applying ``deltas`` in turn (the frame's net change).

    Every slot any of them wrote, below the final count, holds its final
    triangle; each delta wrote all of [its old count, its count), so the
    union covers the growth of the whole sequence.
    """
    out = Delta()
    materials = sorted({m for d in deltas for m in d.surfaces})
    for m in materials:
        count = int(camera.cnt[m])
        written = np.zeros(count, bool)             # a mask, not a sort: deltas can write whole buffers
        for d in deltas:
            if m in d.surfaces:
                slots = np.asarray(d.surfaces[m].slots, np.int64)
                written[slots[slots < count]] = True
        slots = np.flatnonzero(written).astype(np.uint32)
        out.surfaces[m] = SurfaceDelta(slots, camera.index_buffer(m)[slots].copy(), count)
    out.splits = sum(d.splits for d in deltas)
    out.collapses = sum(d.collapses for d in deltas)
    out.parts_shown = sum(d.parts_shown for d in deltas)
    out.parts_hidden = sum(d.parts_hidden for d in deltas)
    out.budget_exhausted = deltas[-1].budget_exhausted
    out.tested = sum(d.tested for d in deltas)
    return out
