"""Acceleration command -> attitude and thrust setpoint, eq. (21)-(22) of section VII.

This is the part of the geometric controller that runs on the companion: it
turns the guidance acceleration a_d into a desired attitude R_d (camera heading
on the target) and a collective thrust, normalised the way PX4 takes it in
SET_ATTITUDE_TARGET. The torque loop of eq. (23)-(24) belongs to the autopilot
(sitl_plant.vehicle.attitude_control).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from companion.core._jit import jit
from companion.core.geometry import E_Z, clip_kernel, cross_kernel, unit_kernel
from companion.core.messages import AttitudeSetpoint, fast_frozen


@dataclass(frozen=True)
class VehicleLimits:
    """What the companion knows about the airframe, all of it readable from PX4.

    hover_thrust_normalized: collective thrust that hovers, in [0, 1] (PX4 MPC_THR_HOVER).
    A linear thrust curve is assumed, so full thrust gives g / hover_thrust_normalized
    of specific force (1.5 g for the paper's vehicle, hover = 2/3).
    max_tilt: rad, largest tilt of the thrust axis from vertical (PX4 MPC_TILTMAX_AIR).
    thrust_headroom: share of full thrust guidance may use; the rest is kept for the
    attitude loop's differential thrust.
    min_vertical_specific_force: m/s^2, never command less upward specific force
    than this (no free fall, never inverted).
    horizontal_margin: share of full thrust kept for horizontal control when the vertical
    demand saturates (PX4 MPC_THR_XY_MARG, default 0.3): a hard climb or braking of a descent
    can no longer take all the thrust and leave the vehicle unable to brake horizontally.
    gravity: m/s^2. mass: kg, used only to report thrust in newtons. max_tilt, gravity and mass
    have no defaults: they are the airframe's (the vehicle file, e.g. Table I), given by keyword.
    """

    hover_thrust_normalized: float
    max_tilt: float = field(kw_only=True)
    gravity: float = field(kw_only=True)
    mass: float = field(kw_only=True)
    thrust_headroom: float = 0.9
    min_vertical_specific_force: float = 0.3 * 9.81
    horizontal_margin: float = 0.3

    def __post_init__(self) -> None:
        if not 0.0 <= self.horizontal_margin <= 1.0:
            raise ValueError(f"horizontal_margin {self.horizontal_margin} is not a share of full thrust in [0, 1]")

    @property
    def max_specific_force(self) -> float:
        """Largest thrust / mass guidance may ask for, m/s^2."""
        return self.thrust_headroom * self.gravity / self.hover_thrust_normalized

    @cached_property
    def kernel_terms(self) -> tuple[float, float, float, float, float, float]:
        """The limits as the setpoint kernels take them: (g, max specific force, its square, horizontal margin
        specific force, minimum vertical specific force, tan(max tilt)). The square is Python's `**` (the C
        library's pow) and tan numpy's (its SIMD tan differs from the C library's in the last bit)."""
        maximum = self.max_specific_force
        return (float(self.gravity), float(maximum), float(maximum**2), float(self.horizontal_margin_specific_force),
                float(self.min_vertical_specific_force), float(np.tan(self.max_tilt)))

    @cached_property
    def setpoint_terms(self) -> tuple[float, ...]:
        """kernel_terms, then the mass (kg) and the hover thrust, as _setpoint takes them."""
        return (*self.kernel_terms, float(self.mass), float(self.hover_thrust_normalized))

    @property
    def horizontal_margin_specific_force(self) -> float:
        """Horizontal specific force (m/s^2) the vertical part may never take away, at most the maximum."""
        return min(self.horizontal_margin * self.gravity / self.hover_thrust_normalized, self.max_specific_force)


def limit_specific_force(acceleration: np.ndarray, limits: VehicleLimits) -> np.ndarray:
    """Clip a_d so the specific force f = g e_Z - a_d (eq. 21) is flyable; returns the flown a_d.

    Vertical first with a horizontal margin, as PX4's position controller does: f_z is
    clipped to [min_vertical_specific_force, max_specific_force], and further to what the
    total-thrust limit leaves after reserving min(|f_h|, horizontal margin) for the horizontal
    part (never below min_vertical_specific_force). The horizontal part is then scaled down to
    respect both the tilt limit (|f_h| <= f_z tan(max_tilt)) and the total-thrust limit
    (|f| <= max_specific_force). The horizontal direction is kept.
    acceleration: m/s^2, NED, shape (3,). Returns m/s^2, shape (3,). The arithmetic is
    _limited_acceleration's (eq. 21), compiled with numba when installed.
    """
    return _limited_acceleration_kernel(np.asarray(acceleration, dtype=float), *_limit_terms(limits))


def _limit_terms(limits: VehicleLimits) -> tuple[float, float, float, float, float, float]:
    """The limits as the kernels take them (computed once per VehicleLimits: it is frozen)."""
    return limits.kernel_terms


def _limited_acceleration(acceleration, gravity, max_specific_force, max_specific_force_squared,
                          horizontal_margin, min_vertical, tan_max_tilt):
    """limit_specific_force's arithmetic (eq. 21) on float64 (3,) a_d and the limits as floats (_limit_terms)."""
    force = gravity * E_Z - acceleration
    horizontal = force[:2]
    horizontal_norm = float(np.hypot(horizontal[0], horizontal[1]))
    reserved = min(horizontal_norm, horizontal_margin)
    vertical_max = max(float(np.sqrt(max(max_specific_force_squared - reserved ** 2, 0.0))), min_vertical)
    vertical = clip_kernel(float(force[2]), min_vertical, vertical_max)
    horizontal_limit = min(vertical * tan_max_tilt,
                           float(np.sqrt(max(max_specific_force_squared - vertical ** 2, 0.0))))
    if horizontal_norm > horizontal_limit:
        horizontal = horizontal * (horizontal_limit / horizontal_norm)
    limited_force = np.array([horizontal[0], horizontal[1], vertical])
    return gravity * E_Z - limited_force


def desired_rotation(acceleration: np.ndarray, los: np.ndarray, gravity: float, heading_fallback: np.ndarray | None = None) -> np.ndarray:
    """R_d = [r3 x lambda x r3, r3 x lambda, r3] of section VII (Fig. 7).

    r3 = (g e_Z - a_d)/|g e_Z - a_d| is the thrust direction (body z, FRD points down);
    r2 = r3 x lambda puts the body x axis (the camera) in the plane of lambda and r3,
    facing the target. The paper's r2 is normalised here: r3 x lambda is unit only
    when lambda is perpendicular to r3. When lambda is parallel to r3 (target straight
    below or above) the heading is undefined; heading_fallback (a forward direction,
    e.g. the previous setpoint's r1) is used instead, else north.
    acceleration: a_d, m/s^2 (3,). los: lambda (3,). Returns shape (3, 3), body FRD -> NED.
    The arithmetic is _rotation's, compiled with numba when installed.
    """
    fallback = _NORTH if heading_fallback is None else np.ascontiguousarray(heading_fallback, dtype=float)
    return _rotation_kernel(np.asarray(acceleration, dtype=float), np.asarray(los, dtype=float), float(gravity), fallback)


_NORTH = np.array([1.0, 0.0, 0.0])


def _rotation(acceleration, los, gravity, heading_fallback):
    """desired_rotation's arithmetic (section VII, Fig. 7) on float64 arrays; heading_fallback (3,) is north when
    the caller has none. |x| is sqrt(x @ x), what np.linalg.norm computes for a vector."""
    thrust_axis = unit_kernel(gravity * E_Z - acceleration)
    right = cross_kernel(thrust_axis, los)
    if np.sqrt(right @ right) < 1e-6 * max(np.sqrt(los @ los), 1e-12):
        right = cross_kernel(thrust_axis, heading_fallback)
        if np.sqrt(right @ right) < 1e-9:
            right = cross_kernel(thrust_axis, np.array([1.0, 0.0, 0.0]))
    right = unit_kernel(right)
    forward = cross_kernel(right, thrust_axis)
    rotation = np.empty((3, 3))
    rotation[:, 0] = forward
    rotation[:, 1] = right
    rotation[:, 2] = thrust_axis
    return rotation


def collective_thrust(acceleration: np.ndarray, rotation: np.ndarray, mass: float, gravity: float) -> float:
    """T = m e_Z^T R_d^T (g e_Z - a_d), eq. (22); newtons."""
    return float(_thrust_kernel(np.asarray(acceleration, dtype=float), np.ascontiguousarray(rotation, dtype=float),
                                float(mass), float(gravity)))


def _thrust(acceleration, rotation, mass, gravity):
    """collective_thrust's arithmetic, eq. (22), on float64 arrays; newtons."""
    return mass * rotation[:, 2] @ (gravity * E_Z - acceleration)


def _setpoint(acceleration, los, heading_fallback, gravity, max_specific_force, max_specific_force_squared,
              horizontal_margin, min_vertical, tan_max_tilt, mass, hover_thrust_normalized):
    """eq. (21)-(22) in one kernel: (flown a_d (3,), R_d (3, 3), T N, normalised thrust) from float64 a_d (3,),
    lambda (3,), the heading fallback (3,) and the limits as floats (_limit_terms, mass, hover thrust)."""
    flown = _limited_acceleration_kernel(acceleration, gravity, max_specific_force, max_specific_force_squared,
                                         horizontal_margin, min_vertical, tan_max_tilt)
    rotation = _rotation_kernel(flown, los, gravity, heading_fallback)
    thrust = _thrust_kernel(flown, rotation, mass, gravity)
    specific_force = thrust / mass
    thrust_normalized = clip_kernel(specific_force / gravity * hover_thrust_normalized, 0.0, 1.0)
    return flown, rotation, thrust, thrust_normalized


def _setpoint_after(acceleration, los, previous_rotation, gravity, max_specific_force, max_specific_force_squared,
                    horizontal_margin, min_vertical, tan_max_tilt, mass, hover_thrust_normalized):
    """_setpoint (eq. (21)-(22)) with the heading fallback the previous R_d's first column r1 (3, 3), as the control
    tick uses it; the identity gives north (r1 = e_X), the fallback when there is no previous setpoint."""
    return _setpoint_kernel(acceleration, los, np.ascontiguousarray(previous_rotation[:, 0]), gravity,
                            max_specific_force, max_specific_force_squared, horizontal_margin, min_vertical,
                            tan_max_tilt, mass, hover_thrust_normalized)


def _setpoint_after_into(acceleration, los, previous_rotation, setpoint_terms, rotation_out, flown_out):
    """_setpoint_after (eq. (21)-(22)) writing R_d into rotation_out (3, 3) and the flown a_d into flown_out (3,);
    returns (T N, normalised thrust) (a kernel's new arrays cost the caller more than filling its own).
    setpoint_terms: the limits as VehicleLimits.setpoint_terms gives them (gravity, max_specific_force,
    max_specific_force_squared, horizontal_margin, min_vertical, tan_max_tilt, mass, hover_thrust_normalized)."""
    (gravity, max_specific_force, max_specific_force_squared, horizontal_margin, min_vertical, tan_max_tilt, mass,
     hover_thrust_normalized) = setpoint_terms
    flown, rotation, thrust, thrust_normalized = _setpoint_after_kernel(
        acceleration, los, previous_rotation, gravity, max_specific_force, max_specific_force_squared,
        horizontal_margin, min_vertical, tan_max_tilt, mass, hover_thrust_normalized)
    rotation_out[:, :] = rotation
    flown_out[:] = flown
    return thrust, thrust_normalized


_limited_acceleration_kernel = jit(_limited_acceleration)
_rotation_kernel = jit(_rotation)
_thrust_kernel = jit(_thrust)
_setpoint_kernel = jit(_setpoint)
_setpoint_after_kernel = jit(_setpoint_after)
_setpoint_after_into_kernel = jit(_setpoint_after_into)
_IDENTITY = np.eye(3)


def attitude_setpoint(
    time: float,
    acceleration: np.ndarray,
    los: np.ndarray,
    limits: VehicleLimits,
    heading_fallback: np.ndarray | None = None,
) -> AttitudeSetpoint:
    """a_d -> (R_d, T) by eq. (21)-(22), within the vehicle's limits, as an autopilot setpoint.

    The normalised thrust is T / (m g) * hover_thrust_normalized, i.e. specific force
    over g times hover thrust (linear thrust curve); the quaternion is [w, x, y, z].
    The arithmetic is _setpoint's (limit_specific_force, desired_rotation, collective_thrust), compiled with
    numba when installed.
    """
    fallback = _NORTH if heading_fallback is None else np.ascontiguousarray(heading_fallback, dtype=float)
    flown, rotation, thrust, thrust_normalized = _setpoint_kernel(
        np.asarray(acceleration, dtype=float), np.asarray(los, dtype=float), fallback, *_limit_terms(limits),
        float(limits.mass), float(limits.hover_thrust_normalized))
    return AttitudeSetpoint(time, rotation, float(thrust_normalized), float(thrust), flown)


def attitude_setpoint_after(time: float, acceleration: np.ndarray, los: np.ndarray, limits: VehicleLimits,
                            previous: AttitudeSetpoint | None) -> AttitudeSetpoint:
    """attitude_setpoint(time, acceleration, los, limits, previous.rotation[:, 0]) (eq. (21)-(22)), and with no
    heading fallback (north) when previous is None: the control tick's call, with the previous setpoint's r1 taken
    in the kernel (_setpoint_after) and the setpoint built without the frozen dataclass's per-field setattr.
    acceleration: a_d, m/s^2, float64 (3,); los: lambda, float64 (3,)."""
    rotation = np.empty((3, 3))
    flown = np.empty(3)
    thrust, thrust_normalized = _setpoint_after_into_kernel(
        acceleration, los, _IDENTITY if previous is None else previous.rotation, limits.setpoint_terms, rotation,
        flown)
    return fast_frozen(AttitudeSetpoint, time=time, rotation=rotation, thrust_normalized=float(thrust_normalized),
                       thrust=float(thrust), acceleration=flown)
