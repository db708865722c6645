"""The MAVLink side of the plant's vehicle that is not PX4's behaviour: the links (one UDP socket each, signing,
stream intervals), the stream tables, the run-log events and counters, and the Rejected error.

sitl_plant.vehicle.mavlink_vehicle builds MavlinkVehicle on these; its docstring says what the links do.
"""

from __future__ import annotations

import collections
import errno
import os
import socket
import time
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

import pymap3d  # noqa: E402

#: Messages PX4 accepts unsigned when signing is required (MavlinkSignControl's list).
UNSIGNED_ALLOWED = frozenset({
    mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE, mavlink.MAVLINK_MSG_ID_COLLISION,
})


#: Seconds from the Unix epoch to 2015-01-01, the origin of MAVLink signing timestamps (units of 10 us).
_SIGNING_EPOCH = 1420070400


#: A new signed stream may start at most this far (10 us units) behind our timestamp (pymavlink: one minute).
_NEW_STREAM_WINDOW = 6000 * 1000


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
