"""The on-disk vertex buffer cache, keyed by ``vertex_buffer_hash``.

``$XDG_CACHE_HOME/caveclod/vertex-buffers/<hash>`` (``~/.cache/...`` when
XDG_CACHE_HOME is unset; ``$CAVECLOD_CACHE_DIR/<hash>`` when that is set),
or a directory given by the caller. Each file is
the payload followed by its CRC-32 (4 bytes, little-endian), checked on
every read from disk; writes go to a temporary file renamed into place, so
readers never see half a file. A cache object also keeps the payloads it
read or wrote last in memory, for the other sessions of its client.
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
import zlib
from pathlib import Path

_HASH = re.compile(r"^[0-9a-f]{8,128}$")
MEMORY_ENTRIES = 2       # payloads a cache object keeps in memory


def default_cache_dir() -> Path:
    """Where clients cache vertex buffers unless told: ``$CAVECLOD_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/caveclod/vertex-buffers`` (``~/.cache`` when XDG_CACHE_HOME is unset)."""
    if os.environ.get("CAVECLOD_CACHE_DIR"):
        return Path(os.environ["CAVECLOD_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "caveclod" / "vertex-buffers"


class VertexBufferCache:
    """get/put of vertex buffer payloads (bytes, or read-only memoryviews: never copied) by their hash."""

    def __init__(self, directory: str | os.PathLike | None = None):
        self.directory = Path(directory) if directory is not None else default_cache_dir()
        self._memory: dict[str, tuple] = {}     # key -> (payload, crc32), oldest first

    def _path(self, key: str) -> Path:
        if not _HASH.match(key):           # the key names a file: never let it be a path
            raise ValueError(f"not a vertex_buffer_hash: {key!r}")
        return self.directory / key

    def get(self, key: str) -> bytes | memoryview | None:
        """The payload stored under ``key``, or None (absent, unreadable or corrupt: then removed)."""
        found = self.lookup(key)
        return None if found is None else found[0]

    def lookup(self, key: str) -> tuple[bytes | memoryview, int] | None:
        """``(payload, its zlib.crc32)`` stored under ``key``, or None.

        Payloads read or stored lately stay in memory (the last
        :data:`MEMORY_ENTRIES`), so the sessions of one client share one copy
        and do not read and check megabytes from disk each (a load generator
        opening 32 sessions of a 1M-triangle mesh spent seconds of its event
        loop on that)."""
        if key in self._memory:
            return self._memory[key]
        path = self._path(key)
        try:
            blob = path.read_bytes()
        except OSError:
            return None
        view = memoryview(blob)                 # read-only: a slice of it copies nothing
        payload, trailer = view[:-4], bytes(view[-4:])
        crc = zlib.crc32(payload)
        if len(trailer) < 4 or struct.unpack("<I", trailer)[0] != crc:
            self.discard(key)
            return None
        self._remember(key, payload, crc)
        return payload, crc

    def _remember(self, key: str, payload: bytes, crc: int) -> None:
        self._memory.pop(key, None)
        self._memory[key] = (payload, crc)
        while len(self._memory) > MEMORY_ENTRIES:
            del self._memory[next(iter(self._memory))]

    def put(self, key: str, payload: bytes | memoryview, crc: int | None = None) -> None:
        """Store ``payload`` under ``key`` atomically (``crc``: its zlib.crc32 where the caller has it);
        a cache that cannot be written is skipped."""
        path = self._path(key)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.directory, prefix=f".{key}.", suffix=".tmp")
        except OSError:
            return
        try:
            crc = zlib.crc32(payload) if crc is None else crc
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
                fh.write(struct.pack("<I", crc))
            os.replace(tmp, path)
            # Kept as it is when nobody can change it (bytes, a read-only view: the vertex buffer's own
            # memory, not a second copy of it); anything writable is copied.
            held = payload if isinstance(payload, bytes) or isinstance(payload, memoryview) and payload.readonly \
                else bytes(payload)
            self._remember(key, held, crc)
        except OSError:
            Path(tmp).unlink(missing_ok=True)

    def discard(self, key: str) -> None:
        self._memory.pop(key, None)
        try:
            self._path(key).unlink()
        except OSError:
            pass
