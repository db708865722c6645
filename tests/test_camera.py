"""Pin-hole camera bearing sensor (paper section VIII, Table I): projection, pixel grid, noise, config, closed loop."""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, nonzero_vectors
from scipy.spatial.transform import Rotation

from companion.assembly import build_sensor
from companion.core.bearing_sensor import CameraModel, measure_bearing
from interfaces.scenario import SCENARIOS_DIR, VEHICLES_DIR, ConfigError, SensorConfig, load_scenario
from studies.closed_loop import Termination, simulate

CAMERA = CameraModel()
LEVEL = np.eye(3)
HALF_PIXEL_DIAGONAL = math.sqrt(0.5) * CAMERA.pixel_angle  # rad, the largest angle a pixel centre can be from a point in its cell


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b))


# Any attitude: a scipy rotation from a non-degenerate quaternion.
attitudes = st.tuples(nonzero_vectors(1.0, min_norm=0.1), floats(-1.0, 1.0)).map(
    lambda drawn: Rotation.from_quat([*drawn[0], drawn[1]]).as_matrix()
)
# A continuous image point anywhere on the 1024 x 1024 sensor (pixel centres at integers), not within
# 1e-6 px of a cell border, where rounding the re-projected point may go either way.
image_points = st.tuples(floats(-0.5, 1023.5), floats(-0.5, 1023.5)).filter(
    lambda point: all(min((c + 0.5) % 1.0, 1.0 - (c + 0.5) % 1.0) > 1e-6 for c in point)
)


def _pinhole_direction(point: tuple[float, float], rotation: np.ndarray) -> np.ndarray:
    """The NED unit ray through a continuous image point of the Table I pin-hole camera, written out:
    camera = FRD body (identity mount), x_c = [1, (u - u0) rho_w / f, (v - v0) rho_h / f]."""
    ray = np.array([1.0, (point[0] - 512.0) * 1e-5 / 0.008, (point[1] - 512.0) * 1e-5 / 0.008])
    return rotation @ (ray / np.linalg.norm(ray))


def _directions_through(camera: CameraModel, points: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """NED directions whose continuous image points are `points` (px, shape (N, 2))."""
    return np.array([camera.bearing(point, rotation) for point in points])


def test_table_one_defaults():
    assert (CAMERA.focal_length, CAMERA.pixel_width, CAMERA.pixel_height) == (0.008, 1e-5, 1e-5)
    assert CAMERA.principal_point == (512.0, 512.0) and CAMERA.image_size == (1024, 1024)
    assert CAMERA.pixel_angle == pytest.approx(1.25e-3)
    horizontal, vertical = CAMERA.field_of_view
    assert math.degrees(horizontal) == pytest.approx(65.2, abs=0.1)
    assert math.degrees(vertical) == pytest.approx(65.2, abs=0.1)


def test_forward_target_lands_on_the_principal_point_and_axes_follow_frd():
    assert CAMERA.project(np.array([1.0, 0.0, 0.0]), LEVEL) == (512, 512)
    # Right of the nose -> +u; below the nose -> +v; f / rho = 800 px per unit tangent.
    assert CAMERA.project(np.array([1.0, 0.1, 0.0]), LEVEL) == (592, 512)
    assert CAMERA.project(np.array([1.0, 0.0, 0.1]), LEVEL) == (512, 592)
    assert CAMERA.project(np.array([1.0, -0.1, -0.1]), LEVEL) == (432, 432)


@settings(max_examples=200, deadline=None)
@given(attitudes, image_points)
def test_project_back_project_round_trip_within_half_a_pixel(rotation: np.ndarray, point: tuple[float, float]):
    true_bearing = _pinhole_direction(point, rotation)
    pixel = CAMERA.project(true_bearing, rotation)
    # The pixel whose cell holds the point (rounding half up, as floor(c + 1/2)).
    assert pixel == tuple(math.floor(c + 0.5) for c in point)
    np.testing.assert_allclose(CAMERA.image_point(true_bearing, rotation), point, atol=1e-7)
    back = CAMERA.bearing(pixel, rotation)
    assert np.linalg.norm(back) == pytest.approx(1.0)
    assert _angle(back, true_bearing) <= HALF_PIXEL_DIAGONAL * (1 + 1e-9)
    # The back-projected ray is the pin-hole ray through the pixel centre.
    np.testing.assert_allclose(back, _pinhole_direction(pixel, rotation), atol=1e-12)
    np.testing.assert_allclose(CAMERA.image_point(back, rotation), pixel, atol=1e-8)


def test_quantisation_error_is_uniform_over_a_pixel():
    rng = np.random.default_rng(12)
    rotation = Rotation.from_euler("ZYX", [0.4, 0.2, -0.1]).as_matrix()
    points = rng.uniform(-0.5, 1023.5, size=(10000, 2))
    errors = []
    for point, true_bearing in zip(points, _directions_through(CAMERA, points, rotation)):
        errors.append(np.array(CAMERA.project(true_bearing, rotation)) - point)
    errors = np.array(errors)
    assert np.max(np.abs(errors)) <= 0.5 + 1e-9
    np.testing.assert_allclose(errors.mean(axis=0), 0.0, atol=0.01)
    np.testing.assert_allclose(errors.std(axis=0), 1.0 / math.sqrt(12.0), rtol=0.02)


@pytest.mark.parametrize(
    "point, inside",
    [
        ((-0.49, 512.0), True), ((-0.51, 512.0), False),
        ((1023.49, 512.0), True), ((1023.51, 512.0), False),
        ((512.0, -0.49), True), ((512.0, -0.51), False),
        ((512.0, 1023.49), True), ((512.0, 1023.51), False),
        ((-0.49, 1023.49), True), ((1023.51, -0.51), False),
    ],
)
def test_field_of_view_edges(point, inside):
    rotation = Rotation.from_euler("ZYX", [1.0, -0.3, 0.2]).as_matrix()
    direction = CAMERA.bearing(point, rotation)
    pixel = CAMERA.project(direction, rotation)
    if inside:
        assert pixel == tuple(math.floor(c + 0.5) for c in point)
    else:
        assert pixel is None


def test_behind_or_beside_the_camera_is_not_seen():
    rng = np.random.default_rng(13)
    assert CAMERA.project(np.array([-1.0, 0.0, 0.0]), LEVEL) is None
    assert CAMERA.project(np.array([-1.0, 0.01, 0.01]), LEVEL) is None  # would fall near the centre if mirrored
    assert CAMERA.project(np.array([0.0, 1.0, 0.0]), LEVEL) is None
    assert CAMERA.image_point(np.array([-1.0, 0.2, 0.0]), LEVEL) is None
    assert CAMERA.measure(np.array([-1.0, 0.0, 0.0]), LEVEL, rng) is None
    assert CAMERA.project(np.array([1.0, 0.7, 0.0]), LEVEL) is None  # 35 deg right: past the 32.6 deg half-FOV


def test_yawed_and_pitched_vehicle():
    """Facing east (yaw 90 deg), nose 20 deg up: the camera axis points east and 20 deg up."""
    rotation = Rotation.from_euler("ZYX", [90.0, 20.0, 0.0], degrees=True).as_matrix()
    up_east = np.array([0.0, math.cos(math.radians(20.0)), -math.sin(math.radians(20.0))])
    assert CAMERA.project(up_east, rotation) == (512, 512)
    # A level target due east is 20 deg below the optical axis: v = v0 + 800 tan(20 deg).
    assert CAMERA.project(np.array([0.0, 1.0, 0.0]), rotation) == (512, round(512 + 800 * math.tan(math.radians(20.0))))
    # North-east is to the left; south-east to the right; north is 90 deg off the axis.
    u_north_east, _ = CAMERA.project(np.array([0.3, 1.0, -0.36]), rotation)
    u_south_east, _ = CAMERA.project(np.array([-0.3, 1.0, -0.36]), rotation)
    assert u_north_east < 512 < u_south_east
    assert CAMERA.project(np.array([1.0, 0.0, 0.0]), rotation) is None
    # Back-projection agrees with the attitude: the centre pixel is the camera axis.
    assert _angle(CAMERA.bearing((512, 512), rotation), up_east) < 1e-12
    # And the same target seen level (pitch 0) moves up the image by the pitch angle.
    level = Rotation.from_euler("ZYX", [90.0, 0.0, 0.0], degrees=True).as_matrix()
    assert CAMERA.project(np.array([0.0, 1.0, 0.0]), level) == (512, 512)


def test_mount_rotation_tilts_the_camera():
    """A camera pitched 20 deg up on a vehicle pitched 20 deg down looks at the horizon."""
    tilted_up = CameraModel.with_mount_angles(0.0, math.radians(20.0), 0.0)
    nose_down = Rotation.from_euler("ZYX", [0.0, -20.0, 0.0], degrees=True).as_matrix()
    assert tilted_up.project(np.array([1.0, 0.0, 0.0]), nose_down) == (512, 512)
    assert CAMERA.project(np.array([1.0, 0.0, 0.0]), nose_down)[1] < 512 - 250  # the fixed camera sees it high in the image
    assert _angle(tilted_up.bearing((512, 512), nose_down), np.array([1.0, 0.0, 0.0])) < 1e-12


def test_scipy_rotation_is_accepted():
    rotation = Rotation.from_euler("ZYX", [30.0, 10.0, 5.0], degrees=True)
    direction = rotation.apply([1.0, 0.05, -0.02])
    assert CAMERA.project(direction, rotation) == CAMERA.project(direction, rotation.as_matrix())


@pytest.mark.parametrize("pixel_noise_std", [0.0, 0.5, 2.0])
def test_measurement_noise_statistics(pixel_noise_std):
    """Measured image point - true image point: mean 0, variance sigma^2 + 1/12 (noise + uniform quantisation)."""
    camera = CameraModel(pixel_noise_std=pixel_noise_std)
    rng = np.random.default_rng(14)
    rotation = Rotation.from_euler("ZYX", [-0.7, 0.3, 0.1]).as_matrix()
    points = rng.uniform(100.0, 924.0, size=(8000, 2))  # away from the edges, so nothing is lost
    errors = []
    for point, true_bearing in zip(points, _directions_through(camera, points, rotation)):
        measured = camera.measure(true_bearing, rotation, rng)
        assert measured is not None and np.linalg.norm(measured) == pytest.approx(1.0)
        errors.append(camera.image_point(measured, rotation) - point)
    errors = np.array(errors)
    expected_std = math.sqrt(pixel_noise_std**2 + 1.0 / 12.0)
    np.testing.assert_allclose(errors.mean(axis=0), 0.0, atol=4 * expected_std / math.sqrt(len(points)))
    np.testing.assert_allclose(errors.std(axis=0), expected_std, rtol=0.03)
    assert abs(np.corrcoef(errors.T)[0, 1]) < 0.03


def test_angular_noise_near_the_centre_matches_the_pixel_angle():
    camera = CameraModel(pixel_noise_std=1.0)
    rng = np.random.default_rng(15)
    forward = np.array([1.0, 0.0, 0.0])
    angles = [_angle(camera.measure(forward, LEVEL, rng), forward) for _ in range(5000)]
    # Rayleigh in two axes of std sqrt(1 + 1/12) px at 1.25e-3 rad/px (the principal point is a pixel centre, so
    # the quantisation of an exactly-centred point is not uniform; the bound is loose on purpose).
    per_axis = math.sqrt(float(np.mean(np.square(angles))) / 2.0)
    assert 0.9 * camera.pixel_angle < per_axis < 1.15 * camera.pixel_angle


def test_noise_is_reproducible_for_a_seed():
    rotation = Rotation.from_euler("ZYX", [0.3, 0.1, 0.0]).as_matrix()
    direction = rotation @ np.array([1.0, 0.2, -0.1])
    first = [CAMERA.measure(direction, rotation, rng) for rng in [np.random.default_rng(3)] * 5]
    second = [CAMERA.measure(direction, rotation, rng) for rng in [np.random.default_rng(3)] * 5]
    np.testing.assert_array_equal(first, second)


def test_measure_bearing_dispatch_and_backward_compatibility():
    true_bearing = np.array([0.6, 0.8, 0.0])
    additive = measure_bearing("additive", true_bearing, 0.01, np.random.default_rng(5))
    np.testing.assert_array_equal(additive, true_bearing + np.random.default_rng(5).normal(0.0, 0.01, 3))
    rotated = measure_bearing("rotation", true_bearing, 0.01, np.random.default_rng(5))
    assert np.linalg.norm(rotated) == pytest.approx(1.0)
    yaw = math.atan2(0.8, 0.6)
    rotation = Rotation.from_euler("ZYX", [yaw, 0.0, 0.0]).as_matrix()
    seen = measure_bearing("camera", true_bearing, 0.01, np.random.default_rng(5), rotation=rotation)
    assert _angle(seen, true_bearing) < 5 * CAMERA.pixel_angle
    assert measure_bearing("camera", -true_bearing, 0.01, np.random.default_rng(5), rotation=rotation) is None
    with pytest.raises(ValueError, match="attitude"):
        measure_bearing("camera", true_bearing, 0.01, np.random.default_rng(5))
    with pytest.raises(ValueError, match="unknown bearing sensor model"):
        measure_bearing("sonar", true_bearing, 0.01, np.random.default_rng(5))


@pytest.mark.parametrize(
    "parameters, message",
    [
        (dict(focal_length=0.0), "focal_length"),
        (dict(pixel_width=-1e-5), "pixel_width"),
        (dict(pixel_noise_std=math.nan), "pixel_noise_std"),
        (dict(image_size=(0, 1024)), "image_size"),
        (dict(principal_point=(1100.0, 512.0)), "principal_point"),
        (dict(mount_quaternion=(0.0, 0.0, 0.0, 0.0)), "mount_quaternion"),
    ],
)
def test_camera_model_rejects_bad_parameters(parameters, message):
    with pytest.raises(ValueError, match=message):
        CameraModel(**parameters)


def test_non_rotation_attitude_is_rejected():
    with pytest.raises(ValueError, match="rotation"):
        CAMERA.project(np.array([1.0, 0.0, 0.0]), 2.0 * np.eye(3))
    with pytest.raises(ValueError, match="shape"):
        CAMERA.project(np.array([1.0, 0.0, 0.0]), np.eye(4))


# --- configuration ---------------------------------------------------------------------------------------------

def test_camera_scenario_configures_the_table_one_camera(scenario_path):
    scenario, _ = load_scenario(scenario_path("constant_velocity_camera"))
    assert scenario.sensor.model == "camera"
    sensor = build_sensor(scenario.sensor)
    assert sensor.needs_attitude
    assert sensor.camera == CameraModel(pixel_noise_std=scenario.sensor.camera.pixel_noise_std)


def test_sensor_config_defaults_and_mount():
    sensor = build_sensor(SensorConfig(model="camera", camera={"mount_rpy_deg": (0.0, 20.0, 0.0), "pixel_noise_std": 0.0}))
    nose_down = Rotation.from_euler("ZYX", [0.0, -20.0, 0.0], degrees=True).as_matrix()
    assert sensor.camera.project(np.array([1.0, 0.0, 0.0]), nose_down) == (512, 512)
    assert build_sensor(SensorConfig()).camera is None


CAMERA_SCENARIO = (SCENARIOS_DIR / "constant_velocity_camera.toml").read_text()


def _write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "vehicles").mkdir(exist_ok=True)
    (tmp_path / "vehicles" / "paper_table1.toml").write_text((VEHICLES_DIR / "paper_table1.toml").read_text())
    (tmp_path / "scenarios").mkdir(exist_ok=True)
    path = tmp_path / "scenarios" / "case.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "old, new, key",
    [
        ("focal_length = 0.008", "focal_length = 0.0", "focal_length"),
        ("pixel_size = [1e-5, 1e-5]", "pixel_size = [1e-5, -1e-5]", "pixel_size"),
        ("pixel_size = [1e-5, 1e-5]", "pixel_size = [1e-5]", "pixel_size"),
        ("principal_point = [512.0, 512.0]", "principal_point = [512.0, 2000.0]", "principal_point"),
        ("image_size = [1024, 1024]", "image_size = [1024, 0]", "image_size"),
        ("image_size = [1024, 1024]", "image_size = [1024.5, 1024]", "image_size"),
        ("pixel_noise_std = 1.0", "pixel_noise_std = -0.5", "pixel_noise_std"),
        ("pixel_noise_std = 1.0", "pixel_noise_std = inf", "pixel_noise_std"),
        ("pixel_noise_std = 1.0", "pixel_noise = 1.0", "pixel_noise"),
        ('model = "camera"', 'model = "webcam"', "model"),
    ],
)
def test_bad_camera_settings_are_rejected_naming_the_key(tmp_path, old, new, key):
    assert old in CAMERA_SCENARIO
    path = _write(tmp_path, CAMERA_SCENARIO.replace(old, new, 1))
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    assert key in str(error.value)


# --- in-process closed loop ------------------------------------------------------------------------------------

def test_camera_scenario_converges_in_closed_loop(scenario_path):
    """The attitude mapping of section VII points body x (the camera) at the target, so it stays in view."""
    scenario, vehicle = load_scenario(scenario_path("constant_velocity_camera"))
    result = simulate(scenario, vehicle)
    summary = result.summary
    assert result.termination is Termination.COMPLETED
    assert summary["range_error_rms"] < 1.0
    assert summary["range_estimation_error_rms"] < 1.0
    sensor_ticks = round(scenario.simulation.duration * scenario.sensor.rate_hz) + 1
    assert summary["bearings_used"] + summary["bearings_out_of_view"] == sensor_ticks
    assert summary["bearings_out_of_view"] < 0.05 * sensor_ticks


def test_additive_scenario_never_reports_out_of_view(scenario_path):
    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    data = scenario.model_dump()
    data["simulation"].update(duration=4.0, summary_window=2.0)
    summary = simulate(type(scenario).model_validate(data), vehicle).summary
    assert summary["bearings_out_of_view"] == 0 and summary["bearings_used"] == 21
