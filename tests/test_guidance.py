"""Guidance of section VI: PPG, helical navigation guidance (eq. 14) and the range
controller (eq. 15-19), including its closed loop on a point-mass pursuer."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, helical_navigation, r_eta, range_control, unit_vectors, vectors

from companion.core.geometry import E_X, orthogonal_projection, unit
from companion.core.guidance import (
    HelicalNavigationGuidance,
    PurePursuitGuidance,
    RangeController,
    RangeErrorState,
    saturation,
    saturation_slope,
)

N_GAIN = 1.0  # section IX: N = 1, c_Z = c_Y = 3.5
C_WEAVE = 3.5
PROPERTY = settings(max_examples=100, deadline=None)

# (t, v, lambda, r): engaged time s, pursuer velocity m/s, unit line of sight, range estimate m.
cases = st.tuples(floats(0.0, 60.0), vectors(12.0), unit_vectors(), floats(0.5, 80.0))
# lambda kept off +-e_X, where R_eta's axis e_X x lambda (and the scipy reference) is undefined.
cases_off_x = cases.filter(lambda case: np.linalg.norm(np.cross(E_X, case[2])) > 1e-3)


# --------------------------------------------------------------------------- PPG and HNG


@PROPERTY
@given(cases, floats(0.1, 5.0))
def test_ppg_is_minus_n_times_the_velocity_across_the_los(case, gain: float) -> None:
    """Section VIII-C1: a = N (v x lambda) x lambda = -N P_lambda v."""
    t, v, los, r = case
    ppg = PurePursuitGuidance(navigation_gain=gain)
    expected = gain * np.cross(np.cross(v, los), los)
    np.testing.assert_allclose(ppg.acceleration(t, v, los, r), expected, atol=1e-12 * max(1.0, gain * np.linalg.norm(v)))
    np.testing.assert_allclose(expected, -gain * (v - (v @ los) * los), atol=1e-12 * max(1.0, gain * np.linalg.norm(v)))
    np.testing.assert_allclose(ppg.acceleration(t, v, los, r), -gain * orthogonal_projection(los) @ v, atol=1e-11)


@PROPERTY
@given(cases)
def test_hng_without_weave_is_exactly_ppg(case) -> None:
    t, v, los, r = case
    """Property 3 of section VI-A: c_Z = c_Y = 0 is pure PPG, a = N (v x lambda) x lambda."""
    hng = HelicalNavigationGuidance(navigation_gain=1.7, c_z=0.0, c_y=0.0, weave_frequency=1.3)
    # exact up to rounding: a few ulps of the unit line of sight and of |v|
    np.testing.assert_allclose(hng.virtual_los(t, los, r), los, atol=1e-12)
    np.testing.assert_allclose(hng.acceleration(t, v, los, r), 1.7 * np.cross(np.cross(v, los), los),
                               atol=1e-12 * max(1.0, np.linalg.norm(v)))


@PROPERTY
@given(cases)
def test_hng_is_perpendicular_to_the_los(case) -> None:
    """a_HN = N (v x lambda_v) x lambda is always perpendicular to lambda, so it never fights a_RC."""
    t, v, los, r = case
    hng = HelicalNavigationGuidance(N_GAIN, C_WEAVE, 2.0 * C_WEAVE)
    for range_estimate in (r, 0.2, 1e-6):  # also where the weave angles are large
        acceleration = hng.acceleration(t, v, los, range_estimate)
        assert acceleration @ los == pytest.approx(0.0, abs=1e-12 * max(1.0, np.linalg.norm(acceleration)))


@PROPERTY
@given(cases, floats(1e-3, 1e3))
def test_hng_accepts_a_non_unit_los(case, scale: float) -> None:
    t, v, los, r = case
    hng = HelicalNavigationGuidance(N_GAIN, C_WEAVE, C_WEAVE)
    np.testing.assert_allclose(hng.acceleration(t, v, scale * los, r), hng.acceleration(t, v, los, r),
                               atol=1e-12 * max(1.0, np.linalg.norm(v)))


@PROPERTY
@given(cases_off_x, floats(0.1, 5.0), floats(0.0, 10.0), floats(0.0, 10.0), floats(0.1, 3.0))
def test_hng_is_eq_14(case, gain: float, c_z: float, c_y: float, omega: float) -> None:
    """The module against eq. (14) written out with scipy's rotations (tests/paper_reference.py)."""
    t, v, los, r = case
    hng = HelicalNavigationGuidance(gain, c_z, c_y, weave_frequency=omega)
    expected = helical_navigation(t, v, los, r, gain, c_z, c_y, omega)
    np.testing.assert_allclose(hng.acceleration(t, v, los, r), expected, atol=1e-9 * max(1.0, gain * np.linalg.norm(v)))


@PROPERTY
@given(cases_off_x)
def test_virtual_los_is_lambda_rotated_by_the_weave_angles(case) -> None:
    """R_eta R_Z(alpha) R_Y(beta) e_X with alpha = c_Z sin(w t)/r, beta = c_Y cos(w t)/r:
    in the frame where lambda is e_X it is (cos a cos b, sin a cos b, -sin b), so its angle
    from lambda is acos(cos a cos b) ~ sqrt(a^2 + b^2)."""
    t, v, los, r = case
    omega, c_z, c_y = 0.8, 2.0, 3.0
    hng = HelicalNavigationGuidance(N_GAIN, c_z, c_y, weave_frequency=omega)
    alpha = c_z * np.sin(omega * t) / r
    beta = c_y * np.cos(omega * t) / r
    virtual = hng.virtual_los(t, los, r)
    assert np.linalg.norm(virtual) == pytest.approx(1.0, abs=1e-12)
    in_los_frame = r_eta(los).inv().apply(virtual)  # scipy's R_eta, not the module's
    expected = np.array([np.cos(alpha) * np.cos(beta), np.sin(alpha) * np.cos(beta), -np.sin(beta)])
    np.testing.assert_allclose(in_los_frame, expected, atol=1e-12)
    angle = np.arccos(np.clip(virtual @ los, -1.0, 1.0))
    assert np.cos(angle) == pytest.approx(np.cos(alpha) * np.cos(beta), abs=1e-12)
    if r > 20.0:  # small angles: the weave cone's angular radius
        assert angle == pytest.approx(np.hypot(alpha, beta), rel=0.02, abs=1e-9)


def test_weave_is_larger_at_short_range() -> None:
    """Property 1 of section VI-A: weak weave far away (tail chase), strong close in."""
    hng = HelicalNavigationGuidance(N_GAIN, C_WEAVE, C_WEAVE)
    los = unit(np.array([1.0, 0.3, -0.2]))
    angles = [np.arccos(np.clip(hng.virtual_los(0.7, los, r) @ los, -1.0, 1.0)) for r in (200.0, 50.0, 15.0, 8.0)]
    assert all(a < b for a, b in zip(angles, angles[1:]))
    assert angles[0] < 0.03


@PROPERTY
@given(cases_off_x, floats(0.2, 3.0))
def test_weave_frequency_sets_the_period(case, omega: float) -> None:
    t, v, los, r = case
    hng = HelicalNavigationGuidance(N_GAIN, C_WEAVE, 2.0, weave_frequency=omega)
    period = 2.0 * np.pi / omega
    np.testing.assert_allclose(hng.virtual_los(t + period, los, r), hng.virtual_los(t, los, r), atol=1e-10)
    np.testing.assert_allclose(hng.acceleration(t + 3 * period, v, los, r), hng.acceleration(t, v, los, r),
                               atol=1e-9 * max(1.0, np.linalg.norm(v)))
    # Half a period flips the weave angles: alpha, beta -> -alpha, -beta (in the frame where lambda is e_X).
    to_los_frame = r_eta(los).inv()
    half = to_los_frame.apply(hng.virtual_los(t + period / 2.0, los, r))
    now = to_los_frame.apply(hng.virtual_los(t, los, r))
    np.testing.assert_allclose(half, [now[0], -now[1], -now[2]], atol=1e-9)


def test_another_weave_frequency_has_another_period() -> None:
    omega = 1.0
    period = 2.0 * np.pi / omega
    other = HelicalNavigationGuidance(N_GAIN, C_WEAVE, 2.0, weave_frequency=1.7 * omega)
    t, los, r = 4.0, unit(np.array([0.3, -1.0, 0.2])), 10.0
    assert np.linalg.norm(other.virtual_los(t + period, los, r) - other.virtual_los(t, los, r)) > 1e-3


def test_default_weave_frequency_is_the_papers_sin_t() -> None:
    hng = HelicalNavigationGuidance(N_GAIN, C_WEAVE, C_WEAVE)
    assert hng.weave_frequency == 1.0
    los = unit(np.array([0.2, 1.0, 0.1]))
    np.testing.assert_allclose(hng.virtual_los(1.0, los, 8.0), hng.virtual_los(1.0 + 2.0 * np.pi, los, 8.0), atol=1e-12)


@PROPERTY
@given(cases)
def test_scale_with_range_false_ignores_the_range(case) -> None:
    """Property 2 of section VI-A: removing the division by r_hat is r_hat = 1."""
    t, v, los, _ = case
    unscaled = HelicalNavigationGuidance(N_GAIN, 0.3, 0.2, scale_with_range=False)
    scaled = HelicalNavigationGuidance(N_GAIN, 0.3, 0.2, scale_with_range=True)
    reference = unscaled.acceleration(t, v, los, 1.0)
    for r in (0.01, 3.0, 50.0, 1e4):
        np.testing.assert_array_equal(unscaled.acceleration(t, v, los, r), reference)
    np.testing.assert_allclose(scaled.acceleration(t, v, los, 1.0), reference, atol=1e-12 * max(1.0, np.linalg.norm(v)))
    # alpha = 0.3 sin(t)/r and beta = 0.2 cos(t)/r are never both zero: the range changes the weave.
    assert np.linalg.norm(scaled.virtual_los(t, los, 10.0) - unscaled.virtual_los(t, los, 10.0)) > 1e-3


# --------------------------------------------------------------------------- sigma


def test_saturation_is_odd_bounded_and_zero_at_zero() -> None:
    assert saturation(0.0) == 0.0
    xs = np.concatenate([np.linspace(-50.0, 50.0, 201), [1e3, -1e6, 1e9]])
    bound = 3.0 * np.pi / 2.0
    for x in xs:
        assert saturation(-x) == -saturation(x)
        assert abs(saturation(x)) < bound or abs(saturation(x)) == pytest.approx(bound)
        assert abs(saturation(x)) <= bound
        assert saturation(x) * x >= 0.0  # sector condition used by the Lyapunov function
    assert saturation(1e6) == pytest.approx(bound, abs=1e-5)
    assert saturation(1e-4) == pytest.approx(1e-4, rel=1e-8)  # sigma'(0) = 1
    # Monotone.
    values = [saturation(x) for x in np.linspace(-30.0, 30.0, 301)]
    assert all(a < b for a, b in zip(values, values[1:]))


@PROPERTY
@given(floats(-100.0, 100.0))
def test_saturation_slope_matches_finite_difference(x: float) -> None:
    h = 1e-5
    numeric = (saturation(x + h) - saturation(x - h)) / (2.0 * h)
    assert saturation_slope(x) == pytest.approx(numeric, rel=1e-7, abs=1e-10)
    assert 0.0 < saturation_slope(x) <= 1.0
    assert saturation(x) == pytest.approx(3.0 * np.arctan(x / 3.0), rel=1e-15, abs=1e-300)  # section VI-B


# --------------------------------------------------------------------------- range controller, algebra


def test_error_state_is_eq_15_16() -> None:
    controller = RangeController(desired_range=8.0)
    dp, dv = np.array([6.0, -3.0, 2.0]), np.array([1.0, 2.0, -4.0])
    error = controller.error_state(dp, dv)
    assert error.range_error == pytest.approx(7.0 - 8.0)
    assert error.range_rate == pytest.approx(dp @ dv / 7.0)


@PROPERTY
@given(floats(0.5, 5.0), floats(-40.0, 40.0), floats(-40.0, 40.0))
def test_virtual_control_makes_the_lyapunov_function_decrease(gain: float, xi1: float, xi2: float) -> None:
    """V = int_0^xi1 sigma + (sigma(xi1) + xi2)^2 / 2 with xi1' = xi2, xi2' = v* gives
    V' = sigma xi2 + (sigma + xi2)(sigma' xi2 + v*) = -sigma^2 - k (sigma + xi2)^2."""
    controller = RangeController(desired_range=8.0, gain=gain)
    v_star = controller.virtual_control(RangeErrorState(xi1, xi2))
    sigma = 3.0 * np.arctan(xi1 / 3.0)
    slope = 1.0 / (1.0 + (xi1 / 3.0) ** 2)
    assert v_star == pytest.approx(-gain * (sigma + xi2) - sigma - slope * xi2, rel=1e-12, abs=1e-12)  # eq. (17)
    v_dot = sigma * xi2 + (sigma + xi2) * (slope * xi2 + v_star)
    expected = -(sigma**2) - gain * (sigma + xi2) ** 2
    assert v_dot == pytest.approx(expected, rel=1e-9, abs=1e-9)
    if abs(xi1) > 1e-6 or abs(xi2) > 1e-6:
        assert expected < 0.0


def test_virtual_control_near_zero_is_a_damped_linear_loop() -> None:
    """Near 0: v* = -(k+1)(xi1 + xi2) (docstring: omega_n = sqrt(k+1))."""
    controller = RangeController(desired_range=8.0, gain=3.0)
    for xi1, xi2 in [(1e-4, 0.0), (0.0, 1e-4), (-3e-5, 2e-5)]:
        assert controller.virtual_control(RangeErrorState(xi1, xi2)) == pytest.approx(-4.0 * (xi1 + xi2), rel=1e-6)
    assert controller.virtual_control(RangeErrorState(0.0, 0.0)) == 0.0


def relative_motion(dp0: np.ndarray, dv0: np.ndarray, pursuer_acceleration: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Target at constant velocity, pursuer at constant acceleration a: dp(t), dv(t)."""
    return dp0 + dv0 * t - 0.5 * pursuer_acceleration * t**2, dv0 - pursuer_acceleration * t


@PROPERTY
@given(vectors(30.0).filter(lambda dp: np.linalg.norm(dp) > 1.0), vectors(6.0), vectors(6.0), vectors(0.3),
       st.sampled_from(["hng", "random", "zero"]), vectors(6.0))
def test_range_control_closes_the_loop_xi2_dot_equals_v_star(dp0, dv0, velocity, bearing_error, lateral: str, random_lateral) -> None:
    """Substituting (18)-(19) into xi2' = (|dv|^2 - xi2^2 - dp^T a)/|dp| gives xi2' = v*
    exactly, for any lateral term and any lambda with lambda^T dp > 0 (eq. 17-19)."""
    controller = RangeController(desired_range=8.0, gain=3.0)
    # A line of sight that disagrees with the estimate (noisy bearing), still well in front.
    los = unit(unit(dp0) + bearing_error)
    assert los @ dp0 > 0.0
    if lateral == "hng":
        a_lateral = HelicalNavigationGuidance(N_GAIN, C_WEAVE, C_WEAVE).acceleration(2.0, velocity, los, np.linalg.norm(dp0))
    elif lateral == "random":
        a_lateral = random_lateral
    else:
        a_lateral = np.zeros(3)
    a_rc = controller.acceleration(dp0, dv0, los, a_lateral)
    np.testing.assert_allclose(np.cross(a_rc, los), np.zeros(3), atol=1e-12 * max(1.0, np.linalg.norm(a_rc)))
    # eq. (15)-(19) written out independently.
    np.testing.assert_allclose(a_rc, range_control(dp0, dv0, los, a_lateral, 8.0, 3.0), rtol=1e-9, atol=1e-9)
    acceleration = a_lateral + a_rc

    # Central differences in time: truncation ~h^2 |d3 xi/dt3|, round-off ~1e-16 |xi| / h, both below 1e-6 here.
    h = 1e-5
    before = controller.error_state(*relative_motion(dp0, dv0, acceleration, -h))
    now = controller.error_state(dp0, dv0)
    after = controller.error_state(*relative_motion(dp0, dv0, acceleration, h))
    xi2_dot = (after.range_rate - before.range_rate) / (2.0 * h)
    xi1_dot = (after.range_error - before.range_error) / (2.0 * h)
    assert xi1_dot == pytest.approx(now.range_rate, rel=1e-6, abs=1e-6)  # eq. (16)
    assert xi2_dot == pytest.approx(controller.virtual_control(now), rel=1e-6, abs=1e-6)


def test_no_longitudinal_command_when_the_los_disagrees_by_90_degrees_or_more() -> None:
    """Remark 3: lambda^T dp <= 0 leaves eq. (18) meaningless; the command is zero."""
    controller = RangeController(desired_range=8.0)
    dp = np.array([10.0, 0.0, 0.0])
    dv = np.array([-1.0, 2.0, 0.0])
    for los in (np.array([0.0, 1.0, 0.0]), unit(np.array([-1.0, 0.5, 0.0])), np.array([-1.0, 0.0, 0.0])):
        assert los @ dp <= 0.0
        np.testing.assert_array_equal(controller.acceleration(dp, dv, los, np.zeros(3)), np.zeros(3))
    assert np.linalg.norm(controller.acceleration(dp, dv, unit(np.array([1.0, 0.9, 0.0])), np.zeros(3))) > 0.0


def test_range_command_stays_moderate_far_away() -> None:
    """Remark 2: the saturation keeps a_RC bounded however far the target is."""
    controller = RangeController(desired_range=8.0, gain=3.0)
    for distance in (50.0, 1e3, 1e5):
        los = unit(np.array([1.0, 1.0, 0.0]))
        a_rc = controller.acceleration(distance * los, np.zeros(3), los, np.zeros(3))
        # v* -> -(k+1) 3 pi/2 at rest far away: about 18.8 m/s^2 towards the target.
        assert a_rc @ los > 0.0
        assert np.linalg.norm(a_rc) <= 4.0 * 3.0 * np.pi / 2.0 + 1e-9


# --------------------------------------------------------------------------- range controller, closed loop

TARGET_START = np.array([0.0, 0.0, -10.0])
TARGET_VELOCITY = np.array([2.0, 1.0, 0.0])
DESIRED_RANGE = 8.0


def closed_loop(start: np.ndarray, use_hng: bool, duration: float = 30.0, dt: float = 0.05) -> dict[str, np.ndarray]:
    """Point-mass pursuer p'' = a_lat + a_RC, perfect knowledge of a constant-velocity
    target, RK4. Returns xi1, xi2 and V at every step."""
    controller = RangeController(desired_range=DESIRED_RANGE, gain=3.0)
    hng = HelicalNavigationGuidance(N_GAIN, C_WEAVE, C_WEAVE)

    def derivative(t: float, state: np.ndarray) -> np.ndarray:
        position, velocity = state[:3], state[3:]
        dp = TARGET_START + TARGET_VELOCITY * t - position
        dv = TARGET_VELOCITY - velocity
        los = unit(dp)
        a_lateral = hng.acceleration(t, velocity, los, float(np.linalg.norm(dp))) if use_hng else np.zeros(3)
        return np.concatenate([velocity, a_lateral + controller.acceleration(dp, dv, los, a_lateral)])

    state = np.concatenate([start, np.zeros(3)])
    xi1, xi2, speed = [], [], []
    steps = int(round(duration / dt))
    for k in range(steps + 1):
        t = k * dt
        error = controller.error_state(TARGET_START + TARGET_VELOCITY * t - state[:3], TARGET_VELOCITY - state[3:])
        xi1.append(error.range_error)
        xi2.append(error.range_rate)
        speed.append(np.linalg.norm(state[3:]))
        if k == steps:
            break
        k1 = derivative(t, state)
        k2 = derivative(t + dt / 2, state + dt / 2 * k1)
        k3 = derivative(t + dt / 2, state + dt / 2 * k2)
        k4 = derivative(t + dt, state + dt * k3)
        state = state + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    xi1_a, xi2_a = np.array(xi1), np.array(xi2)
    sigma = 3.0 * np.arctan(xi1_a / 3.0)
    integral = 3.0 * (xi1_a * np.arctan(xi1_a / 3.0) - 1.5 * np.log1p((xi1_a / 3.0) ** 2))  # int_0^xi1 sigma
    lyapunov = integral + 0.5 * (sigma + xi2_a) ** 2
    return {"xi1": xi1_a, "xi2": xi2_a, "V": lyapunov, "speed": np.array(speed)}


START_FAR = TARGET_START + np.array([60.0, 0.0, 0.0])
START_INSIDE = TARGET_START + np.array([3.0, 0.0, 0.0])
START_FAR_3D = TARGET_START + np.array([-30.0, 40.0, -20.0])


@pytest.fixture(scope="module")
def loops() -> dict[tuple[str, bool], dict[str, np.ndarray]]:
    starts = {"far": START_FAR, "inside": START_INSIDE, "far3d": START_FAR_3D}
    return {(name, hng): closed_loop(start, hng) for name, start in starts.items() for hng in (True, False)}


@pytest.mark.parametrize("start", ["far", "inside", "far3d"])
@pytest.mark.parametrize("use_hng", [True, False], ids=["hng", "no_lateral"])
def test_range_controller_drives_the_range_error_to_zero(loops, start: str, use_hng: bool) -> None:
    run = loops[(start, use_hng)]
    assert abs(run["xi1"][0]) > 4.0  # starts far from r_d (60 m away or 3 m inside)
    assert abs(run["xi1"][-1]) < 1e-3
    assert abs(run["xi2"][-1]) < 1e-3
    assert np.abs(run["xi1"][-100:]).max() < 1e-2  # settled over the last 5 s
    # The Lyapunov function never increases (V' = -sigma^2 - k (sigma + xi2)^2).
    assert np.all(np.diff(run["V"]) <= 1e-9 * max(1.0, run["V"][0]))
    # Approach speed stays bounded: |xi2| <= (3 pi / 2)(1 + 1/k) (docstring of RangeController).
    assert np.abs(run["xi2"]).max() <= 1.5 * np.pi * (1.0 + 1.0 / 3.0) + 1e-6


@pytest.mark.parametrize("start", ["far", "inside", "far3d"])
def test_range_error_dynamics_do_not_depend_on_the_lateral_term(loops, start: str) -> None:
    """With perfect knowledge xi1' = xi2, xi2' = v*(xi1, xi2) is autonomous: HNG only moves
    the pursuer around the target."""
    with_hng, without = loops[(start, True)], loops[(start, False)]
    # Up to the RK4 truncation error, which does depend on the full state (~2e-5 here).
    np.testing.assert_allclose(with_hng["xi1"], without["xi1"], atol=2e-4)
    np.testing.assert_allclose(with_hng["xi2"], without["xi2"], atol=2e-4)


def test_hng_pursuer_ends_up_circling_at_roughly_target_speed(loops) -> None:
    """Under HNG the pursuer follows the target (speed near |v_T|) while weaving around it."""
    run = loops[("far", True)]
    assert np.mean(run["speed"][-100:]) == pytest.approx(np.linalg.norm(TARGET_VELOCITY), rel=0.3)
