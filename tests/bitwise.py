"""Bit-for-bit comparison for the kernel tests (test_*_kernels.py): a helper, not a test module.

The compiled kernels must give the results of the code they replaced to the last bit,
compiled and interpreted; these helpers say what "the same" means there, once.
"""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

#: Seeds for numpy generators that draw a test's random arrays.
seeds = st.integers(0, 2**32 - 1)


def assert_same(actual, expected, path: str = "result") -> None:
    """Bit for bit: the same values, NaN where NaN, the same signs of zero (floats); equal values otherwise;
    tuples entry by entry; an (exception type, message) pair, as the diagnostic tests record a raised
    exception, equal as a pair."""
    if isinstance(expected, tuple) and expected and isinstance(expected[0], type):
        assert actual == expected, f"{path}: {actual} != {expected}"
        return
    if isinstance(expected, tuple):
        assert isinstance(actual, tuple) and len(actual) == len(expected), path
        for k, (a, e) in enumerate(zip(actual, expected)):
            assert_same(a, e, f"{path}[{k}]")
        return
    a, e = np.asarray(actual), np.asarray(expected)
    assert a.shape == e.shape, f"{path}: shape {a.shape} != {e.shape}"
    if e.dtype.kind == "f":
        assert np.array_equal(a, e, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(e)), f"{path}: {a} != {e}"
    else:
        assert np.array_equal(a, e), f"{path}: {a} != {e}"
