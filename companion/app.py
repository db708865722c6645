"""The companion application: target fixes over Zenoh in, attitude/thrust setpoints over MAVLink out.

    companion --config config/scenarios/constant_velocity.toml [--mavlink udpin://127.0.0.1:14540]
              [--zenoh-connect tcp/127.0.0.1:7447] [--zenoh-tls DIR | --insecure] [--log-dir runs/companion]
    companion --precompile      # once after installing with numba: fill the kernel cache, open nothing

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
"abort" command on the companion's command key makes it hold, then land. In a [swarm] scenario,
`--pursuer-id K` flies pursuer K and companion.swarm_link shares its state and bearings with the others.

SIGINT, SIGTERM and SIGHUP stop it in any phase (waiting for the autopilot, arming, taking off,
following, landing): the mission is cancelled, an armed vehicle is handed to the autopilot (offboard
stopped or hold: it holds position), the logs and summary.json are written ("stopped_by"), and the
process exits with 128 + the signal, within about 2 s of wall time whatever MAVSDK is doing.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from companion.core._jit import ENABLED as kernels_compiled
from companion.adapters.mavsdk_log import mavsdk_log_to
from companion.adapters.mavsdk_vehicle import MavsdkVehicle, VehicleError
from companion.adapters.recorder import RunRecorder, TlogWriter
from companion.assembly import build_pipeline, build_sensor, pursuer_scenario
from companion.console import configure_console, say
from companion.core.state_history import StateHistory
from companion.fix_intake import build_command_validator, build_fix_validator
from companion.follower import Follower
from companion.mission import MissionSequencer, Phase
from companion.state_publisher import StatePublisher
from companion.swarm_link import SwarmLink, swarm_companion_id
from companion.target_link import TargetLink
from companion.warmup import warm_up as warm_up_kernels
from interfaces.run_folders import new_run_folder
from interfaces import link_schema as link
from interfaces import zenoh_transport
from interfaces.shutdown import BACKSTOP_MARGIN_S, arm_kill_backstop
from interfaces.cli import (LIVE_PORT, CommandParser, add_zenoh_security_arguments, live_port, output_folder,
                           scenario_file, seed_argument)
from interfaces.scenario import (DEFAULT_SCENARIO, MAX_PURSUERS, ConfigError, LinkConfig, Scenario, VehicleConfig,
                                 load_scenario, pursuer_starts)

__all__ = ["CompanionApp", "Phase", "main"]

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: Own-state samples kept for rebuilding bearings at past fix times, s of vehicle time. A fix can arrive
#: late by however long the target's process was starved of CPU, times the speed factor: with 5 s (the old
#: value) a target stalled for 1 s of wall time at 5x made its catch-up fixes older than the history and
#: their bearings were dropped as no_own_state (tests/test_full_sitl.py stalls it with SIGSTOP). 30 s
#: (1500 samples at 50 Hz) covers a 6 s stall at 5x.
HISTORY_SECONDS = 30.0
#: Signals that stop the companion in any phase (CompanionApp.request_stop).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Wall s allowed for handing the vehicle to the autopilot after a stop signal.
HAND_OVER_TIMEOUT = 0.8
#: Wall s allowed for MAVSDK to close.
CLOSE_TIMEOUT = 0.5
#: Wall s after a stop signal at which the process exits whatever a library is still doing (its logs and
#: summary are written well before: see CompanionApp._shutdown).
HARD_EXIT_AFTER = 2.0


#: Bearing-noise streams of pursuer K > 1: SeedSequence(seed, spawn_key=(SWARM_NOISE_SPAWN_KEY, K)); pursuer 1
#: keeps default_rng(seed), so a one-pursuer run draws what it always drew.
SWARM_NOISE_SPAWN_KEY = 0x5357


def bearing_noise_rng(seed: int, pursuer_id: int) -> np.random.Generator:
    """The bearing sensor's noise stream of pursuer `pursuer_id` for `seed`."""
    if pursuer_id == 1:
        return np.random.default_rng(seed)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(SWARM_NOISE_SPAWN_KEY, pursuer_id)))


def check_pursuer_id(scenario: Scenario, pursuer_id: int) -> None:
    """ConfigError (one line) unless `pursuer_id` is one of the scenario's pursuers: 1 without [swarm], 1..N with."""
    if isinstance(pursuer_id, bool) or not isinstance(pursuer_id, int) or not 1 <= pursuer_id <= MAX_PURSUERS:
        raise ConfigError(f"--pursuer-id {pursuer_id!r}: want an integer in 1..{MAX_PURSUERS}")
    count = 1 if scenario.swarm is None else scenario.swarm.count
    if pursuer_id > count:
        raise ConfigError(f"--pursuer-id {pursuer_id}: scenario {scenario.name!r} has "
                          + ("no [swarm] (one pursuer, id 1)" if scenario.swarm is None else f"pursuers 1..{count}"))
    if scenario.swarm is not None and len(swarm_companion_id(scenario.link.companion_id, pursuer_id)) > 64:
        raise ConfigError(f"[link] companion_id {scenario.link.companion_id!r} is too long to carry the pursuer id "
                          f"(ids are at most 64 characters)")


class CompanionApp:
    """One companion run: builds the parts, connects them, `await app.run()` returns the process exit code."""

    def __init__(self, scenario: Scenario, vehicle_config: VehicleConfig, log_dir: Path, mavlink_url: str | None = None,
                 *, zenoh_connect: tuple[str, ...] | None = None, zenoh_listen: tuple[str, ...] | None = None,
                 seed: int | None = None, zenoh_tls: "zenoh_transport.Identity | None" = None,
                 zenoh_namespace: str | None = None, pursuer_id: int = 1, zenoh_insecure: bool = False) -> None:
        check_pursuer_id(scenario, pursuer_id)
        self.pursuer_id = pursuer_id
        full_scenario = scenario
        if scenario.swarm is not None:
            # Pursuer K flies its own start and range guess ([swarm.pursuers]); its keys carry its id.
            scenario = pursuer_scenario(scenario, pursuer_starts(scenario)[pursuer_id - 1])
            scenario = scenario.model_copy(update={"link": scenario.link.model_copy(
                update={"companion_id": swarm_companion_id(scenario.link.companion_id, pursuer_id)})})
        self.scenario = scenario
        self.summary_written = False  # set once _shutdown has written summary.json (the hard exit checks it)
        self.zenoh_namespace = zenoh_namespace  # None: keys as they are (zenoh_transport.check_namespace)
        self.zenoh_tls = zenoh_tls  # None: plain TCP, unauthenticated (see zenoh_transport.link_security)
        self.zenoh_insecure = zenoh_insecure  # plain TCP beyond loopback asked for (--insecure)
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
            bearing_noise_rng(scenario.simulation.seed if seed is None else seed, pursuer_id), self.history, self.recorder,
            clock=self._vehicle_time, wants_bearings=lambda: self.sequencer.phase in (Phase.READY, Phase.FOLLOWING),
            validator=build_fix_validator(self.link_settings), pipeline=lambda: self.follower.pipeline)
        self.sequencer = MissionSequencer(self.settings, self.settings.follow_duration or scenario.simulation.duration,
                                          link_up=lambda: self.target_link.health.accepted > 0,
                                          link_name=self.target_link.key, log=self.recorder,
                                          commands=build_command_validator(self.link_settings))
        self.follower = Follower(self.target_link, self.history, self.recorder)
        self.swarm: SwarmLink | None = None
        if full_scenario.swarm is not None:
            self.swarm = SwarmLink(full_scenario, pursuer_id, full_scenario.simulation.seed if seed is None else seed,
                                   clock=self._vehicle_time, own_position=self._own_position,
                                   pipeline=lambda: self.follower.pipeline, log_folder=self.recorder.folder)
            self.follower.swarm = self.swarm
        self._session = None
        self.live = None  # companion.adapters.live_view.LiveView with --live
        self.error: str | None = None
        self.stopped_by: str | None = None  # the stop signal's name (SIGTERM...), None while not stopped
        self._mission: asyncio.Task | None = None

    @property
    def phase(self) -> Phase:
        return self.sequencer.phase

    def attach_live_view(self, live) -> None:
        """Serve the flight on `live` (a LiveView): every control sample, and every event but the rejections
        (their counts are on /link)."""
        self.live = live
        self.follower.live = live

        def on_event(time_s: float | None, kind: str, detail: str) -> None:
            live.event(time_s, f"{kind}: {detail}", "warning" if kind.endswith("_failed") else "info")

        self.recorder.listeners.append(on_event)

    def _vehicle_time(self) -> float | None:
        return self.vehicle.latest.state.time if self.vehicle is not None and self.vehicle.latest else None

    def _own_position(self) -> np.ndarray | None:
        return self.vehicle.latest.state.position if self.vehicle is not None and self.vehicle.latest else None

    def request_stop(self, signum: int) -> None:
        """A stop signal (SIGINT, SIGTERM, SIGHUP): end the mission now, whatever the phase. The mission task
        is cancelled (waiting for the autopilot, arming, taking off, following, landing alike); run() then
        hands the vehicle to the autopilot (leave offboard or hold: it holds position, bounded by
        HAND_OVER_TIMEOUT) and writes every log and the summary."""
        if self.stopped_by is None:
            self.stopped_by = signal.Signals(signum).name
            self.recorder.event(self._vehicle_time(), "stop", f"{self.stopped_by}: stopping in phase {self.phase.value}",
                                signal=self.stopped_by, phase=self.phase.value)
        self.sequencer.request_stop()
        if self._mission is not None:
            self._mission.cancel()

    async def run(self) -> int:
        tlog = TlogWriter(self.recorder.folder / "mavlink.tlog").start()
        code = 1
        try:
            if self.stopped_by is None:
                self._mission = asyncio.create_task(self._fly(tlog))
                code = await self._mission
        except asyncio.CancelledError:
            if self.stopped_by is None:
                raise
            await self._hand_over()
        finally:
            await self._shutdown(tlog)
        if self.stopped_by is not None:
            code = 128 + signal.Signals[self.stopped_by].value
        return code

    async def _fly(self, tlog: TlogWriter) -> int:
        """Connect and fly the mission; the exit code (0 when it ended done)."""
        loop = asyncio.get_running_loop()
        code = 1
        try:
            publisher = self._open_zenoh(loop)
            self.vehicle = MavsdkVehicle(self.mavlink_url, connect_timeout=self.settings.connect_timeout,
                                         on_mavlink=tlog.record)
            # Every odometry sample goes into the own-state history as it arrives, from before take-off:
            # a fix stamped just before the follow loop's first sample still finds its own state.
            self.vehicle.sample_observers.append(self.follower.record_state)
            if self.swarm is not None:  # shares go out on the odometry clock from the first sample
                self.vehicle.sample_observers.append(self.swarm.on_sample)
            await self.vehicle.connect()
            limits = await self.vehicle.vehicle_limits(self.vehicle_config.mass, self.vehicle_config.gravity)
            self.recorder.event(None, "vehicle", f"connected; hover thrust {limits.hover_thrust_normalized:.4f}, "
                                                 f"tilt limit {math.degrees(limits.max_tilt):.1f} deg, horizontal margin "
                                                 f"{limits.horizontal_margin:.2f} (from autopilot parameters)")
            pipeline = build_pipeline(self.scenario, self.vehicle_config, limits.hover_thrust_normalized, self.pursuer_id)
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
        return code

    async def _hand_over(self) -> None:
        """After a stop signal: leave the armed vehicle to the autopilot (offboard stopped, or hold), bounded in time."""
        vehicle = self.vehicle
        if vehicle is None or vehicle.action is None or not vehicle.armed:
            return
        offboard = self.phase in (Phase.FOLLOWING, Phase.VEHICLE_LOST, Phase.ABORTING)
        try:
            await asyncio.wait_for(vehicle.stop_offboard() if offboard else vehicle.hold(), HAND_OVER_TIMEOUT)
            self.recorder.event(self._vehicle_time(), "stop", "vehicle handed to the autopilot "
                                                              f"({'offboard stopped' if offboard else 'hold'})")
        except (asyncio.TimeoutError, VehicleError) as error:
            self.recorder.event(self._vehicle_time(), "stop", f"hand-over not acknowledged: {str(error) or 'timeout'}")

    # ------------------------------------------------------------------ zenoh
    def _open_zenoh(self, loop: asyncio.AbstractEventLoop):
        """Open the session, subscribe fixes (target link) and commands; returns the state publisher."""
        settings = self.link_settings
        config = link_config(settings, self.zenoh_listen, self.zenoh_connect, self.zenoh_tls, self.zenoh_namespace,
                             insecure=self.zenoh_insecure)
        self._session = zenoh_transport.open_session(config)
        self.recorder.event(None, "zenoh_security",
                            zenoh_transport.link_security(self.zenoh_tls, insecure=self.zenoh_insecure),
                            role=self.zenoh_tls.role if self.zenoh_tls is not None else None)
        self.target_link.subscribe(self._session, loop)
        if self.swarm is not None:
            self.swarm.subscribe(self._session, loop)
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
            "latency_fix_to_estimator_ms": self.target_link.bearing_latencies_ms.percentiles(),
            "phase": mission.phase.value,
            "error": self.error,
            "engaged_at": mission.engaged_at,
            "setpoints_sent": control.setpoints_sent,
            "vehicle_link_losses": mission.vehicle_link_losses,
            "resumes": mission.resumes,
            "deadline_misses": control.deadline_misses,
            "latency_fix_to_setpoint_ms": control.latencies_ms.percentiles(),
            "link": {**self.target_link.health.as_dict(time.monotonic()),
                     "contest_log": list(self.target_link.validator.contests)},
            "vehicle_status_texts": self.vehicle.status_texts if self.vehicle is not None else [],
            "vehicle_status_texts_dropped": self.vehicle.status_texts_dropped if self.vehicle is not None else 0,
            "bad_odometry": self.vehicle.bad_odometry if self.vehicle is not None else 0,
            "health_reasons_at_end": list(control.pipeline.health.episode_reasons) if control.pipeline is not None else [],
            # how often the safety envelope acted (control ticks and their seconds), None before a pipeline existed
            "envelope": control.pipeline.envelope_record.as_dict() if control.pipeline is not None else None,
            "stopped_by": self.stopped_by,
            "abort_requested": mission.abort_requested and self.stopped_by is None,
            "pursuer_id": self.pursuer_id,
            "companion_id": self.link_settings.companion_id,
            "swarm": self._swarm_summary(),
            "live_view": None if self.live is None else self.live.summary(),
        }

    def _swarm_summary(self) -> dict | None:
        """The share link's figures, the pipeline's law changes and following_since, the vehicle time (s) of the
        pipeline's first bearing in following: the origin of the [swarm.link] windows' clock ([swarm] only; None
        otherwise)."""
        if self.swarm is None:
            return None
        pipeline = self.follower.pipeline
        return {**self.swarm.summary(),
                "law_changes": [] if pipeline is None else [(round(t, 3), law) for t, law in pipeline.law_changes],
                "following_since": None if pipeline is None else pipeline.engaged_at}

    async def _shutdown(self, tlog: TlogWriter) -> None:
        """Logs and summary first (nothing is lost if a library then hangs on close), then MAVSDK
        (bounded: CLOSE_TIMEOUT) and Zenoh."""
        try:
            tlog.stop()
            if self.live is not None:
                self.live.close()
            self.recorder.summary(self.summary())
            self.summary_written = True
            self.recorder.close()
            if self.swarm is not None:
                self.swarm.close()
        finally:
            try:
                if self.vehicle is not None:
                    await asyncio.wait_for(self.vehicle.close(), CLOSE_TIMEOUT)
            except asyncio.TimeoutError:
                pass
            finally:
                if self._session is not None:
                    self._session.close()


def link_config(settings: LinkConfig, listen: tuple[str, ...], connect: tuple[str, ...],
                tls: "zenoh_transport.Identity | None", namespace: str | None = None, *, insecure: bool = False):
    """The companion's Zenoh configuration ([link] `settings` with these endpoints; zenoh_transport.zenoh_config).

    LinkError (one line) when it would reach beyond this computer (an endpoint that is not loopback, multicast
    scouting) without `tls`, unless `insecure` (zenoh_transport.check_exposure): fixes and aborts are obeyed, so a
    plain link is taken only from this computer unless asked for. With TLS or `insecure` it may listen on any
    address.
    """
    config = zenoh_transport.zenoh_config(settings.mode, listen=listen, connect=connect,
                                          overrides=settings.zenoh_overrides, tls=tls, namespace=namespace,
                                          allow_remote_listen=True)
    zenoh_transport.check_exposure(config, tls, insecure=insecure)
    return config


def _pursuer_id(text: str) -> int:
    """argparse type of --pursuer-id: an integer in 1..MAX_PURSUERS."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 1 <= value <= MAX_PURSUERS:
        raise argparse.ArgumentTypeError(f"{value} is outside 1..{MAX_PURSUERS}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `companion` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="companion", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=scenario_file, default=DEFAULT_SCENARIO, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--mavlink", default=None, help="MAVSDK connection URL ([companion] mavlink_url)")
    parser.add_argument("--zenoh-connect", action="append", default=None, help="Zenoh endpoint to connect to (repeatable)")
    parser.add_argument("--zenoh-listen", action="append", default=None, help="Zenoh endpoint to listen on (repeatable)")
    add_zenoh_security_arguments(parser, "companion")
    parser.add_argument("--insecure", action="store_true",
                        help="accept an unauthenticated Zenoh link beyond this computer (an endpoint that is not "
                             "loopback, or multicast scouting) without --zenoh-tls: anyone who reaches it may publish "
                             "fixes or an abort. Without it such a plain link is refused at start")
    parser.add_argument("--log-dir", type=output_folder, default=None, help="run folder (default runs/companion-<time>)")
    parser.add_argument("--seed", type=seed_argument, default=None, help="bearing-noise seed, an integer >= 0 ([simulation] seed)")
    parser.add_argument("--pursuer-id", type=_pursuer_id, default=1, metavar="K",
                        help=f"which pursuer of a [swarm] scenario this companion flies, 1..{MAX_PURSUERS} (its start, its "
                             "share key bof/swarm/K/share, companion id <companion_id>-K); 1 without [swarm] "
                             "(default: %(default)s)")
    parser.add_argument("--live", type=live_port, nargs="?", const=LIVE_PORT, default=None, metavar="PORT",
                        help="serve the flight's channels (poses, 3-D scene, range, health, link) to Foxglove on a "
                             f"WebSocket server while it flies: port {LIVE_PORT} without PORT, 0 for any free port; the "
                             "URL is printed at start. Off by default (nothing is published)")
    parser.add_argument("--live-host", default="127.0.0.1", metavar="HOST",
                        help="address the live view listens on (default: %(default)s, this computer only; 0.0.0.0 "
                             "serves every network the onboard computer is on, unauthenticated)")
    parser.add_argument("--precompile", action="store_true",
                        help="compile the estimator and setpoint kernels into numba's cache (or load them), say where and "
                             "how long it took, and exit without opening any link: run it once on the onboard computer "
                             "after installing, so that the first start before a flight does not wait for the compiler")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    return parser.parse_args(argv)


def precompile() -> int:
    """`companion --precompile`: compile (or load) the kernels now, print the time and numba's cache folder; 0."""
    if not kernels_compiled:
        print("companion: numba is not installed (or BOF_NO_JIT is set): the kernels run as plain Python, "
              "nothing to compile", flush=True)
        return 0
    started = time.perf_counter()
    warm_up_kernels()
    print(f"companion: kernels ready in {time.perf_counter() - started:.1f} s (numba), cached in {kernel_cache_folder()}",
          flush=True)
    return 0


def kernel_cache_folder() -> str:
    """Where numba keeps the compiled kernels: NUMBA_CACHE_DIR when set, else beside the sources (__pycache__), or
    the user's cache folder when the install is read-only. Read from one kernel's cache (numba's own choice)."""
    from companion.core.estimators import _correct_into

    cache = getattr(_correct_into, "_cache", None)
    return str(getattr(cache, "_cache_path", None) or "numba's default cache folder")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.precompile:
        return precompile()
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
    try:
        zenoh_tls = zenoh_transport.tls_identity(args.zenoh_tls, "companion")
        if args.zenoh_namespace is not None:
            zenoh_transport.check_namespace(args.zenoh_namespace)
        # A malformed endpoint, a plain one with --zenoh-tls, or a plain link beyond loopback without --insecure:
        # say so now, before anything is opened, not as a traceback once the app starts.
        link_config(scenario.link, tuple(args.zenoh_listen or scenario.link.listen),
                    tuple(args.zenoh_connect or scenario.link.connect), zenoh_tls, insecure=args.insecure)
    except zenoh_transport.LinkError as error:
        print(f"companion: {error}", file=sys.stderr)
        return 2
    log = configure_console()
    say(f"companion: {zenoh_transport.link_security(zenoh_tls, insecure=args.insecure)}")
    log_dir = args.log_dir or new_run_folder("runs", "companion")
    try:
        check_pursuer_id(scenario, args.pursuer_id)
    except ConfigError as error:
        print(f"companion: {error}", file=sys.stderr)
        return 2
    # Compile (or load from numba's cache) the estimator kernels before any link is open. Done later, inside the
    # event loop (build_estimator), it blocked odometry and fixes for the load time (0.3 s; ~30 s on an empty cache)
    # and the fixes queued meanwhile were refused as future-stamped against the stalled vehicle clock.
    started = time.perf_counter()
    warm_up_kernels()
    if kernels_compiled:
        say(f"companion: kernels ready in {time.perf_counter() - started:.1f} s (numba; `companion --precompile` "
            "fills the cache ahead of a flight)")
    app = CompanionApp(scenario, vehicle_config, log_dir, args.mavlink, zenoh_connect=args.zenoh_connect,
                       zenoh_listen=args.zenoh_listen, seed=args.seed, zenoh_tls=zenoh_tls,
                       zenoh_namespace=args.zenoh_namespace, pursuer_id=args.pursuer_id, zenoh_insecure=args.insecure)
    if args.live is not None:
        from companion.adapters.live_view import LiveView

        try:
            live = LiveView(args.live, args.live_host, app.scenario.guidance.desired_range)
        except RuntimeError as error:  # the SDK's FoxgloveError: port taken, host unknown
            print(f"companion: --live {args.live_host}:{args.live}: {error}", file=sys.stderr)
            return 2
        app.attach_live_view(live)
        say(f"companion: live view on {live.url} (Foxglove: Open connection)")

    def hard_exit(signum: int) -> None:
        written = "logs and summary already written"
        if not app.summary_written:
            # The mission did not unwind in time (a MAVSDK call that ignores cancellation): write the
            # summary from here, as it stands, rather than leave the run without one.
            try:
                app.recorder.summary(app.summary())
                written = "summary written by the hard exit; logs flushed line by line"
            except Exception as error:  # the process is about to end either way: say why there is none
                written = f"NO summary: {type(error).__name__}: {error}"
        log.error(f"companion: still busy {HARD_EXIT_AFTER:g} s after {signal.Signals(signum).name}; exiting now "
                  f"({written})")
        sys.stdout.flush()
        os._exit(128 + signum)

    def on_signal(signum: int) -> None:
        if app.stopped_by is None:
            # MAVSDK's blocking calls run in executor threads that asyncio would wait for at exit: bound it.
            guard = threading.Timer(HARD_EXIT_AFTER, hard_exit, (signum,))
            guard.daemon = True
            guard.start()
            arm_kill_backstop(HARD_EXIT_AFTER + BACKSTOP_MARGIN_S)  # if even that timer cannot run
        app.request_stop(signum)

    async def run() -> int:
        loop = asyncio.get_running_loop()
        for sig in STOP_SIGNALS:
            loop.add_signal_handler(sig, on_signal, sig)
        who = f", pursuer {app.pursuer_id} of {scenario.swarm.count}" if scenario.swarm is not None else ""
        say(f"companion ready: {scenario.name}{who}, vehicle {app.mavlink_url}, log {log_dir}")
        return await app.run()

    with mavsdk_log_to(log):
        code = asyncio.run(run())
    if app.stopped_by is not None:
        say(f"companion: stopped by {app.stopped_by} in phase {app.phase.value}")
    return code


if __name__ == "__main__":
    sys.exit(main())
