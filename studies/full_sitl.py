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
import hashlib
import json
import math
import os
import secrets
import signal
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from interfaces import link_schema as link
from interfaces import zenoh_transport
from interfaces.pki import make_pki
from interfaces.records import write_json
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, load_scenario
from studies.closed_loop import Termination
from studies.metrics import (convergence_text, outcome_lines, summarize, suspect_warning, termination_name, truth_failed,
                             write_summary)
from interfaces.cli import SPEED_FACTOR_BOUNDS, output_folder, scenario_file, seed_argument
from studies.processes import ChildProcess, Interrupted, StopSignals, free_port, stop_all

DEFAULT_SCENARIO = DEFAULT_SCENARIO
GROUND_STATION_ID = "ground-station"
#: bof-sitl --help's epilog
EXIT_STATUS = """exit status: 0 the companion landed (completed, diverged by the health monitor, or aborted) and the flight's truth
is within bounds; 1 the companion failed or no flight figures could be made, a --timeout, or the flight diverged by
truth (range-estimation error RMS over the summary window above [simulation] divergence_rms, default 2 m), came
closer to the target than r_d / 2 or tilted past the vehicle's max_tilt_deg (a swarm: any pursuer); 2 bad arguments;
128 + N stopped by signal N."""


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    columns: dict[str, list] = {name: [] for name in header}
    for line in lines[1:]:
        values = line.split(",")
        if len(values) != len(header):
            continue  # a line cut by an interruption
        for name, value in zip(header, values):
            columns[name].append(value)
    out = {}
    for name, values in columns.items():
        try:
            out[name] = np.array([float(v) if v != "" else math.nan for v in values])
        except ValueError:
            out[name] = np.array(values)
    return out


def _interp(times: np.ndarray, source_times: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(times, source_times, values[:, i]) for i in range(values.shape[1])])


def flight_series(run: Path, target_folder: Path | None = None) -> tuple[dict[str, np.ndarray], float]:
    """The engaged part of the flight as a bof-sim style series (time since engagement),
    truth interpolated from the plant's and target's logs at the companion's sample times.
    Returns (series, engagement time in simulated seconds). target_folder: where target.csv is
    (default: run / "target"; a swarm run has one target for every pursuer's folder)."""
    companion = _read_csv(run / "companion" / "series.csv")
    plant = _read_csv(run / "plant" / "vehicle.csv")
    target = _read_csv((run / "target" if target_folder is None else target_folder) / "target.csv")
    engaged = np.isfinite(companion["est_x"]) & (companion["phase"] == "following")
    if not engaged.any():
        raise RuntimeError("the companion never engaged; see companion/events.jsonl")
    t = companion["time"][engaged]
    t0 = float(t[0])
    stack = lambda source, keys: np.column_stack([source[k] for k in keys])  # noqa: E731
    pursuer = _interp(t, plant["time"], stack(plant, ("x", "y", "z")))
    pursuer_velocity = _interp(t, plant["time"], stack(plant, ("vx", "vy", "vz")))
    q = _interp(t, plant["time"], stack(plant, ("qw", "qx", "qy", "qz")))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    forward = np.column_stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])
    down_z = 1 - 2 * (x * x + y * y)
    target_time = target["stamp"]
    target_position = _interp(t, target_time, stack(target, ("true_n", "true_e", "true_d")))
    target_velocity = _interp(t, target_time, stack(target, ("true_vn", "true_ve", "true_vd")))
    estimate_position = np.column_stack([companion[k][engaged] for k in ("est_x", "est_y", "est_z")])
    estimate_velocity = np.column_stack([companion[k][engaged] for k in ("est_vx", "est_vy", "est_vz")])
    relative = target_position - pursuer
    series = {
        "time": t - t0,
        "pursuer_position": pursuer,
        "pursuer_velocity": pursuer_velocity,
        "pursuer_forward": forward,
        "pursuer_down_z": down_z,
        "target_position": target_position,
        "target_velocity": target_velocity,
        "estimate_position": estimate_position,
        "estimate_velocity": estimate_velocity,
        "range": np.linalg.norm(relative, axis=1),
        "range_estimate": np.linalg.norm(estimate_position - pursuer, axis=1),
        "pursuer_tilt": np.degrees(np.arccos(np.clip(down_z, -1.0, 1.0))),
    }
    # The companion's windowed FIM (section V), -inf while singular, as bof-sim logs it.
    # ... and its filter-health verdict (1 suspect, 0 ok, NaN before the first correction).
    for key in ("observability_log_det", "observability_min_eigenvalue", "health_suspect"):
        if key in companion:
            series[key] = companion[key][engaged]
    horizontal = forward[:, :2]
    los = relative[:, :2]
    norms = np.linalg.norm(horizontal, axis=1) * np.linalg.norm(los, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        series["heading_error"] = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", horizontal, los) / norms, -1.0, 1.0)))
    return series, t0


def bearing_only_check(run: Path) -> dict:
    """What the estimator was given: every bearing in the companion's estimator-input log is a
    direction (norm ~1, the noise of eq. (4) aside). range_inputs_logged counts the bearings that
    carried a measured range (only with a [sensor] range_noise_std) plus any range input column
    in the series log; a bearing-only flight has 0."""
    companion = _read_csv(run / "companion" / "series.csv")
    inputs = _read_csv(run / "companion" / "bearings.csv")
    bearings = np.column_stack([inputs[k] for k in ("direction_x", "direction_y", "direction_z")])
    norms = np.linalg.norm(bearings, axis=1)
    return {
        "bearings_logged": int(len(norms)),
        "bearing_norm_min": float(norms.min()) if norms.size else math.nan,
        "bearing_norm_max": float(norms.max()) if norms.size else math.nan,
        "range_inputs_logged": (int(np.count_nonzero(np.isfinite(inputs["range"]))) if "range" in inputs else 0)
        + sum(1 for key in companion if "range" in key and key != "range_estimate"),
    }


def plot_link(run: Path, engaged_at: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = [json.loads(line) for line in (run / "companion" / "zenoh_rx.jsonl").read_text().splitlines() if line.strip()]
    accepted = [r for r in records if r.get("verdict") == "accepted" and r.get("stamp") is not None]
    rejected = [r for r in records if r.get("verdict") == "rejected" and r.get("sim_time") is not None]
    latency = _read_csv(run / "companion" / "latency.csv")
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
    if state is None:
        return "waiting for the companion"
    text = f"t={state.stamp:6.1f}s phase={state.phase:10s}"
    if state.estimate is not None:
        text += f" range^={_figure(state.estimate.range, '6.1f')} m  sigma_p={_figure(state.estimate.position_std, '5.2f')} m"
    text += f"  fixes {state.link.accepted} ok / {sum(state.link.rejected.values())} rejected"
    return text


#: Wall-clock seconds the children need to start and the companion to connect, arm and take off at any speed;
#: --timeout must leave at least this plus the flight's own duration / speed factor.
STARTUP_ALLOWANCE = 20.0
#: The ground-station port the plant streams to by default (QGroundControl and MAVProxy listen there).
DEFAULT_GCS_PORT = 14550


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


def _termination(folder: Path, companion_summary: dict | None, interrupted: str | None) -> Termination:
    """What ended the flight, from bof-sitl's own view and the companion's phase log (before the estimate's
    verdict, which studies.metrics.summarize adds: a completed flight suspect at the end is DIVERGED)."""
    if interrupted is not None:
        return Termination.INTERRUPTED
    events_path = folder / "companion" / "events.jsonl"
    phases, gave_up = [], False
    if events_path.exists():
        for line in events_path.read_text().splitlines():
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut by an interruption
            if event.get("kind") == "phase":
                phases.append(event.get("phase"))
            # The autopilot took over (link loss, left offboard) and the companion did not resume.
            gave_up |= event.get("kind") == "vehicle_link" and str(event.get("detail", "")).startswith("not resuming")
    if "aborting" in phases or (companion_summary or {}).get("abort_requested"):
        return Termination.ABORTED
    if companion_summary is None or companion_summary.get("phase") != "done" or gave_up or "following" not in phases:
        return Termination.FAILSAFE
    return Termination.COMPLETED


def run(config: Path, out: Path, speed_factor: float | None, seed: int | None, timeout: float | None,
        plots: bool = True, quiet: bool = False, abort_after: float | None = None,
        target_faults: list[str] | None = None,
        on_state: Callable[[link.CompanionState | None, float | None], None] | None = None,
        gcs_port: int = DEFAULT_GCS_PORT, stop: StopSignals | None = None,
        secure: bool = False) -> tuple[int, Path, dict]:
    """Fly `config` through the three processes; returns (exit code, run folder, summary).

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
    and every process (this ground station as role gcs) uses its own role's certificate."""
    scenario, vehicle = load_scenario(config)
    speed = scenario.sitl.speed_factor if speed_factor is None else speed_factor
    seed = scenario.simulation.seed if seed is None else seed
    if seed < 0:
        raise ConfigError(f"--seed {seed} is negative (seeds are integers >= 0)")
    if abort_after is not None and not (math.isfinite(abort_after) and abort_after > 0):
        raise ConfigError(f"--abort-after {abort_after:g}: must be > 0 simulated seconds after engagement")
    if not 1 <= gcs_port <= 65535:
        raise ConfigError(f"--gcs-port {gcs_port} is not a UDP port")
    if timeout is not None and not timeout >= minimum_timeout(scenario, speed):
        raise ConfigError(f"--timeout {timeout:g} s is too short: this flight needs at least "
                          f"{minimum_timeout(scenario, speed):.0f} s of wall time at x{speed:g}")
    check_faults(scenario, target_faults)
    from studies.executors import compile_kernels

    compile_kernels()  # here, once: the children then load numba's cache instead of compiling while the clock runs
    if scenario.swarm is not None:  # one plant and one companion per pursuer (studies.swarm_sitl)
        from studies.swarm_sitl import budget_for, check_swarm_run, run_swarm

        check_swarm_run(scenario, abort_after)
        return run_swarm(config, scenario, vehicle, out, speed, seed, budget_for(scenario, speed, timeout), plots, quiet,
                         target_faults, gcs_port, stop, secure)
    folder = out / f"sitl-{scenario.name}-seed{seed}-{time.strftime('%Y%m%d-%H%M%S')}"
    folder.mkdir(parents=True, exist_ok=True)
    companion_port = free_port()
    endpoint = f"{'tls' if secure else 'tcp'}/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    pki_folder = folder / "pki"
    tls_args = ["--zenoh-tls", str(pki_folder)] if secure else []
    # A plain run gets a namespace of its own, so that it never hears another run on this machine
    # (zenoh_transport.check_namespace says why); a secure run is isolated by its own CA already.
    namespace = None if secure else f"bof-sitl-{secrets.token_hex(4)}"
    if namespace is not None:
        tls_args = ["--zenoh-namespace", namespace]
    signing_args: list[str] = []
    if secure:
        make_pki(pki_folder)
        signing_args = ["--signing-key", str(make_signing_key(pki_folder)), "--mav-sign-cfg", "1"]
    # Where a ground station or a tester joins this run while it flies (the summary comes only at the end).
    write_json(folder / "links.json", {"zenoh": {"endpoint": endpoint, "namespace": namespace, "secure": secure,
                                                 "pki": str(pki_folder) if secure else None},
                                       "mavlink": {"gcs_port": gcs_port, "companion_port": companion_port,
                                                   "signing_required": secure}}, indent=2)
    python = sys.executable
    plant = ChildProcess([python, "-m", "sitl_plant.sitl", "--config", str(config), "--speed-factor", str(speed),
                          "--companion-port", str(companion_port), "--gcs-port", str(gcs_port), "--seed", str(seed),
                          "--log-dir", str(folder / "plant"), "--zenoh-listen", endpoint, "--quiet", *tls_args,
                          *signing_args],
                         folder / "plant.out", ready="sitl-plant ready")
    target = ChildProcess([python, "-m", "sitl_plant.world.target_publisher", "--config", str(config), "--zenoh-connect", endpoint,
                           "--seed", str(seed), "--log-dir", str(folder / "target"), "--wait-for-start", *tls_args,
                           *[arg for fault in (target_faults or []) for arg in ("--fault", fault)]],
                          folder / "target.out", ready="sitl-target ready")
    companion = ChildProcess([python, "-m", "companion", "--config", str(config), "--mavlink",
                              f"udpin://127.0.0.1:{companion_port}", "--zenoh-connect", endpoint, "--seed", str(seed),
                              "--log-dir", str(folder / "companion"), *tls_args],
                             folder / "companion.out", ready="companion ready")
    duration = scenario.companion.follow_duration or scenario.simulation.duration
    budget = timeout if timeout is not None else (duration + 90.0) / speed + 60.0
    print(f"bof-sitl: ground station: udp 127.0.0.1:{gcs_port} (the plant streams its telemetry there)", flush=True)
    print(f"bof-sitl: zenoh {endpoint}, " + ("mutual TLS and access control (pki in the run folder)" if secure else
          f"plain TCP, unauthenticated, namespace {namespace} (other processes join with --zenoh-namespace)"), flush=True)
    station = None
    code = 1
    interrupted: str | None = None
    interrupted_at: float | None = None
    try:
        plant.start(stop=stop)
        target.start(stop=stop)
        station = GroundStation(endpoint, scenario, zenoh_transport.tls_identity(pki_folder, "gcs") if secure else None,
                                namespace=namespace)
        companion.start(stop=stop)
        deadline = time.monotonic() + budget
        next_print = 0.0
        while companion.running:
            if stop is not None:
                stop.check()
            if time.monotonic() > deadline:
                interrupted, interrupted_at = f"timeout after {budget:.0f} s of wall time", time.monotonic()
                break
            state = station.latest
            if state and state.phase == "following" and not station.target_started:
                station.engaged_stamp = state.stamp
                station.start_target(station.engaged_stamp)
            if (abort_after is not None and state and station.engaged_stamp is not None and not station.abort_sent
                    and state.stamp >= station.engaged_stamp + abort_after):
                station.abort_companion(state.stamp)
            if on_state is not None:
                on_state(state, station.engaged_stamp)
            if not quiet and time.monotonic() >= next_print:
                next_print = time.monotonic() + 2.0
                print(f"bof-sitl: {_progress(state)}", flush=True)
            for child in (plant, target):
                if not child.running:
                    raise RuntimeError(f"{child.command[2]} exited early:\n{child.output()[-2000:]}")
            time.sleep(0.05)
        code = companion.process.returncode if interrupted is None else 1
    except Interrupted as signal_stop:
        interrupted = signal.Signals(signal_stop.signum).name
        interrupted_at = stop.received_at if stop is not None else time.monotonic()
        code = 128 + signal_stop.signum
    finally:
        # The companion first, while the plant still answers (it hands the vehicle to the autopilot),
        # then the target and the plant together; each wave bounded by GRACE_PERIOD.
        companion_code, = stop_all((companion,))
        target_code, plant_code = stop_all((target, plant))
        if station is not None:
            station.close()
    stopped_after = None if interrupted_at is None else round(time.monotonic() - interrupted_at, 3)
    summary: dict = {"companion_exit_code": companion_code, "target_exit_code": target_code, "plant_exit_code": plant_code,
                     "speed_factor": speed, "seed": seed, "run_folder": str(folder), "gcs_port": gcs_port,
                     "abort_sent": station.abort_sent if station is not None else False,
                     "interrupted": interrupted, "stopped_after_s": stopped_after,
                     # Refused TLS handshakes as each child's Zenoh logged them (secure mode only; ACL
                     # denials are silent at the receiver, see interfaces.zenoh_transport).
                     "zenoh": {"secure": secure, "endpoint": endpoint, "namespace": namespace, "tls_refused": {child.log_path.stem: zenoh_transport.count_tls_refusals(
                         child.output()) for child in (plant, target, companion)} if secure else None}}
    companion_summary = _read_json(folder / "companion" / "summary.json")
    summary["companion"] = companion_summary
    plant_stats = _read_json(folder / "plant" / "stats.json")
    if plant_stats is not None:
        summary["plant"] = {k: plant_stats.get(k) for k in ("speed_factor_achieved", "late_ticks", "ticks", "slips")}
        summary["plant"]["mavlink_rejected"] = plant_stats.get("mavlink", {}).get("rejected")
    else:
        summary["plant"] = None
    termination = _termination(folder, companion_summary, interrupted)
    summary["termination"], summary["termination_reason"] = termination_name(termination), termination.value
    try:
        if companion_summary is None:
            raise RuntimeError("the companion wrote no summary; see companion.out")
        series, engaged_at = flight_series(folder)
        summary["flight"] = summarize(series, scenario, termination, vehicle)
        summary["flight"]["engaged_at_sim_time"] = engaged_at
        summary["termination"], summary["termination_reason"] = (summary["flight"]["termination"],
                                                                 summary["flight"]["termination_reason"])
        summary["bearing_only"] = bearing_only_check(folder)
        if plots and interrupted is None:
            from studies.plots import plot_errors, plot_trajectories

            plot_trajectories(series, folder / "trajectory.png", f"{scenario.name} (SITL)")
            plot_errors(series, scenario.guidance.desired_range, folder / "errors.png", f"{scenario.name} (SITL)")
            plot_link(folder, engaged_at, folder / "link.png")
    except (RuntimeError, FileNotFoundError, KeyError, ValueError, IndexError) as error:
        summary["flight"] = None
        summary["flight_error"] = str(error)
        code = code or 1
    write_summary(folder / "summary.json", summary, sort_keys=True)
    return code, folder, summary


def make_signing_key(folder: Path) -> Path:
    """A MAVLink 2 signing key for the plant's ground-station link, in `folder` (mode 0600).

    The key is the SHA-256 of a random passphrase, which is how MAVProxy derives its key from
    `signing key <passphrase>`, so the passphrase (mavlink_signing_passphrase.txt, also 0600) is
    all a ground station needs. Returns the key file (64 hex characters, sitl-plant --signing-key).
    """
    passphrase = secrets.token_urlsafe(24)
    for name, text in (("mavlink_signing_passphrase.txt", passphrase),
                       ("mavlink_signing.key", hashlib.sha256(passphrase.encode()).hexdigest())):
        descriptor = os.open(folder / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(descriptor, "w") as handle:
            handle.write(text + "\n")
    return folder / "mavlink_signing.key"


def _read_json(path: Path) -> dict | None:
    """A child's JSON summary, or None when it is missing or cut (a child killed before writing it)."""
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


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
        f"  link: {companion['link']['accepted']} fixes accepted, {sum(companion['link']['rejected'].values())} rejected, "
        f"{companion['link']['bearings_used']} bearings used",
        f"  fix received -> bearing into the estimator: p50 {companion['latency_fix_to_estimator_ms']['p50']:.2f} ms, "
        f"p99 {companion['latency_fix_to_estimator_ms']['p99']:.2f} ms",
        f"  fix received -> next setpoint sent: p50 {latency['p50']:.2f} ms, p99 {latency['p99']:.2f} ms; "
        f"deadline misses {companion['deadline_misses']}/{companion['setpoints_sent']}",
        f"  plant: x{summary['plant']['speed_factor_achieved']} achieved (asked x{summary['speed_factor']:g}), "
        f"MAVLink rejected {summary['plant']['mavlink_rejected'] or 'none'}",
    ]
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
    parser = argparse.ArgumentParser(prog="bof-sitl", description=__doc__.split("\n\n")[0], epilog=EXIT_STATUS)
    parser.add_argument("config", nargs="?", type=scenario_file, default=DEFAULT_SCENARIO,
                        help="scenario TOML (default: %(default)s)")
    parser.add_argument("--speed-factor", type=float, default=None,
                        help="simulated seconds per wall second, within [0.5, 20] (default: the scenario's [sitl] "
                             "speed_factor)")
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
    parser.add_argument("--quiet", action="store_true",
                        help="no progress line every 2 s of wall time, only the final summary (default: print them)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    low, high = SPEED_FACTOR_BOUNDS
    if args.speed_factor is not None and not low <= args.speed_factor <= high:
        parser.error(f"--speed-factor must be within [{low:g}, {high:g}] (MAVSDK needs heartbeats; the plant tops out near 20x)")
    if args.abort_after is not None and not (math.isfinite(args.abort_after) and args.abort_after > 0):
        parser.error(f"--abort-after {args.abort_after:g}: must be > 0 simulated seconds after engagement")
    if not 1 <= args.gcs_port <= 65535:
        parser.error(f"--gcs-port {args.gcs_port} is not a UDP port")
    with StopSignals() as stop:
        try:
            code, folder, summary = run(args.config, args.out, args.speed_factor, args.seed, args.timeout,
                                        not args.no_plots, args.quiet, args.abort_after, args.fault,
                                        gcs_port=args.gcs_port, stop=stop, secure=args.secure)
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
