"""The mission sequencer (companion.mission) against a scripted vehicle: phase transitions, abort in
every phase, vehicle link loss, the autopilot taking over. No processes, no sockets: the fake
vehicle produces odometry on demand at 50 Hz of vehicle time and records every command."""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from companion.adapters.mavsdk_vehicle import VehicleError, VehicleSample
from companion.core.messages import PursuerState
from companion.mission import TRANSITIONS, MissionSequencer, Phase
from interfaces.scenario import CompanionConfig

DT = 0.02  # s, odometry period
SETPOINT = object()  # what the fake follower "computes"; the sequencer only passes it on


@dataclass
class Outage:
    """No odometry from start (vehicle s) until end (None: never back)."""

    start: float
    end: float | None


@dataclass
class FakeVehicle:
    """A vehicle that flies nothing: time advances one odometry period per sample asked for."""

    outages: list[Outage] = field(default_factory=list)
    mode_changes: dict[float, str] = field(default_factory=dict)  # vehicle time -> mode the autopilot switches to
    on_sample: object = None  # called with the vehicle on every new sample (the test's script)
    time: float = 0.0
    latest: VehicleSample | None = None
    armed: bool | None = False
    flight_mode: SimpleNamespace | None = None
    commands: list[tuple[float, str]] = field(default_factory=list)

    def _sample(self) -> VehicleSample:
        self.latest = VehicleSample(PursuerState(self.time, np.zeros(3), np.zeros(3)), np.eye(3))
        for at, mode in list(self.mode_changes.items()):
            if self.time >= at:
                self.flight_mode = SimpleNamespace(name=mode)
                del self.mode_changes[at]
        if self.on_sample is not None:
            self.on_sample(self)
        return self.latest

    def _command(self, what: str) -> None:
        self.commands.append((self.time, what))

    async def next_sample(self, timeout: float = 5.0) -> VehicleSample:
        self.time = round(self.time + DT, 9)
        for outage in self.outages:
            if outage.start <= self.time and (outage.end is None or self.time < outage.end):
                if outage.end is not None:
                    self.time = outage.end - DT  # the caller's next wait ends with the first sample after it
                raise VehicleError(f"no odometry for {timeout:g} s")
        return self._sample()

    async def wait_for(self, predicate, timeout: float, what: str) -> VehicleSample:
        while True:
            sample = await self.next_sample()
            if predicate(sample):
                return sample

    async def arm(self) -> None:
        self._command("arm")
        self.armed = True

    async def takeoff(self, altitude: float, timeout: float = 60.0, settle: float = 0.0) -> VehicleSample:
        self._command("takeoff")
        for _ in range(50 + round(settle * 50)):  # a 1 s climb, then the settling
            sample = await self.next_sample()
        return sample

    async def start_offboard(self, setpoint) -> None:
        self._command("start_offboard")
        self.flight_mode = SimpleNamespace(name="OFFBOARD")

    async def send_setpoint(self, setpoint) -> None:
        self._command("setpoint")

    async def stop_offboard(self) -> None:
        self._command("stop_offboard")
        self.flight_mode = SimpleNamespace(name="HOLD")

    async def land(self) -> None:
        self._command("land")
        self.armed = False


class FakeFollower:
    """Has a setpoint from its fifth sample on and a new one every fifth sample; commands through the vehicle."""

    def __init__(self, vehicle: FakeVehicle) -> None:
        self.vehicle = vehicle
        self.steps = 0

    def step(self, sample):
        self.steps += 1
        ready = self.steps >= 5
        return SimpleNamespace(setpoint=SETPOINT if ready else None, new_setpoint=ready and self.steps % 5 == 0), []

    async def engage(self, output) -> None:
        await self.vehicle.start_offboard(output.setpoint)

    async def send(self, output) -> None:
        await self.vehicle.send_setpoint(output.setpoint)

    async def resume(self, sample) -> None:
        await self.vehicle.start_offboard(SETPOINT)

    async def report(self, sample, output, bearings, phase) -> None:
        pass


class Events:
    def __init__(self) -> None:
        self.records: list[tuple[float | None, str, str]] = []
        self.fields: list[dict] = []

    def event(self, sim_time, kind, detail, **fields) -> None:
        self.records.append((sim_time, kind, detail))
        self.fields.append({"kind": kind, **fields})


def _fly(vehicle: FakeVehicle, link_up=lambda: True, **settings) -> MissionSequencer:
    config = CompanionConfig(**{"settle_time": 0.5, "hold_after_abort": 3.0, **settings})
    sequencer = MissionSequencer(config, follow_duration=10.0, link_up=link_up, link_name="bof/target/t",
                                 log=Events(), echo=lambda line: None)
    asyncio.run(sequencer.run(vehicle, FakeFollower(vehicle)))
    return sequencer


def _phases(sequencer: MissionSequencer) -> list[Phase]:
    return [transition.target for transition in sequencer.transitions]


def _time_of(sequencer: MissionSequencer, phase: Phase) -> float:
    return next(transition.time for transition in sequencer.transitions if transition.target is phase)


def _assert_consistent(sequencer: MissionSequencer) -> None:
    """Each logged transition starts where the previous ended, is allowed, and is in the event log."""
    previous = Phase.WAITING
    for transition in sequencer.transitions:
        assert transition.source is previous and transition.target in TRANSITIONS[previous]
        previous = transition.target
    logged = [fields["phase"] for fields in sequencer.log.fields if fields["kind"] == "phase"]
    assert logged == [phase.value for phase in _phases(sequencer)]


def test_a_nominal_mission_goes_through_every_phase_and_follows_for_the_duration():
    vehicle = FakeVehicle()
    sequencer = _fly(vehicle)
    _assert_consistent(sequencer)
    assert _phases(sequencer) == [Phase.ARMING, Phase.TAKING_OFF, Phase.READY, Phase.FOLLOWING, Phase.LANDING, Phase.DONE]
    kinds = [what for _, what in vehicle.commands]
    assert kinds[:3] == ["arm", "takeoff", "start_offboard"] and kinds[-2:] == ["stop_offboard", "land"]
    assert set(kinds[3:-2]) == {"setpoint"}
    assert _time_of(sequencer, Phase.LANDING) - sequencer.engaged_at == pytest.approx(10.0, abs=2 * DT)
    # The follower's setpoint comes on its fifth sample after ready: engagement then, not before.
    assert sequencer.engaged_at == pytest.approx(_time_of(sequencer, Phase.READY) + 5 * DT)


def _abort_when(phase: Phase):
    def script(vehicle):
        if vehicle.sequencer.phase is phase:
            vehicle.sequencer.request_abort()
    return script


@pytest.mark.parametrize("phase", [Phase.ARMING, Phase.TAKING_OFF, Phase.READY, Phase.FOLLOWING, Phase.VEHICLE_LOST])
@pytest.mark.parametrize("on_return", ["resume", "land"])
def test_abort_in_any_phase_after_arming_holds_then_lands_and_stops_commanding(phase, on_return):
    vehicle = FakeVehicle(outages=[Outage(5.0, 6.0)])  # a vehicle link loss 2-3 s after engagement
    config = CompanionConfig(settle_time=0.5, hold_after_abort=3.0, on_vehicle_link_return=on_return)
    # The transitions go into the vehicle's command list too, so "after the abort" is exact.
    sequencer = MissionSequencer(config, follow_duration=10.0, link_up=lambda: True, link_name="k", log=Events(),
                                 echo=lambda line: vehicle.commands.append((vehicle.time, line)))
    vehicle.sequencer = sequencer
    vehicle.on_sample = _abort_when(phase)
    asyncio.run(sequencer.run(vehicle, FakeFollower(vehicle)))
    _assert_consistent(sequencer)
    assert _phases(sequencer)[-3:] == [Phase.ABORTING, Phase.LANDING, Phase.DONE]
    aborted = next(k for k, (_, what) in enumerate(vehicle.commands) if what.startswith("companion: aborting"))
    after = [(t, what) for t, what in vehicle.commands[aborted:] if not what.startswith("companion:")]
    assert [what for _, what in after] == ["stop_offboard", "land"]  # leave offboard (the autopilot holds), land
    assert after[1][0] - after[0][0] >= 3.0  # hold_after_abort
    if phase in (Phase.ARMING, Phase.TAKING_OFF):
        assert "start_offboard" not in [what for _, what in vehicle.commands]  # never engaged


def test_abort_before_arming_does_not_take_off():
    vehicle = FakeVehicle()
    sequencer = MissionSequencer(CompanionConfig(), follow_duration=10.0, link_up=lambda: False, link_name="k",
                                 log=Events(), echo=lambda line: None)
    vehicle.sequencer = sequencer
    vehicle.on_sample = _abort_when(Phase.WAITING)
    asyncio.run(sequencer.run(vehicle, FakeFollower(vehicle)))
    assert _phases(sequencer) == [Phase.DONE] and vehicle.commands == []


@pytest.mark.parametrize("on_return", ["resume", "land"])
def test_vehicle_link_loss_stops_commanding_until_telemetry_returns(on_return):
    vehicle = FakeVehicle(outages=[Outage(5.0, 6.0)])
    sequencer = _fly(vehicle, on_vehicle_link_return=on_return)
    _assert_consistent(sequencer)
    lost = _time_of(sequencer, Phase.VEHICLE_LOST)
    assert lost < 5.0 and sequencer.vehicle_link_losses == 1
    during = [what for t, what in vehicle.commands if lost <= t < 6.0]
    assert during == ["stop_offboard"]  # the setpoint stream stops at once; the failsafe acts
    back = [what for t, what in vehicle.commands if t >= 6.0]
    if on_return == "resume":
        assert sequencer.resumes == 1
        assert _phases(sequencer)[-4:] == [Phase.VEHICLE_LOST, Phase.FOLLOWING, Phase.LANDING, Phase.DONE]
        assert back[0] == "start_offboard" and back[-2:] == ["stop_offboard", "land"]
    else:
        assert sequencer.resumes == 0
        assert _phases(sequencer)[-3:] == [Phase.VEHICLE_LOST, Phase.LANDING, Phase.DONE]
        assert back == ["stop_offboard", "land"]  # no setpoint after the loss


def test_a_vehicle_link_that_never_returns_fails_the_mission_without_commanding():
    vehicle = FakeVehicle(outages=[Outage(5.0, None)])
    config = CompanionConfig(settle_time=0.5)
    sequencer = MissionSequencer(config, follow_duration=10.0, link_up=lambda: True, link_name="k", log=Events(),
                                 echo=lambda line: None)
    with pytest.raises(VehicleError, match="not back within"):
        asyncio.run(sequencer.run(vehicle, FakeFollower(vehicle)))
    assert sequencer.phase is Phase.VEHICLE_LOST
    assert [what for t, what in vehicle.commands if t >= _time_of(sequencer, Phase.VEHICLE_LOST)] == ["stop_offboard"]
    sequencer.fail("vehicle link gone")
    assert sequencer.phase is Phase.FAILED and sequencer.transitions[-1].detail == "vehicle link gone"


def test_the_autopilot_leaving_offboard_is_accepted_after_the_grace_time():
    vehicle = FakeVehicle(mode_changes={4.0: "POSCTL"})  # a pilot takes over 1-2 s after engagement
    sequencer = _fly(vehicle)  # on_vehicle_link_return = "land" (the default)
    _assert_consistent(sequencer)
    assert _phases(sequencer)[-3:] == [Phase.FOLLOWING, Phase.LANDING, Phase.DONE]
    landing = _time_of(sequencer, Phase.LANDING)
    assert landing == pytest.approx(4.0 + 2.0, abs=3 * DT)  # LEFT_OFFBOARD_GRACE
    # During the grace time setpoints go on (PX4 ignores them outside offboard); then only leave and land.
    assert {what for t, what in vehicle.commands if 4.0 < t < landing} == {"setpoint"}
    assert [what for t, what in vehicle.commands if t >= landing] == ["stop_offboard", "land"]


def test_no_target_fix_within_the_link_timeout_fails_before_arming():
    vehicle = FakeVehicle()
    sequencer = MissionSequencer(CompanionConfig(link_timeout=0.05), follow_duration=10.0, link_up=lambda: False,
                                 link_name="bof/target/target-1", log=Events(), echo=lambda line: None)

    async def slow_next_sample(timeout: float = 5.0):
        await asyncio.sleep(0.01)
        return await FakeVehicle.next_sample(vehicle, timeout)

    vehicle.next_sample = slow_next_sample
    with pytest.raises(VehicleError, match="no valid target fix on bof/target/target-1"):
        asyncio.run(sequencer.run(vehicle, FakeFollower(vehicle)))
    assert sequencer.transitions == [] and vehicle.commands == []


def test_transitions_outside_the_table_are_refused():
    sequencer = MissionSequencer(CompanionConfig(), follow_duration=1.0, link_up=lambda: True, link_name="k",
                                 log=Events(), echo=lambda line: None)
    with pytest.raises(ValueError, match="waiting -> following"):
        sequencer.set_phase(Phase.FOLLOWING)
    sequencer.set_phase(Phase.ARMING)
    sequencer.set_phase(Phase.ARMING, "again")  # staying is no transition
    assert _phases(sequencer) == [Phase.ARMING] and sequencer.transitions[0].time is None


def test_a_stop_while_following_is_an_abort_and_an_earlier_abort_survives_a_stop():
    sequencer = MissionSequencer(CompanionConfig(), follow_duration=1.0, link_up=lambda: True, link_name="k",
                                 log=Events(), echo=lambda line: None)
    sequencer.request_abort()
    sequencer.request_stop()
    assert sequencer.abort_requested and sequencer.stop_requested


class SwarmFollower(FakeFollower):
    """A swarm pursuer's follower: brakes before landing; its speed halves at every braking setpoint from 6 m/s."""

    stops_before_landing = True

    def __init__(self, vehicle: FakeVehicle) -> None:
        super().__init__(vehicle)
        self.speed = 6.0
        self.stops = []

    async def stop(self, sample) -> float:
        await self.vehicle.send_setpoint(None)
        self.stops.append(sample.state.time)
        self.speed /= 2.0
        return self.speed


def _fly_swarm(follower_class) -> tuple[MissionSequencer, FakeVehicle, SwarmFollower]:
    """A nominal mission (10 s of following) with a swarm pursuer's follower of `follower_class`; the vehicle
    knows its sequencer (vehicle.sequencer), for followers that command it."""
    vehicle = FakeVehicle()
    sequencer = MissionSequencer(CompanionConfig(settle_time=0.5, hold_after_abort=3.0), follow_duration=10.0,
                                 link_up=lambda: True, link_name="bof/target/t", log=Events(), echo=lambda line: None)
    vehicle.sequencer = sequencer
    follower = follower_class(vehicle)
    asyncio.run(sequencer.run(vehicle, follower))
    return sequencer, vehicle, follower


def test_a_swarm_pursuer_brakes_to_a_hover_before_the_autopilot_lands_it():
    """After the duration, a swarm pursuer stays in offboard and sends braking setpoints (the follower's stop: the
    separation filter with its neighbours) until slower than STOP_SPEED, then leaves offboard and lands; the
    phases are those of any mission, the braking is in the log."""
    from companion.mission import STOP_SPEED

    sequencer, vehicle, follower = _fly_swarm(SwarmFollower)
    _assert_consistent(sequencer)
    assert _phases(sequencer) == [Phase.ARMING, Phase.TAKING_OFF, Phase.READY, Phase.FOLLOWING, Phase.LANDING, Phase.DONE]
    assert len(follower.stops) == math.ceil(math.log2(6.0 / STOP_SPEED))  # halving from 6 m/s to below 0.3 m/s
    kinds = [what for _, what in vehicle.commands]
    assert kinds[-2:] == ["stop_offboard", "land"] and kinds[-2 - len(follower.stops):-2] == ["setpoint"] * len(follower.stops)
    assert min(follower.stops) >= sequencer.engaged_at + 10.0  # braking after the duration was flown
    assert [kind for _, kind, _ in sequencer.log.records if kind in ("stopping", "stopped")] == ["stopping", "stopped"]


def test_a_swarm_pursuer_gives_up_braking_after_the_timeout():
    """A follower that never gets slow enough brakes for STOP_TIMEOUT s of vehicle time, then lands anyway."""
    from companion.mission import STOP_TIMEOUT

    class NeverSlow(SwarmFollower):
        async def stop(self, sample) -> float:
            await super().stop(sample)
            return 6.0

    sequencer, _, follower = _fly_swarm(NeverSlow)
    assert _phases(sequencer)[-2:] == [Phase.LANDING, Phase.DONE]
    assert follower.stops[-1] - follower.stops[0] == pytest.approx(STOP_TIMEOUT, abs=2 * DT)


def test_an_abort_while_braking_ends_the_braking():
    """An abort command during the braking before landing leaves offboard at the next sample (the autopilot holds
    and lands), as an abort does in any other phase."""
    class AbortedWhileBraking(SwarmFollower):
        async def stop(self, sample) -> float:
            await super().stop(sample)
            self.vehicle.sequencer.request_abort()
            return 6.0

    sequencer, vehicle, follower = _fly_swarm(AbortedWhileBraking)
    assert len(follower.stops) == 1
    assert [what for _, what in vehicle.commands][-2:] == ["stop_offboard", "land"]
    assert _phases(sequencer)[-2:] == [Phase.LANDING, Phase.DONE]
