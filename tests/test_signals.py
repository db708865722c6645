"""Processes that always clean up: SIGTERM, SIGINT and SIGKILL to a running bof-sitl, SIGTERM to a waiting companion.

bof-sitl runs as a real process (its own session, so the test can always kill what is left); its
children are found with psutil while it runs. After the signal: no child alive, every loopback port
they held can be bound again, and the summaries say "interrupted". Every wait has a timeout and
whatever is left is killed at the end, pass or fail.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from studies.processes import ChildProcess, free_port, wait_for

SPEED = "5"


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _kill_all(pids) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def _bindable(kind: int, port: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


class RunningSitl:
    """bof-sitl on constant_velocity at 5x, --gcs-port free, until the companion follows; its children's pids and ports."""

    def __init__(self, tmp_path: Path, scenario: Path, extra: tuple[str, ...] = ()) -> None:
        self.out = tmp_path / "runs"
        self.log = (tmp_path / "bof-sitl.out").open("w")
        self.gcs_port = free_port()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "studies.full_sitl", str(scenario), "--speed-factor", SPEED, "--out", str(self.out),
             "--no-plots", "--quiet", "--gcs-port", str(self.gcs_port), *extra],
            stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        self.children: dict[str, int] = {}

    def folder(self) -> Path | None:
        folders = list(self.out.glob("sitl-*")) if self.out.exists() else []
        return folders[0] if folders else None

    def wait_until_following(self, timeout: float = 120.0, phase: str = "following") -> None:
        def following() -> bool:
            assert self.process.poll() is None, Path(self.log.name).read_text()
            folder = self.folder()
            return folder is not None and f"companion: {phase}" in (folder / "companion.out").read_text(errors="replace") \
                if folder is not None and (folder / "companion.out").exists() else False

        wait_for(following, timeout, f"the companion to reach {phase}")
        for child in psutil.Process(self.process.pid).children(recursive=True):
            line = " ".join(child.cmdline())
            for name, module in (("plant", "sitl_plant.sitl"), ("target", "sitl_plant.world.target_publisher"),
                                 ("companion", "-m companion")):
                if module in line:
                    self.children[name] = child.pid
        assert set(self.children) == {"plant", "target", "companion"}, self.children

    def ports(self) -> list[tuple[int, int]]:
        """(socket kind, port) of every loopback port the children held: the plant's links, the companion's
        MAVLink port, the Zenoh endpoint."""
        folder = self.folder()
        plant_out = (folder / "plant.out").read_text()
        udp = {int(port) for port in re.findall(r"127\.0\.0\.1:(\d+) ->", plant_out)}
        tcp = {int(port) for port in re.findall(r"tcp/127\.0\.0\.1:(\d+)", (folder / "companion.out").read_text()
                                                 + plant_out)}
        udp |= {int(port) for port in re.findall(r"udpin://127\.0\.0\.1:(\d+)", (folder / "companion.out").read_text())}
        return [(socket.SOCK_DGRAM, port) for port in udp] + [(socket.SOCK_STREAM, port) for port in tcp]

    def cleanup(self) -> None:
        _kill_all([self.process.pid, *self.children.values()])
        try:
            self.process.wait(5.0)
        except subprocess.TimeoutExpired:
            pass
        self.log.close()


@pytest.fixture
def sitl(tmp_path, scenario_path):
    running = RunningSitl(tmp_path, scenario_path("constant_velocity"))
    yield running
    running.cleanup()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_stop_signal_mid_flight_stops_every_process_frees_every_port_and_writes_the_summaries(sitl, sig):
    sitl.wait_until_following()
    ports = sitl.ports()
    assert len(ports) >= 3, ports
    sent = time.monotonic()
    sitl.process.send_signal(sig)
    sitl.process.wait(30.0)
    exited_after = time.monotonic() - sent
    assert sitl.process.returncode == 128 + sig, Path(sitl.log.name).read_text()
    assert [name for name, pid in sitl.children.items() if _alive(pid)] == []
    assert [(kind, port) for kind, port in ports if not _bindable(kind, port)] == []
    summary = json.loads((sitl.folder() / "summary.json").read_text())
    assert summary["termination"] == "interrupted" and summary["interrupted"] == sig.name
    companion = json.loads((sitl.folder() / "companion" / "summary.json").read_text())
    assert companion["stopped_by"] == "SIGTERM"  # bof-sitl passes every stop on as SIGTERM
    assert (sitl.folder() / "plant" / "stats.json").exists()
    print(f"{sig.name}: children stopped {summary['stopped_after_s']} s after the signal, bof-sitl exited after "
          f"{exited_after:.2f} s")


def test_sigterm_while_the_companion_lands_still_writes_its_summary(tmp_path, scenario_path):
    """Abort 1 s after engaging (the companion holds, then lands), SIGTERM to bof-sitl while it lands:
    every summary is written, no child is left."""
    sitl = RunningSitl(tmp_path, scenario_path("constant_velocity"), ("--abort-after", "1"))
    try:
        sitl.wait_until_following(phase="landing")
        sitl.process.send_signal(signal.SIGTERM)
        sitl.process.wait(30.0)
        assert [name for name, pid in sitl.children.items() if _alive(pid)] == []
        companion = json.loads((sitl.folder() / "companion" / "summary.json").read_text())
        assert companion["stopped_by"] == "SIGTERM" and companion["phase"] in ("landing", "done")
        assert json.loads((sitl.folder() / "summary.json").read_text())["termination"] == "interrupted"
    finally:
        sitl.cleanup()


def test_sigkill_to_bof_sitl_leaves_no_child_behind(sitl):
    """bof-sitl cannot act on SIGKILL: the kernel's death signal (PR_SET_PDEATHSIG) stops the children."""
    sitl.wait_until_following()
    killed = time.monotonic()
    sitl.process.kill()
    sitl.process.wait(10.0)
    try:
        wait_for(lambda: not any(_alive(pid) for pid in sitl.children.values()), 20.0,
                    f"the children {sitl.children} to exit")
    except RuntimeError as error:  # say which child stayed and what it last printed
        alive = {name: psutil.Process(pid).status() for name, pid in sitl.children.items() if _alive(pid)}
        tails = {name: (sitl.folder() / f"{name}.out").read_text()[-1500:]
                 for name in alive if (sitl.folder() / f"{name}.out").exists()}
        raise AssertionError(f"{error}; still alive: {alive}; last output: {tails}") from None
    print(f"SIGKILL: every child gone {time.monotonic() - killed:.2f} s after it")


def test_sigterm_to_a_companion_waiting_for_its_autopilot_exits_promptly(tmp_path, scenario_path):
    """Nobody answers on the MAVLink port: the companion waits for an autopilot (connect_timeout is much
    longer than the wait below); SIGTERM ends it with 143 and its summary written."""
    log_dir = tmp_path / "companion"
    command = [sys.executable, "-m", "companion", "--config", str(scenario_path("constant_velocity")),
               "--mavlink", f"udpin://127.0.0.1:{free_port()}", "--zenoh-listen",
               f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}", "--log-dir", str(log_dir)]
    child = ChildProcess(command, tmp_path / "companion.out", ready="companion ready")
    try:
        child.start(timeout=60.0)
        time.sleep(1.0)  # well into MAVSDK's wait for the first autopilot
        sent = time.monotonic()
        child.process.send_signal(signal.SIGTERM)
        child.process.wait(15.0)
        print(f"companion waiting for its autopilot: exited {time.monotonic() - sent:.2f} s after SIGTERM")
        assert child.process.returncode == 128 + signal.SIGTERM, child.output()
        summary = json.loads((log_dir / "summary.json").read_text())
        assert summary["stopped_by"] == "SIGTERM" and summary["phase"] == "waiting"
    finally:
        child.stop()
