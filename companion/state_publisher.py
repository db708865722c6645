"""The companion's state on Zenoh, as network B of Fig. 16 did, so a ground station can watch.

At [link] state_rate_hz of vehicle time, in every phase: the mission phase, own state, the
link health, setpoints sent and, once the pipeline runs, the track mode, observability
figures, the filter health (companion.core.health: state, reasons, windowed NIS ratio,
sigma_r / r^) and the estimate with its covariance summary (TargetEstimate.position_std /
velocity_std) and estimated range, and with the IMM estimator its model probabilities
(companion.core.imm). Encoded by interfaces.link_schema.encode_state.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import numpy as np

from companion.adapters.mavsdk_vehicle import MavsdkVehicle, VehicleSample
from companion.core.pipeline import PipelineOutput
from companion.target_link import LinkHealth
from interfaces import link_schema as link

#: How often the loop looks for a new odometry sample, wall s (well under 1 / state_rate_hz).
POLL_PERIOD = 0.02


class StatePublisher:
    """Builds and publishes the state payload.

    companion_id: the sender name. rate_hz: payloads per second of vehicle time. put: sends
    one encoded payload (a Zenoh publisher's put). phase: the mission phase's value now.
    health: the target link's health. control: what the follower has done (setpoints_sent,
    last_output).
    """

    def __init__(self, companion_id: str, rate_hz: float, put: Callable[[bytes], None], phase: Callable[[], str],
                 health: LinkHealth, control) -> None:
        self.companion_id = companion_id
        self.rate_hz = rate_hz
        self.put = put
        self.phase = phase
        self.health = health
        self.control = control
        self.seq = 0
        self._next_time = 0.0

    async def run(self, vehicle: MavsdkVehicle) -> None:
        """Publish from the vehicle's newest sample until cancelled."""
        while True:
            await asyncio.sleep(POLL_PERIOD)
            if vehicle.latest is not None:
                self.publish(vehicle.latest)

    def publish(self, sample: VehicleSample) -> None:
        """Publish the state at the sample's time if the rate allows it."""
        now = sample.state.time
        if now < self._next_time:
            return
        self._next_time = now + 1.0 / self.rate_hz
        state = self.build(sample)
        state.update(sender=self.companion_id, seq=self.seq, stamp=now)
        self.seq += 1
        self.put(link.encode_state(state))

    def build(self, sample: VehicleSample) -> dict:
        """The state fields without sender/seq/stamp; positions m and velocities m/s NED, ages s."""
        last: PipelineOutput | None = self.control.last_output
        state = {
            "phase": self.phase(),
            "pursuer": {"position": sample.state.position, "velocity": sample.state.velocity},
            "link": self.health.as_dict(time.monotonic()),
            "setpoints_sent": self.control.setpoints_sent,
        }
        if last is not None:
            state["track"] = {"mode": last.mode.value, "bearing_age": last.bearing_age}
            if last.observability is not None:
                state["observability"] = dict(last.observability)
            health = getattr(last, "health", None)
            if health is not None:
                state["health"] = health.as_dict()
                action = getattr(last, "health_action", None)
                if action is not None:
                    state["health"].update(action=action.value, process_noise_boost=last.process_noise_boost)
        estimate = last.estimate if last is not None else None
        if estimate is not None:
            state["estimate"] = {
                "time": estimate.time,
                "position": estimate.position,
                "velocity": estimate.velocity,
                "position_std": estimate.position_std,
                "velocity_std": estimate.velocity_std,
                "range": float(np.linalg.norm(estimate.position - sample.state.position)),
            }
            probabilities = model_probabilities(getattr(self.control, "pipeline", None))
            if probabilities is not None:
                state["model_probabilities"] = probabilities
        return state


def model_probabilities(pipeline) -> dict[str, float] | None:
    """{model name: probability} of the pipeline's estimator when it is an interacting-multiple-model
    estimator (companion.core.imm.IMMEstimator: model_names, model_probabilities), else None."""
    estimator = getattr(pipeline, "estimator", None)
    names = getattr(estimator, "model_names", None)
    if names is None:
        return None
    return {name: float(p) for name, p in zip(names, estimator.model_probabilities)}
