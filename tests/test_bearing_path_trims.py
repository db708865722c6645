"""The bearing path's trims of issue 16 (one flight cheaper) compute what the code they replaced computed, bit
for bit: each new kernel compiled against its own Python function (`kernel.py_func`) and against the numpy
expressions it replaced, and each object built without its dataclass constructor equal to the constructor's.

- the u-PLKF's prior line of sight (estimators._prior_line_of_sight): p^-_T + tau v^-_T - p, its length, the
  clipped cosine (Python's min and max: a NaN stays NaN) and remark 3's guard, as UPLKF.correct formed them;
- the u-PLKF's correction report (estimators._correction_report) is CorrectionReport(...);
- the health monitor's numbers in one call (health._bearing_evidence): normalized_innovation_squared's NIS and
  the old geometry (test_diagnostic_kernels.old_health_geometry), its report (health._health_report) is
  HealthReport(...), and its chi^2 bounds cached across monitors (health._nis_bound) are scipy's each time;
- a monitor's whole update: the NIS of an empty innovation is 0 and enters the window, a mismatched innovation
  still raises before anything changes, a restart computes no NIS.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from bitwise import assert_same, seeds
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats

from scipy.stats import chi2
from test_diagnostic_kernels import covariances, families, old_health_geometry, old_normalized_innovation_squared

from companion.core import _jit
from companion.core import estimators, health
from companion.core.estimators import CorrectionReport
from companion.core.health import HealthConfig, HealthMonitor, HealthReport, HealthState

python = _jit.python_function

special = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e-13, 1e300])


def old_prior(state, lead, pursuer_position, direction):
    """UPLKF.correct's prior line of sight before the kernel (505f6f6), with its guard (restart_when_behind)."""
    relative = state[:3] + lead * state[3:] - pursuer_position
    predicted_range = math.sqrt(float(relative.dot(relative)))
    cos_angle = min(max(float(direction @ relative / max(predicted_range, 1e-12)), -1.0), 1.0)
    return relative, predicted_range, cos_angle, cos_angle <= 0.0 or predicted_range < 1e-6


@settings(max_examples=300, deadline=None)
@given(seeds, st.integers(-8, 8), floats(-0.5, 0.5), st.sampled_from(["ahead", "behind", "on", "special"]), special)
def test_prior_line_of_sight(seed, exponent, lead, where, value):
    rng = np.random.default_rng(seed)
    state = rng.normal(size=6) * 10.0**exponent
    pursuer = rng.normal(size=3) * 10.0**exponent
    direction = rng.normal(size=3)
    direction /= math.sqrt(float(direction @ direction))
    if where == "behind":
        state[:3] = pursuer - 10.0**exponent * direction - lead * state[3:]
    elif where == "on":
        state[:3] = pursuer - lead * state[3:]
    elif where == "special":
        state[rng.integers(6)] = value
    expected = old_prior(state, lead, pursuer, direction)
    for function in (estimators._prior_line_of_sight, python(estimators._prior_line_of_sight)):
        relative, predicted_range, cos_angle, behind = function(state, lead, pursuer, direction)
        assert_same((relative, predicted_range, cos_angle), expected[:3])
        assert behind == expected[3]
        assert isinstance(cos_angle, float) and isinstance(predicted_range, float)


def test_prior_line_of_sight_clips_as_pythons_min_and_max():
    """Cosines beyond +-1 by rounding are clipped, a NaN is kept (the guard then does not fire on the cosine)."""
    direction = np.array([-0.29634718220320333, -0.9501875070900958, 0.0965507585165991])  # unit, to rounding
    ahead = np.concatenate((32.425080287829374 * direction, np.zeros(3)))  # cosine 1 + 2^-52 unclipped
    assert float(direction @ ahead[:3] / math.sqrt(float(ahead[:3] @ ahead[:3]))) > 1.0
    for state, cosine in ((ahead, 1.0), (-ahead, -1.0), (np.array([math.nan, 0.0, 0.0, 0, 0, 0]), math.nan)):
        for function in (estimators._prior_line_of_sight, python(estimators._prior_line_of_sight)):
            assert_same(function(state, 0.0, np.zeros(3), direction)[2], cosine)


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
def test_bearing_evidence_is_the_old_nis_and_geometry(seed, family, exponent, with_innovation, log_range,
                                                      covariance_exponent):
    rng = np.random.default_rng(seed)
    innovation_covariance, innovation = covariances(seed, family, exponent)
    bearing, direction = rng.normal(size=3), rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    pursuer, velocity = rng.normal(size=3) * 50.0, rng.normal(size=3) * 5.0
    estimate = pursuer + direction * 10.0**log_range
    factor = rng.normal(size=(6, 6)) * 10.0**covariance_exponent
    covariance = factor @ factor.T
    expected = ((old_normalized_innovation_squared(innovation, innovation_covariance) if with_innovation else math.nan,)
                + old_health_geometry(bearing, pursuer, velocity, estimate, covariance))
    for function in (health._bearing_evidence, python(health._bearing_evidence)):
        result = function(innovation, innovation_covariance, with_innovation, bearing, estimate, pursuer, covariance,
                          velocity)
        assert_same(result, expected)
        assert all(type(value) is float for value in result)


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
    return monitor.update(time, los, np.zeros(3), np.ones(3), 20.0 * los, np.eye(6), innovation, innovation_covariance,
                          dof, reinitialized, None)


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
