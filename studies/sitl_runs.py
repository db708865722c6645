"""What `bof-sitl`'s single-pursuer run (studies.full_sitl) and its swarm run (studies.swarm_sitl) share.

Reading a run folder: the children's CSV logs (read_csv) and JSON summaries (read_json), the engaged
flight as a bof-sim style series (flight_series), what the estimator was given (bearing_only_check) and
what ended the flight (run_termination).

Setting a run up and watching it: the options a run takes besides its scenario, speed and seed
(SitlOptions), the run folder (make_run_folder), the Zenoh network and MAVLink signing every child
joins (ZenohNetwork, make_signing_key), and the wait for the companions to end (watch, Stopped).

Both run modules import this one; it imports neither (the import-linter contract in pyproject.toml).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import secrets
import signal
import socket
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from interfaces.run_folders import new_run_folder
from interfaces.pki import make_pki
from interfaces import zenoh_transport
from interfaces.scenario import Scenario
from studies.closed_loop import Termination
from studies.processes import ChildProcess, Interrupted, StopSignals, free_port

#: The ground-station port the plant streams to by default (QGroundControl and MAVProxy listen there).
DEFAULT_GCS_PORT = 14550
#: Wall s between two looks at the children while the flight runs.
WATCH_PERIOD = 0.05


# --- reading a run folder ------------------------------------------------------------------------------------


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A child's CSV log as {column: array}: numbers as floats (empty cells NaN), other columns as strings;
    a line cut by an interruption (the wrong number of cells) is left out."""
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


def interp(times: np.ndarray, source_times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Every column of `values` (sampled at `source_times`) linearly interpolated at `times`."""
    return np.column_stack([np.interp(times, source_times, values[:, i]) for i in range(values.shape[1])])


def read_json(path: Path) -> dict | None:
    """A child's JSON summary, or None when it is missing or cut (a child killed before writing it)."""
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def flight_series(run: Path, target_folder: Path | None = None) -> tuple[dict[str, np.ndarray], float]:
    """The engaged part of the flight as a bof-sim style series (time since engagement),
    truth interpolated from the plant's and target's logs at the companion's sample times.
    Returns (series, engagement time in simulated seconds). target_folder: where target.csv is
    (default: run / "target"; a swarm run has one target for every pursuer's folder)."""
    companion = read_csv(run / "companion" / "series.csv")
    plant = read_csv(run / "plant" / "vehicle.csv")
    target = read_csv((run / "target" if target_folder is None else target_folder) / "target.csv")
    engaged = np.isfinite(companion["est_x"]) & (companion["phase"] == "following")
    if not engaged.any():
        raise RuntimeError("the companion never engaged; see companion/events.jsonl")
    t = companion["time"][engaged]
    t0 = float(t[0])
    stack = lambda source, keys: np.column_stack([source[k] for k in keys])  # noqa: E731
    pursuer = interp(t, plant["time"], stack(plant, ("x", "y", "z")))
    pursuer_velocity = interp(t, plant["time"], stack(plant, ("vx", "vy", "vz")))
    q = interp(t, plant["time"], stack(plant, ("qw", "qx", "qy", "qz")))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    forward = np.column_stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])
    down_z = 1 - 2 * (x * x + y * y)
    target_time = target["stamp"]
    target_position = interp(t, target_time, stack(target, ("true_n", "true_e", "true_d")))
    target_velocity = interp(t, target_time, stack(target, ("true_vn", "true_ve", "true_vd")))
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
    companion = read_csv(run / "companion" / "series.csv")
    inputs = read_csv(run / "companion" / "bearings.csv")
    bearings = np.column_stack([inputs[k] for k in ("direction_x", "direction_y", "direction_z")])
    norms = np.linalg.norm(bearings, axis=1)
    return {
        "bearings_logged": int(len(norms)),
        "bearing_norm_min": float(norms.min()) if norms.size else math.nan,
        "bearing_norm_max": float(norms.max()) if norms.size else math.nan,
        "range_inputs_logged": (int(np.count_nonzero(np.isfinite(inputs["range"]))) if "range" in inputs else 0)
        + sum(1 for key in companion if "range" in key and key != "range_estimate"),
    }


def run_termination(folder: Path, companion_summary: dict | None, interrupted: str | None) -> Termination:
    """What ended the flight, from bof-sitl's own view and the companion's phase log (before the estimate's
    verdict, which studies.metrics.summarize adds: a completed flight suspect at the end is DIVERGED).
    folder: the one pursuer's folder (its companion/events.jsonl)."""
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


# --- setting a run up and watching it ------------------------------------------------------------------------


@dataclass(frozen=True)
class SitlOptions:
    """What a SITL run takes besides its scenario, speed factor and seed (studies.full_sitl.run documents each):
    plots, quiet, abort_after (one pursuer only), target_faults (sitl-target --fault KEY=VALUE), on_state (the
    single run's progress callback), gcs_port, stop (the caller's StopSignals) and secure (mutual TLS, signing)."""

    plots: bool = True
    quiet: bool = False
    abort_after: float | None = None
    target_faults: tuple[str, ...] | list[str] | None = None
    on_state: Callable | None = None
    gcs_port: int = DEFAULT_GCS_PORT
    stop: StopSignals | None = None
    secure: bool = False
    live: int | None = None

    def live_port(self, pursuer: int = 1) -> int | None:
        """The loopback port pursuer `pursuer`'s companion serves its live view on (a free one for 0), or None."""
        if self.live is None:
            return None
        return free_port(socket.SOCK_STREAM) if self.live == 0 else self.live + pursuer - 1

    def fault_args(self) -> list[str]:
        """sitl-target's --fault options."""
        return [arg for fault in (self.target_faults or []) for arg in ("--fault", fault)]


def live_args(port: int | None) -> list[str]:
    """The companion's --live option for a live view on loopback `port` (none for None)."""
    return [] if port is None else ["--live", str(port)]


def make_run_folder(out: Path, scenario: Scenario, seed: int) -> Path:
    """The run folder sitl-<scenario>-seed<seed>-<time>/ inside `out`, made."""
    return new_run_folder(out, f"sitl-{scenario.name}-seed{seed}")


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


@dataclass(frozen=True)
class ZenohNetwork:
    """The run's one Zenoh network (every child joins it) and the plants' MAVLink signing.

    endpoint: where the first plant listens (tcp or tls on a free loopback port). A plain run gets a namespace
    of its own, so that it never hears another run on this machine (zenoh_transport.check_namespace says why);
    a secure run is isolated by its own CA already (a development PKI in <run>/pki). zenoh_args: the
    options every child takes to join; signing_args: the plants' (signing required, secure runs only)."""

    endpoint: str
    namespace: str | None
    pki_folder: Path
    secure: bool
    zenoh_args: tuple[str, ...]
    signing_args: tuple[str, ...]

    @classmethod
    def create(cls, folder: Path, secure: bool) -> "ZenohNetwork":
        """A network for the run in `folder`: a free port, and with `secure` the PKI and the signing key made."""
        endpoint = f"{'tls' if secure else 'tcp'}/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        pki_folder = folder / "pki"
        namespace = None if secure else f"bof-sitl-{secrets.token_hex(4)}"
        zenoh_args = ("--zenoh-tls", str(pki_folder)) if secure else ("--zenoh-namespace", namespace)
        signing_args: tuple[str, ...] = ()
        if secure:
            make_pki(pki_folder)
            signing_args = ("--signing-key", str(make_signing_key(pki_folder)), "--mav-sign-cfg", "1")
        return cls(endpoint, namespace, pki_folder, secure, zenoh_args, signing_args)

    def links(self) -> dict:
        """links.json's "zenoh": where a ground station or a tester joins this run while it flies."""
        return {"endpoint": self.endpoint, "namespace": self.namespace, "secure": self.secure,
                "pki": str(self.pki_folder) if self.secure else None}

    def ground_station_tls(self) -> zenoh_transport.Identity | None:
        """The ground station's identity (role gcs) on a secure network; None on a plain one."""
        return zenoh_transport.tls_identity(self.pki_folder, "gcs") if self.secure else None

    def summary(self, children: dict[str, ChildProcess]) -> dict:
        """summary.json's "zenoh": with `secure`, the refused TLS handshakes as each child's Zenoh logged them
        (ACL denials are silent at the receiver, see interfaces.zenoh_transport)."""
        return {"secure": self.secure, "endpoint": self.endpoint, "namespace": self.namespace,
                "tls_refused": {name: zenoh_transport.count_tls_refusals(child.output())
                                for name, child in children.items()} if self.secure else None}


@dataclass(frozen=True)
class Stopped:
    """Why a run stopped before its companions ended: `interrupted` as summary.json says it (a signal's name or
    the timeout), `at` the monotonic time it happened, `signum` the signal (None for a timeout)."""

    interrupted: str
    at: float
    signum: int | None = None

    @classmethod
    def by_signal(cls, signal_stop: Interrupted, stop: StopSignals | None) -> "Stopped":
        """The run stopped by the signal `signal_stop` carries (received by `stop`, when there is one)."""
        return cls(signal.Signals(signal_stop.signum).name,
                   stop.received_at if stop is not None else time.monotonic(), signal_stop.signum)

    def stopped_after(self) -> float:
        """Wall s from the stop to now (summary.json's stopped_after_s, once every child has been stopped)."""
        return round(time.monotonic() - self.at, 3)


def watch(running: Callable[[], bool], tick: Callable[[], None], budget: float,
          stop: StopSignals | None) -> Stopped | None:
    """Call `tick` every WATCH_PERIOD wall s while `running()`: None once it is false, a timeout Stopped when
    `budget` wall s have passed first. `stop`'s Interrupted (a signal received) and whatever `tick` raises
    propagate."""
    deadline = time.monotonic() + budget
    while running():
        if stop is not None:
            stop.check()
        if time.monotonic() > deadline:
            return Stopped(f"timeout after {budget:.0f} s of wall time", time.monotonic())
        tick()
        time.sleep(WATCH_PERIOD)
    return None


def fail_on_early_exit(children: Iterable[tuple[str, ChildProcess]]) -> None:
    """RuntimeError with the child's last output when one of `children` (name, child) has exited."""
    for name, child in children:
        if not child.running:
            raise RuntimeError(f"{name} exited early:\n{child.output()[-2000:]}")
