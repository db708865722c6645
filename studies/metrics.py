"""Figures of merit of one flight, the same for both harnesses, and the run folder's summary.json.

`summarize` takes a flight series (the in-process simulator's FlightLog.series(), or the
SITL run's studies.sitl_runs.flight_series(): the same keys) and returns the figures
bof-sim, bof-sitl, the campaign and the Monte Carlo study report. A figure that does not
apply (no convergence, no observability data) is NaN in memory and `null` in summary.json:
`write_summary` turns every non-finite number into null and refuses to write NaN, which is
not JSON.

Two judgements of a flight sit side by side: the filter-health monitor's, which flies without truth
("monitor_verdict"), and the truth's, which only a simulation knows ("truth": `truth_outcome`). "verdict"
is the monitor's word made honest: never "clean" or "recovered" for a flight diverged by truth.
"""

from __future__ import annotations

import enum
import math
from pathlib import Path

import numpy as np

from interfaces.records import write_json
from interfaces.scenario import Scenario, VehicleConfig


def rms(values: np.ndarray) -> float:
    """Root mean square of a 1-D array (units of the input); NaN when empty."""
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan


def median_finite(values: np.ndarray | None, window: np.ndarray) -> float:
    """Median of the finite values of `values` (N,) inside the boolean `window` (N,); NaN when there
    are none or no series. Used for the windowed FIM's log10 det (section V, eq. (7)), which is -inf
    while the FIM is singular."""
    if values is None:
        return math.nan
    chosen = values[window]
    chosen = chosen[np.isfinite(chosen)]
    return float(np.median(chosen)) if chosen.size else math.nan


def convergence_time(time: np.ndarray, range_error: np.ndarray, estimation_error: np.ndarray,
                     threshold: float) -> float:
    """First time (s, from `time` (N,)) after which |range_error| and |estimation_error| (N,, m) both
    stay below `threshold` (m) to the end; NaN if they are not both below it at the last sample."""
    outside = ~((np.abs(range_error) < threshold) & (np.abs(estimation_error) < threshold))
    if not outside.any():
        return float(time[0])
    if outside[-1]:
        return math.nan
    return float(time[np.nonzero(outside)[0][-1] + 1])


def suspect_flags(suspect: np.ndarray) -> np.ndarray:
    """The health series (N,) (1 SUSPECT, 0 OK, NaN before the monitor's first verdict) as bool: flagged or not."""
    return np.nan_to_num(np.asarray(suspect, dtype=float), nan=0.0) > 0.5


def suspected_divergence(time: np.ndarray, suspect: np.ndarray | None, window: np.ndarray) -> dict | None:
    """How long and how often the filter-health monitor (companion.core.health) called the estimate suspect.

    time (N,) s; suspect (N,) 1 while SUSPECT, 0 while OK, NaN before the monitor's first
    verdict; window (N,) bool, the summary window. Returns None without a health series, else
    seconds (s flagged, each sample holding until the next), episodes (OK -> SUSPECT changes,
    a flight starting suspect counts one), recoveries (SUSPECT -> OK changes: episodes that ended),
    first_time (s of the first flag, None if never), in_last_window (flagged at any time in the
    summary window) and at_end (flagged at the last sample).
    """
    if suspect is None:
        return None
    flagged = suspect_flags(suspect)
    held = np.diff(time, append=time[-1])
    starts = np.flatnonzero(flagged & ~np.concatenate([[False], flagged[:-1]]))
    ends = np.flatnonzero(~flagged[1:] & flagged[:-1])
    return {
        "seconds": float(np.sum(held[flagged])),
        "episodes": int(starts.size),
        "recoveries": int(ends.size),
        "first_time": float(time[starts[0]]) if starts.size else None,
        "in_last_window": bool(np.any(flagged[window])),
        "at_end": bool(flagged[-1]),
    }


#: Terminations after which the estimate's verdict still says something (the flight ran as asked, or was
#: stopped from outside); any other termination is a "failed" verdict.
FLOWN = ("COMPLETED", "DIVERGED", "ABORTED", "INTERRUPTED")


def termination_name(termination: enum.Enum) -> str:
    """summary.json's "termination": the lower-case name of a studies.closed_loop.Termination (completed,
    aborted, failsafe, interrupted, diverged, estimate_not_finite, out_of_control)."""
    return termination.name.lower()


def honest_termination(termination: enum.Enum, divergence: dict | None) -> enum.Enum:
    """A flight that flew to the end while the health monitor called its estimate suspect at the end is
    DIVERGED, never COMPLETED; any other termination is returned as it is. `termination` is a
    studies.closed_loop.Termination (looked up by name, so that this module need not import the loop)."""
    if termination.name == "COMPLETED" and divergence is not None and divergence["at_end"]:
        return type(termination)["DIVERGED"]
    return termination


def monitor_verdict(termination: enum.Enum, divergence: dict | None, estimated: bool = True) -> str:
    """The health monitor's own word for the flight, without truth: "failed" (did not fly as asked: FLOWN lists what
    did), "no_estimate" (flown, but `estimated` is False: no estimate over the summary window, e.g. no bearing was
    ever used, so nothing measured the estimate and the monitor had nothing to flag), "suspect" (the health monitor
    still called the estimate suspect at the end: the flight's range may be wrong), "recovered" (it called it suspect
    at some time and OK again at the end: the range was doubted during the flight, so not a clean success either),
    else "clean" (never flagged)."""
    if termination.name not in FLOWN:
        return "failed"
    if not estimated:
        return "no_estimate"
    if divergence is not None and divergence["at_end"]:
        return "suspect"
    if divergence is not None and divergence["episodes"] > 0:
        return "recovered"
    return "clean"


def verdict(termination: enum.Enum, divergence: dict | None, estimated: bool = True, diverged: bool = False) -> str:
    """summary.json's "verdict": the monitor's word (`monitor_verdict`), except that a flight `diverged` by truth
    (its range-estimation error RMS over the summary window above [simulation] divergence_rms, see `truth_outcome`)
    is never "clean" or "recovered": the monitor missed it, and the verdict is "diverged"."""
    word = monitor_verdict(termination, divergence, estimated)
    return "diverged" if diverged and word in ("clean", "recovered") else word


def _seconds_where(time: np.ndarray, condition: np.ndarray) -> float:
    """Seconds during which `condition` (N,) bool held, each sample of `time` (N,) s holding until the next."""
    held = np.diff(time, append=time[-1])
    return float(np.sum(held[condition]))


def truth_outcome(time: np.ndarray, range_: np.ndarray, tilt_deg: np.ndarray, estimation_rms: float,
                  *, estimated: bool, flown: bool, desired_range: float, divergence_rms: float,
                  tilt_limit_deg: float, suspect_at_end: bool, estimation_error: np.ndarray | None = None,
                  suspect: np.ndarray | None = None, window: np.ndarray | None = None) -> dict:
    """What the truth says about a simulated flight (summary.json's "truth"), beside the monitor's verdict.

    time (N,) s; range_ (N,) true |p_T - p|, m; tilt_deg (N,) the pursuer's tilt, deg; estimation_rms: the
    range-estimation error RMS over the summary window, m (NaN when the estimate was missing for part of it);
    estimated: any estimate over the window; flown: the termination is one of FLOWN; desired_range r_d, m;
    divergence_rms: threshold, m; tilt_limit_deg: the airframe's max_tilt_deg; suspect_at_end: the health monitor
    called the estimate suspect at the last sample. estimation_error (N,) m: the range-estimation error
    |p^_T - p| - |p_T - p| (NaN where there was no estimate); suspect (N,) bool: the monitor's verdict at each sample;
    window (N,) bool: the summary window. Without all three (a log without the monitor's verdicts) the monitor's
    record while the estimate was wrong is not judged: its figures are 0 s and False.

    Returns range_estimation_error_rms (m), divergence_rms (m), diverged (an estimate was there and its RMS is not
    <= divergence_rms: a NaN RMS counts as diverged), min_range (m, the closest approach over the series),
    half_desired_range (r_d / 2, m), min_range_breached (min_range < r_d / 2), seconds_below_half_desired_range (s),
    max_tilt_deg (deg), tilt_limit_deg (deg), tilt_exceeded (max tilt > the limit), seconds_above_tilt_limit (s),
    monitor_missed (diverged, yet not suspect at the end), monitor_false_alarm (suspect at the end, yet not
    diverged), seconds_estimate_wrong (s of the summary window with |range-estimation error| above divergence_rms),
    seconds_wrong_flagged (of those, the seconds the monitor called the estimate suspect), monitor_silent_while_wrong
    (diverged, off by more than the limit for some time of the window, and the monitor never called the estimate
    suspect while it was that far off: a miss while it mattered, not only at the end; a flight without an estimate
    to be off is not) and outcome, one word: "failed" (did not fly as asked), "no_estimate" (no estimate over the window),
    "diverged", "envelope_breached" (closer than r_d / 2 or tilted past the limit), else "success"; the first that
    applies in that order (the flags say which others apply too).
    """
    half = 0.5 * desired_range
    diverged = bool(estimated and not estimation_rms <= divergence_rms)
    wrong_seconds = flagged_seconds = 0.0
    judged = estimation_error is not None and suspect is not None and window is not None
    if judged:
        with np.errstate(invalid="ignore"):
            wrong = window & (np.abs(estimation_error) > divergence_rms)
        wrong_seconds = _seconds_where(time, wrong)
        flagged_seconds = _seconds_where(time, wrong & suspect)
    min_range = float(np.min(range_))
    max_tilt = float(np.max(tilt_deg))
    breached = bool(min_range < half)
    exceeded = bool(max_tilt > tilt_limit_deg)
    if not flown:
        outcome = "failed"
    elif not estimated:
        outcome = "no_estimate"
    elif diverged:
        outcome = "diverged"
    elif breached or exceeded:
        outcome = "envelope_breached"
    else:
        outcome = "success"
    return {
        "outcome": outcome,
        "range_estimation_error_rms": estimation_rms,
        "divergence_rms": divergence_rms,
        "diverged": diverged,
        "min_range": min_range,
        "half_desired_range": half,
        "min_range_breached": breached,
        "seconds_below_half_desired_range": _seconds_where(time, range_ < half),
        "max_tilt_deg": max_tilt,
        "tilt_limit_deg": tilt_limit_deg,
        "tilt_exceeded": exceeded,
        "seconds_above_tilt_limit": _seconds_where(time, tilt_deg > tilt_limit_deg),
        "monitor_missed": bool(diverged and not suspect_at_end),
        "monitor_false_alarm": bool(suspect_at_end and not diverged),
        "seconds_estimate_wrong": wrong_seconds,
        "seconds_wrong_flagged": flagged_seconds,
        "monitor_silent_while_wrong": bool(judged and diverged and wrong_seconds > 0.0 and flagged_seconds == 0.0),
    }


def truth_failed(flight: dict) -> bool:
    """True when a `summarize` result (or its JSON) diverged by truth or breached an envelope (closer than r_d / 2,
    tilted past the airframe's limit): the commands that judge one flight then exit 1."""
    truth = flight.get("truth") or {}
    return bool(truth.get("diverged") or truth.get("min_range_breached") or truth.get("tilt_exceeded"))


def _figure(value: float | None, spec: str, unit: str) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{format(value, spec)} {unit}"


def outcome_lines(flight: dict, who: str = "") -> list[str]:
    """The closing block for people: the truth's outcome in words beside the monitor's verdict, then each envelope
    with BREACHED when it was. flight: a `summarize` result (or its JSON, where NaN is null); who: named in the
    first line (e.g. "pursuer 2"), nothing by default."""
    truth = flight["truth"]
    rms_text = _figure(truth["range_estimation_error_rms"], ".2f", "m")
    words = {"success": "success: estimate within the divergence limit, no envelope breached",
             "envelope_breached": "ENVELOPE BREACHED",
             "diverged": "DIVERGED: range estimate wrong by truth",
             "no_estimate": "NO ESTIMATE over the summary window",
             "failed": "FAILED: the flight did not fly as asked"}
    monitor = flight.get("monitor_verdict", flight.get("verdict"))
    judged = monitor not in ("failed", "no_estimate")  # those words come from the flight, not from the monitor
    note = ("  (the monitor missed it)" if judged and truth["monitor_missed"] else
            "  (the monitor's false alarm)" if judged and truth["monitor_false_alarm"] else "")
    half, limit = truth["half_desired_range"], truth["tilt_limit_deg"]
    return [
        f"outcome (truth{', ' + who if who else ''}): {words.get(truth['outcome'], truth['outcome'])}; monitor verdict: {monitor}{note}",
        f"  range-estimation rms {rms_text} over the last {flight['summary_window']:g} s  "
        + (f"DIVERGED (limit {truth['divergence_rms']:g} m)" if truth["diverged"]
           else f"ok (limit {truth['divergence_rms']:g} m)"),
        f"  closest approach {truth['min_range']:.2f} m  "
        + (f"BREACHED (r_d/2 = {half:.1f} m, {truth['seconds_below_half_desired_range']:.1f} s below)"
           if truth["min_range_breached"] else f"ok (r_d/2 = {half:.1f} m)"),
        f"  max tilt {truth['max_tilt_deg']:.1f} deg  "
        + (f"BREACHED (limit {limit:g} deg, {truth['seconds_above_tilt_limit']:.1f} s above)"
           if truth["tilt_exceeded"] else f"ok (limit {limit:g} deg)"),
    ] + monitor_record_lines(flight) + envelope_lines(flight)


def monitor_record_lines(flight: dict) -> list[str]:
    """One line on what the monitor said while the estimate was off by more than the divergence limit in the
    summary window (the truth's seconds_estimate_wrong and seconds_wrong_flagged); none when it never was, or for a
    summary written before the truth carried them."""
    truth = flight["truth"]
    wrong = truth.get("seconds_estimate_wrong")
    if not wrong:
        return []
    flagged = truth["seconds_wrong_flagged"]
    silent = "  (SILENT while it was wrong)" if flagged == 0.0 else ""
    return [f"  estimate more than {truth['divergence_rms']:g} m off for {wrong:.1f} s of the last "
            f"{flight['summary_window']:g} s; the monitor flagged {flagged:.1f} s of them{silent}"]


def envelope_lines(flight: dict) -> list[str]:
    """One line on how often the safety envelope acted (companion.core.safety: the closing-speed limit and the
    heading's rate), from the flight's "envelope" (in process) or its companion's (SITL); none without either."""
    record = flight.get("envelope") or (flight.get("companion") or {}).get("envelope")
    if not record:
        return []
    if not record["closing_ticks"] and not record["heading_ticks"]:
        return ["  safety envelope: never acted"]
    headway, hover = record.get("speed_change_seconds", 0.0), record.get("hover_seconds", 0.0)
    late = record.get("loop_delay_max", 0.0)
    return [f"  safety envelope acted: closing speed limited {record['closing_seconds']:.1f} s, "
            f"heading rate limited {record['heading_seconds']:.1f} s"
            + (f"; planned for a target changing speed {headway:.1f} s" if headway else "")
            + (f"; kept off a slow target {hover:.1f} s" if hover else "")
            + (f"; planned for a control loop up to {late:.2f} s late" if late else "")]


def suspect_warning(flight: dict, reasons: list[str] | tuple[str, ...] = ()) -> str | None:
    """The warning line for people when the health monitor called the estimate suspect at the end, or when there
    was no estimate to judge (verdict "no_estimate"), else None.

    flight: a `summarize` result (or its JSON). reasons: the monitor's reasons at the end, if known.
    """
    if flight.get("verdict") == "no_estimate":
        seen = flight.get("bearings_used")
        why = "" if seen is None else f": {seen} bearings used, {flight.get('bearings_out_of_view', 0)} out of view"
        return f"WARNING: no range estimate over the last {flight['summary_window']:g} s{why} — not a success"
    divergence = flight.get("suspected_divergence")
    if not divergence or not divergence.get("at_end"):
        return None
    why = f" ({', '.join(reasons)})" if reasons else ""
    return (f"WARNING: estimate suspect at the end{why}, flagged {divergence['seconds']:.1f} s in "
            f"{divergence['episodes']} episode(s) — do not trust this flight's range")


def summarize(series: dict[str, np.ndarray], scenario: Scenario, termination: enum.Enum,
              vehicle: VehicleConfig) -> dict:
    """Figures of merit over the last simulation.summary_window seconds, plus whole-flight extremes and the truth.

    series: "time" (N,) s; "range", "range_estimate" (N,) m; "pursuer_tilt", "heading_error" (N,)
    deg; "estimate_position", "target_position" (N, 3) m; "estimate_velocity", "target_velocity",
    "pursuer_velocity" (N, 3) m/s; optional "observability_log_det" (N,) and "health_suspect" (N,)
    (see `suspected_divergence`). vehicle: the airframe flown (its max_tilt_deg is the tilt envelope).
    range_error: |p_T - p| - r_d (m); range_estimation_error: |p^_T - p| - |p_T - p| (m);
    convergence_time: see `convergence_time` (NaN: did not converge). termination: why the flight
    ended (studies.closed_loop.Termination); "termination" is its lower-case name and "termination_reason"
    its sentence, after `honest_termination` (a completed flight whose estimate was suspect at the end is
    "diverged").

    Judgements: "truth" is what the known truth says (`truth_outcome`: "outcome" success / envelope_breached /
    diverged / no_estimate / failed, "diverged" when the range-estimation error RMS over the window is above
    [simulation] divergence_rms, the r_d / 2 and tilt envelopes, "monitor_missed", "monitor_false_alarm");
    "monitor_verdict" is the health monitor's own truth-free word (`monitor_verdict`); "verdict" is that word, except
    "diverged" where the monitor said clean or recovered of a flight diverged by truth (`verdict`).
    """
    time = series["time"]
    window = time >= time[-1] - scenario.simulation.summary_window
    range_error = series["range"] - scenario.guidance.desired_range
    estimation_error = series["range_estimate"] - series["range"]
    position_error = np.linalg.norm(series["estimate_position"] - series["target_position"], axis=1)
    velocity_error = np.linalg.norm(series["estimate_velocity"] - series["target_velocity"], axis=1)
    threshold = scenario.simulation.converged_range_error
    heading_error = series["heading_error"][window]
    divergence = suspected_divergence(time, series.get("health_suspect"), window)
    termination = honest_termination(termination, divergence)
    estimated = bool(np.isfinite(estimation_error[window]).any())
    estimation_rms = rms(estimation_error[window])
    suspect = series.get("health_suspect")
    truth = truth_outcome(time, series["range"], series["pursuer_tilt"], estimation_rms, estimated=estimated,
                          flown=termination.name in FLOWN, desired_range=scenario.guidance.desired_range,
                          divergence_rms=scenario.simulation.divergence_rms, tilt_limit_deg=vehicle.max_tilt_deg,
                          suspect_at_end=divergence is not None and divergence["at_end"],
                          estimation_error=estimation_error, window=window,
                          suspect=None if suspect is None else suspect_flags(suspect))
    return {
        "scenario": scenario.name,
        "termination": termination_name(termination),
        "termination_reason": termination.value,
        "duration": float(time[-1]),
        "summary_window": scenario.simulation.summary_window,
        "desired_range": scenario.guidance.desired_range,
        "range_error_rms": rms(range_error[window]),
        "range_error_max_abs": float(np.max(np.abs(range_error[window]))),
        "range_estimation_error_rms": estimation_rms,
        "range_estimation_error_max_abs": float(np.max(np.abs(estimation_error[window]))),
        "position_estimation_error_rms": rms(position_error[window]),
        "velocity_estimation_error_rms": rms(velocity_error[window]),
        "convergence_time": convergence_time(time, range_error, estimation_error, threshold),
        "convergence_threshold": threshold,
        "min_range": truth["min_range"],
        "max_tilt_deg": truth["max_tilt_deg"],
        "max_speed": float(np.max(np.linalg.norm(series["pursuer_velocity"], axis=1))),
        "heading_error_rms_deg": rms(heading_error[np.isfinite(heading_error)]),
        "observability_log_det_median": median_finite(series.get("observability_log_det"), window),
        "suspected_divergence": divergence,
        "monitor_verdict": monitor_verdict(termination, divergence, estimated),
        "verdict": verdict(termination, divergence, estimated, truth["diverged"]),
        "truth": truth,
        "final_estimate": final_estimate(time, series["estimate_position"]),
    }


def final_estimate(time: np.ndarray, estimate_position: np.ndarray) -> dict | None:
    """The last finite estimated target position: {"time": s in the series' time, "position": [n, e, d] m}."""
    finite = np.flatnonzero(np.all(np.isfinite(estimate_position), axis=1))
    if len(finite) == 0:
        return None
    last = finite[-1]
    return {"time": float(time[last]), "position": [float(v) for v in estimate_position[last]]}


def convergence_text(summary: dict, after: str = "") -> str:
    """One line for people: "converged (...) at t = 12.34 s[ after]" or "did not converge (...)".

    summary: a `summarize` result (convergence_time may be NaN, or None when read back from JSON).
    """
    condition = f"both errors < {summary['convergence_threshold']:g} m for good"
    time = summary["convergence_time"]
    if time is None or not math.isfinite(time):
        return f"did not converge ({condition} never held to the end)"
    return f"converged ({condition}) at t = {time:.2f} s{after}"


def write_summary(path: Path, document: dict, sort_keys: bool = False) -> None:
    """Write a summary as indented JSON to `path`, non-finite numbers as null (interfaces.records.write_json);
    anything not representable raises instead of producing invalid JSON."""
    write_json(path, document, indent=2, sort_keys=sort_keys)
