"""Simulated target drone: the motion models a scenario's [target] chooses.

- TargetModel: constant velocity plus scheduled constant-speed horizontal turns. Covers the
  paper's constant-velocity target (VIII-A1), the "s" maneuver (VIII-A2), the flight
  experiment's 90-degree turn (IX-B2), and the named patterns of [target.circle] (circles,
  and helices when the initial velocity climbs), [target.weave] (repeated s-turns) and
  [target.turn] (one turn through a given angle), which expand to such a schedule.
- SpeedScheduleTarget: stop-and-go along a fixed direction, speed changes at a bounded
  acceleration ([target.stop_and_go]).
- SingerTarget: random acceleration, a first-order Gauss-Markov process (Singer 1970) held
  over short updates, with the speed and the lateral acceleration bounded ([target.singer]).
- SegmentTarget: a list of hover, accelerate, cruise, turn, climb and brake segments flown in
  order ([target] segments); after the last one the target holds its final velocity.
- TrajectoryTarget: a recorded track (CSV or PX4 ULog, interfaces.trajectory) replayed through
  a C2 cubic spline ([target.trajectory]); it hovers at its first point before the replay
  starts and flies on at the spline's final velocity after the last sample.

Every model keeps position, velocity and acceleration exactly consistent (closed-form
propagation between events; the spline and its derivatives for a recorded track), and
target_from_config builds the one a scenario names, for both the in-process simulator and
sitl-target. docs/targets.md describes the segment kinds and the trajectory formats.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from interfaces.scenario import TargetConfig
from interfaces.trajectory import read_trajectory

#: The Singer target's random stream is SeedSequence(seed, spawn_key=SINGER_SPAWN_KEY): a key no
#: other stream of the simulators uses (their streams are the seed's children 0, 1, 2, ...), so
#: adding a random target leaves every other noise of a flight exactly as it was.
SINGER_SPAWN_KEY = (0x7A47,)
#: Below this half turn (rad) in one step an arc is computed as a chord (the closed form cancels);
#: the shipped scenarios' steps turn far more, so their flights keep their exact arithmetic.
SMALL_TURN = 1e-6


class TargetMotion(Protocol):
    """What the harnesses use of a target model. time: s; position: m, NED, shape (3,);
    velocity: m/s, NED, shape (3,); acceleration: m/s^2, NED, shape (3,), the one that holds
    from `time` on (right-continuous where the model switches)."""

    time: float
    position: np.ndarray
    velocity: np.ndarray

    @property
    def acceleration(self) -> np.ndarray: ...

    def step(self, dt: float) -> None: ...

    def advance_to(self, time: float) -> None: ...


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
        self._starts = [m.start for m in self.maneuvers]
        self._speed = math.hypot(self.velocity[0], self.velocity[1])
        if self.maneuvers and self._speed < 1e-9:
            raise ValueError("a turning target needs a nonzero horizontal velocity")

    def lateral_acceleration(self, time: float) -> float:
        """Scheduled lateral acceleration at `time`, m/s^2 (maneuvers do not overlap: the last one started decides)."""
        index = bisect.bisect_right(self._starts, time) - 1
        if index >= 0 and time < self.maneuvers[index].end:
            return self.maneuvers[index].lateral_acceleration
        return 0.0

    @property
    def acceleration(self) -> np.ndarray:
        """m/s^2, NED, shape (3,): the scheduled lateral acceleration, horizontal and to the right of the velocity."""
        lateral = self.lateral_acceleration(self.time)
        if lateral == 0.0 or self._speed == 0.0:
            return np.zeros(3)
        return lateral / self._speed * np.array([-self.velocity[1], self.velocity[0], 0.0])

    def step(self, dt: float) -> None:
        """Advance by dt seconds (the maneuver active at the start of the step holds through it)."""
        turn_rate = self.lateral_acceleration(self.time) / self._speed if self.maneuvers and self._speed > 0.0 else 0.0
        if turn_rate == 0.0:
            # position + velocity * dt element by element on floats: numpy's elementwise multiply and add, the
            # same IEEE operations in the same order (the same bits), without two temporary arrays.
            p0, p1, p2 = self.position.tolist()
            v0, v1, v2 = self.velocity.tolist()
            self.position = np.array((p0 + v0 * dt, p1 + v1 * dt, p2 + v2 * dt))
        else:
            heading = math.atan2(self.velocity[1], self.velocity[0])
            new_heading = heading + turn_rate * dt
            half_turn = 0.5 * turn_rate * dt
            if abs(half_turn) < SMALL_TURN:
                # The difference of sines below cancels catastrophically for a tiny turn: the same arc
                # as a chord, (2 v / w) sin(w dt / 2) along the mean heading.
                chord = self._speed * dt * float(np.sinc(half_turn / math.pi))  # sin(x)/x, 1 at x = 0
                step = [chord * math.cos(heading + half_turn), chord * math.sin(heading + half_turn), self.velocity[2] * dt]
                self.position = self.position + np.array(step)
            else:
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


def _check_time(current: float, time: float) -> None:
    if not math.isfinite(time):
        raise ValueError(f"time must be finite, got {time!r}")
    if time < current:
        raise ValueError(f"cannot propagate backwards from t={current!r} to t={time!r}")


@dataclass(frozen=True)
class SpeedChange:
    """From `start` (s) on, the commanded speed is `speed` (m/s, >= 0)."""

    start: float
    speed: float


class SpeedScheduleTarget:
    """Stop-and-go: straight along the initial velocity's direction, speed following a schedule.

    initial_position: m, NED, shape (3,). initial_velocity: m/s, NED, shape (3,), nonzero:
    its direction is the track, its norm the speed until the first change. schedule:
    commanded speeds; the target accelerates or brakes at max_acceleration (m/s^2) until
    it flies the commanded speed, then holds it. Between events the acceleration is
    constant, so the propagation is exact (position quadratic in time).
    """

    def __init__(self, initial_position: np.ndarray, initial_velocity: np.ndarray, schedule: tuple[SpeedChange, ...],
                 max_acceleration: float) -> None:
        speed = float(np.linalg.norm(initial_velocity))
        if speed < 1e-9:
            raise ValueError("a stop-and-go target needs a nonzero initial_velocity (its direction is the track)")
        if not max_acceleration > 0.0:
            raise ValueError(f"max_acceleration must be positive, got {max_acceleration!r}")
        self.time = 0.0
        self.direction = np.asarray(initial_velocity, dtype=float) / speed
        self.speed = self.initial_speed = speed
        self.position = np.array(initial_position, dtype=float)
        self.schedule = tuple(sorted(schedule, key=lambda change: change.start))
        self.max_acceleration = float(max_acceleration)

    @property
    def velocity(self) -> np.ndarray:
        """m/s, NED, shape (3,)."""
        return self.speed * self.direction

    def commanded_speed(self, time: float) -> float:
        """The speed the schedule asks for at `time` (s), m/s."""
        commanded = None
        for change in self.schedule:
            if change.start <= time:
                commanded = change.speed
        return self.initial_speed if commanded is None else commanded

    def _along_track(self) -> float:
        """Along-track acceleration now, m/s^2: full braking or thrust until the command is reached."""
        error = self.commanded_speed(self.time) - self.speed
        return 0.0 if error == 0.0 else math.copysign(self.max_acceleration, error)

    @property
    def acceleration(self) -> np.ndarray:
        """m/s^2, NED, shape (3,), along the track."""
        return self._along_track() * self.direction

    def step(self, dt: float) -> None:
        """Advance by dt seconds, exactly."""
        self.advance_to(self.time + dt)

    def advance_to(self, time: float) -> None:
        """Propagate exactly to `time` (s, >= self.time), cutting at schedule changes and where a speed is reached."""
        _check_time(self.time, time)
        while self.time < time:
            acceleration = self._along_track()
            end = time
            reached = None
            for change in self.schedule:  # sorted: the first change ahead is the next one
                if self.time < change.start < end:
                    end = change.start
                    break
            if acceleration != 0.0:
                target_speed = self.commanded_speed(self.time)
                reach_time = self.time + (target_speed - self.speed) / acceleration
                if reach_time <= end:
                    end, reached = reach_time, target_speed
            dt = end - self.time
            self.position = self.position + self.direction * (self.speed * dt + 0.5 * acceleration * dt * dt)
            self.speed = reached if reached is not None else self.speed + acceleration * dt
            self.time = end


class SingerTarget:
    """Random-acceleration target (Singer 1970): a first-order Gauss-Markov acceleration, bounded.

    The latent acceleration a_k (m/s^2, NED, shape (3,)) is the exact discretisation of
    da = -a/tau dt + sigma sqrt(2/tau) dW over the update period T:
    a_{k+1} = phi a_k + sigma sqrt(1 - phi^2) w_k, phi = exp(-T/tau), w_k ~ N(0, I), started
    from its stationary law N(0, sigma^2), so E[a(t) a(t+s)] = sigma^2 exp(-|s|/tau) at every
    update. sigma applies to north and east, vertical_sigma (default 0: level flight) to down.
    Over each update the applied acceleration is held constant (position exactly quadratic in
    time) after two limits: the component normal to the velocity is cut so that the lateral
    acceleration |a x v| / |v| stays within max_lateral_acceleration at every instant of the
    update, and the along-track component so that the speed stays within [0, max_speed]
    (the speed is convex in time under a constant acceleration, so the end points decide).
    rng: the target's own generator (target_from_config seeds it from the flight's seed).
    """

    def __init__(self, initial_position: np.ndarray, initial_velocity: np.ndarray, *, time_constant: float, sigma: float,
                 vertical_sigma: float, max_speed: float, max_lateral_acceleration: float, update_period: float,
                 rng: np.random.Generator) -> None:
        if not (time_constant > 0.0 and update_period > 0.0 and sigma >= 0.0 and vertical_sigma >= 0.0
                and max_speed > 0.0 and max_lateral_acceleration > 0.0):
            raise ValueError("time_constant, update_period, max_speed, max_lateral_acceleration must be positive, "
                             "sigma and vertical_sigma non-negative")
        if float(np.linalg.norm(initial_velocity)) > max_speed:
            raise ValueError(f"the initial speed {np.linalg.norm(initial_velocity):g} m/s exceeds max_speed {max_speed:g}")
        self.time = 0.0
        self.position = np.array(initial_position, dtype=float)
        self.velocity = np.array(initial_velocity, dtype=float)
        self.time_constant = float(time_constant)
        self.update_period = float(update_period)
        self.max_speed = float(max_speed)
        self.max_lateral_acceleration = float(max_lateral_acceleration)
        self._sigma = np.array([sigma, sigma, vertical_sigma], dtype=float)
        self._phi = math.exp(-self.update_period / self.time_constant)
        self._drive = self._sigma * math.sqrt(1.0 - self._phi**2)
        self._rng = rng
        self.latent_acceleration = self._sigma * rng.standard_normal(3)
        self._updates = 0
        self._applied = self._limited(self.latent_acceleration)

    @property
    def acceleration(self) -> np.ndarray:
        """m/s^2, NED, shape (3,): the applied (limited) acceleration held over the current update."""
        return self._applied.copy()

    def _limited(self, wanted: np.ndarray) -> np.ndarray:
        """The acceleration applied over the next update for the latent one `wanted` (see the class)."""
        dt = self.update_period
        speed = float(np.linalg.norm(self.velocity))
        if speed == 0.0:
            # No track yet: the whole acceleration is along the velocity it creates (lateral 0).
            magnitude = float(np.linalg.norm(wanted))
            if magnitude * dt <= self.max_speed:
                return wanted.copy()
            return wanted * (self.max_speed / dt / magnitude)
        tangent = self.velocity / speed
        along = float(wanted @ tangent)
        lateral = wanted - along * tangent
        # Speed bounds at the end of the update: never reverse through zero, never over max_speed.
        along = max(along, -speed / dt)
        lateral_norm = float(np.linalg.norm(lateral))
        lateral_norm_capped = min(lateral_norm, self.max_lateral_acceleration)
        room = self.max_speed**2 - (lateral_norm_capped * dt) ** 2
        if (speed + along * dt) ** 2 + (lateral_norm_capped * dt) ** 2 > self.max_speed**2:
            along = (math.sqrt(max(room, 0.0)) - speed) / dt
        # |a x v(t)| = speed * |lateral| is constant over the update and |v(t)| >= the along-track speed,
        # smallest at one end: cap |lateral| so |a x v(t)| / |v(t)| <= the limit throughout.
        slowest = max(min(speed, speed + along * dt), 0.0)
        lateral_limit = self.max_lateral_acceleration * min(1.0, slowest / speed)
        if lateral_norm > lateral_limit:
            lateral = lateral * (lateral_limit / lateral_norm)
        return along * tangent + lateral

    def _next_update_time(self) -> float:
        return (self._updates + 1) * self.update_period

    def step(self, dt: float) -> None:
        """Advance by dt seconds, exactly."""
        self.advance_to(self.time + dt)

    def advance_to(self, time: float) -> None:
        """Propagate exactly to `time` (s, >= self.time); the updates fall at multiples of update_period
        whatever the cuts, so any publish rate sees the same trajectory."""
        _check_time(self.time, time)
        while self.time < time:
            boundary = self._next_update_time()
            end = min(boundary, time)
            dt = end - self.time
            self.position = self.position + self.velocity * dt + 0.5 * self._applied * dt * dt
            self.velocity = self.velocity + self._applied * dt
            self.time = end
            if end == boundary:
                self._updates += 1
                self.latent_acceleration = self._phi * self.latent_acceleration + self._drive * self._rng.standard_normal(3)
                self._applied = self._limited(self.latent_acceleration)


@dataclass(frozen=True)
class _Piece:
    """One closed-form piece of a segment plan, from `start` (s) to the next piece's start.

    position, velocity: the state at `start` (m, m/s, NED, shape (3,)). turn_rate 0: constant
    `acceleration` (m/s^2, NED, shape (3,)), position quadratic in time; turn_rate w != 0 (rad/s about
    down, + right): a horizontal turn at the start's horizontal speed keeping the vertical velocity.
    """

    start: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    turn_rate: float = 0.0

    def state(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) at `time` (s, >= start), NED, shape (3,) each."""
        tau = time - self.start
        if self.turn_rate == 0.0:
            return self.position + self.velocity * tau + 0.5 * self.acceleration * tau * tau, self.velocity + self.acceleration * tau
        north, east, down = self.velocity
        speed, heading = math.hypot(north, east), math.atan2(east, north)
        half_turn = 0.5 * self.turn_rate * tau
        # The arc as its chord, (2 v / w) sin(w tau / 2) along the mean heading: exact, and free of the
        # cancellation the difference-of-sines form has for small turns.
        chord = speed * tau * float(np.sinc(half_turn / math.pi))
        middle, end = heading + half_turn, heading + 2.0 * half_turn
        position = self.position + np.array([chord * math.cos(middle), chord * math.sin(middle), down * tau])
        return position, np.array([speed * math.cos(end), speed * math.sin(end), down])

    def acceleration_at(self, velocity: np.ndarray) -> np.ndarray:
        """m/s^2, NED, shape (3,), given the velocity (m/s) at that instant: w x v for a turn."""
        if self.turn_rate == 0.0:
            return self.acceleration.copy()
        return self.turn_rate * np.array([-velocity[1], velocity[0], 0.0])


def _segment_plan(initial_position: np.ndarray, initial_velocity: np.ndarray, segments: tuple) -> list[_Piece]:
    """The closed-form pieces of a segment list (interfaces.scenario's HoverSegment ... BrakeSegment), ending with
    an unbounded piece at the final velocity. Where a segment reaches a commanded velocity the next piece starts
    from exactly that velocity, so brakes end at rest and hovers hold exactly."""
    time, position, velocity = 0.0, np.array(initial_position, dtype=float), np.array(initial_velocity, dtype=float)
    pieces: list[_Piece] = []

    def fly_to(end: float, acceleration: np.ndarray | None = None, turn_rate: float = 0.0) -> None:
        nonlocal time, position, velocity
        if end <= time:
            return
        piece = _Piece(time, position, velocity, np.zeros(3) if acceleration is None else acceleration, turn_rate)
        pieces.append(piece)
        position, velocity = piece.state(end)
        time = end

    def fly(duration: float, acceleration: np.ndarray | None = None, turn_rate: float = 0.0) -> None:
        fly_to(time + duration, acceleration, turn_rate)

    def change_to(goal: np.ndarray, max_acceleration: float, duration: float | None) -> None:
        nonlocal velocity
        start = time
        change = goal - velocity
        size = float(np.linalg.norm(change))
        if size > 0.0:
            fly(size / max_acceleration, change * (max_acceleration / size))
        velocity = goal
        if duration is not None:
            # The segment ends exactly duration after it began, whatever the rounding of the change's length.
            fly_to(start + duration)

    for index, segment in enumerate(segments):
        if segment.kind == "hover":
            if np.any(velocity != 0.0):
                raise ValueError(f"segments[{index}] (hover): the target still moves at "
                                 f"{np.linalg.norm(velocity):g} m/s when the hover starts")
            fly(segment.duration)
        elif segment.kind == "cruise":
            fly(segment.duration)
        elif segment.kind == "accelerate":
            change_to(np.array(segment.velocity, dtype=float), segment.max_acceleration, segment.duration)
        elif segment.kind == "climb":
            change_to(np.array([velocity[0], velocity[1], -segment.rate]), segment.max_acceleration, segment.duration)
        elif segment.kind == "brake":
            change_to(np.zeros(3), segment.max_acceleration, None)
        elif segment.kind == "turn":
            if math.hypot(velocity[0], velocity[1]) == 0.0:
                raise ValueError(f"segments[{index}] (turn): the target has no horizontal speed to turn")
            fly(segment.turn_time, turn_rate=segment.rate)
        else:
            raise ValueError(f"segments[{index}]: unknown kind {segment.kind!r}")
    pieces.append(_Piece(time, position, velocity, np.zeros(3)))
    return pieces


class SegmentTarget:
    """A list of segments flown in order ([target] segments): hover, accelerate, cruise, turn, climb, brake.

    initial_position: m, NED, shape (3,). initial_velocity: m/s, NED, shape (3,), the first segment's start.
    segments: interfaces.scenario's segment configurations (their docstrings give each kind's motion). Each
    segment is one or two closed-form pieces (a constant acceleration, or a constant-rate horizontal turn),
    so the state at any time is evaluated exactly from the start of its piece and does not depend on how
    time is cut. After the last segment the target holds its final velocity.
    """

    def __init__(self, initial_position: np.ndarray, initial_velocity: np.ndarray, segments: tuple) -> None:
        self.pieces = _segment_plan(initial_position, initial_velocity, segments)
        self._starts = [piece.start for piece in self.pieces]
        self.time = 0.0
        self.position = np.array(initial_position, dtype=float)
        self.velocity = np.array(initial_velocity, dtype=float)
        self._index = 0

    @property
    def end_time(self) -> float:
        """s: when the last segment ends (the final velocity holds from then on)."""
        return self._starts[-1]

    @property
    def acceleration(self) -> np.ndarray:
        """m/s^2, NED, shape (3,): the acceleration of the piece flown from self.time on."""
        return self.pieces[self._index].acceleration_at(self.velocity)

    def step(self, dt: float) -> None:
        """Advance by dt seconds, exactly."""
        self.advance_to(self.time + dt)

    def advance_to(self, time: float) -> None:
        """Propagate exactly to `time` (s, >= self.time); at a piece boundary the new piece holds."""
        _check_time(self.time, time)
        self._index = bisect.bisect_right(self._starts, time) - 1
        self.position, self.velocity = self.pieces[self._index].state(time)
        self.time = time


class TrajectoryTarget:
    """A recorded track replayed ([target.trajectory]): a C2 cubic spline through the samples (scipy's
    CubicSpline, not-a-knot ends); position, velocity and acceleration are the spline and its derivatives.

    times: s, shape (n,), strictly increasing, n >= 4; positions: m, NED, shape (n, 3) (interfaces.trajectory.
    read_trajectory). The replay plays file time times[0] + skip + (t - start) at scenario time t (s), translated
    so that its first point (file time times[0] + skip) is at initial_position (m, NED, shape (3,)). Before
    `start` the target hovers at that point (velocity 0); after the file's last sample it flies on at the
    spline's final velocity (acceleration 0), so position and velocity stay continuous there.
    """

    def __init__(self, times: np.ndarray, positions: np.ndarray, initial_position: np.ndarray, *, skip: float = 0.0,
                 start: float = 0.0) -> None:
        times = np.asarray(times, dtype=float)
        relative = times - times[0]
        if not 0.0 <= skip < relative[-1]:
            raise ValueError(f"skip {skip!r} s must be within the track's {relative[-1]:g} s")
        from scipy.interpolate import CubicSpline  # here: only a recorded track needs scipy.interpolate

        self._spline = CubicSpline(relative, np.asarray(positions, dtype=float), axis=0)
        self._velocity_spline = self._spline.derivative(1)
        self._acceleration_spline = self._spline.derivative(2)
        self.skip, self.start, self.duration = float(skip), float(start), float(relative[-1])
        self._offset = np.asarray(initial_position, dtype=float) - self._spline(self.skip)
        self._last_position = self._spline(self.duration) + self._offset
        self._last_velocity = self._velocity_spline(self.duration)
        self.time = 0.0
        self.position, self.velocity, self._acceleration = self._state(0.0)

    @property
    def end_time(self) -> float:
        """s: the scenario time of the file's last sample (the final velocity holds from then on)."""
        return self.start + self.duration - self.skip

    def _state(self, time: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if time < self.start:
            return self._offset + self._spline(self.skip), np.zeros(3), np.zeros(3)
        replayed = self.skip + (time - self.start)
        if replayed >= self.duration:
            return self._last_position + self._last_velocity * (replayed - self.duration), self._last_velocity.copy(), np.zeros(3)
        return (self._spline(replayed) + self._offset, self._velocity_spline(replayed),
                self._acceleration_spline(replayed))

    @property
    def acceleration(self) -> np.ndarray:
        """m/s^2, NED, shape (3,): the spline's second derivative (0 while hovering before start and after the end)."""
        return self._acceleration.copy()

    def step(self, dt: float) -> None:
        """Advance by dt seconds, exactly."""
        self.advance_to(self.time + dt)

    def advance_to(self, time: float) -> None:
        """Evaluate at `time` (s, >= self.time): the state depends on the time only, not on how it is cut."""
        _check_time(self.time, time)
        self.position, self.velocity, self._acceleration = self._state(time)
        self.time = time


def pattern_maneuvers(config: TargetConfig) -> tuple[Maneuver, ...]:
    """The turn schedule of a [target]: its explicit maneuvers, or those of its named pattern.

    Turns are horizontal at the initial horizontal speed v (m/s); lateral acceleration a
    (m/s^2, + right): circle a = v^2 / radius or v * turn_rate (a helix when the initial
    velocity climbs); weave: +-lateral_acceleration alternating every half_period, the first
    turn half as long so the heading swings symmetrically about the initial one; turn: a
    turn through angle_deg in `duration` at a = v * angle / duration, and the same turn back
    right after it when turn_back is set.
    """
    speed = math.hypot(*config.initial_velocity[:2])
    if config.circle is not None:
        circle = config.circle
        magnitude = speed**2 / circle.radius if circle.radius is not None else speed * circle.turn_rate
        sign = 1.0 if circle.direction == "right" else -1.0
        return (Maneuver(circle.start, circle.end, sign * magnitude),)
    if config.weave is not None:
        weave = config.weave
        sign = 1.0 if weave.direction == "right" else -1.0
        maneuvers, start, length, index = [], weave.start, weave.half_period / 2.0, 0
        while start < weave.end:
            end = min(start + length, weave.end)
            maneuvers.append(Maneuver(start, end, sign * (-1) ** index * weave.lateral_acceleration))
            start, length, index = end, weave.half_period, index + 1
        return tuple(maneuvers)
    if config.turn is not None:
        turn = config.turn
        sign = 1.0 if turn.direction == "right" else -1.0
        magnitude = speed * math.radians(turn.angle_deg) / turn.duration
        first = Maneuver(turn.start, turn.start + turn.duration, sign * magnitude)
        if not turn.turn_back:
            return (first,)
        return first, Maneuver(first.end, first.end + turn.duration, -sign * magnitude)
    return tuple(Maneuver(m.start, m.end, m.lateral_acceleration) for m in config.maneuvers)


def target_from_config(config: TargetConfig, seed: int) -> TargetMotion:
    """The target model a scenario's [target] names, at scenario time 0.

    seed: the flight's seed; only the Singer target draws from it, on its own stream
    (SINGER_SPAWN_KEY). The same config and seed give the same trajectory in both harnesses.
    """
    if config.trajectory is not None:
        recorded = config.trajectory
        times, positions = read_trajectory(Path(recorded.file), recorded.file_format)
        return TrajectoryTarget(times, positions, np.array(config.initial_position), skip=recorded.skip,
                                start=recorded.start)
    position, velocity = np.array(config.initial_position), np.array(config.initial_velocity)
    if config.segments is not None:
        return SegmentTarget(position, velocity, config.segments)
    if config.stop_and_go is not None:
        plan = config.stop_and_go
        return SpeedScheduleTarget(position, velocity, tuple(SpeedChange(c.start, c.speed) for c in plan.schedule),
                                   plan.max_acceleration)
    if config.singer is not None:
        singer = config.singer
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=SINGER_SPAWN_KEY))
        return SingerTarget(position, velocity, time_constant=singer.time_constant, sigma=singer.sigma,
                            vertical_sigma=singer.vertical_sigma, max_speed=singer.max_speed,
                            max_lateral_acceleration=singer.max_lateral_acceleration,
                            update_period=singer.update_period, rng=rng)
    return TargetModel(position, velocity, pattern_maneuvers(config))
