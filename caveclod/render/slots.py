"""Cache mode on the GPU: one camera's N vertex slots, patched in place.

A client in cache mode holds N vertex slots per camera instead of the
vertex buffer; frames write vertices into slots (``VertexWrites``) and the
index buffers hold slot numbers. :class:`SlotVertices` owns one camera's
slots on the GPU: one buffer per planar attribute (positions, normals, uvs,
colours), as the resident vertex buffer, allocated once for N vertices.
Each run of consecutive slots a frame writes becomes one ``Buffer.write``
per attribute at ``slot * stride`` bytes: a frame that brings 200 vertices
uploads 200 vertices, never the slots.
"""

from __future__ import annotations

import moderngl
import numpy as np

from .buffers import UploadStats, slot_runs

# (name in the shader, moderngl layout, components, dtype) per planar attribute.
ATTRIBUTES = (("in_position", "3f", 3, np.float32), ("in_normal", "3f", 3, np.float32),
              ("in_uv", "2f", 2, np.float32), ("in_color", "4f1", 4, np.uint8))


def check_vertex_writes(n_slots: int, colors: bool, slots, arrays, first_slot=0) -> tuple:
    """Validate one camera's vertex writes.

    Args:
        n_slots: N.
        colors: whether the slots have a colour attribute.
        slots: (k,) strictly ascending slots < N, or None: consecutive from
            ``first_slot``.
        arrays: (positions (k, 3), normals (k, 3), uvs (k, 2)[, colors (k, 4) uint8]).

    Returns:
        ``(slots or None, first_slot, arrays)``: slots (k,) int64, arrays
        C-contiguous in the GPU's types.

    Raises:
        ValueError: naming what is wrong.
    """
    arrays = list(arrays)
    want = 4 if colors else 3
    if len(arrays) != want:
        raise ValueError(f"vertex writes need {want} arrays (positions, normals, uvs{', colors' if colors else ''}), "
                         f"got {len(arrays)}")
    k = len(arrays[0])
    out = []
    for (name, _, width, dtype), a in zip(ATTRIBUTES, arrays):
        a = np.asarray(a)
        if a.shape != (k, width):
            raise ValueError(f"{name.removeprefix('in_')} must have shape ({k}, {width}), got {a.shape}")
        if dtype is np.uint8 and a.dtype != np.uint8:
            raise ValueError(f"colors must be uint8 RGBA, got {a.dtype}")
        a = np.ascontiguousarray(a, dtype=dtype)
        if dtype is np.float32 and not np.isfinite(a).all():
            raise ValueError(f"{name.removeprefix('in_')} hold NaN or infinite values")
        out.append(a)
    if slots is None:
        if isinstance(first_slot, (bool, np.bool_)) or not isinstance(first_slot, (int, np.integer)) \
                or first_slot < 0 or first_slot + k > n_slots:
            raise ValueError(f"{k} vertices from slot {first_slot!r} do not fit {n_slots} slots")
        return None, int(first_slot), out
    slots = np.asarray(slots)
    if slots.dtype.kind not in "iu" or slots.shape != (k,):
        raise ValueError(f"slots must be ({k},) integers, one per vertex; got {slots.dtype} {slots.shape}")
    slots = slots.astype(np.int64)
    if k > 1 and (np.diff(slots) <= 0).any():
        raise ValueError("slots must be strictly ascending (unique)")
    if k and (slots[0] < 0 or slots[-1] >= n_slots):
        bad = int(slots[0]) if slots[0] < 0 else int(slots[-1])
        raise ValueError(f"slot {bad} is outside the {n_slots} vertex slots")
    return slots, 0, out


class SlotVertices:
    """One camera's N vertex slots on the GPU (one buffer per attribute).

    Attributes:
        content: ``(buffer, layout, name)`` triples for ``ctx.vertex_array``.
    """

    def __init__(self, ctx: moderngl.Context, n_slots: int, colors: bool, stats: UploadStats):
        self.n_slots, self.colors, self.stats = int(n_slots), bool(colors), stats
        self.content = [(ctx.buffer(reserve=self.n_slots * width * np.dtype(dtype).itemsize), layout, name)
                        for name, layout, width, dtype in ATTRIBUTES[: 4 if colors else 3]]

    def write(self, slots, arrays, first_slot=0) -> None:
        """Write vertices into slots (see :func:`check_vertex_writes`); nothing is written when they are malformed."""
        slots, first_slot, arrays = check_vertex_writes(self.n_slots, self.colors, slots, arrays, first_slot)
        runs = slot_runs(slots, first_slot, len(arrays[0]))
        for (buffer, _, _), a in zip(self.content, arrays):
            stride = a.shape[1] * a.dtype.itemsize
            data = a.reshape(-1).view(np.uint8)
            for slot, lo, hi in runs:
                buffer.write(data[lo * stride: hi * stride], offset=slot * stride)
            self.stats.vertex_bytes += a.nbytes
        self.stats.vertex_writes += len(runs) * len(arrays)

    def read(self) -> list[np.ndarray]:
        """The N slots read back from the GPU: [(N, 3), (N, 3), (N, 2)[, (N, 4)]] (unwritten slots undefined)."""
        out = []
        for (buffer, _, _), (_, _, width, dtype) in zip(self.content, ATTRIBUTES):
            out.append(np.frombuffer(buffer.read(), dtype).reshape(self.n_slots, width).copy())
        return out

    def release(self) -> None:
        for buffer, _, _ in self.content:
            buffer.release()
        self.content = []
