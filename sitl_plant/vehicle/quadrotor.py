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

The arithmetic of all this (right-hand side, allocation, RK4 step with the motor lag) is
in sitl_plant.vehicle.kernels, compiled by numba when it is installed; this module keeps
the state, checks inputs and reads the state out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl_plant.vehicle import kernels
from sitl_plant.vehicle.kernels import Mat3, Vec3, Wrench  # noqa: F401  (re-exported)
from sitl_plant.vehicle.params import QuadrotorParams

#: (x sign, y sign, spin) per motor in PX4 order; spin +1 = CCW = positive yaw moment.
ROTOR_LAYOUT: tuple[tuple[int, int, int], ...] = (
    (1, 1, 1),
    (-1, -1, 1),
    (1, -1, -1),
    (-1, 1, -1),
)

_ORTHONORMAL_TOL = kernels.ORTHONORMAL_TOL


#: Rotation matrix of a unit quaternion (w, x, y, z), row-major 9-tuple (body FRD -> NED).
#: Kept by hand (not scipy's Rotation) for the per-tick paths: the state read-out that the
#: autopilot and the in-process simulator poll every step, and the attitude controller's
#: feed-forward at 500 Hz, where a Rotation object costs more than the step. The kernel's
#: plain-Python twin: called from Python a compiled kernel's dispatch costs as much as the
#: arithmetic, and it never recompiles for an int argument. Anything slower uses scipy.
quaternion_to_rotation = kernels.quaternion_to_rotation.py_func


def rotation_to_quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix, shape (3, 3).

    Shepperd's method: pivot on the largest of trace and diagonal to stay accurate
    near half turns. Per-tick only (the state write of every ground-contact tick, attitude
    setpoints of the in-process simulator); elsewhere scipy's Rotation is used.
    The arithmetic is quaternion_from_rows's.
    """
    return quaternion_from_rows(np.asarray(rotation, dtype=float).tolist())


def quaternion_from_rows(rows: list) -> tuple[float, float, float, float]:
    """rotation_to_quaternion (Shepperd's method) of a rotation given as its rows of Python floats
    (kernels.quaternion_from_matrix, run as plain Python like quaternion_to_rotation above)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rows
    return _quaternion_from_matrix(m00, m01, m02, m10, m11, m12, m20, m21, m22)


_quaternion_from_matrix = kernels.quaternion_from_matrix.py_func
_is_rotation = kernels.is_rotation.py_func


def check_rotation(rotation: np.ndarray, name: str = "rotation") -> np.ndarray:
    """Return rotation as a float (3, 3) array; ValueError unless it is in SO(3) to 1e-6.

    Checked column by column in plain Python (checked_rotation_rows): this runs on every attitude setpoint.
    """
    r = np.array(rotation, dtype=float)
    checked_rotation_rows(r, name)
    return r


def checked_rotation_rows(rotation: np.ndarray, name: str = "rotation") -> list:
    """The rows of `rotation` as lists of Python floats; ValueError unless it is a (3, 3) array in SO(3) to 1e-6
    (check_rotation's test, without its copy of the array)."""
    r = np.asarray(rotation, dtype=float)
    if r.shape != (3, 3):
        raise ValueError(f"{name} must be a (3, 3) array, got {r!r}")
    rows = r.tolist()
    # Columns orthonormal and right-handed (a x b = c) to 1e-6 (kernels.is_rotation, as plain Python)
    if not _is_rotation(*rows[0], *rows[1], *rows[2]):
        raise ValueError(f"{name} is not a proper rotation matrix: {r!r}")
    return rows


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

    This is the allocation matrix of the module docstring (sitl_plant.vehicle.kernels.rotor_wrench);
    the Mixer inverts it.
    """
    w = _vector(rotor_speeds, 4, "rotor_speeds")
    thrust, tx, ty, tz = kernels.rotor_wrench(*(float(x) for x in w), kernels.plant_constants(params))
    return thrust, np.array([tx, ty, tz])


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
        kernels.warm_up()
        self.params = params
        self._k = kernels.plant_constants(params)
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
        # Tuples of Python floats: what the kernels take (sitl_plant.vehicle.kernels).
        self._s: kernels.State = (
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
        return kernels.rotor_wrench(*self._w, self._k)[0]

    @property
    def body_torque(self) -> np.ndarray:
        """Rotor torque about the centre of mass at the current rotor speeds, N m, (3,) FRD."""
        return np.array(kernels.rotor_wrench(*self._w, self._k)[1:])

    @property
    def acceleration(self) -> np.ndarray:
        """Inertial acceleration dv/dt at the current state (gravity, thrust, drag), m/s^2, (3,) NED."""
        k = self._k
        return np.array(kernels.rigid_body_rhs(self._s[3:6], self._s[6:10], self._s[10:13], kernels.rotor_wrench(*self._w, k), k)[0:3])

    def step(self, dt: float, rotor_speed_command: np.ndarray) -> None:
        """Advance one RK4 step of dt seconds holding rotor_speed_command (rad/s, shape (4,)).

        The command is saturated to [0, params.max_rotor_speed] before the motor lag.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be positive and finite, got {dt!r}")
        c = _vector(rotor_speed_command, 4, "rotor_speed_command")
        top = self._max_speed
        self._step(float(dt), *(min(max(float(x), 0.0), top) for x in c))

    def _lag_factors(self, h: float) -> tuple[float, float]:
        """Exact motor-lag factors (exp(-h / (2 T_m)), exp(-h / T_m)) for a step of h seconds, cached."""
        if h != self._lag_step:
            tau = self.params.motor_time_constant
            self._lag_half = math.exp(-0.5 * h / tau)
            self._lag_full = math.exp(-h / tau)
            self._lag_step = h
        return self._lag_half, self._lag_full

    def _step(self, h: float, c1: float, c2: float, c3: float, c4: float) -> None:
        """One step with an already saturated command (floats, rad/s): kernels.rk4_step."""
        eh, ef = self._lag_factors(h)
        self._s, self._w = kernels.rk4_step(h, eh, ef, self._s, self._w, c1, c2, c3, c4, self._k)
