"""Physics checks of the SITL plant: rigid body (eq. (20)), motor lag, saturation, drag,
geometric attitude control (eq. (24)), mixer and the attitude/thrust vehicle."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle, GeometricAttitudeController, Mixer
from sitl_plant.vehicle.params import table1_params
from sitl_plant.vehicle.quadrotor import ROTOR_LAYOUT, Quadrotor, RigidBodyState, hover_rotor_speed, rotor_wrench

PARAMS = table1_params()
M, G = PARAMS.mass, PARAMS.gravity
DT = 1.0 / 500.0
E_Z = np.array([0.0, 0.0, 1.0])


def euler(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Body FRD -> NED from aerospace yaw-pitch-roll (rad)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def angle_between(r_a: np.ndarray, r_b: np.ndarray) -> float:
    return float(Rotation.from_matrix(r_a.T @ r_b).magnitude())


def state_with(**changes: object) -> RigidBodyState:
    base = RigidBodyState.hover(PARAMS)
    fields = {k: getattr(base, k) for k in ("position", "velocity", "rotation", "angular_velocity", "rotor_speeds")}
    fields.update(changes)
    return RigidBodyState(**fields)


def run_open_loop(quad: Quadrotor, command: np.ndarray, seconds: float, dt: float = DT) -> None:
    for _ in range(round(seconds / dt)):
        quad.step(dt, command)


# --------------------------------------------------------------------------- hover


def test_hover_is_an_open_loop_equilibrium() -> None:
    start = RigidBodyState.hover(PARAMS, position=np.array([3.0, -2.0, -20.0]), yaw=0.7)
    quad = Quadrotor(PARAMS, start)
    run_open_loop(quad, np.full(4, hover_rotor_speed(PARAMS)), 5.0)
    end = quad.state
    np.testing.assert_allclose(end.position, start.position, atol=1e-9)
    np.testing.assert_allclose(end.velocity, 0.0, atol=1e-9)
    np.testing.assert_allclose(end.rotation, start.rotation, atol=1e-12)
    np.testing.assert_allclose(end.angular_velocity, 0.0, atol=1e-12)
    assert quad.total_thrust == pytest.approx(M * G, rel=1e-12)


def test_hover_is_a_closed_loop_equilibrium() -> None:
    start = RigidBodyState.hover(PARAMS, position=np.array([0.0, 0.0, -30.0]), yaw=-2.0)
    vehicle = AttitudeThrustVehicle(PARAMS, start, rng=0)
    vehicle.set_attitude_target(start.rotation, PARAMS.hover_thrust)
    vehicle.advance(5.0)
    end = vehicle.state
    np.testing.assert_allclose(end.position, start.position, atol=1e-9)
    np.testing.assert_allclose(end.velocity, 0.0, atol=1e-9)
    np.testing.assert_allclose(end.rotation, start.rotation, atol=1e-12)
    np.testing.assert_allclose(end.rotor_speeds, start.rotor_speeds, rtol=1e-12)
    assert vehicle.time == pytest.approx(5.0)


# --------------------------------------------------------------------------- motor lag


def test_motor_lag_reaches_63_percent_at_time_constant() -> None:
    t_m = PARAMS.motor_time_constant
    w0 = hover_rotor_speed(PARAMS)
    command = np.full(4, w0 + 100.0)

    # Steps dividing T_m exactly: the lag is solved in closed form, so this is exact.
    quad = Quadrotor(PARAMS)
    run_open_loop(quad, command, t_m, dt=t_m / 10)
    fraction = (quad.state.rotor_speeds - w0) / 100.0
    np.testing.assert_allclose(fraction, 1.0 - math.exp(-1.0), rtol=1e-9)

    # At the project's 500 Hz, T_m falls between steps 6 and 7: bracket 63.2 %.
    quad = Quadrotor(PARAMS)
    fractions = [0.0]
    for _ in range(10):
        quad.step(DT, command)
        fractions.append(float((quad.state.rotor_speeds[0] - w0) / 100.0))
    k = int(t_m // DT)
    assert fractions[k] < 1.0 - math.exp(-1.0) < fractions[k + 1]
    assert fractions[7] == pytest.approx(1.0 - math.exp(-7 * DT / t_m), rel=1e-9)


# --------------------------------------------------------------------------- free fall and drag


def test_free_fall_accelerates_at_g() -> None:
    quad = Quadrotor(PARAMS, state_with(rotor_speeds=np.zeros(4)))
    np.testing.assert_allclose(quad.acceleration, G * E_Z, atol=1e-12)
    run_open_loop(quad, np.zeros(4), 1.0)
    np.testing.assert_allclose(quad.state.velocity, G * E_Z, atol=1e-9)
    np.testing.assert_allclose(quad.state.position, 0.5 * G * E_Z, atol=1e-9)
    assert quad.total_thrust == 0.0


@pytest.mark.parametrize("yaw", [0.0, 0.5, -2.5])
def test_body_horizontal_velocity_decays_with_linear_drag(yaw: float) -> None:
    v0 = np.array([3.0, -2.0, 0.0])
    quad = Quadrotor(PARAMS, state_with(rotation=euler(yaw), velocity=v0))
    np.testing.assert_allclose(quad.acceleration, -PARAMS.drag_coefficient / M * v0, atol=1e-12)
    run_open_loop(quad, np.full(4, hover_rotor_speed(PARAMS)), 2.0)
    expected = v0 * math.exp(-PARAMS.drag_coefficient / M * 2.0)
    np.testing.assert_allclose(quad.state.velocity, expected, atol=1e-9)


def test_no_drag_along_body_z() -> None:
    v0 = np.array([0.0, 0.0, -2.0])
    quad = Quadrotor(PARAMS, state_with(velocity=v0))
    run_open_loop(quad, np.full(4, hover_rotor_speed(PARAMS)), 1.0)
    np.testing.assert_allclose(quad.state.velocity, v0, atol=1e-12)


# --------------------------------------------------------------------------- saturation


def test_huge_rotor_commands_never_exceed_1_5_g() -> None:
    quad = Quadrotor(PARAMS)
    for _ in range(100):
        quad.step(DT, np.full(4, 1e6))
        assert quad.total_thrust <= PARAMS.max_total_thrust * (1 + 1e-12)
    assert quad.total_thrust == pytest.approx(1.5 * M * G, rel=1e-3)
    assert quad.acceleration[2] == pytest.approx(-0.5 * G, rel=1e-3)


def test_vehicle_thrust_saturates_at_1_5_g() -> None:
    vehicle = AttitudeThrustVehicle(PARAMS, rng=0)
    vehicle.set_attitude_target(euler(0.3, 0.2, -0.1), 1e4)
    for _ in range(100):
        vehicle.advance(0.01)
        assert vehicle.quadrotor.total_thrust <= PARAMS.max_total_thrust * (1 + 1e-12)
        assert np.all(vehicle.state.rotor_speeds <= PARAMS.max_rotor_speed * (1 + 1e-12))


# --------------------------------------------------------------------------- attitude control


@pytest.mark.parametrize(
    ("start", "target"),
    [
        (euler(0.0, 0.35, 0.52), euler()),  # 20 deg pitch, 30 deg roll
        (euler(1.05, -0.3, 0.4), euler()),  # plus 60 deg of yaw
        (euler(), euler(-0.8, -0.25, 0.2)),  # yawed, tilted target
    ],
)
def test_attitude_converges_within_two_seconds(start: np.ndarray, target: np.ndarray) -> None:
    vehicle = AttitudeThrustVehicle(PARAMS, state_with(rotation=start), rng=0)
    vehicle.set_attitude_target(target, PARAMS.hover_thrust)
    vehicle.advance(2.0)
    assert angle_between(vehicle.state.rotation, target) < math.radians(1.0)
    for _ in range(10):
        vehicle.advance(0.1)
        assert angle_between(vehicle.state.rotation, target) < math.radians(1.0)
    np.testing.assert_allclose(vehicle.state.angular_velocity, 0.0, atol=1e-2)


@pytest.mark.parametrize(
    ("yaw", "pitch", "roll", "direction"),
    [
        (0.0, -10.0, 0.0, [1.0, 0.0, 0.0]),  # FRD nose down -> north (forward)
        (90.0, -10.0, 0.0, [0.0, 1.0, 0.0]),  # facing east, nose down -> east
        (0.0, 0.0, 10.0, [0.0, 1.0, 0.0]),  # right wing down -> right (east)
        (0.0, 10.0, 0.0, [-1.0, 0.0, 0.0]),  # nose up -> south (backward)
    ],
)
def test_constant_tilt_gives_horizontal_acceleration(
    yaw: float, pitch: float, roll: float, direction: list[float]
) -> None:
    tilt = math.radians(10)
    target = euler(math.radians(yaw), math.radians(pitch), math.radians(roll))
    thrust = M * G / math.cos(tilt)
    vehicle = AttitudeThrustVehicle(PARAMS, RigidBodyState.hover(PARAMS, yaw=math.radians(yaw)), rng=0)
    vehicle.set_attitude_target(target, thrust)
    vehicle.advance(2.0)
    state = vehicle.state
    assert angle_between(state.rotation, target) < math.radians(0.01)

    # eq. (20b) with the commanded attitude, plus the drag at the current velocity.
    r3 = target[:, 2]
    v = state.velocity
    expected = G * E_Z - thrust / M * r3 - PARAMS.drag_coefficient / M * (v - r3 * (r3 @ v))
    accel = vehicle.quadrotor.acceleration
    np.testing.assert_allclose(accel, expected, atol=2e-3)

    horizontal = thrust / M * math.sin(tilt)
    assert accel @ np.array(direction) == pytest.approx(horizontal, rel=0.1)  # drag costs ~8 % at 3.4 m/s
    assert abs(accel[2]) < 0.05
    assert v @ np.array(direction) > 0.98 * np.linalg.norm(v)


def test_attitude_error_is_sine_of_angle_times_axis() -> None:
    rd = euler(0.4, -0.2, 0.1)
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    theta = 0.3
    r = rd @ Rotation.from_rotvec(theta * axis).as_matrix()
    e_r = GeometricAttitudeController.attitude_error(r, rd)
    np.testing.assert_allclose(e_r, math.sin(theta) * axis, atol=1e-12)


def test_torque_without_error_gives_desired_angular_acceleration() -> None:
    """With e_R = e_w = 0, eq. (24) in eq. (20d) must give omega' = R^T R_d omega_d' (here R = R_d)."""
    ctrl = GeometricAttitudeController(PARAMS)
    rng = np.random.default_rng(3)
    rotation = Rotation.random(random_state=4).as_matrix()
    w_d = rng.normal(size=3)
    w_d_dot = rng.normal(size=3)
    tau = ctrl.torque(rotation, w_d, rotation, w_d, w_d_dot)
    j = PARAMS.inertia_matrix
    w_dot = np.linalg.solve(j, tau - np.cross(w_d, j @ w_d))
    np.testing.assert_allclose(w_dot, w_d_dot, atol=1e-12)
    np.testing.assert_allclose(ctrl.torque(rotation, np.zeros(3), rotation), 0.0, atol=1e-15)


# --------------------------------------------------------------------------- mixer


def test_allocation_matches_rotor_layout_physics() -> None:
    """Thrust along body -z at each hub (r x F) plus +C_m w^2 yaw for CCW rotors."""
    a = PARAMS.arm_length / math.sqrt(2.0)
    speeds = np.array([500.0, 610.0, 555.0, 430.0])
    force = np.zeros(3)
    torque = np.zeros(3)
    for (x_sign, y_sign, spin), w in zip(ROTOR_LAYOUT, speeds):
        f = np.array([0.0, 0.0, -PARAMS.thrust_coefficient * w**2])
        force += f
        torque += np.cross([x_sign * a, y_sign * a, 0.0], f)
        torque[2] += spin * PARAMS.moment_coefficient * w**2
    thrust, tau = rotor_wrench(PARAMS, speeds)
    assert thrust == pytest.approx(-force[2], rel=1e-14)
    np.testing.assert_allclose(tau, torque, rtol=1e-12, atol=1e-15)
    # Hub positions are PX4 quad X: 1 front-right, 2 rear-left, 3 front-left, 4 rear-right.
    assert [(x, y) for x, y, _ in ROTOR_LAYOUT] == [(1, 1), (-1, -1), (1, -1), (-1, 1)]


@settings(max_examples=200, deadline=None)
@given(
    thrust=st.floats(0.7 * M * G, 1.2 * M * G),
    tx=st.floats(-0.2, 0.2),
    ty=st.floats(-0.2, 0.2),
    tz=st.floats(-0.02, 0.02),
)
def test_mixer_inverts_allocation_when_unsaturated(thrust: float, tx: float, ty: float, tz: float) -> None:
    mixer = Mixer(PARAMS)
    speeds = mixer.rotor_speeds(thrust, np.array([tx, ty, tz]))
    assert np.all(speeds > 0.0) and np.all(speeds < PARAMS.max_rotor_speed)
    thrust_out, torque_out = mixer.allocation(speeds)
    assert thrust_out == pytest.approx(thrust, rel=1e-12)
    np.testing.assert_allclose(torque_out, [tx, ty, tz], atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(
    thrust=st.floats(-50.0, 100.0),
    tx=st.floats(-20.0, 20.0),
    ty=st.floats(-20.0, 20.0),
    tz=st.floats(-5.0, 5.0),
)
def test_mixer_output_is_always_feasible(thrust: float, tx: float, ty: float, tz: float) -> None:
    mixer = Mixer(PARAMS)
    speeds = mixer.rotor_speeds(thrust, np.array([tx, ty, tz]))
    assert np.all(speeds >= 0.0) and np.all(speeds <= PARAMS.max_rotor_speed)
    thrust_out, torque_out = mixer.allocation(speeds)
    assert thrust_out <= PARAMS.max_total_thrust * (1 + 1e-12)
    # Saturation shrinks torques but never reverses them.
    for commanded, delivered in zip((tx, ty, tz), torque_out):
        assert commanded * delivered >= -1e-9


def test_mixer_gives_up_yaw_before_roll_and_pitch() -> None:
    mixer = Mixer(PARAMS)
    torque = np.array([0.3, -0.2, 5.0])
    thrust_out, torque_out = mixer.allocation(mixer.rotor_speeds(M * G, torque))
    assert thrust_out == pytest.approx(M * G, rel=1e-12)
    np.testing.assert_allclose(torque_out[:2], torque[:2], rtol=1e-12)
    assert 0.0 < torque_out[2] < torque[2]


def test_mixer_keeps_roll_at_full_thrust() -> None:
    mixer = Mixer(PARAMS)
    thrust_out, torque_out = mixer.allocation(mixer.rotor_speeds(10 * M * G, np.array([0.5, 0.0, 0.0])))
    assert torque_out[0] == pytest.approx(0.5, rel=1e-12)
    assert thrust_out < PARAMS.max_total_thrust


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_body_torque_spins_the_right_way(axis: int) -> None:
    mixer = Mixer(PARAMS)
    torque = np.zeros(3)
    torque[axis] = 0.02
    speeds = mixer.rotor_speeds(M * G, torque)
    if axis == 2:
        # Positive FRD yaw needs the CCW rotors (1, 2) faster.
        assert speeds[0] > speeds[2] and speeds[1] > speeds[3]
    quad = Quadrotor(PARAMS)
    run_open_loop(quad, speeds, 0.3)
    w = quad.state.angular_velocity
    assert w[axis] > 0.0
    np.testing.assert_allclose(np.delete(w, axis), 0.0, atol=1e-9)
    if axis == 2:
        r = quad.state.rotation
        assert math.atan2(r[1, 0], r[0, 0]) > 0.0  # nose swung from north towards east


# --------------------------------------------------------------------------- rotation / rigid body


def test_rotation_stays_orthonormal_through_long_manoeuvring() -> None:
    vehicle = AttitudeThrustVehicle(PARAMS, rng=0)
    for k in range(3000):  # 60 s at 50 Hz setpoints
        t = k * 0.02
        target = euler(yaw=2.0 * t, pitch=0.5 * math.sin(1.3 * t), roll=0.6 * math.cos(0.9 * t))
        vehicle.set_attitude_target(target, M * G * (1.0 + 0.3 * math.sin(0.4 * t)))
        vehicle.advance(0.02)
        if k % 50 == 0:
            r = vehicle.state.rotation
            np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-13)
            assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-13)
    assert vehicle.time == pytest.approx(60.0)


def test_torque_free_tumbling_conserves_energy_and_momentum() -> None:
    """Equal rotor speeds give zero torque: eq. (20d) must conserve |J w| and w.J w / 2."""
    w0 = np.array([3.0, -2.0, 5.0])
    quad = Quadrotor(PARAMS, state_with(angular_velocity=w0))
    j = PARAMS.inertia_matrix
    energy0 = 0.5 * w0 @ j @ w0
    momentum0 = quad.state.rotation @ j @ w0  # inertial angular momentum
    run_open_loop(quad, np.full(4, hover_rotor_speed(PARAMS)), 10.0)
    s = quad.state
    assert 0.5 * s.angular_velocity @ j @ s.angular_velocity == pytest.approx(energy0, rel=1e-7)
    np.testing.assert_allclose(s.rotation @ j @ s.angular_velocity, momentum0, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(s.rotation.T @ s.rotation, np.eye(3), atol=1e-13)


# --------------------------------------------------------------------------- vehicle API


def test_measured_state_noise_is_seeded_and_has_the_configured_spread() -> None:
    a = AttitudeThrustVehicle(PARAMS, rng=np.random.default_rng(42))
    b = AttitudeThrustVehicle(PARAMS, rng=np.random.default_rng(42))
    samples_a = [np.concatenate(a.measured_state()) for _ in range(4000)]
    samples_b = [np.concatenate(b.measured_state()) for _ in range(4000)]
    np.testing.assert_array_equal(samples_a, samples_b)
    samples = np.array(samples_a)
    np.testing.assert_allclose(samples.mean(axis=0), 0.0, atol=0.01)
    stds = samples.std(axis=0)
    np.testing.assert_allclose(stds[:3], PARAMS.position_noise_std, rtol=0.05)
    np.testing.assert_allclose(stds[3:], PARAMS.velocity_noise_std, rtol=0.05)


def test_advance_rejects_durations_that_are_not_whole_steps() -> None:
    vehicle = AttitudeThrustVehicle(PARAMS, rng=0)
    with pytest.raises(ValueError):
        vehicle.advance(0.0011)
    with pytest.raises(ValueError):
        vehicle.advance(-0.002)
    with pytest.raises(ValueError):
        vehicle.advance(float("inf"))
    for _ in range(50):
        vehicle.advance(0.02)
    assert vehicle.time == pytest.approx(1.0, abs=1e-12)
    with pytest.raises(ValueError):
        AttitudeThrustVehicle(PARAMS, rate_hz=400.0)


def test_state_is_a_copy_and_inputs_are_validated() -> None:
    quad = Quadrotor(PARAMS)
    s = quad.state
    s.position[0] = 99.0
    assert quad.state.position[0] == 0.0
    with pytest.raises(ValueError):
        state_with(rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError):
        AttitudeThrustVehicle(PARAMS, rng=0).set_attitude_target(2.0 * np.eye(3), M * G)


def test_kinematics_reads_the_state_without_building_it():
    # The in-process simulator's per-tick read-out: the same numbers as state's position, velocity and rotation.
    vehicle = AttitudeThrustVehicle(PARAMS, RigidBodyState.hover(PARAMS, yaw=0.7), rng=0)
    tilted = Rotation.from_euler("ZYX", [0.7, 0.2, -0.1]).as_matrix()
    vehicle.set_attitude_target(tilted, 1.1 * PARAMS.hover_thrust)
    vehicle.advance(0.5)
    position, velocity, rotation = vehicle.kinematics()
    state = vehicle.state
    assert np.array(position).tobytes() == state.position.tobytes()
    assert np.array(velocity).tobytes() == state.velocity.tobytes()
    assert np.array(rotation).reshape(3, 3).tobytes() == state.rotation.tobytes()
    assert np.linalg.norm(state.velocity) > 0.1  # it moved: the comparison is not of the start
