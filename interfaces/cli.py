"""The parser and the argparse types every command shares (the companion, the plant's tools and the studies).

    parser = CommandParser(prog="bof-sim", description=...)  # every console script's parser
    parser.add_argument("config", type=scenario_file)    # an existing scenario file, as a Path
    parser.add_argument("--seed", type=seed_argument)     # an integer >= 0

Each type raises argparse.ArgumentTypeError, which argparse turns into one usage line and exit status 2.
"""

from __future__ import annotations

import argparse
import difflib
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from interfaces.scenario import MAX_SPEED_FACTOR, MIN_SPEED_FACTOR


#: The --speed-factor bounds of every command (sitl-plant, bof-sitl; bof-campaign's --sitl-speed), simulated s per
#: wall s: those of the scenario's [sitl] speed_factor (below 0.5 MAVSDK's heartbeats time out, above 20 the plant
#: falls behind).
SPEED_FACTOR_BOUNDS = (MIN_SPEED_FACTOR, MAX_SPEED_FACTOR)
#: The same bounds as the help texts and the error say them.
SPEED_FACTOR_RANGE = f"[{MIN_SPEED_FACTOR:g}, {MAX_SPEED_FACTOR:g}]"


class CommandParser(argparse.ArgumentParser):
    """The argument parser of every console script: argparse without prefix abbreviations, naming a misspelt option.

    `bof-sitl --sped-factor 5` is "unrecognized option --sped-factor (did you mean --speed-factor?)", exit status 2.
    Plain argparse would take an unambiguous prefix (--speed) for the option it starts, and, since it type-checks
    positionals before it reports unknown options, blamed the misspelt option's value on the positional argument
    ("argument config: 5: no such file"). Keyword arguments are argparse.ArgumentParser's; allow_abbrev is False.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs, allow_abbrev=False)

    def parse_args(self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None):
        arguments = sys.argv[1:] if args is None else list(args)
        unknown = self.unknown_long_option(arguments)
        if unknown is not None:
            self.error(unknown)
        return super().parse_args(arguments, namespace)

    def unknown_long_option(self, arguments: Sequence[str]) -> str | None:
        """The error for the first --option in `arguments` that this parser does not have (None: all known).

        Everything after a bare `--` is positional, as argparse reads it; `--name=value` is the option --name.
        """
        known = [option for action in self._actions for option in action.option_strings if option.startswith("--")]
        for argument in arguments:
            if argument == "--":
                return None
            if not argument.startswith("--"):
                continue
            name = argument.split("=", 1)[0]
            if name in known:
                continue
            completions = [option for option in known if option.startswith(name)]
            guesses = completions if len(completions) == 1 else difflib.get_close_matches(name, known, n=1)
            return f"unrecognized option {name}" + (f" (did you mean {guesses[0]}?)" if guesses else "")
        return None


def scenario_file(text: str) -> Path:
    """argparse type: an existing scenario file (not a folder, not a missing path)."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder; give one scenario file, e.g. {text.rstrip('/')}/constant_velocity.toml")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    return path


def output_folder(text: str) -> Path:
    """argparse type: a folder to write into, existing or to be made (--out, --log-dir). Refuses, before anything
    runs, a path that exists and is not a folder, or whose nearest existing parent is not one: such a run used to
    end in a traceback when it wrote its results (after the whole flight, for bof-sim)."""
    path = Path(text)
    for where in (path, *path.parents):
        if where.exists():
            if not where.is_dir():
                raise argparse.ArgumentTypeError(f"{text}: {where} exists and is not a folder")
            break
    return path


def seed_argument(text: str) -> int:
    """argparse type: a seed for numpy's SeedSequence, an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative (seeds are integers >= 0)")
    return value


#: Foxglove's default WebSocket port (what its "Open connection" dialog proposes): a live view's port when
#: --live is given without one.
LIVE_PORT = 8765


def live_port(text: str) -> int:
    """argparse type of --live: a TCP port 0..65535 (0: any free port)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{value} is outside 0..65535")
    return value


def speed_factor_argument(text: str) -> float:
    """argparse type: a speed factor, simulated seconds per wall second, within SPEED_FACTOR_BOUNDS ([0.5, 20])."""
    low, high = SPEED_FACTOR_BOUNDS
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not low <= value <= high:  # also refuses nan
        raise argparse.ArgumentTypeError(f"{text} is outside {SPEED_FACTOR_RANGE} (simulated seconds per wall second: "
                                         f"MAVSDK needs heartbeats, the plant tops out near {high:g}x)")
    return value


def add_zenoh_security_arguments(parser: argparse.ArgumentParser, role: str) -> None:
    """--zenoh-tls DIR and --zenoh-namespace NAME, as every Zenoh process of the project takes them.

    role: the process's identity in a bof-certs folder (plant, target, companion): its certificate
    and key are DIR/<role>.pem and DIR/<role>.key (interfaces.zenoh_transport.tls_identity).
    """
    parser.add_argument("--zenoh-tls", type=Path, default=None, metavar="DIR",
                        help=f"mutual TLS and access control on Zenoh as role '{role}', with DIR/ca.pem, DIR/{role}.pem, "
                             f"DIR/{role}.key (made by bof-certs; endpoints then tls/...). Default: plain TCP, "
                             "unauthenticated")
    parser.add_argument("--zenoh-namespace", default=None, metavar="NAME",
                        help="Zenoh session namespace: every key is prefixed with it on the wire, so runs with different "
                             "namespaces never hear each other (isolation, not authentication). Default: none")
