"""The companion's control loop (companion.follower): what it measures of its own timing."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

from companion.follower import Follower


class _Vehicle:
    """Takes setpoints; `latest` is the newest odometry sample it has (only its time is read here)."""

    def __init__(self) -> None:
        self.latest = SimpleNamespace(state=SimpleNamespace(time=0.0))
        self.sent = 0

    async def send_setpoint(self, setpoint) -> None:
        self.sent += 1


class _Pipeline:
    """Records the loop delays the follower notes."""

    control_period = 0.05

    def __init__(self) -> None:
        self.noted: list[tuple[float, float]] = []

    def note_loop_delay(self, time: float, delay: float) -> None:
        self.noted.append((time, delay))


def test_the_follower_notes_how_long_the_vehicle_flew_each_setpoint_beyond_the_control_period() -> None:
    """Setpoints computed from the states at 0, 0.05, 0.10 and 0.15 s went out when the newest state was 0, 0.05,
    0.40 and 0.45 s. With each but the first the follower notes the vehicle time from the state the previous one
    was computed from to the newest state now, less the control period: 0.05 - 0 - 0.05 = 0,
    0.40 - 0.05 - 0.05 = 0.30 and 0.45 - 0.10 - 0.05 = 0.30 s."""
    follower = Follower(target_link=None, history=None, recorder=None)
    vehicle, pipeline = _Vehicle(), _Pipeline()
    follower.attach(vehicle, pipeline)

    async def fly() -> None:
        for computed_at, sent_at in ((0.0, 0.0), (0.05, 0.05), (0.10, 0.40), (0.15, 0.45)):
            vehicle.latest.state.time = sent_at
            await follower.send(SimpleNamespace(setpoint=None, time=computed_at))

    asyncio.run(fly())
    assert [time for time, _ in pipeline.noted] == [0.05, 0.40, 0.45]
    assert [round(delay, 9) for _, delay in pipeline.noted] == [0.0, 0.30, 0.30]
    assert vehicle.sent == 4
    assert follower.deadline_misses == 2  # the two setpoints sent more than a control period after their state
