"""The control tick's setpoint kernels (attitude.py, guidance.py, geometry.py) give the results of the code they
replaced, bit for bit, compiled (numba) and interpreted.

The reference here is the OLD implementation, copied verbatim from before the kernels (numpy's norm, dot, hypot,
clip, tan, Python's `**`): each public function is compared with it on random inputs (hypothesis), so the
compiled path is checked against numpy's rounding, not only against its own Python function. Where numba's
arithmetic would differ from numpy's or Python's (numba's `x ** 2` is x * x, Python's is pow(x, 2.0); numpy's
tan and arctan are its SIMD routines, not the C library's), the kernels take the value from Python
(VehicleLimits.kernel_terms) or call the C library (companion.core._jit.power); the range controller's
saturation (numpy's arctan) stays in Python, its dot products and norm are a kernel. A whole flight compiled against BOF_NO_JIT=1 is
tests/test_estimator_kernels.py's flight test (it runs the setpoint kernels too).
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from bitwise import assert_same

from companion.core import _jit, attitude, geometry, guidance
from companion.core.attitude import VehicleLimits
from companion.core.guidance import HelicalNavigationGuidance, RangeController, RangeErrorState, RangeExcitation

E_X = np.array([1.0, 0.0, 0.0])
E_Z = np.array([0.0, 0.0, 1.0])
python = _jit.python_function


# ----- the old implementation (before the kernels), verbatim -----------------------------------------------------

def old_unit(vector):
    norm = math.sqrt(float(vector @ vector))
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"cannot normalise vector {vector!r}")
    return vector / norm


def old_skew(vector):
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def old_cross(a, b):
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def old_rodrigues(axis, angle):
    k = old_skew(axis)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def old_rotation_from_x_axis_to(direction):
    lam = old_unit(np.asarray(direction, dtype=float))
    axis = old_cross(E_X, lam)
    sin_theta = float(math.sqrt(axis @ axis))
    cos_theta = float(min(1.0, max(-1.0, lam[0])))
    if sin_theta < 1e-12:
        return np.eye(3) if cos_theta > 0.0 else old_rodrigues(E_Z, math.pi)
    return old_rodrigues(axis / sin_theta, math.atan2(sin_theta, cos_theta))


def old_limit_specific_force(acceleration, limits):
    force = limits.gravity * E_Z - np.asarray(acceleration, dtype=float)
    horizontal = force[:2]
    horizontal_norm = float(np.hypot(horizontal[0], horizontal[1]))
    reserved = min(horizontal_norm, limits.horizontal_margin_specific_force)
    vertical_max = max(float(np.sqrt(max(limits.max_specific_force**2 - reserved**2, 0.0))),
                       limits.min_vertical_specific_force)
    vertical = float(np.clip(force[2], limits.min_vertical_specific_force, vertical_max))
    horizontal_limit = min(
        vertical * np.tan(limits.max_tilt),
        float(np.sqrt(max(limits.max_specific_force**2 - vertical**2, 0.0))),
    )
    if horizontal_norm > horizontal_limit:
        horizontal = horizontal * (horizontal_limit / horizontal_norm)
    limited_force = np.array([horizontal[0], horizontal[1], vertical])
    return limits.gravity * E_Z - limited_force


def old_desired_rotation(acceleration, los, gravity, heading_fallback=None):
    thrust_axis = old_unit(gravity * E_Z - np.asarray(acceleration, dtype=float))
    right = old_cross(thrust_axis, los)
    if np.linalg.norm(right) < 1e-6 * max(float(np.linalg.norm(los)), 1e-12):
        forward_hint = np.array([1.0, 0.0, 0.0]) if heading_fallback is None else np.asarray(heading_fallback, float)
        right = old_cross(thrust_axis, forward_hint)
        if np.linalg.norm(right) < 1e-9:
            right = old_cross(thrust_axis, np.array([1.0, 0.0, 0.0]))
    right = old_unit(right)
    forward = old_cross(right, thrust_axis)
    return np.column_stack([forward, right, thrust_axis])


def old_collective_thrust(acceleration, rotation, mass, gravity):
    return float(mass * rotation[:, 2] @ (gravity * E_Z - np.asarray(acceleration, dtype=float)))


def old_attitude_setpoint(acceleration, los, limits, heading_fallback=None):
    flown = old_limit_specific_force(acceleration, limits)
    rotation = old_desired_rotation(flown, los, limits.gravity, heading_fallback)
    thrust = old_collective_thrust(flown, rotation, limits.mass, limits.gravity)
    specific_force = thrust / limits.mass
    thrust_normalized = float(np.clip(specific_force / limits.gravity * limits.hover_thrust_normalized, 0.0, 1.0))
    return rotation, thrust_normalized, thrust, flown


def old_virtual_los(law, engaged_time, los, range_estimate):
    scale = 1.0 / max(range_estimate, 1e-3) if law.scale_with_range else 1.0
    phase = law.weave_frequency * engaged_time
    rotation_z = geometry.rotation_about_z(law.c_z * np.sin(phase) * scale)
    rotation_y = geometry.rotation_about_y(law.c_y * np.cos(phase) * scale)
    return old_rotation_from_x_axis_to(los) @ rotation_z @ rotation_y @ E_X


def old_helical_acceleration(law, engaged_time, velocity, los, range_estimate):
    los = old_unit(los)
    virtual = old_virtual_los(law, engaged_time, los, range_estimate)
    return law.navigation_gain * old_cross(old_cross(velocity, virtual), los)


def old_excitation_level(excitation, relative_range_std, suspect=False):
    if suspect or not np.isfinite(relative_range_std):
        return 1.0
    return float(np.clip((relative_range_std - excitation.low) / (excitation.high - excitation.low), 0.0, 1.0))


def old_excitation_acceleration(excitation, engaged_time, los, level):
    if level <= 0.0:
        return np.zeros(3)
    basis = old_rotation_from_x_axis_to(old_unit(los))
    phase = excitation.frequency * engaged_time
    cos_phase, sin_phase = np.cos(phase), np.sin(phase)
    direction = cos_phase * basis[:, 1] + sin_phase * basis[:, 2]
    turning = -sin_phase * basis[:, 1] + cos_phase * basis[:, 2]
    return level * excitation.speed * (excitation.damping_gain * direction + excitation.frequency * turning)


# ----- strategies --------------------------------------------------------------------------------------------------

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
vectors = arrays(np.float64, 3, elements=finite)
scales = st.floats(1e-3, 1e2)
special_directions = st.sampled_from([E_X, -E_X, E_Z, -E_Z, np.array([1.0, 1e-13, 0.0]), np.array([-1.0, 0.0, 1e-14])])


def direction_of(vector, scale):
    assume(np.linalg.norm(vector) > 1e-6)
    return vector / np.linalg.norm(vector) * scale


limits_strategy = st.builds(
    lambda hover, tilt, gravity, mass, headroom, minimum, margin: VehicleLimits(
        hover, max_tilt=tilt, gravity=gravity, mass=mass, thrust_headroom=headroom,
        min_vertical_specific_force=minimum * gravity, horizontal_margin=margin),
    st.floats(0.2, 0.9), st.floats(0.05, 1.4), st.floats(9.0, 10.0), st.floats(0.2, 5.0), st.floats(0.5, 1.0),
    st.floats(0.05, 0.6), st.floats(0.0, 1.0))  # a zero minimum vertical force can zero the thrust axis


# ----- tests -------------------------------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(vectors, scales, st.booleans(), special_directions)
def test_rotation_from_x_axis_to_is_the_old_one(vector, scale, special, direction):
    los = direction * scale if special else direction_of(vector, scale)
    assert_same(geometry.rotation_from_x_axis_to(los), old_rotation_from_x_axis_to(los))
    unit_los = old_unit(los)
    assert_same(geometry.rotation_from_unit_x_axis_to(unit_los), python(geometry.rotation_from_unit_x_axis_to)(unit_los))


@settings(max_examples=500, deadline=None)
@given(vectors, st.floats(-300.0, 300.0))
def test_norm_is_numpys(vector, exponent):
    scaled = vector * 2.0**exponent
    assert_same(geometry.norm(scaled), float(np.linalg.norm(scaled)))
    assert type(geometry.norm(scaled)) is float and geometry.norm([3, 4, 0]) == 5.0


@settings(max_examples=300, deadline=None)
@given(finite, finite, finite)
def test_clip_is_numpys(value, low, high):
    assume(low <= high)
    for clip in (geometry.clip, geometry.clip_kernel):
        result = clip(value, low, high)
        assert result == float(np.clip(value, low, high)) and type(float(result)) is float
    assert math.isnan(geometry.clip_kernel(math.nan, low, high)) and math.isnan(geometry.clip(math.nan, low, high))


@settings(max_examples=500, deadline=None)
@given(st.floats(0.0, 1e4), st.floats(-1e4, 1e4))
def test_power_is_pythons(base, negative):
    for value in (base, negative):
        assert_same(_jit.power(value, 2.0), value**2)
        assert_same(_square(value), value**2)  # compiled: the C library's pow, not numba's x * x


def _square_of(value):
    return _jit.power(value, 2.0)


def _squares_of(values):
    squares = np.empty_like(values)
    for k in range(values.shape[0]):
        squares[k] = _jit.power(values[k], 2.0)
    return squares


_square = _jit.numba.njit(_square_of) if _jit.ENABLED else _square_of
_squares = _jit.numba.njit(_squares_of) if _jit.ENABLED else _squares_of


def test_power_is_pythons_on_many_values():
    """numba's own x ** 2 (x * x) differs from Python's pow(x, 2.0) for about 1 value in 1000 of these."""
    values = np.random.default_rng(2).uniform(0.0, 50.0, 200_000)
    assert np.array_equal(_squares(values), np.array([value**2 for value in values.tolist()]))


@settings(max_examples=400, deadline=None)
@given(vectors, vectors, scales, limits_strategy, st.sampled_from(["none", "column", "parallel", "below"]))
def test_attitude_setpoint_is_the_old_one(acceleration, los_vector, scale, limits, case):
    los = direction_of(los_vector, scale)
    fallback = None
    if case == "column":
        fallback = old_rotation_from_x_axis_to(los_vector + 1.0)[:, 0]  # a non-contiguous column, as the pipeline's
    elif case in ("parallel", "below"):  # line of sight along the thrust axis: the fallback branches
        thrust_axis = old_unit(limits.gravity * E_Z - old_limit_specific_force(acceleration, limits))
        los = thrust_axis * scale
        fallback = thrust_axis if case == "below" else old_rotation_from_x_axis_to(los_vector + 1.0)[:, 0]
    setpoint = attitude.attitude_setpoint(0.5, acceleration, los, limits, fallback)
    rotation, thrust_normalized, thrust, flown = old_attitude_setpoint(acceleration, los, limits, fallback)
    assert_same(setpoint.rotation, rotation)
    assert_same(setpoint.acceleration, flown)
    assert setpoint.thrust == thrust and setpoint.thrust_normalized == thrust_normalized
    assert type(setpoint.thrust) is float and type(setpoint.thrust_normalized) is float
    # the pieces, public and kernel-by-kernel against their Python functions
    assert_same(attitude.limit_specific_force(acceleration, limits), flown)
    assert_same(attitude.desired_rotation(flown, los, limits.gravity, fallback), rotation)
    assert attitude.collective_thrust(flown, rotation, limits.mass, limits.gravity) == thrust
    terms = limits.kernel_terms
    fallback_array = attitude._NORTH if fallback is None else np.ascontiguousarray(fallback)
    for kernel, args in ((attitude._limited_acceleration_kernel, (acceleration, *terms)),
                         (attitude._rotation_kernel, (flown, los, terms[0], fallback_array)),
                         (attitude._thrust_kernel, (flown, rotation, limits.mass, limits.gravity))):
        assert_same(kernel(*args), python(kernel)(*args))


def test_attitude_setpoint_raises_on_a_zero_thrust_axis():
    limits = VehicleLimits(0.5, max_tilt=0.5, gravity=9.81, mass=1.0)
    for function in (attitude.desired_rotation, python(attitude._rotation_kernel)):
        try:
            function(np.array([0.0, 0.0, 9.81]), E_X, 9.81, attitude._NORTH)
        except ValueError:
            continue
        raise AssertionError(f"{function} normalised a zero thrust axis")
    assert limits.kernel_terms[2] == limits.max_specific_force**2


@settings(max_examples=400, deadline=None)
@given(st.floats(0.0, 1e3), vectors, vectors, scales, st.floats(0.0, 1e3), st.floats(0.1, 6.0),
       st.floats(-5.0, 5.0), st.floats(-5.0, 5.0), st.floats(0.05, 3.0), st.booleans(), st.booleans(), special_directions)
def test_helical_navigation_is_the_old_one(time, velocity, los_vector, scale, range_estimate, gain, c_z, c_y,
                                           frequency, scaled, special, direction):
    los = direction * scale if special else direction_of(los_vector, scale)
    law = HelicalNavigationGuidance(gain, c_z, c_y, frequency, scaled)
    assert_same(law.acceleration(time, velocity, los, range_estimate),
                old_helical_acceleration(law, time, velocity, los, range_estimate))
    assert_same(law.virtual_los(time, los, range_estimate), old_virtual_los(law, time, los, range_estimate))


@settings(max_examples=400, deadline=None)
@given(st.floats(0.0, 1e3), vectors, scales, st.floats(-0.5, 1.0), st.floats(0.1, 5.0), st.floats(0.0, 5.0),
       st.floats(0.05, 3.0), st.floats(0.0, 0.5), st.booleans(), st.booleans(), special_directions)
def test_range_excitation_is_the_old_one(time, los_vector, scale, level, speed, gain, frequency, rho, suspect,
                                         special, direction):
    los = direction * scale if special else direction_of(los_vector, scale)
    excitation = RangeExcitation(speed, gain, frequency)
    assert_same(excitation.acceleration(time, los, level), old_excitation_acceleration(excitation, time, los, level))
    for value in (rho, math.inf):
        assert excitation.level(value, suspect) == old_excitation_level(excitation, value, suspect)


def old_range_error_state(controller, relative_position, relative_velocity):
    distance = float(np.linalg.norm(relative_position))
    return RangeErrorState(distance - controller.desired_range,
                           float(relative_position @ relative_velocity) / max(distance, 1e-6))


def old_range_acceleration(controller, relative_position, relative_velocity, los, lateral_acceleration):
    error = old_range_error_state(controller, relative_position, relative_velocity)
    distance = float(np.linalg.norm(relative_position))
    u_star = (
        -distance * controller.virtual_control(error)
        + float(relative_velocity @ relative_velocity)
        - error.range_rate**2
        - float(relative_position @ lateral_acceleration)
    )
    projection = float(los @ relative_position)
    if projection <= 1e-6 * max(distance, 1.0):
        return np.zeros(3)
    return u_star / projection * los


@settings(max_examples=400, deadline=None)
@given(vectors, scales, vectors, vectors, vectors, st.floats(0.5, 50.0), st.floats(0.1, 10.0), st.floats(0.5, 10.0),
       st.sampled_from(["any", "tiny", "zero", "nan", "behind"]))
def test_range_controller_is_the_old_one(position, scale, velocity, los_vector, lateral, desired, gain, limit, case):
    """eq. (15)-(19) with the kernel's products against the old numpy ones: the command and the error state."""
    relative = {"any": position * scale, "tiny": position * 1e-9, "zero": np.zeros(3),
                "nan": np.array([np.nan, 1.0, 0.0]), "behind": position * scale}[case]
    los = direction_of(los_vector, 1.0) if case != "behind" or not np.any(relative) else -relative / np.linalg.norm(relative)
    controller = RangeController(desired, gain, limit)
    with np.errstate(invalid="ignore", divide="ignore"):
        command = controller.acceleration(relative, velocity, los, lateral)
        expected = old_range_acceleration(controller, relative, velocity, los, lateral)
        new, old = controller.error_state(relative, velocity), old_range_error_state(controller, relative, velocity)
    if case == "nan":
        # A NaN in gives NaN out; its sign bit is not a result: OpenBLAS's dot sums NaNs in an order that can
        # depend on the arrays' alignment, so even the old code's NaN signs vary from call to call.
        assert np.isnan(command).all() and np.isnan(expected).all()
        assert math.isnan(new.range_error) and math.isnan(old.range_error)
        assert math.isnan(new.range_rate) and math.isnan(old.range_rate)
        return
    assert_same(command, expected)
    assert_same((new.range_error, new.range_rate), (old.range_error, old.range_rate))
    assert type(new.range_rate) is float and type(new.range_error) is float


def test_warm_up_compiles_the_setpoint_kernels():
    _jit.warm_up()
    kernels = (attitude._setpoint_kernel, attitude._rotation_kernel, attitude._thrust_kernel,
               attitude._limited_acceleration_kernel, guidance._helical_acceleration_kernel,
               guidance._virtual_los_kernel, guidance._excitation_acceleration_kernel, guidance._range_terms,
               guidance._range_error_terms)
    for kernel in kernels:
        if _jit.ENABLED:
            assert kernel.signatures, kernel
        else:
            assert python(kernel) is kernel
