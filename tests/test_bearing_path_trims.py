"""The bearing path's one-call kernels against independent references: the clipped cosine of the prior line of
sight, the reports against their dataclasses' constructors, the health monitor's numbers against their closed
forms and scipy's chi^2 quantiles, the windowed FIM's one-call sample against its steps, the own-position tracker
against the textbook constant-velocity Kalman filter in matrix form, and the warm-up compiling these kernels.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from bitwise import assert_close, assert_same, seeds
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats

from scipy.stats import chi2
from test_diagnostic_kernels import covariances, families

from companion import warmup
from companion.core import _jit
from companion.core import estimators, health, observability
from companion.core.estimators import OWN_TRACK_MAX_GAP, CorrectionReport, OwnPositionTracker
from companion.core.health import HealthConfig, HealthMonitor, HealthReport, HealthState

python = _jit.python_function


def test_prior_line_of_sight_clips_as_pythons_min_and_max():
    """Cosines beyond +-1 by rounding are clipped, a NaN is kept (the guard then does not fire on the cosine)."""
    # A target straight ahead whose cosine rounds above 1 on this machine's BLAS (which vectors do depends on
    # its dot kernel, so one is searched for: a few in a hundred random ones do).
    rng = np.random.default_rng(7)
    for _ in range(100_000):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        ahead = np.concatenate((rng.uniform(1.0, 100.0) * direction, np.zeros(3)))
        if float(direction @ ahead[:3] / math.sqrt(float(ahead[:3] @ ahead[:3]))) > 1.0:
            break
    assert float(direction @ ahead[:3] / math.sqrt(float(ahead[:3] @ ahead[:3]))) > 1.0
    for state, cosine in ((ahead, 1.0), (-ahead, -1.0), (np.array([math.nan, 0.0, 0.0, 0, 0, 0]), math.nan)):
        for function in (estimators._prior_line_of_sight, python(estimators._prior_line_of_sight)):
            assert_close(function(state, 0.0, np.zeros(3), direction, np.empty(3))[1], cosine)


@given(floats(0.0, math.pi), st.booleans(), seeds, st.integers(0, 3))
def test_correction_report_is_the_dataclasses(angle, used_predicted, seed, dof):
    rng = np.random.default_rng(seed)
    innovation, covariance = rng.normal(size=3), rng.normal(size=(3, 3))
    report = estimators._correction_report(angle, used_predicted, innovation, covariance, dof)
    expected = CorrectionReport(angle, used_predicted, innovation=innovation, innovation_covariance=covariance,
                                innovation_dof=dof)
    assert type(report) is CorrectionReport
    assert vars(report) == vars(expected) and list(vars(report)) == list(vars(expected))
    assert repr(report) == repr(expected)
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.innovation_dof = 5


# ----- the health monitor ------------------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(seeds, families, st.integers(-8, 6), st.booleans(), floats(-10.0, 3.5), st.integers(-4, 2))
def test_bearing_evidence_is_the_nis_and_the_geometry(seed, family, exponent, with_innovation, log_range,
                                                      covariance_exponent):
    """(NIS, |p_T - p|, sigma_r / r = sqrt(l^T P l) / r, bearing . (p_T - p), |v|), as floats."""
    rng = np.random.default_rng(seed)
    innovation_covariance, innovation = covariances(seed, family, exponent)
    bearing, direction = rng.normal(size=3), rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    pursuer, velocity = rng.normal(size=3) * 50.0, rng.normal(size=3) * 5.0
    estimate = pursuer + direction * 10.0**log_range
    factor = rng.normal(size=(6, 6)) * 10.0**covariance_exponent
    covariance = factor @ factor.T
    relative = estimate - pursuer
    distance = float(np.linalg.norm(relative))
    los = relative / distance
    result = health._bearing_evidence(innovation, innovation_covariance, with_innovation, bearing, estimate, pursuer,
                                      covariance, velocity)
    assert all(type(value) is float for value in result)
    nis, range_estimate, relative_std, cosine, speed = result
    if with_innovation:
        assert_same(nis, health.normalized_innovation_squared(innovation, innovation_covariance))
    else:
        assert math.isnan(nis)
    scale = float(np.linalg.norm(pursuer)) + float(np.linalg.norm(estimate))
    assert range_estimate == pytest.approx(distance, rel=1e-12, abs=1e-15 * scale)
    if distance > 1e-9:
        along = math.sqrt(max(float(los @ covariance[:3, :3] @ los), 0.0))
        assert relative_std * range_estimate == pytest.approx(along, rel=1e-6, abs=1e-12 * math.sqrt(float(np.trace(covariance))))
    assert cosine == pytest.approx(float(bearing @ relative), rel=1e-9, abs=1e-13 * scale * float(np.linalg.norm(bearing)))
    assert speed == pytest.approx(float(np.linalg.norm(velocity)), rel=1e-14)


@given(floats(0.0, 100.0), st.sampled_from(list(HealthState)), st.lists(st.sampled_from(health.REASONS), max_size=3),
       st.lists(floats(-1e3, 1e3), min_size=4, max_size=4))
def test_health_report_is_the_dataclasses(time, state, reasons, numbers):
    values = (time, state, tuple(reasons), tuple(reversed(reasons)), *numbers)
    report, expected = health._health_report(*values), HealthReport(*values)
    assert type(report) is HealthReport
    assert vars(report) == vars(expected) and list(vars(report)) == list(vars(expected))
    assert report == expected and repr(report) == repr(expected)
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.time = 1.0


@given(st.integers(1, 3000), floats(1.0, 5.0), st.sampled_from([0.9, 0.99, 0.999]))
def test_nis_bounds_are_scipys_in_every_monitor(dof, scale, probability):
    expected = scale * float(chi2.ppf(probability, dof))
    config = HealthConfig(nis_scale=scale, nis_probability=probability)
    first, second = HealthMonitor(config), HealthMonitor(config)
    assert_same(first.nis_bound(dof), expected)
    assert_same(second.nis_bound(dof), expected)  # from the shared cache
    assert_same(health._nis_bound(scale, probability, dof), expected)


def test_the_shared_nis_bounds_cache_is_bounded(monkeypatch):
    monkeypatch.setattr(health, "_NIS_BOUNDS", {})
    monkeypatch.setattr(health, "_NIS_BOUNDS_LIMIT", 3)
    for dof in range(1, 8):
        assert_same(health._nis_bound(2.0, 0.999, dof), 2.0 * float(chi2.ppf(0.999, dof)))
        assert len(health._NIS_BOUNDS) <= 3


def _update(monitor, time, innovation, innovation_covariance, dof, reinitialized=False):
    los = np.array([0.8, -0.36, -0.48])
    return monitor.update(time, los, np.zeros(3), np.ones(3), 20.0 * los, np.eye(6), innovation=innovation,
                          innovation_covariance=innovation_covariance, innovation_dof=dof, reinitialized=reinitialized,
                          fim_min_eigenvalue=None)


def test_update_takes_the_nis_as_normalized_innovation_squared_gives_it():
    monitor = HealthMonitor(HealthConfig(min_nis_samples=1))
    innovation_covariance, innovation = covariances(7, "uplkf", -2)
    report = _update(monitor, 0.0, innovation, innovation_covariance, 2)
    assert_same(report.nis, health.normalized_innovation_squared(innovation, innovation_covariance))
    assert_same(report.nis_ratio, report.nis / monitor.nis_bound(2))
    report = _update(monitor, 0.1, np.zeros(0), np.zeros((0, 0)), 1)  # an empty innovation: 0, and it counts
    assert_same(report.nis, 0.0)
    assert monitor._window.dof_sum == 3 and len(monitor._window.samples) == 2
    with pytest.raises(ValueError, match="innovation"):  # nothing added, nothing reported
        _update(monitor, 0.2, np.ones(3), np.eye(2), 2)
    assert len(monitor._window.samples) == 2 and monitor.report.time == 0.1
    report = _update(monitor, 0.3, innovation, innovation_covariance, 2, reinitialized=True)
    assert math.isnan(report.nis) and len(monitor._window.samples) == 0
    report = _update(monitor, 0.4, innovation.tolist(), innovation_covariance.tolist(), 2)  # plain lists
    assert_same(report.nis, health.normalized_innovation_squared(innovation, innovation_covariance))


# ----- the windowed FIM --------------------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(seeds, floats(-4.0, -1.0), floats(-1.0, 4.0), st.booleans(),
       st.sampled_from(["unit", "off", "nan", "range_nan", "range_zero", "range_huge"]))
def test_add_plain_sample_is_plain_sample_then_add_then_drop(seed, log_sigma, log_range, drop, kind):
    rng = np.random.default_rng(seed)
    sigma, range_estimate = 10.0**log_sigma, 10.0**log_range
    bearing = rng.normal(size=3)
    bearing /= np.linalg.norm(bearing)
    if kind == "off":
        bearing *= 1.0 + 1e-6
    elif kind == "nan":
        bearing[1] = math.nan
    range_estimate = {"range_nan": math.nan, "range_zero": 0.0, "range_huge": 1e200}.get(kind, range_estimate)
    information = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(0, 6)
    oldest = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(0, 6)
    try:
        plain = python(observability._plain_sample)(bearing, range_estimate, sigma)
    except OverflowError:  # Python's ** overflowed (the compiled pow gives inf, so False): add raises it either way
        plain = None
    expected_information = information.copy()
    if plain:  # WindowedObservability.add and _drop_older_than as they were
        expected_term = observability._add_contribution(expected_information, bearing, sigma**2 * range_estimate**2)
        if drop:
            expected_information -= oldest
    for function in (observability._add_plain_sample, python(observability._add_plain_sample)):
        window = information.copy()
        term = np.full((3, 3), 7.0)
        if plain is None and function is python(observability._add_plain_sample):
            with pytest.raises(OverflowError):
                function(window, bearing, range_estimate, sigma, oldest, drop, term)
            assert_same(window, information)
            continue
        accepted = function(window, bearing, range_estimate, sigma, oldest, drop, term)
        plain = bool(plain)
        assert accepted == plain
        assert_close(window, expected_information)
        assert_close(term, expected_term if plain else np.full((3, 3), 7.0))


@settings(max_examples=200, deadline=None)
@given(seeds, families, st.integers(-8, 8))
def test_spectrum_into_is_spectrum(seed, family, exponent):
    matrix = np.zeros((3, 3))
    block = covariances(seed, family, exponent)[0]
    matrix[: len(block), : len(block)] = block
    values, minimum, spread = observability._spectrum(matrix)
    for function in (observability._spectrum_into, python(observability._spectrum_into)):
        eigenvalues = np.full(3, 7.0)
        assert_same(function(matrix, eigenvalues), (minimum, spread))
        assert_same(eigenvalues, values)


def test_warm_up_compiles_the_new_kernels():
    warmup.warm_up()
    for kernel in (estimators._prior_line_of_sight, estimators._correct_into, estimators._own_position_step, estimators._carried_position,
                   health._bearing_evidence, observability._add_plain_sample, observability._spectrum_into):
        if _jit.ENABLED:
            assert kernel.signatures, kernel
        else:
            assert python(kernel) is kernel


# ----- the own-position tracker ------------------------------------------------------------------------------------

# ----- the own-position tracker ------------------------------------------------------------------------------------

@settings(max_examples=200, deadline=None)
@given(seeds, floats(-3.0, 0.0), floats(0.1, 10.0), st.sampled_from([5.0, 50.0, 100.0]), st.booleans())
def test_own_position_tracker_is_the_constant_velocity_kalman_filter(seed, log_std, psd, rate, python_kernels):
    """Forward samples within max_gap: the reference is the prediction F x of the textbook per-axis Kalman filter
    (state [position, velocity], F = [[1, dt], [0, 1]], Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]], H = [1, 0],
    R = std^2), started on the first sample with a velocity std of 10 m/s; the kernels compiled or as Python."""
    rng = np.random.default_rng(seed)
    std = 10.0**log_std
    tracker = OwnPositionTracker(std, psd)
    if python_kernels:
        import companion.core.estimators as module
        step, carried = module._own_position_step, module._carried_position
        module._own_position_step, module._carried_position = python(step), python(carried)
    try:
        velocity = rng.normal(size=3) * 5.0
        time = 0.0
        first = velocity * time + rng.normal(size=3) * std
        assert_same(tracker.reference(time, first), first)
        state = np.stack([first, np.zeros(3)])  # rows: position, velocity (3 axes as columns)
        covariance = np.diag([std**2, 100.0])
        for _ in range(int(rng.integers(1, 120))):
            dt = float(rng.choice([1.0 / rate, 3.0 / rate]))
            assert dt <= OWN_TRACK_MAX_GAP
            time += dt
            sample = velocity * time + rng.normal(size=3) * std
            transition = np.array([[1.0, dt], [0.0, 1.0]])
            noise = psd * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
            state = transition @ state
            covariance = transition @ covariance @ transition.T + noise
            prediction = state[0].copy()
            gain = covariance[:, 0] / (covariance[0, 0] + std**2)
            state = state + np.outer(gain, sample - state[0])
            covariance = covariance - np.outer(gain, covariance[0])
            reference = tracker.reference(time, sample)
            np.testing.assert_allclose(reference, prediction, rtol=1e-9, atol=1e-9 * (std + float(np.abs(prediction).max())))
    finally:
        if python_kernels:
            module._own_position_step, module._carried_position = step, carried
