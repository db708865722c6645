"""Baseline guidance laws of section VIII-C (PNG, PD controller, retro-PNG of [14], [16],
the ZEM law of [43]) and planar weaving as HNG with c_Y = 0."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, unit_vectors, vectors
from scipy.spatial.transform import Rotation

from companion.core.baseline_guidance import (
    PDFollowingController,
    ProportionalNavigationGuidance,
    RetroProportionalNavigationGuidance,
    ZEMObservabilityGuidance,
    plane_los_rates,
)
from companion.core.geometry import E_X, orthogonal_projection, unit
from companion.core.guidance import HelicalNavigationGuidance, PurePursuitGuidance

PROPERTY = settings(max_examples=100, deadline=None)

velocities = vectors(12.0)  # v, pursuer velocity, m/s
# dp = p_T - p: range 2..80 m, not within ~3 deg of the vertical, where azimuth rates blow up.
relative_positions = st.tuples(unit_vectors().filter(lambda u: math.hypot(u[0], u[1]) > 0.05), floats(2.0, 80.0)).map(
    lambda pair: pair[0] * pair[1]
)
relative_velocities = vectors(9.0)  # dv = v_T - v, m/s


def split(dp: np.ndarray) -> tuple[np.ndarray, float]:
    """los, range."""
    return unit(dp), float(np.linalg.norm(dp))


def azimuth_elevation(dp: np.ndarray) -> tuple[float, float]:
    return math.atan2(dp[1], dp[0]), math.atan2(-dp[2], math.hypot(dp[0], dp[1]))


def plane_rates_closed_form(dp: np.ndarray, dv: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(beta_dot, eps_dot, e_beta, e_eps) by differentiating beta = atan2(y, x), eps = atan2(-z, hypot(x, y))
    (NED, elevation up) by hand: the per-plane LOS rates of [14], [16], independent of the module."""
    x, y, z = dp
    vx, vy, vz = dv
    horizontal = math.hypot(x, y)
    beta, eps = azimuth_elevation(dp)
    beta_dot = (x * vy - y * vx) / horizontal**2
    horizontal_dot = (x * vx + y * vy) / horizontal
    eps_dot = (horizontal * -vz - -z * horizontal_dot) / (horizontal**2 + z**2)
    e_beta = np.array([-math.sin(beta), math.cos(beta), 0.0])  # d lambda / d beta, normalised
    e_eps = np.array([-math.sin(eps) * math.cos(beta), -math.sin(eps) * math.sin(beta), -math.cos(eps)])  # d lambda / d eps
    return beta_dot, eps_dot, e_beta, e_eps


# --------------------------------------------------------------------------- PNG


def test_png_is_zero_without_los_rate() -> None:
    png = ProportionalNavigationGuidance()
    los = unit(np.array([3.0, -4.0, 2.0]))
    for dv in (-5.0 * los, 2.0 * los, np.zeros(3)):
        np.testing.assert_allclose(png.acceleration(1.0, np.array([4.0, 1.0, -2.0]), los, 30.0, dv), 0.0, atol=1e-12)


def test_png_hand_computed_case() -> None:
    """lambda = e_X, r = 10, dv = [0, 2, 0]: lambda_dot = [0, 0.2, 0], Omega = [0, 0, 0.2];
    v = [5, 0, 0]: a = 3 Omega x v = [0, 3, 0] (towards the target's motion, |a| = N |v| |Omega|)."""
    png = ProportionalNavigationGuidance(navigation_gain=3.0)
    np.testing.assert_allclose(png.los_rate(E_X, 10.0, np.array([0.0, 2.0, 0.0])), [0.0, 0.0, 0.2], atol=1e-15)
    a = png.acceleration(0.0, np.array([5.0, 0.0, 0.0]), E_X, 10.0, np.array([0.0, 2.0, 0.0]))
    np.testing.assert_allclose(a, [0.0, 3.0, 0.0], atol=1e-14)
    a_half = ProportionalNavigationGuidance(1.5).acceleration(0.0, np.array([5.0, 0.0, 0.0]), E_X, 10.0,
                                                               np.array([0.0, 2.0, 0.0]))
    np.testing.assert_allclose(a_half, [0.0, 1.5, 0.0], atol=1e-14)


@PROPERTY
@given(velocities, relative_positions, relative_velocities)
def test_png_is_perpendicular_to_velocity_and_matches_definition(v: np.ndarray, dp: np.ndarray, dv: np.ndarray) -> None:
    png = ProportionalNavigationGuidance(navigation_gain=4.0)
    los, r = split(dp)
    a = png.acceleration(2.0, v, los, r, dv)
    assert a.shape == (3,)
    assert a @ v == pytest.approx(0.0, abs=1e-10 * max(1.0, np.linalg.norm(a) * np.linalg.norm(v)))
    omega = np.cross(los, orthogonal_projection(los) @ dv / r)
    np.testing.assert_allclose(a, 4.0 * np.cross(omega, v), atol=1e-12)
    # Omega is the angular velocity of the LOS: lambda_dot = Omega x lambda
    np.testing.assert_allclose(np.cross(png.los_rate(los, r, dv), los), orthogonal_projection(los) @ dv / r, atol=1e-12)


def test_png_needs_relative_velocity() -> None:
    with pytest.raises(ValueError):
        ProportionalNavigationGuidance().acceleration(0.0, np.ones(3), E_X, 10.0)
    with pytest.raises(ValueError):
        ProportionalNavigationGuidance().acceleration(0.0, np.ones(3), E_X, 10.0, None)


# --------------------------------------------------------------------------- PD controller


@PROPERTY
@given(velocities, relative_positions, relative_velocities)
def test_pd_controller_is_exactly_kp_range_error_plus_kd_relative_velocity(v: np.ndarray, dp: np.ndarray,
                                                                            dv: np.ndarray) -> None:
    pd = PDFollowingController(kp=0.7, kd=0.3, desired_range=12.0)
    los, r = split(dp)
    a = pd.acceleration(5.0, v, los, r, dv)
    np.testing.assert_allclose(a, 0.7 * (r - 12.0) * los + 0.3 * dv, atol=1e-12)
    # p_d - p with p_d = p^_T - r_d lambda
    np.testing.assert_allclose(a, 0.7 * (dp - 12.0 * los) + 0.3 * dv, atol=1e-10)
    # the defaults of section VIII-C1 and VIII-A
    np.testing.assert_allclose(PDFollowingController().acceleration(5.0, v, los, r, dv),
                               0.5 * (r - 8.0) * los + 0.2 * dv, atol=1e-12)


def test_pd_controller_at_the_desired_range_with_matched_velocity_is_zero() -> None:
    np.testing.assert_allclose(PDFollowingController().acceleration(0.0, np.ones(3), E_X, 8.0, np.zeros(3)), 0.0)


def test_only_the_pd_controller_includes_range_control() -> None:
    assert PDFollowingController.includes_range_control is True
    assert PDFollowingController().includes_range_control is True
    others = (PurePursuitGuidance(3.0), HelicalNavigationGuidance(3.0, 3.5, 3.5), ProportionalNavigationGuidance(),
              RetroProportionalNavigationGuidance(), ZEMObservabilityGuidance())
    for law in others:
        assert getattr(law, "includes_range_control", False) is False
    # a ClassVar, not a dataclass field: it cannot be switched off per instance
    assert "includes_range_control" not in {field.name for field in dataclasses.fields(PDFollowingController)}


def test_pd_controller_needs_relative_velocity() -> None:
    with pytest.raises(ValueError):
        PDFollowingController().acceleration(0.0, np.ones(3), E_X, 10.0)


def test_laws_are_frozen() -> None:
    laws = ((ProportionalNavigationGuidance(), "navigation_gain"), (PDFollowingController(), "kp"),
            (RetroProportionalNavigationGuidance(), "gain"), (ZEMObservabilityGuidance(), "k_w"))
    for law, field in laws:
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(law, field, 1.0)


# --------------------------------------------------------------------------- per-plane LOS rates


@PROPERTY
@given(velocities, relative_positions, relative_velocities)
def test_plane_los_rates_match_finite_differences_along_a_straight_path(v: np.ndarray, dp: np.ndarray,
                                                                        dv: np.ndarray) -> None:
    h = 1e-5
    rates = plane_los_rates(dp, dv)
    beta, eps = azimuth_elevation(dp)
    assert rates.beta == pytest.approx(beta, abs=1e-15)
    assert rates.eps == pytest.approx(eps, abs=1e-15)
    beta_dot, eps_dot, e_beta, e_eps = plane_rates_closed_form(dp, dv)
    assert rates.beta_dot == pytest.approx(beta_dot, rel=1e-9, abs=1e-12)
    assert rates.eps_dot == pytest.approx(eps_dot, rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(rates.e_beta, e_beta, atol=1e-12)
    np.testing.assert_allclose(rates.e_eps, e_eps, atol=1e-12)
    beta_plus, eps_plus = azimuth_elevation(dp + h * dv)
    beta_minus, eps_minus = azimuth_elevation(dp - h * dv)
    beta_step = (beta_plus - beta_minus + math.pi) % (2.0 * math.pi) - math.pi  # unwrap across +-pi
    assert rates.beta_dot == pytest.approx(beta_step / (2.0 * h), rel=1e-6, abs=1e-8)
    assert rates.eps_dot == pytest.approx((eps_plus - eps_minus) / (2.0 * h), rel=1e-6, abs=1e-8)


@PROPERTY
@given(velocities, relative_positions, relative_velocities)
def test_plane_unit_vectors_are_orthonormal_with_the_los(v: np.ndarray, dp: np.ndarray, dv: np.ndarray) -> None:
    rates = plane_los_rates(dp, dv)
    los, r = split(dp)
    frame = np.array([los, rates.e_beta, rates.e_eps])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    assert rates.e_beta[2] == 0.0  # horizontal
    # e_eps lies in the vertical plane of the LOS and points towards increasing elevation
    assert np.cross(los, rates.e_eps) @ np.array([0.0, 0.0, 1.0]) == pytest.approx(0.0, abs=1e-12)
    _, eps_up = azimuth_elevation(dp + 1e-4 * r * rates.e_eps)
    assert eps_up > rates.eps
    # lambda_dot = P_lambda dv / r = cos(eps) beta_dot e_beta + eps_dot e_eps
    np.testing.assert_allclose(orthogonal_projection(los) @ dv / r,
                               math.cos(rates.eps) * rates.beta_dot * rates.e_beta + rates.eps_dot * rates.e_eps,
                               atol=1e-12)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_plane_los_rates_straight_above_or_below(sign: float) -> None:
    dp = np.array([0.0, 0.0, sign * 10.0])
    dv = np.array([1.0, 2.0, 0.5])
    rates = plane_los_rates(dp, dv)
    assert rates.beta_dot == 0.0
    assert rates.eps == pytest.approx(-sign * math.pi / 2.0)
    for vector in (rates.e_beta, rates.e_eps):
        assert np.linalg.norm(vector) == pytest.approx(1.0)
        assert vector @ dp == pytest.approx(0.0, abs=1e-12)
    assert all(math.isfinite(value) for value in (rates.beta, rates.beta_dot, rates.eps, rates.eps_dot))


def test_plane_los_rates_reject_a_zero_relative_position() -> None:
    with pytest.raises(ValueError):
        plane_los_rates(np.zeros(3), np.ones(3))


# --------------------------------------------------------------------------- retro-PNG


@PROPERTY
@given(velocities, relative_positions, relative_velocities)
def test_retro_png_pushes_with_the_los_rate(v: np.ndarray, dp: np.ndarray, dv: np.ndarray) -> None:
    retro = RetroProportionalNavigationGuidance()
    los, r = split(dp)
    a = retro.acceleration(1.0, v, los, r, dv)
    beta_dot, eps_dot, e_beta, e_eps = plane_rates_closed_form(dp, dv)
    speed = np.linalg.norm(v)
    scale = max(1.0, speed * (abs(beta_dot) + abs(eps_dot)))
    # a = -K |v| (beta_dot e_beta + eps_dot e_eps), K = 2 (the default gain), per plane.
    np.testing.assert_allclose(a, -2.0 * speed * (beta_dot * e_beta + eps_dot * e_eps), rtol=1e-9, atol=1e-12 * scale)
    assert a @ los == pytest.approx(0.0, abs=1e-10 * max(1.0, np.linalg.norm(a)))
    # opposite to a PNG-like per-plane command (N v_c theta_dot with N v_c > 0)
    assert a @ (beta_dot * e_beta + eps_dot * e_eps) <= 1e-12 * scale


def test_retro_png_scales_with_gain_and_speed() -> None:
    dp = np.array([30.0, 10.0, -8.0])
    dv = np.array([1.0, 3.0, 2.0])
    los, r = split(dp)
    v = np.array([3.0, 0.0, 4.0])
    base = RetroProportionalNavigationGuidance(gain=2.0).acceleration(0.0, v, los, r, dv)
    assert np.linalg.norm(base) > 0.0
    np.testing.assert_allclose(RetroProportionalNavigationGuidance(gain=6.0).acceleration(0.0, v, los, r, dv), 3.0 * base)
    np.testing.assert_allclose(RetroProportionalNavigationGuidance(gain=2.0).acceleration(0.0, 2.5 * v, los, r, dv),
                               2.5 * base)
    # only the speed matters, not the direction of v
    np.testing.assert_allclose(RetroProportionalNavigationGuidance().acceleration(0.0, np.array([0.0, -5.0, 0.0]), los, r, dv),
                               base)


def test_retro_png_is_zero_without_los_rate() -> None:
    dp = np.array([30.0, 10.0, -8.0])
    los, r = split(dp)
    for dv in (-2.0 * los, 3.0 * los, np.zeros(3)):
        a = RetroProportionalNavigationGuidance().acceleration(0.0, np.array([5.0, 1.0, 0.0]), los, r, dv)
        np.testing.assert_allclose(a, 0.0, atol=1e-12)


def test_retro_png_hand_computed_horizontal_case() -> None:
    """dp = 10 e_X, dv = [0, 2, 0]: beta_dot = 0.2 rad/s, e_beta = e_Y; |v| = 5 -> a = -2*5*0.2 e_Y."""
    a = RetroProportionalNavigationGuidance().acceleration(0.0, np.array([0.0, 3.0, 4.0]), E_X, 10.0,
                                                           np.array([0.0, 2.0, 0.0]))
    np.testing.assert_allclose(a, [0.0, -2.0, 0.0], atol=1e-14)


def test_retro_png_needs_relative_velocity() -> None:
    with pytest.raises(ValueError):
        RetroProportionalNavigationGuidance().acceleration(0.0, np.ones(3), E_X, 10.0)


# --------------------------------------------------------------------------- ZEM law of [43]


def test_zem_gain_tends_to_three_as_time_to_go_vanishes() -> None:
    law = ZEMObservabilityGuidance()
    assert law.navigation_gain(0.0) == 3.0
    for t_go in (1e-3, 0.1, 0.5, 1.0):
        assert law.navigation_gain(t_go) == pytest.approx(3.0, abs=1e-3)
    x = law.k_w * 2.0**3
    assert law.navigation_gain(2.0) == pytest.approx(x / math.tan(x / 3.0), rel=1e-12)


def test_zem_gain_is_negative_in_the_retro_interval() -> None:
    law = ZEMObservabilityGuidance(k_w=0.007, max_gain=1e6)
    # x/3 in (pi/2, pi) <=> t_go in ((3 pi / (2 k_w))^(1/3), (3 pi / k_w)^(1/3))
    low, high = (1.5 * math.pi / law.k_w) ** (1 / 3), (3.0 * math.pi / law.k_w) ** (1 / 3)
    for t_go in np.linspace(low, high, 40)[1:-1]:
        x = law.k_w * t_go**3
        assert law.navigation_gain(float(t_go)) < 0.0
        assert law.navigation_gain(float(t_go)) == pytest.approx(x / math.tan(x / 3.0), rel=1e-9)
    # and positive (PNG) below the interval; the gain increases from negative to positive as t_go falls
    assert law.navigation_gain(0.9 * low) > 0.0
    gains = [law.navigation_gain(float(t)) for t in np.linspace(0.99 * high, 0.5, 200)]
    assert all(later > earlier for earlier, later in zip(gains, gains[1:]))


def test_zem_gain_is_finite_and_bounded_across_the_poles() -> None:
    law = ZEMObservabilityGuidance(k_w=0.007, max_gain=10.0)
    poles = [(3.0 * k * math.pi / law.k_w) ** (1 / 3) for k in range(1, 6)]
    sweep = list(np.linspace(0.0, 40.0, 4001)) + poles + [p * (1 + s) for p in poles for s in (-1e-9, 1e-9, -1e-3, 1e-3)]
    gains = np.array([law.navigation_gain(float(t)) for t in sweep])
    assert np.all(np.isfinite(gains))
    assert np.all(np.abs(gains) <= 10.0)
    # the oscillation between the bounds is kept (Fig. 12(b)), only clipped
    assert gains.min() == -10.0 and gains.max() == 10.0
    # x cot(x/3) -> -inf as x/3 -> pi from below (end of the retro interval), +inf from above
    assert law.navigation_gain(poles[0] * (1 - 1e-3)) == -10.0
    assert law.navigation_gain(poles[0] * (1 + 1e-3)) == 10.0


def test_zem_gain_rejects_negative_time_to_go_and_undefined_is_full_retro() -> None:
    law = ZEMObservabilityGuidance(max_gain=7.0)
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError):
            law.navigation_gain(bad)
    assert law.navigation_gain(None) == -7.0
    assert law.navigation_gain(math.inf) == -7.0


def test_zem_time_to_go_rule() -> None:
    law = ZEMObservabilityGuidance(desired_range=8.0, min_closing_speed=0.1)
    assert law.time_to_go(38.0, 5.0) == pytest.approx(6.0)
    assert law.time_to_go(6.0, 5.0) == 0.0  # inside r_d: PNG with N = 3
    assert law.time_to_go(38.0, 0.1) is None
    assert law.time_to_go(38.0, -2.0) is None


def per_plane(dp: np.ndarray, dv: np.ndarray) -> np.ndarray:
    rates = plane_los_rates(dp, dv)
    return rates.beta_dot * rates.e_beta + rates.eps_dot * rates.e_eps


@PROPERTY
@given(velocities, relative_positions, relative_velocities)
def test_zem_command_is_n_vc_theta_dot_per_plane(v: np.ndarray, dp: np.ndarray, dv: np.ndarray) -> None:
    law = ZEMObservabilityGuidance()
    los, r = split(dp)
    a = law.acceleration(3.0, v, los, r, dv)
    closing = -float(los @ dv)
    assert a @ los == pytest.approx(0.0, abs=1e-10 * max(1.0, np.linalg.norm(a)))
    beta_dot, eps_dot, e_beta, e_eps = plane_rates_closed_form(dp, dv)
    theta_dot = beta_dot * e_beta + eps_dot * e_eps
    if closing > law.min_closing_speed:
        t_go = max(r - 8.0, 0.0) / closing
        x = law.k_w * t_go**3
        gain = 3.0 if x == 0.0 else x / math.tan(x / 3.0)  # N = x cot(x/3) of [43], N(0) = 3
        expected = float(np.clip(gain, -law.max_gain, law.max_gain)) * closing * theta_dot
    else:
        expected = -law.max_gain * law.min_closing_speed * theta_dot
    np.testing.assert_allclose(a, expected, rtol=1e-7, atol=1e-12 * max(1.0, law.max_gain * np.linalg.norm(dv)))
    assert np.linalg.norm(a) <= law.max_gain * max(abs(closing), law.min_closing_speed) * np.linalg.norm(per_plane(dp, dv)) + 1e-9


def test_zem_closing_inside_desired_range_is_png_with_gain_three() -> None:
    law = ZEMObservabilityGuidance()
    dv = np.array([-2.0, 1.0, 0.0])  # closing at 2 m/s, beta_dot = 0.2 rad/s
    a = law.acceleration(0.0, np.array([2.0, 0.0, 0.0]), E_X, 5.0, dv)
    np.testing.assert_allclose(a, [0.0, 3.0 * 2.0 * 0.2, 0.0], atol=1e-14)


def test_zem_not_closing_is_a_weak_bounded_retro_push_independent_of_opening_speed() -> None:
    law = ZEMObservabilityGuidance(max_gain=10.0, min_closing_speed=0.1)
    expected = None
    for opening in (0.0, 0.05, 1.0, 10.0):
        dv = np.array([opening, 4.0, 0.0])  # beta_dot = 0.2 rad/s
        a = law.acceleration(0.0, np.array([1.0, 0.0, 0.0]), E_X, 20.0, dv)
        np.testing.assert_allclose(a, [0.0, -10.0 * 0.1 * 0.2, 0.0], atol=1e-14)
        assert a @ np.array([0.0, 1.0, 0.0]) < 0.0  # against beta_dot > 0: retro-PNG
        expected = a if expected is None else expected
        np.testing.assert_allclose(a, expected)


def test_zem_parameters_are_validated() -> None:
    for kwargs in ({"k_w": 0.0}, {"max_gain": -1.0}, {"min_closing_speed": -0.1}):
        with pytest.raises(ValueError):
            ZEMObservabilityGuidance(**kwargs)


def test_zem_needs_relative_velocity() -> None:
    with pytest.raises(ValueError):
        ZEMObservabilityGuidance().acceleration(0.0, np.ones(3), E_X, 10.0)


# --------------------------------------------------------------------------- planar weaving = HNG with c_Y = 0


@PROPERTY
@given(unit_vectors().filter(lambda u: np.linalg.norm(np.cross(E_X, u)) > 1e-3))
def test_planar_weaving_keeps_the_virtual_los_in_the_los_frame_xy_plane(los: np.ndarray) -> None:
    planar = HelicalNavigationGuidance(3.0, 3.0, 0.0)
    helical = HelicalNavigationGuidance(3.0, 3.0, 3.0)
    # The LOS frame R_eta (e_X onto lambda about e_X x lambda), built by scipy, not by the module.
    axis = np.cross(E_X, los)
    to_los_frame = Rotation.from_rotvec(math.acos(float(np.clip(los @ E_X, -1.0, 1.0))) * axis / np.linalg.norm(axis)).inv()
    planar_z = [to_los_frame.apply(planar.virtual_los(t, los, 6.0))[2] for t in np.linspace(0.0, 10.0, 101)]
    helical_z = [to_los_frame.apply(helical.virtual_los(t, los, 6.0))[2] for t in np.linspace(0.0, 10.0, 101)]
    np.testing.assert_allclose(planar_z, 0.0, atol=1e-12)
    assert max(abs(z) for z in helical_z) > 0.1


def test_planar_weaving_command_has_no_z_component_in_the_los_frame() -> None:
    """lambda = e_X, v = s e_X: with c_Y = 0 the virtual LOS is (cos a, sin a, 0) and
    a = N (v x lambda_v) x lambda = N s sin(a) e_Y; with c_Y > 0 it gains -N s sin(b) e_Z."""
    v = np.array([4.0, 0.0, 0.0])
    planar = HelicalNavigationGuidance(3.0, 3.0, 0.0)
    helical = HelicalNavigationGuidance(3.0, 3.0, 3.0)
    times = np.linspace(0.0, 2.0 * math.pi, 50)
    planar_commands = np.array([planar.acceleration(t, v, E_X, 8.0) for t in times])
    helical_commands = np.array([helical.acceleration(t, v, E_X, 8.0) for t in times])
    np.testing.assert_allclose(planar_commands[:, 2], 0.0, atol=1e-14)
    np.testing.assert_allclose(planar_commands[:, 0], 0.0, atol=1e-14)
    assert np.abs(planar_commands[:, 1]).max() > 0.5
    np.testing.assert_allclose(helical_commands[:, 2], -3.0 * 4.0 * np.sin(3.0 * np.cos(times) / 8.0), atol=1e-12)
    assert np.abs(helical_commands[:, 2]).max() > 1.0
