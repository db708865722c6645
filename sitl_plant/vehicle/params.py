"""Physical parameters of the simulated quadrotor.

The plant only knows these numbers; where they come from (a TOML vehicle file, the
paper's Table I in config/vehicles/paper_table1.toml by default) is the scenario
schema's business (interfaces.scenario). No number of Table I is written here.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from interfaces.scenario import VehicleConfig, table1_vehicle


@dataclass(frozen=True)
class QuadrotorParams:
    """Quadrotor airframe, motors and low-level attitude-controller gains; SI units.

    Every value is given explicitly: quadrotor_params(vehicle) builds it from a vehicle
    file, table1_params() from the paper's Table I.
    """

    mass: float  # kg
    gravity: float  # m/s^2
    inertia: tuple[float, float, float]  # kg m^2, body principal axes
    arm_length: float  # m, rotor hub to centre of mass
    thrust_coefficient: float  # N / (rad/s)^2
    moment_coefficient: float  # N m / (rad/s)^2
    motor_time_constant: float  # s, first-order motor lag 1/(T_m s + 1)
    drag_coefficient: float  # N / (m/s), linear body-frame drag, K_r = diag(C_d, C_d, 0)
    max_thrust_to_weight: float  # total thrust <= this * m g
    attitude_kp: float  # N m / rad, geometric attitude controller, eq. (24)
    # Table I's kd/kp = 0.25 s: roll/pitch overdamped (zeta 1.34, 30 deg settles to 1 deg in ~0.8 s)
    # and yaw critically damped; a smaller ratio makes large yaw steps, which saturate the weak
    # C_m yaw authority (~0.1 N m at hover), overshoot by tens of degrees.
    attitude_kd: float  # N m s / rad, eq. (24)
    position_noise_std: float  # m, feedback noise sigma_p (section VIII)
    velocity_noise_std: float  # m/s, feedback noise sigma_v (section VIII)
    # s, Gauss-Markov correlation time of the feedback noise; 0 = white (independent each read-out)
    position_noise_time_constant: float = 0.0
    velocity_noise_time_constant: float = 0.0

    @property
    def inertia_matrix(self) -> np.ndarray:
        """Body inertia J, kg m^2, shape (3, 3)."""
        return np.diag(self.inertia)

    @property
    def hover_thrust(self) -> float:
        """Total thrust that balances gravity, N."""
        return self.mass * self.gravity

    @property
    def max_total_thrust(self) -> float:
        """Largest total thrust the four rotors can give together, N."""
        return self.max_thrust_to_weight * self.mass * self.gravity

    @property
    def max_rotor_speed(self) -> float:
        """Per-rotor speed limit, rad/s, such that four rotors give max_total_thrust."""
        return float(np.sqrt(self.max_total_thrust / (4.0 * self.thrust_coefficient)))

    @property
    def hover_thrust_normalized(self) -> float:
        """Hover thrust as a fraction of max_total_thrust (PX4's MPC_THR_HOVER)."""
        return 1.0 / self.max_thrust_to_weight


def quadrotor_params(vehicle: VehicleConfig) -> QuadrotorParams:
    """Plant parameters from a vehicle file."""
    return QuadrotorParams(
        mass=vehicle.mass,
        gravity=vehicle.gravity,
        inertia=tuple(vehicle.inertia),
        arm_length=vehicle.arm_length,
        thrust_coefficient=vehicle.thrust_coefficient,
        moment_coefficient=vehicle.moment_coefficient,
        motor_time_constant=vehicle.motor_time_constant,
        drag_coefficient=vehicle.drag_coefficient,
        max_thrust_to_weight=vehicle.max_thrust_to_weight,
        attitude_kp=vehicle.attitude_kp,
        attitude_kd=vehicle.attitude_kd,
        position_noise_std=vehicle.position_noise_std,
        velocity_noise_std=vehicle.velocity_noise_std,
        position_noise_time_constant=vehicle.position_noise_time_constant,
        velocity_noise_time_constant=vehicle.velocity_noise_time_constant,
    )


@cache
def table1_params() -> QuadrotorParams:
    """The paper's Table I airframe (config/vehicles/paper_table1.toml) as plant parameters."""
    return quadrotor_params(table1_vehicle())
