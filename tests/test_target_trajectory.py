"""[target.trajectory]: recorded tracks (interfaces.trajectory, sitl_plant.world.target.TrajectoryTarget).

References independent of the code under test: an analytic circle sampled into a CSV (the replay's position,
velocity and acceleration against the circle's own), a cubic polynomial track (which a not-a-knot cubic spline
reproduces exactly) written into a ULog by tests/ulog_writer.py, byte for byte from the ULog layout, and the
values written into each file.
"""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from interfaces.link_schema import fix_to_ned
from interfaces.scenario import SCENARIOS_DIR, ConfigError, TargetConfig, load_plant_scenario, load_scenario
from interfaces.trajectory import read_trajectory
from sitl_plant.world.target import TrajectoryTarget, target_from_config
from studies.closed_loop import simulate
from ulog_writer import LOCAL_POSITION_FIELDS, ulog_bytes, write_local_position_ulog

RADIUS, OMEGA = 20.0, 0.25  # m, rad/s: 5 m/s on the circle, 1.25 m/s^2 towards its centre
CENTRE = np.array([30.0, 10.0, -15.0])
PLACED = [50.0, -25.0, -20.0]


def _circle(time):
    """Position (m), velocity (m/s), acceleration (m/s^2) of the analytic circle, NED, climbing at 0.5 m/s."""
    time = np.asarray(time, dtype=float)
    angle = OMEGA * time
    position = np.stack([CENTRE[0] + RADIUS * np.cos(angle), CENTRE[1] + RADIUS * np.sin(angle), CENTRE[2] - 0.5 * time], -1)
    velocity = np.stack([-RADIUS * OMEGA * np.sin(angle), RADIUS * OMEGA * np.cos(angle), np.full_like(time, -0.5)], -1)
    acceleration = np.stack([-RADIUS * OMEGA**2 * np.cos(angle), -RADIUS * OMEGA**2 * np.sin(angle), np.zeros_like(time)], -1)
    return position, velocity, acceleration


def _write_circle_csv(path: Path, duration: float = 40.0, rate_hz: float = 10.0, t0: float = 100.0) -> Path:
    times = np.arange(0.0, duration + 1e-9, 1.0 / rate_hz)
    positions, _, _ = _circle(times)
    rows = "\n".join(f"{t0 + t!r},{n!r},{e!r},{d!r}" for t, (n, e, d) in zip(times.tolist(), positions.tolist()))
    path.write_text("# an analytic circle, 10 Hz\nt,north,east,down\n" + rows + "\n")
    return path


def _replay(path: Path, **trajectory) -> TrajectoryTarget:
    config = TargetConfig.model_validate({"initial_position": PLACED, "trajectory": {"file": str(path), **trajectory}})
    model = target_from_config(config, 0)
    assert isinstance(model, TrajectoryTarget)
    return model


def _placed_circle(time: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    position, velocity, acceleration = _circle(time)
    return position - _circle(0.0)[0] + PLACED, velocity, acceleration


# --- CSV -------------------------------------------------------------------------------------------------------------

def test_a_csv_circle_at_10_hz_is_replayed_within_millimetres_and_centimetres_per_second(tmp_path):
    model = _replay(_write_circle_csv(tmp_path / "circle.csv"))
    assert model.position.tolist() == PLACED  # the first sample, put at initial_position
    for time in np.linspace(2.0, 38.0, 157):  # mid-track, between samples and on them
        model.advance_to(float(time))
        position, velocity, acceleration = _placed_circle(float(time))
        # A cubic spline through 10 Hz samples of this circle errs by micrometres; linear interpolation would be
        # off by 6 cm/s in velocity and by the whole centripetal acceleration.
        assert np.allclose(model.position, position, rtol=0, atol=1e-3)
        assert np.allclose(model.velocity, velocity, rtol=0, atol=1e-2)
        assert np.allclose(model.acceleration, acceleration, rtol=0, atol=1e-2)


def test_the_columns_may_come_in_any_order_with_others_beside_them(tmp_path):
    times = np.arange(0.0, 3.01, 0.5)
    positions = _circle(times)[0]
    rows = "\n".join(f"87,{d!r},{t!r},{e!r},{n!r}" for t, (n, e, d) in zip(times.tolist(), positions.tolist()))
    path = tmp_path / "shuffled.csv"
    path.write_text(" battery, down ,t,east,north\n" + rows + "\n\n")
    read_times, read_positions = read_trajectory(path, "csv")
    assert read_times.tolist() == times.tolist()
    assert read_positions.tolist() == positions.tolist()


def test_before_start_the_target_hovers_at_the_first_point_and_skip_starts_into_the_file(tmp_path):
    path = _write_circle_csv(tmp_path / "circle.csv")
    model = _replay(path, start=5.0, skip=8.0)
    for time in (0.0, 2.0, 4.999):
        model.advance_to(time)
        assert model.position.tolist() == PLACED and model.velocity.tolist() == [0.0, 0.0, 0.0]
        assert model.acceleration.tolist() == [0.0, 0.0, 0.0]
    for time in (5.0, 12.0, 30.0):  # file time 8 + (t - 5), its point at 8 s put at initial_position
        model.advance_to(time)
        position, velocity, _ = _circle(8.0 + time - 5.0)
        assert np.allclose(model.position, position - _circle(8.0)[0] + PLACED, rtol=0, atol=3e-3)
        assert np.allclose(model.velocity, velocity, rtol=0, atol=3e-2)


def test_after_the_last_sample_the_target_flies_on_at_the_final_velocity(tmp_path):
    model = _replay(_write_circle_csv(tmp_path / "circle.csv", duration=20.0))
    assert model.end_time == pytest.approx(20.0)
    model.advance_to(20.0)
    last_position, last_velocity = model.position.copy(), model.velocity.copy()
    assert np.allclose(last_position, _placed_circle(20.0)[0], rtol=0, atol=1e-9)  # the spline interpolates: exact at samples
    assert np.allclose(last_velocity, _circle(20.0)[1], rtol=0, atol=0.1)  # an end derivative, less exact than mid-track
    for time in (20.5, 27.0, 100.0):
        model.advance_to(time)
        assert np.allclose(model.position, last_position + (time - 20.0) * last_velocity, rtol=0, atol=1e-9)
        assert model.velocity.tolist() == last_velocity.tolist() and model.acceleration.tolist() == [0.0, 0.0, 0.0]


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.floats(0.0, 50.0), max_size=20))
def test_the_replay_does_not_depend_on_how_time_is_cut(tmp_path_factory, cuts):
    path = _write_circle_csv(tmp_path_factory.mktemp("cut") / "circle.csv")
    reference = _replay(path, start=3.0)
    reference.advance_to(50.0)
    model = _replay(path, start=3.0)
    for time in sorted(cuts):
        model.advance_to(time)
    model.step(50.0 - model.time)
    assert model.position.tolist() == reference.position.tolist()
    assert model.velocity.tolist() == reference.velocity.tolist()


# --- ULog ------------------------------------------------------------------------------------------------------------

def _cubic(times: np.ndarray) -> np.ndarray:
    """A cubic polynomial track (m, NED): a not-a-knot cubic spline through its samples is the cubic itself."""
    t = np.asarray(times, dtype=float)
    return np.stack([1.0 + 2.0 * t + 0.1 * t**2 - 0.01 * t**3, -3.0 + 0.5 * t**2 - 0.02 * t**3, -10.0 - 0.3 * t], -1)


def test_a_ulog_written_here_reads_back_the_values_written(tmp_path):
    boot = 3_600_000_000  # us: an hour after boot, as a real log's first sample
    stamps = [boot + 200_000 * k + (k % 3) * 17 for k in range(40)]  # 5 Hz with a few us of jitter
    times = (np.array(stamps) - boot) * 1e-6
    written = _cubic(times).astype(np.float32)  # ULog stores float x, y, z
    path = write_local_position_ulog(tmp_path / "flight.ulg", stamps, [tuple(map(float, row)) for row in written],
                                     start_us=boot - 5_000_000)
    read_times, positions = read_trajectory(path, "ulog")
    assert np.allclose(read_times, (np.array(stamps, dtype=np.int64) - stamps[0]) / 1e6, rtol=0, atol=1e-12)
    assert np.array_equal(positions, written.astype(float))


def test_a_ulog_track_flies_through_a_scenario_and_its_spline_reproduces_a_cubic(tmp_path):
    stamps = [1_000_000 + 100_000 * k for k in range(80)]  # 10 Hz, 7.9 s
    times = np.array([0.1 * k for k in range(80)])
    written = _cubic(times).astype(np.float32)
    (tmp_path / "logs").mkdir()
    write_local_position_ulog(tmp_path / "logs" / "flight.ulg", stamps, [tuple(map(float, row)) for row in written])
    text = (SCENARIOS_DIR / "stop_and_go.toml").read_text().split("[target]")[0].replace(
        'vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml"}"')
    scenario_path = tmp_path / "replay.toml"
    scenario_path.write_text(text + '[target]\ninitial_position = [50.0, -25.0, -20.0]\n\n[target.trajectory]\n'
                             'file = "logs/flight.ulg"\n\n[estimator]\ninitial_position = [40.0, -20.0, -15.0]\n')
    scenario, _ = load_scenario(scenario_path)
    assert scenario.target.trajectory.file == str(tmp_path / "logs" / "flight.ulg")
    model = target_from_config(scenario.target, 0)
    offset = np.array([50.0, -25.0, -20.0]) - _cubic(0.0)
    for time in (0.05, 1.234, 4.0, 7.77):
        model.advance_to(time)
        # float32 storage rounds the samples by up to ~1e-6 m; the spline of the rounded samples stays that close.
        assert np.allclose(model.position, _cubic(time) + offset, rtol=0, atol=1e-5)


def test_the_first_vehicle_local_position_instance_is_the_one_replayed(tmp_path):
    stamps = [100_000 * k for k in range(1, 7)]
    fields = LOCAL_POSITION_FIELDS
    second = [(stamp, 99.0, 99.0, 99.0) for stamp in stamps]
    first = [(stamp, float(k), 0.0, -5.0) for k, stamp in enumerate(stamps)]
    data = bytearray(ulog_bytes({"vehicle_local_position": (fields, first)}))
    path = tmp_path / "two.ulg"
    # A second instance (multi_id 1) of the same topic, subscribed under message id 1.
    data += struct.pack("<HB", 3 + len("vehicle_local_position"), ord("A")) + struct.pack("<BH", 1, 1) + b"vehicle_local_position"
    for row in second:
        payload = struct.pack("<H", 1) + struct.pack("<Qfff", *row)
        data += struct.pack("<HB", len(payload), ord("D")) + payload
    path.write_bytes(bytes(data))
    _, positions = read_trajectory(path, "ulog")
    assert positions[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]


# --- bad files ---------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("content, message", [
    ("", "empty"),
    ("# only a comment\n", "empty"),
    ("time,north,east,down\n0,0,0,0\n1,1,0,0\n2,2,0,0\n3,3,0,0\n", "missing t"),
    ("t,north,east\n0,0,0\n1,1,0\n2,2,0\n3,3,0\n", "missing down"),
    ("t,north,east,down,t\n0,0,0,0,0\n", "t given twice"),
    ("t,north,east,down\n0,0,0,0\n1,1,0,0\n2,2,0,0\n", "3 samples; a trajectory needs at least 4"),
    ("t,north,east,down\n0,0,0,0\n1,1,0\n2,2,0,0\n3,3,0,0\n", "line 3: 3 fields, the header has 4"),
    ("t,north,east,down\n0,0,0,0\n1,x,0,0\n2,2,0,0\n3,3,0,0\n", "line 3: north = 'x' is not a number"),
    ("t,north,east,down\n0,0,0,0\n1,1,0,0\n1,2,0,0\n3,3,0,0\n", "sample 3: time 1 s does not increase"),
    ("t,north,east,down\n0,0,0,0\n2,1,0,0\n1,2,0,0\n3,3,0,0\n", "sample 3: time 1 s does not increase"),
    ("t,north,east,down\n0,0,0,0\nnan,1,0,0\n2,2,0,0\n3,3,0,0\n", "sample 2: time is not finite"),
    ("t,north,east,down\n0,0,0,0\n1,1,inf,0\n2,2,0,0\n3,3,0,0\n", "sample 2: position is not finite"),
    ("t,north,east,down\n0,0,0,0\n1,1,0,0\n2,2,0,0\n3,1e999,0,0\n", "sample 4: position is not finite"),
])
def test_bad_csv_files_are_refused_in_one_line_naming_the_file(tmp_path, content, message):
    path = tmp_path / "track.csv"
    path.write_text(content)
    _refused_in_one_line(path, "csv", message)


def _refused_in_one_line(path: Path, file_format: str, message: str) -> None:
    """read_trajectory refuses the file with a ConfigError matching `message`, one line, the file named first."""
    with pytest.raises(ConfigError, match=message) as error:
        read_trajectory(path, file_format)
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


def test_files_that_are_no_trajectory_are_refused(tmp_path):
    cases = {tmp_path / "missing.csv": "file not found", tmp_path: "not a regular file"}
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"t,north,east,down\n\xff\xfe\n")
    cases[binary] = "not UTF-8"
    huge = tmp_path / "huge.csv"
    with open(huge, "wb") as handle:
        handle.truncate(64 * 1024 * 1024 + 1)  # sparse: no disk used
    cases[huge] = "larger than 64 MiB"
    cases[Path("/dev/zero")] = "not a regular file"  # never ends: refused before reading
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    cases[fifo] = "not a regular file"  # would block a reader: refused without waiting for a writer
    for path, message in cases.items():
        with pytest.raises(ConfigError, match=message) as error:
            read_trajectory(path, "csv")
        assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


def _local_position_rows(count: int) -> list[tuple]:
    return [(100_000 * (k + 1), float(k), 0.0, -5.0) for k in range(count)]


@pytest.mark.parametrize("data, message", [
    (b"", "Header too short"),
    (b"not a ulog file at all, just text", "not a readable ULog file"),
    (ulog_bytes({"vehicle_gps_position": (LOCAL_POSITION_FIELDS, _local_position_rows(6))}), "no vehicle_local_position"),
    (ulog_bytes({"vehicle_local_position": (LOCAL_POSITION_FIELDS[:3], [row[:3] for row in _local_position_rows(6)])}),
     "has no field z"),
    (ulog_bytes({"vehicle_local_position": (LOCAL_POSITION_FIELDS, _local_position_rows(3))}), "3 samples"),
    (ulog_bytes({"vehicle_local_position": (LOCAL_POSITION_FIELDS, [(5, 0.0, 0.0, 0.0), (5, 1.0, 0.0, 0.0),
                                                                     (6, 2.0, 0.0, 0.0), (7, 3.0, 0.0, 0.0)])}),
     "timestamps must increase strictly"),
    (ulog_bytes({"vehicle_local_position": (LOCAL_POSITION_FIELDS, [(1, 0.0, 0.0, 0.0), (2, math.nan, 0.0, 0.0),
                                                                     (3, 2.0, 0.0, 0.0), (4, 3.0, 0.0, 0.0)])}),
     "sample 2: position is not finite"),
])
def test_bad_ulog_files_are_refused_in_one_line_naming_the_file(tmp_path, data, message):
    path = tmp_path / "flight.ulg"
    path.write_bytes(data)
    _refused_in_one_line(path, "ulog", message)


@settings(max_examples=60, deadline=None)
@given(cut=st.integers(16, 400), flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=8))
def test_corrupt_ulog_bytes_are_read_or_refused_never_a_traceback(tmp_path_factory, cut, flips):
    data = bytearray(ulog_bytes({"vehicle_local_position": (LOCAL_POSITION_FIELDS, _local_position_rows(20))}))
    for offset, value in flips:
        data[offset % len(data)] = value
    path = tmp_path_factory.mktemp("corrupt") / "flight.ulg"
    path.write_bytes(bytes(data[:cut]))
    try:
        times, positions = read_trajectory(path, "ulog")
    except ConfigError as error:
        assert str(error).startswith(str(path)) and "\n" not in str(error)
    else:
        assert times.size >= 4 and np.all(np.diff(times) > 0) and np.all(np.isfinite(positions))


# --- the schema and the loaders --------------------------------------------------------------------------------------

def _scenario_text(trajectory: str) -> str:
    head = (SCENARIOS_DIR / "stop_and_go.toml").read_text().split("[target]")[0].replace(
        'vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml"}"')
    return (head + "[target]\ninitial_position = [50.0, -25.0, -20.0]\n\n[target.trajectory]\n" + trajectory
            + "\n[estimator]\ninitial_position = [40.0, -20.0, -15.0]\n")


def test_the_loaders_resolve_the_file_against_the_scenario_folder_from_any_working_directory(tmp_path, monkeypatch):
    folder = tmp_path / "flights"
    (folder / "tracks").mkdir(parents=True)
    _write_circle_csv(folder / "tracks" / "circle.csv")
    (folder / "replay.toml").write_text(_scenario_text('file = "tracks/circle.csv"\n'))
    monkeypatch.chdir(tmp_path)
    expected = str((folder / "tracks" / "circle.csv").resolve())
    for load in (load_scenario, load_plant_scenario):
        scenario, _ = load(Path("flights") / "replay.toml")
        assert scenario.target.trajectory.file == expected
    absolute = tmp_path / "elsewhere.toml"
    absolute.write_text(_scenario_text(f'file = "{expected}"\n'))
    assert load_scenario(absolute)[0].target.trajectory.file == expected


@pytest.mark.parametrize("trajectory, message", [
    ('file = "nowhere.csv"\n', "target.trajectory.file = 'nowhere.csv': .*nowhere.csv: file not found"),
    ('file = "bad.csv"\n', "bad.csv: 2 samples"),
    ('file = "circle.csv"\nskip = 50.0\n', "target.trajectory.skip: 50 s leaves nothing of the 40 s track"),
    ('file = "a\\u0000b.csv"\n', "target.trajectory.file: 'a\\\\x00b.csv' is not a usable path"),
])
def test_a_scenario_with_a_bad_trajectory_is_refused_naming_the_scenario_and_the_key(tmp_path, trajectory, message):
    _write_circle_csv(tmp_path / "circle.csv")
    (tmp_path / "bad.csv").write_text("t,north,east,down\n0,0,0,0\n1,1,0,0\n")
    path = tmp_path / "replay.toml"
    path.write_text(_scenario_text(trajectory))
    for load in (load_scenario, load_plant_scenario):
        with pytest.raises(ConfigError, match=message) as error:
            load(path)
        assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


@pytest.mark.parametrize("fields, message", [
    ({"initial_velocity": [1.0, 0.0, 0.0], "trajectory": {"file": "a.csv"}}, "leave initial_velocity out"),
    ({"trajectory": {"file": "a.csv"}, "segments": [{"kind": "hover", "duration": 1.0}]}, "not several"),
    ({"trajectory": {"file": "a.csv"}, "circle": {"radius": 10.0}}, "not several"),
    ({"trajectory": {"file": "a.txt"}}, "cannot tell the format of 'a.txt'"),
    ({"trajectory": {"file": "a.csv", "format": "gpx"}}, "'csv' or 'ulog'"),
    ({"trajectory": {"file": ""}}, "at least 1 character"),
    ({"trajectory": {"file": "a.csv", "skip": -1.0}}, "greater than or equal to 0"),
    ({"trajectory": {"file": "a.csv", "start": 86401.0}}, "less than or equal to 86400"),
    ({"trajectory": {"file": "a.csv", "origin": [0, 0, 0]}}, "Extra inputs"),
])
def test_inconsistent_trajectory_settings_are_refused(fields, message):
    with pytest.raises(ValidationError, match=message):
        TargetConfig.model_validate({"initial_position": PLACED, **fields})


def test_the_format_is_given_or_told_by_the_extension():
    assert TargetConfig.model_validate({"initial_position": PLACED, "trajectory": {"file": "x/flight.ULG"}}).trajectory.file_format == "ulog"
    assert TargetConfig.model_validate({"initial_position": PLACED, "trajectory": {"file": "x/t.csv"}}).trajectory.file_format == "csv"
    given_format = {"file": "x/t.txt", "format": "csv"}
    assert TargetConfig.model_validate({"initial_position": PLACED, "trajectory": given_format}).trajectory.file_format == "csv"


def test_the_sitl_target_process_flies_the_recorded_track(tmp_path, sitl_target_fixes):
    """sitl-target reads the scenario itself (from its own working directory, not the scenario's folder): the
    trajectory path, relative to the scenario file, reaches it resolved."""
    (tmp_path / "tracks").mkdir()
    _write_circle_csv(tmp_path / "tracks" / "circle.csv")
    path = tmp_path / "replay.toml"
    path.write_text(_scenario_text('file = "tracks/circle.csv"\n'))
    scenario, _ = load_scenario(path)
    fixes = sitl_target_fixes(path, tmp_path)
    assert len(fixes) >= 30 and fixes[-1].stamp == 4.0
    for fix in fixes:
        position, velocity, _ = _circle(fix.stamp)
        assert np.allclose(fix_to_ned(fix, scenario.sitl.home), position - _circle(0.0)[0] + [50.0, -25.0, -20.0],
                           rtol=0, atol=1e-2)
        assert np.allclose(fix.velocity, velocity, rtol=0, atol=0.1)


def test_the_shipped_replay_flies_its_csv_samples_in_the_in_process_simulator():
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "replay_csv.toml")
    samples = np.loadtxt(SCENARIOS_DIR.parent / "trajectories" / "hover_legs.csv", delimiter=",", skiprows=1)
    assert samples.shape[0] >= 600 and samples[-1, 0] >= 60.0
    scenario = scenario.model_copy(update={"simulation": scenario.simulation.model_copy(update={"duration": 12.0,
                                                                                              "summary_window": 4.0})})
    series = simulate(scenario, vehicle, seed=2).series
    offset = np.array(scenario.target.initial_position) - samples[0, 1:]
    matched = 0
    for time, position in zip(series["time"], series["target_position"]):
        index = round(time * 10.0)
        if abs(time - samples[index, 0]) < 1e-9:  # a flight instant on a sample: the spline passes through it
            assert np.allclose(position, samples[index, 1:] + offset, rtol=0, atol=1e-6)
            matched += 1
    assert matched >= 100


#: A corrupt ULog (a cut and a few flipped bytes of this file's own 20-sample log) on which pyulog's definitions
#: loop seeks back before its own header and reads the same messages for ever.
LOOPING_ULOG = "eNoL9clPZxQyZWSAAg0GJyB5kIGhjIEQsGVwK0vNyEzOSY3PyU9OzIkvyC/OLMnMz7MqzcwrMTOJL1EoycxNLS5JzC2wTsvJTyxRqIDSlVC6ylqSwRFoFHZzxBhcGBgWtDGi2bvgAFjCgZcZKtBgjyLxYDILTKkDikSDFBtMHFVCYSE7zChUiQPqnDBLUSUS1nFBJQ6gSjCY8gAJAOSxPc0="


def test_a_ulog_that_sends_the_parser_round_in_circles_is_refused_in_one_line(tmp_path):
    import base64
    import zlib

    path = tmp_path / "looping.ulg"
    path.write_bytes(zlib.decompress(base64.b64decode(LOOPING_ULOG)))
    _refused_in_one_line(path, "ulog", "not a readable ULog file")
