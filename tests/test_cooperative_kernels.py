"""The cooperative laws' kernels (companion.core.cooperative_guidance) and the objects they build, against
independent references: Python's float modulo for the counter-clockwise gap, the validating constructors for the
contexts and neighbours moved in time, the phase-spacing errors' closed form, the finite-vector check's contract;
the separation filter leaves the caller's command alone and its drawn cases reach every branch; the warm-up
compiles every kernel a cooperative tick calls. What the laws command (convergence to the orbit, equal spacing,
separation kept) is tests/test_cooperative_guidance.py's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from companion import warmup
from companion.core import _jit
from companion.core.cooperative_guidance import (CircumnavigationGuidance, CooperativeContext, SeparationFilter,
                                                 StandoffTrackingGuidance, _circumnavigation_acceleration_kernel,
                                                 _circumnavigation_velocity_kernel, _ccw_gap_kernel, _separation_kernel,
                                                 _tracking_kernel)
from companion.core.messages import NeighbourState

FUZZ = settings(max_examples=400, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
TWO_PI = 2.0 * math.pi


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


@FUZZ
@given(st.floats(allow_nan=False), st.floats(allow_nan=False))
def test_the_compiled_gap_is_pythons_float_modulo(a, b):
    """(b - a) mod 2 pi in [0, 2 pi): Python's float %, with the 2 pi it rounds to for a tiny negative difference
    taken as 0."""
    expected = (b - a) % TWO_PI
    assert _bits([_ccw_gap_kernel(a, b)]) == _bits([0.0 if expected >= TWO_PI else expected])


def test_an_advance_that_overflows_raises():
    huge = np.array([1.7e308, 0.0, 0.0])
    context = CooperativeContext(0.0, huge, np.array([1e308, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    law = CircumnavigationGuidance()
    with np.errstate(over="ignore"):  # the overflow is the input under test: it must raise, not warn
        with pytest.raises(ValueError, match="not finite"):
            context.advanced(1.0)
        with pytest.raises(ValueError, match="not finite"):
            law._velocity_after(context, 1.0)


@FUZZ
@given(contexts(), st.floats(-1.0, 1.0))
def test_advanced_is_what_the_constructors_build(context, horizon):
    """CooperativeContext.advanced(h) builds with fast_frozen what the validating constructors build from
    p + h v for the pursuer, the target and every neighbour (times moved by h, velocities kept)."""
    fast = context.advanced(horizon)
    reference = CooperativeContext(
        context.time + horizon, context.own_position + horizon * context.own_velocity, context.own_velocity,
        context.target_position + horizon * context.target_velocity, context.target_velocity,
        tuple(NeighbourState(n.ident, n.time + horizon, n.position + horizon * n.velocity, n.velocity)
              for n in context.neighbours), context.target_acceleration)
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


@FUZZ
@given(guard=separation_filters(), case=separation_cases())
def test_the_separation_filter_leaves_the_callers_command_alone(guard, case):
    own, velocity, command, neighbours = case
    before = command.copy()
    filtered = guard.filter(own, velocity, command, neighbours)
    assert np.isfinite(filtered).all() and filtered.shape == (3,)
    assert _bits(command) == _bits(before)


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
                                         np.array([n.velocity for n in neighbours]).reshape(-1, 3),
                                         guard._kernel_terms(), normals, bounds)
        seen.add("repelled" if not np.array_equal(repelled, command) else "not repelled")
        seen.add("threatened" if threatening else "not threatened")
        if threatening and float(np.linalg.norm(guard.filter(own, velocity, command, neighbours))) > 0.0:
            seen.add("constrained")
        if any(np.array_equal(n.position, own) for n in neighbours):
            seen.add("coincident")

    look()
    assert seen >= {"repelled", "not repelled", "threatened", "not threatened", "constrained", "coincident"}


@FUZZ
@given(contexts(), st.floats(0.0, 200.0))
def test_the_pipelines_moved_neighbours_are_what_the_constructor_builds(context, time):
    """FollowingPipeline._neighbours_at builds checked neighbours with fast_frozen; the reference builds them with
    the NeighbourState constructor, each moved at constant velocity to `time`."""
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


@FUZZ
@given(st.integers(1, 6).flatmap(lambda n: st.lists(st.lists(st.one_of(st.floats(-1e4, 1e4), st.sampled_from(
    [0.0, -0.0, math.pi, -math.pi, TWO_PI, -1e-300])), min_size=n, max_size=n), min_size=1, max_size=30)))
def test_the_spacing_errors_are_the_sorted_gaps_less_the_equal_share(rows):
    """Row by row: the counter-clockwise gaps between the sorted phases mod 2 pi, less 2 pi / n each."""
    from companion.core.cooperative_guidance import phase_spacing_error_rows, phase_spacing_errors

    phases = np.array(rows)
    computed = phase_spacing_error_rows(phases)
    for row, errors in zip(phases, computed):
        ordered = sorted(float(value) % TWO_PI for value in row)
        gaps = [later - earlier for earlier, later in zip(ordered, ordered[1:] + [ordered[0] + TWO_PI])]
        expected = [gap - TWO_PI / len(row) for gap in gaps]
        np.testing.assert_allclose(errors, expected, rtol=0.0, atol=1e-12)
        assert _bits(phase_spacing_errors(row)) == _bits(errors)
        assert abs(float(np.sum(errors))) <= 1e-12
    assert phase_spacing_errors([]).shape == (0,)
    with pytest.raises(ValueError, match="finite"):
        phase_spacing_error_rows(np.array([[0.0, math.nan]]))


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
def test_the_checked_vector_is_a_finite_float_vector_of_three(value):
    """_finite_vector: a float64 array of the value's numbers when it has shape (3,) and all are finite, else a
    ValueError naming the vector."""
    from companion.core.cooperative_guidance import _finite_vector

    array = np.asarray(value, dtype=float)
    if array.shape != (3,) or not np.isfinite(array).all():
        with pytest.raises(ValueError, match="v must be a finite vector of shape \\(3,\\)"):
            _finite_vector(value, "v")
        return
    actual = _finite_vector(value, "v")
    assert actual.dtype == np.float64 and _bits(actual) == _bits(array)


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
