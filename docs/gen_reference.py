"""The reference pages built from the code: CLI help, the scenario schema, paper equations to functions.

Each ``*_page()`` returns one markdown page as a string; ``docs/hooks.py`` adds them to the site at build
time (``mkdocs build`` regenerates them every time, nothing is written into the tree), and
``python docs/gen_reference.py DIR`` writes them into DIR to read them without MkDocs.

* CLI: every console script of ``pyproject.toml`` ``[project.scripts]`` names ``module:main``; the
  module's ``build_parser()`` is the parser that ``main`` uses, and its ``format_help()`` is the page's
  text, as ``--help`` prints it.
* Scenario schema: the strict pydantic models of ``interfaces/scenario/``, walked from ``Scenario``
  (and ``VehicleConfig`` for a vehicle file): per TOML table, the class docstring, then each key's
  type with its bounds, its default and its description (the attribute docstring under the field, or
  the comment just above it).
* Equations: every ``eq. (N)`` / ``eqs. (A)-(B)`` cited in a docstring or comment of the four packages,
  with the function or class it sits in.
"""

from __future__ import annotations

import argparse
import ast
import html
import importlib
import os
import re
import sys
import tomllib
import types
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("companion", "interfaces", "sitl_plant", "studies")

#: Generated page -> builder; the paths are those of mkdocs.yml's nav.
PAGES = {
    "reference/cli.md": "cli_page",
    "reference/scenario-schema.md": "schema_page",
    "reference/equations.md": "equations_page",
}


def _cell(text: str) -> str:
    """One markdown table cell: no line breaks, no bare pipes or angle brackets."""
    return html.escape(" ".join(str(text).split()), quote=False).replace("|", "\\|").replace("*", "\\*")


# --- CLI ---------------------------------------------------------------------------------------------

def console_scripts() -> dict[str, str]:
    """Console script name -> "module:function", from pyproject.toml."""
    with open(ROOT / "pyproject.toml", "rb") as handle:
        return tomllib.load(handle)["project"]["scripts"]


def script_parser(target: str) -> argparse.ArgumentParser:
    module_name, _, _ = target.partition(":")
    module = importlib.import_module(module_name)
    return module.build_parser()


def script_help(name: str, target: str, width: int = 100) -> str:
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)  # argparse wraps at $COLUMNS: a fixed width for a stable page
    try:
        return script_parser(target).format_help()
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous


def cli_page() -> str:
    scripts = console_scripts()
    lines = ["# Command-line reference", "",
             "Generated at build time from each command's argument parser: the text below is what "
             "`COMMAND --help` prints. The commands are the console scripts that `pip install -e .` puts "
             "on the path.", "",
             "| command | entry point | what it does |", "|---|---|---|"]
    helps = {name: script_help(name, target) for name, target in scripts.items()}
    for name, target in scripts.items():
        description = script_parser(target).description or ""
        lines.append(f"| [`{name}`](#{name}) | `{target}` | {_cell(description)} |")
    for name, text in helps.items():
        lines += ["", f"## {name}", "", "```text", text.rstrip(), "```"]
    return "\n".join(lines) + "\n"


# --- scenario schema ---------------------------------------------------------------------------------

def _field_notes(source: str) -> dict[str, dict[str, str]]:
    """class name -> field name -> the attribute docstring under it, else the comment lines above it."""
    tree = ast.parse(source)
    lines = source.splitlines()
    notes: dict[str, dict[str, str]] = {}
    for node in ast.walk(tree):
        if not isinstance(node, ast.ClassDef):
            continue
        fields: dict[str, str] = {}
        body = node.body
        for index, statement in enumerate(body):
            if not (isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)):
                continue
            following = body[index + 1] if index + 1 < len(body) else None
            if (isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
                    and isinstance(following.value.value, str)):
                fields[statement.target.id] = following.value.value
                continue
            comment: list[str] = []
            row = statement.lineno - 2
            while row >= 0 and lines[row].strip().startswith("#"):
                comment.insert(0, lines[row].strip().lstrip("#").strip())
                row -= 1
            text = " ".join(comment)
            if text and not re.search(r"(?<![\w.])_[a-z]\w*", text):  # a note on the code itself is not for users
                fields[statement.target.id] = text
        notes[node.name] = fields
    return notes


def _is_model(kind) -> bool:
    from pydantic import BaseModel
    return isinstance(kind, type) and issubclass(kind, BaseModel)


def _bounds(metadata) -> str:
    words = {"gt": ">", "ge": ">=", "lt": "<", "le": "<=", "min_length": "length >=", "max_length": "length <="}
    found = []
    # A Field(...) inside Annotated (a tuple's items, an optional value) carries its bounds in its own metadata.
    metadata = [inner for item in metadata for inner in (getattr(item, "metadata", None) or [item])]
    for item in metadata:
        for attribute, word in words.items():
            value = getattr(item, attribute, None)
            if value is not None:
                found.append(f"{word} {value:g}" if isinstance(value, float) else f"{word} {value}")
    return ", ".join(found)


def _type_name(annotation, metadata=()) -> str:
    """A reader's name for a field's type, with its bounds: 'float (> 0)', "'hng' | 'ppg'", 'list of [...]'."""
    origin = typing.get_origin(annotation)
    arguments = typing.get_args(annotation)
    if origin is typing.Annotated:
        return _type_name(arguments[0], tuple(metadata) + tuple(annotation.__metadata__))
    bounds = _bounds(metadata)
    suffix = f" ({bounds})" if bounds else ""
    if origin is typing.Literal:
        return " \\| ".join(repr(value) for value in arguments) + suffix
    if origin in (typing.Union, types.UnionType):
        names = [_type_name(argument) for argument in arguments if argument is not type(None)]
        optional = " or none" if type(None) in arguments else ""
        return " \\| ".join(names) + optional + suffix
    if origin is tuple:
        if len(arguments) == 2 and arguments[1] is Ellipsis:
            return f"list of {_type_name(arguments[0])}" + suffix
        names = [_type_name(argument) for argument in arguments]
        if len(set(names)) == 1 and names[0].endswith(")") and " (" in names[0]:  # a vector: its items' bounds once
            item, _, item_bounds = names[0].partition(" (")
            extra = f"; {bounds}" if bounds else ""
            return "[" + ", ".join([item] * len(names)) + f"] (each {item_bounds[:-1]}{extra})"
        return "[" + ", ".join(names) + "]" + suffix
    if _is_model(annotation):
        return f"table ({annotation.__name__})"
    return getattr(annotation, "__name__", str(annotation)) + suffix


def _default(field) -> str:
    from pydantic_core import PydanticUndefined
    if field.is_required():
        return "required"
    value = field.default_factory() if field.default is PydanticUndefined and field.default_factory else field.default
    if _is_model(type(value)):
        return "(table)"
    if isinstance(value, tuple):
        return "[" + ", ".join(_default_value(item) for item in value) + "]"
    return _default_value(value)


def _default_value(value) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return f"{value:g}" if abs(value) < 1e6 or value == float("inf") else repr(value)
    if _is_model(type(value)):
        return "{...}"
    return str(value)


def _sub_models(annotation) -> list[type]:
    """The pydantic models a field's type holds (directly, optional, in a list, or a tagged union)."""
    if _is_model(annotation):
        return [annotation]
    found: list[type] = []
    for argument in typing.get_args(annotation):
        if argument is not type(None) and argument is not Ellipsis:
            found += _sub_models(argument)
    return found


def _is_array(annotation) -> bool:
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _is_array(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return any(_is_array(argument) for argument in typing.get_args(annotation))
    return origin is tuple and len(typing.get_args(annotation)) == 2 and typing.get_args(annotation)[1] is Ellipsis


def _section(model, table: str, notes: dict, seen: set, out: list[str]) -> None:
    key = (model, table)
    if key in seen:
        return
    seen.add(key)
    title = f"`{table.split(' ')[0]}`" + (f" ({model.__name__})" if not table.startswith(model.__name__) else "")
    out += ["", f"## {title}", ""]
    doc = model.__doc__
    from pydantic import BaseModel
    if doc and doc != BaseModel.__doc__ and not doc.startswith("Every section: unknown keys refused"):
        paragraphs = [" ".join(part.split()) for part in re.split(r"\n\s*\n", doc.strip())]
        out += [html.escape(paragraph, quote=False).replace("*", "\\*") + "\n" for paragraph in paragraphs]
    out += ["| key | type | default | description |", "|---|---|---|---|"]
    children = []
    own_notes = {}
    for klass in reversed(model.__mro__):
        own_notes.update(notes.get(klass.__name__, {}))
    for name, field in model.model_fields.items():
        description = field.description or own_notes.get(name, "")
        out.append(f"| `{name}` | {_type_name(field.annotation, field.metadata)} | {_cell(_default(field))} | "
                   f"{_cell(description)} |")
        for sub in _sub_models(field.annotation):
            children.append((sub, name, _is_array(field.annotation)))
    prefix = table.split(" ")[0].strip("[]")
    prefix = "" if prefix == "Scenario" else prefix + "."
    for sub, name, array in children:
        child = f"[[{prefix}{name}]]" if array else f"[{prefix}{name}]"
        if len([c for c in children if c[1] == name]) > 1:
            child += f" {sub.__name__}"
        _section(sub, child, notes, seen, out)


def schema_page() -> str:
    scenario = importlib.import_module("interfaces.scenario")
    notes = _field_notes(Path(scenario.__file__).read_text())
    out = ["# Scenario schema", "",
           "Generated at build time from the pydantic models in `interfaces/scenario/`, which every "
           "command uses to read a scenario file. Every table is strict: an unknown key, a wrong type "
           "(the string `\"12\"` is not the number 12; an integer is accepted for a float), NaN or inf is "
           "refused with a message that names the file and the key. Units are SI (m, s, rad unless a key "
           "says `_deg`); positions and velocities are local NED. Bounds are given with each type; the "
           "checks across keys are in the class docstrings and in `Scenario`'s validators.", "",
           "A scenario file's top level is `Scenario`; its `vehicle` key names a shipped airframe "
           "(`\"paper_table1\"`: `config/vehicles/paper_table1.toml`) or a vehicle file by its path "
           "(relative to the scenario), whose keys are those of the last section, `VehicleConfig`; "
           "a key it leaves out takes the paper's Table I value from `config/vehicles/paper_table1.toml`."]
    seen: set = set()
    out_sections: list[str] = []
    _section(scenario.Scenario, "Scenario", notes, seen, out_sections)
    # The top level's keys are tables, except for name, description and vehicle.
    out_sections[1] = "## Top level (Scenario)"
    _section(scenario.VehicleConfig, "VehicleConfig", notes, seen, out_sections)
    out_sections[out_sections.index("## `VehicleConfig`")] = "## Vehicle file (VehicleConfig)"
    return "\n".join(out + out_sections) + "\n"


# --- paper equations to functions --------------------------------------------------------------------

_NUMBER = r"\((\d+)[a-d]?\)(?:\s?-\s?\((\d+)[a-d]?\))?"
CITATION = re.compile(r"(?P<seed>seed \d{3} )?eqs?\.\s?(?P<numbers>" + _NUMBER + r"(?:(?:,\s?|\s(?:and|to)\s)" + _NUMBER + r")*)")


def _enclosing(tree: ast.AST) -> list[tuple[int, int, str]]:
    """(first line, last line, dotted name) of every class and function, outermost first."""
    spans: list[tuple[int, int, str]] = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}.{child.name}" if prefix else child.name
                spans.append((child.lineno, child.end_lineno, name))
                visit(child, name)
            else:
                visit(child, prefix)

    visit(tree, "")
    return spans


def _compiled_aliases(tree: ast.Module) -> dict[str, list[str]]:
    """function name -> the module-level names bound to it compiled, as in `_kernel = jit(_function)`."""
    aliases: dict[str, list[str]] = {}
    for node in tree.body:
        if (isinstance(node, ast.Assign) and isinstance(node.value, ast.Call) and node.value.args
                and isinstance(node.value.args[0], ast.Name)):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    aliases.setdefault(node.value.args[0].id, []).append(target.id)
    return aliases


def equation_citations(root: Path = ROOT) -> list[dict]:
    """Every equation cited in the packages' source: equation label, file, line, object ('' = module).

    A function compiled under another name (`_kernel = jit(_function)`) is listed under both names."""
    rows = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            source = path.read_text()
            tree = ast.parse(source)
            spans = _enclosing(tree)
            aliases = _compiled_aliases(tree)
            for number, line in enumerate(source.splitlines(), start=1):
                for match in CITATION.finditer(line):
                    inner = [name for first, last, name in spans if first <= number <= last]
                    owner = inner[-1] if inner else ""
                    for first, last in re.findall(_NUMBER, match["numbers"]):
                        label = f"eq. ({first})" + (f"-({last})" if last else "")
                        for name in [owner] + aliases.get(owner, []):
                            rows.append({"paper": (match["seed"] or "").strip() or "the paper",
                                         "equation": label, "first": int(first),
                                         "file": path.relative_to(root).as_posix(), "line": number,
                                         "object": name})
    return rows


def equations_page() -> str:
    rows = equation_citations()
    out = ["# Paper equations in the code", "",
           "Generated at build time: every equation number cited in a docstring or comment of "
           "`companion/`, `interfaces/`, `sitl_plant/` and `studies/`, with the function, method or "
           "class it sits in (a blank object is the module itself). Equation numbers are those of "
           "Li et al., IEEE T-RO 2023, unless a seed paper is named (seed 002, 003, 004: the "
           "comparison papers listed on the home page). The curated table of the method's equations "
           "and where each is implemented is in [Architecture](../architecture.md#paper-equations-in-the-code)."]
    papers = sorted({row["paper"] for row in rows}, key=lambda paper: (paper != "the paper", paper))
    for paper in papers:
        chosen = sorted((row for row in rows if row["paper"] == paper),
                        key=lambda row: (row["first"], row["equation"], row["file"], row["line"]))
        out += ["", f"## {'Li et al. 2023' if paper == 'the paper' else paper.capitalize()}", "",
                "| equation | object | where |", "|---|---|---|"]
        listed = set()
        for row in chosen:
            module = row["file"][:-3].replace("/", ".").removesuffix(".__init__")
            key = (row["equation"], module, row["object"])
            if key in listed:
                continue
            listed.add(key)
            name = f"{module}.{row['object']}" if row["object"] else module
            out.append(f"| {row['equation']} | `{name}` | `{row['file']}:{row['line']}` |")
    return "\n".join(out) + "\n"


def build(name: str) -> str:
    return globals()[PAGES[name]]()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write the generated reference pages into a folder.")
    parser.add_argument("out", type=Path, help="folder to write reference/*.md into")
    args = parser.parse_args(argv)
    for name in PAGES:
        target = args.out / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(build(name))
        print(target)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main())
