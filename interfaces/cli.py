"""argparse types every command shares (the companion, the plant's tools and the studies).

    parser.add_argument("config", type=scenario_file)    # an existing scenario file, as a Path
    parser.add_argument("--seed", type=seed_argument)     # an integer >= 0

Each raises argparse.ArgumentTypeError, which argparse turns into one usage line and exit status 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from interfaces.scenario import MAX_SPEED_FACTOR, MIN_SPEED_FACTOR


#: bof-sitl's --speed-factor (and bof-campaign's --sitl-speed) bounds, simulated s per wall s: those of the
#: scenario's [sitl] speed_factor (below 0.5 MAVSDK's heartbeats time out, above 20 the plant falls behind).
SPEED_FACTOR_BOUNDS = (MIN_SPEED_FACTOR, MAX_SPEED_FACTOR)


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
