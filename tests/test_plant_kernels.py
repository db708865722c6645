"""The plant's scalar kernels (sitl_plant.vehicle.kernels): compiled and plain Python agree bit for bit.

With numba installed (the `test` extra has it) every kernel is compiled by sitl_plant._jit; its
`py_func` is the same function run as plain Python. Both run the same IEEE operations in the same
order (njit without fastmath does not reassociate or fuse into FMA, and sqrt/exp are the correctly
rounded sqrt and the C library's exp in both), so the results are compared as bit patterns, not
with a tolerance. The classes call these kernels: a vehicle's advance is advance_steps' result.
A whole in-process flight with BOF_NO_JIT=1 (in a child interpreter) gives the same summary,
figure for figure, as the compiled one.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sitl_plant import _jit
from sitl_plant.vehicle import kernels
from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle, GeometricAttitudeController, Mixer
from sitl_plant.vehicle.params import table1_params
from sitl_plant.vehicle.quadrotor import Quadrotor

# deadline=None on the property tests: with numba, a kernel's first call in a process loads or
# compiles it (tests/conftest.py warms the kernels up first, but a lone test file may run alone).
PARAMS = table1_params()
ROOT = Path(__file__).resolve().parent.parent
KERNELS = ("quaternion_to_rotation", "rotor_wrench", "rigid_body_rhs", "rk4_step", "error_quaternion",
           "attitude_torque", "mixer_speeds", "advance_steps", "is_rotation", "quaternion_from_matrix",
           "setpoint_quaternion")


def bits(value) -> list[str]:
    """Flatten nested tuples of floats into their exact bit patterns (float.hex keeps -0.0 apart)."""
    if isinstance(value, tuple):
        return [b for item in value for b in bits(item)]
    assert type(value) is float, f"{value!r} is a {type(value).__name__}, not a float"
    return [value.hex()]


def same(kernel, *args) -> tuple:
    """Run the kernel compiled and as plain Python; assert equal bits; return the result."""
    compiled = getattr(kernels, kernel)(*args)
    plain = getattr(kernels, kernel).py_func(*args)
    assert bits(compiled) == bits(plain)
    return compiled


def real(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


unit_quaternions = st.tuples(real(-1.0, 1.0), real(-1.0, 1.0), real(-1.0, 1.0), real(-1.0, 1.0)).filter(
    lambda q: sum(c * c for c in q) > 1e-6
).map(lambda q: tuple(c / math.sqrt(sum(x * x for x in q)) for c in q))
vectors = st.tuples(real(-30.0, 30.0), real(-30.0, 30.0), real(-30.0, 30.0))
rates = st.tuples(real(-20.0, 20.0), real(-20.0, 20.0), real(-20.0, 20.0))
speeds = st.tuples(*(real(0.0, PARAMS.max_rotor_speed) for _ in range(4)))
# Airframes around Table I's, so the constants are not one fixed set.
airframes = st.builds(
    lambda mass, inertia, arm, c_t, c_m, drag, kp, kd: dataclasses.replace(
        PARAMS, mass=mass, inertia=inertia, arm_length=arm, thrust_coefficient=c_t, moment_coefficient=c_m,
        drag_coefficient=drag, attitude_kp=kp, attitude_kd=kd),
    real(0.2, 5.0), st.tuples(real(1e-3, 0.1), real(1e-3, 0.1), real(1e-3, 0.2)), real(0.05, 0.5),
    real(1e-6, 1e-4), real(1e-8, 1e-6), real(0.0, 1.0), real(0.01, 2.0), real(0.001, 1.0),
)
states = st.tuples(vectors, vectors, unit_quaternions, rates).map(lambda parts: tuple(float(x) for p in parts for x in p))


def test_the_compiled_path_is_the_one_under_test():
    """numba is in the `test` extra: unless BOF_NO_JIT asks for plain Python, every kernel is compiled."""
    numba_present = importlib.util.find_spec("numba") is not None
    assert _jit.ENABLED == (numba_present and not _jit.DISABLED_BY_ENVIRONMENT)
    if not _jit.DISABLED_BY_ENVIRONMENT:
        assert numba_present, "the test extra installs numba: pip install -e '.[test]'"
    for name in KERNELS:
        kernel = getattr(kernels, name)
        assert (kernel is not kernel.py_func) == _jit.ENABLED, name


@settings(max_examples=200, deadline=None)
@given(q=unit_quaternions)
def test_quaternion_to_rotation(q):
    same("quaternion_to_rotation", *q)


@settings(max_examples=200, deadline=None)
@given(w=speeds, airframe=airframes)
def test_rotor_wrench(w, airframe):
    same("rotor_wrench", *w, kernels.plant_constants(airframe))


@settings(max_examples=200, deadline=None)
@given(s=states, wrench=st.tuples(real(0.0, 60.0), real(-2.0, 2.0), real(-2.0, 2.0), real(-0.5, 0.5)), airframe=airframes)
def test_rigid_body_rhs(s, wrench, airframe):
    same("rigid_body_rhs", s[3:6], s[6:10], s[10:13], wrench, kernels.plant_constants(airframe))


@settings(max_examples=200, deadline=None)
@given(s=states, w=speeds, command=speeds, h=real(1e-4, 0.02), tau=real(0.005, 0.1), airframe=airframes)
def test_rk4_step(s, w, command, h, tau, airframe):
    lag_half, lag_full = math.exp(-0.5 * h / tau), math.exp(-h / tau)
    state, rotors = same("rk4_step", h, lag_half, lag_full, s, w, *command, kernels.plant_constants(airframe))
    assert len(state) == 13 and len(rotors) == 4


@settings(max_examples=200, deadline=None)
@given(q=unit_quaternions, qd=unit_quaternions)
def test_error_quaternion(q, qd):
    same("error_quaternion", q, qd)


@settings(max_examples=200, deadline=None)
@given(q=unit_quaternions, w=rates, qd=unit_quaternions, wd=rates, wd_dot=rates, feed_forward=st.booleans(),
       airframe=airframes)
def test_attitude_torque(q, w, qd, wd, wd_dot, feed_forward, airframe):
    same("attitude_torque", q, w, qd, wd, wd_dot, feed_forward, kernels.control_constants(airframe))


@settings(max_examples=300, deadline=None)
@given(thrust=real(-10.0, 3.0 * PARAMS.max_total_thrust), torque=st.tuples(real(-3.0, 3.0), real(-3.0, 3.0), real(-1.0, 1.0)),
       airframe=airframes)
def test_mixer_speeds(thrust, torque, airframe):
    """Thrust and torque reach well past saturation, so every branch of the policy runs."""
    result = same("mixer_speeds", thrust, *torque, kernels.mixer_constants(airframe))
    assert all(0.0 <= x <= airframe.max_rotor_speed for x in result)


@settings(max_examples=100, deadline=None)
@given(s=states, w=speeds, qd=unit_quaternions, thrust=real(-5.0, 2.0 * PARAMS.max_total_thrust),
       n=st.integers(0, 40), airframe=airframes)
def test_advance_steps(s, w, qd, thrust, n, airframe):
    h = 0.002
    tau = airframe.motor_time_constant
    same("advance_steps", n, h, math.exp(-0.5 * h / tau), math.exp(-h / tau), s, w, qd, thrust,
         kernels.plant_constants(airframe), kernels.control_constants(airframe), kernels.mixer_constants(airframe))


def test_the_vehicle_advances_by_the_kernel():
    """AttitudeThrustVehicle.advance is advance_steps (compiled or not) on its state: same bits as py_func."""
    vehicle = AttitudeThrustVehicle(PARAMS, rng=0)
    tilt = (math.cos(0.2), math.sin(0.2), 0.0, 0.0)
    vehicle.set_attitude_target_quaternion(tilt, 1.1 * PARAMS.hover_thrust)
    plant = vehicle.quadrotor
    h = vehicle.dt
    expected = kernels.advance_steps.py_func(
        25, h, math.exp(-0.5 * h / PARAMS.motor_time_constant), math.exp(-h / PARAMS.motor_time_constant),
        plant._s, plant._w, tilt, 1.1 * PARAMS.hover_thrust, kernels.plant_constants(PARAMS),
        kernels.control_constants(PARAMS), kernels.mixer_constants(PARAMS))
    vehicle.advance(25 * h)
    assert bits((plant._s, plant._w)) == bits(expected)
    assert expected[0][:3] != (0.0, 0.0, 0.0)  # it moved


def test_the_public_api_never_compiles_a_second_version():
    """A new plant has its kernels ready (Quadrotor's constructor warms them up, so sitl-plant's paced
    loop never stalls on a compilation), and ints or numpy scalars at the public boundary reach the
    kernels as floats: one compiled signature per kernel, whatever the caller passed."""
    quad = Quadrotor(PARAMS)
    if _jit.ENABLED:
        # (the kernels Python calls compiled; these three it calls only as plain functions, and other kernels call
        # them compiled: from numba's cache they get no signature of their own)
        only_inside = ("quaternion_to_rotation", "is_rotation", "quaternion_from_matrix")
        assert all(getattr(kernels, name).signatures for name in KERNELS if name not in only_inside)
    quad.step(1, np.array([0, 1000, 0, 1000]))
    assert quad.total_thrust > 0.0 and quad.acceleration.shape == (3,) and quad.body_torque.shape == (3,)
    controller, mixer = GeometricAttitudeController(PARAMS), Mixer(PARAMS)
    torque = controller.torque(np.eye(3, dtype=int), np.array([1, 0, 0]), np.eye(3), np.array([0, 1, 0]), np.zeros(3, dtype=int))
    assert np.all(np.isfinite(torque))
    assert controller.attitude_error(np.eye(3, dtype=int), np.eye(3)).tolist() == [0.0, 0.0, 0.0]
    assert mixer.rotor_speeds(np.float32(10), np.array([0, 0, 0])).shape == (4,)
    vehicle = AttitudeThrustVehicle(PARAMS, rng=0)
    vehicle.set_attitude_target(np.eye(3, dtype=int), 10)
    vehicle.set_attitude_target_quaternion((1, 0, 0, 0), np.float64(10))
    vehicle.advance(0.01)
    vehicle.set_attitude_target_quaternion((1, 0, 0, 0), 10)
    vehicle.advance(np.float32(0.01))
    if _jit.ENABLED:
        from numba.core.types import unliteral

        for name in KERNELS:
            # A kernel called from another compiled kernel with a constant (advance_steps passes feed_forward=False)
            # is also specialised on that literal when the cache is empty: compiled with its caller, not at run time.
            signatures = {tuple(unliteral(kind) for kind in signature) for signature in getattr(kernels, name).signatures}
            assert len(signatures) <= 1, (name, getattr(kernels, name).signatures)


def _assert_same_figures(actual, expected, where: str) -> None:
    """Nested JSON values equal, floats within 1e-9 relative (1e-12 absolute near zero)."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict) and set(actual) == set(expected), where
        for key in expected:
            _assert_same_figures(actual[key], expected[key], f"{where}.{key}")
    elif isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), where
        for i, (a, e) in enumerate(zip(actual, expected)):
            _assert_same_figures(a, e, f"{where}[{i}]")
    elif isinstance(expected, float) and not isinstance(actual, bool):
        assert actual == pytest.approx(expected, rel=1e-9, abs=1e-12, nan_ok=True), (where, actual, expected)
    else:
        assert actual == expected, (where, actual, expected)


FLIGHT = """
import json, sys
from sitl_plant import _jit
from interfaces.scenario import load_scenario
from studies.closed_loop import simulate
scenario, vehicle = load_scenario(sys.argv[1])
print(_jit.ENABLED)
print(json.dumps(simulate(scenario, vehicle, 1).summary, sort_keys=True, default=str))
"""


def test_a_whole_flight_is_the_same_without_the_compiler(scenario_path):
    """constant_velocity, seed 1, 60 s: the summary of the plain-Python flight (BOF_NO_JIT=1, child
    interpreter: plant and companion kernels alike) equals the compiled one within 1e-9 relative, every figure
    (compiled and plain code round a few operations differently in the last bit; JSON keeps a float's repr)."""
    from interfaces.scenario import load_scenario
    from studies.closed_loop import simulate

    path = scenario_path("constant_velocity")
    environment = dict(os.environ, BOF_NO_JIT="1", PYTHONPATH=os.pathsep.join(
        [str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])))
    child = subprocess.run([sys.executable, "-c", FLIGHT, str(path)], env=environment, cwd=ROOT,
                           capture_output=True, text=True, timeout=600, check=False)
    assert child.returncode == 0, child.stderr
    compiled, plain = child.stdout.splitlines()
    assert compiled == "False"

    scenario, vehicle = load_scenario(path)
    here = json.dumps(simulate(scenario, vehicle, 1).summary, sort_keys=True, default=str)
    summary = json.loads(here)
    _assert_same_figures(summary, json.loads(plain), "summary")
    assert summary["duration"] == pytest.approx(60.0) and summary["termination"] == "completed"
