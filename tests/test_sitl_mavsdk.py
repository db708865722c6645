"""The SITL plant as a MAVLink vehicle, flown by unmodified MAVSDK through companion.adapters.mavsdk_vehicle.

Each test starts `sitl-plant` as a child process on free loopback ports, talks to it
over real UDP, and always stops it. A pymavlink client on the ground-station port
watches at the same time.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import time

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from companion.core.attitude import attitude_setpoint  # noqa: E402
from companion.adapters.mavsdk_vehicle import MavsdkVehicle  # noqa: E402
from mavsdk.plugins.offboard import PositionNedYaw  # noqa: E402
from studies.processes import start_plant  # noqa: E402
from sitl_plant.vehicle.params import table1_params  # noqa: E402
from sitl_plant.vehicle.px4_modes import OFFBOARD, POSITION, decode_custom_mode  # noqa: E402

SPEED = 2.0  # simulated seconds per wall second in these tests
DRAG_PER_MASS = table1_params().drag_coefficient / table1_params().mass  # 1/s, Table I C_d / m (horizontal body drag at small tilt)


@pytest.fixture
def plant(tmp_path):
    child, companion_port, gcs_port = start_plant(tmp_path, speed_factor=SPEED)
    try:
        yield child, companion_port, gcs_port, tmp_path
    finally:
        code = child.stop()
        assert code == 0, child.output()


class GroundStation:
    """pymavlink listening on the ground-station port, collecting what it hears."""

    def __init__(self, port: int) -> None:
        self.connection = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
        self.messages: dict[str, list] = {}

    def pump(self, duration: float) -> None:
        end = time.monotonic() + duration
        while time.monotonic() < end:
            msg = self.connection.recv_match(blocking=True, timeout=0.05)
            if msg is not None:
                self.messages.setdefault(msg.get_type(), []).append(msg)

    def close(self) -> None:
        self.connection.close()


async def _pump_in_background(gcs: GroundStation, stop: asyncio.Event) -> None:
    loop = asyncio.get_running_loop()
    while not stop.is_set():
        await loop.run_in_executor(None, gcs.pump, 0.1)


def _fit_acceleration(samples) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares slope of NED velocity over time, and the mean velocity."""
    t = np.array([s.state.time for s in samples])
    v = np.array([s.state.velocity for s in samples])
    slope = np.polyfit(t - t[0], v, 1)[0]
    return slope, v.mean(axis=0)


def test_mavsdk_flies_the_plant_and_a_ground_station_watches(plant):
    child, companion_port, gcs_port, log_dir = plant
    gcs = GroundStation(gcs_port)

    async def fly():
        stop = asyncio.Event()
        watcher = asyncio.create_task(_pump_in_background(gcs, stop))
        try:
            async with MavsdkVehicle(f"udpin://127.0.0.1:{companion_port}", connect_timeout=15) as vehicle:
                limits = await vehicle.vehicle_limits(table1_params().mass, table1_params().gravity)
                first = await vehicle.next_sample()
                await vehicle.wait_for(lambda s: s.state.time > 1.2, 10, "arming readiness")
                await vehicle.arm()
                hovering = await vehicle.takeoff(4.0, timeout=30, settle=1.0)

                # Offboard at hover: the pipeline's own attitude mapping, zero acceleration.
                level = attitude_setpoint(0.0, np.zeros(3), np.array([1.0, 0.0, 0.0]), limits)
                await vehicle.start_offboard(level)
                entered = await vehicle.wait_for(lambda s: vehicle.flight_mode is not None and vehicle.flight_mode.name == "OFFBOARD", 10, "offboard")
                # Command 1.5 m/s^2 north through eq. (21)-(22): a tilt the autopilot must fly.
                command = np.array([1.5, 0.0, 0.0])
                tilted = attitude_setpoint(0.0, command, np.array([1.0, 0.0, 0.0]), limits)
                await vehicle.send_setpoint(tilted)
                start = (await vehicle.next_sample()).state.time
                samples = []
                while True:
                    sample = await vehicle.next_sample()
                    if sample.state.time > start + 0.8:  # attitude transient over
                        samples.append(sample)
                    if sample.state.time > start + 3.0:
                        break
                # Plain MAVSDK position offboard (what its examples use) works too: fly to a point.
                await vehicle.offboard.set_position_ned(PositionNedYaw(2.0, 3.0, -4.0, 90.0))
                arrived = await vehicle.wait_for(
                    lambda s: np.linalg.norm(s.state.position - [2.0, 3.0, -4.0]) < 0.3 and np.linalg.norm(s.state.velocity) < 0.3,
                    30, "position setpoint reached")
                await vehicle.send_setpoint(level)
                await vehicle.stop_offboard()
                held = await vehicle.wait_for(lambda s: vehicle.flight_mode is not None and vehicle.flight_mode.name == "HOLD", 10, "hold")
                return limits, first, hovering, entered, command, tilted, samples, held, arrived
        finally:
            stop.set()
            await watcher

    try:
        limits, first, hovering, entered, command, tilted, samples, held, arrived = asyncio.run(fly())
    finally:
        gcs.close()

    # Hover thrust and tilt limit came from the autopilot's parameters, not from our config.
    assert limits.hover_thrust_normalized == pytest.approx(1.0 / 1.5, rel=1e-6)
    assert limits.max_tilt == pytest.approx(math.radians(35.0), rel=1e-6)
    # Own state is stamped with simulated time; the vehicle started on the ground at home.
    assert 0.0 <= first.state.time < 5.0
    assert abs(first.state.position[2]) < 0.5
    assert hovering.state.position[2] < -3.7
    # The commanded tilt: ~8.7 deg nose down, thrust raised so the vertical balances.
    tilt = math.degrees(math.acos(tilted.rotation[2, 2]))
    assert tilt == pytest.approx(math.degrees(math.atan(1.5 / 9.81)), abs=0.1)
    measured, mean_velocity = _fit_acceleration(samples)
    expected_north = command[0] - DRAG_PER_MASS * mean_velocity[0]
    assert measured[0] == pytest.approx(expected_north, rel=0.12), (measured, expected_north)
    assert abs(measured[1]) < 0.15 and abs(measured[2]) < 0.3, measured
    heading = math.degrees(math.atan2(arrived.rotation[1, 0], arrived.rotation[0, 0]))
    assert heading == pytest.approx(90.0, abs=3.0)  # the yaw of the position setpoint

    # The ground station saw heartbeats with PX4's mode encoding, and telemetry, meanwhile.
    heartbeats = gcs.messages.get("HEARTBEAT", [])
    assert len(heartbeats) >= 5
    assert all(hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4 and hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR for hb in heartbeats)
    modes = {decode_custom_mode(hb.custom_mode) for hb in heartbeats if hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED}
    assert (OFFBOARD.main, OFFBOARD.sub) in modes
    for kind in ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "ATTITUDE_QUATERNION", "EXTENDED_SYS_STATE", "SYS_STATUS", "HOME_POSITION"):
        assert gcs.messages.get(kind), f"ground station never got {kind}"
    top = min(m.z for m in gcs.messages["LOCAL_POSITION_NED"])
    assert top < -3.5  # it saw the climb too
    home = gcs.messages["HOME_POSITION"][-1]
    assert home.latitude == pytest.approx(47.397742e7, abs=2) and home.longitude == pytest.approx(8.545594e7, abs=2)


def test_offboard_loss_failsafe_holds_and_reports(plant):
    child, companion_port, gcs_port, log_dir = plant
    gcs = GroundStation(gcs_port)

    async def fly_then_vanish():
        async with MavsdkVehicle(f"udpin://127.0.0.1:{companion_port}", connect_timeout=15) as vehicle:
            limits = await vehicle.vehicle_limits(table1_params().mass, table1_params().gravity)
            await vehicle.wait_for(lambda s: s.state.time > 1.2, 10, "arming readiness")
            await vehicle.arm()
            await vehicle.takeoff(3.0, timeout=30, settle=1.5)
            level = attitude_setpoint(0.0, np.zeros(3), np.array([1.0, 0.0, 0.0]), limits)
            await vehicle.start_offboard(level)
            await vehicle.wait_for(lambda s: vehicle.flight_mode is not None and vehicle.flight_mode.name == "OFFBOARD", 10, "offboard")
            # Drift north at 1 m/s^2 for a while, so "holding" is a real change of behaviour.
            await vehicle.send_setpoint(attitude_setpoint(0.0, np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), limits))
            last = await vehicle.wait_for(lambda s: s.state.velocity[0] > 1.5, 10, "moving north")
            return last
        # Leaving the context destroys MAVSDK: the setpoint stream stops, as if the companion crashed.

    try:
        last = asyncio.run(fly_then_vanish())
        gcs.pump(6.0 / SPEED)  # 6 simulated seconds
    finally:
        gcs.close()

    texts = [m.text for m in gcs.messages.get("STATUSTEXT", [])]
    assert any("offboard signal lost" in text for text in texts), texts
    armed_modes = [decode_custom_mode(hb.custom_mode) for hb in gcs.messages["HEARTBEAT"]]
    assert armed_modes[-1] == (POSITION.main, POSITION.sub)  # COM_OBL_RC_ACT = 0: Position mode, holding
    positions = gcs.messages["LOCAL_POSITION_NED"]
    final = positions[-8:]
    speeds = [math.hypot(m.vx, m.vy) for m in final]
    assert max(speeds) < 0.4, speeds  # stopped and holding (noise sigma 0.05 m/s)
    assert all(-4.0 < m.z < -2.0 for m in final), [m.z for m in positions[::10]]  # at altitude, not falling
    # The mode change came within the loss timeout (1 s) plus the 1 Hz heartbeat after it.
    events = [json.loads(line) for line in (log_dir / "events.jsonl").read_text().splitlines()]
    failsafe = [e for e in events if e["kind"] == "statustext" and "offboard signal lost" in e["detail"]]
    assert len(failsafe) == 1
    # It fired COM_OF_LOSS_T (1 s) after the last setpoint the plant received: detected within one 4 ms
    # tick and reported at the end of the tick that switched modes.
    record = [e for e in events if e["kind"] == "failsafe"]
    assert len(record) == 1
    last_setpoint = record[0]["last_setpoint_time"]
    assert last_setpoint >= last.state.time - 0.05 * SPEED  # the stream ran until the companion vanished
    assert 1.0 <= failsafe[0]["time"] - last_setpoint <= 1.0 + 0.0081, (failsafe[0], last_setpoint)
