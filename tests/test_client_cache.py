"""The on-disk vertex buffer cache and the client's index buffers."""

from __future__ import annotations

import numpy as np
import pytest

from caveclod import wire
from caveclod.client.buffers import IndexBuffers
from caveclod.client.cache import VertexBufferCache, default_cache_dir

KEY = "0123456789abcdef0123456789abcdef"


def test_put_get_and_corruption(tmp_path):
    cache = VertexBufferCache(tmp_path / "vb")
    assert cache.get(KEY) is None
    cache.put(KEY, b"payload bytes")
    assert cache.get(KEY) == b"payload bytes"
    assert [p.name for p in (tmp_path / "vb").iterdir()] == [KEY]          # no temporary file left
    path = tmp_path / "vb" / KEY
    path.write_bytes(b"Payload bytes" + path.read_bytes()[-4:])
    fresh = VertexBufferCache(tmp_path / "vb")                                # another process: reads the disk
    assert fresh.get(KEY) is None and not path.exists()                      # corrupt: dropped
    path.write_bytes(b"ab")
    assert fresh.get(KEY) is None and not path.exists()
    path.write_bytes(b"")
    assert fresh.get(KEY) is None and not path.exists()


def test_payloads_read_lately_are_shared_from_memory(tmp_path):
    import zlib

    from caveclod.client import cache as cache_module
    VertexBufferCache(tmp_path).put(KEY, b"the payload")
    cache = VertexBufferCache(tmp_path)
    first = cache.lookup(KEY)
    assert first == (b"the payload", zlib.crc32(b"the payload"))
    (tmp_path / KEY).unlink()                       # a second session does not read the disk again
    assert cache.lookup(KEY)[0] is first[0]
    others = [f"{k:032x}" for k in range(cache_module.MEMORY_ENTRIES)]
    for k in others:
        cache.put(k, b"other")
    assert cache.get(KEY) is None                                 # memory holds the last few only
    cache.discard(others[-1])
    assert cache.get(others[-1]) is None


def test_keys_never_name_other_paths(tmp_path):
    cache = VertexBufferCache(tmp_path)
    for bad in ("../x", "/etc/passwd", "ABCDEF0123", ""):
        with pytest.raises(ValueError):
            cache.get(bad)
        with pytest.raises(ValueError):
            cache.lookup(bad)


def test_default_directory_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("CAVECLOD_CACHE_DIR", str(tmp_path / "own"))
    assert default_cache_dir() == tmp_path / "own"
    monkeypatch.delenv("CAVECLOD_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert default_cache_dir() == tmp_path / "caveclod" / "vertex-buffers"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert str(default_cache_dir()).endswith(".cache/caveclod/vertex-buffers")


def test_an_unwritable_cache_is_skipped(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    cache = VertexBufferCache(blocker / "vb")
    cache.put(KEY, b"x")                  # no exception: a viewer works without a cache
    assert cache.get(KEY) is None


def test_index_buffers_grow_shrink_and_zero_new_slots():
    b = IndexBuffers(cameras=1, materials=2)
    rows = np.arange(300, dtype=np.uint32).reshape(100, 3)
    b.apply(0, wire.Surface(1, 100, np.arange(100, dtype=np.uint32), rows))
    np.testing.assert_array_equal(b.buffer(0, 1), rows)
    b.apply(0, wire.Surface(1, 40, np.array([3], np.uint32), np.array([[7, 8, 9]], np.uint32)))
    assert b.count(0, 1) == 40 and b.buffer(0, 1)[3].tolist() == [7, 8, 9]
    b.apply(0, wire.Surface(1, 42, np.array([40, 41], np.uint32), np.ones((2, 3), np.uint32)))
    assert b.buffer(0, 1)[39].tolist() == rows[39].tolist()
    assert b.triangles(0).keys() == {1}
    with pytest.raises(wire.WireError, match="material 5"):
        b.apply(0, wire.Surface(5, 1, np.zeros(1, np.uint32), np.zeros((1, 3), np.uint32)))
    b.reset(0)
    assert b.triangles(0) == {} and b.crc32(0, 1) == 0
