"""A client's index buffers: one dense (count, 3) uint32 array per (camera, material).

Frames patch them in place (``apply``): resize to the SurfaceDelta's count,
then write its triangles into its slots. Each buffer keeps spare rows, so a
growing buffer is reallocated rarely (by half again, like the server's).
"""

from __future__ import annotations

import numpy as np

from .. import wire


class IndexBuffers:
    """Index buffers of ``cameras`` cameras x ``materials`` materials.

    ``buffer(c, m)`` is the (count, 3) uint32 view a renderer uploads; slot
    k is row k. ``triangles(c)`` equals ``CameraState.triangles()`` of the
    server's camera after the same frames.
    """

    def __init__(self, cameras: int, materials: int):
        self.cameras, self.materials = cameras, materials
        self._rows = [[np.zeros((0, 3), np.uint32) for _ in range(materials)] for _ in range(cameras)]
        self._count = np.zeros((cameras, materials), np.int64)

    def buffer(self, camera: int, material: int) -> np.ndarray:
        """(count, 3) uint32 view of one buffer; valid until the next ``apply``."""
        return self._rows[camera][material][: self._count[camera, material]]

    def count(self, camera: int, material: int) -> int:
        return int(self._count[camera, material])

    def triangles(self, camera: int) -> dict:
        """{material: (k, 3) uint32 copy} of every non-empty buffer of ``camera``."""
        return {m: self.buffer(camera, m).copy() for m in range(self.materials) if self._count[camera, m]}

    def reset(self, camera: int) -> None:
        """Empty every buffer of ``camera`` (a keyframe refills them)."""
        self._count[camera] = 0

    def apply(self, camera: int, surface: wire.Surface) -> None:
        """Resize the (camera, surface.material) buffer to ``surface.count`` and write its slots.

        ``surface`` comes from :func:`caveclod.wire.decode_surface`, which
        checked its slots against the count; a material id out of range
        raises WireError.
        """
        m = surface.material
        if m >= self.materials:
            raise wire.WireError(f"material {m} out of range: the mesh has {self.materials} materials")
        rows, old, new = self._rows[camera][m], int(self._count[camera, m]), int(surface.count)
        if new > len(rows):
            grown = np.zeros((max(new, len(rows) + len(rows) // 2, 64), 3), np.uint32)
            grown[:old] = rows[:old]
            self._rows[camera][m] = rows = grown
        elif new > old:
            rows[old:new] = 0          # slots the frame must write; never stale data
        self._count[camera, m] = new
        rows[surface.slots] = surface.tris

    def crc32(self, camera: int, material: int) -> int:
        """The CRC-32 of a buffer, as SurfaceDelta.crc32 defines it."""
        return wire.buffer_crc32(self.buffer(camera, material))

    @property
    def nbytes(self) -> int:
        return int(sum(r.nbytes for cam in self._rows for r in cam))
