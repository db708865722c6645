"""The companion's console log: the lines it writes while it runs, each stamped with ISO-8601 UTC time.

    2026-12-02T13:45:01.234Z companion ready: constant_velocity, vehicle udpin://127.0.0.1:14540, log runs/...
    2026-12-02T13:45:01.301Z mavsdk info: MAVSDK version: v4.1.0 (mavsdk_impl.cpp:58)
    2026-12-02T13:45:03.912Z companion: following engaged at t=53.22 s

`configure_console()` (once, in `companion`'s main) sends the "companion" logger's records to stdout (warnings and
errors to stderr) in that form; `say(line)` writes one. No line carries terminal escapes: the run folder's
companion.out is read in editors and grepped, and a status text relayed from the vehicle is not allowed to drive
the reader's terminal. Command-line and configuration errors before the start stay plain one-line messages.
"""

from __future__ import annotations

import datetime as dt
import logging
import re
import sys

LOG = logging.getLogger("companion")
#: An ANSI/VT100 control sequence (colours, cursor moves): ESC [ parameters final-letter.
TERMINAL_ESCAPE = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
#: Any other control character but tab and newline (a lone ESC, BEL, carriage return, DEL).
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")


def without_terminal_escapes(text: str) -> str:
    """`text` without its ANSI control sequences and other control characters (tab and newline kept)."""
    return _CONTROL.sub("", TERMINAL_ESCAPE.sub("", text))


def utc_stamp(seconds: float) -> str:
    """POSIX time `seconds` as ISO-8601 UTC to the millisecond, e.g. 2026-12-02T13:45:01.234Z."""
    moment = dt.datetime.fromtimestamp(seconds, dt.timezone.utc)
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


class ConsoleFormatter(logging.Formatter):
    """A record as `<ISO-8601 UTC stamp> <message>`, terminal escapes removed (a traceback follows on its lines)."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.exc_info:
            text = f"{text}\n{self.formatException(record.exc_info)}"
        return f"{utc_stamp(record.created)} {without_terminal_escapes(text)}"


class _ConsoleHandler(logging.Handler):
    """To the process's current stdout (stderr from WARNING up), looked up at every line, flushed at once: the
    owner of a child companion reads its output file as it grows."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            stream = sys.stderr if record.levelno >= logging.WARNING else sys.stdout
            stream.write(self.format(record) + "\n")
            stream.flush()
        except Exception:  # noqa: BLE001  (logging's own contract: a failed line never raises into the caller)
            self.handleError(record)


def configure_console() -> logging.Logger:
    """Give the "companion" logger its console handler and formatter (once per process; later calls change
    nothing) and return it."""
    if not any(isinstance(handler, _ConsoleHandler) for handler in LOG.handlers):
        handler = _ConsoleHandler()
        handler.setFormatter(ConsoleFormatter())
        LOG.addHandler(handler)
        LOG.setLevel(logging.DEBUG)
        LOG.propagate = False
    return LOG


def say(line: str) -> None:
    """One line of the companion's console log (INFO)."""
    LOG.info(line)
