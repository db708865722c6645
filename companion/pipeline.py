"""The one following pipeline: bearing -> estimator -> guidance -> attitude/thrust.

Both harnesses (the in-process simulator and the networked companion app) drive
this same object. It owns no clock: every call says what time it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.attitude import VehicleLimits, attitude_setpoint
from companion.estimators import CorrectionReport, InitialGuess, TargetEstimator
from companion.geometry import unit
from companion.guidance import LateralGuidance, RangeController
from companion.messages import AttitudeSetpoint, BearingMeasurement, PursuerState, TargetEstimate

_TIME_EPS = 1e-9


@dataclass(frozen=True)
class GuidanceTerms:
    """The parts of the acceleration command, eq. (13): a_d = a_HN + a_RC (m/s^2, shape (3,)).

    los: the unit line of sight guidance used. range_estimate: |p^_T - p|, m.
    """

    lateral: np.ndarray
    longitudinal: np.ndarray
    los: np.ndarray
    range_estimate: float


@dataclass(frozen=True)
class PipelineOutput:
    """Result of one pipeline step.

    setpoint: the latest attitude/thrust setpoint (held between control ticks), or
    None before the first bearing. new_setpoint: whether this step computed it.
    estimate: the estimator's state at its latest tick (None before the first bearing).
    guidance: the terms of the latest setpoint. correction: what the bearing of
    this step did to the filter, if a bearing was given.
    """

    time: float
    setpoint: AttitudeSetpoint | None
    new_setpoint: bool
    estimate: TargetEstimate | None
    guidance: GuidanceTerms | None
    correction: CorrectionReport | None


class FollowingPipeline:
    """u-PLKF + lateral guidance + range controller + attitude mapping, stepped by the caller.

    step(time, pursuer, bearing) runs the estimator's time updates up to `time` at its
    own fixed period, corrects with the bearing if one is given, and recomputes the
    setpoint when a control period has elapsed. Callers step it at least at every
    estimator tick, control tick and bearing arrival.

    los_source: "estimate" steers on (p^_T - p)/|p^_T - p| extrapolated to the control
    time (fresh at every control tick, and lambda^T dp > 0 always, remark 3);
    "measurement" steers on the latest measured bearing, as written in the paper.
    """

    def __init__(
        self,
        estimator: TargetEstimator,
        lateral_guidance: LateralGuidance,
        range_controller: RangeController,
        limits: VehicleLimits,
        initial_guess: InitialGuess,
        control_period: float,
        los_source: str = "estimate",
    ) -> None:
        if control_period <= 0.0:
            raise ValueError("control period must be positive")
        if los_source not in ("estimate", "measurement"):
            raise ValueError(f"los_source must be 'estimate' or 'measurement', not {los_source!r}")
        self.estimator = estimator
        self.lateral_guidance = lateral_guidance
        self.range_controller = range_controller
        self.limits = limits
        self.initial_guess = initial_guess
        self.control_period = float(control_period)
        self.los_source = los_source
        self._engaged_at: float | None = None
        self._estimator_ticks = 0
        self._control_ticks = 0
        self._last_bearing: np.ndarray | None = None
        self._setpoint: AttitudeSetpoint | None = None
        self._guidance: GuidanceTerms | None = None

    @property
    def engaged_at(self) -> float | None:
        """Time of the first bearing (estimator start, HNG t = 0), s."""
        return self._engaged_at

    def step(self, time: float, pursuer: PursuerState, bearing: BearingMeasurement | None = None) -> PipelineOutput:
        correction = None
        if self._engaged_at is None:
            if bearing is None:
                return PipelineOutput(time, None, False, None, None, None)
            self.estimator.initialize_on_bearing(bearing, self.initial_guess)
            self._engaged_at = bearing.time
            self._last_bearing = unit(bearing.direction)
        else:
            self._advance_estimator(time)
            if bearing is not None:
                correction = self.estimator.correct(bearing)
                self._last_bearing = unit(bearing.direction)

        new_setpoint = False
        if time >= self._engaged_at + self._control_ticks * self.control_period - _TIME_EPS:
            self._compute_setpoint(time, pursuer)
            self._control_ticks = int(np.floor((time - self._engaged_at) / self.control_period + _TIME_EPS)) + 1
            new_setpoint = True
        return PipelineOutput(time, self._setpoint, new_setpoint, self.estimator.estimate, self._guidance, correction)

    def _advance_estimator(self, time: float) -> None:
        assert self._engaged_at is not None
        period = self.estimator.period
        target_ticks = int(np.floor((time - self._engaged_at) / period + _TIME_EPS))
        while self._estimator_ticks < target_ticks:
            self.estimator.predict()
            self._estimator_ticks += 1

    def _compute_setpoint(self, time: float, pursuer: PursuerState) -> None:
        assert self._engaged_at is not None
        estimate = self.estimator.estimate.extrapolated(time)
        relative_position = estimate.position - pursuer.position
        relative_velocity = estimate.velocity - pursuer.velocity
        range_estimate = float(np.linalg.norm(relative_position))
        if self.los_source == "measurement" and self._last_bearing is not None:
            los = self._last_bearing
        else:
            los = relative_position / max(range_estimate, 1e-9)
        lateral = self.lateral_guidance.acceleration(time - self._engaged_at, pursuer.velocity, los, range_estimate)
        longitudinal = self.range_controller.acceleration(relative_position, relative_velocity, los, lateral)
        heading_fallback = None if self._setpoint is None else self._setpoint.rotation[:, 0]
        self._setpoint = attitude_setpoint(time, lateral + longitudinal, los, self.limits, heading_fallback)
        self._guidance = GuidanceTerms(lateral, longitudinal, los, range_estimate)
