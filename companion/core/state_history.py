"""A short, time-ordered history of the pursuer's own state, queried at past instants.

A target fix (section IX: the target's position sent over the radio) is stamped when
the target was there, which is some tens of milliseconds before it reaches the
companion. The bearing must be built from where the pursuer was *at that stamp*, not
from its latest odometry: at 10 m/s and 100 ms of latency the difference is 1 m, an
angle of ~7 deg at the 8 m following range. StateHistory keeps the recent odometry so
the pursuer's position, velocity and attitude can be read at any recent instant.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from companion.core.bearing_sensor import rotation_matrix


class StateSample(NamedTuple):
    """Pursuer state at one instant. position: m, (3,); velocity: m/s, (3,); rotation: body FRD -> NED, (3, 3)."""

    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray


def _vector3(value: np.ndarray, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=float)
    if vector.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {vector.shape}")
    return vector


class StateHistory:
    """Time-ordered buffer of pursuer samples (time, position, velocity, rotation), NED.

    max_age_s: s, samples older than (newest time - max_age_s) are dropped.
    max_extrapolation: s, how far past the newest sample `at` may extrapolate (at
    constant velocity, attitude held).

    Samples must come in strictly increasing time; an older or duplicate stamp, or a
    sample with non-finite numbers, is ignored and counted (`rejected_out_of_order`,
    `rejected_not_finite`) rather than raised, since telemetry can repeat or reorder.
    """

    def __init__(self, max_age_s: float, max_extrapolation: float = 0.1) -> None:
        if not (math.isfinite(max_age_s) and max_age_s > 0.0):
            raise ValueError(f"max_age_s must be a positive number of seconds, got {max_age_s!r}")
        if not (math.isfinite(max_extrapolation) and max_extrapolation >= 0.0):
            raise ValueError(f"max_extrapolation must be a number of seconds >= 0, got {max_extrapolation!r}")
        self.max_age_s = float(max_age_s)
        self.max_extrapolation = float(max_extrapolation)
        self._times: list[float] = []
        self._positions: list[np.ndarray] = []
        self._velocities: list[np.ndarray] = []
        self._rotations: list[Rotation] = []
        self.rejected_out_of_order = 0
        self.rejected_not_finite = 0

    def __len__(self) -> int:
        return len(self._times)

    @property
    def oldest_time(self) -> float | None:
        """s, stamp of the oldest kept sample (None when empty)."""
        return self._times[0] if self._times else None

    @property
    def newest_time(self) -> float | None:
        """s, stamp of the newest sample (None when empty)."""
        return self._times[-1] if self._times else None

    def append(self, time: float, position: np.ndarray, velocity: np.ndarray, rotation: np.ndarray | Rotation) -> bool:
        """Add a sample; returns False (and counts it) if it was ignored.

        time: s. position: m, (3,). velocity: m/s, (3,). rotation: body -> NED, (3, 3)
        matrix or scipy Rotation. Raises ValueError only for wrong shapes or a matrix
        that is not a rotation.
        """
        position, velocity = _vector3(position, "position"), _vector3(velocity, "velocity")
        time = float(time)
        if not (math.isfinite(time) and np.all(np.isfinite(position)) and np.all(np.isfinite(velocity))):
            self.rejected_not_finite += 1
            return False
        if isinstance(rotation, Rotation):
            attitude = rotation
        else:
            matrix = np.asarray(rotation, dtype=float)
            if matrix.shape == (3, 3) and not np.all(np.isfinite(matrix)):
                self.rejected_not_finite += 1
                return False
            attitude = Rotation.from_matrix(rotation_matrix(matrix))
        if self._times and time <= self._times[-1]:
            self.rejected_out_of_order += 1
            return False
        self._times.append(time)
        self._positions.append(position.copy())
        self._velocities.append(velocity.copy())
        self._rotations.append(attitude)
        self._drop_older_than(time - self.max_age_s)
        return True

    def _drop_older_than(self, cutoff: float) -> None:
        stale = bisect_right(self._times, cutoff - 1e-12)
        if stale:
            del self._times[:stale], self._positions[:stale], self._velocities[:stale], self._rotations[:stale]

    def at(self, time: float) -> StateSample | None:
        """Pursuer state at `time` (s), or None when the history cannot tell.

        Between two samples: position and velocity interpolated linearly, attitude by
        slerp (constant angular rate between the samples). Past the newest sample by
        at most max_extrapolation: p + v dt, v, attitude held. None before the oldest
        kept sample, further past the newest, or when empty.
        """
        times = self._times
        if not times or not math.isfinite(time) or time < times[0]:
            return None
        newest = times[-1]
        if time >= newest:
            lead = time - newest
            if lead > self.max_extrapolation + 1e-9:
                return None
            return StateSample(self._positions[-1] + lead * self._velocities[-1], self._velocities[-1].copy(), self._rotations[-1].as_matrix())
        after = bisect_right(times, time)
        before = after - 1
        if times[before] == time:
            return StateSample(self._positions[before].copy(), self._velocities[before].copy(), self._rotations[before].as_matrix())
        fraction = (time - times[before]) / (times[after] - times[before])
        position = self._positions[before] + fraction * (self._positions[after] - self._positions[before])
        velocity = self._velocities[before] + fraction * (self._velocities[after] - self._velocities[before])
        start = self._rotations[before]
        # Slerp: a constant-rate rotation from the earlier attitude to the later one.
        step = (start.inv() * self._rotations[after]).as_rotvec()
        rotation = (start * Rotation.from_rotvec(fraction * step)).as_matrix()
        return StateSample(position, velocity, rotation)
