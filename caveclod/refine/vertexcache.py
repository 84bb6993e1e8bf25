"""A client's vertex cache, as the server keeps it: N slots, and which vertex each holds.

After Lario, Pajarola & Tirado, *Cached Geometry Manager for view-dependent
LOD rendering* (2004). A client in cache mode holds N vertex slots instead of
the whole vertex buffer. Each frame, the vertices that became active and are
not cached any more are written into slots, chosen by a strategy among the
slots whose vertex is inactive:

* ``fa`` (First Available): the lowest-numbered inactive slot;
* ``lru``: the slot whose vertex was deactivated longest ago (the paper's
  front-framework LRU: removed vertices' slots go just below the frontier);
* ``lru_pq``: the oldest ``pq_fraction`` of the cache (10 % by default, the
  paper's LRU+errorPQ10%) is a priority queue on the error at which the
  slot's vertex appears, and the finest-detail vertex there goes first.

The kernels are in :mod:`caveclod.kernels.vertexcache`. Plain numpy, no
gRPC: the server keeps one cache per camera (:mod:`.cachedcamera`) as the
exact mirror of the client's slots.
"""

from __future__ import annotations

import numpy as np

from ..errors import CaveclodError, InputError
from ..kernels import vertexcache as K

STRATEGIES = {"fa": K.FA, "lru": K.LRU, "lru_pq": K.LRU_PQ}
DEFAULT_STRATEGY = "lru"
DEFAULT_PQ_FRACTION = 0.1


def check_options(slots, strategy: str = DEFAULT_STRATEGY,
                  pq_fraction: float | None = None) -> tuple[int, str, float | None]:
    """``(slots, strategy, pq_fraction)`` checked; InputError names what is wrong and what to give.

    ``pq_fraction`` None means the default (0.1) for ``lru_pq``; it is
    refused with another strategy, which has no priority queue (and gets None).
    """
    if isinstance(slots, (bool, np.bool_)) or not isinstance(slots, (int, np.integer)):
        raise InputError(f"cache_vertices must be a whole number of slots, got {slots!r}")
    if slots < 1:
        raise InputError(f"cache_vertices is {slots}; give a slot count of at least the base mesh's vertices, "
                         "or no cache at all for a resident vertex buffer")
    if strategy not in STRATEGIES:
        raise InputError(f"unknown cache strategy {strategy!r}; choose one of {', '.join(STRATEGIES)}")
    if pq_fraction is None:
        pq_fraction = DEFAULT_PQ_FRACTION if strategy == "lru_pq" else None
    elif strategy != "lru_pq":
        raise InputError(f"a priority-queue fraction applies to the lru_pq strategy only, not {strategy!r}; "
                         "leave it unset or choose lru_pq")
    else:
        try:
            pq_fraction = float(pq_fraction)
        except (TypeError, ValueError):
            raise InputError(f"the priority-queue fraction must be a number in [0, 1), got {pq_fraction!r}") from None
        if not 0.0 <= pq_fraction < 1.0:
            raise InputError(f"the priority-queue fraction must be in [0, 1), got {pq_fraction}; "
                             f"the paper's is {DEFAULT_PQ_FRACTION}")
    return int(slots), strategy, pq_fraction


def vertex_keys(mesh) -> np.ndarray:
    """(d,) float32 priority-queue key of each vertex: the object-space error
    of the split that brings its position into the mesh (+inf for positions of
    the base mesh). Half-edge collapses keep the stationary child's position,
    so a position first appears when the floating child that carries it is
    split off; errors grow up the hierarchy, so a small key is fine detail.
    """
    a = mesh.arrays
    e = mesh.n_positions
    links = np.asarray(a["node_links"])
    floating = links[:, 1]
    npos = np.asarray(a["node_position"])
    pos_of_floating = np.where(floating < e, floating, npos[np.maximum(floating - e, 0)])
    by_position = np.full(e, np.inf, np.float32)
    by_position[pos_of_floating] = np.asarray(a["node_bound"])[:, 4]
    return by_position[mesh.vertex_position_ids]


class VertexCache:
    """N slots over a mesh's d vertices, cross-indexed both ways.

    Args:
        slots: N, at least 1.
        n_vertices: d, the mesh's vertex count.
        strategy: ``fa``, ``lru`` or ``lru_pq``.
        pq_fraction: share of the N slots in the priority queue (``lru_pq``).
        keys: (d,) float32 :func:`vertex_keys` (needed by ``lru_pq`` only).

    Attributes:
        slot_vertex: (N,) int32 vertex in each slot, -1 when empty.
        vertex_slot: (d,) int32 slot of each vertex, -1 when not cached.
        slot_active: (N,) uint8, 1 while the slot's vertex is active.
        inserted, hits: totals over every :meth:`update`.
    """

    def __init__(self, slots: int, n_vertices: int, strategy: str = DEFAULT_STRATEGY,
                 pq_fraction: float | None = None, keys: np.ndarray | None = None):
        slots, strategy, pq_fraction = check_options(slots, strategy, pq_fraction)
        self.n_slots, self.strategy, self.pq_fraction = slots, strategy, pq_fraction
        self._code = STRATEGIES[strategy]
        self.pq_capacity = int(pq_fraction * slots) if pq_fraction is not None else 0
        if self.pq_capacity and (keys is None or len(keys) != n_vertices):
            raise InputError(f"the lru_pq strategy needs a key per vertex ({n_vertices}); pass vertex_keys(mesh)")
        self.vertex_key = np.asarray(keys, np.float32) if keys is not None else np.zeros(n_vertices, np.float32)
        self.slot_vertex = np.full(slots, -1, np.int32)
        self.vertex_slot = np.full(n_vertices, -1, np.int32)
        self.slot_active = np.zeros(slots, np.uint8)
        self.slot_key = np.full(slots, -np.inf, np.float32)
        self.prev = np.full(slots, -1, np.int32)
        self.nxt = np.full(slots, -1, np.int32)
        self.ends = np.full(2, -1, np.int32)
        self.heap = np.empty(max(self.pq_capacity, 1), np.int32)
        self.heap_pos = np.full(slots, -1, np.int32)
        self.hsize = np.zeros(1, np.int64)
        self._relist()
        self.inserted = 0
        self.hits = 0

    def _relist(self) -> None:
        """Every inactive slot into the LRU list, lowest slot at the old end; the queue emptied."""
        self.prev[:] = -1
        self.nxt[:] = -1
        self.heap_pos[:] = -1
        self.hsize[0] = 0
        free = np.flatnonzero(self.slot_active == 0).astype(np.int32)
        if len(free):
            # Oldest first: free[0] is the tail, free[-1] the young end.
            self.nxt[free[1:]] = free[:-1]
            self.prev[free[:-1]] = free[1:]
            self.ends[K.OLD], self.ends[K.YOUNG] = free[0], free[-1]
        else:
            self.ends[:] = -1

    @property
    def n_active(self) -> int:
        """Slots whose vertex is active."""
        return int(self.slot_active.sum())

    @property
    def n_held(self) -> int:
        """Slots holding a vertex, active or not."""
        return int((self.slot_vertex >= 0).sum())

    def update(self, added: np.ndarray, removed: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """One frame: ``removed`` vertices (active, so cached) become inactive,
        ``added`` ones (inactive) active; returns ``(slots, vertices, hits)``:
        the (k,) int32 slots written, ascending, the (k,) int32 vertices now in
        them (each evicting what the slot held), and how many added vertices
        were still cached.

        Raises CaveclodError when more vertices would be active than there are
        slots (the caller fits the LOD to the cache first).
        """
        added = np.ascontiguousarray(np.sort(np.asarray(added, np.int32)))
        removed = np.ascontiguousarray(np.sort(np.asarray(removed, np.int32)))
        out_vertices = np.empty(len(added), np.int32)
        out_slots = np.empty(len(added), np.int32)
        k, hits = K.step(self._code, self.pq_capacity, self.slot_vertex, self.vertex_slot, self.slot_active,
                         self.prev, self.nxt, self.ends, self.heap, self.heap_pos, self.hsize, self.slot_key,
                         self.vertex_key, removed, added, out_vertices, out_slots)
        if k == K.FULL:
            raise CaveclodError(f"vertex cache of {self.n_slots} slots overflowed: more vertices active than slots "
                                "(the LOD must be fitted to the cache before its vertices are cached)")
        order = np.argsort(out_slots[:k], kind="stable")
        self.inserted += int(k)
        self.hits += int(hits)
        return out_slots[:k][order], out_vertices[:k][order], int(hits)

    def forget_inactive(self) -> None:
        """Empty every slot whose vertex is inactive (a keyframe: the client
        empties its slots, and gets back only the active vertices)."""
        gone = (self.slot_active == 0) & (self.slot_vertex >= 0)
        self.vertex_slot[self.slot_vertex[gone]] = -1
        self.slot_vertex[gone] = -1
        self.slot_key[self.slot_active == 0] = -np.inf
        self._relist()

    def active_slots(self) -> tuple[np.ndarray, np.ndarray]:
        """``(slots, vertices)``: (k,) int32 slots holding active vertices, ascending, and those vertices."""
        slots = np.flatnonzero(self.slot_active).astype(np.int32)
        return slots, self.slot_vertex[slots]

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.slot_vertex, self.vertex_slot, self.slot_active, self.slot_key,
                                          self.prev, self.nxt, self.ends, self.heap, self.heap_pos, self.hsize)))

    def validate(self) -> None:
        """Raise AssertionError naming the first broken invariant of the slot maps and lists."""
        held = np.flatnonzero(self.slot_vertex >= 0)
        assert (self.vertex_slot[self.slot_vertex[held]] == held).all(), "slot -> vertex -> slot is not the identity"
        cached = np.flatnonzero(self.vertex_slot >= 0)
        assert (self.slot_vertex[self.vertex_slot[cached]] == cached).all(), "vertex -> slot -> vertex is not the identity"
        assert not (self.slot_active.astype(bool) & (self.slot_vertex < 0)).any(), "an active slot holds no vertex"
        if self._code == K.FA:
            return
        listed = []
        s = int(self.ends[K.OLD])
        while s >= 0 and len(listed) <= self.n_slots:
            listed.append(s)
            s = int(self.prev[s])
        queued = self.heap[: int(self.hsize[0])].tolist()
        inactive = set(np.flatnonzero(self.slot_active == 0).tolist())
        assert len(listed) + len(queued) == len(inactive) and set(listed) | set(queued) == inactive, \
            "the LRU list and the queue do not hold exactly the inactive slots"
        assert (self.heap_pos[queued] == np.arange(len(queued))).all(), "heap positions are stale"
