"""Benchmark: u-PLKF update cost, whole pipeline step cost, closed-loop real-time factor.

Run: python benchmarks/bench_pipeline.py. Prints medians over repeats; timings are
figures for notes, never test assertions (machines here are shared and noisy).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np
from timing import median_us

from companion.assembly import build_pipeline
from interfaces.scenario import load_scenario
from companion.core.estimators import GainProjection, InitialGuess, UPLKF
from companion.core.messages import BearingMeasurement, PursuerState
from studies.closed_loop import simulate

SCENARIO = Path(__file__).resolve().parent.parent / "config" / "scenarios" / "constant_velocity.toml"


def bench_estimator() -> None:
    rng = np.random.default_rng(0)
    for projection in (GainProjection.MEASURED, GainProjection.PREDICTED):  # noise_free: bench_estimators.py
        estimator = UPLKF(0.02, 0.04 * np.eye(3), 1e-4 * np.eye(3), projection, pursuer_position_std=0.1)
        first = BearingMeasurement(0.0, np.array([0.8, -0.4, -0.3]), np.zeros(3))
        estimator.initialize_on_bearing(first, InitialGuess(47.0, 30.0, np.zeros(3), 5.0))
        bearing = BearingMeasurement(0.0, np.array([0.8, -0.4, -0.3]) + rng.normal(0, 0.01, 3), np.zeros(3))
        predict = median_us(estimator.predict, 2000)
        correct = median_us(lambda: estimator.correct(BearingMeasurement(estimator.time, bearing.direction, bearing.pursuer_position)), 2000)
        print(f"u-PLKF ({projection.value:9s}) predict {predict:6.1f} us   correct {correct:6.1f} us")


def bench_pipeline_step() -> None:
    scenario, vehicle = load_scenario(SCENARIO)
    pipeline = build_pipeline(scenario, vehicle, 2.0 / 3.0)
    direction = np.array([0.8, -0.4, -0.3])
    pipeline.step(0.0, PursuerState(0.0, np.zeros(3), np.array([2.0, 0.0, 0.0])), BearingMeasurement(0.0, direction, np.zeros(3)))
    clock = {"t": 0.0}

    def control_tick() -> None:
        clock["t"] += 0.05  # one control period: 2-3 predicts, a bearing and a setpoint each call
        t = clock["t"]
        pipeline.step(t, PursuerState(t, np.zeros(3), np.array([2.0, 0.0, 0.0])), BearingMeasurement(t, direction, np.zeros(3)))

    print(f"pipeline step with predicts + correction + setpoint: {median_us(control_tick, 500):6.1f} us")


def bench_closed_loop() -> None:
    scenario, vehicle = load_scenario(SCENARIO)
    walls, cpus = [], []
    for _ in range(5):
        wall, cpu = time.perf_counter(), time.process_time()
        result = simulate(scenario, vehicle)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    duration = result.summary["duration"]
    print(
        f"closed loop, {duration:.0f} s flight: wall median {statistics.median(walls):.2f} s "
        f"(real-time factor {duration / statistics.median(walls):.0f}x), CPU median {statistics.median(cpus):.2f} s "
        f"({duration / statistics.median(cpus):.0f}x)"
    )


if __name__ == "__main__":
    bench_estimator()
    bench_pipeline_step()
    bench_closed_loop()
