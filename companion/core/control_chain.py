"""One control tick's chain: the law the supervisor chose -> the limiters -> the attitude mapping.

`FollowingPipeline` is the supervisor: from its mode, the health monitor's action, the dropout state and the
neighbours heard it chooses one law object per control tick and hands it the tick's `TickInputs`. The law gives
the commanded acceleration's parts; the pipeline then applies the limiters in a fixed order (keep off min_range,
blend, safety envelope, separation) and maps the command to an attitude and a thrust, eq. (21)-(22). The laws:

* `Tracking`: a lateral law (HNG eq. (14), PPG, ...) plus the range excitation a_X while one is in force, plus the
  range controller's a_RC of eq. (15)-(19): a_d = a_lat + a_RC, eq. (13). A lateral law whose class sets
  `includes_range_control` (the PD controller of VIII-C1) is the whole command. Named "single" (the configured
  law) or "steady" (the same without its weave, while a neighbour gives a baseline).
* `CompleteLaw`: a complete cooperative law on the estimate (seed 002 eq. (10), seed 004 TOGVF), no range-controller
  term. Named "cooperative" (a neighbour is heard) or "lone" (the law on a layer of its own, nobody heard).
* `SafeHold`: the degraded mode's safe behaviour: no weave; the safe range held on the predicted line of sight.

Each law's `name` is what the pipeline records in `law_changes` and summaries report. A law that does not make the
range observable (`observes_range` False: the cooperative laws do not weave) is flown with the keep-off limiter.

Compiled implementation
-----------------------
`COMPILED_TRACKING` maps the exact class of a tracking law's lateral law to a compiled implementation of the
tracking law and, when no limiter acts, the attitude mapping with it: the same kernels the objects' methods call, in
two calls (`compiled_hng_tracking`). It is keyed on the exact class, so a subclass that changes the law flies
through its own methods, and it needs the range controller to be exactly a `RangeController`, whose arithmetic it
computes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.core.attitude import _IDENTITY
from companion.core.cooperative_guidance import CooperativeContext
from companion.core.geometry import relative_terms_kernel
from companion.core.guidance import (_NO_EXCITATION, HelicalNavigationGuidance, LateralGuidance, RangeController,
                                     RangeExcitation, _excitation_terms_kernel, _tracking_command_kernel,
                                     _tracking_terms_kernel, saturation)
from companion.core.messages import TargetEstimate, fast_frozen, once_property


@dataclass(frozen=True)
class TickInputs:
    """What a law is given at one control tick.

    time: s; engaged_time: s since the pipeline engaged. estimate: the target estimate carried to `time`.
    position m, velocity m/s: the pursuer's, float64 (3,) NED. measured_los: the newest measured bearing to fly
    the line of sight on (FollowingPipeline.los_source "measurement"), else None (the estimate's). excitation:
    the range excitation in force, or None; suspect: the health monitor's last verdict called the estimate
    suspect. neighbours: the fresh neighbours; target_acceleration: the estimator's, m/s^2 (3,), or None.
    """

    time: float
    engaged_time: float
    estimate: TargetEstimate
    position: np.ndarray
    velocity: np.ndarray
    measured_los: np.ndarray | None = None
    excitation: RangeExcitation | None = None
    suspect: bool = False
    neighbours: tuple = ()
    target_acceleration: np.ndarray | None = None

    @once_property
    def relative(self) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """(dp = p^_T - p m, dv = v^_T - v m/s, r^ = |dp| m, lambda) with lambda the measured line of sight when
        one is flown, else dp / r^ (geometry.relative_terms_kernel)."""
        estimate = self.estimate
        relative_position, relative_velocity, range_estimate, los = relative_terms_kernel(
            estimate.position, estimate.velocity, self.position, self.velocity)
        return relative_position, relative_velocity, range_estimate, (los if self.measured_los is None
                                                                      else self.measured_los)


@dataclass(frozen=True)
class LawCommand:
    """A law's command at one tick: lateral and longitudinal parts (m/s^2, (3,); their sum is the command), the
    line of sight and range estimate it flew on, and the excitation level s it flew (None: no excitation)."""

    lateral: np.ndarray
    longitudinal: np.ndarray
    los: np.ndarray
    range_estimate: float
    excitation_level: float | None = None


def _law_command(lateral: np.ndarray, longitudinal: np.ndarray, los: np.ndarray, range_estimate: float,
                 excitation_level: float | None = None) -> LawCommand:
    return fast_frozen(LawCommand, lateral=lateral, longitudinal=longitudinal, los=los, range_estimate=range_estimate,
                       excitation_level=excitation_level)


@dataclass(frozen=True)
class Tracking:
    """A lateral law + excitation + range controller, eq. (13): see the module. name: "single" or "steady"."""

    lateral: LateralGuidance
    controller: RangeController
    name: str = "single"
    observes_range = True

    def command(self, tick: TickInputs) -> LawCommand:
        relative_position, relative_velocity, range_estimate, los = tick.relative
        lateral = self.lateral.acceleration(tick.engaged_time, tick.velocity, los, range_estimate, relative_velocity)
        if getattr(self.lateral, "includes_range_control", False):
            return _law_command(lateral, np.zeros(3), los, range_estimate)  # a complete law: no range-controller term
        level = None
        if tick.excitation is not None:
            level, lateral = _excitation_terms_kernel(tick.engaged_time, lateral, relative_position,
                                                      tick.estimate.covariance, los, tick.suspect,
                                                      *tick.excitation.kernel_terms)
        longitudinal = self.controller.acceleration(relative_position, relative_velocity, los, lateral)
        return _law_command(lateral, longitudinal, los, range_estimate, level)


@dataclass(frozen=True)
class CompleteLaw:
    """A complete cooperative law on the estimate: see the module. name: "cooperative" or "lone"."""

    law: object
    name: str = "cooperative"
    observes_range = False

    def command(self, tick: TickInputs) -> LawCommand:
        _, _, range_estimate, los = tick.relative
        estimate = tick.estimate
        lateral = self.law.acceleration(CooperativeContext(tick.time, tick.position, tick.velocity, estimate.position,
                                                           estimate.velocity, tick.neighbours,
                                                           tick.target_acceleration))
        return _law_command(lateral, np.zeros(3), los, range_estimate)


@dataclass(frozen=True)
class SafeHold:
    """The degraded mode's safe behaviour: no lateral term; `controller` (a RangeController at the safe range)
    holds its range on the predicted line of sight."""

    controller: RangeController
    name: str = "safe_hold"
    observes_range = False

    def command(self, tick: TickInputs) -> LawCommand:
        relative_position, relative_velocity, range_estimate, los = tick.relative
        lateral = np.zeros(3)
        longitudinal = self.controller.acceleration(relative_position, relative_velocity, los, lateral)
        return _law_command(lateral, longitudinal, los, range_estimate)


#: The setpoint's parts of eq. (21)-(22) a compiled tick returns with its command: (R_d (3, 3), the flown a_d (3,),
#: thrust T N, normalised thrust).
CompiledSetpoint = tuple[np.ndarray, np.ndarray, float, float]


def compiled_hng_tracking(law: Tracking, tick: TickInputs, setpoint_terms: tuple[float, ...], with_setpoint: bool,
                          previous_rotation: np.ndarray | None) -> tuple[LawCommand, np.ndarray, CompiledSetpoint | None] | None:
    """`law` (HNG + excitation + RangeController) at `tick`, compiled: a_d = a_HN (+ a_X) + a_RC, eq. (13), with a_HN
    of eq. (14), the excitation's a_X at its level when one is in force and the range controller's a_RC of eq.
    (15)-(19), on the estimate's line of sight; when `with_setpoint`, also the setpoint of eq. (21)-(22) for that
    command (attitude_setpoint_after, under the limits' setpoint_terms (VehicleLimits.setpoint_terms);
    previous_rotation: the last R_d (3, 3) for the heading fallback, None for none). The same kernels the objects' methods call, in two calls
    around sigma(xi1) (saturation: numpy's arctan): _tracking_terms and _tracking_command.

    Returns (the LawCommand, a_d (3,), the setpoint's parts or None without `with_setpoint`); None when the range
    controller is not exactly a RangeController (this form computes that class's arithmetic) or a measured line of
    sight is flown (this form flies the estimate's)."""
    controller, excitation = law.controller, tick.excitation
    if type(controller) is not RangeController or tick.measured_los is not None:
        return None
    desired_range, gain, limit = controller.kernel_terms
    estimate = tick.estimate
    los = np.empty(3)
    lateral = np.empty(3)
    terms = _tracking_terms_kernel(
        estimate.position, estimate.velocity, tick.position, tick.velocity, tick.engaged_time, law.lateral.kernel_terms,
        excitation is not None, estimate.covariance, tick.suspect,
        _NO_EXCITATION if excitation is None else excitation.kernel_terms, desired_range, (los, lateral))
    range_estimate, level, range_error = terms[0], terms[1], terms[7]
    longitudinal = np.empty(3)
    command = np.empty(3)
    rotation = np.empty((3, 3))
    flown = np.empty(3)
    thrust, thrust_normalized = _tracking_command_kernel(
        terms[2:], saturation(range_error, limit), gain, limit, los, lateral, (longitudinal, command, rotation, flown),
        with_setpoint, _IDENTITY if previous_rotation is None else previous_rotation, setpoint_terms)
    parts = _law_command(lateral, longitudinal, los, range_estimate, None if excitation is None else level)
    return parts, command, ((rotation, flown, float(thrust), float(thrust_normalized)) if with_setpoint else None)


#: Compiled implementations of a tracking law, by the exact class of its lateral law (see the module).
COMPILED_TRACKING: dict[type, Callable[..., tuple | None]] = {HelicalNavigationGuidance: compiled_hng_tracking}
