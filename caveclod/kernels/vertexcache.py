"""Victim choice of a vertex cache: First-Available, LRU, LRU + error priority queue.

After Lario, Pajarola & Tirado, *Cached Geometry Manager for view-dependent
LOD rendering* (2004), sections 3.2 and 3.3 ("front frameworks": the LOD
reports exactly which vertices each frame adds and removes). A cache of N
slots holds vertex-buffer entries; what a strategy decides is which slot a
new vertex overwrites. Only slots whose vertex is *inactive* (used by no
active face) may be overwritten; an active vertex keeps its slot.

State, all plain arrays (see :class:`caveclod.refine.vertexcache.VertexCache`):

* ``slot_vertex`` (N,) int32: the vertex in each slot, -1 when empty;
  ``vertex_slot`` (d,) int32: the slot of each vertex, -1 when not cached
  (the paper's cross-indexing, both ways);
* ``slot_active`` (N,) uint8: 1 while the slot's vertex is active;
* the LRU list of inactive slots, doubly linked through ``prev``/``nxt``
  (N,) int32 with ``ends[YOUNG]``/``ends[OLD]`` (-1: empty list). The paper's
  front-framework LRU keeps one list with a *frontier* between active and
  inactive slots; the order of the active part never decides anything, so
  only the inactive part is kept: a removed vertex's slot goes in at the
  young end (just below the frontier), a victim comes from the old end (the
  tail), a hit leaves the list wherever it is;
* LRU + PQ: a binary min-heap ``heap`` (P,) int32 of slots, with
  ``heap_pos`` (N,) int32 (-1: not in the heap) and ``hsize`` (1,) int64,
  ordered by (``slot_key``, slot): the key is the object-space error at
  which the slot's vertex appears (small: fine detail, evicted first; -inf:
  an empty slot). The heap is the oldest section of the LRU list: before
  each victim choice it is refilled from the tail up to its capacity P.

FA needs no list: its victim is the lowest-numbered inactive slot (the
paper's scan "from the beginning to the first non-used slot"; within a
frame the scan goes on from where it stopped, which finds the same slot,
since every slot before it was just filled).
"""

import numba as nb
import numpy as np

FA, LRU, LRU_PQ = 0, 1, 2
YOUNG, OLD = 0, 1
FULL = -1            # step(): no inactive slot left for a new vertex


# -- the LRU list of inactive slots ------------------------------------------------

@nb.njit(cache=True, nogil=True, inline="always")
def _push_young(s, prev, nxt, ends):
    prev[s] = -1
    nxt[s] = ends[YOUNG]
    if ends[YOUNG] >= 0:
        prev[ends[YOUNG]] = s
    else:
        ends[OLD] = s
    ends[YOUNG] = s


@nb.njit(cache=True, nogil=True, inline="always")
def _unlink(s, prev, nxt, ends):
    p, n = prev[s], nxt[s]
    if p >= 0:
        nxt[p] = n
    else:
        ends[YOUNG] = n
    if n >= 0:
        prev[n] = p
    else:
        ends[OLD] = p
    prev[s] = -1
    nxt[s] = -1


# -- the error priority queue (an indexed binary min-heap of slots) ----------------

@nb.njit(cache=True, nogil=True, inline="always")
def _less(a, b, slot_key):
    ka, kb = slot_key[a], slot_key[b]
    return ka < kb or (ka == kb and a < b)


@nb.njit(cache=True, nogil=True)
def _sift_up(i, heap, heap_pos, slot_key):
    s = heap[i]
    while i > 0:
        parent = (i - 1) >> 1
        if not _less(s, heap[parent], slot_key):
            break
        heap[i] = heap[parent]
        heap_pos[heap[i]] = i
        i = parent
    heap[i] = s
    heap_pos[s] = i


@nb.njit(cache=True, nogil=True)
def _sift_down(i, heap, heap_pos, hsize, slot_key):
    n = hsize[0]
    s = heap[i]
    while True:
        c = 2 * i + 1
        if c >= n:
            break
        if c + 1 < n and _less(heap[c + 1], heap[c], slot_key):
            c += 1
        if not _less(heap[c], s, slot_key):
            break
        heap[i] = heap[c]
        heap_pos[heap[i]] = i
        i = c
    heap[i] = s
    heap_pos[s] = i


@nb.njit(cache=True, nogil=True)
def _heap_push(s, heap, heap_pos, hsize, slot_key):
    i = hsize[0]
    hsize[0] += 1
    heap[i] = s
    heap_pos[s] = i
    _sift_up(i, heap, heap_pos, slot_key)


@nb.njit(cache=True, nogil=True)
def _heap_remove(s, heap, heap_pos, hsize, slot_key):
    i = heap_pos[s]
    heap_pos[s] = -1
    hsize[0] -= 1
    last = heap[hsize[0]]
    if i == hsize[0]:
        return
    heap[i] = last
    heap_pos[last] = i
    # The moved slot may belong above or below its new place.
    if i > 0 and _less(last, heap[(i - 1) >> 1], slot_key):
        _sift_up(i, heap, heap_pos, slot_key)
    else:
        _sift_down(i, heap, heap_pos, hsize, slot_key)


# -- one frame ------------------------------------------------------------------------

@nb.njit(cache=True, nogil=True)
def _victim(strategy, cursor, slot_active, prev, nxt, ends, heap, heap_pos, hsize, pq_cap, slot_key):
    """The slot a new vertex overwrites, or -1 when every slot is active."""
    if strategy == FA:
        s = cursor[0]
        n = len(slot_active)
        while s < n and slot_active[s]:
            s += 1
        cursor[0] = s
        return s if s < n else -1
    if strategy == LRU_PQ:
        # The oldest section of the list tops up the queue first.
        while hsize[0] < pq_cap and ends[OLD] >= 0:
            t = ends[OLD]
            _unlink(t, prev, nxt, ends)
            _heap_push(t, heap, heap_pos, hsize, slot_key)
        if hsize[0] > 0:
            s = heap[0]
            _heap_remove(s, heap, heap_pos, hsize, slot_key)
            return s
    s = ends[OLD]
    if s >= 0:
        _unlink(s, prev, nxt, ends)
    return s


@nb.njit(cache=True, nogil=True)
def step(strategy, pq_cap, slot_vertex, vertex_slot, slot_active, prev, nxt, ends, heap, heap_pos, hsize,
         slot_key, vertex_key, removed, added, out_vertices, out_slots):
    """Apply one frame's vertex changes; returns (inserted, hits) or (FULL, hits).

    ``removed`` (r,) and ``added`` (a,) are vertex ids, each sorted: the
    vertices the frame deactivates (every one active and cached) and
    activates (none active). In order: removed slots become inactive (LRU:
    pushed young, in the order given); added vertices still cached are hits
    and take their slots back; the others are misses, each written to the
    strategy's victim slot, in the order given, evicting what it held.
    ``out_vertices[:k]``, ``out_slots[:k]`` receive the k misses and their
    slots (both need room for ``a``).
    """
    for i in range(len(removed)):
        s = vertex_slot[removed[i]]
        slot_active[s] = 0
        if strategy != FA:
            _push_young(s, prev, nxt, ends)
    hits = 0
    k = 0
    for i in range(len(added)):
        v = added[i]
        s = vertex_slot[v]
        if s >= 0:
            if strategy != FA:
                if heap_pos[s] >= 0:
                    _heap_remove(s, heap, heap_pos, hsize, slot_key)
                else:
                    _unlink(s, prev, nxt, ends)
            slot_active[s] = 1
            hits += 1
        else:
            out_vertices[k] = v
            k += 1
    cursor = np.zeros(1, np.int64)
    for i in range(k):
        v = out_vertices[i]
        s = _victim(strategy, cursor, slot_active, prev, nxt, ends, heap, heap_pos, hsize, pq_cap, slot_key)
        if s < 0:
            return FULL, hits
        old = slot_vertex[s]
        if old >= 0:
            vertex_slot[old] = -1
        slot_vertex[s] = v
        vertex_slot[v] = s
        slot_active[s] = 1
        slot_key[s] = vertex_key[v]
        out_slots[i] = s
    return k, hits
