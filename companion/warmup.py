"""Warm-up of companion.core's numeric kernels: compile every kernel (or load it from numba's cache) before a
flight, so that no estimator update or control tick waits for the compiler.

This lives beside the app, outside companion.core: it imports every core module that has kernels, and
companion.core._jit, which they all import, must import none of them. The app (companion.app) and the studies'
executors (studies.executors.compile_kernels) call `warm_up`.
"""

from __future__ import annotations

import numpy as np

from companion.core._jit import ENABLED

_warmed_up = False


def pending() -> bool:
    """Whether `warm_up` still has work in this process: numba is in use and the kernels are not compiled or loaded
    yet (the caller may say so before a wait that takes minutes on an empty cache)."""
    return ENABLED and not _warmed_up


def warm_up() -> None:
    """Compile every estimator and setpoint kernel now (or load it from numba's cache on disk), once per process,
    so that no estimator update or control tick waits for the compiler: the companion's first bearing in flight, a study's first flight.

    numba compiles a kernel on its first call and caches the machine code next to the sources (or in
    NUMBA_CACHE_DIR): on a fresh install the first process pays the compilation, about a minute of one core for every
    kernel here, and later processes load the cache and run this in about 0.6 s. This runs the u-PLKF and IMM
    updates once on made-up bearings (at and off the estimator's ticks, with adaptive process noise, both gain
    forms) and reads their estimates (the IMM's `_combined_estimate`), on throwaway estimators, then the baseline estimators' (_warm_up_baselines), the control tick's
    setpoint kernels (_warm_up_setpoint) and the bearing path's diagnostics (_warm_up_diagnostics). Nothing to do
    without numba or after the first call in a process. Callers time it
    (studies.executors.compile_kernels)."""
    global _warmed_up
    if not ENABLED or _warmed_up:
        return
    from companion.core.estimators import AdaptiveNoiseSettings, GainProjection, InitialGuess, UPLKF, limit_range
    from companion.core.imm import IMMEstimator, standard_models
    from companion.core.messages import BearingMeasurement

    sigma = 1e-4 * np.eye(3)
    estimators = [UPLKF(0.02, 0.04 * np.eye(3), sigma, GainProjection.PREDICTED, pursuer_position_std=0.1,
                        adaptive_noise=AdaptiveNoiseSettings())]
    for projection in (GainProjection.PREDICTED, GainProjection.MEASURED):
        estimators.append(IMMEstimator(0.02, standard_models([0.2], 0.04, 0.04), sigma, projection, pursuer_position_std=0.1))
    for estimator in estimators:
        estimator.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3)),
                                        InitialGuess(20.0, 10.0, np.zeros(3), 5.0))
        for k in range(1, 4):
            estimator.predict()
            for lead in (0.0, -0.01):  # a bearing on the tick and a late one
                estimator.correct(BearingMeasurement(estimator.time + lead, np.array([1.0, 0.01 * k, 0.0]),
                                                     np.array([0.0, 0.01 * k, 0.0])))
            estimator.estimate
        getattr(estimator, "acceleration", None)  # the IMM's turn feed-forward (the cooperative laws')
    limit_range(np.array([2.0e6, 0.0, 0.0]), np.zeros(3))
    _warm_up_baselines()
    _warm_up_setpoint()
    _warm_up_diagnostics()
    _warm_up_cooperative()
    _warmed_up = True


def _warm_up_baselines() -> None:
    """The baseline estimators' kernels (companion.core.baseline_estimators: az/el EKF, MSC-EKF with and without a
    reference, range/az/el EKF) on made-up bearings at and off the ticks, a restart behind the sensor, and their
    estimates, so that none compiles in flight."""
    from companion.core.baseline_estimators import MSCEKF, AzElEKF, RangeAzElEKF
    from companion.core.estimators import InitialGuess
    from companion.core.messages import BearingMeasurement

    sigma = 1e-4 * np.eye(3)
    estimators = [AzElEKF(0.02, 0.04 * np.eye(3), sigma, pursuer_position_std=0.1),
                  MSCEKF(0.02, 0.04 * np.eye(3), sigma, pursuer_position_std=0.1),
                  RangeAzElEKF(0.02, sigma, range_noise_std=1.0, pursuer_position_std=0.1)]
    guess = InitialGuess(20.0, 10.0, np.array([-1.0, 0.0, 0.0]), 5.0)
    for estimator in estimators:
        estimator.initialize_on_bearing(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3), range=20.0), guess)
        for k in range(1, 4):
            estimator.predict()
            for lead in (0.0, -0.01):  # a bearing on the tick and a late one
                estimator.correct(BearingMeasurement(estimator.time + lead, np.array([1.0, 0.01 * k, 0.0]),
                                                     np.array([0.0, 0.01 * k, 0.0]), range=20.0))
            estimator.estimate
        if not isinstance(estimator, RangeAzElEKF):  # a prior behind the sensor restarts
            estimator.correct(BearingMeasurement(estimator.time, np.array([-1.0, 0.0, 0.0]), np.zeros(3)))
    cartesian = MSCEKF(0.02, 0.04 * np.eye(3), sigma)  # Cartesian until its first correction
    cartesian.initialize(0.0, np.array([20.0, 0.0, 0.0]), np.zeros(3), np.eye(6))
    cartesian.predict()
    cartesian.estimate
    cartesian.correct(BearingMeasurement(cartesian.time, np.array([1.0, 0.0, 0.0]), np.zeros(3)))


def _warm_up_setpoint() -> None:
    """The control tick's kernels (companion.core.attitude, guidance, geometry) on made-up commands, with and
    without a heading fallback, so that no setpoint in flight waits for the compiler."""
    from companion.core.attitude import (VehicleLimits, attitude_setpoint, attitude_setpoint_after, collective_thrust,
                                         desired_rotation, limit_specific_force)
    from companion.core.geometry import relative_terms_kernel as _relative_terms
    from companion.core.geometry import rotation_from_x_axis_to
    from companion.core.guidance import (_NO_EXCITATION, HelicalNavigationGuidance, RangeController, RangeExcitation,
                                         _excitation_terms_kernel, _tracking_command_kernel, _tracking_terms_kernel,
                                         saturation)

    limits = VehicleLimits(2.0 / 3.0, max_tilt=0.6, gravity=9.81, mass=1.0)
    los = np.array([0.8, -0.36, -0.48])
    velocity = np.array([2.0, 0.5, 0.0])
    guidance = HelicalNavigationGuidance(3.0, 1.0, 1.0)
    lateral = guidance.acceleration(1.0, velocity, los, 20.0)
    guidance.virtual_los(1.0, los, 20.0)
    lateral = lateral + RangeExcitation().acceleration(1.0, los, 0.5)
    controller = RangeController(8.0)
    controller.acceleration(20.0 * los, velocity, los, lateral)
    controller.error_state(20.0 * los, velocity)
    setpoint = attitude_setpoint(1.0, lateral, los, limits)
    attitude_setpoint(1.02, lateral, los, limits, setpoint.rotation[:, 0])
    flown = limit_specific_force(lateral, limits)
    collective_thrust(flown, desired_rotation(flown, los, limits.gravity), limits.mass, limits.gravity)
    rotation_from_x_axis_to(los)
    previous = attitude_setpoint_after(1.04, lateral, los, limits, None)
    attitude_setpoint_after(1.06, lateral, los, limits, previous)
    relative_position, relative_velocity, _, _ = _relative_terms(20.0 * los, velocity, np.zeros(3), velocity)
    excitation = RangeExcitation()
    for suspect in (False, True):
        _excitation_terms_kernel(1.0, lateral, relative_position, np.eye(6), los, suspect, excitation.low,
                                 excitation.high, excitation.speed, excitation.damping_gain, excitation.frequency)
    excitation.level(0.1)
    controller.virtual_control(controller.error_state(20.0 * los, velocity))
    desired_range, gain, limit = controller.kernel_terms
    for excite, with_setpoint in ((False, True), (True, False)):  # the control tick's two kernels (FollowingPipeline)
        los_out, lateral_out, longitudinal, command, rotation, flown = (np.empty(3), np.empty(3), np.empty(3),
                                                                        np.empty(3), np.empty((3, 3)), np.empty(3))
        terms = _tracking_terms_kernel(20.0 * los, velocity, np.zeros(3), 0.5 * velocity, 1.0, guidance.kernel_terms,
                                       excite, np.eye(6), excite, excitation.kernel_terms if excite else _NO_EXCITATION,
                                       desired_range, (los_out, lateral_out))
        _tracking_command_kernel(terms[2:], saturation(terms[-1], limit), gain, limit, los_out, lateral_out,
                                 (longitudinal, command, rotation, flown), with_setpoint, previous.rotation,
                                 limits.setpoint_terms)


def _warm_up_cooperative() -> None:
    """The cooperative laws' kernels (companion.core.cooperative_guidance: the circumnavigation law's, the tracking
    command the standoff law uses, the separation filter's) on a made-up context with a neighbour, so that no
    cooperative control tick waits for the compiler."""
    from companion.core.cooperative_guidance import (CircumnavigationGuidance, CooperativeContext, SeparationFilter,
                                                     StandoffTrackingGuidance)
    from companion.core.messages import NeighbourState

    neighbour = NeighbourState(2, 0.0, np.array([10.0, 5.0, -20.0]), np.array([0.0, 1.0, 0.0]))
    context = CooperativeContext(0.0, np.array([0.0, 0.0, -20.0]), np.array([1.0, 0.0, 0.0]), np.array([20.0, 0.0, -20.0]),
                                 np.array([3.0, 4.0, 0.0]), (neighbour,), np.zeros(3))
    CircumnavigationGuidance().acceleration(context)
    CircumnavigationGuidance().desired_velocity(context)
    StandoffTrackingGuidance().acceleration(context)
    SeparationFilter(2.0).filter(context.own_position, context.own_velocity, np.ones(3), (neighbour,))


def _warm_up_diagnostics() -> None:
    """The bearing path's diagnostic kernels (companion.core.health, observability, pipeline): the NIS of a 3-D
    rank-2 and a 2-D innovation, the windowed FIM's add and measure, the health monitor's update and the
    re-acquisition gate, on made-up numbers, so that no bearing in flight waits for the compiler."""
    from companion.core.geometry import relative_range_std
    from companion.core.health import HealthMonitor, normalized_innovation_squared
    from companion.core.observability import WindowedObservability
    from companion.core.pipeline import _gate_terms

    los = np.array([0.8, -0.36, -0.48])
    across = np.eye(3) - np.outer(los, los)
    normalized_innovation_squared(across @ np.array([0.1, 0.2, 0.3]), 1e-4 * across)
    normalized_innovation_squared(np.array([0.01, -0.02]), np.array([[2e-4, 1e-5], [1e-5, 3e-4]]))
    observability = WindowedObservability(1.0, 0.01)
    for k in range(3):
        observability.add(0.6 * k, np.array([0.6, 0.8, 0.0]) if k % 2 else los, 20.0)
        observability.measure()
        observability.add_and_measure(0.6 * k + 0.3, los, 20.0)
    HealthMonitor().update(0.0, los, np.zeros(3), np.ones(3), 20.0 * los, np.eye(6), innovation=across @ np.ones(3),
                           innovation_covariance=1e-4 * across, innovation_dof=2, reinitialized=False,
                           fim_min_eigenvalue=100.0)
    relative_range_std(20.0 * los, np.eye(3))
    _gate_terms(20.0 * los, 20.0, los, np.eye(3), 0.01)
