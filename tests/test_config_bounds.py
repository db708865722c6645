"""Physical bounds of the scenario and vehicle schema: every bounded key refuses a value just outside its bound,
naming the key, and takes the bound itself; values drawn across the accepted ranges of the physical keys fly.

The bounds are read from the schema's own metadata (pydantic's Field constraints), never restated here.
"""

from __future__ import annotations

import math
import types
import typing
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from interfaces.scenario import DEFAULT_SCENARIO, ConfigError, Scenario, VehicleConfig, load_scenario, load_vehicle
from interfaces.scenario.loading import describe_errors

BOUND_NAMES = ("gt", "ge", "lt", "le")


@dataclass(frozen=True)
class BoundedKey:
    """One numeric key with bounds: `key` as a ConfigError names it (section.key, .i for a vector's component),
    the model and field that hold it, the component index (None: a scalar) and the bounds."""

    key: str
    model: type[BaseModel]
    field: str
    index: int | None
    kind: type
    bounds: dict[str, float]

    def value(self, number: float):
        """The field's value with `number` in this key's place (0 in a vector's other components)."""
        if self.index is None:
            return number
        return tuple(number if i == self.index else 0.0 for i in range(_arity(self.model, self.field)))

    def problems(self, number: float) -> list[str]:
        """The "key: message" lines about this key when its model takes `number` here (other keys' left out)."""
        try:
            self.model.model_validate({self.field: self.value(number)})
        except ValidationError as error:
            prefix = f"{self.key}: "
            return [line for line in describe_errors(error, self.key.rsplit(".", 2 if self.index is not None else 1)[0])
                    if line.startswith(prefix)]
        return []


def _arity(model: type[BaseModel], field: str) -> int:
    annotation, _ = _unwrap(model.model_fields[field].annotation)
    members = [member for member in typing.get_args(annotation) if member is not type(None)]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        annotation, _ = _unwrap(members[0])
    return len(typing.get_args(annotation))


def _unwrap(annotation, metadata=()):
    """(bare annotation, its constraints), Annotated layers and Field(...) objects flattened."""
    if typing.get_origin(annotation) is typing.Annotated:
        inner, *extra = typing.get_args(annotation)
        return _unwrap(inner, (*metadata, *extra))
    flat = [inner for item in metadata for inner in (getattr(item, "metadata", None) or [item])]
    return annotation, flat


def _bounds(metadata) -> dict[str, float]:
    return {name: getattr(item, name) for item in metadata for name in BOUND_NAMES if getattr(item, name, None) is not None}


def bounded_keys(model: type[BaseModel], prefix: str, seen: set | None = None) -> list[BoundedKey]:
    """Every numeric key with bounds in `model` and the models it holds (sections, tables, list items)."""
    seen = set() if seen is None else seen
    found = []
    for name, field in model.model_fields.items():
        found += _keys_of(model, name, f"{prefix}{name}", field.annotation, field.metadata, seen)
    return found


def _keys_of(model, name, key, annotation, metadata, seen) -> list[BoundedKey]:
    annotation, metadata = _unwrap(annotation, metadata)
    origin, arguments = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        return [found for member in arguments if member is not type(None)
                for found in _keys_of(model, name, key, member, metadata, seen)]
    if origin is tuple:
        if len(arguments) == 2 and arguments[1] is Ellipsis:
            item, _ = _unwrap(arguments[0])
            members = typing.get_args(item) if typing.get_origin(item) in (typing.Union, types.UnionType) else (item,)
            return [found for member in members for found in _models_keys(_unwrap(member)[0], f"{key}.0.", seen)]
        keys = []
        for index, item in enumerate(arguments):
            kind, item_metadata = _unwrap(item)
            if kind in (int, float) and _bounds(item_metadata):
                keys.append(BoundedKey(f"{key}.{index}", model, name, index, kind, _bounds(item_metadata)))
        return keys
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return _models_keys(annotation, f"{key}.", seen)
    if annotation in (int, float) and _bounds(metadata):
        return [BoundedKey(key, model, name, None, annotation, _bounds(metadata))]
    return []


def _models_keys(model, prefix, seen) -> list[BoundedKey]:
    if not (isinstance(model, type) and issubclass(model, BaseModel)) or model in seen:
        return []
    seen.add(model)
    return bounded_keys(model, prefix, seen)


SCENARIO_KEYS = bounded_keys(Scenario, "")
VEHICLE_KEYS = bounded_keys(VehicleConfig, "vehicle.")
ALL_KEYS = SCENARIO_KEYS + VEHICLE_KEYS
BY_KEY = {bounded.key: bounded for bounded in ALL_KEYS}


def _outside_and_at(bounded: BoundedKey) -> list[tuple[float, float]]:
    """(a value just outside, the closest value the bound accepts) for each of the key's bounds."""
    pairs = []
    for name, bound in bounded.bounds.items():
        if bounded.kind is int:
            step = {"ge": -1, "gt": 0, "le": 1, "lt": 0}[name]
            inside = {"ge": 0, "gt": 1, "le": 0, "lt": -1}[name]
            pairs.append((bound + step, bound + inside))
            continue
        down, up = math.nextafter(bound, -math.inf), math.nextafter(bound, math.inf)
        pairs.append({"ge": (down, bound), "gt": (bound, up), "le": (up, bound), "lt": (bound, down)}[name])
    return pairs


@pytest.mark.parametrize("bounded", ALL_KEYS, ids=lambda bounded: bounded.key)
def test_each_bounded_key_refuses_just_outside_and_takes_its_bound(bounded):
    for outside, accepted in _outside_and_at(bounded):
        refusals = bounded.problems(outside)
        assert refusals, f"{bounded.key} = {outside!r} was accepted (bounds {bounded.bounds})"
        assert not bounded.problems(accepted), \
            f"{bounded.key} = {accepted!r} was refused: {bounded.problems(accepted)}"


PHYSICAL_KEYS = ("vehicle.mass", "vehicle.gravity", "vehicle.arm_length", "vehicle.max_tilt_deg",
                 *(f"vehicle.inertia.{i}" for i in range(3)), *(f"pursuer.initial_position.{i}" for i in range(3)),
                 *(f"pursuer.initial_velocity.{i}" for i in range(3)), *(f"target.initial_position.{i}" for i in range(3)),
                 *(f"target.initial_velocity.{i}" for i in range(3)))


def test_the_physical_keys_are_bounded_on_both_sides():
    for key in PHYSICAL_KEYS:
        bounds = BY_KEY[key].bounds
        assert bounds.keys() & {"gt", "ge"} and bounds.keys() & {"lt", "le"}, (key, bounds)


@pytest.mark.parametrize("text, key", [
    ("[pursuer]\ninitial_position = [1e160, 0, 0]\n", "pursuer.initial_position.0"),
    ("[pursuer]\ninitial_velocity = [0, 0, -100.5]\n", "pursuer.initial_velocity.2"),
    ("[guidance]\ndesired_range = 1e300\n", "guidance.desired_range"),
    ("[estimator]\nrate_hz = 1e300\n", "estimator.rate_hz"),
])
def test_a_scenario_file_out_of_bounds_is_refused_naming_the_key(tmp_path, text, key):
    source = DEFAULT_SCENARIO.read_text().replace('vehicle = "../vehicles/paper_table1.toml"', 'vehicle = "paper_table1"')
    section = text.split("\n", 1)[0]
    assert section in source
    key_line = text.split("\n")[1]
    path = tmp_path / "scenario.toml"
    name = key_line.split(" = ")[0]
    lines = [line for line in source.splitlines() if not line.startswith(f"{name} =")]
    edited = "\n".join(lines).replace(section, f"{section}\n{key_line}", 1)
    path.write_text(edited)
    with pytest.raises(ConfigError, match=rf"\n  {key}: ") as refusal:
        load_scenario(path)
    assert str(path) in str(refusal.value)


@pytest.mark.parametrize("line, key", [("gravity = 1e300", "gravity"), ("inertia = [1e-12, 1e-2, 1e-2]", "inertia.0"),
                                       ("mass = 0.01", "mass"), ("arm_length = 5.0", "arm_length")])
def test_a_vehicle_file_out_of_bounds_is_refused_naming_the_key(tmp_path, line, key):
    path = tmp_path / "vehicle.toml"
    path.write_text(f"{line}\n")
    with pytest.raises(ConfigError, match=rf"\n  {key}: "):
        load_vehicle(path)


def _range(key: str) -> st.SearchStrategy[float]:
    """Floats the schema accepts at `key` (its bounds read from the metadata)."""
    bounds = BY_KEY[key].bounds
    low = bounds.get("ge", bounds.get("gt"))
    high = bounds.get("le", bounds.get("lt"))
    return st.floats(low, high, exclude_min="gt" in bounds, exclude_max="lt" in bounds, allow_nan=False)


def _vector(prefix: str) -> st.SearchStrategy[tuple[float, float, float]]:
    return st.tuples(*(_range(f"{prefix}.{i}") for i in range(3)))


@pytest.fixture(scope="module")
def short_flight():
    scenario, vehicle = load_scenario(DEFAULT_SCENARIO)
    simulation = scenario.simulation.model_copy(update={"duration": 2.0, "summary_window": 1.0})
    return scenario.model_copy(update={"simulation": simulation}), vehicle


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mass=_range("vehicle.mass"), gravity=_range("vehicle.gravity"), inertia=_vector("vehicle.inertia"),
       arm_length=_range("vehicle.arm_length"), max_tilt_deg=_range("vehicle.max_tilt_deg"),
       pursuer_position=_vector("pursuer.initial_position"), pursuer_velocity=_vector("pursuer.initial_velocity"),
       target_position=_vector("target.initial_position"), target_velocity=_vector("target.initial_velocity"))
def test_any_accepted_airframe_and_start_flies_to_a_clean_termination(short_flight, *, mass, gravity, inertia, arm_length,
                                                                       max_tilt_deg, pursuer_position, pursuer_velocity,
                                                                       target_position, target_velocity):
    """Two seconds in process with values drawn across the accepted ranges: the flight may end out of control,
    with a non-finite estimate or diverged, but it ends with a Termination, never an exception."""
    from studies.closed_loop import Termination, simulate

    scenario, vehicle = short_flight
    vehicle = VehicleConfig.model_validate({**vehicle.model_dump(), "mass": mass, "gravity": gravity, "inertia": inertia,
                                            "arm_length": arm_length, "max_tilt_deg": max_tilt_deg})
    scenario = scenario.model_copy(update={
        "pursuer": scenario.pursuer.model_validate({"initial_position": pursuer_position,
                                                    "initial_velocity": pursuer_velocity}),
        "target": scenario.target.model_copy(update={"initial_position": target_position,
                                                     "initial_velocity": target_velocity})})
    result = simulate(scenario, vehicle)
    assert isinstance(result.termination, Termination)


@pytest.mark.parametrize("airframe, start, target", [
    # Accepted, but too stiff for the 500 Hz step: 1e-5 kg m^2 about one axis on 1 m arms blows the attitude
    # integration up within one estimator tick (1e196 m/s); it used to raise in the guidance's vector maths.
    ({"mass": 2.0, "gravity": 27.0, "inertia": (1.0, 1e-5, 1.0), "arm_length": 1.0, "max_tilt_deg": 5.0},
     (30.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    # The pursuer starts on the target: no bearing at zero range (it used to raise normalising the line of sight).
    ({}, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
])
def test_an_accepted_but_hopeless_flight_ends_with_a_termination(short_flight, airframe, start, target):
    from studies.closed_loop import Termination, simulate

    scenario, vehicle = short_flight
    vehicle = VehicleConfig.model_validate({**vehicle.model_dump(), **airframe})
    scenario = scenario.model_copy(update={
        "pursuer": scenario.pursuer.model_copy(update={"initial_position": start}),
        "target": scenario.target.model_copy(update={"initial_position": target})})
    result = simulate(scenario, vehicle)
    assert isinstance(result.termination, Termination)
    if airframe:
        assert result.termination is Termination.OUT_OF_CONTROL
