"""[target]: its maneuvers, patterns, segments and recorded trajectories."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, model_validator

from interfaces.scenario.common import (FROM_ARRAY, MAX_ACCELERATION_M_S2, MAX_DURATION_S, MAX_SPEED_M_S, Acceleration,
                                        Distance, Duration, NonNegativeDuration, NonNegativeSpeed, Position, Speed,
                                        Velocity, _Strict, _finite_vector)


#: Bounds of [target] segments: a segment lasts at most a day (s); accelerations up to 50 m/s^2 (5 g, beyond any
#: small drone); speeds and climb rates up to 100 m/s; turn rates up to 3 rad/s (a full turn in about 2 s); at most
#: 10000 segments (a longer plan is a recorded track: [target.trajectory]).
MAX_SEGMENT_DURATION = MAX_DURATION_S
MAX_SEGMENT_ACCELERATION = MAX_ACCELERATION_M_S2
MAX_SEGMENT_SPEED = MAX_SPEED_M_S
MAX_TURN_RATE = 3.0
MAX_SEGMENTS = 10000
#: s: the latest end of a maneuver or pattern window: 1e6 s, as scenarios write "until the flight ends" (flights
#: last at most MAX_DURATION_S).
MAX_WINDOW_END_S = 1e6
WindowEnd = Annotated[float, Field(gt=0.0, le=MAX_WINDOW_END_S)]
#: rad/s: the fastest [target.circle] turn_rate, a full turn a second.
MAX_CIRCLE_TURN_RATE = 2.0 * math.pi
#: m/s^2: a signed lateral acceleration (+ turns right).
LateralAcceleration = Annotated[float, Field(ge=-MAX_ACCELERATION_M_S2, le=MAX_ACCELERATION_M_S2)]


class ManeuverConfig(_Strict):
    """A constant-speed horizontal turn: lateral acceleration (m/s^2, + = right turn in NED) from start to end (s)."""

    start: NonNegativeDuration
    end: WindowEnd
    lateral_acceleration: LateralAcceleration

    @model_validator(mode="after")
    def _ordered(self) -> "ManeuverConfig":
        if self.end <= self.start:
            raise ValueError(f"end ({self.end}) must be after start ({self.start})")
        return self


TurnDirection = Literal["right", "left"]
#: The target models a [target] may name besides its maneuvers; at most one per scenario.
TARGET_PATTERNS = ("circle", "weave", "turn", "stop_and_go", "singer", "segments", "trajectory")


class CircleConfig(_Strict):
    """[target.circle]: a coordinated turn at the initial horizontal speed v, from start to end (s).

    Give radius (m; lateral acceleration v^2 / radius) or turn_rate (rad/s; v * turn_rate).
    The vertical velocity of initial_velocity is kept: with a climb it is a helix.
    """

    radius: Distance | None = None
    turn_rate: Annotated[float, Field(gt=0.0, le=MAX_CIRCLE_TURN_RATE)] | None = None
    direction: TurnDirection = "right"
    start: NonNegativeDuration = 0.0
    end: WindowEnd = MAX_WINDOW_END_S

    @model_validator(mode="after")
    def _one_size(self) -> "CircleConfig":
        if (self.radius is None) == (self.turn_rate is None):
            raise ValueError("give radius or turn_rate (one of them)")
        if self.end <= self.start:
            raise ValueError(f"end ({self.end}) must be after start ({self.start})")
        return self


class WeaveConfig(_Strict):
    """[target.weave]: s-turns at the initial horizontal speed: +-lateral_acceleration (m/s^2)
    alternating every half_period (s) from start to end (s); the first turn (to `direction`)
    lasts half_period / 2 so the heading swings symmetrically about the initial one."""

    lateral_acceleration: Acceleration
    half_period: Duration
    direction: TurnDirection = "right"
    start: NonNegativeDuration = 0.0
    end: WindowEnd = 3600.0

    @model_validator(mode="after")
    def _ordered(self) -> "WeaveConfig":
        if self.end <= self.start:
            raise ValueError(f"end ({self.end}) must be after start ({self.start})")
        if (self.end - self.start) / self.half_period > 10000:
            raise ValueError("more than 10000 turns: shorten end or lengthen half_period")
        return self


class TurnConfig(_Strict):
    """[target.turn]: one constant-rate turn through angle_deg (default 90) in duration (s) from
    start (s), at the initial horizontal speed; turn_back: the opposite turn right after it
    (the flight experiment's IX-B2 shape)."""

    start: NonNegativeDuration
    duration: Duration
    angle_deg: Annotated[float, Field(gt=0.0, le=360.0)] = 90.0
    direction: TurnDirection = "right"
    turn_back: bool = False


class SpeedChangeConfig(_Strict):
    """From start (s) on the stop-and-go target aims at speed (m/s; 0 = stop)."""

    start: NonNegativeDuration
    speed: NonNegativeSpeed


class StopAndGoConfig(_Strict):
    """[target.stop_and_go]: straight along initial_velocity's direction (its norm is the first
    speed), the speed following `schedule` at up to max_acceleration (m/s^2)."""

    max_acceleration: Acceleration = 1.0
    schedule: Annotated[tuple[SpeedChangeConfig, ...], FROM_ARRAY, Field(min_length=1)]

    @model_validator(mode="after")
    def _ordered(self) -> "StopAndGoConfig":
        starts = [change.start for change in self.schedule]
        if any(later <= earlier for earlier, later in zip(starts, starts[1:])):
            raise ValueError("schedule: starts must increase strictly")
        return self


#: s: the shortest [target.singer] update_period (SingerConfig).
MIN_SINGER_UPDATE_PERIOD = 1e-3


class SingerConfig(_Strict):
    """[target.singer]: random acceleration, first-order Gauss-Markov (Singer): time_constant tau (s),
    stationary std sigma (m/s^2, north and east) and vertical_sigma (down; 0 = level), held over
    update_period (s); speed kept within [0, max_speed] (m/s) and the acceleration normal to the
    velocity within max_lateral_acceleration (m/s^2). Drawn on its own stream of the flight's seed."""

    time_constant: Duration = 5.0
    sigma: Acceleration = 1.0
    vertical_sigma: Annotated[float, Field(ge=0.0, le=MAX_ACCELERATION_M_S2)] = 0.0
    max_speed: Speed = 10.0
    max_lateral_acceleration: Acceleration = 2.0
    # At least 1 ms (1 kHz, twice the default physics rate): a shorter hold changes nothing a 500 Hz plant resolves,
    # and each update costs about 1 us of wall time, so 1e-300 s would never finish a flight.
    update_period: Annotated[float, Field(ge=MIN_SINGER_UPDATE_PERIOD, le=1.0)] = 0.02


def _bounded_speed(value: tuple[float, float, float]) -> tuple[float, float, float]:
    speed = math.sqrt(sum(component**2 for component in value))
    if speed > MAX_SEGMENT_SPEED:
        raise ValueError(f"speed {speed:g} m/s exceeds {MAX_SEGMENT_SPEED:g} m/s")
    return value


SegmentDuration = Annotated[float, Field(gt=0.0, le=MAX_SEGMENT_DURATION)]
SegmentAcceleration = Annotated[float, Field(gt=0.0, le=MAX_SEGMENT_ACCELERATION)]
SegmentVelocity = Annotated[tuple[float, float, float], FROM_ARRAY, AfterValidator(_finite_vector),
                            AfterValidator(_bounded_speed)]


class HoverSegment(_Strict):
    """kind = "hover": hold the position (velocity 0) for duration (s). The target must be at rest when it starts
    (after a brake, an accelerate to [0, 0, 0] or a zero initial_velocity)."""

    kind: Literal["hover"]
    duration: SegmentDuration


class AccelerateSegment(_Strict):
    """kind = "accelerate": change the velocity to `velocity` (m/s, NED, |v| <= 100) along the straight line in
    velocity space, at max_acceleration (m/s^2, <= 50). The segment ends when the velocity is reached, or after
    duration (s) if given, flying the new velocity for the rest of it; duration must cover the change."""

    kind: Literal["accelerate"]
    velocity: SegmentVelocity
    max_acceleration: SegmentAcceleration = 1.0
    duration: SegmentDuration | None = None


class CruiseSegment(_Strict):
    """kind = "cruise": hold the velocity for duration (s)."""

    kind: Literal["cruise"]
    duration: SegmentDuration


class TurnSegment(_Strict):
    """kind = "turn": a constant-rate horizontal turn at rate (rad/s about NED down, 0 < |rate| <= 3: + turns right,
    heading increasing; - left) for duration (s) or through angle_deg (deg, > 0: the duration is angle / |rate|),
    one of the two. The horizontal speed (which must be nonzero) and the vertical velocity are kept: a climbing
    turn is a helix. The lateral acceleration |rate| x horizontal speed must stay within 50 m/s^2."""

    kind: Literal["turn"]
    rate: Annotated[float, Field(ge=-MAX_TURN_RATE, le=MAX_TURN_RATE)]
    duration: SegmentDuration | None = None
    angle_deg: Annotated[float, Field(gt=0.0, le=36000.0)] | None = None

    @model_validator(mode="after")
    def _one_length(self) -> "TurnSegment":
        if self.rate == 0.0:
            raise ValueError("rate must be nonzero (rad/s; + right, - left); a straight flight is kind = \"cruise\"")
        if (self.duration is None) == (self.angle_deg is None):
            raise ValueError("give duration or angle_deg (one of them)")
        if self.turn_time > MAX_SEGMENT_DURATION:
            raise ValueError(f"angle_deg / |rate| = {self.turn_time:g} s exceeds {MAX_SEGMENT_DURATION:g} s")
        return self

    @property
    def turn_time(self) -> float:
        """s: duration, or angle_deg / |rate|."""
        return self.duration if self.duration is not None else math.radians(self.angle_deg) / abs(self.rate)


class ClimbSegment(_Strict):
    """kind = "climb": change the vertical speed to rate (m/s, + up, - descends, 0 levels off; |rate| <= 100) at
    max_acceleration (m/s^2), keeping the horizontal velocity. Ends when the rate is reached, or after duration (s)
    if given, climbing at the new rate for the rest of it; duration must cover the change."""

    kind: Literal["climb"]
    rate: Annotated[float, Field(ge=-MAX_SEGMENT_SPEED, le=MAX_SEGMENT_SPEED)]
    max_acceleration: SegmentAcceleration = 1.0
    duration: SegmentDuration | None = None


class BrakeSegment(_Strict):
    """kind = "brake": decelerate to rest along the velocity at max_acceleration (m/s^2); the segment ends at rest,
    |v| / max_acceleration s later, |v|^2 / (2 max_acceleration) m further."""

    kind: Literal["brake"]
    max_acceleration: SegmentAcceleration = 1.0


TargetSegment = Annotated[HoverSegment | AccelerateSegment | CruiseSegment | TurnSegment | ClimbSegment | BrakeSegment,
                          Field(discriminator="kind")]


def _check_segments(initial_velocity: tuple[float, float, float], segments: tuple) -> None:
    """The velocity at each segment's start (m/s, NED), followed in closed form, fits that segment: a hover starts
    at rest, a turn with a horizontal speed and within the lateral acceleration bound, an accelerate or climb with a
    duration long enough for its change. ValueError naming the segment otherwise."""
    north, east, down = initial_velocity
    for index, segment in enumerate(segments):
        where = f"segments[{index}] ({segment.kind})"
        if segment.kind == "hover":
            if (north, east, down) != (0.0, 0.0, 0.0):
                speed = math.sqrt(north**2 + east**2 + down**2)
                raise ValueError(f"{where}: the target still moves at {speed:g} m/s when the hover starts; brake "
                                 "(or accelerate to [0, 0, 0]) before it")
        elif segment.kind in ("accelerate", "climb"):
            goal = segment.velocity if segment.kind == "accelerate" else (north, east, -segment.rate)
            change = math.sqrt(sum((b - a) ** 2 for a, b in zip((north, east, down), goal)))
            takes = change / segment.max_acceleration
            if segment.duration is not None and segment.duration < takes * (1.0 - 1e-12):  # rounding is no error
                raise ValueError(f"{where}: duration {segment.duration:g} s is shorter than the {takes:g} s the "
                                 f"change of {change:g} m/s takes at max_acceleration {segment.max_acceleration:g} m/s^2")
            north, east, down = goal
        elif segment.kind == "turn":
            horizontal = math.hypot(north, east)
            if horizontal < 1e-6:
                raise ValueError(f"{where}: the target has no horizontal speed to turn (accelerate first)")
            if abs(segment.rate) * horizontal > MAX_SEGMENT_ACCELERATION:
                raise ValueError(f"{where}: |rate| x horizontal speed = {abs(segment.rate) * horizontal:g} m/s^2 "
                                 f"exceeds {MAX_SEGMENT_ACCELERATION:g} m/s^2")
            angle = segment.rate * segment.turn_time
            north, east = (north * math.cos(angle) - east * math.sin(angle),
                           north * math.sin(angle) + east * math.cos(angle))
        elif segment.kind == "brake":
            north, east, down = 0.0, 0.0, 0.0


#: The largest recorded trajectory file read, bytes: 64 MiB (an hour of 50 Hz CSV is about 10 MB).
MAX_TRAJECTORY_BYTES = 64 * 1024 * 1024
#: File extensions that tell a trajectory's format (TrajectoryConfig.format).
TRAJECTORY_EXTENSIONS = {".csv": "csv", ".ulg": "ulog"}


class TrajectoryConfig(_Strict):
    """[target.trajectory]: a recorded track, replayed through a C2 cubic spline.

    file: the track, relative to the scenario file's folder or absolute (load_scenario makes it absolute).
    format: "csv" (header t,north,east,down: s, m NED) or "ulog" (PX4 ULog, topic vehicle_local_position: timestamp
    us, x, y, z m NED); by default from the extension (.csv, .ulg). skip: s of the file, from its first sample, left
    out (0 to a day). start: the scenario time (s, 0 to a day) at which the replay starts; before it the target
    hovers at the replay's first point. That point is put at [target] initial_position (the track is translated,
    not rotated). After the file's last sample the target flies on at the spline's final velocity.
    """

    file: Annotated[str, Field(min_length=1)]
    format: Literal["csv", "ulog"] | None = None
    skip: Annotated[float, Field(ge=0.0, le=MAX_SEGMENT_DURATION)] = 0.0
    start: Annotated[float, Field(ge=0.0, le=MAX_SEGMENT_DURATION)] = 0.0

    @model_validator(mode="after")
    def _format_known(self) -> "TrajectoryConfig":
        if self.format is None and Path(self.file).suffix.lower() not in TRAJECTORY_EXTENSIONS:
            raise ValueError(f"cannot tell the format of {self.file!r} from its extension: name it .csv or .ulg, "
                             "or give format = \"csv\" or \"ulog\"")
        return self

    @property
    def file_format(self) -> str:
        """"csv" or "ulog": format, or the one the extension tells."""
        return self.format or TRAJECTORY_EXTENSIONS[Path(self.file).suffix.lower()]


class TargetConfig(_Strict):
    """[target]: initial state (m, m/s, NED) and its motion: constant velocity plus `maneuvers`
    (constant-speed horizontal turns), or one named model: circle, weave, turn, stop_and_go, singer,
    segments (a list of hover, accelerate, cruise, turn, climb and brake segments flown in order from
    initial_velocity; after the last one the target holds its final velocity) or trajectory (a recorded
    track, [target.trajectory]; it gives the velocity, so initial_velocity is left out)."""

    initial_position: Position
    initial_velocity: Velocity | None = None
    maneuvers: Annotated[tuple[ManeuverConfig, ...], FROM_ARRAY] = ()
    circle: CircleConfig | None = None
    weave: WeaveConfig | None = None
    turn: TurnConfig | None = None
    stop_and_go: StopAndGoConfig | None = None
    singer: SingerConfig | None = None
    # The emptiness check is _no_overlap's: a Field(min_length=1) would also report every list whose items fail.
    segments: Annotated[tuple[TargetSegment, ...], FROM_ARRAY, Field(max_length=MAX_SEGMENTS)] | None = None
    trajectory: TrajectoryConfig | None = None

    @model_validator(mode="after")
    def _no_overlap(self) -> "TargetConfig":
        ordered = sorted(self.maneuvers, key=lambda m: m.start)
        for earlier, later in zip(ordered, ordered[1:]):
            if later.start < earlier.end:
                raise ValueError(f"maneuvers overlap: [{earlier.start}, {earlier.end}] and [{later.start}, {later.end}]")
        named = [name for name in TARGET_PATTERNS if getattr(self, name) is not None]
        if len(named) + bool(self.maneuvers) > 1:
            raise ValueError(f"give maneuvers or one of {', '.join(TARGET_PATTERNS)}, not several "
                             f"(got {', '.join(named + (['maneuvers'] if self.maneuvers else []))})")
        if self.trajectory is not None:
            if self.initial_velocity is not None:
                raise ValueError("trajectory gives the velocity: leave initial_velocity out")
            return self
        if self.initial_velocity is None:
            raise ValueError("initial_velocity (m/s, NED) is required unless [target.trajectory] gives the motion")
        turning = bool(self.maneuvers) or any(getattr(self, name) is not None for name in ("circle", "weave", "turn"))
        if turning and math.hypot(*self.initial_velocity[:2]) < 1e-6:
            raise ValueError("a turning target needs a nonzero horizontal initial_velocity")
        speed = math.sqrt(sum(component**2 for component in self.initial_velocity))
        if self.stop_and_go is not None and speed < 1e-6:
            raise ValueError("stop_and_go needs a nonzero initial_velocity (its direction is the track)")
        if self.singer is not None and speed > self.singer.max_speed:
            raise ValueError(f"initial speed {speed:g} m/s exceeds singer.max_speed {self.singer.max_speed:g}")
        if self.segments is not None:
            if not self.segments:
                raise ValueError("segments: give at least one segment")
            if speed > MAX_SEGMENT_SPEED:
                raise ValueError(f"initial speed {speed:g} m/s exceeds {MAX_SEGMENT_SPEED:g} m/s")
            _check_segments(self.initial_velocity, self.segments)
        return self
