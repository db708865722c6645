"""The plant's parameter table, served over the MAVLink parameter protocol.

A small set with PX4's names and meanings (PX4 v1.14 semantics), plus read-only
SIM_* parameters that expose the airframe the plant simulates. Setting a
parameter checks its type, range and allowed values; a rejected set leaves the
value unchanged, which is how the MAVLink parameter protocol reports failure
(the PARAM_VALUE echo carries the old value).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterator, Literal

from sitl_plant.vehicle.params import QuadrotorParams

ParamKind = Literal["float", "int"]


class ParameterError(ValueError):
    """A parameter read or write was refused; the message says why."""


@dataclass
class Parameter:
    """One parameter: name (<= 16 chars), value, kind, documentation and constraints."""

    name: str
    value: float
    kind: ParamKind
    description: str
    minimum: float = -math.inf
    maximum: float = math.inf
    allowed: tuple[int, ...] | None = None
    writable: bool = True
    unit: str = ""

    def check(self, value: float) -> float:
        """The value a set would store, or ParameterError."""
        if not self.writable:
            raise ParameterError(f"{self.name} is read-only")
        if not math.isfinite(value):
            raise ParameterError(f"{self.name}: value must be finite, got {value!r}")
        if self.kind == "int":
            if value != int(value):
                raise ParameterError(f"{self.name} is an integer parameter, got {value!r}")
            value = int(value)
            if self.allowed is not None and value not in self.allowed:
                raise ParameterError(f"{self.name}: {value} not supported by this plant (allowed: {self.allowed})")
        if not (self.minimum <= value <= self.maximum):
            raise ParameterError(f"{self.name}: {value} outside [{self.minimum}, {self.maximum}]")
        return float(value)


@dataclass
class ParameterTable:
    """Ordered parameters; index order is the PARAM_VALUE param_index."""

    _params: dict[str, Parameter] = field(default_factory=dict)

    def add(self, parameter: Parameter) -> None:
        if len(parameter.name) > 16 or not parameter.name:
            raise ValueError(f"MAVLink parameter names are 1-16 characters: {parameter.name!r}")
        self._params[parameter.name] = parameter

    def __iter__(self) -> Iterator[Parameter]:
        return iter(self._params.values())

    def __len__(self) -> int:
        return len(self._params)

    def __contains__(self, name: str) -> bool:
        return name in self._params

    def get(self, name: str) -> Parameter:
        try:
            return self._params[name]
        except KeyError:
            raise ParameterError(f"unknown parameter {name!r}") from None

    def by_index(self, index: int) -> Parameter:
        if not 0 <= index < len(self._params):
            raise ParameterError(f"parameter index {index} out of range 0..{len(self._params) - 1}")
        return list(self._params.values())[index]

    def index_of(self, name: str) -> int:
        return list(self._params).index(self.get(name).name)

    def value(self, name: str) -> float:
        return self.get(name).value

    def set(self, name: str, value: float) -> Parameter:
        """Validate and store; ParameterError (value unchanged) if refused."""
        parameter = self.get(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f"{name}: value must be a number, got {value!r}")
        parameter.value = parameter.check(float(value))
        return parameter


# COM_OBL_RC_ACT values this plant can fly (PX4 v1.14: 0 Position, 4 Land, 5 Hold).
# 1 Altitude, 2 Manual, 3 Return, 6 Terminate and 7 Disarm are refused, not faked.
OFFBOARD_LOSS_POSITION = 0
OFFBOARD_LOSS_LAND = 4
OFFBOARD_LOSS_HOLD = 5

# MAV_SIGN_CFG values (PX4's parameter). PX4: 0 signing optional, 1 required except on USB, 2 always.
# The plant has no USB link; 1 requires signing on the ground-station link and leaves the companion link
# unsigned (the wire to the companion stands where PX4's exemption is USB). 2 is refused, not faked.
SIGNING_OFF = 0
SIGNING_REQUIRED_ON_GCS = 1


def default_parameters(params: QuadrotorParams, max_tilt_deg: float, speed_factor: float) -> ParameterTable:
    """The plant's parameters, PX4 defaults where PX4 has the parameter."""
    table = ParameterTable()
    for parameter in (
        Parameter("MPC_THR_HOVER", params.hover_thrust_normalized, "float",
                  "Normalised collective thrust that hovers (linear thrust curve)", 0.1, 0.9),
        Parameter("MPC_TILTMAX_AIR", max_tilt_deg, "float", "Largest tilt in position modes", 20.0, 89.0, unit="deg"),
        Parameter("MPC_THR_XY_MARG", 0.3, "float",
                  "Share of full thrust kept for horizontal control when the vertical demand saturates", 0.0, 0.5),
        Parameter("MPC_TKO_SPEED", 1.5, "float", "Takeoff climb rate", 0.5, 5.0, unit="m/s"),
        Parameter("MPC_LAND_SPEED", 0.7, "float", "Landing descent rate", 0.3, 3.0, unit="m/s"),
        Parameter("MPC_Z_V_AUTO_DN", 1.5, "float", "Descent rate in auto modes (Land above MPC_LAND_ALT1)", 0.5, 4.0,
                  unit="m/s"),
        Parameter("MPC_LAND_ALT1", 10.0, "float", "Land slows down from MPC_Z_V_AUTO_DN below this height", 0.0, 122.0,
                  unit="m"),
        Parameter("MPC_LAND_ALT2", 5.0, "float", "Land descends at MPC_LAND_SPEED below this height", 0.0, 122.0,
                  unit="m"),
        Parameter("MPC_XY_VEL_MAX", 5.0, "float", "Horizontal speed limit in position modes", 0.5, 20.0, unit="m/s"),
        Parameter("MIS_TAKEOFF_ALT", 2.5, "float", "Takeoff altitude above home, also the lowest a takeoff command gets", 0.5, 100.0, unit="m"),
        Parameter("COM_OF_LOSS_T", 1.0, "float", "Offboard setpoint loss timeout", 0.1, 60.0, unit="s"),
        Parameter("COM_OBL_RC_ACT", OFFBOARD_LOSS_POSITION, "int",
                  "Offboard loss action: 0 Position (hold), 4 Land, 5 Hold", 0, 7,
                  allowed=(OFFBOARD_LOSS_POSITION, OFFBOARD_LOSS_LAND, OFFBOARD_LOSS_HOLD)),
        Parameter("COM_DISARM_LAND", 2.0, "float", "Disarm this long after landing; <= 0 never", -1.0, 20.0, unit="s"),
        Parameter("COM_DISARM_PRFLT", 10.0, "float", "Disarm this long after arming without takeoff; <= 0 never",
                  -1.0, 60.0, unit="s"),
        Parameter("MAV_SIGN_CFG", SIGNING_OFF, "int",
                  "MAVLink 2 signing: 0 off, 1 required on the ground-station link (the key is not a parameter)",
                  0, 2, allowed=(SIGNING_OFF, SIGNING_REQUIRED_ON_GCS)),
        Parameter("SIM_SPEED_FACTOR", speed_factor, "float", "Simulation speed over wall clock", writable=False),
        Parameter("SIM_MASS", params.mass, "float", "Vehicle mass", writable=False, unit="kg"),
        Parameter("SIM_IXX", params.inertia[0], "float", "Inertia about body x", writable=False, unit="kg m^2"),
        Parameter("SIM_IYY", params.inertia[1], "float", "Inertia about body y", writable=False, unit="kg m^2"),
        Parameter("SIM_IZZ", params.inertia[2], "float", "Inertia about body z", writable=False, unit="kg m^2"),
        Parameter("SIM_ARM_LEN", params.arm_length, "float", "Rotor hub to centre of mass", writable=False, unit="m"),
        Parameter("SIM_KT", params.thrust_coefficient, "float", "Rotor thrust coefficient", writable=False,
                  unit="N/(rad/s)^2"),
        Parameter("SIM_KM", params.moment_coefficient, "float", "Rotor moment coefficient", writable=False,
                  unit="N m/(rad/s)^2"),
        Parameter("SIM_MOT_TAU", params.motor_time_constant, "float", "Motor time constant", writable=False, unit="s"),
        Parameter("SIM_DRAG", params.drag_coefficient, "float", "Linear body drag", writable=False, unit="N/(m/s)"),
        Parameter("SIM_TWR", params.max_thrust_to_weight, "float", "Full thrust over weight", writable=False),
        Parameter("SIM_ATT_KP", params.attitude_kp, "float", "Attitude controller k_p, eq. (24)", writable=False,
                  unit="N m/rad"),
        Parameter("SIM_ATT_KD", params.attitude_kd, "float", "Attitude controller k_d, eq. (24)", writable=False,
                  unit="N m s/rad"),
    ):
        table.add(parameter)
    return table
