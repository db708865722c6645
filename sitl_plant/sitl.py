"""`sitl-plant`: the quadrotor as a MAVLink vehicle, paced against the wall clock.

    sitl-plant --config config/scenarios/constant_velocity.toml [--speed-factor 2]

Runs the Autopilot tick by tick so that simulated time advances speed_factor times
as fast as the wall clock (like PX4_SIM_SPEED_FACTOR), answering MAVLink on the
companion and ground-station links between ticks. Every timestamp it sends is
simulated time since boot. Stops on SIGINT/SIGTERM or after --duration simulated
seconds, closes its sockets and finishes its logs.

Logs (--log-dir): vehicle.csv (true state at --log-rate), events.jsonl (status
texts, mode changes, rejected packets: the first ones of each reason verbatim, then
one count line per reason and simulated second), stats.json (exact counters,
pacing), rewritten every second and at exit. Lines are flushed as written, so an
interrupted run keeps everything up to the interruption.
"""

from __future__ import annotations

import argparse
import math
import select
import signal
import sys
import time
from pathlib import Path

import numpy as np

from interfaces.shutdown import arm_exit_deadline, keep_alive, stand_down
from interfaces.cli import (SPEED_FACTOR_RANGE, CommandParser, add_zenoh_security_arguments, output_folder,
                            speed_factor_argument)
from interfaces.scenario import (DEFAULT_SCENARIO, ConfigError, PlantScenario, VehicleConfig, load_plant_scenario,
                                 pursuer_starts)
from interfaces.records import AggregatingLog, CsvLog, JsonLinesLog, write_json
from interfaces.link_schema import CLOCK_KEY, ClockTick, encode_clock
from interfaces.zenoh_transport import LinkError, link_security, open_session, publisher, tls_identity, zenoh_config
from sitl_plant.vehicle.autopilot import Autopilot
from sitl_plant.vehicle.params import quadrotor_params
from sitl_plant.vehicle.mavlink_vehicle import COMPANION_STREAMS, GCS_STREAMS, Event, Home, LinkSpec, MavlinkVehicle
from sitl_plant.vehicle.parameters import ParameterError

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: events.jsonl: kinds written as they come (bounded by what the vehicle does, and worth every line).
#: Everything else (rejects, status texts, parameter and signing changes...) a peer can cause at its own rate.
VEHICLE_EVENTS = frozenset({"state", "failsafe", "fault"})
#: events.jsonl: per key (kind, and reason for rejects) this many records verbatim, then counts.
EVENTS_VERBATIM = 20
#: ... except the vehicle's own status texts, which a normal flight has dozens of.
STATUSTEXT_VERBATIM = 500
#: When the plant falls this far (simulated seconds) behind the wall clock it stops trying to
#: catch up and re-anchors; the slip is counted and reported.
MAX_LAG = 0.25


def build_vehicle(
    scenario: PlantScenario,
    vehicle: VehicleConfig,
    *,
    speed_factor: float | None = None,
    companion_port: int | None = None,
    gcs_port: int | None = None,
    seed: int | None = None,
    on_event=None,
    signing_key: bytes | None = None,
    sign_cfg: int | None = None,
    system_id: int = 1,
    pursuer_id: int = 1,
) -> MavlinkVehicle:
    """Autopilot + MAVLink links from a scenario (the plant's sections, load_plant_scenario; a full
    Scenario has them too); keyword overrides take precedence over [sitl].

    signing_key: 32-byte MAVLink signing key for the ground-station link (None: none yet).
    sign_cfg: MAV_SIGN_CFG override (else [sitl.parameters] or 0).
    system_id: the vehicle's MAVLink system id (1..255). pursuer_id: which pursuer of a [swarm] scenario
    this plant is (its start, interfaces.scenario.pursuer_starts); 1 without [swarm]."""
    sitl = scenario.sitl
    starts = pursuer_starts(scenario)
    if not 1 <= pursuer_id <= len(starts):
        raise ConfigError(f"--pursuer-id {pursuer_id}: scenario {scenario.name!r} has pursuers 1..{len(starts)}")
    if not 1 <= system_id <= 255:
        raise ConfigError(f"--system-id {system_id}: MAVLink system ids are 1..255")
    speed = sitl.speed_factor if speed_factor is None else speed_factor
    autopilot = Autopilot(
        quadrotor_params(vehicle),
        start_position=starts[pursuer_id - 1].initial_position[:2],
        yaw=math.radians(sitl.start_yaw_deg),
        tick_rate_hz=sitl.tick_rate_hz,
        physics_rate_hz=scenario.simulation.physics_rate_hz,
        max_tilt_deg=vehicle.max_tilt_deg,
        speed_factor=speed,
        seed=scenario.simulation.seed if seed is None else seed,
    )
    for name, value in sitl.parameters.items():
        try:
            autopilot.parameters.set(name, value)
        except ParameterError as error:
            raise ConfigError(f"sitl.parameters.{name}: {error}") from None
    if sign_cfg is not None:
        try:
            autopilot.parameters.set("MAV_SIGN_CFG", sign_cfg)
        except ParameterError as error:
            raise ConfigError(f"--mav-sign-cfg: {error}") from None
    companion = sitl.companion_port if companion_port is None else companion_port
    gcs = sitl.gcs_port if gcs_port is None else gcs_port
    if (sitl.companion_host, companion) == (sitl.gcs_host, gcs):
        raise ConfigError(f"the companion and ground-station links both send to {sitl.gcs_host}:{gcs}; "
                          "give them different ports")
    links = [
        LinkSpec("companion", sitl.companion_host, companion, COMPANION_STREAMS, sitl.bind_host),
        LinkSpec("gcs", sitl.gcs_host, gcs, GCS_STREAMS, sitl.bind_host, signed=True),
    ]
    vehicle = MavlinkVehicle(autopilot, links, Home(*sitl.home), on_event=on_event, system_id=system_id)
    if signing_key is not None:
        vehicle.set_signing_key(signing_key, source="--signing-key")
    return vehicle


def read_signing_key(path: Path) -> bytes:
    """A MAVLink signing key file: 64 hexadecimal characters (32 bytes), surrounding whitespace allowed.
    ConfigError, naming the file but never its content, if it is anything else."""
    try:
        text = Path(path).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"--signing-key {path}: cannot read it ({error.__class__.__name__})") from None
    if len(text) != 64 or any(c not in "0123456789abcdefABCDEF" for c in text):
        raise ConfigError(f"--signing-key {path}: want 64 hexadecimal characters (a 32-byte key), "
                          f"got {len(text)} characters{'' if len(text) != 64 else ' with non-hex ones'}")
    key = bytes.fromhex(text)
    if not any(key):
        raise ConfigError(f"--signing-key {path}: an all-zero key means 'no signing' in MAVLink")
    return key


class RunLog:
    """The plant's run folder (interfaces.records writers: every line flushed as written); no folder, no files."""

    COLUMNS = ("time", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r",
               "armed", "mode", "landed_state", "thrust_command")

    def __init__(self, folder: Path | None, rate_hz: float, latency: bool = False) -> None:
        self.folder = folder
        self.period = 1.0 / rate_hz if rate_hz > 0 else math.inf
        self._next = 0.0
        self._vehicle = self._events = self._latency = None
        self._bounded = self._texts = None
        if folder is None:
            return
        self._vehicle = CsvLog(folder / "vehicle.csv", self.COLUMNS)
        self._events = JsonLinesLog(folder / "events.jsonl")
        # Anything a peer can trigger at its own rate goes through these: a flood adds a bounded number of
        # lines (first ones verbatim, then one count line per key and simulated second); stats.json is exact.
        self._bounded = AggregatingLog(self._events, verbatim=EVENTS_VERBATIM, window=1.0)
        self._texts = AggregatingLog(self._events, verbatim=STATUSTEXT_VERBATIM, window=1.0)
        if latency:
            self._latency = CsvLog(folder / "odometry_sent.csv", ("time_usec", "wall_monotonic_ns"))

    def event(self, event: Event) -> None:
        if self._events is None:
            return
        record = {"time": round(event.time, 6), "kind": event.kind, "detail": event.detail, **event.fields}
        if event.kind in VEHICLE_EVENTS:
            self._events.write(record)
        elif event.kind == "statustext":
            self._texts.write(event.kind, record, event.time)
        else:
            reason = event.fields.get("reason")
            self._bounded.write(f"{event.kind}:{reason}" if reason else event.kind, record, event.time)

    def tick(self, sim_time: float) -> None:
        """Write the suppressed-count lines that are due (sim_time: s)."""
        for log in (self._bounded, self._texts):
            if log is not None:
                log.tick(sim_time)

    def odometry_sent(self, time_usec: int) -> None:
        if self._latency is not None:
            self._latency.write({"time_usec": time_usec, "wall_monotonic_ns": time.monotonic_ns()})

    def sample(self, autopilot: Autopilot) -> None:
        if self._vehicle is None or autopilot.time + 1e-9 < self._next:
            return
        self._next = autopilot.time + self.period
        state = autopilot.vehicle.quadrotor._s[:13]
        self._vehicle.write({
            "time": f"{autopilot.time:.4f}", **{column: f"{value:.6g}" for column, value in zip(self.COLUMNS[1:14], state)},
            "armed": int(autopilot.armed), "mode": autopilot.mode.name, "landed_state": int(autopilot.landed_state),
            "thrust_command": f"{autopilot.thrust_command:.4f}"})

    def write_stats(self, stats: dict) -> None:
        if self.folder is not None:
            write_json(self.folder / "stats.json", stats, indent=2, sort_keys=True)

    def close(self) -> None:
        for log in (self._bounded, self._texts):
            if log is not None:
                log.flush()
        for log in (self._vehicle, self._events, self._latency):
            if log is not None:
                log.close()


class ClockPublisher:
    """The plant's simulated time on Zenoh (bof/sim/clock), for the target simulator and others."""

    def __init__(self, listen, connect, rate_hz: float, sender: str = "sitl-plant", tls=None,
                 namespace: str | None = None) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"--clock-rate must be positive, got {rate_hz!r}")
        self.session = open_session(zenoh_config(listen=listen, connect=connect, tls=tls, namespace=namespace))
        self.publisher = publisher(self.session, CLOCK_KEY)
        self.period = 1.0 / rate_hz
        self.sender = sender
        self.seq = 0
        self._next = 0.0

    def tick(self, sim_time: float) -> None:
        if sim_time + 1e-9 >= self._next:
            self._next = sim_time + self.period
            self.publisher.put(encode_clock(ClockTick(self.sender, self.seq, sim_time)))
            self.seq += 1

    def close(self) -> None:
        self.session.close()


class RealTimeRunner:
    """Paces an Autopilot + MavlinkVehicle against the wall clock at a speed factor."""

    def __init__(self, vehicle: MavlinkVehicle, speed_factor: float, log: RunLog, duration: float | None = None,
                 progress: bool = False, on_tick=None, clock_anchor: float | None = None, on_turn=None) -> None:
        if not (math.isfinite(speed_factor) and speed_factor > 0):
            raise ValueError(f"speed factor must be positive, got {speed_factor!r}")
        self.vehicle = vehicle
        self.autopilot = vehicle.autopilot
        self.speed = speed_factor
        self.log = log
        self.duration = duration
        self.progress = progress
        self.on_tick = on_tick  # called with the simulated time after every tick
        self.on_turn = on_turn  # called with no arguments at every turn of the loop (the process's keep_alive)
        # time.monotonic() at which simulated time is 0 (shared by every plant given the same anchor), or None:
        # simulated time starts now and a plant that falls MAX_LAG behind re-anchors (a slip)
        self.clock_anchor = clock_anchor
        self.catch_ups = 0  # with an anchor: times it fell MAX_LAG behind and caught up instead of slipping
        self.stop_requested = False
        self.slips = 0
        self.slipped_time = 0.0
        self.max_lag = 0.0
        self.late_ticks = 0
        self.ticks = 0
        self.tick_cpu = []  # seconds of CPU per tick, sampled (for the benchmark)
        self._wall_start = time.monotonic() if clock_anchor is None else clock_anchor

    def stats(self) -> dict:
        wall = time.monotonic() - self._wall_start
        sim = self.autopilot.time
        tick_cpu = np.array(self.tick_cpu[-5000:]) if self.tick_cpu else np.array([math.nan])
        return {
            "sim_time": round(sim, 4),
            "wall_time": round(wall, 4),
            "speed_factor_requested": self.speed,
            "speed_factor_achieved": round(sim / wall, 4) if wall > 0 else None,
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "max_lag_sim_s": round(self.max_lag, 4),
            "slips": self.slips,
            "clock_anchor": self.clock_anchor,
            "system_id": self.vehicle.system_id,
            "catch_ups": self.catch_ups,
            "slipped_sim_s": round(self.slipped_time, 4),
            "tick_cpu_median_us": round(float(np.median(tick_cpu)) * 1e6, 1),
            "tick_cpu_p99_us": round(float(np.percentile(tick_cpu, 99)) * 1e6, 1),
            "mode": self.autopilot.mode.name,
            "armed": self.autopilot.armed,
            "setpoints_received": self.autopilot.setpoints_received,
            "links": {link.name: {"bound": list(link.address), "partner": list(link.partner), "sent": link.sent,
                                  "send_errors": link.send_errors, "dropped_silenced": link.dropped_silenced,
                                  "datagrams": link.datagrams, "from_strangers": link.from_strangers}
                      for link in self.vehicle.links},
            "mavlink": self.vehicle.stats.as_dict(),
            "signing": self.vehicle.signing_status(),
        }

    def run(self) -> None:
        ap, mv, tick = self.autopilot, self.vehicle, self.autopilot.tick_period
        sockets = [link.sock for link in mv.links]
        wall_anchor, sim_anchor = (time.monotonic(), ap.time) if self.clock_anchor is None else (self.clock_anchor, 0.0)
        next_stats = time.monotonic() + 1.0
        next_progress = 10.0
        catching_up = False
        mv.after_tick()  # first heartbeat at time zero
        while not self.stop_requested:
            if self.on_turn is not None:
                self.on_turn()
            if self.duration is not None and ap.time >= self.duration - 1e-9:
                break
            mv.poll()
            now = time.monotonic()
            lag = sim_anchor + (now - wall_anchor) * self.speed - ap.time
            if lag >= tick:
                started = time.perf_counter()
                ap.tick()
                mv.after_tick()
                self.log.sample(ap)
                if self.on_tick is not None:
                    self.on_tick(ap.time)
                if self.ticks % 16 == 0:
                    self.tick_cpu.append(time.perf_counter() - started)
                self.ticks += 1
                self.max_lag = max(self.max_lag, lag)
                if lag > 2.0 * tick:
                    self.late_ticks += 1
                if lag > MAX_LAG and self.clock_anchor is not None:
                    # Several plants share this clock: never leave it; the ticks run back to back until
                    # simulated time is on it again (counted once per episode).
                    if not catching_up:
                        self.catch_ups += 1
                    catching_up = True
                elif lag > MAX_LAG:
                    # Cannot keep up: give up the lost time instead of racing to catch up.
                    self.slips += 1
                    self.slipped_time += lag - tick
                    wall_anchor, sim_anchor = now, ap.time
                elif lag < 2.0 * tick:
                    catching_up = False
            else:
                catching_up = False
                # bounded: before a shared anchor the wait could be seconds, and a stop must not wait for it
                select.select(sockets, [], [], min((tick - lag) / self.speed, 0.05))
            if now >= next_stats:
                next_stats = now + 1.0
                self.log.tick(ap.time)
                self.log.write_stats(self.stats())
                if len(self.tick_cpu) > 20000:
                    del self.tick_cpu[:10000]
            if self.progress and ap.time >= next_progress:
                next_progress += 10.0
                p = ap.state.position
                print(f"sitl-plant t={ap.time:6.1f}s mode={ap.mode.name:8s} armed={int(ap.armed)} "
                      f"pos=({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})", flush=True)
        self.log.write_stats(self.stats())


class _Parser(CommandParser):
    """argparse, but a bad argument is one line on stderr (no usage block) and exit status 2."""

    def error(self, message: str):  # noqa: D401
        self.exit(2, f"{self.prog}: error: {message}\n")


def _number(kind, low: float, high: float = math.inf, low_open: bool = True, what: str = "a number"):
    """argparse type: a finite number of `kind` in (low, high] (or [low, high] when not low_open)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not math.isfinite(value) or value > high or value < low or (low_open and value == low):
            bounds = f"{'(' if low_open else '['}{low:g}, {high:g}]"
            raise argparse.ArgumentTypeError(f"{text} is outside {bounds}")
        return value

    return parse


_port = _number(int, 1, 65535, low_open=False, what="a UDP port")
_positive = _number(float, 0.0)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `sitl-plant` (the CLI reference page prints its help)."""
    parser = _Parser(prog="sitl-plant", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_SCENARIO, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--speed-factor", type=speed_factor_argument, default=None,
                        help=f"simulated seconds per wall second, within {SPEED_FACTOR_RANGE} ([sitl] speed_factor)")
    parser.add_argument("--companion-port", type=_port, default=None, help="UDP port the companion listens on (default 14540)")
    parser.add_argument("--gcs-port", type=_port, default=None,
                        help="UDP port the ground station listens on (default 14550 on [sitl] gcs_host, 127.0.0.1)")
    parser.add_argument("--duration", type=_positive, default=None, help="stop after this many simulated seconds (> 0)")
    parser.add_argument("--seed", type=int, default=None, help="telemetry noise seed ([simulation] seed)")
    parser.add_argument("--log-dir", type=output_folder, default=None, help="write vehicle.csv, events.jsonl, stats.json here")
    parser.add_argument("--log-rate", type=_positive, default=50.0, help="vehicle.csv rows per simulated second (> 0)")
    parser.add_argument("--latency-log", action="store_true", help="also log wall time of every ODOMETRY sent")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                        help="MAVLink 2 signing key for the ground-station link: a file of 64 hex characters")
    parser.add_argument("--mav-sign-cfg", type=int, choices=(0, 1), default=None,
                        help="MAV_SIGN_CFG: 0 signing off, 1 signing required on the ground-station link "
                             "(default: [sitl.parameters] or 0)")
    parser.add_argument("--zenoh-listen", action="append", default=None, metavar="ENDPOINT",
                        help="publish the simulated clock on Zenoh, listening here (e.g. tcp/127.0.0.1:7447); repeatable")
    parser.add_argument("--zenoh-connect", action="append", default=None, metavar="ENDPOINT",
                        help="publish the simulated clock on Zenoh, connecting here; repeatable")
    parser.add_argument("--clock-rate", type=float, default=50.0, help="clock messages per simulated second")
    parser.add_argument("--system-id", type=_number(int, 1, 255, low_open=False, what="a MAVLink system id"),
                        default=1, help="MAVLink system id of this vehicle, 1..255 (default: %(default)s); give each "
                                        "vehicle its own when several stream to one ground station")
    parser.add_argument("--pursuer-id", type=_number(int, 1, 32, low_open=False, what="a pursuer id"), default=1,
                        help="which pursuer of a [swarm] scenario this plant is: it starts at that pursuer's "
                             "[[swarm.pursuers]] position (default: %(default)s)")
    parser.add_argument("--clock-anchor", type=_number(float, 0.0), default=None, metavar="T",
                        help="time.monotonic() (CLOCK_MONOTONIC, s, this machine) at which simulated time is 0: plants "
                             "given the same anchor share one simulated clock (several pursuers); one behind it catches "
                             "up instead of slipping (default: simulated time starts when the plant does)")
    add_zenoh_security_arguments(parser, "plant")
    parser.add_argument("--mavlink-blackout", type=float, nargs=2, action="append", default=None,
                        metavar=("START", "DURATION"),
                        help="fault injection: the companion link goes silent both ways from START for DURATION "
                             "simulated seconds, START counted from the vehicle's first switch to Offboard (when the "
                             "companion takes control; adds to [faults.mavlink] blackouts); repeatable")
    parser.add_argument("--no-faults", action="store_true", help="ignore the scenario's [faults.mavlink] blackouts")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.companion_port is not None and args.companion_port == args.gcs_port:
        parser.error(f"--companion-port and --gcs-port are both {args.gcs_port}; the two links need different ports")
    if not (math.isfinite(args.clock_rate) and args.clock_rate > 0):
        parser.error(f"argument --clock-rate: {args.clock_rate} is not a positive rate")
    for start, duration in args.mavlink_blackout or []:
        if not (math.isfinite(start) and math.isfinite(duration) and start >= 0 and duration > 0):
            parser.error(f"--mavlink-blackout {start} {duration}: need START >= 0 and DURATION > 0")
    return args


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_args(argv)
    except SystemExit as exit_:  # argparse has printed its one line (or the help)
        return int(exit_.code or 0)
    log = None
    try:
        scenario, vehicle_config = load_plant_scenario(args.config)
        key = read_signing_key(args.signing_key) if args.signing_key is not None else None
        if key is not None and args.signing_key.stat().st_mode & 0o077:
            print(f"sitl-plant: warning: --signing-key {args.signing_key} is readable by others (chmod 600 it)",
                  file=sys.stderr, flush=True)
        log = RunLog(args.log_dir, args.log_rate, args.latency_log)
        vehicle = build_vehicle(scenario, vehicle_config, speed_factor=args.speed_factor,
                                companion_port=args.companion_port, gcs_port=args.gcs_port, seed=args.seed, on_event=log.event,
                                signing_key=key, sign_cfg=args.mav_sign_cfg, system_id=args.system_id,
                                pursuer_id=args.pursuer_id)
    except ConfigError as error:
        if log is not None:
            log.close()
        print(f"sitl-plant: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        if log is not None:
            log.close()
        print(f"sitl-plant: cannot open sockets or logs: {error}", file=sys.stderr)
        return 2
    if args.latency_log:
        vehicle.on_odometry_sent = log.odometry_sent
    windows = [] if args.no_faults else [(b.start, b.start + b.duration) for b in scenario.faults.mavlink.blackouts]
    for start, duration in args.mavlink_blackout or []:
        windows.append((start, start + duration))
    vehicle.companion_blackouts = sorted(windows)
    clock = None
    if args.zenoh_listen or args.zenoh_connect or args.zenoh_tls:
        try:
            if not (args.zenoh_listen or args.zenoh_connect):
                raise LinkError("--zenoh-tls: give --zenoh-listen or --zenoh-connect as well (tls/<host>:<port>)")
            tls = tls_identity(args.zenoh_tls, "plant")
            clock = ClockPublisher(args.zenoh_listen or (), args.zenoh_connect or (), args.clock_rate, tls=tls,
                                   namespace=args.zenoh_namespace)
            print(f"sitl-plant: {link_security(tls)}", flush=True)
        except (LinkError, ValueError) as error:
            vehicle.close()
            log.close()
            print(f"sitl-plant: {error}", file=sys.stderr)
            return 2
    speed = scenario.sitl.speed_factor if args.speed_factor is None else args.speed_factor
    runner = RealTimeRunner(vehicle, speed, log, args.duration, progress=not args.quiet,
                            on_tick=clock.tick if clock is not None else None, clock_anchor=args.clock_anchor,
                            on_turn=keep_alive)

    def request_stop(signum, frame):  # noqa: ARG001
        runner.stop_requested = True
        arm_exit_deadline("sitl-plant", signum)

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    links = ", ".join(f"{link.name} {link.address[0]}:{link.address[1]} -> {link.partner[0]}:{link.partner[1]}"
                      for link in vehicle.links)
    gcs = next(link for link in vehicle.links if link.name == "gcs")
    signing = (f"MAV_SIGN_CFG={vehicle.signing_mode}, key {'from ' + vehicle.signing_key_source if vehicle.signing_key_set else 'not set'}")
    print(f"sitl-plant: ground station (--gcs-port) {gcs.partner[0]}:{gcs.partner[1]}; MAVLink signing: {signing}",
          flush=True)
    print(f"sitl-plant ready: {scenario.name}, system id {args.system_id}, pursuer {args.pursuer_id}, speed x{speed:g}, "
          f"links: {links}", flush=True)
    try:
        runner.run()
    finally:
        stats = runner.stats()
        log.write_stats(stats)
        if clock is not None:
            clock.close()
        vehicle.close()
        log.close()
        stand_down()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(f"sitl-plant stopped at t={stats['sim_time']:.1f}s (x{stats['speed_factor_achieved']} achieved), "
          f"rejected: {stats['mavlink']['rejected'] or 'none'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
