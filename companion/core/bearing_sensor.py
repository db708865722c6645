"""Bearing sensor models: how a true line of sight becomes a measured bearing.

The companion rebuilds the true bearing from the target's position and corrupts it
as the configured sensor would; only the corrupted bearing reaches the estimator.
Three models:

* 'additive': lambda~ = lambda + nu, eq. (4);
* 'rotation': lambda~ = R_eta(epsilon) lambda, eq. (25);
* 'camera': the pin-hole camera of the paper's simulation (section VIII, Table I),
  "a pin-hole camera model ... for perceiving the target whose pixel coordinate is
  then transformed to an LOS vector in the navigation frame". The target is projected
  into a 1024 x 1024 image through the vehicle's attitude, jittered by detector noise,
  quantised to the pixel grid and back-projected; outside the field of view there is
  no bearing at all.

Beside the white noise of eq. (4)/(25), seed 003's noise options (Ahmed and Subbarao,
Aerospace 2016): coloured noise (case 2, a first-order Gauss-Markov process per axis,
`GaussMarkovNoise`) and range-dependent variance (case 3, eq. (15)-(16),
`RangeDependentVariance`), for the bearing ('additive'; range-dependent also 'rotation')
and for the range.

Camera frame: x along the optical axis, y to the right of the image (+u), z down the
image (+v), i.e. the body FRD axes when the camera is mounted looking forward (the
default, no gimbal; the paper's attitude mapping of section VII turns body x towards
the target). Pixel centres are at integer coordinates, so pixel (i, j) covers
[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5) and a w x h image spans [-0.5, w - 0.5) x
[-0.5, h - 0.5) (the OpenCV convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from companion.core.geometry import cross, unit


MODELS = ("additive", "rotation", "camera")
_IDENTITY = np.eye(3)


def additive_bearing(true_bearing: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    """lambda~ = lambda + nu, nu ~ N(0, sigma^2 I), eq. (4). Shape (3,); not unit in general."""
    return np.asarray(true_bearing, float) + rng.normal(0.0, noise_std, 3)


def rotated_bearing(true_bearing: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    """lambda~ = R_eta(epsilon) lambda, eq. (25): a rotation by epsilon ~ N(0, sigma^2)
    about a random axis eta perpendicular to lambda. Shape (3,), unit."""
    lam = unit(np.asarray(true_bearing, float))
    helper = rng.normal(size=3)
    axis = unit(np.cross(lam, helper))
    return Rotation.from_rotvec(axis * rng.normal(0.0, noise_std)).apply(lam)


def rotation_matrix(rotation: np.ndarray | Rotation, name: str = "rotation") -> np.ndarray:
    """A body -> NED attitude as a (3, 3) matrix; accepts a matrix or a scipy Rotation.

    Raises ValueError for a wrong shape, non-finite entries or a matrix that is not a rotation.
    """
    if isinstance(rotation, Rotation):
        return rotation.as_matrix()
    matrix = np.asarray(rotation, dtype=float)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name} must be a finite rotation matrix of shape (3, 3), got shape {matrix.shape} with entries {matrix.tolist()!r}")
    # Cheap checks (this runs at every bearing): R^T R = I and det R = r1 . (r2 x r3) > 0.
    if float(np.max(np.abs(matrix.T @ matrix - _IDENTITY))) > 1e-6 or float(matrix[:, 0] @ cross(matrix[:, 1], matrix[:, 2])) < 0.0:
        raise ValueError(f"{name} is not a proper rotation matrix (R^T R != I or det R < 0)")
    return matrix


@dataclass(frozen=True)
class CameraModel:
    """Pin-hole camera fixed to the body, paper Table I (section VIII).

    focal_length: f, m (0.008). pixel_width, pixel_height: rho_w, rho_h, m (1e-5).
    principal_point: (u0, v0), px (512, 512). image_size: (width, height), px
    (1024, 1024), which gives a field of view of about 65 x 65 deg.
    pixel_noise_std: standard deviation of the detector's error on the target's image
    point, px per axis, before quantisation. The paper gives none; 1 px is what a
    detector's box centre typically jitters on a small drone that spans a few tens of
    pixels (a 0.5 m airframe at the 8 m following range covers ~50 px). With the
    quantisation (std 1/sqrt(12) px) that is ~1.3e-3 rad per axis near the image
    centre, well below the sigma = 0.01 the estimator assumes (Sigma = 1e-4 I).
    mount_quaternion: camera -> body rotation [w, x, y, z]; identity = looking along
    body +x with u along body +y and v along body +z.
    """

    focal_length: float = 0.008
    pixel_width: float = 1e-5
    pixel_height: float = 1e-5
    principal_point: tuple[float, float] = (512.0, 512.0)
    image_size: tuple[int, int] = (1024, 1024)
    pixel_noise_std: float = 1.0
    mount_quaternion: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("focal_length", "pixel_width", "pixel_height"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"camera {name} must be a positive finite number, got {value!r}")
        if not (math.isfinite(self.pixel_noise_std) and self.pixel_noise_std >= 0.0):
            raise ValueError(f"camera pixel_noise_std must be a finite number >= 0, got {self.pixel_noise_std!r}")
        width, height = self.image_size
        if int(width) != width or int(height) != height or width <= 0 or height <= 0:
            raise ValueError(f"camera image_size must be two positive integers, got {self.image_size!r}")
        u0, v0 = self.principal_point
        if not (-0.5 <= u0 <= width - 0.5 and -0.5 <= v0 <= height - 0.5):
            raise ValueError(f"camera principal_point {self.principal_point!r} lies outside the {width} x {height} image")
        quaternion = np.asarray(self.mount_quaternion, dtype=float)
        if quaternion.shape != (4,) or not np.all(np.isfinite(quaternion)) or np.linalg.norm(quaternion) < 1e-9:
            raise ValueError(f"camera mount_quaternion must be four finite numbers [w, x, y, z], not all zero; got {self.mount_quaternion!r}")

    @classmethod
    def with_mount_angles(cls, roll: float, pitch: float, yaw: float, **parameters) -> "CameraModel":
        """A camera mounted at roll, pitch, yaw (rad, ZYX, camera relative to body); pitch > 0 looks up."""
        quaternion = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat(scalar_first=True)
        return cls(mount_quaternion=tuple(float(q) for q in quaternion), **parameters)

    @cached_property
    def mount_rotation(self) -> np.ndarray:
        """Camera -> body rotation, shape (3, 3)."""
        return Rotation.from_quat(self.mount_quaternion, scalar_first=True).as_matrix()

    @property
    def pixel_angle(self) -> float:
        """rad subtended by one pixel (width) at the principal point, rho_w / f."""
        return self.pixel_width / self.focal_length

    @property
    def field_of_view(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view, rad (edges of the outer pixels)."""
        (u0, v0), (width, height) = self.principal_point, self.image_size
        horizontal = math.atan((u0 + 0.5) * self.pixel_width / self.focal_length) + math.atan((width - 0.5 - u0) * self.pixel_width / self.focal_length)
        vertical = math.atan((v0 + 0.5) * self.pixel_height / self.focal_length) + math.atan((height - 0.5 - v0) * self.pixel_height / self.focal_length)
        return horizontal, vertical

    def image_point(self, line_of_sight_ned: np.ndarray, rotation_body_to_ned: np.ndarray | Rotation) -> np.ndarray | None:
        """Continuous pixel coordinates (u, v) of a direction, before quantisation.

        u = u0 + f c_y / (rho_w c_x), v = v0 + f c_z / (rho_h c_x), with c the line of
        sight in the camera frame. line_of_sight_ned: shape (3,), any length. Returns
        px, shape (2,), possibly outside the image; None when the direction is not in
        front of the camera (c_x <= 0).
        """
        return self._image_point(line_of_sight_ned, self._camera_to_ned(rotation_body_to_ned))

    def _camera_to_ned(self, rotation_body_to_ned: np.ndarray | Rotation) -> np.ndarray:
        return rotation_matrix(rotation_body_to_ned, "rotation_body_to_ned") @ self.mount_rotation

    def _image_point(self, line_of_sight_ned: np.ndarray, camera_to_ned: np.ndarray) -> np.ndarray | None:
        in_camera = camera_to_ned.T @ unit(np.asarray(line_of_sight_ned, dtype=float))
        if in_camera[0] <= 1e-12:
            return None
        u0, v0 = self.principal_point
        return np.array([
            u0 + self.focal_length * in_camera[1] / (self.pixel_width * in_camera[0]),
            v0 + self.focal_length * in_camera[2] / (self.pixel_height * in_camera[0]),
        ])

    def quantize(self, image_point: np.ndarray) -> tuple[int, int] | None:
        """The pixel (u, v) whose cell holds a continuous image point, or None outside the image."""
        u, v = (math.floor(float(coordinate) + 0.5) for coordinate in image_point)
        width, height = self.image_size
        if 0 <= u < width and 0 <= v < height:
            return u, v
        return None

    def project(self, line_of_sight_ned: np.ndarray, rotation_body_to_ned: np.ndarray | Rotation) -> tuple[int, int] | None:
        """Noise-free image of a direction: the integer pixel (u, v) it falls in.

        None when the target is behind the camera or its pixel is outside the image.
        """
        point = self.image_point(line_of_sight_ned, rotation_body_to_ned)
        return None if point is None else self.quantize(point)

    def bearing(self, pixel: tuple[float, float], rotation_body_to_ned: np.ndarray | Rotation) -> np.ndarray:
        """Back-projection: the unit NED line of sight through pixel (u, v), shape (3,).

        c = [1, (u - u0) rho_w / f, (v - v0) rho_h / f] / |.|, lambda = R R_mount c.
        """
        return self._back_project(pixel, self._camera_to_ned(rotation_body_to_ned))

    def _back_project(self, pixel: tuple[float, float], camera_to_ned: np.ndarray) -> np.ndarray:
        u, v = pixel
        u0, v0 = self.principal_point
        in_camera = np.array([1.0, (u - u0) * self.pixel_width / self.focal_length, (v - v0) * self.pixel_height / self.focal_length])
        return unit(camera_to_ned @ in_camera)

    def measure(self, true_bearing_ned: np.ndarray, rotation_body_to_ned: np.ndarray | Rotation, rng: np.random.Generator) -> np.ndarray | None:
        """Project, add detector noise N(0, pixel_noise_std^2) per axis, quantise, back-project.

        Returns the measured unit NED bearing, shape (3,), or None when the target
        (after noise) is behind the camera or outside the image.
        """
        camera_to_ned = self._camera_to_ned(rotation_body_to_ned)
        point = self._image_point(true_bearing_ned, camera_to_ned)
        if point is None:
            return None
        pixel = self.quantize(point + rng.normal(0.0, self.pixel_noise_std, 2))
        return None if pixel is None else self._back_project(pixel, camera_to_ned)


def measure_bearing(
    model: str,
    true_bearing: np.ndarray,
    noise_std: float,
    rng: np.random.Generator,
    rotation: np.ndarray | Rotation | None = None,
    camera: CameraModel | None = None,
) -> np.ndarray | None:
    """Dispatch on the sensor model: 'additive' eq. (4), 'rotation' eq. (25) or 'camera'.

    true_bearing: unit NED line of sight, shape (3,). noise_std: sigma of eq. (4)/(25)
    (unused by the camera). rotation: body -> NED attitude, needed by 'camera' only.
    camera: the camera's parameters (Table I defaults when None). Returns the measured
    bearing, shape (3,), or None when the camera does not see the target.
    """
    if model == "additive":
        return additive_bearing(true_bearing, noise_std, rng)
    if model == "rotation":
        return rotated_bearing(true_bearing, noise_std, rng)
    if model == "camera":
        if rotation is None:
            raise ValueError("the 'camera' bearing model needs the vehicle attitude (rotation body -> NED)")
        return (camera or CameraModel()).measure(true_bearing, rotation, rng)
    raise ValueError(f"unknown bearing sensor model {model!r} (expected one of {', '.join(MODELS)})")


@dataclass(frozen=True)
class RangeDependentVariance:
    """Seed 003 eq. (15)-(16): sigma_r^2 = a2 (r - a1)^2 + a0 (m^2), angles alpha sigma_r^2 (rad^2).

    a0: m^2, > 0. a1: m. a2: dimensionless, >= 0. alpha: rad^2/m^2, > 0.
    """

    a0: float = 1.0
    a1: float = 1.0
    a2: float = 0.0024
    alpha: float = 1e-5

    def __post_init__(self) -> None:
        if not (self.a0 > 0.0 and self.a2 >= 0.0 and self.alpha > 0.0 and math.isfinite(self.a1)):
            raise ValueError(f"range-dependent noise needs a0 > 0, a2 >= 0, alpha > 0, finite a1; got {self!r}")

    def range_variance(self, true_range: float) -> float:
        """sigma_r^2 of eq. (15), m^2, at the true range r (m)."""
        return self.a2 * (float(true_range) - self.a1) ** 2 + self.a0

    def angle_variance(self, true_range: float) -> float:
        """sigma_phi^2 = sigma_theta^2 of eq. (16), rad^2, at the true range r (m)."""
        return self.alpha * self.range_variance(true_range)


@dataclass
class GaussMarkovNoise:
    """Unit-variance first-order Gauss-Markov noise (seed 003 eq. (11), the shaping filter
    z' = -b z + b w with b = 1/tau), sampled exactly every `period`.

    x_0 ~ N(0, I) (stationary start), x_k = phi x_{k-1} + sqrt(1 - phi^2) w_k with
    phi = exp(-period / time_constant), w_k ~ N(0, I): stationary variance 1 and
    autocorrelation phi^n at lag n. time_constant, period: s, > 0. size: components.
    Multiply by the wanted std (which may vary with time).
    """

    time_constant: float
    period: float
    size: int = 3
    _state: np.ndarray | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not (self.time_constant > 0.0 and self.period > 0.0):
            raise ValueError(f"Gauss-Markov noise needs a positive time constant and period, got {self.time_constant!r}, {self.period!r}")

    @property
    def correlation(self) -> float:
        """phi = exp(-period / time_constant), the lag-one autocorrelation."""
        return math.exp(-self.period / self.time_constant)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """The next sample, shape (size,), unit stationary variance; draws `size` normals from rng."""
        drive = rng.normal(0.0, 1.0, self.size)
        if self._state is None:
            self._state = drive
        else:
            phi = self.correlation
            self._state = phi * self._state + math.sqrt(1.0 - phi * phi) * drive
        return self._state.copy()


@dataclass(frozen=True)
class BearingSensor:
    """A configured bearing sensor: the model, its noise and, for 'camera', the camera.

    noise_time_constant: s, or None (white noise). When set, the 'additive' bearing noise
    and the range noise are `GaussMarkovNoise` with that time constant, stepped once per
    measurement with sample_period (s, the sensor's 1 / rate_hz; required then), scaled by
    their std. range_dependent: seed 003 eq. (15)-(16); the stds then follow the true
    range passed to `measure` and `measure_range` instead of noise_std and range_noise_std.
    With neither, the draws are exactly those of eq. (4)/(25) and r + N(0, sigma_r^2).
    The sensor then holds the noise processes' state: one sensor per flight.
    """

    model: str = "additive"
    noise_std: float = 0.01
    camera: CameraModel | None = None
    range_noise_std: float | None = None
    noise_time_constant: float | None = None
    sample_period: float | None = None
    range_dependent: RangeDependentVariance | None = None
    _bearing_process: GaussMarkovNoise | None = field(default=None, init=False, repr=False, compare=False)
    _range_process: GaussMarkovNoise | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown bearing sensor model {self.model!r} (expected one of {', '.join(MODELS)})")
        if self.model == "camera" and self.camera is None:
            object.__setattr__(self, "camera", CameraModel())
        if self.noise_time_constant is not None:
            if self.model != "additive":
                raise ValueError(f"coloured bearing noise needs the 'additive' model, got {self.model!r}")
            if self.sample_period is None:
                raise ValueError("coloured noise needs the sample_period (1 / rate_hz) it is stepped with")
            object.__setattr__(self, "_bearing_process", GaussMarkovNoise(self.noise_time_constant, self.sample_period, 3))
            object.__setattr__(self, "_range_process", GaussMarkovNoise(self.noise_time_constant, self.sample_period, 1))
        if self.range_dependent is not None and self.model == "camera":
            raise ValueError("range-dependent noise does not apply to the camera")

    @property
    def needs_attitude(self) -> bool:
        """Whether measure() needs the vehicle's attitude."""
        return self.model == "camera"

    def bearing_noise_std(self, true_range: float | None = None) -> float:
        """Per-axis bearing noise std (rad): noise_std, or sqrt(eq. (16)) at true_range (m)."""
        if self.range_dependent is None:
            return self.noise_std
        if true_range is None:
            raise ValueError("range-dependent bearing noise needs the true range")
        return math.sqrt(self.range_dependent.angle_variance(true_range))

    def range_noise(self, true_range: float) -> float | None:
        """Range noise std (m): range_noise_std, or sqrt(eq. (15)) at true_range (m); None without a range sensor."""
        if self.range_noise_std is None:
            return None
        if self.range_dependent is None:
            return self.range_noise_std
        return math.sqrt(self.range_dependent.range_variance(true_range))

    def measure(self, true_bearing: np.ndarray, rng: np.random.Generator, rotation: np.ndarray | Rotation | None = None,
                true_range: float | None = None) -> np.ndarray | None:
        """The measured bearing for a true unit line of sight (NED, shape (3,)); None if not seen.

        true_range: m, needed by range-dependent noise only. Coloured: lambda + sigma x_k,
        x_k the unit Gauss-Markov process (seed 003 case 2 applied to eq. (4)).
        """
        if self._bearing_process is None and self.range_dependent is None:
            return measure_bearing(self.model, true_bearing, self.noise_std, rng, rotation, self.camera)
        std = self.bearing_noise_std(true_range)
        if self._bearing_process is not None:
            return np.asarray(true_bearing, float) + std * self._bearing_process.sample(rng)
        return measure_bearing(self.model, true_bearing, std, rng, rotation, self.camera)

    def measure_range(self, true_range: float, rng: np.random.Generator) -> float | None:
        """Range measured beside the bearing (seed 003 eq. (2)): r + N(0, range_noise_std^2), m,
        floored at 0.1 m; None without a range sensor. Draws from its own generator `rng`, so
        adding a range sensor leaves the bearing noise unchanged. Coloured and range-dependent
        noise as for the bearing (std from `range_noise`)."""
        if self.range_noise_std is None:
            return None
        if self._range_process is None and self.range_dependent is None:
            return max(float(true_range) + float(rng.normal(0.0, self.range_noise_std)), 0.1)
        std = self.range_noise(true_range)
        assert std is not None
        draw = float(self._range_process.sample(rng)[0]) if self._range_process is not None else float(rng.normal())
        return max(float(true_range) + std * draw, 0.1)
