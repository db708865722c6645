"""The plant's MAVLink layer (sitl_plant.vehicle.mavlink_vehicle) against plain UDP client sockets.

Client messages are encoded with pymavlink as system 245 / component 190 and handed
to MavlinkVehicle.handle_datagram directly; the plant's answers travel over real
loopback UDP to two client sockets (companion and ground station) and are parsed
with a separate pymavlink parser. Simulated time is driven with Autopilot.tick()
and MavlinkVehicle.after_tick(); nothing here depends on the wall clock.
"""

from __future__ import annotations

import math
import os
import socket
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from sitl_plant.vehicle.autopilot import ARMING_READY_AFTER, Autopilot  # noqa: E402
from sitl_plant.vehicle.mavlink_vehicle import (  # noqa: E402
    COMPANION_STREAMS,
    GCS_STREAMS,
    Home,
    LinkSpec,
    MavlinkVehicle,
)
from dataclasses import replace  # noqa: E402

from sitl_plant.vehicle.params import QuadrotorParams, table1_params  # noqa: E402
from sitl_plant.vehicle.px4_modes import (  # noqa: E402
    HOLD, LAND, OFFBOARD, POSITION, TAKEOFF, CommandResult, MainMode, Severity, decode_custom_mode)

HOME = Home(47.397742, 8.545594, 488.0)
CLIENT_SYSTEM, CLIENT_COMPONENT = 245, 190
PARAMS = table1_params()
NOISE_FREE = replace(PARAMS, position_noise_std=0.0, velocity_noise_std=0.0)
HOVER = PARAMS.hover_thrust_normalized
LEVEL = (1.0, 0.0, 0.0, 0.0)
RATES_IGNORED = 7  # body roll/pitch/yaw rate ignore bits of SET_ATTITUDE_TARGET.type_mask
THROTTLE_IGNORE = mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
ATTITUDE_IGNORE = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
CUSTOM = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def roll_quaternion(roll_deg: float) -> tuple[float, float, float, float]:
    half = math.radians(roll_deg) / 2.0
    return (math.cos(half), math.sin(half), 0.0, 0.0)


def tilt_deg(rotation: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, float(rotation[2, 2])))))


# --------------------------------------------------------------------------- harness


class Client:
    """A UDP socket on loopback standing in for the companion or the ground station."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self.parser = mavlink.MAVLink(None, srcSystem=255, srcComponent=0)
        self.parser.robust_parsing = True
        # (simulated time, autopilot telemetry of that tick, message)
        self.received: list[tuple[float, object, mavlink.MAVLink_message]] = []

    def drain(self, time: float, telemetry) -> None:
        while True:
            try:
                data, _ = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            for msg in self.parser.parse_buffer(data) or []:
                self.received.append((time, telemetry, msg))

    def take(self, kind: str | None = None) -> list:
        """Messages received so far (of one type, if given); clears the whole log."""
        messages = [m for _, _, m in self.received if kind is None or m.get_type() == kind]
        self.received.clear()
        return messages

    def of_type(self, kind: str) -> list:
        return [m for _, _, m in self.received if m.get_type() == kind]

    def close(self) -> None:
        self.sock.close()


class Harness:
    """Autopilot + MavlinkVehicle with a companion and a ground-station client."""

    def __init__(
        self,
        params: QuadrotorParams = PARAMS,
        seed: int = 5,
        yaw: float = 0.0,
        start_position: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.companion = Client()
        self.gcs = Client()
        self.autopilot = Autopilot(params, start_position=start_position, seed=seed, yaw=yaw)
        self.vehicle = MavlinkVehicle(
            self.autopilot,
            [
                LinkSpec("companion", "127.0.0.1", self.companion.address[1], COMPANION_STREAMS),
                LinkSpec("gcs", "127.0.0.1", self.gcs.address[1], GCS_STREAMS, signed=True),
            ],
            HOME,
            unix_epoch=1.7e9,
        )
        self.mav = mavlink.MAVLink(None, srcSystem=CLIENT_SYSTEM, srcComponent=CLIENT_COMPONENT)

    def close(self) -> None:
        try:
            self.vehicle.close()
        finally:
            self.companion.close()
            self.gcs.close()

    # ---- time
    def drain(self) -> None:
        ap = self.autopilot
        telemetry = ap.telemetry()
        self.companion.drain(ap.time, telemetry)
        self.gcs.drain(ap.time, telemetry)

    def step(self, duration: float) -> None:
        """Tick, send what is due and collect it, for `duration` simulated seconds."""
        ap = self.autopilot
        for _ in range(int(round(duration / ap.tick_period))):
            ap.tick()
            self.vehicle.after_tick()
            self.drain()

    def fly_silently(self, duration: float) -> None:
        """Tick the autopilot only (setup flights), then drop what it wanted to say."""
        self.autopilot.run(duration)
        self.autopilot.take_status_texts()

    # ---- sending
    def deliver(self, data: bytes, link: int = 0) -> None:
        client = self.companion if link == 0 else self.gcs
        self.vehicle.handle_datagram(self.vehicle.links[link], data, client.address)
        self.drain()

    def send(self, msg, link: int = 0) -> bytes:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.deliver(data, link)
        return data

    def command_long(self, command: int, *params: float, target=(1, 1), link: int = 0) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(self.mav.command_long_encode(target[0], target[1], command, 0, *p), link)

    def command_int(self, command: int, p1=0.0, p2=0.0, p3=0.0, p4=0.0, *, x=0, y=0, z=0.0, link: int = 0) -> None:
        self.send(self.mav.command_int_encode(1, 1, mavlink.MAV_FRAME_GLOBAL, command, 0, 0, p1, p2, p3, p4, x, y, z), link)

    def setpoint(self, q=LEVEL, thrust=HOVER, type_mask=RATES_IGNORED, rates=(0.0, 0.0, 0.0), link: int = 0) -> None:
        self.send(self.mav.set_attitude_target_encode(0, 1, 1, type_mask, list(q), *rates, thrust), link)

    def acks(self, client: Client | None = None) -> list:
        return (client or self.companion).take("COMMAND_ACK")

    # ---- setup flights
    def hover(self, altitude: float = 4.0) -> None:
        ap = self.autopilot
        self.fly_silently(ARMING_READY_AFTER + 0.1)
        assert ap.arm() == CommandResult.ACCEPTED
        assert ap.takeoff(altitude) == CommandResult.ACCEPTED
        for _ in range(5000):
            ap.tick()
            if ap.mode == HOLD:
                break
        self.fly_silently(3.5)
        assert ap.mode == HOLD and ap.state.position[2] < -altitude + 0.1
        self.step(0.01)  # flush pending status texts and due streams
        self.companion.take()
        self.gcs.take()


@pytest.fixture
def harness():
    made: list[Harness] = []

    def make(**kwargs) -> Harness:
        h = Harness(**kwargs)
        made.append(h)
        return h

    try:
        yield make
    finally:
        for h in made:
            h.close()


def single_ack(h: Harness, command: int, result: CommandResult) -> None:
    """Exactly one COMMAND_ACK, on the companion link only, for `command`, addressed to the client."""
    acks = h.acks()
    assert len(acks) == 1, acks
    ack = acks[0]
    assert ack.command == command
    assert ack.result == int(result), (ack.result, result)
    assert (ack.target_system, ack.target_component) == (CLIENT_SYSTEM, CLIENT_COMPONENT)
    assert h.gcs.take("COMMAND_ACK") == []


# --------------------------------------------------------------------------- heartbeat


def test_heartbeat_identity_mode_and_armed_flag_on_both_links(harness) -> None:
    h = harness()
    h.step(0.02)
    for client in (h.companion, h.gcs):
        beats = client.take("HEARTBEAT")
        assert len(beats) == 1
        hb = beats[0]
        assert hb.type == mavlink.MAV_TYPE_QUADROTOR
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
        assert hb.custom_mode == (4 << 16) | (3 << 24)  # AUTO / LOITER: Hold
        assert hb.base_mode & CUSTOM
        assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1

    h.step(ARMING_READY_AFTER + 0.1)
    assert len(h.companion.take("HEARTBEAT")) == 1  # 1 Hz
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    single_ack(h, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, CommandResult.ACCEPTED)
    h.step(1.0)
    for client in (h.companion, h.gcs):
        hb = client.take("HEARTBEAT")[-1]
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert decode_custom_mode(hb.custom_mode) == (HOLD.main, HOLD.sub)

    h.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, *([math.nan] * 6), HOME.altitude + 3.0)
    single_ack(h, mavlink.MAV_CMD_NAV_TAKEOFF, CommandResult.ACCEPTED)
    h.step(1.0)
    for client in (h.companion, h.gcs):
        hb = client.take("HEARTBEAT")[-1]
        assert hb.custom_mode == (4 << 16) | (2 << 24)  # AUTO / TAKEOFF
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED

    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.POSCTL)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    assert h.autopilot.mode == POSITION
    h.step(1.0)
    hb = h.gcs.take("HEARTBEAT")[-1]
    assert hb.custom_mode == 3 << 16  # POSCTL, no sub mode


def test_disarmed_heartbeat_after_disarm(harness) -> None:
    h = harness()
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
    acks = h.acks()
    assert [a.result for a in acks] == [CommandResult.ACCEPTED, CommandResult.ACCEPTED]
    assert not h.autopilot.armed
    h.step(1.0)
    assert not h.companion.take("HEARTBEAT")[-1].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


# --------------------------------------------------------------------------- commands


def test_arm_is_denied_early_with_a_critical_text_and_accepted_later(harness) -> None:
    h = harness()
    h.step(0.2)
    h.companion.take()
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    single_ack(h, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, CommandResult.DENIED)
    assert not h.autopilot.armed
    h.step(0.01)
    texts = h.gcs.take("STATUSTEXT")
    assert any(t.severity == Severity.CRITICAL and "Arming denied" in t.text for t in texts), texts

    h.fly_silently(ARMING_READY_AFTER)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    single_ack(h, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, CommandResult.ACCEPTED)
    assert h.autopilot.armed
    assert h.vehicle.stats.commands["MAV_CMD_COMPONENT_ARM_DISARM"] == 2


def test_offboard_without_setpoints_is_temporarily_rejected_then_accepted_with_them(harness) -> None:
    h = harness()
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.OFFBOARD)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.TEMPORARILY_REJECTED)
    assert h.autopilot.mode == HOLD
    h.setpoint()
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.OFFBOARD)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    assert h.autopilot.mode == OFFBOARD


def test_companion_link_blackouts_count_from_the_first_switch_to_offboard(harness) -> None:
    """[faults.mavlink] windows are s after the companion took control: none applies before Offboard; inside one
    nothing reaches the companion (the ground-station link keeps its telemetry) and the offboard-loss failsafe acts."""
    h = harness()
    h.hover()
    h.vehicle.companion_blackouts = [(2.0, 3.0)]
    h.step(4.0)  # in Hold, long after 2-3 s of plant time: no window yet
    assert len(h.companion.take("HEARTBEAT")) >= 3
    h.setpoint()
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.OFFBOARD)
    engaged = h.autopilot.first_offboard_time
    assert h.autopilot.mode == OFFBOARD and engaged == pytest.approx(h.autopilot.time)
    h.companion.take()
    h.gcs.take()
    for _ in range(200):  # 4 s at 50 Hz; the setpoints of the window are dropped with the link
        h.setpoint()
        h.step(0.02)
    def after(client: Client) -> np.ndarray:
        return np.array([time for time, _, message in client.received if message.get_type() == "HEARTBEAT"]) - engaged
    companion, gcs = after(h.companion), after(h.gcs)
    assert not np.any((companion >= 2.0) & (companion < 3.0)), companion
    assert np.any((companion > 1.0) & (companion < 2.0)) and np.any(companion >= 3.0)
    assert np.any((gcs >= 2.0) & (gcs < 3.0))
    assert h.vehicle.links[0].dropped_silenced > 0
    assert h.autopilot.failsafe_active and h.autopilot.mode != OFFBOARD  # COM_OF_LOSS_T = 1 s inside the window


@pytest.mark.parametrize(
    "command, params",
    [
        (mavlink.MAV_CMD_DO_FLIGHTTERMINATION, (1.0,)),
        (mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, ()),
        (mavlink.MAV_CMD_DO_SET_MODE, (CUSTOM, MainMode.ACRO, 0.0)),
        (mavlink.MAV_CMD_DO_SET_MODE, (CUSTOM, MainMode.AUTO, 5.0)),  # AUTO/RTL
        (mavlink.MAV_CMD_DO_SET_MODE, (CUSTOM, MainMode.STABILIZED, 0.0)),
        (mavlink.MAV_CMD_DO_SET_MODE, (0.0, MainMode.POSCTL, 0.0)),  # no custom-mode flag
        (mavlink.MAV_CMD_DO_SET_MODE, (CUSTOM, 3.5, 0.0)),  # not a whole mode number
        (mavlink.MAV_CMD_DO_CHANGE_SPEED, (1.0, 3.0)),
        (31999, ()),  # not a MAV_CMD at all
    ],
    ids=["termination", "rtl", "acro", "auto-rtl", "stabilized", "no-custom-flag", "fractional", "change-speed", "unknown"],
)
def test_unsupported_commands_are_acked_unsupported_and_change_nothing(harness, command: int, params) -> None:
    h = harness()
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.autopilot.arm()
    h.command_long(command, *params)
    single_ack(h, command, CommandResult.UNSUPPORTED)
    assert h.autopilot.mode == HOLD and h.autopilot.armed


def test_command_int_is_acked_and_executed(harness) -> None:
    h = harness()
    h.step(0.1)
    h.command_int(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.POSCTL)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    assert h.autopilot.mode == POSITION
    h.command_int(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    single_ack(h, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, CommandResult.UNSUPPORTED)
    h.command_int(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.AUTO, 3.0)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    assert h.autopilot.mode == HOLD


def test_takeoff_command_uses_param7_as_amsl_altitude(harness) -> None:
    h = harness(params=NOISE_FREE)
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    h.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, *([math.nan] * 6), HOME.altitude + 3.5)
    acks = h.acks()
    assert [(a.command, a.result) for a in acks] == [
        (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, CommandResult.ACCEPTED),
        (mavlink.MAV_CMD_NAV_TAKEOFF, CommandResult.ACCEPTED),
    ]
    assert h.autopilot.mode == TAKEOFF
    h.fly_silently(7.0)
    assert -h.autopilot.state.position[2] == pytest.approx(3.5, abs=0.05)


TAKEOFF_CASES = [
    # (param7 in m AMSL, expected height above home in m, STATUSTEXT severity and text PX4's navigator sends, if any)
    (HOME.altitude + 3.5, 3.5, None),
    (10.0, 2.5, (Severity.CRITICAL, "Using minimum takeoff altitude: 2.50 m")),  # MAVProxy's `takeoff 10`
    (math.nan, 2.5, (Severity.INFO, "Using minimum takeoff altitude: 2.50 m")),
    (HOME.altitude + 2.45, 2.5, None),  # within PX4's 0.1 m of the minimum: raised without a word
    (HOME.altitude - 50.0, 2.5, (Severity.CRITICAL, "Using minimum takeoff altitude: 2.50 m")),
]


@pytest.mark.parametrize("param7, height, text", TAKEOFF_CASES, ids=["above", "mavproxy-10", "nan", "just-below", "below-home"])
def test_takeoff_altitude_is_handled_as_px4_does(harness, param7, height, text) -> None:
    """PX4: param7 is AMSL; unset -> home + MIS_TAKEOFF_ALT; below that minimum -> the minimum (2.5 m default)."""
    h = harness(params=NOISE_FREE)
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    h.step(0.01)
    h.companion.take()
    h.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, *([math.nan] * 6), param7)
    h.step(0.01)
    texts = [(t.severity, t.text) for t in h.companion.of_type("STATUSTEXT")]
    acks = h.companion.take("COMMAND_ACK")
    assert [(a.command, a.result) for a in acks] == [(mavlink.MAV_CMD_NAV_TAKEOFF, CommandResult.ACCEPTED)]
    minimum_texts = [t for t in texts if "minimum takeoff altitude" in t[1]]
    assert minimum_texts == ([] if text is None else [(int(text[0]), text[1])])
    h.fly_silently(8.0)
    assert -h.autopilot.state.position[2] == pytest.approx(height, abs=0.05)


def test_do_land_start_without_a_mission_landing_is_cancelled_as_px4_answers_it(harness) -> None:
    """PX4 answers DO_LAND_START (MAVProxy's `land`) with CANCELLED when no mission has a landing; the
    vehicle goes on holding. NAV_LAND (or Land mode) is how it lands."""
    h = harness()
    h.hover(3.0)
    h.command_long(mavlink.MAV_CMD_DO_LAND_START, target=(1, 0))
    single_ack(h, mavlink.MAV_CMD_DO_LAND_START, CommandResult.CANCELLED)
    assert h.autopilot.mode == HOLD
    h.command_long(mavlink.MAV_CMD_NAV_LAND)
    single_ack(h, mavlink.MAV_CMD_NAV_LAND, CommandResult.ACCEPTED)
    assert h.autopilot.mode == LAND


def test_land_mode_by_do_set_mode_as_mavproxy_mode_land_sends_it(harness) -> None:
    h = harness()
    h.hover(3.0)
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.AUTO, 6.0)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    assert h.autopilot.mode == LAND


def test_commands_to_another_system_or_component_are_ignored_without_ack(harness) -> None:
    h = harness()
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, target=(2, 1))
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, target=(1, 5))
    assert h.companion.take("COMMAND_ACK") == [] and h.gcs.take("COMMAND_ACK") == []
    assert not h.autopilot.armed
    assert h.vehicle.stats.ignored["COMMAND_LONG:other_system"] == 1
    assert h.vehicle.stats.ignored["COMMAND_LONG:other_component"] == 1
    assert h.vehicle.stats.received["COMMAND_LONG"] == 0
    # Broadcast (0/0) is for us.
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, target=(0, 0))
    single_ack(h, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, CommandResult.ACCEPTED)
    assert h.autopilot.armed


def test_a_command_with_nan_in_a_used_parameter_is_denied(harness) -> None:
    h = harness()
    h.fly_silently(ARMING_READY_AFTER + 0.1)
    h.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, math.nan)
    single_ack(h, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, CommandResult.DENIED)
    assert not h.autopilot.armed
    assert h.vehicle.stats.rejected["command_not_finite"] == 1


def test_commands_on_the_gcs_link_are_acked_on_that_link(harness) -> None:
    h = harness()
    h.step(0.1)
    h.command_long(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, link=1)
    acks = h.gcs.take("COMMAND_ACK")
    assert len(acks) == 1 and acks[0].result == CommandResult.UNSUPPORTED
    assert acks[0].target_system == CLIENT_SYSTEM
    assert h.companion.take("COMMAND_ACK") == []


# --------------------------------------------------------------------------- streams


def count(client: Client, kind: str) -> int:
    return len(client.take(kind))


def test_set_message_interval_rerates_disables_and_restores_a_stream(harness) -> None:
    h = harness()
    lpn = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    h.step(0.1)
    h.companion.take(), h.gcs.take()

    h.step(2.0)
    assert count(h.companion, "LOCAL_POSITION_NED") == pytest.approx(60, abs=1)  # 30 Hz default
    assert count(h.gcs, "LOCAL_POSITION_NED") == pytest.approx(10, abs=1)  # 5 Hz default

    h.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, lpn, 200_000)  # 5 Hz
    single_ack(h, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, CommandResult.ACCEPTED)
    h.step(2.0)
    assert count(h.companion, "LOCAL_POSITION_NED") == pytest.approx(10, abs=1)
    assert count(h.gcs, "LOCAL_POSITION_NED") == pytest.approx(10, abs=1)  # other link untouched

    h.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, lpn, -1)
    single_ack(h, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, CommandResult.ACCEPTED)
    h.step(2.0)
    assert count(h.companion, "LOCAL_POSITION_NED") == 0
    assert count(h.gcs, "LOCAL_POSITION_NED") == pytest.approx(10, abs=1)

    h.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, lpn, 0)
    single_ack(h, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, CommandResult.ACCEPTED)
    h.step(2.0)
    assert count(h.companion, "LOCAL_POSITION_NED") == pytest.approx(60, abs=1)


def test_set_message_interval_can_start_a_stream_the_link_does_not_send(harness) -> None:
    h = harness()
    h.step(1.0)
    assert count(h.companion, "VFR_HUD") == 0 and count(h.gcs, "ODOMETRY") == 0
    h.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_VFR_HUD, 250_000)
    single_ack(h, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, CommandResult.ACCEPTED)
    h.step(2.0)
    assert count(h.companion, "VFR_HUD") == pytest.approx(8, abs=1)


@pytest.mark.parametrize(
    "message_id, result",
    [(mavlink.MAVLINK_MSG_ID_HEARTBEAT, CommandResult.DENIED), (31000, CommandResult.UNSUPPORTED)],
    ids=["heartbeat", "unknown"],
)
def test_set_message_interval_refusals(harness, message_id: int, result: CommandResult) -> None:
    h = harness()
    h.step(0.1)
    h.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 10_000)
    single_ack(h, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, result)
    assert h.vehicle.links[0].intervals == h.vehicle.links[0].defaults
    h.companion.take()
    h.step(2.0)
    assert count(h.companion, "HEARTBEAT") == 2  # still 1 Hz


def test_request_message_autopilot_version_and_home_position(harness) -> None:
    h = harness()
    h.step(0.2)  # the t = 0 stream burst is over
    h.companion.take(), h.gcs.take()

    h.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    versions = h.companion.of_type("AUTOPILOT_VERSION")
    single_ack(h, mavlink.MAV_CMD_REQUEST_MESSAGE, CommandResult.ACCEPTED)
    assert len(versions) == 1
    caps = versions[0].capabilities
    assert caps & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert caps & mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    assert versions[0].flight_sw_version >> 24 == 1 and (versions[0].flight_sw_version >> 16) & 0xFF == 14

    h.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION)
    homes = h.companion.of_type("HOME_POSITION")
    single_ack(h, mavlink.MAV_CMD_REQUEST_MESSAGE, CommandResult.ACCEPTED)
    assert len(homes) == 1
    assert homes[0].latitude == pytest.approx(HOME.latitude * 1e7, abs=1)
    assert homes[0].longitude == pytest.approx(HOME.longitude * 1e7, abs=1)
    assert homes[0].altitude == pytest.approx(HOME.altitude * 1000.0, abs=1)
    assert h.gcs.take("HOME_POSITION") == []  # answered on the asking link only

    h.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, 31000)
    others = [m.get_type() for _, _, m in h.companion.received if m.get_type() != "COMMAND_ACK"]
    single_ack(h, mavlink.MAV_CMD_REQUEST_MESSAGE, CommandResult.UNSUPPORTED)
    assert others == []


# --------------------------------------------------------------------------- parameters


def param_value(msg) -> float:
    """A PARAM_VALUE's value, decoding PX4's bytewise integers."""
    if msg.param_type == mavlink.MAV_PARAM_TYPE_INT32:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return msg.param_value


def bytewise(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def test_param_request_read_by_name_and_by_index(harness) -> None:
    h = harness()
    table = h.autopilot.parameters
    h.send(h.mav.param_request_read_encode(1, 1, b"MPC_THR_HOVER", -1))
    values = h.companion.take("PARAM_VALUE")
    assert len(values) == 1
    v = values[0]
    assert v.param_id == "MPC_THR_HOVER"
    assert v.param_type == mavlink.MAV_PARAM_TYPE_REAL32
    assert v.param_value == pytest.approx(1.0 / 1.5, rel=1e-6)
    assert v.param_count == len(table)
    assert v.param_index == table.index_of("MPC_THR_HOVER")
    assert h.gcs.take("PARAM_VALUE") == []

    index = table.index_of("MPC_LAND_SPEED")
    h.send(h.mav.param_request_read_encode(1, 1, b"", index))
    values = h.companion.take("PARAM_VALUE")
    assert len(values) == 1
    assert values[0].param_id == "MPC_LAND_SPEED" and values[0].param_index == index
    assert values[0].param_value == pytest.approx(0.7, rel=1e-6)


def test_int_parameters_are_encoded_bytewise(harness) -> None:
    h = harness()
    h.autopilot.parameters.set("COM_OBL_RC_ACT", 4)
    h.send(h.mav.param_request_read_encode(1, 1, b"COM_OBL_RC_ACT", -1))
    (v,) = h.companion.take("PARAM_VALUE")
    assert v.param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", v.param_value))[0] == 4
    assert v.param_value != 4.0  # the bits, not the number


def test_param_request_list_returns_every_parameter_once(harness) -> None:
    h = harness()
    table = h.autopilot.parameters
    h.send(h.mav.param_request_list_encode(1, 1))
    values = h.companion.take("PARAM_VALUE")
    assert len(values) == len(table) == 28
    assert sorted(v.param_index for v in values) == list(range(len(table)))
    assert {v.param_count for v in values} == {len(table)}
    by_name = {v.param_id: v for v in values}
    assert set(by_name) == {p.name for p in table}
    for parameter in table:
        v = by_name[parameter.name]
        assert v.param_index == table.index_of(parameter.name)
        assert param_value(v) == pytest.approx(parameter.value, rel=1e-6)
    assert by_name["SIM_SPEED_FACTOR"].param_value == pytest.approx(1.0)  # a full 16-char name
    assert by_name["SIM_MASS"].param_value == pytest.approx(PARAMS.mass)


def test_param_set_changes_the_value_and_is_echoed_on_every_link(harness) -> None:
    h = harness()
    h.send(h.mav.param_set_encode(1, 1, b"COM_OF_LOSS_T", 2.5, mavlink.MAV_PARAM_TYPE_REAL32))
    assert h.autopilot.parameters.value("COM_OF_LOSS_T") == 2.5
    for client in (h.companion, h.gcs):
        (v,) = client.take("PARAM_VALUE")
        assert v.param_id == "COM_OF_LOSS_T" and v.param_value == 2.5
    h.send(h.mav.param_set_encode(1, 1, b"COM_OBL_RC_ACT", bytewise(5), mavlink.MAV_PARAM_TYPE_INT32))
    assert h.autopilot.parameters.value("COM_OBL_RC_ACT") == 5
    (v,) = h.companion.take("PARAM_VALUE")
    assert v.param_type == mavlink.MAV_PARAM_TYPE_INT32 and param_value(v) == 5
    assert h.vehicle.stats.rejected["param_set_refused"] == 0


@pytest.mark.parametrize(
    "name, wire_value, wire_type",
    [
        ("COM_OBL_RC_ACT", bytewise(3), mavlink.MAV_PARAM_TYPE_INT32),
        ("SIM_MASS", 2.0, mavlink.MAV_PARAM_TYPE_REAL32),
        ("MPC_LAND_SPEED", 9.0, mavlink.MAV_PARAM_TYPE_REAL32),
    ],
    ids=["unsupported-action", "read-only", "out-of-range"],
)
def test_refused_param_set_echoes_the_unchanged_value(harness, name: str, wire_value: float, wire_type: int) -> None:
    h = harness()
    before = h.autopilot.parameters.value(name)
    h.send(h.mav.param_set_encode(1, 1, name.encode(), wire_value, wire_type))
    assert h.autopilot.parameters.value(name) == before
    assert h.vehicle.stats.rejected["param_set_refused"] == 1
    for client in (h.companion, h.gcs):
        (v,) = client.take("PARAM_VALUE")
        assert v.param_id == name
        assert param_value(v) == pytest.approx(before, rel=1e-6)


def test_unknown_parameters_get_no_reply(harness) -> None:
    h = harness()
    h.send(h.mav.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))
    h.send(h.mav.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))
    h.send(h.mav.param_request_read_encode(1, 1, b"", 500))
    assert h.companion.take("PARAM_VALUE") == [] and h.gcs.take("PARAM_VALUE") == []
    assert h.vehicle.stats.ignored["PARAM_SET:unknown"] == 1
    assert h.vehicle.stats.ignored["PARAM_REQUEST_READ:unknown"] == 2
    assert sum(h.vehicle.stats.rejected.values()) == 0


# --------------------------------------------------------------------------- statustext


def test_long_statustext_arrives_in_chunks_with_one_id(harness) -> None:
    h = harness()
    h.step(0.01)
    h.companion.take(), h.gcs.take()
    h.send(h.mav.param_set_encode(1, 1, b"COM_OBL_RC_ACT", bytewise(3), mavlink.MAV_PARAM_TYPE_INT32))
    h.send(h.mav.param_set_encode(1, 1, b"SIM_MASS", 2.0, mavlink.MAV_PARAM_TYPE_REAL32))
    ids = []
    for client in (h.companion, h.gcs):
        texts = client.take("STATUSTEXT")
        first = [t for t in texts if t.id == texts[0].id]
        assert len(first) >= 2
        assert texts[0].id != 0
        assert [t.chunk_seq for t in first] == list(range(len(first)))
        assert all(t.severity == Severity.WARNING for t in first)
        assert all(len(t.text) == 50 for t in first[:-1])
        joined = "".join(t.text for t in first)
        assert joined.startswith("Param set refused: COM_OBL_RC_ACT")
        assert "3" in joined and len(joined) > 50
        # The second (short) refusal is a single message with id 0.
        rest = [t for t in texts if t.id != texts[0].id]
        assert len(rest) == 1 and rest[0].id == 0 and rest[0].chunk_seq == 0
        assert "SIM_MASS" in rest[0].text
        ids.append(texts[0].id)
    assert ids[0] == ids[1]  # the same logical message on both links


def test_two_long_statustexts_get_different_ids(harness) -> None:
    h = harness()
    for _ in range(2):
        h.send(h.mav.param_set_encode(1, 1, b"COM_OBL_RC_ACT", bytewise(3), mavlink.MAV_PARAM_TYPE_INT32))
    texts = h.companion.take("STATUSTEXT")
    ids = sorted({t.id for t in texts})
    assert len(ids) == 2 and 0 not in ids


# --------------------------------------------------------------------------- ping / timesync


def test_ping_request_is_answered_and_answers_are_not(harness) -> None:
    h = harness()
    h.step(0.1)
    h.companion.take()
    h.send(h.mav.ping_encode(123_456_789, 42, 0, 0))
    (reply,) = h.companion.take("PING")
    assert (reply.time_usec, reply.seq) == (123_456_789, 42)
    assert (reply.target_system, reply.target_component) == (CLIENT_SYSTEM, CLIENT_COMPONENT)
    h.send(h.mav.ping_encode(123_456_789, 43, 1, 1))  # an answer to a ping of the vehicle's
    assert h.companion.take("PING") == []


def test_timesync_request_is_answered_with_simulated_time_in_ns(harness) -> None:
    h = harness()
    h.step(1.24)
    h.companion.take()
    h.send(h.mav.timesync_encode(0, 987_654_321))
    (reply,) = h.companion.take("TIMESYNC")
    assert reply.ts1 == 987_654_321
    assert reply.tc1 == pytest.approx(h.autopilot.time * 1e9, abs=1)
    assert reply.tc1 == pytest.approx(1.24e9, abs=1e3)
    h.send(h.mav.timesync_encode(555, 987_654_321))  # an answer, not a request
    assert h.companion.take("TIMESYNC") == []


# --------------------------------------------------------------------------- position messages


def test_global_position_int_at_home_and_relative_altitude_tracks_z(harness) -> None:
    h = harness(params=NOISE_FREE)
    h.step(0.3)
    positions = h.companion.of_type("GLOBAL_POSITION_INT")
    assert positions
    for m in positions:
        assert abs(m.lat - HOME.latitude * 1e7) <= 1.0  # 1e-7 deg
        assert abs(m.lon - HOME.longitude * 1e7) <= 1.0
        assert m.alt == pytest.approx(HOME.altitude * 1000.0, abs=1)
        assert m.relative_alt == 0
    h.companion.take()

    ap = h.autopilot
    h.step(ARMING_READY_AFTER)
    ap.arm()
    ap.takeoff(3.0)
    h.step(3.0)
    samples = [(t, tel, m) for t, tel, m in h.companion.received if m.get_type() == "GLOBAL_POSITION_INT"]
    assert len(samples) >= 25
    assert max(m.relative_alt for _, _, m in samples) > 2500
    for _, telemetry, m in samples:
        assert m.relative_alt == pytest.approx(-telemetry.position[2] * 1000.0, abs=1)
        assert m.alt - m.relative_alt == pytest.approx(HOME.altitude * 1000.0, abs=2)
        assert abs(m.lat - HOME.latitude * 1e7) <= 1.0 and abs(m.lon - HOME.longitude * 1e7) <= 1.0
        assert m.vz == pytest.approx(telemetry.velocity[2] * 100.0, abs=1)


def test_global_position_int_follows_a_north_offset(harness) -> None:
    h = harness(params=NOISE_FREE, start_position=(111.0, 0.0))
    h.step(0.01)
    (m,) = h.companion.take("GLOBAL_POSITION_INT")
    # 111 m north is about 1e-3 deg of latitude, and no change of longitude.
    assert (m.lat - HOME.latitude * 1e7) == pytest.approx(1e4 * 111.0 / 111.2, rel=0.01)
    assert abs(m.lon - HOME.longitude * 1e7) <= 1.0
    assert m.relative_alt == 0


def test_odometry_twist_is_in_body_frd(harness) -> None:
    h = harness(yaw=0.8)
    ap = h.autopilot
    h.hover(altitude=4.0)
    # Fly a tilted attitude in offboard so the body and NED velocities differ clearly.
    yaw_q = (math.cos(0.4), 0.0, 0.0, math.sin(0.4))
    pitch = math.radians(-15.0)
    pitch_q = (math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0)
    w1, x1, y1, z1 = yaw_q
    w2, x2, y2, z2 = pitch_q
    q = (  # yaw then pitch, body FRD -> NED
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )
    h.setpoint(q, HOVER / math.cos(pitch))
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.OFFBOARD)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    h.companion.take()
    for _ in range(10):
        h.setpoint(q, HOVER / math.cos(pitch))
        h.step(0.2)
    assert ap.mode == OFFBOARD
    samples = [(tel, m) for _, tel, m in h.companion.received if m.get_type() == "ODOMETRY"]
    assert len(samples) == pytest.approx(100, abs=2)  # 50 Hz for 2 s
    assert h.gcs.of_type("ODOMETRY") == []  # off on the ground-station link
    tel, last = samples[-1]
    assert np.linalg.norm(tel.velocity[:2]) > 2.0  # really moving
    for tel, m in samples:
        assert m.frame_id == mavlink.MAV_FRAME_LOCAL_NED and m.child_frame_id == mavlink.MAV_FRAME_BODY_FRD
        np.testing.assert_allclose([m.x, m.y, m.z], tel.position, atol=1e-5)
        np.testing.assert_allclose(m.q, tel.quaternion, atol=1e-6)
        r = Rotation.from_quat(m.q, scalar_first=True).as_matrix()
        v_body = np.array([m.vx, m.vy, m.vz])
        np.testing.assert_allclose(r @ v_body, tel.velocity, atol=1e-4)
    v_body = np.array([last.vx, last.vy, last.vz])
    assert np.linalg.norm(v_body - tel.velocity) > 1.0  # the rotation matters
    assert v_body[0] > 2.0 and abs(v_body[1]) < 0.3  # flying nose first


# --------------------------------------------------------------------------- malformed traffic


def valid_setpoint_still_works(h: Harness) -> None:
    received = h.vehicle.stats.received["SET_ATTITUDE_TARGET"]
    count_before = h.autopilot.setpoints_received
    h.setpoint()
    assert h.autopilot.setpoints_received == count_before + 1
    assert h.vehicle.stats.received["SET_ATTITUDE_TARGET"] == received + 1


def test_bad_crc_is_rejected(harness) -> None:
    h = harness()
    data = bytearray(h.mav.set_attitude_target_encode(0, 1, 1, RATES_IGNORED, list(LEVEL), 0, 0, 0, 0.5).pack(h.mav))
    data[-1] ^= 0xFF
    h.deliver(bytes(data))
    assert h.vehicle.stats.rejected["bad_crc"] == 1
    assert h.autopilot.setpoints_received == 0
    valid_setpoint_still_works(h)


def test_unknown_message_id_is_rejected(harness) -> None:
    h = harness()
    unknown = 42_424
    assert unknown not in mavlink.mavlink_map
    data = bytearray(h.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(h.mav))
    data[7:10] = unknown.to_bytes(3, "little")
    h.deliver(bytes(data))
    assert h.vehicle.stats.rejected["unknown_message_id"] == 1
    assert sum(h.vehicle.stats.received.values()) == 0
    valid_setpoint_still_works(h)


def test_random_garbage_is_rejected_and_valid_setpoints_after_it_are_used(harness) -> None:
    """Each UDP datagram is a whole unit: garbage in one must not eat the next one."""
    h = harness()
    rng = np.random.default_rng(2024)
    for i in range(8):
        garbage = rng.bytes(int(rng.integers(1, 120)))
        rejected_before = sum(h.vehicle.stats.rejected.values())
        h.deliver(garbage)
        assert sum(h.vehicle.stats.rejected.values()) > rejected_before, f"garbage datagram {i} not counted"
        assert sum(h.vehicle.stats.received.values()) == i
        valid_setpoint_still_works(h)


def test_a_truncated_frame_does_not_swallow_the_next_datagram(harness) -> None:
    h = harness()
    frame = h.mav.set_attitude_target_encode(0, 1, 1, RATES_IGNORED, list(LEVEL), 0, 0, 0, 0.5).pack(h.mav)
    h.deliver(frame[:10])  # a datagram cut short
    valid_setpoint_still_works(h)
    valid_setpoint_still_works(h)
    # The cut datagram itself is counted as malformed, once; the valid ones are not.
    assert sum(h.vehicle.stats.rejected.values()) == 1
    assert h.vehicle.stats.rejected["truncated_frame"] == 1


INVALID_SETPOINTS = [
    # (q, thrust, type_mask, body rates, counter key)
    ((math.nan, 0.0, 0.0, 0.0), 0.5, RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_not_finite"),
    (roll_quaternion(30.0), math.nan, RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_not_finite"),
    ((0.0, 0.0, 0.0, 0.0), 0.5, RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_quaternion_zero"),
    (tuple(2.0 * c for c in roll_quaternion(30.0)), 0.5, RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_quaternion_not_unit"),
    (roll_quaternion(30.0), 1.5, RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_thrust_out_of_range"),
    (roll_quaternion(30.0), -0.1, RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_thrust_out_of_range"),
    (roll_quaternion(30.0), 0.5, 0, (0.5, 0.0, 0.0), "setpoint_rates_unsupported"),
    (roll_quaternion(30.0), 0.5, THROTTLE_IGNORE | ATTITUDE_IGNORE | RATES_IGNORED, (0.0, 0.0, 0.0), "setpoint_empty"),
]
INVALID_IDS = ["nan-q", "nan-thrust", "zero-q", "norm-2-q", "thrust-1.5", "thrust-negative", "rates", "empty"]


@pytest.mark.parametrize("q, thrust, mask, rates, key", INVALID_SETPOINTS, ids=INVALID_IDS)
def test_invalid_setpoints_are_rejected_by_reason(harness, q, thrust, mask, rates, key) -> None:
    h = harness()
    h.setpoint(q, thrust, mask, rates)
    assert h.vehicle.stats.rejected[key] == 1
    assert sum(h.vehicle.stats.rejected.values()) == 1
    assert h.autopilot.setpoints_received == 0
    valid_setpoint_still_works(h)


def test_valid_setpoint_variants_are_accepted(harness) -> None:
    h = harness()
    h.setpoint(roll_quaternion(10.0), 0.0)  # zero thrust is in range
    h.setpoint(roll_quaternion(10.0), 1.0)
    h.setpoint(tuple(1.03 * c for c in roll_quaternion(10.0)), 0.5)  # within the norm tolerance
    h.setpoint(roll_quaternion(10.0), 0.5, 0, (0.0, 0.0, 0.0))  # rates not ignored but zero
    assert h.autopilot.setpoints_received == 4
    assert sum(h.vehicle.stats.rejected.values()) == 0


def test_in_offboard_the_vehicle_keeps_the_last_valid_setpoint(harness) -> None:
    h = harness()
    ap = h.autopilot
    h.hover(altitude=4.0)
    h.setpoint(LEVEL, HOVER)
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.OFFBOARD)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    valid = ap.setpoints_received
    for q, thrust, mask, rates, key in INVALID_SETPOINTS:
        before = h.vehicle.stats.rejected[key]
        h.setpoint(q, thrust, mask, rates)
        assert h.vehicle.stats.rejected[key] == before + 1
        h.step(0.3)
        assert ap.mode == OFFBOARD
        assert tilt_deg(ap.state.rotation) < 1.0, key
        assert ap.thrust_command == pytest.approx(HOVER), key
        h.setpoint(LEVEL, HOVER)  # keep the offboard signal alive
        valid += 1
        assert ap.setpoints_received == valid
    # A tilted setpoint with a broken CRC is not flown either.
    tilted = bytearray(h.mav.set_attitude_target_encode(
        0, 1, 1, RATES_IGNORED, list(roll_quaternion(30.0)), 0, 0, 0, HOVER).pack(h.mav))
    tilted[-2] ^= 0x5A
    h.deliver(bytes(tilted))
    assert h.vehicle.stats.rejected["bad_crc"] == 1
    h.step(0.3)
    assert tilt_deg(ap.state.rotation) < 1.0
    assert ap.setpoints_received == valid
    # A valid tilted setpoint is flown.
    h.setpoint(roll_quaternion(20.0), HOVER / math.cos(math.radians(20.0)))
    h.step(1.0)
    assert tilt_deg(ap.state.rotation) == pytest.approx(20.0, abs=1.0)


def test_type_mask_keeps_the_ignored_part(harness) -> None:
    h = harness()
    ap = h.autopilot
    h.hover(altitude=4.0)
    h.setpoint(LEVEL, 0.7)
    h.command_long(mavlink.MAV_CMD_DO_SET_MODE, CUSTOM, MainMode.OFFBOARD)
    single_ack(h, mavlink.MAV_CMD_DO_SET_MODE, CommandResult.ACCEPTED)
    h.step(0.02)
    assert ap.thrust_command == pytest.approx(0.7)

    # THROTTLE_IGNORE: new attitude, previous thrust (the 0.2 sent is ignored).
    h.setpoint(roll_quaternion(5.0), 0.2, RATES_IGNORED | THROTTLE_IGNORE)
    h.step(0.02)
    target, thrust_newton = ap.vehicle.attitude_target
    np.testing.assert_allclose(target, Rotation.from_euler("x", 5.0, degrees=True).as_matrix(), atol=1e-6)
    assert ap.thrust_command == pytest.approx(0.7)
    assert thrust_newton == pytest.approx(0.7 * PARAMS.max_total_thrust)

    # ATTITUDE_IGNORE: new thrust, previous attitude (the 25 deg roll sent is ignored).
    h.setpoint(roll_quaternion(25.0), 0.6, RATES_IGNORED | ATTITUDE_IGNORE)
    h.step(0.02)
    target, thrust_newton = ap.vehicle.attitude_target
    np.testing.assert_allclose(target, Rotation.from_euler("x", 5.0, degrees=True).as_matrix(), atol=1e-6)
    assert ap.thrust_command == pytest.approx(0.6)
    assert sum(h.vehicle.stats.rejected.values()) == 0
    assert ap.setpoints_received >= 3


def test_an_ignored_body_rate_may_hold_any_value(harness) -> None:
    """Only the rates type_mask asks for must be zero; an ignored one is not looked at."""
    h = harness()
    roll_rate_ignored = 1
    h.setpoint(LEVEL, 0.5, roll_rate_ignored | 2 | 4, (0.7, 0.0, 0.0))
    h.setpoint(LEVEL, 0.5, roll_rate_ignored, (0.7, 0.0, 0.0))  # pitch/yaw asked for, but zero
    assert h.autopilot.setpoints_received == 2
    h.setpoint(LEVEL, 0.5, roll_rate_ignored, (0.7, 0.3, 0.0))  # pitch rate asked for and nonzero
    assert h.vehicle.stats.rejected["setpoint_rates_unsupported"] == 1
    assert h.autopilot.setpoints_received == 2


# ---- SET_POSITION_TARGET_LOCAL_NED (MAVSDK's position/velocity offboard)
IGNORE_VEL_ACC_YAWRATE = 0x38 | 0x1C0 | 0x800
IGNORE_POS_ACC_YAWRATE = 0x7 | 0x1C0 | 0x800


def _position_target(h: Harness, mask: int, pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0),
                     yaw=0.0, yaw_rate=0.0, frame=mavlink.MAV_FRAME_LOCAL_NED) -> None:
    h.send(h.mav.set_position_target_local_ned_encode(0, 1, 1, frame, mask, *pos, *vel, *acc, yaw, yaw_rate))


def test_position_setpoint_in_offboard_flies_to_the_point_with_its_yaw(harness) -> None:
    h = harness()
    h.hover(3.0)
    _position_target(h, IGNORE_VEL_ACC_YAWRATE, pos=(3.0, -2.0, -5.0), yaw=math.pi / 2)
    assert h.autopilot.set_mode(OFFBOARD) == CommandResult.ACCEPTED
    for _ in range(12 * 20):  # 12 s at 20 Hz
        _position_target(h, IGNORE_VEL_ACC_YAWRATE, pos=(3.0, -2.0, -5.0), yaw=math.pi / 2)
        h.fly_silently(0.05)
    state = h.autopilot.state
    assert np.linalg.norm(state.position - [3.0, -2.0, -5.0]) < 0.1
    assert math.atan2(state.rotation[1, 0], state.rotation[0, 0]) == pytest.approx(math.pi / 2, abs=0.05)
    assert h.autopilot.mode == OFFBOARD and sum(h.vehicle.stats.rejected.values()) == 0


def test_body_ned_velocity_setpoint_is_rotated_by_the_heading(harness) -> None:
    h = harness(yaw=math.pi / 2)  # facing east
    h.hover(3.0)
    _position_target(h, IGNORE_POS_ACC_YAWRATE | 0x400, vel=(1.0, 0.0, 0.0), frame=mavlink.MAV_FRAME_BODY_NED)
    assert h.autopilot.set_mode(OFFBOARD) == CommandResult.ACCEPTED
    for _ in range(4 * 20):
        _position_target(h, IGNORE_POS_ACC_YAWRATE | 0x400, vel=(1.0, 0.0, 0.0), frame=mavlink.MAV_FRAME_BODY_NED)
        h.fly_silently(0.05)
    velocity = h.autopilot.state.velocity
    assert velocity[1] == pytest.approx(1.0, abs=0.1)  # forward = east
    assert abs(velocity[0]) < 0.1


@pytest.mark.parametrize(
    "mask, frame, kwargs, key",
    [
        (0x1 | 0x38 | 0x1C0 | 0x800, mavlink.MAV_FRAME_LOCAL_NED, {}, "setpoint_type_mask_unsupported"),  # y, z only
        (IGNORE_VEL_ACC_YAWRATE | 0x200, mavlink.MAV_FRAME_LOCAL_NED, {}, "setpoint_type_mask_unsupported"),  # force
        (0x38 | 0x1C0, mavlink.MAV_FRAME_LOCAL_NED, {"yaw_rate": 0.5}, "setpoint_type_mask_unsupported"),
        (IGNORE_VEL_ACC_YAWRATE, mavlink.MAV_FRAME_GLOBAL_INT, {}, "setpoint_frame_unsupported"),
        (IGNORE_VEL_ACC_YAWRATE, mavlink.MAV_FRAME_BODY_NED, {}, "setpoint_frame_unsupported"),  # position in body
        (IGNORE_VEL_ACC_YAWRATE, mavlink.MAV_FRAME_LOCAL_NED, {"pos": (math.nan, 0.0, -3.0)}, "setpoint_not_finite"),
        (0x7 | 0x38 | 0x1C0 | 0x800, mavlink.MAV_FRAME_LOCAL_NED, {}, "setpoint_empty"),
    ],
    ids=["partial-axes", "force", "yaw-rate", "global-frame", "body-position", "nan", "empty"],
)
def test_unusable_position_targets_are_rejected_by_reason(harness, mask, frame, kwargs, key) -> None:
    h = harness()
    _position_target(h, mask, frame=frame, **kwargs)
    assert h.vehicle.stats.rejected[key] == 1
    assert h.autopilot.setpoints_received == 0


def test_thrust_body_set_is_refused_because_pymavlink_has_no_thrust_body_field(harness) -> None:
    h = harness()
    assert "thrust_body" not in mavlink.MAVLink_set_attitude_target_message.fieldnames
    h.setpoint(type_mask=RATES_IGNORED | 32)  # ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET
    assert h.vehicle.stats.rejected == {"setpoint_thrust_body_unsupported": 1}
    assert h.autopilot.setpoints_received == 0
    valid_setpoint_still_works(h)


# --------------------------------------------------------------------------- partners, counting, logs


def test_the_gcs_stream_stays_with_the_configured_gcs_while_an_intruder_talks(harness) -> None:
    h = harness()
    intruder = Client()
    try:
        for _ in range(5):
            data = h.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(h.mav)
            h.vehicle.handle_datagram(h.vehicle.links[1], data, intruder.address)
            h.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, link=1)
            h.vehicle.handle_datagram(h.vehicle.links[1], h.mav.param_request_list_encode(1, 1).pack(h.mav),
                                      intruder.address)
            h.step(0.5)
        intruder.drain(h.autopilot.time, None)
        assert intruder.received == []
        kinds = {m.get_type() for m in h.gcs.take()}
        assert {"HEARTBEAT", "ATTITUDE", "PARAM_VALUE", "AUTOPILOT_VERSION", "COMMAND_ACK"} <= kinds
        assert h.vehicle.links[1].partner == h.gcs.address
        assert h.vehicle.links[1].from_strangers == 10
    finally:
        intruder.close()


def test_a_datagram_with_several_bad_frames_counts_once_under_its_first_reason(harness) -> None:
    h = harness()
    good = h.mav.set_attitude_target_encode(0, 1, 1, RATES_IGNORED, list(LEVEL), 0, 0, 0, 0.5).pack(h.mav)
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    not_finite = h.mav.set_attitude_target_encode(0, 1, 1, RATES_IGNORED, [math.nan, 0, 0, 0], 0, 0, 0, 0.5).pack(h.mav)
    h.deliver(bytes(bad_crc) + b"\x00\x01garbage" + not_finite + good[:9])
    assert h.vehicle.stats.rejected == {"bad_crc": 1}
    assert h.vehicle.stats.reject_events["bad_crc"] == 1
    assert h.vehicle.stats.reject_events["setpoint_not_finite"] == 1
    assert h.vehicle.stats.reject_events["truncated_frame"] == 1
    assert sum(h.vehicle.stats.reject_events.values()) >= 4
    valid_setpoint_still_works(h)


def _garbage(rng: np.random.Generator) -> bytes:
    """A datagram that cannot be a MAVLink frame: it does not start with a frame marker."""
    data = bytearray(rng.bytes(int(rng.integers(1, 200))))
    if data[0] in (0xFD, 0xFE):
        data[0] = 0x00
    return bytes(data)


def test_a_flood_counts_one_reject_per_datagram_and_the_events_log_stays_bounded(harness, tmp_path) -> None:
    from sitl_plant.sitl import RunLog

    h = harness()
    log = RunLog(tmp_path, rate_hz=50.0)
    h.vehicle.on_event = log.event
    rng = np.random.default_rng(14)
    sent = 5000
    for _ in range(sent):
        h.vehicle.handle_datagram(h.vehicle.links[1], _garbage(rng), ("127.0.0.1", 9))
    h.step(1.0)
    log.tick(h.autopilot.time)
    for _ in range(sent):
        h.vehicle.handle_datagram(h.vehicle.links[0], _garbage(rng), ("127.0.0.1", 9))
    log.close()
    assert sum(h.vehicle.stats.rejected.values()) == 2 * sent
    lines = (tmp_path / "events.jsonl").read_text().splitlines()
    rejects = [line for line in lines if '"rejected"' in line]
    suppressed = [line for line in lines if '"suppressed"' in line]
    reasons = set(h.vehicle.stats.reject_events)
    # Per reason: 20 lines verbatim, then one count line per simulated second (two seconds here, plus the close).
    assert len(rejects) <= 20 * len(reasons)
    assert len(lines) <= (20 + 3) * len(reasons) < 2 * sent / 50
    # Every reject event is either written verbatim or counted in a suppressed line.
    import json

    counted = sum(json.loads(line)["count"] for line in suppressed if json.loads(line)["key"].startswith("rejected:"))
    assert len(rejects) + counted == sum(h.vehicle.stats.reject_events.values())


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=300), link=st.sampled_from([0, 1]))
def test_any_datagram_counts_at_most_once_and_never_raises(data: bytes, link: int) -> None:
    h = _SHARED.get("h")
    if h is None:
        h = _SHARED["h"] = Harness()
    before = sum(h.vehicle.stats.rejected.values())
    events_before = sum(h.vehicle.stats.reject_events.values())
    h.vehicle.handle_datagram(h.vehicle.links[link], data, ("127.0.0.1", 9))
    counted = sum(h.vehicle.stats.rejected.values()) - before
    events = sum(h.vehicle.stats.reject_events.values()) - events_before
    assert counted == (1 if events else 0)
    if data and data[0] not in (0xFD, 0xFE):
        assert counted == 1  # garbage from its first byte is always a reject


_SHARED: dict = {}


@pytest.fixture(scope="module", autouse=True)
def _close_shared():
    yield
    h = _SHARED.pop("h", None)
    if h is not None:
        h.close()


def test_a_flood_of_peer_status_texts_is_passed_on_at_a_bounded_rate_and_the_rest_counted(harness) -> None:
    """A peer's STATUSTEXTs go to the other links at most 5 per simulated second (a burst of 5): 100 at one
    instant give 5 relayed and 95 counted; one second later 5 more may pass."""
    h = harness()
    h.step(0.01)
    h.gcs.take()
    for k in range(100):
        h.send(h.mav.statustext_encode(mavlink.MAV_SEVERITY_INFO, f"flood {k}".encode()))
    relayed = [t.text for t in h.gcs.take("STATUSTEXT") if t.text.startswith("flood")]
    assert relayed == [f"flood {k}" for k in range(5)]
    assert h.vehicle.stats.statustext_not_relayed["companion"] == 95
    h.step(1.0)
    for k in range(100, 110):
        h.send(h.mav.statustext_encode(mavlink.MAV_SEVERITY_INFO, f"flood {k}".encode()))
    relayed = [t.text for t in h.gcs.take("STATUSTEXT") if t.text.startswith("flood")]
    assert relayed == [f"flood {k}" for k in range(100, 105)]
    assert h.vehicle.stats.statustext_not_relayed["companion"] == 100
