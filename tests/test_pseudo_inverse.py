"""The u-PLKF's pseudo-inverse shortcut equals the Moore-Penrose pseudo-inverse (section IV-C)."""

import numpy as np
from hypothesis import given, settings
from hypothesis.extra.numpy import arrays
from paper_reference import floats, unit_vectors

from companion.core.estimators import _projector_pseudo_inverse


@settings(max_examples=200, deadline=None)
@given(unit_vectors(), arrays(np.float64, (3, 3), elements=floats(-3.0, 3.0)), floats(1e-4, 1e3))
def test_matches_numpy_pinv_for_rank_two_innovation_covariances(direction, factor, noise_scale):
    """S = P (F F^T) P + s P with P = I - g g^T: rank 2, kernel span(g); numpy's SVD-based pinv is the reference."""
    projection = np.eye(3) - np.outer(direction, direction)
    innovation = projection @ (factor @ factor.T) @ projection + noise_scale * projection
    expected = np.linalg.pinv(innovation, hermitian=True)
    np.testing.assert_allclose(_projector_pseudo_inverse(innovation, direction), expected, atol=1e-9 * np.abs(expected).max())
