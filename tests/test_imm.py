"""The interacting-multiple-model estimator (companion.core.imm) and its coordinated-turn models.

References: the closed-form circular motion of a coordinated turn and a numerical ODE solution
(scipy) for the transition; the existing u-PLKF for the one-model reduction; hand-computed
mixing (exact fractions) for seed 004 eqs. (17)-(19); scipy's singular multivariate normal for
the rank-2 likelihood of eq. (20); the target's true turn for the model probabilities.
"""

from __future__ import annotations

import json
import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.stats import multivariate_normal

from companion.assembly import build_estimator
from companion.core.estimators import (GainProjection, InitialGuess, UPLKF, coordinated_turn_matrices,
                                       transition_matrices)
from companion.core.imm import (IMMEstimator, MotionModel, combine, markov_matrix, mix, rank2_log_likelihood,
                                rank2_log_likelihoods, standard_models)
from companion.core.messages import BearingMeasurement
from interfaces.overrides import ConfigError
from interfaces.scenario import load_scenario
from studies.montecarlo import SCENARIOS, with_overrides

PERIOD = 0.02
SIGMA = 1e-4 * np.eye(3)


# --- the coordinated-turn transition --------------------------------------------------------

def _circle(start: np.ndarray, speed: float, heading: float, climb: float, omega: float, t: float) -> np.ndarray:
    """[p, v] after t s on a circle: horizontal speed `speed` m/s, heading psi = atan2(v_E, v_N)
    growing at omega rad/s, constant vertical (down) speed `climb` m/s. Closed form."""
    psi = heading + omega * t
    north = start[0] + speed / omega * (math.sin(psi) - math.sin(heading))
    east = start[1] - speed / omega * (math.cos(psi) - math.cos(heading))
    return np.array([north, east, start[2] + climb * t, speed * math.cos(psi), speed * math.sin(psi), climb])


@settings(max_examples=200, deadline=None)
@given(omega=st.one_of(st.floats(0.001, 3.0), st.floats(-3.0, -0.001)), speed=st.floats(0.0, 20.0),
       heading=st.floats(-math.pi, math.pi), climb=st.floats(-5.0, 5.0), period=st.floats(0.001, 2.0),
       start=st.tuples(*[st.floats(-100.0, 100.0)] * 3))
def test_turn_transition_follows_the_circle(omega, speed, heading, climb, period, start):
    """A of the turn model carries a state on a circle to the same circle one period later, at any rate."""
    start = np.array(start)
    a, _ = coordinated_turn_matrices(period, omega)
    state = _circle(start, speed, heading, climb, omega, 0.0)
    np.testing.assert_allclose(a @ state, _circle(start, speed, heading, climb, omega, period), rtol=1e-9, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(omega=st.floats(-2.0, 2.0), period=st.floats(0.005, 1.0),
       acceleration=st.tuples(*[st.floats(-3.0, 3.0)] * 3), velocity=st.tuples(*[st.floats(-10.0, 10.0)] * 3))
def test_turn_input_matrix_integrates_the_held_acceleration(omega, period, acceleration, velocity):
    """B: the exact response to an acceleration held over the period (eq. (1)'s noise model), against
    a numerical solution of d/dt p = v, d/dt v_h = omega J v_h + a_h, d/dt v_D = a_D."""
    a_hold = np.array(acceleration)

    def dynamics(_t, x):
        v = x[3:]
        return np.concatenate([v, [-omega * v[1] + a_hold[0], omega * v[0] + a_hold[1], a_hold[2]]])

    x0 = np.concatenate([np.zeros(3), velocity])
    solution = solve_ivp(dynamics, (0.0, period), x0, rtol=1e-11, atol=1e-12).y[:, -1]
    a, b = coordinated_turn_matrices(period, omega)
    np.testing.assert_allclose(a @ x0 + b @ a_hold, solution, rtol=1e-7, atol=1e-8)


@settings(max_examples=100, deadline=None)
@given(period=st.floats(0.001, 1.0), omega=st.floats(-1e-3, 1e-3))
def test_turn_model_tends_to_the_double_integrator(period, omega):
    """omega -> 0 gives eq. (1) (and exactly eq. (1) at omega = 0), on both sides of the series switch."""
    a0, b0 = transition_matrices(period)
    a, b = coordinated_turn_matrices(period, omega)
    theta = abs(omega * period)
    np.testing.assert_allclose(a, a0, atol=2.0 * theta + 1e-15)
    np.testing.assert_allclose(b, b0, atol=period * theta + 1e-15)
    exact_a, exact_b = coordinated_turn_matrices(period, 0.0)
    np.testing.assert_array_equal(exact_a, a0)
    np.testing.assert_array_equal(exact_b, b0)


def test_series_and_closed_form_agree_at_the_switch():
    """Just below and above |omega dt| = 1e-4 the two branches give the same matrices (to rounding)."""
    period = 0.1
    below = coordinated_turn_matrices(period, 1e-3 * (1.0 - 1e-9))
    above = coordinated_turn_matrices(period, 1e-3 * (1.0 + 1e-9))
    for lo, hi in zip(below, above):
        np.testing.assert_allclose(lo, hi, rtol=1e-8, atol=1e-13)


def test_default_uplkf_prediction_is_eq1_and_boost_scales_q():
    """Without a model the u-PLKF predicts with eq. (1)'s A and B Q B^T; process_noise_boost multiplies Q_d."""
    q = 0.04 * np.eye(3)
    a, b = transition_matrices(PERIOD)
    covariance = np.diag([4.0, 3.0, 2.0, 1.0, 0.5, 0.25])
    for boost in (1.0, 3.0):
        f = UPLKF(PERIOD, q, SIGMA)
        f.initialize(0.0, np.ones(3), np.array([1.0, -2.0, 0.5]), covariance)
        f.process_noise_boost = boost
        f.predict()
        np.testing.assert_allclose(f.estimate.covariance, a @ covariance @ a.T + boost * b @ q @ b.T, rtol=1e-13)
        np.testing.assert_allclose(f.estimate.position, np.ones(3) + PERIOD * np.array([1.0, -2.0, 0.5]), rtol=1e-13)


# --- mixing, likelihood, combination ------------------------------------------------------------

def test_mixing_matches_a_hand_computed_two_model_case():
    """Seed 004 eqs. (17)-(19) with mu = (0.6, 0.4), p = [[0.9, 0.1], [0.2, 0.8]], scalar states 1 and 3,
    variances 2 and 5, in exact fractions."""
    mu = [Fraction(6, 10), Fraction(4, 10)]
    p = [[Fraction(9, 10), Fraction(1, 10)], [Fraction(2, 10), Fraction(8, 10)]]
    x, var = [Fraction(1), Fraction(3)], [Fraction(2), Fraction(5)]
    c = [Fraction(62, 100), Fraction(38, 100)]  # 0.6*0.9 + 0.4*0.2, 0.6*0.1 + 0.4*0.8
    w = [[Fraction(54, 62), Fraction(6, 38)], [Fraction(8, 62), Fraction(32, 38)]]  # mu^{i|j}, column j
    x0 = [Fraction(39, 31), Fraction(51, 19)]  # (0.54 + 0.24) / 0.62, (0.06 + 0.96) / 0.38
    p0 = [sum(w[i][j] * (var[i] + (x[i] - x0[j]) ** 2) for i in range(2)) for j in range(2)]
    assert [sum(w[i][j] for i in range(2)) for j in range(2)] == [1, 1]
    predicted, mixed, mixed_var = mix(np.array([float(m) for m in mu]), np.array([[float(v) for v in row] for row in p]),
                                      np.array([[float(v)] for v in x]), np.array([[[float(v)]] for v in var]))
    np.testing.assert_allclose(predicted, [float(v) for v in c], rtol=1e-14)
    np.testing.assert_allclose(mixed[:, 0], [float(v) for v in x0], rtol=1e-14)
    np.testing.assert_allclose(mixed_var[:, 0, 0], [float(v) for v in p0], rtol=1e-14)
    assert float(p0[0]) == pytest.approx(2.8366285, rel=1e-7)  # (54/62)(2 + 64/961) + (8/62)(5 + 2916/961)


def test_combination_is_the_mixture_moments():
    """Seed 004 eqs. (22)-(23): mean and covariance of a two-Gaussian mixture, against a large sample of it."""
    rng = np.random.default_rng(3)
    weights = np.array([0.3, 0.7])
    means = np.array([[1.0, -2.0], [4.0, 0.5]])
    covariances = np.array([[[1.0, 0.3], [0.3, 2.0]], [[0.5, -0.1], [-0.1, 0.8]]])
    picks = rng.choice(2, size=400_000, p=weights)
    samples = np.array([rng.multivariate_normal(means[k], covariances[k], size=(picks == k).sum()) for k in range(2)],
                       dtype=object)
    pooled = np.vstack(list(samples))
    mean, covariance = combine(weights, means, covariances)
    np.testing.assert_allclose(mean, pooled.mean(axis=0), atol=0.01)
    np.testing.assert_allclose(covariance, np.cov(pooled.T), atol=0.02)


@settings(max_examples=50, deadline=None)
@given(eigen=st.tuples(st.floats(1e-4, 1e3), st.floats(1e-4, 1e3)), angles=st.tuples(*[st.floats(0.0, 2 * math.pi)] * 3),
       coefficients=st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)))
def test_rank2_likelihood_is_the_gaussian_on_the_plane(eigen, angles, coefficients):
    """Eq. (20) for a rank-2 S: scipy's singular multivariate normal (pseudo-determinant density)."""
    a, b, c = angles
    rotation = (np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
                @ np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
                @ np.array([[math.cos(c), 0, math.sin(c)], [0, 1, 0], [-math.sin(c), 0, math.cos(c)]]))
    s = rotation @ np.diag([eigen[0], eigen[1], 0.0]) @ rotation.T
    s = 0.5 * (s + s.T)
    y = rotation[:, 0] * coefficients[0] * math.sqrt(eigen[0]) + rotation[:, 1] * coefficients[1] * math.sqrt(eigen[1])
    reference = multivariate_normal(np.zeros(3), s, allow_singular=True).logpdf(y)
    assert rank2_log_likelihood(y, s) == pytest.approx(reference, rel=1e-6, abs=1e-6)
    # in bearing units at a range r: the density of y / r under S / r^2
    r = 1.0 + eigen[0]
    in_angle = multivariate_normal(np.zeros(3), s / r**2, allow_singular=True).logpdf(y / r)
    assert rank2_log_likelihood(y, s, r) == pytest.approx(in_angle, rel=1e-6, abs=1e-6)
    # the closed form with the known kernel g (Cayley-Hamilton), as the IMM evaluates it
    assert rank2_log_likelihood(y, s, r, rotation[:, 2]) == pytest.approx(in_angle, rel=1e-6, abs=1e-6)
    batch = rank2_log_likelihoods(np.array([y, y]), np.array([s, s]), np.array([r, 1.0]), np.array([rotation[:, 2]] * 2))
    assert batch[0] == pytest.approx(in_angle, rel=1e-6, abs=1e-6)
    assert batch[1] == pytest.approx(reference, rel=1e-6, abs=1e-6)


def test_markov_matrix_is_seed_004s():
    np.testing.assert_allclose(markov_matrix(3, 0.98), [[0.98, 0.01, 0.01], [0.01, 0.98, 0.01], [0.01, 0.01, 0.98]])
    imm = IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA, stay_probability=0.98, stay_time=0.2)
    np.testing.assert_allclose(imm.markov_matrix(0.2), markov_matrix(3, 0.98))
    np.testing.assert_allclose(imm.markov_matrix(0.4)[0, 0], 0.98**2)  # two intervals without switching


# --- the estimator against the u-PLKF and the truth ----------------------------------------------

def _bearings(seed: int, steps: int, every: int, target_turn: float = 0.0, noise: float = 0.01):
    """(tick, bearing) pairs: a target starting 40 m ahead at 5 m/s north, turning at target_turn rad/s
    (0: straight), seen from a pursuer weaving (10 m at 0.4 rad/s across, 4 m at 0.25 rad/s vertically)
    about a point that keeps pace with a straight target and stays put for a turning one (which circles
    near it); bearing noise std `noise` per axis every `every` estimator ticks."""
    rng = np.random.default_rng(seed)
    out = []
    for tick in range(0, steps, every):
        t = tick * PERIOD
        pace = 5.0 * t if target_turn == 0.0 else 0.0
        pursuer = np.array([pace, 10.0 * math.sin(0.4 * t), 4.0 * math.sin(0.25 * t)])
        if target_turn == 0.0:
            target = np.array([40.0 + 5.0 * t, 0.0, -5.0])
        else:
            target = _circle(np.array([40.0, 0.0, -5.0]), 5.0, 0.0, 0.0, target_turn, t)[:3]
        direction = (target - pursuer) / np.linalg.norm(target - pursuer) + rng.normal(0.0, noise, 3)
        out.append((tick, BearingMeasurement(t, direction, pursuer)))
    return out


def _run(estimator, bearings, guess: InitialGuess, collect=None):
    ticks = 0
    estimator.initialize_on_bearing(bearings[0][1], guess)
    for tick, bearing in bearings[1:]:
        while ticks < tick:
            estimator.predict()
            ticks += 1
        estimator.correct(bearing)
        if collect is not None:
            collect(estimator)
    return estimator.estimate


GUESS = InitialGuess(30.0, 30.0, np.zeros(3), 5.0)


@pytest.mark.parametrize("every", [1, 10])
def test_one_model_imm_is_the_uplkf(every):
    """An IMM with only the constant-velocity model is the u-PLKF, bit for bit, on the same bearings."""
    bearings = _bearings(5, 2000, every)
    reference = _run(UPLKF(PERIOD, 0.04 * np.eye(3), SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.1), bearings, GUESS)
    imm = IMMEstimator(PERIOD, [MotionModel("cv", 0.0, 0.04)], SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.1)
    estimate = _run(imm, bearings, GUESS)
    np.testing.assert_array_equal(estimate.position, reference.position)
    np.testing.assert_array_equal(estimate.covariance, reference.covariance)
    np.testing.assert_array_equal(imm.model_probabilities, [1.0])


def test_imm_that_never_switches_from_certain_cv_is_the_uplkf():
    """p_ii = 1 with all the probability on the constant-velocity model: the turn models never take part."""
    bearings = _bearings(6, 1500, 5, target_turn=0.2)
    reference = _run(UPLKF(PERIOD, 0.04 * np.eye(3), SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.1), bearings, GUESS)
    imm = IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.1,
                       stay_probability=1.0, initial_probabilities=[1.0, 0.0, 0.0])
    estimate = _run(imm, bearings, GUESS)
    np.testing.assert_allclose(estimate.position, reference.position, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(estimate.covariance, reference.covariance, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(imm.model_probabilities, [1.0, 0.0, 0.0])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), turn=st.one_of(st.just(0.0), st.floats(0.01, 0.4), st.floats(-0.4, -0.01)),
       noise=st.sampled_from([0.0, 0.01, 0.05]),
       every=st.sampled_from([1, 10]), stay=st.floats(0.5, 1.0))
def test_model_probabilities_stay_a_distribution(seed, turn, noise, every, stay):
    bearings = _bearings(seed, 600, every, target_turn=turn, noise=noise)
    imm = IMMEstimator(PERIOD, standard_models([0.1, 0.3], 0.04, 0.1), SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.1,
                       stay_probability=stay)

    def check(estimator):
        mu = estimator.model_probabilities
        assert np.all(np.isfinite(mu)) and np.all(mu >= 0.0) and np.all(mu <= 1.0)
        assert float(mu.sum()) == pytest.approx(1.0, abs=1e-12)

    _run(imm, bearings, GUESS, check)


@pytest.mark.parametrize("turn,winner", [(0.2, "ct+0.2"), (-0.2, "ct-0.2"), (0.0, "cv")])
def test_the_matching_turn_model_wins_on_a_circling_target(turn, winner):
    """Noise-free bearings of a target circling at 0.2 rad/s (or flying straight) seen from a weaving
    pursuer: after 20 s the model of the true motion carries most of the probability."""
    bearings = _bearings(1, 1500, 5, target_turn=turn, noise=0.0)
    imm = IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.0)
    history = []
    _run(imm, bearings, InitialGuess(40.0, 10.0, np.array([5.0, 0.0, 0.0]), 2.0),
         lambda e: history.append(e.model_probabilities) if e.time >= 20.0 else None)
    mean = np.mean(history, axis=0)
    assert imm.model_names[int(np.argmax(mean))] == winner
    assert mean[imm.model_names.index(winner)] > 0.6


def test_boost_reaches_every_model_filter():
    imm = IMMEstimator(PERIOD, standard_models([0.1, 0.3], 0.04, 0.04), SIGMA)
    imm.process_noise_boost = 4.0
    assert imm.process_noise_boost == 4.0
    assert [f.process_noise_boost for f in imm.filters] == [4.0] * 5


def test_restart_behind_the_sensor_is_taken_at_the_imm_level():
    """A combined prediction behind the sensor: every model restarts on the bearing, probabilities reset."""
    imm = IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA)
    imm.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3)), GUESS)
    imm.predict()
    report = imm.correct(BearingMeasurement(PERIOD, np.array([-1.0, 0.0, 0.0]), np.zeros(3)))
    assert report.reinitialized
    np.testing.assert_allclose(imm.model_probabilities, imm.initial_probabilities)
    assert all(f.estimate.position[0] < 0.0 for f in imm.filters)  # on the new bearing, ahead of the sensor


def test_combined_report_is_rank_two_and_feeds_the_monitor():
    bearings = _bearings(2, 400, 5, target_turn=0.2)
    imm = IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA, GainProjection.PREDICTED, pursuer_position_std=0.1)
    reports = []
    imm.initialize_on_bearing(bearings[0][1], GUESS)
    ticks = 0
    for tick, bearing in bearings[1:]:
        while ticks < tick:
            imm.predict()
            ticks += 1
        reports.append(imm.correct(bearing))
    for report in reports:
        assert report.innovation_dof == 2
        values = np.linalg.eigvalsh(report.innovation_covariance)
        assert values[0] <= 1e-9 * values[2] and values[1] > 0.0


# --- configuration ------------------------------------------------------------------------------

def _scenario(**estimator):
    scenario, _ = load_scenario(SCENARIOS / "constant_velocity.toml")
    return with_overrides(scenario, {f"estimator.{k}": v for k, v in estimator.items()})


def test_config_builds_the_imm():
    estimator = build_estimator(_scenario(kind="imm", imm_turn_rates=[0.1, 0.3]))
    assert isinstance(estimator, IMMEstimator)
    assert estimator.model_names == ("cv", "ct+0.1", "ct-0.1", "ct+0.3", "ct-0.3", "speed")
    without = build_estimator(_scenario(kind="imm", imm_turn_rates=[0.1, 0.3], imm_manoeuvre_model=False))
    assert without.model_names == ("cv", "ct+0.1", "ct-0.1", "ct+0.3", "ct-0.3")


@pytest.mark.parametrize("options", [
    {"kind": "imm", "imm_turn_rates": [0.0]},
    {"kind": "imm", "imm_turn_rates": [-0.2]},
    {"kind": "imm", "imm_turn_rates": [5.0]},
    {"kind": "imm", "imm_turn_rates": [0.2, 0.2]},
    {"kind": "imm", "imm_stay_probability": 0.0},
    {"kind": "imm", "imm_stay_probability": 1.5},
    {"kind": "imm", "imm_stay_time": 0.0},
    {"kind": "imm", "imm_turn_process_noise": -1.0},
    {"kind": "uplkf", "imm_turn_rates": [0.3]},
    {"kind": "imm", "adaptive_process_noise": True},
])
def test_config_refuses_bad_imm_options(options):
    with pytest.raises(ConfigError):
        _scenario(**options)


# --- model probabilities in the logs and on the link -------------------------------------------

def _state_document(**changes) -> dict:
    state = {"phase": "following", "sender": "pursuer-1", "seq": 5, "stamp": 2.5,
             "pursuer": {"position": [1.0, 2.0, -20.0], "velocity": [0.5, 0.0, 0.0]},
             "link": {"received": 1, "accepted": 1, "rejected": {}, "bearings_used": 1, "bearings_dropped": {},
                      "last_seq": 0, "last_stamp": 2.2, "last_fix_age_wall": None},
             "setpoints_sent": 3}
    state.update(changes)
    return state


def test_companion_state_carries_optional_model_probabilities():
    from interfaces import link_schema as link

    imm = IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA)
    probabilities = {name: p for name, p in zip(imm.model_names, np.float64(imm.model_probabilities))}
    decoded = link.decode_state(link.encode_state(_state_document(model_probabilities=probabilities)))
    assert decoded.model_probabilities == {"cv": 0.98, "ct+0.2": 0.01, "ct-0.2": 0.01}
    assert link.decode_state(link.encode_state(_state_document())).model_probabilities is None  # older payloads
    with pytest.raises(link.PayloadError) as error:
        link.decode_state(json.dumps({"schema": "bof.companion_state/1", **_state_document(model_probabilities={"cv": 1.5})}).encode())
    assert error.value.reason == "out_of_range"


def test_state_publisher_sends_the_imm_probabilities_and_nothing_for_the_uplkf():
    from types import SimpleNamespace

    from companion.adapters.mavsdk_vehicle import VehicleSample
    from companion.core.messages import PursuerState
    from companion.core.pipeline import TrackMode
    from companion.state_publisher import StatePublisher

    bearing = BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3))
    output = SimpleNamespace(mode=TrackMode.TRACKING, bearing_age=0.0, observability=None, health=None, estimate=None)
    link_health = SimpleNamespace(as_dict=lambda _now: {})
    sample = VehicleSample(PursuerState(1.0, np.zeros(3), np.zeros(3)), np.eye(3))
    for estimator, expected in ((IMMEstimator(PERIOD, standard_models([0.3], 0.04, 0.04), SIGMA), {"cv", "ct+0.3", "ct-0.3"}),
                                (UPLKF(PERIOD, 0.04 * np.eye(3), SIGMA), None)):
        estimator.initialize_on_bearing(bearing, GUESS)
        output.estimate = estimator.estimate
        control = SimpleNamespace(last_output=output, setpoints_sent=0, pipeline=SimpleNamespace(estimator=estimator))
        state = StatePublisher("p", 5.0, lambda _b: None, lambda: "following", link_health, control).build(sample)
        assert (None if "model_probabilities" not in state else set(state["model_probabilities"])) == expected


def test_in_process_log_and_recorder_columns_hold_the_probabilities(tmp_path):
    from companion.adapters.recorder import RunRecorder, model_columns
    from studies.closed_loop import simulate

    scenario, vehicle = load_scenario(SCENARIOS / "circle_5ms.toml")
    flown = with_overrides(scenario, {"estimator.kind": "imm", "simulation.duration": 4.0, "simulation.summary_window": 4.0})
    series = simulate(flown, vehicle, seed=7).series
    engaged = np.isfinite(series["estimate_position"][:, 0])
    probabilities = series["model_probabilities"][engaged]
    assert np.all(np.isfinite(probabilities)) and np.allclose(probabilities.sum(axis=1), 1.0)
    plain = simulate(with_overrides(flown, {"estimator.kind": "uplkf"}), vehicle, seed=7).series
    assert np.all(np.isnan(plain["model_probabilities"]))

    imm = IMMEstimator(PERIOD, standard_models([0.1, 0.3], 0.04, 0.04), SIGMA)
    columns = model_columns(imm)
    assert columns == pytest.approx({"model_straight": 0.98, "model_right": 0.01, "model_left": 0.01})
    assert model_columns(UPLKF(PERIOD, 0.04 * np.eye(3), SIGMA)) == {}
    recorder = RunRecorder(tmp_path)
    recorder.series({"time": 1.0, **columns})
    recorder.close()
    header, row = (tmp_path / "series.csv").read_text().splitlines()
    values = dict(zip(header.split(","), row.split(",")))
    assert float(values["model_straight"]) == pytest.approx(0.98) and float(values["model_left"]) == pytest.approx(0.01)


@settings(max_examples=200, deadline=None)
@given(rates=st.lists(st.floats(0.01, 1.0), min_size=1, max_size=2),
       weights=st.lists(st.floats(0.0, 1.0), min_size=5, max_size=5),
       velocities=st.lists(st.tuples(*[st.floats(-15.0, 15.0)] * 3), min_size=5, max_size=5))
def test_acceleration_is_the_probability_weighted_turn_acceleration(rates, weights, velocities):
    """IMMEstimator.acceleration (the cooperative laws' feed-forward) against the kinematics of a coordinated turn
    about the NED down axis written independently: each turning model's target accelerates by omega_j e_D x v_j
    (np.cross), weighted by its probability mu_j; the constant-velocity model adds nothing, and there is no
    vertical part. Compiled and plain kernel bit for bit."""
    from bitwise import assert_same
    from companion.core import _jit, imm as imm_module

    imm = IMMEstimator(PERIOD, standard_models(rates, 0.04, 0.04), SIGMA)
    imm.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3)),
                              InitialGuess(20.0, 5.0, np.zeros(3), 2.0))
    count = len(imm.models)
    probabilities = np.array(weights[:count]) + 1e-3
    probabilities /= probabilities.sum()
    imm._set_probabilities(probabilities)
    for model_filter, velocity in zip(imm.filters, velocities):
        state = model_filter.state_and_covariance[0].copy()
        state[3:] = velocity
        model_filter.set_state(state, model_filter.state_and_covariance[1])
    expected = np.zeros(3)
    for mu, model, velocity in zip(probabilities, imm.models, velocities):
        expected += mu * model.turn_rate * np.cross([0.0, 0.0, 1.0], velocity)
    acceleration = imm.acceleration
    assert acceleration.shape == (3,) and acceleration[2] == 0.0
    np.testing.assert_allclose(acceleration, expected, rtol=1e-12, atol=1e-12)
    plain = np.zeros(3)
    _jit.python_function(imm_module._turn_acceleration_into)(imm._probabilities, imm._turn_rates, imm._states, plain)
    assert_same(acceleration, plain)


def test_acceleration_before_the_first_bearing():
    """A constant-velocity-only IMM has no turn to feed forward (zero, as before a bearing); with turning models the
    model filters' own RuntimeError says the estimator has not started."""
    assert np.array_equal(IMMEstimator(PERIOD, [MotionModel("cv", 0.0, 0.04)] * 2, SIGMA).acceleration, np.zeros(3))
    with pytest.raises(RuntimeError, match="not initialised"):
        IMMEstimator(PERIOD, standard_models([0.2], 0.04, 0.04), SIGMA).acceleration
