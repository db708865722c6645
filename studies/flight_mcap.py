"""flight.mcap: one flight in Foxglove's well-known schemas (interfaces.flight_channels), from either harness.

    write_flight_mcap(path, flight)       # flight: a FlightRecord, from the in-process series or a SITL run folder
    in_process_record(series, summary, desired_range)
    sitl_record(run_folder, desired_range)

A FlightRecord is the flight as streams, each at its own times in one time base (simulated s of the flight):
the plant's truth, the companion's estimate and outputs, and events. The file is written with foxglove-sdk's MCAP
writer (zstd chunks, with statistics and indexes), the flight's figures in the metadata record "flight".
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import foxglove
import numpy as np

from interfaces.flight_channels import FlightChannels, covariance_from_upper, quaternion_wxyz
from studies.closed_loop import HEALTH_ACTION_CODES, HEALTH_REASON_BITS, TRACK_MODE_CODES

#: The 3-D scene is updated at this rate, Hz (poses and values go in at every logged sample).
SCENE_RATE_HZ = 5.0
#: The plant's truth (500 Hz in SITL) is thinned to this rate, Hz.
TRUTH_RATE_HZ = 50.0
_MODE_NAMES = {code: mode.value for mode, code in TRACK_MODE_CODES.items()}
_ACTION_NAMES = {code: action.value for action, code in HEALTH_ACTION_CODES.items()}


@dataclasses.dataclass
class FlightRecord:
    """One flight as streams; every time in simulated s of the flight (>= 0), arrays row by row.

    pursuer: time (N,), position (N, 3), velocity (N, 3), and the attitude body FRD -> NED as either
    rotation (N, 9) row-major or attitude (N, 4) unit quaternions (w, x, y, z).
    target: time (M,), position (M, 3) (the truth).
    companion: time (K,) and the FlightLog-named columns the companion logged at those times
    (estimate_position, estimate_position_covariance, bearing_direction, command_acceleration,
    thrust_normalized, track_mode, health_suspect, health_reasons, health_nis_ratio, health_action,
    process_noise_boost, model_probabilities; any may be missing), plus pursuer_position at those times.
    events: (time, text, level). link: (time, accepted so far, {reason: rejected so far}).
    metadata: string -> string, the MCAP metadata record "flight" (engaged_at among them)."""

    pursuer: dict[str, np.ndarray]
    target: dict[str, np.ndarray]
    companion: dict[str, np.ndarray]
    events: list[tuple[float, str, str]]
    link: list[tuple[float, int, dict[str, int]]]
    metadata: dict[str, str]
    desired_range: float


def _thinned(times: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of `times` at most one per 1 / rate_hz seconds (the first of each period), the last one kept."""
    if len(times) == 0:
        return np.zeros(0, dtype=int)
    buckets = np.floor(np.asarray(times) * rate_hz + 1e-9)
    keep = np.flatnonzero(np.r_[True, np.diff(buckets) > 0])
    return np.union1d(keep, [len(times) - 1])


def _reasons(bits: float) -> list[str]:
    if not math.isfinite(bits):
        return []
    return [reason for reason, bit in HEALTH_REASON_BITS.items() if int(bits) & bit]


def write_flight_mcap(path: Path, flight: FlightRecord) -> Path:
    """Write `flight` to `path` (replacing it); returns the path. Messages go in time order across channels."""
    path = Path(path)
    path.unlink(missing_ok=True)
    emitter = _Emitter(flight)
    writer = foxglove.open_mcap(path, context=emitter.channels.context)
    try:
        for time_s, kind, index in _timeline(flight):
            emitter.emit(time_s, kind, index)
        writer.write_metadata("flight", flight.metadata)
    finally:
        writer.close()
    return path


# Within one instant: the frame first, then truth, then the companion's row (which reads the truth's latest
# pursuer position for its ray), then the scene, link counts and events.
_ORDER = {"frames": 0, "pursuer": 1, "target": 2, "companion": 3, "scene": 4, "link": 5, "event": 6}


def _timeline(flight: FlightRecord) -> list[tuple[float, str, int]]:
    items: list[tuple[float, str, int]] = [(0.0, "frames", 0)]
    for kind, stream in (("pursuer", flight.pursuer), ("target", flight.target)):
        items += [(float(stream["time"][i]), kind, int(i)) for i in _thinned(stream["time"], TRUTH_RATE_HZ)]
    items += [(float(t), "companion", i) for i, t in enumerate(flight.companion["time"])]
    items += [(float(flight.companion["time"][i]), "scene", int(i)) for i in _thinned(flight.companion["time"], SCENE_RATE_HZ)]
    items += [(float(t), "link", i) for i, (t, _, _) in enumerate(flight.link)]
    items += [(float(t), "event", i) for i, (t, _, _) in enumerate(flight.events)]
    items = [item for item in items if math.isfinite(item[0]) and item[0] >= 0.0]
    items.sort(key=lambda item: (item[0], _ORDER[item[1]], item[2]))
    return items


class _Emitter:
    """Writes a FlightRecord's items on the channels. The per-row figures (attitude quaternions, ranges,
    sigma_r, which values are finite) are computed for whole streams first; rows are then read as lists."""

    def __init__(self, flight: FlightRecord) -> None:
        self.flight = flight
        self.channels = FlightChannels(desired_range=flight.desired_range)
        self.target: list[float] | None = None
        p = flight.pursuer
        if "attitude" in p:
            attitude = np.asarray(p["attitude"], dtype=float)
            down_z = 1.0 - 2.0 * (attitude[:, 1] ** 2 + attitude[:, 2] ** 2)  # R[2, 2] of the unit quaternion
        else:
            rotations = np.asarray(p["rotation"], dtype=float).reshape(-1, 3, 3)
            attitude, down_z = quaternion_wxyz(rotations), rotations[:, 2, 2]
        self.pursuer = {"position": p["position"].tolist(), "attitude": attitude.tolist(),
                        "speed": np.linalg.norm(p["velocity"], axis=1).tolist(),
                        "tilt_deg": np.degrees(np.arccos(np.clip(down_z, -1.0, 1.0))).tolist()}
        self.target_positions = flight.target["position"].tolist()
        c = dict(flight.companion)
        n = len(c["time"])
        if "estimate_position" in c and "pursuer_position" in c:
            offset = c["estimate_position"] - c["pursuer_position"]
            c["range_estimate"] = np.linalg.norm(offset, axis=1)
            if "estimate_position_covariance" in c:
                upper = np.asarray(c["estimate_position_covariance"], dtype=float)
                u = offset / np.where(c["range_estimate"] > 0.0, c["range_estimate"], np.nan)[:, None]
                # u' P u from the upper triangle (xx, xy, xz, yy, yz, zz)
                variance = (upper[:, 0] * u[:, 0] ** 2 + upper[:, 3] * u[:, 1] ** 2 + upper[:, 5] * u[:, 2] ** 2
                            + 2.0 * (upper[:, 1] * u[:, 0] * u[:, 1] + upper[:, 2] * u[:, 0] * u[:, 2]
                                     + upper[:, 4] * u[:, 1] * u[:, 2]))
                c["sigma_r"] = np.sqrt(np.maximum(variance, 0.0))
        #: per column: the rows as lists, None where a value is not finite
        self.rows: dict[str, list] = {}
        for key, values in c.items():
            if key == "time":
                continue
            values = np.asarray(values, dtype=float)
            finite = np.all(np.isfinite(values.reshape(n, -1)), axis=1)
            listed = values.tolist()
            self.rows[key] = [value if ok else None for value, ok in zip(listed, finite.tolist())]

    def _get(self, key: str, index: int):
        column = self.rows.get(key)
        return None if column is None else column[index]

    def emit(self, time_s: float, kind: str, index: int) -> None:
        flight, channels, get = self.flight, self.channels, self._get
        if kind == "frames":
            channels.frames(time_s)
        elif kind == "pursuer":
            p = self.pursuer
            channels.pose("pursuer", time_s, p["position"][index], p["attitude"][index])
            channels.values("/flight/pursuer", time_s, {"speed": p["speed"][index], "tilt_deg": p["tilt_deg"][index]})
        elif kind == "target":
            self.target = self.target_positions[index]
            channels.pose("target", time_s, self.target)
        elif kind == "companion":
            self._companion_row(time_s, index)
        elif kind == "scene":
            upper = get("estimate_position_covariance", index)
            channels.scene(time_s, get("pursuer_position", index), self.target, get("estimate_position", index),
                           None if upper is None else covariance_from_upper(upper), get("bearing_direction", index))
        elif kind == "link":
            _, accepted, rejected = flight.link[index]
            channels.values("/link", time_s, {"accepted": accepted, "rejected": sum(rejected.values()),
                                              "rejected_by_reason": dict(rejected)})
        else:
            _, text, level = flight.events[index]
            channels.event(time_s, text, level)

    def _companion_row(self, time_s: float, index: int) -> None:
        channels, get, desired = self.channels, self._get, self.flight.desired_range
        estimate = get("estimate_position", index)
        if estimate is not None:
            channels.pose("estimate", time_s, estimate)
            values: dict[str, Any] = {"desired_range": desired}
            for key in ("range_estimate", "sigma_r", "range"):
                value = get(key, index)
                if value is not None:
                    values[key] = value
            if "range" in values:
                values["range_error"] = values["range"] - desired
                if "range_estimate" in values:
                    values["range_estimation_error"] = values["range_estimate"] - values["range"]
            channels.values("/flight/range", time_s, values)
        setpoint = get("command_acceleration", index)
        if setpoint is not None:
            thrust = get("thrust_normalized", index)
            channels.values("/setpoint", time_s, {"acc_n": setpoint[0], "acc_e": setpoint[1], "acc_d": setpoint[2],
                                                  **({} if thrust is None else {"thrust_normalized": thrust})})
        models = get("model_probabilities", index)
        if models is not None:
            channels.values("/estimator/models", time_s, dict(zip(("straight", "right", "left"), models)))
        suspect = get("health_suspect", index)
        if suspect is not None:
            reasons, action = get("health_reasons", index), get("health_action", index)
            health: dict[str, Any] = {"suspect": int(suspect), "state": "suspect" if suspect else "ok",
                                      "reasons": [] if reasons is None else _reasons(reasons)}
            for key, name in (("health_nis_ratio", "nis_ratio"), ("process_noise_boost", "process_noise_boost")):
                value = get(key, index)
                if value is not None:
                    health[name] = value
            if action is not None:
                health["action"] = _ACTION_NAMES.get(int(action), str(action))
            channels.values("/health", time_s, health)
        mode = get("track_mode", index)
        if mode is not None:
            channels.values("/track_mode", time_s, {"mode": _MODE_NAMES.get(int(mode), str(mode))})


def _first_estimate_time(times: np.ndarray, estimates: np.ndarray) -> float | None:
    finite = np.flatnonzero(np.all(np.isfinite(estimates), axis=1))
    return None if len(finite) == 0 else float(times[finite[0]])


def _figures_metadata(summary: dict, engaged_at: float | None, harness: str) -> dict[str, str]:
    keys = ("scenario", "seed", "termination", "verdict", "range_estimation_error_rms", "range_error_rms", "min_range",
            "max_tilt_deg", "summary_window", "convergence_time")
    metadata = {"harness": harness, "time_base": "simulated s of the flight",
                "engaged_at": "" if engaged_at is None else repr(engaged_at)}
    metadata.update({key: json.dumps(summary.get(key)) for key in keys if key in summary})
    truth = summary.get("truth") or {}
    for key, name in (("outcome", "outcome"), ("tilt_limit_deg", "max_tilt_limit_deg")):
        if truth.get(key) is not None:
            metadata[name] = str(truth[key])
    return metadata


def in_process_record(series: dict[str, np.ndarray], summary: dict, desired_range: float) -> FlightRecord:
    """bof-sim's flight (studies.closed_loop.FlightLog.series and the summary) as a FlightRecord. The in-process
    flight starts in the air at t = 0; its target is the truth."""
    time = series["time"]
    pursuer = {"time": time, "position": series["pursuer_position"], "velocity": series["pursuer_velocity"],
               "rotation": series["pursuer_rotation"]}
    target = {"time": time, "position": series["target_position"]}
    keys = ("estimate_position", "estimate_position_covariance", "bearing_direction", "command_acceleration",
            "thrust_normalized", "track_mode", "health_suspect", "health_reasons", "health_nis_ratio", "health_action",
            "process_noise_boost", "model_probabilities", "range")
    companion = {"time": time, "pursuer_position": series["pursuer_position"],
                 **{key: series[key] for key in keys if key in series}}
    engaged_at = _first_estimate_time(time, series["estimate_position"])
    events = [] if engaged_at is None else [(engaged_at, "engaged: the estimator is running and following starts", "info")]
    events += [(t, f"track mode {mode}", "warning" if mode != "tracking" else "info")
               for t, mode in summary.get("track_mode_changes", ())]
    events += [(t, f"filter health {state}{' (' + ', '.join(reasons) + ')' if reasons else ''}",
                "warning" if state == "suspect" else "info") for t, state, reasons in summary.get("health_transitions", ())]
    events += [(t, f"link fault {kind}: {detail}", "warning") for t, kind, detail in summary.get("fault_events", ())]
    link = []
    if summary.get("link"):
        link.append((float(time[-1]), int(summary["link"]["accepted"]), dict(summary["link"]["rejected"])))
    return FlightRecord(pursuer, target, companion, sorted(events), link,
                        _figures_metadata(summary, engaged_at, "in-process"), desired_range)


#: events.jsonl kinds written as warnings on /events (the rest are info).
_WARNING_KINDS = ("error", "rejected", "failsafe", "abort", "failed", "lost")
#: A /link message is written at most this often, s (and once at the end).
LINK_PERIOD_S = 0.5


def _event_level(record: dict) -> str:
    kind = str(record.get("kind", ""))
    if kind == "filter_health" and record.get("state") == "suspect":
        return "warning"
    if kind == "track_mode" and record.get("mode") not in (None, "tracking"):
        return "warning"
    return "warning" if any(word in kind for word in _WARNING_KINDS) else "info"


def _jsonl(path: Path) -> list[dict]:
    """A JSON-lines log's records; a line cut by an interruption is skipped."""
    records = []
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        return records
    for line in lines:
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict):
            records.append(record)
    return records


def _link_counts(records: list[dict]) -> list[tuple[float, int, dict[str, int]]]:
    """Cumulative accepted / rejected-by-reason fixes from zenoh_rx.jsonl, at the companion's simulated receipt
    times. Rejections past the first few per reason are logged as once-a-second counts without a simulated time:
    they are counted at the simulated time of the record before them (0 before the vehicle's clock started)."""
    accepted, rejected, out = 0, {}, []
    now, last_written = 0.0, -math.inf
    for record in records:
        stamp = record.get("sim_time")
        if isinstance(stamp, (int, float)) and math.isfinite(stamp):
            now = max(now, float(stamp))
        if record.get("kind") == "suppressed":
            key = str(record.get("key"))
            rejected[key] = rejected.get(key, 0) + int(record.get("count", 0))
        elif record.get("verdict") == "accepted":
            accepted += 1
        elif record.get("verdict") == "rejected":
            key = str(record.get("reason"))
            rejected[key] = rejected.get(key, 0) + 1
        else:
            continue
        if now - last_written >= LINK_PERIOD_S:
            out.append((now, accepted, dict(rejected)))
            last_written = now
    if out and out[-1][1:] != (accepted, rejected):
        out.append((now, accepted, dict(rejected)))
    return out


def sitl_record(run: Path, summary: dict | None, desired_range: float, target_folder: Path | None = None) -> FlightRecord:
    """A bof-sitl run folder's flight as a FlightRecord: the plant's truth (plant/vehicle.csv) and the target's
    (target/target.csv) over the whole flight, the companion's series, events and link log, in the plant's
    simulated time (from its start on the ground). summary: the flight's figures (summary.json's "flight")."""
    from studies.sitl_runs import read_csv

    run = Path(run)
    plant = read_csv(run / "plant" / "vehicle.csv")
    target = read_csv((run / "target" if target_folder is None else target_folder) / "target.csv")
    companion = read_csv(run / "companion" / "series.csv")
    stack = lambda source, keys: np.column_stack([np.asarray(source[k], dtype=float) for k in keys])  # noqa: E731
    attitude = stack(plant, ("qw", "qx", "qy", "qz"))
    attitude /= np.linalg.norm(attitude, axis=1, keepdims=True)
    pursuer = {"time": plant["time"], "position": stack(plant, ("x", "y", "z")),
               "velocity": stack(plant, ("vx", "vy", "vz")), "attitude": attitude}
    truth = {"time": target["stamp"], "position": stack(target, ("true_n", "true_e", "true_d"))}
    time = np.asarray(companion["time"], dtype=float)
    columns = {"time": time, "pursuer_position": stack(companion, ("px", "py", "pz"))}
    pairs = {"estimate_position": ("est_x", "est_y", "est_z"),
             "estimate_position_covariance": ("est_pxx", "est_pxy", "est_pxz", "est_pyy", "est_pyz", "est_pzz"),
             "bearing_direction": ("bearing_x", "bearing_y", "bearing_z"),
             "command_acceleration": ("acc_x", "acc_y", "acc_z"),
             "model_probabilities": ("model_straight", "model_right", "model_left")}
    for key, names in pairs.items():
        if all(name in companion for name in names):
            columns[key] = stack(companion, names)
    for key in ("thrust_normalized", "health_suspect", "health_nis_ratio", "process_noise_boost"):
        if key in companion:
            columns[key] = np.asarray(companion[key], dtype=float)
    codes = {"track_mode": {mode.value: code for mode, code in TRACK_MODE_CODES.items()},
             "health_action": {action.value: code for action, code in HEALTH_ACTION_CODES.items()}}
    for key, table in codes.items():
        if key in companion:
            columns[key] = np.array([table.get(str(value), math.nan) for value in companion[key]], dtype=float)
    # The true range at the companion's samples (the target's truth interpolated at its times).
    if len(truth["time"]) and "estimate_position" in columns:
        true_target = np.column_stack([np.interp(time, truth["time"], truth["position"][:, axis]) for axis in range(3)])
        true_own = np.column_stack([np.interp(time, pursuer["time"], pursuer["position"][:, axis]) for axis in range(3)])
        columns["range"] = np.linalg.norm(true_target - true_own, axis=1)
    following = np.flatnonzero((companion["phase"] == "following") & np.all(np.isfinite(columns.get(
        "estimate_position", np.full((len(time), 3), np.nan))), axis=1)) if "phase" in companion else []
    engaged_at = float(time[following[0]]) if len(following) else None
    events = [] if engaged_at is None else [(engaged_at, "engaged: the estimator is running and following starts", "info")]
    for record in _jsonl(run / "companion" / "events.jsonl"):
        stamp = record.get("time")
        if isinstance(stamp, (int, float)) and math.isfinite(stamp) and stamp >= 0.0:
            events.append((float(stamp), f"{record.get('kind')}: {record.get('detail', '')}", _event_level(record)))
    link = _link_counts(_jsonl(run / "companion" / "zenoh_rx.jsonl"))
    return FlightRecord(pursuer, truth, columns, sorted(events), link,
                        _figures_metadata(summary or {}, engaged_at, "sitl"), desired_range)


def write_sitl_mcap(run: Path, summary: dict | None, desired_range: float, target_folder: Path | None = None) -> str | None:
    """<run>/flight.mcap from a SITL run folder (sitl_record); returns None, or why it could not be written (a
    child's log missing or empty, e.g. a run stopped before the plant started), so a run still gets its summary."""
    try:
        write_flight_mcap(Path(run) / "flight.mcap", sitl_record(run, summary, desired_range, target_folder))
    except (FileNotFoundError, KeyError, ValueError, IndexError) as error:
        return f"no flight.mcap: {type(error).__name__}: {error}"
    return None
