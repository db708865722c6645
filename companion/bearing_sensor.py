"""Bearing sensor models: how a true line of sight becomes a measured bearing.

The companion rebuilds the true bearing from the target's position and corrupts it
as the configured sensor would; only the corrupted bearing reaches the estimator.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from companion.geometry import unit


def additive_bearing(true_bearing: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    """lambda~ = lambda + nu, nu ~ N(0, sigma^2 I), eq. (4). Shape (3,); not unit in general."""
    return np.asarray(true_bearing, float) + rng.normal(0.0, noise_std, 3)


def rotated_bearing(true_bearing: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    """lambda~ = R_eta(epsilon) lambda, eq. (25): a rotation by epsilon ~ N(0, sigma^2)
    about a random axis eta perpendicular to lambda. Shape (3,), unit."""
    lam = unit(np.asarray(true_bearing, float))
    helper = rng.normal(size=3)
    axis = unit(np.cross(lam, helper))
    return Rotation.from_rotvec(axis * rng.normal(0.0, noise_std)).apply(lam)


def measure_bearing(model: str, true_bearing: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    """Dispatch on the configured sensor model ('additive' eq. (4) or 'rotation' eq. (25))."""
    if model == "additive":
        return additive_bearing(true_bearing, noise_std, rng)
    if model == "rotation":
        return rotated_bearing(true_bearing, noise_std, rng)
    raise ValueError(f"unknown bearing sensor model {model!r}")
