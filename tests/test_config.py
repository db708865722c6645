"""Scenario files: every shipped one loads; bad ones fail with a message naming the key."""

import tomllib
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from interfaces.scenario import SCENARIOS_DIR, VEHICLES_DIR, ConfigError, Scenario, load_scenario, load_vehicle
from interfaces.scenario.common import MAX_DISTANCE_M, MAX_SPEED_M_S

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


def test_the_plant_reads_a_scenario_with_every_companion_section_and_leaves_them_to_the_companion(tmp_path):
    """The plant's view skips exactly the sections the full scenario has beyond its own (a [safety] or [health]
    section of a user's file must not stop sitl-plant), and the companion's view still checks them."""
    from interfaces.scenario import COMPANION_SECTIONS, PlantScenario, load_plant_scenario

    assert set(COMPANION_SECTIONS) == set(Scenario.model_fields) - set(PlantScenario.model_fields)
    extra = ('\n[safety]\nspeed_change_latency = 1.0\n\n[health]\nclear_after = 5.0\n'
             '\n[companion]\n\n[dropout]\n')
    path = _write(tmp_path, VALID + extra)
    plant, _ = load_plant_scenario(path)
    full, _ = load_scenario(path)
    assert plant.name == full.name and full.safety.speed_change_latency == 1.0
    path.write_text(VALID + "\n[safety]\nspeed_change_latency = -1.0\n")
    load_plant_scenario(path)
    with pytest.raises(ConfigError, match="speed_change_latency"):
        load_scenario(path)


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
        ("duration = 60.0", "duration = 86400.5", "simulation.duration"),
        ("physics_rate_hz = 500.0", "physics_rate_hz = 1e9", "simulation.physics_rate_hz"),
    ],
)
def test_bad_values_are_rejected_naming_the_key(tmp_path, old, new, key):
    assert old in VALID
    path = _write(tmp_path, VALID.replace(old, new, 1))
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    assert key.split(".")[-1] in str(error.value)
    assert str(path) in str(error.value)


VEHICLE_PATH_LINE = 'vehicle = "../vehicles/paper_table1.toml"'


def _copied(tmp_path: Path, vehicle_line: str) -> Path:
    """constant_velocity copied out of config/scenarios (no vehicles/ folder near it), its vehicle line replaced."""
    assert VEHICLE_PATH_LINE in VALID
    path = tmp_path / "copied.toml"
    path.write_text(VALID.replace(VEHICLE_PATH_LINE, vehicle_line))
    return path


@pytest.mark.parametrize("vehicle_line", ['vehicle = "paper_table1"', ""], ids=["by name", "by default"])
def test_a_copied_scenario_finds_a_shipped_airframe_by_name(tmp_path, scenario_path, vehicle_line):
    from interfaces.scenario import load_plant_scenario

    path = _copied(tmp_path, vehicle_line)
    _, shipped = load_scenario(scenario_path("constant_velocity"))
    scenario, vehicle = load_scenario(path)
    assert vehicle == shipped == load_vehicle(VEHICLES_DIR / "paper_table1.toml")
    assert scenario.vehicle == "paper_table1"
    assert load_plant_scenario(path)[1] == shipped


def test_an_unknown_airframe_name_is_refused_listing_the_shipped_ones(tmp_path):
    path = _copied(tmp_path, 'vehicle = "paper_table2"')
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    message = str(error.value)
    assert message.startswith(f"{path}: vehicle = 'paper_table2': no shipped airframe of that name")
    shipped = sorted(vehicle.stem for vehicle in VEHICLES_DIR.glob("*.toml"))
    assert "paper_table1" in shipped and f"(shipped: {', '.join(shipped)})" in message


def test_a_vehicle_path_is_still_relative_to_the_scenario(tmp_path):
    (tmp_path / "heavy.toml").write_text((VEHICLES_DIR / "paper_table1.toml").read_text().replace("mass = 1.5", "mass = 2.5"))
    for line in ('vehicle = "heavy.toml"', 'vehicle = "./heavy.toml"', f'vehicle = "{tmp_path / "heavy.toml"}"'):
        _, vehicle = load_scenario(_copied(tmp_path, line))
        assert vehicle.mass == 2.5, line
    with pytest.raises(ConfigError, match="not found"):
        load_scenario(_copied(tmp_path, 'vehicle = "../vehicles/paper_table1.toml"'))


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


# --- strict types: what TOML writes is what the model gets, nothing is coerced ---------------

@pytest.mark.parametrize(
    "old, new, key",
    [
        ("desired_range = 8.0", 'desired_range = "12"', "guidance.desired_range"),
        ("seed = 1", 'seed = "3"', "simulation.seed"),
        ("seed = 1", "seed = 3.0", "simulation.seed"),
        ("rate_hz = 50.0", 'rate_hz = "50"', "estimator.rate_hz"),
        ("initial_velocity = [3.0, 4.0, 0.0]", 'initial_velocity = [3.0, "4", 0.0]', "target.initial_velocity.1"),
    ],
)
def test_numeric_strings_are_refused_naming_the_key(tmp_path, old, new, key):
    assert old in VALID
    path = _write(tmp_path, VALID.replace(old, new, 1))
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    assert f"  {key}: " in str(error.value)
    assert "valid" in str(error.value).split(f"  {key}: ", 1)[1].splitlines()[0]


def test_a_boolean_string_is_refused(tmp_path):
    path = _write(tmp_path, VALID.replace("[guidance]", '[guidance]\nscale_with_range = "true"', 1))
    with pytest.raises(ConfigError, match="guidance.scale_with_range"):
        load_scenario(path)


def _guidance_with(literal: str):
    # [health] max_range, at its bound, above the derived min_range (desired_range / 4) of every value drawn below
    return Scenario.model_validate(tomllib.loads(VALID.replace("desired_range = 8.0", f"desired_range = {literal}", 1)
                                                 + f"\n[health]\nmax_range = {MAX_DISTANCE_M!r}\n"))


@given(st.floats(min_value=1e-3, max_value=MAX_DISTANCE_M, allow_nan=False))
def test_a_toml_float_loads_and_its_quoted_form_does_not(value):
    assert _guidance_with(repr(value)).guidance.desired_range == value
    with pytest.raises(ValidationError):
        _guidance_with(f'"{value!r}"')


@given(st.integers(min_value=1, max_value=int(MAX_DISTANCE_M)))
def test_a_toml_integer_is_a_valid_float(value):
    # TOML writes 8 for 8.0; a strict schema must still take it, as the same number.
    desired_range = _guidance_with(str(value)).guidance.desired_range
    assert isinstance(desired_range, float) and desired_range == float(value)


@given(st.lists(st.floats(min_value=-MAX_SPEED_M_S, max_value=MAX_SPEED_M_S), min_size=3, max_size=3))
def test_toml_arrays_load_as_vectors(components):
    literal = "[" + ", ".join(repr(c) for c in components) + "]"
    scenario = Scenario.model_validate(
        tomllib.loads(VALID.replace("initial_velocity = [3.0, 4.0, 0.0]", f"initial_velocity = {literal}", 1)))
    assert scenario.target.initial_velocity == tuple(components)


@pytest.mark.parametrize("path", sorted(VEHICLES_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_vehicle_loads(path):
    vehicle = load_vehicle(path)
    assert vehicle.mass > 0 and len(vehicle.inertia) == 3


@pytest.mark.parametrize("path", sorted(SCENARIOS_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_scenario_keeps_its_arrays(path):
    """Each TOML array of the file arrives as a tuple with the same numbers (the container is the
    only thing converted)."""
    raw = tomllib.loads(path.read_text())
    scenario, _ = load_scenario(path)
    for section, body in raw.items():
        if not isinstance(body, dict):
            continue
        for key, value in body.items():
            if isinstance(value, list) and all(isinstance(item, (int, float)) for item in value):
                assert getattr(getattr(scenario, section), key) == tuple(value), f"{section}.{key}"


def test_table1_defaults_come_from_the_vehicle_file():
    """A vehicle file that gives only a name flies Table I; the values come from paper_table1.toml."""
    from interfaces.scenario import PAPER_TABLE1, VehicleConfig, table1_vehicle
    from sitl_plant.vehicle.params import quadrotor_params, table1_params

    assert PAPER_TABLE1 == SCENARIOS_DIR.parent / "vehicles" / "paper_table1.toml"
    table1 = table1_vehicle()
    assert VehicleConfig().model_dump(exclude={"name"}) == table1.model_dump(exclude={"name"})
    assert table1_params() == quadrotor_params(table1)
    # The paper's numbers (Table I), as printed there.
    assert table1.inertia == (1.745e-2, 1.745e-2, 3.175e-2) and table1.thrust_coefficient == 1.105e-5


def test_no_copy_of_table1_in_the_code():
    """Table I is written once, in config/vehicles/paper_table1.toml: no package source spells
    one of its distinctive numbers (mass 1.5 and g 9.81 are too common to tell)."""
    import ast
    import io
    import tokenize

    from interfaces.scenario import table1_vehicle

    table1 = table1_vehicle()
    distinctive = {*table1.inertia, table1.arm_length, table1.thrust_coefficient, table1.moment_coefficient,
                   table1.motor_time_constant, table1.drag_coefficient}
    copies = []
    for package in ("interfaces", "companion", "sitl_plant", "studies"):
        for source in sorted((SCENARIOS_DIR.parent.parent / package).rglob("*.py")):
            for token in tokenize.generate_tokens(io.StringIO(source.read_text()).readline):
                if token.type == tokenize.NUMBER and ast.literal_eval(token.string) in distinctive:
                    copies.append(f"{source.name}:{token.start[0]}: {token.string}")
    assert copies == []
