"""The checksums caveclod.v1 defines, in numpy: both ends compute them the same way.

* index buffers: CRC-32 (``zlib.crc32``) of the (count, 3) little-endian
  uint32 array (SurfaceDelta.crc32);
* the vertex payload: CRC-32 of its bytes (SessionInfo.vertex_payload_crc32);
* cache mode's slots (VertexWrites.slots_checksum): the sum modulo 2**32,
  over the slots holding a vertex, of the CRC-32 of the slot number
  (little-endian uint32) followed by the vertex's attribute values. A sum of
  per-slot terms, so that a frame that writes k slots updates it in O(k)
  (a CRC of the whole slot buffer would read every slot every frame).
  :func:`rows_crc32` computes many short CRCs at once, byte column by byte
  column, with the table of zlib's CRC-32 (same polynomial, same result).

Plain numpy and zlib: the thin client imports this module.
"""

from __future__ import annotations

import zlib
from typing import Iterable

import numpy as np

U32 = np.dtype("<u4")
MASK = 0xFFFFFFFF


def buffer_crc32(buf: np.ndarray) -> int:
    """CRC-32 of a (count, 3) index buffer as the proto defines it (0 when empty)."""
    return zlib.crc32(np.ascontiguousarray(buf, dtype=U32)) if len(buf) else 0


def payload_crc32(blocks: Iterable[np.ndarray]) -> int:
    """CRC-32 of the concatenated bytes of ``blocks`` (the planar vertex payload)."""
    crc = 0
    for block in blocks:
        crc = zlib.crc32(np.ascontiguousarray(block).reshape(-1).view(np.uint8), crc)
    return crc


def _crc_table() -> np.ndarray:
    """(256,) uint32: CRC-32 of each byte value (reflected polynomial 0xEDB88320)."""
    c = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        c = np.where(c & 1, (c >> 1) ^ np.uint32(0xEDB88320), c >> 1).astype(np.uint32)
    return c


_TABLE = _crc_table()


def rows_crc32(rows: np.ndarray) -> np.ndarray:
    """(k,) uint32: ``zlib.crc32`` of each row of ``rows`` (k, w) uint8.

    One table lookup per byte column over all rows: w numpy operations
    instead of k calls, for the short rows of slot checksums.
    """
    rows = np.asarray(rows, np.uint8)
    crc = np.full(len(rows), MASK, np.uint32)
    for j in range(rows.shape[1]):
        crc = _TABLE[(crc ^ rows[:, j]) & 0xFF] ^ (crc >> 8)
    return crc ^ np.uint32(MASK)


def slot_terms(slots: np.ndarray, blocks: list) -> np.ndarray:
    """(k,) uint32 per-slot terms of the slots checksum.

    Args:
        slots: (k,) slot numbers.
        blocks: the vertices' attributes, one (k, c) array per attribute in
            VertexFormat order (float32 or uint8).
    """
    k = len(slots)
    parts = [np.ascontiguousarray(slots, dtype=U32).view(np.uint8).reshape(k, 4)]
    for b in blocks:
        b = np.ascontiguousarray(b)
        if b.dtype.byteorder == ">":                     # the wire is little-endian
            b = b.astype(b.dtype.newbyteorder("<"))
        # Row width from the shape, not -1: a write of no slots (every part hidden) is (0, w) too.
        parts.append(b.view(np.uint8).reshape(k, b.dtype.itemsize * int(np.prod(b.shape[1:]))))
    return rows_crc32(np.concatenate(parts, axis=1))


class SlotChecksum:
    """One camera's slots checksum, kept up to date as its slots are written.

    ``terms`` (n,) uint32 holds each slot's term (0 for a slot holding no
    vertex); ``value`` is their sum modulo 2**32.
    """

    def __init__(self, n_slots: int):
        self.terms = np.zeros(n_slots, np.uint32)
        self.value = 0

    def write(self, slots: np.ndarray, blocks: list) -> None:
        """Slots ``slots`` (unique) now hold the vertices whose attributes are ``blocks``."""
        slots = np.asarray(slots, np.int64)
        new = slot_terms(slots, blocks)
        old = int(self.terms[slots].sum(dtype=np.uint64))
        self.value = (self.value - old + int(new.sum(dtype=np.uint64))) & MASK
        self.terms[slots] = new

    def reset(self) -> None:
        """No slot holds a vertex."""
        self.terms[:] = 0
        self.value = 0
