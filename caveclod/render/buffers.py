"""GPU index buffers patched in place from a frame's slot writes.

A camera's index buffer of one material lives on the GPU with spare room.
A frame (``SurfaceDelta`` on the wire, :class:`caveclod.SurfaceDelta` in the
core) says the buffer's new triangle count and which slots now hold which
triangle; removals were already filled by the server with the buffer's last
triangle, so the buffer stays dense and a draw is ``count`` triangles from
slot 0. Each run of consecutive slots becomes one ``Buffer.write`` at
``slot * 12`` bytes: a camera that moved a little uploads a few hundred bytes,
not the buffer. Only growth past the capacity reallocates, geometrically,
copying the kept triangles on the GPU (``glCopyBufferSubData``), not from the
CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

TRIANGLE_BYTES = 12          # three uint32 vertex indices
MIN_CAPACITY = 256           # triangles of a buffer's first allocation
GROWTH = 1.5                 # capacity factor when a buffer outgrows its room


@dataclass
class UploadStats:
    """What a renderer sent to the GPU, counted so tests and benchmarks can prove it.

    Attributes:
        index_bytes: index bytes written from the CPU (slot writes, keyframes).
        index_writes: ``Buffer.write`` calls for index data.
        grows: index buffers reallocated because they outgrew their capacity.
        gpu_copy_bytes: index bytes copied GPU-to-GPU when growing (not uploaded).
        vertex_bytes: vertex bytes uploaded: the resident buffer once, at
            creation; in cache mode, the vertices the frames write into slots.
        vertex_writes: ``Buffer.write`` calls for vertex data (cache mode).
        texture_bytes: texture bytes uploaded (once per material).
    """

    index_bytes: int = 0
    index_writes: int = 0
    grows: int = 0
    gpu_copy_bytes: int = 0
    vertex_bytes: int = 0
    vertex_writes: int = 0
    texture_bytes: int = 0


def check_writes(n_vertices: int, count, tris, slots=None, first_slot=0) -> tuple:
    """Validate one buffer's slot writes as the wire defines them.

    Args:
        n_vertices: d, the vertex buffer's length.
        count: triangles in the buffer after the writes.
        tris: (k, 3) or (3k,) integer vertex indices, each < d.
        slots: (k,) strictly ascending slots < count; None: the k triangles
            go to consecutive slots ``first_slot .. first_slot + k - 1``.
        first_slot: used only when ``slots`` is None.

    Returns:
        ``(count, tris, slots, first_slot)``: ints, tris (k, 3) C-contiguous
        little-endian uint32, slots (k,) int64 or None (consecutive).

    Raises:
        ValueError: naming what is wrong.
    """
    count = _whole_number("count", count)
    tris = np.asarray(tris)
    if tris.dtype.kind not in "iu":
        raise ValueError(f"tris must hold integer vertex indices, got dtype {tris.dtype}")
    if tris.ndim == 1 and tris.size % 3 == 0:
        tris = tris.reshape(-1, 3)
    if tris.ndim != 2 or tris.shape[1] != 3:
        raise ValueError(f"tris must have shape (k, 3) (or (3k,)), got {tris.shape}")
    k = len(tris)
    if k and (int(tris.min()) < 0 or int(tris.max()) >= n_vertices):
        bad = int(tris.min()) if int(tris.min()) < 0 else int(tris.max())
        raise ValueError(f"vertex index {bad} is outside the vertex buffer of {n_vertices} vertices")
    if slots is None:
        first_slot = _whole_number("first_slot", first_slot)
        if first_slot + k > count:
            raise ValueError(f"{k} triangles from slot {first_slot} run past count {count}")
    else:
        slots = np.asarray(slots)
        if slots.dtype.kind not in "iu" or slots.shape != (k,):
            raise ValueError(f"slots must be ({k},) integers, one per triangle; got {slots.dtype} {slots.shape}")
        slots = slots.astype(np.int64)
        if k > 1 and (np.diff(slots) <= 0).any():
            raise ValueError("slots must be strictly ascending (unique)")
        if k and (slots[0] < 0 or slots[-1] >= count):
            bad = int(slots[0]) if slots[0] < 0 else int(slots[-1])
            raise ValueError(f"slot {bad} is outside the buffer of count {count}")
        first_slot = 0
    return count, np.ascontiguousarray(tris, dtype="<u4"), slots, first_slot


def _whole_number(name: str, value) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
    return int(value)


def slot_runs(slots: np.ndarray | None, first_slot: int, k: int) -> list[tuple[int, int, int]]:
    """``(slot, a, b)`` per run: rows ``a:b`` of the writes go to consecutive
    slots from ``slot``, each run as long as possible. ``slots`` (k,)
    ascending, or None: all k rows from ``first_slot``."""
    if k == 0:
        return []
    if slots is None:
        return [(first_slot, 0, k)]
    breaks = np.flatnonzero(np.diff(slots) != 1) + 1
    starts = np.r_[0, breaks]
    return list(zip(slots[starts].tolist(), starts.tolist(), np.r_[breaks, k].tolist()))


class IndexBuffer:
    """One (camera, material) index buffer on the GPU.

    Attributes:
        count: triangles to draw (slots ``0 .. count - 1``).
        capacity: triangles the GPU buffer holds before it must grow.
    """

    def __init__(self, ctx: moderngl.Context, n_vertices: int, stats: UploadStats):
        self.ctx = ctx
        self.n_vertices = n_vertices
        self.stats = stats
        self.count = 0
        self.buffer: moderngl.Buffer | None = None      # made by the first triangles
        self._vaos: dict = {}

    @property
    def capacity(self) -> int:
        return 0 if self.buffer is None else self.buffer.size // TRIANGLE_BYTES

    def apply(self, count, tris, slots=None, first_slot=0) -> None:
        """Resize to ``count`` and write ``tris`` into ``slots`` (see :func:`check_writes`).

        Raises ``ValueError`` before touching the buffer when the writes are malformed.
        """
        count, tris, slots, first_slot = check_writes(self.n_vertices, count, tris, slots, first_slot)
        if count > self.capacity:
            self._grow(count)
        self.count = count
        data = tris.reshape(-1).view(np.uint8)          # byte view: slices are not copies
        runs = slot_runs(slots, first_slot, len(tris))
        for slot, a, b in runs:
            self.buffer.write(data[a * TRIANGLE_BYTES: b * TRIANGLE_BYTES], offset=slot * TRIANGLE_BYTES)
        self.stats.index_writes += len(runs)
        self.stats.index_bytes += tris.nbytes

    def clear(self) -> None:
        """Empty the buffer (a keyframe follows); its GPU memory is kept for it."""
        self.count = 0

    def read(self) -> np.ndarray:
        """(count, 3) uint32: the triangles the GPU holds, read back."""
        if self.count == 0:
            return np.zeros((0, 3), np.uint32)
        raw = self.buffer.read(size=self.count * TRIANGLE_BYTES)
        return np.frombuffer(raw, "<u4").reshape(-1, 3).astype(np.uint32)

    def vertex_array(self, program: moderngl.Program, content: list) -> moderngl.VertexArray:
        """The vertex array drawing this buffer with ``program`` (made once per program and buffer)."""
        vao = self._vaos.get(program.glo)
        if vao is None:
            vao = self.ctx.vertex_array(program, content, index_buffer=self.buffer, index_element_size=4)
            self._vaos[program.glo] = vao
        return vao

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        if self.buffer is not None:
            self.buffer.release()
            self.buffer = None

    def _grow(self, count: int) -> None:
        """Reallocate for at least ``count`` triangles; the kept slots are copied on the GPU."""
        capacity = max(count, int(self.capacity * GROWTH), MIN_CAPACITY)
        bigger = self.ctx.buffer(reserve=capacity * TRIANGLE_BYTES)
        keep = self.count * TRIANGLE_BYTES             # count > capacity >= self.count: all are kept
        if keep:
            self.ctx.copy_buffer(bigger, self.buffer, size=keep)
            self.stats.gpu_copy_bytes += keep
        if self.buffer is not None:
            self.stats.grows += 1
        self.release()
        self.buffer = bigger
