"""The plant's own multicopter position controller, built the way PX4's is.

PX4's multicopter position control (mc_pos_control, documented in the PX4 user guide's
"Controller Diagrams") is a cascade, and so is this one:

1. position P loop -> velocity setpoint (plus velocity feed-forward), horizontal speed
   limited with the feed-forward kept first, vertical speed limited to climb/descent rates;
2. velocity PID loop -> acceleration setpoint (plus acceleration feed-forward), the D term
   on the measured acceleration, integrators with anti-windup;
3. acceleration -> normalised thrust vector through the hover thrust (a linear thrust
   curve: MPC_THR_HOVER gives 1 g), vertical thrust first within [MPC_THR_MIN, MPC_THR_MAX],
   tilt within MPC_TILTMAX_AIR, the horizontal part within what MPC_THR_MAX leaves
   (at least MPC_THR_XY_MARG of it);
4. thrust vector + yaw setpoint -> attitude: body z against the thrust, body x in the
   vertical plane of the heading, collective thrust = length of the thrust vector.

Written from that documented design, not from PX4's source. One deliberate difference:
PX4 tilts for the horizontal acceleration against a fixed g; here the thrust vector is the
exact specific force m (a - g e_Z) of the commanded acceleration, so the flown
acceleration equals the command whenever no limit is hit.

Runs at the autopilot's position-control rate (~50 Hz), not in the 500 Hz physics loop,
so it uses numpy and scipy's Rotation freely. Frames: local NED, body FRD. Per-axis NaN in
a setpoint means "not given", as in PX4's trajectory_setpoint. Units SI, angles rad.
It knows nothing of the companion: sitl_plant never imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


def _not_given() -> np.ndarray:
    return np.full(3, np.nan)


@dataclass(frozen=True)
class PositionControlGains:
    """Gains and fixed limits, PX4 v1.14 defaults (parameter names in the comments).

    position_*: 1/s. velocity_*_p: 1/s, velocity_*_i: 1/s^2, velocity_*_d: dimensionless
    (acceleration per acceleration). Rates m/s. thrust_*: normalised collective thrust.
    """

    position_xy: float = 0.95  # MPC_XY_P
    position_z: float = 1.0  # MPC_Z_P
    velocity_xy_p: float = 1.8  # MPC_XY_VEL_P_ACC
    velocity_xy_i: float = 0.4  # MPC_XY_VEL_I_ACC
    velocity_xy_d: float = 0.2  # MPC_XY_VEL_D_ACC
    velocity_z_p: float = 4.0  # MPC_Z_VEL_P_ACC
    velocity_z_i: float = 2.0  # MPC_Z_VEL_I_ACC
    velocity_z_d: float = 0.0  # MPC_Z_VEL_D_ACC
    max_climb_rate: float = 3.0  # MPC_Z_VEL_MAX_UP
    max_descent_rate: float = 1.5  # MPC_Z_VEL_MAX_DN
    thrust_min: float = 0.12  # MPC_THR_MIN
    thrust_max: float = 1.0  # MPC_THR_MAX


@dataclass(frozen=True)
class ControlLimits:
    """What the parameter table may change in flight.

    hover_thrust: normalised thrust that gives 1 g (MPC_THR_HOVER), in (0, 1).
    max_tilt: rad, largest tilt of the thrust axis from vertical (MPC_TILTMAX_AIR), < pi/2.
    max_speed_xy: m/s, horizontal speed limit of the position loop (MPC_XY_VEL_MAX).
    gravity: m/s^2. thrust_xy_margin: normalised horizontal thrust that vertical saturation
    leaves (MPC_THR_XY_MARG).
    """

    hover_thrust: float
    max_tilt: float
    max_speed_xy: float
    gravity: float
    thrust_xy_margin: float = 0.3


@dataclass(frozen=True)
class TrajectorySetpoint:
    """A position/velocity/acceleration setpoint, local NED; NaN on an axis = not given.

    position: m, velocity: m/s (a feed-forward when the position is given too),
    acceleration: m/s^2 feed-forward, each shape (3,). yaw: rad from north towards east.
    An axis with neither position nor velocity is flown open loop on its acceleration.
    """

    position: np.ndarray = field(default_factory=_not_given)
    velocity: np.ndarray = field(default_factory=_not_given)
    acceleration: np.ndarray = field(default_factory=_not_given)
    yaw: float = 0.0


@dataclass(frozen=True)
class AttitudeThrustSetpoint:
    """The controller's output for the attitude loop.

    quaternion: (w, x, y, z) body FRD -> NED. thrust: normalised collective thrust in
    [0, thrust_max]. thrust_vector: normalised thrust in NED, shape (3,) (points up when
    hovering: its z is negative). acceleration: m/s^2 NED, shape (3,), what the thrust
    vector gives together with gravity (the flown acceleration, after the limits).
    """

    quaternion: tuple[float, float, float, float]
    thrust: float
    thrust_vector: np.ndarray
    acceleration: np.ndarray


def trapezoidal_profile(distance: float, max_speed: float, acceleration: float, t: float) -> tuple[float, float, float]:
    """A rest-to-rest move over `distance` (m, >= 0) with speed <= max_speed (m/s) and
    |acceleration| <= acceleration (m/s^2): (travelled m, speed m/s, acceleration m/s^2) at
    time t (s) since its start. Constant acceleration, cruise, constant deceleration; the
    cruise is skipped (a triangle) when the distance is too short to reach max_speed.
    Gives the takeoff climb its position, velocity and acceleration feed-forward, so the
    velocity loop (and its integrator) only sees the vehicle's own tracking error.
    """
    if distance <= 0.0:
        return 0.0, 0.0, 0.0
    peak = min(max_speed, math.sqrt(distance * acceleration))
    ramp = peak / acceleration
    ramp_distance = 0.5 * peak * ramp
    cruise = (distance - 2.0 * ramp_distance) / peak
    if t <= 0.0:
        return 0.0, 0.0, acceleration
    if t < ramp:
        return 0.5 * acceleration * t * t, acceleration * t, acceleration
    if t < ramp + cruise:
        return ramp_distance + peak * (t - ramp), peak, 0.0
    left = 2.0 * ramp + cruise - t
    if left > 0.0:
        return distance - 0.5 * acceleration * left * left, acceleration * left, -acceleration
    return distance, 0.0, 0.0


def limit_horizontal_speed(position_part: np.ndarray, feedforward: np.ndarray, max_speed: float) -> np.ndarray:
    """Horizontal velocity setpoint feedforward + s * position_part with the largest s in [0, 1]
    whose norm stays within max_speed; the feed-forward alone is scaled down if it is too fast.

    The feed-forward is what the trajectory asks for, so it is kept first (PX4 does the same).
    Arguments m/s, shape (2,); returns shape (2,).
    """
    total = feedforward + position_part
    if float(np.hypot(*total)) <= max_speed:
        return total
    ff_norm = float(np.hypot(*feedforward))
    if ff_norm >= max_speed:
        return feedforward * (max_speed / ff_norm)
    # |ff + s p| = max_speed, the positive root of a quadratic in s.
    pp = float(position_part @ position_part)
    fp = float(feedforward @ position_part)
    s = (-fp + math.sqrt(fp * fp - pp * (ff_norm * ff_norm - max_speed * max_speed))) / pp
    return feedforward + s * position_part


def thrust_vector(acceleration: np.ndarray, limits: ControlLimits, gains: PositionControlGains) -> np.ndarray:
    """Normalised thrust vector (NED, shape (3,)) for an acceleration setpoint (m/s^2, NED, (3,)).

    The rotors must supply the specific force a - g e_Z; with a linear thrust curve the
    normalised thrust is that force times hover_thrust / g. Saturation, vertical first:
    the upward component is clipped to [thrust_min, thrust_max] but leaves room for
    min(|horizontal|, thrust_xy_margin) of horizontal thrust; the horizontal component is
    then scaled down (direction kept) to the tilt limit and to what thrust_max leaves.
    """
    scale = limits.hover_thrust / limits.gravity
    wanted = (np.asarray(acceleration, dtype=float) - np.array([0.0, 0.0, limits.gravity])) * scale
    horizontal = wanted[:2]
    horizontal_norm = float(np.hypot(*horizontal))
    up = -float(wanted[2])
    reserved = min(horizontal_norm, limits.thrust_xy_margin)
    up_max = math.sqrt(max(gains.thrust_max**2 - reserved**2, 0.0))
    up = min(max(up, gains.thrust_min), up_max)
    horizontal_max = min(up * math.tan(limits.max_tilt), math.sqrt(max(gains.thrust_max**2 - up * up, 0.0)))
    if horizontal_norm > horizontal_max:
        horizontal = horizontal * (horizontal_max / horizontal_norm)
    return np.array([horizontal[0], horizontal[1], -up])


def thrust_to_attitude(thrust: np.ndarray, yaw: float) -> tuple[tuple[float, float, float, float], float]:
    """Attitude and collective thrust that give the thrust vector `thrust` (normalised, NED, (3,))
    with the nose towards `yaw` (rad) as far as the tilt allows (PX4's "thrust to attitude").

    Body z (FRD, down) points against the thrust; body x is the heading direction with its
    component along body z removed, i.e. it lies in the vertical plane of the heading, and
    body y completes the right-handed frame. Returns ((w, x, y, z) body FRD -> NED, |thrust|).
    A zero thrust vector gives a level attitude.
    """
    tx, ty, tz = (float(c) for c in thrust)
    magnitude = math.sqrt(tx * tx + ty * ty + tz * tz)
    zx, zy, zz = (-tx / magnitude, -ty / magnitude, -tz / magnitude) if magnitude > 1e-9 else (0.0, 0.0, 1.0)
    # y_C = (-sin yaw, cos yaw, 0) is horizontal and perpendicular to the heading; y_C x body_z
    # lies in the heading's vertical plane and is never zero while body_z is not horizontal
    # (tilt < 90 deg). Written on floats: numpy's cross costs more than the rest of the step.
    yx, yy = -math.sin(yaw), math.cos(yaw)
    xx, xy, xz = yy * zz, -yx * zz, yx * zy - yy * zx
    norm = math.sqrt(xx * xx + xy * xy + xz * xz)
    if norm < 1e-9:  # thrust horizontal along y_C: any nose direction across it will do
        xx, xy, xz, norm = 0.0, 0.0, (-1.0 if zz >= 0.0 else 1.0), 1.0
    xx, xy, xz = xx / norm, xy / norm, xz / norm
    body = np.array([[xx, zy * xz - zz * xy, zx],
                     [xy, zz * xx - zx * xz, zy],
                     [xz, zx * xy - zy * xx, zz]])  # columns body x, body z x body x, body z
    q = Rotation.from_matrix(body).as_quat(scalar_first=True)
    if q[0] < 0.0:
        q = -q
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3])), magnitude


class PositionController:
    """Position P -> velocity PID -> acceleration -> thrust vector -> attitude (module docstring).

    Call update() at a fixed period; reset() whenever the loop stops being flown (on the
    ground, disarmed, attitude offboard), so a stale integrator never reaches the motors.
    """

    def __init__(self, gains: PositionControlGains = PositionControlGains()) -> None:
        self.gains = gains
        g = gains
        self._kp_pos = np.array([g.position_xy, g.position_xy, g.position_z])
        self._kp_vel = np.array([g.velocity_xy_p, g.velocity_xy_p, g.velocity_z_p])
        self._ki_vel = np.array([g.velocity_xy_i, g.velocity_xy_i, g.velocity_z_i])
        self._kd_vel = np.array([g.velocity_xy_d, g.velocity_xy_d, g.velocity_z_d])
        self.velocity_integral = np.zeros(3)  # m/s^2, the integrators' share of the acceleration

    def reset(self) -> None:
        """Empty the velocity integrators."""
        self.velocity_integral = np.zeros(3)

    def velocity_setpoint(self, position: np.ndarray, setpoint: TrajectorySetpoint, limits: ControlLimits) -> np.ndarray:
        """Step 1: velocity setpoint, m/s NED (3,); NaN on axes with neither position nor velocity."""
        g = self.gains
        position_part = self._kp_pos * (np.asarray(setpoint.position, float) - position)
        feedforward = np.asarray(setpoint.velocity, float)
        active = ~(np.isnan(position_part) & np.isnan(feedforward))
        position_part = np.nan_to_num(position_part)
        feedforward = np.nan_to_num(feedforward)
        velocity = np.empty(3)
        velocity[:2] = limit_horizontal_speed(position_part[:2], feedforward[:2], limits.max_speed_xy)
        velocity[2] = min(max(position_part[2] + feedforward[2], -g.max_climb_rate), g.max_descent_rate)
        return np.where(active, velocity, np.nan)

    def update(
        self,
        dt: float,
        position: np.ndarray,
        velocity: np.ndarray,
        acceleration: np.ndarray,
        setpoint: TrajectorySetpoint,
        limits: ControlLimits,
    ) -> AttitudeThrustSetpoint:
        """One control step of dt seconds.

        position (m), velocity (m/s), acceleration (m/s^2, for the D term): the vehicle's
        estimate, local NED, shape (3,). Returns the attitude/thrust setpoint.
        """
        g = self.gains
        velocity_sp = self.velocity_setpoint(np.asarray(position, float), setpoint, limits)
        active = ~np.isnan(velocity_sp)
        error = np.where(active, velocity_sp - velocity, 0.0)
        # Step 2: velocity PID, D on the measured acceleration (no kick on setpoint steps).
        from_velocity = np.where(active, self._kp_vel * error + self.velocity_integral - self._kd_vel * acceleration, 0.0)
        wanted = from_velocity + np.nan_to_num(np.asarray(setpoint.acceleration, float))
        # Step 3: thrust vector within the limits.
        thrust = thrust_vector(wanted, limits, g)
        flown = thrust * (limits.gravity / limits.hover_thrust) + np.array([0.0, 0.0, limits.gravity])
        # Anti-windup. Vertical: stop integrating into a saturated thrust. Horizontal: feed
        # the part of the command the limits cut back into the error (tracking anti-windup).
        up = -float(thrust[2])
        if (up <= g.thrust_min + 1e-9 and error[2] > 0.0) or (up >= g.thrust_max - 1e-9 and error[2] < 0.0):
            error[2] = 0.0
        if float(wanted[:2] @ wanted[:2]) > float(flown[:2] @ flown[:2]) + 1e-12 and g.velocity_xy_p > 0.0:
            error[:2] -= (2.0 / g.velocity_xy_p) * (wanted[:2] - flown[:2])
        self.velocity_integral = self.velocity_integral + np.where(active, self._ki_vel * error * dt, 0.0)
        self.velocity_integral[2] = min(max(self.velocity_integral[2], -limits.gravity), limits.gravity)
        # Step 4: attitude.
        quaternion, collective = thrust_to_attitude(thrust, setpoint.yaw)
        return AttitudeThrustSetpoint(quaternion, collective, thrust, flown)
