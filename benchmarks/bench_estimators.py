"""Benchmark: cost of one predict() and one correct() for the u-PLKF and the baseline estimators.

Run: python benchmarks/bench_estimators.py. Prints a Markdown table of medians over
repeats (microseconds); timings are figures for notes, never test assertions (machines
here are shared and noisy). Every estimator sees the same geometry: target ~47 m away
along [0.8, -0.4, -0.3], bearing noise sigma = 0.01, bearings with a true direction
(for the noise-free u-PLKF) and a range (for the range/az/el EKF). The IMM rows: its
predict (every model filter's) and its correct (the model corrections, likelihoods, mixing);
the pipeline also reads the combined estimate once per tick, which the figures include
through correct's own use of it only. The last column compares each update with a fixed
budget reference, the u-PLKF's 33.3 us per update before the IMM and the kernels (the goal: the
default estimator within 4x that); on a loaded machine, time the reference side by side instead
(docs/reproduction.md section 4).

Side by side with the code before a change: python benchmarks/bench_estimators.py --against DIR,
DIR a checkout of the older code (git worktree add /tmp/old <commit>, or git archive <commit> | tar -x -C DIR).
In alternating subprocesses (DIR's code, this tree with its kernels compiled by numba when installed, this
tree with BOF_NO_JIT=1), each round measures the u-PLKF (predicted) and both IMMs as above and one
in-process flight (studies.closed_loop.simulate, constant_velocity, seed 1, median of 5); the table gives the
medians over the rounds and each column's ratio to DIR's. With --baselines: the three baseline estimators' predict
and correct, and one 60 s flight of the estimator study (bof-montecarlo --study estimators, 50 Hz) with each.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from timing import median_us

from companion.core.baseline_estimators import MSCEKF, AzElEKF, RangeAzElEKF
from companion.core.estimators import GainProjection, InitialGuess, UPLKF
from companion.core.imm import IMMEstimator, standard_models
from companion.core.messages import BearingMeasurement

PERIOD = 0.02
PROCESS_NOISE = 0.04 * np.eye(3)
MEASUREMENT_NOISE = 1e-4 * np.eye(3)
LINE_OF_SIGHT = np.array([0.8, -0.4, -0.3]) / np.linalg.norm([0.8, -0.4, -0.3])
RANGE = 47.0
REFERENCE_UPLKF_US = 33.3
"""us: the u-PLKF's update (predict + correct) before the IMM and the kernels, the reference of the cost goal."""


def _estimators() -> list[tuple[str, object]]:
    uplkf = [
        (f"u-PLKF ({projection.value})", UPLKF(PERIOD, PROCESS_NOISE, MEASUREMENT_NOISE, projection, pursuer_position_std=0.1))
        for projection in (GainProjection.MEASURED, GainProjection.PREDICTED, GainProjection.NOISE_FREE)
    ]
    return uplkf + [
        ("AzElEKF", AzElEKF(PERIOD, PROCESS_NOISE, MEASUREMENT_NOISE, pursuer_position_std=0.1)),
        ("MSCEKF", MSCEKF(PERIOD, PROCESS_NOISE, MEASUREMENT_NOISE, pursuer_position_std=0.1)),
        ("RangeAzElEKF", RangeAzElEKF(PERIOD, MEASUREMENT_NOISE, range_noise_std=1.0)),
        ("IMM (cv, ct +-0.2)", IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), MEASUREMENT_NOISE,
                                            GainProjection.PREDICTED, pursuer_position_std=0.1)),
        ("IMM (cv, ct +-0.1, +-0.3)", IMMEstimator(PERIOD, standard_models([0.1, 0.3], 0.04, 0.04), MEASUREMENT_NOISE,
                                                   GainProjection.PREDICTED, pursuer_position_std=0.1)),
        ("IMM (the default)", _default_estimator()),
    ]


def _default_estimator() -> object:
    """The estimator a scenario gets when its [estimator] names nothing but the rate (the tree's defaults: the model
    set of the code on the import path), at this benchmark's period."""
    from companion.assembly import build_estimator
    from interfaces.scenario import SCENARIOS_DIR, load_scenario
    from studies.montecarlo import with_overrides

    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    return build_estimator(with_overrides(scenario, {"estimator": {"rate_hz": 1.0 / PERIOD, "initial_range": RANGE}}))


def bench(count: int = 2000, only: tuple[str, ...] | None = None) -> list[tuple[str, float, float]]:
    """(name, predict us, correct us) per estimator (those named in `only`, when given)."""
    rng = np.random.default_rng(0)
    noisy = LINE_OF_SIGHT + rng.normal(0.0, 0.01, 3)
    results = []
    for name, estimator in _estimators():
        if only is not None and name not in only:
            continue
        first = BearingMeasurement(0.0, LINE_OF_SIGHT, np.zeros(3), range=RANGE, true_direction=LINE_OF_SIGHT)
        estimator.initialize_on_bearing(first, InitialGuess(RANGE, 30.0, np.zeros(3), 5.0))
        predict = median_us(estimator.predict, count)

        def correct(estimator=estimator) -> None:
            estimator.correct(BearingMeasurement(estimator.time, noisy, np.zeros(3), range=RANGE, true_direction=LINE_OF_SIGHT))

        results.append((name, predict, median_us(correct, count)))
    return results


def markdown_table(results: list[tuple[str, float, float]]) -> str:
    reference = next(p + c for name, p, c in results if name == "u-PLKF (predicted)")
    lines = [
        "| estimator | predict median us | correct median us | update (predict+correct) us | ratio to u-PLKF predicted"
        f" | ratio to {REFERENCE_UPLKF_US} us |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, predict, correct in results:
        update = predict + correct
        lines.append(f"| {name} | {predict:.1f} | {correct:.1f} | {update:.1f} | {update / reference:.2f}"
                     f" | {update / REFERENCE_UPLKF_US:.2f} |")
    return "\n".join(lines)


SIDE_BY_SIDE = ("u-PLKF (predicted)", "IMM (cv, ct +-0.2)", "IMM (cv, ct +-0.1, +-0.3)", "IMM (the default)")
"""The rows timed side by side: the u-PLKF's form, a 3-model and a 5-model IMM, and each tree's default estimator."""
BASELINES = {"AzElEKF": "ekf", "MSCEKF": "msc_ekf", "RangeAzElEKF": "ekf_rae"}
"""The rows timed side by side with --baselines, and each one's name in the estimator study (studies.montecarlo)."""


def flight_seconds(repeats: int = 5) -> tuple[float, float]:
    """(median wall time, s, of one in-process flight of constant_velocity at seed 1, its simulated duration, s)."""
    from interfaces.scenario import SCENARIOS_DIR, load_scenario

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    return _median_flight(scenario, vehicle, repeats)


def _median_flight(scenario, vehicle, repeats: int) -> tuple[float, float]:
    """(median wall time, s, of `repeats` seed-1 flights of `scenario` after one that compiles / warms up, its
    simulated duration, s)."""
    from studies.closed_loop import simulate

    duration = simulate(scenario, vehicle, seed=1).summary["duration"]
    walls = []
    for _ in range(repeats):
        started = time.perf_counter()
        simulate(scenario, vehicle, seed=1)
        walls.append(time.perf_counter() - started)
    return statistics.median(walls), duration


def study_flight_seconds(estimator: str, repeats: int = 3) -> tuple[float, float]:
    """(median wall time, s, of one flight of the estimator study (studies.montecarlo: constant_velocity, HNG, the
    paper's system) with `estimator` at 50 Hz bearings, the initial estimate of seed 1, its simulated duration, s)."""
    from interfaces.scenario import SCENARIOS_DIR, load_scenario
    from studies.montecarlo import ESTIMATORS, GUIDANCE, PAPER_INITIAL_BOX, PAPER_SYSTEM, drawn_initial_position, with_overrides

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    scenario = with_overrides(scenario, {**PAPER_SYSTEM, **ESTIMATORS[estimator], **GUIDANCE["hng"], "sensor.rate_hz": 50.0,
                                         "estimator.initialize": "position",
                                         "estimator.initial_position": drawn_initial_position(1, PAPER_INITIAL_BOX)})
    return _median_flight(scenario, vehicle, repeats)


def measure(baselines: bool = False) -> dict:
    """One round in this process (whatever tree is on the import path): the SIDE_BY_SIDE rows and a flight, or with
    `baselines` the BASELINES rows and one estimator-study flight of each."""
    if baselines:
        rows = {name: (predict, correct) for name, predict, correct in bench(only=tuple(BASELINES))}
        flights = {name: study_flight_seconds(estimator) for name, estimator in BASELINES.items()}
        return {"rows": rows, "flights": {name: wall for name, (wall, _) in flights.items()},
                "duration": next(iter(flights.values()))[1]}
    rows = {name: (predict, correct) for name, predict, correct in bench(only=SIDE_BY_SIDE)}
    wall, duration = flight_seconds()
    return {"rows": rows, "flight": wall, "duration": duration}


def side_by_side(other: Path, rounds: int, baselines: bool = False) -> str:
    """Alternating subprocesses of `other`'s code, this tree compiled, this tree with BOF_NO_JIT=1 (module docstring);
    with `baselines` the baseline estimators' rows and flights instead."""
    here = Path(__file__).resolve().parent.parent
    columns = {f"{other}": (other, {}), "this tree": (here, {}), "this tree, BOF_NO_JIT=1": (here, {"BOF_NO_JIT": "1"})}
    results: dict[str, list[dict]] = {label: [] for label in columns}
    for _ in range(rounds):
        for label, (tree, extra) in columns.items():
            environment = {key: value for key, value in os.environ.items() if key != "BOF_NO_JIT"}
            environment.update(PYTHONPATH=str(tree), **extra)
            output = subprocess.run([sys.executable, __file__, "--measure"] + (["--baselines"] if baselines else []),
                                    env=environment, cwd=str(tree), check=True, capture_output=True, text=True).stdout
            results[label].append(json.loads(output.strip().splitlines()[-1]))
    reference = next(iter(columns))

    def median(label: str, pick) -> float:
        return statistics.median(pick(result) for result in results[label])

    lines = [f"Medians of {rounds} alternating rounds, microseconds (flight: seconds of wall time); ratio = {reference} / column.",
             "", "| | " + " | ".join(f"{label} | ratio" for label in columns) + " |",
             "|---|" + "---:|---:|" * len(columns)]
    picks = []
    for name in (BASELINES if baselines else SIDE_BY_SIDE):
        picks += [(f"{name} predict", lambda r, n=name: r["rows"][n][0]), (f"{name} correct", lambda r, n=name: r["rows"][n][1]),
                  (f"{name} update", lambda r, n=name: r["rows"][n][0] + r["rows"][n][1])]
    duration = results[reference][0]["duration"]
    if baselines:
        for name, estimator in BASELINES.items():
            picks.append((f"flight, estimator study, {estimator} at 50 Hz, seed 1 ({duration:.0f} s), median of 3",
                          lambda r, n=name: r["flights"][n]))
    else:
        picks.append((f"flight constant_velocity seed 1 ({duration:.0f} s), median of 5", lambda r: r["flight"]))
    for title, pick in picks:
        base = median(reference, pick)
        cells = [f"{median(label, pick):.3g} | {base / median(label, pick):.2f}" for label in columns]
        lines.append(f"| {title} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, help="a checkout of the older code to time side by side with this tree")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds with --against (default 3)")
    parser.add_argument("--baselines", action="store_true",
                        help="with --against: the baseline estimators (az/el, MSC, range/az/el EKF) and a study flight of each")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)  # one round, JSON (side_by_side's subprocesses)
    arguments = parser.parse_args()
    if arguments.measure:
        print(json.dumps(measure(arguments.baselines)))
    elif arguments.against is not None:
        print(side_by_side(arguments.against.resolve(), arguments.rounds, arguments.baselines))
    else:
        print(markdown_table(bench()))
