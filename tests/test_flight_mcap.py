"""flight.mcap: the flight in Foxglove's schemas, written by bof-sim and read back with the mcap library.

References: the flight's own series and summary.json (what the file must carry), the definition of a
covariance ellipsoid (R diag(semi-axes^2) R' = k^2 P), sigma_r = sqrt(u' P u) in closed form for a
diagonal P, scipy's rotations, and the NED -> (east, north, up) axis map.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from interfaces import flight_channels as fc
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies import flight_plot, run_scenario
from studies.closed_loop import simulate
from studies.montecarlo import with_overrides


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """A 15 s flight through the in-process link with dropouts, its run folder written as bof-sim writes it."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity_dropout.toml")
    scenario = with_overrides(scenario, {"simulation.duration": 15.0, "simulation.summary_window": 10.0})
    result = simulate(scenario, vehicle, seed=3)
    folder = tmp_path_factory.mktemp("run")
    run_scenario.write_run_folder(result, folder, plots=False)
    return result, folder


def test_every_channel_is_there_in_one_time_base(flown):
    result, folder = flown
    flight = fc.read_flight(folder / "flight.mcap")
    assert set(flight.times) == set(fc.ALL_TOPICS)
    duration = float(result.series["time"][-1])
    for topic, times in flight.times.items():
        assert np.all(np.diff(times) >= 0.0), topic
        assert 0.0 <= times[0] and times[-1] <= duration + 1e-9, topic
    # the messages' own timestamps are the log times
    for topic in fc.POSE_TOPICS.values():
        stamps = [m.timestamp.seconds + m.timestamp.nanos * 1e-9 for m in flight.messages[topic]]
        assert np.allclose(stamps, flight.times[topic], atol=1e-9), topic
    assert flight.schemas["/pursuer/pose"] == "foxglove.PoseInFrame"
    assert flight.schemas["/scene"] == "foxglove.SceneUpdate"
    assert flight.schemas["/events"] == "foxglove.Log"


def test_the_last_estimate_and_the_figures_are_the_summarys(flown):
    result, folder = flown
    summary = json.loads((folder / "summary.json").read_text())
    flight = fc.read_flight(folder / "flight.mcap")
    last = flight.messages["/estimate/pose"][-1].pose.position
    expected = summary["final_estimate"]["position"]
    assert max(abs(a - b) for a, b in zip((last.x, last.y, last.z), expected)) <= 1e-9 * max(1.0, np.abs(expected).max())
    assert flight.times["/estimate/pose"][-1] == pytest.approx(summary["final_estimate"]["time"], abs=1e-9)
    meta = flight.metadata["flight"]
    assert float(meta["range_estimation_error_rms"]) == summary["range_estimation_error_rms"]
    assert meta["outcome"] == summary["truth"]["outcome"]
    # the range channel's truth is the series' true range, sample for sample
    times, ranges = flight.series("/flight/range", "range")
    series = result.series
    index = np.searchsorted(series["time"], times - 1e-6)  # log times are whole nanoseconds
    assert np.allclose(ranges, series["range"][index], rtol=0, atol=1e-12)


def test_link_counts_and_events_follow_the_flight(flown):
    result, folder = flown
    flight = fc.read_flight(folder / "flight.mcap")
    link = flight.messages["/link"][-1]
    assert link["accepted"] == result.summary["link"]["accepted"]
    assert link["rejected"] == sum(result.summary["link"]["rejected"].values())
    texts = [m.message for m in flight.messages["/events"]]
    assert texts[0].startswith("engaged")
    faults = [text for text in texts if text.startswith("link fault")]
    assert len(faults) == len(result.summary["fault_events"])


def test_the_health_channel_marks_what_the_series_marks(flown):
    result, folder = flown
    flight = fc.read_flight(folder / "flight.mcap")
    times, suspect = flight.series("/health", "suspect")
    series = result.series
    flagged = np.isfinite(series["health_suspect"])
    assert len(times) == flagged.sum()
    assert np.array_equal(suspect, series["health_suspect"][flagged])


def test_bof_plot_draws_both_figures_from_the_file_alone(flown, tmp_path):
    _, folder = flown
    copy = tmp_path / "only.mcap"
    copy.write_bytes((folder / "flight.mcap").read_bytes())
    assert flight_plot.main([str(copy)]) == 0
    for suffix in ("scene", "plots"):
        png = tmp_path / f"only-{suffix}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_bof_plot_refuses_what_is_not_a_flight(tmp_path, capsys):
    junk = tmp_path / "flight.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    assert flight_plot.main([str(tmp_path)]) == 1
    assert "not a readable flight MCAP" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        flight_plot.main([str(tmp_path / "empty-folder-that-is-missing")])
    assert stop.value.code == 2


def test_suspect_spans_cover_exactly_the_flagged_samples():
    times = np.arange(10.0)
    suspect = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=float)
    assert flight_plot.suspect_spans(times, suspect) == [(1.0, 3.0), (5.0, 6.0), (7.0, 9.0)]


def _spd(values):
    a = np.array(values).reshape(3, 3)
    return a @ a.T + 1e-3 * np.eye(3)


matrices = st.lists(st.floats(-5.0, 5.0), min_size=9, max_size=9).map(_spd)


@settings(max_examples=60, deadline=None)
@given(matrices)
def test_the_ellipsoid_is_the_covariance_at_two_sigma(covariance):
    """R diag((d / 2)^2) R' = k^2 P for the drawn orientation R and diameters d (k = ELLIPSOID_SIGMAS)."""
    (w, x, y, z), diameters = fc.ellipsoid(covariance)
    rotation = Rotation.from_quat([x, y, z, w]).as_matrix()
    rebuilt = rotation @ np.diag((np.array(diameters) / 2.0) ** 2) @ rotation.T
    assert np.allclose(rebuilt, fc.ELLIPSOID_SIGMAS ** 2 * covariance, rtol=1e-7, atol=1e-9)
    assert math.isclose(w * w + x * x + y * y + z * z, 1.0, rel_tol=1e-12) and w >= 0.0


@given(st.lists(st.floats(1e-4, 100.0), min_size=3, max_size=3), st.lists(st.floats(-50, 50), min_size=3, max_size=3))
def test_range_sigma_of_a_diagonal_covariance(variances, offset):
    offset = np.array(offset)
    distance = np.linalg.norm(offset)
    if distance < 1e-3:
        assert math.isnan(fc.range_sigma(np.eye(3), np.zeros(3), np.zeros(3)))
        return
    u = offset / distance
    expected = math.sqrt(sum(v * c * c for v, c in zip(variances, u)))
    assert fc.range_sigma(np.diag(variances), np.zeros(3), offset) == pytest.approx(expected, rel=1e-12)


@given(st.lists(st.floats(-math.pi, math.pi), min_size=3, max_size=3))
def test_quaternions_are_scipys_with_a_non_negative_w(angles):
    rotation = Rotation.from_euler("ZYX", angles)
    w, x, y, z = fc.quaternion_wxyz(rotation.as_matrix())
    assert w >= 0.0
    assert np.allclose(Rotation.from_quat([x, y, z, w]).as_matrix(), rotation.as_matrix(), atol=1e-12)


def test_ned_is_drawn_with_north_on_y_east_on_x_and_down_below():
    assert np.isclose(np.linalg.det(fc.NED_IN_WORLD), 1.0)
    north, east, down = np.eye(3)
    assert np.array_equal(fc.NED_IN_WORLD @ north, [0, 1, 0])
    assert np.array_equal(fc.NED_IN_WORLD @ east, [1, 0, 0])
    assert np.array_equal(fc.NED_IN_WORLD @ down, [0, 0, -1])


def test_a_json_channel_refuses_a_field_it_does_not_declare_and_drops_non_finite_values(tmp_path):
    import foxglove

    channels = fc.FlightChannels()
    writer = foxglove.open_mcap(tmp_path / "x.mcap", context=channels.context)
    channels.values("/flight/range", 1.0, {"range": math.nan, "range_estimate": 7.5})
    with pytest.raises(KeyError, match="no field 'rng'"):
        channels.values("/flight/range", 1.0, {"rng": 1.0})
    with pytest.raises(ValueError, match="not a finite time"):
        channels.pose("pursuer", -1.0, (0, 0, 0))
    writer.close()
    flight = fc.read_flight(tmp_path / "x.mcap")
    assert flight.messages["/flight/range"] == [{"range_estimate": 7.5}]


def test_the_docs_foxglove_layout_shows_only_channels_and_fields_a_flight_has():
    """docs/foxglove-layout.json: every panel it configures is placed in its layout (and only those), and every
    topic or message path it plots names a channel of interfaces.flight_channels and, on a JSON channel, a field
    that channel declares."""
    layout = json.loads((Path(__file__).resolve().parent.parent / "docs" / "foxglove-layout.json").read_text())

    def placed(node) -> list[str]:
        return [node] if isinstance(node, str) else placed(node["first"]) + placed(node["second"])

    assert sorted(placed(layout["layout"])) == sorted(layout["configById"])
    paths = []
    for config in layout["configById"].values():
        paths += [entry["value"] for entry in config.get("paths", [])]
        paths += [f"{topic}." for topic in config.get("topics", {})]
        paths += [f"{config[key]}." for key in ("topicPath", "topicToRender") if key in config]
    assert paths
    for path in paths:
        topic, _, field = path.partition(".")
        assert topic in fc.ALL_TOPICS, path
        if field:
            assert field in fc.JSON_TOPICS[topic], path


@settings(max_examples=30, deadline=None)
@given(st.lists(st.booleans(), min_size=2, max_size=60))
def test_suspect_spans_cover_exactly_the_flagged_samples(flags):
    """Each span runs from a flagged sample that follows an unflagged one (or is the first) to the next unflagged
    sample, or to the last sample when the flight ends flagged: every sample but the last lies in a span
    [start, end) exactly when it is flagged, and there is one span per run of flagged samples."""
    from studies.plots import suspect_spans

    times = np.arange(len(flags)) * 0.1
    spans = suspect_spans(times, np.array(flags, dtype=float))
    for t, flagged in zip(times[:-1], flags[:-1]):
        assert any(start <= t < end for start, end in spans) == flagged
    if flags[-1]:
        assert spans[-1][1] == times[-1]
    assert len(spans) == sum(1 for k, f in enumerate(flags) if f and (k == 0 or not flags[k - 1]))


def test_errors_figure_marks_the_window_the_convergence_and_the_suspect_spans_on_linear_signed_axes():
    """errors.png: the signed range-estimation error and the range on linear axes (values cross zero); with the
    flight's summary, the summary window, the convergence time and each suspect span drawn on every panel."""
    import matplotlib.patches

    from studies.plots import errors_figure

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    result = simulate(scenario.model_copy(update={"simulation": scenario.simulation.model_copy(update={"duration": 30.0})}),
                      vehicle, seed=1)
    series = dict(result.series)
    suspect = np.zeros(len(series["time"]))
    suspect[(series["time"] > 5.0) & (series["time"] < 8.0)] = 1.0  # one suspect span, 5-8 s
    series["health_suspect"] = suspect
    figure = errors_figure(series, scenario.guidance.desired_range, "t", result.summary)
    axes = figure.axes
    assert [ax.get_yscale() for ax in axes] == ["log", "log", "linear", "linear"]
    window = result.summary["summary_window"]
    for ax in axes:
        spans = sorted((p.get_x(), p.get_x() + p.get_width()) for p in ax.patches
                       if isinstance(p, matplotlib.patches.Rectangle))
        assert len(spans) == 2, spans
        (s0, s1), (w0, w1) = spans
        assert 5.0 < s0 < 5.1 and 8.0 <= s1 < 8.1
        assert w1 == pytest.approx(series["time"][-1]) and w1 - w0 == pytest.approx(window)
        vertical = [line.get_xdata()[0] for line in ax.lines if line.get_linestyle() == "--" and len(set(line.get_xdata())) == 1]
        assert vertical == [pytest.approx(result.summary["convergence_time"])]
