"""BearingBuilder: a target fix + the own-state history -> the bearing at the fix stamp (section IX-A)."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, nonzero_vectors
from scipy.spatial.transform import Rotation

from companion.assembly import build_sensor
from companion.core.bearing_builder import BearingBuilder, BuildFailure, BuildResult
from companion.core.bearing_sensor import CameraModel
from interfaces.scenario import SensorConfig
from companion.core.messages import BearingMeasurement
from companion.core.state_history import StateHistory

SPEED = 15.0  # m/s, a fast pursuer heading east
YAW_RATE = 2.0  # rad/s, turning right
NEWEST = 2.0  # s, the latest odometry sample
STAMP = 1.87  # s, the fix stamp: between two 50 Hz samples, 0.13 s of link latency


def _position(time: float) -> np.ndarray:
    return np.array([1.0, -5.0 + SPEED * time, -20.0])


def _yaw(time: float) -> float:
    return -1.0 + YAW_RATE * time


def _attitude(time: float) -> np.ndarray:
    return Rotation.from_euler("ZYX", [_yaw(time), 0.1, 0.0]).as_matrix()


def _history() -> StateHistory:
    history = StateHistory(max_age_s=1.0)
    for time in np.arange(0.0, NEWEST + 1e-9, 0.02):
        history.append(time, _position(time), np.array([0.0, SPEED, 0.0]), _attitude(time))
    return history


def _builder(seed: int = 0, history: StateHistory | None = None, **sensor) -> BearingBuilder:
    return BearingBuilder(build_sensor(SensorConfig(**sensor)), np.random.default_rng(seed), _history() if history is None else history)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b))


TARGET = _position(STAMP) + np.array([8.0, 0.0, 0.0])  # 8 m north of where the pursuer was at the stamp


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["additive", "rotation"]), floats(1.05, NEWEST + 0.1), nonzero_vectors(50.0, min_norm=1.0))
def test_noise_free_bearing_is_the_line_of_sight_at_any_fix_stamp(model, stamp, offset):
    """Any stamp inside the kept second of history (or up to the 0.1 s extrapolation), any target
    at least 1 m away: the bearing is the line of sight from where the pursuer was at that stamp."""
    target = _position(stamp) + offset
    result = _builder(model=model, noise_std=0.0).build(target, stamp)
    assert result.reason is None
    true_los = offset / np.linalg.norm(offset)
    np.testing.assert_allclose(result.bearing.direction, true_los, atol=1e-9)
    np.testing.assert_allclose(result.true_line_of_sight, true_los, atol=1e-9)
    np.testing.assert_allclose(result.bearing.pursuer_position, _position(stamp), atol=1e-9)
    assert result.bearing.time == stamp


def test_the_bearing_is_not_taken_from_the_latest_odometry():
    result = _builder(model="additive", noise_std=0.0).build(TARGET, STAMP)
    # Using the latest odometry instead (1.95 m further east) would be off by ~14 deg.
    stale = (TARGET - _position(NEWEST)) / np.linalg.norm(TARGET - _position(NEWEST))
    assert math.degrees(_angle(result.bearing.direction, stale)) == pytest.approx(math.degrees(math.atan2(SPEED * (NEWEST - STAMP), 8.0)), abs=1e-6)
    assert math.degrees(_angle(result.bearing.direction, stale)) > 10.0


def test_noise_free_camera_bearing_is_within_half_a_pixel():
    target = _position(STAMP) + 8.0 * _attitude(STAMP) @ np.array([1.0, 0.2, -0.1])
    result = _builder(model="camera", camera={"pixel_noise_std": 0.0}).build(target, STAMP)
    assert result.reason is None
    assert _angle(result.bearing.direction, result.true_line_of_sight) <= math.sqrt(0.5) * CameraModel().pixel_angle
    np.testing.assert_allclose(result.bearing.pursuer_position, _position(STAMP), atol=1e-12)


def test_camera_uses_the_attitude_at_the_fix_stamp():
    """The pursuer turns 1 rad between the stamp and its latest sample: only the stamp's attitude is right."""
    stamp = NEWEST - 0.5
    camera = CameraModel()
    ahead_then = _position(stamp) + 8.0 * _attitude(stamp)[:, 0]
    seen = _builder(model="camera").build(ahead_then, stamp)
    assert seen.reason is None
    assert _angle(seen.bearing.direction, seen.true_line_of_sight) < 10 * camera.pixel_angle
    assert camera.project(seen.true_line_of_sight, _attitude(NEWEST)) is None  # the latest attitude would have lost it
    ahead_now = _position(stamp) + 8.0 * _attitude(NEWEST)[:, 0]
    missed = _builder(model="camera").build(ahead_now, stamp)
    assert missed.bearing is None and missed.reason == "out_of_view"
    np.testing.assert_allclose(missed.true_line_of_sight, _attitude(NEWEST)[:, 0], atol=1e-12)


def test_no_own_state_reasons():
    empty = _builder(history=StateHistory(1.0)).build(TARGET, STAMP)
    assert empty == BuildResult(None, BuildFailure.NO_OWN_STATE, None)
    builder = _builder()
    for stamp in (NEWEST - 1.5, NEWEST + 0.2):  # older than the kept history; beyond the 0.1 s extrapolation
        result = builder.build(TARGET, stamp)
        assert result.bearing is None and result.reason == "no_own_state" and result.true_line_of_sight is None
    assert builder.build(TARGET, NEWEST + 0.05).reason is None  # short extrapolation is fine


def test_too_close_reason():
    builder = BearingBuilder(build_sensor(SensorConfig()), np.random.default_rng(0), _history(), min_range=0.5)
    result = builder.build(_position(STAMP) + np.array([0.3, 0.0, 0.2]), STAMP)
    assert result.bearing is None and result.reason == BuildFailure.TOO_CLOSE and result.true_line_of_sight is None
    assert builder.build(_position(STAMP) + np.array([0.6, 0.0, 0.0]), STAMP).reason is None
    assert builder.build(_position(STAMP), STAMP).reason == "too_close"


def test_out_of_view_reason_behind_the_camera():
    behind = _position(STAMP) - 8.0 * _attitude(STAMP)[:, 0]
    result = _builder(model="camera").build(behind, STAMP)
    assert result.bearing is None and result.reason == "out_of_view"
    assert _builder(model="additive").build(behind, STAMP).reason is None  # only the camera has a field of view


def test_additive_and_rotation_noise_statistics():
    true_los = (TARGET - _position(STAMP)) / np.linalg.norm(TARGET - _position(STAMP))
    additive = _builder(seed=31, model="additive", noise_std=0.01)
    errors = np.array([additive.build(TARGET, STAMP).bearing.direction - true_los for _ in range(4000)])
    np.testing.assert_allclose(errors.mean(axis=0), 0.0, atol=0.001)
    np.testing.assert_allclose(errors.std(axis=0), 0.01, rtol=0.05)
    rotation = _builder(seed=32, model="rotation", noise_std=0.01)
    angles = np.array([_angle(rotation.build(TARGET, STAMP).bearing.direction, true_los) for _ in range(4000)])
    assert math.sqrt(float(np.mean(angles**2))) == pytest.approx(0.01, rel=0.05)


def test_same_seed_same_bearings():
    first = [_builder(seed=5, model="camera").build(TARGET, STAMP - 0.01 * k).bearing for k in range(5)]
    second = [_builder(seed=5, model="camera").build(TARGET, STAMP - 0.01 * k).bearing for k in range(5)]
    for a, b in zip(first, second):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a.direction, b.direction)


def test_only_the_bearing_leaves_the_builder():
    """No range goes towards the estimator unless a range sensor is configured, and the truth never does:
    the outputs carry directions and the own position only."""
    assert {field.name for field in dataclasses.fields(BuildResult)} == {"bearing", "reason", "true_line_of_sight"}
    assert {field.name for field in dataclasses.fields(BearingMeasurement)} == {
        "time", "direction", "pursuer_position", "range", "true_direction", "source"}
    result = _builder(model="additive", noise_std=0.0).build(_position(STAMP) + np.array([30.0, 40.0, 0.0]), STAMP)
    assert result.bearing.range is None and result.bearing.true_direction is None
    assert result.bearing.source == 0  # the own sensor's
    assert np.linalg.norm(result.bearing.direction) == pytest.approx(1.0)  # a direction, not the 50 m offset
    assert np.linalg.norm(result.true_line_of_sight) == pytest.approx(1.0)


@pytest.mark.parametrize("target, stamp", [(np.zeros(2), 1.0), (np.array([0.0, math.nan, 0.0]), 1.0), (np.zeros(3), math.inf)])
def test_malformed_fixes_raise(target, stamp):
    with pytest.raises(ValueError, match="target fix"):
        _builder().build(target, stamp)


def test_negative_min_range_is_rejected():
    with pytest.raises(ValueError, match="min_range"):
        BearingBuilder(build_sensor(SensorConfig()), np.random.default_rng(0), _history(), min_range=-1.0)


def test_a_configured_range_sensor_adds_a_noisy_range_and_keeps_the_bearing_noise():
    """Seed 003's measurement set in the companion: range = |p_T - p| + N(0, range_noise_std^2)."""
    target = _position(STAMP) + np.array([30.0, 40.0, 0.0])
    plain = _builder(seed=9, model="additive", noise_std=0.01)
    ranged = _builder(seed=9, model="additive", noise_std=0.01, range_noise_std=0.5)
    ranges = []
    for _ in range(400):
        a, b = plain.build(target, STAMP).bearing, ranged.build(target, STAMP).bearing
        np.testing.assert_array_equal(a.direction, b.direction)  # the range noise has its own stream
        ranges.append(b.range)
    assert abs(np.mean(ranges) - 50.0) < 0.1 and 0.4 < np.std(ranges) < 0.6
