"""Target-fix payloads in, validated NED positions out: the edge in front of the core's FixValidator.

decode (interfaces.link_schema: schema, types, finite numbers, ranges) -> geodetic to
local NED about home (interfaces.geodesy) -> FixValidator (sender, order, plausibility).
Both harnesses use it, so the in-process simulator rejects exactly what the companion does.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.core.fix_validator import Agreement, CommandValidator, FixRejected, FixValidator, FreshnessPolicy
from interfaces import link_schema
from interfaces.scenario import LinkConfig


def build_fix_validator(settings: LinkConfig) -> FixValidator:
    """The FixValidator of the scenario's [link] section (both harnesses build it here)."""
    policy = FreshnessPolicy(max_future_skew=settings.max_future_skew_s, max_age=settings.max_fix_age_s,
                             max_rate_hz=settings.max_fix_rate_hz)
    return FixValidator(settings.target_sender, max_target_speed=settings.max_target_speed, policy=policy,
                        silence=settings.reanchor_silence_s, epoch_switch=settings.epoch_switch_silence_s)


def build_command_validator(settings: LinkConfig) -> CommandValidator:
    """The CommandValidator of the scenario's [link] section: the fixes' skew and age window, 10 commands/s."""
    return CommandValidator(FreshnessPolicy(max_future_skew=settings.max_future_skew_s,
                                            max_age=settings.max_fix_age_s, max_rate_hz=10.0))


class FixIntake:
    """Checks target-fix payloads in arrival order; every refusal is counted in `validator.rejected`.

    validator: the core FixValidator (its counters are the one record of accepted and
    rejected fixes). home: (latitude deg, longitude deg, altitude m AMSL) of the local
    NED origin.
    """

    def __init__(self, validator: FixValidator, home: Sequence[float]) -> None:
        self.validator = validator
        self.home = tuple(float(v) for v in home)

    def check(self, payload: bytes, now: float | None = None,
              agrees: Agreement | None = None) -> tuple[link_schema.TargetFix, np.ndarray]:
        """(fix, NED position m shape (3,)) of an acceptable payload; FixRejected (counted) otherwise.

        now: the receiver's time, s, in the stamps' clock (the freshness window; None: not checked).
        agrees: the filter's verdict on a fix's bearing, for the re-anchor rule (FixValidator).
        """
        return self.check_decoded(self.decode(payload), now, agrees)

    def decode(self, payload: bytes) -> link_schema.TargetFix:
        """check's first step: link_schema.decode_target_fix of the payload; a payload it refuses is counted
        (validator.reject, its reason) and raised as FixRejected."""
        try:
            return link_schema.decode_target_fix(payload)
        except link_schema.PayloadError as error:
            self.validator.reject(error.reason)
            raise FixRejected(error.reason, error.detail) from None

    def check_decoded(self, fix: link_schema.TargetFix, now: float | None = None,
                      agrees: Agreement | None = None) -> tuple[link_schema.TargetFix, np.ndarray]:
        """check's other steps (geodesy, FixValidator) for a fix that `decode` gave: for a caller that reads the
        decoded fix itself first (the in-process simulator's record of whose fixes were delivered), so the
        payload is decoded once. check(payload) is check_decoded(decode(payload))."""
        position = link_schema.fix_to_ned(fix, self.home)
        return fix, self.validator.check(fix.sender, fix.seq, fix.stamp, position, epoch=fix.epoch, now=now,
                                         agrees=agrees)
