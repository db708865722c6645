"""Small geometric helpers shared by the estimator, guidance and attitude mapping.

All vectors are numpy arrays of shape (3,) in the local NED frame unless stated.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core._jit import jit

E_X = np.array([1.0, 0.0, 0.0])
E_Y = np.array([0.0, 1.0, 0.0])
E_Z = np.array([0.0, 0.0, 1.0])


def unit(vector: np.ndarray) -> np.ndarray:
    """Return vector / |vector|; raises ValueError on a zero or non-finite vector."""
    norm = math.sqrt(float(vector @ vector))
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"cannot normalise vector {vector!r}")
    return vector / norm


def orthogonal_projection(g: np.ndarray) -> np.ndarray:
    """Orthogonal projector onto the plane perpendicular to g, eq. (5).

    P_g = I - g g^T / |g|^2; P_g is symmetric, idempotent and ker(P_g) = span(g).
    g: any nonzero vector, shape (3,). Returns shape (3, 3).
    """
    g_unit = unit(np.asarray(g, dtype=float))
    return np.eye(3) - np.outer(g_unit, g_unit)


def unit_finite(vector: np.ndarray) -> np.ndarray:
    """unit()'s arithmetic (vector / sqrt(vector @ vector)) as a kernel for the compiled setpoint path; raises
    ValueError on a zero or non-finite vector (a fixed message: numba formats no arrays). float64 (3,)."""
    norm = math.sqrt(vector @ vector)
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError("cannot normalise a zero or non-finite vector")
    return vector / norm


def all_finite(vector: np.ndarray) -> bool:
    """np.all(np.isfinite(vector)) of a float array, as a bool, without numpy's per-call cost (a Python loop
    over its values: cheaper for the few numbers of a position or velocity)."""
    return all(map(math.isfinite, vector.ravel().tolist()))


def norm(vector: np.ndarray) -> float:
    """|vector| of a float vector as np.linalg.norm computes it (sqrt(vector . vector)), without its per-call
    cost (~2 us): the same dot and the same correctly rounded square root, the same bits."""
    vector = np.asarray(vector, dtype=float)
    return math.sqrt(vector @ vector)


def clip(value: float, low: float, high: float) -> float:
    """np.clip(value, low, high) of a float (minimum(maximum(value, low), high), a NaN value stays NaN), without
    numpy's per-call cost; numba's np.clip takes no scalars."""
    raised = low if value < low else value
    return high if raised > high else raised


def skew(vector: np.ndarray) -> np.ndarray:
    """[x]_x such that skew(x) @ y == cross(x, y); shape (3, 3)."""
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for two 3-vectors (np.cross costs ~20x more on shape (3,) inputs)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _rotation_from_unit_x_axis_to(lam: np.ndarray) -> np.ndarray:
    """rotation_from_x_axis_to's arithmetic after normalisation: lam is the unit line of sight, float64 (3,)."""
    axis = cross_kernel(E_X, lam)
    sin_theta = math.sqrt(axis @ axis)
    cos_theta = min(1.0, max(-1.0, lam[0]))
    if sin_theta < 1e-12:
        return np.eye(3) if cos_theta > 0.0 else rodrigues_kernel(E_Z, math.pi)
    return rodrigues_kernel(axis / sin_theta, math.atan2(sin_theta, cos_theta))


def rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """R = I + sin(theta) [eta]_x + (1 - cos(theta)) [eta]_x^2 (section VI-A), for a unit axis eta; (3, 3)."""
    k = skew_kernel(axis)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def rotation_from_x_axis_to(direction: np.ndarray) -> np.ndarray:
    """R_eta(theta_eta) of section VI-A: the rotation that maps e_X onto `direction`.

    eta = e_X x lambda and theta_eta = acos(lambda^T e_X). The paper's Rodrigues
    formula needs the *unit* axis eta/|eta| (|e_X x lambda| = sin(theta_eta)). For
    lambda = -e_X the axis is undefined; any half turn about an axis perpendicular to
    e_X is valid and e_Z is used. direction: shape (3,), need not be unit. Returns (3, 3).
    """
    return rotation_from_unit_x_axis_to(unit(np.asarray(direction, dtype=float)))


# The same functions compiled (or themselves without numba), for the compiled setpoint kernels
# (companion.core.attitude, companion.core.guidance); Python callers keep the plain functions above.
unit_kernel = jit(unit_finite)
clip_kernel = jit(clip)
skew_kernel = jit(skew)
cross_kernel = jit(cross)
rodrigues_kernel = jit(rodrigues)
rotation_from_unit_x_axis_to = jit(_rotation_from_unit_x_axis_to)


def rotation_about_z(angle: float) -> np.ndarray:
    """R_Z(alpha): rotation by `angle` rad about the z axis, shape (3, 3)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_about_y(angle: float) -> np.ndarray:
    """R_Y(alpha): rotation by `angle` rad about the y axis, shape (3, 3)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


rotation_about_z_kernel = jit(rotation_about_z)
rotation_about_y_kernel = jit(rotation_about_y)


def relative_range_std(relative_position: np.ndarray, position_covariance: np.ndarray) -> float:
    """Relative range uncertainty rho = sigma_r / r^, sigma_r^2 = lambda^T P_pp lambda, lambda = dp / |dp|
    (the range excitation and the health monitor both read it).

    relative_position: dp = p^_T - p, m, (3,). position_covariance: P_pp of the target
    position estimate, m^2, (3, 3). Returns inf for |dp| = 0 (the range is then unknown).
    """
    return float(relative_range_std_kernel(np.ascontiguousarray(relative_position, dtype=float),
                                     np.ascontiguousarray(position_covariance, dtype=float)))


@jit
def relative_range_std_kernel(relative_position: np.ndarray, position_covariance: np.ndarray) -> float:
    """relative_range_std's arithmetic (float64, C-contiguous): |dp| = sqrt(dp . dp) (norm), lambda = dp / |dp|,
    sigma_r = sqrt(max(lambda @ P_pp @ lambda, 0)) (Python's max: a NaN stays NaN), rho = sigma_r / |dp|."""
    distance = math.sqrt(relative_position @ relative_position)
    if distance <= 1e-9:
        return math.inf
    los = relative_position / distance
    variance = los @ position_covariance @ los
    return math.sqrt(0.0 if 0.0 > variance else variance) / distance


@jit
def relative_terms_kernel(target_position: np.ndarray, target_velocity: np.ndarray, position: np.ndarray,
                          velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The control tick's relative state in one call: dp = p^_T - p (m), dv = v^_T - v (m/s), r^ = |dp| as
    norm computes it (sqrt(dp . dp)) and the estimated line of sight dp / max(r^, 1e-9) (Python's max:
    a NaN r^ stays NaN). All float64 (3,)."""
    relative_position = target_position - position
    relative_velocity = target_velocity - velocity
    distance = math.sqrt(relative_position @ relative_position)
    floor = 1e-9 if 1e-9 > distance else distance
    return relative_position, relative_velocity, distance, relative_position / floor
