"""FollowingPipeline with neighbours: which law flies when, the separation filter last, neighbours
carried to the control time, and a neighbour's bearing never taken as our own line of sight.

References: HNG with c_Z = c_Y = 0 is PPG, a = -N P_lambda v (eq. (14), section VIII-C1), written out here;
the line-of-sight angle between two pursuers is plain geometry; constant-velocity extrapolation p + v dt."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.assembly import vehicle_limits
from companion.core.cooperative_guidance import SeparationFilter
from companion.core.estimators import UPLKF, GainProjection, InitialGuess
from companion.core.geometry import unit
from companion.core.guidance import HelicalNavigationGuidance, PurePursuitGuidance, RangeController
from companion.core.messages import BearingMeasurement, NeighbourState, PursuerState
from companion.core.pipeline import Cooperation, FollowingPipeline
from interfaces.scenario import table1_vehicle

LIMITS = vehicle_limits(table1_vehicle(), 2.0 / 3.0)
N = 3.0
TARGET = np.array([20.0, 0.0, -10.0])
OWN = PursuerState(0.0, np.array([0.0, 0.0, -10.0]), np.array([2.0, 1.0, 0.0]))


class RecordingLaw:
    """A complete cooperative law that remembers the contexts it was given and commands a fixed acceleration."""

    includes_range_control = True

    def __init__(self, command: np.ndarray) -> None:
        self.command = np.asarray(command, dtype=float)
        self.contexts = []

    def acceleration(self, context) -> np.ndarray:
        self.contexts.append(context)
        return self.command.copy()


def _pipeline(cooperation: Cooperation | None) -> FollowingPipeline:
    estimator = UPLKF(0.02, 0.04 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED)
    return FollowingPipeline(estimator, HelicalNavigationGuidance(N, 3.5, 3.5), RangeController(8.0), LIMITS,
                             InitialGuess(20.0, 1.0, np.zeros(3), 0.1), control_period=0.05, cooperation=cooperation)


def _engage(pipeline: FollowingPipeline) -> None:
    pipeline.step(0.0, OWN, BearingMeasurement(0.0, unit(TARGET - OWN.position), OWN.position))


def _neighbour_at(angle_deg: float, ident: int = 2, time: float = 0.0) -> NeighbourState:
    """A neighbour 20 m from the target whose line of sight makes `angle_deg` with ours (in the horizontal plane)."""
    ours = unit(TARGET - OWN.position)
    angle = math.radians(angle_deg)
    rotated = np.array([ours[0] * math.cos(angle) - ours[1] * math.sin(angle),
                        ours[0] * math.sin(angle) + ours[1] * math.cos(angle), 0.0])
    return NeighbourState(ident, time, TARGET - 20.0 * rotated, np.zeros(3))


def test_the_weave_is_off_while_a_neighbour_gives_a_baseline_and_comes_back_without_one():
    pipeline = _pipeline(Cooperation(weave_min_angle=math.radians(15.0), steady_guidance=PurePursuitGuidance(N)))
    _engage(pipeline)
    assert pipeline.weaving and pipeline.law_changes == []

    pipeline.set_neighbours([_neighbour_at(60.0)])
    pipeline.step(0.05, PursuerState(0.05, OWN.position, OWN.velocity))
    assert not pipeline.weaving and pipeline.law_changes[-1] == (0.05, "steady")
    los = pipeline._guidance.los
    across = np.eye(3) - np.outer(los, los)
    np.testing.assert_allclose(pipeline._guidance.lateral, -N * across @ OWN.velocity, atol=1e-12)  # PPG

    # A neighbour on the other side of the target sees it along the same line: no baseline, the weave returns.
    pipeline.set_neighbours([_neighbour_at(180.0)])
    pipeline.step(0.10, PursuerState(0.10, OWN.position, OWN.velocity))
    assert pipeline.weaving and pipeline.law_changes[-1] == (0.10, "single")
    pipeline.set_neighbours([_neighbour_at(10.0)])  # below the 15 degree threshold
    pipeline.step(0.15, PursuerState(0.15, OWN.position, OWN.velocity))
    assert pipeline.weaving
    pipeline.set_neighbours(())
    pipeline.step(0.20, PursuerState(0.20, OWN.position, OWN.velocity))
    assert pipeline.weaving and [law for _, law in pipeline.law_changes] == ["steady", "single"]


def test_a_cooperative_law_flies_only_while_a_neighbour_is_fresh_and_sees_it_at_the_control_time():
    law = RecordingLaw([0.5, -0.25, 0.0])
    pipeline = _pipeline(Cooperation(law=law))
    _engage(pipeline)
    assert not law.contexts and not pipeline.cooperating  # alone: the single-pursuer laws
    neighbour = NeighbourState(2, 0.0, np.array([30.0, 10.0, -10.0]), np.array([1.0, -2.0, 0.5]))
    pipeline.set_neighbours([neighbour])
    pipeline.step(0.05, PursuerState(0.05, OWN.position, OWN.velocity))
    assert pipeline.cooperating and len(law.contexts) == 1
    seen = law.contexts[0].neighbours[0]
    np.testing.assert_allclose(seen.position, neighbour.position + 0.05 * neighbour.velocity, atol=1e-12)
    assert seen.time == pytest.approx(0.05)
    np.testing.assert_allclose(pipeline._guidance.longitudinal, np.zeros(3))  # a complete law: no range controller
    pipeline.set_neighbours(())
    pipeline.step(0.10, PursuerState(0.10, OWN.position, OWN.velocity))
    assert not pipeline.cooperating and len(law.contexts) == 1
    assert [law_name for _, law_name in pipeline.law_changes] == ["cooperative", "single"]


def test_the_separation_filter_has_the_last_word():
    """A law that drives straight at a neighbour 2.5 m ahead (min separation 2 m): the command that reaches the
    attitude mapping brakes towards it instead (SeparationFilter's constraint: along n at most -a_b)."""
    ahead = unit(np.array([1.0, 0.0, 0.0]))
    law = RecordingLaw(3.0 * ahead)
    separation = SeparationFilter(2.0, braking_acceleration=3.0, max_acceleration=6.0)
    pipeline = _pipeline(Cooperation(law=law, separation=separation))
    _engage(pipeline)
    neighbour = NeighbourState(2, 0.05, OWN.position + 2.5 * ahead, np.zeros(3))
    pipeline.set_neighbours([neighbour])
    output = pipeline.step(0.05, PursuerState(0.05, OWN.position, OWN.velocity))
    assert output.new_setpoint
    assert float(output.setpoint.acceleration @ ahead) <= -3.0 + 1e-6


def test_a_neighbours_bearing_corrects_the_estimate_but_is_not_our_line_of_sight():
    pipeline = _pipeline(None)
    pipeline.los_source = "measurement"
    _engage(pipeline)
    own_bearing = pipeline._last_bearing.copy()
    other = np.array([20.0, -20.0, -10.0])
    estimate_before = pipeline.estimator.estimate.position.copy()
    output = pipeline.step(0.02, PursuerState(0.02, OWN.position, OWN.velocity),
                           BearingMeasurement(0.02, unit(TARGET + np.array([1.0, 0.0, 0.0]) - other), other, source=2))
    assert output.correction is not None  # used by the estimator
    assert not np.allclose(pipeline.estimator.estimate.position, estimate_before)
    np.testing.assert_array_equal(pipeline._last_bearing, own_bearing)


def test_a_pursuer_that_hears_nobody_flies_the_cooperative_law_on_its_own_layer():
    """Pursuer k of a cooperative flight alone (its share link down): the same law on an orbit 1.5 x
    min_separation x k larger (assembly.build_cooperation), so that it stays clear of the others' circle
    (which it cannot see, nor they it); with a neighbour again, the common orbit."""
    from companion.assembly import LONE_LAYER, build_cooperation
    from interfaces.scenario import SCENARIOS_DIR, load_scenario

    scenario, _ = load_scenario(SCENARIOS_DIR / "swarm_circumnavigation.toml")
    for pursuer_id in (1, 2, 3):
        cooperation = build_cooperation(scenario, pursuer_id)
        assert cooperation.lone_law.desired_radius == pytest.approx(
            cooperation.law.desired_radius + LONE_LAYER * scenario.swarm.min_separation * pursuer_id)
    cooperation = build_cooperation(scenario, 2)
    pipeline = _pipeline(cooperation)
    _engage(pipeline)
    pipeline.step(0.05, PursuerState(0.05, OWN.position, OWN.velocity))
    assert pipeline.law_changes[-1] == (0.0, "lone")  # from the engagement on
    pipeline.set_neighbours([_neighbour_at(120.0)])
    pipeline.step(0.10, PursuerState(0.10, OWN.position, OWN.velocity))
    assert pipeline.law_changes[-1] == (0.10, "cooperative") and pipeline.cooperating


def _brake(pipeline: FollowingPipeline, neighbour: NeighbourState | None, duration: float = 6.0, dt: float = 0.02):
    """Fly stop_setpoint's flown acceleration on a point mass (semi-implicit Euler at dt s) from 6 m/s north at
    10 m height: the own positions and speeds over `duration` s (the neighbour, if any, hovers where it is)."""
    position, velocity = np.array([0.0, 0.0, -10.0]), np.array([6.0, 0.0, 0.0])
    positions, speeds = [position.copy()], [6.0]
    for k in range(int(round(duration / dt))):
        time = k * dt
        pipeline.set_neighbours(() if neighbour is None else (NeighbourState(neighbour.ident, time, neighbour.position,
                                                                             neighbour.velocity),))
        setpoint = pipeline.stop_setpoint(time, PursuerState(time, position.copy(), velocity.copy()))
        assert np.all(np.isfinite(setpoint.rotation)) and 0.0 < setpoint.thrust_normalized <= 1.0
        velocity = velocity + dt * setpoint.acceleration
        position = position + dt * velocity
        positions.append(position.copy())
        speeds.append(float(np.linalg.norm(velocity)))
    return np.array(positions), np.array(speeds)


def test_stop_setpoint_brakes_with_a_one_second_time_constant():
    """Without neighbours the stop is a_d = -k v (k = 1/s): on the Euler-stepped point mass the speed is the closed
    form v0 (1 - k dt)^n, and the pursuer comes to rest after v0 (1 - k dt) (1 - (1 - k dt)^n) / k (about v0 / k =
    6 m) straight on, at its height."""
    from companion.core.pipeline import STOP_GAIN

    positions, speeds = _brake(_pipeline(None), None)
    decay = 1.0 - STOP_GAIN * 0.02
    steps = np.arange(len(speeds))
    np.testing.assert_allclose(speeds, 6.0 * decay**steps, rtol=1e-9)
    assert positions[-1][0] == pytest.approx(6.0 * decay * (1.0 - decay ** steps[-1]) / STOP_GAIN, rel=1e-9)
    assert positions[-1][0] == pytest.approx(6.0 / STOP_GAIN, abs=0.15)
    assert np.max(np.abs(positions[:, 1:] - positions[0, 1:])) < 1e-9


def test_stop_setpoint_does_not_brake_into_a_neighbour():
    """A swarm's end of following: a pursuer braking from 6 m/s toward a pursuer hovering 7.5 m ahead (0.3 m off
    its line) would stop 1.7 m from it on the plain stop (it needs about 6 m); with the separation filter
    (min_separation 2 m; the other not avoiding, so not reciprocal) it never comes within min_separation and still
    comes to rest."""
    neighbour = NeighbourState(2, 0.0, np.array([7.5, 0.3, -10.0]), np.zeros(3))
    separation = SeparationFilter(min_separation=2.0, braking_acceleration=4.0, reciprocal=False)
    plain, _ = _brake(_pipeline(Cooperation()), neighbour)
    assert np.min(np.linalg.norm(plain - neighbour.position, axis=1)) < separation.min_separation
    positions, speeds = _brake(_pipeline(Cooperation(separation=separation)), neighbour)
    assert np.min(np.linalg.norm(positions - neighbour.position, axis=1)) > separation.min_separation
    assert speeds[-1] < 0.3
