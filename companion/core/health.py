"""Filter-health monitor: is the estimate believable, judged without any truth?

The estimator is wrong without knowing it when its model no longer fits the target (a
turning target followed with a constant-velocity model) or when the bearings stop carrying
range information (the pursuer stops weaving: the range is then unobservable and the
estimate may settle anywhere along the line of sight). The monitor looks only at what the
companion has: the innovations and their covariances the estimator computes anyway, the
estimate and its covariance, the own state and the windowed Fisher information of the
bearings (companion.core.observability.WindowedObservability, section V, eq. (7)).

Indicators, evaluated at every estimator correction k (a bearing used):

- ``nis``: normalised innovation squared, eps_k = y_k^T S_k^+ y_k, with y_k the innovation
  and S_k its covariance as the estimator computed them (CorrectionReport; for the u-PLKF
  the pseudo-measurement P_lambda~ (p^-_T - p), rank 2, S_k^+ the Moore-Penrose inverse).
  For a consistent filter eps_k ~ chi^2(m_k), m_k the measurement's degrees of freedom
  (2 for a bearing, 3 with a range), and the sum over a window of n corrections
  ~ chi^2(sum m_k) (independent innovations): the windowed NIS test (Bar-Shalom, Li &
  Kirubarajan 2001, section 5.4). A filter following a manoeuvring target with a
  constant-velocity model is never exactly consistent while the target turns, yet its
  estimate may be good; so the test tolerates innovations up to `nis_scale` times larger in
  variance than the filter claims: raised when sum eps_k > nis_scale * F^-1(nis_probability;
  sum m_k), F the chi^2 distribution function (`nis_ratio` = sum / that bound > 1). 1.5 by
  default: with the IMM's speed-change model the innovations of a good estimate stay closer to
  consistent, and a factor of 2 missed range errors of 3-5 m behind a stop-and-go target
  (measured, docs/reproduction/manoeuvring-experiments.md, section 5.8).
- ``range_uncertain``: the range standard deviation along the estimated line of sight,
  sigma_r = sqrt(lambda^T P_pp lambda), lambda = (p^_T - p)/|p^_T - p|, above
  `max_relative_range_std` times the estimated range r^ = |p^_T - p|; or, once the estimate
  has converged (sigma_r at or below `max_range_std` at some correction since the last
  (re)start), sigma_r above `max_range_std` m again. The absolute bound is the filter's own
  admission that it no longer knows the range to the divergence line (RMS > 2 m):
  measured, a weakly observed target (the flight experiment's turn, section IX-B2, with
  HNG's N = 1 and Q = 1.5 I) drifts 2-4 m off with innovations that stay consistent (NIS
  ratio 0.2-0.35), so only the covariance shows it (sigma_r 1.8-2.6 m, against 0.1-0.9 m on
  good manoeuvring flights and 1.4-1.8 m on the flight experiment's straight legs). Every
  flight starts far above it while converging, hence the "once converged" rule.
- ``behind_sensor``: cheirality; the estimate lies behind the sensor,
  lambda~^T (p^_T - p) <= 0 with lambda~ the measured bearing, or the estimator had to
  restart on the bearing because its prediction was behind it (CorrectionReport.reinitialized).
- ``range_implausible``: r^ outside [min_range, max_range] (m).
- ``link_contested``: the target link's fix validator holds the track because two sources speak in
  the target's epoch (companion.core.fix_validator, "Two sources"): no fix feeds the estimator until
  one is confirmed, so the estimate only coasts. Told by the harness (`link_contested`), counted at
  once and kept raised while the hold lasts; the flight is not clean even when the estimate stayed good.
- ``range_unobservable``: the pursuer has been slower than `slow_speed` for
  `unobservable_time` s (and, when `min_fim_eigenvalue` is set, the windowed FIM's smallest
  eigenvalue, 1/m^2, eq. (7), stayed below it meanwhile). HNG's weave (eq. (14)) scales with
  the pursuer's own speed: when the pursuer stops, the weave dies and the bearings carry no
  range information about a moving target. The windowed FIM alone does not show this
  failure: it treats the target as static, and a target circling a stopped pursuer sweeps
  the bearings around and keeps every eigenvalue large (measured at 5 Hz bearings: smallest
  eigenvalue 200-2800 1/m^2 in the circling failures, about 300 in good constant-velocity
  flights; at 50 Hz about 3000 in both), so by default (None) the speed decides alone.

- ``speed_change`` (off unless `speed_change_probability` is set): the estimator's speed-change models
  (the IMM's, companion.core.imm) hold at least `speed_change_probability` of its model probability. The
  target is changing speed, and until the pursuer's own motion separates the two, a target acceleration
  along the line of sight looks to the bearings like a range error: measured, the range estimate of the
  speed-change phases is where the monitor is otherwise silent while 2 m or more off (docs/reproduction/manoeuvring-experiments.md,
  section 5.10). It counts after `speed_change_time` s and, alone, clears `speed_change_clear` s after it
  was last raised (the other reasons' clear_after would keep a braked and hovering target suspect for long).

Hysteresis: a reason counts once its condition has held at every correction for
`flag_after` s (`unobservable_time` for range_unobservable, at once for behind_sensor); the state becomes SUSPECT
as soon as one reason counts, and goes back to OK only after no condition at all has been
raised for `clear_after` s (for speed_change, `speed_change_clear` s since it was last raised). The monitor itself only observes. What to do about its verdict
is the HealthActionPolicy's (below), which the pipeline (companion.core.pipeline) applies
when `HealthActionConfig.act` is on: while SUSPECT, inflate the estimator's process noise
(its `process_noise_boost`, relaxing back to 1 once OK), restart the estimator on the
bearing (remark 3) when the reasons say the range is wrong (rate-limited), and fly the
range excitation (companion.core.guidance.RangeExcitation) at full level.

numpy, and scipy.special's inverse incomplete gamma function for the chi^2 quantile (`chi2_quantile`).
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import gammaincinv

from companion.core._jit import jit, symmetric_eigen
from companion.core.geometry import relative_range_std_kernel
from companion.core.messages import fast_frozen


class HealthState(str, enum.Enum):
    """OK: nothing suspicious. SUSPECT: at least one indicator says the estimate may be wrong."""

    OK = "ok"
    SUSPECT = "suspect"


#: Every reason the monitor can give, in the order it reports them.
REASONS = ("nis", "range_uncertain", "behind_sensor", "range_implausible", "range_unobservable", "link_contested",
           "speed_change")



def normalized_innovation_squared(innovation: np.ndarray, covariance: np.ndarray) -> float:
    """eps = y^T S^+ y (dimensionless): y the innovation (m,), S its covariance (m, m), S^+ its
    Moore-Penrose inverse (S may be singular: the u-PLKF's bearing pseudo-measurement is rank 2 in 3-D).

    S^+ is numpy.linalg.pinv(S, rcond=1e-10, hermitian=True), computed by the kernel
    _normalized_innovation_squared in numpy's own order (compiled when numba is present). ValueError
    unless y is (m,) and S (m, m); m = 0 gives 0."""
    y, s = _innovation_arrays(innovation, covariance)
    if y.shape[0] == 0:
        return 0.0
    return float(_normalized_innovation_squared(y, s))


def _innovation_arrays(innovation: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """y (m,) and S (m, m) as float64 C-contiguous arrays; ValueError unless their shapes match."""
    y = np.ascontiguousarray(innovation, dtype=float)
    s = np.ascontiguousarray(covariance, dtype=float)
    if y.ndim != 1 or s.shape != (y.shape[0], y.shape[0]):
        raise ValueError(f"need an innovation (m,) and its covariance (m, m), got {y.shape} and {s.shape}")
    return y, s


@jit
def _normalized_innovation_squared(innovation: np.ndarray, covariance: np.ndarray) -> float:
    """y^T S^+ y with S^+ = numpy.linalg.pinv(S, rcond=1e-10, hermitian=True), numpy's operations in numpy's
    order (numpy/linalg/_linalg.py: svd(hermitian=True), then pinv), so the same bits compiled and not:
    S = U diag(w) U^T (eigh); singular values |w| in descending order (a stable argsort of |w|, reversed),
    their signs moved into V^T = (U sign(w))^T; 1/s for s > 1e-10 max(s), 0 otherwise; S^+ = V diag(1/s) U^T
    as (U sign(w)) @ ((1/s)[:, None] * U^T); then (y @ S^+) @ y. innovation: y (m,), covariance: S (m, m),
    m >= 1, float64 C-contiguous."""
    values, vectors = symmetric_eigen(covariance)
    signs = np.copysign(1.0, values)
    singular = np.abs(values)
    order = np.argsort(singular)[::-1]
    singular = singular[order]
    signs = signs[order]
    vectors = vectors[:, order]
    cutoff = 1e-10 * np.max(singular)
    inverse = np.zeros(singular.shape[0])
    for k in range(singular.shape[0]):
        if singular[k] > cutoff:
            inverse[k] = 1.0 / singular[k]
    pseudo_inverse = (vectors * signs) @ (inverse[:, None] * vectors.T)
    return innovation @ pseudo_inverse @ innovation


def _vector(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=float)


@jit
def _evidence(bearing_direction: np.ndarray, estimate_position: np.ndarray, pursuer_position: np.ndarray,
              position_covariance: np.ndarray, pursuer_velocity: np.ndarray) -> tuple[float, float, float, float]:
    """HealthMonitor.update's geometry in one call: (r^ = |p^_T - p|, sigma_r / r^ (geometry.relative_range_std;
    NaN unless r^ > 1e-9), lambda~^T (p^_T - p) (the cheirality test), |v|). Vectors (3,) and P_pp (3, 3), float64
    C-contiguous; norms as np.linalg.norm computes them (sqrt of the dot product)."""
    relative = estimate_position - pursuer_position
    range_estimate = math.sqrt(relative @ relative)
    relative_std = math.nan
    if range_estimate > 1e-9:
        relative_std = relative_range_std_kernel(relative, position_covariance)
    return (range_estimate, relative_std, bearing_direction @ relative,
            math.sqrt(pursuer_velocity @ pursuer_velocity))


_NO_INNOVATION = (np.zeros(1), np.zeros((1, 1)))  # the arguments of a correction without innovation (never read)


@jit
def _bearing_evidence(innovation: np.ndarray, innovation_covariance: np.ndarray, with_innovation: bool,
                      bearing_direction: np.ndarray, estimate_position: np.ndarray, pursuer_position: np.ndarray,
                      estimate_covariance: np.ndarray, pursuer_velocity: np.ndarray
                      ) -> tuple[float, float, float, float, float]:
    """HealthMonitor.update's numbers in one call, as floats: (eps = y^T S^+ y (`_normalized_innovation_squared`;
    NaN unless with_innovation), then `_evidence` on the position block P_pp of estimate_covariance (6, 6)).
    Arrays float64 C-contiguous: y (m,), S (m, m), m >= 1 (read only with_innovation), vectors (3,)."""
    nis = math.nan
    if with_innovation:
        nis = float(_normalized_innovation_squared(innovation, innovation_covariance))
    range_estimate, relative_std, cosine, speed = _evidence(
        bearing_direction, estimate_position, pursuer_position, np.ascontiguousarray(estimate_covariance[:3, :3]),
        pursuer_velocity)
    return nis, float(range_estimate), float(relative_std), float(cosine), float(speed)


@dataclass(frozen=True)
class HealthConfig:
    """Thresholds of the monitor (module docstring). Lengths m, times s, speeds m/s.

    nis_window: s of corrections summed in the windowed NIS. nis_probability: the chi^2
    quantile the sum is compared with (one-sided, upper). min_nis_samples: corrections
    needed in the window before the test is made. nis_scale: tolerated ratio of the actual
    to the claimed innovation variance (>= 1). max_relative_range_std: sigma_r / r^
    limit. max_range_std: m, sigma_r limit once converged (None: not used). min_range,
    max_range: plausible range, m. min_fim_eigenvalue: 1/m^2, smallest
    eigenvalue of the windowed FIM (eq. (7)) below which the range counts as poorly observed
    (None: not used, the pursuer's speed decides alone).
    slow_speed: m/s, pursuer speed below which a poorly observed range is suspicious.
    unobservable_time: s the range must stay poorly observed (and the pursuer slow) before
    it counts. flag_after: s a condition must hold before it counts. clear_after: s without
    any condition before SUSPECT goes back to OK. speed_change_probability: the share of model
    probability on the estimator's speed-change models that raises speed_change (None: not used);
    speed_change_time: s it must hold before it counts; speed_change_clear: s after speed_change was
    last raised before it alone no longer keeps the estimate SUSPECT.
    """

    nis_window: float = 5.0
    nis_probability: float = 0.999
    nis_scale: float = 1.5
    min_nis_samples: int = 10
    max_relative_range_std: float = 1.0
    max_range_std: float | None = 2.0
    min_range: float = 1.0
    max_range: float = 2000.0
    min_fim_eigenvalue: float | None = None
    slow_speed: float = 1.0
    unobservable_time: float = 5.0
    flag_after: float = 3.0
    clear_after: float = 10.0
    speed_change_probability: float | None = None
    speed_change_time: float = 0.5
    speed_change_clear: float = 3.0

    def __post_init__(self) -> None:
        if self.nis_window <= 0.0 or not (0.0 < self.nis_probability < 1.0) or self.min_nis_samples < 1:
            raise ValueError("need nis_window > 0, 0 < nis_probability < 1 and min_nis_samples >= 1")
        if self.nis_scale < 1.0:
            raise ValueError("need nis_scale >= 1")
        if not (0.0 <= self.min_range < self.max_range) or self.max_relative_range_std <= 0.0:
            raise ValueError("need 0 <= min_range < max_range and max_relative_range_std > 0")
        if self.max_range_std is not None and not self.max_range_std > 0.0:
            raise ValueError("need max_range_std > 0 (or None)")
        if min(self.flag_after, self.clear_after, self.unobservable_time, self.speed_change_time,
               self.speed_change_clear) < 0.0:
            raise ValueError("flag_after, clear_after, unobservable_time, speed_change_time and speed_change_clear "
                             "must be >= 0")
        if self.speed_change_probability is not None and not 0.0 < self.speed_change_probability <= 1.0:
            raise ValueError(f"speed_change_probability must be in (0, 1] (or None), got {self.speed_change_probability!r}")


@dataclass(frozen=True)
class HealthReport:
    """The monitor's verdict after a correction.

    time: s. state: OK or SUSPECT (with hysteresis). reasons: the reasons that count now
    (REASONS order; empty when OK, may be empty while SUSPECT waits for clear_after).
    raised: the conditions raised at this correction (before hysteresis). nis: eps_k of this
    correction (NaN without innovation). nis_ratio: windowed NIS sum divided by its chi^2
    bound (> 1 raises "nis"; NaN while the window is short). range_estimate: r^, m.
    relative_range_std: sigma_r / r^.
    """

    time: float
    state: HealthState
    reasons: tuple[str, ...] = ()
    raised: tuple[str, ...] = ()
    nis: float = math.nan
    nis_ratio: float = math.nan
    range_estimate: float = math.nan
    relative_range_std: float = math.nan

    def as_dict(self) -> dict:
        """Plain types for logs and payloads: state, reasons, nis_ratio, relative_range_std."""
        return {"state": self.state.value, "reasons": list(self.reasons), "nis_ratio": self.nis_ratio,
                "relative_range_std": self.relative_range_std}


def _health_report(time, state, reasons, raised, nis, nis_ratio, range_estimate, relative_range_std) -> HealthReport:
    """HealthReport(...), every field given in order, without the frozen dataclass's object.__setattr__ per field
    (one is built at every correction; by keyword, cheaper than pairing names and values): the same object, field
    for field."""
    return fast_frozen(HealthReport, time=time, state=state, reasons=reasons, raised=raised, nis=nis,
                       nis_ratio=nis_ratio, range_estimate=range_estimate, relative_range_std=relative_range_std)


_NIS_BOUNDS: dict[tuple[float, float, int], float] = {}
"""nis_scale x F^-1(nis_probability; dof) by (nis_scale, nis_probability, dof), shared by every monitor of the
process: scipy's chi^2 quantile costs about 80 us, and a study flies thousands of monitors with the same
configuration (a deterministic function: the cached value is the value computed again)."""

_NIS_BOUNDS_LIMIT = 100_000  # entries kept before the cache starts over (a bound on memory, never reached in flight)


def _nis_bound(scale: float, probability: float, dof: int) -> float:
    """scale x the upper chi^2 quantile `probability` at `dof` degrees of freedom (HealthMonitor.nis_bound), cached."""
    key = (scale, probability, dof)
    bound = _NIS_BOUNDS.get(key)
    if bound is None:
        if len(_NIS_BOUNDS) >= _NIS_BOUNDS_LIMIT:
            _NIS_BOUNDS.clear()
        bound = _NIS_BOUNDS[key] = scale * chi2_quantile(probability, dof)
    return bound


def chi2_quantile(probability: float, dof: float) -> float:
    """The chi^2 distribution's quantile at `probability` for `dof` degrees of freedom: 2 P^-1(dof / 2, probability),
    P^-1 the inverse of the regularised lower incomplete gamma function (scipy.special.gammaincinv). It is the
    formula scipy.stats.chi2.ppf evaluates, without importing scipy.stats (about 0.4 s at every start)."""
    return float(2.0 * gammaincinv(dof / 2.0, probability))


@dataclass
class _Window:
    """Time-windowed sums of (nis, dof)."""

    length: float
    samples: deque = field(default_factory=deque)
    nis_sum: float = 0.0
    dof_sum: int = 0

    def add(self, time: float, nis: float, dof: int) -> None:
        self.samples.append((time, nis, dof))
        self.nis_sum += nis
        self.dof_sum += dof
        while self.samples and self.samples[0][0] < time - self.length:
            _, old_nis, old_dof = self.samples.popleft()
            self.nis_sum -= old_nis
            self.dof_sum -= old_dof

    def clear(self) -> None:
        self.samples.clear()
        self.nis_sum, self.dof_sum = 0.0, 0


class HealthMonitor:
    """Feeds on corrections, says OK or SUSPECT (module docstring). Observes only.

    update(...) once per estimator correction; `report` is the latest verdict;
    `transitions` lists (time, state, reasons) at each change of state; `episode_reasons`
    every reason that counted during the current SUSPECT episode (empty while OK).
    """

    def __init__(self, config: HealthConfig | None = None) -> None:
        self.config = config if config is not None else HealthConfig()
        self._window = _Window(self.config.nis_window)
        self._range_converged = False
        self._bounds: dict[int, float] = {}
        self._since: dict[str, float] = {}
        self._last_raised: dict[str, float] = {}  # reason -> the last time its condition was raised
        self._slow_unobservable_since: float | None = None
        self.report = HealthReport(0.0, HealthState.OK)
        self.transitions: list[tuple[float, HealthState, tuple[str, ...]]] = []
        self._episode: set[str] = set()
        self._link_contested = False

    def link_contested(self, time: float, contested: bool) -> HealthReport:
        """The link's fix validator holds the track (contested True) or no longer does, at `time` s. While it
        holds, no correction comes to update the verdict, so the monitor says SUSPECT (reason link_contested) at
        once; once the hold ends, OK comes back clear_after s later at the earliest, as for any reason."""
        self._link_contested = bool(contested)
        self._last_raised["link_contested"] = time
        if contested:
            self._since.setdefault("link_contested", time)
            reasons = self._hold(time, ["link_contested"])
            report = self.report
            if report.state is not HealthState.SUSPECT:
                self.transitions.append((time, HealthState.SUSPECT, reasons))
                self._episode.clear()
            self._episode.update(reasons)
            self.report = _health_report(time, HealthState.SUSPECT, reasons, ("link_contested",), report.nis,
                                         report.nis_ratio, report.range_estimate, report.relative_range_std)
        return self.report

    @property
    def state(self) -> HealthState:
        return self.report.state

    @property
    def episode_reasons(self) -> tuple[str, ...]:
        """Reasons that counted at any time in the current SUSPECT episode, REASONS order; () while OK."""
        return tuple(reason for reason in REASONS if reason in self._episode)

    def nis_bound(self, dof: int) -> float:
        """nis_scale x the upper chi^2 quantile (config.nis_probability) for `dof` degrees of freedom, cached."""
        bound = self._bounds.get(dof)
        if bound is None:
            bound = self._bounds[dof] = _nis_bound(self.config.nis_scale, self.config.nis_probability, dof)
        return bound

    def restart(self) -> None:
        """Forget the innovation window (the estimator was re-initialised: old innovations no longer apply)
        and that the range had converged (a restarted filter converges again first)."""
        self._window.clear()
        self._range_converged = False

    def update(
        self,
        time: float,
        bearing_direction: np.ndarray,
        pursuer_position: np.ndarray,
        pursuer_velocity: np.ndarray,
        estimate_position: np.ndarray,
        estimate_covariance: np.ndarray,
        *,
        innovation: np.ndarray | None = None,
        innovation_covariance: np.ndarray | None = None,
        innovation_dof: int = 0,
        reinitialized: bool = False,
        fim_min_eigenvalue: float | None = None,
        speed_change_probability: float | None = None,
    ) -> HealthReport:
        """One correction's evidence in, the verdict out.

        time: s. bearing_direction: the measured unit bearing, (3,). pursuer_position m and
        pursuer_velocity m/s, (3,). estimate_position: p^_T after the correction, m, (3,);
        estimate_covariance: of [p_T, v_T] (6, 6) (only the position block is read).
        innovation (m,) / innovation_covariance (m, m) / innovation_dof: as the estimator
        computed them, None when it has none. reinitialized: the estimator restarted on this
        bearing. fim_min_eigenvalue: smallest eigenvalue of the windowed FIM, 1/m^2, or None.
        speed_change_probability: the estimator's model probability on its speed-change models after this
        correction, or None when it has none.
        """
        config = self.config
        raised: list[str] = []
        y, s = _NO_INNOVATION
        with_innovation = False
        if reinitialized:
            self.restart()
        elif innovation is not None and innovation_covariance is not None and innovation_dof > 0:
            y, s = _innovation_arrays(innovation, innovation_covariance)
            with_innovation = True
        # eps_k (normalized_innovation_squared's: 0 for an empty innovation) and the geometry, in one kernel call
        contiguous = np.ascontiguousarray  # _vector's conversion, without a call of _vector per argument
        nis, range_estimate, relative_std, cosine, speed = _bearing_evidence(
            y, s, with_innovation and y.shape[0] > 0, contiguous(bearing_direction, float),
            contiguous(estimate_position, float), contiguous(pursuer_position, float),
            contiguous(estimate_covariance, float), contiguous(pursuer_velocity, float))
        if with_innovation:
            if y.shape[0] == 0:
                nis = 0.0
            self._window.add(time, nis, int(innovation_dof))
        nis_ratio = math.nan
        if len(self._window.samples) >= config.min_nis_samples:
            nis_ratio = self._window.nis_sum / self.nis_bound(self._window.dof_sum)
            if nis_ratio > 1.0:
                raised.append("nis")

        if range_estimate > 1e-9:
            range_std = relative_std * range_estimate
            if config.max_range_std is not None and range_std <= config.max_range_std:
                self._range_converged = True
            if relative_std > config.max_relative_range_std or (
                    self._range_converged and config.max_range_std is not None and range_std > config.max_range_std):
                raised.append("range_uncertain")
        if reinitialized or cosine <= 0.0:
            raised.append("behind_sensor")
        if not (config.min_range <= range_estimate <= config.max_range):
            raised.append("range_implausible")

        poorly_observed = config.min_fim_eigenvalue is None or (
            fim_min_eigenvalue is not None and fim_min_eigenvalue < config.min_fim_eigenvalue)
        if poorly_observed and speed < config.slow_speed:
            if self._slow_unobservable_since is None:
                self._slow_unobservable_since = time
            if time - self._slow_unobservable_since >= config.unobservable_time:
                raised.append("range_unobservable")
        else:
            self._slow_unobservable_since = None

        if self._link_contested:
            raised.append("link_contested")
        threshold = config.speed_change_probability
        if threshold is not None and speed_change_probability is not None and speed_change_probability >= threshold:
            raised.append("speed_change")
        reasons = self._hold(time, raised)
        for reason in raised:
            self._last_raised[reason] = time
        state = self.report.state
        if reasons:
            state = HealthState.SUSPECT
        elif state is HealthState.SUSPECT and all(time - last >= self._clear_time(reason)
                                                  for reason, last in self._last_raised.items()):
            state = HealthState.OK
        if state is not self.report.state:
            self.transitions.append((time, state, reasons))
            self._episode.clear()
        if state is HealthState.SUSPECT:
            self._episode.update(reasons)
        self.report = _health_report(time, state, reasons, tuple(raised), nis, nis_ratio, range_estimate, relative_std)
        return self.report

    def _clear_time(self, reason: str) -> float:
        """s after `reason` was last raised before it no longer keeps the state SUSPECT."""
        return self.config.speed_change_clear if reason == "speed_change" else self.config.clear_after

    def _hold(self, time: float, raised: list[str]) -> tuple[str, ...]:
        """Reasons whose condition has held for flag_after s (behind_sensor counts at once)."""
        if not raised and not self._since:
            return ()  # nothing raised now or before: what the loops below give, without them
        for reason in REASONS:
            if reason in raised:
                self._since.setdefault(reason, time)
            else:
                self._since.pop(reason, None)
        held = []
        for reason in REASONS:
            if reason not in self._since:
                continue
            # range_unobservable already waited unobservable_time; cheirality needs no persistence.
            wait = (0.0 if reason in ("behind_sensor", "range_unobservable")
                    else self.config.speed_change_time if reason == "speed_change" else self.config.flag_after)
            # link_contested counts at once, also at a correction whose bearing is stamped before the hold began
            if reason == "link_contested" or time - self._since[reason] >= wait:
                held.append(reason)
        return tuple(held)


# --------------------------------------------------------------------------- acting on the verdict


class HealthAction(str, enum.Enum):
    """What the pipeline does about the monitor's verdict (kept apart from the dropout TrackMode, whose
    modes say whether bearings arrive; this says whether the estimate built from them is believed).

    off: the monitor only reports (`HealthActionConfig.act` false). nominal: acting is on and the
    estimate is judged OK (process_noise_boost relaxing back to 1). recovering: the estimate is
    judged suspect and the actions are on (Q inflated, guidance exciting the range, re-initialisation
    on the bearing when the reasons say the range is wrong).
    """

    OFF = "off"
    NOMINAL = "nominal"
    RECOVERING = "recovering"


#: Reasons that say the range itself is wrong or unknowable, so restarting along the bearing helps.
RANGE_WRONG_REASONS = ("behind_sensor", "range_implausible")


@dataclass(frozen=True)
class HealthActionConfig:
    """What to do while the monitor says SUSPECT. Times s, ratios dimensionless.

    act: False keeps the monitor a pure observer (the flight is the reporting-only pipeline,
    bit for bit). process_noise_boost: factor (>= 1) on the estimator's discrete process noise
    while suspect (the estimator's `process_noise_boost`; estimators without it are left
    alone); once OK again it relaxes back to 1 as 1 + (b - 1) exp(-dt / boost_relax_time).
    reinitialize_reasons: reasons (REASONS) that restart the estimator on the bearing, at the
    current range estimate (clamped to the plausible range) with an along-bearing std of
    reinitialize_relative_std x that range; not more often than every reinitialize_interval s.
    excite: full range excitation while suspect, and a lateral excitation that never lets the
    pursuer stop while sigma_r / r^ is above excitation_high (ramping in from excitation_low),
    for lateral laws that take one (guidance.RangeExcitation). boost_follows_evidence: hold the full
    boost only while some condition is raised at the correction (HealthReport.raised), relaxing
    already during the SUSPECT tail the monitor's clear_after hysteresis keeps (False: full boost for
    the whole SUSPECT episode). boost_reasons: the raised conditions that count as that evidence: a
    model that no longer fits (innovations too large, a prediction behind the sensor, an implausible
    range). Not range_uncertain or range_unobservable: there the bearings carry too little range
    information, a larger Q only spreads the estimate further, and the excitation is the remedy.
    Defaults chosen on tuning seeds (docs/reproduction/manoeuvring-experiments.md, sections 5.5 and 5.6).
    """

    act: bool = False
    process_noise_boost: float = 30.0
    boost_relax_time: float = 5.0
    reinitialize_reasons: tuple[str, ...] = RANGE_WRONG_REASONS
    reinitialize_interval: float = 20.0
    reinitialize_relative_std: float = 0.5
    excite: bool = True
    excitation_low: float = 0.25
    excitation_high: float = 0.5
    boost_follows_evidence: bool = True
    boost_reasons: tuple[str, ...] = ("nis", "behind_sensor", "range_implausible")

    def __post_init__(self) -> None:
        if set(self.boost_reasons) - set(REASONS):
            raise ValueError(f"unknown boost_reasons {sorted(set(self.boost_reasons) - set(REASONS))}; known: {', '.join(REASONS)}")
        if self.process_noise_boost < 1.0 or self.boost_relax_time <= 0.0:
            raise ValueError("need process_noise_boost >= 1 and boost_relax_time > 0")
        unknown = set(self.reinitialize_reasons) - set(REASONS)
        if unknown:
            raise ValueError(f"unknown reinitialize_reasons {sorted(unknown)}; known: {', '.join(REASONS)}")
        if self.reinitialize_interval < 0.0 or self.reinitialize_relative_std <= 0.0:
            raise ValueError("need reinitialize_interval >= 0 and reinitialize_relative_std > 0")
        if not (0.0 <= self.excitation_low < self.excitation_high):
            raise ValueError("need 0 <= excitation_low < excitation_high")


@dataclass(frozen=True)
class ActionDecision:
    """The actions for one verdict. action: HealthAction. process_noise_boost: factor on Q to set now
    (1 means none). reinitialize: restart the estimator on this bearing now. excite: excitation at full level."""

    action: HealthAction
    process_noise_boost: float = 1.0
    reinitialize: bool = False
    excite: bool = False


_REPORT_ONLY = ActionDecision(HealthAction.OFF)
"""The decision of a policy that only reports (act off), at every verdict."""


class HealthActionPolicy:
    """Turns each HealthReport into actions (HealthActionConfig); pure bookkeeping, no estimator access.

    decide(report) once per monitor verdict, in time order. `reinitialize_times` lists the times
    (s) it asked for a restart; `episodes` / `recoveries` count SUSPECT episodes acted on and
    those that ended OK again.
    """

    def __init__(self, config: HealthActionConfig | None = None) -> None:
        self.config = config if config is not None else HealthActionConfig()
        self.boost = 1.0
        self._time: float | None = None
        self._suspect = False
        self.reinitialize_times: list[float] = []
        self.episodes = 0
        self.recoveries = 0

    def decide(self, report: HealthReport, estimator_restarted: bool = False) -> ActionDecision:
        """Actions for `report` (the monitor's latest verdict). estimator_restarted: the estimator
        already restarted on this bearing by itself (no second restart)."""
        config = self.config
        if not config.act:
            return _REPORT_ONLY  # (immutable: one shared decision)
        suspect = report.state is HealthState.SUSPECT
        if suspect and not self._suspect:
            self.episodes += 1
        elif self._suspect and not suspect:
            self.recoveries += 1
        self._suspect = suspect
        elapsed = 0.0 if self._time is None else max(report.time - self._time, 0.0)
        self._time = report.time
        evidence = any(reason in config.boost_reasons for reason in report.raised)
        if suspect and (evidence or not config.boost_follows_evidence):
            self.boost = config.process_noise_boost
        else:
            self.boost = 1.0 + (self.boost - 1.0) * math.exp(-elapsed / config.boost_relax_time)
            if self.boost - 1.0 < 1e-3:
                self.boost = 1.0
        reinitialize = False
        if suspect and not estimator_restarted and any(r in config.reinitialize_reasons for r in report.reasons):
            last = self.reinitialize_times[-1] if self.reinitialize_times else None
            if last is None or report.time - last >= config.reinitialize_interval:
                reinitialize = True
                self.reinitialize_times.append(report.time)
        action = HealthAction.RECOVERING if suspect else HealthAction.NOMINAL
        return ActionDecision(action, self.boost, reinitialize, suspect and config.excite)
