"""Recorded target tracks ([target.trajectory]): read and checked, for the simulated target to replay.

Two formats:

- CSV: a header row naming the columns t, north, east, down (s; m, local NED), in any order, other
  columns ignored; then one sample per row. Blank lines and lines starting with '#' are skipped.
- PX4 ULog (.ulg), read with pyulog: the topic vehicle_local_position (its first instance), fields
  timestamp (us), x, y, z (m, local NED). Its velocities (vx, vy, vz) are not used: the replay
  differentiates its position spline.

Samples are counted from 1 in the messages. read_trajectory returns the samples as they are in the file; the replay (sitl_plant.world.target.
TrajectoryTarget) shifts and places them. A file that is not a regular readable file of at most
MAX_TRAJECTORY_BYTES, has a wrong header or a malformed row, fewer than MIN_TRAJECTORY_SAMPLES samples,
times that are not finite and strictly increasing, or positions that are not finite is refused with a
ConfigError, one line naming the file.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
from pathlib import Path

import numpy as np

from interfaces.scenario import MAX_TRAJECTORY_BYTES, ConfigError, read_regular_file

#: A C2 cubic spline with not-a-knot ends needs four samples.
MIN_TRAJECTORY_SAMPLES = 4
CSV_COLUMNS = ("t", "north", "east", "down")
ULOG_TOPIC = "vehicle_local_position"
ULOG_FIELDS = ("timestamp", "x", "y", "z")


def read_trajectory(path: Path, file_format: str) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a recorded track: times (s, shape (n,), strictly increasing, as in the file) and positions
    (m, local NED, shape (n, 3)). file_format: "csv" or "ulog". ConfigError naming the file if it is refused."""
    path = Path(path)
    data = read_regular_file(path, MAX_TRAJECTORY_BYTES, noun="trajectory file")
    if file_format == "csv":
        times, positions = _csv_samples(path, data)
    elif file_format == "ulog":
        times, positions = _ulog_samples(path, data)
    else:
        raise ConfigError(f"{path}: unknown trajectory format {file_format!r} (csv or ulog)")
    _check_samples(path, times, positions)
    return times, positions


def _csv_samples(path: Path, data: bytes) -> tuple[np.ndarray, np.ndarray]:
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark, as spreadsheet programs write, is not part of the header
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not UTF-8 text (byte {data[error.start]:#04x} at offset {error.start})") from None
    lines = [(number, line) for number, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise ConfigError(f"{path}: empty: expected a header row {','.join(CSV_COLUMNS)} and samples")
    try:
        rows = list(csv.reader(line for _, line in lines))
    except csv.Error as error:
        raise ConfigError(f"{path}: not a readable CSV file ({error})") from None
    header = [name.strip() for name in rows[0]]
    missing = [name for name in CSV_COLUMNS if name not in header]
    doubled = sorted({name for name in header if header.count(name) > 1 and name in CSV_COLUMNS})
    if missing or doubled:
        problem = f"missing {', '.join(missing)}" if missing else f"{', '.join(doubled)} given twice"
        raise ConfigError(f"{path}: line {lines[0][0]}: the header must name the columns {','.join(CSV_COLUMNS)} "
                          f"(s, m NED): {problem}")
    columns = [header.index(name) for name in CSV_COLUMNS]
    values = np.empty((len(rows) - 1, 4))
    for row_index, row in enumerate(rows[1:]):
        number = lines[row_index + 1][0]
        if len(row) != len(header):
            raise ConfigError(f"{path}: line {number}: {len(row)} fields, the header has {len(header)}")
        for column_index, column in enumerate(columns):
            try:
                values[row_index, column_index] = float(row[column])
            except ValueError:
                raise ConfigError(f"{path}: line {number}: {CSV_COLUMNS[column_index]} = {row[column].strip()!r} "
                                  "is not a number") from None
    return values[:, 0], values[:, 1:]


class _ReadBudget(io.BytesIO):
    """The file's bytes for pyulog, with a budget of reads: a well-formed ULog is read about twice over (pyulog
    seeks back to re-read the first data message), while a corrupt message size can send its definitions loop back
    before its own header, for ever. Each read costs its length, and at least 1; past the budget it raises."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self._budget = 4 * len(data) + 4096

    def read(self, size: int | None = -1) -> bytes:
        chunk = super().read(size)
        self._budget -= max(len(chunk), 1)
        if self._budget < 0:
            raise ValueError("the parser kept re-reading the file (a corrupt message size)")
        return chunk


def _ulog_samples(path: Path, data: bytes) -> tuple[np.ndarray, np.ndarray]:
    from pyulog import ULog  # only a ULog replay needs it

    try:
        # pyulog prints its parse warnings; the refusal below says what matters, in one line.
        with contextlib.redirect_stdout(io.StringIO()):
            log = ULog(_ReadBudget(data), message_name_filter_list=[ULOG_TOPIC])
    # A parser of untrusted binary input: whatever it raises on a corrupt file means "not a readable ULog".
    except Exception as error:  # noqa: BLE001
        raise ConfigError(f"{path}: not a readable ULog file ({type(error).__name__}: {error})") from None
    instances = sorted((dataset for dataset in log.data_list if dataset.name == ULOG_TOPIC), key=lambda d: d.multi_id)
    if not instances:
        raise ConfigError(f"{path}: the ULog has no {ULOG_TOPIC} topic (the local position a replay needs)")
    fields = instances[0].data
    missing = [name for name in ULOG_FIELDS if name not in fields]
    if missing:
        raise ConfigError(f"{path}: the ULog's {ULOG_TOPIC} has no field {', '.join(missing)}")
    stamps = np.asarray(fields["timestamp"], dtype=np.uint64)
    if stamps.size and np.any(stamps[1:] <= stamps[:-1]):
        raise ConfigError(f"{path}: {ULOG_TOPIC} timestamps must increase strictly")
    # Differences first, in integer microseconds: a boot time of hours keeps its microsecond resolution.
    times = (stamps - stamps[0]).astype(float) * 1e-6 if stamps.size else np.empty(0)
    positions = np.column_stack([np.asarray(fields[name], dtype=float) for name in ("x", "y", "z")])
    return times, positions


def _check_samples(path: Path, times: np.ndarray, positions: np.ndarray) -> None:
    if times.size < MIN_TRAJECTORY_SAMPLES:
        raise ConfigError(f"{path}: {times.size} samples; a trajectory needs at least {MIN_TRAJECTORY_SAMPLES}")
    if not np.all(np.isfinite(times)):
        raise ConfigError(f"{path}: sample {int(np.argmin(np.isfinite(times))) + 1}: time is not finite")
    steps = np.diff(times)
    if np.any(steps <= 0.0):
        index = int(np.argmax(steps <= 0.0)) + 1
        raise ConfigError(f"{path}: sample {index + 1}: time {times[index]:g} s does not increase "
                          f"(the previous is {times[index - 1]:g} s)")
    finite = np.isfinite(positions).all(axis=1)
    if not finite.all():
        raise ConfigError(f"{path}: sample {int(np.argmin(finite)) + 1}: position is not finite")
    if not math.isfinite(float(times[-1] - times[0])):
        raise ConfigError(f"{path}: the track is too long to replay")
