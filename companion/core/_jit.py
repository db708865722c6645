"""Optional compilation of companion.core's numeric kernels (numba), with a plain-Python fallback.

One implementation. A kernel is an ordinary module-level Python function over float64 arrays and
floats (the u-PLKF's update, the IMM's mixing and combination, the baseline estimators' updates); `jit` hands
back that same function compiled by numba.njit(cache=True) when numba is installed (`pip install
bearing-follow[fast]`), and the function itself otherwise or when the environment sets
BOF_NO_JIT=1. The compiled kernel keeps `kernel.py_func`, the Python original. No fastmath, no parallel.

The contract: a compiled kernel computes what its Python function computes, to rounding. numba compiles
math.hypot to the C library's hypot, x ** 2 to x * x, np.linalg to its own LAPACK bindings; CPython and numpy
round those differently in the last bit, and nothing here copies their bits. The tests check each kernel's
behaviour against independent references, and a whole flight compiled against the same flight in plain
Python (tests/test_estimator_kernels.py, figures within 1e-9 relative).

companion.core imports numba only through this module (the import rules), and never needs it; this module
imports no other companion module (the kernels' warm-up is companion.warmup, outside the core).

`objmode` runs a block in the interpreter from a compiled kernel (the rare general branches that call scipy or
numpy routines numba lacks); without numba it is an empty context manager, so the block simply runs.
`symmetric_eigen` and `symmetric_eigenvalues` are numpy's eigh and eigvalsh as kernels (numba's own compiled,
numpy's in object mode for a matrix with a NaN or an infinity, which numba refuses). `remainder` is
math.remainder, which numba lacks, as a kernel.
"""

from __future__ import annotations

import math
import os

import numpy as np

try:
    if os.environ.get("BOF_NO_JIT", "").strip() not in ("", "0"):
        raise ImportError("BOF_NO_JIT is set: the plain-Python kernels")
    import numba
except ImportError:
    numba = None

ENABLED = numba is not None
"""Whether the kernels are compiled (numba importable and BOF_NO_JIT unset)."""


def jit(function):
    """`function` compiled with numba.njit(cache=True) when ENABLED, else `function` itself."""
    if numba is None:
        return function
    return numba.njit(cache=True)(function)


def jit_inline(function):
    """`jit` for a small kernel that other kernels call on every update: compiled with inline="always", so numba
    puts its body (its typed IR: the same operations) into each compiled caller instead of a call, which would
    pass every array argument by value with its reference counting; called from Python, an ordinary kernel. Not for
    a function with an objmode block (numba cannot inline those)."""
    if numba is None:
        return function
    return numba.njit(cache=True, inline="always")(function)


def python_function(kernel):
    """The plain-Python original of a kernel (its py_func when compiled; the kernel itself when not)."""
    return getattr(kernel, "py_func", kernel)


@jit
def remainder(x: float, y: float) -> float:
    """The IEEE 754 remainder x - n y, n the integer nearest x / y (ties to even): math.remainder, which numba
    lacks, in exact arithmetic (fmod, a comparison with the complement, copysign; CPython's algorithm), so it
    equals math.remainder; ValueError ("math domain error") for an infinite x or a zero y."""
    if math.isfinite(x) and math.isfinite(y):
        if y == 0.0:
            raise ValueError("math domain error")
        absolute_x = abs(x)
        absolute_y = abs(y)
        modulus = float(np.fmod(absolute_x, absolute_y))
        complement = absolute_y - modulus
        if modulus < complement:
            result = modulus
        elif modulus > complement:
            result = -complement
        else:  # halfway between two multiples of y: the even one
            result = modulus - 2.0 * float(np.fmod(0.5 * (absolute_x - modulus), absolute_y))
        return math.copysign(1.0, x) * result
    if math.isnan(x):
        return x
    if math.isnan(y):
        return y
    if math.isinf(x):
        raise ValueError("math domain error")
    return x


class _Interpreted:
    """numba.objmode's stand-in without numba: `with objmode(name="float64"):` just runs its block."""

    def __call__(self, *args, **kwargs) -> "_Interpreted":
        return self

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc_info) -> bool:
        return False


objmode = numba.objmode if numba is not None else _Interpreted()


@jit
def _all_finite(matrix: np.ndarray) -> bool:
    """Every entry of a float64 matrix (n, n) finite (no NaN, no infinity)."""
    for i in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            if not math.isfinite(matrix[i, j]):
                return False
    return True


@jit
def symmetric_eigen(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """numpy.linalg.eigh(matrix) of a symmetric float64 matrix (n, n): (eigenvalues ascending (n,), orthonormal
    eigenvectors as columns (n, n)), LAPACK dsyevd on the lower triangle. Compiled, numba's np.linalg.eigh. A
    matrix with a NaN or an infinity, which numba refuses, goes to numpy's eigh in object mode."""
    if _all_finite(matrix):
        return np.linalg.eigh(matrix)
    with objmode(values="float64[:]", vectors="float64[:, :]"):
        values, vectors = np.linalg.eigh(matrix)
    return values, vectors


@jit
def symmetric_eigenvalues(matrix: np.ndarray) -> np.ndarray:
    """numpy.linalg.eigvalsh(matrix) of a symmetric float64 matrix (n, n): the eigenvalues ascending (n,); compiled,
    numba's np.linalg.eigvalsh, and numpy's in object mode for a matrix with a NaN or an infinity."""
    if _all_finite(matrix):
        return np.linalg.eigvalsh(matrix)
    with objmode(values="float64[:]"):
        values = np.linalg.eigvalsh(matrix)
    return values
