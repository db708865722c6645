"""`sitl-plant`: the quadrotor as a MAVLink vehicle, paced against the wall clock.

    sitl-plant --config config/scenarios/constant_velocity.toml [--speed-factor 2]

Runs the Autopilot tick by tick so that simulated time advances speed_factor times
as fast as the wall clock (like PX4_SIM_SPEED_FACTOR), answering MAVLink on the
companion and ground-station links between ticks. Every timestamp it sends is
simulated time since boot. Stops on SIGINT/SIGTERM or after --duration simulated
seconds, closes its sockets and finishes its logs.

Logs (--log-dir): vehicle.csv (true state at --log-rate), events.jsonl (status
texts, mode changes, every rejected packet), stats.json (counters, pacing),
rewritten every second and at exit. Lines are flushed as written, so an
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

from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, PlantScenario, VehicleConfig, load_plant_scenario
from interfaces.records import CsvLog, JsonLinesLog, write_json
from interfaces.link_schema import CLOCK_KEY, ClockTick, encode_clock
from interfaces.zenoh_transport import LinkError, link_security, open_session, publisher, tls_identity, zenoh_config
from sitl_plant.vehicle.autopilot import Autopilot
from sitl_plant.vehicle.params import quadrotor_params
from sitl_plant.vehicle.mavlink_vehicle import COMPANION_STREAMS, GCS_STREAMS, Event, Home, LinkSpec, MavlinkVehicle
from sitl_plant.vehicle.parameters import ParameterError

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: When the plant falls this far (simulated seconds) behind the wall clock it stops trying to
#: catch up and re-anchors; the slip is counted and reported.
MAX_LAG = 0.25


def build_vehicle(
    scenario: PlantScenario,
    vehicle: VehicleConfig,
    speed_factor: float | None = None,
    companion_port: int | None = None,
    gcs_port: int | None = None,
    seed: int | None = None,
    on_event=None,
) -> MavlinkVehicle:
    """Autopilot + MAVLink links from a scenario (the plant's sections, load_plant_scenario; a full
    Scenario has them too); keyword overrides take precedence over [sitl]."""
    sitl = scenario.sitl
    speed = sitl.speed_factor if speed_factor is None else speed_factor
    autopilot = Autopilot(
        quadrotor_params(vehicle),
        start_position=scenario.pursuer.initial_position[:2],
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
    links = [
        LinkSpec("companion", sitl.companion_host, sitl.companion_port if companion_port is None else companion_port,
                 COMPANION_STREAMS, sitl.bind_host),
        LinkSpec("gcs", sitl.gcs_host, sitl.gcs_port if gcs_port is None else gcs_port, GCS_STREAMS, sitl.bind_host),
    ]
    return MavlinkVehicle(autopilot, links, Home(*sitl.home), on_event=on_event)


class RunLog:
    """The plant's run folder (interfaces.records writers: every line flushed as written); no folder, no files."""

    COLUMNS = ("time", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r",
               "armed", "mode", "landed_state", "thrust_command")

    def __init__(self, folder: Path | None, rate_hz: float, latency: bool = False) -> None:
        self.folder = folder
        self.period = 1.0 / rate_hz if rate_hz > 0 else math.inf
        self._next = 0.0
        self._vehicle = self._events = self._latency = None
        if folder is None:
            return
        self._vehicle = CsvLog(folder / "vehicle.csv", self.COLUMNS)
        self._events = JsonLinesLog(folder / "events.jsonl")
        if latency:
            self._latency = CsvLog(folder / "odometry_sent.csv", ("time_usec", "wall_monotonic_ns"))

    def event(self, event: Event) -> None:
        if self._events is not None:
            self._events.write({"time": round(event.time, 6), "kind": event.kind, "detail": event.detail,
                                **event.fields})

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
        for log in (self._vehicle, self._events, self._latency):
            if log is not None:
                log.close()


class ClockPublisher:
    """The plant's simulated time on Zenoh (bof/sim/clock), for the target simulator and others."""

    def __init__(self, listen, connect, rate_hz: float, sender: str = "sitl-plant", tls=None) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"--clock-rate must be positive, got {rate_hz!r}")
        self.session = open_session(zenoh_config(listen=listen, connect=connect, tls=tls))
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
                 progress: bool = False, on_tick=None) -> None:
        if not (math.isfinite(speed_factor) and speed_factor > 0):
            raise ValueError(f"speed factor must be positive, got {speed_factor!r}")
        self.vehicle = vehicle
        self.autopilot = vehicle.autopilot
        self.speed = speed_factor
        self.log = log
        self.duration = duration
        self.progress = progress
        self.on_tick = on_tick  # called with the simulated time after every tick
        self.stop_requested = False
        self.slips = 0
        self.slipped_time = 0.0
        self.max_lag = 0.0
        self.late_ticks = 0
        self.ticks = 0
        self.tick_cpu = []  # seconds of CPU per tick, sampled (for the benchmark)
        self._wall_start = time.monotonic()

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
            "slipped_sim_s": round(self.slipped_time, 4),
            "tick_cpu_median_us": round(float(np.median(tick_cpu)) * 1e6, 1),
            "tick_cpu_p99_us": round(float(np.percentile(tick_cpu, 99)) * 1e6, 1),
            "mode": self.autopilot.mode.name,
            "armed": self.autopilot.armed,
            "setpoints_received": self.autopilot.setpoints_received,
            "links": {link.name: {"bound": list(link.address), "partner": list(link.partner), "sent": link.sent,
                                  "send_errors": link.send_errors, "dropped_silenced": link.dropped_silenced}
                      for link in self.vehicle.links},
            "mavlink": self.vehicle.stats.as_dict(),
        }

    def run(self) -> None:
        ap, mv, tick = self.autopilot, self.vehicle, self.autopilot.tick_period
        sockets = [link.sock for link in mv.links]
        wall_anchor, sim_anchor = time.monotonic(), ap.time
        next_stats = time.monotonic() + 1.0
        next_progress = 10.0
        mv.after_tick()  # first heartbeat at time zero
        while not self.stop_requested:
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
                if lag > MAX_LAG:
                    # Cannot keep up: give up the lost time instead of racing to catch up.
                    self.slips += 1
                    self.slipped_time += lag - tick
                    wall_anchor, sim_anchor = now, ap.time
            else:
                select.select(sockets, [], [], (tick - lag) / self.speed)
            if now >= next_stats:
                next_stats = now + 1.0
                self.log.write_stats(self.stats())
                if len(self.tick_cpu) > 20000:
                    del self.tick_cpu[:10000]
            if self.progress and ap.time >= next_progress:
                next_progress += 10.0
                p = ap.state.position
                print(f"sitl-plant t={ap.time:6.1f}s mode={ap.mode.name:8s} armed={int(ap.armed)} "
                      f"pos=({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})", flush=True)
        self.log.write_stats(self.stats())


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="sitl-plant", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_SCENARIO, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--speed-factor", type=float, default=None, help="simulated seconds per wall second ([sitl] speed_factor)")
    parser.add_argument("--companion-port", type=int, default=None, help="UDP port the companion listens on (default 14540)")
    parser.add_argument("--gcs-port", type=int, default=None, help="UDP port the ground station listens on (default 14550)")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    parser.add_argument("--seed", type=int, default=None, help="telemetry noise seed ([simulation] seed)")
    parser.add_argument("--log-dir", type=Path, default=None, help="write vehicle.csv, events.jsonl, stats.json here")
    parser.add_argument("--log-rate", type=float, default=50.0, help="vehicle.csv rows per simulated second")
    parser.add_argument("--latency-log", action="store_true", help="also log wall time of every ODOMETRY sent")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--zenoh-listen", action="append", default=None, metavar="ENDPOINT",
                        help="publish the simulated clock on Zenoh, listening here (e.g. tcp/127.0.0.1:7447); repeatable")
    parser.add_argument("--zenoh-connect", action="append", default=None, metavar="ENDPOINT",
                        help="publish the simulated clock on Zenoh, connecting here; repeatable")
    parser.add_argument("--clock-rate", type=float, default=50.0, help="clock messages per simulated second")
    parser.add_argument("--zenoh-tls", type=Path, default=None, metavar="DIR",
                        help="mutual TLS and access control on Zenoh as role 'plant', with DIR/ca.pem, DIR/plant.pem, "
                             "DIR/plant.key (made by bof-certs; endpoints then tls/...). Default: plain TCP, unauthenticated")
    parser.add_argument("--mavlink-blackout", type=float, nargs=2, action="append", default=None,
                        metavar=("START", "DURATION"),
                        help="fault injection: the companion link goes silent both ways from START for DURATION "
                             "simulated seconds (adds to [faults.mavlink] blackouts); repeatable")
    parser.add_argument("--no-faults", action="store_true", help="ignore the scenario's [faults.mavlink] blackouts")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        scenario, vehicle_config = load_plant_scenario(args.config)
        for name, port in (("--companion-port", args.companion_port), ("--gcs-port", args.gcs_port)):
            if port is not None and not 1 <= port <= 65535:
                raise ConfigError(f"{name}: {port} is not a UDP port")
        if args.speed_factor is not None and not (0.0 < args.speed_factor <= 100.0):
            raise ConfigError(f"--speed-factor: {args.speed_factor} outside (0, 100]")
        log = RunLog(args.log_dir, args.log_rate, args.latency_log)
        vehicle = build_vehicle(scenario, vehicle_config, args.speed_factor, args.companion_port, args.gcs_port,
                                args.seed, on_event=log.event)
    except ConfigError as error:
        print(f"sitl-plant: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"sitl-plant: cannot open sockets or logs: {error}", file=sys.stderr)
        return 2
    if args.latency_log:
        vehicle.on_odometry_sent = log.odometry_sent
    windows = [] if args.no_faults else [(b.start, b.start + b.duration) for b in scenario.faults.mavlink.blackouts]
    for start, duration in args.mavlink_blackout or []:
        if not (math.isfinite(start) and math.isfinite(duration) and start >= 0 and duration > 0):
            print(f"sitl-plant: --mavlink-blackout {start} {duration}: need START >= 0 and DURATION > 0", file=sys.stderr)
            vehicle.close()
            log.close()
            return 2
        windows.append((start, start + duration))
    vehicle.companion_blackouts = sorted(windows)
    clock = None
    if args.zenoh_listen or args.zenoh_connect or args.zenoh_tls:
        try:
            if not (args.zenoh_listen or args.zenoh_connect):
                raise LinkError("--zenoh-tls: give --zenoh-listen or --zenoh-connect as well (tls/<host>:<port>)")
            tls = tls_identity(args.zenoh_tls, "plant")
            clock = ClockPublisher(args.zenoh_listen or (), args.zenoh_connect or (), args.clock_rate, tls=tls)
            print(f"sitl-plant: {link_security(tls)}", flush=True)
        except (LinkError, ValueError) as error:
            vehicle.close()
            log.close()
            print(f"sitl-plant: {error}", file=sys.stderr)
            return 2
    speed = scenario.sitl.speed_factor if args.speed_factor is None else args.speed_factor
    runner = RealTimeRunner(vehicle, speed, log, args.duration, progress=not args.quiet,
                            on_tick=clock.tick if clock is not None else None)

    def request_stop(signum, frame):  # noqa: ARG001
        runner.stop_requested = True

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    links = ", ".join(f"{link.name} {link.address[0]}:{link.address[1]} -> {link.partner[0]}:{link.partner[1]}"
                      for link in vehicle.links)
    print(f"sitl-plant ready: {scenario.name}, speed x{speed:g}, links: {links}", flush=True)
    try:
        runner.run()
    finally:
        stats = runner.stats()
        log.write_stats(stats)
        if clock is not None:
            clock.close()
        vehicle.close()
        log.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(f"sitl-plant stopped at t={stats['sim_time']:.1f}s (x{stats['speed_factor_achieved']} achieved), "
          f"rejected: {stats['mavlink']['rejected'] or 'none'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
