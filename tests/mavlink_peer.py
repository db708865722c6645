"""A pymavlink peer for the tests that talk to a running sitl-plant over UDP (not a test module).

It listens on the plant's companion (or ground-station) port on 127.0.0.1 and keeps the
vehicle's latest state as the plant reports it: simulated time from ODOMETRY, NED z from
LOCAL_POSITION_NED, PX4 mode and armed flag from HEARTBEAT (every heartbeat kept with its
time), and every COMMAND_ACK.
"""

from __future__ import annotations

import math
import os
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from sitl_plant.vehicle.px4_modes import decode_custom_mode  # noqa: E402

mavlink = mavutil.mavlink


class MavlinkPeer:
    """A client on `port` (127.0.0.1) with system 245, component 190 (an onboard computer's ids).

    signing_key: 32 bytes to sign what it sends and to accept only frames signed with it
    (pymavlink's setup_signing, as MAVProxy's `signing key`); None: unsigned."""

    def __init__(self, port: int, signing_key: bytes | None = None) -> None:
        self.connection = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=245, source_component=190)
        if signing_key is not None:
            self.connection.setup_signing(signing_key, sign_outgoing=True)
        self.mav = self.connection.mav
        self.time = 0.0  # s, simulated, of the latest ODOMETRY
        self.z = 0.0  # m, NED (negative up)
        self.mode: tuple[int, int] | None = None  # PX4 (main, sub) mode
        self.armed = False
        self.heartbeats: list = []  # (simulated time, HEARTBEAT)
        self.acks: list = []

    def pump(self, duration: float) -> None:
        """Read what arrives for `duration` seconds of wall time."""
        end = time.monotonic() + duration
        while time.monotonic() < end:
            msg = self.connection.recv_match(blocking=True, timeout=0.02)
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "ODOMETRY":
                self.time = msg.time_usec * 1e-6
            elif kind == "LOCAL_POSITION_NED":
                self.z = msg.z
            elif kind == "HEARTBEAT":
                self.mode = decode_custom_mode(msg.custom_mode)
                self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                self.heartbeats.append((self.time, msg))
            elif kind == "COMMAND_ACK":
                self.acks.append(msg)

    def until(self, condition, timeout: float, what: str) -> None:
        """Pump until condition() holds; AssertionError naming `what` after `timeout` s of wall time."""
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise AssertionError(f"timed out waiting for {what} (t={self.time:.2f}, z={self.z:.2f}, mode={self.mode})")
            self.pump(0.05)

    def command(self, command: int, *params: float) -> int:
        """Send COMMAND_LONG to the vehicle (1, 1) and return the MAV_RESULT of its ack."""
        params = list(params) + [math.nan] * (7 - len(params))
        before = len(self.acks)
        self.mav.command_long_send(1, 1, command, 0, *params)
        self.until(lambda: any(a.command == command for a in self.acks[before:]), 5.0, f"ack of {command}")
        return next(a.result for a in self.acks[before:] if a.command == command)

    def close(self) -> None:
        self.connection.close()
