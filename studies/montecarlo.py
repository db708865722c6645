"""`bof-montecarlo`: seeded Monte Carlo over estimators x guidance laws x parameter cases.

    bof-montecarlo [SCENARIO.toml ...] --runs 20 --estimators uplkf ekf --guidance hng ppg
                   [--case NAME:key=value,key=value ...] [--initial-box X0,X1,Y0,Y1,Z0,Z1]
                   [--executor local|serial|dask-local|tcp://host:port] [--workers 2] [--out runs]
    bof-montecarlo --study estimators|guidance|table2 [--runs N] ...   # the paper's section VIII-B/C/D
    bof-montecarlo --study maneuvering [--runs N] ...   # the maneuvering-target scenarios x 5/50 Hz

Every flight is the in-process simulator (studies.closed_loop.simulate): the same
pipeline object as the networked companion, only the estimator / guidance / parameters
named by its case changed. Runs are seeded 1..N; a flight depends only on its scenario,
case and seed, so the results are the same whichever executor ran them.

Estimators (names -> [estimator] settings): by default each scenario's own [estimator] (the
schema's default is the IMM); imm (the interacting multiple model over u-PLKF model
filters), uplkf (gain from the predicted line of sight), uplkf_paper (the paper's exact
u-PLKF), uplkf_optimal (noise-free projection, simulation only), ekf (azimuth/elevation,
Cartesian), msc_ekf (modified spherical coordinates), ekf_rae (seed 003's
range/azimuth/elevation EKF; adds a 1 m range sensor). The paper's studies (estimators,
guidance, table2) fly the paper's system: the health monitor reports but does not act.
Guidance: hng, hng_planar (c_Y = 0), ppg, png, pd, retro_png, zem.

Per flight (results.csv): final_error, mean |range-estimation error| over the last 5 s;
rms_error over the scenario's summary window; diverged: the flight did not complete or
final_error > --divergence-threshold (default 2 m); lost: mean |range - r_d| over the last
5 s > the same threshold (the guidance did not hold the following distance); flagged: the
companion's truth-free health monitor (companion.core.health) judged the estimate suspect at
the end of the flight (the group table counts the flights diverged by RMS, as below, that it missed and its false
alarms, flagged but not diverged by RMS); diverged_rms: the range-estimation error RMS over the summary window > [simulation]
divergence_rms (default 2 m: the truth's "diverged" of studies.metrics.summarize, which bof-sim and
bof-sitl judge by); breached_half_rd: the closest approach over the flight < r_d / 2; tilt_exceeded:
the max tilt > the vehicle's max_tilt_deg (the group table counts both, and the flights with either
as envelope_breaches); plus convergence time, min range, max tilt, the windowed-FIM observability. Time series at
0.2 s go to series.npz for the figures. Output in runs/montecarlo-<label>-<time>/:
results.csv, summary.md, summary.json, series.npz, and the figures (error over time per
group, trajectories and normalised image-plane tracks of the first seed of each group).
A progress bar runs on stderr (--quiet: none).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from interfaces.run_folders import new_run_folder
from interfaces.records import CsvLog
from interfaces.overrides import apply_overrides, parse_assignment
from interfaces.scenario import SCENARIOS_DIR, ConfigError, Scenario, VehicleConfig, load_scenario
from studies.closed_loop import Termination, simulate
from studies import reporting
from studies.executors import check_executor, check_flight_count, make_executor
from studies.processes import Interrupted, RaisingStopSignals
from studies.metrics import write_summary
from interfaces.cli import CommandParser, output_folder, scenario_file

SCENARIOS = SCENARIOS_DIR
DEFAULT_SCENARIO = SCENARIOS / "constant_velocity.toml"
SAMPLE_PERIOD = 0.2  # s, time grid of the stored series
FINAL_WINDOW = 5.0  # s, the end of the flight that decides divergence

#: estimator name -> scenario overrides (dotted keys)
ESTIMATORS: dict[str, dict[str, Any]] = {
    "uplkf": {"estimator.kind": "uplkf", "estimator.gain_projection": "predicted"},
    "uplkf_paper": {"estimator.kind": "uplkf", "estimator.gain_projection": "measured"},
    "uplkf_optimal": {"estimator.kind": "uplkf", "estimator.gain_projection": "noise_free"},
    "ekf": {"estimator.kind": "ekf", "estimator.gain_projection": "predicted"},
    "msc_ekf": {"estimator.kind": "msc_ekf", "estimator.gain_projection": "predicted"},
    "ekf_rae": {"estimator.kind": "ekf_rae", "estimator.gain_projection": "predicted", "sensor.range_noise_std": 1.0},
    "imm": {"estimator.kind": "imm", "estimator.gain_projection": "predicted"},
}
#: The paper's estimators (section VIII-B's comparison); "imm" is not one of them
PAPER_ESTIMATORS = ("uplkf", "uplkf_paper", "uplkf_optimal", "ekf", "msc_ekf", "ekf_rae")
#: --estimators default outside a study: each scenario's own [estimator] (rows labelled with its kind)
SCENARIO_ESTIMATOR = "scenario"
#: The paper's comparisons fly the paper's system: the filter-health monitor reports but does not act, and the
#: guidance laws fly as printed, without the range excitation the defaults add to HNG and PPG
PAPER_SYSTEM = {"health.act": False, "guidance.excitation": "none"}
#: guidance name -> scenario overrides
GUIDANCE: dict[str, dict[str, Any]] = {
    "hng": {"guidance.law": "hng"},
    "hng_planar": {"guidance.law": "hng", "guidance.c_y": 0.0},
    "ppg": {"guidance.law": "ppg"},
    "png": {"guidance.law": "png"},
    "pd": {"guidance.law": "pd"},
    "retro_png": {"guidance.law": "retro_png"},
    "zem": {"guidance.law": "zem"},
}
#: Table II of the paper: HNG parameter sets (N, c_Z, c_Y)
TABLE_II = {"a": (1.0, 3.0, 3.0), "b": (3.0, 3.0, 3.0), "c": (3.0, 3.0, 0.0), "d": (3.0, 3.5, 3.5)}
#: Section VIII-B: the initial estimate drawn uniformly in this box (x0, x1, y0, y1, z0, z1), m
PAPER_INITIAL_BOX = (20.0, 120.0, -50.0, 50.0, -50.0, 50.0)
#: The maneuvering targets (config/scenarios/, sitl_plant/world/target.py), flown with the defaults
MANEUVERING_SCENARIOS = ("circle_5ms", "circle_10ms", "helix_climb", "weave", "turn90_5ms", "stop_and_go", "singer",
                         "seed003_straight", "seed003_vertical", "seed003_helix", "hover_dash", "orbit_tight",
                         "orbit_tight_05", "replay_csv")


@dataclass(frozen=True)
class Study:
    """A named grid: scenarios x estimators x guidance x cases."""

    label: str
    scenarios: tuple[str, ...]
    estimators: tuple[str, ...]
    guidance: tuple[str, ...]
    cases: tuple[tuple[str, dict[str, Any]], ...]
    initial_box: tuple[float, ...] | None = None
    curves_by: str | None = None
    title: str = ""
    windows: tuple[tuple[float, float], ...] = ()
    runs: int = 10  # seeded flights per grid point unless --runs says
    overrides: tuple[tuple[str, Any], ...] = ()  # applied to every flight of the study, before the cases


STUDIES: dict[str, Study] = {
    "estimators": Study(
        "estimators", ("constant_velocity",), PAPER_ESTIMATORS, ("hng",),
        (("5Hz", {"sensor.rate_hz": 5.0}), ("50Hz", {"sensor.rate_hz": 50.0})),
        initial_box=PAPER_INITIAL_BOX, curves_by="estimator", windows=((5.0, 15.0), (15.0, 30.0), (30.0, 60.0)), runs=100,
        overrides=tuple(PAPER_SYSTEM.items()),
        title="Section VIII-B (Fig. 10): estimators, initial estimate uniform in x [20,120], y, z [-50,50] m"),
    "guidance": Study(
        "guidance", ("constant_velocity", "s_maneuver"), ("uplkf",), tuple(GUIDANCE), (("default", {}),),
        curves_by="guidance", windows=((10.0, 30.0), (30.0, 60.0)), overrides=tuple(PAPER_SYSTEM.items()),
        title="Section VIII-C (Figs. 11-12): guidance laws, constant-velocity and maneuvering targets"),
    "table2": Study(
        "table2", ("s_maneuver",), ("uplkf",), ("hng",),
        tuple((name, {"guidance.navigation_gain": n, "guidance.c_z": cz, "guidance.c_y": cy})
              for name, (n, cz, cy) in TABLE_II.items()),
        curves_by="case", windows=((10.0, 30.0), (30.0, 60.0)), overrides=tuple(PAPER_SYSTEM.items()),
        title="Section VIII-D (Table II, Figs. 13-14): HNG parameter sets on the maneuvering target"),
    "maneuvering": Study(
        "maneuvering", MANEUVERING_SCENARIOS, ("imm",), ("hng",),
        (("5Hz", {"sensor.rate_hz": 5.0}), ("50Hz", {"sensor.rate_hz": 50.0})),
        curves_by="case", windows=((10.0, 30.0), (30.0, 60.0)), runs=20,
        title="Maneuvering targets (circles, helices, weave, turn, stop-and-go, Singer, seed 003) "
              "x bearings at 5 and 50 Hz, the defaults: IMM, acting health monitor, HNG"),
}


@dataclass(frozen=True)
class FlightTask:
    """One flight: its labels, the fully resolved scenario and vehicle, its seed."""

    labels: dict[str, str]
    scenario: Scenario
    vehicle: VehicleConfig
    seed: int
    divergence_threshold: float
    windows: tuple[tuple[float, float], ...] = ()


def with_overrides(scenario: Scenario, overrides: dict[str, Any]) -> Scenario:
    """The scenario with dotted-key overrides applied and validated ("guidance.c_y": 0.0; interfaces.overrides)."""
    return apply_overrides(scenario, overrides, f"overrides {overrides}")


def drawn_initial_position(seed: int, box: tuple[float, ...]) -> tuple[float, float, float]:
    """The initial estimate of run `seed`, uniform in box (x0, x1, y0, y1, z0, z1), section VIII-B.

    Drawn from its own generator keyed on the seed only, so every estimator of a seed starts
    from the same point ("with the same initialization, each quadrotor...").
    """
    rng = np.random.default_rng([int(seed), 8])
    low, high = np.array(box[0::2]), np.array(box[1::2])
    return tuple(float(v) for v in rng.uniform(low, high))


#: Keys a case may not set: the runner sets them itself, so the case's value would be silently ignored.
_RUNNER_KEYS = {"simulation.seed": "--runs sets the seeds (1..N)",
                "vehicle": "a case cannot change the vehicle file: give a scenario file that names it"}


def _assignments(body: str) -> list[str]:
    """body split at the commas between assignments, not those inside a TOML array, table or string."""
    items, depth, quote, start = [], 0, "", 0
    for index, char in enumerate(body):
        if quote:
            quote = "" if char == quote else quote
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
        elif char in "]}":
            depth -= 1
        elif char == "," and depth == 0:
            items.append(body[start:index])
            start = index + 1
    items.append(body[start:])
    return items


def parse_case(text: str) -> tuple[str, dict[str, Any]]:
    """'NAME:key=value,key=value' -> (NAME, overrides); values are TOML literals (interfaces.overrides), arrays
    included ("x:pursuer.initial_position=[1,2,3]")."""
    name, _, body = text.partition(":")
    if not name or not body:
        raise ValueError(f"case {text!r}: expected NAME:key=value[,key=value]")
    overrides = dict(parse_assignment(item, f"case {text!r}:") for item in _assignments(body))
    for key in overrides:
        if key in _RUNNER_KEYS:
            raise ValueError(f"case {text!r}: {key}: {_RUNNER_KEYS[key]}")
    return name, overrides


def build_tasks(scenarios: list[tuple[Scenario, VehicleConfig]], estimators: list[str], guidance: list[str],
                cases: list[tuple[str, dict[str, Any]]], runs: int, initial_box: tuple[float, ...] | None,
                divergence_threshold: float, *, duration: float | None = None,
                windows: tuple[tuple[float, float], ...] = (), base_overrides: dict[str, Any] | None = None) -> list[FlightTask]:
    """Every (scenario, estimator, guidance, case, seed) combination, resolved and validated up front.

    estimator SCENARIO_ESTIMATOR keeps each scenario's own [estimator] and labels the rows with its kind.
    Overrides apply in this order: base_overrides (a study's), the estimator's, the guidance law's, the case's."""
    tasks = []
    for (scenario, vehicle), estimator, law, (case, overrides) in itertools.product(scenarios, estimators, guidance, cases):
        own = estimator == SCENARIO_ESTIMATOR
        combined = {**(base_overrides or {}), **({} if own else ESTIMATORS[estimator]), **GUIDANCE[law], **overrides}
        if duration is not None:
            combined["simulation.duration"] = duration
            combined["simulation.summary_window"] = min(scenario.simulation.summary_window, duration)
        base = with_overrides(scenario, combined)
        labels = {"scenario": scenario.name, "estimator": base.estimator.kind if own else estimator, "guidance": law, "case": case}
        for seed in range(1, runs + 1):
            flown = base
            if initial_box is not None:
                flown = with_overrides(base, {"estimator.initialize": "position",
                                              "estimator.initial_position": drawn_initial_position(seed, initial_box)})
            tasks.append(FlightTask(labels, flown, vehicle, seed, divergence_threshold, tuple(windows)))
    return tasks


def image_plane(relative: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Target in the normalised image plane of a vertical camera with the vehicle's position and yaw
    (section VIII-D, Fig. 14): (x_n, y_n) = (d.right, d.down) / (d.forward), shape (N, 2); NaN behind.

    relative: p_T - p, (N, 3), NED. forward: the body x axis in NED, (N, 3) (only its yaw is used).
    """
    yaw = np.arctan2(forward[:, 1], forward[:, 0])
    ahead = relative[:, 0] * np.cos(yaw) + relative[:, 1] * np.sin(yaw)
    right = -relative[:, 0] * np.sin(yaw) + relative[:, 1] * np.cos(yaw)
    with np.errstate(invalid="ignore", divide="ignore"):
        points = np.stack([right / ahead, relative[:, 2] / ahead], axis=1)
    points[ahead <= 1e-6] = np.nan
    return points


def _resample(time: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    if values.ndim == 1:
        return np.interp(grid, time, values, left=np.nan, right=np.nan)
    return np.stack([_resample(time, values[:, k], grid) for k in range(values.shape[1])], axis=1)


def fly(task: FlightTask) -> dict:
    """One flight -> its row of figures and its series on the 0.2 s grid (module level: picklable)."""
    scenario = task.scenario
    result = simulate(scenario, task.vehicle, task.seed)
    series, summary = result.series, result.summary
    t = series["time"]
    error = np.abs(series["range_estimate"] - series["range"])
    range_error = np.abs(series["range"] - scenario.guidance.desired_range)
    end = t >= t[-1] - FINAL_WINDOW
    final_error = float(np.mean(error[end])) if np.all(np.isfinite(error[end])) else math.inf
    final_range_error = float(np.mean(range_error[end]))
    completed = result.termination is Termination.COMPLETED and t[-1] >= scenario.simulation.duration - 1e-6
    engaged = np.isfinite(series["estimate_position"][:, 0])
    row = {
        **task.labels, "seed": task.seed,
        "termination": summary["termination"],  # studies.metrics: completed, diverged (suspect at the end), ...
        "diverged": bool(not completed or not final_error <= task.divergence_threshold),
        "lost": bool(not completed or not final_range_error <= task.divergence_threshold),
        # the companion's own, truth-free verdict (companion.core.health): suspect at the end of the flight
        "flagged": bool(summary["suspected_divergence"]["at_end"]),
        # ... and at any time: "clean" only when never flagged (studies.metrics.verdict)
        "verdict": summary["verdict"],
        # the truth of studies.metrics.summarize: RMS over the summary window > [simulation] divergence_rms, and the
        # envelopes (closest approach < r_d / 2 over the whole flight, max tilt > the vehicle's max_tilt_deg)
        "diverged_rms": summary["truth"]["diverged"],
        "breached_half_rd": summary["truth"]["min_range_breached"],
        "tilt_exceeded": summary["truth"]["tilt_exceeded"],
        # the monitor while it mattered: seconds of the window with the estimate off by more than the limit, the
        # seconds of those it said suspect, and a diverged flight it never flagged while so wrong
        "wrong_s": summary["truth"]["seconds_estimate_wrong"],
        "wrong_flagged_s": summary["truth"]["seconds_wrong_flagged"],
        "silent_while_wrong": summary["truth"]["monitor_silent_while_wrong"],
        "final_error": final_error,
        "rms_error": summary["range_estimation_error_rms"],
        "final_range_error": final_range_error,
        "range_error_rms": summary["range_error_rms"],
        "convergence_time": summary["convergence_time"],
        "min_range": float(np.min(series["range"][engaged])) if engaged.any() else math.nan,
        "max_tilt_deg": summary["max_tilt_deg"],
        "observability_log_det": summary["observability_log_det_median"],
        "reinitialized": summary.get("reinitializations", 0),
        "initial_estimate": json.dumps(list(scenario.estimator.initial_position or ())),
        "flown_s": float(t[-1]),  # simulated seconds flown (the throughput figure counts these)
    }
    for start, stop in task.windows:  # mean |range-estimation error| inside each requested window
        inside = (t >= start) & (t < stop)
        row[window_key(start, stop)] = float(np.mean(error[inside])) if inside.any() else math.nan
    grid = np.arange(0.0, scenario.simulation.duration + 1e-9, SAMPLE_PERIOD)
    relative = series["target_position"] - series["pursuer_position"]
    samples = {
        "time": grid,
        "range_estimation_error": _resample(t, series["range_estimate"] - series["range"], grid),
        "range": _resample(t, series["range"], grid),
        "pursuer_position": _resample(t, series["pursuer_position"], grid),
        "target_position": _resample(t, series["target_position"], grid),
        "estimate_position": _resample(t, series["estimate_position"], grid),
        "image_plane": _resample(t, image_plane(relative, series["pursuer_forward"]), grid),
    }
    return {"row": row, "series": samples}


# --------------------------------------------------------------------------- summaries


def window_key(start: float, stop: float) -> str:
    return f"error_{start:g}-{stop:g}s"


def parse_window(text: str) -> tuple[float, float]:
    """'A:B' (s) -> (A, B) with 0 <= A < B."""
    start, _, stop = text.partition(":")
    try:
        window = (float(start), float(stop))
    except ValueError:
        raise ValueError(f"--error-window {text!r}: expected START:STOP in seconds") from None
    if not (0.0 <= window[0] < window[1]):
        raise ValueError(f"--error-window {text!r}: need 0 <= START < STOP")
    return window


#: group-table figure -> (results.csv column, statistic over the group's runs; NaN and inf skipped)
GROUP_FIGURES = {
    "runs": ("seed", "size"), "diverged": ("diverged", "sum"), "diverged_rms": ("diverged_rms", "sum"), "lost": ("lost", "sum"),
    "flagged": ("flagged", "sum"), "missed": ("missed", "sum"), "false_alarms": ("false_alarm", "sum"),
    "breached_half_rd": ("breached_half_rd", "sum"), "tilt_exceeded": ("tilt_exceeded", "sum"),
    "silent_while_wrong": ("silent_while_wrong", "sum"), "wrong_s": ("wrong_s", "sum"),
    "wrong_flagged_s": ("wrong_flagged_s", "sum"),
    "envelope_breaches": ("envelope_breached", "sum"),
    "final_error_median": ("final_error", "median"), "final_error_p90": ("final_error", lambda values: values.quantile(0.9)),
    "rms_error_median_kept": ("rms_error_kept", "median"), "range_error_rms_median": ("range_error_rms", "median"),
    "converged_runs": ("convergence_time", "count"), "convergence_time_median": ("convergence_time", "median"),
    "min_range": ("min_range", "min"), "max_tilt_deg": ("max_tilt_deg", "max"),
    "observability_log_det_median": ("observability_log_det", "median"),
}


def group_table(rows: list[dict]) -> list[dict]:
    """One line per (scenario, estimator, guidance, case): divergence (both definitions) and envelope breaches
    counted (envelope_breaches: flights closer than r_d / 2 or above the tilt limit, or both), then robust statistics
    (medians over the runs with a finite figure; the RMS error over the runs that did not diverge)."""
    windows = [key for key in rows[0] if key.startswith("error_")] if rows else []
    rows = [{**row, "rms_error_kept": math.nan if row["diverged"] else row["rms_error"],
             # judged against the truth bof-sim judges by (the RMS over the summary window), as the flight's summary is
             "missed": row["diverged_rms"] and not row["flagged"],
             "false_alarm": row["flagged"] and not row["diverged_rms"],
             "envelope_breached": row["breached_half_rd"] or row["tilt_exceeded"]}
            for row in rows]
    figures = {**GROUP_FIGURES, **{f"{key}_median": (key, "median") for key in windows}}
    finite = ["final_error", "rms_error_kept", "range_error_rms", "convergence_time", "min_range", "max_tilt_deg",
              "observability_log_det", *windows]
    return reporting.summarize(rows, ["scenario", "estimator", "guidance", "case"], figures, finite)


def markdown(table: list[dict], title: str, runs: int, threshold: float, executor: str) -> str:
    windows = [key[: -len("_median")] for key in (table[0] if table else {}) if key.startswith("error_")]
    headers = ["scenario", "estimator", "guidance", "case", "diverged", "diverged (RMS)", "lost", "flagged (missed / false)",
               "breached r_d/2 / tilt (any)", "silent while wrong (flagged s / wrong s)",
               "final error median / p90",
               "RMS error median (kept)", "range error RMS median", "converged runs, median time (s)", "min range (m)",
               "max tilt (deg)", "log10 det FIM median",
               *(f"mean abs error {key[len('error_'):]}, median" for key in windows)]
    f = reporting.cell
    lines = [dict(zip(headers, (
        e["scenario"], e["estimator"], e["guidance"], e["case"], f"{e['diverged']}/{e['runs']}",
        f"{e['diverged_rms']}/{e['runs']}", f"{e['lost']}/{e['runs']}",
        f"{e['flagged']}/{e['runs']} ({e['missed']} / {e['false_alarms']})",
        f"{e['breached_half_rd']} / {e['tilt_exceeded']} ({e['envelope_breaches']})",
        f"{e['silent_while_wrong']} ({e['wrong_flagged_s']:.1f} / {e['wrong_s']:.1f})",
        f"{f(e['final_error_median'])} / {f(e['final_error_p90'])}", f(e["rms_error_median_kept"], 3),
        f(e["range_error_rms_median"], 3), f"{e['converged_runs']}, {f(e['convergence_time_median'], 1)}",
        f(e["min_range"]), f(e["max_tilt_deg"], 1), f(e["observability_log_det_median"], 1),
        *(f(e[key + "_median"], 3) for key in windows)))) for e in table]
    return "\n".join([
        f"# {title}", "",
        f"{runs} seeded runs per row (seeds 1..{runs}); executor: {executor}. diverged: did not complete, or mean "
        f"|range-estimation error| over the last {FINAL_WINDOW:g} s > {threshold:g} m. lost: mean |range - r_d| "
        f"over the last {FINAL_WINDOW:g} s > {threshold:g} m. flagged: the companion's health monitor judged the "
        "estimate suspect at the end of the flight, without truth; missed: diverged (RMS) but not flagged; false: "
        "flagged but not diverged (RMS). diverged (RMS): range-estimation error RMS over the last summary window > the scenario's "
        "[simulation] divergence_rms (the truth bof-sim judges by). breached: flights whose closest approach came "
        "under r_d / 2, flights tilted past the vehicle's max_tilt_deg, and (any) flights with either. silent while "
        "wrong: diverged (RMS) flights in which the monitor never said suspect while the range-estimation error was "
        "above the limit in the summary window, with the seconds it did say so of all the seconds the error was above "
        "it (summed over the runs). "
        "Error statistics in m; final error over all runs, "
        "RMS (last summary window) over the runs that did not diverge.", "",
        reporting.markdown(lines, headers)]) + "\n"


# --------------------------------------------------------------------------- runner


def run_tasks(tasks: list[FlightTask], executor_spec: str, workers: int | None, folder: Path,
              progress: bool = True,
              throughput: reporting.Throughput | None = None) -> tuple[list[dict], dict[str, np.ndarray], str]:
    """Fly every task; rows in task order. Each row is appended to results.partial.csv as soon as it
    arrives (an interrupted campaign keeps what it flew); the ordered results.csv replaces it at the end.
    throughput: counts each flight's simulated seconds as it arrives, and stops when the last one has."""
    executor = make_executor(executor_spec, workers, say=reporting.say_as("bof-montecarlo"))
    if throughput is not None:
        throughput.executor = executor.name
    rows: list[dict | None] = [None] * len(tasks)
    series: list[dict | None] = [None] * len(tasks)
    bar = reporting.progress_bar(len(tasks), "flights", enabled=progress, description="bof-montecarlo")
    partial = None
    try:
        for index, result in executor.map(fly, tasks):
            rows[index], series[index] = result["row"], result["series"]
            if partial is None:
                partial = CsvLog(folder / "results.partial.csv", ["index", *result["row"]])
            partial.write({"index": index, **result["row"]})
            if throughput is not None:
                throughput.add(result["row"]["flown_s"])
            bar.update()
    finally:
        bar.close()
        name = executor.name  # after map: a local pool starts no more processes than tasks
        if throughput is not None:
            throughput.executor = name
            throughput.stop()
        executor.close()
        if partial is not None:
            partial.close()
    ordered = [row for row in rows if row is not None]
    results = CsvLog(folder / "results.csv", ordered[0])
    for row in ordered:
        results.write(row)
    results.close()
    partial.path.unlink()
    return ordered, stack_series(series), name


def stack_series(series: list[dict | None]) -> dict[str, np.ndarray]:
    """The flights' series on the common SAMPLE_PERIOD grid, one leading axis over flights (shape (flights, samples, ...)).

    Scenarios of different durations give grids of different lengths: the shorter ones are padded with NaN
    (no sample there), and `time` is the longest flight's grid."""
    kept = [s for s in series if s is not None]
    if not kept:
        return {}
    longest = max(kept, key=lambda s: len(s["time"]))
    stacked = {"time": np.stack([longest["time"]] * len(kept))}
    for key in kept[0]:
        if key == "time":
            continue
        arrays = [s[key] for s in kept]
        length = max(len(a) for a in arrays)
        padded = np.full((len(arrays), length, *arrays[0].shape[1:]), np.nan)
        for row, values in zip(padded, arrays):
            row[: len(values)] = values
        stacked[key] = padded
    return stacked


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-montecarlo` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-montecarlo", description=__doc__.split("\n\n")[0])
    parser.add_argument("scenarios", nargs="*", type=scenario_file, help=f"scenario files (default {DEFAULT_SCENARIO.name})")
    parser.add_argument("--study", choices=list(STUDIES), help="a preset grid: the paper's comparisons (estimators, guidance, table2) or the "
                        "maneuvering targets")
    parser.add_argument("--runs", type=int, default=None, help="seeded flights per grid point (default 10; 100 for --study estimators, "
                        "20 for --study maneuvering)")
    parser.add_argument("--estimators", nargs="+", choices=list(ESTIMATORS),
                        help="estimators to compare (default: each scenario's own [estimator], or the study's set)")
    parser.add_argument("--guidance", nargs="+", choices=list(GUIDANCE),
                        help="guidance laws to compare (default hng, or the study's set)")
    parser.add_argument("--case", action="append", default=None, metavar="NAME:key=value,...",
                        help="a named set of scenario overrides (repeat for a grid), e.g. planar:guidance.c_y=0")
    parser.add_argument("--initial-box", type=str, default=None, metavar="X0,X1,Y0,Y1,Z0,Z1",
                        help="draw each run's initial estimate uniformly in this box, m (section VIII-B)")
    parser.add_argument("--duration", type=float, default=None, help="override the scenarios' duration, s")
    parser.add_argument("--error-window", action="append", default=None, metavar="START:STOP",
                        help="also report the mean |range-estimation error| in this window, s (repeatable)")
    parser.add_argument("--divergence-threshold", type=float, default=2.0, help="m (see the module docstring)")
    parser.add_argument("--executor", default="local", help="local (default), serial, dask-local, or tcp://scheduler:port")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    parser.add_argument("--out", type=output_folder, default=Path("runs"),
                        help="parent folder: the run folder montecarlo-<study, or grid>-<time>/ is made inside it (default runs/)")
    parser.add_argument("--no-plots", action="store_true", help="write the tables and series only, no PNG figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar (it goes to stderr)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)

    study = STUDIES.get(args.study) if args.study else None
    runs = args.runs if args.runs is not None else (study.runs if study else 10)
    if runs < 1 or (args.workers is not None and args.workers < 1) or not 0 < args.divergence_threshold < math.inf:
        print("bof-montecarlo: --runs and --workers must be >= 1, --divergence-threshold > 0 and finite", file=sys.stderr)
        return 2
    try:
        check_executor(args.executor, args.workers)
        paths = args.scenarios or ([SCENARIOS / f"{name}.toml" for name in study.scenarios] if study else [DEFAULT_SCENARIO])
        scenarios = [load_scenario(path) for path in paths]
        estimators = args.estimators or (list(study.estimators) if study else [SCENARIO_ESTIMATOR])
        guidance = args.guidance or (list(study.guidance) if study else ["hng"])
        cases = [parse_case(text) for text in args.case] if args.case else (list(study.cases) if study else [("default", {})])
        box = study.initial_box if study else None
        if args.initial_box:
            box = tuple(float(v) for v in args.initial_box.split(","))
            if len(box) != 6 or not all(map(math.isfinite, box)) or any(box[2 * k] > box[2 * k + 1] for k in range(3)):
                raise ValueError("--initial-box needs X0,X1,Y0,Y1,Z0,Z1, finite, with each low <= high")
        windows = [parse_window(text) for text in args.error_window] if args.error_window else (list(study.windows) if study else [])
        # A name given twice would put two sets of flights (or the same seeds twice) in one row of the table.
        for flag, names in (("scenario", [scenario.name for scenario, _ in scenarios]), ("--estimators", estimators),
                            ("--guidance", guidance), ("--case", [name for name, _ in cases])):
            repeated = sorted({name for name in names if names.count(name) > 1})
            if repeated:
                raise ValueError(f"{flag} {', '.join(repeated)} given twice: its rows would mix two sets of flights")
        check_flight_count(len(scenarios) * len(estimators) * len(guidance) * len(cases) * runs,
                           "the scenarios x estimators x guidance laws x cases x --runs")
        shortest = args.duration if args.duration is not None else min(scenario.simulation.duration for scenario, _ in scenarios)
        late = [f"{start:g}:{stop:g}" for start, stop in windows if stop > shortest + 1e-9]
        if late:  # its column would be empty (NaN) for every flight that ends before it
            raise ValueError(f"--error-window {', '.join(late)} ends after the shortest flight ({shortest:g} s)")
        tasks = build_tasks(scenarios, estimators, guidance, cases, runs, box, args.divergence_threshold,
                            duration=args.duration, windows=tuple(windows),
                            base_overrides=dict(study.overrides) if study else None)
    except (ConfigError, ValueError) as error:
        print(f"bof-montecarlo: {error}", file=sys.stderr)
        return 2
    label = study.label if study else "grid"
    title = study.title if study else f"Monte Carlo grid: {', '.join(s.name for s, _ in scenarios)}"
    folder = new_run_folder(args.out, f"montecarlo-{label}")
    print(f"bof-montecarlo: {len(tasks)} flights -> {folder}", flush=True)
    throughput = reporting.Throughput()
    try:
        with RaisingStopSignals():
            rows, series, executor_name = run_tasks(tasks, args.executor, args.workers, folder,
                                                    progress=not args.quiet, throughput=throughput)
    except Interrupted as stop:
        # Every flight that finished is in results.partial.csv, a row each, written as it arrived.
        print(reporting.interrupted("bof-montecarlo", stop, folder / "results.partial.csv", len(tasks)), file=sys.stderr)
        return 128 + stop.signum
    except (RuntimeError, ValueError, OSError) as error:
        print(f"bof-montecarlo: {error}", file=sys.stderr)
        return 2
    table = group_table(rows)
    report = markdown(table, title, runs, args.divergence_threshold, executor_name)
    np.savez_compressed(folder / "series.npz", **series)
    write_summary(folder / "summary.json", {"title": title, "runs": runs, "groups": table,
                                             "throughput": throughput.record()})
    if not args.no_plots:
        from studies import montecarlo_plots

        report += montecarlo_plots.draw_all(rows, series, folder, curves_by=study.curves_by if study else None, title=title)
    report += f"\n\n{throughput.line('bof-montecarlo')}\n"
    (folder / "summary.md").write_text(report)
    print(reporting.for_terminal(report))
    print(f"run folder: {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
