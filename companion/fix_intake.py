"""Target-fix payloads in, validated NED positions out: the edge in front of the core's FixValidator.

decode (interfaces.link_schema: schema, types, finite numbers, ranges) -> geodetic to
local NED about home (interfaces.geodesy) -> FixValidator (sender, order, plausibility).
Both harnesses use it, so the in-process simulator rejects exactly what the companion does.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.core.fix_validator import FixRejected, FixValidator
from interfaces import link_schema


class FixIntake:
    """Checks target-fix payloads in arrival order; every refusal is counted in `validator.rejected`.

    validator: the core FixValidator (its counters are the one record of accepted and
    rejected fixes). home: (latitude deg, longitude deg, altitude m AMSL) of the local
    NED origin.
    """

    def __init__(self, validator: FixValidator, home: Sequence[float]) -> None:
        self.validator = validator
        self.home = tuple(float(v) for v in home)

    def check(self, payload: bytes) -> tuple[link_schema.TargetFix, np.ndarray]:
        """(fix, NED position m shape (3,)) of an acceptable payload; FixRejected (counted) otherwise."""
        try:
            fix = link_schema.decode_target_fix(payload)
        except link_schema.PayloadError as error:
            self.validator.reject(error.reason)
            raise FixRejected(error.reason, error.detail) from None
        position = link_schema.fix_to_ned(fix, self.home)
        return fix, self.validator.check(fix.sender, fix.seq, fix.stamp, position)
