"""The companion's share link with the other pursuers of a [swarm] scenario, over Zenoh.

What studies.swarm does between its in-process pursuers, done by one networked companion (pursuer
`ident`) for itself, with the same payload and the same fault model:

* **out**: at [swarm] share_rate_hz of vehicle time (the grid k / rate, as the in-process harness), a
  ``bof.pursuer_share/1`` (interfaces.link_schema) on ``bof/swarm/<ident>/share``: the own odometry
  position and velocity at that sample, the newest own bearing not shared yet (its stamp, direction and
  the own position at its stamp), and the estimate once the pipeline has engaged.
* **in**: every share on ``bof/swarm/*/share``, checked in this order, the first failing check naming the
  reason it is rejected and counted (`rejected`): the payload's own PayloadError reason (decode);
  ``own_sender`` (our id: our own share echoed, or an impostor); ``unknown_pursuer`` (an id outside
  1..N); ``no_clock`` (no odometry yet); ``future_stamp`` (stamped more than [link] max_future_skew_s,
  the fix validator's skew, ahead of our vehicle clock); ``too_old`` (stamped more than [link] max_fix_age_s
  behind it, the fixes' age limit); ``stale_seq`` (seq not above the last one
  accepted from that sender in that epoch; a new epoch is a restarted sender and starts over, as in
  studies.swarm); ``seq_jump`` (seq further ahead of the last one than the stamps' advance at the share
  rate allows, SEQ_RATE_FACTOR x plus SEQ_SLACK: a forged seq cannot lock the sender out for longer than
  the future-stamp skew allows); ``queue_full`` (more than MAX_HELD shares held for their delivery time).
* an accepted share then meets [swarm.link] (interfaces.neighbour_link.NeighbourLink) as that module
  says a companion uses it: transmit(share stamp on the windows' clock, sender, us, share position, our newest
  position), the windows' clock counting from this pursuer's start of following (`_scenario_time`).
  Dropped (blackout, out_of_radius, loss): counted in `link_dropped`. Delivered: held until our vehicle
  clock reaches the delivery time, then applied: the sender becomes a neighbour (NeighbourState at the
  share's stamp; a share older than the one already applied from that sender updates nothing) and its
  bearing, with estimator shared_bearings or triangulation_kf, waits for the pipeline as a
  BearingMeasurement at its own stamp with source = sender.

Held shares are applied on every odometry sample (so they never pile up while the pursuer takes off or
lands). `Follower.step` asks `step_inputs(now)` for the fresh neighbours (those heard within [swarm]
neighbour_timeout_s) and the neighbours' bearings received since it last asked (from its first call on:
bearings that came while nobody flew the pipeline are not kept); the pipeline does the rest (no algorithm
here).

swarm_rx.jsonl (in the companion's log folder) records receipts through interfaces.records.AggregatingLog:
per key (``accepted:<sender>``, ``rejected:<reason>``, ``dropped:<reason>``) the first VERBATIM records in
full, then one count line per key and wall second, so a flood adds a bounded number of lines.
"""

from __future__ import annotations

import collections
import dataclasses
import heapq
import math
import time
from collections.abc import Callable

import numpy as np

from companion.core.messages import BearingMeasurement, NeighbourState
from interfaces import link_schema as link
from interfaces.neighbour_link import NeighbourLink
from interfaces.records import AggregatingLog, JsonLinesLog
from interfaces.scenario import Scenario, share_rate_hz

#: The [swarm.link] time of a share received before this pursuer began following, s: before every window (their
#: starts are >= 0), finite as NeighbourLink needs it.
BEFORE_FOLLOWING = -1.0
#: Shares held for their simulated delivery time at most (a flood cannot grow the queue).
MAX_HELD = 256
#: swarm_rx.jsonl: records per key written in full before only counts are.
VERBATIM = 20
#: Rejection reasons this module adds to link_schema.REASONS.
REASONS = ("own_sender", "unknown_pursuer", "no_clock", "future_stamp", "too_old", "stale_seq", "seq_jump", "queue_full")
#: seq may run ahead of the stamp's advance at the share rate by this factor plus SEQ_SLACK (a genuine sender
#: adds 1 per 1 / share_rate_hz s): a forged huge seq in a sender's epoch would lock the sender out.
SEQ_RATE_FACTOR = 2.0
SEQ_SLACK = 10


def swarm_companion_id(companion_id: str, pursuer_id: int) -> str:
    """Pursuer K's companion id in a [swarm] scenario: `<[link] companion_id>-<K>` (its state and command keys)."""
    return f"{companion_id}-{pursuer_id}"


class SwarmLink:
    """Pursuer `ident`'s shares out and its neighbours' in (module docstring).

    scenario: the full scenario (its [swarm], [link] max_future_skew_s, [sensor] rate). ident: this
    pursuer's id, 1..N. seed: the run's seed (the link model's stream when [swarm.link] has no seed, as
    studies.swarm). clock: newest vehicle time, s, or None. own_position: newest own NED position, m,
    (3,), or None. pipeline: returns the FollowingPipeline once there is one. log_folder: where
    swarm_rx.jsonl goes (None: no log). epoch: this publisher's boot id (default: a fresh random one).
    """

    def __init__(self, scenario: Scenario, ident: int, seed: int, clock: Callable[[], float | None],
                 own_position: Callable[[], np.ndarray | None], pipeline: Callable[[], object | None] = lambda: None,
                 log_folder=None, epoch: int | None = None) -> None:
        swarm = scenario.swarm
        if swarm is None:
            raise ValueError(f"scenario {scenario.name!r} has no [swarm]")
        if not 1 <= ident <= swarm.count:
            raise ValueError(f"pursuer id {ident} outside 1..{swarm.count}")
        self.ident = ident
        self.count = swarm.count
        self.timeout = swarm.neighbour_timeout_s
        self.uses_bearings = swarm.estimator in ("shared_bearings", "triangulation_kf")
        self.rate_hz = share_rate_hz(scenario)
        self.max_future_skew = scenario.link.max_future_skew_s
        self.max_age = scenario.link.max_fix_age_s
        self.link = NeighbourLink(swarm.link, swarm.count, seed if swarm.link.seed is None else swarm.link.seed)
        self.clock = clock
        self.own_position = own_position
        self.pipeline = pipeline
        self.epoch = link.new_epoch() if epoch is None else epoch
        self.key = link.pursuer_share_key(ident)
        self.put: Callable[[bytes], None] | None = None
        self.seq = 0
        self.sent = 0
        self.received = 0
        self.accepted = 0
        self.applied = 0
        self.rejected: collections.Counter[str] = collections.Counter()
        self.link_dropped: collections.Counter[str] = collections.Counter()
        self.neighbour_bearings_used = 0
        self.neighbours: dict[int, NeighbourState] = {}
        self._last_seq: dict[int, tuple[int, int, float]] = {}  # sender -> (epoch, seq, stamp) last accepted
        self._held: list[tuple[float, int, link.PursuerShare]] = []
        self._order = 0
        # Neighbours' bearings for the pipeline: collected only once the follower asks for them (before that
        # nobody would take them), at most MAX_HELD (the oldest go first, counted).
        self._inbox: collections.deque[BearingMeasurement] = collections.deque(maxlen=MAX_HELD)
        self._collecting = False
        self.bearings_overflowed = 0
        self._latest_bearing: BearingMeasurement | None = None
        self._shared_bearing_time = -math.inf
        self._next_share = -math.inf
        self._loop = None
        self._log = None
        if log_folder is not None:
            self._log = AggregatingLog(JsonLinesLog(log_folder / "swarm_rx.jsonl"), verbatim=VERBATIM)

    # ------------------------------------------------------------------ out
    def subscribe(self, session, loop) -> None:
        """Declare the share publisher and the subscriber of every pursuer's shares on a Zenoh session;
        received shares are handled on `loop` (the companion's event loop)."""
        from interfaces import zenoh_transport

        self._loop = loop
        publisher = zenoh_transport.publisher(session, self.key)
        self.put = publisher.put
        # Remote publications only: our own shares are not echoed back to us (an own-id share that still
        # arrives came from another process and is rejected as own_sender).
        import zenoh

        session.declare_subscriber(link.PURSUER_SHARE_ALL, self._on_sample, allowed_origin=zenoh.Locality.REMOTE)

    def own_bearings(self, bearings) -> None:
        """The own bearings just given to the pipeline (oldest first): the newest is the next share's."""
        for bearing in bearings:
            if bearing.source == 0 and (self._latest_bearing is None or bearing.time > self._latest_bearing.time):
                self._latest_bearing = bearing

    def on_sample(self, sample) -> None:
        """An odometry sample (companion.adapters.mavsdk_vehicle.VehicleSample, event loop): publish the
        share due at its time, if any (one per 1 / share_rate_hz of vehicle time, on the grid k / rate)."""
        now = sample.state.time
        self._release(now)
        if self.put is None or now + 1e-9 < self._next_share:
            return
        self._next_share = (math.floor(now * self.rate_hz + 1e-9) + 1) / self.rate_hz
        payload = self.share(now, sample.state.position, sample.state.velocity)
        if payload is not None:
            self.put(payload)
            self.sent += 1

    def share(self, now: float, position: np.ndarray, velocity: np.ndarray) -> bytes | None:
        """The encoded share at vehicle time `now` (s) with own position (m) and velocity (m/s), NED (3,);
        None if it cannot be encoded (e.g. a position outside the schema's range: nothing is sent then)."""
        bearing = None
        latest = self._latest_bearing
        if latest is not None and latest.time > self._shared_bearing_time and latest.time <= now:
            bearing = link.SharedBearing(float(latest.time), tuple(map(float, latest.direction)),
                                         tuple(map(float, latest.pursuer_position)))
        estimate = None
        pipeline = self.pipeline()
        if pipeline is not None and pipeline.engaged_at is not None and pipeline.estimator.initialized:
            current = pipeline.estimator.estimate
            if current.time <= now:
                estimate = link.SharedEstimate(float(current.time), tuple(map(float, current.position)),
                                               tuple(map(float, current.velocity)), np.asarray(current.covariance))
        share = link.PursuerShare(self.ident, self.seq, float(now), self.epoch, tuple(map(float, position)),
                                  tuple(map(float, velocity)), bearing, estimate)
        # The estimate, then the bearing, are the optional parts (a diverged covariance, a bearing the schema
        # refuses): the own state still goes.
        payload = None
        for attempt in (share, dataclasses.replace(share, estimate=None),
                        dataclasses.replace(share, estimate=None, bearing=None)):
            try:
                payload = link.encode_pursuer_share(attempt)
            except link.PayloadError:
                continue
            bearing = attempt.bearing
            break
        if payload is None:
            return None
        if bearing is not None:
            self._shared_bearing_time = bearing.stamp
        self.seq += 1
        return payload

    # ------------------------------------------------------------------- in
    def _on_sample(self, sample) -> None:
        """Zenoh thread: hand the payload to the event loop."""
        payload = sample.payload.to_bytes()
        self._loop.call_soon_threadsafe(self.on_share, payload)

    def _record(self, key: str, record: dict) -> None:
        if self._log is not None:
            self._log.write(key, record, time.monotonic())

    def _reject(self, reason: str, now: float | None, detail: str, sender=None) -> None:
        self.rejected[reason] += 1
        self._record(f"rejected:{reason}", {"verdict": "rejected", "reason": reason, "sim_time": now,
                                            "sender": sender, "detail": detail[:200]})

    def on_share(self, payload: bytes) -> None:
        """Event loop: check one received share payload (module docstring); never raises for bad input."""
        self.received += 1
        now = self.clock()
        try:
            share = link.decode_pursuer_share(payload)
        except link.PayloadError as error:
            self._reject(error.reason, now, str(error))
            return
        if share.sender == self.ident:
            self._reject("own_sender", now, f"a share with our own id {self.ident}", share.sender)
            return
        if share.sender > self.count:
            self._reject("unknown_pursuer", now, f"pursuer {share.sender}: pursuers are 1..{self.count}", share.sender)
            return
        if now is None:
            self._reject("no_clock", now, "no vehicle time yet to check the share's stamp against", share.sender)
            return
        if share.stamp > now + self.max_future_skew:
            self._reject("future_stamp", now, f"stamp {share.stamp:.3f} s is {share.stamp - now:.3f} s ahead "
                                              f"(max {self.max_future_skew:g} s)", share.sender)
            return
        if share.stamp < now - self.max_age:
            self._reject("too_old", now, f"stamp {share.stamp:.3f} s is {now - share.stamp:.3f} s old "
                                         f"(max {self.max_age:g} s)", share.sender)
            return
        previous = self._last_seq.get(share.sender)
        if previous is not None and previous[0] == share.epoch and share.seq <= previous[1]:
            self._reject("stale_seq", now, f"seq {share.seq} <= {previous[1]} in epoch {share.epoch}", share.sender)
            return
        if previous is not None and previous[0] == share.epoch:
            allowed = SEQ_RATE_FACTOR * max(0.0, share.stamp - previous[2]) * self.rate_hz + SEQ_SLACK
            if share.seq - previous[1] > allowed:
                self._reject("seq_jump", now, f"seq {share.seq} is {share.seq - previous[1]} past {previous[1]} in "
                                              f"{share.stamp - previous[2]:.3f} s", share.sender)
                return
        if len(self._held) >= MAX_HELD:
            self._reject("queue_full", now, f"{MAX_HELD} shares already held", share.sender)
            return
        self._last_seq[share.sender] = (share.epoch, share.seq, share.stamp)
        self.accepted += 1
        here = self.own_position()
        sent_at = self._scenario_time(share.stamp)
        delivery = self.link.transmit(sent_at, share.sender, self.ident, np.array(share.position),
                                      np.array(share.position) if here is None else here)
        record = {"sim_time": now, "sender": share.sender, "seq": share.seq, "stamp": share.stamp,
                  "bearing": share.bearing is not None}
        if not delivery.delivered:
            self.link_dropped[delivery.reason] += 1
            self._record(f"dropped:{delivery.reason}", {"verdict": "dropped", "reason": delivery.reason, **record})
            return
        deliver_at = share.stamp + (delivery.time - sent_at)  # the link's delay, on the vehicle clock
        self._record(f"accepted:{share.sender}", {"verdict": "accepted", "deliver_at": deliver_at, **record})
        heapq.heappush(self._held, (deliver_at, self._order, share))
        self._order += 1

    def _scenario_time(self, stamp: float) -> float:
        """Vehicle time `stamp` (s) on the clock of the [swarm.link] windows: s since this pursuer began following,
        as the in-process pursuers all start following at scenario time 0 (so a window falls at the same point of
        the following however long the take-off took); before it engaged, BEFORE_FOLLOWING (no window applies)."""
        pipeline = self.pipeline()
        engaged = None if pipeline is None else pipeline.engaged_at
        return BEFORE_FOLLOWING if engaged is None else stamp - engaged

    def _apply(self, share: link.PursuerShare) -> None:
        self.applied += 1
        known = self.neighbours.get(share.sender)
        if known is None or share.stamp > known.time:
            self.neighbours[share.sender] = NeighbourState(share.sender, share.stamp, np.array(share.position),
                                                           np.array(share.velocity))
        # A bearing older than the age limit (the share itself may be fresh) is not given to the estimator.
        if (self.uses_bearings and self._collecting and share.bearing is not None
                and share.bearing.stamp >= share.stamp - self.max_age):
            if len(self._inbox) == self._inbox.maxlen:
                self.bearings_overflowed += 1
            self._inbox.append(BearingMeasurement(share.bearing.stamp, np.array(share.bearing.direction),
                                                  np.array(share.bearing.position), source=share.sender))

    def _release(self, now: float) -> None:
        """Apply the held shares whose delivery time (s) has come by vehicle time `now`."""
        while self._held and self._held[0][0] <= now + 1e-9:
            _, _, share = heapq.heappop(self._held)
            self._apply(share)

    def step_inputs(self, now: float) -> tuple[tuple[NeighbourState, ...], list[BearingMeasurement]]:
        """At vehicle time `now` (s): apply the shares whose delivery time has come, then return the fresh
        neighbours (heard within neighbour_timeout_s, by their stamps) and the neighbours' bearings to give
        the pipeline (each once)."""
        self._collecting = True
        self._release(now)
        fresh = self._fresh(now)
        bearings = list(self._inbox)
        self._inbox.clear()
        self.neighbour_bearings_used += len(bearings)
        if self._log is not None:
            self._log.tick(time.monotonic())
        return fresh, bearings

    def neighbours_at(self, now: float) -> tuple[NeighbourState, ...]:
        """At vehicle time `now` (s), once the pursuer no longer estimates (its braking before landing): apply the
        shares whose delivery time has come and return the fresh neighbours, as step_inputs does, but take no
        bearing from them: none is counted as used, and none is kept from now on."""
        self._collecting = False
        self._inbox.clear()
        self._release(now)
        return self._fresh(now)

    def _fresh(self, now: float) -> tuple[NeighbourState, ...]:
        """The neighbours heard within neighbour_timeout_s of vehicle time `now` (s), by their stamps."""
        return tuple(n for n in self.neighbours.values() if now - n.time <= self.timeout)

    def summary(self) -> dict:
        """The share link's figures for the companion's summary.json."""
        return {"pursuer": self.ident, "pursuers": self.count, "epoch": self.epoch, "shares_sent": self.sent,
                "shares_received": self.received, "shares_accepted": self.accepted, "shares_applied": self.applied,
                "shares_rejected": dict(self.rejected), "shares_dropped_by_link": dict(self.link_dropped),
                "neighbour_bearings_used": self.neighbour_bearings_used,
                "neighbour_bearings_overflowed": self.bearings_overflowed,
                "neighbours_heard": sorted(self.neighbours)}

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
