"""The Zenoh link shared by every process: key expressions and the declared JSON payloads.

The plant (simulated time), the target simulator and the companion, plus any ground-station subscriber, meet on
one loopback Zenoh network. The keys, the payloads (strict pydantic models: no coercion, no NaN or infinity,
unknown fields refused; every one carries the envelope schema, sender, seq and stamp, the stamp in simulated
seconds), their versions and the refusal reasons are described for users in docs/reference/zenoh.md; a
change of fields is a new schema version, and a change here is a change there.

Decoding bytes never raises anything but `PayloadError`, whose ``reason`` is one of `REASONS` (the first problem
found wins: size, UTF-8, JSON, object, schema, unknown then missing fields, then field by field). The
``encode_*`` functions check their input with the same models, so nothing a decoder would refuse is ever sent.
Geodesy lives in `interfaces.geodesy`, the Zenoh session (topology, loopback-only configuration) in
`interfaces.zenoh_transport`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Protocol, Union, get_args

import numpy as np
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Strict, Tag, TypeAdapter,
                      ValidationError, ValidationInfo, field_validator)
from pydantic_core import PydanticCustomError

from interfaces.geodesy import geodetic_to_ned

# --- key expressions ---------------------------------------------------------------

CLOCK_KEY = "bof/sim/clock"
#: Every target's fixes (subscribe with this to hear all targets).
TARGET_FIX_ALL = "bof/target/*/fix"

_NAME = re.compile(r"[A-Za-z0-9_.\-]{1,64}")


def _segment(name: str, what: str) -> str:
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(f"{what} {name!r}: use 1-64 characters from A-Z a-z 0-9 _ . - (it is a Zenoh key segment)")
    return name


def target_fix_key(sender: str) -> str:
    """``bof/target/<sender>/fix``: where target `sender` publishes its position fixes."""
    return f"bof/target/{_segment(sender, 'target sender')}/fix"


def companion_state_key(companion_id: str) -> str:
    """``bof/companion/<id>/state``: the companion's state (phase, estimate, ...)."""
    return f"bof/companion/{_segment(companion_id, 'companion id')}/state"


def companion_command_key(companion_id: str) -> str:
    """``bof/companion/<id>/command``: commands (abort) to that companion."""
    return f"bof/companion/{_segment(companion_id, 'companion id')}/command"


def target_command_key(sender: str) -> str:
    """``bof/target/<sender>/command``: the action command to the target (the paper's network A, Fig. 16)."""
    return f"bof/target/{_segment(sender, 'target sender')}/command"


#: Every pursuer's shares (subscribe with this to hear all neighbours; drop your own id on receipt).
PURSUER_SHARE_ALL = "bof/swarm/*/share"
#: The largest pursuer id (ids are 1..N; MAVLink system ids stop at 255).
MAX_PURSUER_ID = 255


def pursuer_share_key(pursuer: int) -> str:
    """``bof/swarm/<pursuer>/share``: where pursuer `pursuer` (id 1..MAX_PURSUER_ID) publishes its `PursuerShare`."""
    if isinstance(pursuer, bool) or not isinstance(pursuer, (int, np.integer)) or not 1 <= pursuer <= MAX_PURSUER_ID:
        raise ValueError(f"pursuer id {pursuer!r}: use an integer 1..{MAX_PURSUER_ID} (it is a Zenoh key segment)")
    return f"bof/swarm/{int(pursuer)}/share"


# --- constants and public value types ----------------------------------------------

TARGET_FIX_SCHEMA = "bof.target_fix/2"
TARGET_FIX_SCHEMA_V1 = "bof.target_fix/1"
CLOCK_SCHEMA = "bof.clock/1"
COMMAND_SCHEMA = "bof.command/2"
COMMAND_SCHEMA_V1 = "bof.command/1"
COMPANION_STATE_SCHEMA = "bof.companion_state/1"
PURSUER_SHARE_SCHEMA = "bof.pursuer_share/1"

Frame = Literal["geodetic", "ned"]
FRAMES = get_args(Frame)
#: Commands a companion accepts; extend here (a new command an older companion does not
#: know is rejected with "unknown_command", never silently ignored).
CommandName = Literal["abort", "resume", "start"]
COMMANDS = get_args(CommandName)
#: The filter-health monitor's reasons (companion.core.health.REASONS; interfaces imports no companion code).
HealthReason = Literal["nis", "range_uncertain", "behind_sensor", "range_implausible", "range_unobservable",
                       "link_contested", "speed_change"]
HEALTH_REASONS = get_args(HealthReason)
REASONS = frozenset({"too_large", "not_utf8", "not_json", "not_object", "missing_field", "wrong_schema",
                     "unknown_field", "wrong_type", "not_finite", "bad_sender", "bad_frame", "unknown_command",
                     "out_of_range", "bad_covariance"})

MAX_PAYLOAD_BYTES = 65536
MAX_SEQ = 2**63 - 1
MAX_EPOCH = 2**63 - 1
MAX_STAMP = 1e9  # s; 31 years of simulated time
MAX_NED = 1e6  # m
ALTITUDE_RANGE = (-1e3, 1e5)  # m above mean sea level
MAX_SPEED_COMPONENT = 1e3  # m/s
MAX_DETAIL = 200  # characters
MAX_COVARIANCE = 1e12  # |entry| of a shared covariance (m^2, m^2/s, (m/s)^2)
#: Bounds on the norm of a shared bearing direction (a noisy bearing is not unit; a zero one means nothing).
MIN_BEARING_NORM = 1e-2
MAX_BEARING_NORM = 1e2
#: Relative tolerances of the covariance checks: |P - P^T| <= tol max(1, max|P|); eigenvalues >= -tol max(1, max|P|).
COVARIANCE_SYMMETRY_TOLERANCE = 1e-9
COVARIANCE_PSD_TOLERANCE = 1e-9


def new_epoch() -> int:
    """A fresh publisher epoch (boot id): uniform in [0, 2**63), from the operating system's random source."""
    return secrets.randbelow(MAX_EPOCH + 1)


class PayloadError(ValueError):
    """A payload was refused; ``reason`` is one of REASONS, the message says which field and why."""

    def __init__(self, reason: str, detail: str) -> None:
        assert reason in REASONS, reason
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class TargetFix:
    """A target position fix (not checked until encoded; decoded ones passed `TargetFixPayload`).

    sender: target name. seq: message counter. stamp: simulated time of the fix, s.
    frame: "geodetic" (position = latitude deg, longitude deg, altitude m AMSL) or
    "ned" (position = north, east, down m about home). velocity: NED m/s or None.
    epoch: the publisher's boot id (None: a v1 fix, which has none).
    Sequences (numpy arrays too) are stored as tuples of floats.
    """

    sender: str
    seq: int
    stamp: float
    frame: Frame
    position: Vector3
    velocity: Vector3 | None = None
    epoch: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _floats(self.position))
        if self.velocity is not None:
            object.__setattr__(self, "velocity", _floats(self.velocity))


def _floats(values: Any) -> tuple[float, ...]:
    """tuple(float(v) for v in values); a 1-D float numpy array through tolist() (its elements as Python floats of
    the same values, without a numpy scalar each)."""
    if type(values) is np.ndarray and values.ndim == 1 and values.dtype.kind == "f":
        values = values.tolist()
    return tuple(map(float, values))


@dataclass(frozen=True)
class ClockTick:
    """The plant's simulated time: stamp, s since the plant started."""

    sender: str
    seq: int
    stamp: float


@dataclass(frozen=True)
class Command:
    """A command to a companion: one of COMMANDS, with an optional human-readable detail; epoch: the
    sender's boot id (None: a v1 command)."""

    sender: str
    seq: int
    stamp: float
    command: str
    detail: str = ""
    epoch: int | None = None


@dataclass(frozen=True)
class SharedBearing:
    """A pursuer's latest bearing as it shares it: stamp, s (its vehicle clock, when the bearing was taken);
    direction, NED, the measured line of sight as the sensor gave it (not necessarily unit); position, m,
    NED, the sender's own position at `stamp` (the bearing's projection centre)."""

    stamp: float
    direction: Vector3
    position: Vector3

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", tuple(float(v) for v in self.direction))
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))


@dataclass(frozen=True)
class SharedEstimate:
    """A pursuer's target estimate as it shares it: stamp, s; position m and velocity m/s, NED, shape (3,);
    covariance over [position, velocity], 6 x 6 (stored as a tuple of 6 rows; a flat 36-sequence or a
    (6, 6) array is accepted; ValueError if it has another size)."""

    stamp: float
    position: Vector3
    velocity: Vector3
    covariance: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        object.__setattr__(self, "velocity", tuple(float(v) for v in self.velocity))
        covariance = self.covariance
        if type(covariance) is tuple and len(covariance) == 36 and all(type(v) is float for v in covariance):
            # flat floats (what a checked payload holds): the rows as they are, the values the general path gives
            object.__setattr__(self, "covariance", tuple(covariance[i:i + 6] for i in range(0, 36, 6)))
            return
        matrix = np.reshape(np.asarray(covariance, dtype=float), (6, 6))
        object.__setattr__(self, "covariance", tuple(tuple(float(v) for v in row) for row in matrix))

    @property
    def covariance_matrix(self) -> np.ndarray:
        """The covariance as an array, shape (6, 6)."""
        return np.array(self.covariance, dtype=float)


@dataclass(frozen=True)
class PursuerShare:
    """``bof.pursuer_share/1``: what pursuer `sender` (id >= 1) tells its neighbours (module docstring).

    seq: per (sender, epoch), from 0. stamp: s, the sender's vehicle clock. epoch: the sender's boot id.
    position m, velocity m/s: the sender's own state at `stamp`, NED. bearing: its latest bearing or
    None (none yet). estimate: its target estimate or None. Sequences are stored as tuples of floats.
    """

    sender: int
    seq: int
    stamp: float
    epoch: int
    position: Vector3
    velocity: Vector3
    bearing: SharedBearing | None = None
    estimate: SharedEstimate | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        object.__setattr__(self, "velocity", tuple(float(v) for v in self.velocity))


# --- payload models ----------------------------------------------------------------

class _Declared(BaseModel):
    # strict: booleans are not numbers, "1.0" is not a number, nothing is converted.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


Number = Annotated[float, Strict()]
Sender = Annotated[str, Field(pattern=f"^{_NAME.pattern}$")]
Seq = Annotated[int, Field(ge=0, le=MAX_SEQ)]
Epoch = Annotated[int, Field(ge=0, le=MAX_EPOCH)]
Stamp = Annotated[float, Field(ge=0.0, le=MAX_STAMP)]
Latitude = Annotated[Number, Field(ge=-90.0, le=90.0)]  # deg
Longitude = Annotated[Number, Field(ge=-180.0, le=180.0)]  # deg
Altitude = Annotated[Number, Field(ge=ALTITUDE_RANGE[0], le=ALTITUDE_RANGE[1])]  # m AMSL
NedCoordinate = Annotated[Number, Field(ge=-MAX_NED, le=MAX_NED)]  # m
SpeedComponent = Annotated[Number, Field(ge=-MAX_SPEED_COMPONENT, le=MAX_SPEED_COMPONENT)]  # m/s
# JSON has arrays, not tuples: these containers take a list (Strict(False)); their items stay strict.
GeodeticPosition = Annotated[tuple[Latitude, Longitude, Altitude], Strict(False)]
NedPosition = Annotated[tuple[NedCoordinate, NedCoordinate, NedCoordinate], Strict(False)]
NedVelocity = Annotated[tuple[SpeedComponent, SpeedComponent, SpeedComponent], Strict(False)]


class Envelope(_Declared):
    """What every payload starts with: schema name/version, sender, seq, stamp (s of simulated time)."""

    schema_: str = Field(alias="schema")
    sender: Sender
    seq: Seq
    stamp: Stamp


class ClockPayload(Envelope):
    """``bof.clock/1``: the plant's simulated time (stamp, s)."""

    schema_: Literal[CLOCK_SCHEMA] = Field(alias="schema")


class CommandPayload(Envelope):
    """``bof.command/1``: a command (`COMMANDS`) and optional free text for the logs."""

    schema_: Literal[COMMAND_SCHEMA_V1] = Field(alias="schema")
    command: CommandName
    detail: Annotated[str, Field(max_length=MAX_DETAIL)] = ""


class CommandPayloadV2(CommandPayload):
    """``bof.command/2``: v1 plus the sender's ``epoch`` (boot id), between the envelope and the command."""

    schema_: Literal[COMMAND_SCHEMA] = Field(alias="schema")
    epoch: Epoch
    command: CommandName
    detail: Annotated[str, Field(max_length=MAX_DETAIL)] = ""


class TargetFixPayload(Envelope):
    """``bof.target_fix/1`` whatever its frame; decoded as `GeodeticFixPayload` or `NedFixPayload`.

    A fix whose frame is neither is checked against this model, which refuses the frame
    after the fields before it (and unknown/missing fields) have been checked.
    """

    schema_: Literal[TARGET_FIX_SCHEMA_V1] = Field(alias="schema")
    frame: Frame
    position: Annotated[tuple[Number, Number, Number], Strict(False)]
    velocity: NedVelocity | None = None


class GeodeticFixPayload(TargetFixPayload):
    """A fix in WGS-84: position = (latitude deg, longitude deg, altitude m AMSL)."""

    frame: Literal["geodetic"]
    position: GeodeticPosition


class NedFixPayload(TargetFixPayload):
    """A fix in the shared local NED frame: position = (north, east, down) m about home."""

    frame: Literal["ned"]
    position: NedPosition


class TargetFixPayloadV2(Envelope):
    """``bof.target_fix/2``: v1 plus the publisher's ``epoch`` (boot id), checked after the envelope."""

    schema_: Literal[TARGET_FIX_SCHEMA] = Field(alias="schema")
    epoch: Epoch
    frame: Frame
    position: Annotated[tuple[Number, Number, Number], Strict(False)]
    velocity: NedVelocity | None = None


class GeodeticFixPayloadV2(TargetFixPayloadV2):
    """A v2 fix in WGS-84 (see GeodeticFixPayload)."""

    frame: Literal["geodetic"]
    position: GeodeticPosition


class NedFixPayloadV2(TargetFixPayloadV2):
    """A v2 fix in the local NED frame (see NedFixPayload)."""

    frame: Literal["ned"]
    position: NedPosition


def _schema_of(document: Any) -> Any:
    return document.get("schema") if isinstance(document, dict) else getattr(document, "schema_", None)


def _frame_tag(document: Any) -> str:
    """Which fix model checks `document`: its version's and frame's, or TargetFixPayload[V2] (which refuses the
    frame). Any schema but v2 goes to the v1 models (which refuse a wrong schema)."""
    frame = document.get("frame") if isinstance(document, dict) else getattr(document, "frame", None)
    tag = frame if isinstance(frame, str) and frame in FRAMES else "other"
    return tag + "/2" if _schema_of(document) == TARGET_FIX_SCHEMA else tag


def _command_tag(document: Any) -> str:
    return "2" if _schema_of(document) == COMMAND_SCHEMA else "1"


# --- the companion state -----------------------------------------------------------

_OUTGOING = {"outgoing": True}


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as Python numbers and lists (the companion hands its numpy state over)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def _no_value(value: Any, info: ValidationInfo) -> Any:
    """Outgoing, a NaN/inf float means "no value" and is sent as null; incoming, it is refused."""
    value = _plain(value)
    if info.context == _OUTGOING and isinstance(value, float) and not math.isfinite(value):
        return None
    return value


Value = Annotated[Number | None, BeforeValidator(_no_value)]
StateVector = Annotated[tuple[Value, Value, Value], Strict(False), BeforeValidator(_plain)]
Count = Annotated[int, Strict(), Field(ge=0), BeforeValidator(_plain)]


class PursuerState(_Declared):
    """The vehicle's state as the companion last heard it: position m, velocity m/s, NED."""

    position: StateVector
    velocity: StateVector


class LinkState(_Declared):
    """The target link so far: fixes received/accepted, rejections and dropped bearings by reason."""

    received: Count
    accepted: Count
    rejected: dict[str, Count]
    bearings_used: Count
    bearings_dropped: dict[str, Count]
    last_seq: Annotated[Seq | None, BeforeValidator(_plain)]
    last_stamp: Value  # s, simulated
    last_fix_age_wall: Value  # s, wall clock
    contested: bool = False  # the validator holds the track: two sources in the target's epoch
    contests: Count = 0  # holds so far


class TrackState(_Declared):
    """The dropout handling: mode (tracking, coasting, degraded, reacquiring), bearing_age s."""

    mode: str
    bearing_age: Value


class ObservabilityState(_Declared):
    """The windowed FIM measure (companion.core.observability): log10 det, min eigenvalue, spread, count."""

    log_det: Value
    min_eigenvalue: Value
    spread: Value
    count: Count


class HealthStateSection(_Declared):
    """The filter-health monitor's verdict: state ("ok"/"suspect"), reasons, nis_ratio, relative_range_std;
    and what the companion does about it (companion.core.health.HealthAction): action, process_noise_boost
    (absent from senders that only report)."""

    state: Literal["ok", "suspect"]
    reasons: Annotated[list[HealthReason], Strict(False)]
    nis_ratio: Value
    relative_range_std: Value
    action: Literal["off", "nominal", "recovering"] | None = None
    process_noise_boost: Value = None


class EstimateState(_Declared):
    """The estimator's target state at `time` s: NED position m, velocity m/s, their std, range m."""

    time: Value
    position: StateVector
    velocity: StateVector
    position_std: Value
    velocity_std: Value
    range: Value


ModelName = Annotated[str, Field(min_length=1, max_length=32)]
Probability = Annotated[Number, Field(ge=0.0, le=1.0), BeforeValidator(_plain)]


class CompanionState(Envelope):
    """``bof.companion_state/1``: what the companion publishes at [link] state_rate_hz (module docstring)."""

    schema_: Literal[COMPANION_STATE_SCHEMA] = Field(alias="schema")
    seq: Annotated[Seq, BeforeValidator(_plain)]
    stamp: Annotated[Stamp, BeforeValidator(_plain)]
    phase: str
    pursuer: PursuerState
    link: LinkState
    setpoints_sent: Count
    track: TrackState | None = None
    observability: ObservabilityState | None = None
    health: HealthStateSection | None = None
    estimate: EstimateState | None = None
    model_probabilities: Annotated[dict[ModelName, Probability], Field(max_length=16)] | None = None


# --- the pursuer share -------------------------------------------------------------

def _covariance_rows(value: Any) -> Any:
    """A covariance given as 6 lists of 6 (or a (6, 6) array) flattened row by row; anything else as it is."""
    value = _plain(value)
    if isinstance(value, (list, tuple)) and len(value) == 6 and all(isinstance(row, (list, tuple)) for row in value):
        if any(len(row) != 6 for row in value):
            raise PydanticCustomError("covariance_shape", "give 36 numbers or 6 lists of 6 numbers")
        return [entry for row in value for entry in row]
    return value


BearingComponent = Annotated[Number, Field(ge=-MAX_BEARING_NORM, le=MAX_BEARING_NORM)]
CovarianceEntry = Annotated[Number, Field(ge=-MAX_COVARIANCE, le=MAX_COVARIANCE)]
Covariance = Annotated[tuple[CovarianceEntry, ...], Strict(False), Field(min_length=36, max_length=36),
                       BeforeValidator(_covariance_rows)]
PursuerId = Annotated[int, Field(ge=1, le=MAX_PURSUER_ID)]


#: s: a bearing or estimate may be stamped this much after its share (clocks that count ticks and clocks that
#: count periods differ by rounding: an estimator tick start + k dt against a step k dt).
SECTION_STAMP_TOLERANCE = 1e-6


def _not_after(section_stamp: float, info: ValidationInfo, what: str) -> None:
    stamp = info.data.get("stamp")
    if stamp is not None and section_stamp > stamp + SECTION_STAMP_TOLERANCE:
        raise PydanticCustomError("after_share", f"{what} stamp {section_stamp!r} is after the share's stamp {stamp!r}")


class SharedBearingSection(_Declared):
    """A share's ``bearing``: stamp s, direction (NED, norm in [MIN_BEARING_NORM, MAX_BEARING_NORM]), position m."""

    stamp: Stamp
    direction: Annotated[tuple[BearingComponent, BearingComponent, BearingComponent], Strict(False)]
    position: NedPosition

    @field_validator("direction")
    @classmethod
    def _unit_ish(cls, direction: tuple[float, float, float]) -> tuple[float, float, float]:
        norm = math.sqrt(sum(component * component for component in direction))
        if not MIN_BEARING_NORM <= norm <= MAX_BEARING_NORM:
            raise PydanticCustomError("bearing_norm", f"norm {norm:g} outside [{MIN_BEARING_NORM:g}, "
                                      f"{MAX_BEARING_NORM:g}]: not a line of sight")
        return direction


class SharedEstimateSection(_Declared):
    """A share's ``estimate``: stamp s, position m, velocity m/s (NED), covariance (36 entries, row by row)."""

    stamp: Stamp
    position: NedPosition
    velocity: NedVelocity
    covariance: Covariance

    @field_validator("covariance")
    @classmethod
    def _symmetric_psd(cls, entries: tuple[float, ...]) -> tuple[float, ...]:
        matrix = np.array(entries, dtype=float).reshape(6, 6)
        scale = max(1.0, float(np.max(np.abs(matrix))))
        asymmetry = float(np.max(np.abs(matrix - matrix.T)))
        if asymmetry > COVARIANCE_SYMMETRY_TOLERANCE * scale:
            raise PydanticCustomError("bad_covariance", f"not symmetric (max |P - P^T| = {asymmetry:.3g})")
        smallest = float(np.linalg.eigvalsh(0.5 * (matrix + matrix.T))[0])
        if smallest < -COVARIANCE_PSD_TOLERANCE * scale:
            raise PydanticCustomError("bad_covariance", f"not positive semidefinite (smallest eigenvalue "
                                      f"{smallest:.3g})")
        return entries


class PursuerSharePayload(Envelope):
    """``bof.pursuer_share/1``: one pursuer's own state, latest bearing and optional target estimate."""

    schema_: Literal[PURSUER_SHARE_SCHEMA] = Field(alias="schema")
    sender: PursuerId
    epoch: Epoch
    position: NedPosition
    velocity: NedVelocity
    bearing: SharedBearingSection | None = None
    estimate: SharedEstimateSection | None = None

    @field_validator("bearing", "estimate")
    @classmethod
    def _not_after_share(cls, section: Any, info: ValidationInfo) -> Any:
        if section is not None:
            _not_after(section.stamp, info, info.field_name)
        return section


_TARGET_FIX = TypeAdapter(Annotated[
    Union[Annotated[GeodeticFixPayload, Tag("geodetic")], Annotated[NedFixPayload, Tag("ned")],
          Annotated[TargetFixPayload, Tag("other")], Annotated[GeodeticFixPayloadV2, Tag("geodetic/2")],
          Annotated[NedFixPayloadV2, Tag("ned/2")], Annotated[TargetFixPayloadV2, Tag("other/2")]],
    Discriminator(_frame_tag)])
_CLOCK = TypeAdapter(ClockPayload)
_COMMAND = TypeAdapter(Annotated[Union[Annotated[CommandPayload, Tag("1")], Annotated[CommandPayloadV2, Tag("2")]],
                                 Discriminator(_command_tag)])
_STATE = TypeAdapter(CompanionState)
_SHARE = TypeAdapter(PursuerSharePayload)


# --- pydantic's errors as reason codes ---------------------------------------------

_REASON_OF_ERROR = {"extra_forbidden": "unknown_field", "missing": "missing_field", "finite_number": "not_finite",
                    "string_pattern_mismatch": "bad_sender", "greater_than_equal": "out_of_range",
                    "less_than_equal": "out_of_range", "string_too_long": "out_of_range",
                    "bad_covariance": "bad_covariance", "covariance_shape": "wrong_type", "bearing_norm": "out_of_range",
                    "after_share": "out_of_range"}
_REASON_OF_LITERAL = {"schema": "wrong_schema", "frame": "bad_frame", "command": "unknown_command"}
_PRECEDENCE = {"unknown_field": 1, "missing_field": 2}  # then field by field (3), in pydantic's order
_MESSAGES = {("out_of_range", "float_type"): "too large for a float", ("wrong_type", "missing"): "too few items"}


def _reason(kind: str, loc: tuple, value: Any) -> str:
    if not loc:
        return "not_object"
    if kind == "literal_error" and (loc[-1] == "schema" or isinstance(value, str)):
        return _REASON_OF_LITERAL.get(loc[-1], "wrong_type")  # e.g. a health state/reason not in its list
    if kind == "missing" and isinstance(loc[-1], int):  # an array too short
        return "wrong_type"
    if kind == "float_type" and type(value) is int:  # an integer no float can hold
        return "out_of_range"
    if loc == ("sender",) and kind in ("greater_than_equal", "less_than_equal"):  # a pursuer id outside 1..255
        return "bad_sender"
    return _REASON_OF_ERROR.get(kind, "wrong_type")  # every *_type, too_long, ... error


def _validate(adapter: TypeAdapter, document: Any, *, tagged: bool = False, context: dict | None = None) -> Any:
    """`document` checked by `adapter`'s model; PayloadError for the first problem (module docstring)."""
    try:
        return adapter.validate_python(document, context=context)
    except ValidationError as error:
        problems = []
        for item in error.errors(include_url=False):
            loc = item["loc"][1:] if tagged else item["loc"]  # a tagged union puts the tag first
            reason = _reason(item["type"], loc, item.get("input"))
            problems.append((0 if loc == ("schema",) else _PRECEDENCE.get(reason, 3), len(problems), reason, loc, item))
        _, _, reason, loc, item = min(problems)
        path = "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in loc).lstrip(".") or "payload"
        shown = "" if item["type"] in ("missing", "extra_forbidden") else f" = {repr(item.get('input'))[:60]}"
        message = _MESSAGES.get((reason, item["type"]), item["msg"])
        raise PayloadError(reason, f"{path}{shown}: {message}") from None


# --- decoding ----------------------------------------------------------------------

class _HasBytes(Protocol):
    def to_bytes(self) -> bytes: ...


#: What the decoders take: bytes, or anything with to_bytes() such as a zenoh.ZBytes sample payload.
Payload = Union[bytes, bytearray, _HasBytes]


def _parse(payload: Any) -> dict:
    if hasattr(payload, "to_bytes"):  # zenoh.ZBytes
        payload = payload.to_bytes()
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise TypeError(f"payload must be bytes or zenoh.ZBytes, not {type(payload).__name__}")
    payload = bytes(payload)
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise PayloadError("too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as error:
        raise PayloadError("not_utf8", str(error)) from None
    try:
        document = json.loads(text)  # NaN/Infinity tokens parse, and the models refuse them (not_finite)
    except (ValueError, RecursionError) as error:  # JSONDecodeError, too many digits, too deep
        raise PayloadError("not_json", str(error)[:200]) from None
    if not isinstance(document, dict):
        raise PayloadError("not_object", f"a JSON {type(document).__name__}, expected an object")
    return document


def decode_target_fix(payload: Payload) -> TargetFix:
    """Parse and check a ``bof.target_fix/2`` (or /1: epoch None) payload; PayloadError (with .reason) if refused."""
    fix = _validate(_TARGET_FIX, _parse(payload), tagged=True)
    return TargetFix(fix.sender, fix.seq, fix.stamp, fix.frame, fix.position, fix.velocity, getattr(fix, "epoch", None))


def decode_clock(payload: Payload) -> ClockTick:
    """Parse and check a ``bof.clock/1`` payload; PayloadError (with .reason) if it is refused."""
    tick = _validate(_CLOCK, _parse(payload))
    return ClockTick(tick.sender, tick.seq, tick.stamp)


def decode_command(payload: Payload) -> Command:
    """Parse and check a ``bof.command/2`` (or /1: epoch None) payload; PayloadError (with .reason) if refused."""
    command = _validate(_COMMAND, _parse(payload), tagged=True)
    return Command(command.sender, command.seq, command.stamp, command.command, command.detail,
                   getattr(command, "epoch", None))


def decode_state(payload: Payload) -> CompanionState:
    """Parse and check a ``bof.companion_state/1`` payload; PayloadError (with .reason) if it is refused.

    Absent sections (track, observability, health, estimate) are None, as are null numbers.
    """
    return _validate(_STATE, _parse(payload))


def decode_pursuer_share(payload: Payload) -> PursuerShare:
    """Parse and check a ``bof.pursuer_share/1`` payload; PayloadError (with .reason) if it is refused."""
    return _share_of(_validate(_SHARE, _parse(payload)))


def _share_of(share: PursuerSharePayload) -> PursuerShare:
    """The `PursuerShare` a checked payload model says."""
    bearing = estimate = None
    if share.bearing is not None:
        bearing = SharedBearing(share.bearing.stamp, share.bearing.direction, share.bearing.position)
    if share.estimate is not None:
        estimate = SharedEstimate(share.estimate.stamp, share.estimate.position, share.estimate.velocity,
                                  share.estimate.covariance)
    return PursuerShare(share.sender, share.seq, share.stamp, share.epoch, share.position, share.velocity,
                        bearing, estimate)


# --- encoding ----------------------------------------------------------------------

def _dump(model: Envelope) -> bytes:
    # Optional fields at their default (no velocity, no detail, no estimate yet) are left out.
    document = model.model_dump(by_alias=True, exclude_defaults=True)
    try:
        data = json.dumps(document, allow_nan=False, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    except UnicodeEncodeError as error:  # lone surrogates in a string
        raise PayloadError("not_utf8", str(error)) from None
    if len(data) > MAX_PAYLOAD_BYTES:
        raise PayloadError("too_large", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    return data


def _versioned(envelope: Any, current: str, legacy: str) -> dict:
    """The document of a dataclass envelope: the current schema with its epoch, or the legacy one without.
    Its fields as they are (what dataclasses.asdict gives for these flat envelopes, without its deep copy:
    the validation only reads them)."""
    document = {field.name: getattr(envelope, field.name) for field in dataclasses.fields(envelope)}
    if document["epoch"] is None:
        del document["epoch"]
        return {"schema": legacy, **document}
    return {"schema": current, **document}


def encode_target_fix(fix: TargetFix) -> bytes:
    """The ``bof.target_fix/2`` payload of `fix` (``/1`` if fix.epoch is None); PayloadError if a decoder
    would refuse it."""
    return _dump(_validate(_TARGET_FIX, _versioned(fix, TARGET_FIX_SCHEMA, TARGET_FIX_SCHEMA_V1), tagged=True))


def encode_clock(tick: ClockTick) -> bytes:
    """The ``bof.clock/1`` payload of `tick`; PayloadError if a decoder would refuse it."""
    return _dump(_validate(_CLOCK, {"schema": CLOCK_SCHEMA, **dataclasses.asdict(tick)}))


def encode_command(command: Command) -> bytes:
    """The ``bof.command/2`` payload of `command` (``/1`` if command.epoch is None); PayloadError if a decoder
    would refuse it."""
    return _dump(_validate(_COMMAND, _versioned(command, COMMAND_SCHEMA, COMMAND_SCHEMA_V1), tagged=True))


def _share_document(share: PursuerShare) -> dict[str, Any]:
    """The document of `share` that the encoder checks and writes (covariance flat, row by row)."""
    document: dict[str, Any] = {"schema": PURSUER_SHARE_SCHEMA, "sender": share.sender, "seq": share.seq,
                                "stamp": share.stamp, "epoch": share.epoch, "position": share.position,
                                "velocity": share.velocity}
    if share.bearing is not None:
        bearing = share.bearing
        document["bearing"] = {"stamp": bearing.stamp, "direction": bearing.direction, "position": bearing.position}
    if share.estimate is not None:
        estimate = share.estimate
        document["estimate"] = {"stamp": estimate.stamp, "position": estimate.position, "velocity": estimate.velocity,
                                "covariance": [entry for row in estimate.covariance for entry in row]}
    return document


def encode_pursuer_share(share: PursuerShare) -> bytes:
    """The ``bof.pursuer_share/1`` payload of `share` (covariance written flat, row by row); PayloadError if a
    decoder would refuse it."""
    return _dump(_validate(_SHARE, _share_document(share)))


def checked_pursuer_share(share: PursuerShare) -> PursuerShare:
    """decode_pursuer_share(encode_pursuer_share(share)) without the bytes in between, for a harness that hands
    shares from pursuer to pursuer in one process (studies.swarm): `share` checked by the same model the encoder
    checks it with (PayloadError with the encoder's reason if it is refused), then rebuilt from the checked model
    as the decoder rebuilds what it checked. The same share, value for value and bit for bit: the JSON the encoder
    writes carries every number exactly (Python writes a float's shortest repr, which reads back to the same
    float; integers are exact), the decoder's model checks the same values the encoder's passed, and a share the
    model accepts is far below MAX_PAYLOAD_BYTES (a few hundred bytes, every field bounded); checked against the
    round trip on arbitrary shares in tests/test_swarm_schema.py. Bytes that arrive over a network are decoded and
    checked by decode_pursuer_share, as before."""
    return _share_of(_validate(_SHARE, _share_document(share)))


def encode_state(state: dict) -> bytes:
    """The ``bof.companion_state/1`` payload of `state` (a dict of `CompanionState`'s fields, schema optional).

    numpy scalars and arrays are taken as Python numbers and lists; non-finite floats
    (NaN, +-inf: "no value", e.g. no observability yet) in the state's numbers become
    null (the envelope's stamp must be finite). PayloadError if a decoder would refuse it.
    """
    if not isinstance(state, dict):
        raise PayloadError("not_object", f"state must be a dict, got {type(state).__name__}")
    return _dump(_validate(_STATE, {"schema": COMPANION_STATE_SCHEMA, **state}, context=_OUTGOING))


# --- frames ------------------------------------------------------------------------

def fix_to_ned(fix: TargetFix, home: Sequence[float]) -> np.ndarray:
    """The fix's position in the local NED frame about `home`, m, shape (3,).

    home: (latitude deg, longitude deg, altitude m AMSL) of the NED origin (the
    scenario's [sitl] home). A "ned" fix is returned as is.
    """
    if fix.frame == "ned":
        return np.array(fix.position, dtype=float)
    return geodetic_to_ned(fix.position, home)
