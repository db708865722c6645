"""The baselines reach both harnesses through the config: estimator kinds, guidance laws, the
range sensor, the simulation-only noise-free projection, and a clear error for wrong combinations."""

from __future__ import annotations

import numpy as np
import pytest

from companion import app
from companion.assembly import build_sensor, build_estimator, build_lateral_guidance, build_pipeline
from companion.core.baseline_estimators import AzElEKF, MSCEKF, RangeAzElEKF
from companion.core.baseline_guidance import (PDFollowingController, ProportionalNavigationGuidance,
                                         RetroProportionalNavigationGuidance, ZEMObservabilityGuidance)
from companion.core.bearing_sensor import BearingSensor
from interfaces.scenario import ConfigError, SensorConfig, load_scenario
from companion.core.estimators import GainProjection, UPLKF
from companion.core.guidance import HelicalNavigationGuidance, PurePursuitGuidance
from companion.core.messages import BearingMeasurement, PursuerState
from studies.closed_loop import simulate
from studies.montecarlo import DEFAULT_SCENARIO, with_overrides


@pytest.fixture(scope="module")
def loaded():
    return load_scenario(DEFAULT_SCENARIO)


@pytest.mark.parametrize("overrides, kind", [
    ({}, UPLKF),
    ({"estimator.kind": "ekf"}, AzElEKF),
    ({"estimator.kind": "msc_ekf"}, MSCEKF),
    ({"estimator.kind": "ekf_rae", "sensor.range_noise_std": 1.0}, RangeAzElEKF),
])
def test_estimator_kind_builds_its_filter(loaded, overrides, kind):
    assert isinstance(build_estimator(with_overrides(loaded[0], overrides)), kind)


def test_noise_free_projection_is_the_optimal_uplkf(loaded):
    estimator = build_estimator(with_overrides(loaded[0], {"estimator.gain_projection": "noise_free"}))
    assert estimator.gain_projection is GainProjection.NOISE_FREE


@pytest.mark.parametrize("law, overrides, kind", [
    ("hng", {}, HelicalNavigationGuidance),
    ("ppg", {}, PurePursuitGuidance),
    ("png", {}, ProportionalNavigationGuidance),
    ("pd", {"guidance.pd_kp": 0.7}, PDFollowingController),
    ("retro_png", {}, RetroProportionalNavigationGuidance),
    ("zem", {"guidance.zem_k_w": 0.01}, ZEMObservabilityGuidance),
])
def test_guidance_law_builds_its_class(loaded, law, overrides, kind):
    built = build_lateral_guidance(with_overrides(loaded[0], {"guidance.law": law, **overrides}))
    assert isinstance(built, kind)
    if law == "pd":
        assert (built.kp, built.kd, built.desired_range) == (0.7, 0.2, 8.0)
    if law == "zem":
        assert built.k_w == 0.01


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
