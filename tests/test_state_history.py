"""StateHistory: own-state buffer read at past instants (interpolation, slerp, extrapolation, ordering, ageing)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, unit_vectors
from scipy.spatial.transform import Rotation

from companion.core.state_history import StateHistory

START_ATTITUDE = Rotation.from_euler("ZYX", [0.4, -0.1, 0.05])
BODY_RATE = np.array([0.3, -0.5, 1.2])  # rad/s, constant, body frame
POSITION_0 = np.array([3.0, -2.0, -20.0])
VELOCITY_0 = np.array([12.0, -4.0, 1.5])
ACCELERATION = np.array([0.5, 2.0, -0.3])


def _attitude(time: float) -> Rotation:
    """R(t) = R0 exp([omega]_x t): constant body rate."""
    return START_ATTITUDE * Rotation.from_rotvec(BODY_RATE * time)


def _position(time: float) -> np.ndarray:
    return POSITION_0 + VELOCITY_0 * time


def _filled(times, max_age_s: float = 10.0, max_extrapolation: float = 0.1, velocity=lambda t: VELOCITY_0) -> StateHistory:
    history = StateHistory(max_age_s, max_extrapolation)
    for time in times:
        assert history.append(time, _position(time), velocity(time), _attitude(time).as_matrix())
    return history


PROPERTY = settings(max_examples=40, deadline=None)

# Sample times as odometry arrives: 25-100 Hz with jitter, 2..100 samples.
sample_times = st.lists(floats(0.01, 0.04), min_size=2, max_size=100).map(np.cumsum)
# Query instants as fractions of the buffered span.
query_fractions = st.lists(floats(0.0, 1.0), min_size=1, max_size=30)


def _queries(times: np.ndarray, fractions: list[float]) -> np.ndarray:
    return times[0] + np.asarray(fractions) * (times[-1] - times[0])


@PROPERTY
@given(sample_times, query_fractions)
def test_linear_motion_is_interpolated_exactly(times: np.ndarray, fractions: list[float]):
    history = _filled(times)
    for query in _queries(times, fractions):
        position, velocity, _ = history.at(query)
        np.testing.assert_allclose(position, _position(query), atol=1e-10)
        np.testing.assert_allclose(velocity, VELOCITY_0, atol=1e-12)


@PROPERTY
@given(sample_times, query_fractions)
def test_linearly_changing_velocity_is_interpolated_exactly(times: np.ndarray, fractions: list[float]):
    history = _filled(times, velocity=lambda t: VELOCITY_0 + ACCELERATION * t)
    for query in _queries(times, fractions):
        np.testing.assert_allclose(history.at(query).velocity, VELOCITY_0 + ACCELERATION * query, atol=1e-10)


@PROPERTY
@given(sample_times, query_fractions, unit_vectors(), floats(0.0, 3.0))
def test_constant_rate_rotation_is_recovered_by_slerp(times: np.ndarray, fractions: list[float], axis: np.ndarray, rate: float):
    """R(t) = R0 exp([omega]_x t) for any constant body rate up to 3 rad/s, sampled at >= 25 Hz
    (under a half turn between samples, so the shortest arc is the true one); scipy is the reference."""
    def attitude(time: float) -> Rotation:
        return START_ATTITUDE * Rotation.from_rotvec(rate * axis * time)

    history = StateHistory(10.0, 0.1)
    for time in times:
        assert history.append(time, _position(time), VELOCITY_0, attitude(time).as_matrix())
    for query in _queries(times, fractions):
        rotation = history.at(query).rotation
        np.testing.assert_allclose(rotation, attitude(query).as_matrix(), atol=1e-9)
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)


def test_slerp_beats_matrix_interpolation_at_midpoints():
    """Halfway between samples 0.2 s apart at ~1.3 rad/s, element-wise averaging of matrices is visibly off."""
    history = _filled([0.0, 0.2])
    midpoint = history.at(0.1).rotation
    averaged = 0.5 * (_attitude(0.0).as_matrix() + _attitude(0.2).as_matrix())
    truth = _attitude(0.1).as_matrix()
    assert np.max(np.abs(midpoint - truth)) < 1e-12
    assert np.max(np.abs(averaged - truth)) > 1e-3


def test_sample_times_return_the_samples():
    times = [0.0, 0.02, 0.05, 0.07]
    history = _filled(times)
    for time in times:
        position, velocity, rotation = history.at(time)
        np.testing.assert_array_equal(position, _position(time))
        np.testing.assert_allclose(rotation, _attitude(time).as_matrix(), atol=1e-12)


def test_extrapolation_is_limited_to_max_extrapolation():
    history = _filled([0.0, 0.02, 0.04])
    newest = history.newest_time
    position, velocity, rotation = history.at(newest + 0.05)
    np.testing.assert_allclose(position, _position(newest + 0.05), atol=1e-12)  # constant velocity
    np.testing.assert_allclose(rotation, _attitude(newest).as_matrix(), atol=1e-12)  # attitude held
    assert history.at(newest + 0.1) is not None
    assert history.at(newest + 0.1001) is None
    assert history.at(newest + 5.0) is None
    no_extrapolation = _filled([0.0, 0.02], max_extrapolation=0.0)
    assert no_extrapolation.at(0.02) is not None and no_extrapolation.at(0.0201) is None
    wider = _filled([0.0, 0.02], max_extrapolation=0.5)
    assert wider.at(0.4) is not None


def test_before_the_oldest_sample_or_empty_gives_none():
    assert StateHistory(1.0).at(0.0) is None
    history = _filled([1.0, 1.1])
    assert history.at(0.999) is None
    assert history.at(math.nan) is None


def test_out_of_order_and_duplicate_samples_are_ignored_and_counted():
    history = _filled([0.0, 0.1, 0.2])
    assert not history.append(0.15, np.zeros(3), np.zeros(3), np.eye(3))
    assert not history.append(0.2, np.zeros(3), np.zeros(3), np.eye(3))
    assert history.rejected_out_of_order == 2 and len(history) == 3
    np.testing.assert_allclose(history.at(0.15).position, _position(0.15), atol=1e-12)  # unaffected
    assert history.append(0.3, _position(0.3), VELOCITY_0, _attitude(0.3).as_matrix())
    assert len(history) == 4


def test_non_finite_samples_are_ignored_and_counted():
    history = _filled([0.0])
    assert not history.append(0.1, np.array([0.0, math.nan, 0.0]), np.zeros(3), np.eye(3))
    assert not history.append(0.1, np.zeros(3), np.array([math.inf, 0.0, 0.0]), np.eye(3))
    assert not history.append(math.nan, np.zeros(3), np.zeros(3), np.eye(3))
    assert not history.append(0.1, np.zeros(3), np.zeros(3), np.full((3, 3), math.nan))
    assert history.rejected_not_finite == 4 and len(history) == 1


def test_old_samples_are_dropped():
    history = _filled(np.arange(0.0, 5.0, 0.02), max_age_s=1.0)
    assert history.newest_time - history.oldest_time <= 1.0 + 1e-9
    assert history.oldest_time >= history.newest_time - 1.0 - 1e-9
    assert len(history) in (50, 51)
    assert history.at(history.newest_time - 1.5) is None
    assert history.at(history.newest_time - 0.9) is not None


def test_scipy_rotation_samples_are_accepted():
    history = StateHistory(1.0)
    assert history.append(0.0, np.zeros(3), np.zeros(3), _attitude(0.0))
    assert history.append(0.1, np.zeros(3), np.zeros(3), _attitude(0.1))
    np.testing.assert_allclose(history.at(0.05).rotation, _attitude(0.05).as_matrix(), atol=1e-12)


def test_returned_arrays_are_copies():
    history = _filled([0.0, 0.1])
    history.at(0.1).position[:] = 99.0
    history.at(0.0).velocity[:] = 99.0
    np.testing.assert_array_equal(history.at(0.1).position, _position(0.1))
    np.testing.assert_array_equal(history.at(0.0).velocity, VELOCITY_0)


@pytest.mark.parametrize("arguments", [(0.0,), (-1.0,), (math.inf,), (1.0, -0.1), (1.0, math.nan)])
def test_bad_construction_is_rejected(arguments):
    with pytest.raises(ValueError):
        StateHistory(*arguments)


def test_malformed_samples_raise():
    history = StateHistory(1.0)
    with pytest.raises(ValueError, match="position"):
        history.append(0.0, np.zeros(2), np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="velocity"):
        history.append(0.0, np.zeros(3), np.zeros((3, 1)), np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        history.append(0.0, np.zeros(3), np.zeros(3), 3.0 * np.eye(3))
