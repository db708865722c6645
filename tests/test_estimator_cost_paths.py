"""The closed forms and shortcuts of the u-PLKF and IMM updates against numpy's general routines or exact
arithmetic, on random inputs (hypothesis). Whole flights are the seed-1 figures' (tests/test_flight_figures.py)."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from paper_reference import floats, symmetric_with_eigenvalues, unit_vectors

from companion.core.estimators import (SHORTCUT_EIGENVALUE_BAND, _is_positive_semidefinite, _projector,
                                       _projector_pseudo_inverse, _solve_identity)
from companion.core.imm import markov_matrix


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, (3, 3), elements=floats(-10.0, 10.0)), st.integers(-6, 6))
def test_solve_identity_is_numpys_inverse_and_determinant(matrix, exponent):
    """_solve_identity's M^-1 is np.linalg.inv(M) (to rounding scaled by M's condition number) and its determinant
    the exact determinant of M's float entries (rational arithmetic, to rounding scaled by Hadamard's bound on
    |det M|: numpy's LU determinant loses the small rows of a badly scaled M, even its sign); M is reported singular
    only when its exact determinant is 0 to rounding."""
    matrix = matrix * 10.0**exponent
    reference_determinant = float(_exact_determinant(matrix))
    hadamard = float(np.prod(np.abs(matrix).sum(axis=1)))  # |det M| <= the product of its rows' 1-norms
    inverse, determinant, regular = _solve_identity(matrix)
    if not regular:
        assert abs(reference_determinant) <= 1e-12 * hadamard
        return
    assert abs(determinant - reference_determinant) <= 1e-12 * hadamard + 1e-300
    condition = np.linalg.cond(matrix)
    if condition < 1e8:
        reference = np.linalg.inv(matrix)
        np.testing.assert_allclose(inverse, reference, rtol=0.0, atol=1e-14 * condition * float(np.abs(reference).max()))


def _exact_determinant(matrix: np.ndarray) -> Fraction:
    """det M by cofactors in exact rational arithmetic on M's float64 entries (Fraction holds each exactly)."""
    m = [[Fraction(float(value)) for value in row] for row in matrix]
    return (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))


def test_solve_identity_reports_an_exactly_singular_matrix():
    inverse, determinant, regular = _solve_identity(np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]]))
    assert not regular and determinant == 0.0


@settings(max_examples=300, deadline=None)
@given(unit_vectors(), arrays(np.float64, (3, 3), elements=floats(-3.0, 3.0)), floats(1e-4, 1e2))
def test_pseudo_inverse_shortcut_is_the_numpy_formula(direction, factor, noise_scale):
    """On the shortcut's band the result is (S + g g^T)^-1 - g g^T with np.linalg.inv and np.outer, to rounding
    (the band bounds the condition number of S + g g^T)."""
    projection = np.eye(3) - np.outer(direction, direction)
    innovation = projection @ (factor @ factor.T) @ projection + noise_scale * projection
    low, high = SHORTCUT_EIGENVALUE_BAND
    trace = float(np.trace(innovation))
    outer = np.outer(direction, direction)
    if not (low <= trace <= high and np.linalg.det(innovation + outer) >= (1.0 + 1e-9) * low * trace):
        return  # the general branch (SVD), covered by tests/test_pseudo_inverse.py
    expected = np.linalg.inv(innovation + outer) - outer
    shifted = innovation + outer
    atol = 1e-13 * np.linalg.cond(shifted) * float(np.abs(np.linalg.inv(shifted)).max())
    np.testing.assert_allclose(_projector_pseudo_inverse(innovation, direction), expected, rtol=0.0, atol=atol)


@settings(max_examples=200, deadline=None)
@given(unit_vectors())
def test_projector_is_eye_minus_outer_to_the_last_bit(direction):
    np.testing.assert_array_equal(_projector(direction), np.eye(3) - np.outer(direction, direction))


@settings(max_examples=400, deadline=None)
@given(st.integers(0, 2**32 - 1), arrays(np.float64, 6, elements=floats(-1.0, 1.0)), st.integers(-8, 8),
       st.sampled_from(["any", "psd_singular", "tiny_negative"]))
def test_positive_semidefinite_check_is_eigvalsh_decision(seed, values, exponent, kind):
    """The Joseph-form decision: the Cholesky-first check says "PSD" exactly when eigvalsh's smallest
    eigenvalue is >= 0, except possibly when that eigenvalue is negative at rounding level (|lambda_min|
    below 1e-13 of the largest), where eigvalsh's own sign is rounding noise. Matrices
    Q diag(l) Q^T with random rotations: any signs, exactly one zero eigenvalue (PSD singular: Cholesky
    fails, so the decision is eigvalsh's own), one eigenvalue -1e-15 of the largest."""
    matrix = symmetric_with_eigenvalues(seed, values, exponent, kind)
    smallest, largest = np.linalg.eigvalsh(matrix)[[0, -1]]
    decision = _is_positive_semidefinite(matrix)
    if decision != (not smallest < 0.0):
        assert decision and abs(smallest) <= 1e-13 * max(abs(largest), abs(smallest))


@pytest.mark.parametrize("entry", [(2, 3), (0, 0), (5, 5), (5, 0)])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_positive_semidefinite_check_on_non_finite_entries_is_eigvalsh_decision(entry, value):
    """A non-finite entry: the check defers to eigvalsh, the same decision or the same LinAlgError."""
    matrix = np.eye(6)
    matrix[entry] = matrix[entry[::-1]] = value
    try:
        expected = not np.linalg.eigvalsh(matrix)[0] < 0.0  # the test UPLKF.correct used to make
    except np.linalg.LinAlgError:
        with pytest.raises(np.linalg.LinAlgError):
            _is_positive_semidefinite(matrix)
        return
    assert _is_positive_semidefinite(matrix) == expected


@settings(max_examples=200, deadline=None)
@given(st.integers(2, 7), floats(0.0, 1.0))
def test_markov_matrix_is_full_with_the_diagonal_filled(count, stay):
    leave = (1.0 - stay) / (count - 1)
    expected = np.full((count, count), leave)
    np.fill_diagonal(expected, stay)
    np.testing.assert_array_equal(markov_matrix(count, stay), expected)
