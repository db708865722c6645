"""The IMM's per-tick steps: its combined estimate and its prediction, cheaper, the same results.

- `_combined_estimate` (the estimate's kernel: `_combine_kernel` written into fresh arrays, with the position std)
  is `_combine_kernel` and TargetEstimate.position_std bit for bit, compiled and interpreted;
- `position_std_of` (TargetEstimate.position_std's function, compiled into that kernel) is sqrt(tr P_pp / 3),
  NaN and signed zeros included;
- on random sequences of IMM steps, every estimate handed out stays what it was when handed out (a snapshot:
  later steps never write its arrays), and every new one is the combination of the model filters' current
  states, with the position std its once_property would compute;
- on the same sequences, each prediction uses every model filter's current process-noise factors (adaptive scale
  and boost), however they were changed: through the IMM, on a model filter directly, on its adaptive noise;
- after warmup.warm_up the new kernel is compiled.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from bitwise import assert_same, seeds

from companion.core import _jit
from companion import warmup
from companion.core import imm
from companion.core.estimators import AdaptiveNoiseSettings, AdaptiveProcessNoise, GainProjection, InitialGuess, _predict_kernel
from companion.core.imm import IMMEstimator, combine, standard_models
from companion.core.messages import BearingMeasurement, TargetEstimate, position_std_of

python = _jit.python_function


def stacked_models(seed: int, count: int, exponent: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random model probabilities (count,), states (count, 6) and symmetric PSD covariances (count, 6, 6)."""
    rng = np.random.default_rng(seed)
    factors = rng.normal(size=(count, 6, 6))
    covariances = (factors @ factors.transpose(0, 2, 1) + 1e-3 * np.eye(6)) * 10.0**exponent
    return rng.dirichlet(np.ones(count)), rng.normal(size=(count, 6)) * 10.0, covariances


def rms_position_std(covariance: np.ndarray) -> float:
    """The definition of a position std: sqrt(tr P_pp / 3), the RMS of the three axes' stds (a negative trace of a
    broken filter clipped to 0, Python's max: a NaN trace first stays NaN)."""
    trace = float(covariance[0, 0] + covariance[1, 1] + covariance[2, 2])
    return math.sqrt(max(trace, 0.0) / 3.0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), st.sampled_from([0.0, -0.0])),
                min_size=3, max_size=3))
def test_position_std_of_is_the_rms_of_the_axes(diagonal):
    covariance = np.zeros((6, 6))
    covariance[range(3), range(3)] = diagonal
    with np.errstate(all="ignore"):
        expected = rms_position_std(covariance)
        assert_same(position_std_of(covariance), expected)
        assert_same(imm._position_std(covariance), expected)  # compiled (when numba is there)
        assert_same(TargetEstimate(0.0, np.zeros(3), np.zeros(3), covariance).position_std, expected)


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([1, 2, 3, 5]), st.integers(-4, 6))
def test_combined_estimate_is_the_combination_and_its_std(seed, count, exponent):
    probabilities, states, covariances = stacked_models(seed, count, exponent)
    expected_state, expected_covariance = python(imm._combine_kernel)(probabilities, states, covariances)
    for kernel in (imm._combined_estimate, python(imm._combined_estimate)):
        position, velocity, covariance = np.full(3, np.nan), np.full(3, np.nan), np.full((6, 6), np.nan)
        std = kernel(probabilities, states, covariances, position, velocity, covariance)
        assert_same((position, velocity, covariance), (expected_state[:3], expected_state[3:], expected_covariance))
        assert_same(std, rms_position_std(expected_covariance))


# --- whole IMMs on random sequences of steps -----------------------------------------------------------

STEPS = st.lists(st.one_of(
    st.tuples(st.just("predict"), st.integers(1, 4)),
    st.tuples(st.just("correct"), st.floats(-0.015, 0.0)),  # a bearing on the tick or late
    st.tuples(st.just("imm boost"), st.sampled_from([1.0, 2.5, 30.0])),
    st.tuples(st.just("model boost"), st.tuples(st.integers(0, 2), st.sampled_from([1.0, 0.5, 4.0]))),
    st.tuples(st.just("model scale"), st.tuples(st.integers(0, 2), st.sampled_from([1.0, 3.0, 7.5]))),
    st.tuples(st.just("model adaptive"), st.integers(0, 2)),
    st.tuples(st.just("set states"), st.integers(0, 2**16)),
), min_size=1, max_size=40)


def _bearing(estimator: IMMEstimator, lead: float, k: int) -> BearingMeasurement:
    time = estimator.time + lead
    target = np.array([30.0 + 2.0 * time, 5.0 * math.sin(0.3 * time), -10.0])
    pursuer = np.array([math.sin(1.1 * time), 2.0 * math.cos(0.7 * time), -5.0])
    return BearingMeasurement(time, target - pursuer + 0.05 * math.sin(7.0 * k), pursuer)


def _expected_prediction(estimator: IMMEstimator) -> tuple[np.ndarray, np.ndarray]:
    """Each model filter's own time update (UPLKF.predict's `_predict_kernel` with its current scale and boost)
    on copies of the stacked states."""
    states, covariances = estimator._states.copy(), estimator._covariances.copy()
    for j, model_filter in enumerate(estimator.filters):
        python(_predict_kernel)(model_filter._a, model_filter._q_discrete, model_filter.process_noise_scale,
                                    float(model_filter.process_noise_boost), states[j], covariances[j])
    return states, covariances


@settings(max_examples=150, deadline=None)
@given(STEPS, st.booleans())
def test_estimates_stay_snapshots_and_predictions_take_every_noise_factor(steps, adaptive):
    """After every step one more prediction (checked against each model filter's own, with its factors of the
    moment), then the estimate (checked against the combination of the current states and every estimate handed
    out before, unchanged)."""
    estimator = IMMEstimator(0.02, standard_models([0.2], 0.04, 0.04), 1e-4 * np.eye(3), GainProjection.PREDICTED,
                             pursuer_position_std=0.1, adaptive_noise=AdaptiveNoiseSettings() if adaptive else None)
    estimator.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.2, -0.3]), np.zeros(3)),
                                    InitialGuess(30.0, 10.0, np.zeros(3), 5.0))
    handed_out = []  # (estimate, copies of its arrays and std when handed out)

    def predict(label: str) -> None:
        expected = _expected_prediction(estimator)
        estimator.predict()
        assert_same((estimator._states, estimator._covariances), expected, label)

    for k, (kind, value) in enumerate(steps):
        if kind == "predict":
            for _ in range(value):
                predict(f"step {k}: {kind}")
        elif kind == "correct":
            estimator.correct(_bearing(estimator, value, k))
        elif kind == "imm boost":
            estimator.process_noise_boost = value
        elif kind == "model boost":
            estimator.filters[value[0]].process_noise_boost = value[1]
        elif kind == "model scale":
            noise = estimator.filters[value[0]].adaptive_noise
            if noise is not None:
                noise.scale = value[1]
        elif kind == "model adaptive":  # adaptive noise switched on (at a scale of 2) or off on one model filter
            model_filter = estimator.filters[value]
            if model_filter.adaptive_noise is None:
                noise = AdaptiveProcessNoise(AdaptiveNoiseSettings())
                noise.scale = 2.0
                predict(f"step {k}: before {kind}")  # (the IMM has seen every change but the switch itself)
                model_filter.adaptive_noise = noise
            else:
                model_filter.adaptive_noise = None
        else:
            rng = np.random.default_rng(value)
            estimator.set_model_states([(state + rng.normal(size=6), covariance)
                                        for state, covariance in zip(estimator._states, estimator._covariances)])
        predict(f"after step {k}: {kind}")
        estimate = estimator.estimate
        assert estimator.estimate is estimate  # kept until the next step
        state, covariance = combine(estimator._weights, estimator._states, estimator._covariances)
        assert_same((estimate.time, estimate.position, estimate.velocity, estimate.covariance),
                    (estimator.filters[0].time, state[:3], state[3:], covariance), f"step {k}: {kind}")
        assert_same(estimate.position_std,
                    TargetEstimate(estimate.time, state[:3], state[3:], covariance).position_std, f"step {k}: std")
        handed_out.append((estimate, (estimate.time, estimate.position.copy(), estimate.velocity.copy(),
                                      estimate.covariance.copy(), estimate.position_std)))
        for j, (old, kept) in enumerate(handed_out):
            assert_same((old.time, old.position, old.velocity, old.covariance, old.position_std), kept,
                        f"estimate {j} after step {k}: {kind}")


def test_warm_up_compiles_the_combined_estimate():
    """warmup.warm_up reads the IMMs' estimates: no flight waits for `_combined_estimate` (and `_position_std` in it)."""
    warmup.warm_up()
    if _jit.ENABLED:
        assert imm._combined_estimate.signatures
    else:
        assert python(imm._combined_estimate) is imm._combined_estimate
