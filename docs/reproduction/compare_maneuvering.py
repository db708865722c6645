"""The manoeuvring study's two runs side by side (docs/reproduction.md, section 5.7).

    python docs/reproduction/compare_maneuvering.py [--following] NOW/results.csv BEFORE/results.csv

NOW: `bof-montecarlo --study maneuvering` (the defaults); BEFORE: the same scenarios, seeds and bearing rates flown
another way (cases named "<rate>-<anything>": the earlier defaults, or `[safety] enabled = false`). Prints one markdown line per scenario and bearing rate:
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


def cell(now: float, before: float, digits: int) -> str:
    return f"{now:.{digits}f} ({before:.{digits}f})"


def main(argv: list[str]) -> int:
    following = "--following" in argv
    argv = [arg for arg in argv if arg != "--following"]
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    frames = [pd.read_csv(path) for path in argv]
    now, before = figures(frames[0]), figures(frames[1])
    desired = 8.0  # every scenario of the study follows at r_d = 8 m
    print("| scenario | rate | diverged | RMS median | RMS worst | closer than r_d/2 | closest / r_d | tilt over limit | max tilt (deg) | missed / false alarms |"
          + (" range error median (m) |" if following else ""))
    print("|---|---|---|---|---|---|---|---|---|---|" + ("---|" if following else ""))
    counts = ["runs", "diverged", "breached", "tilted", "missed", "false_alarms"]
    now[counts], before[counts] = now[counts].astype(int), before[counts].astype(int)
    for n in now.itertuples():  # itertuples keeps each column's type (iterrows makes the counts floats)
        scenario, rate = n.Index
        b = next(before.loc[[(scenario, rate)]].itertuples())
        print(f"| {scenario} | {rate} | {n.diverged}/{n.runs} ({b.diverged}) | {cell(n.rms_median, b.rms_median, 2)} | "
              f"{cell(n.rms_worst, b.rms_worst, 2)} | {n.breached} ({b.breached}) | "
              f"{cell(n.closest / desired, b.closest / desired, 2)} | {n.tilted} ({b.tilted}) | "
              f"{cell(n.tilt_max, b.tilt_max, 1)} | {n.missed} / {n.false_alarms} ({b.missed} / {b.false_alarms}) |"
              + (f" {cell(n.following, b.following, 1)} |" if following else ""))
    total_now, total_before = now[counts].sum(), before[counts].sum()
    print(f"\nall: diverged {total_now.diverged} ({total_before.diverged}) of {total_now.runs}; closer than r_d/2 "
          f"{total_now.breached} ({total_before.breached}); tilt over the limit {total_now.tilted} ({total_before.tilted}); "
          f"missed {total_now.missed} ({total_before.missed}), false alarms {total_now.false_alarms} "
          f"({total_before.false_alarms})" + silent_text(frames))
    return 0


def silent_text(frames: list[pd.DataFrame]) -> str:
    """'; silent while wrong N (M)' from the two results tables, or '' when either lacks the column."""
    if any("silent_while_wrong" not in rows for rows in frames):
        return ""
    now, before = (int((rows["silent_while_wrong"].astype(str) == "True").sum()) for rows in frames)
    return f"; silent while wrong {now} ({before})"


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
