"""Every console script's command line: a misspelt option is named as such, never blamed on a positional; one
speed-factor range."""

from __future__ import annotations

import contextlib
import importlib
import io
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def _parser(command: str):
    module, _ = SCRIPTS[command].split(":")
    return importlib.import_module(module).build_parser()


PARSERS = {command: _parser(command) for command in sorted(SCRIPTS)}


def _long_options(parser) -> list[str]:
    return sorted(option for action in parser._actions for option in action.option_strings if option.startswith("--"))


def _parse(command: str, arguments: list[str]) -> tuple[int, str]:
    """Exit status and stderr of `command arguments` when its parser refuses them."""
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), pytest.raises(SystemExit) as exit_:
        PARSERS[command].parse_args(arguments)
    return exit_.value.code, stderr.getvalue()


def _misspelt(option: str, where: int, swap: bool) -> str:
    """`option` with one character of its name deleted (swap False) or swapped with the next one (swap True)."""
    name = option[2:]
    where %= len(name) - 1 if swap else len(name)
    if swap:
        name = name[:where] + name[where + 1] + name[where] + name[where + 2:]
    else:
        name = name[:where] + name[where + 1:]
    return "--" + name


@pytest.mark.parametrize("command, arguments, message", [
    ("bof-sitl", ["--sped-factor", "5"], "unrecognized option --sped-factor (did you mean --speed-factor?)"),
    ("bof-sim", ["--sed", "3"], "unrecognized option --sed (did you mean --seed?)"),
    ("bof-sitl", ["--speed", "5"], "unrecognized option --speed (did you mean --speed-factor?)"),  # no abbreviations
    ("bof-certs", ["--role", "plant", "pki"], "unrecognized option --role (did you mean --roles?)"),
    ("bof-sim", ["--sede=3"], "unrecognized option --sede (did you mean --seed?)"),
    ("bof-montecarlo", ["--zzzzzz"], "unrecognized option --zzzzzz"),
])
def test_a_misspelt_option_is_named_with_the_nearest_real_one(command, arguments, message):
    code, stderr = _parse(command, arguments)
    assert code == 2
    assert stderr.strip().splitlines()[-1] == f"{command}: error: {message}"


def test_after_a_bare_double_dash_everything_is_positional():
    code, stderr = _parse("bof-sim", ["--", "--sed"])
    assert code == 2
    assert stderr.strip().splitlines()[-1] == "bof-sim: error: argument scenario: --sed: no such file"


def test_every_command_takes_no_abbreviation():
    for command, parser in PARSERS.items():
        assert parser.allow_abbrev is False, command


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_every_one_character_slip_of_a_real_option_is_reported_as_that_slip(data):
    command = data.draw(st.sampled_from(sorted(PARSERS)), label="command")
    options = _long_options(PARSERS[command])
    option = data.draw(st.sampled_from(options), label="option")
    swap = data.draw(st.booleans(), label="swap")
    typo = _misspelt(option, data.draw(st.integers(0, 100), label="where"), swap)
    assume(typo not in options and len(typo) > 2)
    code, stderr = _parse(command, [typo, "5", "other"])
    assert code == 2
    last = stderr.strip().splitlines()[-1]
    assert last.startswith(f"{command}: error: unrecognized option {typo}"), last
    assert "argument " not in last  # no positional (nor another option) takes the blame


def test_the_installed_command_says_so_in_one_usage_error(tmp_path):
    done = subprocess.run([sys.executable, "-m", "studies.full_sitl", "--sped-factor", "5"], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == ("bof-sitl: error: unrecognized option --sped-factor "
                                                    "(did you mean --speed-factor?)")
    assert list(tmp_path.iterdir()) == []


#: Every option that sets the SITL's speed factor, simulated seconds per wall second.
SPEED_OPTIONS = [("sitl-plant", "--speed-factor"), ("bof-sitl", "--speed-factor"), ("bof-campaign", "--sitl-speed")]


def test_the_speed_options_are_all_the_commands_have():
    found = [(command, option) for command, parser in PARSERS.items() for option in _long_options(parser)
             if "speed" in option]
    assert sorted(found) == sorted(SPEED_OPTIONS)


@pytest.mark.parametrize("command, option", SPEED_OPTIONS)
def test_every_speed_factor_is_within_one_range(command, option):
    for refused in ("0.4", "21", "0", "nan", "100"):
        code, stderr = _parse(command, [option, refused])
        assert code == 2
        assert stderr.strip().splitlines()[-1].startswith(
            f"{command}: error: argument {option}: {refused} is outside [0.5, 20]"), stderr
    for accepted in ("0.5", "20", "5"):
        assert getattr(PARSERS[command].parse_args([option, accepted]), option[2:].replace("-", "_")) == float(accepted)
    help_text = " ".join(PARSERS[command].format_help().split())
    assert "within [0.5, 20]" in help_text
