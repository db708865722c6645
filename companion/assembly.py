"""Build the pipeline a scenario describes (used by both harnesses).

The one bridge from a scenario to core objects. Each choice the schema offers as a Literal
(sensor model, estimator kind, guidance law) is a registry from that literal to a small
factory, so adding a baseline is one entry.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.core.attitude import VehicleLimits
from interfaces.derived_defaults import (EXCITED_LAWS, SAFETY_BRAKING_SHARE, SAFETY_MAX_BRAKING_SHARE, dropout_min_range,
                                         default_excitation, dropout_safe_range, health_min_range,
                                         safety_speed_change_latency)
from interfaces.scenario import (ConfigError, EstimatorConfig, GuidanceConfig, PursuerStart, Scenario, SensorConfig,
                                 VehicleConfig)
from companion.core.bearing_sensor import BearingSensor, CameraModel, RangeDependentVariance
from companion.core.baseline_estimators import AzElEKF, MSCEKF, RangeAzElEKF
from companion.core.baseline_guidance import (PDFollowingController, ProportionalNavigationGuidance,
                                         RetroProportionalNavigationGuidance, Seed003BacksteppingGuidance,
                                         ZEMObservabilityGuidance)
from companion.core.estimators import AdaptiveNoiseSettings, GainProjection, InitialGuess, TargetEstimator, UPLKF
from companion.core.guidance import (HelicalNavigationGuidance, LateralGuidance, PurePursuitGuidance, RangeController,
                                     RangeExcitation)
from companion.core.health import HealthActionConfig, HealthActionPolicy, HealthConfig, HealthMonitor
from companion.core.imm import IMMEstimator, standard_models
from companion.core.safety import SafetyEnvelope
from companion.core.cooperative_estimation import FusionEstimator, TriangulationKalmanEstimator
from companion.core.cooperative_guidance import CircumnavigationGuidance, SeparationFilter, StandoffTrackingGuidance
from companion.core.pipeline import Cooperation, DropoutPolicy, FollowingPipeline


def _camera_sensor(config: SensorConfig) -> BearingSensor:
    """The pin-hole camera of section VIII ([sensor.camera]; noise_std unused)."""
    settings = config.camera
    roll, pitch, yaw = np.radians(settings.mount_rpy_deg)
    camera = CameraModel.with_mount_angles(
        float(roll), float(pitch), float(yaw),
        focal_length=settings.focal_length,
        pixel_width=settings.pixel_size[0],
        pixel_height=settings.pixel_size[1],
        principal_point=tuple(settings.principal_point),
        image_size=tuple(settings.image_size),
        pixel_noise_std=settings.pixel_noise_std,
    )
    return BearingSensor("camera", config.noise_std, camera, config.range_noise_std)


def _direction_noise_sensor(config: SensorConfig) -> BearingSensor:
    """Direction noise added to the true line of sight: eq. (4) ('additive') or eq. (25) ('rotation'),
    white by default; coloured and/or range-dependent (seed 003 cases 2 and 3) when configured."""
    dependent = config.range_dependent_noise
    return BearingSensor(config.model, config.noise_std, range_noise_std=config.range_noise_std,
                         noise_time_constant=config.noise_time_constant, sample_period=1.0 / config.rate_hz,
                         range_dependent=None if dependent is None else RangeDependentVariance(
                             dependent.a0, dependent.a1, dependent.a2, dependent.alpha))


#: [sensor] model -> the sensor it builds. Keys are exactly SensorConfig.model's Literal values.
SENSORS: dict[str, Callable[[SensorConfig], BearingSensor]] = {
    "additive": _direction_noise_sensor,
    "rotation": _direction_noise_sensor,
    "camera": _camera_sensor,
}


def build_sensor(config: SensorConfig) -> BearingSensor:
    """The bearing sensor a scenario's [sensor] section describes (eq. (4), eq. (25) or the camera)."""
    return SENSORS[config.model](config)


@dataclass(frozen=True)
class EstimatorSettings:
    """What every estimator factory receives, derived once from [estimator] (and [sensor]).

    period: 1 / rate_hz, s. process_noise: Q = process_noise I, (m/s^2)^2, shape (3, 3).
    measurement_noise: Sigma = measurement_noise I of eq. (4), shape (3, 3).
    """

    scenario: Scenario
    period: float
    process_noise: np.ndarray
    measurement_noise: np.ndarray

    @property
    def config(self) -> EstimatorConfig:
        return self.scenario.estimator


def _uplkf(s: EstimatorSettings) -> TargetEstimator:
    """The paper's u-PLKF (section IV) with the configured gain projection (and, opt-in, adaptive Q)."""
    c = s.config
    adaptive = AdaptiveNoiseSettings(c.adaptive_max_scale, c.adaptive_nis_time_constant, c.adaptive_rise_time_constant,
                                     c.adaptive_relax_time_constant, c.adaptive_nis_threshold) \
        if c.adaptive_process_noise else None
    return UPLKF(period=s.period, process_noise=s.process_noise, measurement_noise=s.measurement_noise,
                 gain_projection=GainProjection(c.gain_projection),
                 pursuer_position_std=c.pursuer_position_std, restart_when_behind=c.restart_when_behind,
                 adaptive_noise=adaptive)


def _azel_ekf(s: EstimatorSettings) -> TargetEstimator:
    """The classic azimuth/elevation EKF of section VIII-B (Cartesian state)."""
    return AzElEKF(s.period, s.process_noise, s.measurement_noise, pursuer_position_std=s.config.pursuer_position_std,
                   restart_when_behind=s.config.restart_when_behind)


def _msc_ekf(s: EstimatorSettings) -> TargetEstimator:
    """The modified-spherical-coordinates EKF of section II-A."""
    return MSCEKF(s.period, s.process_noise, s.measurement_noise, pursuer_position_std=s.config.pursuer_position_std,
                  restart_when_behind=s.config.restart_when_behind)


def _range_azel_ekf(s: EstimatorSettings) -> TargetEstimator:
    """Seed 003's range/azimuth/elevation EKF; the Scenario validator guarantees a range sensor."""
    range_noise_std = s.scenario.sensor.range_noise_std
    assert range_noise_std is not None
    return RangeAzElEKF(s.period, measurement_noise=s.measurement_noise, range_noise_std=max(range_noise_std, 1e-3),
                        pursuer_position_std=s.config.pursuer_position_std)


def _imm(s: EstimatorSettings) -> TargetEstimator:
    """The interacting-multiple-model estimator (companion.core.imm): constant velocity with Q = process_noise I,
    a right and a left coordinated turn (Q = imm_turn_process_noise I) per imm_turn_rates entry, and with
    imm_manoeuvre_model the manoeuvre model of target_max_acceleration (imm.manoeuvre_model)."""
    c = s.config
    models = standard_models(c.imm_turn_rates, c.process_noise, c.imm_turn_process_noise,
                             c.target_max_acceleration if c.imm_manoeuvre_model else None)
    return IMMEstimator(s.period, models, s.measurement_noise, gain_projection=GainProjection(c.gain_projection),
                        pursuer_position_std=c.pursuer_position_std, restart_when_behind=c.restart_when_behind,
                        stay_probability=c.imm_stay_probability, stay_time=c.imm_stay_time)


#: [estimator] kind -> its factory. Keys are exactly EstimatorConfig.kind's Literal values;
#: a new baseline is one entry here and one value in the schema's Literal.
ESTIMATORS: dict[str, Callable[[EstimatorSettings], TargetEstimator]] = {
    "uplkf": _uplkf,
    "ekf": _azel_ekf,
    "msc_ekf": _msc_ekf,
    "ekf_rae": _range_azel_ekf,
    "imm": _imm,
}


def build_estimator(scenario: Scenario) -> TargetEstimator:
    """The estimator of the scenario's [estimator] section: the u-PLKF or a baseline of section VIII-B.
    (The companion compiles the kernels before it opens any link, `companion.app`; studies before they start
    workers, `studies.executors.compile_kernels`; elsewhere numba compiles each kernel on its first call.)"""
    settings = scenario.estimator
    derived = EstimatorSettings(scenario, period=1.0 / settings.rate_hz,
                                process_noise=settings.process_noise * np.eye(3),
                                measurement_noise=settings.measurement_noise * np.eye(3))
    return ESTIMATORS[settings.kind](derived)


#: [guidance] law -> its factory. Keys are exactly GuidanceConfig.law's Literal values.
LATERAL_GUIDANCE: dict[str, Callable[[GuidanceConfig], LateralGuidance]] = {
    "hng": lambda g: HelicalNavigationGuidance(g.navigation_gain, g.c_z, g.c_y, g.weave_frequency, g.scale_with_range),
    "ppg": lambda g: PurePursuitGuidance(g.navigation_gain),
    "png": lambda g: ProportionalNavigationGuidance(g.navigation_gain),
    "pd": lambda g: PDFollowingController(g.pd_kp, g.pd_kd, g.desired_range),
    "retro_png": lambda g: RetroProportionalNavigationGuidance(g.retro_gain),
    "zem": lambda g: ZEMObservabilityGuidance(g.zem_k_w, g.zem_max_gain, g.desired_range),
    "seed003": lambda g: Seed003BacksteppingGuidance(g.seed003_alpha, g.seed003_gain, g.desired_range,
                                                           g.seed003_max_approach_speed),
}


def build_lateral_guidance(scenario: Scenario) -> LateralGuidance:
    """The [guidance] law: HNG (eq. 14), a baseline of section VIII-C or seed 003's law."""
    return LATERAL_GUIDANCE[scenario.guidance.law](scenario.guidance)


def build_range_controller(scenario: Scenario) -> RangeController:
    """The range controller of eq. (15)-(19). The schema has no choice of range controller: every law
    but 'pd' (whose class says includes_range_control) gets this longitudinal term, and the dropout
    policy's safe behaviour uses it for every law."""
    return RangeController(scenario.guidance.desired_range, scenario.guidance.range_gain)


def build_excitation(scenario: Scenario) -> RangeExcitation | None:
    """[guidance] excitation (left out, its default for the law and the estimator: default_excitation): None for
    'none' (the paper's law unchanged), else the RangeExcitation with the lateral law's navigation gain as the
    damping it cancels."""
    g = scenario.guidance
    mode = g.excitation if g.excitation is not None else default_excitation(g.law, scenario.estimator.kind)
    if mode == "none":
        return None
    return RangeExcitation(g.excitation_speed, g.navigation_gain, g.excitation_frequency, g.excitation_low,
                           g.excitation_high)


def initial_guess(scenario: Scenario) -> InitialGuess:
    """Range guess along the first bearing: initial_range, else |initial_position - pursuer start|."""
    settings = scenario.estimator
    if settings.initial_range is not None:
        guess_range = settings.initial_range
    else:
        assert settings.initial_position is not None
        guess_range = float(np.linalg.norm(np.subtract(settings.initial_position, scenario.pursuer.initial_position)))
    start = np.array(settings.initial_position, dtype=float) if settings.initialize == "position" else None
    return InitialGuess(guess_range, settings.initial_range_std, np.array(settings.initial_velocity), settings.initial_velocity_std,
                        position=start)


def vehicle_limits(vehicle: VehicleConfig, hover_thrust_normalized: float) -> VehicleLimits:
    """What the companion may ask of the airframe; hover thrust comes from the autopilot."""
    return VehicleLimits(
        hover_thrust_normalized=hover_thrust_normalized,
        max_tilt=np.deg2rad(vehicle.max_tilt_deg),
        gravity=vehicle.gravity,
        mass=vehicle.mass,
    )


def build_pipeline(scenario: Scenario, vehicle: VehicleConfig, hover_thrust_normalized: float,
                   pursuer_id: int = 1) -> FollowingPipeline:
    """The one pipeline object both harnesses drive (pursuer_id: which pursuer of a [swarm] flies it)."""
    return FollowingPipeline(
        estimator=build_swarm_estimator(scenario),
        lateral_guidance=build_lateral_guidance(scenario),
        range_controller=build_range_controller(scenario),
        limits=vehicle_limits(vehicle, hover_thrust_normalized),
        initial_guess=initial_guess(scenario),
        control_period=1.0 / scenario.guidance.rate_hz,
        los_source=scenario.guidance.los_source,
        dropout=dropout_policy(scenario),
        excitation=build_excitation(scenario),
        health=HealthMonitor(health_config(scenario)),
        actions=HealthActionPolicy(health_action_config(scenario)),
        action_excitation=build_action_excitation(scenario),
        cooperation=build_cooperation(scenario, pursuer_id),
        envelope=safety_envelope(scenario, vehicle),
    )


def safety_envelope(scenario: Scenario, vehicle: VehicleConfig) -> SafetyEnvelope | None:
    """[safety] as the pipeline's SafetyEnvelope (None when disabled): the closest approach is the dropout
    policy's min_range (r_d / 2 by default), the target's braking [estimator] target_max_acceleration, and
    the pursuer's own braking, unless given, half of g tan(max_tilt) planned and 0.9 g tan(max_tilt) at most."""
    settings = scenario.safety
    if not settings.enabled:
        return None
    speed_change_model = scenario.estimator.kind == "imm" and scenario.estimator.imm_manoeuvre_model
    speed_change_latency = settings.speed_change_latency
    if speed_change_latency is None:
        speed_change_latency = safety_speed_change_latency(speed_change_model)
    elif speed_change_latency > 0.0 and not speed_change_model:
        raise ConfigError("safety: speed_change_latency needs the speed-change model: [estimator] kind = 'imm' with "
                          f"imm_manoeuvre_model = true (got kind {scenario.estimator.kind!r})")
    tilt_limited = vehicle.gravity * math.tan(math.radians(vehicle.max_tilt_deg))
    braking = settings.braking_acceleration if settings.braking_acceleration is not None else SAFETY_BRAKING_SHARE * tilt_limited
    try:
        return SafetyEnvelope(min_range=dropout_policy(scenario).min_range,
                              target_max_acceleration=scenario.estimator.target_max_acceleration,
                              braking_acceleration=braking,
                              max_braking_acceleration=max(SAFETY_MAX_BRAKING_SHARE * tilt_limited, braking), range_sigmas=settings.range_sigmas,
                              speed_sigmas=settings.speed_sigmas,
                              reaction_time=settings.reaction_time, velocity_gain=settings.velocity_gain,
                              max_yaw_rate=math.radians(settings.max_yaw_rate_deg),
                              untrusted_range_share=settings.untrusted_range_share,
                              tilt_margin=math.radians(settings.tilt_margin_deg),
                              estimate_latency=settings.estimate_latency,
                              speed_change_latency=speed_change_latency,
                              speed_change_memory=settings.speed_change_memory,
                              speed_change_trigger=settings.speed_change_trigger,
                              speed_change_speed=settings.speed_change_speed,
                              speed_change_window=settings.speed_change_window,
                              hover_standoff=settings.hover_standoff, hover_speed=settings.hover_speed,
                              loop_delay_memory=settings.loop_delay_memory)
    except ValueError as error:
        raise ConfigError(f"safety: {error}") from None


def pursuer_scenario(scenario: Scenario, start: PursuerStart) -> Scenario:
    """`scenario` as pursuer `start.ident` flies it: [pursuer] is its start and [estimator] initial_position
    its own range guess's point ([swarm.pursuers]); unchanged for a scenario without [swarm]."""
    if scenario.swarm is None:
        return scenario
    pursuer = scenario.pursuer.model_copy(update={"initial_position": tuple(start.initial_position),
                                                  "initial_velocity": tuple(start.initial_velocity)})
    update = {"pursuer": pursuer}
    if start.estimator_initial_position is not None:
        update["estimator"] = scenario.estimator.model_copy(
            update={"initial_position": tuple(start.estimator_initial_position)})
    return scenario.model_copy(update=update)


#: Separation filter limits: within what the Table I airframe realises horizontally at its 35 degree tilt
#: (g tan 35 deg = 6.9 m/s^2), braking at half of it.
SEPARATION_MAX_ACCELERATION = 6.0
SEPARATION_BRAKING = 3.0


#: A lone pursuer's layer: its orbit radius grows by LONE_LAYER x min_separation x its id.
LONE_LAYER = 1.5


def build_cooperation(scenario: Scenario, pursuer_id: int = 1) -> Cooperation | None:
    """[swarm]'s guidance as the pipeline's Cooperation of pursuer `pursuer_id`: the cooperative law (None for
    'hng'), its lone layer (the same law on an orbit LONE_LAYER x min_separation x pursuer_id larger: pursuers
    that hear nobody each fly their own circle, clear of the others' by at least 1.5 min_separation), the
    separation filter, and HNG's weave switch (off while a neighbour's line of sight is weave_min_angle_deg
    from ours). None without [swarm]."""
    swarm = scenario.swarm
    if swarm is None:
        return None
    g = scenario.guidance
    law = None
    if swarm.guidance == "circumnavigation":
        c = swarm.circumnavigation
        law = CircumnavigationGuidance(desired_radius=g.desired_range, g1=c.g1, g2=c.g2, g3=c.g3, alpha=c.alpha,
                                       altitude_offset=c.altitude_offset, velocity_gain=c.velocity_gain,
                                       max_acceleration=c.max_acceleration)
    elif swarm.guidance == "standoff":
        t = swarm.standoff
        law = StandoffTrackingGuidance(standoff_radius=t.radius, min_turn_radius=t.inner_radius, speed=t.speed,
                                       min_speed=t.min_speed, max_speed=t.max_speed, phase_gain=t.phase_gain,
                                       standoff_height=t.height, max_vertical_speed=t.max_vertical_speed,
                                       max_vertical_acceleration=t.max_vertical_acceleration,
                                       velocity_gain=t.velocity_gain, max_acceleration=t.max_acceleration)
    lone = None
    if law is not None and swarm.count > 1:  # one pursuer alone has nobody to keep clear of: the single laws
        layer = LONE_LAYER * swarm.min_separation * pursuer_id
        lone = (dataclasses.replace(law, desired_radius=law.desired_radius + layer)
                if isinstance(law, CircumnavigationGuidance)
                else dataclasses.replace(law, standoff_radius=law.standoff_radius + layer))
    steady = PurePursuitGuidance(g.navigation_gain) if g.law == "hng" else None
    separation = SeparationFilter(swarm.min_separation, max_acceleration=SEPARATION_MAX_ACCELERATION,
                                  braking_acceleration=SEPARATION_BRAKING)
    return Cooperation(law=law, separation=separation, lone_law=lone,
                       weave_min_angle=None if steady is None else float(np.radians(swarm.weave_min_angle_deg)),
                       steady_guidance=steady)


def build_swarm_estimator(scenario: Scenario) -> TargetEstimator:
    """[swarm] estimator: 'triangulation_kf' is seed 002's Kalman enhancement on triangulated bearing pairs
    ([swarm.triangulation]: Q = process_noise I9 per step, R = measurement_noise I3); 'fusion' is the
    [estimator] section's filter inside a FusionEstimator ([swarm.fusion] method; the harness hands its
    `absorb` the neighbours' shared estimates as they arrive, at most neighbour_timeout_s old); every other
    choice flies the [estimator] section's filter (fed the neighbours' bearings or not: the harness decides)."""
    swarm = scenario.swarm
    if swarm is None or swarm.estimator == "own":
        return build_estimator(scenario)
    if swarm.estimator == "fusion":
        # the own [estimator] filter on the own bearings, absorbing the neighbours' shared estimates
        if scenario.estimator.kind not in ("uplkf", "imm"):
            raise ConfigError(f"[swarm] estimator = 'fusion' needs [estimator] kind 'uplkf' or 'imm', "
                              f"not {scenario.estimator.kind!r}")
        method = {"covariance_intersection": "ci", "seed004": "seed004"}[swarm.fusion.method]
        return FusionEstimator(build_estimator(scenario), method, max_age_s=swarm.neighbour_timeout_s)
    if swarm.estimator == "shared_bearings":
        # The u-PLKF and the IMM (whose model filters are u-PLKFs) take a neighbour's bearing as it is: the
        # pseudo-linear measurement stacks naturally over sources. The baselines' EKF corrections do not.
        if scenario.estimator.kind not in ("uplkf", "imm"):
            raise ConfigError(f"[swarm] estimator = 'shared_bearings' needs [estimator] kind 'uplkf' or 'imm', "
                              f"not {scenario.estimator.kind!r}")
        return build_estimator(scenario)
    t = swarm.triangulation
    return TriangulationKalmanEstimator(1.0 / scenario.estimator.rate_hz, process_noise=t.process_noise,
                                        measurement_noise=t.measurement_noise,
                                        bearing_noise_std=max(scenario.sensor.noise_std, 1e-4))


def health_config(scenario: Scenario) -> HealthConfig:
    """The [health] section's monitor thresholds; the plausible range starts at guidance.desired_range / 4 by default."""
    h = scenario.health
    min_range = h.min_range if h.min_range is not None else health_min_range(scenario.guidance.desired_range)
    try:
        return HealthConfig(nis_window=h.nis_window, nis_probability=h.nis_probability, nis_scale=h.nis_scale,
                            min_nis_samples=h.min_nis_samples, max_relative_range_std=h.max_relative_range_std,
                            max_range_std=h.max_range_std,
                            min_range=min_range, max_range=h.max_range, slow_speed=h.slow_speed,
                            unobservable_time=h.unobservable_time, flag_after=h.flag_after, clear_after=h.clear_after,
                            speed_change_probability=h.speed_change_probability,
                            speed_change_time=h.speed_change_time, speed_change_clear=h.speed_change_clear)
    except ValueError as error:
        raise ConfigError(f"health: {error}") from None


def health_action_config(scenario: Scenario) -> HealthActionConfig:
    """The [health] section's actions (act, Q boost, re-initialisation, excitation)."""
    h = scenario.health
    return HealthActionConfig(act=h.act, process_noise_boost=h.process_noise_boost, boost_relax_time=h.boost_relax_time,
                              reinitialize_reasons=tuple(h.reinitialize_reasons),
                              reinitialize_interval=h.reinitialize_interval,
                              reinitialize_relative_std=h.reinitialize_relative_std, excite=h.excite,
                              excitation_low=h.excitation_low, excitation_high=h.excitation_high,
                              boost_follows_evidence=h.boost_follows_evidence,
                              boost_reasons=tuple(h.boost_reasons))


def build_action_excitation(scenario: Scenario) -> RangeExcitation | None:
    """The excitation the health actions fly when [guidance] has none: [guidance] excitation_speed and
    excitation_frequency, the lateral law's gain as its damping, [health] excitation_low/high as its
    thresholds. None for lateral laws it was not designed for (only 'hng' and 'ppg')."""
    g, h = scenario.guidance, scenario.health
    if g.law not in EXCITED_LAWS or not h.act or not h.excite:
        return None
    return RangeExcitation(g.excitation_speed, g.navigation_gain, g.excitation_frequency, h.excitation_low,
                           h.excitation_high)


def dropout_policy(scenario: Scenario) -> DropoutPolicy:
    """The [dropout] section; safe/min range default to 1.5 / 0.5 x the desired range."""
    settings = scenario.dropout
    desired = scenario.guidance.desired_range
    try:
        return DropoutPolicy(
            coast_after=settings.coast_after, coast_limit=settings.coast_limit, max_position_std=settings.max_position_std,
            safe_range=settings.safe_range if settings.safe_range is not None else dropout_safe_range(desired),
            min_range=settings.min_range if settings.min_range is not None else dropout_min_range(desired),
            gate_sigma=settings.gate_sigma, bearing_noise_std=max(scenario.sensor.noise_std, 1e-3),
            reacquire_bearings=settings.reacquire_bearings, restart_range_std=settings.restart_range_std,
            max_jerk=settings.max_jerk, blend_time=settings.blend_time)
    except ValueError as error:
        raise ConfigError(f"dropout: {error}") from None
