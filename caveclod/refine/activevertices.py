"""Which vertices a camera's active faces use, and which each delta adds and removes.

A :class:`~caveclod.refine.camera.Delta` says which index-buffer slots an
update rewrote, not which vertices came and went: a vertex-buffer entry (a
surface group at a position) is used by every active face of its group
around the position, so one split can add a vertex, or only re-point faces
between vertices already in use. :class:`ActiveVertices` keeps a reference
count per vertex (how many active face corners use it) and its own copy of
the index buffers, so that a delta's overwritten and truncated rows are
known; a vertex whose count leaves or reaches 0 was added or removed. The
cost is that of the delta (one compiled pass over the rows it touches,
:mod:`caveclod.kernels.refcount`), not of the mesh.
"""

from __future__ import annotations

import numpy as np

from ..kernels import refcount as R


class ActiveVertices:
    """Reference counts of the vertices used by a camera's index buffers.

    Args:
        n_vertices: d, the mesh's vertex count.
        buffers: {material: (k, 3) uint32} the camera's index buffers now
            (``CameraState.triangles()``).

    Attributes:
        refs: (d,) int32 active face corners using each vertex.
        count: vertices with a count above 0.
    """

    def __init__(self, n_vertices: int, buffers: dict):
        self.refs = np.zeros(n_vertices, np.int32)
        self._mark = np.zeros(n_vertices, np.uint8)        # scratch of the kernel: vertices touched by a delta
        self._rows: dict[int, np.ndarray] = {}
        self._count: dict[int, int] = {}
        for m, tris in buffers.items():
            self._rows[m] = np.array(tris, np.uint32).reshape(-1, 3)
            self._count[m] = len(tris)
            np.add.at(self.refs, self._rows[m].ravel(), 1)
        self.count = int(np.count_nonzero(self.refs))

    def vertices(self) -> np.ndarray:
        """(k,) int32 the active vertices, ascending."""
        return np.flatnonzero(self.refs).astype(np.int32)

    def buffer(self, material: int) -> np.ndarray:
        """(count, 3) uint32 view of this copy of one index buffer."""
        return self._rows.get(material, np.zeros((0, 3), np.uint32))[: self._count.get(material, 0)]

    def reorder(self, material: int, order: np.ndarray) -> None:
        """Follow a reorder of one buffer's slots: slot j now holds what slot ``order[j]`` held
        (:meth:`CameraState.reorder_for_vertex_cache`); the counts do not change."""
        rows = self._rows[material]
        n = self._count[material]
        rows[:n] = rows[:n][order]

    def apply(self, delta) -> tuple[np.ndarray, np.ndarray]:
        """Take one delta's slot writes; returns ``(added, removed)``: (k,)
        int32 vertices whose count went from 0 to above, and from above to 0,
        each ascending.

        ``delta.surfaces`` is {material: SurfaceDelta(slots, tris, count)},
        as :meth:`CameraState.update` returns it.
        """
        surfaces = delta.surfaces
        if not surfaces:
            return np.zeros(0, np.int32), np.zeros(0, np.int32)
        # Every vertex a delta touches has a corner in a row it overwrites,
        # cuts off or writes: room for all of them.
        room = sum(3 * (2 * len(d.slots) + max(self._count.get(m, 0) - int(d.count), 0))
                   for m, d in surfaces.items())
        touched = np.empty(room, np.int32)
        before = np.empty(room, np.int32)
        n = 0
        for m, d in surfaces.items():
            rows, old, new = self._rows.get(m), self._count.get(m, 0), int(d.count)
            if rows is None or new > len(rows):
                grown = np.zeros((max(new, 0 if rows is None else len(rows) + len(rows) // 4 + 16), 3), np.uint32)
                if rows is not None:
                    grown[:old] = rows[:old]
                self._rows[m] = rows = grown
            n = R.apply_writes(self.refs, self._mark, rows, old, new, np.asarray(d.slots, np.int64),
                               np.asarray(d.tris, np.uint32), touched, before, n)
            self._count[m] = new
        added = np.empty(n, np.int32)
        removed = np.empty(n, np.int32)
        a, r = R.classify(self.refs, self._mark, touched, before, n, added, removed)
        self.count += a - r
        return np.sort(added[:a]), np.sort(removed[:r])

    @property
    def nbytes(self) -> int:
        return int(self.refs.nbytes + self._mark.nbytes + sum(r.nbytes for r in self._rows.values()))
