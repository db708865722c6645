"""The repository's config folder and the bounded file reads every loader goes through."""

from __future__ import annotations

import os
import stat
import sys
import tomllib
from pathlib import Path

from interfaces.scenario.common import ConfigError


#: The repository's config folder: airframes in vehicles/, flights in scenarios/.
CONFIG_DIR = Path(__file__).resolve().parent.parent.parent / "config"
SCENARIOS_DIR = CONFIG_DIR / "scenarios"
VEHICLES_DIR = CONFIG_DIR / "vehicles"
#: The paper's section VIII-A1 constant-velocity flight, every command's default.
DEFAULT_SCENARIO = SCENARIOS_DIR / "constant_velocity.toml"


#: The largest scenario or vehicle file read, bytes: 16 MiB. The shipped files are under 5 kB and a scenario with a
#: 100,000-entry maneuvers list is about 8 MB (it loads); anything bigger is not a configuration, and without a cap a
#: huge or growing file would be read into memory whole.
MAX_CONFIG_BYTES = 16 * 1024 * 1024


def read_regular_file(path: Path, limit: int, noun: str = "configuration file") -> bytes:
    """The bytes of `path`, a readable regular file (not a directory, device or pipe: /dev/zero never ends, a FIFO
    blocks) of at most `limit` bytes; else ConfigError, one line naming the file. noun: what the file should be,
    for the messages."""
    try:
        # O_NONBLOCK: opening a FIFO must not wait for a writer (it is refused just below, after fstat, which
        # also judges the file actually opened); it changes nothing for a regular file.
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except PermissionError:
        raise ConfigError(f"{path}: cannot be read: permission denied") from None
    except (OSError, ValueError) as error:  # ValueError: a NUL byte in the path
        raise ConfigError(f"{path}: cannot be read: {getattr(error, 'strerror', None) or error}") from None
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise ConfigError(f"{path}: not a regular file (a directory, device or pipe is no {noun})")
        with os.fdopen(descriptor, "rb", closefd=False) as handle:
            data = handle.read(limit + 1)
    except OSError as error:
        raise ConfigError(f"{path}: cannot be read: {error.strerror or error}") from None
    finally:
        os.close(descriptor)
    if len(data) > limit:
        raise ConfigError(f"{path}: larger than {limit // 2**20} MiB, too large for a {noun}")
    return data


def _read_toml(path: Path) -> dict:
    """The TOML document in `path`. ConfigError, one line naming the file, unless it is a readable regular file
    of at most MAX_CONFIG_BYTES bytes (read_regular_file) of UTF-8 TOML that tomllib can read (no nesting deeper
    than Python's recursion limit, no integer literal longer than Python's 4300 digits)."""
    data = read_regular_file(path, MAX_CONFIG_BYTES)
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not UTF-8 text (byte {data[error.start]:#04x} at offset {error.start}); "
                          "TOML files are UTF-8") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML: arrays or inline tables nested too deeply") from None
    except ValueError as error:  # an integer literal over Python's int_max_str_digits
        reason = (f"an integer literal has more than {sys.get_int_max_str_digits()} digits" if "digits" in str(error)
                  else str(error).splitlines()[0])
        raise ConfigError(f"{path}: not valid TOML: {reason}") from None
