"""The IMM's model filters share one own-position tracker: the same results as a tracker per model filter.

Every model filter of an IMM with PREDICTED gains and pursuer_position_std > 0 keeps an OwnPositionTracker fed the
same samples, so IMMEstimator shares one (fed once per correction) until a correction that may leave some model
filter unfed (`_correct_each`: a model restarting on the bearing), which gives each model filter its own copy first.
Here, two IMMs see the same bearings: the default one and one whose trackers are separate from the start (what
every IMM was before the sharing); their states, covariances, probabilities and reports are equal bit for bit, over
random flights with late bearings, neighbours' bearings and model filters pushed behind the sensor (so that they
restart and their trackers part). Checked to fail when the sharing is broken: without the copy before
`_correct_each`, or with the shared tracker fed one more sample per correction. (Feeding the shared tracker the
same sample again is harmless: a second sample at the same stamp leaves OwnPositionTracker unchanged and gets the
same reference.)
"""

from __future__ import annotations

import numpy as np
from bitwise import assert_same, seeds
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.estimators import GainProjection, InitialGuess
from companion.core.imm import IMMEstimator, standard_models
from companion.core.messages import BearingMeasurement

PERIOD = 0.02
actions = st.lists(st.sampled_from(["predict", "correct", "late", "early", "neighbour", "push_behind", "repeat"]),
                   min_size=5, max_size=60)


def _imm() -> IMMEstimator:
    return IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.5), 1e-4 * np.eye(3), GainProjection.PREDICTED,
                        pursuer_position_std=0.1)


def _same(a: IMMEstimator, b: IMMEstimator) -> None:
    assert_same(a._states, b._states, "states")
    assert_same(a._covariances, b._covariances, "covariances")
    assert_same(a.model_probabilities, b.model_probabilities, "probabilities")
    assert_same(a._weights, b._weights, "weights")


def _report(report) -> tuple:
    return (report.innovation_angle, report.used_predicted_projection, report.reinitialized,
            np.full(3, np.nan) if report.innovation is None else report.innovation,
            np.full((3, 3), np.nan) if report.innovation_covariance is None else report.innovation_covariance)


@settings(max_examples=60, deadline=None)
@given(seeds, actions)
def test_a_shared_tracker_gives_the_results_of_one_tracker_per_model(seed, steps):
    rng = np.random.default_rng(seed)
    shared, separate = _imm(), _imm()
    separate._separate_trackers()  # a tracker per model filter from the start: the IMM before the sharing
    assert shared._shared_tracks and not separate._shared_tracks
    target = np.array([40.0, -20.0, -10.0]) + rng.normal(0.0, 5.0, 3)
    first = BearingMeasurement(0.0, target / np.linalg.norm(target), np.zeros(3))
    for imm in (shared, separate):
        imm.initialize_on_bearing(first, InitialGuess(30.0, 10.0, np.zeros(3), 3.0))
    last = first
    for step in steps:
        if step == "predict":
            for imm in (shared, separate):
                imm.predict()
        elif step == "push_behind":  # one model filter's target behind the sensor: it restarts at the next bearing
            k = int(rng.integers(1, 3))
            pairs = [(np.array(s), np.array(c)) for s, c in (f.state_and_covariance for f in shared.filters)]
            pairs[k][0][:3] = -pairs[k][0][:3]
            for imm in (shared, separate):
                imm.set_model_states(pairs)
        else:
            time = shared.time + {"late": -0.5 * PERIOD, "early": 0.3 * PERIOD}.get(step, 0.0)
            if step == "repeat":
                bearing = BearingMeasurement(last.time, last.direction, last.pursuer_position, source=last.source)
            else:
                own = rng.normal(0.0, 0.1, 3) + time * np.array([2.0, 0.0, 0.0])
                direction = target - own + rng.normal(0.0, 0.3, 3)
                bearing = BearingMeasurement(time, direction, own, source=int(rng.integers(1, 3)) if step == "neighbour" else 0)
            last = bearing
            reports = [imm.correct(BearingMeasurement(bearing.time, bearing.direction, bearing.pursuer_position,
                                                      source=bearing.source)) for imm in (shared, separate)]
            assert_same(_report(reports[0]), _report(reports[1]), step)
        _same(shared, separate)


def test_separating_gives_each_model_filter_its_own_tracker_equal_to_the_shared_one():
    imm = _imm()
    imm.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3)),
                              InitialGuess(30.0, 10.0, np.zeros(3), 3.0))
    for k in range(5):
        imm.predict()
        imm.correct(BearingMeasurement(imm.time, np.array([1.0, 0.01 * k, 0.0]), np.array([0.02 * k, 0.0, 0.0]), source=k % 2))
    trackers = [model_filter._own_track for model_filter in imm.filters]
    assert all(tracker is trackers[0] for tracker in trackers)
    neighbours = imm.filters[0]._neighbour_tracks
    assert list(neighbours) == [1] and all(f._neighbour_tracks is neighbours for f in imm.filters)
    imm._separate_trackers()
    separated = [model_filter._own_track for model_filter in imm.filters]
    assert len({id(tracker) for tracker in separated}) == 3 and separated[0] is trackers[0]
    for tracker in separated[1:]:
        assert vars(tracker).keys() == vars(trackers[0]).keys()
        for key, value in vars(trackers[0]).items():
            assert_same(getattr(tracker, key), value, key)
    assert len({id(f._neighbour_tracks[1]) for f in imm.filters}) == 3
