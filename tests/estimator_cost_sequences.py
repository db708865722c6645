"""Bearing sequences and estimator runs for tests/test_estimator_cost_paths.py, and the recorder of
its reference (python tests/estimator_cost_sequences.py with the pre-change companion package first
on PYTHONPATH writes tests/data/estimator_cost_reference.npz). Public API only, so it runs on the
code before and after the cost work alike."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from companion.core.estimators import AdaptiveNoiseSettings, GainProjection, InitialGuess, UPLKF
from companion.core.imm import IMMEstimator, standard_models
from companion.core.messages import BearingMeasurement

REFERENCE = Path(__file__).parent / "data" / "estimator_cost_reference.npz"
PERIOD = 0.02
STEPS = 1500  # 30 s at 50 Hz
KEEP = 50  # every 50th estimate is recorded (a difference at any step carries on to the later ones)


def bearing_sequence(seed: int, bearing_std: float, steps: int = STEPS) -> list[BearingMeasurement]:
    """A target on a 0.25 rad/s turn at 5 m/s, a pursuer weaving ~10 m away with white 0.1 m
    own-position noise, one bearing per 50 Hz tick with isotropic noise of bearing_std (rad)."""
    rng = np.random.default_rng(seed)
    bearings = []
    for k in range(steps):
        t = k * PERIOD
        heading = 0.25 * t
        target = np.array([20.0 * np.sin(heading), 20.0 * (1.0 - np.cos(heading)), -10.0])
        pursuer = target + np.array([-10.0 * np.cos(heading) + 2.0 * np.sin(1.3 * t), -10.0 * np.sin(heading),
                                     4.0 + np.sin(0.7 * t)])
        true_direction = (target - pursuer) / np.linalg.norm(target - pursuer)
        direction = true_direction + rng.normal(0.0, bearing_std, 3)
        reported = pursuer + rng.normal(0.0, 0.1, 3)
        bearings.append(BearingMeasurement(t, direction / np.linalg.norm(direction), reported,
                                           true_direction=true_direction))
    return bearings


def estimators() -> dict[str, object]:
    """The configurations whose update paths the change touches."""
    q, sigma = 0.04 * np.eye(3), 1e-4 * np.eye(3)
    return {
        "uplkf_predicted": UPLKF(PERIOD, q, sigma, GainProjection.PREDICTED, pursuer_position_std=0.1),
        "uplkf_measured": UPLKF(PERIOD, q, sigma, GainProjection.MEASURED, pursuer_position_std=0.1),
        "uplkf_noise_free": UPLKF(PERIOD, q, sigma, GainProjection.NOISE_FREE),
        "uplkf_adaptive": UPLKF(PERIOD, q, sigma, GainProjection.PREDICTED, pursuer_position_std=0.1,
                                adaptive_noise=AdaptiveNoiseSettings()),
        "imm": IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), sigma, GainProjection.PREDICTED,
                            pursuer_position_std=0.1),
        "imm_measured": IMMEstimator(PERIOD, standard_models([0.1, 0.3], 0.04, 0.04), sigma, GainProjection.MEASURED,
                                     pursuer_position_std=0.1),
    }


def run(estimator, bearings: list[BearingMeasurement], boost: float = 1.0) -> dict[str, np.ndarray]:
    """After each predict + correct: states (steps, 6), covariances (steps, 6, 6), and the correction
    report's innovation (steps, 3) and innovation covariance (steps, 3, 3) that the health monitor
    reads (NaN where a correction restarted the filter)."""
    estimator.initialize_on_bearing(bearings[0], InitialGuess(15.0, 10.0, np.zeros(3), 5.0))
    estimator.process_noise_boost = boost
    rows: dict[str, list] = {"states": [], "covariances": [], "innovations": [], "innovation_covariances": []}
    for bearing in bearings[1:]:
        estimator.predict()
        report = estimator.correct(bearing)
        estimate = estimator.estimate
        rows["states"].append(np.concatenate([estimate.position, estimate.velocity]))
        rows["covariances"].append(estimate.covariance)
        rows["innovations"].append(np.full(3, np.nan) if report.innovation is None else report.innovation)
        rows["innovation_covariances"].append(np.full((3, 3), np.nan) if report.innovation_covariance is None
                                              else report.innovation_covariance)
    return {kind: np.array(values) for kind, values in rows.items()}


def reference_runs() -> dict[str, np.ndarray]:
    """Every configuration on the normal (0.01 rad) and the far too noisy (1 rad) sequences."""
    runs = {}
    for label, bearing_std, boost in (("normal", 0.01, 1.0), ("noisy", 1.0, 1.0), ("boosted", 0.01, 3.0)):
        bearings = bearing_sequence(7, bearing_std)
        for name, estimator in estimators().items():
            for kind, values in run(estimator, bearings, boost).items():
                runs[f"{label}/{name}/{kind}"] = values[KEEP - 1::KEEP]
    return runs


if __name__ == "__main__" and sys.argv[1:] == []:
    np.savez_compressed(REFERENCE, **reference_runs())
    print(f"wrote {REFERENCE}")
