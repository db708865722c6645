"""Several pursuers in process (studies.swarm) and the 'fusion' estimator (FusionEstimator).

References: the single-pursuer simulator (studies.closed_loop) for one pursuer, the flown geometry
(positions in the series) for separation, range and phase spacing, and the closed forms of the
information sum and of covariance intersection for the fusion.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.assembly import build_estimator, build_swarm_estimator
from companion.core.cooperative_estimation import FusionEstimator
from companion.core.estimators import UPLKF, GainProjection, InitialGuess
from companion.core.messages import BearingMeasurement, TargetEstimate
from interfaces.scenario import load_scenario
from studies.closed_loop import simulate
from studies.swarm import simulate_swarm

SCENARIOS = Path(__file__).resolve().parent.parent / "config" / "scenarios"


def _load(name: str = "swarm_circumnavigation", duration: float | None = None):
    scenario, vehicle = load_scenario(SCENARIOS / f"{name}.toml")
    if duration is not None:
        scenario = scenario.model_copy(update={"simulation": scenario.simulation.model_copy(update={"duration": duration})})
    return scenario, vehicle


def _swarm(scenario, **update):
    return scenario.model_copy(update={"swarm": scenario.swarm.model_copy(update=update)})


# ---------------------------------------------------------------------------------------------
# The harness
# ---------------------------------------------------------------------------------------------

FIGURES = ("range_error_rms", "range_estimation_error_rms", "range_estimation_error_max_abs",
           "position_estimation_error_rms", "velocity_estimation_error_rms", "min_range", "max_tilt_deg", "max_speed",
           "heading_error_rms_deg", "duration", "termination")


def test_one_pursuer_in_a_swarm_table_flies_the_single_pursuer_flight_exactly():
    """[swarm] with one entry: the single-pursuer simulator's flight of the same seed, bit for bit (no
    neighbour ever: the single laws, the same draws)."""
    scenario, vehicle = _load(duration=20.0)
    alone = _swarm(scenario, pursuers=scenario.swarm.pursuers[:1])
    reference = simulate(scenario.model_copy(update={"swarm": None}), vehicle, seed=3)
    flown = simulate_swarm(alone, vehicle, seed=3)
    for key in FIGURES:
        assert flown.summary[key] == reference.summary[key], key
    np.testing.assert_array_equal(flown.series[1]["pursuer_position"], reference.series["pursuer_position"])
    np.testing.assert_array_equal(flown.series[1]["range_estimate"], reference.series["range_estimate"])
    assert flown.summary["law_changes"] == []


def _phase_gaps(positions: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Angular gaps between neighbouring pursuers around the target, rad, (N,) per sample: positions (N, T, 3)."""
    phases = np.sort(np.arctan2(positions[:, :, 1] - target[:, 1], positions[:, :, 0] - target[:, 0]), axis=0)
    return np.diff(np.vstack([phases, phases[:1] + 2 * np.pi]), axis=0)


def test_three_pursuers_keep_apart_keep_off_the_target_and_converge():
    scenario, vehicle = _load()
    result = simulate_swarm(scenario, vehicle, seed=1)
    series = result.series
    positions = np.array([series[k]["pursuer_position"] for k in (1, 2, 3)])
    target = series[1]["target_position"]
    gaps = np.linalg.norm(positions[:, None] - positions[None, :], axis=3)
    closest = min(float(gaps[i, j].min()) for i in range(3) for j in range(i + 1, 3))
    assert closest >= scenario.swarm.min_separation
    ranges = np.linalg.norm(positions - target[None], axis=2)
    assert ranges.min() >= 0.5 * scenario.guidance.desired_range
    window = series[1]["time"] >= series[1]["time"][-1] - 20.0
    # every pursuer's estimate within 1 m of the target over the last 20 s, and on the circle within 2 m
    for k in (1, 2, 3):
        error = np.linalg.norm(series[k]["estimate_position"] - series[k]["target_position"], axis=1)
        assert error[window].max() < 1.0
        horizontal = np.linalg.norm((positions[k - 1] - target)[:, :2], axis=1)
        assert np.abs(horizontal[window] - scenario.guidance.desired_range).max() < 2.0
    spacing = _phase_gaps(positions[:, window], target[window]) - 2 * np.pi / 3
    assert math.degrees(float(np.sqrt(np.mean(spacing**2)))) < 5.0
    assert result.termination.name == "COMPLETED"


def test_with_every_share_lost_each_pursuer_flies_alone():
    """loss_probability 1: no neighbour bearing reaches any estimator and nobody ever cooperates: each pursuer
    flies the circumnavigation law alone on its own layer (an orbit 1.5 min_separation x its id larger,
    companion.assembly.build_cooperation) from the start, and the pursuers stay apart."""
    scenario, vehicle = _load(duration=20.0)
    silent = _swarm(scenario, link=scenario.swarm.link.model_copy(update={"loss_probability": 1.0}))
    result = simulate_swarm(silent, vehicle, seed=2)
    for entry in result.summary["pursuers"]:
        assert entry["neighbour_bearings_used"] == 0
        assert entry["bearings_used"] > 0
        assert entry["law_changes"] == [(0.0, "lone")]
    link = result.summary["share_link"]
    assert link.get("delivered", 0) == 0 and link["offered"] > 0 and link["loss"] == link["offered"]
    assert result.summary["min_pursuer_separation"] > silent.swarm.min_separation


def test_with_shares_the_pursuers_cooperate_and_use_neighbour_bearings():
    scenario, vehicle = _load(duration=10.0)
    result = simulate_swarm(scenario, vehicle, seed=2)
    for entry in result.summary["pursuers"]:
        assert entry["neighbour_bearings_used"] > 0
        assert entry["law_changes"] and entry["law_changes"][0][1] == "cooperative"


def test_a_flight_is_determined_by_its_seed():
    scenario, vehicle = _load(duration=8.0)
    first, again, other = (simulate_swarm(scenario, vehicle, seed=s) for s in (5, 5, 6))
    for k in (1, 2, 3):
        for key in ("pursuer_position", "range_estimate", "estimate_position"):
            np.testing.assert_array_equal(first.series[k][key], again.series[k][key])
    assert not np.array_equal(first.series[2]["range_estimate"], other.series[2]["range_estimate"])


def test_fusion_flight_absorbs_estimates_and_converges():
    """estimator 'fusion' (covariance intersection): own bearings only, neighbours' estimates absorbed;
    every pursuer's estimate ends within 1 m of the target."""
    scenario, vehicle = _load()
    result = simulate_swarm(_swarm(scenario, estimator="fusion"), vehicle, seed=1)
    series = result.series
    window = series[1]["time"] >= series[1]["time"][-1] - 20.0
    for entry in result.summary["pursuers"]:
        assert entry["neighbour_bearings_used"] == 0
        assert entry["estimates_absorbed"] > 100
        assert entry["estimates_refused"] == {}
        data = series[entry["pursuer"]]
        error = np.linalg.norm(data["estimate_position"] - data["target_position"], axis=1)
        assert error[window].max() < 1.0


# ---------------------------------------------------------------------------------------------
# FusionEstimator against the closed forms
# ---------------------------------------------------------------------------------------------

def _spd(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    factor = rng.standard_normal((6, 6))
    return scale * (factor @ factor.T + 0.1 * np.eye(6))


def _own_filter(rng: np.random.Generator, time: float = 4.0) -> tuple[UPLKF, np.ndarray, np.ndarray]:
    inner = UPLKF(0.02, 0.04 * np.eye(3), 1e-4 * np.eye(3), GainProjection.PREDICTED)
    state = rng.standard_normal(6) * 5.0
    covariance = _spd(rng)
    inner.initialize(time, state[:3], state[3:], covariance)
    return inner, state, covariance


def _estimate(time: float, state: np.ndarray, covariance: np.ndarray) -> TargetEstimate:
    return TargetEstimate(time, state[:3].copy(), state[3:].copy(), covariance.copy())


@given(st.integers(0, 2**32 - 1), st.integers(1, 3))
@settings(max_examples=40, deadline=None)
def test_seed004_absorb_is_the_information_sum(seed, count):
    rng = np.random.default_rng(seed)
    inner, x_own, p_own = _own_filter(rng)
    fusion = FusionEstimator(inner, "seed004")
    neighbours = [(rng.standard_normal(6) * 5.0, _spd(rng)) for _ in range(count)]
    assert fusion.absorb([_estimate(4.0, x, p) for x, p in neighbours]) == count
    information = np.linalg.inv(p_own) + sum(np.linalg.inv(p) for _, p in neighbours)
    expected_p = np.linalg.inv(information)
    expected_x = expected_p @ (np.linalg.solve(p_own, x_own) + sum(np.linalg.solve(p, x) for x, p in neighbours))
    got = fusion.estimate
    np.testing.assert_allclose(got.covariance, expected_p, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(np.concatenate([got.position, got.velocity]), expected_x, rtol=1e-6, atol=1e-7)
    assert got.time == 4.0 and fusion.absorbed == count


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=40, deadline=None)
def test_ci_absorb_is_the_trace_optimal_convex_combination_of_informations(seed):
    """P^-1 = w P1^-1 + (1 - w) P2^-1 for one w in [0, 1], x = P (w P1^-1 x1 + (1 - w) P2^-1 x2), and no
    w on a fine grid gives a smaller trace (Julier & Uhlmann's covariance intersection)."""
    rng = np.random.default_rng(seed)
    inner, x1, p1 = _own_filter(rng)
    x2, p2 = rng.standard_normal(6) * 5.0, _spd(rng, 2.0)
    fusion = FusionEstimator(inner, "ci")
    fusion.absorb([_estimate(4.0, x2, p2)])
    got = fusion.estimate
    i1, i2 = np.linalg.inv(p1), np.linalg.inv(p2)
    fused_information = np.linalg.inv(got.covariance)
    w = float(np.sum((fused_information - i2) * (i1 - i2)) / np.sum((i1 - i2) ** 2))
    assert -1e-9 <= w <= 1 + 1e-9
    np.testing.assert_allclose(fused_information, w * i1 + (1 - w) * i2, rtol=1e-5, atol=1e-7 * np.abs(i1).max())
    np.testing.assert_allclose(np.concatenate([got.position, got.velocity]),
                               got.covariance @ (w * i1 @ x1 + (1 - w) * i2 @ x2), rtol=1e-5, atol=1e-6)
    grid = [np.trace(np.linalg.inv(v * i1 + (1 - v) * i2)) for v in np.linspace(0.0, 1.0, 401)]
    assert np.trace(got.covariance) <= min(grid) * (1 + 1e-7)


def test_a_late_neighbour_estimate_is_carried_to_the_own_time_at_constant_velocity():
    rng = np.random.default_rng(7)
    inner, x_own, p_own = _own_filter(rng, time=4.0)
    fusion = FusionEstimator(inner, "seed004")
    x2, p2 = rng.standard_normal(6), _spd(rng)
    fusion.absorb([_estimate(3.6, x2, p2)])
    transition = np.eye(6)
    transition[:3, 3:] = 0.4 * np.eye(3)
    carried_x, carried_p = transition @ x2, transition @ p2 @ transition.T
    expected_p = np.linalg.inv(np.linalg.inv(p_own) + np.linalg.inv(carried_p))
    expected_x = expected_p @ (np.linalg.solve(p_own, x_own) + np.linalg.solve(carried_p, carried_x))
    np.testing.assert_allclose(fusion.estimate.covariance, expected_p, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(fusion.estimate.position, expected_x[:3], rtol=1e-6, atol=1e-7)


def test_an_imm_absorbs_into_every_model_filter_and_keeps_its_probabilities():
    scenario, _ = _load()
    imm = build_estimator(scenario)
    assert hasattr(imm, "filters") and len(imm.filters) > 1
    fusion = FusionEstimator(imm, "seed004")
    bearing = BearingMeasurement(0.0, np.array([0.6, -0.3, -0.2]) / np.linalg.norm([0.6, -0.3, -0.2]), np.zeros(3))
    fusion.initialize_on_bearing(bearing, InitialGuess(50.0, 30.0, np.zeros(3), 5.0))
    for step in range(1, 26):
        fusion.predict()
        if step % 10 == 0:
            fusion.correct(BearingMeasurement(step * 0.02, bearing.direction, np.array([0.5 * step * 0.02, 0.0, 0.0])))
    before = [tuple(np.array(a) for a in f.state_and_covariance) for f in imm.filters]
    probabilities = imm.model_probabilities
    rng = np.random.default_rng(3)
    x2 = np.concatenate([50.0 * bearing.direction, np.zeros(3)]) + rng.standard_normal(6)
    p2 = _spd(rng)
    fusion.absorb([_estimate(imm.time, x2, p2)])
    for model_filter, (x1, p1) in zip(imm.filters, before):
        expected_p = np.linalg.inv(np.linalg.inv(p1) + np.linalg.inv(p2))
        expected_x = expected_p @ (np.linalg.solve(p1, x1) + np.linalg.solve(p2, x2))
        state, covariance = model_filter.state_and_covariance
        np.testing.assert_allclose(covariance, expected_p, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(state, expected_x, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(imm.model_probabilities, probabilities)
    assert fusion.motion_probabilities == imm.motion_probabilities  # the wrapper shows the IMM's extras
    fusion.process_noise_boost = 2.0
    assert imm.process_noise_boost == 2.0


def test_hostile_or_useless_estimates_are_refused_counted_and_change_nothing():
    rng = np.random.default_rng(11)
    uninitialized = FusionEstimator(UPLKF(0.02, np.eye(3), 1e-4 * np.eye(3)), "ci")
    assert uninitialized.absorb([_estimate(0.0, np.zeros(6), np.eye(6))]) == 0
    assert uninitialized.rejections["not_initialized"] == 1
    inner, x_own, p_own = _own_filter(rng)
    fusion = FusionEstimator(inner, "ci", max_age_s=1.0)
    singular = np.zeros((6, 6))
    singular[0, 0] = 1.0
    negative = -np.eye(6)
    bad = [_estimate(4.0, np.full(6, np.nan), np.eye(6)), _estimate(4.0, np.zeros(6), np.full((6, 6), np.inf)),
           _estimate(math.nan, np.zeros(6), np.eye(6)), _estimate(2.0, np.zeros(6), np.eye(6)),
           _estimate(4.0, np.zeros(6), singular), _estimate(4.0, np.zeros(6), negative)]
    assert fusion.absorb(bad) == 0
    assert fusion.rejections == {"not_finite": 3, "too_old": 1, "not_positive_definite": 2}
    np.testing.assert_array_equal(np.concatenate([fusion.estimate.position, fusion.estimate.velocity]), x_own)
    np.testing.assert_array_equal(fusion.estimate.covariance, p_own)
    # a good one next to the bad ones is still fused
    assert fusion.absorb(bad[:1] + [_estimate(4.0, x_own, p_own)]) == 1
    with pytest.raises(ValueError):
        FusionEstimator(inner, "average")


def test_assembly_builds_the_fusion_estimator_from_swarm_fusion():
    scenario, _ = _load()
    for method, short in (("covariance_intersection", "ci"), ("seed004", "seed004")):
        fused = _swarm(scenario, estimator="fusion", fusion=scenario.swarm.fusion.model_copy(update={"method": method}))
        estimator = build_swarm_estimator(fused)
        assert isinstance(estimator, FusionEstimator) and estimator.method == short
        assert estimator.max_age_s == scenario.swarm.neighbour_timeout_s
