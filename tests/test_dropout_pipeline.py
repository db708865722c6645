"""The pipeline through link dropouts: coast, safe behaviour, gated re-acquisition, no command steps.

A point-mass pursuer flies the pipeline's acceleration command exactly (no attitude
dynamics), so what is checked is the pipeline's own logic; bearings (eq. 4 noise) come
at 5 Hz except inside the blackout windows.
"""

from __future__ import annotations

import numpy as np
import pytest

from companion.assembly import vehicle_limits
from interfaces.scenario import table1_vehicle
from companion.core.estimators import GainProjection, InitialGuess, UPLKF
from companion.core.guidance import HelicalNavigationGuidance, RangeController
from companion.core.messages import BearingMeasurement, PursuerState
from companion.core.pipeline import DropoutPolicy, FollowingPipeline, TrackMode

DESIRED = 8.0


def _pipeline(policy: DropoutPolicy | None = None) -> FollowingPipeline:
    estimator = UPLKF(0.02, 0.04 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED, pursuer_position_std=0.0)
    return FollowingPipeline(estimator, HelicalNavigationGuidance(3.0, 3.5, 3.5), RangeController(DESIRED),
                             vehicle_limits(table1_vehicle(), 1.0 / 1.5), InitialGuess(50.0, 30.0, np.zeros(3), 5.0), 0.05, dropout=policy)


def fly(blackouts=(), duration=60.0, target_turn_at=None, seed=3, policy=None):
    """Run the loop; returns per-step records and the pipeline."""
    rng = np.random.default_rng(seed)
    pipeline = _pipeline(policy)
    p, v = np.zeros(3), np.array([2.0, 0.0, 0.0])
    target, target_velocity = np.array([50.0, -25.0, -20.0]), np.array([3.0, 4.0, 0.0])
    dt = 0.02
    records = []
    command = np.zeros(3)
    for k in range(int(duration / dt) + 1):
        t = k * dt
        bearing = None
        if k % 10 == 0 and not any(start <= t < start + length for start, length in blackouts):
            los = (target - p) / np.linalg.norm(target - p)
            bearing = BearingMeasurement(t, los + rng.normal(0.0, 0.01, 3), p.copy())
        output = pipeline.step(t, PursuerState(t, p.copy(), v.copy()), bearing)
        if output.setpoint is not None:
            command = output.setpoint.acceleration
        estimate = output.estimate
        records.append({
            "time": t, "mode": output.mode, "range": float(np.linalg.norm(target - p)),
            "range_error": float(np.linalg.norm(estimate.position - p) - np.linalg.norm(target - p)) if estimate else np.nan,
            "command": command.copy(), "new": output.new_setpoint, "reinitialized": output.reinitialized,
            "gated_out": output.gated_out,
        })
        v = v + command * dt
        p = p + v * dt
        if target_turn_at is not None and abs(t - target_turn_at) < dt / 2:
            target_velocity = np.array([-4.0, 3.0, 0.0])  # a sharp unannounced turn, inside a blackout
        target = target + target_velocity * dt
    return records, pipeline


def _modes_between(records, start, stop):
    return {r["mode"] for r in records if start <= r["time"] < stop}


def test_no_dropout_means_always_tracking_and_unchanged_behaviour():
    records, pipeline = fly(duration=40.0)
    assert {r["mode"] for r in records} == {TrackMode.TRACKING}
    assert pipeline.mode_changes == [] and pipeline.reinitializations == 0
    assert abs(records[-1]["range_error"]) < 0.5 and abs(records[-1]["range"] - DESIRED) < 0.5


def test_short_blackout_coasts_and_comes_back_without_restart():
    records, pipeline = fly(blackouts=[(30.0, 2.0)], duration=45.0)
    assert TrackMode.COASTING in _modes_between(records, 30.7, 32.0)
    assert TrackMode.DEGRADED not in {r["mode"] for r in records}
    assert _modes_between(records, 33.0, 45.0) == {TrackMode.TRACKING}
    assert pipeline.reinitializations == 0
    assert max(abs(r["range_error"]) for r in records if r["time"] > 34.0) < 1.0


def test_long_blackout_switches_to_the_safe_behaviour_and_never_closes_in():
    policy = DropoutPolicy(safe_range=12.0, min_range=4.0)
    records, pipeline = fly(blackouts=[(30.0, 10.0)], duration=55.0, policy=policy)
    degraded = [r for r in records if r["mode"] == TrackMode.DEGRADED]
    assert degraded and min(r["time"] for r in degraded) == pytest.approx(30.0 + policy.coast_limit, abs=0.25)
    assert min(r["range"] for r in records if r["time"] > 25.0) > policy.min_range
    # It backs off towards the safe range while blind.
    assert np.mean([r["range"] for r in degraded[-25:]]) > DESIRED + 1.0
    # and returns to following with a small error within 10 s of the link coming back.
    back = [r for r in records if r["time"] > 40.0 + 10.0]
    assert {r["mode"] for r in back} == {TrackMode.TRACKING}
    assert max(abs(r["range_error"]) for r in back) < 1.0


def test_a_target_that_turned_during_the_blackout_is_reacquired_by_restarting_on_the_bearing():
    records, pipeline = fly(blackouts=[(30.0, 8.0)], duration=60.0, target_turn_at=31.0)
    assert any(r["gated_out"] for r in records if 38.0 <= r["time"] < 40.0)
    assert pipeline.reinitializations >= 1
    assert TrackMode.REACQUIRING in {mode for _, mode in pipeline.mode_changes}
    late = [r for r in records if r["time"] > 50.0]
    assert {r["mode"] for r in late} == {TrackMode.TRACKING}
    assert max(abs(r["range_error"]) for r in late) < 1.0


def test_the_command_never_steps_faster_than_the_jerk_limit_after_a_mode_change():
    policy = DropoutPolicy(safe_range=12.0, min_range=4.0, max_jerk=15.0, blend_time=2.0)
    records, pipeline = fly(blackouts=[(30.0, 6.0)], duration=45.0, policy=policy, target_turn_at=31.0)
    limit = policy.max_jerk * 0.05 + 1e-9
    changes = [t for t, _ in pipeline.mode_changes]
    commands = [(r["time"], r["command"]) for r in records if r["new"]]
    checked = 0
    for (t0, a0), (t1, a1) in zip(commands, commands[1:]):
        if any(change <= t1 < change + policy.blend_time for change in changes):
            assert np.linalg.norm(a1 - a0) <= limit, (t1, np.linalg.norm(a1 - a0))
            checked += 1
    assert checked > 20
