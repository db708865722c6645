"""The health monitor that acts (companion.core.health.HealthActionPolicy, driven by the pipeline).

References: the policy's contract written as properties over synthetic verdicts (actions while
SUSPECT and only then; restarts spaced by the interval; the relaxation of the Q boost as the
exponential it is, exp(-a) exp(-b) = exp(-(a + b))); the constant-velocity time update of
section IV-C in closed form for the boosted Q; the in-process simulator with a circling target
the constant-velocity filter loses, and with act off against the reporting-only pipeline.
"""

from __future__ import annotations

import asyncio
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.estimators import UPLKF, InitialGuess
from companion.core.health import (REASONS, RANGE_WRONG_REASONS, HealthAction, HealthActionConfig,
                                   HealthActionPolicy, HealthMonitor, HealthReport, HealthState)
from companion.core.messages import BearingMeasurement
from interfaces import link_schema as link
from interfaces.scenario import ConfigError, Scenario, load_scenario
from studies.closed_loop import simulate

VERDICTS = st.lists(
    st.tuples(st.floats(0.01, 3.0), st.booleans(), st.sets(st.sampled_from(REASONS)), st.sets(st.sampled_from(REASONS))),
    min_size=1, max_size=80)


def _reports(steps) -> list[HealthReport]:
    """Synthetic verdicts: (time step s, suspect, reasons, raised) -> HealthReports in time order."""
    time, reports = 0.0, []
    for dt, suspect, reasons, raised in steps:
        time += dt
        state = HealthState.SUSPECT if suspect else HealthState.OK
        ordered = tuple(r for r in REASONS if r in reasons) if suspect else ()
        reports.append(HealthReport(time, state, ordered, tuple(r for r in REASONS if r in raised)))
    return reports


@settings(max_examples=200, deadline=None)
@given(steps=VERDICTS, boost=st.floats(1.0, 100.0), relax=st.floats(0.5, 30.0), interval=st.floats(0.0, 30.0),
       follows=st.booleans())
def test_actions_happen_when_and_only_when_the_monitor_says_suspect(steps, boost, relax, interval, follows):
    config = HealthActionConfig(act=True, process_noise_boost=boost, boost_relax_time=relax,
                                reinitialize_reasons=RANGE_WRONG_REASONS + ("nis",), reinitialize_interval=interval,
                                boost_follows_evidence=follows)
    policy = HealthActionPolicy(config)
    full_at: float | None = None  # time of the last verdict that set the full boost
    last_restart = None
    for report in _reports(steps):
        decision = policy.decide(report)
        suspect = report.state is HealthState.SUSPECT
        assert (decision.action is HealthAction.RECOVERING) == suspect
        assert decision.excite == suspect
        evidence = bool(set(report.raised) & {"nis", "behind_sensor", "range_implausible"})  # a model that no longer fits
        if suspect and (evidence or not follows):
            assert decision.process_noise_boost == boost
            full_at = report.time
        elif full_at is None:
            assert decision.process_noise_boost == 1.0  # never boosted yet: nothing to relax from
        else:
            # exp(-dt1/tau) exp(-dt2/tau) ... = exp(-(t - t_full)/tau), snapped to 1 within 1e-3
            expected = 1.0 + (boost - 1.0) * math.exp(-(report.time - full_at) / relax)
            assert decision.process_noise_boost == pytest.approx(1.0 if expected - 1.0 < 1e-3 else expected,
                                                                 rel=1e-9, abs=2e-3)
            assert 1.0 <= decision.process_noise_boost <= boost
        wants = suspect and any(r in config.reinitialize_reasons for r in report.reasons)
        if decision.reinitialize:
            assert wants and (last_restart is None or report.time - last_restart >= interval)
            last_restart = report.time
        elif wants:
            assert last_restart is not None and report.time - last_restart < interval  # only the rate limit says no
    assert policy.reinitialize_times == sorted(policy.reinitialize_times)


@given(steps=VERDICTS)
def test_with_act_off_nothing_is_ever_decided(steps):
    policy = HealthActionPolicy(HealthActionConfig(act=False))
    for report in _reports(steps):
        decision = policy.decide(report)
        assert (decision.action, decision.process_noise_boost, decision.reinitialize, decision.excite) == (
            HealthAction.OFF, 1.0, False, False)
    assert policy.reinitialize_times == [] and policy.episodes == 0


@pytest.mark.parametrize("interval, expected", [(20.0, [0.0, 20.0, 40.0, 60.0]), (25.0, [0.0, 25.0, 50.0]),
                                                (0.0, None)])
def test_restarts_are_rate_limited(interval, expected):
    """A verdict 'behind the sensor' at every 5 Hz bearing for 60 s restarts once per interval, not at every bearing."""
    policy = HealthActionPolicy(HealthActionConfig(act=True, reinitialize_interval=interval))
    times = [round(0.2 * k, 6) for k in range(301)]
    for time in times:
        policy.decide(HealthReport(time, HealthState.SUSPECT, ("behind_sensor",)))
    assert policy.reinitialize_times == (times if expected is None else expected)


def test_no_second_restart_when_the_estimator_restarted_itself():
    policy = HealthActionPolicy(HealthActionConfig(act=True))
    decision = policy.decide(HealthReport(1.0, HealthState.SUSPECT, ("behind_sensor",)), estimator_restarted=True)
    assert decision.action is HealthAction.RECOVERING and not decision.reinitialize


def test_episodes_and_recoveries_are_counted():
    policy = HealthActionPolicy(HealthActionConfig(act=True))
    for time, state in enumerate("OSSOOSOS"):
        policy.decide(HealthReport(float(time), HealthState.SUSPECT if state == "S" else HealthState.OK, ("nis",)))
    assert (policy.episodes, policy.recoveries) == (3, 2)


@pytest.mark.parametrize("bad", [dict(process_noise_boost=0.5), dict(reinitialize_reasons=("nope",)),
                                 dict(excitation_low=0.5, excitation_high=0.5), dict(boost_relax_time=0.0)])
def test_the_action_config_refuses_nonsense(bad):
    with pytest.raises(ValueError):
        HealthActionConfig(**bad)


# --------------------------------------------------------------------------- estimator: the Q boost


@given(boost=st.floats(1.0, 1000.0), period=st.floats(0.005, 0.5), q=st.floats(1e-4, 10.0))
def test_the_boost_multiplies_the_discrete_process_noise_of_section_iv_c(boost, period, q):
    """P^- = A P A^T + b B Q B^T with the constant-velocity A = [[I, T I], [0, I]], B = [[T^2/2 I], [T I]]."""
    filt = UPLKF(period, q * np.eye(3), 1e-4 * np.eye(3))
    filt.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3)),
                               InitialGuess(20.0, 5.0, np.zeros(3), 1.0))
    before = filt.estimate.covariance.copy()
    filt.process_noise_boost = boost
    filt.predict()
    a = np.block([[np.eye(3), period * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    b = np.vstack([0.5 * period**2 * np.eye(3), period * np.eye(3)])
    expected = a @ before @ a.T + boost * q * (b @ b.T)
    np.testing.assert_allclose(filt.estimate.covariance, expected, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------- pipeline and flights


class _ScriptedMonitor(HealthMonitor):
    """A monitor whose verdict is scripted by time (s) instead of computed: SUSPECT inside `windows`."""

    def __init__(self, windows, reasons=("behind_sensor",)) -> None:
        super().__init__()
        self.windows, self.reasons = windows, reasons

    def update(self, time, *args, **kwargs) -> HealthReport:
        suspect = any(start <= time < end for start, end in self.windows)
        self.report = HealthReport(time, HealthState.SUSPECT if suspect else HealthState.OK,
                                   self.reasons if suspect else (), self.reasons if suspect else ())
        return self.report


def _scenario(scenario_path, name="constant_velocity", **health) -> tuple[Scenario, object]:
    scenario, vehicle = load_scenario(scenario_path(name))
    document = scenario.model_dump()
    document["health"].update(health)
    return type(scenario).model_validate(document), vehicle


def test_the_pipeline_acts_on_the_estimator_only_while_suspect(scenario_path):
    """Scripted verdicts through the real pipeline: the estimator's boost is the configured factor exactly while
    SUSPECT, relaxes after, and the restarts happen inside the window at the rate limit."""
    from companion.assembly import build_pipeline
    from companion.core.messages import PursuerState

    scenario, vehicle = _scenario(scenario_path, act=True, process_noise_boost=7.0, reinitialize_interval=4.0)
    pipeline = build_pipeline(scenario, vehicle, 0.5)
    pipeline.health = _ScriptedMonitor([(3.0, 11.0)])
    pursuer = PursuerState(0.0, np.zeros(3), np.array([2.0, 0.0, 0.0]))
    boosts, restarts = [], []
    for k in range(100):  # 20 s of 5 Hz bearings towards a target 20 m ahead
        time = 0.2 * k
        pursuer = PursuerState(time, np.array([2.0 * time, 0.0, 0.0]), np.array([2.0, 0.0, 0.0]))
        target = np.array([20.0 + 3.0 * time, 5.0, 0.0])
        bearing = BearingMeasurement(time, (target - pursuer.position) / np.linalg.norm(target - pursuer.position),
                                     pursuer.position)
        output = pipeline.step(time, pursuer, bearing)
        boosts.append((time, pipeline.estimator.process_noise_boost, output.health_action))
        if output.health_reinitialized:
            restarts.append(round(time, 6))
    for time, boost, action in boosts[1:]:
        if 3.0 <= time < 11.0:
            assert boost == 7.0 and action is HealthAction.RECOVERING
        else:
            assert action is HealthAction.NOMINAL
            assert boost == (1.0 if time < 3.0 else pytest.approx(1.0 + 6.0 * math.exp(-(time - 10.8) / 5.0), abs=2e-3))
    assert restarts == [3.0, 7.0] and pipeline.health_reinitializations == 2


def _circling(scenario_path, **health):
    """The constant-velocity scenario with its target on a 25 m circle at 5 m/s, flown with the u-PLKF alone (the
    former default, which loses it: a flight for the monitor to act on); `health` overrides [health]."""
    scenario, vehicle = _scenario(scenario_path, **health)
    document = scenario.model_dump()
    document["estimator"]["kind"] = "uplkf"
    document["target"]["initial_velocity"] = [5.0, 0.0, 0.0]
    document["target"]["maneuvers"] = [{"start": 0.0, "end": 60.0, "lateral_acceleration": 1.0}]
    document["name"] = "circling"
    return type(scenario).model_validate(document), vehicle


def test_a_flight_built_to_fail_is_flagged_and_the_actions_are_logged(scenario_path):
    result = simulate(*_circling(scenario_path, act=True), seed=2)
    summary, series = result.summary, result.series
    assert summary["suspected_divergence"]["episodes"] >= 1
    assert summary["monitor_verdict"] in ("suspect", "recovered")  # flagged: never a clean success
    assert summary["verdict"] != "clean"
    actions = summary["health_actions"]
    assert actions["act"] is True and actions["episodes"] >= 1
    assert ("recovering" in [action for _, action in actions["changes"]])
    suspect = series["health_suspect"] == 1.0
    boost = series["process_noise_boost"]
    assert np.nanmax(boost) == 30.0 and np.all(suspect[boost == 30.0])  # the default factor, set only while suspect
    first = np.argmax(suspect)
    assert np.all(boost[:first][np.isfinite(boost[:first])] == 1.0)  # nothing before the first flag
    assert np.all(series["health_action"][suspect] == 2.0)
    json.dumps(summary)


def test_act_off_is_the_reporting_only_pipeline_bit_for_bit(scenario_path):
    """act = false, whatever the other action settings: the same series as the reporting-only pipeline (act = false alone), sample for
    sample, on a flight the monitor flags (so there would be something to act on)."""
    reference = simulate(*_circling(scenario_path, act=False), seed=3)
    other = simulate(*_circling(scenario_path, act=False, process_noise_boost=50.0, reinitialize_interval=0.0,
                                reinitialize_reasons=list(REASONS), excitation_low=0.0, excitation_high=0.01), seed=3)
    assert np.nanmax(reference.series["health_suspect"]) == 1.0
    for key, values in reference.series.items():
        np.testing.assert_array_equal(other.series[key], values, err_msg=key)
    assert np.all(reference.series["process_noise_boost"][np.isfinite(reference.series["process_noise_boost"])] == 1.0)
    assert reference.summary["health_actions"]["changes"] == [] and reference.summary["health_actions"]["act"] is False


def test_the_health_section_is_strict(scenario_path):
    for bad in (dict(act="yes"), dict(reinitialize_reasons=["bogus"]), dict(excitation_low=0.6),
                dict(process_noise_boost=0.5), dict(unknown_key=1)):
        with pytest.raises((ValueError, ConfigError)):
            _scenario(scenario_path, **bad)


# --------------------------------------------------------------------------- companion: STATUSTEXT and Zenoh


class _Vehicle:
    def __init__(self) -> None:
        self.texts: list[tuple[str, str]] = []

    async def status_text(self, text: str, severity: str = "WARNING") -> None:
        self.texts.append((severity, text))


def test_the_follower_announces_each_action_change_and_restart(app):
    from companion.adapters.mavsdk_vehicle import VehicleSample
    from companion.core.messages import PursuerState
    from companion.core.pipeline import TrackMode

    vehicle = _Vehicle()
    app.follower.vehicle = vehicle
    sample = VehicleSample(PursuerState(1.0, np.zeros(3), np.zeros(3)), np.eye(3))
    steps = [(1.0, HealthState.OK, HealthAction.NOMINAL, 1.0, False),
             (2.0, HealthState.SUSPECT, HealthAction.RECOVERING, 10.0, True),
             (3.0, HealthState.SUSPECT, HealthAction.RECOVERING, 10.0, False),
             (9.0, HealthState.OK, HealthAction.NOMINAL, 8.0, False)]
    for time, state, action, boost, restarted in steps:
        verdict = HealthReport(time, state, ("behind_sensor",) if state is HealthState.SUSPECT else ())
        output = SimpleNamespace(time=time, mode=TrackMode.TRACKING, bearing_age=0.0, health=verdict, estimate=None,
                                 observability=None, setpoint=None, new_setpoint=False, health_action=action,
                                 process_noise_boost=boost, health_reinitialized=restarted)
        asyncio.run(app.follower.report(sample, output, [], "following"))
    app.recorder.close()
    assert vehicle.texts == [("WARNING", "range estimate suspect: behind_sensor"),
                             ("WARNING", "recovering: Q inflated, range excitation on"),
                             ("WARNING", "range estimate restarted on bearing"),
                             ("INFO", "range estimate consistent again"),
                             ("INFO", "estimate trusted: recovery actions off")]
    assert all(len(text) <= 50 for _, text in vehicle.texts)  # one STATUSTEXT each
    events = [json.loads(line) for line in (app.recorder.folder / "events.jsonl").read_text().splitlines()]
    assert [(e["time"], e["kind"]) for e in events if e["kind"] in ("health_action", "health_restart")] == [
        (2.0, "health_action"), (2.0, "health_restart"), (9.0, "health_action")]
    rows = (app.recorder.folder / "series.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert [row.split(",")[header.index("health_action")] for row in rows[1:]] == [
        "nominal", "recovering", "recovering", "nominal"]


def test_the_zenoh_state_carries_the_action(app):
    from companion.adapters.mavsdk_vehicle import VehicleSample
    from companion.core.messages import PursuerState
    from companion.core.pipeline import TrackMode
    from companion.state_publisher import StatePublisher

    verdict = HealthReport(1.0, HealthState.SUSPECT, ("nis",), nis_ratio=2.5, relative_range_std=0.3)
    control = SimpleNamespace(setpoints_sent=1, last_output=SimpleNamespace(
        mode=TrackMode.TRACKING, bearing_age=0.0, observability=None, estimate=None, health=verdict,
        health_action=HealthAction.RECOVERING, process_noise_boost=10.0))
    sent: list[bytes] = []
    StatePublisher("pursuer-1", 5.0, sent.append, phase=lambda: "following", health=app.target_link.health,
                   control=control).publish(VehicleSample(PursuerState(1.0, np.zeros(3), np.zeros(3)), np.eye(3)))
    health = link.decode_state(sent[0]).health
    assert (health.state, health.action, health.process_noise_boost) == ("suspect", "recovering", 10.0)


def test_a_state_from_a_reporting_only_sender_still_decodes():
    state = dict(sender="p", seq=0, stamp=1.0, phase="following",
                 pursuer={"position": [0.0, 0.0, -20.0], "velocity": [1.0, 0.0, 0.0]},
                 link={"received": 1, "accepted": 1, "rejected": {}, "bearings_used": 1, "bearings_dropped": {},
                       "last_seq": 0, "last_stamp": 1.0, "last_fix_age_wall": 0.1}, setpoints_sent=3,
                 health={"state": "ok", "reasons": [], "nis_ratio": 0.5, "relative_range_std": 0.05})
    health = link.decode_state(link.encode_state(state)).health
    assert health.action is None and health.process_noise_boost is None
    with pytest.raises(link.PayloadError):
        link.decode_state(link.encode_state({**state, "health": {**state["health"], "action": "panicking"}}))
