"""The u-PLKF's pseudo-inverse shortcut equals the Moore-Penrose pseudo-inverse (section IV-C)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.estimators import _projector_pseudo_inverse


@settings(max_examples=200, deadline=None)
@given(st.integers(min_value=0, max_value=2**32 - 1), st.floats(min_value=1e-4, max_value=1e3))
def test_matches_numpy_pinv_for_rank_two_innovation_covariances(seed, noise_scale):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    projection = np.eye(3) - np.outer(direction, direction)
    factor = rng.normal(size=(3, 3))
    innovation = projection @ (factor @ factor.T) @ projection + noise_scale * projection
    expected = np.linalg.pinv(innovation, hermitian=True)
    np.testing.assert_allclose(_projector_pseudo_inverse(innovation, direction), expected, atol=1e-9 * np.abs(expected).max())
