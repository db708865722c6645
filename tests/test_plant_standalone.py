"""sitl-plant stands alone: it flies with the companion and the studies absent from its interpreter.

The plant runs as a child process whose interpreter refuses to import `companion` and
`studies` (a meta-path finder installed before anything else raises ImportError for
them and their submodules). A pymavlink client on free loopback ports arms it, takes
off, holds and lands; the child reports that it never had either package loaded.
"""

from __future__ import annotations

import os
import sys

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from sitl_plant.vehicle.px4_modes import HOLD, LAND, TAKEOFF  # noqa: E402
from studies.processes import ChildProcess, free_port  # noqa: E402
from mavlink_peer import MavlinkPeer  # noqa: E402

mavlink = mavutil.mavlink
SPEED = 4.0  # simulated seconds per wall second
BLOCKED = ("companion", "studies")

#: Run as `python -c WRAPPER <sitl-plant arguments>`.
WRAPPER = f"""
import importlib.abc, runpy, sys

BLOCKED = {BLOCKED!r}

class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{{name}} is blocked in this interpreter", name=name)
        return None

sys.meta_path.insert(0, Blocker())
for name in BLOCKED:
    try:
        __import__(name)
    except ImportError:
        print(f"standalone: {{name}} cannot be imported", flush=True)
    else:
        raise SystemExit(f"{{name}} was importable")
try:
    runpy.run_module("sitl_plant.sitl", run_name="__main__", alter_sys=True)
finally:
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    print(f"standalone: loaded from the blocked packages: {{loaded or 'none'}}", flush=True)
"""


@pytest.fixture
def standalone_plant(tmp_path):
    companion_port, gcs_port = free_port(), free_port()
    command = [sys.executable, "-c", WRAPPER, "--quiet", "--speed-factor", str(SPEED), "--companion-port",
               str(companion_port), "--gcs-port", str(gcs_port), "--log-dir", str(tmp_path)]
    child = ChildProcess(command, tmp_path / "plant.out", ready="sitl-plant ready")
    try:
        child.start(timeout=30.0)
        yield child, companion_port
    finally:
        child.stop()


def test_sitl_plant_flies_takeoff_hold_land_without_the_companion_package(standalone_plant):
    child, port = standalone_plant
    client = MavlinkPeer(port)
    try:
        client.until(lambda: client.time > 1.2, 15.0, "arming readiness")
        assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0) == mavlink.MAV_RESULT_ACCEPTED
        assert client.command(mavlink.MAV_CMD_NAV_TAKEOFF) == mavlink.MAV_RESULT_ACCEPTED  # MIS_TAKEOFF_ALT, 2.5 m
        client.until(lambda: client.mode == (TAKEOFF.main, TAKEOFF.sub), 5.0, "Takeoff mode")
        client.until(lambda: client.mode == (HOLD.main, HOLD.sub), 30.0 / SPEED + 10.0, "takeoff complete")
        held_from = client.time
        heights = []
        while client.time < held_from + 3.0:
            client.pump(0.05)
            heights.append(client.z)
        assert client.mode == (HOLD.main, HOLD.sub) and client.armed
        assert all(-2.5 - 0.5 < z < -2.5 + 0.5 for z in heights), heights  # telemetry noise sigma 0.1 m
        assert client.command(mavlink.MAV_CMD_NAV_LAND) == mavlink.MAV_RESULT_ACCEPTED
        client.until(lambda: client.mode == (LAND.main, LAND.sub), 5.0, "Land mode")
        client.until(lambda: not client.armed, 60.0 / SPEED + 10.0, "landed and disarmed")
    finally:
        client.close()
        code = child.stop()
    output = child.output()
    assert code == 0, output
    assert "standalone: companion cannot be imported" in output
    assert "standalone: studies cannot be imported" in output
    assert "standalone: loaded from the blocked packages: none" in output
    assert "sitl-plant stopped" in output
