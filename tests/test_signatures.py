"""Every function's positional parameters stay few enough to read at a call site: at most 8 outside the numba
kernels, at most 12 in a kernel (a kernel takes its state as arrays and tuples, not as dozens of floats). Past
that, the parameters are keyword-only (after `*`), so every call names them."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("companion", "sitl_plant", "interfaces", "studies", "benchmarks", "tests")
MAX_POSITIONAL = 8
MAX_KERNEL_POSITIONAL = 12
KERNEL_WRAPPERS = {"jit", "jit_inline"}


def _positional(function: ast.FunctionDef | ast.AsyncFunctionDef, in_class: bool) -> int:
    names = [a.arg for a in function.args.posonlyargs + function.args.args]
    if in_class and names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names)


def _wrapped(tree: ast.Module) -> set[str]:
    """Names of module functions compiled as kernels by a call such as `_kernel = jit(_function)`."""
    return {node.args[0].id for node in ast.walk(tree)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in KERNEL_WRAPPERS
            and node.args and isinstance(node.args[0], ast.Name)}


def _functions(tree: ast.Module):
    """(function, inside a class) for every def in the module, nested ones included."""
    def walk(node, in_class):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield child, in_class
                yield from walk(child, False)
            elif isinstance(child, ast.ClassDef):
                yield from walk(child, True)
            else:
                yield from walk(child, in_class)
    yield from walk(tree, False)


def overlong() -> list[str]:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            wrapped = _wrapped(tree)
            for function, in_class in _functions(tree):
                kernel = function.name in wrapped or any(
                    (d.id if isinstance(d, ast.Name) else getattr(d, "attr", None)) in KERNEL_WRAPPERS
                    for d in function.decorator_list)
                limit = MAX_KERNEL_POSITIONAL if kernel else MAX_POSITIONAL
                count = _positional(function, in_class)
                if count > limit:
                    found.append(f"{path.relative_to(ROOT)}:{function.lineno} {function.name}: {count} > {limit}")
    return found


def test_no_function_takes_more_positional_parameters_than_its_limit():
    assert overlong() == []


def test_the_check_sees_a_long_signature_and_a_kernel(tmp_path, monkeypatch):
    """The counting itself: a plain function with 9 positional parameters is flagged, the same as a kernel is not,
    a 13-parameter kernel is, and keyword-only parameters and self never count."""
    package = tmp_path / "probe"
    package.mkdir()
    (package / "module.py").write_text(
        "def plain(a, b, c, d, e, f, g, h, i): pass\n"
        "def fine(a, b, c, d, e, f, g, h, *, i, j, k): pass\n"
        "def inner(a, b, c, d, e, f, g, h, i): pass\n"
        "inner_kernel = jit(inner)\n"
        "@jit_inline\n"
        "def wide(a, b, c, d, e, f, g, h, i, j, k, l, m): pass\n"
        "class Thing:\n"
        "    def method(self, a, b, c, d, e, f, g, h): pass\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGES", ("probe",))
    flagged = [line.split()[1] for line in overlong()]
    assert flagged == ["plain:", "wide:"]
