"""The manoeuvring study's table, of one run or of two side by side (docs/reproduction.md, section 5).

    python docs/reproduction/compare_maneuvering.py [--following] NOW/results.csv [BEFORE/results.csv]

NOW: `bof-montecarlo --study maneuvering` (the defaults); BEFORE, when given: the same scenarios, seeds and bearing
rates flown another way (cases named "<rate>-<anything>": the earlier defaults, or `[safety] enabled = false`), each
of its figures in parentheses after NOW's. Prints one markdown line per scenario and bearing rate:
flights diverged by truth (range-estimation RMS over the summary window > 2 m), the median and worst RMS, the
flights closer than r_d / 2 and the closest approach over r_d, the flights above the tilt limit and the largest
tilt, and the monitor's misses (diverged, not flagged at the end) and false alarms (flagged, not diverged). The
closing line adds, when both files have the column, the diverged flights in which the monitor never said suspect
while the estimate was off by more than the limit (silent while wrong). --following adds a last column: the median
over the flights of the range-tracking error RMS | |p_T - p| - r_d | over the summary window (how far from r_d the
pursuer followed).
"""

from __future__ import annotations

import sys

import pandas as pd


def figures(rows: pd.DataFrame) -> pd.DataFrame:
    rows = rows.copy()
    rows["rate"] = rows["case"].str.split("-").str[0]
    for column in ("diverged_rms", "breached_half_rd", "tilt_exceeded", "flagged"):
        rows[column] = rows[column].astype(str) == "True"
    rows["missed"] = rows["diverged_rms"] & ~rows["flagged"]
    rows["false_alarm"] = rows["flagged"] & ~rows["diverged_rms"]
    return rows.groupby(["scenario", "rate"]).agg(
        runs=("seed", "size"), diverged=("diverged_rms", "sum"), rms_median=("rms_error", "median"),
        rms_worst=("rms_error", "max"), breached=("breached_half_rd", "sum"), closest=("min_range", "min"),
        tilted=("tilt_exceeded", "sum"), tilt_max=("max_tilt_deg", "max"), missed=("missed", "sum"),
        false_alarms=("false_alarm", "sum"), following=("range_error_rms", "median"))


def cell(now: float, before: float | None, digits: int) -> str:
    return f"{now:.{digits}f}" if before is None else f"{now:.{digits}f} ({before:.{digits}f})"


def count(now: int, before: int | None) -> str:
    return f"{now}" if before is None else f"{now} ({before})"


def main(argv: list[str]) -> int:
    following = "--following" in argv
    argv = [arg for arg in argv if arg != "--following"]
    if len(argv) not in (1, 2):
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    frames = [pd.read_csv(path) for path in argv]
    now = figures(frames[0])
    before = figures(frames[1]) if len(frames) == 2 else None
    desired = 8.0  # every scenario of the study follows at r_d = 8 m
    print("| scenario | rate | diverged | RMS median | RMS worst | closer than r_d/2 | closest / r_d | tilt over limit | max tilt (deg) | missed / false alarms |"
          + (" range error median (m) |" if following else ""))
    print("|---|---|---|---|---|---|---|---|---|---|" + ("---|" if following else ""))
    counts = ["runs", "diverged", "breached", "tilted", "missed", "false_alarms"]
    now[counts] = now[counts].astype(int)
    if before is not None:
        before[counts] = before[counts].astype(int)
    for n in now.itertuples():  # itertuples keeps each column's type (iterrows makes the counts floats)
        scenario, rate = n.Index
        b = next(before.loc[[(scenario, rate)]].itertuples()) if before is not None else None
        of = (lambda name: None) if b is None else (lambda name: getattr(b, name))
        alarms = f"{n.missed} / {n.false_alarms}" + ("" if b is None else f" ({b.missed} / {b.false_alarms})")
        print(f"| {scenario} | {rate} | {n.diverged}/{n.runs}" + ("" if b is None else f" ({b.diverged})")
              + f" | {cell(n.rms_median, of('rms_median'), 2)} | {cell(n.rms_worst, of('rms_worst'), 2)} | "
              f"{count(n.breached, of('breached'))} | "
              f"{cell(n.closest / desired, None if b is None else b.closest / desired, 2)} | "
              f"{count(n.tilted, of('tilted'))} | {cell(n.tilt_max, of('tilt_max'), 1)} | {alarms} |"
              + (f" {cell(n.following, of('following'), 1)} |" if following else ""))
    total = now[counts].sum()
    earlier = before[counts].sum() if before is not None else None
    of = (lambda name: None) if earlier is None else (lambda name: int(earlier[name]))
    print(f"\nall: diverged {count(total.diverged, of('diverged'))} of {total.runs}; closer than r_d/2 "
          f"{count(total.breached, of('breached'))}; tilt over the limit {count(total.tilted, of('tilted'))}; "
          f"missed {count(total.missed, of('missed'))}, false alarms {count(total.false_alarms, of('false_alarms'))}"
          + silent_text(frames))
    return 0


def silent_text(frames: list[pd.DataFrame]) -> str:
    """'; silent while wrong N' (with ' (M)' for a second table) from the results tables, or '' when any lacks the
    column."""
    if any("silent_while_wrong" not in rows for rows in frames):
        return ""
    counts = [int((rows["silent_while_wrong"].astype(str) == "True").sum()) for rows in frames]
    return f"; silent while wrong {count(counts[0], counts[1] if len(counts) == 2 else None)}"


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
