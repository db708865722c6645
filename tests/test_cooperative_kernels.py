"""The cooperative laws' kernels (issue 16) against the code they replaced, bit for bit.

The reference below is a VERBATIM COPY of CircumnavigationGuidance.desired_velocity and of the feed-forward it was
flown with (_tracking_acceleration over CooperativeContext.advanced, the helpers phase, phase_gaps, _ccw_gap,
_planar, _ned, _rot90, _saturate, geometry.norm) as they were at 1c852b6, before the law became
_circumnavigation_velocity_kernel. Contexts are drawn at random (neighbours at any phase, the pursuer above the
target, capped and uncapped relative speeds) and the law's outputs must equal the reference's to the last bit, with
the kernel compiled and as plain Python.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.core import _jit
from companion.core.cooperative_guidance import (CircumnavigationGuidance, CooperativeContext,
                                                 _circumnavigation_velocity_kernel, _ccw_gap_kernel)
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


def _ref_acceleration(self, context):
    desired_velocity = lambda c: _ref_desired_velocity(self, c)
    velocity_gain, feedforward_horizon, max_acceleration = self.velocity_gain, self.feedforward_horizon, self.max_acceleration
    u = desired_velocity(context)
    command = velocity_gain * (u - context.own_velocity)
    if feedforward_horizon > 0.0:
        command = command + (desired_velocity(_ref_advanced(context, feedforward_horizon))
                             - desired_velocity(_ref_advanced(context, -feedforward_horizon))) / (2.0 * feedforward_horizon)
    if context.target_acceleration is not None:
        command = command + context.target_acceleration
    return _ref_saturate(command, max_acceleration)


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
        monkeypatch.setattr(module, "_circumnavigation_velocity_kernel",
                            _jit.python_function(_circumnavigation_velocity_kernel))
        monkeypatch.setattr(module, "_ccw_gap_kernel", _jit.python_function(_ccw_gap_kernel))
    return request.param


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
    """After _jit.warm_up, a control tick of the law compiles nothing more (the same argument types)."""
    _jit.warm_up()
    if not _jit.ENABLED:
        assert _jit.python_function(_circumnavigation_velocity_kernel) is _circumnavigation_velocity_kernel
        return
    compiled = list(_circumnavigation_velocity_kernel.signatures)
    assert compiled
    neighbours = tuple(NeighbourState(k, 1.0, np.array([5.0 * k, 1.0, -20.0]), np.ones(3)) for k in (2, 3))
    for present in ((), neighbours):
        CircumnavigationGuidance().acceleration(CooperativeContext(
            1.0, np.array([0.0, 0.0, -20.0]), np.ones(3), np.array([30.0, 5.0, -20.0]), np.ones(3), present))
    assert list(_circumnavigation_velocity_kernel.signatures) == compiled
