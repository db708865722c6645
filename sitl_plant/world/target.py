"""Simulated target drone: constant velocity plus scheduled constant-speed turns.

Covers the paper's constant-velocity target (VIII-A1), the "s" maneuver (VIII-A2)
and the flight experiment's 90-degree turn (IX-B2): each maneuver is a horizontal
lateral acceleration normal to the velocity over a time window, at constant speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Maneuver:
    """Lateral acceleration (m/s^2, positive turns right in NED, i.e. heading increases) from start to end (s)."""

    start: float
    end: float
    lateral_acceleration: float


class TargetModel:
    """Target kinematics, propagated exactly between steps.

    initial_position: m, NED, shape (3,). initial_velocity: m/s, NED, shape (3,).
    Turns keep the speed and the vertical velocity; the heading rate is
    lateral_acceleration / horizontal speed.
    """

    def __init__(self, initial_position: np.ndarray, initial_velocity: np.ndarray, maneuvers: tuple[Maneuver, ...] = ()) -> None:
        self.time = 0.0
        self.position = np.array(initial_position, dtype=float)
        self.velocity = np.array(initial_velocity, dtype=float)
        self.maneuvers = tuple(sorted(maneuvers, key=lambda m: m.start))
        self._speed = math.hypot(self.velocity[0], self.velocity[1])
        if self.maneuvers and self._speed < 1e-9:
            raise ValueError("a turning target needs a nonzero horizontal velocity")

    def lateral_acceleration(self, time: float) -> float:
        """Scheduled lateral acceleration at `time`, m/s^2."""
        for maneuver in self.maneuvers:
            if maneuver.start <= time < maneuver.end:
                return maneuver.lateral_acceleration
        return 0.0

    def step(self, dt: float) -> None:
        """Advance by dt seconds (the maneuver active at the start of the step holds through it)."""
        turn_rate = self.lateral_acceleration(self.time) / self._speed if self._speed > 0.0 else 0.0
        if turn_rate == 0.0:
            self.position = self.position + self.velocity * dt
        else:
            heading = math.atan2(self.velocity[1], self.velocity[0])
            new_heading = heading + turn_rate * dt
            scale = self._speed / turn_rate
            self.position = self.position + np.array(
                [
                    scale * (math.sin(new_heading) - math.sin(heading)),
                    scale * (math.cos(heading) - math.cos(new_heading)),
                    self.velocity[2] * dt,
                ]
            )
            self.velocity = np.array([self._speed * math.cos(new_heading), self._speed * math.sin(new_heading), self.velocity[2]])
        self.time += dt

    def advance_to(self, time: float) -> None:
        """Propagate exactly to `time` (s, >= self.time), splitting the step at maneuver starts and ends.

        The position and velocity at `time` do not depend on how the interval is cut,
        so any publish rate sees the same trajectory. ValueError if `time` is in the past.
        """
        if not math.isfinite(time):
            raise ValueError(f"time must be finite, got {time!r}")
        if time < self.time:
            raise ValueError(f"cannot propagate backwards from t={self.time!r} to t={time!r}")
        boundaries = sorted({edge for m in self.maneuvers for edge in (m.start, m.end) if self.time < edge < time})
        for boundary in (*boundaries, time):
            if boundary > self.time:
                self.step(boundary - self.time)
                # Land exactly on the boundary, so the next piece sees the maneuver that starts there.
                self.time = boundary
