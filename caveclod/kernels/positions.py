"""The position of each vertex: the inverse of the static mesh's CSR ``pos_vstart``.

Every camera's kernels read it (``vpos``: a corner's position is
``vpos[vertex]``), so a process derives it once per mesh. One pass that
writes each entry once: ``np.repeat(np.arange(e), np.diff(pos_vstart))``
made three arrays of the vertex count's size and took 1.35 s at 16.8M
vertices, the largest part of a large mesh's first camera.
"""

import numba as nb


@nb.njit(cache=True, nogil=True)
def fill_vertex_positions(pos_vstart, out):
    """Write into ``out`` (d,) int32 the position x of each vertex v, pos_vstart[x] <= v < pos_vstart[x + 1],
    for ``pos_vstart`` (e + 1,). Entries outside ``out`` are skipped, never written (the CSR of an
    unchecked file may be anything)."""
    d = len(out)
    for x in range(len(pos_vstart) - 1):
        for v in range(max(pos_vstart[x], 0), min(pos_vstart[x + 1], d)):
            out[v] = x
