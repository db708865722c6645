"""Study commands stopped early: what they keep on disk, how fast they end, and that no worker outlives them.

Each command runs as a real process in its own session (so the test can find, and at the end always kill, every
process it started: psutil, by session id). The signals come from the test, as a terminal, `kill` or a batch
scheduler would send them. Every wait has a timeout.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from interfaces.scenario import SCENARIOS_DIR, VEHICLES_DIR
from studies.processes import wait_for


def _session(sid: int) -> list[int]:
    """Live processes of session `sid` (zombies are dead)."""
    found = []
    for process in psutil.process_iter(["status"]):
        try:
            if os.getsid(process.pid) == sid and process.info["status"] != psutil.STATUS_ZOMBIE:
                found.append(process.pid)
        except (ProcessLookupError, PermissionError, psutil.Error):
            continue
    return found


class Command:
    """A study command in its own session; `stop()` kills whatever of the session is left."""

    def __init__(self, argv: list[str], cwd: Path) -> None:
        self.process = subprocess.Popen([sys.executable, "-m", *argv], cwd=cwd, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.sid = self.process.pid

    def children(self) -> list[int]:
        return [pid for pid in _session(self.sid) if pid != self.process.pid]

    def finish(self, timeout: float) -> tuple[int, str, str]:
        out, err = self.process.communicate(timeout=timeout)
        return self.process.returncode, out, err

    def stop(self) -> None:
        for pid in _session(self.sid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.process.poll() is None:
            self.process.kill()
        self.process.communicate(timeout=10)


def _rows(path: Path) -> list[dict]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _one_folder(out: Path) -> Path:
    folders = [path for path in out.iterdir() if path.is_dir()]
    assert len(folders) == 1, folders
    return folders[0]


def _first_record(out: Path, name: str) -> Path:
    """The partial log `name` in the run folder under `out`, once it holds a record (a line after the header)."""
    found: list[Path] = []

    def written() -> bool:
        found[:] = list(out.glob(f"*/{name}"))
        return bool(found) and len(found[0].read_text().splitlines()) >= (2 if name.endswith(".csv") else 1)

    wait_for(written, 120, f"a first record in {name}")
    return found[0]


def test_ctrl_c_twice_keeps_every_finished_flight(tmp_path):
    """SIGINT, then another 0.2 s later (an impatient user): exit 130, no worker left, and the flights on disk are
    whole rows that the message counts. The second Ctrl-C used to leave the parent waiting on its workers for good."""
    command = Command(["studies.montecarlo", "--study", "estimators", "--runs", "20", "--workers", "2", "--no-plots",
                       "--quiet", "--out", str(tmp_path)], tmp_path)
    try:
        partial = _first_record(tmp_path, "results.partial.csv")
        assert len(command.children()) == 2  # the two workers
        command.process.send_signal(signal.SIGINT)
        time.sleep(0.2)
        if command.process.poll() is None:
            command.process.send_signal(signal.SIGINT)
        code, _, err = command.finish(timeout=30)
        assert code == 128 + signal.SIGINT
        wait_for(lambda: not _session(command.sid), 10, "no process left in the study's session")
        rows = _rows(partial)
        # the parent's closing line; a worker stopping at the same moment may write to the shared stderr after it
        lines = [re.search(r"interrupted by SIGINT: (\d+) of 240 flights kept in (.+)$", line)
                 for line in err.strip().splitlines()]
        kept = [match for match in lines if match]
        assert len(kept) == 1, err
        assert int(kept[0].group(1)) == len(rows) >= 1 and Path(kept[0].group(2)) == partial, err
        assert len({row["index"] for row in rows}) == len(rows)
        assert all(row["termination"] and row["flown_s"] for row in rows)  # whole rows, no cut line
        assert not (partial.parent / "results.csv").exists()
    finally:
        command.stop()


def test_an_interrupted_study_does_not_wait_for_the_flights_in_the_air(tmp_path):
    """Flights of 20,000 s (about 30 s of wall time each, more at 50 Hz): a Ctrl-C two seconds in ends the study
    long before any of them could end (the workers are stopped, not waited for), and says nothing was kept."""
    command = Command(["studies.montecarlo", "--study", "estimators", "--runs", "1", "--duration", "20000",
                       "--workers", "2", "--no-plots", "--quiet", "--out", str(tmp_path)], tmp_path)
    try:
        wait_for(lambda: len(command.children()) == 2, 60, "two workers")
        time.sleep(2.0)
        command.process.send_signal(signal.SIGINT)
        code, _, err = command.finish(timeout=15)  # a flight in the air would take 30 s or more to end
        assert code == 128 + signal.SIGINT
        assert err.strip().splitlines()[-1] == ("bof-montecarlo: interrupted by SIGINT: no flight had finished "
                                                "(12 planned); nothing written")
        wait_for(lambda: not _session(command.sid), 10, "no process left in the study's session")
    finally:
        command.stop()


def test_a_killed_study_leaves_no_worker(tmp_path):
    """SIGKILL to the parent alone (the OOM killer, a scheduler's hard limit): the kernel ends its workers (their
    death signal), instead of leaving them reparented to init, holding memory and the parent's output pipe."""
    command = Command(["studies.montecarlo", "--study", "estimators", "--runs", "20", "--workers", "2", "--no-plots",
                       "--quiet", "--out", str(tmp_path)], tmp_path)
    try:
        _first_record(tmp_path, "results.partial.csv")
        workers = command.children()
        assert len(workers) == 2
        command.process.kill()
        command.process.wait(timeout=10)
        wait_for(lambda: not any(psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
                                    for pid in workers), 10, "the workers to end")
    finally:
        command.stop()


def test_a_campaign_stopped_by_sigterm_keeps_its_rows_under_a_partial_name(tmp_path):
    command = Command(["studies.campaign", "--seeds", "40", "--workers", "2", "--quiet", "--out", str(tmp_path)],
                      tmp_path)
    try:
        partial = _first_record(tmp_path, "results.partial.csv")
        command.process.send_signal(signal.SIGTERM)
        code, out, err = command.finish(timeout=30)
        assert code == 128 + signal.SIGTERM
        folder = _one_folder(tmp_path)
        assert f"-> {folder}" in out.splitlines()[0]  # where the run goes, said before the first flight
        rows = _rows(partial)
        assert f"interrupted by SIGTERM: {len(rows)} of " in err and len(rows) >= 1
        assert not (folder / "results.csv").exists() and not (folder / "summary.json").exists()
        wait_for(lambda: not _session(command.sid), 10, "no process left in the campaign's session")
    finally:
        command.stop()


def test_a_swarm_study_stopped_by_sighup_keeps_its_flights(tmp_path):
    command = Command(["studies.swarm_study", "--seeds", "10", "--parts", "a", "--workers", "2", "--quiet",
                       "--out", str(tmp_path)], tmp_path)
    try:
        partial = _first_record(tmp_path, "flights.partial.jsonl")
        command.process.send_signal(signal.SIGHUP)
        code, _, err = command.finish(timeout=30)
        assert code == 128 + signal.SIGHUP
        records = [json.loads(line) for line in partial.read_text().splitlines()]
        assert f"interrupted by SIGHUP: {len(records)} of 40 flights kept in {partial}" in err
        for record in records:  # what the finished study would have tabulated: each pursuer's row of that flight
            assert {row["seed"] for row in record["rows"]} == {record["seed"]}
            assert record["case"] in ("cv_single", "cv_swarm", "turn_single", "turn_swarm")
        wait_for(lambda: not _session(command.sid), 10, "no process left in the study's session")
    finally:
        command.stop()


def _wait_for_stop_handlers(pid: int, timeout: float = 60.0) -> None:
    """Until the process catches SIGTERM (its SigCgt mask in /proc: bof-sim installs its stop handlers for SIGINT,
    SIGTERM and SIGHUP together, and Python catches only SIGINT of its own), so a signal sent then meets them
    however long the imports took on a loaded machine (a fixed 3 s was not always enough)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:") and int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)):
                return
        time.sleep(0.05)
    raise AssertionError(f"process {pid} never installed its stop handlers in {timeout:g} s")


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_bof_sim_interrupted_says_so_in_one_line(tmp_path, stop):
    long_flight = (SCENARIOS_DIR / "constant_velocity.toml").read_text()
    long_flight = long_flight.replace('vehicle = "../vehicles/paper_table1.toml"',
                                      f'vehicle = "{VEHICLES_DIR / "paper_table1.toml"}"')
    long_flight = long_flight.replace("duration = 60.0", "duration = 20000.0")
    scenario = tmp_path / "long.toml"
    scenario.write_text(long_flight)
    command = Command(["studies.run_scenario", str(scenario), "--no-plots", "--out", str(tmp_path / "runs")], tmp_path)
    try:
        _wait_for_stop_handlers(command.process.pid)  # imports and the scenario done: bof-sim is flying
        time.sleep(0.5)
        assert command.process.poll() is None
        command.process.send_signal(stop)
        code, _, err = command.finish(timeout=30)
        assert code == 128 + stop
        assert err.strip().splitlines() == [f"bof-sim: interrupted by {signal.Signals(stop).name}: the flight is written "
                                            "when it ends, so nothing was kept (a folder being written may be incomplete)"]
    finally:
        command.stop()
