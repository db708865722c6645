"""Secure Zenoh links: the development PKI, mutual TLS and access control, checked against zenoh itself.

The intruders here are zenoh sessions configured by hand (zenoh's own configuration keys, no
access control of their own), not through `zenoh_config`: what they can or cannot do is what
the genuine nodes' Zenoh refuses. Every "nothing arrived" is proven on a link shown to carry
traffic: the refused message is sent first, an allowed one after it on the same link, and the
check runs once the allowed one has arrived (a Zenoh link delivers in order).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import re
import shutil
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.verification import PolicyBuilder, Store
from hypothesis import given, settings
from hypothesis import strategies as st

from interfaces import pki
from interfaces import link_schema as link
from interfaces.zenoh_transport import (PUBLISH_RIGHTS, LinkError, check_exposure, count_tls_refusals,
                                        endpoint_is_loopback, link_security, open_session, remote_exposure,
                                        tls_identity, zenoh_config)
from studies.processes import ChildProcess, free_port

TIMEOUT = 20.0  # s of wall time before a wait gives up (never reached when things work)
COMMAND_KEY = link.companion_command_key("pursuer-1")
TARGET_COMMAND_KEY = link.target_command_key("target-1")
FIX_KEY = link.target_fix_key("target-1")


# ---------------------------------------------------------------------------- PKI
@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("certs") / "pki"
    pki.make_pki(folder)
    return folder


@pytest.fixture(scope="module")
def foreign_certs(tmp_path_factory) -> Path:
    """Same roles, another CA (an attacker's own development CA)."""
    folder = tmp_path_factory.mktemp("foreign") / "pki"
    pki.make_pki(folder)
    return folder


def test_bof_certs_writes_a_ca_and_one_certificate_per_role_with_private_keys(tmp_path, capsys):
    folder = tmp_path / "pki"
    assert pki.main([str(folder), "--days", "7"]) == 0
    assert "development" in capsys.readouterr().out
    names = sorted(path.name for path in folder.iterdir())
    assert names == sorted(["ca.pem", "ca.key"] + [f"{role}.{ext}" for role in pki.ROLES for ext in ("pem", "key")])
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    for path in folder.glob("*.key"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path


def test_role_certificates_pass_an_independent_tls_verifier_as_server_and_client(certs):
    """cryptography's own X.509 path validation (the CA/B and webpki rules, as rustls applies them)
    accepts every role certificate as a TLS server for 127.0.0.1, ::1 and localhost and as a client."""
    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    store = Store([ca])
    now = dt.datetime.now(dt.timezone.utc)
    for role in pki.ROLES:
        certificate = x509.load_pem_x509_certificate((certs / f"{role}.pem").read_bytes())
        assert certificate.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == role
        for name in (x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.IPAddress(ipaddress.ip_address("::1")),
                     x509.DNSName("localhost")):
            chain = PolicyBuilder().store(store).time(now).build_server_verifier(name).verify(certificate, [])
            assert chain[-1] == ca
        client = PolicyBuilder().store(store).time(now).build_client_verifier().verify(certificate, [])
        assert client.chain[-1] == ca


def test_bof_certs_refuses_a_folder_in_use_unless_forced(tmp_path, capsys):
    folder = tmp_path / "pki"
    assert pki.main([str(folder)]) == 0
    before = (folder / "ca.pem").read_bytes()
    capsys.readouterr()
    assert pki.main([str(folder)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "--force" in error
    assert (folder / "ca.pem").read_bytes() == before
    assert pki.main([str(folder), "--force"]) == 0
    assert (folder / "ca.pem").read_bytes() != before


@pytest.mark.parametrize("argv, message", [
    (["--days", "0"], "--days"),
    (["--days", "99999"], "--days"),
    (["--roles", "Target/1"], "role"),
])
def test_bof_certs_bad_arguments_give_one_line(tmp_path, capsys, argv, message):
    assert pki.main([str(tmp_path / "pki"), *argv]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error
    assert not (tmp_path / "pki").exists()


def test_bof_certs_a_folder_that_cannot_be_made(capsys):
    assert pki.main(["/dev/null/pki"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "cannot create the folder" in error


def test_bof_certs_a_file_in_the_way(tmp_path, capsys):
    (tmp_path / "pki").write_text("not a folder")
    assert pki.main([str(tmp_path / "pki")]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_identity_refuses_what_a_peer_would_refuse(tmp_path, certs, foreign_certs):
    folder = tmp_path / "mixed"
    shutil.copytree(certs, folder)
    assert pki.identity(folder, "target").certificate == (folder / "target.pem").absolute()
    shutil.copy(folder / "gcs.pem", folder / "target.pem")  # the gcs certificate under the target's name
    with pytest.raises(pki.PkiError, match="common name 'gcs'"):
        pki.identity(folder, "target")
    shutil.copy(certs / "target.pem", folder / "target.pem")
    shutil.copy(certs / "plant.key", folder / "target.key")
    with pytest.raises(pki.PkiError, match="does not belong"):
        pki.identity(folder, "target")
    shutil.copy(foreign_certs / "target.pem", folder / "target.pem")
    with pytest.raises(pki.PkiError, match="not issued by the CA"):
        pki.identity(folder, "target")
    later = dt.datetime.now(dt.timezone.utc) + dt.timedelta(days=pki.DEFAULT_DAYS + 1)
    with pytest.raises(pki.PkiError, match="not now"):
        pki.identity(certs, "companion", now=later)
    with pytest.raises(LinkError, match="missing"):
        tls_identity(tmp_path / "nowhere", "companion")
    assert tls_identity(None, "companion") is None


@settings(max_examples=25, deadline=None)
@given(roles=st.lists(st.from_regex(r"[a-z0-9][a-z0-9_\-]{0,31}", fullmatch=True), min_size=1, max_size=4, unique=True))
def test_any_valid_role_name_gets_a_certificate_with_that_common_name(tmp_path_factory, roles):
    folder = tmp_path_factory.mktemp("roles") / "pki"
    issued = pki.make_pki(folder, roles, days=1)
    assert list(issued) == roles
    for role in roles:
        certificate = x509.load_pem_x509_certificate((folder / f"{role}.pem").read_bytes())
        assert certificate.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == role
        assert pki.identity(folder, role).role == role


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.text(alphabet=st.characters(blacklist_characters="\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"),
                                                  max_size=40)), max_size=30))
def test_tls_refusals_are_counted_line_by_line(lines):
    """Zenoh's refused-handshake lines (its format, with or without colours) among any other output."""
    text = []
    for refusal, noise in lines:
        if refusal:
            text.append(f"2026-11-29T11:28:42.144991Z \x1b[33m WARN\x1b[0m acc-0 ThreadId(05) \x1b[2mzenoh_link_tls::unicast\x1b[0m: "
                        f"peer sent no certificates. {noise}")
        else:
            text.append(f"companion: {noise}".replace("WARN", "warn").replace("zenoh_link_tls", "tls"))
    assert count_tls_refusals("\n".join(text)) == sum(refusal for refusal, _ in lines)


# ----------------------------------------------------------------------- zenoh peers
def _config(listen, connect, tls: dict | None) -> zenoh.Config:
    """An intruder's session, written with zenoh's own keys: TLS settings `tls`, and no access control."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("connect/endpoints", json.dumps(connect))
    config.insert_json5("scouting/multicast/enabled", "false")
    if tls is not None:
        config.insert_json5("transport/link/tls", json.dumps(tls))
    return config


def _intruder(endpoint: str, ca: Path, folder: Path | None, role: str | None) -> zenoh.Session:
    """A peer trusting `ca`, presenting folder/role certificate (None: no certificate at all)."""
    tls = {"root_ca_certificate": str(ca), "enable_mtls": folder is not None}
    listen = []
    if folder is not None:
        files = {"certificate": str(folder / f"{role}.pem"), "private_key": str(folder / f"{role}.key")}
        tls.update({f"{side}_{name}": path for side in ("listen", "connect") for name, path in files.items()})
        listen = ["tls/127.0.0.1:0"]
    return zenoh.open(_config(listen, [endpoint], tls))


class Inbox:
    """What a subscriber heard: (key, payload bytes), in order, from Zenoh's threads."""

    def __init__(self, session: zenoh.Session, key: str = "bof/**") -> None:
        self.samples: list[tuple[str, bytes]] = []
        self._lock = threading.Condition()
        self.subscriber = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample) -> None:
        with self._lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_bytes()))
            self._lock.notify_all()

    def wait_for(self, key: str, payload: bytes) -> None:
        """Until (key, payload) has been heard; fails the test after TIMEOUT."""
        with self._lock:
            assert self._lock.wait_for(lambda: (key, payload) in self.samples, TIMEOUT), \
                f"never heard {key} {payload!r}; heard {self.samples[-5:]}"

    def on(self, key: str) -> list[bytes]:
        with self._lock:
            return [payload for k, payload in self.samples if k == key]


def _until(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def _put_until_heard(session: zenoh.Session, inbox: Inbox, key: str, payload: bytes) -> None:
    """Put repeatedly until `inbox` hears it: the route from `session` to the subscriber is up."""
    deadline = time.monotonic() + TIMEOUT
    while (key, payload) not in inbox.samples:
        assert time.monotonic() < deadline, f"{key} never got through"
        session.put(key, payload)
        time.sleep(0.05)


@pytest.fixture
def mesh(certs):
    """A secure mesh as the processes build it: plant listening, companion and target connecting."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    sessions = {}
    try:
        sessions["plant"] = open_session(zenoh_config(listen=[endpoint], tls=tls_identity(certs, "plant")))
        for role in ("companion", "target"):
            sessions[role] = open_session(zenoh_config(connect=[endpoint], tls=tls_identity(certs, role)))
        inbox = Inbox(sessions["companion"])
        target_commands = Inbox(sessions["target"], TARGET_COMMAND_KEY)
        _put_until_heard(sessions["target"], inbox, FIX_KEY, b"genuine-0")
        yield endpoint, sessions, inbox, target_commands
    finally:
        for session in sessions.values():
            session.close()


@pytest.fixture
def intruders():
    opened: list[zenoh.Session] = []
    yield opened
    for session in opened:
        session.close()


def test_target_fixes_reach_the_companion_over_mutual_tls(mesh):
    _, sessions, inbox, _ = mesh
    for i in range(1, 51):
        sessions["target"].put(FIX_KEY, f"genuine-{i}".encode())
    inbox.wait_for(FIX_KEY, b"genuine-50")
    assert inbox.on(FIX_KEY)[-50:] == [f"genuine-{i}".encode() for i in range(1, 51)]
    # Zenoh's own view of the companion's links: TLS, authenticated by the peers' certificate names.
    links = sessions["companion"].info.links()
    assert links and all(link_.dst.startswith("tls/") for link_ in links)
    assert {link_.auth_identifier for link_ in links} == {"plant", "target"}


def test_a_peer_without_a_certificate_cannot_join(mesh, certs, intruders, capfd):
    endpoint, sessions, inbox, _ = mesh
    capfd.readouterr()
    intruder = _intruder(endpoint, certs / "ca.pem", None, None)  # trusts our CA, has no certificate of its own
    intruders.append(intruder)
    heard = Inbox(intruder, "bof/target/**")  # what the genuine target publishes; the intruder puts elsewhere
    refusals = []
    _until(lambda: refusals.append(count_tls_refusals(capfd.readouterr().out)) or sum(refusals) >= 2,
           "the plant's Zenoh to log two refused handshakes")
    for i in range(20):
        intruder.put(COMMAND_KEY, b"abort from nobody")
        sessions["target"].put(FIX_KEY, f"after-{i}".encode())
    inbox.wait_for(FIX_KEY, b"after-19")
    assert inbox.on(COMMAND_KEY) == []
    assert heard.samples == []
    assert intruder.info.links() == []


def test_a_certificate_from_another_ca_cannot_join(mesh, certs, foreign_certs, intruders, capfd):
    endpoint, sessions, inbox, _ = mesh
    capfd.readouterr()
    # Trusting our CA (so it would accept the plant) but presenting a 'gcs' certificate of its own CA.
    intruder = _intruder(endpoint, certs / "ca.pem", foreign_certs, "gcs")
    intruders.append(intruder)
    heard = Inbox(intruder, "bof/target/**")  # what the genuine target publishes; the intruder puts elsewhere
    refusals = []
    _until(lambda: refusals.append(count_tls_refusals(capfd.readouterr().out)) or sum(refusals) >= 2,
           "the plant's Zenoh to log two refused handshakes")
    for i in range(20):
        intruder.put(COMMAND_KEY, b"abort from a foreign CA")
        sessions["target"].put(FIX_KEY, f"after-{i}".encode())
    inbox.wait_for(FIX_KEY, b"after-19")
    assert inbox.on(COMMAND_KEY) == []
    assert heard.samples == []
    assert intruder.info.links() == []


def test_a_plain_tcp_peer_cannot_join_a_tls_listener(mesh, intruders, capfd):
    endpoint, sessions, inbox, _ = mesh
    capfd.readouterr()
    intruder = zenoh.open(_config([], ["tcp/" + endpoint.removeprefix("tls/")], None))
    intruders.append(intruder)
    heard = Inbox(intruder, "bof/target/**")
    refusals = []
    _until(lambda: refusals.append(count_tls_refusals(capfd.readouterr().out)) or sum(refusals) >= 2,
           "the plant's Zenoh to log two refused handshakes")
    for i in range(20):
        intruder.put(COMMAND_KEY, b"abort over plain TCP")
        sessions["target"].put(FIX_KEY, f"after-{i}".encode())
    inbox.wait_for(FIX_KEY, b"after-19")
    assert inbox.on(COMMAND_KEY) == [] and heard.samples == [] and intruder.info.links() == []


def test_the_target_identity_cannot_command_even_without_access_control_of_its_own(mesh, certs, intruders):
    """A peer holding the genuine target certificate (a stolen key, or the target itself) joins,
    and may publish fixes, but the companion's and the target's Zenoh drop its commands on ingress."""
    endpoint, sessions, inbox, target_commands = mesh
    intruder = _intruder(endpoint, certs / "ca.pem", certs, "target")
    intruders.append(intruder)
    _put_until_heard(intruder, inbox, FIX_KEY, b"intruder fix")  # joined: it may publish fixes
    _until(lambda: "companion" in {l.auth_identifier for l in intruder.info.links()}, "a direct link to the companion")
    for i in range(10):
        intruder.put(COMMAND_KEY, link.encode_command(link.Command("intruder", i, 1.0, "abort")))
        intruder.put(TARGET_COMMAND_KEY, link.encode_command(link.Command("intruder", i, 1.0, "start")))
        intruder.put("bof/sim/clock", link.encode_clock(link.ClockTick("intruder", i, 1e6)))
        intruder.put("bof/companion/pursuer-1/state", b"{}")
    intruder.put(FIX_KEY, b"intruder fix after")
    inbox.wait_for(FIX_KEY, b"intruder fix after")
    assert inbox.on(COMMAND_KEY) == [] and inbox.on(TARGET_COMMAND_KEY) == []
    assert inbox.on("bof/sim/clock") == [] and inbox.on("bof/companion/pursuer-1/state") == []
    assert target_commands.samples == []


def test_the_gcs_identity_commands_but_cannot_publish_fixes(mesh, certs, intruders):
    endpoint, sessions, inbox, target_commands = mesh
    gcs = _intruder(endpoint, certs / "ca.pem", certs, "gcs")  # the genuine ground station, no ACL of its own
    intruders.append(gcs)
    _put_until_heard(gcs, inbox, COMMAND_KEY, b"probe")
    for i in range(10):
        gcs.put(FIX_KEY, f"fix from the gcs {i}".encode())
    gcs.put(COMMAND_KEY, b"abort from the gcs")
    gcs.put(TARGET_COMMAND_KEY, b"start from the gcs")
    inbox.wait_for(COMMAND_KEY, b"abort from the gcs")
    target_commands.wait_for(TARGET_COMMAND_KEY, b"start from the gcs")
    assert not [payload for payload in inbox.on(FIX_KEY) if payload.startswith(b"fix from the gcs")]


def test_plain_mode_still_links_and_says_it_is_unauthenticated():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    plant = open_session(zenoh_config(listen=[endpoint]))
    companion = open_session(zenoh_config(connect=[endpoint]))
    target = open_session(zenoh_config(connect=[endpoint]))
    try:
        inbox = Inbox(companion)
        _put_until_heard(target, inbox, FIX_KEY, b"plain fix")
        assert {link_.auth_identifier for link_ in companion.info.links()} == {None}
    finally:
        for session in (target, companion, plant):
            session.close()
    assert "UNAUTHENTICATED" in link_security(None)


def test_secure_configuration_takes_only_tls_endpoints(certs):
    identity = tls_identity(certs, "companion")
    with pytest.raises(LinkError, match="not TLS"):
        zenoh_config(connect=["tcp/127.0.0.1:7447"], tls=identity)
    with pytest.raises(LinkError, match="not TLS"):
        zenoh_config(listen=["tcp/127.0.0.1:0"], tls=identity)
    line = link_security(identity)
    assert "'companion'" in line and "bof/companion/*/state" in line and "\n" not in line
    assert set(PUBLISH_RIGHTS) == set(pki.ROLES)


# --------------------------------------------------------------------- whole chain
def test_bof_sitl_secure_flies_and_refuses_intruders(tmp_path):
    """bof-sitl --secure on a short flight: every process on mutual TLS, the flight completes, and
    during it a peer without a certificate is refused (counted by the plant's Zenoh) and a peer
    with the stolen target key cannot abort the companion (dropped by the companion's Zenoh)."""
    from studies import full_sitl
    from interfaces.scenario import SCENARIOS_DIR

    scenario = (SCENARIOS_DIR / "constant_velocity.toml").read_text()
    vehicle = (SCENARIOS_DIR / "../vehicles/paper_table1.toml").resolve()
    scenario = scenario.replace('vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{vehicle}"')
    scenario = re.sub(r"(?m)^duration = 60\.0$", "duration = 25.0", scenario)
    scenario = re.sub(r"(?m)^summary_window = 20\.0$", "summary_window = 10.0", scenario)
    config = tmp_path / "short.toml"
    config.write_text(scenario)
    out = tmp_path / "runs"
    attack: dict = {}
    PROBE = b"probe " * 111  # 666 bytes: no genuine fix is that long

    def on_state(state, engaged_at):
        if engaged_at is None or attack or state is None or state.phase != "following":
            return
        folder = next(out.iterdir())
        endpoint = re.search(r"connect \['(tls/[^']+)'\]", (folder / "target.out").read_text())[1]
        attack["nobody"] = _intruder(endpoint, folder / "pki" / "ca.pem", None, None)
        attack["stolen"] = stolen = _intruder(endpoint, folder / "pki" / "ca.pem", folder / "pki", "target")
        _until(lambda: "companion" in {l.auth_identifier for l in stolen.info.links()}, "a link to the companion")
        time.sleep(0.5)  # the companion's subscriber declarations reach the new peer
        for seq in range(20):
            abort = link.encode_command(link.Command("ground-station", 10_000 + seq, state.stamp, "abort"))
            stolen.put(COMMAND_KEY, abort)
            attack["nobody"].put(COMMAND_KEY, abort)
        stolen.put(FIX_KEY, PROBE)  # after the aborts on the same link: proves the link carried them

    try:
        code, folder, summary = full_sitl.run(config, out, 5.0, seed=1, timeout=240.0, plots=False, quiet=True,
                                              on_state=on_state, secure=True)
    finally:
        for session in attack.values():
            session.close()
    assert attack, "the companion never engaged"
    assert code == 0, (folder / "companion.out").read_text()[-3000:]
    assert summary["companion"]["phase"] == "done" and summary["abort_sent"] is False
    assert summary["zenoh"]["secure"] is True
    assert summary["zenoh"]["tls_refused"]["plant"] >= 1  # the certificate-less peer, at the plant's listener
    events = [json.loads(line) for line in (folder / "companion" / "events.jsonl").read_text().splitlines()]
    assert not [e for e in events if e["kind"] in ("command", "command_rejected")]
    received = [json.loads(line) for line in (folder / "companion" / "zenoh_rx.jsonl").read_text().splitlines()]
    assert [r["verdict"] for r in received if r.get("bytes") == len(PROBE)] == ["rejected"]  # the probe arrived
    assert [e["role"] for e in events if e["kind"] == "zenoh_security"] == ["companion"]
    for role in ("plant", "target", "companion"):
        assert f"mutual TLS as '{role}'" in (folder / f"{role}.out").read_text()
    assert summary["companion"]["link"]["accepted"] > 0
    for name in ("ca.key", "target.key"):
        assert stat.S_IMODE((folder / "pki" / name).stat().st_mode) == 0o600


# ------------------------------------------------------------ plain links stay on loopback
PORTS = st.integers(0, 65535)
PROTOCOLS = st.sampled_from(["tcp", "tls", "udp", "quic", "ws"])
HOSTNAMES = st.from_regex(r"[A-Za-z][A-Za-z0-9\-]{0,20}(\.[A-Za-z][A-Za-z0-9\-]{0,20}){0,3}", fullmatch=True)


@settings(max_examples=300, deadline=None)
@given(protocol=PROTOCOLS, port=PORTS, address=st.ip_addresses(v=4))
def test_an_ipv4_endpoint_is_loopback_exactly_when_it_is_in_127_0_0_0_8(protocol, port, address):
    expected = address in ipaddress.ip_network("127.0.0.0/8")
    assert endpoint_is_loopback(f"{protocol}/{address}:{port}") is expected


@settings(max_examples=300, deadline=None)
@given(protocol=PROTOCOLS, port=PORTS, address=st.ip_addresses(v=6))
def test_a_bracketed_ipv6_endpoint_is_loopback_only_for_ipv6_or_mapped_loopback(protocol, port, address):
    loopback = address == ipaddress.IPv6Address("::1") or (
        address.ipv4_mapped is not None and address.ipv4_mapped in ipaddress.ip_network("127.0.0.0/8"))
    assert endpoint_is_loopback(f"{protocol}/[{address}]:{port}") is loopback
    assert endpoint_is_loopback(f"{protocol}/[{address}]:{port}#iface=lo") is loopback


@settings(max_examples=300, deadline=None)
@given(protocol=PROTOCOLS, port=PORTS, host=HOSTNAMES)
def test_no_host_name_is_loopback_but_localhost(protocol, port, host):
    assert endpoint_is_loopback(f"{protocol}/{host}:{port}") is (host == "localhost")


@pytest.mark.parametrize("endpoint, loopback", [
    ("tcp/127.0.0.1:7447", True), ("tcp/127.255.0.9:1", True), ("tcp/[::1]:7447", True), ("tcp/localhost:7447", True),
    ("tls/[::ffff:127.0.0.1]:7447", True), ("tcp/0.0.0.0:7447", False), ("tcp/[::]:7447", False),
    ("tcp/192.0.2.1:7447", False), ("tcp/128.0.0.1:7447", False), ("tcp/LOCALHOST:7447", False),
    ("tcp/localhost.example.org:7447", False), ("tcp/127.0.0.1.example.org:7447", False),
    ("udp/224.0.0.224:7447", False), ("tcp/[fe80::1]:7447", False),
])
def test_loopback_endpoints_by_example(endpoint, loopback):
    assert endpoint_is_loopback(endpoint) is loopback


def test_the_default_session_is_loopback_only_and_multicast_scouting_is_off():
    for config in (zenoh_config(), zenoh_config(connect=["tcp/127.0.0.1:7447"]),
                   zenoh_config("client", connect=["tcp/[::1]:7447"]), zenoh_config(listen=["tcp/localhost:7447"])):
        assert json.loads(config.get_json("scouting/multicast/enabled")) is False
        assert remote_exposure(config) is None
        check_exposure(config, None)
    # Zenoh's own defaults listen on every interface and scout by multicast: both are exposure.
    bare = zenoh.Config()
    assert remote_exposure(bare) == "listen endpoint 'tcp/[::]:0' is not loopback"
    bare.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    assert remote_exposure(bare) == "multicast scouting is on (it finds peers on every network)"
    bare.insert_json5("scouting/multicast/enabled", "false")
    assert remote_exposure(bare) is None


@pytest.mark.parametrize("kwargs, named", [
    ({"connect": ["tcp/127.0.0.1:7447", "tcp/192.0.2.1:7447"]}, "connect endpoint 'tcp/192.0.2.1:7447'"),
    ({"listen": ["tcp/0.0.0.0:7447"], "allow_remote_listen": True}, "listen endpoint 'tcp/0.0.0.0:7447'"),
    ({"listen": ["tcp/[::]:0"], "allow_remote_listen": True}, "listen endpoint 'tcp/[::]:0'"),
    ({"overrides": {"connect.endpoints": '["tcp/198.51.100.7:7447"]'}}, "connect endpoint 'tcp/198.51.100.7:7447'"),
    ({"overrides": {"connect/endpoints": '{peer: ["udp/example.org:7447"]}'}},
     "connect endpoint 'udp/example.org:7447'"),
    ({"overrides": {"scouting.multicast.enabled": "true"}}, "multicast scouting is on"),
])
def test_a_plain_session_beyond_loopback_is_refused_unless_insecure(kwargs, named):
    config = zenoh_config(**kwargs)
    with pytest.raises(LinkError) as refusal:
        check_exposure(config, None)
    message = str(refusal.value)
    assert named in message and "--zenoh-tls DIR" in message and "--insecure" in message and "\n" not in message
    check_exposure(config, None, insecure=True)


def test_a_tls_identity_may_connect_and_listen_beyond_loopback(certs):
    from companion.app import link_config
    from interfaces.scenario import LinkConfig

    identity = tls_identity(certs, "companion")
    config = link_config(LinkConfig(), ("tls/0.0.0.0:7447",), ("tls/192.0.2.1:7447",), identity)
    assert json.loads(config.get_json("connect/endpoints")) == ["tls/192.0.2.1:7447"]
    with pytest.raises(LinkError, match="'tcp/192.0.2.1:7447' is not loopback"):
        link_config(LinkConfig(), (), ("tcp/192.0.2.1:7447",), None)


def test_the_start_line_says_unauthenticated_and_whether_insecure_was_asked_for():
    plain, insecure = link_security(None), link_security(None, insecure=True)
    assert plain.startswith("Zenoh link UNAUTHENTICATED: ") and "--insecure" not in plain
    assert insecure.startswith("Zenoh link UNAUTHENTICATED, as asked by --insecure: ") and "\n" not in insecure


def test_companion_refuses_a_plain_remote_endpoint_before_opening_anything(tmp_path):
    """`companion --zenoh-connect tcp/192.0.2.1:7447` (a documentation address): exit 2, one line on stderr naming
    the endpoint and both ways out, and nothing made (no run folder, no socket: it ends before the console)."""
    result = subprocess.run([sys.executable, "-m", "companion", "--zenoh-connect", "tcp/192.0.2.1:7447"],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr.strip().splitlines() == [
        "companion: Zenoh connect endpoint 'tcp/192.0.2.1:7447' is not loopback and the link would be unauthenticated "
        "(anyone who reaches it could publish fixes or an abort): use --zenoh-tls DIR for mutual TLS and access "
        "control, or --insecure to accept an unauthenticated link"]
    assert result.stdout == "" and list(tmp_path.iterdir()) == []
    listen = subprocess.run([sys.executable, "-m", "companion", "--zenoh-listen", "tcp/0.0.0.0:7447"],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert listen.returncode == 2 and "listen endpoint 'tcp/0.0.0.0:7447' is not loopback" in listen.stderr


def test_companion_with_insecure_starts_and_says_the_link_is_unauthenticated(tmp_path):
    """With --insecure the same endpoint passes the check: the companion goes on and its first line says that its
    link is unauthenticated as asked (it would then load its kernels and wait for an autopilot nobody runs; the
    test stops it there)."""
    command = [sys.executable, "-m", "companion", "--zenoh-connect", "tcp/192.0.2.1:7447", "--insecure",
               "--mavlink", f"udpin://127.0.0.1:{free_port()}", "--log-dir", str(tmp_path / "companion")]
    child = ChildProcess(command, tmp_path / "companion.out", ready="companion: Zenoh link")
    try:
        child.start(timeout=120.0)
        line = child.wait_for_line("companion: Zenoh link", 1.0)
        assert line.startswith("companion: Zenoh link UNAUTHENTICATED, as asked by --insecure: "), line
        assert child.running  # past the check: it refuses in about a second when it refuses
    finally:
        child.stop()
    assert not child.running
