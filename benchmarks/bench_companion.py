"""Benchmark of the whole SITL chain: the constant-velocity scenario flown by bof-sitl at several
speed factors. Not a test; quote medians and the spread between runs.

    python benchmarks/bench_companion.py [--speeds 1 10] [--config config/scenarios/constant_velocity.toml]

A progress bar (on stderr) follows each flight in simulated seconds since the companion engaged.
Reported per speed factor: target fix received -> bearing into the estimator, and -> the next
setpoint sent (wall clock, p50/p99), companion control deadline misses (a setpoint sent after the
next 20 Hz control tick was already due, in vehicle time), the plant's achieved speed factor, and
the flight's range and range-estimation errors (so a fast run that flies worse is visible).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tqdm import tqdm  # noqa: E402

from interfaces import link_schema  # noqa: E402
from interfaces.scenario import load_scenario  # noqa: E402
from studies import full_sitl  # noqa: E402

DEFAULT = Path(__file__).resolve().parent.parent / "config" / "scenarios" / "constant_velocity.toml"


def _converged(flight: dict) -> str:
    value = flight.get("convergence_time")
    return "did not converge" if value is None or not math.isfinite(value) else f"{value:.1f}"


def _show(bar: tqdm, state: "link_schema.CompanionState | None", engaged_at: float | None) -> None:
    """Move `bar` to the simulated seconds followed so far; its postfix names the companion's phase."""
    phase = "starting" if state is None else state.phase
    if phase != bar.postfix:
        bar.set_postfix_str(phase, refresh=False)
    if state is not None and engaged_at is not None:
        bar.update(min(max(state.stamp - engaged_at, 0.0), bar.total) - bar.n)
    else:
        bar.refresh()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 10.0],
                        help="speed factors to fly, one flight each (default: 1 10)")
    parser.add_argument("--config", type=Path, default=DEFAULT, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1, help="seed of every flight (default: %(default)s)")
    args = parser.parse_args(argv)
    scenario, _ = load_scenario(args.config)
    follow = scenario.companion.follow_duration or scenario.simulation.duration
    print("| speed | achieved | fix->estimator p50 / p99 (ms) | fix->setpoint p50 / p99 (ms) | deadline misses | "
          "range err rms (m) | range-est err rms (m) | converged (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for speed in args.speeds:
        with tempfile.TemporaryDirectory() as folder, \
                tqdm(total=follow, desc=f"x{speed:g}", unit="sim s", file=sys.stderr, leave=False,
                     bar_format="{desc}{postfix} |{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}]") as bar:
            code, _, summary = full_sitl.run(args.config, Path(folder), speed, args.seed, None, plots=False, quiet=True,
                                             on_state=lambda state, engaged: _show(bar, state, engaged))
        companion = summary["companion"]
        to_estimator = companion["latency_fix_to_estimator_ms"]
        to_setpoint = companion["latency_fix_to_setpoint_ms"]
        flight = summary.get("flight") or {}
        print(f"| {speed:g} | {summary['plant']['speed_factor_achieved']:.2f} | "
              f"{to_estimator['p50']:.2f} / {to_estimator['p99']:.2f} | {to_setpoint['p50']:.2f} / {to_setpoint['p99']:.2f} | "
              f"{companion['deadline_misses']}/{companion['setpoints_sent']} | {flight.get('range_error_rms', float('nan')):.3f} | "
              f"{flight.get('range_estimation_error_rms', float('nan')):.3f} | {_converged(flight)} |"
              + ("" if code == 0 else f" (exit {code})"), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
