"""Borrowed arrays (caveclod/kernels/borrow.py): the same data, shape and
strides as the owner, writes seen by the owner, for every layout the
kernels pass (1-D, 2-D, strided views, several dtypes)."""

import numba as nb
import numpy as np
import pytest

from caveclod.kernels.borrow import borrow


@nb.njit(cache=False)
def _sum_and_bump(a):
    """Sum of ``a`` before, after adding 1 to each element through a borrowed view."""
    b = borrow(a)
    before = 0.0
    for i in range(b.size):
        before += b.flat[i]
    for i in np.ndindex(b.shape):
        b[i] += 1
    return before, b.shape[0], b.ndim


@nb.njit(cache=False)
def _inner(b, out):
    b = borrow(b)
    out = borrow(out)
    for i in range(b.shape[0]):
        out[i] = b[i, 0] * 10 + b[i, 1]


@nb.njit(cache=False)
def _outer(n):
    # A kernel's own scratch goes to an inner function that borrows it (the
    # module's rule): the allocating frame keeps it alive through the call.
    b = np.arange(2 * n).reshape(n, 2)
    out = np.empty(n, np.int64)
    _inner(b, out)
    return out


@pytest.mark.parametrize("make", [
    lambda: np.arange(12, dtype=np.float64),
    lambda: np.arange(12, dtype=np.int32).reshape(4, 3),
    lambda: np.arange(24, dtype=np.int64).reshape(6, 4)[::2, 1:3],     # strided, not contiguous
    lambda: np.arange(10, dtype=np.uint8),
])
def test_a_borrowed_view_reads_and_writes_the_owner(make):
    a = make()
    expected = a.astype(np.float64).sum()
    before, rows, ndim = _sum_and_bump(a)
    assert before == expected
    assert (rows, ndim) == (a.shape[0], a.ndim)
    np.testing.assert_array_equal(a, make() + 1)


def test_scratch_borrowed_by_an_inner_function_stays_alive():
    out = _outer(1000)
    np.testing.assert_array_equal(out, np.arange(1000) * 22 + 1)     # b[i] = (2i, 2i + 1)
