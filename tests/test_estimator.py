"""u-PLKF of section IV: model matrices (eq. 1), pseudo-linear measurement (eq. 5-6),
initialisation (remark 3), prediction, correction, the restart guard, bearings between
ticks, convergence of both gain forms, and the range bias of the paper's gain form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from paper_reference import floats, unit_vectors, vectors

from companion.core.estimators import (
    UPLKF,
    CorrectionReport,
    GainProjection,
    InitialGuess,
    pseudo_linear_measurement_matrix,
    transition_matrices,
)
from companion.core.geometry import orthogonal_projection, unit
from companion.core.messages import BearingMeasurement

SIGMA = 0.01  # bearing noise of eq. (4), Sigma = sigma^2 I (section IX)
Q_TARGET = 0.1  # target acceleration covariance, (m/s^2)^2 per axis

#: The forms that can fly (NOISE_FREE needs the true line of sight; tested on its own below).
FLYABLE = (GainProjection.MEASURED, GainProjection.PREDICTED)
PROPERTY = settings(max_examples=60, deadline=None)

# A symmetric positive definite 6x6 covariance: R R^T + c I with R's entries in [-1, 1].
covariances = st.tuples(arrays(np.float64, (6, 6), elements=floats(-1.0, 1.0)), floats(0.5, 2.0)).map(
    lambda drawn: drawn[0] @ drawn[0].T + drawn[1] * np.eye(6)
)


def make_filter(
    form: GainProjection,
    period: float = 0.02,
    q: float = Q_TARGET,
    sigma: float = SIGMA,
    restart_when_behind: bool = True,
) -> UPLKF:
    return UPLKF(period, q * np.eye(3), sigma**2 * np.eye(3), form, restart_when_behind=restart_when_behind)


def cross_bearing_residual(estimate_position: np.ndarray, pursuer_position: np.ndarray, bearing: np.ndarray) -> float:
    """|P_lambda (p^_T - p)|: distance of the estimate from the bearing line, m."""
    return float(np.linalg.norm(orthogonal_projection(bearing) @ (estimate_position - pursuer_position)))


# --------------------------------------------------------------------------- eq. (1)


@PROPERTY
@given(floats(1e-3, 2.0), vectors(5.0), vectors(5.0), vectors(5.0))
def test_transition_matrices_are_the_discrete_double_integrator(period: float, p: np.ndarray, v: np.ndarray, u: np.ndarray) -> None:
    a, b = transition_matrices(period)
    eye, zero = np.eye(3), np.zeros((3, 3))
    assert a.shape == (6, 6) and b.shape == (6, 3)
    np.testing.assert_array_equal(a[:3, :3], eye)
    np.testing.assert_allclose(a[:3, 3:], period * eye, rtol=0, atol=0)
    np.testing.assert_array_equal(a[3:, :3], zero)
    np.testing.assert_array_equal(a[3:, 3:], eye)
    np.testing.assert_allclose(b[:3], 0.5 * period**2 * eye, rtol=1e-15, atol=0)
    np.testing.assert_allclose(b[3:], period * eye, rtol=0, atol=0)
    # A x + B u is the exact motion under a constant acceleration u over one period.
    stepped = a @ np.concatenate([p, v]) + b @ u
    np.testing.assert_allclose(stepped[:3], p + v * period + 0.5 * u * period**2, atol=1e-11)
    np.testing.assert_allclose(stepped[3:], v + u * period, atol=1e-11)
    # Composition: A(dt1) A(dt2) = A(dt1 + dt2).
    np.testing.assert_allclose(a @ transition_matrices(0.3)[0], transition_matrices(period + 0.3)[0], atol=1e-12)


# --------------------------------------------------------------------------- eq. (5)-(6)


@PROPERTY
@given(vectors(40.0), vectors(40.0).filter(lambda d: np.linalg.norm(d) > 0.5), vectors(6.0), vectors(3.0),
       arrays(np.float64, 3, elements=floats(-3.0 * SIGMA, 3.0 * SIGMA)))
def test_noise_free_bearing_zeroes_the_pseudo_linear_measurement(pursuer, separation, relative_velocity, offset, nu) -> None:
    target = pursuer + separation
    bearing = (target - pursuer) / np.linalg.norm(target - pursuer)
    x = np.concatenate([target - pursuer, relative_velocity])
    h = pseudo_linear_measurement_matrix(bearing)
    assert h.shape == (3, 6)
    np.testing.assert_array_equal(h[:, 3:], np.zeros((3, 3)))  # velocity does not enter eq. (6)
    np.testing.assert_allclose(h @ x, np.zeros(3), atol=1e-12 * np.linalg.norm(x))
    # Only the direction of the bearing matters (lambda~ of eq. (4) is not unit).
    np.testing.assert_allclose(pseudo_linear_measurement_matrix(2.5 * bearing) @ x, np.zeros(3), atol=1e-11 * np.linalg.norm(x))
    # A wrong target position gives a nonzero residual: its component across the bearing.
    residual = h @ (x + np.concatenate([offset, np.zeros(3)]))
    # P_lambda of eq. (5) written out: I - lambda lambda^T for the unit bearing.
    np.testing.assert_allclose(residual, offset - (bearing @ offset) * bearing, atol=1e-10 * max(1.0, np.linalg.norm(x)))
    # With a noisy bearing, P_lambda~ (p_T - p) = -r P_lambda~ nu, eq. (6).
    noisy = bearing + nu
    r = np.linalg.norm(target - pursuer)
    across_noisy = np.eye(3) - np.outer(noisy, noisy) / (noisy @ noisy)
    np.testing.assert_allclose(pseudo_linear_measurement_matrix(noisy) @ x, -r * across_noisy @ nu, atol=1e-10 * max(1.0, r))


# --------------------------------------------------------------------------- initialisation


def test_initialize_on_bearing_places_the_target_on_the_first_bearing() -> None:
    estimator = make_filter(GainProjection.MEASURED, sigma=0.02)
    pursuer = np.array([1.0, -2.0, -30.0])
    direction = 1.3 * unit(np.array([0.6, 0.7, 0.2]))  # lambda~ need not be unit
    guess = InitialGuess(range=25.0, range_std=10.0, velocity=np.array([0.5, 0.0, -0.2]), velocity_std=3.0)
    estimator.initialize_on_bearing(BearingMeasurement(4.25, direction, pursuer), guess)

    estimate = estimator.estimate
    assert estimator.initialized
    assert estimate.time == 4.25
    # Remark 3: p_T(0) = p(0) + r(0) lambda~(0)/|lambda~(0)|, so lambda~^T dp(0) = r(0) > 0.
    np.testing.assert_allclose(estimate.position, pursuer + 25.0 * unit(direction), atol=1e-12)
    assert unit(direction) @ (estimate.position - pursuer) == pytest.approx(25.0)
    np.testing.assert_allclose(estimate.velocity, guess.velocity)

    covariance = estimate.covariance
    np.testing.assert_allclose(covariance, covariance.T, atol=0.0)
    np.testing.assert_allclose(covariance[:3, 3:], np.zeros((3, 3)))
    np.testing.assert_allclose(covariance[3:, 3:], 9.0 * np.eye(3))
    values, vectors = np.linalg.eigh(covariance[:3, :3])
    # Long along the bearing (range_std), thin across it (range times bearing noise).
    assert values[2] == pytest.approx(10.0**2)
    assert abs(vectors[:, 2] @ unit(direction)) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(values[:2], (25.0 * 0.02) ** 2, rtol=1e-10)
    assert values[2] / values[0] > 100.0


def test_estimate_before_initialisation_raises() -> None:
    estimator = make_filter(GainProjection.PREDICTED)
    assert not estimator.initialized
    with pytest.raises(RuntimeError):
        estimator.estimate
    with pytest.raises(RuntimeError):
        estimator.predict()


def test_nonpositive_period_is_rejected() -> None:
    with pytest.raises(ValueError):
        UPLKF(0.0, np.eye(3), np.eye(3))


# --------------------------------------------------------------------------- prediction


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 50), vectors(10.0), vectors(10.0), covariances)
def test_predict_is_constant_velocity_extrapolation(ticks: int, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray) -> None:
    period, q = 0.02, 0.7
    estimator = make_filter(GainProjection.MEASURED, period=period, q=q)
    estimator.initialize(10.0, position, velocity, covariance)
    for _ in range(ticks):
        estimator.predict()

    estimate = estimator.estimate
    assert estimate.time == pytest.approx(10.0 + ticks * period, abs=1e-12)
    np.testing.assert_allclose(estimate.position, position + ticks * period * velocity, atol=1e-10)
    np.testing.assert_allclose(estimate.velocity, velocity, atol=1e-12)
    # P_n = A^n P_0 A^nT + sum_j A^j B Q B^T A^jT, with the double integrator of eq. (1) written out.
    a = np.block([[np.eye(3), period * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    b = np.vstack([0.5 * period**2 * np.eye(3), period * np.eye(3)])
    expected = np.linalg.matrix_power(a, ticks) @ covariance @ np.linalg.matrix_power(a, ticks).T
    for j in range(ticks):
        a_j = np.linalg.matrix_power(a, j)
        expected += a_j @ b @ (q * np.eye(3)) @ b.T @ a_j.T
    np.testing.assert_allclose(estimate.covariance, expected, rtol=1e-10, atol=1e-12)
    # The mean agrees with TargetEstimate.extrapolated from the start.
    np.testing.assert_allclose(estimate.position, (position + velocity * (estimate.time - 10.0)), atol=1e-10)


# --------------------------------------------------------------------------- one correction


@pytest.mark.parametrize("form", FLYABLE)
def test_noise_free_bearing_with_correct_prior_leaves_the_estimate_unchanged(form: GainProjection) -> None:
    estimator = make_filter(form, sigma=0.0)
    target, velocity = np.array([12.0, 4.0, -8.0]), np.array([1.0, -0.5, 0.2])
    pursuer = np.array([0.0, 1.0, -10.0])
    estimator.initialize(0.0, target, velocity, np.diag([9.0, 9.0, 9.0, 1.0, 1.0, 1.0]))
    report = estimator.correct(BearingMeasurement(0.0, unit(target - pursuer), pursuer))
    assert report.innovation_angle == pytest.approx(0.0, abs=1e-7)
    assert not report.reinitialized
    np.testing.assert_allclose(estimator.estimate.position, target, atol=1e-9)
    np.testing.assert_allclose(estimator.estimate.velocity, velocity, atol=1e-9)
    assert cross_bearing_residual(estimator.estimate.position, pursuer, target - pursuer) < 1e-9


@PROPERTY
@given(vectors(10.0), unit_vectors(), vectors(2.0), covariances)
def test_noise_free_correction_puts_the_paper_filter_on_the_bearing_line(pursuer, direction, prior_error, covariance) -> None:
    """With Sigma = 0, H x+ = (I - H P H^T (H P H^T)^+) H x- = 0: the estimate lands on the line."""
    estimator = make_filter(GainProjection.MEASURED, sigma=0.0)
    target = pursuer + 10.0 * direction
    prior = target + prior_error
    estimator.initialize(0.0, prior, np.zeros(3), covariance)
    bearing = target - pursuer
    assume(cross_bearing_residual(prior, pursuer, bearing) > 0.05)
    report = estimator.correct(BearingMeasurement(0.0, bearing, pursuer))
    assert report.innovation_angle > 0.0 and not report.used_predicted_projection
    assert cross_bearing_residual(estimator.estimate.position, pursuer, bearing) < 1e-8


def test_noise_free_correction_with_predicted_projection_moves_towards_the_bearing_line() -> None:
    """The instrumental form projects across the *predicted* line of sight, so a single
    noise-free update lands on the bearing line only up to second order in the angle."""
    rng = np.random.default_rng(11)
    estimator = make_filter(GainProjection.PREDICTED, sigma=0.0)
    pursuer = np.zeros(3)
    target = np.array([10.0, 0.0, 0.0])
    prior = target + np.array([0.0, 0.4, -0.3])
    root = rng.normal(size=(6, 6))
    estimator.initialize(0.0, prior, np.zeros(3), root @ root.T + 0.5 * np.eye(6))
    before = cross_bearing_residual(prior, pursuer, target)
    report = estimator.correct(BearingMeasurement(0.0, target, pursuer))
    assert report.used_predicted_projection
    after = cross_bearing_residual(estimator.estimate.position, pursuer, target)
    assert after < 0.05 * before


@pytest.mark.parametrize("form", FLYABLE)
def test_correction_shrinks_covariance_across_the_bearing_only(form: GainProjection) -> None:
    estimator = make_filter(form)
    pursuer = np.zeros(3)
    direction = unit(np.array([1.0, 1.0, -0.5]))
    estimator.initialize_on_bearing(
        BearingMeasurement(0.0, direction, pursuer), InitialGuess(20.0, 10.0, np.zeros(3), 2.0)
    )
    estimator.predict()
    before = estimator.estimate.covariance
    estimator.correct(BearingMeasurement(estimator.time, direction, pursuer))
    after = estimator.estimate.covariance
    np.testing.assert_allclose(after, after.T, atol=0.0)
    assert np.linalg.eigvalsh(after).min() > -1e-12
    # P+ <= P- (information never lost) ...
    assert np.linalg.eigvalsh(before - after).min() > -1e-10
    # ... and a single bearing says nothing about the range: the along-bearing variance stays.
    along_before = direction @ before[:3, :3] @ direction
    along_after = direction @ after[:3, :3] @ direction
    assert along_after == pytest.approx(along_before, rel=1e-6)


def exact_rank2_pseudo_inverse(matrix: np.ndarray, null_direction: np.ndarray) -> np.ndarray:
    """S^+ = U (U^T S U)^-1 U^T with U an orthonormal basis of the plane perpendicular to g."""
    basis = np.linalg.svd(orthogonal_projection(null_direction))[0][:, :2]
    return basis @ np.linalg.inv(basis.T @ matrix @ basis) @ basis.T


@PROPERTY
@given(st.sampled_from(FLYABLE), st.sampled_from([10.0, 30.0, 100.0, 1000.0]), unit_vectors(),
       arrays(np.float64, 3, elements=floats(-0.15, 0.15)))
def test_correction_is_the_kalman_update_with_the_rank2_pseudo_inverse(form: GainProjection, range_std: float,
                                                                     first: np.ndarray, bearing_error: np.ndarray) -> None:
    """K = P H^T (H P H^T + V Sigma V^T)^+ with the Moore-Penrose inverse of the rank-2
    innovation covariance (kernel = the projection's direction). Regression: a generic
    np.linalg.pinv kept the rounding residue along that kernel as a ~1e15 eigenvalue, so
    with an uncertain prior range a single correction could grow the covariance (by ~6 m^2
    at range_std = 1000 m) and move the PREDICTED form's estimate off the bearing (by
    ~600 m at range_std = 1000 m, ~8 m at range_std = 10 m, against ~1.4 m exactly)."""
    sigma = 0.01
    estimator = make_filter(form, sigma=sigma)
    estimator.initialize_on_bearing(
        BearingMeasurement(0.0, first, np.zeros(3)), InitialGuess(20.0, range_std, np.zeros(3), 2.0)
    )
    estimator.predict()
    prior = estimator.estimate
    bearing = unit(first + bearing_error)
    estimator.correct(BearingMeasurement(prior.time, bearing, np.zeros(3)))
    posterior = estimator.estimate

    relative = prior.position
    gain_direction = unit(relative) if form is GainProjection.PREDICTED else bearing
    projection = orthogonal_projection(gain_direction)
    h = np.hstack([projection, np.zeros((3, 3))])
    r = np.linalg.norm(relative)
    innovation_covariance = h @ prior.covariance @ h.T + r**2 * sigma**2 * projection
    gain = prior.covariance @ h.T @ exact_rank2_pseudo_inverse(innovation_covariance, gain_direction)
    expected_state = np.concatenate([prior.position, prior.velocity]) - gain @ (orthogonal_projection(bearing) @ relative)
    expected_covariance = (np.eye(6) - gain @ h) @ prior.covariance
    scale = 1.0 + range_std
    state_mismatch = np.abs(np.concatenate([posterior.position, posterior.velocity]) - expected_state).max() / scale
    covariance_mismatch = np.abs(posterior.covariance - expected_covariance).max() / scale**2
    assert max(state_mismatch, covariance_mismatch) < 1e-9
    growth = -np.linalg.eigvalsh(prior.covariance - posterior.covariance).min() / scale**2
    assert growth < 1e-12  # P+ <= P-


# --------------------------------------------------------------------------- restart guard


def test_prior_behind_the_sensor_restarts_on_the_bearing() -> None:
    estimator = make_filter(GainProjection.MEASURED)
    pursuer = np.array([0.0, 0.0, -10.0])
    direction = unit(np.array([1.0, 0.2, 0.1]))
    velocity = np.array([0.3, -0.1, 0.0])
    behind = pursuer - 6.0 * unit(np.array([1.0, -0.3, 0.2]))  # angle > 90 deg from the bearing
    estimator.initialize(2.0, behind, velocity, np.eye(6))
    bearing = BearingMeasurement(2.0, direction, pursuer)

    report = estimator.correct(bearing)
    assert isinstance(report, CorrectionReport)
    assert report.reinitialized
    assert report.innovation_angle > np.pi / 2
    estimate = estimator.estimate
    # Restarted on the bearing (remark 3) at the predicted range, keeping the velocity.
    np.testing.assert_allclose(estimate.position, pursuer + 6.0 * direction, atol=1e-12)
    np.testing.assert_allclose(estimate.velocity, velocity)
    assert estimate.time == 2.0
    assert direction @ (estimate.position - pursuer) > 0.0
    values, vectors = np.linalg.eigh(estimate.covariance[:3, :3])
    assert abs(vectors[:, 2] @ direction) == pytest.approx(1.0, abs=1e-9)  # long along the bearing


def test_without_the_guard_a_prior_behind_the_sensor_is_pulled_onto_the_mirrored_half_line() -> None:
    estimator = make_filter(GainProjection.MEASURED, sigma=0.0, restart_when_behind=False)
    pursuer = np.zeros(3)
    direction = np.array([1.0, 0.0, 0.0])
    estimator.initialize(0.0, np.array([-6.0, 0.5, 0.0]), np.zeros(3), np.eye(6))
    report = estimator.correct(BearingMeasurement(0.0, direction, pursuer))
    assert not report.reinitialized
    position = estimator.estimate.position
    assert cross_bearing_residual(position, pursuer, direction) < 1e-8
    assert direction @ (position - pursuer) < 0.0  # the phantom the guard exists for


# --------------------------------------------------------------------------- bearing between ticks


def _transition(lead: float) -> np.ndarray:
    """F(tau) of the constant-velocity model, written out (eq. (1) over tau s): [[I, tau I], [0, I]]."""
    return np.block([[np.eye(3), lead * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])


@pytest.mark.parametrize("form", FLYABLE)
def test_bearing_between_ticks_is_the_correction_at_its_own_time(form: GainProjection) -> None:
    """A bearing tau s after the estimator's tick measures p_T(t + tau) = p_T + tau v_T: without process
    noise the correction at the tick, carried by F(tau), is the Kalman correction of the prior carried to
    the bearing's stamp (mean F x, covariance F P F^T), exactly: a linear Gaussian model's update does not
    depend on the time at which its state is written."""
    period, lead = 0.02, 0.013  # bearing 13 ms after the estimator tick
    position, velocity = np.array([20.0, 5.0, -12.0]), np.array([3.0, -2.0, 1.0])
    covariance = np.diag([4.0, 4.0, 4.0, 1.0, 1.0, 1.0]) + 0.3 * np.eye(6)[:, ::-1]
    pursuer = np.array([1.0, 0.0, -10.0])
    true_target = np.array([20.4, 5.6, -11.9]) + velocity * lead  # somewhat off the prior
    bearing = BearingMeasurement(1.0 + lead, unit(true_target - pursuer) + np.array([0.0, 0.002, -0.001]), pursuer)

    off_tick = make_filter(form, period=period, q=0.0)
    off_tick.initialize(1.0, position, velocity, covariance)
    transition = _transition(lead)
    on_tick = make_filter(form, period=period, q=0.0)
    on_tick.initialize(1.0 + lead, position + lead * velocity, velocity, transition @ covariance @ transition.T)

    report_off = off_tick.correct(bearing)
    report_on = on_tick.correct(bearing)
    assert report_off.innovation_angle == pytest.approx(report_on.innovation_angle, rel=1e-12, abs=1e-15)
    np.testing.assert_allclose(report_off.innovation_covariance, report_on.innovation_covariance, atol=1e-12)
    carried = off_tick.estimate
    state = transition @ np.concatenate([carried.position, carried.velocity])
    np.testing.assert_allclose(state[:3], on_tick.estimate.position, atol=1e-10)
    np.testing.assert_allclose(state[3:], on_tick.estimate.velocity, atol=1e-10)
    np.testing.assert_allclose(transition @ carried.covariance @ transition.T, on_tick.estimate.covariance, atol=1e-10)
    assert off_tick.estimate.time == 1.0  # the estimate stays on the estimator's own tick

    # Ignoring the stamp (comparing with the un-extrapolated mean) would give another innovation.
    stale = make_filter(form, period=period)
    stale.initialize(1.0 + lead, position, velocity, covariance)
    assert abs(stale.correct(bearing).innovation_angle - report_on.innovation_angle) > 1e-4


@PROPERTY
@given(st.sampled_from(FLYABLE), st.integers(1, 400), st.data(), vectors(30.0), vectors(5.0), covariances)
def test_a_late_bearing_is_the_correction_it_would_have_been_on_time(form, ticks, data, offset, velocity, covariance):
    """A bearing that arrives `ticks - taken` estimator periods late (a stalled link, a neighbour's shared
    bearing): without process noise, correcting the current prior with it gives exactly the estimate that
    correcting on time and predicting on would have given (the u-PLKF's H = P_lambda [I, tau I] for a bearing
    tau s before the filter's time). With the former H = [P_lambda, 0] a bearing 7.5 s late made the filter
    move its current position as if it were the position 7.5 s before, and a 0.5 s latency diverged a flight."""
    taken = data.draw(st.integers(0, ticks - 1))
    period = 0.02
    pursuer = np.array([0.0, 0.0, -10.0])
    start = pursuer + np.array([15.0, -5.0, 3.0]) + 0.2 * offset
    target_then = start + taken * period * velocity + np.array([0.7, -0.4, 0.3])  # somewhat off the prior
    assume(np.linalg.norm(target_then - pursuer) > 3.0)
    bearing = BearingMeasurement(1.0 + taken * period, unit(target_then - pursuer), pursuer)

    late = make_filter(form, period=period, q=0.0, restart_when_behind=False)
    late.initialize(1.0, start, velocity, covariance)
    on_time = make_filter(form, period=period, q=0.0, restart_when_behind=False)
    on_time.initialize(1.0, start, velocity, covariance)
    for _ in range(ticks):
        late.predict()
    for _ in range(taken):
        on_time.predict()
    on_time.correct(bearing)
    for _ in range(ticks - taken):
        on_time.predict()
    late.correct(bearing)
    scale = 1.0 + float(np.abs(covariance).max()) * (1.0 + (ticks * period) ** 2)
    np.testing.assert_allclose(late.estimate.position, on_time.estimate.position, atol=1e-8 * scale)
    np.testing.assert_allclose(late.estimate.velocity, on_time.estimate.velocity, atol=1e-8 * scale)
    np.testing.assert_allclose(late.estimate.covariance, on_time.estimate.covariance, atol=1e-8 * scale)


def test_a_late_bearing_is_trusted_less_with_process_noise() -> None:
    """With process noise the target may have manoeuvred since a late bearing was taken: its innovation
    covariance gains the position variance q |tau|^3 / 3 of a white-noise acceleration of density
    q = Q Delta t (Q = 0.1 (m/s^2)^2, Delta t = 0.02 s) over |tau| = 5 s, projected across the bearing."""
    period, q = 0.02, Q_TARGET
    pursuer = np.zeros(3)
    direction = np.array([1.0, 0.0, 0.0])
    covariance = np.eye(6)
    with_noise = make_filter(GainProjection.PREDICTED, period=period, q=q)
    without = make_filter(GainProjection.PREDICTED, period=period, q=0.0)
    for estimator in (with_noise, without):
        estimator.initialize(10.0, np.array([20.0, 0.0, 0.0]), np.zeros(3), covariance)  # on the bearing
    bearing = BearingMeasurement(5.0, direction, pursuer)
    difference = with_noise.correct(bearing).innovation_covariance - without.correct(bearing).innovation_covariance
    expected = q * period * 5.0**3 / 3.0 * orthogonal_projection(direction)
    np.testing.assert_allclose(difference, expected, atol=1e-12)


def test_exact_bearing_between_ticks_for_a_correct_prior_needs_no_correction() -> None:
    period, lead = 0.02, 0.011
    target, velocity = np.array([15.0, -3.0, -9.0]), np.array([4.0, 2.0, -1.0])
    pursuer = np.array([0.0, 0.0, -10.0])
    estimator = make_filter(GainProjection.MEASURED, period=period, sigma=0.0)
    estimator.initialize(0.0, target, velocity, np.eye(6))
    bearing = BearingMeasurement(lead, target + lead * velocity - pursuer, pursuer)
    report = estimator.correct(bearing)
    assert report.innovation_angle == pytest.approx(0.0, abs=1e-7)
    np.testing.assert_allclose(estimator.estimate.position, target, atol=1e-9)
    np.testing.assert_allclose(estimator.estimate.velocity, velocity, atol=1e-9)


# --------------------------------------------------------------------------- convergence


@dataclass
class Run:
    position_error: np.ndarray  # |p^_T - p_T| after each correction, m
    velocity_error: np.ndarray  # |v^_T - v_T|, m/s
    range_error: np.ndarray  # |p^_T - p| - |p_T - p|, m
    min_eigenvalue: float  # smallest covariance eigenvalue seen
    max_asymmetry: float


def circling_run(
    form: GainProjection,
    *,
    seed: int,
    estimator_period: float = 0.02,
    bearing_every: int = 1,
    duration: float = 20.0,
    initial_range: float = 20.0,
    target_velocity: np.ndarray = np.array([1.0, 0.5, 0.0]),
    vertical_weave: float = 2.0,
    restart_when_behind: bool = False,
) -> Run:
    """Open loop: target at constant velocity, pursuer on a circle of radius 8 m around it
    (angular rate 0.5 rad/s, optionally weaving vertically), additive bearing noise of eq. (4)."""
    rng = np.random.default_rng(seed)
    estimator = make_filter(form, period=estimator_period, restart_when_behind=restart_when_behind)
    target_start = np.array([5.0, 0.0, -10.0])
    position_error, velocity_error, range_error = [], [], []
    min_eigenvalue, max_asymmetry = np.inf, 0.0
    for k in range(int(round(duration / estimator_period)) + 1):
        t = k * estimator_period
        target = target_start + target_velocity * t
        pursuer = target + np.array([8.0 * np.cos(0.5 * t), 8.0 * np.sin(0.5 * t), vertical_weave * np.sin(t)])
        if k > 0:
            estimator.predict()
        if k % bearing_every:
            continue
        true_range = float(np.linalg.norm(target - pursuer))
        bearing = BearingMeasurement(t, (target - pursuer) / true_range + rng.normal(0.0, SIGMA, 3), pursuer)
        if k == 0:
            estimator.initialize_on_bearing(bearing, InitialGuess(initial_range, 10.0, np.zeros(3), 2.0))
            continue
        estimator.correct(bearing)
        estimate = estimator.estimate
        assert estimate.time == pytest.approx(t, abs=1e-9)
        position_error.append(np.linalg.norm(estimate.position - target))
        velocity_error.append(np.linalg.norm(estimate.velocity - target_velocity))
        range_error.append(np.linalg.norm(estimate.position - pursuer) - true_range)
        min_eigenvalue = min(min_eigenvalue, float(np.linalg.eigvalsh(estimate.covariance).min()))
        max_asymmetry = max(max_asymmetry, float(np.abs(estimate.covariance - estimate.covariance.T).max()))
    return Run(np.array(position_error), np.array(velocity_error), np.array(range_error), min_eigenvalue, max_asymmetry)


@pytest.mark.parametrize(
    ("form", "bearing_every", "position_tolerance", "velocity_tolerance"),
    [
        # Section IX: estimator at 50 Hz, bearings at 5 Hz; the paper's filter exactly.
        (GainProjection.MEASURED, 10, 0.5, 0.25),
        (GainProjection.PREDICTED, 10, 0.5, 0.25),
        # Bearings at the estimator rate (50 Hz): only the instrumental form (see the bias test).
        (GainProjection.PREDICTED, 1, 0.3, 0.15),
    ],
)
def test_filter_converges_on_an_observable_trajectory(
    form: GainProjection, bearing_every: int, position_tolerance: float, velocity_tolerance: float
) -> None:
    run = circling_run(form, seed=3, bearing_every=bearing_every, initial_range=20.0)  # true range 8 m
    assert run.position_error[0] > 2.0  # starts wrong
    # Final errors, and the whole last 5 s (robust to one unlucky sample).
    last = run.position_error[-len(run.position_error) // 4 :]
    assert run.position_error[-1] < position_tolerance
    assert run.velocity_error[-1] < velocity_tolerance
    assert np.sqrt(np.mean(last**2)) < position_tolerance
    assert np.abs(run.range_error[-len(run.range_error) // 4 :]).mean() < position_tolerance
    # Covariance stays symmetric and positive semi-definite throughout.
    assert run.max_asymmetry < 1e-12
    assert run.min_eigenvalue > 0.0


def test_measured_form_converges_for_any_initial_range_guess() -> None:
    for initial_range in (4.0, 30.0):
        run = circling_run(GainProjection.MEASURED, seed=5, bearing_every=10, initial_range=initial_range)
        assert run.position_error[-1] < 0.5
        assert run.velocity_error[-1] < 0.25


# --------------------------------------------------------------------------- range bias


BIAS_SEEDS = range(4)


@pytest.fixture(scope="module")
def bias_runs() -> dict[GainProjection, np.ndarray]:
    """Final range error over the last 2 s, per seed, bearings at 50 Hz for 20 s, true range 8 m."""
    results = {}
    for form in FLYABLE:
        errors = []
        for seed in BIAS_SEEDS:
            run = circling_run(form, seed=100 + seed, bearing_every=1, initial_range=12.0, vertical_weave=0.0)
            errors.append(run.range_error[-100:].mean())
        results[form] = np.array(errors)
    return results


def test_paper_gain_form_underestimates_the_range_at_high_bearing_rate(bias_runs: dict[GainProjection, np.ndarray]) -> None:
    """The paper's H_k uses the noisy bearing, so the gain is correlated with the noise it
    corrects. At 50 Hz the range estimate collapses towards the pursuer, open loop:
    measured about -7.3 m of the true 8 m for every seed (std ~0.1 m)."""
    measured = bias_runs[GainProjection.MEASURED]
    assert np.all(measured < -4.0), measured  # every seed, same direction (short)
    assert measured.mean() < -6.0, measured
    assert measured.std() < 1.0, measured


def test_predicted_gain_form_removes_the_range_bias(bias_runs: dict[GainProjection, np.ndarray]) -> None:
    """The instrumental (predicted-LOS) gain is uncorrelated with the current noise: measured
    mean range error about 0.01 m on the same runs."""
    predicted = bias_runs[GainProjection.PREDICTED]
    measured = bias_runs[GainProjection.MEASURED]
    assert np.all(np.abs(predicted) < 0.3), predicted
    assert abs(predicted.mean()) < 0.15, predicted
    assert abs(predicted.mean()) < 0.05 * abs(measured.mean())


def test_optimal_uplkf_is_the_paper_filter_fed_the_true_bearing() -> None:
    """Section VIII-B's "optimal u-PLKF": H from the noise-free line of sight. It must equal the
    paper's form given the true direction, whatever noise the measured direction carries, and it
    refuses a bearing without the truth (it cannot fly)."""
    rng = np.random.default_rng(3)
    optimal, reference = make_filter(GainProjection.NOISE_FREE), make_filter(GainProjection.MEASURED)
    target, velocity, pursuer = np.array([30.0, -10.0, -5.0]), np.array([2.0, 1.0, 0.0]), np.zeros(3)
    for estimator in (optimal, reference):
        estimator.initialize(0.0, target + np.array([8.0, 3.0, -2.0]), np.zeros(3), np.diag([100.0] * 3 + [4.0] * 3))
    for tick in range(1, 200):
        for estimator in (optimal, reference):
            estimator.predict()
        time = optimal.time
        pursuer = np.array([2.0 * time, 5.0 * np.sin(time), 3.0 * np.cos(time)])
        truth = unit(target + velocity * time - pursuer)
        noisy = truth + rng.normal(0.0, 0.05, 3)
        if tick % 10 == 0:
            optimal.correct(BearingMeasurement(time, noisy, pursuer, true_direction=truth))
            reference.correct(BearingMeasurement(time, truth, pursuer))
    np.testing.assert_allclose(optimal.estimate.position, reference.estimate.position, atol=1e-9)
    np.testing.assert_allclose(optimal.estimate.covariance, reference.estimate.covariance, atol=1e-9)
    assert np.linalg.norm(optimal.estimate.position - (target + velocity * optimal.time)) < 1.0
    with pytest.raises(ValueError, match="true_direction"):
        optimal.correct(BearingMeasurement(optimal.time, truth, pursuer))
