"""The filter-health monitor (companion.core.health) and how flights report it.

References: the chi-square(2) quantile in closed form, -2 ln(1 - p), a textbook linear
Kalman filter written here on simulated data, hand-made geometry for cheirality, and the
in-process simulator with a shipped good scenario and a circling target the default loses.
"""

from __future__ import annotations

import asyncio
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from companion.core.health import (REASONS, chi2_quantile, HealthConfig, HealthMonitor, HealthState,
                                   normalized_innovation_squared)
from interfaces import link_schema as link
from interfaces.scenario import load_scenario
from studies.closed_loop import simulate
from studies.run_scenario import format_summary

FRONT = dict(bearing_direction=np.array([1.0, 0.0, 0.0]), pursuer_position=np.zeros(3),
             pursuer_velocity=np.array([5.0, 0.0, 0.0]), estimate_position=np.array([10.0, 0.0, 0.0]),
             estimate_covariance=np.eye(6) * 0.01)


@given(probability=st.floats(0.5, 0.99999), scale=st.floats(1.0, 5.0))
def test_the_nis_bound_of_two_degrees_of_freedom_is_the_closed_form(probability, scale):
    """chi^2 with 2 dof is exponential with mean 2: its p-quantile is -2 ln(1 - p)."""
    monitor = HealthMonitor(HealthConfig(nis_probability=probability, nis_scale=scale))
    assert monitor.nis_bound(2) == pytest.approx(-2.0 * scale * math.log1p(-probability), rel=1e-9)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_nis_of_a_rank2_covariance_is_the_2d_nis_in_its_plane(seed):
    """A rank-2 S = U C U^T (U an orthonormal 3x2 basis of the measurement plane): y^T S^+ y = a^T C^-1 a for y = U a,
    whatever component along the kernel y also has."""
    rng = np.random.default_rng(seed)
    basis, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    plane, kernel = basis[:, :2], basis[:, 2]
    factor = rng.normal(size=(2, 2))
    c = factor @ factor.T + 0.1 * np.eye(2)
    a = rng.normal(size=2)
    y = plane @ a + rng.normal() * kernel
    expected = float(a @ np.linalg.solve(c, a))
    assert normalized_innovation_squared(y, plane @ c @ plane.T) == pytest.approx(expected, rel=1e-7)


def _kalman_nis_run(true_noise_std: float, assumed_noise_std: float, steps: int, seed: int,
                    config: HealthConfig) -> tuple[HealthMonitor, list[HealthState]]:
    """A 2-axis constant-velocity linear KF (position measured on both axes, dof 2) on simulated data,
    its innovations fed to the monitor at 10 Hz; the rest of the geometry kept healthy."""
    rng = np.random.default_rng(seed)
    dt, q = 0.1, 0.05
    f = np.kron(np.eye(2), np.array([[1.0, dt], [0.0, 1.0]]))
    g = np.kron(np.eye(2), np.array([[0.5 * dt**2], [dt]]))
    h = np.kron(np.eye(2), np.array([[1.0, 0.0]]))
    r = assumed_noise_std**2 * np.eye(2)
    truth = np.array([0.0, 1.0, 0.0, -0.5])
    x, p = truth + rng.normal(size=4), np.eye(4)
    monitor, states = HealthMonitor(config), []
    for k in range(steps):
        truth = f @ truth + g @ (np.sqrt(q) * rng.normal(size=2))
        x, p = f @ x, f @ p @ f.T + q * g @ g.T
        z = h @ truth + true_noise_std * rng.normal(size=2)
        y, s = z - h @ x, h @ p @ h.T + r
        gain = p @ h.T @ np.linalg.inv(s)
        x, p = x + gain @ y, (np.eye(4) - gain @ h) @ p
        states.append(monitor.update(k * dt, innovation=y, innovation_covariance=s, innovation_dof=2, **FRONT).state)
    return monitor, states


def test_a_correctly_tuned_kalman_filter_is_rarely_flagged():
    """With the pure chi-square test (nis_scale 1, 0.999 quantile over 5 s windows) a consistent filter raises the
    NIS condition in about 0.1 % of the windows; after flag_after = 3 s of persistence almost never."""
    config = HealthConfig(nis_scale=1.0, nis_probability=0.999)
    flagged = 0
    for seed in range(5):
        _, states = _kalman_nis_run(0.5, 0.5, 2000, seed, config)
        flagged += sum(state is HealthState.SUSPECT for state in states)
    assert flagged / 10_000 < 0.01


def test_a_mistuned_kalman_filter_is_flagged_for_nis():
    """True measurement noise 3x what the filter assumes (9x the variance): flagged, for the NIS, and for good."""
    monitor, states = _kalman_nis_run(1.5, 0.5, 600, 1, HealthConfig())
    assert states[-1] is HealthState.SUSPECT and monitor.report.reasons == ("nis",)
    first = states.index(HealthState.SUSPECT)
    assert all(state is HealthState.SUSPECT for state in states[first:])


def test_an_estimate_behind_the_sensor_is_flagged_at_once():
    monitor = HealthMonitor()
    report = monitor.update(0.0, **{**FRONT, "estimate_position": np.array([-10.0, 0.0, 0.0])})
    assert report.state is HealthState.SUSPECT and report.reasons == ("behind_sensor",)


def test_a_restart_on_the_bearing_counts_as_behind_the_sensor():
    report = HealthMonitor().update(0.0, reinitialized=True, **FRONT)
    assert "behind_sensor" in report.reasons


@pytest.mark.parametrize("distance, flagged", [(0.5, True), (5.0, False), (3000.0, True)])
def test_range_outside_the_configured_bounds_is_implausible(distance, flagged):
    monitor = HealthMonitor(HealthConfig(min_range=1.0, max_range=2000.0, flag_after=0.0))
    report = monitor.update(0.0, **{**FRONT, "estimate_position": np.array([distance, 0.0, 0.0]),
                                    "estimate_covariance": np.eye(6) * 1e-6})
    assert ("range_implausible" in report.reasons) is flagged


def test_range_std_is_taken_along_the_line_of_sight():
    """sigma_r = sqrt(lambda^T P_pp lambda): a large variance across the line of sight does not count."""
    covariance = np.diag([4.0, 400.0, 400.0, 1.0, 1.0, 1.0])
    report = HealthMonitor().update(0.0, **{**FRONT, "estimate_covariance": covariance})
    assert report.relative_range_std == pytest.approx(2.0 / 10.0)
    assert report.raised == ()


def test_hysteresis_needs_persistence_to_flag_and_quiet_to_clear():
    """A condition must hold flag_after s to count (one that comes and goes faster never flags); once SUSPECT,
    clear_after s without any condition to clear (a chattering condition keeps it SUSPECT, without chatter)."""
    config = HealthConfig(max_relative_range_std=0.5, flag_after=1.0, clear_after=3.0)
    monitor = HealthMonitor(config)
    wide = np.diag([100.0, 0.01, 0.01, 1.0, 1.0, 1.0])  # sigma_r = 10 m at 10 m: relative 1.0
    times = np.arange(200) / 10.0
    states = []
    for tenth, t in enumerate(times):
        chatter = tenth % 10 < 5  # 0.5 s raised, 0.5 s quiet
        uncertain = (t < 5.0 and chatter) or 6.0 <= t < 7.5 or (9.0 <= t < 15.0 and chatter)
        covariance = wide if uncertain else FRONT["estimate_covariance"]
        states.append(monitor.update(t, **{**FRONT, "estimate_covariance": covariance}).state)
    suspect = np.array([s is HealthState.SUSPECT for s in states])
    assert not suspect[times < 6.95].any()
    assert suspect[(times > 6.95) & (times < 17.35)].all()  # raised last at 14.4: clears 3 s later
    assert not suspect[times > 17.45].any()
    assert [state for _, state, _ in monitor.transitions] == [HealthState.SUSPECT, HealthState.OK]


def test_a_held_link_is_suspect_at_once_and_clears_only_clear_after_its_end():
    """link_contested: told by the harness, it needs no correction to flag (none comes while the track is held)
    and no persistence; OK comes back clear_after s after the hold ends, as for any reason."""
    monitor = HealthMonitor(HealthConfig(clear_after=3.0))
    for k in range(10):
        assert monitor.update(k / 10, **FRONT).state is HealthState.OK
    report = monitor.link_contested(1.0, True)
    assert report.state is HealthState.SUSPECT and report.reasons == ("link_contested",)
    assert monitor.transitions[-1][:2] == (1.0, HealthState.SUSPECT)
    monitor.link_contested(4.0, False)
    states = [(t, monitor.update(t, **FRONT).state) for t in np.arange(4.1, 9.0, 0.1)]
    assert all(state is HealthState.SUSPECT for t, state in states if t < 6.95)
    assert all(state is HealthState.OK for t, state in states if t > 7.05)
    assert "link_contested" not in monitor.report.reasons


def test_the_payload_reasons_are_the_monitors():
    assert link.HEALTH_REASONS == REASONS


# --------------------------------------------------------------------------- flights


def _circling(scenario_path, speed: float, lateral_acceleration: float, old_defaults: bool = True):
    """The constant-velocity scenario with its target circling at `speed` m/s (radius v^2 / a), flown with the
    former defaults (the u-PLKF alone, the monitor only reporting), which lose such a target; with
    old_defaults False, today's defaults (the IMM, the monitor acting)."""
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    document = scenario.model_dump()
    if old_defaults:
        document["estimator"]["kind"] = "uplkf"
        document["health"]["act"] = False
    document["target"]["initial_velocity"] = [speed, 0.0, 0.0]
    document["target"]["maneuvers"] = [{"start": 0.0, "end": 60.0, "lateral_acceleration": lateral_acceleration}]
    document["name"] = "circling"
    return type(scenario).model_validate(document), vehicle


def test_a_good_constant_velocity_flight_ends_clean(scenario_path):
    result = simulate(*load_scenario(scenario_path("constant_velocity")), seed=2)
    summary = result.summary
    assert summary["range_estimation_error_rms"] < 0.5
    assert summary["suspected_divergence"]["at_end"] is False
    assert summary["verdict"] == "clean"
    assert "do not trust" not in format_summary(summary)


def test_a_circling_target_the_default_loses_is_flagged_and_not_a_clean_success(scenario_path):
    """25 m circle at 5 m/s: the range estimate is tens of metres off; the monitor, with no truth, says so."""
    result = simulate(*_circling(scenario_path, 5.0, 1.0), seed=2)
    summary = result.summary
    assert summary["range_estimation_error_rms"] > 2.0  # the failure the monitor must see
    assert summary["termination"] == "diverged"  # it flew to the end, but never "completed" with this estimate
    assert result.termination.name == "COMPLETED"  # the loop itself ran to the end
    divergence = summary["suspected_divergence"]
    assert divergence["at_end"] and divergence["in_last_window"] and divergence["seconds"] > 20.0
    assert summary["verdict"] == "suspect"
    assert "estimate suspect" in format_summary(summary) and "do not trust this flight's range" in format_summary(summary)
    assert np.nanmax(result.series["health_suspect"]) == 1.0
    json.dumps(summary)  # plain types for summary.json


def test_a_flight_that_never_sees_its_target_is_no_success(scenario_path):
    """The Table I camera behind a 1 m lens (the schema's longest; 0.008 m in Table I): a field of view of 0.6 deg,
    no bearing in 60 s, no estimate. The monitor had nothing to flag, so the verdict must not be "clean"."""
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    document = scenario.model_dump()
    document["sensor"]["model"] = "camera"
    document["sensor"]["camera"] = {**(document["sensor"].get("camera") or {}), "focal_length": 1.0}
    result = simulate(type(scenario).model_validate(document), vehicle)
    summary = result.summary
    assert summary["bearings_used"] == 0 and summary["bearings_out_of_view"] == 301  # 5 Hz for 60 s
    assert np.isnan(result.series["range_estimate"]).all()
    assert summary["termination"] == "completed" and summary["verdict"] == "no_estimate"
    assert "WARNING: no range estimate over the last 20 s: 0 bearings used, 301 out of view" in format_summary(summary)
    json.dumps(summary)


def test_the_default_follows_the_circle_the_old_default_lost(scenario_path):
    """The same 25 m circle with today's defaults (the IMM's turn models): followed, and not flagged."""
    summary = simulate(*_circling(scenario_path, 5.0, 1.0, old_defaults=False), seed=2).summary
    assert summary["range_estimation_error_rms"] < 1.0, summary
    assert summary["min_range"] > 0.5 * summary["desired_range"]
    assert summary["suspected_divergence"]["at_end"] is False and summary["verdict"] in ("clean", "recovered")


# --------------------------------------------------------------------------- state payload and companion


@pytest.fixture
def app_factory(tmp_path, scenario_path):
    """Companion apps on the constant-velocity scenario, no vehicle and no sockets (close their recorder)."""
    from companion.app import CompanionApp

    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    return lambda: CompanionApp(scenario, vehicle, tmp_path / "run")


def _state(**extra) -> dict:
    return dict(sender="pursuer-1", seq=0, stamp=1.0, phase="following",
                pursuer={"position": [0.0, 0.0, -20.0], "velocity": [1.0, 0.0, 0.0]},
                link={"received": 1, "accepted": 1, "rejected": {}, "bearings_used": 1, "bearings_dropped": {},
                      "last_seq": 0, "last_stamp": 1.0, "last_fix_age_wall": 0.1},
                setpoints_sent=3, **extra)


def test_state_payload_decodes_with_and_without_health():
    assert link.decode_state(link.encode_state(_state())).health is None
    health = {"state": "suspect", "reasons": ["nis", "range_unobservable"], "nis_ratio": math.nan,
              "relative_range_std": 0.05}
    decoded = link.decode_state(link.encode_state(_state(health=health))).health
    assert (decoded.state, decoded.reasons, decoded.nis_ratio, decoded.relative_range_std) == (
        "suspect", ["nis", "range_unobservable"], None, 0.05)


@pytest.mark.parametrize("health, reason", [
    ({"state": "bad", "reasons": [], "nis_ratio": 1.0, "relative_range_std": 0.1}, "wrong_type"),
    ({"state": "ok", "reasons": ["nope"], "nis_ratio": 1.0, "relative_range_std": 0.1}, "wrong_type"),
    ({"state": "ok", "reasons": [], "nis_ratio": 1.0}, "missing_field"),
])
def test_state_payload_refuses_a_malformed_health_section(health, reason):
    payload = json.dumps({"schema": link.COMPANION_STATE_SCHEMA, **_state(health=health)}).encode()
    with pytest.raises(link.PayloadError) as error:
        link.decode_state(payload)
    assert error.value.reason == reason


class _Vehicle:
    def __init__(self) -> None:
        self.texts: list[tuple[str, str]] = []

    async def status_text(self, text: str, severity: str = "WARNING") -> None:
        self.texts.append((severity, text))


def test_the_follower_announces_each_health_change_once(app_factory):
    """STATUSTEXT and a structured filter_health event on each OK <-> SUSPECT change, none while it stays."""
    from companion.adapters.mavsdk_vehicle import VehicleSample
    from companion.core.health import HealthReport
    from companion.core.messages import PursuerState
    from companion.core.pipeline import TrackMode

    app = app_factory()
    vehicle = _Vehicle()
    app.follower.vehicle = vehicle
    sample = VehicleSample(PursuerState(1.0, np.zeros(3), np.zeros(3)), np.eye(3))
    verdicts = [HealthReport(1.0, HealthState.OK), HealthReport(2.0, HealthState.SUSPECT, ("nis",), nis_ratio=3.0),
                HealthReport(3.0, HealthState.SUSPECT, ("nis",), nis_ratio=4.0), HealthReport(9.0, HealthState.OK)]
    for verdict in verdicts:
        output = SimpleNamespace(time=verdict.time, mode=TrackMode.TRACKING, bearing_age=0.0, health=verdict,
                                 estimate=None, observability=None, setpoint=None, new_setpoint=False)
        asyncio.run(app.follower.report(sample, output, [], "following"))
    app.recorder.close()
    assert vehicle.texts == [("WARNING", "range estimate suspect: nis"), ("INFO", "range estimate consistent again")]
    events = [json.loads(line) for line in (app.recorder.folder / "events.jsonl").read_text().splitlines()]
    health_events = [(e["time"], e["state"], e["reasons"]) for e in events if e["kind"] == "filter_health"]
    assert health_events == [(2.0, "suspect", ["nis"]), (9.0, "ok", [])]
    rows = (app.recorder.folder / "series.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert [row.split(",")[header.index("health")] for row in rows[1:]] == ["ok", "suspect", "suspect", "ok"]


def test_state_publisher_puts_the_health_in_the_state(app_factory):
    from companion.adapters.mavsdk_vehicle import VehicleSample
    from companion.core.health import HealthReport
    from companion.core.messages import PursuerState
    from companion.core.pipeline import TrackMode
    from companion.state_publisher import StatePublisher

    app = app_factory()
    verdict = HealthReport(1.0, HealthState.SUSPECT, ("range_unobservable",), nis_ratio=0.5, relative_range_std=0.04)
    control = SimpleNamespace(setpoints_sent=1, last_output=SimpleNamespace(
        mode=TrackMode.TRACKING, bearing_age=0.0, observability=None, estimate=None, health=verdict))
    sent: list[bytes] = []
    publisher = StatePublisher("pursuer-1", 5.0, sent.append, phase=lambda: "following",
                               health=app.target_link.health, control=control)
    publisher.publish(VehicleSample(PursuerState(1.0, np.zeros(3), np.zeros(3)), np.eye(3)))
    app.recorder.close()
    health = link.decode_state(sent[0]).health
    assert (health.state, health.reasons, health.nis_ratio, health.relative_range_std) == (
        "suspect", ["range_unobservable"], 0.5, 0.04)


def test_episode_reasons_gather_every_reason_of_the_current_episode():
    """The end-of-flight warning names what made the episode, even while SUSPECT waits to clear."""
    monitor = HealthMonitor(HealthConfig(flag_after=0.0, clear_after=3.0))
    behind = {**FRONT, "estimate_position": np.array([-10.0, 0.0, 0.0])}
    far = {**FRONT, "estimate_position": np.array([3000.0, 0.0, 0.0]), "estimate_covariance": np.eye(6) * 1e-6}
    monitor.update(0.0, **behind)
    monitor.update(1.0, **far)
    monitor.update(2.0, **FRONT)
    assert monitor.state is HealthState.SUSPECT and monitor.report.reasons == ()
    assert monitor.episode_reasons == ("behind_sensor", "range_implausible")
    monitor.update(5.0, **FRONT)
    assert monitor.state is HealthState.OK and monitor.episode_reasons == ()


@settings(max_examples=60, deadline=None)
@given(bound=st.floats(0.5, 5.0), along=st.lists(st.floats(0.01, 10.0), min_size=1, max_size=60))
@example(bound=2.0, along=[3.0, 1.0, 2.5, 1.5, 4.0])
def test_the_absolute_range_std_counts_only_once_the_range_has_converged(bound, along):
    """range_uncertain from the absolute bound: raised exactly when sigma_r (here the along-line-of-sight std of a
    diagonal covariance, by construction) exceeds max_range_std AND some earlier-or-current correction since the
    last restart had sigma_r <= max_range_std; a restart forgets the convergence. The relative bound is kept out
    of the way (10 m range, max_relative_range_std 100). A sigma within rounding of the bound is left out: the
    monitor compares sqrt(sigma^2) / 10 * 10, which may round either side of it (hypothesis found sigma == bound)."""
    assume(all(abs(sigma - bound) > 1e-9 * bound for sigma in along))
    monitor = HealthMonitor(HealthConfig(max_range_std=bound, max_relative_range_std=100.0, min_nis_samples=10_000))
    converged = False
    for k, sigma in enumerate(along + along):
        if k == len(along):
            monitor.restart()
            converged = False
        covariance = np.diag([sigma**2, 0.01, 0.01, 1.0, 1.0, 1.0])
        report = monitor.update(0.1 * k, **{**FRONT, "estimate_covariance": covariance})
        converged = converged or sigma <= bound
        assert ("range_uncertain" in report.raised) == (converged and sigma > bound)
        assert report.relative_range_std == pytest.approx(sigma / 10.0, rel=1e-9)


@given(probability=st.floats(1e-6, 1.0 - 1e-9), dof=st.integers(1, 60))
def test_the_chi2_quantile_is_scipy_stats_chi2_ppf(probability, dof):
    """The monitor's and the fusion gate's chi^2 quantile is scipy.stats' chi2.ppf (the library it avoids importing
    at start), and the chi^2 CDF brings it back to the probability."""
    quantile = chi2_quantile(probability, dof)
    assert quantile == pytest.approx(float(chi2.ppf(probability, dof)), rel=1e-13, abs=1e-300)
    assert float(chi2.cdf(quantile, dof)) == pytest.approx(probability, rel=1e-9, abs=1e-12)


def test_starting_the_companion_imports_neither_scipy_stats_nor_matplotlib():
    """What the companion app and bof-sim load at start: no scipy.stats, scipy.optimize or matplotlib (each costs
    0.1-0.5 s of start-up and none is needed to fly)."""
    import subprocess
    import sys

    code = ("import sys, companion.app, studies.run_scenario; "
            "print(sorted(m for m in ('scipy.stats', 'scipy.optimize', 'matplotlib') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert loaded.stdout.strip() == "[]"


@settings(max_examples=40, deadline=None)
@given(threshold=st.floats(0.5, 0.99), hold=st.floats(0.2, 2.0), clear=st.floats(0.5, 5.0),
       start=st.floats(1.0, 5.0), length=st.floats(2.5, 6.0))
def test_a_speed_change_counts_after_its_hold_and_clears_its_own_time_after(threshold, hold, clear, start, length):
    """The estimator's speed-change probability at or above the threshold from `start` for `length` s, below it
    otherwise (corrections every 0.1 s): SUSPECT with the reason speed_change once it has held `hold` s since the
    first correction that raised it, OK again `clear` s after the last (not clear_after s); never with the key
    unset, whatever the probability."""
    config = HealthConfig(speed_change_probability=threshold, speed_change_time=hold, speed_change_clear=clear,
                          clear_after=30.0)
    monitor, unset = HealthMonitor(config), HealthMonitor(HealthConfig())
    times = np.arange(0, 160) / 10.0
    raised = (times >= start - 1e-9) & (times < start + length - 1e-9)
    states = []
    for t, on in zip(times, raised):
        probability = threshold if on else 0.5 * threshold
        report = monitor.update(t, **FRONT, speed_change_probability=probability)
        states.append((report.state, report.reasons))
        assert unset.update(t, **FRONT, speed_change_probability=1.0).state is HealthState.OK
    first, last = times[raised][0], times[raised][-1]  # the first and last corrections that raised it
    for t, (state, reasons) in zip(times, states):
        if first + hold + 0.1 - 1e-9 <= t <= last:  # counted by the correction after the hold at the latest
            assert state is HealthState.SUSPECT and "speed_change" in reasons
        elif t < first + hold - 0.1 or t >= last + clear + 0.1 - 1e-9:
            assert state is HealthState.OK


def test_the_speed_change_reason_needs_a_probability_in_0_1():
    for bad in (0.0, 1.5, -0.1):
        with pytest.raises(ValueError, match="speed_change_probability"):
            HealthConfig(speed_change_probability=bad)
