"""The baselines reach both harnesses through the config: the registries of companion.assembly
cover exactly the schema's choices, each built estimator runs at the configured rate and finds a
target whose position is known in closed form, each built guidance law gives the command its
defining equation gives, plus the range sensor, the simulation-only noise-free projection, and
clear errors for wrong combinations."""

from __future__ import annotations

import math
import typing

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from companion import app, assembly
from companion.assembly import build_estimator, build_lateral_guidance, build_pipeline, build_sensor
from companion.core.estimators import InitialGuess
from companion.core.messages import BearingMeasurement, PursuerState
from interfaces.scenario import (ConfigError, EstimatorConfig, GuidanceConfig, SensorConfig, DEFAULT_SCENARIO,
                                 load_scenario)
from studies.closed_loop import simulate
from studies.montecarlo import with_overrides


@pytest.fixture(scope="module")
def loaded():
    return load_scenario(DEFAULT_SCENARIO)


# --------------------------------------------------------------------------- registries

@pytest.mark.parametrize("registry, schema, field", [
    (assembly.ESTIMATORS, EstimatorConfig, "kind"),
    (assembly.LATERAL_GUIDANCE, GuidanceConfig, "law"),
    (assembly.SENSORS, SensorConfig, "model"),
])
def test_each_registry_covers_exactly_the_schema_literal(registry, schema, field):
    """A value the schema accepts but the registry lacks would fail at run time; a key the schema
    refuses is dead code. The Literal is read from the pydantic model itself."""
    annotation = schema.model_fields[field].annotation
    assert typing.get_origin(annotation) is typing.Literal
    assert sorted(registry) == sorted(typing.get_args(annotation))


# --------------------------------------------------------------------------- estimators

P_T0 = np.array([50.0, -25.0, -20.0])  # m, target at t = 0
V_T = np.array([3.0, 4.0, 0.0])  # m/s, constant
BEARING_PERIOD = 0.2  # s, 5 Hz fixes


def _target(t: float) -> np.ndarray:
    return P_T0 + V_T * t


def _observer(t: float) -> np.ndarray:
    """A pursuer that flies along with the target and weaves (radius 6 m, 0.5 rad/s): range observable."""
    return np.array([3.0 * t + 6.0 * math.cos(0.5 * t), 4.0 * t + 6.0 * math.sin(0.5 * t), -18.0 + 2.0 * math.sin(0.3 * t)])


def _bearing(t: float, rng: np.random.Generator, noise: float, with_range: bool) -> BearingMeasurement:
    relative = _target(t) - _observer(t)
    distance = float(np.linalg.norm(relative))
    true_direction = relative / distance
    return BearingMeasurement(t, true_direction + rng.normal(0.0, noise, 3), _observer(t),
                              range=distance + rng.normal(0.0, 1.0) if with_range else None,
                              true_direction=true_direction)


def _fly(estimator, duration: float, noise: float, with_range: bool, seed: int = 3) -> list[float]:
    """Start on the first bearing with a 30 % range error, predict every period, correct at 5 Hz;
    returns |p^_T - p_T(t)| after each bearing (m)."""
    rng = np.random.default_rng(seed)
    first = _bearing(0.0, rng, noise, with_range)
    true_range = float(np.linalg.norm(_target(0.0) - _observer(0.0)))
    estimator.initialize_on_bearing(first, InitialGuess(1.3 * true_range, 30.0, np.zeros(3), 5.0))
    errors = []
    every = round(BEARING_PERIOD / estimator.period)
    for tick in range(1, round(duration / estimator.period) + 1):
        estimator.predict()
        if tick % every == 0:
            estimator.correct(_bearing(estimator.time, rng, noise, with_range))
            errors.append(float(np.linalg.norm(estimator.estimate.position - _target(estimator.time))))
    return errors


@pytest.mark.parametrize("overrides", [
    {},
    {"estimator.kind": "ekf"},
    {"estimator.kind": "msc_ekf"},
    {"estimator.kind": "ekf_rae", "sensor.range_noise_std": 1.0},
], ids=["uplkf", "ekf", "msc_ekf", "ekf_rae"])
def test_built_estimator_runs_at_the_configured_rate_and_finds_the_target(loaded, overrides):
    """period = 1 / rate_hz (25 Hz here, not the default); after 40 s of eq. (4) bearings (sigma 0.01)
    from a weaving observer the estimate is the closed-form target position p_T(0) + v_T t."""
    estimator = build_estimator(with_overrides(loaded[0], {**overrides, "estimator.rate_hz": 25.0}))
    assert estimator.period == pytest.approx(1.0 / 25.0, rel=1e-12)
    errors = _fly(estimator, 40.0, noise=0.01, with_range="sensor.range_noise_std" in overrides)
    if "sensor.range_noise_std" in overrides:
        assert errors[0] < 5.0  # the range EKF uses the measured range at once
    else:
        assert errors[0] > 5.0  # bearing-only: the range guess is 30 % off
    assert np.mean(errors[-50:]) < 2.0  # the last 10 s


def test_noise_free_projection_uses_only_the_true_line_of_sight(loaded):
    """The optimal u-PLKF of section VIII-B takes gain and residual from the true direction: with
    bearings five times noisier than configured it still lands on the target; without the true
    direction (the networked companion) it refuses."""
    estimator = build_estimator(with_overrides(loaded[0], {"estimator.gain_projection": "noise_free"}))
    errors = _fly(estimator, 40.0, noise=0.05, with_range=False)
    assert np.mean(errors[-50:]) < 0.5
    with pytest.raises(ValueError, match="true_direction"):
        estimator.correct(BearingMeasurement(estimator.time, np.array([1.0, 0.0, 0.0]), np.zeros(3)))


# --------------------------------------------------------------------------- guidance laws

UNIT = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(np.array).filter(lambda v: 0.3 < np.linalg.norm(v))
VECTOR = st.lists(st.floats(-8.0, 8.0), min_size=3, max_size=3).map(np.array)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _los_derivative(relative_position: np.ndarray, relative_velocity: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """d/dt (dp / |dp|) along dp' = dv by central differences (independent of the laws' projections)."""
    return (_unit(relative_position + step * relative_velocity) - _unit(relative_position - step * relative_velocity)) / (2 * step)


def _plane_rates(relative_position: np.ndarray, relative_velocity: np.ndarray, step: float = 1e-6):
    """(beta', eps', e_beta, e_eps) by central differences of beta = atan2(d_y, d_x), eps = atan2(-d_z, rho)."""
    def angles(dp):
        return math.atan2(dp[1], dp[0]), math.atan2(-dp[2], math.hypot(dp[0], dp[1]))
    (b1, e1), (b0, e0) = angles(relative_position + step * relative_velocity), angles(relative_position - step * relative_velocity)
    beta, eps = angles(relative_position)
    e_beta = np.array([-math.sin(beta), math.cos(beta), 0.0])
    e_eps = np.array([-math.sin(eps) * math.cos(beta), -math.sin(eps) * math.sin(beta), -math.cos(eps)])
    beta_step = (b1 - b0 + math.pi) % (2 * math.pi) - math.pi  # across the +-pi cut
    return beta_step / (2 * step), (e1 - e0) / (2 * step), e_beta, e_eps


def _law(loaded, law: str, **overrides):
    return build_lateral_guidance(with_overrides(loaded[0], {"guidance.law": law, **overrides}))


@settings(max_examples=60, deadline=None)
@given(velocity=VECTOR, los=UNIT, distance=st.floats(2.0, 80.0), time=st.floats(0.0, 30.0))
def test_hng_is_perpendicular_to_the_line_of_sight_and_is_ppg_far_away(loaded, velocity, los, distance, time):
    """Eq. (14): a_HN = N (v x lambda_v) x lambda is perpendicular to lambda; the weave angle
    c / r^ vanishes as r^ grows, leaving PPG, -N P_lambda v, with the configured N = 3."""
    hng = _law(loaded, "hng")
    los = _unit(los)
    command = hng.acceleration(time, velocity, los, distance)
    assert abs(command @ los) < 1e-9 * max(1.0, np.linalg.norm(command))
    far = hng.acceleration(time, velocity, los, 1e9)
    np.testing.assert_allclose(far, -3.0 * (velocity - (velocity @ los) * los), atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(velocity=VECTOR, los=UNIT, distance=st.floats(2.0, 80.0))
def test_ppg_is_minus_n_times_the_velocity_across_the_line_of_sight(loaded, velocity, los, distance):
    """Section VIII-C1: a = N (v x lambda) x lambda = -N (I - lambda lambda^T) v, N = navigation_gain = 2.5."""
    los = _unit(los)
    command = _law(loaded, "ppg", **{"guidance.navigation_gain": 2.5}).acceleration(0.0, velocity, los, distance)
    np.testing.assert_allclose(command, -2.5 * (velocity - (velocity @ los) * los), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(velocity=VECTOR, los=UNIT, distance=st.floats(2.0, 80.0), relative_velocity=VECTOR)
def test_png_turns_the_velocity_with_the_line_of_sight_rate(loaded, velocity, los, distance, relative_velocity):
    """Section VIII-C1: a = N Omega x v with Omega = lambda x lambda', lambda' here by finite
    differences of the line of sight along dp' = dv; N = navigation_gain = 3."""
    los = _unit(los)
    command = _law(loaded, "png").acceleration(0.0, velocity, los, distance, relative_velocity)
    omega = np.cross(los, _los_derivative(distance * los, relative_velocity))
    np.testing.assert_allclose(command, 3.0 * np.cross(omega, velocity), atol=1e-6 * (1.0 + np.linalg.norm(command)))


@settings(max_examples=60, deadline=None)
@given(los=UNIT, distance=st.floats(2.0, 80.0), relative_velocity=VECTOR)
def test_pd_is_the_configured_spring_and_damper(loaded, los, distance, relative_velocity):
    """Section VIII-C1: a = k_P (p_d - p) + k_D (v^_T - v), p_d - p = (r^ - r_d) lambda; k_P from the
    override (0.7), k_D and r_d from the scenario (0.2, 8 m)."""
    los = _unit(los)
    command = _law(loaded, "pd", **{"guidance.pd_kp": 0.7}).acceleration(0.0, np.zeros(3), los, distance, relative_velocity)
    np.testing.assert_allclose(command, 0.7 * (distance - 8.0) * los + 0.2 * relative_velocity, atol=1e-9)


def _away_from_the_vertical(los: np.ndarray) -> bool:
    return math.hypot(los[0], los[1]) > 0.2


@settings(max_examples=60, deadline=None)
@given(velocity=VECTOR, los=UNIT.filter(lambda v: _away_from_the_vertical(_unit(v))), distance=st.floats(2.0, 80.0),
       relative_velocity=VECTOR)
def test_retro_png_pushes_with_the_per_plane_line_of_sight_rates(loaded, velocity, los, distance, relative_velocity):
    """Section VIII-C2 after refs. [14], [16]: a = -g |v| (beta' e_beta + eps' e_eps) per plane,
    the angle rates by finite differences; g = retro_gain = 2."""
    los = _unit(los)
    command = _law(loaded, "retro_png").acceleration(0.0, velocity, los, distance, relative_velocity)
    beta_dot, eps_dot, e_beta, e_eps = _plane_rates(distance * los, relative_velocity)
    expected = -2.0 * np.linalg.norm(velocity) * (beta_dot * e_beta + eps_dot * e_eps)
    np.testing.assert_allclose(command, expected, atol=1e-5 * (1.0 + np.linalg.norm(expected)))


@settings(max_examples=60, deadline=None)
@given(los=UNIT.filter(lambda v: _away_from_the_vertical(_unit(v))), distance=st.floats(9.0, 60.0),
       closing=st.floats(0.5, 6.0), across=VECTOR)
def test_zem_gain_is_the_cotangent_of_the_time_to_go(loaded, los, distance, closing, across):
    """Ref. [43] as in section VIII-C2: a = N v_c (beta' e_beta + eps' e_eps) with
    N = x cot(x/3), x = k_w t_go^3, t_go = (r^ - r_d) / v_c, clipped to +-zem_max_gain; k_w = 0.01
    from the override, r_d = 8 m and max gain 10 from the scenario."""
    los = _unit(los)
    relative_velocity = -closing * los + (across - (across @ los) * los)  # closing at v_c
    command = _law(loaded, "zem", **{"guidance.zem_k_w": 0.01}).acceleration(0.0, np.zeros(3), los, distance,
                                                                             relative_velocity)
    x = 0.01 * ((distance - 8.0) / closing) ** 3
    gain = 3.0 if x < 1e-9 else x / math.tan(x / 3.0)
    gain = min(10.0, max(-10.0, gain))
    beta_dot, eps_dot, e_beta, e_eps = _plane_rates(distance * los, relative_velocity)
    expected = gain * closing * (beta_dot * e_beta + eps_dot * e_eps)
    np.testing.assert_allclose(command, expected, atol=1e-5 * (1.0 + np.linalg.norm(expected)))


# --------------------------------------------------------------------------- the rest of the wiring

def test_wrong_combinations_are_clear_config_errors(loaded):
    scenario = loaded[0]
    with pytest.raises(ConfigError, match="range_noise_std"):
        with_overrides(scenario, {"estimator.kind": "ekf_rae"})
    with pytest.raises(ConfigError, match="u-PLKF only"):
        with_overrides(scenario, {"estimator.kind": "ekf", "estimator.gain_projection": "measured"})
    with pytest.raises(ConfigError, match="initial_position"):
        with_overrides(scenario, {"estimator.initialize": "position", "estimator.initial_position": None})


def test_pd_controller_replaces_the_range_controller(loaded):
    """Section VIII-C1: the PD command is the whole acceleration, a = k_P (p_d - p) + k_D (v^_T - v)."""
    scenario, vehicle = loaded
    pipeline = build_pipeline(with_overrides(scenario, {"guidance.law": "pd"}), vehicle, 0.5)
    pursuer = PursuerState(0.0, np.zeros(3), np.array([2.0, 0.0, 0.0]))
    direction = np.array([0.8, -0.4, -0.3]) / np.linalg.norm([0.8, -0.4, -0.3])
    output = pipeline.step(0.0, pursuer, BearingMeasurement(0.0, direction, np.zeros(3)))
    terms = output.guidance
    np.testing.assert_array_equal(terms.longitudinal, np.zeros(3))
    estimate = output.estimate
    relative_velocity = estimate.velocity - pursuer.velocity
    expected = 0.5 * (terms.range_estimate - 8.0) * terms.los + 0.2 * relative_velocity
    np.testing.assert_allclose(terms.lateral, expected, atol=1e-12)


def test_range_sensor_adds_range_without_changing_the_bearing_noise():
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    plain = build_sensor(SensorConfig())
    ranged = build_sensor(SensorConfig(range_noise_std=1.0))
    los = np.array([0.6, 0.8, 0.0])
    np.testing.assert_array_equal(plain.measure(los, rng_a), ranged.measure(los, rng_b))
    assert plain.measure_range(20.0, np.random.default_rng(1)) is None
    samples = [ranged.measure_range(20.0, np.random.default_rng(seed)) for seed in range(400)]
    assert abs(np.mean(samples) - 20.0) < 0.2 and 0.85 < np.std(samples) < 1.15


def test_in_process_flight_with_range_sensor_and_optimal_filter(loaded):
    """The simulator fills range and the true direction; both baselines then fly and converge."""
    scenario, vehicle = loaded
    short = {"simulation.duration": 30.0, "simulation.summary_window": 10.0}
    rae = simulate(with_overrides(scenario, {**short, "estimator.kind": "ekf_rae", "sensor.range_noise_std": 1.0}), vehicle, 2)
    optimal = simulate(with_overrides(scenario, {**short, "estimator.gain_projection": "noise_free"}), vehicle, 2)
    for result in (rae, optimal):
        assert result.termination.name == "COMPLETED"
        assert result.summary["range_estimation_error_rms"] < 1.0


def test_companion_refuses_the_simulation_only_filter(tmp_path, capsys):
    text = DEFAULT_SCENARIO.read_text().replace('gain_projection = "predicted"', 'gain_projection = "noise_free"')
    config = tmp_path / "optimal.toml"
    config.write_text(text.replace('vehicle = "../vehicles/', f'vehicle = "{DEFAULT_SCENARIO.parent.parent}/vehicles/'))
    assert app.main(["--config", str(config), "--log-dir", str(tmp_path / "log")]) == 2
    assert "simulation-only" in capsys.readouterr().err
