"""The one following pipeline: bearing -> estimator -> guidance -> attitude/thrust.

Both harnesses (the in-process simulator and the networked companion app) drive
this same object. It owns no clock: every call says what time it is.
"""

from __future__ import annotations

import dataclasses
import math
import enum
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.core.attitude import _IDENTITY, VehicleLimits, attitude_setpoint_after
from companion.core.control_chain import COMPILED_TRACKING, CompleteLaw, SafeHold, TickInputs, Tracking
from companion.core.cooperative_guidance import SeparationFilter, neighbours_make_range_observable
from companion.core.estimators import CorrectionReport, InitialGuess, TargetEstimator
from companion.core._jit import jit
from companion.core.geometry import E_X, all_finite, clip_kernel, norm
from companion.core.guidance import LateralGuidance, RangeController, RangeExcitation
from companion.core.health import (
    HealthAction,
    HealthActionConfig,
    HealthActionPolicy,
    HealthConfig,
    HealthMonitor,
    HealthReport,
    HealthState,
)
from companion.core.messages import (
    AttitudeSetpoint,
    BearingMeasurement,
    NeighbourState,
    PursuerState,
    TargetEstimate,
    fast_frozen,
)
from companion.core.observability import WindowedObservability
from companion.core.safety import (_NO_HEADING, EnvelopeRecord, SafetyEnvelope, SpeedChangeLatch,
                                   _heading_into_kernel, _heading_setpoint_into_kernel, _limit_closing_into_kernel)
from interfaces.derived_defaults import dropout_min_range, dropout_safe_range, health_min_range

_TIME_EPS = 1e-9

#: k of FollowingPipeline.stop_setpoint's a_d = -k v, 1/s: the pursuer's velocity decays with a 1 s time constant.
STOP_GAIN = 1.0


class TrackMode(str, enum.Enum):
    """How well the pipeline currently knows where the target is.

    tracking: bearings arrive. coasting: none for a while; the estimator predicts and the
    guidance flies on the prediction. degraded: the gap passed the coast limit or the
    prediction got too uncertain; the safe behaviour holds a safe distance on the
    predicted line of sight. reacquiring: bearings are back but disagree with the
    prediction; after `reacquire_bearings` of them in a row the filter is restarted on
    the newest one.
    """

    TRACKING = "tracking"
    COASTING = "coasting"
    DEGRADED = "degraded"
    REACQUIRING = "reacquiring"


@dataclass(frozen=True)
class DropoutPolicy:
    """What the pipeline does when bearings stop and come back (issue: link dropouts).

    coast_after: s without a bearing before the track counts as coasting (a few bearing
    periods). coast_limit: s without a bearing before the safe behaviour takes over.
    max_position_std: m, while coasting the safe behaviour also takes over when the predicted
    target position's standard deviation (sqrt(trace P_pp / 3)) exceeds this.
    safe_range: m, range held in the safe behaviour (no weave, only the range controller
    on the predicted line of sight). min_range: m, never command closing on the target
    while the predicted range minus two standard deviations is below this.
    gate_sigma: a bearing after a gap is accepted when its angle to the predicted line of
    sight is below gate_sigma x the predicted angular standard deviation (prediction and
    bearing noise together). reacquire_bearings: rejected bearings in a row that restart
    the filter on the newest one, at the predicted range with restart_range_std.
    max_jerk: m/s^3, for blend_time s after any change of mode the acceleration command
    moves towards the new law at most this fast, so the vehicle is never handed a step.
    """

    coast_after: float = 0.6
    coast_limit: float = 3.0
    max_position_std: float = 6.0
    safe_range: float = 12.0
    min_range: float = 4.0
    gate_sigma: float = 4.0
    bearing_noise_std: float = 0.01
    reacquire_bearings: int = 2
    restart_range_std: float = 10.0
    max_jerk: float = 15.0
    blend_time: float = 2.0

    def __post_init__(self) -> None:
        if not (0.0 < self.coast_after <= self.coast_limit):
            raise ValueError("need 0 < coast_after <= coast_limit")
        if not (0.0 < self.min_range < self.safe_range):
            raise ValueError("need 0 < min_range < safe_range")
        if self.reacquire_bearings < 1 or self.gate_sigma <= 0.0 or self.max_jerk <= 0.0:
            raise ValueError("reacquire_bearings >= 1, gate_sigma > 0 and max_jerk > 0 are required")


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
    this step did to the filter, if a bearing was given. mode / bearing_age / gated_out /
    reinitialized: the dropout handling (TrackMode). observability: the windowed FIM measure
    of the bearings used (companion.core.observability.WindowedObservability.measure), or None.
    health: the filter-health monitor's latest verdict (companion.core.health), updated at
    each correction; None before the first one. health_action: what the pipeline does about
    it (HealthAction: off when it only reports, nominal, recovering while suspect and acting).
    process_noise_boost: the factor on Q the actions set on the estimator (1 when none).
    health_reinitialized: the actions restarted the estimator on this step's bearing.
    """

    time: float
    setpoint: AttitudeSetpoint | None
    new_setpoint: bool
    estimate: TargetEstimate | None
    guidance: GuidanceTerms | None
    correction: CorrectionReport | None
    mode: TrackMode = TrackMode.TRACKING
    bearing_age: float = 0.0
    gated_out: bool = False
    reinitialized: bool = False
    observability: dict | None = None
    health: HealthReport | None = None
    health_action: HealthAction = HealthAction.OFF
    process_noise_boost: float = 1.0
    health_reinitialized: bool = False


def _output(time, *, setpoint, new_setpoint, estimate, guidance, correction, mode, bearing_age, gated_out,
            reinitialized, observability, health, health_action, process_noise_boost, health_reinitialized) -> PipelineOutput:
    """PipelineOutput(...), every field given in order, without the frozen dataclass's object.__setattr__ per
    field (one is built at every step; by keyword, which is cheaper than pairing names and values)."""
    return fast_frozen(PipelineOutput, time=time, setpoint=setpoint, new_setpoint=new_setpoint, estimate=estimate,
                       guidance=guidance, correction=correction, mode=mode, bearing_age=bearing_age,
                       gated_out=gated_out, reinitialized=reinitialized, observability=observability, health=health,
                       health_action=health_action, process_noise_boost=process_noise_boost,
                       health_reinitialized=health_reinitialized)


@dataclass(frozen=True)
class Cooperation:
    """What the pipeline does with its neighbours, other pursuers following the same target.

    law: a complete cooperative law (companion.core.cooperative_guidance: CircumnavigationGuidance, seed 002
    eq. (10); StandoffTrackingGuidance, seed 004 TOGVF) flown while at least one neighbour is fresh; with
    none, the single-pursuer laws (lateral guidance + range controller) take over again. None: every
    pursuer flies the single-pursuer laws. separation: applied to every command (any mode, any law), so
    pursuers keep min_separation apart (SeparationFilter's guarantee and its limits). weave_min_angle: rad;
    while a fresh neighbour's line of sight to the estimated target is at least this far from ours (a
    triangulation baseline: `neighbours_make_range_observable`), the lateral law flies without its weave
    (`steady_guidance`, HNG with c_Z = c_Y = 0 = PPG, eq. (14)), and weaves again when none is.
    None: always weave. steady_guidance: the lateral law without weave (required with weave_min_angle).
    lone_law: what a pursuer of a cooperative flight (law given) flies while it hears no neighbour: the
    same law on a layer of its own (a larger orbit, companion.assembly.build_cooperation), so that a
    pursuer whose share link is down cannot fly into the orbit of the others, who cannot see it either.
    None: the single-pursuer laws (lateral guidance + range controller).
    """

    law: object | None = None
    separation: SeparationFilter | None = None
    weave_min_angle: float | None = None
    steady_guidance: LateralGuidance | None = None
    lone_law: object | None = None

    def __post_init__(self) -> None:
        if self.weave_min_angle is not None and self.steady_guidance is None:
            raise ValueError("weave_min_angle needs the steady (non-weaving) lateral law")


class FollowingPipeline:
    """u-PLKF + lateral guidance + range controller + attitude mapping, stepped by the caller.

    step(time, pursuer, bearing) runs the estimator's time updates up to `time` at its
    own fixed period, corrects with the bearing if one is given, and recomputes the
    setpoint when a control period has elapsed. Callers step it at least at every
    estimator tick, control tick and bearing arrival.

    los_source: "estimate" steers on (p^_T - p)/|p^_T - p| extrapolated to the control
    time (fresh at every control tick, and lambda^T dp > 0 always, remark 3);
    "measurement" steers on the latest measured bearing, as written in the paper.

    health: the filter-health monitor fed at each correction (default: HealthMonitor with
    its default thresholds, a plausible range from r_d / 4 up).

    actions: what to do while the monitor says suspect (companion.core.health.HealthActionPolicy;
    default: HealthActionConfig() defaults). With act off the monitor only observes and the
    flight is the reporting-only pipeline. With it on, at each correction: the estimator's
    `process_noise_boost` (when it has one) gets the policy's factor; a restart on the bearing
    (remark 3) at the current range estimate with a large along-bearing std when the reasons
    say the range is wrong (rate-limited by the policy); and the guidance excitation at full
    level while suspect: `excitation` when given, else `action_excitation` (a RangeExcitation
    whose low/high thresholds are the policy's: it also keeps the pursuer from stopping while
    sigma_r / r^ is high). `health_action_changes` lists (time, HealthAction);
    `health_reinitializations` counts the restarts the actions made.

    excitation: None (default) flies the lateral law as given (the paper's HNG). A
    RangeExcitation adds its lateral term a_X (perpendicular to the line of sight) to the
    lateral law while the range is poorly observed: level s from the estimate's
    rho = sigma_r / r^ at the control time, s = 1 while the health monitor says suspect.
    Not added in the degraded mode (safe behaviour) nor to a complete law (PD).
    `excitation_level` holds the latest s.

    envelope: the safety envelope applied to every command after the law and the blend, before the
    separation filter (companion.core.safety: the closing speed from a pessimistic range, the heading's
    rate of turn); None flies the laws' commands as they are. `envelope_record` counts the ticks it acted.
    """

    def __init__(
        self,
        estimator: TargetEstimator,
        lateral_guidance: LateralGuidance,
        range_controller: RangeController,
        limits: VehicleLimits,
        initial_guess: InitialGuess,
        control_period: float,
        *,
        los_source: str = "estimate",
        dropout: DropoutPolicy | None = None,
        observability_window: float = 5.0,
        health: HealthMonitor | None = None,
        excitation: RangeExcitation | None = None,
        actions: HealthActionPolicy | None = None,
        action_excitation: RangeExcitation | None = None,
        cooperation: Cooperation | None = None,
        envelope: SafetyEnvelope | None = None,
    ) -> None:
        if control_period <= 0.0:
            raise ValueError("control period must be positive")
        if los_source not in ("estimate", "measurement"):
            raise ValueError(f"los_source must be 'estimate' or 'measurement', not {los_source!r}")
        self.estimator = estimator
        self.lateral_guidance = lateral_guidance
        self.range_controller = range_controller
        self.envelope = envelope
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
        self.dropout = dropout if dropout is not None else DropoutPolicy(
            safe_range=dropout_safe_range(range_controller.desired_range),
            min_range=dropout_min_range(range_controller.desired_range))
        self._safe_controller = dataclasses.replace(range_controller, desired_range=self.dropout.safe_range)
        self.mode = TrackMode.TRACKING
        self._last_bearing_time: float | None = None
        self._rejected_in_row = 0
        self._blend_until = -np.inf
        self._last_command: np.ndarray | None = None
        # (vehicle time s, delay s) of the control loop's late setpoints the harness measured (note_loop_delay)
        self._loop_delays: deque[tuple[float, float]] = deque()
        self.mode_changes: list[tuple[float, TrackMode]] = []
        self.reinitializations = 0
        self.observability = WindowedObservability(observability_window, self.dropout.bearing_noise_std)
        self._observability_measure: dict | None = None
        self._observed_until = -np.inf  # s, the newest bearing in the windowed FIM
        self._extrapolation: tuple[TargetEstimate, float, TargetEstimate] | None = None  # _estimate_at's last
        self.health = health if health is not None else HealthMonitor(
            HealthConfig(min_range=health_min_range(range_controller.desired_range)))
        self._health_report: HealthReport | None = None
        self.excitation = excitation
        self.excitation_level = 0.0
        self.actions = actions if actions is not None else HealthActionPolicy(HealthActionConfig())
        self.action_excitation = action_excitation
        self.health_action = HealthAction.NOMINAL if self.actions.config.act else HealthAction.OFF
        self.health_action_changes: list[tuple[float, HealthAction]] = []
        self.health_reinitializations = 0
        self._process_noise_boost = 1.0
        self.cooperation = cooperation
        # The laws the supervisor chooses from (companion.core.control_chain), built once.
        self._single = Tracking(lateral_guidance, range_controller, "single")
        self._steady = (None if cooperation is None or cooperation.steady_guidance is None
                        else Tracking(cooperation.steady_guidance, range_controller, "steady"))
        self._cooperative = None if cooperation is None or cooperation.law is None else CompleteLaw(cooperation.law, "cooperative")
        self._lone = None if cooperation is None or cooperation.lone_law is None else CompleteLaw(cooperation.lone_law, "lone")
        self._safe_hold = SafeHold(self._safe_controller)
        self._neighbours: tuple = ()
        self.weaving = True
        self.cooperating = False
        self.law_changes: list[tuple[float, str]] = []
        self.link_held = False
        self.envelope_record = EnvelopeRecord()
        self._speed_change = None if envelope is None else SpeedChangeLatch(envelope)

    @property
    def limits(self) -> VehicleLimits:
        """The limits the setpoints are computed with: the airframe's (as set), within the envelope's tilt margin."""
        return self._limits

    @limits.setter
    def limits(self, airframe: VehicleLimits) -> None:
        self._limits = airframe if self.envelope is None else self.envelope.commanded_limits(airframe)

    def set_neighbours(self, neighbours) -> None:
        """The fresh neighbours (companion.core.messages.NeighbourState, the caller filters freshness) the next
        setpoints are computed with; () when none is fresh (single-pursuer following). Each is carried to the
        control time at its own velocity before the laws and the separation filter see it."""
        self._neighbours = tuple(neighbours)

    def stop_setpoint(self, time: float, pursuer: PursuerState) -> AttitudeSetpoint:
        """The setpoint that stops the pursuer where it is, once it has followed (a swarm's end of following, before
        the autopilot lands it: companion.mission): a_d = -k v (k = STOP_GAIN, 1/s; no estimate, no guidance law),
        through the separation filter with the neighbours heard (so that no pursuer brakes into another that has
        stopped or still follows), then eq. (21)-(22) with the last setpoint's heading. time: s; pursuer: its
        state (m, m/s, NED). The setpoint becomes the pipeline's last one."""
        velocity = np.asarray(pursuer.velocity, dtype=float)
        command = -STOP_GAIN * velocity
        separation = None if self.cooperation is None else self.cooperation.separation
        neighbours = self._neighbours_at(time)
        if separation is not None and neighbours:
            command = separation.filter(pursuer.position, velocity, command, neighbours)
        previous = self._setpoint
        heading = E_X if previous is None else np.ascontiguousarray(previous.rotation[:, 0])
        self._last_command = command
        self._setpoint = attitude_setpoint_after(time, command, heading, self.limits, previous)
        return self._setpoint

    def _neighbours_at(self, time: float) -> tuple:
        """The neighbours extrapolated to `time` (s) at constant velocity (their shares are late by the link's
        delay and up to a share period)."""
        if not self._neighbours:
            return ()
        moved = []
        for n in self._neighbours:
            position = n.position + (time - n.time) * n.velocity
            if type(n) is not NeighbourState or not (math.isfinite(time) and all_finite(position)):
                moved.append(NeighbourState(n.ident, time, position, n.velocity))  # checks (ValueError), converts
            else:  # what the constructor builds from a checked neighbour and a finite move, without its checks
                moved.append(fast_frozen(NeighbourState, ident=n.ident, time=time, position=position, velocity=n.velocity))
        return tuple(moved)

    @property
    def engaged_at(self) -> float | None:
        """Time of the first bearing (estimator start, HNG t = 0), s."""
        return self._engaged_at

    def step(self, time: float, pursuer: PursuerState, bearing: BearingMeasurement | None = None) -> PipelineOutput:
        correction = None
        gated_out = reinitialized = health_reinitialized = False
        if self._engaged_at is None:
            if bearing is None:
                return PipelineOutput(time, None, False, None, None, None)
            self.estimator.initialize_on_bearing(bearing, self.initial_guess)
            self._engaged_at = bearing.time
            self._note_bearing(bearing)
            self._observe(bearing)
        else:
            self._advance_estimator(time)
            if bearing is not None:
                correction, gated_out, reinitialized = self._use_bearing(bearing)
                if correction is not None:
                    self._check_health(bearing, pursuer, correction)
                    health_reinitialized = self._act_on_health(bearing, correction)
                elif reinitialized:
                    self.health.restart()
        self._update_mode(time)

        new_setpoint = False
        if time >= self._engaged_at + self._control_ticks * self.control_period - _TIME_EPS:
            self._compute_setpoint(time, pursuer)
            self._control_ticks = math.floor((time - self._engaged_at) / self.control_period + _TIME_EPS) + 1
            new_setpoint = True
        age = time - self._last_bearing_time if self._last_bearing_time is not None else 0.0
        return _output(time, setpoint=self._setpoint, new_setpoint=new_setpoint, estimate=self.estimator.estimate,
                       guidance=self._guidance, correction=correction, mode=self.mode, bearing_age=age,
                       gated_out=gated_out, reinitialized=reinitialized, observability=self._observability_measure,
                       health=self._health_report, health_action=self.health_action,
                       process_noise_boost=self._process_noise_boost, health_reinitialized=health_reinitialized)

    def step_all(self, time: float, pursuer: PursuerState, bearings) -> PipelineOutput:
        """step() once per bearing (in the order given; one step without a bearing when there is none), all at
        `time`: the last output, with new_setpoint True when any of the steps computed one (the setpoint is
        the latest). What every harness calls each tick: when several bearings arrive in one tick, the
        setpoint is computed on the first step and a caller that looked only at the last step's new_setpoint
        would never send it."""
        if not bearings:  # the usual step: no bearing arrived
            return self.step(time, pursuer, None)
        output = None
        new_setpoint = False
        for bearing in bearings:
            output = self.step(time, pursuer, bearing)
            new_setpoint = new_setpoint or output.new_setpoint
        return output if output.new_setpoint == new_setpoint else dataclasses.replace(output, new_setpoint=new_setpoint)

    def _check_health(self, bearing: BearingMeasurement, pursuer: PursuerState, correction: CorrectionReport) -> None:
        """Hand the monitor what this correction computed (it reads, never writes)."""
        estimate = self._estimate_at(bearing.time)
        fim = self._observability_measure
        self._health_report = self.health.update(
            bearing.time, bearing.unit_direction, bearing.pursuer_position, pursuer.velocity,
            estimate.position, estimate.covariance, innovation=correction.innovation,
            innovation_covariance=correction.innovation_covariance, innovation_dof=correction.innovation_dof,
            reinitialized=correction.reinitialized,
            fim_min_eigenvalue=None if fim is None else float(fim["min_eigenvalue"]),
            speed_change_probability=self._speed_change_probability())

    def _speed_change_probability(self) -> float | None:
        """The estimator's model probability on its speed-change models (the IMM's), None for an estimator without
        them: what the monitor's speed_change reason and the envelope's speed-change headway both read."""
        return getattr(self.estimator, "speed_change_probability", None)

    def _act_on_health(self, bearing: BearingMeasurement, correction: CorrectionReport) -> bool:
        """The policy's actions for the verdict just made; True when it restarted the estimator."""
        decision = self.actions.decide(self._health_report, correction.reinitialized)
        if decision.action is not self.health_action:
            self.health_action = decision.action
            self.health_action_changes.append((bearing.time, decision.action))
        if decision.action is HealthAction.OFF:
            return False
        if hasattr(self.estimator, "process_noise_boost"):
            self.estimator.process_noise_boost = decision.process_noise_boost
            self._process_noise_boost = decision.process_noise_boost
        if not decision.reinitialize:
            return False
        self._restart_on_bearing(bearing)
        return True

    def _restart_on_bearing(self, bearing: BearingMeasurement) -> None:
        """The health actions' restart: at the current range estimate (the desired range when that is
        implausible), along-bearing std reinitialize_relative_std x that range."""
        plausible = self.health.config

        def at_range(predicted: float) -> tuple[float, float]:
            distance = predicted if plausible.min_range <= predicted <= plausible.max_range else self.range_controller.desired_range
            return distance, self.actions.config.reinitialize_relative_std * distance

        self._restart_estimator(bearing, at_range)
        self.health.restart()
        self.health_reinitializations += 1

    def _restart_estimator(self, bearing: BearingMeasurement, guess_range: Callable[[float], tuple[float, float]]) -> None:
        """Remark 3 again, on `bearing`: guess_range(predicted range, m) gives the restart's (range, along-bearing
        std), m; the velocity estimate is kept with the initial guess's velocity std, and the estimator's tick
        count restarts at the bearing's time."""
        estimate = self._estimate_at(bearing.time)
        distance, range_std = guess_range(float(np.linalg.norm(estimate.position - bearing.pursuer_position)))
        self.estimator.initialize_on_bearing(bearing, InitialGuess(distance, range_std, estimate.velocity,
                                                                   self.initial_guess.velocity_std))
        self._estimator_ticks = math.floor((bearing.time - self._engaged_at) / self.estimator.period + _TIME_EPS)

    def _use_bearing(self, bearing: BearingMeasurement) -> tuple[CorrectionReport | None, bool, bool]:
        """Correct with a bearing; after a gap, only if it agrees with the prediction (the gate)."""
        if self.mode == TrackMode.TRACKING or self._agrees_with_prediction(bearing):
            self._rejected_in_row = 0
            correction = self.estimator.correct(bearing)
            self._note_bearing(bearing)
            self._observe(bearing)
            return correction, False, False
        self._rejected_in_row += 1
        if self._rejected_in_row < self.dropout.reacquire_bearings:
            self._set_mode(bearing.time, TrackMode.REACQUIRING)
            return None, True, False
        # The prediction is no longer credible: restart along the new bearing at the predicted range.
        self._restart_estimator(bearing, lambda predicted: (predicted, self.dropout.restart_range_std))
        self.reinitializations += 1
        self._rejected_in_row = 0
        self._note_bearing(bearing)
        self._observe(bearing)
        return None, False, True

    def _note_bearing(self, bearing: BearingMeasurement) -> None:
        """The newest bearing used, for the measured line of sight and the bearing age: a late bearing
        (older than one already used) corrects the estimate but does not make the track older. A
        neighbour's bearing (source != 0) keeps the track fresh but is no line of sight from here."""
        if self._last_bearing_time is None or bearing.time >= self._last_bearing_time:
            if bearing.source == 0:
                self._last_bearing = bearing.unit_direction
            self._last_bearing_time = bearing.time

    def _observe(self, bearing: BearingMeasurement) -> None:
        """Feed the windowed FIM (section V, eq. (7)) with a bearing used, at the estimated range."""
        if bearing.time < self._observed_until:
            # A late bearing (a neighbour's share that arrived after newer bearings): it has corrected the
            # estimate; the windowed FIM takes bearings in time order only, so it is left out of it.
            return
        estimate = self._estimate_at(bearing.time)
        distance = norm(estimate.position - bearing.pursuer_position)
        if distance > 1e-6:
            self._observed_until = bearing.time
            self._observability_measure = self.observability.add_and_measure(bearing.time, bearing.unit_direction,
                                                                             distance)

    def line_of_sight_agrees(self, time: float, pursuer_position: np.ndarray, target_position: np.ndarray) -> bool | None:
        """Whether the line of sight from `pursuer_position` to `target_position` (NED m, (3,)) at `time` (s)
        agrees with the estimator's prediction, within the re-acquisition gate (dropout gate_sigma); None
        before engagement or for a degenerate geometry. For the fix validator's re-anchor rule: it reads the
        estimate, never changes it."""
        if self._engaged_at is None:
            return None
        relative = np.asarray(target_position, dtype=float) - np.asarray(pursuer_position, dtype=float)
        distance = norm(relative)  # np.linalg.norm's bits (geometry.norm)
        if not math.isfinite(distance) or distance < 1e-6:
            return None
        return self._agrees_with_prediction(BearingMeasurement(time, relative / distance, np.asarray(pursuer_position, dtype=float)))

    def _agrees_with_prediction(self, bearing: BearingMeasurement) -> bool:
        estimate = self._estimate_at(bearing.time)
        relative = np.ascontiguousarray(estimate.position - bearing.pursuer_position, dtype=float)
        distance = norm(relative)
        if distance < 1e-6:
            return False
        cosine, angular_std = _gate_terms(relative, distance, bearing.unit_direction,
                                          np.ascontiguousarray(estimate.covariance[:3, :3], dtype=float),
                                          self.dropout.bearing_noise_std)
        angle = float(np.arccos(cosine))  # numpy's arccos (its SIMD routine where it has one)
        return angle <= self.dropout.gate_sigma * angular_std

    def link_contested(self, time: float, contested: bool) -> None:
        """The target link's fix validator holds the track (two sources in the target's epoch, neither confirmed:
        companion.core.fix_validator) or no longer does, at `time` s; both harnesses call it when that changes.
        While held no bearing comes, the health monitor says SUSPECT (link_contested) and the pursuer flies
        the safe behaviour (TrackMode.DEGRADED: the dropout policy's safe range on the predicted line of sight)
        at once rather than coast on an estimate the first lies may have touched."""
        contested = bool(contested)
        if contested == self.link_held:
            return
        self.link_held = contested
        self._health_report = self.health.link_contested(time, contested)
        if self._engaged_at is not None:
            self._update_mode(time)

    def _update_mode(self, time: float) -> None:
        if self._last_bearing_time is None:
            return
        if self.link_held:
            self._set_mode(time, TrackMode.DEGRADED)
            return
        gap = time - self._last_bearing_time
        estimate = self.estimator.estimate
        position_std = estimate.position_std
        policy = self.dropout
        if gap >= policy.coast_limit or (gap >= policy.coast_after and position_std > policy.max_position_std):
            mode = TrackMode.DEGRADED
        elif gap >= policy.coast_after:
            # Degraded stays degraded while the bearings stay old, unless they are late but keep the
            # estimate tight (a link with a steady latency above coast_after): then it coasts, with
            # hysteresis (half the std that made it degraded), rather than hold the safe range forever.
            recovered = position_std <= 0.5 * policy.max_position_std
            mode = TrackMode.DEGRADED if self.mode == TrackMode.DEGRADED and not recovered else TrackMode.COASTING
        elif self.mode == TrackMode.REACQUIRING and self._rejected_in_row > 0:
            mode = TrackMode.REACQUIRING
        else:
            mode = TrackMode.TRACKING
        self._set_mode(time, mode)

    def _set_mode(self, time: float, mode: TrackMode) -> None:
        if mode != self.mode:
            self.mode = mode
            self.mode_changes.append((time, mode))
            self._blend_until = time + self.dropout.blend_time

    def _estimate_at(self, time: float) -> TargetEstimate:
        """The estimator's estimate carried to `time` (s) at constant velocity (TargetEstimate.extrapolated); the
        last one is kept while the estimate and the time are the same, since a bearing's FIM, health check and
        setpoint each ask for the same one (a snapshot: the estimator makes a new object when it changes)."""
        estimate = self.estimator.estimate
        memo = self._extrapolation
        if memo is not None and memo[0] is estimate and memo[1] == time and math.copysign(1.0, memo[1]) == math.copysign(1.0, time):
            return memo[2]
        extrapolated = estimate.extrapolated(time)
        self._extrapolation = (estimate, time, extrapolated)
        return extrapolated

    def _advance_estimator(self, time: float) -> None:
        assert self._engaged_at is not None
        period = self.estimator.period
        target_ticks = math.floor((time - self._engaged_at) / period + _TIME_EPS)
        while self._estimator_ticks < target_ticks:
            self.estimator.predict()
            self._estimator_ticks += 1

    def _target_acceleration(self) -> np.ndarray | None:
        """The estimator's target acceleration (m/s^2, (3,)) when it has one (the IMM's turn models, the
        constant-acceleration filter), for the cooperative laws' feed-forward; None otherwise or if not finite."""
        acceleration = getattr(self.estimator, "acceleration", None)
        if acceleration is None:
            return None
        acceleration = np.asarray(acceleration, dtype=float)
        return acceleration if acceleration.shape == (3,) and all_finite(acceleration) else None

    def _choose_law(self, time: float, pursuer: PursuerState, target_position: np.ndarray,
                    neighbours: tuple) -> Tracking | CompleteLaw:
        """The law of this tick (companion.core.control_chain): the cooperative law ('cooperative', a neighbour
        heard), its own layer ('lone', the cooperative law's, nobody heard), the lateral law without weave ('steady',
        a neighbour's line of sight gives a baseline) or the configured laws ('single'); a change is recorded (by
        name) in law_changes and blended like a change of mode (max_jerk for blend_time)."""
        cooperation = self.cooperation
        law = self._single
        if not neighbours:
            if self._cooperative is not None and self._lone is not None:
                law = self._lone
        elif self._cooperative is not None:
            law = self._cooperative
        elif self._steady is not None and cooperation.weave_min_angle is not None and neighbours_make_range_observable(
                pursuer.position, target_position, [n.position for n in neighbours], cooperation.weave_min_angle):
            law = self._steady
        self.cooperating = law is self._cooperative
        current = self.law_changes[-1][1] if self.law_changes else self._single.name
        if law.name != current:
            self.law_changes.append((time, law.name))
            self._blend_until = time + self.dropout.blend_time
        self.weaving = law is self._single
        return law

    def _excitation_in_force(self) -> RangeExcitation | None:
        """The excitation the lateral law gets this tick: the configured one, else the health actions' own while
        they act and may excite (full while suspect, and never a stop while sigma_r / r^ is high: the action
        excitation's own low/high thresholds), else None."""
        if self.excitation is not None:
            return self.excitation
        if self.action_excitation is not None and self.health_action is not HealthAction.OFF and self.actions.config.excite:
            return self.action_excitation
        return None

    def _compute_setpoint(self, time: float, pursuer: PursuerState) -> None:
        """One control tick's chain (companion.core.control_chain): the supervisor's law (the safe hold in the
        degraded mode), then keep-off, blend, the safety envelope and separation, then the attitude mapping."""
        assert self._engaged_at is not None
        estimate = self._estimate_at(time)
        neighbours = self._neighbours_at(time)
        chosen = self._choose_law(time, pursuer, estimate.position, neighbours)
        law = self._safe_hold if self.mode == TrackMode.DEGRADED else chosen
        cooperation = self.cooperation
        # The command's adjustments this tick, decided before the command (none depends on it). Keep off
        # min_range: in any mode but tracking, while recovering (the estimate is judged wrong, so its range cannot
        # be trusted to close on) and under a law that does not make the range observable (a cooperative law does
        # not weave: its range may never have been). Blend: within blend_time of a change of mode or law.
        # Separate: with neighbours heard.
        keep_off = (self.mode != TrackMode.TRACKING or self.health_action is HealthAction.RECOVERING
                    or not chosen.observes_range)
        blend = self._last_command is not None and time < self._blend_until
        separate = cooperation is not None and cooperation.separation is not None and bool(neighbours)
        report = self._health_report
        tick = fast_frozen(
            TickInputs, time=time, engaged_time=time - self._engaged_at, estimate=estimate,
            position=np.asarray(pursuer.position, dtype=float), velocity=np.asarray(pursuer.velocity, dtype=float),
            measured_los=self._last_bearing if self.los_source == "measurement" else None,
            excitation=self._excitation_in_force(), suspect=report is not None and report.state == HealthState.SUSPECT,
            neighbours=neighbours, target_acceleration=self._target_acceleration() if isinstance(law, CompleteLaw) else None)
        compiled = COMPILED_TRACKING.get(type(law.lateral)) if isinstance(law, Tracking) else None
        outcome = None
        if compiled is not None:
            # The tracking law and, when no limiter acts, the attitude mapping in kernels: the same arithmetic.
            previous = self._setpoint
            outcome = compiled(law, tick, self.limits.setpoint_terms,
                               not (keep_off or blend or separate or self.envelope is not None),
                               None if previous is None else previous.rotation)
        if outcome is not None:
            parts, command, compiled_setpoint = outcome
        else:
            parts, compiled_setpoint = law.command(tick), None
            command = parts.lateral + parts.longitudinal
        if parts.excitation_level is not None:
            self.excitation_level = parts.excitation_level
        lateral, longitudinal, los, range_estimate = parts.lateral, parts.longitudinal, parts.los, parts.range_estimate
        if keep_off:
            range_std = float(np.sqrt(max(los @ estimate.covariance[:3, :3] @ los, 0.0)))
            closing = float(command @ los)
            if range_estimate - 2.0 * range_std < self.dropout.min_range and closing > 0.0:
                command = command - closing * los  # never close on an uncertain target below min_range
        if blend:
            step_limit = self.dropout.max_jerk * self.control_period
            change = command - self._last_command
            size = norm(change)
            if size > step_limit:
                command = self._last_command + change * (step_limit / size)
        heading = None
        if self.envelope is not None:
            # The target's velocity is counted on while bearings keep the estimate tight (tracking, or coasting
            # through a steady latency), not on a prediction alone (degraded, reacquiring).
            trusted = self.mode in (TrackMode.TRACKING, TrackMode.COASTING)
            command, heading = self._within_envelope(time, command, los, range_estimate, estimate, pursuer, trusted)
        if separate:
            # Last, so that no mode, law or blend can undo it.
            command = cooperation.separation.filter(pursuer.position, pursuer.velocity, command, neighbours)
        self._last_command = command
        if compiled_setpoint is not None:  # the compiled tick's setpoint of this same command
            rotation, flown, thrust, thrust_normalized = compiled_setpoint
            self._setpoint = fast_frozen(AttitudeSetpoint, time=time, rotation=rotation,
                                         thrust_normalized=thrust_normalized, thrust=thrust, acceleration=flown)
        elif heading is not None:  # the envelope's heading, exactly (safety.heading_axis)
            previous = self._setpoint
            rotation, flown = np.empty((3, 3)), np.empty(3)
            thrust, thrust_normalized = _heading_setpoint_into_kernel(
                command, heading, _IDENTITY if previous is None else previous.rotation, self.limits.setpoint_terms,
                rotation, flown)
            self._setpoint = fast_frozen(AttitudeSetpoint, time=time, rotation=rotation,
                                         thrust_normalized=float(thrust_normalized), thrust=float(thrust),
                                         acceleration=flown)
        else:  # heading fallback: the previous setpoint's r1
            self._setpoint = attitude_setpoint_after(time, command, los, self.limits, self._setpoint)
        self._guidance = fast_frozen(GuidanceTerms, lateral=lateral, longitudinal=longitudinal, los=los,
                                     range_estimate=range_estimate)

    def note_loop_delay(self, time: float, delay: float) -> None:
        """The networked harness measured its control loop `delay` s late at vehicle time `time` (s): the vehicle
        time from the state one setpoint was computed from to the newest state when the next went out, beyond the
        control period. The safety envelope adds the largest delay of the last loop_delay_memory s to its
        reaction time (companion.core.safety, rule 1); a delay that is not finite or not above 0 is not kept, nor
        any without an envelope or with its loop_delay_memory 0."""
        envelope = self.envelope
        if envelope is None or envelope.loop_delay_memory <= 0.0:
            return
        if math.isfinite(time) and math.isfinite(delay) and delay > 0.0:
            self._loop_delays.append((time, delay))
            self._forget_loop_delays(time)  # so that at most memory / control period are kept

    def _forget_loop_delays(self, time: float) -> None:
        """Drop the loop delays noted more than the envelope's loop_delay_memory before `time` (s)."""
        delays, oldest = self._loop_delays, time - self.envelope.loop_delay_memory
        while delays and delays[0][0] < oldest:
            delays.popleft()

    def _loop_delay(self, time: float) -> float:
        """The largest loop delay noted within the envelope's loop_delay_memory before `time` (s), 0 for none."""
        self._forget_loop_delays(time)
        return max((delay for _, delay in self._loop_delays), default=0.0)

    def _within_envelope(self, time: float, command: np.ndarray, los: np.ndarray, range_estimate: float,
                         estimate: TargetEstimate, pursuer: PursuerState, trusted: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """The command (m/s^2, (3,)) within the safety envelope, and the horizontal heading for R_d (None before the
        first setpoint with a vertical line of sight: lambda then): companion.core.safety, its closing-speed rule from
        this estimate's sigma_r and sigma_v along the line of sight, the target's velocity counted only when
        `trusted`; with the envelope's speed_change_latency, planned with it while the target has lately changed
        speed; with its hover_standoff, min_range raised while the target is slow. Counts the ticks it acted in envelope_record."""
        envelope, record = self.envelope, self.envelope_record
        terms = envelope.kernel_terms
        if envelope.speed_change_latency > 0.0 and self._speed_change.holds(
                time, self._speed_change_probability(), estimate.velocity, self.control_period):
            terms = envelope.speed_change_terms
            record.speed_change_seconds += self.control_period
        if envelope.hover_standoff > 0.0:
            terms, raised = envelope.hover_terms(terms, estimate.velocity)
            if raised:
                record.hover_seconds += self.control_period
        delay = self._loop_delay(time)
        if delay > 0.0:
            terms = envelope.delayed_terms(terms, delay)
            record.loop_delay_seconds += self.control_period
            record.loop_delay_max = max(record.loop_delay_max, delay)
        heading_los = los
        if self._last_bearing is not None and time - self._last_bearing_time < self.dropout.coast_after:
            los = self._last_bearing  # the measured line of sight while fresh: a measurement, not the estimate
        limited = np.empty(3)
        if _limit_closing_into_kernel(command, los, np.asarray(pursuer.velocity, dtype=float), estimate.covariance,
                                      estimate.velocity, float(range_estimate), trusted, terms, limited):
            command = limited
            record.closing_ticks += 1
            record.closing_seconds += self.control_period
        previous = self._setpoint
        heading = np.empty(3)
        state = _heading_into_kernel(heading_los, _NO_HEADING if previous is None else previous.rotation[:, 0],
                                     0.0 if previous is None else time - previous.time, envelope.max_yaw_rate, heading)
        if state == 2:
            record.heading_ticks += 1
            record.heading_seconds += self.control_period
        return command, (heading if state else None)


@jit
def _gate_terms(relative: np.ndarray, distance: float, measured: np.ndarray, position_covariance: np.ndarray,
                bearing_noise_std: float) -> tuple[float, float]:
    """The re-acquisition gate's terms (FollowingPipeline._agrees_with_prediction): the cosine between the
    predicted line of sight relative / distance and the measured unit bearing, clipped to [-1, 1], and the
    angular std sqrt(tr(P_perp P_pp P_perp) / (2 r^2) + sigma^2) (rad), P_perp = I - lambda lambda^T; numpy's
    operations in numpy's order (np.clip, the two matrix products, the trace summed left to right, Python's
    ** for r^2 and sigma^2). relative (3,), m; distance r, m; measured (3,); P_pp (3, 3), m^2; sigma rad."""
    predicted = relative / distance
    cosine = clip_kernel(predicted @ measured, -1.0, 1.0)
    across = np.eye(3) - np.outer(predicted, predicted)
    spread = across @ position_covariance @ across
    lateral_variance = (spread[0, 0] + spread[1, 1] + spread[2, 2]) / 2.0
    variance = lateral_variance / distance ** 2 + bearing_noise_std ** 2
    return cosine, (math.sqrt(variance) if variance >= 0.0 else math.nan)  # np.sqrt: NaN below 0
