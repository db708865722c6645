"""bof-intruder's attacks checked at the receiving end: a plain Zenoh subscriber and a pymavlink autopilot.

Every Zenoh attack publishes to a subscriber of this test (zenoh itself is the reference): what it
delivers must decode with interfaces.link_schema and carry exactly the fields the attack promised
(seq 2**62, stamp +1e6 s, the burst 30 m off, computed here with the WGS-84 closed form, not with
the code under test). The MAVLink arm goes to a pymavlink peer acting as the autopilot, which must
receive exactly one valid COMMAND_LONG arm (signed or not, as asked). The floods are counted at the
receiver: never more than rate x duration (+1), never a well-formed message that could act.
"""

from __future__ import annotations

import json
import math
import os
import socket
import threading
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
import pytest  # noqa: E402
from hypothesis import given, settings, strategies as st  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from interfaces import link_schema as link  # noqa: E402
from interfaces.zenoh_transport import open_session, zenoh_config  # noqa: E402
from studies import intruder  # noqa: E402
from studies.processes import free_port  # noqa: E402

SENDER = "target-1"
COMPANION = "pursuer-1"
HOME = (47.397742, 8.545594, 488.0)
WGS84_A, WGS84_E2 = 6378137.0, 6.69437999014e-3


def _local_offset(position, reference) -> tuple[float, float, float]:
    """NED offset (m) of geodetic `position` from `reference`, WGS-84 radii of curvature at the reference
    (closed form; exact to well under a millimetre over tens of metres)."""
    lat = math.radians(reference[0])
    w = math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    prime_vertical = WGS84_A / w
    meridian = WGS84_A * (1.0 - WGS84_E2) / w**3
    north = math.radians(position[0] - reference[0]) * (meridian + reference[2])
    east = math.radians(position[1] - reference[1]) * (prime_vertical + reference[2]) * math.cos(lat)
    return north, east, -(position[2] - reference[2])


class Listener:
    """The test's own Zenoh peer: listens on a free loopback port and keeps every sample on bof/** (key, bytes)."""

    def __init__(self, subscribe: bool = True) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        self.session = open_session(zenoh_config(listen=[self.endpoint]))
        self.samples: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()
        if subscribe:
            self.session.declare_subscriber("bof/**", self._on_sample)

    def _on_sample(self, sample) -> None:
        with self._lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_bytes()))

    def on(self, key: str) -> list[bytes]:
        with self._lock:
            return [payload for k, payload in self.samples if k == key]

    def wait_for(self, key: str, count: int, timeout: float = 10.0) -> list[bytes]:
        end = time.monotonic() + timeout
        while time.monotonic() < end and len(self.on(key)) < count:
            time.sleep(0.02)
        return self.on(key)

    def quiet(self, key: str, timeout: float = 10.0) -> list[bytes]:
        """Wait until nothing new arrives on `key` for 0.5 s (or `timeout`), then return what arrived."""
        end, last, since = time.monotonic() + timeout, -1, time.monotonic()
        while time.monotonic() < end:
            count = len(self.on(key))
            if count != last:
                last, since = count, time.monotonic()
            elif time.monotonic() - since > 0.5:
                break
            time.sleep(0.05)
        return self.on(key)


@pytest.fixture
def zenoh_pair():
    listener = Listener()
    attacker = intruder.open_peer(listener.endpoint)
    try:
        yield listener, attacker
    finally:
        attacker.close()
        listener.session.close()


def _reference(frame: str = "geodetic", seq: int = 41, stamp: float = 12.5) -> link.TargetFix:
    position = (47.3981, 8.5461, 508.0) if frame == "geodetic" else (30.0, -12.0, -20.0)
    return intruder.make_fix(SENDER, seq, stamp, frame, position, (3.0, 4.0, 0.0), epoch=123456789)


def _epoch_kept(fix: link.TargetFix, reference: link.TargetFix) -> bool:
    return getattr(fix, "epoch", None) == getattr(reference, "epoch", None)


@pytest.mark.parametrize("late", [False, True], ids=["fix", "latest-genuine-callable"])
def test_future_seq_delivers_one_fix_with_seq_2_62_at_the_target_position(zenoh_pair, late):
    listener, attacker = zenoh_pair
    reference = _reference()
    sent = intruder.spoof_future_seq(attacker, (lambda: reference) if late else reference)
    delivered = listener.wait_for(link.target_fix_key(SENDER), 1)
    assert sent.count == 1 and sent.matched and len(delivered) == 1
    fix = link.decode_target_fix(delivered[0])
    assert (fix.sender, fix.seq, fix.frame, fix.position) == (SENDER, 2**62, "geodetic", reference.position)
    assert fix.stamp > reference.stamp and _epoch_kept(fix, reference)
    assert delivered == sent.payloads


def test_future_stamp_delivers_one_fix_stamped_a_million_seconds_ahead(zenoh_pair):
    listener, attacker = zenoh_pair
    reference = _reference("ned")
    intruder.spoof_future_stamp(attacker, reference)
    (payload,) = listener.wait_for(link.target_fix_key(SENDER), 1)
    fix = link.decode_target_fix(payload)
    assert fix.seq == reference.seq + 1 and fix.stamp == pytest.approx(reference.stamp + 1e6, abs=1e-6)
    assert fix.position == reference.position and fix.sender == SENDER and _epoch_kept(fix, reference)


def test_burst_delivers_three_consistent_fixes_30_m_east_with_seq_far_ahead(zenoh_pair):
    listener, attacker = zenoh_pair
    reference = _reference()
    sent = intruder.spoof_burst(attacker, reference)
    delivered = listener.wait_for(link.target_fix_key(SENDER), 3)
    assert sent.count == 3 and len(delivered) == 3
    fixes = [link.decode_target_fix(payload) for payload in delivered]
    assert [f.seq for f in fixes] == [reference.seq + 10**6 + i for i in range(3)]
    assert all(a.stamp < b.stamp for a, b in zip(fixes, fixes[1:])) and fixes[0].stamp > reference.stamp
    for fix in fixes:
        north, east, down = _local_offset(fix.position, reference.position)
        assert (north, east, down) == pytest.approx((0.0, 30.0, 0.0), abs=0.01)
        assert fix.sender == SENDER and _epoch_kept(fix, reference)


def test_replay_resends_the_recorded_payloads_verbatim_and_in_order(zenoh_pair):
    listener, attacker = zenoh_pair
    recorded = [link.encode_target_fix(_reference("ned", seq=i, stamp=0.2 * i)) for i in range(10)]
    sent = intruder.replay(attacker, SENDER, recorded, rate_hz=100.0)
    delivered = listener.wait_for(link.target_fix_key(SENDER), 10)
    assert sent.count == 10 and delivered == recorded


def test_steady_spoof_follows_the_target_on_a_bounded_drifting_offset(zenoh_pair):
    listener, attacker = zenoh_pair
    start = time.monotonic()

    def genuine() -> link.TargetFix:  # a target moving north at 3 m/s, one fix per 0.2 s
        k = int((time.monotonic() - start) / 0.2)
        return intruder.make_fix(SENDER, k, 0.2 * k, "ned", (3.0 * 0.2 * k, 0.0, -20.0), epoch=7)

    sent = intruder.spoof_steady(attacker, genuine, rate_hz=20.0, duration=1.5, drift=(0.0, 10.0, 0.0), max_offset=8.0)
    delivered = listener.quiet(link.target_fix_key(SENDER))
    assert 1 <= sent.count <= 20 * 1.5 + 1 and len(delivered) == sent.count
    fixes = [link.decode_target_fix(payload) for payload in delivered]
    east = [f.position[1] for f in fixes]
    assert all(0.0 <= e <= 8.0 + 1e-9 for e in east) and east[-1] > east[0]
    assert all(b >= a - 1e-9 for a, b in zip(east, east[1:]))  # drifting away, capped at 8 m
    for fix, seq, reference in zip(fixes, sent.promised["seqs"], sent.promised["references"]):
        assert fix.seq == seq and fix.position[0] == reference[0] and fix.sender == SENDER


def test_abort_is_one_well_formed_abort_on_the_companion_command_key(zenoh_pair):
    listener, attacker = zenoh_pair
    sent = intruder.send_abort(attacker, COMPANION, stamp=3.0)
    (payload,) = listener.wait_for(link.companion_command_key(COMPANION), 1)
    command = link.decode_command(payload)
    assert sent.count == 1 and (command.command, command.sender, command.stamp) == ("abort", "intruder", 3.0)


def test_a_plain_unknown_peer_sees_and_delivers_on_an_unsecured_mesh():
    """The baseline the secure mode must change: a plain peer hears the mesh and its spoof is delivered."""
    listener = Listener()
    stop = threading.Event()
    publisher = listener.session.declare_publisher(link.CLOCK_KEY)

    def clock() -> None:
        k = 0
        while not stop.is_set():
            publisher.put(link.encode_clock(link.ClockTick("sitl-plant", k, 0.02 * k)))
            k += 1
            time.sleep(0.02)

    thread = threading.Thread(target=clock, daemon=True)
    thread.start()
    try:
        sent = intruder.unknown_peer(listener.endpoint, None, _reference(), listen_s=1.0)
        delivered = listener.wait_for(link.target_fix_key(SENDER), 1)
    finally:
        stop.set()
        thread.join(5.0)
        listener.session.close()
    assert sent.promised["session"] == "opened" and sent.promised["seen"] > 0
    assert delivered == sent.payloads and link.decode_target_fix(delivered[0]).seq == 2**62


def test_zenoh_flood_respects_its_bound_and_never_sends_a_usable_fix_or_command(zenoh_pair):
    listener, attacker = zenoh_pair
    rate, duration = 200.0, 1.0
    sent = intruder.zenoh_flood(attacker, SENDER, COMPANION, rate_hz=rate, duration=duration)
    fixes = listener.quiet(link.target_fix_key(SENDER))
    commands = listener.quiet(link.companion_command_key(COMPANION))
    assert 0 < sent.count <= rate * duration + 1 and sum(sent.kinds.values()) == sent.count
    assert 0 < len(fixes) + len(commands) <= sent.count
    for payload in fixes:  # malformed, or from someone else: never the target's fix
        try:
            assert link.decode_target_fix(payload).sender != SENDER
        except link.PayloadError:
            pass
    for payload in commands:
        with pytest.raises(link.PayloadError) as error:
            link.decode_command(payload)
        assert error.value.reason == "unknown_command"


# --- MAVLink -----------------------------------------------------------------------------

class Autopilot:
    """A pymavlink autopilot (system 1, component 1) on a free loopback port: answers COMMAND_LONG with
    COMMAND_ACK ACCEPTED, arms on ARM, sends HEARTBEAT every 0.1 s to whoever spoke last, keeps every
    message it received (with whether it carried a valid signature when it has a key)."""

    def __init__(self, key: bytes | None = None) -> None:
        self.port = free_port()
        self.connection = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=1, source_component=1)
        if key is not None:  # only signed messages with this key get through; unsigned ones are refused
            self.connection.setup_signing(key, sign_outgoing=False)
        self.received: list = []
        self.armed = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_heartbeat = 0.0
        while not self._stop.is_set():
            msg = self.connection.recv_match(blocking=True, timeout=0.02)
            if msg is not None and msg.get_type() != "BAD_DATA":
                self.received.append((msg, getattr(msg, "_signed", False)))
                if msg.get_type() == "COMMAND_LONG":
                    if msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM and msg.param1 == 1.0:
                        self.armed = True
                    self.connection.mav.command_ack_send(msg.command, mav.MAV_RESULT_ACCEPTED)
            if time.monotonic() >= next_heartbeat and self.connection.clients:  # udpin: whoever has spoken
                next_heartbeat = time.monotonic() + 0.1
                base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
                self.connection.mav.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, 0,
                                                   mav.MAV_STATE_STANDBY)

    def commands(self) -> list:
        return [(msg, signed) for msg, signed in self.received if msg.get_type() == "COMMAND_LONG"]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.connection.close()


@pytest.fixture
def autopilot_factory():
    made = []

    def make(key=None) -> Autopilot:
        made.append(Autopilot(key))
        return made[-1]

    yield make
    for autopilot in made:
        autopilot.close()


def test_unsigned_arm_sends_exactly_one_valid_command_long_arm(autopilot_factory):
    autopilot = autopilot_factory()
    result = intruder.mavlink_arm(f"udpout:127.0.0.1:{autopilot.port}", wait_s=3.0, observe_s=0.5)
    ((msg, signed),) = autopilot.commands()
    assert (msg.command, msg.param1, msg.target_system, msg.target_component) == (
        mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 1, 1)
    assert msg.get_srcSystem() == 255 and not signed and msg.get_header().incompat_flags & 1 == 0
    assert result.heartbeats > 0 and result.armed_before is False and result.armed_after is True
    assert result.acks["MAV_CMD_COMPONENT_ARM_DISARM"] == mav.MAV_RESULT_ACCEPTED


def test_signed_arm_is_verified_by_a_peer_with_the_key_and_refused_by_one_without(autopilot_factory):
    key = bytes(range(32))
    genuine = autopilot_factory(key)
    result = intruder.mavlink_arm(f"udpout:127.0.0.1:{genuine.port}", signing_key=key, wait_s=3.0, observe_s=0.5)
    ((msg, signed),) = genuine.commands()
    assert signed and msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM and result.signed
    other = autopilot_factory(bytes(32))  # another key: the signature does not verify
    intruder.mavlink_arm(f"udpout:127.0.0.1:{other.port}", signing_key=key, wait_s=0.5, observe_s=0.5)
    assert other.commands() == [] and not other.armed


def test_signing_key_file_must_be_64_hex_characters(tmp_path):
    good, bad = tmp_path / "good.key", tmp_path / "bad.key"
    good.write_text("ab" * 32 + "\n")
    bad.write_text("xyz")
    assert intruder.read_signing_key(good) == bytes([0xAB] * 32)
    with pytest.raises(ValueError):
        intruder.read_signing_key(bad)


def test_mavlink_flood_respects_its_bound_and_never_commands_the_vehicle():
    datagrams: list[bytes] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        sink.bind(("127.0.0.1", 0))
        sink.settimeout(0.5)
        done = threading.Event()

        def drain() -> None:  # read as they come, so the socket buffer never drops any
            while True:
                try:
                    datagrams.append(sink.recv(65535))
                except socket.timeout:
                    if done.is_set():
                        return

        reader = threading.Thread(target=drain, daemon=True)
        reader.start()
        rate, duration = 300.0, 1.0
        result = intruder.mavlink_flood("127.0.0.1", sink.getsockname()[1], rate_hz=rate, duration=duration)
        done.set()
        reader.join(10.0)
    # UDP may drop on a loaded machine, never duplicate: what arrives is at most what was sent, within the bound.
    assert 0 < len(datagrams) <= sum(result.sent.values()) <= rate * duration + 1
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    for data in datagrams:
        for msg in parser.parse_buffer(data) or []:
            assert getattr(msg, "target_system", 0) != 1  # nothing addressed to the vehicle (system 1)
            assert msg.get_type() != "COMMAND_LONG" or msg.target_system == 42


# --- payload helpers, observation, discovery -------------------------------------------------

@settings(max_examples=50, deadline=None)
@given(lat=st.floats(-80.0, 80.0), lon=st.floats(-179.0, 179.0), alt=st.floats(0.0, 3000.0),
       north=st.floats(-50.0, 50.0), east=st.floats(-50.0, 50.0), down=st.floats(-20.0, 20.0))
def test_offset_position_moves_a_geodetic_fix_by_the_ned_offset(lat, lon, alt, north, east, down):
    fix = intruder.make_fix(SENDER, 1, 1.0, "geodetic", (lat, lon, alt))
    moved = intruder.offset_position(fix, (north, east, down))
    # The closed form is a tangent-plane approximation: good to ~1e-3 m at 50 m (curvature aside).
    assert _local_offset(moved, fix.position) == pytest.approx((north, east, down), abs=0.01)


def _state(seq: int, stamp: float, pursuer, accepted: int, rejected: dict, last_seq: int, last_stamp: float,
           estimate_range: float) -> bytes:
    return link.encode_state(dict(
        sender=COMPANION, seq=seq, stamp=stamp, phase="following",
        pursuer={"position": list(pursuer), "velocity": [0.0, 0.0, 0.0]},
        link={"received": accepted + sum(rejected.values()), "accepted": accepted, "rejected": rejected,
              "bearings_used": accepted, "bearings_dropped": {}, "last_seq": last_seq, "last_stamp": last_stamp,
              "last_fix_age_wall": 0.1},
        setpoints_sent=seq,
        estimate={"time": stamp, "position": [0.0, 0.0, -20.0], "velocity": [0.0, 0.0, 0.0], "position_std": 0.1,
                  "velocity_std": 0.1, "range": estimate_range}))


def test_observer_row_gives_the_refusals_lockout_and_min_range_of_a_scripted_window():
    """A scripted companion: a fixed target at (0, 0, -20), the pursuer 10 m north then 6 m north, genuine fixes
    accepted at stamps 0-2 and 5-6 (none between: a 3 s lockout), 4 spoofs rejected as stale_seq."""
    listener = Listener(subscribe=False)  # so that the publishers match the observer's subscribers only
    publisher_fix = listener.session.declare_publisher(link.target_fix_key(SENDER))
    publisher_state = listener.session.declare_publisher(link.companion_state_key(COMPANION))
    observer = intruder.Observer(listener.endpoint, SENDER, COMPANION)
    try:
        intruder.wait_matched(publisher_state, 5.0)
        intruder.wait_matched(publisher_fix, 5.0)
        genuine = {k: link.encode_target_fix(intruder.make_fix(SENDER, k, float(k), "ned", (0.0, 0.0, -20.0), epoch=1))
                   for k in range(7)}
        for k in range(3):
            publisher_fix.put(genuine[k])
        time.sleep(0.3)
        publisher_state.put(_state(0, 2.0, (10.0, 0.0, -20.0), 3, {}, 2, 2.0, 10.0))
        assert observer.wait(lambda: observer.latest_state() is not None, 5.0)
        time.sleep(0.1)
        start = time.monotonic()
        for k in (3, 4):
            publisher_fix.put(genuine[k])
        publisher_state.put(_state(1, 3.0, (8.0, 0.0, -20.0), 3, {"stale_seq": 3}, 2, 2.0, 8.0))
        publisher_state.put(_state(2, 4.0, (6.0, 0.0, -20.0), 3, {"stale_seq": 6}, 2, 2.0, 6.0))
        for k in (5, 6):
            publisher_fix.put(genuine[k])
        time.sleep(0.2)
        publisher_state.put(_state(3, 5.0, (7.0, 0.0, -20.0), 4, {"stale_seq": 6}, 5, 5.0, 7.0))
        publisher_state.put(_state(4, 6.0, (8.0, 0.0, -20.0), 5, {"stale_seq": 6}, 6, 6.0, 8.0))
        assert observer.wait(lambda: len(observer.states) == 5 and len(observer.genuine()) == 7, 5.0)
        row = observer.row("scripted", 4, start, time.monotonic(), desired_range=8.0)
    finally:
        observer.close()
        listener.session.close()
    # 6 rejects in the window, of which the 2 genuine fixes (3, 4) never accepted: 4 refusals of the intruder.
    assert (row.refused, row.lockout_s, row.min_range_m, row.target_kept) == (4, 3.0, 6.0, True)


def test_discover_reads_the_zenoh_endpoint_and_the_gcs_socket_from_a_run_folder(tmp_path):
    run = tmp_path / "sitl-x-seed1-20260101-000000"
    (run / "plant").mkdir(parents=True)
    (run / "target.out").write_text("sitl-target ready: x, publishing bof/target/target-1/fix at 5 Hz (geodetic), "
                                    "clock bof/sim/clock, zenoh peer listen ['tcp/127.0.0.1:0'] connect "
                                    "['tcp/127.0.0.1:40123'], faults: none\n")
    (run / "plant" / "stats.json").write_text(json.dumps(
        {"links": {"gcs": {"bound": ["127.0.0.1", 50001], "partner": ["127.0.0.1", 14550]}}}))
    found = intruder.discover(tmp_path)
    assert (found.run, found.zenoh, found.gcs, found.gcs_partner) == (
        run, "tcp/127.0.0.1:40123", ("127.0.0.1", 50001), ("127.0.0.1", 14550))


def test_tls_overrides_name_zenohs_own_tls_settings(tmp_path):
    tls = intruder.Tls.from_dir(tmp_path, "gcs")
    overrides = tls.overrides()
    assert json.loads(overrides["transport/link/tls/root_ca_certificate"]) == str(Path(tmp_path) / "ca.pem")
    assert json.loads(overrides["transport/link/tls/connect_certificate"]) == str(Path(tmp_path) / "gcs.pem")
    assert json.loads(overrides["transport/link/tls/enable_mtls"]) is True
    no_cert = intruder.Tls(tmp_path / "ca.pem").overrides()
    assert "transport/link/tls/connect_certificate" not in no_cert
    config = zenoh_config(connect=["tls/127.0.0.1:7447"], overrides=overrides)  # zenoh accepts the keys
    assert json.loads(config.get_json("transport/link/tls/enable_mtls")) is True


def test_rx_log_accounting_counts_accepted_spoofs_and_the_gap_between_accepted_genuine_fixes(tmp_path):
    """A scripted zenoh_rx.jsonl: genuine fixes every 0.2 s; the spoof (seq 2**62) accepted at t = 10.1 s,
    then genuine fixes rejected until stamp 3.0, accepted again from 3.2: the lockout is 3.2 - 1.0 = 2.2 s."""
    ns = lambda t: int(t * 1e9)  # noqa: E731
    records = [{"received_ns": ns(9.0 + 0.2 * k), "verdict": "accepted", "seq": k, "stamp": 0.2 * k} for k in range(6)]
    records.append({"received_ns": ns(10.11), "verdict": "accepted", "seq": 2**62, "stamp": 1.01})
    records += [{"received_ns": ns(9.0 + 0.2 * k), "verdict": "rejected", "reason": "stale_seq"} for k in range(6, 16)]
    records += [{"received_ns": ns(9.0 + 0.2 * k), "verdict": "accepted", "seq": k, "stamp": 0.2 * k} for k in range(16, 20)]
    log = tmp_path / "zenoh_rx.jsonl"
    log.write_text("\n".join(json.dumps(r) for r in records) + "\n{\"cut")
    genuine = {(k, 0.2 * k) for k in range(20)}
    spoofs, lockout = intruder._rx_accounting(log, 10.05, 13.0, {(2**62, 1.01)}, genuine, end_stamp=3.8)
    assert spoofs == 1 and lockout == pytest.approx(3.2 - 1.0)


# --- mutual TLS: an unknown peer against a secure mesh ------------------------------------------

def _pki(folder: Path, roles: tuple[str, ...]) -> Path:
    """A throwaway CA (folder/ca.pem) and, per role, folder/<role>.pem/.key signed by it (common name = role,
    SAN 127.0.0.1 and localhost), made with `cryptography` (independent of the project's own PKI command)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"test-ca-{folder.name}")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
          .not_valid_after(now + datetime.timedelta(days=1))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    (folder / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    for name in roles:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])).issuer_name(ca_name)
                .public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
                .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                            x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                               critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .sign(ca_key, hashes.SHA256()))
        (folder / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        (folder / f"{name}.key").write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                                               serialization.PrivateFormat.PKCS8,
                                                               serialization.NoEncryption()))
    return folder


class SecureListener(Listener):
    """The test's peer, listening with mutual TLS (role `plant` of the test PKI), publishing a clock at 50 Hz."""

    def __init__(self, pki: Path) -> None:
        self.endpoint = f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        self.session = open_session(zenoh_config(listen=[self.endpoint],
                                                 overrides=intruder.Tls.from_dir(pki, "plant").overrides()))
        self.samples = []
        self._lock = threading.Lock()
        self.session.declare_subscriber("bof/**", self._on_sample)
        self._stop = threading.Event()
        clock = self.session.declare_publisher(link.CLOCK_KEY)

        def tick() -> None:
            k = 0
            while not self._stop.wait(0.02):
                clock.put(link.encode_clock(link.ClockTick("sitl-plant", k, 0.02 * k)))
                k += 1

        self._thread = threading.Thread(target=tick, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.session.close()


@pytest.fixture
def secure_mesh(tmp_path):
    pki = _pki(tmp_path / "pki", ("plant", "gcs"))
    foreign = _pki(tmp_path / "foreign", ("target",))
    listener = SecureListener(pki)
    try:
        yield listener, pki, foreign
    finally:
        listener.close()


def test_a_trusted_tls_peer_hears_the_mesh_and_delivers(secure_mesh):
    """The positive control: Tls's overrides make a working mTLS peer (so the refusals below are mTLS's doing)."""
    listener, pki, _ = secure_mesh
    sent = intruder.unknown_peer(listener.endpoint, intruder.Tls.from_dir(pki, "gcs"), _reference(), listen_s=1.0)
    delivered = listener.wait_for(link.target_fix_key(SENDER), 1)
    assert sent.promised["seen"] > 0 and delivered == sent.payloads


@pytest.mark.parametrize("who", ["no certificate", "foreign CA", "plain TCP"])
def test_an_unknown_peer_sees_and_delivers_nothing_on_a_mutual_tls_mesh(secure_mesh, who):
    listener, pki, foreign = secure_mesh
    tls = {"no certificate": intruder.Tls(pki / "ca.pem"), "foreign CA": intruder.Tls.from_dir(foreign, "target"),
           "plain TCP": None}[who]
    endpoint = listener.endpoint if tls is not None else listener.endpoint.replace("tls/", "tcp/")
    sent = intruder.unknown_peer(endpoint, tls, _reference(), listen_s=1.5, match_timeout=1.0)
    time.sleep(0.5)
    assert sent.promised["seen"] == 0 and not sent.matched
    assert listener.on(link.target_fix_key(SENDER)) == []


def test_the_command_line_attacks_a_scripted_sitl_and_writes_its_row(tmp_path):
    """bof-intruder future-seq against a scripted mesh (genuine NED fixes at 10 Hz, a companion state at 10 Hz):
    the intruder's fix reaches the mesh with seq 2**62 and the JSON row says one was sent."""
    listener = Listener()
    fixes = listener.session.declare_publisher(link.target_fix_key(SENDER))
    states = listener.session.declare_publisher(link.companion_state_key(COMPANION))
    stop = threading.Event()

    def scripted() -> None:
        k = 0
        while not stop.wait(0.1):
            fixes.put(link.encode_target_fix(intruder.make_fix(SENDER, k, 0.1 * k, "ned", (0.3 * k, 0.0, -20.0), epoch=5)))
            states.put(_state(k, 0.1 * k, (0.3 * k - 8.0, 0.0, -20.0), k + 1, {}, k, 0.1 * k, 8.0))
            k += 1

    thread = threading.Thread(target=scripted, daemon=True)
    thread.start()
    out = tmp_path / "row.json"
    try:
        code = intruder.main(["--zenoh", listener.endpoint, "--wait", "10", "--settle", "0.3", "--observe", "1",
                              "future-seq", "--json", str(out)])
    finally:
        stop.set()
        thread.join(5.0)
        listener.session.close()
    result = json.loads(out.read_text())
    spoofs = [link.decode_target_fix(p) for p in listener.on(link.target_fix_key(SENDER))]
    assert code == 0 and result["row"]["attack"] == "future-seq" and result["row"]["sent"] == 1
    assert [fix.seq for fix in spoofs if fix.seq == 2**62] == [2**62]


@pytest.mark.parametrize("arguments, fragment", [
    (["--config", "config"], "is a folder"),  # an IsADirectoryError traceback before
    (["--settle", "nan"], "--settle"), (["--settle", "-1"], "--settle"),
    (["--takeoff", "nan"], "--takeoff"), (["--takeoff", "0"], "--takeoff"),
    (["--seq-lead", "-1"], "--seq-lead"),
])
def test_bad_arguments_are_refused_in_one_line(capsys, arguments, fragment):
    with pytest.raises(SystemExit) as exit_:
        intruder.main(["replay", "--zenoh", "tcp/127.0.0.1:9", *arguments])
    assert exit_.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith("bof-intruder: error:") and fragment in line, line
