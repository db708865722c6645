"""`bof-seed-repro`: the seed papers' several-pursuer simulations, flown in process (docs/reproduction.md).

    bof-seed-repro 002                      # seed 002, every variant, flight seeds 0-4
    bof-seed-repro 004 --seeds 0 1 2        # seed 004, three flight seeds
    bof-seed-repro 004 --duration 300       # shortened (the folder's summary says so)

Seed 002 (Zhou et al. 2024): five pursuers circumnavigate a moving target at D* = 5 m with protocol (10);
the seed reports no numbers, only figures (range-estimate error, D_i - D*, neighbour angles Delta_i, tracks).
Seed 004 (Optics Express 2019): three pursuers standoff-track (TOGVF) a turning ground target; the seed's
figures of merit are the standoff distance, the phase spacing and the target-position RMS of its filters.

Each variant is a scenario file of config/scenarios plus a few `section.key = value` overrides
(interfaces.overrides, the estimator being compared), flown by studies.swarm.simulate_swarm for every flight
seed. The run folder <out>/seed<paper>-<time>/ holds, per variant and flight seed, <variant>/seed<k>/ with
metrics.json and four figures (distances.png, phase_gaps.png, estimation.png, tracks.png: one curve per
pursuer), and at the top summary.json (every flight's metrics, then per variant the mean, min and max over
the flight seeds) and summary.md (the same as a table).

Metrics (per flight; "steady" = from the variant's steady_from to the end):
* distance error: seed 002 |p_T - p_i|_h - D* (horizontal, the seed is planar); seed 004 |p_T - p_i|_h - R
  (the standoff radius) and the height error (height above the target - H);
* phase-gap error: every consecutive CCW gap between the pursuers' phases about the TRUE target minus
  2 pi / n (seed 002's Delta_i - 2 pi / n; seed 004's phase coordination);
* estimation error: |p^_T - p_T| of each pursuer's estimate (seed 002: |p^_i0 - p_i0|, the relative
  position, is the same number since the pursuer knows its own position), and of the velocity;
* settling times: from when each error stays under its bound to the end (the latest pursuer).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time as wall
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import studies.swarm as swarm_module
from interfaces.run_folders import new_run_folder
from interfaces.overrides import apply_overrides
from interfaces.scenario import (IMM_OPTIONS, MAX_DURATION_S, ConfigError, EstimatorConfig, Scenario, VehicleConfig,
                                 load_scenario)
from interfaces.cli import CommandParser, output_folder
from studies.metrics import write_summary
from studies.swarm import SwarmResult

SCENARIOS = Path(__file__).resolve().parent.parent / "config" / "scenarios"
TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Variant:
    """One flown configuration of a seed paper's simulation.

    key: folder and table name; scenario: file name in config/scenarios; overrides: dotted keys applied
    on top (interfaces.overrides); figure: which of the seed's figures it is compared with; steady_from: s,
    start of the steady window of the metrics; bounds: error bounds of the settling times (distance m,
    phase deg, estimation m)."""

    key: str
    scenario: str
    overrides: dict = field(default_factory=dict)
    figure: str = ""
    steady_from: float = 60.0
    bounds: tuple[float, float, float] = (1.0, 10.0, 1.0)


SEED002_KF = {"swarm.estimator": "triangulation_kf"}
SEED002_UPLKF = {"swarm.estimator": "shared_bearings", "estimator.kind": "uplkf"}
#: The seed's Figs. 4-6 are noise-free; 0.01 rad (our sensor's usual noise) stands for that.
SEED002_LOW_NOISE = {"sensor.noise_std": 0.01, "estimator.measurement_noise": 1e-4}
SEED004_IMM = {"swarm.estimator": "shared_bearings"}
#: The u-PLKF refuses IMM options other than the defaults, and the seed 004 scenario sets its own: back to the defaults.
SEED004_UPLKF = {"swarm.estimator": "shared_bearings", "estimator.kind": "uplkf",
                 **{f"estimator.{name}": EstimatorConfig.model_fields[name].default for name in IMM_OPTIONS}}

#: Seed 002: the seed's gains (orbit 7.5 m/s on 5 m, 11 m/s^2: beyond the Table I quadrotor) and the scaled
#: file (g2 = 0.5: 3.8 m/s, 2.8 m/s^2), each with the seed's own Kalman enhancement and with the u-PLKF fed
#: the neighbours' bearings, under the seed's Fig. 7 noise (0.187 rad); the scaled file also with 0.01 rad
#: for the seed's noise-free Figs. 4-6 (high-speed target).
#: Seed 004: TOGVF standoff with phase coordination, IMM (straight, +-0.008, +-0.01 rad/s) vs u-PLKF.
REPRODUCTIONS: dict[str, tuple[Variant, ...]] = {
    "002": (
        Variant("seed_gains_triangulation_kf", "seed002_circumnavigation.toml", SEED002_KF, "Fig. 7"),
        Variant("seed_gains_uplkf", "seed002_circumnavigation.toml", SEED002_UPLKF, "Fig. 7"),
        Variant("scaled_triangulation_kf", "seed002_circumnavigation_scaled.toml", SEED002_KF, "Fig. 7"),
        Variant("scaled_uplkf", "seed002_circumnavigation_scaled.toml", SEED002_UPLKF, "Fig. 7"),
        Variant("scaled_triangulation_kf_low_noise", "seed002_circumnavigation_scaled.toml",
                {**SEED002_KF, **SEED002_LOW_NOISE}, "Figs. 4-6"),
        Variant("scaled_uplkf_low_noise", "seed002_circumnavigation_scaled.toml",
                {**SEED002_UPLKF, **SEED002_LOW_NOISE}, "Figs. 4-6"),
    ),
    "004": (
        Variant("imm", "seed004_standoff.toml", SEED004_IMM, "Figs. 6-7, 13-16", steady_from=300.0,
                bounds=(10.0, 30.0, 5.0)),
        Variant("uplkf", "seed004_standoff.toml", SEED004_UPLKF, "Figs. 6-7, 13-16", steady_from=300.0,
                bounds=(10.0, 30.0, 5.0)),
    ),
}


def load_variant(variant: Variant, duration: float | None = None) -> tuple[Scenario, VehicleConfig]:
    """The variant's scenario (its file with its overrides, and the duration if given) and vehicle."""
    scenario, vehicle = load_scenario(SCENARIOS / variant.scenario)
    overrides = dict(variant.overrides)
    if duration is not None:
        overrides["simulation.duration"] = float(duration)
        overrides["simulation.summary_window"] = min(scenario.simulation.summary_window, float(duration))
    return apply_overrides(scenario, overrides, variant.key), vehicle


def fly(variant: Variant, seed: int, duration: float | None = None) -> SwarmResult:
    """Fly one variant for one flight seed (studies.swarm.simulate_swarm)."""
    scenario, vehicle = load_variant(variant, duration)
    return swarm_module.simulate_swarm(scenario, vehicle, seed=seed)


# ---------------------------------------------------------------------------------------------- metrics


def orbit_phases(series: dict[int, dict[str, np.ndarray]]) -> np.ndarray:
    """Phase of each pursuer about the true target, rad, shape (T, n), pursuers in id order: the angle
    of the horizontal offset target -> pursuer measured from east towards north (counter-clockwise seen
    from above, the orbit direction)."""
    columns = []
    for ident in sorted(series):
        offset = series[ident]["pursuer_position"] - series[ident]["target_position"]
        columns.append(np.arctan2(offset[:, 0], offset[:, 1]))
    return np.stack(columns, axis=1)


def gaps_ahead(phases: np.ndarray) -> np.ndarray:
    """Delta_i of seed 002 for every pursuer: the CCW angle to the nearest pursuer ahead, rad in (0, 2 pi],
    shape (T, n) for phases (T, n). With n pursuers the gaps of one instant sum to 2 pi."""
    ahead = np.mod(phases[:, None, :] - phases[:, :, None], TWO_PI)  # [t, i, j]: CCW angle from i to j
    count = phases.shape[1]
    ahead[:, np.arange(count), np.arange(count)] = np.inf
    ahead[ahead == 0.0] = TWO_PI  # two pursuers at one phase: the one "ahead" is a full turn away
    return ahead.min(axis=2)


def settle_time(time: np.ndarray, error: np.ndarray, bound: float) -> float | None:
    """First time from which |error| (shape (T,) or (T, k), all columns) stays under bound to the end;
    None if it is over the bound at the end."""
    over = ~(np.abs(error) < bound)
    if over.ndim == 2:
        over = over.any(axis=1)
    indices = np.flatnonzero(over)
    if len(indices) == 0:
        return float(time[0])
    return None if indices[-1] + 1 >= len(time) else float(time[indices[-1] + 1])


def _rms(values: np.ndarray) -> float | None:
    values = np.asarray(values, dtype=float).ravel()
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values**2))) if len(values) else None


def _max_abs(values: np.ndarray) -> float | None:
    values = np.asarray(values, dtype=float).ravel()
    values = values[np.isfinite(values)]
    return float(np.max(np.abs(values))) if len(values) else None


def error_series(result: SwarmResult) -> dict[str, np.ndarray]:
    """The figures' curves, each (T, n) with one column per pursuer (id order), plus time (T,):
    distance_error m, height_error m (seed 004, NaN otherwise), phase_gap rad, position_error m,
    velocity_error m/s."""
    series = result.series
    idents = sorted(series)
    time = series[idents[0]]["time"]
    swarm = result.scenario.swarm
    if swarm.guidance == "standoff":
        radius, height = swarm.standoff.radius, swarm.standoff.height
    else:  # circumnavigation: D* is [guidance] desired_range (companion.assembly)
        radius, height = result.scenario.guidance.desired_range, None
    distance, height_error, position, velocity = [], [], [], []
    for ident in idents:
        data = series[ident]
        offset = data["target_position"] - data["pursuer_position"]
        distance.append(np.hypot(offset[:, 0], offset[:, 1]) - radius)
        height_error.append(offset[:, 2] - height if height is not None else np.full(len(time), np.nan))
        position.append(np.linalg.norm(data["estimate_position"] - data["target_position"], axis=1))
        velocity.append(np.linalg.norm(data["estimate_velocity"] - data["target_velocity"], axis=1))
    return {"time": time, "distance_error": np.stack(distance, axis=1), "height_error": np.stack(height_error, axis=1),
            "phase_gap": gaps_ahead(orbit_phases(series)), "position_error": np.stack(position, axis=1),
            "velocity_error": np.stack(velocity, axis=1)}


def flight_metrics(result: SwarmResult, variant: Variant) -> dict:
    """One flight's figures (module docstring), steady window from variant.steady_from."""
    curves = error_series(result)
    time = curves["time"]
    steady = time >= variant.steady_from
    count = curves["phase_gap"].shape[1]
    phase_error = np.degrees(curves["phase_gap"] - TWO_PI / count)
    distance_bound, phase_bound, estimation_bound = variant.bounds
    summary = result.summary
    return {
        "variant": variant.key, "scenario": variant.scenario, "overrides": variant.overrides,
        "seed": summary["seed"], "duration": float(time[-1]), "termination": summary["termination"],
        "termination_reason": summary["termination_reason"], "steady_from": variant.steady_from,
        "distance_error_rms": _rms(curves["distance_error"][steady]),
        "distance_error_mean": float(np.nanmean(curves["distance_error"][steady])) if steady.any() else None,
        "distance_error_max_abs": _max_abs(curves["distance_error"][steady]),
        "height_error_rms": _rms(curves["height_error"][steady]),
        "phase_gap_error_deg_rms": _rms(phase_error[steady]),
        "phase_gap_error_deg_max_abs": _max_abs(phase_error[steady]),
        "position_estimation_error_rms": _rms(curves["position_error"][steady]),
        "position_estimation_error_rms_per_pursuer": [_rms(column) for column in curves["position_error"][steady].T],
        "velocity_estimation_error_rms": _rms(curves["velocity_error"][steady]),
        "distance_settled_at": settle_time(time, curves["distance_error"], distance_bound),
        "phase_settled_at": settle_time(time, phase_error, phase_bound),
        "estimation_settled_at": settle_time(time, curves["position_error"], estimation_bound),
        "settle_bounds": {"distance_m": distance_bound, "phase_deg": phase_bound, "estimation_m": estimation_bound},
        "min_pursuer_separation": summary["min_pursuer_separation"],
        "max_tilt_deg": max(entry["max_tilt_deg"] for entry in summary["pursuers"]),
        "max_speed": max(entry["max_speed"] for entry in summary["pursuers"]),
        "neighbour_bearings_used": [entry["neighbour_bearings_used"] for entry in summary["pursuers"]],
    }


AGGREGATED = ("distance_error_rms", "distance_error_mean", "height_error_rms", "phase_gap_error_deg_rms",
              "position_estimation_error_rms", "velocity_estimation_error_rms", "distance_settled_at",
              "phase_settled_at", "estimation_settled_at", "min_pursuer_separation", "max_tilt_deg")


def aggregate(flights: Sequence[dict]) -> dict:
    """Mean, min and max over flight seeds of each AGGREGATED figure; a settling time that never came
    (None) is counted in `never`."""
    out = {"flights": len(flights), "terminations": sorted({f["termination"] for f in flights})}
    for key in AGGREGATED:
        values = [f[key] for f in flights if f[key] is not None]
        out[key] = ({"mean": float(np.mean(values)), "min": float(np.min(values)), "max": float(np.max(values)),
                     "never": len(flights) - len(values)} if values else None)
    return out


# ---------------------------------------------------------------------------------------------- figures


def _per_pursuer(axes, time: np.ndarray, values: np.ndarray, scale: float = 1.0) -> None:
    for column in range(values.shape[1]):
        axes.plot(time, values[:, column] * scale, lw=0.9, label=f"pursuer {column + 1}")


def plot_flight(result: SwarmResult, variant: Variant, folder: Path, title: str) -> None:
    """distances.png, phase_gaps.png, estimation.png, tracks.png of one flight into `folder`."""
    curves = error_series(result)
    time = curves["time"]
    count = curves["phase_gap"].shape[1]
    standoff = result.scenario.swarm.guidance == "standoff"

    rows = 2 if standoff else 1
    figure, axes = plt.subplots(rows, 1, figsize=(8, 3.2 * rows), sharex=True, squeeze=False)
    _per_pursuer(axes[0, 0], time, curves["distance_error"])
    axes[0, 0].axhline(0.0, color="k", lw=0.6)
    axes[0, 0].set_ylabel("|p_T - p_i|_h - R [m]" if standoff else "D_i - D* [m]")
    if standoff:
        _per_pursuer(axes[1, 0], time, curves["height_error"])
        axes[1, 0].axhline(0.0, color="k", lw=0.6)
        axes[1, 0].set_ylabel("height above target - H [m]")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].legend(fontsize=7, ncol=count)
    axes[0, 0].set_title(f"{title}: distance to the target")
    figure.tight_layout()
    figure.savefig(folder / "distances.png", dpi=110)
    plt.close(figure)

    figure, axes = plt.subplots(figsize=(8, 3.4))
    _per_pursuer(axes, time, curves["phase_gap"], scale=180.0 / math.pi)
    axes.axhline(360.0 / count, color="k", lw=0.8, ls="--", label=f"2 pi / {count}")
    axes.set_ylabel("Delta_i, CCW gap ahead [deg]")
    axes.set_xlabel("time [s]")
    axes.set_ylim(0.0, 360.0)
    axes.legend(fontsize=7, ncol=count + 1)
    axes.set_title(f"{title}: phase gaps")
    figure.tight_layout()
    figure.savefig(folder / "phase_gaps.png", dpi=110)
    plt.close(figure)

    figure, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    _per_pursuer(axes[0], time, curves["position_error"])
    axes[0].set_ylabel("|p^_T - p_T| [m]")
    axes[0].set_yscale("log")
    _per_pursuer(axes[1], time, curves["velocity_error"])
    axes[1].set_ylabel("|v^_T - v_T| [m/s]")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("time [s]")
    axes[0].legend(fontsize=7, ncol=count)
    axes[0].set_title(f"{title}: target estimation error")
    figure.tight_layout()
    figure.savefig(folder / "estimation.png", dpi=110)
    plt.close(figure)

    figure, axes = plt.subplots(figsize=(7, 7))
    first = result.series[min(result.series)]
    axes.plot(first["target_position"][:, 1], first["target_position"][:, 0], "k-", lw=1.2, label="target")
    for ident in sorted(result.series):
        track = result.series[ident]["pursuer_position"]
        axes.plot(track[:, 1], track[:, 0], lw=0.7, label=f"pursuer {ident}")
        axes.plot(track[0, 1], track[0, 0], "o", ms=4, color=axes.lines[-1].get_color())
    axes.set_xlabel("east [m]")
    axes.set_ylabel("north [m]")
    axes.set_aspect("equal", adjustable="datalim")
    axes.legend(fontsize=7)
    axes.set_title(f"{title}: tracks (map view)")
    figure.tight_layout()
    figure.savefig(folder / "tracks.png", dpi=110)
    plt.close(figure)


# ---------------------------------------------------------------------------------------------- report


def _cell(entry: dict | None, digits: int = 2) -> str:
    if entry is None:
        return "never"
    text = f"{entry['mean']:.{digits}f} [{entry['min']:.{digits}f}, {entry['max']:.{digits}f}]"
    return text + (f" ({entry['never']} never)" if entry.get("never") else "")


def _number(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def summary_table(paper: str, aggregates: dict[str, dict]) -> str:
    """Markdown table of the variants' aggregates: mean [min, max] over flight seeds."""
    lines = [f"# Seed {paper} reproduction: mean [min, max] over flight seeds", "",
             "| variant | flights | distance err RMS m | phase gap err RMS deg | position est. RMS m | "
             "velocity est. RMS m/s | distance settled s | phase settled s | estimate settled s | closest m |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for key, entry in aggregates.items():
        lines.append(f"| {key} | {entry['flights']} ({', '.join(entry['terminations'])}) | "
                     f"{_cell(entry['distance_error_rms'])} | {_cell(entry['phase_gap_error_deg_rms'])} | "
                     f"{_cell(entry['position_estimation_error_rms'])} | {_cell(entry['velocity_estimation_error_rms'])} | "
                     f"{_cell(entry['distance_settled_at'], 1)} | {_cell(entry['phase_settled_at'], 1)} | "
                     f"{_cell(entry['estimation_settled_at'], 1)} | {_cell(entry['min_pursuer_separation'])} |")
    return "\n".join(lines) + "\n"


def run(paper: str, seeds: Sequence[int], out: Path, duration: float | None = None,
        variants: Sequence[str] | None = None, figures: bool = True, echo=print) -> Path:
    """Fly `paper`'s variants (all, or those named) for every flight seed; write and return the run folder."""
    chosen = [v for v in REPRODUCTIONS[paper] if variants is None or v.key in variants]
    unknown = set(variants or ()) - {v.key for v in REPRODUCTIONS[paper]}
    if unknown:
        raise ConfigError(f"seed {paper} has no variant {sorted(unknown)}; it has {[v.key for v in REPRODUCTIONS[paper]]}")
    folder = new_run_folder(out, f"seed{paper}")
    flights: dict[str, list[dict]] = {}
    for variant in chosen:
        flights[variant.key] = []
        for seed in seeds:
            started = wall.perf_counter()
            result = fly(variant, seed, duration)
            elapsed = wall.perf_counter() - started
            metrics = flight_metrics(result, variant)
            metrics["wall_time_s"] = elapsed
            metrics["shared_estimates_dropped"] = {str(entry["pursuer"]): entry["estimates_not_shared"]
                                                   for entry in result.summary["pursuers"]}
            flights[variant.key].append(metrics)
            target = folder / variant.key / f"seed{seed}"
            target.mkdir(parents=True)
            write_summary(target / "metrics.json", metrics)
            if figures:
                plot_flight(result, variant, target, f"seed {paper} {variant.key}, flight seed {seed}")
            echo(f"{variant.key} seed {seed}: {metrics['termination']} ({metrics['termination_reason']}), "
                 f"{metrics['duration']:.0f} s in {elapsed:.1f} s; steady distance err rms "
                 f"{_number(metrics['distance_error_rms'])} m, phase gap err rms "
                 f"{_number(metrics['phase_gap_error_deg_rms'], 1)} deg, position est. rms "
                 f"{_number(metrics['position_estimation_error_rms'])} m")
    aggregates = {key: aggregate(entries) for key, entries in flights.items()}
    write_summary(folder / "summary.json", {"paper": paper, "seeds": list(seeds), "duration_override": duration,
                                            "variants": {v.key: dataclasses.asdict(v) for v in chosen},
                                            "aggregates": aggregates, "flights": flights})
    (folder / "summary.md").write_text(summary_table(paper, aggregates))
    return folder


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-seed-repro` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-seed-repro",
                           description="Fly the seed papers' several-pursuer simulations (seed 002 "
                                       "circumnavigation, seed 004 standoff) and write a run folder.")
    parser.add_argument("paper", choices=sorted(REPRODUCTIONS), help="which seed paper's simulation")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4],
                        help="flight seeds, integers >= 0 (default: %(default)s)")
    parser.add_argument("--variants", nargs="+", default=None,
                        help="only these variants (default: all; names in docs/reproduction.md)")
    parser.add_argument("--duration", type=float, default=None,
                        help="s, shorten (or lengthen) every flight (default: the scenario files' durations)")
    parser.add_argument("--out", type=output_folder, default="runs", help="parent folder of the run folder (default: %(default)s)")
    parser.add_argument("--no-figures", action="store_true", help="metrics only, no PNGs")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if any(seed < 0 for seed in args.seeds):
        parser.error("--seeds: each seed must be >= 0")
    for flag, values in (("--seeds", args.seeds), ("--variants", args.variants or [])):
        repeated = sorted({str(value) for value in values if values.count(value) > 1})
        if repeated:  # a seed twice wrote the same run folder twice (FileExistsError after the first flight)
            parser.error(f"{flag}: {', '.join(repeated)} given twice")
    if args.duration is not None and not 0.0 < args.duration <= MAX_DURATION_S:
        parser.error(f"--duration must be > 0 and at most {MAX_DURATION_S:g} s")
    try:
        folder = run(args.paper, args.seeds, Path(args.out), args.duration, args.variants, not args.no_figures)
    except ConfigError as error:
        print(f"bof-seed-repro: {error}", file=sys.stderr)
        return 2
    print((folder / "summary.md").read_text())
    print(f"run folder: {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
