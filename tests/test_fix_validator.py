"""Target-fix validation: every rejection reason, and recovery after a bad reference."""

from __future__ import annotations

import numpy as np
import pytest

from interfaces import link_schema as link
from companion.core.fix_validator import FixRejected, FixValidator
from companion.fix_intake import FixIntake

HOME = (47.397742, 8.545594, 488.0)


def _fix(seq, stamp, position, sender="target-1"):
    return link.encode_target_fix(link.TargetFix(sender, seq, stamp, "ned", position))


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


def test_a_single_wild_fix_is_rejected_and_a_consistent_run_re_anchors():
    intake = FixIntake(FixValidator("target-1"), HOME)
    validator = intake.validator
    intake.check(_fix(0, 0.0, (0.0, 0.0, -20.0)))  # a wrong reference (e.g. a glitch at start)
    for k in range(1, 3):
        with pytest.raises(FixRejected):
            intake.check(_fix(k, 0.2 * k, (300.0 + 0.5 * k, 0.0, -20.0)))
    fix, position = intake.check(_fix(3, 0.6, (301.5, 0.0, -20.0)))  # third consistent one: new reference
    assert validator.reanchored == 1 and position[0] == pytest.approx(301.5)
    intake.check(_fix(4, 0.8, (302.0, 0.0, -20.0)))
    assert validator.rejected == {"implausible_jump": 2}
    # Alternating outliers that disagree with each other never re-anchor.
    for k, north in enumerate((600.0, 900.0, 600.0, 900.0), start=5):
        with pytest.raises(FixRejected):
            intake.check(_fix(k, 0.8 + 0.2 * (k - 4), (north, 0.0, -20.0)))
