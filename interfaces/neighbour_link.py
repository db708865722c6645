"""Faults of the pursuer <-> pursuer share link ([swarm.link]), on the simulated clock.

Several pursuers share their bearings and state (``bof.pursuer_share/1``, interfaces.link_schema).
`NeighbourLink` decides, for one share going from one pursuer to another, whether it arrives and when.
It keeps no clock and does no I/O (every call says what time it is), so the in-process harness calls it
for every (sender, receiver) pair it simulates and a networked companion calls it on receipt of each
neighbour's share, with the same decisions:

    link = NeighbourLink(scenario.swarm.link, pursuers=scenario.swarm.count, simulation_seed=scenario.simulation.seed)
    delivery = link.transmit(now, sender, receiver, sender_position, receiver_position)
    if delivery.delivered:
        deliver_at(delivery.time, share)          # the harness queues it; a companion holds it until then
    link.counters                                 # Counter: offered, delivered, blackout, out_of_radius, loss

A companion calls it on receipt with the share's own stamp as the time (counted from the companion's own start of
following, which is scenario time 0 for the in-process pursuers), the share's position as the
sender's and its own latest position as the receiver's, and uses the share once its clock reaches the
delivery time (the real network's delay comes on top). `NeighbourLink.from_scenario` builds it from a
scenario's [swarm].

Times are scenario seconds (s since the scenario started), as [faults] blackouts are; positions are
NED m, shape (3,). What happens to one share, in this order (the first reason that applies is counted):

1. **blackout**: the sender or the receiver is inside one of its windows [start, end): dropped.
2. **out_of_radius**: the 3-D distance between the two positions exceeds ``radius``: dropped (a share
   reaches every pursuer within ``radius``, the seed 002 neighbour set ||p_j - p_i|| <= rho).
3. **loss**: dropped with probability ``loss_probability``, independently per share and receiver.
4. otherwise **delivered** at time + latency_s + U(0, jitter_s) (never earlier than latency_s, never
   later than latency_s + jitter_s).

Randomness: each ordered pair (sender, receiver) has its own generator, from
``SeedSequence(seed, spawn_key=(sender, receiver))`` with [swarm.link] seed, or
``SeedSequence(simulation_seed, spawn_key=(NEIGHBOUR_SPAWN_KEY, sender, receiver))`` when it has none (a
stream no other draw of the simulators uses). Every call draws exactly two uniforms from its pair's
generator (loss, jitter) whatever happens to the share. So the k-th share from i to j meets the same
draws however the calls of other pairs interleave with it, and whichever process makes them: the
in-process harness (all pairs in one object) and N companions (pairs (*, j) in companion j's object)
decide the same. Same config, same seed, same calls per pair: same decisions.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from interfaces.scenario import Scenario, SwarmLinkConfig

#: Derived link seeds: SeedSequence(simulation seed, spawn_key=(NEIGHBOUR_SPAWN_KEY, sender, receiver)).
NEIGHBOUR_SPAWN_KEY = 0x5A4E
#: Why a share was dropped, in the order they are checked.
DROP_REASONS = ("blackout", "out_of_radius", "loss")


@dataclass(frozen=True)
class Delivery:
    """What became of one share: delivered (bool); time, s (scenario time it arrives, None if dropped);
    reason: None if delivered, else one of DROP_REASONS; distance: m, between sender and receiver."""

    delivered: bool
    time: float | None
    reason: str | None
    distance: float


class NeighbourLink:
    """The [swarm.link] fault model for pursuers 1..`pursuers` (module docstring).

    config: the validated [swarm.link]. simulation_seed: [simulation] seed, used when config.seed is None.
    counters: Counter of "offered", "delivered" and each of DROP_REASONS (all pairs together);
    pair_counters[(sender, receiver)]: the same per ordered pair.
    """

    def __init__(self, config: SwarmLinkConfig, pursuers: int, simulation_seed: int = 0) -> None:
        if isinstance(pursuers, bool) or not isinstance(pursuers, int) or pursuers < 1:
            raise ValueError(f"pursuers must be an integer >= 1, got {pursuers!r}")
        for window in config.blackouts:
            if window.pursuer > pursuers:
                raise ValueError(f"blackout of pursuer {window.pursuer}, but pursuers are 1..{pursuers}")
        self.config = config
        self.pursuers = pursuers
        self._seed = simulation_seed
        self._windows = {ident: [(w.start, w.end) for w in config.blackouts if w.pursuer == ident]
                         for ident in range(1, pursuers + 1)}
        self._generators: dict[tuple[int, int], np.random.Generator] = {}
        self.counters: Counter = Counter()
        self.pair_counters: dict[tuple[int, int], Counter] = {}

    @classmethod
    def from_scenario(cls, scenario: "Scenario") -> "NeighbourLink":
        """The link of `scenario`'s [swarm.link] for its N pursuers; ValueError if it has no [swarm]."""
        if scenario.swarm is None:
            raise ValueError(f"scenario {scenario.name!r} has no [swarm]: one pursuer, no share link")
        return cls(scenario.swarm.link, scenario.swarm.count, scenario.simulation.seed)

    def generator(self, sender: int, receiver: int) -> np.random.Generator:
        """The pair's own generator (created on first use; module docstring, Randomness)."""
        pair = (sender, receiver)
        if pair not in self._generators:
            if self.config.seed is not None:
                sequence = np.random.SeedSequence(self.config.seed, spawn_key=pair)
            else:
                sequence = np.random.SeedSequence(self._seed, spawn_key=(NEIGHBOUR_SPAWN_KEY, *pair))
            self._generators[pair] = np.random.default_rng(sequence)
        return self._generators[pair]

    def blacked_out(self, pursuer: int, time: float) -> bool:
        """Whether `pursuer` is inside one of its blackout windows at `time` (s, scenario time)."""
        return any(start <= time < end for start, end in self._windows[pursuer])

    def transmit(self, time: float, sender: int, receiver: int, sender_position: np.ndarray,
                 receiver_position: np.ndarray) -> Delivery:
        """Decide one share from `sender` to `receiver` sent at `time` (s, scenario time), both positions
        NED m shape (3,) at that time. ValueError for an id outside 1..pursuers, sender == receiver, or a
        non-finite time or position (a caller's error: nothing is drawn or counted then)."""
        for name, ident in (("sender", sender), ("receiver", receiver)):
            if isinstance(ident, bool) or not isinstance(ident, (int, np.integer)) or not 1 <= ident <= self.pursuers:
                raise ValueError(f"{name} {ident!r}: pursuer ids are 1..{self.pursuers}")
        if sender == receiver:
            raise ValueError(f"a pursuer does not send to itself (sender = receiver = {sender})")
        if not math.isfinite(time):
            raise ValueError(f"time must be finite, got {time!r}")
        here, there = (np.asarray(p, dtype=float).reshape(3) for p in (sender_position, receiver_position))
        if not (np.all(np.isfinite(here)) and np.all(np.isfinite(there))):
            raise ValueError("positions must be finite")
        pair = (int(sender), int(receiver))
        loss_draw, jitter_draw = self.generator(*pair).random(2)  # always both: module docstring, Randomness
        distance = float(np.linalg.norm(here - there))
        if self.blacked_out(pair[0], time) or self.blacked_out(pair[1], time):
            reason = "blackout"
        elif distance > self.config.radius:
            reason = "out_of_radius"
        elif loss_draw < self.config.loss_probability:
            reason = "loss"
        else:
            reason = None
        counters = self.pair_counters.setdefault(pair, Counter())
        for counter in (self.counters, counters):
            counter["offered"] += 1
            counter[reason or "delivered"] += 1
        if reason is not None:
            return Delivery(False, None, reason, distance)
        return Delivery(True, float(time + self.config.latency_s + jitter_draw * self.config.jitter_s), None, distance)
