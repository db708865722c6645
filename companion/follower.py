"""The control loop while following: one odometry sample in, at most one setpoint out.

Per sample: own state into the history the bearings are rebuilt from, the bearings whose fix
time that history now covers, the shared FollowingPipeline on the vehicle's clock, then (when
the mission sequencer allows commanding) the setpoint to the autopilot. It also keeps the
control-side figures of the run (setpoints sent, deadline misses, fix-to-setpoint latency),
announces track-mode and filter-health changes (log, STATUSTEXT) and writes the series row. Whether it may
command at all is the sequencer's decision (companion.mission).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from companion.adapters.mavsdk_vehicle import MavsdkVehicle, VehicleError, VehicleSample
from companion.adapters.recorder import RecentSamples, RunRecorder, model_columns
from companion.core.health import HealthAction, HealthReport, HealthState
from companion.core.messages import BearingMeasurement
from companion.core.pipeline import FollowingPipeline, PipelineOutput
from companion.core.state_history import StateHistory

if TYPE_CHECKING:
    from companion.target_link import PendingFix, TargetLink

#: Track mode -> (STATUSTEXT severity, text) the autopilot forwards to the ground station.
TRACK_MODE_TEXTS = {
    "coasting": ("INFO", "target link silent: coasting on prediction"),
    "degraded": ("WARNING", "target link lost: holding safe distance"),
    "reacquiring": ("INFO", "target fixes back: re-acquiring"),
    "tracking": ("INFO", "target tracked"),
}

#: Filter health (companion.core.health) -> STATUSTEXT severity and the start of its text (reasons follow).
HEALTH_TEXTS = {
    HealthState.SUSPECT: ("WARNING", "range estimate suspect"),
    HealthState.OK: ("INFO", "range estimate consistent again"),
}

#: What the companion does about the verdict (companion.core.health.HealthAction) -> STATUSTEXT severity and text.
HEALTH_ACTION_TEXTS = {
    HealthAction.RECOVERING: ("WARNING", "recovering: Q inflated, range excitation on"),
    HealthAction.NOMINAL: ("INFO", "estimate trusted: recovery actions off"),
    HealthAction.OFF: ("INFO", "health actions off: reporting only"),
}
#: STATUSTEXT when the health actions restarted the estimator on the bearing.
HEALTH_RESTART_TEXT = ("WARNING", "range estimate restarted on bearing")


class Follower:
    """Drives the pipeline with odometry and bearings; `attach` the vehicle and pipeline before `step`.

    target_link: gives the bearings due at a time. history: the own-state history the target
    link's bearing builder reads. recorder: the run folder (events, series, latency).
    """

    def __init__(self, target_link: "TargetLink", history: StateHistory, recorder: RunRecorder) -> None:
        self.target_link = target_link
        self.history = history
        self.recorder = recorder
        self.vehicle: MavsdkVehicle | None = None
        self.pipeline: FollowingPipeline | None = None
        self.setpoints_sent = 0
        self.deadline_misses = 0
        self.latencies_ms = RecentSamples()  # fix received -> first setpoint sent after its bearing, ms
        self.last_output: PipelineOutput | None = None
        self.health_state = HealthState.OK
        self.health_action: HealthAction | None = None
        self._awaiting_setpoint: list["PendingFix"] = []
        self._previous_setpoint_time: float | None = None  # s, vehicle time of the state the last setpoint came from
        #: companion.swarm_link.SwarmLink of a [swarm] scenario (None: one pursuer): its neighbours and their
        #: bearings go to the pipeline with the own ones, and it learns the own bearings it shares next
        self.swarm = None
        #: companion.adapters.live_view.LiveView with --live (None: nothing is published)
        self.live = None

    def attach(self, vehicle: MavsdkVehicle, pipeline: FollowingPipeline) -> None:
        self.vehicle = vehicle
        self.pipeline = pipeline

    def record_state(self, sample: VehicleSample) -> None:
        """Put one odometry sample into the own-state history (a sample already there is ignored)."""
        state = sample.state
        newest = self.history.newest_time
        if newest is None or state.time > newest:
            self.history.append(state.time, state.position, state.velocity, sample.rotation)

    def step(self, sample: VehicleSample) -> tuple[PipelineOutput, list[BearingMeasurement]]:
        """Own state in, due bearings (oldest first) through the pipeline; returns its last output and the bearings."""
        self.record_state(sample)
        due = self.target_link.due_bearings(sample.state.time)
        self._awaiting_setpoint.extend(fix for fix, _ in due)
        bearings = [bearing for _, bearing in due]
        self.pipeline.link_contested(sample.state.time, self.target_link.validator.contested)
        if self.swarm is not None:
            self.swarm.own_bearings(bearings)
            neighbours, shared = self.swarm.step_inputs(sample.state.time)
            self.pipeline.set_neighbours(neighbours)
            bearings = sorted(bearings + shared, key=lambda b: b.time)
        return self.pipeline.step_all(sample.state.time, sample.state, bearings), bearings

    @property
    def stops_before_landing(self) -> bool:
        """In a swarm the mission brakes to a hover with the separation filter (`stop`) before it lands: the
        autopilot's landing knows nothing of the other pursuers, and one that ends its following a moment before
        another would otherwise be flown into."""
        return self.swarm is not None

    async def stop(self, sample: VehicleSample) -> float:
        """One braking setpoint (FollowingPipeline.stop_setpoint, with the neighbours heard now) to the vehicle;
        returns the vehicle's speed, m/s."""
        self.record_state(sample)
        if self.swarm is not None:
            self.pipeline.set_neighbours(self.swarm.neighbours_at(sample.state.time))
        await self.vehicle.send_setpoint(self.pipeline.stop_setpoint(sample.state.time, sample.state))
        return float(np.linalg.norm(sample.state.velocity))

    async def engage(self, output: PipelineOutput) -> None:
        """Start offboard with the first setpoint (PX4 needs the stream before the mode switch)."""
        await self.vehicle.start_offboard(output.setpoint)
        self._sent(output)

    async def send(self, output: PipelineOutput) -> None:
        await self.vehicle.send_setpoint(output.setpoint)
        self._sent(output)

    async def resume(self, sample: VehicleSample) -> None:
        """Re-engage after the autopilot had taken over: a fresh setpoint from the newest state, then offboard."""
        self.record_state(sample)
        self._previous_setpoint_time = None  # the loop did not run late while the autopilot flew
        output = self.pipeline.step(sample.state.time, sample.state, None)
        await self.vehicle.start_offboard(output.setpoint)

    async def report(self, sample: VehicleSample, output: PipelineOutput, bearings: list[BearingMeasurement],
                     phase: str) -> None:
        """Announce a track-mode or health change, remember the output (the state publisher reads it), write the series row."""
        if self.last_output is not None and output.mode != self.last_output.mode:
            await self._track_mode_changed(output)
        if output.health is not None and output.health.state is not self.health_state:
            self.health_state = output.health.state
            await self._health_changed(output.health)
        action = getattr(output, "health_action", None)
        if action is not None and self.health_action is not None and action is not self.health_action:
            await self._health_action_changed(output)
        if action is not None:
            self.health_action = action
        if getattr(output, "health_reinitialized", False):
            await self._announce(output.time, "health_restart", "estimator restarted on the bearing", HEALTH_RESTART_TEXT)
        self.last_output = output
        row = self._log_row(sample, output, bearings, phase)
        if self.live is not None:
            link = self.target_link.health
            self.live.publish(row, sample.rotation, self.target_link.last_position,
                              {"accepted": link.accepted, "rejected": link.rejected},
                              () if output.health is None else tuple(output.health.reasons))

    async def _track_mode_changed(self, output: PipelineOutput) -> None:
        """Say so in the log, on Zenoh (next state) and to the autopilot/ground station (STATUSTEXT)."""
        severity, text = TRACK_MODE_TEXTS[output.mode.value]
        self.recorder.event(output.time, "track_mode", f"{output.mode.value} (bearing age {output.bearing_age:.2f} s)",
                            mode=output.mode.value, bearing_age=round(output.bearing_age, 4))
        try:
            await self.vehicle.status_text(text, severity)
        except VehicleError as error:
            self.recorder.event(output.time, "status_text_failed", str(error))

    async def _health_changed(self, health: HealthReport) -> None:
        """The monitor changed its mind: structured event in the log, STATUSTEXT (<= 50 characters) to the
        autopilot/ground station; the next Zenoh state carries it too. Nothing in the flight changes."""
        severity, text = HEALTH_TEXTS[health.state]
        reasons = ",".join(health.reasons)
        self.recorder.event(health.time, "filter_health", f"{health.state.value}{f' ({reasons})' if reasons else ''}",
                            state=health.state.value, reasons=list(health.reasons),
                            nis_ratio=None if health.nis_ratio != health.nis_ratio else round(health.nis_ratio, 4),
                            relative_range_std=round(health.relative_range_std, 4))
        try:
            await self.vehicle.status_text(f"{text}: {reasons}" if reasons else text, severity)
        except VehicleError as error:
            self.recorder.event(health.time, "status_text_failed", str(error))

    async def _health_action_changed(self, output: PipelineOutput) -> None:
        """The pipeline started or stopped acting on the verdict (Q boost, excitation, restarts): event and STATUSTEXT."""
        action = output.health_action
        await self._announce(output.time, "health_action", f"{action.value} (Q x{output.process_noise_boost:.3g})",
                             HEALTH_ACTION_TEXTS[action], action=action.value,
                             process_noise_boost=round(output.process_noise_boost, 4))

    async def _announce(self, time_s: float, kind: str, detail: str, text: tuple[str, str], **fields) -> None:
        """A structured event in the log and a STATUSTEXT (severity, text) to the autopilot/ground station."""
        self.recorder.event(time_s, kind, detail, **fields)
        severity, message = text
        try:
            await self.vehicle.status_text(message, severity)
        except VehicleError as error:
            self.recorder.event(time_s, "status_text_failed", str(error))

    def _sent(self, output: PipelineOutput) -> None:
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
        # How late the loop ran: the vehicle flew the previous setpoint from the state it was computed from until
        # this one went out (at the newest state), one control period when on time; the safety envelope plans
        # with the excess (companion.core.safety, rule 1).
        if self._previous_setpoint_time is not None:
            self.pipeline.note_loop_delay(newest, newest - self._previous_setpoint_time - self.pipeline.control_period)
        self._previous_setpoint_time = output.time

    def _log_row(self, sample: VehicleSample, output: PipelineOutput, bearings: list[BearingMeasurement], phase: str) -> dict:
        """Write the series row of this sample (companion.adapters.recorder.SERIES_COLUMNS) and return it."""
        s = sample.state
        row = {"time": s.time, "phase": phase, "track_mode": output.mode.value, "bearing_age": output.bearing_age,
               "px": s.position[0], "py": s.position[1], "pz": s.position[2],
               "vx": s.velocity[0], "vy": s.velocity[1], "vz": s.velocity[2],
               "new_setpoint": int(output.new_setpoint)}
        if output.estimate is not None:
            e = output.estimate.extrapolated(s.time)
            row.update(est_x=e.position[0], est_y=e.position[1], est_z=e.position[2],
                       est_vx=e.velocity[0], est_vy=e.velocity[1], est_vz=e.velocity[2],
                       est_position_std=e.position_std,
                       range_estimate=float(np.linalg.norm(e.position - s.position)))
            c = e.covariance
            row.update(est_pxx=float(c[0, 0]), est_pxy=float(c[0, 1]), est_pxz=float(c[0, 2]),
                       est_pyy=float(c[1, 1]), est_pyz=float(c[1, 2]), est_pzz=float(c[2, 2]))
        own = [b for b in bearings if b.source == 0]  # a neighbour's shared bearing is not this sensor's
        if own:
            b = own[-1]
            row.update(bearing_x=float(b.direction[0]), bearing_y=float(b.direction[1]), bearing_z=float(b.direction[2]),
                       bearing_time=b.time)
        if output.observability is not None:
            row.update(observability_log_det=float(output.observability["log_det"]),
                       observability_min_eigenvalue=float(output.observability["min_eigenvalue"]))
        if output.health is not None:
            row.update(health=output.health.state.value,
                       health_suspect=int(output.health.state is HealthState.SUSPECT),
                       health_nis_ratio=output.health.nis_ratio)
        action = getattr(output, "health_action", None)
        if action is not None:
            row.update(health_action=action.value, process_noise_boost=output.process_noise_boost)
        if output.estimate is not None:
            row.update(model_columns(self.pipeline.estimator))
        if output.setpoint is not None:
            a = output.setpoint.acceleration
            row.update(acc_x=float(a[0]), acc_y=float(a[1]), acc_z=float(a[2]), thrust_normalized=output.setpoint.thrust_normalized)
        self.recorder.series(row)
        return row
