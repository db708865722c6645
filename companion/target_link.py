"""The companion's end of the target link: target-fix payloads in over Zenoh, bearings out.

As in the paper's flight experiment (section IX-A, Fig. 16), the target's position arrives
over a radio link; the bearing is rebuilt on board from it and the vehicle's own position at
the fix time, corrupted as the configured sensor would corrupt it. Zenoh delivers samples on
its own thread: they are handed to the asyncio loop with their receipt time, checked there
by the FixIntake (decode, geodesy, FixValidator: freshness against the vehicle's clock, order
per publisher epoch, plausibility, and the re-anchor rule fed with the pipeline's predicted line
of sight), and queued while the mission wants bearings; the follower then asks for the bearings whose fix time the own-state history
covers (BearingBuilder). LinkHealth keeps what the link has done so far.
"""

from __future__ import annotations

import asyncio
import collections
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from companion.adapters.recorder import RecentSamples, RunRecorder
from companion.core.bearing_builder import BearingBuilder
from companion.core.bearing_sensor import BearingSensor
from companion.core.fix_validator import FixRejected, FixValidator
from companion.core.messages import BearingMeasurement
from companion.core.state_history import StateHistory
from companion.fix_intake import FixIntake
from interfaces import link_schema as link

#: A fix whose stamp is further than this ahead of the newest own state waits for it, s.
MAX_EXTRAPOLATION = 0.1
#: A fix still unusable this long after its stamp (no own state at that time) is dropped, s.
FIX_MAX_WAIT = 1.0


@dataclass
class PendingFix:
    """An accepted fix waiting for its bearing. seq, stamp (s, target clock = vehicle clock),
    position: NED m shape (3,), received_ns: monotonic receipt time, ns."""

    seq: int
    stamp: float
    position: np.ndarray
    received_ns: int


class LinkHealth:
    """What the target link has done so far; the validation counts are the FixValidator's own."""

    def __init__(self, validator: FixValidator) -> None:
        self.validator = validator
        self.received = 0
        self.bearings_used = 0
        self.bearings_dropped: collections.Counter[str] = collections.Counter()
        self.last_received_wall: float | None = None

    @property
    def accepted(self) -> int:
        return self.validator.accepted

    @property
    def rejected(self) -> collections.Counter[str]:
        return self.validator.rejected

    def as_dict(self, now_wall: float) -> dict:
        return {
            "received": self.received,
            "accepted": self.accepted,
            "rejected": dict(self.rejected),
            "bearings_used": self.bearings_used,
            "bearings_dropped": dict(self.bearings_dropped),
            "contested": self.validator.contested,
            "contests": self.validator.contest_count_total,
            "last_seq": self.validator.last_seq,
            "last_stamp": self.validator.last_stamp,
            "last_fix_age_wall": None if self.last_received_wall is None else round(now_wall - self.last_received_wall, 3),
        }


class TargetLink:
    """Target fixes in, bearings out.

    target_sender: the only sender whose fixes count. home: (lat deg, lon deg, alt m AMSL) of
    the local NED origin. sensor, rng: the bearing sensor model and its noise stream. history:
    the own-state history (the follower appends to it). recorder: zenoh_rx.jsonl and
    bearings.csv. clock: the newest vehicle time, s, or None (logged with each message).
    wants_bearings: whether the mission is at a point where accepted fixes are queued for
    bearings (before that they only prove the link is up). validator: the FixValidator
    (default: the [link] defaults; companion.fix_intake.build_fix_validator makes it from the
    scenario). pipeline: returns the FollowingPipeline once there is one (its predicted line of
    sight feeds the validator's re-anchor rule), or None.

    The validator's ``now`` is `clock` (vehicle time, the plant's clock in SITL, the clock the
    fixes are stamped in); before the first odometry a fix is rejected as ``no_clock``.
    """

    def __init__(self, target_sender: str, home: Sequence[float], sensor: BearingSensor, rng: np.random.Generator,
                 history: StateHistory, recorder: RunRecorder, clock: Callable[[], float | None],
                 wants_bearings: Callable[[], bool], *, validator: FixValidator | None = None,
                 pipeline: Callable[[], object | None] = lambda: None) -> None:
        self.key = link.target_fix_key(target_sender)
        self.validator = validator if validator is not None else FixValidator(target_sender)
        self.pipeline = pipeline
        self.intake = FixIntake(self.validator, home)
        self.health = LinkHealth(self.validator)
        self.history = history
        self.builder = BearingBuilder(sensor, rng, history)
        self.recorder = recorder
        self.clock = clock
        self.wants_bearings = wants_bearings
        self.pending: collections.deque[PendingFix] = collections.deque()
        self.bearing_latencies_ms = RecentSamples()  # fix received -> its bearing given to the estimator, ms
        self.last_position: np.ndarray | None = None  # the newest accepted fix, local NED m
        self._loop: asyncio.AbstractEventLoop | None = None

    def subscribe(self, session, loop: asyncio.AbstractEventLoop) -> None:
        """Declare the fix subscriber on a Zenoh session; fixes are then checked on `loop`."""
        self._loop = loop
        session.declare_subscriber(self.key, self._on_sample)

    def _on_sample(self, sample) -> None:
        """Zenoh thread: hand the payload to the event loop with its receipt time."""
        payload = sample.payload.to_bytes()
        received = time.monotonic_ns()
        self._loop.call_soon_threadsafe(self.on_fix, payload, received)

    def on_fix(self, payload: bytes, received_ns: int) -> None:
        """Event loop: check one payload (counted in health either way), log it, queue it if bearings are wanted."""
        self.health.received += 1
        now = self.clock()
        record = {"received_ns": received_ns, "sim_time": now, "bytes": len(payload)}
        try:
            if now is None:
                self.validator.reject("no_clock")
                raise FixRejected("no_clock", "no vehicle time yet to check the fix's stamp against")
            fix, position = self.intake.check(payload, now=now, agrees=self._agrees)
        except FixRejected as error:
            record.update(verdict="rejected", reason=error.reason, detail=str(error))
            self.recorder.zenoh(record)
            return
        self.health.last_received_wall = time.monotonic()
        self.last_position = position
        record.update(verdict="accepted", seq=fix.seq, epoch=fix.epoch, stamp=fix.stamp, frame=fix.frame,
                      position=list(fix.position))
        self.recorder.zenoh(record)
        if self.wants_bearings():
            self.pending.append(PendingFix(fix.seq, fix.stamp, position, received_ns))

    def _agrees(self, position: np.ndarray, stamp: float) -> bool | None:
        """The pipeline's verdict on the line of sight to `position` (NED m) from the own position at `stamp` (s)."""
        pipeline = self.pipeline()
        sample = self.history.at(stamp)
        if pipeline is None or sample is None:
            return None
        return pipeline.line_of_sight_agrees(stamp, sample.position, position)

    def due_bearings(self, now: float) -> list[tuple[PendingFix, BearingMeasurement]]:
        """(fix, bearing) for the queued fixes whose stamp the own-state history covers at vehicle time
        `now` (s), oldest first. A fix ahead of the history waits up to FIX_MAX_WAIT; one that cannot
        give a bearing is counted in health.bearings_dropped under the builder's reason."""
        due = []
        while self.pending and self.pending[0].stamp <= now + MAX_EXTRAPOLATION:
            fix = self.pending.popleft()
            result = self.builder.build(fix.position, fix.stamp)
            if result.bearing is None:
                if result.reason == "no_own_state" and now - fix.stamp < FIX_MAX_WAIT and fix.stamp > now:
                    self.pending.appendleft(fix)
                    break
                self.health.bearings_dropped[result.reason] += 1
                continue
            due.append((fix, result.bearing))
            self.recorder.bearing(result.bearing, fix.seq)
            self.health.bearings_used += 1
            self.bearing_latencies_ms.append((time.monotonic_ns() - fix.received_ns) * 1e-6)
        return due
