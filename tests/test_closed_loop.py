"""Closed-loop flights of the paper's scenarios in the in-process simulator (fixed seeds)."""

import numpy as np
import pytest

from interfaces.scenario import SCENARIOS_DIR, Scenario, load_scenario
from studies.closed_loop import Termination, simulate
from studies.run_scenario import main as bof_sim


def _with(scenario: Scenario, section: str, **changes) -> Scenario:
    data = scenario.model_dump()
    data[section].update(changes)
    return Scenario.model_validate(data)


@pytest.fixture(scope="module")
def constant_velocity():
    return load_scenario(SCENARIOS_DIR / "constant_velocity.toml")


@pytest.fixture(scope="module")
def constant_velocity_flight(constant_velocity):
    scenario, vehicle = constant_velocity
    return simulate(scenario, vehicle)


def test_constant_velocity_converges(constant_velocity_flight):
    summary = constant_velocity_flight.summary
    assert constant_velocity_flight.termination is Termination.COMPLETED
    # Section VIII-A1: the pursuer settles at r_d = 8 m and the estimate converges.
    assert summary["range_error_rms"] < 0.4
    assert summary["range_estimation_error_rms"] < 0.4
    assert summary["velocity_estimation_error_rms"] < 0.2
    assert summary["convergence_time"] < 20.0
    # Physical sanity: the guidance stays within the vehicle's tilt limit (35 deg) and never rams the target.
    assert summary["max_tilt_deg"] < 40.0
    assert summary["min_range"] > 4.0


def test_pursuer_flies_a_helix_around_the_line_of_sight(constant_velocity_flight):
    """HNG weaves: after convergence the pursuer's offset from the target's track circles in 3-D."""
    series = constant_velocity_flight.series
    late = series["time"] > 30.0
    relative = series["pursuer_position"][late] - series["target_position"][late]
    along = np.array([3.0, 4.0, 0.0]) / 5.0
    lateral = relative - np.outer(relative @ along, along)
    # Both lateral directions (horizontal-cross and vertical) are exercised, not a planar weave.
    horizontal_cross = lateral @ np.array([-0.8, 0.6, 0.0])
    vertical = lateral[:, 2]
    assert np.std(horizontal_cross) > 0.5 and np.std(vertical) > 0.5


def test_flight_is_deterministic_for_a_seed(constant_velocity, constant_velocity_flight):
    scenario, vehicle = constant_velocity
    again = simulate(_with(scenario, "simulation", duration=10.0, summary_window=5.0), vehicle)
    first = constant_velocity_flight.series
    count = len(again.series["time"])
    np.testing.assert_array_equal(again.series["pursuer_position"], first["pursuer_position"][:count])
    other = simulate(_with(scenario, "simulation", duration=10.0, summary_window=5.0), vehicle, seed=7)
    assert not np.array_equal(other.series["pursuer_position"], again.series["pursuer_position"])


def test_s_maneuver_keeps_following(scenario_path):
    scenario, vehicle = load_scenario(scenario_path("s_maneuver"))
    result = simulate(scenario, vehicle)
    summary = result.summary
    assert result.termination is Termination.COMPLETED
    # Section VIII-A2: errors stay bounded (not zero) while the target accelerates unknown
    # to the filter (Q = 0.04 I assumes 0.2 m/s^2, the turn is 0.5 m/s^2). Seed 1 peaks
    # at about 6 m during the reversal; a diverging filter would run off to tens of metres.
    during = (result.series["time"] > 15.0) & (result.series["time"] < 30.0)
    estimation_error = np.abs(result.series["range_estimate"] - result.series["range"])
    assert np.max(estimation_error[during]) < 8.0
    assert summary["range_estimation_error_rms"] < 1.0
    assert summary["min_range"] > scenario.guidance.desired_range / 2


def test_paper_filter_fails_at_50hz_where_default_does_not(constant_velocity):
    """The known weakness (issue #2): the noisy bearing inside H biases the paper's u-PLKF.

    At 50 Hz bearings the paper's exact form loses the range in closed loop on some
    seeds (which ones depends on the noise draw); the default instrumental-gain form
    stays converged on every one. Same seeds, same flights otherwise.
    """
    scenario, vehicle = constant_velocity
    fast = _with(_with(scenario, "sensor", rate_hz=50.0), "simulation", duration=40.0)
    paper_form = _with(fast, "estimator", gain_projection="measured", restart_when_behind=False, pursuer_position_std=0.0)
    seeds = (1, 2, 3, 4)
    default = [simulate(fast, vehicle, seed=seed).summary for seed in seeds]
    paper = [simulate(paper_form, vehicle, seed=seed).summary for seed in seeds]
    assert max(s["range_estimation_error_rms"] for s in default) < 0.5
    assert max(s["range_error_rms"] for s in default) < 0.5
    assert max(s["range_estimation_error_rms"] for s in paper) > 2.0


def test_ppg_is_hng_with_zero_weave(constant_velocity):
    scenario, vehicle = constant_velocity
    short = _with(scenario, "simulation", duration=5.0, summary_window=5.0)
    ppg = simulate(_with(short, "guidance", law="ppg"), vehicle)
    hng_zero = simulate(_with(short, "guidance", c_z=0.0, c_y=0.0), vehicle)
    np.testing.assert_allclose(ppg.series["pursuer_position"], hng_zero.series["pursuer_position"], atol=1e-9)


def test_bof_sim_writes_a_run_folder(tmp_path, scenario_path, capsys):
    import json

    code = bof_sim([str(scenario_path("constant_velocity")), "--out", str(tmp_path), "--seed", "3"])
    assert code == 0
    (folder,) = list(tmp_path.iterdir())
    for name in ("series.npz", "series.csv", "summary.json", "trajectory.png", "errors.png"):
        assert (folder / name).stat().st_size > 0
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["seed"] == 3 and summary["termination"] == "COMPLETED"
    assert "range-estimation error" in capsys.readouterr().out


def test_bof_sim_reports_config_errors(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[target]\ninitial_position = [0, 0, 0]\n')
    assert bof_sim([str(bad), "--out", str(tmp_path)]) == 2
    assert "initial_velocity" in capsys.readouterr().err
