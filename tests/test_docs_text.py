"""Product text describes the product as it is: no issue numbers, commit hashes or work-session talk.

History belongs in CHANGELOG.md and the git log. This test reads README.md, every markdown page under
docs/, and the comments and string literals (docstrings, help texts, messages) of every .py file under
companion/ interfaces/ sitl_plant/ studies/ tests/ benchmarks/ docs/, and fails naming file:line for:

* an issue number: the word issue (or issues) followed by a number, or a number after a hash sign, in prose;
* a commit hash: 7 to 40 hex digits, at least one a-f letter and one digit, in backticks, in parentheses or
  after "commit", "main", "at", "of", "since", "before" or "after" (hex constants in code are code, not text, and
  are not read);
* work-session talk: a working session called a stop (this, the last, the previous one), the time an issue was
  filed, or an issue spoken of as the current one.

The examples below are built from their words (`_words`), so that this file's own text never reads as history.

`BOF_DOCS_TEXT_ROOT=/path/to/checkout` points the test at another tree (to check that it finds the
references of an older one).
"""

from __future__ import annotations

import io
import os
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(os.environ.get("BOF_DOCS_TEXT_ROOT", Path(__file__).resolve().parent.parent))
PY_PACKAGES = ("companion", "interfaces", "sitl_plant", "studies", "tests", "benchmarks", "docs")

HEX = r"(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}"
PATTERNS = {
    "issue number": re.compile(r"\bissues?[ -]#?\d+\b", re.IGNORECASE),
    "issue reference #N": re.compile(r"(?<![\w&/#])#\d{1,3}\b"),
    "commit hash": re.compile(r"`" + HEX + r"`|\b(?:commit|main|at|of|since|before|after)\s+" + HEX + r"\b|\("
                              + HEX + r"\)"),
    "work-session talk": re.compile(r"\b(?:this|last|previous|second)\s+stop\b|\bat\s+filing\b|\bwas\s+filed\b"
                                    r"|\b(?:the|this)\s+issue's\b|\bthis\s+issue\b", re.IGNORECASE),
}

#: (file, text) pairs allowed on purpose, each with its reason. Keep it empty unless a test asserts on
#: such text or a format requires it.
ALLOWED: dict[tuple[str, str], str] = {}

#: This file names, in its docstring and its pattern tests, exactly what it refuses.
SELF = "tests/test_docs_text.py"


def _allowed(relative: str, line: str) -> bool:
    return any(relative == file and text in line for file, text in ALLOWED)


def _markdown_files(root: Path) -> list[Path]:
    files = [root / "README.md"] if (root / "README.md").exists() else []
    return files + sorted((root / "docs").rglob("*.md")) if (root / "docs").is_dir() else files


def _python_files(root: Path) -> list[Path]:
    return [path for package in PY_PACKAGES if (root / package).is_dir()
            for path in sorted((root / package).rglob("*.py")) if ".venv" not in path.parts]


def _text_lines(path: Path):
    """(line number, text) of the prose in a file: every line of markdown; a .py file's comments and strings."""
    source = path.read_text(encoding="utf-8")
    if path.suffix == ".md":
        yield from enumerate(source.splitlines(), start=1)
        return
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type in (tokenize.COMMENT, tokenize.STRING) or token.type == getattr(tokenize, "FSTRING_MIDDLE", -1):
            for offset, text in enumerate(token.string.splitlines()):
                yield token.start[0] + offset, text


def findings(root: Path = ROOT) -> list[str]:
    found = []
    for path in _markdown_files(root) + _python_files(root):
        relative = path.relative_to(root).as_posix()
        if relative == SELF:
            continue
        for number, line in _text_lines(path):
            for what, pattern in PATTERNS.items():
                match = pattern.search(line)
                if match and not _allowed(relative, line):
                    found.append(f"{relative}:{number}: {what}: {match.group(0)!r} in {line.strip()[:120]!r}")
    return found


def _words(*words: object) -> str:
    """The words joined by single spaces: an example sentence of the tests below."""
    return " ".join(str(word) for word in words)


def test_the_patterns_catch_what_they_are_for():
    caught = [_words("the share link", "(issue", "15)"), _words("see", "#" + "16", "for that"),
              _words("measured at", "`b5cc" + "200`"), _words("as of commit", "1c852" + "b6"),
              _words("the reference is its code at", "1c852" + "b6"), _words("simulate_swarm of", "1c852" + "b6"),
              _words("the code at the start of this", "stop"), _words("about 25 min at", "filing"),
              _words("when issue", 13, "was", "filed"), _words("the", "issue's", "targets"),
              _words("the fixes of this", "issue")]
    left = ["PKCS#8 keys", "a 0x7f mask", "seed 004 eq. (21)", "`deadbeef` is no hash (no digit)",
            "`1234567` is a number", "the stop signal", "issued 10 commands", "a namespace of bof-sitl-0a1b2c3d"]
    for text in caught:
        assert any(pattern.search(text) for pattern in PATTERNS.values()), text
    for text in left:
        assert not any(pattern.search(text) for pattern in PATTERNS.values()), text


def test_product_text_names_no_issue_commit_or_work_session():
    if not (ROOT / "README.md").exists():
        pytest.fail(f"no README.md under {ROOT}")
    found = findings()
    assert not found, "history in product text (move it to CHANGELOG.md):\n" + "\n".join(found)
