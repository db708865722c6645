"""bof-swarm-study on a small scale: 2 seeds, short flights."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from studies import swarm_study
from studies.swarm import simulate_swarm


def test_the_study_writes_its_tables_and_they_match_the_flights(tmp_path, capsys):
    assert swarm_study.main(["--seeds", "2", "--duration", "10", "--parts", "a", "b", "--executor", "serial",
                             "--quiet", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    (folder,) = tmp_path.iterdir()
    assert {p.name for p in folder.iterdir()} == {"results.csv", "summary.json", "summary.md"}
    with open(folder / "results.csv") as handle:
        rows = list(csv.DictReader(handle))
    per_case = {}
    for row in rows:
        per_case.setdefault(row["case"], []).append(row)
    # one row per pursuer and seed: cv/turn single (1), cv/turn swarm (3), the blackout swarm (3)
    assert {case: len(r) for case, r in per_case.items()} == {
        "cv_single": 2, "cv_swarm": 6, "turn_single": 2, "turn_swarm": 6, "cv_swarm_blackout": 6}
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["seeds"] == 2 and summary["flight_seconds"] == pytest.approx(10.0 * 2 * (1 + 3 + 1 + 3 + 3))

    # a row is what the harness gives for that flight
    case = next(c for c in swarm_study.build_cases(("a",), 10.0) if c.name == "cv_swarm")
    direct = simulate_swarm(case.scenario, case.vehicle, 2)
    row = next(r for r in per_case["cv_swarm"] if r["seed"] == "2" and r["pursuer"] == "3")
    assert float(row["range_estimation_rms"]) == pytest.approx(direct.summary["pursuers"][2]["range_estimation_error_rms"],
                                                               rel=1e-12)
    assert float(row["min_pursuer_separation"]) == pytest.approx(direct.summary["min_pursuer_separation"], rel=1e-12)

    # the tables pool the rows: root mean square over pursuers, then over seeds
    for name, table in summary["tables"].items():
        flights = {}
        for r in per_case[name]:
            flights.setdefault(r["seed"], []).append(float(r["range_estimation_rms"]) ** 2)
        pooled = math.sqrt(np.mean([math.sqrt(np.mean(v)) ** 2 for v in flights.values()]))
        assert table["range_estimation_rms_pooled"] == pytest.approx(pooled, rel=1e-9)
        assert table["seeds"] == 2
        assert table["min_range"] == pytest.approx(min(float(r["min_range"]) for r in per_case[name]))
    silent = [r for r in per_case["cv_swarm_blackout"] if r["silent"] == "True"]
    assert {r["pursuer"] for r in silent} == {str(swarm_study.BLACKOUT_PURSUER)}
    goals = {g["goal"]: g for g in summary["goals"]}
    assert any("blackout" in goal for goal in goals) and any(goal.startswith("turning") for goal in goals)
    report = (folder / "summary.md").read_text()
    assert "| cv_swarm | 3 |" in report and "| goal | measured | met |" in report
    assert report in printed and "per wall second" in printed


def test_part_c_flies_every_estimator_on_the_constant_velocity_swarm():
    cases = {case.name: case for case in swarm_study.build_cases(("c",))}
    assert set(cases) == {"cv_own", "cv_shared_bearings", "cv_triangulation_kf", "cv_fusion_ci", "cv_fusion_seed004"}
    assert {name: (c.scenario.swarm.estimator, c.scenario.swarm.fusion.method) for name, c in cases.items()} == {
        "cv_own": ("own", "covariance_intersection"), "cv_shared_bearings": ("shared_bearings", "covariance_intersection"),
        "cv_triangulation_kf": ("triangulation_kf", "covariance_intersection"),
        "cv_fusion_ci": ("fusion", "covariance_intersection"), "cv_fusion_seed004": ("fusion", "seed004")}
    assert all(c.scenario.swarm.count == 3 for c in cases.values())


def test_worker_processes_give_the_serial_rows():
    cases = [c for c in swarm_study.build_cases(("a",), 4.0) if c.name == "cv_single"]
    serial = swarm_study.run_study(cases, 2, "serial", progress=False)[0]
    local = swarm_study.run_study(cases, 2, "local", workers=1, progress=False)[0]
    assert serial == local


def test_bad_arguments_are_refused(tmp_path):
    assert swarm_study.main(["--seeds", "0", "--out", str(tmp_path)]) == 2
    assert swarm_study.main(["--workers", "0", "--out", str(tmp_path)]) == 2
    assert swarm_study.main(["--seeds", "100000000", "--out", str(tmp_path)]) == 2  # before its tasks are built
    # --duration goes through the schema as the files' own would (it skipped validation: nan, inf, a year)
    for duration in ("nan", "inf", "100000"):
        assert swarm_study.main(["--duration", duration, "--seeds", "1", "--out", str(tmp_path)]) == 2
    assert list(tmp_path.iterdir()) == []


def test_a_case_that_is_another_case_is_flown_once():
    cases = [c for c in swarm_study.build_cases(("a", "c"), 3.0) if c.name in ("cv_swarm", "cv_shared_bearings")]
    rows, flights, _, _ = swarm_study.run_study(cases, 1, "serial", progress=False)
    assert len(flights) == 1
    by_case = {name: [{k: v for k, v in r.items() if k not in ("case", "part")} for r in rows if r["case"] == name]
               for name in ("cv_swarm", "cv_shared_bearings")}
    assert len(by_case["cv_swarm"]) == 3 and by_case["cv_swarm"] == by_case["cv_shared_bearings"]
