"""Which build code made a file: a digest of the builder's and the kernels' sources.

Each build records it in its report (``info["build_code"]``), so that what
keeps built files around (the benchmarks' caches of built-ins) can tell a
file this checkout would make from one made by other code, and build again.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path


@lru_cache(maxsize=1)
def build_code() -> str:
    """16 hex digits of every source under ``caveclod/builder`` and ``caveclod/kernels``, and the file format's."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.blake2b(digest_size=8)
    for path in sorted([*root.glob("builder/*.py"), *root.glob("kernels/*.py"), root / "staticmesh.py"]):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def made_by_this_code(path) -> bool:
    """Whether the ``.cvc`` file at ``path`` records this checkout's :func:`build_code`
    (False for files from before it was recorded, or damaged ones)."""
    from ..errors import CaveclodError
    from ..staticmesh import load
    try:
        return load(path, check=False).info.get("build_code") == build_code()
    except (CaveclodError, OSError):
        return False
