"""Independent references for the property tests: the paper's equations written out again
from the text (Li et al., IEEE T-RO 2023), on numpy and scipy's Rotation only, and the
hypothesis strategies that feed them.

Nothing here imports the package under test, so a test that compares the package with
these functions compares two independent implementations of the same equation.
Conventions: NED world frame, FRD body frame, gravity +g e_Z, vectors shape (3,).
"""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

E_X = np.array([1.0, 0.0, 0.0])
E_Z = np.array([0.0, 0.0, 1.0])

# --------------------------------------------------------------------------- strategies


def floats(low: float, high: float) -> st.SearchStrategy[float]:
    """Finite floats in [low, high]."""
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


def vectors(scale: float = 10.0) -> st.SearchStrategy[np.ndarray]:
    """Any 3-vector with components in [-scale, scale] (zero included)."""
    return st.tuples(floats(-scale, scale), floats(-scale, scale), floats(-scale, scale)).map(np.array)


def nonzero_vectors(scale: float = 10.0, min_norm: float = 1e-3) -> st.SearchStrategy[np.ndarray]:
    """3-vectors of norm in [min_norm, sqrt(3) scale]: a direction is well defined."""
    return vectors(scale).filter(lambda v: float(np.linalg.norm(v)) >= min_norm)


def unit_vectors() -> st.SearchStrategy[np.ndarray]:
    """Unit 3-vectors, normalised from a vector of norm >= 0.1 (no degenerate direction)."""
    return nonzero_vectors(1.0, min_norm=0.1).map(lambda v: v / np.linalg.norm(v))


def scaled_vectors() -> st.SearchStrategy[np.ndarray]:
    """Nonzero vectors whose norm spans 1e-4 .. 1e4 (direction-only quantities must not care)."""
    return st.tuples(unit_vectors(), st.sampled_from([1e-4, 1e-2, 1.0, 5.0, 1e2, 1e4])).map(lambda pair: pair[0] * pair[1])


# --------------------------------------------------------------------------- eq. (5)


def projector(g: np.ndarray) -> np.ndarray:
    """P_g = I - g g^T / |g|^2, eq. (5)."""
    return np.eye(3) - np.outer(g, g) / float(g @ g)


# --------------------------------------------------------------------------- eq. (14)


def r_eta(los: np.ndarray) -> Rotation:
    """R_eta(theta_eta), eta = e_X x lambda, theta_eta = acos(lambda^T e_X) (section VI-A): the
    rotation by theta_eta about the unit axis eta. lambda must not be parallel to e_X."""
    lam = los / np.linalg.norm(los)
    axis = np.cross(E_X, lam)
    theta = np.arccos(np.clip(lam @ E_X, -1.0, 1.0))
    return Rotation.from_rotvec(theta * axis / np.linalg.norm(axis))


def helical_navigation(t: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                       n: float, c_z: float, c_y: float, omega: float = 1.0) -> np.ndarray:
    """a_HN = N v x (R_eta R_Z R_Y e_X) x lambda, eq. (14), with R_Z = R_Z(c_Z sin(w t)/r_hat),
    R_Y = R_Y(c_Y cos(w t)/r_hat); the cross products associate left to right,
    (v x lambda_v) x lambda (the paper's PPG a = N (v x lambda) x lambda is the c = 0 case)."""
    lam = los / np.linalg.norm(los)
    alpha = c_z * np.sin(omega * t) / range_estimate
    beta = c_y * np.cos(omega * t) / range_estimate
    virtual = (r_eta(lam) * Rotation.from_euler("z", alpha) * Rotation.from_euler("y", beta)).apply(E_X)
    return n * np.cross(np.cross(velocity, virtual), lam)


# --------------------------------------------------------------------------- eq. (15)-(19)


def sigma(x: float) -> float:
    """sigma(x) = 3 atan(x / 3), section VI-B."""
    return 3.0 * np.arctan(x / 3.0)


def sigma_slope(x: float) -> float:
    """d sigma / dx = 1 / (1 + (x/3)^2)."""
    return 1.0 / (1.0 + (x / 3.0) ** 2)


def range_control(dp: np.ndarray, dv: np.ndarray, los: np.ndarray, a_hn: np.ndarray, r_d: float, k: float) -> np.ndarray:
    """a_RC = u* / (lambda^T dp) lambda, eq. (18), with xi_1 (15), xi_2 (16), v* (17), u* (19)."""
    distance = np.linalg.norm(dp)
    xi1 = distance - r_d
    xi2 = dp @ dv / distance
    v_star = -k * (sigma(xi1) + xi2) - sigma(xi1) - sigma_slope(xi1) * xi2
    u_star = -distance * v_star + dv @ dv - xi2**2 - dp @ a_hn
    return u_star / (los @ dp) * los


# --------------------------------------------------------------------------- eq. (21)-(22)


def desired_attitude(acceleration: np.ndarray, los: np.ndarray, gravity: float) -> Rotation:
    """R_d of eq. (21)-(22) built another way: the rotation that puts body z exactly on the thrust
    direction (g e_Z - a_d)/|g e_Z - a_d| and body x (the camera) as close as possible to lambda,
    by scipy's Wahba solver with an infinite weight on the first pair. lambda must not be
    parallel to the thrust direction."""
    thrust_axis = gravity * E_Z - acceleration
    thrust_axis = thrust_axis / np.linalg.norm(thrust_axis)
    rotation, _ = Rotation.align_vectors([thrust_axis, los / np.linalg.norm(los)], [E_Z, E_X], weights=[np.inf, 1.0])
    return rotation


def symmetric_with_eigenvalues(seed: int, values: np.ndarray, exponent: int, kind: str) -> np.ndarray:
    """Q diag(l) Q^T for a random rotation Q (scipy's special_ortho_group, seeded), l = values 10^exponent;
    kind "any": those signs; "psd_singular": |l| + 10^exponent with l_0 = 0 exactly; "tiny_negative": the same
    with l_0 = -1e-15 of the largest. Symmetrised to the last bit. For positive-semidefinite decisions."""
    from scipy.stats import special_ortho_group

    rotation = special_ortho_group.rvs(len(values), random_state=np.random.default_rng(seed))
    eigenvalues = values * 10.0**exponent
    if kind != "any":
        eigenvalues = np.abs(eigenvalues) + 10.0**exponent
        eigenvalues[0] = 0.0 if kind == "psd_singular" else -1e-15 * eigenvalues.max()
    matrix = rotation @ np.diag(eigenvalues) @ rotation.T
    return 0.5 * (matrix + matrix.T)
