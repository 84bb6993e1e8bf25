"""Quiet third-party readers: what they print is noise to a ``caveclod build`` user.

trimesh and tifffile log what they repair or skip in a damaged file (through
the ``logging`` module, which, when the application configured no logging,
prints warnings and their tracebacks on stderr), and numpy and Pillow warn
about overflows and odd sizes. None of it tells the user what to do: what
matters reaches them as the loader's one-line InputError, or as the result.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np


@contextmanager
def quiet_reading(*loggers: str) -> Iterator[None]:
    """Silence warnings, numpy's floating-point warnings and the named loggers
    (and their children) while the body runs; restores them afterwards.

    Warnings are ignored, not turned into errors: a caller that wants one as
    an error (Pillow's decompression-bomb warning) filters it inside.
    """
    saved = [(logging.getLogger(name), logging.getLogger(name).level) for name in loggers]
    try:
        for logger, _ in saved:
            logger.setLevel(logging.CRITICAL + 1)      # above every level: nothing is emitted
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            yield
    finally:
        for logger, level in saved:
            logger.setLevel(level)
