"""The in-process swarm harness's bookkeeping (studies/swarm.py) against the figure's definition, tick by tick.

_closest_separation computes the separation figure of all ticks at once; the reference computes it one tick at a
time (np.linalg.norm of the tick's pair offsets, np.min over the pairs, min() folded over the ticks). Positions are drawn at random, NaNs and coincident pursuers among
them; the figure must be the same float, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from studies.swarm import _closest_separation

FUZZ = settings(max_examples=300, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


def _reference(positions: np.ndarray) -> float:
    upper = np.triu_indices(positions.shape[1], 1)  # each pair of pursuers once
    separation = math.inf
    for tick in positions:
        gaps = np.linalg.norm(tick[:, None, :] - tick[None, :, :], axis=2)
        closest = float(np.min(gaps[upper]))
        separation = min(separation, closest)
    return separation


elements = st.one_of(st.floats(-1e3, 1e3), st.floats(-1e160, 1e160), st.just(math.nan), st.just(0.0))


@FUZZ
@given(st.integers(2, 5).flatmap(lambda n: hnp.arrays(np.float64, st.tuples(st.integers(1, 40), st.just(n), st.just(3)),
                                                          elements=elements)))
def test_the_closest_separation_is_the_per_tick_fold(positions):
    if positions.shape[0] > 1 and positions.shape[1] > 1:
        positions[1, 1] = positions[1, 0]  # two pursuers at one point
    with np.errstate(over="ignore"):  # huge coordinates: a distance may overflow to inf, in both
        expected = _reference(positions)
        actual = _closest_separation(positions, np.triu_indices(positions.shape[1], 1))
    assert type(actual) is float
    assert math.isnan(actual) if math.isnan(expected) else actual.hex() == expected.hex()


@FUZZ
@given(hnp.arrays(np.float64, (1, 2, 3), elements=st.floats(-1e3, 1e3)))
def test_one_pair_at_one_tick_is_its_norm_to_the_bit(positions):
    """One distance alone (nothing for the minima to hide): the norm's rounding itself is checked."""
    expected = _reference(positions)
    assert _closest_separation(positions, np.triu_indices(2, 1)).hex() == expected.hex()
