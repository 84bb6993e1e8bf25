"""What one camera's client holds, kept by the server to write op streams against.

FRAME_ENCODING_OPS (and OPS_LINKED) describes a delta by reference to the buffer the client
holds before it (a COPY of a triangle at another slot, a CORNER re-pointed
in place), so the server keeps that buffer: 12 bytes per active triangle of
the camera, only in sessions that asked for op streams. It is updated by the
same compiled call that writes the stream
(:func:`caveclod.kernels.opstream.encode_and_apply`), so it is always the
buffer the frames sent so far produce; the index buffers' CRCs check it.
"""

from __future__ import annotations

import numpy as np

from ..kernels import opstream as K


class HeldBuffers:
    """The (count, 3) uint32 index buffers of one camera's client, one per material.

    ``links``: None for FRAME_ENCODING_OPS streams, or (targets, ranks) of
    :attr:`caveclod.server.meshes.ServedMesh.op_links` for OPS_LINKED ones.
    """

    def __init__(self, materials: int, links: tuple | None = None):
        self.rows = [np.zeros((0, 3), np.uint32) for _ in range(materials)]
        self.count = np.zeros(materials, np.int64)
        self.links = links
        self._out = np.empty(256, np.uint8)

    def encode(self, material: int, count: int, slots: np.ndarray, tris: np.ndarray) -> bytes:
        """The op stream of writing ``tris`` (k, 3) into ``slots`` (k,) with the
        buffer resized to ``count``; the writes are applied to the held buffer."""
        rows = self._room(material, count)
        need = 8 + len(slots) * K.MAX_OP_BYTES
        if len(self._out) < need:
            self._out = np.empty(need + need // 2, np.uint8)
        if self.links is None:
            n = K.encode_and_apply(rows, int(self.count[material]), int(count), slots, tris, self._out)
        else:
            n = K.encode_linked_and_apply(rows, int(self.count[material]), int(count), slots, tris, *self.links,
                                          self._out)
        self.count[material] = count
        return self._out[:n].tobytes()

    def replace(self, material: int, buffer: np.ndarray) -> None:
        """The client's buffer is now ``buffer`` (k, 3) (a keyframe)."""
        k = len(buffer)
        self._room(material, k)[:k] = buffer
        self.count[material] = k

    def _room(self, material: int, count: int) -> np.ndarray:
        """The material's rows, grown (held rows kept) to hold ``count`` triangles."""
        rows = self.rows[material]
        if count > len(rows):
            grown = np.zeros((count + count // 4 + 16, 3), np.uint32)
            grown[: self.count[material]] = rows[: self.count[material]]
            self.rows[material] = rows = grown
        return rows

    def buffer(self, material: int) -> np.ndarray:
        """(count, 3) view of what the client holds for ``material``."""
        return self.rows[material][: self.count[material]]

    @property
    def nbytes(self) -> int:
        return int(sum(r.nbytes for r in self.rows)) + self._out.nbytes + self.count.nbytes


def compile_encoders() -> None:
    """Compile (or load from numba's cache) both op-stream encoders with the argument
    types sessions use, so that no session's first frame waits for it."""
    targets = np.array([0, 0, 1, 3], np.uint32)
    links = (targets, np.zeros(4, np.uint8))
    for held in (HeldBuffers(1), HeldBuffers(1, links)):
        held.replace(0, np.array([[0, 1, 3]], np.uint32))
        held.encode(0, 2, np.array([0, 1], np.uint32), np.array([[0, 2, 3], [1, 2, 0]], np.uint32))
