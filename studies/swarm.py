"""In-process simulator of several pursuers following one target (seeds 002 and 004).

Each pursuer is what the single-pursuer simulator flies (studies.closed_loop): its own Table I plant, its
own bearing sensor and its own FollowingPipeline, built by the same assembly (companion.assembly). What is
added is the share link between them, as the networked companions have it: every pursuer publishes a
``bof.pursuer_share/1`` (interfaces.link_schema) at [swarm] share_rate_hz with its own measured state and its
latest bearing (and its estimate), checked by the payload schema as its encoder checks it and handed over as
the receivers would decode it (interfaces.link_schema.checked_pursuer_share: the encoder's JSON carries every
value exactly, so the bytes in between change nothing in process); the share goes through the neighbour-link fault
model (interfaces.neighbour_link: radius, loss, latency, blackouts) and the receiver

* hands the neighbour's bearing to its estimator at the bearing's own stamp, from the neighbour's position
  then (estimator 'shared_bearings' and 'triangulation_kf'; 'own' and 'fusion' keep to their own bearings);
* hands the neighbour's shared estimate to its estimator's `absorb` (estimator 'fusion':
  companion.core.cooperative_estimation.FusionEstimator), all that arrived since its last tick at once;
* knows the neighbour's state for the cooperative guidance and the separation filter for as long as it is
  fresh ([swarm] neighbour_timeout_s); with no fresh neighbour it flies the single-pursuer laws.

The loop is deterministic for a seed. Pursuer 1 draws exactly what the single-pursuer simulator draws for
the same seed (plant, sensor and range streams), so one pursuer alone flies the single flight exactly;
pursuer k > 1 has streams of its own.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from companion.assembly import build_pipeline, build_sensor, pursuer_scenario
from companion.core.cooperative_guidance import phase_spacing_error_rows, phase_spacing_errors
from companion.core.geometry import all_finite
from companion.core.messages import BearingMeasurement, NeighbourState, PursuerState, TargetEstimate, fast_frozen
from companion.core.pipeline import FollowingPipeline
from interfaces.link_schema import (
    MAX_EPOCH,
    PayloadError,
    PursuerShare,
    SharedBearing,
    SharedEstimate,
    checked_pursuer_share,
)
from interfaces.neighbour_link import NeighbourLink
from interfaces.scenario import (
    ConfigError,
    PursuerStart,
    Scenario,
    VehicleConfig,
    pursuer_starts,
    share_rate_hz,
)
from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle
from sitl_plant.vehicle.params import quadrotor_params
from sitl_plant.world.link_faults import injects_anything
from sitl_plant.world.target import target_from_config
from studies.closed_loop import (
    MAX_SPEED,
    FlightLog,
    Termination,
    _initial_state,
    _log_row,
    _measure,
    _sum3,
    health_actions_summary,
)
from studies.metrics import rms, summarize

#: Streams of pursuer k > 1: SeedSequence(seed, spawn_key=(SWARM_SPAWN_KEY, k)).spawn(3) (plant, sensor, range).
SWARM_SPAWN_KEY = 0x5357
#: Streams of the publishers' epochs: SeedSequence(seed, spawn_key=(EPOCH_SPAWN_KEY, k)).
EPOCH_SPAWN_KEY = 0xE90D


@dataclass
class _Pursuer:
    """One pursuer of the swarm and what it knows of the others."""

    ident: int
    scenario: Scenario
    plant: AttitudeThrustVehicle
    pipeline: FollowingPipeline
    sensor: object
    sensor_rng: np.random.Generator
    range_rng: np.random.Generator
    epoch: int
    log: FlightLog
    seq: int = 0
    latest_bearing: BearingMeasurement | None = None
    shared_bearing_time: float = -math.inf
    neighbours: dict[int, NeighbourState] = field(default_factory=dict)
    inbox: list[BearingMeasurement] = field(default_factory=list)
    estimate_inbox: list[TargetEstimate] = field(default_factory=list)
    first_bearing: float | None = None
    termination: Termination = Termination.COMPLETED
    bearings_used: int = 0
    neighbour_bearings_used: int = 0
    shares_rejected: dict[str, int] = field(default_factory=dict)
    last_seq: dict[int, tuple[int, int]] = field(default_factory=dict)
    estimates_not_shared: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class SwarmResult:
    """A finished swarm flight: series per pursuer (id -> studies.closed_loop.FlightLog series), the summary
    (pursuer 1's single-pursuer keys, plus `pursuers`, `phase_spacing_error_deg_rms`, `min_pursuer_separation`
    and the share link's figures) and the worst termination of any pursuer."""

    scenario: Scenario
    series: dict[int, dict[str, np.ndarray]]
    summary: dict
    termination: Termination


def _streams(seed: int, ident: int) -> list[np.random.Generator]:
    sequence = np.random.SeedSequence(seed) if ident == 1 else np.random.SeedSequence(seed, spawn_key=(SWARM_SPAWN_KEY, ident))
    return [np.random.default_rng(s) for s in sequence.spawn(3)]


def _pursuer(scenario: Scenario, vehicle: VehicleConfig, start: PursuerStart, seed: int, rows: int) -> _Pursuer:
    own = pursuer_scenario(scenario, start)
    params = quadrotor_params(vehicle)
    plant_rng, sensor_rng, range_rng = _streams(seed, start.ident)
    plant = AttitudeThrustVehicle(params, _initial_state(own, params), scenario.simulation.physics_rate_hz, plant_rng)
    epoch = int(np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(EPOCH_SPAWN_KEY, start.ident))).integers(
        0, MAX_EPOCH, endpoint=True))
    return _Pursuer(start.ident, own, plant, build_pipeline(own, vehicle, params.hover_thrust_normalized, start.ident),
                    build_sensor(scenario.sensor), sensor_rng, range_rng, epoch, FlightLog(rows))


def _share(pursuer: _Pursuer, time: float, position: np.ndarray, velocity: np.ndarray) -> PursuerShare:
    """Pursuer's bof.pursuer_share/1 at `time`: its measured state, its newest bearing if not shared yet,
    its estimate; as its receivers decode it (interfaces.link_schema.checked_pursuer_share: what
    decode_pursuer_share(encode_pursuer_share(share)) gives, without the JSON in between)."""
    bearing = None
    latest = pursuer.latest_bearing
    if latest is not None and latest.time > pursuer.shared_bearing_time:
        bearing = SharedBearing(latest.time, latest.direction.tolist(), latest.pursuer_position.tolist())
        pursuer.shared_bearing_time = latest.time
    estimate = None
    if pursuer.pipeline.engaged_at is not None:
        current = pursuer.pipeline.estimator.estimate
        # the covariance as 36 floats, row by row (what SharedEstimate makes of a (6, 6) array, without numpy)
        estimate = SharedEstimate(current.time, current.position.tolist(), current.velocity.tolist(),
                                  tuple(np.asarray(current.covariance, dtype=float).ravel().tolist()))
    share = PursuerShare(pursuer.ident, pursuer.seq, time, pursuer.epoch, position.tolist(), velocity.tolist(), bearing,
                         estimate)
    pursuer.seq += 1
    try:
        return checked_pursuer_share(share)
    except PayloadError as error:
        if estimate is None:
            raise
        # An estimate the schema refuses (a diverged one: |v| > 1e3 m/s, a covariance out of range) is left out
        # of the share, and counted; the rest of the share still goes.
        pursuer.estimates_not_shared[error.reason] = pursuer.estimates_not_shared.get(error.reason, 0) + 1
        return checked_pursuer_share(dataclasses.replace(share, estimate=None))


def _receive(receiver: _Pursuer, share: PursuerShare, uses_bearings: bool, uses_estimates: bool = False) -> None:
    """Keep what one share (as decoded: `_share`) says: the neighbour's state, and its bearing for the estimator.
    A share that is older than one already heard from its sender and epoch is counted and dropped. With
    uses_estimates the neighbour's shared estimate waits for the estimator's absorb (estimator 'fusion'). (The
    schema checked the share when it was made, as the encoder does: nothing the decoder would refuse is sent.)"""
    if share.sender == receiver.ident:
        receiver.shares_rejected["own_sender"] = receiver.shares_rejected.get("own_sender", 0) + 1
        return
    previous = receiver.last_seq.get(share.sender)
    if previous is not None and previous[0] == share.epoch and share.seq <= previous[1]:
        receiver.shares_rejected["stale_seq"] = receiver.shares_rejected.get("stale_seq", 0) + 1
        return
    receiver.last_seq[share.sender] = (share.epoch, share.seq)
    receiver.neighbours[share.sender] = NeighbourState(share.sender, share.stamp, np.array(share.position),
                                                       np.array(share.velocity))
    if uses_bearings and share.bearing is not None:
        receiver.inbox.append(BearingMeasurement(share.bearing.stamp, np.array(share.bearing.direction),
                                                 np.array(share.bearing.position), source=share.sender))
    if uses_estimates and share.estimate is not None:
        receiver.estimate_inbox.append(TargetEstimate(share.estimate.stamp, np.array(share.estimate.position),
                                                      np.array(share.estimate.velocity),
                                                      share.estimate.covariance_matrix))


def simulate_swarm(scenario: Scenario, vehicle: VehicleConfig, seed: int | None = None) -> SwarmResult:
    """Fly every pursuer of `scenario` ([swarm]; one pursuer without it) in process. seed overrides
    scenario.simulation.seed."""
    seed = scenario.simulation.seed if seed is None else seed
    if injects_anything(scenario.faults):
        raise ConfigError("[faults] on the target link is not simulated with several pursuers yet: fly it with bof-sitl")
    swarm = scenario.swarm
    physics_hz = scenario.simulation.physics_rate_hz
    every = {
        "estimator": round(physics_hz / scenario.estimator.rate_hz),
        "control": round(physics_hz / scenario.guidance.rate_hz),
        "sensor": round(physics_hz / scenario.sensor.rate_hz),
        "share": round(physics_hz / share_rate_hz(scenario)),
    }
    dt = 1.0 / physics_hz
    total_steps = round(scenario.simulation.duration * physics_hz)
    event_steps = sorted({step for period in every.values() for step in range(0, total_steps + 1, period)})
    starts = pursuer_starts(scenario)
    pursuers = [_pursuer(scenario, vehicle, start, seed, len(event_steps)) for start in starts]
    target = target_from_config(scenario.target, seed)
    link = None if swarm is None else NeighbourLink(swarm.link, swarm.count, seed if swarm.link.seed is None else swarm.link.seed)
    timeout = math.inf if swarm is None else swarm.neighbour_timeout_s
    uses_bearings = swarm is not None and swarm.estimator in ("shared_bearings", "triangulation_kf")
    uses_estimates = swarm is not None and swarm.estimator == "fusion"
    in_flight: list[tuple[float, int, int, PursuerShare]] = []  # (delivery time, order, receiver id, share)
    order = 0
    separation = math.inf
    phase_errors = []  # (time, phases): the spacing errors of the summary window are computed at the end

    upper = np.triu_indices(len(pursuers), 1)  # each pair of pursuers once
    # The true positions of every tick, for the separation figures (computed at the end: _closest_separation).
    positions = np.empty((len(event_steps), len(pursuers), 3))
    sensor_every, share_every = every["sensor"], every["share"]
    max_speed_squared = MAX_SPEED**2
    last_index = len(event_steps) - 1
    for index, step in enumerate(event_steps):
        time = step * dt
        # The true state as tuples (plant.kinematics(): the values of plant.state, without its arrays), then the
        # measured one, pursuer by pursuer.
        states = [(*p.plant.kinematics(), *p.plant.measured_state()) for p in pursuers]
        if step % sensor_every == 0:
            for p, (position, _, rotation, measured_position, _) in zip(pursuers, states):
                bearing = _measure(p.sensor, time, target.position - np.array(position), np.array(rotation).reshape(3, 3),
                                   measured_position, p.sensor_rng, p.range_rng)
                if bearing is not None:
                    p.inbox.append(bearing)
                    p.latest_bearing = bearing
                    if p.first_bearing is None:
                        p.first_bearing = time
        if link is not None and step % share_every == 0:
            for sender, sender_state in zip(pursuers, states):
                share = _share(sender, time, sender_state[3], sender_state[4])
                for receiver, receiver_state in zip(pursuers, states):
                    if receiver is sender:
                        continue
                    delivery = link.transmit(time, sender.ident, receiver.ident, sender_state[3], receiver_state[3])
                    if delivery.delivered:
                        heapq.heappush(in_flight, (delivery.time, order, receiver.ident, share))
                        order += 1
        while in_flight and in_flight[0][0] <= time + 1e-9:
            _, _, receiver_id, share = heapq.heappop(in_flight)
            _receive(pursuers[receiver_id - 1], share, uses_bearings, uses_estimates)

        for k, (p, (position, velocity, rotation, measured_position, measured_velocity)) in enumerate(zip(pursuers, states)):
            own = fast_frozen(PursuerState, time=time, position=measured_position, velocity=measured_velocity)
            p.pipeline.set_neighbours(tuple(n for n in p.neighbours.values() if time - n.time <= timeout)
                                      if p.neighbours else ())
            if p.estimate_inbox:
                # estimator 'fusion': the shares that arrived since the last tick, fused into the own filter at once
                p.pipeline.estimator.absorb(p.estimate_inbox)
                p.estimate_inbox.clear()
            bearings = sorted(p.inbox, key=_bearing_time) if p.inbox else []
            p.inbox.clear()
            output = p.pipeline.step_all(time, own, bearings)
            if bearings:
                own_bearings = sum(1 for b in bearings if b.source == 0)
                p.bearings_used += own_bearings
                p.neighbour_bearings_used += len(bearings) - own_bearings
            if output.new_setpoint and output.setpoint is not None:
                p.plant.set_attitude_target(output.setpoint.rotation,
                                            output.setpoint.thrust_normalized * p.plant.params.max_total_thrust)
            estimate = output.estimate
            # The sum of the six numbers in numpy's order (ndarray.sum of three adds them left to right), as floats.
            if estimate is not None and not math.isfinite(_sum3(estimate.position.tolist()) + _sum3(estimate.velocity.tolist())):
                p.termination = Termination.ESTIMATE_NOT_FINITE
            vx, vy, vz = velocity  # |v|^2 summed left to right (as studies.closed_loop)
            if rotation[8] < 0.0 or vx * vx + vy * vy + vz * vz > max_speed_squared:
                p.termination = Termination.OUT_OF_CONTROL
            _log_row(p.log, time, position, velocity, rotation, target, output, p.pipeline.estimator, bearings=bearings)
            positions[index, k] = position

        if len(pursuers) > 1:
            phases = np.arctan2(positions[index, :, 1] - target.position[1], positions[index, :, 0] - target.position[0])
            if not all_finite(phases):
                phase_spacing_errors(phases)  # raises, as it would have here
            phase_errors.append((time, phases))
        if any(p.termination is not Termination.COMPLETED for p in pursuers) or index == last_index:
            break
        gap = event_steps[index + 1] - step
        target.step(gap * dt)
        for p in pursuers:
            p.plant.advance(gap * dt)

    if len(pursuers) > 1:
        separation = _closest_separation(positions[:index + 1], upper)
    return _result(scenario, vehicle, pursuers, link, seed, separation, phase_errors)


def _bearing_time(bearing: BearingMeasurement) -> float:
    return bearing.time


def _closest_separation(positions: np.ndarray, upper: tuple[np.ndarray, np.ndarray]) -> float:
    """The closest two pursuers ever came, m: positions (ticks, pursuers, 3) m; upper, each pair once
    (np.triu_indices). Tick by tick the smallest distance of a pair (np.min of the pairs' norms: NaN if one is
    NaN), then the smallest of those as min() folds them (a NaN tick is passed over). The norms of all ticks at
    once: numpy reduces each pair's three squares alone, in the same order whatever the number of ticks."""
    gaps = np.linalg.norm(positions[:, :, None, :] - positions[:, None, :, :], axis=3)
    separation = math.inf
    for closest in np.min(gaps[:, upper[0], upper[1]], axis=1).tolist():
        separation = min(separation, closest)
    return separation


def _all_bearings_time(pursuers: list[_Pursuer]) -> float | None:
    firsts = [p.first_bearing for p in pursuers]
    return None if any(t is None for t in firsts) else max(firsts)


def _settled_under(time: np.ndarray, error: np.ndarray, bound: float, after: float) -> float | None:
    """Seconds after `after` from which |error| stays under `bound` to the end (None: never)."""
    above = np.flatnonzero((time >= after) & ~(np.abs(error) < bound))
    if len(above) == 0:
        return 0.0
    last = above[-1]
    return None if last + 1 >= len(time) else float(time[last + 1] - after)


def _result(scenario: Scenario, vehicle: VehicleConfig, pursuers: list[_Pursuer], link: NeighbourLink | None, seed: int, separation: float,
            phase_errors: list[tuple[float, np.ndarray]]) -> SwarmResult:
    """phase_errors: (time s, the pursuers' orbit phases about the target then, rad), every tick."""
    all_bearings = _all_bearings_time(pursuers)
    series = {}
    entries = []
    for p in pursuers:
        data = p.log.series()
        series[p.ident] = data
        summary = summarize(data, p.scenario, p.termination, vehicle)
        summary["pursuer"] = p.ident
        summary["bearings_used"] = p.bearings_used
        summary["neighbour_bearings_used"] = p.neighbour_bearings_used
        if hasattr(p.pipeline.estimator, "absorb"):
            summary["estimates_absorbed"] = p.pipeline.estimator.absorbed
            summary["estimates_refused"] = dict(p.pipeline.estimator.rejections)
        summary["shares_rejected"] = dict(p.shares_rejected)
        summary["estimates_not_shared"] = dict(p.estimates_not_shared)
        summary["first_bearing_time"] = p.first_bearing
        estimation_error = data["range_estimate"] - data["range"]
        summary["range_estimation_settled_1m_after_all_bearings"] = (
            None if all_bearings is None else _settled_under(data["time"], estimation_error, 1.0, all_bearings))
        summary["track_mode_changes"] = [(round(t, 3), mode.value) for t, mode in p.pipeline.mode_changes]
        summary["law_changes"] = [(round(t, 3), law) for t, law in p.pipeline.law_changes]
        summary["reinitializations"] = p.pipeline.reinitializations
        summary["health_actions"] = health_actions_summary(p.pipeline)
        summary["envelope"] = p.pipeline.envelope_record.as_dict()
        summary["seed"] = seed
        entries.append(summary)
    top = dict(entries[0])
    top["pursuers"] = entries
    window_start = entries[0]["duration"] - scenario.simulation.summary_window
    recent = [phases for time, phases in phase_errors if time >= window_start]
    # the window's spacing errors tick after tick, all ticks at once (phase_spacing_error_rows)
    top["phase_spacing_error_deg_rms"] = (float(np.degrees(rms(phase_spacing_error_rows(np.array(recent)).ravel())))
                                          if recent else None)
    top["min_pursuer_separation"] = separation if math.isfinite(separation) else None
    top["min_separation"] = None if scenario.swarm is None else scenario.swarm.min_separation
    top["all_pursuers_had_a_bearing_at"] = all_bearings
    if link is not None:
        top["share_link"] = {key: int(value) for key, value in link.counters.items()}
    worst = next((p.termination for p in pursuers if p.termination is not Termination.COMPLETED), Termination.COMPLETED)
    # The flight is as good as its worst pursuer: the first one that did not complete names the termination.
    failed = next((e for e in entries if e["termination"] != "completed"), None)
    if failed is not None:
        top["termination"], top["termination_reason"] = failed["termination"], f"pursuer {failed['pursuer']}: {failed['termination_reason']}"
    return SwarmResult(scenario, series, top, worst)
