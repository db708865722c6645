"""Malformed MAVLink thrown at a flying sitl-plant over real UDP: it survives, counts, keeps flying.

A pymavlink client plays a (badly behaved) companion on the offboard port: it arms,
takes off, holds offboard with valid level setpoints and mixes every kind of bad
packet into the stream. The vehicle must stay in offboard on its last valid
setpoint, and the plant's stats.json must count each bad packet under its reason.
"""

from __future__ import annotations

import json
import math
import os


os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from studies.processes import start_plant  # noqa: E402
from sitl_plant.vehicle.px4_modes import OFFBOARD, decode_custom_mode  # noqa: E402
from mavlink_peer import MavlinkPeer  # noqa: E402

mavlink = mavutil.mavlink
SPEED = 2.0
HOVER = 1.0 / 1.5
RATES_IGNORED = 7


class Companion(MavlinkPeer):
    """A (badly behaved) companion on the offboard port: valid setpoints and raw bytes."""

    def setpoint(self, q=(1.0, 0.0, 0.0, 0.0), thrust=HOVER, type_mask=RATES_IGNORED, rates=(0.0, 0.0, 0.0)) -> None:
        self.mav.set_attitude_target_send(0, 1, 1, type_mask, q, *rates, thrust)

    def raw(self, data: bytes) -> None:
        self.connection.write(data)

    def close(self) -> None:
        self.connection.close()


def _packed(mav, message) -> bytearray:
    return bytearray(message.pack(mav))


def test_plant_survives_counts_and_keeps_flying_on_malformed_traffic(tmp_path):
    child, companion_port, gcs_port = start_plant(tmp_path, speed_factor=SPEED)
    companion = Companion(companion_port)
    try:
        companion.until(lambda: companion.time > 1.3, 10.0, "arming readiness")
        assert companion.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0) == mavlink.MAV_RESULT_ACCEPTED
        assert companion.command(mavlink.MAV_CMD_NAV_TAKEOFF) == mavlink.MAV_RESULT_ACCEPTED
        companion.until(lambda: companion.z < -2.4, 15.0, "takeoff")
        start = companion.time
        companion.until(lambda: companion.time > start + 1.5, 10.0, "settling in Hold")
        companion.setpoint()
        companion.pump(0.05)
        assert companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1.0, OFFBOARD.main, 0.0) == mavlink.MAV_RESULT_ACCEPTED
        altitude = companion.z

        mav = companion.mav
        bad_crc = _packed(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        bad_crc[-1] ^= 0xFF
        unknown_id = _packed(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        unknown_id[7:10] = (0xEE, 0xEE, 0x00)
        tilt = (math.cos(math.radians(20)), math.sin(math.radians(20)), 0.0, 0.0)
        malformed = [
            ("bad_crc", lambda: companion.raw(bytes(bad_crc))),
            ("unknown_message_id", lambda: companion.raw(bytes(unknown_id))),
            ("setpoint_not_finite", lambda: companion.setpoint(q=(math.nan, 0.0, 0.0, 0.0))),
            ("setpoint_not_finite", lambda: companion.setpoint(q=tilt, thrust=math.inf)),
            ("setpoint_quaternion_zero", lambda: companion.setpoint(q=(0.0, 0.0, 0.0, 0.0))),
            ("setpoint_thrust_out_of_range", lambda: companion.setpoint(q=tilt, thrust=1.5)),
            ("setpoint_thrust_out_of_range", lambda: companion.setpoint(q=tilt, thrust=-0.1)),
        ]
        # Ten rounds: a valid level setpoint, then each malformed packet, then a pause.
        for _ in range(10):
            for _, send in malformed:
                companion.setpoint()
                send()
                companion.pump(0.02)
            companion.pump(0.05)
        end = companion.time
        companion.until(lambda: companion.time > end + 0.5, 5.0, "a last look")
        in_flight = [hb for t, hb in companion.heartbeats if t > start + 2.0]
        last_z = companion.z
    finally:
        companion.close()
        code = child.stop()
    assert code == 0, child.output()

    # Kept flying in offboard on the last valid (level, hover) setpoint, not on any bad one.
    assert in_flight and all(decode_custom_mode(hb.custom_mode) == (OFFBOARD.main, OFFBOARD.sub) for hb in in_flight)
    assert all(hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED for hb in in_flight)
    assert abs(last_z - altitude) < 1.0, (altitude, last_z)
    truth = (tmp_path / "vehicle.csv").read_text().splitlines()
    header = truth[0].split(",")
    rows = [dict(zip(header, line.split(","))) for line in truth[1:]]
    offboard_rows = [r for r in rows if r["mode"] == "Offboard"]
    assert offboard_rows
    # Level: the 20 deg tilt and the NaN/zero quaternions never reached the attitude controller.
    worst_tilt = max(math.degrees(2 * math.asin(min(1.0, math.hypot(float(r["qx"]), float(r["qy"]))))) for r in offboard_rows)
    assert worst_tilt < 3.0, worst_tilt

    stats = json.loads((tmp_path / "stats.json").read_text())
    rejected = stats["mavlink"]["rejected"]
    expected: dict[str, int] = {}
    for key, _ in malformed:
        expected[key] = expected.get(key, 0) + 10
    for key, count in expected.items():
        assert rejected.get(key) == count, (key, rejected)
    assert stats["mavlink"]["received"]["SET_ATTITUDE_TARGET"] >= 10 * len(malformed)
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert sum(1 for e in events if e["kind"] == "rejected") == sum(expected.values())
