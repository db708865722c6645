"""Seed 003 (Ahmed and Subbarao, Aerospace 2016) complete: its backstepping law with the sign
erratum fixed, the acceleration it asks of the first-order autopilot, its coloured and
range-dependent measurement noise, and a flight of the scenario that puts them together.

References are independent of the code under test: the chaser's first-order autopilot, eq. (4),
integrated here in its own variables (v_g, gamma, chi); numerical differentiation of the velocity
vector; the Gauss-Markov process's closed-form statistics; eq. (15)-(16) evaluated by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from companion.core.baseline_guidance import Seed003BacksteppingGuidance
from companion.core.bearing_sensor import BearingSensor, RangeDependentVariance
from interfaces.scenario import SCENARIOS_DIR, SensorConfig, load_scenario
from studies.closed_loop import simulate

AUTOPILOT = (100.0, 100.0, 100.0)  # seed 003's c_1 = c_2 = c_3


def _velocity_ned(speed: float, gamma: float, chi: float) -> np.ndarray:
    """Eq. (4)'s kinematics in NED (z down): v_g [cos g cos chi, cos g sin chi, -sin g]."""
    return speed * np.array([math.cos(gamma) * math.cos(chi), math.cos(gamma) * math.sin(chi), -math.sin(gamma)])


def _fly_point_mass(printed_sign: bool, duration: float = 20.0, step: float = 1e-3) -> list[float]:
    """The seed's chaser (eq. (4), c_i = 100) driven by eq. (5)-(7) against a constant-velocity target
    with full target state; returns |range - r_d| every 0.1 s (inf once not finite)."""
    law = Seed003BacksteppingGuidance(alpha=1.0, gain=5.0, desired_range=8.0, max_approach_speed=1e3, autopilot_gains=AUTOPILOT)
    c1, c2, c3 = AUTOPILOT
    position, speed, gamma, chi = np.array([0.0, 0.0, 0.0]), 8.0, 0.17, 0.17
    target, target_velocity = np.array([50.0, 50.0, -50.0]), np.array([6.0, 8.0, 0.0])
    errors = []
    for k in range(int(round(duration / step))):
        velocity = _velocity_ned(speed, gamma, chi)
        relative = target - position
        distance = float(np.linalg.norm(relative))
        if k % 100 == 0:
            errors.append(abs(distance - 8.0) if math.isfinite(distance) else math.inf)
        with np.errstate(all="ignore"):
            command = law.commands(velocity, relative / distance, distance, target_velocity - velocity, printed_sign)
        if not all(math.isfinite(value) for value in command) or abs(speed) > 1e4:
            errors.append(math.inf)
            break
        speed += step * c1 * (command.speed - speed)
        gamma += step * c2 * (command.flight_path_angle - gamma)
        chi += step * c3 * (command.course - chi)
        position = position + step * velocity
        target = target + step * target_velocity
    return errors


def test_corrected_law_holds_the_desired_range_through_the_first_order_autopilot():
    errors = _fly_point_mass(printed_sign=False)
    assert errors[0] > 50.0
    assert max(errors[-20:]) < 0.05  # the last 2 s: 8 m behind the target to 5 cm


def test_printed_sign_of_eq_5_6_diverges():
    """Documents the erratum: as printed, v~_i' = +lambda v~_i, so the loop leaves at once."""
    errors = _fly_point_mass(printed_sign=True, duration=2.0)
    assert errors[-1] == math.inf or errors[-1] > 10.0 * errors[0]


angles = st.floats(-1.3, 1.3)
unit_vectors = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.2)


@settings(max_examples=200, deadline=None)
@given(speed=st.floats(0.5, 15.0), gamma=angles, chi=st.floats(-3.1, 3.1), los=unit_vectors,
       distance=st.floats(2.0, 60.0), target_velocity=st.tuples(*(st.floats(-8.0, 8.0),) * 3))
def test_acceleration_is_the_rate_of_the_autopilots_velocity(speed, gamma, chi, los, distance, target_velocity):
    """a_d = d/dt v_g e_v(gamma, chi) with v_g', gamma', chi' from eq. (4) fed by the commands (5)-(7),
    here by central differences of the velocity vector."""
    law = Seed003BacksteppingGuidance(autopilot_gains=AUTOPILOT)
    velocity = _velocity_ned(speed, gamma, chi)
    lam = np.asarray(los) / np.linalg.norm(los)
    dv = np.asarray(target_velocity) - velocity
    command = law.commands(velocity, lam, distance, dv)
    c1, c2, c3 = AUTOPILOT
    rates = (c1 * (command.speed - speed), c2 * (command.flight_path_angle - gamma), c3 * (command.course - chi))
    h = 1e-6
    numeric = (_velocity_ned(speed + h * rates[0], gamma + h * rates[1], chi + h * rates[2])
               - _velocity_ned(speed - h * rates[0], gamma - h * rates[1], chi - h * rates[2])) / (2 * h)
    acceleration = law.acceleration(0.0, velocity, lam, distance, dv)
    assert np.allclose(acceleration, numeric, rtol=1e-5, atol=1e-5 * (1.0 + np.linalg.norm(numeric)))


@given(climb=st.floats(0.0, 15.0), lag=st.floats(-3.0, 3.0))
def test_vertical_target_is_guarded(climb, lag):
    """Target straight above, both climbing: v_1^d = 0 and the pursuer's course undefined."""
    law = Seed003BacksteppingGuidance()
    velocity = np.array([0.0, 0.0, -climb])
    acceleration = law.acceleration(0.0, velocity, np.array([0.0, 0.0, -1.0]), 8.0 + lag, np.array([0.0, 0.0, -1.0]))
    assert np.all(np.isfinite(acceleration))
    assert np.allclose(acceleration[:2], 0.0)


@pytest.mark.parametrize(("acceleration", "expected"), [(1.0, 1.0), (10.0, 3.0)])
def test_target_acceleration_filter_recovers_a_constant_acceleration(acceleration, expected):
    """The derivative filter of section 2.2 on v_T(t) = (a t, 0, 0) sampled at 20 Hz: a first-order
    filter of an exact difference quotient reaches a (bounded at 3 m/s^2) within a few time constants."""
    law = Seed003BacksteppingGuidance(target_acceleration_time_constant=1.0, max_target_acceleration=3.0)
    for k in range(400):
        estimate = law.target_acceleration(0.05 * k, np.array([acceleration * 0.05 * k, 0.0, 0.0]))
    assert np.allclose(estimate, [expected, 0.0, 0.0], atol=1e-6)


def _noise(sensor: BearingSensor, count: int, seed: int, true_range: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    bearing_rng, range_rng = np.random.default_rng(seed), np.random.default_rng(seed + 1)
    lam = np.array([0.6, 0.8, 0.0])
    bearings = np.array([sensor.measure(lam, bearing_rng, true_range=true_range) - lam for _ in range(count)])
    ranges = np.array([sensor.measure_range(true_range, range_rng) - true_range for _ in range(count)])
    return bearings, ranges


def test_default_sensor_is_white_eq_4():
    """Without the seed's options a bearing is lambda + N(0, sigma^2 I) drawn straight from the generator."""
    lam = np.array([0.0, 0.6, 0.8])
    sensor = BearingSensor(noise_std=0.02, range_noise_std=1.5)
    assert np.array_equal(sensor.measure(lam, np.random.default_rng(3)), lam + 0.02 * np.random.default_rng(3).normal(size=3))
    assert sensor.measure_range(20.0, np.random.default_rng(4)) == 20.0 + 1.5 * np.random.default_rng(4).normal()


def _autocorrelation(series: np.ndarray, lag: int) -> float:
    return float(np.mean(series[:-lag] * series[lag:]) / np.mean(series * series))


@pytest.mark.parametrize("time_constant", [0.2, 1.0])
def test_gauss_markov_noise_has_its_stationary_std_and_exponential_autocorrelation(time_constant):
    period, count = 0.05, 200_000
    sensor = BearingSensor(noise_std=0.01, range_noise_std=2.0, noise_time_constant=time_constant, sample_period=period)
    bearings, ranges = _noise(sensor, count, seed=11)
    for series, std in ((bearings[:, 0], 0.01), (bearings[:, 2], 0.01), (ranges, 2.0)):
        assert np.std(series) == pytest.approx(std, rel=0.04)
        for lag in (1, 4):
            assert _autocorrelation(series, lag) == pytest.approx(math.exp(-lag * period / time_constant), abs=0.03)


@pytest.mark.parametrize(("distance", "range_variance"), [(3.0, 1.0096), (11.0, 1.24), (51.0, 7.0), (101.0, 25.0)])
def test_range_dependent_variance_is_eq_15_16(distance, range_variance):
    """Seed 003 case 3: a0 = 1, a1 = 1, a2 = 0.0024, alpha = 1e-5; 0.0024 (r - 1)^2 + 1 by hand."""
    model = RangeDependentVariance(a0=1.0, a1=1.0, a2=0.0024, alpha=1e-5)
    assert model.range_variance(distance) == pytest.approx(range_variance)
    assert model.angle_variance(distance) == pytest.approx(1e-5 * range_variance)
    sensor = BearingSensor(noise_std=0.01, range_noise_std=1.0, range_dependent=model)
    bearings, ranges = _noise(sensor, 20_000, seed=5, true_range=distance)
    assert np.std(ranges) == pytest.approx(math.sqrt(range_variance), rel=0.04)
    assert np.std(bearings) == pytest.approx(math.sqrt(1e-5 * range_variance), rel=0.04)


def test_schema_refuses_coloured_noise_on_other_models():
    with pytest.raises(ValidationError, match="noise_time_constant"):
        SensorConfig(model="rotation", noise_time_constant=0.5)
    with pytest.raises(ValidationError, match="camera"):
        SensorConfig(model="camera", range_dependent_noise={})


def test_seed003_scenario_flies_with_a_finite_estimate():
    """seed003_ekf_rae, seed 1: the law follows the helix on the EKF's estimate (figures in docs/guide/studies.md)."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "seed003_ekf_rae.toml")
    assert scenario.guidance.law == "seed003" and scenario.estimator.kind == "ekf_rae"
    summary = simulate(scenario, vehicle, seed=1).summary
    assert summary["termination"] in ("completed", "diverged")  # flew to the end (the health verdict aside)
    assert math.isfinite(summary["range_estimation_error_rms"]) and summary["range_estimation_error_rms"] < 3.0
    assert summary["min_range"] > scenario.guidance.desired_range / 2.0


@pytest.mark.parametrize("noise", [{"noise_time_constant": 0.5}, {"range_dependent_noise": {}}])
def test_seed003_noise_options_fly_through_the_simulator(noise):
    """The coloured and the range-dependent sensor reach the estimator in a flight (figures in docs/guide/studies.md)."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "seed003_ekf_rae.toml")
    sensor = SensorConfig(**{**scenario.sensor.model_dump(), **noise})
    summary = simulate(scenario.model_copy(update={"sensor": sensor}), vehicle, seed=1).summary
    assert summary["termination"] in ("completed", "diverged")  # flew to the end (the health verdict aside)
    assert math.isfinite(summary["range_estimation_error_rms"]) and summary["range_estimation_error_rms"] < 3.0
