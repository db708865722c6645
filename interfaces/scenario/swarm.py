"""[swarm]: several pursuers, their starts, their link and their cooperative laws."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Literal, TYPE_CHECKING

from pydantic import Field, model_validator

from interfaces.scenario.common import (FROM_ARRAY, MAX_DISTANCE_M, Acceleration, Distance, Duration, Gain,
                                        NonNegativeDuration, NonNegativeSpeed, Position, PositionComponent, Rate, Speed, Velocity, _Strict)
from interfaces.scenario.vehicle import PursuerConfig

if TYPE_CHECKING:  # annotations only: the modules below import this one
    from interfaces.scenario.full import Scenario
    from interfaces.scenario.plant import PlantScenario


#: The most pursuers a scenario may fly (ids 1..MAX_PURSUERS).
MAX_PURSUERS = 32
SWARM_GUIDANCE = ("hng", "circumnavigation", "standoff")
SWARM_ESTIMATORS = ("own", "shared_bearings", "triangulation_kf", "fusion")
PursuerIdent = Annotated[int, Field(ge=1, le=MAX_PURSUERS)]


class SwarmPursuerConfig(_Strict):
    """One [[swarm.pursuers]] entry (the k-th entry is pursuer k): where it starts (m, m/s, NED) and the
    position its estimator's range guess is taken from (default: [estimator] initial_position). Pursuer 1
    may leave initial_position / initial_velocity out to take [pursuer]'s (when both give one and [pursuer]
    is not at its defaults, they must agree); every other pursuer must give initial_position
    (initial_velocity defaults to rest)."""

    initial_position: Position | None = None
    initial_velocity: Velocity | None = None
    estimator_initial_position: Position | None = None


class SwarmBlackout(_Strict):
    """A window [start, end) (s, scenario time) during which `pursuer` neither sends nor receives shares."""

    pursuer: PursuerIdent
    start: NonNegativeDuration
    end: Duration

    @model_validator(mode="after")
    def _ordered(self) -> "SwarmBlackout":
        if self.end <= self.start:
            raise ValueError(f"end ({self.end:g}) must be after start ({self.start:g})")
        return self


class SwarmLinkConfig(_Strict):
    """[swarm.link]: faults of the pursuer <-> pursuer share link (interfaces.neighbour_link.NeighbourLink).

    radius: m, communication radius (a share reaches only pursuers within it, 3-D distance at the send
    time; default inf = everyone, `radius = inf` may be written). loss_probability: independent loss per
    share and receiver. latency_s + U(0, jitter_s): delivery delay, s. blackouts: windows in which one
    pursuer neither sends nor receives. seed: the link's own seed (None: derived from simulation.seed on
    a stream no other draw uses, like [faults])."""

    radius: Annotated[float, Field(gt=0.0, allow_inf_nan=True)] = math.inf
    loss_probability: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    latency_s: NonNegativeDuration = 0.0
    jitter_s: NonNegativeDuration = 0.0
    blackouts: Annotated[tuple[SwarmBlackout, ...], FROM_ARRAY] = ()
    seed: Annotated[int, Field(ge=0)] | None = None

    @model_validator(mode="after")
    def _windows_apart(self) -> "SwarmLinkConfig":
        by_pursuer: dict[int, list[SwarmBlackout]] = {}
        for window in self.blackouts:
            by_pursuer.setdefault(window.pursuer, []).append(window)
        for pursuer, windows in sorted(by_pursuer.items()):
            ordered = sorted(windows, key=lambda w: w.start)
            for earlier, later in zip(ordered, ordered[1:]):
                if later.start < earlier.end:
                    raise ValueError(f"blackouts: pursuer {pursuer}'s windows [{earlier.start:g}, {earlier.end:g}) and "
                                     f"[{later.start:g}, {later.end:g}) overlap")
        return self


class CircumnavigationConfig(_Strict):
    """[swarm.circumnavigation]: seed 002 eq. (10), u_i = g1 (|p^_i0| - D*) phi_i0 + g2 D* (alpha + g3 Delta_i)
    phi_bar_i0, with D* = [guidance] desired_range and the seed's gains as defaults (g1 = 1.2, g2 = 1 1/s,
    g3 = 0.4 1/rad, alpha = 1 rad). The seed's u_i is a velocity (single integrator): the quadrotor tracks it
    with acceleration velocity_gain (u_i - v) (1/s, plus the target-velocity feed-forward), bounded by
    max_acceleration (m/s^2). altitude_offset: m, height of the orbit plane above the target (0 = the
    horizontal plane through the target, the 3-D extension of the planar seed)."""

    g1: Gain = 1.2
    g2: Gain = 1.0
    g3: Gain = 0.4
    alpha: Gain = 1.0
    velocity_gain: Gain = 2.0
    max_acceleration: Acceleration = 4.0
    altitude_offset: PositionComponent = 0.0


class StandoffConfig(_Strict):
    """[swarm.standoff]: seed 004's TOGVF (eq. (26)-(29), inner circle when inside) with its vertical
    profile (eq. (30)-(31)), moving-target scaling (eq. (32)-(34)) and phase coordination (eq. (36)-(40)).

    radius: R, m, horizontal standoff distance. inner_radius: r_min, m, the inner tangential circle (the
    vehicle's smallest turning radius), below radius. height: H, m, above the target. speed: v0, m/s,
    horizontal speed of each pursuer (above the target's); the phase coordination changes it within
    [min_speed, max_speed] with gain phase_gain (k2 = k3 of eq. (38)-(40), m/s per rad of phase-gap
    error). max_vertical_speed (m/s) and max_vertical_acceleration (m/s^2): the vertical profile's limits.
    velocity_gain (1/s) and max_acceleration (m/s^2): how the quadrotor tracks the field's velocity."""

    radius: Distance = 20.0
    inner_radius: Distance = 5.0
    height: PositionComponent = 10.0
    speed: Speed = 8.0
    min_speed: NonNegativeSpeed = 2.0
    max_speed: Speed = 15.0
    phase_gain: Gain = 1.0
    max_vertical_speed: Speed = 3.0
    max_vertical_acceleration: Acceleration = 1.0
    velocity_gain: Gain = 2.0
    max_acceleration: Acceleration = 4.0

    @model_validator(mode="after")
    def _consistent(self) -> "StandoffConfig":
        if self.inner_radius >= self.radius:
            raise ValueError(f"inner_radius ({self.inner_radius:g}) must be below radius ({self.radius:g})")
        if not self.min_speed <= self.speed <= self.max_speed:
            raise ValueError(f"speed ({self.speed:g}) must lie in [min_speed, max_speed] = "
                             f"[{self.min_speed:g}, {self.max_speed:g}]")
        return self


class TriangulationConfig(_Strict):
    """[swarm.triangulation]: seed 002's estimator for estimator = 'triangulation_kf' (defaults: the seed's).

    k1, k2: the adaptive PI estimator's gains (eq. (9); 1/s, 1/s^2). switch_time: s, when each pursuer
    switches from the PI estimator to the Kalman enhancement (eq. (31)-(33); the seed's N = 2500 steps of
    0.01 s). process_noise: q of Q = q I6. measurement_noise: R = r I (m^2, the triangulated position).
    initial_std: P0 = initial_std^2 I6."""

    k1: Gain = 4.0
    k2: Gain = 0.12
    switch_time: NonNegativeDuration = 25.0
    process_noise: Annotated[float, Field(gt=0.0, le=2500.0)] = 0.2
    measurement_noise: Annotated[float, Field(gt=0.0, le=MAX_DISTANCE_M**2)] = 1.0
    initial_std: Distance = 1.0


class FusionConfig(_Strict):
    """[swarm.fusion]: estimator = 'fusion': each pursuer's own u-PLKF estimate fused with its neighbours'
    shared ones. method 'covariance_intersection' (consistent whatever the unknown cross-covariance) or
    'seed004' (seed 004 eq. (24)-(25): the information sum, cross-covariance ignored)."""

    method: Literal["covariance_intersection", "seed004"] = "covariance_intersection"


_SWARM_SUBTABLES = {"circumnavigation": ("guidance", "circumnavigation"), "standoff": ("guidance", "standoff"),
                    "triangulation": ("estimator", "triangulation_kf"), "fusion": ("estimator", "fusion")}


class SwarmConfig(_Strict):
    """[swarm]: several pursuers around one target (docs/guide/swarm.md).
    Absent: one pursuer, as before.

    pursuers: [[swarm.pursuers]], the k-th is pursuer k (1..MAX_PURSUERS). guidance: 'hng' (each flies
    [guidance]), 'circumnavigation' (seed 002 eq. (10), [swarm.circumnavigation]), 'standoff' (seed 004
    TOGVF, [swarm.standoff]). estimator: 'own' (u-PLKF on its own bearings), 'shared_bearings' (u-PLKF on
    its own and its neighbours' bearings), 'triangulation_kf' (seed 002, [swarm.triangulation]), 'fusion'
    (shared estimates fused, [swarm.fusion]). min_separation: m, pursuers never closer. share_rate_hz:
    shares per second per pursuer (default: [sensor] rate_hz). weave_min_angle_deg: HNG's weave is off
    while a neighbour's bearing makes at least this angle with the own one. neighbour_timeout_s: a
    neighbour silent this long (s) no longer counts (back to single-pursuer following). link: [swarm.link].
    """

    pursuers: Annotated[tuple[SwarmPursuerConfig, ...], FROM_ARRAY, Field(min_length=1, max_length=MAX_PURSUERS)]
    guidance: Literal["hng", "circumnavigation", "standoff"] = "hng"
    estimator: Literal["own", "shared_bearings", "triangulation_kf", "fusion"] = "own"
    min_separation: Distance = 2.0
    share_rate_hz: Rate | None = None
    weave_min_angle_deg: Annotated[float, Field(gt=0.0, le=90.0)] = 15.0
    neighbour_timeout_s: Duration = 1.0
    circumnavigation: CircumnavigationConfig = CircumnavigationConfig()
    standoff: StandoffConfig = StandoffConfig()
    triangulation: TriangulationConfig = TriangulationConfig()
    fusion: FusionConfig = FusionConfig()
    link: SwarmLinkConfig = SwarmLinkConfig()

    @property
    def count(self) -> int:
        """N, the number of pursuers."""
        return len(self.pursuers)

    @model_validator(mode="after")
    def _consistent(self) -> "SwarmConfig":
        for table, (key, value) in _SWARM_SUBTABLES.items():
            # compared with the defaults, not "was it written": a dumped and re-validated config (overrides) has all
            if getattr(self, key) != value and getattr(self, table) != type(self).model_fields[table].default:
                raise ValueError(f"[swarm.{table}] applies to {key} = {value!r} only, not to {key} = "
                                 f"{getattr(self, key)!r}")
        for index, pursuer in enumerate(self.pursuers[1:], start=2):
            if pursuer.initial_position is None:
                raise ValueError(f"pursuers[{index - 1}] (pursuer {index}): initial_position is required "
                                 "(only pursuer 1 may take [pursuer]'s)")
        for window in self.link.blackouts:
            if window.pursuer > self.count:
                raise ValueError(f"link.blackouts: pursuer {window.pursuer} does not exist (pursuers are 1..{self.count})")
        return self


@dataclass(frozen=True)
class PursuerStart:
    """Pursuer `ident` (1..N) as a scenario starts it: initial_position m, initial_velocity m/s (NED, (3,)),
    estimator_initial_position m (the range guess's point; None when the scenario gives none)."""

    ident: int
    initial_position: tuple[float, float, float]
    initial_velocity: tuple[float, float, float]
    estimator_initial_position: tuple[float, float, float] | None


def pursuer_starts(scenario: "Scenario | PlantScenario") -> tuple[PursuerStart, ...]:
    """Every pursuer of `scenario`, ids 1..N: one (from [pursuer]) without [swarm], else [[swarm.pursuers]]
    with pursuer 1's missing values from [pursuer] and every missing estimator_initial_position from
    [estimator] initial_position (None for a PlantScenario, which has no [estimator])."""
    estimator = getattr(scenario, "estimator", None)
    guess = None if estimator is None else estimator.initial_position
    base = scenario.pursuer
    if scenario.swarm is None:
        return (PursuerStart(1, base.initial_position, base.initial_velocity, guess),)
    starts = []
    for ident, entry in enumerate(scenario.swarm.pursuers, start=1):
        position = entry.initial_position if entry.initial_position is not None else base.initial_position
        velocity = entry.initial_velocity if entry.initial_velocity is not None else (
            base.initial_velocity if ident == 1 else (0.0, 0.0, 0.0))
        own_guess = entry.estimator_initial_position if entry.estimator_initial_position is not None else guess
        starts.append(PursuerStart(ident, position, velocity, own_guess))
    return tuple(starts)


def share_rate_hz(scenario: "Scenario") -> float:
    """Shares per second per pursuer: [swarm] share_rate_hz, else [sensor] rate_hz (one share per bearing)."""
    rate = None if scenario.swarm is None else scenario.swarm.share_rate_hz
    return scenario.sensor.rate_hz if rate is None else rate


def _check_swarm(scenario: "Scenario | PlantScenario") -> None:
    """[swarm] against the other sections: pursuer 1 against [pursuer], the starts apart, the share rate."""
    swarm = scenario.swarm
    if swarm is None:
        return
    first = swarm.pursuers[0]
    # [pursuer] at its defaults counts as not given (a dumped and re-validated config has every section)
    if scenario.pursuer != PursuerConfig():
        for key in ("initial_position", "initial_velocity"):
            given = getattr(first, key)
            if given is not None and tuple(given) != tuple(getattr(scenario.pursuer, key)):
                raise ValueError(f"swarm.pursuers[0].{key} {list(given)} differs from pursuer.{key} "
                                 f"{list(getattr(scenario.pursuer, key))}: give pursuer 1's start once")
    starts = pursuer_starts(scenario)
    for index, one in enumerate(starts):
        for other in starts[index + 1:]:
            distance = math.dist(one.initial_position, other.initial_position)
            if distance < swarm.min_separation:
                raise ValueError(f"swarm: pursuers {one.ident} and {other.ident} start {distance:g} m apart, closer "
                                 f"than min_separation = {swarm.min_separation:g} m")
    if swarm.share_rate_hz is not None:
        ratio = scenario.simulation.physics_rate_hz / swarm.share_rate_hz
        if swarm.share_rate_hz > scenario.simulation.physics_rate_hz or abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"swarm.share_rate_hz = {swarm.share_rate_hz} must divide simulation.physics_rate_hz = "
                             f"{scenario.simulation.physics_rate_hz} into whole steps")


def _check_swarm_geometry(scenario: "Scenario") -> None:
    """Equally spaced on their circle, N pursuers must stay min_separation apart (chord 2 r sin(pi / N))."""
    swarm = scenario.swarm
    if swarm is None or swarm.count < 2:
        return
    if swarm.guidance == "circumnavigation":
        offset = swarm.circumnavigation.altitude_offset
        if abs(offset) >= scenario.guidance.desired_range:
            raise ValueError(f"swarm.circumnavigation.altitude_offset ({offset:g} m) must be smaller in size than "
                             f"guidance.desired_range ({scenario.guidance.desired_range:g} m)")
        radius, what = math.sqrt(scenario.guidance.desired_range**2 - offset**2), "guidance.desired_range"
    elif swarm.guidance == "standoff":
        radius, what = swarm.standoff.radius, "swarm.standoff.radius"
    else:
        return
    chord = 2.0 * radius * math.sin(math.pi / swarm.count)
    if chord <= swarm.min_separation:
        raise ValueError(f"swarm: {swarm.count} pursuers equally spaced on a circle of radius {radius:g} m ({what}) "
                         f"are {chord:.3g} m apart, not more than min_separation = {swarm.min_separation:g} m")
