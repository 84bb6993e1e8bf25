"""A TIFF's samples read by window: only the strips or tiles a part of the grid lies in, one at a time.

``caveclod build big.tif --stride K`` keeps one sample in K a side. Read
whole, a 40,000 x 40,000 float32 GeoTIFF is 6.4 GB in memory before its
100 million kept samples (0.4 GB) are taken; read by window, the memory is
the kept samples and one strip or tile. :class:`TiffWindow` has a
``shape`` and a ``dtype`` and gives the samples of a slice of rows and
columns (``window[r0::k, ::k]``, what
:func:`caveclod.builder.terrain.every_kth_sample` takes), reading and
decoding only the strips or tiles that hold one of them: a file of one
row a strip at stride K reads 1/K of its strips.

Only a file tifffile decodes on its own is read so (uncompressed or
deflate, one band; a cloud-optimized GeoTIFF's full resolution, its
overviews left alone); :func:`open_window` returns None for the others
(LZW without the imagecodecs package, several bands, ...), which the
reader reads whole as before.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .quiet import quiet_reading


class TiffWindow:
    """A single-band TIFF page's samples, read by window (see the module docstring).

    Attributes:
        path: the file.
        shape: (rows, cols) of the page.
        dtype: the samples' type, native byte order.
    """

    ndim = 2

    def __init__(self, path: str, shape: tuple[int, int], dtype: np.dtype, chunk: tuple[int, int],
                 offsets: np.ndarray, counts: np.ndarray, decode):
        self.path = path
        self.shape = shape
        self.dtype = dtype
        self._chunk = chunk               # (rows, cols) of one strip or tile
        self._offsets, self._counts = offsets, counts
        self._decode = decode             # tifffile's decoder of this page's strips or tiles
        self.chunks_read = 0              # strips or tiles read so far (tests: how much a window read)

    def __array__(self, dtype=None, copy=None):
        """Every sample (``np.asarray(window)``): what the whole-file reader would have read."""
        whole = self[:, :]
        return whole if dtype is None else whole.astype(dtype)

    def __getitem__(self, key) -> np.ndarray:
        """The samples of ``key``, a (rows, cols) pair of slices with positive steps, as a new
        (len(rows), len(cols)) array."""
        if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(s, slice) for s in key)):
            raise TypeError("a TiffWindow takes a pair of slices, e.g. window[r0::k, ::k]")
        rows = np.arange(*key[0].indices(self.shape[0]))
        cols = np.arange(*key[1].indices(self.shape[1]))
        if (len(rows) > 1 and rows[1] < rows[0]) or (len(cols) > 1 and cols[1] < cols[0]):
            raise ValueError("a TiffWindow reads with positive steps only")
        out = np.empty((len(rows), len(cols)), self.dtype)
        if out.size == 0:
            return out
        ch, cw = self._chunk
        across = -(-self.shape[1] // cw)              # strips or tiles a row of them
        try:
            with open(self.path, "rb") as fh, quiet_reading("tifffile"):
                for r, r0, r1 in _runs(rows // ch):
                    in_rows = rows[r0:r1] - r * ch
                    for c, c0, c1 in _runs(cols // cw):
                        chunk = self._read(fh, r * across + c)
                        out[r0:r1, c0:c1] = chunk[in_rows][:, cols[c0:c1] - c * cw]
        except Exception as exc:  # noqa: BLE001 - a damaged strip or tile surfaces as many exception types
            from .terrain import _describe
            raise InputError(f"cannot read heightfield {self.path} ({_describe(exc)}); check that the file is "
                             "intact") from None
        return out

    def _read(self, fh, index: int) -> np.ndarray:
        """Strip or tile ``index`` decoded: (rows, cols) of this file's chunk (the last strip may be shorter)."""
        fh.seek(int(self._offsets[index]))
        data = fh.read(int(self._counts[index]))
        segment, _, shape = self._decode(data, index, jpegtables=None)
        self.chunks_read += 1
        if segment is None:
            raise ValueError(f"strip or tile {index} of {self.path} could not be decoded")
        return np.asarray(segment).reshape(shape[1:3]).astype(self.dtype, copy=False)   # a short strip: refused


def _squeezed(shape) -> tuple:
    return tuple(n for n in shape if n != 1)


def _runs(chunk_of: np.ndarray) -> list[tuple[int, int, int]]:
    """(chunk, start, stop) of each run of equal values in ``chunk_of`` (n,) ascending."""
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(chunk_of)) + 1, [len(chunk_of)]])
    return [(int(chunk_of[a]), int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:])]


def open_window(path: str) -> TiffWindow | None:
    """A :class:`TiffWindow` on ``path``'s first page, or None where it cannot be read by window:
    not one band of numbers on a page of its own, strips or tiles missing (the whole-file reader
    refuses those, saying so), or a compression tifffile decodes only with imagecodecs. Its first
    strip or tile is decoded here, so that a file that would fail part-way is read whole instead."""
    import tifffile

    try:
        with quiet_reading("tifffile"), tifffile.TiffFile(path) as tif:
            page, series = tif.pages[0], tif.series[0]
            # What the whole-file reader reads (tifffile's first series) must be this one page: a
            # cloud-optimized GeoTIFF's overviews are further pages, a stack of bands is not read so.
            if len(series.pages) != 1 or series.pages[0].offset != page.offset \
                    or _squeezed(series.shape) != _squeezed((page.imagelength, page.imagewidth)) \
                    or page.samplesperpixel != 1 or page.imagedepth != 1 or page.dtype is None \
                    or page.dtype.kind not in "iuf" or page.bitspersample != 8 * page.dtype.itemsize:
                return None
            n = int(np.prod(page.chunked))
            offsets, counts = np.asarray(page.dataoffsets, np.int64), np.asarray(page.databytecounts, np.int64)
            if len(offsets) != n or len(counts) != n or not ((offsets > 0) & (counts > 0)).all():
                return None
            chunk = (page.tilelength, page.tilewidth) if page.is_tiled else (page.rowsperstrip, page.imagewidth)
            if chunk[0] < 1 or chunk[1] < 1:
                return None
            window = TiffWindow(path, (int(page.imagelength), int(page.imagewidth)),
                                page.dtype.newbyteorder("="), (min(int(chunk[0]), int(page.imagelength)),
                                                               int(chunk[1])), offsets, counts, page.decode)
            window[:1, :1]                            # decodable here, or read whole
            window.chunks_read = 0
            return window
    except Exception:       # noqa: BLE001 - anything unusual: the whole-file reader reads it or says why not
        return None
