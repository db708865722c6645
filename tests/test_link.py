"""The Zenoh link: keys, payload schemas and their refusals, frames, session configuration, a real loopback session."""

from __future__ import annotations

import json
import math
import socket
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from interfaces import link_schema as link
from interfaces.link_schema import CLOCK_KEY, REASONS, ClockTick, Command, PayloadError, TargetFix, decode_clock, decode_command, decode_target_fix, encode_clock, encode_command, encode_state, encode_target_fix, fix_to_ned
from interfaces.zenoh_transport import LinkError, open_session, publisher, zenoh_config
from interfaces.geodesy import ned_to_geodetic
from sitl_plant.vehicle.mavlink_vehicle import Home
from studies.processes import free_port, poll_until

HOME = (47.397742, 8.545594, 488.0)
FUZZ = settings(max_examples=300, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])


def _fix(**changes) -> dict:
    document = {"schema": "bof.target_fix/1", "sender": "target-1", "seq": 3, "stamp": 1.2, "frame": "ned",
                "position": [10.0, -5.0, -20.0], "velocity": [3.0, 4.0, 0.0]}
    document.update(changes)
    return document


def _bytes(document) -> bytes:
    return json.dumps(document).encode()


def test_keys_and_key_segments():
    assert CLOCK_KEY == "bof/sim/clock"
    assert link.target_fix_key("target-1") == "bof/target/target-1/fix"
    assert link.companion_state_key("pursuer_1") == "bof/companion/pursuer_1/state"
    assert link.companion_command_key("pursuer_1") == "bof/companion/pursuer_1/command"
    for bad in ("", "a/b", "*", "t**", "a b", "x" * 65, "$x"):
        with pytest.raises(ValueError, match="key segment"):
            link.target_fix_key(bad)


@pytest.mark.parametrize("fix", [
    TargetFix("target-1", 0, 0.0, "geodetic", (47.3982, 8.5451, 508.25), (3.0, 4.0, -0.5)),
    TargetFix("t.2", 2**63 - 1, 1e9, "geodetic", (-90.0, 180.0, -1000.0)),
    TargetFix("target_3", 17, 12.345678901234567, "ned", np.array([1e6, -1e6, 0.1]), np.array([0.0, -1e3, 1e3])),
])
def test_target_fix_round_trip(fix):
    payload = encode_target_fix(fix)
    assert json.loads(payload)["schema"] == "bof.target_fix/1"
    decoded = decode_target_fix(payload)
    assert decoded == fix
    assert isinstance(decoded.position, tuple) and all(type(v) is float for v in decoded.position)


def test_clock_and_command_round_trip():
    tick = ClockTick("plant", 41, 0.004 * 41)
    assert decode_clock(encode_clock(tick)) == tick
    assert json.loads(encode_clock(tick)) == {"schema": "bof.clock/1", "sender": "plant", "seq": 41, "stamp": 0.004 * 41}
    for command in (Command("gcs", 0, 3.5, "abort"), Command("gcs", 1, 4.0, "resume", "wind over limit, résumé")):
        assert decode_command(encode_command(command)) == command
    assert "detail" not in json.loads(encode_command(Command("gcs", 0, 3.5, "abort")))


def test_decoders_take_zenoh_bytes_and_refuse_non_bytes():
    import zenoh

    tick = ClockTick("plant", 1, 2.0)
    assert decode_clock(zenoh.ZBytes(encode_clock(tick))) == tick
    assert decode_clock(bytearray(encode_clock(tick))) == tick
    with pytest.raises(TypeError):
        decode_clock("{}")


def _state(**changes) -> dict:
    """A state as the companion builds it (numpy arrays and scalars included)."""
    state = {"phase": "following", "sender": "pursuer-1", "seq": np.int64(5), "stamp": np.float64(2.5),
             "pursuer": {"position": np.array([1.0, 2.0, -20.0]), "velocity": np.array([0.5, 0.0, 0.0])},
             "link": {"received": 12, "accepted": 10, "rejected": {"not_json": 2}, "bearings_used": 9,
                      "bearings_dropped": {"no_own_state": 1}, "last_seq": 11, "last_stamp": np.float64(2.2),
                      "last_fix_age_wall": None},
             "setpoints_sent": 120,
             "track": {"mode": "tracking", "bearing_age": 0.1},
             "observability": {"log_det": -math.inf, "min_eigenvalue": 0.0, "spread": math.nan, "count": 9},
             "estimate": {"time": 2.4, "position": np.array([60.0, np.nan, -20.0]), "velocity": np.array([1.0, np.inf, 0.0]),
                          "position_std": 0.8, "velocity_std": 0.3, "range": 59.0}}
    state.update(changes)
    return state


def test_state_encoding_nulls_non_finite_and_converts_numpy():
    document = json.loads(encode_state(_state()))
    assert document == {
        "schema": "bof.companion_state/1", "sender": "pursuer-1", "seq": 5, "stamp": 2.5, "phase": "following",
        "pursuer": {"position": [1.0, 2.0, -20.0], "velocity": [0.5, 0.0, 0.0]},
        "link": {"received": 12, "accepted": 10, "rejected": {"not_json": 2}, "bearings_used": 9,
                 "bearings_dropped": {"no_own_state": 1}, "last_seq": 11, "last_stamp": 2.2, "last_fix_age_wall": None},
        "setpoints_sent": 120, "track": {"mode": "tracking", "bearing_age": 0.1},
        "observability": {"log_det": None, "min_eigenvalue": 0.0, "spread": None, "count": 9},
        "estimate": {"time": 2.4, "position": [60.0, None, -20.0], "velocity": [1.0, None, 0.0], "position_std": 0.8,
                     "velocity_std": 0.3, "range": 59.0}}
    # Before the first bearing the app sends no track, observability or estimate: they stay absent.
    early = json.loads(encode_state(_state(track=None, observability=None, estimate=None)))
    assert not {"track", "observability", "estimate"} & set(early)


def test_state_decodes_for_the_ground_station():
    state = link.decode_state(encode_state(_state()))
    assert (state.sender, state.seq, state.stamp, state.phase) == ("pursuer-1", 5, 2.5, "following")
    assert state.estimate.position == (60.0, None, -20.0) and state.estimate.range == 59.0
    assert state.observability.log_det is None and state.link.rejected == {"not_json": 2}
    assert link.decode_state(encode_state(_state(estimate=None))).estimate is None
    # Incoming, a non-finite number is refused like in every payload (only the encoder maps it to null).
    document = json.loads(encode_state(_state()))
    document["estimate"]["range"] = math.inf
    with pytest.raises(PayloadError) as error:
        link.decode_state(json.dumps(document).encode())
    assert error.value.reason == "not_finite"


@pytest.mark.parametrize("state, reason", [
    ({k: v for k, v in _state().items() if k != "sender"}, "missing_field"),
    ({k: v for k, v in _state().items() if k != "link"}, "missing_field"),
    (_state(estimate={"time": 1.0, "position": [0.0] * 3, "velocity": [0.0] * 3, "position_std": 1.0,
                      "velocity_std": 1.0}), "missing_field"),
    (_state(stamp=float("nan")), "not_finite"),
    (_state(seq=-1), "out_of_range"),
    (_state(setpoints_sent=-1), "out_of_range"),
    (_state(phase=object()), "wrong_type"),
    (_state(setpoints_sent=True), "wrong_type"),
    (_state(pursuer={"position": [0.0, 0.0], "velocity": [0.0] * 3}), "wrong_type"),
    (_state(link=dict(_state()["link"], rejected={1: 2})), "wrong_type"),
    (_state(schema="bof.other/1"), "wrong_schema"),
    (_state(colour="red"), "unknown_field"),
    (_state(track={"mode": "tracking", "bearing_age": 0.1, "why": "?"}), "unknown_field"),
    ([("sender", "c")], "not_object"),
], ids=lambda value: value if isinstance(value, str) else "")
def test_state_encoding_refuses_what_the_schema_does_not_declare(state, reason):
    with pytest.raises(PayloadError) as error:
        encode_state(state)
    assert error.value.reason == reason


REFUSALS = [
    (decode_target_fix, b"x" * (link.MAX_PAYLOAD_BYTES + 1), "too_large"),
    (decode_target_fix, b"\xff\xfe{}", "not_utf8"),
    (decode_target_fix, b"{'schema': 1}", "not_json"),
    (decode_target_fix, b"[" * 5000, "not_json"),
    (decode_clock, b'{"stamp": 1' + b"0" * 5000 + b"}", "not_json"),
    (decode_target_fix, b"[1, 2]", "not_object"),
    (decode_target_fix, _bytes({k: v for k, v in _fix().items() if k != "schema"}), "missing_field"),
    (decode_target_fix, _bytes({k: v for k, v in _fix().items() if k != "position"}), "missing_field"),
    (decode_target_fix, _bytes(_fix(schema="bof.target_fix/3")), "wrong_schema"),
    (decode_clock, _bytes(_fix()), "wrong_schema"),
    (decode_target_fix, _bytes(_fix(colour="red")), "unknown_field"),
    (decode_target_fix, _bytes(_fix(seq=True)), "wrong_type"),
    (decode_target_fix, _bytes(_fix(seq=1.0)), "wrong_type"),
    (decode_target_fix, _bytes(_fix(stamp="1.0")), "wrong_type"),
    (decode_target_fix, _bytes(_fix(position=[1.0, 2.0])), "wrong_type"),
    (decode_target_fix, _bytes(_fix(velocity={"n": 1})), "wrong_type"),
    (decode_target_fix, _bytes(_fix(sender=7)), "wrong_type"),
    (decode_target_fix, _bytes(_fix(frame=1)), "wrong_type"),
    (decode_target_fix, _bytes(_fix(stamp=float("nan"))), "not_finite"),
    (decode_target_fix, _bytes(_fix(position=[1.0, float("inf"), 0.0])), "not_finite"),
    (decode_target_fix, b'{"schema": "bof.target_fix/1", "sender": "t", "seq": 0, "stamp": 1e999, "frame": "ned", '
                        b'"position": [0, 0, 0]}', "not_finite"),
    (decode_target_fix, _bytes(_fix(sender="")), "bad_sender"),
    (decode_target_fix, _bytes(_fix(sender="bad/sender")), "bad_sender"),
    (decode_target_fix, _bytes(_fix(frame="enu")), "bad_frame"),
    (decode_command, _bytes({"schema": "bof.command/1", "sender": "gcs", "seq": 0, "stamp": 0, "command": "land"}),
     "unknown_command"),
    (decode_target_fix, _bytes(_fix(seq=-1)), "out_of_range"),
    (decode_target_fix, _bytes(_fix(seq=2**63)), "out_of_range"),
    (decode_target_fix, _bytes(_fix(stamp=-0.5)), "out_of_range"),
    (decode_target_fix, _bytes(_fix(stamp=10**400)), "out_of_range"),
    (decode_target_fix, _bytes(_fix(frame="geodetic", position=[90.5, 8.0, 400.0])), "out_of_range"),
    (decode_target_fix, _bytes(_fix(frame="geodetic", position=[47.0, -180.1, 400.0])), "out_of_range"),
    (decode_target_fix, _bytes(_fix(frame="geodetic", position=[47.0, 8.0, 2e5])), "out_of_range"),
    (decode_target_fix, _bytes(_fix(position=[0.0, 1.000001e6, 0.0])), "out_of_range"),
    (decode_target_fix, _bytes(_fix(velocity=[0.0, 0.0, -1001.0])), "out_of_range"),
    (decode_command, _bytes({"schema": "bof.command/1", "sender": "gcs", "seq": 0, "stamp": 0, "command": "abort",
                             "detail": "x" * 201}), "out_of_range"),
    (link.decode_pursuer_share, _bytes({"schema": "bof.pursuer_share/1", "sender": 2, "seq": 0, "stamp": 1.0, "epoch": 5,
                                        "position": [0, 0, 0], "velocity": [0, 0, 0],
                                        "estimate": {"stamp": 1.0, "position": [9, 0, 0], "velocity": [0, 0, 0],
                                                     "covariance": [-1.0] + [0.0] * 35}}), "bad_covariance"),
]


@pytest.mark.parametrize("decode, payload, reason", REFUSALS)
def test_every_refusal_has_its_reason(decode, payload, reason):
    with pytest.raises(PayloadError) as error:
        decode(payload)
    assert error.value.reason == reason
    assert str(error.value).startswith(reason)


def test_every_reason_code_is_exercised():
    assert {reason for _, _, reason in REFUSALS} == REASONS


def test_optional_fields_may_be_absent_or_null():
    assert decode_target_fix(_bytes(_fix(velocity=None))).velocity is None
    assert decode_target_fix(_bytes({k: v for k, v in _fix().items() if k != "velocity"})).velocity is None
    assert decode_target_fix(_bytes(_fix(seq=0, stamp=0))).stamp == 0.0


def test_encoders_refuse_what_decoders_would_refuse():
    for fix, reason in (
        (TargetFix("t", 0, 0.0, "geodetic", (91.0, 0.0, 0.0)), "out_of_range"),
        (TargetFix("t", -1, 0.0, "ned", (0.0, 0.0, 0.0)), "out_of_range"),
        (TargetFix("t", 0, math.nan, "ned", (0.0, 0.0, 0.0)), "not_finite"),
        (TargetFix("t", 0, 0.0, "ned", (0.0, 0.0, math.inf)), "not_finite"),
        (TargetFix("t", 0, 0.0, "ecef", (0.0, 0.0, 0.0)), "bad_frame"),
        (TargetFix("a b", 0, 0.0, "ned", (0.0, 0.0, 0.0)), "bad_sender"),
    ):
        with pytest.raises(PayloadError) as error:
            encode_target_fix(fix)
        assert error.value.reason == reason
    with pytest.raises(PayloadError) as error:
        encode_command(Command("gcs", 0, 0.0, "self_destruct"))
    assert error.value.reason == "unknown_command"


# --- fuzzing: decoding raises PayloadError and nothing else ---------------------------

DECODERS = (decode_target_fix, decode_clock, decode_command)
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)


def _decode_all(payload: bytes) -> None:
    for decode in DECODERS:
        try:
            decode(payload)
        except PayloadError as error:
            assert error.reason in REASONS


@FUZZ
@given(st.binary(max_size=300))
def test_fuzz_arbitrary_bytes(payload):
    _decode_all(payload)


@FUZZ
@given(json_values)
def test_fuzz_arbitrary_json(value):
    _decode_all(json.dumps(value).encode())


@FUZZ
@given(st.sampled_from(["bof.target_fix/1", "bof.clock/1", "bof.command/1"]),
       st.sampled_from(["schema", "sender", "seq", "stamp", "frame", "position", "velocity", "command", "detail", "x"]),
       st.one_of(json_values, st.just(None)), st.booleans())
def test_fuzz_nearly_valid_documents(schema, field, value, delete):
    document = _fix(schema=schema, command="abort", detail="why")
    if schema == "bof.target_fix/1":
        document.pop("command"), document.pop("detail")
    elif schema == "bof.clock/1":
        for name in ("frame", "position", "velocity", "command", "detail"):
            document.pop(name)
    else:
        for name in ("frame", "position", "velocity"):
            document.pop(name)
    if delete:
        document.pop(field, None)
    else:
        document[field] = value
    _decode_all(json.dumps(document).encode())


# --- properties of the declared payloads (bounds as the module docstring documents them) ---

PROPERTY = settings(max_examples=200, derandomize=True, deadline=None, database=None)


def _finite(low: float, high: float):
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


senders = st.from_regex(r"[A-Za-z0-9_.\-]{1,64}", fullmatch=True)
seqs = st.integers(0, 2**63 - 1)
stamps = _finite(0.0, 1e9)
positions = st.one_of(
    st.tuples(st.just("geodetic"), st.tuples(_finite(-90.0, 90.0), _finite(-180.0, 180.0), _finite(-1e3, 1e5))),
    st.tuples(st.just("ned"), st.tuples(*[_finite(-1e6, 1e6)] * 3)))
velocities = st.none() | st.tuples(*[_finite(-1e3, 1e3)] * 3)
valid_fixes = st.builds(lambda sender, seq, stamp, placed, velocity: TargetFix(sender, seq, stamp, *placed, velocity),
                        senders, seqs, stamps, positions, velocities)
FIX_FIELDS = ("schema", "sender", "seq", "stamp", "frame", "position", "velocity")


def _document(fix: TargetFix) -> dict:
    document = {"schema": "bof.target_fix/1", "sender": fix.sender, "seq": fix.seq, "stamp": fix.stamp,
                "frame": fix.frame, "position": list(fix.position)}
    if fix.velocity is not None:
        document["velocity"] = list(fix.velocity)
    return document


def _reason(decode, document) -> str | None:
    try:
        decode(json.dumps(document).encode())
    except PayloadError as error:
        return error.reason
    return None


@PROPERTY
@given(valid_fixes)
def test_any_valid_fix_survives_encoding_exactly(fix):
    payload = encode_target_fix(fix)
    assert json.loads(payload) == _document(fix)  # read back by Python's own JSON parser
    assert decode_target_fix(payload) == fix


@PROPERTY
@given(st.builds(ClockTick, senders, seqs, stamps),
       st.builds(Command, senders, seqs, stamps, st.sampled_from(["abort", "resume", "start"]), st.text(max_size=200)))
def test_any_valid_clock_tick_and_command_survive_encoding(tick, command):
    assert decode_clock(encode_clock(tick)) == tick
    assert decode_command(encode_command(command)) == command


@PROPERTY
@given(valid_fixes, st.text(min_size=1, max_size=12).filter(lambda key: key not in FIX_FIELDS), json_values)
def test_any_extra_key_is_an_unknown_field(fix, key, value):
    assert _reason(decode_target_fix, {**_document(fix), key: value}) == "unknown_field"
    tick = {"schema": "bof.clock/1", "sender": fix.sender, "seq": fix.seq, "stamp": fix.stamp}
    assert _reason(decode_clock, {**tick, key: value}) == "unknown_field"
    command = {"schema": "bof.command/1", "sender": fix.sender, "seq": fix.seq, "stamp": fix.stamp, "command": "abort"}
    if key != "detail":
        assert _reason(decode_command, {**command, key: value}) == "unknown_field"


NUMBER_SLOTS = [("stamp", None), ("position", 0), ("position", 1), ("position", 2),
                ("velocity", 0), ("velocity", 1), ("velocity", 2)]


def _with(document: dict, slot: tuple[str, int | None], value) -> dict:
    name, index = slot
    document = dict(document, velocity=list(document.get("velocity") or [0.0, 0.0, 0.0]))
    if index is None:
        document[name] = value
    else:
        document[name] = list(document[name])
        document[name][index] = value
    return document


def _as_fix(document: dict) -> TargetFix:
    return TargetFix(document["sender"], document["seq"], document["stamp"], document["frame"], document["position"],
                     document["velocity"])


@PROPERTY
@given(valid_fixes, st.sampled_from(NUMBER_SLOTS), st.sampled_from([math.nan, math.inf, -math.inf]))
def test_any_non_finite_number_is_not_finite(fix, slot, value):
    document = _with(_document(fix), slot, value)  # json.dumps writes the NaN / Infinity tokens
    assert _reason(decode_target_fix, document) == "not_finite"
    with pytest.raises(PayloadError) as error:
        encode_target_fix(_as_fix(document))
    assert error.value.reason == "not_finite"


@PROPERTY
@given(valid_fixes, st.sampled_from([*NUMBER_SLOTS, ("seq", None)]), st.booleans())
def test_booleans_are_not_numbers(fix, slot, value):
    assert _reason(decode_target_fix, _with(_document(fix), slot, value)) == "wrong_type"


def _outside(low: float, high: float):
    return _finite(-1e300, low).filter(lambda v: v < low) | _finite(high, 1e300).filter(lambda v: v > high)


@PROPERTY
@given(valid_fixes, st.data())
def test_any_number_outside_its_documented_domain_is_out_of_range(fix, data):
    bounds = {("stamp", None): (0.0, 1e9), ("velocity", 0): (-1e3, 1e3), ("velocity", 1): (-1e3, 1e3),
              ("velocity", 2): (-1e3, 1e3)}
    if fix.frame == "geodetic":
        bounds.update({("position", 0): (-90.0, 90.0), ("position", 1): (-180.0, 180.0), ("position", 2): (-1e3, 1e5)})
    else:
        bounds.update({("position", axis): (-1e6, 1e6) for axis in range(3)})
    slot = data.draw(st.sampled_from(sorted(bounds, key=str)))
    document = _with(_document(fix), slot, data.draw(_outside(*bounds[slot])))
    assert _reason(decode_target_fix, document) == "out_of_range"
    with pytest.raises(PayloadError) as error:
        encode_target_fix(_as_fix(document))
    assert error.value.reason == "out_of_range"
    seq = data.draw(st.integers(max_value=-1) | st.integers(min_value=2**63))
    assert _reason(decode_target_fix, dict(_document(fix), seq=seq)) == "out_of_range"


# One fault per field, in the fields' order: what each does alone.
FIELD_FAULTS = [("sender", "bad/sender", "bad_sender"), ("seq", -1, "out_of_range"), ("stamp", "1.0", "wrong_type"),
                ("frame", "enu", "bad_frame"), ("position", [1.0, 2.0], "wrong_type"),
                ("velocity", [0.0, 0.0, 2e3], "out_of_range")]


@PROPERTY
@given(valid_fixes, st.sampled_from([None, "missing", "wrong"]), st.booleans(),
       st.sets(st.sampled_from(["sender", "seq", "stamp", "frame", "position"])),
       st.sets(st.sampled_from(range(len(FIELD_FAULTS)))))
def test_the_first_problem_in_the_documented_order_wins(fix, schema_fault, extra, dropped, faulted):
    """Schema, then unknown fields, then missing fields, then field by field."""
    document = _document(fix)
    for index in faulted:
        name, value, _ = FIELD_FAULTS[index]
        document[name] = value
    for name in dropped:
        document.pop(name)
    if extra:
        document["colour"] = "red"
    if schema_fault == "missing":
        document.pop("schema")
    elif schema_fault == "wrong":
        document["schema"] = "bof.target_fix/3"
    field_reasons = [reason for index, (name, _, reason) in enumerate(FIELD_FAULTS)
                     if index in faulted and name not in dropped]
    expected = ({"missing": "missing_field", "wrong": "wrong_schema"}.get(schema_fault)
                or ("unknown_field" if extra else None) or ("missing_field" if dropped else None)
                or (field_reasons[0] if field_reasons else None))
    assert _reason(decode_target_fix, document) == expected


@PROPERTY
@given(st.lists(st.one_of(_finite(-1e6, 1e6), st.sampled_from([math.nan, math.inf, -math.inf])),
                min_size=10, max_size=10))
def test_state_numbers_go_out_finite_or_null(values):
    estimate = {"time": values[0], "position": np.array(values[1:4]), "velocity": np.array(values[4:7]),
                "position_std": values[7], "velocity_std": values[8], "range": values[9]}
    sent = json.loads(encode_state(_state(estimate=estimate)))["estimate"]
    flat = [sent["time"], *sent["position"], *sent["velocity"], sent["position_std"], sent["velocity_std"], sent["range"]]
    assert flat == [value if math.isfinite(value) else None for value in values]
    received = link.decode_state(encode_state(_state(estimate=estimate))).estimate
    assert [received.time, *received.position, *received.velocity] == flat[:7]


# --- frames ------------------------------------------------------------------------

def test_geodetic_ned_round_trip_under_a_millimetre_over_a_kilometre():
    rng = np.random.default_rng(7)
    points = np.vstack([rng.uniform([-1000, -1000, -300], [1000, 1000, 50], size=(200, 3)),
                        [[1000.0, 1000.0, -300.0], [-1000.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    worst = 0.0
    for seq, ned in enumerate(points):
        geodetic = ned_to_geodetic(ned, HOME)
        fix = decode_target_fix(encode_target_fix(TargetFix("t", seq, 0.0, "geodetic", geodetic)))
        worst = max(worst, float(np.linalg.norm(fix_to_ned(fix, HOME) - ned)))
    assert worst < 1e-3
    # The same convention as the MAVLink plant's GLOBAL_POSITION_INT.
    assert np.allclose(ned_to_geodetic((120.0, -40.0, -20.0), HOME), Home(*HOME).to_geodetic(120.0, -40.0, -20.0),
                       rtol=0, atol=1e-12)
    ned_fix = TargetFix("t", 0, 0.0, "ned", (1.0, 2.0, 3.0))
    assert np.array_equal(fix_to_ned(ned_fix, HOME), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        fix_to_ned(TargetFix("t", 0, 0.0, "geodetic", (47.0, 8.0, 400.0)), (95.0, 0.0, 0.0))


# --- session configuration ---------------------------------------------------------

def test_config_listens_on_loopback_only():
    peer = zenoh_config(connect=["tcp/127.0.0.1:7447"])
    assert json.loads(peer.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert json.loads(peer.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(peer.get_json("scouting/multicast/enabled")) is False
    assert json.loads(peer.get_json("mode")) == "peer"
    plant = zenoh_config(listen=["tcp/127.0.0.1:7447", "tcp/[::1]:7448", "tcp/localhost:7449"])
    assert len(json.loads(plant.get_json("listen/endpoints"))) == 3
    client = zenoh_config("client", connect=["tcp/127.0.0.1:7447"])
    assert json.loads(client.get_json("listen/endpoints")) == []
    for endpoint in ("tcp/0.0.0.0:7447", "tcp/[::]:7447", "tcp/192.168.1.10:7447", "udp/example.org:7447"):
        with pytest.raises(LinkError, match="not loopback"):
            zenoh_config(listen=[endpoint])
    remote = zenoh_config(listen=["tcp/0.0.0.0:7447"], allow_remote_listen=True)
    assert json.loads(remote.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]


@pytest.mark.parametrize("kwargs, match", [
    ({"mode": "server"}, "mode"),
    ({"mode": "client"}, "needs a connect"),
    ({"mode": "client", "connect": ["tcp/127.0.0.1:1"], "listen": ["tcp/127.0.0.1:0"]}, "cannot listen"),
    ({"connect": ["127.0.0.1:7447"]}, "expected <protocol>"),
    ({"listen": ["tcp/127.0.0.1"]}, "expected <protocol>"),
    ({"listen": ["tcp/127.0.0.1:70000"]}, "expected <protocol>"),
])
def test_config_errors_say_what_is_wrong(kwargs, match):
    with pytest.raises(LinkError, match=match):
        zenoh_config(**kwargs)


def test_open_session_error_is_a_link_error():
    with pytest.raises(LinkError, match="cannot open"):
        open_session(zenoh_config("client", connect=[f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]))


def test_fixes_cross_a_real_loopback_session_in_order():
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    listener = open_session(zenoh_config(listen=[endpoint]))
    talker = None
    try:
        talker = open_session(zenoh_config(connect=[endpoint]))
        received: list[TargetFix] = []
        lock = threading.Lock()

        def on_fix(sample):
            fix = decode_target_fix(sample.payload)
            with lock:
                received.append(fix)

        subscriber = listener.declare_subscriber(link.TARGET_FIX_ALL, on_fix)
        fixes = publisher(talker, link.target_fix_key("target-9"))
        assert poll_until(lambda: fixes.matching_status.matching, 10.0), "the subscriber never became visible"
        sent = [TargetFix("target-9", seq, seq * 0.2, "ned", (seq, -seq, -20.0), (5.0, -5.0, 0.0)) for seq in range(100)]
        for fix in sent:
            fixes.put(encode_target_fix(fix))
        assert poll_until(lambda: len(received) >= len(sent), 10.0), f"received {len(received)} of {len(sent)}"
        with lock:
            assert received == sent
        subscriber.undeclare()
    finally:
        if talker is not None:
            talker.close()
        listener.close()


def test_ground_station_progress_line_names_the_phase_the_rejections_and_shows_missing_figures_as_dashes():
    """bof-sitl's progress line reads the decoded state: the range estimate only while the companion follows (a null
    range or std, no estimate yet: the encoder nulls NaN, prints '-'), the monitor's word when it calls the estimate
    suspect, and the refused fixes by reason."""
    from studies.full_sitl import _progress

    full = _progress(link.decode_state(encode_state(_state())))
    assert "phase=following" in full and "range^=  59.0 m" in full and "sigma_p= 0.80 m" in full
    assert "fixes 10 ok / 2 rejected (not_json 2)" in full and "SUSPECT" not in full
    estimate = dict(_state()["estimate"], range=float("nan"), position_std=float("inf"))
    line = _progress(link.decode_state(encode_state(_state(estimate=estimate))))
    assert "range^=- m" in line and "sigma_p=- m" in line
    landing = _progress(link.decode_state(encode_state(_state(phase="landing"))))
    assert "phase=landing" in landing and "range^" not in landing and "sigma_p" not in landing
    several = dict(_state()["link"], rejected={"no_clock": 4, "future_stamp": 7})
    assert "11 rejected (future_stamp 7, no_clock 4)" in _progress(link.decode_state(encode_state(_state(link=several))))
    health = {"state": "suspect", "reasons": ["nis"], "nis_ratio": 4.0, "relative_range_std": 0.1}
    assert "estimate SUSPECT (nis)" in _progress(link.decode_state(encode_state(_state(health=health))))
    assert _progress(None) == "waiting for the companion"


# --- schema v2: the publisher epoch ------------------------------------------------------------

V2_FIX = {"schema": "bof.target_fix/2", "sender": "target-1", "seq": 0, "stamp": 1.2, "epoch": 2**63 - 1,
          "frame": "ned", "position": [10.0, -5.0, -20.0]}
V2_COMMAND = {"schema": "bof.command/2", "sender": "gcs", "seq": 0, "stamp": 3.0, "epoch": 0, "command": "abort"}


def test_v2_is_what_encoders_write_and_v1_still_decodes():
    fix = TargetFix("target-1", 0, 1.2, "ned", (10.0, -5.0, -20.0), epoch=2**63 - 1)
    assert json.loads(encode_target_fix(fix)) == V2_FIX  # the documented document, field for field
    assert decode_target_fix(_bytes(V2_FIX)) == fix
    command = Command("gcs", 0, 3.0, "abort", epoch=0)
    assert json.loads(encode_command(command)) == V2_COMMAND
    assert decode_command(_bytes(V2_COMMAND)) == command
    # v1 documents (no epoch) decode with epoch None; an envelope without epoch is written as v1.
    assert decode_target_fix(_bytes(_fix())).epoch is None
    v1_command = {key: value for key, value in V2_COMMAND.items() if key != "epoch"} | {"schema": "bof.command/1"}
    assert decode_command(_bytes(v1_command)) == Command("gcs", 0, 3.0, "abort")
    assert json.loads(encode_target_fix(TargetFix("t", 0, 0.0, "ned", (0.0, 0.0, 0.0))))["schema"] == "bof.target_fix/1"


@pytest.mark.parametrize("decode, document, reason", [
    (decode_target_fix, {k: v for k, v in V2_FIX.items() if k != "epoch"}, "missing_field"),
    (decode_target_fix, {**V2_FIX, "epoch": -1}, "out_of_range"),
    (decode_target_fix, {**V2_FIX, "epoch": 2**63}, "out_of_range"),
    (decode_target_fix, {**V2_FIX, "epoch": True}, "wrong_type"),
    (decode_target_fix, {**V2_FIX, "epoch": 1.0}, "wrong_type"),
    (decode_target_fix, {**_fix(), "epoch": 5}, "unknown_field"),  # v1 has no epoch
    (decode_target_fix, {**V2_FIX, "frame": "enu"}, "bad_frame"),
    (decode_target_fix, {**V2_FIX, "position": [1e7, 0.0, 0.0]}, "out_of_range"),
    (decode_command, {k: v for k, v in V2_COMMAND.items() if k != "epoch"}, "missing_field"),
    (decode_command, {**V2_COMMAND, "epoch": "7"}, "wrong_type"),
    (decode_command, {**V2_COMMAND, "schema": "bof.command/3"}, "wrong_schema"),
    (decode_command, {**V2_COMMAND, "command": "land"}, "unknown_command"),
])
def test_v2_refusals_have_their_reasons(decode, document, reason):
    with pytest.raises(PayloadError) as error:
        decode(_bytes(document))
    assert error.value.reason == reason


@FUZZ
@given(st.integers(0, 2**63 - 1), st.integers(0, 2**63 - 1), st.sampled_from(["geodetic", "ned"]))
def test_any_epoch_survives_encoding(epoch, seq, frame):
    position = (47.0, 8.0, 500.0) if frame == "geodetic" else (1.0, 2.0, 3.0)
    fix = TargetFix("target-1", seq, 5.0, frame, position, epoch=epoch)
    assert decode_target_fix(encode_target_fix(fix)) == fix
    assert decode_command(encode_command(Command("gcs", seq, 5.0, "start", epoch=epoch))).epoch == epoch


def test_new_epochs_are_in_range_and_differ():
    epochs = {link.new_epoch() for _ in range(100)}
    assert len(epochs) == 100 and all(0 <= e < 2**63 for e in epochs)
