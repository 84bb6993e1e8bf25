"""Which build code made a file: a digest of the builder's and the kernels' sources.

Each build records it in its report (``info["build_code"]``), so that what
keeps built files around (the benchmarks' caches of built-ins) can tell a
file this checkout would make from one made by other code, and build again.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
"""The ``caveclod`` package's directory, which source names are relative to."""


def add_sources(h, names) -> None:
    """Feed hash ``h`` each source of ``names`` (paths under ``caveclod/``,
    such as ``"kernels/simplify.py"``): its name, then its bytes."""
    for name in names:
        h.update(name.encode())
        h.update((ROOT / name).read_bytes())


@lru_cache(maxsize=1)
def build_code() -> str:
    """16 hex digits of every source under ``caveclod/builder`` and ``caveclod/kernels``, and the file format's."""
    h = hashlib.blake2b(digest_size=8)
    add_sources(h, sorted(path.relative_to(ROOT).as_posix()
                          for path in [*ROOT.glob("builder/*.py"), *ROOT.glob("kernels/*.py"), ROOT / "staticmesh.py"]))
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
