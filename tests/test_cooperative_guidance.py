"""Cooperative guidance: seed 002 circumnavigation, seed 004 TOGVF, separation, weaving switch.

References are independent of the code under test: closed forms of circle geometry and kinematics,
and trajectories integrated with scipy's solve_ivp (single integrator, the seeds' own model) or with
the exact constant-acceleration update of a double integrator.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from companion.core.cooperative_guidance import (
    CircumnavigationGuidance,
    CooperativeContext,
    SeparationFilter,
    StandoffTrackingGuidance,
    line_of_sight_angle,
    neighbours_make_range_observable,
    phase,
    phase_spacing_errors,
    tangent_point,
)
from companion.core.messages import NeighbourState

# The seed's kinematic law as published: no turn-rate cap (our addition for bounded acceleration).
SEED002 = dict(desired_radius=5.0, g1=1.2, g2=1.0, g3=0.4, alpha=1.0, max_turn_acceleration=math.inf)
# Seed 002's five initial positions lost their signs in the text; these are spread in all four quadrants.
SEED002_STARTS = np.array([[3.0, 8.0], [-6.0, 4.0], [-7.0, -5.0], [2.0, -9.0], [9.0, -1.0]])  # (north, east)


def seed002_target_velocity(t: float) -> np.ndarray:
    """Seed 002's target velocity v_t = [2 - 2 cos(0.1 t), 2 + sin(0.05 t)] (seed x -> east, y -> north), NED."""
    east, north = 2.0 - 2.0 * math.cos(0.1 * t), 2.0 + math.sin(0.05 * t)
    return np.array([north, east, 0.0])


def seed002_target_position(t: float) -> np.ndarray:
    """Integral of seed002_target_velocity from 0 (target at the origin at t = 0), NED."""
    east = 2.0 * t - 20.0 * math.sin(0.1 * t)
    north = 2.0 * t + 20.0 * (1.0 - math.cos(0.05 * t))
    return np.array([north, east, 0.0])


def seed002_target_acceleration(t: float) -> np.ndarray:
    return np.array([0.05 * math.cos(0.05 * t), 0.2 * math.sin(0.1 * t), 0.0])


def neighbours_of(i: int, positions: np.ndarray, velocities: np.ndarray, time: float) -> tuple[NeighbourState, ...]:
    return tuple(NeighbourState(j + 1, time, positions[j], velocities[j]) for j in range(len(positions)) if j != i)


def horizontal_radius(position: np.ndarray, target: np.ndarray) -> float:
    return float(np.hypot(position[0] - target[0], position[1] - target[1]))


# ---------------------------------------------------------------------------------------------- conventions

def test_phase_convention_is_counter_clockwise_seen_from_above():
    target = np.array([10.0, -3.0, -5.0])
    assert phase(target + [0.0, 2.0, 0.0], target) == pytest.approx(0.0)  # east
    assert phase(target + [2.0, 0.0, 0.0], target) == pytest.approx(math.pi / 2)  # north
    assert phase(target + [0.0, -2.0, 0.0], target) == pytest.approx(math.pi)  # west
    assert phase(target + [-2.0, 0.0, 7.0], target) == pytest.approx(-math.pi / 2)  # south, any height


def test_single_pursuer_on_the_orbit_flies_north_from_the_east_point():
    """Seen from above, CCW from the east point heads north at the seed's tangential speed g2 D* alpha."""
    law = CircumnavigationGuidance(**SEED002)
    context = CooperativeContext(0.0, np.array([0.0, 5.0, 0.0]), np.zeros(3), np.zeros(3), np.zeros(3))
    assert law.desired_velocity(context) == pytest.approx([5.0, 0.0, 0.0])
    assert law.includes_range_control and StandoffTrackingGuidance.includes_range_control


def test_radial_term_and_target_feed_forward():
    """Off the orbit, eq. (10) adds g1 (D - D*) along the bearing; the target velocity is fed forward."""
    law = CircumnavigationGuidance(**SEED002)
    v_t = np.array([1.0, -2.0, 0.5])
    context = CooperativeContext(0.0, np.array([0.0, 9.0, 0.0]), np.zeros(3), np.zeros(3), v_t)
    # D = 9: radial 1.2 * 4 towards the target (west, -east), tangential 5 north.
    assert law.desired_velocity(context) == pytest.approx(v_t + [5.0, -4.8, 0.0])


def test_spacing_angle_is_the_nearest_neighbour_ahead():
    law = CircumnavigationGuidance(**SEED002)
    at = lambda angle: np.array([5.0 * math.sin(angle), 5.0 * math.cos(angle), 0.0])  # phase angle, (n, e, d)
    neighbours = (NeighbourState(2, 0.0, at(2.0), np.zeros(3)), NeighbourState(3, 0.0, at(-0.5), np.zeros(3)),
                  NeighbourState(4, 0.0, at(1.0), np.zeros(3)))
    context = CooperativeContext(0.0, at(0.3), np.zeros(3), np.zeros(3), np.zeros(3), neighbours)
    assert law.spacing_angle(context) == pytest.approx(0.7)
    alone = CooperativeContext(0.0, at(0.3), np.zeros(3), np.zeros(3), np.zeros(3))
    assert law.spacing_angle(alone) == 0.0


@given(st.integers(1, 8), st.floats(-10.0, 10.0), st.permutations(range(8)))
def test_phase_spacing_errors_vanish_for_equal_spacing(count, rotation, order):
    shuffled = [k for k in order if k < count]  # a permutation of range(count)
    errors = phase_spacing_errors([rotation + 2.0 * math.pi * k / count for k in shuffled])
    assert errors.shape == (count,)
    assert np.max(np.abs(errors)) < 1e-9


@given(st.lists(st.floats(-20.0, 20.0), min_size=1, max_size=10))
def test_phase_spacing_errors_sum_to_zero_and_match_sorted_gaps(phases):
    errors = phase_spacing_errors(phases)
    assert abs(float(np.sum(errors))) < 1e-9
    assert np.all(errors >= -2.0 * math.pi / len(phases) - 1e-12)


def test_phase_spacing_errors_closed_form():
    errors = phase_spacing_errors([math.pi, 0.0, math.pi / 2])
    third = 2.0 * math.pi / 3.0
    assert errors == pytest.approx([math.pi / 2 - third, math.pi / 2 - third, math.pi - third])
    assert phase_spacing_errors([]).shape == (0,)


vectors = st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3).map(np.array)


@settings(max_examples=80, deadline=None)
@given(vectors, vectors, vectors, vectors, st.lists(st.tuples(vectors, vectors), max_size=4))
def test_commands_are_finite_and_bounded_for_any_finite_state(own_p, own_v, target_p, target_v, others):
    """No finite state (including coincident vehicles, a pursuer right above the target, far-off values) makes a
    law or the filter return NaN or exceed its acceleration limit."""
    neighbours = tuple(NeighbourState(k + 2, 0.0, p, v) for k, (p, v) in enumerate(others))
    context = CooperativeContext(0.0, own_p, own_v, target_p, target_v, neighbours)
    guard = SeparationFilter(min_separation=2.0, max_acceleration=8.0)
    for law in (CircumnavigationGuidance(max_acceleration=10.0), StandoffTrackingGuidance(max_acceleration=8.0)):
        command = law.acceleration(context)
        assert np.all(np.isfinite(command)) and float(np.linalg.norm(command)) <= law.max_acceleration * (1 + 1e-12)
        filtered = guard.filter(own_p, own_v, command, neighbours)
        assert np.all(np.isfinite(filtered)) and float(np.linalg.norm(filtered)) <= 8.0 * (1 + 1e-12)


def test_bad_input_is_rejected():
    with pytest.raises(ValueError):
        CooperativeContext(0.0, np.array([np.nan, 0.0, 0.0]), np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError):
        CooperativeContext(0.0, np.zeros(2), np.zeros(3), np.zeros(3), np.zeros(3))
    for ident in (0, -1, True, 1.5):
        with pytest.raises(ValueError):
            NeighbourState(ident, 0.0, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError):
        NeighbourState(2, 0.0, np.array([0.0, np.inf, 0.0]), np.zeros(3))
    with pytest.raises(ValueError):
        CircumnavigationGuidance(desired_radius=-1.0)
    with pytest.raises(ValueError):
        StandoffTrackingGuidance(standoff_radius=5.0, min_turn_radius=5.0)
    with pytest.raises(ValueError):
        SeparationFilter(min_separation=2.0, influence_distance=1.0)


# ---------------------------------------------------------------------------------------------- seed 002

def _seed002_kinematics(moving: bool, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Seed 002's single-integrator swarm p_i' = u_i with a perfect target estimate, by solve_ivp.

    Returns (times (K,), positions (K, 5, 3))."""
    law = CircumnavigationGuidance(**SEED002)
    zeros = np.zeros((5, 3))

    def target(t):
        return (seed002_target_position(t), seed002_target_velocity(t)) if moving else (np.zeros(3), np.zeros(3))

    def rhs(t, y):
        positions = y.reshape(5, 3)
        p_t, v_t = target(t)
        return np.concatenate([law.desired_velocity(CooperativeContext(t, positions[i], zeros[i], p_t, v_t,
                                                                       neighbours_of(i, positions, zeros, t)))
                               for i in range(5)])

    start = np.column_stack([SEED002_STARTS, np.zeros(5)]).reshape(-1)
    times = np.linspace(0.0, duration, 301)
    solution = solve_ivp(rhs, (0.0, duration), start, t_eval=times, rtol=1e-8, atol=1e-9, max_step=0.05)
    assert solution.success
    return solution.t, solution.y.T.reshape(-1, 5, 3)


@pytest.mark.parametrize("moving", [False, True], ids=["stationary", "moving"])
def test_seed002_five_pursuers_converge_to_radius_and_equal_spacing(moving):
    """Seed 002 section 5 setting (N = 5, its gains, its target velocity): D_i -> D*, Delta_i -> 2 pi / 5."""
    times, positions = _seed002_kinematics(moving, 40.0)
    target = [seed002_target_position(t) if moving else np.zeros(3) for t in times]
    radius_error = np.array([[horizontal_radius(p, target[k]) - 5.0 for p in positions[k]] for k in range(len(times))])
    spacing_error = np.array([phase_spacing_errors([phase(p, target[k]) for p in positions[k]])
                              for k in range(len(times))])
    late = times >= 30.0
    print(f"seed002 moving={moving}: max |D - D*| last 10 s = {np.max(np.abs(radius_error[late])):.2e} m, "
          f"max |gap - 2pi/5| = {np.degrees(np.max(np.abs(spacing_error[late]))):.2e} deg, "
          f"at t=10 s {np.max(np.abs(radius_error[times >= 10.0][0])):.2e} m / "
          f"{np.degrees(np.max(np.abs(spacing_error[times >= 10.0][0]))):.2e} deg")
    assert np.max(np.abs(radius_error[late])) < 1e-4
    assert np.degrees(np.max(np.abs(spacing_error[late]))) < 0.01
    # Gaps: on the orbit seed 002's proof gives Delta' = -g2 g3 L Delta (L the Laplacian of the directed ring);
    # its slowest eigenvalues 1 - exp(+-2 pi i / 5) make the RMS gap error decay at g2 g3 (1 - cos(2 pi / 5)).
    rms = np.sqrt(np.mean(spacing_error ** 2, axis=1))
    window = (times >= 10.0) & (times <= 30.0)
    rate = -np.polyfit(times[window], np.log(rms[window]), 1)[0]
    print(f"  gap RMS decay rate {rate:.5f} 1/s, closed form {0.4 * (1.0 - math.cos(2.0 * math.pi / 5.0)):.5f} 1/s")
    assert rate == pytest.approx(0.4 * (1.0 - math.cos(2.0 * math.pi / 5.0)), rel=0.01)
    # Radius: eq. (10)'s radial dynamics D' = -g1 (D - D*) (the tangential term is perpendicular and the target
    # velocity is fed forward) give D(t) - D* = (D(0) - D*) exp(-g1 t) exactly, target moving or not.
    initial = np.hypot(SEED002_STARTS[:, 0], SEED002_STARTS[:, 1]) - 5.0
    for k in (30, 60, 100):
        expected = initial * math.exp(-1.2 * times[k])
        assert radius_error[k] == pytest.approx(expected, abs=1e-5)


def test_euler_steps_leave_the_closed_form_radius_offset():
    """Explicit Euler at seed 002's dt = 0.01: each step along the tangent leaves the circle by V^2 dt^2 / (2 D);
    the radial term pulls g1 (D - D*) dt back, so D - D* settles at V^2 dt / (2 g1 D*) (V = g2 D* alpha for one
    pursuer) -- an independent check of the sign and size of both terms."""
    law = CircumnavigationGuidance(**SEED002)
    dt, position = 0.01, np.array([0.0, 5.0, 0.0])
    for step in range(3000):
        position = position + dt * law.desired_velocity(
            CooperativeContext(step * dt, position, np.zeros(3), np.zeros(3), np.zeros(3)))
    expected = 5.0 ** 2 * dt / (2.0 * 1.2 * 5.0)
    assert horizontal_radius(position, np.zeros(3)) - 5.0 == pytest.approx(expected, rel=0.02)


def test_lone_pursuer_orbit_period():
    """No neighbour: Delta = 0, angular rate g2 alpha on the orbit; one turn takes 2 pi / (g2 alpha)."""
    law = CircumnavigationGuidance(desired_radius=5.0, g1=1.2, g2=0.5, g3=0.4, alpha=1.0, max_turn_acceleration=math.inf)
    rhs = lambda t, p: law.desired_velocity(CooperativeContext(t, p, np.zeros(3), np.zeros(3), np.zeros(3)))
    period = 2.0 * math.pi / 0.5
    solution = solve_ivp(rhs, (0.0, period), [0.0, 5.0, 0.0], rtol=1e-10, atol=1e-10)
    assert solution.y[:, -1] == pytest.approx([0.0, 5.0, 0.0], abs=1e-6)
    quarter = solve_ivp(rhs, (0.0, period / 4), [0.0, 5.0, 0.0], rtol=1e-10, atol=1e-10)
    assert quarter.y[:, -1] == pytest.approx([5.0, 0.0, 0.0], abs=1e-6)  # east -> north: counter-clockwise


def _double_integrator_swarm(law, guidance_filter, starts, duration, dt, moving, target_acceleration=True,
                             target_scale=1.0):
    """Double integrators p'' = a under the acceleration law, exact constant-acceleration steps.

    Returns per-step (time, positions (N, 3), target position (3,)) lists."""
    count = len(starts)
    positions, velocities = np.array(starts, dtype=float), np.zeros((count, 3))
    log = []
    for step in range(int(round(duration / dt))):
        t = step * dt
        p_t = target_scale * seed002_target_position(t) if moving else np.zeros(3)
        v_t = target_scale * seed002_target_velocity(t) if moving else np.zeros(3)
        a_t = target_scale * seed002_target_acceleration(t) if (moving and target_acceleration) else None
        commands = []
        for i in range(count):
            neighbours = neighbours_of(i, positions, velocities, t)
            command = law.acceleration(CooperativeContext(t, positions[i], velocities[i], p_t, v_t, neighbours, a_t))
            if guidance_filter is not None:
                command = guidance_filter.filter(positions[i], velocities[i], command, neighbours)
            commands.append(command)
        commands = np.array(commands)
        positions = positions + velocities * dt + 0.5 * commands * dt * dt
        velocities = velocities + commands * dt
        log.append((t + dt, positions.copy(), target_scale * seed002_target_position(t + dt) if moving else np.zeros(3)))
    return log


@pytest.mark.parametrize("moving", [False, True], ids=["stationary", "moving"])
def test_acceleration_law_on_double_integrators_reaches_the_seed002_orbit(moving):
    """The velocity-tracking acceleration law on double integrators (3-D, 3 m above the target, starting 4 m
    off that altitude) reproduces the kinematic result: radius, altitude offset and equal spacing."""
    law = CircumnavigationGuidance(**SEED002, altitude_offset=3.0, velocity_gain=3.0, max_acceleration=30.0)
    starts = np.column_stack([SEED002_STARTS, np.full(5, 1.0)])
    log = _double_integrator_swarm(law, None, starts, 40.0, 0.005, moving)
    late = [entry for entry in log if entry[0] >= 30.0]
    radius = max(abs(horizontal_radius(p, target) - 5.0) for _, ps, target in late for p in ps)
    height = max(abs((target[2] - p[2]) - 3.0) for _, ps, target in late for p in ps)
    spacing = max(np.max(np.abs(phase_spacing_errors([phase(p, target) for p in ps]))) for _, ps, target in late)
    print(f"double integrator moving={moving}: max |D - D*| {radius:.3e} m, max |h - 3| {height:.2e} m, "
          f"max gap error {np.degrees(spacing):.2e} deg")
    assert radius < 0.02
    assert height < 1e-3
    assert np.degrees(spacing) < 0.1


def _issue_case(law, guard, duration=60.0, dt=0.01):
    """Three pursuers taking off 5-7 m apart, target 56 m away and 20 m up flying 5 m/s (the constant-velocity
    scenario's target), perfect estimate; double integrators. Returns (spacing RMS deg over the last 20 s,
    radius RMS m over the last 20 s, minimum pursuer separation m, minimum range to the target m)."""
    positions = np.array([[0.0, 0.0, 0.0], [5.0, -3.0, 0.0], [-4.0, 6.0, 0.0]])
    velocities = np.zeros((3, 3))
    spacing, radius, separation, closest = [], [], math.inf, math.inf
    for step in range(int(round(duration / dt))):
        t = step * dt
        target = np.array([50.0, -25.0, -20.0]) + np.array([3.0, 4.0, 0.0]) * t
        commands = []
        for i in range(3):
            neighbours = neighbours_of(i, positions, velocities, t)
            command = law.acceleration(CooperativeContext(t, positions[i], velocities[i], target,
                                                          np.array([3.0, 4.0, 0.0]), neighbours))
            commands.append(command if guard is None else guard.filter(positions[i], velocities[i], command, neighbours))
        commands = np.array(commands)
        assert np.all(np.linalg.norm(commands, axis=1) <= 6.0 + 1e-9)
        positions = positions + velocities * dt + 0.5 * commands * dt * dt
        velocities = velocities + commands * dt
        target = np.array([50.0, -25.0, -20.0]) + np.array([3.0, 4.0, 0.0]) * (t + dt)
        separation = min([separation] + [float(np.linalg.norm(positions[i] - positions[j]))
                                         for i in range(3) for j in range(i)])
        closest = min([closest] + [float(np.linalg.norm(p - target)) for p in positions])
        if t + dt > duration - 20.0:
            spacing.append(phase_spacing_errors([phase(p, target) for p in positions]))
            radius.extend(horizontal_radius(p, target) - law.desired_radius for p in positions)
    return (float(np.degrees(np.sqrt(np.mean(np.square(spacing))))), float(np.sqrt(np.mean(np.square(radius)))),
            separation, closest)


def test_default_circumnavigation_fits_a_6_ms2_multirotor():
    """The swarm goals' geometry with the defaults (D* = 8 m, 6 m/s^2): spacing RMS < 5 deg, radius converged,
    separation kept by the filter, never closer than r_d / 2 to the target. With g2 = 0.5 the orbit needs
    6.75 m/s^2: without the turn cap a pursuer saturates and circles outside the orbit; with it the radius
    converges (the spacing then cannot, as the docstring says: the cap binds on the orbit)."""
    guard = SeparationFilter(min_separation=3.0, braking_acceleration=3.0, max_acceleration=6.0, horizon=0.05)
    spacing, radius, separation, closest = _issue_case(CircumnavigationGuidance(), guard)
    uncapped = _issue_case(CircumnavigationGuidance(g2=0.5, max_turn_acceleration=math.inf), None)
    capped = _issue_case(CircumnavigationGuidance(g2=0.5), None)
    print(f"defaults, 3 pursuers, 6 m/s^2: spacing RMS {spacing:.3f} deg, radius RMS {radius:.3f} m, "
          f"min separation {separation:.2f} m, min range {closest:.2f} m; g2 = 0.5 without the turn cap: spacing "
          f"RMS {uncapped[0]:.1f} deg, radius RMS {uncapped[1]:.2f} m; with it: {capped[0]:.1f} deg, {capped[1]:.3f} m")
    assert spacing < 5.0
    assert radius < 0.1
    assert separation >= 3.0
    assert closest > 4.0
    assert uncapped[1] > 1.0
    assert capped[1] < 0.1


# ---------------------------------------------------------------------------------------------- seed 004

@given(st.floats(0.5, 50.0), st.floats(1.001, 20.0), st.floats(-math.pi, math.pi))
def test_tangent_point_is_tangent_and_counter_clockwise(radius, ratio, angle):
    offset = radius * ratio * np.array([math.cos(angle), math.sin(angle)])
    point = tangent_point(offset, radius)
    assert float(np.linalg.norm(point)) == pytest.approx(radius, rel=1e-9)
    to_point = point - offset
    assert abs(float(to_point @ point)) <= 1e-7 * radius * radius * ratio  # radius _|_ tangent line
    # Flying P -> T then on the circle: the heading at T is the CCW tangent (-T_y, T_x) / R.
    assert float(to_point @ np.array([-point[1], point[0]])) > 0.0
    # Seed 004 eq. (26) closed form with its upper signs.
    r2 = float(offset @ offset)
    root = math.sqrt(r2 - radius ** 2)
    assert point == pytest.approx([radius ** 2 / r2 * offset[0] - radius / r2 * offset[1] * root,
                                   radius ** 2 / r2 * offset[1] + radius / r2 * offset[0] * root])


def _togvf_kinematic(law, start, duration):
    rhs = lambda t, p: law.desired_velocity(CooperativeContext(t, p, np.zeros(3), np.zeros(3), np.zeros(3)))
    solution = solve_ivp(rhs, (0.0, duration), start, max_step=0.1, rtol=1e-7, atol=1e-8)
    assert solution.success
    return solution.y.T


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 30.0), st.floats(-math.pi, math.pi), st.floats(-15.0, 15.0))
def test_togvf_converges_to_the_standoff_circle_and_never_enters_the_inner_limit(radius0, angle, height0):
    """Stationary target, seed 004's kinematic setting: the horizontal distance tends to R and the altitude to H;
    started inside, the distance to the target never decreases (so never below r_min if started at or beyond it)."""
    law = StandoffTrackingGuidance(standoff_radius=8.0, min_turn_radius=2.0, speed=3.0, standoff_height=4.0,
                                   max_vertical_speed=2.0, max_vertical_acceleration=1.0)
    start = np.array([radius0 * math.sin(angle), radius0 * math.cos(angle), -height0])
    path = _togvf_kinematic(law, start, 40.0)
    radii = np.hypot(path[:, 0], path[:, 1])
    assert abs(radii[-1] - 8.0) < 1e-3
    assert abs(-path[-1, 2] - 4.0) < 1e-3
    if radius0 < 8.0:
        assert np.all(np.diff(radii) >= -1e-6)
        assert radii.min() >= min(radius0, 2.0) - 1e-6
    else:
        assert radii.min() >= 8.0 - 0.5 - 1e-6  # outside: the tangent path stays outside the circle up to the band


def test_togvf_vertical_profile_is_seed004_eq31():
    """Eq. (30)-(31): full rate above z0 = H + v^2 / (2 a), then sqrt(2 a (z - H)); linear hold at k_z near H."""
    law = StandoffTrackingGuidance(max_vertical_speed=2.0, max_vertical_acceleration=1.0, vertical_gain=5.0)
    critical = 2.0 ** 2 / (2.0 * 1.0)
    assert law.vertical_speed(critical + 5.0) == pytest.approx(2.0)
    assert law.vertical_speed(critical) == pytest.approx(2.0)
    assert law.vertical_speed(1.5) == pytest.approx(math.sqrt(3.0))
    assert law.vertical_speed(0.01) == pytest.approx(0.05)  # sqrt(0.02) = 0.14 > k_z e = 0.05: linear hold
    # A descent from 20 m above H under this profile: constant deceleration a from z0, as the seed's time optimum.
    context = lambda z: CooperativeContext(0.0, np.array([0.0, 8.0, -z]), np.zeros(3), np.zeros(3), np.zeros(3))
    law_h = StandoffTrackingGuidance(standoff_height=10.0, max_vertical_speed=2.0, max_vertical_acceleration=1.0,
                                     vertical_gain=5.0)
    assert law_h.desired_velocity(context(30.0))[2] == pytest.approx(2.0)  # descend (down is +)
    assert law_h.desired_velocity(context(11.5))[2] == pytest.approx(math.sqrt(3.0))
    assert law_h.desired_velocity(context(5.0))[2] < 0.0  # below H: climb


@given(st.floats(0.0, 2.0 * math.pi), st.floats(0.0, 2.9), st.floats(0.0, 2.0 * math.pi), st.floats(1.0, 6.0))
def test_moving_target_scale_holds_the_ground_speed(direction_angle, target_speed, target_angle, speed):
    """Eq. (34): alpha > 0 with |alpha v_d + v_t| = v whenever the target is slower than the pursuer."""
    # alpha >= 1 - |v_t| / v (triangle inequality), so alpha_min = 0.1 cannot bind below 0.9 v.
    assume(target_speed <= 0.9 * speed - 1e-6)
    law = StandoffTrackingGuidance(alpha_min=0.1)
    relative = speed * np.array([math.cos(direction_angle), math.sin(direction_angle)])
    target = target_speed * np.array([math.cos(target_angle), math.sin(target_angle)])
    alpha = law.moving_target_scale(relative, target, speed)
    assert alpha > 0.0
    assert float(np.linalg.norm(alpha * relative + target)) == pytest.approx(speed, rel=1e-9)


def test_moving_target_faster_than_the_pursuer_falls_back_to_alpha_min():
    law = StandoffTrackingGuidance(alpha_min=0.1)
    # |alpha (3, 0) + (0, 5)| >= 5 > 3 for every alpha: no root. Along (5, 0): both roots negative.
    assert law.moving_target_scale(np.array([3.0, 0.0]), np.array([0.0, 5.0]), 3.0) == pytest.approx(0.1)
    assert law.moving_target_scale(np.array([3.0, 0.0]), np.array([5.0, 0.0]), 3.0) == pytest.approx(0.1)
    # Head-on and faster: two positive roots, 8/3 and 2/3; the larger one (-b + sqrt) is taken.
    assert law.moving_target_scale(np.array([3.0, 0.0]), np.array([-5.0, 0.0]), 3.0) == pytest.approx(8.0 / 3.0)


def test_phase_coordination_speed_closed_form():
    """Eq. (40) generalised: v_i = clip(v0 + k R (ahead - behind), v_min, v_max)."""
    law = StandoffTrackingGuidance(standoff_radius=8.0, speed=3.0, min_speed=1.0, max_speed=6.0, phase_gain=0.2)
    at = lambda angle: np.array([8.0 * math.sin(angle), 8.0 * math.cos(angle), 0.0])
    make = lambda own, others: CooperativeContext(
        0.0, at(own), np.zeros(3), np.zeros(3), np.zeros(3),
        tuple(NeighbourState(k + 2, 0.0, at(a), np.zeros(3)) for k, a in enumerate(others)))
    assert law.coordinated_speed(make(0.0, [])) == pytest.approx(3.0)
    assert law.coordinated_speed(make(0.0, [2.0 * math.pi / 3, -2.0 * math.pi / 3])) == pytest.approx(3.0)
    assert law.coordinated_speed(make(0.0, [2.5, -1.5])) == pytest.approx(3.0 + 1.6 * (2.5 - 1.5))
    assert law.coordinated_speed(make(0.0, [3.0, -0.1])) == pytest.approx(6.0)  # saturated at v_max
    assert law.coordinated_speed(make(0.0, [0.1, -3.0])) == pytest.approx(1.0)  # saturated at v_min


@pytest.mark.parametrize("case", ["stationary", "slow", "fast"])
def test_togvf_three_pursuers_reach_the_circle_with_equal_spacing(case):
    """Seed 004 section 4.3 (3 UAVs), scaled to our vehicles, on double integrators. Moving cases use seed 002's
    target: 'slow' = its low-speed level 0.1 v_t, 'fast' = v_t (up to 5 m/s) with a faster pursuer. As seed 004
    notes, for a moving target the gaps oscillate about 2 pi / 3 (the scaling alpha varies round the orbit), so
    only the stationary case is held to a tight bound; the figures are measured."""
    speed, max_speed, scale = {"stationary": (3.0, 6.0, 0.0), "slow": (3.0, 6.0, 0.1), "fast": (6.0, 10.0, 1.0)}[case]
    law = StandoffTrackingGuidance(standoff_radius=8.0, min_turn_radius=2.0, speed=speed, min_speed=1.0,
                                   max_speed=max_speed, phase_gain=1.0, standoff_height=3.0, max_acceleration=15.0)
    starts = np.array([[12.0, 3.0, -6.0], [-4.0, 11.0, -1.0], [1.0, -14.0, -3.0]])
    log = _double_integrator_swarm(law, None, starts, 90.0, 0.02, scale > 0.0, target_scale=scale)
    late = [entry for entry in log if entry[0] >= 70.0]
    radius = max(abs(horizontal_radius(p, target) - 8.0) for _, ps, target in late for p in ps)
    height = max(abs((target[2] - p[2]) - 3.0) for _, ps, target in late for p in ps)
    spacing = np.array([phase_spacing_errors([phase(p, target) for p in ps]) for _, ps, target in late])
    closest = min(horizontal_radius(p, target) for _, ps, target in log for p in ps)
    worst, rms = np.degrees(np.max(np.abs(spacing))), np.degrees(np.sqrt(np.mean(spacing ** 2)))
    print(f"TOGVF {case}: max |r - R| last 20 s {radius:.3e} m, max |h - H| {height:.1e} m, gap error max "
          f"{worst:.3f} deg rms {rms:.3f} deg, closest to target {closest:.2f} m")
    bounds = {"stationary": (1e-2, 0.5), "slow": (1e-2, 3.0), "fast": (0.1, 25.0)}[case]
    assert radius < bounds[0]
    assert worst < bounds[1]
    assert height < 1e-2
    assert closest > 2.0


# ---------------------------------------------------------------------------------------------- separation

def _pair_minimum_distance(p1, v1, a1, p2, v2, a2, dt, substeps=8):
    """Minimum distance within one constant-acceleration step, sampled finely (exact motion, fine sampling)."""
    taus = np.linspace(0.0, dt, substeps + 1)
    dp, dv, da = p1 - p2, v1 - v2, a1 - a2
    return min(float(np.linalg.norm(dp + dv * t + 0.5 * da * t * t)) for t in taus)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(st.lists(st.floats(-12.0, 12.0), min_size=3, max_size=3), st.lists(st.floats(-4.0, 4.0), min_size=6, max_size=6),
       st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6), st.floats(1.0, 3.0), st.sampled_from([0.01, 0.05]))
def test_separation_filter_keeps_two_pursuers_apart(offset, velocities, bias, min_separation, dt):
    """Two double integrators, each commanded straight at the other at full acceleration plus a random bias,
    both filtered: from any state with braking margin left, they never come closer than min_separation."""
    guard = SeparationFilter(min_separation=min_separation, braking_acceleration=3.0, max_acceleration=6.0,
                             horizon=0.05)
    p = [np.zeros(3), np.array(offset, dtype=float)]
    v = [np.array(velocities[:3]), np.array(velocities[3:])]
    distance = float(np.linalg.norm(p[1] - p[0]))
    assume(distance > 0.1)
    closing = float((v[0] - v[1]) @ (p[1] - p[0])) / distance
    assume(guard.braking_margin(distance, closing) >= guard._trigger_margin(closing))
    closest = distance
    for step in range(int(round(10.0 / dt))):
        commands = []
        for i in (0, 1):
            j = 1 - i
            towards = (p[j] - p[i]) / float(np.linalg.norm(p[j] - p[i]))
            nominal = 6.0 * towards + 3.0 * np.array(bias[3 * i:3 * i + 3])
            neighbour = (NeighbourState(j + 1, step * dt, p[j], v[j]),)
            commands.append(guard.filter(p[i], v[i], nominal, neighbour))
            assert float(np.linalg.norm(commands[-1])) <= 6.0 + 1e-9
        closest = min(closest, _pair_minimum_distance(p[0], v[0], commands[0], p[1], v[1], commands[1], dt))
        for i in (0, 1):
            p[i] = p[i] + v[i] * dt + 0.5 * commands[i] * dt * dt
            v[i] = v[i] + commands[i] * dt
    assert closest >= min_separation - 1e-9


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(st.lists(st.floats(-12.0, 12.0), min_size=3, max_size=3), st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6),
       st.floats(1.0, 3.0), st.sampled_from([0.01, 0.02, 0.05]))
def test_non_reciprocal_filter_keeps_clear_of_a_constant_velocity_neighbour(offset, velocities, min_separation, dt):
    """Only this pursuer filters (reciprocal=False); the neighbour flies on at constant velocity and this pursuer's
    nominal command chases it at full acceleration: the separation still holds (update period <= horizon)."""
    guard = SeparationFilter(min_separation=min_separation, braking_acceleration=4.0, max_acceleration=6.0,
                             horizon=0.05, reciprocal=False)
    p, q = np.zeros(3), np.array(offset, dtype=float)
    v, w = np.array(velocities[:3]), np.array(velocities[3:])
    distance = float(np.linalg.norm(q - p))
    assume(distance > 0.1)
    closing = float((v - w) @ (q - p)) / distance
    assume(guard.braking_margin(distance, closing) >= guard._trigger_margin(closing))
    closest = distance
    for step in range(int(round(8.0 / dt))):
        command = guard.filter(p, v, 6.0 * (q - p) / float(np.linalg.norm(q - p)),
                               (NeighbourState(2, step * dt, q, w),))
        closest = min(closest, _pair_minimum_distance(p, v, command, q, w, np.zeros(3), dt))
        p, v, q = p + v * dt + 0.5 * command * dt * dt, v + command * dt, q + w * dt
    assert closest >= min_separation - 1e-9


def test_separation_filter_leaves_distant_commands_alone_and_repels_smoothly():
    guard = SeparationFilter(min_separation=2.0, influence_distance=5.0, repulsion_gain=1.0)
    command = np.array([0.5, -1.0, 0.2])
    far = (NeighbourState(2, 0.0, np.array([20.0, 0.0, 0.0]), np.zeros(3)),)
    assert guard.filter(np.zeros(3), np.zeros(3), command, far) == pytest.approx(command)
    # Neighbour 3.5 m north, both still: repulsion k ((5 - 3.5) / 3)^2 = 0.25 m/s^2 southwards, no constraint.
    near = (NeighbourState(2, 0.0, np.array([3.5, 0.0, 0.0]), np.zeros(3)),)
    assert guard.filter(np.zeros(3), np.zeros(3), command, near) == pytest.approx(command + [-0.25, 0.0, 0.0])


def test_separation_filter_brakes_a_closing_pursuer():
    """Closing at 4 m/s from 3 m with d_min = 2: the component towards the neighbour becomes -a_b, the rest is kept."""
    guard = SeparationFilter(min_separation=2.0, influence_distance=2.5, braking_acceleration=3.0, max_acceleration=8.0)
    neighbour = (NeighbourState(2, 0.0, np.array([3.0, 0.0, 0.0]), np.zeros(3)),)
    out = guard.filter(np.zeros(3), np.array([4.0, 0.0, 0.0]), np.array([5.0, 1.0, 0.0]), neighbour)
    assert out == pytest.approx([-3.0, 1.0, 0.0])


def test_separation_in_the_seed002_swarm_with_the_filter():
    """Seed 002's five pursuers on double integrators around its moving target, with the filter: measured minimum
    separation (the guarantee is pairwise; this is the five-pursuer figure)."""
    law = CircumnavigationGuidance(**SEED002, velocity_gain=3.0, max_acceleration=30.0)
    guard = SeparationFilter(min_separation=1.5, influence_distance=2.5, braking_acceleration=6.0,
                             max_acceleration=30.0, horizon=0.05)
    starts = np.array([[0.0, 2.0 + 2.5 * k, 0.0] for k in range(5)])  # in a row at one phase: all head for one point
    results = {}
    for name, filter_ in (("unfiltered", None), ("filtered", guard)):
        log = _double_integrator_swarm(law, filter_, starts, 30.0, 0.01, True)
        results[name] = min(float(np.linalg.norm(ps[i] - ps[j])) for _, ps, _ in log
                            for i in range(5) for j in range(i))
        late = [entry for entry in log if entry[0] >= 25.0]
        results[name + " gap error deg"] = max(
            np.degrees(np.max(np.abs(phase_spacing_errors([phase(p, target) for p in ps])))) for _, ps, target in late)
    print("seed002 swarm minimum separation:", results)
    assert results["unfiltered"] < 1.5  # the case does bring pursuers too close without the filter
    assert results["filtered"] >= 1.5
    assert results["filtered gap error deg"] < 0.5


# ---------------------------------------------------------------------------------------------- weaving switch

def test_weaving_switch_geometric_cases():
    own, target = np.array([0.0, 0.0, 0.0]), np.array([10.0, 0.0, 0.0])
    limit = math.radians(15.0)
    assert not neighbours_make_range_observable(own, target, [], limit)
    assert neighbours_make_range_observable(own, target, [np.array([10.0, 10.0, 0.0])], limit)  # 90 deg
    assert not neighbours_make_range_observable(own, target, [np.array([20.0, 0.0, 0.0])], limit)  # same line
    assert not neighbours_make_range_observable(own, target, [np.array([5.0, 0.0, 0.0])], limit)  # behind, in line
    assert not neighbours_make_range_observable(own, target, [target.copy()], limit)  # no line of sight
    # 10 m from the target, 14 deg and 16 deg off our line of sight.
    below = target - 10.0 * np.array([math.cos(math.radians(14.0)), math.sin(math.radians(14.0)), 0.0])
    above = target - 10.0 * np.array([math.cos(math.radians(16.0)), 0.0, math.sin(math.radians(16.0))])
    assert not neighbours_make_range_observable(own, target, [below], limit)
    assert neighbours_make_range_observable(own, target, [below, above], limit)
    # Opposite side, 16 deg off the line: lines of sight 164 deg apart as directions, 16 deg as lines.
    opposite = target + 10.0 * np.array([math.cos(math.radians(16.0)), math.sin(math.radians(16.0)), 0.0])
    assert neighbours_make_range_observable(own, target, [opposite], limit)
    assert not neighbours_make_range_observable(own, target, [np.array([np.nan, 0.0, 0.0])], limit)
    with pytest.raises(ValueError):
        neighbours_make_range_observable(own, target, [], 0.0)


@given(st.floats(0.0, math.pi), st.floats(1.0, 50.0), st.floats(1.0, 50.0), st.floats(-math.pi, math.pi))
def test_line_of_sight_angle_matches_the_construction(angle, own_range, other_range, roll):
    """Place the neighbour's line of sight at a known angle (rotated about our line of sight by `roll`)."""
    target = np.array([3.0, -2.0, -10.0])
    own = target - own_range * np.array([1.0, 0.0, 0.0])
    direction = np.array([math.cos(angle), math.sin(angle) * math.cos(roll), math.sin(angle) * math.sin(roll)])
    neighbour = target - other_range * direction
    expected = min(angle, math.pi - angle)
    assert line_of_sight_angle(own, neighbour, target) == pytest.approx(expected, abs=1e-7)
