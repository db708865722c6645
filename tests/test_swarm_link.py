"""The companion's share link (companion.swarm_link): shares out on the odometry clock, neighbours' shares in,
checked, put through [swarm.link] and handed to the pipeline. References: the payload schema's own decoder
(interfaces.link_schema), the [swarm.link] fault model's stated contract (interfaces.neighbour_link: the same
calls per pair give the same decisions), and the numbers written into the shares by hand."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.messages import BearingMeasurement, PursuerState
from companion.swarm_link import MAX_HELD, SwarmLink, swarm_companion_id
from interfaces import link_schema as link
from interfaces.neighbour_link import NeighbourLink
from interfaces.scenario import SCENARIOS_DIR, load_scenario

SCENARIO, _ = load_scenario(SCENARIOS_DIR / "swarm_circumnavigation.toml")


def _scenario(**link_settings):
    swarm = SCENARIO.swarm.model_copy(update={"link": SCENARIO.swarm.link.model_copy(update=link_settings)})
    return SCENARIO.model_copy(update={"swarm": swarm})


@dataclass
class Sample:
    state: PursuerState


class Clock:
    def __init__(self, now: float | None = 10.0) -> None:
        self.now = now
        self.position = np.zeros(3)

    def __call__(self):
        return self.now


def _link(ident: int = 1, scenario=SCENARIO, clock: Clock | None = None, log_folder=None, seed: int = 1) -> tuple[SwarmLink, Clock, list]:
    clock = clock or Clock()
    sent: list[bytes] = []
    swarm = SwarmLink(scenario, ident, seed, clock=clock, own_position=lambda: clock.position, log_folder=log_folder,
                      epoch=100 + ident)
    swarm.put = sent.append
    return swarm, clock, sent


def _share(sender: int = 2, seq: int = 0, stamp: float = 10.0, epoch: int = 7, position=(20.0, 0.0, -20.0),
           bearing: link.SharedBearing | None = None) -> bytes:
    return link.encode_pursuer_share(link.PursuerShare(sender, seq, stamp, epoch, position, (1.0, 2.0, 0.0), bearing))


def test_companion_ids_carry_the_pursuer_id():
    assert swarm_companion_id("pursuer-1", 3) == "pursuer-1-3"


def test_shares_go_out_at_the_share_rate_on_the_odometry_clock_and_decode_with_the_schema():
    """50 Hz odometry for 2 s at [sensor] rate_hz = 5 (the scenario's share rate): one share per 0.2 s, on
    the grid k / 5, each carrying the sample's own position and velocity, seq 0, 1, 2... in our epoch."""
    swarm, clock, sent = _link(ident=2)
    times = [10.0 + k / 50.0 for k in range(100)]
    for t in times:
        swarm.on_sample(Sample(PursuerState(t, np.array([t, -1.0, -20.0]), np.array([0.5, 0.0, 0.0]))))
    shares = [link.decode_pursuer_share(payload) for payload in sent]
    assert [s.stamp for s in shares] == pytest.approx([10.0 + k * 0.2 for k in range(10)])
    assert [s.seq for s in shares] == list(range(10))
    assert all(s.sender == 2 and s.epoch == 102 for s in shares)
    assert all(s.position == (s.stamp, -1.0, -20.0) and s.velocity == (0.5, 0.0, 0.0) for s in shares)
    assert swarm.sent == 10


def test_the_newest_own_bearing_is_shared_once_with_its_own_stamp_and_position():
    swarm, clock, sent = _link()
    bearing = BearingMeasurement(9.93, np.array([0.6, 0.8, 0.0]), np.array([1.0, 2.0, -20.0]))
    older = BearingMeasurement(9.73, np.array([1.0, 0.0, 0.0]), np.array([0.0, 2.0, -20.0]))
    neighbours = BearingMeasurement(9.95, np.array([0.0, 1.0, 0.0]), np.array([5.0, 5.0, -20.0]), source=3)
    swarm.own_bearings([older, bearing, neighbours])  # a neighbour's bearing is never passed on as ours
    for t in (10.0, 10.2):
        swarm.on_sample(Sample(PursuerState(t, np.zeros(3), np.zeros(3))))
    first, second = (link.decode_pursuer_share(p) for p in sent)
    assert first.bearing == link.SharedBearing(9.93, (0.6, 0.8, 0.0), (1.0, 2.0, -20.0))
    assert second.bearing is None


def test_a_neighbours_share_gives_a_neighbour_and_its_bearing_at_its_own_stamp():
    swarm, clock, _ = _link(ident=1)
    swarm.step_inputs(9.8)  # the follower runs
    bearing = link.SharedBearing(9.9, (0.0, 1.0, 0.0), (19.0, 0.0, -20.0))
    swarm.on_share(_share(sender=2, stamp=10.0, bearing=bearing))
    neighbours, bearings = swarm.step_inputs(10.0)
    assert [(n.ident, n.time) for n in neighbours] == [(2, 10.0)]
    np.testing.assert_array_equal(neighbours[0].position, [20.0, 0.0, -20.0])
    np.testing.assert_array_equal(neighbours[0].velocity, [1.0, 2.0, 0.0])
    assert len(bearings) == 1 and bearings[0].source == 2 and bearings[0].time == 9.9
    np.testing.assert_array_equal(bearings[0].pursuer_position, [19.0, 0.0, -20.0])
    np.testing.assert_array_equal(bearings[0].direction, [0.0, 1.0, 0.0])
    assert swarm.step_inputs(10.1)[1] == []  # each bearing once
    # the neighbour is fresh for neighbour_timeout_s after its stamp, by its stamp
    timeout = SCENARIO.swarm.neighbour_timeout_s
    assert len(swarm.step_inputs(10.0 + timeout)[0]) == 1
    assert swarm.step_inputs(10.0 + timeout + 0.01)[0] == ()


def test_after_following_the_neighbours_come_without_their_bearings():
    """neighbours_at (the braking before landing): the fresh neighbours as step_inputs gives them, but no bearing is
    taken, counted as used or kept, also from shares that arrive later."""
    swarm, clock, _ = _link(ident=1)
    swarm.step_inputs(9.8)  # the follower runs
    bearing = link.SharedBearing(9.9, (0.0, 1.0, 0.0), (19.0, 0.0, -20.0))
    swarm.on_share(_share(sender=2, stamp=10.0, bearing=bearing))
    neighbours = swarm.neighbours_at(10.0)
    assert [(n.ident, n.time) for n in neighbours] == [(2, 10.0)]
    np.testing.assert_array_equal(neighbours[0].position, [20.0, 0.0, -20.0])
    swarm.on_share(_share(sender=2, seq=1, stamp=10.2, bearing=link.SharedBearing(10.1, (0.0, 1.0, 0.0), (19.0, 0.0, -20.0))))
    assert [(n.ident, n.time) for n in swarm.neighbours_at(10.2)] == [(2, 10.2)]
    assert swarm.neighbour_bearings_used == 0 and len(swarm._inbox) == 0
    assert swarm.neighbours_at(10.2 + SCENARIO.swarm.neighbour_timeout_s + 0.01) == ()


def test_a_fresh_share_carrying_a_bearing_older_than_the_age_limit_gives_the_state_but_not_the_bearing():
    swarm, _, _ = _link(ident=1, clock=Clock(20.0))
    swarm.step_inputs(19.8)
    swarm.on_share(_share(stamp=20.0, bearing=link.SharedBearing(9.99, (0.0, 1.0, 0.0), (19.0, 0.0, -20.0))))
    neighbours, bearings = swarm.step_inputs(20.0)
    assert [n.ident for n in neighbours] == [2] and bearings == []


def test_estimator_own_keeps_the_neighbours_bearings_out():
    scenario = SCENARIO.model_copy(update={"swarm": SCENARIO.swarm.model_copy(update={"estimator": "own"})})
    swarm, _, _ = _link(scenario=scenario)
    swarm.step_inputs(9.8)
    swarm.on_share(_share(bearing=link.SharedBearing(9.9, (0.0, 1.0, 0.0), (19.0, 0.0, -20.0))))
    neighbours, bearings = swarm.step_inputs(10.0)
    assert len(neighbours) == 1 and bearings == []


@pytest.mark.parametrize("payload, reason, now", [
    (b"\xff\xfe", "not_utf8", 10.0),
    (b"[]", "not_object", 10.0),
    (_share(sender=1), "own_sender", 10.0),
    (_share(sender=4), "unknown_pursuer", 10.0),
    (_share(stamp=10.0 + 0.51), "future_stamp", 10.0),  # [link] max_future_skew_s = 0.5
    (_share(stamp=10.0), "too_old", 20.01),  # [link] max_fix_age_s = 10
])
def test_bad_shares_are_rejected_and_counted_by_reason(payload, reason, now):
    swarm, _, _ = _link(ident=1, clock=Clock(now))
    swarm.on_share(payload)
    assert swarm.rejected == {reason: 1} and swarm.accepted == 0
    assert swarm.step_inputs(now) == ((), [])


def test_a_share_before_any_odometry_is_rejected_as_no_clock():
    swarm, _, _ = _link(clock=Clock(None))
    swarm.on_share(_share())
    assert swarm.rejected == {"no_clock": 1}


def test_replays_are_stale_per_sender_and_epoch_and_a_restarted_sender_starts_over():
    swarm, _, _ = _link(ident=1)
    for seq in (0, 1, 1, 0):
        swarm.on_share(_share(seq=seq))
    assert swarm.accepted == 2 and swarm.rejected == {"stale_seq": 2}
    swarm.on_share(_share(seq=0, epoch=8))  # a new boot of pursuer 2
    swarm.on_share(_share(sender=3, seq=0))  # another sender has its own sequence
    assert swarm.accepted == 4 and swarm.rejected == {"stale_seq": 2}


def test_a_forged_far_ahead_seq_cannot_lock_the_sender_out():
    """seq 2**62 in the genuine sender's epoch: refused (seq_jump); the genuine shares go on being accepted.
    Losses are no jump: 20 shares missed in 4 s (5 Hz) still pass."""
    swarm, clock, _ = _link(ident=1)
    swarm.on_share(_share(seq=0, stamp=10.0))
    swarm.on_share(_share(seq=2**62, stamp=10.1))
    clock.now = 10.2
    swarm.on_share(_share(seq=1, stamp=10.2))
    clock.now = 14.2
    swarm.on_share(_share(seq=21, stamp=14.2))
    assert swarm.rejected == {"seq_jump": 1} and swarm.accepted == 3


def test_the_link_model_decides_as_the_fault_model_does_for_the_same_calls():
    """[swarm.link] with loss and jitter: the shares the companion keeps are exactly those a NeighbourLink
    of the same config and seed delivers for (stamp, sender, us, sender position, our position), and each
    is applied only once our clock reaches its delivery time."""
    scenario = _scenario(loss_probability=0.4, latency_s=0.3, jitter_s=0.2)
    swarm, clock, _ = _link(ident=1, scenario=scenario, seed=5)
    reference = NeighbourLink(scenario.swarm.link, 3, 5)
    expected = []
    for k in range(200):
        stamp = 10.0 + 0.2 * k
        clock.now = stamp
        sender = 2 + k % 2
        position = (20.0 + k, 0.0, -20.0)
        swarm.on_share(_share(sender=sender, seq=k, stamp=stamp, position=position))
        decision = reference.transmit(stamp, sender, 1, np.array(position), clock.position)
        expected.append(decision)
    assert swarm.link_dropped == {"loss": sum(not d.delivered for d in expected)}
    delivered = sorted(d.time for d in expected if d.delivered)
    applied_at = []
    for now in np.arange(10.0, 10.0 + 0.2 * 200 + 1.0, 0.01):
        before = swarm.applied
        swarm.step_inputs(float(now))
        applied_at += [float(now)] * (swarm.applied - before)
    assert len(applied_at) == len(delivered)
    for due, applied in zip(delivered, applied_at):
        assert due <= applied + 1e-9 < due + 0.01 + 1e-9


def test_shares_are_applied_on_odometry_before_the_follower_runs_and_their_bearings_not_kept():
    """Taking off (no follower yet): a long climb of shares never fills the held queue, the neighbours are
    known, and the bearings that came then are not handed to the pipeline when it starts."""
    swarm, clock, _ = _link(scenario=_scenario(latency_s=0.1))
    bearing = link.SharedBearing(0.0, (0.0, 1.0, 0.0), (19.0, 0.0, -20.0))
    for k in range(3 * MAX_HELD):
        clock.now = 0.2 * k
        swarm.on_share(_share(seq=k, stamp=clock.now, bearing=link.SharedBearing(clock.now, bearing.direction, bearing.position)))
        swarm.on_sample(Sample(PursuerState(clock.now + 0.15, np.zeros(3), np.zeros(3))))
    assert swarm.rejected == {} and swarm.applied == 3 * MAX_HELD
    neighbours, bearings = swarm.step_inputs(clock.now + 0.15)
    assert [n.ident for n in neighbours] == [2] and bearings == []


def test_held_shares_are_bounded():
    swarm, clock, _ = _link(scenario=_scenario(latency_s=100.0))
    for k in range(MAX_HELD + 50):
        clock.now = 10.0 + 0.2 * k
        swarm.on_share(_share(seq=k, stamp=clock.now))
    assert swarm.accepted == MAX_HELD and swarm.rejected == {"queue_full": 50}


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.binary(max_size=400),
                 st.dictionaries(st.sampled_from(["schema", "sender", "seq", "stamp", "epoch", "position", "velocity",
                                                  "bearing", "estimate", "extra"]),
                                 st.one_of(st.none(), st.integers(-5, 2**64), st.floats(allow_nan=True),
                                           st.text(max_size=8), st.lists(st.floats(-1e7, 1e7), max_size=4)))
                 .map(lambda d: json.dumps({"schema": link.PURSUER_SHARE_SCHEMA, **d}).encode())))
def test_no_payload_raises_and_every_one_is_counted_once(payload):
    swarm, _, _ = _link(ident=1)
    swarm.on_share(payload)
    swarm.step_inputs(20.0)
    assert swarm.received == 1 == swarm.accepted + sum(swarm.rejected.values())
    for neighbour in swarm.neighbours.values():
        assert 1 <= neighbour.ident <= 3 and neighbour.ident != 1
        assert np.all(np.isfinite(neighbour.position)) and math.isfinite(neighbour.time)


def test_the_receive_log_stays_bounded_under_a_flood(tmp_path):
    swarm, _, _ = _link(log_folder=tmp_path)
    for k in range(5000):
        swarm.on_share(b"not json" if k % 2 else _share(sender=1, seq=k))
    swarm.close()
    lines = (tmp_path / "swarm_rx.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    assert len(lines) < 100
    counted = sum(r["count"] for r in records if r.get("kind") == "suppressed")
    verbatim = sum(1 for r in records if r.get("verdict") == "rejected")
    assert counted + verbatim == 5000 == sum(swarm.rejected.values())
