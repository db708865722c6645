"""Opt-in adaptive process noise of the u-PLKF (companion.core.estimators.AdaptiveProcessNoise).

The references are independent of the code: the chi-square law of the normalised innovation
squared of a correctly tuned linear-Gaussian Kalman filter (scipy.stats.chi2), and exact
equality with the constant-Q filter when the option is off or cannot act (max_scale = 1).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from companion.assembly import build_estimator
from companion.core.estimators import (AdaptiveNoiseSettings, AdaptiveProcessNoise, GainProjection, InitialGuess,
                                       UPLKF)
from companion.core.messages import BearingMeasurement
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, load_scenario
from interfaces.overrides import apply_overrides

PERIOD = 0.02  # s, 50 Hz estimator and bearings
SEEDS = st.integers(0, 2**32 - 1)


def _bearings(seed: int, count: int, turn_rate: float = 0.0) -> list[BearingMeasurement]:
    """Noisy bearings of a target 10 m ahead of a weaving pursuer, at 50 Hz; the target flies
    straight at 3 m/s (turn_rate 0) or circles at turn_rate rad/s."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        t = k * PERIOD
        if turn_rate == 0.0:
            target = np.array([10.0 + 3.0 * t, 0.0, -5.0])
        else:
            target = np.array([10.0 + 3.0 / turn_rate * np.sin(turn_rate * t),
                               3.0 / turn_rate * (1.0 - np.cos(turn_rate * t)), -5.0])
        pursuer = target - np.array([10.0, 2.0 * np.sin(0.5 * t), 1.0 + np.cos(0.5 * t)])
        line = target - pursuer
        noisy = line / np.linalg.norm(line) + 0.01 * rng.standard_normal(3)
        out.append(BearingMeasurement(t, noisy / np.linalg.norm(noisy), pursuer + 0.0))
    return out


def _fly(estimator: UPLKF, bearings: list[BearingMeasurement]) -> tuple[np.ndarray, np.ndarray, list[float]]:
    estimator.initialize_on_bearing(bearings[0], InitialGuess(range=8.0, range_std=5.0, velocity=np.zeros(3),
                                                              velocity_std=3.0))
    scales = []
    for bearing in bearings[1:]:
        estimator.predict()
        estimator.correct(bearing)
        scales.append(estimator.process_noise_scale)
    estimate = estimator.estimate
    return np.concatenate([estimate.position, estimate.velocity]), estimate.covariance, scales


def _uplkf(adaptive: AdaptiveNoiseSettings | None) -> UPLKF:
    return UPLKF(PERIOD, 0.04 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED, pursuer_position_std=0.0,
                 adaptive_noise=adaptive)


def test_option_off_by_default_and_the_built_filter_matches_the_constant_q_one() -> None:
    scenario, _ = load_scenario(DEFAULT_SCENARIO)
    assert scenario.estimator.adaptive_process_noise is False
    scenario = apply_overrides(scenario, {"estimator.kind": "uplkf"}, "test")  # the option is the u-PLKF's
    built = build_estimator(scenario)
    assert isinstance(built, UPLKF) and built.adaptive_noise is None and built.process_noise_scale == 1.0
    on = build_estimator(apply_overrides(scenario, {"estimator.adaptive_process_noise": True,
                                                    "estimator.adaptive_max_scale": 9.0}, "test"))
    assert isinstance(on, UPLKF) and on.adaptive_noise is not None and on.adaptive_noise.settings.max_scale == 9.0


def test_option_refused_for_the_baselines() -> None:
    scenario, _ = load_scenario(DEFAULT_SCENARIO)
    with pytest.raises((ConfigError, ValueError)):
        apply_overrides(scenario, {"estimator.kind": "ekf", "estimator.adaptive_process_noise": True}, "test")


@settings(max_examples=10, deadline=None)
@given(SEEDS, st.sampled_from([0.0, 0.5]))
def test_a_scale_that_cannot_act_leaves_the_filter_bit_identical(seed: int, turn_rate: float) -> None:
    """max_scale = 1 clips every scale to exactly 1: the filter must equal the constant-Q one bit for bit."""
    bearings = _bearings(seed, 400, turn_rate)
    state_off, cov_off, _ = _fly(_uplkf(None), bearings)
    state_on, cov_on, scales = _fly(_uplkf(AdaptiveNoiseSettings(max_scale=1.0)), bearings)
    assert set(scales) == {1.0}
    np.testing.assert_array_equal(state_on, state_off)
    np.testing.assert_array_equal(cov_on, cov_off)


@settings(max_examples=10, deadline=None)
@given(SEEDS, st.floats(1.0, 100.0), st.sampled_from([0.0, 0.5, 1.0]))
def test_the_scale_stays_within_its_bounds(seed: int, max_scale: float, turn_rate: float) -> None:
    _, covariance, scales = _fly(_uplkf(AdaptiveNoiseSettings(max_scale=max_scale)), _bearings(seed, 500, turn_rate))
    assert all(1.0 <= s <= max_scale * (1 + 1e-12) for s in scales)
    assert np.all(np.isfinite(covariance))


def _linear_kalman_nis(seed: int, steps: int, adapter: AdaptiveProcessNoise, acceleration_from: int | None = None,
                       acceleration: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A 1-D constant-velocity target with white acceleration noise q, position measured with
    noise r, tracked by the textbook Kalman filter with exactly these q and r (times the
    adapter's scale). From step acceleration_from on, the truth also gets a constant
    acceleration (a manoeuvre the model does not have). Returns the NIS and scale per step."""
    rng = np.random.default_rng(seed)
    dt, q, r = 0.1, 0.01, 0.25
    a = np.array([[1.0, dt], [0.0, 1.0]])
    b = np.array([0.5 * dt**2, dt])
    h = np.array([1.0, 0.0])
    truth = np.zeros(2)
    x, p = np.zeros(2), np.diag([r, 1.0])
    nis, scales = np.empty(steps), np.empty(steps)
    for k in range(steps):
        u = rng.normal(0.0, np.sqrt(q))
        if acceleration_from is not None and k >= acceleration_from:
            u += acceleration
        truth = a @ truth + b * u
        x, p = a @ x, a @ p @ a.T + adapter.scale * q * np.outer(b, b)
        y = truth[0] + rng.normal(0.0, np.sqrt(r)) - h @ x
        s = h @ p @ h + r
        nis[k] = y * y / s
        gain = p @ h / s
        x, p = x + gain * y, p - np.outer(gain, h @ p)
        scales[k] = adapter.update(k * dt, nis[k], 1)
    return nis, scales


@settings(max_examples=10, deadline=None)
@given(SEEDS)
def test_consistent_innovations_keep_the_scale_near_one(seed: int) -> None:
    """A correctly tuned linear-Gaussian filter: its NIS is chi^2(1) (checked against the
    distribution's 99.9 % interval for the sum), and the scale stays near 1 throughout."""
    steps = 3000
    nis, scales = _linear_kalman_nis(seed, steps, AdaptiveProcessNoise(AdaptiveNoiseSettings(max_scale=25.0)))
    settled = nis[100:]
    low, high = chi2.ppf([0.0005, 0.9995], settled.size)
    assert low <= settled.sum() <= high * 1.05  # the small Q inflation only lowers the NIS
    assert np.median(scales) < 1.2
    assert np.max(scales) < 3.0


@settings(max_examples=10, deadline=None)
@given(SEEDS)
def test_a_manoeuvre_raises_the_scale_and_it_relaxes_afterwards(seed: int) -> None:
    """An unmodelled 2 m/s^2 acceleration makes the windowed NIS far exceed its chi^2 bound;
    the scale rises well above 1. Fed chi^2(1) samples afterwards it relaxes back to 1."""
    adapter = AdaptiveProcessNoise(AdaptiveNoiseSettings(max_scale=25.0))
    nis, scales = _linear_kalman_nis(seed, 600, adapter, acceleration_from=300, acceleration=2.0)
    window = nis[300:340]
    assert window.sum() > chi2.ppf(0.999, window.size)  # the manoeuvre is visible in the NIS
    assert scales[299] < 2.0 and scales[300:].max() > 5.0
    rng = np.random.default_rng(seed)
    t0 = 600 * 0.1
    # 120 s of consistent innovations; the running mean is below 1 about half of the time
    # (the median of a chi^2 mean is below its expectation), so ~6 relax_time_constant of decay.
    for k in range(1, 1201):
        adapter.update(t0 + 0.1 * k, float(chi2.rvs(1, random_state=rng)), 1)
    assert adapter.scale < 1.2
