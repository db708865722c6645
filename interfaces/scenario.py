"""Scenario and vehicle files (TOML), validated strictly.

A scenario names a vehicle file (path relative to the scenario file) and sets the
pursuer, target, sensor, estimator, guidance and simulation. Unknown or mistyped
keys, non-finite numbers and impossible values are rejected with a ConfigError that
names the file and the key; nothing half-runs. A target replaying a recorded track
([target.trajectory]) names its file relative to the scenario file too: the loaders
read and check it and make the path absolute (docs/targets.md).
"""

from __future__ import annotations

import math
import os
import re
import stat
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, TypeVar, get_args

from interfaces.derived_defaults import (DROPOUT_MIN_RANGE_FACTOR, DROPOUT_SAFE_RANGE_FACTOR,
                                         HEALTH_MIN_RANGE_FACTOR, dropout_min_range, dropout_safe_range,
                                         health_min_range)
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict, ValidationError, field_validator, model_validator


class ConfigError(ValueError):
    """A configuration file is missing, unreadable or invalid; the message names the key."""


def _finite_vector(value: tuple[float, float, float]) -> tuple[float, float, float]:
    if not all(math.isfinite(component) for component in value):
        raise ValueError("all three components must be finite numbers")
    return value


#: TOML has arrays, not tuples: a tuple field takes a list for its container; its items stay strict.
FROM_ARRAY = Strict(False)
Vector3 = Annotated[tuple[float, float, float], FROM_ARRAY, AfterValidator(_finite_vector)]
Positive = Annotated[float, Field(gt=0.0)]
NonNegative = Annotated[float, Field(ge=0.0)]


#: The repository's config folder: airframes in vehicles/, flights in scenarios/.
CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
SCENARIOS_DIR = CONFIG_DIR / "scenarios"
VEHICLES_DIR = CONFIG_DIR / "vehicles"
#: The paper's section VIII-A1 constant-velocity flight, every command's default.
DEFAULT_SCENARIO = SCENARIOS_DIR / "constant_velocity.toml"


#: The largest scenario or vehicle file read, bytes: 16 MiB. The shipped files are under 5 kB and a scenario with a
#: 100,000-entry maneuvers list is about 8 MB (it loads); anything bigger is not a configuration, and without a cap a
#: huge or growing file would be read into memory whole.
MAX_CONFIG_BYTES = 16 * 1024 * 1024


def read_regular_file(path: Path, limit: int, noun: str = "configuration file") -> bytes:
    """The bytes of `path`, a readable regular file (not a directory, device or pipe: /dev/zero never ends, a FIFO
    blocks) of at most `limit` bytes; else ConfigError, one line naming the file. noun: what the file should be,
    for the messages."""
    try:
        # O_NONBLOCK: opening a FIFO must not wait for a writer (it is refused just below, after fstat, which
        # also judges the file actually opened); it changes nothing for a regular file.
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except PermissionError:
        raise ConfigError(f"{path}: cannot be read: permission denied") from None
    except (OSError, ValueError) as error:  # ValueError: a NUL byte in the path
        raise ConfigError(f"{path}: cannot be read: {getattr(error, 'strerror', None) or error}") from None
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise ConfigError(f"{path}: not a regular file (a directory, device or pipe is no {noun})")
        with os.fdopen(descriptor, "rb", closefd=False) as handle:
            data = handle.read(limit + 1)
    except OSError as error:
        raise ConfigError(f"{path}: cannot be read: {error.strerror or error}") from None
    finally:
        os.close(descriptor)
    if len(data) > limit:
        raise ConfigError(f"{path}: larger than {limit // 2**20} MiB, too large for a {noun}")
    return data


def _read_toml(path: Path) -> dict:
    """The TOML document in `path`. ConfigError, one line naming the file, unless it is a readable regular file
    of at most MAX_CONFIG_BYTES bytes (read_regular_file) of UTF-8 TOML that tomllib can read (no nesting deeper
    than Python's recursion limit, no integer literal longer than Python's 4300 digits)."""
    data = read_regular_file(path, MAX_CONFIG_BYTES)
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not UTF-8 text (byte {data[error.start]:#04x} at offset {error.start}); "
                          "TOML files are UTF-8") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML: arrays or inline tables nested too deeply") from None
    except ValueError as error:  # an integer literal over Python's int_max_str_digits
        reason = (f"an integer literal has more than {sys.get_int_max_str_digits()} digits" if "digits" in str(error)
                  else str(error).splitlines()[0])
        raise ConfigError(f"{path}: not valid TOML: {reason}") from None


#: The paper's Table I airframe. Its numbers live in this file only: VehicleConfig's defaults
#: are read from it, and the plant builds its parameters from a VehicleConfig.
PAPER_TABLE1 = VEHICLES_DIR / "paper_table1.toml"
_TABLE1 = _read_toml(PAPER_TABLE1)


class _Strict(BaseModel):
    """Every section: unknown keys refused, no NaN/inf, no coercion (the string "12" is not the
    number 12; an integer is accepted where a float is expected, as TOML writes `8` for 8.0)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


class VehicleConfig(_Strict):
    """Airframe and the autopilot-side limits; SI units. A key a vehicle file leaves out takes
    the paper's Table I value from config/vehicles/paper_table1.toml (PAPER_TABLE1)."""

    name: str = "quadrotor"
    mass: Positive = _TABLE1["mass"]
    gravity: Positive = _TABLE1["gravity"]
    inertia: Vector3 = tuple(_TABLE1["inertia"])
    arm_length: Positive = _TABLE1["arm_length"]
    thrust_coefficient: Positive = _TABLE1["thrust_coefficient"]
    moment_coefficient: Positive = _TABLE1["moment_coefficient"]
    motor_time_constant: Positive = _TABLE1["motor_time_constant"]
    drag_coefficient: NonNegative = _TABLE1["drag_coefficient"]
    max_thrust_to_weight: Annotated[float, Field(gt=1.0, le=5.0)] = _TABLE1["max_thrust_to_weight"]
    attitude_kp: Positive = _TABLE1["attitude_kp"]
    attitude_kd: Positive = _TABLE1["attitude_kd"]
    position_noise_std: NonNegative = _TABLE1["position_noise_std"]
    velocity_noise_std: NonNegative = _TABLE1["velocity_noise_std"]
    # Own-state feedback error model: 0 (the default) draws the noise above independently at
    # every read-out (white, section VIII); tau > 0 makes it first-order Gauss-Markov with that
    # time constant, s, and the same stationary std (an autopilot's fused position error is
    # correlated over seconds, not independent at 50 Hz).
    position_noise_time_constant: NonNegative = 0.0
    velocity_noise_time_constant: NonNegative = 0.0
    max_tilt_deg: Annotated[float, Field(gt=0.0, lt=80.0)] = _TABLE1["max_tilt_deg"]

    @model_validator(mode="after")
    def _inertia_positive(self) -> "VehicleConfig":
        if min(self.inertia) <= 0.0:
            raise ValueError("inertia: all principal moments must be positive")
        return self


class PursuerConfig(_Strict):
    initial_position: Vector3 = (0.0, 0.0, 0.0)
    initial_velocity: Vector3 = (0.0, 0.0, 0.0)


class ManeuverConfig(_Strict):
    """A constant-speed horizontal turn: lateral acceleration (m/s^2, + = right turn in NED) from start to end (s)."""

    start: NonNegative
    end: NonNegative
    lateral_acceleration: float

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

    radius: Positive | None = None
    turn_rate: Positive | None = None
    direction: TurnDirection = "right"
    start: NonNegative = 0.0
    end: Positive = 1e6

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

    lateral_acceleration: Positive
    half_period: Positive
    direction: TurnDirection = "right"
    start: NonNegative = 0.0
    end: Positive = 3600.0

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

    start: NonNegative
    duration: Positive
    angle_deg: Annotated[float, Field(gt=0.0, le=360.0)] = 90.0
    direction: TurnDirection = "right"
    turn_back: bool = False


class SpeedChangeConfig(_Strict):
    """From start (s) on the stop-and-go target aims at speed (m/s; 0 = stop)."""

    start: NonNegative
    speed: NonNegative


class StopAndGoConfig(_Strict):
    """[target.stop_and_go]: straight along initial_velocity's direction (its norm is the first
    speed), the speed following `schedule` at up to max_acceleration (m/s^2)."""

    max_acceleration: Positive = 1.0
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

    time_constant: Positive = 5.0
    sigma: Positive = 1.0
    vertical_sigma: NonNegative = 0.0
    max_speed: Positive = 10.0
    max_lateral_acceleration: Positive = 2.0
    # At least 1 ms (1 kHz, twice the default physics rate): a shorter hold changes nothing a 500 Hz plant resolves,
    # and each update costs about 1 us of wall time, so 1e-300 s would never finish a flight.
    update_period: Annotated[float, Field(ge=MIN_SINGER_UPDATE_PERIOD, le=1.0)] = 0.02


#: Bounds of [target] segments: a segment lasts at most a day (s); accelerations up to 50 m/s^2 (5 g, beyond any
#: small drone); speeds and climb rates up to 100 m/s; turn rates up to 3 rad/s (a full turn in about 2 s); at most
#: 10000 segments (a longer plan is a recorded track: [target.trajectory]).
MAX_SEGMENT_DURATION = 86400.0
MAX_SEGMENT_ACCELERATION = 50.0
MAX_SEGMENT_SPEED = 100.0
MAX_TURN_RATE = 3.0
MAX_SEGMENTS = 10000


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

    initial_position: Vector3
    initial_velocity: Vector3 | None = None
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


PositiveInt = Annotated[int, Field(gt=0)]


class CameraConfig(_Strict):
    """Pin-hole camera of the paper's simulation (section VIII, Table I), used when sensor.model = 'camera'.

    focal_length: m. pixel_size: (rho_w, rho_h), m. principal_point: (u0, v0), px,
    inside the image. image_size: (width, height), px. pixel_noise_std: detector noise
    on the image point, px per axis (before the pixel-grid quantisation).
    mount_rpy_deg: camera relative to body (roll, pitch, yaw; ZYX, deg; pitch > 0 looks
    up); zero = looking along body +x, no gimbal.
    """

    focal_length: Positive = 0.008
    pixel_size: Annotated[tuple[Positive, Positive], FROM_ARRAY] = (1e-5, 1e-5)
    principal_point: Annotated[tuple[float, float], FROM_ARRAY] = (512.0, 512.0)
    image_size: Annotated[tuple[PositiveInt, PositiveInt], FROM_ARRAY] = (1024, 1024)
    pixel_noise_std: NonNegative = 1.0
    mount_rpy_deg: Vector3 = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _principal_point_in_image(self) -> "CameraConfig":
        (u0, v0), (width, height) = self.principal_point, self.image_size
        if not (-0.5 <= u0 <= width - 0.5 and -0.5 <= v0 <= height - 0.5):
            raise ValueError(f"principal_point ({u0}, {v0}) must lie inside the {width} x {height} image")
        return self


MAX_BEARING_NOISE_STD = 10.0
"""Largest accepted [sensor] noise_std (unit-vector units for 'additive', rad for 'rotation')."""
MAX_RANGE_NOISE_STD = 1.0e4
"""m: largest accepted [sensor] range_noise_std."""


class RangeDependentNoise(_Strict):
    """Seed 003 eq. (15)-(16): sigma_r^2 = a2 (r - a1)^2 + a0 for the range, alpha times that for
    each bearing angle (r the true range, m). Defaults: the seed's case 3."""

    a0: Positive = 1.0
    """m^2: the variance at r = a1 (its minimum)."""
    a1: NonNegative = 1.0
    """m: the range of least noise."""
    a2: NonNegative = 0.0024
    """dimensionless: growth of the variance with (r - a1)^2."""
    alpha: Positive = 1e-5
    """rad^2/m^2: angle variance per m^2 of range variance."""


class SensorConfig(_Strict):
    """Bearing sensor: 'additive' is eq. (4) (nu ~ N(0, noise_std^2 I)); 'rotation' is eq. (25)
    (epsilon ~ N(0, noise_std^2)); 'camera' is the pin-hole camera of section VIII ([sensor.camera];
    noise_std is then unused).

    Accepted noise: every noise_std in [0, MAX_BEARING_NOISE_STD], range_noise_std in
    [0, MAX_RANGE_NOISE_STD] m and any finite pixel_noise_std >= 0 flies: the estimators stay
    finite however far the bearings are from the Sigma they were given, though a bearing with
    noise_std near 1 carries almost no information and the estimate is then poor. Larger values
    are refused: beyond a few units the measured direction is indistinguishable from a uniformly
    random one, and at 1e150 and above the noise overflows the bearing arithmetic."""

    model: Literal["additive", "rotation", "camera"] = "additive"
    noise_std: NonNegative = 0.01
    rate_hz: Positive = 5.0
    camera: CameraConfig = CameraConfig()
    range_noise_std: NonNegative | None = None
    """m. A range sensor beside the bearing (seed 003's measurement set): every bearing then
    also carries |p_T - p| + N(0, range_noise_std^2). None (default): bearings only."""
    noise_time_constant: Positive | None = None
    """s. Coloured noise (seed 003 case 2): the bearing noise (model 'additive') and the range
    noise become first-order Gauss-Markov processes with this time constant and the same
    stationary std, sampled at rate_hz. None (default): white noise."""
    range_dependent_noise: RangeDependentNoise | None = None
    """Seed 003 case 3 (eq. (15)-(16)): the noise std follows the true range, sqrt(sigma_r^2) for the
    range and sqrt(alpha sigma_r^2) per bearing axis, replacing range_noise_std and noise_std in the
    sensor (the estimators keep their configured constant noise). Not for model 'camera'."""

    @model_validator(mode="after")
    def _noise_options_fit_the_model(self) -> "SensorConfig":
        if self.noise_time_constant is not None and self.model != "additive":
            raise ValueError(f"noise_time_constant (coloured noise) needs model = 'additive', got {self.model!r}")
        if self.range_dependent_noise is not None and self.model == "camera":
            raise ValueError("range_dependent_noise does not apply to the camera (its noise is in pixels)")
        return self

    @field_validator("noise_std")
    @classmethod
    def _bearing_noise_carries_information(cls, value: float) -> float:
        if value > MAX_BEARING_NOISE_STD:
            raise ValueError(
                f"must be at most {MAX_BEARING_NOISE_STD:g}, got {value!r}: with noise of that size per axis the "
                "measured bearing is a uniformly random direction (the true line of sight has length 1), so no "
                "estimator can follow it")
        return value

    @field_validator("range_noise_std")
    @classmethod
    def _range_noise_carries_information(cls, value: float | None) -> float | None:
        if value is not None and value > MAX_RANGE_NOISE_STD:
            raise ValueError(
                f"must be at most {MAX_RANGE_NOISE_STD:g} m, got {value!r}: a range sensor with noise of 10 km "
                "and more says nothing about a target followed at metres; leave range_noise_std out for bearings only")
        return value


class EstimatorConfig(_Strict):
    """Target estimator. kind 'imm' (the default since issue 13) is the interacting-multiple-model
    estimator over u-PLKF model filters (constant velocity and left/right coordinated turns, options
    imm_*; README "IMM estimator"): as accurate as the u-PLKF on constant-velocity targets and the
    one that follows sustained turns (docs/reproduction.md 5.6). kind 'uplkf' is the paper's
    u-PLKF (section IV) alone; gain_projection 'measured' is its exact form, 'predicted' the
    default (README), 'noise_free' the simulation-only "optimal u-PLKF" of section VIII-B. The
    baselines: 'ekf' (azimuth/elevation, Cartesian state, the paper's classic EKF), 'msc_ekf'
    (modified spherical coordinates), 'ekf_rae' (seed 003: range/azimuth/elevation; needs
    [sensor] range_noise_std). initialize: 'bearing' starts on the
    first bearing at the range guess (remark 3); 'position' starts at initial_position itself with
    an isotropic initial_range_std (the initialisation study of section VIII-B)."""

    kind: Literal["uplkf", "ekf", "msc_ekf", "ekf_rae", "imm"] = "imm"
    gain_projection: Literal["predicted", "measured", "noise_free"] = "predicted"
    initialize: Literal["bearing", "position"] = "bearing"
    rate_hz: Positive = 50.0
    process_noise: Positive = 0.04
    adaptive_process_noise: bool = False
    """u-PLKF only. True: Q = s process_noise I with a scale 1 <= s <= adaptive_max_scale raised while
    the innovations are larger than the filter claims (mean NIS per degree of freedom above
    adaptive_nis_threshold) and relaxed back to 1 when they are not (README "Estimators";
    companion.core.estimators.AdaptiveProcessNoise). False (default): the constant Q."""
    adaptive_max_scale: float = Field(25.0, ge=1.0)
    adaptive_nis_time_constant: Positive = 2.0
    """s, of the running mean of the NIS per degree of freedom."""
    adaptive_rise_time_constant: Positive = 2.0
    """s, of the scale's growth while that mean exceeds adaptive_nis_threshold."""
    adaptive_relax_time_constant: Positive = 10.0
    """s, of its return to 1 while the mean is below 1."""
    adaptive_nis_threshold: float = Field(3.0, gt=1.0)
    imm_turn_rates: Annotated[tuple[float, ...], FROM_ARRAY] = (0.2,)
    """kind 'imm' only: omega, rad/s, of the coordinated-turn models (README "IMM estimator"); each rate
    gives a right (+omega) and a left (-omega) model beside the constant-velocity one. Each in
    (0, IMM_MAX_TURN_RATE]; an empty list leaves the constant-velocity model alone (the u-PLKF)."""
    imm_turn_process_noise: Positive = 0.04
    """kind 'imm' only: q of the turn models, (m/s^2)^2 per axis (the constant-velocity model uses process_noise)."""
    imm_manoeuvre_model: bool = False
    """kind 'imm' only: add the manoeuvre model (white-noise acceleration, q = (target_max_acceleration / 3)^2
    per axis) for a target that changes speed: hovers, dashes, brakes. False (default): the constant-velocity
    and turn models alone; with the safety envelope the manoeuvre model lost weaving and tightly circling
    targets that the default set keeps (docs/safety.md)."""
    target_max_acceleration: Annotated[float, Field(gt=0.0, le=30.0)] = 3.0
    """m/s^2: the largest acceleration (or braking) the followed target is expected to have: the IMM's
    manoeuvre model's noise, and the braking the safety envelope plans for ([safety])."""
    imm_stay_probability: float = Field(0.98, gt=0.0, le=1.0)
    """kind 'imm' only: p_ii, the probability that the target keeps its motion model over imm_stay_time s
    (seed 004: 0.98, the rest split evenly over the other models)."""
    imm_stay_time: Positive = 1.0
    """kind 'imm' only: s, the interval imm_stay_probability refers to (p_ii = p^(Delta / imm_stay_time)
    over a correction interval Delta, so the switching is the same at any bearing rate)."""
    measurement_noise: Positive = 1e-4
    pursuer_position_std: NonNegative = 0.1
    restart_when_behind: bool = True
    initial_position: Vector3 | None = None
    initial_range: Positive | None = None
    initial_range_std: Positive = 30.0
    initial_velocity: Vector3 = (0.0, 0.0, 0.0)
    initial_velocity_std: Positive = 5.0

    @model_validator(mode="after")
    def _has_range_guess(self) -> "EstimatorConfig":
        if self.initial_position is None and self.initial_range is None:
            raise ValueError("set initial_range or initial_position (the range guess along the first bearing)")
        if self.initialize == "position" and self.initial_position is None:
            raise ValueError("initialize = 'position' needs initial_position")
        if self.adaptive_process_noise and self.kind != "uplkf":
            raise ValueError(f"adaptive_process_noise is implemented for kind = 'uplkf' only, got {self.kind!r} "
                             "(the default kind is 'imm': set kind = 'uplkf' with it)")
        for rate in self.imm_turn_rates:
            if not (math.isfinite(rate) and 0.0 < rate <= IMM_MAX_TURN_RATE):
                raise ValueError(f"imm_turn_rates: each turn rate must be in (0, {IMM_MAX_TURN_RATE:g}] rad/s, got {rate!r} "
                                 "(a rate gives both a right and a left model)")
        if len(set(self.imm_turn_rates)) != len(self.imm_turn_rates):
            raise ValueError(f"imm_turn_rates: a rate is repeated in {self.imm_turn_rates!r}")
        if self.kind != "imm":
            changed = [name for name in IMM_OPTIONS if getattr(self, name) != type(self).model_fields[name].default]
            if changed:
                raise ValueError(f"{', '.join(changed)} applies to kind = 'imm' only, not to kind = {self.kind!r}")
        return self


IMM_MAX_TURN_RATE = 2.0
"""rad/s: the largest turn rate an IMM model may assume (a 2 m/s^2 turn at 1 m/s; a multirotor target
turning faster is hovering, which the constant-velocity model covers)."""
IMM_OPTIONS = ("imm_turn_rates", "imm_turn_process_noise", "imm_stay_probability", "imm_stay_time", "imm_manoeuvre_model")


GUIDANCE_LAWS = ("hng", "ppg", "png", "pd", "retro_png", "zem", "seed003")


class GuidanceConfig(_Strict):
    """Guidance law (section VI; baselines of section VIII-C). 'hng' helical navigation (eq. 14;
    c_y = 0 is planar weaving), 'ppg' pure pursuit, 'png' 3-D proportional navigation, 'pd' the
    PD controller (k_p, k_d; replaces the range controller), 'retro_png' retro-PNG of refs
    [14]/[16] per horizontal/vertical plane (retro_gain), 'zem' the ZEM-based law of ref. [43]
    (zem_k_w, zem_max_gain), 'seed003' seed 003's backstepping speed / flight-path / course law
    (eq. (5)-(8), sign erratum fixed; seed003_alpha, seed003_gain, seed003_max_approach_speed), holding
    desired_range behind the target. All but 'pd' and 'seed003' add the range controller of eq. (18)."""

    law: Literal["hng", "ppg", "png", "pd", "retro_png", "zem", "seed003"] = "hng"
    navigation_gain: Positive = 3.0
    c_z: NonNegative = 3.5
    c_y: NonNegative = 3.5
    weave_frequency: Positive = 1.0
    scale_with_range: bool = True
    desired_range: Positive = 8.0
    range_gain: Positive = 3.0
    rate_hz: Positive = 20.0
    los_source: Literal["estimate", "measurement"] = "estimate"
    pd_kp: Positive = 0.5
    pd_kd: Positive = 0.2
    retro_gain: Positive = 2.0
    zem_k_w: Positive = 0.007
    zem_max_gain: Positive = 10.0
    seed003_alpha: Positive = 0.5
    """1/s: seed 003's position gain alpha_1 = alpha_2 = alpha_3 (the seed flies 1)."""
    seed003_gain: Positive = 1.0
    """1/s: seed 003's velocity/course gain lambda_1..3 (the seed's 50 assumes a 100/s autopilot)."""
    seed003_max_approach_speed: Positive = 3.0
    """m/s: bound on seed 003's approach velocity alpha |e| towards the following point (not in the seed)."""
    # Range excitation (issue 13; companion.core.guidance.RangeExcitation): 'none' is the paper's
    # law unchanged; 'uncertainty' adds a lateral term that makes the pursuer circle the line of
    # sight at excitation_speed (m/s, angular rate excitation_frequency rad/s) while the relative
    # range std sigma_r / r^ is above excitation_low (full above excitation_high) or the health
    # monitor says suspect. Only for 'hng' and 'ppg' (its design cancels their N P v damping).
    excitation: Literal["none", "uncertainty"] = "none"
    excitation_speed: Positive = 1.0
    excitation_frequency: Positive = 0.5
    excitation_low: NonNegative = 0.05
    excitation_high: Positive = 0.15

    @model_validator(mode="after")
    def _excitation_consistent(self) -> "GuidanceConfig":
        if self.excitation != "none":
            if self.law not in ("hng", "ppg"):
                raise ValueError(f"excitation = {self.excitation!r} needs law 'hng' or 'ppg', not {self.law!r}")
            if self.excitation_low >= self.excitation_high:
                raise ValueError("excitation_low must be below excitation_high")
        return self


#: The longest flight a scenario may ask for, s: a day. Longer is a typo for a multirotor, and an in-process flight
#: holds its whole log in memory (about 2 GB for a day at the default rates: 60 rows a second of 46 floats).
MAX_DURATION_S = 86_400.0
#: The fastest physics step a scenario may ask for, Hz: 20x the paper's 500 Hz. Faster would only make the plant
#: crawl (a 60 s flight at 1 GHz is 6e10 RK4 steps) without a visible change in a 2 ms-scale rigid body.
MAX_PHYSICS_RATE_HZ = 10_000.0


#: Range-estimation error RMS over the summary window above which a simulated flight has diverged by truth, m
#: ([simulation] divergence_rms; studies.metrics.summarize's "truth").
DIVERGENCE_RMS_M = 2.0
#: The largest [simulation] divergence_rms a scenario may set, m: beyond it no bearing-only estimate is judged at all.
MAX_DIVERGENCE_RMS_M = 1000.0


class SimulationConfig(_Strict):
    """The simulated flight and how it is judged. duration, summary_window: s; converged_range_error (the
    convergence threshold) and divergence_rms (range-estimation error RMS over the summary window above which the
    flight has diverged by truth): m."""

    duration: Annotated[float, Field(gt=0.0, le=MAX_DURATION_S)] = 60.0
    seed: Annotated[int, Field(ge=0)] = 0
    physics_rate_hz: Annotated[float, Field(ge=500.0, le=MAX_PHYSICS_RATE_HZ)] = 500.0
    summary_window: Positive = 20.0
    converged_range_error: Positive = 1.0
    divergence_rms: Annotated[float, Field(gt=0.0, le=MAX_DIVERGENCE_RMS_M)] = DIVERGENCE_RMS_M


Port = Annotated[int, Field(ge=1, le=65535)]
#: [sitl] speed_factor bounds, simulated s per wall s: bof-sitl's --speed-factor range.
MIN_SPEED_FACTOR, MAX_SPEED_FACTOR = 0.5, 20.0


class SitlConfig(_Strict):
    """The bundled SITL plant as a MAVLink vehicle (sitl-plant); PX4 SITL's ports and home by default.

    The vehicle starts at rest on the ground below pursuer.initial_position (local NED
    z = 0 is the ground at home), heading start_yaw_deg. parameters overrides PX4-style
    parameters of the plant (e.g. COM_OF_LOSS_T = 0.5); names and ranges are checked
    when the plant starts.
    """

    home: Vector3 = (47.397742, 8.545594, 488.0)
    # bof-sitl's --speed-factor range (studies/full_sitl.py: below 0.5 MAVSDK misses heartbeats, above 20 the plant
    # cannot keep up); sitl-plant's own --speed-factor flag, which overrides this key, takes (0, 100].
    speed_factor: Annotated[float, Field(ge=MIN_SPEED_FACTOR, le=MAX_SPEED_FACTOR)] = 1.0
    companion_host: str = "127.0.0.1"
    companion_port: Port = 14540
    gcs_host: str = "127.0.0.1"
    gcs_port: Port = 14550
    bind_host: str = "127.0.0.1"
    tick_rate_hz: Positive = 250.0
    start_yaw_deg: Annotated[float, Field(ge=-180.0, le=360.0)] = 0.0
    parameters: dict[str, float] = {}

    @model_validator(mode="after")
    def _home_on_earth(self) -> "SitlConfig":
        latitude, longitude, _ = self.home
        if not (-90.0 <= latitude <= 90.0 and -180.0 <= longitude <= 180.0):
            raise ValueError(f"home: latitude/longitude ({latitude}, {longitude}) outside [-90, 90] x [-180, 180]")
        return self


class LinkConfig(_Strict):
    """The Zenoh link: target fixes in, companion state out, commands (abort) in.

    mode: Zenoh session mode. listen/connect: Zenoh endpoints ("tcp/127.0.0.1:7447",
    "tls/host:port", ...); the command line can override them. zenoh_overrides: raw Zenoh
    configuration entries (dotted key -> JSON5 value), e.g. TLS certificates:
    {"transport.link.tls.root_ca_certificate" = '"/path/ca.pem"'}. Multicast scouting is
    off unless an override turns it on. The target publishes at sensor.rate_hz.

    Fix and command validation (companion.core.fix_validator; README "Link validation"):
    max_future_skew_s: a stamp more than this ahead of the receiver's clock is refused
    (future_stamp). max_fix_age_s: a stamp older than this is refused (too_old).
    max_fix_rate_hz: seq may advance at most this fast (per stamp second, plus 10) within
    one publisher epoch (seq_jump). reanchor_silence_s: a track of fixes inconsistent with
    the last accepted one may take over only after the accepted track has been silent this
    long (or when it agrees with the filter's predicted bearing and the old one does not).
    epoch_switch_silence_s: fixes of another publisher epoch (a restarted target) are taken
    only once the accepted epoch has been silent this long (other_epoch before).
    max_target_speed: m/s, the plausibility bound between two fixes (plus 5 m of noise).
    """

    mode: Literal["peer", "client", "router"] = "peer"
    listen: Annotated[tuple[str, ...], FROM_ARRAY] = ()
    connect: Annotated[tuple[str, ...], FROM_ARRAY] = ()
    zenoh_overrides: dict[str, str] = {}
    target_sender: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")] = "target-1"
    companion_id: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")] = "pursuer-1"
    fix_frame: Literal["geodetic", "ned"] = "geodetic"
    fix_noise_std: NonNegative = 0.0
    state_rate_hz: Positive = 5.0
    max_future_skew_s: NonNegative = 0.5
    max_fix_age_s: Positive = 10.0
    max_fix_rate_hz: Positive = 50.0
    reanchor_silence_s: Positive = 2.0
    epoch_switch_silence_s: NonNegative = 0.5
    max_target_speed: Positive = 30.0


class CompanionConfig(_Strict):
    """The companion application's mission.

    mavlink_url: MAVSDK URL of the autopilot. engage_altitude: take off to this height above
    home (m), hover settle_time (s), then engage on the first bearing. follow_duration: follow
    this long (s of vehicle time) before landing; default simulation.duration.
    link_timeout / connect_timeout: wall-clock seconds to wait for the first target fix /
    the autopilot. hold_after_abort: hover this long (s) after an abort before landing.
    vehicle_link_timeout: wall-clock seconds without odometry after which the vehicle link
    counts as lost: the companion stops commanding and lets the autopilot's offboard-loss
    failsafe act. vehicle_link_wait: how long (wall s) to wait for it to come back before
    giving up. on_vehicle_link_return: "resume" re-engages offboard and goes on following;
    "land" (the default, the operator's call) lands instead.
    """

    mavlink_url: str = "udpin://127.0.0.1:14540"
    engage_altitude: Annotated[float, Field(gt=1.0, le=120.0)] = 20.0
    settle_time: NonNegative = 1.5
    follow_duration: Annotated[float, Field(gt=0.0, le=MAX_DURATION_S)] | None = None
    link_timeout: Positive = 60.0
    connect_timeout: Positive = 30.0
    hold_after_abort: NonNegative = 3.0
    vehicle_link_timeout: Positive = 1.0
    vehicle_link_wait: Positive = 60.0
    on_vehicle_link_return: Literal["resume", "land"] = "land"


Probability = Annotated[float, Field(ge=0.0, le=1.0)]
SenderName = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
#: How a corrupted fix is broken (sitl_plant.world.link_faults documents each and the decoder's reason it earns).
CorruptKind = Literal["invalid_utf8", "truncated_json", "missing_field", "non_finite", "string_number",
                      "absurd_position"]
CORRUPT_KINDS: tuple[str, ...] = get_args(CorruptKind)


class BlackoutWindow(_Strict):
    """A link outage from start for duration, s (scenario time for the target link, plant time for MAVLink)."""

    start: NonNegative
    duration: NonNegative

    @property
    def end(self) -> float:
        return self.start + self.duration


def _check_windows(windows: tuple[BlackoutWindow, ...], key: str) -> None:
    ordered = sorted(windows, key=lambda w: w.start)
    for earlier, later in zip(ordered, ordered[1:]):
        if later.start < earlier.end:
            raise ValueError(f"{key}: windows [{earlier.start:g}, {earlier.end:g}) and "
                             f"[{later.start:g}, {later.end:g}) overlap")


class BurstLossConfig(_Strict):
    """Gilbert-Elliott bursty loss: a good/bad Markov chain stepped once per target fix.

    Give either the per-message transition probabilities (p_good_to_bad, p_bad_to_good)
    or the mean durations in seconds (mean_burst_s in the bad state, mean_gap_s in the
    good state; converted with the interval between consecutive fixes: p = interval /
    mean). loss_in_good / loss_in_bad: probability that a fix is lost in that state.
    """

    p_good_to_bad: Probability | None = None
    p_bad_to_good: Probability | None = None
    mean_burst_s: Positive | None = None
    mean_gap_s: Positive | None = None
    loss_in_good: Probability = 0.0
    loss_in_bad: Probability = 1.0

    @model_validator(mode="after")
    def _one_form(self) -> "BurstLossConfig":
        given = [name for name in ("p_good_to_bad", "p_bad_to_good", "mean_burst_s", "mean_gap_s")
                 if getattr(self, name) is not None]
        if given not in (["p_good_to_bad", "p_bad_to_good"], ["mean_burst_s", "mean_gap_s"]):
            raise ValueError("burst: give p_good_to_bad and p_bad_to_good, or mean_burst_s and mean_gap_s "
                             f"(got {', '.join(given) or 'neither'})")
        return self


class MavlinkFaultsConfig(_Strict):
    """Faults of the companion <-> vehicle MAVLink link (applied by the plant).

    blackouts: windows, s of simulated time since the plant started, during which
    the link is silent both ways.
    """

    blackouts: Annotated[tuple[BlackoutWindow, ...], FROM_ARRAY] = ()

    @model_validator(mode="after")
    def _no_overlap(self) -> "MavlinkFaultsConfig":
        _check_windows(self.blackouts, "mavlink.blackouts")
        return self


#: Hz: the fastest impostor or steady spoofer [faults] may inject (each of its messages is an event of the flight: an
#: unbounded rate never finishes and fills memory; 1 kHz is 200x the default bearing rate).
MAX_ATTACK_RATE_HZ = 1000.0


class FaultsConfig(_Strict):
    """Fault injection on the target -> companion link (sitl_plant.world.link_faults); defaults inject nothing.

    Times of blackouts are scenario time (s since the target started its scenario).
    loss_probability: independent loss per fix. burst: Gilbert-Elliott bursty loss
    ([faults.burst]). latency_s + U(0, jitter_s): delivery delay, s. reorder_probability:
    a fix is held back reorder_delay_s more (choose it above the fix period + jitter so
    the next fix overtakes it). duplicate_probability: a second copy duplicate_delay_s
    later. stale_probability: an extra copy of an older fix, stale_min_age_s to
    stale_max_age_s old. corrupt_probability: the fix is replaced by a broken one, kind
    drawn uniformly from corrupt_kinds. stalls: windows in which the target's publisher is frozen (a
    loaded machine, a stopped process): the fixes of the window are not lost but all delivered at its
    end, back to back, with their own stamps. impostor_rate_hz: a second publisher on the same
    key as impostor_sender, impostor_offset m (NED) away from the target (0 = off).
    seed: the faults' own seed (None: derived from simulation.seed). mavlink: faults of
    the MAVLink link ([faults.mavlink]).

    Attacks (sitl_plant.world.link_faults documents each; times are scenario s, None = off):
    future_seq_at: one extra copy of a genuine fix with seq + 2**62. future_stamp_at: one
    extra copy stamped 1e6 s ahead. replay_at: the last replay_count genuine fixes sent
    again, back to back. restart_at: the genuine publisher restarts (silent restart_gap_s,
    then a new epoch, seq from 0). spoof_burst_at: spoof_burst_count fixes as the target,
    spoof_offset m (NED) off, 20 ms apart. spoof_rate_hz (> 0: on, from spoof_from s): a
    steady spoofer as the target at that rate, spoof_offset m off the genuine track. The
    spoofer's seq is the genuine one + spoof_seq_lead; its epoch is its own (spoof_epoch =
    "own") or the genuine one it overheard ("target").
    """

    seed: Annotated[int, Field(ge=0)] | None = None
    loss_probability: Probability = 0.0
    burst: BurstLossConfig | None = None
    blackouts: Annotated[tuple[BlackoutWindow, ...], FROM_ARRAY] = ()
    latency_s: NonNegative = 0.0
    jitter_s: NonNegative = 0.0
    stalls: Annotated[tuple[BlackoutWindow, ...], FROM_ARRAY] = ()
    reorder_probability: Probability = 0.0
    reorder_delay_s: Positive = 0.3
    duplicate_probability: Probability = 0.0
    duplicate_delay_s: NonNegative = 0.01
    stale_probability: Probability = 0.0
    stale_min_age_s: NonNegative = 1.0
    stale_max_age_s: Positive = 5.0
    corrupt_probability: Probability = 0.0
    corrupt_kinds: Annotated[tuple[CorruptKind, ...], FROM_ARRAY, Field(min_length=1)] = CORRUPT_KINDS
    impostor_rate_hz: Annotated[float, Field(ge=0.0, le=MAX_ATTACK_RATE_HZ)] = 0.0
    impostor_sender: SenderName = "impostor-1"
    impostor_offset: Vector3 = (30.0, 0.0, 0.0)
    future_seq_at: NonNegative | None = None
    future_stamp_at: NonNegative | None = None
    replay_at: NonNegative | None = None
    replay_count: Annotated[int, Field(ge=1, le=10000)] = 25
    restart_at: NonNegative | None = None
    restart_gap_s: NonNegative = 1.0
    spoof_burst_at: NonNegative | None = None
    spoof_burst_count: Annotated[int, Field(ge=1, le=1000)] = 3
    spoof_rate_hz: Annotated[float, Field(ge=0.0, le=MAX_ATTACK_RATE_HZ)] = 0.0
    spoof_from: NonNegative = 0.0
    spoof_offset: Vector3 = (30.0, 0.0, 0.0)
    spoof_seq_lead: Annotated[int, Field(ge=0, le=2**62)] = 2**40
    spoof_epoch: Literal["own", "target"] = "own"
    mavlink: MavlinkFaultsConfig = MavlinkFaultsConfig()

    @model_validator(mode="after")
    def _consistent(self) -> "FaultsConfig":
        _check_windows(self.blackouts, "blackouts")
        _check_windows(self.stalls, "stalls")
        if self.stale_min_age_s > self.stale_max_age_s:
            raise ValueError(f"stale_min_age_s ({self.stale_min_age_s}) must not exceed stale_max_age_s "
                             f"({self.stale_max_age_s})")
        if len(set(self.corrupt_kinds)) != len(self.corrupt_kinds):
            raise ValueError("corrupt_kinds: each kind at most once")
        return self


class DropoutConfig(_Strict):
    """What the companion does when bearings stop and come back (companion.core.pipeline.DropoutPolicy).

    coast_after / coast_limit: s without a bearing before coasting / before the safe
    behaviour (hold safe_range on the predicted line of sight, no weave, never closing while
    the predicted range minus 2 sigma is under min_range). max_position_std: m, while
    coasting the safe behaviour also starts when the prediction gets this uncertain.
    gate_sigma, reacquire_bearings, restart_range_std: re-acquisition gate and restart.
    max_jerk (m/s^3) and blend_time (s): how fast the command may change after a mode change.
    safe_range / min_range default to 1.5 and 0.5 times guidance.desired_range.
    """

    coast_after: Positive = 0.6
    coast_limit: Positive = 3.0
    max_position_std: Positive = 6.0
    safe_range: Positive | None = None
    min_range: Positive | None = None
    gate_sigma: Positive = 4.0
    reacquire_bearings: Annotated[int, Field(ge=1)] = 2
    restart_range_std: Positive = 10.0
    max_jerk: Positive = 15.0
    blend_time: NonNegative = 2.0

    @model_validator(mode="after")
    def _ordered(self) -> "DropoutConfig":
        if self.coast_after > self.coast_limit:
            raise ValueError("coast_after must not exceed coast_limit")
        return self


class SafetyConfig(_Strict):
    """The safety envelope applied to every command (companion.core.safety.SafetyEnvelope), whatever the estimate.

    enabled: False flies the guidance laws' commands as they are (for studies of the laws alone). The closest
    the pursuer may come is [dropout] min_range (r_d / 2 by default). range_sigmas: k of the pessimistic range
    r^ - k sigma_r; speed_sigmas: of the target's speed away from us, v^_T . lambda - k sigma_v.
    braking_acceleration: m/s^2 the pursuer plans to brake with; default half
    of g tan(max_tilt) of the airframe. reaction_time: s until braking takes effect. velocity_gain: 1/s.
    max_yaw_rate_deg: deg/s, the setpoint heading's largest rate of turn. untrusted_range_share: the share of
    the pessimistic range counted on while the estimate is a prediction without bearings (degraded, reacquiring).
    tilt_margin_deg: deg, the setpoints' tilt limit is the airframe's max_tilt_deg less this. The
    target's largest deceleration is [estimator] target_max_acceleration.
    """

    enabled: bool = True
    range_sigmas: Annotated[float, Field(ge=0.0, le=10.0)] = 2.0
    speed_sigmas: Annotated[float, Field(ge=0.0, le=10.0)] = 0.0
    braking_acceleration: Annotated[float, Field(gt=0.0, le=30.0)] | None = None
    reaction_time: Annotated[float, Field(ge=0.0, le=5.0)] = 0.3
    velocity_gain: Annotated[float, Field(gt=0.0, le=20.0)] = 2.0
    max_yaw_rate_deg: Annotated[float, Field(gt=0.0, le=1000.0)] = 45.0
    untrusted_range_share: Annotated[float, Field(gt=0.0, le=1.0)] = 1.0
    tilt_margin_deg: Annotated[float, Field(ge=0.0, lt=20.0)] = 3.0


HealthReasonName = Literal["nis", "range_uncertain", "behind_sensor", "range_implausible", "range_unobservable"]


class HealthSection(_Strict):
    """The filter-health monitor (companion.core.health: HealthConfig, HealthActionConfig; README "Filter health").

    Monitor: nis_window s, nis_probability, nis_scale, min_nis_samples, max_relative_range_std,
    max_range_std m (sigma_r limit once the range has converged; a large value turns it off),
    min_range m (default guidance.desired_range / 4), max_range m, slow_speed m/s,
    unobservable_time s, flag_after s, clear_after s. Actions while suspect: act (default true since issue 13; false: the
    monitor only reports), process_noise_boost (factor on Q, >= 1) relaxing back to 1 with
    boost_relax_time s once OK, reinitialize_reasons (restart on the bearing at the current range
    with an along-bearing std of reinitialize_relative_std x that range, at most every
    reinitialize_interval s), excite (full range excitation while suspect; without
    [guidance] excitation, also never a stop while sigma_r / r^ > excitation_high, ramping in
    from excitation_low; lateral laws 'hng' and 'ppg' only), boost_reasons (the raised conditions that
    call for the Q boost), boost_follows_evidence (full boost only
    while a condition is raised, relaxing during the SUSPECT tail).
    """

    nis_window: Positive = 5.0
    nis_probability: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.999
    nis_scale: Annotated[float, Field(ge=1.0)] = 2.0
    min_nis_samples: Annotated[int, Field(ge=1)] = 10
    max_relative_range_std: Positive = 1.0
    max_range_std: Positive | None = 2.0
    min_range: NonNegative | None = None
    max_range: Positive = 2000.0
    slow_speed: NonNegative = 1.0
    unobservable_time: NonNegative = 5.0
    flag_after: NonNegative = 3.0
    clear_after: NonNegative = 10.0
    act: bool = True
    process_noise_boost: Annotated[float, Field(ge=1.0)] = 30.0
    boost_relax_time: Positive = 5.0
    reinitialize_reasons: Annotated[tuple[HealthReasonName, ...], FROM_ARRAY] = ("behind_sensor", "range_implausible")
    reinitialize_interval: NonNegative = 20.0
    reinitialize_relative_std: Positive = 0.5
    excite: bool = True
    excitation_low: NonNegative = 0.25
    excitation_high: Positive = 0.5
    boost_follows_evidence: bool = True
    boost_reasons: Annotated[tuple[HealthReasonName, ...], FROM_ARRAY] = ("nis", "behind_sensor", "range_implausible")

    @model_validator(mode="after")
    def _ordered(self) -> "HealthSection":
        if self.min_range is not None and self.min_range >= self.max_range:
            raise ValueError("min_range must be below max_range")
        if self.excitation_low >= self.excitation_high:
            raise ValueError("excitation_low must be below excitation_high")
        return self


#: Hz: the slowest loop rate (one period of 100 s). Slower is a typo, and 1e-300 Hz passes the divides-the-physics-
#: rate check yet overflows the estimator's transition matrix (period**2) with an OverflowError at take-off.
MIN_LOOP_RATE_HZ = 0.01


def _check_rates(physics_rate_hz: float, **rates_hz: float) -> None:
    """Every loop rate (Hz, by section) must be at least MIN_LOOP_RATE_HZ and divide the physics rate into whole
    steps; ValueError naming the key."""
    for section, rate in rates_hz.items():
        key = f"{section}.{'tick_rate_hz' if section == 'sitl' else 'rate_hz'}"
        if rate < MIN_LOOP_RATE_HZ:
            raise ValueError(f"{key} = {rate:g} must be at least {MIN_LOOP_RATE_HZ:g} Hz (one step per 100 s)")
        ratio = physics_rate_hz / rate
        if rate > physics_rate_hz or abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"{key} = {rate} must divide simulation.physics_rate_hz = {physics_rate_hz} into whole steps")

# --- several pursuers (issue 15) ----------------------------------------------------

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

    initial_position: Vector3 | None = None
    initial_velocity: Vector3 | None = None
    estimator_initial_position: Vector3 | None = None


class SwarmBlackout(_Strict):
    """A window [start, end) (s, scenario time) during which `pursuer` neither sends nor receives shares."""

    pursuer: PursuerIdent
    start: NonNegative
    end: Positive

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
    latency_s: NonNegative = 0.0
    jitter_s: NonNegative = 0.0
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

    g1: Positive = 1.2
    g2: Positive = 1.0
    g3: Positive = 0.4
    alpha: Positive = 1.0
    velocity_gain: Positive = 2.0
    max_acceleration: Positive = 4.0
    altitude_offset: float = 0.0


class StandoffConfig(_Strict):
    """[swarm.standoff]: seed 004's TOGVF (eq. (26)-(29), inner circle when inside) with its vertical
    profile (eq. (30)-(31)), moving-target scaling (eq. (32)-(34)) and phase coordination (eq. (36)-(40)).

    radius: R, m, horizontal standoff distance. inner_radius: r_min, m, the inner tangential circle (the
    vehicle's smallest turning radius), below radius. height: H, m, above the target. speed: v0, m/s,
    horizontal speed of each pursuer (above the target's); the phase coordination changes it within
    [min_speed, max_speed] with gain phase_gain (k2 = k3 of eq. (38)-(40), m/s per rad of phase-gap
    error). max_vertical_speed (m/s) and max_vertical_acceleration (m/s^2): the vertical profile's limits.
    velocity_gain (1/s) and max_acceleration (m/s^2): how the quadrotor tracks the field's velocity."""

    radius: Positive = 20.0
    inner_radius: Positive = 5.0
    height: float = 10.0
    speed: Positive = 8.0
    min_speed: NonNegative = 2.0
    max_speed: Positive = 15.0
    phase_gain: Positive = 1.0
    max_vertical_speed: Positive = 3.0
    max_vertical_acceleration: Positive = 1.0
    velocity_gain: Positive = 2.0
    max_acceleration: Positive = 4.0

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

    k1: Positive = 4.0
    k2: Positive = 0.12
    switch_time: NonNegative = 25.0
    process_noise: Positive = 0.2
    measurement_noise: Positive = 1.0
    initial_std: Positive = 1.0


class FusionConfig(_Strict):
    """[swarm.fusion]: estimator = 'fusion': each pursuer's own u-PLKF estimate fused with its neighbours'
    shared ones. method 'covariance_intersection' (consistent whatever the unknown cross-covariance) or
    'seed004' (seed 004 eq. (24)-(25): the information sum, cross-covariance ignored)."""

    method: Literal["covariance_intersection", "seed004"] = "covariance_intersection"


_SWARM_SUBTABLES = {"circumnavigation": ("guidance", "circumnavigation"), "standoff": ("guidance", "standoff"),
                    "triangulation": ("estimator", "triangulation_kf"), "fusion": ("estimator", "fusion")}


class SwarmConfig(_Strict):
    """[swarm]: several pursuers around one target (issue 15; README "Several pursuers: configuration").
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
    min_separation: Positive = 2.0
    share_rate_hz: Positive | None = None
    weave_min_angle_deg: Annotated[float, Field(gt=0.0, le=90.0)] = 15.0
    neighbour_timeout_s: Positive = 1.0
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



#: Longest scenario name: it becomes part of run-folder names (e.g. sitl-<name>-seed<k>-<time>/), within 255 bytes.
MAX_NAME_LENGTH = 100
_NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def _run_folder_name(value: str) -> str:
    """A scenario name usable as one path component: letters, digits, '_', '-', '.'; not starting with '.'
    (hidden, '..') or '-' (read as an option); 1..MAX_NAME_LENGTH characters. No '/', NUL or absolute path."""
    if not (len(value) <= MAX_NAME_LENGTH and _NAME_PATTERN.fullmatch(value)):
        shown = repr(value) if len(value) <= 40 else f"{value[:40]!r}... ({len(value)} characters)"
        raise ValueError(f"must be 1-{MAX_NAME_LENGTH} letters, digits, '_', '-' or '.', starting with a letter, digit "
                         f"or '_' (it names run folders), got {shown}")
    return value


ScenarioName = Annotated[str, AfterValidator(_run_folder_name)]

def _check_ranges(scenario: "Scenario") -> None:
    """The companion's health monitor needs min_range < max_range and its dropout policy min_range < safe_range,
    with the defaults derived from guidance.desired_range: refused here, naming the keys, not at take-off."""
    desired = scenario.guidance.desired_range
    health = scenario.health
    if health.min_range is None and health_min_range(desired) >= health.max_range:
        raise ValueError(f"health.max_range ({health.max_range:g} m) must exceed health.min_range, whose default is "
                         f"guidance.desired_range / 4 = {health_min_range(desired):g} m: raise max_range or "
                         "set health.min_range")
    dropout = scenario.dropout
    safe = dropout.safe_range if dropout.safe_range is not None else dropout_safe_range(desired)
    low = dropout.min_range if dropout.min_range is not None else dropout_min_range(desired)
    if low >= safe:
        def said(key: str, value: float, factor: float) -> str:
            given = getattr(dropout, key) is not None
            return f"dropout.{key} ({value:g} m{'' if given else f', default {factor:g} x guidance.desired_range'})"
        raise ValueError(f"{said('min_range', low, DROPOUT_MIN_RANGE_FACTOR)} must be below "
                         f"{said('safe_range', safe, DROPOUT_SAFE_RANGE_FACTOR)}")


class Scenario(_Strict):
    name: ScenarioName
    description: str = ""
    vehicle: str = "../vehicles/paper_table1.toml"
    pursuer: PursuerConfig = PursuerConfig()
    target: TargetConfig
    sensor: SensorConfig = SensorConfig()
    estimator: EstimatorConfig
    guidance: GuidanceConfig = GuidanceConfig()
    simulation: SimulationConfig = SimulationConfig()
    sitl: SitlConfig = SitlConfig()
    link: LinkConfig = LinkConfig()
    companion: CompanionConfig = CompanionConfig()
    faults: FaultsConfig = FaultsConfig()
    dropout: DropoutConfig = DropoutConfig()
    safety: SafetyConfig = SafetyConfig()
    health: HealthSection = HealthSection()
    swarm: SwarmConfig | None = None

    @property
    def pursuer_count(self) -> int:
        """N: 1 without [swarm]."""
        return 1 if self.swarm is None else self.swarm.count

    @model_validator(mode="after")
    def _rates_fit_physics(self) -> "Scenario":
        _check_rates(self.simulation.physics_rate_hz, estimator=self.estimator.rate_hz, guidance=self.guidance.rate_hz,
                     sensor=self.sensor.rate_hz, sitl=self.sitl.tick_rate_hz)
        if self.simulation.summary_window > self.simulation.duration:
            raise ValueError("simulation.summary_window must not exceed simulation.duration")
        if self.estimator.kind == "ekf_rae" and self.sensor.range_noise_std is None:
            raise ValueError("estimator.kind = 'ekf_rae' measures range: set sensor.range_noise_std")
        if self.estimator.kind not in ("uplkf", "imm") and self.estimator.gain_projection != "predicted":
            raise ValueError(f"estimator.gain_projection applies to the u-PLKF only, not to kind = {self.estimator.kind!r}")
        _check_swarm(self)
        _check_swarm_geometry(self)
        _check_ranges(self)
        return self




#: The companion's own sections: the plant and the target simulator never read them, so a
#: scenario whose [estimator] or [guidance] is broken or missing still flies the plant.
COMPANION_SECTIONS = ("estimator", "guidance", "companion", "dropout", "health")


class PlantSensorConfig(_Strict):
    """The one key of [sensor] the plant's side reads: the target publishes a fix per bearing."""

    rate_hz: Positive = SensorConfig.model_fields["rate_hz"].default


class PlantScenario(_Strict):
    """What sitl-plant and sitl-target read of a scenario, validated as strictly as Scenario
    (same section models); COMPANION_SECTIONS and the rest of [sensor] are not looked at."""

    name: ScenarioName
    description: str = ""
    vehicle: str = Scenario.model_fields["vehicle"].default
    pursuer: PursuerConfig = PursuerConfig()
    target: TargetConfig
    sensor: PlantSensorConfig = PlantSensorConfig()
    simulation: SimulationConfig = SimulationConfig()
    sitl: SitlConfig = SitlConfig()
    link: LinkConfig = LinkConfig()
    faults: FaultsConfig = FaultsConfig()
    swarm: SwarmConfig | None = None

    @property
    def pursuer_count(self) -> int:
        """N: 1 without [swarm]."""
        return 1 if self.swarm is None else self.swarm.count

    @model_validator(mode="after")
    def _rates_fit_physics(self) -> "PlantScenario":
        _check_rates(self.simulation.physics_rate_hz, sensor=self.sensor.rate_hz, sitl=self.sitl.tick_rate_hz)
        _check_swarm(self)
        return self


def describe_errors(error: ValidationError, root: str = "") -> list[str]:
    """One "section.key: message" per problem pydantic found (unknown keys said plainly); root: a
    section name put in front of every key (e.g. "faults" when validating that section alone)."""
    problems = []
    for item in error.errors():
        key = ".".join(str(part) for part in (root, *item["loc"]) if str(part)) or "(top level)"
        message = "unknown key (check the spelling)" if item["type"] == "extra_forbidden" else item["msg"]
        problems.append(f"{key}: {message}")
    return problems


ScenarioT = TypeVar("ScenarioT", Scenario, PlantScenario)


def _format(path: Path, error: ValidationError) -> str:
    return "\n".join([f"{path}: invalid configuration", *(f"  {problem}" for problem in describe_errors(error))])


def _scenario_vehicle(scenario_path: Path, vehicle: str) -> VehicleConfig:
    """The vehicle file a scenario names (relative to the scenario's folder), read and validated; a ConfigError names
    the scenario file and its `vehicle` key besides the vehicle file's own message."""
    try:
        resolved = (scenario_path.parent / vehicle).resolve()
    except (OSError, ValueError, RuntimeError) as error:  # a NUL byte, a symlink loop
        raise ConfigError(f"{scenario_path}: vehicle: {vehicle!r} is not a usable path ({error})") from None
    try:
        return load_vehicle(resolved)
    except ConfigError as error:
        raise ConfigError(f"{scenario_path}: vehicle = {vehicle!r}: {error}") from None


def _scenario_trajectory(scenario_path: Path, scenario: ScenarioT) -> ScenarioT:
    """The scenario with its [target.trajectory] file made absolute (relative paths are relative to the
    scenario's folder, as `vehicle` is), after reading and checking the track; unchanged without one. The
    absolute path lets both harnesses, and a copy of the configuration written elsewhere, find the file.
    ConfigError naming the scenario file and the key besides the trajectory file's own message."""
    trajectory = scenario.target.trajectory
    if trajectory is None:
        return scenario
    key = "target.trajectory.file"
    try:
        resolved = (scenario_path.parent / trajectory.file).resolve()
    except (OSError, ValueError, RuntimeError) as error:  # a NUL byte, a symlink loop
        raise ConfigError(f"{scenario_path}: {key}: {trajectory.file!r} is not a usable path ({error})") from None
    # Imported here: interfaces.trajectory builds on this module (ConfigError, read_regular_file).
    from interfaces.trajectory import read_trajectory

    try:
        times, _ = read_trajectory(resolved, trajectory.file_format)
    except ConfigError as error:
        raise ConfigError(f"{scenario_path}: {key} = {trajectory.file!r}: {error}") from None
    length = float(times[-1] - times[0])
    if trajectory.skip >= length:
        raise ConfigError(f"{scenario_path}: target.trajectory.skip: {trajectory.skip:g} s leaves nothing of the "
                          f"{length:g} s track in {resolved}")
    placed = trajectory.model_copy(update={"file": str(resolved)})
    return scenario.model_copy(update={"target": scenario.target.model_copy(update={"trajectory": placed})})


def load_vehicle(path: str | Path) -> VehicleConfig:
    """Read and validate a vehicle TOML file."""
    path = Path(path)
    try:
        return VehicleConfig.model_validate(_read_toml(path))
    except ValidationError as error:
        raise ConfigError(_format(path, error)) from None


def table1_vehicle() -> VehicleConfig:
    """The paper's Table I airframe, read and validated from PAPER_TABLE1."""
    return load_vehicle(PAPER_TABLE1)


def load_plant_scenario(path: str | Path) -> tuple[PlantScenario, VehicleConfig]:
    """Read and validate what the plant's side needs of a scenario file (PlantScenario) and the
    vehicle file it names; the companion's sections may be broken or absent."""
    path = Path(path)
    document = {key: value for key, value in _read_toml(path).items() if key not in COMPANION_SECTIONS}
    sensor = document.get("sensor")
    if isinstance(sensor, dict):
        document["sensor"] = {key: value for key, value in sensor.items() if key in PlantSensorConfig.model_fields}
    try:
        scenario = PlantScenario.model_validate(document)
    except ValidationError as error:
        raise ConfigError(_format(path, error)) from None
    return _scenario_trajectory(path, scenario), _scenario_vehicle(path, scenario.vehicle)


def load_scenario(path: str | Path) -> tuple[Scenario, VehicleConfig]:
    """Read and validate a scenario file and the vehicle file it names."""
    path = Path(path)
    try:
        scenario = Scenario.model_validate(_read_toml(path))
    except ValidationError as error:
        raise ConfigError(_format(path, error)) from None
    return _scenario_trajectory(path, scenario), _scenario_vehicle(path, scenario.vehicle)
