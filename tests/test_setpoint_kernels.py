"""The control tick's compiled form (control_chain.COMPILED_TRACKING's HNG tick: the tracking kernels of guidance.py
and attitude.py)
flies what the law objects' methods fly, a subclass flies its own law, and the warm-up compiles every setpoint
kernel. What each kernel computes is checked against the paper's equations in tests/test_attitude.py,
tests/test_guidance.py, tests/test_geometry.py and tests/test_excitation.py; a whole flight compiled against the
same flight in plain Python (BOF_NO_JIT=1) is tests/test_estimator_kernels.py's flight test.
"""

from __future__ import annotations

import numpy as np

from bitwise import assert_same

from companion import warmup
from companion.core import _jit, attitude, control_chain, guidance
from companion.core.attitude import VehicleLimits
from companion.core.control_chain import COMPILED_TRACKING, TickInputs, Tracking, compiled_hng_tracking
from companion.core.guidance import HelicalNavigationGuidance, RangeController
from companion.core.messages import TargetEstimate

python = _jit.python_function


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
    """Count the tracking command kernel's calls by the compiled tick (control_chain.compiled_hng_tracking), by
    whether it made the setpoint."""
    calls = {True: 0, False: 0}
    command_kernel = control_chain._tracking_command_kernel

    def counted(*args):
        calls[args[7]] += 1  # with_setpoint
        return command_kernel(*args)

    monkeypatch.setattr(control_chain, "_tracking_command_kernel", counted)
    return calls


def test_the_compiled_tick_is_the_methods_tick(monkeypatch):
    """FollowingPipeline._compute_setpoint with HNG's compiled tick (control_chain.compiled_hng_tracking: the two
    tracking kernels) against the same pipeline without it (the law objects' methods, then the adjustments):
    whole flights with dropouts (coasting, degraded, blends) and the health actions, every series bit for bit,
    with the compiled tick taken out of COMPILED_TRACKING. The compiled tick runs, with the setpoint in its kernel
    (the flight without the safety envelope) and without (a blend or the envelope: the adjustments then follow
    it)."""
    calls = _count_compiled_ticks(monkeypatch)
    compiled = _flights()
    assert calls[True] > 100 and calls[False] > 0
    counted_so_far = dict(calls)
    monkeypatch.delitem(COMPILED_TRACKING, HelicalNavigationGuidance)
    methods = _flights()
    assert calls == counted_so_far  # the methods only
    for fast, slow in zip(compiled, methods):
        assert fast.keys() == slow.keys()
        for key in fast:
            assert_same(fast[key], slow[key], key)


def test_a_subclass_flies_its_own_law(monkeypatch):
    """A compiled tick belongs to the exact class it is registered for: a subclass of HNG (which may change the
    law) flies through its own methods, never its parent's compiled tick. An unchanged subclass flies the same flight
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
    estimate = TargetEstimate(1.0, np.array([10.0, 0.0, -5.0]), np.zeros(3), np.eye(6))
    tick = TickInputs(1.0, 1.0, estimate, np.zeros(3), np.array([1.0, 0.0, 0.0]))
    terms = VehicleLimits(0.5, max_tilt=0.5, gravity=9.81, mass=1.0).setpoint_terms
    assert compiled_hng_tracking(Tracking(law, Other(8.0)), tick, terms, True, None) is None
    parts, command, setpoint = compiled_hng_tracking(Tracking(law, RangeController(8.0)), tick, terms, True, None)
    assert setpoint is not None and parts.excitation_level is None  # a setpoint, no excitation
    np.testing.assert_array_equal(command, parts.lateral + parts.longitudinal)
    # The methods' command of the same tick.
    methods = Tracking(law, RangeController(8.0)).command(tick)
    assert_same(methods.lateral, parts.lateral, "lateral")
    assert_same(methods.longitudinal, parts.longitudinal, "longitudinal")


def test_warm_up_compiles_the_setpoint_kernels():
    warmup.warm_up()
    from companion.core.geometry import relative_terms_kernel as _relative_terms
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
