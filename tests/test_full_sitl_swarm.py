"""End to end with three pursuers: swarm_circumnavigation flown through 3 plants, 3 companions and 1 target,
real MAVLink (one system id per plant) and one Zenoh network with mutual TLS and access control (--secure).

bof-sitl's `run` starts 7 children on free loopback ports and stops them all whatever happens. The checks
use the processes' own truth logs (the plants' vehicle.csv, the target's target.csv) and what each
companion logged receiving (swarm_rx.jsonl), not the harness's figures alone.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from studies import full_sitl, sitl_runs
from studies.processes import free_port
from tests.swarm_config import COUNT, SCENARIO, scenario_copy

#: Simulated s per wall s. Seven processes at 2x take most of two cores and at 1x about half; the module has the
#: machine to itself (tests/conftest.py EXCLUSIVE_FILES), and at 1.5x the plants keep the shared clock even with
#: a CPU burner beside them. The module's 80 s flight then takes about 2.5 min of wall time.
SPEED = 1.5


#: [swarm.link] blackout of pursuer 2 in the module's flight, s into the following (each companion counts from its
#: own start of following). The blackout falls while the formation is still spacing out, and in six SITL flights
#: the phase spacing error came under 10 deg between 50 and 60 s of following (up to 100 deg at 20-35 s); with a 65 s
#: flight the summary window (the last 20 s of following) took in the end of that and three of the six were over
#: 10 deg RMS (13-15 deg). The module's flight is longer than the shipped scenario (DURATION) so that the window
#: starts after the re-spacing.
BLACKOUT = (16.0, 24.0)
DURATION = 80.0


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """One flight for the module: --secure (mutual TLS, access control, MAVLink signing) with a share-link
    blackout of pursuer 2, so the checks of a whole flight and of the blackout's survival share one flight."""
    out = tmp_path_factory.mktemp("swarm-sitl")
    path = scenario_copy(out / "swarm_blackout.toml", DURATION,
                         f"blackouts = [{{pursuer = 2, start = {BLACKOUT[0]}, end = {BLACKOUT[1]}}}]\n")
    code, folder, summary = full_sitl.run(path, out / "runs", SPEED, seed=1, timeout=300.0, plots=True, quiet=True,
                                          gcs_port=free_port(), secure=True)
    return code, folder, summary


def _csv(path: Path) -> dict[str, np.ndarray]:
    return sitl_runs.read_csv(path)


def _track(folder: Path, ident: int) -> tuple[np.ndarray, np.ndarray]:
    plant = _csv(folder / f"pursuer-{ident}" / "plant" / "vehicle.csv")
    return plant["time"], np.column_stack([plant["x"], plant["y"], plant["z"]])


def test_every_child_ends_cleanly_and_every_pursuer_completes(flown):
    code, folder, summary = flown
    assert code == 0, [(folder / f"pursuer-{k}" / "companion.out").read_text()[-2000:] for k in range(1, COUNT + 1)]
    assert summary["interrupted"] is None
    assert set(summary["exit_codes"]) == {"target", *(f"plant-{k}" for k in range(1, COUNT + 1)),
                                          *(f"companion-{k}" for k in range(1, COUNT + 1))}
    assert all(code == 0 for code in summary["exit_codes"].values()), summary["exit_codes"]
    assert [entry["pursuer"] for entry in summary["pursuers"]] == list(range(1, COUNT + 1))
    for k in range(1, COUNT + 1):
        events = [json.loads(line) for line in (folder / f"pursuer-{k}" / "companion" / "events.jsonl").read_text().splitlines()]
        phases = [e["phase"] for e in events if e["kind"] == "phase"]
        assert phases[-3:] == ["following", "landing", "done"], (k, phases)
        plant = _csv(folder / f"pursuer-{k}" / "plant" / "vehicle.csv")
        assert plant["armed"][-1] == 0 and abs(plant["z"][-1]) < 0.05  # landed and disarmed
        stats = json.loads((folder / f"pursuer-{k}" / "plant" / "stats.json").read_text())
        assert stats["mavlink"]["rejected"] == {}
    assert summary["termination"] == "completed", summary["termination_reason"]


def test_each_plant_has_its_own_system_id_and_starts_at_its_pursuers_start(flown):
    _, folder, summary = flown
    links = json.loads((folder / "links.json").read_text())
    ports = {links["mavlink"]["pursuers"][str(k)]["companion_port"] for k in range(1, COUNT + 1)}
    assert len(ports) == COUNT
    starts = [SCENARIO.pursuer.initial_position] + [p.initial_position for p in SCENARIO.swarm.pursuers[1:]]
    for k in range(1, COUNT + 1):
        text = (folder / f"pursuer-{k}" / "companion.out").read_text()
        assert f"New system on: 127.0.0.1:" in text and f"(system ID: {k})" in text  # MAVSDK's own words
        assert summary["pursuers"][k - 1]["plant"]["system_id"] == k  # as the plant itself reports it
        _, track = _track(folder, k)
        assert np.linalg.norm(track[0, :2] - np.array(starts[k - 1][:2])) < 0.5


def test_every_pursuer_uses_its_neighbours_bearings(flown):
    _, folder, summary = flown
    for entry in summary["pursuers"]:
        k = entry["pursuer"]
        assert entry["neighbour_bearings_used"] > 100, entry
        assert any(law == "cooperative" for _, law in entry["law_changes"])
        records = [json.loads(line) for line in (folder / f"pursuer-{k}" / "companion" / "swarm_rx.jsonl").read_text().splitlines()]
        heard = {r["sender"] for r in records if r.get("verdict") == "accepted"}
        assert heard == set(range(1, COUNT + 1)) - {k}
        # Each plant keeps its own simulated clock against one shared wall-clock anchor; on a loaded machine a
        # plant falls behind it and a neighbour's share then reads as stamped ahead of the receiver's clock:
        # refused and counted, as a forged stamp would be. So more than a few such refusals (2 % of the shares
        # heard: odometry reaches a busy companion late too) must come with a plant that lagged by a quarter of
        # the allowed skew at least (the receiver's and the sender's lags add). No other reason may appear
        # (no_clock: shares heard before the first odometry).
        rejected = entry["shares_rejected"] or {}
        assert set(rejected) <= {"no_clock", "future_stamp"}, rejected
        if rejected.get("future_stamp", 0) > 0.02 * entry["companion"]["swarm"]["shares_received"]:
            lag = max(other["plant"]["max_lag_sim_s"] for other in summary["pursuers"])
            assert lag >= SCENARIO.link.max_future_skew_s / 4, (rejected, [other["plant"] for other in summary["pursuers"]])


def test_pursuers_keep_their_separation_and_their_distance_to_the_target(flown):
    """From the truth logs: any two pursuers, over the whole flight, never closer than [swarm] min_separation;
    each pursuer, while it follows, never closer than r_d / 2 to the target."""
    _, folder, summary = flown
    tracks = [_track(folder, k) for k in range(1, COUNT + 1)]
    start = max(t[0] for t, _ in tracks)
    end = min(t[-1] for t, _ in tracks)
    grid = np.arange(start, end, 0.02)
    at = [np.column_stack([np.interp(grid, t, p[:, i]) for i in range(3)]) for t, p in tracks]
    closest = min(float(np.min(np.linalg.norm(at[i] - at[j], axis=1))) for i in range(COUNT) for j in range(i + 1, COUNT))
    assert closest > SCENARIO.swarm.min_separation
    assert summary["min_pursuer_separation"] >= closest - 0.05
    target = _csv(folder / "target" / "target.csv")
    for k, (t, p) in enumerate(tracks, start=1):
        series = _csv(folder / f"pursuer-{k}" / "companion" / "series.csv")
        following = series["time"][series["phase"] == "following"]
        moments = t[(t >= following[0]) & (t <= following[-1])]
        truth = np.column_stack([np.interp(moments, target["stamp"], target[key]) for key in ("true_n", "true_e", "true_d")])
        own = np.column_stack([np.interp(moments, t, p[:, i]) for i in range(3)])
        assert float(np.min(np.linalg.norm(truth - own, axis=1))) > SCENARIO.guidance.desired_range / 2, k


def test_summary_has_the_in_process_layout_and_cpu_per_process(flown):
    _, folder, summary = flown
    written = json.loads((folder / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"{c} in summary"))
    for key in ("pursuers", "phase_spacing_error_deg_rms", "min_pursuer_separation", "range_estimation_error_rms",
                "range_error_rms", "min_range", "termination", "cpu", "share_link"):
        assert key in written, key
    assert written["range_error_rms"] == written["pursuers"][0]["range_error_rms"]
    assert written["phase_spacing_error_deg_rms"] is not None and written["phase_spacing_error_deg_rms"] < 10.0
    for entry in written["pursuers"]:
        assert entry["range_estimation_error_rms"] < 0.5, entry
        assert entry["deadline_misses"] is not None
    assert set(written["cpu"]) == set(written["exit_codes"])
    for name, usage in written["cpu"].items():
        assert 0.0 < usage["cpu_s"] and 0.0 < usage["cpu_share"] < 2.0, (name, usage)
    assert (folder / "tracks.png").stat().st_size > 0
    assert written["zenoh"]["secure"] and all(count == 0 for count in written["zenoh"]["tls_refused"].values())
    assert math.isfinite(written["pursuers"][1]["range_error_rms"])
    from studies.swarm_sitl import format_swarm_sitl_summary

    print(format_swarm_sitl_summary(written))  # the measured figures, with pytest -s


def test_a_share_link_blackout_of_one_pursuer_is_survived_and_recovered(flown):
    """The link model drops every share to and from pursuer 2 inside the blackout (5 Hz x 10 s x 2 neighbours),
    pursuer 2 flies its lone layer (the law on an orbit of its own) and returns to the cooperative law, and every
    pursuer completes with its estimate converged. The pursuers keep their separation throughout: the silent
    one's layer keeps it off the others' circle (flying HNG on the common circle instead, they came 1.29 m
    apart in SITL, 0.5-1.6 m in process)."""
    code, folder, summary = flown
    start, end = BLACKOUT
    assert code == 0 and summary["termination"] == "completed", summary.get("termination_reason")
    rate = SCENARIO.sensor.rate_hz
    dropped = {entry["pursuer"]: entry["companion"]["swarm"]["shares_dropped_by_link"] for entry in summary["pursuers"]}
    assert summary["share_link"]["blackout"] == sum(d["blackout"] for d in dropped.values())
    assert set(dropped[2]) == {"blackout"} and abs(dropped[2]["blackout"] - 2 * rate * (end - start)) <= 4, dropped
    for k in (1, 3):
        assert set(dropped[k]) == {"blackout"} and abs(dropped[k]["blackout"] - rate * (end - start)) <= 2, dropped
    # The windows count from each companion's start of following (its pipeline's first bearing, `following_since`:
    # before the first setpoint the summary's engaged_at records, by more on a busy machine); simulated time.
    engaged = [entry["companion"]["engaged_at"] for entry in summary["pursuers"]]
    since = [entry["companion"]["swarm"]["following_since"] for entry in summary["pursuers"]]
    assert all(s <= e for s, e in zip(since, engaged)), (since, engaged)
    laws = summary["pursuers"][1]["law_changes"]
    rounding = 1e-3  # s: the law changes are logged to the millisecond
    fallback = [t for t, law in laws if law == "lone" and since[1] + start - rounding < t < since[1] + end]
    back = [t for t, law in laws if law == "cooperative" and t >= since[1] + end - rounding]
    assert fallback and back, (laws, since)
    tracks = [_track(folder, k) for k in range(1, COUNT + 1)]
    grid = np.arange(max(t[0] for t, _ in tracks), min(t[-1] for t, _ in tracks), 0.02)
    at = [np.column_stack([np.interp(grid, t, p[:, i]) for i in range(3)]) for t, p in tracks]
    closest = np.min([np.linalg.norm(at[i] - at[j], axis=1) for i in range(COUNT) for j in range(i + 1, COUNT)], axis=0)
    outside = (grid < min(since) + start) | (grid > max(since) + end + SCENARIO.swarm.neighbour_timeout_s)
    assert float(np.min(closest[outside])) > SCENARIO.swarm.min_separation
    assert float(np.min(closest)) > SCENARIO.swarm.min_separation
    print(f"closest pursuers during the blackout: {float(np.min(closest[~outside])):.2f} m, outside it: "
          f"{float(np.min(closest[outside])):.2f} m")
