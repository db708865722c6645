"""The seed reproductions (studies.seed_reproductions, `bof-seed-repro`; docs/reproduction.md seeds 002 and 004)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies import seed_reproductions as repro

FIGURES = ("distances.png", "phase_gaps.png", "estimation.png", "tracks.png")


@given(st.lists(st.floats(-10.0, 10.0), min_size=2, max_size=8, unique=True))
@settings(max_examples=200, deadline=None)
def test_gaps_ahead_are_the_sorted_phase_differences(phases):
    """Delta_i is the CCW distance from pursuer i to the next phase up (mod 2 pi): the same multiset as the
    differences of the sorted phases, summing to 2 pi, and pursuer i plus its gap lands on another pursuer."""
    wrapped = np.mod(np.array(phases), 2.0 * math.pi)
    if len(np.unique(np.round(wrapped, 9))) < len(wrapped):
        return  # two phases equal mod 2 pi: the gap of one of them is a convention
    gaps = repro.gaps_ahead(np.array([phases]))[0]
    ordered = np.sort(wrapped)
    reference = np.diff(np.append(ordered, ordered[0] + 2.0 * math.pi))
    assert np.allclose(np.sort(gaps), np.sort(reference), atol=1e-9)
    assert math.isclose(gaps.sum(), 2.0 * math.pi, abs_tol=1e-9)
    for own, gap in zip(wrapped, gaps):
        landing = np.mod(own + gap, 2.0 * math.pi)
        assert np.min(np.abs(np.angle(np.exp(1j * (wrapped - landing))))) < 1e-9


def test_orbit_phases_of_pursuers_equally_spaced_around_a_moving_target():
    """Five pursuers 72 deg apart on a 5 m circle about a target anywhere: every gap is 2 pi / 5."""
    count, steps = 5, 4
    target = np.array([[3.0 * k, -2.0 * k, -10.0] for k in range(steps)])
    series = {}
    for i in range(count):
        angle = 0.3 + i * 2.0 * math.pi / count + 0.1 * np.arange(steps)  # all turn together
        offset = np.stack([5.0 * np.sin(angle), 5.0 * np.cos(angle), np.zeros(steps)], axis=1)  # north, east
        series[i + 1] = {"pursuer_position": target + offset, "target_position": target}
    gaps = repro.gaps_ahead(repro.orbit_phases(series))
    assert np.allclose(gaps, 2.0 * math.pi / count)


def test_settle_time():
    time = np.arange(10.0)
    assert repro.settle_time(time, np.array([5, 5, 0.5, 3, 0.2, 0.1, 0.1, 0.0, 0.1, 0.1]), 1.0) == 4.0
    assert repro.settle_time(time, np.full(10, 0.5), 1.0) == 0.0
    assert repro.settle_time(time, np.append(np.zeros(9), 2.0), 1.0) is None


def test_every_variant_loads():
    """Every variant's scenario file with its overrides is a valid scenario (the flown estimator is the one
    the variant names)."""
    for paper, variants in repro.REPRODUCTIONS.items():
        for variant in variants:
            scenario, _ = repro.load_variant(variant)
            assert scenario.swarm is not None and scenario.swarm.count == (5 if paper == "002" else 3)
            for key, value in variant.overrides.items():
                section, name = key.split(".")
                assert getattr(getattr(scenario, section), name) == (tuple(value) if isinstance(value, list) else value)


def test_scaled_seed002_differs_from_the_seed_file_only_in_g2():
    seed, _ = load_scenario(SCENARIOS_DIR / "seed002_circumnavigation.toml")
    scaled, _ = load_scenario(SCENARIOS_DIR / "seed002_circumnavigation_scaled.toml")
    a, b = seed.model_dump(), scaled.model_dump()
    assert (a["swarm"]["circumnavigation"]["g2"], b["swarm"]["circumnavigation"]["g2"]) == (1.0, 0.5)
    for document in (a, b):
        document["swarm"]["circumnavigation"].pop("g2")
        document.pop("name")
        document.pop("description")
    assert a == b


@pytest.mark.parametrize("paper, variant", [("002", "scaled_uplkf"), ("004", "imm")])
def test_short_reproduction_writes_its_folder_and_the_pursuers_close_in(tmp_path, paper, variant, capsys):
    """bof-seed-repro for 4 s: the run folder has the metrics, the summary and the four figures, and every
    pursuer got its setpoints (it moves; in seed 002 its horizontal distance to the target, 40-60 m at the
    start, shrinks). Four seconds, not minutes."""
    assert repro.main([paper, "--seeds", "0", "--variants", variant, "--duration", "4", "--out", str(tmp_path)]) == 0
    folder = next(tmp_path.iterdir())
    flight = folder / variant / "seed0"
    for name in FIGURES:
        assert (flight / name).stat().st_size > 1000
    metrics = json.loads((flight / "metrics.json").read_text())
    summary = json.loads((folder / "summary.json").read_text())
    assert metrics["termination"] == "completed" and summary["aggregates"][variant]["flights"] == 1
    assert "| " + variant + " |" in (folder / "summary.md").read_text()
    assert "run folder" in capsys.readouterr().out
    result = repro.fly(next(v for v in repro.REPRODUCTIONS[paper] if v.key == variant), 0, duration=4.0)
    for data in result.series.values():
        offset = data["target_position"] - data["pursuer_position"]
        distance = np.hypot(offset[:, 0], offset[:, 1])
        speed = np.linalg.norm(data["pursuer_velocity"], axis=1)
        assert speed[-1] > 1.0  # m/s: a pursuer whose setpoints never reach its plant stays at 0
        if paper == "002":  # seed 004's target drives away at 10 m/s, faster than a pursuer starting at rest
            assert distance[-1] < distance[0] - 1.0


def test_cli_refuses_an_unknown_variant(tmp_path, capsys):
    assert repro.main(["002", "--variants", "nope", "--out", str(tmp_path)]) == 2
    assert "no variant" in capsys.readouterr().err


@pytest.mark.parametrize("arguments, message", [
    (["--seeds", "1", "1"], "--seeds: 1 given twice"),  # wrote one run folder twice: FileExistsError after a flight
    (["--duration", "inf"], "--duration must be > 0"),
    (["--duration", "nan"], "--duration must be > 0"),
    (["--duration", "1e9"], "--duration must be > 0"),
])
def test_cli_refuses_what_it_cannot_fly_before_it_flies(tmp_path, capsys, arguments, message):
    with pytest.raises(SystemExit) as exit_:
        repro.main(["004", *arguments, "--variants", "uplkf", "--out", str(tmp_path)])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
