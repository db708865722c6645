"""Several pursuers: the bof.pursuer_share/1 payload, the [swarm] scenario schema, the scenario files."""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import threading
import tomllib
from collections import Counter

import numpy as np
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from interfaces import link_schema as link
from interfaces.link_schema import (REASONS, PayloadError, PursuerShare, SharedBearing, SharedEstimate,
                                    decode_pursuer_share, encode_pursuer_share, pursuer_share_key)
from interfaces.neighbour_link import NeighbourLink
from interfaces.scenario import (SCENARIOS_DIR, VEHICLES_DIR, ConfigError, Scenario, SwarmLinkConfig,
                                 load_plant_scenario, load_scenario, pursuer_starts, share_rate_hz)

FUZZ = settings(max_examples=300, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
SWARM_FILES = ("swarm_circumnavigation", "seed002_circumnavigation", "seed002_circumnavigation_scaled",
               "seed004_standoff", "swarm_turning")


# --- the payload -------------------------------------------------------------------

def _share_document(**changes) -> dict:
    document = {"schema": "bof.pursuer_share/1", "sender": 2, "seq": 7, "stamp": 12.5, "epoch": 99,
                "position": [10.0, -4.0, -20.0], "velocity": [1.0, 2.0, 0.0],
                "bearing": {"stamp": 12.4, "direction": [0.6, 0.8, 0.0], "position": [9.9, -4.2, -20.0]},
                "estimate": {"stamp": 12.5, "position": [40.0, 0.0, -20.0], "velocity": [3.0, 4.0, 0.0],
                             "covariance": np.diag([4.0, 4.0, 1.0, 0.5, 0.5, 0.1]).ravel().tolist()}}
    document.update(changes)
    return document


def _with(path: tuple, value) -> dict:
    """_share_document() with the entry at `path` (keys / indices) replaced by `value`."""
    document = _share_document()
    place = document
    for key in path[:-1]:
        place = place[key]
    place[path[-1]] = value
    return document


def _bytes(document) -> bytes:
    return json.dumps(document).encode()


def test_share_key_follows_the_key_scheme_and_zenoh_matches_it():
    assert pursuer_share_key(1) == "bof/swarm/1/share"
    assert pursuer_share_key(np.int64(255)) == "bof/swarm/255/share"
    wildcard = zenoh.KeyExpr(link.PURSUER_SHARE_ALL)
    for ident in (1, 2, 17, 255):
        assert wildcard.includes(zenoh.KeyExpr(pursuer_share_key(ident)))
    assert not wildcard.intersects(zenoh.KeyExpr(link.target_fix_key("target-1")))
    assert not wildcard.intersects(zenoh.KeyExpr(link.companion_state_key("pursuer-1")))
    for bad in (0, -1, 256, True, "3", 2.0, None):
        with pytest.raises(ValueError, match="pursuer id"):
            pursuer_share_key(bad)


def test_a_share_decodes_to_what_it_says():
    share = decode_pursuer_share(_bytes(_share_document()))
    assert share.sender == 2 and share.seq == 7 and share.stamp == 12.5 and share.epoch == 99
    assert share.position == (10.0, -4.0, -20.0) and share.velocity == (1.0, 2.0, 0.0)
    assert share.bearing == SharedBearing(12.4, (0.6, 0.8, 0.0), (9.9, -4.2, -20.0))
    assert share.estimate.covariance_matrix.shape == (6, 6)
    assert np.array_equal(share.estimate.covariance_matrix, np.diag([4.0, 4.0, 1.0, 0.5, 0.5, 0.1]))


def test_bearing_and_estimate_are_optional_and_the_covariance_may_be_nested():
    without = _share_document(bearing=None)
    del without["estimate"]
    share = decode_pursuer_share(_bytes(without))
    assert share.bearing is None and share.estimate is None
    del without["bearing"]
    assert decode_pursuer_share(_bytes(without)) == share
    nested = _with(("estimate", "covariance"), np.diag([4.0, 4.0, 1.0, 0.5, 0.5, 0.1]).tolist())
    assert decode_pursuer_share(_bytes(nested)) == decode_pursuer_share(_bytes(_share_document()))
    # The encoder writes the flat form, and only what is there.
    payload = json.loads(encode_pursuer_share(share))
    assert "bearing" not in payload and "estimate" not in payload
    assert len(json.loads(encode_pursuer_share(decode_pursuer_share(_bytes(nested))))["estimate"]["covariance"]) == 36


ROTATION = np.array([[0.0, -1.0], [1.0, 0.0]])
SHARE_REFUSALS = [
    (_share_document(sender=0), "bad_sender"),
    (_share_document(sender=256), "bad_sender"),
    (_share_document(sender="2"), "wrong_type"),
    (_share_document(sender=True), "wrong_type"),
    (_share_document(sender=2.0), "wrong_type"),
    (_share_document(schema="bof.pursuer_share/2"), "wrong_schema"),
    (_share_document(schema="bof.target_fix/2"), "wrong_schema"),
    ({k: v for k, v in _share_document().items() if k != "epoch"}, "missing_field"),
    ({k: v for k, v in _share_document().items() if k != "velocity"}, "missing_field"),
    (_share_document(colour="red"), "unknown_field"),
    (_with(("bearing", "noise"), 0.1), "unknown_field"),
    (_with(("bearing", "stamp"), 12.6), "out_of_range"),              # taken after it was shared
    (_with(("estimate", "stamp"), 13.0), "out_of_range"),
    (_with(("bearing", "direction"), [0.0, 0.0, 0.0]), "out_of_range"),
    (_with(("bearing", "direction"), [1e-3, 0.0, 0.0]), "out_of_range"),
    (_with(("bearing", "direction"), [99.0, 99.0, 0.0]), "out_of_range"),
    (_with(("bearing", "direction"), [1.0, 0.0]), "wrong_type"),
    (_with(("bearing", "position"), [0.0, 2e6, 0.0]), "out_of_range"),
    (_with(("position",), [0.0, float("nan"), 0.0]), "not_finite"),
    (_with(("velocity",), [0.0, 0.0, 1001.0]), "out_of_range"),
    (_with(("estimate", "covariance"), [1.0] * 35), "wrong_type"),
    (_with(("estimate", "covariance"), [1.0] * 37), "wrong_type"),
    (_with(("estimate", "covariance"), [[1.0] * 6] * 5 + [[1.0] * 5]), "wrong_type"),
    (_with(("estimate", "covariance"), [float("inf")] + [0.0] * 35), "not_finite"),
    (_with(("estimate", "covariance"), [1e13] + [0.0] * 35), "out_of_range"),
    (_with(("estimate", "covariance"), ["1.0"] + [0.0] * 35), "wrong_type"),
    # not symmetric: one off-diagonal entry
    (_with(("estimate", "covariance", 1), 0.5), "bad_covariance"),
    # symmetric but indefinite: [[1, 2], [2, 1]] has eigenvalues 3 and -1
    (_with(("estimate", "covariance"), np.kron(np.eye(3), [[1.0, 2.0], [2.0, 1.0]]).ravel().tolist()),
     "bad_covariance"),
    # a negative variance
    (_with(("estimate", "covariance"), np.diag([-1e-3, 1, 1, 1, 1, 1]).ravel().tolist()), "bad_covariance"),
]


@pytest.mark.parametrize("document, reason", SHARE_REFUSALS)
def test_every_malformed_share_gets_its_reason(document, reason):
    with pytest.raises(PayloadError) as error:
        decode_pursuer_share(_bytes(document))
    assert error.value.reason == reason
    assert str(error.value).startswith(reason)


def test_a_semidefinite_covariance_is_accepted():
    # Rank 1 (a line of sight with no information across it): PSD, eigenvalues 0 and 2.
    semidefinite = np.kron(np.eye(3), [[1.0, 1.0], [1.0, 1.0]]).ravel().tolist()
    assert decode_pursuer_share(_bytes(_with(("estimate", "covariance"), semidefinite))).estimate is not None


def test_the_encoder_refuses_what_the_decoder_would():
    good = decode_pursuer_share(_bytes(_share_document()))
    indefinite = SharedEstimate(1.0, (0, 0, 0), (0, 0, 0), np.kron(np.eye(3), [[1.0, 2.0], [2.0, 1.0]]))
    for share, reason in (
        (PursuerShare(0, 0, 0.0, 1, (0, 0, 0), (0, 0, 0)), "bad_sender"),
        (PursuerShare(1, -1, 0.0, 1, (0, 0, 0), (0, 0, 0)), "out_of_range"),
        (PursuerShare(1, 0, math.nan, 1, (0, 0, 0), (0, 0, 0)), "not_finite"),
        (PursuerShare(1, 0, 2.0, 1, (0, 0, 0), (0, 0, 0), estimate=indefinite), "bad_covariance"),
        (PursuerShare(1, 0, 0.5, 1, (0, 0, 0), (0, 0, 0), SharedBearing(1.0, (1, 0, 0), (0, 0, 0))), "out_of_range"),
        (PursuerShare(1, 0, 1.0, 1, (0, 0, 0), (0, 0, 0), SharedBearing(1.0, (0, 0, 0), (0, 0, 0))), "out_of_range"),
    ):
        with pytest.raises(PayloadError) as error:
            encode_pursuer_share(share)
        assert error.value.reason == reason
    assert decode_pursuer_share(encode_pursuer_share(good)) == good


def test_shares_cross_a_real_loopback_session_and_a_broken_one_is_only_counted():
    """Pursuers 2 and 3 publish on their keys; pursuer 1 hears both on the wildcard, refuses a broken payload
    with its reason and passes each share through its NeighbourLink on receipt."""
    from interfaces.zenoh_transport import open_session, publisher, zenoh_config
    from studies.processes import free_port, poll_until

    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    listener = open_session(zenoh_config(listen=[endpoint]))
    talker = None
    try:
        talker = open_session(zenoh_config(connect=[endpoint]))
        received, refused, lock = [], Counter(), threading.Lock()

        def on_share(sample):
            try:
                share = decode_pursuer_share(sample.payload)
            except PayloadError as error:
                with lock:
                    refused[error.reason] += 1
                return
            with lock:
                received.append((str(sample.key_expr), share))

        subscriber = listener.declare_subscriber(link.PURSUER_SHARE_ALL, on_share)
        outlets = {ident: publisher(talker, pursuer_share_key(ident)) for ident in (2, 3)}
        assert poll_until(lambda: all(o.matching_status.matching for o in outlets.values()), 10.0), "no subscriber seen"
        sent, where = [], {2: (10.0, 0.0, -10.0), 3: (30.0, 0.0, -10.0)}   # 14.1 m and 31.6 m from pursuer 1
        for seq in range(20):
            for ident, outlet in outlets.items():
                share = PursuerShare(ident, seq, 0.2 * seq, 40 + ident, where[ident], (1.0, 0.0, 0.0),
                                     SharedBearing(0.2 * seq, (0.6, -0.8, 0.0), where[ident]))
                outlet.put(encode_pursuer_share(share))
                sent.append(share)
        outlets[2].put(_bytes(_with(("estimate", "covariance", 1), 0.5)))
        assert poll_until(lambda: len(received) >= len(sent) and refused, 10.0), f"{len(received)} of {len(sent)}"
        subscriber.undeclare()
        with lock:
            by_sender = sorted(received, key=lambda item: (item[1].sender, item[1].seq))
            assert by_sender == [(pursuer_share_key(s.sender), s) for s in sorted(sent, key=lambda s: (s.sender, s.seq))]
            assert refused == {"bad_covariance": 1}
        # on receipt, pursuer 1 at the origin decides each share with its link (radius 25 m: pursuer 3 is out of reach)
        neighbour_link = NeighbourLink(SwarmLinkConfig(radius=25.0), pursuers=3)
        fates = Counter(neighbour_link.transmit(share.stamp, share.sender, 1, np.array(share.position),
                                                np.zeros(3)).reason or "delivered" for _, share in received)
        assert fates == {"delivered": 20, "out_of_radius": 20}
    finally:
        if talker is not None:
            talker.close()
        listener.close()


# Valid shares, drawn from the documented domain (module docstring of interfaces.link_schema).
coordinate = st.floats(-1e6, 1e6)
speed = st.floats(-1e3, 1e3)
stamps = st.floats(0.0, 1e9)


@st.composite
def shares(draw) -> PursuerShare:
    stamp = draw(stamps)
    bearing = None
    if draw(st.booleans()):
        direction = draw(st.tuples(*[st.floats(-50.0, 50.0)] * 3).filter(lambda d: 0.02 < math.hypot(*d) < 99.0))
        bearing = SharedBearing(draw(st.floats(0.0, stamp)), direction, draw(st.tuples(coordinate, coordinate, coordinate)))
    estimate = None
    if draw(st.booleans()):
        # A A^T is positive semidefinite; (M + M^T) / 2 makes it exactly symmetric in floating point.
        factor = np.array(draw(st.lists(st.floats(-1e5, 1e5), min_size=36, max_size=36))).reshape(6, 6)
        product = factor @ factor.T
        estimate = SharedEstimate(draw(st.floats(0.0, stamp)), draw(st.tuples(coordinate, coordinate, coordinate)),
                                  draw(st.tuples(speed, speed, speed)), 0.5 * (product + product.T))
    return PursuerShare(draw(st.integers(1, 255)), draw(st.integers(0, 2**63 - 1)), stamp,
                        draw(st.integers(0, 2**63 - 1)), draw(st.tuples(coordinate, coordinate, coordinate)),
                        draw(st.tuples(speed, speed, speed)), bearing, estimate)


@FUZZ
@given(shares())
def test_round_trip(share):
    payload = encode_pursuer_share(share)
    assert len(payload) <= link.MAX_PAYLOAD_BYTES
    assert decode_pursuer_share(payload) == share


def _bits(value):
    """A share (or any part of it) as nested tuples of (type, exact value): floats by their hex form, so -0.0 and
    0.0 differ and an int is not a float."""
    if dataclasses.is_dataclass(value):
        return (type(value).__name__, tuple(_bits(getattr(value, f.name)) for f in dataclasses.fields(value)))
    if isinstance(value, tuple):
        return tuple(_bits(item) for item in value)
    return (type(value).__name__, value.hex() if type(value) is float else value)


# Shares from anywhere, valid or not: every number of any size and sign, NaN and infinities, integers where the
# schema wants floats, stamps after the share's, covariances that are not symmetric or not semidefinite. Each
# field is mostly valid (so that about a third of the shares are), with exact integers and signed zeros among them.
anything = st.one_of(st.floats(), st.integers(-2**64, 2**64), st.sampled_from([0.0, -0.0, 1e-300, 1e300]))


def _mostly(valid, other=anything):
    """`valid` seven times in eight, else `other`."""
    return st.integers(0, 7).flatmap(lambda pick: other if pick == 0 else valid)


@st.composite
def any_shares(draw) -> PursuerShare:
    number = st.one_of(st.floats(-900.0, 900.0), st.integers(-900, 900), st.sampled_from([0.0, -0.0]))
    vector = lambda: draw(_mostly(st.tuples(number, number, number), st.tuples(anything, anything, anything)))
    stamp_of = lambda: draw(_mostly(st.one_of(stamps, st.integers(0, 10**9), st.sampled_from([0.0, -0.0]))))
    stamp = stamp_of()
    section_stamp = lambda: draw(_mostly(st.just(stamp), st.one_of(stamps, anything)))
    bearing = estimate = None
    if draw(st.booleans()):
        bearing = SharedBearing(section_stamp(), draw(_mostly(st.tuples(*[st.floats(-120.0, 120.0)] * 3),
                                                         st.tuples(*[st.floats(-0.02, 0.02)] * 3))), vector())
    if draw(st.booleans()):
        factor = np.array(draw(st.lists(st.floats(-1e5, 1e5), min_size=36, max_size=36))).reshape(6, 6)
        covariance = draw(_mostly(st.just(factor @ factor.T), st.sampled_from([factor, 0.5 * (factor + factor.T)])))
        estimate = SharedEstimate(section_stamp(), vector(), vector(), covariance)
    return PursuerShare(draw(_mostly(st.integers(1, 255), st.one_of(st.integers(-2, 300), st.booleans()))),
                        draw(_mostly(st.integers(0, 2**63 - 1), st.integers(-2**64, 2**64))), stamp,
                        draw(_mostly(st.integers(0, 2**63 - 1), st.integers(-2**64, 2**64))), vector(), vector(),
                        bearing, estimate)


def _check_in_process(share: PursuerShare) -> None:
    try:
        decoded = decode_pursuer_share(encode_pursuer_share(share))
    except PayloadError as error:
        with pytest.raises(PayloadError) as refused:
            link.checked_pursuer_share(share)
        assert refused.value.reason == error.reason
        return
    assert _bits(link.checked_pursuer_share(share)) == _bits(decoded)


@FUZZ
@given(shares())
def test_a_checked_valid_share_is_the_encoded_one_decoded_bit_for_bit(share):
    """The in-process harness's shortcut (checked_pursuer_share) against the wire: encode, then decode."""
    _check_in_process(share)


@FUZZ
@given(any_shares())
def test_a_checked_share_is_the_encoded_one_decoded_or_refused_for_the_same_reason(share):
    _check_in_process(share)


@FUZZ
@given(st.lists(st.one_of(st.floats(), st.sampled_from([0.0, -0.0])), min_size=36, max_size=36))
def test_a_flat_covariance_of_floats_gives_the_rows_the_general_path_gives(entries):
    """SharedEstimate keeps 36 flat floats as six slices; a (6, 6) array goes through numpy (the general path)."""
    flat = SharedEstimate(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), tuple(entries))
    general = SharedEstimate(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), np.array(entries).reshape(6, 6))
    assert _bits(flat.covariance) == _bits(general.covariance)
    assert all(type(row) is tuple and len(row) == 6 for row in flat.covariance)


def _number(value) -> bool:
    return type(value) in (int, float) and math.isfinite(value)


def _vector(value, bound: float) -> bool:
    return type(value) is list and len(value) == 3 and all(_number(v) and abs(v) <= bound for v in value)


def _independently_valid(document) -> bool | None:
    """The documented rules read straight off the JSON document (plain Python and numpy, not the schema):
    True valid, False invalid, None within a factor 2 of a covariance tolerance or a section stamped after its
    share by at most the documented 1e-6 s (either verdict is right)."""
    if type(document) is not dict or document.get("schema") != "bof.pursuer_share/1":
        return False
    allowed = {"schema", "sender", "seq", "stamp", "epoch", "position", "velocity", "bearing", "estimate"}
    if not set(document) <= allowed or not {"sender", "seq", "stamp", "epoch", "position", "velocity"} <= set(document):
        return False
    sender, seq, stamp, epoch = (document[key] for key in ("sender", "seq", "stamp", "epoch"))
    if not (type(sender) is int and 1 <= sender <= 255 and type(seq) is int and 0 <= seq < 2**63
            and type(epoch) is int and 0 <= epoch < 2**63 and _number(stamp) and 0 <= stamp <= 1e9):
        return False
    if not (_vector(document["position"], 1e6) and _vector(document["velocity"], 1e3)):
        return False
    bearing = document.get("bearing")
    if bearing is not None:
        if type(bearing) is not dict or set(bearing) != {"stamp", "direction", "position"}:
            return False
        if not (_number(bearing["stamp"]) and 0 <= bearing["stamp"] <= stamp + 2e-6 and _vector(bearing["direction"], 100)
                and 0.01 <= math.hypot(*bearing["direction"]) <= 100 and _vector(bearing["position"], 1e6)):
            return False
    estimate = document.get("estimate")
    if estimate is not None:
        if type(estimate) is not dict or set(estimate) != {"stamp", "position", "velocity", "covariance"}:
            return False
        if not (_number(estimate["stamp"]) and 0 <= estimate["stamp"] <= stamp + 2e-6 and _vector(estimate["position"], 1e6)
                and _vector(estimate["velocity"], 1e3)):
            return False
        entries = estimate["covariance"]
        if type(entries) is list and len(entries) == 6 and all(type(row) is list and len(row) == 6 for row in entries):
            entries = [v for row in entries for v in row]
        if not (type(entries) is list and len(entries) == 36 and all(_number(v) and abs(v) <= 1e12 for v in entries)):
            return False
        matrix = np.array(entries, dtype=float).reshape(6, 6)
        scale = max(1.0, float(np.abs(matrix).max()))
        asymmetry = float(np.abs(matrix - matrix.T).max())
        if asymmetry > 2e-9 * scale:
            return False
        # PSD by Cholesky factorisations of the matrix lifted by half and twice the documented tolerance (another
        # route than the decoder's eigenvalues): between the two the verdict may go either way.
        symmetric = 0.5 * (matrix + matrix.T)
        if not _factorises(symmetric + 2e-9 * scale * np.eye(6)):
            return False
        if asymmetry > 0.5e-9 * scale or not _factorises(symmetric + 0.5e-9 * scale * np.eye(6)):
            return None
    # within a factor 2 of the 1e-6 s a section may follow its share (above, more than 2e-6 s is refused)
    if any(section["stamp"] > stamp + 0.5e-6 for section in (bearing, estimate) if section is not None):
        return None
    return True


def _factorises(matrix: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        return False
    return True


def _meaning(document: dict) -> PursuerShare:
    """What a valid document says, read without the decoder."""
    bearing = document.get("bearing")
    estimate = document.get("estimate")
    return PursuerShare(
        document["sender"], document["seq"], float(document["stamp"]), document["epoch"], document["position"],
        document["velocity"],
        None if bearing is None else SharedBearing(float(bearing["stamp"]), bearing["direction"], bearing["position"]),
        None if estimate is None else SharedEstimate(float(estimate["stamp"]), estimate["position"],
                                                     estimate["velocity"], estimate["covariance"]))


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**64, 2**64) | st.floats() | st.text(max_size=8),
    lambda children: st.lists(children, max_size=7) | st.dictionaries(st.text(max_size=8), children, max_size=3),
    max_leaves=40)


def _paths(value, prefix=()):
    """Every (path, value) inside a JSON document, the root first."""
    yield prefix, value
    if isinstance(value, dict):
        for key, child in value.items():
            yield from _paths(child, (*prefix, key))
    elif isinstance(value, list):
        for index, child in enumerate(value):
            yield from _paths(child, (*prefix, index))


@st.composite
def mutated_documents(draw):
    document = json.loads(encode_pursuer_share(draw(shares())))
    for _ in range(draw(st.integers(1, 3))):
        paths = [path for path, _ in _paths(document)]
        path = draw(st.sampled_from(paths))
        kind = draw(st.sampled_from(["replace", "delete", "add", "nudge", "int"]))
        if not path:
            document = draw(json_values) if kind == "replace" else document
            if kind == "add" and isinstance(document, dict):
                document[draw(st.text(max_size=8))] = draw(json_values)
            continue
        parent = document
        for key in path[:-1]:
            parent = parent[key]
        key, value = path[-1], parent[path[-1]]
        if kind == "replace":
            parent[key] = draw(json_values)
        elif kind == "delete":
            del parent[key]
        elif kind == "add" and isinstance(value, dict):
            value[draw(st.text(max_size=8))] = draw(json_values)
        elif kind == "add" and isinstance(value, list):
            value.insert(draw(st.integers(0, len(value))), draw(json_values))
        elif kind == "nudge" and type(value) is float:
            parent[key] = value * draw(st.sampled_from([-1.0, 1.0 + 1e-12, 1e3, 0.0]))
        elif kind == "int" and type(value) is float and value.is_integer() and abs(value) < 2**53:
            parent[key] = int(value)  # 3 and 3.0 are the same number
    return document


def _check_decoding(payload: bytes, document) -> None:
    try:
        decoded = decode_pursuer_share(payload)
    except PayloadError as error:
        assert error.reason in REASONS
        assert _independently_valid(document) is not True, f"refused a valid share ({error})"
        return
    assert _independently_valid(document) is not False, "decoded a share the documented rules refuse"
    assert decoded == _meaning(document)


@FUZZ
@given(mutated_documents())
def test_a_mutated_share_decodes_to_its_meaning_or_is_refused(document):
    _check_decoding(json.dumps(document).encode(), document)


@FUZZ
@given(shares(), st.data())
def test_a_share_with_broken_bytes_is_refused_or_decodes_to_its_meaning(share, data):
    payload = bytearray(encode_pursuer_share(share))
    action = data.draw(st.sampled_from(["truncate", "flip", "insert", "delete"]))
    index = data.draw(st.integers(0, len(payload) - 1))
    if action == "truncate":
        del payload[index:]
    elif action == "flip":
        payload[index] ^= 1 << data.draw(st.integers(0, 7))
    elif action == "insert":
        payload.insert(index, data.draw(st.integers(0, 255)))
    else:
        del payload[index]
    try:
        document = json.loads(bytes(payload).decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        document = None
    _check_decoding(bytes(payload), document)


@FUZZ
@given(st.binary(max_size=400))
def test_arbitrary_bytes_raise_payload_error_only(payload):
    try:
        decode_pursuer_share(payload)
    except PayloadError as error:
        assert error.reason in REASONS


# --- the [swarm] schema --------------------------------------------------------------

BASE = (SCENARIOS_DIR / "constant_velocity.toml").read_text().replace(
    'vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{(VEHICLES_DIR / "paper_table1.toml").as_posix()}"')
THREE = """
[swarm]
guidance = "circumnavigation"
estimator = "shared_bearings"

[[swarm.pursuers]]

[[swarm.pursuers]]
initial_position = [80.0, -60.0, -20.0]

[[swarm.pursuers]]
initial_position = [70.0, 10.0, -25.0]
estimator_initial_position = [45.0, -22.0, -18.0]
"""


def _load(tmp_path, text: str):
    path = tmp_path / "scenario.toml"
    path.write_text(text)
    return load_scenario(path)[0]


@pytest.mark.parametrize("path", sorted(p for p in SCENARIOS_DIR.glob("*.toml") if p.stem not in SWARM_FILES),
                         ids=lambda p: p.stem)
def test_every_single_pursuer_scenario_stays_one_pursuer(path):
    scenario, _ = load_scenario(path)
    raw = tomllib.loads(path.read_text())
    assert scenario.swarm is None and scenario.pursuer_count == 1
    pursuer = raw.get("pursuer", {})
    estimator = raw["estimator"].get("initial_position")
    (start,) = pursuer_starts(scenario)
    assert start.ident == 1
    assert start.initial_position == tuple(pursuer.get("initial_position", (0.0, 0.0, 0.0)))
    assert start.initial_velocity == tuple(pursuer.get("initial_velocity", (0.0, 0.0, 0.0)))
    assert start.estimator_initial_position == (None if estimator is None else tuple(estimator))
    assert share_rate_hz(scenario) == raw.get("sensor", {}).get("rate_hz", 5.0)
    plant, _ = load_plant_scenario(path)
    assert plant.swarm is None and plant.pursuer_count == 1


def test_a_swarm_section_and_its_defaults(tmp_path):
    scenario = _load(tmp_path, BASE + THREE)
    swarm = scenario.swarm
    assert scenario.pursuer_count == swarm.count == 3
    starts = pursuer_starts(scenario)
    assert [s.ident for s in starts] == [1, 2, 3]
    assert starts[0].initial_position == (0.0, 0.0, 0.0) and starts[0].initial_velocity == (2.0, 0.0, 0.0)
    assert starts[1].initial_velocity == (0.0, 0.0, 0.0)
    assert starts[1].estimator_initial_position == (40.0, -20.0, -15.0)   # [estimator] initial_position
    assert starts[2].estimator_initial_position == (45.0, -22.0, -18.0)
    assert (swarm.min_separation, swarm.weave_min_angle_deg, share_rate_hz(scenario)) == (2.0, 15.0, 5.0)
    circ = swarm.circumnavigation
    assert (circ.g1, circ.g2, circ.g3, circ.alpha) == (1.2, 1.0, 0.4, 1.0)   # seed 002's gains
    assert swarm.link.radius == math.inf and swarm.link.loss_probability == 0.0 and swarm.link.seed is None
    assert _load(tmp_path, BASE + THREE.replace('guidance = "circumnavigation"',
                                                'guidance = "circumnavigation"\nshare_rate_hz = 10.0'))\
        .swarm.share_rate_hz == 10.0
    linked = _load(tmp_path, BASE + THREE + "\n[swarm.link]\nradius = inf\nseed = 4\n"
                   "blackouts = [{pursuer = 2, start = 10.0, end = 20.0}, {pursuer = 2, start = 20.0, end = 25.0}]\n")
    assert linked.swarm.link.radius == math.inf and len(linked.swarm.link.blackouts) == 2


SWARM_ERRORS = [
    (THREE + "\n[swarm.link]\nblackouts = [{pursuer = 4, start = 1.0, end = 2.0}]\n", "pursuer 4 does not exist"),
    (THREE + "\n[swarm.link]\nblackouts = [{pursuer = 0, start = 1.0, end = 2.0}]\n", "greater than or equal to 1"),
    (THREE + "\n[swarm.link]\nblackouts = [{pursuer = 1, start = 5.0, end = 5.0}]\n", "end (5) must be after start (5)"),
    (THREE + "\n[swarm.link]\nblackouts = [{pursuer = 1, start = 5.0, end = 9.0}, {pursuer = 1, start = 8.0, end = 12.0}]\n",
     "pursuer 1's windows [5, 9) and [8, 12) overlap"),
    (THREE + "\n[swarm.link]\nblackouts = [{pursuer = 1, start = 5.0}]\n", "end: Field required"),
    (THREE + "\n[swarm.link]\nradius = nan\n", "radius"),
    (THREE + "\n[swarm.link]\nradius = 0.0\n", "greater than 0"),
    (THREE + "\n[swarm.link]\nloss_probability = 1.5\n", "less than or equal to 1"),
    (THREE + "\n[swarm.link]\nlatency_s = -0.1\n", "greater than or equal to 0"),
    (THREE + "\n[swarm.link]\nloss = 0.1\n", "unknown key"),
    (THREE.replace('initial_position = [80.0, -60.0, -20.0]', 'initial_velocity = [0.0, 0.0, 0.0]'),
     "pursuers[1] (pursuer 2): initial_position is required"),
    (THREE.replace('[80.0, -60.0, -20.0]', '[0.5, 1.0, -1.0]'), "pursuers 1 and 2 start 1.5 m apart"),
    (THREE.replace('estimator = "shared_bearings"', 'estimator = "shared_bearings"\nmin_separation = 80.0'),
     "pursuers 1 and 3 start 75 m apart, closer than min_separation = 80 m"),
    (THREE.replace('estimator = "shared_bearings"', 'estimator = "shared_bearings"\nmin_separation = 50.0'),
     "3 pursuers equally spaced on a circle of radius 8 m (guidance.desired_range) are 13.9 m apart"),
    (THREE.replace('guidance = "circumnavigation"', 'guidance = "circle"'), "swarm.guidance"),
    (THREE.replace('estimator = "shared_bearings"', 'estimator = "kalman"'), "swarm.estimator"),
    (THREE + "\n[swarm.standoff]\nradius = 30.0\n", "[swarm.standoff] applies to guidance = 'standoff' only"),
    (THREE + "\n[swarm.triangulation]\nk1 = 2.0\n", "[swarm.triangulation] applies to estimator = 'triangulation_kf'"),
    (THREE.replace('guidance = "circumnavigation"', 'guidance = "standoff"') + "\n[swarm.standoff]\ninner_radius = 25.0\n",
     "inner_radius (25) must be below radius (20)"),
    (THREE.replace('guidance = "circumnavigation"', 'guidance = "standoff"') + "\n[swarm.standoff]\nspeed = 20.0\n",
     "speed (20) must lie in [min_speed, max_speed]"),
    (THREE + "\n[swarm.circumnavigation]\naltitude_offset = 8.0\n", "altitude_offset (8 m) must be smaller"),
    (THREE.replace('estimator = "shared_bearings"', 'estimator = "shared_bearings"\nshare_rate_hz = 7.0'),
     "swarm.share_rate_hz = 7.0 must divide"),
    (THREE.replace('estimator = "shared_bearings"', 'estimator = "shared_bearings"\nweave_min_angle_deg = 95.0'),
     "weave_min_angle_deg"),
    (THREE.replace('estimator = "shared_bearings"', 'estimator = "shared_bearings"\ncount = 3'), "unknown key"),
    ("\n[swarm]\npursuers = []\n", "at least 1 item"),
    ("\n[swarm]\nguidance = \"hng\"\n", "swarm.pursuers: Field required"),
    (THREE.replace("[[swarm.pursuers]]\n\n[[swarm.pursuers]]",
                   "[[swarm.pursuers]]\ninitial_position = [1.0, 0.0, 0.0]\n\n[[swarm.pursuers]]", 1),
     "differs from pursuer.initial_position"),
    (THREE.replace("initial_position = [70.0, 10.0, -25.0]", "initial_position = [70.0, 10.0]"), "initial_position"),
    (THREE.replace("initial_position = [70.0, 10.0, -25.0]", 'initial_position = ["70", 10.0, -25.0]'),
     "initial_position"),
]


@pytest.mark.parametrize("swarm, message", SWARM_ERRORS)
def test_a_bad_swarm_section_is_refused_naming_the_key(tmp_path, swarm, message):
    with pytest.raises(ConfigError) as error:
        _load(tmp_path, BASE + swarm)
    assert message in str(error.value)
    assert str(tmp_path / "scenario.toml") in str(error.value)


def test_too_many_pursuers_and_a_crowded_circle_are_refused(tmp_path):
    many = "\n[swarm]\n" + "".join(f"\n[[swarm.pursuers]]\ninitial_position = [{10.0 * k}, 100.0, -20.0]\n"
                                   for k in range(33))
    with pytest.raises(ConfigError, match="at most 32 items"):
        _load(tmp_path, BASE + many)
    # 20 pursuers equally spaced on the 8 m circle are 2 * 8 * sin(pi / 20) = 2.50 m apart: more than 2 m is fine,
    # with min_separation = 2.6 m they cannot be.
    twenty = "\n[swarm]\nguidance = \"circumnavigation\"\n\n[[swarm.pursuers]]\n" + "".join(
        f"\n[[swarm.pursuers]]\ninitial_position = [{10.0 * k}, 100.0, -20.0]\n" for k in range(19))
    assert _load(tmp_path, BASE + twenty).pursuer_count == 20
    with pytest.raises(ConfigError, match=r"are 2.5 m apart, not more than min_separation = 2.6 m"):
        _load(tmp_path, BASE + twenty.replace('guidance = "circumnavigation"',
                                              'guidance = "circumnavigation"\nmin_separation = 2.6'))


@settings(max_examples=60, deadline=None, database=None)
@given(st.integers(1, 6), st.lists(st.tuples(st.integers(1, 8), st.floats(0.0, 100.0), st.floats(0.1, 50.0)),
                                   max_size=4))
def test_blackout_ids_must_name_a_pursuer(count, windows):
    """Valid exactly when every window's pursuer is one of 1..N (windows made not to overlap)."""
    starts = "".join(f"\n[[swarm.pursuers]]\ninitial_position = [{100.0 + 10.0 * k}, 0.0, -20.0]\n" for k in range(count))
    spread = [(ident, 200.0 * index + start, 200.0 * index + start + length)
              for index, (ident, start, length) in enumerate(windows)]
    blackouts = ", ".join(f"{{pursuer = {i}, start = {a!r}, end = {b!r}}}" for i, a, b in spread)
    text = BASE.replace("initial_position = [0.0, 0.0, 0.0]", "initial_position = [100.0, 0.0, -20.0]", 1)
    document = tomllib.loads(text + "\n[swarm]\n" + starts + f"\n[swarm.link]\nblackouts = [{blackouts}]\n")
    document["vehicle"] = "../vehicles/paper_table1.toml"
    if all(ident <= count for ident, _, _ in spread):
        assert Scenario.model_validate(document).swarm.count == count
    else:
        with pytest.raises(ValueError, match="does not exist"):
            Scenario.model_validate(document)


def test_a_swarm_scenario_survives_overrides_and_a_dump(tmp_path):
    """Campaigns re-validate a dumped scenario with overrides merged (interfaces.overrides): every sub-table
    and [pursuer] is then present, which must not read as "written by the user"."""
    from interfaces.overrides import apply_overrides

    for name in SWARM_FILES:
        scenario, _ = load_scenario(SCENARIOS_DIR / f"{name}.toml")
        assert Scenario.model_validate(scenario.model_dump()) == scenario
        changed = apply_overrides(scenario, {"swarm.link.loss_probability": 0.25, "simulation.seed": 9}, "--set")
        assert changed.swarm.link.loss_probability == 0.25 and changed.swarm.pursuers == scenario.swarm.pursuers
    # pursuer 1 given only in [swarm] (no [pursuer]): its start is the swarm entry's, also after a dump
    text = BASE.replace("[pursuer]\ninitial_position = [0.0, 0.0, 0.0]\ninitial_velocity = [2.0, 0.0, 0.0]\n", "")
    only_swarm = _load(tmp_path, text + THREE.replace("[[swarm.pursuers]]\n\n[[swarm.pursuers]]",
                                                      "[[swarm.pursuers]]\ninitial_position = [5.0, 5.0, -20.0]\n\n"
                                                      "[[swarm.pursuers]]", 1))
    assert "pursuer" not in only_swarm.model_fields_set
    assert pursuer_starts(only_swarm)[0].initial_position == (5.0, 5.0, -20.0)
    again = Scenario.model_validate(only_swarm.model_dump())
    assert pursuer_starts(again) == pursuer_starts(only_swarm)
    with pytest.raises(ConfigError, match=r"\[swarm.standoff\] applies to guidance = 'standoff' only"):
        apply_overrides(only_swarm, {"swarm.standoff.radius": 30.0}, "--set")


# --- the scenario files --------------------------------------------------------------

@pytest.mark.parametrize("name", SWARM_FILES)
def test_the_swarm_files_load_for_companion_and_plant(name):
    scenario, vehicle = load_scenario(SCENARIOS_DIR / f"{name}.toml")
    plant, _ = load_plant_scenario(SCENARIOS_DIR / f"{name}.toml")
    assert plant.swarm == scenario.swarm and plant.pursuer_count == scenario.pursuer_count
    starts = pursuer_starts(scenario)
    assert [s.initial_position for s in pursuer_starts(plant)] == [s.initial_position for s in starts]
    assert vehicle.max_tilt_deg == 35.0


def test_swarm_circumnavigation_is_the_constant_velocity_case_with_three_pursuers():
    scenario, _ = load_scenario(SCENARIOS_DIR / "swarm_circumnavigation.toml")
    single, _ = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    assert scenario.pursuer_count == 3
    assert scenario.target == single.target and scenario.sensor == single.sensor
    assert scenario.pursuer == single.pursuer and scenario.estimator == single.estimator
    # the lone pursuer's gentler range excitation (the file's comment) is the only difference in [guidance]
    gentler = {"excitation_speed": 4.0, "excitation_low": 0.05, "excitation_high": 0.15}
    assert {key: getattr(scenario.guidance, key) for key in gentler} == gentler
    assert scenario.guidance == single.guidance.model_copy(update=gentler) and scenario.guidance.desired_range == 8.0
    assert (scenario.swarm.guidance, scenario.swarm.estimator) == ("circumnavigation", "shared_bearings")
    target = np.array([50.0, -25.0, -20.0])
    distances = [float(np.linalg.norm(np.array(s.initial_position) - target)) for s in pursuer_starts(scenario)]
    assert all(30.0 <= d <= 60.0 for d in distances), distances


def test_seed002_file_has_the_seeds_case():
    scenario, _ = load_scenario(SCENARIOS_DIR / "seed002_circumnavigation.toml")
    swarm = scenario.swarm
    assert scenario.pursuer_count == 5 and scenario.guidance.desired_range == 5.0
    c = swarm.circumnavigation
    assert (c.g1, c.g2, c.g3, c.alpha) == (1.2, 1.0, 0.4, 1.0)
    t = swarm.triangulation
    assert (t.k1, t.k2, t.process_noise, t.measurement_noise, t.initial_std) == (4.0, 0.12, 0.2, 1.0, 1.0)
    assert t.switch_time == pytest.approx(2500 * 0.01)
    assert scenario.sensor.noise_std == pytest.approx(math.sqrt(0.035), abs=1e-3)
    # planar: every pursuer and the target at one altitude, the seed's |p_i| in x-y
    starts = pursuer_starts(scenario)
    assert {s.initial_position[2] for s in starts} == {scenario.target.initial_position[2]} == {-10.0}
    seed_magnitudes = [(35, 40), (36, 50), (2, 48), (30, 49), (26, 34)]
    assert [tuple(abs(v) for v in s.initial_position[:2]) for s in starts] == seed_magnitudes
    # the time average of the seed's v_t = [2 - 2 cos(0.1 t), 2 + sin(0.05 t)] over its common period 40 pi s
    times = np.linspace(0.0, 40.0 * math.pi, 200001)
    mean = [np.trapezoid(2 - 2 * np.cos(0.1 * times), times) / times[-1],
            np.trapezoid(2 + np.sin(0.05 * times), times) / times[-1]]
    assert scenario.target.initial_velocity[:2] == pytest.approx(mean, abs=1e-6)


def test_seed004_file_has_the_seeds_target():
    scenario, _ = load_scenario(SCENARIOS_DIR / "seed004_standoff.toml")
    assert scenario.pursuer_count == 3 and scenario.swarm.guidance == "standoff"
    assert scenario.swarm.estimator == "fusion"
    target = scenario.target
    speed = math.hypot(*target.initial_velocity[:2])
    assert speed == pytest.approx(10.0) and target.initial_position[2] == 0.0 == target.initial_velocity[2]
    (right, left) = target.maneuvers
    assert (right.start, right.end, left.start, left.end) == (140.0, 360.0, 360.0, 700.0)
    # turn rate = lateral acceleration / speed; + is right in NED
    assert right.lateral_acceleration / speed == pytest.approx(0.008)
    assert left.lateral_acceleration / speed == pytest.approx(-0.01)
    assert scenario.simulation.duration == 700.0
    standoff = scenario.swarm.standoff
    assert standoff.min_speed > speed   # seed 004 eq. (34) needs the pursuers faster than the target
    assert scenario.guidance.desired_range == pytest.approx(math.hypot(standoff.radius, standoff.height), abs=0.5)
