"""The pieces the several-pursuer SITL adds, each alone: the command lines' new options (one-line refusals),
the plant's pursuer start, system id and shared clock anchor, and the pipeline fed a neighbour's late bearing."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from interfaces.scenario import SCENARIOS_DIR, load_plant_scenario, load_scenario
from studies.processes import free_port

SWARM = SCENARIOS_DIR / "swarm_circumnavigation.toml"
SINGLE = SCENARIOS_DIR / "constant_velocity.toml"


def _one_line_error(main, argv, capsys) -> str:
    code = main(argv)
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err and len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("argv, fragment", [
    (["--config", str(SWARM), "--pursuer-id", "0"], "--pursuer-id"),
    (["--config", str(SWARM), "--pursuer-id", "33"], "--pursuer-id"),
    (["--config", str(SWARM), "--pursuer-id", "x"], "--pursuer-id"),
    (["--config", str(SWARM), "--pursuer-id", "4"], "pursuers 1..3"),
    (["--config", str(SINGLE), "--pursuer-id", "2"], "no [swarm]"),
])
def test_companion_refuses_a_pursuer_id_it_cannot_fly_in_one_line(tmp_path, capsys, argv, fragment):
    from companion import app

    try:
        line = _one_line_error(app.main, [*argv, "--log-dir", str(tmp_path / "log")], capsys)
    except SystemExit as exit_:  # argparse's own refusal: exit status 2, one line after the usage
        assert exit_.code == 2
        line = capsys.readouterr().err.strip().splitlines()[-1]
    assert fragment in line, line
    assert not (tmp_path / "log").exists()


@pytest.mark.parametrize("argv, fragment", [
    (["--system-id", "0"], "--system-id"),
    (["--system-id", "256"], "--system-id"),
    (["--pursuer-id", "0"], "--pursuer-id"),
    (["--config", str(SWARM), "--pursuer-id", "4"], "pursuers 1..3"),
    (["--config", str(SINGLE), "--pursuer-id", "2"], "pursuers 1..1"),
    (["--clock-anchor", "-1"], "--clock-anchor"),
])
def test_the_plant_refuses_bad_ids_and_anchors_in_one_line(tmp_path, capsys, argv, fragment):
    from sitl_plant import sitl

    line = _one_line_error(sitl.main, [*argv, "--companion-port", str(free_port()), "--gcs-port", str(free_port()),
                                       "--duration", "0.1", "--quiet"], capsys)
    assert fragment in line, line


def test_each_plant_starts_at_its_pursuers_start_with_its_system_id():
    from sitl_plant.sitl import build_vehicle

    scenario, vehicle = load_plant_scenario(SWARM)
    expected = {1: (0.0, 0.0), 2: (80.0, -60.0), 3: (70.0, 10.0)}  # the file's [[swarm.pursuers]]
    for ident, start in expected.items():
        plant = build_vehicle(scenario, vehicle, speed_factor=1.0, companion_port=free_port(), gcs_port=free_port(),
                              system_id=40 + ident, pursuer_id=ident)
        try:
            np.testing.assert_allclose(plant.autopilot.state.position[:2], start)
            assert plant.system_id == 40 + ident
            assert all(link.mav.srcSystem == 40 + ident for link in plant.links)  # what pymavlink stamps on every packet
        finally:
            plant.close()


def test_plants_given_one_anchor_share_one_clock(tmp_path, capsys):
    """Two plants, started 0.6 s apart with the same --clock-anchor: both end at simulated time
    (stop - anchor) x speed, which they reached at the same wall instant, so their clocks agree."""
    from studies.processes import ChildProcess, plant_command, stop_all

    speed = 4.0
    anchor = time.monotonic() + 1.0
    children = []
    for index in range(2):
        command = plant_command(SWARM, speed, free_port(), free_port(), tmp_path / f"p{index}",
                                ["--pursuer-id", str(index + 1), "--system-id", str(index + 1),
                                 "--clock-anchor", f"{anchor:.6f}"])
        children.append(ChildProcess(command, tmp_path / f"p{index}.out", ready="sitl-plant ready").start(30.0))
        time.sleep(0.6)

    def caught_up() -> bool:
        """Both plants' stats.json (written every second) at most 0.5 s of wall time behind the anchor's clock:
        a plant launched after the anchor (its start-up is seconds on a loaded machine) catches up first."""
        clock = (time.monotonic() - anchor) * speed
        try:
            times = [json.loads((tmp_path / f"p{i}" / "stats.json").read_text())["sim_time"] for i in range(2)]
        except (OSError, ValueError, KeyError):
            return False
        return all(t >= clock - 0.5 * speed - speed for t in times)  # the file is up to 1 s old

    try:
        deadline = time.monotonic() + 30.0
        while not caught_up() and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(1.5)
    finally:
        stopped = time.monotonic()
        codes = stop_all(children)
    assert codes == [0, 0], [c.output() for c in children]
    ends = [json.loads((tmp_path / f"p{i}" / "stats.json").read_text())["sim_time"] for i in range(2)]
    # Each stops within the stop wave (<= ~0.2 s wall here) after `stopped`, once both had caught up with the
    # anchor's clock (within 1 s of wall time: a loaded machine may still hold one back). What tells the two clocks
    # apart is their agreement: a simulated clock started at its own launch would differ by 0.6 s x speed = 2.4 s,
    # and would never catch up with the anchor's (the wait above would time out and the bounds below fail).
    print(f"plants' simulated time at the stop {ends}, the anchor's {(stopped - anchor) * speed:.3f} s")
    for end in ends:
        assert (stopped - anchor - 1.0) * speed <= end <= (stopped - anchor + 1.0) * speed, ends
    assert abs(ends[0] - ends[1]) < 0.6 * speed / 2, ends


def test_a_neighbours_bearing_older_than_the_newest_one_used_corrects_without_breaking_the_pipeline():
    """A share delivered late: its bearing (source 2, stamp before the newest own bearing) reaches
    pipeline.step after newer ones. The pipeline takes it (the estimator's late-bearing update) and the
    windowed FIM keeps its time order (it refused out-of-order times with ValueError before)."""
    from companion.assembly import build_pipeline, pursuer_scenario
    from companion.core.messages import BearingMeasurement, PursuerState
    from interfaces.scenario import pursuer_starts

    scenario, vehicle = load_scenario(SWARM)
    own = pursuer_scenario(scenario, pursuer_starts(scenario)[0])
    pipeline = build_pipeline(own, vehicle, 0.5)
    target = np.array([50.0, -25.0, -20.0])
    me = np.array([0.0, 0.0, -20.0])
    neighbour = np.array([80.0, -60.0, -20.0])

    def bearing(t, where, source=0):
        direction = (target - where) / np.linalg.norm(target - where)
        return BearingMeasurement(t, direction, where, source=source)

    state = lambda t: PursuerState(t, me, np.zeros(3))  # noqa: E731
    for k in range(10):
        pipeline.step(0.2 * k, state(0.2 * k), bearing(0.2 * k, me))
    output = pipeline.step(1.8, state(1.8), bearing(1.5, neighbour, source=2))  # late: 1.5 < 1.8
    assert output.estimate is not None and np.all(np.isfinite(output.estimate.position))
    output = pipeline.step(2.0, state(2.0), bearing(2.0, me))
    assert np.all(np.isfinite(output.estimate.position))


def test_bof_sitl_refuses_what_a_swarm_run_does_not_do_in_one_line_before_making_anything(tmp_path, capsys):
    from studies import full_sitl

    out = tmp_path / "runs"
    with pytest.raises(SystemExit) as exit_:
        full_sitl.main([str(SWARM), "--abort-after", "3", "--out", str(out)])
    assert exit_.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith("bof-sitl: error:") and "--abort-after is for one pursuer" in line, line
    assert not out.exists()
