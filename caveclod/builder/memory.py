"""Will a build fit in memory? Checked before the work starts, not found out by the OOM killer.

The build holds its arrays in memory: about 265-310 bytes per input
triangle at its peak on the built-in terrains, input included (README,
"Performance", the build table; ``benchmarks/build.py`` measures the
build, ``caveclod build`` adds packing the downloads and writing). An
input that needs more than the machine (or the container) has would run
for minutes and then be killed without a word, perhaps taking other
processes with it. So :func:`check_build_memory` compares the estimate
with what is available and refuses with the figures and what to do. The
build gives the C heap's free pages back between its phases
(:func:`give_back_freed_memory`), so that the peak is its arrays', not
what the allocator kept.

What is available is the kernel's ``MemAvailable`` (free memory plus what
the page cache can give back), and within a container the cgroup's limit
less its usage (cgroup v2 ``memory.max``/``memory.current``, or v1
``memory.limit_in_bytes``/``memory.usage_in_bytes``): a Kubernetes pod's
``resources.limits.memory`` is what kills it, not the node's memory.
Where neither can be read (not Linux) nothing is checked.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

from ..errors import InputError

PEAK_BYTES_PER_TRIANGLE = 320
"""The build's peak per input triangle, rounded up from the 264-306 B measured."""

_UNLIMITED = 1 << 60          # cgroup v1 writes "no limit" as a huge number


def available_bytes(root: str | os.PathLike = "/") -> int | None:
    """Bytes this process may still allocate: the least of the kernel's
    ``MemAvailable`` and the cgroup's limit less its usage; None if neither is
    readable. ``root`` is the file system root (tests point it elsewhere)."""
    root = Path(root)
    found = []
    meminfo = _read(root / "proc/meminfo")
    if meminfo is not None:
        for line in meminfo.splitlines():
            if line.startswith("MemAvailable:"):
                found.append(int(line.split()[1]) * 1024)
                break
    for limit_file, usage_file in (("sys/fs/cgroup/memory.max", "sys/fs/cgroup/memory.current"),
                                   ("sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "sys/fs/cgroup/memory/memory.usage_in_bytes")):
        limit, usage = _read(root / limit_file), _read(root / usage_file)
        if limit is None or usage is None:
            continue
        limit, usage = limit.strip(), usage.strip()
        if limit == "max" or not limit.isdigit() or not usage.isdigit() or int(limit) >= _UNLIMITED:
            break
        found.append(max(0, int(limit) - int(usage)))
        break
    return min(found) if found else None


def _read(path: Path) -> str | None:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError):
        return None


def check_build_memory(triangles: int, what: str, available: int | None = None,
                       grid_shape: tuple[int, int] | None = None, stride: int = 1) -> None:
    """Refuse a build of ``triangles`` input triangles that would not fit.

    ``what`` names the input in the message; ``available`` (bytes) defaults
    to :func:`available_bytes`. ``grid_shape``: a heightfield's (rows, cols),
    read at every ``stride``-th sample: the message then names the smallest
    ``--stride`` that would fit. Raises :class:`InputError` saying how much
    the build needs, how much there is, and what to do.
    """
    if available is None:
        available = available_bytes()
    need = int(triangles) * PEAK_BYTES_PER_TRIANGLE
    if available is None or need <= available:
        return
    gib = 1 << 30
    smaller = "cut the input into smaller pieces"
    if grid_shape is not None:
        k = _stride_that_fits(grid_shape, stride, available)
        smaller = ("cut the heightfield into smaller pieces" if k is None else
                   f"build one sample in {k} a side with --stride {k} "
                   f"({grid_triangles(grid_shape, k):,} triangles, cells {k} times as wide), or cut the "
                   "heightfield into smaller pieces")
    raise InputError(
        f"{what}: {int(triangles):,} triangles need about {need / gib:.1f} GiB to build (about "
        f"{PEAK_BYTES_PER_TRIANGLE} bytes a triangle at the build's peak) and {available / gib:.1f} GiB are "
        f"available here; build on a machine (or in a container) with more memory, {smaller}; "
        "--no-memory-check builds anyway")


def grid_triangles(shape, stride: int = 1) -> int:
    """Triangles of a heightfield of ``shape`` (rows, cols) samples with no holes (two a cell), at
    one sample in ``stride`` a side (:func:`caveclod.builder.terrain.every_kth_sample`): what its
    build may need memory for, known before its mesh is made."""
    rows, cols = shape[:2]
    return 2 * max((rows - 1) // stride, 0) * max((cols - 1) // stride, 0)


def _stride_that_fits(shape, stride: int, available: int) -> int | None:
    """The smallest stride above ``stride`` whose build fits in ``available`` bytes, or None
    where even one leaving 2 samples a side would not."""
    rows, cols = shape[:2]
    for k in range(stride + 1, max(rows, cols)):
        if (rows - 1) // k < 1 or (cols - 1) // k < 1:
            return None
        if grid_triangles(shape, k) * PEAK_BYTES_PER_TRIANGLE <= available:
            return k
    return None


READ_BYTES_PER_FILE_BYTE = {"obj": 9.0, "ply-ascii": 18.0, "ply": 13.0, "stl-ascii": 8.5, "stl": 11.5, "off": 18.0,
                            "glb": 13.0}
"""Peak memory of reading a mesh file, per byte of the file, by format: rounded up from
``load_mesh_file`` on a 2M-triangle mesh (2026-11-29: OBJ with texture coordinates 8.7, ASCII PLY
17.0, binary PLY 12.2, ASCII STL 7.8, binary STL 10.6, OFF 17.5, GLB 12.6). The text formats'
readers (trimesh's) hold 600-1,400 bytes a triangle, more than the build's peak. A compressed GLB
(Draco, meshopt) decodes to several times its size: for those the estimate is low, and the build's
own check, after reading, is what holds."""


def mesh_file_kind(path: str | os.PathLike) -> str | None:
    """The key of :data:`READ_BYTES_PER_FILE_BYTE` for a mesh file (PLY and STL sniffed for
    ASCII), or None for formats not estimated (glTF with its own buffers, anything else)."""
    path = Path(path)
    ext = path.suffix.lower().lstrip(".")
    if ext not in ("obj", "ply", "stl", "off", "glb"):
        return None
    if ext in ("ply", "stl"):
        try:
            with open(path, "rb") as f:
                head = f.read(512)
                size = os.fstat(f.fileno()).st_size
        except OSError:
            return None
        if ext == "ply":
            return "ply-ascii" if b"format ascii" in head else "ply"
        # Binary STL: an 80-byte header, a count, 50 bytes a triangle (a header may begin with "solid" too).
        count = int.from_bytes(head[80:84], "little") if len(head) >= 84 else -1
        return "stl" if 84 + 50 * count == size else "stl-ascii"
    return ext


def check_read_memory(path: str | os.PathLike, what: str, available: int | None = None) -> None:
    """Refuse to read a mesh file whose reading alone would not fit (see
    :data:`READ_BYTES_PER_FILE_BYTE`), before it starts; ``available`` as for
    :func:`check_build_memory`."""
    kind = mesh_file_kind(path)
    if kind is None:
        return
    try:
        size = os.path.getsize(path)
    except OSError:
        return                          # the reader says what is wrong with the path
    if available is None:
        available = available_bytes()
    need = int(size * READ_BYTES_PER_FILE_BYTE[kind])
    if available is None or need <= available:
        return
    gib = 1 << 30
    lean = min(READ_BYTES_PER_FILE_BYTE[k] for k in ("ply", "glb"))
    advice = ("convert it to binary PLY or GLB (their readers hold far less a triangle), "
              if kind not in ("ply", "glb") and READ_BYTES_PER_FILE_BYTE[kind] > lean else "")
    raise InputError(
        f"{what}: reading this {size / gib:.1f} GiB {kind.upper()} file takes about {need / gib:.1f} GiB (about "
        f"{READ_BYTES_PER_FILE_BYTE[kind]:g} times its size) and {available / gib:.1f} GiB are available here; "
        f"{advice}read it on a machine (or in a container) with more memory, or cut it into smaller pieces; "
        "--no-memory-check reads it anyway")


def give_back_freed_memory() -> None:
    """Give the C heap's free pages back to the system (glibc's ``malloc_trim``).

    Each phase of the build frees arrays of a few megabytes that glibc keeps
    for later allocations, but the next phase's arrays come in other sizes
    and it grows the heap instead: after a 1M-triangle build 180 MB were free
    and still resident, and packing the vertex downloads then raised the
    peak from 300 to 360 bytes a triangle. A no-op where the C library is not
    glibc.
    """
    global _malloc_trim
    if _malloc_trim is None:
        try:
            _malloc_trim = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _malloc_trim = False
    if _malloc_trim:
        _malloc_trim(0)


_malloc_trim = None
