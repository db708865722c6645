"""The estimator kernels (companion.core.estimators, imm) against independent references, and a whole flight
compiled against the same flight in plain Python.

- the IMM's posterior model probabilities (seed 004 eq. (21)) against scipy's softmax of ln Lambda + ln c, and
  its mixing (eqs. (17)-(19)) against the textbook sums written out model by model (a model no likely model
  switches to keeps its own estimate);
- the IMM's one-call correction against its model-by-model path (the same kernels composed in Python) on
  sequences with late bearings, adaptive process noise, a neighbour's bearings and a boost;
- a deep copy of an IMM runs on its own stacked states;
- a whole seed-1 flight of the default estimator compiled in this process against the same flight in a
  subprocess with BOF_NO_JIT=1 (the plain-Python kernels): every logged series within 1e-9 relative.
The u-PLKF's update, the pseudo-inverse and the PSD test are checked against the paper's equations and numpy in
tests/test_estimator.py, tests/test_pseudo_inverse.py and tests/test_estimator_cost_paths.py; the IMM's steps in
tests/test_imm.py.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import softmax
from bitwise import assert_close_series, assert_same, seeds

from companion.core import imm
from companion.core.estimators import AdaptiveNoiseSettings, GainProjection, InitialGuess
from companion.core.imm import IMMEstimator, standard_models
from companion.core.messages import BearingMeasurement

ROOT = Path(__file__).resolve().parent.parent


def covariance(seed: int, size: int, exponent: int) -> np.ndarray:
    """A random symmetric positive definite matrix (size, size) of scale 10^exponent."""
    factor = np.random.default_rng(seed).normal(size=(size, size))
    return (factor @ factor.T + 1e-3 * np.eye(size)) * 10.0**exponent


# --- the IMM's steps against their equations ---------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(seeds, st.sampled_from([1, 2, 3, 5]), st.integers(-6, 6), st.integers(0, 2))
def test_posterior_probabilities_are_bayes_rule(seed, count, exponent, restarted):
    """mu^j = Lambda^j c_j / sum_t Lambda^t c_t; a model without a finite likelihood (restarted) gets 0, and with
    no finite likelihood at all the predicted probabilities c stand."""
    rng = np.random.default_rng(seed)
    log_likelihoods = rng.normal(size=count) * 10.0 ** (exponent / 3)
    log_likelihoods[:min(restarted, count)] = -math.inf
    weights = rng.dirichlet(np.ones(count))
    posterior = imm._posterior_probabilities(log_likelihoods, weights)
    if restarted >= count:
        np.testing.assert_array_equal(posterior, weights)
        return
    np.testing.assert_allclose(posterior, softmax(log_likelihoods + np.log(weights)), rtol=1e-12, atol=1e-300)
    assert math.isclose(float(posterior.sum()), 1.0, rel_tol=1e-14)


def textbook_mixing(probabilities, transition, states, covariances):
    """IMM mixing written out: c_j = sum_i p_ij mu_i, mu_i|j = p_ij mu_i / c_j, x0_j = sum_i mu_i|j x_i,
    P0_j = sum_i mu_i|j (P_i + (x_i - x0_j)(x_i - x0_j)^T); a model with c_j = 0 keeps its own estimate."""
    count = len(probabilities)
    predicted = np.array([sum(transition[i, j] * probabilities[i] for i in range(count)) for j in range(count)])
    mixed, mixed_covariances = np.empty_like(states), np.empty_like(covariances)
    for j in range(count):
        if predicted[j] <= 0.0:
            mixed[j], mixed_covariances[j] = states[j], covariances[j]
            continue
        weights = [transition[i, j] * probabilities[i] / predicted[j] for i in range(count)]
        mixed[j] = sum(w * x for w, x in zip(weights, states))
        mixed_covariances[j] = sum(w * (p + np.outer(x - mixed[j], x - mixed[j]))
                                   for w, x, p in zip(weights, states, covariances))
    return predicted, mixed, mixed_covariances


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([2, 3, 5]), st.integers(-3, 6), st.booleans())
def test_mixing_is_the_textbook_sums(seed, count, exponent, unreachable):
    rng = np.random.default_rng(seed)
    probabilities = rng.dirichlet(np.ones(count))
    transition = imm.markov_matrix(count, 0.9)
    states = rng.normal(size=(count, 6)) * 10.0
    covariances = np.array([covariance(seed + j, 6, exponent) for j in range(count)])
    if unreachable:  # a model no likely model switches to (c_j = 0)
        transition[:, -1] = 0.0
        transition[-1, -1] = 1.0
        probabilities[-1] = 0.0
        probabilities /= probabilities.sum()
    predicted, mixed, mixed_covariances = imm._mix_kernel(probabilities, transition, states, covariances)
    expected = textbook_mixing(probabilities, transition, states, covariances)
    np.testing.assert_allclose(predicted, expected[0], rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(mixed, expected[1], rtol=0.0, atol=1e-12 * float(np.abs(states).max()))
    scale = float(np.abs(expected[2]).max())
    np.testing.assert_allclose(mixed_covariances, expected[2], rtol=0.0, atol=1e-12 * scale)


# --- the IMM's one-call correction is its model-by-model correction -----------------------------------


def late_and_shared_bearings(seed: int, steps: int = 600) -> list[list[BearingMeasurement]]:
    """Per 50 Hz tick, the bearings of a turning target seen from a weaving pursuer with noisy own position:
    on the tick, some late (up to 0.15 s), and every fifth tick a neighbour's (source 1)."""
    rng = np.random.default_rng(seed)
    ticks = []
    for k in range(steps):
        t = 0.02 * k
        bearings = []
        for stamp, source, offset in ((t, 0, np.zeros(3)), (t - rng.uniform(0.0, 0.15), 0, np.zeros(3)),
                                      (t, 1, np.array([0.0, 6.0, -1.0]))):
            if (source == 1 and k % 5) or (stamp != t and k % 3):
                continue
            heading = 0.3 * stamp
            target = np.array([20.0 * np.sin(heading), 20.0 * (1.0 - np.cos(heading)), -10.0])
            pursuer = np.array([-12.0 + np.sin(1.1 * stamp), 2.0 * np.cos(0.7 * stamp), -5.0]) + offset
            direction = target - pursuer
            direction = direction / np.linalg.norm(direction) + rng.normal(0.0, 0.01, 3)
            bearings.append(BearingMeasurement(stamp, direction, pursuer + rng.normal(0.0, 0.1, 3), source=source))
        ticks.append(bearings)
    return ticks


@pytest.mark.parametrize("adaptive", [False, True])
def test_one_call_correction_is_the_model_by_model_correction(adaptive, monkeypatch):
    def run(one_call: bool) -> list:
        estimator = IMMEstimator(0.02, standard_models([0.2], 0.04, 0.04), 1e-4 * np.eye(3), GainProjection.PREDICTED,
                                 pursuer_position_std=0.1, adaptive_noise=AdaptiveNoiseSettings() if adaptive else None)
        if one_call:  # count the corrections the one call made (and those with the tracker's step in it)
            def counting(*arguments):
                result = kernel(*arguments)
                if result[2] == imm._CORRECTED:
                    calls.append(bool(arguments[-1][imm._TRACK_STEP]))
                return result
            monkeypatch.setattr(imm, "_imm_correction", counting)
        else:  # the same kernel told the gains are not PREDICTED: every correction model filter by model filter
            def model_by_model(*arguments):
                switches = arguments[-1].copy()
                switches[imm._PREDICTED_GAIN] = False
                return kernel(*arguments[:-1], switches)
            monkeypatch.setattr(imm, "_imm_correction", model_by_model)
        ticks = late_and_shared_bearings(11)
        estimator.initialize_on_bearing(ticks[0][0], InitialGuess(15.0, 10.0, np.zeros(3), 5.0))
        rows = []
        for k, bearings in enumerate(ticks[1:]):
            estimator.predict()
            if k == 300:
                estimator.process_noise_boost = 3.0
            for bearing in bearings:
                report = estimator.correct(bearing)
                corrections.append(1)
                rows.append((report.innovation_angle, report.innovation, report.innovation_covariance))
            estimate = estimator.estimate
            rows.append((estimate.position, estimate.velocity, estimate.covariance, estimator.model_probabilities,
                         estimator.motion_probabilities))
        return rows

    kernel = imm._imm_correction
    calls, corrections = [], []
    one_call = run(True)
    assert len(calls) > 0.9 * len(corrections)  # the one-call path took (nearly) every correction
    assert sum(calls) > 0.5 * len(calls)  # most with the shared tracker's step inside (the rest: late bearings)
    each = run(False)
    assert len(one_call) == len(each)
    for k, (a, b) in enumerate(zip(one_call, each)):  # the same to rounding (Python's ** and numba's x * x differ)
        assert len(a) == len(b)
        for j, (x, y) in enumerate(zip(a, b)):
            assert_close_series(x, y, f"row {k}[{j}]")


def test_a_copied_imm_runs_on_its_own_stacked_states():
    """The model filters' states are rows of the IMM's stacked arrays: a deep copy (or a pickle) keeps that
    binding, so the copy continues exactly as the original and leaves it alone."""
    import copy
    import pickle

    ticks = late_and_shared_bearings(5, steps=200)
    original = IMMEstimator(0.02, standard_models([0.2], 0.04, 0.04), 1e-4 * np.eye(3), GainProjection.PREDICTED,
                            pursuer_position_std=0.1)
    original.initialize_on_bearing(ticks[0][0], InitialGuess(15.0, 10.0, np.zeros(3), 5.0))
    copies = []
    for k, bearings in enumerate(ticks[1:]):
        if k == 100:
            copies = [copy.deepcopy(original), pickle.loads(pickle.dumps(original))]
        for estimator in [original, *copies]:
            estimator.predict()
            for bearing in bearings:
                estimator.correct(bearing)
        for duplicate in copies:
            for model_filter, row in zip(duplicate.filters, duplicate._states):
                assert np.shares_memory(model_filter.state_and_covariance[0], row)
            assert not np.shares_memory(duplicate._states, original._states)
            assert_same(duplicate.estimate.position, original.estimate.position)
            assert_same(duplicate.estimate.covariance, original.estimate.covariance)
    assert copies


# --- a whole flight, compiled and interpreted ---------------------------------------------------------

_FLIGHT = """
import sys
import numpy as np
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies.closed_loop import simulate
scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
np.savez(sys.argv[1], **simulate(scenario, vehicle, seed=1).series)
"""


def test_a_flight_is_the_same_compiled_and_interpreted(tmp_path):
    """constant_velocity, seed 1 (the default IMM): every logged series of the flight flown here with the
    compiled kernels (when numba is installed) is the one a BOF_NO_JIT=1 interpreter flies, within 1e-9 relative
    (the two round some operations differently in the last bit)."""
    from interfaces.scenario import SCENARIOS_DIR, load_scenario
    from studies.closed_loop import simulate

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    assert scenario.estimator.kind == "imm"
    here = simulate(scenario, vehicle, seed=1).series
    output = tmp_path / "interpreted.npz"
    environment = dict(os.environ, BOF_NO_JIT="1", PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    subprocess.run([sys.executable, "-c", _FLIGHT, str(output)], check=True, cwd=ROOT, env=environment, timeout=600)
    there = np.load(output)
    assert sorted(there.files) == sorted(here)
    for name in here:
        assert_close_series(here[name], there[name], name)

