"""The u-PLKF's pseudo-inverse equals the Moore-Penrose pseudo-inverse (section IV-C), at any
scale of the innovation covariance (a diverging filter reaches 1e50 and beyond)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from paper_reference import floats, unit_vectors
from scipy.stats import special_ortho_group

from companion.core.estimators import _projector_pseudo_inverse


@settings(max_examples=200, deadline=None)
@given(unit_vectors(), arrays(np.float64, (3, 3), elements=floats(-3.0, 3.0)), floats(1e-4, 1e3))
def test_matches_numpy_pinv_for_rank_two_innovation_covariances(direction, factor, noise_scale):
    """S = P (F F^T) P + s P with P = I - g g^T: rank 2, kernel span(g); numpy's SVD-based pinv is the reference,
    with a relative cutoff (1e-10) that discards the rounding-level third eigenvalue: numpy's default cutoff
    (about 1e-15) sometimes keeps it and returns entries of order 1e17. The two non-zero eigenvalues are at
    least s >= 1e-4 and at most |F|_F^2 + s <= 81 + 1e3, a ratio (about 1e7) far inside the cutoff."""
    projection = np.eye(3) - np.outer(direction, direction)
    innovation = projection @ (factor @ factor.T) @ projection + noise_scale * projection
    expected = np.linalg.pinv(innovation, rcond=1e-10, hermitian=True)
    np.testing.assert_allclose(_projector_pseudo_inverse(innovation, direction), expected, atol=1e-9 * np.abs(expected).max())


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(-40, 60), floats(0.0, 4.0))
def test_matches_numpy_pinv_at_any_scale(seed, exponent, spread):
    """Random rank-2 PSD S = Q diag(0, l1, l2) Q^T, kernel g = Q e_1, with l1 = 10^exponent and
    l2 = l1 10^-spread: from far below to far above unit scale (where the shortcut
    (S + g g^T)^-1 - g g^T is numerically singular). Reference: numpy's pinv on the same S,
    whose rounding-level third eigenvalue its relative cutoff discards."""
    rotation = special_ortho_group.rvs(3, random_state=np.random.default_rng(seed))
    largest = 10.0**exponent
    innovation = rotation @ np.diag([0.0, largest, largest * 10.0**-spread]) @ rotation.T
    innovation = 0.5 * (innovation + innovation.T)
    expected = np.linalg.pinv(innovation, rcond=1e-10, hermitian=True)
    actual = _projector_pseudo_inverse(innovation, rotation[:, 0])
    np.testing.assert_allclose(actual, expected, rtol=0.0, atol=1e-7 * np.abs(expected).max())
    assert np.all(np.isfinite(actual))
