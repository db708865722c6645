"""The airframe ([vehicle] files, the paper's Table I by default) and [pursuer], its start."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from interfaces.scenario.common import NonNegative, Positive, Vector3, _Strict
from interfaces.scenario.files import VEHICLES_DIR, _read_toml


#: The paper's Table I airframe. Its numbers live in this file only: VehicleConfig's defaults
#: are read from it, and the plant builds its parameters from a VehicleConfig.
PAPER_TABLE1 = VEHICLES_DIR / "paper_table1.toml"
_TABLE1 = _read_toml(PAPER_TABLE1)


class VehicleConfig(_Strict):
    """Airframe and the autopilot-side limits; SI units. A key a vehicle file leaves out takes
    the paper's Table I value from config/vehicles/paper_table1.toml (PAPER_TABLE1)."""

    name: str = "quadrotor"
    mass: Positive = _TABLE1["mass"]
    gravity: Positive = _TABLE1["gravity"]
    inertia: Vector3 = tuple(_TABLE1["inertia"])
    arm_length: Positive = _TABLE1["arm_length"]
    thrust_coefficient: Positive = _TABLE1["thrust_coefficient"]
    moment_coefficient: Positive = _TABLE1["moment_coefficient"]
    motor_time_constant: Positive = _TABLE1["motor_time_constant"]
    drag_coefficient: NonNegative = _TABLE1["drag_coefficient"]
    max_thrust_to_weight: Annotated[float, Field(gt=1.0, le=5.0)] = _TABLE1["max_thrust_to_weight"]
    attitude_kp: Positive = _TABLE1["attitude_kp"]
    attitude_kd: Positive = _TABLE1["attitude_kd"]
    position_noise_std: NonNegative = _TABLE1["position_noise_std"]
    velocity_noise_std: NonNegative = _TABLE1["velocity_noise_std"]
    # Own-state feedback error model: 0 (the default) draws the noise above independently at
    # every read-out (white, section VIII); tau > 0 makes it first-order Gauss-Markov with that
    # time constant, s, and the same stationary std (an autopilot's fused position error is
    # correlated over seconds, not independent at 50 Hz).
    position_noise_time_constant: NonNegative = 0.0
    velocity_noise_time_constant: NonNegative = 0.0
    max_tilt_deg: Annotated[float, Field(gt=0.0, lt=80.0)] = _TABLE1["max_tilt_deg"]

    @model_validator(mode="after")
    def _inertia_positive(self) -> "VehicleConfig":
        if min(self.inertia) <= 0.0:
            raise ValueError("inertia: all principal moments must be positive")
        return self


class PursuerConfig(_Strict):
    initial_position: Vector3 = (0.0, 0.0, 0.0)
    initial_velocity: Vector3 = (0.0, 0.0, 0.0)
