"""[dropout], [safety] and [health]: the companion's degraded modes, envelope and filter-health monitor."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from interfaces.link_schema import HealthReason
from interfaces.scenario.common import (FROM_ARRAY, MAX_GAIN, Distance, Duration, NonNegativeDistance,
                                        NonNegativeDuration, NonNegativeSpeed, _Strict)


class DropoutConfig(_Strict):
    """What the companion does when bearings stop and come back (companion.core.pipeline.DropoutPolicy).

    coast_after / coast_limit: s without a bearing before coasting / before the safe
    behaviour (hold safe_range on the predicted line of sight, no weave, never closing while
    the predicted range minus 2 sigma is under min_range). max_position_std: m, while
    coasting the safe behaviour also starts when the prediction gets this uncertain.
    gate_sigma, reacquire_bearings, restart_range_std: re-acquisition gate and restart.
    max_jerk (m/s^3) and blend_time (s): how fast the command may change after a mode change.
    safe_range / min_range default to 1.5 and 0.5 times guidance.desired_range.
    """

    coast_after: Duration = 0.6
    coast_limit: Duration = 3.0
    max_position_std: Distance = 6.0
    safe_range: Distance | None = None
    min_range: Distance | None = None
    gate_sigma: Annotated[float, Field(gt=0.0, le=100.0)] = 4.0
    reacquire_bearings: Annotated[int, Field(ge=1, le=10_000)] = 2
    restart_range_std: Distance = 10.0
    max_jerk: Annotated[float, Field(gt=0.0, le=1000.0)] = 15.0
    blend_time: NonNegativeDuration = 2.0

    @model_validator(mode="after")
    def _ordered(self) -> "DropoutConfig":
        if self.coast_after > self.coast_limit:
            raise ValueError("coast_after must not exceed coast_limit")
        return self


class SafetyConfig(_Strict):
    """The safety envelope applied to every command (companion.core.safety.SafetyEnvelope), whatever the estimate.

    enabled: False flies the guidance laws' commands as they are (for studies of the laws alone). The closest
    the pursuer may come is [dropout] min_range (r_d / 2 by default). range_sigmas: k of the pessimistic range
    r^ - k sigma_r; speed_sigmas: of the target's speed away from us, v^_T . lambda - k sigma_v.
    braking_acceleration: m/s^2 the pursuer plans to brake with; default half
    of g tan(max_tilt) of the airframe. reaction_time: s until braking takes effect. velocity_gain: 1/s.
    max_yaw_rate_deg: deg/s, the setpoint heading's largest rate of turn. untrusted_range_share: the share of
    the pessimistic range counted on while the estimate is a prediction without bearings (degraded, reacquiring).
    tilt_margin_deg: deg, the setpoints' tilt limit is the airframe's max_tilt_deg less this. The
    target's largest deceleration is [estimator] target_max_acceleration. estimate_latency: s the estimate may
    lag a target that starts braking: taken off the target's credited stopping distance (u_T t_e) and added to
    reaction_time; 0 (default) counts on the estimate showing the braking at once (docs/safety.md).
    speed_change_latency: s, the estimate_latency planned with only while the target has lately changed speed
    (0: never): for speed_change_memory s after the IMM's speed-change models last held at least
    speed_change_trigger of its model probability while the estimated target speed stood at least
    speed_change_speed m/s from its average over speed_change_window s (0: the probability alone); needs
    [estimator] kind 'imm' with imm_manoeuvre_model, and is 1 s by default with it, 0 without it
    (interfaces.derived_defaults). hover_standoff: m added to min_range while the target is slow (0: never), in
    full at rest, falling linearly to 0 at an estimated target speed of hover_speed m/s: a hovering target may
    leave straight at the pursuer, which the bearings show late; by default the distance a target at [estimator]
    target_max_acceleration covers from rest in 2 s (6 m at 3 m/s^2). loop_delay_memory: s for which a delay of
    the networked companion's control loop it measured (the vehicle flew a setpoint longer than the control
    period) is added to reaction_time (0: never).
    """

    enabled: bool = True
    range_sigmas: Annotated[float, Field(ge=0.0, le=10.0)] = 2.0
    speed_sigmas: Annotated[float, Field(ge=0.0, le=10.0)] = 0.0
    braking_acceleration: Annotated[float, Field(gt=0.0, le=30.0)] | None = None
    reaction_time: Annotated[float, Field(ge=0.0, le=5.0)] = 0.3
    velocity_gain: Annotated[float, Field(gt=0.0, le=20.0)] = 2.0
    max_yaw_rate_deg: Annotated[float, Field(gt=0.0, le=1000.0)] = 45.0
    untrusted_range_share: Annotated[float, Field(gt=0.0, le=1.0)] = 1.0
    tilt_margin_deg: Annotated[float, Field(ge=0.0, lt=20.0)] = 3.0
    estimate_latency: Annotated[float, Field(ge=0.0, le=5.0)] = 0.0
    speed_change_latency: Annotated[float, Field(ge=0.0, le=5.0)] | None = None
    speed_change_memory: Annotated[float, Field(ge=0.0, le=3600.0)] = 30.0
    speed_change_trigger: Annotated[float, Field(gt=0.0, le=1.0)] = 0.5
    speed_change_speed: Annotated[float, Field(ge=0.0, le=50.0)] = 1.0
    speed_change_window: Annotated[float, Field(gt=0.0, le=60.0)] = 1.0
    hover_standoff: Annotated[float, Field(ge=0.0, le=100.0)] | None = None
    hover_speed: Annotated[float, Field(gt=0.0, le=50.0)] = 1.0
    loop_delay_memory: Annotated[float, Field(ge=0.0, le=3600.0)] = 10.0


HealthReasonName = HealthReason  # the monitor's reasons, as the link payloads name them


class HealthSection(_Strict):
    """The filter-health monitor (companion.core.health: HealthConfig, HealthActionConfig; docs/explanation/estimation.md, "Filter health").

    Monitor: nis_window s, nis_probability, nis_scale, min_nis_samples, max_relative_range_std,
    max_range_std m (sigma_r limit once the range has converged; a large value turns it off),
    min_range m (default guidance.desired_range / 4), max_range m, slow_speed m/s,
    unobservable_time s, flag_after s, clear_after s, speed_change_probability (the IMM's probability on its
    speed-change models that raises the reason speed_change; unset: not used), speed_change_time s (how long it
    must hold), speed_change_clear s (how long after it SUSPECT may clear when it was the only reason). Actions while suspect: act (default true; false: the
    monitor only reports), process_noise_boost (factor on Q, >= 1) relaxing back to 1 with
    boost_relax_time s once OK, reinitialize_reasons (restart on the bearing at the current range
    with an along-bearing std of reinitialize_relative_std x that range, at most every
    reinitialize_interval s), excite (full range excitation while suspect; without
    [guidance] excitation, also never a stop while sigma_r / r^ > excitation_high, ramping in
    from excitation_low; lateral laws 'hng' and 'ppg' only), boost_reasons (the raised conditions that
    call for the Q boost), boost_follows_evidence (full boost only
    while a condition is raised, relaxing during the SUSPECT tail).
    """

    nis_window: Duration = 5.0
    nis_probability: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.999
    nis_scale: Annotated[float, Field(ge=1.0, le=MAX_GAIN)] = 1.5
    min_nis_samples: Annotated[int, Field(ge=1, le=100_000)] = 10
    max_relative_range_std: Annotated[float, Field(gt=0.0, le=100.0)] = 1.0
    max_range_std: Distance | None = 2.0
    min_range: NonNegativeDistance | None = None
    max_range: Distance = 2000.0
    slow_speed: NonNegativeSpeed = 1.0
    unobservable_time: NonNegativeDuration = 5.0
    flag_after: NonNegativeDuration = 3.0
    clear_after: NonNegativeDuration = 10.0
    speed_change_probability: Annotated[float, Field(gt=0.0, le=1.0)] | None = None
    speed_change_time: NonNegativeDuration = 0.5
    speed_change_clear: NonNegativeDuration = 3.0
    act: bool = True
    process_noise_boost: Annotated[float, Field(ge=1.0, le=MAX_GAIN)] = 30.0
    boost_relax_time: Duration = 5.0
    reinitialize_reasons: Annotated[tuple[HealthReasonName, ...], FROM_ARRAY] = ("behind_sensor", "range_implausible")
    reinitialize_interval: NonNegativeDuration = 20.0
    reinitialize_relative_std: Annotated[float, Field(gt=0.0, le=100.0)] = 0.5
    excite: bool = True
    excitation_low: Annotated[float, Field(ge=0.0, le=100.0)] = 0.25
    excitation_high: Annotated[float, Field(gt=0.0, le=100.0)] = 0.5
    boost_follows_evidence: bool = True
    boost_reasons: Annotated[tuple[HealthReasonName, ...], FROM_ARRAY] = ("nis", "behind_sensor", "range_implausible")

    @model_validator(mode="after")
    def _ordered(self) -> "HealthSection":
        if self.min_range is not None and self.min_range >= self.max_range:
            raise ValueError("min_range must be below max_range")
        if self.excitation_low >= self.excitation_high:
            raise ValueError("excitation_low must be below excitation_high")
        return self
