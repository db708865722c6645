"""The baseline estimators' kernels (companion/core/baseline_estimators.py) compute what the code they replaced
computed, bit for bit, compiled by numba and interpreted.

Evidence:
- the Python-equivalent twins of companion.core._jit that the kernels call (hypot, remainder) against math.hypot and
  math.remainder, and the transcendentals compiled (math.cos, sin, atan2, acos) against Python's, on many random
  arguments; numba's np.linalg.eigh and solve against numpy's;
- every kernel against a verbatim copy of the code it replaced (the helpers and the bodies of the update methods,
  below, with `self.` attributes as arguments) on random inputs (hypothesis), compiled and as its Python function
  (`python_function`, whose inner calls run compiled): identical values, NaN and signs of zero included;
- whole flights of the three baselines (the estimator study's setup, 50 Hz) compiled in this process against the
  same flights in a BOF_NO_JIT=1 subprocess: every logged series equal. (Against the code before the kernels, the
  same flights at 5 and 50 Hz were compared once when the kernels were written: equal.)
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from bitwise import assert_same, seeds
from paper_reference import floats, symmetric_with_eigenvalues, unit_vectors

from companion.core import _jit
from companion import warmup
from companion.core import baseline_estimators as be
from companion.core.baseline_estimators import MAX_ELEVATION, MAX_INVERSE_RANGE, MIN_INVERSE_RANGE, MIN_RANGE
from companion.core.estimators import limit_range, transition_matrices

ROOT = Path(__file__).resolve().parent.parent
python = _jit.python_function


def copies(arguments: tuple) -> list:
    return [np.array(a) if isinstance(a, np.ndarray) else a for a in arguments]


def agree(kernel, old, *arguments) -> None:
    """The kernel compiled, its Python function, and the old code: the same result on the same arguments."""
    expected = old(*copies(arguments))
    assert_same(kernel(*copies(arguments)), expected, f"{kernel.__name__} compiled")
    assert_same(python(kernel)(*copies(arguments)), expected, f"{kernel.__name__} interpreted")


def covariance(seed: int, size: int, exponent: int) -> np.ndarray:
    """A random symmetric positive definite matrix (size, size) of scale 10^exponent."""
    factor = np.random.default_rng(seed).normal(size=(size, size))
    return (factor @ factor.T + 1e-3 * np.eye(size)) * 10.0**exponent


# --- the code the kernels replaced, verbatim (module helpers renamed old_*; method bodies as functions) ------------


def old_wrap_angle(angle: float) -> float:
    """Wrap an angle (rad) to (-pi, pi]."""
    wrapped = math.remainder(float(angle), 2.0 * math.pi)  # in [-pi, pi]
    return math.pi if wrapped == -math.pi else wrapped


def old_symmetrize(matrix: np.ndarray) -> np.ndarray:
    return 0.5 * (matrix + matrix.T)


def old_symmetric_psd(matrix: np.ndarray) -> np.ndarray:
    """The nearest symmetric positive semi-definite matrix (Frobenius norm; Higham 1988): the
    symmetric part with its negative eigenvalues set to zero. Shape (n, n) in and out.

    Why: the MSC-EKF moves its covariance through congruences J P J^T whose Jacobians are badly
    scaled far out (at the inverse-range floor, entries of 1e6 beside 1e-6), and their rounding
    can leave eigenvalues of -1e-6 beside 0.1, which the next steps amplify. A symmetric
    PSD input comes back unchanged (the same bits).
    """
    symmetric = old_symmetrize(matrix)
    eigenvalues, vectors = np.linalg.eigh(symmetric)
    if eigenvalues[0] >= 0.0:
        return symmetric
    return old_symmetrize((vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T)


def old_horizontal_and_range(relative: np.ndarray) -> tuple[float, float]:
    """(rho, r) of a relative position, m, guarded: r >= MIN_RANGE and rho >= r cos(MAX_ELEVATION)."""
    dx, dy, dz = float(relative[0]), float(relative[1]), float(relative[2])
    rho = math.hypot(dx, dy)
    r = max(math.sqrt(rho * rho + dz * dz), MIN_RANGE)
    return max(rho, r * math.cos(MAX_ELEVATION)), r


def old_azimuth_elevation(relative: np.ndarray) -> np.ndarray:
    """[beta, eps], rad, of a relative position d (m, shape (3,)) in NED; shape (2,).

    beta = atan2(d_y, d_x), eps = atan2(-d_z, sqrt(d_x^2 + d_y^2)) (section VIII-B's
    azimuth/elevation measurement, elevation positive up). atan2 is finite everywhere.
    """
    dx, dy, dz = float(relative[0]), float(relative[1]), float(relative[2])
    return np.array([math.atan2(dy, dx), math.atan2(-dz, math.hypot(dx, dy))])


def old_azimuth_elevation_jacobian(relative: np.ndarray) -> np.ndarray:
    """d[beta, eps]/dd at d (m, shape (3,)); shape (2, 3), units 1/m.

    Standard form: dbeta/dd = [-d_y, d_x, 0]/rho^2, deps/dd = [d_z d_x/(r^2 rho),
    d_z d_y/(r^2 rho), -rho/r^2] (NED, so the sign of the z terms differs from an
    up-axis frame). rho and r are guarded (see `_horizontal_and_range`).
    """
    dx, dy, dz = float(relative[0]), float(relative[1]), float(relative[2])
    rho, r = old_horizontal_and_range(relative)
    rho2, r2 = rho * rho, r * r
    return np.array(
        [
            [-dy / rho2, dx / rho2, 0.0],
            [dz * dx / (r2 * rho), dz * dy / (r2 * rho), -rho / r2],
        ]
    )


def old_range_azimuth_elevation(relative: np.ndarray) -> np.ndarray:
    """[r, beta, eps] (m, rad, rad) of d = p_T - p, seed 003 eq. (2)-(3) in NED; shape (3,)."""
    angles = old_azimuth_elevation(relative)
    return np.array([float(np.linalg.norm(relative)), angles[0], angles[1]])


def old_range_azimuth_elevation_jacobian(relative: np.ndarray) -> np.ndarray:
    """H_rd of seed 003 (section 2.2) in NED, d[r, beta, eps]/dd; shape (3, 3).

    Range row d^T / r. Azimuth row [-d_y/rho^2, d_x/rho^2, 0]: the corrected row of the
    seed-003 erratum (the paper prints the divisor rho instead of rho^2). Elevation row as
    in `azimuth_elevation_jacobian` (NED: eps = atan2(-d_z, rho)).
    """
    _, r = old_horizontal_and_range(relative)
    return np.vstack([np.asarray(relative, float) / r, old_azimuth_elevation_jacobian(relative)])


def old_angle_noise_covariance(bearing_variance: float, relative: np.ndarray, pursuer_position_std: float) -> np.ndarray:
    """R of the [azimuth, elevation] measurement, rad^2, shape (2, 2) (module docstring).

    R = sigma^2 diag(1/cos^2(eps), 1) + sigma_p^2 J_d J_d^T: first-order mapping of the
    additive unit-vector noise of eq. (4) and of the own-position noise, at the
    (predicted) relative position d (m, shape (3,)); eps clipped to +-MAX_ELEVATION.
    """
    rho, r = old_horizontal_and_range(relative)
    cos_eps = rho / r
    r_matrix = np.diag([bearing_variance / (cos_eps * cos_eps), bearing_variance])
    if pursuer_position_std > 0.0:
        s2 = pursuer_position_std**2
        r_matrix = r_matrix + np.diag([s2 / (rho * rho), s2 / (r * r)])
    return r_matrix


def old_innovation_angle(direction: np.ndarray, relative: np.ndarray) -> float:
    """Angle, rad, between the unit measured bearing and the predicted line of sight d."""
    norm = float(np.linalg.norm(relative))
    if norm < MIN_RANGE:
        return 0.5 * math.pi
    return float(math.acos(min(1.0, max(-1.0, float(direction @ relative) / norm))))


def old_innovation_covariance(covariance: np.ndarray, h: np.ndarray, r: np.ndarray) -> np.ndarray:
    """S = H P H^T + R, shape (m, m), the covariance of the residual (reported, as in `_kalman_update`)."""
    return old_symmetrize(h @ covariance @ h.T + r)


def old_kalman_update(
    state: np.ndarray, covariance: np.ndarray, residual: np.ndarray, h: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """EKF measurement update (Table 1 of seed 003; standard textbook form), Joseph covariance.

    K = P H^T (H P H^T + R)^-1, x+ = x + K nu, P+ = (I - K H) P (I - K H)^T + K R K^T
    (the Joseph form keeps P+ symmetric PSD for any gain). Shapes: state (n,),
    covariance (n, n), residual (m,), h (m, n), r (m, m).
    """
    ph_t = covariance @ h.T
    innovation_covariance = old_symmetrize(h @ ph_t + r)
    gain = np.linalg.solve(innovation_covariance, ph_t.T).T
    i_kh = np.eye(state.size) - gain @ h
    updated = i_kh @ covariance @ i_kh.T + gain @ r @ gain.T
    return state + gain @ residual, old_symmetrize(updated)


def old_unit_and_partials(beta: float, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u(beta, eps) = [cos eps cos beta, cos eps sin beta, -sin eps] (NED, eps up) and du/dbeta, du/deps."""
    cb, sb, ce, se = math.cos(beta), math.sin(beta), math.cos(eps), math.sin(eps)
    u = np.array([ce * cb, ce * sb, -se])
    u_beta = np.array([-ce * sb, ce * cb, 0.0])
    u_eps = np.array([-se * cb, -se * sb, -ce])
    return u, u_beta, u_eps


def old_cartesian_from_msc(y: np.ndarray) -> np.ndarray:
    """Relative Cartesian [d, d_dot] (m, m/s; shape (6,)) from MSC y (shape (6,)).

    y = [beta, eps, w = 1/r, beta_dot, eps_dot, s = r_dot/r] (Stallard 1991 [23], the
    modified spherical coordinates of section II-A, with this module's NED angles).
    Standard form: d = u/w, d_dot = (s u + beta_dot du/dbeta + eps_dot du/deps)/w.
    w is floored at MIN_INVERSE_RANGE.
    """
    beta, eps, w, beta_dot, eps_dot, s = (float(value) for value in y)
    w = max(w, MIN_INVERSE_RANGE)
    u, u_beta, u_eps = old_unit_and_partials(beta, eps)
    return np.concatenate([u / w, (s * u + beta_dot * u_beta + eps_dot * u_eps) / w])


def old_msc_from_cartesian(relative_state: np.ndarray) -> np.ndarray:
    """MSC y = [beta, eps, 1/r, beta_dot, eps_dot, r_dot/r] from [d, d_dot] (shape (6,) each).

    Standard form (inverse of `cartesian_from_msc`): beta = atan2(d_y, d_x),
    eps = atan2(-d_z, rho), 1/r, beta_dot = (d_x v_y - d_y v_x)/rho^2,
    eps_dot = (-rho v_z + d_z rho_dot)/r^2 with rho_dot = (d_x v_x + d_y v_y)/rho,
    r_dot/r = d.v / r^2. Units rad, 1/m, rad/s, 1/s. rho and r guarded.
    """
    d = np.asarray(relative_state[:3], float)
    v = np.asarray(relative_state[3:], float)
    dx, dy, dz = float(d[0]), float(d[1]), float(d[2])
    vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
    rho, r = old_horizontal_and_range(d)
    r2 = r * r
    rho_dot = (dx * vx + dy * vy) / rho
    return np.array(
        [
            math.atan2(dy, dx),
            math.atan2(-dz, math.hypot(dx, dy)),
            min(1.0 / r, MAX_INVERSE_RANGE),
            (dx * vy - dy * vx) / (rho * rho),
            (-rho * vz + dz * rho_dot) / r2,
            (dx * vx + dy * vy + dz * vz) / r2,
        ]
    )


def old_cartesian_from_msc_jacobian(y: np.ndarray) -> np.ndarray:
    """d[d, d_dot]/dy of `cartesian_from_msc` (analytic); shape (6, 6).

    Columns: dd/dbeta = u_beta/w, dd/deps = u_eps/w, dd/dw = -d/w, and for the rate part
    d d_dot/dbeta = (s u_beta + beta_dot u_bb + eps_dot u_be)/w, d d_dot/deps =
    (s u_eps + beta_dot u_be - eps_dot u)/w (u_ee = -u), d d_dot/dw = -d_dot/w,
    d d_dot/d[beta_dot, eps_dot, s] = [u_beta, u_eps, u]/w.
    """
    beta, eps, w, beta_dot, eps_dot, s = (float(value) for value in y)
    w = max(w, MIN_INVERSE_RANGE)
    cb, sb, ce, se = math.cos(beta), math.sin(beta), math.cos(eps), math.sin(eps)
    u, u_beta, u_eps = old_unit_and_partials(beta, eps)
    u_bb = np.array([-ce * cb, -ce * sb, 0.0])
    u_be = np.array([se * sb, -se * cb, 0.0])
    d = u / w
    d_dot = (s * u + beta_dot * u_beta + eps_dot * u_eps) / w
    jacobian = np.zeros((6, 6))
    jacobian[:3, 0] = u_beta / w
    jacobian[:3, 1] = u_eps / w
    jacobian[:3, 2] = -d / w
    jacobian[3:, 0] = (s * u_beta + beta_dot * u_bb + eps_dot * u_be) / w
    jacobian[3:, 1] = (s * u_eps + beta_dot * u_be - eps_dot * u) / w
    jacobian[3:, 2] = -d_dot / w
    jacobian[3:, 3] = u_beta / w
    jacobian[3:, 4] = u_eps / w
    jacobian[3:, 5] = u / w
    return jacobian


def old_msc_from_cartesian_jacobian(relative_state: np.ndarray) -> np.ndarray:
    """dy/d[d, d_dot] of `msc_from_cartesian` (analytic); shape (6, 6).

    Derivatives of the standard forms in `msc_from_cartesian` (rho, r guarded), with
    N = -rho v_z + d_z q/rho, q = d_x v_x + d_y v_y, eps_dot = N/r^2.
    """
    dx, dy, dz, vx, vy, vz = (float(value) for value in relative_state)
    d = np.array([dx, dy, dz])
    v = np.array([vx, vy, vz])
    rho, r = old_horizontal_and_range(d)
    rho2, r2 = rho * rho, r * r
    r4 = r2 * r2
    q = dx * vx + dy * vy
    jacobian = np.zeros((6, 6))
    jacobian[:2, :3] = old_azimuth_elevation_jacobian(d)
    jacobian[2, :3] = -d / (r2 * r)
    # beta_dot = c / rho^2, c = dx vy - dy vx
    c = dx * vy - dy * vx
    jacobian[3, :3] = [vy / rho2 - 2.0 * dx * c / (rho2 * rho2), -vx / rho2 - 2.0 * dy * c / (rho2 * rho2), 0.0]
    jacobian[3, 3:] = [-dy / rho2, dx / rho2, 0.0]
    # eps_dot = N / r^2
    n = -rho * vz + dz * q / rho
    rho3 = rho2 * rho
    dn_dd = np.array(
        [
            -dx / rho * vz + dz * (vx / rho - q * dx / rho3),
            -dy / rho * vz + dz * (vy / rho - q * dy / rho3),
            q / rho,
        ]
    )
    dn_dv = np.array([dz * dx / rho, dz * dy / rho, -rho])
    jacobian[4, :3] = dn_dd / r2 - 2.0 * n * d / r4
    jacobian[4, 3:] = dn_dv / r2
    # s = d.v / r^2
    jacobian[5, :3] = v / r2 - 2.0 * float(d @ v) * d / r4
    jacobian[5, 3:] = d / r2
    return jacobian


def old_flight_path_velocity(speed: float, gamma: float, chi: float) -> np.ndarray:
    """NED velocity of seed 003 eq. (10): v [cos g cos chi, cos g sin chi, -sin g]; m/s, shape (3,).

    gamma positive climbing. The paper's frame has z up (z' = v sin g); in NED z is down,
    hence the minus sign on the third component.
    """
    cg, sg, cc, sc = math.cos(gamma), math.sin(gamma), math.cos(chi), math.sin(chi)
    return speed * np.array([cg * cc, cg * sc, -sg])


def old_flight_path_velocity_jacobian(speed: float, gamma: float, chi: float) -> np.ndarray:
    """d velocity / d(v, gamma, chi) of `flight_path_velocity`: F_rd1 of seed 003 in NED; shape (3, 3)."""
    cg, sg, cc, sc = math.cos(gamma), math.sin(gamma), math.cos(chi), math.sin(chi)
    return np.array(
        [
            [cg * cc, -speed * sg * cc, -speed * cg * sc],
            [cg * sc, -speed * sg * sc, speed * cg * cc],
            [-sg, -speed * cg, 0.0],
        ]
    )


def old_flight_path_step(state: np.ndarray, dt: float) -> np.ndarray:
    """Mean of seed 003 eq. (9)-(10) over dt (s) with no commands: exact integral; shape (6,).

    With v, gamma, chi constant (white-noise driven, zero mean) the position moves on a
    straight line: p(t + dt) = p + dt * velocity(v, gamma, chi).
    """
    stepped = np.array(state, dtype=float)
    stepped[:3] += dt * old_flight_path_velocity(stepped[3], stepped[4], stepped[5])
    return stepped


def old_flight_path_step_jacobian(state: np.ndarray, dt: float) -> np.ndarray:
    """Exact Jacobian of `flight_path_step`: I + F_r dt, F_r = [[0, F_rd1], [0, 0]]; shape (6, 6).

    F_r is the state Jacobian of seed 003 section 2.2 without the v^c - v term (no
    commands), in NED. Because the discrete map is linear in dt, I + F_r dt is exact.
    """
    jacobian = np.eye(6)
    jacobian[:3, 3:] = dt * old_flight_path_velocity_jacobian(state[3], state[4], state[5])
    return jacobian


def old_linear_predict(a, q_discrete, state, covariance):
    """AzElEKF.predict (and MSCEKF.predict without a reference)."""
    return a @ state, old_symmetrize(a @ covariance @ a.T + q_discrete)


def old_az_el_correct(state, covariance, lead, pursuer_position, direction, restart_when_behind, bearing_variance,
                      pursuer_position_std):
    """AzElEKF.correct after _measured_direction (the restart returns its innovation angle and range)."""
    relative = state[:3] + lead * state[3:] - np.asarray(pursuer_position, float)
    innovation_angle = old_innovation_angle(direction, relative)
    predicted_range = float(np.linalg.norm(relative))
    if restart_when_behind and (float(direction @ relative) <= 0.0 or predicted_range < 1e-6):
        return True, innovation_angle, predicted_range
    residual = old_azimuth_elevation(direction) - old_azimuth_elevation(relative)
    residual = np.array([old_wrap_angle(residual[0]), old_wrap_angle(residual[1])])
    jacobian = old_azimuth_elevation_jacobian(relative)
    h = np.hstack([jacobian, lead * jacobian])
    r = old_angle_noise_covariance(bearing_variance, relative, pursuer_position_std)
    innovation_covariance = old_innovation_covariance(covariance, h, r)
    state, covariance = old_kalman_update(state, covariance, residual, h, r)
    state[:3] = limit_range(state[:3], np.asarray(pursuer_position, dtype=float))
    return False, innovation_angle, predicted_range, residual, innovation_covariance, state, covariance


def old_guard(y):
    """MSCEKF._guard."""
    guarded = y.copy()
    guarded[0] = old_wrap_angle(guarded[0])
    guarded[1] = min(MAX_ELEVATION, max(-MAX_ELEVATION, float(guarded[1])))
    guarded[2] = min(MAX_INVERSE_RANGE, max(MIN_INVERSE_RANGE, float(guarded[2])))
    return guarded


def old_msc_propagate(state, covariance, a, q_discrete):
    """MSCEKF._propagate."""
    moved = a @ old_cartesian_from_msc(state)
    j_c = a @ old_cartesian_from_msc_jacobian(state)
    j_m = old_msc_from_cartesian_jacobian(moved)
    cartesian_covariance = j_c @ covariance @ j_c.T + q_discrete
    return old_guard(old_msc_from_cartesian(moved)), old_symmetric_psd(j_m @ cartesian_covariance @ j_m.T)


def old_msc_set_cartesian(cartesian, covariance, reference):
    """MSCEKF._set_cartesian with a reference: (y, P_y)."""
    reference = np.asarray(reference, float).reshape(3).copy()
    relative_state = cartesian.copy()
    relative_state[:3] -= reference
    j_m = old_msc_from_cartesian_jacobian(relative_state)
    return old_guard(old_msc_from_cartesian(relative_state)), old_symmetric_psd(j_m @ covariance @ j_m.T)


def old_msc_cartesian(state, covariance, reference):
    """MSCEKF._cartesian (reference None: the Cartesian state as it is)."""
    if reference is None:
        return state.copy(), covariance.copy()
    relative_state = old_cartesian_from_msc(state)
    j_c = old_cartesian_from_msc_jacobian(state)
    relative_state[:3] += reference
    return relative_state, old_symmetric_psd(j_c @ covariance @ j_c.T)


def old_msc_correct(state, covariance, reference, pursuer_position, lead, direction, restart_when_behind, bearing_variance,
                    pursuer_position_std):
    """MSCEKF.correct after _require_state (the restart returns the re-referenced prior, angle, range, velocity)."""
    pursuer = np.asarray(pursuer_position, float)
    cartesian, cartesian_covariance = old_msc_cartesian(state, covariance, reference)
    state, covariance = old_msc_set_cartesian(cartesian, cartesian_covariance, pursuer)
    if lead == 0.0:
        relative_state = old_cartesian_from_msc(state)
        predicted = state[:2]
        h = np.hstack([np.eye(2), np.zeros((2, 4))])
    else:
        a_lead, _ = transition_matrices(lead)
        relative_state = a_lead @ old_cartesian_from_msc(state)
        predicted = old_msc_from_cartesian(relative_state)[:2]
        h = (old_msc_from_cartesian_jacobian(relative_state)[:2] @ a_lead) @ old_cartesian_from_msc_jacobian(state)
    relative = relative_state[:3]
    innovation_angle = old_innovation_angle(direction, relative)
    predicted_range = float(np.linalg.norm(relative))
    if restart_when_behind and (float(direction @ relative) <= 0.0 or predicted_range < 1e-6):
        return state, covariance, True, innovation_angle, predicted_range, relative_state[3:].copy()
    residual = old_azimuth_elevation(direction) - predicted
    residual = np.array([old_wrap_angle(residual[0]), old_wrap_angle(residual[1])])
    r = old_angle_noise_covariance(bearing_variance, relative, pursuer_position_std)
    innovation_covariance = old_innovation_covariance(covariance, h, r)
    updated, updated_covariance = old_kalman_update(state, covariance, residual, h, r)
    return (state, covariance, False, innovation_angle, predicted_range, residual, innovation_covariance,
            old_guard(updated), updated_covariance)


def old_flight_path_predict(state, covariance, period, q_discrete):
    """RangeAzElEKF.predict."""
    f = old_flight_path_step_jacobian(state, period)
    return old_flight_path_step(state, period), old_symmetrize(f @ covariance @ f.T + q_discrete)


def old_fold(state, covariance):
    """RangeAzElEKF._fold."""
    state = state.copy()
    if state[3] < 0.0:
        state[3], state[4], state[5] = -state[3], -state[4], state[5] + math.pi
        flip = np.diag([1.0, 1.0, 1.0, -1.0, -1.0, 1.0])
        covariance = flip @ covariance @ flip
    state[4] = old_wrap_angle(state[4])
    state[5] = old_wrap_angle(state[5])
    return state, covariance


def old_range_az_el_correct(state, covariance, lead, pursuer_position, direction, measured_range, range_noise_std,
                            bearing_variance, pursuer_position_std):
    """RangeAzElEKF.correct after _require_state."""
    relative = old_flight_path_step(state, lead)[:3] - np.asarray(pursuer_position, float)
    innovation_angle = old_innovation_angle(direction, relative)
    angles = old_azimuth_elevation(direction)
    measured = np.array([float(measured_range), angles[0], angles[1]])
    residual = measured - old_range_azimuth_elevation(relative)
    residual[1] = old_wrap_angle(residual[1])
    residual[2] = old_wrap_angle(residual[2])
    h_d = old_range_azimuth_elevation_jacobian(relative)
    h = np.hstack([h_d, lead * (h_d @ old_flight_path_velocity_jacobian(state[3], state[4], state[5]))])
    rho, r = old_horizontal_and_range(relative)
    cos_eps = rho / r
    r_matrix = np.diag([range_noise_std**2, bearing_variance / cos_eps**2, bearing_variance])
    if pursuer_position_std > 0.0:
        r_matrix = r_matrix + pursuer_position_std**2 * (h_d @ h_d.T)
    innovation_covariance = old_innovation_covariance(covariance, h, r_matrix)
    updated, updated_covariance = old_kalman_update(state, covariance, residual, h, r_matrix)
    updated, updated_covariance = old_fold(updated, updated_covariance)
    return innovation_angle, residual, innovation_covariance, updated, updated_covariance


def old_flight_path_cartesian(state, covariance):
    """RangeAzElEKF._cartesian."""
    transform = np.eye(6)
    transform[3:, 3:] = old_flight_path_velocity_jacobian(state[3], state[4], state[5])
    cartesian = np.concatenate([state[:3], old_flight_path_velocity(state[3], state[4], state[5])])
    return cartesian, old_symmetrize(transform @ covariance @ transform.T)


# --- what numba compiles differently from Python: the twins, the C library, LAPACK --------------------------------


@_jit.jit
def _compiled_scalars(x: np.ndarray, y: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Row by row: cos x, sin x, atan2(x, y), acos c, _jit.hypot(x, y), _jit.remainder(x, 2 pi), sqrt |x|."""
    out = np.empty((7, x.size))
    for i in range(x.size):
        out[0, i] = math.cos(x[i])
        out[1, i] = math.sin(x[i])
        out[2, i] = math.atan2(x[i], y[i])
        out[3, i] = math.acos(c[i])
        out[4, i] = _jit.hypot(x[i], y[i])
        out[5, i] = _jit.remainder(x[i], 2.0 * math.pi)
        out[6, i] = math.sqrt(abs(x[i]))
    return out


def _python_scalars(x: np.ndarray, y: np.ndarray, c: np.ndarray) -> np.ndarray:
    """_compiled_scalars with Python's own math functions."""
    return np.array([[math.cos(a) for a in x], [math.sin(a) for a in x], [math.atan2(a, b) for a, b in zip(x, y)],
                     [math.acos(a) for a in c], [math.hypot(a, b) for a, b in zip(x, y)],
                     [math.remainder(a, 2.0 * math.pi) for a in x], [math.sqrt(abs(a)) for a in x]])


@pytest.mark.parametrize("scale", [1e-310, 1e-8, 1.0, 10.0, 1e4, 1e150])
def test_scalar_functions_are_pythons(scale):
    """The transcendentals numba compiles to the C library (cos, sin, atan2, acos: the functions CPython calls) and
    the twins for the two CPython computes itself (hypot, remainder) on 3 x 40,000 random arguments per scale,
    second arguments from 1e-200 to 1e3 times the first (subnormals at the smallest scale)."""
    rng = np.random.default_rng(int(-math.log10(scale) * 7) % 1000)
    count = 40_000
    for ratio in (1e-200, 1e-3, 1.0, 1e3):
        x = rng.normal(size=count) * scale
        y = rng.normal(size=count) * scale * ratio
        c = rng.uniform(-1.0, 1.0, count)
        assert_same(_compiled_scalars(x, y, c), _python_scalars(x, y, c), f"ratio {ratio}")


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, math.pi, -math.pi, 5e-324])),
       st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 2.0 * math.pi, 5e-324])))
def test_hypot_and_remainder_twins_everywhere(x, y):
    """Any floats, infinities, NaN, zeros of either sign and subnormals: the values of math.hypot and math.remainder,
    and math.remainder's ValueError where it raises one (an infinite x, a zero y)."""
    compiled_hypot = _compiled_twins(x, y, True)
    assert_same(compiled_hypot, math.hypot(x, y))
    try:
        expected = math.remainder(x, y)
    except ValueError:
        with pytest.raises(ValueError):
            _compiled_twins(x, y, False)
    else:
        assert_same(_compiled_twins(x, y, False), expected)


@_jit.jit
def _compiled_twins(x: float, y: float, use_hypot: bool) -> float:
    return _jit.hypot(x, y) if use_hypot else _jit.remainder(x, y)


@_jit.jit
def _compiled_eigh(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.linalg.eigh(matrix)


@_jit.jit
def _compiled_solve(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    return np.linalg.solve(matrix, rhs)


@settings(max_examples=300, deadline=None)
@given(seeds, st.lists(floats(-1.0, 1.0), min_size=6, max_size=6), st.integers(-8, 8),
       st.sampled_from(["any", "psd_singular", "tiny_negative"]))
def test_lapack_eigh_is_numpys(seed, values, exponent, kind):
    """numba's np.linalg.eigh (dsyevd through scipy's LAPACK) gives numpy's eigenvalues and vectors, the values
    that decide and build `_symmetric_psd`."""
    matrix = symmetric_with_eigenvalues(seed, np.array(values), exponent, kind)
    compiled, interpreted = _compiled_eigh(matrix), np.linalg.eigh(matrix)
    assert_same(tuple(np.asarray(a) for a in compiled), tuple(np.asarray(a) for a in interpreted))


@settings(max_examples=300, deadline=None)
@given(seeds, st.sampled_from([2, 3]), st.integers(-8, 8))
def test_lapack_solve_is_numpys(seed, size, exponent):
    """numba's np.linalg.solve (dgesv) gives numpy's solution: the gain of `_kalman_update`."""
    rng = np.random.default_rng(seed)
    matrix = covariance(seed, size, exponent)
    rhs = rng.normal(size=(6, size)).T * 10.0 ** (exponent / 2)
    assert_same(_compiled_solve(matrix, rhs), np.linalg.solve(matrix, rhs))


# --- the helpers -----------------------------------------------------------------------------------------------------


def relative_positions() -> st.SearchStrategy[np.ndarray]:
    """Relative positions, m, from 1e-9 to 1e7 m, near and on the poles (zero horizontal part) and zero itself."""
    return st.one_of(
        st.tuples(st.lists(floats(-1.0, 1.0), min_size=3, max_size=3), st.integers(-9, 7)).map(
            lambda t: np.array(t[0]) * 10.0 ** t[1]),
        st.tuples(floats(-1e-6, 1e-6), floats(-1e-6, 1e-6), floats(-1e3, 1e3)).map(np.array),
        st.just(np.zeros(3)), st.just(np.array([0.0, 0.0, -5.0])))


@settings(max_examples=300, deadline=None)
@given(relative_positions(), unit_vectors(), floats(1e-8, 1e-1), st.sampled_from([0.0, 0.1, 3.0]),
       st.one_of(floats(-1e3, 1e3), st.sampled_from([math.pi, -math.pi, 3.0 * math.pi, 0.0, -0.0])))
def test_angle_helpers(relative, direction, bearing_variance, pursuer_position_std, angle):
    agree(be.wrap_angle, old_wrap_angle, angle)
    agree(be._horizontal_and_range, old_horizontal_and_range, relative)
    agree(be.azimuth_elevation, old_azimuth_elevation, relative)
    agree(be.azimuth_elevation_jacobian, old_azimuth_elevation_jacobian, relative)
    agree(be.range_azimuth_elevation, old_range_azimuth_elevation, relative)
    agree(be.range_azimuth_elevation_jacobian, old_range_azimuth_elevation_jacobian, relative)
    agree(be.angle_noise_covariance, old_angle_noise_covariance, bearing_variance, relative, pursuer_position_std)
    agree(be._innovation_angle, old_innovation_angle, direction, relative)


def msc_states() -> st.SearchStrategy[np.ndarray]:
    """MSC states y: angles anywhere (beyond +-pi, at the poles), 1/r from below the floor to above the ceiling."""
    return st.tuples(floats(-10.0, 10.0), floats(-2.0, 2.0), st.sampled_from([1e-9, 1e-6, 1e-3, 0.02, 1.0, 1e3, 1e4]),
                     floats(-2.0, 2.0), floats(-2.0, 2.0), floats(-3.0, 3.0)).map(np.array)


def relative_states() -> st.SearchStrategy[np.ndarray]:
    return st.tuples(relative_positions(), st.lists(floats(-30.0, 30.0), min_size=3, max_size=3)).map(
        lambda t: np.concatenate([t[0], t[1]]))


@settings(max_examples=300, deadline=None)
@given(msc_states(), relative_states())
def test_msc_transforms(y, relative_state):
    agree(be._unit_and_partials, old_unit_and_partials, float(y[0]), float(y[1]))
    agree(be.cartesian_from_msc, old_cartesian_from_msc, y)
    agree(be.cartesian_from_msc_jacobian, old_cartesian_from_msc_jacobian, y)
    agree(be.msc_from_cartesian, old_msc_from_cartesian, relative_state)
    agree(be.msc_from_cartesian_jacobian, old_msc_from_cartesian_jacobian, relative_state)
    agree(be._msc_guard, old_guard, y)


def flight_path_states() -> st.SearchStrategy[np.ndarray]:
    """[x, y, z, v, gamma, chi] with negative speeds (the fold) and angles beyond +-pi."""
    return st.tuples(st.lists(floats(-500.0, 500.0), min_size=3, max_size=3), floats(-20.0, 20.0), floats(-4.0, 4.0),
                     floats(-10.0, 10.0)).map(lambda t: np.array([*t[0], t[1], t[2], t[3]]))


@settings(max_examples=300, deadline=None)
@given(flight_path_states(), floats(-0.5, 0.5), seeds, st.integers(-4, 4))
def test_flight_path_helpers_and_updates(state, dt, seed, exponent):
    prior = covariance(seed, 6, exponent)
    agree(be.flight_path_velocity, old_flight_path_velocity, float(state[3]), float(state[4]), float(state[5]))
    agree(be.flight_path_velocity_jacobian, old_flight_path_velocity_jacobian, float(state[3]), float(state[4]),
          float(state[5]))
    agree(be.flight_path_step, old_flight_path_step, state, dt)
    agree(be.flight_path_step_jacobian, old_flight_path_step_jacobian, state, dt)
    agree(be._fold_flight_path, old_fold, state, prior)
    agree(be._flight_path_to_cartesian, old_flight_path_cartesian, state, prior)
    noise = np.zeros((6, 6))
    noise[3:, 3:] = be.SEED003_PROCESS_NOISE * 0.02
    agree(be._flight_path_predict, old_flight_path_predict, state, prior, 0.02, noise)


@settings(max_examples=300, deadline=None)
@given(seeds, st.lists(floats(-1.0, 1.0), min_size=6, max_size=6), st.integers(-8, 8),
       st.sampled_from(["any", "psd_singular", "tiny_negative"]), floats(0.0, 1e-3))
def test_symmetric_psd_both_branches(seed, values, exponent, kind, asymmetry):
    """Symmetric inputs with negative eigenvalues (the repair), PSD ones (returned as they are), and slightly
    asymmetric ones (as a congruence leaves them)."""
    matrix = symmetric_with_eigenvalues(seed, np.array(values), exponent, kind)
    matrix = matrix + asymmetry * np.triu(matrix, 1)
    agree(be._symmetrize, old_symmetrize, matrix)
    agree(be._symmetric_psd, old_symmetric_psd, matrix)


@settings(max_examples=300, deadline=None)
@given(seeds, st.sampled_from([2, 3]), st.integers(-6, 8), st.integers(-8, 0))
def test_kalman_update_and_innovation_covariance(seed, size, exponent, noise_exponent):
    rng = np.random.default_rng(seed)
    state = rng.normal(size=6) * 30.0
    prior = covariance(seed, 6, exponent)
    h = rng.normal(size=(size, 6)) * 10.0 ** rng.integers(-3, 2, size=(size, 1))
    r = covariance(seed + 1, size, noise_exponent)
    residual = rng.normal(size=size) * 10.0**noise_exponent
    agree(be._innovation_covariance, old_innovation_covariance, prior, h, r)
    agree(be._kalman_update, old_kalman_update, state, prior, residual, h, r)


@settings(max_examples=200, deadline=None)
@given(seeds, st.integers(-4, 8), st.sampled_from([0.02, 0.2]))
def test_linear_predict(seed, exponent, period):
    a, b = transition_matrices(period)
    noise = b @ (0.04 * np.eye(3)) @ b.T
    state = np.random.default_rng(seed).normal(size=6) * 30.0
    agree(be._linear_predict, old_linear_predict, a, noise, state, covariance(seed, 6, exponent))


# --- the updates -----------------------------------------------------------------------------------------------------


def bearing_geometry(seed: int, distance: float, noise: float, behind: bool):
    """(target state [p_T, v_T], pursuer position, unit measured bearing) at `distance` m, the bearing `noise` rad off
    (behind: the bearing points away from the target)."""
    rng = np.random.default_rng(seed)
    pursuer = rng.normal(size=3) * 5.0
    line = rng.normal(size=3)
    line /= np.linalg.norm(line)
    state = np.concatenate([pursuer + distance * line, rng.normal(size=3) * 3.0])
    direction = (-line if behind else line) + rng.normal(size=3) * noise
    return state, pursuer, direction / np.linalg.norm(direction)


leads = st.one_of(st.just(0.0), st.just(1.7763568394002505e-15), floats(-0.3, 0.3))


@settings(max_examples=300, deadline=None)
@given(seeds, st.sampled_from([1e-7, 0.5, 40.0, 2e6]), st.sampled_from([0.0, 0.01, 1.0]), st.booleans(), st.booleans(),
       leads, st.integers(-3, 6), st.sampled_from([0.0, 0.1]))
def test_az_el_correct(seed, distance, noise, behind, restart_when_behind, lead, exponent, pursuer_position_std):
    state, pursuer, direction = bearing_geometry(seed, distance, noise, behind)
    arguments = (state, covariance(seed, 6, exponent), lead, pursuer, direction, restart_when_behind, 1e-4,
                 pursuer_position_std)
    expected = old_az_el_correct(*copies(arguments))
    for kernel in (be._az_el_correct, python(be._az_el_correct)):
        result = kernel(*copies(arguments))
        assert_same(result if not expected[0] else result[:3], expected)


@settings(max_examples=300, deadline=None)
@given(msc_states(), seeds, st.integers(-6, 4), st.sampled_from([0.02, 0.2]))
def test_msc_propagate_and_transforms_of_the_covariance(y, seed, exponent, period):
    """Far out (1/r at the floor) the congruences leave negative eigenvalues that `_symmetric_psd` repairs."""
    a, b = transition_matrices(period)
    noise = b @ (0.04 * np.eye(3)) @ b.T
    prior = covariance(seed, 6, exponent)
    reference = np.random.default_rng(seed).normal(size=3) * 10.0
    agree(be._msc_propagate, old_msc_propagate, y, prior, a, noise)
    agree(be._msc_to_absolute, old_msc_cartesian, y, prior, reference)
    cartesian = old_cartesian_from_msc(y)
    agree(be._msc_from_absolute, old_msc_set_cartesian, cartesian, prior, reference)


@settings(max_examples=300, deadline=None)
@given(seeds, st.sampled_from([1e-7, 0.5, 40.0, 2e6]), st.sampled_from([0.0, 0.01, 1.0]), st.booleans(), st.booleans(),
       leads, st.integers(-3, 4), st.sampled_from([0.0, 0.1]), st.booleans())
def test_msc_correct(seed, distance, noise, behind, restart_when_behind, lead, exponent, pursuer_position_std, referenced):
    """Re-referencing from a Cartesian start or from the last pursuer position, on the tick or lead s off it."""
    target, pursuer, direction = bearing_geometry(seed, distance, noise, behind)
    prior = covariance(seed, 6, exponent)
    if referenced:
        reference = pursuer + np.random.default_rng(seed + 1).normal(size=3) * 2.0
        state, prior = old_msc_set_cartesian(target, prior, reference)
    else:
        reference, state = None, target
    a_lead = transition_matrices(0.02)[0] if lead == 0.0 else transition_matrices(lead)[0]
    expected = old_msc_correct(*copies((state, prior, reference, pursuer, lead, direction, restart_when_behind, 1e-4,
                                        pursuer_position_std)))
    arguments = (state, prior, referenced, pursuer if reference is None else reference, pursuer, lead, a_lead, direction,
                 restart_when_behind, 1e-4, pursuer_position_std)
    for kernel in (be._msc_correct, python(be._msc_correct)):
        result = kernel(*copies(arguments))
        if expected[2]:  # restarted: the re-referenced prior, the angle, the range and the velocity at the bearing
            assert_same(result[:5] + (result[5][3:],), expected)
        else:
            assert_same(result[:5] + result[6:], expected)


@settings(max_examples=300, deadline=None)
@given(flight_path_states(), seeds, st.sampled_from([1e-7, 0.5, 40.0, 2e6]), st.sampled_from([0.0, 0.01, 1.0]),
       st.booleans(), leads, st.integers(-3, 4), st.sampled_from([0.0, 0.1]), floats(0.0, 100.0))
def test_range_az_el_correct(state, seed, distance, noise, behind, lead, exponent, pursuer_position_std, measured_range):
    target, pursuer, direction = bearing_geometry(seed, distance, noise, behind)
    state = state.copy()
    state[:3] = target[:3]
    agree(be._range_az_el_correct, old_range_az_el_correct, state, covariance(seed, 6, exponent), lead, pursuer,
          direction, measured_range, 1.0, 1e-4, pursuer_position_std)


# --- whole flights ---------------------------------------------------------------------------------------------------

_FLIGHTS = """
import sys
import numpy as np
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies.closed_loop import simulate
from studies.montecarlo import ESTIMATORS, GUIDANCE, PAPER_INITIAL_BOX, PAPER_SYSTEM, drawn_initial_position, with_overrides

def flight(estimator):
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    flown = with_overrides(scenario, {**PAPER_SYSTEM, **ESTIMATORS[estimator], **GUIDANCE["hng"], "sensor.rate_hz": 50.0,
                                      "simulation.duration": 20.0, "simulation.summary_window": 10.0,
                                      "estimator.initialize": "position",
                                      "estimator.initial_position": drawn_initial_position(2, PAPER_INITIAL_BOX)})
    return simulate(flown, vehicle, seed=2).series

if __name__ == "__main__":
    for estimator in ("ekf", "msc_ekf", "ekf_rae"):
        np.savez(sys.argv[1] + estimator + ".npz", **flight(estimator))
"""


def test_baseline_flights_are_the_same_compiled_and_interpreted(tmp_path):
    """The estimator study's flights of the three baselines (constant_velocity, HNG, 50 Hz bearings, the initial
    estimate of seed 2, 20 s): every logged series flown here (compiled when numba is installed) equals the one a
    BOF_NO_JIT=1 interpreter flies."""
    namespace: dict = {}
    exec(compile(_FLIGHTS, "flights", "exec"), namespace)
    prefix = str(tmp_path / "interpreted_")
    environment = dict(os.environ, BOF_NO_JIT="1", PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    subprocess.run([sys.executable, "-c", _FLIGHTS, prefix], check=True, cwd=ROOT, env=environment, timeout=900)
    for estimator in ("ekf", "msc_ekf", "ekf_rae"):
        here = namespace["flight"](estimator)
        there = np.load(prefix + estimator + ".npz")
        assert sorted(there.files) == sorted(here)
        for name in here:
            assert_same(here[name], there[name], f"{estimator} {name}")


_WARM_UP_THEN_FLY = _FLIGHTS.replace('if __name__ == "__main__":', '''def compiled_signatures():
    from companion.core import baseline_estimators
    return {name: len(getattr(baseline_estimators, name).signatures) for name in dir(baseline_estimators)
            if hasattr(getattr(baseline_estimators, name), "signatures")}

if __name__ == "__main__":
    from companion import warmup
    warmup.warm_up()
    before = compiled_signatures()
    for estimator in ("ekf", "msc_ekf", "ekf_rae"):
        flight(estimator)
    print(before == compiled_signatures(), sum(before.values()))
    sys.exit(0)''')


def test_warm_up_compiles_every_kernel_a_baseline_flight_calls():
    """In a fresh interpreter, after warmup.warm_up(), flights of the three baselines compile nothing more. (Without
    numba the kernels are their Python functions, and warm_up has nothing to do.)"""
    if not _jit.ENABLED:
        for kernel in (be._linear_predict, be._az_el_correct, be._msc_propagate, be._msc_correct, be._msc_to_absolute,
                       be._flight_path_predict, be._range_az_el_correct, be._flight_path_to_cartesian):
            assert python(kernel) is kernel and not hasattr(kernel, "signatures")
        return
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    output = subprocess.run([sys.executable, "-c", _WARM_UP_THEN_FLY, "unused"], check=True, cwd=ROOT, env=environment,
                            timeout=900, capture_output=True, text=True).stdout.split()
    assert output[0] == "True" and int(output[1]) >= 10
