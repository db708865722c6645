"""[faults]: link and MAVLink faults injected on the plant's side."""

from __future__ import annotations

from typing import Annotated, Literal, get_args

from pydantic import Field, model_validator

from interfaces.scenario.common import (FROM_ARRAY, Duration, NonNegativeDuration, Position, Probability, Velocity,
                                        _Strict)


SenderName = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
#: How a corrupted fix is broken (sitl_plant.world.link_faults documents each and the decoder's reason it earns).
CorruptKind = Literal["invalid_utf8", "truncated_json", "missing_field", "non_finite", "string_number",
                      "absurd_position"]
CORRUPT_KINDS: tuple[str, ...] = get_args(CorruptKind)


class BlackoutWindow(_Strict):
    """A link outage from start for duration, s (scenario time for the target link, plant time for MAVLink)."""

    start: NonNegativeDuration
    duration: NonNegativeDuration

    @property
    def end(self) -> float:
        return self.start + self.duration


def _check_windows(windows: tuple[BlackoutWindow, ...], key: str) -> None:
    ordered = sorted(windows, key=lambda w: w.start)
    for earlier, later in zip(ordered, ordered[1:]):
        if later.start < earlier.end:
            raise ValueError(f"{key}: windows [{earlier.start:g}, {earlier.end:g}) and "
                             f"[{later.start:g}, {later.end:g}) overlap")


class BurstLossConfig(_Strict):
    """Gilbert-Elliott bursty loss: a good/bad Markov chain stepped once per target fix.

    Give either the per-message transition probabilities (p_good_to_bad, p_bad_to_good)
    or the mean durations in seconds (mean_burst_s in the bad state, mean_gap_s in the
    good state; converted with the interval between consecutive fixes: p = interval /
    mean). loss_in_good / loss_in_bad: probability that a fix is lost in that state.
    """

    p_good_to_bad: Probability | None = None
    p_bad_to_good: Probability | None = None
    mean_burst_s: Duration | None = None
    mean_gap_s: Duration | None = None
    loss_in_good: Probability = 0.0
    loss_in_bad: Probability = 1.0

    @model_validator(mode="after")
    def _one_form(self) -> "BurstLossConfig":
        given = [name for name in ("p_good_to_bad", "p_bad_to_good", "mean_burst_s", "mean_gap_s")
                 if getattr(self, name) is not None]
        if given not in (["p_good_to_bad", "p_bad_to_good"], ["mean_burst_s", "mean_gap_s"]):
            raise ValueError("burst: give p_good_to_bad and p_bad_to_good, or mean_burst_s and mean_gap_s "
                             f"(got {', '.join(given) or 'neither'})")
        return self


class MavlinkFaultsConfig(_Strict):
    """Faults of the companion <-> vehicle MAVLink link (applied by the plant).

    blackouts: windows during which the link is silent both ways; start is s of simulated
    time after the vehicle first switched to Offboard (the companion took control and
    began following), so a window falls at the same point of the following whatever the
    take-off took.
    """

    blackouts: Annotated[tuple[BlackoutWindow, ...], FROM_ARRAY] = ()

    @model_validator(mode="after")
    def _no_overlap(self) -> "MavlinkFaultsConfig":
        _check_windows(self.blackouts, "mavlink.blackouts")
        return self


#: Hz: the fastest impostor or steady spoofer [faults] may inject (each of its messages is an event of the flight: an
#: unbounded rate never finishes and fills memory; 1 kHz is 200x the default bearing rate).
MAX_ATTACK_RATE_HZ = 1000.0


class FaultsConfig(_Strict):
    """Fault injection on the target -> companion link (sitl_plant.world.link_faults); defaults inject nothing.

    Times of blackouts are scenario time (s since the target started its scenario).
    loss_probability: independent loss per fix. burst: Gilbert-Elliott bursty loss
    ([faults.burst]). latency_s + U(0, jitter_s): delivery delay, s. reorder_probability:
    a fix is held back reorder_delay_s more (choose it above the fix period + jitter so
    the next fix overtakes it). duplicate_probability: a second copy duplicate_delay_s
    later. stale_probability: an extra copy of an older fix, stale_min_age_s to
    stale_max_age_s old. corrupt_probability: the fix is replaced by a broken one, kind
    drawn uniformly from corrupt_kinds. stalls: windows in which the target's publisher is frozen (a
    loaded machine, a stopped process): the fixes of the window are not lost but all delivered at its
    end, back to back, with their own stamps. impostor_rate_hz: a second publisher on the same
    key as impostor_sender, impostor_offset m (NED) away from the target (0 = off).
    seed: the faults' own seed (None: derived from simulation.seed). mavlink: faults of
    the MAVLink link ([faults.mavlink]).

    Attacks (sitl_plant.world.link_faults documents each; times are scenario s, None = off):
    future_seq_at: one extra copy of a genuine fix with seq + 2**62. future_stamp_at: one
    extra copy stamped 1e6 s ahead. replay_at: the last replay_count genuine fixes sent
    again, back to back. restart_at: the genuine publisher restarts (silent restart_gap_s,
    then a new epoch, seq from 0). spoof_burst_at: spoof_burst_count fixes as the target,
    spoof_offset m (NED) off, 20 ms apart. spoof_rate_hz (> 0: on, from spoof_from s): a
    steady spoofer as the target at that rate, spoof_offset m off the genuine track (plus spoof_drift m/s x the
    time since spoof_from). The
    spoofer's seq is the genuine one + spoof_seq_lead; its epoch is its own (spoof_epoch =
    "own") or the genuine one it overheard ("target").
    """

    seed: Annotated[int, Field(ge=0)] | None = None
    loss_probability: Probability = 0.0
    burst: BurstLossConfig | None = None
    blackouts: Annotated[tuple[BlackoutWindow, ...], FROM_ARRAY] = ()
    latency_s: NonNegativeDuration = 0.0
    jitter_s: NonNegativeDuration = 0.0
    stalls: Annotated[tuple[BlackoutWindow, ...], FROM_ARRAY] = ()
    reorder_probability: Probability = 0.0
    reorder_delay_s: Duration = 0.3
    duplicate_probability: Probability = 0.0
    duplicate_delay_s: NonNegativeDuration = 0.01
    stale_probability: Probability = 0.0
    stale_min_age_s: NonNegativeDuration = 1.0
    stale_max_age_s: Duration = 5.0
    corrupt_probability: Probability = 0.0
    corrupt_kinds: Annotated[tuple[CorruptKind, ...], FROM_ARRAY, Field(min_length=1)] = CORRUPT_KINDS
    impostor_rate_hz: Annotated[float, Field(ge=0.0, le=MAX_ATTACK_RATE_HZ)] = 0.0
    impostor_sender: SenderName = "impostor-1"
    impostor_offset: Position = (30.0, 0.0, 0.0)
    future_seq_at: NonNegativeDuration | None = None
    future_stamp_at: NonNegativeDuration | None = None
    replay_at: NonNegativeDuration | None = None
    replay_count: Annotated[int, Field(ge=1, le=10000)] = 25
    restart_at: NonNegativeDuration | None = None
    restart_gap_s: NonNegativeDuration = 1.0
    spoof_burst_at: NonNegativeDuration | None = None
    spoof_burst_count: Annotated[int, Field(ge=1, le=1000)] = 3
    spoof_rate_hz: Annotated[float, Field(ge=0.0, le=MAX_ATTACK_RATE_HZ)] = 0.0
    spoof_from: NonNegativeDuration = 0.0
    spoof_duration: Duration | None = None
    """s the steady spoofer speaks from spoof_from (None: to the end of the flight)."""
    spoof_offset: Position = (30.0, 0.0, 0.0)
    spoof_drift: Velocity = (0.0, 0.0, 0.0)
    """m/s, NED: the steady spoofer's offset grows by this much per second from spoof_from (a patient liar:
    spoof_offset 0, a slow drift, spoof_epoch "target", spoof_seq_lead 1)."""
    spoof_seq_lead: Annotated[int, Field(ge=0, le=2**62)] = 2**40
    spoof_epoch: Literal["own", "target"] = "own"
    mavlink: MavlinkFaultsConfig = MavlinkFaultsConfig()

    @model_validator(mode="after")
    def _consistent(self) -> "FaultsConfig":
        _check_windows(self.blackouts, "blackouts")
        _check_windows(self.stalls, "stalls")
        if self.stale_min_age_s > self.stale_max_age_s:
            raise ValueError(f"stale_min_age_s ({self.stale_min_age_s}) must not exceed stale_max_age_s "
                             f"({self.stale_max_age_s})")
        if len(set(self.corrupt_kinds)) != len(self.corrupt_kinds):
            raise ValueError("corrupt_kinds: each kind at most once")
        return self
