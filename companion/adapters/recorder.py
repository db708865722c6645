"""The companion's run log: every file is written line by line and flushed, so an
interrupted run keeps everything up to the interruption.

    series.csv      one row per own-state sample while engaged: own state, estimate (with its position
                    covariance's upper triangle, est_pxx ... est_pzz, m^2),
                    bearing used (if any), command, setpoint, filter health and, with the IMM
                    estimator, its model probabilities summed by motion (model_straight,
                    model_right, model_left; companion.core.imm)
    bearings.csv    every bearing given to the estimator (its only measurement input; a range
                    column is filled only when a range sensor is configured)
    zenoh_rx.jsonl  every Zenoh message received, with receipt time and verdict; rejected ones
                    through an AggregatingLog (the first REJECTS_VERBATIM per reason in full, then
                    one {"kind": "suppressed", "key": reason, "count", "first", "last"} line per
                    reason per second, times in wall seconds), so no sender can fill the disk
    events.jsonl    phase changes, status texts, errors; "*_rejected" events (refused commands)
                    aggregated the same way, keyed by kind and reason
    latency.csv     target message received -> setpoint sent (wall clock), per bearing
    mavlink.tlog    the autopilot's MAVLink traffic as MAVSDK forwards it in process (standard .tlog:
                    8-byte big-endian microsecond timestamp + raw packet)
"""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

import numpy as np

from interfaces.records import AggregatingLog, CsvLog, JsonLinesLog, fmt, write_json

SERIES_COLUMNS = (
    "time", "phase", "track_mode", "bearing_age",
    "px", "py", "pz", "vx", "vy", "vz",
    "est_x", "est_y", "est_z", "est_vx", "est_vy", "est_vz", "est_position_std", "range_estimate",
    "est_pxx", "est_pxy", "est_pxz", "est_pyy", "est_pyz", "est_pzz",
    "bearing_x", "bearing_y", "bearing_z", "bearing_time",
    "acc_x", "acc_y", "acc_z", "thrust_normalized", "new_setpoint",
    "observability_log_det", "observability_min_eigenvalue", "health", "health_suspect", "health_nis_ratio",
    "health_action", "process_noise_boost",
    "model_straight", "model_right", "model_left",
)
BEARING_COLUMNS = ("time", "direction_x", "direction_y", "direction_z", "pursuer_x", "pursuer_y", "pursuer_z",
                   "fix_seq", "range")
#: Rejected messages / refused commands logged in full per reason before only counts are written.
REJECTS_VERBATIM = 20
LATENCY_COLUMNS = ("fix_seq", "fix_stamp", "received_ns", "setpoint_sent_ns", "latency_ms")


def model_columns(estimator: object) -> dict[str, float]:
    """The series' model_straight / model_right / model_left columns: an IMM estimator's model
    probabilities summed by motion (IMMEstimator.motion_probabilities); empty for any other estimator."""
    motion = getattr(estimator, "motion_probabilities", None)
    if motion is None:
        return {}
    return dict(zip(("model_straight", "model_right", "model_left"), (float(p) for p in motion)))


class RecentSamples:
    """The most recent `capacity` values of a figure sampled through a flight (e.g. a latency in ms), in a ring
    preallocated once: memory does not grow with the flight (8 bytes a value, touched as written). `count` is every
    value ever added, `values()` the kept ones (up to capacity, oldest first)."""

    def __init__(self, capacity: int = 100_000) -> None:
        self._ring = np.empty(capacity)
        self.count = 0

    def append(self, value: float) -> None:
        self._ring[self.count % len(self._ring)] = value
        self.count += 1

    def __len__(self) -> int:
        return min(self.count, len(self._ring))

    def values(self) -> np.ndarray:
        if self.count <= len(self._ring):
            return self._ring[: self.count].copy()
        start = self.count % len(self._ring)
        return np.concatenate([self._ring[start:], self._ring[:start]])

    def percentiles(self) -> dict:
        """p50 / p99 / max of the kept values and how many were added in all; NaN figures when none."""
        data = self.values() if len(self) else np.array([np.nan])
        return {"p50": float(np.percentile(data, 50)), "p99": float(np.percentile(data, 99)), "max": float(np.max(data)),
                "count": self.count}


class RunRecorder:
    """Opens the run folder's files (interfaces.records writers: every line flushed as written)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self._series = CsvLog(self.folder / "series.csv", SERIES_COLUMNS, ignore_extra=True)
        self._zenoh = JsonLinesLog(self.folder / "zenoh_rx.jsonl")
        self._events = JsonLinesLog(self.folder / "events.jsonl")
        self._bearings = CsvLog(self.folder / "bearings.csv", BEARING_COLUMNS)
        self._latency = CsvLog(self.folder / "latency.csv", LATENCY_COLUMNS)
        self._zenoh_rejects = AggregatingLog(self._zenoh, verbatim=REJECTS_VERBATIM)
        self._event_rejects = AggregatingLog(self._events, verbatim=REJECTS_VERBATIM)
        #: called with (sim_time, kind, detail) for every event that is not a rejection (the live view's /events)
        self.listeners: list = []

    def series(self, row: dict) -> None:
        """One own-state sample: SERIES_COLUMNS -> value; floats with 6 significant digits, NaN left empty."""
        self._series.write({column: fmt(value, ".6g") if isinstance(value, float) else value
                            for column, value in row.items()})

    def zenoh(self, record: dict) -> None:
        """One received message; a rejected one (verdict "rejected") is aggregated by its reason."""
        if record.get("verdict") == "rejected":
            self._zenoh_rejects.write(str(record.get("reason")), record, time.monotonic())
        else:
            self._zenoh.write(record)
            self._zenoh_rejects.tick(time.monotonic())

    def event(self, sim_time: float | None, kind: str, detail: str, **fields) -> None:
        """One event: simulated time (s, None before telemetry), kind, human-readable detail, and the
        event's figures as structured fields (e.g. phase="following", bearing_age=0.4). Kinds ending in
        "_rejected" are aggregated per (kind, reason field) so that a flood of refusals stays bounded."""
        record = {"time": None if sim_time is None else round(sim_time, 4), "wall": round(time.time(), 3),
                  "kind": kind, "detail": detail, **fields}
        if kind.endswith("_rejected"):
            self._event_rejects.write(f"{kind}:{fields.get('reason', '')}", record, time.monotonic())
        else:
            self._events.write(record)
            self._event_rejects.tick(time.monotonic())
            for listener in self.listeners:
                listener(sim_time, kind, detail)

    def bearing(self, bearing, fix_seq: int) -> None:
        """One estimator input: the bearing (its time, direction, projection centre), the fix it came from,
        and the measured range when a range sensor is configured (empty otherwise)."""
        values = (bearing.time, *bearing.direction, *bearing.pursuer_position)
        row = {column: fmt(value, ".9g") for column, value in zip(BEARING_COLUMNS, values)}
        self._bearings.write({**row, "fix_seq": fix_seq, "range": fmt(bearing.range, ".6g")})

    def latency(self, fix_seq: int, fix_stamp: float, received_ns: int, sent_ns: int) -> None:
        self._latency.write({"fix_seq": fix_seq, "fix_stamp": f"{fix_stamp:.4f}", "received_ns": received_ns,
                             "setpoint_sent_ns": sent_ns, "latency_ms": f"{(sent_ns - received_ns) * 1e-6:.3f}"})

    def summary(self, summary: dict) -> None:
        write_json(self.folder / "summary.json", summary, indent=2, sort_keys=True)

    def close(self) -> None:
        self._zenoh_rejects.flush()
        self._event_rejects.flush()
        for log in (self._series, self._zenoh, self._events, self._latency, self._bearings):
            log.close()


class TlogWriter:
    """Appends the MAVLink packets MAVSDK hands over (MavsdkVehicle(on_mavlink=writer.record)) to a .tlog.

    No socket: the packets come from MAVSDK's raw:// connection in process (earlier versions listened
    on a UDP port, and MAVSDK's forwarding socket on 0.0.0.0 relayed anything it received to the
    autopilot). record() may be called from any thread; packets after stop() are dropped.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._file = self.path.open("wb", buffering=0)
        self._lock = threading.Lock()
        self.packets = 0

    def start(self) -> "TlogWriter":
        return self

    def record(self, packet: bytes) -> None:
        """One packet: the 8-byte big-endian microsecond wall-clock stamp, then the packet as received."""
        with self._lock:
            if self._file is None:
                return
            self._file.write(struct.pack(">Q", int(time.time() * 1e6)) + bytes(packet))
            self.packets += 1

    def stop(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
