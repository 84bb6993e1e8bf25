"""Walking the faces around a vertex over face-neighbour links.

Shared by the build (faces over positions) and the runtime (faces over
nodes). Conventions used everywhere in caveclod:

* ``corners[f] = (a, b, c)`` counter-clockwise; edge ``k`` of face ``f`` runs
  from corner ``k`` to corner ``k+1``; ``nbrs[f, k]`` is the face across edge
  ``k`` or -1 on a border.
* Around a vertex ``x`` sitting at corner ``k`` of ``f``, the *outgoing* edge
  is ``k`` (x -> next) and the *incoming* edge is ``k+2`` (prev -> x). Stepping
  across the outgoing edge is a "forward" step of the fan walk.
"""

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, inline="always")
def corner_of(corners, f, x):
    """Corner index (0..2) of vertex ``x`` in face ``f``, or -1."""
    if corners[f, 0] == x:
        return 0
    if corners[f, 1] == x:
        return 1
    if corners[f, 2] == x:
        return 2
    return -1


@nb.njit(cache=True, nogil=True)
def replace_in_row(rows, r, old, new):
    """Replace the first ``old`` in ``rows[r]`` (a neighbour link) by ``new``."""
    for k in range(3):
        if rows[r, k] == old:
            rows[r, k] = new
            return


@nb.njit(cache=True, nogil=True, inline="always")
def step_forward(corners, nbrs, f, x):
    """Face after ``f`` around ``x`` (across x's outgoing edge), or -1."""
    return nbrs[f, corner_of(corners, f, x)]


@nb.njit(cache=True, nogil=True, inline="always")
def step_backward(corners, nbrs, f, x):
    """Face before ``f`` around ``x`` (across x's incoming edge), or -1."""
    return nbrs[f, (corner_of(corners, f, x) + 2) % 3]


@nb.njit(cache=True, nogil=True)
def collect_fan(corners, nbrs, f0, x, out):
    """Write the faces around ``x`` (starting at ``f0``) into ``out``.

    Returns ``(count, on_border)``. A closed fan is listed in forward order
    from ``f0``; an open fan is listed from its backward end to its forward
    end. ``count`` is capped by ``len(out)``; the caller treats a full buffer
    as "too many to handle" (the build never collapses such vertices).
    """
    cap = out.shape[0]
    # Forward first: a closed fan (the common case) is done in one loop.
    n = 0
    f = f0
    while True:
        if n >= cap:
            return cap, False
        out[n] = f
        n += 1
        f = step_forward(corners, nbrs, f, x)
        if f == f0:
            return n, False
        if f == -1:
            break
    # Open fan: find its backward end and list it from there.
    f = f0
    while True:
        g = step_backward(corners, nbrs, f, x)
        if g == -1:
            break
        f = g
        n += 1
        if n > cap:
            return cap, True
    start = f
    n = 0
    while True:
        if n >= cap:
            return cap, True
        out[n] = f
        n += 1
        f = step_forward(corners, nbrs, f, x)
        if f == -1 or f == start:
            break
    return n, True


FAN_CAPACITY = 4096
"""Largest fan the build walks; vertices of higher valence are left alone."""


def fan_buffer() -> np.ndarray:
    """A scratch buffer for :func:`collect_fan`."""
    return np.empty(FAN_CAPACITY, np.int32)
