"""`companion --live`: the flight's Foxglove channels (interfaces.flight_channels) served while it flies.

A Foxglove WebSocket server (foxglove-sdk, loopback by default) in a private foxglove Context: Foxglove's
"Open connection" to ws://127.0.0.1:PORT shows the same channels, in the same time base (the vehicle's
clock: the plant's simulated time in SITL), as the flight.mcap written afterwards. Off unless asked for:
without --live this module is not imported and nothing is published.

Publishing never waits for a client: the SDK queues each message per client (a bounded backlog, the
oldest dropped first) and sends it from its own threads. The cost the control loop pays per published
sample is timed and reported in the companion's summary (``live_view.publish_us``).
"""

from __future__ import annotations

import math
import time
from typing import Any, Mapping

import numpy as np

from companion.adapters.recorder import RecentSamples
from interfaces.flight_channels import FlightChannels, covariance_from_upper, quaternion_wxyz, range_sigma

#: The scene (ellipsoid, bearing ray, path traces) and the world -> ned transform are refreshed at these
#: periods of flight time, s; poses and values go out with every sample.
SCENE_PERIOD = 0.2
FRAMES_PERIOD = 1.0
#: How many publish-cost samples the summary's percentiles are taken over (the most recent).
COST_SAMPLES = 20_000
_COVARIANCE = ("est_pxx", "est_pxy", "est_pxz", "est_pyy", "est_pyz", "est_pzz")


def _finite(row: Mapping[str, Any], *keys: str) -> list[float] | None:
    values = [row.get(key) for key in keys]
    if any(not isinstance(v, (int, float)) or not math.isfinite(v) for v in values):
        return None
    return [float(v) for v in values]


class LiveView:
    """The live channels of one companion run. `publish` one series row per control sample, `event` one line,
    `close` at the end (the server stops, clients see it go)."""

    def __init__(self, port: int, host: str = "127.0.0.1", desired_range: float | None = None) -> None:
        import foxglove

        self.channels = FlightChannels(desired_range=desired_range)
        self.server = foxglove.start_server(name="bearing-follow companion", host=host, port=port,
                                            context=self.channels.context)
        self.host, self.port = host, self.server.port
        self.costs_us = RecentSamples(COST_SAMPLES)
        self.published = 0
        self._next_scene = -math.inf
        self._next_frames = -math.inf

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, row: Mapping[str, Any], rotation: np.ndarray, target: np.ndarray | None,
                link: Mapping[str, Any], health_reasons: tuple[str, ...] = ()) -> None:
        """One companion sample: `row` as the series logs it (companion.follower), the attitude body FRD -> NED
        (3 x 3), the newest accepted target fix (NED m) or None, the link's counts (accepted, rejected by reason)."""
        started = time.perf_counter_ns()
        channels, t = self.channels, float(row["time"])
        if t < 0.0 or not math.isfinite(t):
            return
        if t >= self._next_frames:
            channels.frames(t)
            self._next_frames = t + FRAMES_PERIOD
        pursuer = [float(row["px"]), float(row["py"]), float(row["pz"])]
        channels.pose("pursuer", t, pursuer, quaternion_wxyz(rotation).tolist())
        channels.values("/flight/pursuer", t, {"speed": math.hypot(row["vx"], row["vy"], row["vz"]),
                                               "tilt_deg": math.degrees(math.acos(max(-1.0, min(1.0, rotation[2, 2]))))})
        if target is not None:
            channels.pose("target", t, target)
        estimate = _finite(row, "est_x", "est_y", "est_z")
        upper = _finite(row, *_COVARIANCE)
        covariance = None if upper is None else covariance_from_upper(upper)
        if estimate is not None:
            channels.pose("estimate", t, estimate)
            values = {"range_estimate": row.get("range_estimate", math.nan)}
            if covariance is not None:
                values["sigma_r"] = range_sigma(covariance, np.array(pursuer), np.array(estimate))
            if channels.desired_range is not None:
                values["desired_range"] = channels.desired_range
            channels.values("/flight/range", t, values)
        acceleration = _finite(row, "acc_x", "acc_y", "acc_z")
        if acceleration is not None:
            channels.values("/setpoint", t, {"acc_n": acceleration[0], "acc_e": acceleration[1], "acc_d": acceleration[2],
                                             "thrust_normalized": row.get("thrust_normalized", math.nan)})
        models = _finite(row, "model_straight", "model_right", "model_left")
        if models is not None:
            channels.values("/estimator/models", t, dict(zip(("straight", "right", "left"), models)))
        if "health" in row:
            health = {"suspect": int(row.get("health_suspect", 0)), "state": row["health"], "reasons": list(health_reasons),
                      "nis_ratio": row.get("health_nis_ratio", math.nan)}
            if "health_action" in row:
                health.update(action=row["health_action"], process_noise_boost=row.get("process_noise_boost", math.nan))
            channels.values("/health", t, health)
        channels.values("/track_mode", t, {"mode": row["track_mode"]})
        rejected = dict(link.get("rejected", {}))
        channels.values("/link", t, {"accepted": int(link.get("accepted", 0)), "rejected": sum(rejected.values()),
                                     "rejected_by_reason": rejected})
        if t >= self._next_scene:
            bearing = _finite(row, "bearing_x", "bearing_y", "bearing_z")
            channels.scene(t, pursuer, None if target is None else [float(v) for v in target], estimate, covariance,
                           bearing)
            self._next_scene = t + SCENE_PERIOD
        self.published += 1
        self.costs_us.append((time.perf_counter_ns() - started) * 1e-3)

    def event(self, time_s: float | None, text: str, level: str = "info") -> None:
        """A line on /events (an event before the vehicle's first time stamp is not shown: it has no time)."""
        if time_s is not None and math.isfinite(time_s) and time_s >= 0.0:
            self.channels.event(time_s, text, level)

    def summary(self) -> dict:
        """Where it served and what publishing cost the control loop: p50 / p99 / max, us per sample."""
        return {"url": self.url, "samples_published": self.published, "publish_us": self.costs_us.percentiles()}

    def close(self) -> None:
        self.server.stop()
