"""Own-state (position/velocity feedback) error model: white by default, first-order
Gauss-Markov when the vehicle file gives a time constant."""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from interfaces.scenario import ConfigError, load_vehicle
from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle, gauss_markov_step
from sitl_plant.vehicle.params import quadrotor_params, table1_params

PARAMS = table1_params()
times = st.floats(min_value=1e-3, max_value=100.0)


@given(elapsed=times, tau=times)
def test_gauss_markov_step_coefficients_are_the_exact_ou_discretisation(elapsed, tau):
    """e' = exp(-dt/tau) e + sqrt(1 - exp(-2 dt/tau)) w, so var e' = var e when var e = var w."""
    unit = np.array([1.0, -2.0, 0.5])
    decay = gauss_markov_step(unit, np.zeros(3), elapsed, tau)
    fresh = gauss_markov_step(np.zeros(3), unit, elapsed, tau)
    a = math.exp(-elapsed / tau)
    np.testing.assert_allclose(decay, a * unit, rtol=1e-12)
    np.testing.assert_allclose(fresh, math.sqrt(-math.expm1(-2.0 * elapsed / tau)) * unit, rtol=1e-9, atol=1e-300)
    assert (decay[0] ** 2 + fresh[0] ** 2) == pytest.approx(1.0, rel=1e-12)


@given(first=times, second=times, tau=times)
def test_gauss_markov_mean_decay_composes_over_steps(first, second, tau):
    """The conditional mean decays as exp(-t/tau) whatever the read-out times (Markov semigroup)."""
    start = np.array([0.3, -0.1, 2.0])
    two = gauss_markov_step(gauss_markov_step(start, np.zeros(3), first, tau), np.zeros(3), second, tau)
    np.testing.assert_allclose(two, gauss_markov_step(start, np.zeros(3), first + second, tau), rtol=1e-9, atol=1e-300)


def test_gauss_markov_step_edge_cases():
    previous, innovation = np.array([1.0, 2.0, 3.0]), np.array([-1.0, 0.5, 0.0])
    np.testing.assert_array_equal(gauss_markov_step(previous, innovation, 0.0, 2.0), previous)
    np.testing.assert_array_equal(gauss_markov_step(previous, innovation, 0.3, 0.0), innovation)


def test_gauss_markov_long_run_matches_stationary_std_and_autocorrelation():
    """Closed form of a stationary first-order Gauss-Markov process: std sigma, autocorrelation
    exp(-lag / tau). 200 000 steps of 0.02 s with tau = 0.2 s: 20 000 correlation times."""
    sigma, tau, dt, n = 0.1, 0.2, 0.02, 200_000
    rng = np.random.default_rng(7)
    innovations = rng.normal(0.0, sigma, (n, 3))
    errors = np.empty((n, 3))
    errors[0] = innovations[0]
    for k in range(1, n):
        errors[k] = gauss_markov_step(errors[k - 1], innovations[k], dt, tau)
    np.testing.assert_allclose(errors.mean(axis=0), 0.0, atol=0.1 * sigma)
    np.testing.assert_allclose(errors.std(axis=0), sigma, rtol=0.03)
    for lag in (1, 5, 10, 20):
        x = errors[:-lag].ravel()
        y = errors[lag:].ravel()
        correlation = float(np.mean(x * y) / np.mean(errors**2))
        assert correlation == pytest.approx(math.exp(-lag * dt / tau), abs=0.02)


def _errors(vehicle: AttitudeThrustVehicle, samples: int, every: float) -> np.ndarray:
    """Feedback minus truth, shape (samples, 6): position then velocity error."""
    out = np.empty((samples, 6))
    for k in range(samples):
        truth = vehicle.state
        p, v = vehicle.measured_state()
        out[k] = np.concatenate([p - truth.position, v - truth.velocity])
        vehicle.advance(every)
    return out


def test_white_default_draws_independent_normals_from_the_vehicle_generator():
    """Default (no time constant): each read-out is N(0, sigma_p^2), N(0, sigma_v^2), drawn in that order."""
    assert PARAMS.position_noise_time_constant == 0.0 and PARAMS.velocity_noise_time_constant == 0.0
    errors = _errors(AttitudeThrustVehicle(PARAMS, rng=11), 50, 0.01)
    reference = np.random.default_rng(11)
    expected = np.array([np.concatenate([reference.normal(0.0, PARAMS.position_noise_std, 3),
                                         reference.normal(0.0, PARAMS.velocity_noise_std, 3)]) for _ in range(50)])
    np.testing.assert_allclose(errors, expected, atol=1e-9)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), position_std=st.sampled_from([0.0, 1e-3, 0.05, 0.3, 7.0]),
       velocity_std=st.sampled_from([0.0, 0.02, 0.1, 2.5]), tau=st.sampled_from([0.0, 0.4]))
def test_feedback_noise_is_the_generators_normal_draws_bit_for_bit(seed, position_std, velocity_std, tau):
    """The vehicle draws its normals a block at a time (AttitudeThrustVehicle._next_normals); every read-out
    is still truth + Generator.normal(0, sigma_p, 3), then Generator.normal(0, sigma_v, 3) of a generator with
    the same seed, to the bit, across block boundaries (white), and the Gauss-Markov recursion of those draws."""
    params = replace(PARAMS, position_noise_std=position_std, velocity_noise_std=velocity_std,
                     position_noise_time_constant=tau, velocity_noise_time_constant=tau)
    vehicle = AttitudeThrustVehicle(params, rng=seed)
    reference = np.random.default_rng(seed)
    error, then = None, 0.0
    calls = AttitudeThrustVehicle._NORMALS_BLOCK + 9
    for k in range(calls):
        truth, now = vehicle.state, vehicle.time
        p, v = vehicle.measured_state()
        white_p, white_v = reference.normal(0.0, position_std, 3), reference.normal(0.0, velocity_std, 3)
        if tau > 0.0:
            error = (white_p, white_v) if error is None else (
                gauss_markov_step(error[0], white_p, now - then, tau), gauss_markov_step(error[1], white_v, now - then, tau))
            white_p, white_v, then = *error, now
        assert p.tobytes() == (truth.position + white_p).tobytes() and v.tobytes() == (truth.velocity + white_v).tobytes(), k
        if k % 64 == 0 or (tau > 0.0 and k % 3 == 0):  # a few read-outs repeat at the same instant
            vehicle.advance(0.01)


def test_a_negative_feedback_noise_std_is_refused_as_numpy_refused_it():
    vehicle = AttitudeThrustVehicle(replace(PARAMS, position_noise_std=-0.1), rng=0)
    with pytest.raises(ValueError):
        vehicle.measured_state()
    with pytest.raises(ValueError):
        np.random.default_rng(0).normal(0.0, -0.1, 3)


def test_vehicle_gauss_markov_follows_the_closed_form_recursion_in_vehicle_time():
    """With tau set, the vehicle's error is the OU recursion over its own clock, fed by the same
    draws as the white model (so no other random stream moves), and a repeated read-out at the
    same instant sees the same error."""
    params = replace(PARAMS, position_noise_time_constant=2.0, velocity_noise_time_constant=0.5)
    vehicle = AttitudeThrustVehicle(params, rng=3)
    every = 0.02
    errors = _errors(vehicle, 40, every)
    draws = np.random.default_rng(3)
    white = np.array([np.concatenate([draws.normal(0.0, params.position_noise_std, 3),
                                      draws.normal(0.0, params.velocity_noise_std, 3)]) for _ in range(40)])
    a = np.repeat([math.exp(-every / 2.0), math.exp(-every / 0.5)], 3)
    expected = np.empty_like(white)
    expected[0] = white[0]
    for k in range(1, 40):
        expected[k] = a * expected[k - 1] + np.sqrt(1.0 - a**2) * white[k]
    np.testing.assert_allclose(errors, expected, atol=1e-9)
    truth = vehicle.state
    first, second = vehicle.measured_state(), vehicle.measured_state()
    np.testing.assert_allclose(first[0] - truth.position, second[0] - truth.position, atol=1e-12)


def test_time_constant_loads_from_a_vehicle_file(tmp_path):
    path = tmp_path / "slow_gnss.toml"
    path.write_text('name = "slow-gnss"\nposition_noise_time_constant = 5.0\nvelocity_noise_time_constant = 2\n')
    vehicle = load_vehicle(path)
    params = quadrotor_params(vehicle)
    assert params.position_noise_time_constant == 5.0 and params.velocity_noise_time_constant == 2.0
    assert params.position_noise_std == PARAMS.position_noise_std  # std unchanged: Table I
    path.write_text("position_noise_time_constant = -1.0\n")
    with pytest.raises(ConfigError, match="position_noise_time_constant"):
        load_vehicle(path)
