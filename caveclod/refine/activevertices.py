"""Which vertices a camera's active faces use, and which each delta adds and removes.

A :class:`~caveclod.refine.camera.Delta` says which index-buffer slots an
update rewrote, not which vertices came and went: a vertex-buffer entry (a
surface group at a position) is used by every active face of its group
around the position, so one split can add a vertex, or only re-point faces
between vertices already in use. :class:`ActiveVertices` keeps a reference
count per vertex (how many active face corners use it) and its own copy of
the index buffers, so that a delta's overwritten and truncated rows are
known; a vertex whose count leaves or reaches 0 was added or removed. The
cost is that of the delta (numpy over the rows it writes), not of the mesh.
"""

from __future__ import annotations

import numpy as np


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

    def apply(self, delta) -> tuple[np.ndarray, np.ndarray]:
        """Take one delta's slot writes; returns ``(added, removed)``: (k,)
        int32 vertices whose count went from 0 to above, and from above to 0,
        each ascending.

        ``delta.surfaces`` is {material: SurfaceDelta(slots, tris, count)},
        as :meth:`CameraState.update` returns it.
        """
        gone, came = [], []
        for m, d in delta.surfaces.items():
            rows, old, new = self._rows.get(m), self._count.get(m, 0), int(d.count)
            if rows is None:
                rows = self._rows[m] = np.zeros((0, 3), np.uint32)
            slots = np.asarray(d.slots, np.int64)
            # Rows overwritten (slots below the old count) and rows cut off
            # by a shorter buffer lose their corners; written rows gain theirs.
            gone.append(rows[slots[slots < old]].ravel())
            if new < old:
                gone.append(rows[new:old].ravel())
            came.append(np.asarray(d.tris, np.uint32).ravel())
            if new > len(rows):
                grown = np.zeros((max(new, len(rows) + len(rows) // 4 + 16), 3), np.uint32)
                grown[:old] = rows[:old]
                self._rows[m] = rows = grown
            rows[slots] = d.tris
            self._count[m] = new
        if not came:
            return np.zeros(0, np.int32), np.zeros(0, np.int32)
        gone = np.concatenate(gone)
        came = np.concatenate(came)
        touched = np.unique(np.concatenate([gone, came]))
        before = self.refs[touched]
        np.subtract.at(self.refs, gone, 1)
        np.add.at(self.refs, came, 1)
        after = self.refs[touched]
        added = touched[(before == 0) & (after > 0)].astype(np.int32)
        removed = touched[(before > 0) & (after == 0)].astype(np.int32)
        self.count += len(added) - len(removed)
        return added, removed

    @property
    def nbytes(self) -> int:
        return int(self.refs.nbytes + sum(r.nbytes for r in self._rows.values()))
