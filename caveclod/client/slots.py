"""A cache-mode client's vertex slots: N vertices per camera instead of the vertex buffer.

In cache mode (``Open.cache_vertices``) the frames write vertices into
slots (``VertexWrites``) and the index buffers hold slot numbers. A
:class:`SlotBuffer` keeps one camera's N slots in the vertex buffer's planar
layout (one array per attribute, as :class:`caveclod.render.Vertices` and
the GPU take them), which slots hold a vertex, and the slots checksum,
updated per written slot (:class:`caveclod.checksums.SlotChecksum`).
"""

from __future__ import annotations

import numpy as np

from .. import wire
from ..checksums import SlotChecksum
from ..v1 import caveclod_pb2 as pb

_DTYPES = {pb.SCALAR_TYPE_FLOAT32: np.dtype("<f4"), pb.SCALAR_TYPE_UINT8: np.dtype("u1")}


class SlotBuffer:
    """One camera's N vertex slots.

    Args:
        n_slots: N (SessionInfo.cache_vertices).
        fmt: the session's VertexFormat (which attributes, of which types).

    Attributes:
        arrays: {name: (N, c) array} per attribute, in the format's order:
            "position", "normal", "texcoord" (float32) and "color" (uint8)
            when the mesh has colours. Rows of slots holding no vertex are
            stale or zero; draw only slots the index buffers use.
        held: (N,) bool, True where a slot holds a vertex.
        checksum: the slots checksum (``checksum.value``).
    """

    def __init__(self, n_slots: int, fmt: pb.VertexFormat):
        self.n_slots = int(n_slots)
        self.arrays: dict[str, np.ndarray] = {}
        for a in fmt.attributes:
            if a.type not in _DTYPES:
                raise wire.WireError(f"vertex attribute {a.semantic} has unknown scalar type {a.type}; "
                                     "upgrade the client")
            name = pb.AttributeSemantic.Name(a.semantic).removeprefix("ATTRIBUTE_SEMANTIC_").lower()
            self.arrays[name] = np.zeros((self.n_slots, a.components), _DTYPES[a.type])
        self.held = np.zeros(self.n_slots, bool)
        self.checksum = SlotChecksum(self.n_slots)

    @property
    def positions(self) -> np.ndarray:
        return self.arrays["position"]

    @property
    def normals(self) -> np.ndarray:
        return self.arrays["normal"]

    @property
    def uvs(self) -> np.ndarray:
        return self.arrays["texcoord"]

    @property
    def colors(self) -> np.ndarray | None:
        return self.arrays.get("color")

    @property
    def n_held(self) -> int:
        """Slots holding a vertex (never more than N)."""
        return int(self.held.sum())

    def write(self, w: wire.SlotWrites) -> None:
        """Write the vertices of ``w`` (from :func:`caveclod.wire.decode_slot_writes`) into their slots."""
        if len(w.blocks) != len(self.arrays):
            raise wire.WireError(f"vertex writes carry {len(w.blocks)} attributes, the format {len(self.arrays)}")
        slots = np.asarray(w.slots, np.int64)
        for array, block in zip(self.arrays.values(), w.blocks):
            array[slots] = block
        self.held[slots] = True
        self.checksum.write(slots, w.blocks)

    def reset(self) -> None:
        """No slot holds a vertex any more (a keyframe of the camera follows)."""
        self.held[:] = False
        self.checksum.reset()

    def unheld(self, tris: np.ndarray) -> np.ndarray:
        """The slots among ``tris`` (any shape of slot numbers) that hold no vertex, ascending."""
        tris = np.asarray(tris, np.int64).ravel()
        return np.unique(tris[~self.held[tris]])

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.arrays.values()) + self.held.nbytes + self.checksum.terms.nbytes)
