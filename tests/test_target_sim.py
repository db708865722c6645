"""The target model's exact propagation and the sitl-target process on a real Zenoh clock."""

from __future__ import annotations

import csv
import json
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from interfaces.scenario import TargetConfig, load_scenario
from interfaces.link_schema import ClockTick, decode_target_fix, encode_clock, fix_to_ned
from studies.processes import ChildProcess
from sitl_plant.world.target import Maneuver, TargetModel
from sitl_plant.world.target_publisher import FixSchedule, TargetLog, TargetPublisher, TargetTruth

MANEUVERS = (Maneuver(2.0, 5.0, 0.5), Maneuver(5.0, 7.0, -0.8), Maneuver(9.0, 9.5, 1.0))
START = np.array([10.0, -5.0, -20.0])
VELOCITY = np.array([3.0, 1.0, -0.2])


def _model() -> TargetModel:
    return TargetModel(START, VELOCITY, MANEUVERS)


def _at(time: float) -> TargetModel:
    model = _model()
    model.advance_to(time)
    return model


# --- TargetModel.advance_to ----------------------------------------------------------

def test_advance_to_equals_many_small_steps_on_an_exact_grid():
    dt = 1.0 / 1024  # binary: the small steps land exactly on every maneuver boundary
    stepped = _model()
    for _ in range(12 * 1024):
        stepped.step(dt)
    assert stepped.time == 12.0
    advanced = _at(12.0)
    assert np.allclose(advanced.position, stepped.position, rtol=0, atol=1e-9)
    assert np.allclose(advanced.velocity, stepped.velocity, rtol=0, atol=1e-12)


def test_advance_to_does_not_depend_on_how_time_is_cut():
    reference = _at(11.3)
    rng = np.random.default_rng(3)
    for _ in range(5):
        cuts = np.sort(rng.uniform(0.0, 11.3, size=int(rng.integers(1, 40))))
        model = _model()
        for cut in (*cuts, 11.3):
            model.advance_to(float(cut))
        assert model.time == 11.3
        assert np.allclose(model.position, reference.position, rtol=0, atol=1e-9)
        assert np.allclose(model.velocity, reference.velocity, rtol=0, atol=1e-12)


def test_advance_to_follows_exact_arcs_across_maneuver_boundaries():
    speed = math.hypot(*VELOCITY[:2])
    heading = math.atan2(VELOCITY[1], VELOCITY[0])
    # Straight until 2 s.
    assert np.allclose(_at(2.0).position, START + 2.0 * VELOCITY, rtol=0, atol=1e-12)
    # A circle of radius V^2 / a about a fixed centre from 2 to 5 s, then the opposite turn from 5 to 7 s.
    entry = _at(2.0).position
    radius = speed**2 / 0.5
    centre = entry[:2] + radius * np.array([-math.sin(heading), math.cos(heading)])  # right turn: centre to the right
    for t in (2.5, 3.7, 4.999, 5.0):
        model = _at(t)
        assert abs(np.linalg.norm(model.position[:2] - centre) - radius) < 1e-9
        expected_heading = heading + 0.5 / speed * (t - 2.0)
        assert math.isclose(math.atan2(model.velocity[1], model.velocity[0]), expected_heading, abs_tol=1e-12)
        assert math.isclose(model.position[2], START[2] + VELOCITY[2] * t, abs_tol=1e-12)
        assert math.isclose(math.hypot(*model.velocity[:2]), speed, rel_tol=1e-12)
    heading_5 = heading + 0.5 / speed * 3.0
    entry = _at(5.0).position
    radius = speed**2 / 0.8
    centre = entry[:2] + radius * np.array([math.sin(heading_5), -math.cos(heading_5)])  # left turn
    for t in (5.5, 6.9, 7.0):
        assert abs(np.linalg.norm(_at(t).position[:2] - centre) - radius) < 1e-9
    # Straight again between 7 and 9 s with the heading reached at 7 s.
    v7 = _at(7.0).velocity
    assert np.allclose(_at(8.5).position, _at(7.0).position + 1.5 * v7, rtol=0, atol=1e-9)


def test_advance_to_refuses_the_past_and_step_still_works():
    model = _at(3.0)
    with pytest.raises(ValueError, match="backwards"):
        model.advance_to(2.0)
    with pytest.raises(ValueError, match="finite"):
        model.advance_to(math.inf)
    model.advance_to(3.0)
    assert model.time == 3.0
    model.step(0.5)
    assert model.time == 3.5


# --- schedule, truth, publisher (no network) ---------------------------------------

def test_schedule_stamps_are_exact_multiples_and_never_ahead_of_the_clock():
    schedule = FixSchedule(20.0)
    assert schedule.due(0.13) == []  # anchored at the first multiple >= 0.13: 0.15
    assert schedule.due(0.15) == [0.15]
    assert schedule.due(0.31) == [0.2, 0.25, 0.3]  # a catch-up burst, each fix with its own stamp
    assert schedule.due(0.31) == []
    clock, stamps = 0.31, []
    for _ in range(1000):
        clock += 0.004  # the plant's tick: float sums, never exact multiples
        due = schedule.due(clock)
        assert all(stamp <= clock + 1e-9 for stamp in due)
        stamps += due
    assert np.allclose(np.diff(stamps), 0.05, atol=1e-12)
    assert all(abs(stamp * 20.0 - round(stamp * 20.0)) < 1e-9 for stamp in stamps)
    assert len(stamps) == 80  # 0.35 .. 4.30


def _target_config() -> TargetConfig:
    return TargetConfig(initial_position=tuple(START), initial_velocity=tuple(VELOCITY),
                        maneuvers=[{"start": m.start, "end": m.end, "lateral_acceleration": m.lateral_acceleration}
                                   for m in MANEUVERS])


def test_truth_hovers_before_the_start_time_then_flies_the_scenario():
    truth = TargetTruth(_target_config(), start_time=2.0)
    scenario_time, position, velocity = truth.at(1.5)
    assert scenario_time == 0.0 and np.array_equal(position, START) and np.array_equal(velocity, np.zeros(3))
    scenario_time, position, velocity = truth.at(8.0)
    assert scenario_time == 6.0
    assert np.allclose(position, _at(6.0).position, rtol=0, atol=1e-12)
    assert np.allclose(velocity, _at(6.0).velocity, rtol=0, atol=1e-12)
    _, position, _ = truth.at(3.0)  # back in time (a restarted plant): flown again from the start
    assert np.allclose(position, _at(1.0).position, rtol=0, atol=1e-12)


def test_publisher_counts_bad_clocks_and_handles_restarts_and_jumps(tmp_path):
    sent: list[bytes] = []
    target = TargetPublisher(TargetTruth(_target_config()), FixSchedule(5.0), sent.append, TargetLog(tmp_path, "ned"),
                             "target-1", "ned", (47.0, 8.0, 400.0), 0.0, rng=np.random.default_rng(0), duration=100.0)

    def tick(stamp: float, sender: str = "plant", seq: int = 0) -> None:
        target.on_clock_payload(encode_clock(ClockTick(sender, seq, stamp)))

    for payload in (b"", b"\xff", b"[]", b'{"schema": "bof.clock/1"}', json.dumps({"schema": "bof.clock/1",
                    "sender": "plant", "seq": 0, "stamp": -1.0}).encode()):
        target.on_clock_payload(payload)
    assert dict(target.rejected) == {"not_json": 1, "not_utf8": 1, "not_object": 1, "missing_field": 1,
                                     "out_of_range": 1}
    tick(0.0)
    tick(1.0)
    tick(1.0, sender="second-plant")
    assert target.ignored["other_sender"] == 1
    stamps = [decode_target_fix(payload).stamp for payload in sent]
    assert stamps == [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
    tick(0.5)  # the plant restarted
    tick(0.6)
    tick(50.0)  # a jump: the gap is not published
    assert target.events == {"clock_backwards": 1, "clock_jump": 1}
    fixes = [decode_target_fix(payload) for payload in sent]
    assert [fix.stamp for fix in fixes[6:]] == [0.6, 50.0]
    assert [fix.seq for fix in fixes] == list(range(8))
    assert np.allclose(fixes[6].position, _at(0.6).position, rtol=0, atol=1e-12)
    tick(101.0)
    assert target.finished and fixes[-1].stamp <= 100.0


# --- the sitl-target process -------------------------------------------------------

def _scenario(tmp_path: Path, scenario_path) -> Path:
    """constant_velocity with MANEUVERS, so the process's fixes cross maneuver boundaries."""
    text = scenario_path("constant_velocity").read_text()
    vehicle = scenario_path("constant_velocity").parent.parent / "vehicles" / "paper_table1.toml"
    text = text.replace('vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{vehicle}"')
    maneuvers = ", ".join(f"{{ start = {m.start}, end = {m.end}, lateral_acceleration = {m.lateral_acceleration} }}"
                          for m in MANEUVERS)
    text = text.replace("initial_velocity = [3.0, 4.0, 0.0]",
                        f"initial_velocity = {VELOCITY.tolist()}\nmaneuvers = [{maneuvers}]")
    text = text.replace("initial_position = [50.0, -25.0, -20.0]", f"initial_position = {START.tolist()}")
    path = tmp_path / "scenario.toml"
    path.write_text(text)
    return path


def _listening_addresses(pid: int) -> list[str]:
    """Local addresses of the TCP sockets `pid` listens on (Linux /proc)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    addresses = []
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # 0A = LISTEN
                host, port = fields[1].split(":")
                addresses.append(f"{table}:{host}:{int(port, 16)}")
    return addresses


LOOPBACK_V4 = "0100007F"  # 127.0.0.1 as /proc/net/tcp writes it


def _csv_rows(path: Path) -> list[dict]:
    with path.open() as handle:
        return list(csv.DictReader(handle))


def test_target_process_follows_the_clock_end_to_end(tmp_path, scenario_path, clock_and_fixes):
    scenario = _scenario(tmp_path, scenario_path)
    home = load_scenario(scenario)[0].sitl.home
    rate, start_time = 20.0, 1.0
    link = clock_and_fixes("target-1")
    child = None
    try:
        command = [sys.executable, "-m", "sitl_plant.world.target_publisher", "--config", str(scenario), "--zenoh-connect",
                   link.endpoint, "--rate", str(rate), "--start-time", str(start_time), "--log-dir", str(tmp_path / "logs"),
                   "--seed", "1"]
        child = ChildProcess(command, tmp_path / "target.out", ready="sitl-target ready").start(timeout=20.0)
        child.wait_for_line("sitl-target: waiting for the simulation clock", timeout=10.0)
        addresses = _listening_addresses(child.process.pid)
        assert addresses and all(address.startswith(f"tcp:{LOOPBACK_V4}:") for address in addresses), addresses
        for bad in (b"not json", b'{"schema": "bof.clock/9"}', b'{"schema": "bof.clock/1", "sender": "plant", '
                    b'"seq": 0, "stamp": NaN}'):
            link.clock.put(bad)
        # 50 ticks per wall second, 0.08 s of simulated time each (4x wall time): 1 or 2 fixes due per tick.
        link.run_clock(until_sim=9.6, step=0.08, period=0.02, timeout=15.0)
        final = link.run_clock(until_sim=12.0, step=0.08, period=0.02, timeout=5.0,
                               done=lambda: any(fix.stamp >= 9.6 - 1e-9 for fix in link.received()))
        assert final < 12.0, "the fixes stopped arriving"
        exit_code = child.stop()
        output = child.output()
    finally:
        if child is not None:
            child.stop()
        link.close()
    assert exit_code == 0, output
    assert output.count("waiting for the simulation clock") == 1
    assert "rejected clock payloads: {'not_json': 1, 'wrong_schema': 1, 'not_finite': 1}" in output, output

    fixes = link.received()
    seqs = [fix.seq for fix in fixes]
    assert seqs == list(range(len(seqs))), "seq must start at 0 and step by 1 with nothing lost"
    assert fixes[-1].stamp >= 9.6 - 1e-9
    for fix in fixes:
        assert abs(fix.stamp * rate - round(fix.stamp * rate)) < 1e-9, fix.stamp
        assert fix.sender == "target-1" and fix.frame == "geodetic"
        model = _at(max(0.0, fix.stamp - start_time))
        assert np.linalg.norm(fix_to_ned(fix, home) - model.position) < 1e-3, fix
        expected_velocity = model.velocity if fix.stamp >= start_time else np.zeros(3)
        assert np.allclose(fix.velocity, expected_velocity, rtol=0, atol=1e-12)
    assert np.diff([fix.stamp for fix in fixes]) == pytest.approx(1.0 / rate, abs=1e-9)

    rows = _csv_rows(tmp_path / "logs" / "target.csv")
    assert [int(row["seq"]) for row in rows] == list(range(len(rows)))
    assert len(rows) >= seqs[-1] + 1
    by_seq = {int(row["seq"]): row for row in rows}
    for fix in fixes:
        row = by_seq[fix.seq]
        assert float(row["stamp"]) == fix.stamp
        assert (float(row["published_lat_deg"]), float(row["published_lon_deg"]), float(row["published_alt_m"])) == fix.position
        truth = np.array([float(row[f"true_{axis}"]) for axis in "ned"])
        assert np.linalg.norm(fix_to_ned(fix, home) - truth) < 1e-3


def test_target_process_stops_at_its_duration_with_noisy_ned_fixes(tmp_path, scenario_path, clock_and_fixes):
    scenario = _scenario(tmp_path, scenario_path)
    rate, noise = 50.0, 0.5
    link = clock_and_fixes("target-2")
    child = None
    try:
        command = [sys.executable, "-m", "sitl_plant.world.target_publisher", "--config", str(scenario), "--zenoh-connect",
                   link.endpoint, "--rate", str(rate), "--frame", "ned", "--noise-std", str(noise), "--sender", "target-2",
                   "--duration", "6.0", "--seed", "4", "--log-dir", str(tmp_path / "logs")]
        child = ChildProcess(command, tmp_path / "target.out", ready="sitl-target ready").start(timeout=20.0)
        link.run_clock(until_sim=8.0, step=0.1, period=0.01, timeout=15.0, done=lambda: not child.running)
        child.process.wait(10.0)
        exit_code = child.process.returncode
        output = child.output()
    finally:
        if child is not None:
            child.stop()
        link.close()
    assert exit_code == 0, output
    assert "sitl-target stopped at t=6.000s" in output, output
    rows = _csv_rows(tmp_path / "logs" / "target.csv")
    stamps = [float(row["stamp"]) for row in rows]
    assert stamps[-1] == 6.0 and np.diff(stamps) == pytest.approx(1.0 / rate, abs=1e-9)
    error = np.array([[float(row[f"published_{axis}"]) - float(row[f"true_{axis}"]) for axis in "ned"] for row in rows])
    assert len(error) >= 250
    assert np.all(np.abs(error.mean(axis=0)) < 4 * noise / math.sqrt(len(error)))
    assert np.all(np.abs(error.std(axis=0) / noise - 1.0) < 0.2)
    for fix in link.received():
        row = rows[fix.seq]
        assert fix.frame == "ned" and fix.position == tuple(float(row[f"published_{axis}"]) for axis in "ned")


@pytest.mark.parametrize("arguments, message", [
    (["--rate", "0"], "--rate"),
    (["--noise-std", "-1"], "--noise-std"),
    (["--start-time", "nan"], "--start-time"),
    (["--duration", "0"], "--duration"),
    (["--sender", "a/b"], "--sender"),
    (["--home", "91", "8", "400"], "--home"),
    (["--config", "no/such/scenario.toml"], "file not found"),
    (["--zenoh-listen", "tcp/0.0.0.0:7447"], "not loopback"),
    (["--zenoh-connect", "127.0.0.1:7447"], "expected <protocol>"),
])
def test_bad_arguments_exit_2_saying_why(arguments, message, capsys):
    from sitl_plant.world import target_publisher as target_sim

    assert target_sim.main(arguments) == 2
    error = capsys.readouterr().err
    assert error.startswith("sitl-target: ") and message in error, error
