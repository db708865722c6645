"""Cooperative target estimation for several pursuers (seeds 002 and 004).

Three pieces, numpy/scipy only:

* `triangulate`: the target position from two bearings taken by two different pursuers, seed
  002 eqs. (27)-(30) (law of sines, with the sin(theta) erratum fixed) generalised to 3-D as the
  midpoint of closest approach of the two bearing rays, with a first-order covariance.
* `TriangulationKalmanEstimator`: seed 002 eqs. (31)-(33), a constant-acceleration Kalman filter
  fed by the triangulated positions, behind the `TargetEstimator` protocol of
  companion.core.estimators so the pipeline can fly on it in place of the u-PLKF.
* Track fusion of a pursuer's own estimate with its neighbours' shared estimates: seed 004
  eqs. (24)-(25) for two estimates (cross-covariance ignored, as the seed does), and covariance
  intersection (consistent whatever the unknown cross-covariance) for any number.

Frames: local NED, SI units, angles in radians. A bearing is a `BearingMeasurement`; its
`source` tells the own sensor (0) from a neighbour's (its id >= 1), its `pursuer_position` is the
position of whoever took it at `bearing.time`.
"""

from __future__ import annotations

import enum
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from companion.core.estimators import CorrectionReport, InitialGuess, MAX_RANGE, explicit_start
from companion.core.health import chi2_quantile
from companion.core.messages import BearingMeasurement, TargetEstimate

# --------------------------------------------------------------------------------------------
# Triangulation, seed 002 eqs. (27)-(30)
# --------------------------------------------------------------------------------------------

DEFAULT_MIN_ANGLE = math.radians(5.0)
"""rad: smallest accepted angle between the two bearing lines. Below it the rays are taken as
parallel: the range along each ray is ~ baseline / sin(angle), and its first-order error
(range x bearing noise / sin(angle)) grows without bound (seed 002, remark 6: the target and the
two pursuers lined up)."""


class TriangulationRejection(str, enum.Enum):
    """Why two bearings gave no position (the reasons the estimator counts)."""

    INVALID = "invalid"
    """A non-finite or zero direction or position."""
    NEAR_PARALLEL = "near_parallel"
    """The lines' angle is below the minimum (parallel or anti-parallel rays; also one sensor
    position on the other's line)."""
    BEHIND_SENSOR = "behind_sensor"
    """The closest approach lies behind (or at) either sensor: the rays diverge."""
    TOO_FAR = "too_far"
    """The closest approach is beyond MAX_RANGE from a sensor (a numerical guard)."""


@dataclass(frozen=True)
class Triangulation:
    """A triangulated target position.

    time: s, the newer bearing's time stamp (the older bearing is used as it is, see `triangulate`).
    position: m, NED, shape (3,). covariance: m^2, shape (3, 3), first order in the bearing noise.
    ranges: m, distance along bearing a and along bearing b to their points of closest approach.
    angle: rad, in (0, pi/2], angle between the two bearing lines.
    gap: m, distance between the two rays at closest approach (0 for exactly intersecting rays).
    age: s, >= 0, time between the two bearings.
    """

    time: float
    position: np.ndarray
    covariance: np.ndarray
    ranges: tuple[float, float]
    angle: float
    gap: float
    age: float


def law_of_sines_range(own_direction: np.ndarray, neighbour_direction: np.ndarray, baseline: np.ndarray) -> float:
    """D_i, the range from pursuer i to the target by the law of sines, seed 002 eqs. (27)-(28).

    In the triangle pursuer i, neighbour nu, target (seed 002 Fig. 1), (27) reads
    D_i sin(angle at the target) = D_{i,nu} sin(angle at nu), so

        D_i = |baseline x u_nu| / |u_i x u_nu|,

    with u_i = own_direction, u_nu = neighbour_direction (unit bearings to the target, shape
    (2,) or (3,)) and baseline = p_nu - p_i (m, same shape). Erratum fixed (notes, seed 002):
    the paper's identity sin(theta) = ||P_x P_y|| for unit x, y in R^2 gives |cos(theta)| (the
    product of the two projectors is x_perp x_perp^T y_perp y_perp^T, of norm |x . y|); the sine
    is |x1 y2 - x2 y1|, the norm of the cross product, which is what this uses (in 3-D the norm
    of the 3-D cross product, the same sine). D_{i,nu} = |p_nu - p_i| comes from the shared
    positions here, not from eq. (29)'s bearing rate (each shared bearing carries its taker's
    position). Returns m; inf for parallel bearings. Exact only for coplanar rays that meet:
    `triangulate` is the general 3-D form.
    """
    def in_3d(vector: np.ndarray) -> np.ndarray:  # planar vectors get z = 0 (numpy's 2-D cross is deprecated)
        array = np.asarray(vector, dtype=float).reshape(-1)
        return np.append(array, 0.0) if array.size == 2 else array.reshape(3)

    u_i, u_nu, d = in_3d(own_direction), in_3d(neighbour_direction), in_3d(baseline)
    u_i, u_nu = u_i / np.linalg.norm(u_i), u_nu / np.linalg.norm(u_nu)
    sine_target = float(np.linalg.norm(np.cross(u_i, u_nu)))
    if sine_target == 0.0:
        return math.inf
    return float(np.linalg.norm(np.cross(d, u_nu))) / sine_target


_MIN_SINE = 1e-9
"""Lines closer to parallel than this sine are parallel whatever min_angle says (A = P_a + P_b is
then singular to working precision)."""


def _finite_time(value: object) -> bool:
    """Whether a time stamp is a finite real number (a hostile one may be anything)."""
    try:
        return math.isfinite(float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


def _valid_vector(vector: np.ndarray) -> np.ndarray | None:
    try:
        array = np.asarray(vector, dtype=float).reshape(3)
    except (TypeError, ValueError):
        return None
    return array if bool(np.all(np.isfinite(array))) else None


def triangulation_attempt(bearing_a: BearingMeasurement, bearing_b: BearingMeasurement, bearing_noise_std: float = 0.01,
                          min_angle: float = DEFAULT_MIN_ANGLE) -> Triangulation | TriangulationRejection:
    """`triangulate` with the full result or the reason for no result (see there)."""
    u_a, u_b = _valid_vector(bearing_a.direction), _valid_vector(bearing_b.direction)
    p_a, p_b = _valid_vector(bearing_a.pursuer_position), _valid_vector(bearing_b.pursuer_position)
    if u_a is None or u_b is None or p_a is None or p_b is None \
            or not (_finite_time(bearing_a.time) and _finite_time(bearing_b.time)):
        return TriangulationRejection.INVALID
    norm_a, norm_b = float(np.linalg.norm(u_a)), float(np.linalg.norm(u_b))
    if norm_a == 0.0 or norm_b == 0.0:
        return TriangulationRejection.INVALID
    u_a, u_b = u_a / norm_a, u_b / norm_b
    normal = np.cross(u_a, u_b)
    sine = float(np.linalg.norm(normal))  # sin of the angle between the lines (|x1 y2 - x2 y1| in 2-D)
    angle = math.atan2(sine, abs(float(u_a @ u_b)))  # in [0, pi/2]: lines, not rays
    if angle < min_angle or sine < _MIN_SINE:
        return TriangulationRejection.NEAR_PARALLEL
    baseline = p_b - p_a
    # Law of sines in 3-D: the parameters of the closest points, p_a + s u_a and p_b + t u_b.
    # For intersecting rays s = |baseline x u_b| / |u_a x u_b|, eq. (28) with the fixed sine;
    # projecting on the common normal keeps the sign and covers skew rays.
    s = float(np.cross(baseline, u_b) @ normal) / sine**2
    t = float(np.cross(baseline, u_a) @ normal) / sine**2
    if not (s > 0.0 and t > 0.0):
        return TriangulationRejection.BEHIND_SENSOR
    if s > MAX_RANGE or t > MAX_RANGE:
        return TriangulationRejection.TOO_FAR
    closest_a, closest_b = p_a + s * u_a, p_b + t * u_b
    position = 0.5 * (closest_a + closest_b)
    # First-order covariance. The midpoint minimises the sum of squared distances to the two lines,
    # sum_i |P_i (x - p_i)|^2 with P_i = I - u_i u_i^T, so A x = sum_i P_i p_i, A = P_a + P_b.
    # A bearing error du_i (perpendicular to u_i, std sigma per axis) moves line i by ~ r_i du_i at
    # the target; then dx = A^-1 sum_i r_i P_i du_i and Cov x = sigma^2 A^-1 (s^2 P_a + t^2 P_b) A^-1.
    covariance = first_order_covariance(u_a, u_b, s, t, bearing_noise_std)
    return Triangulation(max(bearing_a.time, bearing_b.time), position, covariance, (s, t), angle,
                         float(np.linalg.norm(closest_a - closest_b)), abs(bearing_a.time - bearing_b.time))


def first_order_covariance(direction_a: np.ndarray, direction_b: np.ndarray, range_a: float, range_b: float,
                           bearing_noise_std: float) -> np.ndarray:
    """sigma^2 A^-1 (r_a^2 P_a + r_b^2 P_b) A^-1, A = P_a + P_b, P = I - u u^T: the first-order
    covariance (m^2, (3, 3)) of the closest-approach midpoint of two rays with unit directions
    u_a, u_b (3,), ranges r_a, r_b (m) to the point, bearing noise sigma (rad per axis). See
    `triangulation_attempt`; needs non-parallel directions."""
    projector_a = np.eye(3) - np.outer(direction_a, direction_a)
    projector_b = np.eye(3) - np.outer(direction_b, direction_b)
    a_inverse = np.linalg.inv(projector_a + projector_b)
    covariance = bearing_noise_std**2 * a_inverse @ (range_a**2 * projector_a + range_b**2 * projector_b) @ a_inverse
    return 0.5 * (covariance + covariance.T)


def triangulate(bearing_a: BearingMeasurement, bearing_b: BearingMeasurement, bearing_noise_std: float = 0.01,
                min_angle: float = DEFAULT_MIN_ANGLE,
                rejections: Counter | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """Target position from two bearings, seed 002 eqs. (27)-(30), in 3-D.

    Seed 002 solves the planar triangle pursuer i / neighbour / target by the law of sines
    (`law_of_sines_range`; the sin(theta) erratum fixed: the sine of the angle between unit x, y
    is |x1 y2 - x2 y1|, not ||P_x P_y||, which is |cos(theta)|). In 3-D two noisy bearing rays
    do not meet in general; the position is the midpoint of their closest approach (the point
    that minimises the sum of squared distances to both lines), which equals the law-of-sines
    point whenever the rays meet.

    bearing_a, bearing_b: the two bearings (directions need not be unit; pursuer_position, m,
    (3,), the taker's position at the bearing's time). bearing_noise_std: sigma, rad, the
    bearing noise per axis perpendicular to the line of sight. min_angle: rad, the smallest
    accepted angle between the two lines. Returns (position, m, shape (3,); covariance, m^2,
    shape (3, 3)) or None; with `rejections` given, each None adds one to
    rejections[reason.value] (TriangulationRejection: near_parallel, behind_sensor, too_far,
    invalid).

    Covariance: first order, sigma^2 A^-1 (r_a^2 P_a + r_b^2 P_b) A^-1 with A = P_a + P_b,
    P = I - u u^T, r the range along each ray. It grows like 1/sin^2 of the angle between the
    lines and with the ranges squared.

    Time. Bearings taken at different times are used as they are: the result is stamped at the
    newer time, and the target's motion between the two (speed x age) is an error the
    covariance does not contain. The caller pairs bearings close in time
    (`TriangulationKalmanEstimator` pairs within max_pair_age_s and puts the age into its
    measurement model).
    """
    result = triangulation_attempt(bearing_a, bearing_b, bearing_noise_std, min_angle)
    if isinstance(result, TriangulationRejection):
        if rejections is not None:
            rejections[result.value] += 1
        return None
    return result.position, result.covariance


# --------------------------------------------------------------------------------------------
# Kalman enhancement, seed 002 eqs. (31)-(33)
# --------------------------------------------------------------------------------------------

MAX_SOURCES = 64
"""Most sources (own sensor and neighbours) whose waiting bearings the Kalman enhancement keeps:
a stream of ever new source ids cannot grow its memory (the oldest are dropped)."""

INSTRUMENT_MAX_RELATIVE_STD = 0.1
"""The Kalman enhancement's R (measurement_noise None) comes from the predicted geometry once the
prior position std is below this fraction of the predicted ranges (see
TriangulationKalmanEstimator._measurement_covariance)."""

SEED_002_PROCESS_NOISE = 0.2
"""Seed 002's Q = 0.2 I per filter step (section 5, with its dt = 0.01 s), dimensionless factor on I(9)."""
SEED_002_MEASUREMENT_NOISE = 1.0
"""Seed 002's R = I, m^2."""


def constant_acceleration_transition(period: float) -> np.ndarray:
    """Phi of seed 002 section 5: [[I, dt I, dt^2/2 I], [0, I, dt I], [0, 0, I]], shape (9, 9),
    state [position (3), velocity (3), acceleration (3)]; period dt, s."""
    eye = np.eye(3)
    zero = np.zeros((3, 3))
    return np.block([[eye, period * eye, 0.5 * period**2 * eye], [zero, eye, period * eye], [zero, zero, eye]])


def white_jerk_process_noise(period: float, jerk_psd: float) -> np.ndarray:
    """Discrete process noise of the constant-acceleration model driven by white jerk, shape (9, 9).

    Per axis q [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]
    (Bar-Shalom, Li & Kirubarajan 2001, section 6.2.3), q = jerk_psd in (m/s^3)^2 s, dt = period
    in s. The rate-independent alternative to seed 002's Q = 0.2 I per step."""
    dt = period
    block = jerk_psd * np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                                 [dt**3 / 6, dt**2 / 2, dt]])
    return np.kron(block, np.eye(3))


class TriangulationKalmanEstimator:
    """Seed 002's Kalman enhancement, eqs. (31)-(33): a constant-acceleration Kalman filter fed by
    triangulated target positions; a `TargetEstimator` (companion.core.estimators).

    State. Seed 002 filters the relative position [p_i0, v_i0, a_i0] of the target (2-D, Phi of
    its section 5). Here the state is the absolute target state x = [p_T, v_T, a_T] (m, m/s,
    m/s^2, NED, shape (9,)), like the u-PLKF, so pursuer motion enters only through the bearing
    rays; the seed's relative velocity plus the own velocity (eq. (32)) is then v_T itself.
    `estimate` is a TargetEstimate with the 6x6 covariance of [p_T, v_T].

    Measurements. Bearings arrive one at a time through `correct(bearing)`. The estimator keeps
    the latest unused bearing of every source (0 = own sensor, >= 1 a neighbour). A new bearing
    is paired with the freshest unused bearing of another source taken within max_pair_age_s
    of it (ties: the larger angle between the lines). The pair gives one measurement, the
    triangulated point z, through the Kalman update; both bearings are consumed,
    so every bearing enters at most one triangulation and successive measurements have
    independent errors, as the Kalman filter assumes (re-using a bearing in two
    triangulations would correlate them and make the filter overconfident). A bearing with no
    partner waits for one; a degenerate pair (`triangulate`'s reasons) is counted in
    `rejections` and the new bearing waits in place of its source's older one.

    Time. The filter ticks at `period` like the u-PLKF; a triangulated position stamped between
    ticks (lead tau = its time - the filter's time, either sign) is compared with the prior
    carried there: H = [I, tau I, tau^2/2 I]. Bearings of different times (age d > 0): the older
    ray saw the target at p_T - v_T d + a_T d^2 / 2. The midpoint is linear in the ray origins
    (x = A^-1 sum_i P_i p_i), so the target's motion moves it by -L (v_T d - a_T d^2 / 2) with
    L = A^-1 P_old (A = P_a + P_b); `compensate_age` puts that into the model,
    H = [I, tau I - d L, tau^2/2 I + d^2/2 L], exact for a constant-acceleration target (off: the
    older ray is taken as simultaneous). Not done by moving the older ray with the velocity
    estimate: that makes the measurement depend on the filter's own state, and with small
    bearing noise that loop diverged (44 m RMS error with 1e-6 noise, three sensors, 0.1 s ages).

    Before the first pair (design choice). `initialize_on_bearing` starts on the first bearing
    like remark 3 of the main paper: p_T = p + r_hat u, long along the bearing (range_std), thin
    across it (r_hat x bearing_noise_std), velocity from the guess, acceleration isotropic
    (acceleration_std); or at initial_guess.position when the guess gives one. A lone bearing
    carries no range, so no correction is made from it: until a neighbour's bearing pairs
    with one, the filter only predicts and its covariance grows, which is what the pipeline's
    dropout and health logic read. The same holds whenever the neighbours fall silent: this
    estimator does not fall back to bearing-only estimation (the u-PLKF fed with all bearings
    does).

    Noise. process_noise: Q added at every prediction, a scalar q (Q = q I(9)) or a (9, 9)
    matrix; seed 002's is 0.2 I per step (`SEED_002_PROCESS_NOISE`; at its dt = 0.01 s). It is
    per step, so its meaning changes with the rate: `white_jerk_process_noise` gives a
    rate-independent Q. measurement_noise: R, m^2, a scalar (R = r I(3)) or (3, 3); seed 002's
    R = I (`SEED_002_MEASUREMENT_NOISE`). None uses the triangulation's first-order
    covariance (the consistent choice when bearing_noise_std is the sensor's), evaluated at the
    predicted target position once the prior is credible (`_measurement_covariance` says why).
    process_noise_boost: factor on Q (the pipeline's health actions set it), 1 by default.

    period: s. bearing_noise_std: rad, the bearing noise per axis (for the triangulation
    covariance and the remark-3 start). min_angle: rad (see `triangulate`). max_pair_age_s: s.
    acceleration_std: m/s^2, initial 1-sigma per axis of the acceleration.
    max_time_offset_s: s, a bearing stamped further than this from the filter's time (either
    way) is refused and counted ("time_offset"): H = [I, tau I, tau^2/2 I] is for short leads.
    gate_probability: None (default, the seed has no gate) or p in (0, 1): an update whose
    normalised innovation squared exceeds the chi-square(3) p-quantile is refused and counted
    ("gated"), e.g. a neighbour reporting a wrong position. A gate can lock a filter out after a
    manoeuvre its prior did not foresee, hence off by default.

    Bad input never raises and never changes the state: a non-finite or zero bearing is counted
    ("invalid_bearing"); degenerate pairs are counted by reason; the waiting bearings are kept for
    at most MAX_SOURCES sources.
    """

    def __init__(self, period: float, process_noise: float | np.ndarray = SEED_002_PROCESS_NOISE,
                 measurement_noise: float | np.ndarray | None = SEED_002_MEASUREMENT_NOISE,
                 *, bearing_noise_std: float = 0.01, min_angle: float = DEFAULT_MIN_ANGLE,
                 max_pair_age_s: float = 0.25, acceleration_std: float = 1.0, compensate_age: bool = True,
                 max_time_offset_s: float = 1.0, gate_probability: float | None = None) -> None:
        if not period > 0.0:
            raise ValueError("estimator period must be positive")
        if not bearing_noise_std > 0.0 or not max_pair_age_s >= 0.0 or not 0.0 <= min_angle < math.pi / 2:
            raise ValueError("need bearing_noise_std > 0, max_pair_age_s >= 0 and 0 <= min_angle < pi/2")
        if not max_time_offset_s > 0.0 or not (gate_probability is None or 0.0 < gate_probability < 1.0):
            raise ValueError("need max_time_offset_s > 0 and gate_probability in (0, 1) or None")
        self.period = float(period)
        self.process_noise = (float(process_noise) * np.eye(9) if np.ndim(process_noise) == 0
                              else np.array(process_noise, dtype=float).reshape(9, 9))
        self.measurement_noise = None if measurement_noise is None else (
            float(measurement_noise) * np.eye(3) if np.ndim(measurement_noise) == 0
            else np.array(measurement_noise, dtype=float).reshape(3, 3))
        self.bearing_noise_std = float(bearing_noise_std)
        self.min_angle = float(min_angle)
        self.max_pair_age_s = float(max_pair_age_s)
        self.acceleration_std = float(acceleration_std)
        self.compensate_age = bool(compensate_age)
        self.max_time_offset_s = float(max_time_offset_s)
        self.gate_probability = gate_probability
        self._gate = math.inf if gate_probability is None else chi2_quantile(gate_probability, 3)
        # last time stamp per source that went into a triangulation: a bearing is used at most once,
        # also when the pipeline hands the same bearing to initialize_on_bearing after correct
        self._consumed: dict[int, float] = {}
        self.process_noise_boost: float = 1.0
        self._transition = constant_acceleration_transition(self.period)
        self._state: np.ndarray | None = None
        self._covariance: np.ndarray | None = None
        self._start_time = 0.0
        self._ticks = 0
        self._waiting: dict[int, BearingMeasurement] = {}
        self.rejections: Counter[str] = Counter()
        """Counts of unusable pairs and bearings by reason (TriangulationRejection values, and
        'invalid_bearing' for a bearing that cannot be stored)."""
        self.updates = 0
        """Number of triangulated positions used."""
        self.last_triangulation: Triangulation | None = None

    # -- TargetEstimator protocol ------------------------------------------------------------
    @property
    def initialized(self) -> bool:
        return self._state is not None

    @property
    def time(self) -> float:
        """Time of the current estimate, s (start + ticks x period)."""
        return self._start_time + self._ticks * self.period

    @property
    def estimate(self) -> TargetEstimate:
        """Position, velocity and the 6x6 covariance of [p_T, v_T] (copies)."""
        state, covariance = self._require_state()
        return TargetEstimate(self.time, state[:3].copy(), state[3:6].copy(), covariance[:6, :6].copy())

    @property
    def acceleration(self) -> np.ndarray:
        """Estimated target acceleration, m/s^2, shape (3,)."""
        return self._require_state()[0][6:].copy()

    @property
    def state_and_covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the full state (9,) and its covariance (9, 9)."""
        state, covariance = self._require_state()
        return state.copy(), covariance.copy()

    def initialize(self, time: float, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray,
                   acceleration: np.ndarray | None = None) -> None:
        """Start from an explicit estimate: covariance of [p_T, v_T] (6, 6) or of the full state (9, 9)."""
        covariance = np.asarray(covariance, dtype=float)
        full = np.zeros((9, 9))
        if covariance.shape == (9, 9):
            full = covariance.copy()
        else:
            full[:6, :6] = covariance.reshape(6, 6)
            full[6:, 6:] = self.acceleration_std**2 * np.eye(3)
        acceleration = np.zeros(3) if acceleration is None else np.asarray(acceleration, dtype=float).reshape(3)
        self._start_time = float(time)
        self._ticks = 0
        self._state = np.concatenate([np.asarray(position, dtype=float).reshape(3),
                                      np.asarray(velocity, dtype=float).reshape(3), acceleration])
        self._covariance = full

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        """Remark 3 of the main paper on this bearing (see the class docstring); the bearing is also
        kept to be paired with a neighbour's. Restarts keep the waiting bearings (they are about
        the target, not about the filter)."""
        start = explicit_start(initial_guess)
        if start is not None:
            self.initialize(bearing.time, start[0], initial_guess.velocity, start[1])
        else:
            direction = np.asarray(bearing.direction, dtype=float)
            direction = direction / np.linalg.norm(direction)
            along = np.outer(direction, direction)
            cross_std = max(initial_guess.range * self.bearing_noise_std, 1e-3)
            covariance = np.zeros((6, 6))
            covariance[:3, :3] = initial_guess.range_std**2 * along + cross_std**2 * (np.eye(3) - along)
            covariance[3:, 3:] = initial_guess.velocity_std**2 * np.eye(3)
            self.initialize(bearing.time, np.asarray(bearing.pursuer_position, dtype=float) + initial_guess.range * direction,
                            initial_guess.velocity, covariance)
        self._store(bearing)

    def predict(self) -> None:
        """x^- = Phi x, P^- = Phi P Phi^T + boost Q (seed 002 section 5's model)."""
        state, covariance = self._require_state()
        self._state = self._transition @ state
        self._covariance = self._transition @ covariance @ self._transition.T + self.process_noise_boost * self.process_noise
        self._ticks += 1

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        """Use one bearing: pair it and update with the triangulated position, or keep it waiting.

        Returns a CorrectionReport whose innovation (m, (3,)), innovation_covariance S (m^2,
        (3, 3)) and innovation_dof (3) are those of the position update, or None / 0 when the
        bearing only waits. innovation_angle: rad, between this bearing and the line of sight to
        the prior mean (nan for an unusable bearing)."""
        state, _ = self._require_state()
        if _valid_vector(bearing.pursuer_position) is None or _valid_vector(bearing.direction) is None \
                or not float(np.linalg.norm(bearing.direction)) > 0.0 or not _finite_time(bearing.time):
            self.rejections["invalid_bearing"] += 1
            return CorrectionReport(math.nan, False)
        if abs(bearing.time - self.time) > self.max_time_offset_s:
            self.rejections["time_offset"] += 1
            return CorrectionReport(math.nan, False)
        innovation_angle = self._innovation_angle(bearing, state)
        partner = self._partner_for(bearing)
        if partner is None:
            self._store(bearing)
            return CorrectionReport(innovation_angle, False)
        pair = (bearing, partner)
        result = triangulation_attempt(*pair, self.bearing_noise_std, self.min_angle)
        if isinstance(result, TriangulationRejection):
            self.rejections[result.value] += 1
            self._store(bearing)
            return CorrectionReport(innovation_angle, False)
        del self._waiting[partner.source]
        for used in (bearing, partner):
            self._consumed[used.source] = max(used.time, self._consumed.get(used.source, -math.inf))
        self._bound(self._consumed, lambda time: time)
        self.last_triangulation = result
        innovation, innovation_covariance = self._update(result, pair)
        if innovation is None:
            self.rejections["gated"] += 1
            return CorrectionReport(innovation_angle, False)
        return CorrectionReport(innovation_angle, False, innovation=innovation,
                                innovation_covariance=innovation_covariance, innovation_dof=3)

    # -- internals ---------------------------------------------------------------------------
    def _store(self, bearing: BearingMeasurement) -> None:
        """Keep the bearing as its source's waiting one (if newer than that and than any already
        used); drop waiting bearings too old to pair with it; at most MAX_SOURCES are kept."""
        if bearing.time <= self._consumed.get(bearing.source, -math.inf):
            return
        waiting = self._waiting.get(bearing.source)
        if waiting is None or bearing.time >= waiting.time:
            self._waiting[bearing.source] = bearing
        newest = max(candidate.time for candidate in self._waiting.values())
        for source in [source for source, candidate in self._waiting.items()
                       if candidate.time < newest - self.max_pair_age_s]:
            del self._waiting[source]
        self._bound(self._waiting, lambda candidate: candidate.time)

    @staticmethod
    def _bound(table: dict, time_of) -> None:
        """Keep the MAX_SOURCES entries with the newest times (a flood of source ids stays bounded)."""
        while len(table) > MAX_SOURCES:
            del table[min(table, key=lambda key: time_of(table[key]))]

    def _partner_for(self, bearing: BearingMeasurement) -> BearingMeasurement | None:
        best: BearingMeasurement | None = None
        best_key = (-math.inf, -math.inf)
        direction = np.asarray(bearing.direction, dtype=float) / float(np.linalg.norm(bearing.direction))
        for source, candidate in self._waiting.items():
            if source == bearing.source or abs(candidate.time - bearing.time) > self.max_pair_age_s:
                continue
            other = np.asarray(candidate.direction, dtype=float)
            cosine = abs(float(direction @ other)) / float(np.linalg.norm(other))
            key = (candidate.time, -cosine)
            if key > best_key:
                best, best_key = candidate, key
        return best

    def _innovation_angle(self, bearing: BearingMeasurement, state: np.ndarray) -> float:
        lead = bearing.time - self.time
        relative = state[:3] + lead * state[3:6] + 0.5 * lead**2 * state[6:] - np.asarray(bearing.pursuer_position, float)
        norm = float(np.linalg.norm(relative)) * float(np.linalg.norm(bearing.direction))
        if norm == 0.0:
            return math.nan
        return math.acos(min(max(float(relative @ np.asarray(bearing.direction, float)) / norm, -1.0), 1.0))

    def _measurement_covariance(self, result: Triangulation, pair: tuple[BearingMeasurement, BearingMeasurement],
                                predicted: np.ndarray, predicted_covariance: np.ndarray) -> np.ndarray:
        """R for one triangulated position (measurement_noise None): the first-order covariance at the
        predicted target position when the prior is credible, else at the triangulated one.

        Why. The covariance at the triangulated point grows with its own (noisy) ranges, so an error
        outwards along a ray gets a larger R, hence less weight, than the same error inwards: R is
        correlated with the noise it weighs, and the filter ends overconfident (measured: mean NEES
        6.8 for 6 degrees of freedom on a target moving away from two sensors, 400 runs; 6.1 with R
        from the true geometry). The predicted position does not depend on the current bearings (the
        instrumental-variable idea of the u-PLKF's predicted gain projection). It is used once the
        prior position std is below INSTRUMENT_MAX_RELATIVE_STD of the predicted ranges and the
        predicted lines are not near parallel; before (a remark-3 start) the triangulated geometry."""
        origins = [np.asarray(b.pursuer_position, dtype=float) for b in pair]
        rays = [predicted - origin for origin in origins]
        ranges = [float(np.linalg.norm(ray)) for ray in rays]
        position_std = math.sqrt(max(float(np.trace(predicted_covariance)), 0.0) / 3.0)
        if min(ranges) > 0.0 and position_std < INSTRUMENT_MAX_RELATIVE_STD * min(ranges):
            u_a, u_b = rays[0] / ranges[0], rays[1] / ranges[1]
            sine = float(np.linalg.norm(np.cross(u_a, u_b)))
            if sine >= _MIN_SINE and math.atan2(sine, abs(float(u_a @ u_b))) >= self.min_angle:
                return first_order_covariance(u_a, u_b, ranges[0], ranges[1], self.bearing_noise_std)
        return result.covariance

    def _update(self, result: Triangulation,
                pair: tuple[BearingMeasurement, BearingMeasurement]) -> tuple[np.ndarray | None, np.ndarray]:
        """Kalman update with z = p_T(t) + noise at lead tau = t - filter time (seed 002 eq. (31)).
        Returns (innovation, S); innovation None when the gate refused the update (nothing changed)."""
        state, prior = self._require_state()
        tau = result.time - self.time
        eye = np.eye(3)
        h = np.hstack([eye, tau * eye, 0.5 * tau**2 * eye])
        if self.compensate_age and result.age > 0.0:
            older = min(pair, key=lambda b: b.time)
            u_a, u_b = (np.asarray(b.direction, dtype=float) / float(np.linalg.norm(b.direction)) for b in pair)
            u_old = np.asarray(older.direction, dtype=float) / float(np.linalg.norm(older.direction))
            projector_old = eye - np.outer(u_old, u_old)
            lag = np.linalg.solve(2.0 * eye - np.outer(u_a, u_a) - np.outer(u_b, u_b), projector_old)  # L = A^-1 P_old
            h[:, 3:6] -= result.age * lag
            h[:, 6:9] += 0.5 * result.age**2 * lag
        r = self.measurement_noise
        if r is None:
            r = self._measurement_covariance(result, pair, h @ state, h @ prior @ h.T)
        innovation = result.position - h @ state
        cross = prior @ h.T
        innovation_covariance = h @ cross + r
        innovation_covariance = 0.5 * (innovation_covariance + innovation_covariance.T)
        factor = cho_factor(innovation_covariance)
        if float(innovation @ cho_solve(factor, innovation)) > self._gate:
            return None, innovation_covariance
        gain = cho_solve(factor, cross.T).T
        self._state = state + gain @ innovation
        i_kh = np.eye(9) - gain @ h
        covariance = i_kh @ prior @ i_kh.T + gain @ r @ gain.T  # Joseph form: stays symmetric PSD
        self._covariance = 0.5 * (covariance + covariance.T)
        self.updates += 1
        return innovation, innovation_covariance

    def _require_state(self) -> tuple[np.ndarray, np.ndarray]:
        if self._state is None or self._covariance is None:
            raise RuntimeError("estimator not initialised: it needs a first bearing")
        return self._state, self._covariance


# --------------------------------------------------------------------------------------------
# Track fusion, seed 004 eqs. (24)-(25), and covariance intersection
# --------------------------------------------------------------------------------------------

def _checked(mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(mean, dtype=float).reshape(-1)
    p = np.asarray(covariance, dtype=float)
    if p.shape != (x.size, x.size) or not (np.all(np.isfinite(x)) and np.all(np.isfinite(p))):
        raise ValueError(f"need a finite mean (n,) and covariance (n, n), got {x.shape} and {p.shape}")
    return x, 0.5 * (p + p.T)


def fuse_two(x1: np.ndarray, p1: np.ndarray, x2: np.ndarray, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """State-vector fusion of two estimates, seed 004 eqs. (24)-(25), cross-covariance ignored:

        x = x1 + P1 (P1 + P2)^-1 (x2 - x1),     P = P1 - P1 (P1 + P2)^-1 P1^T.

    x1, x2: means, shape (n,); p1, p2: their covariances, (n, n), P1 + P2 positive definite.
    Equal to the information-form fusion (P1^-1 + P2^-1)^-1 of independent estimates. The seed
    treats the two UAVs' errors as independent; estimates that share information (a common
    prior, the same target manoeuvre, shared bearings) are correlated and this P is then too
    small: `covariance_intersection` is the consistent choice. Returns (x (n,), P (n, n)).
    """
    x1, p1 = _checked(x1, p1)
    x2, p2 = _checked(x2, p2)
    if x1.shape != x2.shape:
        raise ValueError("the two estimates have different sizes")
    factor = cho_factor(p1 + p2)  # raises LinAlgError unless P1 + P2 is positive definite
    gain = cho_solve(factor, p1.T).T  # P1 (P1 + P2)^-1
    fused = gain @ p2  # = P1 - P1 (P1 + P2)^-1 P1^T, written as P1 (P1 + P2)^-1 P2 (no cancellation)
    return x1 + gain @ (x2 - x1), 0.5 * (fused + fused.T)


@dataclass(frozen=True)
class FusedEstimate:
    """Result of covariance intersection: mean (n,), covariance (n, n), and the weights omega_i
    (one per input, >= 0, summing to 1) with P^-1 = sum_i omega_i P_i^-1."""

    mean: np.ndarray
    covariance: np.ndarray
    weights: tuple[float, ...]


def _information(covariance: np.ndarray) -> np.ndarray:
    factor = cho_factor(covariance)  # LinAlgError unless positive definite
    return cho_solve(factor, np.eye(covariance.shape[0]))


def _ci_pair(x1: np.ndarray, p1: np.ndarray, x2: np.ndarray, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    i1, i2 = _information(p1), _information(p2)

    def trace_for(omega: float) -> float:
        return float(np.trace(np.linalg.inv(omega * i1 + (1.0 - omega) * i2)))

    from scipy.optimize import minimize_scalar  # here: only this fusion needs scipy.optimize (0.1 s to import)

    search = minimize_scalar(trace_for, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-8})
    # The bounded search never evaluates the ends exactly; the optimum is at one when an input dominates.
    omega = min((0.0, 1.0, float(search.x)), key=trace_for)
    information = omega * i1 + (1.0 - omega) * i2
    covariance = np.linalg.inv(information)
    mean = covariance @ (omega * i1 @ x1 + (1.0 - omega) * i2 @ x2)
    return mean, 0.5 * (covariance + covariance.T), omega


def covariance_intersection(estimates: Sequence[tuple[np.ndarray, np.ndarray]]) -> FusedEstimate:
    """Covariance intersection (Julier & Uhlmann 1997) of estimates (x_i (n,), P_i (n, n), PD):

        P^-1 = sum_i omega_i P_i^-1,   x = P sum_i omega_i P_i^-1 x_i,   omega_i >= 0, sum omega_i = 1.

    Whatever the (unknown) cross-covariances of the inputs, P is at least the true error
    covariance of x whenever every P_i is at least its own, so it is the consistent way to fuse
    a pursuer's own estimate with neighbours' estimates that share bearings or a prior (seed
    004's eqs. (24)-(25), `fuse_two`, ignore the cross-covariance). omega minimises trace P
    (scipy.optimize.minimize_scalar on [0, 1], ends included). For more than two inputs the
    fusion is sequential: ((1 with 2) with 3) ..., one scalar search each; every step is a CI of
    two consistent estimates, hence consistent, but the weights are not the joint optimum and
    depend on the order. The weights returned are the products over the steps.
    """
    if len(estimates) == 0:
        raise ValueError("nothing to fuse")
    mean, covariance = _checked(*estimates[0])
    weights = [1.0]
    for x, p in estimates[1:]:
        x, p = _checked(x, p)
        if x.shape != mean.shape:
            raise ValueError("the estimates have different sizes")
        mean, covariance, omega = _ci_pair(mean, covariance, x, p)
        weights = [w * omega for w in weights] + [1.0 - omega]
    if len(estimates) == 1:
        _information(covariance)  # the same positive-definiteness check as the others
    return FusedEstimate(mean, covariance, tuple(weights))


def fuse_target_estimates(own: TargetEstimate, others: Sequence[TargetEstimate], method: str = "ci") -> TargetEstimate:
    """A pursuer's own estimate fused with neighbours' shared ones, at own.time.

    Each neighbour estimate is carried to own.time at constant velocity with its covariance
    propagated by the same transition (F P F^T, no process noise added: the gap is short, and
    a large gap should be refused by the caller). method: "ci" (`covariance_intersection`,
    own estimate first) or "seed004" (`fuse_two` applied in turn, cross-covariances ignored;
    for more than two UAVs seed 004 is ambiguous, this is one reading). Returns a TargetEstimate
    at own.time, covariance (6, 6).
    """
    pairs = [(np.concatenate([own.position, own.velocity]), own.covariance)]
    for other in others:
        gap = own.time - other.time
        transition = np.eye(6)
        transition[:3, 3:] = gap * np.eye(3)
        state = transition @ np.concatenate([other.position, other.velocity])
        pairs.append((state, transition @ other.covariance @ transition.T))
    if method == "ci":
        fused = covariance_intersection(pairs)
        mean, covariance = fused.mean, fused.covariance
    elif method == "seed004":
        mean, covariance = _checked(*pairs[0])
        for x, p in pairs[1:]:
            mean, covariance = fuse_two(mean, covariance, x, p)
    else:
        raise ValueError(f"unknown fusion method {method!r}: 'ci' or 'seed004'")
    return TargetEstimate(own.time, mean[:3].copy(), mean[3:].copy(), covariance)


# --------------------------------------------------------------------------------------------
# A pursuer's own filter absorbing its neighbours' shared estimates (estimator = 'fusion')
# --------------------------------------------------------------------------------------------

FUSION_METHODS = ("ci", "seed004")


class FusionEstimator:
    """A pursuer's own bearing-only filter that also absorbs its neighbours' shared estimates: seed 004's
    distributed fusion (its Fig. 2: each UAV filters its own measurements, then the estimates are fused
    among the UAVs, eqs. (24)-(25), and the next cycle starts from the fused result); a `TargetEstimator`.

    inner: the own filter (companion.core.estimators.UPLKF, or companion.core.imm.IMMEstimator whose model
    filters are u-PLKFs); it sees only the bearings the harness hands `correct` (the own ones). `absorb`
    fuses the current estimate with neighbours' estimates (`fuse_target_estimates`: each carried to the
    own time at constant velocity) and writes the result back into the filter, so the own filter goes on
    from the fused state (feedback). For an IMM every model-conditioned estimate is fused with the same
    neighbours (the model probabilities are left as they are). method: "ci" (covariance intersection:
    consistent whatever the cross-covariance, hence safe with feedback, where a neighbour's estimate
    already holds some of ours) or "seed004" (`fuse_two` in turn, cross-covariance ignored: with feedback
    the same information is counted again at every share, so the covariance shrinks faster than the error
    and the filter trusts its own bearings less and less; kept for the comparison).

    Hostile or useless input never changes the state: an estimate that is not finite, whose covariance is
    not positive definite, whose stamp lies more than max_age_s (s) from the own time, is refused and
    counted in `rejections` by reason ("not_finite", "not_positive_definite", "too_old"; "not_initialized"
    when the own filter has not started). `absorbed` counts the estimates fused.

    Every other attribute (process_noise_boost, motion_probabilities, ...) is the inner filter's.
    """

    def __init__(self, inner, method: str = "ci", max_age_s: float = 1.0) -> None:
        if method not in FUSION_METHODS:
            raise ValueError(f"unknown fusion method {method!r}: one of {FUSION_METHODS}")
        if not max_age_s > 0.0:
            raise ValueError("max_age_s must be positive")
        self.inner = inner
        self.method = method
        self.max_age_s = float(max_age_s)
        self.period = inner.period
        self.absorbed = 0
        self.rejections: Counter = Counter()

    # --- the TargetEstimator protocol: the own filter's ---------------------------------------
    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        self.inner.initialize_on_bearing(bearing, initial_guess)

    def predict(self) -> None:
        self.inner.predict()

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        return self.inner.correct(bearing)

    @property
    def initialized(self) -> bool:
        return self.inner.initialized

    @property
    def estimate(self) -> TargetEstimate:
        return self.inner.estimate

    @property
    def process_noise_boost(self) -> float:
        # AttributeError (hasattr False) when the own filter has none: the pipeline then leaves it alone
        return self.inner.process_noise_boost

    @process_noise_boost.setter
    def process_noise_boost(self, value: float) -> None:
        self.inner.process_noise_boost = value

    def __getattr__(self, name: str):
        # only called for names this class lacks: the own filter's extras (motion_probabilities, time, ...)
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    # --- the fusion ---------------------------------------------------------------------------
    def absorb(self, estimates: Sequence[TargetEstimate]) -> int:
        """Fuse neighbours' estimates (TargetEstimate: time s, position m, velocity m/s NED (3,), covariance
        (6, 6) over [position, velocity]) into the own filter, all at once. Returns how many were fused
        (the others are counted in `rejections`)."""
        if not self.inner.initialized:
            self.rejections["not_initialized"] += len(estimates)
            return 0
        own_time = self.inner.estimate.time
        usable = [estimate for estimate in estimates if self._usable(estimate, own_time)]
        if not usable:
            return 0
        filters = list(getattr(self.inner, "filters", None) or [self.inner])
        fused_states = []
        for model_filter in filters:
            state, covariance = model_filter.state_and_covariance
            own = TargetEstimate(own_time, state[:3].copy(), state[3:].copy(), covariance.copy())
            try:
                fused = fuse_target_estimates(own, usable, self.method)
            except np.linalg.LinAlgError:  # the own covariance degenerate: keep the own estimate
                self.rejections["fusion_failed"] += len(usable)
                return 0
            fused_states.append((np.concatenate([fused.position, fused.velocity]), fused.covariance))
        if hasattr(self.inner, "set_model_states"):
            self.inner.set_model_states(fused_states)
        else:
            self.inner.set_state(*fused_states[0])
        self.absorbed += len(usable)
        return len(usable)

    def _usable(self, estimate: TargetEstimate, own_time: float) -> bool:
        try:
            position = np.asarray(estimate.position, dtype=float).reshape(3)
            velocity = np.asarray(estimate.velocity, dtype=float).reshape(3)
            covariance = np.asarray(estimate.covariance, dtype=float).reshape(6, 6)
            stamp = float(estimate.time)
        except (TypeError, ValueError, AttributeError):
            self.rejections["not_finite"] += 1
            return False
        if not (math.isfinite(stamp) and np.all(np.isfinite(position)) and np.all(np.isfinite(velocity))
                and np.all(np.isfinite(covariance))):
            self.rejections["not_finite"] += 1
            return False
        if abs(own_time - stamp) > self.max_age_s:
            self.rejections["too_old"] += 1
            return False
        try:
            cho_factor(0.5 * (covariance + covariance.T))
        except np.linalg.LinAlgError:
            self.rejections["not_positive_definite"] += 1
            return False
        return True
