"""The docs' "Paper equations in the code" table (docs/architecture.md) points at objects that exist and cite the equation.

For each row, every named object (a module, class, function or method) is imported and its own
docstring must cite the row's equation: "eq. (N)" or a range "eq. (A)-(B)" / "(A)-(B)" that
covers it, with the "seed 003" prefix where the row has one. A renamed or moved function, or a
docstring that lost its citation, fails here.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "docs" / "architecture.md").read_text()
ROW = re.compile(r"^\| (?P<equation>(?:seed \d{3} )?eq\. \(\d+\)(?:-\(\d+\))?) \| [^|]+ \| (?P<where>[^|]+) \|$", re.M)
NUMBERS = re.compile(r"\((\d+)[a-d]?\)(?:\s?-\s?\((\d+)[a-d]?\))?")


def _rows() -> list[tuple[str, str]]:
    return [(match["equation"], name) for match in ROW.finditer(README) for name in re.findall(r"`([\w.]+)`", match["where"])]


def _resolve(dotted: str):
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attribute in parts[cut:]:
            target = getattr(target, attribute)
        return target
    raise ImportError(dotted)


def _cited(docstring: str, equation: str) -> bool:
    numbers = [int(n) for n in re.findall(r"\d+", re.sub(r"^seed \d{3} ", "", equation))]
    wanted = set(range(numbers[0], numbers[-1] + 1))
    seed = equation[:8] if equation.startswith("seed") else ""
    found: set[int] = set()
    for citation in re.finditer(r"eqs?\.\s?" + NUMBERS.pattern + r"(?:,\s?" + NUMBERS.pattern + r")*", docstring):
        preceding = docstring[max(0, citation.start() - 9):citation.start()]
        if seed and seed not in preceding:
            continue
        for first, last in NUMBERS.findall(citation.group(0)):
            found.update(range(int(first), int(last or first) + 1))
    return wanted <= found


def test_the_table_is_there_and_covers_the_method():
    equations = {equation for equation, _ in _rows()}
    # the estimator, guidance, range controller and attitude mapping of sections IV, VI, VII
    assert {"eq. (6)", "eq. (14)", "eq. (15)-(19)", "eq. (21)-(22)"} <= equations


@pytest.mark.parametrize("equation, name", _rows())
def test_each_named_object_cites_its_equation(equation, name):
    target = _resolve(name)
    docstring = inspect.getdoc(target) or ""
    assert _cited(docstring, equation), f"{name} does not cite {equation}"


def test_the_generated_index_lists_every_object_of_the_table():
    """The generated reference page (docs/gen_reference.py) finds each citation the curated table relies on."""
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    cited = {(row["file"][:-3].replace("/", ".").removesuffix(".__init__")
              + (f".{row['object']}" if row["object"] else "")) for row in generator.equation_citations(ROOT)}
    missing = [name for _, name in _rows() if name not in cited]
    assert not missing, f"not in the generated equation index: {missing}"
