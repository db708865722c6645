"""The airframe ([vehicle] files, the paper's Table I by default) and [pursuer], its start."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from interfaces.scenario.common import FROM_ARRAY, Position, Velocity, _Strict
from interfaces.scenario.files import VEHICLES_DIR, _read_toml


#: The paper's Table I airframe. Its numbers live in this file only: VehicleConfig's defaults
#: are read from it, and the plant builds its parameters from a VehicleConfig.
PAPER_TABLE1 = VEHICLES_DIR / "paper_table1.toml"
_TABLE1 = _read_toml(PAPER_TABLE1)


# What a small multirotor can be (SI units): from a 50 g micro drone to a 50 kg heavy lifter.
#: kg.
Mass = Annotated[float, Field(ge=0.05, le=50.0)]
#: m/s^2: from below the Moon's 1.6 to above Jupiter's 25.
Gravity = Annotated[float, Field(ge=1.0, le=30.0)]
#: kg m^2: a principal moment of inertia.
InertiaComponent = Annotated[float, Field(ge=1e-5, le=10.0)]
#: kg m^2: the three principal moments (Jxx, Jyy, Jzz).
Inertia = Annotated[tuple[InertiaComponent, InertiaComponent, InertiaComponent], FROM_ARRAY]
#: m: centre to rotor.
ArmLength = Annotated[float, Field(ge=0.02, le=2.0)]
#: N/(rad/s)^2.
ThrustCoefficient = Annotated[float, Field(ge=1e-9, le=1e-2)]
#: N m/(rad/s)^2.
MomentCoefficient = Annotated[float, Field(ge=1e-12, le=1e-3)]
#: s: from above half the 500 Hz physics step (the plant integrates it explicitly) to a sluggish 1 s.
MotorTimeConstant = Annotated[float, Field(ge=1e-3, le=1.0)]
#: N/(m/s).
DragCoefficient = Annotated[float, Field(ge=0.0, le=10.0)]
#: N m/rad (kp) or N m s/rad (kd).
AttitudeGain = Annotated[float, Field(gt=0.0, le=100.0)]
#: s: 0 white noise, else first-order Gauss-Markov.
NoiseTimeConstant = Annotated[float, Field(ge=0.0, le=3600.0)]


class VehicleConfig(_Strict):
    """Airframe and the autopilot-side limits; SI units. A key a vehicle file leaves out takes
    the paper's Table I value from config/vehicles/paper_table1.toml (PAPER_TABLE1)."""

    name: str = "quadrotor"
    mass: Mass = _TABLE1["mass"]
    gravity: Gravity = _TABLE1["gravity"]
    inertia: Inertia = tuple(_TABLE1["inertia"])
    arm_length: ArmLength = _TABLE1["arm_length"]
    thrust_coefficient: ThrustCoefficient = _TABLE1["thrust_coefficient"]
    moment_coefficient: MomentCoefficient = _TABLE1["moment_coefficient"]
    motor_time_constant: MotorTimeConstant = _TABLE1["motor_time_constant"]
    drag_coefficient: DragCoefficient = _TABLE1["drag_coefficient"]
    max_thrust_to_weight: Annotated[float, Field(gt=1.0, le=5.0)] = _TABLE1["max_thrust_to_weight"]
    attitude_kp: AttitudeGain = _TABLE1["attitude_kp"]
    attitude_kd: AttitudeGain = _TABLE1["attitude_kd"]
    position_noise_std: Annotated[float, Field(ge=0.0, le=100.0)] = _TABLE1["position_noise_std"]
    """m: own-position feedback noise (a GNSS fix is a few metres at worst)."""
    velocity_noise_std: Annotated[float, Field(ge=0.0, le=10.0)] = _TABLE1["velocity_noise_std"]
    """m/s: own-velocity feedback noise."""
    # Own-state feedback error model: 0 (the default) draws the noise above independently at
    # every read-out (white, section VIII); tau > 0 makes it first-order Gauss-Markov with that
    # time constant, s, and the same stationary std (an autopilot's fused position error is
    # correlated over seconds, not independent at 50 Hz).
    position_noise_time_constant: NoiseTimeConstant = 0.0
    velocity_noise_time_constant: NoiseTimeConstant = 0.0
    # Below 5 deg a multirotor cannot accelerate or brake enough to follow anything (PX4's MPC_TILTMAX_AIR
    # starts at 20 deg), and the planned braking g tan(max_tilt) / 2 underflows to 0 near 0 deg.
    max_tilt_deg: Annotated[float, Field(ge=5.0, lt=80.0)] = _TABLE1["max_tilt_deg"]


class PursuerConfig(_Strict):
    initial_position: Position = (0.0, 0.0, 0.0)
    initial_velocity: Velocity = (0.0, 0.0, 0.0)
