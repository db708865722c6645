"""`bof-sim`: fly a scenario in the in-process simulator and write a run folder.

The run folder holds series.npz (every logged column), series.csv (the main
columns, for spreadsheets), summary.json and two plots (trajectory.png, errors.png).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, load_scenario
from studies.closed_loop import SimulationResult, simulate
from studies.plots import plot_errors, plot_trajectories

DEFAULT_SCENARIO = DEFAULT_SCENARIO


def write_run_folder(result: SimulationResult, folder: Path) -> None:
    """Write series, summary and plots of one flight into `folder` (created if needed)."""
    folder.mkdir(parents=True, exist_ok=True)
    series = result.series
    np.savez_compressed(folder / "series.npz", **series)
    with (folder / "series.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        vectors = ("pursuer_position", "pursuer_velocity", "target_position", "estimate_position", "estimate_velocity", "command_acceleration")
        scalars = ("range", "range_estimate", "thrust_normalized", "pursuer_tilt")
        writer.writerow(["time"] + [f"{key}_{axis}" for key in vectors for axis in "ned"] + list(scalars))
        for row in range(len(series["time"])):
            writer.writerow(
                [f"{series['time'][row]:.3f}"]
                + [f"{value:.4f}" for key in vectors for value in series[key][row]]
                + [f"{series[key][row]:.4f}" for key in scalars]
            )
    (folder / "summary.json").write_text(json.dumps(_json_safe(result.summary), indent=2) + "\n")
    title = f"{result.scenario.name} (seed {result.summary['seed']})"
    plot_trajectories(series, folder / "trajectory.png", title)
    plot_errors(series, result.scenario.guidance.desired_range, folder / "errors.png", title)


def _json_safe(summary: dict) -> dict:
    return {key: (None if isinstance(value, float) and not math.isfinite(value) else value) for key, value in summary.items()}


def format_summary(summary: dict) -> str:
    """A few human lines for the terminal."""
    lines = [
        f"scenario {summary['scenario']}: {summary['termination_reason']} ({summary['duration']:.1f} s, seed {summary['seed']})",
        f"  over the last {summary['summary_window']:.0f} s:",
        f"    range error |p_T - p| - r_d     rms {summary['range_error_rms']:.3f} m, max {summary['range_error_max_abs']:.3f} m (r_d = {summary['desired_range']} m)",
        f"    range-estimation error          rms {summary['range_estimation_error_rms']:.3f} m, max {summary['range_estimation_error_max_abs']:.3f} m",
        f"    position / velocity estimation  rms {summary['position_estimation_error_rms']:.3f} m, {summary['velocity_estimation_error_rms']:.3f} m/s",
        f"  converged (both errors < {summary['convergence_threshold']} m for good) at t = {summary['convergence_time']:.2f} s",
        f"  minimum range {summary['min_range']:.2f} m, max tilt {summary['max_tilt_deg']:.1f} deg, max speed {summary['max_speed']:.1f} m/s",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bof-sim", description="Fly a bearing-only following scenario in the in-process simulator.")
    parser.add_argument("scenario", nargs="?", default=str(DEFAULT_SCENARIO), help="scenario TOML (default: the paper's constant-velocity case)")
    parser.add_argument("--out", default="runs", help="parent folder for the run folder (default: runs/)")
    parser.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    args = parser.parse_args(argv)

    try:
        scenario, vehicle = load_scenario(args.scenario)
    except ConfigError as error:
        print(f"bof-sim: {error}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    result = simulate(scenario, vehicle, seed=args.seed)
    elapsed = time.perf_counter() - started
    folder = Path(args.out) / f"{scenario.name}-seed{result.summary['seed']}-{time.strftime('%Y%m%d-%H%M%S')}"
    if args.no_plots:
        folder.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(folder / "series.npz", **result.series)
        (folder / "summary.json").write_text(json.dumps(_json_safe(result.summary), indent=2) + "\n")
    else:
        write_run_folder(result, folder)
    print(format_summary(result.summary))
    print(f"  simulated {result.summary['duration']:.0f} s in {elapsed:.2f} s ({result.summary['duration'] / elapsed:.0f}x real time)")
    print(f"run folder: {folder}")
    return 0 if result.termination.name in ("COMPLETED", "INTERRUPTED") else 1


if __name__ == "__main__":
    sys.exit(main())
