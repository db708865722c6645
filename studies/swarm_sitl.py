"""`bof-sitl` for a [swarm] scenario: one plant and one companion per pursuer, one target, one Zenoh network.

    bof-sitl config/scenarios/swarm_circumnavigation.toml [--speed-factor 1] [--secure] [--out runs]

studies.full_sitl.main comes here when the scenario has [swarm]. For pursuer K = 1..N it starts

* a plant: ``sitl-plant --pursuer-id K --system-id K`` (pursuer K's [[swarm.pursuers]] start, its own MAVLink
  system id and companion port; every plant streams ground-station telemetry to the one --gcs-port, where a
  ground station sees N vehicles told apart by their system ids). All plants get the same ``--clock-anchor``
  (CLOCK_MONOTONIC s at which simulated time is 0), so they share one simulated clock, the clock the target's
  fixes and every share are stamped in. Only pursuer 1's plant is on Zenoh (it listens; it publishes
  bof/sim/clock for the target).
* a companion: ``companion --pursuer-id K`` on its plant's port: it flies pursuer K, publishes its
  bof.pursuer_share/1 on bof/swarm/K/share and hears the others' (companion.swarm_link); its state and
  command keys use the companion id ``<[link] companion_id>-K``.

and one ``sitl-target`` (waiting for "start", which this ground station sends when every companion follows,
leaving out any companion that has already ended).
Every process joins the same Zenoh network in one namespace (plain) or with mutual TLS and access control
(--secure: every companion uses the companion certificate, which may put bof/swarm/*/share). SIGINT,
SIGTERM and SIGHUP stop every child (companions first, then the target and the plants) and the summaries are
still written.

The run folder sitl-<scenario>-seed<seed>-<time>/::

    pursuer-K/plant/ pursuer-K/companion/   pursuer K's plant and companion logs (as bof-sitl's plant/ and
    pursuer-K/plant.out companion.out       companion/; companion/swarm_rx.jsonl: the shares it received)
    target/ target.out                      the one target
    summary.json    the in-process layout (studies.swarm): pursuer 1's single-pursuer keys at the top,
                    `pursuers` (one entry per pursuer: its figures, its companion's summary, its plant's
                    pacing), `phase_spacing_error_deg_rms`, `min_pursuer_separation`, and `cpu` (user +
                    system CPU s and share of one core per child process, psutil, sampled to the end)
    tracks.png      every pursuer's track and estimate around the target (studies.plots.plot_swarm_tracks)
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from companion.swarm_link import swarm_companion_id
from companion.assembly import pursuer_scenario
from companion.core.cooperative_guidance import phase_spacing_errors
from interfaces import link_schema as link
from interfaces import zenoh_transport
from interfaces.records import write_json
from interfaces.scenario import ConfigError, Scenario, VehicleConfig, pursuer_starts
from studies.metrics import outcome_lines, rms, summarize, termination_name, write_summary
from studies.processes import ChildProcess, Interrupted, StopSignals, free_port, start_together, stop_all
from studies.flight_mcap import write_sitl_mcap
from studies.sitl_runs import (SitlOptions, live_args, Stopped, ZenohNetwork, fail_on_early_exit, flight_series, interp,
                               make_run_folder, read_csv, read_json, run_termination, watch)

#: Wall s between the start of the first plant and simulated time 0 of every plant, per pursuer (the plants
#: start one after the other; one that starts late catches up on the ground, before anyone connects).
ANCHOR_LEAD_PER_PURSUER = 1.5
#: Wall s between two CPU samples of the children.
CPU_SAMPLE_PERIOD = 0.5


def plant_seed(seed: int, ident: int) -> int:
    """Pursuer `ident`'s plant telemetry-noise seed: `seed` for pursuer 1, a derived one for the others."""
    if ident == 1:
        return seed
    return int(np.random.SeedSequence(seed, spawn_key=(0x504C, ident)).generate_state(1)[0])


class SwarmGroundStation:
    """Watches every companion's state on Zenoh and starts the target once they all follow."""

    def __init__(self, endpoint: str, scenario: Scenario, tls: zenoh_transport.Identity | None,
                 namespace: str | None) -> None:
        self.session = zenoh_transport.open_session(zenoh_transport.zenoh_config("peer", listen=(), connect=(endpoint,),
                                                                                 tls=tls, namespace=namespace))
        self.ids = [swarm_companion_id(scenario.link.companion_id, k) for k in range(1, scenario.swarm.count + 1)]
        self.latest: dict[str, link.CompanionState] = {}
        for companion_id in self.ids:
            self.session.declare_subscriber(link.companion_state_key(companion_id), self._on_state)
        self._target_command = zenoh_transport.publisher(self.session, link.target_command_key(scenario.link.target_sender))
        self.epoch = link.new_epoch()
        self.target_started = False
        self.started_stamp: float | None = None

    def _on_state(self, sample) -> None:
        try:
            state = link.decode_state(sample.payload)
        except link.PayloadError:
            return
        if state.sender in self.ids:
            self.latest[state.sender] = state

    def all_following(self, gone: frozenset[str] = frozenset()) -> bool:
        """Every companion follows, except those in `gone` (ended: they will never follow); at least one does."""
        waiting = [i for i in self.ids if i not in gone]
        return bool(waiting) and all(i in self.latest and self.latest[i].phase == "following" for i in waiting)

    def start_target(self) -> None:
        stamp = max(s.stamp for s in self.latest.values())
        self._target_command.put(link.encode_command(link.Command("ground-station", 1, stamp, "start", epoch=self.epoch)))
        self.target_started, self.started_stamp = True, stamp

    def progress(self) -> str:
        if not self.latest:
            return "waiting for the companions"
        parts = []
        for companion_id in self.ids:
            state = self.latest.get(companion_id)
            if state is None:
                parts.append(f"{companion_id}: -")
                continue
            text = f"{companion_id}: {state.phase}"
            if state.estimate is not None and state.estimate.range is not None:
                text += f" r^={state.estimate.range:.1f}"
            parts.append(text)
        stamp = max(s.stamp for s in self.latest.values())
        return f"t={stamp:6.1f}s " + ", ".join(parts)

    def close(self) -> None:
        self.session.close()


class CpuMeter:
    """User + system CPU seconds of each child (and its descendants), sampled until it ends (psutil)."""

    def __init__(self) -> None:
        import psutil

        self._psutil = psutil
        self.samples: dict[str, dict] = {}
        self._next = 0.0

    def sample(self, children: dict[str, ChildProcess], force: bool = False) -> None:
        now = time.monotonic()
        if not force and now < self._next:
            return
        self._next = now + CPU_SAMPLE_PERIOD
        for name, child in children.items():
            if not child.running:
                continue
            try:
                process = self._psutil.Process(child.process.pid)
                total = process.cpu_times()
                cpu = total.user + total.system
                for descendant in process.children(recursive=True):
                    try:
                        times = descendant.cpu_times()
                        cpu += times.user + times.system
                    except self._psutil.Error:
                        continue
                started = process.create_time()
            except self._psutil.Error:
                continue
            self.samples[name] = {"cpu_s": round(cpu, 3), "wall_s": round(time.time() - started, 3)}

    def report(self) -> dict:
        """{child: {cpu_s, wall_s, cpu_share (of one core)}}, from the last sample of each child."""
        out = {}
        for name, sample in self.samples.items():
            share = sample["cpu_s"] / sample["wall_s"] if sample["wall_s"] > 0 else None
            out[name] = {**sample, "cpu_share": None if share is None else round(share, 4)}
        return out


def _engaged_spans(folder: Path, count: int) -> list[tuple[float, float] | None]:
    """Per pursuer, (first, last) simulated time it was following with an estimate (None: never)."""
    spans = []
    for ident in range(1, count + 1):
        try:
            series = read_csv(folder / f"pursuer-{ident}" / "companion" / "series.csv")
        except (FileNotFoundError, IndexError):
            spans.append(None)
            continue
        engaged = np.isfinite(series.get("est_x", np.array([]))) & (series.get("phase", np.array([])) == "following")
        spans.append(None if not engaged.any() else (float(series["time"][engaged][0]), float(series["time"][engaged][-1])))
    return spans


def swarm_geometry(folder: Path, count: int, summary_window: float, rate_hz: float = 10.0) -> dict:
    """Closest pursuers and phase spacing from the plants' and the target's truth logs (one shared clock).

    min_pursuer_separation: m, the smallest 3-D distance between any two pursuers while at least one of them
    follows (None with one pursuer or no overlap). phase_spacing_error_deg_rms: RMS of
    companion.core.cooperative_guidance.phase_spacing_errors (horizontal phases about the target, deg) over
    the last `summary_window` s of the span where every pursuer follows (None if there is none)."""
    plants = [read_csv(folder / f"pursuer-{k}" / "plant" / "vehicle.csv") for k in range(1, count + 1)]
    target = read_csv(folder / "target" / "target.csv")
    spans = _engaged_spans(folder, count)
    out = {"min_pursuer_separation": None, "phase_spacing_error_deg_rms": None, "all_following_span": None}
    known = [s for s in spans if s is not None]
    if count < 2 or not known:
        return out
    start = max(min(s[0] for s in known), max(float(p["time"][0]) for p in plants))
    end = min(max(s[1] for s in known), min(float(p["time"][-1]) for p in plants))
    if end <= start:
        return out
    grid = np.arange(start, end, 1.0 / rate_hz)
    positions = np.stack([interp(grid, p["time"], np.column_stack([p["x"], p["y"], p["z"]])) for p in plants])
    gaps = np.linalg.norm(positions[:, None, :, :] - positions[None, :, :, :], axis=3)
    pairs = np.triu_indices(count, 1)
    out["min_pursuer_separation"] = float(np.min(gaps[pairs[0], pairs[1], :]))
    if any(s is None for s in spans):
        return out
    all_start, all_end = max(s[0] for s in spans), min(s[1] for s in spans)
    if all_end <= all_start:
        return out
    out["all_following_span"] = [all_start, all_end]
    window = grid[(grid >= max(all_start, all_end - summary_window)) & (grid <= all_end)]
    if window.size == 0:
        return out
    target_position = interp(window, target["stamp"], np.column_stack([target["true_n"], target["true_e"], target["true_d"]]))
    errors = []
    for index, moment in enumerate(window):
        where = np.stack([interp(np.array([moment]), p["time"], np.column_stack([p["x"], p["y"]]))[0] for p in plants])
        relative = where - target_position[index, :2]
        errors.append(phase_spacing_errors(np.arctan2(relative[:, 1], relative[:, 0])))
    out["phase_spacing_error_deg_rms"] = float(np.degrees(rms(np.concatenate(errors))))
    return out


def check_swarm_run(scenario: Scenario, abort_after: float | None) -> None:
    """ConfigError (one line) for what a swarm SITL run does not do."""
    if scenario.swarm is None:
        raise ConfigError(f"scenario {scenario.name!r} has no [swarm]")
    if scenario.swarm.estimator == "fusion":
        raise ConfigError("[swarm] estimator = 'fusion' is not flown yet (as in bof-sim)")
    if abort_after is not None:
        raise ConfigError("--abort-after is for one pursuer; with [swarm] stop the run with Ctrl-C")


def run_swarm(config: Path, scenario: Scenario, vehicle: VehicleConfig, out: Path, speed: float, seed: int, budget: float,
              options: SitlOptions = SitlOptions(), *,
              on_progress: Callable[[SwarmGroundStation], None] | None = None) -> tuple[int, Path, dict]:
    """Fly the [swarm] scenario `config` (already loaded and checked as `scenario`) through 2N + 1 processes;
    returns (exit code, run folder, summary). options: as studies.full_sitl.run's keywords (its on_state and
    abort_after are for one pursuer: not used); vehicle: the airframe every pursuer flies (its max_tilt_deg is
    the summaries' tilt envelope); budget: wall s for the whole flight. on_progress: called about every 50 ms
    of wall time with the ground station."""
    return SwarmRun(config, scenario, vehicle, out, speed, seed, options).fly(budget, on_progress)


class SwarmRun:
    """A swarm's SITL run, step by step: the run folder and its network (made on construction), a plant and a
    companion per pursuer and the one target, the flight watched as the ground station, then one summary entry
    per pursuer and the swarm's figures, read from the run folder (`fly`)."""

    def __init__(self, config: Path, scenario: Scenario, vehicle: VehicleConfig, out: Path, speed: float, seed: int,
                 options: SitlOptions) -> None:
        self.config, self.scenario, self.vehicle = config, scenario, vehicle
        self.speed, self.seed, self.options = speed, seed, options
        self.count = scenario.swarm.count
        self.folder = make_run_folder(out, scenario, seed)
        self.network = ZenohNetwork.create(self.folder, options.secure)
        self.companion_ports = {k: free_port() for k in range(1, self.count + 1)}
        write_json(self.folder / "links.json", {
            "zenoh": self.network.links(),
            "mavlink": {"gcs_port": options.gcs_port, "signing_required": options.secure,
                        "pursuers": {str(k): {"system_id": k, "companion_port": port}
                                     for k, port in self.companion_ports.items()}}}, indent=2)
        self.plants, self.companions, self.target = self._children()
        self.children = {**{f"plant-{k}": c for k, c in self.plants.items()}, "target": self.target,
                         **{f"companion-{k}": c for k, c in self.companions.items()}}
        self.cpu = CpuMeter()
        self.station: SwarmGroundStation | None = None
        self.anchor: float | None = None
        self._next_print = 0.0

    def _children(self) -> tuple[dict[int, ChildProcess], dict[int, ChildProcess], ChildProcess]:
        """Pursuer K's plant and companion (by K), and the target, not started yet."""
        python, config, seed, network = sys.executable, str(self.config), self.seed, self.network
        zenoh_args, gcs_port = list(network.zenoh_args), self.options.gcs_port
        plants, companions = {}, {}
        self.live_ports = {k: self.options.live_port(k) for k in range(1, self.count + 1)}
        for k in range(1, self.count + 1):
            where = self.folder / f"pursuer-{k}"
            zenoh = ["--zenoh-listen", network.endpoint, *zenoh_args] if k == 1 else []
            plants[k] = ChildProcess([python, "-m", "sitl_plant.sitl", "--config", config, "--speed-factor",
                                      str(self.speed), "--pursuer-id", str(k), "--system-id", str(k),
                                      "--companion-port", str(self.companion_ports[k]), "--gcs-port", str(gcs_port),
                                      "--seed", str(plant_seed(seed, k)), "--log-dir", str(where / "plant"), "--quiet",
                                      *zenoh, *network.signing_args],
                                     where / "plant.out", ready="sitl-plant ready")
            companions[k] = ChildProcess([python, "-m", "companion", "--config", config, "--pursuer-id", str(k),
                                          "--mavlink", f"udpin://127.0.0.1:{self.companion_ports[k]}",
                                          "--zenoh-connect", network.endpoint, "--seed", str(seed), "--log-dir",
                                          str(where / "companion"), *zenoh_args, *live_args(self.live_ports[k])],
                                         where / "companion.out", ready="companion ready")
        target = ChildProcess([python, "-m", "sitl_plant.world.target_publisher", "--config", config, "--zenoh-connect",
                               network.endpoint, "--seed", str(seed), "--log-dir", str(self.folder / "target"),
                               "--wait-for-start", *zenoh_args, *self.options.fault_args()],
                              self.folder / "target.out", ready="sitl-target ready")
        return plants, companions, target

    def fly(self, budget: float, on_progress: Callable[[SwarmGroundStation], None] | None) -> tuple[int, Path, dict]:
        """Start the children, watch the flight for at most `budget` wall s, stop them all and write the summary;
        returns (exit code, run folder, summary)."""
        options, network, count = self.options, self.network, self.count
        print(f"bof-sitl: {count} pursuers; ground station: udp 127.0.0.1:{options.gcs_port} (system ids 1..{count})",
              flush=True)
        print(f"bof-sitl: zenoh {network.endpoint}, " + ("mutual TLS and access control (pki in the run folder)"
              if options.secure else f"plain TCP, unauthenticated, namespace {network.namespace}"), flush=True)
        for k, port in self.live_ports.items():
            if port is not None:
                print(f"bof-sitl: pursuer {k} live view ws://127.0.0.1:{port} (Foxglove: Open connection)", flush=True)
        self._on_progress = on_progress
        code = 1
        stopped: Stopped | None = None
        try:
            self._start()
            stopped = watch(lambda: any(c.running for c in self.companions.values()), self._tick, budget, options.stop)
            self.cpu.sample(self.children, force=True)
            codes = [c.process.returncode for c in self.companions.values()]
            code = (0 if all(c == 0 for c in codes) else 1) if stopped is None else 1
        except Interrupted as signal_stop:
            stopped = Stopped.by_signal(signal_stop, options.stop)
            code = 128 + signal_stop.signum
        finally:
            self.cpu.sample(self.children, force=True)
            # Companions first, while the plants still answer (each hands its vehicle to its autopilot).
            companion_codes = stop_all(self.companions.values())
            other_codes = stop_all([self.target, *self.plants.values()])
            if self.station is not None:
                self.station.close()
        stopped_after = None if stopped is None else stopped.stopped_after()
        interrupted = None if stopped is None else stopped.interrupted
        exit_codes = {"target": other_codes[0], **{f"plant-{k}": c for k, c in zip(self.plants, other_codes[1:])},
                      **{f"companion-{k}": c for k, c in zip(self.companions, companion_codes)}}
        entries, series = [], {}
        for k in range(1, count + 1):
            entry, data = self._pursuer_entry(k, interrupted, exit_codes)
            entries.append(entry)
            if data is not None:
                series[k] = data
        top, code = self._swarm_summary(entries, code)
        top.update(speed_factor=self.speed, seed=self.seed, run_folder=str(self.folder), gcs_port=options.gcs_port,
                   interrupted=interrupted, stopped_after_s=stopped_after, exit_codes=exit_codes, cpu=self.cpu.report(),
                   clock_anchor=self.anchor,
                   target_started_at=None if self.station is None else self.station.started_stamp,
                   zenoh=network.summary(self.children))
        if options.plots and interrupted is None and series:
            from studies.plots import plot_swarm_tracks

            plot_swarm_tracks(series, self.folder / "tracks.png",
                              f"{self.scenario.name} (SITL, {count} pursuers, seed {self.seed})")
        write_summary(self.folder / "summary.json", top, sort_keys=True)
        return code, self.folder, top

    def _start(self) -> None:
        """The plants on one clock anchor, then the target and the ground station, then the companions."""
        stop = self.options.stop
        self.anchor = time.monotonic() + ANCHOR_LEAD_PER_PURSUER * self.count
        # Each wave starts together, then waits for every ready line: the pursuers take off and engage within
        # about a second of one another, as the in-process pursuers all start at once.
        for plant in self.plants.values():
            plant.command += ["--clock-anchor", f"{self.anchor:.6f}"]
        start_together(self.plants.values(), stop)
        self.target.start(stop=stop)
        self.station = SwarmGroundStation(self.network.endpoint, self.scenario, self.network.ground_station_tls(),
                                          self.network.namespace)
        start_together(self.companions.values(), stop)

    def _tick(self) -> None:
        """One look as the ground station: sample the children's CPU, start the target once every companion still
        flying follows, report progress; RuntimeError when a plant or the target has exited."""
        station = self.station
        self.cpu.sample(self.children)
        gone = frozenset(station.ids[k - 1] for k, c in self.companions.items() if not c.running)
        if not station.target_started and station.all_following(gone):
            station.start_target()
        if self._on_progress is not None:
            self._on_progress(station)
        if not self.options.quiet and time.monotonic() >= self._next_print:
            self._next_print = time.monotonic() + 2.0
            print(f"bof-sitl: {station.progress()}", flush=True)
        fail_on_early_exit((name, child) for name, child in self.children.items() if not name.startswith("companion"))

    def _pursuer_entry(self, k: int, interrupted: str | None, exit_codes: dict) -> tuple[dict, dict | None]:
        """Pursuer `k`'s summary entry (its figures from the truth logs, or why there are none; its companion's
        summary and its plant's pacing) and its flight series (None without figures)."""
        where = self.folder / f"pursuer-{k}"
        own = pursuer_scenario(self.scenario, pursuer_starts(self.scenario)[k - 1])
        companion_summary = read_json(where / "companion" / "summary.json")
        plant_stats = read_json(where / "plant" / "stats.json") or {}
        termination = run_termination(where, companion_summary, interrupted)
        entry: dict = {"pursuer": k, "termination": termination_name(termination),
                       "termination_reason": termination.value}
        data = None
        try:
            if companion_summary is None:
                raise RuntimeError(f"pursuer {k}'s companion wrote no summary; see pursuer-{k}/companion.out")
            data, engaged_at = flight_series(where, self.folder / "target")
            entry.update(summarize(data, own, termination, self.vehicle))
            entry["engaged_at_sim_time"] = engaged_at
        except (RuntimeError, FileNotFoundError, KeyError, ValueError, IndexError) as error:
            entry["flight_error"] = str(error)
        mcap_error = write_sitl_mcap(where, entry if "flight_error" not in entry else None,
                                     own.guidance.desired_range, self.folder / "target")
        if mcap_error:
            entry["mcap_error"] = mcap_error
        swarm = (companion_summary or {}).get("swarm") or {}
        entry.update(pursuer=k, neighbour_bearings_used=swarm.get("neighbour_bearings_used"),
                     shares_rejected=swarm.get("shares_rejected"), law_changes=swarm.get("law_changes"),
                     deadline_misses=(companion_summary or {}).get("deadline_misses"),
                     setpoints_sent=(companion_summary or {}).get("setpoints_sent"),
                     companion=companion_summary,
                     plant={key: plant_stats.get(key) for key in ("system_id", "speed_factor_achieved", "late_ticks",
                                                                  "ticks", "slips", "catch_ups", "max_lag_sim_s")},
                     companion_exit_code=exit_codes[f"companion-{k}"], plant_exit_code=exit_codes[f"plant-{k}"])
        entry["plant"]["mavlink_rejected"] = plant_stats.get("mavlink", {}).get("rejected")
        return entry, data

    def _swarm_summary(self, entries: list[dict], code: int) -> tuple[dict, int]:
        """The summary's top level: pursuer 1's single-pursuer keys, `pursuers`, the swarm's geometry and share
        link, the first failed pursuer's termination; returns it and the exit code (`code`, 1 when it was 0 and a
        pursuer failed or has no figures)."""
        scenario = self.scenario
        top = {key: value for key, value in entries[0].items() if key not in ("companion", "plant")}
        top["pursuers"] = entries
        try:
            geometry = swarm_geometry(self.folder, self.count, scenario.simulation.summary_window)
        except (FileNotFoundError, KeyError, ValueError, IndexError) as error:
            geometry = {"min_pursuer_separation": None, "phase_spacing_error_deg_rms": None,
                        "geometry_error": str(error)}
        top.update(geometry)
        top["min_separation"] = scenario.swarm.min_separation
        top["share_link"] = share_link_counts(entries)
        failed = next((e for e in entries if e["termination"] != "completed"), None)
        if failed is not None:
            top["termination"] = failed["termination"]
            top["termination_reason"] = f"pursuer {failed['pursuer']}: {failed['termination_reason']}"
            code = code or 1
        if any("flight_error" in e for e in entries):
            code = code or 1
        return top, code


def share_link_counts(entries: list[dict]) -> dict:
    """The [swarm.link] model's counts over every receiver, as bof-sim's share_link: each share a companion
    accepted was offered to the model once (offered, delivered, and the drops by reason)."""
    links = [((e.get("companion") or {}).get("swarm") or {}) for e in entries]
    offered = sum(l.get("shares_accepted", 0) for l in links)
    dropped: dict[str, int] = {}
    for l in links:
        for reason, n in (l.get("shares_dropped_by_link") or {}).items():
            dropped[reason] = dropped.get(reason, 0) + n
    return {"offered": offered, "delivered": offered - sum(dropped.values()), **dropped}


def format_swarm_sitl_summary(summary: dict) -> str:
    """The run's lines: the swarm's figures, one line per pursuer, CPU per process, then each pursuer's closing
    block (truth and monitor, studies.metrics.outcome_lines)."""
    spacing, separation = summary.get("phase_spacing_error_deg_rms"), summary.get("min_pursuer_separation")
    lines = [f"run folder: {summary['run_folder']}",
             f"termination: {summary.get('termination')}, {summary.get('termination_reason')}",
             f"  {len(summary['pursuers'])} pursuers: phase spacing error rms "
             f"{'n/a' if spacing is None else f'{spacing:.2f} deg'}, closest pursuers "
             f"{'n/a' if separation is None else f'{separation:.2f} m'} (limit {summary['min_separation']} m)"]
    for entry in summary["pursuers"]:
        if "flight_error" in entry:
            lines.append(f"    pursuer {entry['pursuer']}: {entry['termination']}: {entry['flight_error']}")
            continue
        lines.append(f"    pursuer {entry['pursuer']}: {entry['termination']}, range-estimation rms "
                     f"{entry['range_estimation_error_rms']:.3f} m, range error rms {entry['range_error_rms']:.3f} m, "
                     f"min range {entry['min_range']:.2f} m, neighbour bearings used {entry['neighbour_bearings_used']}, "
                     f"deadline misses {entry['deadline_misses']}/{entry['setpoints_sent']}, "
                     f"plant x{entry['plant']['speed_factor_achieved']}")
    cpu = summary.get("cpu") or {}
    if cpu:
        lines.append("  CPU (share of one core): " + ", ".join(
            f"{name} {value['cpu_share']:.2f}" for name, value in sorted(cpu.items()) if value.get("cpu_share") is not None))
    for entry in summary["pursuers"]:
        if "truth" in entry:
            lines += outcome_lines(entry, f"pursuer {entry['pursuer']}")
    return "\n".join(lines)


def budget_for(scenario: Scenario, speed: float, timeout: float | None) -> float:
    """Wall s for the whole run: --timeout, else (follow duration + 90 s) / speed + 60 s + 10 s per pursuer."""
    if timeout is not None:
        return timeout
    duration = scenario.companion.follow_duration or scenario.simulation.duration
    return (duration + 90.0) / speed + 60.0 + 10.0 * scenario.swarm.count
