"""MAVSDK's own messages through the companion's console log, instead of MAVSDK's default console output.

By default MAVSDK prints each message to stdout with ANSI colour codes and a local 12-hour clock
("\\x1b[34m[02:05:12|Info ] \\x1b[0mMAVSDK version: v4.1.0 (mavsdk_impl.cpp:58)"), which has no option to turn the
colours off. MAVSDK's log callback takes the messages instead: each becomes one record of the companion's logger,
stamped and filtered like the companion's own lines (companion.console):

    2026-12-02T13:45:01.301Z mavsdk info: MAVSDK version: v4.1.0 (mavsdk_impl.cpp:58)
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

from mavsdk.logging import LogLevel, log_subscribe, log_unsubscribe

#: MAVSDK's levels as logging's.
LEVELS = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO, LogLevel.WARN: logging.WARNING,
          LogLevel.ERROR: logging.ERROR}


def mavsdk_message(level: LogLevel, message: str, file: str | None, line: int) -> tuple[int, str]:
    """One MAVSDK message as (logging level, text): "mavsdk <level>: <message> (<file>:<line>)"."""
    where = f" ({file}:{line})" if file else ""
    return LEVELS.get(level, logging.INFO), f"mavsdk {level.name.lower()}: {message}{where}"


@contextlib.contextmanager
def mavsdk_log_to(logger: logging.Logger) -> Iterator[None]:
    """Within the block, every MAVSDK message goes to `logger` and MAVSDK prints nothing itself."""

    def forward(level: LogLevel, message: str, file: str | None, line: int) -> bool:
        logger.log(*mavsdk_message(level, message, file, line))
        return True  # handled: MAVSDK's default (coloured) output is skipped

    log_subscribe(forward)
    try:
        yield
    finally:
        log_unsubscribe()
