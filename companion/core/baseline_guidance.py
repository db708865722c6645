"""Baseline guidance laws that section VIII-C compares with HNG.

Every law here satisfies the `LateralGuidance` protocol of `companion.core.guidance`:
acceleration(engaged_time s, velocity m/s (3,), los unit (3,), range_estimate m,
relative_velocity m/s (3,) = v^_T - v) -> m/s^2, shape (3,). Frames: local NED
(z down), SI units.

* `ProportionalNavigationGuidance` - 3-D PNG, section VIII-C1 (Fig. 11(a)).
* `PDFollowingController` - the PD controller of section VIII-C1 (Fig. 11(c)); a
  complete command (`includes_range_control = True`).
* `RetroProportionalNavigationGuidance` - retro-PNG of refs. [14], [16],
  section VIII-C2 (Fig. 12(a)), applied per plane.
* `Seed003BacksteppingGuidance` - seed 003's speed / flight-path / course law, eq. (5)-(8),
  erratum fixed, converted to an acceleration through its first-order autopilot (eq. (4)).
* `ZEMObservabilityGuidance` - the linear observability-enhancement law of
  ref. [43], section VIII-C2 (Fig. 12(b)), applied per plane.

PPG is `companion.core.guidance.PurePursuitGuidance`; planar weaving guidance is
`HelicalNavigationGuidance` with c_Y = 0 (section VI-A, property 3), so neither is
repeated here.

The per-plane laws (refs. [14], [16], [43] are 2-D) use `plane_los_rates`: the
horizontal plane carries the azimuth beta of the relative position, the vertical
plane through the line of sight carries its elevation eps. With
lambda = (cos eps cos beta, cos eps sin beta, -sin eps) the three unit vectors
lambda, e_beta = d lambda/d beta / cos eps, e_eps = d lambda/d eps are orthonormal
and lambda_dot = P_lambda dv / r = cos(eps) beta_dot e_beta + eps_dot e_eps, so the
per-plane commands are always perpendicular to the line of sight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from companion.core.geometry import cross, orthogonal_projection, unit

# Range floor (m) below which a range estimate is not trusted as a divisor (as in HNG).
_MIN_RANGE = 1e-3


def _require_relative_velocity(relative_velocity: np.ndarray | None, law: str) -> np.ndarray:
    if relative_velocity is None:
        raise ValueError(f"{law} needs the estimated relative velocity v^_T - v")
    return np.asarray(relative_velocity, dtype=float)


class PlaneLosRates(NamedTuple):
    """Per-plane line-of-sight angles and rates of `plane_los_rates`.

    beta: azimuth of the relative position in the horizontal plane, rad, atan2(d_y, d_x).
    beta_dot: rad/s. eps: elevation, positive up, rad, atan2(-d_z, rho) with
    rho = hypot(d_x, d_y). eps_dot: rad/s. e_beta: [-sin beta, cos beta, 0], unit,
    horizontal, perpendicular to the line of sight. e_eps: unit vector perpendicular to
    the line of sight in its vertical plane, pointing towards increasing elevation.
    """

    beta: float
    beta_dot: float
    eps: float
    eps_dot: float
    e_beta: np.ndarray
    e_eps: np.ndarray


def plane_los_rates(relative_position: np.ndarray, relative_velocity: np.ndarray,
                    vertical_tolerance: float = 1e-9) -> PlaneLosRates:
    """Azimuth/elevation of the line of sight and their rates (horizontal and vertical planes).

    relative_position: dp = p_T - p, m, shape (3,), NED, nonzero. relative_velocity:
    dv = v_T - v, m/s, shape (3,). With r = |dp| and rho = hypot(d_x, d_y):
    beta_dot = e_beta . dv / rho (the 2-D LOS rate in the horizontal plane) and
    eps_dot = e_eps . dv / r (the 2-D LOS rate in the vertical plane containing the
    line of sight); these are the time derivatives of atan2(d_y, d_x) and
    atan2(-d_z, rho) along dp' = dv.

    Straight above/below the pursuer (rho <= vertical_tolerance * r) the azimuth is
    undefined: beta = atan2(d_y, d_x) (0 for d_x = d_y = 0) only fixes the frame and
    beta_dot is set to 0, so the horizontal-plane term vanishes. Note that beta_dot
    grows like 1/rho as the line of sight approaches the vertical, a property of the
    per-plane decomposition itself.
    """
    dp = np.asarray(relative_position, dtype=float)
    dv = np.asarray(relative_velocity, dtype=float)
    distance = float(np.linalg.norm(dp))
    if not math.isfinite(distance) or distance == 0.0:
        raise ValueError(f"relative position {dp!r} has no direction")
    rho = math.hypot(float(dp[0]), float(dp[1]))
    beta = math.atan2(float(dp[1]), float(dp[0]))
    eps = math.atan2(-float(dp[2]), rho)
    sin_b, cos_b = math.sin(beta), math.cos(beta)
    sin_e = -float(dp[2]) / distance
    cos_e = rho / distance
    e_beta = np.array([-sin_b, cos_b, 0.0])
    e_eps = np.array([-sin_e * cos_b, -sin_e * sin_b, -cos_e])
    beta_dot = float(e_beta @ dv) / rho if rho > vertical_tolerance * distance else 0.0
    eps_dot = float(e_eps @ dv) / distance
    return PlaneLosRates(beta, beta_dot, eps, eps_dot, e_beta, e_eps)


def _relative_position(los: np.ndarray, range_estimate: float) -> np.ndarray:
    """dp^ = r^ lambda (m, (3,)), with r^ floored at _MIN_RANGE."""
    return max(float(range_estimate), _MIN_RANGE) * unit(np.asarray(los, dtype=float))


@dataclass(frozen=True)
class ProportionalNavigationGuidance:
    """3-D pure PNG of section VIII-C1 (Fig. 11(a)), after ref. [34].

    a = N Omega x v with the LOS rate vector Omega = lambda x lambda_dot (rad/s, (3,))
    and lambda_dot = P_lambda dv / r^ (dv = v^_T - v). a is perpendicular to the
    pursuer velocity v; it has a component along lambda in general, which the range
    controller of eq. (18) accounts for (its -dp^T a term), so the law is combined
    with the range controller like PPG and HNG.

    navigation_gain: N, dimensionless.
    """

    includes_range_control: ClassVar[bool] = False

    navigation_gain: float = 3.0

    def los_rate(self, los: np.ndarray, range_estimate: float, relative_velocity: np.ndarray) -> np.ndarray:
        """Omega = lambda x P_lambda dv / r^, rad/s, shape (3,)."""
        lam = unit(np.asarray(los, dtype=float))
        lam_dot = orthogonal_projection(lam) @ np.asarray(relative_velocity, dtype=float) / max(float(range_estimate), _MIN_RANGE)
        return cross(lam, lam_dot)

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """a = N Omega x v. velocity m/s (3,), los (3,), range m, relative_velocity m/s (3,) (required).

        Returns m/s^2, shape (3,). Raises ValueError without relative_velocity.
        """
        dv = _require_relative_velocity(relative_velocity, "PNG")
        return self.navigation_gain * cross(self.los_rate(los, range_estimate, dv), np.asarray(velocity, dtype=float))


@dataclass(frozen=True)
class PDFollowingController:
    """PD controller of section VIII-C1 (Fig. 11(c)): a complete acceleration command.

    a = k_P (p_d - p) + k_D (v^_T - v) with p_d = p^_T - r_d lambda; since
    p^_T - p = r^ lambda, p_d - p = (r^ - r_d) lambda. The pipeline adds no
    range-controller term (`includes_range_control = True`).

    kp: k_P, 1/s^2. kd: k_D, 1/s. desired_range: r_d, m (section VIII-A: 8 m).
    """

    includes_range_control: ClassVar[bool] = True

    kp: float = 0.5
    kd: float = 0.2
    desired_range: float = 8.0

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """los (3,), range m, relative_velocity m/s (3,) (required). Returns m/s^2, shape (3,)."""
        dv = _require_relative_velocity(relative_velocity, "the PD controller")
        lam = unit(np.asarray(los, dtype=float))
        return self.kp * (float(range_estimate) - self.desired_range) * lam + self.kd * dv


@dataclass(frozen=True)
class RetroProportionalNavigationGuidance:
    """Retro-PNG of refs. [14], [16] as adapted in section VIII-C2 (Fig. 12(a)).

    The 2-D optimal law a = -2 |v| theta_dot is applied in the horizontal plane
    (theta = azimuth beta, along e_beta) and in the vertical plane containing the line
    of sight (theta = elevation eps, along e_eps), and the two are added:
    a = -gain |v| (beta_dot e_beta + eps_dot e_eps), see `plane_los_rates`.
    |v| is the pursuer's current 3-D speed (the paper drops the constant-speed
    assumption). The command is perpendicular to the line of sight and pushes *with*
    the LOS rate (opposite to PNG), so it is combined with the range controller.

    gain: the 2 of [14], [16], dimensionless. Units: |v| m/s x rad/s -> m/s^2.
    """

    includes_range_control: ClassVar[bool] = False

    gain: float = 2.0

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """velocity m/s (3,), los (3,), range m, relative_velocity m/s (3,) (required). Returns m/s^2, (3,)."""
        dv = _require_relative_velocity(relative_velocity, "retro-PNG")
        rates = plane_los_rates(_relative_position(los, range_estimate), dv)
        speed = float(np.linalg.norm(np.asarray(velocity, dtype=float)))
        return -self.gain * speed * (rates.beta_dot * rates.e_beta + rates.eps_dot * rates.e_eps)


@dataclass(frozen=True)
class ZEMObservabilityGuidance:
    """Linear observability-enhancement optimal guidance of ref. [43], section VIII-C2 (Fig. 12(b)).

    [43]: a = k_w t_go z cot(k_w t_go^3 / 3) with the zero-effort miss z; rewritten as
    a = N v_c theta_dot with N = k_w t_go^3 cot(k_w t_go^3 / 3) (see `navigation_gain`).
    Applied per plane like retro-PNG: a = N v_c (beta_dot e_beta + eps_dot e_eps),
    perpendicular to the line of sight, combined with the range controller.
    v_c = -lambda . dv is the closing speed, m/s.

    With x = k_w t_go^3: N -> 3 (classic PNG) as t_go -> 0, N < 0 (retro-PNG) for
    pi/2 < x/3 < pi, and N has poles at x/3 = k pi. [43] picks k_w so that the
    initial time-to-go lies in the retro-PNG interval.

    Time-to-go rule (a following task has no intercept, so the paper says t_go
    "cannot be accurately defined"; this is the choice made here):

    * closing, v_c > min_closing_speed: t_go = max(r^ - r_d, 0) / v_c, the time to
      reach the desired range at the current closing speed; inside r_d it is 0, so
      the law is PNG with N = 3. N = clip(x cot(x/3), -max_gain, max_gain): the
      cotangent oscillation with poles that the paper blames for the Fig. 12(b)
      failure stays in the command (t_go swings as r^ and v_c vary), only bounded.
    * not closing, v_c <= min_closing_speed: t_go is undefined (`time_to_go` returns
      None). The law then stays at the far, retro-PNG end of the design interval of
      [43] (N -> -inf as x/3 -> pi from below, clipped): N = -max_gain, and the
      undefined closing speed is replaced by min_closing_speed, i.e.
      a = -max_gain min_closing_speed (beta_dot e_beta + eps_dot e_eps). It keeps a
      weak retro-PNG push that builds LOS rate (observability), keeps the sign of the
      command independent of how fast the range opens (a negative v_c would turn
      retro-PNG into PNG), and bounds it by max_gain min_closing_speed |theta_dot|.

    k_w: 1/s^3. max_gain: bound on |N|, dimensionless, > 0. desired_range: r_d, m.
    min_closing_speed: m/s, >= 0.
    """

    includes_range_control: ClassVar[bool] = False

    k_w: float = 0.007
    max_gain: float = 10.0
    desired_range: float = 8.0
    min_closing_speed: float = 0.1

    def __post_init__(self) -> None:
        if not self.k_w > 0.0:
            raise ValueError(f"k_w must be positive, got {self.k_w}")
        if not self.max_gain > 0.0:
            raise ValueError(f"max_gain must be positive, got {self.max_gain}")
        if not self.min_closing_speed >= 0.0:
            raise ValueError(f"min_closing_speed must be non-negative, got {self.min_closing_speed}")

    def time_to_go(self, range_estimate: float, closing_speed: float) -> float | None:
        """t_go = max(r^ - r_d, 0) / v_c in s, or None (undefined) when v_c <= min_closing_speed."""
        if not closing_speed > self.min_closing_speed:
            return None
        return max(float(range_estimate) - self.desired_range, 0.0) / float(closing_speed)

    def navigation_gain(self, t_go: float | None) -> float:
        """N = k_w t_go^3 cot(k_w t_go^3 / 3), clipped to [-max_gain, max_gain].

        t_go: s, >= 0; None or +inf means undefined and gives -max_gain (see the class
        docstring). N(0) = 3 (limit of x cot(x/3)); at the poles x/3 = k pi it returns
        +-max_gain. Raises ValueError for a negative or NaN t_go.
        """
        if t_go is None or t_go == math.inf:
            return -self.max_gain
        if not t_go >= 0.0:
            raise ValueError(f"time-to-go must be non-negative, got {t_go}")
        x = self.k_w * float(t_go) ** 3
        if x < 1e-4:
            gain = 3.0 - x * x / 27.0  # series of x cot(x/3)
        else:
            sine, cosine = math.sin(x / 3.0), math.cos(x / 3.0)
            gain = x * cosine / sine if sine != 0.0 else math.copysign(math.inf, cosine)
        return float(min(self.max_gain, max(-self.max_gain, gain)))

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """los (3,), range m, relative_velocity m/s (3,) (required). Returns m/s^2, shape (3,)."""
        dv = _require_relative_velocity(relative_velocity, "the ZEM guidance law")
        dp = _relative_position(los, range_estimate)
        closing_speed = -float(unit(dp) @ dv)
        t_go = self.time_to_go(range_estimate, closing_speed)
        gain = self.navigation_gain(t_go)
        speed = closing_speed if t_go is not None else self.min_closing_speed
        rates = plane_los_rates(dp, dv)
        return gain * speed * (rates.beta_dot * rates.e_beta + rates.eps_dot * rates.e_eps)


class _FilteredDerivative:
    """First-order filtered derivative of a sampled vector (seed 003's "derivative estimation
    filter", section 2.2, in its simplest form): d_k = d_{k-1} + dt / (tau + dt) ((x_k - x_{k-1}) / dt
    - d_{k-1}), d = 0 until two samples. A sample at a time not after the last restarts it."""

    def __init__(self, time_constant: float) -> None:
        self.time_constant = float(time_constant)
        self._time: float | None = None
        self._value = np.zeros(3)
        self._rate = np.zeros(3)

    def update(self, time: float, value: np.ndarray) -> np.ndarray:
        """The filtered rate (units of value per s, (3,)) after a sample at time (s)."""
        if self._time is None or not time > self._time:
            self._time, self._value, self._rate = float(time), np.array(value, dtype=float), np.zeros(3)
            return self._rate.copy()
        step = float(time) - self._time
        raw = (np.asarray(value, dtype=float) - self._value) / step
        self._rate = self._rate + step / (self.time_constant + step) * (raw - self._rate)
        self._time, self._value = float(time), np.array(value, dtype=float)
        return self._rate.copy()


class FlightPathCommands(NamedTuple):
    """Seed 003's commands to the chaser's first-order autopilot (eq. (5)-(7), erratum fixed).

    speed: v_g^c, m/s. flight_path_angle: gamma^c, rad, positive climbing. course: chi^c,
    rad, from north towards east (NED heading).
    """

    speed: float
    flight_path_angle: float
    course: float


def flight_path_angles(velocity_ned: np.ndarray) -> tuple[float, float, float]:
    """(v_g, gamma, chi) of a NED velocity (m/s, (3,)): speed m/s, flight-path angle rad
    (positive climbing), course rad (atan2(v_E, v_N)); seed 003 eq. (4) with z up = -z_NED."""
    v = np.asarray(velocity_ned, dtype=float)
    horizontal = math.hypot(float(v[0]), float(v[1]))
    return float(np.linalg.norm(v)), math.atan2(-float(v[2]), horizontal), math.atan2(float(v[1]), float(v[0]))


@dataclass(frozen=True)
class Seed003BacksteppingGuidance:
    """Backstepping-like speed / flight-path / course law of seed 003 (Ahmed and Subbarao,
    Aerospace 2016), eq. (5)-(8), with the erratum's sign fixed, as a complete following command.

    Frame: the seed's x north, y east, z up (NED with z negated). Following task: the law
    tracks the reference point p_r = p^_T - r_d lambda (r_d behind the target on the line
    of sight) instead of the target itself, so the position error of eq. (8) is
    e = p - p_r = (r_d - r^) lambda, and its velocity x_r' = v^_T - r_d lambda' with
    lambda' = P_lambda dv / r^ (dv = v^_T - v). x_r'' in eq. (8) is the target's acceleration
    from the seed's derivative estimation filter (section 2.2) applied to the estimated target
    velocity (`target_acceleration`: first order, target_acceleration_time_constant s, norm
    bounded by max_target_acceleration m/s^2; None: x_r'' = 0); r_d lambda'' is neglected.
    With the filter, `acceleration` keeps state between calls: one law per flight.

    Desired velocity (eq. (8)): u = -alpha e + x_r' (horizontal gains alpha, vertical alpha);
    v_1^d = |u_h|, v_2^d = u_z, chi^d = atan2(u_y, u_x); with e' = v - x_r':
    u' = -alpha e', v_1^d' = u_h . u_h' / v_1^d, v_2^d' = u_z',
    chi^d' = (cos chi^d u_y' - sin chi^d u_x') / v_1^d. Departure from the seed: alpha |e|
    is bounded by max_approach_speed (the direction kept, u' differentiated accordingly,
    `_bounded_approach`); unbounded, a target 80 m away asks for 40 m/s at alpha = 0.5,
    which the seed's point mass flies and a quadrotor does not (seed003_ekf_rae went out
    of control that way at lambda = 2).

    Commands with the erratum fixed (A_1 = -v_1^d' + lambda v~_1, A_2 = -v_2^d' + lambda v~_2,
    v~_1 = v_g cos g - v_1^d, v~_2 = v_g sin g - v_2^d, chi~ = wrap(chi - chi^d)):
    v_g^c = v_g + [-cos g A_1 - sin g A_2] / c_1 (eq. (5)), g^c = g + [sin g A_1 -
    cos g A_2] / (c_2 v_g) (eq. (6)), chi^c = chi - (-chi^d' + lambda chi~) / c_3 (eq. (7)).
    Through the first-order autopilot of eq. (4) these give v~_i' = -lambda v~_i and
    chi~' = -lambda chi~; the printed leading minus of (5)-(6) gives v~_i' = +lambda v~_i.

    Acceleration command (what the pipeline's attitude mapping, eq. (21)-(22), needs): the
    autopilot's rates v_g' = c_1 (v_g^c - v_g), g' = c_2 (g^c - g), chi' = c_3 (chi^c - chi)
    put into the point mass's acceleration (eq. (4): V' = v_g' e_v + v_g g' e_g + v_g cos g chi' e_chi,
    z negated for NED). c_1, c_2, c_3 cancel and the result is regular at
    v_g = 0: a_up = -A_1 [cos chi, sin chi, 0] - A_2 [0, 0, 1]
    + v_g cos g (chi^d' - lambda chi~) [-sin chi, cos chi, 0].

    Singularities guarded: v_1^d below min_horizontal_speed (a vertical target, or the
    reference point reached) divides by min_horizontal_speed instead (v_1^d' is then still
    bounded by |u_h'|), and chi^d' = 0, chi^d = chi (hold the course); a pursuer whose
    horizontal speed is below min_horizontal_speed takes chi = chi^d (its course is
    undefined). The 1 / v_g of eq. (6) only appears in `commands`, floored the same way.

    alpha: position gain alpha_1 = alpha_2 = alpha_3, 1/s. gain: lambda_1 = lambda_2 =
    lambda_3, 1/s. desired_range: r_d, m. max_approach_speed: bound on alpha |e|, m/s. autopilot_gains: (c_1, c_2, c_3), 1/s (the seed's
    100), used by `commands` only. The seed's lambda = 50 assumes a 100/s autopilot; a
    quadrotor's attitude loop is far slower. Defaults measured on seed 003's helix
    (seed003_ekf_rae, seeds 1-6, in-process quadrotor): alpha = 0.5, lambda = 1, 3 m/s
    approach bound, 1 s / 3 m/s^2 acceleration filter follow at 1.0-1.5 m range-error RMS and
    never closer than 7.9 m; a 5 m/s bound lets the approach overshoot to 4.1 m, no filter
    (x_r'' = 0) lags 8.7 m RMS, lambda = 2 gives 5-6 m (seeds 1-3).
    """

    includes_range_control: ClassVar[bool] = True

    alpha: float = 0.5
    gain: float = 1.0
    desired_range: float = 8.0
    max_approach_speed: float = 3.0
    target_acceleration_time_constant: float | None = 1.0
    max_target_acceleration: float = 3.0
    autopilot_gains: tuple[float, float, float] = (100.0, 100.0, 100.0)
    min_horizontal_speed: float = 0.05

    def __post_init__(self) -> None:
        for name in ("alpha", "gain", "desired_range", "max_approach_speed", "min_horizontal_speed"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if len(self.autopilot_gains) != 3 or not all(c > 0.0 for c in self.autopilot_gains):
            raise ValueError(f"autopilot_gains must be three positive numbers, got {self.autopilot_gains!r}")
        tau = self.target_acceleration_time_constant
        if tau is not None and not tau > 0.0:
            raise ValueError(f"target_acceleration_time_constant must be positive or None, got {tau!r}")
        object.__setattr__(self, "_target_acceleration", None if tau is None else _FilteredDerivative(tau))

    def target_acceleration(self, engaged_time: float, target_velocity: np.ndarray) -> np.ndarray:
        """x_r'' fed to eq. (8): the filtered derivative of the estimated target velocity (NED, m/s^2,
        (3,)), its norm bounded by max_target_acceleration; zero without the filter. Stateful."""
        if self._target_acceleration is None:
            return np.zeros(3)
        rate = self._target_acceleration.update(engaged_time, target_velocity)
        size = float(np.linalg.norm(rate))
        return rate if size <= self.max_target_acceleration else rate * (self.max_target_acceleration / size)

    def _errors(self, velocity: np.ndarray, los: np.ndarray, range_estimate: float, relative_velocity: np.ndarray,
                target_acceleration: np.ndarray | None = None) -> tuple[float, float, float, float, float, float, float, float]:
        """(v_g, g, chi, A_1, A_2, chi~, chi^d', v_1^d) of the class docstring (seed frame, z up)."""
        up = np.array([1.0, 1.0, -1.0])
        lam = unit(np.asarray(los, dtype=float))
        r = max(float(range_estimate), _MIN_RANGE)
        v_ned = np.asarray(velocity, dtype=float)
        dv = np.asarray(relative_velocity, dtype=float)
        reference_velocity = up * (v_ned + dv - self.desired_range * (orthogonal_projection(lam) @ dv) / r)
        error = up * ((self.desired_range - r) * lam)
        v = up * v_ned
        approach, approach_dot = self._bounded_approach(error, v - reference_velocity)
        u = reference_velocity - approach
        u_dot = -approach_dot
        if target_acceleration is not None:
            u_dot = u_dot + up * np.asarray(target_acceleration, dtype=float)
        v1d = math.hypot(float(u[0]), float(u[1]))
        v2d, v2d_dot = float(u[2]), float(u_dot[2])
        v1d_dot = float(u[0] * u_dot[0] + u[1] * u_dot[1]) / max(v1d, self.min_horizontal_speed)
        speed, gamma, chi = flight_path_angles(v_ned)
        if v1d >= self.min_horizontal_speed:
            chi_d = math.atan2(float(u[1]), float(u[0]))
            chi_d_dot = (math.cos(chi_d) * float(u_dot[1]) - math.sin(chi_d) * float(u_dot[0])) / v1d
        else:
            chi_d, chi_d_dot = chi, 0.0
        if speed * math.cos(gamma) < self.min_horizontal_speed:
            chi = chi_d
        a1 = -v1d_dot + self.gain * (speed * math.cos(gamma) - v1d)
        a2 = -v2d_dot + self.gain * (speed * math.sin(gamma) - v2d)
        chi_error = math.remainder(chi - chi_d, 2.0 * math.pi)
        return speed, gamma, chi, a1, a2, chi_error, chi_d_dot, v1d

    def _bounded_approach(self, error: np.ndarray, error_rate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """w = alpha e and w' = alpha e' (m/s, m/s^2, (3,)), or beyond max_approach_speed
        w = s e / |e| (s = max_approach_speed) and w' = s P_e e' / |e|, P_e = I - e e^T / |e|^2."""
        scaled = self.alpha * error
        size = float(np.linalg.norm(scaled))
        if size <= self.max_approach_speed:
            return scaled, self.alpha * error_rate
        direction = error / float(np.linalg.norm(error))
        rate = self.max_approach_speed / float(np.linalg.norm(error)) * (error_rate - direction * float(direction @ error_rate))
        return self.max_approach_speed * direction, rate

    def commands(self, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                 relative_velocity: np.ndarray, printed_sign: bool = False,
                 target_acceleration: np.ndarray | None = None) -> FlightPathCommands:
        """v_g^c, gamma^c, chi^c of eq. (5)-(7), erratum fixed (printed_sign=True: as printed).

        velocity m/s (3,) NED, los (3,), range m, relative_velocity m/s (3,), target_acceleration
        x_r'' m/s^2 (3,) NED or None (zero). Stateless.
        """
        speed, gamma, chi, a1, a2, chi_error, chi_d_dot, _ = self._errors(velocity, los, range_estimate,
                                                                          relative_velocity, target_acceleration)
        c1, c2, c3 = self.autopilot_gains
        sign = -1.0 if printed_sign else 1.0
        return FlightPathCommands(
            speed + sign * (-math.cos(gamma) * a1 - math.sin(gamma) * a2) / c1,
            gamma + sign * (math.sin(gamma) * a1 - math.cos(gamma) * a2) / (c2 * max(speed, self.min_horizontal_speed)),
            chi - (-chi_d_dot + self.gain * chi_error) / c3,
        )

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """The autopilot acceleration the law asks for (class docstring), m/s^2, NED, shape (3,).

        velocity m/s (3,), los (3,), range m, relative_velocity m/s (3,) (required).
        """
        dv = _require_relative_velocity(relative_velocity, "the seed 003 law")
        target_acceleration = self.target_acceleration(engaged_time, np.asarray(velocity, dtype=float) + dv)
        speed, gamma, chi, a1, a2, chi_error, chi_d_dot, _ = self._errors(velocity, los, range_estimate, dv,
                                                                          target_acceleration)
        turn = speed * math.cos(gamma) * (chi_d_dot - self.gain * chi_error)
        cc, sc = math.cos(chi), math.sin(chi)
        return np.array([-a1 * cc - turn * sc, -a1 * sc + turn * cc, a2])
