"""The estimator kernels (companion.core._jit) give the same results compiled and interpreted, bit for bit.

Four kinds of evidence:
- every kernel, compiled by numba, against its own Python function (`kernel.py_func`) on random inputs
  (hypothesis). A kernel's Python function calls the other kernels compiled, so each function's own
  arithmetic is what a test compares; the leaves (BLAS and LAPACK calls, the rare branches in object mode)
  have their own tests. Without numba the kernels are their Python functions and these comparisons are
  trivially equal: the flight test below then still compares the two interpreters' runs;
- the sums that the kernels write out term by term against the vectorised numpy forms they replace
  (numpy's reductions: left to right over a row of 3, its pairwise sum over 9 terms), and the clipping of
  the restart test against Python's min and max, NaN included;
- the IMM's one-call correction against its model-by-model path (the same kernels composed in Python) on
  sequences with late bearings, adaptive process noise, a neighbour's bearings and a boost;
- a whole seed-1 flight of the default estimator compiled in this process against the same flight in a
  subprocess with BOF_NO_JIT=1 (the plain-Python kernels): every logged series equal.
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
from hypothesis.extra.numpy import arrays
from bitwise import assert_same, seeds
from paper_reference import floats, symmetric_with_eigenvalues, unit_vectors
from scipy.stats import special_ortho_group

from companion.core import _jit
from companion.core import estimators as uplkf
from companion.core import imm
from companion.core.estimators import AdaptiveNoiseSettings, GainProjection, InitialGuess, UPLKF
from companion.core.imm import IMMEstimator, standard_models
from companion.core.messages import BearingMeasurement

ROOT = Path(__file__).resolve().parent.parent
python = _jit.python_function


def both(kernel, *args):
    """(compiled result, Python result) on copies of the arguments (kernels may write in place), and the copies."""
    compiled_args = [np.array(a) if isinstance(a, np.ndarray) else a for a in args]
    python_args = [np.array(a) if isinstance(a, np.ndarray) else a for a in args]
    return kernel(*compiled_args), python(kernel)(*python_args), compiled_args, python_args


def covariance(seed: int, size: int, exponent: int) -> np.ndarray:
    """A random symmetric positive definite matrix (size, size) of scale 10^exponent."""
    factor = np.random.default_rng(seed).normal(size=(size, size))
    return (factor @ factor.T + 1e-3 * np.eye(size)) * 10.0**exponent


def _call_dgesv(matrix: np.ndarray, rhs: np.ndarray):
    return _jit.lapack_dgesv(matrix, rhs)


def _call_dpotrf(matrix: np.ndarray):
    return _jit.lapack_dpotrf(matrix)


# the LAPACK bindings run compiled inside a kernel (called from Python, lapack_dgesv is scipy's wrapper itself)
compiled_dgesv, compiled_dpotrf = _jit.jit(_call_dgesv), _jit.jit(_call_dpotrf)


# --- the leaves ------------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(unit_vectors(), arrays(np.float64, 3, elements=floats(-1e3, 1e3)).filter(lambda v: float(v @ v) > 1e-6))
def test_projector_and_unit_vector(direction, vector):
    assert_same(*both(uplkf._projector, direction)[:2])
    assert_same(*both(uplkf._unit_vector, vector)[:2])


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, (3, 3), elements=floats(-10.0, 10.0)), st.integers(-6, 6))
def test_lapack_solve(matrix, exponent):
    """The compiled dgesv call is scipy's dgesv: LU factors, pivots, solution and info (singular included)."""
    matrix = matrix * 10.0**exponent
    rhs = np.arange(9.0).reshape(3, 3) - 4.0
    compiled, interpreted = compiled_dgesv(matrix, rhs), _jit.lapack_dgesv(matrix, rhs)
    assert compiled[3] == interpreted[3]
    assert_same(tuple(np.asarray(x, dtype=float) for x in compiled[:3]),
                tuple(np.asarray(x, dtype=float) for x in interpreted[:3]))
    assert_same(*both(uplkf._solve_identity, matrix)[:2])


def test_lapack_solve_of_an_exactly_singular_matrix():
    singular = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]])
    compiled, interpreted = both(uplkf._solve_identity, singular)[:2]
    assert compiled[2] is False and interpreted[2] is False and compiled[1] == interpreted[1] == 0.0


@settings(max_examples=300, deadline=None)
@given(seeds, arrays(np.float64, 6, elements=floats(-1.0, 1.0)), st.integers(-8, 8),
       st.sampled_from(["any", "psd_singular", "tiny_negative"]))
def test_positive_semidefinite_check(seed, values, exponent, kind):
    """Cholesky (compiled dpotrf) and its eigvalsh fallback (object mode) decide as the Python function."""
    matrix = symmetric_with_eigenvalues(seed, values, exponent, kind)
    assert uplkf._is_positive_semidefinite(matrix) == python(uplkf._is_positive_semidefinite)(matrix)
    factor, info = compiled_dpotrf(matrix)
    reference, reference_info = _jit.lapack_dpotrf(matrix)
    assert info == reference_info
    if info == 0:
        assert_same(np.tril(factor), np.tril(reference))


@settings(max_examples=300, deadline=None)
@given(seeds, st.integers(-40, 60), floats(0.0, 4.0))
def test_pseudo_inverse_both_branches(seed, exponent, spread):
    """Rank-2 S = Q diag(0, l1, l2) Q^T from far below to far above unit scale: the shortcut (compiled
    dgesv) inside the band, the general form (object mode: scipy's null_space, numpy's pinv) outside."""
    rotation = special_ortho_group.rvs(3, random_state=np.random.default_rng(seed))
    largest = 10.0**exponent
    matrix = rotation @ np.diag([0.0, largest, largest * 10.0**-spread]) @ rotation.T
    matrix = 0.5 * (matrix + matrix.T)
    assert_same(*both(uplkf._projector_pseudo_inverse, matrix, np.ascontiguousarray(rotation[:, 0]))[:2])


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, 3, elements=floats(-1.0, 1.0)), arrays(np.float64, 3, elements=floats(-1e3, 1e3)),
       st.sampled_from([1.0, 1e3, 1e6, 1e9]))
def test_limit_range(direction, pursuer, distance):
    target = pursuer + distance * direction
    compiled, interpreted = both(uplkf.limit_range, target, pursuer)[:2]
    assert_same(compiled, interpreted)


@settings(max_examples=150, deadline=None)
@given(seeds, arrays(np.float64, (6, 6), elements=st.integers(-8, 8)))
def test_estimate_stds_are_numpys_trace(seed, exponents):
    """TargetEstimate's position_std / velocity_std add the diagonal term by term: the same float as
    sqrt(max(np.trace(block), 0) / 3) (numpy's trace sums left to right), negative traces clipped to 0."""
    from companion.core.messages import TargetEstimate
    covariance = np.random.default_rng(seed).standard_normal((6, 6)) * 10.0**exponents
    estimate = TargetEstimate(0.0, np.zeros(3), np.zeros(3), covariance)
    assert estimate.position_std == math.sqrt(max(float(np.trace(covariance[:3, :3])), 0.0) / 3.0)
    assert estimate.velocity_std == math.sqrt(max(float(np.trace(covariance[3:, 3:])), 0.0) / 3.0)


@given(seeds, st.integers(-4, 8), unit_vectors(), floats(-0.5, 0.5), st.booleans())
def test_joseph_update(seed, exponent, direction, lead, at_tick):
    rng = np.random.default_rng(seed)
    prior = covariance(seed, 6, exponent)
    gain = rng.normal(size=(6, 3))
    measurement = covariance(seed + 1, 3, exponent - 2)
    projection = np.eye(3) - np.outer(direction, direction)
    assert_same(*both(uplkf._joseph_update, prior, gain, projection, measurement, 0.0 if at_tick else lead)[:2])


# --- the u-PLKF's update ---------------------------------------------------------------------------


def predict_inputs(seed: int, exponent: int, turn_rate: float):
    """A u-PLKF time update's inputs: the coordinated-turn A (6, 6) over 0.02 s, B Q B^T for Q = 0.04 I, a state (6,)
    of tens of metres and a covariance of scale 10^exponent (6, 6)."""
    a, b = uplkf.coordinated_turn_matrices(0.02, turn_rate)
    noise = b @ (0.04 * np.eye(3)) @ b.T
    state = np.random.default_rng(seed).normal(size=6) * 30.0
    return a, noise, state, covariance(seed, 6, exponent)


@settings(max_examples=150, deadline=None)
@given(seeds, st.integers(-3, 6), floats(-0.5, 0.5), st.sampled_from([1.0, 1.7]), st.sampled_from([1.0, 4.0]))
def test_predict(seed, exponent, turn_rate, scale, boost):
    a, noise, state, p = predict_inputs(seed, exponent, turn_rate)
    _, _, compiled_args, python_args = both(uplkf._predict_kernel, a, noise, scale, boost, state, p)
    assert_same(tuple(compiled_args[4:]), tuple(python_args[4:]))


def correction_arguments(seed: int, exponent: int, lead: float, late: bool, use_predicted: bool, position_noise: bool,
                         noise_scale: float, reference_offset: float | None) -> tuple:
    """`_correct_kernel`'s arguments for a random prior and geometry (the bearing noise_scale rad off, the gain's own
    position reference_offset m from the bearing's; None: no reference)."""
    rng = np.random.default_rng(seed)
    state = np.concatenate([rng.normal(size=3) * 40.0, rng.normal(size=3) * 3.0])
    pursuer = rng.normal(size=3) * 5.0
    relative = state[:3] + lead * state[3:] - pursuer
    direction = relative / np.linalg.norm(relative) + rng.normal(size=3) * noise_scale
    direction = direction / math.sqrt(float(direction @ direction))
    reference = pursuer + rng.normal(size=3) * (0.0 if reference_offset is None else reference_offset)
    lead_noise = covariance(seed + 2, 3, -3) if late else np.zeros((3, 3))
    return (state, covariance(seed, 6, exponent), relative, math.sqrt(float(relative.dot(relative))), direction, reference,
            reference_offset is not None, use_predicted, lead, late, 1e-4 * np.eye(3), position_noise, 0.01, lead_noise,
            pursuer)


@settings(max_examples=200, deadline=None)
@given(seeds, st.integers(-3, 6), floats(-0.3, 0.3), st.booleans(), st.booleans(), st.booleans(),
       st.sampled_from([0.0, 0.01, 1.0]), st.sampled_from([None, 0.0, 0.1, 1e3]))
def test_correct(seed, exponent, lead, late, use_predicted, position_noise, noise_scale, reference_offset):
    """The whole correction, in place, with its returned innovation, S and S^+ (noisy bearings reach the
    general pseudo-inverse and the Joseph form; a far reference the gain's fallback to the bearing's position)."""
    arguments = correction_arguments(seed, exponent, lead if late else 0.0, late, use_predicted, position_noise, noise_scale,
                                     reference_offset)
    compiled, interpreted, compiled_args, python_args = both(uplkf._correct_kernel, *arguments)
    assert_same(compiled, interpreted)
    assert_same(tuple(compiled_args[:2]), tuple(python_args[:2]))


# --- the IMM steps ---------------------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(st.one_of(floats(-1e3, 1e3), st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0])),
       st.one_of(floats(0.0, 1e3), st.sampled_from([math.nan, math.inf, 0.0, 1e-13])))
def test_clipped_cosine_is_pythons_min_and_max(dot, length):
    expected = min(max(dot / max(length, 1e-12), -1.0), 1.0)
    for function in (uplkf._clipped_cosine, python(uplkf._clipped_cosine)):
        assert_same(function(dot, length), expected)


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 7), floats(0.0, 1.0), floats(0.1, 5.0), st.one_of(floats(-1.0, 5.0), st.just(math.nan)))
def test_markov_matrix(count, stay, stay_time, interval):
    assert_same(*both(imm.markov_matrix, count, stay)[:2])
    compiled, interpreted = both(imm._markov_matrix_over, count, stay, stay_time, interval)[:2]
    assert_same(compiled, interpreted)
    if count > 1:  # the IMM's p_ii = stay^(max(interval, 0) / stay_time), in Python's float arithmetic
        assert_same(np.diag(interpreted), np.full(count, stay ** (max(interval, 0.0) / stay_time)))


def imm_inputs(seed: int, count: int, exponent: int):
    """Model probabilities (count,), Markov matrix, states (count, 6), covariances (count, 6, 6)."""
    rng = np.random.default_rng(seed)
    probabilities = rng.dirichlet(np.ones(count))
    states = rng.normal(size=(count, 6)) * 10.0
    covariances = np.array([covariance(seed + j, 6, exponent) for j in range(count)])
    return probabilities, imm.markov_matrix(count, 0.9), states, covariances


def old_mix(probabilities, transition, states, covariances):
    """The vectorised mixing the kernel replaced (np.matmul over the stacked models)."""
    predicted = probabilities @ transition
    everyone = bool((predicted > 0.0).all())
    weights = transition * probabilities[:, None] / (predicted if everyone else np.where(predicted > 0.0, predicted, 1.0))[None, :]
    if not everyone:
        for j in np.flatnonzero(predicted <= 0.0):
            weights[:, j] = 0.0
            weights[j, j] = 1.0
    mixed = weights.T @ states
    count, size = states.shape
    mixed_covariances = (weights.T @ covariances.reshape(count, size * size)).reshape(count, size, size)
    spread = states[None, :, :] - mixed[:, None, :]
    mixed_covariances += np.matmul((spread * weights.T[:, :, None]).transpose(0, 2, 1), spread)
    return predicted, mixed, mixed_covariances


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([2, 3, 5]), st.integers(-3, 6), st.booleans())
def test_mix_and_combine(seed, count, exponent, unreachable):
    probabilities, transition, states, covariances = imm_inputs(seed, count, exponent)
    if unreachable:  # a model no likely model switches to (c_j = 0): it keeps its own estimate
        transition[:, -1] = 0.0
        transition[-1, -1] = 1.0
        probabilities[-1] = 0.0
        probabilities /= probabilities.sum()
    compiled, interpreted = both(imm._mix_kernel, probabilities, transition, states, covariances)[:2]
    assert_same(compiled, interpreted)
    assert_same(interpreted, old_mix(probabilities, transition, states, covariances))
    _, _, compiled_args, python_args = both(imm._mix_into, probabilities, transition, states, covariances)
    assert_same(tuple(compiled_args[2:]), tuple(python_args[2:]))
    assert_same(*both(imm._combine_kernel, probabilities, states, covariances)[:2])


def old_likelihoods(innovations, covariances, scales, null_directions):
    """The vectorised rank-2 likelihoods the kernel replaced (numpy's reductions over the stacked models)."""
    e1 = covariances[:, 0, 0] + covariances[:, 1, 1] + covariances[:, 2, 2]
    e2 = 0.5 * (e1 * e1 - (covariances * covariances).sum(axis=(1, 2)))
    along = (null_directions * innovations).sum(axis=1)
    quadratic = (np.matmul(covariances, innovations[:, :, None])[:, :, 0] * innovations).sum(axis=1)
    result = []
    for k, (e1_k, e2_k, along_k, quadratic_k, scale_k) in enumerate(zip(e1.tolist(), e2.tolist(), along.tolist(),
                                                                        quadratic.tolist(), scales.tolist())):
        if not e2_k > 0.0:
            result.append(-math.inf)
            continue
        nis = (e1_k * (float(innovations[k] @ innovations[k]) - along_k * along_k) - quadratic_k) / e2_k
        value = -0.5 * (nis + 2.0 * math.log(2.0 * math.pi) + math.log(e2_k)) + 2.0 * math.log(scale_k) if scale_k > 0.0 else -math.inf
        result.append(float(value) if math.isfinite(value) else -math.inf)
    return np.array(result)


def old_posterior(log_likelihoods, weights):
    """The list arithmetic of the model probabilities the kernel replaced (seed 004 eq. (21))."""
    log_posterior = [ll + math.log(c) if math.isfinite(ll) and c > 0.0 else -math.inf
                     for ll, c in zip(log_likelihoods.tolist(), weights.tolist())]
    peak = max(log_posterior)
    if peak == -math.inf:
        return weights.copy()
    posterior = [math.exp(value - peak) for value in log_posterior]
    total = sum(posterior)
    return np.array([value / total for value in posterior])


@settings(max_examples=200, deadline=None)
@given(seeds, st.sampled_from([1, 3, 5]), st.integers(-6, 8), st.booleans())
def test_likelihoods_combined_innovation_and_probabilities(seed, count, exponent, degenerate):
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    projectors = np.eye(3)[None] - directions[:, :, None] * directions[:, None, :]
    covariances = np.array([p @ covariance(seed + k, 3, exponent) @ p for k, p in enumerate(projectors)])
    if degenerate:
        covariances[0] = 0.0  # rank 0: no likelihood
    innovations = np.array([p @ rng.normal(size=3) for p in projectors]) * 10.0 ** (exponent / 2)
    scales = rng.uniform(0.0 if degenerate else 1.0, 50.0, count)
    compiled, interpreted = both(imm._rank2_log_likelihoods_kernel, innovations, covariances, scales, directions)[:2]
    assert_same(compiled, interpreted)
    assert_same(interpreted, old_likelihoods(innovations, covariances, scales, directions))
    weights = rng.dirichlet(np.ones(count))
    relative = rng.normal(size=3) * 20.0
    assert_same(*both(imm._combined_innovation, weights, innovations, covariances, relative,
                      math.sqrt(float(relative @ relative)))[:2])
    for log_likelihoods in (interpreted, np.full(count, -math.inf)):
        compiled, interpreted_posterior = both(imm._posterior_probabilities, log_likelihoods, weights)[:2]
        assert_same(compiled, interpreted_posterior)
        assert_same(interpreted_posterior, old_posterior(log_likelihoods, weights))


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([3, 5]), floats(-0.3, 0.3), st.booleans())
def test_prior_lines_of_sight(seed, count, lead, behind):
    """The models' lines of sight as the IMM summed them and as each model filter's correct takes them."""
    rng = np.random.default_rng(seed)
    states = rng.normal(size=(count, 6)) * 20.0
    weights = rng.dirichlet(np.ones(count))
    pursuer = rng.normal(size=3)
    direction = rng.normal(size=3)
    direction /= math.sqrt(float(direction @ direction))
    # every model ahead of the sensor, near the bearing; with `behind` the first one behind it
    states[:, :3] = pursuer + 30.0 * direction + rng.normal(size=(count, 3)) - lead * states[:, 3:]
    if behind:
        states[0, :3] = pursuer - 10.0 * direction - lead * states[0, 3:]
    for restart_when_behind in (True, False):
        outputs = (np.full((count, 3), np.nan), np.full(count, np.nan), np.full(count, np.nan), np.full(3, np.nan))
        compiled, interpreted, compiled_args, python_args = both(
            imm._prior_lines_of_sight, states, weights, lead, pursuer, direction, restart_when_behind, *outputs)
        assert_same(compiled, interpreted)
        assert_same(tuple(compiled_args[6:]), tuple(python_args[6:]))  # the lines of sight it writes
        model_relative, ranges, model_ranges, relative = python_args[6:]
        predicted_range, cos_angle, every_model_corrects = interpreted
        expected_relative = states[:, :3] + lead * states[:, 3:] - pursuer
        assert_same(model_relative, expected_relative)
        assert_same(ranges, np.sqrt((expected_relative * expected_relative).sum(axis=1)))
        restarts = []
        for j, row in enumerate(expected_relative):  # UPLKF.correct's own formulas
            row_range = math.sqrt(float(row.dot(row)))
            assert_same(model_ranges[j], row_range)
            cosine = min(max(float(direction @ row / max(row_range, 1e-12)), -1.0), 1.0)
            restarts.append(restart_when_behind and (cosine <= 0.0 or row_range < 1e-6))
        assert every_model_corrects == (not any(restarts))
        assert every_model_corrects == (not (behind and restart_when_behind))
        assert_same(relative, weights @ expected_relative)
        assert_same(cos_angle, min(max(float(direction @ relative / max(predicted_range, 1e-12)), -1.0), 1.0))


def imm_bearing(seed: int, states: np.ndarray, probabilities: np.ndarray, lead: float, late: bool, noise_scale: float):
    """A bearing for an IMM correction test: (its generator, the pursuer position (3,), a unit direction that is
    the first model's line of sight plus noise of noise_scale, the lead (0 unless late), the prior lines of sight
    (model_relative (n, 3), ranges (n,), model_ranges (n,), relative (3,)) as imm._prior_lines_of_sight writes
    them, the combined prior's range)."""
    count = states.shape[0]
    rng = np.random.default_rng(seed)
    pursuer = rng.normal(size=3)
    direction = rng.normal(size=3) * noise_scale + states[0, :3] - pursuer
    direction /= math.sqrt(float(direction @ direction))
    lead = lead if late else 0.0
    lines_of_sight = np.empty((count, 3)), np.empty(count), np.empty(count), np.empty(3)
    predicted_range = imm._prior_lines_of_sight(states, probabilities, lead, pursuer, direction, True, *lines_of_sight)[0]
    return rng, pursuer, direction, lead, lines_of_sight, predicted_range


@settings(max_examples=100, deadline=None)
@given(seeds, st.sampled_from([3, 5]), st.integers(-2, 4), floats(-0.3, 0.3), st.booleans(), st.sampled_from([0.0, 0.01, 1.0]))
def test_predict_models_and_whole_imm_correction(seed, count, exponent, lead, late, noise_scale):
    probabilities, _, states, covariances = imm_inputs(seed, count, exponent)
    transitions = np.array([uplkf.coordinated_turn_matrices(0.02, 0.1 * j)[0] for j in range(count)])
    noises = np.array([0.01 * (j + 1) * np.eye(6) for j in range(count)])
    factors = np.linspace(1.0, 2.0, count)
    _, _, compiled_args, python_args = both(imm._predict_models, transitions, noises, factors, factors[::-1].copy(),
                                            states, covariances)
    assert_same(tuple(compiled_args[4:]), tuple(python_args[4:]))
    rng, pursuer, direction, lead, lines_of_sight, predicted_range = imm_bearing(seed, states, probabilities, lead,
                                                                               late, noise_scale)
    model_relative, ranges, model_ranges, relative = lines_of_sight
    references = pursuer + rng.normal(size=(count, 3)) * 0.1
    arguments = (states, covariances, model_relative, ranges, model_ranges, direction, references, True, lead, late,
                 np.array([1e-4 * np.eye(3)] * count), True, 0.01,
                 np.array([covariance(seed + j, 3, -3) for j in range(count)]), pursuer, probabilities, relative,
                 predicted_range, 0.98, 1.0, 0.2, True, np.full(count, np.nan), np.full(count, np.nan))
    written = (0, 1, 15, 22, 23)  # states, covariances, weights (the next c), nis, probabilities
    compiled, interpreted, compiled_args, python_args = both(imm._imm_correct_kernel, *arguments)
    assert_same(compiled, interpreted)
    assert_same(tuple(compiled_args[k] for k in written), tuple(python_args[k] for k in written))
    assert np.isfinite(python_args[22]).all() and math.isclose(float(python_args[23].sum()), 1.0)
    # one reference (1, 3) for every model (their shared own-position tracker) is that row repeated per model
    one = both(imm._imm_correct_kernel, *arguments[:6], references[:1], *arguments[7:])
    repeated = both(imm._imm_correct_kernel, *arguments[:6], np.repeat(references[:1], count, axis=0), *arguments[7:])
    for (result, args), (expected, expected_args) in zip((one[0::2], one[1::2]), (repeated[0::2], repeated[1::2])):
        assert_same(result, expected)
        assert_same(tuple(args[k] for k in written), tuple(expected_args[k] for k in written))


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
                    calls.append(arguments[15])
                return result
            monkeypatch.setattr(imm, "_imm_correction", counting)
        else:  # the same kernel told the gains are not PREDICTED: every correction model filter by model filter
            monkeypatch.setattr(imm, "_imm_correction", lambda *arguments: kernel(*arguments[:7], False, *arguments[8:]))
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
    for k, (a, b) in enumerate(zip(one_call, each)):
        assert_same(tuple(np.asarray(x, dtype=float) for x in a), tuple(np.asarray(x, dtype=float) for x in b), f"row {k}")


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
    compiled kernels (when numba is installed) equals the one a BOF_NO_JIT=1 interpreter flies."""
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
        assert_same(here[name], there[name], name)
