"""`sitl-target`: the target drone as a process publishing position fixes over Zenoh.

    python -m sitl_plant.world.target_publisher --zenoh-connect tcp/127.0.0.1:7447 [--rate 5] [--frame geodetic]

Stands in for the target of the paper's flight experiment, whose GNSS position reached
the pursuer over a Zigbee radio. The target flies the scenario's [target] (constant
velocity plus scheduled turns or a named motion model, sitl_plant.world.target) on the **plant's clock**:
it subscribes to ``bof/sim/clock`` and, whenever simulated time reaches the next
multiple of 1/rate, publishes a ``bof.target_fix/2`` on ``bof/target/<sender>/fix``
stamped with that multiple, with this process's epoch (a random boot id drawn at start: a
restarted sitl-target has a new epoch and counts seq from 0 again) (several fixes, each with its own stamp, if one clock tick
covers several). It never runs ahead of the clock, and waits (saying so once) until a
clock arrives. Before --start-time (simulated s) the target hovers at its initial
position; after it, scenario time = simulated time - start time.

Clock ticks that do not decode are counted by reason and ignored; ticks from a second
clock sender are ignored; a clock that goes back (a restarted plant) restarts the
target from its initial state; a forward jump of more than MAX_CLOCK_JUMP re-anchors
the fix schedule instead of publishing the whole gap.

Link faults (sitl_plant.world.link_faults): the scenario's [faults] sit between the encoder and the
publisher. Every fix is offered to the fault model and every clock tick publishes what
it says is due (its delays are resolved to the clock's tick); the impostor's fixes go
out on the same key. --faults off disables them; --fault KEY=VALUE (repeatable, VALUE a
TOML value, e.g. --fault loss_probability=0.3 --fault 'blackouts=[{start=20,duration=5}]')
overrides one setting. The faults' seed is [faults] seed, else derived from the seed.

Log (--log-dir): target.csv, one row per fix produced, before the link faults (seq,
stamp, scenario time, true NED position and velocity, published position in the
published frame), and faults.jsonl, one line per injected fault ({"time": simulated s,
"kind", "detail", and the fault's fields such as "seq"}; past FAULTS_VERBATIM lines of one kind,
one count line per kind per simulated second: interfaces.records.AggregatingLog), both flushed
line by line. A one-line count of the faults is
printed at exit. SIGINT/SIGTERM, or reaching --duration simulated seconds, closes the session,
finishes the log and exits 0; bad arguments exit 2.
"""

from __future__ import annotations

import argparse
import math
import queue
import signal
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

from interfaces.shutdown import arm_exit_deadline, keep_alive, stand_down
from interfaces.cli import CommandParser, add_zenoh_security_arguments, output_folder
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, FaultsConfig, TargetConfig, load_plant_scenario
from interfaces.link_schema import (CLOCK_KEY, PayloadError, TargetFix, decode_clock, decode_command, encode_target_fix,
                                    new_epoch, target_command_key, target_fix_key)
from interfaces.records import AggregatingLog, CsvLog, JsonLinesLog
from interfaces.zenoh_transport import LinkError, link_security, open_session, publisher, tls_identity, zenoh_config
from interfaces.geodesy import ned_to_geodetic
from sitl_plant.world.link_faults import FaultEvent, LinkFaults, describe, fault_rng, override_faults
from sitl_plant.world.target import TargetMotion, target_from_config

DEFAULT_SCENARIO = DEFAULT_SCENARIO
#: A fix is due when the clock is within this much (s) of its stamp (clock stamps are sums of floats).
CLOCK_TOLERANCE = 1e-9
#: A forward clock jump larger than this (simulated s) re-anchors the schedule instead of publishing the gap.
MAX_CLOCK_JUMP = 10.0
#: Say once that we wait for the clock when none came within this many wall seconds.
WAIT_NOTICE_AFTER = 0.5
CLOCK_QUEUE_SIZE = 10000
#: faults.jsonl: events of one kind written in full before only counts are (a steady spoof is 5 a second).
FAULTS_VERBATIM = 1000
#: A start command stamped further ahead of / behind the clock than this (s) is refused.
COMMAND_MAX_SKEW = 0.5
COMMAND_MAX_AGE = 2.0


class FixSchedule:
    """Fix stamps k / rate_hz (k an integer, so stamps are exact multiples), due once the clock reaches them.

    The first stamp is the first multiple at or after the first clock time seen: a
    target started late does not publish the past.
    """

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self._next_index: int | None = None

    def restart(self) -> None:
        """Forget the position in the schedule; the next clock time anchors it again."""
        self._next_index = None

    def due(self, clock_time: float) -> list[float]:
        """Stamps (s) that became due now that simulated time is `clock_time` (s), in order."""
        if self._next_index is None:
            self._next_index = math.ceil(clock_time * self.rate_hz - CLOCK_TOLERANCE * self.rate_hz)
        stamps = []
        while self._next_index / self.rate_hz <= clock_time + CLOCK_TOLERANCE:
            stamps.append(self._next_index / self.rate_hz)
            self._next_index += 1
        return stamps


def target_model(config: TargetConfig, seed: int = 0) -> TargetMotion:
    """The scenario's target model at scenario time 0 (sitl_plant.world.target.target_from_config;
    seed: the flight's seed, drawn from by the random-acceleration target only)."""
    return target_from_config(config, seed)


class TargetTruth:
    """The target's true state at any simulated time: hover until start_time (s), then the scenario."""

    def __init__(self, config: TargetConfig, start_time: float = 0.0, seed: int = 0) -> None:
        self.config = config
        self.start_time = start_time
        self.seed = seed
        self.model = target_model(config, seed)

    def at(self, sim_time: float) -> tuple[float, np.ndarray, np.ndarray]:
        """(scenario time s, position m NED shape (3,), velocity m/s NED shape (3,)) at `sim_time` (s)."""
        scenario_time = max(0.0, sim_time - self.start_time)
        if scenario_time < self.model.time:  # the clock went back: fly again from the start
            self.model = target_model(self.config, self.seed)
        self.model.advance_to(scenario_time)
        velocity = self.model.velocity.copy() if sim_time >= self.start_time else np.zeros(3)
        return scenario_time, self.model.position.copy(), velocity


class TargetLog:
    """target.csv: one row per fix produced (interfaces.records.CsvLog, flushed as written); no folder, no file.

    Positions and velocities are written with repr (every digit), so readers recover the exact floats.
    """

    def __init__(self, folder: Path | None, frame: str) -> None:
        self._log = None
        if folder is None:
            return
        published = ("published_lat_deg", "published_lon_deg", "published_alt_m") if frame == "geodetic" else (
            "published_n", "published_e", "published_d")
        self._columns = ("seq", "stamp", "scenario_time", "true_n", "true_e", "true_d", "true_vn", "true_ve", "true_vd",
                         *published)
        self._log = CsvLog(folder / "target.csv", self._columns)

    def fix(self, fix: TargetFix, scenario_time: float, position: np.ndarray, velocity: np.ndarray) -> None:
        if self._log is not None:
            values = (fix.stamp, scenario_time, *position, *velocity, *fix.position)
            self._log.write({"seq": fix.seq, **{column: repr(float(value))
                                                for column, value in zip(self._columns[1:], values)}})

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None


class FaultLog:
    """faults.jsonl: one JSON line per injected link fault (its time, kind, detail and fields), flushed as
    written (no file without a folder)."""

    def __init__(self, folder: Path | None) -> None:
        self._log = AggregatingLog(JsonLinesLog(folder / "faults.jsonl"), verbatim=FAULTS_VERBATIM) \
            if folder is not None else None

    def write(self, events: list[FaultEvent]) -> None:
        if self._log is not None:
            for event in events:
                self._log.write(event.kind, event.record(), event.time)

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None


class TargetPublisher:
    """Clock ticks in, fixes out: everything sitl-target does between two clock ticks.

    faults: the link's fault model (None: every fix is sent as it is made); its events
    go to fault_log.
    """

    def __init__(self, truth: TargetTruth, schedule: FixSchedule, send, log: TargetLog, sender: str, frame: str,
                 home: tuple[float, float, float], noise_std: float, *, rng: np.random.Generator,
                 duration: float | None = None, faults: LinkFaults | None = None,
                 fault_log: FaultLog | None = None, epoch: int | None = None) -> None:
        self.truth = truth
        self.epoch = new_epoch() if epoch is None else epoch  # this process's boot id
        self.schedule = schedule
        self.send = send  # callable(bytes)
        self.log = log
        self.sender = sender
        self.frame = frame
        self.home = home
        self.noise_std = noise_std
        self.rng = rng
        self.duration = duration
        self.seq = 0
        self.clock_sender: str | None = None
        self.clock_time: float | None = None
        self.ticks = 0
        self.rejected: Counter[str] = Counter()  # clock payloads by PayloadError reason
        self.ignored: Counter[str] = Counter()  # valid ticks not used: other_sender
        self.events: Counter[str] = Counter()  # clock_backwards, clock_jump, unpublishable
        self.finished = False
        self.faults = faults
        self.fault_log = fault_log
        self._fault_events_logged = 0

    def on_clock_payload(self, payload: bytes) -> None:
        """Handle one raw clock payload: decode, check, publish every fix it makes due."""
        try:
            tick = decode_clock(payload)
        except PayloadError as error:
            self.rejected[error.reason] += 1
            return
        if self.clock_sender is None:
            self.clock_sender = tick.sender
        elif tick.sender != self.clock_sender:
            self.ignored["other_sender"] += 1
            return
        self.ticks += 1
        if self.clock_time is not None and tick.stamp < self.clock_time:
            self.events["clock_backwards"] += 1
            print(f"sitl-target: clock went back from {self.clock_time:.3f} to {tick.stamp:.3f} s; "
                  "restarting the target from its initial state", flush=True)
            self.schedule.restart()
            if self.faults is not None:
                self.faults.restart(tick.stamp)
        elif self.clock_time is not None and tick.stamp - self.clock_time > MAX_CLOCK_JUMP:
            self.events["clock_jump"] += 1
            print(f"sitl-target: clock jumped from {self.clock_time:.3f} to {tick.stamp:.3f} s; "
                  "not publishing the gap", flush=True)
            self.schedule.restart()
        self.clock_time = tick.stamp
        for stamp in self.schedule.due(tick.stamp):
            if self.duration is not None and stamp > self.duration + CLOCK_TOLERANCE:
                break
            self.publish(stamp)
        self.deliver(tick.stamp)
        if self.duration is not None and tick.stamp >= self.duration - CLOCK_TOLERANCE:
            self.finished = True

    def deliver(self, now: float) -> None:
        """Send what the link faults have due at simulated time `now` (s) and log their new events."""
        if self.faults is None:
            return
        for payload in self.faults.due(now):
            self.send(payload)
        if self.fault_log is not None:
            self.fault_log.write(self.faults.events[self._fault_events_logged:])
        self._fault_events_logged = len(self.faults.events)

    def on_command_payload(self, payload: bytes) -> None:
        """The action command: "start" begins the scenario at the current simulated time (once)."""
        try:
            command = decode_command(payload)
        except PayloadError as error:
            self.rejected[f"command:{error.reason}"] += 1
            return
        if command.command != "start":
            self.ignored[f"command:{command.command}"] += 1
            return
        if self.clock_time is not None and not (
                self.clock_time - COMMAND_MAX_AGE <= command.stamp <= self.clock_time + COMMAND_MAX_SKEW):
            self.rejected["command:future_stamp" if command.stamp > self.clock_time else "command:too_old"] += 1
            return
        if math.isinf(self.truth.start_time):
            self.truth.start_time = self.clock_time if self.clock_time is not None else command.stamp
            print(f"sitl-target: start command from {command.sender}; scenario starts at t={self.truth.start_time:.3f} s",
                  flush=True)
        else:
            self.ignored["command:start_again"] += 1

    def publish(self, stamp: float) -> None:
        """Publish the fix of simulated time `stamp` (s): true position + N(0, noise_std^2 I) m, in the frame."""
        scenario_time, position, velocity = self.truth.at(stamp)
        measured = position + self.rng.normal(0.0, self.noise_std, 3) if self.noise_std > 0 else position
        published = ned_to_geodetic(measured, self.home) if self.frame == "geodetic" else measured
        fix = TargetFix(self.sender, self.seq, stamp, self.frame, published, velocity, self.epoch)
        try:
            payload = encode_target_fix(fix)
        except PayloadError as error:  # e.g. the target flew out of the schema's ranges
            if not self.events["unpublishable"]:
                print(f"sitl-target: cannot publish the fix at t={stamp:.3f} s: {error}", flush=True)
            self.events["unpublishable"] += 1
            return
        if self.faults is None:
            self.send(payload)
        else:  # scenario time is negative (-inf while waiting for the start command) before the scenario
            self.faults.offer(stamp, payload, stamp - self.truth.start_time)
        self.log.fix(fix, scenario_time, position, velocity)
        self.seq += 1


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `sitl-target` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="sitl-target", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_SCENARIO, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (the plant); repeatable")
    parser.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on, loopback only (default tcp/127.0.0.1:0); repeatable")
    add_zenoh_security_arguments(parser, "target")
    parser.add_argument("--rate", type=float, default=None, help="fixes per simulated second (default: [sensor] rate_hz)")
    parser.add_argument("--frame", choices=("geodetic", "ned"), default=None,
                        help="publish [lat, lon, alt AMSL] or local [n, e, d] m (default: [link] fix_frame)")
    parser.add_argument("--noise-std", type=float, default=None,
                        help="GNSS-like Gaussian position noise, m, per NED axis (default: [link] fix_noise_std)")
    parser.add_argument("--sender", default=None, help="target name, key bof/target/<sender>/fix (default: [link] target_sender)")
    parser.add_argument("--start-time", type=float, default=0.0,
                        help="simulated time (s) at which the target starts its scenario; it hovers before")
    parser.add_argument("--wait-for-start", action="store_true",
                        help="hover until a 'start' command arrives on bof/target/<sender>/command (the paper's "
                             "action command); the scenario then starts at that simulated time")
    parser.add_argument("--duration", type=float, default=None, help="stop at this simulated time (s)")
    parser.add_argument("--seed", type=int, default=None, help="noise seed (default: [simulation] seed)")
    parser.add_argument("--log-dir", type=output_folder, default=None, help="write target.csv and faults.jsonl here")
    parser.add_argument("--faults", choices=("on", "off"), default="on",
                        help="inject the scenario's [faults] on the link (default: on); off ignores --fault too")
    parser.add_argument("--fault", action="append", default=[], metavar="KEY=VALUE",
                        help="override a [faults] setting, VALUE in TOML, e.g. loss_probability=0.3 or "
                             "'blackouts=[{start=20,duration=5}]' or burst.mean_burst_s=2; repeatable")
    parser.add_argument("--home", type=float, nargs=3, default=None, metavar=("LAT", "LON", "ALT"),
                        help="geodetic origin of the NED frame, deg deg m AMSL (default: the scenario's [sitl] home)")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    return parser.parse_args(argv)


#: Hz: the fastest fix rate sitl-target publishes (200x the paper's 5 Hz radio; each fix is a Zenoh message and a
#: log row, and 1e300 Hz was accepted and never published a second fix).
MAX_FIX_RATE_HZ = 1000.0


def _check_args(args: argparse.Namespace) -> None:
    def require(ok: bool, message: str) -> None:
        if not ok:
            raise ConfigError(message)

    require(0 < args.rate <= MAX_FIX_RATE_HZ, f"--rate: {args.rate} must be within (0, {MAX_FIX_RATE_HZ:g}] Hz")
    require(math.isfinite(args.noise_std) and args.noise_std >= 0, f"--noise-std: {args.noise_std} must be >= 0 m")
    require(math.isfinite(args.start_time) and args.start_time >= 0, f"--start-time: {args.start_time} must be >= 0 s")
    require(args.duration is None or (math.isfinite(args.duration) and args.duration > 0),
            f"--duration: {args.duration} must be > 0 s")
    require(args.seed is None or args.seed >= 0, f"--seed: {args.seed} must be >= 0")
    try:
        target_fix_key(args.sender)
    except ValueError as error:
        raise ConfigError(f"--sender: {error}") from None
    if args.home is not None:
        latitude, longitude, altitude = args.home
        require(-90 <= latitude <= 90 and -180 <= longitude <= 180 and math.isfinite(altitude),
                f"--home: ({latitude}, {longitude}, {altitude}) is not latitude [-90, 90], longitude [-180, 180], altitude")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        scenario, _ = load_plant_scenario(args.config)
        args.rate = scenario.sensor.rate_hz if args.rate is None else args.rate
        args.frame = scenario.link.fix_frame if args.frame is None else args.frame
        args.noise_std = scenario.link.fix_noise_std if args.noise_std is None else args.noise_std
        args.sender = scenario.link.target_sender if args.sender is None else args.sender
        _check_args(args)
        faults_config = override_faults(scenario.faults, args.fault) if args.faults == "on" else FaultsConfig()
        tls = tls_identity(args.zenoh_tls, "target")
        config = zenoh_config(listen=args.zenoh_listen, connect=args.zenoh_connect, tls=tls,
                              namespace=args.zenoh_namespace)
    except (ConfigError, LinkError) as error:
        print(f"sitl-target: {error}", file=sys.stderr)
        return 2
    home = tuple(args.home) if args.home is not None else tuple(scenario.sitl.home)
    seed = scenario.simulation.seed if args.seed is None else args.seed
    faults = LinkFaults(faults_config, fault_rng(faults_config, seed))
    faults = faults if faults.enabled else None
    try:
        log = TargetLog(args.log_dir, args.frame)
        fault_log = FaultLog(args.log_dir)
    except OSError as error:
        print(f"sitl-target: cannot write the log: {error}", file=sys.stderr)
        return 2
    try:
        session = open_session(config)
    except LinkError as error:
        log.close()
        fault_log.close()
        print(f"sitl-target: {error}", file=sys.stderr)
        return 2

    stop = threading.Event()
    clock_payloads: queue.Queue[bytes] = queue.Queue(CLOCK_QUEUE_SIZE)
    dropped = Counter()

    def on_clock(sample) -> None:  # a Zenoh thread: hand over, decode in the main thread
        try:
            clock_payloads.put_nowait(("clock", sample.payload.to_bytes()))
        except queue.Full:
            dropped["queue_full"] += 1

    def on_command(sample) -> None:
        try:
            clock_payloads.put_nowait(("command", sample.payload.to_bytes()))
        except queue.Full:
            dropped["queue_full"] += 1

    def request_stop(signum, frame) -> None:  # noqa: ARG001
        stop.set()
        arm_exit_deadline("sitl-target", signum)

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    key = target_fix_key(args.sender)
    try:
        fixes = publisher(session, key)
        start_time = math.inf if args.wait_for_start else args.start_time
        target = TargetPublisher(TargetTruth(scenario.target, start_time, seed), FixSchedule(args.rate), fixes.put, log,
                                 args.sender, args.frame, home, args.noise_std, rng=np.random.default_rng(seed),
                                 duration=args.duration, faults=faults, fault_log=fault_log)
        clock = session.declare_subscriber(CLOCK_KEY, on_clock)
        commands = session.declare_subscriber(target_command_key(args.sender), on_command)
        listen = args.zenoh_listen or ["tcp/127.0.0.1:0" if tls is None else "tls/127.0.0.1:0"]
        print(f"sitl-target: {link_security(tls)}", flush=True)
        print(f"sitl-target ready: {scenario.name}, publishing {key} at {args.rate:g} Hz ({args.frame}), "
              f"epoch {target.epoch}, clock {CLOCK_KEY}, zenoh peer listen {listen} connect {args.zenoh_connect}, "
              f"faults: {describe(faults_config) if args.faults == 'on' else 'off'}", flush=True)
        started = time.monotonic()
        said_waiting = False
        while not stop.is_set() and not target.finished:
            keep_alive()
            try:
                payload = clock_payloads.get(timeout=0.1)
            except queue.Empty:
                if target.clock_time is None and not said_waiting and time.monotonic() - started > WAIT_NOTICE_AFTER:
                    said_waiting = True
                    print(f"sitl-target: waiting for the simulation clock on {CLOCK_KEY}", flush=True)
                continue
            kind, payload = payload
            if kind == "command":
                target.on_command_payload(payload)
            else:
                target.on_clock_payload(payload)
        clock.undeclare()
        commands.undeclare()
        fixes.undeclare()
    finally:
        session.close()
        log.close()
        fault_log.close()
        stand_down()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    clock_time = "no clock" if target.clock_time is None else f"t={target.clock_time:.3f}s"
    print(f"sitl-target stopped at {clock_time}: {target.seq} fixes, {target.ticks} clock ticks, "
          f"rejected clock payloads: {dict(target.rejected) or 'none'}, ignored: {dict(target.ignored + dropped) or 'none'}, "
          f"events: {dict(target.events) or 'none'}", flush=True)
    if faults is None:
        print(f"sitl-target faults: {'off' if args.faults == 'off' else 'none configured'}", flush=True)
    else:
        print(f"sitl-target faults: {dict(sorted(faults.counters.items())) or 'none injected'}, "
              f"{faults.pending} still in flight at exit", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
