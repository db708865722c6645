"""`bof-campaign`: link-dropout Monte Carlo. Does the companion keep the target when the link misbehaves?

    bof-campaign [config/scenarios/constant_velocity.toml] [--seeds 10] [--patterns blackout_5s loss_30]
                 [--sitl blackout_5s] [--out runs]

Each fault pattern is a [faults] section applied to the scenario; every (pattern, seed)
flight runs in the in-process simulator (same pipeline, same fault model, same fix
validator as the networked companion) in parallel worker processes. Patterns named
with --sitl are also flown once through the full SITL (bof-sitl, real processes, the
faults injected by sitl-target). Output (runs/campaign-<scenario>-<time>/): results.csv
(one row per flight), summary.md (one row per pattern, with the pass/fail of the
targets below) and summary.json. Progress bars on stderr (flights done; simulated time and
phase of each SITL flight); --quiet turns them off.

Figures per flight (times are scenario seconds):
* kept: the estimate still tracks at the end (range-estimation error under 1 m over the
  last 5 s) and the range is within [r_d/2, 2 r_d]; the flight did not blow up.
* min_range: closest approach after engagement, m.
* worst_error: largest |range-estimation error| from the first fault onwards (for faults
  that last the whole flight, from 20 s on, after the initial convergence), m.
* reconverge: after each blackout ends, time until the range-estimation error is under
  1 m and stays there until the next fault or the end; the worst of them, s.

Targets (constant-velocity scenario): the target kept in every flight, never closer than
r_d / 2, range-estimation error back under 1 m within 10 s of the link returning.

Attack patterns (`ATTACK_PATTERNS`: future_seq, future_stamp, replay, target_restart,
spoof_burst, spoof_steady, and the two spoofs in the target's own overheard epoch:
spoof_burst_sniffed, spoof_steady_sniffed, and spoof_close_sniffed, a spoof close enough to be
plausible; the [faults] attacks of sitl_plant.world.link_faults, at 30 s or from
10 s) add per flight, from the in-process link's record of which deliveries were the genuine
target's (studies.closed_loop.GenuineRecord):
* lockout: the longest run of rejected genuine fixes, s (from the first of them to the next
  accepted one); attack_messages / attack_refused / attack_accepted_far: the attacker's messages
  delivered, those rejected (they appear in the reject counters), those accepted while more
  than 5 m off the genuine fix.
Patient liars (`LIAR_PATTERNS`: patient_liar, patient_liar_altitude): a steady spoofer in the target's
overheard epoch that republishes each genuine fix first, seq 1 ahead, drifting 0.5 m/s off (north, or
down only), for 15 s from 30 s. Its lies are as plausible as the truth, so the validator holds the
track (companion.core.fix_validator, "Two sources") and the pursuer stands off until the liar falls
silent. Per flight: flagged_after, s from the first lie to the hold; verdict (never "clean").
Targets: never closer than r_d / 2, flagged within FLAG_LIMIT s, no flight clean, no lie accepted far off.
Attack targets, every flight: the target kept, never closer than r_d / 2, lockout <= LOCKOUT_LIMIT
s, every attack message refused (none accepted far off). In SITL (no genuine/foreign split in
the companion's log) lockout is the longest gap between accepted fixes less one fix period,
and the attack's messages (faults.jsonl) must not exceed the companion's reject count.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from interfaces.run_folders import new_run_folder
from interfaces import link_schema
from interfaces.overrides import apply_overrides, format_assignment
from interfaces.records import CsvLog
from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, VehicleConfig, load_scenario
from studies.closed_loop import Termination, simulate
from studies import reporting
from studies.executors import check_executor, check_flight_count, make_executor
from studies.processes import Interrupted, RaisingStopSignals, wait_for
from studies.metrics import write_summary
from interfaces.cli import SPEED_FACTOR_RANGE, CommandParser, output_folder, scenario_file, speed_factor_argument

DEFAULT_SCENARIO = DEFAULT_SCENARIO
CONVERGED = 1.0  # m, range-estimation error
STEADY_FROM = 20.0  # s, when continuous faults start counting (after the initial convergence)
BLACKOUT_AT = 30.0  # s, scenario time of the blackouts: steady following
ATTACK_AT = 30.0  # s, scenario time of the one-shot attacks
LOCKOUT_LIMIT = 1.0  # s, the longest run of rejected genuine fixes an attack may cause

#: name -> ([faults] overrides, description). Blackouts are in scenario seconds.
PATTERNS: dict[str, tuple[dict, str]] = {
    "none": ({}, "no fault (baseline)"),
    "blackout_1s": ({"blackouts": [{"start": BLACKOUT_AT, "duration": 1.0}]}, "1 s blackout at 30 s"),
    "blackout_2s": ({"blackouts": [{"start": BLACKOUT_AT, "duration": 2.0}]}, "2 s blackout at 30 s"),
    "blackout_5s": ({"blackouts": [{"start": BLACKOUT_AT, "duration": 5.0}]}, "5 s blackout at 30 s"),
    "blackout_10s": ({"blackouts": [{"start": BLACKOUT_AT, "duration": 10.0}]}, "10 s blackout at 30 s"),
    "loss_30": ({"loss_probability": 0.3}, "30 % independent loss"),
    "bursty_2s": ({"burst": {"mean_burst_s": 2.0, "mean_gap_s": 8.0}}, "Gilbert-Elliott, mean burst 2 s, mean gap 8 s"),
    "latency_jitter": ({"latency_s": 0.15, "jitter_s": 0.1}, "150 ms latency, 100 ms jitter"),
    "reorder_duplicate": ({"reorder_probability": 0.2, "duplicate_probability": 0.2}, "20 % reordered, 20 % duplicated"),
    "stale": ({"stale_probability": 0.2}, "20 % stale (old) messages"),
    "corrupt": ({"corrupt_probability": 0.2}, "20 % corrupted payloads (all kinds)"),
    "impostor": ({"impostor_rate_hz": 5.0}, "a second publisher on the key, 5 Hz"),
    "future_seq": ({"future_seq_at": ATTACK_AT}, "one copy of a fix with seq + 2^62, 10 ms newer, at 30 s"),
    "future_stamp": ({"future_stamp_at": ATTACK_AT}, "one copy of a fix stamped 1e6 s ahead at 30 s"),
    "replay": ({"replay_at": ATTACK_AT}, "the last 25 genuine fixes (5 s) re-sent at 30 s"),
    "target_restart": ({"restart_at": ATTACK_AT}, "the target's publisher restarts at 30 s: 1 s silent, new epoch, seq 0"),
    "spoof_burst": ({"spoof_burst_at": ATTACK_AT},
                    "3 consistent fixes as the target, 30 m off, seq 2^40 ahead, at 30 s"),
    "spoof_steady": ({"spoof_rate_hz": 5.0, "spoof_from": 10.0},
                     "a second source as the target from 10 s, 5 Hz, 30 m off, seq 2^40 ahead"),
    "spoof_burst_sniffed": ({"spoof_burst_at": ATTACK_AT, "spoof_epoch": "target"},
                            "the spoof burst in the target's own epoch (overheard), seq 2^40 ahead"),
    "spoof_steady_sniffed": ({"spoof_rate_hz": 5.0, "spoof_from": 10.0, "spoof_epoch": "target", "spoof_seq_lead": 1},
                             "the steady spoof in the target's own epoch, seq 1 ahead"),
    "spoof_close_sniffed": ({"spoof_rate_hz": 5.0, "spoof_from": 10.0, "spoof_epoch": "target", "spoof_seq_lead": 1,
                             "spoof_offset": [10.0, 0.0, 0.0]},
                            "the steady spoof 10 m off (plausible), in the target's own epoch, seq 1 ahead, first"),
    "patient_liar": ({"spoof_rate_hz": 5.0, "spoof_from": ATTACK_AT, "spoof_epoch": "target", "spoof_seq_lead": 1,
                      "spoof_offset": [0.0, 0.0, 0.0], "spoof_drift": [0.5, 0.0, 0.0], "spoof_duration": 15.0},
                     "for 15 s from 30 s, each genuine fix republished first, seq 1 ahead, in the target's epoch, "
                     "drifting 0.5 m/s north"),
    "patient_liar_altitude": ({"spoof_rate_hz": 5.0, "spoof_from": ATTACK_AT, "spoof_epoch": "target",
                               "spoof_seq_lead": 1, "spoof_offset": [0.0, 0.0, 0.0], "spoof_drift": [0.0, 0.0, 0.5],
                               "spoof_duration": 15.0},
                              "the patient liar drifting 0.5 m/s down only"),
}
#: The attack patterns and their targets (module docstring).
ATTACK_PATTERNS = ("future_seq", "future_stamp", "replay", "target_restart", "spoof_burst", "spoof_steady",
                   "spoof_burst_sniffed", "spoof_steady_sniffed", "spoof_close_sniffed")
#: Attacks from outside the link model, flown only in full SITL with `bof-sitl --secure` (mutual TLS,
#: access control, MAVLink signing required on the ground-station link) by studies.intruder once the
#: companion follows: name -> (intruder attack, the intruder's identity, description). Identity: "none"
#: (TLS without a certificate), "foreign" (a certificate from another CA), a role of the run's own PKI
#: (a stolen key), or None (MAVLink: unsigned).
INTRUDER_PATTERNS: dict[str, tuple[str, str | None, str]] = {
    "abort_unauthenticated": ("abort", "none", "SITL --secure: an abort from a Zenoh peer without a certificate"),
    "unknown_peer": ("unknown-peer", "foreign", "SITL --secure: a peer with another CA's certificate publishes a "
                                                "future-seq fix and listens"),
    "abort_stolen_target_key": ("abort", "target", "SITL --secure: an abort from a peer holding the target's own "
                                                   "certificate (access control: only gcs commands)"),
    "mavlink_unsigned_arm": ("arm", None, "SITL --secure: an unsigned arm + takeoff to 10 m on the plant's "
                                          "ground-station port, signing required"),
}
#: Liars whose fixes are as plausible as the genuine ones (module docstring): the track is held, not kept.
LIAR_PATTERNS = ("patient_liar", "patient_liar_altitude")
#: s: a liar must be flagged (the track held, the monitor suspect) within this long of its first fix.
FLAG_LIMIT = 2.0
TARGET_PATTERNS = ("blackout_1s", "blackout_2s", "blackout_5s", "blackout_10s", "loss_30", "bursty_2s")


def with_faults(scenario: Scenario, overrides: dict) -> Scenario:
    """The scenario with its [faults] section replaced by `overrides`, the whole scenario re-validated."""
    return apply_overrides(scenario, {"faults": overrides}, "bof-campaign [faults]")


def blackout_windows(overrides: dict) -> list[tuple[float, float]]:
    return sorted((b["start"], b["start"] + b["duration"]) for b in overrides.get("blackouts", []))


def flight_metrics(series: dict[str, np.ndarray], scenario: Scenario, termination: Termination,
                   windows: list[tuple[float, float]], continuous: bool) -> dict:
    """The figures of one flight (see the module docstring)."""
    t = series["time"]
    engaged = np.isfinite(series["estimate_position"][:, 0])
    error = np.abs(series["range_estimate"] - series["range"])
    distance = series["range"]
    desired = scenario.guidance.desired_range
    end = t >= t[-1] - 5.0
    kept = bool(termination is Termination.COMPLETED and np.all(engaged[end]) and np.mean(error[end]) < CONVERGED
                and 0.5 * desired <= distance[-1] <= 2.0 * desired)
    if windows:
        fault_from = windows[0][0]
    elif continuous:
        fault_from = STEADY_FROM
    else:
        fault_from = math.inf
    during = engaged & (t >= fault_from)
    reconverge = []
    for index, (_, stop) in enumerate(windows):
        horizon = windows[index + 1][0] if index + 1 < len(windows) else t[-1] + 1.0
        span = (t >= stop) & (t < horizon)
        bad = span & (error >= CONVERGED)
        if not span.any():
            continue
        if not bad.any():
            reconverge.append(0.0)
        elif bad[np.nonzero(span)[0][-1]]:
            reconverge.append(math.inf)  # still off at the end of the span
        else:
            reconverge.append(float(t[np.nonzero(bad)[0][-1] + 1] - stop))
    return {
        "kept": kept,
        "termination": termination.name,
        "min_range": float(np.min(distance[engaged])) if engaged.any() else math.nan,
        "worst_error": float(np.max(error[during])) if during.any() else math.nan,
        "reconverge": max(reconverge) if reconverge else math.nan,
        "final_error": float(np.mean(error[end])),
    }


def _fly(task: tuple[str, int, Scenario, VehicleConfig]) -> dict:
    name, seed, scenario, vehicle = task
    overrides = PATTERNS[name][0] if name in PATTERNS else {}
    result = simulate(scenario, vehicle, seed)
    metrics = flight_metrics(result.series, scenario, result.termination, blackout_windows(overrides),
                             continuous=bool(overrides) and not overrides.get("blackouts"))
    link = result.summary.get("link", {})
    modes = result.summary.get("track_mode_changes", [])
    genuine = link.get("genuine", {})
    attack_messages = sum(count for kind, count in link.get("faults", {}).items() if kind.startswith("attack_"))
    return {"pattern": name, "seed": seed, **metrics,
            "flown_s": float(result.series["time"][-1]),  # simulated seconds flown (the throughput figure)
            "lockout": genuine.get("longest_rejected_run_s", math.nan),
            "attack_messages": attack_messages,
            "attack_refused": genuine.get("foreign_rejected", 0),
            "attack_accepted_far": genuine.get("foreign_accepted_far", 0),
            "reanchors": len(link.get("reanchors", [])),
            "fixes_accepted": link.get("accepted", math.nan), "fixes_rejected": sum(link.get("rejected", {}).values()),
            "rejected_by_reason": json.dumps(link.get("rejected", {}), sort_keys=True),
            "degraded_entries": sum(1 for _, mode in modes if mode == "degraded"),
            "reinitialized": result.summary.get("reinitializations", 0),
            "verdict": result.summary.get("verdict", ""), "clean": result.summary.get("verdict") == "clean",
            "flagged_after": (_flagged_after(link.get("contest_log", []), overrides.get("spoof_from", 0.0))
                              if overrides.get("spoof_rate_hz") else math.nan)}


def _flagged_after(contests: list[dict], start: float) -> float:
    """s from an attack's start (in the validator's clock) to the first hold of the track at or after it (the
    validator's contest log); inf when the track was never held."""
    held = [c["start"] - start for c in contests if c["start"] >= start - 1e-6]
    return min(held) if held else math.inf


#: pattern-table figure -> (results.csv column, statistic over the pattern's flights; NaN skipped)
PATTERN_FIGURES = {
    "flights": ("seed", "size"), "kept": ("kept", "sum"), "min_range": ("min_range", "min"),
    "worst_error_median": ("worst_error", "median"), "worst_error_max": ("worst_error", "max"),
    "reconverge_median": ("reconverge", "median"), "reconverge_max": ("reconverge", "max"),
    "lockout_max": ("lockout", "max"), "attack_messages": ("attack_messages", "sum"),
    "attack_refused": ("attack_refused", "sum"), "attack_accepted_far": ("attack_accepted_far", "sum"),
    "flagged_after_max": ("flagged_after", "max"), "clean": ("clean", "sum"),
}


def pattern_table(rows: list[dict], desired_range: float) -> list[dict]:
    """One line per pattern: shares, extremes, medians, and the targets' verdict. A reconvergence that
    never came (inf) counts in the median and the maximum; the worst error counts where finite."""
    table = []
    for group in reporting.summarize(rows, ["pattern"], PATTERN_FIGURES, finite=["worst_error"]):
        name, kept = group["pattern"], group.pop("kept")
        entry = {"pattern": name, "description": PATTERNS.get(name, ({}, name))[1], "flights": group["flights"],
                 "kept_share": kept / group["flights"],
                 **{key: group[key] for key in PATTERN_FIGURES if key not in ("flights", "kept")}}
        if name in ATTACK_PATTERNS:
            entry["meets_targets"] = bool(kept == group["flights"] and entry["min_range"] >= 0.5 * desired_range
                                          and entry["lockout_max"] <= LOCKOUT_LIMIT
                                          and entry["attack_refused"] == entry["attack_messages"]
                                          and entry["attack_accepted_far"] == 0)
        if name in LIAR_PATTERNS:
            entry["meets_targets"] = bool(entry["min_range"] >= 0.5 * desired_range
                                          and entry["flagged_after_max"] <= FLAG_LIMIT and entry["clean"] == 0
                                          and entry["attack_accepted_far"] == 0)
        if name in TARGET_PATTERNS:
            reconverge_max = entry["reconverge_max"]
            entry["meets_targets"] = bool(kept == group["flights"] and entry["min_range"] >= 0.5 * desired_range
                                          and (math.isnan(reconverge_max) or reconverge_max <= 10.0))
        table.append(entry)
    return table


def markdown(table: list[dict], sitl_rows: list[dict], scenario: Scenario, seeds: int) -> str:
    def f(value: float, digits: int) -> str:  # 'never' for a reconvergence that did not come
        return reporting.cell(value, digits, infinite="never")

    headers = ["pattern", "flights", "target kept", "min range (m)",
               "worst range-est. error during fault, median / max (m)",
               "re-converge after link returns, median / max (s)", "targets"]
    lines = [dict(zip(headers, (
        f"{e['pattern']} ({e['description']})", str(e["flights"]), f"{100 * e['kept_share']:.0f} %", f(e["min_range"], 2),
        f"{f(e['worst_error_median'], 2)} / {f(e['worst_error_max'], 2)}",
        f"{f(e['reconverge_median'], 1)} / {f(e['reconverge_max'], 1)}",
        {True: "met", False: "**missed**"}.get(e.get("meets_targets"), "-")))) for e in table]
    parts = [f"# Link-dropout campaign: {scenario.name}, {seeds} seeds per pattern, r_d = {scenario.guidance.desired_range:g} m",
             "", reporting.markdown(lines, headers)]
    attacks = [e for e in table if e["pattern"] in ATTACK_PATTERNS]
    if attacks:
        headers = ["attack", "flights", "target kept", "min range (m)", "longest genuine lockout, max (s)",
                   "attack messages", "refused (counted)", "accepted > 5 m off", "targets"]
        lines = [dict(zip(headers, (
            f"{e['pattern']} ({e['description']})", str(e["flights"]), f"{100 * e['kept_share']:.0f} %",
            f(e["min_range"], 2), f(e["lockout_max"], 2), str(int(e["attack_messages"])), str(int(e["attack_refused"])),
            str(int(e["attack_accepted_far"])), "met" if e["meets_targets"] else "**missed**"))) for e in attacks]
        parts += ["", f"Attacks (targets: kept, min range >= r_d/2, lockout <= {LOCKOUT_LIMIT:g} s, every attack "
                      "message refused and counted):", "", reporting.markdown(lines, headers)]
    liars = [e for e in table if e["pattern"] in LIAR_PATTERNS]
    if liars:
        headers = ["liar", "flights", "target kept", "min range (m)", "flagged after, max (s)", "longest genuine lockout, "
                   "max (s)", "lies accepted", "flights called clean", "targets"]
        lines = [dict(zip(headers, (
            f"{e['pattern']} ({e['description']})", str(e["flights"]), f"{100 * e['kept_share']:.0f} %",
            f(e["min_range"], 2), f(e["flagged_after_max"], 2), f(e["lockout_max"], 2),
            str(int(e["attack_messages"] - e["attack_refused"])), str(int(e["clean"])),
            "met" if e["meets_targets"] else "**missed**"))) for e in liars]
        parts += ["", f"Patient liars (targets: never closer than r_d/2, the track held within {FLAG_LIMIT:g} s of the "
                      "first lie, no flight called clean, no lie accepted > 5 m off):", "", reporting.markdown(lines, headers)]
    intruders = [r for r in sitl_rows if r["pattern"] in INTRUDER_PATTERNS]
    sitl_rows = [r for r in sitl_rows if r["pattern"] not in INTRUDER_PATTERNS]
    if intruders:
        headers = ["attack (full SITL, --secure)", "kept", "min range (m)", "longest gap (s)", "termination", "obeyed",
                   "intruder sent", "refused, counted where", "targets"]

        def counted(r: dict) -> str:
            if r.get("error"):
                return r["error"]
            if INTRUDER_PATTERNS[r["pattern"]][0] == "arm":
                return f"{r['intruder_refused']} signing_unsigned (plant stats.json)"
            if r["intruder_counted"]:
                return f"{r['tls_refused']} TLS handshakes (Zenoh logs)"
            return "refused by access control; not countable at the receiver"

        lines = [dict(zip(headers, (
            f"{r['pattern']} ({INTRUDER_PATTERNS[r['pattern']][2]})", str(r.get("kept", "-")), f(r.get("min_range", math.nan), 2),
            f(r.get("lockout", math.nan), 2), str(r.get("termination", "-")), str(r.get("obeyed", "-")),
            str(r.get("intruder_sent", "-")), counted(r),
            {True: "met", False: "**missed**"}.get(r.get("meets_targets"), "-")))) for r in intruders]
        parts += ["", "Intruders from outside (full SITL with mutual TLS, access control and MAVLink signing; "
                      "bof-intruder once the companion follows):", "", reporting.markdown(lines, headers)]
    if sitl_rows:
        headers = ["pattern", "kept", "min range (m)", "worst error (m)", "re-converge (s)", "fixes rejected",
                   "attack messages heard", "accepted > 5 m off", "longest gap (s)", "targets"]
        lines = [dict(zip(headers, (r["pattern"], str(r["kept"]), f(r["min_range"], 2), f(r["worst_error"], 2),
                                    f(r["reconverge"], 1), str(r["fixes_rejected"]), str(r.get("attack_messages", "-")),
                                    str(r.get("attack_accepted_far", "-")), f(r.get("lockout", math.nan), 2),
                                    {True: "met", False: "**missed**"}.get(r.get("meets_targets"), "-"))))
                 for r in sitl_rows]
        parts += ["", "Full SITL (real processes, MAVLink, Zenoh; faults injected by sitl-target):", "",
                  reporting.markdown(lines, headers)]
    return "\n".join(parts) + "\n"


def _sitl_case(config: Path, name: str, folder: Path, speed: float, show_progress: bool = True) -> dict:
    from studies import full_sitl

    overrides = PATTERNS[name][0]
    faults = [format_assignment(key, value) for key, value in overrides.items()]
    with reporting.progress_bar(None, "sim s", enabled=show_progress, description=f"bof-campaign SITL {name}") as bar:
        def progress(state: link_schema.CompanionState | None, engaged_at: float | None) -> None:
            if state is not None:
                bar.update(state.stamp - bar.n)
                bar.set_postfix(phase=state.phase, refresh=False)

        code, run_folder, summary = full_sitl.run(config, folder, speed, None, None, plots=True, quiet=True,
                                                  target_faults=faults, on_state=progress)
    scenario, _ = load_scenario(config)
    series, _ = full_sitl.flight_series(run_folder)
    metrics = flight_metrics(series, scenario, Termination.COMPLETED if code == 0 else Termination.OUT_OF_CONTROL,
                             blackout_windows(overrides), continuous=not overrides.get("blackouts"))
    link = summary["companion"]["link"]
    row = {"pattern": name, **metrics, "fixes_rejected": sum(link["rejected"].values()), "run_folder": str(run_folder)}
    if name in LIAR_PATTERNS:
        row.update(_sitl_attack_figures(Path(run_folder), scenario.sensor.rate_hz, scenario.sitl.home))
        # The companion's validator and the target's fault log share the plant's clock.
        row["flagged_after"] = _flagged_after(link.get("contest_log", []), row["first_attack"])
        row["verdict"] = (summary.get("flight") or {}).get("verdict", "")
        row["meets_targets"] = bool(row["min_range"] >= 0.5 * scenario.guidance.desired_range
                                    and row["flagged_after"] <= FLAG_LIMIT and row["verdict"] != "clean"
                                    and row["attack_accepted_far"] == 0)
    if name in ATTACK_PATTERNS:
        row.update(_sitl_attack_figures(Path(run_folder), scenario.sensor.rate_hz, scenario.sitl.home))
        if "restart_at" in overrides:  # the restart's own silence is no rejection
            row["lockout"] = max(0.0, row["lockout"] - with_faults(scenario, overrides).faults.restart_gap_s)
        row["meets_targets"] = bool(row["kept"] and row["min_range"] >= 0.5 * scenario.guidance.desired_range
                                    and row["lockout"] <= LOCKOUT_LIMIT and row["attack_accepted_far"] == 0
                                    and row["attack_messages"] <= row["fixes_rejected"])
    return row


def _sitl_intruder_case(config: Path, name: str, folder: Path, speed: float) -> dict:
    """One `bof-sitl --secure` flight with the INTRUDER_PATTERNS attack `name` sent by studies.intruder
    once the companion follows; the flight's figures and what the intruder achieved.

    Targets: kept, never closer than r_d/2, lockout <= LOCKOUT_LIMIT, not aborted, the vehicle
    never left the companion's control, and the intruder refused and counted: refused TLS
    handshakes in the processes' Zenoh logs (no certificate, another CA), the plant's
    signing_unsigned count (MAVLink). An access-control denial (a stolen key of the wrong role)
    is silent at the receiver: that row is refused but cannot be counted (`counted` False).
    """
    import threading

    from interfaces.pki import make_pki
    from studies import full_sitl, intruder

    attack, identity, _ = INTRUDER_PATTERNS[name]
    folder.mkdir(parents=True, exist_ok=True)
    before = set(folder.glob("sitl-*"))
    outcome: dict = {}

    def fly() -> None:
        try:
            outcome["run"] = full_sitl.run(config, folder, speed, None, None, plots=False, quiet=True, secure=True)
        except Exception as error:  # reported in the row; the attack side stops waiting
            outcome["error"] = f"{type(error).__name__}: {error}"

    thread = threading.Thread(target=fly, name=f"bof-sitl {name}", daemon=True)
    thread.start()
    attack_result: dict = {}
    try:
        wait_for(lambda: "error" in outcome or any((f / "links.json").exists() for f in set(folder.glob("sitl-*")) - before),
                  120.0, "the SITL run folder")
        if "error" in outcome:
            raise RuntimeError(outcome["error"])
        run_folder = next(f for f in set(folder.glob("sitl-*")) - before if (f / "links.json").exists())
        wait_for(lambda: "run" in outcome or "error" in outcome or "companion: following" in
                  ((run_folder / "companion.out").read_text(errors="replace")
                   if (run_folder / "companion.out").exists() else ""), 180.0, "the companion to follow")
        time.sleep(2.0 / speed * 5)  # 10 s of simulated following before the attack
        endpoints = intruder.discover(run_folder)
        pki = run_folder / "pki"
        zenoh_tls, role = None, None
        if identity == "none":
            zenoh_tls = pki  # the CA only: TLS without a certificate of its own
        elif identity == "foreign":  # a well-formed gcs certificate, but from a CA this run never trusted
            zenoh_tls, role = folder / f"foreign-ca-{name}", "gcs"
            make_pki(zenoh_tls, roles=("gcs",), force=True)
        elif identity is not None:
            zenoh_tls, role = pki, identity
        options = intruder.AttackOptions(attack, config=config, zenoh_tls=zenoh_tls, role=role, observer_tls=pki,
                                         observer_role="gcs", duration=2.0, observe=3.0, settle=0.5, wait=60.0,
                                         takeoff=10.0 if attack == "arm" else None)
        try:
            attack_result = intruder.run_attack(endpoints, options)
        except (RuntimeError, ValueError, OSError) as error:
            attack_result = {"error": f"{type(error).__name__}: {error}"}
    finally:
        thread.join(timeout=600.0)
    if "run" not in outcome:
        return {"pattern": name, "meets_targets": False, "error": outcome.get("error", "the SITL flight did not end"),
                "attack": attack_result}
    code, run_folder, summary = outcome["run"]
    scenario, _ = load_scenario(config)
    series, _ = full_sitl.flight_series(run_folder)
    metrics = flight_metrics(series, scenario, Termination.COMPLETED if code == 0 else Termination.OUT_OF_CONTROL,
                             [], continuous=True)
    link = summary["companion"]["link"]
    figures = _sitl_attack_figures(Path(run_folder), scenario.sensor.rate_hz, scenario.sitl.home)
    tls_refused = sum((summary.get("zenoh") or {}).get("tls_refused", {}).values())
    plant_rejected = (attack_result.get("plant") or {}).get("rejected", {})
    sent = int((attack_result.get("row") or {}).get("sent") or 0)
    if attack == "arm":
        # Every unsigned message refused (signing_unsigned, plant/stats.json); a takeoff obeyed would have
        # taken the vehicle out of offboard and the companion would have ended in failsafe.
        refused = int(plant_rejected.get("signing_unsigned", 0))
        counted = refused >= sent > 0
        obeyed = refused < sent  # and the termination (completed/diverged) says the companion kept control
    else:
        # TLS refusals are counted from the processes' Zenoh logs; an access-control denial is silent.
        refused = tls_refused if identity in ("none", "foreign") else None
        counted = bool(refused) if identity in ("none", "foreign") else False
        obeyed = summary.get("termination") == "aborted" or bool((summary.get("companion") or {}).get("abort_requested"))
    row = {"pattern": name, **metrics, "fixes_rejected": sum(link["rejected"].values()), "run_folder": str(run_folder),
           "termination": summary.get("termination"), "lockout": figures["lockout"],
           "attack_accepted_far": figures["attack_accepted_far"], "intruder_refused": refused,
           "intruder_sent": sent, "intruder_counted": counted, "obeyed": obeyed, "tls_refused": tls_refused,
           "attack": (attack_result.get("row") or {}).get("notes") or attack_result.get("error")}
    row["meets_targets"] = bool(row["kept"] and row["min_range"] >= 0.5 * scenario.guidance.desired_range
                                and row["lockout"] <= LOCKOUT_LIMIT and not obeyed and row["attack_accepted_far"] == 0
                                and row["termination"] in ("completed", "diverged")
                                # counted wherever the receiver can see it (not an access-control denial)
                                and (counted or identity not in ("none", "foreign", None)))
    return row


def _jsonl(path: Path) -> list[dict]:
    records = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                records.append(json.loads(line))
            except ValueError:
                pass  # a line cut by a kill
    return records


def _sitl_attack_figures(run_folder: Path, rate_hz: float, home) -> dict:
    """From the run's logs: lockout (longest gap between accepted fixes' stamps, less one period, s),
    attack_messages (the attack events in the target's faults.jsonl, suppressed counts included, sent
    while the companion was still receiving) and attack_accepted_far (accepted fixes more than 5 m
    from what the genuine target published at that stamp, target.csv)."""
    received = _jsonl(run_folder / "companion" / "zenoh_rx.jsonl")
    heard_until = max((r["sim_time"] for r in received if isinstance(r.get("sim_time"), float)), default=math.inf)
    events = _jsonl(run_folder / "target" / "faults.jsonl")
    attack = 0
    first_attack = math.inf
    for e in events:
        if str(e.get("kind")).startswith("attack_") and e.get("time", 0.0) <= heard_until:
            attack += 1
            first_attack = min(first_attack, float(e.get("time", math.inf)))
        elif e.get("kind") == "suppressed" and str(e.get("key")).startswith("attack_") and e["first"] <= heard_until:
            attack += e["count"]
    accepted = [r for r in received if r.get("verdict") == "accepted" and isinstance(r.get("stamp"), float)]
    stamps = sorted(r["stamp"] for r in accepted)
    gaps = np.diff(stamps) if len(stamps) > 1 else np.array([0.0])
    published = {}
    table = run_folder / "target" / "target.csv"
    if table.exists():
        import csv

        with table.open() as handle:
            for line in csv.DictReader(handle):
                columns = [key for key in line if key.startswith("published_")]
                published[round(float(line["stamp"]), 6)] = [float(line[key]) for key in columns]
    far = 0
    for record in accepted:
        genuine = published.get(round(record["stamp"], 6))
        frame = record.get("frame", "ned")
        position = link_schema.TargetFix("x", 0, 0.0, frame, record["position"])
        if genuine is None:
            far += 1
            continue
        truth = link_schema.TargetFix("x", 0, 0.0, frame, genuine)
        distance = np.linalg.norm(link_schema.fix_to_ned(position, home) - link_schema.fix_to_ned(truth, home))
        far += int(not distance <= 5.0)
    return {"lockout": max(0.0, float(np.max(gaps)) - 1.0 / rate_hz), "attack_messages": attack,
            "attack_accepted_far": far, "first_attack": first_attack}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-campaign` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-campaign", description=__doc__.split("\n\n")[0],
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("config", nargs="?", type=scenario_file, default=DEFAULT_SCENARIO, help="scenario TOML")
    parser.add_argument("--seeds", type=int, default=10, help="in-process flights per pattern (seeds 1..N)")
    parser.add_argument("--patterns", nargs="+", default=list(PATTERNS), choices=list(PATTERNS), metavar="PATTERN",
                        help="fault patterns flown in process: " + "; ".join(
                            f"{name}: {description}".replace("%", "%%") for name, (_, description) in PATTERNS.items()))
    parser.add_argument("--sitl", nargs="*", default=[], choices=[*PATTERNS, *INTRUDER_PATTERNS], metavar="PATTERN",
                        help="patterns also flown once each in full SITL (bof-sitl: real processes, faults by sitl-target); "
                             "and, SITL only, intruders from outside against bof-sitl --secure: " + "; ".join(
                                 f"{name}: {description}" for name, (_, _, description) in INTRUDER_PATTERNS.items()))
    parser.add_argument("--sitl-speed", type=speed_factor_argument, default=5.0,
                        help=f"SITL speed factor, simulated seconds per wall second, within {SPEED_FACTOR_RANGE} "
                             "(bof-sitl's --speed-factor)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="worker processes for the in-process flights")
    parser.add_argument("--executor", default="local",
                        help="where the in-process flights run: local (processes), serial, dask-local, or tcp://scheduler:port")
    parser.add_argument("--out", type=output_folder, default=Path("runs"),
                        help="parent folder; the run goes to OUT/campaign-<scenario>-<time>/")
    parser.add_argument("--quiet", action="store_true", help="no progress bars (they go to stderr)")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.seeds < 1 or args.workers < 1:
        print("bof-campaign: --seeds and --workers must be >= 1", file=sys.stderr)
        return 2
    try:
        check_executor(args.executor, args.workers)
        check_flight_count(len(args.patterns) * args.seeds, "--patterns x --seeds")
        scenario, vehicle = load_scenario(args.config)
        tasks = [(name, seed, with_faults(scenario, PATTERNS[name][0]), vehicle)
                 for name in args.patterns for seed in range(1, args.seeds + 1)]
    except (ConfigError, ValueError) as error:
        print(f"bof-campaign: {error}", file=sys.stderr)
        return 2
    folder = new_run_folder(args.out, f"campaign-{scenario.name}")
    print(f"bof-campaign: {len(tasks)} in-process flights -> {folder}", flush=True)
    slots: list[dict | None] = [None] * len(tasks)
    try:
        executor = make_executor(args.executor, args.workers, say=reporting.say_as("bof-campaign"))
    except (RuntimeError, ValueError, OSError) as error:
        print(f"bof-campaign: {error}", file=sys.stderr)
        return 2
    results = None
    # Rows in completion order, each on disk as it arrives; renamed results.csv once every flight is in.
    partial = folder / "results.partial.csv"
    bar = reporting.progress_bar(len(tasks), "flights", enabled=not args.quiet, description="bof-campaign")
    throughput = reporting.Throughput(executor=executor.name)
    try:
        with RaisingStopSignals():
            try:
                for index, row in executor.map(_fly, tasks):
                    slots[index] = row
                    if results is None:
                        results = CsvLog(partial, row)
                    results.write(row)  # every row carries its pattern and seed
                    throughput.add(row["flown_s"])
                    bar.update()
            finally:
                throughput.executor = executor.name  # after map: a local pool starts no more processes than tasks
                throughput.stop()
                bar.close()
                executor.close()
                if results is not None:
                    results.close()
    except Interrupted as stop:
        print(reporting.interrupted("bof-campaign", stop, partial, len(tasks)), file=sys.stderr)
        return 128 + stop.signum
    if results is not None:
        partial.replace(folder / "results.csv")
    rows = [row for row in slots if row is not None]
    table = pattern_table(rows, scenario.guidance.desired_range)
    sitl_rows = [_sitl_intruder_case(args.config, name, folder / "sitl", args.sitl_speed) if name in INTRUDER_PATTERNS
                 else _sitl_case(args.config, name, folder / "sitl", args.sitl_speed, not args.quiet) for name in args.sitl]
    report = markdown(table, sitl_rows, scenario, args.seeds)
    report += f"\n\n{throughput.line('bof-campaign')} (in-process flights; SITL cases not counted)\n"
    (folder / "summary.md").write_text(report)
    write_summary(folder / "summary.json", {"patterns": table, "sitl": sitl_rows, "throughput": throughput.record()})
    print(reporting.for_terminal(report))
    print(f"run folder: {folder}")
    missed = [e["pattern"] for e in table + sitl_rows if e.get("meets_targets") is False]
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
