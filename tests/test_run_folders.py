"""Run folders: two runs started in the same second never share one."""
from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor

from interfaces.run_folders import new_run_folder

SECOND = time.strptime("2026-12-07 18:50:23", "%Y-%m-%d %H:%M:%S")


def _make(parent: str) -> str:
    return str(new_run_folder(parent, "sitl-stop_and_go-seed1", SECOND))


def test_runs_started_in_the_same_second_get_folders_of_their_own(tmp_path):
    """Sixteen runs named in one second, from four processes at once: sixteen folders, each made, none shared,
    the first with the plain name and the others numbered 2-16 in some order."""
    with ProcessPoolExecutor(4) as pool:
        made = list(pool.map(_make, [str(tmp_path / "runs")] * 16))
    assert len(set(made)) == 16
    base = "sitl-stop_and_go-seed1-20261207-185023"
    assert sorted(made) == sorted(str(tmp_path / "runs" / (base if k == 1 else f"{base}-{k}")) for k in range(1, 17))
    assert all((tmp_path / "runs" / name).is_dir() for name in made)


def test_bof_sim_twice_in_one_second_writes_two_run_folders(tmp_path, scenario_path, monkeypatch):
    """Two short bof-sim flights into one --out, the clock held at one second: both run folders and both
    summaries are kept."""
    import interfaces.run_folders
    from studies.run_scenario import main as bof_sim

    monkeypatch.setattr(interfaces.run_folders.time, "localtime", lambda *_: SECOND)
    source = scenario_path("constant_velocity")
    vehicles = source.parent.parent / "vehicles"
    text = source.read_text().replace('vehicle = "../vehicles/', f'vehicle = "{vehicles}/')
    short = tmp_path / "short.toml"
    short.write_text(text.replace("duration = 60.0", "duration = 2.0").replace("summary_window = 20.0",
                                                                              "summary_window = 2.0"))
    out = tmp_path / "out"
    for _ in range(2):
        bof_sim([str(short), "--out", str(out), "--no-plots"])
    folders = sorted(folder.name for folder in out.iterdir())
    assert folders == ["constant_velocity-seed1-20261207-185023", "constant_velocity-seed1-20261207-185023-2"]
    assert all((out / name / "summary.json").is_file() for name in folders)
