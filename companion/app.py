"""The companion application: target fixes over Zenoh in, attitude/thrust setpoints over MAVLink out.

    companion --config config/scenarios/constant_velocity.toml [--mavlink udpin://0.0.0.0:14540]
              [--zenoh-connect tcp/127.0.0.1:7447] [--log-dir runs/companion]

As in the paper's flight experiment (section IX-A, Fig. 16), the target's position
arrives over a radio link (Zenoh here, Zigbee there), the bearing is rebuilt on board
from it and the vehicle's own position at the fix time, corrupted as the configured
sensor would corrupt it, and only that bearing reaches the u-PLKF. The shared
FollowingPipeline runs on the vehicle's clock (odometry time stamps): estimator 50 Hz,
control 20 Hz, bearings as they arrive.

This module is the assembly and the command line. The parts, one job each:
companion.mission (MissionSequencer: the phases waiting -> arming -> taking_off -> ready ->
following -> landing -> done, abort, vehicle link loss), companion.target_link (TargetLink:
fixes in, bearings out, link health), companion.follower (Follower: the per-sample control
loop while following), companion.state_publisher (StatePublisher: the companion's state on
its Zenoh state key, as network B of Fig. 16 did, so a ground station can watch). An
"abort" command on the companion's command key makes it hold, then land.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys
import time
from pathlib import Path

import numpy as np

from companion.adapters.mavsdk_vehicle import MavsdkVehicle, VehicleError
from companion.adapters.recorder import RunRecorder, TlogWriter
from companion.assembly import build_pipeline, build_sensor
from companion.core.state_history import StateHistory
from companion.fix_intake import build_command_validator, build_fix_validator
from companion.follower import Follower
from companion.mission import MissionSequencer, Phase
from companion.state_publisher import StatePublisher
from companion.target_link import TargetLink
from interfaces import link_schema as link
from interfaces import zenoh_transport
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, VehicleConfig, load_scenario

__all__ = ["CompanionApp", "Phase", "main"]

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: Own-state samples kept for rebuilding bearings at past fix times, s.
HISTORY_SECONDS = 5.0


def _percentiles(values: list[float]) -> dict:
    """p50/p99/max (ms) and count of a latency list; NaN figures when it is empty."""
    data = np.array(values) if values else np.array([math.nan])
    return {"p50": float(np.percentile(data, 50)), "p99": float(np.percentile(data, 99)), "max": float(np.max(data)),
            "count": len(values)}


class CompanionApp:
    """One companion run: builds the parts, connects them, `await app.run()` returns the process exit code."""

    def __init__(self, scenario: Scenario, vehicle_config: VehicleConfig, log_dir: Path, mavlink_url: str | None = None,
                 zenoh_connect: tuple[str, ...] | None = None, zenoh_listen: tuple[str, ...] | None = None,
                 seed: int | None = None) -> None:
        self.scenario = scenario
        self.vehicle_config = vehicle_config
        self.settings = scenario.companion
        self.link_settings = scenario.link
        self.mavlink_url = mavlink_url or self.settings.mavlink_url
        self.zenoh_connect = tuple(zenoh_connect) if zenoh_connect is not None else tuple(self.link_settings.connect)
        self.zenoh_listen = tuple(zenoh_listen) if zenoh_listen is not None else tuple(self.link_settings.listen)
        self.recorder = RunRecorder(log_dir)
        self.vehicle: MavsdkVehicle | None = None
        self.history = StateHistory(HISTORY_SECONDS)
        self.target_link = TargetLink(
            self.link_settings.target_sender, scenario.sitl.home, build_sensor(scenario.sensor),
            np.random.default_rng(scenario.simulation.seed if seed is None else seed), self.history, self.recorder,
            clock=self._vehicle_time, wants_bearings=lambda: self.sequencer.phase in (Phase.READY, Phase.FOLLOWING),
            validator=build_fix_validator(self.link_settings), pipeline=lambda: self.follower.pipeline)
        self.sequencer = MissionSequencer(self.settings, self.settings.follow_duration or scenario.simulation.duration,
                                          link_up=lambda: self.target_link.health.accepted > 0,
                                          link_name=self.target_link.key, log=self.recorder,
                                          commands=build_command_validator(self.link_settings))
        self.follower = Follower(self.target_link, self.history, self.recorder)
        self._session = None
        self.error: str | None = None

    @property
    def phase(self) -> Phase:
        return self.sequencer.phase

    def _vehicle_time(self) -> float | None:
        return self.vehicle.latest.state.time if self.vehicle is not None and self.vehicle.latest else None

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        tlog = TlogWriter(self.recorder.folder / "mavlink.tlog").start()
        code = 1
        try:
            publisher = self._open_zenoh(loop)
            self.vehicle = MavsdkVehicle(self.mavlink_url, connect_timeout=self.settings.connect_timeout,
                                         forward_url=f"udpout://127.0.0.1:{tlog.port}")
            # Every odometry sample goes into the own-state history as it arrives, from before take-off:
            # a fix stamped just before the follow loop's first sample still finds its own state.
            self.vehicle.sample_observers.append(self.follower.record_state)
            await self.vehicle.connect()
            limits = await self.vehicle.vehicle_limits(self.vehicle_config.mass, self.vehicle_config.gravity)
            self.recorder.event(None, "vehicle", f"connected; hover thrust {limits.hover_thrust_normalized:.4f}, "
                                                 f"tilt limit {math.degrees(limits.max_tilt):.1f} deg (from autopilot parameters)")
            pipeline = build_pipeline(self.scenario, self.vehicle_config, limits.hover_thrust_normalized)
            pipeline.limits = limits
            self.follower.attach(self.vehicle, pipeline)
            states = StatePublisher(self.link_settings.companion_id, self.link_settings.state_rate_hz, publisher.put,
                                    phase=lambda: self.sequencer.phase.value, health=self.target_link.health,
                                    control=self.follower)
            state_task = asyncio.create_task(states.run(self.vehicle))
            try:
                await self.sequencer.run(self.vehicle, self.follower)
            finally:
                state_task.cancel()
            code = 0 if self.phase == Phase.DONE else 1
        except VehicleError as error:
            self.error = str(error)
            self.sequencer.fail(str(error))
        except Exception as error:  # log before dying; the summary says what happened
            self.error = f"{type(error).__name__}: {error}"
            self.sequencer.fail(self.error)
            raise
        finally:
            await self._shutdown(tlog)
        return code

    # ------------------------------------------------------------------ zenoh
    def _open_zenoh(self, loop: asyncio.AbstractEventLoop):
        """Open the session, subscribe fixes (target link) and commands; returns the state publisher."""
        settings = self.link_settings
        config = zenoh_transport.zenoh_config(settings.mode, listen=self.zenoh_listen, connect=self.zenoh_connect,
                                              overrides=settings.zenoh_overrides)
        self._session = zenoh_transport.open_session(config)
        self.target_link.subscribe(self._session, loop)
        self._session.declare_subscriber(link.companion_command_key(settings.companion_id),
                                         lambda sample: loop.call_soon_threadsafe(self.on_command, sample.payload.to_bytes()))
        return zenoh_transport.publisher(self._session, link.companion_state_key(settings.companion_id))

    def on_command(self, payload: bytes) -> None:
        """Event loop: a command payload from the ground station; only a valid "abort" acts."""
        try:
            command = link.decode_command(payload)
        except link.PayloadError as error:
            self.recorder.event(None, "command_rejected", f"{error.reason}: {error}", reason=error.reason)
            return
        refusal = self.sequencer.refuse_command(command, self._vehicle_time())
        if refusal is not None:  # replayed, reordered, stale or far-future: counted, never obeyed
            self.recorder.event(self._vehicle_time(), "command_rejected", refusal, reason=refusal.split(":")[0])
            return
        self.recorder.event(None, "command", f"{command.command} from {command.sender}", command=command.command,
                            sender=command.sender)
        if command.command == "abort":
            self.sequencer.request_abort()

    # ---------------------------------------------------------------- the end
    def summary(self) -> dict:
        mission, control = self.sequencer, self.follower
        return {
            "latency_fix_to_estimator_ms": _percentiles(self.target_link.bearing_latencies_ms),
            "phase": mission.phase.value,
            "error": self.error,
            "engaged_at": mission.engaged_at,
            "setpoints_sent": control.setpoints_sent,
            "vehicle_link_losses": mission.vehicle_link_losses,
            "resumes": mission.resumes,
            "deadline_misses": control.deadline_misses,
            "latency_fix_to_setpoint_ms": _percentiles(control.latencies_ms),
            "link": self.target_link.health.as_dict(time.monotonic()),
            "vehicle_status_texts": self.vehicle.status_texts if self.vehicle is not None else [],
            "bad_odometry": self.vehicle.bad_odometry if self.vehicle is not None else 0,
            "health_reasons_at_end": list(control.pipeline.health.episode_reasons) if control.pipeline is not None else [],
        }

    async def _shutdown(self, tlog: TlogWriter) -> None:
        try:
            if self.vehicle is not None:
                await self.vehicle.close()
        finally:
            tlog.stop()
            if self._session is not None:
                self._session.close()
            self.recorder.summary(self.summary())
            self.recorder.close()


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="companion", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_SCENARIO, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--mavlink", default=None, help="MAVSDK connection URL ([companion] mavlink_url)")
    parser.add_argument("--zenoh-connect", action="append", default=None, help="Zenoh endpoint to connect to (repeatable)")
    parser.add_argument("--zenoh-listen", action="append", default=None, help="Zenoh endpoint to listen on (repeatable)")
    parser.add_argument("--log-dir", type=Path, default=None, help="run folder (default runs/companion-<time>)")
    parser.add_argument("--seed", type=int, default=None, help="bearing-noise seed ([simulation] seed)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        scenario, vehicle_config = load_scenario(args.config)
    except ConfigError as error:
        print(f"companion: {error}", file=sys.stderr)
        return 2
    if scenario.estimator.gain_projection == "noise_free":
        print("companion: estimator.gain_projection = 'noise_free' is the simulation-only optimal u-PLKF of "
              "section VIII-B (it needs the true line of sight); it cannot fly. Use 'predicted' or 'measured'.",
              file=sys.stderr)
        return 2
    log_dir = args.log_dir or Path("runs") / f"companion-{time.strftime('%Y%m%d-%H%M%S')}"
    app = CompanionApp(scenario, vehicle_config, log_dir, args.mavlink, args.zenoh_connect, args.zenoh_listen, args.seed)

    async def run() -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, app.sequencer.request_stop)
        print(f"companion ready: {scenario.name}, vehicle {app.mavlink_url}, log {log_dir}", flush=True)
        return await app.run()

    return asyncio.run(run())


if __name__ == "__main__":
    sys.exit(main())
