"""Every bearing noise the scenario schema accepts flies: the estimators stay finite with a
symmetric positive semi-definite covariance whatever the bearings (noise_std = 1
used to end in LinAlgError from the u-PLKF's pseudo-inverse), and the schema refuses, with
its reason, only noise that no estimator could use."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats

from companion.core.baseline_estimators import AzElEKF, MSCEKF, RangeAzElEKF
from companion.core.bearing_sensor import BearingSensor
from companion.core.estimators import MAX_RANGE, GainProjection, InitialGuess, UPLKF
from companion.core.messages import BearingMeasurement
from interfaces.scenario import MAX_BEARING_NOISE_STD, MAX_RANGE_NOISE_STD, SCENARIOS_DIR, Scenario, load_scenario
from studies.closed_loop import Termination, simulate

PERIOD = 0.02


def _estimators(sigma: float, range_noise_std: float) -> dict:
    """Every estimator kind, told a bearing noise sigma that need not match the sensor's."""
    q, sigma_matrix = 0.04 * np.eye(3), sigma**2 * np.eye(3)
    return {
        "uplkf_predicted": UPLKF(PERIOD, q, sigma_matrix, GainProjection.PREDICTED, pursuer_position_std=0.1),
        "uplkf_measured": UPLKF(PERIOD, q, sigma_matrix, GainProjection.MEASURED, pursuer_position_std=0.1),
        "ekf": AzElEKF(PERIOD, q, sigma_matrix, 0.1),
        "msc_ekf": MSCEKF(PERIOD, q, sigma_matrix, 0.1),
        "ekf_rae": RangeAzElEKF(PERIOD, sigma_matrix, max(range_noise_std, 0.1), pursuer_position_std=0.1),
    }


def _degenerate(kind: str, true_bearing: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Bearings the noise can produce at large noise_std, forced: the exact opposite of the
    line of sight, one perpendicular to it, and very short or very long noisy vectors."""
    if kind == "antiparallel":
        return -true_bearing
    if kind == "perpendicular":
        return np.cross(true_bearing, [0.0, 0.0, 1.0]) + np.cross(true_bearing, [1.0, 0.0, 0.0])
    if kind == "short":
        return 1e-6 * measured
    if kind == "long":
        return 1e3 * measured
    return measured


def _assert_sound(name: str, estimate) -> None:
    """Finite state; covariance finite, symmetric and PSD (its eigenvalues, up to rounding)."""
    assert np.all(np.isfinite(estimate.position)) and np.all(np.isfinite(estimate.velocity)), name
    covariance = estimate.covariance
    assert np.all(np.isfinite(covariance)), name
    scale = max(float(np.max(np.abs(covariance))), 1e-300)
    np.testing.assert_allclose(covariance, covariance.T, rtol=0.0, atol=1e-12 * scale, err_msg=name)
    eigenvalues = np.linalg.eigvalsh(0.5 * (covariance + covariance.T))
    assert eigenvalues.min() >= -1e-9 * scale, (name, eigenvalues)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    model=st.sampled_from(["additive", "rotation"]),
    noise_std=st.one_of(st.just(MAX_BEARING_NOISE_STD), st.just(1.0), floats(0.0, MAX_BEARING_NOISE_STD)),
    sigma=st.sampled_from([1e-3, 1e-2, 0.1, 1.0, 10.0]),
    range_noise_std=st.sampled_from([0.0, 1.0, MAX_RANGE_NOISE_STD]),
    degenerate=st.lists(st.sampled_from(["none", "none", "antiparallel", "perpendicular", "short", "long"]),
                        min_size=60, max_size=60),
)
def test_estimators_stay_finite_and_psd_under_any_accepted_bearing_noise(seed, model, noise_std, sigma, range_noise_std,
                                                                           degenerate):
    rng = np.random.default_rng(seed)
    sensor = BearingSensor(model, noise_std, range_noise_std=range_noise_std)
    estimators = _estimators(sigma, range_noise_std)
    target, target_velocity = np.array([30.0, -10.0, -15.0]), np.array([3.0, 4.0, 0.0])
    pursuer, pursuer_velocity = np.zeros(3), np.array([2.0, 1.0, -0.5])
    guess = InitialGuess(25.0, 30.0, np.zeros(3), 5.0)
    for step, kind in enumerate(degenerate):
        time = step * 5 * PERIOD
        relative = target + time * target_velocity - (pursuer + time * pursuer_velocity)
        true_bearing = relative / np.linalg.norm(relative)
        direction = _degenerate(kind, true_bearing, sensor.measure(true_bearing, rng))
        bearing = BearingMeasurement(time, direction, pursuer + time * pursuer_velocity,
                                     range=sensor.measure_range(float(np.linalg.norm(relative)), rng))
        for name, estimator in estimators.items():
            if not estimator.initialized:
                estimator.initialize_on_bearing(bearing, guess)
            else:
                for _ in range(5):
                    estimator.predict()
                estimator.correct(bearing)
            _assert_sound(name, estimator.estimate)
            if name.startswith("uplkf") or name == "ekf":
                # The ceiling on the estimated range holds after every correction.
                assert np.linalg.norm(estimator.estimate.position - bearing.pursuer_position) <= MAX_RANGE * (1 + 1e-9)


def test_short_flight_at_noise_std_one_completes():
    """The hard case: noise_std = 1 with the estimator's Sigma left at 1e-4 I. Useless bearings,
    a poor estimate, but no exception and a finite estimate throughout a 15 s flight."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    data = scenario.model_dump()
    data["sensor"]["noise_std"] = 1.0
    data["simulation"].update(duration=15.0, summary_window=10.0)
    result = simulate(Scenario.model_validate(data), vehicle, seed=1)
    assert result.termination is Termination.COMPLETED
    assert result.summary["duration"] == pytest.approx(15.0, abs=0.05)
    for key in ("estimate_position", "estimate_velocity"):
        engaged = ~np.isnan(result.series[key]).any(axis=1)
        assert engaged.sum() > 100 and np.all(np.isfinite(result.series[key][engaged]))


def _sensor_section(**sensor) -> dict:
    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    data = scenario.model_dump()
    data["sensor"].update(sensor)
    return data


@pytest.mark.parametrize("sensor", [{"noise_std": MAX_BEARING_NOISE_STD}, {"range_noise_std": MAX_RANGE_NOISE_STD},
                                    {"model": "camera", "camera": {"pixel_noise_std": 1e6}}])
def test_schema_accepts_noise_up_to_the_bounds(sensor):
    data = _sensor_section(**{key: value for key, value in sensor.items() if key != "camera"})
    if "camera" in sensor:
        data["sensor"]["camera"].update(sensor["camera"])
    Scenario.model_validate(data)


@pytest.mark.parametrize(("key", "value", "reason"), [("noise_std", math.nextafter(MAX_BEARING_NOISE_STD, math.inf), "uniformly random"),
                                                     ("range_noise_std", 2 * MAX_RANGE_NOISE_STD, "says nothing")])
def test_schema_refuses_useless_noise_with_its_reason(key, value, reason):
    with pytest.raises(ValueError, match=reason):
        Scenario.model_validate(_sensor_section(**{key: value}))
