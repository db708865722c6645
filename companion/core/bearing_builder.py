"""Rebuild the target's bearing on board from a target fix, as in the flight experiment.

Section IX-A: "the target position is transmitted to the pursuer based on wireless
communication. Then, the bearing of the target is reconstructed based on the
transmitted target position. It should be noted that the pursuer MAV *only* utilizes
the bearing information of the target." BearingBuilder does that reconstruction:

    lambda = (p_T - p(t_fix)) / |p_T - p(t_fix)|

with the pursuer's own position p read from a StateHistory at the fix's stamp (not
the latest odometry), then corrupted by the configured sensor model (eq. (4), eq. (25)
or the pin-hole camera through the interpolated attitude). Only the direction leaves
this module; the range |p_T - p| is used for the too-close check and then forgotten.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from companion.core.bearing_sensor import BearingSensor
from companion.core.messages import BearingMeasurement
from companion.core.state_history import StateHistory


class BuildFailure(enum.StrEnum):
    """Why a target fix gave no bearing (compares equal to its string value)."""

    NO_OWN_STATE = "no_own_state"  # the history cannot give the pursuer's state at the fix stamp
    TOO_CLOSE = "too_close"  # |p_T - p| < min_range: the direction is meaningless
    OUT_OF_VIEW = "out_of_view"  # the camera would not see the target


@dataclass(frozen=True)
class BuildResult:
    """Outcome of one target fix.

    bearing: what goes to the estimator, or None. reason: why not (a BuildFailure),
    None when a bearing was built. true_line_of_sight: the noise-free unit line of
    sight at the fix stamp, NED, shape (3,), for logging only (None when the own state
    was unknown or the target too close); it is never sent to the estimator.
    """

    bearing: BearingMeasurement | None
    reason: BuildFailure | None
    true_line_of_sight: np.ndarray | None = None


class BearingBuilder:
    """Target fix + own-state history -> measured bearing (section IX-A).

    sensor: the bearing sensor model (eq. (4), eq. (25) or the camera) with its noise. rng: the sensor noise's random
    generator. history: the pursuer's own states (position, velocity, attitude).
    min_range: m, fixes closer than this give no bearing.
    """

    def __init__(self, sensor: BearingSensor, rng: np.random.Generator, history: StateHistory, min_range: float = 0.5) -> None:
        if not (math.isfinite(min_range) and min_range >= 0.0):
            raise ValueError(f"min_range must be a finite number of metres >= 0, got {min_range!r}")
        self._sensor = sensor
        self._rng = rng
        self._range_rng = rng.spawn(1)[0]  # range noise (a range sensor) on its own stream
        self._history = history
        self._min_range = float(min_range)

    def build(self, target_position_ned: np.ndarray, stamp: float) -> BuildResult:
        """The bearing of a target fix: target position p_T (m, NED, shape (3,)) valid at `stamp` (s).

        The BearingMeasurement carries time = stamp and the interpolated own position
        as its projection centre. Raises ValueError for a malformed fix.
        """
        target_position = np.asarray(target_position_ned, dtype=float)
        if target_position.shape != (3,) or not np.all(np.isfinite(target_position)) or not math.isfinite(stamp):
            raise ValueError(f"a target fix needs a finite position of shape (3,) and a finite stamp, got {target_position_ned!r} at {stamp!r}")
        own = self._history.at(stamp)
        if own is None:
            return BuildResult(None, BuildFailure.NO_OWN_STATE)
        relative = target_position - own.position
        distance = math.sqrt(float(relative @ relative))
        if distance < self._min_range or distance == 0.0:
            return BuildResult(None, BuildFailure.TOO_CLOSE)
        line_of_sight = relative / distance
        direction = self._sensor.measure(line_of_sight, self._rng, own.rotation, true_range=distance)
        if direction is None:
            return BuildResult(None, BuildFailure.OUT_OF_VIEW, line_of_sight)
        measured_range = self._sensor.measure_range(distance, self._range_rng)
        return BuildResult(BearingMeasurement(float(stamp), direction, own.position, measured_range), None, line_of_sight)
