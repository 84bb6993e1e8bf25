"""The on-disk vertex buffer cache, keyed by ``vertex_buffer_hash``.

``$XDG_CACHE_HOME/caveclod/vertex-buffers/<hash>`` (``~/.cache/...`` when
XDG_CACHE_HOME is unset), or a directory given by the caller. Each file is
the payload followed by its CRC-32 (4 bytes, little-endian), checked on
every read; writes go to a temporary file renamed into place, so readers
never see half a file.
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
import zlib
from pathlib import Path

_HASH = re.compile(r"^[0-9a-f]{8,128}$")


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "caveclod" / "vertex-buffers"


class VertexBufferCache:
    """get/put of vertex buffer payloads (bytes) by their hash."""

    def __init__(self, directory: str | os.PathLike | None = None):
        self.directory = Path(directory) if directory is not None else default_cache_dir()

    def _path(self, key: str) -> Path:
        if not _HASH.match(key):           # the key names a file: never let it be a path
            raise ValueError(f"not a vertex_buffer_hash: {key!r}")
        return self.directory / key

    def get(self, key: str) -> bytes | None:
        """The payload stored under ``key``, or None (absent, unreadable or corrupt: then removed)."""
        path = self._path(key)
        try:
            blob = path.read_bytes()
        except OSError:
            return None
        payload, trailer = blob[:-4], blob[-4:]
        if len(trailer) < 4 or struct.unpack("<I", trailer)[0] != zlib.crc32(payload):
            self.discard(key)
            return None
        return payload

    def put(self, key: str, payload: bytes) -> None:
        """Store ``payload`` under ``key`` atomically; a cache that cannot be written is skipped."""
        path = self._path(key)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.directory, prefix=f".{key}.", suffix=".tmp")
        except OSError:
            return
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
                fh.write(struct.pack("<I", zlib.crc32(payload)))
            os.replace(tmp, path)
        except OSError:
            Path(tmp).unlink(missing_ok=True)

    def discard(self, key: str) -> None:
        try:
            self._path(key).unlink()
        except OSError:
            pass
