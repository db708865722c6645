"""Late bearings in the closed loop: fixes that arrive seconds after their stamps (a link's steady latency, a
stalled target process that catches up) still give a good estimate and a followed target.

The simulator flies the paper's constant-velocity case with the link model's latency ([faults] latency_s), so
every fix goes through the same encoder, fault model, validator and bearing-at-its-stamp path as over Zenoh.
The references are physical: the pursuer keeps r_d to within a metre over the last 20 s and never comes
within r_d / 2 of the target. Before the u-PLKF measured a late bearing at its own time (H = P_lambda [I, tau I])
a steady 0.5 s latency diverged seed 1 (range-estimation RMS 178 m) and 1 s sent the pursuer hundreds of metres
away (range error RMS 191 m: stuck in the degraded mode, whose exit needed a fresh bearing)."""

from __future__ import annotations

import pytest

from interfaces.scenario import SCENARIOS_DIR, FaultsConfig, load_scenario
from studies.closed_loop import simulate


def _with_latency(latency: float, jitter: float = 0.0):
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    faults = scenario.faults.model_copy(update={"latency_s": latency, "jitter_s": jitter})
    return scenario.model_copy(update={"faults": faults}), vehicle


@pytest.mark.parametrize("latency, jitter", [(0.5, 0.0), (1.0, 0.2), (2.0, 0.0)])
def test_a_steady_link_latency_keeps_the_target(latency, jitter):
    scenario, vehicle = _with_latency(latency, jitter)
    for seed in (0, 1):
        summary = simulate(scenario, vehicle, seed=seed).summary
        assert summary["termination"] == "completed", (latency, seed, summary["termination"])
        assert summary["link"]["delivered"] > 0.9 * summary["link"]["offered"]
        assert summary["range_estimation_error_rms"] < 1.0, (latency, seed, summary["range_estimation_error_rms"])
        assert summary["range_error_rms"] < 1.0, (latency, seed, summary["range_error_rms"])
        assert summary["min_range"] > 0.5 * summary["desired_range"], (latency, seed, summary["min_range"])


def test_a_stalled_target_publisher_costs_neither_the_estimate_nor_the_safe_range():
    """The in-process twin of the SITL test of a stopped target process: three times while following, the
    publisher freezes for 7.5 s and then delivers the window's fixes at once ([faults] stalls). The pursuer
    coasts, turns degraded (holds the safe range on the prediction), then takes the catch-up fixes at their
    own stamps. Physical reference: it never comes within r_d / 2 of the target. Before the attitude mapping kept PX4's horizontal thrust margin, a hard vertical demand on
    re-engagement took all the thrust (acceleration flown [0, 0, -3.43] for 2 s) and the pursuer could not
    brake: 0.95 m from the target in SITL; in process here 4.7-6.9 m over seeds 1-6 (now 5.4-7.5 m)."""
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    stalls = [{"start": start, "duration": 7.5} for start in (5.0, 20.0, 35.0)]
    faults = scenario.faults.model_copy(update={"stalls": FaultsConfig.model_validate({"stalls": stalls}).stalls})
    scenario = scenario.model_copy(update={"faults": faults})
    for seed in (1, 4):
        summary = simulate(scenario, vehicle, seed=seed).summary
        assert summary["termination"] == "completed", (seed, summary["termination"])
        assert summary["link"]["delivered"] >= summary["link"]["offered"] - 1, (seed, summary["link"])
        assert summary["range_estimation_error_rms"] < 1.0, (seed, summary["range_estimation_error_rms"])
        assert summary["min_range"] > 0.5 * summary["desired_range"], (seed, summary["min_range"])
        # No bound on range_error_rms: the last stall (35-42.5 s) falls in the 20 s summary window, and while
        # degraded the pursuer holds the safe range (1.5 r_d), as it should.
