"""Union-find over an int array of parents (each element its own parent at the start)."""

import numba as nb


@nb.njit(cache=True, nogil=True, inline="always")
def find(up, x):
    """Representative of ``x`` in ``up``, halving the path on the way."""
    while up[x] != x:
        up[x] = up[up[x]]
        x = up[x]
    return x
