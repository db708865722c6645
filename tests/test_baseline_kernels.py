"""The baseline estimators' kernels (companion/core/baseline_estimators.py) against independent references, and
whole flights compiled against the same flights in plain Python.

- `_jit.remainder` (math.remainder, which numba lacks), compiled and interpreted, against CPython's math.remainder
  on any floats, its ValueError included;
- the EKF's measurement update against the textbook Joseph form solved by scipy.linalg, and `_symmetric_psd`
  against Higham's nearest PSD matrix from scipy's eigh;
- whole flights of the three baselines (the estimator study's setup, 50 Hz) compiled in this process against the
  same flights in a BOF_NO_JIT=1 subprocess: every logged series within 1e-9 relative; and the warm-up compiling
  every kernel they call.
The angle conventions, Jacobians (central differences), MSC transforms and the filters' behaviour are
tests/test_baseline_estimators.py's.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st
from bitwise import assert_close_series, assert_same, seeds
from paper_reference import floats, symmetric_with_eigenvalues

from companion.core import _jit
from companion.core import baseline_estimators as be

ROOT = Path(__file__).resolve().parent.parent
python = _jit.python_function


def covariance(seed: int, size: int, exponent: int) -> np.ndarray:
    """A random symmetric positive definite matrix (size, size) of scale 10^exponent."""
    factor = np.random.default_rng(seed).normal(size=(size, size))
    return (factor @ factor.T + 1e-3 * np.eye(size)) * 10.0**exponent


@_jit.jit
def _compiled_remainder(x: float, y: float) -> float:
    return _jit.remainder(x, y)


@settings(max_examples=500, deadline=None)
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, math.pi, -math.pi, 5e-324])),
       st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 2.0 * math.pi, 5e-324])))
def test_remainder_is_math_remainder(x, y):
    """Any floats, infinities, NaN, zeros of either sign and subnormals: math.remainder's value (exact: the same
    float), and its ValueError where it raises one (an infinite x, a zero y), from a kernel and from Python."""
    for function in (_compiled_remainder, python(_jit.remainder)):
        try:
            expected = math.remainder(x, y)
        except ValueError:
            with pytest.raises(ValueError):
                function(x, y)
        else:
            assert_same(function(x, y), expected)


@settings(max_examples=300, deadline=None)
@given(seeds, st.sampled_from([2, 3]), st.integers(-6, 8), st.integers(-8, 0))
def test_kalman_update_is_the_joseph_form(seed, size, exponent, noise_exponent):
    """K = P H^T S^-1 with S = H P H^T + R, x+ = x + K nu, P+ = (I - K H) P (I - K H)^T + K R K^T."""
    rng = np.random.default_rng(seed)
    state = rng.normal(size=6) * 30.0
    prior = covariance(seed, 6, exponent)
    h = rng.normal(size=(size, 6)) * 10.0 ** rng.integers(-3, 2, size=(size, 1))
    r = covariance(seed + 1, size, noise_exponent)
    residual = rng.normal(size=size) * 10.0**noise_exponent
    innovation_covariance = h @ prior @ h.T + r
    gain = scipy.linalg.solve(innovation_covariance, h @ prior, assume_a="pos").T
    i_kh = np.eye(6) - gain @ h
    expected_covariance = i_kh @ prior @ i_kh.T + gain @ r @ gain.T
    updated, updated_covariance = be._kalman_update(state, prior, residual, h, r)
    np.testing.assert_allclose(be._innovation_covariance(prior, h, r), innovation_covariance, rtol=1e-12,
                               atol=1e-12 * float(np.abs(innovation_covariance).max()))
    correction = gain @ residual
    np.testing.assert_allclose(updated, state + correction, rtol=1e-13, atol=1e-6 * float(np.abs(correction).max()))
    np.testing.assert_array_equal(updated_covariance, updated_covariance.T)
    np.testing.assert_allclose(updated_covariance, expected_covariance, rtol=0.0,
                               atol=1e-6 * float(np.abs(prior).max()))


@settings(max_examples=300, deadline=None)
@given(seeds, st.lists(floats(-1.0, 1.0), min_size=6, max_size=6), st.integers(-8, 8),
       st.sampled_from(["any", "psd_singular", "tiny_negative"]), floats(0.0, 1e-3))
def test_symmetric_psd_is_highams_nearest_psd_matrix(seed, values, exponent, kind, asymmetry):
    """The symmetric part with its negative eigenvalues set to 0 (scipy's eigh), and a symmetric PSD input
    returned as it is; slightly asymmetric inputs as a congruence leaves them."""
    matrix = symmetric_with_eigenvalues(seed, np.array(values), exponent, kind)
    matrix = matrix + asymmetry * np.triu(matrix, 1)
    symmetric = 0.5 * (matrix + matrix.T)
    eigenvalues, vectors = scipy.linalg.eigh(symmetric)
    repaired = be._symmetric_psd(matrix)
    np.testing.assert_array_equal(repaired, repaired.T)
    largest = float(np.abs(eigenvalues).max())
    if eigenvalues[0] > 1e-12 * largest:  # clearly PSD (a zero eigenvalue's sign is rounding noise)
        assert_same(repaired, symmetric)
    expected = (vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T
    np.testing.assert_allclose(repaired, expected, rtol=0.0, atol=1e-12 * largest)


# --- whole flights, compiled and interpreted ---------------------------------------------------------------------


_FLIGHTS = """
import sys
import numpy as np
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies.closed_loop import simulate
from studies.montecarlo import ESTIMATORS, GUIDANCE, PAPER_INITIAL_BOX, PAPER_SYSTEM, drawn_initial_position, with_overrides

def flight(estimator):
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    flown = with_overrides(scenario, {**PAPER_SYSTEM, **ESTIMATORS[estimator], **GUIDANCE["hng"], "sensor.rate_hz": 50.0,
                                      "simulation.duration": 20.0, "simulation.summary_window": 10.0,
                                      "estimator.initialize": "position",
                                      "estimator.initial_position": drawn_initial_position(2, PAPER_INITIAL_BOX)})
    return simulate(flown, vehicle, seed=2).series

if __name__ == "__main__":
    for estimator in ("ekf", "msc_ekf", "ekf_rae"):
        np.savez(sys.argv[1] + estimator + ".npz", **flight(estimator))
"""


def test_baseline_flights_are_the_same_compiled_and_interpreted(tmp_path):
    """The estimator study's flights of the three baselines (constant_velocity, HNG, 50 Hz bearings, the initial
    estimate of seed 2, 20 s): every logged series flown here (compiled when numba is installed) is the one a
    BOF_NO_JIT=1 interpreter flies, within 1e-9 relative."""
    namespace: dict = {}
    exec(compile(_FLIGHTS, "flights", "exec"), namespace)
    prefix = str(tmp_path / "interpreted_")
    environment = dict(os.environ, BOF_NO_JIT="1", PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    subprocess.run([sys.executable, "-c", _FLIGHTS, prefix], check=True, cwd=ROOT, env=environment, timeout=900)
    for estimator in ("ekf", "msc_ekf", "ekf_rae"):
        here = namespace["flight"](estimator)
        there = np.load(prefix + estimator + ".npz")
        assert sorted(there.files) == sorted(here)
        for name in here:
            assert_close_series(here[name], there[name], f"{estimator} {name}")


_WARM_UP_THEN_FLY = _FLIGHTS.replace('if __name__ == "__main__":', '''def compiled_signatures():
    from companion.core import baseline_estimators
    return {name: len(getattr(baseline_estimators, name).signatures) for name in dir(baseline_estimators)
            if hasattr(getattr(baseline_estimators, name), "signatures")}

if __name__ == "__main__":
    from companion import warmup
    warmup.warm_up()
    before = compiled_signatures()
    for estimator in ("ekf", "msc_ekf", "ekf_rae"):
        flight(estimator)
    print(before == compiled_signatures(), sum(before.values()))
    sys.exit(0)''')


def test_warm_up_compiles_every_kernel_a_baseline_flight_calls():
    """In a fresh interpreter, after warmup.warm_up(), flights of the three baselines compile nothing more. (Without
    numba the kernels are their Python functions, and warm_up has nothing to do.)"""
    if not _jit.ENABLED:
        for kernel in (be._linear_predict, be._az_el_correct, be._msc_propagate, be._msc_correct, be._msc_to_absolute,
                       be._flight_path_predict, be._range_az_el_correct, be._flight_path_to_cartesian):
            assert python(kernel) is kernel and not hasattr(kernel, "signatures")
        return
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    output = subprocess.run([sys.executable, "-c", _WARM_UP_THEN_FLY, "unused"], check=True, cwd=ROOT, env=environment,
                            timeout=900, capture_output=True, text=True).stdout.split()
    assert output[0] == "True" and int(output[1]) >= 10
