"""The estimator kernels that write into scratch arrays (no array per step) give the bits of the kernels
they replaced, compiled and interpreted.

The reference is a verbatim copy of the kernels before the change (tests/old_kernels17.py),
run the same way as the kernel under test (compiled when numba is installed, plain Python otherwise or with
BOF_NO_JIT=1); each new kernel is also run as its own Python function (`python_function`: its arithmetic
interpreted, the kernels it calls compiled). Random priors, geometries and model sets (hypothesis), the rare
branches included: late bearings, a reference far off, noisy bearings (the general pseudo-inverse, the Joseph
form), adaptive scales and boosts, a model with c_j = 0, no finite likelihood.
"""

from __future__ import annotations

import math

import numpy as np
import old_kernels17 as old
from bitwise import assert_same, seeds
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, unit_vectors
from test_estimator_kernels import correction_arguments, covariance, imm_bearing, imm_inputs, predict_inputs

from companion.core import _jit
from companion.core import estimators as uplkf
from companion.core import imm

python = _jit.python_function


def copies(args):
    return [np.array(a) if isinstance(a, np.ndarray) else a for a in args]


def outcome(function, *args):
    """function(*args), or the (type, message) of what it raised."""
    try:
        return function(*args)
    except Exception as error:  # noqa: BLE001 - the error itself is the outcome compared
        return type(error), str(error)


def against_old(new_kernel, old_kernel, *args):
    """(the old kernel's result and arguments after the call) == the new kernel's, compiled and as its Python
    function, each on its own copies of the arguments; returns the old kernel's (result, arguments)."""
    expected_args = copies(args)
    expected = old_kernel(*expected_args)
    for kernel in (new_kernel, python(new_kernel)):
        actual_args = copies(args)
        assert_same(kernel(*actual_args), expected)
        assert_same(tuple(actual_args), tuple(expected_args), "arguments")
    return expected, expected_args


@settings(max_examples=150, deadline=None)
@given(seeds, st.integers(-6, 10))
def test_lapack_into_bindings_are_the_allocating_ones(seed, exponent):
    """dgesv and dpotrf into the caller's (Fortran-ordered) arrays: the LU factors, pivots, solution, Cholesky factor
    and info of `lapack_dgesv` and `lapack_dpotrf`, inside a kernel and from Python."""
    rng = np.random.default_rng(seed)
    matrix = rng.normal(size=(3, 3)) * 10.0**exponent
    spd = covariance(seed, 6, exponent)
    indefinite = spd - 2.0 * np.linalg.eigvalsh(spd)[-1] * np.eye(6)

    @_jit.jit
    def solve(matrix, rhs, factors, pivots, solution):
        return _jit.lapack_dgesv_into(matrix, rhs, factors, pivots, solution)

    @_jit.jit
    def solve_allocating(matrix, rhs):
        return _jit.lapack_dgesv(matrix, rhs)

    @_jit.jit
    def factor(matrix, out):
        return _jit.lapack_dpotrf_into(matrix, out)

    @_jit.jit
    def factor_allocating(matrix):
        return _jit.lapack_dpotrf(matrix)

    for kernel in (solve, python(solve)):
        factors, pivots, solution = np.empty((3, 3)).T, np.empty(3, dtype=np.int32), np.empty((3, 3)).T
        info = kernel(matrix, np.eye(3), factors, pivots, solution)
        lu, piv, x, expected_info = solve_allocating(matrix, np.eye(3))
        assert info == expected_info
        assert_same((factors, solution), (lu, x))
        assert np.array_equal(pivots, piv)
    for kernel in (factor, python(factor)):
        for target in (spd, indefinite):
            out = np.empty((6, 6)).T
            info = kernel(target, out)
            expected, expected_info = factor_allocating(target)
            assert info == expected_info
            lower = np.tril_indices(6)
            assert_same(out[lower], expected[lower])  # dpotrf leaves the strict upper triangle undefined


@settings(max_examples=150, deadline=None)
@given(seeds, st.integers(-12, 60), unit_vectors(), st.sampled_from([1.0, 1e-8, 1e8]))
def test_pseudo_inverse_and_psd_test(seed, exponent, direction, spread):
    """Both branches of the pseudo-inverse (the band's shortcut, scipy's general form beyond it) and the PSD test
    (Cholesky; eigvalsh for a singular or non-finite matrix)."""
    rng = np.random.default_rng(seed)
    projector = np.eye(3) - np.outer(direction, direction)
    matrix = projector @ np.diag(np.array([1.0, spread, 1.0]) * rng.uniform(0.5, 2.0, 3)) @ projector * 10.0**(exponent / 6)
    matrix = 0.5 * (matrix + matrix.T)
    against_old(uplkf._projector_pseudo_inverse, old._projector_pseudo_inverse, matrix, direction)
    against_old(uplkf._solve_identity, old._solve_identity, matrix + np.outer(direction, direction))
    against_old(uplkf._solve_identity, old._solve_identity, np.outer(direction, direction))  # exactly singular
    for candidate in (covariance(seed, 6, exponent // 6), -covariance(seed, 6, 0), np.zeros((6, 6)),
                      np.full((6, 6), np.nan)):  # the last: eigvalsh's LinAlgError
        expected = outcome(old._is_positive_semidefinite, candidate)
        assert outcome(uplkf._is_positive_semidefinite, candidate) == expected
        assert outcome(python(uplkf._is_positive_semidefinite), candidate) == expected


@settings(max_examples=150, deadline=None)
@given(seeds, st.integers(-3, 6), floats(-0.5, 0.5), st.sampled_from([1.0, 1.7]), st.sampled_from([1.0, 4.0]))
def test_predict(seed, exponent, turn_rate, scale, boost):
    a, noise, state, p = predict_inputs(seed, exponent, turn_rate)
    against_old(uplkf._predict_kernel, old._predict_kernel, a, noise, scale, boost, state, p)


@settings(max_examples=300, deadline=None)
@given(seeds, st.integers(-3, 6), floats(-0.3, 0.3), st.booleans(), st.booleans(), st.booleans(),
       st.sampled_from([0.0, 0.01, 1.0]), st.sampled_from([None, 0.0, 0.1, 1e3]), st.booleans())
def test_correction(seed, exponent, lead, late, use_predicted, position_noise, noise_scale, reference_offset, with_nis):
    """The u-PLKF's correction (`_correct_kernel` and UPLKF.correct's `_correct_into`) in place, its innovation, S,
    S^+ and NIS: noisy bearings reach the general pseudo-inverse and the Joseph form; a far reference the gain's
    fallback to the bearing's position; a late bearing the lead terms."""
    arguments = correction_arguments(seed, exponent, lead if late else 0.0, late, use_predicted, position_noise,
                                     noise_scale, reference_offset)
    against_old(uplkf._correct_kernel, old._correct_kernel, *arguments)
    against_old(uplkf._correct_into, old._correct_into, *arguments, with_nis, np.full(3, np.nan), np.full((3, 3), np.nan))


@settings(max_examples=150, deadline=None)
@given(seeds, st.sampled_from([2, 3, 5]), st.integers(-2, 4), floats(-0.3, 0.3), st.booleans(),
       st.sampled_from([0.0, 0.01, 1.0]), st.booleans(), st.booleans())
def test_predict_models_and_imm_correction(seed, count, exponent, lead, late, noise_scale, one_reference, with_nis):
    """Every model's time update, then the IMM's whole correction (each model's u-PLKF correction, the likelihoods,
    the combined innovation, the probabilities, the mixing): the states, covariances, weights (the next c), NIS and
    probabilities it writes and the combined innovation it returns."""
    probabilities, _, states, covariances = imm_inputs(seed, count, exponent)
    transitions = np.array([uplkf.coordinated_turn_matrices(0.02, 0.1 * j)[0] for j in range(count)])
    noises = np.array([0.01 * (j + 1) * np.eye(6) for j in range(count)])
    factors = np.linspace(1.0, 2.0, count)
    _, predicted = against_old(imm._predict_models, old._predict_models, transitions, noises, factors,
                               factors[::-1].copy(), states, covariances)
    states, covariances = predicted[4:]
    rng, pursuer, direction, lead, lines_of_sight, predicted_range = imm_bearing(seed, states, probabilities, lead,
                                                                               late, noise_scale)
    model_relative, ranges, model_ranges, relative = lines_of_sight
    references = pursuer + rng.normal(size=(1 if one_reference else count, 3)) * 0.1
    arguments = (states, covariances, model_relative, ranges, model_ranges, direction, references, True, lead, late,
                 np.array([1e-4 * (j + 1) * np.eye(3) for j in range(count)]), True, 0.01,
                 np.array([covariance(seed + j, 3, -3) for j in range(count)]), pursuer, probabilities, relative,
                 predicted_range, 0.98, 1.0, 0.2, with_nis, np.full(count, np.nan), np.full(count, np.nan))
    against_old(imm._imm_correct_kernel, old._imm_correct_kernel, *arguments)


@settings(max_examples=200, deadline=None)
@given(seeds, st.sampled_from([1, 2, 3, 5]), st.integers(-3, 5), st.booleans(), st.booleans())
def test_imm_steps(seed, count, exponent, unreachable, no_likelihood):
    """The IMM's steps one by one, the degenerate cases included: a model no likely model leads to (c_j = 0), no
    finite likelihood (the predicted probabilities stand), an S that is not rank 2 (-inf), a zero scale."""
    rng = np.random.default_rng(seed)
    probabilities, transition, states, covariances = imm_inputs(seed, count, exponent)
    if unreachable and count > 1:
        transition = transition.copy()
        transition[:, 0] = 0.0
        transition[0, 0] = 1.0
        probabilities = probabilities.copy()
        probabilities[0] = 0.0
        probabilities /= probabilities.sum()
    against_old(imm._mix_into, old._mix_into, probabilities, transition, states, covariances)
    innovations = rng.normal(size=(count, 3))
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    projectors = np.eye(3) - directions[:, :, None] * directions[:, None, :]
    innovation_covariances = np.array([p @ covariance(seed + j, 3, exponent) @ p for j, p in enumerate(projectors)])
    if count > 1:
        innovation_covariances[-1] = 0.0  # rank 0: -inf
    scales = rng.uniform(1.0, 100.0, count)
    scales[0] = 0.0 if unreachable else scales[0]
    _, likelihood_args = against_old(imm._rank2_log_likelihoods_kernel, old._rank2_log_likelihoods_kernel, innovations,
                                     innovation_covariances, scales, directions)
    log_likelihoods = old._rank2_log_likelihoods_kernel(*likelihood_args)
    if no_likelihood:
        log_likelihoods[:] = -math.inf
    against_old(imm._posterior_probabilities, old._posterior_probabilities, log_likelihoods, probabilities)
    relative = rng.normal(size=3) * 30.0
    against_old(imm._combined_innovation, old._combined_innovation, probabilities, innovations, innovation_covariances,
                relative, math.sqrt(float(relative @ relative)))
