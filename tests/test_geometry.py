"""Geometric helpers: the projector P_g of eq. (5), R_eta of section VI-A and [x]_x."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from paper_reference import floats, nonzero_vectors, projector, r_eta, scaled_vectors, unit_vectors, vectors
from scipy.spatial.transform import Rotation

from companion.core.geometry import (
    E_X,
    E_Y,
    E_Z,
    cross,
    orthogonal_projection,
    rodrigues,
    rotation_about_y,
    rotation_about_z,
    rotation_from_x_axis_to,
    skew,
    unit,
)

PROPERTY = settings(max_examples=150, deadline=None)


def assert_proper_rotation(rotation: np.ndarray, atol: float = 1e-12) -> None:
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=atol)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=atol)


# --------------------------------------------------------------------------- unit


def test_unit_normalises_and_rejects_degenerate_vectors() -> None:
    assert np.linalg.norm(unit(np.array([3.0, -4.0, 12.0]))) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(unit(np.array([0.0, 0.0, -2.5])), -E_Z)
    for bad in (np.zeros(3), np.array([np.nan, 0.0, 1.0]), np.array([np.inf, 0.0, 0.0])):
        with pytest.raises(ValueError):
            unit(bad)


# --------------------------------------------------------------------------- P_g, eq. (5)


@PROPERTY
@given(scaled_vectors())
def test_projector_is_symmetric_idempotent_with_kernel_span_g(g: np.ndarray) -> None:
    projector_g = orthogonal_projection(g)
    np.testing.assert_allclose(projector_g, projector(g), atol=1e-12)  # eq. (5) written out
    np.testing.assert_allclose(projector_g, projector_g.T, atol=0.0)
    np.testing.assert_allclose(projector_g @ projector_g, projector_g, atol=1e-12)
    # ker(P_g) = span(g): P_g g = 0, and the rank is exactly 2 (eigenvalues 0, 1, 1).
    np.testing.assert_allclose(projector_g @ g, np.zeros(3), atol=1e-12 * np.linalg.norm(g))
    np.testing.assert_allclose(projector_g @ (-3.7 * g), np.zeros(3), atol=1e-11 * np.linalg.norm(g))
    assert np.linalg.matrix_rank(projector_g) == 2
    np.testing.assert_allclose(np.linalg.eigvalsh(projector_g), [0.0, 1.0, 1.0], atol=1e-12)
    assert np.trace(projector_g) == pytest.approx(2.0, abs=1e-12)


@PROPERTY
@given(nonzero_vectors(5.0, min_norm=0.1), nonzero_vectors(5.0, min_norm=0.1), floats(0.1, 10.0))
def test_projector_leaves_vectors_perpendicular_to_g_unchanged(g: np.ndarray, other: np.ndarray, scale: float) -> None:
    z = np.cross(g, other) * scale  # z is perpendicular to g
    np.testing.assert_allclose(orthogonal_projection(g) @ z, z, atol=1e-12 * max(1.0, np.linalg.norm(z)))


@PROPERTY
@given(nonzero_vectors(5.0, min_norm=0.1), vectors(5.0))
def test_projector_gives_the_perpendicular_component(g: np.ndarray, z: np.ndarray) -> None:
    projected = orthogonal_projection(g) @ z
    scale = max(1.0, np.linalg.norm(z))
    assert projected @ g == pytest.approx(0.0, abs=1e-12 * scale * np.linalg.norm(g))
    # z = P_g z + (component along g): the removed part is parallel to g.
    np.testing.assert_allclose(np.cross(z - projected, g), np.zeros(3), atol=1e-12 * scale * np.linalg.norm(g))
    # |P_g z| = |g x z| / |g|.
    assert np.linalg.norm(projected) == pytest.approx(np.linalg.norm(np.cross(g, z)) / np.linalg.norm(g), rel=1e-9, abs=1e-12 * scale)


def test_projector_depends_only_on_the_line_of_g() -> None:
    g = np.array([0.3, -1.2, 2.0])
    for factor in (1e-6, 0.5, 7.0, -1.0, -1e5):
        np.testing.assert_allclose(orthogonal_projection(factor * g), orthogonal_projection(g), atol=1e-12)


def test_projector_rejects_zero_vector() -> None:
    with pytest.raises(ValueError):
        orthogonal_projection(np.zeros(3))


# --------------------------------------------------------------------------- skew


@PROPERTY
@given(vectors(10.0), vectors(10.0))
def test_skew_is_the_cross_product_matrix(x: np.ndarray, y: np.ndarray) -> None:
    scale = max(1.0, np.linalg.norm(x) * np.linalg.norm(y))
    np.testing.assert_allclose(skew(x) @ y, np.cross(x, y), atol=1e-12 * scale)
    np.testing.assert_allclose(skew(x), -skew(x).T, atol=0.0)
    np.testing.assert_allclose(skew(x) @ x, np.zeros(3), atol=1e-12 * max(1.0, x @ x))
    # [x]_x^2 = x x^T - |x|^2 I  (used in the Rodrigues formula of R_eta)
    np.testing.assert_allclose(skew(x) @ skew(x), np.outer(x, x) - (x @ x) * np.eye(3), atol=1e-12 * max(1.0, x @ x))


@PROPERTY
@given(vectors(10.0), vectors(10.0))
def test_cross_matches_numpy(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(cross(a, b), np.cross(a, b), atol=1e-12 * max(1.0, np.linalg.norm(a) * np.linalg.norm(b)))
    np.testing.assert_allclose(cross(a, b), -cross(b, a), atol=0.0)


# --------------------------------------------------------------------------- Rodrigues, R_eta


@PROPERTY
@given(unit_vectors(), floats(-np.pi, np.pi), nonzero_vectors(1.0, min_norm=0.1))
def test_rodrigues_is_the_rotation_about_the_axis(axis: np.ndarray, angle: float, other: np.ndarray) -> None:
    rotation = rodrigues(axis, angle)
    assert_proper_rotation(rotation)
    np.testing.assert_allclose(rotation @ axis, axis, atol=1e-12)  # the axis is fixed
    np.testing.assert_allclose(np.trace(rotation), 1.0 + 2.0 * np.cos(angle), atol=1e-12)  # by the angle
    np.testing.assert_allclose(Rotation.from_rotvec(angle * axis).as_matrix(), rotation, atol=1e-12)
    v = np.cross(axis, other)  # a vector perpendicular to the axis turns by +angle
    if np.linalg.norm(v) > 1e-3 and abs(abs(angle) - np.pi) > 1e-6:  # the sign of a half turn is arbitrary
        turned = rotation @ v
        assert np.arctan2(axis @ np.cross(v, turned), v @ turned) == pytest.approx(angle, abs=1e-9)


@PROPERTY
@given(scaled_vectors().filter(lambda d: np.linalg.norm(np.cross(E_X, d)) > 1e-6 * np.linalg.norm(d)))
def test_rotation_from_x_axis_maps_e_x_onto_the_direction(direction: np.ndarray) -> None:
    rotation = rotation_from_x_axis_to(direction)
    assert_proper_rotation(rotation)
    lam = direction / np.linalg.norm(direction)
    np.testing.assert_allclose(rotation @ E_X, lam, atol=1e-12)
    # The rotation is about eta = e_X x lambda: the axis is fixed.
    axis = np.cross(E_X, lam)
    np.testing.assert_allclose(rotation @ axis, axis, atol=1e-12)
    # It is the paper's R_eta(theta_eta), built by scipy from the axis-angle pair.
    np.testing.assert_allclose(rotation, r_eta(direction).as_matrix(), atol=1e-9)


def test_rotation_from_x_axis_to_itself_is_identity() -> None:
    np.testing.assert_allclose(rotation_from_x_axis_to(E_X), np.eye(3), atol=0.0)
    np.testing.assert_allclose(rotation_from_x_axis_to(4.2 * E_X), np.eye(3), atol=0.0)


def test_rotation_from_x_axis_to_minus_x_is_a_half_turn() -> None:
    rotation = rotation_from_x_axis_to(-E_X)
    assert_proper_rotation(rotation)
    np.testing.assert_allclose(rotation @ E_X, -E_X, atol=1e-12)
    # Half turn: R^2 = I, trace -1.
    np.testing.assert_allclose(rotation @ rotation, np.eye(3), atol=1e-12)
    assert np.trace(rotation) == pytest.approx(-1.0, abs=1e-12)


@pytest.mark.parametrize("epsilon", [1e-3, 1e-6, 1e-9, 1e-12, 1e-15])
@pytest.mark.parametrize("perpendicular", [E_Y, E_Z, unit(np.array([0.0, 1.0, -1.0]))])
def test_rotation_from_x_axis_near_antiparallel_is_well_behaved(epsilon: float, perpendicular: np.ndarray) -> None:
    direction = -E_X + epsilon * perpendicular
    rotation = rotation_from_x_axis_to(direction)
    assert np.all(np.isfinite(rotation))
    assert_proper_rotation(rotation, atol=1e-10)
    np.testing.assert_allclose(rotation @ E_X, unit(direction), atol=1e-10)


@pytest.mark.parametrize("epsilon", [1e-6, 1e-10, 1e-13])
def test_rotation_from_x_axis_near_parallel_is_well_behaved(epsilon: float) -> None:
    direction = E_X + epsilon * np.array([0.0, 0.6, -0.8])
    rotation = rotation_from_x_axis_to(direction)
    assert_proper_rotation(rotation, atol=1e-10)
    np.testing.assert_allclose(rotation @ E_X, unit(direction), atol=1e-10)
    np.testing.assert_allclose(rotation, np.eye(3), atol=10 * epsilon + 1e-12)


# --------------------------------------------------------------------------- R_Z, R_Y


@PROPERTY
@given(floats(-2.0 * np.pi, 2.0 * np.pi))
def test_elementary_rotations_match_their_closed_forms(angle: float) -> None:
    c, s = np.cos(angle), np.sin(angle)
    np.testing.assert_allclose(rotation_about_z(angle), [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(rotation_about_y(angle), [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], atol=1e-12)
    assert_proper_rotation(rotation_about_z(angle))
    assert_proper_rotation(rotation_about_y(angle))
    # The same active rotations as scipy builds them.
    np.testing.assert_allclose(rotation_about_z(angle), Rotation.from_euler("z", angle).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(rotation_about_y(angle), Rotation.from_euler("y", angle).as_matrix(), atol=1e-12)


@given(arrays(np.float64, st.sampled_from([(3,), (2,), (6,), (3, 3)]),
              elements=st.floats(allow_nan=True, allow_infinity=True, width=64)))
def test_all_finite_is_numpys(values):
    from companion.core.geometry import all_finite

    assert all_finite(values) is bool(np.all(np.isfinite(values)))
