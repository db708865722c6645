"""Values computed once and shared within a step are the values each reader computed for itself.

- BearingMeasurement.unit_direction: the estimator, the health monitor, the windowed FIM and the track read
  one unit bearing per bearing; it is geometry.unit's, bit for bit, and a bad direction still raises;
- FollowingPipeline._estimate_at: a bearing's FIM, health check and setpoint share one extrapolated estimate;
  it is TargetEstimate.extrapolated's, bit for bit, and a new one as soon as the estimate changes;
- TargetEstimate.position_std is computed once per snapshot: np.trace's float (test_estimator_kernels.py
  checks the sum itself; here, that the cached value is that of the covariance it was built with);
- the in-process simulator's finiteness check adds three floats as ndarray.sum does (left to right), so
  it calls an estimate non-finite exactly when numpy's sum overflowed or met a NaN.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from bitwise import assert_same, seeds
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from companion.assembly import build_pipeline
from companion.core.geometry import unit
from companion.core.messages import BearingMeasurement, PursuerState, TargetEstimate
from interfaces.scenario import load_scenario
from studies.closed_loop import _sum3

SCENARIO = Path(__file__).resolve().parent.parent / "config" / "scenarios" / "constant_velocity.toml"
finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@given(arrays(np.float64, 3, elements=finite))
def test_the_shared_unit_bearing_is_units(direction):
    bearing = BearingMeasurement(0.0, direction, np.zeros(3))
    try:
        expected = unit(direction)
    except ValueError:  # zero, or so small that its square underflows
        with pytest.raises(ValueError):
            bearing.unit_direction
        return
    assert_same(bearing.unit_direction, expected)
    assert bearing.unit_direction is bearing.unit_direction  # once per bearing
    if float(direction @ direction) > 1e-300:  # (a subnormal square loses digits: unit() is then only near 1)
        assert math.isclose(float(np.linalg.norm(bearing.unit_direction)), 1.0, rel_tol=1e-12)


@pytest.mark.parametrize("bad", [np.zeros(3), np.array([np.nan, 0.0, 1.0]), np.array([np.inf, 0.0, 0.0])])
def test_a_bad_bearing_direction_still_raises_every_time(bad):
    bearing = BearingMeasurement(0.0, bad, np.zeros(3))
    for _ in range(2):  # a failure is not cached as a value
        with pytest.raises(ValueError):
            bearing.unit_direction


@settings(max_examples=100, deadline=None)
@given(seeds, st.integers(-8, 8))
def test_the_cached_position_std_is_that_of_its_covariance(seed, exponent):
    covariance = np.random.default_rng(seed).standard_normal((6, 6)) * 10.0**exponent
    estimate = TargetEstimate(1.0, np.zeros(3), np.zeros(3), covariance)
    expected = math.sqrt(max(float(np.trace(covariance[:3, :3])), 0.0) / 3.0)
    assert estimate.position_std == expected
    assert estimate.position_std == expected  # read twice: the same


@given(arrays(np.float64, 3, elements=st.floats(allow_nan=True, allow_infinity=True, width=64)))
def test_the_finiteness_sum_is_numpys(values):
    total = _sum3(values.tolist())
    with np.errstate(over="ignore", invalid="ignore"):
        expected = values.sum()
    assert math.isfinite(total) == bool(np.isfinite(expected))
    if math.isfinite(total):
        assert total == float(expected)


def test_overflow_depends_on_the_order_and_the_check_keeps_numpys():
    values = np.array([1e308, 1e308, -1e308])  # left to right overflows; the other grouping would not
    with np.errstate(over="ignore"):
        assert not np.isfinite(values.sum())
    assert not math.isfinite(_sum3(values.tolist()))


@settings(max_examples=25, deadline=None)
@given(seeds, st.lists(st.sampled_from(["bearing", "late", "tick", "read"]), min_size=1, max_size=25))
def test_the_shared_extrapolation_is_the_estimates_and_follows_it(seed, actions):
    """After any sequence of ticks, bearings (on time and late) and reads, _estimate_at(t) is
    estimator.estimate.extrapolated(t) bit for bit: never an extrapolation of an older estimate."""
    scenario, vehicle = load_scenario(SCENARIO)
    pipeline = build_pipeline(scenario, vehicle, 2.0 / 3.0)
    rng = np.random.default_rng(seed)
    target = np.array([30.0, -10.0, -5.0])
    time = 0.0

    def bearing_at(stamp: float) -> BearingMeasurement:
        direction = target - np.zeros(3) + rng.normal(0.0, 0.3, 3)
        return BearingMeasurement(stamp, direction / np.linalg.norm(direction) + rng.normal(0.0, 0.01, 3), np.zeros(3))

    pipeline.step(time, PursuerState(time, np.zeros(3), np.zeros(3)), bearing_at(time))
    for action in actions:
        if action in ("bearing", "tick"):
            time += 0.02
        bearing = {"bearing": bearing_at(time), "late": bearing_at(time - 0.013)}.get(action)
        if action != "read":
            pipeline.step(time, PursuerState(time, np.zeros(3), np.zeros(3)), bearing)
        # a fixed stamp first and last: after a change of the estimate, the first question is the old one
        for stamp in (0.5, time, time - 0.013, 0.5):
            shared = pipeline._estimate_at(stamp)
            fresh = pipeline.estimator.estimate.extrapolated(stamp)
            assert shared.time == fresh.time
            assert_same(shared.position, fresh.position)
            assert_same(shared.velocity, fresh.velocity)
            assert_same(shared.covariance, fresh.covariance)


def test_once_property_computes_on_the_first_read_only():
    from companion.core.messages import once_property

    class Message:
        calls = 0

        @once_property
        def value(self):
            """doc"""
            Message.calls += 1
            return [Message.calls]

    first, second = Message(), Message()
    assert first.value is first.value and first.value == [1]  # computed once, then the stored object
    assert second.value == [2]  # per instance
    assert Message.calls == 2 and Message.value.__doc__ == "doc" and isinstance(Message.value, once_property)


def test_fast_frozen_builds_what_each_constructor_builds():
    """Every message the pipeline builds with messages.fast_frozen, against its dataclass constructor: no
    __post_init__ (which fast_frozen would skip), the same fields and values, equal, and still frozen."""
    import dataclasses

    from companion.core.estimators import CorrectionReport
    from companion.core.health import HealthReport, HealthState
    from companion.core.messages import AttitudeSetpoint, fast_frozen
    from companion.core.pipeline import GuidanceTerms, PipelineOutput, TrackMode

    vector = np.array([1.0, -2.0, 0.5])
    samples = {
        AttitudeSetpoint: dict(time=1.0, rotation=np.eye(3), thrust_normalized=0.5, thrust=9.8, acceleration=vector),
        CorrectionReport: dict(innovation_angle=0.1, used_predicted_projection=True, reinitialized=False,
                               innovation=vector, innovation_covariance=np.eye(3), innovation_dof=2),
        HealthReport: dict(time=1.0, state=HealthState.OK, reasons=(), raised=(), nis=1.0, nis_ratio=0.5,
                           range_estimate=8.0, relative_range_std=0.1),
        TargetEstimate: dict(time=1.0, position=vector, velocity=vector, covariance=np.eye(6)),
        GuidanceTerms: dict(lateral=vector, longitudinal=vector, los=vector, range_estimate=8.0),
    }
    samples[PipelineOutput] = {field.name: None for field in dataclasses.fields(PipelineOutput)} | {
        "time": 1.0, "new_setpoint": False, "mode": TrackMode.TRACKING}
    for cls, values in samples.items():
        assert "__post_init__" not in vars(cls), cls
        assert set(values) == {field.name for field in dataclasses.fields(cls)}, cls
        built, constructed = fast_frozen(cls, **values), cls(**values)
        assert type(built) is cls and vars(built).keys() == vars(constructed).keys()
        for name in values:
            assert getattr(built, name) is getattr(constructed, name)
        assert fast_frozen(cls, values.items()).__dict__ == built.__dict__
        with pytest.raises(dataclasses.FrozenInstanceError):
            built.time = 2.0


@pytest.mark.parametrize("helper", ["pipeline._output", "health._health_report"])
def test_the_message_helpers_are_the_constructors_with_the_same_arguments(helper):
    """pipeline._output(values) builds PipelineOutput(*values), health._health_report(values) HealthReport(*values):
    the same fields in the dataclass's order (a helper whose parameters were in another order, or missed a field
    added to the class, would fail here)."""
    import dataclasses
    import importlib
    import inspect

    module_name, function_name = helper.split(".")
    module = importlib.import_module(f"companion.core.{module_name}")
    function = getattr(module, function_name)
    cls = inspect.signature(function).return_annotation
    cls = getattr(module, cls) if isinstance(cls, str) else cls
    names = [field.name for field in dataclasses.fields(cls)]
    assert list(inspect.signature(function).parameters) == names
    values = [object() for _ in names]  # distinct objects: any mix-up of two fields shows
    parameters = inspect.signature(function).parameters.values()
    positional = [value for p, value in zip(parameters, values) if p.kind is not p.KEYWORD_ONLY]
    keywords = {p.name: value for p, value in zip(parameters, values) if p.kind is p.KEYWORD_ONLY}
    built, constructed = function(*positional, **keywords), cls(*values)
    assert type(built) is cls and vars(built).keys() == vars(constructed).keys()
    for name in names:
        assert getattr(built, name) is getattr(constructed, name)
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.time = 2.0


def test_a_policy_that_only_reports_decides_off_every_time():
    """With act off, decide gives ActionDecision(OFF) (boost 1, no restart, no excitation) whatever the verdict, and
    keeps no count of episodes (the shared decision it returns is the value the constructor gives)."""
    from companion.core.health import (ActionDecision, HealthAction, HealthActionConfig, HealthActionPolicy,
                                       HealthReport, HealthState)

    policy = HealthActionPolicy(HealthActionConfig(act=False))
    for time, state, reasons in ((1.0, HealthState.OK, ()), (2.0, HealthState.SUSPECT, ("range_implausible",)),
                                 (3.0, HealthState.SUSPECT, ("behind_sensor",)), (4.0, HealthState.OK, ())):
        report = HealthReport(time, state, reasons, reasons)
        assert policy.decide(report) == ActionDecision(HealthAction.OFF)
        assert policy.decide(report, estimator_restarted=True) == ActionDecision(HealthAction.OFF, 1.0, False, False)
    assert policy.episodes == 0 and policy.recoveries == 0 and policy.reinitialize_times == []
