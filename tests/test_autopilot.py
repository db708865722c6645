"""The plant's flight stack (sitl_plant.vehicle.autopilot), driven tick by tick without sockets.

Arming and auto-disarm, takeoff/hold/land, ground contact, offboard attitude flight
and the offboard-loss failsafe for every supported COM_OBL_RC_ACT, the parameter
table and the telemetry noise. Frames: local NED, z = 0 is the ground, z < 0 is up.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl_plant.vehicle.autopilot import (
    ARMING_READY_AFTER,
    LAND_DETECT_TIME,
    Autopilot,
    OffboardAttitude,
)
from sitl_plant.vehicle.parameters import ParameterError
from sitl_plant.vehicle.params import QuadrotorParams, table1_params
from sitl_plant.vehicle.px4_modes import HOLD, LAND, OFFBOARD, POSITION, TAKEOFF, CommandResult, LandedState, Severity

PARAMS = table1_params()
G = PARAMS.gravity
DRAG_PER_MASS = PARAMS.drag_coefficient / PARAMS.mass  # 1/s, horizontal body drag at small tilt
HOVER = PARAMS.hover_thrust_normalized
GROUND_TOLERANCE = 1e-9  # m: the vehicle never sinks below z = 0 by more than this


# --------------------------------------------------------------------------- helpers


def make_autopilot(seed: int = 7, params: QuadrotorParams = PARAMS) -> Autopilot:
    return Autopilot(params, seed=seed)


def tick_checking_ground(ap: Autopilot, duration: float) -> None:
    """Tick for `duration` s, asserting after every tick that the vehicle is not below ground."""
    for _ in range(int(round(duration / ap.tick_period))):
        ap.tick()
        z = float(ap.state.position[2])
        assert z <= ap.ground_z + GROUND_TOLERANCE, f"below ground at t={ap.time:.3f}: z={z}"


def tick_until(ap: Autopilot, condition, timeout: float, what: str) -> float:
    """Tick until condition(ap) holds; returns the simulated time at the start of that tick."""
    end = ap.time + timeout
    while ap.time < end:
        started = ap.time
        ap.tick()
        if condition(ap):
            return started
    raise AssertionError(f"{what} did not happen within {timeout} s (t={ap.time:.3f}, mode={ap.mode.name})")


def texts_of(ap: Autopilot) -> list[tuple[Severity, str]]:
    return ap.take_status_texts()


def armed_after_ready(seed: int = 7) -> Autopilot:
    ap = make_autopilot(seed)
    ap.run(ARMING_READY_AFTER + 0.1)
    assert ap.arm() == CommandResult.ACCEPTED
    return ap


def hovering(altitude: float | None = None, settle: float = 3.5, seed: int = 7) -> Autopilot:
    """Armed, taken off to `altitude` (default MIS_TAKEOFF_ALT), in Hold and settled."""
    ap = armed_after_ready(seed)
    assert ap.takeoff(altitude) == CommandResult.ACCEPTED
    tick_until(ap, lambda a: a.mode == HOLD, 10.0, "takeoff complete")
    ap.run(settle)
    ap.take_status_texts()
    return ap


def pitch_quaternion(pitch: float) -> tuple[float, float, float, float]:
    """Level-yaw attitude pitched by `pitch` rad (FRD: negative = nose down), w x y z."""
    return (math.cos(0.5 * pitch), 0.0, math.sin(0.5 * pitch), 0.0)


LEVEL = (1.0, 0.0, 0.0, 0.0)


def enter_offboard(ap: Autopilot, quaternion=LEVEL, thrust: float = HOVER) -> None:
    ap.offboard_setpoint(OffboardAttitude(quaternion, thrust))
    assert ap.set_mode(OFFBOARD) == CommandResult.ACCEPTED
    assert ap.mode == OFFBOARD


def horizontal_speed(ap: Autopilot) -> float:
    v = ap.state.velocity
    return float(math.hypot(v[0], v[1]))


# --------------------------------------------------------------------------- arming


def test_arming_is_denied_before_the_estimator_is_ready_and_accepted_after() -> None:
    ap = make_autopilot()
    ap.run(0.5)
    assert ap.arm() == CommandResult.DENIED
    assert not ap.armed
    texts = texts_of(ap)
    assert any(sev == Severity.CRITICAL and "Arming denied" in text for sev, text in texts), texts

    ap.run(ARMING_READY_AFTER - 0.5 + 0.02)
    assert ap.time >= ARMING_READY_AFTER
    assert ap.arm() == CommandResult.ACCEPTED
    assert ap.armed
    assert all(sev != Severity.CRITICAL for sev, _ in texts_of(ap))


def test_force_arming_bypasses_the_readiness_check() -> None:
    ap = make_autopilot()
    ap.run(0.2)
    assert ap.arm(force=True) == CommandResult.ACCEPTED
    assert ap.armed


def test_disarm_is_refused_in_the_air_unless_forced() -> None:
    ap = hovering()
    assert ap.landed_state == LandedState.IN_AIR
    assert ap.disarm() == CommandResult.DENIED
    assert ap.armed
    texts = texts_of(ap)
    assert any(sev == Severity.CRITICAL and "Disarming denied" in text for sev, text in texts), texts
    ap.run(0.5)
    assert ap.armed and ap.state.position[2] < -2.0  # still flying

    assert ap.disarm(force=True) == CommandResult.ACCEPTED
    assert not ap.armed
    # Unpowered, it falls and stops on the ground, never below it.
    tick_checking_ground(ap, 1.5)
    assert ap.state.position[2] == pytest.approx(0.0, abs=GROUND_TOLERANCE)
    assert ap.on_ground
    assert ap.landed_state == LandedState.ON_GROUND


def test_auto_preflight_disarm_after_COM_DISARM_PRFLT_without_takeoff() -> None:
    ap = make_autopilot()
    ap.parameters.set("COM_DISARM_PRFLT", 0.5)
    ap.run(ARMING_READY_AFTER + 0.1)
    armed_at = ap.time
    assert ap.arm() == CommandResult.ACCEPTED
    texts_of(ap)
    disarmed_at = tick_until(ap, lambda a: not a.armed, 3.0, "preflight disarm")
    assert armed_at + 0.5 - 1e-9 <= disarmed_at <= armed_at + 0.5 + ap.tick_period + 1e-9
    texts = [text for _, text in texts_of(ap)]
    assert any("preflight" in text for text in texts), texts
    assert ap.state.position[2] == pytest.approx(0.0, abs=GROUND_TOLERANCE)


def test_no_preflight_disarm_when_COM_DISARM_PRFLT_is_negative() -> None:
    ap = make_autopilot()
    ap.parameters.set("COM_DISARM_PRFLT", -1.0)
    ap.run(ARMING_READY_AFTER + 0.1)
    assert ap.arm() == CommandResult.ACCEPTED
    ap.run(3.0)
    assert ap.armed


def test_disarm_after_landing_after_COM_DISARM_LAND() -> None:
    ap = hovering()
    ap.parameters.set("COM_DISARM_LAND", 1.0)
    assert ap.land() == CommandResult.ACCEPTED
    touchdown = tick_until(ap, lambda a: a.on_ground, 10.0, "touchdown")
    touchdown_end = touchdown + ap.tick_period  # ground contact is detected at the end of the tick
    assert ap.armed
    disarmed_at = tick_until(ap, lambda a: not a.armed, 5.0, "disarm after landing")
    expected = touchdown_end + LAND_DETECT_TIME + 1.0
    assert expected - 1e-9 <= disarmed_at <= expected + ap.tick_period + 1e-9
    texts = [text for _, text in texts_of(ap)]
    assert "Landing detected" in texts and any("Disarmed by landing" in t for t in texts), texts


# --------------------------------------------------------------------------- takeoff / land


def test_takeoff_is_denied_when_disarmed() -> None:
    ap = make_autopilot()
    ap.run(ARMING_READY_AFTER + 0.1)
    assert ap.takeoff() == CommandResult.DENIED
    assert ap.mode != TAKEOFF
    assert any(sev == Severity.CRITICAL and "Takeoff denied" in text for sev, text in texts_of(ap))
    ap.run(1.0)
    assert ap.state.position[2] == 0.0


@pytest.mark.parametrize("altitude", [float("nan"), 0.2, -3.0, 2000.0])
def test_takeoff_to_an_invalid_altitude_is_denied(altitude: float) -> None:
    ap = armed_after_ready()
    assert ap.takeoff(altitude) == CommandResult.DENIED
    assert ap.mode == HOLD
    ap.run(0.5)
    assert ap.on_ground


def test_takeoff_to_MIS_TAKEOFF_ALT_then_hold_with_landed_states() -> None:
    ap = armed_after_ready()
    target = ap.parameters.value("MIS_TAKEOFF_ALT")
    assert ap.landed_state == LandedState.ON_GROUND
    assert ap.takeoff() == CommandResult.ACCEPTED
    assert ap.mode == TAKEOFF
    states = [ap.landed_state]
    modes = [ap.mode]
    for _ in range(int(round(6.0 / ap.tick_period))):
        ap.tick()
        assert ap.state.position[2] <= GROUND_TOLERANCE
        if ap.landed_state != states[-1]:
            states.append(ap.landed_state)
        if ap.mode != modes[-1]:
            modes.append(ap.mode)
    assert states == [LandedState.ON_GROUND, LandedState.TAKEOFF, LandedState.IN_AIR]
    assert modes == [TAKEOFF, HOLD]
    assert -ap.state.position[2] == pytest.approx(target, abs=0.05)
    assert np.hypot(*ap.state.position[:2]) < 0.05
    assert np.linalg.norm(ap.state.velocity) < 0.05
    texts = [text for _, text in texts_of(ap)]
    assert "Takeoff complete" in texts


def test_takeoff_to_an_explicit_altitude() -> None:
    ap = armed_after_ready()
    assert ap.takeoff(4.0) == CommandResult.ACCEPTED
    tick_until(ap, lambda a: a.mode == HOLD, 10.0, "takeoff complete")
    # Takeoff ends within its tolerance of the target, Hold then brings it there.
    assert -ap.state.position[2] == pytest.approx(4.0, abs=0.15)
    tick_checking_ground(ap, 2.0)
    assert -ap.state.position[2] == pytest.approx(4.0, abs=0.05)
    assert ap.mode == HOLD and ap.landed_state == LandedState.IN_AIR


def test_takeoff_is_denied_when_already_flying() -> None:
    ap = hovering()
    z = ap.state.position[2]
    assert ap.takeoff(6.0) == CommandResult.DENIED
    assert ap.mode == HOLD
    ap.run(1.0)
    assert ap.state.position[2] == pytest.approx(z, abs=0.05)


def test_hold_keeps_position_within_centimetres() -> None:
    ap = hovering(altitude=3.0)
    start = ap.state.position
    worst = 0.0
    for _ in range(int(round(4.0 / ap.tick_period))):
        ap.tick()
        worst = max(worst, float(np.linalg.norm(ap.state.position - start)))
    assert worst < 0.03
    assert ap.mode == HOLD and ap.armed


def test_land_descends_at_MPC_LAND_SPEED_and_lands() -> None:
    ap = hovering(altitude=3.0)
    land_speed = ap.parameters.value("MPC_LAND_SPEED")
    assert ap.land() == CommandResult.ACCEPTED
    assert ap.mode == LAND
    states = [ap.landed_state]
    samples = []
    for _ in range(int(round(6.5 / ap.tick_period))):
        ap.tick()
        z = float(ap.state.position[2])
        assert z <= GROUND_TOLERANCE
        if ap.landed_state != states[-1]:
            states.append(ap.landed_state)
        if -2.2 < z < -0.5:  # past the initial transient, before touchdown
            samples.append((ap.time, z))
    assert states == [LandedState.LANDING, LandedState.ON_GROUND]
    t, z = np.array(samples).T
    rate = np.polyfit(t, z, 1)[0]
    assert rate == pytest.approx(land_speed, rel=0.05)
    assert ap.on_ground and ap.state.position[2] == 0.0


def test_land_from_height_slows_down_as_px4_does() -> None:
    """PX4's slow landing: MPC_Z_V_AUTO_DN (1.5 m/s) above MPC_LAND_ALT1 (10 m), MPC_LAND_SPEED (0.7 m/s) below
    MPC_LAND_ALT2 (5 m), the speed linear in the height between them; the descent time is their closed form."""
    ap = armed_after_ready(7)
    assert ap.takeoff(20.0) == CommandResult.ACCEPTED
    tick_until(ap, lambda a: a.mode == HOLD, 30.0, "takeoff complete")
    ap.run(3.5)
    value = ap.parameters.value
    fast, slow, high, low = (value(name) for name in ("MPC_Z_V_AUTO_DN", "MPC_LAND_SPEED", "MPC_LAND_ALT1",
                                                      "MPC_LAND_ALT2"))
    assert (fast, slow, high, low) == (1.5, 0.7, 10.0, 5.0)  # PX4's defaults
    ap.land()
    started = ap.time
    samples = []
    while not ap.on_ground and ap.time - started < 60.0:
        ap.tick()
        samples.append((ap.time, -float(ap.state.position[2]), -float(ap.state.velocity[2])))
    t, height, climb = np.array(samples).T
    assert ap.on_ground
    for band, expected in (((11.0, 18.0), fast), ((0.5, 4.5), slow), ((7.4, 7.6), slow + (fast - slow) * 0.5)):
        inside = (height > band[0]) & (height < band[1])
        assert -climb[inside] == pytest.approx(np.full(inside.sum(), expected), abs=0.08), band
    # dt = dh / v(h): (20 - 10) / fast + (10 - 5) ln(fast / slow) / (fast - slow) + 5 / slow, plus the ramp
    # from the hover at VERTICAL_ACCELERATION (fast / 2 / a of lag) and the touchdown.
    closed_form = (20.0 - high) / fast + (high - low) * math.log(fast / slow) / (fast - slow) + low / slow
    assert ap.time - started == pytest.approx(closed_form + fast / (2 * 2.0), abs=0.5)


def test_land_speed_follows_the_parameter() -> None:
    ap = hovering(altitude=3.0)
    ap.parameters.set("MPC_LAND_SPEED", 1.2)
    ap.land()
    ap.run(1.0)
    samples = []
    for _ in range(int(round(0.8 / ap.tick_period))):
        ap.tick()
        samples.append((ap.time, float(ap.state.position[2])))
    t, z = np.array(samples).T
    assert np.polyfit(t, z, 1)[0] == pytest.approx(1.2, rel=0.05)


def test_disarmed_vehicle_stays_on_the_ground_even_with_full_offboard_thrust() -> None:
    ap = make_autopilot()
    ap.run(ARMING_READY_AFTER + 0.1)
    enter_offboard(ap, pitch_quaternion(math.radians(-20.0)), 1.0)
    for _ in range(int(round(2.0 / ap.tick_period))):
        ap.offboard_setpoint(OffboardAttitude(pitch_quaternion(math.radians(-20.0)), 1.0))
        ap.tick()
        assert np.all(ap.state.position == 0.0)
        assert np.all(ap.state.velocity == 0.0)
    assert ap.thrust_command == 0.0
    assert ap.landed_state == LandedState.ON_GROUND


# --------------------------------------------------------------------------- offboard


def test_offboard_needs_a_recent_setpoint() -> None:
    ap = hovering()
    assert ap.set_mode(OFFBOARD) == CommandResult.TEMPORARILY_REJECTED
    assert ap.mode == HOLD
    texts = texts_of(ap)
    assert any(sev == Severity.CRITICAL and "Offboard" in text for sev, text in texts), texts

    ap.offboard_setpoint(OffboardAttitude(LEVEL, HOVER))
    ap.run(0.5)  # within COM_OF_LOSS_T of the setpoint
    assert ap.set_mode(OFFBOARD) == CommandResult.ACCEPTED
    assert ap.mode == OFFBOARD


def test_offboard_is_rejected_when_the_only_setpoint_is_stale() -> None:
    ap = hovering()
    ap.offboard_setpoint(OffboardAttitude(LEVEL, HOVER))
    ap.run(ap.parameters.value("COM_OF_LOSS_T") + 0.1)
    assert ap.set_mode(OFFBOARD) == CommandResult.TEMPORARILY_REJECTED
    assert ap.mode == HOLD


@pytest.mark.parametrize("tilt_deg", [8.0, 15.0])
def test_offboard_tilt_gives_g_tan_tilt_minus_drag(tilt_deg: float) -> None:
    ap = hovering(altitude=5.0)
    tilt = math.radians(tilt_deg)
    enter_offboard(ap)
    ap.run(0.3)
    quaternion = pitch_quaternion(-tilt)  # nose down: accelerate north
    thrust = HOVER / math.cos(tilt)
    samples = []
    for i in range(int(round(2.4 / ap.tick_period))):
        if i % 10 == 0:
            ap.offboard_setpoint(OffboardAttitude(quaternion, thrust))
        ap.tick()
        if i * ap.tick_period > 0.6:  # attitude transient over
            samples.append((ap.time, *ap.state.velocity))
    assert ap.mode == OFFBOARD
    data = np.array(samples)
    t, v = data[:, 0], data[:, 1:]
    slope = np.polyfit(t - t[0], v, 1)[0]
    expected_north = G * math.tan(tilt) - DRAG_PER_MASS * v[:, 0].mean()
    assert slope[0] == pytest.approx(expected_north, rel=0.05), (slope, expected_north)
    assert abs(slope[1]) < 0.05 * expected_north
    assert abs(slope[2]) < 0.15, slope  # thrust hover/cos(tilt) balances gravity
    assert ap.thrust_command == pytest.approx(thrust)


def test_offboard_without_setpoints_to_keep_it_alive_falls_back_to_position() -> None:
    """Default COM_OBL_RC_ACT is 0: Position mode."""
    ap = hovering()
    assert ap.parameters.value("COM_OBL_RC_ACT") == 0
    enter_offboard(ap)
    tick_until(ap, lambda a: a.mode != OFFBOARD, 3.0, "failsafe")
    assert ap.mode == POSITION and ap.failsafe_active


@pytest.mark.parametrize(
    "action, mode",
    [(0, POSITION), (4, LAND), (5, HOLD)],
    ids=["position", "land", "hold"],
)
def test_offboard_loss_failsafe(action: int, mode) -> None:
    ap = hovering(altitude=4.0)
    ap.parameters.set("COM_OBL_RC_ACT", action)
    ap.parameters.set("COM_OF_LOSS_T", 0.5)
    loss_timeout = ap.parameters.value("COM_OF_LOSS_T")
    tilt = math.radians(10.0)
    enter_offboard(ap)
    quaternion, thrust = pitch_quaternion(-tilt), HOVER / math.cos(tilt)
    last_setpoint = ap.time
    for i in range(int(round(1.5 / ap.tick_period))):
        if i % 25 == 0:  # 10 Hz, much faster than the timeout
            ap.offboard_setpoint(OffboardAttitude(quaternion, thrust))
            last_setpoint = ap.time
        ap.tick()
        assert ap.mode == OFFBOARD and not ap.failsafe_active
    texts_of(ap)
    fired_at = tick_until(ap, lambda a: a.mode != OFFBOARD, 3.0, "failsafe")
    assert last_setpoint + loss_timeout < fired_at <= last_setpoint + loss_timeout + ap.tick_period + 1e-9
    assert ap.mode == mode
    assert ap.failsafe_active
    texts = texts_of(ap)
    assert any(sev == Severity.CRITICAL and "offboard signal lost" in text for sev, text in texts), texts

    speed_at_failsafe = horizontal_speed(ap)
    z_at_failsafe = float(ap.state.position[2])
    assert speed_at_failsafe > 1.5  # it was really moving
    if mode == LAND:
        ap.run(1.5)
        samples = []
        for _ in range(int(round(1.0 / ap.tick_period))):
            ap.tick()
            samples.append((ap.time, float(ap.state.position[2])))
        t, z = np.array(samples).T
        assert np.polyfit(t, z, 1)[0] == pytest.approx(ap.parameters.value("MPC_LAND_SPEED"), rel=0.1)
        assert z[-1] > z_at_failsafe + 1.0
    else:
        tick_checking_ground(ap, 6.0)
        assert horizontal_speed(ap) < 0.1 < speed_at_failsafe
        assert ap.state.position[2] == pytest.approx(z_at_failsafe, abs=0.3)
        assert ap.mode == mode and ap.armed


def test_failsafe_does_not_fire_while_setpoints_arrive_and_fires_after_they_stop() -> None:
    ap = hovering()
    ap.parameters.set("COM_OF_LOSS_T", 0.5)
    enter_offboard(ap)
    last_setpoint = ap.time
    for i in range(int(round(3.0 / ap.tick_period))):
        if i % 100 == 0:  # every 0.4 s, just inside the 0.5 s timeout
            ap.offboard_setpoint(OffboardAttitude(LEVEL, HOVER))
            last_setpoint = ap.time
        ap.tick()
        assert ap.mode == OFFBOARD and not ap.failsafe_active
    assert all("offboard signal lost" not in text for _, text in texts_of(ap))
    fired_at = tick_until(ap, lambda a: a.failsafe_active, 2.0, "failsafe")
    assert last_setpoint + 0.5 < fired_at <= last_setpoint + 0.5 + ap.tick_period + 1e-9


def test_returning_to_offboard_clears_the_failsafe() -> None:
    ap = hovering()
    ap.parameters.set("COM_OF_LOSS_T", 0.3)
    enter_offboard(ap)
    tick_until(ap, lambda a: a.failsafe_active, 2.0, "failsafe")
    enter_offboard(ap)
    assert not ap.failsafe_active


# --------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    "name, value",
    [
        ("COM_OBL_RC_ACT", 4.5),  # an integer parameter given a fraction
        ("COM_OBL_RC_ACT", 3),  # Return: not something this plant can fly
        ("COM_OBL_RC_ACT", 7),
        ("COM_OBL_RC_ACT", -1),
        ("MPC_LAND_SPEED", 0.1),  # below the minimum
        ("MPC_LAND_SPEED", 10.0),  # above the maximum
        ("MPC_LAND_SPEED", float("nan")),
        ("COM_OF_LOSS_T", float("inf")),
        ("MPC_THR_HOVER", 0.95),
        ("SIM_MASS", 2.0),  # read-only
        ("SIM_MASS", PARAMS.mass),  # read-only even when unchanged
    ],
)
def test_refused_parameter_sets_raise_and_leave_the_value(name: str, value: float) -> None:
    ap = make_autopilot()
    before = ap.parameters.value(name)
    with pytest.raises(ParameterError):
        ap.parameters.set(name, value)
    assert ap.parameters.value(name) == before


def test_unknown_parameter_raises() -> None:
    ap = make_autopilot()
    with pytest.raises(ParameterError):
        ap.parameters.set("NO_SUCH_PARAM", 1.0)
    with pytest.raises(ParameterError):
        ap.parameters.value("NO_SUCH_PARAM")


def test_accepted_parameter_sets_store_the_value() -> None:
    ap = make_autopilot()
    for action in (4, 5, 0):
        ap.parameters.set("COM_OBL_RC_ACT", action)
        assert ap.parameters.value("COM_OBL_RC_ACT") == action
    ap.parameters.set("COM_OBL_RC_ACT", 4.0)  # integral float is fine
    assert ap.parameters.value("COM_OBL_RC_ACT") == 4
    ap.parameters.set("MPC_LAND_SPEED", 1.1)
    assert ap.parameters.value("MPC_LAND_SPEED") == 1.1
    assert ap.parameters.value("MPC_THR_HOVER") == pytest.approx(1.0 / 1.5)
    assert ap.parameters.value("SIM_MASS") == PARAMS.mass


# --------------------------------------------------------------------------- telemetry


def test_telemetry_noise_is_shared_within_a_tick_and_fresh_across_ticks() -> None:
    ap = make_autopilot(seed=11)
    ap.tick()
    first = ap.telemetry()
    again = ap.telemetry()
    np.testing.assert_array_equal(first.position, again.position)
    np.testing.assert_array_equal(first.velocity, again.velocity)
    assert np.any(first.position != 0.0)  # noisy, although the vehicle sits at the origin
    ap.tick()
    later = ap.telemetry()
    assert np.all(later.position != first.position)
    assert np.all(later.velocity != first.velocity)
    assert later.time == pytest.approx(first.time + ap.tick_period)


def test_telemetry_noise_std_matches_the_airframe_and_is_seeded() -> None:
    ap = make_autopilot(seed=3)
    twin = make_autopilot(seed=3)
    other = make_autopilot(seed=4)
    positions, velocities = [], []
    for _ in range(1500):
        ap.tick()
        twin.tick()
        other.tick()
        t = ap.telemetry()
        positions.append(t.position)
        velocities.append(t.velocity)
        np.testing.assert_array_equal(twin.telemetry().position, t.position)
    assert np.any(other.telemetry().position != ap.telemetry().position)
    positions, velocities = np.array(positions), np.array(velocities)
    # The vehicle sits still at the origin, so all spread is noise.
    assert np.all(ap.state.position == 0.0)
    np.testing.assert_allclose(positions.std(axis=0), PARAMS.position_noise_std, rtol=0.08)
    np.testing.assert_allclose(velocities.std(axis=0), PARAMS.velocity_noise_std, rtol=0.08)
    np.testing.assert_allclose(positions.mean(axis=0), 0.0, atol=0.01)
    np.testing.assert_allclose(velocities.mean(axis=0), 0.0, atol=0.005)


@pytest.mark.parametrize("value", ["1.0", None, True, [1.0]])
def test_parameter_set_with_a_non_number_is_a_parameter_error(value) -> None:
    ap = Autopilot(PARAMS, seed=0)
    before = ap.parameters.value("COM_OF_LOSS_T")
    with pytest.raises(ParameterError):
        ap.parameters.set("COM_OF_LOSS_T", value)
    assert ap.parameters.value("COM_OF_LOSS_T") == before
