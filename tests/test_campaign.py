"""The dropout campaign: per-flight figures and the campaign command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from interfaces.scenario import load_scenario
from studies import campaign
from studies.closed_loop import Termination


def _series(error: np.ndarray, distance: np.ndarray) -> dict:
    n = error.size
    t = np.arange(n) * 0.1
    estimate = np.zeros((n, 3))
    return {"time": t, "estimate_position": estimate, "range_estimate": distance + error, "range": distance}


def test_flight_metrics_reconverge_worst_error_and_kept(scenario_path):
    scenario, _ = load_scenario(scenario_path("constant_velocity"))
    t = np.arange(600) * 0.1
    error = np.where((t >= 30.0) & (t < 38.0), 3.0, 0.2)  # bad from 30 s until 38 s
    metrics = campaign.flight_metrics(_series(error, np.full(600, 8.0)), scenario, Termination.COMPLETED,
                                      [(30.0, 35.0)], continuous=False)
    assert metrics["kept"] and metrics["worst_error"] == pytest.approx(3.0)
    assert metrics["reconverge"] == pytest.approx(3.0, abs=0.11)  # link back at 35 s, under 1 m from 38 s
    lost = campaign.flight_metrics(_series(np.where(t >= 30.0, 3.0, 0.2), np.full(600, 8.0)), scenario,
                                   Termination.COMPLETED, [(30.0, 35.0)], continuous=False)
    assert not lost["kept"] and math.isinf(lost["reconverge"])
    too_far = campaign.flight_metrics(_series(np.full(600, 0.2), np.full(600, 20.0)), scenario, Termination.COMPLETED,
                                      [], continuous=True)
    assert not too_far["kept"] and math.isnan(too_far["reconverge"])


def test_the_campaign_command_writes_its_tables(tmp_path, scenario_path):
    code = campaign.main([str(scenario_path("constant_velocity")), "--seeds", "2", "--patterns", "blackout_5s", "corrupt",
                          "--workers", "2", "--out", str(tmp_path)])
    folder = next(tmp_path.glob("campaign-*"))
    rows = (folder / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 4
    summary = json.loads((folder / "summary.json").read_text())
    patterns = {entry["pattern"]: entry for entry in summary["patterns"]}
    assert patterns["blackout_5s"]["kept_share"] == 1.0 and patterns["blackout_5s"]["meets_targets"] is True
    assert "meets_targets" not in patterns["corrupt"]
    assert code == 0
    corrupt = [row for row in rows[1:] if row.startswith("corrupt")]
    assert all("not_" in row or "missing_field" in row or "out_of_range" in row for row in corrupt)
    assert "| blackout_5s" in (folder / "summary.md").read_text()
    # Throughput: 4 flights of constant_velocity's 60 s, over the wall time of the in-process part.
    assert summary["throughput"]["flights"] == 4 and summary["throughput"]["simulated_s"] == pytest.approx(240.0, abs=0.1)
    assert "240 simulated flight-s" in (folder / "summary.md").read_text()


@pytest.mark.parametrize("name", campaign.ATTACK_PATTERNS)
def test_every_attack_leaves_the_flight_kept_and_the_intruder_refused_and_counted(name, scenario_path):
    """The attack targets, per attack, in the in-process loop (same fault model and validator as SITL):
    the target kept, never closer than r_d / 2, the genuine fixes accepted again within 1 s, and every
    message the attacker sent (the fault model's own count) refused and in the reject counters."""
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    row = campaign._fly((name, 1, campaign.with_faults(scenario, campaign.PATTERNS[name][0]), vehicle))
    assert row["kept"] and row["termination"] == "COMPLETED"
    assert row["min_range"] >= 0.5 * scenario.guidance.desired_range
    assert row["lockout"] <= campaign.LOCKOUT_LIMIT
    if name != "target_restart":
        assert row["attack_messages"] > 0
    # A liar in the overheard epoch, plausible and first, gets exactly one fix in before the conflict shows
    # (docs/guide/faults.md, "Link validation": what it cannot defend); every other attack message is refused.
    slipped = 1 if name == "spoof_close_sniffed" else 0
    assert row["attack_refused"] == row["attack_messages"] - slipped and row["attack_accepted_far"] == slipped
    assert row["fixes_rejected"] >= row["attack_messages"] - slipped
    assert row["reanchors"] == slipped  # the conflict rule, once


@pytest.mark.parametrize("name", campaign.LIAR_PATTERNS)
def test_a_patient_liar_holds_the_track_and_the_flight_is_not_called_clean(name, scenario_path):
    """The patient liar (republishing each genuine fix first, seq 1 ahead, drifting 0.5 m/s, for 15 s): flagged
    (the track held) within 2 s of its first lie, never closer than r_d / 2, no lie accepted far off, the pursuer
    standing off (degraded) meanwhile, the flight's verdict not clean, and the genuine fixes accepted again once
    it falls silent."""
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    overrides = campaign.PATTERNS[name][0]
    row = campaign._fly((name, 2, campaign.with_faults(scenario, overrides), vehicle))
    assert row["flagged_after"] <= campaign.FLAG_LIMIT
    assert row["min_range"] >= 0.5 * scenario.guidance.desired_range
    assert row["attack_accepted_far"] == 0 and row["verdict"] != "clean"
    assert row["degraded_entries"] >= 1
    # held from the first proof to 2 s after the liar's last fix (contest_clear), then the genuine target again
    assert row["lockout"] <= overrides["spoof_duration"] + 2.0 + 0.5
    assert row["kept"]
    assert json.loads(row["rejected_by_reason"]).get("contested", 0) >= 5 * overrides["spoof_duration"]


@pytest.mark.parametrize("speed", ["0", "nan", "100"])
def test_a_sitl_speed_bof_sitl_would_refuse_is_refused_before_any_flight(tmp_path, capsys, speed):
    # --sitl-speed 0 used to fly every in-process flight, then die dividing by zero in the SITL case and lose the report
    with pytest.raises(SystemExit) as exit_:
        campaign.main(["--seeds", "1", "--patterns", "none", "--sitl", "none", "--sitl-speed", speed,
                       "--out", str(tmp_path)])
    assert exit_.value.code == 2
    assert f"argument --sitl-speed: {speed} is outside [0.5, 20]" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_huge_seed_count_is_refused_before_its_tasks_are_built(tmp_path, capsys):
    assert campaign.main(["--seeds", "100000000", "--patterns", "none", "--out", str(tmp_path)]) == 2
    assert "make 100,000,000 flights; at most 100,000 in one run" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
