"""Comparisons for the kernel tests (test_*_kernels.py): a helper, not a test module.

`assert_same` is bit for bit, for results that must be identical (the same code on the same input: a copy of an
estimator, a path that must not change a flight); `assert_close_series` is what compiled and plain-Python flights
must agree to: within 1e-9 of each series' scale (the two round some operations differently in the last bit).
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


def assert_close(actual, expected, path: str = "result", rtol: float = 1e-12) -> None:
    """What one kernel compiled and the same kernel as plain Python agree to: floats within `rtol` of the
    result's own scale (the largest finite magnitude), NaN where NaN, infinities equal; tuples entry by entry;
    everything else equal."""
    if isinstance(expected, tuple):
        assert isinstance(actual, tuple) and len(actual) == len(expected), path
        for k, (a, e) in enumerate(zip(actual, expected)):
            assert_close(a, e, f"{path}[{k}]", rtol)
        return
    a, e = np.asarray(actual), np.asarray(expected)
    assert a.shape == e.shape, f"{path}: shape {a.shape} != {e.shape}"
    if e.dtype.kind != "f":
        assert np.array_equal(a, e), f"{path}: {a} != {e}"
        return
    assert np.array_equal(np.isnan(a), np.isnan(e)), f"{path}: {a} != {e}"
    infinite = np.isinf(e)
    assert np.array_equal(a[infinite], e[infinite]), f"{path}: {a} != {e}"
    finite = np.isfinite(e)
    scale = float(np.abs(e[finite]).max()) if finite.any() else 0.0
    np.testing.assert_allclose(a[finite], e[finite], rtol=rtol, atol=rtol * scale, err_msg=path)


def assert_close_series(actual, expected, name: str) -> None:
    """Within 1e-9 of the series' own scale (NaN where NaN); non-float series equal."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape, name
    if expected.dtype.kind != "f":
        assert np.array_equal(actual, expected), name
        return
    assert np.array_equal(np.isnan(actual), np.isnan(expected)), name
    finite = np.isfinite(expected)
    assert np.array_equal(actual[~finite & ~np.isnan(expected)], expected[~finite & ~np.isnan(expected)]), name
    scale = float(np.abs(expected[finite]).max()) if finite.any() else 0.0
    np.testing.assert_allclose(actual[finite], expected[finite], rtol=1e-9, atol=1e-9 * scale, err_msg=name)
