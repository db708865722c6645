"""bof-montecarlo: grid building, divergence accounting, executors that agree, outputs on disk."""

from __future__ import annotations

import csv
import json
import math
import multiprocessing
import os

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.assembly import build_estimator, build_lateral_guidance
from interfaces.scenario import ConfigError, load_scenario
from studies import montecarlo
from studies.closed_loop import simulate
from studies.executors import WORKERS_PER_CORE, local_workers, make_executor

SCENARIO = montecarlo.DEFAULT_SCENARIO


@pytest.fixture(scope="module")
def loaded():
    return load_scenario(SCENARIO)


def test_overrides_are_validated(loaded):
    scenario, _ = loaded
    changed = montecarlo.with_overrides(scenario, {"guidance.c_y": 0.0, "sensor.rate_hz": 50.0})
    assert changed.guidance.c_y == 0.0 and changed.sensor.rate_hz == 50.0
    assert scenario.guidance.c_y == 3.5  # the original is untouched
    with pytest.raises(ConfigError, match="unknown key"):
        montecarlo.with_overrides(scenario, {"guidance.c_q": 1.0})
    with pytest.raises(ConfigError, match="range_noise_std"):
        montecarlo.with_overrides(scenario, {"estimator.kind": "ekf_rae"})
    with pytest.raises(ConfigError):
        montecarlo.with_overrides(scenario, {"guidance.law": "magic"})


def test_case_parsing():
    name, overrides = montecarlo.parse_case("planar:guidance.c_y=0,guidance.law='hng',sensor.rate_hz=50")
    assert name == "planar"
    assert overrides == {"guidance.c_y": 0, "guidance.law": "hng", "sensor.rate_hz": 50}
    for bad in ("planar", "planar:", "x:guidance.c_y", "x:guidance.law=hng"):
        with pytest.raises(ValueError):
            montecarlo.parse_case(bad)
    # keys the runner sets itself were silently ignored
    with pytest.raises(ValueError, match="--runs sets the seeds"):
        montecarlo.parse_case("x:simulation.seed=7")
    with pytest.raises(ValueError, match="cannot change the vehicle file"):
        montecarlo.parse_case("x:vehicle='other.toml'")


def _literal(value) -> str:
    """A TOML literal of an int, a list of ints or a string without quotes."""
    if isinstance(value, list):
        return "[" + ",".join(map(str, value)) + "]"
    return f"'{value}'" if isinstance(value, str) else str(value)


@given(st.dictionaries(st.from_regex(r"[a-z]{1,6}\.[a-z_]{1,8}", fullmatch=True).filter(lambda key: key != "simulation.seed"),
                       st.one_of(st.integers(-1000, 1000), st.lists(st.integers(-99, 99), max_size=4),
                                 st.text(alphabet="ab,[] =", max_size=6)),
                       min_size=1, max_size=4))
def test_a_case_reads_back_every_assignment_arrays_and_commas_in_strings_included(assignments):
    # It split on every comma, so an array value ("[1,2,3]") could not be given at all.
    body = ",".join(f"{key}={_literal(value)}" for key, value in assignments.items())
    assert montecarlo.parse_case(f"c:{body}") == ("c", assignments)


def test_every_preset_study_resolves_to_valid_flights():
    for study in montecarlo.STUDIES.values():
        scenarios = [load_scenario(montecarlo.SCENARIOS / f"{name}.toml") for name in study.scenarios]
        tasks = montecarlo.build_tasks(scenarios, list(study.estimators), list(study.guidance), list(study.cases), 2,
                                       study.initial_box, 2.0)
        assert len(tasks) == 2 * len(scenarios) * len(study.estimators) * len(study.guidance) * len(study.cases)
        for task in tasks:  # each one builds its estimator and law
            build_estimator(task.scenario)
            build_lateral_guidance(task.scenario)


def test_estimator_study_draws_one_start_per_seed_inside_the_box():
    study = montecarlo.STUDIES["estimators"]
    scenarios = [load_scenario(SCENARIO)]
    tasks = montecarlo.build_tasks(scenarios, ["uplkf", "ekf"], ["hng"], [("5Hz", {})], 3, study.initial_box, 2.0)
    starts = {}
    for task in tasks:
        assert task.scenario.estimator.initialize == "position"
        start = task.scenario.estimator.initial_position
        assert 20 <= start[0] <= 120 and -50 <= start[1] <= 50 and -50 <= start[2] <= 50
        starts.setdefault(task.seed, set()).add(start)
    assert all(len(points) == 1 for points in starts.values())  # same start for every estimator of a seed
    assert len({next(iter(points)) for points in starts.values()}) == 3  # different across seeds


def test_explicit_initial_estimate_is_where_the_filter_starts(loaded):
    scenario, vehicle = loaded
    start = montecarlo.drawn_initial_position(4, montecarlo.PAPER_INITIAL_BOX)
    flown = montecarlo.with_overrides(scenario, {"estimator.initialize": "position", "estimator.initial_position": start,
                                                 "simulation.duration": 1.0, "simulation.summary_window": 1.0})
    series = simulate(flown, vehicle, 1).series
    first = np.nonzero(np.isfinite(series["estimate_position"][:, 0]))[0][0]
    np.testing.assert_allclose(series["estimate_position"][first], start, atol=1e-12)


def test_image_plane_projection():
    forward = np.tile([1.0, 0.0, 0.0], (4, 1))
    relative = np.array([[10.0, 0.0, 0.0], [10.0, 5.0, 0.0], [10.0, 0.0, 2.0], [-10.0, 0.0, 0.0]])
    points = montecarlo.image_plane(relative, forward)
    np.testing.assert_allclose(points[:3], [[0.0, 0.0], [0.5, 0.0], [0.0, 0.2]])
    assert np.all(np.isnan(points[3]))  # behind the camera
    # yaw 90 deg (facing east): a target to the east is straight ahead, one to the south is on the right
    east = np.tile([0.0, 1.0, 0.0], (2, 1))
    np.testing.assert_allclose(montecarlo.image_plane(np.array([[0.0, 8.0, 0.0], [-4.0, 8.0, 0.0]]), east),
                               [[0.0, 0.0], [0.5, 0.0]], atol=1e-12)


def test_divergence_is_counted_not_averaged(loaded):
    scenario, vehicle = loaded
    base = montecarlo.with_overrides(scenario, {"simulation.duration": 8.0, "simulation.summary_window": 8.0})
    labels = {"scenario": "s", "estimator": "uplkf", "guidance": "hng", "case": "c"}
    strict = montecarlo.fly(montecarlo.FlightTask(labels, base, vehicle, 1, 1e-6))
    lenient = montecarlo.fly(montecarlo.FlightTask(labels, base, vehicle, 1, 1e6))
    assert strict["row"]["final_error"] == lenient["row"]["final_error"] > 1e-6
    assert strict["row"]["diverged"] and not lenient["row"]["diverged"]
    rows = [dict(strict["row"], seed=1), dict(lenient["row"], seed=2), dict(lenient["row"], seed=3, final_error=math.inf,
                                                                              diverged=True)]
    (entry,) = montecarlo.group_table(rows)
    assert entry["runs"] == 3 and entry["diverged"] == 2
    assert math.isfinite(entry["final_error_median"])  # the infinite run is counted, not averaged in


def _same_row(a: dict, b: dict) -> bool:
    """Equal, bit for bit, with NaN equal to NaN."""
    def same(x, y):
        return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
    return a.keys() == b.keys() and all(same(a[key], b[key]) for key in a)


def _grid_tasks(loaded):
    scenario, vehicle = loaded
    return montecarlo.build_tasks([(scenario, vehicle)], ["uplkf", "ekf"], ["hng", "pd"], [("short", {})], 2, None,
                                  2.0, duration=6.0)


def _run(executor_spec, tasks):
    executor = make_executor(executor_spec, 2)
    try:
        results = sorted(executor.map(montecarlo.fly, tasks), key=lambda item: item[0])
    finally:
        executor.close()
    return [index for index, _ in results], [result for _, result in results]


def test_local_processes_and_dask_give_the_serial_results(loaded):
    tasks = _grid_tasks(loaded)
    indices, serial = _run("serial", tasks)
    assert indices == list(range(len(tasks)))
    for spec in ("local", "dask-local"):
        other_indices, other = _run(spec, tasks)
        assert other_indices == indices
        for mine, theirs in zip(serial, other):
            assert _same_row(mine["row"], theirs["row"]), spec
            for key in mine["series"]:
                np.testing.assert_array_equal(mine["series"][key], theirs["series"][key])


def test_unknown_executor_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown executor"):
        make_executor("threads")


def test_local_workers_are_bounded_by_the_machine(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    assert local_workers(None) == 2
    assert [local_workers(count) for count in (1, 2, 8)] == [1, 2, 8]
    for count in (0, -1, 9, 100_000):
        with pytest.raises(ValueError, match="use 1 to 8 on this machine"):
            local_workers(count)
        with pytest.raises(ValueError, match="use 1 to 8 on this machine"):
            make_executor("dask-local", count)  # refused before any cluster starts


def _process_id(task: int) -> int:
    return os.getpid()


def test_a_local_pool_starts_no_more_processes_than_tasks():
    before = set(multiprocessing.active_children())
    executor = make_executor("local", WORKERS_PER_CORE * (os.cpu_count() or 1))
    try:
        pids = {pid for _, pid in executor.map(_process_id, [1, 2])}
        started = set(multiprocessing.active_children()) - before  # the pool's processes, still alive until close
        assert pids <= {process.pid for process in started}
        assert 1 <= len(started) <= 2
        assert executor.name == f"local processes ({len(started)})"
    finally:
        executor.close()
    assert not set(multiprocessing.active_children()) - before


def test_too_many_workers_are_refused_before_a_run_folder(tmp_path, capsys):
    assert montecarlo.main(["--workers", "100000", "--runs", "1", "--out", str(tmp_path)]) == 2
    assert "local workers: use 1 to" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_command_writes_table_csv_series_and_figures(tmp_path):
    code = montecarlo.main([str(SCENARIO), "--runs", "2", "--duration", "6", "--estimators", "uplkf", "msc_ekf",
                            "--case", "planar:guidance.c_y=0", "--case", "helical:guidance.c_y=3.5",
                            "--executor", "serial", "--out", str(tmp_path)])
    assert code == 0
    (folder,) = tmp_path.iterdir()
    with (folder / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 * 2 * 2
    assert [int(row["seed"]) for row in rows] == [1, 2] * 4  # task order, whatever the completion order
    assert {row["case"] for row in rows} == {"planar", "helical"}
    assert not (folder / "results.partial.csv").exists()
    summary = (folder / "summary.md").read_text()
    assert sum(line.startswith("| constant_velocity ") for line in summary.splitlines()) == 4
    with np.load(folder / "series.npz") as series:
        assert series["range_estimation_error"].shape == (8, 31)
        assert series["image_plane"].shape == (8, 31, 2)
    for name in ("errors_over_time.png", "trajectories.png", "image_plane.png"):
        assert (folder / name).stat().st_size > 10_000
    # Throughput: 8 flights of the --duration (6 s) each, 48 simulated flight-s, over the wall time of the run.
    throughput = json.loads((folder / "summary.json").read_text())["throughput"]
    assert throughput["flights"] == 8 and throughput["simulated_s"] == pytest.approx(48.0)
    assert throughput["flight_s_per_wall_s"] == pytest.approx(48.0 / throughput["wall_s"])
    assert f"48 simulated flight-s in {throughput['wall_s']:.1f} s wall" in summary


def test_error_windows_average_the_requested_span(loaded):
    scenario, vehicle = loaded
    base = montecarlo.with_overrides(scenario, {"simulation.duration": 8.0, "simulation.summary_window": 8.0})
    labels = {"scenario": "s", "estimator": "uplkf", "guidance": "hng", "case": "c"}
    result = montecarlo.fly(montecarlo.FlightTask(labels, base, vehicle, 1, 2.0, ((1.0, 4.0), (4.0, 8.0), (20.0, 30.0))))
    row, samples = result["row"], result["series"]
    early, late = row["error_1-4s"], row["error_4-8s"]
    grid_error = np.abs(samples["range_estimation_error"])
    inside = (samples["time"] >= 1.0) & (samples["time"] < 4.0)
    assert early == pytest.approx(np.mean(grid_error[inside]), rel=0.1)  # the 0.2 s grid against every tick
    assert late < early  # the estimate converges
    assert math.isnan(row["error_20-30s"])  # a window after the flight has no figure
    (entry,) = montecarlo.group_table([row])
    assert entry["error_4-8s_median"] == late
    assert montecarlo.parse_window("10:30") == (10.0, 30.0)
    for bad in ("10", "30:10", "a:b", "-1:2"):
        with pytest.raises(ValueError):
            montecarlo.parse_window(bad)


def test_command_rejects_bad_arguments(tmp_path, capsys):
    assert montecarlo.main(["--runs", "0", "--out", str(tmp_path)]) == 2
    assert montecarlo.main(["--case", "broken", "--out", str(tmp_path)]) == 2
    assert montecarlo.main(["--initial-box", "1,0,0,1,0,1", "--out", str(tmp_path)]) == 2
    assert montecarlo.main(["--error-window", "5", "--out", str(tmp_path)]) == 2
    assert "bof-montecarlo:" in capsys.readouterr().err
    # not a number: nan passed `<= 0` and counted every flight diverged; an infinite box crashed numpy's uniform
    assert montecarlo.main(["--divergence-threshold", "nan", "--out", str(tmp_path)]) == 2
    assert montecarlo.main(["--initial-box=nan,nan,0,1,0,1", "--out", str(tmp_path)]) == 2
    assert montecarlo.main(["--initial-box=-inf,inf,0,1,0,1", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("bof-montecarlo:") == 3
    # a typo of a count is refused before a billion tasks are built (each holds a validated scenario)
    assert montecarlo.main(["--runs", "1000000000", "--executor", "serial", "--out", str(tmp_path)]) == 2
    assert "make 1,000,000,000 flights; at most 100,000 in one run" in capsys.readouterr().err
    # a name twice would mix two sets of flights in one row of the table
    assert montecarlo.main(["--guidance", "hng", "hng", "--out", str(tmp_path)]) == 2
    assert montecarlo.main(["--case=a:guidance.c_y=0", "--case=a:guidance.c_y=3.5", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("given twice") == 2
    # a window past the end of the flight gave an all-NaN column and no word about it
    assert montecarlo.main(["--duration", "3", "--error-window", "100:200", "--out", str(tmp_path)]) == 2
    assert "--error-window 100:200 ends after the shortest flight (3 s)" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_scenarios_of_different_durations_share_one_series_file(tmp_path):
    """Flights of 4 s and 6 s in one grid: the shorter one's series is padded with NaN past its end
    (0.2 s grid: 21 and 31 samples), the table has both."""
    text = SCENARIO.read_text()
    paths = []
    for name, duration in (("short", 4.0), ("long", 6.0)):
        path = tmp_path / f"{name}.toml"
        # each its own name: two files of one name would share a row of the table (refused)
        path.write_text(text.replace('vehicle = "../vehicles/', f'vehicle = "{SCENARIO.parent.parent}/vehicles/')
                        .replace('name = "constant_velocity"', f'name = "{name}"')
                        .replace("duration = 60.0", f"duration = {duration}").replace("summary_window = 20.0", "summary_window = 2.0"))
        paths.append(path)
    out = tmp_path / "out"
    assert montecarlo.main([*map(str, paths), "--runs", "1", "--executor", "serial", "--no-plots", "--quiet",
                            "--out", str(out)]) == 0
    (folder,) = out.iterdir()
    with np.load(folder / "series.npz") as series:
        error = series["range_estimation_error"]
        assert error.shape == (2, 31)
        assert np.isnan(error[0, 21:]).all() and np.isfinite(error[0, 1:21]).any()
        assert np.isfinite(error[1, 21:]).any()
        np.testing.assert_allclose(series["time"][0], np.arange(31) * 0.2, atol=1e-9)


def test_studies_fly_the_right_system_and_a_grid_keeps_each_scenarios_estimator():
    """The paper's studies fly the paper's system (monitor reporting only); the maneuvering study flies today's
    defaults (IMM, acting monitor); without --estimators a scenario keeps its own [estimator] and its rows say which."""
    for name in ("estimators", "guidance", "table2"):
        study = montecarlo.STUDIES[name]
        scenarios = [load_scenario(montecarlo.SCENARIOS / f"{s}.toml") for s in study.scenarios]
        tasks = montecarlo.build_tasks(scenarios, list(study.estimators), list(study.guidance), list(study.cases), 1,
                                       study.initial_box, 2.0, base_overrides=dict(study.overrides))
        assert all(task.scenario.health.act is False for task in tasks)
        assert "imm" not in {task.labels["estimator"] for task in tasks}
    study = montecarlo.STUDIES["maneuvering"]
    tasks = montecarlo.build_tasks([load_scenario(montecarlo.SCENARIOS / "circle_5ms.toml")], list(study.estimators),
                                   ["hng"], list(study.cases), 1, None, 2.0, base_overrides=dict(study.overrides))
    assert all(t.scenario.estimator.kind == "imm" and t.scenario.health.act is True for t in tasks)
    own = [load_scenario(montecarlo.SCENARIOS / f"{s}.toml") for s in ("seed003_ekf_rae", "constant_velocity")]
    tasks = montecarlo.build_tasks(own, [montecarlo.SCENARIO_ESTIMATOR], ["hng"], [("default", {})], 1, None, 2.0)
    assert [t.labels["estimator"] for t in tasks] == ["ekf_rae", "imm"]
    assert [t.scenario.estimator.kind for t in tasks] == ["ekf_rae", "imm"]


def test_the_parent_compiles_the_kernels_before_starting_workers():
    """A local process pool (and bof-sitl) first compiles the plant's and the estimators' numba kernels in the
    parent (or loads them from the cache), so the workers load the cache instead of each compiling for ~30 s."""
    from companion.core import _jit as estimator_jit
    from companion.core import estimators, imm
    from sitl_plant import _jit as plant_jit
    from sitl_plant.vehicle import kernels
    from studies.executors import compile_kernels

    assert compile_kernels() >= 0.0
    if plant_jit.ENABLED:
        assert kernels.advance_steps.signatures and kernels.rk4_step.signatures
    if estimator_jit.ENABLED:
        # the kernels Python calls (a kernel only other kernels call, such as _correct_with, gets no signature of
        # its own when its callers come from numba's cache, so it says nothing about what was compiled)
        assert (estimators._correct_into.signatures and estimators._predict_kernel.signatures
                and imm._imm_correction.signatures and imm._predict_models.signatures
                and imm._turn_acceleration_into.signatures)


_CELL = st.text(alphabet="abcdefghij0123456789 ./()-", min_size=0, max_size=40).map(str.strip)


@given(st.integers(1, 12).flatmap(lambda columns: st.tuples(
    st.lists(_CELL.filter(bool), min_size=columns, max_size=columns, unique=True),
    st.lists(st.lists(_CELL, min_size=columns, max_size=columns), min_size=0, max_size=6))),
    st.text(alphabet="abc de", min_size=0, max_size=400))
def test_a_report_on_the_terminal_fits_120_columns_and_keeps_each_rows_leading_cells(table, prose):
    """The terminal's copy of a study report (the whole one goes to summary.md): every line within 120
    columns, unless one word or the first column alone is wider; a table keeps its first columns, each row's
    cells as they were, and says how many of its columns it shows when it drops any."""
    from studies import reporting

    headers, rows = table
    report = f"# title\n\n{prose}\n\n" + reporting.markdown([dict(zip(headers, row)) for row in rows], headers)
    text = reporting.for_terminal(report)
    longest_word = max((len(word) for word in prose.split()), default=0)
    lines = text.splitlines()
    table_lines = [line for line in lines if line.startswith("|")]
    first = max(len(cell) for cell in [headers[0], *(row[0] for row in rows)] + ["---"])
    for line in lines:
        assert len(line) <= max(reporting.TERMINAL_WIDTH, longest_word, first + 4), line
    shown = len(table_lines[0].strip("|").split("|"))
    assert 1 <= shown <= len(headers)
    assert [cell.strip() for cell in table_lines[0].strip("|").split("|")] == [h.strip() for h in headers[:shown]]
    for line, row in zip(table_lines[2:], rows):
        assert [cell.strip() for cell in line.strip("|").split("|")] == [c.strip() for c in row[:shown]]
    assert (f"({shown} of {len(headers)} columns; the whole table is in summary.md)" in text) == (shown < len(headers))


def test_progress_written_to_a_file_is_plain_lines_about_every_tenth_of_the_run(monkeypatch):
    """Captured (not a terminal), the progress is lines of their own, no carriage returns or bar characters: about
    one per tenth of the run, each saying how far it is, the last one the whole run."""
    import io

    from studies import reporting

    captured = io.StringIO()
    monkeypatch.setattr("sys.stderr", captured)
    with reporting.progress_bar(200, "flights", description="study") as bar:
        for _ in range(200):
            bar.update()
    text = captured.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and "#" not in text and "|" not in text
    assert 5 <= len(lines) <= 13, lines
    assert all(line.startswith("study: ") and " flights (" in line for line in lines)
    assert lines[-1].startswith("study: 200/200 flights (100 %)")
