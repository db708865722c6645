"""The pursuer <-> pursuer share link's fault model (interfaces.neighbour_link, [swarm.link])."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from interfaces.neighbour_link import DROP_REASONS, NeighbourLink
from interfaces.scenario import SCENARIOS_DIR, SwarmLinkConfig, load_scenario

NEAR = (np.zeros(3), np.array([5.0, 0.0, 0.0]))


def _link(pursuers: int = 3, simulation_seed: int = 0, **config) -> NeighbourLink:
    return NeighbourLink(SwarmLinkConfig(**config), pursuers=pursuers, simulation_seed=simulation_seed)


def _send(link: NeighbourLink, count: int, sender: int = 1, receiver: int = 2, period: float = 0.2):
    return [link.transmit(k * period, sender, receiver, *NEAR) for k in range(count)]


@pytest.mark.parametrize("probability", [0.05, 0.3, 0.7])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_loss_follows_the_binomial(probability, seed):
    """The lost count of n shares is Binomial(n, p) (two-sided exact test), per pair and over all pairs."""
    link = _link(pursuers=3, simulation_seed=seed, loss_probability=probability)
    n = 3000
    per_pair = {}
    for sender, receiver in itertools.permutations((1, 2, 3), 2):
        per_pair[(sender, receiver)] = sum(not d.delivered for d in _send(link, n, sender, receiver))
    for lost in per_pair.values():
        assert stats.binomtest(lost, n, probability).pvalue > 1e-3
    assert stats.binomtest(sum(per_pair.values()), 6 * n, probability).pvalue > 1e-3
    assert link.counters["loss"] == sum(per_pair.values()) and link.counters["offered"] == 6 * n


def test_losses_are_independent_of_each_other():
    """Runs of losses have the lengths of independent draws: a loss follows a loss with probability p
    (chi-square on the 2 x 2 table of consecutive outcomes)."""
    outcomes = np.array([not d.delivered for d in _send(_link(simulation_seed=5, loss_probability=0.4), 20000)])
    table = np.array([[np.sum(~outcomes[:-1] & ~outcomes[1:]), np.sum(~outcomes[:-1] & outcomes[1:])],
                      [np.sum(outcomes[:-1] & ~outcomes[1:]), np.sum(outcomes[:-1] & outcomes[1:])]])
    assert stats.chi2_contingency(table).pvalue > 1e-3


def test_delay_is_latency_plus_uniform_jitter():
    link = _link(simulation_seed=3, latency_s=0.25, jitter_s=0.1)
    deliveries = _send(link, 5000, period=0.01)
    delays = np.array([d.time - k * 0.01 for k, d in enumerate(deliveries)])
    assert all(d.delivered for d in deliveries)
    assert delays.min() >= 0.25 - 1e-12 and delays.max() <= 0.35 + 1e-12
    assert stats.kstest((delays - 0.25) / 0.1, "uniform").pvalue > 1e-3
    # without jitter, exactly the latency
    assert [d.time - k * 0.2 for k, d in enumerate(_send(_link(latency_s=0.5), 10))] == pytest.approx([0.5] * 10)


def test_radius_is_exact_in_three_dimensions():
    # 3^2 + 4^2 + 12^2 = 13^2: the two pursuers are exactly 13 m apart.
    here, there = np.array([1.0, -2.0, -20.0]), np.array([4.0, 2.0, -8.0])
    assert _link(radius=13.0).transmit(0.0, 1, 2, here, there).delivered
    dropped = _link(radius=math.nextafter(13.0, 0.0)).transmit(0.0, 1, 2, here, there)
    assert (dropped.delivered, dropped.reason, dropped.distance) == (False, "out_of_radius", 13.0)
    assert _link(radius=math.inf).transmit(0.0, 1, 2, np.zeros(3), np.full(3, 1e9)).delivered


@settings(max_examples=200, deadline=None, database=None)
@given(st.floats(0.0, 1e4), st.floats(1e-3, 1e4))
def test_within_radius_on_an_axis(distance, radius):
    delivery = _link(radius=radius).transmit(1.0, 2, 3, np.array([0.0, 0.0, -10.0]), np.array([0.0, distance, -10.0]))
    assert delivery.delivered == (distance <= radius)
    assert delivery.reason == (None if distance <= radius else "out_of_radius")


def test_blackout_silences_both_ends_exactly_in_its_window():
    link = _link(pursuers=3, blackouts=[{"pursuer": 2, "start": 5.0, "end": 8.0}])
    for time, silent in ((4.999, False), (5.0, True), (7.999, True), (8.0, False), (100.0, False)):
        for sender, receiver in ((2, 1), (1, 2), (3, 2), (2, 3)):
            delivery = link.transmit(time, sender, receiver, *NEAR)
            assert delivery.delivered != silent and delivery.reason == ("blackout" if silent else None)
        assert link.transmit(time, 1, 3, *NEAR).delivered and link.transmit(time, 3, 1, *NEAR).delivered
    assert link.counters["blackout"] == 2 * 4


def test_a_blackout_is_counted_before_the_radius_and_the_radius_before_the_loss():
    link = _link(radius=1.0, loss_probability=1.0, blackouts=[{"pursuer": 1, "start": 0.0, "end": 1.0}])
    far = (np.zeros(3), np.array([10.0, 0.0, 0.0]))
    assert link.transmit(0.5, 1, 2, *far).reason == "blackout"
    assert link.transmit(1.5, 1, 2, *far).reason == "out_of_radius"
    assert link.transmit(1.5, 1, 2, np.zeros(3), np.array([0.5, 0.0, 0.0])).reason == "loss"
    assert link.counters == {"offered": 3, "blackout": 1, "out_of_radius": 1, "loss": 1}


@settings(max_examples=50, deadline=None, database=None)
@given(st.integers(0, 2**32), st.lists(st.tuples(st.integers(1, 4), st.integers(1, 4), st.floats(0.0, 200.0),
                                                 st.floats(0.0, 400.0)), max_size=60))
def test_counters_add_up(seed, calls):
    link = _link(pursuers=4, simulation_seed=seed, radius=200.0, loss_probability=0.3,
                 blackouts=[{"pursuer": 3, "start": 50.0, "end": 120.0}])
    made = 0
    for sender, receiver, time, east in calls:
        if sender == receiver:
            continue
        link.transmit(time, sender, receiver, np.zeros(3), np.array([0.0, east, 0.0]))
        made += 1
    assert link.counters["offered"] == made
    assert link.counters["delivered"] + sum(link.counters[r] for r in DROP_REASONS) == made
    assert sum(c["offered"] for c in link.pair_counters.values()) == made


def _decisions(link: NeighbourLink, order: list[tuple[int, int]]) -> dict:
    """Per pair, in its order: (delivered, delay s) of each share (sent at a time depending on the interleaving)."""
    decisions: dict = {}
    for step, (sender, receiver) in enumerate(order):
        delivery = link.transmit(step * 0.05, sender, receiver, *NEAR)
        delay = None if delivery.time is None else round(delivery.time - step * 0.05, 9)
        decisions.setdefault((sender, receiver), []).append((delivery.delivered, delay))
    return decisions


def test_same_seed_same_decisions_and_another_seed_others():
    settings_ = dict(loss_probability=0.3, jitter_s=0.05)
    first = [(d.delivered, d.time) for d in _send(_link(simulation_seed=11, **settings_), 500)]
    assert first == [(d.delivered, d.time) for d in _send(_link(simulation_seed=11, **settings_), 500)]
    assert first != [(d.delivered, d.time) for d in _send(_link(simulation_seed=12, **settings_), 500)]
    # [swarm.link] seed overrides the simulation's seed
    own = [(d.delivered, d.time) for d in _send(_link(simulation_seed=11, seed=7, **settings_), 500)]
    assert own == [(d.delivered, d.time) for d in _send(_link(simulation_seed=99, seed=7, **settings_), 500)]
    assert own != first


def test_each_pair_meets_the_same_draws_whatever_the_interleaving():
    """The in-process harness calls every pair in one object; companion j calls only (*, j) in its own:
    the k-th share of a pair must meet the same fate in both."""
    pairs = list(itertools.permutations((1, 2, 3), 2))
    rounds = [pair for _ in range(200) for pair in pairs]
    together = _decisions(_link(simulation_seed=4, loss_probability=0.4, jitter_s=0.1), rounds)
    shuffled = list(rounds)
    np.random.default_rng(0).shuffle(shuffled)
    assert _decisions(_link(simulation_seed=4, loss_probability=0.4, jitter_s=0.1), shuffled) == together
    for receiver in (1, 2, 3):   # one object per receiving companion, only its pairs
        alone = _decisions(_link(simulation_seed=4, loss_probability=0.4, jitter_s=0.1),
                           [pair for pair in rounds if pair[1] == receiver])
        assert alone == {pair: fate for pair, fate in together.items() if pair[1] == receiver}


def test_other_faults_do_not_change_which_shares_are_lost():
    """Every call draws the same values whatever happens, so adding a blackout leaves the loss pattern
    outside it as it was."""
    plain = _send(_link(simulation_seed=8, loss_probability=0.5), 400)
    blacked = _send(_link(simulation_seed=8, loss_probability=0.5, blackouts=[{"pursuer": 2, "start": 20.0, "end": 40.0}]), 400)
    outside = [k for k in range(400) if not 20.0 <= k * 0.2 < 40.0]
    assert [plain[k].delivered for k in outside] == [blacked[k].delivered for k in outside]
    assert all(blacked[k].reason == "blackout" for k in range(400) if 20.0 <= k * 0.2 < 40.0)


def test_a_callers_mistake_is_a_value_error_and_not_counted():
    link = _link(pursuers=3)
    for args in ((0.0, 1, 1), (0.0, 0, 2), (0.0, 1, 4), (0.0, True, 2), (math.nan, 1, 2), (math.inf, 1, 2)):
        with pytest.raises(ValueError):
            link.transmit(*args, *NEAR)
    with pytest.raises(ValueError, match="finite"):
        link.transmit(0.0, 1, 2, np.array([0.0, math.nan, 0.0]), np.zeros(3))
    assert link.counters["offered"] == 0
    with pytest.raises(ValueError, match="pursuers are 1..2"):
        _link(pursuers=2, blackouts=[{"pursuer": 3, "start": 0.0, "end": 1.0}])
    with pytest.raises(ValueError, match="pursuers must be"):
        _link(pursuers=0)


def test_built_from_a_scenario():
    scenario, _ = load_scenario(SCENARIOS_DIR / "seed002_circumnavigation.toml")
    link = NeighbourLink.from_scenario(scenario)
    assert link.pursuers == 5 and link.config.radius == 100.0
    far = link.transmit(0.0, 1, 5, np.zeros(3), np.array([0.0, 100.5, 0.0]))
    assert far.reason == "out_of_radius"
    with pytest.raises(ValueError, match="no \\[swarm\\]"):
        NeighbourLink.from_scenario(load_scenario(SCENARIOS_DIR / "constant_velocity.toml")[0])
