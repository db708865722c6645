"""The in-process link's and bearing path's direct constructions against their definitions, bit for bit.

TargetFix's vector conversion (`_floats`) against Python's float of each entry; the steady spoofer's position
against numpy's sum; LinkFaults._log's FaultEvent and closed_loop._bearing's BearingMeasurement against their
constructors.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from interfaces import link_schema
from interfaces.link_schema import TargetFix

#: Awkward floats: zeros, subnormals, huge, the non-finite ones.
_EDGE_FLOATS = (0.0, -0.0, 5e-324, 1e-300, 1e16, 1.5e300, math.nan, math.inf, -math.inf, 0.1, 1 / 3, 1.5e6, 1e6)
floats = st.one_of(st.sampled_from(_EDGE_FLOATS), st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-2e6, 2e6), st.floats(-200.0, 200.0))
numbers = st.one_of(st.sampled_from(_EDGE_FLOATS), floats, st.integers(-2**64, 2**64), st.booleans())

# --- TargetFix's conversion of its vectors -------------------------------------------

@settings(max_examples=200)
@given(st.one_of(st.lists(floats, min_size=0, max_size=4).map(np.array),
                 st.lists(st.integers(-2**62, 2**62), min_size=3, max_size=3).map(np.array),
                 st.lists(floats, min_size=3, max_size=3).map(lambda v: np.array(v, dtype=np.float32)),
                 st.lists(floats, min_size=3, max_size=3), st.tuples(numbers, numbers, numbers)))
def test_target_fix_vectors_are_pythons_floats(values):
    """_floats(values) is tuple(float(v) for v in values), to the bit, and refuses what float() refuses."""
    def bits(vector):
        return [struct.pack("<d", v) for v in vector]
    try:
        expected = tuple(float(v) for v in values)
    except (TypeError, OverflowError) as error:
        with pytest.raises(type(error)):
            link_schema._floats(values)
        return
    got = link_schema._floats(values)
    assert all(type(v) is float for v in got) and bits(got) == bits(expected)


# --- the spoofer's position -------------------------------------------------------------

@settings(max_examples=200)
@given(st.tuples(*[st.floats(-1e6, 1e6)] * 3),
       st.one_of(st.tuples(*[st.floats(-1e3, 1e3)] * 3), st.tuples(*[st.integers(-1000, 1000)] * 3)))
def test_spoofed_position_is_numpys_sum(position, offset):
    """The steady spoofer's fix sits at np.array(genuine position) + np.array(spoof_offset) float for float."""
    from interfaces.scenario import FaultsConfig
    from sitl_plant.world.link_faults import LinkFaults
    config = FaultsConfig(spoof_rate_hz=5.0, spoof_offset=offset)
    faults = LinkFaults(config, np.random.default_rng(1))
    faults._attack_template = TargetFix("target-1", 4, 1.0, "ned", position, None, 9)
    spoofed = faults._spoofed(1.2)
    expected = tuple(np.array(position) + np.array(config.spoof_offset))
    assert [struct.pack("<d", v) for v in spoofed.position] == [struct.pack("<d", float(v)) for v in expected]


# --- the bearing sensor path --------------------------------------------------------

def test_harness_bearing_is_the_constructors():
    """studies.closed_loop._bearing builds the BearingMeasurement its constructor builds: the same fields in the same
    order, equal, immutable, with the same unit_direction."""
    from companion.core.messages import BearingMeasurement
    from studies.closed_loop import _bearing
    direction, position, true_direction = np.array([0.6, 0.8, 0.01]), (1.0, 2.0, 3.0), np.array([0.6, 0.8, 0.0])
    for range_ in (None, 8.5):
        built = BearingMeasurement(2.5, direction, position, range_, true_direction)
        fast = _bearing(2.5, direction, position, range_, true_direction)
        assert type(fast) is BearingMeasurement
        assert list(vars(fast).items()) == list(vars(built).items())
        assert repr(fast) == repr(built)
        assert np.array_equal(fast.unit_direction, built.unit_direction)
        with pytest.raises(AttributeError):
            fast.time = 3.0


def test_fault_events_are_the_constructors():
    """LinkFaults._log builds the FaultEvent its constructor builds (fields in order, equal, record, immutable)."""
    from interfaces.scenario import FaultsConfig
    from sitl_plant.world.link_faults import FaultEvent, LinkFaults
    faults = LinkFaults(FaultsConfig(loss_probability=0.5), np.random.default_rng(1))
    faults._log(1.25, "loss", "seq=3", seq=3)
    faults._log(2.5, "stall", "frozen")
    for event, built in zip(faults.events, (FaultEvent(1.25, "loss", "seq=3", {"seq": 3}), FaultEvent(2.5, "stall", "frozen"))):
        assert type(event) is FaultEvent and list(vars(event).items()) == list(vars(built).items())
        assert event == built and repr(event) == repr(built) and event.record() == built.record()
        with pytest.raises(AttributeError):
            event.kind = "x"
    assert faults.counters == {"loss": 1, "stall": 1}
