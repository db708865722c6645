"""The truth beside the health monitor: summarize's "truth", the honest verdict, bof-sim's exit status and closing
block, and bof-montecarlo's truth columns.

References: synthetic series whose truth is built in the test (a constant estimation error, a range dip of known
length, a tilt above the limit), and for real flights figures recomputed by hand from the logged series (numpy on
series.npz), never by calling the code under test a second time.
"""

from __future__ import annotations

import csv
import json
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from interfaces.overrides import format_assignment
from interfaces.scenario import DIVERGENCE_RMS_M, SCENARIOS_DIR, ConfigError, load_scenario
from studies import montecarlo
from studies.closed_loop import Termination
from studies.metrics import summarize, truth_failed
from studies.run_scenario import main as bof_sim

N = 601  # samples over 60 s: dt = 0.1 s exactly
TIME = np.linspace(0.0, 60.0, N)
DT = 0.1


@pytest.fixture(scope="module")
def loaded():
    return load_scenario(SCENARIOS_DIR / "constant_velocity.toml")  # r_d = 8 m, window 20 s, tilt limit 35 deg


def _series(range_: np.ndarray, estimation_error: float | np.ndarray = 0.0, tilt: float | np.ndarray = 10.0,
            suspect: np.ndarray | None = None) -> dict:
    """The pursuer at rest at the origin, the target on the north axis at `range_` (N,), m; the range estimate off by
    `estimation_error` m; tilt in deg; optional health_suspect (1 suspect, 0 ok, NaN before the first verdict)."""
    estimate = range_ + estimation_error
    zeros = np.zeros((N, 3))
    series = {"time": TIME, "range": range_, "range_estimate": estimate,
              "target_position": np.column_stack([range_, np.zeros(N), np.zeros(N)]),
              "estimate_position": np.column_stack([estimate, np.zeros(N), np.zeros(N)]),
              "target_velocity": zeros, "estimate_velocity": zeros, "pursuer_velocity": zeros,
              "pursuer_tilt": np.broadcast_to(np.asarray(tilt, dtype=float), (N,)).copy(), "heading_error": np.zeros(N)}
    if suspect is not None:
        series["health_suspect"] = suspect
    return series


def _at_rd(scenario) -> np.ndarray:
    return np.full(N, scenario.guidance.desired_range)


def test_the_default_divergence_limit_is_two_metres(loaded):
    scenario, _ = loaded
    assert DIVERGENCE_RMS_M == 2.0 and scenario.simulation.divergence_rms == 2.0


def test_a_constant_three_metre_error_has_diverged_and_the_monitor_missed_it(loaded):
    scenario, vehicle = loaded
    summary = summarize(_series(_at_rd(scenario), 3.0), scenario, Termination.COMPLETED, vehicle)
    truth = summary["truth"]
    assert truth["range_estimation_error_rms"] == pytest.approx(3.0, abs=1e-12)
    assert truth["diverged"] and truth["outcome"] == "diverged" and truth["divergence_rms"] == 2.0
    # no health series: the monitor flagged nothing, so its word is "clean" and it missed the divergence
    assert summary["monitor_verdict"] == "clean" and summary["verdict"] == "diverged"
    assert truth["monitor_missed"] and not truth["monitor_false_alarm"]
    assert truth_failed(summary)


def test_a_constant_one_metre_error_is_a_success(loaded):
    scenario, vehicle = loaded
    summary = summarize(_series(_at_rd(scenario), -1.0), scenario, Termination.COMPLETED, vehicle)
    truth = summary["truth"]
    assert truth["range_estimation_error_rms"] == pytest.approx(1.0, abs=1e-12)
    assert not truth["diverged"] and truth["outcome"] == "success"
    assert summary["verdict"] == summary["monitor_verdict"] == "clean"
    assert not truth["monitor_missed"] and not truth["monitor_false_alarm"] and not truth_failed(summary)


def test_an_error_only_before_the_window_does_not_count(loaded):
    scenario, vehicle = loaded
    error = np.where(TIME < 39.0, 10.0, 0.5)  # the window is t >= 40 s
    truth = summarize(_series(_at_rd(scenario), error), scenario, Termination.COMPLETED, vehicle)["truth"]
    assert truth["range_estimation_error_rms"] == pytest.approx(0.5, abs=1e-12) and not truth["diverged"]


def test_the_divergence_limit_is_the_scenarios(loaded):
    scenario, vehicle = loaded
    lenient = montecarlo.with_overrides(scenario, {"simulation.divergence_rms": 4.0})
    truth = summarize(_series(_at_rd(scenario), 3.0), lenient, Termination.COMPLETED, vehicle)["truth"]
    assert not truth["diverged"] and truth["divergence_rms"] == 4.0 and truth["outcome"] == "success"


@pytest.mark.parametrize("value", [0.0, -1.0, 1001.0, "2"])
def test_a_bad_divergence_limit_is_refused(loaded, value):
    scenario, _ = loaded
    with pytest.raises(ConfigError, match="divergence_rms"):
        montecarlo.with_overrides(scenario, {"simulation.divergence_rms": value})


def test_closer_than_half_the_desired_range_is_a_breach_and_timed(loaded):
    scenario, vehicle = loaded
    range_ = _at_rd(scenario)
    range_[100:125] = 3.9  # 25 samples of 0.1 s below r_d / 2 = 4 m: 2.5 s
    summary = summarize(_series(range_), scenario, Termination.COMPLETED, vehicle)
    truth = summary["truth"]
    assert truth["min_range"] == 3.9 and truth["half_desired_range"] == 4.0 and truth["min_range_breached"]
    assert truth["seconds_below_half_desired_range"] == pytest.approx(2.5, abs=1e-9)
    assert truth["outcome"] == "envelope_breached" and not truth["diverged"] and truth_failed(summary)
    assert summary["verdict"] == "clean"  # the estimate was right: the monitor's word stands


def test_exactly_half_the_desired_range_is_no_breach(loaded):
    scenario, vehicle = loaded
    range_ = _at_rd(scenario)
    range_[100] = 4.0
    truth = summarize(_series(range_), scenario, Termination.COMPLETED, vehicle)["truth"]
    assert not truth["min_range_breached"] and truth["seconds_below_half_desired_range"] == 0.0


@pytest.mark.parametrize("peak, exceeded", [(36.0, True), (35.0, False), (34.0, False)])
def test_tilt_above_the_airframe_limit_is_exceeded_and_timed(loaded, peak, exceeded):
    scenario, vehicle = loaded
    assert vehicle.max_tilt_deg == 35.0
    tilt = np.full(N, 20.0)
    tilt[300:312] = peak  # 12 samples: 1.2 s at the peak
    summary = summarize(_series(_at_rd(scenario), tilt=tilt), scenario, Termination.COMPLETED, vehicle)
    truth = summary["truth"]
    assert truth["max_tilt_deg"] == peak and truth["tilt_limit_deg"] == 35.0 and truth["tilt_exceeded"] is exceeded
    assert truth["seconds_above_tilt_limit"] == pytest.approx(1.2 if exceeded else 0.0, abs=1e-9)
    assert truth["outcome"] == ("envelope_breached" if exceeded else "success")
    assert truth_failed(summary) is exceeded


def test_a_flight_that_did_not_fly_is_failed_whatever_its_truth(loaded):
    scenario, vehicle = loaded
    summary = summarize(_series(_at_rd(scenario), 5.0), scenario, Termination.OUT_OF_CONTROL, vehicle)
    assert summary["truth"]["outcome"] == "failed" and summary["verdict"] == "failed"
    assert summary["truth"]["diverged"]  # the flags still say what the truth was


def test_no_estimate_over_the_window_is_its_own_outcome(loaded):
    scenario, vehicle = loaded
    summary = summarize(_series(_at_rd(scenario), math.nan), scenario, Termination.COMPLETED, vehicle)
    assert summary["truth"]["outcome"] == "no_estimate" and summary["verdict"] == "no_estimate"
    assert not summary["truth"]["diverged"]


def test_an_estimate_missing_for_part_of_the_window_counts_as_diverged(loaded):
    scenario, vehicle = loaded
    error = np.where(TIME >= 50.0, math.nan, 0.1)
    summary = summarize(_series(_at_rd(scenario), error), scenario, Termination.COMPLETED, vehicle)
    assert summary["truth"]["diverged"] and summary["verdict"] == "diverged"


def test_a_suspect_monitor_on_a_good_estimate_is_a_false_alarm(loaded):
    scenario, vehicle = loaded
    suspect = np.zeros(N)
    suspect[-50:] = 1.0
    summary = summarize(_series(_at_rd(scenario), 0.2, suspect=suspect), scenario, Termination.COMPLETED, vehicle)
    assert summary["verdict"] == "suspect" and summary["termination"] == "diverged"
    assert summary["truth"]["monitor_false_alarm"] and not summary["truth"]["monitor_missed"]
    assert summary["truth"]["outcome"] == "success"


flags = st.lists(st.sampled_from([0.0, 1.0, math.nan]), min_size=N, max_size=N)


@settings(max_examples=60, deadline=None)
# from 2 m + 1e-9: 8 m + e - 8 m rounds e by up to 2e-15 m, which may bring 2 m + 1 ulp back to 2 m
@given(suspect=flags, error=st.floats(2.0 + 1e-9, 100.0), sign=st.sampled_from([-1.0, 1.0]))
def test_a_flight_above_the_limit_is_never_clean_or_recovered(loaded, suspect, error, sign):
    scenario, vehicle = loaded
    suspect = np.array(suspect)
    summary = summarize(_series(_at_rd(scenario), sign * error, suspect=suspect), scenario, Termination.COMPLETED,
                        vehicle)
    flagged = np.nan_to_num(suspect, nan=0.0) > 0.5
    # the monitor's own word, by its rule: suspect at the end, recovered when flagged before, else clean
    expected_monitor = "suspect" if flagged[-1] else "recovered" if flagged.any() else "clean"
    assert summary["monitor_verdict"] == expected_monitor
    assert summary["verdict"] not in ("clean", "recovered")
    assert summary["verdict"] == ("suspect" if flagged[-1] else "diverged")
    assert summary["truth"]["diverged"] and summary["truth"]["monitor_missed"] is (not flagged[-1])


@settings(max_examples=40, deadline=None)
@given(suspect=flags, error=st.floats(-2.0, 2.0))
def test_a_flight_within_the_limit_keeps_the_monitors_word(loaded, suspect, error):
    scenario, vehicle = loaded
    suspect = np.array(suspect)
    summary = summarize(_series(_at_rd(scenario), error, suspect=suspect), scenario, Termination.COMPLETED, vehicle)
    flagged = np.nan_to_num(suspect, nan=0.0) > 0.5
    assert summary["verdict"] == summary["monitor_verdict"] == (
        "suspect" if flagged[-1] else "recovered" if flagged.any() else "clean")
    assert not summary["truth"]["diverged"] and summary["truth"]["monitor_false_alarm"] is bool(flagged[-1])


# --- bof-sim: closing block and exit status on real flights ----------------------------------------------------------

def _flown(tmp_path) -> tuple[dict, dict]:
    (folder,) = list(tmp_path.iterdir())
    return json.loads((folder / "summary.json").read_text()), dict(np.load(folder / "series.npz"))


def _window_rms(series: dict, window: float) -> float:
    t = series["time"]
    inside = t >= t[-1] - window
    return float(np.sqrt(np.mean((series["range_estimate"][inside] - series["range"][inside]) ** 2)))


#: The earlier defaults these unguarded flights were measured with, as dotted overrides: the range excitation at
#: 4 m/s ramped in from sigma_r / r^ = 0.05, and the IMM's two turn pairs.
EARLIER = {"guidance.excitation_speed": 4.0, "guidance.excitation_low": 0.05, "guidance.excitation_high": 0.15,
           "estimator.imm_turn_rates": [0.2, 0.4]}


def _without_envelope(tmp_path, name: str):
    """A copy of a shipped scenario with [safety] enabled = false (the guidance law's commands as they are) and the
    EARLIER settings, which on stop_and_go lose the range, fly closer than r_d / 2 and tilt past the airframe's
    limit; the vehicle named absolutely."""
    vehicle_file = (SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml").resolve()
    text = (SCENARIOS_DIR / f"{name}.toml").read_text().replace('vehicle = "../vehicles/paper_table1.toml"',
                                                                f'vehicle = "{vehicle_file}"')
    for dotted, value in EARLIER.items():
        section, key = dotted.split(".")
        # the key on the line after its table's header (the header's own comment left as it is)
        text, count = re.subn(rf"^\[{section}\][^\n]*\n", lambda header: f"{header.group(0)}{format_assignment(key, value)}\n",
                              text, count=1, flags=re.MULTILINE)
        assert count == 1, section
    path = tmp_path / f"{name}.toml"
    path.write_text(text + "\n[safety]\nenabled = false\n")
    return path


def test_bof_sim_exits_1_for_a_diverged_flight_that_breaks_both_envelopes(tmp_path, capsys):
    path = _without_envelope(tmp_path, "stop_and_go")
    out_folder = tmp_path / "runs"
    code = bof_sim([str(path), "--out", str(out_folder), "--seed", "1", "--no-plots"])
    out = capsys.readouterr().out
    summary, series = _flown(out_folder)
    scenario, vehicle = load_scenario(path)
    half = scenario.guidance.desired_range / 2
    # the truth by hand from the logged series
    assert _window_rms(series, scenario.simulation.summary_window) > 2.0
    assert float(np.min(series["range"])) < half and float(np.max(series["pursuer_tilt"])) > vehicle.max_tilt_deg
    assert code == 1
    assert summary["truth"]["diverged"] and summary["truth"]["min_range_breached"] and summary["truth"]["tilt_exceeded"]
    assert summary["truth"]["outcome"] == "diverged" and summary["verdict"] not in ("clean", "recovered")
    assert "outcome (truth): DIVERGED" in out
    assert f"closest approach {np.min(series['range']):.2f} m  BREACHED (r_d/2 = {half:.1f} m" in out
    assert f"max tilt {np.max(series['pursuer_tilt']):.1f} deg  BREACHED (limit {vehicle.max_tilt_deg:g} deg" in out


def test_bof_sim_exits_1_when_only_an_envelope_breaks(tmp_path, capsys):
    """The constant-velocity flight started 3 m from the target, the initial estimate exact: the estimate holds,
    the range starts under r_d / 2."""
    text = (SCENARIOS_DIR / "constant_velocity.toml").read_text()
    vehicle_file = (SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml").resolve()
    changes = {'vehicle = "../vehicles/paper_table1.toml"': f'vehicle = "{vehicle_file}"',
               "initial_position = [0.0, 0.0, 0.0]": "initial_position = [47.0, -25.0, -20.0]",
               "initial_position = [40.0, -20.0, -15.0]": "initial_position = [50.0, -25.0, -20.0]"}
    for old, new in changes.items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / "close_start.toml"
    path.write_text(text)
    out_folder = tmp_path / "runs"
    code = bof_sim([str(path), "--out", str(out_folder), "--no-plots"])
    out = capsys.readouterr().out
    summary, series = _flown(out_folder)
    assert float(np.min(series["range"])) < 4.0 and _window_rms(series, 20.0) <= 2.0  # by hand
    assert code == 1 and summary["truth"]["outcome"] == "envelope_breached"
    assert "outcome (truth): ENVELOPE BREACHED" in out and "BREACHED (r_d/2 = 4.0 m" in out


def test_bof_sim_exits_0_for_a_success_and_says_so(tmp_path, capsys):
    code = bof_sim([str(SCENARIOS_DIR / "constant_velocity.toml"), "--out", str(tmp_path), "--no-plots"])
    out = capsys.readouterr().out
    summary, series = _flown(tmp_path)
    assert _window_rms(series, 20.0) <= 2.0 and float(np.min(series["range"])) >= 4.0  # by hand
    assert float(np.max(series["pursuer_tilt"])) <= 35.0
    assert code == 0 and summary["truth"]["outcome"] == "success"
    assert "outcome (truth): success" in out and "BREACHED" not in out and "DIVERGED" not in out


def test_bof_sim_help_states_the_exit_rule(capsys):
    with pytest.raises(SystemExit):
        bof_sim(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "diverged by truth" in out and "r_d / 2" in out and "max_tilt_deg" in out


# --- the monitor while the estimate was wrong ------------------------------------------------------------------------

WINDOW_START = 400  # TIME[400] = 40 s: the first sample of the 20 s summary window (601 samples, 0.1 s apart)


@settings(max_examples=60, deadline=None)
@given(wrong=st.tuples(st.integers(WINDOW_START, 590), st.integers(10, 100)),
       flagged=st.tuples(st.integers(0, 600), st.integers(0, 200)), error=st.floats(10.0, 50.0))
def test_the_seconds_the_monitor_flagged_while_the_estimate_was_wrong(loaded, wrong, flagged, error):
    """An error of `error` m over samples [a, a + n) inside the window (0.5 m elsewhere) and the monitor suspect over
    samples [c, c + m): the estimate was wrong for 0.1 n s (every such sample holds until the next, 0.1 s) and
    flagged for 0.1 x the overlap of the two runs of samples; at least 10 samples of 10 m or more put the window's
    RMS above 2 m, so the flight diverged, and it was silent while wrong exactly when the runs do not overlap."""
    scenario, vehicle = loaded
    (a, n), (c, m) = wrong, flagged
    n = min(n, 600 - a)  # the last sample (t = 60 s) holds for no time: keep the episode before it (a <= 590: n >= 10)
    errors = np.full(N, 0.5)
    errors[a:a + n] = error
    suspect = np.zeros(N)
    suspect[c:min(c + m, N)] = 1.0
    truth = summarize(_series(_at_rd(scenario), errors, suspect=suspect), scenario, Termination.COMPLETED,
                      vehicle)["truth"]
    overlap = max(0, min(a + n, c + m, 600) - max(a, c))
    assert truth["diverged"]
    assert truth["seconds_estimate_wrong"] == pytest.approx(DT * n, abs=1e-9)
    assert truth["seconds_wrong_flagged"] == pytest.approx(DT * overlap, abs=1e-9)
    assert truth["monitor_silent_while_wrong"] is (overlap == 0)


def test_a_wrong_estimate_before_the_window_or_within_the_limit_is_not_counted(loaded):
    scenario, vehicle = loaded
    errors = np.where(TIME < 39.0, 30.0, 1.9)  # far off before the window, within 2 m in it
    truth = summarize(_series(_at_rd(scenario), errors, suspect=np.zeros(N)), scenario, Termination.COMPLETED,
                      vehicle)["truth"]
    assert truth["seconds_estimate_wrong"] == 0.0 and not truth["monitor_silent_while_wrong"]


def test_an_estimate_that_went_missing_is_diverged_but_the_monitor_was_not_silent_while_wrong(loaded):
    """The estimate good until t = 50 s, then none (NaN) to the end: the flight counts as diverged, but no second of
    the window had an estimate more than 2 m off, so the monitor cannot have been silent while it was wrong."""
    scenario, vehicle = loaded
    error = np.where(TIME >= 50.0, math.nan, 0.1)
    truth = summarize(_series(_at_rd(scenario), error, suspect=np.zeros(N)), scenario, Termination.COMPLETED,
                      vehicle)["truth"]
    assert truth["diverged"] and truth["seconds_estimate_wrong"] == 0.0
    assert not truth["monitor_silent_while_wrong"]


def test_without_the_monitors_record_its_silence_is_not_judged(loaded):
    """A log without health_suspect (no monitor verdicts): the flight diverged, but nothing says what the monitor
    said, so it is not called silent."""
    scenario, vehicle = loaded
    truth = summarize(_series(_at_rd(scenario), 3.0), scenario, Termination.COMPLETED, vehicle)["truth"]
    assert truth["diverged"] and truth["seconds_estimate_wrong"] == 0.0
    assert not truth["monitor_silent_while_wrong"]


def test_the_closing_block_says_when_the_monitor_was_silent_while_wrong(loaded):
    from studies.metrics import outcome_lines

    scenario, vehicle = loaded
    errors = np.where((TIME >= 45.0 - 1e-9) & (TIME < 50.0 - 1e-9), 12.0, 0.2)  # 5 s off by 12 m
    silent = summarize(_series(_at_rd(scenario), errors, suspect=np.zeros(N)), scenario, Termination.COMPLETED,
                       vehicle)
    assert "  estimate more than 2 m off for 5.0 s of the last 20 s; the monitor flagged 0.0 s of them  (SILENT while " \
           "it was wrong)" in outcome_lines(silent)
    suspect = np.where(TIME >= 47.0 - 1e-9, 1.0, 0.0)  # from 47 s on: 3 s of the 5
    heard = summarize(_series(_at_rd(scenario), errors, suspect=suspect), scenario, Termination.COMPLETED, vehicle)
    assert "  estimate more than 2 m off for 5.0 s of the last 20 s; the monitor flagged 3.0 s of them" in \
        outcome_lines(heard)
    good = summarize(_series(_at_rd(scenario), 0.2, suspect=np.zeros(N)), scenario, Termination.COMPLETED, vehicle)
    assert not any("off for" in line for line in outcome_lines(good))


# --- bof-montecarlo's truth columns -----------------------------------------------------------------------------------

def test_montecarlo_rows_and_table_count_divergence_and_breaches(tmp_path):
    code = montecarlo.main([str(SCENARIOS_DIR / "stop_and_go.toml"), "--runs", "1", "--executor", "serial",
                            "--case", "unguarded:safety.enabled=false," + ",".join(
                                format_assignment(key, value) for key, value in EARLIER.items()), "--no-plots", "--quiet",
                            "--out", str(tmp_path)])
    assert code == 0
    (folder,) = list(tmp_path.iterdir())
    with (folder / "results.csv").open() as handle:
        (row,) = list(csv.DictReader(handle))
    # seed 1 of stop_and_go without the envelope, with the earlier excitation and turn pairs, flown by bof-sim above: diverged by RMS, closer
    # than r_d / 2, above the tilt limit
    assert (row["diverged_rms"], row["breached_half_rd"], row["tilt_exceeded"]) == ("True", "True", "True")
    (group,) = json.loads((folder / "summary.json").read_text())["groups"]
    assert (group["diverged_rms"], group["breached_half_rd"], group["tilt_exceeded"], group["envelope_breaches"]) == (
        1, 1, 1, 1)
    report = (folder / "summary.md").read_text()
    assert "breached r_d/2 / tilt (any)" in report and "| 1 / 1 (1)" in report
    # the monitor while wrong: the row's seconds as the flight's truth has them, summed in the group
    assert float(row["wrong_flagged_s"]) <= float(row["wrong_s"])
    assert group["wrong_s"] == pytest.approx(float(row["wrong_s"])) and "silent while wrong" in report
    assert group["silent_while_wrong"] == (row["silent_while_wrong"] == "True")


def test_montecarlo_group_counts_a_flight_breaching_both_once(loaded):
    scenario, vehicle = loaded
    base = montecarlo.with_overrides(scenario, {"simulation.duration": 8.0, "simulation.summary_window": 8.0})
    labels = {"scenario": "s", "estimator": "uplkf", "guidance": "hng", "case": "c"}
    row = montecarlo.fly(montecarlo.FlightTask(labels, base, vehicle, 1, 2.0))["row"]
    assert {"diverged_rms", "breached_half_rd", "tilt_exceeded"} <= row.keys()
    flags = [(True, False, True), (False, True, False), (True, True, False), (False, False, False)]
    rows = [dict(row, seed=k + 1, breached_half_rd=b, tilt_exceeded=t, diverged_rms=d)
            for k, (b, t, d) in enumerate(flags)]
    (entry,) = montecarlo.group_table(rows)
    assert (entry["breached_half_rd"], entry["tilt_exceeded"], entry["envelope_breaches"], entry["diverged_rms"]) == (
        2, 2, 3, 1)


def test_montecarlo_counts_the_monitors_misses_against_the_rms_truth(loaded):
    """The table's missed / false alarms judge the monitor's flag at the end against diverged_rms, the truth each
    flight's summary and bof-sim judge by, not against the last-5-s mean (`diverged`): four flights, each pairing of
    the two, none diverged by the last-5-s mean (judged by it, there would be no miss and two false alarms)."""
    scenario, vehicle = loaded
    base = montecarlo.with_overrides(scenario, {"simulation.duration": 8.0, "simulation.summary_window": 8.0})
    labels = {"scenario": "s", "estimator": "uplkf", "guidance": "hng", "case": "c"}
    row = montecarlo.fly(montecarlo.FlightTask(labels, base, vehicle, 1, 2.0))["row"]
    pairs = [(True, True), (True, False), (False, True), (False, False)]  # (diverged_rms, flagged)
    rows = [dict(row, seed=k + 1, diverged_rms=d, flagged=f, diverged=False) for k, (d, f) in enumerate(pairs)]
    (entry,) = montecarlo.group_table(rows)
    assert (entry["missed"], entry["false_alarms"], entry["flagged"]) == (1, 1, 2)


# --- bof-sitl's exit status and the closing block from summary.json ---------------------------------------------------

def _truth(**flags) -> dict:
    return {"truth": {"diverged": False, "min_range_breached": False, "tilt_exceeded": False, **flags}}


@pytest.mark.parametrize("code, summary, expected", [
    (0, {"flight": _truth()}, 0),
    (0, {"flight": _truth(diverged=True)}, 1),
    (0, {"flight": _truth(min_range_breached=True)}, 1),
    (0, {"flight": _truth(tilt_exceeded=True)}, 1),
    (0, {"flight": None}, 0),  # no figures: run() has already made the code 1 in that case
    (130, {"flight": _truth(diverged=True)}, 130),  # an interrupt keeps 128 + signal
    (0, {"pursuers": [{"pursuer": 1, **_truth()}, {"pursuer": 2, **_truth(tilt_exceeded=True)}]}, 1),
    (0, {"pursuers": [{"pursuer": 1, **_truth()}, {"pursuer": 2, "flight_error": "no series"}]}, 0),
])
def test_bof_sitl_exit_status_judges_the_truth(code, summary, expected):
    from studies.full_sitl import judged_exit_code

    assert judged_exit_code(code, summary) == expected


def test_the_closing_block_reads_a_summary_json_with_nulls(loaded, tmp_path):
    from studies.metrics import outcome_lines, write_summary

    scenario, vehicle = loaded
    range_ = _at_rd(scenario)
    range_[10:20] = 2.0
    summary = summarize(_series(range_, np.where(TIME >= 59.0, math.nan, 0.1), tilt=40.0), scenario,
                        Termination.COMPLETED, vehicle)
    write_summary(tmp_path / "summary.json", summary)
    lines = outcome_lines(json.loads((tmp_path / "summary.json").read_text()), "pursuer 2")
    assert lines[0] == "outcome (truth, pursuer 2): DIVERGED: range estimate wrong by truth; monitor verdict: clean  " \
                       "(the monitor missed it)"
    assert lines[1] == "  range-estimation rms n/a over the last 20 s  DIVERGED (limit 2 m)"
    assert lines[2] == "  closest approach 2.00 m  BREACHED (r_d/2 = 4.0 m, 1.0 s below)"
    assert lines[3] == "  max tilt 40.0 deg  BREACHED (limit 35 deg, 60.0 s above)"


def test_the_closing_block_blames_no_monitor_for_a_flight_that_did_not_fly(loaded):
    """A flight the autopilot's failsafe ended early whose estimate was off: the truth says FAILED and the verdict
    is "failed" (from the termination); the monitor judged nothing, so the line says nothing of a miss."""
    from studies.metrics import outcome_lines

    scenario, vehicle = loaded
    summary = summarize(_series(_at_rd(scenario), np.full(TIME.shape, 5.0)), scenario, Termination.FAILSAFE, vehicle)
    assert summary["truth"]["outcome"] == "failed" and summary["truth"]["monitor_missed"]
    line = outcome_lines(summary)[0]
    assert line == "outcome (truth): FAILED: the flight did not fly as asked; monitor verdict: failed"


def test_bof_sim_exits_1_when_any_pursuer_of_a_swarm_is_judged_bad(tmp_path, capsys):
    """swarm_turning with a divergence limit of 1 cm (its pursuers' RMS is 0.15-0.19 m at seed 1): every pursuer
    diverged by that limit, so the command fails, and each pursuer's closing block says so."""
    text = (SCENARIOS_DIR / "swarm_turning.toml").read_text()
    vehicle_file = (SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml").resolve()
    for old, new in (('vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{vehicle_file}"'),
                     ("[simulation]\n", "[simulation]\ndivergence_rms = 0.01\n")):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / "swarm_strict.toml"
    path.write_text(text)
    code = bof_sim([str(path), "--out", str(tmp_path / "runs"), "--no-plots", "--seed", "1"])
    out = capsys.readouterr().out
    (folder,) = list((tmp_path / "runs").iterdir())
    series = np.load(folder / "series.npz")
    for ident in (1, 2, 3):  # by hand from each pursuer's logged series
        t, error = series[f"p{ident}_time"], series[f"p{ident}_range_estimate"] - series[f"p{ident}_range"]
        assert np.sqrt(np.mean(error[t >= t[-1] - 20.0] ** 2)) > 0.01
        assert f"outcome (truth, pursuer {ident}): DIVERGED" in out
    assert code == 1 and "DIVERGED (limit 0.01 m)" in out
