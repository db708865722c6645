"""Optional compilation of companion.core's numeric kernels (numba), with a plain-Python fallback.

One implementation. A kernel is an ordinary module-level Python function over float64 arrays and
floats (the u-PLKF's update, the IMM's mixing and combination, the baseline estimators' updates); `jit` hands
back that same function compiled by numba.njit(cache=True) when numba is installed (`pip install
bearing-follow[fast]`), and the function itself otherwise or when the environment sets
BOF_NO_JIT=1. The compiled kernel keeps `kernel.py_func`, the Python original, which the tests run
side by side with it. No fastmath, no parallel: the compiled arithmetic is the Python function's
IEEE arithmetic in the same order, and the matrix products go to the same BLAS (numba calls scipy's,
numpy its own: OpenBLAS both) so the two agree to the last bit (tests/test_estimator_kernels.py).

companion.core imports numba only through this module (the import rules), and never needs it.

Two LAPACK calls have a compiled twin here, `lapack_dgesv` and `lapack_dpotrf`: in Python they are
scipy.linalg.lapack's wrappers (what the u-PLKF called before it had kernels); compiled, numba's
binding of the very same routine (scipy's cython_lapack). `objmode` runs a block in the interpreter
from a compiled kernel (the rare general branches that call scipy or numpy routines numba lacks);
without numba it is an empty context manager, so the block simply runs.

`symmetric_eigen` and `symmetric_eigenvalues` are numpy's eigh and eigvalsh as kernels: numba's versions call
the same LAPACK routine (dsyevd, lower triangle) through scipy's binding and give numpy's bits (checked in
tests/test_diagnostic_kernels.py); a matrix with a NaN or an infinity, which numba refuses, goes to numpy's in
object mode.

Three scalar functions have a compiled twin that computes what Python computes where numba would not: `power`
(numba folds x ** 2 into x * x), `hypot` (numba calls the C library's hypot, CPython has its own algorithm) and
`remainder` (numba has no math.remainder).
"""

from __future__ import annotations

import math
import os

import numpy as np
from scipy.linalg.lapack import dgesv as _scipy_dgesv, dpotrf as _scipy_dpotrf

try:
    if os.environ.get("BOF_NO_JIT", "").strip() not in ("", "0"):
        raise ImportError("BOF_NO_JIT is set: the plain-Python kernels")
    import numba
    from numba import errors as _numba_errors, types as _numba_types
    from numba.extending import overload as _numba_overload
    from numba.np.linalg import _LAPACK as _NUMBA_LAPACK
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


def power(base: float, exponent: float) -> float:
    """base ** exponent of two floats, as Python computes it: the C library's pow (CPython's float power).

    Compiled, numba would turn `x ** 2` into x * x, which differs from pow(x, 2.0) in the last bit for about
    one argument in a thousand; this calls the C library's pow under its glibc alias `powf64` instead, a
    symbol LLVM does not know, so it cannot fold it into a multiplication (the same routine CPython calls).
    Where the C library has no `powf64` (not glibc), the compiled kernel calls `pow`, which LLVM may fold."""
    return base ** exponent


def hypot(x: float, y: float) -> float:
    """sqrt(x^2 + y^2) of two floats, as Python computes it: math.hypot.

    CPython's math.hypot is its own algorithm, not the C library's hypot (which numba compiles `math.hypot`
    to, and which differs from it in the last bit for about one argument in 500). Compiled, this is a
    transcription of the CPython 3.11 algorithm (_cpython_hypot: lossless scaling by a power of two, exact
    squares, compensated sums and one Newton correction of the square root; subnormal arguments by the plain
    scaled sum), equal to math.hypot bit for bit (tests/test_baseline_kernels.py, on millions of arguments)."""
    return math.hypot(x, y)


def remainder(x: float, y: float) -> float:
    """The IEEE 754 remainder x - n y, n the integer nearest x / y (ties to even), as Python computes it:
    math.remainder, which raises ValueError ("math domain error") for an infinite x or a zero y.

    numba has no math.remainder. Compiled, the CPython algorithm in exact arithmetic (_cpython_remainder:
    fmod, a comparison with the complement, copysign): every step is exact, so it equals math.remainder."""
    return math.remainder(x, y)


def _split_square(x: float) -> tuple[float, float]:
    """(x * x rounded, its rounding error), exactly (Veltkamp-Dekker splitting, no fma)."""
    square = x * x
    t = x * 134217729.0  # 2^27 + 1
    high = t - (t - x)
    low = x - high
    return square, ((high * high - square) + 2.0 * high * low) + low * low


_split_square = jit(_split_square)


def _cpython_hypot(x: float, y: float) -> float:
    """math.hypot(x, y) of CPython 3.11 (Modules/mathmodule.c, vector_norm for two coordinates), in float
    arithmetic numba compiles as written (no fast-math: no contraction, no reassociation)."""
    x = abs(x)
    y = abs(y)
    largest = y if y > x else x
    if math.isinf(x) or math.isinf(y):
        return math.inf
    if math.isnan(x) or math.isnan(y):
        return math.nan
    if largest == 0.0:
        return largest
    exponent = math.frexp(largest)[1]
    if exponent < -1023:  # subnormal: 2^-exponent would overflow; the scaled sum of the older algorithm
        total = 1.0
        fraction = 0.0
        for value in (x, y):
            value = value / largest
            value = value * value
            previous = total
            total += value
            fraction += (previous - total) + value
        return largest * math.sqrt(total - 1.0 + fraction)
    scale = math.ldexp(1.0, -exponent)
    total = 1.0
    fraction_products = 0.0
    fraction_sums = 0.0
    for value in (x, y):
        square, square_error = _split_square(value * scale)
        summed = total + square
        sum_error = (total - summed) + square
        total = summed
        fraction_products += square_error
        fraction_sums += sum_error
    root = math.sqrt(total - 1.0 + (fraction_products + fraction_sums))
    square, square_error = _split_square(root)
    summed = total - square
    sum_error = (total - summed) - square
    total = summed
    fraction_products -= square_error
    fraction_sums += sum_error
    correction = total - 1.0 + (fraction_products + fraction_sums)
    root += correction / (2.0 * root)
    return root / scale


def _cpython_remainder(x: float, y: float) -> float:
    """math.remainder(x, y) of CPython (m_remainder and math_2's domain check), exact at every step."""
    if math.isfinite(x) and math.isfinite(y):
        if y == 0.0:
            raise ValueError("math domain error")
        absolute_x = abs(x)
        absolute_y = abs(y)
        modulus = np.fmod(absolute_x, absolute_y)
        complement = absolute_y - modulus
        if modulus < complement:
            result = modulus
        elif modulus > complement:
            result = -complement
        else:  # halfway between two multiples of y: the even one
            result = modulus - 2.0 * np.fmod(0.5 * (absolute_x - modulus), absolute_y)
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
    eigenvectors as columns (n, n)), LAPACK dsyevd on the lower triangle. Compiled, numba's np.linalg.eigh: the
    same routine (jobz V, uplo L) through scipy's LAPACK, numpy's bits (tests/test_diagnostic_kernels.py). A
    matrix with a NaN or an infinity, which numba refuses, goes to numpy's eigh in object mode."""
    if _all_finite(matrix):
        return np.linalg.eigh(matrix)
    with objmode(values="float64[:]", vectors="float64[:, :]"):
        values, vectors = np.linalg.eigh(matrix)
    return values, vectors


@jit
def symmetric_eigenvalues(matrix: np.ndarray) -> np.ndarray:
    """numpy.linalg.eigvalsh(matrix) of a symmetric float64 matrix (n, n): the eigenvalues ascending (n,), LAPACK
    dsyevd without vectors on the lower triangle; compiled, numba's np.linalg.eigvalsh (the same routine, jobz N,
    uplo L, through scipy's LAPACK), and numpy's in object mode for a matrix with a NaN or an infinity."""
    if _all_finite(matrix):
        return np.linalg.eigvalsh(matrix)
    with objmode(values="float64[:]"):
        values = np.linalg.eigvalsh(matrix)
    return values


def lapack_dgesv(matrix: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """LAPACK dgesv on a square matrix A (n, n) and right-hand sides B (n, m): (LU factors (n, n), the
    0-based pivots (n,), X = A^-1 B (n, m), info), as scipy.linalg.lapack.dgesv returns them. Compiled,
    the same LAPACK routine through numba's binding of scipy's cython_lapack (pivots shifted to 0-based)."""
    return _scipy_dgesv(matrix, rhs)


def lapack_dpotrf(matrix: np.ndarray) -> tuple[np.ndarray, int]:
    """LAPACK dpotrf, lower triangle, of a symmetric matrix (n, n): (factor (n, n) whose lower triangle is
    the Cholesky factor and whose strict upper triangle is undefined, info), scipy's dpotrf(lower=1, clean=0).
    Compiled, the same LAPACK routine through numba's binding."""
    return _scipy_dpotrf(matrix, lower=1, clean=0)


def lapack_dgesv_into(matrix: np.ndarray, rhs: np.ndarray, factors: np.ndarray, pivots: np.ndarray,
                      solution: np.ndarray) -> int:
    """`lapack_dgesv` with its results written into the caller's arrays (no new ones: numba would allocate each):
    the LU factors into factors (n, n), the 0-based pivots into pivots (n,) int32, X = A^-1 B into solution (n, m);
    returns info. Compiled, factors and solution must be Fortran-ordered (e.g. the .T of a C-ordered buffer): LAPACK
    works in them in place, on the same column-major copies of A and B that `lapack_dgesv` makes."""
    lu, piv, x, info = _scipy_dgesv(matrix, rhs)
    factors[:, :] = lu
    pivots[:] = piv
    solution[:, :] = x
    return int(info)


def lapack_dpotrf_into(matrix: np.ndarray, factor: np.ndarray) -> int:
    """`lapack_dpotrf` with the factor written into the caller's factor (n, n) (Fortran-ordered when compiled, e.g.
    the .T of a C-ordered buffer: LAPACK works in it in place, on the same column-major copy `lapack_dpotrf` makes);
    returns info."""
    result, info = _scipy_dpotrf(matrix, lower=1, clean=0)
    factor[:, :] = result
    return int(info)


if numba is not None:

    def _libm_has(symbol: str) -> bool:
        try:
            import ctypes
            import ctypes.util

            return hasattr(ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6"), symbol)
        except OSError:
            return False

    _C_POW = _numba_types.ExternalFunction("powf64" if _libm_has("powf64") else "pow",
                                          _numba_types.float64(_numba_types.float64, _numba_types.float64))

    @_numba_overload(power, jit_options={"cache": True})
    def _power_compiled(base, exponent):
        def implementation(base, exponent):
            return _C_POW(float(base), float(exponent))

        return implementation

    _compiled_hypot = numba.njit(cache=True)(_cpython_hypot)
    _compiled_remainder = numba.njit(cache=True)(_cpython_remainder)

    @_numba_overload(hypot, jit_options={"cache": True})
    def _hypot_compiled(x, y):
        def implementation(x, y):
            return _compiled_hypot(float(x), float(y))

        return implementation

    @_numba_overload(remainder, jit_options={"cache": True})
    def _remainder_compiled(x, y):
        def implementation(x, y):
            return _compiled_remainder(float(x), float(y))

        return implementation

    @_numba_overload(lapack_dgesv, jit_options={"cache": True})
    def _lapack_dgesv_compiled(matrix, rhs):
        gesv = _NUMBA_LAPACK().numba_xgesv(_numba_types.float64)
        kind = ord("d")

        def implementation(matrix, rhs):
            n = matrix.shape[0]
            count = rhs.shape[1]
            factors = np.ascontiguousarray(matrix.T)  # its memory is A in column-major order, as LAPACK reads it
            solution = np.ascontiguousarray(rhs.T)
            pivots = np.empty(n, dtype=np.int32)
            info = gesv(kind, n, count, factors.ctypes, n, pivots.ctypes, solution.ctypes, n)
            return factors.T, (pivots - 1).astype(np.int64), solution.T, int(info)

        return implementation

    @_numba_overload(lapack_dpotrf, jit_options={"cache": True})
    def _lapack_dpotrf_compiled(matrix):
        potrf = _NUMBA_LAPACK().numba_xxpotrf(_numba_types.float64)
        kind = ord("d")
        lower = ord("L")

        def implementation(matrix):
            n = matrix.shape[0]
            factor = np.ascontiguousarray(matrix.T)
            info = potrf(kind, lower, n, factor.ctypes, n)
            return factor.T, int(info)

        return implementation

    @_numba_overload(lapack_dgesv_into, jit_options={"cache": True})
    def _lapack_dgesv_into_compiled(matrix, rhs, factors, pivots, solution):
        gesv = _NUMBA_LAPACK().numba_xgesv(_numba_types.float64)
        kind = ord("d")
        if factors.layout != "F" or solution.layout != "F" or pivots.dtype != _numba_types.int32:
            raise _numba_errors.TypingError("lapack_dgesv_into: Fortran-ordered factors and solution, int32 pivots")

        def implementation(matrix, rhs, factors, pivots, solution):
            n = matrix.shape[0]
            count = rhs.shape[1]
            factors[:, :] = matrix  # column-major: the memory `lapack_dgesv` hands LAPACK
            solution[:, :] = rhs
            info = gesv(kind, n, count, factors.ctypes, n, pivots.ctypes, solution.ctypes, n)
            for i in range(n):
                pivots[i] -= 1
            return int(info)

        return implementation

    @_numba_overload(lapack_dpotrf_into, jit_options={"cache": True})
    def _lapack_dpotrf_into_compiled(matrix, factor):
        potrf = _NUMBA_LAPACK().numba_xxpotrf(_numba_types.float64)
        kind = ord("d")
        lower = ord("L")
        if factor.layout != "F":
            raise _numba_errors.TypingError("lapack_dpotrf_into: a Fortran-ordered factor")

        def implementation(matrix, factor):
            n = matrix.shape[0]
            factor[:, :] = matrix  # column-major: the memory `lapack_dpotrf` hands LAPACK
            info = potrf(kind, lower, n, factor.ctypes, n)
            return int(info)

        return implementation
