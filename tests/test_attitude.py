"""Acceleration command -> attitude and thrust, eq. (21)-(22) of section VII (NED, FRD body,
R maps body to NED, gravity +g e_Z)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.core.attitude import (
    VehicleLimits,
    attitude_setpoint,
    collective_thrust,
    desired_rotation,
    limit_specific_force,
)
from companion.core.geometry import E_X, E_Y, E_Z, orthogonal_projection, unit

G = 9.81
LIMITS = VehicleLimits(hover_thrust_normalized=2.0 / 3.0)  # paper's vehicle: full thrust = 1.5 g


def random_commands(count: int, seed: int, scale: float = 4.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """(a_d, lambda) pairs; a_d keeps g e_Z - a_d pointing up (flyable thrust direction)."""
    rng = np.random.default_rng(seed)
    cases = []
    while len(cases) < count:
        acceleration = rng.normal(0.0, scale, 3)
        los = rng.normal(size=3)
        if (G - acceleration[2]) > 1.0:
            cases.append((acceleration, los))
    return cases


COMMANDS = random_commands(40, seed=21)


def assert_proper_rotation(rotation: np.ndarray) -> None:
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)


# --------------------------------------------------------------------------- R_d


@pytest.mark.parametrize(("acceleration", "los"), COMMANDS)
def test_desired_rotation_columns(acceleration: np.ndarray, los: np.ndarray) -> None:
    rotation = desired_rotation(acceleration, los, G)
    assert_proper_rotation(rotation)
    r1, r2, r3 = rotation.T
    # r3: thrust direction (FRD z points down, so the rotors push along -r3 and a = g e_Z - T/m r3).
    np.testing.assert_allclose(r3, unit(G * E_Z - acceleration), atol=1e-12)
    # r2 = r3 x lambda / |.|: perpendicular to lambda and to r3.
    assert r2 @ los == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(r2, unit(np.cross(r3, los)), atol=1e-12)
    # r1 (camera) lies in the plane of lambda and r3, facing the target.
    assert np.linalg.det(np.column_stack([r1, unit(los), r3])) == pytest.approx(0.0, abs=1e-12)
    assert r1 @ los > 0.0
    np.testing.assert_allclose(r1, unit(orthogonal_projection(r3) @ los), atol=1e-12)
    # It is the paper's R_d = [r3 x lambda x r3, r3 x lambda, r3] up to normalisation of r2.
    np.testing.assert_allclose(r1, unit(np.cross(np.cross(r3, los), r3)), atol=1e-12)


def test_hover_facing_north_is_the_identity() -> None:
    np.testing.assert_allclose(desired_rotation(np.zeros(3), E_X, G), np.eye(3), atol=1e-15)
    np.testing.assert_allclose(desired_rotation(np.zeros(3), 5.0 * E_X, G), np.eye(3), atol=1e-15)


@pytest.mark.parametrize("yaw", [0.3, np.pi / 2, -2.0, np.pi])
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


@pytest.mark.parametrize(("acceleration", "los"), COMMANDS[:20])
def test_collective_thrust_is_mass_times_specific_force(acceleration: np.ndarray, los: np.ndarray) -> None:
    mass = 1.7
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


@pytest.mark.parametrize("seed", range(5))
def test_limited_command_is_flyable(seed: int) -> None:
    rng = np.random.default_rng(seed)
    tan_tilt = np.tan(LIMITS.max_tilt)
    for _ in range(200):
        command = rng.normal(0.0, 15.0, 3)
        flown = limit_specific_force(command, LIMITS)
        force, wanted = specific_force(flown), specific_force(command)
        horizontal, wanted_horizontal = force[:2], wanted[:2]
        # Tilt limit, total thrust limit, minimum upward force.
        assert np.linalg.norm(horizontal) <= force[2] * tan_tilt + 1e-9
        assert np.linalg.norm(force) <= LIMITS.max_specific_force + 1e-9
        assert force[2] >= LIMITS.min_vertical_specific_force - 1e-12
        # Vertical first: f_z is the commanded one clipped to its range.
        assert force[2] == pytest.approx(
            np.clip(wanted[2], LIMITS.min_vertical_specific_force, LIMITS.max_specific_force), abs=1e-12
        )
        # The horizontal direction is kept; it is only scaled down.
        assert np.linalg.norm(horizontal) <= np.linalg.norm(wanted_horizontal) + 1e-12
        assert horizontal[0] * wanted_horizontal[1] - horizontal[1] * wanted_horizontal[0] == pytest.approx(0.0, abs=1e-9)
        assert horizontal @ wanted_horizontal >= 0.0
        # Limiting twice changes nothing.
        np.testing.assert_allclose(limit_specific_force(flown, LIMITS), flown, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_feasible_commands_are_untouched(seed: int) -> None:
    rng = np.random.default_rng(50 + seed)
    tan_tilt = np.tan(LIMITS.max_tilt)
    checked = 0
    while checked < 100:
        command = rng.normal(0.0, 5.0, 3)
        force = specific_force(command)
        feasible = (
            LIMITS.min_vertical_specific_force <= force[2] <= LIMITS.max_specific_force
            and np.linalg.norm(force[:2]) <= force[2] * tan_tilt
            and np.linalg.norm(force) <= LIMITS.max_specific_force
        )
        if not feasible:
            continue
        checked += 1
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
    # A hard climb: the vertical part takes everything, no horizontal force is left.
    flown = limit_specific_force(np.array([3.0, 0.0, -30.0]), LIMITS)
    np.testing.assert_allclose(specific_force(flown), [0.0, 0.0, LIMITS.max_specific_force], atol=1e-12)


# --------------------------------------------------------------------------- setpoint


@pytest.mark.parametrize(("acceleration", "los"), COMMANDS + random_commands(20, seed=99, scale=20.0))
def test_attitude_setpoint_is_consistent(acceleration: np.ndarray, los: np.ndarray) -> None:
    setpoint = attitude_setpoint(3.5, acceleration, los, LIMITS)
    flown = limit_specific_force(acceleration, LIMITS)
    assert setpoint.time == 3.5
    np.testing.assert_allclose(setpoint.acceleration, flown, atol=0.0)
    np.testing.assert_allclose(setpoint.rotation, desired_rotation(flown, los, LIMITS.gravity), atol=1e-12)
    # Quaternion [w, x, y, z] of the same rotation, canonical sign w >= 0.
    quaternion = setpoint.quaternion
    assert quaternion.shape == (4,)
    assert np.linalg.norm(quaternion) == pytest.approx(1.0, abs=1e-12)
    assert quaternion[0] >= 0.0
    np.testing.assert_allclose(Rotation.from_quat(quaternion, scalar_first=True).as_matrix(), setpoint.rotation, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(np.roll(quaternion, -1)).as_matrix(), setpoint.rotation, atol=1e-12)
    # Thrust: T = m |f| (eq. 22) and its normalised form with a linear thrust curve.
    force = np.linalg.norm(specific_force(flown))
    assert setpoint.thrust == pytest.approx(LIMITS.mass * force, rel=1e-12)
    assert setpoint.thrust_normalized == pytest.approx(LIMITS.hover_thrust_normalized * force / LIMITS.gravity, rel=1e-12)
    assert 0.0 <= setpoint.thrust_normalized <= LIMITS.thrust_headroom + 1e-12


def test_hover_setpoint_is_level_at_hover_thrust() -> None:
    for hover in (2.0 / 3.0, 0.5, 0.38):
        limits = VehicleLimits(hover_thrust_normalized=hover, mass=2.3)
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
