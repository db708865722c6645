"""The mission sequencer: the companion's commander, an explicit state machine over the mission phases.

    waiting -> arming -> taking_off -> ready -> following -> landing -> done
    waiting -> done                           (abort command before arming: no take-off)
    ready -> landing                          (the vehicle link failed before engagement)
    following <-> vehicle_link_lost -> landing
    ready | following | vehicle_link_lost -> aborting -> landing    (abort command, or a stop while following)
    any phase -> failed

waiting: for odometry and a first valid target fix. arming, taking_off (to the engage
altitude), then a settle hover. ready: the pipeline runs on every odometry sample until it
has a first setpoint; the companion then starts offboard (following) and follows for
follow_duration of vehicle time; in a swarm it then brakes to a hover in offboard with the separation
filter (still in the following phase, logged as "stopping"/"stopped" events) before the autopilot lands it,
so that a pursuer that ends its following a moment before another is not flown into. An abort command makes it leave offboard (the autopilot
holds), hover hold_after_abort and land; an abort before arming ends the mission on the
ground. Vehicle link loss (no odometry for vehicle_link_timeout) stops all commanding and
leaves the autopilot's offboard-loss failsafe in charge; when telemetry returns the
companion resumes or lands as [companion] on_vehicle_link_return says. The same happens
when the autopilot leaves offboard on its own.

Every transition is checked against TRANSITIONS and recorded as a `Transition`
(time, from, to, detail), logged as a "phase" event and printed. The per-sample control
work while following is the Follower's (companion.follower); the sequencer decides when it
may command the vehicle.
"""

from __future__ import annotations

import asyncio
import enum
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from companion.adapters.mavsdk_vehicle import VehicleError, VehicleSample
from companion.console import say
from companion.core.fix_validator import CommandValidator, FixRejected
from interfaces.scenario import CompanionConfig

if TYPE_CHECKING:
    from companion.follower import Follower

#: The autopilot must show a mode other than offboard this long (vehicle s) before the companion
#: concludes it took over (heartbeats come at 1 Hz).
LEFT_OFFBOARD_GRACE = 2.0
#: A swarm pursuer's braking before it lands (MissionSequencer._stop_in_place) ends below this speed, m/s, or after
#: this long, s of vehicle time (a 1 s time constant takes 6 m/s to 0.3 m/s in 3 s).
STOP_SPEED = 0.3
STOP_TIMEOUT = 6.0


class Phase(str, enum.Enum):
    WAITING = "waiting"
    ARMING = "arming"
    TAKING_OFF = "taking_off"
    READY = "ready"
    FOLLOWING = "following"
    VEHICLE_LOST = "vehicle_link_lost"
    ABORTING = "aborting"
    LANDING = "landing"
    DONE = "done"
    FAILED = "failed"


#: The allowed transitions; any phase may also go to FAILED (an error ends the mission wherever it is).
TRANSITIONS: dict[Phase, frozenset[Phase]] = {
    Phase.WAITING: frozenset({Phase.ARMING, Phase.DONE}),
    Phase.ARMING: frozenset({Phase.TAKING_OFF}),
    Phase.TAKING_OFF: frozenset({Phase.READY}),
    Phase.READY: frozenset({Phase.FOLLOWING, Phase.ABORTING, Phase.LANDING}),
    Phase.FOLLOWING: frozenset({Phase.VEHICLE_LOST, Phase.ABORTING, Phase.LANDING}),
    Phase.VEHICLE_LOST: frozenset({Phase.FOLLOWING, Phase.ABORTING, Phase.LANDING}),
    Phase.ABORTING: frozenset({Phase.LANDING}),
    Phase.LANDING: frozenset({Phase.DONE}),
    Phase.DONE: frozenset(),
    Phase.FAILED: frozenset(),
}


@dataclass(frozen=True)
class Transition:
    """One phase change. time: vehicle time s (None before the first odometry). detail: why, free text."""

    time: float | None
    source: Phase
    target: Phase
    detail: str


class EventLog(Protocol):
    def event(self, sim_time: float | None, kind: str, detail: str) -> None: ...


class Vehicle(Protocol):
    """What the sequencer asks of the autopilot (companion.adapters.mavsdk_vehicle.MavsdkVehicle)."""

    latest: VehicleSample | None
    armed: bool | None
    flight_mode: object | None

    async def next_sample(self, timeout: float = 5.0) -> VehicleSample: ...
    async def wait_for(self, predicate: Callable[[VehicleSample], bool], timeout: float, what: str) -> VehicleSample: ...
    async def arm(self) -> None: ...
    async def takeoff(self, altitude: float, timeout: float = 60.0, settle: float = 0.0) -> VehicleSample: ...
    async def stop_offboard(self) -> None: ...
    async def land(self) -> None: ...


class MissionSequencer:
    """Runs one mission on one vehicle; `phase` is its state, `transitions` its history.

    settings: the scenario's [companion] section. follow_duration: s of vehicle time to follow
    once engaged. link_up: true once a valid target fix has arrived. link_name: the fix key, for
    the timeout message. log: where events go (the run recorder). echo: writes each transition (default: the
    companion's console log, companion.console).
    commands: the freshness and order check of ground-station commands (CommandValidator; its
    counters say what was refused).
    """

    def __init__(self, settings: CompanionConfig, follow_duration: float, link_up: Callable[[], bool], link_name: str,
                 log: EventLog, echo: Callable[[str], None] = say,
                 commands: CommandValidator | None = None) -> None:
        self.commands = commands if commands is not None else CommandValidator()
        self.settings = settings
        self.follow_duration = follow_duration
        self.link_up = link_up
        self.link_name = link_name
        self.log = log
        self.echo = echo
        self.phase = Phase.WAITING
        self.transitions: list[Transition] = []
        self.abort_requested = False
        self.stop_requested = False
        self.engaged_at: float | None = None
        self.vehicle_link_losses = 0
        self.resumes = 0
        self.vehicle: Vehicle | None = None
        self._left_offboard_since: float | None = None

    # ------------------------------------------------------------ the machine
    def set_phase(self, phase: Phase, detail: str = "") -> None:
        """Go to `phase` (a no-op if already there); ValueError for a transition TRANSITIONS does not allow."""
        if phase == self.phase:
            return
        if phase not in TRANSITIONS[self.phase] and phase is not Phase.FAILED:
            raise ValueError(f"mission: no transition {self.phase.value} -> {phase.value}")
        sample = self.vehicle.latest if self.vehicle is not None else None
        transition = Transition(sample.state.time if sample else None, self.phase, phase, detail)
        self.phase = phase
        self.transitions.append(transition)
        self.log.event(transition.time, "phase", f"{phase.value} {detail}".strip(), phase=phase.value,
                       previous=transition.source.value)
        self.echo(f"companion: {phase.value} {detail}".rstrip())

    def fail(self, detail: str) -> None:
        self.set_phase(Phase.FAILED, detail)

    def refuse_command(self, command, now: float | None) -> str | None:
        """Why a decoded command (interfaces.link_schema.Command) must not act ("reason: detail"), or None
        if it may: order per (sender, epoch) and freshness against vehicle time `now` (s; None: no_clock)."""
        try:
            self.commands.check(command.sender, command.epoch, command.seq, command.stamp, now)
        except FixRejected as error:
            return str(error)
        return None

    def request_abort(self) -> None:
        """The ground station's abort: hold, then land (before arming: do not take off)."""
        self.abort_requested = True

    def request_stop(self) -> None:
        """SIGINT/SIGTERM: end the mission; while following that means abort (hold, then land)."""
        self.stop_requested = True
        self.abort_requested = self.abort_requested or self.phase == Phase.FOLLOWING

    # -------------------------------------------------------------- mission
    async def run(self, vehicle: Vehicle, follower: "Follower") -> None:
        """Fly the mission to done (or return early on a stop while on the ground); VehicleError on failure."""
        self.vehicle = vehicle
        await vehicle.next_sample(10.0)
        await self._wait_for_link()
        if self.stop_requested:
            return
        if self.abort_requested:
            self.set_phase(Phase.DONE, "abort command before arming: not taking off")
            return
        self.set_phase(Phase.ARMING)
        await vehicle.wait_for(lambda s: True, 10.0, "own state")
        await self._retry("arm", vehicle.arm, attempts=10, pause=0.5)
        self.set_phase(Phase.TAKING_OFF, f"to {self.settings.engage_altitude:g} m")
        await vehicle.takeoff(self.settings.engage_altitude, timeout=120.0, settle=self.settings.settle_time)
        self.set_phase(Phase.READY)
        await self._follow(follower)
        if self.abort_requested:
            self.set_phase(Phase.ABORTING, "abort command: holding")
            await vehicle.stop_offboard()
            start = vehicle.latest.state.time
            await vehicle.wait_for(lambda s: s.state.time > start + self.settings.hold_after_abort, 60.0, "abort hold")
        elif self.phase in (Phase.FOLLOWING, Phase.VEHICLE_LOST):
            if self.phase is Phase.FOLLOWING and not self.stop_requested and getattr(follower, "stops_before_landing", False):
                await self._stop_in_place(follower)
            try:
                await vehicle.stop_offboard()
            except VehicleError as error:
                self.log.event(vehicle.latest.state.time, "vehicle_link", f"offboard stop: {error}")
        if self.stop_requested and not self.abort_requested:
            return
        self.set_phase(Phase.LANDING)
        await vehicle.land()
        await self._wait_until(lambda: vehicle.armed is False, 120.0, "disarm after landing")
        self.set_phase(Phase.DONE)

    async def _stop_in_place(self, follower: "Follower") -> None:
        """After the duration is flown, in a swarm: brake to a hover in offboard, with the separation filter (the
        follower's `stop`), until slower than STOP_SPEED m/s or STOP_TIMEOUT s of vehicle time, then the autopilot
        lands it. A lost vehicle link, an abort or a stop ends the braking (what follows is the autopilot's)."""
        vehicle = self.vehicle
        start = vehicle.latest.state.time
        self.log.event(start, "stopping", "braking to a hover with the separation filter before landing")
        speed, now = math.inf, start
        while speed >= STOP_SPEED and now - start <= STOP_TIMEOUT and not (self.abort_requested or self.stop_requested):
            try:
                sample = await vehicle.next_sample(self.settings.vehicle_link_timeout)
            except VehicleError as error:
                self.log.event(now, "vehicle_link", f"braking: {error}")
                return
            now = sample.state.time
            speed = await follower.stop(sample)
        self.log.event(now, "stopped", f"{speed:.2f} m/s after {now - start:.2f} s", speed=round(speed, 3))

    async def _retry(self, what: str, action: Callable[[], Awaitable[None]], attempts: int, pause: float) -> None:
        for attempt in range(attempts):
            try:
                return await action()
            except VehicleError as error:
                if attempt == attempts - 1:
                    raise
                self.log.event(None, "retry", f"{what}: {error}")
                await asyncio.sleep(pause)

    @staticmethod
    async def _wait_until(predicate: Callable[[], bool], timeout: float, what: str) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not predicate():
            if loop.time() > deadline:
                raise VehicleError(f"timed out after {timeout:g} s waiting for {what}")
            await asyncio.sleep(0.05)

    async def _wait_for_link(self) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.settings.link_timeout
        while not self.link_up() and not self.stop_requested and not self.abort_requested:
            if loop.time() > deadline:
                raise VehicleError(f"no valid target fix on {self.link_name} within {self.settings.link_timeout:g} s")
            await self.vehicle.next_sample(10.0)

    # ------------------------------------------------------------ following
    async def _follow(self, follower: "Follower") -> None:
        """ready -> following until the duration is flown, an abort/stop, or the vehicle link is gone for good."""
        vehicle = self.vehicle
        while not (self.abort_requested or self.stop_requested):
            try:
                sample = await vehicle.next_sample(self.settings.vehicle_link_timeout)
            except VehicleError:
                if self.engaged_at is None or not await self._vehicle_link_lost(follower):
                    return
                continue
            output, bearings = follower.step(sample)
            if output.setpoint is not None and self.engaged_at is None:
                await follower.engage(output)
                self.engaged_at = sample.state.time
                self.set_phase(Phase.FOLLOWING, f"engaged at t={sample.state.time:.2f} s")
            elif output.new_setpoint and output.setpoint is not None:
                await follower.send(output)
            await follower.report(sample, output, bearings, self.phase.value)
            if self.engaged_at is not None and sample.state.time >= self.engaged_at + self.follow_duration:
                break
            if self.engaged_at is not None and vehicle.flight_mode is not None and vehicle.flight_mode.name != "OFFBOARD":
                # The autopilot left offboard (its failsafe, or a pilot): it is in charge now.
                if self._left_offboard_since is None:
                    self._left_offboard_since = sample.state.time
                elif sample.state.time - self._left_offboard_since > LEFT_OFFBOARD_GRACE:
                    reason = f"autopilot left offboard (mode {vehicle.flight_mode.name})"
                    if not await self._after_autopilot_took_over(sample, follower, reason):
                        return
            else:
                self._left_offboard_since = None

    async def _vehicle_link_lost(self, follower: "Follower") -> bool:
        """No odometry for vehicle_link_timeout: stop commanding (MAVSDK's re-sending included) and let
        the autopilot's offboard-loss failsafe act. When telemetry returns, re-engage if
        [companion] on_vehicle_link_return = "resume"; otherwise land. Returns True to go on following."""
        vehicle = self.vehicle
        lost_at = vehicle.latest.state.time
        self.vehicle_link_losses += 1
        self.set_phase(Phase.VEHICLE_LOST, f"no telemetry for {self.settings.vehicle_link_timeout:g} s")
        try:
            await vehicle.stop_offboard()  # stops the setpoint stream first; the mode command may not get through
        except VehicleError as error:
            self.log.event(lost_at, "vehicle_link", f"offboard stop not acknowledged: {error}")
        try:
            sample = await vehicle.next_sample(self.settings.vehicle_link_wait)
        except VehicleError:
            raise VehicleError(f"vehicle link lost at t={lost_at:.2f} s and not back within "
                               f"{self.settings.vehicle_link_wait:g} s") from None
        self.log.event(sample.state.time, "vehicle_link", f"telemetry back after {sample.state.time - lost_at:.2f} s "
                                                          f"(autopilot mode {vehicle.flight_mode.name if vehicle.flight_mode else '?'})")
        return await self._after_autopilot_took_over(sample, follower, "vehicle link back")

    async def _after_autopilot_took_over(self, sample: VehicleSample, follower: "Follower", reason: str) -> bool:
        """Re-engage offboard if [companion] on_vehicle_link_return allows it, else leave it to landing."""
        self.log.event(sample.state.time, "vehicle_link", reason)
        self._left_offboard_since = None
        if self.settings.on_vehicle_link_return != "resume":
            self.log.event(sample.state.time, "vehicle_link", "not resuming (on_vehicle_link_return = land)")
            return False
        await follower.resume(sample)
        self.resumes += 1
        self.set_phase(Phase.FOLLOWING, f"resumed at t={sample.state.time:.2f} s")
        return True
