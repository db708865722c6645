"""Every target fix (and every command) is checked before it can act (both harnesses use this).

decode (schema, types, finite numbers, ranges: interfaces.link_schema) -> sender id ->
freshness against the receiver's clock -> sequence and time-stamp order per (sender, epoch)
-> physically plausible jump from the last accepted fix, or a re-anchor rule that a liar
cannot take over. A fix that fails any check is rejected with a reason and counted; it never
reaches the filter and changes no state that a later genuine fix is checked against.

No clock of its own: the caller passes ``now``, its current time in the clock the stamps use
(simulated seconds: the vehicle's odometry time in the companion, the loop time in process).
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.core.geometry import norm

#: Every reason a FixValidator counts besides the decoder's (interfaces.link_schema.REASONS).
REASONS = ("wrong_sender", "no_clock", "future_stamp", "too_old", "stale_seq", "stale_stamp", "seq_jump",
           "other_epoch", "contested", "implausible_jump")

#: agrees(position NED m (3,), stamp s) -> True/False (does the bearing from the own position at `stamp` to
#: `position` agree with the filter's prediction?), or None when the filter cannot say (not engaged, no own state).
Agreement = Callable[[np.ndarray, float], "bool | None"]


class FixRejected(ValueError):
    """A fix the companion will not use; `reason` is a short code (see FixValidator)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True)
class FreshnessPolicy:
    """How a message's envelope is checked against the receiver's clock and its sender's history.

    max_future_skew: s a stamp may be ahead of the receiver's ``now`` (clock offset and
    transport jitter) before it is ``future_stamp``. max_age: s a stamp may be behind
    ``now`` before it is ``too_old``. max_rate_hz, seq_slack: within one (sender, epoch),
    ``seq`` may advance by at most max_rate_hz x (stamp advance) + seq_slack
    (``seq_jump`` beyond: no jump to 2**62 becomes the reference). max_epochs: (sender,
    epoch) order states kept; beyond it the one with the fewest accepted messages (the
    least recently accepted among equals) is forgotten, so an invented-epoch flood neither
    grows memory nor pushes out the long-lived genuine epoch.
    """

    max_future_skew: float = 0.5
    max_age: float = 2.0
    max_rate_hz: float = 50.0
    seq_slack: int = 10
    max_epochs: int = 16

    def __post_init__(self) -> None:
        if not (self.max_future_skew >= 0 and self.max_age > 0 and self.max_rate_hz > 0 and self.seq_slack >= 0
                and self.max_epochs >= 1):
            raise ValueError(f"FreshnessPolicy: bad settings {self}")


class _Order:
    """Per-(sender, epoch) seq/stamp order, bounded (FreshnessPolicy.max_epochs; fewest accepted out first)."""

    def __init__(self, policy: FreshnessPolicy) -> None:
        self.policy = policy
        self.states: collections.OrderedDict[tuple, tuple[int, float]] = collections.OrderedDict()
        self.counts: dict[tuple, int] = {}
        self.contested: set[tuple] = set()  # keys proven to carry two sources (FixValidator, "conflict")

    def check(self, key: tuple, seq: int, stamp: float, now: float | None) -> tuple[int, float] | None:
        """FixRejected (freshness, order) or the key's (last seq, last stamp) (None: an epoch not held)."""
        self.check_fresh(stamp, now)
        last = self.states.get(key)
        if last is not None:
            last_seq, last_stamp = last
            if seq <= last_seq:
                raise FixRejected("stale_seq", f"seq {seq} after {last_seq}")
            if stamp <= last_stamp:
                raise FixRejected("stale_stamp", f"stamp {stamp} after {last_stamp}")
            self.check_rate(last_seq, last_stamp, seq, stamp)
        return last

    def check_fresh(self, stamp: float, now: float | None) -> None:
        """FixRejected future_stamp / too_old for a stamp outside [now - max_age, now + max_future_skew]."""
        policy = self.policy
        if now is not None:
            if stamp > now + policy.max_future_skew:
                raise FixRejected("future_stamp", f"stamp {stamp:.3f} s is {stamp - now:.3f} s ahead of now")
            if stamp < now - policy.max_age:
                raise FixRejected("too_old", f"stamp {stamp:.3f} s is {now - stamp:.3f} s old")

    def check_rate(self, last_seq: int, last_stamp: float, seq: int, stamp: float) -> None:
        """FixRejected seq_jump when seq advanced faster than the policy allows since (last_seq, last_stamp)."""
        policy = self.policy
        if seq - last_seq > policy.max_rate_hz * (stamp - last_stamp) + policy.seq_slack:
            raise FixRejected("seq_jump", f"seq {last_seq} -> {seq} in {stamp - last_stamp:.3f} s")

    def reset(self, key: tuple, seq: int, stamp: float) -> None:
        """Make (seq, stamp) the key's last accepted message, even if an accepted forgery was ahead of it."""
        if key in self.states:
            self.states[key] = (seq, stamp)

    def accept(self, key: tuple, seq: int, stamp: float) -> None:
        last = self.states.get(key)
        if last is None or stamp > last[1]:
            self.states[key] = (seq, stamp)
        self.states.move_to_end(key)
        self.counts[key] = self.counts.get(key, 0) + 1
        while len(self.states) > self.policy.max_epochs:
            # min() over the insertion order (least recently accepted first) keeps the first of equals.
            victim = min((k for k in self.states if k != key), key=lambda k: self.counts[k])
            del self.states[victim], self.counts[victim]
            self.contested.discard(victim)


@dataclass
class _Track:
    """A run of mutually consistent fixes that disagree with the reference (a re-anchor candidate)."""

    epoch: int | None
    seq: int
    stamp: float
    position: np.ndarray
    count: int


class FixValidator:
    """Accepts or rejects target fixes, in arrival order.

    Reasons: any interfaces.link_schema decode reason (counted through `reject`), plus
    wrong_sender (not the configured target), no_clock (the caller has no time yet),
    future_stamp / too_old (outside [now - max_age, now + max_future_skew]), stale_seq /
    stale_stamp (not after the last accepted fix of the same epoch, or, from an epoch not
    held, not after the reference), seq_jump (seq advanced faster than the policy allows),
    other_epoch (a fix of another epoch than the reference's while the reference's epoch
    still speaks), implausible_jump (the target would have moved faster than
    max_target_speed, plus jump_margin metres of noise, since the reference: the last
    accepted fix), contested (see Conflict).

    Order is per epoch (the publisher's boot id): a restarted publisher (new epoch, seq from
    0) is not stale, but a new epoch earns nothing for being new: the track stays with the
    reference's epoch while it speaks, and another epoch takes over only once nothing has been
    accepted for epoch_switch s, with fixes that are fresh, newer than the reference and
    plausible like any other. Rejected fixes change no order state, so no single message (a
    seq of 2**62, a stamp 1e6 s ahead, a replay) locks the genuine target out, and a second
    source inventing its own epoch cannot interleave with the genuine one.

    Re-anchor: fixes that are implausible against the reference but consistent with each
    other form a candidate track (at most max_candidates kept). After reanchor_after of
    them the candidate becomes the reference only if (a) its latest fix agrees with the
    bearing the filter predicts while the reference does not (``agrees``, from the pipeline
    owner), or (b) the reference's track has gone silent: no fix accepted for silence s.
    A liar publishing beside a genuine target that keeps publishing therefore never takes
    the track unless it lies along the predicted line of sight (which a bearing-only filter
    cannot see anyway).

    Conflict: a liar who overheard the genuine epoch and speaks first can get a plausible
    fix in with a seq or stamp just ahead, making the genuine next fix look stale. When a fix
    of the reference's epoch is stale only because of the reference (in order after the fix
    accepted before it) and the two are mutually implausible, the epoch carries two
    sources: it is marked contested, the filter arbitrates (the new fix replaces the
    reference when its line of sight agrees with the prediction and the reference's does not:
    rule "conflict"), and from then on a fix of that epoch farther than jump_margin +
    contested_speed (10 m/s) x dt from the reference extrapolated at its own velocity (last
    two fixes) is refused (``contested``): the liar, who already meets the looser plausibility
    bound, no longer interleaves with the genuine track. The liar's first fix, accepted before
    the conflict showed, is the price.

    Two sources, whatever they say: a patient liar republishes each genuine fix a little ahead
    (seq + 1, the next stamp, a slow drift) and is plausible, first and self-consistent. A single
    publisher never sends two different fixes under one seq of one epoch, and never has its fresh
    fixes refused as out of order at the rate it publishes. So either, for fixes plausible against the
    reference (a far-off one cannot take the track and is refused as before), is proof of a second source
    in the epoch: a fix whose seq an accepted fix of the reference's epoch already carried with
    another stamp or position (``duplicate_seq``, twice within contest_window s, so that no single
    message holds the track; an exact copy, a duplicate or a replay, proves nothing), or at least contest_count fresh, out-of-order fixes (not copies) within contest_window
    s that are at least contest_share of the fixes accepted meanwhile (``stale_rate``). On proof
    the filter arbitrates as above; when it cannot tell the two apart (both agree with the
    prediction: the lie is close), the track is held: every fix is refused ``contested``, from
    every epoch, so the estimator is fed by neither source and the pipeline flies its safe
    standoff. The hold ends when one source is confirmed: by the prediction (a new proof that the
    filter can arbitrate), by the other going silent (contest_clear s of fresh, in-order fixes
    with no new proof: the survivor becomes the reference, rule "contest_cleared"), or by the
    held epoch falling silent for silence s. Authentication (TLS, upstream of this check) is the
    third confirmation: with it an outsider cannot speak at all. On a plain link any peer that
    hears the target can therefore hold the track (the pursuer stands off), but not steer it.
    `contested` says whether the track is held now; `contests` lists the holds.

    target_sender: expected sender id. max_target_speed: m/s. jump_margin: m. policy:
    freshness and order (FreshnessPolicy). silence: s. reanchor_after: fixes. epoch_switch: s.
    contest_window: s; contest_count: fixes; contest_share: dimensionless; contest_clear: s.
    """

    #: Accepted fixes of the reference's epoch remembered for the duplicate_seq proof.
    SEEN = 256
    #: Holds kept in `contests` (the count goes on in `contest_count_total`).
    MAX_CONTESTS = 100

    def __init__(self, target_sender: str, *, max_target_speed: float = 30.0, jump_margin: float = 5.0,
                 policy: FreshnessPolicy | None = None, silence: float = 2.0, reanchor_after: int = 3,
                 max_candidates: int = 4, epoch_switch: float = 0.5, contest_window: float = 2.0,
                 contest_count: int = 5, contest_share: float = 0.8, contest_clear: float = 2.0) -> None:
        self.target_sender = target_sender
        self.max_target_speed = float(max_target_speed)
        self.jump_margin = float(jump_margin)
        self.policy = policy if policy is not None else FreshnessPolicy()
        self.silence = float(silence)
        self.epoch_switch = float(epoch_switch)
        self.reanchor_after = int(reanchor_after)
        self.max_candidates = int(max_candidates)
        self.rejected: collections.Counter[str] = collections.Counter()
        self.accepted = 0
        self.reanchored = 0
        self.reanchors: list[tuple[float, str]] = []  # (stamp s, rule "prediction" or "silence")
        self.last_seq: int | None = None
        self.last_stamp: float | None = None
        self.last_position: np.ndarray | None = None
        self.last_epoch: int | None = None
        self._last_accept_time: float | None = None  # `now` (or stamp without a clock) of the last acceptance
        self._order = _Order(self.policy)
        self._candidates: list[_Track] = []
        self._previous: tuple[int, float] = (-1, -math.inf)  # (seq, stamp) accepted before the reference, same epoch
        self._previous_position: np.ndarray | None = None
        self.contested_speed = 10.0  # m/s: velocity change allowed per second of extrapolation in a contested epoch
        if not (contest_window > 0 and contest_count >= 1 and 0 <= contest_share <= 1 and contest_clear > 0):
            raise ValueError("need contest_window > 0, contest_count >= 1, 0 <= contest_share <= 1, contest_clear > 0")
        self.contest_window = float(contest_window)
        self.contest_count = int(contest_count)
        self.contest_share = float(contest_share)
        self.contest_clear = float(contest_clear)
        self._seen: collections.OrderedDict[int, tuple[float, np.ndarray]] = collections.OrderedDict()
        self._stale: collections.deque[float] = collections.deque()  # clock of fresh out-of-order fixes (not copies)
        self._collisions: collections.deque[float] = collections.deque()  # clock of duplicate_seq collisions
        self._accepts: collections.deque[float] = collections.deque()  # clock of accepted fixes, same window
        self._hold: _Hold | None = None
        self.contests: list[dict] = []  # {"start", "end" (None while held), "proof", "ended"} in the clock of `now`
        self.contest_count_total = 0

    @property
    def contested(self) -> bool:
        """Whether the track is held now: two sources proven in one epoch and neither confirmed (class docstring)."""
        return self._hold is not None

    @property
    def epochs_held(self) -> int:
        """Epochs whose order is remembered (bounded by policy.max_epochs)."""
        return len(self._order.states)

    def _plausible(self, position: np.ndarray, stamp: float, reference: np.ndarray, reference_stamp: float) -> bool:
        jump = norm(position - reference)  # np.linalg.norm's bits (geometry.norm), without its wrapper
        return math.isfinite(jump) and jump <= self.max_target_speed * abs(stamp - reference_stamp) + self.jump_margin

    def reject(self, reason: str) -> None:
        """Count a fix refused before it reached the validator (e.g. a payload that did not decode)."""
        self.rejected[reason] += 1

    def check(self, sender: str, seq: int, stamp: float, position: np.ndarray, *, epoch: int | None = None,
              now: float | None = None, agrees: Agreement | None = None) -> np.ndarray:
        """The NED position (m, shape (3,)) of an acceptable fix; FixRejected (counted) otherwise.

        sender, seq, stamp (s), epoch (None for a v1 fix): the fix's envelope. position: NED, m,
        shape (3,). now: the receiver's time, s, in the stamps' clock (None: freshness is not
        checked; callers with a clock that has no time yet reject with "no_clock" instead).
        agrees: the filter's verdict on a fix's bearing (re-anchor rule (a)); None: rule (b) only.
        """
        try:
            return self._check(sender, epoch, seq, float(stamp), np.asarray(position, dtype=float), now, agrees)
        except FixRejected as error:
            self.rejected[error.reason] += 1
            raise

    def _check(self, sender: str, epoch: int | None, seq: int, stamp: float, position: np.ndarray,
               now: float | None, agrees: Agreement | None) -> np.ndarray:
        if sender != self.target_sender:
            raise FixRejected("wrong_sender", f"sender {sender!r}, expected {self.target_sender!r}")
        key = (sender, epoch)
        clock = stamp if now is None else now
        if self._hold is not None:
            return self._while_held(key, epoch, seq, stamp, position, now, clock, agrees)
        try:
            held = self._order.check(key, seq, stamp, now)
        except FixRejected as error:
            if error.reason in ("stale_seq", "stale_stamp") and epoch == self.last_epoch:
                proof = self._second_source(seq, stamp, position, clock)
                if proof is not None:
                    return self._contest(key, proof, seq, stamp, position, clock, agrees)
            if error.reason in ("stale_seq", "stale_stamp") and self._conflicts(epoch, seq, stamp, position):
                return self._arbitrate(key, error, seq, stamp, position, now, agrees)
            raise
        if key in self._order.contested and epoch == self.last_epoch and not self._on_track(position, stamp):
            raise FixRejected("contested", f"epoch {epoch} carries two sources; this fix is off the reference's track")
        other = self.last_position is not None and epoch != self.last_epoch
        if (held is None or other) and self.last_stamp is not None and stamp <= self.last_stamp:
            raise FixRejected("stale_stamp", f"stamp {stamp} of epoch {epoch} not after the reference {self.last_stamp}")
        reanchor = False
        plausible = self.last_position is None or self._plausible(position, stamp, self.last_position, self.last_stamp)
        if plausible and other and (stamp if now is None else now) - self._last_accept_time < self.epoch_switch:
            raise FixRejected("other_epoch", f"epoch {epoch} while the reference's epoch {self.last_epoch} speaks")
        if not plausible:
            rule = self._candidate(epoch, seq, stamp, position, now, agrees)
            if rule is None:
                jump = norm(position - self.last_position)
                raise FixRejected("implausible_jump", f"{jump:.1f} m in {stamp - self.last_stamp:.2f} s")
            self.reanchored += 1
            self.reanchors.append((stamp, rule))
            self._candidates.clear()
            reanchor = True
        self.accepted += 1
        self._order.accept(key, seq, stamp)
        self._last_accept_time = clock
        if reanchor or self.last_stamp is None or stamp > self.last_stamp:  # the reference never goes back in time
            self._set_reference(epoch, seq, stamp, position)
        self._remember(epoch, seq, stamp, position, clock)
        return position

    # ----------------------------------------------------------------------------- two sources in one epoch

    def _remember(self, epoch: int | None, seq: int, stamp: float, position: np.ndarray, clock: float) -> None:
        """Keep an accepted fix of the reference's epoch for the duplicate_seq proof (SEEN of them)."""
        if epoch != self.last_epoch:
            return
        self._seen[seq] = (stamp, position)
        self._seen.move_to_end(seq)
        while len(self._seen) > self.SEEN:
            self._seen.popitem(last=False)
        self._accepts.append(clock)
        _trim(self._accepts, clock - self.contest_window)

    def _second_source(self, seq: int, stamp: float, position: np.ndarray, clock: float) -> tuple | None:
        """A fresh, out-of-order fix of the reference's epoch: the proof it gives of a second source, or None.

        ("duplicate_seq", stamp, position of the accepted fix it collides with) or ("stale_rate", the reference's
        stamp and position): see the class docstring."""
        if self.last_position is None or not self._plausible(position, stamp, self.last_position, self.last_stamp):
            return None  # a fix that could not be the target's anyway: refused as it is, it cannot take the track
        seen = self._seen.get(seq)
        if seen is not None:
            if _same_fix(seen, stamp, position):
                return None  # a copy (duplicate, replay): one source
            # One collision is one message, which alone must not hold the genuine track: the second within
            # contest_window is the proof.
            self._collisions.append(clock)
            _trim(self._collisions, clock - self.contest_window)
            return ("duplicate_seq", seen[0], seen[1]) if len(self._collisions) >= 2 else None
        if any(_same_fix(other, stamp, position) for other in self._seen.values()):
            return None  # a replay of an accepted fix under another seq is no second publisher either
        self._stale.append(clock)
        _trim(self._stale, clock - self.contest_window)
        _trim(self._accepts, clock - self.contest_window)
        if len(self._stale) >= max(self.contest_count, self.contest_share * len(self._accepts)):
            return ("stale_rate", self.last_stamp, self.last_position)
        return None

    def _contest(self, key: tuple, proof: tuple, seq: int, stamp: float, position: np.ndarray, clock: float,
                 agrees: Agreement | None) -> np.ndarray:
        """Proof of two sources: the filter arbitrates (the new fix replaces the reference, rule "conflict"; or the
        reference stays and the new one is refused), else the track is held (class docstring)."""
        rule, other_stamp, other_position = proof
        verdict = _arbitration(agrees, position, stamp, other_position, other_stamp)
        self._order.contested.add(key)  # from now on fixes far off the reference's track are refused
        if verdict == "new":
            self._take(key, seq, stamp, position, clock, "conflict")
            return position
        if verdict == "reference":
            raise FixRejected("contested", f"epoch {key[1]} carries two sources ({rule}); the filter sides with the reference")
        self._hold = _Hold(key, clock, clock, clock, (seq, stamp, position), {seq: (stamp, position)})
        self.contest_count_total += 1
        self.contests.append({"start": clock, "end": None, "proof": rule, "ended": None})
        del self.contests[:-self.MAX_CONTESTS]
        raise FixRejected("contested", f"epoch {key[1]} carries two sources ({rule}); the track is held")

    def _take(self, key: tuple, seq: int, stamp: float, position: np.ndarray, clock: float, rule: str) -> None:
        """Make the fix the reference (a confirmed source) and accept it."""
        self._order.reset(key, seq, stamp)
        if key not in self._order.states:
            self._order.accept(key, seq, stamp)
        self.reanchored += 1
        self.reanchors.append((stamp, rule))
        self.accepted += 1
        self._last_accept_time = clock
        self._seen.clear()
        self._stale.clear()
        self._collisions.clear()
        self._previous, self._previous_position = (-1, -math.inf), None
        self.last_seq, self.last_stamp, self.last_position, self.last_epoch = seq, stamp, position, key[1]
        self._remember(key[1], seq, stamp, position, clock)

    def _end_hold(self, clock: float, how: str) -> None:
        self._hold = None
        if self.contests and self.contests[-1]["end"] is None:
            self.contests[-1].update(end=clock, ended=how)

    def _while_held(self, key: tuple, epoch: int | None, seq: int, stamp: float, position: np.ndarray,
                    now: float | None, clock: float, agrees: Agreement | None) -> np.ndarray:
        """A fix while the track is held: watched for a new proof, refused until one source is confirmed."""
        hold = self._hold
        if clock - hold.last_seen >= self.silence:
            self._end_hold(clock, "silence")  # the held epoch fell silent: the usual rules again
            return self._check(key[0], epoch, seq, stamp, position, now, agrees)
        self._order.check_fresh(stamp, now)
        if key != hold.key:
            raise FixRejected("contested", f"epoch {epoch} while the track is held (two sources in epoch {hold.key[1]})")
        hold.last_seen = clock
        last_seq, last_stamp, last_position = hold.latest
        other = hold.seen.get(seq)
        if other is not None and _same_fix(other, stamp, position):
            raise FixRejected("contested", f"a copy of seq {seq} while the track is held")
        if (other is not None or seq <= last_seq or stamp <= last_stamp
                or not self._plausible(position, stamp, last_position, last_stamp)):
            hold.last_evidence = clock  # the second source still speaks (out of order, or off the other's track)
            other_stamp, other_position = other if other is not None else (last_stamp, last_position)
            if _arbitration(agrees, position, stamp, other_position, other_stamp) == "new":
                self._end_hold(clock, "prediction")
                self._take(key, seq, stamp, position, clock, "conflict")
                return position
            raise FixRejected("contested", f"epoch {epoch} still carries two sources; the track is held")
        self._order.check_rate(last_seq, last_stamp, seq, stamp)
        hold.latest = (seq, stamp, position)
        hold.seen[seq] = (stamp, position)
        if len(hold.seen) > self.SEEN:
            hold.seen.pop(next(iter(hold.seen)))
        if clock - hold.last_evidence < self.contest_clear:
            raise FixRejected("contested", f"epoch {epoch} carried two sources {clock - hold.last_evidence:.2f} s ago; "
                                           "the track is held")
        self._end_hold(clock, "other_silent")
        self._take(key, seq, stamp, position, clock, "contest_cleared")
        return position

    def _set_reference(self, epoch: int | None, seq: int, stamp: float, position: np.ndarray) -> None:
        same = self.last_stamp is not None and epoch == self.last_epoch
        self._previous = (self.last_seq, self.last_stamp) if same else (-1, -math.inf)
        self._previous_position = self.last_position if same else None
        self.last_seq, self.last_stamp, self.last_position, self.last_epoch = seq, stamp, position, epoch

    def _on_track(self, position: np.ndarray, stamp: float) -> bool:
        """In a contested epoch: within jump_margin + contested_speed x dt of the reference extrapolated at the
        velocity of its last two fixes (a tighter bound than plausibility, which the liar already meets)."""
        dt = stamp - self.last_stamp
        velocity = np.zeros(3)
        if self._previous_position is not None and self.last_stamp - self._previous[1] > 1e-6:
            velocity = (self.last_position - self._previous_position) / (self.last_stamp - self._previous[1])
        miss = norm(position - self.last_position - velocity * dt)
        return math.isfinite(miss) and miss <= self.jump_margin + self.contested_speed * abs(dt)

    def _conflicts(self, epoch: int | None, seq: int, stamp: float, position: np.ndarray) -> bool:
        """Whether an order-stale fix proves a second source in the reference's epoch (class docstring)."""
        if self.last_position is None or epoch != self.last_epoch:
            return False
        previous_seq, previous_stamp = self._previous
        return (seq > previous_seq and stamp > previous_stamp
                and not self._plausible(position, stamp, self.last_position, self.last_stamp))

    def _arbitrate(self, key: tuple, error: FixRejected, seq: int, stamp: float, position: np.ndarray,
                   now: float | None, agrees: Agreement | None) -> np.ndarray:
        """Two sources in one epoch: the filter decides whether `position` replaces the reference; else `error`."""
        self._order.contested.add(key)
        if _arbitration(agrees, position, stamp, self.last_position, self.last_stamp) != "new":
            raise error
        self._order.reset(key, seq, stamp)
        self.reanchored += 1
        self.reanchors.append((stamp, "conflict"))
        self.accepted += 1
        self._last_accept_time = stamp if now is None else now
        self._seen.pop(self.last_seq, None)  # the refuted fix proves nothing more
        self.last_seq, self.last_stamp, self.last_position = seq, stamp, position  # the previous fix stays
        self._remember(self.last_epoch, seq, stamp, position, self._last_accept_time)
        return position

    def _candidate(self, epoch: int | None, seq: int, stamp: float, position: np.ndarray, now: float | None,
                   agrees: Agreement | None) -> str | None:
        """Add the fix to its candidate track; the re-anchor rule that lets it in ("prediction", "silence") or None."""
        track = next((c for c in self._candidates if c.epoch == epoch and c.seq < seq and c.stamp < stamp
                      and self._plausible(position, stamp, c.position, c.stamp)), None)
        if track is None:
            track = _Track(epoch, seq, stamp, position, 1)
            self._candidates.append(track)
            if len(self._candidates) > self.max_candidates:
                self._candidates.pop(0)  # the oldest-started candidate goes
        else:
            track.seq, track.stamp, track.position, track.count = seq, stamp, position, track.count + 1
        if track.count < self.reanchor_after:
            return None
        clock = stamp if now is None else now
        if self._last_accept_time is not None and clock - self._last_accept_time >= self.silence:
            return "silence"
        if _arbitration(agrees, position, stamp, self.last_position, self.last_stamp) == "new":
            return "prediction"
        return None


@dataclass
class _Hold:
    """A held track (FixValidator, "Two sources"): the held (sender, epoch), clock s of its start, of the last proof
    and of the last fix heard, the newest in-order fix heard (seq, stamp, position) and the fixes heard by seq."""

    key: tuple
    start: float
    last_evidence: float
    last_seen: float
    latest: tuple
    seen: dict


def _same_fix(seen: tuple[float, np.ndarray], stamp: float, position: np.ndarray) -> bool:
    """Whether (stamp s, NED position m) is the remembered fix itself (a copy), within float noise."""
    return abs(seen[0] - stamp) <= 1e-9 and bool(np.all(np.abs(seen[1] - position) <= 1e-6))


def _trim(times: collections.deque, before: float) -> None:
    while times and times[0] < before:
        times.popleft()


def _arbitration(agrees: Agreement | None, position: np.ndarray, stamp: float, other_position: np.ndarray,
                 other_stamp: float) -> str | None:
    """"new" when the filter's prediction agrees with the new fix and not with the other, "reference" when the
    reverse, None when it cannot tell them apart (or cannot say)."""
    if agrees is None:
        return None
    new, old = agrees(position, stamp), agrees(other_position, other_stamp)
    if new is True and old is False:
        return "new"
    if new is False and old is True:
        return "reference"
    return None


class CommandValidator:
    """Freshness and order of commands (abort, resume, start) per (sender, epoch), as for fixes.

    Reasons: no_clock, future_stamp, too_old, stale_seq, stale_stamp, seq_jump
    (FreshnessPolicy; a replayed, reordered or far-future command is refused and changes
    nothing). It does not authenticate: who may send commands is the transport's business
    (Zenoh access control). policy: FreshnessPolicy (default: 10 commands/s, 0.5 s skew,
    2 s old at most).
    """

    def __init__(self, policy: FreshnessPolicy | None = None) -> None:
        self.policy = policy if policy is not None else FreshnessPolicy(max_rate_hz=10.0)
        self.rejected: collections.Counter[str] = collections.Counter()
        self.accepted = 0
        self._order = _Order(self.policy)

    def check(self, sender: str, epoch: int | None, seq: int, stamp: float, now: float | None) -> None:
        """Return if the command may act; FixRejected (counted) otherwise. now: receiver time, s (None: no_clock)."""
        try:
            if now is None:
                raise FixRejected("no_clock", "no time yet to check the command's stamp against")
            self._order.check((sender, epoch), seq, float(stamp), now)
        except FixRejected as error:
            self.rejected[error.reason] += 1
            raise
        self._order.accept((sender, epoch), seq, float(stamp))
        self.accepted += 1
