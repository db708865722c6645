"""Optional compilation of the plant's scalar kernels.

`jit` is numba.njit(cache=True) when numba can be imported and the environment variable
BOF_NO_JIT is unset (or empty, or "0"); otherwise it is the identity, and the kernels run
as the plain Python they are written in. Either way there is one implementation: a
compiled kernel is the same Python function (its `py_func`), and the results are the same
(tests/test_plant_kernels.py). Install the compiler with `pip install -e ".[fast]"`.

Without numba the identity decorator still sets `py_func` on the function (to itself),
so code and tests can name the plain-Python twin either way.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TypeVar

F = TypeVar("F", bound=Callable)

DISABLED_BY_ENVIRONMENT = os.environ.get("BOF_NO_JIT", "") not in ("", "0")

try:
    if DISABLED_BY_ENVIRONMENT:
        raise ImportError("BOF_NO_JIT is set")
    import numba
except ImportError:
    numba = None

#: True when the kernels are compiled (numba importable and BOF_NO_JIT unset).
ENABLED = numba is not None


def _plain(function: F) -> F:
    function.py_func = function  # type: ignore[attr-defined]
    return function


jit: Callable[[F], F] = numba.njit(cache=True) if numba is not None else _plain
