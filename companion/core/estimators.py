"""Bearing-only target estimators (section IV).

Every estimator here has the same narrow interface (`TargetEstimator`) so the
pipeline, the simulators and the comparison tools can swap them by config.

State convention. The paper writes the filter on the relative state
x = x_T - x_P, eq. (2), whose prediction is x^-_k = A(x_{k-1} + x_{P,k-1}) - x_{P,k}.
That is the same as propagating the absolute target state x_T = x + x_P with A,
so the filter stores x_T = [p_T, v_T] (what guidance needs) and forms the
relative vector p_T - p only inside the correction, exactly where eq. (6) uses it.
Pursuer position errors then enter only through the measurement, as they do in
the real system.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.linalg import null_space

from companion.core._jit import jit, jit_inline, objmode
from companion.core.geometry import orthogonal_projection, unit
from companion.core.messages import BearingMeasurement, TargetEstimate, fast_frozen


class TargetEstimator(Protocol):
    """What the pipeline needs from a bearing-only target estimator."""

    period: float

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: "InitialGuess") -> None: ...

    def predict(self) -> None: ...

    def correct(self, bearing: BearingMeasurement) -> "CorrectionReport": ...

    @property
    def initialized(self) -> bool: ...

    @property
    def estimate(self) -> TargetEstimate: ...


@dataclass(frozen=True)
class InitialGuess:
    """Prior knowledge used to start the filter on the first bearing (remark 3, section VI-B).

    range: r_hat(0), m, the guessed distance along the first bearing.
    range_std: m, 1-sigma uncertainty of that guess along the bearing.
    velocity: m/s, shape (3,), guessed target velocity.
    velocity_std: m/s, 1-sigma per axis.
    position: m, shape (3,), NED. When given, the filter starts at this target position
    instead of on the first bearing, with an isotropic range_std (the initialisation
    study of section VIII-B draws it at random); None (default) is remark 3.
    """

    range: float
    range_std: float
    velocity: np.ndarray
    velocity_std: float
    position: np.ndarray | None = None


@dataclass(frozen=True)
class CorrectionReport:
    """What one correction did, for logs and diagnostics.

    innovation_angle: rad, angle between the measured bearing and the predicted line of sight.
    used_predicted_projection: whether the gain used the predicted (instrumental) projection.
    reinitialized: the prediction lay behind the sensor (angle > 90 deg), so the filter
    restarted on this bearing instead of correcting.
    innovation: the residual the update used, shape (m,) (the u-PLKF's pseudo-measurement
    P_lambda~ (p^-_T - p), m, shape (3,); angles in rad for the angle-measuring baselines),
    None when there was no update. innovation_covariance: its predicted covariance S, shape
    (m, m) (rank 2 for the u-PLKF). innovation_dof: degrees of freedom of the measurement
    (the rank of S: 2 for a bearing, 3 with a range); 0 without innovation. For the filter
    health monitor (companion.core.health); the update itself never reads them.
    """

    innovation_angle: float
    used_predicted_projection: bool
    reinitialized: bool = False
    innovation: np.ndarray | None = None
    innovation_covariance: np.ndarray | None = None
    innovation_dof: int = 0


def _correction_report(innovation_angle: float, used_predicted_projection: bool, innovation: np.ndarray,
                       innovation_covariance: np.ndarray, innovation_dof: int) -> CorrectionReport:
    """CorrectionReport(innovation_angle, used_predicted_projection, False, innovation, innovation_covariance,
    innovation_dof) of a correction that updated, without the frozen dataclass's object.__setattr__ per field
    (one is built at every correction): the same object, field for field."""
    return fast_frozen(CorrectionReport, innovation_angle=innovation_angle, used_predicted_projection=used_predicted_projection,
                       reinitialized=False, innovation=innovation, innovation_covariance=innovation_covariance,
                       innovation_dof=innovation_dof)


class GainProjection(enum.Enum):
    """Which bearing builds the projection in the Kalman gain of the u-PLKF."""

    MEASURED = "measured"
    """The paper's form: H_k = [P_lambda~, 0] from the noisy bearing, section IV-C."""

    PREDICTED = "predicted"
    """Instrumental-variable form: gain from the predicted line of sight (uncorrelated with the current noise)."""

    NOISE_FREE = "noise_free"
    """The "optimal u-PLKF" of section VIII-B: H_k = [P_lambda, 0] from the true line of sight
    (BearingMeasurement.true_direction), in the gain and the residual. A simulation-only
    benchmark: it shows what a perfect bearing would give, and cannot fly."""



MAX_RANGE = 1.0e6
"""m: ceiling on the estimated target range. A numerical guard, not a model: a filter fed
bearings far noisier than its Sigma (noise_std = 1 against Sigma = 1e-4 I) pushes its range
out at nearly every correction, to 1e29 m within a minute of 50 Hz bearings and on to
overflow, and a following drone never has a target 1000 km away. A corrected estimate beyond it is pulled
back along its line of sight (`limit_range`); restarts use at most this range. The
MSC-EKF's inverse-range floor (baseline_estimators.MIN_INVERSE_RANGE) is the same bound."""


@jit
def limit_range(target_position: np.ndarray, pursuer_position: np.ndarray) -> np.ndarray:
    """The target position (m, NED, shape (3,)) moved along its line of sight from the
    pursuer (m, shape (3,)) to at most MAX_RANGE away; the same array when already within.
    Float64 arrays (a kernel: companion.core._jit)."""
    relative = target_position - pursuer_position
    distance = math.sqrt(float(np.dot(relative, relative)))  # np.linalg.norm's own formula, without its wrapper
    if distance <= MAX_RANGE:
        return target_position
    return pursuer_position + (MAX_RANGE / distance) * relative


def transition_matrices(period: float) -> tuple[np.ndarray, np.ndarray]:
    """A and B of the discrete double integrator, eq. (1).

    period: Delta t, s. Returns A shape (6, 6) and B shape (6, 3).
    """
    eye = np.eye(3)
    a = np.block([[eye, period * eye], [np.zeros((3, 3)), eye]])
    b = np.vstack([0.5 * period**2 * eye, period * eye])
    return a, b


_SMALL_TURN_ANGLE = 1e-4
"""rad: below this |omega Delta t| the coordinated-turn coefficients use their Taylor series
(the closed forms divide by omega and lose digits to cancellation)."""


def coordinated_turn_matrices(period: float, turn_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """A and B of the 3-D coordinated turn at a known turn rate about the NED down axis.

    The target's horizontal velocity rotates at turn_rate omega (rad/s; positive is a
    clockwise turn seen from above, i.e. a right turn: the heading psi = atan2(v_E, v_N)
    grows at omega), its vertical velocity is constant:

        d/dt p = v,   d/dt v_h = omega J v_h + a_h,   d/dt v_D = a_D,   J = [[0, -1], [1, 0]],

    with a the target acceleration held constant over each period, the same noise model as
    eq. (1) (whose double integrator this is at omega = 0). The discretisation is exact:
    A = exp(F Delta t) and B = int_0^Delta t exp(F s) ds L, L = [0; I]. With theta = omega Delta t,
    the horizontal blocks are

        A_vv = R(theta) = [[c, -s], [s, c]],           A_pv = [[s, -(1 - c)], [1 - c, s]] / omega,
        B_v = A_pv,                                      B_p = [[1 - c, -(theta - s)], [theta - s, 1 - c]] / omega^2,

    c = cos theta, s = sin theta; the down axis is eq. (1)'s. As omega -> 0 both tend to
    `transition_matrices` (A_pv -> Delta t I, B_p -> Delta t^2 / 2 I); for
    |theta| < 1e-4 the series to theta^2 are used, exactly eq. (1) at omega = 0.

    period: Delta t, s. turn_rate: omega, rad/s. Returns A shape (6, 6), B shape (6, 3),
    state order [p_N, p_E, p_D, v_N, v_E, v_D].
    """
    a, b = transition_matrices(period)
    theta = turn_rate * period
    if theta == 0.0:
        return a, b
    if abs(theta) < _SMALL_TURN_ANGLE:
        # sin(theta)/omega, (1 - cos)/omega, (1 - cos)/omega^2, (theta - sin)/omega^2 to second order in theta
        sin_w = period * (1.0 - theta**2 / 6.0)
        one_minus_cos_w = period * (theta / 2.0 - theta**3 / 24.0)
        one_minus_cos_w2 = period**2 * (0.5 - theta**2 / 24.0)
        theta_minus_sin_w2 = period**2 * (theta / 6.0 - theta**3 / 120.0)
    else:
        sin_w = math.sin(theta) / turn_rate
        one_minus_cos_w = (1.0 - math.cos(theta)) / turn_rate
        one_minus_cos_w2 = (1.0 - math.cos(theta)) / turn_rate**2
        theta_minus_sin_w2 = (theta - math.sin(theta)) / turn_rate**2
    cos_t, sin_t = math.cos(theta), math.sin(theta)
    rotation = np.array([[cos_t, -sin_t], [sin_t, cos_t]])
    position_from_velocity = np.array([[sin_w, -one_minus_cos_w], [one_minus_cos_w, sin_w]])
    position_from_acceleration = np.array([[one_minus_cos_w2, -theta_minus_sin_w2],
                                           [theta_minus_sin_w2, one_minus_cos_w2]])
    a[0:2, 3:5] = position_from_velocity
    a[3:5, 3:5] = rotation
    b[0:2, 0:2] = position_from_acceleration
    b[3:5, 0:2] = position_from_velocity
    return a, b


SHORTCUT_EIGENVALUE_BAND = (2.0**-10, 2.0**10)
"""Bounds on the non-zero eigenvalues of the innovation covariance (m^2 scale) inside which
`_projector_pseudo_inverse` uses the one-inverse shortcut; outside it, the general form."""


_EYE3 = np.eye(3)
_EYE3.flags.writeable = False

# The numeric kernels below (`@jit`) are plain Python functions over float64 arrays, compiled by numba when it is
# installed (companion.core._jit): the same arithmetic in the same order either way, the matrix products in BLAS.


@jit
def _projector(unit_vector: np.ndarray) -> np.ndarray:
    """I - g g^T for a unit g (3,), shape (3, 3): eq. (5) for an already normalised vector.
    The same arithmetic as np.eye(3) - np.outer(g, g), without their per-call allocations."""
    return _EYE3 - unit_vector[:, None] * unit_vector


@jit_inline
def _projector_into(unit_vector: np.ndarray, out: np.ndarray) -> None:
    """`_projector` written into out (3, 3): the same products g_i g_j, then the same differences from I."""
    np.multiply(unit_vector[:, None], unit_vector, out)
    np.subtract(_EYE3, out, out)


@jit
def _solve_identity(matrix: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """(M^-1, det M, ok) for a 3x3 M, by the adjugate: M^-1 = adj(M) / det M, det M by cofactors along the first
    row. Accurate for the well-conditioned matrices it is used on (`_projector_pseudo_inverse`'s shortcut, whose
    eigenvalues lie in SHORTCUT_EIGENVALUE_BAND). ok is False when det M is 0 or not finite (no inverse)."""
    inverse = np.empty((3, 3))
    determinant, regular = _solve_identity_into(matrix, inverse)
    return inverse, determinant, regular


@jit_inline
def _solve_identity_into(matrix: np.ndarray, inverse: np.ndarray) -> tuple[float, bool]:
    """`_solve_identity` with M^-1 written into inverse (3, 3); returns (det M, ok). inverse may be matrix itself."""
    a, b, c = matrix[0, 0], matrix[0, 1], matrix[0, 2]
    d, e, f = matrix[1, 0], matrix[1, 1], matrix[1, 2]
    g, h, k = matrix[2, 0], matrix[2, 1], matrix[2, 2]
    c00, c01, c02 = e * k - f * h, c * h - b * k, b * f - c * e
    c10, c11, c12 = f * g - d * k, a * k - c * g, c * d - a * f
    c20, c21, c22 = d * h - e * g, b * g - a * h, a * e - b * d
    determinant = a * c00 + b * c10 + c * c20
    if determinant == 0.0 or not math.isfinite(determinant):
        return 0.0, False
    inverse[0, 0], inverse[0, 1], inverse[0, 2] = c00 / determinant, c01 / determinant, c02 / determinant
    inverse[1, 0], inverse[1, 1], inverse[1, 2] = c10 / determinant, c11 / determinant, c12 / determinant
    inverse[2, 0], inverse[2, 1], inverse[2, 2] = c20 / determinant, c21 / determinant, c22 / determinant
    return determinant, True


def _eigenvalues_not_negative(covariance: np.ndarray) -> bool:
    """not np.linalg.eigvalsh(covariance)[0] < 0: the PSD test `_is_positive_semidefinite` falls back to (a NaN
    eigenvalue is not negative; eigvalsh's LinAlgError propagates)."""
    return bool(not np.linalg.eigvalsh(covariance)[0] < 0.0)


@jit
def _is_positive_semidefinite(covariance: np.ndarray) -> bool:
    """Whether the symmetric covariance (n, n) is PSD, i.e. not np.linalg.eigvalsh(covariance)[0] < 0, cheaply.

    A Cholesky factorisation (np.linalg.cholesky, lower triangle as eigvalsh reads it) succeeds for a positive
    definite matrix at a sixth of the cost of np.linalg.eigvalsh on a 6x6; when it fails (or its factor is not
    finite) the decision is eigvalsh's, so a positive semi-definite singular matrix is still accepted and a NaN
    gets eigvalsh's answer (or error). The two can disagree only when Cholesky succeeds while eigvalsh's smallest
    eigenvalue is negative at rounding level (|lambda_min| ~ 1e-16 ||P||, where its sign is rounding noise): then
    the short form is kept, a matrix Cholesky-factorisable to working precision."""
    if _cholesky_succeeds(covariance):
        return True
    return _eigenvalues_not_negative_compiled(covariance)  # rare (a singular or non-finite covariance)


@jit
def _cholesky_succeeds(covariance: np.ndarray) -> bool:
    """Whether np.linalg.cholesky factors the symmetric covariance (n, n) into a finite factor."""
    try:
        factor = np.linalg.cholesky(covariance)
    except Exception:  # LinAlgError: not positive definite
        return False
    trace = 0.0  # finite or not: the order of the sum does not matter (each term is at most ~1e154)
    for i in range(factor.shape[0]):
        trace += factor[i, i]
    return math.isfinite(trace)


@jit
def _eigenvalues_not_negative_compiled(covariance: np.ndarray) -> bool:
    """`_eigenvalues_not_negative` (numpy's eigvalsh itself, in object mode) from a kernel."""
    with objmode(result="boolean"):
        result = _eigenvalues_not_negative(covariance)
    return result


#: Neighbour position trackers kept by one u-PLKF (the oldest is dropped beyond it): more than any swarm flies.
MAX_TRACKED_SOURCES = 64

#: |bearing time - filter time| (s) below which a bearing counts as taken at the filter's time: the in-process
#: simulator's bearings fall on estimator ticks to rounding, and take exactly the paper's H = [P_lambda, 0].
_LEAD_EPSILON = 1e-9

_ZERO33 = np.zeros((3, 3))  # the lead noise of a bearing at the filter's time (never written; writable like the
# late bearings' own, so the compiled correction has one signature)


def _general_pseudo_inverse(matrix: np.ndarray, null_direction: np.ndarray) -> np.ndarray:
    """E (E^T S E)^+ E^T, `_projector_pseudo_inverse`'s general form (C-ordered, (3, 3))."""
    basis = null_space(np.reshape(null_direction, (1, 3)))
    block = basis.T @ matrix @ basis
    return np.ascontiguousarray(basis @ np.linalg.pinv(0.5 * (block + block.T), hermitian=True) @ basis.T)


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
    result = np.empty((3, 3))
    work = np.empty((2, 3, 3))
    _projector_pseudo_inverse_into(matrix, null_direction, result, work[0], work[1])
    return result


@jit_inline
def _projector_pseudo_inverse_into(matrix: np.ndarray, null_direction: np.ndarray, out: np.ndarray, outer: np.ndarray,
                                   shifted: np.ndarray) -> None:
    """`_projector_pseudo_inverse` written into out (3, 3), C-ordered; outer and shifted (3, 3) its scratch."""
    np.multiply(null_direction[:, None], null_direction, outer)  # np.outer's arithmetic without its argument handling
    low, high = SHORTCUT_EIGENVALUE_BAND
    trace = float(matrix[0, 0] + matrix[1, 1] + matrix[2, 2])
    if low <= trace <= high:
        np.add(matrix, outer, shifted)
        determinant, regular = _solve_identity_into(shifted, shifted)
        if regular and determinant >= low * trace:  # smallest eigenvalue >= det / trace >= low
            np.subtract(shifted, outer, out)
            return
    _general_pseudo_inverse_into(matrix, null_direction, out)  # rare (a diverging filter)


@jit
def _general_pseudo_inverse_into(matrix: np.ndarray, null_direction: np.ndarray, out: np.ndarray) -> None:
    """`_general_pseudo_inverse` (scipy's null_space and numpy's pinv, in object mode) written into out (3, 3)."""
    with objmode(result="float64[:, ::1]"):
        result = _general_pseudo_inverse(matrix, null_direction)
    out[:, :] = result


@jit
def _joseph_update(prior: np.ndarray, gain: np.ndarray, projection: np.ndarray, measurement_covariance: np.ndarray,
                   lead: float = 0.0) -> np.ndarray:
    """Joseph form of the covariance update, P = (I - K H) P^- (I - K H)^T + K R K^T, H = [P_lambda, 0]
    (H = P_lambda [I, tau I] for a bearing `lead` = tau s away from the filter's time, UPLKF.correct).

    The short form (I - K H) P^- of section IV-C is the same matrix in exact arithmetic and is
    what the filter uses; with a prior of condition number beyond ~1e12 (only a filter fed
    bearings far noisier than its Sigma gets there) its rounding can leave negative
    eigenvalues, which later steps amplify. The Joseph form is a sum of two congruences of
    PSD matrices, so it stays PSD to rounding. prior: P^-, (6, 6). gain: K, (6, 3).
    projection: P_lambda of H, (3, 3). measurement_covariance: R_k, (3, 3). Returns (6, 6).
    """
    h = np.hstack((projection, np.zeros((3, 3)))) if lead == 0.0 else np.hstack((projection, lead * projection))
    i_kh = np.eye(6) - gain @ h
    covariance = i_kh @ prior @ i_kh.T + gain @ measurement_covariance @ gain.T
    return 0.5 * (covariance + covariance.T)


@jit
def _behind_sensor(cos_angle: float, predicted_range: float) -> bool:
    """Remark 3's guard: a prediction behind the sensor (cosine to the bearing <= 0) or on it (range < 1 um) is
    not corrected but restarted on the bearing."""
    return cos_angle <= 0.0 or predicted_range < 1e-6


@jit
def _clipped_cosine(dot: float, length: float) -> float:
    """min(max(dot / max(length, 1e-12), -1.0), 1.0) with Python's min and max (a NaN stays NaN): the cosine
    between the bearing and the predicted line of sight as UPLKF.correct clips it (`_prior_line_of_sight`; the
    IMM's models and combined prior take the same)."""
    length = 1e-12 if 1e-12 > length else length  # max(length, 1e-12): the first argument unless the second is larger
    cosine = dot / length
    if -1.0 > cosine:
        cosine = -1.0
    if 1.0 < cosine:
        cosine = 1.0
    return cosine


@jit
def _prior_line_of_sight(state: np.ndarray, lead: float, pursuer_position: np.ndarray, direction: np.ndarray,
                         relative: np.ndarray) -> tuple[float, float, bool]:
    """UPLKF.correct's look at the prior from the bearing: writes relative = p^-_T + tau v^-_T - p (3,), m, the prior
    mean carried to the bearing's time (tau = `lead`, s) seen from the bearing's position p (pursuer_position
    (3,)), into `relative` (3,) (an argument rather than a result: numba boxes every array it returns); returns
    its length (np.linalg.norm's formula, without its wrapper), the cosine between the unit bearing `direction`
    (3,) and it, clipped to [-1, 1] as np.clip would (Python's min and max on floats: a NaN stays NaN), and
    remark 3's guard on them (`_behind_sensor`). state: x^- = [p^-_T, v^-_T] (6,)."""
    relative[:] = state[:3] + lead * state[3:] - pursuer_position  # p^-_T - p
    predicted_range = math.sqrt(float(np.dot(relative, relative)))
    cosine = _clipped_cosine(float(direction @ relative), predicted_range)
    return predicted_range, cosine, _behind_sensor(cosine, predicted_range)


@jit
def _normalized_innovation_squared(innovation: np.ndarray, innovation_inverse: np.ndarray) -> float:
    """eps = y^T S^+ y, the NIS of a correction (AdaptiveProcessNoise)."""
    return float(innovation @ innovation_inverse @ innovation)


@jit
def _predict_kernel(transition: np.ndarray, discrete_process_noise: np.ndarray, scale: float, boost: float,
                    state: np.ndarray, covariance: np.ndarray) -> None:
    """Time update over one period, section IV-C: x^- = A x, P^- = A P A^T + B Q B^T, in place.

    transition: A (6, 6). discrete_process_noise: B Q B^T (6, 6), scaled by the adaptive factor
    s_k (`scale`) and then by the health monitor's `boost` (each skipped at 1: 1 Q is Q exactly).
    state: x (6,) and covariance: P (6, 6), overwritten with x^- and P^-."""
    _predict_with(transition, discrete_process_noise, scale, boost, state, covariance, np.empty(6), np.empty((3, 6, 6)))


@jit_inline
def _predict_with(transition: np.ndarray, discrete_process_noise: np.ndarray, scale: float, boost: float,
                  state: np.ndarray, covariance: np.ndarray, moved: np.ndarray, work: np.ndarray) -> None:
    """`_predict_kernel` with its intermediate arrays in the caller's scratch, moved (6,) and work (3, 6, 6): the
    same products (BLAS, the same operands in the same order) and the same elementwise sums, without an array per
    step."""
    half = work[0]
    full = work[1]
    noise = discrete_process_noise
    if scale != 1.0 or boost != 1.0:
        scaled = work[2]
        if scale != 1.0:
            np.multiply(scale, noise, scaled)
            noise = scaled
        if boost != 1.0:
            np.multiply(boost, noise, scaled)
            noise = scaled
    np.dot(transition, state, moved)  # A x
    state[:] = moved
    np.dot(transition, covariance, half)  # (A P) A^T + noise
    np.dot(half, transition.T, full)
    np.add(full, noise, covariance)


@jit_inline
def _measured_projection_into(direction: np.ndarray, out: np.ndarray, unit: np.ndarray) -> None:
    """P_lambda~ = I - u u^T, u = direction / |direction| (`_projector(direction / |direction|)`'s arithmetic: the
    same BLAS dot, division and products), written into out (3, 3); unit (3,): u."""
    np.divide(direction, math.sqrt(float(np.dot(direction, direction))), unit)
    _projector_into(unit, out)


# `_correct_with`'s scratch (`_correction_work`): the index of each intermediate in its stack of that shape
_GAIN_RELATIVE, _GAIN_DIRECTION, _LIMIT, _UNIT = 0, 1, 2, 3  # (3,)
_CORRECTION, _UPDATED = 0, 1  # (6,)
_MEASURED_PROJECTION, _GAIN_PROJECTION, _NOISE_TRANSITION, _PRODUCT, _MEASUREMENT_COVARIANCE, _TERM = 0, 1, 2, 3, 4, 5
_PRIOR_ROWS, _INVERSE, _OUTER, _SHIFTED = 6, 7, 8, 9  # (3, 3)
_POSITION_ROWS, _CROSS_COVARIANCE, _GAIN = 0, 1, 2  # (6, 3)
_PROJECTED_ROWS, _MEASURED_ROWS = 0, 1  # (3, 6)
_REDUCTION, _POSTERIOR = 0, 1  # (6, 6)


@jit
def _correction_work() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_correct_with`'s scratch: stacks of (3,), (6,), (3, 3), (6, 3), (3, 6) and (6, 6) float64 arrays (indexed by
    the constants above; a stack's element is a C-ordered array without a reshape)."""
    return (np.empty((4, 3)), np.empty((2, 6)), np.empty((10, 3, 3)), np.empty((3, 6, 3)), np.empty((2, 3, 6)),
            np.empty((2, 6, 6)))


@jit_inline
def _correct_with(state: np.ndarray, covariance: np.ndarray, bearing: tuple, measured_projection: np.ndarray,
                  noises: tuple, scalars: tuple, switches: tuple, outputs: tuple, work: tuple) -> np.ndarray:
    """Measurement update with one bearing, eq. (6) and section IV-C (`UPLKF.correct`'s arithmetic), in place.

        K_k = P^-_k H^T (H P^-_k H^T + V_k Sigma V_k^T)^+,   V_k = r^- P_lambda,
        x_k = x^-_k - K_k H_k x^-_k,   P_k = (I - K_k H) P^-_k   (Joseph form if that is not PSD)

    with H_k x^-_k = P_lambda~ (p^-_T - p) and H = [P_lambda, 0] from the gain's line of sight (H = P_lambda [I, tau I]
    for a bearing tau = `lead` s off the filter's time, when `late`).

    state: x^- (6,), covariance: P^- (6, 6), overwritten with x_k and P_k. bearing = (relative: p^-_T - p (3,), m,
    at the bearing's time; direction: the unit bearing of the residual (3,); reference: the own position the gain's
    line of sight starts from (3,), m (OwnPositionTracker), when use_reference, else p; pursuer_position: p (3,),
    m, the bearing's position). measured_projection: P_lambda~ (3, 3) (the same for every model of an IMM:
    `_measured_projection_into`). noises = (measurement_noise: Sigma (3, 3); lead_noise: the late bearing's
    target-motion covariance (3, 3), m^2). scalars = (predicted_range: |relative|, m; lead: tau, s;
    position_variance: sigma_p^2, m^2, added as sigma_p^2 P when add_position_noise). switches = (use_reference;
    use_predicted: the PREDICTED gain, from the gain's line of sight (False takes `direction`); late;
    add_position_noise). outputs = (innovation, innovation_covariance): the pseudo-measurement innovation
    y = P_lambda~ (p^-_T - p) (3,) and its covariance S (3, 3) are written there; every intermediate lives in
    `work` (`_correction_work`). Returns S^+ (3, 3), a view into `work` (valid until its next use)."""
    relative, direction, reference, pursuer_position = bearing
    measurement_noise, lead_noise = noises
    predicted_range, lead, position_variance = scalars
    use_reference, use_predicted, late, add_position_noise = switches
    innovation, innovation_covariance = outputs
    vectors, rows, small, tall, wide, square = work
    gain_relative, gain_range = relative, predicted_range
    if use_reference:
        # Errors in variables: the gain's line of sight from an own position that does not
        # carry this sample's error (OwnPositionTracker), the residual from the sample itself.
        from_reference = vectors[_GAIN_RELATIVE]
        np.subtract(pursuer_position, reference, from_reference)
        np.add(relative, from_reference, from_reference)
        reference_range = math.sqrt(float(np.dot(from_reference, from_reference)))
        if not reference_range < 1e-6:
            gain_relative, gain_range = from_reference, reference_range
    gain_direction = direction
    if use_predicted:
        gain_direction = vectors[_GAIN_DIRECTION]
        np.divide(gain_relative, gain_range, gain_direction)
    gain_projection = small[_GAIN_PROJECTION]
    _projector_into(gain_direction, gain_projection)
    # H = [P, 0], so H P^- H^T = P P^-_pp P and P^- H^T = P^-[:, :3] P.
    # A bearing taken tau = lead s away from the filter's time (a late fix, a neighbour's shared
    # bearing) measures p_T(t + tau) = p_T + tau v_T + w_tau: H = P [I, tau I], and w_tau, the
    # target's own acceleration over |tau|, adds its position variance to the measurement noise.
    # P^- M^T, M = [I, tau I] (a contiguous copy of the columns: the same BLAS product, with no strided operand)
    position_rows = tall[_POSITION_ROWS]
    if late:
        np.multiply(lead, covariance[:, 3:], position_rows)
        np.add(covariance[:, :3], position_rows, position_rows)
    else:
        position_rows[:, :] = covariance[:, :3]
    cross_covariance = tall[_CROSS_COVARIANCE]
    np.dot(position_rows, gain_projection, cross_covariance)
    noise_transition = small[_NOISE_TRANSITION]
    np.multiply(gain_range, gain_projection, noise_transition)  # V_k = r^- P_lambda
    product = small[_PRODUCT]
    measurement_covariance = small[_MEASUREMENT_COVARIANCE]
    np.dot(noise_transition, measurement_noise, product)  # (V Sigma) V^T
    np.dot(product, noise_transition.T, measurement_covariance)
    term = small[_TERM]
    if add_position_noise:
        np.multiply(position_variance, gain_projection, term)
        np.add(measurement_covariance, term, measurement_covariance)
    if late:
        np.dot(gain_projection, lead_noise, product)
        np.dot(product, gain_projection, term)
        np.add(measurement_covariance, term, measurement_covariance)
    prior_rows = cross_covariance[:3]  # M P^- M^T P
    if late:
        prior_rows = small[_PRIOR_ROWS]
        np.multiply(lead, cross_covariance[3:], prior_rows)
        np.add(cross_covariance[:3], prior_rows, prior_rows)
    np.dot(gain_projection, prior_rows, innovation_covariance)
    np.add(innovation_covariance, measurement_covariance, innovation_covariance)
    innovation_inverse = small[_INVERSE]
    _projector_pseudo_inverse_into(innovation_covariance, gain_direction, innovation_inverse, small[_OUTER],
                                   small[_SHIFTED])
    gain = tall[_GAIN]
    np.dot(cross_covariance, innovation_inverse, gain)
    # x_k = x^-_k - K_k H_k x^-_k, with H_k x^-_k = P_lambda~ (p^-_T - p)
    np.dot(measured_projection, relative, innovation)  # H_k x^-_k, also the report's innovation
    correction = rows[_CORRECTION]
    updated = rows[_UPDATED]
    np.dot(gain, innovation, correction)
    np.subtract(state, correction, updated)
    _limit_range_in_place(updated[:3], pursuer_position, vectors[_LIMIT])
    measured_rows = covariance[:3]  # M P^-
    if late:
        measured_rows = wide[_MEASURED_ROWS]
        np.multiply(lead, covariance[3:], measured_rows)
        np.add(covariance[:3], measured_rows, measured_rows)
    projected_rows = wide[_PROJECTED_ROWS]
    reduction = square[_REDUCTION]
    posterior = square[_POSTERIOR]
    np.dot(gain_projection, measured_rows, projected_rows)
    np.dot(gain, projected_rows, reduction)
    np.subtract(covariance, reduction, posterior)  # (I - K H) P^-
    np.add(posterior, posterior.T, reduction)  # 0.5 (P + P^T)
    np.multiply(0.5, reduction, reduction)
    if _is_positive_semidefinite(reduction):
        covariance[:, :] = reduction
    else:
        covariance[:, :] = _joseph_update(covariance, gain, gain_projection, measurement_covariance,
                                          lead if late else 0.0)
    state[:] = updated
    return innovation_inverse


@jit_inline
def _limit_range_in_place(target_position: np.ndarray, pursuer_position: np.ndarray, relative: np.ndarray) -> None:
    """`limit_range` in place on target_position (3,) (the same dot, division, product and sum), relative (3,) its
    scratch."""
    np.subtract(target_position, pursuer_position, relative)
    distance = math.sqrt(float(np.dot(relative, relative)))  # np.linalg.norm's own formula, without its wrapper
    if distance <= MAX_RANGE:
        return
    np.multiply(MAX_RANGE / distance, relative, relative)
    np.add(pursuer_position, relative, target_position)


@jit
def _correct_into(state: np.ndarray, covariance: np.ndarray, bearing: tuple, noises: tuple, scalars: tuple,
                  switches: tuple, with_nis: bool, outputs: tuple) -> float:
    """UPLKF.correct's one kernel call: `_correct_with` on its own scratch, P_lambda~ formed from the bearing's
    direction, the innovation y (3,) and its covariance S (3, 3) written into outputs = (innovation,
    innovation_covariance) (arguments rather than results: numba boxes every array it returns), and the NIS
    y^T S^+ y (`_normalized_innovation_squared`) returned when with_nis (NaN otherwise). bearing, noises, scalars,
    switches: as `_correct_with` takes them."""
    work = _correction_work()
    measured_projection = work[2][_MEASURED_PROJECTION]
    _measured_projection_into(bearing[1], measured_projection, work[0][_UNIT])
    innovation_inverse = _correct_with(state, covariance, bearing, measured_projection, noises, scalars, switches,
                                       outputs, work)
    if with_nis:
        return _normalized_innovation_squared(outputs[0], innovation_inverse)
    return math.nan


def explicit_start(initial_guess: InitialGuess) -> tuple[np.ndarray, np.ndarray] | None:
    """(position, covariance of [p_T, v_T]) when the guess fixes the start position, else None.

    Isotropic: range_std on every position axis, velocity_std on every velocity axis.
    """
    if initial_guess.position is None:
        return None
    covariance = np.diag([initial_guess.range_std**2] * 3 + [initial_guess.velocity_std**2] * 3)
    return np.asarray(initial_guess.position, dtype=float).reshape(3).copy(), covariance


def on_bearing_covariance(direction: np.ndarray, along_std: float, cross_std: float, velocity_std: float) -> np.ndarray:
    """Remark 3 start covariance of [p_T, v_T], shape (6, 6): long along the unit bearing
    `direction` (along_std, m), thin across it (cross_std, m), isotropic velocity (velocity_std, m/s)."""
    along = np.outer(direction, direction)
    covariance = np.zeros((6, 6))
    covariance[:3, :3] = along_std**2 * along + cross_std**2 * (np.eye(3) - along)
    covariance[3:, 3:] = velocity_std**2 * np.eye(3)
    return covariance


def restart_guess(previous: InitialGuess | None, predicted_range: float, velocity: np.ndarray) -> InitialGuess:
    """The guess a filter restarts on when its prediction lies behind the sensor (remark 3):
    the predicted range (at least 1 m), an along-bearing std of at least that range, the
    current velocity estimate. Always on the bearing, never at an explicit position."""
    predicted_range = min(predicted_range, MAX_RANGE)
    guess = previous or InitialGuess(predicted_range, predicted_range, velocity, 5.0)
    return InitialGuess(max(predicted_range, 1.0), max(guess.range_std, predicted_range), velocity, guess.velocity_std)


def pseudo_linear_measurement_matrix(bearing: np.ndarray) -> np.ndarray:
    """H = [P_lambda, 0_3x3] of the pseudo-linear measurement, eq. (6); shape (3, 6)."""
    return np.hstack([orthogonal_projection(bearing), np.zeros((3, 3))])


@dataclass(frozen=True)
class AdaptiveNoiseSettings:
    """Parameters of `AdaptiveProcessNoise` (the opt-in `[estimator] adaptive_process_noise`).

    max_scale: upper bound of the Q scale, dimensionless (>= 1; 1 is the constant-Q filter).
    nis_time_constant: tau_m, s, of the running mean of the NIS per degree of freedom.
    rise_time_constant: tau_s, s, of the scale's growth while the innovations are too large.
    relax_time_constant: tau_r, s, of its return to 1 once they are not.
    nis_threshold: m_hi (> 1), the mean NIS per degree of freedom above which the scale rises.
    """

    max_scale: float = 25.0
    nis_time_constant: float = 2.0
    rise_time_constant: float = 2.0
    relax_time_constant: float = 10.0
    nis_threshold: float = 3.0

    def __post_init__(self) -> None:
        if self.max_scale < 1.0 or self.nis_threshold <= 1.0 or min(
                self.nis_time_constant, self.rise_time_constant, self.relax_time_constant) <= 0.0:
            raise ValueError("need max_scale >= 1, nis_threshold > 1 and positive time constants")


class NoiseChanges:
    """A count of the sets of some u-PLKFs' process-noise factors, owned by whoever reads them.

    Each UPLKF reports to one record (its own, or the one an interacting-multiple-model estimator hands to all its
    model filters: `UPLKF._report_noise_changes_to`): every set of its process_noise_boost or adaptive_noise, and
    of its AdaptiveProcessNoise's scale, adds one to `count` after the new value is in place. The IMM collects its
    model filters' scales and boosts for its prediction kernel again only when the count has moved since it last
    did (IMMEstimator.predict): one comparison of integers per tick instead of reading every factor, and no change
    of a factor, whoever makes it, goes unseen. A count may also move without a change (an adaptive noise keeps
    reporting to a filter's earlier records): that costs a collection, never a missed change."""

    __slots__ = ("count",)

    def __init__(self) -> None:
        self.count = 0


class AdaptiveProcessNoise:
    """Process-noise scale s_k >= 1 driven by the innovation statistics (Q_k = s_k Q).

    A constant-velocity model with a small Q cannot follow a target that keeps turning: the
    prediction lags the target and the bearings' innovations grow beyond what the covariance
    predicts. Their normalised squares say so without truth: for a consistent filter the NIS
    eps_k = y_k^T S_k^+ y_k is chi^2 with d_k = rank S_k degrees of freedom (Bar-Shalom, Li &
    Kirubarajan 2001, section 5.4), so eps_k / d_k has mean 1. Covariance matching (Mehra 1972)
    turns a sustained excess into more process noise. With dt_k the time since the previous
    correction:

        running mean  m_k = m_{k-1} + (1 - exp(-dt_k / tau_m)) (eps_k / d_k - m_{k-1}),   m_0 = 1
        scale         ln s_k = ln s_{k-1} + (dt_k / tau_s) ln(m_k / m_hi)   if m_k > m_hi   (rise)
                      ln s_k = ln s_{k-1} exp(-dt_k / tau_r)                if m_k < 1      (relax)
                      ln s_k = ln s_{k-1}                                   otherwise      (hold)
        then clipped to 0 <= ln s_k <= ln max_scale.

    Why a dead band. A pure integrator of ln(m_k) (rise and relax on the same law) is a random
    walk reflected at s = 1 for a consistent filter: the running mean of a few tens of chi^2
    samples fluctuates by +-20 %, and the floor turns those fluctuations into an upward drift
    (measured: a median scale near 2 on a correctly tuned linear filter). Rising only above
    m_hi keeps a consistent filter at s = 1 (the running mean's standard deviation is about
    0.2 at 10 Hz and less at 50 Hz), while a manoeuvre, whose NIS is many times its
    expectation, raises s geometrically until the innovations fall back under m_hi. The
    default m_hi = 3 was chosen on tuning seeds (101-103): the u-PLKF's pseudo-linear
    innovations run above their chi^2 expectation on good flights too (range-scaled noise,
    own-position noise; the health monitor likewise tolerates a factor 2), and with m_hi = 1.5
    the s-manoeuvre at 50 Hz lost accuracy (RMS 0.24 -> 1.1 m) and circles at 50 Hz came
    within 3 m of the target; with 3 both stayed close to the constant-Q filter's figures.
    The relaxation is exponential in ln s (s -> 1 with time constant tau_r) whenever the
    innovations are below their expectation, so a burst of Q does not outlive the manoeuvre.
    The clip keeps the filter never less cautious than the configured Q nor beyond max_scale.
    Everything is a function of the corrections' times and NIS only: deterministic.

    Caveat (measured, docs/reproduction/manoeuvring-experiments.md, 5.3): a larger Q makes the innovations consistent
    with S again, so the same statistic can no longer reveal a wrong range; the NIS test of the
    health monitor then stays quiet on flights whose estimate is still wrong.
    """

    def __init__(self, settings: AdaptiveNoiseSettings) -> None:
        self.settings = settings
        self._scale = 1.0
        self.mean_nis = 1.0
        self._last_time: float | None = None
        self._records: tuple[NoiseChanges, ...] = ()  # of the filters it serves (UPLKF.adaptive_noise)

    @property
    def scale(self) -> float:
        """s_k, the current factor on Q (>= 1)."""
        return self._scale

    @scale.setter
    def scale(self, value: float) -> None:
        self._scale = value
        for record in self._records:  # (after the change: an IMM that sees the new count reads the new value)
            record.count += 1

    def _report_to(self, record: NoiseChanges) -> None:
        """Count every later set of the scale in `record` too (the record of a filter this noise serves)."""
        if not any(known is record for known in self._records):
            self._records += (record,)

    def update(self, time: float, nis: float, dof: int) -> float:
        """Fold in one correction's NIS eps_k (dimensionless) with dof = d_k degrees of freedom,
        taken at time, s; returns the new scale s_k."""
        if dof <= 0 or not math.isfinite(nis):
            return self._scale
        dt = 0.0 if self._last_time is None else max(float(time) - self._last_time, 0.0)
        self._last_time = float(time)
        settings = self.settings
        self.mean_nis += (1.0 - math.exp(-dt / settings.nis_time_constant)) * (nis / dof - self.mean_nis)
        log_scale = math.log(self._scale)
        if self.mean_nis > settings.nis_threshold:
            log_scale += dt / settings.rise_time_constant * math.log(self.mean_nis / settings.nis_threshold)
        elif self.mean_nis < 1.0:
            log_scale *= math.exp(-dt / settings.relax_time_constant)
        self.scale = math.exp(min(max(log_scale, 0.0), math.log(settings.max_scale)))
        return self._scale


OWN_ACCELERATION_PSD = 1.0
"""(m/s^2)^2 s: white-acceleration spectral density of `OwnPositionTracker`'s constant-velocity
model of the pursuer. Chosen on a recorded constant_velocity flight (HNG weave, pursuer
acceleration about 1.4 m/s^2 RMS per axis, 6 m/s^2 peak) as the value with the smallest
one-sample-ahead position error at 5, 50 and 100 Hz samples (0.18, 0.05, 0.04 m against
sigma_p = 0.1 m); 0.3 to 3 do nearly as well. Only the gain's direction depends on it."""

OWN_TRACK_MAX_GAP = 1.0
"""s: a gap between own-position samples beyond which `OwnPositionTracker` restarts on the
new sample (its prediction across a long gap is worse than the sample it replaces)."""


class OwnPositionTracker:
    """Constant-velocity Kalman filter of the reported pursuer position, one sample ahead.

    Why. The PREDICTED u-PLKF builds its gain from the predicted line of sight p^-_T - p. If p
    is the very own-position sample p = p_true + e whose error e also sits in the residual
    -P_lambda~ e, the gain is correlated with the noise it corrects. To second order in e,
    with the prior mean on the target, a position covariance a lambda lambda^T + b P_lambda
    (m^2, along and across the line of sight), g = (r lambda - e)/|r lambda - e| ~ lambda -
    P_lambda e / r gives lambda^T K ~ (a / (b + R)) (P_lambda e)^T / r, R = r^2 sigma_nu^2 +
    sigma_p^2 (Sigma = sigma_nu^2 I), and the residual -P_lambda e moves the estimate along
    the line of sight by

        E[dr] = a E|P_lambda e|^2 / (r (b + R)) = 2 sigma_p^2 a / (r (b + R))   (m, outwards)

    at every update, so with white own-position noise the range bias grows with the bearing
    rate (measured on a static geometry: tests/test_eiv.py).
    The tracker's prediction of the position at a sample's time uses only earlier samples,
    so with white noise it is independent of that sample's e: an instrumental variable for
    the own position, as the predicted target position is one for the bearing.

    Model (per axis, the three axes share one 2x2 covariance because the noise is
    isotropic): x = [p, v], x_k = F x_{k-1} + w, F = [[1, dt], [0, 1]], Q = q [[dt^3/3,
    dt^2/2], [dt^2/2, dt]] (q = `acceleration_psd`, (m/s^2)^2 s), measurement p + e with
    e ~ N(0, sigma_p^2) (`position_std`, m). A second sample at the last stamp gets the
    prediction made before the first; a late one (older than the last) the state carried back
    to its time, and it is not folded in; the first sample and one more than `max_gap` (s)
    away from the last are their own reference (and the tracker restarts on a later one).
    Scalar arithmetic only, one kernel call per sample (`_own_position_step`).
    """

    def __init__(self, position_std: float, acceleration_psd: float = OWN_ACCELERATION_PSD,
                 max_gap: float = OWN_TRACK_MAX_GAP) -> None:
        if not position_std > 0.0:
            raise ValueError("the own-position tracker needs a positive position_std")
        self.position_std = float(position_std)
        self.acceleration_psd = float(acceleration_psd)
        self.max_gap = float(max_gap)
        self._time: float | None = None
        # [x (3), v (3), p00, p01, p11]: the state and the shared covariance, stepped by one kernel call per
        # sample (_own_position_step: scalar arithmetic, no numpy operation on three elements).
        self._filter = np.zeros(9)
        self._last_prediction = np.zeros(3)

    def reference(self, time: float, position: np.ndarray) -> np.ndarray:
        """The own position (m, shape (3,)) at `time` (s) predicted from the samples before
        this one; then folds this sample (the reported position, m, shape (3,)) in.
        Special cases (first, repeated, late, after a gap): see the class docstring."""
        dt = None if self._time is None else time - self._time
        if dt is None or abs(dt) > self.max_gap:
            position = np.array(position, dtype=float)
            if dt is None or dt > 0.0:
                self._restart(float(time), position)
            return position
        if dt == 0.0:
            # A second bearing at the same stamp: the state already holds that sample's error,
            # the prediction made before it does not.
            return self._last_prediction
        if dt < 0.0:
            # A late sample: carried back from later ones, it is not folded in (the tracker
            # runs forward in time only).
            return _carried_position(self._filter, dt)
        prediction = np.empty(3)
        _own_position_step(self._filter, dt, self.acceleration_psd, self.position_std, np.asarray(position, dtype=float),
                           prediction)
        self._last_prediction = prediction
        self._time = time
        return self._last_prediction

    def _plan(self, time: float) -> tuple[float | None, np.ndarray | None]:
        """How `reference` takes a sample at `time`, without taking it: (dt, None) for its usual step over dt s from
        the last sample (0 < dt <= max_gap: `_own_position_step`, its prediction the reference); (None, the
        reference) for a repeated or a late sample (which `reference` does not fold in); (None, None) for a first
        sample or one after a gap (`reference` restarts on it)."""
        if self._time is None:
            return None, None
        dt = time - self._time
        if abs(dt) > self.max_gap:
            return None, None
        if dt == 0.0:
            return None, self._last_prediction
        if dt < 0.0:
            return None, _carried_position(self._filter, dt)
        return dt, None

    def _restart(self, time: float, position: np.ndarray) -> None:
        self._time = time
        # [x (3), v (3), p00, p01, p11]; unknown velocity: a prior std of 10 m/s, far beyond a following drone's
        # speed changes.
        self._filter = np.array((*position.tolist(), 0.0, 0.0, 0.0, self.position_std**2, 0.0, 100.0))
        self._last_prediction = position


@jit
def _carried_position(track: np.ndarray, dt: float) -> np.ndarray:
    """OwnPositionTracker's state [x, v, ...] (`track`) carried dt s (a late sample: dt < 0): x + dt v, (3,)."""
    return np.array((track[0] + dt * track[3], track[1] + dt * track[4], track[2] + dt * track[5]))


@jit
def _own_position_step(track: np.ndarray, dt: float, acceleration_psd: float, position_std: float,
                       position: np.ndarray, prediction: np.ndarray) -> None:
    """One step of OwnPositionTracker's constant-velocity Kalman filter, in place on `track` = [x (3), v (3), p00,
    p01, p11] (m, m/s and the shared 2x2 covariance [[p00, p01], [p01, p11]]): the time update over dt > 0 s with
    white acceleration of density q = acceleration_psd, (m/s^2)^2 s, then the measurement update with the sample
    `position` (3,), m, of noise std position_std, m. Writes the prediction x + dt v into `prediction` (3,), m (an
    argument rather than a result: numba boxes every array it returns)."""
    x0, x1, x2 = float(track[0]), float(track[1]), float(track[2])
    v0, v1, v2 = float(track[3]), float(track[4]), float(track[5])
    old_p00, old_p01, old_p11 = float(track[6]), float(track[7]), float(track[8])
    q = acceleration_psd
    # Time update of the shared 2x2 covariance [[p00, p01], [p01, p11]] and of the state.
    p00 = old_p00 + dt * (2.0 * old_p01 + dt * old_p11) + q * dt ** 3 / 3.0
    p01 = old_p01 + dt * old_p11 + q * dt ** 2 / 2.0
    p11 = old_p11 + q * dt
    a0, a1, a2 = x0 + dt * v0, x1 + dt * v1, x2 + dt * v2
    # Measurement update with the sample: gains k0 (position), k1 (velocity).
    innovation_variance = p00 + position_std ** 2
    k0, k1 = p00 / innovation_variance, p01 / innovation_variance
    z0, z1, z2 = float(position[0]), float(position[1]), float(position[2])
    e0, e1, e2 = z0 - a0, z1 - a1, z2 - a2
    track[0], track[1], track[2] = a0 + k0 * e0, a1 + k0 * e1, a2 + k0 * e2
    track[3], track[4], track[5] = v0 + k1 * e0, v1 + k1 * e1, v2 + k1 * e2
    track[6], track[7], track[8] = (1.0 - k0) * p00, (1.0 - k0) * p01, p11 - k1 * p01
    prediction[0], prediction[1], prediction[2] = a0, a1, a2


class UPLKF:
    """3-D bearing-only pseudo-linear Kalman filter, u-PLKF (section IV-C).

    Prediction at a fixed period (the estimator rate), correction whenever a bearing
    arrives. With gain_projection=MEASURED this is exactly the paper's filter:

        K_k = P^-_k H_k^T (H_k P^-_k H_k^T + V_k Sigma V_k^T)^+,   H_k = [P_lambda~_k, 0]
        x_k = x^-_k - K_k H_k x^-_k,   P_k = (I - K_k H_k) P^-_k,   V_k = r^-_k P_lambda~_k

    The paper's form puts the noisy bearing inside H_k, so the gain is correlated
    with the noise it corrects; the bias this leaves accumulates with every update
    and in closed loop at 20-50 Hz bearing rates the range estimate runs away (see
    docs/explanation/estimation.md for the measurements). PREDICTED (the default of
    the scenarios) builds the projection of the gain and covariance from the
    predicted line of sight lambda^- = (p^-_T - p)/|p^-_T - p|, an instrumental
    variable that does not depend on the current noise, while the innovation stays
    the paper's pseudo-linear residual -P_lambda~ (p^-_T - p).

    Bearings far noisier than Sigma (a sensor noise_std of 1 against Sigma = 1e-4 I). Each
    correction then trusts a bearing tens of degrees off; the PREDICTED form's step lies
    across the predicted line of sight and lengthens the range, so the range estimate grows
    geometrically (1e29 m within a minute of 50 Hz bearings) and the innovation covariance
    with it. Three guards keep such a filter finite without touching normal flight: the
    estimated range is capped at MAX_RANGE, the pseudo-inverse is scale-safe
    (`_projector_pseudo_inverse`), and the covariance update turns to the Joseph form when
    rounding has made the short form indefinite. In normal flight none of them acts, so the
    filter is the same bit for bit; for any bearing, state and covariance stay finite and
    the covariance symmetric PSD.

    Both forms share one guard: eq. (6) only says the target lies on the *line*
    through p along lambda~, so a prediction that has drifted behind the sensor
    (lambda~^T (p^-_T - p) <= 0) would be pulled onto the mirrored half-line, and the
    range controller would then chase a phantom. Such a prediction is not credible:
    the filter restarts on the bearing (remark 3) at the predicted range.

    Own-position noise. Eq. (6) takes the pursuer position p as exact, but p comes
    from the autopilot's estimate (sigma_p = 0.1 m in section VIII). At the 8 m
    following range that is an angular error larger than the bearing noise itself, so
    pursuer_position_std adds its projection to the measurement covariance:
    R_k = V_k Sigma V_k^T + sigma_p^2 P P^T. Zero gives the paper's R_k.
    The same error also sits in the regressor (errors in variables): with PREDICTED, a gain
    built from p^-_T - p with this bearing's own noisy p is correlated with the -P_lambda~ e
    in its residual and pushes the range outwards at every update (+0.2 m at 50 Hz, +0.3 m at
    100 Hz on constant_velocity with white 0.1 m noise). So with pursuer_position_std > 0
    the PREDICTED gain (its projection and V_k's range) uses p^-_T - p_ref, p_ref the own
    position predicted from the earlier bearings' own positions (`OwnPositionTracker`); the
    residual keeps the measured p. MEASURED and NOISE_FREE are untouched.

    period: Delta t, s. process_noise: Q, target acceleration covariance, (m/s^2)^2,
    shape (3, 3). measurement_noise: Sigma, covariance of nu in eq. (4), shape (3, 3).
    pursuer_position_std: sigma_p, m. restart_when_behind: the guard above (False is
    the paper's filter exactly). adaptive_noise: None (default) keeps Q constant; settings
    make Q_k = s_k Q with s_k from `AdaptiveProcessNoise`, fed each correction's NIS.

    Motion model. By default the target is eq. (1)'s double integrator. A model filter of
    an interacting-multiple-model estimator (companion.core.imm) passes its own transition
    (A, shape (6, 6)) and discrete process noise (Q_d, shape (6, 6), m^2 and (m/s)^2) instead,
    e.g. `coordinated_turn_matrices`; the correction is the same for every model.
    process_noise_boost: a factor >= 0 on the discrete process noise of every prediction
    (after the adaptive scale), 1 by default; the filter-health monitor raises it while it
    judges the estimate unreliable.
    """

    def __init__(
        self,
        period: float,
        process_noise: np.ndarray,
        measurement_noise: np.ndarray,
        gain_projection: GainProjection = GainProjection.MEASURED,
        *,
        pursuer_position_std: float = 0.0,
        restart_when_behind: bool = True,
        adaptive_noise: AdaptiveNoiseSettings | None = None,
        transition: np.ndarray | None = None,
        discrete_process_noise: np.ndarray | None = None,
    ) -> None:
        if period <= 0.0:
            raise ValueError("estimator period must be positive")
        self.period = float(period)
        self.process_noise = np.asarray(process_noise, dtype=float).reshape(3, 3)
        self.measurement_noise = np.asarray(measurement_noise, dtype=float).reshape(3, 3)
        self.gain_projection = GainProjection(gain_projection)
        self.pursuer_position_std = float(pursuer_position_std)
        self.restart_when_behind = bool(restart_when_behind)
        self._a, self._b = transition_matrices(self.period)
        self._q_discrete = self._b @ self.process_noise @ self._b.T
        if transition is not None:
            self._a = np.array(transition, dtype=float).reshape(6, 6)
        if discrete_process_noise is not None:
            self._q_discrete = np.array(discrete_process_noise, dtype=float).reshape(6, 6)
        self._noise_changes = NoiseChanges()  # where the sets of the factors below are counted (NoiseChanges)
        self.adaptive_noise = None if adaptive_noise is None else AdaptiveProcessNoise(adaptive_noise)
        self._process_noise_boost = 1.0
        # The PREDICTED form's own-position instrumental variable (kept across restarts: it tracks
        # the pursuer, not the target); None where it does not apply.
        self._own_track = (OwnPositionTracker(self.pursuer_position_std)
                           if self.gain_projection is GainProjection.PREDICTED and self.pursuer_position_std > 0.0 else None)
        self._neighbour_tracks: dict[int, OwnPositionTracker] = {}  # the same for each neighbour's bearings
        # x = [p_T, v_T] and P live in these two arrays, updated in place (None before the first start); an IMM
        # hands its model filters rows of its stacked arrays instead (`_use_storage`), so it reads them unstacked.
        self._state_storage = np.zeros(6)
        self._covariance_storage = np.zeros((6, 6))
        self._state: np.ndarray | None = None
        self._covariance: np.ndarray | None = None
        self._start_time = 0.0
        self._ticks = 0
        self._initial_guess: InitialGuess | None = None
        self._snapshot: TargetEstimate | None = None
        self._relative = np.zeros(3)  # correct's p^-_T - p (`_prior_line_of_sight` writes it; read within correct only)

    @property
    def initialized(self) -> bool:
        return self._state is not None

    @property
    def adaptive_noise(self) -> AdaptiveProcessNoise | None:
        """The adaptive process noise (None: Q constant)."""
        return self._adaptive_noise

    @adaptive_noise.setter
    def adaptive_noise(self, value: AdaptiveProcessNoise | None) -> None:
        self._adaptive_noise = value
        if value is not None:
            value._report_to(self._noise_changes)  # its scale is this filter's process_noise_scale
        self._noise_changes.count += 1

    @property
    def process_noise_boost(self) -> float:
        """The factor on the discrete process noise of every prediction (class docstring)."""
        return self._process_noise_boost

    @process_noise_boost.setter
    def process_noise_boost(self, value: float) -> None:
        if value is not self._process_noise_boost:  # (the very same object again changes nothing: the health
            self._process_noise_boost = value       # actions set the boost at every bearing, mostly to 1.0)
            self._noise_changes.count += 1

    def _report_noise_changes_to(self, record: NoiseChanges) -> None:
        """Count the sets of this filter's process-noise factors in `record` from now on (an interacting-multiple-model
        estimator hands one record to all its model filters); counts one for the switch itself."""
        self._noise_changes = record
        if self._adaptive_noise is not None:
            self._adaptive_noise._report_to(record)
        record.count += 1

    @property
    def time(self) -> float:
        """Time of the current estimate, s (start + ticks * period, so it never drifts)."""
        return self._start_time + self._ticks * self.period

    @property
    def estimate(self) -> TargetEstimate:
        """The current estimate (a snapshot: later updates do not change it)."""
        if self._snapshot is None:
            state, covariance = self._require_state()
            self._snapshot = TargetEstimate(self.time, state[:3].copy(), state[3:].copy(), covariance.copy())
        return self._snapshot

    def initialize(self, time: float, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray) -> None:
        """Start from an explicit target estimate; covariance of [p_T, v_T], shape (6, 6)."""
        self._start_time = float(time)
        self._ticks = 0
        self._snapshot = None
        self._state_storage[:3] = np.asarray(position, float).reshape(3)
        self._state_storage[3:] = np.asarray(velocity, float).reshape(3)
        self._covariance_storage[:] = np.asarray(covariance, dtype=float).reshape(6, 6)
        self._state, self._covariance = self._state_storage, self._covariance_storage

    def _use_storage(self, state: np.ndarray, covariance: np.ndarray) -> None:
        """Keep x and P in the given arrays from now on (float64, C-contiguous, (6,) and (6, 6); before the first start):
        an interacting-multiple-model estimator passes rows of its stacked model states, which the filter then
        updates in place."""
        if self._state is not None:
            raise RuntimeError("the storage of an estimator is fixed before its first start")
        self._state_storage, self._covariance_storage = state, covariance

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        """p_T(0) = p(0) + r_hat(0) lambda~(0), remark 3 of section VI-B.

        The position covariance is long along the bearing (range_std) and thin across
        it (r_hat(0) times the bearing noise), the velocity covariance isotropic. With
        initial_guess.position set, the filter starts there instead (section VIII-B).
        """
        self._initial_guess = initial_guess
        start = explicit_start(initial_guess)
        if start is not None:
            self.initialize(bearing.time, start[0], initial_guess.velocity, start[1])
            return
        direction = bearing.unit_direction
        bearing_std = float(np.sqrt(np.trace(self.measurement_noise) / 3.0))
        cross_std = max(initial_guess.range * bearing_std, 1e-3)
        covariance = on_bearing_covariance(direction, initial_guess.range_std, cross_std, initial_guess.velocity_std)
        self.initialize(
            bearing.time,
            bearing.pursuer_position + initial_guess.range * direction,
            initial_guess.velocity,
            covariance,
        )

    @property
    def state_and_covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """The current [p_T, v_T] (6,) and its covariance (6, 6) themselves, not copies (read only; the next
        predict, correct or start overwrites them in place): what an interacting-multiple-model estimator
        mixes and combines at every correction."""
        return self._require_state()

    def set_state(self, state: np.ndarray, covariance: np.ndarray) -> None:
        """Replace the state [p_T, v_T] (m, m/s, shape (6,)) and its covariance (6, 6), keeping the
        clock: an interacting-multiple-model estimator hands each model filter its mixed start this way."""
        self._require_state()
        self._snapshot = None
        self._state[:] = np.asarray(state, dtype=float).reshape(6)
        self._covariance[:] = np.asarray(covariance, dtype=float).reshape(6, 6)

    def predict(self) -> None:
        """Time update over one period, section IV-C: x^- = A x, P^- = A P A^T + B Q B^T (`_predict_kernel`)."""
        state, covariance = self._require_state()
        _predict_kernel(self._a, self._q_discrete, self.process_noise_scale, float(self._process_noise_boost),
                        state, covariance)
        self._advance_clock()

    def _advance_clock(self) -> None:
        """One period passed (the state was just predicted over it)."""
        self._snapshot = None
        self._ticks += 1

    @property
    def process_noise_scale(self) -> float:
        """s_k, the current factor on Q (1 with adaptive_noise off)."""
        return 1.0 if self._adaptive_noise is None else self._adaptive_noise._scale

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        """Measurement update with one bearing, eq. (6) and section IV-C (`_correct_with`)."""
        state, covariance = self._require_state()
        # The bearing may fall between estimator ticks (the networked app receives them
        # at arbitrary times): compare it with the prior mean carried to its time stamp.
        lead = bearing.time - self.time
        pursuer_position = np.asarray(bearing.pursuer_position, dtype=float)
        # p^-_T - p, its length and clipped cosine to the bearing, and remark 3's guard, in one kernel call
        relative = self._relative
        predicted_range, cos_angle, behind = _prior_line_of_sight(state, lead, pursuer_position, bearing.unit_direction,
                                                                  relative)
        innovation_angle = float(np.arccos(cos_angle))
        if self.restart_when_behind and behind:
            # The guard: a prediction behind the sensor (or on it) restarts the filter on the bearing.
            self._restart_on(bearing, predicted_range, state[3:].copy())  # a copy: the storage is overwritten
            return CorrectionReport(innovation_angle, False, reinitialized=True)
        reference, direction, late, lead_noise = self._correction_inputs(bearing, lead, bearing.unit_direction)
        use_predicted = self.gain_projection is GainProjection.PREDICTED
        self._snapshot = None
        position_std = self.pursuer_position_std
        innovation, innovation_covariance = np.empty(3), np.empty((3, 3))
        nis = _correct_into(
            state, covariance, (relative, direction, pursuer_position if reference is None else reference,
                                pursuer_position), (self.measurement_noise, lead_noise),
            (predicted_range, lead, position_std**2), (reference is not None, use_predicted, late, position_std > 0.0),
            self._adaptive_noise is not None, (innovation, innovation_covariance))
        self._note_innovation(bearing, nis)
        return _correction_report(innovation_angle, use_predicted, innovation, innovation_covariance, 2)

    def _correction_inputs(self, bearing: BearingMeasurement, lead: float,
                           direction: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, bool, np.ndarray]:
        """What `_correct_with` needs beyond the prior and the bearing: (the own position the gain's line of
        sight starts from (3,) (OwnPositionTracker; None without one), the residual's unit bearing (3,), whether
        the bearing is late, the late bearing's noise (3, 3)). Feeds the own-position tracker with this bearing's
        position (so once per correction that is not a restart)."""
        reference = None
        if self._own_track is not None:
            tracker = self._own_track if bearing.source == 0 else self._source_track(bearing.source)
            reference = tracker.reference(bearing.time, bearing.pursuer_position)
        if self.gain_projection is GainProjection.NOISE_FREE:
            if bearing.true_direction is None:
                raise ValueError("the noise-free (optimal) u-PLKF needs BearingMeasurement.true_direction: simulation only")
            direction = unit(bearing.true_direction)
        late = abs(lead) > _LEAD_EPSILON
        return reference, direction, late, self._lead_noise(lead) if late else _ZERO33

    def _note_innovation(self, bearing: BearingMeasurement, nis: float) -> None:
        """After a correction: the adaptive process noise takes its NIS y^T S^+ y (2 degrees of freedom; `_correct_into`
        computes it when there is adaptive noise)."""
        if self._adaptive_noise is not None:
            self._adaptive_noise.update(bearing.time, nis, 2)

    def _source_track(self, source: int) -> OwnPositionTracker:
        """The position tracker of a neighbour's bearings (source != 0): each pursuer's reported positions are
        their own series (one tracker fed several pursuers would predict none of them)."""
        tracks = self._neighbour_tracks
        if source not in tracks:
            if len(tracks) >= MAX_TRACKED_SOURCES:
                tracks.pop(next(iter(tracks)))
            tracks[source] = OwnPositionTracker(self.pursuer_position_std)
        return tracks[source]

    def _lead_noise(self, lead: float) -> np.ndarray:
        """Covariance of w_tau, the target position's departure from p_T + tau v_T over |tau| = |lead| s, m^2,
        shape (3, 3): q |tau|^3 / 3 of a continuous white-noise acceleration whose density q = Q Delta t is
        the one this filter's discrete model accumulates per second (velocity variance Delta t^2 Q per
        period), with the same adaptive scale and boost as the predictions. The correlation of w_tau with
        the current state (Bar-Shalom's exact out-of-sequence update) is left out."""
        scale = self._process_noise_boost * (1.0 if self._adaptive_noise is None else self._adaptive_noise._scale)
        return (scale * self.period * abs(lead) ** 3 / 3.0) * self.process_noise

    def _restart_on(self, bearing: BearingMeasurement, predicted_range: float, velocity: np.ndarray) -> None:
        self.initialize_on_bearing(bearing, restart_guess(self._initial_guess, predicted_range, velocity))

    def _require_state(self) -> tuple[np.ndarray, np.ndarray]:
        if self._state is None or self._covariance is None:
            raise RuntimeError("estimator not initialised: it needs a first bearing")
        return self._state, self._covariance
