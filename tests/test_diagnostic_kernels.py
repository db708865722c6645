"""The bearing path's diagnostic kernels (health.py, observability.py, geometry.relative_range_std, the pipeline's
re-acquisition gate) give the results of the code they replaced, bit for bit, compiled (numba) and interpreted.

The reference is the OLD implementation, copied verbatim below from before the kernels (numpy's pinv(hermitian=True),
eigvalsh, norm, trace, clip, Python's `**`). Evidence:
- the LAPACK leaves: numba's eigh/eigvalsh (scipy's dsyevd) against numpy's (its own dsyevd) on random symmetric
  matrices (positive definite, rank-deficient, indefinite, the u-PLKF's rank-2 and the baseline EKFs' 2x2 innovation
  covariances, windowed FIMs), eigenvalues and eigenvectors bit for bit;
- the NIS against numpy's pinv on the same families, on every tie pattern of a diagonal covariance (the order of
  equal singular values is argsort's, numpy's and numba's agree) and on non-finite covariances (numpy in object
  mode: the same NaN, the same LinAlgError);
- the windowed FIM (add, measure, the window's drop) against the old class on random windows, and its ValueErrors
  (and OverflowErrors) for bad input;
- HealthMonitor.update's geometry, relative_range_std and the gate against the old arithmetic;
- each kernel compiled against its own Python function (`kernel.py_func`);
- a 50 Hz baseline-EKF flight compiled against the same flight in a BOF_NO_JIT=1 subprocess (the default
  IMM flight is tests/test_estimator_kernels.py's), and warm_up compiling every diagnostic kernel.
"""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from bitwise import assert_same, seeds
from paper_reference import floats, symmetric_with_eigenvalues, unit_vectors

from companion.core import _jit, geometry, health, observability, pipeline
from companion import warmup
from companion.core.geometry import unit
from companion.core.observability import WindowedObservability, _check_bearings, _check_ranges, _check_sigma

# The old code warns (numpy's RuntimeWarning) where a degenerate input divides by zero or takes the square root of a
# negative number; the compiled kernels give the same values without numpy's warning.
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
ROOT = Path(__file__).resolve().parent.parent
python = _jit.python_function


def outcome(function, *args):
    """function(*args), or (exception type, message) when it raises."""
    try:
        return function(*args)
    except Exception as error:  # noqa: BLE001 - the exception itself is the result compared
        return type(error), str(error)


# ----- the old implementation (before the kernels), verbatim -----------------------------------------------------

def old_normalized_innovation_squared(innovation, covariance):
    y = np.asarray(innovation, dtype=float)
    s = np.asarray(covariance, dtype=float)
    return float(y @ np.linalg.pinv(s, rcond=1e-10, hermitian=True) @ y)


def old_norm(vector):
    return float(np.linalg.norm(vector))


def old_relative_range_std(relative_position, position_covariance):
    distance = geometry.norm(relative_position)
    if distance <= 1e-9:
        return float("inf")
    los = relative_position / distance
    return float(np.sqrt(max(float(los @ position_covariance @ los), 0.0))) / distance


def old_health_geometry(bearing_direction, pursuer_position, pursuer_velocity, estimate_position, estimate_covariance):
    """HealthMonitor.update's geometry as it was: (range_estimate, relative_std, cheirality dot, speed)."""
    relative = np.asarray(estimate_position, float) - np.asarray(pursuer_position, float)
    range_estimate = float(np.linalg.norm(relative))
    relative_std = math.nan
    if range_estimate > 1e-9:
        relative_std = old_relative_range_std(relative, np.asarray(estimate_covariance)[:3, :3])
    cosine = float(np.asarray(bearing_direction, float) @ relative)
    speed = float(np.linalg.norm(pursuer_velocity))
    return range_estimate, relative_std, cosine, speed


def old_gate(relative, covariance, direction, bearing_noise_std, gate_sigma):
    """FollowingPipeline._agrees_with_prediction's arithmetic as it was (estimate.covariance (6, 6))."""
    distance = float(np.linalg.norm(relative))
    if distance < 1e-6:
        return False
    predicted = relative / distance
    measured = unit(direction)
    angle = float(np.arccos(np.clip(predicted @ measured, -1.0, 1.0)))
    across = np.eye(3) - np.outer(predicted, predicted)
    lateral_variance = float(np.trace(across @ covariance[:3, :3] @ across)) / 2.0
    angular_std = float(np.sqrt(lateral_variance / distance**2 + bearing_noise_std**2))
    return angle <= gate_sigma * angular_std


class OldWindowedObservability:
    _SINGULAR_TOLERANCE = 1e-12

    def __init__(self, window_s: float, sigma: float) -> None:
        window_s = float(window_s)
        if not math.isfinite(window_s) or window_s <= 0.0:
            raise ValueError(f"window_s must be positive and finite, got {window_s!r}")
        self.window_s = window_s
        self.sigma = _check_sigma(sigma)
        self._samples = deque()
        self._information = np.zeros((3, 3))
        self._latest_time = -math.inf

    def add(self, time, bearing, range_estimate):
        time = float(time)
        if not math.isfinite(time) or time < self._latest_time:
            raise ValueError(f"time must be finite and non-decreasing, got {time!r}")
        bearing = _check_bearings(np.asarray(bearing, dtype=float).reshape(1, 3))[0]
        range_estimate = float(_check_ranges(np.array([range_estimate], dtype=float), 1)[0])
        contribution = (np.eye(3) - np.outer(bearing, bearing)) / (self.sigma**2 * range_estimate**2)
        self._samples.append((time, contribution))
        self._information += contribution
        self._latest_time = time
        self._drop_older_than(time - self.window_s)

    def _drop_older_than(self, cutoff):
        while self._samples and self._samples[0][0] < cutoff:
            _, contribution = self._samples.popleft()
            self._information -= contribution
        if not self._samples:
            self._information = np.zeros((3, 3))

    @property
    def information(self):
        return self._information.copy()

    def measure(self):
        eigenvalues = np.linalg.eigvalsh(self._information)
        largest = float(eigenvalues[-1])
        eigenvalues = np.where(eigenvalues <= self._SINGULAR_TOLERANCE * max(largest, 0.0), 0.0, eigenvalues)
        if largest <= 0.0:
            eigenvalues = np.zeros(3)
        minimum = float(eigenvalues[0])
        log_det = float(np.sum(np.log10(eigenvalues))) if minimum > 0.0 else -math.inf
        mean = float(eigenvalues.mean())
        spread = float(np.sum((eigenvalues - mean) ** 2) / mean**2) if mean > 0.0 else math.nan
        return {"log_det": log_det, "min_eigenvalue": minimum, "spread": spread, "count": len(self._samples)}


# ----- covariances ---------------------------------------------------------------------------------------------

def uplkf_innovation_covariance(seed: int, exponent: int, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The u-PLKF's bearing pseudo-measurement covariance, rank 2: S = P_l (C + floor I) P_l with P_l = I - l l^T
    for a random unit l and a random positive definite C of scale 10^exponent (floor: a fraction of that scale),
    and an innovation in S's range (what P_l (p^-_T - p) gives)."""
    rng = np.random.default_rng(seed)
    los = rng.normal(size=3)
    los /= np.linalg.norm(los)
    across = np.eye(3) - np.outer(los, los)
    factor = rng.normal(size=(3, 3))
    inner = (factor @ factor.T + floor * np.eye(3)) * 10.0**exponent
    return across @ inner @ across, across @ rng.normal(size=3) * 10.0 ** (exponent / 2)


def ekf_innovation_covariance(seed: int, exponent: int) -> tuple[np.ndarray, np.ndarray]:
    """A baseline EKF's 2x2 innovation covariance H P H^T + R (angles, rad^2) and an angle residual."""
    rng = np.random.default_rng(seed)
    jacobian = rng.normal(size=(2, 6)) * 10.0**exponent
    factor = rng.normal(size=(6, 6))
    covariance = jacobian @ (factor @ factor.T) @ jacobian.T + 1e-6 * np.eye(2)
    return 0.5 * (covariance + covariance.T), rng.normal(size=2) * 10.0 ** (exponent / 2)


def fim(seed: int, count: int) -> np.ndarray:
    """A windowed FIM of eq. (7): count bearings near one direction at ranges 5-100 m, sigma 0.01."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=3)
    information = np.zeros((3, 3))
    for _ in range(count):
        bearing = base + rng.normal(size=3) * 10.0 ** rng.uniform(-4, 0)
        bearing /= np.linalg.norm(bearing)
        information += (np.eye(3) - np.outer(bearing, bearing)) / (0.01**2 * rng.uniform(5.0, 100.0) ** 2)
    return information


def covariances(seed: int, family: str, exponent: int) -> tuple[np.ndarray, np.ndarray]:
    """(S, y) of one family: 'uplkf' rank 2 in 3-D, 'ekf' 2x2, 'psd' and 'indefinite' 3x3 or 2x2 with one tiny
    or zero eigenvalue ('singular'), and a windowed FIM with its own innovation."""
    rng = np.random.default_rng(seed)
    if family == "uplkf":
        return uplkf_innovation_covariance(seed, exponent, 10.0 ** rng.uniform(-6, 0))
    if family == "ekf":
        return ekf_innovation_covariance(seed, exponent)
    if family == "fim":
        return fim(seed, int(rng.integers(1, 300))), rng.normal(size=3)
    size = int(rng.integers(2, 4))
    kind = {"psd": "psd_singular", "tiny": "tiny_negative", "indefinite": "any"}[family]
    matrix = symmetric_with_eigenvalues(seed, rng.uniform(-1.0, 1.0, size=size), exponent, kind)
    return matrix, rng.normal(size=size) * 10.0 ** (exponent / 2)


families = st.sampled_from(["uplkf", "ekf", "psd", "tiny", "indefinite", "fim"])


# ----- the LAPACK leaves -------------------------------------------------------------------------------------------

@settings(max_examples=400, deadline=None)
@given(seeds, families, st.integers(-8, 6))
def test_symmetric_eigen_is_numpys_eigh_and_eigvalsh(seed, family, exponent):
    """numba's eigh/eigvalsh (dsyevd through scipy's LAPACK) give numpy's (its own dsyevd) to the bit."""
    matrix = np.ascontiguousarray(covariances(seed, family, exponent)[0])
    values, vectors = _jit.symmetric_eigen(matrix)
    reference_values, reference_vectors = np.linalg.eigh(matrix)
    assert_same((values, vectors), (reference_values, reference_vectors))
    assert_same(_jit.symmetric_eigenvalues(matrix), np.linalg.eigvalsh(matrix))
    assert_same(python(_jit.symmetric_eigen)(matrix), (reference_values, reference_vectors))


def test_symmetric_eigen_of_non_finite_matrices_is_numpys():
    """numba refuses NaN and infinity; the kernels hand those to numpy's eigh/eigvalsh in object mode."""
    for entry in (math.nan, math.inf, -math.inf):
        matrix = np.eye(3)
        matrix[2, 0] = entry
        assert_same(outcome(_jit.symmetric_eigen, matrix), outcome(np.linalg.eigh, matrix))
        assert_same(outcome(_jit.symmetric_eigenvalues, matrix), outcome(np.linalg.eigvalsh, matrix))


# ----- the NIS -----------------------------------------------------------------------------------------------------

@settings(max_examples=500, deadline=None)
@given(seeds, families, st.integers(-10, 6), st.booleans())
def test_nis_is_the_old_pinv_nis(seed, family, exponent, off_range):
    covariance, innovation = covariances(seed, family, exponent)
    if off_range:  # an innovation with a component in S's null space too
        innovation = innovation + np.random.default_rng(seed).normal(size=innovation.shape)
    expected = old_normalized_innovation_squared(innovation, covariance)
    assert_same(health.normalized_innovation_squared(innovation, covariance), expected)
    assert_same(python(health._normalized_innovation_squared)(innovation, covariance), expected)
    assert type(health.normalized_innovation_squared(innovation, covariance)) is float


@pytest.mark.parametrize("size", [1, 2, 3])
def test_nis_of_every_tie_pattern_is_the_old_one(size):
    """Diagonal covariances with equal singular values in every arrangement (argsort's order of ties), signs,
    zeros, values below the cutoff, NaN and infinity: the same NIS, NaN or LinAlgError as numpy's pinv."""
    for values in itertools.product([0.0, 1.0, -1.0, 2.5e-3, 1e-14, math.nan, math.inf], repeat=size):
        covariance = np.diag(values)
        for innovation in (np.ones(size), np.arange(1.0, size + 1.0), np.full(size, -0.0)):
            expected = outcome(old_normalized_innovation_squared, innovation, covariance)
            assert_same(outcome(health.normalized_innovation_squared, innovation, covariance), expected, str(values))
            assert_same(outcome(python(health._normalized_innovation_squared), innovation, covariance), expected)


def test_nis_of_non_finite_off_diagonal_covariances_is_the_old_one():
    for entry, (i, j) in itertools.product((math.nan, math.inf), ((1, 0), (0, 1), (2, 2))):
        covariance = np.full((3, 3), 0.3) + np.eye(3)
        covariance[i, j] = entry
        expected = outcome(old_normalized_innovation_squared, np.ones(3), covariance)
        assert_same(outcome(health.normalized_innovation_squared, np.ones(3), covariance), expected)


def test_nis_of_views_lists_and_the_empty_innovation():
    covariance, innovation = uplkf_innovation_covariance(3, 0, 1e-3)
    wide = np.zeros((3, 6))
    wide[:, ::2] = covariance
    assert_same(health.normalized_innovation_squared(innovation.tolist(), wide[:, ::2]),
                old_normalized_innovation_squared(innovation, covariance))
    assert health.normalized_innovation_squared(np.zeros(0), np.zeros((0, 0))) == 0.0
    for bad in ((np.ones(3), np.eye(2)), (np.ones(2), np.ones(2)), (np.ones((2, 2)), np.eye(2))):
        with pytest.raises((ValueError, TypeError)):  # numpy's matmul, eigh (LinAlgError) or float() refused them
            old_normalized_innovation_squared(*bad)
        with pytest.raises(ValueError, match="innovation"):
            health.normalized_innovation_squared(*bad)


# ----- the windowed FIM --------------------------------------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(seeds, floats(-4.0, -1.0), floats(0.1, 5.0), st.sampled_from([5.0, 50.0]))
def test_windowed_fim_is_the_old_one(seed, log_sigma, window, rate):
    """Bearings near one direction at 5 or 50 Hz with pauses (the window empties) and repeated times: after
    every add, the same information matrix and the same measure (values and Python types)."""
    rng = np.random.default_rng(seed)
    sigma = 10.0**log_sigma
    new, old = WindowedObservability(window, sigma), OldWindowedObservability(window, sigma)
    base = rng.normal(size=3)
    time = 0.0
    for _ in range(int(rng.integers(1, 200))):
        time += rng.choice([0.0, 1.0 / rate, 3.0 / rate, 2.0 * window])
        bearing = base + rng.normal(size=3) * 10.0 ** rng.uniform(-4, 0)
        bearing /= np.linalg.norm(bearing)
        range_estimate = float(10.0 ** rng.uniform(0.0, 3.0))
        new.add(time, bearing, range_estimate)
        old.add(time, bearing, range_estimate)
        assert_same(new.information, old.information)
        measured, expected = new.measure(), old.measure()
        assert measured.keys() == expected.keys()
        for key in expected:
            assert type(measured[key]) is type(expected[key]), key
            assert_same(measured[key], expected[key], key)


@settings(max_examples=200, deadline=None)
@given(seeds, families, st.integers(-8, 8))
def test_fim_spectrum_is_the_old_measure(seed, family, exponent):
    """measure() of any symmetric matrix held as the window's information (rank-deficient and indefinite ones
    too: the zeroed eigenvalues, the -inf log det, the NaN spread)."""
    matrix = np.zeros((3, 3))
    block = covariances(seed, family, exponent)[0]
    matrix[: len(block), : len(block)] = block
    new, old = WindowedObservability(1.0, 0.01), OldWindowedObservability(1.0, 0.01)
    new._information, old._information = matrix.copy(), matrix.copy()
    measured, expected = new.measure(), old.measure()
    for key in expected:
        assert type(measured[key]) is type(expected[key]), key
        assert_same(measured[key], expected[key], key)
    assert_same(python(observability._spectrum)(matrix), observability._spectrum(matrix))


_B = np.array([0.6, 0.8, 0.0])
BAD_BEARINGS = [_B * (1 + 0.9e-6), _B * (1 + 1.1e-6), _B * (1 - 0.49e-6), np.array([math.nan, 0.0, 1.0]),
                np.array([math.inf, 0.0, 0.0]), _B[:2], _B.reshape(1, 3), _B.reshape(3, 1), [0.6, 0.8, 0.0],
                np.array([[0.6, 9.0], [0.8, 9.0], [0.0, 9.0]])[:, 0], _B.astype(np.float32), 1.0, np.zeros(4)]
BAD_RANGES = [1e155, 1e-170, 10.0, 0.0, -1.0, math.inf, math.nan, np.float32(5.0), np.int64(3), 3, True,
              np.array([5.0]), np.array(5.0), "x"]


@pytest.mark.parametrize("time", [1.0, -1.0, math.nan])
def test_windowed_fim_rejects_what_it_rejected(time):
    """Every combination of an odd time, bearing and range: the same error (type and message) as before, or the
    same information and measure; nothing added on an error."""
    for bearing, range_estimate in itertools.product(BAD_BEARINGS, BAD_RANGES):
        results = []
        for window in (WindowedObservability(2.0, 0.01), OldWindowedObservability(2.0, 0.01)):
            window.add(0.0, np.array([1.0, 0.0, 0.0]), 20.0)
            result = outcome(window.add, time, bearing, range_estimate)
            results.append((result if isinstance(result, tuple) else None, window.information.tobytes(),
                            repr(outcome(window.measure))))
        assert results[0] == results[1], (bearing, range_estimate)


@pytest.mark.parametrize("sigma", [1e-200, 1e160, 0.01])
def test_windowed_fim_overflows_as_before(sigma):
    """sigma^2 r^2 by Python's **: the same OverflowError (or LinAlgError of a non-finite FIM) as before."""
    for range_estimate in (1e-170, 1e155, 5.0, 1e-300):
        results = []
        for window in (WindowedObservability(2.0, sigma), OldWindowedObservability(2.0, sigma)):
            result = outcome(window.add, 0.0, _B, range_estimate)
            results.append((result if isinstance(result, tuple) else None, repr(outcome(window.measure))))
        assert results[0] == results[1], range_estimate


@settings(max_examples=200, deadline=None)
@given(unit_vectors(), floats(-1e-6, 1e-6), floats(1e-3, 1e4), floats(1e-5, 1.0))
def test_fim_kernels_against_their_python_functions(direction, stretch, range_estimate, sigma):
    bearing = direction * (1.0 + stretch)
    assert observability._plain_sample(bearing, range_estimate, sigma) == python(observability._plain_sample)(
        bearing, range_estimate, sigma)
    information = np.eye(3)
    reference = np.eye(3)
    scale = sigma**2 * range_estimate**2
    assert_same(observability._add_contribution(information, bearing, scale),
                python(observability._add_contribution)(reference, bearing, scale))
    assert_same(information, reference)


# ----- the health monitor's geometry, relative_range_std, the gate -------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(unit_vectors(), arrays(np.float64, 3, elements=floats(-100.0, 100.0)),
       arrays(np.float64, 3, elements=floats(-10.0, 10.0)), unit_vectors(), floats(-10.0, 3.5), seeds,
       st.integers(-4, 2))
def test_health_geometry_is_the_old_one(bearing, pursuer, velocity, direction, log_range, seed, exponent):
    estimate = pursuer + direction * 10.0**log_range
    factor = np.random.default_rng(seed).normal(size=(6, 6)) * 10.0**exponent
    covariance = factor @ factor.T
    expected = old_health_geometry(bearing, pursuer, velocity, estimate, covariance)
    arguments = (bearing, estimate, pursuer, np.ascontiguousarray(covariance[:3, :3]), velocity)
    assert_same(tuple(float(v) for v in health._evidence(*arguments)), expected)
    assert_same(tuple(float(v) for v in python(health._evidence)(*arguments)), expected)
    relative = estimate - pursuer
    assert_same(geometry.relative_range_std(relative, covariance[:3, :3]), old_relative_range_std(relative, covariance[:3, :3]))
    assert_same(geometry.relative_range_std(np.zeros(3), covariance[:3, :3]), math.inf)
    assert_same(geometry.norm(relative), old_norm(relative))  # what pipeline._observe now calls


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, 3, elements=floats(-1e3, 1e3)), arrays(np.float64, 3, elements=floats(-1.0, 1.0)),
       seeds, st.integers(-4, 3), floats(-4.0, -1.0), st.booleans())
def test_gate_is_the_old_one(relative, offset, seed, exponent, log_noise, negative):
    """The re-acquisition gate (FollowingPipeline._agrees_with_prediction) decides as before; its terms compiled
    are its Python function's. A negative covariance (a broken filter) gives NaN, as numpy's sqrt did."""
    distance = geometry.norm(relative)
    assume(distance >= 1e-6)
    factor = np.random.default_rng(seed).normal(size=(6, 6)) * 10.0**exponent
    covariance = (-1.0 if negative else 1.0) * (factor @ factor.T)
    direction = relative + offset * distance
    assume(geometry.norm(direction) > 0.0)
    noise = 10.0**log_noise
    arguments = (np.ascontiguousarray(relative), distance, unit(direction), np.ascontiguousarray(covariance[:3, :3]), noise)
    cosine, angular_std = pipeline._gate_terms(*arguments)
    assert_same((float(cosine), float(angular_std)), tuple(float(v) for v in python(pipeline._gate_terms)(*arguments)))
    assert (float(np.arccos(cosine)) <= 3.0 * angular_std) == old_gate(relative, covariance, direction, noise, 3.0)


# ----- warm-up and a whole flight ----------------------------------------------------------------------------------

def test_warm_up_compiles_the_diagnostic_kernels():
    warmup.warm_up()
    # The kernels Python calls: one that only other kernels call (health._evidence, observability._spectrum...) has
    # no signature of its own when its callers load from numba's cache, so it would say nothing (and the test
    # failed when run alone, with a warm cache).
    kernels = (health._normalized_innovation_squared, health._bearing_evidence, observability._add_plain_sample,
               observability._add_plain_sample_measured, observability._spectrum_into,
               geometry.relative_range_std_kernel, pipeline._gate_terms)
    for kernel in kernels:
        if _jit.ENABLED:
            assert kernel.signatures, kernel
        else:
            assert python(kernel) is kernel


_FLIGHT = """
import sys
import numpy as np
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies.closed_loop import simulate
from studies.montecarlo import ESTIMATORS, with_overrides
scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
scenario = with_overrides(scenario, {**ESTIMATORS["ekf"], "sensor.rate_hz": 50.0, "simulation.duration": 20.0})
np.savez(sys.argv[1], **simulate(scenario, vehicle, seed=1).series)
"""


def test_a_50hz_baseline_flight_is_the_same_compiled_and_interpreted(tmp_path):
    """constant_velocity with the baseline EKF (2-D angle innovations, 2x2 covariances) and 50 Hz bearings for
    20 s, seed 1: every logged series flown here (compiled kernels when numba is installed) equals the one a
    BOF_NO_JIT=1 interpreter flies."""
    here_path, there_path = tmp_path / "compiled.npz", tmp_path / "interpreted.npz"
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    for output, flag in ((here_path, os.environ.get("BOF_NO_JIT", "")), (there_path, "1")):
        environment = dict(os.environ, BOF_NO_JIT=flag, PYTHONPATH=path)
        subprocess.run([sys.executable, "-c", _FLIGHT, str(output)], check=True, cwd=ROOT, env=environment, timeout=600)
    here, there = np.load(here_path), np.load(there_path)
    assert sorted(there.files) == sorted(here.files)
    assert np.isfinite(here["health_nis_ratio"]).any()  # the NIS ran on 2-D innovations
    for name in here.files:
        assert_same(here[name], there[name], name)
