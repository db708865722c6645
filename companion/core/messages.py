"""Typed messages that flow through the pipeline: link -> bearing -> estimator ->
guidance -> attitude/thrust -> vehicle.

All positions and velocities are in the local NED frame, SI units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from companion.core.geometry import all_finite, unit


class once_property:
    """functools.cached_property without the lock Python 3.11 takes at every first read (about 0.5 us, paid by
    every new message: a bearing's unit direction, an estimate's std): the value is computed on the first read
    and stored in the instance's __dict__, which later reads find first (a non-data descriptor). Messages are
    immutable, so the value never goes stale; two threads reading the same new message at once may both
    compute it (the same value)."""

    def __init__(self, function) -> None:
        self.function = function
        self.name = function.__name__
        self.__doc__ = function.__doc__

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, instance, owner=None):
        if instance is None:
            return self
        value = self.function(instance)
        instance.__dict__[self.name] = value
        return value


def fast_frozen(cls, pairs=(), /, **fields):
    """cls(**fields) for a frozen dataclass without __post_init__, given every field (by name, or as (name,
    value) pairs): the same object, field for field, without dataclasses' object.__setattr__ per field (about
    0.15 us each; the pipeline builds a few such messages at every step). tests/test_shared_computations.py
    checks each class it is used for against its own constructor."""
    instance = object.__new__(cls)
    instance.__dict__.update(pairs, **fields)
    return instance


@dataclass(frozen=True)
class PursuerState:
    """Own-vehicle state as the autopilot reports it.

    time: s. position: m, shape (3,). velocity: m/s, shape (3,).
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray


def pursuer_state(time: float, position: np.ndarray, velocity: np.ndarray) -> PursuerState:
    """PursuerState(time, position, velocity), built the way fast_frozen builds a message (the same object, field
    for field), with the three fields written straight into the new instance's __dict__: no keyword dict and no
    update call, half the constructor's cost (the in-process harness builds one at every step).
    tests/test_harness_fast_paths.py checks it against the constructor."""
    instance = object.__new__(PursuerState)
    fields = instance.__dict__
    fields["time"] = time
    fields["position"] = position
    fields["velocity"] = velocity
    return instance


@dataclass(frozen=True)
class BearingMeasurement:
    """A measured line-of-sight to the target, eq. (4).

    time: s, when the bearing was taken. direction: shape (3,), NED; the noisy
    bearing lambda~ = lambda + nu is not exactly unit and is used as given.
    pursuer_position: m, shape (3,), own position when the bearing was taken
    (the projection centre of the measurement).
    range: m, a measured range to the target taken with the bearing, only when a range
    sensor exists ([sensor] range_noise_std); bearing-only estimators ignore it.
    true_direction: the noise-free unit line of sight, shape (3,). Simulation only: the
    in-process simulator fills it for the "optimal u-PLKF" benchmark of section VIII-B;
    the networked companion never does.
    source: who took the bearing: 0 is this vehicle's own sensor (the default); a neighbour
    pursuer's shared bearing carries that pursuer's id (>= 1), with its pursuer_position
    at its own time stamp (cooperative following, seeds 002 and 004).
    """

    time: float
    direction: np.ndarray
    pursuer_position: np.ndarray
    range: float | None = None
    true_direction: np.ndarray | None = None
    source: int = 0

    @once_property
    def unit_direction(self) -> np.ndarray:
        """direction / |direction| (companion.core.geometry.unit; ValueError on a zero or non-finite direction),
        computed once per bearing: the estimator, the health monitor, the windowed FIM and the track all read
        it. Treat it as read only (it is shared)."""
        return unit(self.direction)


def position_std_of(covariance: np.ndarray) -> float:
    """sqrt(max(trace(P_pos), 0) / 3), m, of a covariance of [position, velocity] (6, 6): TargetEstimate.position_std.

    A plain function over a float64 array, so that an estimator's kernel can compile this very function
    (companion.core.imm's combined estimate) and hand out the std with the estimate. c[0,0] + c[1,1] + c[2,2] in
    that order is np.trace's sum exactly; `0.0 if 0.0 > total else total` is Python's max(total, 0.0) (a NaN
    stays NaN, -0.0 stays -0.0), which numba would not necessarily compile to the same comparison."""
    total = covariance[0, 0] + covariance[1, 1] + covariance[2, 2]
    return math.sqrt((0.0 if 0.0 > total else total) / 3.0)


@dataclass(frozen=True)
class TargetEstimate:
    """Estimated target state.

    time: s. position: m, shape (3,). velocity: m/s, shape (3,).
    covariance: of [position, velocity], shape (6, 6).
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray

    @once_property
    def position_std(self) -> float:
        """RMS per-axis standard deviation of the position, m: sqrt(trace(P_pos) / 3).

        P_pos = covariance[:3, :3]. For an isotropic covariance sigma^2 I it is sigma; it is
        the figure the dropout policy, the companion's state/series and the simulator's
        flight log all report (one definition, so the harnesses agree). Computed once per estimate
        (an estimate is a snapshot).
        """
        return position_std_of(self.covariance)

    @property
    def velocity_std(self) -> float:
        """RMS per-axis standard deviation of the velocity, m/s: sqrt(trace(P_vel) / 3), P_vel = covariance[3:, 3:]."""
        c = self.covariance
        return math.sqrt(max(float(c[3, 3] + c[4, 4] + c[5, 5]), 0.0) / 3.0)

    def extrapolated(self, time: float) -> "TargetEstimate":
        """Constant-velocity extrapolation of the mean to `time` (covariance unchanged)."""
        return fast_frozen(TargetEstimate, time=time, position=self.position + self.velocity * (time - self.time),
                           velocity=self.velocity, covariance=self.covariance)


@dataclass(frozen=True)
class NeighbourState:
    """Another pursuer as cooperative guidance and estimation see it.

    ident: pursuer id >= 1. time: s, stamp of position/velocity. position: m, shape (3,),
    NED. velocity: m/s, shape (3,), NED. Construction rejects a bad id, a non-finite time
    and non-finite or wrongly shaped vectors with ValueError (vectors are stored as float
    arrays), so one malformed neighbour report cannot reach the guidance as NaN.
    """

    ident: int
    time: float
    position: np.ndarray
    velocity: np.ndarray

    def __post_init__(self) -> None:
        if isinstance(self.ident, bool) or not isinstance(self.ident, (int, np.integer)) or self.ident < 1:
            raise ValueError(f"neighbour ident must be an integer >= 1, got {self.ident!r}")
        if not math.isfinite(float(self.time)):
            raise ValueError(f"neighbour time must be finite, got {self.time!r}")
        for name in ("position", "velocity"):
            vector = np.asarray(getattr(self, name), dtype=float)
            if vector.shape != (3,) or not all_finite(vector):
                raise ValueError(f"neighbour {name} must be a finite vector of shape (3,), got {getattr(self, name)!r}")
            object.__setattr__(self, name, vector)


@dataclass(frozen=True)
class AttitudeSetpoint:
    """What the companion sends the autopilot (maps to MAVLink SET_ATTITUDE_TARGET).

    rotation: desired attitude R_d, body FRD -> NED, shape (3, 3).
    thrust_normalized: collective thrust in [0, 1], 1 = all rotors at maximum.
    thrust: the same thrust in newtons (needs the vehicle mass; informative).
    acceleration: the acceleration command a_d it realises, m/s^2, shape (3,),
    after the vehicle's limits were applied.
    """

    time: float
    rotation: np.ndarray
    thrust_normalized: float
    thrust: float
    acceleration: np.ndarray

    @once_property
    def quaternion(self) -> np.ndarray:
        """R_d as a unit quaternion [w, x, y, z] with w >= 0 (MAVLink's order), shape (4,)."""
        quaternion = Rotation.from_matrix(self.rotation).as_quat(scalar_first=True)
        return -quaternion if quaternion[0] < 0.0 else quaternion
