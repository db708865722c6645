"""The Zenoh link shared by every process: key expressions, JSON payloads, session configuration.

In the paper's flight experiment the target's position reached the pursuer over a
Zigbee radio; here it travels over Zenoh. Three processes meet on one loopback
network: the SITL plant (owns simulated time and publishes it), the target simulator
(`sitl-target`) and the companion, plus any ground-station subscriber.

Key expressions
---------------
=============================  ===================  ============================
key                            payload              published by
=============================  ===================  ============================
``bof/sim/clock``              ``bof.clock/1``      the plant, every tick
``bof/target/<sender>/fix``    ``bof.target_fix/1`` the target (``sitl-target``)
``bof/companion/<id>/state``   ``bof.companion_state/1``  the companion
``bof/companion/<id>/command`` ``bof.command/1``    a ground station (abort)
``bof/target/<sender>/command`` ``bof.command/1``   a ground station (start)
=============================  ===================  ============================

Payloads are UTF-8 JSON objects (Zenoh encoding ``application/json``). Every one
carries ``schema`` (name/version), ``sender`` (its author, 1-64 characters from
``A-Z a-z 0-9 _ . -``, also usable as a key segment), ``seq`` (int >= 0, +1 per message
of that sender and key) and ``stamp`` (float >= 0, **simulated seconds** of the
sender's clock, i.e. of the plant's ``bof/sim/clock``). Unknown fields are rejected:
any change of fields is a new schema version.

* ``bof.target_fix/1``: ``frame`` is ``"geodetic"`` (``position`` = [lat_deg, lon_deg,
  alt_m_amsl], WGS-84) or ``"ned"`` (``position`` = [n, e, d] m in the shared local
  NED frame, origin at home, z down); optional ``velocity`` = [vn, ve, vd] m/s, NED
  in both frames (as GNSS receivers report it).
* ``bof.clock/1``: the envelope only; ``stamp`` is the plant's simulated time.
* ``bof.command/1``: ``command`` (one of ``COMMANDS``: ``"abort"``, ``"resume"`` for a
  companion, ``"start"`` for a target waiting for its action command) and an
  optional ``detail`` (free text, <= 200 characters, for the logs).
* ``bof.companion_state/1``: the envelope plus any JSON-able fields (encode only,
  `encode_state`).

Decoding bytes never raises anything but `PayloadError`, whose ``reason`` is one of
`REASONS`; the first problem found wins (size, UTF-8, JSON, object, schema, unknown
then missing fields, then field by field):

==================  ==============================================================
``too_large``       more than `MAX_PAYLOAD_BYTES` bytes
``not_utf8``        not valid UTF-8
``not_json``        not JSON (or nested deeper than Python's parser allows)
``not_object``      JSON, but not an object
``missing_field``   a required field is absent (``schema`` included)
``wrong_schema``    ``schema`` is not this decoder's name/version
``unknown_field``   a field this schema version does not define
``wrong_type``      a field has the wrong JSON type or length (booleans are not numbers)
``not_finite``      NaN or +-Infinity where a number is required
``bad_sender``      ``sender`` empty, too long, or not ``[A-Za-z0-9_.-]``
``bad_frame``       ``frame`` is a string other than ``"geodetic"`` / ``"ned"``
``unknown_command`` ``command`` is a string not in `COMMANDS`
``out_of_range``    a number outside its domain: seq < 0 or >= 2**63, stamp < 0 or
                    > 1e9 s, latitude outside [-90, 90], longitude outside [-180,
                    180], altitude outside [-1e3, 1e5] m, |NED coordinate| > 1e6 m,
                    |velocity component| > 1e3 m/s, detail longer than 200 chars
==================  ==============================================================

The ``encode_*`` functions check their input with the same rules, so nothing a
decoder would refuse is ever sent (they raise `PayloadError` too).

Geodesy lives in `interfaces.geodesy`, the Zenoh session (topology, loopback-only
configuration) in `interfaces.zenoh_transport`.

Usage::

    session = open_session(zenoh_config(connect=["tcp/127.0.0.1:7447"]))
    fixes = publisher(session, target_fix_key("target-1"))
    fixes.put(encode_target_fix(TargetFix("target-1", seq, stamp, "ned", (10.0, 5.0, -20.0))))

    def on_clock(sample):                       # runs on a Zenoh thread
        try:
            tick = decode_clock(sample.payload)
        except PayloadError as error:
            rejected[error.reason] += 1
    clock = session.declare_subscriber(CLOCK_KEY, on_clock)
    ...
    session.close()
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

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


# --- payloads ----------------------------------------------------------------------

TARGET_FIX_SCHEMA = "bof.target_fix/1"
CLOCK_SCHEMA = "bof.clock/1"
COMMAND_SCHEMA = "bof.command/1"
COMPANION_STATE_SCHEMA = "bof.companion_state/1"

FRAMES = ("geodetic", "ned")
#: Commands a companion accepts; extend here (a new command an older companion does not
#: know is rejected with "unknown_command", never silently ignored).
COMMANDS = ("abort", "resume", "start")
REASONS = frozenset({"too_large", "not_utf8", "not_json", "not_object", "missing_field", "wrong_schema",
                     "unknown_field", "wrong_type", "not_finite", "bad_sender", "bad_frame", "unknown_command",
                     "out_of_range"})

MAX_PAYLOAD_BYTES = 65536
MAX_SEQ = 2**63 - 1
MAX_STAMP = 1e9  # s; 31 years of simulated time
MAX_NED = 1e6  # m
ALTITUDE_RANGE = (-1e3, 1e5)  # m above mean sea level
MAX_SPEED_COMPONENT = 1e3  # m/s
MAX_DETAIL = 200  # characters


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
    """A target position fix.

    sender: target name. seq: message counter. stamp: simulated time of the fix, s.
    frame: "geodetic" (position = latitude deg, longitude deg, altitude m AMSL) or
    "ned" (position = north, east, down m about home). velocity: NED m/s or None.
    Sequences (numpy arrays too) are stored as tuples of floats.
    """

    sender: str
    seq: int
    stamp: float
    frame: Literal["geodetic", "ned"]
    position: Vector3
    velocity: Vector3 | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        if self.velocity is not None:
            object.__setattr__(self, "velocity", tuple(float(v) for v in self.velocity))


@dataclass(frozen=True)
class ClockTick:
    """The plant's simulated time: stamp, s since the plant started."""

    sender: str
    seq: int
    stamp: float


@dataclass(frozen=True)
class Command:
    """A command to a companion: one of COMMANDS, with an optional human-readable detail."""

    sender: str
    seq: int
    stamp: float
    command: str
    detail: str = ""


# --- decoding ----------------------------------------------------------------------

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
        document = json.loads(text)
    except (ValueError, RecursionError) as error:  # JSONDecodeError, too many digits, too deep
        raise PayloadError("not_json", str(error)[:200]) from None
    if not isinstance(document, dict):
        raise PayloadError("not_object", f"a JSON {type(document).__name__}, expected an object")
    return document


def _check_fields(document: dict, schema: str, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> None:
    if "schema" not in document:
        raise PayloadError("missing_field", "schema")
    if document["schema"] != schema:
        found = document["schema"]
        found = repr(found[:60]) if isinstance(found, str) else f"a JSON {type(found).__name__}"
        raise PayloadError("wrong_schema", f"{found}, expected {schema!r}")
    unknown = sorted(set(document) - {"schema", *required, *optional})
    if unknown:
        raise PayloadError("unknown_field", f"{', '.join(repr(k)[:40] for k in unknown[:5])} not in {schema}")
    for name in required:
        if name not in document:
            raise PayloadError("missing_field", name)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(value: Any, name: str) -> float:
    if not _is_number(value):
        raise PayloadError("wrong_type", f"{name} must be a number, got {type(value).__name__}")
    try:
        number = float(value)
    except OverflowError:
        raise PayloadError("out_of_range", f"{name} is too large") from None
    if not math.isfinite(number):
        raise PayloadError("not_finite", f"{name} is {number}")
    return number


def _in_range(number: float, low: float, high: float, name: str) -> float:
    if not low <= number <= high:
        raise PayloadError("out_of_range", f"{name} = {number!r} outside [{low:g}, {high:g}]")
    return number


def _vector(value: Any, name: str) -> Vector3:
    if not isinstance(value, list) or len(value) != 3:
        raise PayloadError("wrong_type", f"{name} must be a list of 3 numbers")
    return tuple(_number(component, f"{name}[{i}]") for i, component in enumerate(value))


def _envelope(document: dict) -> tuple[str, int, float]:
    sender, seq = document["sender"], document["seq"]
    if not isinstance(sender, str):
        raise PayloadError("wrong_type", f"sender must be a string, got {type(sender).__name__}")
    if not _NAME.fullmatch(sender):
        raise PayloadError("bad_sender", f"{sender[:80]!r}: 1-64 characters from A-Z a-z 0-9 _ . -")
    if not isinstance(seq, int) or isinstance(seq, bool):
        raise PayloadError("wrong_type", f"seq must be an integer, got {type(seq).__name__}")
    if not 0 <= seq <= MAX_SEQ:
        raise PayloadError("out_of_range", "seq > 2**63 - 1" if seq > 0 else f"seq = {seq} < 0")
    stamp = _in_range(_number(document["stamp"], "stamp"), 0.0, MAX_STAMP, "stamp")
    return sender, seq, stamp


def _position(frame: str, position: Vector3) -> Vector3:
    if frame == "geodetic":
        _in_range(position[0], -90.0, 90.0, "latitude")
        _in_range(position[1], -180.0, 180.0, "longitude")
        _in_range(position[2], *ALTITUDE_RANGE, "altitude")
    else:
        for axis, value in zip("ned", position):
            _in_range(value, -MAX_NED, MAX_NED, f"position {axis}")
    return position


def _decode_target_fix(document: dict) -> TargetFix:
    _check_fields(document, TARGET_FIX_SCHEMA, ("sender", "seq", "stamp", "frame", "position"), ("velocity",))
    sender, seq, stamp = _envelope(document)
    frame = document["frame"]
    if not isinstance(frame, str):
        raise PayloadError("wrong_type", f"frame must be a string, got {type(frame).__name__}")
    if frame not in FRAMES:
        raise PayloadError("bad_frame", f"{frame[:40]!r}, expected one of {FRAMES}")
    position = _position(frame, _vector(document["position"], "position"))
    velocity = document.get("velocity")
    if velocity is not None:
        velocity = _vector(velocity, "velocity")
        for axis, value in zip(("vn", "ve", "vd"), velocity):
            _in_range(value, -MAX_SPEED_COMPONENT, MAX_SPEED_COMPONENT, f"velocity {axis}")
    return TargetFix(sender, seq, stamp, frame, position, velocity)


def _decode_clock(document: dict) -> ClockTick:
    _check_fields(document, CLOCK_SCHEMA, ("sender", "seq", "stamp"))
    return ClockTick(*_envelope(document))


def _decode_command(document: dict) -> Command:
    _check_fields(document, COMMAND_SCHEMA, ("sender", "seq", "stamp", "command"), ("detail",))
    sender, seq, stamp = _envelope(document)
    command, detail = document["command"], document.get("detail", "")
    if not isinstance(command, str):
        raise PayloadError("wrong_type", f"command must be a string, got {type(command).__name__}")
    if command not in COMMANDS:
        raise PayloadError("unknown_command", f"{command[:40]!r}, expected one of {COMMANDS}")
    if not isinstance(detail, str):
        raise PayloadError("wrong_type", f"detail must be a string, got {type(detail).__name__}")
    if len(detail) > MAX_DETAIL:
        raise PayloadError("out_of_range", f"detail has {len(detail)} characters > {MAX_DETAIL}")
    return Command(sender, seq, stamp, command, detail)


def decode_target_fix(payload: "bytes | zenoh.ZBytes") -> TargetFix:
    """Parse and check a ``bof.target_fix/1`` payload; PayloadError (with .reason) if it is refused."""
    return _decode_target_fix(_parse(payload))


def decode_clock(payload: "bytes | zenoh.ZBytes") -> ClockTick:
    """Parse and check a ``bof.clock/1`` payload; PayloadError (with .reason) if it is refused."""
    return _decode_clock(_parse(payload))


def decode_command(payload: "bytes | zenoh.ZBytes") -> Command:
    """Parse and check a ``bof.command/1`` payload; PayloadError (with .reason) if it is refused."""
    return _decode_command(_parse(payload))


# --- encoding ----------------------------------------------------------------------

def _dump(document: dict) -> bytes:
    try:
        data = json.dumps(document, allow_nan=False, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    except ValueError as error:  # a NaN/inf that slipped past a check
        raise PayloadError("not_finite", str(error)) from None
    except UnicodeEncodeError as error:  # lone surrogates in a string
        raise PayloadError("not_utf8", str(error)) from None
    if len(data) > MAX_PAYLOAD_BYTES:
        raise PayloadError("too_large", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    return data


def _envelope_dict(schema: str, sender: str, seq: int, stamp: float) -> dict:
    return {"schema": schema, "sender": sender, "seq": seq, "stamp": stamp}


def encode_target_fix(fix: TargetFix) -> bytes:
    """The ``bof.target_fix/1`` payload of `fix`; PayloadError if a decoder would refuse it."""
    document = _envelope_dict(TARGET_FIX_SCHEMA, fix.sender, fix.seq, fix.stamp)
    document.update(frame=fix.frame, position=list(fix.position))
    if fix.velocity is not None:
        document["velocity"] = list(fix.velocity)
    _decode_target_fix(document)
    return _dump(document)


def encode_clock(tick: ClockTick) -> bytes:
    """The ``bof.clock/1`` payload of `tick`; PayloadError if a decoder would refuse it."""
    document = _envelope_dict(CLOCK_SCHEMA, tick.sender, tick.seq, tick.stamp)
    _decode_clock(document)
    return _dump(document)


def encode_command(command: Command) -> bytes:
    """The ``bof.command/1`` payload of `command`; PayloadError if a decoder would refuse it."""
    document = _envelope_dict(COMMAND_SCHEMA, command.sender, command.seq, command.stamp)
    document["command"] = command.command
    if command.detail:
        document["detail"] = command.detail
    _decode_command(document)
    return _dump(document)


def _json_value(value: Any, path: str) -> Any:
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.ndarray):
        return _json_value(value.tolist(), path)
    if isinstance(value, (list, tuple)):
        return [_json_value(item, f"{path}[{i}]") for i, item in enumerate(value)]
    if isinstance(value, dict):
        converted = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise PayloadError("wrong_type", f"{path}: key {key!r} is not a string")
            converted[key] = _json_value(item, f"{path}.{key}")
        return converted
    raise PayloadError("wrong_type", f"{path}: {type(value).__name__} is not JSON-serialisable")


def encode_state(state: dict) -> bytes:
    """A ``bof.companion_state/1`` payload: `state` with the schema added.

    state must hold sender, seq and stamp (checked as in every payload) and may hold
    anything JSON-able: None, bool, int, float, str, lists/tuples, dicts with string
    keys, numpy scalars and arrays. Non-finite floats (NaN, +-inf: "no value", e.g. no
    estimate yet) become null. Anything else raises PayloadError("wrong_type").
    """
    if not isinstance(state, dict):
        raise PayloadError("not_object", f"state must be a dict, got {type(state).__name__}")
    if "schema" in state and state["schema"] != COMPANION_STATE_SCHEMA:
        raise PayloadError("wrong_schema", f"{state['schema']!r}, expected {COMPANION_STATE_SCHEMA!r}")
    for name in ("sender", "seq", "stamp"):
        if name not in state:
            raise PayloadError("missing_field", name)
    envelope = {name: state[name].item() if isinstance(state[name], np.generic) else state[name]
                for name in ("sender", "seq", "stamp")}
    sender, seq, stamp = _envelope(envelope)
    document = {"schema": COMPANION_STATE_SCHEMA, **_json_value(state, "state")}
    document.update(sender=sender, seq=seq, stamp=stamp)
    return _dump(document)


# --- frames ------------------------------------------------------------------------

def fix_to_ned(fix: TargetFix, home: Sequence[float]) -> np.ndarray:
    """The fix's position in the local NED frame about `home`, m, shape (3,).

    home: (latitude deg, longitude deg, altitude m AMSL) of the NED origin (the
    scenario's [sitl] home). A "ned" fix is returned as is.
    """
    if fix.frame == "ned":
        return np.array(fix.position, dtype=float)
    return geodetic_to_ned(fix.position, home)
