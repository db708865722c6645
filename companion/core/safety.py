"""The safety envelope: what the command may never do, whatever the estimate says.

The guidance laws fly on the estimate. A bearing-only estimate can be wrong in exactly the way that
matters most for safety: while the target accelerates away the range estimate collapses towards
r_d, and when it then brakes the pursuer arrives too fast. The envelope is applied to every
command after the law (and before the vehicle's own limits), with two rules:

1. **Closing speed from a pessimistic range.** With r_p = r^ - k sigma_r the range the estimate
   cannot rule out (sigma_r = sqrt(lambda^T P_pp lambda)), and the target's speed away from us
   u_T = v^_T . lambda - k_v sigma_v, the pursuer closes along the line of sight
   no faster than it can stop before min_range even if the target starts braking now at the
   largest deceleration a target can have (a_T):

       gap = r_p - r_min + max(u_T, 0)^2 / (2 a_T) - max(u_T, 0) t_e  (target's stopping distance)
       u_max = sqrt((a_P t_r)^2 + 2 a_P gap) - a_P t_r   if gap > 0,    (own stopping distance,
       u_max = gain_retreat * gap                         otherwise     t_r of reaction)

   plus min(u_T, 0) when the target comes towards us. t_e is the estimate's latency: a filter sees a braking
   target only some time after it began to brake (a constant-velocity prediction carries it on at u_T), so the
   target may already have braked for t_e and stops u_T^2 / (2 a_T) beyond where it was t_e ago, that is
   u_T t_e short of the credit counted from the estimate's present position. The same t_e is added to t_r:
   the pursuer starts braking only once the estimate shows the target braking. While the pursuer's own closing speed
   u_P = v_P . lambda comes near u_max the command's line-of-sight component becomes
   min(a . lambda, k_v (u_max - u_P) + du_max/dt), bounded below by -a_max, the hardest braking the
   airframe flies (a_P < a_max keeps the rest for the lateral law while the envelope only plans).
   It is the longitudinal rule of responsibility-sensitive safety (Shalev-Shwartz et al. 2017)
   applied to a target whose range is known only up to k sigma. When the estimate is not trusted
   (the pipeline's call: a prediction without bearings, degraded or reacquiring) the envelope counts
   on only untrusted_range_share of the pessimistic range and leaves the target's stopping distance
   out (u_T taken as at most 0). The line of sight is the latest measured bearing while it is fresh (a
   measurement, not the estimate), else the estimate's.

   **A target that has changed speed.** A latency held always keeps the pursuer a time headway behind every
   target at speed, steady ones too. speed_change_latency is a t_e used only while the target has lately
   changed speed: from the moment the estimator's speed-change models (the IMM's, companion.core.imm) hold at
   least speed_change_trigger of its model probability, while the estimated speed |v^_T| is also at least
   speed_change_speed away from its average over the last speed_change_window s, until speed_change_memory s
   after they last did (SpeedChangeLatch; t_e is then the larger of the two latencies). The speed test keeps
   turns out: at the end of a coordinated turn the speed-change model briefly explains the bearings best, but
   the speed has not changed. A target that hovers, dashes and brakes is followed with the headway; one that
   flies or turns at a steady speed at r_d.

   **A target that hovers.** A hovering target may leave in any direction, straight at the pursuer too, and a
   departure along the line of sight shows in the bearings only after one to two seconds (the range is not
   observable from one bearing). hover_standoff (m) is added to r_min while the estimated target speed |v^_T|
   is below hover_speed: in full at rest, falling linearly to nothing at hover_speed. The pursuer then waits at
   that much more distance for the departure it cannot yet see.

   **A control loop that runs late.** t_r is the airframe's answer to a command sent on time. A companion that
   falls behind (a busy computer; a SITL run faster than real time, where every wall-clock millisecond of delay is
   several of the vehicle's) leaves the vehicle flying an old setpoint for longer: the harness measures that
   delay, the vehicle time from the state one setpoint was computed from to the newest state when the next went
   out, beyond the control period (FollowingPipeline.note_loop_delay), and the envelope adds the largest of the
   last loop_delay_memory s to t_r. A loop that keeps time adds nothing; the in-process simulator has no such
   delay.

2. **Heading rate.** The setpoint's heading is the line of sight's horizontal direction, turned
   towards at most max_yaw_rate (rad/s): a geometric attitude controller tracking a yaw step couples
   the yaw error into roll and pitch, and a pursuer close to a target whose bearing swings fast tilted
   10 deg past its tilt limit that way. The horizontal heading replaces lambda in eq. (21)'s R_d.

3. **Tilt margin.** The setpoints' tilt is kept tilt_margin below the airframe's limit: the
   attitude loop overshoots a fast-moving tilt setpoint by a few degrees, and the limit is the
   airframe's, not the setpoint's.

The rules' arithmetic is in kernels (companion.core._jit: compiled with numba when installed, plain Python
otherwise) that the envelope's methods and the control tick both call: a few scalar operations per tick.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from companion.core._jit import jit, remainder
from companion.core.attitude import VehicleLimits, _limited_acceleration_kernel, _setpoint_after_into_kernel
from companion.core.messages import once_property
from interfaces.derived_defaults import SPEED_CHANGE_LATENCY, safety_hover_standoff


@dataclass(frozen=True)
class SafetyEnvelope:
    """The envelope's parameters (module docstring). Distances m, speeds m/s, accelerations m/s^2, times s.

    min_range: r_min, the closest the pursuer may come to the target (the default setup takes r_d / 2).
    range_sigmas: k of the pessimistic range r^ - k sigma_r. speed_sigmas: k_v of the target's pessimistic
    speed away from us, v^_T . lambda - k_v sigma_v.
    target_max_acceleration: a_T, the largest deceleration a target can have (the estimator's stated
    target acceleration bound). braking_acceleration: a_P, the braking the pursuer plans with (well
    inside what its tilt limit allows, since the lateral law needs the rest). reaction_time: t_r, the
    latency until a braking command takes effect. max_braking_acceleration: a_max, the hardest braking the
    envelope commands when the closing speed is already above the limit (at least a_P). velocity_gain: k_v, 1/s, how hard the closing speed
    is pulled down to the limit. retreat_gain: 1/s, the speed away per metre inside r_min.
    max_yaw_rate: rad/s, the heading's largest rate of turn. untrusted_range_share: the share of the
    pessimistic range counted on while the estimate is not trusted, in (0, 1]. tilt_margin: rad, kept
    between the setpoints' tilt and the airframe's limit (`commanded_limits`). estimate_latency: t_e, s, how long
    the estimate may lag a target that starts braking (module docstring, rule 1; 0 counts on it at once).
    speed_change_latency: s, the t_e while the target has lately changed speed (0: never), that is for
    speed_change_memory s after the estimator's speed-change models last held at least speed_change_trigger (a
    probability in (0, 1]) of its model probability while the estimated speed was at least speed_change_speed
    (m/s; 0: the probability alone) from its exponential average with time constant speed_change_window (s)
    (module docstring, rule 1; SpeedChangeLatch; it needs an estimator with speed-change models and never
    trips without them). hover_standoff: m added to min_range while the target hovers (0: never; None, the
    default: interfaces.derived_defaults.safety_hover_standoff of target_max_acceleration), in full at rest and
    falling linearly to 0 at an estimated target speed of hover_speed (m/s) (module docstring, rule 1;
    `hover_share`). loop_delay_memory: s a measured delay of the control loop is added to t_r for (0: never;
    module docstring, rule 1).
    """

    min_range: float
    target_max_acceleration: float
    braking_acceleration: float
    max_braking_acceleration: float
    range_sigmas: float = 2.0
    speed_sigmas: float = 0.0
    reaction_time: float = 0.3
    velocity_gain: float = 2.0
    retreat_gain: float = 1.0
    max_yaw_rate: float = math.radians(45.0)
    untrusted_range_share: float = 1.0
    tilt_margin: float = math.radians(3.0)
    estimate_latency: float = 0.0
    speed_change_latency: float = SPEED_CHANGE_LATENCY
    speed_change_memory: float = 30.0
    speed_change_trigger: float = 0.5
    speed_change_speed: float = 1.0
    speed_change_window: float = 1.0
    hover_standoff: float | None = None
    hover_speed: float = 1.0
    loop_delay_memory: float = 10.0

    def __post_init__(self) -> None:
        if self.hover_standoff is None:
            object.__setattr__(self, "hover_standoff", safety_hover_standoff(self.target_max_acceleration))
        values = (self.min_range, self.target_max_acceleration, self.braking_acceleration, self.velocity_gain,
                  self.retreat_gain, self.max_yaw_rate)
        if not all(math.isfinite(v) and v > 0.0 for v in values):
            raise ValueError("the safety envelope's min_range, accelerations, gains and max_yaw_rate must be finite and > 0")
        if not (math.isfinite(self.max_braking_acceleration) and self.max_braking_acceleration >= self.braking_acceleration):
            raise ValueError("max_braking_acceleration must be finite and at least braking_acceleration")
        for name in ("range_sigmas", "speed_sigmas"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}")
        for name in ("reaction_time", "estimate_latency", "speed_change_latency", "speed_change_memory",
                     "speed_change_speed", "hover_standoff", "loop_delay_memory"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}")
        if not (math.isfinite(self.tilt_margin) and 0.0 <= self.tilt_margin < math.radians(20.0)):
            raise ValueError(f"tilt_margin must be in [0, 20) deg, got {math.degrees(self.tilt_margin)!r} deg")
        for name in ("speed_change_window", "hover_speed"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.speed_change_trigger <= 1.0:
            raise ValueError(f"speed_change_trigger must be in (0, 1], got {self.speed_change_trigger!r}")
        if not 0.0 < self.untrusted_range_share <= 1.0:
            raise ValueError(f"untrusted_range_share must be in (0, 1], got {self.untrusted_range_share!r}")

    def commanded_limits(self, limits: VehicleLimits) -> VehicleLimits:
        """The airframe's limits with the setpoints' tilt limit tilt_margin below its own (module docstring,
        rule 3); the airframe's limits when the margin would leave less than 5 deg."""
        tilt = limits.max_tilt - self.tilt_margin
        if self.tilt_margin == 0.0 or tilt < math.radians(5.0):
            return limits
        return dataclasses.replace(limits, max_tilt=tilt)

    @once_property
    def kernel_terms(self) -> tuple[float, ...]:
        """The closing-speed rule's parameters as its kernels take them (_closing_limit): (r_min, a_T, a_P, a_max,
        k, k_v, t_r, velocity gain, retreat gain, untrusted share, t_e), floats (computed on the first read and
        kept: the envelope is frozen)."""
        return (float(self.min_range), float(self.target_max_acceleration), float(self.braking_acceleration),
                float(self.max_braking_acceleration), float(self.range_sigmas), float(self.speed_sigmas),
                float(self.reaction_time), float(self.velocity_gain), float(self.retreat_gain),
                float(self.untrusted_range_share), float(self.estimate_latency))

    @once_property
    def speed_change_terms(self) -> tuple[float, ...]:
        """The kernel_terms of this envelope with t_e the larger of estimate_latency and speed_change_latency: the
        terms while the target has lately changed speed (module docstring, rule 1)."""
        latency = max(self.estimate_latency, self.speed_change_latency)
        return dataclasses.replace(self, estimate_latency=latency).kernel_terms

    @staticmethod
    def delayed_terms(terms: tuple[float, ...], delay: float) -> tuple[float, ...]:
        """`terms` (kernel_terms, or those of the headway or the hover standoff) with the reaction time t_r, their
        seventh, `delay` s longer (module docstring, rule 1: a control loop that runs late)."""
        return (*terms[:6], terms[6] + delay, *terms[7:])

    def hover_share(self, velocity: np.ndarray) -> float:
        """The share of hover_standoff added to min_range for a target whose estimated velocity is `velocity`
        (m/s, (3,)) (module docstring, rule 1): 1 at rest, falling linearly to 0 at hover_speed, 0 beyond; 1 for a
        speed that is not finite (no estimate to trust); 0 whenever hover_standoff is 0."""
        if self.hover_standoff == 0.0:
            return 0.0
        speed = _speed(velocity)
        if not math.isfinite(speed):
            return 1.0
        return max(0.0, 1.0 - speed / self.hover_speed)

    def hover_terms(self, terms: tuple[float, ...], velocity: np.ndarray) -> tuple[tuple[float, ...], bool]:
        """`terms` (kernel_terms or speed_change_terms) with r_min, their first, raised by hover_share(velocity) x
        hover_standoff for a target whose estimated velocity is `velocity` (m/s, (3,)); and whether it was raised."""
        share = self.hover_share(velocity)
        if share <= 0.0:
            return terms, False
        return (terms[0] + share * self.hover_standoff, *terms[1:]), True

    def closing_speed_limit(self, range_estimate: float, range_std: float, target_speed_away: float,
                            target_speed_std: float, trust_target_velocity: bool) -> float:
        """u_max, m/s (module docstring, rule 1): the largest speed along the line of sight towards the target
        that still stops the pursuer before min_range. range_estimate r^ and range_std sigma_r, m;
        target_speed_away v^_T . lambda and its std, m/s; trust_target_velocity False counts on
        untrusted_range_share of the pessimistic range and leaves out the target's stopping distance (its speed
        counts only when it comes towards us). The arithmetic is _closing_limit's."""
        return _closing_limit_kernel(float(range_estimate), float(range_std), float(target_speed_away),
                                     float(target_speed_std), bool(trust_target_velocity), self.kernel_terms)[0]

    def limit_closing(self, command: np.ndarray, los: np.ndarray, pursuer_velocity: np.ndarray, range_estimate: float,
                      range_std: float, target_speed_away: float, target_speed_std: float,
                      trusted: bool) -> np.ndarray | None:
        """The command (m/s^2, (3,)) with its line-of-sight component lowered so the closing speed
        v_P . lambda stays at or comes down to the limit of rule 1 (`closing_speed_limit`, from the estimate's
        range_estimate, range_std, target_speed_away and target_speed_std, m and m/s, and `trusted`), never
        below -max_braking_acceleration; None when the command already keeps within it (nothing to change).
        los: unit lambda (3,); pursuer_velocity: v_P, m/s (3,).

        The line-of-sight acceleration wanted is k_v (u_max - u_P) plus the limit's own rate: the gap shrinks at
        the closing speed relative to the target, u_P - u_T, and du_max/dgap = a_P / (u_max + a_P t_r), so
        du_max/dt = -(a_P / (u_max + a_P t_r)) (u_P - u_T). At u_P = u_max on a target at rest, with t_r = 0,
        that is braking at exactly a_P, the profile u_max was built on. The arithmetic is _wanted_along's."""
        command = np.asarray(command, dtype=float)
        los = np.asarray(los, dtype=float)
        wanted = _wanted_along_kernel(float(np.asarray(pursuer_velocity, dtype=float) @ los), float(range_estimate),
                                      float(range_std), float(target_speed_away), float(target_speed_std),
                                      bool(trusted), self.kernel_terms)
        along = float(command @ los)
        if along <= wanted:
            return None
        return command + (wanted - along) * los

    def heading(self, los: np.ndarray, previous_forward: np.ndarray | None,
                interval: float) -> tuple[np.ndarray | None, bool]:
        """The horizontal unit vector R_d's heading is built from (module docstring, rule 2), and whether the rate
        limit turned it short of the line of sight: lambda's horizontal direction, reached from the previous
        setpoint's heading at no more than max_yaw_rate x interval. While lambda is within VERTICAL_LOS of the
        vertical its horizontal direction is noise and the previous heading is held. (None, False) with no
        previous setpoint: lambda itself then. los: unit lambda (3,); previous_forward: the last R_d's first
        column (3,); interval: s since that setpoint. The arithmetic is _heading_into's.

        Horizontal rather than lambda itself: R_d's forward axis is the part of its heading vector across the
        thrust axis, and a line of sight nearly along the thrust axis (a target above a tilted pursuer) leaves
        that part to the tilt, so the heading swung with every change of the command and the attitude loop,
        chasing it, was left 150 deg off in yaw and 25 deg past the tilt it was asked for."""
        heading = np.empty(3)
        state = _heading_into_kernel(np.asarray(los, dtype=float),
                                     _NO_HEADING if previous_forward is None else np.asarray(previous_forward, dtype=float),
                                     float(interval), float(self.max_yaw_rate), heading)
        return (None, False) if state == 0 else (heading, state == 2)


#: rad: a line of sight closer than this to the vertical has no heading of its own (`SafetyEnvelope.heading`).
VERTICAL_LOS = math.radians(6.0)


def heading_axis(heading: np.ndarray, flown_acceleration: np.ndarray, gravity: float) -> np.ndarray:
    """The body x axis (unit, (3,)) whose horizontal direction is exactly `heading` (a horizontal unit vector) and
    which is perpendicular to the thrust axis r3 = (g e_Z - a) / |g e_Z - a| of the flown acceleration a (m/s^2,
    (3,)): x_B = (y_C x r3) / |y_C x r3| with y_C = e_Z x heading, PX4's thrust-and-yaw to attitude. Handed to
    eq. (21)'s R_d in place of lambda it gives R_d = [x_B, r3 x x_B, r3]: the heading exactly, where lambda's
    part across r3 would tilt it by up to tan(tilt) x the tilt's share along the heading (16 deg at 32 deg)."""
    north, east = float(heading[0]), float(heading[1])
    fx, fy, fz = -float(flown_acceleration[0]), -float(flown_acceleration[1]), gravity - float(flown_acceleration[2])
    # (e_Z x heading) x f with e_Z x heading = (-east, north, 0): written out (numpy's cross costs 70 us a call)
    x, y, z = north * fz, east * fz, -east * fy - north * fx
    length = math.sqrt(x * x + y * y + z * z)
    return np.array([x / length, y / length, z / length])


def _speed(velocity: np.ndarray) -> float:
    """|v|, m/s, of an estimated velocity (3,): what the hover standoff and the speed-change latch read."""
    return math.sqrt(float(velocity[0]) ** 2 + float(velocity[1]) ** 2 + float(velocity[2]) ** 2)


_NO_HEADING = np.zeros(3)  # a previous heading that is none: _heading_into takes it as no previous setpoint


def _closing_limit(range_estimate, range_std, target_speed_away, target_speed_std, trusted, terms):
    """(u_max, the target's speed away from us as counted), m/s: rule 1 of the module docstring
    (SafetyEnvelope.closing_speed_limit) on floats, `trusted` a bool and the envelope's kernel_terms."""
    (min_range, target_max_acceleration, braking, _, range_sigmas, speed_sigmas, reaction_time, _, retreat_gain,
     untrusted_range_share, estimate_latency) = terms
    pessimistic_range = range_estimate - range_sigmas * range_std
    away = target_speed_away - speed_sigmas * target_speed_std
    if not trusted:
        pessimistic_range *= untrusted_range_share
        away = away if away < 0.0 else 0.0  # min(away, 0): a NaN stays NaN
    gap = pessimistic_range - min_range
    if away > 0.0:
        gap += away * away / (2.0 * target_max_acceleration) - away * estimate_latency
    lag = reaction_time + estimate_latency
    if gap > 0.0:
        limit = math.sqrt((braking * lag) * (braking * lag) + 2.0 * braking * gap) - braking * lag
    else:
        limit = retreat_gain * gap
    return limit + (away if away < 0.0 else 0.0), away


def _wanted_along(closing_speed, range_estimate, range_std, target_speed_away, target_speed_std, trusted, terms):
    """The line-of-sight acceleration, m/s^2, that keeps the closing speed v_P . lambda = closing_speed (m/s) at
    or brings it down to rule 1's u_max (SafetyEnvelope.limit_closing), never below -a_max; floats, `trusted` a
    bool and the envelope's kernel_terms."""
    limit, away = _closing_limit_kernel(range_estimate, range_std, target_speed_away, target_speed_std, trusted,
                                        terms)
    _, _, braking, max_braking, _, _, reaction_time, velocity_gain, _, _, estimate_latency = terms
    if limit > 0.0:
        relative_closing = closing_speed - (away if away > 0.0 else 0.0)
        feed_forward = (braking * (relative_closing if relative_closing > 0.0 else 0.0)
                        / (limit + braking * (reaction_time + estimate_latency)))
        wanted = velocity_gain * (limit - closing_speed) - feed_forward
    else:
        wanted = velocity_gain * (limit - closing_speed) if closing_speed <= 0.0 else -max_braking
    return -max_braking if -max_braking > wanted else wanted  # max(wanted, -a_max): a NaN stays NaN


def _limit_closing_into(command, los, pursuer_velocity, covariance, target_velocity, range_estimate, trusted, terms,
                        out):
    """The control tick's rule 1 in one call: sigma_r = sqrt(lambda^T P_pp lambda) and sigma_v = sqrt(lambda^T P_vv
    lambda) from the estimate's covariance (6, 6), the target's speed away v^_T . lambda, and
    SafetyEnvelope.limit_closing's command (_wanted_along) written into out (3,); returns whether it changed the
    command (out is then the limited command; otherwise out is left as it was). command, los (unit), pursuer and
    target velocity: float64 (3,); range_estimate r^ m; trusted: bool; terms: the envelope's kernel_terms."""
    range_variance = los @ np.ascontiguousarray(covariance[:3, :3]) @ los
    speed_variance = los @ np.ascontiguousarray(covariance[3:, 3:]) @ los
    range_std = math.sqrt(0.0 if 0.0 > range_variance else range_variance)  # max(v, 0): a NaN stays NaN
    speed_std = math.sqrt(0.0 if 0.0 > speed_variance else speed_variance)
    wanted = _wanted_along_kernel(pursuer_velocity @ los, range_estimate, range_std, target_velocity @ los, speed_std,
                                  trusted, terms)
    along = command @ los
    if along <= wanted:
        return False
    for axis in range(3):
        out[axis] = command[axis] + (wanted - along) * los[axis]
    return True


def _heading_into(los, previous_forward, interval, max_yaw_rate, out):
    """Rule 2 (SafetyEnvelope.heading) writing the heading into out (3,): 0 no heading (out untouched), 1 the
    heading, 2 the heading, rate-limited short of lambda. los: unit lambda (3,); previous_forward: the last R_d's
    first column (3,), zeros for none; interval s; max_yaw_rate rad/s."""
    horizontal = math.hypot(los[0], los[1])
    if math.hypot(previous_forward[0], previous_forward[1]) < 1e-6:
        if horizontal < 1e-6:
            return 0
        out[0], out[1], out[2] = los[0] / horizontal, los[1] / horizontal, 0.0
        return 1
    current = math.atan2(previous_forward[1], previous_forward[0])
    if horizontal < math.sin(VERTICAL_LOS):
        out[0], out[1], out[2] = math.cos(current), math.sin(current), 0.0
        return 1
    turn = remainder(math.atan2(los[1], los[0]) - current, 2.0 * math.pi)
    step = max_yaw_rate * (interval if interval > 0.0 else 0.0)
    limited = abs(turn) > step
    heading = current + (math.copysign(step, turn) if limited else turn)
    out[0], out[1], out[2] = math.cos(heading), math.sin(heading), 0.0
    return 2 if limited else 1


def _heading_setpoint_into(command, heading, previous_rotation, setpoint_terms, rotation_out, flown_out):
    """The setpoint of eq. (21)-(22) for `command` (m/s^2, (3,)) flown on the envelope's horizontal `heading` (unit
    (3,)): R_d built on heading_axis (the heading across the thrust axis of the flown command) in place of lambda,
    as attitude._setpoint_after_into writes it (rotation_out (3, 3), flown_out (3,)); returns (T N, normalised
    thrust). setpoint_terms: VehicleLimits.setpoint_terms; previous_rotation: the last R_d (3, 3)."""
    gravity, max_specific_force, max_specific_force_squared, horizontal_margin, min_vertical, tan_max_tilt = \
        setpoint_terms[0], setpoint_terms[1], setpoint_terms[2], setpoint_terms[3], setpoint_terms[4], setpoint_terms[5]
    flown = _limited_acceleration_kernel(command, gravity, max_specific_force, max_specific_force_squared,
                                         horizontal_margin, min_vertical, tan_max_tilt)
    axis = _heading_axis_kernel(heading, flown, gravity)
    return _setpoint_after_into_kernel(command, axis, previous_rotation, setpoint_terms, rotation_out, flown_out)


_closing_limit_kernel = jit(_closing_limit)
_wanted_along_kernel = jit(_wanted_along)
_limit_closing_into_kernel = jit(_limit_closing_into)
_heading_into_kernel = jit(_heading_into)
_heading_axis_kernel = jit(heading_axis)
_heading_setpoint_into_kernel = jit(_heading_setpoint_into)


class SpeedChangeLatch:
    """Whether the envelope plans with its speed_change_latency (module docstring, rule 1): since the last tick at
    which the estimator's speed-change probability held speed_change_trigger while the estimated speed stood at
    least speed_change_speed from its running average, for speed_change_memory s. The average is exponential
    with time constant speed_change_window (one step of period / window, at most 1, per tick; it starts at the
    first speed it sees)."""

    def __init__(self, envelope: SafetyEnvelope) -> None:
        self.envelope = envelope
        self.last_seen = -math.inf  # s: the last tick that counted as a speed change
        self.average_speed = math.nan  # m/s

    def holds(self, time: float, probability: float | None, velocity: np.ndarray, period: float) -> bool:
        """One control tick at `time` (s): the estimator's speed-change probability (None: it has no such
        models), the estimated target velocity (m/s, (3,)) and the control period (s). True while the headway
        is in force."""
        envelope = self.envelope
        speed = _speed(velocity)
        average = speed if math.isnan(self.average_speed) else self.average_speed
        changed = abs(speed - average) >= envelope.speed_change_speed
        if math.isfinite(speed):
            self.average_speed = average + min(1.0, period / envelope.speed_change_window) * (speed - average)
        if changed and probability is not None and probability >= envelope.speed_change_trigger:
            self.last_seen = time
        return time - self.last_seen <= envelope.speed_change_memory


@dataclass
class EnvelopeRecord:
    """How often the envelope acted: control ticks whose closing speed it limited, and whose heading it
    rate-limited, each with the simulated seconds of those ticks (ticks x control period); the seconds it
    planned with speed_change_latency (the target had lately changed speed), those it kept some of
    hover_standoff (the target was slow or hovering) and those it added a measured loop delay to the reaction
    time, with the largest delay added (s)."""

    closing_ticks: int = 0
    heading_ticks: int = 0
    closing_seconds: float = 0.0
    heading_seconds: float = 0.0
    speed_change_seconds: float = 0.0
    hover_seconds: float = 0.0
    loop_delay_seconds: float = 0.0
    loop_delay_max: float = 0.0

    def as_dict(self) -> dict:
        return {"closing_ticks": self.closing_ticks, "closing_seconds": self.closing_seconds,
                "heading_ticks": self.heading_ticks, "heading_seconds": self.heading_seconds,
                "speed_change_seconds": self.speed_change_seconds, "hover_seconds": self.hover_seconds,
                "loop_delay_seconds": self.loop_delay_seconds, "loop_delay_max": self.loop_delay_max}
