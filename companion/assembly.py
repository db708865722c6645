"""Build the pipeline a scenario describes (used by both harnesses)."""

from __future__ import annotations

import numpy as np

from companion.core.attitude import VehicleLimits
from interfaces.scenario import ConfigError, Scenario, SensorConfig, VehicleConfig
from companion.core.bearing_sensor import BearingSensor, CameraModel
from companion.core.baseline_estimators import AzElEKF, MSCEKF, RangeAzElEKF
from companion.core.baseline_guidance import (PDFollowingController, ProportionalNavigationGuidance,
                                         RetroProportionalNavigationGuidance, ZEMObservabilityGuidance)
from companion.core.estimators import GainProjection, InitialGuess, TargetEstimator, UPLKF
from companion.core.guidance import HelicalNavigationGuidance, LateralGuidance, PurePursuitGuidance, RangeController
from companion.core.pipeline import DropoutPolicy, FollowingPipeline


def build_sensor(config: SensorConfig) -> BearingSensor:
    """The bearing sensor a scenario's [sensor] section describes (eq. (4), eq. (25) or the camera)."""
    if config.model != "camera":
        return BearingSensor(config.model, config.noise_std, range_noise_std=config.range_noise_std)
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


def build_estimator(scenario: Scenario) -> TargetEstimator:
    """The estimator of the scenario's [estimator] section: the u-PLKF or a baseline of section VIII-B."""
    settings = scenario.estimator
    period = 1.0 / settings.rate_hz
    process_noise = settings.process_noise * np.eye(3)
    measurement_noise = settings.measurement_noise * np.eye(3)
    if settings.kind == "ekf":
        return AzElEKF(period, process_noise, measurement_noise, pursuer_position_std=settings.pursuer_position_std,
                       restart_when_behind=settings.restart_when_behind)
    if settings.kind == "msc_ekf":
        return MSCEKF(period, process_noise, measurement_noise, pursuer_position_std=settings.pursuer_position_std,
                      restart_when_behind=settings.restart_when_behind)
    if settings.kind == "ekf_rae":
        assert scenario.sensor.range_noise_std is not None  # the Scenario validator guarantees it
        return RangeAzElEKF(period, measurement_noise=measurement_noise,
                            range_noise_std=max(scenario.sensor.range_noise_std, 1e-3),
                            pursuer_position_std=settings.pursuer_position_std)
    return UPLKF(
        period=period,
        process_noise=process_noise,
        measurement_noise=measurement_noise,
        gain_projection=GainProjection(settings.gain_projection),
        pursuer_position_std=settings.pursuer_position_std,
        restart_when_behind=settings.restart_when_behind,
    )


def build_lateral_guidance(scenario: Scenario) -> LateralGuidance:
    """The [guidance] law: HNG (eq. 14) or a baseline of section VIII-C."""
    settings = scenario.guidance
    if settings.law == "ppg":
        return PurePursuitGuidance(settings.navigation_gain)
    if settings.law == "png":
        return ProportionalNavigationGuidance(settings.navigation_gain)
    if settings.law == "pd":
        return PDFollowingController(settings.pd_kp, settings.pd_kd, settings.desired_range)
    if settings.law == "retro_png":
        return RetroProportionalNavigationGuidance(settings.retro_gain)
    if settings.law == "zem":
        return ZEMObservabilityGuidance(settings.zem_k_w, settings.zem_max_gain, settings.desired_range)
    return HelicalNavigationGuidance(settings.navigation_gain, settings.c_z, settings.c_y, settings.weave_frequency, settings.scale_with_range)


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


def build_pipeline(scenario: Scenario, vehicle: VehicleConfig, hover_thrust_normalized: float) -> FollowingPipeline:
    """The one pipeline object both harnesses drive."""
    return FollowingPipeline(
        estimator=build_estimator(scenario),
        lateral_guidance=build_lateral_guidance(scenario),
        range_controller=RangeController(scenario.guidance.desired_range, scenario.guidance.range_gain),
        limits=vehicle_limits(vehicle, hover_thrust_normalized),
        initial_guess=initial_guess(scenario),
        control_period=1.0 / scenario.guidance.rate_hz,
        los_source=scenario.guidance.los_source,
        dropout=dropout_policy(scenario),
    )


def dropout_policy(scenario: Scenario) -> DropoutPolicy:
    """The [dropout] section; safe/min range default to 1.5 / 0.5 x the desired range."""
    settings = scenario.dropout
    desired = scenario.guidance.desired_range
    try:
        return DropoutPolicy(
            coast_after=settings.coast_after, coast_limit=settings.coast_limit, max_position_std=settings.max_position_std,
            safe_range=settings.safe_range if settings.safe_range is not None else 1.5 * desired,
            min_range=settings.min_range if settings.min_range is not None else 0.5 * desired,
            gate_sigma=settings.gate_sigma, bearing_noise_std=max(scenario.sensor.noise_std, 1e-3),
            reacquire_bearings=settings.reacquire_bearings, restart_range_std=settings.restart_range_std,
            max_jerk=settings.max_jerk, blend_time=settings.blend_time)
    except ValueError as error:
        raise ConfigError(f"dropout: {error}") from None
