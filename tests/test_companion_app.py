"""The companion application's target link and command handling, driven directly (no vehicle, no sockets)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from interfaces import link_schema as link
from interfaces import geodesy
from companion.app import CompanionApp, Phase
from interfaces.scenario import load_scenario


#: The vehicle time the tests' companion sees (the validator's "now", s): fixes stamped 0.6-3.1 s are fresh.
NOW = 2.6


@pytest.fixture
def app(app):
    """The conftest app with a vehicle clock standing still at NOW (no vehicle is connected)."""
    app.target_link.clock = lambda: NOW
    app._vehicle_time = lambda: NOW
    return app


def _fix(seq: int, stamp: float, position=(60.0, -20.0, -20.0), sender="target-1", frame="ned") -> bytes:
    return link.encode_target_fix(link.TargetFix(sender, seq, stamp, frame, position))


def test_fixes_are_validated_and_counted_by_reason(app):
    app.target_link.on_fix(_fix(0, 1.0), 0)
    app.target_link.on_fix(_fix(1, 1.2, sender="intruder"), 0)
    app.target_link.on_fix(_fix(1, 1.2), 0)
    app.target_link.on_fix(_fix(1, 1.4), 0)  # repeated seq
    app.target_link.on_fix(_fix(2, 1.2), 0)  # stamp not after the last one
    app.target_link.on_fix(b"\xff\xfe not json", 0)
    app.target_link.on_fix(b'{"schema": "bof.target_fix/1"}', 0)
    assert app.target_link.health.received == 7
    assert app.target_link.health.accepted == 2
    assert dict(app.target_link.health.rejected) == {"wrong_sender": 1, "stale_seq": 1, "stale_stamp": 1, "not_utf8": 1, "missing_field": 1}
    records = [json.loads(line) for line in (app.recorder.folder / "zenoh_rx.jsonl").read_text().splitlines()]
    assert [r["verdict"] for r in records] == ["accepted", "rejected", "accepted", "rejected", "rejected", "rejected", "rejected"]
    # Before the companion is ready to follow, fixes only prove the link is up.
    assert not app.target_link.pending


def test_geodetic_fix_becomes_the_ned_position_about_home(app):
    app.sequencer.phase = Phase.READY
    home = app.scenario.sitl.home
    geodetic = geodesy.ned_to_geodetic((60.0, -20.0, -20.0), home)
    app.target_link.on_fix(_fix(0, 2.0, position=geodetic, frame="geodetic"), 123)
    assert len(app.target_link.pending) == 1
    np.testing.assert_allclose(app.target_link.pending[0].position, [60.0, -20.0, -20.0], atol=1e-3)
    assert app.target_link.pending[0].received_ns == 123


def test_a_bearing_is_built_at_the_fix_time_from_own_state_history(app):
    app.sequencer.phase = Phase.READY
    for k in range(11):  # own state at 50 Hz, flying north at 5 m/s
        t = 2.0 + 0.02 * k
        app.history.append(t, np.array([5.0 * (t - 2.0), 0.0, -20.0]), np.array([5.0, 0.0, 0.0]), np.eye(3))
    app.target_link.on_fix(_fix(0, 2.1, position=(60.0, 0.0, -20.0)), 0)
    app.target_link.on_fix(_fix(1, 2.5, position=(60.0, 0.0, -20.0)), 0)  # ahead of the own state: waits
    due = app.target_link.due_bearings(2.2)
    assert len(due) == 1 and len(app.target_link.pending) == 1
    assert due[0][0].seq == 0
    bearings = [bearing for _, bearing in due]
    assert bearings[0].time == pytest.approx(2.1)
    np.testing.assert_allclose(bearings[0].pursuer_position, [0.5, 0.0, -20.0], atol=1e-9)
    assert np.linalg.norm(bearings[0].direction - [1.0, 0.0, 0.0]) < 0.05  # eq. (4) noise, sigma 0.01


def test_abort_command_is_honoured_and_garbage_commands_are_not(app):
    app.on_command(b"abort")
    assert not app.sequencer.abort_requested
    app.on_command(link.encode_command(link.Command("ground-station", 0, 3.0, "abort")))
    assert app.sequencer.abort_requested
    events = [json.loads(line) for line in (app.recorder.folder / "events.jsonl").read_text().splitlines()]
    assert [e["kind"] for e in events] == ["command_rejected", "command"]


def test_every_malformed_kind_is_counted_under_its_reason_and_never_reaches_the_bearings(app):
    from sitl_plant.world.link_faults import CORRUPTION_REASONS, corrupt_payload

    app.sequencer.phase = Phase.READY
    app.target_link.on_fix(_fix(0, 1.0), 0)
    expected = {}
    for seq, (kind, reason) in enumerate(sorted(CORRUPTION_REASONS.items()), start=1):
        broken, _ = corrupt_payload(_fix(seq, 1.0 + 0.2 * seq), kind, np.array([0.3, 0.6]))
        app.target_link.on_fix(broken, 0)
        expected[reason] = expected.get(reason, 0) + 1
    app.target_link.on_fix(_fix(50, 2.4, sender="impostor-1"), 0)
    app.target_link.on_fix(_fix(0, 1.0), 0)  # a duplicate / stale message
    app.target_link.on_fix(_fix(7, 2.5, position=(5000.0, 0.0, -20.0)), 0)  # a wild jump
    expected.update(wrong_sender=1, stale_seq=1, implausible_jump=1)
    assert dict(app.target_link.health.rejected) == expected
    assert app.target_link.health.accepted == 1 and len(app.target_link.pending) == 1  # only the valid fix is queued


@pytest.fixture
def bare_app(tmp_path_factory, scenario_path):
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    application = CompanionApp(scenario, vehicle, tmp_path_factory.mktemp("fuzz"))
    application.target_link.clock = lambda: NOW
    yield application
    application.recorder.close()


def test_fuzzed_payloads_never_crash_the_companion_and_are_all_accounted_for(bare_app):
    from hypothesis import HealthCheck, given, settings, strategies as st

    json_like = st.recursive(st.none() | st.booleans() | st.floats(allow_nan=True) | st.integers() | st.text(max_size=8),
                             lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
                             max_leaves=12)

    @settings(max_examples=300, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.one_of(st.binary(max_size=300), json_like.map(lambda value: json.dumps(value).encode())))
    def run(payload):
        before = bare_app.target_link.health.received
        bare_app.target_link.on_fix(payload, 0)
        assert bare_app.target_link.health.received == before + 1
        assert bare_app.target_link.health.accepted + sum(bare_app.target_link.health.rejected.values()) == bare_app.target_link.health.received

    run()


class _Control:
    """What the state publisher reads from the follower."""

    def __init__(self, last_output) -> None:
        self.last_output = last_output
        self.setpoints_sent = 7


def test_state_payload_carries_the_estimate_summary_at_the_state_rate(app):
    """5 Hz of vehicle time; position_std / velocity_std are the RMS per-axis sigmas sqrt(trace/3) of the
    covariance blocks (here diag(4, 9, 16) m^2 and diag(1, 1, 1) (m/s)^2), range |p^_T - p|."""
    from companion.adapters.mavsdk_vehicle import VehicleSample
    from companion.core.messages import PursuerState, TargetEstimate
    from companion.core.pipeline import TrackMode
    from companion.state_publisher import StatePublisher
    from types import SimpleNamespace

    estimate = TargetEstimate(3.0, np.array([30.0, 40.0, -20.0]), np.array([1.0, 0.0, 0.0]),
                              np.diag([4.0, 9.0, 16.0, 1.0, 1.0, 1.0]))
    output = SimpleNamespace(mode=TrackMode.TRACKING, bearing_age=0.1, observability=None, estimate=estimate)
    sent: list[bytes] = []
    publisher = StatePublisher("pursuer-1", 5.0, sent.append, phase=lambda: "following",
                               health=app.target_link.health, control=_Control(output))
    for k in range(26):  # 0.5 s at 50 Hz
        publisher.publish(VehicleSample(PursuerState(3.0 + 0.02 * k, np.array([0.0, 0.0, -20.0]), np.zeros(3)), np.eye(3)))
    states = [json.loads(payload) for payload in sent]
    assert [s["seq"] for s in states] == [0, 1, 2]
    stamps = np.array([s["stamp"] for s in states])
    assert stamps[0] == 3.0 and np.all((np.diff(stamps) > 0.2 - 1e-9) & (np.diff(stamps) < 0.2 + 0.02 + 1e-9))
    state = states[0]
    assert (state["schema"], state["sender"], state["phase"], state["setpoints_sent"]) == (
        "bof.companion_state/1", "pursuer-1", "following", 7)
    assert state["estimate"]["position_std"] == pytest.approx(np.sqrt(29.0 / 3.0))
    assert state["estimate"]["velocity_std"] == pytest.approx(1.0)
    assert state["estimate"]["range"] == pytest.approx(50.0)
    assert state["track"] == {"mode": "tracking", "bearing_age": 0.1}
    assert set(state) == {"schema", "sender", "seq", "stamp", "phase", "pursuer", "link", "setpoints_sent", "track",
                          "estimate"}


def test_a_fix_stamped_before_the_follow_loops_first_sample_still_gets_its_bearing(app):
    """The own-state history is fed by every odometry sample as it arrives (the adapter's
    sample_observers -> Follower.record_state), not only by the follow loop. A fix stamped while
    the loop was starting (after READY, before its first sample) finds its own state; the
    loop's own call with a sample already recorded changes nothing."""
    from types import SimpleNamespace

    def sample(t):
        state = SimpleNamespace(time=t, position=np.array([5.0 * (t - 2.0), 0.0, -20.0]), velocity=np.array([5.0, 0.0, 0.0]))
        return SimpleNamespace(state=state, rotation=np.eye(3))

    for k in range(11):  # what the adapter hands the observers at 50 Hz while the phase turns READY
        app.follower.record_state(sample(2.0 + 0.02 * k))
    app.sequencer.phase = Phase.READY
    app.target_link.on_fix(_fix(0, 2.15, position=(60.0, 0.0, -20.0)), 0)
    app.follower.record_state(sample(2.2))  # the follow loop's first sample: already in the history
    due = app.target_link.due_bearings(2.2)
    assert [fix.seq for fix, _ in due] == [0] and not app.target_link.health.bearings_dropped
    np.testing.assert_allclose(due[0][1].pursuer_position, [0.75, 0.0, -20.0], atol=1e-9)
    assert app.history.rejected_out_of_order == 0 and len(app.history) == 11


def test_the_tlog_path_binds_nothing_outside_loopback_and_relays_nothing_to_the_autopilot(tmp_path):
    """A pymavlink peer plays the autopilot. The companion's MAVSDK side (the adapter with the tlog writer)
    opens only loopback sockets; MAVLink sent to each of them from another local socket (system 77: an
    arm command and a STATUSTEXT) never reaches the autopilot, while the companion's own heartbeats do
    (the path works) and the autopilot's heartbeats land in the tlog."""
    import asyncio
    import os
    import threading
    import time

    import psutil

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    from companion.adapters.mavsdk_vehicle import MavsdkVehicle
    from companion.adapters.recorder import TlogWriter
    from studies.processes import free_port

    mavlink = mavutil.mavlink
    port = free_port()
    autopilot = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    heard: list[tuple[int, int, str]] = []  # (system, component, message type) of everything the autopilot got
    stop = threading.Event()

    def run_autopilot() -> None:
        next_heartbeat = 0.0
        while not stop.is_set():
            if time.monotonic() >= next_heartbeat:
                next_heartbeat = time.monotonic() + 0.1
                autopilot.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0,
                                             mavlink.MAV_STATE_STANDBY)
            message = autopilot.recv_match(blocking=True, timeout=0.02)
            if message is None or message.get_type() == "BAD_DATA":
                continue
            heard.append((message.get_srcSystem(), message.get_srcComponent(), message.get_type()))
            if message.get_type() == "COMMAND_LONG" and message.get_srcSystem() != 77:
                autopilot.mav.command_ack_send(message.command, mavlink.MAV_RESULT_ACCEPTED)

    own = os.getpid()

    def sockets() -> set[tuple[str, int, int]]:
        return {(c.laddr.ip, c.laddr.port, c.type) for c in psutil.Process(own).net_connections(kind="inet")}

    thread = threading.Thread(target=run_autopilot, daemon=True)
    tlog = TlogWriter(tmp_path / "mavlink.tlog")
    intruder = None
    try:
        thread.start()
        time.sleep(0.3)  # the peer's own socket is bound by its first send
        before = sockets()

        async def fly() -> set:
            vehicle = MavsdkVehicle(f"udpin://127.0.0.1:{port}", connect_timeout=20.0, odometry_rate_hz=None,
                                    on_mavlink=tlog.record)
            await vehicle.connect()
            try:
                opened = sockets() - before
                nonlocal intruder
                for _, target_port, kind in opened:
                    if kind != socket.SOCK_DGRAM:
                        continue
                    intruder = mavutil.mavlink_connection(f"udpout:127.0.0.1:{target_port}", source_system=77,
                                                          source_component=1)
                    for _ in range(5):
                        intruder.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
                        intruder.mav.statustext_send(mavlink.MAV_SEVERITY_CRITICAL, b"intruder")
                        await asyncio.sleep(0.05)
                    intruder.close()
                    intruder = None
                await asyncio.sleep(1.5)  # MAVSDK's own heartbeats are 1 Hz: at least one reaches the peer
                return opened
            finally:
                await vehicle.close()

        import socket

        opened = asyncio.run(fly())
    finally:
        stop.set()
        thread.join(5.0)
        autopilot.close()
        if intruder is not None:
            intruder.close()
        tlog.stop()
    assert opened and all(ip == "127.0.0.1" for ip, _, _ in opened), opened
    assert [entry for entry in heard if entry[0] == 77] == []
    # MAVSDK as a companion computer speaks as system 1 with its own component id (not the autopilot's 1).
    assert any(kind == "HEARTBEAT" and system == 1 and component != 1 for system, component, kind in heard), heard
    log = mavutil.mavlink_connection(str(tmp_path / "mavlink.tlog"))
    recorded = []
    while (message := log.recv_match()) is not None:
        recorded.append((message.get_srcSystem(), message.get_type()))
    log.close()
    # The tlog records what arrived on the autopilot link (the intruder's datagrams to that port included):
    # a record, not a relay.
    assert (1, "HEARTBEAT") in recorded and tlog.packets == len(recorded)


def test_before_the_first_odometry_fixes_and_commands_are_refused_as_no_clock(app):
    app.target_link.clock = lambda: None
    app._vehicle_time = lambda: None
    app.target_link.on_fix(_fix(0, 1.0), 0)
    app.on_command(link.encode_command(link.Command("ground-station", 0, 1.0, "abort", epoch=3)))
    assert dict(app.target_link.health.rejected) == {"no_clock": 1} and not app.sequencer.abort_requested


def test_a_future_or_replayed_message_never_locks_the_genuine_sender_out(app):
    genuine = [link.TargetFix("target-1", k, 1.0 + 0.2 * k, "ned", (60.0 + 0.5 * k, -20.0, -20.0), epoch=11)
               for k in range(8)]
    app.target_link.on_fix(link.encode_target_fix(genuine[0]), 0)
    forged = [link.TargetFix("target-1", 2**62, 1.1, "ned", (60.0, -20.0, -20.0), epoch=11),
              link.TargetFix("target-1", 1, 1.0 + 1e6, "ned", (60.0, -20.0, -20.0), epoch=11),
              link.TargetFix("target-1", 5, 1.1, "ned", (90.0, -20.0, -20.0), epoch=99)]
    for fix in forged:
        app.target_link.on_fix(link.encode_target_fix(fix), 0)
    for fix in genuine[1:]:
        app.target_link.on_fix(link.encode_target_fix(fix), 0)
    assert app.target_link.health.accepted == 8
    assert dict(app.target_link.health.rejected) == {"seq_jump": 1, "future_stamp": 1, "implausible_jump": 1}


def test_commands_are_refused_when_replayed_reordered_or_far_in_the_future(app):
    abort = link.Command("ground-station", 4, 2.5, "abort", epoch=8)
    app.on_command(link.encode_command(link.Command("ground-station", 3, 2.4, "resume", epoch=8)))
    app.on_command(link.encode_command(link.Command("ground-station", 9, 2.5 + 1e6, "abort", epoch=8)))
    assert not app.sequencer.abort_requested
    app.on_command(link.encode_command(abort))
    assert app.sequencer.abort_requested
    app.sequencer.abort_requested = False
    app.on_command(link.encode_command(abort))  # the same command again: a replay
    assert not app.sequencer.abort_requested
    assert dict(app.sequencer.commands.rejected) == {"future_stamp": 1, "stale_seq": 1}


def test_a_reject_flood_leaves_the_logs_bounded_and_the_counters_exact(app):
    from companion.adapters.recorder import REJECTS_VERBATIM

    for k in range(3000):
        app.target_link.on_fix(b"\xff flood", 0)
        app.on_command(b"flood")
    app.recorder.close()
    assert app.target_link.health.rejected["not_utf8"] == 3000
    received = [json.loads(line) for line in (app.recorder.folder / "zenoh_rx.jsonl").read_text().splitlines()]
    events = [json.loads(line) for line in (app.recorder.folder / "events.jsonl").read_text().splitlines()]
    for records in (received, events):
        verbatim = [r for r in records if r.get("kind") != "suppressed"]
        suppressed = [r for r in records if r.get("kind") == "suppressed"]
        assert len(verbatim) == REJECTS_VERBATIM
        assert len(verbatim) + sum(r["count"] for r in suppressed) == 3000  # every reject written or counted
        assert len(records) < REJECTS_VERBATIM + 10  # a few seconds of wall time: a few count lines


def test_live_view_refuses_a_taken_port_or_a_bad_one_before_any_link_opens(tmp_path):
    """`companion --live PORT` on a port another program holds, or outside 0..65535: one line naming it and exit 2
    (the taken port is found before MAVLink or Zenoh is opened: the refusal comes without an autopilot)."""
    import socket
    import subprocess
    import sys

    scenario = Path(__file__).resolve().parent.parent / "config" / "scenarios" / "constant_velocity.toml"
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        taken = holder.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "companion", "--config", str(scenario), "--live", str(taken),
                                 "--log-dir", str(tmp_path / "run")], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert f"--live 127.0.0.1:{taken}" in result.stderr and "in use" in result.stderr
    result = subprocess.run([sys.executable, "-m", "companion", "--live", "70000"], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2 and "--live: 70000 is outside 0..65535" in result.stderr


def test_odometry_from_the_raw_stream_is_the_autopilots_own_in_ned():
    """The vehicle adapter reads ODOMETRY from MAVSDK's raw stream: an autopilot packet (system 1, component 1)
    yaw 90 deg with body velocity (2, 0, 0) becomes NED velocity (0, 2, 0) (a quarter turn, closed form) at its
    time_usec; the same message from another system or component, a pose in another frame (counted as bad
    odometry) and garbage bytes change nothing; a packet split in two still decodes."""
    import asyncio
    import math
    import os

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common as mav

    from companion.adapters.mavsdk_vehicle import MavsdkVehicle

    def odometry(system: int, component: int, time_usec: int, frame: int = mav.MAV_FRAME_LOCAL_NED) -> bytes:
        sender = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        half = math.radians(90.0) / 2.0
        return sender.odometry_encode(time_usec, frame, mav.MAV_FRAME_BODY_FRD, 1.0, 2.0, -3.0,
                                      [math.cos(half), 0.0, 0.0, math.sin(half)], 2.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                      [math.nan] * 21, [math.nan] * 21, 0, mav.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100).pack(sender)

    async def feed() -> MavsdkVehicle:
        vehicle = MavsdkVehicle()
        vehicle._loop, vehicle._autopilot_id = asyncio.get_running_loop(), 1
        vehicle._on_raw(odometry(7, 1, 1_000_000) + odometry(1, 190, 1_100_000))
        vehicle._on_raw(odometry(1, 1, 1_200_000, frame=mav.MAV_FRAME_GLOBAL))
        packet = odometry(1, 1, 2_000_000)
        vehicle._on_raw(packet[:7])
        vehicle._on_raw(packet[7:])
        vehicle._on_raw(b"\xfd\x09garbage")
        await asyncio.sleep(0)
        return vehicle

    vehicle = asyncio.run(feed())
    sample = vehicle.latest
    assert sample is not None and sample.state.time == 2.0
    np.testing.assert_allclose(sample.state.position, [1.0, 2.0, -3.0], atol=1e-6)
    np.testing.assert_allclose(sample.state.velocity, [0.0, 2.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(sample.rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)
    assert vehicle.bad_odometry == 1


@given(st.integers(1, 50), st.lists(st.floats(-1e6, 1e6), max_size=200))
def test_recent_samples_keep_the_newest_values_in_order_and_count_them_all(capacity, values):
    """RecentSamples: the last `capacity` values added, oldest first (a deque with that maxlen is the reference),
    and the count of all of them."""
    import collections

    from companion.adapters.recorder import RecentSamples

    samples, reference = RecentSamples(capacity), collections.deque(maxlen=capacity)
    for value in values:
        samples.append(value)
        reference.append(value)
    assert samples.count == len(values) and len(samples) == len(reference)
    assert samples.values().tolist() == list(reference)
    figures = samples.percentiles()
    assert figures["count"] == len(values)
    if reference:
        assert figures["p50"] == np.percentile(list(reference), 50) and figures["max"] == max(reference)
    else:
        assert np.isnan(figures["p50"]) and np.isnan(figures["max"])
