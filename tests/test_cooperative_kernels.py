"""The cooperative laws' kernels (issue 16) against the code they replaced, bit for bit.

The references below are VERBATIM COPIES, as they were at 1c852b6, of CircumnavigationGuidance.desired_velocity and
of the feed-forward it was flown with (_tracking_acceleration over CooperativeContext.advanced, the helpers phase,
phase_gaps, _ccw_gap, _planar, _ned, _rot90, _saturate, geometry.norm), before the law became
_circumnavigation_velocity_kernel, and of SeparationFilter.filter (with braking_margin, _trigger_margin,
_threatening, _limit_keeping_constraints), before its parts 1 and 2 became _separation_kernel. Contexts are drawn at random (neighbours at any phase, the pursuer above the
target, capped and uncapped relative speeds) and the law's outputs must equal the reference's to the last bit, with
the kernel compiled and as plain Python.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from companion.core import _jit
from companion import warmup
from companion.core.cooperative_guidance import (CircumnavigationGuidance, CooperativeContext, SeparationFilter,
                                                 StandoffTrackingGuidance, _braking_margin,
                                                 _circumnavigation_acceleration_kernel,
                                                 _circumnavigation_velocity_kernel, _ccw_gap_kernel, _separation_kernel,
                                                 _tracking_kernel, _trigger_margin)
from companion.core.messages import NeighbourState

FUZZ = settings(max_examples=400, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
TWO_PI = 2.0 * math.pi
_EPS = 1e-9


# --- the reference: verbatim copy of the replaced code (1c852b6) ---------------------------------------------

def _ref_norm(vector):
    vector = np.asarray(vector, dtype=float)
    return math.sqrt(vector @ vector)


def _ref_planar(vector):
    return np.array([vector[1], vector[0]], dtype=float)


def _ref_ned(planar, down=0.0):
    return np.array([planar[1], planar[0], down], dtype=float)


def _ref_rot90(planar):
    return np.array([-planar[1], planar[0]], dtype=float)


def _ref_phase(own_position, target_position):
    offset = np.asarray(own_position, dtype=float) - np.asarray(target_position, dtype=float)
    return math.atan2(float(offset[0]), float(offset[1]))


def _ref_ccw_gap(from_phase, to_phase):
    gap = (to_phase - from_phase) % TWO_PI
    return 0.0 if gap >= TWO_PI else gap  # float % can return 2 pi for a tiny negative difference


def _ref_phase_gaps(own_phase, neighbour_phases):
    phases = list(neighbour_phases)
    if not phases:
        return None
    ahead = min(_ref_ccw_gap(own_phase, p) for p in phases)
    behind = min(_ref_ccw_gap(p, own_phase) for p in phases)
    return ahead, behind


def _ref_context_gaps(context):
    own = _ref_phase(context.own_position, context.target_position)
    return _ref_phase_gaps(own, [_ref_phase(n.position, context.target_position) for n in context.neighbours])


def _ref_saturate(vector, limit):
    length = _ref_norm(vector)
    return vector if length <= limit else vector * (limit / length)


def _ref_advanced(self, horizon):
    return CooperativeContext(
        self.time + horizon,
        self.own_position + horizon * self.own_velocity,
        self.own_velocity,
        self.target_position + horizon * self.target_velocity,
        self.target_velocity,
        tuple(NeighbourState(n.ident, n.time + horizon, n.position + horizon * n.velocity, n.velocity)
              for n in self.neighbours),
        self.target_acceleration,
    )


def _ref_desired_velocity(self, context):
    offset = _ref_planar(context.target_position - context.own_position)  # pursuer -> target
    distance = _ref_norm(offset)
    phi = offset / distance if distance > _EPS else np.array([-1.0, 0.0])
    phi_bar = -_ref_rot90(phi)  # phi rotated by pi/2 clockwise seen from above
    gaps = _ref_context_gaps(context)
    delta = 0.0 if gaps is None else gaps[0]
    tangential = self.g2 * self.desired_radius * (self.alpha + self.g3 * delta)
    tangential = min(tangential, math.sqrt(self._turn_acceleration * max(distance, _EPS)))
    horizontal = self.g1 * (distance - self.desired_radius) * phi + tangential * phi_bar
    desired_down = context.target_position[2] - self.altitude_offset
    relative = _ref_ned(horizontal, self.vertical_gain * (desired_down - context.own_position[2]))
    return context.target_velocity + _ref_saturate(relative, self.max_relative_speed)


def _ref_acceleration(self, context, desired_velocity=None):
    desired_velocity = desired_velocity or (lambda c: _ref_desired_velocity(self, c))
    velocity_gain, feedforward_horizon, max_acceleration = self.velocity_gain, self.feedforward_horizon, self.max_acceleration
    u = desired_velocity(context)
    command = velocity_gain * (u - context.own_velocity)
    if feedforward_horizon > 0.0:
        command = command + (desired_velocity(_ref_advanced(context, feedforward_horizon))
                             - desired_velocity(_ref_advanced(context, -feedforward_horizon))) / (2.0 * feedforward_horizon)
    if context.target_acceleration is not None:
        command = command + context.target_acceleration
    return _ref_saturate(command, max_acceleration)


def _ref_braking_margin(self, distance, closing_speed):
    closing = max(closing_speed, 0.0)
    sharing = 2.0 if self.reciprocal else 1.0
    return distance - self.min_separation - closing * closing / (2.0 * sharing * self.braking_acceleration)


def _ref_trigger_margin(self, closing_speed):
    closing = max(closing_speed, 0.0)
    tau = self.horizon
    return (1.0 + self.max_acceleration / self.braking_acceleration) * (
        closing * tau + self.max_acceleration * tau * tau)


def _ref_threatening(self, offset, relative_velocity, distance, closing_speed):
    if _ref_braking_margin(self, distance, closing_speed) <= _ref_trigger_margin(self, closing_speed):
        return True
    speed2 = float(relative_velocity @ relative_velocity)
    if speed2 <= _EPS:
        return False
    t_closest = min(max(float(offset @ relative_velocity) / speed2, 0.0), self.horizon)
    return _ref_norm(offset - t_closest * relative_velocity) < self.min_separation


def _ref_filter(self, own_position, own_velocity, acceleration, neighbours):
    position = np.asarray(own_position, dtype=float)
    velocity = np.asarray(own_velocity, dtype=float)
    command = np.asarray(acceleration, dtype=float).copy()
    geometry = []
    for neighbour in neighbours:
        offset = neighbour.position - position
        distance = _ref_norm(offset)
        if distance <= _EPS:
            continue  # coincident: no direction to push along (cannot be reached from m >= 0)
        normal = offset / distance
        relative_velocity = velocity - neighbour.velocity
        geometry.append((offset, normal, relative_velocity, distance, float(relative_velocity @ normal)))
    for _, normal, _, distance, _ in geometry:
        if distance < self._influence:
            depth = (self._influence - distance) / (self._influence - self.min_separation)
            command = command - self.repulsion_gain * min(depth, 1.0) ** 2 * normal
    active = []
    for offset, normal, relative_velocity, distance, closing in geometry:
        if _ref_threatening(self, offset, relative_velocity, distance, closing):
            active.append((normal, -self.braking_acceleration if closing > 0.0 else 0.0))
    if not active:
        return _ref_saturate(command, self.max_acceleration)
    for _ in range(self.passes):
        for normal, bound in active:
            along = float(command @ normal)
            if along > bound:
                command = command + (bound - along) * normal
    return _ref_limit_keeping_constraints(self, command, active)


def _ref_limit_keeping_constraints(self, command, active):
    if _ref_norm(command) <= self.max_acceleration:
        return command
    basis = np.linalg.qr(np.array([normal for normal, _ in active]).T)[0]  # orthonormal span of normals
    constrained = basis @ (basis.T @ command)
    free = command - constrained
    constrained_norm = _ref_norm(constrained)
    if constrained_norm >= self.max_acceleration:
        return constrained * (self.max_acceleration / constrained_norm)
    room = math.sqrt(self.max_acceleration ** 2 - constrained_norm ** 2)
    return constrained + _ref_saturate(free, room)


# --- random laws and contexts --------------------------------------------------------------------------------

def _bits(array) -> list[str]:
    return [float(v).hex() for v in np.asarray(array, dtype=float).ravel()]


coordinate = st.floats(-200.0, 200.0)
speed = st.floats(-20.0, 20.0)
vectors = st.tuples(coordinate, coordinate, coordinate).map(np.array)
velocities = st.tuples(speed, speed, speed).map(np.array)


@st.composite
def laws(draw) -> CircumnavigationGuidance:
    return CircumnavigationGuidance(
        desired_radius=draw(st.floats(0.5, 30.0)), g1=draw(st.floats(0.01, 2.0)), g2=draw(st.floats(0.01, 2.0)),
        g3=draw(st.floats(0.0, 2.0)), alpha=draw(st.floats(0.1, 2.0)), altitude_offset=draw(st.floats(-10.0, 10.0)),
        vertical_gain=draw(st.floats(0.1, 3.0)), velocity_gain=draw(st.floats(0.1, 4.0)),
        max_acceleration=draw(st.floats(0.5, 10.0)),
        max_relative_speed=draw(st.one_of(st.just(math.inf), st.floats(0.5, 20.0))),
        feedforward_horizon=draw(st.sampled_from([0.0, 0.05, draw(st.floats(1e-3, 0.5))])),
        max_turn_acceleration=draw(st.one_of(st.none(), st.just(math.inf), st.floats(0.1, 10.0))))


@st.composite
def contexts(draw) -> CooperativeContext:
    target = draw(vectors)
    own = draw(st.one_of(vectors, st.just(target + np.array([0.0, 0.0, -5.0])),  # above the target
                         st.just(target.copy())))
    neighbours = []
    for ident in range(2, 2 + draw(st.integers(0, 4))):
        position = draw(st.one_of(vectors, st.just(own.copy()),  # at the pursuer's own phase
                                  st.just(2.0 * target - own)))  # opposite
        neighbours.append(NeighbourState(ident, draw(st.floats(0.0, 100.0)), position, draw(velocities)))
    acceleration = draw(st.one_of(st.none(), velocities))
    return CooperativeContext(draw(st.floats(0.0, 100.0)), own, draw(velocities), target, draw(velocities),
                              tuple(neighbours), acceleration)


@pytest.fixture(params=["compiled", "plain"])
def kernel_mode(request, monkeypatch):
    """Run each test with the kernels as they are (compiled when numba is) and as plain Python."""
    if request.param == "plain":
        import companion.core.cooperative_guidance as module
        for kernel in (_circumnavigation_velocity_kernel, _ccw_gap_kernel, _separation_kernel, _braking_margin,
                       _trigger_margin, _tracking_kernel, _circumnavigation_acceleration_kernel):
            monkeypatch.setattr(module, kernel.__name__, _jit.python_function(kernel))
    return request.param


@st.composite
def separation_filters(draw) -> SeparationFilter:
    min_separation = draw(st.floats(0.2, 5.0))
    max_acceleration = draw(st.floats(0.5, 10.0))
    return SeparationFilter(
        min_separation, influence_distance=draw(st.one_of(st.none(), st.floats(1.01, 4.0).map(lambda f: f * min_separation))),
        repulsion_gain=draw(st.floats(0.0, 3.0)), braking_acceleration=draw(st.floats(0.1, 1.0)) * max_acceleration,
        max_acceleration=max_acceleration, horizon=draw(st.floats(0.01, 1.0)), passes=draw(st.integers(1, 4)),
        reciprocal=draw(st.booleans()))


@st.composite
def separation_cases(draw):
    """(own position, own velocity, command, neighbours): neighbours close by (inside the influence distance, at
    the pursuer's own position, within a metre), closing and not."""
    own = draw(vectors)
    velocity = draw(velocities)
    near = st.tuples(*[st.floats(-6.0, 6.0)] * 3).map(np.array)
    neighbours = []
    for ident in range(2, 2 + draw(st.integers(0, 4))):
        position = draw(st.one_of(near.map(lambda d: own + d), st.just(own.copy()), vectors,
                                  st.floats(-1.0, 1.0).map(lambda x: own + np.array([x, 0.3, 0.0]))))
        approaching = st.floats(0.01, 0.5).map(lambda rate: velocity + rate * (own - position))  # slowly, head on
        neighbour_velocity = draw(st.one_of(velocities, st.just(velocity.copy()), st.just(-velocity), approaching))
        neighbours.append(NeighbourState(ident, 0.0, position, neighbour_velocity))
    command = draw(st.one_of(st.tuples(*[st.floats(-15.0, 15.0)] * 3).map(np.array), st.just(np.zeros(3))))
    return own, velocity, command, tuple(neighbours)


@settings(FUZZ, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])  # set once per mode
@given(law=laws(), context=contexts())
def test_the_law_gives_the_replaced_code_bits(kernel_mode, law, context):
    assert _bits(law.desired_velocity(context)) == _bits(_ref_desired_velocity(law, context))
    assert _bits(law.acceleration(context)) == _bits(_ref_acceleration(law, context))
    for horizon in (0.05, -0.05, law.feedforward_horizon):
        assert _bits(law._velocity_after(context, horizon)) == _bits(
            _ref_desired_velocity(law, context if horizon == 0.0 else _ref_advanced(context, horizon)))


@FUZZ
@given(law=laws(), context=contexts())
def test_the_compiled_and_plain_kernels_agree(law, context):
    arguments = (context.own_position, context.own_velocity, context.target_position, context.target_velocity,
                 context.neighbour_positions, context.neighbour_velocities, 0.05, law.g1, law.g2, law.g3, law.alpha,
                 law.desired_radius, law._turn_acceleration, law.altitude_offset, law.vertical_gain,
                 law.max_relative_speed)
    compiled, plain = np.full(3, np.nan), np.full(3, np.nan)
    assert _circumnavigation_velocity_kernel(*arguments, compiled)
    assert _jit.python_function(_circumnavigation_velocity_kernel)(*arguments, plain)
    assert _bits(compiled) == _bits(plain)


@FUZZ
@given(st.floats(allow_nan=False), st.floats(allow_nan=False))
def test_the_compiled_gap_is_pythons_float_modulo(a, b):
    gap = _ccw_gap_kernel(a, b)
    assert _bits([gap]) == _bits([_ref_ccw_gap(a, b)])


def test_an_advance_that_overflows_raises_as_the_contexts_did():
    huge = np.array([1.7e308, 0.0, 0.0])
    context = CooperativeContext(0.0, huge, np.array([1e308, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    law = CircumnavigationGuidance()
    with np.errstate(over="ignore"):  # the overflow is the input under test: it must raise, not warn
        with pytest.raises(ValueError):
            _ref_advanced(context, 1.0)
        with pytest.raises(ValueError, match="not finite"):
            context.advanced(1.0)
        with pytest.raises(ValueError, match="not finite"):
            law._velocity_after(context, 1.0)


@FUZZ
@given(contexts(), st.floats(-1.0, 1.0))
def test_advanced_is_what_the_constructors_build(context, horizon):
    """CooperativeContext.advanced builds with fast_frozen: the same fields as the validating constructors."""
    fast, reference = context.advanced(horizon), _ref_advanced(context, horizon)
    assert fast.time == reference.time
    for name in ("own_position", "own_velocity", "target_position", "target_velocity"):
        assert _bits(getattr(fast, name)) == _bits(getattr(reference, name))
    assert (fast.target_acceleration is None) == (reference.target_acceleration is None)
    assert len(fast.neighbours) == len(reference.neighbours)
    for mine, theirs in zip(fast.neighbours, reference.neighbours):
        assert type(mine) is NeighbourState and mine.ident == theirs.ident and mine.time == theirs.time
        assert _bits(mine.position) == _bits(theirs.position) and _bits(mine.velocity) == _bits(theirs.velocity)
    assert fast.neighbour_positions.shape == (len(context.neighbours), 3)


def test_warm_up_compiles_the_kernel_a_cooperative_tick_calls():
    """After warmup.warm_up, a control tick of the law compiles nothing more (the same argument types)."""
    warmup.warm_up()
    kernels = (_circumnavigation_velocity_kernel, _circumnavigation_acceleration_kernel, _tracking_kernel,
               _separation_kernel)
    if not _jit.ENABLED:
        assert all(_jit.python_function(kernel) is kernel for kernel in kernels)
        return
    compiled = [list(kernel.signatures) for kernel in kernels]
    assert all(compiled)
    neighbours = tuple(NeighbourState(k, 1.0, np.array([5.0 * k, 1.0, -20.0]), np.ones(3)) for k in (2, 3))
    for present in ((), neighbours):
        context = CooperativeContext(1.0, np.array([0.0, 0.0, -20.0]), np.ones(3), np.array([30.0, 5.0, -20.0]),
                                     np.ones(3), present)
        command = CircumnavigationGuidance().acceleration(context)
        StandoffTrackingGuidance().acceleration(context)
        SeparationFilter(2.0).filter(context.own_position, context.own_velocity, command, present)
    assert [list(kernel.signatures) for kernel in kernels] == compiled


@settings(FUZZ, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])  # set once per mode
@given(guard=separation_filters(), case=separation_cases())
def test_the_separation_filter_gives_the_replaced_code_bits(kernel_mode, guard, case):
    own, velocity, command, neighbours = case
    before = command.copy()
    assert _bits(guard.filter(own, velocity, command, neighbours)) == _bits(_ref_filter(guard, own, velocity, command, neighbours))
    assert _bits(command) == _bits(before)  # the caller's command is not written
    for neighbour in neighbours:
        offset = neighbour.position - own
        distance, closing = _ref_norm(offset), float((velocity - neighbour.velocity) @ offset)
        assert guard.braking_margin(distance, closing) == _ref_braking_margin(guard, distance, closing)
        assert guard._trigger_margin(closing) == _ref_trigger_margin(guard, closing)


def test_the_separation_cases_reach_every_branch():
    """The drawn cases repel, threaten and constrain (else the test above would check little)."""
    seen = set()

    @settings(FUZZ, max_examples=300)
    @given(guard=separation_filters(), case=separation_cases())
    def look(guard, case):
        own, velocity, command, neighbours = case
        normals, bounds = np.empty((len(neighbours), 3)), np.empty(len(neighbours))
        repelled = command.copy()
        threatening = _separation_kernel(own, velocity, repelled, np.array([n.position for n in neighbours]).reshape(-1, 3),
                                         np.array([n.velocity for n in neighbours]).reshape(-1, 3), guard.min_separation,
                                         guard._influence, guard.repulsion_gain, guard.braking_acceleration,
                                         guard.max_acceleration, guard.horizon, 2.0 if guard.reciprocal else 1.0,
                                         normals, bounds)
        seen.add("repelled" if not np.array_equal(repelled, command) else "not repelled")
        seen.add("threatened" if threatening else "not threatened")
        if threatening and _ref_norm(_ref_filter(guard, own, velocity, command, neighbours)) > 0.0:
            seen.add("constrained")
        if any(np.array_equal(n.position, own) for n in neighbours):
            seen.add("coincident")

    look()
    assert seen >= {"repelled", "not repelled", "threatened", "not threatened", "constrained", "coincident"}


@FUZZ
@given(contexts(), st.floats(0.0, 200.0))
def test_the_pipelines_moved_neighbours_are_what_the_constructor_builds(context, time):
    """FollowingPipeline._neighbours_at builds checked neighbours with fast_frozen; the reference is its code at
    1c852b6 (the NeighbourState constructor)."""
    from companion.core.pipeline import FollowingPipeline

    holder = object.__new__(FollowingPipeline)  # only the neighbours are needed
    holder._neighbours = context.neighbours
    moved = holder._neighbours_at(time)
    reference = tuple(NeighbourState(n.ident, time, n.position + (time - n.time) * n.velocity, n.velocity)
                      for n in context.neighbours)
    assert len(moved) == len(reference)
    for mine, theirs in zip(moved, reference):
        assert type(mine) is NeighbourState and mine.ident == theirs.ident and mine.time == theirs.time
        assert _bits(mine.position) == _bits(theirs.position) and mine.velocity is theirs.velocity


def test_a_moved_neighbour_that_overflows_raises_as_the_constructor_did():
    from companion.core.pipeline import FollowingPipeline

    holder = object.__new__(FollowingPipeline)
    holder._neighbours = (NeighbourState(2, 0.0, np.array([1.7e308, 0.0, 0.0]), np.array([1e308, 0.0, 0.0])),)
    with np.errstate(over="ignore"), pytest.raises(ValueError, match="neighbour position must be a finite vector"):
        holder._neighbours_at(1.0)  # the overflow is the input under test: it must raise, not warn


@st.composite
def standoff_laws(draw) -> StandoffTrackingGuidance:
    radius = draw(st.floats(2.0, 30.0))
    speed = draw(st.floats(1.0, 8.0))
    return StandoffTrackingGuidance(
        standoff_radius=radius, min_turn_radius=draw(st.floats(0.1, 0.45)) * radius, speed=speed,
        min_speed=draw(st.floats(0.2, 1.0)) * speed, max_speed=speed * draw(st.floats(1.0, 3.0)),
        phase_gain=draw(st.floats(0.0, 1.0)), standoff_height=draw(st.floats(-10.0, 10.0)),
        velocity_gain=draw(st.floats(0.1, 4.0)), max_acceleration=draw(st.floats(0.5, 10.0)),
        feedforward_horizon=draw(st.sampled_from([0.0, 0.05, draw(st.floats(1e-3, 0.5))])))


@settings(FUZZ, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])  # set once per mode
@given(law=standoff_laws(), context=contexts())
def test_the_standoff_laws_tracking_command_gives_the_replaced_code_bits(kernel_mode, law, context):
    """The standoff law's desired velocity is its own (unchanged) code; its feed-forward and saturation are now
    _tracking_kernel's: the reference is the replaced _tracking_acceleration over the same desired velocity."""
    expected = _ref_acceleration(law, context, law.desired_velocity)
    assert _bits(law.acceleration(context)) == _bits(expected)


def _ref_phase_spacing_errors(phases):
    """phase_spacing_errors at 1c852b6, verbatim."""
    values = np.asarray(phases, dtype=float).reshape(-1)
    if values.size == 0:
        return np.zeros(0)
    if not np.all(np.isfinite(values)):
        raise ValueError("phases must be finite")
    ordered = np.sort(np.mod(values, TWO_PI))
    gaps = np.diff(np.append(ordered, ordered[0] + TWO_PI))
    return gaps - TWO_PI / values.size


@FUZZ
@given(st.integers(1, 6).flatmap(lambda n: st.lists(st.lists(st.one_of(st.floats(-1e4, 1e4), st.sampled_from(
    [0.0, -0.0, math.pi, -math.pi, TWO_PI, -1e-300])), min_size=n, max_size=n), min_size=1, max_size=30)))
def test_the_spacing_error_rows_are_the_replaced_function_row_by_row(rows):
    from companion.core.cooperative_guidance import phase_spacing_error_rows, phase_spacing_errors

    phases = np.array(rows)
    expected = [_bits(_ref_phase_spacing_errors(row)) for row in phases]
    assert [_bits(row) for row in phase_spacing_error_rows(phases)] == expected
    assert [_bits(phase_spacing_errors(row)) for row in phases] == expected
    assert phase_spacing_errors([]).shape == (0,)
    with pytest.raises(ValueError, match="finite"):
        phase_spacing_error_rows(np.array([[0.0, math.nan]]))


def _ref_finite_vector(value, name):
    """_finite_vector at 1c852b6, verbatim."""
    vector = np.asarray(value, dtype=float)
    if vector.shape != (3,) or not _jit_free_all_finite(vector):
        raise ValueError(f"{name} must be a finite vector of shape (3,), got {value!r}")
    return vector


def _jit_free_all_finite(vector):
    return bool(np.all(np.isfinite(vector)))


shapes = st.sampled_from([(3,), (3,), (3,), (2,), (4,), (1, 3), ()])
vector_like = st.one_of(
    hnp.arrays(st.sampled_from([np.float64, np.float32, np.dtype(">f8")]), shapes,
               elements=st.floats(allow_nan=True, allow_infinity=True, width=32)),
    hnp.arrays(np.int64, shapes, elements=st.integers(-10, 10)),
    hnp.arrays(np.float64, (3,), elements=st.sampled_from([0.0, -1.5, math.nan, math.inf, -math.inf])),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=2, max_size=4),
    st.tuples(*[st.integers(-10, 10)] * 3))


@FUZZ
@given(vector_like)
def test_the_checked_vector_is_the_replaced_check(value):
    from companion.core.cooperative_guidance import _finite_vector

    try:
        expected = _ref_finite_vector(value, "v")
    except ValueError as error:
        with pytest.raises(ValueError) as raised:
            _finite_vector(value, "v")
        assert str(raised.value) == str(error)
        return
    actual = _finite_vector(value, "v")
    assert (actual is value) == (expected is value)
    assert actual.dtype == expected.dtype and _bits(actual) == _bits(expected)


@FUZZ
@given(contexts())
def test_a_context_holds_what_its_constructor_was_given_checked(context):
    rebuilt = CooperativeContext(context.time, list(context.own_position), context.own_velocity,
                                 context.target_position, context.target_velocity, list(context.neighbours),
                                 context.target_acceleration)
    assert type(rebuilt.own_position) is np.ndarray and rebuilt.own_velocity is context.own_velocity
    assert type(rebuilt.neighbours) is tuple and rebuilt.neighbours == context.neighbours
    with pytest.raises(Exception):
        rebuilt.time = 1.0  # still frozen
