"""[estimator]: the target filter and its IMM options."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, model_validator

from interfaces.scenario.common import (FROM_ARRAY, MAX_ACCELERATION_M_S2, MAX_GAIN, Distance, Duration,
                                        NonNegativeDistance, Position, Rate, Speed, Velocity, _Strict)


#: (m/s^2)^2 per axis: a process noise q, at most that of a white acceleration of MAX_ACCELERATION_M_S2.
ProcessNoise = Annotated[float, Field(gt=0.0, le=MAX_ACCELERATION_M_S2**2)]
#: A bearing's noise variance the filter assumes (unit-vector units squared; sensor.noise_std is at most 10).
MeasurementNoise = Annotated[float, Field(gt=0.0, le=100.0)]


class EstimatorConfig(_Strict):
    """Target estimator. kind 'imm' (the default) is the interacting-multiple-model
    estimator over u-PLKF model filters (constant velocity and left/right coordinated turns, options
    imm_*; docs/explanation/estimation.md, "IMM estimator"): as accurate as the u-PLKF on constant-velocity targets and the
    one that follows sustained turns (docs/reproduction/manoeuvring-experiments.md, 5.6). kind 'uplkf' is the paper's
    u-PLKF (section IV) alone; gain_projection 'measured' is its exact form, 'predicted' the
    default (docs/explanation/estimation.md), 'noise_free' the simulation-only "optimal u-PLKF" of section VIII-B. The
    baselines: 'ekf' (azimuth/elevation, Cartesian state, the paper's classic EKF), 'msc_ekf'
    (modified spherical coordinates), 'ekf_rae' (seed 003: range/azimuth/elevation; needs
    [sensor] range_noise_std). initialize: 'bearing' starts on the
    first bearing at the range guess (remark 3); 'position' starts at initial_position itself with
    an isotropic initial_range_std (the initialisation study of section VIII-B)."""

    kind: Literal["uplkf", "ekf", "msc_ekf", "ekf_rae", "imm"] = "imm"
    gain_projection: Literal["predicted", "measured", "noise_free"] = "predicted"
    initialize: Literal["bearing", "position"] = "bearing"
    rate_hz: Rate = 50.0
    process_noise: ProcessNoise = 0.04
    adaptive_process_noise: bool = False
    """u-PLKF only. True: Q = s process_noise I with a scale 1 <= s <= adaptive_max_scale raised while
    the innovations are larger than the filter claims (mean NIS per degree of freedom above
    adaptive_nis_threshold) and relaxed back to 1 when they are not (docs/explanation/estimation.md;
    companion.core.estimators.AdaptiveProcessNoise). False (default): the constant Q."""
    adaptive_max_scale: float = Field(25.0, ge=1.0, le=MAX_GAIN)
    adaptive_nis_time_constant: Duration = 2.0
    """s, of the running mean of the NIS per degree of freedom."""
    adaptive_rise_time_constant: Duration = 2.0
    """s, of the scale's growth while that mean exceeds adaptive_nis_threshold."""
    adaptive_relax_time_constant: Duration = 10.0
    """s, of its return to 1 while the mean is below 1."""
    adaptive_nis_threshold: float = Field(3.0, gt=1.0, le=MAX_GAIN)
    imm_turn_rates: Annotated[tuple[float, ...], FROM_ARRAY] = (0.2, 0.4, 0.6)
    """kind 'imm' only: omega, rad/s, of the coordinated-turn models (docs/explanation/estimation.md, "IMM estimator"); each rate
    gives a right (+omega) and a left (-omega) model beside the constant-velocity one. Each in
    (0, IMM_MAX_TURN_RATE]; an empty list leaves the constant-velocity model alone (the u-PLKF)."""
    imm_turn_process_noise: ProcessNoise = 0.04
    """kind 'imm' only: q of the turn models, (m/s^2)^2 per axis (the constant-velocity model uses process_noise)."""
    imm_manoeuvre_model: bool = True
    """kind 'imm' only: add the speed-change model for a target that hovers, dashes and brakes: white-noise
    acceleration of std 2/3 target_max_acceleration along the model's own velocity (on every axis while it
    is slower than 1 m/s) and process_noise across it (companion.core.imm.manoeuvre_model). False: the
    constant-velocity and turn models alone."""
    target_max_acceleration: Annotated[float, Field(gt=0.0, le=30.0)] = 3.0
    """m/s^2: the largest acceleration (or braking) the followed target is expected to have: the IMM's
    manoeuvre model's noise, and the braking the safety envelope plans for ([safety])."""
    imm_stay_probability: float = Field(0.98, gt=0.0, le=1.0)
    """kind 'imm' only: p_ii, the probability that the target keeps its motion model over imm_stay_time s
    (seed 004: 0.98, the rest split evenly over the other models)."""
    imm_stay_time: Duration = 1.0
    """kind 'imm' only: s, the interval imm_stay_probability refers to (p_ii = p^(Delta / imm_stay_time)
    over a correction interval Delta, so the switching is the same at any bearing rate)."""
    measurement_noise: MeasurementNoise = 1e-4
    pursuer_position_std: NonNegativeDistance = 0.1
    restart_when_behind: bool = True
    initial_position: Position | None = None
    initial_range: Distance | None = None
    initial_range_std: Distance = 30.0
    initial_velocity: Velocity = (0.0, 0.0, 0.0)
    initial_velocity_std: Speed = 5.0

    @model_validator(mode="after")
    def _has_range_guess(self) -> "EstimatorConfig":
        if self.initial_position is None and self.initial_range is None:
            raise ValueError("set initial_range or initial_position (the range guess along the first bearing)")
        if self.initialize == "position" and self.initial_position is None:
            raise ValueError("initialize = 'position' needs initial_position")
        if self.adaptive_process_noise and self.kind != "uplkf":
            raise ValueError(f"adaptive_process_noise is implemented for kind = 'uplkf' only, got {self.kind!r} "
                             "(the default kind is 'imm': set kind = 'uplkf' with it)")
        for rate in self.imm_turn_rates:
            if not (math.isfinite(rate) and 0.0 < rate <= IMM_MAX_TURN_RATE):
                raise ValueError(f"imm_turn_rates: each turn rate must be in (0, {IMM_MAX_TURN_RATE:g}] rad/s, got {rate!r} "
                                 "(a rate gives both a right and a left model)")
        if len(set(self.imm_turn_rates)) != len(self.imm_turn_rates):
            raise ValueError(f"imm_turn_rates: a rate is repeated in {self.imm_turn_rates!r}")
        if self.kind != "imm":
            changed = [name for name in IMM_OPTIONS if getattr(self, name) != type(self).model_fields[name].default]
            if changed:
                raise ValueError(f"{', '.join(changed)} applies to kind = 'imm' only, not to kind = {self.kind!r}")
        return self


IMM_MAX_TURN_RATE = 2.0
"""rad/s: the largest turn rate an IMM model may assume (a 2 m/s^2 turn at 1 m/s; a multirotor target
turning faster is hovering, which the constant-velocity model covers)."""
IMM_OPTIONS = ("imm_turn_rates", "imm_turn_process_noise", "imm_stay_probability", "imm_stay_time", "imm_manoeuvre_model")
