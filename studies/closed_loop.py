"""In-process closed-loop simulator: plant + target + bearing sensor + the companion pipeline.

Deterministic for a seed, no network, no wall clock. The loop reads like the block
diagram of the paper's Fig. 2:

    target.step -> bearing sensor -> pipeline.step (estimator, guidance, attitude map)
    -> autopilot (attitude controller, mixer) -> quadrotor.step
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from companion.assembly import build_sensor, build_pipeline
from companion.core.bearing_sensor import BearingSensor
from interfaces.scenario import Scenario, VehicleConfig
from companion.core.fix_validator import FixRejected, FixValidator
from companion.fix_intake import FixIntake, build_fix_validator
from interfaces.link_schema import MAX_EPOCH, TargetFix, encode_target_fix
from companion.core.geometry import norm
from companion.core.messages import BearingMeasurement, pursuer_state
from companion.core.health import REASONS, HealthAction, HealthState
from companion.core.pipeline import TrackMode
from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle
from sitl_plant.vehicle.params import QuadrotorParams, quadrotor_params
from sitl_plant.vehicle.quadrotor import RigidBodyState
from sitl_plant.world.link_faults import LinkFaults, fault_rng
from sitl_plant.world.target import TargetMotion, target_from_config
from studies.metrics import summarize


class Termination(enum.Enum):
    """Why a flight ended (in process or in SITL); the value is a sentence for people. summary.json's
    "termination" is the lower-case name (studies.metrics.termination_name)."""

    COMPLETED = "flew the whole scenario"
    ESTIMATE_NOT_FINITE = "estimator state became NaN or infinite"
    OUT_OF_CONTROL = "out of control: tilted past 90 degrees, faster than 60 m/s, or its state no longer finite"
    ABORTED = "aborted by the ground station's command: held, then landed"
    FAILSAFE = "the companion stopped commanding before the end; the autopilot's failsafe was left in charge"
    INTERRUPTED = "interrupted (a stop signal or the wall-clock timeout); every process was stopped"
    DIVERGED = "flew the whole scenario, but the health monitor called the estimate suspect at the end"


#: track_mode column of the flight log: the pipeline's TrackMode as a number.
TRACK_MODE_CODES = {TrackMode.TRACKING: 0, TrackMode.COASTING: 1, TrackMode.DEGRADED: 2, TrackMode.REACQUIRING: 3}
#: health_reasons column of the flight log: bit i set when companion.core.health.REASONS[i] counts.
HEALTH_REASON_BITS = {reason: 1 << bit for bit, reason in enumerate(REASONS)}
#: health_action column of the flight log: what the pipeline does about the verdict (companion.core.health.HealthAction).
HEALTH_ACTION_CODES = {HealthAction.OFF: 0, HealthAction.NOMINAL: 1, HealthAction.RECOVERING: 2}

MAX_SPEED = 60.0  # m/s, far above anything the Table I vehicle can reach with 1.5 g of thrust


class FlightLog:
    """Time series of one flight, one row per loop tick, preallocated.

    Raw columns are written in the loop; derived ones (range, tilt, heading error...)
    are computed vectorised by `series()`. Rows before the estimator starts hold NaN.
    """

    _WIDTHS = {
        "time": 1, "pursuer_position": 3, "pursuer_velocity": 3, "pursuer_forward": 3, "pursuer_down_z": 1,
        "target_position": 3, "target_velocity": 3, "estimate_position": 3, "estimate_velocity": 3,
        "estimate_position_std": 1, "command_acceleration": 3, "thrust_normalized": 1, "track_mode": 1, "bearing_age": 1,
        "observability_log_det": 1, "observability_min_eigenvalue": 1,
        "health_suspect": 1, "health_reasons": 1, "health_nis_ratio": 1, "health_relative_range_std": 1,
        "health_action": 1, "process_noise_boost": 1, "health_reinitialized": 1,
        "model_probabilities": 3,  # IMM estimator only: (straight, right turn, left turn), IMMEstimator.motion_probabilities
        "pursuer_rotation": 9,  # body FRD -> NED, row by row
        "estimate_position_covariance": 6,  # the estimate's position covariance, upper triangle (xx, xy, xz, yy, yz, zz), m^2
        "bearing_direction": 3,  # the last own bearing given to the estimator at this tick (NaN: none)
    }

    _WIDTH = sum(_WIDTHS.values())
    #: A row as the bytes of its float64s in the machine's order: struct's packing of a row of Python floats is
    #: about a third cheaper than numpy's conversion of the same list (the same float64s, NaN payloads included).
    _ROW = struct.Struct(f"={_WIDTH}d")

    def __init__(self, rows: int) -> None:
        # One table, a row per tick (`_log_row` writes a whole row in one assignment); each column is a view of it.
        # The table lives in a bytearray so that a row can be written as bytes (_log_row); NaN until written.
        self._bytes = bytearray(rows * self._ROW.size)
        self._table = np.frombuffer(self._bytes, dtype=np.float64).reshape(rows, self._WIDTH)
        self._table[:] = np.nan
        self._data = {}
        start = 0
        for key, width in self._WIDTHS.items():
            self._data[key] = self._table[:, start:start + width]
            start += width
        self.rows = 0

    def append(self, **values: object) -> None:
        row = self.rows
        for key, value in values.items():
            self._data[key][row] = value
        self.rows += 1

    def series(self) -> dict[str, np.ndarray]:
        """All columns trimmed to the rows written, plus the derived ones; (N,) or (N, 3)."""
        # copies: contiguous columns of their own (the table's columns are strided views)
        out = {key: (array[: self.rows, 0] if array.shape[1] == 1 else array[: self.rows]).copy() for key, array in self._data.items()}
        relative = out["target_position"] - out["pursuer_position"]
        out["range"] = np.linalg.norm(relative, axis=1)
        out["range_estimate"] = np.linalg.norm(out["estimate_position"] - out["pursuer_position"], axis=1)
        out["pursuer_tilt"] = np.degrees(np.arccos(np.clip(out["pursuer_down_z"], -1.0, 1.0)))
        forward, los = out["pursuer_forward"][:, :2], relative[:, :2]
        norms = np.linalg.norm(forward, axis=1) * np.linalg.norm(los, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cosine = np.where(norms > 1e-9, np.einsum("ij,ij->i", forward, los) / norms, np.nan)
        out["heading_error"] = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
        return out


@dataclass(frozen=True)
class SimulationResult:
    """A finished flight: its series (see FlightLog), the summary and why it ended."""

    scenario: Scenario
    series: dict[str, np.ndarray]
    summary: dict
    termination: Termination


def _initial_state(scenario: Scenario, params: QuadrotorParams) -> RigidBodyState:
    hover = RigidBodyState.hover(params, np.array(scenario.pursuer.initial_position))
    return RigidBodyState(hover.position, np.array(scenario.pursuer.initial_velocity), hover.rotation, hover.angular_velocity, hover.rotor_speeds)


def simulate(scenario: Scenario, vehicle: VehicleConfig, seed: int | None = None) -> SimulationResult:
    """Fly one scenario in process. seed overrides scenario.simulation.seed."""
    seed = scenario.simulation.seed if seed is None else seed
    # The third stream (range noise) leaves the first two exactly as they were without it.
    plant_rng, sensor_rng, range_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    link = InProcessLink(scenario, seed)
    params = quadrotor_params(vehicle)
    autopilot = AttitudeThrustVehicle(params, _initial_state(scenario, params), scenario.simulation.physics_rate_hz, plant_rng)
    target = target_from_config(scenario.target, seed)
    pipeline = build_pipeline(scenario, vehicle, params.hover_thrust_normalized)
    sensor = build_sensor(scenario.sensor)

    physics_hz = scenario.simulation.physics_rate_hz
    every = {
        "estimator": round(physics_hz / scenario.estimator.rate_hz),
        "control": round(physics_hz / scenario.guidance.rate_hz),
        "sensor": round(physics_hz / scenario.sensor.rate_hz),
    }
    dt = 1.0 / physics_hz
    total_steps = round(scenario.simulation.duration * physics_hz)
    # The loop visits only the physics steps where something happens (a bearing, an
    # estimator tick, a control tick); the plant runs on its own fixed step in between.
    event_steps = sorted({step for period in every.values() for step in range(0, total_steps + 1, period)})
    log = FlightLog(len(event_steps))
    termination = Termination.COMPLETED
    bearings_used = 0
    bearings_out_of_view = 0

    sensor_every = every["sensor"]
    last_index = len(event_steps) - 1
    max_speed_squared = MAX_SPEED**2
    for index, step in enumerate(event_steps):
        time = step * dt
        # The true state as tuples (autopilot.kinematics(): the values of autopilot.state, without its arrays).
        position, velocity, rotation = autopilot.kinematics()
        vx, vy, vz = velocity  # |v|^2 summed left to right (what numpy's dot of three gave here, to the bit)
        speed_squared = vx * vx + vy * vy + vz * vz
        if index and not (speed_squared <= max_speed_squared and math.isfinite(_sum3(position) + sum(rotation))):
            # Lost since the last tick: faster than MAX_SPEED, or the airframe's integration blew up (a stiff
            # attitude loop, e.g. a tiny inertia against long arms, gave 1e196 m/s or NaN within one tick). Logged
            # with the last tick's commands; the companion's vector maths never sees a state it cannot use.
            termination = Termination.OUT_OF_CONTROL
            _log_row(log, time, position, velocity, rotation, target, output, pipeline.estimator,
                     estimate_values=estimate_values, bearings=[])
            break
        measured_position, measured_velocity = autopilot.measured_state()
        pursuer = pursuer_state(time, measured_position, measured_velocity)  # PursuerState(...), see there
        bearings = []
        if link.enabled:
            # Fixes go through the fault model and the validator, as over the real link; the
            # bearing is then taken at each delivered fix's time from the pursuer's state then.
            if step % sensor_every == 0:
                # The true position and attitude as autopilot.state holds them (the same arrays of the same floats)
                link.offer(time, target.position, target.velocity, np.array(position), np.array(rotation).reshape(3, 3),
                           measured_position)
            for stamp, fix_position, sample in link.deliver(time, pipeline):
                bearing = _measure(sensor, stamp, fix_position - sample.true_position, sample.rotation,
                                   sample.measured_position, sensor_rng, range_rng)
                if bearing is None:
                    bearings_out_of_view += 1
                else:
                    bearings.append(bearing)
            pipeline.link_contested(time, link.validator.contested)
        elif step % sensor_every == 0:
            # The camera sees through the vehicle's true attitude; outside its field of view no bearing comes.
            bearing = _measure(sensor, time, target.position - np.array(position), np.array(rotation).reshape(3, 3),
                               measured_position, sensor_rng, range_rng)
            if bearing is None:
                bearings_out_of_view += 1
            else:
                bearings.append(bearing)
        bearings_used += len(bearings)
        output = pipeline.step_all(time, pursuer, bearings)
        if output.new_setpoint and output.setpoint is not None:
            # The autopilot side: attitude in, normalised thrust scaled by its own maximum.
            # (The networked harness sends the same attitude as a quaternion.)
            autopilot.set_attitude_target(output.setpoint.rotation, output.setpoint.thrust_normalized * params.max_total_thrust)

        estimate = output.estimate
        if estimate is not None:
            # The estimate's six numbers as floats, read once for this check and the log row. The check: the sum of
            # the three positions plus that of the three velocities (_sum3's order: what ndarray.sum of three adds).
            estimate_values = estimate.position.tolist() + estimate.velocity.tolist()
            e0, e1, e2, e3, e4, e5 = estimate_values
            if not math.isfinite((e0 + e1 + e2) + (e3 + e4 + e5)):
                termination = Termination.ESTIMATE_NOT_FINITE
        else:
            estimate_values = None
        down_z = rotation[8]
        if down_z < 0.0 or speed_squared > max_speed_squared:
            termination = Termination.OUT_OF_CONTROL
        _log_row(log, time, position, velocity, rotation, target, output, pipeline.estimator,
                 estimate_values=estimate_values, bearings=bearings)
        if termination is not Termination.COMPLETED or index == last_index:
            break
        gap = (event_steps[index + 1] - step) * dt
        target.step(gap)
        autopilot.advance(gap)

    series = log.series()
    summary = summarize(series, scenario, termination, vehicle)
    summary["bearings_used"] = bearings_used
    summary["bearings_out_of_view"] = bearings_out_of_view
    summary["track_mode_changes"] = [(round(t, 3), mode.value) for t, mode in pipeline.mode_changes]
    summary["reinitializations"] = pipeline.reinitializations
    summary["health_transitions"] = [(round(t, 3), state.value, list(reasons))
                                     for t, state, reasons in pipeline.health.transitions]
    summary["health_reasons_at_end"] = list(pipeline.health.episode_reasons)
    summary["health_actions"] = health_actions_summary(pipeline)
    summary["envelope"] = pipeline.envelope_record.as_dict()  # how often the safety envelope acted
    if link.enabled:
        summary["link"] = link.summary()
        summary["fault_events"] = [(round(e.time, 3), e.kind, e.detail) for e in link.faults.events]
    summary["seed"] = seed
    return SimulationResult(scenario, series, summary, termination)


def _sum3(values: list[float]) -> float:
    """values[0] + values[1] + values[2]: what ndarray.sum gives for three float64 (left to right, no pairwise
    split below eight), without its call."""
    return values[0] + values[1] + values[2]


def health_actions_summary(pipeline) -> dict:
    """What the health actions did in a flight (companion.core.health.HealthActionPolicy): act (on/off),
    reinitializations (restarts on the bearing they made), episodes (SUSPECT episodes acted on), recoveries
    (of those, ended OK again), changes [(time s, action)]."""
    policy = pipeline.actions
    return {"act": policy.config.act, "reinitializations": pipeline.health_reinitializations,
            "episodes": policy.episodes, "recoveries": policy.recoveries,
            "changes": [(round(t, 3), action.value) for t, action in pipeline.health_action_changes]}


def _measure(sensor: BearingSensor, time: float, line_of_sight: np.ndarray, rotation: np.ndarray,
             measured_position: np.ndarray, sensor_rng: np.random.Generator,
             range_rng: np.random.Generator) -> BearingMeasurement | None:
    """The bearing (and range, with a range sensor) of the true line of sight; None when not seen.

    The noise-free direction rides along as true_direction for the simulation-only
    "optimal u-PLKF" benchmark (section VIII-B); every other estimator ignores it.
    At zero range (the pursuer on the target) there is no direction: no bearing, as the
    companion's bearing builder gives none (too_close).
    """
    distance = norm(line_of_sight)  # np.linalg.norm's sqrt(x . x), without its wrapper
    if distance == 0.0:
        return None
    true_direction = line_of_sight / distance
    direction = sensor.measure(true_direction, sensor_rng, rotation, true_range=distance)
    if direction is None:
        return None
    return _bearing(time, direction, measured_position, sensor.measure_range(distance, range_rng), true_direction)


def _bearing(time: float, direction: np.ndarray, pursuer_position, range_: float | None,
             true_direction: np.ndarray) -> BearingMeasurement:
    """BearingMeasurement(time, direction, pursuer_position, range_, true_direction) (source 0: the own sensor),
    built as messages.pursuer_state builds its message: the same object, field for field and in the
    constructor's order, without the frozen dataclass's setattr per field. tests/test_link_sensor_costs.py
    checks it against the constructor."""
    instance = object.__new__(BearingMeasurement)
    fields = instance.__dict__
    fields["time"] = time
    fields["direction"] = direction
    fields["pursuer_position"] = pursuer_position
    fields["range"] = range_
    fields["true_direction"] = true_direction
    fields["source"] = 0
    return instance


class _Sample(NamedTuple):
    """The pursuer at an offered fix's time: true position m (NED), attitude R ((3, 3) body -> NED), measured
    position (a named tuple: immutable, and cheaper to build at every offered fix than a frozen dataclass)."""

    true_position: np.ndarray
    rotation: np.ndarray
    measured_position: np.ndarray


class InProcessLink:
    """The target link of the in-process simulator when [faults] injects something: fixes are
    encoded as on the real link (local NED frame), pass LinkFaults, and are checked by the same
    FixValidator as the companion's (now = the loop time; the re-anchor rule asks the pipeline
    whether a fix's line of sight agrees with its prediction). The pursuer's state at each fix
    time is kept so a late fix gives the bearing of its own time. The publisher's epoch is
    drawn from the seed (its own stream), so a flight is reproducible."""

    def __init__(self, scenario: Scenario, seed: int) -> None:
        self.faults = LinkFaults(scenario.faults, fault_rng(scenario.faults, seed))
        self.enabled = self.faults.enabled
        self.sender = scenario.link.target_sender
        self.epoch = int(np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xE90C,))).integers(
            0, MAX_EPOCH, endpoint=True))
        self.validator: FixValidator = build_fix_validator(scenario.link)
        self.intake = FixIntake(self.validator, scenario.sitl.home)
        self._seq = 0
        self._samples: dict[int, _Sample] = {}
        self._rate = scenario.sensor.rate_hz
        self.offered = 0
        self.delivered = 0
        # Which deliveries are the genuine target's (the first delivery of a fix as offered) and which are
        # someone else's (attacks, replays, copies): for the attack campaign's lockout and intruder figures.
        self._offered: dict[int, np.ndarray] = {}
        self.genuine = GenuineRecord()

    def offer(self, time: float, position: np.ndarray, velocity: np.ndarray, true_position: np.ndarray,
              rotation: np.ndarray, measured_position: np.ndarray) -> None:
        """Publish the target's fix of `time` (s; position m, velocity m/s, NED) through the fault model, and keep
        the pursuer's sample then: its true position (m, NED), attitude R ((3, 3) body -> NED) and measured position."""
        fix = TargetFix(self.sender, self._seq, time, "ned", position, velocity, self.epoch)
        payload = encode_target_fix(fix)
        self._seq += 1
        key = round(time * self._rate)
        self._samples[key] = _Sample(true_position, rotation, measured_position)
        self._samples.pop(key - round(30.0 * self._rate), None)  # keep 30 s for stale fixes
        self._offered[key] = np.asarray(position, dtype=float).copy()
        self._offered.pop(key - round(30.0 * self._rate), None)
        self.faults.offer(time, payload, time, fix)  # the fix too: the attack model need not decode the payload
        self.offered += 1

    def deliver(self, time: float, pipeline=None):
        """(stamp, NED position, pursuer sample at the stamp) of each valid fix due now (s); pipeline: the
        FollowingPipeline whose predicted line of sight the validator's re-anchor rule consults."""
        payloads = self.faults.due(time)
        if not payloads:  # most ticks
            return

        def agrees(position: np.ndarray, stamp: float) -> bool | None:
            sample = self._samples.get(round(stamp * self._rate))
            if pipeline is None or sample is None:
                return None
            return pipeline.line_of_sight_agrees(stamp, sample.measured_position, position)

        for payload in payloads:
            self.delivered += 1
            # intake.check(payload) in its two steps, so that the payload is decoded once: by intake.decode
            # (a payload it refuses is counted there), for both _origin's bookkeeping and the validator.
            try:
                fix = self.intake.decode(payload)
            except FixRejected:
                self.genuine.note(time, None, False, math.nan)  # bytes that do not decode: nobody's
                continue
            genuine, off_truth = self._origin(fix)
            try:
                fix, position = self.intake.check_decoded(fix, now=time, agrees=agrees)
            except FixRejected:
                self.genuine.note(time, genuine, False, off_truth)
                continue
            self.genuine.note(time, genuine, True, off_truth)
            sample = self._samples.get(round(fix.stamp * self._rate))
            if sample is not None:
                yield fix.stamp, position, sample

    def _origin(self, fix: TargetFix) -> tuple[bool, float]:
        """(genuine?, distance m of its position from the offered fix of its stamp) of a delivered fix (decoded):
        genuine is the first delivery of an offered fix, unchanged (bytes that do not decode are nobody's)."""
        key = round(fix.stamp * self._rate)
        offered = self._offered.get(key)
        if offered is None or abs(fix.stamp - key / self._rate) > 1e-6 or fix.frame != "ned":
            return False, math.inf
        distance = norm(np.array(fix.position) - offered)  # np.linalg.norm's bits (geometry.norm)
        genuine = distance == 0.0 and fix.sender == self.sender and key not in self.genuine.seen
        if genuine:
            self.genuine.seen.add(key)
            if len(self.genuine.seen) > 4 * round(30.0 * self._rate):
                self.genuine.seen = {k for k in self.genuine.seen if k > key - round(30.0 * self._rate)}
        return genuine, distance

    def summary(self) -> dict:
        return {"offered": self.offered, "genuine": self.genuine.summary(), "delivered": self.delivered, "accepted": self.validator.accepted,
                "rejected": dict(self.validator.rejected), "faults": dict(self.faults.counters),
                "reanchors": [(round(stamp, 3), rule) for stamp, rule in self.validator.reanchors],
                "contests": self.validator.contest_count_total, "contest_log": list(self.validator.contests)}


class GenuineRecord:
    """What became of the genuine target's fixes and of everyone else's, as delivered.

    Genuine: accepted / rejected counts and the longest run of consecutive rejected genuine fixes
    (count, and s of loop time from the first of them to the next accepted one, or to the last
    delivery when none came). Foreign (attacks, replays, copies): accepted, rejected, and
    accepted_far (accepted while more than FAR m from the genuine fix of its stamp).
    """

    FAR = 5.0  # m

    def __init__(self) -> None:
        self.seen: set[int] = set()
        self.accepted = self.rejected = 0
        self.foreign_accepted = self.foreign_rejected = self.foreign_accepted_far = 0
        self.longest_run = 0
        self.longest_run_s = 0.0
        self._run = 0
        self._run_start: float | None = None
        self._last_time = 0.0

    def note(self, time: float, genuine: bool | None, accepted: bool, off_truth: float) -> None:
        self._last_time = time
        if genuine is None:
            return
        if not genuine:
            if accepted:
                self.foreign_accepted += 1
                self.foreign_accepted_far += int(not off_truth <= self.FAR)
            else:
                self.foreign_rejected += 1
            return
        if accepted:
            self.accepted += 1
            if self._run_start is not None:
                self.longest_run_s = max(self.longest_run_s, time - self._run_start)
            self._run, self._run_start = 0, None
        else:
            self.rejected += 1
            self._run += 1
            self._run_start = time if self._run_start is None else self._run_start
            self.longest_run = max(self.longest_run, self._run)

    def summary(self) -> dict:
        open_run = 0.0 if self._run_start is None else self._last_time - self._run_start
        return {"accepted": self.accepted, "rejected": self.rejected, "longest_rejected_run": self.longest_run,
                "longest_rejected_run_s": max(self.longest_run_s, open_run), "foreign_accepted": self.foreign_accepted,
                "foreign_rejected": self.foreign_rejected, "foreign_accepted_far": self.foreign_accepted_far}


_NAN2, _NAN3, _NAN4, _NAN6, _NAN7 = ((math.nan,) * n for n in (2, 3, 4, 6, 7))


def _log_row(log: FlightLog, time: float, position, velocity, rotation, target: TargetMotion, output,
             estimator: object = None, *, estimate_values: list[float] | None = None, bearings=()) -> None:
    """One row of the flight log, the columns in FlightLog._WIDTHS's order, written into its preallocated
    table in one assignment (a column at a time costs a numpy call each, a keyword append a dict as well).
    position, velocity: the true ones (3 numbers each); rotation: the true body FRD -> NED rotation, its 9
    entries row by row; estimate_values: output.estimate's position and velocity as six floats when the caller
    has them already; bearings: those given to the estimator at this tick (the last own one is logged)."""
    estimate, setpoint = output.estimate, output.setpoint
    # Arrays go in as lists (ndarray.tolist: the same floats, without a numpy scalar per element).
    values = [time, *position, *velocity, *rotation[0::3], rotation[8], *target.position.tolist(), *target.velocity.tolist()]
    if estimate is not None:
        values += estimate.position.tolist() + estimate.velocity.tolist() if estimate_values is None else estimate_values
        values.append(estimate.position_std)
    else:
        values += _NAN7
    if setpoint is not None:
        values += setpoint.acceleration.tolist()
        values.append(setpoint.thrust_normalized)
    else:
        values += _NAN4
    values += (TRACK_MODE_CODES[output.mode], output.bearing_age) if estimate is not None else _NAN2
    observability = output.observability
    values += _NAN2 if observability is None else (observability["log_det"], observability["min_eigenvalue"])
    health = output.health
    if health is not None:
        reasons = health.reasons
        values += (float(health.state is HealthState.SUSPECT), sum(HEALTH_REASON_BITS[reason] for reason in reasons) if reasons else 0,
                   health.nis_ratio, health.relative_range_std, HEALTH_ACTION_CODES[output.health_action],
                   output.process_noise_boost, float(output.health_reinitialized))
    else:
        values += _NAN7
    motion = getattr(estimator, "motion_probabilities", None) if estimate is not None else None
    values += _NAN3 if motion is None else motion
    values += rotation
    if estimate is not None:
        c = estimate.covariance
        values += (c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2])
    else:
        values += _NAN6
    own = [bearing for bearing in bearings if bearing.source == 0]
    values += own[-1].direction.tolist() if own else _NAN3
    row = log.rows
    size = log._ROW.size
    try:
        log._bytes[row * size:(row + 1) * size] = log._ROW.pack(*values)
    except struct.error:  # a value struct refuses (not a float, or an int too large): numpy's conversion, as before
        log._table[row] = values
    log.rows = row + 1
