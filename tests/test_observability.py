"""Section V observability: eq. (7)-(10) identities, the eq. (12) optimiser, the windowed FIM, Figs. 3-5."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_reference import floats, unit_vectors

from companion.core.observability import (
    Plane,
    WindowedObservability,
    eigenvalue_spread,
    fim_determinant,
    fisher_information,
    g_matrix,
    g_norm_squared_equal_range,
    optimize_placement,
    random_placement,
    spread_from_g,
)
from studies import observability_figures

BACK_PLANE = Plane(point=[-1.0, 0.0, 0.0], normal=[1.0, 0.0, 0.0], gain=1.0)


def _unit_rows(array):
    return array / np.linalg.norm(array, axis=1, keepdims=True)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(unit_vectors(), floats(0.5, 30.0)), min_size=2, max_size=14), floats(0.01, 0.2), floats(1.0, 20.0))
def test_explicit_forms_match_direct_computation(observations, sigma, r_d):
    bearings = np.array([bearing for bearing, _ in observations])
    ranges = np.array([distance for _, distance in observations])
    information = fisher_information(bearings, ranges, sigma)
    # eq. (7): I_n = sum_i P_lambda_i / (sigma^2 r_i^2)
    expected = sum((np.eye(3) - np.outer(b, b)) / (sigma**2 * r**2) for b, r in zip(bearings, ranges))
    np.testing.assert_allclose(information, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    # eq. (9): G = sum_i lambda_i lambda_i^T / (sigma^2 r_i^2)
    g_expected = sum(np.outer(b, b) / (sigma**2 * r**2) for b, r in zip(bearings, ranges))
    np.testing.assert_allclose(g_matrix(bearings, ranges, sigma), g_expected, rtol=1e-12, atol=1e-12 * np.abs(g_expected).max())
    # eq. (8) with unequal ranges against the definition of J via the eigenvalues
    eigenvalues = np.linalg.eigvalsh(information)
    spread_eigen = float(np.sum((eigenvalues - eigenvalues.mean()) ** 2))
    scale = eigenvalues.max() ** 2
    assert eigenvalue_spread(information) == pytest.approx(spread_eigen, rel=1e-9, abs=1e-12 * scale)
    assert spread_from_g(bearings, ranges, sigma) == pytest.approx(spread_eigen, rel=1e-9, abs=1e-9 * scale)
    assert fim_determinant(bearings, ranges, sigma) == pytest.approx(np.prod(eigenvalues), rel=1e-9, abs=1e-9 * eigenvalues.max() ** 3)
    # eq. (10) with equal ranges against eq. (9) written out
    g = sum(np.outer(b, b) for b in bearings) / (sigma**2 * r_d**2)
    assert g_norm_squared_equal_range(bearings, sigma, r_d) == pytest.approx(float(np.sum(g**2)), rel=1e-12)


def test_bad_input_raises():
    with pytest.raises(ValueError):
        fisher_information(np.array([[1.0, 1.0, 0.0]]), np.array([1.0]), 0.1)
    with pytest.raises(ValueError):
        fisher_information(np.array([[1.0, 0.0, 0.0]]), np.array([-1.0]), 0.1)
    with pytest.raises(ValueError):
        g_matrix(np.array([[1.0, 0.0, 0.0]]), np.array([1.0]), 0.0)
    with pytest.raises(ValueError):
        Plane(point=[0.0, 0.0, 0.0], normal=[2.0, 0.0, 0.0], gain=1.0)
    with pytest.raises(ValueError):
        optimize_placement(np.array([[-1.0, 0.0, 0.0]]), [BACK_PLANE], duration=1.0)
    with pytest.raises(ValueError):
        optimize_placement(np.array([[1.0, 0.0, 0.0]]), steps=10, duration=1.0)


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_gradient_force_alone_decreases_g_norm(seed):
    rng = np.random.default_rng(seed)
    initial = random_placement(10, rng)
    result = optimize_placement(initial, (), k_g=1.0, k_m=0.0, dt=1e-3, duration=3.0)
    increments = np.diff(result.g_norms)
    assert increments.max() <= 1e-9  # Lyapunov: V = ||G||_F^2 / 2 never increases
    assert result.final_g_norm < result.g_norms[0]
    assert result.final_g_norm == pytest.approx(10 / math.sqrt(3.0), abs=0.02)  # unconstrained optimum


def test_particles_never_cross_planes():
    rng = np.random.default_rng(5)
    planes = [
        Plane(point=[0.3, 0.0, 0.0], normal=[1.0, 0.0, 0.0], gain=0.05),
        Plane(point=[0.0, 0.0, 0.4], normal=[0.0, 0.0, -1.0], gain=0.05),
    ]
    initial = random_placement(10, rng, planes)
    result = optimize_placement(
        initial, planes, k_g=20.0, k_m=50.0, dt=5e-3, duration=20.0, record_times=np.arange(0.0, 20.01, 0.05)
    )
    for plane in planes:
        assert np.all(plane.signed_distance(result.positions.reshape(-1, 3)) > 0.0)
        assert np.all(plane.signed_distance(result.final_bearings) > 0.0)
    np.testing.assert_allclose(np.linalg.norm(result.positions, axis=2), 1.0, atol=1e-12)


def test_fig3_configuration_converges_to_revolving_circle():
    rng = np.random.default_rng(1)
    initial = random_placement(10, rng, [BACK_PLANE])
    result = optimize_placement(initial, [BACK_PLANE], k_g=1.0, k_m=5.0, dt=1e-3, duration=10.0, record_times=[10.0])
    assert 10 / math.sqrt(3.0) < result.final_g_norm < 10 / math.sqrt(2.0)
    centred = result.final_bearings - result.final_bearings.mean(axis=0)
    singular_values = np.linalg.svd(centred, compute_uv=False)
    assert singular_values[2] < 1e-3 * singular_values[1]  # nearly planar: a circle on the sphere
    speeds = np.linalg.norm(result.velocities[-1], axis=1)
    assert speeds.min() > 0.1  # dynamic equilibrium: the particles revolve


def test_random_placement_respects_planes_and_seed():
    planes = [Plane(point=[0.5, 0.0, 0.0], normal=[1.0, 0.0, 0.0], gain=1.0)]
    first = random_placement(50, np.random.default_rng(3), planes)
    second = random_placement(50, np.random.default_rng(3), planes)
    np.testing.assert_array_equal(first, second)
    assert np.all(first[:, 0] > 0.5)
    np.testing.assert_allclose(np.linalg.norm(first, axis=1), 1.0)


def test_windowed_single_direction_is_rank_two():
    window = WindowedObservability(window_s=10.0, sigma=0.05)
    for index in range(20):
        window.add(0.2 * index, np.array([0.0, 0.6, 0.8]), 20.0)
    measure = window.measure()
    assert measure["count"] == 20
    assert measure["log_det"] == -math.inf
    assert measure["min_eigenvalue"] == 0.0
    assert np.linalg.matrix_rank(window.information) == 2


def test_windowed_spread_bearings_full_rank_and_window_drops():
    rng = np.random.default_rng(7)
    window = WindowedObservability(window_s=2.0, sigma=0.05)
    bearings = random_placement(30, rng)
    for index, bearing in enumerate(bearings):
        window.add(0.25 * index, bearing, 10.0)  # binary-exact times: no rounding at the window edge
    measure = window.measure()
    assert measure["count"] == 9  # samples in [7.25 - 2.0, 7.25]
    assert measure["min_eigenvalue"] > 0.0
    assert math.isfinite(measure["log_det"])
    expected = fisher_information(bearings[-9:], np.full(9, 10.0), 0.05)
    np.testing.assert_allclose(window.information, expected, rtol=1e-9, atol=1e-9)
    assert measure["log_det"] == pytest.approx(math.log10(np.linalg.det(expected)), rel=1e-9)


def test_helix_beats_pure_pursuit():
    times = np.arange(0.0, 10.0, 0.2)
    helix = _unit_rows(np.column_stack([np.full_like(times, 2.0), np.cos(times), np.sin(times)]))
    pursuit = _unit_rows(np.column_stack([np.ones_like(times), 0.01 * np.sin(times), 0.01 * np.cos(times)]))
    measures = []
    for bearings in (helix, pursuit):
        window = WindowedObservability(window_s=20.0, sigma=0.05)
        for time, bearing in zip(times, bearings):
            window.add(time, bearing, 30.0)
        measures.append(window.measure())
    assert measures[0]["min_eigenvalue"] > 100 * measures[1]["min_eigenvalue"]
    assert measures[0]["log_det"] > measures[1]["log_det"]
    assert measures[0]["spread"] < measures[1]["spread"]


def test_figure_command_writes_files(tmp_path):
    # --out is the parent folder, as for every bof-* command: one run folder is created inside it.
    assert observability_figures.main(["--out", str(tmp_path), "--seed", "1", "--random", "50"]) == 0
    (out,) = tmp_path.iterdir()
    assert out.name.startswith("observability-")
    for name in ("fig3.png", "fig4.png", "fig5.png", "summary.json"):
        assert (out / name).stat().st_size > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["random_placements"] == 50
    assert summary["bound_isotropic"] < summary["fig3_final_g_norm"] < summary["bound_great_circle"]
    assert 0.0 <= summary["share_random_worse"] <= 1.0


def _measures_equal(first: dict, second: dict) -> bool:
    return first.keys() == second.keys() and all(
        (math.isnan(a) and math.isnan(b)) or a == b for a, b in ((first[k], second[k]) for k in first))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([0.0, 0.02, 0.2, 0.7, 1.5, 4.0]), unit_vectors(),
                          st.one_of(floats(0.5, 500.0), st.sampled_from([0.0, -3.0, math.inf, math.nan, 1e200]))),
                min_size=1, max_size=40),
       st.sampled_from([0.5, 1.0, 3.0]))
def test_add_and_measure_is_add_then_measure(samples, window):
    """WindowedObservability.add_and_measure (the pipeline's one call per bearing) against add then measure on a
    twin: the same FIM to the bit, the same measure, the same window, the same error for a bad sample, over
    sequences whose gaps make none, one or several old terms leave the window at once."""
    fused, reference = WindowedObservability(window, 0.01), WindowedObservability(window, 0.01)
    time = 0.0
    for gap, bearing, distance in samples:
        time += gap
        try:
            reference.add(time, bearing, distance)
            expected = reference.measure()
        except (ValueError, OverflowError) as error:
            with pytest.raises(type(error)):
                fused.add_and_measure(time, bearing, distance)
        else:
            assert _measures_equal(fused.add_and_measure(time, bearing, distance), expected)
        assert fused.information.tobytes() == reference.information.tobytes()
        assert [t for t, _ in fused._samples] == [t for t, _ in reference._samples]
