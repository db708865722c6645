"""Small geometric helpers shared by the estimator, guidance and attitude mapping.

All vectors are numpy arrays of shape (3,) in the local NED frame unless stated.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

E_X = np.array([1.0, 0.0, 0.0])
E_Y = np.array([0.0, 1.0, 0.0])
E_Z = np.array([0.0, 0.0, 1.0])


def unit(vector: np.ndarray) -> np.ndarray:
    """Return vector / |vector|; raises ValueError on a zero or non-finite vector."""
    norm = float(np.linalg.norm(vector))
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError(f"cannot normalise vector {vector!r}")
    return vector / norm


def orthogonal_projection(g: np.ndarray) -> np.ndarray:
    """Orthogonal projector onto the plane perpendicular to g, eq. (5).

    P_g = I - g g^T / |g|^2; P_g is symmetric, idempotent and ker(P_g) = span(g).
    g: any nonzero vector, shape (3,). Returns shape (3, 3).
    """
    g_unit = unit(np.asarray(g, dtype=float))
    return np.eye(3) - np.outer(g_unit, g_unit)


def skew(vector: np.ndarray) -> np.ndarray:
    """[x]_x such that skew(x) @ y == cross(x, y); shape (3, 3)."""
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_from_x_axis_to(direction: np.ndarray) -> np.ndarray:
    """R_eta(theta_eta) of section VI-A: the rotation that maps e_X onto `direction`.

    eta = e_X x lambda and theta_eta = acos(lambda^T e_X); the Rodrigues formula of
    the paper needs the *unit* axis eta/|eta| (|e_X x lambda| = sin(theta_eta)),
    which scipy's rotation-vector form takes care of. For lambda = -e_X the axis is
    undefined; any half turn about an axis perpendicular to e_X is valid and e_Z is
    used. direction: shape (3,), need not be unit. Returns shape (3, 3).
    """
    lam = unit(np.asarray(direction, dtype=float))
    axis = np.cross(E_X, lam)
    sin_theta = float(np.linalg.norm(axis))
    cos_theta = float(np.clip(lam @ E_X, -1.0, 1.0))
    theta = float(np.arctan2(sin_theta, cos_theta))
    if sin_theta < 1e-12:
        if cos_theta > 0.0:
            return np.eye(3)
        return Rotation.from_rotvec(np.pi * E_Z).as_matrix()
    return Rotation.from_rotvec(axis / sin_theta * theta).as_matrix()


def rotation_about_z(angle: float) -> np.ndarray:
    """R_Z(alpha): rotation by `angle` rad about the z axis, shape (3, 3)."""
    return Rotation.from_rotvec(angle * E_Z).as_matrix()


def rotation_about_y(angle: float) -> np.ndarray:
    """R_Y(alpha): rotation by `angle` rad about the y axis, shape (3, 3)."""
    return Rotation.from_rotvec(angle * E_Y).as_matrix()
