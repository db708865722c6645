"""Verbatim copies of the estimator kernels as they were before the allocation trims (companion/core/estimators.py
and imm.py), the reference of tests/test_kernel_temporaries.py: a helper, not a test
module. Only the kernels that changed are copied; the ones they call that did not change (the projector, the
range limit, the Joseph form, the LAPACK bindings, the mixing's `_mix_kernel`, the Markov matrix, the NIS) are
the package's own. Compiled with the package's `jit` (plain Python without numba or with BOF_NO_JIT=1)."""

from __future__ import annotations

import math

import numpy as np

from companion.core._jit import jit, lapack_dgesv, lapack_dpotrf, objmode
from companion.core.estimators import (_EYE3, SHORTCUT_EIGENVALUE_BAND, _eigenvalues_not_negative,
                                       _general_pseudo_inverse, _joseph_update, _normalized_innovation_squared,
                                       _projector, _unit_vector, limit_range)
from companion.core.imm import _LOG_TWO_PI, _markov_matrix_over, _mix_kernel


@jit
def _solve_identity(matrix: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """(M^-1, det M, ok) for a 3x3 M by one LAPACK LU solve (dgesv) against the identity.

    np.linalg.inv is this same dgesv solve (M^-1 equal to the last bit: tests/test_estimator_cost_paths.py),
    at a third of its cost on a 3x3 without numpy's wrapper. The determinant is the product of
    the LU pivots with the permutation's sign (np.linalg.det forms it through logarithms, so the
    two agree to rounding). M^-1 comes Fortran-ordered. ok is False when M is exactly singular
    (det 0, no inverse)."""
    lu, pivots, inverse, info = lapack_dgesv(matrix, _EYE3)
    if info != 0:
        return inverse, 0.0, False
    determinant = float(lu[0, 0] * lu[1, 1] * lu[2, 2])
    # row interchanges (the pivots are 0-based; the last row is always itself)
    swaps = (1 if pivots[0] != 0 else 0) + (1 if pivots[1] != 1 else 0)
    return inverse, -determinant if swaps % 2 else determinant, True


@jit
def _is_positive_semidefinite(covariance: np.ndarray) -> bool:
    """Whether the symmetric covariance (n, n) is PSD, i.e. not np.linalg.eigvalsh(covariance)[0] < 0, cheaply.

    A Cholesky factorisation (LAPACK dpotrf, lower triangle as eigvalsh reads it) succeeds for a
    positive definite matrix at a sixth of the cost of np.linalg.eigvalsh on a 6x6; when it fails
    (or meets a non-finite entry, which dpotrf lets through) the decision is eigvalsh's exactly,
    so a positive semi-definite singular matrix is still accepted and a NaN gets eigvalsh's answer (or error) as before.
    The two can disagree only when Cholesky succeeds while eigvalsh's smallest eigenvalue is
    negative at rounding level (|lambda_min| ~ 1e-16 ||P||, where its sign is rounding noise):
    then the short form is kept, a matrix Cholesky-factorisable to working precision."""
    factor, info = lapack_dpotrf(covariance)
    if info == 0:
        trace = 0.0  # finite or not: the order of the sum does not matter (each term is at most ~1e154)
        for i in range(factor.shape[0]):
            trace += factor[i, i]
        if math.isfinite(trace):
            return True
    with objmode(result="boolean"):  # rare (a singular or non-finite covariance): numpy's eigvalsh itself
        result = _eigenvalues_not_negative(covariance)
    return result


@jit
def _projector_pseudo_inverse(matrix: np.ndarray, null_direction: np.ndarray) -> np.ndarray:
    """Moore-Penrose pseudo-inverse of a symmetric PSD 3x3 `matrix` S whose kernel is span(g).

    The innovation covariance of section IV-C is rank 2 with kernel span(g), g the unit
    vector of its projector. Shape (3, 3) in and out; g: shape (3,), unit.

    Shortcut: S^+ = (S + g g^T)^-1 - g g^T exactly, one 3x3 inverse. It is accurate only
    while the two non-zero eigenvalues of S are on the scale of the added unit eigenvalue:
    a diverging filter drives them to 1e50 and beyond, the g g^T term is then lost in the
    rounding of S's entries and S + g g^T is numerically singular (LinAlgError); tiny or
    very unequal eigenvalues lose accuracy the same way. So the shortcut is taken only when
    both lie in SHORTCUT_EIGENVALUE_BAND (their sum is trace S, their product
    det(S + g g^T)), which holds throughout normal flight. Otherwise the general form:
    E (E^T S E)^+ E^T, with E (3, 2) an orthonormal basis of g's orthogonal complement and
    the 2x2 pseudo-inverse from numpy's SVD, which is defined for any finite S and any
    unit g (a rank-deficient block gives the pseudo-inverse, never an error).
    """
    outer = null_direction[:, None] * null_direction  # np.outer's arithmetic without its argument handling
    low, high = SHORTCUT_EIGENVALUE_BAND
    trace = float(matrix[0, 0] + matrix[1, 1] + matrix[2, 2])
    if low <= trace <= high:
        inverse, determinant, regular = _solve_identity(matrix + outer)  # np.linalg.inv's solve, cheaper
        if regular and determinant >= low * trace:  # smallest eigenvalue >= det / trace >= low
            return inverse - outer
    with objmode(result="float64[:, ::1]"):  # rare (a diverging filter): scipy's null_space and numpy's pinv
        result = _general_pseudo_inverse(matrix, null_direction)
    return result


@jit
def _predict_kernel(transition: np.ndarray, discrete_process_noise: np.ndarray, scale: float, boost: float,
                    state: np.ndarray, covariance: np.ndarray) -> None:
    """Time update over one period, section IV-C: x^- = A x, P^- = A P A^T + B Q B^T, in place.

    transition: A (6, 6). discrete_process_noise: B Q B^T (6, 6), scaled by the adaptive factor
    s_k (`scale`) and then by the health monitor's `boost` (each skipped at 1: 1 Q is Q exactly).
    state: x (6,) and covariance: P (6, 6), overwritten with x^- and P^-."""
    noise = discrete_process_noise
    if scale != 1.0:
        noise = scale * noise
    if boost != 1.0:
        noise = boost * noise
    state[:] = transition @ state
    covariance[:] = transition @ covariance @ transition.T + noise


@jit
def _correct_kernel(state: np.ndarray, covariance: np.ndarray, relative: np.ndarray, predicted_range: float,
                    direction: np.ndarray, reference: np.ndarray, use_reference: bool, use_predicted: bool, lead: float,
                    late: bool, measurement_noise: np.ndarray, add_position_noise: bool, position_variance: float,
                    lead_noise: np.ndarray, pursuer_position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measurement update with one bearing, eq. (6) and section IV-C (`UPLKF.correct`'s arithmetic), in place.

        K_k = P^-_k H^T (H P^-_k H^T + V_k Sigma V_k^T)^+,   V_k = r^- P_lambda,
        x_k = x^-_k - K_k H_k x^-_k,   P_k = (I - K_k H) P^-_k   (Joseph form if that is not PSD)

    with H_k x^-_k = P_lambda~ (p^-_T - p) and H = [P_lambda, 0] from the gain's line of sight (H = P_lambda [I, tau I]
    for a bearing tau = `lead` s off the filter's time, when `late`).

    state: x^- (6,), covariance: P^- (6, 6), overwritten with x_k and P_k. relative: p^-_T - p (3,), m, at the
    bearing's time, and predicted_range its length, m. direction: the unit bearing of the residual (3,).
    reference: the own position the gain's line of sight starts from (3,), m (OwnPositionTracker), when
    use_reference; else p. use_predicted: the PREDICTED gain (from that line of sight; False takes `direction`).
    measurement_noise: Sigma (3, 3). add_position_noise, position_variance: sigma_p^2 P, m^2. lead_noise: the
    late bearing's target-motion covariance (3, 3), m^2. pursuer_position: p (3,), m, the bearing's position.
    Returns the pseudo-measurement innovation y = P_lambda~ (p^-_T - p) (3,), its covariance S (3, 3) and S^+."""
    gain_relative, gain_range = relative, predicted_range
    if use_reference:
        # Errors in variables: the gain's line of sight from an own position that does not
        # carry this sample's error (OwnPositionTracker), the residual from the sample itself.
        gain_relative = relative + (pursuer_position - reference)
        gain_range = math.sqrt(float(np.dot(gain_relative, gain_relative)))
        if gain_range < 1e-6:
            gain_relative, gain_range = relative, predicted_range
    measured_projection = _projector(_unit_vector(direction))
    gain_direction = gain_relative / gain_range if use_predicted else direction
    gain_projection = _projector(gain_direction)
    # H = [P, 0], so H P^- H^T = P P^-_pp P and P^- H^T = P^-[:, :3] P.
    # A bearing taken tau = lead s away from the filter's time (a late fix, a neighbour's shared
    # bearing) measures p_T(t + tau) = p_T + tau v_T + w_tau: H = P [I, tau I], and w_tau, the
    # target's own acceleration over |tau|, adds its position variance to the measurement noise.
    # P^- M^T, M = [I, tau I] (a contiguous copy of the columns: the same BLAS product, with no strided operand)
    position_rows = covariance[:, :3] + lead * covariance[:, 3:] if late else np.ascontiguousarray(covariance[:, :3])
    cross_covariance = position_rows @ gain_projection
    noise_transition = gain_range * gain_projection  # V_k = r^- P_lambda
    measurement_covariance = noise_transition @ measurement_noise @ noise_transition.T
    if add_position_noise:
        measurement_covariance = measurement_covariance + position_variance * gain_projection
    if late:
        measurement_covariance = measurement_covariance + gain_projection @ lead_noise @ gain_projection
    prior_rows = cross_covariance[:3] + lead * cross_covariance[3:] if late else cross_covariance[:3]  # M P^- M^T P
    innovation_covariance = gain_projection @ prior_rows + measurement_covariance
    innovation_inverse = _projector_pseudo_inverse(innovation_covariance, gain_direction)
    gain = cross_covariance @ innovation_inverse
    # x_k = x^-_k - K_k H_k x^-_k, with H_k x^-_k = P_lambda~ (p^-_T - p)
    innovation = measured_projection @ relative  # H_k x^-_k, also the report's innovation
    updated = state - gain @ innovation
    updated[:3] = limit_range(updated[:3], pursuer_position)
    measured_rows = covariance[:3] + lead * covariance[3:] if late else covariance[:3]  # M P^-
    posterior = covariance - gain @ (gain_projection @ measured_rows)  # (I - K H) P^-
    posterior = 0.5 * (posterior + posterior.T)
    if not _is_positive_semidefinite(posterior):
        posterior = _joseph_update(covariance, gain, gain_projection, measurement_covariance, lead if late else 0.0)
    state[:] = updated
    covariance[:] = posterior
    return innovation, innovation_covariance, innovation_inverse


@jit
def _correct_into(state: np.ndarray, covariance: np.ndarray, relative: np.ndarray, predicted_range: float,
                  direction: np.ndarray, reference: np.ndarray, use_reference: bool, use_predicted: bool, lead: float,
                  late: bool, measurement_noise: np.ndarray, add_position_noise: bool, position_variance: float,
                  lead_noise: np.ndarray, pursuer_position: np.ndarray, with_nis: bool, innovation: np.ndarray,
                  innovation_covariance: np.ndarray) -> float:
    """`_correct_kernel` (its arguments first, the same update in place) with the innovation y (3,) and its
    covariance S (3, 3) written into `innovation` and `innovation_covariance` (arguments rather than results: numba
    boxes every array it returns), and the NIS y^T S^+ y (`_normalized_innovation_squared`) returned when with_nis
    (NaN otherwise): UPLKF.correct's one kernel call."""
    result, result_covariance, result_inverse = _correct_kernel(
        state, covariance, relative, predicted_range, direction, reference, use_reference, use_predicted, lead, late,
        measurement_noise, add_position_noise, position_variance, lead_noise, pursuer_position)
    innovation[:] = result
    innovation_covariance[:] = result_covariance
    if with_nis:
        return _normalized_innovation_squared(result, result_inverse)
    return math.nan


@jit
def _rank2_log_likelihoods_kernel(innovations: np.ndarray, covariances: np.ndarray, scales: np.ndarray,
                                  null_directions: np.ndarray) -> np.ndarray:
    """`rank2_log_likelihoods`, seed 004 eq. (20) as `rank2_log_likelihood` takes it with its null direction, on
    C-ordered float64 arrays (a kernel: companion.core._jit). The sums are written out in the order numpy's
    reductions of the vectorised form took them (a row of 3: left to right; the 9 squares of S: numpy's
    pairwise sum), so its results are those bit for bit."""
    count = innovations.shape[0]
    result = np.empty(count)
    for k in range(count):
        covariance = covariances[k]
        innovation = innovations[k]
        e1 = covariance[0, 0] + covariance[1, 1] + covariance[2, 2]
        s = covariance * covariance
        square_sum = ((s[0, 0] + s[0, 1]) + (s[0, 2] + s[1, 0])) + ((s[1, 1] + s[1, 2]) + (s[2, 0] + s[2, 1])) + s[2, 2]
        e2 = 0.5 * (e1 * e1 - square_sum)
        g = null_directions[k]
        along = g[0] * innovation[0] + g[1] * innovation[1] + g[2] * innovation[2]
        s_y = covariance @ innovation
        quadratic = s_y[0] * innovation[0] + s_y[1] * innovation[1] + s_y[2] * innovation[2]
        if not e2 > 0.0:
            result[k] = -math.inf
            continue
        nis = (e1 * (float(innovation @ innovation) - along * along) - quadratic) / e2
        scale = scales[k]
        value = -0.5 * (nis + 2.0 * _LOG_TWO_PI + math.log(e2)) + 2.0 * math.log(scale) if scale > 0.0 else -math.inf
        result[k] = value if math.isfinite(value) else -math.inf
    return result


@jit
def _combined_innovation(weights: np.ndarray, innovations: np.ndarray, covariances: np.ndarray, relative: np.ndarray,
                         predicted_range: float) -> tuple[np.ndarray, np.ndarray]:
    """y = sum_j c_j y_j and its covariance sum_j c_j [S_j + (y_j - y)(y_j - y)^T] projected across the combined
    predicted line of sight g = `relative` / `predicted_range` (IMMEstimator._combined_report, a kernel:
    companion.core._jit). weights (n,), innovations (n, 3), covariances (n, 3, 3) -> (3,), (3, 3)."""
    innovation = weights @ innovations
    spread = innovations - innovation
    covariance = (weights @ covariances.reshape(weights.shape[0], 9)).reshape(3, 3) + (weights[:, None] * spread).T @ spread
    # (I - g g^T) C (I - g g^T), g the combined predicted line of sight, expanded
    g = relative / predicted_range
    cg = covariance @ g
    # broadcast products: np.outer's arithmetic without its per-call argument handling; cg g^T is
    # (g cg^T)^T exactly (each entry the same product), and the in-place steps keep the order of the sum
    g_cg = g[:, None] * cg
    covariance = covariance - g_cg
    covariance -= g_cg.T
    covariance += float(g @ cg) * (g[:, None] * g)
    return innovation, 0.5 * (covariance + covariance.T)


@jit
def _posterior_probabilities(log_likelihoods: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """mu^j = Lambda^j c_j / sum_t Lambda^t c_t, seed 004 eq. (21), in logarithms (a kernel: companion.core._jit).
    log_likelihoods: ln Lambda^j (n,); predicted: c (n,). With no finite likelihood (every model restarted)
    the predicted probabilities c stand (a copy)."""
    count = predicted.shape[0]
    log_posterior = np.empty(count)
    for j in range(count):
        likelihood, weight = log_likelihoods[j], predicted[j]
        log_posterior[j] = likelihood + math.log(weight) if math.isfinite(likelihood) and weight > 0.0 else -math.inf
    peak = log_posterior[0]
    for j in range(1, count):
        if log_posterior[j] > peak:
            peak = log_posterior[j]
    if peak == -math.inf:
        return predicted.copy()
    posterior = np.empty(count)
    total = 0.0
    for j in range(count):
        posterior[j] = math.exp(log_posterior[j] - peak)
        total += posterior[j]
    return posterior / total


@jit
def _mix_into(probabilities: np.ndarray, transition: np.ndarray, states: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Seed 004 eqs. (17)-(19) in place: each model's state (n, d) and covariance (n, d, d) replaced by its mixed
    start (the covariance symmetrised); returns the predicted model probabilities c (n,)."""
    predicted, mixed, mixed_covariances = _mix_kernel(probabilities, transition, states, covariances)
    for j in range(states.shape[0]):
        states[j] = mixed[j]
        covariances[j] = 0.5 * (mixed_covariances[j] + mixed_covariances[j].T)
    return predicted


@jit
def _predict_models(transitions: np.ndarray, discrete_process_noises: np.ndarray, scales: np.ndarray, boosts: np.ndarray,
                    states: np.ndarray, covariances: np.ndarray) -> None:
    """Every model filter's time update (section IV-C, UPLKF's `_predict_kernel`), in place on the stacked
    states (n, 6) and covariances (n, 6, 6); transitions and discrete process noises (n, 6, 6), each model's
    adaptive scale and boost (n,)."""
    for j in range(states.shape[0]):
        _predict_kernel(transitions[j], discrete_process_noises[j], scales[j], boosts[j], states[j], covariances[j])


@jit
def _imm_correct_kernel(states: np.ndarray, covariances: np.ndarray, model_relative: np.ndarray, ranges: np.ndarray,
                        model_ranges: np.ndarray, direction: np.ndarray, references: np.ndarray, use_reference: bool,
                        lead: float, late: bool, measurement_noises: np.ndarray, add_position_noise: bool, position_variance: float,
                        lead_noises: np.ndarray, pursuer_position: np.ndarray, weights: np.ndarray,
                        relative: np.ndarray, predicted_range: float, stay_probability: float, stay_time: float,
                        interval: float, with_nis: bool, nis: np.ndarray, probabilities: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """One IMM correction of models with the PREDICTED gain, none restarting (IMMEstimator.correct), in place on
    the stacked states (n, 6) and covariances (n, 6, 6):

    every model's u-PLKF correction (eq. (6), section IV-C: `_correct_kernel`), their likelihoods (seed 004
    eq. (20), `_rank2_log_likelihoods_kernel`, the kernel of each S_j its model's predicted line of sight), the
    combined innovation for the health monitor (`_combined_innovation`), the model probabilities (eq. (21),
    `_posterior_probabilities`) and the mixing for the next cycle (eqs. (17)-(19), `_mix_into`).

    The per-model inputs are `_correct_kernel`'s, stacked (references (n, 3), or (1, 3) for one reference every
    model takes (the model filters' shared OwnPositionTracker); measurement_noises and lead_noises (n, 3, 3)); model_relative (n, 3), ranges and model_ranges (n,) as `_prior_lines_of_sight` gives them; weights: c (n,); relative and predicted_range: the combined line of
    sight; stay_probability, stay_time, interval: the Markov matrix p_ij over the interval since the last
    correction (`_markov_matrix_over`). Writes each model's NIS y_j^T S_j^+ y_j into nis (n,) (when with_nis; left
    alone otherwise), mu into probabilities (n,) and the next c into weights (n,) (after every use of the old c),
    the caller's arrays; returns the combined innovation (3,) and covariance (3, 3)."""
    count = states.shape[0]
    innovations = np.empty((count, 3))
    innovation_covariances = np.empty((count, 3, 3))
    for j in range(count):
        innovation, innovation_covariance, innovation_inverse = _correct_kernel(
            states[j], covariances[j], model_relative[j], model_ranges[j], direction, references[j if references.shape[0] > 1 else 0], use_reference, True,
            lead, late, measurement_noises[j], add_position_noise, position_variance, lead_noises[j], pursuer_position)
        innovations[j] = innovation
        innovation_covariances[j] = innovation_covariance
        if with_nis:
            nis[j] = _normalized_innovation_squared(innovation, innovation_inverse)
    log_likelihoods = _rank2_log_likelihoods_kernel(innovations, innovation_covariances, ranges,
                                                    model_relative / ranges[:, None])
    innovation, innovation_covariance = _combined_innovation(weights, innovations, innovation_covariances, relative,
                                                             predicted_range)
    probabilities[:] = _posterior_probabilities(log_likelihoods, weights)
    weights[:] = _mix_into(probabilities, _markov_matrix_over(count, stay_probability, stay_time, interval), states,
                           covariances)
    return innovation, innovation_covariance
