"""Scenario files: every shipped one loads; bad ones fail with a message naming the key."""

from pathlib import Path

import pytest

from interfaces.scenario import SCENARIOS_DIR, VEHICLES_DIR, ConfigError, load_scenario

VALID = (SCENARIOS_DIR / "constant_velocity.toml").read_text()


def _write(tmp_path: Path, text: str) -> Path:
    vehicles = tmp_path / "vehicles"
    vehicles.mkdir(exist_ok=True)
    (vehicles / "paper_table1.toml").write_text((VEHICLES_DIR / "paper_table1.toml").read_text())
    scenarios = tmp_path / "scenarios"
    scenarios.mkdir(exist_ok=True)
    path = scenarios / "case.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("path", sorted(SCENARIOS_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_scenario_loads(path):
    scenario, vehicle = load_scenario(path)
    assert scenario.name == path.stem
    assert vehicle.mass > 0


def test_paper_constant_velocity_values(scenario_path):
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    assert scenario.target.initial_position == (50.0, -25.0, -20.0)
    assert scenario.target.initial_velocity == (3.0, 4.0, 0.0)
    assert scenario.pursuer.initial_velocity == (2.0, 0.0, 0.0)
    assert scenario.estimator.initial_position == (40.0, -20.0, -15.0)
    assert scenario.estimator.process_noise == 0.04 and scenario.estimator.measurement_noise == 1e-4
    assert (scenario.guidance.desired_range, scenario.guidance.navigation_gain, scenario.guidance.c_z, scenario.guidance.c_y) == (8.0, 3.0, 3.5, 3.5)
    assert (scenario.estimator.rate_hz, scenario.guidance.rate_hz, scenario.sensor.rate_hz) == (50.0, 20.0, 5.0)
    assert vehicle.mass == 1.5 and vehicle.motor_time_constant == 0.0136


@pytest.mark.parametrize(
    "old, new, key",
    [
        ("desired_range = 8.0", "desired_rang = 8.0", "guidance.desired_rang"),
        ("desired_range = 8.0", "desired_range = -8.0", "guidance.desired_range"),
        ("desired_range = 8.0", "desired_range = nan", "guidance.desired_range"),
        ("rate_hz = 50.0", "rate_hz = 70.0", "estimator.rate_hz"),
        ('law = "hng"', 'law = "pnq"', "guidance.law"),
        ("initial_velocity = [3.0, 4.0, 0.0]", "initial_velocity = [3.0, 4.0]", "target.initial_velocity"),
        ("noise_std = 0.01", 'noise_std = "small"', "sensor.noise_std"),
        ("[simulation]", "[simulation]\nbogus = 1", "simulation.bogus"),
    ],
)
def test_bad_values_are_rejected_naming_the_key(tmp_path, old, new, key):
    assert old in VALID
    path = _write(tmp_path, VALID.replace(old, new, 1))
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    assert key.split(".")[-1] in str(error.value)
    assert str(path) in str(error.value)


def test_missing_range_guess_is_rejected(tmp_path):
    path = _write(tmp_path, VALID.replace("initial_position = [40.0, -20.0, -15.0]", ""))
    with pytest.raises(ConfigError, match="initial_range or initial_position"):
        load_scenario(path)


def test_bad_vehicle_file_is_rejected(tmp_path):
    path = _write(tmp_path, VALID)
    (tmp_path / "vehicles" / "paper_table1.toml").write_text("mass = 0.0\n")
    with pytest.raises(ConfigError, match="mass"):
        load_scenario(path)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_scenario(tmp_path / "nope.toml")
    path = _write(tmp_path, "name = [unclosed\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_scenario(path)
