"""MAVLink 2 signing on the plant's ground-station link (MAV_SIGN_CFG), against pymavlink as the peer.

The peer's frames are signed by pymavlink's own MAVLink 2 signing (the secret key, link id and
timestamp set on its encoder as mavutil's setup_signing does), and the plant's answers are
checked by a pymavlink parser that holds the key (or a wrong one). Nothing here recomputes a
signature. Datagrams are handed to MavlinkVehicle.handle_datagram as in test_mavlink_vehicle;
answers travel over loopback UDP to the client sockets.
"""

from __future__ import annotations

import os
import struct
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from sitl_plant.vehicle.autopilot import ARMING_READY_AFTER  # noqa: E402
from sitl_plant.vehicle.px4_modes import CommandResult  # noqa: E402
from test_mavlink_vehicle import CLIENT_COMPONENT, CLIENT_SYSTEM, Harness  # noqa: E402

KEY = bytes(range(1, 33))
WRONG_KEY = bytes(range(101, 133))
ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
COMPANION, GCS = 0, 1


class _Holder:
    def __init__(self, mav) -> None:
        self.mav = mav


def signer(key: bytes, link_id: int = 7, timestamp: int | None = None) -> mavlink.MAVLink:
    """A ground station's encoder whose frames pymavlink signs with `key` (as MAVProxy's `signing setup`)."""
    mav = mavlink.MAVLink(None, srcSystem=CLIENT_SYSTEM, srcComponent=CLIENT_COMPONENT)
    mavutil.mavfile.setup_signing(_Holder(mav), key, sign_outgoing=True, initial_timestamp=timestamp, link_id=link_id)
    return mav


def checker(key: bytes) -> mavlink.MAVLink:
    """A parser that refuses every frame not signed with `key`."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    mavutil.mavfile.setup_signing(_Holder(parser), key, sign_outgoing=False, link_id=0)
    return parser


def arm_frame(mav: mavlink.MAVLink, arm: float = 1.0) -> bytes:
    frame = mav.command_long_encode(1, 1, ARM, 0, arm, 0, 0, 0, 0, 0, 0).pack(mav)
    mav.seq = (mav.seq + 1) % 256
    return frame


@pytest.fixture
def plant():
    """A ready-to-arm plant with MAV_SIGN_CFG = 1 and KEY set on the ground-station link."""
    made: list[Harness] = []

    def make(key: bytes | None = KEY, sign_cfg: int = 1) -> Harness:
        h = Harness()
        made.append(h)
        h.autopilot.parameters.set("MAV_SIGN_CFG", sign_cfg)
        if key is not None:
            h.vehicle.set_signing_key(key, source="test")
        h.fly_silently(ARMING_READY_AFTER + 0.1)
        h.step(0.02)
        h.companion.take()
        h.gcs.take()
        return h

    try:
        yield make
    finally:
        for h in made:
            h.close()


def gcs_acks(h: Harness) -> list:
    return h.gcs.take("COMMAND_ACK")


def test_an_unsigned_arm_from_the_ground_station_is_refused_counted_and_unanswered(plant) -> None:
    h = plant()
    h.command_long(ARM, 1.0, link=GCS)
    assert not h.autopilot.armed
    assert h.vehicle.stats.rejected["signing_unsigned"] == 1
    assert h.vehicle.stats.commands[mavlink.enums["MAV_CMD"][ARM].name] == 0
    h.step(0.05)
    assert gcs_acks(h) == []
    assert h.acks() == []


def test_the_same_arm_signed_with_the_key_is_obeyed_and_the_answer_is_signed(plant) -> None:
    h = plant()
    h.gcs.parser = checker(KEY)
    h.deliver(arm_frame(signer(KEY)), GCS)
    assert h.autopilot.armed
    assert sum(h.vehicle.stats.rejected.values()) == 0
    acks = gcs_acks(h)
    assert [(a.command, a.result) for a in acks] == [(ARM, CommandResult.ACCEPTED)]
    assert acks[0].get_signed()


def test_the_ground_station_stream_is_signed_with_the_key(plant) -> None:
    h = plant()
    h.gcs.parser = checker(KEY)
    h.step(1.2)
    received = h.gcs.take()
    assert "HEARTBEAT" in {m.get_type() for m in received}
    assert all(m.get_signed() for m in received)
    # Under another key none of it verifies (and the companion link is not signed at all).
    other = checker(WRONG_KEY)
    h.gcs.parser = other
    h.step(1.0)
    assert {m.get_type() for m in h.gcs.take()} == {"BAD_DATA"}


def test_an_arm_signed_with_a_wrong_key_is_refused(plant) -> None:
    h = plant()
    h.deliver(arm_frame(signer(WRONG_KEY)), GCS)
    assert not h.autopilot.armed
    assert h.vehicle.stats.rejected["signing_bad_signature"] == 1


def test_a_replayed_signed_arm_is_refused(plant) -> None:
    h = plant()
    gcs = signer(KEY)
    arm = arm_frame(gcs)
    h.deliver(arm, GCS)
    assert h.autopilot.armed
    h.deliver(arm_frame(gcs, arm=0.0), GCS)  # the genuine station disarms
    assert not h.autopilot.armed
    h.deliver(arm, GCS)  # an eavesdropper sends the captured arm again
    assert not h.autopilot.armed
    assert h.vehicle.stats.rejected["signing_replayed"] == 1


def test_a_captured_frame_from_a_stream_older_than_a_minute_is_refused(plant) -> None:
    h = plant()
    old = signer(KEY, link_id=9, timestamp=int((time.time() - 1420070400 - 3600) * 100_000))
    h.deliver(arm_frame(old), GCS)
    assert not h.autopilot.armed
    assert h.vehicle.stats.rejected["signing_stale_timestamp"] == 1


def test_a_forged_frame_with_a_future_timestamp_does_not_lock_out_the_genuine_station(plant) -> None:
    h = plant()
    gcs = signer(KEY, link_id=7)
    # Same stream (link id, system, component), a timestamp a year ahead, the wrong key.
    forger = signer(WRONG_KEY, link_id=7, timestamp=gcs.signing.timestamp + 365 * 86400 * 100_000)
    h.deliver(arm_frame(forger), GCS)
    assert not h.autopilot.armed
    h.deliver(arm_frame(gcs), GCS)
    assert h.autopilot.armed
    assert h.vehicle.stats.rejected == {"signing_bad_signature": 1}


def test_heartbeat_unsigned_is_refused_and_radio_status_accepted_as_px4_does(plant) -> None:
    h = plant()
    h.send(h.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0), GCS)
    h.send(h.mav.radio_status_encode(200, 190, 100, 10, 10, 0, 0), GCS)
    assert h.vehicle.stats.rejected == {"signing_unsigned": 1}
    assert h.vehicle.stats.received["RADIO_STATUS"] == 1


def test_the_companion_link_stays_unsigned(plant) -> None:
    h = plant()
    h.command_long(ARM, 1.0, link=COMPANION)
    assert h.autopilot.armed
    assert [(a.command, a.result) for a in h.acks()] == [(ARM, CommandResult.ACCEPTED)]
    assert sum(h.vehicle.stats.rejected.values()) == 0


def test_without_a_key_the_ground_station_link_takes_nothing_until_setup_signing_on_the_companion_link(plant) -> None:
    h = plant(key=None)
    h.deliver(arm_frame(signer(KEY)), GCS)
    assert not h.autopilot.armed and h.vehicle.stats.rejected["signing_no_key"] == 1
    # SETUP_SIGNING on the ground-station link would let any sender pick the key: refused.
    setup = h.mav.setup_signing_encode(1, 1, list(KEY), 0)
    h.send(setup, GCS)
    assert not h.vehicle.signing_key_set
    h.send(setup, COMPANION)
    assert h.vehicle.signing_key_set
    h.deliver(arm_frame(signer(KEY)), GCS)
    assert h.autopilot.armed


def test_signing_off_takes_unsigned_traffic_and_still_signs_what_it_sends(plant) -> None:
    h = plant(sign_cfg=0)
    h.command_long(ARM, 1.0, link=GCS)
    assert h.autopilot.armed
    h.gcs.take()
    h.gcs.parser = checker(KEY)
    h.step(1.1)
    received = h.gcs.take()
    assert received and all(m.get_signed() for m in received)


def test_an_all_zero_setup_signing_clears_the_key(plant) -> None:
    h = plant()
    h.send(h.mav.setup_signing_encode(1, 1, [0] * 32, 0), COMPANION)
    assert not h.vehicle.signing_key_set
    h.deliver(arm_frame(signer(KEY)), GCS)
    assert not h.autopilot.armed and h.vehicle.stats.rejected["signing_no_key"] == 1


def test_the_key_is_not_a_parameter(plant) -> None:
    h = plant()
    h.send(h.mav.param_request_list_encode(1, 1), COMPANION)
    values = h.companion.take("PARAM_VALUE")
    names = {v.param_id for v in values}
    assert len(values) == len(h.autopilot.parameters) and "MAV_SIGN_CFG" in names
    assert not any("KEY" in name or "SECRET" in name for name in names)
    # No PARAM_VALUE carries any 4 consecutive bytes of the key.
    payloads = b"".join(bytes(v.get_msgbuf()) for v in values)
    assert not any(KEY[i:i + 4] in payloads for i in range(0, 29))
    # Reading a made-up key parameter gets no answer.
    h.send(h.mav.param_request_read_encode(1, 1, b"MAV_SIGN_KEY", -1), COMPANION)
    assert h.companion.take("PARAM_VALUE") == []


def test_mav_sign_cfg_2_is_refused_as_a_parameter(plant) -> None:
    h = plant(sign_cfg=0)
    h.send(h.mav.param_set_encode(1, 1, b"MAV_SIGN_CFG", *_int_param(2)), COMPANION)
    assert h.vehicle.signing_mode == 0
    assert h.vehicle.stats.rejected["param_set_refused"] == 1


def _int_param(value: int) -> tuple[float, int]:
    return struct.unpack("<f", struct.pack("<i", value))[0], mavlink.MAV_PARAM_TYPE_INT32


@settings(max_examples=60, deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=64), min_size=1, max_size=6))
def test_signing_state_survives_any_sequence_of_datagrams(datagrams) -> None:
    """Whatever arrives first, a correctly signed arm from the genuine station afterwards is obeyed."""
    h = Harness()
    try:
        h.autopilot.parameters.set("MAV_SIGN_CFG", 1)
        h.vehicle.set_signing_key(KEY, source="test")
        h.fly_silently(ARMING_READY_AFTER + 0.1)
        for data in datagrams:
            before = sum(h.vehicle.stats.rejected.values())
            h.deliver(data, GCS)
            assert sum(h.vehicle.stats.rejected.values()) - before in (0, 1)
        assert not h.autopilot.armed
        h.deliver(arm_frame(signer(KEY)), GCS)
        assert h.autopilot.armed
    finally:
        h.close()
