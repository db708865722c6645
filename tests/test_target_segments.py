"""[target] segments (sitl_plant.world.target.SegmentTarget) against closed-form kinematics written here.

References independent of the code under test: constant-acceleration kinematics (distance (v1^2 - v0^2) / (2 a)
along a straight speed change, the mean velocity (v0 + v1) / 2 over a constant-acceleration change), circle
geometry (a turn at rate w keeps the speed, rotates the velocity by w T and stays on the circle of radius v / |w|
about the centre on its normal), finite differences of the propagated states, and the hand-computed track of a
scenario flown end to end in the in-process simulator.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from interfaces.scenario import SCENARIOS_DIR, Scenario, TargetConfig, load_scenario
from sitl_plant.world.target import SegmentTarget, target_from_config
from studies.closed_loop import simulate

START = [10.0, -5.0, -20.0]
H = 1e-5  # s, finite-difference step


def _config(segments: list[dict], velocity=(0.0, 0.0, 0.0)) -> TargetConfig:
    return TargetConfig.model_validate({"initial_position": START, "initial_velocity": list(velocity), "segments": segments})


def _target(segments: list[dict], velocity=(0.0, 0.0, 0.0)) -> SegmentTarget:
    model = target_from_config(_config(segments, velocity), 0)
    assert isinstance(model, SegmentTarget)
    return model


def _at(segments: list[dict], time: float, velocity=(0.0, 0.0, 0.0)) -> SegmentTarget:
    model = _target(segments, velocity)
    model.advance_to(time)
    return model


unit_directions = st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)).filter(
    lambda v: math.sqrt(sum(c * c for c in v)) > 0.1).map(lambda v: np.array(v) / math.sqrt(sum(c * c for c in v)))
accelerations = st.floats(0.2, 5.0)


# --- each kind against its closed form -------------------------------------------------------------------------------

def test_hover_holds_the_position_exactly_and_acceleration_is_right_continuous():
    segments = [{"kind": "hover", "duration": 5.0}, {"kind": "accelerate", "velocity": [4.0, 0.0, 0.0], "max_acceleration": 2.0}]
    model = _target(segments)
    for time in (0.1, 2.5, 4.999999):
        model.advance_to(time)
        assert model.position.tolist() == START and model.velocity.tolist() == [0.0, 0.0, 0.0]
        assert model.acceleration.tolist() == [0.0, 0.0, 0.0]
    model.advance_to(5.0)
    assert model.position.tolist() == START
    assert model.acceleration.tolist() == [2.0, 0.0, 0.0]  # the accelerate holds from its start on


@settings(max_examples=60, deadline=None)
@given(direction=unit_directions, v0=st.floats(0.0, 10.0), gain=st.floats(0.5, 10.0), a=accelerations,
       cruise=st.floats(0.1, 10.0))
def test_a_straight_speed_change_covers_v1_squared_minus_v0_squared_over_2a(direction, v0, gain, a, cruise):
    v1 = v0 + gain
    segments = [{"kind": "accelerate", "velocity": (v1 * direction).tolist(), "max_acceleration": a},
                {"kind": "cruise", "duration": cruise}]
    reach = gain / a
    model = _at(segments, reach, velocity=(v0 * direction).tolist())
    distance = (v1**2 - v0**2) / (2.0 * a)
    assert np.allclose(model.position, np.array(START) + distance * direction, rtol=0, atol=1e-9 * (1 + distance))
    assert np.allclose(model.velocity, v1 * direction, rtol=0, atol=1e-12 * (1 + v1))
    model.advance_to(reach + cruise)
    assert np.allclose(model.position, np.array(START) + (distance + v1 * cruise) * direction, rtol=0,
                       atol=1e-9 * (1 + distance + v1 * cruise))


@settings(max_examples=60, deadline=None)
@given(v0=st.tuples(*[st.floats(-10.0, 10.0)] * 3), v1=st.tuples(*[st.floats(-10.0, 10.0)] * 3), a=accelerations,
       extra=st.floats(0.0, 5.0))
def test_any_velocity_change_flies_the_mean_velocity_and_a_given_duration_holds_the_new_one(v0, v1, a, extra):
    v0, v1 = np.array(v0), np.array(v1)
    change = float(np.linalg.norm(v1 - v0))
    assume(change > 1e-3)
    takes = change / a
    segments = [{"kind": "accelerate", "velocity": v1.tolist(), "max_acceleration": a, "duration": takes + extra}]
    model = _at(segments, takes, velocity=v0.tolist())
    assert np.allclose(model.position, np.array(START) + 0.5 * (v0 + v1) * takes, rtol=0, atol=1e-9 * (1 + 10 * takes))
    assert np.allclose(model.velocity, v1, rtol=0, atol=1e-12 * (1 + change))
    model.advance_to(takes + extra + 3.0)  # the duration's rest, then the final velocity held
    assert np.allclose(model.position, np.array(START) + 0.5 * (v0 + v1) * takes + v1 * (extra + 3.0), rtol=0,
                       atol=1e-9 * (1 + 10 * (takes + extra + 3.0)))


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(0.5, 15.0), heading=st.floats(-math.pi, math.pi), climb=st.floats(-3.0, 3.0),
       rate=st.floats(0.05, 2.0), sign=st.sampled_from([1.0, -1.0]), duration=st.floats(0.1, 30.0))
def test_a_turn_keeps_the_speed_rotates_the_velocity_by_rate_times_time_and_stays_on_its_circle(
        speed, heading, climb, rate, sign, duration):
    assume(rate * speed <= 50.0)
    w = sign * rate
    velocity = [speed * math.cos(heading), speed * math.sin(heading), -climb]
    model = _at([{"kind": "turn", "rate": w, "duration": duration}], duration, velocity=velocity)
    assert math.hypot(*model.velocity[:2]) == pytest.approx(speed, rel=1e-12)
    assert model.velocity[2] == pytest.approx(-climb, abs=1e-12)
    turned = math.atan2(model.velocity[1], model.velocity[0]) - heading
    assert math.remainder(turned - w * duration, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    radius = speed / rate
    # Centre: radius to the right of the track for a right turn (+w), to the left for a left one.
    centre = np.array(START[:2]) + sign * radius * np.array([-math.sin(heading), math.cos(heading)])
    assert np.linalg.norm(model.position[:2] - centre) == pytest.approx(radius, abs=1e-9 * (1 + radius))
    assert model.position[2] == pytest.approx(START[2] - climb * duration, abs=1e-9 * (1 + abs(climb) * duration))
    assert model.acceleration.tolist() == [0.0, 0.0, 0.0]  # the turn is over: the final velocity holds
    halfway = _at([{"kind": "turn", "rate": w, "duration": duration}], 0.5 * duration, velocity=velocity)
    # Centripetal: |a| = w v, towards the centre.
    towards = np.append(centre - halfway.position[:2], 0.0) / radius
    assert np.allclose(halfway.acceleration, rate * speed * towards, rtol=0, atol=1e-9 * (1 + rate * speed))


def test_a_turn_through_an_angle_lasts_angle_over_rate():
    # 90 degrees left at 0.5 rad/s from 6 m/s north: pi s on a 12 m circle, ending 12 m north and 12 m west, westbound.
    model = _at([{"kind": "turn", "rate": -0.5, "angle_deg": 90.0}, {"kind": "cruise", "duration": 2.0}],
                math.pi, velocity=[6.0, 0.0, 0.0])
    assert np.allclose(model.position, np.array(START) + [12.0, -12.0, 0.0], rtol=0, atol=1e-9)
    assert np.allclose(model.velocity, [0.0, -6.0, 0.0], rtol=0, atol=1e-12)
    model.advance_to(math.pi + 2.0)
    assert np.allclose(model.position, np.array(START) + [12.0, -24.0, 0.0], rtol=0, atol=1e-9)
    assert model.acceleration.tolist() == [0.0, 0.0, 0.0]


@settings(max_examples=60, deadline=None)
@given(horizontal=st.tuples(st.floats(-8.0, 8.0), st.floats(-8.0, 8.0)), rate=st.floats(0.5, 5.0), a=accelerations,
       hold=st.floats(0.0, 5.0))
def test_a_climb_changes_the_vertical_speed_at_the_bound_and_keeps_the_horizontal_velocity(horizontal, rate, a, hold):
    takes = rate / a
    model = _at([{"kind": "climb", "rate": rate, "max_acceleration": a, "duration": takes + hold}], takes + hold,
                velocity=[*horizontal, 0.0])
    gained = rate**2 / (2 * a) + rate * hold  # m up: (v1^2 - v0^2) / (2 a), then the new rate for the rest
    assert model.position[2] == pytest.approx(START[2] - gained, abs=1e-9 * (1 + gained))
    assert np.allclose(model.position[:2], np.array(START[:2]) + np.array(horizontal) * (takes + hold), rtol=0, atol=1e-9 * 100)
    assert np.allclose(model.velocity, [*horizontal, -rate], rtol=0, atol=1e-12 * 10)


@settings(max_examples=60, deadline=None)
@given(direction=unit_directions, speed=st.floats(0.1, 20.0), a=accelerations)
def test_brake_stops_after_v_squared_over_2a_and_then_hovers_exactly(direction, speed, a):
    segments = [{"kind": "brake", "max_acceleration": a}, {"kind": "hover", "duration": 4.0}]
    stop = speed / a
    model = _target(segments, velocity=(speed * direction).tolist())
    model.advance_to(0.5 * stop)
    assert np.linalg.norm(model.velocity) == pytest.approx(0.5 * speed, rel=1e-9)
    model.advance_to(stop)
    assert np.allclose(model.position, np.array(START) + speed**2 / (2 * a) * direction, rtol=0,
                       atol=1e-9 * (1 + speed**2 / a))
    assert np.linalg.norm(model.velocity) <= 1e-9 * speed
    model.advance_to(stop + 1e-6)
    stopped = model.position.copy()
    assert model.velocity.tolist() == [0.0, 0.0, 0.0]
    for time in (stop + 1.0, stop + 4.0, stop + 100.0):  # the hover, then the final velocity (zero) held
        model.advance_to(time)
        assert model.position.tolist() == stopped.tolist() and model.velocity.tolist() == [0.0, 0.0, 0.0]


def test_after_the_last_segment_the_final_velocity_holds():
    model = _target([{"kind": "accelerate", "velocity": [3.0, 4.0, -1.0], "max_acceleration": 1.0}])
    assert model.end_time == pytest.approx(math.sqrt(26.0))
    model.advance_to(model.end_time)
    at_end = model.position.copy()
    model.advance_to(model.end_time + 10.0)
    assert np.allclose(model.position, at_end + 10.0 * np.array([3.0, 4.0, -1.0]), rtol=0, atol=1e-9)
    assert model.acceleration.tolist() == [0.0, 0.0, 0.0]


# --- random segment lists: continuity, calculus, any cut -------------------------------------------------------------

@st.composite
def segment_lists(draw) -> tuple[list[float], list[dict]]:
    """(initial velocity, a valid list of 1-8 segments of every kind), following whether the target is at rest
    and whether it has a horizontal speed, so that hovers and turns come where they can be flown."""
    velocity = draw(st.sampled_from([[0.0, 0.0, 0.0], [4.0, -2.0, 0.5]]))
    at_rest, horizontal = velocity == [0.0, 0.0, 0.0], velocity[:2] != [0.0, 0.0]
    segments = []
    for _ in range(draw(st.integers(1, 8))):
        kinds = ["accelerate", "cruise", "climb", "brake"] + (["hover"] if at_rest else []) + (["turn"] if horizontal else [])
        kind = draw(st.sampled_from(kinds))
        if kind == "hover":
            segments.append({"kind": kind, "duration": draw(st.floats(0.1, 5.0))})
        elif kind == "cruise":
            segments.append({"kind": kind, "duration": draw(st.floats(0.1, 5.0))})
        elif kind == "accelerate":
            goal = [draw(st.floats(-10.0, 10.0)), draw(st.floats(-10.0, 10.0)), draw(st.floats(-3.0, 3.0))]
            segments.append({"kind": kind, "velocity": goal, "max_acceleration": draw(st.floats(0.5, 5.0))})
            at_rest, horizontal = goal == [0.0, 0.0, 0.0], math.hypot(*goal[:2]) > 1e-3
        elif kind == "climb":
            rate = draw(st.floats(-3.0, 3.0))
            segments.append({"kind": kind, "rate": rate, "max_acceleration": draw(st.floats(0.5, 5.0))})
            at_rest = at_rest and rate == 0.0
        elif kind == "brake":
            segments.append({"kind": kind, "max_acceleration": draw(st.floats(0.5, 5.0))})
            at_rest, horizontal = True, False
        else:
            length = {"duration": draw(st.floats(0.1, 10.0))} if draw(st.booleans()) else {"angle_deg": draw(st.floats(1.0, 720.0))}
            segments.append({"kind": kind, "rate": draw(st.floats(0.05, 1.0)) * draw(st.sampled_from([1.0, -1.0])), **length})
    return velocity, segments


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(plan=segment_lists())
def test_position_and_velocity_are_continuous_across_every_boundary_and_derivatives_agree(plan):
    velocity, segments = plan
    model = _target(segments, velocity)
    boundaries = [piece.start for piece in model.pieces[1:]]
    assert boundaries == sorted(boundaries)

    def state(time: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        probe = _target(segments, velocity)
        probe.advance_to(time)
        return probe.position, probe.velocity, probe.acceleration

    for boundary, following in zip(boundaries, [*boundaries[1:], math.inf]):
        before, after = state(max(boundary - H, 0.0)), state(boundary)
        step = boundary - max(boundary - H, 0.0)
        # Across a boundary the position moves by at most |v| h and the velocity by at most |a| h (speeds up to
        # 15 m/s, accelerations up to 15 m/s^2 here): no jump.
        assert np.linalg.norm(after[0] - before[0]) <= 20.0 * step + 1e-9
        assert np.linalg.norm(after[1] - before[1]) <= 20.0 * step + 1e-9
        if following - boundary < 2 * H:
            continue  # a piece shorter than the difference step: its neighbours' checks cover it
        # Inside the piece that starts here: velocity is the derivative of position, acceleration of velocity.
        ahead = state(boundary + H)
        assert np.allclose((ahead[0] - after[0]) / H, 0.5 * (ahead[1] + after[1]), rtol=0, atol=1e-4)
        assert np.allclose((ahead[1] - after[1]) / H, after[2], rtol=0, atol=1e-3)


@settings(max_examples=40, deadline=None)
@given(plan=segment_lists(), cuts=st.lists(st.floats(0.0, 60.0), max_size=30))
def test_step_and_advance_to_agree_whatever_the_cuts(plan, cuts):
    velocity, segments = plan
    end = 60.0
    reference = _target(segments, velocity)
    reference.advance_to(end)
    cut = _target(segments, velocity)
    for time in sorted(cuts):
        cut.advance_to(time)
    cut.advance_to(end)
    stepped = _target(segments, velocity)
    for _ in range(600):
        stepped.step(0.1)
    for model in (cut, stepped):
        assert model.time == pytest.approx(end, abs=1e-9)
        assert np.allclose(model.position, reference.position, rtol=0, atol=1e-6)
        assert np.allclose(model.velocity, reference.velocity, rtol=0, atol=1e-9)


def test_advance_to_refuses_the_past_and_non_finite_times():
    model = _target([{"kind": "hover", "duration": 2.0}])
    model.advance_to(1.0)
    with pytest.raises(ValueError, match="backwards"):
        model.advance_to(0.5)
    with pytest.raises(ValueError, match="finite"):
        model.advance_to(math.nan)


# --- the schema --------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("velocity, segments, message", [
    ([0, 0, 0], [], "at least one segment"),
    ([0, 0, 0], [{"kind": "jump", "duration": 1.0}], "does not match any of the expected tags"),
    ([0, 0, 0], [{"duration": 1.0}], "discriminator 'kind'"),
    ([0, 0, 0], [{"kind": "hover"}], "duration"),
    ([0, 0, 0], [{"kind": "hover", "duration": 0.0}], "greater than 0"),
    ([0, 0, 0], [{"kind": "hover", "duration": 86401.0}], "less than or equal to 86400"),
    ([0, 0, 0], [{"kind": "cruise", "duration": 1.0, "speed": 3.0}], "Extra inputs"),
    ([1, 0, 0], [{"kind": "hover", "duration": 1.0}], "still moves at 1 m/s"),
    ([0, 0, 0], [{"kind": "accelerate", "velocity": [5, 0, 0]}, {"kind": "hover", "duration": 1.0}], "segments\\[1\\] \\(hover\\)"),
    ([0, 0, 0], [{"kind": "accelerate", "velocity": [101, 0, 0]}], "exceeds 100 m/s"),
    ([0, 0, 0], [{"kind": "accelerate", "velocity": [5, 0, 0], "max_acceleration": 51.0}], "less than or equal to 50"),
    ([0, 0, 0], [{"kind": "accelerate", "velocity": [5, 0, 0], "max_acceleration": 0.0}], "greater than 0"),
    ([0, 0, 0], [{"kind": "accelerate", "velocity": [8, 0, 0], "max_acceleration": 2.0, "duration": 3.0}], "shorter than the 4 s"),
    ([0, 0, 0], [{"kind": "climb", "rate": 2.0, "max_acceleration": 1.0, "duration": 1.0}], "shorter than the 2 s"),
    ([0, 0, 0], [{"kind": "turn", "rate": 0.3, "duration": 5.0}], "no horizontal speed"),
    ([0, 0, -2], [{"kind": "turn", "rate": 0.3, "duration": 5.0}], "no horizontal speed"),
    ([5, 0, 0], [{"kind": "brake"}, {"kind": "turn", "rate": 0.3, "duration": 5.0}], "segments\\[1\\] \\(turn\\)"),
    ([5, 0, 0], [{"kind": "turn", "rate": 0.0, "duration": 5.0}], "rate must be nonzero"),
    ([5, 0, 0], [{"kind": "turn", "rate": 3.5, "duration": 5.0}], "less than or equal to 3"),
    ([5, 0, 0], [{"kind": "turn", "rate": 0.3}], "duration or angle_deg"),
    ([5, 0, 0], [{"kind": "turn", "rate": 0.3, "duration": 1.0, "angle_deg": 20.0}], "duration or angle_deg"),
    ([30, 0, 0], [{"kind": "turn", "rate": 2.0, "duration": 1.0}], "exceeds 50 m/s\\^2"),
    ([0, 0, 0], [{"kind": "climb", "rate": 120.0}], "less than or equal to 100"),
    ([0, 0, 0], [{"kind": "accelerate", "velocity": [1, "2", 0]}], "valid number"),
])
def test_impossible_segments_are_refused_saying_why(velocity, segments, message):
    with pytest.raises(ValidationError, match=message):
        _config(segments, velocity)


def test_segments_exclude_the_other_models_and_need_an_initial_velocity():
    with pytest.raises(ValidationError, match="not several"):
        TargetConfig.model_validate({"initial_position": START, "initial_velocity": [5.0, 0.0, 0.0],
                                     "segments": [{"kind": "cruise", "duration": 1.0}], "circle": {"radius": 10.0}})
    with pytest.raises(ValidationError, match="not several"):
        TargetConfig.model_validate({"initial_position": START, "initial_velocity": [5.0, 0.0, 0.0],
                                     "segments": [{"kind": "cruise", "duration": 1.0}],
                                     "maneuvers": [{"start": 0.0, "end": 1.0, "lateral_acceleration": 1.0}]})
    with pytest.raises(ValidationError, match="initial_velocity .* is required"):
        TargetConfig.model_validate({"initial_position": START, "segments": [{"kind": "hover", "duration": 1.0}]})


def test_array_of_tables_and_inline_arrays_are_the_same_segments(tmp_path):
    head = (SCENARIOS_DIR / "stop_and_go.toml").read_text().split("[target]")[0].replace(
        'vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml"}"')
    tail = "\n[estimator]\ninitial_position = [40.0, -20.0, -15.0]\n"
    tables = tmp_path / "tables.toml"
    tables.write_text(head + '[target]\ninitial_position = [50.0, 0.0, -20.0]\ninitial_velocity = [0.0, 0.0, 0.0]\n'
                      '[[target.segments]]\nkind = "hover"\nduration = 2.0\n'
                      '[[target.segments]]\nkind = "accelerate"\nvelocity = [3.0, 0.0, 0.0]\nmax_acceleration = 1.5\n' + tail)
    inline = tmp_path / "inline.toml"
    inline.write_text(head + '[target]\ninitial_position = [50.0, 0.0, -20.0]\ninitial_velocity = [0.0, 0.0, 0.0]\n'
                      'segments = [{ kind = "hover", duration = 2.0 },\n'
                      '            { kind = "accelerate", velocity = [3.0, 0.0, 0.0], max_acceleration = 1.5 }]\n' + tail)
    assert load_scenario(tables)[0].target == load_scenario(inline)[0].target


# --- end to end --------------------------------------------------------------------------------------------------------

def _expected_track(time: float) -> np.ndarray:
    """The segments of test_segments_fly_in_the_in_process_simulator, by hand: hover 4 s; 0 -> 6 m/s north at
    2 m/s^2 (3 s, 9 m); cruise 3 s (18 m); a right turn at 0.5 rad/s through 90 degrees (pi s, radius 12 m, centre
    12 m east of where it starts); then east at 6 m/s."""
    p0 = np.array([50.0, -25.0, -20.0])
    if time <= 4.0:
        return p0
    if time <= 7.0:
        return p0 + [(time - 4.0) ** 2, 0.0, 0.0]
    if time <= 10.0:
        return p0 + [9.0 + 6.0 * (time - 7.0), 0.0, 0.0]
    if time <= 10.0 + math.pi:
        angle = 0.5 * (time - 10.0)
        return p0 + [27.0 + 12.0 * math.sin(angle), 12.0 - 12.0 * math.cos(angle), 0.0]
    return p0 + [39.0, 12.0 + 6.0 * (time - 10.0 - math.pi), 0.0]


def test_segments_fly_in_the_in_process_simulator():
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    document = scenario.model_dump()
    document["target"] = {"initial_position": [50.0, -25.0, -20.0], "initial_velocity": [0.0, 0.0, 0.0], "segments": [
        {"kind": "hover", "duration": 4.0},
        {"kind": "accelerate", "velocity": [6.0, 0.0, 0.0], "max_acceleration": 2.0},
        {"kind": "cruise", "duration": 3.0},
        {"kind": "turn", "rate": 0.5, "angle_deg": 90.0}]}
    document["simulation"].update(duration=15.0, summary_window=5.0)
    series = simulate(Scenario.model_validate(document), vehicle, seed=3).series
    times = series["time"]
    assert times[-1] == pytest.approx(15.0, abs=0.05)
    checked = 0
    for index in range(0, len(times), 7):
        assert np.allclose(series["target_position"][index], _expected_track(float(times[index])), rtol=0, atol=1e-6)
        checked += 1
    assert checked > 50
    hovering = times <= 4.0
    assert np.all(series["target_position"][hovering] == [50.0, -25.0, -20.0])


def test_the_shipped_hover_dash_scenario_flies_its_description():
    scenario, _ = load_scenario(SCENARIOS_DIR / "hover_dash.toml")
    model = target_from_config(scenario.target, 1)
    start = np.array([50.0, -25.0, -20.0])
    # hover 8 s; 0 -> 8 m/s north at 2.5 m/s^2: 3.2 s, 8^2 / 5 = 12.8 m; cruise 10 s, 80 m; brake: 3.2 s, 12.8 m.
    expected = {8.0: start, 11.2: start + [12.8, 0, 0], 21.2: start + [92.8, 0, 0], 24.4: start + [105.6, 0, 0],
                34.4: start + [105.6, 0, 0]}
    for time, position in expected.items():
        model.advance_to(time)
        assert np.allclose(model.position, position, rtol=0, atol=1e-9)
    assert model.velocity.tolist() == [0.0, 0.0, 0.0]
    # then east to 7 m/s at 2.5 m/s^2 (2.8 s, 9.8 m) and on at 7 m/s
    model.advance_to(60.0)
    assert np.allclose(model.position, start + [105.6, 9.8 + 7.0 * (60.0 - 34.4 - 2.8), 0.0], rtol=0, atol=1e-9)
    assert np.allclose(model.velocity, [0.0, 7.0, 0.0], rtol=0, atol=1e-12)
