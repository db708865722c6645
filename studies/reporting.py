"""Tables and progress for the studies (bof-montecarlo, bof-campaign): pandas, tabulate, tqdm.

    table = summarize(rows, ["pattern"], {"flights": ("seed", "size"), "min_range": ("min_range", "min")})
    text = markdown(lines, ["pattern", "flights"])      # lines: dicts of already formatted cells
    with progress_bar(len(tasks), "flights", enabled=not quiet) as bar: ... bar.update()

Group statistics skip missing figures (NaN) the way the tables have always read: a median
over the runs that have the figure, '-' (`cell`) where no run has it.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd
from tqdm import tqdm

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


def progress_bar(total: int | None, unit: str, enabled: bool = True, description: str | None = None) -> tqdm:
    """A progress bar on stderr (done/total, rate, elapsed, time left); nothing at all when not enabled.

    In a terminal it redraws in place; written to a file or pipe it redraws only about every tenth of the run.
    """
    interactive = sys.stderr.isatty()
    return tqdm(total=total, unit=f" {unit}", desc=description, file=sys.stderr, disable=not enabled,
                dynamic_ncols=interactive, mininterval=0.5 if interactive else 0.0,
                miniters=None if interactive else max(1, (total or 10) // 10), ascii=not interactive)
