"""Autopilot low-level side: geometric attitude control (eq. (23)-(24)), mixing and the
attitude/thrust-setpoint vehicle that the companion side drives.

Frames as in sitl_plant.vehicle.quadrotor: NED inertial, FRD body, R maps body -> NED.
The hot loop (controller, mixer, plant step) is sitl_plant.vehicle.kernels.advance_steps on
plain floats and tuples (compiled by numba when it is installed); the classes here hold the
setpoint and the constants and call those kernels. numpy arrays appear only at the public boundary.
"""

from __future__ import annotations

import math

import numpy as np

from sitl_plant.vehicle import kernels
from sitl_plant.vehicle.params import QuadrotorParams
from sitl_plant.vehicle.quadrotor import (
    Quadrotor,
    RigidBodyState,
    Vec3,
    check_rotation,
    quaternion_to_rotation,
    rotation_to_quaternion,
    rotor_wrench,
)

Quat = tuple[float, float, float, float]

_ZERO3: Vec3 = kernels.ZERO3

MIN_RATE_HZ = 500.0


def _vec3(v: np.ndarray | None, name: str) -> Vec3:
    if v is None:
        return _ZERO3
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


class GeometricAttitudeController:
    """PD controller on the tangent bundle of SO(3), paper eq. (23)-(24).

    tau = -k_p e_R - k_d e_w + [w]x J w - J([w]x R^T R_d w_d - R^T R_d w_d')   (24)

    with e_w = w - R^T R_d w_d and the attitude error of Lee et al. (the paper's
    ref. [55]), e_R = 1/2 (R_d^T R - R^T R_d)^vee. Section VII prints the two
    products the other way round; with tau = -k_p e_R that sign would be positive
    feedback (R = R_d exp(theta [a]x) gives (R^T R_d - R_d^T R)^vee / 2 = -theta a),
    so the stable convention of [55] is used. Gains: params.attitude_kp
    (N m / rad) and params.attitude_kd (N m s / rad).

    The hot path works on unit quaternions (w, x, y, z): for R_e = R_d^T R = R(q_e),
    q_e = q_d^* (x) q, the error is exactly e_R = 2 w_e (x_e, y_e, z_e).
    """

    def __init__(self, params: QuadrotorParams) -> None:
        self.params = params
        self._c = kernels.control_constants(params)

    @staticmethod
    def attitude_error(rotation: np.ndarray, rotation_desired: np.ndarray) -> np.ndarray:
        """e_R of eq. (24), shape (3,), body frame; equals sin(angle) * axis of R_d^T R."""
        qe = kernels.error_quaternion(
            rotation_to_quaternion(check_rotation(rotation)),
            rotation_to_quaternion(check_rotation(rotation_desired, "rotation_desired")),
        )
        return np.array([2.0 * qe[0] * qe[1], 2.0 * qe[0] * qe[2], 2.0 * qe[0] * qe[3]])

    def torque(
        self,
        rotation: np.ndarray,
        angular_velocity: np.ndarray,
        rotation_desired: np.ndarray,
        angular_velocity_desired: np.ndarray | None = None,
        angular_acceleration_desired: np.ndarray | None = None,
    ) -> np.ndarray:
        """Body torque of eq. (24), N m, shape (3,).

        rotation, rotation_desired: (3, 3) body -> NED. angular_velocity: (3,) rad/s
        body. angular_velocity_desired / angular_acceleration_desired: (3,) in the
        desired body frame, rad/s and rad/s^2; default zero as in the paper.
        """
        return np.array(
            self._torque(
                rotation_to_quaternion(check_rotation(rotation)),
                _vec3(angular_velocity, "angular_velocity"),
                rotation_to_quaternion(check_rotation(rotation_desired, "rotation_desired")),
                _vec3(angular_velocity_desired, "angular_velocity_desired"),
                _vec3(angular_acceleration_desired, "angular_acceleration_desired"),
            )
        )

    def _torque(self, q: Quat, w: Vec3, qd: Quat, wd: Vec3 = _ZERO3, wd_dot: Vec3 = _ZERO3) -> Vec3:
        """Eq. (24) on unit quaternions and 3-tuples (kernels.attitude_torque); the feed-forward
        terms run only when a desired rate or acceleration was given."""
        return kernels.attitude_torque(q, w, qd, wd, wd_dot, not (wd is _ZERO3 and wd_dot is _ZERO3), self._c)


class Mixer:
    """Total thrust + body torque -> rotor speed commands for the X layout.

    Inverts the allocation matrix of sitl_plant.vehicle.quadrotor in squared speeds
    u_i = w_i^2. Saturation policy, applied in this order so that attitude
    authority is lost last and yaw first:

    1. thrust is clipped to [0, params.max_total_thrust];
    2. if the roll/pitch differential alone spans more than [0, u_max], the roll
       and pitch torques are scaled down together (direction kept);
    3. the collective is shifted as little as possible so that collective +/-
       roll/pitch fits in [0, u_max]; roll/pitch beats thrust, so near zero or
       full thrust the delivered thrust differs from the command (like PX4 airmode);
    4. yaw torque is clipped to the headroom that is left; it is the first to go.

    Unsaturated, allocation(mixer(T, tau)) == (T, tau) exactly (up to rounding).
    """

    def __init__(self, params: QuadrotorParams) -> None:
        self.params = params
        self._m = kernels.mixer_constants(params)

    def rotor_speeds(self, thrust: float, torque: np.ndarray) -> np.ndarray:
        """Rotor speed commands, rad/s, shape (4,), PX4 motor order.

        thrust: total thrust, N. torque: body torque (roll, pitch, yaw), N m, shape (3,).
        """
        if not math.isfinite(thrust):
            raise ValueError(f"thrust must be finite, got {thrust!r}")
        return np.array(self._speeds(float(thrust), *_vec3(torque, "torque")))

    def allocation(self, rotor_speeds: np.ndarray) -> tuple[float, np.ndarray]:
        """Forward allocation (the plant's): rotor speeds (4,) rad/s -> (thrust N, torque (3,) N m)."""
        return rotor_wrench(self.params, rotor_speeds)

    def _speeds(self, thrust: float, tx: float, ty: float, tz: float) -> tuple[float, float, float, float]:
        """The policy above on floats (kernels.mixer_speeds); returns w_1..w_4 in rad/s."""
        return kernels.mixer_speeds(thrust, tx, ty, tz, self._m)


def gauss_markov_step(previous: np.ndarray, innovation: np.ndarray, elapsed: float, time_constant: float) -> np.ndarray:
    """One exact step of a first-order Gauss-Markov (Ornstein-Uhlenbeck) error process.

    e(t + dt) = a e(t) + sqrt(1 - a^2) w with a = exp(-dt / tau) and w ~ N(0, sigma^2): the
    exact discretisation of de = -e / tau dt + sigma sqrt(2 / tau) dW, so an error started in
    N(0, sigma^2) keeps std sigma and has autocorrelation exp(-|dt| / tau) at any step size.

    previous: e(t), shape (3,). innovation: w, shape (3,), already scaled to the stationary
    std sigma. elapsed: dt >= 0, s (0 returns previous: a repeated read-out at the same time
    sees the same error). time_constant: tau, s; 0 means white (returns innovation).
    """
    if time_constant <= 0.0:
        return innovation
    a = math.exp(-elapsed / time_constant)
    return a * previous + math.sqrt(max(0.0, 1.0 - a * a)) * innovation


class AttitudeThrustVehicle:
    """The "PX4 side": attitude + thrust setpoints in, rigid-body motion out.

    Controller (eq. (24)), mixer and plant RK4 all run at rate_hz (>= 500 Hz) with
    the true attitude and body rates (the autopilot's attitude estimate is assumed
    perfect). Position/velocity feedback to the companion carries the Gaussian
    noise of section VIII point 4, drawn from the generator given at construction.

    params: airframe. state: initial state, default hover at the origin.
    rng: numpy Generator, int seed or None (fresh entropy), as np.random.default_rng.
    The initial setpoint holds the initial attitude at hover thrust.
    """

    def __init__(
        self,
        params: QuadrotorParams,
        state: RigidBodyState | None = None,
        rate_hz: float = 500.0,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz >= MIN_RATE_HZ):
            raise ValueError(f"rate_hz must be >= {MIN_RATE_HZ:g}, got {rate_hz!r}")
        self.params = params
        self.rate_hz = float(rate_hz)
        self._dt = 1.0 / self.rate_hz
        self._plant = Quadrotor(params, state)
        self._controller = GeometricAttitudeController(params)
        self._mixer = Mixer(params)
        self._rng = np.random.default_rng(rng)
        # Last Gauss-Markov feedback error (position, velocity) and its vehicle time, s.
        self._feedback_error: tuple[np.ndarray, np.ndarray] | None = None
        self._feedback_time = 0.0
        self._normals: list[list[float]] = []  # _next_normals' block and its next row
        self._normals_row = 0
        self._steps = 0
        self._qd: Quat = self._plant._s[6:10]  # type: ignore[assignment]
        self._thrust = float(params.hover_thrust)

    @property
    def quadrotor(self) -> Quadrotor:
        """The underlying plant (for thrust / acceleration read-outs in tests and logs)."""
        return self._plant

    @property
    def state(self) -> RigidBodyState:
        """Copy of the true plant state."""
        return self._plant.state

    def kinematics(self) -> tuple[Vec3, Vec3, tuple[float, ...]]:
        """The true position (m, NED), velocity (m/s, NED) and attitude R (body FRD -> NED, row-major 9-tuple)
        as tuples of floats: the values `state` holds (state.position, state.velocity, state.rotation), read
        without building a RigidBodyState and its five arrays (the in-process simulator reads them every tick)."""
        s = self._plant._s
        return s[0:3], s[3:6], quaternion_to_rotation(*s[6:10])

    @property
    def time(self) -> float:
        """Simulated time since construction, s (an integer number of internal steps)."""
        return self._steps * self._dt

    @property
    def dt(self) -> float:
        """Internal fixed step, s."""
        return self._dt

    @property
    def attitude_target(self) -> tuple[np.ndarray, float]:
        """Current setpoint: (R_d (3, 3) body -> NED, thrust N)."""
        return np.array(quaternion_to_rotation(*self._qd)).reshape(3, 3), self._thrust

    def set_attitude_target(self, rotation_desired: np.ndarray, thrust_newton: float) -> None:
        """Hold attitude R_d ((3, 3) desired body FRD -> NED, proper rotation to 1e-6) and
        total thrust (N; the mixer clips it to [0, 1.5 m g]) until the next call."""
        # checked_rotation_rows + quaternion_from_rows in one kernel call (kernels.setpoint_quaternion)
        r = np.asarray(rotation_desired, dtype=float)
        if r.shape != (3, 3):
            raise ValueError(f"rotation_desired must be a (3, 3) array, got {r!r}")
        proper, qw, qx, qy, qz = kernels.setpoint_quaternion(*r.ravel().tolist())
        if not proper:
            raise ValueError(f"rotation_desired is not a proper rotation matrix: {r!r}")
        thrust = float(thrust_newton)
        if not math.isfinite(thrust):
            raise ValueError(f"thrust_newton must be finite, got {thrust_newton!r}")
        self._qd = (qw, qx, qy, qz)
        self._thrust = thrust

    def set_attitude_target_quaternion(self, quaternion: tuple[float, float, float, float], thrust_newton: float) -> None:
        """As set_attitude_target, with R_d given as a quaternion (w, x, y, z), body FRD -> NED.

        The quaternion must be finite with norm within 1e-3 of one; it is renormalised.
        """
        w, x, y, z = (float(c) for c in quaternion)
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        thrust = float(thrust_newton)
        if not (math.isfinite(norm) and abs(norm - 1.0) < 1e-3 and math.isfinite(thrust)):
            raise ValueError(f"need a unit quaternion and finite thrust, got {quaternion!r}, {thrust_newton!r}")
        self._qd = (w / norm, x / norm, y / norm, z / norm)
        self._thrust = thrust

    def advance(self, duration: float) -> None:
        """Run controller + mixer + plant for `duration` seconds.

        duration must be a non-negative whole number of internal steps (1/rate_hz);
        anything else raises ValueError rather than silently drifting the clock.
        """
        steps_float = float(duration) * self.rate_hz
        n = round(steps_float) if math.isfinite(steps_float) else -1
        if n < 0 or abs(steps_float - n) > 1e-6:
            raise ValueError(f"duration {duration!r} s is not a non-negative multiple of {self._dt!r} s")
        plant, h = self._plant, self._dt
        lag_half, lag_full = plant._lag_factors(h)
        plant._s, plant._w = kernels.advance_steps(
            n, h, lag_half, lag_full, plant._s, plant._w, self._qd, self._thrust,
            plant._k, self._controller._c, self._mixer._m,
        )
        self._steps += n

    _NORMALS_BLOCK = 512
    """Rows of six standard normals drawn from the generator at a time (measured_state takes one row per call)."""

    def _next_normals(self) -> list[float]:
        """The next six N(0, 1) draws of the vehicle's generator, in its order: drawn a block of rows at a time
        (Generator.standard_normal fills an array with the draws a series of smaller calls would take, so the
        numbers are those of six draws per call; the generator itself runs up to a block ahead)."""
        block, row = self._normals, self._normals_row
        if row == len(block):
            block, row = self._rng.standard_normal((self._NORMALS_BLOCK, 6)).tolist(), 0
            self._normals = block
        self._normals_row = row + 1
        return block[row]

    def measured_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Noisy feedback (position m, velocity m/s), each shape (3,) NED.

        Noise is N(0, params.position_noise_std^2) and N(0, params.velocity_noise_std^2)
        per axis. With a zero time constant (the default) it is drawn independently each
        call; with params.position_noise_time_constant / velocity_noise_time_constant
        tau > 0 it is first-order Gauss-Markov in the vehicle's clock (gauss_markov_step),
        with the same stationary std. Either way each call takes the next six normal draws
        of the vehicle's generator (`_next_normals`: a block at a time, so the generator runs
        ahead of the calls; give the vehicle a generator of its own), so no other random
        stream moves.
        """
        s = self._plant._s
        params = self.params
        sp, sv = params.position_noise_std, params.velocity_noise_std
        if not (sp >= 0.0 and sv >= 0.0):
            raise ValueError(f"feedback noise stds must be >= 0, got {sp!r}, {sv!r}")
        z = self._next_normals()
        # Generator.normal(0, sigma, 3) is 0 + sigma z per draw (numpy's random_normal): the same floats
        w0, w1, w2 = 0.0 + sp * z[0], 0.0 + sp * z[1], 0.0 + sp * z[2]
        u0, u1, u2 = 0.0 + sv * z[3], 0.0 + sv * z[4], 0.0 + sv * z[5]
        if params.position_noise_time_constant <= 0.0 and params.velocity_noise_time_constant <= 0.0:
            return np.array((s[0] + w0, s[1] + w1, s[2] + w2)), np.array((s[3] + u0, s[4] + u1, s[5] + u2))
        white_p, white_v = np.array((w0, w1, w2)), np.array((u0, u1, u2))
        now = self.time
        if self._feedback_error is None:
            error_p, error_v = white_p, white_v  # start in the stationary distribution
        else:
            elapsed = now - self._feedback_time
            error_p = gauss_markov_step(self._feedback_error[0], white_p, elapsed, params.position_noise_time_constant)
            error_v = gauss_markov_step(self._feedback_error[1], white_v, elapsed, params.velocity_noise_time_constant)
        self._feedback_error, self._feedback_time = (error_p, error_v), now
        white_p, white_v = error_p, error_v
        p = np.array(s[0:3]) + white_p
        v = np.array(s[3:6]) + white_v
        return p, v
