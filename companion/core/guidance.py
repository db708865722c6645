"""Guidance: helical navigation (eq. 13-14) and the range controller (eq. 15-19).

The lateral law is swappable (`LateralGuidance` protocol); the range controller
adds the longitudinal term along the line of sight, eq. (18).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from companion.core._jit import jit
from companion.core.attitude import _setpoint_after_into_kernel
from companion.core.geometry import (E_X, clip_kernel, cross, cross_kernel, relative_range_std_kernel,
                                     relative_terms_kernel, rotation_about_y_kernel, rotation_about_z_kernel,
                                     rotation_from_unit_x_axis_to, rotation_from_x_axis_to, unit, unit_kernel)
from companion.core.messages import once_property


class LateralGuidance(Protocol):
    """A lateral (observability-enhancing) acceleration law, perpendicular to the line of sight.

    acceleration(engaged_time s, velocity m/s (3,), los unit (3,), range_estimate m,
    relative_velocity m/s (3,) = v^_T - v) -> m/s^2 (3,). Laws that do not need the
    estimated relative velocity ignore it. A law whose class sets
    `includes_range_control = True` is a complete command (the PD controller of
    section VIII-C1): the pipeline then adds no range-controller term.

    companion.core.control_chain may hold a compiled implementation of the tracking tick for a law's
    exact class (COMPILED_TRACKING: HNG's); every other law, subclasses included, flies its methods.
    """

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray: ...


@dataclass(frozen=True)
class PurePursuitGuidance:
    """PPG of section VIII-C1: a = N (v x lambda) x lambda = -N P_lambda v.

    navigation_gain: N, 1/s.
    """

    navigation_gain: float

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """velocity: m/s, shape (3,); los: unit line of sight, shape (3,). Returns m/s^2, shape (3,)."""
        return self.navigation_gain * cross(cross(velocity, los), los)


@dataclass(frozen=True)
class HelicalNavigationGuidance:
    """Helical navigation guidance HNG, eq. (14).

    a_HN = N (v x R_eta R_Z R_Y e_X) x lambda, with R_eta mapping e_X onto lambda,
    R_Z = R_Z(c_Z sin(w t) / r_hat) and R_Y = R_Y(c_Y cos(w t) / r_hat).

    The rotated vector R_eta R_Z R_Y e_X is a virtual line of sight that circles the
    real one with an angular radius that grows as the range shrinks; pursuing it
    makes the pursuer weave on a helix. With c_Z = c_Y = 0 it is exactly PPG.

    navigation_gain: N, 1/s. c_z, c_y: weave gains, m (divided by range -> rad).
    weave_frequency: w, rad/s (the paper's sin(t) means w = 1 rad/s).
    scale_with_range: divide the weave angles by r_hat (the paper); False uses r_hat = 1
    (property 2 of section VI-A).
    """

    navigation_gain: float
    c_z: float
    c_y: float
    weave_frequency: float = 1.0
    scale_with_range: bool = True

    def virtual_los(self, engaged_time: float, los: np.ndarray, range_estimate: float) -> np.ndarray:
        """R_eta R_Z R_Y e_X of eq. (14); unit vector, shape (3,). The arithmetic is _virtual_los's."""
        _, c_z, c_y, weave_frequency, scale_with_range = self.kernel_terms
        return _virtual_los_kernel(float(engaged_time), np.asarray(los, dtype=float), float(range_estimate), c_z, c_y,
                                   weave_frequency, scale_with_range)

    def acceleration(self, engaged_time: float, velocity: np.ndarray, los: np.ndarray, range_estimate: float,
                     relative_velocity: np.ndarray | None = None) -> np.ndarray:
        """Lateral command a_HN, eq. (14). velocity m/s (3,), los unit (3,), range m. Returns m/s^2 (3,).
        The arithmetic is _helical_acceleration's, compiled with numba when installed."""
        return _helical_acceleration_kernel(float(engaged_time), np.asarray(velocity, dtype=float),
                                            np.asarray(los, dtype=float), float(range_estimate), *self.kernel_terms)

    @once_property
    def kernel_terms(self) -> tuple[float, float, float, float, bool]:
        """(N, c_Z, c_Y, w) as floats and scale_with_range as a bool, as the kernels take them (computed on the
        first read and kept: the law is frozen)."""
        return (float(self.navigation_gain), float(self.c_z), float(self.c_y), float(self.weave_frequency),
                bool(self.scale_with_range))


def _virtual_los(engaged_time, los, range_estimate, c_z, c_y, weave_frequency, scale_with_range):
    """R_eta R_Z R_Y e_X of eq. (14) (HelicalNavigationGuidance.virtual_los) on floats and a float64 (3,) los."""
    scale = 1.0 / max(range_estimate, 1e-3) if scale_with_range else 1.0
    phase = weave_frequency * engaged_time
    rotation_z = rotation_about_z_kernel(c_z * np.sin(phase) * scale)
    rotation_y = rotation_about_y_kernel(c_y * np.cos(phase) * scale)
    return rotation_from_unit_x_axis_to(unit_kernel(los)) @ rotation_z @ rotation_y @ E_X


def _helical_acceleration(engaged_time, velocity, los, range_estimate, navigation_gain, c_z, c_y, weave_frequency,
                          scale_with_range):
    """a_HN = N (v x R_eta R_Z R_Y e_X) x lambda, eq. (14) (HelicalNavigationGuidance.acceleration), on floats and
    float64 (3,) velocity and line of sight (normalised here)."""
    los = unit_kernel(los)
    virtual = _virtual_los_kernel(engaged_time, los, range_estimate, c_z, c_y, weave_frequency, scale_with_range)
    return navigation_gain * cross_kernel(cross_kernel(velocity, virtual), los)


_virtual_los_kernel = jit(_virtual_los)
_helical_acceleration_kernel = jit(_helical_acceleration)


def saturation(x: float, limit: float = 3.0) -> float:
    """sigma(x) = 3 atan(x/3), section VI-B; |sigma| < 3 pi / 2."""
    return limit * float(np.arctan(x / limit))


def saturation_slope(x: float, limit: float = 3.0) -> float:
    """sigma'(x) = 1 / (1 + (x/3)^2)."""
    return 1.0 / (1.0 + (x / limit) ** 2)


_saturation_slope_kernel = jit(saturation_slope)


@jit
def _range_error_terms(relative_position: np.ndarray, relative_velocity: np.ndarray) -> tuple[float, float]:
    """(|dp|, xi_2 = dp^T dv / |dp|) of eq. (15)-(16), m and m/s: |dp| as geometry.norm (sqrt(dp . dp)), the
    denominator max(|dp|, 1e-6) as Python's max takes it (the first argument unless the second is larger,
    so a NaN stays NaN). dp, dv: float64 (3,)."""
    distance = math.sqrt(relative_position @ relative_position)
    floor = 1e-6 if 1e-6 > distance else distance
    return float(distance), float((relative_position @ relative_velocity) / floor)


@jit
def _range_terms(relative_position: np.ndarray, relative_velocity: np.ndarray, los: np.ndarray,
                 lateral_acceleration: np.ndarray) -> tuple[float, float, float, float, float]:
    """The products eq. (18)-(19) need, in one call: (|dp|, xi_2, dv^T dv, dp^T a_HN, lambda^T dp)
    (`_range_error_terms` for the first two). All float64 (3,)."""
    distance, range_rate = _range_error_terms(relative_position, relative_velocity)
    return (distance, range_rate, float(relative_velocity @ relative_velocity),
            float(relative_position @ lateral_acceleration), float(los @ relative_position))


@dataclass(frozen=True)
class RangeErrorState:
    """xi_1 = |dp| - r_d (eq. 15), m, and xi_2 = dp^T dv / |dp| (eq. 16), m/s."""

    range_error: float
    range_rate: float


@dataclass(frozen=True)
class RangeController:
    """Longitudinal range controller, eq. (15)-(19).

    Closed loop (target acceleration zero): xi1' = xi2, xi2' = v*, and with eq. (17)
    V' = -sigma(xi1)^2 - k (sigma(xi1) + xi2)^2 < 0.

    Choice of k (the paper gives none). Near xi = 0 (sigma ~ xi, sigma' ~ 1) the loop is
    xi1'' + (k+1) xi1' + (k+1) xi1 = 0: natural frequency sqrt(k+1), damping
    sqrt(k+1)/2. k = 3 makes it critically damped at 2 rad/s, five times slower
    than the attitude loop, so the quadrotor can fly it. Far away the closing
    speed settles where v* = 0 with sigma saturated: |xi2| -> (3 pi/2)(1 + 1/k),
    6.3 m/s for k = 3. Larger k closes more slowly and feeds more estimate noise
    into the command; smaller k is underdamped.

    desired_range: r_d, m. gain: k, 1/s. saturation_limit: the 3 of sigma, m.
    """

    desired_range: float
    gain: float = 3.0
    saturation_limit: float = 3.0

    def error_state(self, relative_position: np.ndarray, relative_velocity: np.ndarray) -> RangeErrorState:
        """eq. (15)-(16) from dp = p^_T - p (m, (3,)) and dv = v^_T - v (m/s, (3,))."""
        distance, range_rate = _range_error_terms(np.asarray(relative_position, dtype=float),
                                                  np.asarray(relative_velocity, dtype=float))
        return RangeErrorState(distance - self.desired_range, range_rate)

    def virtual_control(self, error: RangeErrorState) -> float:
        """v* = -k[sigma(xi1) + xi2] - sigma(xi1) - sigma'(xi1) xi2, eq. (17); m/s^2."""
        return self._virtual_control(error.range_error, error.range_rate)

    def _virtual_control(self, range_error: float, range_rate: float) -> float:
        """v* of eq. (17) from xi1 = range_error (m) and xi2 = range_rate (m/s) (virtual_control's arithmetic):
        sigma(xi1) here (saturation: numpy's arctan), the rest _virtual_control_terms's."""
        _, gain, limit = self.kernel_terms
        return float(_virtual_control_terms_kernel(saturation(range_error, limit), range_error, range_rate, gain,
                                                   limit))

    @once_property
    def kernel_terms(self) -> tuple[float, float, float]:
        """(r_d, k, the 3 of sigma) as floats, as the kernels take them (computed on the first read and kept: the
        controller is frozen)."""
        return float(self.desired_range), float(self.gain), float(self.saturation_limit)

    def acceleration(
        self,
        relative_position: np.ndarray,
        relative_velocity: np.ndarray,
        los: np.ndarray,
        lateral_acceleration: np.ndarray,
    ) -> np.ndarray:
        """a_RC = u* / (lambda^T dp) lambda, eq. (18), with u* of eq. (19).

        relative_position: dp = p^_T - p, m, (3,). relative_velocity: dv = v^_T - v, m/s, (3,).
        los: unit line of sight lambda, (3,). lateral_acceleration: a_HN, m/s^2, (3,).
        Returns m/s^2, shape (3,). The arithmetic is _range_ratio_terms's, sigma(xi1) (saturation: numpy's arctan),
        then _range_command's.
        """
        desired_range, gain, limit = self.kernel_terms
        los = np.asarray(los, dtype=float)
        distance, range_rate, speed_squared, lateral_work, projection, range_error = _range_ratio_terms(
            np.asarray(relative_position, dtype=float), np.asarray(relative_velocity, dtype=float), los,
            np.asarray(lateral_acceleration, dtype=float), desired_range)
        return _range_command_kernel(distance, range_rate, speed_squared, lateral_work, projection, range_error,
                                     saturation(range_error, limit), gain, limit, los)


@jit
def _range_ratio_terms(relative_position: np.ndarray, relative_velocity: np.ndarray, los: np.ndarray,
                       lateral_acceleration: np.ndarray,
                       desired_range: float) -> tuple[float, float, float, float, float, float]:
    """_range_terms (|dp|, xi_2, dv^T dv, dp^T a_HN, lambda^T dp), then xi_1 = |dp| - r_d, eq. (15), whose
    sigma(xi1) (saturation: numpy's arctan) is taken between this kernel and _range_command."""
    distance, range_rate, speed_squared, lateral_work, projection = _range_terms(
        relative_position, relative_velocity, los, lateral_acceleration)
    return distance, range_rate, speed_squared, lateral_work, projection, distance - desired_range


def _virtual_control_terms(sigma, range_error, range_rate, gain, saturation_limit):
    """v* = -k[sigma(xi1) + xi2] - sigma(xi1) - sigma'(xi1) xi2, eq. (17), on floats: sigma = sigma(xi1) given
    (saturation, section VI-B: numpy's arctan, which a kernel cannot call), xi1 = range_error, xi2 = range_rate,
    sigma' = saturation_slope."""
    slope = _saturation_slope_kernel(range_error, saturation_limit)
    return -gain * (sigma + range_rate) - sigma - slope * range_rate


def _range_command(distance, range_rate, speed_squared, lateral_work, projection, range_error, sigma, gain,
                   saturation_limit, los):
    """a_RC = u* / (lambda^T dp) lambda, eq. (18), u* = -|dp| v* + dv^T dv - xi_2^2 - dp^T a_HN, eq. (19), v* of
    eq. (17) (_virtual_control_terms), from _range_ratio_terms's terms and sigma(xi1) (saturation); zero when
    lambda^T dp <= 1e-6 max(|dp|, 1) (remark 3: the estimate disagrees with the line of sight by 90 degrees or
    more; no longitudinal command is meaningful). Python's max (a NaN |dp| stays NaN). los: float64 (3,)."""
    u_star = (
        -distance * _virtual_control_terms_kernel(sigma, range_error, range_rate, gain, saturation_limit)
        + speed_squared
        - range_rate ** 2
        - lateral_work
    )
    if projection <= 1e-6 * (1.0 if 1.0 > distance else distance):
        return np.zeros(3)
    return u_star / projection * los


_virtual_control_terms_kernel = jit(_virtual_control_terms)
_range_command_kernel = jit(_range_command)


@dataclass(frozen=True)
class RangeExcitation:
    """Lateral excitation that keeps the range observable while it is poorly known.

    Why. A bearing-only filter learns the range only from how the line of sight turns in
    response to the pursuer's own motion: with a constant-velocity target model the
    relative position dp obeys dp'' = a_T - a, and the bearings lambda = dp / |dp| fix dp
    up to a scale unless the own-ship acceleration a has a component perpendicular to
    lambda (the classic bearing-only observability condition; section V's windowed FIM,
    eq. (7), grows only with the spread of the bearings). HNG's weave, eq. (14), is
    a_HN = N (v x lambda_v) x lambda: it is linear in the pursuer's own velocity v, so when
    the pursuer slows to match a slow or circling target the weave - and the range
    information with it - vanishes, while a wrong range estimate near r_d still looks
    self-consistent to the filter.

    What. While the relative range standard deviation rho = sigma_r / r^ is large, make the
    pursuer's own velocity perpendicular to lambda track a vector of fixed size rotating
    about lambda:

        u(t) = cos(w t) e_1 + sin(w t) e_2,   u_perp(t) = -sin(w t) e_1 + cos(w t) e_2 = u'(t) / w,
        a_X  = s V_X (N u + w u_perp),        |a_X| = s V_X sqrt(N^2 + w^2),

    with (e_1, e_2) the second and third columns of R_eta (the rotation taking e_X onto
    lambda that eq. (14) uses), so e_1, e_2, lambda are orthonormal and a_X . lambda = 0.
    The N u term cancels HNG's/PPG's damping of the lateral velocity (-N P_lambda v):
    with a = a_HN + a_X and v_perp = P_lambda v (line of sight turning slowly),
    v_perp' = N (s V_X u - v_perp) + s V_X u' + (HNG's weave), so v_perp -> s V_X u: the pursuer circles the line of sight at speed s V_X,
    i.e. a perpendicular own-ship acceleration of s V_X w and a baseline of radius
    s V_X / w, whatever its own speed. A pursuer at rest is therefore never left with a
    zero (stop) command while s > 0: its lateral command is a_X itself.

    The level s in [0, 1] ramps with rho between rho_0 (low) and rho_1 (high):

        s = clip((rho - rho_0) / (rho_1 - rho_0), 0, 1),   and s = 1 while the health
        monitor (companion.core.health) judges the estimate suspect,

    because a diverged filter can be confident and wrong (small sigma_r), which the monitor
    detects from its innovations. Section V's windowed FIM is not used: it treats the target
    as static, so a target circling a stopped pursuer sweeps the bearings and keeps it large
    (docs/explanation/estimation.md, "Filter health"). With the range well observed (rho <= rho_0, not
    suspect) a_X = 0 and the guidance is the paper's HNG.

    speed: V_X, m/s. damping_gain: N of the lateral law it is added to, 1/s.
    frequency: w, rad/s. low / high: rho_0 < rho_1, dimensionless.
    """

    speed: float = 8.0
    damping_gain: float = 3.0
    frequency: float = 0.5
    low: float = 0.02
    high: float = 0.06

    def __post_init__(self) -> None:
        if not (self.speed > 0.0 and self.damping_gain >= 0.0 and self.frequency > 0.0):
            raise ValueError("need speed > 0, damping_gain >= 0 and frequency > 0")
        if not (0.0 <= self.low < self.high):
            raise ValueError("need 0 <= low < high")

    def level(self, relative_range_std: float, suspect: bool = False) -> float:
        """s in [0, 1] from rho = sigma_r / r^ (dimensionless) and the health verdict (see class); the arithmetic
        is _excitation_level's."""
        low, high, _, _, _ = self.kernel_terms
        return _excitation_level_kernel(float(relative_range_std), bool(suspect), low, high)

    def peak_acceleration(self, level: float = 1.0) -> float:
        """|a_X| = s V_X sqrt(N^2 + w^2), m/s^2 (constant in time)."""
        return level * self.speed * float(np.hypot(self.damping_gain, self.frequency))

    def acceleration(self, engaged_time: float, los: np.ndarray, level: float) -> np.ndarray:
        """a_X = s V_X (N u + w u_perp), m/s^2, shape (3,); perpendicular to the unit line of sight los (3,).

        engaged_time: s since the first bearing. level: s in [0, 1].
        The arithmetic is _excitation_acceleration's, compiled with numba when installed.
        """
        _, _, speed, damping_gain, frequency = self.kernel_terms
        return _excitation_acceleration_kernel(float(engaged_time), np.asarray(los, dtype=float), float(level), speed,
                                               damping_gain, frequency)

    @once_property
    def kernel_terms(self) -> tuple[float, float, float, float, float]:
        """(rho_0, rho_1, V_X, N, w) as floats, as _excitation_terms takes them (computed on the first read and
        kept: the excitation is frozen)."""
        return float(self.low), float(self.high), float(self.speed), float(self.damping_gain), float(self.frequency)


def _excitation_acceleration(engaged_time, los, level, speed, damping_gain, frequency):
    """a_X = s V_X (N u + w u_perp) of RangeExcitation.acceleration on floats and a float64 (3,) line of sight
    (normalised here, then once more as rotation_from_x_axis_to does)."""
    if level <= 0.0:
        return np.zeros(3)
    basis = rotation_from_unit_x_axis_to(unit_kernel(unit_kernel(los)))
    phase = frequency * engaged_time
    cos_phase, sin_phase = np.cos(phase), np.sin(phase)
    direction = cos_phase * basis[:, 1] + sin_phase * basis[:, 2]
    turning = -sin_phase * basis[:, 1] + cos_phase * basis[:, 2]
    return level * speed * (damping_gain * direction + frequency * turning)


def _excitation_level(relative_range_std, suspect, low, high):
    """s = clip((rho - rho_0) / (rho_1 - rho_0), 0, 1), and 1 while suspect or for a rho that is not finite
    (RangeExcitation.level), on floats: rho, rho_0 = low, rho_1 = high."""
    if suspect or not math.isfinite(relative_range_std):
        return 1.0
    return clip_kernel((relative_range_std - low) / (high - low), 0.0, 1.0)


def _excitation_terms(engaged_time, lateral, relative_position, covariance, los, suspect, low, high, speed,
                      damping_gain, frequency):
    """(s, a_lat + a_X) in one call, for the control tick: rho = sigma_r / r^ from dp (3,) and the estimate's
    covariance (6, 6) (geometry.relative_range_std on its P_pp block), the level s of RangeExcitation.level
    (_excitation_level) and a_X = s V_X (N u + w u_perp) of RangeExcitation.acceleration
    (_excitation_acceleration) added to the lateral command a_lat (3,). All float64."""
    rho = relative_range_std_kernel(relative_position, np.ascontiguousarray(covariance[:3, :3]))
    level = _excitation_level_kernel(rho, suspect, low, high)
    return level, lateral + _excitation_acceleration_kernel(engaged_time, los, level, speed, damping_gain, frequency)


_excitation_acceleration_kernel = jit(_excitation_acceleration)
_excitation_level_kernel = jit(_excitation_level)
_excitation_terms_kernel = jit(_excitation_terms)


_NO_EXCITATION = (0.0, 1.0, 1.0, 0.0, 1.0)  # RangeExcitation.kernel_terms' place when no excitation is flown


def _tracking_terms(target_position, target_velocity, position, velocity, engaged_time, law_terms, excite, covariance,
                    suspect, excitation_terms, desired_range, outputs):
    """The control tick's guidance up to the range controller's arctan, in one call (FollowingPipeline's usual
    tick: HNG, the excitation when `excite`, the range controller), calling the kernels the objects call:
    geometry.relative_terms (dp, dv, r^, lambda), HNG's a_HN, eq. (14) (_helical_acceleration, on the pursuer's
    velocity), when `excite` the excitation's level and a_lat + a_X (_excitation_terms on the estimate's covariance
    (6, 6) and the health verdict `suspect`), and the range controller's terms (_range_ratio_terms). law_terms:
    HelicalNavigationGuidance.kernel_terms; excitation_terms: RangeExcitation.kernel_terms (_NO_EXCITATION when
    not excited). Writes lambda and a_lat into outputs = (los_out, lateral_out) (float64 (3,)); returns (r^, the excitation level s (0
    when not excited), |dp|, xi_2, dv^T dv, dp^T a_lat, lambda^T dp, xi_1): _range_command's terms follow r^ and s,
    the last one the argument of sigma (saturation: numpy's arctan), taken between this kernel and the next."""
    navigation_gain, c_z, c_y, weave_frequency, scale_with_range = law_terms
    low, high, speed, damping_gain, frequency = excitation_terms
    los_out, lateral_out = outputs
    relative_position, relative_velocity, range_estimate, los = relative_terms_kernel(
        target_position, target_velocity, position, velocity)
    lateral = _helical_acceleration_kernel(engaged_time, velocity, los, range_estimate, navigation_gain, c_z, c_y,
                                           weave_frequency, scale_with_range)
    level = 0.0
    if excite:
        level, lateral = _excitation_terms_kernel(engaged_time, lateral, relative_position, covariance, los, suspect,
                                                  low, high, speed, damping_gain, frequency)
    distance, range_rate, speed_squared, lateral_work, projection, range_error = _range_ratio_terms(
        relative_position, relative_velocity, los, lateral, desired_range)
    los_out[:] = los
    lateral_out[:] = lateral
    return range_estimate, level, distance, range_rate, speed_squared, lateral_work, projection, range_error


def _tracking_command(range_terms, sigma, gain, saturation_limit, los, lateral, outputs, with_setpoint,
                      previous_rotation, setpoint_terms):
    """The rest of _tracking_terms's tick after sigma(xi1) (saturation, numpy's arctan), on range_terms, the last six
    of _tracking_terms's results (|dp|, xi_2, dv^T dv, dp^T a_lat, lambda^T dp, xi_1): a_RC of eq. (18)-(19)
    (_range_command) and the command a_d = a_lat + a_RC, eq. (13), written into outputs = (longitudinal_out,
    command_out, rotation_out, flown_out); with `with_setpoint` also the setpoint of eq. (21)-(22) for that command
    (attitude._setpoint_after_into under setpoint_terms, VehicleLimits.setpoint_terms; the previous R_d (3, 3) giving
    the heading fallback): R_d into rotation_out (3, 3), the flown a_d into flown_out, and returns (T N, normalised
    thrust); without, (nan, nan)."""
    distance, range_rate, speed_squared, lateral_work, projection, range_error = range_terms
    longitudinal_out, command_out, rotation_out, flown_out = outputs
    longitudinal = _range_command_kernel(distance, range_rate, speed_squared, lateral_work, projection, range_error,
                                         sigma, gain, saturation_limit, los)
    longitudinal_out[:] = longitudinal
    command_out[:] = lateral + longitudinal
    if not with_setpoint:
        return math.nan, math.nan
    return _setpoint_after_into_kernel(command_out, los, previous_rotation, setpoint_terms, rotation_out, flown_out)


_tracking_terms_kernel = jit(_tracking_terms)
_tracking_command_kernel = jit(_tracking_command)
