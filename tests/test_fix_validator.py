"""Target-fix validation: every rejection reason, and recovery after a bad reference."""

from __future__ import annotations

import numpy as np
import pytest

from interfaces import link_schema as link
from companion.core.fix_validator import FixRejected, FixValidator
from companion.fix_intake import FixIntake

HOME = (47.397742, 8.545594, 488.0)


def _fix(seq, stamp, position, sender="target-1", epoch=7):
    return link.encode_target_fix(link.TargetFix(sender, seq, stamp, "ned", position, epoch=epoch))


def test_accepts_a_plausible_stream_and_converts_to_ned():
    intake = FixIntake(FixValidator("target-1"), HOME)
    validator = intake.validator
    for k in range(10):
        fix, position = intake.check(_fix(k, 0.2 * k, (50.0 + 0.6 * k, -25.0 + 0.8 * k, -20.0)))
        np.testing.assert_allclose(position, [50.0 + 0.6 * k, -25.0 + 0.8 * k, -20.0])
    assert validator.accepted == 10 and not validator.rejected


@pytest.mark.parametrize(
    "payload, reason",
    [
        (_fix(5, 1.2, (50.0, -25.0, -20.0), sender="impostor-1"), "wrong_sender"),
        (_fix(1, 1.2, (50.0, -25.0, -20.0)), "stale_seq"),
        (_fix(5, 1.0, (50.0, -25.0, -20.0)), "stale_stamp"),
        (_fix(5, 1.2, (400.0, -25.0, -20.0)), "implausible_jump"),
        (b"{not json", "not_json"),
        (b'{"schema": "bof.target_fix/1", "sender": "target-1", "seq": 5, "stamp": 1.2, "frame": "ned", "position": [NaN, 0, 0]}', "not_finite"),
    ],
    ids=["wrong-sender", "stale-seq", "stale-stamp", "jump", "not-json", "nan"],
)
def test_each_rejection_reason_is_counted_and_the_state_is_kept(payload, reason):
    intake = FixIntake(FixValidator("target-1"), HOME)
    validator = intake.validator
    intake.check(_fix(1, 1.0, (50.0, -25.0, -20.0)))
    with pytest.raises(FixRejected) as error:
        intake.check(payload)
    assert error.value.reason == reason
    assert validator.rejected == {reason: 1}
    assert (validator.last_seq, validator.last_stamp) == (1, 1.0)  # a reject changes nothing
    intake.check(_fix(2, 1.2, (50.5, -25.0, -20.0)))
    assert validator.accepted == 2


def test_a_consistent_run_re_anchors_only_after_the_reference_went_silent():
    intake = FixIntake(FixValidator("target-1", silence=2.0), HOME)
    validator = intake.validator
    intake.check(_fix(0, 0.0, (0.0, 0.0, -20.0)))  # a wrong reference (e.g. a glitch at start)
    for k in range(1, 10):  # 300 m away, consistent, but the reference spoke 0.2-1.8 s ago: refused
        with pytest.raises(FixRejected):
            intake.check(_fix(k, 0.2 * k - 0.1, (300.0 + 0.5 * k, 0.0, -20.0)), now=0.2 * k)
    fix, position = intake.check(_fix(10, 1.9, (305.0, 0.0, -20.0)), now=2.0)  # silent for 2.0 s: taken
    assert validator.reanchored == 1 and validator.reanchors == [(1.9, "silence")] and position[0] == 305.0
    intake.check(_fix(12, 2.3, (306.0, 0.0, -20.0)), now=2.4)
    assert validator.rejected == {"implausible_jump": 9}
    # Outliers, however consistent, do not re-anchor before the reference has been silent for 2 s.
    for k, north in enumerate((600.0, 900.0) * 5, start=13):
        with pytest.raises(FixRejected):
            intake.check(_fix(k, 2.3 + 0.1 * (k - 12), (north, 0.0, -20.0)), now=2.3 + 0.1 * (k - 12))
    assert validator.reanchored == 1


# --- attacks: properties over any interleaving -----------------------------------------------
#
# The reference is the protocol the validator documents, not its code: a genuine target flying a
# straight line at up to 10 m/s publishes every PERIOD s (seq +1, stamp = the loop time, one epoch);
# an attacker slips any of the messages below between two genuine fixes. Far spoofs sit at least
# FAR m off the genuine track: beyond what max_target_speed (30 m/s) x (skew 0.5 s + one period) +
# jump_margin (5 m) + the target's own motion could explain, so no plausibility rule may take them.

from hypothesis import given, settings, strategies as st

from companion.core.fix_validator import CommandValidator, FreshnessPolicy

PERIOD = 0.2
FAR = 40.0
GENUINE_EPOCH = 12345


def _truth(start, velocity, t):
    return np.asarray(start) + np.asarray(velocity) * t


attack = st.one_of(
    st.tuples(st.just("future_seq"), st.integers(2**40, 2**62)),
    st.tuples(st.just("future_stamp"), st.floats(1.0, 1e6)),
    st.tuples(st.just("replay"), st.integers(1, 40)),
    st.tuples(st.just("spoof"), st.tuples(st.floats(FAR, 500.0), st.floats(0, 2 * np.pi), st.floats(-0.2, 0.5),
                                          st.integers(0, 2**62), st.sampled_from(["genuine", "invented"]))),
)
flight = st.tuples(
    st.tuples(st.floats(-100, 100), st.floats(-100, 100)),  # start, m
    st.tuples(st.floats(-7, 7), st.floats(-7, 7)),  # velocity, m/s (|v| < 10)
    st.lists(st.lists(attack, max_size=4), min_size=5, max_size=60),  # attacker messages before each genuine fix
    st.integers(0, 2**62),  # the attacker's invented epochs start here
)


def _attacker_fix(kind, value, k, start, velocity, history, invented):
    """(sender, epoch, seq, stamp, position) of the attacker's message slipped in before genuine fix k."""
    now = k * PERIOD
    last_seq, last_stamp = k - 1, (k - 1) * PERIOD
    if kind == "future_seq":
        return "target-1", GENUINE_EPOCH, last_seq + value, last_stamp, _truth(start, velocity, last_stamp)
    if kind == "future_stamp":
        return "target-1", GENUINE_EPOCH, last_seq + 1, last_stamp + value, _truth(start, velocity, last_stamp)
    if kind == "replay":
        return history[max(0, len(history) - value)]
    distance, angle, ahead, seq, epoch = value
    stamp = now + ahead
    offset = distance * np.array([np.cos(angle), np.sin(angle), 0.0])
    return ("target-1", GENUINE_EPOCH if epoch == "genuine" else next(invented), seq, stamp,
            _truth(start, velocity, stamp) + offset)


@settings(max_examples=300, deadline=None)
@given(flight)
def test_the_genuine_target_is_never_locked_out_and_far_liars_never_get_in(case):
    start, velocity, attacks, epoch_base = case
    start, velocity = np.array([*start, -20.0]), np.array([*velocity, 0.0])
    validator = FixValidator("target-1")
    invented = iter(range(epoch_base, epoch_base + 10**6))
    history = []
    for k, slipped in enumerate(attacks, start=0):
        now = k * PERIOD
        if k > 0:
            for kind, value in slipped:
                sender, epoch, seq, stamp, position = _attacker_fix(kind, value, k, start, velocity, history, invented)
                if stamp > 1e9 or seq >= 2**63:
                    continue
                try:
                    validator.check(sender, seq, stamp, position, epoch=epoch, now=now)
                except FixRejected:
                    continue
                # Whatever got in is the genuine track (a replay of it, a copy with a seq the bound allowed).
                assert np.linalg.norm(position - _truth(start, velocity, stamp)) < 1e-6, (kind, value)
        genuine = ("target-1", GENUINE_EPOCH, k, now, _truth(start, velocity, now))
        validator.check(genuine[0], genuine[2], genuine[3], genuine[4], epoch=genuine[1], now=now)  # never raises
        history.append(genuine)
    assert validator.accepted >= len(attacks)
    assert validator.epochs_held <= validator.policy.max_epochs and len(validator._candidates) <= validator.max_candidates


@settings(max_examples=200, deadline=None)
@given(flight, st.integers(1, 50), st.integers(0, 2**62))
def test_a_restarted_genuine_target_is_accepted_within_the_epoch_switch_time_whatever_the_attacker_sent(
        case, restart, new_epoch):
    """A restart with no gap: a new epoch, seq from 0, the same track. The new epoch is refused (other_epoch)
    only until the old one has been silent for epoch_switch (0.5 s): at most 2 fixes at 5 Hz, then all accepted."""
    start, velocity, attacks, epoch_base = case
    start, velocity = np.array([*start, -20.0]), np.array([*velocity, 0.0])
    validator = FixValidator("target-1")
    invented = iter(range(epoch_base, epoch_base + 10**6))
    history = []
    for k, slipped in enumerate(attacks):
        now = k * PERIOD
        for kind, value in slipped if k > 0 else ():
            sender, epoch, seq, stamp, position = _attacker_fix(kind, value, k, start, velocity, history, invented)
            try:
                validator.check(sender, seq, stamp, position, epoch=epoch, now=now)
            except FixRejected:
                pass
        epoch, seq = (GENUINE_EPOCH, k) if k < restart else (new_epoch if new_epoch != GENUINE_EPOCH else 0, k - restart)
        try:
            validator.check("target-1", seq, now, _truth(start, velocity, now), epoch=epoch, now=now)
        except FixRejected as error:
            assert error.reason == "other_epoch" and restart <= k < restart + 3, (k, restart, error)
        history.append(("target-1", epoch, seq, now, _truth(start, velocity, now)))


def test_an_invented_epoch_flood_of_plausible_fixes_keeps_memory_bounded_and_the_genuine_epoch():
    validator = FixValidator("target-1", policy=FreshnessPolicy(max_epochs=8))
    for k in range(50):
        now = k * PERIOD
        for j in range(100 if k else 0):  # 100 new epochs per genuine fix, each right on the track, each newer
            stamp = now - PERIOD + 0.001 * (j + 1)
            try:
                validator.check("target-1", 0, stamp, np.array([5.0 * stamp, 0.0, -20.0]), epoch=10**6 * k + j, now=now)
            except FixRejected:
                pass
        validator.check("target-1", k, now, np.array([5.0 * now, 0.0, -20.0]), epoch=GENUINE_EPOCH, now=now)
        assert validator.epochs_held <= 8
    assert validator.accepted == 50 and validator.rejected == {"other_epoch": 4900}
    # The genuine epoch's order is still held: its replays are refused.
    with pytest.raises(FixRejected, match="stale_seq"):
        validator.check("target-1", 3, 49 * PERIOD, np.array([5.0 * 49 * PERIOD, 0.0, -20.0]), epoch=GENUINE_EPOCH,
                        now=49 * PERIOD)


@pytest.mark.parametrize("stamp, reason", [(10.0 + 0.51, "future_stamp"), (10.0 + 1e6, "future_stamp"),
                                           (10.0 - 2.01, "too_old")])
def test_the_freshness_window_is_the_documented_one(stamp, reason):
    validator = FixValidator("target-1")  # defaults: 0.5 s skew, 2 s age
    with pytest.raises(FixRejected, match=reason):
        validator.check("target-1", 0, stamp, np.zeros(3), epoch=1, now=10.0)
    assert validator.last_stamp is None  # never the reference
    validator.check("target-1", 0, 10.49, np.zeros(3), epoch=1, now=10.0)
    validator.check("target-1", 1, 10.5 + 1e-9, np.zeros(3), epoch=1, now=10.0 + 1e-9)
    FixValidator("target-1").check("target-1", 0, 8.0, np.zeros(3), epoch=2, now=10.0)  # exactly 2 s old: fresh


def test_a_seq_jump_is_refused_and_a_lost_stretch_is_not():
    validator = FixValidator("target-1")  # 50 Hz + 10
    validator.check("target-1", 0, 0.0, np.zeros(3), epoch=1, now=0.0)
    with pytest.raises(FixRejected, match="seq_jump"):
        validator.check("target-1", 2**62, 0.2, np.zeros(3), epoch=1, now=0.2)
    with pytest.raises(FixRejected, match="seq_jump"):
        validator.check("target-1", 21, 0.2, np.zeros(3), epoch=1, now=0.2)  # 50 x 0.2 + 10 = 20
    validator.check("target-1", 20, 0.2, np.zeros(3), epoch=1, now=0.2)
    validator.check("target-1", 70, 10.2, np.zeros(3), epoch=1, now=10.2)  # 10 s of lost fixes at 5 Hz


def test_the_prediction_rule_re_anchors_only_when_the_filter_sides_with_the_new_track():
    """Rule (a): a consistent run that the predicted line of sight supports, while the reference's is not."""
    def run(new_agrees, old_agrees):
        validator = FixValidator("target-1")
        validator.check("target-1", 0, 0.0, np.array([0.0, 0.0, -20.0]), epoch=1, now=0.0)
        verdicts = []
        for k in range(1, 4):
            agrees = lambda position, stamp: new_agrees if position[0] > 100 else old_agrees  # noqa: E731
            try:
                validator.check("target-1", k, 0.1 * k, np.array([300.0, 0.0, -20.0]), epoch=2, now=0.1 * k,
                                agrees=agrees)
                verdicts.append(True)
            except FixRejected:
                verdicts.append(False)
        return verdicts, validator.reanchors

    assert run(True, False) == ([False, False, True], [(pytest.approx(0.3), "prediction")])
    assert run(True, True) == ([False, False, False], [])  # a lie along the line of sight changes nothing
    assert run(True, None) == ([False, False, False], [])  # the filter cannot say: no
    assert run(False, False) == ([False, False, False], [])


def test_commands_are_ordered_per_sender_and_epoch_and_fresh():
    commands = CommandValidator()
    with pytest.raises(FixRejected, match="no_clock"):
        commands.check("gcs", 1, 0, 5.0, None)
    commands.check("gcs", 1, 0, 5.0, 5.1)
    for args, reason in [((1, 0, 5.0, 5.2), "stale_seq"), ((1, 1, 5.0, 5.2), "stale_stamp"),
                         ((1, 2**62, 5.3, 5.3), "seq_jump"), ((1, 1, 5.0 + 1e6, 5.3), "future_stamp"),
                         ((1, 1, 1.0, 5.3), "too_old")]:
        with pytest.raises(FixRejected, match=reason):
            commands.check("gcs", *args)
    commands.check("gcs", 1, 1, 5.4, 5.4)  # the genuine next command still acts
    commands.check("gcs", 2, 0, 5.5, 5.5)  # a restarted ground station: new epoch, seq from 0
    assert commands.accepted == 3 and sum(commands.rejected.values()) == 6


def test_a_liar_in_the_overheard_epoch_who_speaks_first_gets_one_fix_in_then_the_filter_arbitrates():
    """Seq one ahead, the same stamps, 8 m off (plausible against the previous fix at 30 m/s), always
    first: its first fix is accepted, the genuine one then looks stale but is in order after the fix
    before: two sources in one epoch. The filter (stub: agrees within 1 m of the truth) sides with the
    genuine fix, which takes the reference back; the liar is refused from then on as off the track."""
    def truth(t):
        return np.array([5.0 * t, 0.0, -20.0])

    def agrees(position, stamp):
        return bool(np.linalg.norm(position - truth(stamp)) < 1.0)

    validator = FixValidator("target-1")
    verdicts = {"genuine": [], "liar": []}
    for k in range(40):
        t = k * PERIOD
        messages = [("genuine", k, truth(t))] if k < 5 else [("liar", k + 1, truth(t) + [8.0, 0.0, 0.0]),
                                                            ("genuine", k, truth(t))]
        for who, seq, position in messages:
            try:
                validator.check("target-1", seq, t, position, epoch=GENUINE_EPOCH, now=t, agrees=agrees)
                verdicts[who].append(True)
            except FixRejected as error:
                verdicts[who].append(error.reason)
    assert verdicts["genuine"] == [True] * 40
    assert verdicts["liar"] == [True] + ["contested"] * 34
    assert validator.reanchors == [(pytest.approx(1.0), "conflict")]


# --------------------------------------------------------------------------- two sources in one epoch
# The reference is the protocol itself: one publisher sends each seq of its epoch once (copies are
# byte-identical), in order; so two different fixes under one seq, or fresh fixes refused as out of
# order at the publishing rate, are two sources, and a stream of one source never is.


def _verdict(validator, seq, stamp, position, now, agrees=None):
    try:
        validator.check("target-1", seq, stamp, position, epoch=GENUINE_EPOCH, now=now, agrees=agrees)
        return True
    except FixRejected as error:
        return error.reason


@settings(max_examples=200, deadline=None)
@given(st.tuples(st.floats(-7, 7), st.floats(-7, 7)), st.integers(40, 150),
       st.lists(st.sampled_from(["send", "lose", "duplicate", "swap"]), min_size=150, max_size=150))
def test_one_publisher_is_never_taken_for_two_whatever_its_link_does(velocity, count, fates):
    """Losses, duplicates and reordering of single fixes (one swap with the next fix at most every 5 fixes, a
    link that reorders more loses the stream anyway) never hold the track, and the newest fix always gets in."""
    velocity = np.array([*velocity, 0.0])
    messages, last_swap = [], -10
    k = 0
    while k < count:
        fate = fates[k]
        fix = (k, k * PERIOD, _truth((0.0, 0.0, -20.0), velocity, k * PERIOD))
        if fate == "swap" and k - last_swap >= 5 and k + 1 < count:
            following = (k + 1, (k + 1) * PERIOD, _truth((0.0, 0.0, -20.0), velocity, (k + 1) * PERIOD))
            messages += [following, fix]
            last_swap, k = k, k + 2
            continue
        if fate != "lose":
            messages += [fix, fix] if fate == "duplicate" else [fix]
        k += 1
    validator = FixValidator("target-1")
    newest = -1
    for seq, stamp, position in messages:
        verdict = _verdict(validator, seq, stamp, position, now=stamp + 0.05)
        if seq > newest:
            assert verdict is True
            newest = seq
        assert not validator.contested
    assert validator.contest_count_total == 0 and validator.contests == []


@settings(max_examples=100, deadline=None)
@given(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)), st.integers(1, 8), st.integers(5, 40),
       st.integers(10, 60))
def test_a_patient_liar_holds_the_track_within_two_seconds_and_never_steers_it(drift, lead, start, duration):
    """A liar that republishes each genuine fix it hears first, seq `lead` ahead, with the next stamp, drifting
    `drift` m/s off: plausible, first and self-consistent. The track is held (every fix refused, `contested`)
    within 2 s of its first lie, no lie gets in after that, and once it falls silent the genuine fixes are
    accepted again within contest_clear once the genuine stream has overtaken the liar's last seq (lead fix
    periods) plus a fix period. agrees: None (the filter cannot tell them apart)."""
    drift, truth = np.array(drift), lambda t: np.array([5.0 * t, 0.0, -20.0])
    validator = FixValidator("target-1")
    first_lie = start * PERIOD
    held_at = None
    lies_in_after_hold = 0
    back_at = None
    for k in range(start + duration + 30):
        t = k * PERIOD
        lying = start <= k < start + duration
        if lying:
            lie = truth(t - PERIOD) + drift * (t - first_lie)
            accepted = _verdict(validator, k - 1 + lead, t, lie, now=t) is True
            lies_in_after_hold += int(accepted and held_at is not None)
        genuine = _verdict(validator, k, t, truth(t), now=t)
        if validator.contested and held_at is None:
            held_at = t
        if k >= start + duration and genuine is True and back_at is None:
            back_at = t
    assert held_at is not None and held_at - first_lie <= 2.0
    assert lies_in_after_hold == 0
    assert back_at is not None
    assert back_at - (start + duration) * PERIOD <= validator.contest_clear + (lead + 1) * PERIOD + 1e-9
    assert validator.contests[0]["proof"] in ("duplicate_seq", "stale_rate") and validator.contests[-1]["end"] is not None


def test_one_colliding_message_does_not_hold_the_track():
    """No single message may lock the genuine target out: one forged fix under the next seq gets in, the genuine
    fix under that seq is refused stale, and the next genuine fix is accepted; no hold."""
    validator = FixValidator("target-1")
    truth = lambda t: np.array([5.0 * t, 0.0, -20.0])  # noqa: E731
    for k in range(5):
        assert _verdict(validator, k, k * PERIOD, truth(k * PERIOD), now=k * PERIOD) is True
    assert _verdict(validator, 5, 1.0, truth(0.8) + [1.0, 0.0, 0.0], now=1.0) is True  # the forgery
    assert _verdict(validator, 5, 1.0, truth(1.0), now=1.0) == "stale_seq"
    assert _verdict(validator, 6, 1.2, truth(1.2), now=1.2) is True
    assert not validator.contested and validator.contest_count_total == 0


def test_the_filter_confirms_the_genuine_source_when_it_can_tell_them_apart():
    """A liar far enough off for the predicted line of sight to tell (stub: agrees within 1 m of the truth) is
    refuted at each proof: the genuine fix takes the reference back (rule "conflict"), no hold, and no two
    genuine fixes in a row are refused. (A liar this close, within jump_margin, still gets its fixes in between:
    docs/guide/faults.md, "what it cannot defend".)"""
    truth = lambda t: np.array([5.0 * t, 0.0, -20.0])  # noqa: E731
    agrees = lambda position, stamp: bool(np.linalg.norm(position - truth(stamp)) < 1.0)  # noqa: E731
    validator = FixValidator("target-1")
    verdicts = []
    for k in range(20):
        t = k * PERIOD
        if k >= 5:
            _verdict(validator, k, t, truth(t - PERIOD) + [3.0, 0.0, 0.0], now=t, agrees=agrees)
        verdicts.append(_verdict(validator, k, t, truth(t), now=t, agrees=agrees))
    assert not validator.contested and validator.contest_count_total == 0
    refused_runs = "".join("." if v is True else "x" for v in verdicts).split(".")
    assert max(len(run) for run in refused_runs) <= 1  # never two genuine fixes in a row refused
    assert "conflict" in {rule for _, rule in validator.reanchors}
