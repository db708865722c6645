"""[sensor]: the bearing sensor, its camera and its noise."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from interfaces.scenario.common import FROM_ARRAY, Duration, NonNegative, NonNegativeDistance, Rate, _Strict


#: px: the widest or tallest image (a 100-megapixel sensor is 12,000 px wide).
MAX_IMAGE_SIDE = 20_000
ImageSide = Annotated[int, Field(gt=0, le=MAX_IMAGE_SIDE)]
#: m: a pixel's width or height (1 um to 1 mm).
PixelSize = Annotated[float, Field(ge=1e-6, le=1e-3)]
#: deg.
Angle = Annotated[float, Field(ge=-360.0, le=360.0)]


class CameraConfig(_Strict):
    """Pin-hole camera of the paper's simulation (section VIII, Table I), used when sensor.model = 'camera'.

    focal_length: m. pixel_size: (rho_w, rho_h), m. principal_point: (u0, v0), px,
    inside the image. image_size: (width, height), px. pixel_noise_std: detector noise
    on the image point, px per axis (before the pixel-grid quantisation).
    mount_rpy_deg: camera relative to body (roll, pitch, yaw; ZYX, deg; pitch > 0 looks
    up); zero = looking along body +x, no gimbal.
    """

    focal_length: Annotated[float, Field(gt=0.0, le=1.0)] = 0.008
    pixel_size: Annotated[tuple[PixelSize, PixelSize], FROM_ARRAY] = (1e-5, 1e-5)
    principal_point: Annotated[tuple[float, float], FROM_ARRAY] = (512.0, 512.0)
    image_size: Annotated[tuple[ImageSide, ImageSide], FROM_ARRAY] = (1024, 1024)
    pixel_noise_std: NonNegative = 1.0
    mount_rpy_deg: Annotated[tuple[Angle, Angle, Angle], FROM_ARRAY] = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _principal_point_in_image(self) -> "CameraConfig":
        (u0, v0), (width, height) = self.principal_point, self.image_size
        if not (-0.5 <= u0 <= width - 0.5 and -0.5 <= v0 <= height - 0.5):
            raise ValueError(f"principal_point ({u0}, {v0}) must lie inside the {width} x {height} image")
        return self


MAX_BEARING_NOISE_STD = 10.0
"""Largest accepted [sensor] noise_std (unit-vector units for 'additive', rad for 'rotation')."""
MAX_RANGE_NOISE_STD = 1.0e4
"""m: largest accepted [sensor] range_noise_std."""


class RangeDependentNoise(_Strict):
    """Seed 003 eq. (15)-(16): sigma_r^2 = a2 (r - a1)^2 + a0 for the range, alpha times that for
    each bearing angle (r the true range, m). Defaults: the seed's case 3."""

    a0: Annotated[float, Field(gt=0.0, le=MAX_RANGE_NOISE_STD**2)] = 1.0
    """m^2: the variance at r = a1 (its minimum)."""
    a1: NonNegativeDistance = 1.0
    """m: the range of least noise."""
    a2: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0024
    """dimensionless: growth of the variance with (r - a1)^2."""
    alpha: Annotated[float, Field(gt=0.0, le=1.0)] = 1e-5
    """rad^2/m^2: angle variance per m^2 of range variance."""


class SensorConfig(_Strict):
    """Bearing sensor: 'additive' is eq. (4) (nu ~ N(0, noise_std^2 I)); 'rotation' is eq. (25)
    (epsilon ~ N(0, noise_std^2)); 'camera' is the pin-hole camera of section VIII ([sensor.camera];
    noise_std is then unused).

    Accepted noise: every noise_std in [0, MAX_BEARING_NOISE_STD], range_noise_std in
    [0, MAX_RANGE_NOISE_STD] m and any finite pixel_noise_std >= 0 flies: the estimators stay
    finite however far the bearings are from the Sigma they were given, though a bearing with
    noise_std near 1 carries almost no information and the estimate is then poor. Larger values
    are refused: beyond a few units the measured direction is indistinguishable from a uniformly
    random one, and at 1e150 and above the noise overflows the bearing arithmetic."""

    model: Literal["additive", "rotation", "camera"] = "additive"
    noise_std: NonNegative = 0.01
    rate_hz: Rate = 5.0
    camera: CameraConfig = CameraConfig()
    range_noise_std: NonNegative | None = None
    """m. A range sensor beside the bearing (seed 003's measurement set): every bearing then
    also carries |p_T - p| + N(0, range_noise_std^2). None (default): bearings only."""
    noise_time_constant: Duration | None = None
    """s. Coloured noise (seed 003 case 2): the bearing noise (model 'additive') and the range
    noise become first-order Gauss-Markov processes with this time constant and the same
    stationary std, sampled at rate_hz. None (default): white noise."""
    range_dependent_noise: RangeDependentNoise | None = None
    """Seed 003 case 3 (eq. (15)-(16)): the noise std follows the true range, sqrt(sigma_r^2) for the
    range and sqrt(alpha sigma_r^2) per bearing axis, replacing range_noise_std and noise_std in the
    sensor (the estimators keep their configured constant noise). Not for model 'camera'."""

    @model_validator(mode="after")
    def _noise_options_fit_the_model(self) -> "SensorConfig":
        if self.noise_time_constant is not None and self.model != "additive":
            raise ValueError(f"noise_time_constant (coloured noise) needs model = 'additive', got {self.model!r}")
        if self.range_dependent_noise is not None and self.model == "camera":
            raise ValueError("range_dependent_noise does not apply to the camera (its noise is in pixels)")
        return self

    @field_validator("noise_std")
    @classmethod
    def _bearing_noise_carries_information(cls, value: float) -> float:
        if value > MAX_BEARING_NOISE_STD:
            raise ValueError(
                f"must be at most {MAX_BEARING_NOISE_STD:g}, got {value!r}: with noise of that size per axis the "
                "measured bearing is a uniformly random direction (the true line of sight has length 1), so no "
                "estimator can follow it")
        return value

    @field_validator("range_noise_std")
    @classmethod
    def _range_noise_carries_information(cls, value: float | None) -> float | None:
        if value is not None and value > MAX_RANGE_NOISE_STD:
            raise ValueError(
                f"must be at most {MAX_RANGE_NOISE_STD:g} m, got {value!r}: a range sensor with noise of 10 km "
                "and more says nothing about a target followed at metres; leave range_noise_std out for bearings only")
        return value
