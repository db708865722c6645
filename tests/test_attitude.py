"""Acceleration command -> attitude and thrust, eq. (21)-(22) of section VII (NED, FRD body,
R maps body to NED, gravity +g e_Z)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from paper_reference import desired_attitude, floats, unit_vectors, vectors
from scipy.spatial.transform import Rotation

from companion.assembly import vehicle_limits
from interfaces.scenario import table1_vehicle
from companion.core.attitude import (
    VehicleLimits,
    attitude_setpoint,
    collective_thrust,
    desired_rotation,
    limit_specific_force,
)
from companion.core.geometry import E_X, E_Y, E_Z, orthogonal_projection, unit

G = 9.81
LIMITS = vehicle_limits(table1_vehicle(), 2.0 / 3.0)  # paper's vehicle: full thrust = 1.5 g
PROPERTY = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])


def _flyable(acceleration: np.ndarray) -> bool:
    """g e_Z - a_d points up by more than 1 m/s^2 (a thrust direction a quadrotor can hold)."""
    return bool(G - acceleration[2] > 1.0)


# (a_d, lambda): a_d keeps g e_Z - a_d pointing up; lambda not parallel to the thrust axis.
commands = st.tuples(vectors(12.0).filter(_flyable), unit_vectors()).filter(
    lambda pair: np.linalg.norm(np.cross(G * E_Z - pair[0], pair[1])) > 1e-3 * np.linalg.norm(G * E_Z - pair[0])
)
# Any command, also far beyond what the airframe can fly (the setpoint limits it).
wild_commands = st.tuples(vectors(60.0), unit_vectors())


def assert_proper_rotation(rotation: np.ndarray) -> None:
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)


# --------------------------------------------------------------------------- R_d


@PROPERTY
@given(commands)
def test_desired_rotation_columns(command: tuple[np.ndarray, np.ndarray]) -> None:
    acceleration, los = command
    rotation = desired_rotation(acceleration, los, G)
    assert_proper_rotation(rotation)
    r1, r2, r3 = rotation.T
    # r3: thrust direction (FRD z points down, so the rotors push along -r3 and a = g e_Z - T/m r3).
    thrust_direction = (G * E_Z - acceleration) / np.linalg.norm(G * E_Z - acceleration)
    np.testing.assert_allclose(r3, thrust_direction, atol=1e-12)
    # r2 = r3 x lambda / |.|: perpendicular to lambda and to r3.
    assert r2 @ los == pytest.approx(0.0, abs=1e-12)
    assert r2 @ r3 == pytest.approx(0.0, abs=1e-12)
    # r1 (camera) lies in the plane of lambda and r3, facing the target.
    assert r1 @ np.cross(los, r3) == pytest.approx(0.0, abs=1e-12)  # triple product: coplanar
    assert r1 @ los > 0.0
    # It is the paper's R_d = [r3 x lambda x r3, r3 x lambda, r3] up to normalisation of r2.
    right = np.cross(thrust_direction, los)
    np.testing.assert_allclose(r2, right / np.linalg.norm(right), atol=1e-10)
    forward = np.cross(right, thrust_direction)
    np.testing.assert_allclose(r1, forward / np.linalg.norm(forward), atol=1e-10)
    # Independent construction: scipy's Wahba solution (z on the thrust axis, x nearest lambda).
    np.testing.assert_allclose(rotation, desired_attitude(acceleration, los, G).as_matrix(), atol=1e-9)


def test_hover_facing_north_is_the_identity() -> None:
    np.testing.assert_allclose(desired_rotation(np.zeros(3), E_X, G), np.eye(3), atol=1e-15)
    np.testing.assert_allclose(desired_rotation(np.zeros(3), 5.0 * E_X, G), np.eye(3), atol=1e-15)


@PROPERTY
@given(floats(-np.pi, np.pi))
def test_hover_heading_follows_a_horizontal_los(yaw: float) -> None:
    los = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    np.testing.assert_allclose(desired_rotation(np.zeros(3), los, G), Rotation.from_euler("z", yaw).as_matrix(), atol=1e-12)


def test_hover_with_target_above_or_below_pitches_nothing() -> None:
    """Hovering, the thrust axis stays vertical whatever the elevation of the target; the
    camera heading is the horizontal projection of the line of sight."""
    for los in (np.array([1.0, 1.0, -3.0]), np.array([-2.0, 0.5, 4.0])):
        rotation = desired_rotation(np.zeros(3), los, G)
        np.testing.assert_allclose(rotation[:, 2], E_Z, atol=1e-12)
        np.testing.assert_allclose(rotation[:, 0], unit(np.array([los[0], los[1], 0.0])), atol=1e-12)


@pytest.mark.parametrize("acceleration", [np.zeros(3), np.array([2.0, -1.0, 0.5])])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_los_parallel_to_thrust_axis_uses_the_fallback_heading(acceleration: np.ndarray, sign: float) -> None:
    r3 = unit(G * E_Z - acceleration)
    los = sign * 7.0 * r3  # target straight below (or above) along the thrust axis
    fallback = np.array([0.2, 1.0, 0.1])
    rotation = desired_rotation(acceleration, los, G, heading_fallback=fallback)
    assert_proper_rotation(rotation)
    np.testing.assert_allclose(rotation[:, 2], r3, atol=1e-12)
    np.testing.assert_allclose(rotation[:, 0], unit(orthogonal_projection(r3) @ fallback), atol=1e-12)
    # No fallback given: north (projected).
    rotation = desired_rotation(acceleration, los, G)
    assert_proper_rotation(rotation)
    np.testing.assert_allclose(rotation[:, 0], unit(orthogonal_projection(r3) @ E_X), atol=1e-12)
    # A fallback parallel to the thrust axis as well: still north, still a rotation.
    rotation = desired_rotation(acceleration, los, G, heading_fallback=r3)
    assert_proper_rotation(rotation)
    np.testing.assert_allclose(rotation[:, 0], unit(orthogonal_projection(r3) @ E_X), atol=1e-12)


def test_hover_target_straight_below_with_fallback_keeps_the_previous_heading() -> None:
    previous_forward = np.array([0.0, 1.0, 0.0])  # east
    rotation = desired_rotation(np.zeros(3), E_Z, G, heading_fallback=previous_forward)
    np.testing.assert_allclose(rotation, np.column_stack([E_Y, -E_X, E_Z]), atol=1e-12)


# --------------------------------------------------------------------------- T, eq. (22)


@PROPERTY
@given(commands, floats(0.2, 20.0))
def test_collective_thrust_is_mass_times_specific_force(command: tuple[np.ndarray, np.ndarray], mass: float) -> None:
    acceleration, los = command
    rotation = desired_rotation(acceleration, los, G)
    thrust = collective_thrust(acceleration, rotation, mass, G)
    assert thrust == pytest.approx(mass * np.linalg.norm(G * E_Z - acceleration), rel=1e-12)
    # Eq. (21) is then satisfied exactly: g e_Z - T/m R e_Z = a_d.
    np.testing.assert_allclose(G * E_Z - thrust / mass * rotation @ E_Z, acceleration, atol=1e-12)


def test_collective_thrust_projects_on_the_body_z_axis_of_any_attitude() -> None:
    rotation = Rotation.from_euler("ZYX", [0.4, 0.3, -0.2]).as_matrix()
    acceleration = np.array([1.0, -2.0, 0.5])
    expected = 2.0 * rotation[:, 2] @ (G * E_Z - acceleration)  # m e_Z^T R^T (g e_Z - a)
    assert collective_thrust(acceleration, rotation, 2.0, G) == pytest.approx(expected, rel=1e-12)


# --------------------------------------------------------------------------- limits


def specific_force(acceleration: np.ndarray) -> np.ndarray:
    return LIMITS.gravity * E_Z - acceleration


def test_vehicle_limits_maximum_specific_force() -> None:
    assert LIMITS.max_specific_force == pytest.approx(0.9 * 1.5 * 9.81)


def assert_within_limits(force: np.ndarray, limits: VehicleLimits = LIMITS) -> None:
    """Tilt limit, total thrust limit, minimum upward force."""
    assert np.linalg.norm(force[:2]) <= force[2] * np.tan(limits.max_tilt) + 1e-9
    assert np.linalg.norm(force) <= limits.max_specific_force + 1e-9
    assert force[2] >= limits.min_vertical_specific_force - 1e-12


@PROPERTY
@given(vectors(60.0))
@example(np.array([0.0, 5.96e-08, -4.0]))  # a horizontal wish below the limiter's resolution, vertical force capped
def test_limited_command_is_flyable(command: np.ndarray) -> None:
    flown = limit_specific_force(command, LIMITS)
    force, wanted = specific_force(flown), specific_force(command)
    horizontal, wanted_horizontal = force[:2], wanted[:2]
    assert_within_limits(force)
    # Vertical first, but never taking the horizontal margin (PX4 MPC_THR_XY_MARG): f_z is the commanded
    # one clipped to its range, the top of the range lowered so that min(|f_h wanted|, margin) fits in the
    # total-thrust sphere.
    margin = min(np.linalg.norm(wanted_horizontal), LIMITS.horizontal_margin_specific_force)
    top = max(np.sqrt(LIMITS.max_specific_force**2 - margin**2), LIMITS.min_vertical_specific_force)
    assert force[2] == pytest.approx(np.clip(wanted[2], LIMITS.min_vertical_specific_force, top), abs=1e-12)
    # What the margin promises: the horizontal part keeps at least min(wanted, margin), unless the tilt cone
    # at that vertical force is narrower.
    promised = min(margin, force[2] * np.tan(LIMITS.max_tilt))
    # To the resolution of the limiter's arithmetic: the horizontal room left under a saturated vertical force is
    # sqrt(f_max^2 - f_z^2), which cannot resolve a reserve below about sqrt(ulp(f_max^2)) (1.7e-7 m/s^2 here): a
    # wanted horizontal force of 6e-8 m/s^2 with f_z capped comes out as 0 (hypothesis found command = (0, 5.96e-8,
    # -4); a sweep of tiny horizontal commands gave shortfalls up to 1.2e-7 m/s^2, none beyond).
    resolution = math.sqrt(np.spacing(LIMITS.max_specific_force**2)) + 1e-9
    assert np.linalg.norm(horizontal) >= promised - resolution
    # The horizontal direction is kept; it is only scaled down.
    assert np.linalg.norm(horizontal) <= np.linalg.norm(wanted_horizontal) + 1e-12
    assert horizontal[0] * wanted_horizontal[1] - horizontal[1] * wanted_horizontal[0] == pytest.approx(0.0, abs=1e-9)
    assert horizontal @ wanted_horizontal >= 0.0
    # Limiting twice changes nothing.
    np.testing.assert_allclose(limit_specific_force(flown, LIMITS), flown, atol=1e-12)


# A flyable specific force by construction: f_z in its range, then a horizontal part inside
# both the tilt cone and the total-thrust sphere (fraction < 1 of the tighter bound).
feasible_forces = st.tuples(
    floats(LIMITS.min_vertical_specific_force, LIMITS.max_specific_force), floats(0.0, 0.999), floats(-np.pi, np.pi)
).map(
    lambda drawn: np.array([
        *(drawn[1] * min(drawn[0] * np.tan(LIMITS.max_tilt), np.sqrt(LIMITS.max_specific_force**2 - drawn[0] ** 2))
          * np.array([np.cos(drawn[2]), np.sin(drawn[2])])),
        drawn[0],
    ])
)


@PROPERTY
@given(feasible_forces)
def test_feasible_commands_are_untouched(force: np.ndarray) -> None:
    command = LIMITS.gravity * E_Z - force
    np.testing.assert_allclose(limit_specific_force(command, LIMITS), command, rtol=0.0, atol=1e-12)


def test_limits_on_named_cases() -> None:
    tan_tilt = np.tan(LIMITS.max_tilt)
    # Free fall asked: keeps the minimum upward force.
    flown = limit_specific_force(np.array([0.0, 0.0, 2.0 * G]), LIMITS)
    assert specific_force(flown)[2] == pytest.approx(LIMITS.min_vertical_specific_force)
    # A hard horizontal push at hover height: tilt-limited, direction kept.
    flown = limit_specific_force(np.array([30.0, -40.0, 0.0]), LIMITS)
    force = specific_force(flown)
    assert force[2] == pytest.approx(G)
    np.testing.assert_allclose(force[:2], -unit(np.array([30.0, -40.0])) * G * tan_tilt, atol=1e-12)
    np.testing.assert_allclose(flown[:2], unit(np.array([30.0, -40.0])) * G * tan_tilt, atol=1e-12)
    # A hard climb with a push north: the vertical part takes all but the horizontal margin, 0.3 of full
    # thrust (0.3 g / hover = 4.41 m/s^2 here, PX4's MPC_THR_XY_MARG default), which keeps the push (braking
    # still works while climbing flat out); the total stays at the maximum.
    flown = limit_specific_force(np.array([30.0, 0.0, -30.0]), LIMITS)
    margin = 0.3 * G / (2.0 / 3.0)
    np.testing.assert_allclose(specific_force(flown), [-margin, 0.0, np.sqrt(LIMITS.max_specific_force**2 - margin**2)],
                               atol=1e-12)
    # A pure climb asks for no horizontal force, and gets the whole maximum vertically.
    flown = limit_specific_force(np.array([0.0, 0.0, -30.0]), LIMITS)
    np.testing.assert_allclose(specific_force(flown), [0.0, 0.0, LIMITS.max_specific_force], atol=1e-12)
    # A small push under a hard climb keeps only what it asked (0.5 m/s^2 < margin).
    flown = limit_specific_force(np.array([0.5, 0.0, -30.0]), LIMITS)
    np.testing.assert_allclose(specific_force(flown), [-0.5, 0.0, np.sqrt(LIMITS.max_specific_force**2 - 0.25)],
                               atol=1e-12)
    with pytest.raises(ValueError, match="horizontal_margin"):
        VehicleLimits(hover_thrust_normalized=0.5, max_tilt=0.5, gravity=G, mass=1.0, horizontal_margin=1.5)


# --------------------------------------------------------------------------- setpoint


def _heading_defined(command: tuple[np.ndarray, np.ndarray]) -> bool:
    """lambda is not (nearly) along the thrust axis of the flown command, so eq. (21)'s yaw is defined."""
    acceleration, los = command
    axis = specific_force(limit_specific_force(acceleration, LIMITS))
    return bool(np.linalg.norm(np.cross(axis, los)) > 1e-3 * np.linalg.norm(axis))


@PROPERTY
@given(st.one_of(commands, wild_commands).filter(_heading_defined), floats(0.0, 1e4))
def test_attitude_setpoint_obeys_eq_21_22_within_the_limits(command: tuple[np.ndarray, np.ndarray], time: float) -> None:
    """Physics, not the module's own helpers: body z anti-parallel to a_d - g e_Z, T = m |a_d - g e_Z|
    (eq. 22), T normalised by the full thrust m g / hover, camera yaw on the target (eq. 21 and
    R_d), the tilt limit respected; scipy's Rotation is the independent rotation library."""
    acceleration, los = command
    setpoint = attitude_setpoint(time, acceleration, los, LIMITS)
    flown = setpoint.acceleration
    assert setpoint.time == time
    assert_proper_rotation(setpoint.rotation)
    # The flown command is flyable, and is the command itself whenever that was flyable.
    force = specific_force(flown)
    assert_within_limits(force)
    wanted = specific_force(acceleration)
    feasible = (LIMITS.min_vertical_specific_force <= wanted[2] <= LIMITS.max_specific_force
                and np.linalg.norm(wanted[:2]) <= wanted[2] * np.tan(LIMITS.max_tilt)
                and np.linalg.norm(wanted) <= LIMITS.max_specific_force)
    if feasible:
        np.testing.assert_allclose(flown, acceleration, atol=1e-12)
    # Body z (FRD, down) is anti-parallel to a_d - g e_Z; the tilt from vertical is within the limit.
    body_z = Rotation.from_matrix(setpoint.rotation).apply(E_Z)
    np.testing.assert_allclose(body_z, -(flown - G * E_Z) / np.linalg.norm(flown - G * E_Z), atol=1e-12)
    assert np.arccos(np.clip(body_z @ E_Z, -1.0, 1.0)) <= LIMITS.max_tilt + 1e-9
    # Eq. (21): g e_Z - T/m R e_Z = a_d, and eq. (22): T = m |a_d - g e_Z|.
    assert setpoint.thrust == pytest.approx(LIMITS.mass * np.linalg.norm(flown - G * E_Z), rel=1e-12)
    np.testing.assert_allclose(G * E_Z - setpoint.thrust / LIMITS.mass * body_z, flown, atol=1e-10)
    full_thrust = LIMITS.mass * G / LIMITS.hover_thrust_normalized  # linear thrust curve through the hover point
    assert setpoint.thrust_normalized == pytest.approx(setpoint.thrust / full_thrust, rel=1e-12)
    assert 0.0 <= setpoint.thrust_normalized <= LIMITS.thrust_headroom + 1e-12
    # Yaw: the camera (body x) is the part of lambda across the thrust axis; the whole attitude
    # is scipy's Wahba solution for (z -> thrust axis exactly, x -> lambda).
    camera = Rotation.from_matrix(setpoint.rotation).apply(E_X)
    across = los - (los @ body_z) * body_z
    np.testing.assert_allclose(camera, across / np.linalg.norm(across), atol=1e-9)
    reference = desired_attitude(flown, los, G)
    assert (reference.inv() * Rotation.from_matrix(setpoint.rotation)).magnitude() < 1e-8
    # Quaternion [w, x, y, z] of the same rotation, canonical sign w >= 0.
    quaternion = setpoint.quaternion
    assert quaternion.shape == (4,)
    assert np.linalg.norm(quaternion) == pytest.approx(1.0, abs=1e-12)
    assert quaternion[0] >= 0.0
    np.testing.assert_allclose(Rotation.from_quat(quaternion, scalar_first=True).as_matrix(), setpoint.rotation, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(np.roll(quaternion, -1)).as_matrix(), setpoint.rotation, atol=1e-12)


def test_hover_setpoint_is_level_at_hover_thrust() -> None:
    for hover in (2.0 / 3.0, 0.5, 0.38):
        limits = VehicleLimits(hover_thrust_normalized=hover, max_tilt=LIMITS.max_tilt, gravity=LIMITS.gravity, mass=2.3)
        setpoint = attitude_setpoint(0.0, np.zeros(3), E_X, limits)
        assert setpoint.thrust_normalized == pytest.approx(hover, abs=1e-15)
        assert setpoint.thrust == pytest.approx(2.3 * 9.81, rel=1e-15)
        np.testing.assert_allclose(setpoint.quaternion, [1.0, 0.0, 0.0, 0.0], atol=1e-15)
        np.testing.assert_allclose(setpoint.rotation, np.eye(3), atol=1e-15)


def test_setpoint_heading_fallback_is_passed_through() -> None:
    previous_forward = E_Y
    setpoint = attitude_setpoint(0.0, np.zeros(3), 3.0 * E_Z, LIMITS, heading_fallback=previous_forward)
    np.testing.assert_allclose(setpoint.rotation[:, 0], E_Y, atol=1e-12)


def test_quaternion_sign_is_canonical_for_a_half_turn_heading() -> None:
    # Facing south: rotation by pi about z, where both signs of the quaternion are close.
    for los in (np.array([-1.0, 1e-9, 0.0]), np.array([-1.0, -1e-9, 0.0]), -E_X):
        quaternion = attitude_setpoint(0.0, np.zeros(3), los, LIMITS).quaternion
        assert quaternion[0] >= 0.0
        np.testing.assert_allclose(np.abs(quaternion), [0.0, 0.0, 0.0, 1.0], atol=1e-8)
