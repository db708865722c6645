"""Multistep bearing-only observability of section V: FIM, eigenvalue spread, placement optimiser.

Pure numerics, no I/O. Vectors are numpy arrays in the NED frame; a bearing lambda_i
is the unit vector from the observer to the target, shape (3,). Ranges are in m and
sigma is the bearing noise standard deviation (rad, dimensionless on the unit sphere).

Contents:
- eq. (7): the Fisher information matrix (FIM) of n bearings, `fisher_information`;
- eq. (8)-(10): the eigenvalue-spread metric J = ||I_n - mean_eig I||_F^2 and its
  explicit forms through G, `eigenvalue_spread`, `g_matrix`, `spread_from_g`,
  `g_norm_squared_equal_range`;
- eq. (12): the behaviour-based particle optimiser of problem (11), `optimize_placement`;
- `WindowedObservability`: an online FIM over a sliding time window for the companion.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from companion.core._jit import jit, symmetric_eigenvalues

_UNIT_TOLERANCE = 1e-6
# Eigenvalues below this fraction of the largest one are reported as exactly zero.
_SINGULAR_TOLERANCE = 1e-12
# A step is accepted only if it keeps at least this fraction of the distance to every plane.
_PLANE_KEEP_FRACTION = 0.5
_MAX_STEP_HALVINGS = 40


# --------------------------------------------------------------------------- validation


def _check_sigma(sigma: float) -> float:
    sigma = float(sigma)
    if not math.isfinite(sigma) or sigma <= 0.0:
        raise ValueError(f"sigma must be positive and finite, got {sigma!r}")
    return sigma


def _check_bearings(bearings: np.ndarray) -> np.ndarray:
    array = np.asarray(bearings, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ValueError(f"bearings must have shape (n, 3) with n >= 1, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError("bearings must be finite")
    norms = np.linalg.norm(array, axis=1)
    if np.any(np.abs(norms - 1.0) > _UNIT_TOLERANCE):
        raise ValueError(f"bearings must be unit vectors; norms range {norms.min():.6g}..{norms.max():.6g}")
    return array


def _check_ranges(ranges: np.ndarray, count: int) -> np.ndarray:
    array = np.asarray(ranges, dtype=float)
    if array.shape != (count,):
        raise ValueError(f"ranges must have shape ({count},), got {array.shape}")
    if not np.all(np.isfinite(array)) or np.any(array <= 0.0):
        raise ValueError("ranges must be positive and finite")
    return array


def _check_matrix(matrix: np.ndarray) -> np.ndarray:
    array = np.asarray(matrix, dtype=float)
    if array.shape != (3, 3) or not np.all(np.isfinite(array)):
        raise ValueError(f"expected a finite (3, 3) matrix, got shape {array.shape}")
    return array


# --------------------------------------------------------------------------- eq. (7)-(10)


def fisher_information(bearings: np.ndarray, ranges: np.ndarray, sigma: float) -> np.ndarray:
    """FIM of n bearings about the target position, eq. (7).

    I_n = (1/sigma^2) sum_i (1/r_i^2) (I - lambda_i lambda_i^T).
    bearings: unit vectors, shape (n, 3); ranges: m, shape (n,); sigma: bearing noise std.
    Returns shape (3, 3), units 1/(m^2 sigma^2).
    """
    bearings = _check_bearings(bearings)
    ranges = _check_ranges(ranges, len(bearings))
    sigma = _check_sigma(sigma)
    weights = 1.0 / (sigma**2 * ranges**2)
    return weights.sum() * np.eye(3) - g_matrix(bearings, ranges, sigma)


def g_matrix(bearings: np.ndarray, ranges: np.ndarray, sigma: float) -> np.ndarray:
    """G = (1/sigma^2) sum_i (1/r_i^2) lambda_i lambda_i^T, eq. (9); shape (3, 3).

    bearings: unit vectors, shape (n, 3); ranges: m, shape (n,).
    """
    bearings = _check_bearings(bearings)
    ranges = _check_ranges(ranges, len(bearings))
    sigma = _check_sigma(sigma)
    weights = 1.0 / (sigma**2 * ranges**2)
    return (bearings * weights[:, None]).T @ bearings


def eigenvalue_spread(information: np.ndarray) -> float:
    """J = ||I_n - mean_eig I_3||_F^2, the metric minimised in section V (before eq. (8)).

    information: a symmetric (3, 3) matrix (the FIM). mean_eig = trace / 3.
    """
    information = _check_matrix(information)
    mean_eigenvalue = np.trace(information) / 3.0
    return float(np.sum((information - mean_eigenvalue * np.eye(3)) ** 2))


def spread_from_g(bearings: np.ndarray, ranges: np.ndarray, sigma: float) -> float:
    """Explicit form of the spread, eq. (8): ||G||_F^2 - (1/3) (sum_i 1/(sigma^2 r_i^2))^2.

    Holds for unequal ranges: I_n = S I - G with S = sum_i 1/(sigma^2 r_i^2) = trace(G).
    """
    g = g_matrix(bearings, ranges, sigma)
    weight_sum = float(np.sum(1.0 / (sigma**2 * np.asarray(ranges, dtype=float) ** 2)))
    return float(np.sum(g**2)) - weight_sum**2 / 3.0


def g_norm_squared_equal_range(bearings: np.ndarray, sigma: float, r_d: float) -> float:
    """||G||_F^2 for all ranges equal to r_d, eq. (10).

    ||G||_F^2 = (n + sum_i sum_{j != i} (lambda_i^T lambda_j)^2) / (sigma^4 r_d^4).
    Note: the paper prints a factor 2 in front of the double sum over j != i, which
    counts every pair twice; the correct expression is either the double sum over
    j != i without the 2 (used here) or 2 * sum_{i < j}. The tests check this
    against ||G||_F^2 computed directly from eq. (9).
    """
    bearings = _check_bearings(bearings)
    sigma = _check_sigma(sigma)
    r_d = float(r_d)
    if not math.isfinite(r_d) or r_d <= 0.0:
        raise ValueError(f"r_d must be positive and finite, got {r_d!r}")
    cosines_squared = (bearings @ bearings.T) ** 2
    n = len(bearings)
    off_diagonal = float(cosines_squared.sum() - np.trace(cosines_squared))
    return (n + off_diagonal) / (sigma**4 * r_d**4)


def fim_determinant(bearings: np.ndarray, ranges: np.ndarray, sigma: float) -> float:
    """det(I_n) of the FIM of eq. (7), the classical metric the spread J stands in for."""
    return float(np.linalg.det(fisher_information(bearings, ranges, sigma)))


# --------------------------------------------------------------------------- eq. (12)


@dataclass(frozen=True)
class Plane:
    """A repulsive plane of eq. (12c).

    point: any point on the plane, shape (3,); normal: unit normal, shape (3,), pointing
    INTO the allowed region; gain: k_b > 0. The signed distance of a particle x is
    d = normal^T (x - point), positive on the allowed side.
    """

    point: np.ndarray
    normal: np.ndarray
    gain: float

    def __post_init__(self) -> None:
        point = np.asarray(self.point, dtype=float).reshape(-1)
        normal = np.asarray(self.normal, dtype=float).reshape(-1)
        if point.shape != (3,) or normal.shape != (3,):
            raise ValueError("plane point and normal must have shape (3,)")
        if not (np.all(np.isfinite(point)) and np.all(np.isfinite(normal))):
            raise ValueError("plane point and normal must be finite")
        if abs(float(np.linalg.norm(normal)) - 1.0) > _UNIT_TOLERANCE:
            raise ValueError(f"plane normal must be a unit vector, got {normal!r}")
        gain = float(self.gain)
        if not math.isfinite(gain) or gain < 0.0:
            raise ValueError(f"plane gain must be non-negative and finite, got {self.gain!r}")
        point.setflags(write=False)
        normal.setflags(write=False)
        object.__setattr__(self, "point", point)
        object.__setattr__(self, "normal", normal)
        object.__setattr__(self, "gain", gain)

    def signed_distance(self, positions: np.ndarray) -> np.ndarray:
        """d = normal^T (x - point) for positions of shape (n, 3); shape (n,), > 0 where allowed."""
        return (np.asarray(positions, dtype=float) - self.point) @ self.normal


@dataclass(frozen=True)
class PlacementResult:
    """Output of `optimize_placement`.

    times: recorded times, s, shape (m,); positions: particles (bearings) at those times,
    shape (m, n, 3); velocities: d lambda_i/dt = f_i1 + f_i2 + f_i3 there, shape (m, n, 3);
    step_times: s, shape (steps + 1,); g_norms: ||G||_F after every step, shape (steps + 1,);
    final_bearings: shape (n, 3); final_g_norm: ||G||_F of final_bearings;
    shrunk_steps: number of particle steps that were shortened to keep off a plane.
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    step_times: np.ndarray
    g_norms: np.ndarray
    final_bearings: np.ndarray
    final_g_norm: float
    shrunk_steps: int


def _project_tangent(bearings: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Row-wise P_lambda v = v - lambda (lambda^T v)."""
    return vectors - bearings * np.sum(bearings * vectors, axis=1, keepdims=True)


def _forces(
    bearings: np.ndarray, planes: Sequence[Plane], k_g: float, k_m: float, weight: float
) -> np.ndarray:
    """Particle velocities d lambda_i/dt = f_i1 + f_i2 + f_i3, eq. (12a)-(12c); shape (n, 3), every particle on the
    allowed side of every plane (d_ij > 0; the integration loop keeps them there). f_i1 = -k_g P G lambda_i (G of
    eq. (9) with r_i = r_d), f_i2 = k_m P (lambda_{i-1} - lambda_i) with lambda_0 = lambda_n (cyclic),
    f_i3 = sum_j k_bj P n_j / d_ij; weight = 1/(sigma^2 r_d^2)."""
    g = weight * (bearings.T @ bearings)
    force = -k_g * (bearings @ g)
    force += k_m * (np.roll(bearings, 1, axis=0) - bearings)
    for plane in planes:
        force += (plane.gain / plane.signed_distance(bearings))[:, None] * plane.normal
    # P_lambda is linear, so projecting the sum equals summing the projections of (12a)-(12c).
    return _project_tangent(bearings, force)


def _allowed(positions: np.ndarray, planes: Sequence[Plane]) -> np.ndarray:
    ok = np.ones(len(positions), dtype=bool)
    for plane in planes:
        ok &= plane.signed_distance(positions) > 0.0
    return ok


def random_placement(n: int, rng: np.random.Generator, planes: Sequence[Plane] = ()) -> np.ndarray:
    """n unit vectors uniform on the sphere, restricted to the allowed side of every plane.

    Rejection sampling of isotropic Gaussian directions; deterministic for a seeded rng.
    Returns shape (n, 3). ValueError if the allowed region is (numerically) empty.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    accepted: list[np.ndarray] = []
    draws = 0
    while len(accepted) < n:
        draws += 1
        if draws > 1000:
            raise ValueError("could not sample the allowed region of the sphere (too small?)")
        candidates = rng.standard_normal((4 * n, 3))
        candidates /= np.linalg.norm(candidates, axis=1, keepdims=True)
        accepted.extend(candidates[_allowed(candidates, planes)])
    return np.array(accepted[:n])


def _step(
    bearings: np.ndarray, velocity: np.ndarray, dt: float, planes: Sequence[Plane]
) -> tuple[np.ndarray, int]:
    """One explicit Euler step followed by renormalisation onto the unit sphere.

    A particle whose step would leave it with less than half of its distance to any plane
    has its step halved until it does not; after _MAX_STEP_HALVINGS it stays put. Since
    distances stay > 0 this way, no particle can ever cross a plane (the 1/d force of
    eq. (12c) is singular there, so a plain Euler step could jump over it).
    """
    old_distances = [plane.signed_distance(bearings) for plane in planes]
    step_scale = np.ones(len(bearings))
    shrunk = 0
    for _ in range(_MAX_STEP_HALVINGS + 1):
        candidate = bearings + (dt * step_scale)[:, None] * velocity
        candidate /= np.linalg.norm(candidate, axis=1, keepdims=True)
        bad = np.zeros(len(bearings), dtype=bool)
        for plane, old in zip(planes, old_distances):
            bad |= plane.signed_distance(candidate) < _PLANE_KEEP_FRACTION * old
        if not bad.any():
            return candidate, shrunk
        shrunk += int(bad.sum())
        step_scale[bad] *= 0.5
    candidate[bad] = bearings[bad]
    return candidate, shrunk


def optimize_placement(
    initial: np.ndarray,
    planes: Sequence[Plane] = (),
    *,
    k_g: float = 1.0,
    k_m: float = 5.0,
    dt: float = 1e-3,
    steps: int | None = None,
    duration: float | None = None,
    sigma: float = 1.0,
    r_d: float = 1.0,
    record_times: Sequence[float] = (),
) -> PlacementResult:
    """Behaviour-based solution of problem (11) by the particle dynamics of eq. (12).

    d lambda_i/dt = f_i1 + f_i2 + f_i3 (eq. (12a)-(12c), see `_forces`), integrated by
    explicit Euler with step dt (s) and renormalised to the unit sphere after every step;
    steps that would approach a plane too fast are shortened (see `_step`), so particles never
    cross a plane. Give exactly one of `steps` or `duration` (s).
    initial: unit vectors, shape (n, 3), strictly inside the allowed region.
    record_times: times (s, within [0, duration]) at which positions and velocities are kept;
    each is rounded to the nearest step.
    """
    bearings = _check_bearings(initial).copy()
    _check_sigma(sigma)
    for name, value in (("k_g", k_g), ("k_m", k_m)):
        if not math.isfinite(value) or value < 0.0:
            raise ValueError(f"{name} must be non-negative and finite, got {value!r}")
    if not math.isfinite(dt) or dt <= 0.0:
        raise ValueError(f"dt must be positive and finite, got {dt!r}")
    if (steps is None) == (duration is None):
        raise ValueError("give exactly one of steps or duration")
    if steps is None:
        if not math.isfinite(duration) or duration < 0.0:
            raise ValueError(f"duration must be non-negative and finite, got {duration!r}")
        steps = int(round(duration / dt))
    if int(steps) != steps or steps < 0:
        raise ValueError(f"steps must be a non-negative integer, got {steps!r}")
    if not _allowed(bearings, planes).all():
        raise ValueError("initial particles must lie strictly on the allowed side of every plane")
    record_steps = {}
    for time in record_times:
        index = int(round(float(time) / dt))
        if index < 0 or index > steps:
            raise ValueError(f"record time {time!r} s is outside [0, {steps * dt}] s")
        record_steps.setdefault(index, []).append(float(time))

    weight = 1.0 / (sigma**2 * float(r_d) ** 2)
    g_norms = np.empty(steps + 1)
    times: list[float] = []
    positions: list[np.ndarray] = []
    velocities: list[np.ndarray] = []
    shrunk_total = 0
    for index in range(steps + 1):
        g_norms[index] = weight * np.linalg.norm(bearings.T @ bearings)
        velocity = _forces(bearings, planes, k_g, k_m, weight)
        for time in record_steps.get(index, ()):
            times.append(time)
            positions.append(bearings.copy())
            velocities.append(velocity.copy())
        if index < steps:
            bearings, shrunk = _step(bearings, velocity, dt, planes)
            shrunk_total += shrunk
    order = np.argsort(times, kind="stable")
    n = len(bearings)
    return PlacementResult(
        times=np.asarray(times)[order],
        positions=np.asarray(positions).reshape(-1, n, 3)[order],
        velocities=np.asarray(velocities).reshape(-1, n, 3)[order],
        step_times=np.arange(steps + 1) * dt,
        g_norms=g_norms,
        final_bearings=bearings,
        final_g_norm=float(g_norms[-1]),
        shrunk_steps=shrunk_total,
    )


# --------------------------------------------------------------------------- online measure


class WindowedObservability:
    """FIM of eq. (7) over the bearings of the last `window_s` seconds, for the companion.

    Keeps a running sum of (I - lambda lambda^T) / (sigma^2 r^2) with a deque for removal,
    so `add` and `measure` cost O(1) per sample. The range is the current range estimate (m).
    """

    def __init__(self, window_s: float, sigma: float) -> None:
        window_s = float(window_s)
        if not math.isfinite(window_s) or window_s <= 0.0:
            raise ValueError(f"window_s must be positive and finite, got {window_s!r}")
        self.window_s = window_s
        self.sigma = _check_sigma(sigma)
        self._samples: deque[tuple[float, np.ndarray]] = deque()
        self._information = np.zeros((3, 3))
        self._latest_time = -math.inf
        self._eigenvalues = np.zeros(3)  # measure's, written by _spectrum_into (read within measure only)

    def add(self, time: float, bearing: np.ndarray, range_estimate: float) -> None:
        """Add one bearing (unit, shape (3,)) at `time` (s, non-decreasing) with range (m)."""
        time = float(time)
        if not math.isfinite(time) or time < self._latest_time:
            raise ValueError(f"time must be finite and non-decreasing, got {time!r}")
        bearing = np.ascontiguousarray(bearing, dtype=float)
        samples = self._samples
        cutoff = time - self.window_s
        if bearing.shape == (3,) and isinstance(range_estimate, (float, int)):
            # The usual sample in one kernel call: the checks, its term added, and the oldest term taken out
            # when it leaves the window now (_drop_older_than's first subtraction, in the same order).
            drop = bool(samples) and samples[0][0] < cutoff
            contribution = np.empty((3, 3))
            if _add_plain_sample(self._information, bearing, float(range_estimate), self.sigma,
                                 samples[0][1] if drop else _NO_CONTRIBUTION, drop, contribution):
                if drop:
                    samples.popleft()
                samples.append((time, contribution))
                self._latest_time = time
                self._drop_older_than(cutoff)
                return
        # fisher_information's checks decide (ValueError), then Python's ** (OverflowError)
        bearing = _check_bearings(bearing.reshape(1, 3))[0]
        range_estimate = float(_check_ranges(np.array([range_estimate], dtype=float), 1)[0])
        contribution = _add_contribution(self._information, bearing, self.sigma**2 * range_estimate**2)
        samples.append((time, contribution))
        self._latest_time = time
        self._drop_older_than(cutoff)

    def add_and_measure(self, time: float, bearing: np.ndarray, range_estimate: float) -> dict[str, float]:
        """add(time, bearing, range_estimate), then measure(): what the pipeline calls at every bearing used. The
        usual sample, when no more than one older term leaves the window with it, takes one kernel call for both
        (`_add_plain_sample_measured`: the same term, the same subtraction, the spectrum of the same matrix);
        anything else goes through add and measure themselves."""
        time = float(time)
        if not (math.isfinite(time) and time >= self._latest_time):
            self.add(time, bearing, range_estimate)  # its ValueError
        bearing = np.ascontiguousarray(bearing, dtype=float)
        samples = self._samples
        if bearing.shape == (3,) and isinstance(range_estimate, (float, int)):
            cutoff = time - self.window_s
            drop = bool(samples) and samples[0][0] < cutoff
            contribution = np.empty((3, 3))
            added, minimum, spread = _add_plain_sample_measured(
                self._information, bearing, float(range_estimate), self.sigma,
                samples[0][1] if drop else _NO_CONTRIBUTION, drop, contribution, self._eigenvalues)
            if added:
                if drop:
                    samples.popleft()
                samples.append((time, contribution))
                self._latest_time = time
                if not samples[0][0] < cutoff:  # nothing more leaves: the spectrum is the window's
                    return self._measure_report(minimum, spread)
                self._drop_older_than(cutoff)
                return self.measure()
        self.add(time, bearing, range_estimate)  # its checks decide (ValueError) as they always did
        return self.measure()

    def _drop_older_than(self, cutoff: float) -> None:
        while self._samples and self._samples[0][0] < cutoff:
            _, contribution = self._samples.popleft()
            self._information -= contribution
        if not self._samples:
            self._information = np.zeros((3, 3))  # no rounding residue once empty

    @property
    def information(self) -> np.ndarray:
        """The windowed FIM, shape (3, 3)."""
        return self._information.copy()

    def measure(self) -> dict[str, float]:
        """Observability of the window.

        log_det: log10 det(FIM), -inf if singular; min_eigenvalue: smallest eigenvalue (eigenvalues
        below 1e-12 of the largest count as 0); spread: J of eq. (8) divided by the squared mean
        eigenvalue (scale-free; 0 for an isotropic FIM, nan when empty); count: samples in window.
        """
        minimum, spread = _spectrum_into(self._information, self._eigenvalues)
        return self._measure_report(minimum, spread)

    def _measure_report(self, minimum: float, spread: float) -> dict[str, float]:
        """measure's figures from `_spectrum_into`'s (the eigenvalues in self._eigenvalues)."""
        log_det = -math.inf
        if minimum > 0.0:
            # numpy's log10 (its SIMD routine where it has one, not the C library's), summed left to right as np.sum sums 3.
            first, second, third = np.log10(self._eigenvalues).tolist()
            log_det = first + second + third
        return {"log_det": log_det, "min_eigenvalue": float(minimum), "spread": float(spread), "count": len(self._samples)}


@jit
def _plain_sample(bearing: np.ndarray, range_estimate: float, sigma: float) -> bool:
    """True when the checks of fisher_information would certainly pass: bearing (3,) finite with a norm within
    half of _UNIT_TOLERANCE of 1, range_estimate (m) finite and positive, and sigma^2, r^2 finite (Python's **
    would not overflow). False does not mean invalid: the caller then runs those checks."""
    squared = 0.0
    for k in range(3):
        if not math.isfinite(bearing[k]):
            return False
        squared += bearing[k] * bearing[k]
    return (abs(math.sqrt(squared) - 1.0) <= 0.5 * _UNIT_TOLERANCE and math.isfinite(range_estimate)
            and range_estimate > 0.0 and math.isfinite(sigma ** 2) and math.isfinite(range_estimate ** 2))


_NO_CONTRIBUTION = np.zeros((3, 3))  # the term _add_plain_sample takes out when none leaves the window (never read)


@jit
def _add_plain_sample(information: np.ndarray, bearing: np.ndarray, range_estimate: float, sigma: float,
                      oldest: np.ndarray, drop_oldest: bool, term: np.ndarray) -> bool:
    """WindowedObservability.add's usual sample: when `_plain_sample` holds, its term of eq. (7) is added to
    `information` (3, 3) in place (`_add_contribution`, scale sigma^2 r^2 by the C library's pow as Python's **
    computes it) and written into `term` (3, 3) (an argument rather than a result: numba boxes every array it
    returns), then, when drop_oldest, the window's oldest term `oldest` (3, 3) is subtracted (numpy's -=); True.
    Otherwise False, and nothing changes: the caller runs the checks. bearing: lambda (3,), float64 C-contiguous;
    range_estimate: m; sigma: rad."""
    if not _plain_sample(bearing, range_estimate, sigma):
        return False
    term[:] = _add_contribution(information, bearing, sigma ** 2 * range_estimate ** 2)
    if drop_oldest:
        information -= oldest
    return True


@jit
def _add_plain_sample_measured(information: np.ndarray, bearing: np.ndarray, range_estimate: float, sigma: float,
                               oldest: np.ndarray, drop_oldest: bool, term: np.ndarray,
                               eigenvalues: np.ndarray) -> tuple[bool, float, float]:
    """`_add_plain_sample` (its arguments first, the same update in place), then, when it added the sample,
    `_spectrum_into` of the updated FIM with its eigenvalues written into `eigenvalues` (3,): (added, the smallest
    eigenvalue, the spread); (False, NaN, NaN) with nothing changed otherwise. WindowedObservability.add_and_measure's
    one call."""
    if not _add_plain_sample(information, bearing, range_estimate, sigma, oldest, drop_oldest, term):
        return False, math.nan, math.nan
    minimum, spread = _spectrum_into(information, eigenvalues)
    return True, minimum, spread


@jit
def _add_contribution(information: np.ndarray, bearing: np.ndarray, scale: float) -> np.ndarray:
    """One bearing's term of the FIM, eq. (7): (I - lambda lambda^T) / (sigma^2 r^2), (3, 3), added to
    `information` (3, 3) in place and returned. bearing: lambda (3,); scale: sigma^2 r^2 (rad^2 m^2) as Python
    computed it."""
    contribution = (np.eye(3) - np.outer(bearing, bearing)) / scale
    information += contribution
    return contribution


@jit
def _spectrum(information: np.ndarray) -> tuple[np.ndarray, float, float]:
    """WindowedObservability.measure's arithmetic but the logarithm: the FIM's (eq. (7)) eigenvalues (3,) ascending
    (numpy's eigvalsh; those at or below _SINGULAR_TOLERANCE of the largest set to 0, all 0 when the largest is
    not positive), the smallest, and the scale-free spread sum((e - mean)^2) / mean^2 (J of eq. (8) over the
    squared mean eigenvalue; NaN unless mean > 0), each as numpy and Python compute it (sums left to right,
    mean = sum / 3, mean^2 by the C library's pow)."""
    eigenvalues = symmetric_eigenvalues(information)
    largest = eigenvalues[-1]
    floor = 0.0 if 0.0 > largest else largest  # Python's max(largest, 0.0)
    eigenvalues = np.where(eigenvalues <= _SINGULAR_TOLERANCE * floor, 0.0, eigenvalues)
    if largest <= 0.0:
        eigenvalues = np.zeros(3)
    mean = (eigenvalues[0] + eigenvalues[1] + eigenvalues[2]) / 3.0
    spread = math.nan
    if mean > 0.0:
        deviations = eigenvalues - mean
        squares = deviations * deviations
        spread = (squares[0] + squares[1] + squares[2]) / mean ** 2
    return eigenvalues, eigenvalues[0], spread


@jit
def _spectrum_into(information: np.ndarray, eigenvalues: np.ndarray) -> tuple[float, float]:
    """`_spectrum` of the FIM `information` (3, 3) with its eigenvalues written into `eigenvalues` (3,) (an argument
    rather than a result: numba boxes every array it returns); returns (the smallest, the spread)."""
    values, minimum, spread = _spectrum(information)
    eigenvalues[:] = values
    return minimum, spread
