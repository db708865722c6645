"""MAVLink 2 around the autopilot: the plant speaks to a companion and a ground station like PX4 SITL.

Each link is one UDP socket, like one PX4 mavlink instance: it sends everything
(streams, heartbeats, answers) to its configured partner (14540 for the
offboard/companion link, 14550 for the ground station, both configurable) and never
re-targets to whoever sent the last datagram, so a stranger on the port can neither
steal the stream nor receive answers. Encoding, parsing and MAVLink 2 signing are
pymavlink's (common dialect); this module only decides what PX4 would answer.

Every incoming datagram is used, ignored as not ours/not needed (counted per message
in `ignored`), or rejected: `rejected` counts one per datagram, under the reason of its
first problem (a fuzzer's datagram counts once however many frames it breaks into);
`reject_events` counts every problem found. Each reject is an event for the run log.
Nothing a peer sends can raise out of `handle_datagram`.

Signing (MAV_SIGN_CFG = 1, as PX4's MavlinkSignControl): on the ground-station link
only frames with a valid signature under the key are used, except RADIO_STATUS,
ADSB_VEHICLE and COLLISION which PX4 also takes unsigned; unsigned, badly signed and
replayed frames are refused and counted by reason. Without a key that link refuses
everything but those three, as PX4 does on a non-USB link. The key comes from a file
(sitl-plant --signing-key) or a SETUP_SIGNING on the companion link; it is never a
parameter. The companion link stays unsigned both ways (on an aircraft it is a wire,
and MAVSDK cannot sign).
"""

from __future__ import annotations

import collections
import errno
import math
import os
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Callable

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

import numpy as np  # noqa: E402
import pymap3d  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from sitl_plant.vehicle.autopilot import Autopilot, OffboardAttitude, OffboardTrajectory  # noqa: E402
from sitl_plant.vehicle.parameters import SIGNING_OFF, Parameter, ParameterError  # noqa: E402
from sitl_plant.vehicle.px4_modes import (  # noqa: E402
    HOLD,
    LAND,
    OFFBOARD,
    POSITION,
    TAKEOFF,
    CommandResult,
    LandedState,
    Severity,
    mode_from_main_sub,
)

#: ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET. pymavlink's SET_ATTITUDE_TARGET has no thrust_body field
#: (checked: 2.4.37 and 2.4.50, the newest release), so a setpoint with this bit is refused rather than
#: flown on a thrust that cannot be read.
THRUST_BODY_SET = 32
#: A setpoint quaternion whose norm is further than this from 1 is rejected, not renormalised.
QUATERNION_NORM_TOLERANCE = 0.05
#: Messages PX4 accepts unsigned when signing is required (MavlinkSignControl's list).
UNSIGNED_ALLOWED = frozenset({
    mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE, mavlink.MAVLINK_MSG_ID_COLLISION,
})
#: Seconds from the Unix epoch to 2015-01-01, the origin of MAVLink signing timestamps (units of 10 us).
_SIGNING_EPOCH = 1420070400
#: A new signed stream may start at most this far (10 us units) behind our timestamp (pymavlink: one minute).
_NEW_STREAM_WINDOW = 6000 * 1000

_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_AHRS
)

CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
)
#: Reported as PX4 v1.14.0 (release), the version whose modes and parameters are modelled.
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255

# Default stream rates in Hz of simulated time, per link kind (PX4's "onboard" and "normal" profiles, simplified).
COMPANION_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: 50.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
}
GCS_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 5.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: 0.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
}
#: Messages a peer may request or re-rate (the streams above plus these one-shot ones).
STREAMABLE = frozenset(COMPANION_STREAMS) | frozenset(GCS_STREAMS) | {mavlink.MAVLINK_MSG_ID_HEARTBEAT}
ONE_SHOT = frozenset({mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION})

# Parameters (0-based) each command needs finite; others may be NaN ("unset") as MAVLink allows.
_PARAMS_USED: dict[int, tuple[int, ...]] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: (0,),
    mavlink.MAV_CMD_DO_SET_MODE: (0, 1),
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: (0, 1),
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: (0,),
    mavlink.MAV_CMD_REQUEST_MESSAGE: (0,),
}

# Known messages we receive and deliberately do nothing with (not errors).
_QUIET = frozenset({
    "HEARTBEAT", "COMMAND_ACK", "SYSTEM_TIME", "PARAM_VALUE", "TIMESYNC", "MISSION_ACK",
    "REQUEST_DATA_STREAM", "MANUAL_CONTROL", "RC_CHANNELS_OVERRIDE",
})


@dataclass(frozen=True)
class Home:
    """Geodetic position of the local NED origin (WGS-84 degrees, metres above mean sea level)."""

    latitude: float
    longitude: float
    altitude: float

    def to_geodetic(self, north: float, east: float, down: float) -> tuple[float, float, float]:
        lat, lon, alt = pymap3d.ned2geodetic(north, east, down, self.latitude, self.longitude, self.altitude)
        return float(lat), float(lon), float(alt)


@dataclass
class LinkSpec:
    """Where a link sends (its partner, always) and where it binds (loopback by default).

    signed: MAV_SIGN_CFG applies to this link (the ground-station link); signed outgoing traffic
    whenever a key is set."""

    name: str
    partner_host: str
    partner_port: int
    streams: dict[int, float]
    bind_host: str = "127.0.0.1"
    bind_port: int = 0
    signed: bool = False


class _SigningHolder:
    """Lets pymavlink's mavfile.setup_signing/disable_signing act on a bare MAVLink object."""

    def __init__(self, mav: mavlink.MAVLink) -> None:
        self.mav = mav


def signing_timestamp(unix_time: float | None = None) -> int:
    """MAVLink signing timestamp (10 us units since 2015-01-01 UTC) of a Unix time (s; default now)."""
    now = time.time() if unix_time is None else unix_time
    return int(max(now - _SIGNING_EPOCH, 0.0) * 100_000)


class Link:
    """One UDP socket speaking MAVLink 2 as system 1 / component 1 (one PX4 mavlink instance)."""

    def __init__(self, spec: LinkSpec, system_id: int, component_id: int, link_id: int = 0) -> None:
        self.spec = spec
        self.name = spec.name
        self.link_id = link_id  # MAVLink signing link id of our outgoing stream (PX4: the instance number)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.sock.bind((spec.bind_host, spec.bind_port))
        self.address: tuple[str, int] = self.sock.getsockname()
        self.partner = (spec.partner_host, spec.partner_port)
        self.mav = mavlink.MAVLink(self, srcSystem=system_id, srcComponent=component_id)  # encoder (own sequence)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True  # bad frames become BAD_DATA messages
        # Why the signature of a frame failed (frame bytes -> reason), filled while a datagram is parsed.
        self.signature_failures: dict[bytes, str] = {}
        self._install_signature_check()
        self.intervals: dict[int, float] = {mid: (1.0 / hz if hz > 0 else 0.0) for mid, hz in spec.streams.items()}
        self.defaults = dict(self.intervals)
        self.next_due: dict[int, float] = {mid: 0.0 for mid in self.intervals}
        self.sent = 0
        self.send_errors = 0
        self.datagrams = 0  # datagrams read (silenced ones excluded)
        self.from_strangers = 0  # datagrams from an address other than the partner's (used all the same)
        self.silenced = False  # fault injection: the link is down both ways
        self.dropped_silenced = 0

    def reset_parser(self) -> None:
        """Drop a half-read frame: a fresh parser that keeps the signing state (key, stream timestamps)."""
        signing = self.parser.signing
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.parser.signing = signing
        self._install_signature_check()

    def _install_signature_check(self) -> None:
        parser = self.parser
        verify = parser.check_signature  # pymavlink's HMAC-SHA-256 check, bound to this parser

        def check_signature(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
            # pymavlink stores a stream's timestamp before it checks the signature, so one forged frame
            # with a far-future timestamp would make every genuine frame of that stream look replayed.
            # Keep the state of a failed check as it was, and note why it failed.
            signing = parser.signing
            key = (msgbuf[-13], src_system, src_component)
            stamp = int.from_bytes(bytes(msgbuf[-12:-6]), "little")
            previous = signing.stream_timestamps.get(key)
            own = signing.timestamp
            if verify(msgbuf, src_system, src_component):
                return True
            if previous is None:
                signing.stream_timestamps.pop(key, None)
            else:
                signing.stream_timestamps[key] = previous
            signing.timestamp = own
            if previous is not None and stamp <= previous:
                reason = "signing_replayed"
            elif previous is None and stamp + _NEW_STREAM_WINDOW < own:
                reason = "signing_stale_timestamp"
            else:
                reason = "signing_bad_signature"
            if len(self.signature_failures) < 64:
                self.signature_failures[bytes(msgbuf)] = reason
            return False

        parser.check_signature = check_signature

    def set_signing(self, key: bytes | None, allow_unsigned, initial_timestamp: int) -> None:
        """Sign outgoing frames and check incoming ones with `key` (32 bytes), or stop signing (None).

        allow_unsigned(mav, message_id) -> bool: pymavlink's callback for unsigned or badly signed frames."""
        if key is None:
            mavutil.mavfile.disable_signing(_SigningHolder(self.mav))
            mavutil.mavfile.disable_signing(_SigningHolder(self.parser))
            self.parser.signing.stream_timestamps.clear()
            return
        mavutil.mavfile.setup_signing(_SigningHolder(self.mav), key, sign_outgoing=True,
                                      initial_timestamp=initial_timestamp, link_id=self.link_id)
        mavutil.mavfile.setup_signing(_SigningHolder(self.parser), key, sign_outgoing=False,
                                      allow_unsigned_callback=allow_unsigned, initial_timestamp=initial_timestamp,
                                      link_id=self.link_id)
        self.parser.signing.stream_timestamps.clear()

    def write(self, data: bytes) -> None:
        """pymavlink's file interface: one packet per datagram to the partner."""
        if self.silenced:
            self.dropped_silenced += 1
            return
        try:
            self.sock.sendto(data, self.partner)
            self.sent += 1
        except OSError as error:
            # Nobody listening yet (ICMP port unreachable) or a full buffer: PX4 drops too.
            if error.errno not in (errno.ECONNREFUSED, errno.EAGAIN, errno.ENOBUFS, errno.EWOULDBLOCK):
                raise
            self.send_errors += 1

    def set_interval(self, message_id: int, interval: float) -> None:
        """interval in simulated seconds; 0 turns the stream off."""
        self.intervals[message_id] = interval
        self.next_due.setdefault(message_id, 0.0)

    def close(self) -> None:
        self.sock.close()


@dataclass
class Event:
    """Something worth a line in the run log: simulated time (s), kind, human-readable detail, and the
    event's figures as structured fields (logged beside the detail, e.g. mode="Offboard", armed=True)."""

    time: float
    kind: str
    detail: str
    fields: dict = field(default_factory=dict)


@dataclass
class MavlinkStats:
    """Per-run counters: packets used per message type, ignored ones, rejected datagrams by the reason of
    their first problem (one per datagram), every reject event by reason, commands by name."""

    received: collections.Counter = field(default_factory=collections.Counter)
    ignored: collections.Counter = field(default_factory=collections.Counter)
    rejected: collections.Counter = field(default_factory=collections.Counter)
    reject_events: collections.Counter = field(default_factory=collections.Counter)
    commands: collections.Counter = field(default_factory=collections.Counter)
    #: peers' STATUSTEXTs not passed on to the other links (over STATUSTEXT_RELAY_RATE), by source link
    statustext_not_relayed: collections.Counter = field(default_factory=collections.Counter)

    def as_dict(self) -> dict:
        return {
            "received": dict(self.received),
            "ignored": dict(self.ignored),
            "rejected": dict(self.rejected),
            "reject_events": dict(self.reject_events),
            "commands": dict(self.commands),
            "statustext_not_relayed": dict(self.statustext_not_relayed),
        }


#: Peers' STATUSTEXTs passed on to the other links, per simulated second and source link (token bucket).
STATUSTEXT_RELAY_RATE = 5.0


class Rejected(Exception):
    """A message is malformed; args[0] is the counter key, args[1] the detail."""


def validate_attitude_target(msg: mavlink.MAVLink_set_attitude_target_message) -> OffboardAttitude:
    """SET_ATTITUDE_TARGET -> OffboardAttitude, honouring type_mask; Rejected if unusable.

    Attitude and thrust are what the plant flies; body rates are accepted only as
    'ignored' or all zero (this plant has no rate-setpoint mode). Thrust is
    normalised in [0, 1]. THRUST_BODY_SET is refused: pymavlink does not decode the
    thrust_body field it points to.
    """
    mask = int(msg.type_mask)
    ignore_attitude = bool(mask & mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE)
    ignore_thrust = bool(mask & mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE)
    values = [*msg.q, msg.thrust, msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate]
    if not all(math.isfinite(v) for v in values):
        raise Rejected("setpoint_not_finite", f"NaN or inf in {values}")
    rates = (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)
    asked = [rate for bit, rate in zip((1, 2, 4), rates) if not mask & bit and rate != 0.0]
    if asked:
        raise Rejected("setpoint_rates_unsupported", f"type_mask {mask:#x} asks for body rates {rates}")
    if mask & THRUST_BODY_SET and not ignore_thrust:
        raise Rejected("setpoint_thrust_body_unsupported", f"type_mask {mask:#x}: THRUST_BODY_SET (no thrust_body field)")
    if ignore_attitude and ignore_thrust:
        raise Rejected("setpoint_empty", f"type_mask {mask:#x} ignores both attitude and thrust")
    quaternion = None
    if not ignore_attitude:
        w, x, y, z = (float(c) for c in msg.q)
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if norm < 1e-6:
            raise Rejected("setpoint_quaternion_zero", f"quaternion {tuple(msg.q)} has zero norm")
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise Rejected("setpoint_quaternion_not_unit", f"quaternion norm {norm:.4f}")
        quaternion = (w / norm, x / norm, y / norm, z / norm)
    thrust = None
    if not ignore_thrust:
        thrust = float(msg.thrust)
        if not 0.0 <= thrust <= 1.0:
            raise Rejected("setpoint_thrust_out_of_range", f"thrust {thrust} outside [0, 1]")
    return OffboardAttitude(quaternion, thrust)


# SET_POSITION_TARGET_LOCAL_NED.type_mask groups (POSITION_TARGET_TYPEMASK_*).
_POSITION_BITS, _VELOCITY_BITS, _ACCELERATION_BITS = 0x7, 0x38, 0x1C0
_FORCE_SET, _YAW_IGNORE, _YAW_RATE_IGNORE = 0x200, 0x400, 0x800


def validate_position_target(msg, yaw_now: float) -> OffboardTrajectory:
    """SET_POSITION_TARGET_LOCAL_NED -> OffboardTrajectory; Rejected if unusable.

    Frames: LOCAL_NED, or BODY_NED for velocity/acceleration (rotated by the current yaw,
    as MAVSDK's velocity_body uses it). Each of position, velocity and acceleration is
    used all three axes or not at all; force setpoints and yaw rate are not supported.
    """
    mask = int(msg.type_mask)
    groups = {}
    for name, bits, values in (("position", _POSITION_BITS, (msg.x, msg.y, msg.z)),
                               ("velocity", _VELOCITY_BITS, (msg.vx, msg.vy, msg.vz)),
                               ("acceleration", _ACCELERATION_BITS, (msg.afx, msg.afy, msg.afz))):
        ignored = mask & bits
        if ignored not in (0, bits):
            raise Rejected("setpoint_type_mask_unsupported", f"type_mask {mask:#x}: {name} given on some axes only")
        if not ignored:
            if not all(math.isfinite(v) for v in values):
                raise Rejected("setpoint_not_finite", f"{name} {values}")
            groups[name] = tuple(float(v) for v in values)
    if mask & _FORCE_SET:
        raise Rejected("setpoint_type_mask_unsupported", f"type_mask {mask:#x}: force setpoints")
    if not mask & _YAW_RATE_IGNORE and msg.yaw_rate != 0.0:
        raise Rejected("setpoint_type_mask_unsupported", f"type_mask {mask:#x}: yaw rate {msg.yaw_rate}")
    yaw = None
    if not mask & _YAW_IGNORE:
        if not math.isfinite(msg.yaw):
            raise Rejected("setpoint_not_finite", f"yaw {msg.yaw}")
        yaw = float(msg.yaw)
    if not groups:
        raise Rejected("setpoint_empty", f"type_mask {mask:#x} ignores position, velocity and acceleration")
    if msg.coordinate_frame == mavlink.MAV_FRAME_BODY_NED:
        if "position" in groups:
            raise Rejected("setpoint_frame_unsupported", "position in BODY_NED")
        c, s = math.cos(yaw_now), math.sin(yaw_now)
        for name in ("velocity", "acceleration"):
            if name in groups:
                x, y, z = groups[name]
                groups[name] = (c * x - s * y, s * x + c * y, z)
        if yaw is not None:
            yaw += yaw_now
    elif msg.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
        raise Rejected("setpoint_frame_unsupported", f"coordinate frame {msg.coordinate_frame}")
    return OffboardTrajectory(groups.get("position"), groups.get("velocity"), groups.get("acceleration"), yaw)


def _param_wire_value(parameter: Parameter) -> tuple[float, int]:
    """PX4 encodes integer parameters bytewise: the int32's bytes inside the float field."""
    if parameter.kind == "int":
        return struct.unpack("<f", struct.pack("<i", int(parameter.value)))[0], mavlink.MAV_PARAM_TYPE_INT32
    return float(parameter.value), mavlink.MAV_PARAM_TYPE_REAL32


def _param_from_wire(value: float, param_type: int) -> float:
    if param_type in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT16,
                      mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT8):
        return float(struct.unpack("<i", struct.pack("<f", value))[0])
    return float(value)


class MavlinkVehicle:
    """The plant as a MAVLink vehicle: decodes, answers and streams on behalf of an Autopilot.

    autopilot: the flight stack. links: the UDP endpoints (companion, ground station...).
    home: geodetic position of the local origin. on_event: called with each Event
    (statustext, rejects, mode/arming changes) for the run log.
    unix_epoch: wall-clock time (s) that simulated time 0 corresponds to, for
    SYSTEM_TIME; every other timestamp is simulated time since boot.
    """

    def __init__(
        self,
        autopilot: Autopilot,
        links: list[LinkSpec],
        home: Home,
        system_id: int = 1,
        component_id: int = 1,
        on_event: Callable[[Event], None] | None = None,
        unix_epoch: float | None = None,
    ) -> None:
        self.autopilot = autopilot
        self.home = home
        self.system_id = system_id
        self.component_id = component_id
        self.links = [Link(spec, system_id, component_id, link_id=index) for index, spec in enumerate(links)]
        self.stats = MavlinkStats()
        self._signing_key: bytes | None = None  # never a parameter, never logged
        self.signing_key_source = "none"
        self._datagram_rejects: list[tuple[str, str]] | None = None
        self.on_event = on_event or (lambda event: None)
        self.unix_epoch = time.time() if unix_epoch is None else unix_epoch
        self._next_heartbeat = 0.0
        self._statustext_id = 0
        self._relay_tokens: dict[str, tuple[float, float]] = {}  # link name -> (tokens, simulated time s)
        self._last_mode = autopilot.mode
        self._last_armed = autopilot.armed
        self.on_odometry_sent: Callable[[int], None] | None = None
        self._builder_table = self._builders()
        #: Fault injection: (start, end) windows of simulated time when the companion link is down both ways.
        self.companion_blackouts: list[tuple[float, float]] = []

    # --------------------------------------------------------------- helpers
    @property
    def time_boot_ms(self) -> int:
        return int(self.autopilot.time * 1000.0) & 0xFFFFFFFF

    @property
    def time_usec(self) -> int:
        return int(round(self.autopilot.time * 1e6))

    def _event(self, kind: str, detail: str, **fields) -> None:
        self.on_event(Event(self.autopilot.time, kind, detail, fields))

    def _reject(self, link: Link, reason: str, detail: str) -> None:
        """One problem with incoming traffic: an event and a reject_events count; `rejected` counts the
        datagram once, under its first problem (at the end of handle_datagram)."""
        self.stats.reject_events[reason] += 1
        self._event("rejected", f"{link.name}: {reason}: {detail}", reason=reason, link=link.name)
        if self._datagram_rejects is not None:
            self._datagram_rejects.append((reason, detail))
        else:
            self.stats.rejected[reason] += 1

    # --------------------------------------------------------------- signing
    @property
    def signing_mode(self) -> int:
        """MAV_SIGN_CFG: 0 off, 1 signing required on the ground-station link."""
        return int(self.autopilot.parameters.value("MAV_SIGN_CFG"))

    @property
    def signing_key_set(self) -> bool:
        return self._signing_key is not None

    def set_signing_key(self, key: bytes | None, initial_timestamp: int = 0, source: str = "file") -> None:
        """Use `key` (32 bytes) on the signed links from now on, or none (None or all zero, as PX4).

        initial_timestamp: signing timestamp (10 us since 2015) to start from; the wall clock's
        if that is later. The key itself is never logged or served as a parameter."""
        if key is not None and len(key) != 32:
            raise ValueError(f"a MAVLink signing key is 32 bytes, got {len(key)}")
        if key is not None and not any(key) and initial_timestamp == 0:
            key = None  # PX4: an all-zero key with a zero timestamp clears signing
        self._signing_key = None if key is None else bytes(key)
        self.signing_key_source = "none" if key is None else source
        stamp = max(int(initial_timestamp), signing_timestamp())
        for link in self.links:
            if link.spec.signed:
                link.set_signing(self._signing_key, self._allow_unsigned, stamp)
        self._event("signing", f"signing key {'set' if key is not None else 'cleared'} ({source})",
                    key_set=key is not None, source=source)

    def _allow_unsigned(self, mav, message_id: int) -> bool:
        """pymavlink's allow_unsigned_callback: what a signed link takes without a valid signature."""
        return self.signing_mode == SIGNING_OFF or message_id in UNSIGNED_ALLOWED

    def signing_status(self) -> dict:
        """For stats.json: mode, whether a key is set and where from, signature counts per signed link."""
        return {"MAV_SIGN_CFG": self.signing_mode, "key_set": self.signing_key_set, "key_source": self.signing_key_source,
                "links": {link.name: {"good_signatures": link.parser.signing.goodsig_count,
                                      "bad_signatures": link.parser.signing.badsig_count,
                                      "accepted_unsigned": link.parser.signing.unsigned_count,
                                      "refused_unsigned": link.parser.signing.reject_count}
                          for link in self.links if link.spec.signed}}

    def close(self) -> None:
        for link in self.links:
            link.close()

    def fileno_map(self) -> dict[int, Link]:
        return {link.sock.fileno(): link for link in self.links}

    # --------------------------------------------------------------- receive
    def poll(self, link: Link | None = None, max_datagrams: int = 1000) -> int:
        """Read and handle every datagram waiting (on one link or all); returns how many."""
        handled = 0
        for current in [link] if link is not None else self.links:
            for _ in range(max_datagrams):
                try:
                    data, address = current.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:  # ICMP errors surface here on some kernels
                    break
                self.handle_datagram(current, data, address)
                handled += 1
        return handled

    def _update_blackouts(self) -> None:
        now = self.autopilot.time
        for link in self.links:
            if link.name != "companion":
                continue
            silenced = any(start <= now < end for start, end in self.companion_blackouts)
            if silenced != link.silenced:
                link.silenced = silenced
                self._event("fault", f"mavlink blackout {'start' if silenced else 'end'} on the {link.name} link")

    def handle_datagram(self, link: Link, data: bytes, address: tuple[str, int] | None = None) -> None:
        """Parse one datagram and act on every message in it; never raises for bad input.

        On UDP a datagram carries whole frames. Bytes left over at its end (a cut-off
        frame, or garbage with a start byte in it) are rejected as 'truncated_frame' and
        dropped with the parser state, so they can never swallow the next datagram.
        A datagram with any problem counts once in stats.rejected, under its first one.
        """
        if link.silenced:
            link.dropped_silenced += 1
            return
        link.datagrams += 1
        if address is not None and address != link.partner:
            link.from_strangers += 1
        link.signature_failures.clear()
        self._datagram_rejects = problems = []
        try:
            try:
                messages = link.parser.parse_buffer(data) or []
            except Exception as error:  # pymavlink raises for a few corrupt headers even when robust
                self._reject(link, "bad_data", f"parser error: {error}")
                link.reset_parser()
                return
            leftover = link.parser.buf_len()
            if leftover > 0:
                link.reset_parser()
            for msg in messages:
                try:
                    self.handle_message(link, msg, address)
                except Rejected as rejected:
                    self._reject(link, rejected.args[0], rejected.args[1])
                except Exception as error:  # a bug here must not take the vehicle down
                    self._reject(link, "handler_error", f"{msg.get_type()}: {error!r}")
            if leftover > 0:  # the datagram's tail, so its problem comes after those of the frames before it
                self._reject(link, "truncated_frame", f"{leftover} bytes of an incomplete frame")
        finally:
            self._datagram_rejects = None
            if problems:
                self.stats.rejected[problems[0][0]] += 1

    def handle_message(self, link: Link, msg: mavlink.MAVLink_message, address: tuple[str, int] | None) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            reason = msg.reason.lower()
            if "invalid signature" in reason:
                frame = bytes(msg.data)
                signed = len(frame) > 2 and frame[0] == mavlink.PROTOCOL_MARKER_V2 and frame[2] & mavlink.MAVLINK_IFLAG_SIGNED
                key = link.signature_failures.get(frame, "signing_bad_signature") if signed else "signing_unsigned"
                raise Rejected(key, f"{'signed' if signed else 'unsigned'} frame refused ({_frame_message_name(frame)})")
            key = "bad_crc" if "crc" in reason else ("bad_prefix" if "prefix" in reason else "bad_data")
            raise Rejected(key, msg.reason)
        if kind == "UNKNOWN" or isinstance(msg, mavlink.MAVLink_unknown):
            raise Rejected("unknown_message_id", f"message id {msg.get_msgId()}")
        if (link.spec.signed and self._signing_key is None and self.signing_mode != SIGNING_OFF
                and msg.get_msgId() not in UNSIGNED_ALLOWED):
            # PX4 with signing required and no key takes nothing on a non-USB link but the allowed few.
            raise Rejected("signing_no_key", f"{kind}: signing required and no key set")
        target = getattr(msg, "target_system", None)
        if target is not None and target not in (0, self.system_id):
            self.stats.ignored[f"{kind}:other_system"] += 1
            return
        target_component = getattr(msg, "target_component", None)
        if target_component is not None and target_component not in (0, self.component_id):
            self.stats.ignored[f"{kind}:other_component"] += 1
            return
        self.stats.received[kind] += 1
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is not None:
            handler(link, msg)
        elif kind not in _QUIET:
            self.stats.ignored[kind] += 1

    # ------------------------------------------------------------- handlers
    def _on_set_attitude_target(self, link: Link, msg) -> None:
        self.autopilot.offboard_setpoint(validate_attitude_target(msg))

    def _on_set_position_target_local_ned(self, link: Link, msg) -> None:
        _, _, yaw = _euler(self.autopilot.telemetry().quaternion)
        self.autopilot.offboard_trajectory(validate_position_target(msg, yaw))

    def _on_setup_signing(self, link: Link, msg) -> None:
        """SETUP_SIGNING sets (or, all zero, clears) the key: taken on the companion link only, which on an
        aircraft is a wire; on the ground-station link it would let anyone on the network set the key."""
        if link.spec.signed:
            raise Rejected("setup_signing_refused", "SETUP_SIGNING is taken on the companion link only")
        key = bytes(msg.secret_key)
        self.set_signing_key(key, int(msg.initial_timestamp), source=f"SETUP_SIGNING on the {link.name} link")

    def _on_command_long(self, link: Link, msg) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(link, msg, int(msg.command), params)

    def _on_command_int(self, link: Link, msg) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x * 1e-7, msg.y * 1e-7, msg.z)
        self._command(link, msg, int(msg.command), params)

    def _command(self, link: Link, msg, command: int, params: tuple[float, ...]) -> None:
        name = mavlink.enums["MAV_CMD"][command].name if command in mavlink.enums["MAV_CMD"] else str(command)
        self.stats.commands[name] += 1
        try:
            result = self._execute(link, command, params)
        except Rejected as rejected:
            self._reject(link, rejected.args[0], rejected.args[1])
            result = CommandResult.DENIED
        if result == CommandResult.UNSUPPORTED:
            self._event("command_unsupported", f"{link.name}: {name} {params}")
        self._send(link, link.mav.command_ack_encode(command, int(result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _execute(self, link: Link, command: int, p: tuple[float, ...]) -> CommandResult:
        ap = self.autopilot
        used = _PARAMS_USED.get(command, ())
        if not all(math.isfinite(p[i]) for i in used):
            raise Rejected("command_not_finite", f"command {command} params {p}")
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            force = p[1] == 21196.0
            if p[0] == 1.0:
                return ap.arm(force)
            if p[0] == 0.0:
                return ap.disarm(force)
            return CommandResult.DENIED
        if command == mavlink.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6])
        if command == mavlink.MAV_CMD_NAV_LAND:
            return ap.land()
        if command == mavlink.MAV_CMD_DO_LAND_START:
            # PX4 (navigator) starts the mission's landing sequence; with no mission landing it warns on its
            # console only and answers CANCELLED. The plant has no missions. MAV_CMD_NAV_LAND or Land mode lands.
            self._event("command_cancelled", f"{link.name}: DO_LAND_START: planned mission landing not available")
            return CommandResult.CANCELLED
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return CommandResult.UNSUPPORTED
            mode = mode_from_main_sub(p[1], p[2] if math.isfinite(p[2]) else 0.0)
            return CommandResult.UNSUPPORTED if mode is None else ap.set_mode(mode)
        if command == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
            return ap.set_mode(HOLD)
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_message_interval(link, int(p[0]), p[1])
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            message_id = int(p[0])
            interval = link.intervals.get(message_id)
            value = -1 if not interval else int(interval * 1e6)
            if message_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                value = 1_000_000
            self._send(link, link.mav.message_interval_encode(message_id, value))
            return CommandResult.ACCEPTED
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            return self._send_once(link, int(p[0]))
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return self._send_once(link, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        return CommandResult.UNSUPPORTED

    def _takeoff(self, altitude_amsl: float) -> CommandResult:
        """MAV_CMD_NAV_TAKEOFF as PX4 takes param7 (m AMSL): unset (NaN) means home + MIS_TAKEOFF_ALT,
        said in an info text; a value below that is raised to it, with a critical text when more
        than 0.1 m below (PX4's navigator takeoff); above it, flown as given."""
        minimum = float(self.autopilot.parameters.value("MIS_TAKEOFF_ALT"))
        text = None
        if not math.isfinite(altitude_amsl):
            relative = minimum
            text = (Severity.INFO, f"Using minimum takeoff altitude: {minimum:.2f} m")
        else:
            relative = altitude_amsl - self.home.altitude
            if relative < minimum:
                if relative < minimum - 0.1:
                    text = (Severity.CRITICAL, f"Using minimum takeoff altitude: {minimum:.2f} m")
                relative = minimum
        result = self.autopilot.takeoff(relative)
        if result == CommandResult.ACCEPTED and text is not None:
            self._statustext(*text)
        return result

    def _set_message_interval(self, link: Link, message_id: int, interval_us: float) -> CommandResult:
        if message_id not in STREAMABLE or message_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return CommandResult.UNSUPPORTED if message_id not in STREAMABLE else CommandResult.DENIED
        if interval_us == -1:
            link.set_interval(message_id, 0.0)
        elif interval_us == 0:
            link.set_interval(message_id, link.defaults.get(message_id, 0.0))
        elif interval_us > 0:
            link.set_interval(message_id, max(interval_us * 1e-6, self.autopilot.tick_period))
        else:
            return CommandResult.DENIED
        return CommandResult.ACCEPTED

    def _send_once(self, link: Link, message_id: int) -> CommandResult:
        if message_id in STREAMABLE or message_id in ONE_SHOT:
            self._send(link, self._build(link, message_id))
            return CommandResult.ACCEPTED
        return CommandResult.UNSUPPORTED

    def _on_param_request_read(self, link: Link, msg) -> None:
        table = self.autopilot.parameters
        try:
            name = msg.param_id if msg.param_index < 0 else table.by_index(msg.param_index).name
            parameter = table.get(name)
        except ParameterError as error:
            self.stats.ignored["PARAM_REQUEST_READ:unknown"] += 1
            self._event("param_unknown", str(error))
            return  # PX4 stays silent for unknown parameters; the requester times out
        self._send_param(link, parameter)

    def _on_param_request_list(self, link: Link, msg) -> None:
        for parameter in self.autopilot.parameters:
            self._send_param(link, parameter)

    def _on_param_set(self, link: Link, msg) -> None:
        table = self.autopilot.parameters
        if msg.param_id not in table:
            self.stats.ignored["PARAM_SET:unknown"] += 1
            self._event("param_unknown", f"set of unknown parameter {msg.param_id!r}")
            return
        value = _param_from_wire(msg.param_value, msg.param_type)
        try:
            parameter = table.set(msg.param_id, value)
            self._event("param_set", f"{parameter.name} = {parameter.value:g}")
        except ParameterError as error:
            parameter = table.get(msg.param_id)
            self._reject(link, "param_set_refused", str(error))
            self._statustext(Severity.WARNING, f"Param set refused: {error}")
        for each in self.links:  # PX4 broadcasts the new value on every link
            self._send_param(each, parameter)

    def _send_param(self, link: Link, parameter: Parameter) -> None:
        value, kind = _param_wire_value(parameter)
        table = self.autopilot.parameters
        self._send(link, link.mav.param_value_encode(
            parameter.name.encode(), value, kind, len(table), table.index_of(parameter.name)))

    def _on_timesync(self, link: Link, msg) -> None:
        if msg.tc1 == 0:
            self._send(link, link.mav.timesync_encode(int(self.autopilot.time * 1e9), msg.ts1))

    def _on_statustext(self, link: Link, msg) -> None:
        """A peer's STATUSTEXT (the companion's): logged and passed on to the other links, as PX4 does, at
        most STATUSTEXT_RELAY_RATE per simulated second from each link (a burst of STATUSTEXT_RELAY_RATE
        passes): a peer that floods status texts must not flood the other side (the companion's MAVSDK
        prints every one it gets). Texts not relayed are counted (stats statustext_not_relayed)."""
        text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("utf-8", "replace")
        self._event("peer_statustext", f"{link.name} [{msg.severity}] {text}")
        now = self.autopilot.time
        tokens, last = self._relay_tokens.get(link.name, (STATUSTEXT_RELAY_RATE, now))
        tokens = min(STATUSTEXT_RELAY_RATE, tokens + (now - last) * STATUSTEXT_RELAY_RATE)
        if tokens < 1.0:
            self._relay_tokens[link.name] = (tokens, now)
            self.stats.statustext_not_relayed[link.name] += 1
            return
        self._relay_tokens[link.name] = (tokens - 1.0, now)
        for other in self.links:
            if other is not link:
                self._send(other, other.mav.statustext_encode(msg.severity, text.encode("utf-8")[:50]))

    def _on_ping(self, link: Link, msg) -> None:
        if msg.target_system == 0 and msg.target_component == 0:  # a request, not an answer to ours
            self._send(link, link.mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_mission_request_list(self, link: Link, msg) -> None:
        self._send(link, link.mav.mission_count_encode(msg.get_srcSystem(), msg.get_srcComponent(), 0,
                                                      getattr(msg, "mission_type", 0)))

    # ------------------------------------------------------------------ send
    def _send(self, link: Link, msg: mavlink.MAVLink_message) -> None:
        link.mav.send(msg)

    def _statustext(self, severity: Severity, text: str) -> None:
        """STATUSTEXT on every link; texts over 50 characters go out in chunks (MAVLink 2 id/chunk_seq)."""
        self._event("statustext", f"[{severity.name}] {text}")
        raw = text.encode("utf-8")[:50 * 20]
        self._statustext_id = (self._statustext_id % 65535) + 1
        chunks = [raw[i:i + 50] for i in range(0, len(raw), 50)] or [b""]
        for link in self.links:
            for seq, chunk in enumerate(chunks):
                message_id = self._statustext_id if len(chunks) > 1 else 0
                self._send(link, link.mav.statustext_encode(int(severity), chunk, message_id, seq))

    def after_tick(self) -> None:
        """Send what is due at the current simulated time: status texts, heartbeat, streams."""
        ap = self.autopilot
        now = ap.time
        if self.companion_blackouts:
            self._update_blackouts()
        if ap.mode != self._last_mode or ap.armed != self._last_armed:
            self._event("state", f"mode={ap.mode.name} armed={ap.armed}", mode=ap.mode.name, armed=bool(ap.armed))
            if ap.failsafe_active and self._last_mode == OFFBOARD:
                self._event("failsafe", f"offboard lost: last setpoint at t={ap.last_setpoint_time:.4f} s, "
                                        f"now {ap.mode.name}", last_setpoint_time=ap.last_setpoint_time,
                            mode=ap.mode.name)
            self._last_mode, self._last_armed = ap.mode, ap.armed
        for severity, text in ap.take_status_texts():
            self._statustext(severity, text)
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + 1.0
            if self._signing_key is not None:
                # Our signing clocks follow the wall clock (as a real autopilot's do), so a peer that
                # restarts takes our new stream and an old captured frame is refused as stale.
                wall_stamp = signing_timestamp()
                for link in self.links:
                    if link.spec.signed:
                        for mav in (link.mav, link.parser):
                            mav.signing.timestamp = max(mav.signing.timestamp, wall_stamp)
            for link in self.links:
                self._send(link, self._heartbeat(link))
        for link in self.links:
            for message_id, interval in link.intervals.items():
                if interval <= 0.0:
                    continue
                due = link.next_due[message_id]
                if now + 1e-9 >= due:
                    try:
                        self._send(link, self._build(link, message_id))
                    except (struct.error, ValueError, OverflowError) as error:
                        # A value that does not fit its field must not stop the vehicle; count and go on.
                        self.stats.ignored[f"encode_error:{message_id}"] += 1
                        self._event("encode_error", f"{link.name}: message {message_id}: {error}")
                    # Keep the phase but never queue a burst after a pause.
                    link.next_due[message_id] = due + interval if due + interval > now else now + interval

    # ------------------------------------------------------------- messages
    def _heartbeat(self, link: Link):
        ap = self.autopilot
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if ap.mode in (HOLD, TAKEOFF, LAND):
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        elif ap.mode == OFFBOARD:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        elif ap.mode == POSITION:
            base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if ap.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if ap.failsafe_active:
            status = mavlink.MAV_STATE_CRITICAL
        elif ap.armed:
            status = mavlink.MAV_STATE_ACTIVE
        else:
            status = mavlink.MAV_STATE_STANDBY
        return link.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, ap.mode.custom_mode, status)

    def _build(self, link: Link, message_id: int):
        builder = self._builder_table.get(message_id)
        if builder is None:
            raise KeyError(message_id)
        return builder(link)

    def _builders(self) -> dict[int, Callable]:
        return {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._extended_sys_state,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._attitude_quaternion,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._local_position_ned,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._global_position_int,
            mavlink.MAVLINK_MSG_ID_ODOMETRY: self._odometry,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._gps_raw_int,
            mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: self._system_time,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self._vfr_hud,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
        }

    def _sys_status(self, link: Link):
        health = _SENSORS
        ready, _ = self.autopilot.ready_to_arm
        present = _SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if ready or self.autopilot.armed:
            health |= mavlink.MAV_SYS_STATUS_PREARM_CHECK
        return link.mav.sys_status_encode(present, present, health, 100, 16800, -1, -1, 0, 0, 0, 0, 0, 0)

    def _extended_sys_state(self, link: Link):
        return link.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self.autopilot.landed_state))

    def _attitude_quaternion(self, link: Link):
        t = self.autopilot.telemetry()
        w = t.angular_velocity
        return link.mav.attitude_quaternion_encode(self.time_boot_ms, *t.quaternion, w[0], w[1], w[2], (1.0, 0.0, 0.0, 0.0))

    def _attitude(self, link: Link):
        t = self.autopilot.telemetry()
        roll, pitch, yaw = _euler(t.quaternion)
        w = t.angular_velocity
        return link.mav.attitude_encode(self.time_boot_ms, roll, pitch, yaw, w[0], w[1], w[2])

    def _local_position_ned(self, link: Link):
        t = self.autopilot.telemetry()
        p, v = t.position, t.velocity
        return link.mav.local_position_ned_encode(self.time_boot_ms, p[0], p[1], p[2], v[0], v[1], v[2])

    def _global_position_int(self, link: Link):
        t = self.autopilot.telemetry()
        lat, lon, alt = self.home.to_geodetic(*t.position)
        _, _, yaw = _euler(t.quaternion)
        v = t.velocity
        return link.mav.global_position_int_encode(
            self.time_boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)),
            int(round(-t.position[2] * 1000.0)), _i16(v[0] * 100.0), _i16(v[1] * 100.0), _i16(v[2] * 100.0),
            int(round(math.degrees(yaw) % 360.0 * 100.0)) % 36000,
        )

    def _odometry(self, link: Link):
        """ODOMETRY as PX4 sends it: pose in local NED, twist in body FRD (the child frame)."""
        ap = self.autopilot
        t = ap.telemetry()
        v_body = _attitude_of(t.quaternion).apply(t.velocity, inverse=True)
        w = t.angular_velocity
        sp = ap.params.position_noise_std**2
        sv = ap.params.velocity_noise_std**2
        pose_cov = [math.nan] * 21
        vel_cov = [math.nan] * 21
        pose_cov[0] = pose_cov[6] = pose_cov[11] = sp
        vel_cov[0] = vel_cov[6] = vel_cov[11] = sv
        msg = link.mav.odometry_encode(
            self.time_usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
            t.position[0], t.position[1], t.position[2], t.quaternion,
            v_body[0], v_body[1], v_body[2], w[0], w[1], w[2], pose_cov, vel_cov, 0,
            mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100,
        )
        if self.on_odometry_sent is not None:
            self.on_odometry_sent(self.time_usec)
        return msg

    def _home_position(self, link: Link):
        ap = self.autopilot
        lat, lon, alt = self.home.to_geodetic(*ap.home)
        h = ap.home
        return link.mav.home_position_encode(
            int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)), h[0], h[1], h[2],
            (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, self.time_usec)

    def _gps_raw_int(self, link: Link):
        t = self.autopilot.telemetry()
        lat, lon, alt = self.home.to_geodetic(*t.position)
        speed = float(np.hypot(t.velocity[0], t.velocity[1]))
        course = math.degrees(math.atan2(t.velocity[1], t.velocity[0])) % 360.0
        return link.mav.gps_raw_int_encode(
            self.time_usec, mavlink.GPS_FIX_TYPE_3D_FIX, int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round(alt * 1000.0)), 80, 120, int(speed * 100.0), int(course * 100.0) % 36000, 14)

    def _system_time(self, link: Link):
        return link.mav.system_time_encode(int((self.unix_epoch + self.autopilot.time) * 1e6), self.time_boot_ms)

    def _vfr_hud(self, link: Link):
        t = self.autopilot.telemetry()
        _, _, yaw = _euler(t.quaternion)
        speed = float(np.hypot(t.velocity[0], t.velocity[1]))
        _, _, alt = self.home.to_geodetic(*t.position)
        return link.mav.vfr_hud_encode(speed, speed, int(math.degrees(yaw) % 360.0), min(100, max(0, int(self.autopilot.thrust_command * 100))),
                                       alt, -t.velocity[2])

    def _autopilot_version(self, link: Link):
        return link.mav.autopilot_version_encode(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1)


def _frame_message_name(frame: bytes) -> str:
    """The message name a raw MAVLink frame announces in its header (for log lines)."""
    if len(frame) >= 10 and frame[0] == mavlink.PROTOCOL_MARKER_V2:
        message_id = int.from_bytes(frame[7:10], "little")
    elif len(frame) >= 6 and frame[0] == mavlink.PROTOCOL_MARKER_V1:
        message_id = frame[5]
    else:
        return "?"
    kind = mavlink.mavlink_map.get(message_id)
    return kind.msgname if kind is not None else f"id {message_id}"


def _i16(value: float) -> int:
    return int(max(-32768, min(32767, round(value))))


def _attitude_of(quaternion: tuple[float, float, float, float]) -> Rotation:
    """The body FRD -> NED rotation of a unit quaternion (w, x, y, z)."""
    return Rotation.from_quat(quaternion, scalar_first=True)


def _euler(quaternion: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad, ZYX convention as MAVLink ATTITUDE uses."""
    yaw, pitch, roll = _attitude_of(quaternion).as_euler("ZYX")
    return float(roll), float(pitch), float(yaw)


__all__ = ["Home", "Link", "LinkSpec", "MavlinkVehicle", "MavlinkStats", "Rejected", "validate_attitude_target",
           "LandedState", "LAND", "TAKEOFF"]
