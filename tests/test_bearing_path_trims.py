"""The bearing path's trims of issue 16 (one flight cheaper) compute what the code they replaced computed, bit
for bit: each new kernel compiled against its own Python function (`kernel.py_func`) and against the numpy
expressions it replaced, and each object built without its dataclass constructor equal to the constructor's.

- the u-PLKF's prior line of sight (estimators._prior_line_of_sight): p^-_T + tau v^-_T - p, its length, the
  clipped cosine (Python's min and max: a NaN stays NaN) and remark 3's guard, as UPLKF.correct formed them;
- the u-PLKF's correction report (estimators._correction_report) is CorrectionReport(...).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from bitwise import assert_same, seeds
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats

from companion.core import _jit
from companion.core import estimators
from companion.core.estimators import CorrectionReport

python = _jit.python_function

special = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e-13, 1e300])


def old_prior(state, lead, pursuer_position, direction):
    """UPLKF.correct's prior line of sight before the kernel (505f6f6), with its guard (restart_when_behind)."""
    relative = state[:3] + lead * state[3:] - pursuer_position
    predicted_range = math.sqrt(float(relative.dot(relative)))
    cos_angle = min(max(float(direction @ relative / max(predicted_range, 1e-12)), -1.0), 1.0)
    return relative, predicted_range, cos_angle, cos_angle <= 0.0 or predicted_range < 1e-6


@settings(max_examples=300, deadline=None)
@given(seeds, st.integers(-8, 8), floats(-0.5, 0.5), st.sampled_from(["ahead", "behind", "on", "special"]), special)
def test_prior_line_of_sight(seed, exponent, lead, where, value):
    rng = np.random.default_rng(seed)
    state = rng.normal(size=6) * 10.0**exponent
    pursuer = rng.normal(size=3) * 10.0**exponent
    direction = rng.normal(size=3)
    direction /= math.sqrt(float(direction @ direction))
    if where == "behind":
        state[:3] = pursuer - 10.0**exponent * direction - lead * state[3:]
    elif where == "on":
        state[:3] = pursuer - lead * state[3:]
    elif where == "special":
        state[rng.integers(6)] = value
    expected = old_prior(state, lead, pursuer, direction)
    for function in (estimators._prior_line_of_sight, python(estimators._prior_line_of_sight)):
        relative, predicted_range, cos_angle, behind = function(state, lead, pursuer, direction)
        assert_same((relative, predicted_range, cos_angle), expected[:3])
        assert behind == expected[3]
        assert isinstance(cos_angle, float) and isinstance(predicted_range, float)


def test_prior_line_of_sight_clips_as_pythons_min_and_max():
    """Cosines beyond +-1 by rounding are clipped, a NaN is kept (the guard then does not fire on the cosine)."""
    direction = np.array([-0.29634718220320333, -0.9501875070900958, 0.0965507585165991])  # unit, to rounding
    ahead = np.concatenate((32.425080287829374 * direction, np.zeros(3)))  # cosine 1 + 2^-52 unclipped
    assert float(direction @ ahead[:3] / math.sqrt(float(ahead[:3] @ ahead[:3]))) > 1.0
    for state, cosine in ((ahead, 1.0), (-ahead, -1.0), (np.array([math.nan, 0.0, 0.0, 0, 0, 0]), math.nan)):
        for function in (estimators._prior_line_of_sight, python(estimators._prior_line_of_sight)):
            assert_same(function(state, 0.0, np.zeros(3), direction)[2], cosine)


@given(floats(0.0, math.pi), st.booleans(), seeds, st.integers(0, 3))
def test_correction_report_is_the_dataclasses(angle, used_predicted, seed, dof):
    rng = np.random.default_rng(seed)
    innovation, covariance = rng.normal(size=3), rng.normal(size=(3, 3))
    report = estimators._correction_report(angle, used_predicted, innovation, covariance, dof)
    expected = CorrectionReport(angle, used_predicted, innovation=innovation, innovation_covariance=covariance,
                                innovation_dof=dof)
    assert type(report) is CorrectionReport
    assert vars(report) == vars(expected) and list(vars(report)) == list(vars(expected))
    assert repr(report) == repr(expected)
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.innovation_dof = 5
