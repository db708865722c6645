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

from bitwise import assert_same, seeds

from companion.core import _jit, attitude, geometry, guidance
from companion import warmup
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
    if case in ("column", "parallel"):  # the fallback is a direction: los_vector + 1 must not vanish
        assume(float(np.linalg.norm(los_vector + 1.0)) > 1e-6)
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


def old_virtual_control(controller, error):
    """RangeController.virtual_control before its kernel (saturation and saturation_slope in Python), verbatim."""
    sigma = controller.saturation_limit * float(np.arctan(error.range_error / controller.saturation_limit))
    slope = 1.0 / (1.0 + (error.range_error / controller.saturation_limit) ** 2)
    return -controller.gain * (sigma + error.range_rate) - sigma - slope * error.range_rate


def old_range_acceleration(controller, relative_position, relative_velocity, los, lateral_acceleration):
    error = old_range_error_state(controller, relative_position, relative_velocity)
    distance = float(np.linalg.norm(relative_position))
    u_star = (
        -distance * old_virtual_control(controller, error)
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


@settings(max_examples=500, deadline=None)
@given(st.floats(-1e4, 1e4), st.floats(-1e3, 1e3), st.floats(0.1, 10.0), st.floats(0.5, 10.0))
def test_virtual_control_is_the_old_one(range_error, range_rate, gain, limit):
    """v* of eq. (17): numpy's arctan in Python, the rest _virtual_control_terms (compiled and not), against the old
    method (saturation, saturation_slope)."""
    controller = RangeController(8.0, gain, limit)
    error = RangeErrorState(range_error, range_rate)
    expected = old_virtual_control(controller, error)
    assert_same(controller.virtual_control(error), expected)
    assert type(controller.virtual_control(error)) is float
    sigma = guidance.saturation(range_error, limit)
    for kernel in (guidance._virtual_control_terms_kernel, python(guidance._virtual_control_terms_kernel)):
        assert_same(kernel(sigma, range_error, range_rate, gain, limit), expected)
    assert_same(guidance._saturation_slope_kernel(range_error, limit), 1.0 / (1.0 + (range_error / limit) ** 2))


def old_relative_terms(target_position, target_velocity, position, velocity):
    """The control tick's first lines before _relative_terms (FollowingPipeline._compute_setpoint), verbatim."""
    relative_position = target_position - position
    relative_velocity = target_velocity - velocity
    range_estimate = geometry.norm(relative_position)
    los = relative_position / max(range_estimate, 1e-9)
    return relative_position, relative_velocity, range_estimate, los


def old_relative_range_std(relative_position, position_covariance):
    distance = float(np.linalg.norm(relative_position))
    if distance <= 1e-9:
        return math.inf
    los = relative_position / distance
    return float(np.sqrt(max(los @ position_covariance @ los, 0.0))) / distance


@settings(max_examples=400, deadline=None)
@given(vectors, vectors, vectors, vectors, st.sampled_from(["any", "same", "tiny", "nan"]))
def test_relative_terms_are_the_old_ones(target_position, target_velocity, position, velocity, case):
    position = {"any": position, "same": target_position, "tiny": target_position + 1e-12,
                "nan": np.array([np.nan, 0.0, 0.0])}[case]
    from companion.core.pipeline import _relative_terms
    with np.errstate(invalid="ignore"):
        expected = old_relative_terms(target_position, target_velocity, position, velocity)
    for kernel in (_relative_terms, python(_relative_terms)):
        result = kernel(target_position, target_velocity, position, velocity)
        if case == "nan":  # OpenBLAS's dot gives NaNs of either sign: NaN-ness only there
            assert math.isnan(result[2]) and np.isnan(result[3]).all() and np.isnan(expected[3]).all()
            assert_same(result[:2], expected[:2])
            continue
        assert_same(result, expected)
        assert type(result[2]) is float


def _covariance(seed, scale):
    factor = np.random.default_rng(seed).normal(size=(6, 6)) * scale
    return factor @ factor.T


@settings(max_examples=400, deadline=None)
@given(st.floats(0.0, 1e3), vectors, vectors, scales, st.integers(0, 2**32 - 1), st.floats(1e-4, 1e2),
       st.sampled_from([0.0, 0.01, 0.1]), st.floats(0.1, 5.0), st.floats(0.0, 5.0), st.floats(0.05, 3.0),
       st.booleans(), st.sampled_from(["any", "zero", "indefinite"]))
def test_excitation_terms_are_the_old_ones(time, lateral, position, scale, seed, spread, low, speed, gain, frequency,
                                           suspect, case):
    """rho, the level and a_lat + a_X in one kernel against the old pipeline's three calls (relative_range_std on
    P_pp, RangeExcitation.level with np.isfinite and np.clip, the acceleration) and the numpy sum."""
    relative = {"any": position * scale, "zero": np.zeros(3), "indefinite": position * scale}[case]
    assume(case == "zero" or np.linalg.norm(relative) > 1e-6)
    covariance = _covariance(seed, spread)
    if case == "indefinite":
        covariance = -covariance  # lambda P lambda < 0: sigma_r = 0 (Python's max), the level at its low end
    los = relative / np.linalg.norm(relative) if case != "zero" else E_X
    excitation = RangeExcitation(speed, gain, frequency, low, low + 0.1)
    rho = old_relative_range_std(relative, covariance[:3, :3])
    level = old_excitation_level(excitation, rho, suspect)
    expected = (level, lateral + old_excitation_acceleration(excitation, time, los, level))
    args = (time, lateral, relative, covariance, los, suspect, excitation.low, excitation.high, excitation.speed,
            excitation.damping_gain, excitation.frequency)
    for kernel in (guidance._excitation_terms_kernel, python(guidance._excitation_terms_kernel)):
        result = kernel(*args)
        assert_same(result, expected)
        assert type(result[0]) is float
    assert excitation.level(rho, suspect) == level and type(excitation.level(rho, suspect)) is float


@settings(max_examples=300, deadline=None)
@given(vectors, vectors, vectors, scales, limits_strategy, st.booleans())
def test_attitude_setpoint_after_is_the_old_one(acceleration, los_vector, previous_vector, scale, limits, first):
    """The control tick's call: the previous setpoint's r1 as heading fallback (or none), built without setattr."""
    los = direction_of(los_vector, scale)
    assume(np.linalg.norm(previous_vector + 1.0) > 1e-6)
    previous = None if first else attitude.attitude_setpoint(0.0, previous_vector, np.ascontiguousarray(
        old_rotation_from_x_axis_to(previous_vector + 1.0)[:, 0]), limits)
    fallback = None if previous is None else previous.rotation[:, 0]
    setpoint = attitude.attitude_setpoint_after(0.5, acceleration, los, limits, previous)
    rotation, thrust_normalized, thrust, flown = old_attitude_setpoint(acceleration, los, limits, fallback)
    assert type(setpoint) is attitude.AttitudeSetpoint and setpoint.time == 0.5
    assert_same(setpoint.rotation, rotation)
    assert_same(setpoint.acceleration, flown)
    assert setpoint.thrust == thrust and setpoint.thrust_normalized == thrust_normalized
    assert type(setpoint.thrust) is float and type(setpoint.thrust_normalized) is float
    identity = attitude._IDENTITY if previous is None else previous.rotation
    args = (acceleration, los, identity, *limits.setpoint_terms)
    assert_same(attitude._setpoint_after_kernel(*args), python(attitude._setpoint_after_kernel)(*args))


def test_attitude_setpoint_after_takes_the_fallback_along_the_thrust_axis():
    """With lambda along the thrust axis the heading is the previous r1 (the branch the fallback exists for)."""
    limits = VehicleLimits(0.5, max_tilt=0.5, gravity=9.81, mass=1.0)
    previous = attitude.attitude_setpoint(0.0, np.zeros(3), np.array([0.0, 1.0, 0.0]), limits)
    below = attitude.attitude_setpoint_after(0.02, np.zeros(3), E_Z, limits, previous)
    assert_same(below.rotation, old_attitude_setpoint(np.zeros(3), E_Z, limits, previous.rotation[:, 0])[0])
    assert np.array_equal(below.rotation[:, 0], np.array([0.0, 1.0, 0.0]))
    first = attitude.attitude_setpoint_after(0.0, np.zeros(3), E_Z, limits, None)
    assert np.array_equal(first.rotation[:, 0], E_X)  # north without a previous setpoint


# ----- the plant's side of a setpoint (sitl_plant.vehicle.quadrotor), old code verbatim ----------------------------

def old_rotation_to_quaternion(rotation):
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(rotation, dtype=float).tolist()
    trace = m00 + m11 + m22
    if trace >= m00 and trace >= m11 and trace >= m22:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif m11 >= m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    scale = (1.0 if q[0] >= 0.0 else -1.0) / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] * scale, q[1] * scale, q[2] * scale, q[3] * scale)


def old_check_rotation(rotation, name="rotation"):
    r = np.array(rotation, dtype=float)
    if r.shape != (3, 3):
        raise ValueError(f"{name} must be a (3, 3) array, got {r!r}")
    (a0, b0, c0), (a1, b1, c1), (a2, b2, c2) = r.tolist()
    residuals = (
        a0 * a0 + a1 * a1 + a2 * a2 - 1.0,
        b0 * b0 + b1 * b1 + b2 * b2 - 1.0,
        c0 * c0 + c1 * c1 + c2 * c2 - 1.0,
        a0 * b0 + a1 * b1 + a2 * b2,
        a0 * c0 + a1 * c1 + a2 * c2,
        b0 * c0 + b1 * c1 + b2 * c2,
        a1 * b2 - a2 * b1 - c0,
        a2 * b0 - a0 * b2 - c1,
        a0 * b1 - a1 * b0 - c2,
    )
    if not all(abs(x) <= 1e-6 for x in residuals):
        raise ValueError(f"{name} is not a proper rotation matrix: {r!r}")
    return r


def _outcome(function, *args):
    try:
        return function(*args)
    except ValueError as error:
        return (ValueError, str(error))


@settings(max_examples=400, deadline=None)
@given(vectors, scales, st.floats(-1e-5, 1e-5), st.integers(0, 8),
       st.sampled_from(["rotation", "perturbed", "nan", "reflection", "shape", "half turn"]))
def test_plant_setpoint_in_is_the_old_one(vector, scale, perturbation, entry, case):
    """AttitudeThrustVehicle.set_attitude_target's check and quaternion (checked_rotation_rows,
    quaternion_from_rows) against check_rotation + rotation_to_quaternion as they were: the same quaternion, the
    same rejections with the same messages, near the 1e-6 tolerance too."""
    from sitl_plant.vehicle import quadrotor
    rotation = old_rotation_from_x_axis_to(direction_of(vector, scale))
    if case == "half turn":
        rotation = old_rodrigues(old_unit(np.array([0.0, vector[1], vector[2]]) + E_Z * 1e-3), math.pi)
    flat = rotation.reshape(-1).copy()
    if case == "perturbed":
        flat[entry] += perturbation
    elif case == "nan":
        flat[entry] = math.nan
    elif case == "reflection":
        flat[entry % 3::3] *= -1.0  # a column flipped: orthonormal, left-handed
    matrix = flat.reshape(3, 3) if case != "shape" else flat[:6].reshape(2, 3)

    def old(r):
        return old_rotation_to_quaternion(old_check_rotation(r, "rotation_desired"))

    def new(r):
        return quadrotor.quaternion_from_rows(quadrotor.checked_rotation_rows(r, "rotation_desired"))

    expected = _outcome(old, matrix)
    _assert_same_outcome(_outcome(new, matrix), expected)
    square = matrix if case != "shape" else rotation
    _assert_same_outcome(_outcome(quadrotor.rotation_to_quaternion, square), _outcome(old_rotation_to_quaternion, square))
    checked = _outcome(quadrotor.check_rotation, matrix)
    _assert_same_outcome(checked, _outcome(old_check_rotation, matrix))
    assert checked is not matrix  # check_rotation still returns its own copy


def _assert_same_outcome(actual, expected):
    """The same exception and message, or the same numbers bit for bit (NaN where NaN)."""
    if isinstance(expected, tuple) and isinstance(expected[0], type):
        assert actual == expected
    else:
        assert_same(np.asarray(actual), np.asarray(expected))
        assert type(actual) is type(expected)


def old_tracking_tick(law, controller, excitation, limits, engaged_time, target_position, target_velocity, position,
                      velocity, covariance, suspect, previous):
    """The pipeline's usual control tick before guidance._tracking_terms/_tracking_command (FollowingPipeline.
    _compute_setpoint's single-law branch, then attitude_setpoint_after) in the old code of this file: the old
    relative terms, HNG, excitation (rho, level, a_X) and range controller, and the setpoint of a_HN + a_RC."""
    relative_position, relative_velocity, range_estimate, los = old_relative_terms(
        target_position, target_velocity, position, velocity)
    lateral = old_helical_acceleration(law, engaged_time, velocity, los, range_estimate)
    level = 0.0
    if excitation is not None:
        level = old_excitation_level(excitation, old_relative_range_std(relative_position, covariance[:3, :3]), suspect)
        lateral = lateral + old_excitation_acceleration(excitation, engaged_time, los, level)
    longitudinal = old_range_acceleration(controller, relative_position, relative_velocity, los, lateral)
    command = lateral + longitudinal
    fallback = None if previous is None else previous[:, 0]
    rotation, thrust_normalized, thrust, flown = old_attitude_setpoint(command, los, limits, fallback)
    return los, lateral, range_estimate, level, longitudinal, command, rotation, flown, thrust, thrust_normalized


@settings(max_examples=300, deadline=None)
@given(vectors, vectors, vectors, vectors, scales, st.floats(0.0, 100.0), st.floats(0.1, 6.0), st.floats(-5.0, 5.0),
       st.floats(-5.0, 5.0), st.floats(0.5, 50.0), st.floats(0.1, 10.0), st.floats(0.5, 10.0), st.booleans(),
       st.booleans(), seeds, st.sampled_from([0.0, 0.01, 0.1]), limits_strategy, st.booleans(),
       st.sampled_from(["any", "behind"]))
def test_tracking_kernels_are_the_old_tick(target, target_velocity, position, velocity, scale, time, gain, c_z, c_y,
                                           desired, range_gain, limit, excite, suspect, seed, spread, limits, first,
                                           case):
    """guidance._tracking_terms, numpy's arctan and _tracking_command (compiled and not) against the old tick
    verbatim (old_tracking_tick): lambda, a_lat, r^, the level, a_RC, a_d and the setpoint, bit for bit."""
    target = target * scale
    assume(np.linalg.norm(target - position) > 1e-6)
    law = HelicalNavigationGuidance(gain, c_z, c_y)
    controller = RangeController(desired, range_gain, limit)
    excitation = RangeExcitation() if excite else None
    covariance = _covariance(seed, spread)
    previous = None if first else old_rotation_from_x_axis_to(velocity + 1.0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        expected = old_tracking_tick(law, controller, excitation, limits, time, target, target_velocity, position,
                                     velocity, covariance, suspect, previous)
    assume(np.linalg.norm(limits.gravity * E_Z - expected[7]) > 1e-9)  # a thrust axis to normalise
    desired_range, range_gain, limit = controller.kernel_terms
    terms_kernel, command_kernel = guidance._tracking_terms_kernel, guidance._tracking_command_kernel
    for terms_kernel, command_kernel in ((terms_kernel, command_kernel), (python(terms_kernel), python(command_kernel))):
        for with_setpoint in (True, False):
            los, lateral, longitudinal, command, rotation, flown = (np.empty(3), np.empty(3), np.empty(3), np.empty(3),
                                                                    np.empty((3, 3)), np.empty(3))
            terms = terms_kernel(target, target_velocity, position, velocity, time, *law.kernel_terms, excite,
                                 covariance, suspect, *(excitation.kernel_terms if excite else guidance._NO_EXCITATION),
                                 desired_range, los, lateral)
            thrust, thrust_normalized = command_kernel(
                *terms[2:], guidance.saturation(terms[-1], limit), range_gain, limit, los, lateral, longitudinal, command,
                with_setpoint, attitude._IDENTITY if previous is None else previous, *limits.setpoint_terms, rotation,
                flown)
            assert_same((los, lateral, terms[0], terms[1], longitudinal, command), expected[:6])
            assert type(terms[0]) is float and type(terms[1]) is float
            if with_setpoint:
                assert_same((rotation, flown, thrust, thrust_normalized), expected[6:])
            else:
                assert math.isnan(thrust) and math.isnan(thrust_normalized)


def _flights(names=("constant_velocity_dropout", "stop_and_go"), seed=3, unguarded=("constant_velocity_dropout",)):
    """Seeded flights' series; the scenarios in `unguarded` fly without the safety envelope, whose adjustments
    otherwise take every setpoint out of the compiled tick's kernel."""
    from interfaces.scenario import SCENARIOS_DIR, load_scenario
    from studies.closed_loop import simulate
    from studies.montecarlo import with_overrides

    flights = []
    for name in names:
        scenario, vehicle = load_scenario(SCENARIOS_DIR / f"{name}.toml")
        if name in unguarded:
            scenario = with_overrides(scenario, {"safety.enabled": False})
        flights.append(simulate(scenario, vehicle, seed).series)
    return flights


def _count_compiled_ticks(monkeypatch) -> dict[bool, int]:
    """Count guidance._tracking_command_kernel's calls (HNG's compiled tick), by whether it made the setpoint."""
    calls = {True: 0, False: 0}
    command_kernel = guidance._tracking_command_kernel

    def counted(*args):
        calls[args[13]] += 1
        return command_kernel(*args)

    monkeypatch.setattr(guidance, "_tracking_command_kernel", counted)
    return calls


def test_the_compiled_tick_is_the_methods_tick(monkeypatch):
    """FollowingPipeline._compute_setpoint with HNG's compiled tick (HelicalNavigationGuidance.compiled_tick: the
    two tracking kernels) against the same pipeline without it (the law objects' methods, then the adjustments):
    whole flights with dropouts (coasting, degraded, blends) and the health actions, every series bit for bit,
    with the compiled tick taken away from the class. The compiled tick runs, with the setpoint in its kernel
    (the flight without the safety envelope) and without (a blend or the envelope: the adjustments then follow
    it)."""
    calls = _count_compiled_ticks(monkeypatch)
    compiled = _flights()
    assert calls[True] > 100 and calls[False] > 0
    counted_so_far = dict(calls)
    monkeypatch.delattr(HelicalNavigationGuidance, "compiled_tick")
    methods = _flights()
    assert calls == counted_so_far  # the methods only
    for fast, slow in zip(compiled, methods):
        assert fast.keys() == slow.keys()
        for key in fast:
            assert_same(fast[key], slow[key], key)


def test_a_subclass_flies_its_own_law(monkeypatch):
    """A law's compiled form belongs to the class that declares it: a subclass of HNG (which may change the law)
    flies through its own methods, never its parent's compiled tick. An unchanged subclass flies the same flight
    bit for bit; one whose acceleration is a pure pursuit (c_Z = c_Y = 0: HNG's own reduction, eq. (14)) has its
    method called on every control tick and flies a different flight."""
    from companion import assembly

    reference = _flights(("constant_velocity",))[0]
    calls = _count_compiled_ticks(monkeypatch)

    class Unchanged(HelicalNavigationGuidance):
        pass

    law_calls = []

    class Pursuit(HelicalNavigationGuidance):
        def acceleration(self, engaged_time, velocity, los, range_estimate, relative_velocity=None):
            law_calls.append(engaged_time)
            return HelicalNavigationGuidance(self.navigation_gain, 0.0, 0.0).acceleration(
                engaged_time, velocity, los, range_estimate, relative_velocity)

    for law in (Unchanged, Pursuit):
        monkeypatch.setitem(assembly.LATERAL_GUIDANCE, "hng", lambda g, law=law: law(
            g.navigation_gain, g.c_z, g.c_y, g.weave_frequency, g.scale_with_range))
        series = _flights(("constant_velocity",))[0]
        assert calls == {True: 0, False: 0}
        if law is Unchanged:
            for key in reference:
                assert_same(series[key], reference[key], key)
        else:
            # every control tick of the 60 s flight at 20 Hz from the first bearing (no dropout: no degraded tick)
            assert len(law_calls) == 1201 and np.allclose(np.diff(law_calls), 0.05)
            assert not np.array_equal(series["pursuer_position"], reference["pursuer_position"])


def test_the_compiled_tick_needs_exactly_the_range_controller():
    """HNG's compiled tick computes RangeController's arithmetic; for any other controller (a subclass may change
    it) it declines, and the pipeline then calls the controller's own method."""

    class Other(RangeController):
        pass

    law = HelicalNavigationGuidance(3.0, 1.0, 1.0)
    arguments = (1.0, np.array([10.0, 0.0, -5.0]), np.zeros(3), np.eye(6), np.zeros(3), np.array([1.0, 0.0, 0.0]),
                 None, False, VehicleLimits(0.5, max_tilt=0.5, gravity=9.81, mass=1.0).setpoint_terms, True, None)
    assert law.compiled_tick(Other(8.0), *arguments) is None
    tick = law.compiled_tick(RangeController(8.0), *arguments)
    assert tick is not None and len(tick) == 7 and tick[6] is not None and tick[1] is None  # a setpoint, no level


def test_warm_up_compiles_the_setpoint_kernels():
    warmup.warm_up()
    from companion.core.pipeline import _relative_terms
    kernels = (attitude._setpoint_kernel, attitude._rotation_kernel, attitude._thrust_kernel,
               attitude._limited_acceleration_kernel, guidance._helical_acceleration_kernel,
               guidance._virtual_los_kernel, guidance._excitation_acceleration_kernel, guidance._range_ratio_terms,
               guidance._range_command_kernel, guidance._virtual_control_terms_kernel, guidance._range_error_terms,
               attitude._setpoint_after_into_kernel, guidance._excitation_terms_kernel,
               guidance._excitation_level_kernel, _relative_terms, guidance._tracking_terms_kernel,
               guidance._tracking_command_kernel)
    # guidance._saturation_slope_kernel is not listed: only other kernels call it, and a kernel called only from
    # kernels has no signature of its own when its callers load from numba's cache (as in the other warm-up tests)
    for kernel in kernels:
        if _jit.ENABLED:
            assert kernel.signatures, kernel
        else:
            assert python(kernel) is kernel
