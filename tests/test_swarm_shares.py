"""The in-process harness's shares (studies/swarm.py): what a pursuer says to its neighbours is checked by the
payload schema (interfaces.link_schema.checked_pursuer_share: what its encoder and decoder give, tested against
them in tests/test_swarm_schema.py), so the reference is the schema."""

from __future__ import annotations

import math

import numpy as np

from companion.core.messages import BearingMeasurement, TargetEstimate
from interfaces.scenario import SCENARIOS_DIR, load_scenario, pursuer_starts
from studies import swarm


class _Estimator:
    def __init__(self, estimate: TargetEstimate) -> None:
        self.estimate = estimate


def _pursuer(estimate: TargetEstimate):
    scenario, vehicle = load_scenario(SCENARIOS_DIR / "swarm_circumnavigation.toml")
    pursuer = swarm._pursuer(scenario, vehicle, pursuer_starts(scenario)[1], seed=3, rows=1)
    pursuer.pipeline._engaged_at = 0.0
    pursuer.pipeline.estimator = _Estimator(estimate)
    pursuer.latest_bearing = BearingMeasurement(11.5, np.array([0.0, 1.0, 0.0]), np.array([1.0, 2.0, -3.0]), source=0)
    return pursuer


def test_a_share_carries_the_newest_bearing_once_and_an_estimate_a_rounding_step_late():
    """The estimate's clock (ticks of the estimator) may run one float step past the share's (steps of the
    loop): the schema allows 1 us, so the share decodes with its estimate."""
    estimate = TargetEstimate(math.nextafter(11.75, 12.0), np.zeros(3), np.ones(3), np.eye(6))
    pursuer = _pursuer(estimate)
    first = swarm._share(pursuer, 11.75, np.zeros(3), np.zeros(3))
    second = swarm._share(pursuer, 11.95, np.zeros(3), np.zeros(3))
    assert first.sender == 2 and first.estimate is not None and first.bearing.stamp == 11.5
    assert second.bearing is None and second.seq == first.seq + 1  # the bearing is shared once
    assert pursuer.estimates_not_shared == {}


def test_a_diverged_estimate_is_left_out_of_the_share_and_counted():
    """An estimate the schema refuses (|v| > 1e3 m/s: a diverged filter) does not stop the flight: the share
    goes without it and the pursuer counts it by the schema's reason."""
    estimate = TargetEstimate(11.0, np.zeros(3), np.array([2000.0, 0.0, 0.0]), np.eye(6))
    pursuer = _pursuer(estimate)
    share = swarm._share(pursuer, 11.75, np.zeros(3), np.zeros(3))
    assert share.estimate is None and share.bearing is not None
    assert sum(pursuer.estimates_not_shared.values()) == 1
