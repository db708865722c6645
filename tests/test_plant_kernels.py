"""The plant's kernels (sitl_plant.vehicle.kernels): the compiled path is the one flown, the classes fly the
kernels, one compiled signature per kernel, and a whole in-process flight with BOF_NO_JIT=1 (in a child
interpreter) gives the same summary as the compiled one within 1e-9 relative. What the kernels compute is checked
against physics in tests/test_plant.py and tests/test_position_control.py.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sitl_plant import _jit
from sitl_plant.vehicle import kernels
from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle, GeometricAttitudeController, Mixer
from sitl_plant.vehicle.params import table1_params
from sitl_plant.vehicle.quadrotor import Quadrotor

PARAMS = table1_params()
ROOT = Path(__file__).resolve().parent.parent
KERNELS = ("quaternion_to_rotation", "rotor_wrench", "rigid_body_rhs", "rk4_step", "error_quaternion",
           "attitude_torque", "mixer_speeds", "advance_steps", "is_rotation", "quaternion_from_matrix",
           "setpoint_quaternion")


def test_the_compiled_path_is_the_one_under_test():
    """numba is in the `test` extra: unless BOF_NO_JIT asks for plain Python, every kernel is compiled."""
    numba_present = importlib.util.find_spec("numba") is not None
    assert _jit.ENABLED == (numba_present and not _jit.DISABLED_BY_ENVIRONMENT)
    if not _jit.DISABLED_BY_ENVIRONMENT:
        assert numba_present, "the test extra installs numba: pip install -e '.[test]'"
    for name in KERNELS:
        kernel = getattr(kernels, name)
        assert (kernel is not kernel.py_func) == _jit.ENABLED, name


def test_the_vehicle_advances_by_the_kernel():
    """AttitudeThrustVehicle.advance is advance_steps on its state: what the plain-Python kernel computes, to
    rounding."""
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
    np.testing.assert_allclose(np.array(plant._s + plant._w), np.array(expected[0] + expected[1]), rtol=1e-12,
                               atol=1e-12)
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
