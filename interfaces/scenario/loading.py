"""The loaders: a scenario or vehicle file read, validated and its paths resolved."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from pydantic import ValidationError

from interfaces.scenario.common import ConfigError
from interfaces.scenario.files import VEHICLES_DIR, _read_toml
from interfaces.scenario.full import Scenario
from interfaces.scenario.plant import COMPANION_SECTIONS, PlantScenario, PlantSensorConfig
from interfaces.scenario.vehicle import PAPER_TABLE1, VehicleConfig


def describe_errors(error: ValidationError, root: str = "") -> list[str]:
    """One "section.key: message" per problem pydantic found (unknown keys said plainly); root: a
    section name put in front of every key (e.g. "faults" when validating that section alone)."""
    problems = []
    for item in error.errors():
        key = ".".join(str(part) for part in (root, *item["loc"]) if str(part)) or "(top level)"
        message = "unknown key (check the spelling)" if item["type"] == "extra_forbidden" else item["msg"]
        problems.append(f"{key}: {message}")
    return problems


ScenarioT = TypeVar("ScenarioT", Scenario, PlantScenario)


def _format(path: Path, error: ValidationError) -> str:
    return "\n".join([f"{path}: invalid configuration", *(f"  {problem}" for problem in describe_errors(error))])


def shipped_vehicle_names() -> list[str]:
    """The airframes a scenario's `vehicle` may name without a path: config/vehicles/<name>.toml, sorted."""
    return sorted(path.stem for path in VEHICLES_DIR.glob("*.toml"))


def is_vehicle_name(vehicle: str) -> bool:
    """True when a scenario's `vehicle` value is a shipped airframe's name ("paper_table1": no folder separator, no
    .toml), not a path to a vehicle file."""
    return "/" not in vehicle and "\\" not in vehicle and not vehicle.endswith(".toml")


def _scenario_vehicle(scenario_path: Path, vehicle: str) -> VehicleConfig:
    """The vehicle a scenario names, read and validated: a shipped airframe by name (config/vehicles/<name>.toml of
    the installed package, wherever the scenario is), or a vehicle file by its path (relative to the scenario's
    folder). A ConfigError names the scenario file and its `vehicle` key besides the vehicle file's own message; for
    an unknown name it lists the shipped ones."""
    if is_vehicle_name(vehicle):
        names = shipped_vehicle_names()
        if vehicle not in names:
            raise ConfigError(f"{scenario_path}: vehicle = {vehicle!r}: no shipped airframe of that name (shipped: "
                              f"{', '.join(names)}); a vehicle file of your own is given by its path, relative to "
                              "the scenario, ending in .toml")
        resolved = VEHICLES_DIR / f"{vehicle}.toml"
    else:
        try:
            resolved = (scenario_path.parent / vehicle).resolve()
        except (OSError, ValueError, RuntimeError) as error:  # a NUL byte, a symlink loop
            raise ConfigError(f"{scenario_path}: vehicle: {vehicle!r} is not a usable path ({error})") from None
    try:
        return load_vehicle(resolved)
    except ConfigError as error:
        raise ConfigError(f"{scenario_path}: vehicle = {vehicle!r}: {error}") from None


def _scenario_trajectory(scenario_path: Path, scenario: ScenarioT) -> ScenarioT:
    """The scenario with its [target.trajectory] file made absolute (relative paths are relative to the
    scenario's folder, as `vehicle` is), after reading and checking the track; unchanged without one. The
    absolute path lets both harnesses, and a copy of the configuration written elsewhere, find the file.
    ConfigError naming the scenario file and the key besides the trajectory file's own message."""
    trajectory = scenario.target.trajectory
    if trajectory is None:
        return scenario
    key = "target.trajectory.file"
    try:
        resolved = (scenario_path.parent / trajectory.file).resolve()
    except (OSError, ValueError, RuntimeError) as error:  # a NUL byte, a symlink loop
        raise ConfigError(f"{scenario_path}: {key}: {trajectory.file!r} is not a usable path ({error})") from None
    # Imported here: interfaces.trajectory builds on this package (ConfigError, read_regular_file).
    from interfaces.trajectory import read_trajectory

    try:
        times, _ = read_trajectory(resolved, trajectory.file_format)
    except ConfigError as error:
        raise ConfigError(f"{scenario_path}: {key} = {trajectory.file!r}: {error}") from None
    length = float(times[-1] - times[0])
    if trajectory.skip >= length:
        raise ConfigError(f"{scenario_path}: target.trajectory.skip: {trajectory.skip:g} s leaves nothing of the "
                          f"{length:g} s track in {resolved}")
    placed = trajectory.model_copy(update={"file": str(resolved)})
    return scenario.model_copy(update={"target": scenario.target.model_copy(update={"trajectory": placed})})


def load_vehicle(path: str | Path) -> VehicleConfig:
    """Read and validate a vehicle TOML file."""
    path = Path(path)
    try:
        return VehicleConfig.model_validate(_read_toml(path))
    except ValidationError as error:
        raise ConfigError(_format(path, error)) from None


def table1_vehicle() -> VehicleConfig:
    """The paper's Table I airframe, read and validated from PAPER_TABLE1."""
    return load_vehicle(PAPER_TABLE1)


def load_plant_scenario(path: str | Path) -> tuple[PlantScenario, VehicleConfig]:
    """Read and validate what the plant's side needs of a scenario file (PlantScenario) and the
    vehicle file it names; the companion's sections may be broken or absent."""
    path = Path(path)
    document = {key: value for key, value in _read_toml(path).items() if key not in COMPANION_SECTIONS}
    sensor = document.get("sensor")
    if isinstance(sensor, dict):
        document["sensor"] = {key: value for key, value in sensor.items() if key in PlantSensorConfig.model_fields}
    try:
        scenario = PlantScenario.model_validate(document)
    except ValidationError as error:
        raise ConfigError(_format(path, error)) from None
    return _scenario_trajectory(path, scenario), _scenario_vehicle(path, scenario.vehicle)


def load_scenario(path: str | Path) -> tuple[Scenario, VehicleConfig]:
    """Read and validate a scenario file and the vehicle file it names."""
    path = Path(path)
    try:
        scenario = Scenario.model_validate(_read_toml(path))
    except ValidationError as error:
        raise ConfigError(_format(path, error)) from None
    return _scenario_trajectory(path, scenario), _scenario_vehicle(path, scenario.vehicle)
