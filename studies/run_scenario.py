"""`bof-sim`: fly a scenario in the in-process simulator and write a run folder.

The run folder <scenario>-seed<seed>-<time>/, created inside --out (default runs/), holds
flight.mcap (the flight in Foxglove's schemas, studies.flight_mcap; a swarm: flight-p<k>.mcap per pursuer),
series.npz (every logged column), series.csv (the main columns, for spreadsheets),
summary.json (figures that do not apply are null) and two plots (trajectory.png, errors.png).
The in-process loop has no MAVLink link: a scenario's [faults.mavlink] applies in bof-sitl only,
which the summary ("notes") and the terminal say. The terminal's closing block states the truth's
outcome beside the health monitor's verdict (studies.metrics.outcome_lines).
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

from interfaces.run_folders import new_run_folder
from interfaces.cli import CommandParser, output_folder, scenario_file, seed_argument
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, load_scenario
from studies.closed_loop import SimulationResult, simulate
from studies.flight_mcap import in_process_record, write_flight_mcap
from studies.metrics import convergence_text, outcome_lines, suspect_warning, truth_failed, write_summary
from studies.processes import Interrupted, RaisingStopSignals
from studies.swarm import SwarmResult, simulate_swarm

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: bof-sim --help's epilog
EXIT_STATUS = """exit status: 0 the flight ran to the end (completed or diverged by the health monitor) with its truth
within bounds; 1 it did not run to the end, had no estimate over the summary window, diverged by truth
(range-estimation error RMS over the summary window above [simulation] divergence_rms, default 2 m), came closer
to the target than r_d / 2 or tilted past the vehicle's max_tilt_deg (a swarm: any pursuer); 2 bad arguments or scenario;
128 + N stopped by signal N."""


def write_run_folder(result: SimulationResult, folder: Path, plots: bool = True) -> None:
    """Write flight.mcap, series, summary and (with `plots`) series.csv and the plots of one flight into `folder`
    (created if needed)."""
    folder.mkdir(parents=True, exist_ok=True)
    series = result.series
    write_flight_mcap(folder / "flight.mcap", in_process_record(series, result.summary, result.scenario.guidance.desired_range))
    np.savez_compressed(folder / "series.npz", **series)
    if not plots:
        write_summary(folder / "summary.json", result.summary)
        return
    with (folder / "series.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        vectors = ("pursuer_position", "pursuer_velocity", "target_position", "estimate_position", "estimate_velocity", "command_acceleration")
        scalars = ("range", "range_estimate", "thrust_normalized", "pursuer_tilt")
        # the IMM estimator's model probabilities (straight, right, left), only when it flew
        models = series["model_probabilities"] if np.isfinite(series.get("model_probabilities", np.nan)).any() else None
        writer.writerow(["time"] + [f"{key}_{axis}" for key in vectors for axis in "ned"] + list(scalars)
                        + (["model_straight", "model_right", "model_left"] if models is not None else []))
        for row in range(len(series["time"])):
            writer.writerow(
                [f"{series['time'][row]:.3f}"]
                + [f"{value:.4f}" for key in vectors for value in series[key][row]]
                + [f"{series[key][row]:.4f}" for key in scalars]
                + ([f"{value:.4f}" for value in models[row]] if models is not None else [])
            )
    write_summary(folder / "summary.json", result.summary)
    from studies.plots import plot_errors, plot_trajectories  # matplotlib only when plots are drawn

    title = f"{result.scenario.name} (seed {result.summary['seed']})"
    plot_trajectories(series, folder / "trajectory.png", title)
    plot_errors(series, result.scenario.guidance.desired_range, folder / "errors.png", title, result.summary)


def in_process_notes(scenario: Scenario) -> list[str]:
    """What of `scenario` the in-process simulator leaves out (one sentence each; empty: nothing)."""
    notes = []
    if scenario.faults.mavlink.blackouts:
        notes.append(f"[faults.mavlink] ({len(scenario.faults.mavlink.blackouts)} blackout(s)) applies in SITL only "
                     "(bof-sitl): the in-process simulator has no MAVLink link, so this flight has none")
    return notes


def format_summary(summary: dict, outcome: bool = True) -> str:
    """A few human lines for the terminal; with `outcome`, the closing block of studies.metrics.outcome_lines."""
    lines = [
        f"scenario {summary['scenario']}: termination {summary['termination']}, {summary['termination_reason']} "
        f"({summary['duration']:.1f} s, seed {summary['seed']})",
        f"  over the last {summary['summary_window']:.0f} s:",
        f"    range error |p_T - p| - r_d     rms {summary['range_error_rms']:.3f} m, max {summary['range_error_max_abs']:.3f} m (r_d = {summary['desired_range']} m)",
        f"    range-estimation error          rms {summary['range_estimation_error_rms']:.3f} m, max {summary['range_estimation_error_max_abs']:.3f} m",
        f"    position / velocity estimation  rms {summary['position_estimation_error_rms']:.3f} m, {summary['velocity_estimation_error_rms']:.3f} m/s",
        f"  {convergence_text(summary)}",
        f"  minimum range {summary['min_range']:.2f} m, max tilt {summary['max_tilt_deg']:.1f} deg, max speed {summary['max_speed']:.1f} m/s",
    ]
    lines += [f"  note: {note}" for note in summary.get("notes", ())]
    warning = suspect_warning(summary, summary.get("health_reasons_at_end", ()))
    if warning:
        lines.append(f"  {warning}")
    if outcome:
        lines += outcome_lines(summary)
    return "\n".join(lines)


def write_swarm_folder(result: SwarmResult, folder: Path, plots: bool = True) -> None:
    """flight-p<k>.mcap for each pursuer k, summary.json, series.npz (every FlightLog column of pursuer k as
    p<k>_<column>) and, with plots, the
    tracks of every pursuer (tracks.png) and pursuer 1's error curves (errors.png)."""
    folder.mkdir(parents=True, exist_ok=True)
    for ident, data in result.series.items():
        entry = next((e for e in result.summary["pursuers"] if e["pursuer"] == ident), result.summary)
        write_flight_mcap(folder / f"flight-p{ident}.mcap",
                          in_process_record(data, entry, result.scenario.guidance.desired_range))
    np.savez_compressed(folder / "series.npz", **{f"p{ident}_{key}": values for ident, data in result.series.items()
                                                   for key, values in data.items()})
    write_summary(folder / "summary.json", result.summary)
    if plots:
        from studies.plots import plot_errors, plot_swarm_tracks  # matplotlib only when plots are drawn

        title = f"{result.scenario.name} (seed {result.summary['seed']}, {len(result.series)} pursuers)"
        plot_swarm_tracks(result.series, folder / "tracks.png", title)
        plot_errors(result.series[1], result.scenario.guidance.desired_range, folder / "errors.png", f"{title}: pursuer 1")


def format_swarm_summary(summary: dict, outcome: bool = True) -> str:
    """The flight's lines, then one line per pursuer; with `outcome`, each pursuer's closing block (truth and monitor,
    studies.metrics.outcome_lines)."""
    lines = [format_summary(summary, outcome=False).replace("  over the last", "  pursuer 1, over the last", 1)]
    spacing = summary["phase_spacing_error_deg_rms"]
    separation = summary["min_pursuer_separation"]
    lines.append(f"  {len(summary['pursuers'])} pursuers: phase spacing error rms "
                 f"{'n/a' if spacing is None else f'{spacing:.2f} deg'} over the last {summary['summary_window']:.0f} s, "
                 f"closest pursuers {'n/a' if separation is None else f'{separation:.2f} m'} "
                 f"(limit {summary['min_separation']} m)")
    for entry in summary["pursuers"]:
        lines.append(f"    pursuer {entry['pursuer']}: {entry['termination']}, range-estimation rms "
                     f"{entry['range_estimation_error_rms']:.3f} m, range error rms {entry['range_error_rms']:.3f} m, "
                     f"min range {entry['min_range']:.2f} m, neighbour bearings used {entry['neighbour_bearings_used']}")
    for entry in summary["pursuers"] if outcome else ():
        lines += outcome_lines(entry, f"pursuer {entry['pursuer']}")
    return "\n".join(lines)


def _fly_swarm(scenario: Scenario, vehicle, args) -> int:
    started = time.perf_counter()
    try:
        result = simulate_swarm(scenario, vehicle, seed=args.seed)
    except ConfigError as error:
        print(f"bof-sim: {error}", file=sys.stderr)
        return 2
    elapsed = time.perf_counter() - started
    folder = new_run_folder(args.out, f"{scenario.name}-seed{result.summary['seed']}")
    write_swarm_folder(result, folder, plots=not args.no_plots)
    print(format_swarm_summary(result.summary, outcome=False))
    print(f"  simulated {result.summary['duration']:.0f} s of {len(result.series)} pursuers in {elapsed:.2f} s")
    print(f"run folder: {folder}")
    for entry in result.summary["pursuers"]:
        print("\n".join(outcome_lines(entry, f"pursuer {entry['pursuer']}")))
    judged = [entry["pursuer"] for entry in result.summary["pursuers"] if truth_failed(entry)]
    return 0 if result.termination.name in ("COMPLETED", "INTERRUPTED") and not judged else 1


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-sim` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-sim", description="Fly a bearing-only following scenario in the in-process simulator.",
                           epilog=EXIT_STATUS)
    parser.add_argument("scenario", nargs="?", type=scenario_file, default=DEFAULT_SCENARIO,
                        help="scenario TOML (default: the paper's constant-velocity case, %(default)s)")
    parser.add_argument("--out", type=output_folder, default="runs",
                        help="parent folder: the run folder <scenario>-seed<seed>-<time>/ is created inside it "
                             "(default: %(default)s)")
    parser.add_argument("--seed", type=seed_argument, default=None,
                        help="seed of the flight's noise, an integer >= 0 (default: the scenario's [simulation] seed)")
    parser.add_argument("--no-plots", action="store_true",
                        help="write only flight.mcap, series.npz and summary.json, no PNG plots or series.csv "
                             "(default: write them)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)

    try:
        scenario, vehicle = load_scenario(args.scenario)
    except ConfigError as error:
        print(f"bof-sim: {error}", file=sys.stderr)
        return 2
    try:
        with RaisingStopSignals():
            return _fly_swarm(scenario, vehicle, args) if scenario.swarm is not None else _fly(scenario, vehicle, args)
    except Interrupted as stop:
        # An in-process flight lives in memory until it ends (a minute of flight takes about 0.1 s), then its
        # folder is written in one go: there is nothing partial worth keeping.
        print(f"bof-sim: {stop}: the flight is written when it ends, so nothing was kept (a folder being written "
              f"may be incomplete)", file=sys.stderr)
        return 128 + stop.signum


def _fly(scenario: Scenario, vehicle, args) -> int:
    started = time.perf_counter()
    result = simulate(scenario, vehicle, seed=args.seed)
    elapsed = time.perf_counter() - started
    notes = in_process_notes(scenario)
    if notes:
        result.summary["notes"] = notes
    folder = new_run_folder(args.out, f"{scenario.name}-seed{result.summary['seed']}")
    write_run_folder(result, folder, plots=not args.no_plots)
    print(format_summary(result.summary, outcome=False))
    print(f"  simulated {result.summary['duration']:.0f} s in {elapsed:.2f} s ({result.summary['duration'] / elapsed:.0f}x real time)")
    print(f"run folder: {folder}")
    print("\n".join(outcome_lines(result.summary)))
    flown = result.termination.name in ("COMPLETED", "INTERRUPTED") and result.summary["verdict"] != "no_estimate"
    return 0 if flown and not truth_failed(result.summary) else 1


if __name__ == "__main__":
    sys.exit(main())
