"""The plant's own position controller (sitl_plant.vehicle.position_control) against physics.

References are independent of the controller's code: hover is m g, the attitude's body z
is read back with scipy's Rotation and compared with the specific force a - g e_Z, the
steady state of a point mass flown in closed loop is compared with zero (PID) and with
the closed-form offset of a P-P cascade, and the full plant holds a height with a wrong
hover-thrust parameter.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sitl_plant.vehicle.autopilot import ARMING_READY_AFTER, Autopilot
from sitl_plant.vehicle.params import QuadrotorParams, table1_params
from sitl_plant.vehicle.position_control import (
    ControlLimits,
    PositionControlGains,
    PositionController,
    TrajectorySetpoint,
    limit_horizontal_speed,
    thrust_to_attitude,
    thrust_vector,
    trapezoidal_profile,
)
from sitl_plant.vehicle.px4_modes import HOLD, CommandResult

PARAMS: QuadrotorParams = table1_params()
G = PARAMS.gravity
E_Z = np.array([0.0, 0.0, 1.0])
GAINS = PositionControlGains()
LIMITS = ControlLimits(hover_thrust=PARAMS.hover_thrust_normalized, max_tilt=math.radians(35.0), max_speed_xy=5.0,
                       gravity=G)
DT = 0.02  # 50 Hz, the autopilot's position-control rate

finite = st.floats(-60.0, 60.0, allow_nan=False)
accelerations = st.tuples(finite, finite, finite).map(np.array)


def body_axes(quaternion) -> np.ndarray:
    """Columns: body x, y, z in NED, from an independent library."""
    return Rotation.from_quat(np.asarray(quaternion), scalar_first=True).as_matrix()


def tilt(quaternion) -> float:
    return math.acos(min(1.0, float(body_axes(quaternion)[2, 2])))


def test_hover_thrust_carries_m_g_and_the_attitude_is_level_on_the_heading() -> None:
    controller = PositionController()
    at = np.array([1.0, -2.0, -5.0])
    out = controller.update(DT, at, np.zeros(3), np.zeros(3), TrajectorySetpoint(position=at, yaw=0.7), LIMITS)
    # Normalised thrust times the full thrust of the airframe is the weight.
    assert out.thrust * PARAMS.max_total_thrust == pytest.approx(PARAMS.mass * G, rel=1e-12)
    np.testing.assert_allclose(body_axes(out.quaternion), Rotation.from_euler("z", 0.7).as_matrix(), atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(accelerations, st.floats(10.0, 60.0), st.floats(0.2, 0.8))
def test_tilt_and_thrust_limits_hold_for_any_commanded_acceleration(acceleration, max_tilt_deg, hover) -> None:
    limits = ControlLimits(hover, math.radians(max_tilt_deg), 5.0, G)
    thrust = thrust_vector(acceleration, limits, GAINS)
    quaternion, collective = thrust_to_attitude(thrust, 0.3)
    assert tilt(quaternion) <= math.radians(max_tilt_deg) + 1e-9
    assert GAINS.thrust_min - 1e-12 <= collective <= GAINS.thrust_max + 1e-12
    assert -thrust[2] >= GAINS.thrust_min - 1e-12  # never less than MPC_THR_MIN upwards


@settings(max_examples=300, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-math.pi, math.pi))
def test_thrust_points_along_the_commanded_acceleration_minus_gravity(ax, ay, az, yaw) -> None:
    """Inside the limits (here at most 32 deg of tilt and 0.92 of full thrust), eq. (20b) of the
    rigid body: thrust/m along -body z must equal a - g e_Z."""
    acceleration = np.array([ax, ay, az])
    quaternion, collective = thrust_to_attitude(thrust_vector(acceleration, LIMITS, GAINS), yaw)
    axes = body_axes(quaternion)
    specific_force = collective * PARAMS.max_total_thrust / PARAMS.mass * -axes[:, 2]  # N / kg along -body z
    np.testing.assert_allclose(specific_force + G * E_Z, acceleration, atol=1e-9)
    # Nose in the vertical plane of the heading, pointing forward.
    heading = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    assert abs(float(axes[:, 0] @ np.cross(E_Z, heading))) < 1e-9
    assert float(axes[:, 0] @ heading) > 0.0


@settings(max_examples=300, deadline=None)
@given(st.tuples(finite, finite).map(np.array), st.tuples(finite, finite).map(np.array), st.floats(0.5, 20.0))
def test_horizontal_speed_limit_keeps_the_feedforward_first(position_part, feedforward, max_speed) -> None:
    velocity = limit_horizontal_speed(position_part, feedforward, max_speed)
    assert float(np.hypot(*velocity)) <= max_speed * (1 + 1e-9)
    if float(np.hypot(*feedforward)) <= max_speed:
        # feedforward + s * position_part with s in [0, 1]: the rest lies along the position part,
        # points the same way and is no longer (to the rounding of the sum, relative to its terms)
        rest = velocity - feedforward
        length = float(np.hypot(*position_part))
        rounding = 1e-12 * (1.0 + float(np.hypot(*feedforward)) + length)
        assert float(np.hypot(*rest)) <= length + rounding
        assert float(rest @ position_part) >= -rounding * length
        assert abs(float(rest[0] * position_part[1] - rest[1] * position_part[0])) <= rounding * length


def fly_point_mass(controller: PositionController, setpoint: TrajectorySetpoint, true_hover: float,
                   disturbance: np.ndarray, duration: float, drag_per_mass: float = 0.0,
                   start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A point mass under gravity, the rotor thrust along -body z (linear thrust curve whose real
    hover thrust is true_hover), linear drag and a constant disturbance (m/s^2). Returns (p, v)."""
    p = np.zeros(3) if start is None else start.copy()
    v = np.zeros(3)
    a = np.zeros(3)
    for _ in range(int(round(duration / DT))):
        out = controller.update(DT, p, v, a, setpoint, LIMITS)
        up = -body_axes(out.quaternion)[:, 2]
        a = out.thrust * G / true_hover * up + G * E_Z - drag_per_mass * v + disturbance
        v = v + a * DT
        p = p + v * DT
    return p, v


def test_hold_error_goes_to_zero_with_a_wrong_hover_thrust_and_a_steady_wind() -> None:
    target = np.array([2.0, -1.0, -5.0])
    wind = np.array([0.4, -0.3, 0.0])
    p, v = fly_point_mass(PositionController(), TrajectorySetpoint(position=target), 0.6, wind, 60.0,
                          drag_per_mass=PARAMS.drag_coefficient / PARAMS.mass)
    np.testing.assert_allclose(p, target, atol=1e-3)
    np.testing.assert_allclose(v, 0.0, atol=1e-3)


def test_without_integrators_the_offset_is_the_closed_form_of_a_p_p_cascade() -> None:
    """With no integral action a wrong hover thrust leaves a steady height error: the vertical
    loop must ask for a = g (1 - true_hover / believed_hover), so e_z = a / (K_p,z K_v,z)."""
    gains = PositionControlGains(velocity_xy_i=0.0, velocity_z_i=0.0)
    true_hover = 0.6
    target = np.array([0.0, 0.0, -5.0])
    p, _ = fly_point_mass(PositionController(gains), TrajectorySetpoint(position=target), true_hover, np.zeros(3), 40.0)
    needed = G * (1.0 - true_hover / LIMITS.hover_thrust)
    expected_error = needed / (gains.position_z * gains.velocity_z_p)  # target - position, NED z
    assert target[2] - p[2] == pytest.approx(expected_error, rel=1e-3)
    assert abs(expected_error) > 0.1  # so the PID's zero above is not trivially small


def test_velocity_setpoint_is_tracked_against_drag() -> None:
    velocity = np.array([3.0, -1.0, 0.5])
    p, v = fly_point_mass(PositionController(), TrajectorySetpoint(velocity=velocity), LIMITS.hover_thrust, np.zeros(3),
                          30.0, drag_per_mass=PARAMS.drag_coefficient / PARAMS.mass, start=np.array([0.0, 0.0, -50.0]))
    np.testing.assert_allclose(v, velocity, atol=1e-3)


def test_the_plant_holds_its_height_although_MPC_THR_HOVER_is_wrong() -> None:
    """The full flight stack: rotors, motor lag, attitude loop. The P-P offset would be
    g (1 - 0.667/0.6) / (1 * 4) = 0.27 m; the integrator takes it away."""
    ap = Autopilot(PARAMS, seed=3)
    ap.run(ARMING_READY_AFTER + 0.1)
    assert ap.arm() == CommandResult.ACCEPTED and ap.takeoff(4.0) == CommandResult.ACCEPTED
    while ap.mode != HOLD:
        ap.tick()
    ap.parameters.set("MPC_THR_HOVER", 0.6)
    ap.run(25.0)
    assert ap.state.position[2] == pytest.approx(-4.0, abs=0.01)
    assert np.hypot(*ap.state.position[:2]) < 0.01


def test_acceleration_only_is_flown_open_loop() -> None:
    controller = PositionController()
    command = np.array([1.0, 0.5, -0.5])
    out = controller.update(DT, np.zeros(3), np.array([5.0, 5.0, 5.0]), np.zeros(3),
                            TrajectorySetpoint(acceleration=command), LIMITS)
    np.testing.assert_allclose(out.acceleration, command, atol=1e-12)  # the velocity is not fed back


@settings(max_examples=100, deadline=None)
@given(st.floats(0.05, 100.0), st.floats(0.3, 5.0), st.floats(0.5, 5.0))
def test_takeoff_profile_is_a_rest_to_rest_move_within_its_limits(distance, max_speed, acceleration) -> None:
    """Integrating the profile's acceleration gives its speed, and its speed its position
    (trapezoidal rule); it ends at rest on the distance and never exceeds its limits."""
    peak = min(max_speed, math.sqrt(distance * acceleration))
    duration = distance / peak + peak / acceleration  # closed form of a trapezoid / triangle
    times = np.linspace(0.0, duration + 1.0, 20001)
    s, v, a = np.array([trapezoidal_profile(distance, max_speed, acceleration, t) for t in times]).T
    step = times[1] - times[0]
    assert np.all(v <= max_speed + 1e-12) and np.all(np.abs(a) <= acceleration + 1e-12) and np.all(v >= -1e-12)
    np.testing.assert_allclose(np.cumsum((v[1:] + v[:-1]) / 2) * step, s[1:], atol=1e-3 * max(distance, 1.0))
    np.testing.assert_allclose(np.cumsum((a[1:] + a[:-1]) / 2) * step, v[1:], atol=2 * acceleration * step)
    assert s[-1] == distance and v[-1] == 0.0
    assert s[np.searchsorted(times, duration * 0.999)] < distance
