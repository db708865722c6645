"""The bearing path's trims of issue 16 (one flight cheaper) compute what the code they replaced computed, bit
for bit: each new kernel compiled against its own Python function (`kernel.py_func`) and against the numpy
expressions it replaced, and each object built without its dataclass constructor equal to the constructor's.

- the u-PLKF's prior line of sight (estimators._prior_line_of_sight): p^-_T + tau v^-_T - p, its length, the
  clipped cosine (Python's min and max: a NaN stays NaN) and remark 3's guard, as UPLKF.correct formed them;
- the u-PLKF's correction report (estimators._correction_report) is CorrectionReport(...);
- the u-PLKF's one kernel call (estimators._correct_into) is _correct_kernel's update, innovation and S, and the
  NIS _normalized_innovation_squared gave from S^+ when called after it (adaptive process noise);
- the health monitor's numbers in one call (health._bearing_evidence): normalized_innovation_squared's NIS and
  the old geometry (test_diagnostic_kernels.old_health_geometry), its report (health._health_report) is
  HealthReport(...), and its chi^2 bounds cached across monitors (health._nis_bound) are scipy's each time;
- a monitor's whole update: the NIS of an empty innovation is 0 and enters the window, a mismatched innovation
  still raises before anything changes, a restart computes no NIS;
- the windowed FIM's usual sample in one call (observability._add_plain_sample): _plain_sample's decision, then
  _add_contribution's term added and the oldest term subtracted, in that order, as add and _drop_older_than did
  (test_diagnostic_kernels.test_windowed_fim_is_the_old_one compares whole windows with the old class);
- the own-position tracker's step in one kernel (estimators._own_position_step, _carried_position): every
  reference of random sample sequences (repeated stamps, late samples, gaps) is the old tracker's;
- measure's spectrum written into the window's buffer (observability._spectrum_into) is _spectrum's;
- after warmup.warm_up every new kernel is compiled.
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
from test_estimator_kernels import correction_arguments

from companion.core import _jit
from companion import warmup
from companion.core import estimators, health, observability
from companion.core.estimators import OWN_ACCELERATION_PSD, OWN_TRACK_MAX_GAP, CorrectionReport, OwnPositionTracker
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
        relative = np.full(3, 7.0)
        predicted_range, cos_angle, behind = function(state, lead, pursuer, direction, relative)
        assert_same((relative, predicted_range, cos_angle), expected[:3])
        assert behind == expected[3]
        assert isinstance(cos_angle, float) and isinstance(predicted_range, float)


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
            assert_same(function(state, 0.0, np.zeros(3), direction, np.empty(3))[1], cosine)


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


@settings(max_examples=300, deadline=None)
@given(seeds, st.integers(-3, 6), floats(-0.3, 0.3), st.booleans(), st.booleans(), st.booleans(),
       st.sampled_from([0.0, 0.01, 1.0]), st.sampled_from([None, 0.0, 0.1, 1e3]), st.booleans())
def test_correct_into_is_correct_kernel_then_nis(seed, exponent, lead, late, use_predicted, position_noise,
                                                 noise_scale, reference_offset, with_nis):
    """Noisy bearings reach the general pseudo-inverse and the Joseph form, as in test_estimator_kernels.test_correct."""
    arguments = correction_arguments(seed, exponent, lead if late else 0.0, late, use_predicted, position_noise,
                                     noise_scale, reference_offset)
    copies = [np.array(a) if isinstance(a, np.ndarray) else a for a in arguments]
    innovation, innovation_covariance, innovation_inverse = estimators._correct_kernel(*copies)
    expected_nis = estimators._normalized_innovation_squared(innovation, innovation_inverse) if with_nis else math.nan
    for function in (estimators._correct_into, python(estimators._correct_into)):
        mine = [np.array(a) if isinstance(a, np.ndarray) else a for a in arguments]
        y, s = np.full(3, 7.0), np.full((3, 3), 7.0)
        nis = function(*mine, with_nis, y, s)
        assert_same((y, s, nis), (innovation, innovation_covariance, expected_nis))
        assert_same(tuple(mine[:2]), tuple(copies[:2]))  # the same state and covariance, updated in place
        assert type(nis) is float


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
        assert_same(window, expected_information)
        assert_same(term, expected_term if plain else np.full((3, 3), 7.0))


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

class OldOwnPositionTracker:
    """estimators.OwnPositionTracker as it was (505f6f6), verbatim: tuples of Python floats."""

    def __init__(self, position_std: float, acceleration_psd: float = OWN_ACCELERATION_PSD,
                 max_gap: float = OWN_TRACK_MAX_GAP) -> None:
        if not position_std > 0.0:
            raise ValueError("the own-position tracker needs a positive position_std")
        self.position_std = float(position_std)
        self.acceleration_psd = float(acceleration_psd)
        self.max_gap = float(max_gap)
        self._time: float | None = None
        # Per-axis floats rather than numpy arrays: at three elements the arithmetic is cheaper
        # than numpy's per-call overhead, and this runs at every correction.
        self._position = (0.0, 0.0, 0.0)
        self._velocity = (0.0, 0.0, 0.0)
        self._last_prediction = np.zeros(3)
        self._p00 = self._p01 = self._p11 = 0.0

    def reference(self, time: float, position: np.ndarray) -> np.ndarray:
        """The own position (m, shape (3,)) at `time` (s) predicted from the samples before
        this one; then folds this sample (the reported position, m, shape (3,)) in.
        Special cases (first, repeated, late, after a gap): see the class docstring."""
        dt = None if self._time is None else time - self._time
        if dt is None or abs(dt) > self.max_gap:
            position = np.array(position, dtype=float)
            if dt is None or dt > 0.0:
                self._restart(float(time), position)
            return position
        if dt == 0.0:
            # A second bearing at the same stamp: the state already holds that sample's error,
            # the prediction made before it does not.
            return self._last_prediction
        x0, x1, x2 = self._position
        v0, v1, v2 = self._velocity
        if dt < 0.0:
            # A late sample: carried back from later ones, it is not folded in (the tracker
            # runs forward in time only).
            return np.array((x0 + dt * v0, x1 + dt * v1, x2 + dt * v2))
        q = self.acceleration_psd
        # Time update of the shared 2x2 covariance [[p00, p01], [p01, p11]] and of the state.
        p00 = self._p00 + dt * (2.0 * self._p01 + dt * self._p11) + q * dt**3 / 3.0
        p01 = self._p01 + dt * self._p11 + q * dt**2 / 2.0
        p11 = self._p11 + q * dt
        a0, a1, a2 = x0 + dt * v0, x1 + dt * v1, x2 + dt * v2
        # Measurement update with the sample: gains k0 (position), k1 (velocity).
        innovation_variance = p00 + self.position_std**2
        k0, k1 = p00 / innovation_variance, p01 / innovation_variance
        z0, z1, z2 = np.asarray(position, dtype=float).tolist()
        e0, e1, e2 = z0 - a0, z1 - a1, z2 - a2
        self._position = (a0 + k0 * e0, a1 + k0 * e1, a2 + k0 * e2)
        self._velocity = (v0 + k1 * e0, v1 + k1 * e1, v2 + k1 * e2)
        self._p00, self._p01, self._p11 = (1.0 - k0) * p00, (1.0 - k0) * p01, p11 - k1 * p01
        self._time = time
        self._last_prediction = np.array((a0, a1, a2))
        return self._last_prediction

    def _restart(self, time: float, position: np.ndarray) -> None:
        self._time = time
        self._position = tuple(position.tolist())
        self._velocity = (0.0, 0.0, 0.0)
        self._last_prediction = position
        # Unknown velocity: a prior std of 10 m/s, far beyond a following drone's speed changes.
        self._p00, self._p01, self._p11 = self.position_std**2, 0.0, 100.0


@settings(max_examples=200, deadline=None)
@given(seeds, floats(-3.0, 0.0), floats(0.1, 10.0), st.sampled_from([5.0, 50.0, 100.0]), st.booleans())
def test_own_position_tracker_is_the_old_one(seed, log_std, psd, rate, python_kernels):
    """References of a random own-position series (noisy, with repeated stamps, late samples and gaps beyond
    max_gap) equal the old tracker's, bit for bit; the kernels compiled or as Python functions."""
    rng = np.random.default_rng(seed)
    std = 10.0**log_std
    new, old = OwnPositionTracker(std, psd), OldOwnPositionTracker(std, psd)
    if python_kernels:
        import companion.core.estimators as module
        step, carried = module._own_position_step, module._carried_position
        module._own_position_step, module._carried_position = python(step), python(carried)
    try:
        time = 0.0
        velocity = rng.normal(size=3) * 5.0
        for _ in range(int(rng.integers(1, 120))):
            time += rng.choice([1.0 / rate, 0.0, -0.5 / rate, 2.0 * OWN_TRACK_MAX_GAP, 3.0 / rate],
                               p=[0.7, 0.08, 0.08, 0.04, 0.1])
            position = velocity * time + rng.normal(size=3) * std
            assert_same(new.reference(time, position), old.reference(time, position))
    finally:
        if python_kernels:
            module._own_position_step, module._carried_position = step, carried
