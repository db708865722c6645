"""Baseline target estimators for comparison with the u-PLKF (sections II-A and VIII-B).

All three have the interface of `companion.core.estimators.TargetEstimator` and the
bookkeeping of `UPLKF` (time = start + ticks * period, a snapshot estimate in
Cartesian NED with a 6x6 covariance of [p_T, v_T], bearings between ticks handled
by extrapolating the prior mean by bearing.time - time):

- `AzElEKF`: the "classic EKF" of section VIII-B. Cartesian state [p_T, v_T], the
  constant-velocity model of eq. (1), measurement z = [azimuth, elevation].
- `MSCEKF`: modified spherical coordinates EKF (section II-A, Stallard 1991 [23]):
  state [beta, eps, 1/r, beta_dot, eps_dot, r_dot/r] of the target relative to a
  fixed reference point, measurement z = [azimuth, elevation] on H = [I2, 0].
- `RangeAzElEKF`: the continuous-discrete EKF of seed 003 (Ahmed and Subbarao,
  Aerospace 2016, eq. (2)-(3), (9)-(10), Table 1): state [x, y, z, v, gamma, chi],
  measurement [range, azimuth, elevation]. Needs a range sensor.

Conventions (local NED, z down, SI units). For the relative position d = p_T - p:
azimuth beta = atan2(d_y, d_x), elevation eps = atan2(-d_z, sqrt(d_x^2 + d_y^2))
(positive up), range r = |d|. Angle residuals are wrapped to (-pi, pi].

Bearing noise. Eq. (4) adds nu ~ N(0, sigma^2 I) to the unit line of sight (the
constructors take Sigma like the u-PLKF; sigma^2 = trace(Sigma)/3). To first order the
angles of lambda + nu move by J_u nu, J_u the Jacobian of (beta, eps) at the unit
vector, whose rows are orthogonal with norms 1/cos(eps) and 1, so the angle noise is
R = sigma^2 diag(1/cos^2(eps), 1). Own-position noise p + n_p, n_p ~ N(0, sigma_p^2 I),
adds sigma_p^2 J_d J_d^T = sigma_p^2 diag(1/rho^2, 1/r^2) (rho = r cos(eps)), the angular
counterpart of the u-PLKF's own-position term (sigma_p^2 / r^2 on each angle, with
azimuth measured in the horizontal plane).

Numerical guards: the elevation used in Jacobians and noise covariances is clipped to
+-(90 deg - MAX_ELEVATION_MARGIN), ranges are floored at MIN_RANGE, covariance updates
use the Joseph form and are symmetrised, the MSC-EKF's covariance transforms are kept PSD
(`_symmetric_psd`), and the az/el EKF's range is capped at MAX_RANGE, so finite inputs never
give NaN or overflow, however noisy the bearings.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core._jit import jit, remainder
from companion.core.estimators import (MAX_RANGE, CorrectionReport, InitialGuess, explicit_start, limit_range,
                                       on_bearing_covariance, restart_guess, transition_matrices)
from companion.core.geometry import unit
from companion.core.messages import BearingMeasurement, TargetEstimate

MAX_ELEVATION_MARGIN = 1e-3
"""rad: elevations used in Jacobians/covariances are clipped to +-(pi/2 - this)."""
MAX_ELEVATION = 0.5 * math.pi - MAX_ELEVATION_MARGIN
MIN_RANGE = 1e-6
"""m: floor on ranges used as divisors."""
MIN_INVERSE_RANGE = 1.0 / MAX_RANGE
"""1/m: floor on the MSC inverse range (targets at most MAX_RANGE = 1000 km away)."""
MAX_INVERSE_RANGE = 1e3
"""1/m: ceiling on the MSC inverse range (targets at least 1 mm away)."""


# --------------------------------------------------------------------------- shared helpers
#
# The arithmetic of every update is in module-level kernels (`@jit`) over float64 arrays and floats, compiled by
# numba when it is installed (companion.core._jit), the plain Python functions otherwise (BOF_NO_JIT=1): the same
# operations in the same order either way (math.remainder, which numba lacks, as _jit.remainder), agreeing to
# rounding. The classes keep the clock, the snapshots and the restarts.


@jit
def wrap_angle(angle: float) -> float:
    """Wrap an angle (rad) to (-pi, pi]."""
    wrapped = remainder(float(angle), 2.0 * math.pi)  # in [-pi, pi]
    return math.pi if wrapped == -math.pi else wrapped


@jit
def _symmetrize(matrix: np.ndarray) -> np.ndarray:
    return 0.5 * (matrix + matrix.T)


@jit
def _symmetric_psd(matrix: np.ndarray) -> np.ndarray:
    """The nearest symmetric positive semi-definite matrix (Frobenius norm; Higham 1988): the
    symmetric part with its negative eigenvalues set to zero. Shape (n, n) in and out.

    Why: the MSC-EKF moves its covariance through congruences J P J^T whose Jacobians are badly
    scaled far out (at the inverse-range floor, entries of 1e6 beside 1e-6), and their rounding
    can leave eigenvalues of -1e-6 beside 0.1, which the next steps amplify. A symmetric
    PSD input comes back unchanged.
    """
    symmetric = _symmetrize(matrix)
    eigenvalues, vectors = np.linalg.eigh(symmetric)
    if eigenvalues[0] >= 0.0:
        return symmetric
    vectors = np.ascontiguousarray(vectors)  # C-ordered as numpy's (numba's come Fortran-ordered)
    return _symmetrize((vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T)


@jit
def _horizontal_and_range(relative: np.ndarray) -> tuple[float, float]:
    """(rho, r) of a relative position, m, guarded: r >= MIN_RANGE and rho >= r cos(MAX_ELEVATION)."""
    dx, dy, dz = float(relative[0]), float(relative[1]), float(relative[2])
    rho = math.hypot(dx, dy)
    r = max(math.sqrt(rho * rho + dz * dz), MIN_RANGE)
    return max(rho, r * math.cos(MAX_ELEVATION)), r


@jit
def _norm(vector: np.ndarray) -> float:
    """|vector|, m, as np.linalg.norm computes it for a float vector: sqrt(vector . vector), the same BLAS dot."""
    return math.sqrt(float(np.dot(vector, vector)))


@jit
def azimuth_elevation(relative: np.ndarray) -> np.ndarray:
    """[beta, eps], rad, of a relative position d (m, shape (3,)) in NED; shape (2,).

    beta = atan2(d_y, d_x), eps = atan2(-d_z, sqrt(d_x^2 + d_y^2)) (section VIII-B's
    azimuth/elevation measurement, elevation positive up). atan2 is finite everywhere.
    """
    dx, dy, dz = float(relative[0]), float(relative[1]), float(relative[2])
    return np.array([math.atan2(dy, dx), math.atan2(-dz, math.hypot(dx, dy))])


@jit
def azimuth_elevation_jacobian(relative: np.ndarray) -> np.ndarray:
    """d[beta, eps]/dd at d (m, shape (3,)); shape (2, 3), units 1/m.

    Standard form: dbeta/dd = [-d_y, d_x, 0]/rho^2, deps/dd = [d_z d_x/(r^2 rho),
    d_z d_y/(r^2 rho), -rho/r^2] (NED, so the sign of the z terms differs from an
    up-axis frame). rho and r are guarded (see `_horizontal_and_range`).
    """
    dx, dy, dz = float(relative[0]), float(relative[1]), float(relative[2])
    rho, r = _horizontal_and_range(relative)
    rho2, r2 = rho * rho, r * r
    return np.array(
        [
            [-dy / rho2, dx / rho2, 0.0],
            [dz * dx / (r2 * rho), dz * dy / (r2 * rho), -rho / r2],
        ]
    )


@jit
def range_azimuth_elevation(relative: np.ndarray) -> np.ndarray:
    """[r, beta, eps] (m, rad, rad) of d = p_T - p, seed 003 eq. (2)-(3) in NED; shape (3,)."""
    angles = azimuth_elevation(relative)
    return np.array([_norm(relative), angles[0], angles[1]])


@jit
def range_azimuth_elevation_jacobian(relative: np.ndarray) -> np.ndarray:
    """H_rd of seed 003 (section 2.2) in NED, d[r, beta, eps]/dd; shape (3, 3).

    Range row d^T / r. Azimuth row [-d_y/rho^2, d_x/rho^2, 0]: the corrected row of the
    seed-003 erratum (the paper prints the divisor rho instead of rho^2). Elevation row as
    in `azimuth_elevation_jacobian` (NED: eps = atan2(-d_z, rho)).
    """
    _, r = _horizontal_and_range(relative)
    jacobian = np.empty((3, 3))
    jacobian[0] = relative / r
    jacobian[1:] = azimuth_elevation_jacobian(relative)
    return jacobian


@jit
def angle_noise_covariance(bearing_variance: float, relative: np.ndarray, pursuer_position_std: float) -> np.ndarray:
    """R of the [azimuth, elevation] measurement, rad^2, shape (2, 2) (module docstring).

    R = sigma^2 diag(1/cos^2(eps), 1) + sigma_p^2 J_d J_d^T: first-order mapping of the
    additive unit-vector noise of eq. (4) and of the own-position noise, at the
    (predicted) relative position d (m, shape (3,)); eps clipped to +-MAX_ELEVATION.
    """
    rho, r = _horizontal_and_range(relative)
    cos_eps = rho / r
    r_matrix = np.diag(np.array([bearing_variance / (cos_eps * cos_eps), bearing_variance]))
    if pursuer_position_std > 0.0:
        s2 = pursuer_position_std ** 2
        r_matrix = r_matrix + np.diag(np.array([s2 / (rho * rho), s2 / (r * r)]))
    return r_matrix


def _measured_direction(bearing: BearingMeasurement) -> np.ndarray:
    return unit(np.asarray(bearing.direction, dtype=float))


@jit
def _innovation_angle(direction: np.ndarray, relative: np.ndarray) -> float:
    """Angle, rad, between the unit measured bearing and the predicted line of sight d."""
    norm = _norm(relative)
    if norm < MIN_RANGE:
        return 0.5 * math.pi
    return float(math.acos(min(1.0, max(-1.0, float(direction @ relative) / norm))))


@jit
def _behind(restart_when_behind: bool, direction: np.ndarray, relative: np.ndarray, predicted_range: float) -> bool:
    """The restart guard (remark 3, as the u-PLKF's): a prior behind the sensor or on it."""
    return restart_when_behind and (float(direction @ relative) <= 0.0 or predicted_range < 1e-6)


@jit
def _innovation_covariance(covariance: np.ndarray, h: np.ndarray, r: np.ndarray) -> np.ndarray:
    """S = H P H^T + R, shape (m, m), the covariance of the residual (reported, as in `_kalman_update`)."""
    return _symmetrize(h @ covariance @ h.T + r)


@jit
def _kalman_update(
    state: np.ndarray, covariance: np.ndarray, residual: np.ndarray, h: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """EKF measurement update (Table 1 of seed 003; standard textbook form), Joseph covariance.

    K = P H^T (H P H^T + R)^-1, x+ = x + K nu, P+ = (I - K H) P (I - K H)^T + K R K^T
    (the Joseph form keeps P+ symmetric PSD for any gain). Shapes: state (n,),
    covariance (n, n), residual (m,), h (m, n), r (m, m).
    """
    ph_t = covariance @ h.T
    innovation_covariance = _symmetrize(h @ ph_t + r)
    # numpy's solve returns a C-ordered (m, n), numba's a Fortran-ordered one: made C-ordered here, so that
    # K = its transpose is Fortran-ordered either way and K nu, K H, K R K^T take the same BLAS paths
    # (a C-ordered K sends K nu to the other gemv kernel, which rounds differently)
    gain = np.ascontiguousarray(np.linalg.solve(innovation_covariance, ph_t.T)).T
    i_kh = np.eye(state.size) - gain @ h
    updated = i_kh @ covariance @ i_kh.T + gain @ r @ gain.T
    return state + gain @ residual, _symmetrize(updated)


@jit
def _linear_predict(transition: np.ndarray, discrete_process_noise: np.ndarray, state: np.ndarray,
                    covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x^-, P^-) of eq. (1): x^- = A x, P^- = A P A^T + B Q B^T (symmetrised); A (6, 6), B Q B^T (6, 6)."""
    return transition @ state, _symmetrize(transition @ covariance @ transition.T + discrete_process_noise)


class _TickedFilter:
    """Clock and snapshot bookkeeping shared by the baselines (same rules as UPLKF)."""

    def __init__(self, period: float, measurement_noise: np.ndarray, pursuer_position_std: float) -> None:
        if period <= 0.0:
            raise ValueError("estimator period must be positive")
        self.period = float(period)
        self.measurement_noise = np.asarray(measurement_noise, dtype=float).reshape(3, 3)
        self.bearing_variance = float(np.trace(self.measurement_noise)) / 3.0  # sigma^2 of eq. (4)
        self.pursuer_position_std = float(pursuer_position_std)
        self._start_time = 0.0
        self._ticks = 0
        self._snapshot: TargetEstimate | None = None
        self._initial_guess: InitialGuess | None = None
        self._state: np.ndarray | None = None  # the filter's own state vector, shape (6,)
        self._covariance: np.ndarray | None = None

    @property
    def time(self) -> float:
        """Time of the current estimate, s (start + ticks * period, so it never drifts)."""
        return self._start_time + self._ticks * self.period

    @property
    def initialized(self) -> bool:
        return self._state is not None

    def _require_state(self) -> tuple[np.ndarray, np.ndarray]:
        if self._state is None or self._covariance is None:
            raise RuntimeError("estimator not initialised: it needs a first bearing")
        return self._state, self._covariance

    @property
    def estimate(self) -> TargetEstimate:
        """The current estimate in Cartesian NED (a snapshot: later updates do not change it)."""
        if self._snapshot is None:
            state, covariance = self._cartesian()
            self._snapshot = TargetEstimate(self.time, state[:3].copy(), state[3:].copy(), _symmetrize(covariance))
        return self._snapshot

    def _cartesian(self) -> tuple[np.ndarray, np.ndarray]:
        """Absolute [p_T, v_T] (shape (6,)) and its covariance (6, 6)."""
        raise NotImplementedError

    def _restart_on(self, bearing: BearingMeasurement, predicted_range: float, velocity: np.ndarray) -> None:
        """Remark 3 restart at the predicted range (as `UPLKF._restart_on`)."""
        self.initialize_on_bearing(bearing, restart_guess(self._initial_guess, predicted_range, velocity))  # type: ignore[attr-defined]

    def _bearing_start(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> tuple[np.ndarray, np.ndarray]:
        """(position, covariance of [p_T, v_T]) of remark 3 or of the explicit start."""
        start = explicit_start(initial_guess)
        if start is not None:
            return start
        direction = _measured_direction(bearing)
        cross_std = max(initial_guess.range * math.sqrt(self.bearing_variance), 1e-3)
        covariance = on_bearing_covariance(direction, initial_guess.range_std, cross_std, initial_guess.velocity_std)
        return np.asarray(bearing.pursuer_position, float) + initial_guess.range * direction, covariance


class _ConstantVelocityFilter(_TickedFilter):
    """The constant-velocity target model of eq. (1) shared by the az/el EKF and the MSC-EKF:
    Q (target acceleration covariance, (m/s^2)^2, (3, 3)), A, B and B Q B^T, and the restart guard."""

    def __init__(self, period: float, process_noise: np.ndarray, measurement_noise: np.ndarray,
                 pursuer_position_std: float = 0.0, restart_when_behind: bool = True) -> None:
        super().__init__(period, measurement_noise, pursuer_position_std)
        self.process_noise = np.asarray(process_noise, dtype=float).reshape(3, 3)
        self.restart_when_behind = bool(restart_when_behind)
        self._a, self._b = transition_matrices(self.period)
        self._q_discrete = self._b @ self.process_noise @ self._b.T


# --------------------------------------------------------------------------- classic EKF


@jit
def _az_el_correct(state: np.ndarray, covariance: np.ndarray, lead: float, pursuer_position: np.ndarray,
                   direction: np.ndarray, restart_when_behind: bool, bearing_variance: float, pursuer_position_std: float):
    """`AzElEKF.correct`'s arithmetic: the [beta, eps] update of section VIII-B with H = J_d [I3, lead I3].

    state: [p_T, v_T] (6,), covariance (6, 6), at the filter's time; lead: bearing time - filter time, s;
    pursuer_position: p (3,), m; direction: the unit measured bearing (3,). Returns (restart, innovation angle,
    predicted range, residual (2,), S (2, 2), x+ (6,), P+ (6, 6)): restart when the guard fires (then the rest
    is the prior, unused), else the Joseph update with its target position kept within MAX_RANGE."""
    relative = state[:3] + lead * state[3:] - pursuer_position
    innovation_angle = _innovation_angle(direction, relative)
    predicted_range = _norm(relative)
    if _behind(restart_when_behind, direction, relative, predicted_range):
        return True, innovation_angle, predicted_range, np.zeros(2), np.zeros((2, 2)), state, covariance
    residual = azimuth_elevation(direction) - azimuth_elevation(relative)
    residual = np.array([wrap_angle(residual[0]), wrap_angle(residual[1])])
    jacobian = azimuth_elevation_jacobian(relative)
    h = np.hstack((jacobian, lead * jacobian))
    r = angle_noise_covariance(bearing_variance, relative, pursuer_position_std)
    innovation_covariance = _innovation_covariance(covariance, h, r)
    updated, updated_covariance = _kalman_update(state, covariance, residual, h, r)
    # A linearised angle update steps along the tangent plane, so large residuals (a
    # sensor much noisier than Sigma) lengthen the range at every bearing: keep it bounded.
    updated[:3] = limit_range(updated[:3], pursuer_position)
    return False, innovation_angle, predicted_range, residual, innovation_covariance, updated, updated_covariance


class AzElEKF(_ConstantVelocityFilter):
    """The "classic EKF" of section VIII-B: Cartesian [p_T, v_T], measurement [azimuth, elevation].

    Prediction as the u-PLKF (eq. (1)): x^- = A x, P^- = A P A^T + B Q B^T. Correction
    with z = [beta, eps] of the measured bearing and h(x) = [beta, eps](p_T - p)
    (analytic Jacobian, `azimuth_elevation_jacobian`), R from `angle_noise_covariance`.

    The restart guard of the u-PLKF applies: a prior that lies behind the sensor
    (angle to the bearing > 90 deg) restarts the filter on the bearing (remark 3).

    period: Delta t, s. process_noise: Q, target acceleration covariance, (m/s^2)^2,
    shape (3, 3). measurement_noise: Sigma of eq. (4), shape (3, 3) (sigma^2 = trace/3).
    pursuer_position_std: sigma_p, m (0: the paper's EKF). restart_when_behind: the guard.
    (The constructor is the constant-velocity base's.)
    """

    def initialize(self, time: float, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray) -> None:
        """Start from an explicit target estimate; covariance of [p_T, v_T], shape (6, 6)."""
        self._start_time = float(time)
        self._ticks = 0
        self._snapshot = None
        self._state = np.concatenate([np.asarray(position, float).reshape(3), np.asarray(velocity, float).reshape(3)])
        self._covariance = _symmetrize(np.array(covariance, dtype=float).reshape(6, 6))

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        """p_T(0) = p(0) + r_hat(0) lambda~(0) (remark 3), or initial_guess.position when set."""
        self._initial_guess = initial_guess
        position, covariance = self._bearing_start(bearing, initial_guess)
        self.initialize(bearing.time, position, initial_guess.velocity, covariance)

    def predict(self) -> None:
        """Time update over one period (eq. (1)): x^- = A x, P^- = A P A^T + B Q B^T."""
        state, covariance = self._require_state()
        self._snapshot = None
        self._state, self._covariance = _linear_predict(self._a, self._q_discrete, state, covariance)
        self._ticks += 1

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        """EKF update with z = [beta, eps] (section VIII-B; Table 1 of seed 003 form).

        Between ticks the measurement is a function of the state at `time` through
        d = p_T + lead v_T - p (lead = bearing.time - time), so H = J_d [I3, lead I3]
        (exact linearisation of that map; the process noise over the lead is neglected,
        as in the u-PLKF). Azimuth residual wrapped to (-pi, pi].
        """
        state, covariance = self._require_state()
        lead = bearing.time - self.time
        pursuer = np.asarray(bearing.pursuer_position, float)
        direction = _measured_direction(bearing)
        restart, innovation_angle, predicted_range, residual, innovation_covariance, updated, updated_covariance = \
            _az_el_correct(state, covariance, lead, pursuer, direction, self.restart_when_behind, self.bearing_variance,
                           self.pursuer_position_std)
        if restart:
            self._restart_on(bearing, predicted_range, state[3:].copy())
            return CorrectionReport(innovation_angle, False, reinitialized=True)
        self._snapshot = None
        self._state, self._covariance = updated, updated_covariance
        return CorrectionReport(innovation_angle, False, innovation=residual, innovation_covariance=innovation_covariance,
                                innovation_dof=2)

    def _cartesian(self) -> tuple[np.ndarray, np.ndarray]:
        return self._require_state()


# --------------------------------------------------------------------------- modified spherical coordinates


@jit
def _unit_and_partials(beta: float, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u(beta, eps) = [cos eps cos beta, cos eps sin beta, -sin eps] (NED, eps up) and du/dbeta, du/deps."""
    cb, sb, ce, se = math.cos(beta), math.sin(beta), math.cos(eps), math.sin(eps)
    u = np.array([ce * cb, ce * sb, -se])
    u_beta = np.array([-ce * sb, ce * cb, 0.0])
    u_eps = np.array([-se * cb, -se * sb, -ce])
    return u, u_beta, u_eps


@jit
def cartesian_from_msc(y: np.ndarray) -> np.ndarray:
    """Relative Cartesian [d, d_dot] (m, m/s; shape (6,)) from MSC y (shape (6,)).

    y = [beta, eps, w = 1/r, beta_dot, eps_dot, s = r_dot/r] (Stallard 1991 [23], the
    modified spherical coordinates of section II-A, with this module's NED angles).
    Standard form: d = u/w, d_dot = (s u + beta_dot du/dbeta + eps_dot du/deps)/w.
    w is floored at MIN_INVERSE_RANGE.
    """
    beta, eps, w, beta_dot, eps_dot, s = float(y[0]), float(y[1]), float(y[2]), float(y[3]), float(y[4]), float(y[5])
    w = max(w, MIN_INVERSE_RANGE)
    u, u_beta, u_eps = _unit_and_partials(beta, eps)
    return np.concatenate((u / w, (s * u + beta_dot * u_beta + eps_dot * u_eps) / w))


@jit
def msc_from_cartesian(relative_state: np.ndarray) -> np.ndarray:
    """MSC y = [beta, eps, 1/r, beta_dot, eps_dot, r_dot/r] from [d, d_dot] (shape (6,) each).

    Standard form (inverse of `cartesian_from_msc`): beta = atan2(d_y, d_x),
    eps = atan2(-d_z, rho), 1/r, beta_dot = (d_x v_y - d_y v_x)/rho^2,
    eps_dot = (-rho v_z + d_z rho_dot)/r^2 with rho_dot = (d_x v_x + d_y v_y)/rho,
    r_dot/r = d.v / r^2. Units rad, 1/m, rad/s, 1/s. rho and r guarded.
    """
    d = relative_state[:3]
    dx, dy, dz = float(relative_state[0]), float(relative_state[1]), float(relative_state[2])
    vx, vy, vz = float(relative_state[3]), float(relative_state[4]), float(relative_state[5])
    rho, r = _horizontal_and_range(d)
    r2 = r * r
    rho_dot = (dx * vx + dy * vy) / rho
    return np.array(
        [
            math.atan2(dy, dx),
            math.atan2(-dz, math.hypot(dx, dy)),
            min(1.0 / r, MAX_INVERSE_RANGE),
            (dx * vy - dy * vx) / (rho * rho),
            (-rho * vz + dz * rho_dot) / r2,
            (dx * vx + dy * vy + dz * vz) / r2,
        ]
    )


@jit
def cartesian_from_msc_jacobian(y: np.ndarray) -> np.ndarray:
    """d[d, d_dot]/dy of `cartesian_from_msc` (analytic); shape (6, 6).

    Columns: dd/dbeta = u_beta/w, dd/deps = u_eps/w, dd/dw = -d/w, and for the rate part
    d d_dot/dbeta = (s u_beta + beta_dot u_bb + eps_dot u_be)/w, d d_dot/deps =
    (s u_eps + beta_dot u_be - eps_dot u)/w (u_ee = -u), d d_dot/dw = -d_dot/w,
    d d_dot/d[beta_dot, eps_dot, s] = [u_beta, u_eps, u]/w.
    """
    beta, eps, w, beta_dot, eps_dot, s = float(y[0]), float(y[1]), float(y[2]), float(y[3]), float(y[4]), float(y[5])
    w = max(w, MIN_INVERSE_RANGE)
    cb, sb, ce, se = math.cos(beta), math.sin(beta), math.cos(eps), math.sin(eps)
    u, u_beta, u_eps = _unit_and_partials(beta, eps)
    u_bb = np.array([-ce * cb, -ce * sb, 0.0])
    u_be = np.array([se * sb, -se * cb, 0.0])
    d = u / w
    d_dot = (s * u + beta_dot * u_beta + eps_dot * u_eps) / w
    jacobian = np.zeros((6, 6))
    jacobian[:3, 0] = u_beta / w
    jacobian[:3, 1] = u_eps / w
    jacobian[:3, 2] = -d / w
    jacobian[3:, 0] = (s * u_beta + beta_dot * u_bb + eps_dot * u_be) / w
    jacobian[3:, 1] = (s * u_eps + beta_dot * u_be - eps_dot * u) / w
    jacobian[3:, 2] = -d_dot / w
    jacobian[3:, 3] = u_beta / w
    jacobian[3:, 4] = u_eps / w
    jacobian[3:, 5] = u / w
    return jacobian


@jit
def msc_from_cartesian_jacobian(relative_state: np.ndarray) -> np.ndarray:
    """dy/d[d, d_dot] of `msc_from_cartesian` (analytic); shape (6, 6).

    Derivatives of the standard forms in `msc_from_cartesian` (rho, r guarded), with
    N = -rho v_z + d_z q/rho, q = d_x v_x + d_y v_y, eps_dot = N/r^2.
    """
    dx, dy, dz = float(relative_state[0]), float(relative_state[1]), float(relative_state[2])
    vx, vy, vz = float(relative_state[3]), float(relative_state[4]), float(relative_state[5])
    d = np.array([dx, dy, dz])
    v = np.array([vx, vy, vz])
    rho, r = _horizontal_and_range(d)
    rho2, r2 = rho * rho, r * r
    r4 = r2 * r2
    q = dx * vx + dy * vy
    jacobian = np.zeros((6, 6))
    jacobian[:2, :3] = azimuth_elevation_jacobian(d)
    jacobian[2, :3] = -d / (r2 * r)
    # beta_dot = c / rho^2, c = dx vy - dy vx
    c = dx * vy - dy * vx
    jacobian[3, 0] = vy / rho2 - 2.0 * dx * c / (rho2 * rho2)
    jacobian[3, 1] = -vx / rho2 - 2.0 * dy * c / (rho2 * rho2)
    jacobian[3, 2] = 0.0
    jacobian[3, 3] = -dy / rho2
    jacobian[3, 4] = dx / rho2
    jacobian[3, 5] = 0.0
    # eps_dot = N / r^2
    n = -rho * vz + dz * q / rho
    rho3 = rho2 * rho
    dn_dd = np.array(
        [
            -dx / rho * vz + dz * (vx / rho - q * dx / rho3),
            -dy / rho * vz + dz * (vy / rho - q * dy / rho3),
            q / rho,
        ]
    )
    dn_dv = np.array([dz * dx / rho, dz * dy / rho, -rho])
    jacobian[4, :3] = dn_dd / r2 - 2.0 * n * d / r4
    jacobian[4, 3:] = dn_dv / r2
    # s = d.v / r^2
    jacobian[5, :3] = v / r2 - 2.0 * float(d @ v) * d / r4
    jacobian[5, 3:] = d / r2
    return jacobian


@jit
def _msc_guard(y: np.ndarray) -> np.ndarray:
    """y with beta wrapped, eps clipped to +-MAX_ELEVATION, 1/r kept in [MIN_INVERSE_RANGE, MAX_INVERSE_RANGE]."""
    guarded = y.copy()
    guarded[0] = wrap_angle(guarded[0])
    guarded[1] = min(MAX_ELEVATION, max(-MAX_ELEVATION, float(guarded[1])))
    guarded[2] = min(MAX_INVERSE_RANGE, max(MIN_INVERSE_RANGE, float(guarded[2])))
    return guarded


@jit
def _msc_propagate(state: np.ndarray, covariance: np.ndarray, a: np.ndarray,
                   q_discrete: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y^-, P^-) over one step with transition A and Cartesian process noise Q_d (`MSCEKF`'s docstring):
    y^- = m(A c(y)) guarded, P^- = J_m (A J_c P J_c^T A^T + Q_d) J_m^T kept PSD."""
    moved = a @ cartesian_from_msc(state)
    j_c = a @ cartesian_from_msc_jacobian(state)
    j_m = msc_from_cartesian_jacobian(moved)
    cartesian_covariance = j_c @ covariance @ j_c.T + q_discrete
    return _msc_guard(msc_from_cartesian(moved)), _symmetric_psd(j_m @ cartesian_covariance @ j_m.T)


@jit
def _msc_from_absolute(cartesian: np.ndarray, covariance: np.ndarray,
                       reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y, P_y) of absolute [p_T, v_T] (6,) and its covariance (6, 6) about p_ref (3,): y = m([p_T - p_ref, v_T])
    guarded, P_y = J_m P J_m^T kept PSD."""
    relative_state = cartesian.copy()
    relative_state[:3] -= reference
    j_m = msc_from_cartesian_jacobian(relative_state)
    return _msc_guard(msc_from_cartesian(relative_state)), _symmetric_psd(j_m @ covariance @ j_m.T)


@jit
def _msc_to_absolute(state: np.ndarray, covariance: np.ndarray,
                     reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Absolute [p_ref + d, d_dot] (6,) of MSC y about p_ref (3,) and J_c P J_c^T (6, 6) kept PSD."""
    relative_state = cartesian_from_msc(state)
    j_c = cartesian_from_msc_jacobian(state)
    relative_state[:3] += reference
    return relative_state, _symmetric_psd(j_c @ covariance @ j_c.T)


@jit
def _msc_correct(state: np.ndarray, covariance: np.ndarray, referenced: bool, reference: np.ndarray,
                 pursuer_position: np.ndarray, lead: float, a_lead: np.ndarray, direction: np.ndarray,
                 restart_when_behind: bool, bearing_variance: float, pursuer_position_std: float):
    """`MSCEKF.correct`'s arithmetic: re-reference to the bearing's pursuer position, then the [beta, eps] update
    on H = [I2, 0] (H = [I2, 0] J_m(A(lead) c(y)) A(lead) J_c(y) for a bearing lead s off the filter's time).

    state, covariance: y (6,) and P (6, 6) about `reference` (3,) when `referenced`, else absolute Cartesian.
    pursuer_position: p (3,), m, the new reference. a_lead: A(lead) (6, 6), used when lead != 0. direction: the
    unit measured bearing (3,). Returns (y', P' about p, restart, innovation angle, predicted range, the relative
    state at the bearing's time (6,), residual (2,), S (2, 2), y+ (6,), P+ (6, 6)); on restart the last four are
    placeholders (the re-referenced prior)."""
    if referenced:
        cartesian, cartesian_covariance = _msc_to_absolute(state, covariance, reference)
    else:
        cartesian, cartesian_covariance = state.copy(), covariance.copy()
    state, covariance = _msc_from_absolute(cartesian, cartesian_covariance, pursuer_position)
    if lead == 0.0:
        relative_state = cartesian_from_msc(state)
        predicted = state[:2]
        h = np.hstack((np.eye(2), np.zeros((2, 4))))
    else:
        relative_state = a_lead @ cartesian_from_msc(state)
        predicted = msc_from_cartesian(relative_state)[:2]
        h = (msc_from_cartesian_jacobian(relative_state)[:2] @ a_lead) @ cartesian_from_msc_jacobian(state)
    relative = relative_state[:3]
    innovation_angle = _innovation_angle(direction, relative)
    predicted_range = _norm(relative)
    if _behind(restart_when_behind, direction, relative, predicted_range):
        return (state, covariance, True, innovation_angle, predicted_range, relative_state, np.zeros(2),
                np.zeros((2, 2)), state, covariance)
    residual = azimuth_elevation(direction) - predicted
    residual = np.array([wrap_angle(residual[0]), wrap_angle(residual[1])])
    r = angle_noise_covariance(bearing_variance, relative, pursuer_position_std)
    innovation_covariance = _innovation_covariance(covariance, h, r)
    updated, updated_covariance = _kalman_update(state, covariance, residual, h, r)
    return (state, covariance, False, innovation_angle, predicted_range, relative_state, residual, innovation_covariance,
            _msc_guard(updated), updated_covariance)


class MSCEKF(_ConstantVelocityFilter):
    """Modified spherical coordinates EKF (section II-A; Stallard 1991 [23]).

    State y = [beta, eps, 1/r, beta_dot, eps_dot, r_dot/r] of d = p_T - p_ref, p_ref a
    fixed reference point: the pursuer position at the last correction (the first
    bearing's at initialisation). predict() does not know the pursuer's motion, so
    between corrections p_ref stays fixed and [d, d_dot] moves as the constant-velocity
    target (d_dot = v_T). Propagation is exact for the mean,
    y^- = m(A c(y)), c = `cartesian_from_msc`, m = `msc_from_cartesian`, with
    covariance P^- = J_m (A J_c P J_c^T A^T + B Q B^T) J_m^T using the analytic Jacobians
    J_c at y and J_m at A c(y) (the process noise of eq. (1) mapped into MSC).

    correct() first re-references to the bearing's pursuer position p (exact transform
    through Cartesian, y' = m(c(y) + [p_ref - p, 0]), P' = J_m J_c P J_c^T J_m^T), then
    updates linearly on H = [I2, 0] with z = [beta, eps] of the bearing and R of
    `angle_noise_covariance`. A bearing between ticks uses the mean carried by
    lead = bearing.time - time, and H = [I2, 0] J_m(A(lead) c(y)) A(lead) J_c(y).
    After the update 1/r is kept in [MIN_INVERSE_RANGE, MAX_INVERSE_RANGE], beta
    wrapped and eps clipped to +-MAX_ELEVATION.

    `initialize` without a reference keeps the Cartesian estimate until the first
    correction supplies one. Restart guard as `AzElEKF`.

    period: s. process_noise: Q, (m/s^2)^2, shape (3, 3). measurement_noise: Sigma of
    eq. (4), shape (3, 3). pursuer_position_std: sigma_p, m.
    """

    def __init__(
        self,
        period: float,
        process_noise: np.ndarray,
        measurement_noise: np.ndarray,
        pursuer_position_std: float = 0.0,
        restart_when_behind: bool = True,
    ) -> None:
        super().__init__(period, process_noise, measurement_noise, pursuer_position_std, restart_when_behind)
        self._reference: np.ndarray | None = None  # while None, _state is absolute Cartesian, else MSC y

    @property
    def reference(self) -> np.ndarray | None:
        """p_ref, m, shape (3,), or None while the state is still Cartesian."""
        return None if self._reference is None else self._reference.copy()

    @property
    def msc_state(self) -> np.ndarray | None:
        """y, shape (6,), or None while the state is still Cartesian."""
        return None if self._reference is None or self._state is None else self._state.copy()

    def initialize(
        self,
        time: float,
        position: np.ndarray,
        velocity: np.ndarray,
        covariance: np.ndarray,
        reference: np.ndarray | None = None,
    ) -> None:
        """Start from an explicit Cartesian target estimate; covariance of [p_T, v_T], (6, 6).

        reference: p_ref, m, shape (3,). None keeps the estimate Cartesian until the
        first correction re-references it to that bearing's pursuer position.
        """
        self._start_time = float(time)
        self._ticks = 0
        self._snapshot = None
        cartesian = np.concatenate([np.asarray(position, float).reshape(3), np.asarray(velocity, float).reshape(3)])
        self._set_cartesian(cartesian, np.array(covariance, dtype=float).reshape(6, 6), reference)

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        """Remark 3 start (or initial_guess.position), referenced to the bearing's pursuer position."""
        self._initial_guess = initial_guess
        position, covariance = self._bearing_start(bearing, initial_guess)
        self.initialize(bearing.time, position, initial_guess.velocity, covariance, bearing.pursuer_position)

    def predict(self) -> None:
        """Time update over one period with p_ref fixed (class docstring)."""
        state, covariance = self._require_state()
        self._snapshot = None
        if self._reference is None:
            self._state, self._covariance = _linear_predict(self._a, self._q_discrete, state, covariance)
        else:
            self._state, self._covariance = _msc_propagate(state, covariance, self._a, self._q_discrete)
        self._ticks += 1

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        """Re-reference to bearing.pursuer_position, then the [beta, eps] update (class docstring)."""
        state, covariance = self._require_state()
        pursuer = np.asarray(bearing.pursuer_position, float).reshape(3).copy()
        lead = bearing.time - self.time
        try:
            direction = _measured_direction(bearing)
        except ValueError:  # a bearing that cannot be normalised: re-referenced first, as it always was
            self._set_cartesian(*self._cartesian(), pursuer)
            raise
        a_lead = self._a if lead == 0.0 else transition_matrices(lead)[0]
        referenced = self._reference is not None
        (state, covariance, restart, innovation_angle, predicted_range, relative_state, residual, innovation_covariance,
         updated, updated_covariance) = _msc_correct(state, covariance, referenced,
                                                     self._reference if referenced else pursuer, pursuer, lead, a_lead,
                                                     direction, self.restart_when_behind, self.bearing_variance,
                                                     self.pursuer_position_std)
        self._snapshot = None
        self._reference, self._state, self._covariance = pursuer, state, covariance
        if restart:
            self._restart_on(bearing, predicted_range, relative_state[3:].copy())
            return CorrectionReport(innovation_angle, False, reinitialized=True)
        self._state, self._covariance = updated, updated_covariance
        return CorrectionReport(innovation_angle, False, innovation=residual, innovation_covariance=innovation_covariance,
                                innovation_dof=2)

    def _set_cartesian(self, cartesian: np.ndarray, covariance: np.ndarray, reference: np.ndarray | None) -> None:
        """Store absolute [p_T, v_T] and its covariance as MSC about `reference` (or as-is when None)."""
        self._snapshot = None
        if reference is None:
            self._reference = None
            self._state = cartesian.copy()
            self._covariance = _symmetrize(covariance)
            return
        self._reference = np.asarray(reference, float).reshape(3).copy()
        self._state, self._covariance = _msc_from_absolute(cartesian, covariance, self._reference)

    def _cartesian(self) -> tuple[np.ndarray, np.ndarray]:
        """Absolute [p_ref + d, d_dot] and J_c P J_c^T."""
        state, covariance = self._require_state()
        if self._reference is None:
            return state.copy(), covariance.copy()
        return _msc_to_absolute(state, covariance, self._reference)


# --------------------------------------------------------------------------- seed 003 EKF


SEED003_PROCESS_NOISE = 2.0 * np.diag([1.0, math.radians(0.57) ** 2, math.radians(0.57) ** 2])
"""Q_r of seed 003 case 1: 2 diag(1, (0.57 deg)^2, (0.57 deg)^2) for (v, gamma, chi), units (m/s)^2/s, rad^2/s."""


@jit
def flight_path_velocity(speed: float, gamma: float, chi: float) -> np.ndarray:
    """NED velocity of seed 003 eq. (10): v [cos g cos chi, cos g sin chi, -sin g]; m/s, shape (3,).

    gamma positive climbing. The paper's frame has z up (z' = v sin g); in NED z is down,
    hence the minus sign on the third component.
    """
    cg, sg, cc, sc = math.cos(gamma), math.sin(gamma), math.cos(chi), math.sin(chi)
    return speed * np.array([cg * cc, cg * sc, -sg])


@jit
def flight_path_velocity_jacobian(speed: float, gamma: float, chi: float) -> np.ndarray:
    """d velocity / d(v, gamma, chi) of `flight_path_velocity`: F_rd1 of seed 003 in NED; shape (3, 3)."""
    cg, sg, cc, sc = math.cos(gamma), math.sin(gamma), math.cos(chi), math.sin(chi)
    return np.array(
        [
            [cg * cc, -speed * sg * cc, -speed * cg * sc],
            [cg * sc, -speed * sg * sc, speed * cg * cc],
            [-sg, -speed * cg, 0.0],
        ]
    )


@jit
def flight_path_step(state: np.ndarray, dt: float) -> np.ndarray:
    """Mean of seed 003 eq. (9)-(10) over dt (s) with no commands: exact integral; shape (6,).

    With v, gamma, chi constant (white-noise driven, zero mean) the position moves on a
    straight line: p(t + dt) = p + dt * velocity(v, gamma, chi).
    """
    stepped = state.astype(np.float64)  # a copy
    stepped[:3] += dt * flight_path_velocity(stepped[3], stepped[4], stepped[5])
    return stepped


@jit
def flight_path_step_jacobian(state: np.ndarray, dt: float) -> np.ndarray:
    """Exact Jacobian of `flight_path_step`: I + F_r dt, F_r = [[0, F_rd1], [0, 0]]; shape (6, 6).

    F_r is the state Jacobian of seed 003 section 2.2 without the v^c - v term (no
    commands), in NED. Because the discrete map is linear in dt, I + F_r dt is exact.
    """
    jacobian = np.eye(6)
    jacobian[:3, 3:] = dt * flight_path_velocity_jacobian(state[3], state[4], state[5])
    return jacobian


@jit
def _flight_path_predict(state: np.ndarray, covariance: np.ndarray, period: float,
                         discrete_process_noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`RangeAzElEKF.predict`'s arithmetic: X^- = `flight_path_step`(X, period), P^- = F P F^T + G Q G^T dt with
    F = `flight_path_step_jacobian` (symmetrised); X (6,), P (6, 6), G Q G^T dt (6, 6)."""
    f = flight_path_step_jacobian(state, period)
    return flight_path_step(state, period), _symmetrize(f @ covariance @ f.T + discrete_process_noise)


@jit
def _fold_flight_path(state: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep v >= 0 ((v, g, chi) ~ (-v, -g, chi + pi), Jacobian diag(-1, -1, 1)) and wrap the angles."""
    state = state.copy()
    if state[3] < 0.0:
        state[3], state[4], state[5] = -state[3], -state[4], state[5] + math.pi
        flip = np.diag(np.array([1.0, 1.0, 1.0, -1.0, -1.0, 1.0]))
        covariance = flip @ covariance @ flip
    state[4] = wrap_angle(state[4])
    state[5] = wrap_angle(state[5])
    return state, covariance


@jit
def _range_az_el_correct(state: np.ndarray, covariance: np.ndarray, lead: float, pursuer_position: np.ndarray,
                         direction: np.ndarray, measured_range: float, range_noise_std: float, bearing_variance: float,
                         pursuer_position_std: float):
    """`RangeAzElEKF.correct`'s arithmetic: the [r, beta, eps] update of seed 003 Table 1, H = H_rd [I3, lead F_rd1]
    (the erratum's azimuth row), R = diag(sigma_r^2, sigma^2/cos^2(eps), sigma^2) + sigma_p^2 H_rd H_rd^T.

    state: X (6,), covariance (6, 6); pursuer_position: p (3,), m; direction: the unit measured bearing (3,);
    measured_range: m. Returns (innovation angle, residual (3,), S (3, 3), X+ (6,), P+ (6, 6)), X+ folded."""
    relative = flight_path_step(state, lead)[:3] - pursuer_position
    innovation_angle = _innovation_angle(direction, relative)
    angles = azimuth_elevation(direction)
    measured = np.array([measured_range, angles[0], angles[1]])
    residual = measured - range_azimuth_elevation(relative)
    residual[1] = wrap_angle(residual[1])
    residual[2] = wrap_angle(residual[2])
    h_d = range_azimuth_elevation_jacobian(relative)
    h = np.hstack((h_d, lead * (h_d @ flight_path_velocity_jacobian(state[3], state[4], state[5]))))
    rho, r = _horizontal_and_range(relative)
    cos_eps = rho / r
    r_matrix = np.diag(np.array([range_noise_std ** 2, bearing_variance / cos_eps ** 2, bearing_variance]))
    if pursuer_position_std > 0.0:
        r_matrix = r_matrix + pursuer_position_std ** 2 * (h_d @ h_d.T)
    innovation_covariance = _innovation_covariance(covariance, h, r_matrix)
    updated, updated_covariance = _kalman_update(state, covariance, residual, h, r_matrix)
    updated, updated_covariance = _fold_flight_path(updated, updated_covariance)
    return innovation_angle, residual, innovation_covariance, updated, updated_covariance


@jit
def _flight_path_to_cartesian(state: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[p_T, v_T] (6,) with v_T = velocity(v, gamma, chi) and T P T^T (6, 6), T = blockdiag(I3, F_rd1), symmetrised."""
    transform = np.eye(6)
    transform[3:, 3:] = flight_path_velocity_jacobian(state[3], state[4], state[5])
    cartesian = np.concatenate((state[:3], flight_path_velocity(state[3], state[4], state[5])))
    return cartesian, _symmetrize(transform @ covariance @ transform.T)


class RangeAzElEKF(_TickedFilter):
    """Continuous-discrete EKF of seed 003 (eq. (9)-(10), Table 1) with range/azimuth/elevation.

    State X = [x, y, z, v, gamma, chi] (NED position, m; speed, m/s; flight-path angle,
    positive climbing; course), the target model of eq. (10) without commands, v, gamma,
    chi driven by white noise (G = [0; I3]). Each tick: X^- = `flight_path_step`
    (closed-form integral of the mean), P^- = F P F^T + G Q G^T dt with
    F = `flight_path_step_jacobian`. Correction with z = [r, beta, eps] of
    d = p_T - p (seed 003 eq. (2)-(3) in NED), H = `range_azimuth_elevation_jacobian`
    (with the erratum's azimuth row), R = diag(sigma_r^2, sigma^2/cos^2(eps), sigma^2)
    (+ sigma_p^2 J_d J_d^T for own-position noise).

    After each update a negative speed is folded back, (v, gamma, chi) ->
    (-v, -gamma, chi + pi) (the same velocity), with the covariance flipped accordingly;
    gamma and chi are wrapped to (-pi, pi].

    period: s. measurement_noise: Sigma of eq. (4), shape (3, 3) (sigma^2 = trace/3).
    range_noise_std: sigma_r, m. process_noise: Q_r, shape (3, 3), default
    `SEED003_PROCESS_NOISE` (case 1). pursuer_position_std: sigma_p, m.
    """

    def __init__(
        self,
        period: float,
        measurement_noise: np.ndarray,
        range_noise_std: float = 1.0,
        process_noise: np.ndarray | None = None,
        pursuer_position_std: float = 0.0,
    ) -> None:
        super().__init__(period, measurement_noise, pursuer_position_std)
        if range_noise_std <= 0.0:
            raise ValueError("range_noise_std must be positive")
        self.range_noise_std = float(range_noise_std)
        q = SEED003_PROCESS_NOISE if process_noise is None else process_noise
        self.process_noise = np.asarray(q, dtype=float).reshape(3, 3)
        self._q_discrete = np.zeros((6, 6))
        self._q_discrete[3:, 3:] = self.process_noise * self.period  # G Q G^T dt

    @property
    def flight_path_state(self) -> np.ndarray | None:
        """X = [x, y, z, v, gamma, chi], shape (6,), or None before initialisation."""
        return None if self._state is None else self._state.copy()

    def initialize(self, time: float, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray) -> None:
        """Start from a Cartesian estimate; covariance of [p_T, v_T], shape (6, 6).

        The position block is kept. The velocity is converted to (v, gamma, chi); below
        0.1 m/s it is taken as 0.1 m/s along +x (direction unknown). With
        velocity_std = sqrt(trace(P_vv)/3): speed std = velocity_std, angle std =
        min(pi, velocity_std / max(speed, 1 m/s)), independent of the position.
        """
        self._start_time = float(time)
        self._ticks = 0
        self._snapshot = None
        covariance = np.array(covariance, dtype=float).reshape(6, 6)
        velocity = np.asarray(velocity, float).reshape(3)
        speed = float(np.linalg.norm(velocity))
        velocity_std = math.sqrt(max(float(np.trace(covariance[3:, 3:])) / 3.0, 0.0))
        if speed < 0.1:
            speed, gamma, chi = 0.1, 0.0, 0.0
            angle_std = math.pi
        else:
            gamma = math.atan2(-velocity[2], math.hypot(velocity[0], velocity[1]))
            chi = math.atan2(velocity[1], velocity[0])
            angle_std = min(math.pi, velocity_std / max(speed, 1.0))
        self._state = np.concatenate([np.asarray(position, float).reshape(3), [speed, gamma, chi]])
        start = np.zeros((6, 6))
        start[:3, :3] = covariance[:3, :3]
        start[3:, 3:] = np.diag([velocity_std**2, angle_std**2, angle_std**2])
        self._covariance = _symmetrize(start)

    def initialize_on_bearing(self, bearing: BearingMeasurement, initial_guess: InitialGuess) -> None:
        """p_T(0) = p + r lambda~, r the measured range when bearing.range is set, else the guess.

        Along-bearing std: range_noise_std with a measured range, initial_guess.range_std
        otherwise; across: r times the bearing noise. initial_guess.position, when set,
        overrides (isotropic range_std, `explicit_start`).
        """
        self._initial_guess = initial_guess
        start = explicit_start(initial_guess)
        if start is not None:
            self.initialize(bearing.time, start[0], initial_guess.velocity, start[1])
            return
        direction = _measured_direction(bearing)
        if bearing.range is not None:
            start_range, along_std = max(float(bearing.range), MIN_RANGE), self.range_noise_std
        else:
            start_range, along_std = initial_guess.range, initial_guess.range_std
        cross_std = max(start_range * math.sqrt(self.bearing_variance), 1e-3)
        covariance = on_bearing_covariance(direction, along_std, cross_std, initial_guess.velocity_std)
        position = np.asarray(bearing.pursuer_position, float) + start_range * direction
        self.initialize(bearing.time, position, initial_guess.velocity, covariance)

    def predict(self) -> None:
        """Continuous-discrete time update over one period (seed 003 Table 1, discretised)."""
        state, covariance = self._require_state()
        self._snapshot = None
        self._state, self._covariance = _flight_path_predict(state, covariance, self.period, self._q_discrete)
        self._ticks += 1

    def correct(self, bearing: BearingMeasurement) -> CorrectionReport:
        """EKF update with z = [r, beta, eps] (seed 003 Table 1; H with the erratum row).

        Between ticks: d = p_T + lead velocity(v, gamma, chi) - p, so
        H = H_rd [I3, lead F_rd1]. Angle residuals wrapped to (-pi, pi].
        """
        if bearing.range is None:
            raise ValueError("RangeAzElEKF needs a range measurement (a [sensor] range_noise_std)")
        state, covariance = self._require_state()
        lead = bearing.time - self.time
        pursuer = np.asarray(bearing.pursuer_position, float)
        direction = _measured_direction(bearing)
        innovation_angle, residual, innovation_covariance, self._state, self._covariance = _range_az_el_correct(
            state, covariance, lead, pursuer, direction, float(bearing.range), self.range_noise_std, self.bearing_variance,
            self.pursuer_position_std)
        self._snapshot = None
        return CorrectionReport(innovation_angle, False, innovation=residual, innovation_covariance=innovation_covariance,
                                innovation_dof=3)

    _fold = staticmethod(_fold_flight_path)

    def _cartesian(self) -> tuple[np.ndarray, np.ndarray]:
        """[p_T, v_T] with v_T = velocity(v, gamma, chi) and T P T^T, T = blockdiag(I3, F_rd1)."""
        state, covariance = self._require_state()
        return _flight_path_to_cartesian(state, covariance)
