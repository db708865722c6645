"""The one `section.key=value` override mechanism for scenario files and their sections.

Every command that lets a user change a setting without editing a file goes through here:
`sitl-target --fault KEY=VALUE` ([faults] keys), `bof-montecarlo --case NAME:key=value,...`
(scenario keys) and the studies' preset grids and fault patterns (dicts of dotted keys).

    key, value = parse_assignment("guidance.c_y=0", "--case")      # ("guidance.c_y", 0)
    scenario = apply_overrides(scenario, {key: value}, "--case")    # a new, fully validated Scenario
    format_assignment("blackouts", [{"start": 20.0, "duration": 5.0}])  # 'blackouts=[{start = 20.0, ...}]'

VALUE is a TOML value (read by `tomllib`): numbers, 'quoted strings', true/false, arrays,
inline tables. KEY is a dotted path into nested sections; a table given whole replaces the
table, a dotted key changes one entry and keeps the rest. The result is the model's own
validation of the merged document (`model_validate`), so a bad value gets the schema's
message and an unknown key is refused ("unknown key (check the spelling)").
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from interfaces.scenario import ConfigError, describe_errors

Model = TypeVar("Model", bound=BaseModel)
_PART = re.compile(r"[A-Za-z0-9_-]+")


def parse_assignment(text: str, context: str, example: str = "") -> tuple[str, Any]:
    """'section.key=value' -> ("section.key", value), value read as a TOML value.

    context: how the user gave it, for messages ("--fault"); example: a valid assignment shown when
    `text` is malformed. ConfigError "<context> ...: expected KEY=VALUE" or "... is not a TOML value".
    """
    key, separator, literal = text.partition("=")
    key, literal = key.strip(), literal.strip()
    if not separator or not literal or not all(_PART.fullmatch(part) for part in key.split(".")):
        hint = f", e.g. {example}" if example else ""
        raise ConfigError(f"{context} {text!r}: expected KEY=VALUE{hint}")
    try:
        value = tomllib.loads(f"value = {literal}")["value"]
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{context} {key}: {literal!r} is not a TOML value ({error}; quote strings)") from None
    except (RecursionError, ValueError):  # arrays nested too deeply, an integer over Python's 4300 digits
        raise ConfigError(f"{context} {key}: the value is not a TOML value Python can read (nested too deeply or "
                          "an integer too long)") from None
    return key, value


def apply_overrides(model: Model, overrides: Mapping[str, Any] | Iterable[tuple[str, Any]], context: str,
                    root: str = "") -> Model:
    """A new `model` (pydantic) with the dotted-key `overrides` merged into its data and re-validated.

    overrides: "section.key" -> value, or (key, value) pairs applied in order (a dict value replaces
    the whole table, a later key wins over an earlier one). context: prefix of the
    messages ("--fault"); root: the model's own section name, prepended to keys in messages ("faults").
    ConfigError naming every bad key, with the schema's message; `model` itself is untouched.
    """
    document = model.model_dump()
    for key, value in overrides.items() if isinstance(overrides, Mapping) else overrides:
        path = key.split(".")
        table = document
        for depth, part in enumerate(path[:-1]):
            if table.get(part) is None:
                table[part] = {}  # an absent optional table; validation says if it may not be there
            if not isinstance(table[part], dict):
                raise ConfigError(f"{context} {key}: {_dotted(root, *path[:depth + 1])} is not a table")
            table = table[part]
        table[path[-1]] = value
    try:
        return type(model).model_validate(document)
    except ValidationError as error:
        raise ConfigError(f"{context}: " + "; ".join(describe_errors(error, root))) from None


def format_assignment(key: str, value: Any) -> str:
    """The inverse of `parse_assignment`: "key=<value as a TOML literal>" (numbers, strings, booleans,
    lists, dicts as inline tables). ValueError for values TOML cannot hold (None, objects)."""
    return f"{key}={_toml_literal(value)}"


def _toml_literal(value: Any) -> str:
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{name} = {_toml_literal(item)}" for name, item in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_literal(item) for item in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):  # a TOML basic string: quote, backslash and control characters as \uXXXX
        return '"' + "".join(f"\\u{ord(c):04x}" if c in '"\\' or ord(c) < 0x20 or ord(c) == 0x7F else c for c in value) + '"'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else ("inf" if value > 0 else "-inf"))
    raise ValueError(f"{value!r} has no TOML literal")


def _dotted(*parts: Any) -> str:
    return ".".join(str(part) for part in parts if str(part))
