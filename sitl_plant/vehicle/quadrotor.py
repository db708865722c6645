"""Rigid-body quadrotor plant, paper eq. (20a)-(20d) plus the section VIII realism points.

Frames and conventions
----------------------
* Inertial frame: local NED; gravity is +g e_Z.
* Body frame: FRD (x forward, y right, z down). R maps body vectors to NED, so the
  thrust, which pushes along body -z, enters eq. (20b) as -(T/m) R e_Z.
* Attitude is integrated as a unit quaternion q = (w, x, y, z) (Hamilton, scalar
  first, body -> NED), renormalised after every step so R stays on SO(3).

Rotor layout (PX4 quad X, arms at 45 deg, hub-to-centre distance d = arm_length)
-------------------------------------------------------------------------------
With a = d / sqrt(2) the hub positions in body FRD are::

    motor 1  front-right  ( a,  a)  spins CCW (seen from above)
    motor 2  rear-left    (-a, -a)  spins CCW
    motor 3  front-left   ( a, -a)  spins CW
    motor 4  rear-right   (-a,  a)  spins CW

Rotor i gives thrust f_i = C_T w_i^2 along body -z and a reaction (drag) moment of
magnitude C_m w_i^2 about body z, opposite to its spin. A CCW rotor therefore
pushes the airframe clockwise seen from above, which in FRD is a *positive* yaw
moment (nose turns from north to east). With u_i = w_i^2 the allocation is::

    T     = C_T   ( u1 + u2 + u3 + u4)
    tau_x = C_T a (-u1 + u2 + u3 - u4)      roll right: left rotors (2, 3) faster
    tau_y = C_T a ( u1 - u2 + u3 - u4)      pitch up:   front rotors (1, 3) faster
    tau_z = C_m   ( u1 + u2 - u3 - u4)      yaw right:  CCW rotors (1, 2) faster

Extra physics (section VIII, points 1-3)
----------------------------------------
1. First-order motor lag w_i' = (c_i - w_i) / T_m. The command c_i is held over a
   step, so this linear ODE is solved exactly and the RK4 stages of the rigid body
   see the exact rotor speeds at t, t + h/2 and t + h.
2. The command is saturated to [0, max_rotor_speed], so total thrust <= 1.5 m g.
3. Linear body drag -K_r R^T v with K_r = diag(C_d, C_d, 0), rotated into NED:
   R(-K_r R^T v) = -C_d (v - r3 (r3 . v)), r3 = R e_Z (no drag along body z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sitl_plant.vehicle.params import QuadrotorParams

#: (x sign, y sign, spin) per motor in PX4 order; spin +1 = CCW = positive yaw moment.
ROTOR_LAYOUT: tuple[tuple[int, int, int], ...] = (
    (1, 1, 1),
    (-1, -1, 1),
    (1, -1, -1),
    (-1, 1, -1),
)

_ORTHONORMAL_TOL = 1e-6

Vec3 = tuple[float, float, float]
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
Wrench = tuple[float, float, float, float]


def quaternion_to_rotation(qw: float, qx: float, qy: float, qz: float) -> Mat3:
    """Rotation matrix of a unit quaternion, row-major 9-tuple (body FRD -> NED).

    Kept by hand (not scipy's Rotation) for the per-tick paths only: the state read-out
    that the autopilot and the in-process simulator poll every step, and the attitude
    controller's feed-forward at 500 Hz, where a Rotation object costs more than the step.
    Anything slower uses scipy.spatial.transform.Rotation.
    """
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz = qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    return (
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    )


def rotation_to_quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix, shape (3, 3).

    Shepperd's method: pivot on the largest of trace and diagonal to stay accurate
    near half turns. Per-tick only (the state write of every ground-contact tick, attitude
    setpoints of the in-process simulator); elsewhere scipy's Rotation is used.
    """
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(rotation, dtype=float).tolist()
    trace = m00 + m11 + m22
    if trace >= m00 and trace >= m11 and trace >= m22:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif m11 >= m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    scale = (1.0 if q[0] >= 0.0 else -1.0) / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] * scale, q[1] * scale, q[2] * scale, q[3] * scale)


def check_rotation(rotation: np.ndarray, name: str = "rotation") -> np.ndarray:
    """Return rotation as a float (3, 3) array; ValueError unless it is in SO(3) to 1e-6.

    Checked column by column in plain Python: this runs on every attitude setpoint.
    """
    r = np.array(rotation, dtype=float)
    if r.shape != (3, 3):
        raise ValueError(f"{name} must be a (3, 3) array, got {r!r}")
    (a0, b0, c0), (a1, b1, c1), (a2, b2, c2) = r.tolist()
    # Columns a, b, c must be orthonormal and right-handed (a x b = c).
    residuals = (
        a0 * a0 + a1 * a1 + a2 * a2 - 1.0,
        b0 * b0 + b1 * b1 + b2 * b2 - 1.0,
        c0 * c0 + c1 * c1 + c2 * c2 - 1.0,
        a0 * b0 + a1 * b1 + a2 * b2,
        a0 * c0 + a1 * c1 + a2 * c2,
        b0 * c0 + b1 * c1 + b2 * c2,
        a1 * b2 - a2 * b1 - c0,
        a2 * b0 - a0 * b2 - c1,
        a0 * b1 - a1 * b0 - c2,
    )
    # `not <=` also rejects NaN and infinities.
    if not all(abs(x) <= _ORTHONORMAL_TOL for x in residuals):
        raise ValueError(f"{name} is not a proper rotation matrix: {r!r}")
    return r


def _vector(value: object, size: int, name: str) -> np.ndarray:
    v = np.array(value, dtype=float).reshape(-1)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be {size} finite numbers, got {value!r}")
    return v


def hover_rotor_speed(params: QuadrotorParams) -> float:
    """Rotor speed at which four rotors carry m g, rad/s."""
    return math.sqrt(params.hover_thrust / (4.0 * params.thrust_coefficient))


def rotor_wrench(params: QuadrotorParams, rotor_speeds: np.ndarray) -> tuple[float, np.ndarray]:
    """Total thrust (N) and body torque (N m, shape (3,)) of rotor speeds (rad/s, shape (4,)).

    This is the allocation matrix of the module docstring; the Mixer inverts it.
    """
    w = _vector(rotor_speeds, 4, "rotor_speeds")
    thrust, tx, ty, tz = _make_wrench_function(params)(*(float(x) for x in w))
    return thrust, np.array([tx, ty, tz])


def _make_wrench_function(params: QuadrotorParams) -> Callable[[float, float, float, float], Wrench]:
    c_t = params.thrust_coefficient
    c_ta = params.thrust_coefficient * params.arm_length / math.sqrt(2.0)
    c_m = params.moment_coefficient

    def wrench(w1: float, w2: float, w3: float, w4: float) -> Wrench:
        u1, u2, u3, u4 = w1 * w1, w2 * w2, w3 * w3, w4 * w4
        return (
            c_t * (u1 + u2 + u3 + u4),
            c_ta * (-u1 + u2 + u3 - u4),
            c_ta * (u1 - u2 + u3 - u4),
            c_m * (u1 + u2 - u3 - u4),
        )

    return wrench


def _make_dynamics(params: QuadrotorParams) -> Callable[..., tuple[float, ...]]:
    """Build the rigid-body right-hand side, eq. (20b)-(20d) plus drag.

    f(vx, vy, vz, qw, qx, qy, qz, wx, wy, wz, T, tau_x, tau_y, tau_z) returns
    (v', q', omega') as a 10-tuple; p' = v (eq. (20a)) is left to the integrator.
    Scalar arguments instead of a state vector because this runs four times per
    plant step and packing/unpacking sequences would dominate its cost.
    """
    g = params.gravity
    inv_m = 1.0 / params.mass
    drag_per_mass = params.drag_coefficient / params.mass
    jx, jy, jz = params.inertia
    inv_jx, inv_jy, inv_jz = 1.0 / jx, 1.0 / jy, 1.0 / jz
    jz_jy, jx_jz, jy_jx = jz - jy, jx - jz, jy - jx

    def dynamics(
        vx: float, vy: float, vz: float,
        qw: float, qx: float, qy: float, qz: float,
        wx: float, wy: float, wz: float,
        thrust: float, tx: float, ty: float, tz: float,
    ) -> tuple[float, ...]:
        # Only r3 = R e_Z is needed: thrust acts along it and, since
        # R diag(1, 1, 0) R^T = I - r3 r3^T, the drag R(-K_r R^T v) = -C_d (v - r3 (r3 . v)).
        r02 = 2.0 * (qx * qz + qw * qy)
        r12 = 2.0 * (qy * qz - qw * qx)
        r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
        vertical = r02 * vx + r12 * vy + r22 * vz
        a3 = thrust * inv_m - drag_per_mass * vertical
        return (
            -a3 * r02 - drag_per_mass * vx,  # eq. (20b) + drag
            -a3 * r12 - drag_per_mass * vy,
            g - a3 * r22 - drag_per_mass * vz,
            # eq. (20c) as q' = q (x) (0, omega) / 2
            -0.5 * (qx * wx + qy * wy + qz * wz),
            0.5 * (qw * wx + qy * wz - qz * wy),
            0.5 * (qw * wy - qx * wz + qz * wx),
            0.5 * (qw * wz + qx * wy - qy * wx),
            # eq. (20d) with diagonal J
            (tx - jz_jy * wy * wz) * inv_jx,
            (ty - jx_jz * wz * wx) * inv_jy,
            (tz - jy_jx * wx * wy) * inv_jz,
        )

    return dynamics


@dataclass(frozen=True)
class RigidBodyState:
    """Full plant state. Arrays are validated, converted to float and never aliased.

    position: (3,) m, NED.        velocity: (3,) m/s, NED.
    rotation: (3, 3) body FRD -> NED.  angular_velocity: (3,) rad/s, body FRD.
    rotor_speeds: (4,) rad/s, PX4 motor order (see module docstring).
    """

    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray
    angular_velocity: np.ndarray
    rotor_speeds: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _vector(self.position, 3, "position"))
        object.__setattr__(self, "velocity", _vector(self.velocity, 3, "velocity"))
        object.__setattr__(self, "rotation", check_rotation(self.rotation))
        object.__setattr__(self, "angular_velocity", _vector(self.angular_velocity, 3, "angular_velocity"))
        speeds = _vector(self.rotor_speeds, 4, "rotor_speeds")
        if np.any(speeds < 0.0):
            raise ValueError(f"rotor speeds must be >= 0, got {speeds!r}")
        object.__setattr__(self, "rotor_speeds", speeds)

    @classmethod
    def _trusted(
        cls,
        position: np.ndarray,
        velocity: np.ndarray,
        rotation: np.ndarray,
        angular_velocity: np.ndarray,
        rotor_speeds: np.ndarray,
    ) -> "RigidBodyState":
        """Build from fresh float arrays the plant already keeps valid, skipping the
        checks (the state read-out is polled by the simulation loop)."""
        state = object.__new__(cls)
        for key, value in (
            ("position", position),
            ("velocity", velocity),
            ("rotation", rotation),
            ("angular_velocity", angular_velocity),
            ("rotor_speeds", rotor_speeds),
        ):
            object.__setattr__(state, key, value)
        return state

    @classmethod
    def hover(
        cls, params: QuadrotorParams, position: np.ndarray | None = None, yaw: float = 0.0
    ) -> "RigidBodyState":
        """Exact hover equilibrium: level at heading `yaw` (rad, from north towards east),
        at rest, every rotor at the speed giving m g / 4."""
        c, s = math.cos(yaw), math.sin(yaw)
        return cls(
            position=np.zeros(3) if position is None else position,
            velocity=np.zeros(3),
            rotation=np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
            angular_velocity=np.zeros(3),
            rotor_speeds=np.full(4, hover_rotor_speed(params)),
        )


class Quadrotor:
    """Quadrotor rigid body with motor lag, rotor saturation and linear drag.

    Integration: classic RK4 on (p, v, q, omega) with the rotor speeds taken from the
    exact solution of the motor lag at the stage times; the quaternion is
    renormalised after every step.

    params: airframe. state: initial state (default: hover at the origin); rotor
    speeds above params.max_rotor_speed are clipped to it on load.
    """

    def __init__(self, params: QuadrotorParams, state: RigidBodyState | None = None) -> None:
        self.params = params
        self._dynamics = _make_dynamics(params)
        self._wrench = _make_wrench_function(params)
        self._max_speed = params.max_rotor_speed
        self._lag_step = -1.0
        self._lag_half = 0.0
        self._lag_full = 0.0
        self.state = state if state is not None else RigidBodyState.hover(params)

    @property
    def state(self) -> RigidBodyState:
        """Copy of the current state."""
        s = self._s
        return RigidBodyState._trusted(
            np.array(s[0:3]),
            np.array(s[3:6]),
            np.array(quaternion_to_rotation(*s[6:10])).reshape(3, 3),
            np.array(s[10:13]),
            np.array(self._w),
        )

    @state.setter
    def state(self, state: RigidBodyState) -> None:
        if not isinstance(state, RigidBodyState):
            raise TypeError(f"expected RigidBodyState, got {type(state).__name__}")
        self._s: tuple[float, ...] = (
            *(float(x) for x in state.position),
            *(float(x) for x in state.velocity),
            *rotation_to_quaternion(state.rotation),
            *(float(x) for x in state.angular_velocity),
        )
        self._w: tuple[float, float, float, float] = tuple(  # type: ignore[assignment]
            min(float(x), self._max_speed) for x in state.rotor_speeds
        )

    @property
    def total_thrust(self) -> float:
        """Total rotor thrust at the current rotor speeds, N (>= 0, <= 1.5 m g)."""
        return self._wrench(*self._w)[0]

    @property
    def body_torque(self) -> np.ndarray:
        """Rotor torque about the centre of mass at the current rotor speeds, N m, (3,) FRD."""
        return np.array(self._wrench(*self._w)[1:])

    @property
    def acceleration(self) -> np.ndarray:
        """Inertial acceleration dv/dt at the current state (gravity, thrust, drag), m/s^2, (3,) NED."""
        return np.array(self._dynamics(*self._s[3:13], *self._wrench(*self._w))[0:3])

    def step(self, dt: float, rotor_speed_command: np.ndarray) -> None:
        """Advance one RK4 step of dt seconds holding rotor_speed_command (rad/s, shape (4,)).

        The command is saturated to [0, params.max_rotor_speed] before the motor lag.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be positive and finite, got {dt!r}")
        c = _vector(rotor_speed_command, 4, "rotor_speed_command")
        top = self._max_speed
        self._step(dt, *(min(max(float(x), 0.0), top) for x in c))

    def _step(self, h: float, c1: float, c2: float, c3: float, c4: float) -> None:
        """Hot path: one step with an already saturated command (floats, rad/s).

        Written out stage by stage on scalars; a loop over state vectors costs
        more than the arithmetic at this size.
        """
        if h != self._lag_step:
            tau = self.params.motor_time_constant
            self._lag_half = math.exp(-0.5 * h / tau)
            self._lag_full = math.exp(-h / tau)
            self._lag_step = h
        eh, ef = self._lag_half, self._lag_full
        w1, w2, w3, w4 = self._w
        d1, d2, d3, d4 = w1 - c1, w2 - c2, w3 - c3, w4 - c4
        wrench, f = self._wrench, self._dynamics
        t0, x0, y0, z0 = wrench(w1, w2, w3, w4)
        tm, xm, ym, zm = wrench(c1 + d1 * eh, c2 + d2 * eh, c3 + d3 * eh, c4 + d4 * eh)
        e1, e2, e3, e4 = c1 + d1 * ef, c2 + d2 * ef, c3 + d3 * ef, c4 + d4 * ef
        te, xe, ye, ze = wrench(e1, e2, e3, e4)

        px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz = self._s
        hh = 0.5 * h
        a1x, a1y, a1z, q1w, q1x, q1y, q1z, o1x, o1y, o1z = f(
            vx, vy, vz, qw, qx, qy, qz, wx, wy, wz, t0, x0, y0, z0
        )
        v2x, v2y, v2z = vx + hh * a1x, vy + hh * a1y, vz + hh * a1z
        a2x, a2y, a2z, q2w, q2x, q2y, q2z, o2x, o2y, o2z = f(
            v2x, v2y, v2z,
            qw + hh * q1w, qx + hh * q1x, qy + hh * q1y, qz + hh * q1z,
            wx + hh * o1x, wy + hh * o1y, wz + hh * o1z,
            tm, xm, ym, zm,
        )
        v3x, v3y, v3z = vx + hh * a2x, vy + hh * a2y, vz + hh * a2z
        a3x, a3y, a3z, q3w, q3x, q3y, q3z, o3x, o3y, o3z = f(
            v3x, v3y, v3z,
            qw + hh * q2w, qx + hh * q2x, qy + hh * q2y, qz + hh * q2z,
            wx + hh * o2x, wy + hh * o2y, wz + hh * o2z,
            tm, xm, ym, zm,
        )
        v4x, v4y, v4z = vx + h * a3x, vy + h * a3y, vz + h * a3z
        a4x, a4y, a4z, q4w, q4x, q4y, q4z, o4x, o4y, o4z = f(
            v4x, v4y, v4z,
            qw + h * q3w, qx + h * q3x, qy + h * q3y, qz + h * q3z,
            wx + h * o3x, wy + h * o3y, wz + h * o3z,
            te, xe, ye, ze,
        )
        h6 = h / 6.0
        qw += h6 * (q1w + 2.0 * (q2w + q3w) + q4w)
        qx += h6 * (q1x + 2.0 * (q2x + q3x) + q4x)
        qy += h6 * (q1y + 2.0 * (q2y + q3y) + q4y)
        qz += h6 * (q1z + 2.0 * (q2z + q3z) + q4z)
        inv = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        self._s = (
            px + h6 * (vx + 2.0 * (v2x + v3x) + v4x),
            py + h6 * (vy + 2.0 * (v2y + v3y) + v4y),
            pz + h6 * (vz + 2.0 * (v2z + v3z) + v4z),
            vx + h6 * (a1x + 2.0 * (a2x + a3x) + a4x),
            vy + h6 * (a1y + 2.0 * (a2y + a3y) + a4y),
            vz + h6 * (a1z + 2.0 * (a2z + a3z) + a4z),
            qw * inv, qx * inv, qy * inv, qz * inv,
            wx + h6 * (o1x + 2.0 * (o2x + o3x) + o4x),
            wy + h6 * (o1y + 2.0 * (o2y + o3y) + o4y),
            wz + h6 * (o1z + 2.0 * (o2z + o3z) + o4z),
        )
        self._w = (e1, e2, e3, e4)
