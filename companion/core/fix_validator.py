"""Every target fix is checked before it can become a bearing (both harnesses use this).

decode (schema, types, finite numbers, ranges: interfaces.link_schema) -> sender id -> sequence
and time-stamp order -> physically plausible jump from the last accepted fix. A fix
that fails any check is rejected with a reason and counted; it never reaches the filter.
"""

from __future__ import annotations

import collections
import math
import numpy as np


class FixRejected(ValueError):
    """A fix the companion will not use; `reason` is a short code (see FixValidator)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class FixValidator:
    """Accepts or rejects target-fix payloads, in arrival order.

    Reasons: any interfaces.link_schema decode reason (not_json, missing_field, not_finite,
    out_of_range, ...), plus wrong_sender (not the configured target), stale_seq (seq not
    after the last accepted one: duplicates, reordered or replayed messages), stale_stamp
    (time stamp not after the last accepted one), implausible_jump (the target would have
    moved faster than max_target_speed, plus jump_margin metres of position noise, since
    the last accepted fix). After reanchor_after (3) consecutive implausible fixes that
    agree with each other, the third is accepted and becomes the new reference, so one bad
    fix cannot lock the target out for good.

    target_sender: expected sender id. max_target_speed: m/s. jump_margin: m.
    """

    def __init__(self, target_sender: str, max_target_speed: float = 30.0, jump_margin: float = 5.0) -> None:
        self.target_sender = target_sender
        self.max_target_speed = float(max_target_speed)
        self.jump_margin = float(jump_margin)
        self.rejected: collections.Counter[str] = collections.Counter()
        self.accepted = 0
        self.last_seq: int | None = None
        self.last_stamp: float | None = None
        self.last_position: np.ndarray | None = None
        self.reanchor_after = 3
        self.reanchored = 0
        self._outlier: tuple[np.ndarray, float, int] | None = None

    def _plausible(self, position: np.ndarray, stamp: float, reference: np.ndarray, reference_stamp: float) -> bool:
        jump = float(np.linalg.norm(position - reference))
        return math.isfinite(jump) and jump <= self.max_target_speed * abs(stamp - reference_stamp) + self.jump_margin

    def reject(self, reason: str) -> None:
        """Count a fix refused before it reached the validator (e.g. a payload that did not decode)."""
        self.rejected[reason] += 1

    def check(self, sender: str, seq: int, stamp: float, position: np.ndarray) -> np.ndarray:
        """The NED position (m, shape (3,)) of an acceptable fix; FixRejected (counted) otherwise.

        sender, seq, stamp (s): the fix's envelope. position: NED, m, shape (3,).
        """
        try:
            return self._check(sender, seq, stamp, np.asarray(position, dtype=float))
        except FixRejected as error:
            self.rejected[error.reason] += 1
            raise

    def _check(self, sender: str, seq: int, stamp: float, position: np.ndarray) -> np.ndarray:
        if sender != self.target_sender:
            raise FixRejected("wrong_sender", f"sender {sender!r}, expected {self.target_sender!r}")
        if self.last_seq is not None and seq <= self.last_seq:
            raise FixRejected("stale_seq", f"seq {seq} after {self.last_seq}")
        if self.last_stamp is not None and stamp <= self.last_stamp:
            raise FixRejected("stale_stamp", f"stamp {stamp} after {self.last_stamp}")
        if self.last_position is not None and not self._plausible(position, stamp, self.last_position, self.last_stamp):
            # A run of fixes that agree with each other but not with the last accepted one
            # means that one was wrong (or the target really jumped): re-anchor on them.
            previous = self._outlier
            agrees = previous is not None and self._plausible(position, stamp, previous[0], previous[1])
            count = previous[2] + 1 if agrees else 1
            self._outlier = (position, stamp, count)
            if count < self.reanchor_after:
                jump = float(np.linalg.norm(position - self.last_position))
                raise FixRejected("implausible_jump", f"{jump:.1f} m in {stamp - self.last_stamp:.2f} s")
            self.reanchored += 1
        self._outlier = None
        self.accepted += 1
        self.last_seq, self.last_stamp, self.last_position = seq, stamp, position
        return position
