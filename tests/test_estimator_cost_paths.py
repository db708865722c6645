"""The cheaper arithmetic of the u-PLKF and IMM updates changes no result.

Two kinds of evidence:
- every closed form or shortcut against numpy's general routine on random inputs (hypothesis);
- whole bearing sequences (a turning target seen at 50 Hz from a weaving pursuer with noisy
  own position, and a filter fed bearings far noisier than its Sigma, which takes the scale-safe
  pseudo-inverse and the Joseph form) against the states the filters produced before the
  change, recorded in tests/data/estimator_cost_reference.npz by this module's
  `reference_runs` on the pre-change code (regenerate: python tests/test_estimator_cost_paths.py).
"""

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


def run(estimator, bearings: list[BearingMeasurement], boost: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """States (steps, 6) and covariances (steps, 6, 6) after each predict + correct."""
    estimator.initialize_on_bearing(bearings[0], InitialGuess(15.0, 10.0, np.zeros(3), 5.0))
    estimator.process_noise_boost = boost
    states, covariances = [], []
    for bearing in bearings[1:]:
        estimator.predict()
        estimator.correct(bearing)
        estimate = estimator.estimate
        states.append(np.concatenate([estimate.position, estimate.velocity]))
        covariances.append(estimate.covariance)
    return np.array(states), np.array(covariances)


def reference_runs() -> dict[str, np.ndarray]:
    """Every configuration on the normal (0.01 rad) and the far too noisy (1 rad) sequences."""
    runs = {}
    for label, bearing_std, boost in (("normal", 0.01, 1.0), ("noisy", 1.0, 1.0), ("boosted", 0.01, 3.0)):
        bearings = bearing_sequence(7, bearing_std)
        for name, estimator in estimators().items():
            states, covariances = run(estimator, bearings, boost)
            runs[f"{label}/{name}/states"] = states[KEEP - 1::KEEP]
            runs[f"{label}/{name}/covariances"] = covariances[KEEP - 1::KEEP]
    return runs


if __name__ == "__main__" and sys.argv[1:] == []:
    np.savez_compressed(REFERENCE, **reference_runs())
    print(f"wrote {REFERENCE}")
