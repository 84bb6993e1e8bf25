"""Reference counts of the vertices an index buffer uses, updated by slot writes.

The kernel behind :class:`caveclod.refine.activevertices.ActiveVertices`:
one pass over a delta's rows (the overwritten, the cut off, the written),
touching only the vertices they name; each vertex's count before the first
touch is kept, so that the caller can tell which vertices came and went
without sorting or scanning the mesh.
"""

import numba as nb


@nb.njit(cache=True, nogil=True, inline="always")
def _touch(v, refs, mark, touched, before, n):
    if mark[v] == 0:
        mark[v] = 1
        touched[n] = v
        before[n] = refs[v]
        return n + 1
    return n


@nb.njit(cache=True, nogil=True)
def apply_writes(refs, mark, rows, old, new, slots, tris, touched, before, n):
    """Apply one buffer's slot writes to ``rows`` and the counts; returns the new touch count.

    Args:
        refs: (d,) int32 counts. mark: (d,) uint8 scratch, 0 outside a delta.
        rows: (cap, 3) uint32 this copy of the buffer, cap >= ``new``.
        old, new: the buffer's count before and after.
        slots: (k,) slots written (all < new); tris: (k, 3) their triangles.
        touched, before: out: vertices touched in this delta (from ``n`` on)
            and their counts before it.
    """
    for i in range(len(slots)):            # rows overwritten lose their corners ...
        s = slots[i]
        if s < old:
            for j in range(3):
                v = rows[s, j]
                n = _touch(v, refs, mark, touched, before, n)
                refs[v] -= 1
    for s in range(new, old):              # ... and so do rows cut off the end
        for j in range(3):
            v = rows[s, j]
            n = _touch(v, refs, mark, touched, before, n)
            refs[v] -= 1
    for i in range(len(slots)):            # written rows gain theirs
        s = slots[i]
        for j in range(3):
            v = tris[i, j]
            n = _touch(v, refs, mark, touched, before, n)
            refs[v] += 1
            rows[s, j] = v
    return n


@nb.njit(cache=True, nogil=True)
def classify(refs, mark, touched, before, n, added, removed):
    """Split the ``n`` touched vertices into added (count 0 -> above) and
    removed (above -> 0); clears their marks. Returns (n_added, n_removed)."""
    a = 0
    r = 0
    for i in range(n):
        v = touched[i]
        mark[v] = 0
        if before[i] == 0 and refs[v] > 0:
            added[a] = v
            a += 1
        elif before[i] > 0 and refs[v] == 0:
            removed[r] = v
            r += 1
    return a, r
