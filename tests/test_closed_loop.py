"""Closed-loop flights of the paper's scenarios in the in-process simulator (fixed seeds)."""

import json
import math
import statistics

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from interfaces.scenario import SCENARIOS_DIR, Scenario, load_scenario
from studies.closed_loop import Termination, simulate
from studies.metrics import convergence_text, median_finite, summarize, write_summary
from studies.plots import MIN_VERTICAL_SHARE, vertical_exaggeration
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
    """The known weakness: the noisy bearing inside H biases the paper's u-PLKF.

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
    code = bof_sim([str(scenario_path("constant_velocity")), "--out", str(tmp_path), "--seed", "3"])
    assert code == 0
    (folder,) = list(tmp_path.iterdir())
    for name in ("series.npz", "series.csv", "summary.json", "trajectory.png", "errors.png"):
        assert (folder / name).stat().st_size > 0
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["seed"] == 3 and summary["termination"] == "completed"
    assert "range-estimation error" in capsys.readouterr().out


def test_bof_sim_reports_config_errors(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[target]\ninitial_position = [0, 0, 0]\n')
    assert bof_sim([str(bad), "--out", str(tmp_path)]) == 2
    assert "initial_velocity" in capsys.readouterr().err


# --- the shared flight figures (studies.metrics) and what bof-sim writes and says --------------

def _strict_json(text: str):
    """json.loads that refuses NaN/Infinity, which are not JSON."""
    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")
    return json.loads(text, parse_constant=refuse)


def _flat_series(time: np.ndarray, range_: np.ndarray, range_estimate: np.ndarray) -> dict:
    """A flight series with the pursuer at rest at the origin and the target on the north axis."""
    n = len(time)
    target = np.column_stack([range_, np.zeros(n), np.zeros(n)])
    estimate = np.column_stack([range_estimate, np.zeros(n), np.zeros(n)])
    return {"time": time, "range": range_, "range_estimate": range_estimate, "target_position": target,
            "estimate_position": estimate, "target_velocity": np.zeros((n, 3)), "estimate_velocity": np.zeros((n, 3)),
            "pursuer_velocity": np.zeros((n, 3)), "pursuer_tilt": np.zeros(n), "heading_error": np.zeros(n)}


@given(offset=st.floats(-0.9, 0.9), settle=st.integers(1, 199))
def test_summary_figures_against_closed_form(constant_velocity, offset, settle):
    """Range r_d + 5 m until sample `settle`, then r_d + offset, with the estimate exact: the range error
    is |offset| (rms and max) over the last 20 s, the estimation error 0, and the flight converged at
    the sample where both fell below 1 m."""
    scenario, vehicle = constant_velocity
    time = np.linspace(0.0, 60.0, 200)
    desired = scenario.guidance.desired_range
    range_ = np.where(np.arange(200) < settle, desired + 5.0, desired + offset)
    summary = summarize(_flat_series(time, range_, range_), scenario, Termination.COMPLETED, vehicle)
    if settle < int(np.argmax(time >= 40.0)):
        assert summary["range_error_rms"] == pytest.approx(abs(offset), abs=1e-12)
        assert summary["range_error_max_abs"] == pytest.approx(abs(offset), abs=1e-12)
    assert summary["range_estimation_error_rms"] == 0.0
    assert summary["convergence_time"] == time[settle]
    assert summary["min_range"] == pytest.approx(desired + min(offset, 5.0))
    assert "did not converge" not in convergence_text(summary)


def test_a_flight_that_ends_outside_the_threshold_did_not_converge(constant_velocity, tmp_path):
    scenario, vehicle = constant_velocity
    time = np.linspace(0.0, 60.0, 200)
    range_ = np.full(200, scenario.guidance.desired_range + 3.0)
    summary = summarize(_flat_series(time, range_, range_), scenario, Termination.COMPLETED, vehicle)
    assert math.isnan(summary["convergence_time"])
    assert convergence_text(summary).startswith("did not converge") and "nan" not in convergence_text(summary)
    write_summary(tmp_path / "summary.json", summary)
    assert _strict_json((tmp_path / "summary.json").read_text())["convergence_time"] is None


@given(st.lists(st.floats(-50.0, 50.0), min_size=1, max_size=40), st.integers(0, 10))
def test_observability_median_skips_singular_windows(values, singular):
    """The windowed FIM's log10 det is -inf while singular: the median is over the finite values only."""
    logged = np.array([-math.inf] * singular + values)
    assert median_finite(logged, np.ones(len(logged), dtype=bool)) == pytest.approx(statistics.median(values))
    assert math.isnan(median_finite(None, np.ones(3, dtype=bool)))
    assert math.isnan(median_finite(np.full(4, -math.inf), np.ones(4, dtype=bool)))


def test_summary_json_has_null_for_every_non_finite_number(tmp_path):
    document = {"a": math.nan, "b": [1.0, math.inf, np.float64(-math.inf)], "c": {"d": np.float32(2.5), "e": (np.int64(3),)},
                "f": np.array([0.5, math.nan])}
    write_summary(tmp_path / "summary.json", document)
    assert _strict_json((tmp_path / "summary.json").read_text()) == {"a": None, "b": [1.0, None, None],
                                                                      "c": {"d": 2.5, "e": [3]}, "f": [0.5, None]}


def test_bof_sim_says_did_not_converge_and_writes_null(tmp_path, scenario_path, capsys):
    # circle_10ms at seed 1 ends with the range error above 1 m (tests/data/seed1_flight_figures.json: null).
    assert bof_sim([str(scenario_path("circle_10ms")), "--out", str(tmp_path), "--seed", "1", "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "did not converge" in out and "nan" not in out
    (folder,) = list(tmp_path.iterdir())
    summary = _strict_json((folder / "summary.json").read_text())
    assert summary["convergence_time"] is None and "notes" not in summary


def test_bof_sim_says_mavlink_faults_apply_in_sitl_only(tmp_path, scenario_path, capsys):
    assert bof_sim([str(scenario_path("constant_velocity_vehicle_link_loss")), "--out", str(tmp_path), "--no-plots"]) == 0
    assert "[faults.mavlink]" in capsys.readouterr().out
    (folder,) = list(tmp_path.iterdir())
    (note,) = _strict_json((folder / "summary.json").read_text())["notes"]
    assert "SITL only" in note


@given(st.floats(1.0, 1e4), st.floats(1.0, 1e4), st.floats(1e-2, 1e4))
def test_trajectory_up_axis_is_stretched_only_when_flat_and_never_below_a_quarter(north, east, up):
    stretch = vertical_exaggeration((north, east, up))
    assert stretch >= 1.0
    assert stretch * up >= MIN_VERTICAL_SHARE * max(north, east) * (1 - 1e-12)
    if up >= MIN_VERTICAL_SHARE * max(north, east):
        assert stretch == 1.0
