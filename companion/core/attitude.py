"""Acceleration command -> attitude and thrust setpoint, eq. (21)-(22) of section VII.

This is the part of the geometric controller that runs on the companion: it
turns the guidance acceleration a_d into a desired attitude R_d (camera heading
on the target) and a collective thrust, normalised the way PX4 takes it in
SET_ATTITUDE_TARGET. The torque loop of eq. (23)-(24) belongs to the autopilot
(sitl_plant.vehicle.attitude_control).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.core.geometry import E_Z, cross, unit
from companion.core.messages import AttitudeSetpoint


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
    acceleration: m/s^2, NED, shape (3,). Returns m/s^2, shape (3,).
    """
    force = limits.gravity * E_Z - np.asarray(acceleration, dtype=float)
    horizontal = force[:2]
    horizontal_norm = float(np.hypot(horizontal[0], horizontal[1]))
    reserved = min(horizontal_norm, limits.horizontal_margin_specific_force)
    vertical_max = max(float(np.sqrt(max(limits.max_specific_force**2 - reserved**2, 0.0))),
                       limits.min_vertical_specific_force)
    vertical = float(np.clip(force[2], limits.min_vertical_specific_force, vertical_max))
    horizontal_limit = min(
        vertical * np.tan(limits.max_tilt),
        float(np.sqrt(max(limits.max_specific_force**2 - vertical**2, 0.0))),
    )
    if horizontal_norm > horizontal_limit:
        horizontal = horizontal * (horizontal_limit / horizontal_norm)
    limited_force = np.array([horizontal[0], horizontal[1], vertical])
    return limits.gravity * E_Z - limited_force


def desired_rotation(acceleration: np.ndarray, los: np.ndarray, gravity: float, heading_fallback: np.ndarray | None = None) -> np.ndarray:
    """R_d = [r3 x lambda x r3, r3 x lambda, r3] of section VII (Fig. 7).

    r3 = (g e_Z - a_d)/|g e_Z - a_d| is the thrust direction (body z, FRD points down);
    r2 = r3 x lambda puts the body x axis (the camera) in the plane of lambda and r3,
    facing the target. The paper's r2 is normalised here: r3 x lambda is unit only
    when lambda is perpendicular to r3. When lambda is parallel to r3 (target straight
    below or above) the heading is undefined; heading_fallback (a forward direction,
    e.g. the previous setpoint's r1) is used instead, else north.
    acceleration: a_d, m/s^2 (3,). los: lambda (3,). Returns shape (3, 3), body FRD -> NED.
    """
    thrust_axis = unit(gravity * E_Z - np.asarray(acceleration, dtype=float))
    right = cross(thrust_axis, los)
    if np.linalg.norm(right) < 1e-6 * max(float(np.linalg.norm(los)), 1e-12):
        forward_hint = np.array([1.0, 0.0, 0.0]) if heading_fallback is None else np.asarray(heading_fallback, float)
        right = cross(thrust_axis, forward_hint)
        if np.linalg.norm(right) < 1e-9:
            right = cross(thrust_axis, np.array([1.0, 0.0, 0.0]))
    right = unit(right)
    forward = cross(right, thrust_axis)
    return np.column_stack([forward, right, thrust_axis])


def collective_thrust(acceleration: np.ndarray, rotation: np.ndarray, mass: float, gravity: float) -> float:
    """T = m e_Z^T R_d^T (g e_Z - a_d), eq. (22); newtons."""
    return float(mass * rotation[:, 2] @ (gravity * E_Z - np.asarray(acceleration, dtype=float)))


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
    """
    flown = limit_specific_force(acceleration, limits)
    rotation = desired_rotation(flown, los, limits.gravity, heading_fallback)
    thrust = collective_thrust(flown, rotation, limits.mass, limits.gravity)
    specific_force = thrust / limits.mass
    thrust_normalized = float(np.clip(specific_force / limits.gravity * limits.hover_thrust_normalized, 0.0, 1.0))
    return AttitudeSetpoint(time, rotation, thrust_normalized, thrust, flown)
