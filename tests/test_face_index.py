"""The camera's face -> record hash table against a plain dict."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from caveclod.kernels import refine as K


@settings(max_examples=200, deadline=None)
@given(ops=st.lists(st.tuples(st.booleans(), st.integers(0, 200), st.integers(0, 10_000)), max_size=120),
       size=st.sampled_from([64, 128, 256]))
def test_table_matches_a_dict(ops, size):
    """Random inserts and deletes, with many collisions in a small table."""
    table = np.full((size, 2), -1, np.int32)
    ref = {}
    for insert, face, rec in ops:
        if insert and (face in ref or len(ref) < size // 2):
            K._store(table, face, rec)
            ref[face] = rec
        elif not insert:
            K._forget(table, face)
            ref.pop(face, None)
        for f in range(0, 201, 7):
            assert K._find(table, f) == ref.get(f, -1)
    assert sorted(table[table[:, 0] >= 0, 0].tolist()) == sorted(ref)
    for f, r in ref.items():
        assert K._find(table, f) == r
