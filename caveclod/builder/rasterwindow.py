"""Heightfield files read by window: only the part of the grid a build keeps.

``caveclod build big.tif --stride K`` keeps one sample in K a side. Read
whole, a 40,000 x 40,000 float32 GeoTIFF is 6.4 GB in memory before its
100 million kept samples (0.4 GB) are taken. A window has a ``shape`` and
a ``dtype`` and gives the samples of a slice of rows and columns
(``window[r0::k, ::k]``, what
:func:`caveclod.builder.terrain.every_kth_sample` takes), holding only
them and a piece of the file at a time:

* :class:`TiffWindow` reads and decodes only the strips or tiles that hold
  a wanted sample, one at a time (a file of one row a strip at stride K
  reads 1/K of its strips). Only a file tifffile decodes on its own is
  read so (uncompressed or deflate, one band; a cloud-optimized GeoTIFF's
  full resolution, its overviews left alone); the others (LZW without the
  imagecodecs package, several bands, ...) are read whole as before.
* :class:`AsciiGridWindow` parses an ESRI ASCII grid's text in blocks of
  :data:`ASCII_BLOCK` bytes read one after another, storing only the
  wanted samples. It reads every ``.asc``, whole ones too: reading the text
  at once held it, every sample as float64 and their concatenation (8 to
  10 bytes of text and 16 of numbers a sample), where a block at a time
  holds the wanted samples and about 14 MB for the block (its tokens as
  Python bytes objects are most of it).
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod

import numpy as np

from ..errors import InputError
from .quiet import quiet_reading

ASCII_BLOCK = 1 << 20
"""Bytes of an ESRI ASCII grid's text parsed at a time."""


class RasterWindow(ABC):
    """A (rows, cols) grid of samples in a file, read by window (see the module docstring).

    Attributes:
        path: the file.
        shape: (rows, cols).
        dtype: the samples' type, native byte order.
    """

    ndim = 2

    def __init__(self, path: str, shape: tuple[int, int], dtype: np.dtype):
        self.path, self.shape, self.dtype = path, shape, np.dtype(dtype)

    def __array__(self, dtype=None, copy=None):
        """Every sample (``np.asarray(window)``): what the whole-file reader would have read."""
        whole = self[:, :]
        return whole if dtype is None else whole.astype(dtype)

    def __getitem__(self, key) -> np.ndarray:
        """The samples of ``key``, a (rows, cols) pair of slices with positive steps, as a new
        (len(rows), len(cols)) array."""
        if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(s, slice) for s in key)):
            raise TypeError(f"a {type(self).__name__} takes a pair of slices, e.g. window[r0::k, ::k]")
        rows = np.arange(*key[0].indices(self.shape[0]))
        cols = np.arange(*key[1].indices(self.shape[1]))
        if (len(rows) > 1 and rows[1] < rows[0]) or (len(cols) > 1 and cols[1] < cols[0]):
            raise ValueError("a window reads with positive steps only")
        out = np.empty((len(rows), len(cols)), self.dtype)
        if out.size:
            try:
                self._fill(out, rows, cols)
            except InputError:
                raise
            except Exception as exc:  # noqa: BLE001 - a damaged file surfaces as many exception types
                from .terrain import _describe
                raise InputError(f"cannot read heightfield {self.path} ({_describe(exc)}); check that the file "
                                 "is intact") from None
        return out

    @abstractmethod
    def _fill(self, out: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> None:
        """Write the samples at ``rows`` x ``cols`` (ascending) into ``out``; any exception but an
        InputError is a damaged file (:meth:`__getitem__` says so)."""


class TiffWindow(RasterWindow):
    """A single-band TIFF page's samples, read strip by strip or tile by tile (:func:`open_window`)."""

    def __init__(self, path: str, shape: tuple[int, int], dtype: np.dtype, chunk: tuple[int, int],
                 offsets: np.ndarray, counts: np.ndarray, decode):
        super().__init__(path, shape, dtype)
        self._chunk = chunk               # (rows, cols) of one strip or tile
        self._offsets, self._counts = offsets, counts
        self._decode = decode             # tifffile's decoder of this page's strips or tiles
        self.chunks_read = 0              # strips or tiles read so far (tests: how much a window read)

    def _fill(self, out, rows, cols) -> None:
        ch, cw = self._chunk
        across = -(-self.shape[1] // cw)              # strips or tiles a row of them
        with open(self.path, "rb") as fh, quiet_reading("tifffile"):
            for r, r0, r1 in _runs(rows // ch):
                in_rows = rows[r0:r1] - r * ch
                for c, c0, c1 in _runs(cols // cw):
                    chunk = self._read(fh, r * across + c)
                    out[r0:r1, c0:c1] = chunk[in_rows][:, cols[c0:c1] - c * cw]

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


class AsciiGridWindow(RasterWindow):
    """An ESRI ASCII grid's samples (float64, rows from north to south), parsed a block at a time.

    Opening reads the header (:func:`caveclod.builder.terrain.ascii_grid_header`; InputError
    where it is not one); reading checks every token: a sample that is not a number, or a count
    other than nrows x ncols, is refused naming the file, as the whole file's reading did.
    """

    def __init__(self, path: str, what: str = "heightfield"):
        from .terrain import MAX_ASCII_GRID_SAMPLES, ascii_grid_header
        header = ascii_grid_header(path)
        rows, cols = int(header["nrows"]), int(header["ncols"])
        if rows * cols > MAX_ASCII_GRID_SAMPLES:
            raise InputError(f"{what} {path}: {rows:,} x {cols:,} samples are more than this reader takes; "
                             "convert it to a GeoTIFF")
        super().__init__(path, (rows, cols), np.float64)
        self.what = what
        self._data_at = int(header["_data_at"])

    def _fill(self, out, rows, cols) -> None:
        n_rows, n_cols = self.shape
        row_at = np.full(n_rows, -1, np.int64)       # each sample's place in ``out`` (-1: not wanted)
        row_at[rows] = np.arange(len(rows))
        col_at = np.full(n_cols, -1, np.int64)
        col_at[cols] = np.arange(len(cols))
        whole = len(rows) == n_rows and len(cols) == n_cols
        done = 0                                     # samples parsed so far
        with open(self.path, "rb") as fh:
            fh.seek(self._data_at)
            for values in self._blocks(fh):
                if done + len(values) > n_rows * n_cols:
                    done += len(values)
                    continue                          # too many: counted to the end, then refused
                if whole:
                    out.reshape(-1)[done:done + len(values)] = values
                else:
                    at = np.arange(done, done + len(values))
                    r, c = row_at[at // n_cols], col_at[at % n_cols]
                    keep = (r >= 0) & (c >= 0)
                    out[r[keep], c[keep]] = values[keep]
                done += len(values)
        if done != n_rows * n_cols:
            raise InputError(f"{self.what} {self.path} holds {done:,} samples after its header, which says nrows "
                             f"{n_rows} x ncols {n_cols} = {n_rows * n_cols:,}; check that the file is whole (and "
                             "uses '.' decimals)")

    def _blocks(self, fh):
        """The samples' values, (n,) float64 a block of about :data:`ASCII_BLOCK` bytes at a time (cut
        after the block's last whitespace, so that no number is split)."""
        rest = b""
        while True:
            chunk = fh.read(ASCII_BLOCK)
            text = rest + chunk
            if not chunk:
                if text.strip():
                    yield self._numbers(text)
                return
            cut = max(text.rfind(b) for b in (b" ", b"\n", b"\r", b"\t"))
            if cut < 0:
                rest = text                           # no whitespace yet: one very long token
                continue
            yield self._numbers(text[:cut])
            rest = text[cut:]

    def _numbers(self, text: bytes) -> np.ndarray:
        try:
            return np.array(text.split(), dtype=np.float64)
        except ValueError as exc:
            from .terrain import _one_line
            raise InputError(f"{self.what} {self.path} holds a sample that is not a number ({_one_line(exc)[:80]}); "
                             "an ESRI ASCII grid writes them with '.' decimals, separated by spaces") from None


def open_window(path: str) -> RasterWindow | None:
    """A window on a heightfield file that can be read so (see the module docstring), else None:
    the whole-file reader then reads it, or says what is wrong with it."""
    ext = os.path.splitext(path)[1].lower()
    if ext in (".tif", ".tiff"):
        return _tiff_window(path)
    if ext == ".asc":
        try:
            return AsciiGridWindow(path)
        except (InputError, OSError):
            return None
    return None


def _tiff_window(path: str) -> TiffWindow | None:
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
