"""Baseline estimators (companion/baseline_estimators.py): the classic az/el EKF of section
VIII-B, the modified spherical coordinates EKF of section II-A and the range/az/el EKF of
seed 003. Jacobians against central differences, MSC round trips, the angle noise
mapping, open-loop convergence with a weaving observer, initialisation, bearings between
ticks, and numerical guards (poles, unobservable geometry)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, vectors

from companion.core.baseline_estimators import (
    MAX_ELEVATION,
    MSCEKF,
    SEED003_PROCESS_NOISE,
    AzElEKF,
    RangeAzElEKF,
    angle_noise_covariance,
    azimuth_elevation,
    azimuth_elevation_jacobian,
    cartesian_from_msc,
    cartesian_from_msc_jacobian,
    flight_path_step,
    flight_path_step_jacobian,
    flight_path_velocity,
    msc_from_cartesian,
    msc_from_cartesian_jacobian,
    range_azimuth_elevation,
    range_azimuth_elevation_jacobian,
    wrap_angle,
)
from companion.core.estimators import CorrectionReport, InitialGuess
from companion.core.messages import BearingMeasurement, TargetEstimate

SIGMA = 0.01  # bearing noise of eq. (4), Sigma = sigma^2 I
PERIOD = 0.02  # 50 Hz ticks
BEARING_EVERY = 10  # 5 Hz bearings
Q_TARGET = 0.04 * np.eye(3)
P_T0 = np.array([50.0, -25.0, -20.0])
V_T = np.array([3.0, 4.0, 0.0])
KINDS = ("azel", "msc", "rae")


def make(kind: str, period: float = PERIOD):
    if kind == "azel":
        return AzElEKF(period, Q_TARGET, SIGMA**2 * np.eye(3))
    if kind == "msc":
        return MSCEKF(period, Q_TARGET, SIGMA**2 * np.eye(3))
    return RangeAzElEKF(period, SIGMA**2 * np.eye(3), range_noise_std=1.0)


def central_difference(function, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    x = np.asarray(x, float)
    columns = []
    for i in range(x.size):
        delta = np.zeros_like(x)
        delta[i] = step
        columns.append((np.asarray(function(x + delta)) - np.asarray(function(x - delta))) / (2.0 * step))
    return np.column_stack(columns)


PROPERTY = settings(max_examples=80, deadline=None)

# A relative position 5-100 m away, elevation within +-60 deg, azimuth away from +-pi.
relative_positions = st.tuples(floats(5.0, 100.0), floats(-2.8, 2.8), floats(-1.0, 1.0)).map(
    lambda drawn: drawn[0] * np.array([math.cos(drawn[2]) * math.cos(drawn[1]), math.cos(drawn[2]) * math.sin(drawn[1]),
                                       -math.sin(drawn[2])])
)


def assert_covariance_ok(covariance: np.ndarray) -> None:
    assert covariance.shape == (6, 6)
    assert np.all(np.isfinite(covariance))
    np.testing.assert_allclose(covariance, covariance.T, rtol=0, atol=1e-9 * max(1.0, float(np.abs(covariance).max())))
    assert np.linalg.eigvalsh(covariance).min() > -1e-9 * max(1.0, float(np.abs(covariance).max()))


# --------------------------------------------------------------------------- helpers and Jacobians


@PROPERTY
@given(floats(-50.0, 50.0))
def test_wrap_angle_range(angle: float) -> None:
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3.0 * math.pi / 2.0) == pytest.approx(-math.pi / 2.0)
    assert wrap_angle(-7.0) == pytest.approx(-7.0 + 2.0 * math.pi)
    wrapped = wrap_angle(angle)
    assert -math.pi < wrapped <= math.pi
    assert math.isclose(math.cos(wrapped), math.cos(angle), abs_tol=1e-12)
    assert math.isclose(math.sin(wrapped), math.sin(angle), abs_tol=1e-12)


def test_angle_conventions_in_ned() -> None:
    # north: azimuth 0; east: +90 deg; up (negative z): elevation +90 deg direction.
    np.testing.assert_allclose(azimuth_elevation(np.array([1.0, 0.0, 0.0])), [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(azimuth_elevation(np.array([0.0, 2.0, 0.0])), [math.pi / 2, 0.0], atol=1e-15)
    np.testing.assert_allclose(azimuth_elevation(np.array([1.0, 0.0, -1.0])), [0.0, math.pi / 4], atol=1e-15)
    np.testing.assert_allclose(range_azimuth_elevation(np.array([3.0, 0.0, 4.0])), [5.0, 0.0, -math.atan2(4, 3)], atol=1e-15)


@PROPERTY
@given(relative_positions)
def test_angle_jacobians_match_central_differences(d: np.ndarray) -> None:
    # The angles themselves, NED: azimuth from north towards east, elevation up (-z).
    np.testing.assert_allclose(azimuth_elevation(d), [math.atan2(d[1], d[0]), math.atan2(-d[2], math.hypot(d[0], d[1]))], atol=1e-12)
    np.testing.assert_allclose(range_azimuth_elevation(d)[0], np.linalg.norm(d), rtol=1e-12)
    step = 1e-6 * np.linalg.norm(d)  # relative step: round-off ~1e-16 |f| / step stays small at 100 m
    np.testing.assert_allclose(azimuth_elevation_jacobian(d), central_difference(azimuth_elevation, d, step), rtol=1e-6, atol=1e-9)
    numeric = central_difference(range_azimuth_elevation, d, step)
    analytic = range_azimuth_elevation_jacobian(d)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-9)
    # The seed-003 erratum: the azimuth row is -y/rho^2, x/rho^2 (not divided by rho only).
    rho = math.hypot(d[0], d[1])
    np.testing.assert_allclose(analytic[1, :2], [-d[1] / rho**2, d[0] / rho**2], rtol=1e-12)


@PROPERTY
@given(vectors(60.0), floats(0.5, 15.0), floats(-1.2, 1.2), floats(-3.0, 3.0))
def test_flight_path_step_and_jacobian(position: np.ndarray, speed: float, gamma: float, chi: float) -> None:
    state = np.concatenate([position, [speed, gamma, chi]])
    dt = 0.05
    # Central differences with a 1e-6 step lose ~1e-16 |x| / 1e-6 to round-off on the position rows.
    np.testing.assert_allclose(flight_path_step_jacobian(state, dt), central_difference(lambda x: flight_path_step(x, dt), state),
                               rtol=1e-6, atol=1e-9 * max(1.0, float(np.abs(state).max())))
    # NED: a climbing target (gamma > 0) moves to negative z.
    climbing = np.array([0.0, 0.0, 0.0, 10.0, 0.3, 0.0])
    assert flight_path_step(climbing, 1.0)[2] == pytest.approx(-10.0 * math.sin(0.3))
    # Speed and flight-path angles give the Cartesian velocity of eq. (10).
    velocity = flight_path_velocity(state[3], state[4], state[5])
    assert np.linalg.norm(velocity) == pytest.approx(state[3])
    # v (cos gamma cos chi, cos gamma sin chi, -sin gamma): NED, gamma up, chi from north.
    np.testing.assert_allclose(velocity, speed * np.array([math.cos(gamma) * math.cos(chi), math.cos(gamma) * math.sin(chi), -math.sin(gamma)]),
                               atol=1e-12 * speed)
    np.testing.assert_allclose(flight_path_step(state, dt)[:3], state[:3] + dt * velocity, atol=1e-12)


@PROPERTY
@given(relative_positions, vectors(15.0))
def test_msc_round_trip_and_jacobians(relative_position: np.ndarray, relative_velocity: np.ndarray) -> None:
    relative_state = np.concatenate([relative_position, relative_velocity])
    y = msc_from_cartesian(relative_state)
    np.testing.assert_allclose(cartesian_from_msc(y), relative_state, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(msc_from_cartesian(cartesian_from_msc(y)), y, rtol=1e-10, atol=1e-12)
    assert y[2] == pytest.approx(1.0 / np.linalg.norm(relative_state[:3]))
    assert y[5] == pytest.approx(relative_state[:3] @ relative_state[3:] / np.linalg.norm(relative_state[:3]) ** 2)
    j_m = msc_from_cartesian_jacobian(relative_state)
    j_c = cartesian_from_msc_jacobian(y)
    np.testing.assert_allclose(j_m, central_difference(msc_from_cartesian, relative_state, 1e-6), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(j_c, central_difference(cartesian_from_msc, y, 1e-7), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(j_m @ j_c, np.eye(6), atol=1e-8)  # inverse maps, inverse Jacobians


def test_msc_rates_are_the_angle_rates() -> None:
    """beta_dot, eps_dot of msc_from_cartesian are the time derivatives of the angles."""
    d, v = np.array([20.0, -7.0, -9.0]), np.array([1.0, 3.0, -2.0])
    y = msc_from_cartesian(np.concatenate([d, v]))
    dt = 1e-6
    rates = (azimuth_elevation(d + dt * v) - azimuth_elevation(d - dt * v)) / (2.0 * dt)
    np.testing.assert_allclose(y[3:5], rates, rtol=1e-6)


def test_angle_noise_covariance_matches_monte_carlo() -> None:
    """R = sigma^2 diag(1/cos^2 eps, 1) is the first-order covariance of the angles of lambda + nu."""
    rng = np.random.default_rng(3)
    direction = np.array([math.cos(1.0) * math.cos(0.4), math.cos(1.0) * math.sin(0.4), -math.sin(1.0)])  # eps = 1 rad
    samples = direction + rng.normal(0.0, SIGMA, (20000, 3))
    angles = np.array([azimuth_elevation(sample) for sample in samples])
    empirical = np.cov(angles.T)
    predicted = angle_noise_covariance(SIGMA**2, 30.0 * direction, 0.0)
    np.testing.assert_allclose(np.diag(empirical), np.diag(predicted), rtol=0.05)
    assert abs(empirical[0, 1]) < 0.05 * math.sqrt(empirical[0, 0] * empirical[1, 1])
    # Own-position noise adds sigma_p^2 / rho^2 (azimuth) and sigma_p^2 / r^2 (elevation).
    with_position = angle_noise_covariance(SIGMA**2, 30.0 * direction, 0.1)
    np.testing.assert_allclose(np.diag(with_position - predicted), [0.01 / (30.0 * math.cos(1.0)) ** 2, 0.01 / 900.0], rtol=1e-9)


# --------------------------------------------------------------------------- open-loop scenario


def pursuer_position(t: float, stationary: bool = False) -> np.ndarray:
    """A helix carried along with the target (observable), or a fixed point."""
    if stationary:
        return np.zeros(3)
    return V_T * t + np.array([10.0 * math.cos(t), 10.0 * math.sin(t), 5.0 * math.sin(0.5 * t)])


def make_bearing(t: float, rng: np.random.Generator, with_range: bool, stationary: bool = False) -> BearingMeasurement:
    pursuer = pursuer_position(t, stationary)
    relative = P_T0 + V_T * t - pursuer
    line_of_sight = relative / np.linalg.norm(relative)
    measured_range = float(np.linalg.norm(relative) + rng.normal(0.0, 1.0)) if with_range else None
    return BearingMeasurement(t, line_of_sight + rng.normal(0.0, SIGMA, 3), pursuer, range=measured_range, true_direction=line_of_sight)


def run_open_loop(estimator, seed: int, with_range: bool, stationary: bool = False, duration: float = 60.0):
    rng = np.random.default_rng(seed)
    first = make_bearing(0.0, rng, with_range, stationary)
    true_range = float(np.linalg.norm(P_T0 - first.pursuer_position))
    estimator.initialize_on_bearing(first, InitialGuess(0.7 * true_range, 0.5 * true_range, np.zeros(3), 5.0))
    initial_error = float(np.linalg.norm(estimator.estimate.position - P_T0))
    errors, velocity_errors = [], []
    for tick in range(1, int(round(duration / PERIOD)) + 1):
        before = estimator.time
        estimator.predict()
        assert estimator.time == pytest.approx(before + PERIOD, abs=1e-12)
        assert estimator.time == pytest.approx(tick * PERIOD, abs=1e-9)
        if tick % BEARING_EVERY == 0:
            report = estimator.correct(make_bearing(estimator.time, rng, with_range, stationary))
            assert isinstance(report, CorrectionReport) and not report.used_predicted_projection
        estimate = estimator.estimate
        errors.append(float(np.linalg.norm(estimate.position - (P_T0 + V_T * estimate.time))))
        velocity_errors.append(float(np.linalg.norm(estimate.velocity - V_T)))
    return initial_error, np.array(errors), np.array(velocity_errors)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_converges_with_a_weaving_observer(kind: str, seed: int) -> None:
    estimator = make(kind)
    with_range = kind == "rae"
    initial_error, errors, velocity_errors = run_open_loop(estimator, seed, with_range)
    if with_range:
        assert initial_error < 5.0  # started on the measured range
        assert velocity_errors[0] > 4.0  # but with the velocity guess 0 (true speed 5 m/s)
    else:
        assert initial_error > 12.0  # the 30 % range error, ~15 m
    assert np.all(np.isfinite(errors))
    assert errors[-1] < 2.0
    assert errors[-500:].mean() < 2.0  # the last 10 s, not a lucky sample
    assert velocity_errors[-500:].mean() < 1.0
    estimate = estimator.estimate
    assert isinstance(estimate, TargetEstimate)
    assert_covariance_ok(estimate.covariance)
    # The reported uncertainty is consistent in size with the error it describes.
    position_std = math.sqrt(np.trace(estimate.covariance[:3, :3]))
    assert 0.05 < position_std < 10.0


@pytest.mark.parametrize("kind", ("azel", "msc"))
def test_stationary_observer_stays_finite(kind: str) -> None:
    """A fixed, non-manoeuvring observer leaves the range unobservable: no NaN, finite covariance."""
    estimator = make(kind)
    _, errors, velocity_errors = run_open_loop(estimator, 5, with_range=False, stationary=True)
    assert np.all(np.isfinite(errors)) and np.all(np.isfinite(velocity_errors))
    estimate = estimator.estimate
    assert np.all(np.isfinite(estimate.position)) and np.all(np.isfinite(estimate.velocity))
    assert_covariance_ok(estimate.covariance)


def test_uninitialised_estimators_refuse_to_run() -> None:
    for kind in KINDS:
        estimator = make(kind)
        assert not estimator.initialized
        with pytest.raises(RuntimeError):
            estimator.predict()
        with pytest.raises(RuntimeError):
            _ = estimator.estimate
    with pytest.raises(ValueError):
        AzElEKF(0.0, Q_TARGET, SIGMA**2 * np.eye(3))


# --------------------------------------------------------------------------- initialisation


@pytest.mark.parametrize("kind", KINDS)
def test_remark_3_start_on_the_bearing(kind: str) -> None:
    estimator = make(kind)
    pursuer = np.array([1.0, 2.0, -3.0])
    direction = np.array([2.0, -1.0, -0.5])  # not unit: normalised by the estimator
    estimator.initialize_on_bearing(BearingMeasurement(4.0, direction, pursuer), InitialGuess(40.0, 12.0, np.zeros(3), 5.0))
    assert estimator.initialized and estimator.time == 4.0
    unit_direction = direction / np.linalg.norm(direction)
    estimate = estimator.estimate
    np.testing.assert_allclose(estimate.position, pursuer + 40.0 * unit_direction, atol=1e-9)
    assert_covariance_ok(estimate.covariance)
    # Long along the bearing (range_std), thin across it (r_hat * sigma).
    along = unit_direction @ estimate.covariance[:3, :3] @ unit_direction
    assert along == pytest.approx(12.0**2, rel=1e-6)
    across_direction = np.array([1.0, 2.0, 0.0]) / math.sqrt(5.0)  # perpendicular to `direction`
    assert across_direction @ estimate.covariance[:3, :3] @ across_direction == pytest.approx((40.0 * SIGMA) ** 2, rel=1e-6)


@pytest.mark.parametrize("kind", KINDS)
def test_explicit_start_position(kind: str) -> None:
    estimator = make(kind)
    start = np.array([40.0, -20.0, -15.0])
    velocity = np.array([1.0, -2.0, 0.5])
    guess = InitialGuess(47.0, 10.0, velocity, 2.0, position=start)
    estimator.initialize_on_bearing(BearingMeasurement(1.5, np.array([0.8, -0.4, -0.3]), np.zeros(3), range=60.0), guess)
    estimate = estimator.estimate
    np.testing.assert_allclose(estimate.position, start, atol=1e-9)
    np.testing.assert_allclose(estimate.velocity, velocity, atol=1e-9)
    assert estimate.time == 1.5
    np.testing.assert_allclose(np.diag(estimate.covariance[:3, :3]), [100.0] * 3, rtol=1e-6)
    assert_covariance_ok(estimate.covariance)


def test_range_ekf_starts_on_the_measured_range_and_needs_range() -> None:
    estimator = make("rae")
    direction = np.array([0.0, 0.6, -0.8])
    estimator.initialize_on_bearing(BearingMeasurement(0.0, direction, np.ones(3), range=25.0), InitialGuess(60.0, 30.0, np.zeros(3), 5.0))
    np.testing.assert_allclose(estimator.estimate.position, np.ones(3) + 25.0 * direction, atol=1e-12)
    assert direction @ estimator.estimate.covariance[:3, :3] @ direction == pytest.approx(1.0, rel=1e-6)  # range_noise_std^2
    # No velocity guess: 0.1 m/s along +x with angles unknown (std pi).
    state = estimator.flight_path_state
    np.testing.assert_allclose(state[3:], [0.1, 0.0, 0.0])
    assert estimator._covariance[4, 4] == pytest.approx(math.pi**2)
    # Without a range reading: the guessed range.
    estimator.initialize_on_bearing(BearingMeasurement(0.0, direction, np.ones(3)), InitialGuess(60.0, 30.0, np.array([0.0, 5.0, 0.0]), 2.0))
    np.testing.assert_allclose(estimator.estimate.position, np.ones(3) + 60.0 * direction, atol=1e-12)
    np.testing.assert_allclose(estimator.flight_path_state[3:], [5.0, 0.0, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(estimator.estimate.velocity, [0.0, 5.0, 0.0], atol=1e-12)
    assert estimator._covariance[5, 5] == pytest.approx((2.0 / 5.0) ** 2)
    estimator.predict()
    with pytest.raises(ValueError, match="RangeAzElEKF needs a range measurement"):
        estimator.correct(BearingMeasurement(estimator.time, direction, np.ones(3)))


def test_range_ekf_default_process_noise_is_seed_003_case_1() -> None:
    estimator = make("rae")
    np.testing.assert_allclose(estimator.process_noise, SEED003_PROCESS_NOISE)
    assert SEED003_PROCESS_NOISE[0, 0] == 2.0
    assert SEED003_PROCESS_NOISE[1, 1] == pytest.approx(2.0 * math.radians(0.57) ** 2)
    with pytest.raises(ValueError):
        RangeAzElEKF(PERIOD, SIGMA**2 * np.eye(3), range_noise_std=0.0)


def test_range_ekf_keeps_a_nonnegative_speed() -> None:
    """A correction that drives v below zero is folded to (-v, -gamma, chi + pi): same velocity."""
    state = np.array([0.0, 0.0, 0.0, -2.0, 0.3, 0.5])
    covariance = np.diag([1.0, 1.0, 1.0, 0.5, 0.1, 0.2])
    covariance[3, 4] = covariance[4, 3] = 0.05
    folded, folded_covariance = RangeAzElEKF._fold(state, covariance)
    assert folded[3] == 2.0
    np.testing.assert_allclose(flight_path_velocity(*folded[3:]), flight_path_velocity(*state[3:]), atol=1e-12)
    assert folded_covariance[3, 4] == pytest.approx(0.05)  # both signs flipped
    assert folded_covariance[4, 5] == 0.0 and folded_covariance[3, 3] == 0.5


def test_msc_initialize_without_reference_waits_for_a_bearing() -> None:
    estimator = make("msc")
    covariance = np.diag([25.0] * 3 + [4.0] * 3)
    estimator.initialize(2.0, P_T0, V_T, covariance)
    assert estimator.reference is None
    np.testing.assert_allclose(estimator.estimate.position, P_T0)
    estimator.predict()
    np.testing.assert_allclose(estimator.estimate.position, P_T0 + PERIOD * V_T, atol=1e-12)
    truth = P_T0 + PERIOD * V_T
    estimator.correct(BearingMeasurement(estimator.time, truth - np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 3.0])))
    np.testing.assert_allclose(estimator.reference, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(estimator.estimate.position, truth, atol=1e-6)  # noise-free bearing through the prior
    assert_covariance_ok(estimator.estimate.covariance)


def test_msc_re_reference_keeps_the_cartesian_estimate() -> None:
    """Moving p_ref is an exact change of coordinates: the Cartesian mean and covariance stay."""
    estimator = make("msc")
    covariance = np.diag([25.0, 16.0, 9.0, 4.0, 3.0, 2.0])
    covariance[0, 3] = covariance[3, 0] = 1.0
    estimator.initialize(0.0, P_T0, V_T, covariance, reference=np.zeros(3))
    before = estimator.estimate
    estimator._set_cartesian(*estimator._cartesian(), np.array([10.0, 5.0, -3.0]))
    after = estimator.estimate
    np.testing.assert_allclose(after.position, before.position, atol=1e-9)
    np.testing.assert_allclose(after.velocity, before.velocity, atol=1e-9)
    np.testing.assert_allclose(after.covariance, covariance, rtol=1e-8, atol=1e-8)


# --------------------------------------------------------------------------- bearings between ticks, guards


@pytest.mark.parametrize("kind", KINDS)
def test_bearing_between_ticks_uses_the_extrapolated_prior(kind: str) -> None:
    """With a perfect prior and a noise-free bearing taken half a tick later, nothing moves.

    Ignoring the lead would see the target 0.25 m off (5 m/s for 0.05 s at 20 m: 12 mrad).
    """
    period = 0.1
    estimator = make(kind, period)
    pursuer = np.array([30.0, -30.0, -15.0])
    covariance = np.diag([4.0] * 3 + [1.0] * 3)
    if kind == "msc":
        estimator.initialize(0.0, P_T0, V_T, covariance, reference=pursuer)
    else:
        estimator.initialize(0.0, P_T0, V_T, covariance)
    estimator.predict()
    prior = estimator.estimate
    t = estimator.time + 0.5 * period
    truth = P_T0 + V_T * t
    report = estimator.correct(BearingMeasurement(t, truth - pursuer, pursuer, range=float(np.linalg.norm(truth - pursuer))))
    assert report.innovation_angle < 1e-9
    assert not report.reinitialized
    after = estimator.estimate
    assert after.time == prior.time  # the estimate stays on the tick grid
    np.testing.assert_allclose(after.position, prior.position, atol=1e-6)
    np.testing.assert_allclose(after.velocity, prior.velocity, atol=1e-6)
    assert np.trace(after.covariance[:3, :3]) < np.trace(prior.covariance[:3, :3])  # information was used
    assert_covariance_ok(after.covariance)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("vertical", [1.0, -1.0])
def test_bearing_at_the_pole_stays_finite(kind: str, vertical: float) -> None:
    estimator = make(kind)
    estimator.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3), range=30.0), InitialGuess(30.0, 10.0, np.zeros(3), 5.0))
    for _ in range(20):
        estimator.predict()
        estimator.correct(BearingMeasurement(estimator.time, np.array([0.0, 0.0, vertical]), np.zeros(3), range=30.0))
    estimate = estimator.estimate
    assert np.all(np.isfinite(estimate.position)) and np.all(np.isfinite(estimate.velocity))
    assert np.all(np.isfinite(estimate.covariance))
    assert abs(float(azimuth_elevation(estimate.position)[1])) <= 0.5 * math.pi


@pytest.mark.parametrize("kind", ("azel", "msc"))
def test_prior_behind_the_sensor_restarts_on_the_bearing(kind: str) -> None:
    estimator = make(kind)
    estimator.initialize(0.0, np.array([20.0, 0.0, 0.0]), np.zeros(3), np.eye(6), **({"reference": np.zeros(3)} if kind == "msc" else {}))
    estimator.predict()
    report = estimator.correct(BearingMeasurement(estimator.time, np.array([-1.0, 0.0, 0.0]), np.zeros(3)))
    assert report.reinitialized
    np.testing.assert_allclose(estimator.estimate.position, [-20.0, 0.0, 0.0], atol=1e-9)
    assert_covariance_ok(estimator.estimate.covariance)


def test_elevation_clip_constant_is_below_the_pole() -> None:
    assert 0.5 * math.pi - 0.01 < MAX_ELEVATION < 0.5 * math.pi
    covariance = angle_noise_covariance(SIGMA**2, np.array([0.0, 0.0, -10.0]), 0.1)
    assert np.all(np.isfinite(covariance))


def test_azel_between_ticks_equals_an_update_at_the_bearing_time() -> None:
    """The constant-velocity map over the lead is linear and exact, so correcting the tick state
    with H = J_d [I, lead I] equals updating the state carried to the bearing time and carrying
    it back."""
    rng = np.random.default_rng(11)
    period, lead = 0.1, 0.06
    covariance = np.diag([9.0, 4.0, 6.0, 1.0, 2.0, 0.5])
    covariance[0, 4] = covariance[4, 0] = 0.3
    on_tick = AzElEKF(period, Q_TARGET, SIGMA**2 * np.eye(3))
    on_tick.initialize(0.0, P_T0, V_T, covariance)
    pursuer = np.array([20.0, -10.0, -5.0])
    bearing = BearingMeasurement(lead, P_T0 + V_T * lead - pursuer + rng.normal(0.0, 2.0, 3), pursuer)
    on_tick.correct(bearing)
    a_lead = np.block([[np.eye(3), lead * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    at_bearing = AzElEKF(period, Q_TARGET, SIGMA**2 * np.eye(3))
    carried = a_lead @ np.concatenate([P_T0, V_T])
    at_bearing.initialize(lead, carried[:3], carried[3:], a_lead @ covariance @ a_lead.T)
    at_bearing.correct(bearing)
    back = np.linalg.inv(a_lead)
    state = back @ np.concatenate([at_bearing.estimate.position, at_bearing.estimate.velocity])
    np.testing.assert_allclose(on_tick.estimate.position, state[:3], atol=1e-9)
    np.testing.assert_allclose(on_tick.estimate.velocity, state[3:], atol=1e-9)
    np.testing.assert_allclose(on_tick.estimate.covariance, back @ at_bearing.estimate.covariance @ back.T, atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_azimuth_residual_is_wrapped_across_pi(kind: str) -> None:
    """Prior at azimuth +179.9 deg, bearing at -179.9 deg: a 0.2 deg residual, not 359.8 deg."""
    estimator = make(kind)
    prior_direction = np.array([math.cos(math.radians(179.9)), math.sin(math.radians(179.9)), 0.0])
    measured = np.array([math.cos(math.radians(-179.9)), math.sin(math.radians(-179.9)), 0.0])
    covariance = np.diag([4.0] * 3 + [1.0] * 3)
    extra = {"reference": np.zeros(3)} if kind == "msc" else {}
    estimator.initialize(0.0, 20.0 * prior_direction, np.zeros(3), covariance, **extra)
    report = estimator.correct(BearingMeasurement(0.0, measured, np.zeros(3), range=20.0))
    assert report.innovation_angle == pytest.approx(math.radians(0.2), rel=1e-6)
    assert np.linalg.norm(estimator.estimate.position - 20.0 * prior_direction) < 0.1


def test_range_ekf_prediction_adds_the_discretised_process_noise() -> None:
    """P^- = F P F^T + G Q G^T dt: the (v, gamma, chi) block grows by Q dt each tick."""
    estimator = make("rae")
    estimator.initialize(0.0, P_T0, V_T, np.diag([1.0] * 3 + [0.25] * 3))
    before = estimator._covariance.copy()
    state = estimator.flight_path_state
    estimator.predict()
    f = flight_path_step_jacobian(state, PERIOD)
    expected = f @ before @ f.T
    expected[3:, 3:] += SEED003_PROCESS_NOISE * PERIOD
    np.testing.assert_allclose(estimator._covariance, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(estimator.estimate.position, P_T0 + PERIOD * V_T, atol=1e-12)
    np.testing.assert_allclose(estimator.estimate.velocity, V_T, atol=1e-12)


def test_msc_prediction_is_the_cartesian_constant_velocity_prediction() -> None:
    """Exact mean propagation and the Jacobian-mapped covariance: in Cartesian terms one MSC
    predict is x^- = A x, P^- = A P A^T + B Q B^T (the Jacobians of the two maps are inverse)."""
    msc = make("msc")
    covariance = np.diag([9.0, 4.0, 6.0, 1.0, 2.0, 0.5])
    covariance[1, 3] = covariance[3, 1] = 0.4
    msc.initialize(0.0, P_T0, V_T, covariance, reference=np.array([5.0, 3.0, -1.0]))
    # The Cartesian constant-velocity model written out (not another estimator of the module).
    a = np.block([[np.eye(3), PERIOD * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    b = np.vstack([0.5 * PERIOD**2 * np.eye(3), PERIOD * np.eye(3)])
    state, expected = np.concatenate([P_T0, V_T]), covariance.copy()
    for _ in range(25):
        msc.predict()
        state, expected = a @ state, a @ expected @ a.T + b @ Q_TARGET @ b.T
    np.testing.assert_allclose(msc.estimate.position, state[:3], atol=1e-9)
    np.testing.assert_allclose(msc.estimate.velocity, state[3:], atol=1e-9)
    np.testing.assert_allclose(msc.estimate.covariance, expected, rtol=1e-7, atol=1e-9)


def test_msc_update_matches_the_cartesian_ekf_to_first_order() -> None:
    """Same prior, same small-residual bearing between ticks: both EKFs linearise the same
    measurement, so their corrections agree to first order (velocity included, via the lead)."""
    covariance = np.diag([9.0, 4.0, 6.0, 1.0, 2.0, 0.5])
    pursuer = np.array([20.0, -10.0, -5.0])
    msc, azel = make("msc", 0.1), make("azel", 0.1)
    msc.initialize(0.0, P_T0, V_T, covariance, reference=np.zeros(3))
    azel.initialize(0.0, P_T0, V_T, covariance)
    lead = 0.05
    direction = P_T0 + V_T * lead - pursuer + np.array([0.0, 0.02, -0.02])  # ~1 mrad off
    for estimator in (msc, azel):
        estimator.correct(BearingMeasurement(lead, direction, pursuer))
    position_step = azel.estimate.position - P_T0
    velocity_step = azel.estimate.velocity - V_T
    assert np.linalg.norm(velocity_step) > 1e-4
    np.testing.assert_allclose(msc.estimate.position - P_T0, position_step, atol=0.02 * np.linalg.norm(position_step))
    np.testing.assert_allclose(msc.estimate.velocity - V_T, velocity_step, atol=0.02 * np.linalg.norm(velocity_step))
    np.testing.assert_allclose(msc.estimate.covariance, azel.estimate.covariance, rtol=0.02, atol=0.02)
