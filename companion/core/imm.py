"""Interacting-multiple-model (IMM) estimator over pseudo-linear model filters.

A target that keeps turning is not a constant-velocity target: the u-PLKF's prediction lags
it, and with the small Q that the constant-velocity cases need, the bearings' correction
cannot keep up. The IMM (Blom & Bar-Shalom 1988; seed 004 eqs. (17)-(23), its straight /
left-turn / right-turn models with p_ii = 0.98) runs one u-PLKF per motion model, each with
its own transition and process noise but the same correction (`UPLKF.correct`), and weighs
them by how well each predicted the bearings.

One cycle per bearing used (k), with n models, Markov matrix p_ij (the probability that the
target switches from model i to model j between two corrections) and model probabilities
mu^i_{k-1}:

1. Mixing, seed 004 eqs. (17)-(19): predicted model probabilities c_j = sum_i p_ij mu^i,
   mixing weights mu^{i|j} = p_ij mu^i / c_j, and each model filter restarts from
   x0^j = sum_i mu^{i|j} x^i,  P0^j = sum_i mu^{i|j} [P^i + (x^i - x0^j)(x^i - x0^j)^T].
   Done right after each correction, so the model filters then predict from their mixed
   starts at the estimator rate until the next bearing (any number of predictions).
2. Model-conditioned filtering: every model filter predicts with its own A_j, Q_j and
   corrects with the bearing (eq. (6), section IV-C).
3. Model probabilities, seed 004 eqs. (20)-(21): mu^j_k = Lambda^j c_j / sum_t Lambda^t c_t,
   Lambda^j the likelihood of the bearing under model j, from the model's pseudo-linear
   innovation y_j and its innovation covariance S_j. S_j has rank 2 (a bearing constrains two
   directions), so the Gaussian density is the one on S_j's range. It is taken in bearing
   (angle) units: Lambda^j = N(y_j / r_j; 0, S_j / r_j^2), r_j the model's predicted range,
   that is exp(-y^T S^+ y / 2) r_j^2 / (2 pi sqrt(pdet S)), pdet the product of the two
   non-zero eigenvalues. Why not N(y_j; 0, S_j) as printed: y_j = P_lambda~ (p^-_T - p) is
   r_j times the bearing error, and S_j grows with r_j^2 (R_k = r^2 P Sigma P); the density of
   the pseudo-measurement then favours whichever model predicts the target closer (measured:
   on a straight target, a turn model predicting 35 m instead of the true 42 m won with
   noise-free bearings, and the IMM left the right model). The factor r_j^2 is the Jacobian
   that makes the densities of different models densities of the same quantity, the bearing.
   Evaluated in logarithms (the densities of 50 Hz bearings differ by hundreds of orders of
   magnitude during a manoeuvre).
4. Combination, seed 004 eqs. (22)-(23): x = sum_j mu^j x^j,
   P = sum_j mu^j [P^j + (x^j - x)(x^j - x)^T]; that is the estimate the pipeline flies on.

The Markov matrix is defined per time, not per correction, so the same settings mean the
same switching at 5 Hz and at 50 Hz bearings: over a correction interval Delta,
p_ii = stay_probability^(Delta / stay_time), the rest split evenly over the other models
(seed 004's p_ii = 0.98, p_ij = 0.01 at Delta = stay_time).

Restarts. The IMM checks the combined prediction against the bearing first: behind the
sensor (remark 3, the u-PLKF's guard), every model restarts on the bearing at the combined
predicted range and the probabilities return to their initial values. A single model whose
own prediction is behind the sensor restarts itself (its own guard) and gets zero
likelihood for that bearing, so the next mixing rebuilds it from the others.

numpy only (and the u-PLKF of companion.core.estimators); the numeric steps are kernels that numba compiles
when it is installed (companion.core._jit), the same functions either way.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.core._jit import jit, jit_inline
from companion.core.estimators import (_LEAD_EPSILON, AdaptiveNoiseSettings, AdaptiveProcessNoise, CorrectionReport,
                                       GainProjection, InitialGuess, NoiseChanges, UPLKF, _behind_sensor, _clipped_cosine,
                                       _MEASURED_PROJECTION, _UNIT, _correct_with, _correction_work,
                                       _correction_report, _measured_projection_into, _normalized_innovation_squared,
                                       _own_position_step, _predict_with, coordinated_turn_matrices, restart_guess)
from companion.core.geometry import unit
from companion.core.messages import BearingMeasurement, TargetEstimate, fast_frozen, position_std_of

_LOG_TWO_PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class MotionModel:
    """One model filter of the IMM.

    name: for logs ("cv", "ct+0.30", ...). turn_rate: omega, rad/s, about the NED down axis
    (0: eq. (1)'s constant velocity; > 0 a right turn seen from above). process_noise: q,
    (m/s^2)^2, the target acceleration variance per axis of this model (Q = q I).
    along_track_noise: q_a, (m/s^2)^2; when > 0 the acceleration variance along the model's own
    velocity estimate, q staying across it (a target that changes speed but not direction;
    `speed_change_noise`), recomputed at every prediction. 0 (default): Q = q I.
    """

    name: str
    turn_rate: float
    process_noise: float
    along_track_noise: float = 0.0


def standard_models(turn_rates: Sequence[float], cv_process_noise: float, turn_process_noise: float,
                    manoeuvre_acceleration: float | None = None) -> list[MotionModel]:
    """Constant velocity first, then a right (+omega) and a left (-omega) coordinated turn per
    turn rate (rad/s, each > 0): seed 004's straight / right / left set for one rate; then, when
    manoeuvre_acceleration (m/s^2) is given, the speed-change model (`manoeuvre_model`) with the
    constant-velocity model's q across its track."""
    models = [MotionModel("cv", 0.0, cv_process_noise)]
    for rate in turn_rates:
        models.append(MotionModel(f"ct+{rate:g}", float(rate), turn_process_noise))
        models.append(MotionModel(f"ct-{rate:g}", -float(rate), turn_process_noise))
    if manoeuvre_acceleration is not None:
        models.append(manoeuvre_model(manoeuvre_acceleration, cv_process_noise))
    return models


#: The share of the target's largest acceleration a_max taken as the speed-change model's along-track standard
#: deviation: sigma_a = 2 a_max / 3, inside Bar-Shalom, Li and Kirubarajan's 0.5 a_max to a_max for a
#: white-noise-acceleration model (2001, section 6.3.2).
MANOEUVRE_SHARE = 2.0 / 3.0

#: m/s: the speed below which the speed-change model no longer knows the direction of its track, so its acceleration
#: variance blends to q_a on every axis (`speed_change_noise`): a hovering target may leave in any direction.
HOVER_SPEED = 1.0


def manoeuvre_model(max_acceleration: float, cross_process_noise: float) -> MotionModel:
    """The model of a target that changes speed (takes off, dashes, brakes): white-noise acceleration of variance
    q_a = (MANOEUVRE_SHARE a_max)^2 along its own velocity and cross_process_noise ((m/s^2)^2) across it, a_max
    the target's largest acceleration (m/s^2). Across its track the model is as quiet as the constant-velocity
    model: an isotropic q_a would explain the pursuer's own weave as target motion, and the range would no
    longer show in the bearings (measured: the weave and the tight orbits diverged with it). Along the line of
    sight of a pursuer behind its target, a speed change moves the target only along the bearing, which the
    pursuer's weave tells apart from a range error."""
    if not (math.isfinite(max_acceleration) and max_acceleration > 0.0):
        raise ValueError(f"the manoeuvre model needs a finite max_acceleration > 0, got {max_acceleration!r}")
    if not (math.isfinite(cross_process_noise) and cross_process_noise >= 0.0):
        raise ValueError(f"the manoeuvre model needs a finite cross_process_noise >= 0, got {cross_process_noise!r}")
    return MotionModel("speed", 0.0, cross_process_noise, (MANOEUVRE_SHARE * max_acceleration) ** 2)


def speed_change_noise(velocity: np.ndarray, along: float, across: float) -> np.ndarray:
    """The speed-change model's acceleration covariance (3, 3), (m/s^2)^2, for its velocity estimate v (3,), m/s:

        Q_a = across I + (along - across) [(1 - s) I + s v v^T / |v|^2],   s = |v|^2 / (|v|^2 + v_0^2),

    v_0 = HOVER_SPEED: along its track `along`, across it `across`, and isotropic `along` for a target at rest."""
    out = np.empty((3, 3))
    _speed_change_noise_into(np.asarray(velocity, dtype=float), float(along), float(across), out)
    return out


@jit_inline
def _speed_change_noise_into(velocity: np.ndarray, along: float, across: float, out: np.ndarray) -> None:
    """`speed_change_noise` into out (3, 3): (across + w (1 - s)) I + (w / (|v|^2 + v_0^2)) v v^T, w = along - across
    (s / |v|^2 written out, so a target at rest needs no division by its speed)."""
    speed_squared = float(np.dot(velocity, velocity))
    spread = along - across
    denominator = speed_squared + HOVER_SPEED * HOVER_SPEED
    diagonal = across + spread * HOVER_SPEED * HOVER_SPEED / denominator
    factor = spread / denominator
    for i in range(3):
        for j in range(3):
            out[i, j] = factor * velocity[i] * velocity[j]
        out[i, i] += diagonal


@jit
def _speed_change_noises_into(indices: np.ndarray, states: np.ndarray, along: np.ndarray, across: np.ndarray,
                              inputs: np.ndarray, discrete_process_noises: np.ndarray) -> None:
    """For each speed-change model j in indices: Q_d,j = B_j Q_a(v_j) B_j^T (`speed_change_noise` of its velocity
    states[j, 3:], along[j] and across[j]; B_j (6, 3), inputs[j]) into discrete_process_noises[j] (6, 6)."""
    acceleration, product = np.empty((3, 3)), np.empty((6, 3))
    for j in indices:
        _speed_change_noise_into(states[j, 3:], along[j], across[j], acceleration)
        np.dot(inputs[j], acceleration, product)
        noise = discrete_process_noises[j]
        for row in range(6):
            for column in range(6):
                noise[row, column] = (product[row, 0] * inputs[j, column, 0] + product[row, 1] * inputs[j, column, 1]
                                      + product[row, 2] * inputs[j, column, 2])


@jit
def markov_matrix(count: int, stay_probability: float) -> np.ndarray:
    """p_ij, shape (count, count): stay_probability on the diagonal, the rest split evenly over
    the other models (seed 004's matrix for count = 3, stay_probability = 0.98); rows sum to 1."""
    if count == 1:
        return np.ones((1, 1))
    leave = (1.0 - stay_probability) / (count - 1)
    matrix = np.full((count, count), leave)
    for i in range(count):
        matrix[i, i] = stay_probability
    return matrix


@jit
def _markov_matrix_over(count: int, stay_probability: float, stay_time: float, interval: float) -> np.ndarray:
    """p_ij over `interval` s: p_ii = stay_probability^(interval / stay_time) (module docstring; a negative
    interval counts as 0, as max(interval, 0.0) takes it)."""
    return markov_matrix(count, stay_probability ** ((0.0 if 0.0 > interval else interval) / stay_time))


def mix(probabilities: np.ndarray, transition: np.ndarray, states: np.ndarray,
        covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMM input interaction, seed 004 eqs. (17)-(19).

    probabilities: mu^i_{k-1}, shape (n,). transition: p_ij, (n, n). states: x^i, (n, d).
    covariances: P^i, (n, d, d). Returns (c, x0, P0): the predicted model probabilities
    c_j = sum_i p_ij mu^i, (n,), and each model's mixed start x0^j (n, d) and P0^j (n, d, d).
    """
    return _mix_kernel(*(np.ascontiguousarray(value, dtype=float) for value in (probabilities, transition, states, covariances)))


@jit
def _mix_kernel(probabilities: np.ndarray, transition: np.ndarray, states: np.ndarray,
                covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`mix`, seed 004 eqs. (17)-(19), on C-ordered float64 arrays (a kernel: companion.core._jit)."""
    predicted = probabilities @ transition
    everyone = True  # (predicted > 0).all(): no c_j is 0 (the usual case)
    for value in predicted:
        if not value > 0.0:
            everyone = False
    # dividing by c itself when no c_j is 0 is np.where's arithmetic without the where
    weights = transition * probabilities[:, None] / (predicted if everyone else np.where(predicted > 0.0, predicted, 1.0))[None, :]  # mu^{i|j}
    # A model with c_j = 0 (p_ij = 0 from every likely model) takes no part in anything until
    # its probability returns; it keeps its own estimate instead of an empty mixture.
    if not everyone:
        for j in range(predicted.shape[0]):
            if predicted[j] <= 0.0:
                weights[:, j] = 0.0
                weights[j, j] = 1.0
    mixed = weights.T @ states
    count, size = states.shape
    mixed_covariances = (weights.T @ covariances.reshape(count, size * size)).reshape(count, size, size)
    spread = states[None, :, :] - mixed[:, None, :]  # [j, i] = x^i - x0^j
    for j in range(count):  # sum_i mu^{i|j} (x^i - x0^j)(x^i - x0^j)^T, one BLAS product per model
        mixed_covariances[j] += (spread[j] * weights.T[j][:, None]).T @ spread[j]
    return predicted, mixed, mixed_covariances


def combine(probabilities: np.ndarray, states: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IMM output combination, seed 004 eqs. (22)-(23): the moment-matched mixture of the
    model estimates. probabilities (n,), states (n, d), covariances (n, d, d) -> x (d,), P (d, d)."""
    return _combine_kernel(*(np.ascontiguousarray(value, dtype=float) for value in (probabilities, states, covariances)))


@jit
def _combine_kernel(probabilities: np.ndarray, states: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`combine`, seed 004 eqs. (22)-(23), on C-ordered float64 arrays (a kernel: companion.core._jit)."""
    state = probabilities @ states
    spread = states - state
    size = states.shape[1]
    covariance = (probabilities @ covariances.reshape(probabilities.shape[0], size * size)).reshape(size, size)
    covariance += (probabilities[:, None] * spread).T @ spread
    return state, 0.5 * (covariance + covariance.T)


_position_std = jit(position_std_of)
"""TargetEstimate.position_std's function (companion.core.messages.position_std_of) as a kernel."""


@jit
def _combined_estimate(probabilities: np.ndarray, states: np.ndarray, covariances: np.ndarray, position: np.ndarray,
                       velocity: np.ndarray, covariance: np.ndarray) -> float:
    """The combined estimate, seed 004 eqs. (22)-(23) (`_combine_kernel`), written into the caller's arrays: position
    (3,) and velocity (3,) from x, covariance (6, 6) from P (fresh arrays for a snapshot: numba would box each array
    it returned); returns its position std (`position_std_of`, TargetEstimate.position_std) (IMMEstimator.estimate,
    a kernel: companion.core._jit)."""
    state, combined = _combine_kernel(probabilities, states, covariances)
    position[:] = state[:3]
    velocity[:] = state[3:]
    covariance[:] = combined
    return _position_std(covariance)


@jit
def _turn_acceleration_into(probabilities: np.ndarray, turn_rates: np.ndarray, states: np.ndarray,
                            total: np.ndarray) -> None:
    """IMMEstimator.acceleration's sum into total (3,) (zeros in): for each model j with omega_j != 0, in model
    order, total[:2] += (mu_j omega_j) (-v_E,j, v_N,j), J v_h,j of coordinated_turn_matrices; probabilities (n,),
    turn_rates omega (n,) rad/s, states (n, 6). Each product and sum as numpy's `weight * rate * array` and `+=`
    took them."""
    for j in range(turn_rates.shape[0]):
        rate = turn_rates[j]
        if rate != 0.0:
            factor = probabilities[j] * rate
            east, north = states[j, 4], states[j, 3]
            total[0] += factor * -east
            total[1] += factor * north


def _target_estimate(time: float, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray,
                     position_std: float) -> TargetEstimate:
    """TargetEstimate(time, position, velocity, covariance) with its position_std already known (the value its
    once_property would compute, `position_std_of`), without the frozen dataclass's object.__setattr__ per field."""
    return fast_frozen(TargetEstimate, time=time, position=position, velocity=velocity, covariance=covariance,
                       position_std=position_std)


def rank2_log_likelihood(innovation: np.ndarray, covariance: np.ndarray, scale: float = 1.0,
                         null_direction: np.ndarray | None = None) -> float:
    """ln N(y / r; 0, S / r^2) on the range of a rank-2 symmetric PSD S (3, 3), y (3,), r = scale > 0:
    the likelihood of seed 004 eq. (20) for the u-PLKF's bearing pseudo-measurement, whose S is
    singular along the predicted line of sight; with r the predicted range, the density of the
    bearing error y / r (module docstring). -(y^T S^+ y + ln pdet(2 pi S)) / 2 + 2 ln r; -inf when S
    has fewer than two positive eigenvalues or y is not finite.

    null_direction: g, the unit kernel of S (the u-PLKF's S = P_g (.) P_g, g the predicted line of
    sight), when known. Then without an eigen-decomposition: with e1 = tr S and
    e2 = ((tr S)^2 - tr S^2) / 2 (= lambda_1 lambda_2, pdet S, since the third eigenvalue is 0),
    each non-zero eigenvalue solves lambda^2 - e1 lambda + e2 = 0, so 1/lambda = (e1 - lambda)/e2
    and S^+ = (e1 (I - g g^T) - S) / e2 (Cayley-Hamilton on the range of S). Without g: the two
    largest eigenvalues of numpy's eigh.
    """
    if null_direction is not None:
        e1 = float(covariance[0, 0] + covariance[1, 1] + covariance[2, 2])
        e2 = 0.5 * (e1 * e1 - float(np.sum(covariance * covariance)))
        along = float(null_direction @ innovation)
        nis = (e1 * (float(innovation @ innovation) - along * along) - float(innovation @ covariance @ innovation)) / e2 \
            if e2 > 0.0 else math.nan
        if not (e2 > 0.0 and math.isfinite(nis) and math.isfinite(e2)):
            return -math.inf
        return -0.5 * (nis + 2.0 * _LOG_TWO_PI + math.log(e2)) + 2.0 * math.log(scale)
    values, vectors = np.linalg.eigh(covariance)
    top = values[1:]
    if not (top[0] > 0.0 and math.isfinite(float(top[1]))):
        return -math.inf
    projected = vectors[:, 1:].T @ innovation
    nis = float(projected**2 @ (1.0 / top))
    if not math.isfinite(nis):
        return -math.inf
    return -0.5 * (nis + 2.0 * _LOG_TWO_PI + math.log(float(top[0])) + math.log(float(top[1]))) + 2.0 * math.log(scale)


def rank2_log_likelihoods(innovations: np.ndarray, covariances: np.ndarray, scales: np.ndarray,
                          null_directions: np.ndarray) -> np.ndarray:
    """`rank2_log_likelihood` with its null_direction for n models at once: innovations (n, 3),
    covariances (n, 3, 3), scales (n,), null_directions (n, 3) -> (n,), -inf where S is not rank 2."""
    return _rank2_log_likelihoods_kernel(*(np.ascontiguousarray(value, dtype=float)
                                           for value in (innovations, covariances, scales, null_directions)))


@jit
def _rank2_log_likelihoods_kernel(innovations: np.ndarray, covariances: np.ndarray, scales: np.ndarray,
                                  null_directions: np.ndarray) -> np.ndarray:
    """`rank2_log_likelihoods`, seed 004 eq. (20) as `rank2_log_likelihood` takes it with its null direction, on
    C-ordered float64 arrays (a kernel: companion.core._jit). The sums are written out in the order numpy's
    reductions of the vectorised form took them (a row of 3: left to right; the 9 squares of S: numpy's
    pairwise sum), so its results are those bit for bit."""
    result = np.empty(innovations.shape[0])
    _rank2_log_likelihoods_into(innovations, covariances, scales, null_directions, result)
    return result


@jit_inline
def _rank2_log_likelihoods_into(innovations: np.ndarray, covariances: np.ndarray, scales: np.ndarray,
                                null_directions: np.ndarray, result: np.ndarray) -> None:
    """`_rank2_log_likelihoods_kernel` written into result (n,): the same sums, products and BLAS product, without
    an array per model (the squares of S's entries one by one: an elementwise product is that product)."""
    count = innovations.shape[0]
    s_y = np.empty(3)
    for k in range(count):
        covariance = covariances[k]
        innovation = innovations[k]
        e1 = covariance[0, 0] + covariance[1, 1] + covariance[2, 2]
        c00, c01, c02 = covariance[0, 0], covariance[0, 1], covariance[0, 2]
        c10, c11, c12 = covariance[1, 0], covariance[1, 1], covariance[1, 2]
        c20, c21, c22 = covariance[2, 0], covariance[2, 1], covariance[2, 2]
        square_sum = ((c00 * c00 + c01 * c01) + (c02 * c02 + c10 * c10)) + ((c11 * c11 + c12 * c12)
                                                                            + (c20 * c20 + c21 * c21)) + c22 * c22
        e2 = 0.5 * (e1 * e1 - square_sum)
        g = null_directions[k]
        along = g[0] * innovation[0] + g[1] * innovation[1] + g[2] * innovation[2]
        np.dot(covariance, innovation, s_y)
        quadratic = s_y[0] * innovation[0] + s_y[1] * innovation[1] + s_y[2] * innovation[2]
        if not e2 > 0.0:
            result[k] = -math.inf
            continue
        nis = (e1 * (float(innovation @ innovation) - along * along) - quadratic) / e2
        scale = scales[k]
        value = -0.5 * (nis + 2.0 * _LOG_TWO_PI + math.log(e2)) + 2.0 * math.log(scale) if scale > 0.0 else -math.inf
        result[k] = value if math.isfinite(value) else -math.inf


@jit
def _combined_innovation(weights: np.ndarray, innovations: np.ndarray, covariances: np.ndarray, relative: np.ndarray,
                         predicted_range: float) -> tuple[np.ndarray, np.ndarray]:
    """y = sum_j c_j y_j and its covariance sum_j c_j [S_j + (y_j - y)(y_j - y)^T] projected across the combined
    predicted line of sight g = `relative` / `predicted_range` (IMMEstimator._combined_report, a kernel:
    companion.core._jit). weights (n,), innovations (n, 3), covariances (n, 3, 3) -> (3,), (3, 3)."""
    innovation, covariance = np.empty(3), np.empty((3, 3))
    _combined_innovation_into(weights, innovations, covariances, relative, predicted_range, innovation, covariance)
    return innovation, covariance


@jit_inline
def _combined_innovation_into(weights: np.ndarray, innovations: np.ndarray, covariances: np.ndarray,
                              relative: np.ndarray, predicted_range: float, innovation: np.ndarray,
                              covariance: np.ndarray) -> None:
    """`_combined_innovation` written into innovation (3,) and covariance (3, 3) (the same BLAS products and
    elementwise steps, the intermediates in one scratch array)."""
    count = weights.shape[0]
    work = np.empty(2 * 3 * count + 9 * 5 + 3 * 2)
    spread = work[0:3 * count].reshape(count, 3)
    weighted = work[3 * count:6 * count].reshape(count, 3)
    offset = 6 * count
    mean = work[offset:offset + 9].reshape(3, 3)
    scatter = work[offset + 9:offset + 18].reshape(3, 3)
    summed = work[offset + 18:offset + 27].reshape(3, 3)
    g_cg = work[offset + 27:offset + 36].reshape(3, 3)
    g_g = work[offset + 36:offset + 45].reshape(3, 3)
    g = work[offset + 45:offset + 48]
    cg = work[offset + 48:offset + 51]
    np.dot(weights, innovations, innovation)
    np.subtract(innovations, innovation, spread)
    np.dot(weights, covariances.reshape(count, 9), mean.reshape(9))
    np.multiply(weights[:, None], spread, weighted)
    np.dot(weighted.T, spread, scatter)
    np.add(mean, scatter, summed)
    # (I - g g^T) C (I - g g^T), g the combined predicted line of sight, expanded
    np.divide(relative, predicted_range, g)
    np.dot(summed, g, cg)
    # broadcast products: np.outer's arithmetic without its per-call argument handling; cg g^T is
    # (g cg^T)^T exactly (each entry the same product), and the in-place steps keep the order of the sum
    np.multiply(g[:, None], cg, g_cg)
    np.subtract(summed, g_cg, summed)
    np.subtract(summed, g_cg.T, summed)
    np.multiply(g[:, None], g, g_g)
    np.multiply(float(np.dot(g, cg)), g_g, g_g)
    np.add(summed, g_g, summed)
    np.add(summed, summed.T, covariance)
    np.multiply(0.5, covariance, covariance)


@jit
def _posterior_probabilities(log_likelihoods: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """mu^j = Lambda^j c_j / sum_t Lambda^t c_t, seed 004 eq. (21), in logarithms (a kernel: companion.core._jit).
    log_likelihoods: ln Lambda^j (n,); predicted: c (n,). With no finite likelihood (every model restarted)
    the predicted probabilities c stand (a copy)."""
    posterior = np.empty(predicted.shape[0])
    _posterior_probabilities_into(log_likelihoods, predicted, posterior)
    return posterior


@jit_inline
def _posterior_probabilities_into(log_likelihoods: np.ndarray, predicted: np.ndarray, posterior: np.ndarray) -> None:
    """`_posterior_probabilities` written into posterior (n,) (not predicted's memory)."""
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
        posterior[:] = predicted
        return
    total = 0.0
    for j in range(count):
        posterior[j] = math.exp(log_posterior[j] - peak)
        total += posterior[j]
    np.divide(posterior, total, posterior)


@jit
def _mix_into(probabilities: np.ndarray, transition: np.ndarray, states: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Seed 004 eqs. (17)-(19) in place: each model's state (n, d) and covariance (n, d, d) replaced by its mixed
    start (the covariance symmetrised); returns the predicted model probabilities c (n,)."""
    predicted = np.empty(states.shape[0])
    _mix_in_place(probabilities, transition, states, covariances, predicted)
    return predicted


@jit_inline
def _mix_in_place(probabilities: np.ndarray, transition: np.ndarray, states: np.ndarray, covariances: np.ndarray,
                  predicted: np.ndarray) -> None:
    """`_mix_into` with c written into predicted (n,) (not the memory of any other argument): `_mix_kernel`'s BLAS
    products and elementwise steps in the same order, its intermediates in one scratch array."""
    count, size = states.shape
    work = np.empty(count * count + count * size * (3 + count + size) + size * size)
    weights = work[0:count * count].reshape(count, count)
    offset = count * count
    mixed = work[offset:offset + count * size].reshape(count, size)
    offset += count * size
    mixed_covariances = work[offset:offset + count * size * size].reshape(count, size * size)
    offset += count * size * size
    spread = work[offset:offset + count * count * size].reshape(count, count, size)
    offset += count * count * size
    weighted = work[offset:offset + count * size].reshape(count, size)
    offset += count * size
    scatter = work[offset:offset + size * size].reshape(size, size)
    np.dot(probabilities, transition, predicted)
    everyone = True  # (predicted > 0).all(): no c_j is 0 (the usual case)
    for value in predicted:
        if not value > 0.0:
            everyone = False
    np.multiply(transition, probabilities[:, None], weights)  # mu^{i|j}
    if everyone:  # dividing by c itself when no c_j is 0 is np.where's arithmetic without the where
        np.divide(weights, predicted[None, :], weights)
    else:
        np.divide(weights, np.where(predicted > 0.0, predicted, 1.0)[None, :], weights)
        # A model with c_j = 0 (p_ij = 0 from every likely model) takes no part in anything until
        # its probability returns; it keeps its own estimate instead of an empty mixture.
        for j in range(count):
            if predicted[j] <= 0.0:
                weights[:, j] = 0.0
                weights[j, j] = 1.0
    np.dot(weights.T, states, mixed)
    np.dot(weights.T, covariances.reshape(count, size * size), mixed_covariances)
    np.subtract(states[None, :, :], mixed[:, None, :], spread)  # [j, i] = x^i - x0^j
    for j in range(count):  # sum_i mu^{i|j} (x^i - x0^j)(x^i - x0^j)^T, one BLAS product per model
        np.multiply(spread[j], weights.T[j][:, None], weighted)
        np.dot(weighted.T, spread[j], scatter)
        np.add(mixed_covariances[j], scatter.reshape(size * size), mixed_covariances[j])
    for j in range(count):
        states[j] = mixed[j]
        mixed_covariance = mixed_covariances[j].reshape(size, size)
        np.add(mixed_covariance, mixed_covariance.T, covariances[j])
        np.multiply(0.5, covariances[j], covariances[j])


@jit
def _predict_models(transitions: np.ndarray, discrete_process_noises: np.ndarray, scales: np.ndarray, boosts: np.ndarray,
                    states: np.ndarray, covariances: np.ndarray) -> None:
    """Every model filter's time update (section IV-C, UPLKF's `_predict_kernel`), in place on the stacked
    states (n, 6) and covariances (n, 6, 6); transitions and discrete process noises (n, 6, 6), each model's
    adaptive scale and boost (n,)."""
    moved, work = np.empty(6), np.empty((3, 6, 6))  # one scratch for every model (`_predict_with`)
    for j in range(states.shape[0]):
        _predict_with(transitions[j], discrete_process_noises[j], scales[j], boosts[j], states[j], covariances[j], moved,
                      work)


@jit
def _prior_lines_of_sight(states: np.ndarray, weights: np.ndarray, lead: float, pursuer_position: np.ndarray,
                          direction: np.ndarray, restart_when_behind: bool, model_relative: np.ndarray,
                          ranges: np.ndarray, model_ranges: np.ndarray, relative: np.ndarray) -> tuple[float, float, bool]:
    """Each model's prior line of sight at the bearing's time as UPLKF.correct forms it, and the combined one.

    states (n, 6); weights: c (n,); lead: bearing time - filter time, s; pursuer_position (3,); direction: the
    unit bearing (3,). Writes model_relative (n, 3) = p^-_T,j - p, ranges (n,) (their lengths, summed as the
    IMM's vectorised form), model_ranges (n,) (each as the model filter's own correct takes it) and relative =
    sum_j c_j model_relative_j (3,) (the caller's arrays: no new ones to hand back per call); returns the
    combined line of sight's length, its clipped cosine to the bearing, and whether every model filter corrects
    (a positive range, and none restarts: remark 3's guard on its own clipped cosine and range when
    restart_when_behind)."""
    count = states.shape[0]
    model_relative[:] = states[:, :3] + lead * states[:, 3:] - pursuer_position
    every_model_corrects = True
    for j in range(count):
        row = model_relative[j]
        ranges[j] = math.sqrt(row[0] * row[0] + row[1] * row[1] + row[2] * row[2])
        model_ranges[j] = math.sqrt(float(np.dot(row, row)))
        if not ranges[j] > 0.0 or (restart_when_behind and _behind_sensor(
                _clipped_cosine(float(np.dot(direction, row)), model_ranges[j]), model_ranges[j])):
            every_model_corrects = False
    relative[:] = weights @ model_relative
    predicted_range = math.sqrt(float(np.dot(relative, relative)))
    cos_angle = _clipped_cosine(float(np.dot(direction, relative)), predicted_range)
    return predicted_range, cos_angle, every_model_corrects


@jit
def _imm_correct_into(states: np.ndarray, covariances: np.ndarray, weights: np.ndarray, pursuer_position: np.ndarray,
                      direction: np.ndarray, references: np.ndarray, noises: tuple, lines_of_sight: tuple,
                      outputs: tuple, scalars: np.ndarray, switches: np.ndarray, predicted_range: float) -> None:
    """One IMM correction of models with the PREDICTED gain, none restarting (IMMEstimator.correct), in place on
    the stacked states (n, 6) and covariances (n, 6, 6):

    every model's u-PLKF correction (eq. (6), section IV-C: `_correct_with`, one scratch for all of them and the
    bearing's measured projection formed once, the same for every model), their likelihoods (seed 004 eq. (20),
    `_rank2_log_likelihoods_into`, the kernel of each S_j its model's predicted line of sight), the combined
    innovation for the health monitor (`_combined_innovation_into`), the model probabilities (eq. (21),
    `_posterior_probabilities_into`) and the mixing for the next cycle (eqs. (17)-(19), `_mix_in_place`).

    weights: c (n,), the next c written into it (after every use of the old c); pursuer_position and the unit
    bearing direction (3,); references: the own positions the gains start from, (n, 3), or (1, 3) for one every
    model takes (the model filters' shared OwnPositionTracker). noises, lines_of_sight, outputs, scalars and
    switches as `_imm_correction` takes them (lines_of_sight as `_prior_lines_of_sight` wrote them; each model's NIS
    y_j^T S_j^+ y_j written into nis when the _WITH_NIS switch is on, left alone otherwise; mu into probabilities;
    the combined innovation (3,) and covariance (3, 3) into innovation and innovation_covariance); predicted_range:
    the combined line of sight's length, m. The Markov matrix p_ij is over the interval since the last correction
    (`_markov_matrix_over`)."""
    measurement_noises, lead_noises = noises
    model_relative, ranges, model_ranges, relative = lines_of_sight
    nis, probabilities, innovation, innovation_covariance = outputs
    lead, position_variance = scalars[_LEAD], scalars[_POSITION_VARIANCE]
    switches_j = (switches[_USE_REFERENCE], True, switches[_LATE], switches[_ADD_POSITION_NOISE])
    count = states.shape[0]
    per_model = np.empty(count * (3 + 9 + 3 + 1))
    innovations = per_model[0:3 * count].reshape(count, 3)
    innovation_covariances = per_model[3 * count:12 * count].reshape(count, 3, 3)
    null_directions = per_model[12 * count:15 * count].reshape(count, 3)
    log_likelihoods = per_model[15 * count:16 * count]
    work = _correction_work()
    measured_projection = work[2][_MEASURED_PROJECTION]
    _measured_projection_into(direction, measured_projection, work[0][_UNIT])
    for j in range(count):
        bearing = (model_relative[j], direction, references[j if references.shape[0] > 1 else 0], pursuer_position)
        innovation_inverse = _correct_with(
            states[j], covariances[j], bearing, measured_projection, (measurement_noises[j], lead_noises[j]),
            (model_ranges[j], lead, position_variance), switches_j, (innovations[j], innovation_covariances[j]), work)
        if switches[_WITH_NIS]:
            nis[j] = _normalized_innovation_squared(innovations[j], innovation_inverse)
    np.divide(model_relative, ranges[:, None], null_directions)
    _rank2_log_likelihoods_into(innovations, innovation_covariances, ranges, null_directions, log_likelihoods)
    _combined_innovation_into(weights, innovations, innovation_covariances, relative, predicted_range, innovation,
                              innovation_covariance)
    _posterior_probabilities_into(log_likelihoods, weights, probabilities)
    _mix_in_place(probabilities, _markov_matrix_over(count, scalars[_STAY_PROBABILITY], scalars[_STAY_TIME],
                                                     scalars[_INTERVAL]), states, covariances, weights)


_CORRECTED, _RESTART, _MODEL_BY_MODEL, _NEEDS_REFERENCES = 0, 1, 2, 3
"""What `_imm_correction` did: corrected every model; nothing, the combined prior being behind the sensor (every
model restarts); nothing, some model filter correcting on its own (one restarts, or the gain is not PREDICTED:
IMMEstimator._correct_each); nothing, the own positions the gains start from to be given (`have_references`)."""


# `_imm_correction`'s packed arguments: its scalars (float64 (8,)) and its switches (bool (8,)), by index
_LEAD, _TRACK_DT, _ACCELERATION_PSD, _TRACK_STD, _POSITION_VARIANCE, _STAY_PROBABILITY, _STAY_TIME, _INTERVAL = range(8)
_CORRECTION_SCALARS = 8
(_RESTART_WHEN_BEHIND, _PREDICTED_GAIN, _HAVE_REFERENCES, _USE_REFERENCE, _TRACK_STEP, _LATE, _ADD_POSITION_NOISE,
 _WITH_NIS) = range(8)
_CORRECTION_SWITCHES = 8


@jit
def _imm_correction(states: np.ndarray, covariances: np.ndarray, weights: np.ndarray, pursuer_position: np.ndarray,
                    direction: np.ndarray, noises: tuple, own_positions: tuple, lines_of_sight: tuple, outputs: tuple,
                    scalars: np.ndarray, switches: np.ndarray) -> tuple[float, float, int]:
    """IMMEstimator.correct's kernel: one call for the whole usual correction (a kernel: companion.core._jit).

    states (n, 6), covariances (n, 6, 6) and weights (n,) (the predicted model probabilities c, then the next
    cycle's) are updated in place; pursuer_position and the unit bearing direction (3,). The rest packed:
    noises = (measurement_noises (n, 3, 3), lead_noises (n, 3, 3)); own_positions = (references (1 or n, 3), track
    (9,), prediction (3,)); lines_of_sight = (model_relative (n, 3), ranges (n,), model_ranges (n,), relative (3,)),
    written; outputs = (nis (n,), probabilities (n,), innovation (3,), innovation_covariance (3, 3)), written;
    scalars (float64, indexed by _LEAD, _TRACK_DT, _ACCELERATION_PSD, _TRACK_STD, _POSITION_VARIANCE,
    _STAY_PROBABILITY, _STAY_TIME, _INTERVAL) and switches (bool, indexed by _RESTART_WHEN_BEHIND, _PREDICTED_GAIN,
    _HAVE_REFERENCES, _USE_REFERENCE, _TRACK_STEP, _LATE, _ADD_POSITION_NOISE, _WITH_NIS).

    First the prior lines of sight (`_prior_lines_of_sight`, into lines_of_sight); then, unless the combined prior is
    behind the sensor (remark 3's guard, with the restart_when_behind switch: `_RESTART`), some model filter must
    correct on its own (a model restarting, or not predicted_gain: `_MODEL_BY_MODEL`) or the own positions are not
    given (not have_references: `_NEEDS_REFERENCES`), which leave the states alone: the own position the gains start
    from (the model filters' shared OwnPositionTracker's usual step, `_own_position_step` on `track` over track_dt s
    with its acceleration_psd and track_std, its prediction written into `prediction` and taken as every model's
    reference, with the track_step switch; else `references` as `_imm_correct_into` takes them) and every step of
    the IMM cycle (`_imm_correct_into`: the models' u-PLKF corrections, eq. (6), their likelihoods, seed 004 eq.
    (20), the model probabilities, eq. (21), the mixing, eqs. (17)-(19)), the combined innovation and its covariance
    written into outputs (`_CORRECTED`). Returns the combined prior's range, its clipped cosine to the bearing and
    what it did."""
    model_relative, ranges, model_ranges, relative = lines_of_sight
    references, track, prediction = own_positions
    lead = scalars[_LEAD]
    restart_when_behind = switches[_RESTART_WHEN_BEHIND]
    predicted_range, cos_angle, every_model_corrects = _prior_lines_of_sight(
        states, weights, lead, pursuer_position, direction, restart_when_behind, model_relative, ranges, model_ranges,
        relative)
    if restart_when_behind and _behind_sensor(cos_angle, predicted_range):
        return predicted_range, cos_angle, _RESTART
    if not (every_model_corrects and switches[_PREDICTED_GAIN]):
        return predicted_range, cos_angle, _MODEL_BY_MODEL
    if not switches[_HAVE_REFERENCES]:
        return predicted_range, cos_angle, _NEEDS_REFERENCES
    if switches[_TRACK_STEP]:  # OwnPositionTracker.reference's usual step, its prediction every model's reference
        _own_position_step(track, scalars[_TRACK_DT], scalars[_ACCELERATION_PSD], scalars[_TRACK_STD],
                           pursuer_position, prediction)
        references = prediction.reshape(1, 3)
    _imm_correct_into(states, covariances, weights, pursuer_position, direction, references, noises, lines_of_sight,
                      outputs, scalars, switches, predicted_range)
    return predicted_range, cos_angle, _CORRECTED


class IMMEstimator:
    """Interacting-multiple-model estimator over u-PLKF model filters (module docstring).

    Same interface as the u-PLKF (`TargetEstimator`). period: Delta t, s, of every model
    filter's prediction. models: the motion models (`standard_models`), at least one.
    measurement_noise: Sigma of eq. (4), (3, 3). gain_projection, pursuer_position_std,
    restart_when_behind, adaptive_noise: as the u-PLKF's, for every model filter.
    stay_probability: p_ii over stay_time s (module docstring); 1 never switches.
    initial_probabilities: mu_0, (n,); default: seed 004's 0.98 on the first model
    (constant velocity) and the rest split evenly.

    The model filters keep their states in rows of two stacked arrays of the IMM ((n, 6), (n, 6, 6)),
    which every step updates in place: a predict of all models, or a whole correction, is one kernel call
    (companion.core._jit) over them.
    """

    def __init__(
        self,
        period: float,
        models: Sequence[MotionModel],
        measurement_noise: np.ndarray,
        gain_projection: GainProjection = GainProjection.PREDICTED,
        *,
        pursuer_position_std: float = 0.0,
        restart_when_behind: bool = True,
        stay_probability: float = 0.98,
        stay_time: float = 1.0,
        initial_probabilities: Sequence[float] | None = None,
        adaptive_noise: AdaptiveNoiseSettings | None = None,
    ) -> None:
        if not models:
            raise ValueError("the IMM needs at least one motion model")
        if not (0.0 < stay_probability <= 1.0) or stay_time <= 0.0:
            raise ValueError("need 0 < stay_probability <= 1 and stay_time > 0")
        self.period = float(period)
        self.models = tuple(models)
        self.stay_probability = float(stay_probability)
        self.stay_time = float(stay_time)
        self.restart_when_behind = bool(restart_when_behind)
        count = len(self.models)
        self._states = np.zeros((count, 6))  # x^j, the model filters' own storage (UPLKF._use_storage)
        self._covariances = np.zeros((count, 6, 6))  # P^j
        self.filters: list[UPLKF] = []
        inputs = np.zeros((count, 6, 3))  # B_j, for the speed-change models' Q_d at every prediction
        for j, model in enumerate(self.models):
            a, b = coordinated_turn_matrices(self.period, model.turn_rate)
            inputs[j] = b
            # a speed-change model's filter keeps its largest variance as Q (what a late bearing's lead noise reads)
            process_noise = max(model.process_noise, model.along_track_noise) * np.eye(3)
            model_filter = UPLKF(self.period, process_noise, measurement_noise, gain_projection,
                                 pursuer_position_std=pursuer_position_std, restart_when_behind=restart_when_behind,
                                 adaptive_noise=adaptive_noise, transition=a,
                                 discrete_process_noise=b @ process_noise @ b.T)
            self.filters.append(model_filter)
        self._bind_storage()
        # one record of the sets of the model filters' process-noise factors (estimators.NoiseChanges), theirs and
        # this IMM's: `_collect_noise_factors` reads the factors again when its count has moved
        self._noise_changes = NoiseChanges()
        for model_filter in self.filters:
            model_filter._report_noise_changes_to(self._noise_changes)
        # One own-position tracker for every model filter (and one set of neighbours' trackers): they would be fed
        # the same samples (every one-call correction feeds each model filter's), so while they are
        # shared one reference per correction is every model's. `_correct_each`, where a model filter may restart
        # and skip its feed, gives each model filter its own copy first (`_separate_trackers`).
        self._shared_tracks = len(self.filters) > 1 and self.filters[0]._own_track is not None
        if self._shared_tracks:
            for model_filter in self.filters[1:]:
                model_filter._own_track = self.filters[0]._own_track
                model_filter._neighbour_tracks = self.filters[0]._neighbour_tracks
        # the model filters' fixed matrices, stacked for the kernels
        self._transitions = np.array([model_filter._a for model_filter in self.filters])
        self._discrete_process_noises = np.array([model_filter._q_discrete for model_filter in self.filters])
        self._measurement_noises = np.array([model_filter.measurement_noise for model_filter in self.filters])
        # the speed-change models (MotionModel.along_track_noise > 0): their indices, q_a, q and B
        along = np.array([model.along_track_noise for model in self.models], dtype=float)
        self._speed_models = np.flatnonzero(along > 0.0)
        self._speed_noise_terms = (along, np.array([model.process_noise for model in self.models], dtype=float), inputs)
        self._no_references, self._no_lead_noises = np.zeros((count, 3)), np.zeros((count, 3, 3))  # not used / zero
        self._no_track = np.zeros(9), np.zeros(3)  # `_imm_correction`'s track and prediction without a tracker's step
        # the prior lines of sight of a correction (`_prior_lines_of_sight` writes them): p^-_T,j - p (n, 3), their
        # lengths twice (n,) (as summed by the IMM, as by each model filter), the combined p^-_T - p (3,)
        self._lines_of_sight = (np.empty((count, 3)), np.empty(count), np.empty(count), np.empty(3))
        self._nis = np.zeros(count)  # each model's NIS of the last correction (`_imm_correct_into` writes it)
        # each model filter's adaptive scale and boost for `_predict_models` and its adaptive noise (None: off), as
        # collected when the count of `_noise_changes` was `_noise_count` (`_collect_noise_factors`)
        self._scales, self._boosts = np.ones(count), np.ones(count)
        self._adaptive_noises: tuple[AdaptiveProcessNoise | None, ...] = (None,) * count
        self._any_adaptive = False
        self._noise_count = -1
        if initial_probabilities is None:
            initial = np.full(count, 0.02 / (count - 1)) if count > 1 else np.ones(1)
            initial[0] = 0.98 if count > 1 else 1.0
        else:
            initial = np.asarray(initial_probabilities, dtype=float).reshape(count)
            if np.any(initial < 0.0) or not math.isclose(float(initial.sum()), 1.0, rel_tol=1e-9):
                raise ValueError("initial_probabilities must be a probability distribution over the models")
        self.initial_probabilities = initial
        rates = np.array([model.turn_rate for model in self.models])
        self._turn_rates = rates  # omega_j, rad/s (`acceleration`)
        self._motion_masks = (rates == 0.0, rates > 0.0, rates < 0.0)
        self._set_probabilities(initial.copy())  # mu_k after the last correction
        self._weights = initial.copy()  # c_j: weights of the model filters' current states
        self._last_correction_time: float | None = None
        self._initial_guess: InitialGuess | None = None
        self._snapshot: TargetEstimate | None = None
        self._process_noise_boost = 1.0
        self._started = False  # every model filter has started (`_require_states`)

    def _bind_storage(self) -> None:
        """Each model filter keeps its x and P in its row of the stacked arrays (UPLKF._use_storage)."""
        for j, model_filter in enumerate(self.filters):
            started = model_filter._state is not None
            model_filter._state = model_filter._covariance = None
            model_filter._use_storage(self._states[j], self._covariances[j])
            if started:
                model_filter._state, model_filter._covariance = self._states[j], self._covariances[j]

    def __setstate__(self, state: dict) -> None:
        """A copy (copy.deepcopy, pickle) binds its model filters to its own stacked arrays again: copying
        loses the rows' view of them."""
        self.__dict__.update(state)
        self._bind_storage()

    # --- the TargetEstimator interface ------------------------------------------------

    @property
    def initialized(self) -> bool:
        return self.filters[0].initialized

    @property
    def time(self) -> float:
        """Time of the current estimate, s (the model filters share one clock)."""
        return self.filters[0].time

    @property
    def estimate(self) -> TargetEstimate:
        """The combined estimate, seed 004 eqs. (22)-(23) (a snapshot, kept until the next step changes the states)."""
        snapshot = self._snapshot
        if snapshot is None:
            filters = self.filters
            if len(filters) == 1:
                snapshot = self._snapshot = filters[0].estimate
            else:
                if not self._started:
                    self._require_states()
                # fresh arrays every time: the snapshot handed out is never written again
                position, velocity, covariance = np.empty(3), np.empty(3), np.empty((6, 6))
                position_std = _combined_estimate(self._weights, self._states, self._covariances, position, velocity,
                                                  covariance)
                snapshot = self._snapshot = _target_estimate(filters[0].time, position, velocity, covariance, position_std)
        return snapshot

    @property
    def acceleration(self) -> np.ndarray:
        """The target's expected acceleration, m/s^2, shape (3,) NED: sum_j mu_j omega_j J v_h,j, each model's
        coordinated-turn acceleration (coordinated_turn_matrices: d/dt v_h = omega J v_h, J = [[0, -1], [1, 0]];
        no vertical part) weighted by its probability. Zero for the constant-velocity model; a feed-forward
        for guidance laws that take one (companion.core.cooperative_guidance)."""
        if not self._started and self._turn_rates.any():
            self._require_states()  # a turning model's UPLKF RuntimeError before the first bearing
        total = np.zeros(3)
        _turn_acceleration_into(self._probabilities, self._turn_rates, self._states, total)
        return total

    def _require_states(self) -> None:
        """Every model filter has started (else UPLKF's RuntimeError). Once they all have, `_started` says so and
        the steps skip this check (a started filter never stops: its storage is fixed, `_bind_storage`)."""
        for model_filter in self.filters:
            if model_filter._state is None or model_filter._covariance is None:  # the check, without a call per filter
                model_filter._require_state()
        self._started = True

    @property
    def model_probabilities(self) -> np.ndarray:
        """mu_k, shape (n,), in the order of `models`: each model's probability after the last
        correction (the initial probabilities before any)."""
        return self._probabilities.copy()

    @property
    def speed_change_probability(self) -> float | None:
        """The model probability on the speed-change models (manoeuvre_model: along-track acceleration noise)
        after the last correction; None when the model set has none."""
        if not self._speed_models.size:
            return None
        return float(self._probabilities[self._speed_models].sum())

    @property
    def model_names(self) -> tuple[str, ...]:
        return tuple(model.name for model in self.models)

    @property
    def motion_probabilities(self) -> tuple[float, float, float]:
        """(straight, right turn, left turn): mu_k summed over the constant-velocity models
        (turn_rate 0), the right turns (> 0) and the left turns (< 0); fixed-width, for logs
        (summed once per change of mu_k)."""
        if self._motion_probabilities is None:
            self._motion_probabilities = tuple(float(self._probabilities[mask].sum()) for mask in self._motion_masks)
        return self._motion_probabilities

    def _set_probabilities(self, probabilities: np.ndarray) -> None:
        """mu_k := probabilities (n,) (its sums by motion follow on the next read of `motion_probabilities`)."""
        self._probabilities = probabilities
        self._motion_probabilities: tuple[float, float, float] | None = None

    @property
    def process_noise_boost(self) -> float:
        """The factor on every model filter's discrete process noise (UPLKF.process_noise_boost)."""
        return self._process_noise_boost

    @process_noise_boost.setter
    def process_noise_boost(self, value: float) -> None:
        self._process_noise_boost = float(value)
        for model_filter in self.filters:
            model_filter.process_noise_boost = self._process_noise_boost

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        """Every model filter starts on the bearing (remark 3); probabilities back to their initial values."""
        self._initial_guess = initial_guess
        for model_filter in self.filters:
            model_filter.initialize_on_bearing(bearing, initial_guess)
        self._reset_probabilities()

    def set_model_states(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        """Replace every model filter's [p_T, v_T] (6,) and covariance (6, 6), in the order of `models`,
        keeping the clock and the model probabilities (track fusion with neighbours' estimates,
        companion.core.cooperative_estimation.FusionEstimator)."""
        if len(pairs) != len(self.filters):
            raise ValueError(f"need {len(self.filters)} model states, got {len(pairs)}")
        # copied first: a pair may be a view of the storage that an earlier model's set_state overwrites
        pairs = [(np.array(state, dtype=float), np.array(covariance, dtype=float)) for state, covariance in pairs]
        for model_filter, (state, covariance) in zip(self.filters, pairs):
            model_filter.set_state(state, covariance)
        self._snapshot = None

    def predict(self) -> None:
        """Each model filter's own time update over one period (all in one `_predict_models` call)."""
        self._snapshot = None
        filters = self.filters
        if not self._started:
            self._require_states()
        if self._speed_models.size:
            along, across, inputs = self._speed_noise_terms
            _speed_change_noises_into(self._speed_models, self._states, along, across, inputs,
                                      self._discrete_process_noises)
            if len(filters) == 1:
                filters[0]._q_discrete[:, :] = self._discrete_process_noises[0]
        if len(filters) == 1:
            filters[0].predict()
            return
        if self._noise_count != self._noise_changes.count:  # a scale or a boost may have changed since
            self._collect_noise_factors()
        _predict_models(self._transitions, self._discrete_process_noises, self._scales, self._boosts, self._states,
                        self._covariances)
        for model_filter in filters:  # UPLKF._advance_clock, without a call per model filter
            model_filter._snapshot = None
            model_filter._ticks += 1

    def _collect_noise_factors(self) -> None:
        """Each model filter's adaptive scale and boost (UPLKF.predict's factors) into `_scales` and `_boosts` (new
        arrays) and its adaptive noise into `_adaptive_noises` (`_any_adaptive`: any not None), as of the count of
        `_noise_changes` read first (a change made meanwhile moves the count again)."""
        self._noise_count = self._noise_changes.count
        filters = self.filters
        self._scales = np.array([model_filter.process_noise_scale for model_filter in filters], dtype=float)
        self._boosts = np.array([float(model_filter.process_noise_boost) for model_filter in filters], dtype=float)
        self._adaptive_noises = tuple(model_filter._adaptive_noise for model_filter in filters)
        self._any_adaptive = any(noise is not None for noise in self._adaptive_noises)

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        """Model-conditioned corrections, model probabilities, then the mixing for the next cycle.

        The usual correction (PREDICTED gains, no model restarting) is one `_imm_correction` call, the own-position
        tracker's step included; `_correct_each` takes the other cases. The report's innovation is that of the
        combined prediction (see `_combined_report`).
        """
        filters = self.filters
        if len(filters) == 1:
            self._snapshot = None
            return filters[0].correct(bearing)
        if not self._started:
            self._require_states()
        if self._noise_count != self._noise_changes.count:  # an adaptive noise may have come or gone since
            self._collect_noise_factors()
        first = filters[0]
        time = bearing.time
        lead = time - first.time
        pursuer_position = np.asarray(bearing.pursuer_position, dtype=float)
        direction = bearing.unit_direction
        interval = self.stay_time if self._last_correction_time is None else time - self._last_correction_time
        late = abs(lead) > _LEAD_EPSILON  # (UPLKF._correction_inputs)
        lead_noises = np.array([model_filter._lead_noise(lead) for model_filter in filters]) if late else self._no_lead_noises
        # The own position the gains start from: none without an own-position tracker; with the model filters' shared
        # tracker, its usual step inside the kernel, or the reference of a repeated or late sample, which it does not
        # take in (OwnPositionTracker._plan); else (a first sample or one after a gap, which restart the tracker, or
        # trackers no longer shared) `_references`, once the kernel has found that every model corrects.
        track, prediction = self._no_track
        references, track_dt, tracker = self._no_references, None, None
        own_track = first._own_track
        have_references = own_track is None
        if own_track is not None and self._shared_tracks:
            tracker = own_track if bearing.source == 0 else first._neighbour_tracks.get(bearing.source)
            if tracker is not None:
                track_dt, reference = tracker._plan(time)
                if track_dt is not None:
                    track, prediction, have_references = tracker._filter, np.empty(3), True
                else:
                    tracker = None
                    if reference is not None:
                        references, have_references = reference[None, :], True
        model_relative, ranges, model_ranges, relative = self._lines_of_sight
        position_std = first.pursuer_position_std
        scalars = np.array([lead, 0.0 if track_dt is None else track_dt,
                            0.0 if tracker is None else tracker.acceleration_psd,
                            0.0 if tracker is None else tracker.position_std, position_std**2, self.stay_probability,
                            self.stay_time, interval], dtype=float)
        switches = np.array([self.restart_when_behind, first.gain_projection is GainProjection.PREDICTED,
                             have_references, own_track is not None, tracker is not None, late, position_std > 0.0,
                             self._any_adaptive], dtype=bool)
        innovation, innovation_covariance = np.empty(3), np.empty((3, 3))
        arguments = (self._states, self._covariances, self._weights, pursuer_position, direction,
                     (self._measurement_noises, lead_noises))
        records = (self._lines_of_sight, (self._nis, self._probabilities, innovation, innovation_covariance))
        predicted_range, cos_angle, outcome = _imm_correction(*arguments, (references, track, prediction), *records,
                                                              scalars, switches)
        if outcome == _NEEDS_REFERENCES:
            scalars[_TRACK_DT] = scalars[_ACCELERATION_PSD] = scalars[_TRACK_STD] = 0.0
            switches[_HAVE_REFERENCES], switches[_USE_REFERENCE], switches[_TRACK_STEP] = True, True, False
            predicted_range, cos_angle, outcome = _imm_correction(
                *arguments, (self._references(bearing, lead, direction), track, prediction), *records, scalars,
                switches)
        if outcome == _RESTART:
            guess = restart_guess(self._initial_guess, predicted_range, self._weights @ self._states[:, 3:])
            for model_filter in filters:
                model_filter.initialize_on_bearing(bearing, guess)
            self._reset_probabilities()
            return CorrectionReport(float(np.arccos(cos_angle)), False, reinitialized=True)
        if outcome == _CORRECTED:
            if tracker is not None:  # the rest of the tracker's usual step (OwnPositionTracker.reference)
                tracker._last_prediction = prediction
                tracker._time = time
            if self._any_adaptive:
                nis = self._nis
                for j, noise in enumerate(self._adaptive_noises):
                    if noise is not None:  # UPLKF._note_innovation with the kernel's NIS
                        noise.update(time, float(nis[j]), 2)
            for model_filter in filters:
                model_filter._snapshot = None
            self._motion_probabilities = None  # mu_k, written in place: its sums by motion anew (`_set_probabilities`)
            self._snapshot = None
            report = _correction_report(float(np.arccos(cos_angle)), True, innovation, innovation_covariance, 2)
        else:
            report = self._correct_each(bearing, model_relative, ranges, relative, predicted_range, cos_angle, interval)
        self._last_correction_time = time
        return report

    def _references(self, bearing: BearingMeasurement, lead: float, direction: np.ndarray) -> np.ndarray:
        """The own positions every model's gain starts from (UPLKF._correction_inputs, which feeds the own-position
        trackers this bearing's position): (1, 3), the one of the shared tracker, or (n, 3), each model filter's."""
        if self._shared_tracks:
            return self.filters[0]._correction_inputs(bearing, lead, direction)[0][None, :]
        return np.array([model_filter._correction_inputs(bearing, lead, direction)[0] for model_filter in self.filters])

    def _correct_each(self, bearing: BearingMeasurement, model_relative: np.ndarray, ranges: np.ndarray,
                      relative: np.ndarray, predicted_range: float, cos_angle: float, interval: float) -> CorrectionReport:
        """The correction model filter by model filter (any gain projection; models may restart on the bearing)."""
        self._separate_trackers()
        reports = [model_filter.correct(bearing) for model_filter in self.filters]
        self._snapshot = None
        if all([r.innovation is not None and r.innovation_covariance is not None for r in reports]) and (ranges > 0.0).all():
            innovations = np.array([r.innovation for r in reports])
            covariances = np.array([r.innovation_covariance for r in reports])
            if reports[0].used_predicted_projection:  # the kernel of each S_j is its model's predicted line of sight
                log_likelihoods = rank2_log_likelihoods(innovations, covariances, ranges, model_relative / ranges[:, None])
            else:
                log_likelihoods = np.array([rank2_log_likelihood(y, c, r) for y, c, r in zip(innovations, covariances, ranges)])
            report = self._combined_report(self._weights, innovations, covariances, relative, predicted_range, cos_angle,
                                           reports[0].used_predicted_projection)
        else:  # a model restarted on this bearing: it has no likelihood and no innovation
            used = [j for j, r in enumerate(reports) if r.innovation is not None and r.innovation_covariance is not None
                    and ranges[j] > 0.0]
            log_likelihoods = np.full(len(reports), -math.inf)
            for j in used:
                log_likelihoods[j] = rank2_log_likelihood(reports[j].innovation, reports[j].innovation_covariance, ranges[j])
            if used:
                weights = self._weights[used]
                weights = weights / weights.sum() if weights.sum() > 0.0 else np.full(len(used), 1.0 / len(used))
                report = self._combined_report(weights, np.array([reports[j].innovation for j in used]),
                                               np.array([reports[j].innovation_covariance for j in used]),
                                               relative, predicted_range, cos_angle, reports[0].used_predicted_projection)
            else:
                report = CorrectionReport(float(np.arccos(cos_angle)), reports[0].used_predicted_projection, reinitialized=True)
        self._set_probabilities(self._updated_probabilities(log_likelihoods))
        self._weights = _mix_into(self._probabilities, self.markov_matrix(interval), self._states, self._covariances)
        for model_filter in self.filters:
            model_filter._snapshot = None
        return report

    def _separate_trackers(self) -> None:
        """Give every model filter its own copy of the shared own-position trackers (from now on each feeds its own):
        before a correction in which a model filter may restart and skip its feed, so the trackers of the others
        go on exactly as separate trackers fed the same samples until now would."""
        if not self._shared_tracks:
            return
        self._shared_tracks = False
        first = self.filters[0]
        for model_filter in self.filters[1:]:
            model_filter._own_track = copy.deepcopy(first._own_track)
            model_filter._neighbour_tracks = copy.deepcopy(first._neighbour_tracks)

    # --- the IMM steps -----------------------------------------------------------------

    def markov_matrix(self, interval: float) -> np.ndarray:
        """p_ij over `interval` s: p_ii = stay_probability^(interval / stay_time) (module docstring)."""
        return _markov_matrix_over(len(self.models), self.stay_probability, self.stay_time, float(interval))

    def _updated_probabilities(self, log_likelihoods: np.ndarray) -> np.ndarray:
        """mu^j = Lambda^j c_j / sum_t Lambda^t c_t, seed 004 eq. (21), in logarithms (`_posterior_probabilities`).
        With no finite likelihood (every model restarted) the predicted probabilities c stand."""
        return _posterior_probabilities(np.asarray(log_likelihoods, dtype=float), self._weights)

    @staticmethod
    def _combined_report(weights: np.ndarray, innovations: np.ndarray, covariances: np.ndarray, relative: np.ndarray,
                         predicted_range: float, cos_angle: float, used_predicted: bool) -> CorrectionReport:
        """The innovation of the combined prediction, for the health monitor.

        y = P_lambda~ (p^-_T - p) of the combined prior is sum_j c_j y_j (the pseudo-measurement
        is linear in the prior); its covariance is the moment-matched mixture
        sum_j c_j [S_j + (y_j - y)(y_j - y)^T], projected across the combined predicted line of
        sight so it keeps rank 2 (each S_j is singular along its own model's line of sight).
        The combined innovation rather than the most likely model's: the monitor judges the
        estimate the guidance flies on, which is the combination; the most likely model's
        innovation looks consistent whenever one model fits, even while the models disagree
        and the combination is off, and the mixture's S grows with that disagreement.
        Models that restarted on this bearing (no innovation) are left out (weights renormalised).
        weights (n,), innovations (n, 3), covariances (n, 3, 3); relative: the combined p^-_T - p, m.
        The arithmetic: `_combined_innovation`.
        """
        innovation, covariance = _combined_innovation(
            *(np.ascontiguousarray(value, dtype=float) for value in (weights, innovations, covariances, relative)),
            float(predicted_range))
        return CorrectionReport(float(np.arccos(cos_angle)), used_predicted, innovation=innovation,
                                innovation_covariance=covariance, innovation_dof=2)

    def _reset_probabilities(self) -> None:
        self._set_probabilities(self.initial_probabilities.copy())
        self._weights = self.initial_probabilities.copy()
        self._last_correction_time = None
        self._snapshot = None
