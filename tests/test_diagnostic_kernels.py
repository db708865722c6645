"""The bearing path's diagnostic kernels (health.py, observability.py, the pipeline's re-acquisition gate) against
independent references: numpy's eigh, scipy's pinvh, the closed form of the projected covariance's trace.

numba's eigh and eigvalsh (symmetric_eigen, symmetric_eigenvalues) against their definition, A v = lambda v with
orthonormal v, and numpy's eigenvalues; a NaN or an infinity goes to numpy's in object mode (the same outcome).
The NIS against scipy's pinvh with numpy's cutoff; the windowed FIM's input checks; the gate's terms against the
trace identity tr(P_perp P P_perp) = tr P - lambda^T P lambda; the warm-up compiling every diagnostic kernel. What the
NIS and the windowed FIM mean is tests/test_health.py's and tests/test_observability.py's.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.linalg
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from bitwise import assert_same, seeds
from paper_reference import floats, symmetric_with_eigenvalues

from companion import warmup
from companion.core import _jit, geometry, health, observability, pipeline
from companion.core.geometry import unit
from companion.core.observability import WindowedObservability

python = _jit.python_function


def outcome(function, *args):
    """function(*args), or (exception type, message) when it raises."""
    try:
        return function(*args)
    except Exception as error:  # noqa: BLE001 - the exception itself is the result compared
        return type(error), str(error)


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


# ----- eigh and eigvalsh ---------------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(seeds, families, st.integers(-8, 6))
def test_symmetric_eigen_is_an_eigendecomposition(seed, family, exponent):
    """Ascending eigenvalues, numpy's to rounding; orthonormal eigenvectors with A v = lambda v."""
    matrix = np.ascontiguousarray(covariances(seed, family, exponent)[0])
    scale = float(np.abs(matrix).max()) or 1.0
    values, vectors = _jit.symmetric_eigen(matrix)
    reference = np.linalg.eigvalsh(matrix)
    assert np.all(np.diff(values) >= 0.0)
    np.testing.assert_allclose(values, reference, rtol=0.0, atol=1e-12 * scale)
    np.testing.assert_allclose(_jit.symmetric_eigenvalues(matrix), reference, rtol=0.0, atol=1e-12 * scale)
    np.testing.assert_allclose(vectors.T @ vectors, np.eye(len(matrix)), rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(matrix @ vectors, vectors * values, rtol=0.0, atol=1e-12 * scale)


def test_symmetric_eigen_of_non_finite_matrices_is_numpys():
    """numba refuses NaN and infinity; the kernels hand those to numpy's eigh/eigvalsh in object mode."""
    for entry in (math.nan, math.inf, -math.inf):
        matrix = np.eye(3)
        matrix[2, 0] = entry
        assert_same(outcome(_jit.symmetric_eigen, matrix), outcome(np.linalg.eigh, matrix))
        assert_same(outcome(_jit.symmetric_eigenvalues, matrix), outcome(np.linalg.eigvalsh, matrix))


# ----- the NIS -------------------------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(seeds, st.sampled_from([2, 3]), st.integers(0, 2), st.integers(-8, 6), floats(0.0, 6.0), st.booleans())
def test_nis_is_the_pseudo_inverse_quadratic_form(seed, size, zeros, exponent, spread, off_range):
    """y^T S^+ y for S = Q diag(l) Q^T with `zeros` exact zero eigenvalues and the others up to 10^spread apart:
    scipy's pinvh with numpy's cutoff (1e-10 of the largest eigenvalue), far from it on both sides."""
    assume(zeros < size)
    rng = np.random.default_rng(seed)
    eigenvalues = 10.0 ** (exponent - rng.uniform(0.0, spread, size))
    eigenvalues[:zeros] = 0.0
    covariance = symmetric_with_eigenvalues(seed, eigenvalues, 0, "any")
    innovation = covariance @ rng.normal(size=size) * 10.0 ** (-exponent / 2)  # in S's range
    if off_range:  # a component in S's null space too
        innovation = innovation + rng.normal(size=size) * 10.0 ** (exponent / 2)
    expected = float(innovation @ scipy.linalg.pinvh(covariance, rtol=1e-10) @ innovation)
    nis = health.normalized_innovation_squared(innovation, covariance)
    assert type(nis) is float
    assert nis == pytest.approx(expected, rel=1e-6, abs=1e-9)


def test_nis_of_views_lists_and_the_empty_innovation():
    covariance, innovation = uplkf_innovation_covariance(3, 0, 1e-3)
    wide = np.zeros((3, 6))
    wide[:, ::2] = covariance
    assert health.normalized_innovation_squared(innovation.tolist(), wide[:, ::2]) == pytest.approx(
        health.normalized_innovation_squared(innovation, covariance.copy()), rel=1e-12)
    assert health.normalized_innovation_squared(np.zeros(0), np.zeros((0, 0))) == 0.0
    for bad in ((np.ones(3), np.eye(2)), (np.ones(2), np.ones(2)), (np.ones((2, 2)), np.eye(2))):
        with pytest.raises(ValueError, match="innovation"):
            health.normalized_innovation_squared(*bad)


# ----- the windowed FIM's input checks -------------------------------------------------------------------------

_B = np.array([0.6, 0.8, 0.0])
BAD_BEARINGS = [_B * (1 + 0.9e-6), _B * (1 + 1.1e-6), _B * (1 - 0.49e-6), np.array([math.nan, 0.0, 1.0]),
                np.array([math.inf, 0.0, 0.0]), _B[:2], _B.reshape(1, 3), _B.reshape(3, 1), [0.6, 0.8, 0.0],
                np.array([[0.6, 9.0], [0.8, 9.0], [0.0, 9.0]])[:, 0], _B.astype(np.float32), 1.0, np.zeros(4)]
BAD_RANGES = [1e155, 1e-170, 10.0, 0.0, -1.0, math.inf, math.nan, np.float32(5.0), np.int64(3), 3, True,
              np.array([5.0]), np.array(5.0), "x"]



@pytest.mark.parametrize("time", [1.0, -1.0, math.nan])
def test_windowed_fim_refuses_bad_samples_and_adds_nothing(time):
    """Every combination of an odd time, bearing and range: a ValueError, TypeError or OverflowError that leaves the
    information as it was, or (a finite non-decreasing time) a sample added to it."""
    for bearing, range_estimate in itertools.product(BAD_BEARINGS, BAD_RANGES):
        window = WindowedObservability(2.0, 0.01)
        window.add(0.0, np.array([1.0, 0.0, 0.0]), 20.0)
        before = window.information
        try:
            window.add(time, bearing, range_estimate)
        except (ValueError, TypeError, OverflowError):
            assert np.array_equal(window.information, before), (bearing, range_estimate)
            continue
        assert math.isfinite(time) and time >= 0.0, (time, bearing, range_estimate)
        assert not np.array_equal(window.information, before, equal_nan=True), (bearing, range_estimate)


# ----- the re-acquisition gate ---------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, 3, elements=floats(-1e3, 1e3)), arrays(np.float64, 3, elements=floats(-1.0, 1.0)),
       seeds, st.integers(-4, 3), floats(-4.0, -1.0))
def test_gate_terms_are_the_closed_form(relative, offset, seed, exponent, log_noise):
    """The re-acquisition gate's (FollowingPipeline._agrees_with_prediction) cosine between the predicted line of
    sight and the bearing, and its angular std sqrt((tr P - l^T P l) / (2 r^2) + sigma^2)."""
    distance = float(np.sqrt(relative @ relative))
    assume(distance >= 1e-6)
    factor = np.random.default_rng(seed).normal(size=(3, 3)) * 10.0**exponent
    covariance = factor @ factor.T
    direction = relative + offset * distance
    assume(float(np.sqrt(direction @ direction)) > 1e-3 * distance)
    noise = 10.0**log_noise
    measured = unit(direction)
    cosine, angular_std = pipeline._gate_terms(np.ascontiguousarray(relative), distance, measured, covariance, noise)
    los = relative / distance
    expected_cosine = min(max(float(los @ direction) / float(np.sqrt(direction @ direction)), -1.0), 1.0)
    lateral = (float(np.trace(covariance)) - float(los @ covariance @ los)) / 2.0
    assert -1.0 <= cosine <= 1.0 and cosine == pytest.approx(expected_cosine, abs=1e-12)
    assert angular_std == pytest.approx(math.sqrt(max(lateral, 0.0) / distance**2 + noise**2), rel=1e-9)


# ----- warm-up -------------------------------------------------------------------------------------------------

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
