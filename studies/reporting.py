"""Tables and progress for the studies (bof-montecarlo, bof-campaign): pandas, tabulate, tqdm.

    table = summarize(rows, ["pattern"], {"flights": ("seed", "size"), "min_range": ("min_range", "min")})
    text = markdown(lines, ["pattern", "flights"])      # lines: dicts of already formatted cells
    with progress_bar(len(tasks), "flights", enabled=not quiet) as bar: ... bar.update()

Group statistics skip missing figures (NaN) the way the tables have always read: a median
over the runs that have the figure, '-' (`cell`) where no run has it.
"""

from __future__ import annotations

import csv
import math
import sys
import textwrap
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

@dataclass
class Throughput:
    """Simulated flight-seconds per wall-clock second of a study: start it before the first flight, `add` each
    flight's simulated duration as it arrives, read `line()` / `record()` at the end.

    The wall clock (time.perf_counter) runs from construction to `stop()` (or to the reading, if not stopped):
    it includes the executor's start-up and every worker's idle time, so it is what a user waits for.
    """

    executor: str | None = None
    flights: int = 0
    simulated_s: float = 0.0
    _started: float = field(default_factory=time.perf_counter)
    _stopped: float | None = None

    def add(self, simulated_s: float) -> None:
        if math.isfinite(simulated_s) and simulated_s > 0.0:
            self.simulated_s += simulated_s
        self.flights += 1

    def stop(self) -> None:
        self._stopped = time.perf_counter()

    @property
    def wall_s(self) -> float:
        return (self._stopped if self._stopped is not None else time.perf_counter()) - self._started

    @property
    def rate(self) -> float:
        """Simulated flight-seconds per wall second (0 before any time has passed)."""
        wall = self.wall_s
        return self.simulated_s / wall if wall > 0.0 else 0.0

    def line(self, tool: str) -> str:
        executor = "" if self.executor is None else f" ({self.executor})"
        return (f"{tool}: {self.flights} flights, {self.simulated_s:.0f} simulated flight-s in {self.wall_s:.1f} s wall"
                f"{executor}: {self.rate:.0f} flight-s per wall second")

    def record(self) -> dict:
        return {"flights": self.flights, "simulated_s": self.simulated_s, "wall_s": self.wall_s,
                "flight_s_per_wall_s": self.rate, "executor": self.executor}


def summarize(rows: Sequence[Mapping[str, Any]], by: Sequence[str], statistics: Mapping[str, tuple[str, Any]],
              finite: Sequence[str] = ()) -> list[dict]:
    """One dict per group of `rows` (groups in order of first appearance): the `by` labels, then
    output name -> (column, statistic) in the order given.

    statistic: a pandas aggregation ("size", "sum", "count", "median", "min", "max") or a function of
    the group's pandas Series; NaN never counts. finite: columns whose infinities count as missing too (e.g. the
    final error of a flight that blew up: counted elsewhere, never averaged in).
    """
    frame = pd.DataFrame(list(rows))
    for column in finite:
        frame[column] = pd.to_numeric(frame[column], errors="coerce").replace([math.inf, -math.inf], math.nan)
    table = frame.groupby(list(by), sort=False).agg(**statistics).reset_index()
    return table.to_dict("records")


def cell(value: Any, digits: int = 2, infinite: str = "inf") -> str:
    """A figure for a markdown table: fixed `digits`; '-' where it does not apply (None, NaN); `infinite` for inf."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return infinite
    return f"{value:.{digits}f}"


def markdown(lines: Sequence[Mapping[str, str]], headers: Sequence[str]) -> str:
    """A markdown (pipe) table of `lines`, cells taken as given (already formatted text), columns `headers`."""
    frame = pd.DataFrame(list(lines), columns=list(headers))
    return frame.to_markdown(index=False, tablefmt="pipe", disable_numparse=True, stralign="left")


#: Terminal width the study commands print to; the whole report is in the run folder's summary.md.
TERMINAL_WIDTH = 120


def for_terminal(report: str, width: int = TERMINAL_WIDTH, where: str = "summary.md") -> str:
    """A markdown report as a terminal shows it in `width` columns: prose wrapped; a pipe table wider than `width`
    keeps its leading columns that fit (the first always) and says how many of them it shows and where the whole
    table is. Lines that are neither (headings, links) are kept as they are."""
    out: list[str] = []
    lines = report.splitlines()
    k = 0
    while k < len(lines):
        if not lines[k].startswith("|"):
            line = lines[k]
            out += textwrap.wrap(line, width, break_long_words=False, break_on_hyphens=False) if len(line) > width else [line]
            k += 1
            continue
        table = []
        while k < len(lines) and lines[k].startswith("|"):
            table.append([cell.strip() for cell in lines[k].strip().strip("|").split("|")])
            k += 1
        out += _narrow_table(table, width, where)
    return "\n".join(out)


def _narrow_table(rows: list[list[str]], width: int, where: str) -> list[str]:
    """Rows of a pipe table (the second one its rule) with as many leading columns as fit in `width`."""
    count = max(len(row) for row in rows)
    rows = [row + [""] * (count - len(row)) for row in rows]
    body = [row for index, row in enumerate(rows) if index != 1]
    widths = [max(max(len(row[c]) for row in body), 3) for c in range(count)]
    shown, used = 0, 1
    while shown < count and (shown == 0 or used + widths[shown] + 3 <= width):
        used += widths[shown] + 3
        shown += 1

    def line(cells: list[str]) -> str:
        return "| " + " | ".join(cell.ljust(widths[c]) for c, cell in enumerate(cells[:shown])) + " |"

    text = [line(body[0]), "|" + "|".join("-" * (widths[c] + 2) for c in range(shown)) + "|"]
    text += [line(row) for row in body[1:]]
    if shown < count:
        text.append(f"({shown} of {count} columns; the whole table is in {where})")
    return text


class _Lines:
    """A stream for tqdm that is not a terminal: each redraw (tqdm's '\\r' + state) becomes a line of its own,
    an unchanged state is not repeated, so a captured log reads one progress line per tenth of the run."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self._last = ""

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip()
        if line and line.split(",")[0] != self._last.split(",")[0]:
            self.stream.write(line + "\n")
            self._last = line

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(total: int | None, unit: str, enabled: bool = True, description: str | None = None) -> tqdm:
    """A progress bar on stderr (done/total, rate, elapsed, time left); nothing at all when not enabled.

    In a terminal it redraws in place; written to a file or pipe it prints a plain line about every tenth of the
    run instead (no carriage returns, no bar).
    """
    interactive = sys.stderr.isatty()
    if interactive:
        return tqdm(total=total, unit=f" {unit}", desc=description, file=sys.stderr, disable=not enabled,
                    dynamic_ncols=True, mininterval=0.5)
    if total is None:  # no tenths to count: a line every 5 s
        return tqdm(total=None, unit=f" {unit}", desc=description, file=_Lines(sys.stderr), disable=not enabled,
                    mininterval=5.0, bar_format="{desc}: {n_fmt}{unit}, {elapsed} elapsed, {rate_fmt}")
    return tqdm(total=total, unit=f" {unit}", desc=description, file=_Lines(sys.stderr), disable=not enabled,
                mininterval=0.0, miniters=max(1, total // 10),
                bar_format="{desc}: {n_fmt}/{total_fmt}{unit} ({percentage:3.0f} %), {elapsed} elapsed, {remaining} left")


def say_as(command: str, stream=None):
    """A function that prints one line as `command: line`, flushed, on `stream` (default: stderr, beside a study's
    progress), e.g. for studies.executors.compile_kernels."""
    def say(line: str) -> None:
        print(f"{command}: {line}", file=sys.stderr if stream is None else stream, flush=True)
    return say


def interrupted(command: str, reason: object, path: Path | None, total: int) -> str:
    """The line a study command prints when a stop signal ends it early: how many of `total` flights the log at
    `path` holds (its records as they are on disk: CSV rows after the header, or JSON lines), and where."""
    if path is None or not path.exists():
        return f"{command}: {reason}: no flight had finished ({total} planned); nothing written"
    with path.open(newline="") as handle:
        records = sum(1 for _ in csv.reader(handle)) - 1 if path.suffix == ".csv" else sum(1 for line in handle if line.strip())
    kept = max(0, records)  # a CSV interrupted before its header was written holds none
    return f"{command}: {reason}: {kept} of {total} flights kept in {path}"
