"""The IMM's correction in one kernel call, and the process-noise change records.

- `imm._imm_correction` (the prior lines of sight, the shared own-position tracker's usual step and the whole IMM
  cycle in one call) takes each of its outcomes where it should (what its corrections compute is
  tests/test_estimator_kernels.py's one-call-versus-model-by-model check and tests/test_imm.py's);
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
from companion.core.estimators import (AdaptiveNoiseSettings, AdaptiveProcessNoise, GainProjection, InitialGuess,
                                       NoiseChanges, UPLKF)
from companion.core.imm import IMMEstimator, standard_models
from companion.core.messages import BearingMeasurement

python = _jit.python_function


# --- the one-kernel correction's outcomes -----------------------------------------------------------------


def correction_arguments(seed: int, count: int, lead: float, behind: str, reference: str) -> dict:
    """Random inputs of `_imm_correction` (by name; `correct` packs them): a turning target's models near the bearing; behind: "none",
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


def correct(a: dict) -> tuple:
    """`_imm_correction` on the arguments of `correction_arguments`, packed as it takes them."""
    scalars = np.zeros(imm._CORRECTION_SCALARS)
    for index, name in ((imm._LEAD, "lead"), (imm._TRACK_DT, "track_dt"), (imm._ACCELERATION_PSD, "acceleration_psd"),
                        (imm._TRACK_STD, "track_std"), (imm._POSITION_VARIANCE, "position_variance"),
                        (imm._STAY_PROBABILITY, "stay_probability"), (imm._STAY_TIME, "stay_time"),
                        (imm._INTERVAL, "interval")):
        scalars[index] = a[name]
    switches = np.zeros(imm._CORRECTION_SWITCHES, dtype=bool)
    for index, name in ((imm._RESTART_WHEN_BEHIND, "restart_when_behind"), (imm._PREDICTED_GAIN, "predicted_gain"),
                        (imm._HAVE_REFERENCES, "have_references"), (imm._USE_REFERENCE, "use_reference"),
                        (imm._TRACK_STEP, "track_step"), (imm._LATE, "late"),
                        (imm._ADD_POSITION_NOISE, "add_position_noise"), (imm._WITH_NIS, "with_nis")):
        switches[index] = a[name]
    return imm._imm_correction(a["states"], a["covariances"], a["weights"], a["pursuer_position"], a["direction"],
                               (a["measurement_noises"], a["lead_noises"]), (a["references"], a["track"], a["prediction"]),
                               (a["model_relative"], a["ranges"], a["model_ranges"], a["relative"]),
                               (a["nis"], a["probabilities"], a["innovation"], a["innovation_covariance"]), scalars,
                               switches)


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([3, 5]), st.sampled_from([0.0, -0.01, 0.12]), st.sampled_from(["none", "one", "all"]),
       st.sampled_from(["none", "step", "given", "missing"]))
def test_one_kernel_takes_each_outcome_where_it_should(seed, count, lead, behind, reference):
    """A combined prior behind the sensor restarts; one model behind it goes model filter by model filter; a
    tracker-less call without references asks for them; otherwise it corrects: the models' probabilities a
    distribution, their NIS finite, the states moved. Told the gains are not PREDICTED, it writes no state."""
    arguments = correction_arguments(seed, count, lead, behind, reference)
    result = correct(arguments)
    expected = {"all": imm._RESTART, "one": imm._MODEL_BY_MODEL}.get(
        behind, imm._NEEDS_REFERENCES if reference == "missing" else imm._CORRECTED)
    assert result[2] == expected
    fresh = correction_arguments(seed, count, lead, behind, reference)
    original = fresh["states"]
    relative = original[:, :3] + lead * original[:, 3:] - arguments["pursuer_position"]  # the prior lines of sight
    np.testing.assert_allclose(arguments["model_relative"], relative, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(result[0], np.linalg.norm(fresh["weights"] @ relative), rtol=1e-12)
    if expected == imm._CORRECTED:
        assert np.isfinite(arguments["nis"]).all()
        assert math.isclose(float(arguments["probabilities"].sum()), 1.0, rel_tol=1e-12)
        assert (arguments["probabilities"] >= 0.0).all()
        assert not np.array_equal(arguments["states"], original)
    else:
        assert_same(arguments["states"], original)
    arguments = correction_arguments(seed, count, lead, behind, reference)
    arguments["predicted_gain"] = False
    result = correct(arguments)
    assert result[2] == (imm._RESTART if behind == "all" else imm._MODEL_BY_MODEL)
    assert_same(arguments["states"], original)


# --- a bearing sequence for the change records ----------------------------------------------------------------


def _bearing(time: float, k: int, pursuer_offset: np.ndarray = np.zeros(3), source: int = 0,
             sign: float = 1.0) -> BearingMeasurement:
    """A bearing of a target near (30, 0, -10) m from a weaving pursuer (sign -1: pointing away from the target)."""
    target = np.array([30.0 + 2.0 * time, 8.0 * math.sin(0.3 * time), -10.0])
    pursuer = np.array([math.sin(1.1 * time), 2.0 * math.cos(0.7 * time), -5.0]) + pursuer_offset
    return BearingMeasurement(time, sign * (target - pursuer) + 0.1 * math.sin(7.0 * k), pursuer + 0.05 * math.cos(5.0 * k),
                              source=source)


def fly_steps(steps, adaptive: bool, position_std: float, projection: GainProjection) -> IMMEstimator:
    """An IMM through a sequence of steps: ("predict", ticks), ("boost", factor), ("bearing", lead) on or off the tick,
    ("again", 0) at the last bearing's stamp, ("neighbour", source), ("behind", 0) a bearing pointing away, ("model
    behind", 0) a bearing after the second model's prediction is moved 50 m behind the pursuer."""
    estimator = IMMEstimator(0.02, standard_models([0.2], 0.04, 0.04), 1e-4 * np.eye(3), projection,
                             pursuer_position_std=position_std,
                             adaptive_noise=AdaptiveNoiseSettings() if adaptive else None)
    estimator.initialize_on_bearing(_bearing(0.0, 0), InitialGuess(30.0, 10.0, np.zeros(3), 5.0))
    last = 0.0
    for k, (kind, value) in enumerate(steps):
        if kind == "predict":
            for _ in range(value):
                estimator.predict()
            continue
        if kind == "boost":
            estimator.process_noise_boost = value
            continue
        time = estimator.time + value if kind == "bearing" else last if kind == "again" else estimator.time
        if kind == "neighbour":
            bearing = _bearing(time, k, np.array([0.0, 6.0 * value, -1.0]), source=value)
        elif kind == "behind":
            bearing = _bearing(time, k, sign=-1.0)
        else:
            bearing = _bearing(time, k)
        if kind == "model behind":
            estimator.set_model_states([(state - (50.0 if j == 1 else 0.0) * np.array([1.0, 0, 0, 0, 0, 0]), covariance)
                                        for j, (state, covariance) in enumerate(zip(estimator._states,
                                                                                    estimator._covariances))])
        estimator.correct(bearing)
        last = time
    return estimator


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
        fly_steps(steps, True, position_std, GainProjection.PREDICTED)
    assert list(imm._imm_correction.signatures) == signatures
