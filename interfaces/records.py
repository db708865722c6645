"""The run-folder writers every process uses: CSV tables and JSON-lines logs, one line per record.

Run folders are read after the run by other processes (studies.full_sitl, the plots, the tests), so
the formats are part of what the processes agree on. Every line is flushed when written (line
buffering), so a run that is killed keeps everything up to the interruption; a line cut by the
kill itself is the only loss, and the readers skip it.

    table = CsvLog(folder / "series.csv", ("time", "x"))
    table.write({"time": 0.02, "x": fmt(1.234567, ".3g")})      # missing columns are left empty
    events = JsonLinesLog(folder / "events.jsonl")
    events.write({"time": 1.5, "kind": "phase", "detail": "following"})
    write_json(folder / "summary.json", {"rms": 0.3})               # whole file, replaced atomically

CSV rows go through `csv.DictWriter` (header from the column list, "\\n" line ends, empty cells for
absent values); JSON through `json` (numpy scalars and arrays converted with their ``tolist``). The
writers do no numerical formatting of their own: a column whose readers depend on a number format
is formatted by its caller with `fmt`.
"""

from __future__ import annotations

import csv
import json
import math
import os
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any


def plain(value: Any) -> Any:
    """`json` default hook: numpy scalars and arrays (anything with ``tolist``) as Python values."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def fmt(value: Any, spec: str) -> str:
    """`value` as text with the format `spec` (e.g. ".6g"); "" for None and NaN (an empty CSV cell)."""
    if value is None:
        return ""
    number = float(value)
    return "" if math.isnan(number) else format(number, spec)


class CsvLog:
    """A CSV table written row by row, each row flushed as written.

    path: the file (created, parents too; an existing file is replaced). columns: the header, in order.
    ignore_extra: keys of a row that are not columns are dropped (else ValueError).
    """

    def __init__(self, path: Path, columns: Iterable[str], ignore_extra: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = tuple(columns)
        self._handle = self.path.open("w", newline="", buffering=1)
        self._writer = csv.DictWriter(self._handle, fieldnames=self.columns, restval="", lineterminator="\n",
                                      extrasaction="ignore" if ignore_extra else "raise")
        self._writer.writeheader()
        self.late_rows = 0  # rows offered after close (a callback that outlived the run): counted, not written

    def write(self, row: Mapping[str, Any]) -> None:
        """One row: column -> value (str as given, other values through str(); absent or None: empty)."""
        if self._handle.closed:
            self.late_rows += 1
            return
        self._writer.writerow(row)

    def close(self) -> None:
        self._handle.close()


class JsonLinesLog:
    """A JSON-lines log: one JSON object per line, each flushed as written; safe to call from several threads."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._handle = self.path.open("w", buffering=1)
        self._lock = threading.Lock()
        self.late_records = 0  # records offered after close (a callback that outlived the run): counted, not written

    def write(self, record: Mapping[str, Any]) -> None:
        line = json.dumps(record, default=plain)
        with self._lock:
            if self._handle.closed:
                self.late_records += 1
                return
            self._handle.write(line + "\n")

    def close(self) -> None:
        with self._lock:
            self._handle.close()


def json_ready(value: Any) -> Any:
    """`value` with numpy scalars/arrays as Python numbers/lists, tuples as lists and every NaN or
    infinity as None (JSON null: "not applicable"), recursively through dicts and lists."""
    if isinstance(value, dict):
        return {str(key): json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(item) for item in value]
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return json_ready(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, document: Any, **dumps: Any) -> None:
    """`document` as a JSON file that readers never see half written (a temporary file, then os.replace).

    Non-finite numbers are written as null (see json_ready), so the file is always valid JSON;
    anything else not representable raises. dumps: keyword arguments of json.dumps (indent, sort_keys).
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(json_ready(document), allow_nan=False, **dumps) + "\n")
    os.replace(tmp, path)


class AggregatingLog:
    """Bounded logging of repeated records (rejects, refusals) in front of a JSON-lines log.

    For each key (a short code from a bounded set, e.g. a reject reason) the first
    `verbatim` records are written as given; after that the records of that key are only
    counted, and at most one line per key and `window` seconds says how many were
    suppressed::

        {"kind": "suppressed", "key": "stale_seq", "count": 4810, "first": t0, "last": t1}

    (t0, t1: the `now` values of the first and last suppressed record, in whatever clock the
    caller passes: wall or simulated seconds). So a sender that floods the process can add at
    most verbatim + (duration / window + 1) lines per key, whatever its rate. Keys beyond
    `max_keys` distinct ones are counted under "other" (a sender that varies the key cannot
    grow the log either). `written` and `suppressed` count records per key. Call `flush`
    (or `close`) at the end so that the last counts are written.

    log: anything with write(record) (JsonLinesLog). verbatim: records per key written
    in full (>= 0). window: seconds between suppressed-count lines of one key (> 0).
    """

    def __init__(self, log: Any, verbatim: int = 20, window: float = 1.0, max_keys: int = 64) -> None:
        if verbatim < 0 or not window > 0 or max_keys < 1:
            raise ValueError("AggregatingLog: verbatim >= 0, window > 0 and max_keys >= 1")
        self.log = log
        self.verbatim = int(verbatim)
        self.window = float(window)
        self.max_keys = int(max_keys)
        self.written: dict[str, int] = {}
        self.suppressed: dict[str, int] = {}
        self._pending: dict[str, list] = {}  # key -> [count, first, last, window start]
        self._lock = threading.Lock()

    def write(self, key: str, record: Mapping[str, Any], now: float) -> None:
        """Log `record` under `key` (verbatim while under the limit, else counted); now: s."""
        with self._lock:
            if key not in self.written and len(self.written) >= self.max_keys:
                key = "other"
            written = self.written.get(key, 0)
            if written < self.verbatim:
                self.written[key] = written + 1
                self.log.write(record)
                return
            self.written.setdefault(key, written)
            self.suppressed[key] = self.suppressed.get(key, 0) + 1
            pending = self._pending.get(key)
            if pending is None:
                self._pending[key] = [1, now, now, now]
            else:
                pending[0] += 1
                pending[2] = now
            self._flush_due(now)

    def _flush_due(self, now: float | None) -> None:
        for key in list(self._pending):
            count, first, last, start = self._pending[key]
            if now is None or now - start >= self.window:
                self.log.write({"kind": "suppressed", "key": key, "count": count, "first": first, "last": last})
                del self._pending[key]

    def tick(self, now: float) -> None:
        """Write the counts whose window has passed (call now and then, so that a flood that
        stops is still reported before the end)."""
        with self._lock:
            self._flush_due(now)

    def flush(self) -> None:
        """Write every pending count now."""
        with self._lock:
            self._flush_due(None)

    def close(self) -> None:
        self.flush()
        close = getattr(self.log, "close", None)
        if close is not None:
            close()
