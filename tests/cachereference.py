"""The vertex cache in slow, obviously correct Python: the yardstick of tests/test_vertexcache.py.

Sets and lists, no kernels, no incremental bookkeeping: the active vertices
of a frame are recomputed from the whole index buffers; the strategies'
victims are found by searching lists. The rules are those written in
caveclod.refine.vertexcache and caveclod.kernels.vertexcache:

* removed vertices' slots become inactive, in ascending vertex order
  (LRU: each becomes the youngest inactive slot);
* added vertices still cached take their slots back (hits);
* the others, in ascending vertex order, each overwrite the victim:
  FA the lowest inactive slot; LRU the slot deactivated longest ago (empty
  slots, lowest first, before any); LRU+PQ: the oldest ``int(fraction * N)``
  inactive slots form a queue, topped up from the oldest before each choice,
  and the one whose key (error, -inf when empty) is smallest goes, ties to
  the lower slot.
"""

from __future__ import annotations

import numpy as np


def active_vertices(buffers: dict) -> set:
    """The vertices any triangle of ``buffers`` {material: (k, 3)} uses."""
    out = set()
    for tris in buffers.values():
        out.update(int(v) for v in np.asarray(tris).ravel())
    return out


class ReferenceCache:
    def __init__(self, slots: int, strategy: str, pq_fraction: float = 0.1, keys=None):
        self.n, self.strategy = slots, strategy
        self.pq_cap = int(pq_fraction * slots) if strategy == "lru_pq" else 0
        self.keys = keys
        self.slot_vertex = [None] * slots          # vertex in each slot
        self.active = set()                       # active vertices
        self.order = list(range(slots))           # inactive slots, oldest first (lru, lru_pq)
        self.queue = []                           # inactive slots in the priority queue (lru_pq)

    def where(self, v):
        """The slot holding v, or None (a plain search)."""
        for s, held in enumerate(self.slot_vertex):
            if held == v:
                return s
        return None

    def _key(self, s):
        v = self.slot_vertex[s]
        return (-np.inf if v is None else float(self.keys[v]), s)

    def update(self, added, removed) -> dict:
        """{slot: vertex} written this frame."""
        for v in sorted(removed):
            assert v in self.active
            self.active.discard(v)
            self.order.append(self.where(v))           # the youngest inactive slot
        misses = []
        for v in sorted(added):
            assert v not in self.active
            s = self.where(v)
            if s is None:
                misses.append(v)
                continue
            if s in self.queue:
                self.queue.remove(s)
            elif s in self.order:
                self.order.remove(s)
            self.active.add(v)
        written = {}
        for v in misses:
            s = self._victim()
            self.slot_vertex[s] = v
            self.active.add(v)
            written[s] = v
        assert len(self.active) <= self.n
        return written

    def _victim(self):
        if self.strategy == "fa":
            return min(s for s in range(self.n) if self.slot_vertex[s] not in self.active or self.slot_vertex[s] is None)
        if self.strategy == "lru_pq":
            while len(self.queue) < self.pq_cap and self.order:
                self.queue.append(self.order.pop(0))
            if self.queue:
                best = min(self.queue, key=self._key)
                self.queue.remove(best)
                return best
        return self.order.pop(0)

    def forget_inactive(self):
        for s, v in enumerate(self.slot_vertex):
            if v is not None and v not in self.active:
                self.slot_vertex[s] = None
        self.order = [s for s in range(self.n) if self.slot_vertex[s] is None]
        self.queue = []
