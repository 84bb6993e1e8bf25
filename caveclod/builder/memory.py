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


def check_build_memory(triangles: int, what: str, available: int | None = None) -> None:
    """Refuse a build of ``triangles`` input triangles that would not fit.

    ``what`` names the input in the message; ``available`` (bytes) defaults
    to :func:`available_bytes`. Raises :class:`InputError` saying how much the
    build needs, how much there is, and what to do.
    """
    if available is None:
        available = available_bytes()
    need = int(triangles) * PEAK_BYTES_PER_TRIANGLE
    if available is None or need <= available:
        return
    gib = 1 << 30
    raise InputError(
        f"{what}: {int(triangles):,} triangles need about {need / gib:.1f} GiB to build (about "
        f"{PEAK_BYTES_PER_TRIANGLE} bytes a triangle at the build's peak) and {available / gib:.1f} GiB are "
        "available here; build on a machine (or in a container) with more memory, cut the input into "
        "smaller pieces, or for a heightfield take every second sample; --no-memory-check builds anyway")


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
