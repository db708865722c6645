"""The target motion library (sitl_plant/world/target.py) against closed forms and numerical calculus.

References independent of the code under test: finite differences of the propagated states
(velocity is the derivative of position, acceleration of velocity), the geometry of a circle
(radius v^2 / a, centre on the normal, period 2 pi R / v), a hand-written trapezoidal speed
profile, and the moments of a first-order Gauss-Markov process (std sigma, autocorrelation
exp(-lag / tau), with Bartlett's sampling error).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy.integrate import trapezoid

from interfaces.link_schema import fix_to_ned
from interfaces.scenario import SCENARIOS_DIR, TargetConfig, load_scenario
from sitl_plant.world.target import SingerTarget, SpeedScheduleTarget, TargetModel, target_from_config
from studies.closed_loop import simulate

START = [10.0, -5.0, -20.0]
H = 1e-4  # s, finite-difference step
STEPS = 64  # sub-steps of H the acceleration is summed over


def _target(**fields) -> TargetConfig:
    return TargetConfig.model_validate({"initial_position": START, **fields})


def _horizontal(speed: float, heading: float, climb: float = 0.0) -> list[float]:
    return [speed * math.cos(heading), speed * math.sin(heading), -climb]


speeds = st.floats(0.5, 10.0)
headings = st.floats(-math.pi, math.pi)
directions = st.sampled_from(["right", "left"])


@st.composite
def target_configs(draw) -> TargetConfig:
    """A [target] of any model, with parameters across the supported envelope (0-10 m/s, up to 2 m/s^2)."""
    kind = draw(st.sampled_from(["maneuvers", "circle", "weave", "turn", "stop_and_go", "singer"]))
    speed, heading = draw(speeds), draw(headings)
    climb = draw(st.floats(-2.0, 2.0))
    velocity = _horizontal(speed, heading, climb)
    if kind == "maneuvers":
        return _target(initial_velocity=velocity, maneuvers=[
            {"start": 1.0, "end": 4.0, "lateral_acceleration": draw(st.floats(-2.0, 2.0))},
            {"start": 6.0, "end": 9.5, "lateral_acceleration": draw(st.floats(-2.0, 2.0))}])
    if kind == "circle":
        size = {"radius": draw(st.floats(speed**2 / 2.0, 200.0))} if draw(st.booleans()) else \
            {"turn_rate": draw(st.floats(0.01, 2.0 / speed))}
        return _target(initial_velocity=velocity, circle={**size, "direction": draw(directions)})
    if kind == "weave":
        return _target(initial_velocity=velocity, weave={"lateral_acceleration": draw(st.floats(0.1, 2.0)),
                                                          "half_period": draw(st.floats(0.5, 10.0)),
                                                          "direction": draw(directions), "end": 30.0})
    if kind == "turn":
        angle = draw(st.floats(1.0, 360.0))
        shortest = speed * math.radians(angle) / 2.0  # s: lateral acceleration v * angle / duration <= 2 m/s^2
        return _target(initial_velocity=velocity, turn={"start": draw(st.floats(0.0, 5.0)),
                                                        "duration": draw(st.floats(shortest, shortest + 10.0)),
                                                        "angle_deg": angle,
                                                        "direction": draw(directions), "turn_back": draw(st.booleans())})
    if kind == "stop_and_go":
        starts = sorted(set(draw(st.lists(st.floats(0.0, 12.0), min_size=1, max_size=4))))
        return _target(initial_velocity=velocity, stop_and_go={
            "max_acceleration": draw(st.floats(0.2, 3.0)),
            "schedule": [{"start": start, "speed": draw(st.floats(0.0, 10.0))} for start in starts]})
    return _target(initial_velocity=_horizontal(draw(st.floats(0.0, 10.0)), heading),
                   singer={"time_constant": draw(st.floats(0.5, 10.0)), "sigma": draw(st.floats(0.1, 4.0)),
                           "vertical_sigma": draw(st.floats(0.0, 1.0)), "update_period": draw(st.sampled_from([0.01, 0.02, 0.05]))})


def _state(model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return model.position.copy(), np.array(model.velocity, dtype=float), model.acceleration.copy()


@settings(max_examples=150, deadline=None)
@given(config=target_configs(), seed=st.integers(0, 2**32 - 1), time=st.floats(2 * H, 15.0))
@example(config=_target(initial_velocity=[1.0, 0.0, -0.0078125],  # a speed change of 3e-5 s, shorter than H
                        stop_and_go={"max_acceleration": 1.0, "schedule": [{"start": 1.0, "speed": 1.0}]}),
         seed=0, time=1.0)
def test_velocity_is_the_derivative_of_position_and_acceleration_of_velocity(config, seed, time):
    model = target_from_config(config, seed)
    model.advance_to(time - H)
    p0, _, _ = _state(model)
    model.advance_to(time)
    _, v1, _ = _state(model)
    # The acceleration is piecewise continuous (right-continuous at its switches, and a speed change can be
    # shorter than H), so velocity is checked as its integral: the change of v over [t, t + H] against the
    # left Riemann sum of a on a grid of STEPS sub-steps h, which is off by at most h x (the variation of a between
    # the grid points, plus twice its largest value for a pulse that starts and ends between two of them).
    step = H / STEPS
    samples = []
    for k in range(1, STEPS + 1):
        samples.append(_state(model)[2])
        model.advance_to(time + k * step)
    p2, v2, a2 = _state(model)
    samples = np.array(samples + [a2])
    integral = samples[:-1].sum(axis=0) * step
    bound = step * (np.abs(np.diff(samples, axis=0)).sum(axis=0) + 2 * np.abs(samples).max(axis=0)) + 1e-9
    # Velocity is continuous: the central difference is off by at most H * |jump of the acceleration|.
    assert np.allclose((p2 - p0) / (2 * H), v1, rtol=0, atol=2e-3)
    assert (np.abs(v2 - v1 - integral) <= bound).all()


@settings(max_examples=50, deadline=None)
@given(config=target_configs(), seed=st.integers(0, 2**32 - 1),
       cuts=st.lists(st.floats(0.0, 20.0), max_size=30))
def test_the_trajectory_does_not_depend_on_how_time_is_cut(config, seed, cuts):
    reference = target_from_config(config, seed)
    reference.advance_to(20.0)
    model = target_from_config(config, seed)
    for cut in (*sorted(cuts), 20.0):
        model.advance_to(cut)
    assert np.allclose(model.position, reference.position, rtol=0, atol=1e-8)
    assert np.allclose(model.velocity, reference.velocity, rtol=0, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(speed=speeds, heading=headings, climb=st.floats(-3.0, 3.0), direction=directions,
       radius=st.floats(5.0, 200.0), by_rate=st.booleans(), time=st.floats(0.0, 200.0))
def test_circle_and_helix_geometry(speed, heading, climb, direction, radius, by_rate, time):
    size = {"turn_rate": speed / radius} if by_rate else {"radius": radius}
    config = _target(initial_velocity=_horizontal(speed, heading, climb), circle={**size, "direction": direction})
    model = target_from_config(config, 0)
    side = 1.0 if direction == "right" else -1.0  # NED: a right turn's centre is at heading + 90 deg
    centre = np.array(START[:2]) + side * radius * np.array([-math.sin(heading), math.cos(heading)])
    model.advance_to(time)
    assert math.hypot(*(model.position[:2] - centre)) == pytest.approx(radius, rel=1e-9)
    assert np.linalg.norm(model.acceleration) == pytest.approx(speed**2 / radius, rel=1e-9)
    assert math.hypot(*model.velocity[:2]) == pytest.approx(speed, rel=1e-12)
    assert model.position[2] == pytest.approx(START[2] - climb * time, abs=1e-9)
    assert model.velocity[2] == -climb
    # the acceleration points at the centre
    inward = (centre - model.position[:2]) / radius
    assert model.acceleration[:2] @ inward == pytest.approx(speed**2 / radius, rel=1e-9)
    # one full turn later it is back over the same point
    period = 2 * math.pi * radius / speed
    before = model.position[:2].copy()
    model.advance_to(time + period)
    assert np.allclose(model.position[:2], before, rtol=0, atol=1e-7 * radius)


@settings(max_examples=60, deadline=None)
@given(speed=speeds, heading=headings, angle=st.floats(1.0, 179.0), duration=st.floats(0.5, 20.0),
       direction=directions, back=st.booleans())
def test_turn_pattern_turns_through_its_angle_at_constant_speed(speed, heading, angle, duration, direction, back):
    config = _target(initial_velocity=_horizontal(speed, heading),
                     turn={"start": 3.0, "duration": duration, "angle_deg": angle, "direction": direction, "turn_back": back})
    model = target_from_config(config, 0)
    model.advance_to(3.0 + duration)
    turned = math.degrees(math.atan2(model.velocity[1], model.velocity[0]) - heading)
    expected = angle if direction == "right" else -angle
    assert (turned - expected + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-7)
    model.advance_to(3.0 + 2 * duration + 1.0)
    final = math.degrees(math.atan2(model.velocity[1], model.velocity[0]) - heading)
    assert (final - (0.0 if back else expected) + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-7)
    assert np.linalg.norm(model.velocity) == pytest.approx(speed, rel=1e-12)


@settings(max_examples=40, deadline=None)
@given(speed=speeds, acceleration=st.floats(0.1, 2.0), half_period=st.floats(1.0, 10.0), direction=directions)
def test_weave_swings_the_heading_symmetrically(speed, acceleration, half_period, direction):
    config = _target(initial_velocity=[speed, 0.0, 0.0],
                     weave={"lateral_acceleration": acceleration, "half_period": half_period, "direction": direction})
    model = target_from_config(config, 0)
    amplitude = acceleration / speed * half_period / 2  # rad: turn rate a / v for half_period / 2
    swings = []
    for k in range(6):
        model.advance_to(half_period / 2 + k * half_period)
        swings.append(math.atan2(model.velocity[1], model.velocity[0]))
    sign = 1.0 if direction == "right" else -1.0
    expected = np.array([sign * amplitude * (-1) ** k for k in range(6)])
    assert np.allclose((np.array(swings) - expected + math.pi) % (2 * math.pi) - math.pi, 0.0, rtol=0, atol=1e-9)


def test_stop_and_go_scenario_follows_the_trapezoidal_speed_profile():
    scenario, _ = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    model = target_from_config(scenario.target, 1)
    # Written out by hand from the file: 5 m/s, brake at 1.5 m/s^2 from 10 s, 8 m/s from 20 s, stop at 35 s, 5 m/s at 45 s.
    knots_t = [0.0, 10.0, 10.0 + 5 / 1.5, 20.0, 20.0 + 8 / 1.5, 35.0, 35.0 + 8 / 1.5, 45.0, 45.0 + 5 / 1.5, 60.0]
    knots_v = [5.0, 5.0, 0.0, 0.0, 8.0, 8.0, 0.0, 0.0, 5.0, 5.0]
    for time in np.linspace(0.0, 60.0, 241):
        model.advance_to(float(time))
        past = [t for t in knots_t if t < time] + [float(time)]
        distance = trapezoid(np.interp(past, knots_t, knots_v), past)  # exact: the speed is piecewise linear
        assert model.velocity == pytest.approx([np.interp(time, knots_t, knots_v), 0.0, 0.0], abs=1e-9)
        assert model.position == pytest.approx([50.0 + distance, -25.0, -20.0], abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(config=target_configs().filter(lambda c: c.stop_and_go is not None), time=st.floats(0.0, 30.0))
def test_stop_and_go_keeps_its_track_and_its_acceleration_bound(config, time):
    model = target_from_config(config, 0)
    direction = np.array(config.initial_velocity) / np.linalg.norm(config.initial_velocity)
    model.advance_to(time)
    assert isinstance(model, SpeedScheduleTarget)
    assert np.allclose(np.cross(model.velocity, direction), 0.0, atol=1e-12) and model.velocity @ direction >= 0.0
    assert np.linalg.norm(model.acceleration) <= config.stop_and_go.max_acceleration * (1 + 1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), sigma=st.floats(0.5, 6.0), tau=st.floats(0.3, 10.0),
       speed=st.floats(0.0, 10.0), heading=headings, vertical=st.floats(0.0, 2.0),
       period=st.sampled_from([0.01, 0.02, 0.05, 0.1]), offset=st.floats(0.0, 1.0))
def test_singer_speed_and_lateral_acceleration_stay_within_bounds(seed, sigma, tau, speed, heading, vertical, period, offset):
    config = _target(initial_velocity=_horizontal(speed, heading),
                     singer={"time_constant": tau, "sigma": sigma, "vertical_sigma": vertical, "update_period": period})
    model = target_from_config(config, seed)
    # sample between and on the updates, including just after them where the speed may be lowest
    for time in np.arange(offset * period, 30.0, 0.37 * period):
        model.advance_to(float(time))
        velocity, acceleration = np.asarray(model.velocity), model.acceleration
        speed_now = float(np.linalg.norm(velocity))
        assert speed_now <= 10.0 + 1e-9
        if speed_now > 1e-6:
            assert np.linalg.norm(np.cross(acceleration, velocity)) / speed_now <= 2.0 + 1e-9


def test_singer_without_vertical_sigma_stays_level():
    config = _target(initial_velocity=[4.0, 3.0, 0.0], singer={"sigma": 3.0})
    model = target_from_config(config, 7)
    for time in np.arange(0.0, 120.0, 0.5):
        model.advance_to(float(time))
        assert model.position[2] == START[2] and model.velocity[2] == 0.0


def _bartlett_std(phi: float, lag: int, samples: int) -> float:
    """Bartlett's large-sample std of the lag-`lag` sample autocorrelation of an AR(1) with coefficient phi."""
    variance = ((1 + phi**2) * (1 - phi ** (2 * lag)) / (1 - phi**2) - 2 * lag * phi ** (2 * lag)) / samples
    return math.sqrt(variance)


def test_singer_acceleration_has_the_gauss_markov_moments():
    sigma, tau, period, updates = 1.3, 1.0, 0.1, 50_000
    model = SingerTarget(np.zeros(3), np.array([5.0, 0.0, 0.0]), time_constant=tau, sigma=sigma, vertical_sigma=0.0,
                         max_speed=1e12, max_lateral_acceleration=1e12, update_period=period,
                         rng=np.random.default_rng(2024))
    samples = np.empty((updates, 2))
    for k in range(updates):
        model.advance_to(k * period)
        samples[k] = model.acceleration[:2]
    phi = math.exp(-period / tau)
    for axis in range(2):
        series = samples[:, axis]
        # std of the sample variance of an AR(1): sigma^2 sqrt(2 (1 + phi^2) / ((1 - phi^2) N))
        variance_std = sigma**2 * math.sqrt(2 * (1 + phi**2) / ((1 - phi**2) * updates))
        assert abs(series.var() - sigma**2) < 5 * variance_std
        assert abs(series.mean()) < 5 * sigma * math.sqrt((1 + phi) / ((1 - phi) * updates))
        centred = series - series.mean()
        for lag_time in (0.5, 1.0, 2.0):
            lag = round(lag_time / period)
            correlation = (centred[:-lag] @ centred[lag:]) / (centred @ centred)
            assert abs(correlation - math.exp(-lag_time / tau)) < 5 * _bartlett_std(phi, lag, updates)


def test_singer_draws_from_its_own_stream_of_the_seed():
    config = _target(initial_velocity=[5.0, 0.0, 0.0], singer={})
    first, again, other = (target_from_config(config, seed) for seed in (3, 3, 4))
    for model in (first, again, other):
        model.advance_to(30.0)
    assert np.array_equal(first.position, again.position)
    assert not np.allclose(first.position, other.position)


@pytest.mark.parametrize("name", ["seed003_straight", "seed003_vertical", "seed003_helix"])
def test_seed003_trajectories(name):
    """Seed 003, section 4: from (100, 100, 100) m (z up; NED down = -100) at 10 m/s; A level along x (north),
    B straight up, C a helix at gamma = 45 deg turning at 2 pi / 30 rad/s."""
    scenario, _ = load_scenario(SCENARIOS_DIR / f"{name}.toml")
    model = target_from_config(scenario.target, 1)
    assert np.array_equal(model.position, [100.0, 100.0, -100.0])
    assert np.linalg.norm(model.velocity) == pytest.approx(10.0, rel=1e-12)
    model.advance_to(30.0)
    gamma = {"seed003_straight": 0.0, "seed003_vertical": math.pi / 2, "seed003_helix": math.pi / 4}[name]
    assert -model.position[2] == pytest.approx(100.0 + 30.0 * 10.0 * math.sin(gamma), abs=1e-9)
    horizontal = model.position[:2] - 100.0
    if name == "seed003_helix":
        assert np.allclose(horizontal, 0.0, atol=1e-9)  # one full turn in 30 s
        assert np.linalg.norm(model.acceleration) == pytest.approx(10.0 * math.cos(gamma) * 2 * math.pi / 30, rel=1e-12)
    else:
        assert np.allclose(horizontal, [30.0 * 10.0 * math.cos(gamma), 0.0], atol=1e-9)


@pytest.mark.parametrize("fields, message", [
    ({"maneuvers": [{"start": 0.0, "end": 5.0, "lateral_acceleration": 1.0}], "circle": {"radius": 10.0}}, "not several"),
    ({"circle": {"radius": 10.0}, "singer": {}}, "not several"),
    ({"circle": {"radius": 10.0, "turn_rate": 0.1}}, "radius or turn_rate"),
    ({"circle": {}}, "radius or turn_rate"),
    ({"stop_and_go": {"schedule": [{"start": 5.0, "speed": 0.0}, {"start": 5.0, "speed": 3.0}]}}, "increase strictly"),
    ({"stop_and_go": {"schedule": []}}, "at least 1"),
    ({"singer": {"max_speed": 4.0}}, "exceeds singer.max_speed"),
    ({"singer": {"sigma": 0.0}}, "greater than 0"),
    ({"turn": {"start": 1.0, "duration": 5.0, "angle_deg": 400.0}}, "less than or equal to 360"),
    ({"weave": {"lateral_acceleration": 1.0, "half_period": 2.0, "spin": 1}}, "Extra inputs"),
])
def test_inconsistent_target_models_are_refused_saying_why(fields, message):
    with pytest.raises(ValidationError, match=message):
        _target(initial_velocity=[5.0, 0.0, 0.0], **fields)


def test_turning_patterns_need_a_horizontal_velocity():
    with pytest.raises(ValidationError, match="nonzero horizontal"):
        _target(initial_velocity=[0.0, 0.0, -3.0], circle={"radius": 10.0})
    assert isinstance(target_from_config(_target(initial_velocity=[3.0, 0.0, 0.0]), 0), TargetModel)


def test_in_process_simulator_flies_the_configured_model():
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "singer.toml")
    scenario = scenario.model_copy(update={"simulation": scenario.simulation.model_copy(update={"duration": 8.0,
                                                                                              "summary_window": 4.0})})
    series = simulate(scenario, vehicle, seed=5).series
    model = target_from_config(scenario.target, 5)
    for index in range(0, len(series["time"]), 37):
        model.advance_to(float(series["time"][index]))
        assert np.allclose(series["target_position"][index], model.position, rtol=0, atol=1e-9)
        assert np.allclose(series["target_velocity"][index], model.velocity, rtol=0, atol=1e-9)


def test_sitl_target_process_flies_the_configured_model(tmp_path, sitl_target_fixes):
    """sitl-target with the Singer scenario and --seed: its fixes are the same trajectory as target_from_config's."""
    text = (SCENARIOS_DIR / "singer.toml").read_text().replace(
        'vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml"}"')
    path = tmp_path / "singer.toml"
    path.write_text(text)
    scenario, _ = load_scenario(path)
    fixes = sitl_target_fixes(path, tmp_path, "--seed", "6")
    assert len(fixes) >= 30 and fixes[-1].stamp == 4.0
    model = target_from_config(scenario.target, 6)
    for fix in fixes:
        model.advance_to(fix.stamp)
        assert np.allclose(fix_to_ned(fix, scenario.sitl.home), model.position, rtol=0, atol=1e-9)
        assert np.allclose(fix.velocity, model.velocity, rtol=0, atol=1e-12)
