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


# --------------------------------------------------------------------------- signing, partners, command line

KEY = bytes(range(200, 232))


def test_with_signing_required_a_signed_ground_station_flies_and_an_unsigned_intruder_is_refused(tmp_path):
    """The standalone plant with MAV_SIGN_CFG=1 and a key file, a pymavlink ground station that signs (and
    verifies the plant's signed stream with the key), and an unsigned intruder on the same port."""
    import json

    companion_port, gcs_port = free_port(), free_port()
    key_file = tmp_path / "signing.key"
    key_file.write_text(KEY.hex() + "\n")
    command = [sys.executable, "-c", WRAPPER, "--quiet", "--speed-factor", str(SPEED), "--companion-port",
               str(companion_port), "--gcs-port", str(gcs_port), "--log-dir", str(tmp_path / "plant"),
               "--mav-sign-cfg", "1", "--signing-key", str(key_file)]
    child = ChildProcess(command, tmp_path / "plant.out", ready="sitl-plant ready")
    gcs = intruder = None
    try:
        child.start(timeout=30.0)
        gcs = MavlinkPeer(gcs_port, signing_key=KEY)  # signs, and takes only frames signed with KEY
        gcs.until(lambda: len(gcs.heartbeats) >= 3, 20.0, "signed heartbeats")  # 3 s simulated: ready to arm
        assert gcs.connection.mav.signing.goodsig_count >= 3
        (plant_address,) = gcs.connection.clients  # where the plant's ground-station stream comes from
        intruder = mavutil.mavlink_connection(f"udpout:{plant_address[0]}:{plant_address[1]}", source_system=255)
        for _ in range(3):
            intruder.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            intruder.mav.command_long_send(1, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 500.0)
        # The signed request below is answered after the intruder's datagrams were read (one socket, in order).
        assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == \
            mavlink.MAV_RESULT_ACCEPTED
        seen = len(gcs.heartbeats)
        gcs.until(lambda: len(gcs.heartbeats) > seen, 10.0, "a heartbeat after the intruder")
        assert not gcs.armed
        assert [a.command for a in gcs.acks] == [mavlink.MAV_CMD_REQUEST_MESSAGE]
        assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0) == mavlink.MAV_RESULT_ACCEPTED
        gcs.until(lambda: gcs.armed, 10.0, "armed by the signed ground station")
    finally:
        for peer in (gcs, intruder):
            if peer is not None:
                peer.close()
        code = child.stop()
    output = child.output()
    assert code == 0, output
    assert f"ground station (--gcs-port) 127.0.0.1:{gcs_port}; MAVLink signing: MAV_SIGN_CFG=1, key from --signing-key" \
        in output
    assert KEY.hex() not in output
    stats = json.loads((tmp_path / "plant" / "stats.json").read_text())
    assert stats["mavlink"]["rejected"]["signing_unsigned"] == 6
    assert stats["links"]["gcs"]["from_strangers"] == 6
    assert stats["links"]["gcs"]["datagrams"] == 6 + 2  # the intruder's and the ground station's two commands
    assert stats["signing"]["key_set"] and stats["signing"]["MAV_SIGN_CFG"] == 1
    assert KEY.hex() not in (tmp_path / "plant" / "events.jsonl").read_text()


BAD_ARGUMENTS = [
    (["--companion-port", "14600", "--gcs-port", "14600"], "both 14600"),
    (["--gcs-port", "14540"], "different ports"),  # the companion's default port
    (["--duration", "-3"], "--duration"),
    (["--duration", "0"], "--duration"),
    (["--speed-factor", "nan"], "--speed-factor"),
    (["--speed-factor", "0"], "--speed-factor"),
    (["--speed-factor", "1000"], "--speed-factor"),
    (["--log-rate", "-1"], "--log-rate"),
    (["--clock-rate", "0"], "--clock-rate"),
    (["--gcs-port", "70000"], "--gcs-port"),
    (["--mav-sign-cfg", "2"], "--mav-sign-cfg"),
    (["--signing-key", "/nonexistent/key"], "--signing-key"),
    (["--mavlink-blackout", "-1", "2"], "--mavlink-blackout"),
]


@pytest.mark.parametrize("arguments, mentions", BAD_ARGUMENTS, ids=[" ".join(a) for a, _ in BAD_ARGUMENTS])
def test_bad_arguments_are_one_line_errors_with_status_2(arguments, mentions, capsys):
    from sitl_plant import sitl

    assert sitl.main(arguments) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("sitl-plant"), err
    assert mentions in err


@pytest.mark.parametrize("content", ["abc", "zz" * 32, "00" * 32, KEY.hex() + "ff"])
def test_a_bad_signing_key_file_is_refused_without_showing_it(content, tmp_path, capsys):
    from sitl_plant import sitl

    path = tmp_path / "key"
    path.write_text(content)
    assert sitl.main(["--signing-key", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--signing-key" in err and content not in err


def test_the_cli_error_has_no_traceback_in_a_real_process(tmp_path):
    import subprocess

    done = subprocess.run([sys.executable, "-m", "sitl_plant.sitl", "--duration", "-3", "--companion-port", "1"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1, done.stderr
