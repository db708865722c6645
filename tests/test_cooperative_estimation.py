"""Cooperative estimation (companion.core.cooperative_estimation) against independent references:
exact geometry of noise-free rays, the planar law of sines written out here, Monte Carlo
statistics with chi-square bounds (scipy.stats), the information form of fusion and the true
error covariance of correlated inputs."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import stats

from companion.core.cooperative_estimation import (
    DEFAULT_MIN_ANGLE,
    TriangulationKalmanEstimator,
    covariance_intersection,
    fuse_target_estimates,
    fuse_two,
    law_of_sines_range,
    triangulate,
    triangulation_attempt,
    white_jerk_process_noise,
)
from companion.core.estimators import InitialGuess, TargetEstimator
from companion.core.messages import BearingMeasurement, TargetEstimate

coordinate = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coordinate, coordinate, coordinate).map(np.array)


def _bearing(target: np.ndarray, sensor: np.ndarray, time: float = 0.0, source: int = 0,
             noise: np.ndarray | None = None) -> BearingMeasurement:
    line = (target - sensor) / np.linalg.norm(target - sensor)
    return BearingMeasurement(time, line if noise is None else line + noise, sensor, source=source)


def _line_angle(u: np.ndarray, v: np.ndarray) -> float:
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    return math.atan2(float(np.linalg.norm(np.cross(u, v))), abs(float(u @ v)))


# ---------------------------------------------------------------------------------------------
# Triangulation
# ---------------------------------------------------------------------------------------------

@given(point, point, point)
@settings(max_examples=200, deadline=None)
def test_noise_free_rays_meet_at_the_target(target, sensor_a, sensor_b):
    """Two exact bearings from anywhere meet at the target (the geometry is the reference)."""
    assume(np.linalg.norm(target - sensor_a) > 1.0 and np.linalg.norm(target - sensor_b) > 1.0)
    assume(_line_angle(target - sensor_a, target - sensor_b) > math.radians(10.0))
    result = triangulate(_bearing(target, sensor_a), _bearing(target, sensor_b, source=1))
    assert result is not None
    position, covariance = result
    scale = max(np.linalg.norm(target - sensor_a), np.linalg.norm(target - sensor_b))
    np.testing.assert_allclose(position, target, atol=1e-9 * scale + 1e-9)
    np.testing.assert_allclose(covariance, covariance.T)
    assert np.linalg.eigvalsh(covariance)[0] > 0.0


def _paper_sine(x: np.ndarray, y: np.ndarray) -> float:
    """Seed 002's printed identity sin(theta) = ||P_x P_y|| (spectral norm, 2-D projectors)."""
    projector = lambda g: np.eye(2) - np.outer(g, g) / (g @ g)  # noqa: E731
    return float(np.linalg.norm(projector(x) @ projector(y), 2))


@given(st.tuples(coordinate, coordinate).map(np.array), st.tuples(coordinate, coordinate).map(np.array),
       st.tuples(coordinate, coordinate).map(np.array))
@settings(max_examples=200, deadline=None)
def test_planar_law_of_sines_with_the_erratum_fixed(target, own, neighbour):
    """In the plane, D_i = D_inu sin(angle at nu) / sin(angle at the target) with sines from
    |x1 y2 - x2 y1| gives the true range; the triangulation (z = 0 plane) gives the same point."""
    assume(min(np.linalg.norm(target - own), np.linalg.norm(target - neighbour)) > 1.0)
    u_i = (target - own) / np.linalg.norm(target - own)
    u_nu = (target - neighbour) / np.linalg.norm(target - neighbour)
    assume(_line_angle(np.append(u_i, 0.0), np.append(u_nu, 0.0)) > math.radians(10.0))
    d = neighbour - own
    # written out here: the 2-D cross products
    expected = abs(d[0] * u_nu[1] - d[1] * u_nu[0]) / abs(u_i[0] * u_nu[1] - u_i[1] * u_nu[0])
    true_range = float(np.linalg.norm(target - own))
    assert expected == pytest.approx(true_range, rel=1e-9, abs=1e-9)
    assert law_of_sines_range(u_i, u_nu, d) == pytest.approx(true_range, rel=1e-9, abs=1e-9)
    flat = lambda v: np.append(v, 0.0)  # noqa: E731
    position, _ = triangulate(_bearing(flat(target), flat(own)), _bearing(flat(target), flat(neighbour), source=2))
    np.testing.assert_allclose(position, flat(target), atol=1e-8 * max(1.0, true_range))


@given(st.floats(0.05, math.pi - 0.05), st.floats(0.0, 2 * math.pi))
@settings(max_examples=100, deadline=None)
def test_the_papers_sine_identity_is_the_cosine(theta, heading):
    """||P_x P_y|| = |cos(theta)|, not sin(theta): the erratum."""
    x = np.array([math.cos(heading), math.sin(heading)])
    y = np.array([math.cos(heading + theta), math.sin(heading + theta)])
    assert _paper_sine(x, y) == pytest.approx(abs(math.cos(theta)), abs=1e-9)
    assert abs(x[0] * y[1] - x[1] * y[0]) == pytest.approx(math.sin(theta), abs=1e-9)


def test_the_papers_form_gives_a_wrong_range_where_it_should_not():
    """A right-angle triangle: the printed identity makes the angle at the target's sine 0 (cos 90)."""
    own, neighbour, target = np.array([0.0, 0.0]), np.array([10.0, 10.0]), np.array([10.0, 0.0])
    u_i, u_nu = (target - own) / 10.0, (target - neighbour) / 10.0  # perpendicular lines: theta = 90 deg
    d = neighbour - own
    target_sine_paper = _paper_sine(u_i, u_nu)
    assert target_sine_paper == pytest.approx(0.0, abs=1e-12)  # the paper's range is then infinite
    assert law_of_sines_range(u_i, u_nu, d) == pytest.approx(10.0)
    # a 30-degree triangle: the paper's form is off by a factor tan(theta) / tan(angle at nu) ...
    target = np.array([10.0, 10.0 * math.tan(math.radians(30.0))])
    neighbour = np.array([20.0, 0.0])
    u_i = (target - own) / np.linalg.norm(target - own)
    u_nu = (target - neighbour) / np.linalg.norm(target - neighbour)
    d = neighbour - own
    paper = np.linalg.norm(d) * _paper_sine(-d, u_nu) / _paper_sine(u_i, u_nu)
    true_range = float(np.linalg.norm(target - own))
    assert abs(paper - true_range) / true_range > 0.5
    assert law_of_sines_range(u_i, u_nu, d) == pytest.approx(true_range)


@pytest.mark.parametrize("direction_b, reason, min_angle", [
    (np.array([1.0, 0.0, 0.0]), "near_parallel", DEFAULT_MIN_ANGLE),  # parallel rays
    (np.array([1.0, 0.0, 0.0]), "near_parallel", 0.0),  # parallel, even with no minimum angle
    (np.array([-1.0, 0.0, 0.0]), "near_parallel", DEFAULT_MIN_ANGLE),  # anti-parallel
    (np.array([-1.0, 0.0, 0.0]), "near_parallel", 0.0),
    (np.array([1.0, -math.tan(math.radians(3.0)), 0.0]), "near_parallel", DEFAULT_MIN_ANGLE),  # 3 deg < 5 deg
    (np.array([0.0, -1.0, 0.0]), "behind_sensor", DEFAULT_MIN_ANGLE),  # the lines cross behind sensor b
    (np.array([np.nan, 0.0, 0.0]), "invalid", DEFAULT_MIN_ANGLE),
    (np.zeros(3), "invalid", DEFAULT_MIN_ANGLE),
])
def test_degenerate_pairs_give_none_and_a_counted_reason(direction_b, reason, min_angle):
    a = BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3))
    b = BearingMeasurement(0.0, direction_b, np.array([0.0, 10.0, 0.0]), source=1)
    rejections: Counter = Counter()
    assert triangulate(a, b, min_angle=min_angle, rejections=rejections) is None
    assert rejections == Counter({reason: 1})


def test_first_order_covariance_matches_monte_carlo():
    """Empirical covariance of triangulations of noisy bearings vs the first-order covariance:
    mean NEES within the chi-square(3 N) 99 % interval, and the matrices within 10 %."""
    rng = np.random.default_rng(7)
    target, sensor_a, sensor_b = np.array([10.0, 5.0, 0.0]), np.array([-10.0, 0.0, -8.0]), np.array([15.0, -20.0, -5.0])
    sigma, count = 0.01, 4000
    positions, nees = [], 0.0
    for _ in range(count):
        a = _bearing(target, sensor_a, noise=sigma * rng.standard_normal(3))
        b = _bearing(target, sensor_b, source=1, noise=sigma * rng.standard_normal(3))
        position, covariance = triangulate(a, b, bearing_noise_std=sigma)
        positions.append(position)
        error = position - target
        nees += float(error @ np.linalg.solve(covariance, error))
    low, high = stats.chi2.ppf([0.005, 0.995], 3 * count)
    assert low <= nees <= high
    empirical = np.cov(np.array(positions).T)
    _, nominal = triangulate(_bearing(target, sensor_a), _bearing(target, sensor_b, source=1), bearing_noise_std=sigma)
    assert np.linalg.norm(empirical - nominal) <= 0.1 * np.linalg.norm(nominal)


def test_bearings_at_different_times_are_stamped_at_the_newer_one_and_used_as_they_are():
    target, sensor_a, sensor_b = np.array([10.0, 0.0, 0.0]), np.zeros(3), np.array([10.0, -10.0, 0.0])
    old = _bearing(target, sensor_a, time=1.0)
    moved = target + np.array([0.0, 1.0, 0.0])  # the target moved 1 m before the newer bearing
    new = _bearing(moved, sensor_b, time=1.5, source=1)
    result = triangulation_attempt(old, new)
    assert result.time == 1.5 and result.age == 0.5
    # the older ray (the x axis) is used as is: the point lies on it, not at the moved target
    assert abs(result.position[1]) < 0.6 and np.linalg.norm(result.position - moved) > 0.5


# ---------------------------------------------------------------------------------------------
# Kalman enhancement
# ---------------------------------------------------------------------------------------------

SENSOR_A, SENSOR_B = np.array([-20.0, 0.0, -10.0]), np.array([0.0, -25.0, -10.0])


def _monte_carlo_nees(velocity: np.ndarray, runs: int, seed: int, duration: float = 20.0,
                      period: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Run `runs` filters on a target p(t) = v t seen by SENSOR_A and SENSOR_B (noise 0.01 per axis,
    both at every tick); start drawn from the filter's own prior. Returns NEES of [p, v] at the end
    (runs,) and the final position errors, m (runs,)."""
    rng = np.random.default_rng(seed)
    sigma, position_std, velocity_std = 0.01, 10.0, 2.0
    nees, errors = [], []
    for _ in range(runs):
        estimator = TriangulationKalmanEstimator(period, process_noise=white_jerk_process_noise(period, 1e-8),
                                                 measurement_noise=None, bearing_noise_std=sigma,
                                                 acceleration_std=0.1)
        start = position_std * rng.standard_normal(3)
        guess = InitialGuess(20.0, position_std, velocity + velocity_std * rng.standard_normal(3), velocity_std,
                             position=start)
        target = np.zeros(3)
        estimator.initialize_on_bearing(_bearing(target, SENSOR_A, noise=sigma * rng.standard_normal(3)), guess)
        for k in range(1, int(round(duration / period)) + 1):
            time = k * period
            target = velocity * time
            estimator.predict()
            estimator.correct(_bearing(target, SENSOR_A, time, 0, sigma * rng.standard_normal(3)))
            estimator.correct(_bearing(target, SENSOR_B, time, 2, sigma * rng.standard_normal(3)))
        estimate = estimator.estimate
        assert estimate.time == pytest.approx(duration)
        error = np.concatenate([estimate.position - target, estimate.velocity - velocity])
        nees.append(float(error @ np.linalg.solve(estimate.covariance, error)))
        errors.append(float(np.linalg.norm(estimate.position - target)))
    return np.array(nees), np.array(errors)


@pytest.mark.parametrize("velocity", [np.zeros(3), np.array([1.0, 0.5, 0.0])], ids=["stationary", "constant_velocity"])
def test_kalman_enhancement_is_consistent_and_converges(velocity):
    runs = 60
    nees, errors = _monte_carlo_nees(velocity, runs, seed=11)
    low, high = stats.chi2.ppf([0.005, 0.995], 6 * runs)
    assert low <= nees.sum() <= high
    # from a 10 m per axis (17 m RMS) start to within the filtered triangulation accuracy (0.07 m
    # stationary, 0.17 m moving away to about 40 m from both sensors, measured)
    assert np.sqrt(np.mean(errors**2)) < 0.3


def test_seed_values_converge():
    """Seed 002's Q = 0.2 I, R = I: not consistent here, but the estimate converges to the target."""
    rng = np.random.default_rng(3)
    estimator = TriangulationKalmanEstimator(0.1)
    estimator.initialize_on_bearing(_bearing(np.zeros(3), SENSOR_A), InitialGuess(5.0, 30.0, np.zeros(3), 5.0))
    velocity = np.array([1.0, 0.5, 0.0])
    errors = [np.linalg.norm(estimator.estimate.position)]  # the start, 5 m along the bearing (target 20 m away)
    for k in range(1, 201):
        target = velocity * k * 0.1
        estimator.predict()
        estimator.correct(_bearing(target, SENSOR_A, k * 0.1, 0, 0.01 * rng.standard_normal(3)))
        estimator.correct(_bearing(target, SENSOR_B, k * 0.1, 1, 0.01 * rng.standard_normal(3)))
        errors.append(np.linalg.norm(estimator.estimate.position - target))
    assert errors[0] > 30.0 * np.sqrt(np.mean(np.square(errors[-50:])))
    assert np.sqrt(np.mean(np.square(errors[-50:]))) < 0.5
    assert estimator.updates == 200


def test_it_is_a_target_estimator_and_waits_for_a_pair():
    """Before a neighbour's bearing nothing is corrected: the start is remark 3's point on the bearing
    at the guessed range, and predictions only widen the covariance."""
    estimator: TargetEstimator = TriangulationKalmanEstimator(0.1)
    members = ("period", "initialize_on_bearing", "predict", "correct", "initialized", "estimate")
    assert all(hasattr(TargetEstimator, name) or name == "period" for name in members)
    assert all(hasattr(estimator, name) for name in members if name != "estimate") and not estimator.initialized
    target = np.array([10.0, 0.0, 0.0])
    estimator.initialize_on_bearing(_bearing(target, np.zeros(3)), InitialGuess(30.0, 20.0, np.zeros(3), 1.0))
    np.testing.assert_allclose(estimator.estimate.position, [30.0, 0.0, 0.0])
    trace = np.trace(estimator.estimate.covariance)
    for k in range(1, 5):
        estimator.predict()
        report = estimator.correct(_bearing(target, np.zeros(3), k * 0.1))  # own bearings only
        assert report.innovation is None and report.innovation_dof == 0
    np.testing.assert_allclose(estimator.estimate.position, [30.0, 0.0, 0.0])
    assert np.trace(estimator.estimate.covariance) > trace and estimator.updates == 0
    report = estimator.correct(_bearing(target, np.array([10.0, -10.0, 0.0]), 0.4, source=3))
    assert report.innovation_dof == 3 and report.innovation.shape == (3,) and report.innovation_covariance.shape == (3, 3)
    assert np.linalg.norm(estimator.estimate.position - target) < 0.1
    assert estimator.estimate.covariance.shape == (6, 6)


def test_pairing_rules():
    """Different sources only, within max_pair_age_s, each bearing in at most one triangulation."""
    target = np.array([10.0, 0.0, 0.0])
    sensors = {0: np.zeros(3), 1: np.array([10.0, -10.0, 0.0]), 2: np.array([20.0, 0.0, -5.0])}
    estimator = TriangulationKalmanEstimator(0.1, max_pair_age_s=0.25)
    estimator.initialize_on_bearing(_bearing(target, sensors[0]), InitialGuess(10.0, 5.0, np.zeros(3), 1.0))
    estimator.correct(_bearing(target, sensors[0], 0.0))  # the same source: no pair
    assert estimator.updates == 0
    estimator.correct(_bearing(target, sensors[1], 0.5, source=1))  # 0.5 s after: too old to pair
    assert estimator.updates == 0
    estimator.correct(_bearing(target, sensors[2], 0.6, source=2))  # pairs with source 1's
    assert estimator.updates == 1
    estimator.correct(_bearing(target, sensors[0], 0.6))  # 1 and 2 consumed, own bearing of t = 0 too old
    assert estimator.updates == 1
    for k, source in enumerate([1, 2, 0, 1, 2, 0]):  # round robin: every second bearing completes a pair
        estimator.correct(_bearing(target, sensors[source], 0.7 + 0.01 * k, source=source))
    assert estimator.updates == 4


def test_the_age_of_the_older_bearing_is_in_the_measurement_model():
    """A target moving at a known velocity (tight velocity prior), bearings 0.2 s apart, no noise:
    with the age in the model the update lands on the target at the newer time; without, it is
    off by a fraction of speed x age (the raw midpoint is off either way)."""
    velocity = np.array([2.0, 1.0, 0.0])
    misses = {}
    for compensate in (True, False):
        estimator = TriangulationKalmanEstimator(0.1, compensate_age=compensate, max_pair_age_s=0.3,
                                                 measurement_noise=1e-6)
        # a known constant velocity: the full 9x9 covariance, tight on velocity and acceleration
        estimator.initialize(0.0, np.array([10.0, 0.0, 0.0]), velocity, np.diag([100.0] * 3 + [1e-10] * 6))
        estimator.correct(_bearing(np.array([10.0, 0.0, 0.0]), np.zeros(3), 0.0))
        estimator.predict()
        estimator.predict()
        moved = np.array([10.0, 0.0, 0.0]) + 0.2 * velocity
        estimator.correct(_bearing(moved, np.array([15.0, -12.0, -3.0]), 0.2, source=1))
        assert estimator.time == pytest.approx(0.2) and estimator.updates == 1
        misses[compensate] = np.linalg.norm(estimator.estimate.position - moved)
        assert np.linalg.norm(estimator.last_triangulation.position - moved) > 0.1
    assert misses[True] < 1e-4 and misses[False] > 0.1


def test_three_sensors_in_turn_converge_with_little_noise():
    """Three sensors, pairs spanning one or two ticks, bearing noise 1e-5: the filter must follow
    the target to the noise level (moving the older ray with the filter's own velocity estimate
    instead diverged here, to 44 m)."""
    rng = np.random.default_rng(5)
    sensors = [np.array([-20.0, 0.0, -10.0]), np.array([10.0, -25.0, -10.0]), np.array([15.0, 20.0, -5.0])]
    velocity = np.array([1.0, 0.5, 0.0])
    estimator = TriangulationKalmanEstimator(0.1, process_noise=white_jerk_process_noise(0.1, 0.01),
                                             measurement_noise=None, bearing_noise_std=1e-5)
    estimator.initialize_on_bearing(_bearing(np.zeros(3), sensors[0]), InitialGuess(20.0, 30.0, np.zeros(3), 5.0))
    errors = []
    for k in range(1, 201):
        target = velocity * 0.1 * k
        estimator.predict()
        for source, sensor in enumerate(sensors):
            estimator.correct(_bearing(target, sensor, 0.1 * k, source, 1e-5 * rng.standard_normal(3)))
        errors.append(np.linalg.norm(estimator.estimate.position - target))
    assert estimator.updates == 300
    assert max(errors[100:]) < 2e-3


def test_hostile_bearings_are_counted_and_change_nothing():
    estimator = TriangulationKalmanEstimator(0.1)
    estimator.initialize_on_bearing(_bearing(np.array([10.0, 0, 0]), np.zeros(3)), InitialGuess(10.0, 5.0, np.zeros(3), 1.0))
    before = estimator.state_and_covariance
    for bad in (BearingMeasurement(0.0, np.array([np.nan, 0, 0]), np.zeros(3), source=1),
                BearingMeasurement(0.0, np.zeros(3), np.zeros(3), source=1),
                BearingMeasurement(math.inf, np.array([1.0, 0, 0]), np.zeros(3), source=1),
                BearingMeasurement(0.0, np.array([1.0, 0, 0]), np.array([np.inf, 0, 0]), source=1),
                BearingMeasurement(None, np.array([1.0, 0, 0]), np.zeros(3), source=1),  # type: ignore[arg-type]
                BearingMeasurement(0.0, np.array([1.0, 0]), np.zeros(3), source=1),
                BearingMeasurement(0.0, "north", np.zeros(3), source=1)):  # type: ignore[arg-type]
        assert estimator.correct(bad).innovation is None
    assert estimator.rejections["invalid_bearing"] == 7
    after = estimator.state_and_covariance
    np.testing.assert_array_equal(before[0], after[0])
    np.testing.assert_array_equal(before[1], after[1])
    # a degenerate pair is counted too (the neighbour on the own ray, looking the same way)
    estimator.correct(BearingMeasurement(0.0, np.array([1.0, 0, 0]), np.array([-5.0, 0, 0]), source=1))
    assert estimator.rejections["near_parallel"] == 1 and estimator.updates == 0


def test_far_stamps_wrong_neighbours_and_floods_are_contained():
    target = np.array([10.0, 0.0, 0.0])
    guess = InitialGuess(10.0, 5.0, np.zeros(3), 1.0)
    estimator = TriangulationKalmanEstimator(0.1, measurement_noise=None, gate_probability=0.999)
    estimator.initialize_on_bearing(_bearing(target, np.zeros(3)), guess)
    # a bearing stamped 5 s away from the filter's time is refused, not stored
    estimator.correct(_bearing(target, np.array([10.0, -10.0, 0.0]), -5.0, source=1))
    estimator.correct(_bearing(target, np.array([10.0, -10.0, 0.0]), 5.0, source=1))
    assert estimator.rejections["time_offset"] == 2 and estimator.updates == 0
    estimator.correct(_bearing(target, np.array([10.0, -10.0, 0.0]), 0.0, source=1))
    assert estimator.updates == 1
    for k in range(1, 30):  # converge on the target
        estimator.predict()
        estimator.correct(_bearing(target, np.zeros(3), 0.1 * k))
        estimator.correct(_bearing(target, np.array([10.0, -10.0, 0.0]), 0.1 * k, source=1))
    before = estimator.state_and_covariance
    # a neighbour that reports a position 5 m off its true one: its triangulation is gated out
    estimator.correct(_bearing(target, np.zeros(3), 3.0))
    estimator.correct(BearingMeasurement(3.0, np.array([0.0, 1.0, 0.0]), np.array([15.0, -10.0, 0.0]), source=1))
    assert estimator.rejections["gated"] == 1
    np.testing.assert_array_equal(before[0], estimator.state_and_covariance[0])
    # two thousand made-up source ids: the waiting table stays bounded
    for source in range(2_000):
        estimator.correct(_bearing(target, np.array([0.0, 0.0, -10.0 - source]), 3.0, source=100 + source))
    assert len(estimator._waiting) <= 64 and len(estimator._consumed) <= 64


def test_a_bearing_handed_back_on_a_restart_is_not_used_twice():
    """The pipeline's health restart calls initialize_on_bearing with a bearing correct() just used."""
    target = np.array([10.0, 0.0, 0.0])
    estimator = TriangulationKalmanEstimator(0.1)
    estimator.initialize_on_bearing(_bearing(target, np.zeros(3)), InitialGuess(10.0, 5.0, np.zeros(3), 1.0))
    used = _bearing(target, np.array([10.0, -10.0, 0.0]), 0.0, source=1)
    estimator.correct(used)
    assert estimator.updates == 1
    estimator.initialize_on_bearing(used, InitialGuess(10.0, 5.0, np.zeros(3), 1.0))
    estimator.correct(_bearing(target, np.array([0.0, 10.0, 0.0]), 0.0, source=2))
    assert estimator.updates == 1  # source 2 found nothing unused to pair with


# ---------------------------------------------------------------------------------------------
# Fusion
# ---------------------------------------------------------------------------------------------

def _random_covariance(rng: np.random.Generator, n: int) -> np.ndarray:
    factor = rng.standard_normal((n, n))
    return factor @ factor.T + 0.05 * np.eye(n)


seeds = st.integers(0, 2**32 - 1)


@given(seeds, st.integers(1, 6))
@settings(max_examples=100, deadline=None)
def test_seed004_fusion_is_the_information_form(seed, n):
    rng = np.random.default_rng(seed)
    x1, x2 = rng.standard_normal(n), rng.standard_normal(n)
    p1, p2 = _random_covariance(rng, n), _random_covariance(rng, n)
    x, p = fuse_two(x1, p1, x2, p2)
    information = np.linalg.inv(p1) + np.linalg.inv(p2)
    np.testing.assert_allclose(p, np.linalg.inv(information), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(x, np.linalg.solve(information, np.linalg.solve(p1, x1) + np.linalg.solve(p2, x2)),
                               rtol=1e-7, atol=1e-8)


@given(seeds, st.integers(1, 6), st.integers(2, 4))
@settings(max_examples=100, deadline=None)
def test_covariance_intersection_is_consistent_for_correlated_inputs(seed, n, count):
    """Inputs with a joint covariance (random cross-covariances): the CI covariance bounds the
    true error covariance of the fused estimate, which is computed here from the joint one."""
    rng = np.random.default_rng(seed)
    joint = _random_covariance(rng, n * count)
    blocks = [joint[i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(count)]
    means = [rng.standard_normal(n) for _ in range(count)]
    fused = covariance_intersection(list(zip(means, blocks)))
    assert len(fused.weights) == count and sum(fused.weights) == pytest.approx(1.0)
    # x = sum_i W_i x_i with W_i = omega_i P P_i^-1 (the CI form): its error covariance W Joint W^T
    gains = np.hstack([w * fused.covariance @ np.linalg.inv(block) for w, block in zip(fused.weights, blocks)])
    np.testing.assert_allclose(fused.mean, gains @ np.concatenate(means), rtol=1e-6, atol=1e-6)
    true_covariance = gains @ joint @ gains.T
    margin = np.linalg.eigvalsh(fused.covariance - true_covariance)[0]
    assert margin >= -1e-8 * np.linalg.norm(fused.covariance)


@given(seeds, st.integers(1, 6))
@settings(max_examples=60, deadline=None)
def test_covariance_intersection_minimises_the_trace_and_keeps_a_dominating_input(seed, n):
    rng = np.random.default_rng(seed)
    p1 = _random_covariance(rng, n)
    p2 = p1 + _random_covariance(rng, n)  # P2 > P1: input 1 dominates
    x1, x2 = rng.standard_normal(n), rng.standard_normal(n)
    fused = covariance_intersection([(x1, p1), (x2, p2)])
    assert fused.weights == (1.0, 0.0)
    np.testing.assert_allclose(fused.covariance, p1, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fused.mean, x1, rtol=1e-9, atol=1e-12)
    # and for unrelated inputs: no weight on a fine grid does better
    p3 = _random_covariance(rng, n)
    fused = covariance_intersection([(x1, p1), (x2, p3)])
    grid = [np.trace(np.linalg.inv(w * np.linalg.inv(p1) + (1 - w) * np.linalg.inv(p3))) for w in np.linspace(0, 1, 401)]
    assert np.trace(fused.covariance) <= min(grid) * (1 + 1e-9)


def test_seed004_fusion_is_overconfident_on_identical_estimates_ci_is_not():
    """The same estimate twice (fully correlated): the true fused error covariance is P itself."""
    p = np.diag([4.0, 1.0])
    _, seed_covariance = fuse_two(np.zeros(2), p, np.zeros(2), p)
    np.testing.assert_allclose(seed_covariance, p / 2)
    fused = covariance_intersection([(np.zeros(2), p), (np.zeros(2), p)])
    np.testing.assert_allclose(fused.covariance, p)


def test_fusing_target_estimates_carries_neighbours_to_the_own_time():
    own = TargetEstimate(2.0, np.array([10.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.eye(6))
    late = TargetEstimate(1.0, np.array([9.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 0.25 * np.eye(6))
    for method in ("ci", "seed004"):
        fused = fuse_target_estimates(own, [late], method)
        assert fused.time == 2.0
        np.testing.assert_allclose(fused.position, own.position, atol=1e-9)
        assert fused.position_std < own.position_std
    with pytest.raises(ValueError):
        fuse_target_estimates(own, [late], "average")
    with pytest.raises(ValueError):
        covariance_intersection([(np.zeros(2), np.full((2, 2), np.nan))])


def test_comparison_script_orders_the_estimators():
    """The measurement script (tests/cooperative_estimation_comparison.py) on two seeds: cooperation beats one static sensor,
    whose range is unobservable against a constant-velocity target."""
    from tests.cooperative_estimation_comparison import compare

    summary = compare(range(2))
    single = summary["uplkf_single"]["rms_5_30"]
    for name in ("tkf_seed", "tkf_consistent", "uplkf_all", "uplkf_ci"):
        assert summary[name]["rms_5_30"] < single / 10
