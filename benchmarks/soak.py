"""Soak: a whole bof-sitl flight under a bounded MAVLink and Zenoh flood; are memory and logs bounded?

    python benchmarks/soak.py [--duration 600] [--speed-factor 1] [--mavlink-rate 500] [--zenoh-rate 500] [--out runs]

Runs `bof-sitl` (the scenario's [simulation] duration set to --duration simulated seconds at
--speed-factor, so the companion follows that long) as a child in its own process group. Once the
companion follows, it floods from this process for as long as the companion follows (so a machine that cannot keep
--speed-factor still floods the whole flight):
* MAVLink (studies.intruder.mavlink_flood): --mavlink-rate datagrams/s of garbage and valid but
  unwanted messages to the plant's ground-station socket (read from the run's plant/stats.json);
* Zenoh (studies.intruder.zenoh_flood): --zenoh-rate messages/s of malformed and well-formed but
  wrong payloads on the target's fix key and the companion's command key.
Every --sample s (10) it records each process's resident memory (VmRSS from /proc/<pid>/status:
bof-sitl and every descendant), the run folder's total size in bytes and the companion's link
counters (from its state on Zenoh).

Output (soak-<time>/ in --out): soak.csv (one row per sample), soak.json (per process: max and last
RSS, RSS growth over the last half of following in simulated time (at most its last 30 minutes) and its
least-squares slope; log bytes first, last,
growth over the last half; the companion's deadline misses and reject counts and the plant's late
ticks, slips and MAVLink rejects, from the run's summaries; what the floods sent), the scenario it
flew, bof-sitl.out and the run folder. Every child is stopped on any exit (SIGINT, then SIGTERM,
then SIGKILL to each process group, descendants included). Linux only (/proc).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from interfaces import link_schema as link  # noqa: E402
from interfaces.overrides import format_assignment  # noqa: E402
from interfaces.records import CsvLog, write_json  # noqa: E402
from interfaces.scenario import DEFAULT_SCENARIO, load_scenario  # noqa: E402
from studies import intruder  # noqa: E402

#: s of simulated time: the longest stretch at the end of following whose memory growth is judged
JUDGED_S = 1800.0

ROLES = (("sitl_plant.world.target_publisher", "target"), ("sitl_plant.sitl", "plant"), ("companion", "companion"),
         ("bof-sitl", "bof-sitl"), ("studies.full_sitl", "bof-sitl"))


# --- /proc ----------------------------------------------------------------------------------

def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time in clock ticks) of `pid`, or None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) "
    return int(fields[1]), int(fields[19])


def descendants(root: int) -> dict[int, int]:
    """{pid: start time} of every live descendant of `root` (a scan of /proc)."""
    parents: dict[int, list[int]] = {}
    starts: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            stat = _stat(int(entry))
            if stat is not None:
                parents.setdefault(stat[0], []).append(int(entry))
                starts[int(entry)] = stat[1]
    found, todo = {}, [root]
    while todo:
        for child in parents.get(todo.pop(), []):
            if child not in found:
                found[child] = starts[child]
                todo.append(child)
    return found


def rss_kb(pid: int) -> int | None:
    """Resident set size of `pid` in kB (VmRSS), None if it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def role(pid: int) -> str:
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return f"pid{pid}"
    for needle, name in ROLES:
        if needle in command:
            return name
    return f"pid{pid}"


def folder_bytes(folder: Path) -> int:
    total = 0
    for directory, _, files in os.walk(folder):
        for name in files:
            try:
                total += os.path.getsize(os.path.join(directory, name))
            except OSError:
                pass
    return total


def stop_group(process: subprocess.Popen, others: dict[int, int], timeout: float = 15.0) -> None:
    """Stop bof-sitl (SIGINT: it stops its children and writes its summaries), then SIGTERM/SIGKILL its group,
    then every descendant seen (`others`: pid -> start time, so a reused pid is never signalled)."""
    for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        if process.poll() is not None:
            break
        try:
            os.killpg(process.pid, sig)
        except ProcessLookupError:
            break
        try:
            process.wait(wait)
        except subprocess.TimeoutExpired:
            continue
    for sig in (signal.SIGTERM, signal.SIGKILL):
        alive = [pid for pid, start in others.items() if (_stat(pid) or (0, None))[1] == start]
        for pid in alive:
            try:
                os.killpg(pid, sig) if os.getpgid(pid) == pid else os.kill(pid, sig)
            except (ProcessLookupError, PermissionError):
                pass
        if alive:
            time.sleep(2.0)


# --- the run ------------------------------------------------------------------------------------

def soak_scenario(config: Path, duration: float, path: Path) -> Path:
    """`config` with [simulation] duration (and [companion] follow_duration if set) = `duration` s, its vehicle file
    by absolute path, written to `path`."""
    with open(config, "rb") as handle:
        document = tomllib.load(handle)
    document["vehicle"] = str((config.parent / document.get("vehicle", "../vehicles/paper_table1.toml")).resolve())
    document.setdefault("simulation", {})["duration"] = float(duration)
    if "follow_duration" in document.get("companion", {}):  # it would cut the flight short
        document["companion"]["follow_duration"] = float(duration)
    lines = [format_assignment(k, v) for k, v in document.items() if not isinstance(v, dict)]
    for name, table in document.items():
        if isinstance(table, dict):
            lines += ["", f"[{name}]", *(format_assignment(k, v) for k, v in table.items())]
    path.write_text("\n".join(lines) + "\n")
    load_scenario(path)  # the same scenario, checked
    return path


class StateWatcher:
    """The companion's latest state on Zenoh (plain session: a soak of a secure SITL is for later)."""

    def __init__(self, endpoint: str, companion_id: str, namespace: str | None = None) -> None:
        self.latest: link.CompanionState | None = None
        self.session = intruder.open_peer(endpoint, namespace=namespace)
        self.session.declare_subscriber(link.companion_state_key(companion_id), self._on_state)

    def _on_state(self, sample) -> None:
        try:
            self.latest = link.decode_state(sample.payload)
        except link.PayloadError:
            pass

    def close(self) -> None:
        self.session.close()


def _slope_per_min(times: list[float], values: list[float]) -> float | None:
    if len(times) < 2:
        return None
    return round(float(np.polyfit(np.array(times) / 60.0, np.array(values, dtype=float), 1)[0]), 1)


def summarize(samples: list[dict], pids: dict[str, list[int]], run: Path | None) -> dict:
    """soak.json's figures from the samples (see the module docstring)."""
    out: dict = {"samples": len(samples), "processes": {}}
    following = [s for s in samples if s.get("phase") == "following" and s.get("sim_time") not in (None, "")]
    if following:  # the last half of following in simulated time, at most its last 30 minutes
        span = following[-1]["sim_time"] - following[0]["sim_time"]
        start = following[-1]["sim_time"] - min(span / 2.0, JUDGED_S)
        half = [s for s in following if s["sim_time"] >= start]
    else:
        half = samples[len(samples) // 2:]
    out["judged_sim_time_s"] = [half[0].get("sim_time"), half[-1].get("sim_time")] if half else None
    for name in pids:
        series = [(s["wall_s"], s[f"rss_kb_{name}"]) for s in samples if s.get(f"rss_kb_{name}") not in (None, "")]
        tail = [(t, v) for t, v in series if half and half[0]["wall_s"] <= t <= half[-1]["wall_s"]]
        out["processes"][name] = {
            "max_rss_kb": max((v for _, v in series), default=None),
            "last_rss_kb": series[-1][1] if series else None,
            "rss_growth_last_half_kb": tail[-1][1] - tail[0][1] if len(tail) >= 2 else None,
            "rss_slope_last_half_kb_per_min": _slope_per_min([t for t, _ in tail], [v for _, v in tail]),
        }
    logs = [s["log_bytes"] for s in samples]
    out["log_bytes"] = {"first": logs[0] if logs else None, "last": logs[-1] if logs else None,
                        "growth_last_half": half[-1]["log_bytes"] - half[0]["log_bytes"] if len(half) >= 2 else None,
                        "slope_last_half_bytes_per_min": _slope_per_min([s["wall_s"] for s in half],
                                                                        [s["log_bytes"] for s in half])}
    if run is not None and (run / "summary.json").exists():
        summary = json.loads((run / "summary.json").read_text())
        companion = summary.get("companion", {})
        out["companion"] = {"deadline_misses": companion.get("deadline_misses"),
                            "setpoints_sent": companion.get("setpoints_sent"),
                            "link_rejected": companion.get("link", {}).get("rejected"),
                            "link_accepted": companion.get("link", {}).get("accepted")}
        out["plant"] = summary.get("plant")
        out["flight"] = {k: (summary.get("flight") or {}).get(k) for k in ("min_range", "range_error_rms", "max_tilt_deg")}
    elif run is not None:
        out["summary_missing"] = f"{run / 'summary.json'} not written"
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_SCENARIO, help="scenario TOML (default: %(default)s)")
    parser.add_argument("--duration", type=float, default=600.0,
                        help="simulated seconds to follow; the floods last as long (default: %(default)s)")
    parser.add_argument("--speed-factor", type=float, default=1.0,
                        help="simulated seconds per wall second of the flight, 0.5 to 20 (default: %(default)s)")
    parser.add_argument("--mavlink-rate", type=float, default=500.0, help="MAVLink flood, datagrams/s (default: %(default)s)")
    parser.add_argument("--zenoh-rate", type=float, default=500.0, help="Zenoh flood, messages/s (default: %(default)s)")
    parser.add_argument("--sample", type=float, default=10.0, help="seconds between samples (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("runs"), help="parent of the soak-<time>/ folder (default: %(default)s)")
    args = parser.parse_args(argv)
    for name in ("duration", "speed_factor", "mavlink_rate", "zenoh_rate", "sample"):
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            parser.error(f"--{name.replace('_', '-')} must be positive")
    def interrupted(signum, frame):  # noqa: ARG001 - SIGTERM/SIGHUP end the soak like Ctrl-C: the finally cleans up
        raise KeyboardInterrupt

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, interrupted)
    scenario, _ = load_scenario(args.config)
    folder = args.out / f"soak-{time.strftime('%Y%m%d-%H%M%S')}"
    folder.mkdir(parents=True)
    config = soak_scenario(args.config, args.duration, folder / "scenario.toml")
    wall = args.duration / args.speed_factor  # s of following at the asked speed
    flood_limit = 10.0 * wall + 600.0  # wall s; the floods end when following does, long before this
    command = [sys.executable, "-m", "studies.full_sitl", str(config), "--speed-factor", f"{args.speed_factor:g}",
               "--out", str(folder / "runs"), "--no-plots", "--timeout", str(wall + 300.0)]
    log = (folder / "bof-sitl.out").open("w")
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
    seen: dict[int, int] = {}
    names: dict[str, list[int]] = {}
    samples: list[dict] = []
    floods: dict[str, dict] = {}
    threads: list[threading.Thread] = []
    watcher = None
    run = None
    # Columns fixed up front (a process not running yet leaves its cell empty; other processes are not in the CSV,
    # they are in soak.json).
    csv = CsvLog(folder / "soak.csv", ["wall_s", "flooding", "sim_time", "phase", "log_bytes", "fixes_accepted",
                                       "fixes_rejected", *[f"rss_kb_{n}" for n in ("bof-sitl", "plant", "target",
                                                                                    "companion")]], ignore_extra=True)
    stop = threading.Event()
    started = time.monotonic()
    flood_started = None
    try:
        while process.poll() is None:
            if run is None:
                try:
                    endpoints = intruder.discover(folder / "runs")
                except FileNotFoundError:
                    endpoints = None
                if endpoints is not None and endpoints.zenoh and endpoints.gcs:
                    run = endpoints.run
                    watcher = StateWatcher(endpoints.zenoh, scenario.link.companion_id, endpoints.namespace)
            if (flood_started is None and watcher is not None and watcher.latest is not None
                    and watcher.latest.phase == "following"):
                flood_started = time.monotonic()
                endpoints = intruder.discover(run)
                session = intruder.open_peer(endpoints.zenoh, namespace=endpoints.namespace)  # the run's own

                def zenoh_flood() -> None:
                    try:
                        floods["zenoh"] = intruder.zenoh_flood(session, scenario.link.target_sender,
                                                               scenario.link.companion_id, rate_hz=args.zenoh_rate,
                                                               duration=flood_limit, stop=stop).summary()
                    finally:
                        session.close()

                def mavlink_flood() -> None:
                    result = intruder.mavlink_flood(*endpoints.gcs, rate_hz=args.mavlink_rate, duration=flood_limit,
                                                    stop=stop)
                    floods["mavlink"] = {"sent": result.sent, "notes": result.notes, "target": list(endpoints.gcs)}

                threads = [threading.Thread(target=zenoh_flood, daemon=True),
                           threading.Thread(target=mavlink_flood, daemon=True)]
                for thread in threads:
                    thread.start()
            if (flood_started is not None and not stop.is_set() and watcher.latest is not None
                    and watcher.latest.phase != "following"):
                stop.set()  # following ended: so do the floods
            now = time.monotonic()
            if not samples or now - started >= samples[-1]["wall_s"] + args.sample:
                live = {process.pid: (_stat(process.pid) or (0, 0))[1], **descendants(process.pid)}
                seen.update(live)
                row = {"wall_s": round(now - started, 1), "flooding": int(any(t.is_alive() for t in threads))}
                for pid in live:
                    name = role(pid)
                    names.setdefault(name, [])
                    if pid not in names[name]:
                        names[name].append(pid)
                    value = rss_kb(pid)
                    if value is not None:
                        row[f"rss_kb_{name}"] = row.get(f"rss_kb_{name}", 0) + value
                row["log_bytes"] = folder_bytes(run) if run is not None else 0
                state = watcher.latest if watcher is not None else None
                row.update(sim_time=state.stamp if state else "", phase=state.phase if state else "",
                           fixes_accepted=state.link.accepted if state else "",
                           fixes_rejected=sum(state.link.rejected.values()) if state else "")
                samples.append(row)
                csv.write(row)
                print(f"soak: {json.dumps(row)}", flush=True)
            time.sleep(0.2)
    except KeyboardInterrupt:
        print("soak: interrupted; stopping bof-sitl and its children", file=sys.stderr)
    finally:
        stop.set()
        stop_group(process, seen)
        for thread in threads:
            thread.join(10.0)
        if watcher is not None:
            watcher.close()
        csv.close()
        log.close()
    result = summarize(samples, names, run)
    result.update(bof_sitl_exit_code=process.returncode, duration=args.duration, speed_factor=args.speed_factor,
                  mavlink_rate=args.mavlink_rate,
                  zenoh_rate=args.zenoh_rate, run_folder=str(run) if run else None, floods=floods,
                  flood_started_after_s=round(flood_started - started, 1) if flood_started else None)
    write_json(folder / "soak.json", result, indent=2, sort_keys=True)
    print(json.dumps(result, indent=2, sort_keys=True))
    return 0 if process.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
