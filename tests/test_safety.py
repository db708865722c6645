"""The safety envelope (companion.core.safety) against kinematics written here, and in flight."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from companion.core.attitude import VehicleLimits
from companion.core.imm import HOVER_SPEED, manoeuvre_model, speed_change_noise
from companion.core.safety import SafetyEnvelope, SpeedChangeLatch
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies.closed_loop import simulate
from studies.montecarlo import with_overrides

G = 9.81


def envelope(**changes) -> SafetyEnvelope:
    values = dict(min_range=4.0, target_max_acceleration=3.0, braking_acceleration=3.0, max_braking_acceleration=6.0,
                  range_sigmas=2.0, speed_sigmas=2.0, reaction_time=0.0)
    values.update(changes)
    return SafetyEnvelope(**values)


@given(gap=st.floats(0.01, 200.0), braking=st.floats(0.5, 10.0))
def test_the_closing_limit_is_the_speed_that_stops_within_the_gap(gap: float, braking: float) -> None:
    """No reaction time, an exact estimate and a target that is not moving: u_max = sqrt(2 a_P gap), the speed
    from which braking at a_P ends exactly at min_range (v^2 = 2 a d)."""
    rule = envelope(braking_acceleration=braking, max_braking_acceleration=braking)
    limit = rule.closing_speed_limit(4.0 + gap, 0.0, 0.0, 0.0, True)
    assert limit == pytest.approx(math.sqrt(2.0 * braking * gap), rel=1e-12)


@given(gap=st.floats(0.01, 100.0), lag=st.floats(0.0, 2.0))
def test_with_a_reaction_time_the_distance_to_stop_is_the_gap(gap: float, lag: float) -> None:
    """u t_r + u^2 / (2 a_P) = gap at u = u_max: coasting through the reaction time, then braking."""
    rule = envelope(reaction_time=lag)
    u = rule.closing_speed_limit(4.0 + gap, 0.0, 0.0, 0.0, True)
    assert u * lag + u * u / (2.0 * 3.0) == pytest.approx(gap, rel=1e-9)


def test_the_pessimistic_range_and_the_targets_stopping_distance() -> None:
    """r_p = r^ - k sigma_r; a target moving away at u_T adds u_T^2 / (2 a_T), only while trusted; one coming
    towards us takes its speed off the limit; inside min_range the limit is a retreat."""
    rule = envelope()
    assert rule.closing_speed_limit(10.0, 1.0, 0.0, 0.0, True) == pytest.approx(math.sqrt(2 * 3.0 * (10 - 2 - 4)))
    # away at 6 m/s with sigma 0.5: 5 m/s counts, 25 / 6 m of stopping
    expected = math.sqrt(2 * 3.0 * (10 - 2 - 4 + 25.0 / 6.0))
    assert rule.closing_speed_limit(10.0, 1.0, 6.0, 0.5, True) == pytest.approx(expected)
    assert rule.closing_speed_limit(10.0, 1.0, 6.0, 0.5, False) == pytest.approx(math.sqrt(2 * 3.0 * 4.0))
    assert rule.closing_speed_limit(10.0, 0.0, -2.0, 0.0, True) == pytest.approx(math.sqrt(2 * 3.0 * 6.0) - 2.0)
    assert rule.closing_speed_limit(3.0, 0.0, 0.0, 0.0, True) == pytest.approx(-1.0)  # 1 m inside: back at 1 m/s
    halved = envelope(untrusted_range_share=0.5)
    assert halved.closing_speed_limit(20.0, 0.0, 0.0, 0.0, False) == pytest.approx(math.sqrt(2 * 3.0 * 6.0))


@settings(max_examples=60, deadline=None)
@given(start_range=st.floats(6.0, 60.0), speed=st.floats(0.0, 15.0), sigma=st.floats(0.0, 2.0))
def test_a_point_mass_closing_on_a_hovering_target_never_passes_min_range(start_range: float, speed: float,
                                                                          sigma: float) -> None:
    """A double integrator at 50 Hz that asks to close at 3 m/s^2 for good, the envelope between it and its
    acceleration, an estimate that is right (its sigma only makes it more careful): the range never goes
    below min_range, whatever the start speed, as long as it could stop from there at all."""
    rule = envelope(reaction_time=0.1)
    los = np.array([1.0, 0.0, 0.0])
    position, velocity, target = 0.0, speed, start_range
    if speed * speed / (2 * 6.0) > start_range - 4.0 - 2.0 * sigma:
        return  # even the hardest braking cannot stop it in time: outside what any rule can promise
    dt = 0.02
    closest = target - position
    for _ in range(int(40.0 / dt)):
        distance = target - position
        command = np.array([3.0, 0.0, 0.0])
        limited = rule.limit_closing(command, los, np.array([velocity, 0.0, 0.0]), distance, sigma, 0.0, 0.0, True)
        acceleration = float((command if limited is None else limited)[0])
        assert acceleration >= -6.0 - 1e-12
        position += velocity * dt + 0.5 * acceleration * dt * dt
        velocity += acceleration * dt
        closest = min(closest, target - position)
    assert closest >= 4.0 - 0.05, closest


def _follow_a_braking_target(rule: SafetyEnvelope, speed: float, latency: float, braking: float) -> float:
    """The closest a point mass comes to a target it follows at 8 m, both at `speed`, when the target brakes to a
    stop at `braking` m/s^2 after 2 s. The envelope sees the target as a filter that lags by `latency` s would:
    its state `latency` s ago carried on at constant velocity. The follower asks to close at 1 m/s^2 for good."""
    dt = 0.01
    los = np.array([1.0, 0.0, 0.0])
    position, velocity = 0.0, speed
    history: list[tuple[float, float]] = []  # the target's (position, speed) at every step
    target, target_speed = 8.0, speed
    closest = target - position
    lag_steps = round(latency / dt)
    for step in range(int(20.0 / dt)):
        history.append((target, target_speed))
        seen_position, seen_speed = history[max(0, step - lag_steps)]
        seen = seen_position + seen_speed * min(step, lag_steps) * dt
        command = np.array([1.0, 0.0, 0.0])
        limited = rule.limit_closing(command, los, np.array([velocity, 0.0, 0.0]), seen - position, 0.0, seen_speed,
                                     0.0, True)
        acceleration = float((command if limited is None else limited)[0])
        position += velocity * dt + 0.5 * acceleration * dt * dt
        velocity += acceleration * dt
        if step * dt >= 2.0:
            slowed = max(target_speed - braking * dt, 0.0)
            target += 0.5 * (target_speed + slowed) * dt
            target_speed = slowed
        else:
            target += target_speed * dt
        closest = min(closest, target - position)
    return closest


@settings(max_examples=40, deadline=None)
@given(speed=st.floats(1.0, 6.0), latency=st.floats(0.2, 1.0), braking=st.floats(1.0, 3.0))
def test_a_follower_whose_estimate_lags_a_braking_target_stops_short_of_min_range(speed: float, latency: float,
                                                                                    braking: float) -> None:
    """RSS with a late view of the target: a target that brakes at up to a_T is seen braking only `latency` s
    later. With estimate_latency at least that lag the follower never comes closer than min_range (4 m), from
    8 m behind at any speed it can follow there; it falls back instead (the gap it keeps grows with speed)."""
    rule = envelope(speed_sigmas=0.0, reaction_time=0.1, estimate_latency=latency, max_braking_acceleration=6.0)
    assert _follow_a_braking_target(rule, speed, latency, braking) >= 4.0 - 0.05


def test_without_the_latency_term_a_lagging_estimate_lets_the_follower_too_close() -> None:
    """The same target braking at a_T = 3 m/s^2 from 5 m/s, seen 1 s late: the rule that credits the target's
    whole stopping distance from the lagging estimate (estimate_latency 0) lets the follower inside min_range."""
    late = envelope(speed_sigmas=0.0, reaction_time=0.1, estimate_latency=0.0, max_braking_acceleration=6.0)
    aware = dataclasses.replace(late, estimate_latency=1.0)
    assert _follow_a_braking_target(late, 5.0, 1.0, 3.0) < 4.0 - 0.5
    assert _follow_a_braking_target(aware, 5.0, 1.0, 3.0) >= 4.0 - 0.05


@given(previous=st.floats(-math.pi, math.pi), wanted=st.floats(-math.pi, math.pi), interval=st.floats(0.01, 0.5),
       elevation=st.floats(-1.4, 1.4))
def test_the_heading_is_the_horizontal_line_of_sight_turned_at_most_at_the_yaw_rate(
        previous: float, wanted: float, interval: float, elevation: float) -> None:
    rule = envelope(max_yaw_rate=math.radians(90.0))
    forward = np.array([math.cos(previous), math.sin(previous), 0.0])
    los = np.array([math.cos(elevation) * math.cos(wanted), math.cos(elevation) * math.sin(wanted), -math.sin(elevation)])
    heading, limited = rule.heading(los, forward, interval)
    assert heading is not None and heading[2] == 0.0 and math.isclose(float(np.linalg.norm(heading)), 1.0)
    moved = math.remainder(math.atan2(heading[1], heading[0]) - previous, 2 * math.pi)
    turn = math.remainder(wanted - previous, 2 * math.pi)
    step = math.radians(90.0) * interval
    assert limited == (abs(turn) > step)
    assert moved == pytest.approx(math.copysign(step, turn) if limited else turn, abs=1e-9)


def test_a_vertical_line_of_sight_holds_the_heading() -> None:
    rule = envelope()
    forward = np.array([0.0, 1.0, 0.0])
    heading, limited = rule.heading(np.array([0.03, 0.0, -1.0]) / math.hypot(0.03, 1.0), forward, 0.05)
    assert not limited and heading == pytest.approx(forward)
    assert rule.heading(np.array([0.0, 0.0, -1.0]), None, 0.0) == (None, False)


def test_the_setpoints_keep_the_tilt_margin() -> None:
    limits = VehicleLimits(2.0 / 3.0, max_tilt=math.radians(35.0), gravity=G, mass=1.0)
    commanded = envelope(tilt_margin=math.radians(3.0)).commanded_limits(limits)
    assert math.degrees(commanded.max_tilt) == pytest.approx(32.0)
    assert envelope(tilt_margin=0.0).commanded_limits(limits) is limits


@pytest.mark.parametrize("field, value", [("min_range", 0.0), ("braking_acceleration", -1.0), ("range_sigmas", -1.0),
                                          ("max_braking_acceleration", 1.0), ("untrusted_range_share", 0.0),
                                          ("tilt_margin", math.radians(25.0)), ("max_yaw_rate", math.nan),
                                          ("speed_change_latency", -0.5), ("speed_change_memory", math.inf),
                                          ("speed_change_trigger", 0.0), ("speed_change_trigger", 1.5),
                                          ("speed_change_speed", -1.0), ("speed_change_window", 0.0)])
def test_bad_envelope_parameters_are_refused(field: str, value: float) -> None:
    with pytest.raises(ValueError):
        envelope(**{field: value})


def test_the_speed_change_model_takes_two_thirds_of_a_max_along_its_track() -> None:
    model = manoeuvre_model(3.0, 0.04)
    assert model.turn_rate == 0.0 and model.process_noise == 0.04 and model.along_track_noise == pytest.approx(4.0)
    for bad in ((0.0, 0.04), (math.inf, 0.04), (3.0, -1.0)):
        with pytest.raises(ValueError):
            manoeuvre_model(*bad)


@settings(max_examples=80, deadline=None)
@given(velocity=st.tuples(*[st.floats(-20.0, 20.0)] * 3), across=st.floats(0.0, 1.0), extra=st.floats(0.0, 10.0))
def test_the_speed_change_noise_is_along_the_track_and_quiet_across_it(velocity, across: float, extra: float) -> None:
    """Q_a's eigen-decomposition (numpy's eigh): `along` with its eigenvector along v, and twice
    across + (along - across) v_0^2 / (|v|^2 + v_0^2) across it (v_0 = 1 m/s): the acceleration variance the
    model allows is along v for a moving target, isotropic `along` for one at rest."""
    v = np.array(velocity)
    along = across + extra
    values, vectors = np.linalg.eigh(speed_change_noise(v, along, across))
    speed_squared = float(v @ v)
    lateral = across + extra * HOVER_SPEED**2 / (speed_squared + HOVER_SPEED**2)
    assert sorted(values) == pytest.approx(sorted([along, lateral, lateral]), abs=1e-9 * (1.0 + along))
    if speed_squared > 1e-6 and extra > 1e-3 and along - lateral > 1e-6 * along:
        top = vectors[:, int(np.argmax(values))]
        assert abs(float(top @ v)) / math.sqrt(speed_squared) == pytest.approx(1.0, abs=1e-6)


def test_a_stop_and_go_flight_keeps_its_tilt_inside_the_airframes_limit_and_counts_the_envelope() -> None:
    """The stop-and-go target with the defaults: the setpoints' tilt stays 3 deg inside 35 deg, and the vehicle's
    own tilt (the plant's attitude loop tracking them) never passes 35 deg in three flights; with the envelope
    off, the same flights come to the limit and one passes it (the yaw steps the heading rule takes out:
    34.99, 34.96 and 43.7 deg at seeds 101-103)."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    unguarded = []
    for seed in (101, 102, 103):
        on = simulate(scenario, vehicle, seed)
        assert on.summary["max_tilt_deg"] <= vehicle.max_tilt_deg - 2.0, seed
        off = simulate(with_overrides(scenario, {"safety.enabled": False}), vehicle, seed)
        unguarded.append(off.summary["max_tilt_deg"])
    assert max(unguarded) > vehicle.max_tilt_deg, unguarded


@given(heading_angle=st.floats(-math.pi, math.pi), north=st.floats(-6.0, 6.0), east=st.floats(-6.0, 6.0),
       down=st.floats(-3.0, 3.0))
def test_the_heading_axis_points_exactly_along_the_heading_and_across_the_thrust(heading_angle, north, east, down):
    """The setpoint's body x axis through eq. (21)'s mapping: horizontally along the heading (no yaw from the tilt),
    perpendicular to the thrust axis, and R_d a rotation (scipy's Rotation reads its yaw back)."""
    from scipy.spatial.transform import Rotation

    from companion.core.attitude import desired_rotation
    from companion.core.safety import heading_axis

    heading = np.array([math.cos(heading_angle), math.sin(heading_angle), 0.0])
    acceleration = np.array([north, east, down])
    axis = heading_axis(heading, acceleration, G)
    thrust = np.array([0.0, 0.0, G]) - acceleration
    assert abs(float(axis @ thrust)) < 1e-9 * np.linalg.norm(thrust)
    rotation = desired_rotation(acceleration, axis, G)
    yaw = Rotation.from_matrix(rotation).as_euler("ZYX")[0]
    assert math.remainder(yaw - heading_angle, 2 * math.pi) == pytest.approx(0.0, abs=1e-7)
    assert float(rotation[:, 0] @ heading) > 0.0


@settings(max_examples=200)
@given(seed=st.integers(0, 2**32 - 1), trusted=st.booleans(), range_estimate=st.floats(0.5, 80.0))
def test_the_control_ticks_closing_rule_reads_sigma_r_and_sigma_v_along_the_line_of_sight(seed, trusted, range_estimate):
    """The control tick's one-call closing rule is limit_closing with sigma_r = sqrt(l' P_pp l) and sigma_v =
    sqrt(l' P_vv l) taken from the estimate's 6 x 6 covariance (numpy's einsum here) and the target's speed away
    v_T . l: the same command, or no change where limit_closing leaves it."""
    from companion.core.safety import _limit_closing_into_kernel

    rng = np.random.default_rng(seed)
    root = rng.normal(scale=rng.uniform(0.05, 3.0), size=(6, 6))
    covariance = root @ root.T
    los = rng.normal(size=3)
    los /= np.linalg.norm(los)
    command, pursuer, target = rng.normal(scale=4.0, size=(3, 3))
    rule = envelope(reaction_time=0.3, estimate_latency=0.2)
    range_std = math.sqrt(np.einsum("i,ij,j", los, covariance[:3, :3], los))
    speed_std = math.sqrt(np.einsum("i,ij,j", los, covariance[3:, 3:], los))
    expected = rule.limit_closing(command, los, pursuer, range_estimate, range_std, float(target @ los), speed_std,
                                  trusted)
    out = np.full(3, np.nan)
    changed = _limit_closing_into_kernel(command, los, pursuer, covariance, target, range_estimate, trusted,
                                         rule.kernel_terms, out)
    assert changed == (expected is not None)
    if changed:
        np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-9)
    else:
        assert np.all(np.isnan(out))  # left as it was


@given(heading_angle=st.floats(-math.pi, math.pi), north=st.floats(-15.0, 15.0), east=st.floats(-15.0, 15.0),
       down=st.floats(-15.0, 8.0))
def test_the_setpoint_on_the_envelopes_heading_yaws_exactly_to_it_and_thrusts_along_the_flown_command(
        heading_angle, north, east, down):
    """The setpoint the control tick builds on the envelope's heading: scipy reads its yaw back as the heading,
    its thrust axis is g e_Z minus the command as limit_specific_force flies it, and the flown command it
    reports is that one."""
    from scipy.spatial.transform import Rotation

    from companion.core.attitude import limit_specific_force
    from companion.core.safety import _heading_setpoint_into_kernel

    limits = VehicleLimits(2.0 / 3.0, max_tilt=math.radians(35.0), gravity=G, mass=1.3)
    heading = np.array([math.cos(heading_angle), math.sin(heading_angle), 0.0])
    command = np.array([north, east, down])
    rotation, flown = np.empty((3, 3)), np.empty(3)
    thrust, normalized = _heading_setpoint_into_kernel(command, heading, np.eye(3), limits.setpoint_terms, rotation,
                                                       flown)
    expected = limit_specific_force(command, limits)
    np.testing.assert_allclose(flown, expected, rtol=1e-12, atol=1e-12)
    force = np.array([0.0, 0.0, G]) - expected
    np.testing.assert_allclose(rotation[:, 2], force / np.linalg.norm(force), atol=1e-9)
    yaw = Rotation.from_matrix(rotation).as_euler("ZYX")[0]
    assert math.remainder(yaw - heading_angle, 2 * math.pi) == pytest.approx(0.0, abs=1e-7)
    assert thrust == pytest.approx(limits.mass * np.linalg.norm(force), rel=1e-9)
    assert 0.0 <= normalized <= 1.0


#: The range excitation and the IMM's turn pairs the speed-change headway and the hover standoff were measured with
#: (docs/reproduction.md, section 5.11).
ALWAYS_EXCITING = {"guidance.excitation_low": 0.01, "guidance.excitation_high": 0.03, "guidance.excitation_speed": 8.0,
                   "estimator.imm_turn_rates": [0.2, 0.4]}
NO_HEADWAY_NOR_STANDOFF = {"safety.speed_change_latency": 0.0, "safety.hover_standoff": 0.0}


def test_the_headway_for_a_target_changing_speed_keeps_off_a_braking_target_and_leaves_a_steady_one_alone() -> None:
    """speed_change_latency in flight. replay_csv's recorded target dashes to 6 m/s and brakes at up to 3 m/s^2
    (config/trajectories/make_hover_legs.py): at 50 Hz, seed 9, without it the pursuer comes within r_d / 2 of the
    braking target; with 1 s it never does, planning with it from the first dash on. A constant-velocity target
    never trips it: its flight is the same to the bit. (No hover standoff in either, so only the headway acts.)"""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "replay_csv.toml")
    scenario = with_overrides(scenario, {"sensor.rate_hz": 50.0, **ALWAYS_EXCITING, **NO_HEADWAY_NOR_STANDOFF})
    half = scenario.guidance.desired_range / 2.0
    without = simulate(scenario, vehicle, 9)
    assert without.summary["truth"]["min_range"] < half
    assert without.summary["envelope"]["speed_change_seconds"] == 0.0
    headway = simulate(with_overrides(scenario, {"safety.speed_change_latency": 1.0}), vehicle, 9)
    assert headway.summary["truth"]["min_range"] >= half
    assert headway.summary["envelope"]["speed_change_seconds"] > 0.5 * scenario.simulation.duration

    steady, steady_vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    steady = with_overrides(steady, {**ALWAYS_EXCITING, **NO_HEADWAY_NOR_STANDOFF})
    plain = simulate(steady, steady_vehicle, 2)
    guarded = simulate(with_overrides(steady, {"safety.speed_change_latency": 1.0}), steady_vehicle, 2)
    assert guarded.summary["envelope"]["speed_change_seconds"] == 0.0
    np.testing.assert_array_equal(guarded.series["pursuer_position"], plain.series["pursuer_position"])


def test_the_headway_for_a_target_changing_speed_needs_the_imms_speed_change_model() -> None:
    """Without the speed-change model nothing would ever trip it: refused with a clear error, not ignored."""
    from companion.assembly import safety_envelope
    from interfaces.scenario import ConfigError

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    for changes in ({"estimator.kind": "uplkf"}, {"estimator.imm_manoeuvre_model": False}):
        with pytest.raises(ConfigError, match="speed_change_latency"):
            safety_envelope(with_overrides(scenario, {"safety.speed_change_latency": 1.0, **changes}), vehicle)
    assert safety_envelope(with_overrides(scenario, {"safety.speed_change_latency": 1.0}), vehicle).speed_change_latency == 1.0


def test_the_headway_lasts_speed_change_memory_after_the_last_speed_change() -> None:
    """stop_and_go's target flies at 5 m/s, brakes to a hover from 10 s, leaves again at 20 s, and changes speed
    until 48 s of the 60 s flight. The headway starts with a speed change, never before the first one (at most
    50 s), lasts speed_change_memory after its last trigger (at least 5 s and 30 s with 5 and 30 s of memory),
    and grows with the memory."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")

    def seconds(memory: float) -> float:
        changes = {"safety.speed_change_latency": 1.0, "safety.speed_change_memory": memory}
        return simulate(with_overrides(scenario, changes), vehicle, 1).summary["envelope"]["speed_change_seconds"]

    alone, short, long = seconds(0.0), seconds(5.0), seconds(30.0)
    assert 0.0 < alone < short < long <= 50.0
    assert short >= 5.0 and long >= 30.0


def test_a_turn_at_a_steady_speed_does_not_trip_the_headway() -> None:
    """turn90_5ms's target turns 90 deg at a steady 5 m/s. As the turn ends the IMM's speed-change model explains
    the bearings best for a moment, so the model probability alone trips the headway (speed_change_speed 0); the
    estimated speed hardly moves, so with the speed test (1 m/s, the default) it never trips."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "turn90_5ms.toml")

    def seconds(speed: float) -> float:
        changes = {"safety.speed_change_latency": 1.0, "safety.speed_change_speed": speed}
        return simulate(with_overrides(scenario, changes), vehicle, 1).summary["envelope"]["speed_change_seconds"]

    assert seconds(0.0) > 10.0
    assert seconds(1.0) == 0.0


def latch(**changes) -> SpeedChangeLatch:
    return SpeedChangeLatch(envelope(speed_change_latency=1.0, **changes))


@given(speed=st.floats(0.0, 30.0), rate=st.floats(-2.0, 2.0), threshold=st.floats(0.1, 5.0),
       window=st.floats(0.1, 5.0), period=st.sampled_from([0.01, 0.02, 0.05, 0.1]))
def test_a_steady_speed_in_any_direction_never_trips_the_latch(speed, rate, threshold, window, period) -> None:
    """A target turning at any rate (rad/s) at a constant speed, the estimator sure it changes speed
    (probability 1): the speed never leaves its average, so the latch never holds."""
    gate = latch(speed_change_speed=threshold, speed_change_window=window)
    for k in range(400):
        angle = rate * k * period
        velocity = speed * np.array([math.cos(angle), math.sin(angle), 0.0])
        assert not gate.holds(k * period, 1.0, velocity, period)


@given(acceleration=st.floats(0.2, 5.0), threshold=st.floats(0.2, 3.0), window=st.floats(0.2, 3.0),
       period=st.sampled_from([0.01, 0.02, 0.05]))
def test_a_speed_ramp_trips_the_latch_as_its_exponential_average_lags(acceleration, threshold, window, period) -> None:
    """A speed ramp s = a t, probability 1. The exponential average with step alpha = period / window lags it by
    a tau (1 - (1 - alpha)^n) after n ticks (tau = window), never more than a tau: below the threshold for
    a tau < threshold, so never tripped; at least twice the threshold, so tripped by tau ln 2 + one tick."""
    lag = acceleration * window
    if threshold * 0.95 <= lag <= 2.05 * threshold:
        return  # too near the boundaries for a floating-point verdict
    gate = latch(speed_change_speed=threshold, speed_change_window=window)
    tripped = None
    for k in range(int(4.0 * window / period) + 2):
        if gate.holds(k * period, 1.0, np.array([0.0, acceleration * k * period, 0.0]), period) and tripped is None:
            tripped = k * period
    if lag < threshold:
        assert tripped is None
    else:
        assert tripped is not None and tripped <= window * math.log(2.0) + period + 1e-9


@given(memory=st.floats(0.0, 20.0), period=st.sampled_from([0.02, 0.1]))
def test_the_latch_holds_for_its_memory_after_the_last_change_and_needs_the_probability(memory, period) -> None:
    """A speed step of 5 m/s (threshold 1 m/s) at t = 1 s, then steady: with probability 1 the latch holds from
    the step for `memory` s and then lets go; with the probability under the trigger, or None (no speed-change
    model), it never holds."""
    def run(probability):
        gate = latch(speed_change_speed=1.0, speed_change_window=1.0, speed_change_memory=memory)
        held = []
        for k in range(int((memory + 5.0) / period)):
            time = k * period
            speed = 0.0 if time < 1.0 - 1e-9 else 5.0
            held.append((time, gate.holds(time, probability, np.array([speed, 0.0, 0.0]), period)))
        return held

    held = run(1.0)
    on = [time for time, holding in held if holding]
    assert on and on[0] >= 1.0 - 1e-9 and on[0] <= 1.0 + period + 1e-9
    assert on[-1] >= on[0] + memory - 1e-9 - period and on[-1] <= 1.0 + 2.0 + memory + 1e-9
    assert not held[-1][1]
    assert not any(holding for _, holding in run(0.4))
    assert not any(holding for _, holding in run(None))


def test_the_scenario_schema_and_the_envelope_give_each_shared_key_the_same_default() -> None:
    """[safety] (interfaces.scenario.safety.SafetyConfig) and the core's SafetyEnvelope declare their defaults
    separately (the interfaces may not import the core): every key they share, degrees converted, defaults alike,
    so a pipeline built in code flies as one built from a scenario file. The two derived ones are compared as
    built: the standoff for the same target acceleration, and the headway for an estimator with the speed-change
    model (without it the core's headway never trips, so 0 and its default fly alike)."""
    from interfaces.scenario.safety import SafetyConfig

    core = {field.name: field.default for field in dataclasses.fields(SafetyEnvelope)
            if field.default is not dataclasses.MISSING}
    shared = 0
    for name, field in SafetyConfig.model_fields.items():
        key, scale = (name[:-4], math.radians(1.0)) if name.endswith("_deg") else (name, 1.0)
        if key in core and field.default is not None:
            shared += 1
            assert field.default * scale == pytest.approx(core[key], rel=1e-12), name
    assert shared >= 13
    scenario, _ = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    built, bare = _built_envelope(scenario), envelope(target_max_acceleration=scenario.estimator.target_max_acceleration)
    assert (built.hover_standoff, built.speed_change_latency) == (bare.hover_standoff, bare.speed_change_latency)


@given(speed=st.floats(0.0, 20.0), hover_speed=st.floats(0.2, 5.0), standoff=st.floats(0.5, 20.0),
       gap=st.floats(0.0, 60.0), lag=st.floats(0.0, 1.0), latency=st.floats(0.0, 2.0),
       heading=st.floats(-math.pi, math.pi))
def test_a_hovering_target_is_kept_hover_standoff_farther_off(speed, hover_speed, standoff, gap, lag, latency,
                                                               heading) -> None:
    """A target at rest on an exact estimate: the pursuer's closing limit is the speed that stops it (reaction
    time t_r, braking a_P) hover_standoff x (1 - |v| / hover_speed) beyond min_range, falling linearly to the
    plain limit at hover_speed: u t_r + u^2 / (2 a_P) = the gap left, written out here. The velocity's direction
    does not matter, and the speed-change terms are raised alike."""
    from companion.core.safety import _closing_limit_kernel
    rule = envelope(reaction_time=lag, hover_standoff=standoff, hover_speed=hover_speed,
                    speed_change_latency=latency)
    velocity = speed * np.array([math.cos(heading), math.sin(heading), 0.0])
    share = max(0.0, 1.0 - float(np.linalg.norm(velocity)) / hover_speed)
    for base in (rule.kernel_terms, rule.speed_change_terms):
        terms, raised = rule.hover_terms(base, velocity)
        if abs(share) > 1e-12 or speed > hover_speed * (1.0 + 1e-12):  # at |v| = hover_speed itself, either way
            assert raised == (share > 0.0)
        left = gap - share * standoff
        limit = _closing_limit_kernel(4.0 + gap, 0.0, 0.0, 0.0, True, terms)[0]
        braking, t = 3.0, lag + base[-1]
        if left > 0.0:
            assert limit * t + limit ** 2 / (2.0 * braking) == pytest.approx(left, rel=1e-9, abs=1e-9)
        else:
            assert limit == pytest.approx(left, rel=1e-9, abs=1e-12)  # retreat_gain 1/s x the gap


def test_the_hover_standoff_is_off_at_0_and_full_for_an_estimate_that_is_not_finite() -> None:
    rule = envelope(hover_standoff=0.0)
    assert rule.hover_terms(rule.kernel_terms, np.zeros(3)) == (rule.kernel_terms, False)
    kept = envelope(hover_standoff=5.0)
    assert kept.hover_share(np.array([math.nan, 0.0, 0.0])) == 1.0
    for bad in ({"hover_standoff": -1.0}, {"hover_speed": 0.0}, {"hover_speed": math.inf}):
        with pytest.raises(ValueError, match="hover_"):
            envelope(**bad)


def test_a_hover_standoff_keeps_off_a_target_leaving_its_hover_towards_the_pursuer() -> None:
    """stop_and_go at 50 Hz, seed 2, with the range excitation and the speed-change headway: the target hovers
    from 13 s, and leaves at 20 s towards the pursuer, which the bearings show about 2 s late; without a standoff
    the pursuer comes within r_d / 2 of it, with the default (6 m) it never does. It waits farther off the
    hovering target, and only while the target is slow (the two hovers, their brakings and departures: 5-30 s of
    the 60). A constant-velocity target's flight is the same to the bit with or without it: the standoff is kept
    only while the estimate starts up from rest, far from the target."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    scenario = with_overrides(scenario, {"sensor.rate_hz": 50.0, **ALWAYS_EXCITING, "safety.speed_change_latency": 1.0})
    assert _built_envelope(scenario).hover_standoff == 6.0
    half = scenario.guidance.desired_range / 2.0
    without = simulate(with_overrides(scenario, {"safety.hover_standoff": 0.0}), vehicle, 2)
    kept = simulate(scenario, vehicle, 2)
    assert without.summary["truth"]["min_range"] < half <= kept.summary["truth"]["min_range"]
    assert without.summary["envelope"]["hover_seconds"] == 0.0
    assert 5.0 <= kept.summary["envelope"]["hover_seconds"] <= 30.0
    hovering = (without.series["time"] >= 15.0) & (without.series["time"] < 20.0)
    assert np.median(kept.series["range"][hovering]) > np.median(without.series["range"][hovering])

    steady, steady_vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    plain = simulate(with_overrides(steady, {"safety.hover_standoff": 0.0}), steady_vehicle, 2)
    guarded = simulate(steady, steady_vehicle, 2)
    assert guarded.summary["envelope"]["hover_seconds"] <= 0.5
    np.testing.assert_array_equal(guarded.series["pursuer_position"], plain.series["pursuer_position"])


def _built_envelope(scenario) -> SafetyEnvelope:
    """The envelope companion.assembly builds for `scenario` on the paper's airframe."""
    from companion.assembly import safety_envelope
    _, vehicle = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    return safety_envelope(scenario, vehicle)


@given(acceleration=st.floats(0.1, 20.0))
@settings(max_examples=25, deadline=None)
def test_the_default_standoff_is_what_a_target_at_its_acceleration_bound_covers_from_rest_in_two_seconds(
        acceleration) -> None:
    """Left out, [safety] hover_standoff is a_T T^2 / 2 with T = 2 s and a_T = [estimator]
    target_max_acceleration (constant-acceleration kinematics from rest); a value given is kept."""
    scenario, _ = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    changed = with_overrides(scenario, {"estimator.target_max_acceleration": acceleration})
    assert _built_envelope(changed).hover_standoff == pytest.approx(acceleration * 2.0 ** 2 / 2.0, rel=1e-12)
    assert _built_envelope(with_overrides(changed, {"safety.hover_standoff": 1.5})).hover_standoff == 1.5


def test_the_default_headway_needs_no_setting_and_follows_the_estimator() -> None:
    """Left out, [safety] speed_change_latency is 1 s with the IMM's speed-change model (the default estimator)
    and 0 with any other estimator, which is then accepted, not refused."""
    scenario, _ = load_scenario(SCENARIOS_DIR / "stop_and_go.toml")
    assert _built_envelope(scenario).speed_change_latency == 1.0
    for changes in ({"estimator.kind": "uplkf"}, {"estimator.imm_manoeuvre_model": False}):
        assert _built_envelope(with_overrides(scenario, changes)).speed_change_latency == 0.0


def _follow_with_noted_delays(memory: float, delays: dict[float, float], duration: float = 40.0):
    """A pursuer following a constant-velocity target on bearings at 5 Hz (the pipeline with the envelope,
    loop_delay_memory `memory` s), while a harness notes loop delays {vehicle time s: delay s}; returns the
    envelope's record."""
    from companion.assembly import vehicle_limits
    from companion.core.estimators import GainProjection, InitialGuess, UPLKF
    from companion.core.guidance import HelicalNavigationGuidance, RangeController
    from companion.core.messages import BearingMeasurement, PursuerState
    from companion.core.pipeline import FollowingPipeline
    from interfaces.scenario import table1_vehicle

    rng = np.random.default_rng(5)
    estimator = UPLKF(0.02, 0.04 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED, pursuer_position_std=0.0)
    pipeline = FollowingPipeline(estimator, HelicalNavigationGuidance(3.0, 3.5, 3.5), RangeController(8.0),
                                 vehicle_limits(table1_vehicle(), 1.0 / 1.5), InitialGuess(50.0, 30.0, np.zeros(3), 5.0),
                                 0.05, envelope=envelope(reaction_time=0.3, loop_delay_memory=memory))
    p, v = np.zeros(3), np.array([2.0, 0.0, 0.0])
    target, target_velocity = np.array([50.0, -25.0, -20.0]), np.array([3.0, 4.0, 0.0])
    dt, command = 0.02, np.zeros(3)
    for k in range(int(duration / dt) + 1):
        t = k * dt
        for at, delay in delays.items():
            if abs(t - at) < dt / 2:
                pipeline.note_loop_delay(t, delay)
        bearing = None
        if k % 10 == 0:
            los = (target - p) / np.linalg.norm(target - p)
            bearing = BearingMeasurement(t, los + rng.normal(0.0, 0.01, 3), p.copy())
        output = pipeline.step(t, PursuerState(t, p.copy(), v.copy()), bearing)
        if output.setpoint is not None:
            command = output.setpoint.acceleration
        v = v + command * dt
        p = p + v * dt
        target = target + target_velocity * dt
    return pipeline.envelope_record


def test_a_late_control_loop_lengthens_the_reaction_time_for_the_memory() -> None:
    """Delays noted at 10 s (0.4 s) and 15 s (0.2 s) with a 10 s memory: the envelope plans with the largest, 0.4 s,
    from 10 s until 25 s, when the last one is forgotten (15 s of control ticks); not kept: delays not above 0 or
    not finite, and any with the memory 0."""
    record = _follow_with_noted_delays(10.0, {10.0: 0.4, 15.0: 0.2, 30.0: 0.0, 32.0: -1.0, 34.0: math.nan})
    assert record.loop_delay_max == pytest.approx(0.4)
    assert record.loop_delay_seconds == pytest.approx(15.0, abs=0.1)
    never = _follow_with_noted_delays(0.0, {10.0: 0.4, 15.0: 0.2})
    assert never.loop_delay_max == 0.0 and never.loop_delay_seconds == 0.0
    assert _follow_with_noted_delays(10.0, {}).as_dict()["loop_delay_seconds"] == 0.0
