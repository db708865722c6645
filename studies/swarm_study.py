"""The goals for several pursuers, measured in process over seeds (bof-swarm-study).

    bof-swarm-study [--seeds 20] [--workers N] [--executor local|serial|...] [--out runs] [--parts a b c]

Three parts, every flight by studies.swarm.simulate_swarm (one pursuer: the scenario without [swarm]):

(a) one pursuer against three (swarm_circumnavigation.toml) on the constant-velocity target, and on the
    turning target (swarm_turning.toml: circle_5ms.toml's target, everything else the same): range-
    estimation RMS over the last summary window (20 s) and its ratio to the single pursuer's, the time
    after every pursuer had a bearing until every pursuer's range-estimation error stays under 1 m
    (range_estimation_settled_1m_after_all_bearings), phase spacing RMS over the window, the smallest
    pursuer separation against [swarm] min_separation, the smallest pursuer-target range against r_d/2,
    divergences;
(b) the constant-velocity swarm with pursuer 2's share link blacked out for BLACKOUT (s) ([swarm.link]
    blackouts): the others' range-estimation error during the blackout and whether any diverges; the
    silent one's error during the blackout and the time after it until its error stays under 1 m;
(c) the estimators on the constant-velocity swarm: own, shared_bearings, triangulation_kf, fusion with
    covariance intersection and with seed 004's information sum.

Statistics over seeds 1..N. A flight's range-estimation RMS is pooled over its pursuers (the root of the
mean of their squared RMS); a case's is pooled over its flights. A divergence is a pursuer whose flight
did not complete or whose estimate the health monitor still called suspect at the end (studies.metrics
verdict 'failed' or 'suspect'), or whose
range-estimation RMS over the window exceeds DIVERGED_RMS.

Writes results.csv (one row per flight and pursuer), summary.json and summary.md (the tables, the goals
met or not) into runs/swarm-study-<time>/ and prints the tables; the last line gives the simulated
flight-seconds (pursuers x simulated seconds) per wall-clock second.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from interfaces.run_folders import new_run_folder
from interfaces.overrides import apply_overrides
from interfaces.records import JsonLinesLog
from interfaces.scenario import ConfigError, Scenario, SwarmBlackout, VehicleConfig, load_scenario
from interfaces.cli import CommandParser, output_folder
from studies import reporting
from studies.executors import check_executor, check_flight_count, make_executor
from studies.processes import Interrupted, RaisingStopSignals
from studies.metrics import write_summary
from studies.swarm import simulate_swarm

SCENARIOS = Path(__file__).resolve().parent.parent / "config" / "scenarios"
CONSTANT_VELOCITY = SCENARIOS / "swarm_circumnavigation.toml"
TURNING = SCENARIOS / "swarm_turning.toml"
#: s: pursuer 2's share link is silent over [BLACKOUT_START, BLACKOUT_START + BLACKOUT) in part (b)
BLACKOUT_START = 30.0
BLACKOUT = 10.0
BLACKOUT_PURSUER = 2
#: m: a pursuer whose range-estimation RMS over the window exceeds this counts as diverged
DIVERGED_RMS = 2.0
#: the goals: the swarm's range-estimation RMS ratio to one pursuer, settling time, phase spacing
GOAL_RATIO = 1.0 / 3.0
GOAL_SETTLED_S = 3.0
GOAL_PHASE_DEG = 5.0

ESTIMATORS = (("own", "own", None), ("shared_bearings", "shared_bearings", None),
              ("triangulation_kf", "triangulation_kf", None), ("fusion_ci", "fusion", "covariance_intersection"),
              ("fusion_seed004", "fusion", "seed004"))
PARTS = ("a", "b", "c")


@dataclass(frozen=True)
class Case:
    """One flown configuration: name, part ('a', 'b', 'c'), target ('constant velocity' / 'turning'),
    the scenario and its vehicle."""

    name: str
    part: str
    target: str
    scenario: Scenario
    vehicle: VehicleConfig


def _with_swarm(scenario: Scenario, **update) -> Scenario:
    return scenario.model_copy(update={"swarm": scenario.swarm.model_copy(update=update)})


def _estimator(scenario: Scenario, estimator: str, fusion_method: str | None) -> Scenario:
    swarm = scenario.swarm
    update = {"estimator": estimator}
    if fusion_method is not None:
        update["fusion"] = swarm.fusion.model_copy(update={"method": fusion_method})
    return _with_swarm(scenario, **update)


def build_cases(parts: tuple[str, ...] = PARTS, duration: float | None = None) -> list[Case]:
    """The study's configurations (see the module docstring). duration: s, overrides the files' (tests)."""
    loaded = {}
    for label, path in (("constant velocity", CONSTANT_VELOCITY), ("turning", TURNING)):
        scenario, vehicle = load_scenario(path)
        if duration is not None:  # validated as the file's own duration would be (ConfigError naming the key)
            window = min(scenario.simulation.summary_window, duration)  # as bof-montecarlo --duration does
            scenario = apply_overrides(scenario, {"simulation.duration": float(duration),
                                                  "simulation.summary_window": window}, f"--duration {duration}")
        if scenario.swarm is None:
            raise ConfigError(f"{path.name} has no [swarm]")
        loaded[label] = (scenario, vehicle)
    cases = []
    if "a" in parts:
        for label, short in (("constant velocity", "cv"), ("turning", "turn")):
            scenario, vehicle = loaded[label]
            cases.append(Case(f"{short}_single", "a", label, scenario.model_copy(update={"swarm": None}), vehicle))
            cases.append(Case(f"{short}_swarm", "a", label, scenario, vehicle))
    scenario, vehicle = loaded["constant velocity"]
    if "b" in parts:
        end = min(BLACKOUT_START + BLACKOUT, scenario.simulation.duration)
        start = min(BLACKOUT_START, 0.5 * scenario.simulation.duration)
        blackout = SwarmBlackout(pursuer=BLACKOUT_PURSUER, start=start, end=max(end, start + 1e-3))
        link = scenario.swarm.link.model_copy(update={"blackouts": (blackout,)})
        cases.append(Case("cv_swarm_blackout", "b", "constant velocity", _with_swarm(scenario, link=link), vehicle))
    if "c" in parts:
        for name, estimator, method in ESTIMATORS:
            cases.append(Case(f"cv_{name}", "c", "constant velocity", _estimator(scenario, estimator, method), vehicle))
    return cases


def _settled_under(time: np.ndarray, error: np.ndarray, bound: float, after: float) -> float:
    """s after `after` from which |error| < bound to the end; inf if it never does (studies.swarm's rule)."""
    above = np.flatnonzero((time >= after) & ~(np.abs(error) < bound))
    if len(above) == 0:
        return 0.0
    last = above[-1]
    return math.inf if last + 1 >= len(time) else float(time[last + 1] - after)


def fly(task: tuple[Case, int]) -> dict:
    """One flight of `case` with `seed`: one dict per pursuer ("rows") and the flight's figures."""
    case, seed = task
    started = time.perf_counter()
    result = simulate_swarm(case.scenario, case.vehicle, seed)
    wall = time.perf_counter() - started
    summary = result.summary
    scenario = case.scenario
    blackout = scenario.swarm.link.blackouts[0] if scenario.swarm is not None and scenario.swarm.link.blackouts else None
    rows = []
    for entry in summary["pursuers"]:
        ident = entry["pursuer"]
        series = result.series[ident]
        t = series["time"]
        error = series["range_estimate"] - series["range"]
        settled = entry["range_estimation_settled_1m_after_all_bearings"]
        diverged = (entry["termination"] != "completed" or entry.get("verdict") in ("failed", "suspect")
                    or not (entry["range_estimation_error_rms"] <= DIVERGED_RMS))
        row = {
            "case": case.name, "part": case.part, "target": case.target, "seed": seed, "pursuer": ident,
            "pursuers": len(summary["pursuers"]), "termination": entry["termination"], "verdict": entry.get("verdict"),
            "diverged": bool(diverged),
            "range_estimation_rms": entry["range_estimation_error_rms"],
            "range_estimation_max_abs": entry["range_estimation_error_max_abs"],
            "range_error_rms": entry["range_error_rms"],
            "settled_1m_after_all_bearings": math.inf if settled is None else float(settled),
            "min_range": entry["min_range"], "desired_range": entry["desired_range"],
            "neighbour_bearings_used": entry.get("neighbour_bearings_used", 0),
            "estimates_absorbed": entry.get("estimates_absorbed", 0),
            "law_changes": len(entry.get("law_changes", ())),
        }
        if blackout is not None:
            during = (t >= blackout.start) & (t < blackout.end)
            row["blackout_max_abs_error"] = float(np.max(np.abs(error[during]))) if during.any() else math.nan
            row["settled_1m_after_blackout"] = _settled_under(t, error, 1.0, blackout.end)
            row["silent"] = ident == blackout.pursuer
        rows.append(row)
    flight = {
        "case": case.name, "seed": seed, "wall_s": wall,
        "flight_seconds": float(summary["duration"]) * len(summary["pursuers"]),
        "phase_spacing_error_deg_rms": summary.get("phase_spacing_error_deg_rms"),
        "min_pursuer_separation": summary.get("min_pursuer_separation"),
        "min_separation": summary.get("min_separation"),
    }
    for row in rows:
        row.update({key: flight[key] for key in ("phase_spacing_error_deg_rms", "min_pursuer_separation", "min_separation")})
    return {"rows": rows, "flight": flight}


def _pooled(values) -> float:
    values = np.asarray([v for v in values], dtype=float)
    return float(np.sqrt(np.mean(values**2))) if len(values) else math.nan


def _flight_rms(rows: list[dict]) -> dict[int, float]:
    """seed -> the flight's range-estimation RMS pooled over its pursuers."""
    by_seed: dict[int, list[float]] = {}
    for row in rows:
        by_seed.setdefault(row["seed"], []).append(row["range_estimation_rms"])
    return {seed: _pooled(values) for seed, values in by_seed.items()}


def case_table(rows: list[dict]) -> dict:
    """The figures of one case over its seeds (rows of `fly`)."""
    flights = _flight_rms(rows)
    settled_by_seed: dict[int, float] = {}
    for row in rows:
        settled_by_seed[row["seed"]] = max(settled_by_seed.get(row["seed"], 0.0), row["settled_1m_after_all_bearings"])
    settled = np.array(list(settled_by_seed.values()), dtype=float)
    phase = [row["phase_spacing_error_deg_rms"] for row in rows if row["pursuer"] == 1
             and row["phase_spacing_error_deg_rms"] is not None]
    separations = [row["min_pursuer_separation"] for row in rows if row["min_pursuer_separation"] is not None]
    diverged_flights = {row["seed"] for row in rows if row["diverged"]}
    first = rows[0]
    table = {
        "case": first["case"], "part": first["part"], "target": first["target"], "pursuers": first["pursuers"],
        "seeds": len(flights),
        "range_estimation_rms_pooled": _pooled(list(flights.values())),
        "range_estimation_rms_median": float(np.median(list(flights.values()))),
        "range_estimation_rms_max": float(np.max(list(flights.values()))),
        "settled_1m_median": float(np.median(settled)),
        "settled_1m_max": float(np.max(settled)),
        "settled_1m_within_goal": int(np.sum(settled <= GOAL_SETTLED_S)),
        "phase_spacing_deg_rms_median": float(np.median(phase)) if phase else None,
        "phase_spacing_deg_rms_max": float(np.max(phase)) if phase else None,
        "min_pursuer_separation": float(np.min(separations)) if separations else None,
        "min_separation": first["min_separation"],
        "min_range": float(min(row["min_range"] for row in rows)),
        "half_desired_range": 0.5 * first["desired_range"],
        "diverged_flights": len(diverged_flights),
        "diverged_pursuers": int(sum(row["diverged"] for row in rows)),
    }
    if "silent" in first:
        silent = [row for row in rows if row["silent"]]
        others = [row for row in rows if not row["silent"]]
        recovered = np.array([row["settled_1m_after_blackout"] for row in silent], dtype=float)
        table.update({
            "others_blackout_max_abs_error": float(np.max([row["blackout_max_abs_error"] for row in others])),
            "others_diverged": int(sum(row["diverged"] for row in others)),
            "others_range_estimation_rms_pooled": _pooled([row["range_estimation_rms"] for row in others]),
            "silent_blackout_max_abs_error_median": float(np.median([row["blackout_max_abs_error"] for row in silent])),
            "silent_blackout_max_abs_error_max": float(np.max([row["blackout_max_abs_error"] for row in silent])),
            "silent_recovered_1m_median": float(np.median(recovered)),
            "silent_recovered_1m_max": float(np.max(recovered)),
            "silent_recovered": int(np.sum(np.isfinite(recovered))),
            "silent_range_estimation_rms_pooled": _pooled([row["range_estimation_rms"] for row in silent]),
            "silent_diverged": int(sum(row["diverged"] for row in silent)),
        })
    return table


def goals(tables: dict[str, dict]) -> list[dict]:
    """The in-process goals against the tables: [{goal, measured, met}]."""
    out = []

    def add(goal: str, measured: str, met: bool) -> None:
        out.append({"goal": goal, "measured": measured, "met": bool(met)})

    for short, label in (("cv", "constant velocity"), ("turn", "turning")):
        single, swarm = tables.get(f"{short}_single"), tables.get(f"{short}_swarm")
        if single is None or swarm is None:
            continue
        ratio = swarm["range_estimation_rms_pooled"] / single["range_estimation_rms_pooled"]
        add(f"{label}: range-estimation RMS (last window) of 3 pursuers <= 1/3 of one pursuer's",
            f"{swarm['range_estimation_rms_pooled']:.3f} m / {single['range_estimation_rms_pooled']:.3f} m = {ratio:.3f}",
            ratio <= GOAL_RATIO)
        add(f"{label}: every pursuer's range-estimation error < 1 m within {GOAL_SETTLED_S:g} s of all having a bearing",
            f"{swarm['settled_1m_within_goal']}/{swarm['seeds']} seeds; median {swarm['settled_1m_median']:.2f} s, "
            f"max {swarm['settled_1m_max']:.2f} s", swarm["settled_1m_within_goal"] == swarm["seeds"])
        phase = swarm["phase_spacing_deg_rms_max"]
        add(f"{label}: phase spacing RMS < {GOAL_PHASE_DEG:g} deg after convergence (last window)",
            f"median {swarm['phase_spacing_deg_rms_median']:.2f} deg, max {phase:.2f} deg", phase < GOAL_PHASE_DEG)
        add(f"{label}: pursuers never closer than min_separation",
            f"{swarm['min_pursuer_separation']:.2f} m >= {swarm['min_separation']:g} m",
            swarm["min_pursuer_separation"] >= swarm["min_separation"])
        add(f"{label}: never closer than r_d/2 to the target",
            f"{swarm['min_range']:.2f} m >= {swarm['half_desired_range']:g} m", swarm["min_range"] >= swarm["half_desired_range"])
        add(f"{label}: no divergence", f"{swarm['diverged_flights']}/{swarm['seeds']} flights", swarm["diverged_flights"] == 0)
    blackout = tables.get("cv_swarm_blackout")
    if blackout is not None:
        add(f"blackout of pursuer {BLACKOUT_PURSUER}'s share link for {BLACKOUT:g} s: the others keep the target, no divergence",
            f"others' max |error| during it {blackout['others_blackout_max_abs_error']:.3f} m, "
            f"{blackout['others_diverged']} diverged", blackout["others_diverged"] == 0)
        add("blackout: the silent one recovers (error < 1 m for good after the blackout)",
            f"{blackout['silent_recovered']}/{blackout['seeds']} seeds; median {blackout['silent_recovered_1m_median']:.2f} s, "
            f"max {blackout['silent_recovered_1m_max']:.2f} s after; max |error| during it "
            f"{blackout['silent_blackout_max_abs_error_max']:.3f} m",
            blackout["silent_recovered"] == blackout["seeds"] and blackout["silent_diverged"] == 0)
        add("blackout: pursuers never closer than min_separation (nobody hears the silent one)",
            f"{blackout['min_pursuer_separation']:.2f} m against {blackout['min_separation']:g} m",
            blackout["min_pursuer_separation"] >= blackout["min_separation"])
    return out


def _f(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "never"
    return f"{value:.{digits}f}"


def markdown(tables: dict[str, dict], goal_rows: list[dict], seeds: int, executor: str) -> str:
    lines = [f"# Several pursuers: measured ({seeds} seeds, 1..{seeds}; executor: {executor})", ""]
    a_and_c = [t for t in tables.values() if t["part"] in ("a", "c")]
    if a_and_c:
        single = {t["target"]: t["range_estimation_rms_pooled"] for t in tables.values() if t["pursuers"] == 1}
        lines += ["| case | pursuers | range-est. RMS pooled (m) | median | max | ratio to single | settled < 1 m: median / max (s), within 3 s "
                  "| phase RMS median / max (deg) | min separation (limit) m | min range (r_d/2) m | diverged flights |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for t in a_and_c:
            ratio = t["range_estimation_rms_pooled"] / single[t["target"]] if t["target"] in single else None
            lines.append(
                f"| {t['case']} | {t['pursuers']} | {_f(t['range_estimation_rms_pooled'])} | {_f(t['range_estimation_rms_median'])} "
                f"| {_f(t['range_estimation_rms_max'])} | {_f(ratio)} | {_f(t['settled_1m_median'], 2)} / {_f(t['settled_1m_max'], 2)}, "
                f"{t['settled_1m_within_goal']}/{t['seeds']} | {_f(t['phase_spacing_deg_rms_median'], 2)} / {_f(t['phase_spacing_deg_rms_max'], 2)} "
                f"| {_f(t['min_pursuer_separation'], 2)} ({_f(t['min_separation'], 1)}) | {_f(t['min_range'], 2)} ({_f(t['half_desired_range'], 1)}) "
                f"| {t['diverged_flights']}/{t['seeds']} |")
        lines.append("")
    blackout = tables.get("cv_swarm_blackout")
    if blackout is not None:
        lines += [f"Blackout: pursuer {BLACKOUT_PURSUER}'s share link silent over [{BLACKOUT_START:g}, {BLACKOUT_START + BLACKOUT:g}) s",
                  "", "| who | max abs range-est. error during it (m) | RMS last window (m) | error < 1 m for good after it (s) | diverged |",
                  "|---|---|---|---|---|",
                  f"| the others | {_f(blackout['others_blackout_max_abs_error'])} (max) | {_f(blackout['others_range_estimation_rms_pooled'])} "
                  f"| - | {blackout['others_diverged']} |",
                  f"| the silent one | {_f(blackout['silent_blackout_max_abs_error_median'])} median, {_f(blackout['silent_blackout_max_abs_error_max'])} max "
                  f"| {_f(blackout['silent_range_estimation_rms_pooled'])} | {_f(blackout['silent_recovered_1m_median'], 2)} median, "
                  f"{_f(blackout['silent_recovered_1m_max'], 2)} max ({blackout['silent_recovered']}/{blackout['seeds']} recovered) "
                  f"| {blackout['silent_diverged']} |", "",
                  f"Closest pursuers in these flights {_f(blackout['min_pursuer_separation'], 2)} m (limit "
                  f"{_f(blackout['min_separation'], 1)} m); phase spacing RMS over the last window (from the blackout's "
                  f"end) median {_f(blackout['phase_spacing_deg_rms_median'], 1)} deg, max "
                  f"{_f(blackout['phase_spacing_deg_rms_max'], 1)} deg.", ""]
    if goal_rows:
        lines += ["| goal | measured | met |", "|---|---|---|"]
        lines += [f"| {g['goal']} | {g['measured']} | {'yes' if g['met'] else 'NO'} |" for g in goal_rows]
        lines.append("")
    lines += [f"Range-estimation RMS over the last summary window, pooled over pursuers and seeds (root mean square); "
              f"settled: time after every pursuer had a bearing until every pursuer's error stays < 1 m (per flight the "
              f"slowest pursuer); diverged: did not complete, suspect at the end, or RMS > {DIVERGED_RMS:g} m.", ""]
    return "\n".join(lines)


def flown_cases(cases: list[Case]) -> tuple[list[Case], dict[str, int]]:
    """The cases to fly and, for each case's name, the index of the one flown for it: a case whose scenario another
    case already flies (cv_shared_bearings is cv_swarm) is flown once."""
    flown: list[Case] = []
    same_as: dict[str, int] = {}
    for case in cases:
        twin = next((k for k, other in enumerate(flown) if other.scenario == case.scenario and other.vehicle == case.vehicle), None)
        if twin is None:
            flown.append(case)
            twin = len(flown) - 1
        same_as[case.name] = twin
    return flown, same_as


def run_study(cases: list[Case], seeds: int, executor_spec: str = "local", workers: int | None = None,
              progress: bool = True, partial_log: Path | None = None) -> tuple[list[dict], list[dict], str, float]:
    """Fly every case for seeds 1..seeds; returns (pursuer rows, flights flown, executor name, wall s), in
    case and seed order whatever order the workers finish in. partial_log: a JSON-lines file that gets each
    flight's result as it arrives (None: none)."""
    flown, same_as = flown_cases(cases)
    tasks = [(case, seed) for case in flown for seed in range(1, seeds + 1)]
    executor = make_executor(executor_spec, workers, say=reporting.say_as("bof-swarm-study"))
    results: list[dict | None] = [None] * len(tasks)
    # Each flight's result on disk as it arrives (a JSON line: task index, case, seed, rows, flight), so that an
    # interrupted study keeps what it flew; removed once the study's own files are written (main).
    log = JsonLinesLog(partial_log) if partial_log is not None else None
    started = time.perf_counter()
    try:
        for done, (index, result) in enumerate(executor.map(fly, tasks), start=1):
            results[index] = result
            if log is not None:
                case, seed = tasks[index]
                log.write({"task": index, "case": case.name, "seed": seed, **result})
            if progress:
                print(f"\r{done}/{len(tasks)} flights", end="", file=sys.stderr, flush=True)
    finally:
        executor.close()
        if log is not None:
            log.close()
        if progress:
            print(file=sys.stderr)
    wall = time.perf_counter() - started
    rows, flights = [], []
    for case in cases:
        for seed in range(seeds):
            result = results[same_as[case.name] * seeds + seed]
            rows += [{**row, "case": case.name, "part": case.part} for row in result["rows"]]
            if flown[same_as[case.name]] is case:
                flights.append(result["flight"])
    return rows, flights, executor.name, wall


def write_results(folder: Path, rows: list[dict]) -> None:
    columns = []
    for row in rows:
        columns += [key for key in row if key not in columns]
    with open(folder / "results.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-swarm-study` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-swarm-study", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20, help="seeds 1..N per case (default 20)")
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS),
                        help="a: one vs three pursuers; b: share-link blackout; c: estimators (default all)")
    parser.add_argument("--executor", default="local", help="local (default), serial, dask-local, or tcp://scheduler:port")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: the cores but one)")
    parser.add_argument("--duration", type=float, default=None, help="override the scenarios' duration, s (quick looks)")
    parser.add_argument("--out", type=output_folder, default=Path("runs"), help="parent of the run folder swarm-study-<time>/")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.seeds < 1 or (args.workers is not None and args.workers < 1) or (args.duration is not None and args.duration <= 0):
        print("bof-swarm-study: --seeds and --workers must be >= 1, --duration > 0", file=sys.stderr)
        return 2
    workers = args.workers if args.workers is not None else max(1, (os.cpu_count() or 1) - 1)
    try:
        check_executor(args.executor, workers)
        cases = build_cases(tuple(args.parts), args.duration)
        check_flight_count(len(flown_cases(cases)[0]) * args.seeds, "the cases x --seeds")
    except (ConfigError, ValueError, OSError) as error:
        print(f"bof-swarm-study: {error}", file=sys.stderr)
        return 2
    folder = new_run_folder(args.out, "swarm-study")
    print(f"bof-swarm-study: {len(cases)} cases x {args.seeds} seeds -> {folder}", flush=True)
    partial = folder / "flights.partial.jsonl"
    try:
        with RaisingStopSignals():
            rows, flights, executor_name, wall = run_study(cases, args.seeds, args.executor, workers,
                                                           progress=not args.quiet, partial_log=partial)
    except Interrupted as stop:
        planned = len(flown_cases(cases)[0]) * args.seeds
        print(reporting.interrupted("bof-swarm-study", stop, partial, planned), file=sys.stderr)
        return 128 + stop.signum
    except (RuntimeError, ValueError, OSError) as error:
        print(f"bof-swarm-study: {error}", file=sys.stderr)
        return 2
    tables = {case.name: case_table([row for row in rows if row["case"] == case.name]) for case in cases}
    goal_rows = goals(tables)
    flight_seconds = sum(flight["flight_seconds"] for flight in flights)
    report = markdown(tables, goal_rows, args.seeds, executor_name)
    write_results(folder, rows)
    write_summary(folder / "summary.json", {"seeds": args.seeds, "executor": executor_name, "tables": tables,
                                            "goals": goal_rows, "flights": flights, "wall_s": wall,
                                            "flight_seconds": flight_seconds})
    (folder / "summary.md").write_text(report)
    partial.unlink(missing_ok=True)  # every flight is in results.csv and summary.json now
    print(report)
    print(f"run folder: {folder}")
    print(f"{flight_seconds:.0f} simulated flight-seconds (pursuers x s) in {wall:.0f} s wall: "
          f"{flight_seconds / wall:.1f} per wall second ({executor_name})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
