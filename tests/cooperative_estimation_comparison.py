"""Comparison of cooperative estimators on one pure-core case (a measurement, not a test).

Three static sensors 120 degrees apart on a 25 m circle, 10 m above the middle of the track
of a constant-velocity ground target (1.0, 0.5, 0) m/s that starts at the origin; every sensor
takes a bearing at every 10 Hz filter tick (eq. (4) additive noise N(0, 0.01^2 I) on the unit
line of sight, i.e. about 0.01 rad), all stamped at the tick. Estimators:

  (a) TriangulationKalmanEstimator, seed 002's Q = 0.2 I per step and R = I ("tkf_seed"), and
      with a white-jerk Q (q = 0.01 (m/s^3)^2 s) and each triangulation's own covariance as R
      ("tkf_consistent"), and the latter with the older bearing of a pair taken as simultaneous
      (compensate_age off, "tkf_no_age_model"; with three sensors one pair in three spans two ticks);
  (b) one u-PLKF fed with all three sensors' bearings ("uplkf_all");
  (c) a u-PLKF fed with sensor 1 only ("uplkf_single");
  (d) three single-sensor u-PLKFs fused at every tick by covariance intersection ("uplkf_ci"),
      and by seed 004's eqs. (24)-(25) in turn ("uplkf_seed004").

The u-PLKFs are built as companion.assembly builds them from the scenario defaults (predicted
gain projection, Q = 0.04 I (m/s^2)^2, Sigma = 1e-4 I, restart when behind), with
pursuer_position_std = 0 since the sensors' positions are exact here. Every estimator starts
on sensor 1's (or its own sensor's) first bearing at a 25 m range guess (std 30 m), velocity
guess 0 (std 5 m/s). Reported: RMS of the 3-D position error pooled over the seeds, over
t in [5, 30] s and over the last 10 s, and the mean position NEES over t in [5, 30] s (3 for a
consistent estimator; larger: its covariance claims more than it has).

A second pass staggers the sensors: sensor i takes its bearing PERIOD/3 x i after the tick
(the pairs are then 1/30 or 2/30 s apart).

Run: python tests/cooperative_estimation_comparison.py [number of seeds, default 20]
"""

from __future__ import annotations

import sys

import numpy as np

from companion.core.cooperative_estimation import TriangulationKalmanEstimator, fuse_target_estimates, white_jerk_process_noise
from companion.core.estimators import GainProjection, InitialGuess, UPLKF
from companion.core.messages import BearingMeasurement

PERIOD = 0.1
DURATION = 30.0
NOISE_STD = 0.01
TARGET_START = np.array([0.0, 0.0, 0.0])
TARGET_VELOCITY = np.array([1.0, 0.5, 0.0])
_CENTRE = TARGET_START + TARGET_VELOCITY * DURATION / 2
SENSORS = [(_CENTRE + np.array([25.0 * np.cos(angle), 25.0 * np.sin(angle), -10.0]))
           for angle in np.radians([0.0, 120.0, 240.0])]
GUESS = InitialGuess(25.0, 30.0, np.zeros(3), 5.0)
NAMES = ("tkf_seed", "tkf_consistent", "tkf_no_age_model", "uplkf_all", "uplkf_single", "uplkf_ci", "uplkf_seed004")


def _uplkf() -> UPLKF:
    return UPLKF(period=PERIOD, process_noise=0.04 * np.eye(3), measurement_noise=NOISE_STD**2 * np.eye(3),
                 gain_projection=GainProjection.PREDICTED, pursuer_position_std=0.0, restart_when_behind=True)


def _errors(estimate, target: np.ndarray) -> tuple[float, float]:
    """(|position error|, m; position NEES) of a TargetEstimate."""
    error = estimate.position - target
    return float(np.linalg.norm(error)), float(error @ np.linalg.solve(estimate.covariance[:3, :3], error))


def run(seed: int, stagger: float = 0.0) -> dict[str, np.ndarray]:
    """One run: name -> (ticks, 2) array of [position error, m; position NEES] at t = k PERIOD,
    k = 0..DURATION/PERIOD. stagger: s, sensor i takes its bearing at t + i stagger (0: all at the tick)."""
    rng = np.random.default_rng(seed)
    ticks = int(round(DURATION / PERIOD))
    estimators = {
        "tkf_seed": TriangulationKalmanEstimator(PERIOD, bearing_noise_std=NOISE_STD),
        "tkf_consistent": TriangulationKalmanEstimator(PERIOD, process_noise=white_jerk_process_noise(PERIOD, 0.01),
                                                       measurement_noise=None, bearing_noise_std=NOISE_STD),
        "tkf_no_age_model": TriangulationKalmanEstimator(PERIOD, process_noise=white_jerk_process_noise(PERIOD, 0.01),
                                                         measurement_noise=None, bearing_noise_std=NOISE_STD,
                                                         compensate_age=False),
        "uplkf_all": _uplkf(),
    }
    singles = [_uplkf() for _ in SENSORS]
    errors: dict[str, list[tuple[float, float]]] = {name: [] for name in NAMES}
    for k in range(ticks + 1):
        time = k * PERIOD
        target = TARGET_START + TARGET_VELOCITY * time
        bearings = []
        for source, sensor in enumerate(SENSORS):
            taken = time + source * stagger
            seen = TARGET_START + TARGET_VELOCITY * taken
            line = (seen - sensor) / np.linalg.norm(seen - sensor)
            bearings.append(BearingMeasurement(taken, line + NOISE_STD * rng.standard_normal(3), sensor, source=source))
        for estimator in estimators.values():
            if k == 0:
                estimator.initialize_on_bearing(bearings[0], GUESS)
                rest = bearings[1:]
            else:
                estimator.predict()
                rest = bearings
            for bearing in rest:
                estimator.correct(bearing)
        for single, bearing in zip(singles, bearings):
            if k == 0:
                single.initialize_on_bearing(bearing, GUESS)
            else:
                single.predict()
                single.correct(bearing)
        for name, estimator in estimators.items():
            errors[name].append(_errors(estimator.estimate, target))
        own = singles[0].estimate
        errors["uplkf_single"].append(_errors(own, target))
        others = [single.estimate for single in singles[1:]]
        errors["uplkf_ci"].append(_errors(fuse_target_estimates(own, others, "ci"), target))
        errors["uplkf_seed004"].append(_errors(fuse_target_estimates(own, others, "seed004"), target))
    return {name: np.array(values) for name, values in errors.items()}


def compare(seeds: range, stagger: float = 0.0) -> dict[str, dict[str, float]]:
    """name -> {"rms_5_30": m, "rms_last_10": m, "nees_5_30": mean position NEES} pooled over the seeds."""
    runs = [run(seed, stagger) for seed in seeds]
    times = np.arange(len(runs[0][NAMES[0]])) * PERIOD
    after_5, last_10 = times >= 5.0 - 1e-9, times >= DURATION - 10.0 - 1e-9
    summary = {}
    for name in NAMES:
        stacked = np.stack([result[name] for result in runs])  # (seeds, ticks, 2)
        summary[name] = {"rms_5_30": float(np.sqrt(np.mean(stacked[:, after_5, 0] ** 2))),
                         "rms_last_10": float(np.sqrt(np.mean(stacked[:, last_10, 0] ** 2))),
                         "nees_5_30": float(np.mean(stacked[:, after_5, 1]))}
    return summary


def main() -> None:
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    for stagger in (0.0, PERIOD / 3):
        summary = compare(range(count), stagger)
        print(f"bearings of sensor i at t + {stagger:.3f} i s")
        print(f"{'estimator':<18}{'RMS 5-30 s (m)':>16}{'RMS last 10 s (m)':>20}{'NEES 5-30 s':>14}   ({count} seeds)")
        for name, figures in summary.items():
            print(f"{name:<18}{figures['rms_5_30']:>16.3f}{figures['rms_last_10']:>20.3f}{figures['nees_5_30']:>14.2f}")


if __name__ == "__main__":
    main()
