"""The IMM's correction in one kernel call, and the process-noise change records (issue 16).

- `imm._imm_correction` (the prior lines of sight, the shared own-position tracker's usual step and the whole IMM
  cycle in one call) gives, compiled and interpreted, what the calls it replaced give (`_prior_lines_of_sight`, then
  OwnPositionTracker's `_own_position_step`, then `_imm_correct_kernel`), bit for bit, with each of its outcomes;
- on random sequences of steps (bearings on the tick, late, repeated, after a gap, a neighbour's, behind the
  sensor; boosts; adaptive noise), IMMEstimator.correct gives what a verbatim copy of its code before the change
  gives (`OldCorrect`, on `_prior_lines_of_sight` and `_imm_correct_kernel`): reports, states, probabilities,
  trackers, estimates, bit for bit;
- every set of a process-noise factor (a model filter's boost or adaptive noise, an adaptive noise's scale, the
  IMM's boost) moves the count of the record the IMM reads (estimators.NoiseChanges, owned by the IMM and its model
  filters, no module-level state), also for an adaptive noise that serves a filter of another IMM and in a deep
  copy, which counts in its own record; a u-PLKF on its own has its own record.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from bitwise import assert_same, seeds

from companion.core import _jit
from companion import warmup
from companion.core import estimators
from companion.core import imm
from companion.core.estimators import (AdaptiveNoiseSettings, AdaptiveProcessNoise, CorrectionReport, GainProjection,
                                       InitialGuess, NoiseChanges, UPLKF, _behind_sensor, _own_position_step,
                                       restart_guess)
from companion.core.imm import IMMEstimator, _imm_correct_kernel, _prior_lines_of_sight, standard_models
from companion.core.messages import BearingMeasurement

python = _jit.python_function


def both(kernel, *args):
    """(compiled result, Python result) on copies of the arguments (kernels write in place), and the copies."""
    compiled_args = [np.array(a) if isinstance(a, np.ndarray) else a for a in args]
    python_args = [np.array(a) if isinstance(a, np.ndarray) else a for a in args]
    return kernel(*compiled_args), python(kernel)(*python_args), compiled_args, python_args


# --- the kernel against the three calls it replaced ---------------------------------------------------------


def correction_arguments(seed: int, count: int, lead: float, behind: str, reference: str) -> dict:
    """Random inputs of `_imm_correction` (by name): a turning target's models near the bearing; behind: "none",
    "one" (the first model behind the sensor) or "all" (the combined prior behind it); reference: "none" (no
    tracker), "step" (the tracker's step in the kernel), "given" ((1, 3) references) or "missing"."""
    rng = np.random.default_rng(seed)
    pursuer = rng.normal(size=3)
    direction = rng.normal(size=3)
    direction /= math.sqrt(float(direction @ direction))
    states = rng.normal(size=(count, 6))
    states[:, :3] = pursuer + 30.0 * direction + rng.normal(size=(count, 3)) - lead * states[:, 3:]
    if behind == "one":
        states[0, :3] = pursuer - 10.0 * direction - lead * states[0, 3:]
    elif behind == "all":
        states[:, :3] = pursuer - 10.0 * direction + rng.normal(size=(count, 3)) - lead * states[:, 3:]
    weights = rng.dirichlet(np.ones(count))
    if behind == "one":  # (and the combined prior ahead)
        weights = np.concatenate([[0.1], 0.9 * weights[1:] / weights[1:].sum()])
    factors = rng.normal(size=(count, 6, 6))
    track = np.concatenate([pursuer + rng.normal(size=3) * 0.1, rng.normal(size=3), [0.01, 0.002, 0.5]])
    late = lead != 0.0
    return dict(
        states=states, covariances=factors @ factors.transpose(0, 2, 1) + 1e-2 * np.eye(6),
        weights=weights, lead=lead, pursuer_position=pursuer, direction=direction,
        restart_when_behind=True, predicted_gain=True, model_relative=np.full((count, 3), np.nan),
        ranges=np.full(count, np.nan), model_ranges=np.full(count, np.nan), relative=np.full(3, np.nan),
        have_references=reference != "missing", references=pursuer + rng.normal(size=(1, 3)) * 0.1,
        use_reference=reference != "none", track_step=reference == "step", track=track, track_dt=0.02,
        acceleration_psd=1.0, track_std=0.1, prediction=np.full(3, np.nan), late=late,
        measurement_noises=np.array([1e-4 * np.eye(3)] * count), add_position_noise=True, position_variance=0.01,
        lead_noises=np.array([(j + 1) * 1e-3 * np.eye(3) if late else np.zeros((3, 3)) for j in range(count)]),
        stay_probability=0.98, stay_time=1.0, interval=0.02, with_nis=True, nis=np.full(count, np.nan),
        probabilities=np.full(count, np.nan), innovation=np.full(3, np.nan), innovation_covariance=np.full((3, 3), np.nan))


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([3, 5]), st.sampled_from([0.0, -0.01, 0.12]), st.sampled_from(["none", "one", "all"]),
       st.sampled_from(["none", "step", "given", "missing"]))
def test_one_kernel_is_the_calls_it_replaced(seed, count, lead, behind, reference):
    arguments = correction_arguments(seed, count, lead, behind, reference)
    names = list(arguments)
    compiled, interpreted, compiled_args, python_args = both(imm._imm_correction, *arguments.values())
    assert_same(compiled, interpreted)
    assert_same(tuple(compiled_args), tuple(python_args))
    # the replaced calls, on copies
    a = {name: np.array(value) if isinstance(value, np.ndarray) else value for name, value in arguments.items()}
    predicted_range, cos_angle, every_model_corrects = _prior_lines_of_sight(
        a["states"], a["weights"], a["lead"], a["pursuer_position"], a["direction"], True, a["model_relative"],
        a["ranges"], a["model_ranges"], a["relative"])
    if _behind_sensor(cos_angle, predicted_range):
        outcome = imm._RESTART
    elif not every_model_corrects:
        outcome = imm._MODEL_BY_MODEL
    elif reference == "missing":
        outcome = imm._NEEDS_REFERENCES
    else:
        outcome = imm._CORRECTED
        references = a["references"]
        if reference == "step":  # OwnPositionTracker.reference's step: its prediction the reference
            _own_position_step(a["track"], 0.02, 1.0, 0.1, a["pursuer_position"], a["prediction"])
            references = a["prediction"][None, :]
        innovation, innovation_covariance = _imm_correct_kernel(
            a["states"], a["covariances"], a["model_relative"], a["ranges"], a["model_ranges"], a["direction"],
            references, reference != "none", lead, a["late"], a["measurement_noises"], True, 0.01, a["lead_noises"],
            a["pursuer_position"], a["weights"], a["relative"], predicted_range, 0.98, 1.0, 0.02, True, a["nis"],
            a["probabilities"])
        a["innovation"][:], a["innovation_covariance"][:] = innovation, innovation_covariance
    assert interpreted == (predicted_range, cos_angle, outcome)
    assert outcome == {"all": imm._RESTART, "one": imm._MODEL_BY_MODEL}.get(
        behind, imm._NEEDS_REFERENCES if reference == "missing" else imm._CORRECTED)
    for k, name in enumerate(names):  # every array it writes (and leaves alone) as the replaced calls do
        assert_same(python_args[k], a[name], name)
    # the gains not PREDICTED: nothing but the lines of sight, model filter by model filter
    arguments["predicted_gain"] = False
    result = python(imm._imm_correction)(*arguments.values())
    assert result[2] == (imm._RESTART if behind == "all" else imm._MODEL_BY_MODEL)
    assert_same(arguments["states"], correction_arguments(seed, count, lead, behind, reference)["states"])


# --- whole IMMs against the code before the change ------------------------------------------------------------


class OldCorrect(IMMEstimator):
    """IMMEstimator with its correct and _correct_all as they were before `_imm_correction` (verbatim, 1c852b6)."""

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        filters = self.filters
        if len(filters) == 1:
            self._snapshot = None
            return filters[0].correct(bearing)
        self._require_states()
        lead = bearing.time - self.time
        pursuer_position = np.asarray(bearing.pursuer_position, dtype=float)
        direction = bearing.unit_direction
        model_relative, ranges, model_ranges, relative = self._lines_of_sight
        predicted_range, cos_angle, every_model_corrects = _prior_lines_of_sight(
            self._states, self._weights, lead, pursuer_position, direction, self.restart_when_behind, model_relative,
            ranges, model_ranges, relative)
        if self.restart_when_behind and _behind_sensor(cos_angle, predicted_range):
            guess = restart_guess(self._initial_guess, predicted_range, self._weights @ self._states[:, 3:])
            for model_filter in filters:
                model_filter.initialize_on_bearing(bearing, guess)
            self._reset_probabilities()
            return CorrectionReport(float(np.arccos(cos_angle)), False, reinitialized=True)
        interval = self.stay_time if self._last_correction_time is None else bearing.time - self._last_correction_time
        if every_model_corrects and filters[0].gain_projection is GainProjection.PREDICTED:
            report = self._correct_all(bearing, lead, pursuer_position, direction, model_relative, ranges, model_ranges,
                                       relative, predicted_range, cos_angle, interval)
        else:
            report = self._correct_each(bearing, model_relative, ranges, relative, predicted_range, cos_angle, interval)
        self._last_correction_time = bearing.time
        return report

    def _correct_all(self, bearing, lead, pursuer_position, direction, model_relative, ranges, model_ranges, relative,
                     predicted_range, cos_angle, interval) -> CorrectionReport:
        filters = self.filters
        if self._shared_tracks:
            reference, direction, late, lead_noise = filters[0]._correction_inputs(bearing, lead, direction)
            references = reference[None, :]
            lead_noises = (np.array([lead_noise] + [model_filter._lead_noise(lead) for model_filter in filters[1:]])
                           if late else self._no_lead_noises)
        else:
            inputs = [model_filter._correction_inputs(bearing, lead, direction) for model_filter in filters]
            reference, direction, late = inputs[0][:3]
            references = np.array([reference for reference, *_ in inputs]) if reference is not None else None
            lead_noises = np.array([lead_noise for *_, lead_noise in inputs]) if late else self._no_lead_noises
        use_reference = reference is not None
        adaptive = [model_filter._adaptive_noise for model_filter in filters]
        nis, probabilities = self._nis, self._probabilities
        innovation, innovation_covariance = _imm_correct_kernel(
            self._states, self._covariances, model_relative, ranges, model_ranges, direction,
            references if use_reference else self._no_references, use_reference,
            lead, late, self._measurement_noises, filters[0].pursuer_position_std > 0.0, filters[0].pursuer_position_std**2,
            lead_noises, pursuer_position,
            self._weights, relative, predicted_range, self.stay_probability, self.stay_time, interval, any(adaptive), nis,
            probabilities)
        for j, model_filter in enumerate(filters):
            model_filter._snapshot = None
            if adaptive[j] is not None:
                adaptive[j].update(bearing.time, float(nis[j]), 2)
        self._set_probabilities(probabilities)
        self._snapshot = None
        return CorrectionReport(float(np.arccos(cos_angle)), True, innovation=innovation,
                                innovation_covariance=innovation_covariance, innovation_dof=2)


STEPS = st.lists(st.one_of(
    st.tuples(st.just("predict"), st.sampled_from([1, 2, 3, 60])),  # 60 ticks: a gap beyond the tracker's max_gap
    st.tuples(st.just("bearing"), st.sampled_from([0.0, -0.007, -0.15, 0.0])),  # on the tick or late
    st.tuples(st.just("again"), st.just(0)),  # a second bearing at the last bearing's stamp
    st.tuples(st.just("neighbour"), st.integers(1, 2)),
    st.tuples(st.just("behind"), st.just(0)),  # a bearing away from the target: the combined prior behind the sensor
    st.tuples(st.just("boost"), st.sampled_from([1.0, 3.0])),
    st.tuples(st.just("model behind"), st.just(0)),  # one model's prediction behind the sensor
), min_size=1, max_size=40)


def _bearing(time: float, k: int, pursuer_offset: np.ndarray = np.zeros(3), source: int = 0,
             sign: float = 1.0) -> BearingMeasurement:
    """A bearing of a target near (30, 0, -10) m from a weaving pursuer (sign -1: pointing away from the target)."""
    target = np.array([30.0 + 2.0 * time, 8.0 * math.sin(0.3 * time), -10.0])
    pursuer = np.array([math.sin(1.1 * time), 2.0 * math.cos(0.7 * time), -5.0]) + pursuer_offset
    return BearingMeasurement(time, sign * (target - pursuer) + 0.1 * math.sin(7.0 * k), pursuer + 0.05 * math.cos(5.0 * k),
                              source=source)


def _observed(estimator: IMMEstimator, report) -> tuple:
    own = estimator.filters[0]._own_track
    trackers = [own] + list(estimator.filters[0]._neighbour_tracks.values()) if own is not None else []
    return ((report.innovation_angle, report.used_predicted_projection, report.reinitialized, report.innovation,
             report.innovation_covariance, report.innovation_dof) if report is not None else (),
            estimator._states, estimator._covariances, estimator._weights, estimator.model_probabilities,
            estimator.motion_probabilities, estimator.time, estimator._shared_tracks,
            tuple((t._time, t._filter, t._last_prediction) for t in trackers),
            tuple(f.process_noise_scale for f in estimator.filters),
            (estimator.estimate.position, estimator.estimate.velocity, estimator.estimate.covariance))


@settings(max_examples=60, deadline=None)
@given(STEPS, st.booleans(), st.sampled_from([0.1, 0.0]), st.sampled_from([GainProjection.PREDICTED, GainProjection.MEASURED]))
def test_correct_is_the_code_it_replaced(steps, adaptive, position_std, projection):
    pair = [cls(0.02, standard_models([0.2], 0.04, 0.04), 1e-4 * np.eye(3), projection, pursuer_position_std=position_std,
                adaptive_noise=AdaptiveNoiseSettings() if adaptive else None) for cls in (IMMEstimator, OldCorrect)]
    for estimator in pair:
        estimator.initialize_on_bearing(_bearing(0.0, 0), InitialGuess(30.0, 10.0, np.zeros(3), 5.0))
    last = 0.0
    for k, (kind, value) in enumerate(steps):
        observed = []
        for estimator in pair:
            report = None
            if kind == "predict":
                for _ in range(value):
                    estimator.predict()
            elif kind == "boost":
                estimator.process_noise_boost = value
            else:
                time = estimator.time + value if kind == "bearing" else last if kind == "again" else estimator.time
                if kind == "neighbour":
                    bearing = _bearing(time, k, np.array([0.0, 6.0 * value, -1.0]), source=value)
                elif kind == "behind":
                    bearing = _bearing(time, k, sign=-1.0)
                else:
                    bearing = _bearing(time, k)
                if kind == "model behind":  # the second model's prediction 50 m back, behind the pursuer
                    estimator.set_model_states([(state - (50.0 if j == 1 else 0.0) * np.array([1.0, 0, 0, 0, 0, 0]),
                                                 covariance) for j, (state, covariance) in
                                                enumerate(zip(estimator._states, estimator._covariances))])
                report = estimator.correct(bearing)
                new_last = time
            observed.append(_observed(estimator, report))
        assert_same(observed[0], observed[1], f"step {k}: {kind} {value}")
        if kind not in ("predict", "boost"):
            last = new_last


def test_the_sequences_reach_every_outcome(monkeypatch):
    """The random sequences above take every path of the one-kernel correction (on a fixed sequence)."""
    outcomes = []
    kernel = imm._imm_correction

    def recording(*arguments):
        result = kernel(*arguments)
        outcomes.append((result[2], arguments[15]))
        return result

    monkeypatch.setattr(imm, "_imm_correction", recording)
    steps = [("predict", 1), ("bearing", 0.0), ("predict", 1), ("bearing", 0.0), ("again", 0), ("bearing", -0.007),
             ("neighbour", 1), ("predict", 1), ("neighbour", 1), ("predict", 60), ("bearing", 0.0), ("behind", 0),
             ("predict", 1), ("bearing", 0.0), ("predict", 1), ("bearing", 0.0), ("model behind", 0), ("predict", 1),
             ("bearing", 0.0)]
    test_correct_is_the_code_it_replaced.hypothesis.inner_test(steps, False, 0.1, GainProjection.PREDICTED)
    assert {(imm._CORRECTED, True), (imm._CORRECTED, False), (imm._NEEDS_REFERENCES, False), (imm._RESTART, False),
            (imm._MODEL_BY_MODEL, False)} <= set(outcomes)


# --- the process-noise change records ---------------------------------------------------------------------------


def test_no_module_level_change_count():
    """The count of process-noise changes is owned by the filters (NoiseChanges), not by the module."""
    assert not any(isinstance(value, int) and "noise" in name for name, value in vars(estimators).items())
    first, second = UPLKF(0.02, np.eye(3), np.eye(3)), UPLKF(0.02, np.eye(3), np.eye(3))
    assert isinstance(first._noise_changes, NoiseChanges) and first._noise_changes is not second._noise_changes


def _imm(adaptive: bool = True) -> IMMEstimator:
    estimator = IMMEstimator(0.02, standard_models([0.2], 0.04, 0.04), 1e-4 * np.eye(3), GainProjection.PREDICTED,
                             pursuer_position_std=0.1, adaptive_noise=AdaptiveNoiseSettings() if adaptive else None)
    estimator.initialize_on_bearing(_bearing(0.0, 0), InitialGuess(30.0, 10.0, np.zeros(3), 5.0))
    return estimator


def _changes(estimator: IMMEstimator):
    """Every way to set one of its process-noise factors, each a (label, function) pair."""
    filters = estimator.filters
    return [
        ("imm boost", lambda: setattr(estimator, "process_noise_boost", 2.0)),
        ("model boost", lambda: setattr(filters[1], "process_noise_boost", 0.5)),
        ("scale", lambda: setattr(filters[2].adaptive_noise, "scale", 4.0)),
        ("adaptive update", lambda: filters[0].adaptive_noise.update(1.0, 50.0, 2)),
        ("adaptive off", lambda: setattr(filters[2], "adaptive_noise", None)),
        ("adaptive on", lambda: setattr(filters[2], "adaptive_noise", AdaptiveProcessNoise(AdaptiveNoiseSettings()))),
    ]


@pytest.mark.parametrize("label", [label for label, _ in _changes(_imm())])
def test_every_change_moves_the_imms_count_and_its_prediction_takes_it(label):
    estimator = _imm()
    estimator.predict()
    change = dict(_changes(estimator))[label]
    before = estimator._noise_changes.count
    change()
    assert estimator._noise_changes.count > before, label
    assert all(f._noise_changes is estimator._noise_changes for f in estimator.filters)
    expected_states, expected_covariances = estimator._states.copy(), estimator._covariances.copy()
    for j, model_filter in enumerate(estimator.filters):  # each model filter's own prediction with its factors
        python(estimators._predict_kernel)(model_filter._a, model_filter._q_discrete, model_filter.process_noise_scale,
                                           float(model_filter.process_noise_boost), expected_states[j], expected_covariances[j])
    estimator.predict()
    assert_same((estimator._states, estimator._covariances), (expected_states, expected_covariances), label)


def test_an_adaptive_noise_serving_two_imms_counts_in_both_and_a_copy_in_its_own():
    first, second = _imm(), _imm()
    shared = first.filters[1].adaptive_noise
    second.filters[0].adaptive_noise = shared  # one noise, a model filter of each IMM
    counts = (first._noise_changes.count, second._noise_changes.count)
    shared.scale = 6.0
    assert (first._noise_changes.count, second._noise_changes.count) > counts
    assert first._noise_changes.count > counts[0] and second._noise_changes.count > counts[1]
    for estimator, j in ((first, 1), (second, 0)):
        estimator.predict()
        assert estimator._scales[j] == 6.0
    twin = copy.deepcopy(first)
    assert twin._noise_changes is not first._noise_changes
    assert all(f._noise_changes is twin._noise_changes for f in twin.filters)
    before = (first._noise_changes.count, twin._noise_changes.count)
    twin.filters[1].adaptive_noise.scale = 9.0  # the copy's noise: counts in the copy's record
    assert twin._noise_changes.count > before[1]
    twin.predict()
    first.predict()
    assert twin._scales[1] == 9.0 and first._scales[1] == 6.0
    alone = UPLKF(0.02, 0.04 * np.eye(3), 1e-4 * np.eye(3), adaptive_noise=AdaptiveNoiseSettings())
    own = alone._noise_changes.count
    alone.adaptive_noise.scale = 2.0
    alone.process_noise_boost = 3.0
    assert alone._noise_changes.count == own + 2


def test_warm_up_compiles_the_one_kernel_correction():
    """warmup.warm_up runs IMM corrections on and off the tracker's step: no flight waits for `_imm_correction`, and
    the corrections of a flight's kinds take the signature it compiled."""
    warmup.warm_up()
    if not _jit.ENABLED:
        assert python(imm._imm_correction) is imm._imm_correction
        return
    signatures = list(imm._imm_correction.signatures)
    assert signatures
    steps = [("predict", 1), ("bearing", 0.0), ("again", 0), ("bearing", -0.007), ("neighbour", 1), ("predict", 60),
             ("bearing", 0.0), ("behind", 0), ("predict", 1), ("bearing", 0.0), ("model behind", 0), ("bearing", 0.0)]
    for position_std in (0.1, 0.0):
        test_correct_is_the_code_it_replaced.hypothesis.inner_test(steps, True, position_std, GainProjection.PREDICTED)
    assert list(imm._imm_correction.signatures) == signatures
