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

import math
import time
from typing import Callable

from sitl_plant.vehicle.autopilot import Autopilot, OffboardAttitude, OffboardTrajectory
# The protocol pieces, re-exported: sitl_plant.sitl, the tests and the benchmarks import them from here.
from sitl_plant.vehicle.mavlink_protocol import (COMPANION_STREAMS, GCS_STREAMS, ONE_SHOT, STATUSTEXT_RELAY_RATE,
                                                 STREAMABLE, UNSIGNED_ALLOWED, _QUIET, Event, Home, Link, LinkSpec,
                                                 MavlinkStats, Rejected, _frame_message_name, mavlink,
                                                 signing_timestamp)
from sitl_plant.vehicle.mavlink_commands import MavlinkCommands
from sitl_plant.vehicle.mavlink_params import MavlinkParameters
from sitl_plant.vehicle.mavlink_streams import CAPABILITIES, FLIGHT_SW_VERSION, MavlinkStreams, _euler
from sitl_plant.vehicle.parameters import SIGNING_OFF
from sitl_plant.vehicle.px4_modes import LAND, TAKEOFF, LandedState, Severity

#: ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET. pymavlink's SET_ATTITUDE_TARGET has no thrust_body field
#: (checked: 2.4.37 and 2.4.50, the newest release), so a setpoint with this bit is refused rather than
#: flown on a thrust that cannot be read.
THRUST_BODY_SET = 32
#: A setpoint quaternion whose norm is further than this from 1 is rejected, not renormalised.
QUATERNION_NORM_TOLERANCE = 0.05


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


class MavlinkVehicle(MavlinkParameters, MavlinkCommands, MavlinkStreams):
    """The plant as a MAVLink vehicle: decodes, answers and streams on behalf of an Autopilot.

    autopilot: the flight stack. links: the UDP endpoints (companion, ground station...).
    home: geodetic position of the local origin. on_event: called with each Event
    (statustext, rejects, mode/arming changes) for the run log.
    unix_epoch: wall-clock time (s) that simulated time 0 corresponds to, for
    SYSTEM_TIME; every other timestamp is simulated time since boot.

    Here: the links, signing, receiving (every datagram checked and dispatched to an _on_<message> handler) and
    the handlers of setpoints, signing, time sync, status texts, pings and missions. The parameter protocol
    (MavlinkParameters), the commands (MavlinkCommands) and the streams (MavlinkStreams, after_tick) are mixins
    in their own modules; the links and the stream tables are sitl_plant.vehicle.mavlink_protocol's.
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
        #: Fault injection: (start, end) windows, simulated s after the vehicle first entered Offboard, when the
        #: companion link is down both ways.
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
        """Silence the companion link inside `companion_blackouts`: (start, end) windows, s after the vehicle first
        entered Offboard (when the companion took control; no window applies before)."""
        engaged = self.autopilot.first_offboard_time
        if engaged is None:
            return
        since = self.autopilot.time - engaged
        for link in self.links:
            if link.name != "companion":
                continue
            silenced = any(start <= since < end for start, end in self.companion_blackouts)
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


__all__ = ["CAPABILITIES", "COMPANION_STREAMS", "Event", "FLIGHT_SW_VERSION", "GCS_STREAMS", "Home", "LAND", "LandedState",
           "Link", "LinkSpec", "MavlinkStats", "MavlinkVehicle", "ONE_SHOT", "Rejected", "STATUSTEXT_RELAY_RATE",
           "STREAMABLE", "TAKEOFF", "UNSIGNED_ALLOWED", "signing_timestamp", "validate_attitude_target",
           "validate_position_target"]
