"""FollowingPipeline: engagement on the first bearing, estimator and control rates, the
HNG clock, the line of sight guidance uses, and argument validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from paper_reference import helical_navigation, range_control

from companion.assembly import vehicle_limits
from interfaces.scenario import table1_vehicle
from companion.core.estimators import UPLKF, GainProjection, InitialGuess
from companion.core.geometry import E_Z, unit
from companion.core.guidance import HelicalNavigationGuidance, RangeController
from companion.core.messages import BearingMeasurement, PursuerState
from companion.core.pipeline import FollowingPipeline

ESTIMATOR_PERIOD = 0.02  # 50 Hz
CONTROL_PERIOD = 0.05  # 20 Hz
STEP = 0.01  # the caller steps at 100 Hz
ENGAGE_TIME = 3.0
GUESS = InitialGuess(range=15.0, range_std=10.0, velocity=np.zeros(3), velocity_std=2.0)
LIMITS = vehicle_limits(table1_vehicle(), 2.0 / 3.0)
G = 9.81

TARGET_START = np.array([20.0, 5.0, -12.0])
TARGET_VELOCITY = np.array([1.0, 0.5, 0.0])
PURSUER_START = np.array([0.0, 0.0, -10.0])
PURSUER_VELOCITY = np.array([1.5, 0.0, -0.2])


def target_at(t: float) -> np.ndarray:
    return TARGET_START + TARGET_VELOCITY * t


def pursuer_at(t: float) -> PursuerState:
    return PursuerState(t, PURSUER_START + PURSUER_VELOCITY * t, PURSUER_VELOCITY.copy())


def bearing_at(t: float) -> BearingMeasurement:
    pursuer = pursuer_at(t).position
    return BearingMeasurement(t, unit(target_at(t) - pursuer), pursuer)


class CountingUPLKF(UPLKF):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.predicts = 0
        self.corrections = 0

    def predict(self) -> None:
        self.predicts += 1
        super().predict()

    def correct(self, bearing):
        self.corrections += 1
        return super().correct(bearing)


class RecordingGuidance:
    """A lateral law that records the clock it is given and commands nothing."""

    def __init__(self) -> None:
        self.calls: list[tuple[float, np.ndarray, np.ndarray, float]] = []

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        assert relative_velocity is not None and relative_velocity.shape == (3,)  # the pipeline always passes it
        self.calls.append((engaged_time, velocity.copy(), los.copy(), range_estimate))
        return np.zeros(3)


def make_pipeline(lateral=None, los_source: str = "estimate", control_period: float = CONTROL_PERIOD) -> FollowingPipeline:
    estimator = CountingUPLKF(
        ESTIMATOR_PERIOD, 0.1 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED
    )
    return FollowingPipeline(
        estimator,
        lateral if lateral is not None else HelicalNavigationGuidance(1.0, 3.5, 3.5),
        RangeController(desired_range=8.0),
        LIMITS,
        GUESS,
        control_period,
        los_source=los_source,
    )


def step_times(start: float, count: int) -> list[float]:
    return [start + k * STEP for k in range(count)]


# --------------------------------------------------------------------------- engagement


def test_no_setpoint_before_the_first_bearing() -> None:
    pipeline = make_pipeline()
    for t in step_times(0.0, 50):
        output = pipeline.step(t, pursuer_at(t))
        assert output.time == t
        assert output.setpoint is None and not output.new_setpoint
        assert output.estimate is None and output.guidance is None and output.correction is None
    assert pipeline.engaged_at is None
    assert not pipeline.estimator.initialized
    assert pipeline.estimator.predicts == 0


def test_first_bearing_initialises_the_estimator_on_the_bearing() -> None:
    pipeline = make_pipeline()
    pipeline.step(ENGAGE_TIME - STEP, pursuer_at(ENGAGE_TIME - STEP))
    bearing = bearing_at(ENGAGE_TIME)
    output = pipeline.step(ENGAGE_TIME, pursuer_at(ENGAGE_TIME), bearing)
    assert pipeline.engaged_at == ENGAGE_TIME
    assert output.correction is None  # the first bearing initialises, it does not correct
    assert pipeline.estimator.corrections == 0 and pipeline.estimator.predicts == 0
    # Remark 3: p_T(0) = p(0) + r(0) lambda~(0).
    assert output.estimate.time == ENGAGE_TIME
    np.testing.assert_allclose(output.estimate.position, bearing.pursuer_position + GUESS.range * bearing.direction)
    # A first setpoint right away, steering along the bearing.
    assert output.new_setpoint and output.setpoint is not None
    assert output.setpoint.time == ENGAGE_TIME
    np.testing.assert_allclose(output.guidance.los, bearing.direction, atol=1e-12)
    assert output.guidance.range_estimate == pytest.approx(GUESS.range)


def test_later_bearings_correct_the_estimator() -> None:
    pipeline = make_pipeline()
    pipeline.step(ENGAGE_TIME, pursuer_at(ENGAGE_TIME), bearing_at(ENGAGE_TIME))
    t = ENGAGE_TIME + 0.04
    output = pipeline.step(t, pursuer_at(t), bearing_at(t))
    assert output.correction is not None and not output.correction.reinitialized
    assert pipeline.estimator.corrections == 1
    output = pipeline.step(t + STEP, pursuer_at(t + STEP))
    assert output.correction is None
    assert pipeline.estimator.corrections == 1


# --------------------------------------------------------------------------- rates


def iter_engaged(pipeline: FollowingPipeline, seconds: float, bearing_every: int = 1):
    """Engage at ENGAGE_TIME, then step at 100 Hz with a bearing every `bearing_every` steps."""
    for k in range(int(round(seconds / STEP)) + 1):
        t = ENGAGE_TIME + k * STEP
        bearing = bearing_at(t) if k % bearing_every == 0 else None
        yield k, t, pipeline.step(t, pursuer_at(t), bearing)


def run_engaged(pipeline: FollowingPipeline, seconds: float, bearing_every: int = 1):
    return list(iter_engaged(pipeline, seconds, bearing_every))


@pytest.mark.parametrize("bearing_every", [1, 3, 1000])
def test_estimator_predicts_at_its_own_period(bearing_every: int) -> None:
    pipeline = make_pipeline()
    for k, t, output in iter_engaged(pipeline, 1.0, bearing_every):
        ticks = k // 2  # 100 Hz steps, 50 Hz estimator
        assert pipeline.estimator.predicts == ticks
        assert output.estimate.time == pytest.approx(ENGAGE_TIME + ticks * ESTIMATOR_PERIOD, abs=1e-9)
        assert output.estimate.time <= t + 1e-9
    assert pipeline.estimator.predicts == 50
    assert pipeline.estimator.corrections == len(range(0, 101, bearing_every)) - 1  # the first one initialised


def test_control_is_recomputed_only_every_control_period() -> None:
    pipeline = make_pipeline()
    outputs = run_engaged(pipeline, 1.0)
    flags = [output.new_setpoint for _, _, output in outputs]
    assert flags == [k % 5 == 0 for k, _, _ in outputs]  # 20 Hz control stepped at 100 Hz
    assert sum(flags) == 21
    last_time = None
    for k, t, output in outputs:
        if output.new_setpoint:
            last_time = t
        # Held between control ticks: the setpoint is the one computed at the last tick.
        assert output.setpoint.time == pytest.approx(last_time)
        assert output.setpoint.time == pytest.approx(ENGAGE_TIME + (k // 5) * CONTROL_PERIOD)


def test_control_and_estimator_catch_up_after_a_gap_without_bursts() -> None:
    pipeline = make_pipeline()
    pipeline.step(ENGAGE_TIME, pursuer_at(ENGAGE_TIME), bearing_at(ENGAGE_TIME))
    t = ENGAGE_TIME + 0.13  # the caller was late: 6 estimator ticks and 2 control ticks missed
    output = pipeline.step(t, pursuer_at(t))
    assert pipeline.estimator.predicts == 6
    assert output.estimate.time == pytest.approx(ENGAGE_TIME + 0.12)
    assert output.new_setpoint and output.setpoint.time == pytest.approx(t)
    # The control grid stays anchored at the engagement time: next tick at +0.15.
    assert not pipeline.step(ENGAGE_TIME + 0.14, pursuer_at(ENGAGE_TIME + 0.14)).new_setpoint
    assert pipeline.step(ENGAGE_TIME + 0.15, pursuer_at(ENGAGE_TIME + 0.15)).new_setpoint


# --------------------------------------------------------------------------- guidance inputs


def test_hng_clock_starts_at_engagement() -> None:
    recorder = RecordingGuidance()
    pipeline = make_pipeline(lateral=recorder)
    for t in step_times(0.0, 30):  # nothing seen yet
        pipeline.step(t, pursuer_at(t))
    outputs = run_engaged(pipeline, 0.5)
    control_times = [t for _, t, output in outputs if output.new_setpoint]
    assert len(recorder.calls) == len(control_times) == 11
    for (engaged_time, velocity, _, _), t in zip(recorder.calls, control_times):
        assert engaged_time == pytest.approx(t - ENGAGE_TIME, abs=1e-12)
        np.testing.assert_array_equal(velocity, PURSUER_VELOCITY)
    assert recorder.calls[0][0] == 0.0


def test_command_is_hng_plus_range_control_on_the_estimated_los() -> None:
    """The terms against the paper, not against the guidance objects the pipeline holds:
    a_HN of eq. (14) and a_RC of eq. (15)-(19) written out in tests/paper_reference.py, their
    geometry (a_HN across the line of sight, a_RC along it), and eq. (13) a_d = a_HN + a_RC."""
    n, c_weave, desired_range, gain = 1.0, 3.5, 8.0, 3.0
    pipeline = make_pipeline(lateral=HelicalNavigationGuidance(n, c_weave, c_weave))
    limited = 0
    for _, t, output in run_engaged(pipeline, 0.6):
        if not output.new_setpoint:
            continue
        pursuer = pursuer_at(t)
        estimate = output.estimate.extrapolated(t)
        dp = estimate.position - pursuer.position
        dv = estimate.velocity - pursuer.velocity
        los = dp / np.linalg.norm(dp)
        terms = output.guidance
        # los_source="estimate": (p^_T - p)/|.| with the estimate carried to the control time.
        np.testing.assert_allclose(terms.los, los, atol=1e-12)
        assert terms.range_estimate == pytest.approx(np.linalg.norm(dp))
        # HNG clock: time since engagement, the paper's sin(t) (w = 1 rad/s).
        lateral = helical_navigation(t - ENGAGE_TIME, pursuer.velocity, los, np.linalg.norm(dp), n, c_weave, c_weave)
        np.testing.assert_allclose(terms.lateral, lateral, atol=1e-9)
        assert terms.lateral @ los == pytest.approx(0.0, abs=1e-12 * max(1.0, np.linalg.norm(terms.lateral)))
        longitudinal = range_control(dp, dv, los, lateral, desired_range, gain)
        np.testing.assert_allclose(terms.longitudinal, longitudinal, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(np.cross(terms.longitudinal, los), np.zeros(3), atol=1e-12 * max(1.0, np.linalg.norm(longitudinal)))
        # a_d = a_HN + a_RC, eq. (13), flown as commanded when flyable, else clipped vertical first
        # with the horizontal direction kept (the limits' own properties are in test_attitude.py).
        command = lateral + longitudinal
        wanted, flown = G * E_Z - command, G * E_Z - output.setpoint.acceleration
        tilt_ok = np.linalg.norm(wanted[:2]) <= wanted[2] * np.tan(LIMITS.max_tilt)
        if tilt_ok and LIMITS.min_vertical_specific_force <= wanted[2] and np.linalg.norm(wanted) <= LIMITS.max_specific_force:
            np.testing.assert_allclose(flown, wanted, atol=1e-9)
        else:
            assert flown[2] == pytest.approx(np.clip(wanted[2], LIMITS.min_vertical_specific_force, LIMITS.max_specific_force))
            assert flown[0] * wanted[1] - flown[1] * wanted[0] == pytest.approx(0.0, abs=1e-9) and flown[:2] @ wanted[:2] >= 0.0
            assert np.linalg.norm(flown[:2]) <= flown[2] * np.tan(LIMITS.max_tilt) + 1e-9
        limited += not np.allclose(flown, wanted, atol=1e-9)
        # The camera (body x) looks along the line of sight used.
        assert output.setpoint.rotation[:, 0] @ los > 0.0
    assert 0 < limited  # the far start asks for more than the airframe gives: the limiting branch is exercised


def test_measurement_los_source_steers_on_the_latest_bearing() -> None:
    pipeline = make_pipeline(los_source="measurement")
    latest = None
    for k, t, output in run_engaged(pipeline, 0.5, bearing_every=3):
        if k % 3 == 0:
            latest = unit(bearing_at(t).direction)
        if output.new_setpoint:
            np.testing.assert_allclose(output.guidance.los, latest, atol=1e-12)


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("source", ["bearing", "", "Estimate", "measured"])
def test_unknown_los_source_is_rejected(source: str) -> None:
    with pytest.raises(ValueError):
        make_pipeline(los_source=source)


@pytest.mark.parametrize("period", [0.0, -0.05])
def test_nonpositive_control_period_is_rejected(period: float) -> None:
    with pytest.raises(ValueError):
        make_pipeline(control_period=period)


def test_step_grid_is_robust_to_float_time_stamps() -> None:
    """Times built by repeated addition (not k * dt) still hit every tick exactly once."""
    pipeline = make_pipeline()
    t = ENGAGE_TIME
    pipeline.step(t, pursuer_at(t), bearing_at(t))
    setpoints = 1
    for _ in range(200):
        t += STEP
        setpoints += pipeline.step(t, pursuer_at(t)).new_setpoint
    assert pipeline.estimator.predicts == 100
    assert setpoints == 41
    assert math.isclose(pipeline.estimator.estimate.time, ENGAGE_TIME + 2.0, abs_tol=1e-9)


def test_step_all_reports_the_setpoint_computed_on_any_of_its_steps():
    """Two bearings in one tick at a control time: the setpoint is computed on the first step and the second
    step computes none; the tick's output must still say a new setpoint came (every harness sends on it), and
    carry the latest one. A caller that read only the last step's flag never sent such setpoints."""
    estimator = UPLKF(ESTIMATOR_PERIOD, 0.04 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED)
    pipeline = FollowingPipeline(estimator, HelicalNavigationGuidance(3.0, 3.5, 3.5), RangeController(8.0), LIMITS,
                                 GUESS, control_period=CONTROL_PERIOD)
    pipeline.step(0.0, pursuer_at(0.0), bearing_at(0.0))
    at = CONTROL_PERIOD
    separate = [pipeline.step(at, pursuer_at(at), bearing_at(at - 0.01)), None]
    separate[1] = pipeline.step(at, pursuer_at(at), bearing_at(at))
    assert separate[0].new_setpoint and not separate[1].new_setpoint  # the situation itself
    at = 2 * CONTROL_PERIOD
    output = pipeline.step_all(at, pursuer_at(at), [bearing_at(at - 0.01), bearing_at(at)])
    assert output.new_setpoint and output.setpoint is not None and output.setpoint.time == pytest.approx(at)
    later = pipeline.step_all(at + 0.01, pursuer_at(at + 0.01), [])
    assert not later.new_setpoint
