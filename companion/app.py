"""The companion application: target fixes over Zenoh in, attitude/thrust setpoints over MAVLink out.

    companion --config config/scenarios/constant_velocity.toml [--mavlink udpin://0.0.0.0:14540]
              [--zenoh-connect tcp/127.0.0.1:7447] [--log-dir runs/companion]

As in the paper's flight experiment (section IX-A, Fig. 16), the target's position
arrives over a radio link (Zenoh here, Zigbee there), the bearing is rebuilt on board
from it and the vehicle's own position at the fix time, corrupted as the configured
sensor would corrupt it, and only that bearing reaches the u-PLKF. The shared
FollowingPipeline runs on the vehicle's clock (odometry time stamps): estimator 50 Hz,
control 20 Hz, bearings as they arrive.

Mission phases: waiting (vehicle and link) -> arming -> taking_off (to the engage
altitude) -> ready -> following (offboard) -> landing -> done. An "abort" command on
the companion's command key makes it hold, then land. The companion publishes its state
(phase, own state, estimate, covariance summary, link health) on its state key, as
network B of Fig. 16 did, so a ground station can watch.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import enum
import math
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from interfaces import link_schema as link
from interfaces import zenoh_transport
from companion.assembly import build_sensor, build_pipeline
from companion.core.bearing_builder import BearingBuilder
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, VehicleConfig, load_scenario
from companion.core.fix_validator import FixRejected, FixValidator
from companion.fix_intake import FixIntake
from companion.core.messages import BearingMeasurement
from companion.core.pipeline import FollowingPipeline, PipelineOutput
from companion.adapters.recorder import RunRecorder, TlogWriter
from companion.core.state_history import StateHistory
from companion.adapters.mavsdk_vehicle import MavsdkVehicle, VehicleError, VehicleSample

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: Own-state samples kept for rebuilding bearings at past fix times, s.
HISTORY_SECONDS = 5.0
#: A fix whose stamp is further than this ahead of the newest own state waits for it, s.
MAX_EXTRAPOLATION = 0.1
#: The autopilot must show a mode other than offboard this long (vehicle s) before the companion
#: concludes it took over (heartbeats come at 1 Hz).
LEFT_OFFBOARD_GRACE = 2.0
#: A fix still unusable this long after its stamp (no own state at that time) is dropped, s.
FIX_MAX_WAIT = 1.0


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


@dataclass
class PendingFix:
    seq: int
    stamp: float
    position: np.ndarray
    received_ns: int


class LinkHealth:
    """What the target link has done so far; the validation counts are the FixValidator's own."""

    def __init__(self, validator: FixValidator) -> None:
        self.validator = validator
        self.received = 0
        self.bearings_used = 0
        self.bearings_dropped: collections.Counter[str] = collections.Counter()
        self.last_received_wall: float | None = None

    @property
    def accepted(self) -> int:
        return self.validator.accepted

    @property
    def rejected(self) -> collections.Counter[str]:
        return self.validator.rejected

    def as_dict(self, now_wall: float) -> dict:
        return {
            "received": self.received,
            "accepted": self.accepted,
            "rejected": dict(self.rejected),
            "bearings_used": self.bearings_used,
            "bearings_dropped": dict(self.bearings_dropped),
            "last_seq": self.validator.last_seq,
            "last_stamp": self.validator.last_stamp,
            "last_fix_age_wall": None if self.last_received_wall is None else round(now_wall - self.last_received_wall, 3),
        }


class CompanionApp:
    """One companion run. `await app.run()` returns the process exit code."""

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
        self.home = tuple(scenario.sitl.home)
        self.recorder = RunRecorder(log_dir)
        self.phase = Phase.WAITING
        self.rng = np.random.default_rng(scenario.simulation.seed if seed is None else seed)
        self.validator = FixValidator(self.link_settings.target_sender)
        self.intake = FixIntake(self.validator, self.home)
        self.health = LinkHealth(self.validator)
        self.history = StateHistory(HISTORY_SECONDS)
        self.builder = BearingBuilder(build_sensor(scenario.sensor), self.rng, self.history)
        self.pipeline: FollowingPipeline | None = None
        self.vehicle: MavsdkVehicle | None = None
        self.pending: collections.deque[PendingFix] = collections.deque()
        self.abort_requested = False
        self.stop_requested = False
        self.engaged_at: float | None = None
        self.setpoints_sent = 0
        self.vehicle_link_losses = 0
        self.resumes = 0
        self._left_offboard_since: float | None = None
        self.deadline_misses = 0
        self.latencies_ms: list[float] = []  # fix received -> first setpoint sent after its bearing
        self.bearing_latencies_ms: list[float] = []  # fix received -> its bearing given to the estimator
        self._awaiting_setpoint: list[PendingFix] = []
        self._state_seq = 0
        self._next_state_time = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._session = None
        self._state_publisher = None
        self._last_output: PipelineOutput | None = None
        self.error: str | None = None

    # ------------------------------------------------------------------ phases
    def _set_phase(self, phase: Phase, detail: str = "") -> None:
        if phase != self.phase:
            self.phase = phase
            sample = self.vehicle.latest if self.vehicle is not None else None
            self.recorder.event(sample.state.time if sample else None, "phase", f"{phase.value} {detail}".strip(),
                                phase=phase.value)
            print(f"companion: {phase.value} {detail}".rstrip(), flush=True)

    async def run(self) -> int:
        self._loop = asyncio.get_running_loop()
        tlog = TlogWriter(self.recorder.folder / "mavlink.tlog").start()
        code = 1
        try:
            self._open_zenoh()
            self.vehicle = MavsdkVehicle(self.mavlink_url, connect_timeout=self.settings.connect_timeout,
                                         forward_url=f"udpout://127.0.0.1:{tlog.port}")
            await self.vehicle.connect()
            limits = await self.vehicle.vehicle_limits(self.vehicle_config.mass, self.vehicle_config.gravity)
            self.recorder.event(None, "vehicle", f"connected; hover thrust {limits.hover_thrust_normalized:.4f}, "
                                                 f"tilt limit {math.degrees(limits.max_tilt):.1f} deg (from autopilot parameters)")
            self.pipeline = build_pipeline(self.scenario, self.vehicle_config, limits.hover_thrust_normalized)
            self.pipeline.limits = limits
            state_task = asyncio.create_task(self._state_loop())
            try:
                await self._mission()
            finally:
                state_task.cancel()
            code = 0 if self.phase == Phase.DONE else 1
        except VehicleError as error:
            self.error = str(error)
            self._set_phase(Phase.FAILED, str(error))
        except Exception as error:  # log before dying; the summary says what happened
            self.error = f"{type(error).__name__}: {error}"
            self._set_phase(Phase.FAILED, self.error)
            raise
        finally:
            await self._shutdown(tlog)
        return code

    async def _mission(self) -> None:
        vehicle = self.vehicle
        await vehicle.next_sample(10.0)
        await self._wait_for_link()
        if self.stop_requested:
            return
        self._set_phase(Phase.ARMING)
        await vehicle.wait_for(lambda s: True, 10.0, "own state")
        await self._retry("arm", vehicle.arm, attempts=10, pause=0.5)
        self._set_phase(Phase.TAKING_OFF, f"to {self.settings.engage_altitude:g} m")
        hovering = await vehicle.takeoff(self.settings.engage_altitude, timeout=120.0)
        await vehicle.wait_for(lambda s: s.state.time > hovering.state.time + self.settings.settle_time, 60.0, "settling")
        self._set_phase(Phase.READY)
        await self._follow()
        if self.abort_requested:
            self._set_phase(Phase.ABORTING, "abort command: holding")
            await vehicle.stop_offboard()
            start = vehicle.latest.state.time
            await vehicle.wait_for(lambda s: s.state.time > start + self.settings.hold_after_abort, 60.0, "abort hold")
        elif self.phase in (Phase.FOLLOWING, Phase.VEHICLE_LOST):
            try:
                await vehicle.stop_offboard()
            except VehicleError as error:
                self.recorder.event(vehicle.latest.state.time, "vehicle_link", f"offboard stop: {error}")
        if self.stop_requested and not self.abort_requested:
            return
        self._set_phase(Phase.LANDING)
        await vehicle.land()
        await self._wait_until(lambda: vehicle.armed is False, 120.0, "disarm after landing")
        self._set_phase(Phase.DONE)

    async def _retry(self, what: str, action, attempts: int, pause: float) -> None:
        for attempt in range(attempts):
            try:
                return await action()
            except VehicleError as error:
                if attempt == attempts - 1:
                    raise
                self.recorder.event(None, "retry", f"{what}: {error}")
                await asyncio.sleep(pause)

    async def _wait_until(self, predicate, timeout: float, what: str) -> None:
        deadline = self._loop.time() + timeout
        while not predicate():
            if self._loop.time() > deadline:
                raise VehicleError(f"timed out after {timeout:g} s waiting for {what}")
            await asyncio.sleep(0.05)

    async def _wait_for_link(self) -> None:
        deadline = self._loop.time() + self.settings.link_timeout
        while self.health.accepted == 0 and not self.stop_requested:
            if self._loop.time() > deadline:
                raise VehicleError(f"no valid target fix on {link.target_fix_key(self.link_settings.target_sender)} "
                                   f"within {self.settings.link_timeout:g} s")
            await self.vehicle.next_sample(10.0)

    # --------------------------------------------------------------- following
    async def _follow(self) -> None:
        vehicle, pipeline = self.vehicle, self.pipeline
        duration = self.settings.follow_duration or self.scenario.simulation.duration
        while not (self.abort_requested or self.stop_requested):
            try:
                sample = await vehicle.next_sample(self.settings.vehicle_link_timeout)
            except VehicleError:
                if self.engaged_at is None or not await self._vehicle_link_lost():
                    return
                continue
            self._record_state(sample)
            bearings = self._due_bearings(sample.state.time)
            output = None
            for bearing in bearings or [None]:
                output = pipeline.step(sample.state.time, sample.state, bearing)
            if output.setpoint is not None and self.engaged_at is None:
                await vehicle.start_offboard(output.setpoint)
                self.engaged_at = sample.state.time
                self._set_phase(Phase.FOLLOWING, f"engaged at t={sample.state.time:.2f} s")
                self._sent(sample, output)
            elif output.new_setpoint and output.setpoint is not None:
                await vehicle.send_setpoint(output.setpoint)
                self._sent(sample, output)
            if self._last_output is not None and output.mode != self._last_output.mode:
                await self._track_mode_changed(output)
            self._last_output = output
            self._log_row(sample, output, bearings)
            if self.engaged_at is not None and sample.state.time >= self.engaged_at + duration:
                break
            if self.engaged_at is not None and vehicle.flight_mode is not None and vehicle.flight_mode.name != "OFFBOARD":
                # The autopilot left offboard (its failsafe, or a pilot): it is in charge now.
                if self._left_offboard_since is None:
                    self._left_offboard_since = sample.state.time
                elif sample.state.time - self._left_offboard_since > LEFT_OFFBOARD_GRACE:
                    if not await self._after_autopilot_took_over(sample, f"autopilot left offboard (mode {vehicle.flight_mode.name})"):
                        return
            else:
                self._left_offboard_since = None

    async def _vehicle_link_lost(self) -> bool:
        """No odometry for vehicle_link_timeout: stop commanding (MAVSDK's re-sending included) and let
        the autopilot's offboard-loss failsafe act. When telemetry returns, re-engage if
        [companion] on_vehicle_link_return = "resume"; otherwise land. Returns True to go on following."""
        vehicle = self.vehicle
        lost_at = vehicle.latest.state.time
        self.vehicle_link_losses += 1
        self._set_phase(Phase.VEHICLE_LOST, f"no telemetry for {self.settings.vehicle_link_timeout:g} s")
        try:
            await vehicle.stop_offboard()  # stops the setpoint stream first; the mode command may not get through
        except VehicleError as error:
            self.recorder.event(lost_at, "vehicle_link", f"offboard stop not acknowledged: {error}")
        try:
            sample = await vehicle.next_sample(self.settings.vehicle_link_wait)
        except VehicleError:
            raise VehicleError(f"vehicle link lost at t={lost_at:.2f} s and not back within "
                               f"{self.settings.vehicle_link_wait:g} s") from None
        self.recorder.event(sample.state.time, "vehicle_link", f"telemetry back after {sample.state.time - lost_at:.2f} s "
                                                                f"(autopilot mode {vehicle.flight_mode.name if vehicle.flight_mode else '?'})")
        return await self._after_autopilot_took_over(sample, "vehicle link back")

    async def _after_autopilot_took_over(self, sample: VehicleSample, reason: str) -> bool:
        """Re-engage offboard if [companion] on_vehicle_link_return allows it, else leave it to landing."""
        self.recorder.event(sample.state.time, "vehicle_link", reason)
        self._left_offboard_since = None
        if self.settings.on_vehicle_link_return != "resume":
            self.recorder.event(sample.state.time, "vehicle_link", "not resuming (on_vehicle_link_return = land)")
            return False
        self._record_state(sample)
        output = self.pipeline.step(sample.state.time, sample.state, None)
        await self.vehicle.start_offboard(output.setpoint)
        self.resumes += 1
        self._set_phase(Phase.FOLLOWING, f"resumed at t={sample.state.time:.2f} s")
        return True

    async def _track_mode_changed(self, output: PipelineOutput) -> None:
        """Say so in the log, on Zenoh (next state) and to the autopilot/ground station (STATUSTEXT)."""
        texts = {
            "coasting": ("INFO", "target link silent: coasting on prediction"),
            "degraded": ("WARNING", "target link lost: holding safe distance"),
            "reacquiring": ("INFO", "target fixes back: re-acquiring"),
            "tracking": ("INFO", "target tracked"),
        }
        severity, text = texts[output.mode.value]
        self.recorder.event(output.time, "track_mode", f"{output.mode.value} (bearing age {output.bearing_age:.2f} s)",
                            mode=output.mode.value, bearing_age=output.bearing_age)
        try:
            await self.vehicle.status_text(text, severity)
        except VehicleError as error:
            self.recorder.event(output.time, "status_text_failed", str(error))

    def _sent(self, sample: VehicleSample, output: PipelineOutput) -> None:
        now_ns = time.monotonic_ns()
        self.setpoints_sent += 1
        for fix in self._awaiting_setpoint:
            self.recorder.latency(fix.seq, fix.stamp, fix.received_ns, now_ns)
            self.latencies_ms.append((now_ns - fix.received_ns) * 1e-6)
        self._awaiting_setpoint = []
        # Deadline: the setpoint of a control tick must be out before the next tick is due.
        newest = self.vehicle.latest.state.time
        if newest - output.time > self.pipeline.control_period:
            self.deadline_misses += 1

    def _record_state(self, sample: VehicleSample) -> None:
        state = sample.state
        self.history.append(state.time, state.position, state.velocity, sample.rotation)

    def _due_bearings(self, now: float) -> list[BearingMeasurement]:
        """Bearings from the fixes whose stamp the own-state history now covers, oldest first."""
        bearings = []
        while self.pending and self.pending[0].stamp <= now + MAX_EXTRAPOLATION:
            fix = self.pending.popleft()
            result = self.builder.build(fix.position, fix.stamp)
            if result.bearing is None:
                if result.reason == "no_own_state" and now - fix.stamp < FIX_MAX_WAIT and fix.stamp > now:
                    self.pending.appendleft(fix)
                    break
                self.health.bearings_dropped[result.reason] += 1
                continue
            bearings.append(result.bearing)
            self.recorder.bearing(result.bearing, fix.seq)
            self.health.bearings_used += 1
            self._awaiting_setpoint.append(fix)
            self.bearing_latencies_ms.append((time.monotonic_ns() - fix.received_ns) * 1e-6)
        return bearings

    # ------------------------------------------------------------------ zenoh
    def _open_zenoh(self) -> None:
        settings = self.link_settings
        config = zenoh_transport.zenoh_config(settings.mode, listen=self.zenoh_listen, connect=self.zenoh_connect,
                                   overrides=settings.zenoh_overrides)
        self._session = zenoh_transport.open_session(config)
        self._session.declare_subscriber(link.target_fix_key(settings.target_sender), self._on_fix_sample)
        self._session.declare_subscriber(link.companion_command_key(settings.companion_id), self._on_command_sample)
        self._state_publisher = zenoh_transport.publisher(self._session, link.companion_state_key(settings.companion_id))

    def _on_fix_sample(self, sample) -> None:
        """Zenoh thread: hand the payload to the event loop with its receipt time."""
        payload = sample.payload.to_bytes()
        received = time.monotonic_ns()
        self._loop.call_soon_threadsafe(self._on_fix, payload, received)

    def _on_command_sample(self, sample) -> None:
        payload = sample.payload.to_bytes()
        self._loop.call_soon_threadsafe(self._on_command, payload)

    def _on_fix(self, payload: bytes, received_ns: int) -> None:
        self.health.received += 1
        sim_time = self.vehicle.latest.state.time if self.vehicle is not None and self.vehicle.latest else None
        record = {"received_ns": received_ns, "sim_time": sim_time, "bytes": len(payload)}
        try:
            fix, position = self.intake.check(payload)
        except FixRejected as error:
            record.update(verdict="rejected", reason=error.reason, detail=str(error))
            self.recorder.zenoh(record)
            return
        self.health.last_received_wall = time.monotonic()
        record.update(verdict="accepted", seq=fix.seq, stamp=fix.stamp, frame=fix.frame, position=list(fix.position))
        self.recorder.zenoh(record)
        if self.phase in (Phase.READY, Phase.FOLLOWING):
            self.pending.append(PendingFix(fix.seq, fix.stamp, position, received_ns))

    def _on_command(self, payload: bytes) -> None:
        try:
            command = link.decode_command(payload)
        except link.PayloadError as error:
            self.recorder.event(None, "command_rejected", f"{error.reason}: {error}")
            return
        self.recorder.event(None, "command", f"{command.command} from {command.sender}", command=command.command,
                            sender=command.sender)
        if command.command == "abort":
            self.abort_requested = True

    async def _state_loop(self) -> None:
        """Publish the state at state_rate_hz of vehicle time in every phase."""
        while True:
            await asyncio.sleep(0.02)
            if self.vehicle is not None and self.vehicle.latest is not None:
                self._publish_state(self.vehicle.latest)

    def _publish_state(self, sample: VehicleSample) -> None:
        now = sample.state.time
        if self._state_publisher is None or now < self._next_state_time:
            return
        self._next_state_time = now + 1.0 / self.link_settings.state_rate_hz
        state = {
            "phase": self.phase.value,
            "pursuer": {"position": sample.state.position, "velocity": sample.state.velocity},
            "link": self.health.as_dict(time.monotonic()),
            "setpoints_sent": self.setpoints_sent,
        }
        if self._last_output is not None:
            state["track"] = {"mode": self._last_output.mode.value, "bearing_age": self._last_output.bearing_age}
            if self._last_output.observability is not None:
                state["observability"] = dict(self._last_output.observability)
        estimate = self._last_output.estimate if self._last_output is not None else None
        if estimate is not None:
            covariance = estimate.covariance
            state["estimate"] = {
                "time": estimate.time,
                "position": estimate.position,
                "velocity": estimate.velocity,
                "position_std": float(math.sqrt(max(np.trace(covariance[:3, :3]), 0.0) / 3.0)),
                "velocity_std": float(math.sqrt(max(np.trace(covariance[3:, 3:]), 0.0) / 3.0)),
                "range": float(np.linalg.norm(estimate.position - sample.state.position)),
            }
        state.update(sender=self.link_settings.companion_id, seq=self._state_seq, stamp=now)
        self._state_seq += 1
        self._state_publisher.put(link.encode_state(state))

    # ----------------------------------------------------------------- logging
    def _log_row(self, sample: VehicleSample, output: PipelineOutput, bearings: list[BearingMeasurement]) -> None:
        s = sample.state
        row = {"time": s.time, "phase": self.phase.value, "track_mode": output.mode.value, "bearing_age": output.bearing_age,
               "px": s.position[0], "py": s.position[1], "pz": s.position[2],
               "vx": s.velocity[0], "vy": s.velocity[1], "vz": s.velocity[2],
               "new_setpoint": int(output.new_setpoint)}
        if output.estimate is not None:
            e = output.estimate.extrapolated(s.time)
            row.update(est_x=e.position[0], est_y=e.position[1], est_z=e.position[2],
                       est_vx=e.velocity[0], est_vy=e.velocity[1], est_vz=e.velocity[2],
                       est_position_std=float(math.sqrt(max(np.trace(e.covariance[:3, :3]), 0.0) / 3.0)),
                       range_estimate=float(np.linalg.norm(e.position - s.position)))
        if bearings:
            b = bearings[-1]
            row.update(bearing_x=float(b.direction[0]), bearing_y=float(b.direction[1]), bearing_z=float(b.direction[2]),
                       bearing_time=b.time)
        if output.observability is not None:
            row.update(observability_log_det=float(output.observability["log_det"]),
                       observability_min_eigenvalue=float(output.observability["min_eigenvalue"]))
        if output.setpoint is not None:
            a = output.setpoint.acceleration
            row.update(acc_x=float(a[0]), acc_y=float(a[1]), acc_z=float(a[2]), thrust_normalized=output.setpoint.thrust_normalized)
        self.recorder.series(row)

    def summary(self) -> dict:
        latencies = np.array(self.latencies_ms) if self.latencies_ms else np.array([math.nan])
        to_estimator = np.array(self.bearing_latencies_ms) if self.bearing_latencies_ms else np.array([math.nan])
        return {
            "latency_fix_to_estimator_ms": {
                "p50": float(np.percentile(to_estimator, 50)), "p99": float(np.percentile(to_estimator, 99)),
                "max": float(np.max(to_estimator)), "count": len(self.bearing_latencies_ms)},
            "phase": self.phase.value,
            "error": self.error,
            "engaged_at": self.engaged_at,
            "setpoints_sent": self.setpoints_sent,
            "vehicle_link_losses": self.vehicle_link_losses,
            "resumes": self.resumes,
            "deadline_misses": self.deadline_misses,
            "latency_fix_to_setpoint_ms": {
                "p50": float(np.percentile(latencies, 50)), "p99": float(np.percentile(latencies, 99)),
                "max": float(np.max(latencies)), "count": len(self.latencies_ms)},
            "link": self.health.as_dict(time.monotonic()),
            "vehicle_status_texts": self.vehicle.status_texts if self.vehicle is not None else [],
            "bad_odometry": self.vehicle.bad_odometry if self.vehicle is not None else 0,
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

        def request_stop() -> None:
            app.stop_requested = True
            app.abort_requested = app.phase == Phase.FOLLOWING  # hold, then land

        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, request_stop)
        print(f"companion ready: {scenario.name}, vehicle {app.mavlink_url}, log {log_dir}", flush=True)
        return await app.run()

    return asyncio.run(run())


if __name__ == "__main__":
    sys.exit(main())
