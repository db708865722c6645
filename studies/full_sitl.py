"""`bof-sitl`: one scenario flown end to end through real processes, real MAVLink and real Zenoh.

    bof-sitl [config/scenarios/constant_velocity.toml] [--speed-factor 2] [--out runs]

The run folder sitl-<scenario>-seed<seed>-<time>/ is created inside --out (default runs/).

Starts, on free loopback ports, the plant (sitl-plant: MAVLink vehicle, simulated
clock on Zenoh), the target simulator (sitl-target: fixes on Zenoh) and the companion
(companion: MAVSDK + Zenoh + the shared pipeline), then acts as the ground station: it
watches the companion's state on Zenoh, prints progress, and sends the target its
"start" (the paper's action command, Fig. 16 network A) once the companion is
following. When the companion has landed it stops everything and writes the run folder:

Each child runs in its own process group; SIGINT (Ctrl-C), SIGTERM and SIGHUP to bof-sitl stop
them all (SIGTERM, SIGKILL after 2.5 s) and still write every summary (termination "interrupted");
if bof-sitl itself dies, the kernel sends each child SIGTERM (studies.processes). The plant streams
ground-station telemetry to udp 127.0.0.1:--gcs-port (default 14550), printed at start.

    plant/ target/ companion/   each process's own logs (companion/mavlink.tlog included)
    summary.json                the same figures of merit as bof-sim (studies.metrics), from the
                                truth logs; figures that do not apply are null
    trajectory.png errors.png   3-D trajectory and errors (paper Fig. 8 style)
    link.png                    target link timeline: fixes received/rejected, bearings used, latency

A scenario with [swarm] is flown by studies.swarm_sitl: one plant and one companion per pursuer, one target.

The terminal's closing block states the truth's outcome beside the health monitor's verdict
(studies.metrics.outcome_lines); the exit status (EXIT_STATUS) is 1 for a flight that diverged by
truth or breached an envelope, even when every process exited cleanly.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from interfaces import link_schema as link
from interfaces import zenoh_transport
from interfaces.records import write_json
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, VehicleConfig, load_scenario
from studies.closed_loop import Termination
from studies.flight_mcap import write_sitl_mcap
from studies.metrics import (convergence_text, outcome_lines, summarize, suspect_warning, termination_name, truth_failed,
                             write_summary)
from interfaces.cli import (LIVE_PORT, SPEED_FACTOR_RANGE, CommandParser, live_port, output_folder, scenario_file,
                            seed_argument, speed_factor_argument)
from studies.processes import ChildProcess, Interrupted, StopSignals, free_port, stop_all
# The run folder's reading and the set-up both runs share (flight_series is used from here too: bof-campaign).
from studies.sitl_runs import (DEFAULT_GCS_PORT, SitlOptions, live_args, Stopped, ZenohNetwork, bearing_only_check,
                               fail_on_early_exit, flight_series, make_run_folder, read_csv, read_json,
                               run_termination, watch)

DEFAULT_SCENARIO = DEFAULT_SCENARIO
GROUND_STATION_ID = "ground-station"
#: bof-sitl --help's epilog
EXIT_STATUS = """exit status: 0 the companion landed (completed, diverged by the health monitor, or aborted) and the flight's truth
is within bounds; 1 the companion failed or no flight figures could be made, a --timeout, or the flight diverged by
truth (range-estimation error RMS over the summary window above [simulation] divergence_rms, default 2 m), came
closer to the target than r_d / 2 or tilted past the vehicle's max_tilt_deg (a swarm: any pursuer); 2 bad arguments;
128 + N stopped by signal N."""


def plot_link(run: Path, engaged_at: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = [json.loads(line) for line in (run / "companion" / "zenoh_rx.jsonl").read_text().splitlines() if line.strip()]
    accepted = [r for r in records if r.get("verdict") == "accepted" and r.get("stamp") is not None]
    rejected = [r for r in records if r.get("verdict") == "rejected" and r.get("sim_time") is not None]
    latency = read_csv(run / "companion" / "latency.csv")
    figure, axes = plt.subplots(2, 1, figsize=(8.0, 5.5), sharex=True)
    stamps = np.array([r["stamp"] for r in accepted]) - engaged_at
    if stamps.size > 1:
        axes[0].plot(stamps[1:], np.diff(stamps), "b.", markersize=3, label="fix interval (accepted)")
    if rejected:
        axes[0].plot(np.array([r["sim_time"] for r in rejected]) - engaged_at, np.zeros(len(rejected)), "rx", label="rejected")
    top = max(0.5, 1.2 * float(np.max(np.diff(stamps)))) if stamps.size > 1 else 1.0
    axes[0].set_ylim(0.0, top)
    axes[0].ticklabel_format(axis="y", useOffset=False)
    axes[0].set_ylabel("interval between fixes [s]")
    axes[0].legend(loc="upper right")
    axes[0].grid(True, alpha=0.3)
    if latency.get("fix_stamp") is not None and latency["fix_stamp"].size:
        axes[1].plot(latency["fix_stamp"] - engaged_at, latency["latency_ms"], "k.", markersize=3)
    axes[1].set_ylabel("fix received -> setpoint sent [ms]")
    axes[1].set_xlabel("time since engagement [s]")
    axes[1].grid(True, alpha=0.3)
    axes[0].set_title("target link")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


class GroundStation:
    """Watches the companion's state on Zenoh and starts the target when the companion follows."""

    def __init__(self, endpoint: str, scenario: Scenario, tls: zenoh_transport.Identity | None = None,
                 namespace: str | None = None) -> None:
        self.scenario = scenario
        self.session = zenoh_transport.open_session(zenoh_transport.zenoh_config("peer", listen=(), connect=(endpoint,),
                                                                                 tls=tls, namespace=namespace))
        self.latest: link.CompanionState | None = None
        self.states = 0
        self.session.declare_subscriber(link.companion_state_key(scenario.link.companion_id), self._on_state)
        self._target_command = zenoh_transport.publisher(self.session, link.target_command_key(scenario.link.target_sender))
        self._companion_command = zenoh_transport.publisher(self.session, link.companion_command_key(scenario.link.companion_id))
        self._seq = 0
        self.epoch = link.new_epoch()  # this ground station's boot id: its commands are bof.command/2
        self.target_started = False
        self.abort_sent = False
        self.engaged_stamp: float | None = None

    def _on_state(self, sample) -> None:
        try:
            self.latest = link.decode_state(sample.payload)
            self.states += 1
        except link.PayloadError:
            pass

    def abort_companion(self, stamp: float) -> None:
        self._seq += 1
        self._companion_command.put(link.encode_command(link.Command(GROUND_STATION_ID, self._seq, stamp, "abort",
                                                                     "ground station --abort-after", epoch=self.epoch)))
        self.abort_sent = True

    def start_target(self, stamp: float) -> None:
        self._seq += 1
        self._target_command.put(link.encode_command(link.Command(GROUND_STATION_ID, self._seq, stamp, "start", epoch=self.epoch)))
        self.target_started = True

    def close(self) -> None:
        self.session.close()


def _figure(value: float | None, spec: str) -> str:
    """A figure of the state for people: '-' where the companion had none (null in the payload)."""
    return "-" if value is None else format(value, spec)


def _progress(state: link.CompanionState | None) -> str:
    """bof-sitl's progress line: the companion's phase; while it follows, the range estimate, its spread and the
    health monitor's word when it calls the estimate suspect; the target fixes accepted and refused, by reason."""
    if state is None:
        return "waiting for the companion"
    text = f"t={state.stamp:6.1f}s phase={state.phase:10s}"
    if state.phase == "following" and state.estimate is not None:
        text += f" range^={_figure(state.estimate.range, '6.1f')} m  sigma_p={_figure(state.estimate.position_std, '5.2f')} m"
        if state.health is not None and state.health.state == "suspect":
            text += f"  estimate SUSPECT ({', '.join(state.health.reasons) or 'no reason given'})"
    return text + f"  fixes {state.link.accepted} ok / {_rejections(state.link.rejected)}"


#: Wall-clock seconds the children need to start and the companion to connect, arm and take off at any speed;
#: --timeout must leave at least this plus the flight's own duration / speed factor.
STARTUP_ALLOWANCE = 20.0
#: Wall-clock seconds each child may take to print its ready line (they start together and share the cores).
STARTUP_TIMEOUT = 60.0


def check_faults(scenario: Scenario, target_faults: list[str] | None) -> None:
    """ConfigError (one line) for an unknown [faults] key or a bad value in --fault KEY=VALUE, exactly as
    sitl-target would refuse it, before any process or folder exists."""
    from sitl_plant.world.link_faults import override_faults

    try:
        override_faults(scenario.faults, target_faults or [])
    except ConfigError:
        raise
    except ValueError as error:
        raise ConfigError(f"--fault: {error}") from None


def minimum_timeout(scenario: Scenario, speed: float) -> float:
    """The shortest --timeout (wall s) that can let the flight finish: startup plus the flight at `speed`."""
    duration = scenario.companion.follow_duration or scenario.simulation.duration
    return STARTUP_ALLOWANCE + duration / speed


def run(config: Path, out: Path, speed_factor: float | None, seed: int | None = None, timeout: float | None = None, *,
        plots: bool = True, quiet: bool = False, abort_after: float | None = None,
        target_faults: list[str] | None = None,
        on_state: Callable[[link.CompanionState | None, float | None], None] | None = None,
        gcs_port: int = DEFAULT_GCS_PORT, stop: StopSignals | None = None,
        secure: bool = False, live: int | None = None) -> tuple[int, Path, dict]:
    """Fly `config` through the three processes; returns (exit code, run folder, summary).

    speed_factor, seed: None takes the scenario's [sitl] speed_factor and [simulation] seed. timeout: wall s
    for the whole flight (at least minimum_timeout; None: (follow duration + 90 s) / speed + 60 s).
    abort_after: send the companion an abort this many simulated seconds after it engaged (> 0).
    target_faults: KEY=VALUE overrides of [faults] for sitl-target (its --fault option).
    on_state: called about every 50 ms of wall time with the companion's latest state payload
    (None before the first) and the vehicle time it engaged at (s; None before), e.g. to show
    progress while `quiet`. gcs_port: UDP port on 127.0.0.1 the plant streams ground-station
    telemetry to. stop: the caller's StopSignals (bof-sitl's main installs one); when it has
    received SIGINT, SIGTERM or SIGHUP the children are stopped at once (SIGTERM, SIGKILL after
    studies.processes.GRACE_PERIOD), the summaries are written (termination "interrupted", no
    plots) and the exit code is 128 + the signal. Arguments are checked (ConfigError) before the
    run folder is made.
    secure: Zenoh with mutual TLS and access control: a development PKI is made in <run>/pki
    and every process (this ground station as role gcs) uses its own role's certificate.
    live: the companion serves its Foxglove live view on this loopback port (0: a free one; pursuer k of a
    swarm on live + k - 1); None: no live view.
    A scenario with [swarm] is flown by studies.swarm_sitl.run_swarm (on_state is not called)."""
    options = SitlOptions(plots=plots, quiet=quiet, abort_after=abort_after, target_faults=target_faults,
                          on_state=on_state, gcs_port=gcs_port, stop=stop, secure=secure,
                          live=live)
    scenario, vehicle = load_scenario(config)
    speed = scenario.sitl.speed_factor if speed_factor is None else speed_factor
    seed = scenario.simulation.seed if seed is None else seed
    check_run(scenario, speed, seed, timeout, options)
    from studies.executors import compile_kernels
    from studies.reporting import say_as

    # here, once: the children then load numba's cache instead of compiling while the clock runs
    compile_kernels(None if quiet else say_as("bof-sitl", sys.stdout))
    if scenario.swarm is not None:  # one plant and one companion per pursuer (studies.swarm_sitl)
        from studies.swarm_sitl import budget_for, check_swarm_run, run_swarm

        check_swarm_run(scenario, abort_after)
        return run_swarm(config, scenario, vehicle, out, speed, seed, budget_for(scenario, speed, timeout), options)
    duration = scenario.companion.follow_duration or scenario.simulation.duration
    budget = timeout if timeout is not None else (duration + 90.0) / speed + 60.0
    return SingleRun(config, scenario, vehicle, out, speed, seed, options).fly(budget)


def check_run(scenario: Scenario, speed: float, seed: int, timeout: float | None, options: SitlOptions) -> None:
    """ConfigError (one line) for a bad seed, --abort-after, --gcs-port, --timeout or --fault, before any process
    or folder exists."""
    if seed < 0:
        raise ConfigError(f"--seed {seed} is negative (seeds are integers >= 0)")
    abort_after = options.abort_after
    if abort_after is not None and not (math.isfinite(abort_after) and abort_after > 0):
        raise ConfigError(f"--abort-after {abort_after:g}: must be > 0 simulated seconds after engagement")
    if not 1 <= options.gcs_port <= 65535:
        raise ConfigError(f"--gcs-port {options.gcs_port} is not a UDP port")
    if options.live is not None and not 0 <= options.live <= 65535 - (scenario.swarm.count - 1 if scenario.swarm else 0):
        raise ConfigError(f"--live {options.live} is not a TCP port (0: any free port)")
    if timeout is not None and not timeout >= minimum_timeout(scenario, speed):
        raise ConfigError(f"--timeout {timeout:g} s is too short: this flight needs at least "
                          f"{minimum_timeout(scenario, speed):.0f} s of wall time at x{speed:g}")
    check_faults(scenario, options.target_faults)


class SingleRun:
    """One pursuer's SITL run, step by step: the run folder and its network (made on construction), the three
    children, the flight watched as the ground station, then the summary read from the run folder (`fly`)."""

    def __init__(self, config: Path, scenario: Scenario, vehicle: VehicleConfig, out: Path, speed: float, seed: int,
                 options: SitlOptions) -> None:
        self.config, self.scenario, self.vehicle = config, scenario, vehicle
        self.speed, self.seed, self.options = speed, seed, options
        self.folder = make_run_folder(out, scenario, seed)
        self.companion_port = free_port()
        self.network = ZenohNetwork.create(self.folder, options.secure)
        write_json(self.folder / "links.json", {"zenoh": self.network.links(),
                                                "mavlink": {"gcs_port": options.gcs_port,
                                                            "companion_port": self.companion_port,
                                                            "signing_required": options.secure}}, indent=2)
        self.live_port = options.live_port()
        self.plant, self.target, self.companion = self._children()
        self.station: GroundStation | None = None
        self.termination = Termination.INTERRUPTED  # until the summary reads it from the run folder
        self._next_print = 0.0

    def _children(self) -> tuple[ChildProcess, ChildProcess, ChildProcess]:
        """The plant, the target and the companion, not started yet."""
        python, config, folder, seed = sys.executable, str(self.config), self.folder, str(self.seed)
        network, zenoh_args = self.network, list(self.network.zenoh_args)
        plant = ChildProcess([python, "-m", "sitl_plant.sitl", "--config", config, "--speed-factor", str(self.speed),
                              "--companion-port", str(self.companion_port), "--gcs-port", str(self.options.gcs_port),
                              "--seed", seed, "--log-dir", str(folder / "plant"), "--zenoh-listen", network.endpoint,
                              "--quiet", *zenoh_args, *network.signing_args],
                             folder / "plant.out", ready="sitl-plant ready")
        target = ChildProcess([python, "-m", "sitl_plant.world.target_publisher", "--config", config, "--zenoh-connect",
                               network.endpoint, "--seed", seed, "--log-dir", str(folder / "target"), "--wait-for-start",
                               *zenoh_args, *self.options.fault_args()],
                              folder / "target.out", ready="sitl-target ready")
        companion = ChildProcess([python, "-m", "companion", "--config", config, "--mavlink",
                                  f"udpin://127.0.0.1:{self.companion_port}", "--zenoh-connect", network.endpoint,
                                  "--seed", seed, "--log-dir", str(folder / "companion"), *zenoh_args,
                                  *live_args(self.live_port)],
                                 folder / "companion.out", ready="companion ready")
        return plant, target, companion

    def fly(self, budget: float) -> tuple[int, Path, dict]:
        """Start the children, watch the flight for at most `budget` wall s, stop them all and write the summary;
        returns (exit code, run folder, summary)."""
        options, network = self.options, self.network
        print(f"bof-sitl: ground station: udp 127.0.0.1:{options.gcs_port} (the plant streams its telemetry there)",
              flush=True)
        print(f"bof-sitl: zenoh {network.endpoint}, " + ("mutual TLS and access control (pki in the run folder)"
              if options.secure else f"plain TCP, unauthenticated, namespace {network.namespace} (other processes "
                                     "join with --zenoh-namespace)"), flush=True)
        if self.live_port is not None:
            print(f"bof-sitl: live view ws://127.0.0.1:{self.live_port} (Foxglove: Open connection)", flush=True)
        code = 1
        stopped: Stopped | None = None
        try:
            # All three start at once, so their start-up overlaps (the target and the companion find the plant's
            # Zenoh listener whenever it is up); the ground station joins once the plant listens.
            for child in (self.plant, self.target, self.companion):
                child.spawn()
            self.plant.wait_ready(STARTUP_TIMEOUT, options.stop)
            self.station = GroundStation(network.endpoint, self.scenario, network.ground_station_tls(),
                                         namespace=network.namespace)
            self.target.wait_ready(STARTUP_TIMEOUT, options.stop)
            self.companion.wait_ready(STARTUP_TIMEOUT, options.stop)
            stopped = watch(lambda: self.companion.running, self._tick, budget, options.stop)
            code = self.companion.process.returncode if stopped is None else 1
        except Interrupted as signal_stop:
            stopped = Stopped.by_signal(signal_stop, options.stop)
            code = 128 + signal_stop.signum
        finally:
            # The companion first, while the plant still answers (it hands the vehicle to the autopilot),
            # then the target and the plant together; each wave bounded by GRACE_PERIOD.
            self.exit_codes = (*stop_all((self.companion,)), *stop_all((self.target, self.plant)))
            if self.station is not None:
                self.station.close()
        summary = self._summary(stopped)
        code = self._judge_flight(summary, stopped is None, code)
        write_summary(self.folder / "summary.json", summary, sort_keys=True)
        return code, self.folder, summary

    def _tick(self) -> None:
        """One look as the ground station: start the target once the companion follows, send the abort when due,
        report progress; RuntimeError when the plant or the target has exited."""
        station, options = self.station, self.options
        state = station.latest
        if state and state.phase == "following" and not station.target_started:
            station.engaged_stamp = state.stamp
            station.start_target(station.engaged_stamp)
        if (options.abort_after is not None and state and station.engaged_stamp is not None and not station.abort_sent
                and state.stamp >= station.engaged_stamp + options.abort_after):
            station.abort_companion(state.stamp)
        if options.on_state is not None:
            options.on_state(state, station.engaged_stamp)
        if not options.quiet and time.monotonic() >= self._next_print:
            self._next_print = time.monotonic() + 2.0
            print(f"bof-sitl: {_progress(state)}", flush=True)
        fail_on_early_exit((child.command[2], child) for child in (self.plant, self.target))

    def _summary(self, stopped: Stopped | None) -> dict:
        """summary.json before the flight's figures: the children's exit codes and summaries, the run's settings,
        and the termination as bof-sitl and the companion saw it."""
        companion_code, target_code, plant_code = self.exit_codes
        children = {child.log_path.stem: child for child in (self.plant, self.target, self.companion)}
        summary: dict = {"companion_exit_code": companion_code, "target_exit_code": target_code,
                         "plant_exit_code": plant_code, "speed_factor": self.speed, "seed": self.seed,
                         "run_folder": str(self.folder), "gcs_port": self.options.gcs_port,
                         "abort_sent": self.station.abort_sent if self.station is not None else False,
                         "interrupted": None if stopped is None else stopped.interrupted,
                         "stopped_after_s": None if stopped is None else stopped.stopped_after(),
                         "zenoh": self.network.summary(children)}
        summary["companion"] = read_json(self.folder / "companion" / "summary.json")
        plant_stats = read_json(self.folder / "plant" / "stats.json")
        if plant_stats is not None:
            summary["plant"] = {k: plant_stats.get(k) for k in ("speed_factor_achieved", "late_ticks", "ticks", "slips")}
            summary["plant"]["mavlink_rejected"] = plant_stats.get("mavlink", {}).get("rejected")
        else:
            summary["plant"] = None
        self.termination = run_termination(self.folder, summary["companion"], summary["interrupted"])
        summary["termination"], summary["termination_reason"] = (termination_name(self.termination),
                                                                 self.termination.value)
        return summary

    def _judge_flight(self, summary: dict, plots: bool, code: int) -> int:
        """The flight's figures from the truth logs into `summary` (and its plots, with `plots` and the options'),
        or why there are none; returns the exit code (`code`, 1 when it was 0 and there are no figures)."""
        folder, scenario = self.folder, self.scenario
        try:
            if summary["companion"] is None:
                raise RuntimeError("the companion wrote no summary; see companion.out")
            series, engaged_at = flight_series(folder)
            summary["flight"] = summarize(series, scenario, self.termination, self.vehicle)
            summary["flight"]["engaged_at_sim_time"] = engaged_at
            summary["termination"], summary["termination_reason"] = (summary["flight"]["termination"],
                                                                     summary["flight"]["termination_reason"])
            summary["bearing_only"] = bearing_only_check(folder)
            mcap_error = write_sitl_mcap(folder, summary["flight"], scenario.guidance.desired_range)
            if mcap_error:
                summary["mcap_error"] = mcap_error
            if self.options.plots and plots:
                from studies.plots import plot_errors, plot_trajectories

                plot_trajectories(series, folder / "trajectory.png", f"{scenario.name} (SITL)")
                plot_errors(series, scenario.guidance.desired_range, folder / "errors.png", f"{scenario.name} (SITL)",
                            summary["flight"])
                plot_link(folder, engaged_at, folder / "link.png")
        except (RuntimeError, FileNotFoundError, KeyError, ValueError, IndexError) as error:
            summary["flight"] = None
            summary["flight_error"] = str(error)
            code = code or 1
            # the truth and whatever the companion logged, even without figures
            mcap_error = write_sitl_mcap(folder, None, scenario.guidance.desired_range)
            if mcap_error:
                summary["mcap_error"] = mcap_error
        return code


def _rejections(rejected: dict[str, int]) -> str:
    """'3 rejected (no_clock 3)': the refused fixes and their reasons, most frequent first."""
    reasons = ", ".join(f"{reason} {count}" for reason, count in sorted(rejected.items(), key=lambda item: -item[1]))
    return f"{sum(rejected.values())} rejected" + (f" ({reasons})" if reasons else "")


def format_summary(summary: dict) -> str:
    flight = summary.get("flight")
    lines = [f"run folder: {summary['run_folder']}",
             f"termination: {summary.get('termination')}, {summary.get('termination_reason')}"]
    zenoh = summary.get("zenoh") or {}
    if zenoh.get("secure"):
        refused = ", ".join(f"{name} {count}" for name, count in zenoh["tls_refused"].items())
        lines.append(f"  zenoh: mutual TLS + access control; TLS handshakes refused: {refused}")
        lines.append(f"  MAVLink: signing required on the ground-station link (MAV_SIGN_CFG=1); MAVProxy: "
                     f"signing key <the passphrase in {summary['run_folder']}/pki/mavlink_signing_passphrase.txt>")
    elif zenoh:
        lines.append(f"  zenoh: plain TCP, unauthenticated, namespace {zenoh.get('namespace')} "
                     "(--secure for mutual TLS and access control)")
    if not flight:
        lines.append(f"no flight figures: {summary.get('flight_error')}")
        return "\n".join(lines)
    companion = summary["companion"]
    latency = companion["latency_fix_to_setpoint_ms"]
    lines += [
        f"  range error vs r_d = {flight['desired_range']:g} m (last {flight['summary_window']:g} s): rms {flight['range_error_rms']:.3f} m",
        f"  range estimation error: rms {flight['range_estimation_error_rms']:.3f} m, max {flight['range_estimation_error_max_abs']:.3f} m",
        f"  position / velocity estimation: rms {flight['position_estimation_error_rms']:.3f} m, {flight['velocity_estimation_error_rms']:.3f} m/s",
        f"  {convergence_text(flight, after=' after engagement')}",
        f"  minimum range {flight['min_range']:.2f} m, max tilt {flight['max_tilt_deg']:.1f} deg",
        f"  link: {companion['link']['accepted']} fixes accepted, {_rejections(companion['link']['rejected'])}, "
        f"{companion['link']['bearings_used']} bearings used",
        f"  fix received -> bearing into the estimator: p50 {companion['latency_fix_to_estimator_ms']['p50']:.2f} ms, "
        f"p99 {companion['latency_fix_to_estimator_ms']['p99']:.2f} ms",
        f"  fix received -> next setpoint sent: p50 {latency['p50']:.2f} ms, p99 {latency['p99']:.2f} ms",
        f"  control deadlines: {companion['deadline_misses']} of {companion['setpoints_sent']} setpoints late  "
        + ("ok" if companion["deadline_misses"] == 0 else "MISSED (a setpoint out after the next tick was due)"),
        f"  plant: x{summary['plant']['speed_factor_achieved']} achieved (asked x{summary['speed_factor']:g}), "
        f"MAVLink rejected {summary['plant']['mavlink_rejected'] or 'none'}",
    ]
    live = companion.get("live_view")
    if live:
        cost = live["publish_us"]
        lines.append(f"  live view {live['url']}: {live['samples_published']} samples published, "
                     f"p50 {cost['p50']:.0f} us, p99 {cost['p99']:.0f} us per sample")
    warning = suspect_warning(flight, companion.get("health_reasons_at_end", ()))
    if warning:
        lines.append(f"  {warning}")
    lines += outcome_lines({**flight, "envelope": companion.get("envelope")})
    return "\n".join(lines)


def judged_exit_code(code: int, summary: dict) -> int:
    """bof-sitl's exit status from `run`'s `code` and the run's summary: `code` when it is not 0, else 1 when the
    flight (or any pursuer of a swarm) diverged by truth or breached an envelope (studies.metrics.truth_failed)."""
    if code != 0:
        return code
    flights = list(summary["pursuers"]) if "pursuers" in summary else [summary.get("flight") or {}]
    return 1 if any(truth_failed(flight) for flight in flights) else 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-sitl` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-sitl", description=__doc__.split("\n\n")[0], epilog=EXIT_STATUS)
    parser.add_argument("config", nargs="?", type=scenario_file, default=DEFAULT_SCENARIO,
                        help="scenario TOML (default: %(default)s)")
    parser.add_argument("--speed-factor", type=speed_factor_argument, default=None,
                        help=f"simulated seconds per wall second, within {SPEED_FACTOR_RANGE} (default: the scenario's "
                             "[sitl] speed_factor)")
    parser.add_argument("--seed", type=seed_argument, default=None,
                        help="seed of the plant's, target's and companion's noise, an integer >= 0 (default: the "
                             "scenario's [simulation] seed)")
    parser.add_argument("--out", type=output_folder, default=Path("runs"),
                        help="parent folder: the run folder sitl-<scenario>-seed<seed>-<time>/ is created inside it "
                             "(default: %(default)s)")
    parser.add_argument("--timeout", type=float, default=None,
                        help="wall-clock limit for the whole flight, s, at least 20 s + the flight's duration / speed "
                             "factor (default: (follow duration + 90 s) / speed factor + 60 s)")
    parser.add_argument("--no-plots", action="store_true",
                        help="skip trajectory.png, errors.png and link.png (default: draw them)")
    parser.add_argument("--fault", action="append", default=None, metavar="KEY=VALUE",
                        help="override a [faults] setting of the target link (sitl-target --fault), e.g. "
                             "loss_probability=0.3; repeatable; checked before anything starts (default: the "
                             "scenario's [faults])")
    parser.add_argument("--abort-after", type=float, default=None,
                        help="as the ground station, send the companion 'abort' this many simulated seconds (> 0) "
                             "after it engages (default: never)")
    parser.add_argument("--gcs-port", type=int, default=DEFAULT_GCS_PORT,
                        help="UDP port on 127.0.0.1 the plant streams ground-station telemetry to (QGroundControl, "
                             "MAVProxy) (default: %(default)s)")
    parser.add_argument("--secure", action="store_true",
                        help="Zenoh with mutual TLS and access control (a development PKI in <run>/pki, every process "
                             "with its own certificate) and MAVLink 2 signing required on the plant's ground-station "
                             "link (key and passphrase in <run>/pki) (default: plain TCP, unauthenticated, unsigned)")
    parser.add_argument("--live", type=live_port, nargs="?", const=LIVE_PORT, default=None, metavar="PORT",
                        help=f"the companion serves the flight live to Foxglove (Open connection, ws://127.0.0.1:PORT): "
                             f"port {LIVE_PORT} without PORT, 0 for any free port (printed); pursuer k of a swarm on "
                             "PORT + k - 1. Off by default")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress line every 2 s of wall time, only the final summary (default: print them)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.abort_after is not None and not (math.isfinite(args.abort_after) and args.abort_after > 0):
        parser.error(f"--abort-after {args.abort_after:g}: must be > 0 simulated seconds after engagement")
    if not 1 <= args.gcs_port <= 65535:
        parser.error(f"--gcs-port {args.gcs_port} is not a UDP port")
    with StopSignals() as stop:
        try:
            code, folder, summary = run(args.config, args.out, args.speed_factor, args.seed, args.timeout,
                                        plots=not args.no_plots, quiet=args.quiet, abort_after=args.abort_after,
                                        target_faults=args.fault, gcs_port=args.gcs_port, stop=stop,
                                        secure=args.secure, live=args.live)
        except ConfigError as error:
            parser.error(str(error))
    if summary.get("interrupted"):
        print(f"bof-sitl: {summary['interrupted']}: every process stopped {summary['stopped_after_s']} s after it, "
              f"summaries written", file=sys.stderr)
    if "pursuers" in summary:
        from studies.swarm_sitl import format_swarm_sitl_summary

        print(format_swarm_sitl_summary(summary))
    else:
        print(format_summary(summary))
    return judged_exit_code(code, summary)


if __name__ == "__main__":
    sys.exit(main())
