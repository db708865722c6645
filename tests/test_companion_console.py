"""The companion's console output (companion.out in a bof-sitl run): ISO-8601 UTC stamps, no terminal escapes."""

from __future__ import annotations

import asyncio
import datetime as dt
import logging
import re
import socket
import sys

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

from companion.adapters.mavsdk_log import mavsdk_log_to
from companion.console import ConsoleFormatter, without_terminal_escapes
from studies.processes import ChildProcess, free_port

STAMP = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z")


def _utc(stamp: str) -> dt.datetime:
    assert STAMP.fullmatch(stamp), stamp
    moment = dt.datetime.fromisoformat(stamp)
    assert moment.utcoffset() == dt.timedelta(0), stamp
    return moment


class _Kept(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def test_terminal_escapes_are_taken_out_and_the_text_kept():
    mavsdk_default = "\x1b[34m[02:05:12|Info ] \x1b[0mMAVSDK version: v4.1.0 (mavsdk_impl.cpp:58)"
    assert without_terminal_escapes(mavsdk_default) == "[02:05:12|Info ] MAVSDK version: v4.1.0 (mavsdk_impl.cpp:58)"
    assert without_terminal_escapes("\x1b[2K\x1b[1;31mred\x1b[0m\tand\x07 \x1bplain\r") == "red\tand plain"
    assert without_terminal_escapes("two\nlines") == "two\nlines"


def test_a_console_line_is_its_utc_time_then_the_message_without_escapes():
    record = logging.LogRecord("companion", logging.INFO, __file__, 1, "companion: \x1b[32m%s\x1b[0m", ("ready",), None)
    stamp, text = ConsoleFormatter().format(record).split(" ", 1)
    assert text == "companion: ready"
    assert abs(_utc(stamp).timestamp() - record.created) < 1e-3


def test_mavsdk_prints_nothing_itself_and_its_messages_reach_the_log(capfd):
    async def open_and_close() -> None:
        sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
        await sdk.__aenter__()
        await sdk.__aexit__(None, None, None)

    logger = logging.getLogger("tests.mavsdk_log")
    logger.setLevel(logging.DEBUG)
    kept = _Kept()
    logger.addHandler(kept)
    try:
        with mavsdk_log_to(logger):
            asyncio.run(open_and_close())
    finally:
        logger.removeHandler(kept)
    printed = capfd.readouterr()
    assert "MAVSDK version" not in printed.out + printed.err and "\x1b" not in printed.out + printed.err
    version = [record for record in kept.records if "MAVSDK version" in record.getMessage()]
    assert version and version[0].levelno == logging.INFO
    assert re.fullmatch(r"mavsdk info: MAVSDK version: v\S+ \(\S+:\d+\)", version[0].getMessage())


def test_the_companion_child_writes_stamped_lines_without_escapes(tmp_path, scenario_path):
    """As bof-sitl starts it (ChildProcess, output to companion.out), waiting for an autopilot nobody runs."""
    out = tmp_path / "companion.out"
    command = [sys.executable, "-m", "companion", "--config", str(scenario_path("constant_velocity")),
               "--mavlink", f"udpin://127.0.0.1:{free_port()}", "--zenoh-listen",
               f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}", "--log-dir", str(tmp_path / "companion")]
    child = ChildProcess(command, out, ready="companion ready")
    try:
        ready = child.start(timeout=120.0) and child.wait_for_line("companion ready", 1.0)
        assert ready.startswith("companion ready: constant_velocity")
        child.wait_for_line("mavsdk info: MAVSDK version", 30.0)
    finally:
        child.stop()
    lines = [line for line in out.read_text().splitlines() if line]
    assert "\x1b" not in out.read_text()
    for line in lines:
        stamp, _, text = line.partition(" ")
        _utc(stamp)
        assert text
    texts = [line.partition(" ")[2] for line in lines]
    assert any(text.startswith("companion ready: ") for text in texts)
    assert any(text.startswith("mavsdk info: MAVSDK version: ") for text in texts)
