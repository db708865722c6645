"""Link-fault injection (sitl_plant.world.link_faults) on synthetic 5 Hz fix streams, its config, and sitl-target with faults."""

from __future__ import annotations

import functools
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from interfaces.scenario import CORRUPT_KINDS, SCENARIOS_DIR, VEHICLES_DIR, ConfigError, FaultsConfig, load_scenario
from interfaces.link_schema import ClockTick, PayloadError, TargetFix, decode_target_fix, encode_clock, encode_target_fix, fix_to_ned
from interfaces.geodesy import ned_to_geodetic
from sitl_plant.world.link_faults import CORRUPTION_REASONS, LinkFaults, corrupt_payload, fault_rng, override_faults
from studies.processes import ChildProcess
from sitl_plant.world.target_publisher import FaultLog, FixSchedule, TargetLog, TargetPublisher, TargetTruth

RATE = 5.0  # Hz, the flight experiment's fix rate
HOME = (47.397742, 8.545594, 488.0)


def _position(seq: int) -> np.ndarray:
    return np.array([10.0 + 0.6 * seq, 5.0 + 0.8 * seq, -20.0])


@functools.cache
def _fix(seq: int, frame: str = "ned") -> bytes:
    position = _position(seq) if frame == "ned" else ned_to_geodetic(_position(seq), HOME)
    return encode_target_fix(TargetFix("target-1", seq, seq / RATE, frame, position, (3.0, 4.0, 0.0), EPOCH))


EPOCH = 424242  # the genuine publisher's epoch in these streams


def _faults(seed: int = 7, **settings) -> LinkFaults:
    return LinkFaults(FaultsConfig(**settings), np.random.default_rng(seed))


def _run(faults: LinkFaults, count: int, frame: str = "ned", scenario_offset: float = 0.0,
         tick: float | None = None) -> list[tuple[float, bytes]]:
    """Offer `count` fixes at 5 Hz (scenario time = time - scenario_offset) and collect (delivery tick s, payload).

    tick: call due() every `tick` s (default: only at each offer), then once well after the end.
    """
    delivered, next_tick = [], 0.0
    for seq in range(count):
        now = seq / RATE
        if tick is not None:
            while next_tick < now - 1e-12:
                delivered += [(next_tick, payload) for payload in faults.due(next_tick)]
                next_tick = round(next_tick + tick, 9)
        faults.offer(now, _fix(seq, frame), now - scenario_offset)
        delivered += [(now, payload) for payload in faults.due(now)]
    end = count / RATE + 20.0
    if tick is not None:
        while next_tick <= end:
            delivered += [(next_tick, payload) for payload in faults.due(next_tick)]
            next_tick = round(next_tick + tick, 9)
    delivered += [(end, payload) for payload in faults.due(end)]
    return delivered


def _seqs(delivered: list[tuple[float, bytes]], sender: str = "target-1") -> list[int]:
    fixes = (decode_target_fix(payload) for _, payload in delivered)
    return [fix.seq for fix in fixes if fix.sender == sender]


def _event_seqs(faults: LinkFaults, kind: str) -> list[int]:
    return [event.fields["seq"] for event in faults.events if event.kind == kind]


# --- pass-through, loss ---------------------------------------------------------------

def test_disabled_config_passes_everything_through_unchanged_at_once():
    faults = _faults()
    assert not faults.enabled
    for seq in range(20):
        payload = _fix(seq)
        faults.offer(seq / RATE, payload, seq / RATE)
        assert faults.due(seq / RATE) == [payload]
    assert faults.events == [] and not faults.counters and faults.pending == 0
    # [faults.mavlink] is not this link's business.
    assert not LinkFaults(FaultsConfig.model_validate({"mavlink": {"blackouts": [{"start": 1, "duration": 2}]}}),
                          np.random.default_rng(0)).enabled


def test_independent_loss_rate_matches_p_and_every_loss_is_logged():
    count, p = 5000, 0.3
    faults = _faults(loss_probability=p)
    assert faults.enabled
    delivered = _seqs(_run(faults, count))
    lost = sorted(set(range(count)) - set(delivered))
    assert abs(len(lost) - p * count) < 4 * math.sqrt(count * p * (1 - p))
    assert _event_seqs(faults, "loss") == lost
    assert delivered == sorted(delivered) and faults.counters["loss"] == len(lost)
    assert all(event.time == seq / RATE for event, seq in zip(faults.events, lost))


@pytest.mark.parametrize("burst", [{"mean_burst_s": 2.0, "mean_gap_s": 10.0},
                                   {"p_good_to_bad": 0.02, "p_bad_to_good": 0.1}], ids=["seconds", "probabilities"])
def test_gilbert_elliott_mean_burst_length(burst):
    count = 20000  # 4000 s at 5 Hz: about 330 bursts
    faults = _faults(burst=burst)
    delivered = _seqs(_run(faults, count))
    lost = np.zeros(count, dtype=bool)
    lost[_event_seqs(faults, "burst_loss")] = True
    edges = np.diff(np.concatenate(([0], lost.astype(int), [0])))
    bursts = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)  # lengths of the runs of lost fixes
    gaps = np.flatnonzero(edges == 1)[1:] - np.flatnonzero(edges == -1)[:-1]
    assert len(bursts) > 200
    # Mean burst 2 s = 10 fixes at 5 Hz, mean gap 10 s = 50 fixes; geometric, std ~ mean.
    assert abs(bursts.mean() - 10.0) < 4 * bursts.std() / math.sqrt(len(bursts))
    assert abs(gaps.mean() - 50.0) < 4 * gaps.std() / math.sqrt(len(gaps))
    assert delivered == list(np.flatnonzero(~lost))


def test_burst_loss_in_good_and_bad_states():
    faults = _faults(burst={"p_good_to_bad": 0.0, "p_bad_to_good": 0.0, "loss_in_good": 0.5})
    delivered = _seqs(_run(faults, 2000))
    assert abs(len(delivered) - 1000) < 4 * math.sqrt(500)
    assert all(event.fields["state"] == "good" for event in faults.events)


# --- blackouts ------------------------------------------------------------------------

def test_blackout_drops_exactly_the_fixes_in_its_scenario_time_window_and_logs_start_and_end():
    # Scenario time runs 1 s behind simulated time: the window [3, 5) s is simulated [4, 6) s.
    faults = _faults(blackouts=[{"start": 3.0, "duration": 2.0}, {"start": 8.0, "duration": 0.1}])
    delivered = _seqs(_run(faults, 60, scenario_offset=1.0))
    assert sorted(set(range(60)) - set(delivered)) == list(range(20, 30)) + [45]
    starts_ends = [(event.kind, event.time) for event in faults.events]
    assert starts_ends == [("blackout_start", 4.0), ("blackout_end", 6.0), ("blackout_start", 9.0),
                           ("blackout_end", 9.2)]
    assert faults.events[1].fields == {"window_start": 3.0, "window_end": 5.0, "dropped": 10}
    assert faults.counters["blackout_drop"] == 11


def test_blackout_end_is_noticed_by_due_and_negative_scenario_time_is_outside_every_window():
    faults = _faults(blackouts=[{"start": 0.0, "duration": 1.0}])
    faults.offer(0.0, _fix(0), -math.inf)  # waiting for the start command
    faults.offer(0.2, _fix(1), -0.3)
    assert len(faults.due(0.2)) == 2 and faults.events == []
    faults.offer(0.6, _fix(3), 0.1)  # the scenario started at 0.5 s
    assert faults.due(0.6) == [] and [e.kind for e in faults.events] == ["blackout_start"]
    assert faults.due(1.4) == [] and len(faults.events) == 1
    faults.due(1.5)  # no fix offered since: due() notices the end
    assert [(e.kind, e.time) for e in faults.events] == [("blackout_start", 0.6), ("blackout_end", 1.5)]


# --- stalls ---------------------------------------------------------------------------

def test_a_stall_holds_its_window_and_delivers_it_back_to_back_at_its_end_with_the_original_stamps():
    # Scenario time 1 s behind simulated time: the window [3, 5) s is simulated [4, 6) s; 10 fixes at 5 Hz.
    faults = _faults(stalls=[{"start": 3.0, "duration": 2.0}], latency_s=0.05)
    delivered = _run(faults, 60, scenario_offset=1.0, tick=0.01)
    assert _seqs(delivered) == list(range(60))  # nothing lost, order kept
    held = [(time, decode_target_fix(payload)) for time, payload in delivered if 20 <= decode_target_fix(payload).seq < 30]
    # All ten arrive on the first tick at or after the window's end (simulated 6 s; the latency still applies to the
    # last ones, whose delay would end later), each with its own stamp, so their ages run from 2 s down to ~0.
    assert all(abs(time - 6.0) < 0.01 + 1e-9 or abs(time - (fix.stamp + 0.05)) < 0.01 + 1e-9 for time, fix in held)
    assert max(time for time, _ in held) <= 6.06
    assert [fix.stamp for _, fix in held] == [seq / RATE for seq in range(20, 30)]
    ages = [time - fix.stamp for time, fix in held]
    assert ages[0] == pytest.approx(2.0, abs=0.011) and ages == sorted(ages, reverse=True)
    outside = [time - decode_target_fix(payload).stamp for time, payload in delivered
               if not 20 <= decode_target_fix(payload).seq < 30]
    assert max(outside) < 0.05 + 0.01 + 1e-9  # only the latency elsewhere
    assert [(event.kind, event.fields) for event in faults.events if event.kind == "stall"] == [
        ("stall", {"window_start": 3.0, "window_end": 5.0})]


def test_stalls_change_no_other_faults_draws_and_overlapping_windows_are_refused():
    alone = _faults(loss_probability=0.3)
    stalled = _faults(loss_probability=0.3, stalls=[{"start": 2.0, "duration": 3.0}])
    _run(alone, 100), _run(stalled, 100)
    assert _event_seqs(alone, "loss") == _event_seqs(stalled, "loss")
    with pytest.raises(ValueError, match="stalls"):
        FaultsConfig(stalls=[{"start": 1.0, "duration": 2.0}, {"start": 2.0, "duration": 1.0}])


# --- delays, order, copies ------------------------------------------------------------

def test_latency_with_uniform_jitter():
    latency, jitter, count = 0.1, 0.05, 200
    faults = _faults(latency_s=latency, jitter_s=jitter)
    delivered = _run(faults, count, tick=0.001)
    delays = np.array([time - decode_target_fix(payload).stamp for time, payload in delivered])
    assert len(delays) == count and _seqs(delivered) == list(range(count))  # jitter < period: order kept
    assert delays.min() >= latency - 1e-9 and delays.max() <= latency + jitter + 0.001 + 1e-9
    assert abs(delays.mean() - (latency + jitter / 2 + 0.0005)) < 4 * jitter / math.sqrt(12 * count) + 0.0005
    assert faults.counters["delay"] == count


def test_reordering_lets_the_next_fix_overtake():
    faults = _faults(reorder_probability=0.2)
    seqs = _seqs(_run(faults, 500))
    held = _event_seqs(faults, "reorder")
    assert 50 < len(held) < 150 and sorted(seqs) == list(range(500))
    for seq in held:
        if seq + 1 < 500 and seq + 1 not in held:
            assert seqs.index(seq + 1) < seqs.index(seq)
    assert any(later < earlier for earlier, later in zip(seqs, seqs[1:]))


def test_duplicates_come_slightly_later():
    faults = _faults(duplicate_probability=0.2, duplicate_delay_s=0.01)
    delivered = _run(faults, 300, tick=0.01)
    seqs = _seqs(delivered)
    doubled = _event_seqs(faults, "duplicate")
    assert 30 < len(doubled) < 90
    assert sorted(seqs) == sorted(list(range(300)) + doubled)
    for seq in doubled:
        first, second = (time for time, payload in delivered if decode_target_fix(payload).seq == seq)
        assert 0.0 < second - first <= 0.01 + 1e-9


def test_stale_copies_carry_older_stamps_and_seqs():
    faults = _faults(stale_probability=0.2, stale_min_age_s=1.0, stale_max_age_s=5.0)
    fixes = [decode_target_fix(payload) for _, payload in _run(faults, 300)]
    stale_count = faults.counters["stale"]
    assert len(fixes) == 300 + stale_count and stale_count > 30
    newest = -1
    for fix in fixes:
        if fix.seq > newest:
            newest = fix.seq
            continue
        age = newest / RATE - fix.stamp  # a stale copy: delivered right after fix `newest`
        assert 1.0 - 1e-9 <= age <= 5.0 + 1e-9 and fix.seq < newest
    # None in the first second: nothing old enough yet.
    assert all(event.time >= 1.0 for event in faults.events if event.kind == "stale")


# --- corruption -----------------------------------------------------------------------

@pytest.mark.parametrize("frame", ["ned", "geodetic"])
@pytest.mark.parametrize("kind", CORRUPT_KINDS)
def test_each_corruption_is_refused_by_the_decoder_with_its_reason(kind, frame):
    faults = _faults(corrupt_probability=1.0, corrupt_kinds=[kind])
    delivered = _run(faults, 60, frame=frame)
    assert len(delivered) == 60 and faults.counters["corrupt"] == 60
    for _, payload in delivered:
        with pytest.raises(PayloadError) as error:
            decode_target_fix(payload)
        assert error.value.reason == CORRUPTION_REASONS[kind], (kind, payload)
    assert [(event.fields["seq"], event.fields["corruption"]) for event in faults.events] == [
        (seq, kind) for seq in range(60)]


def test_corruption_of_arbitrary_bytes_and_a_uniform_mix():
    for kind in CORRUPT_KINDS:
        broken, detail = corrupt_payload(b"\x00not a fix", kind, np.array([0.5, 0.5]))
        with pytest.raises(PayloadError):
            decode_target_fix(broken)
    faults = _faults(corrupt_probability=0.5)
    _run(faults, 1200)
    kinds = [event.fields["corruption"] for event in faults.events]
    assert abs(len(kinds) - 600) < 4 * math.sqrt(300)
    assert {kind: kinds.count(kind) for kind in CORRUPT_KINDS} == pytest.approx(
        {kind: 100 for kind in CORRUPT_KINDS}, abs=4 * math.sqrt(100))


# --- impostor -------------------------------------------------------------------------

@pytest.mark.parametrize("frame", ["ned", "geodetic"])
def test_impostor_publishes_decodable_fixes_with_its_own_sender_and_seq(frame):
    faults = _faults(impostor_rate_hz=1.0, impostor_offset=(30.0, -5.0, 2.0),
                     blackouts=[{"start": 3.0, "duration": 3.0}])
    delivered = [decode_target_fix(payload) for _, payload in _run(faults, 50, frame=frame)]
    impostors = [fix for fix in delivered if fix.sender == "impostor-1"]
    # It goes on talking after the last fix (due() is called until 30 s): look at the first 10 s.
    impostors = [fix for fix in impostors if fix.stamp < 10.0]
    assert [fix.seq for fix in impostors] == list(range(10)) and [fix.stamp for fix in impostors] == list(range(10))
    for fix in impostors:  # the tick's own fix was offered just before: moved by the offset
        true = _position(round(fix.stamp * RATE))
        reference = true if frame == "ned" else ned_to_geodetic(true, HOME)
        moved = fix_to_ned(fix, reference) if frame == "geodetic" else np.array(fix.position) - true
        assert np.allclose(moved, (30.0, -5.0, 2.0), atol=1e-6)
    assert [e.kind for e in faults.events if e.time < 10.0].count("impostor") == 10  # blackouts do not silence it
    assert len([fix for fix in delivered if fix.sender == "target-1"]) == 50 - 15


# --- determinism and randomness -------------------------------------------------------

EVERYTHING = dict(loss_probability=0.1, burst={"mean_burst_s": 1.0, "mean_gap_s": 8.0},
                  blackouts=[{"start": 5.0, "duration": 2.0}], latency_s=0.05, jitter_s=0.3, reorder_probability=0.1,
                  duplicate_probability=0.1, stale_probability=0.1, corrupt_probability=0.1, impostor_rate_hz=0.5)


def test_same_seed_gives_identical_bytes_and_events():
    first, second, other = _faults(3, **EVERYTHING), _faults(3, **EVERYTHING), _faults(4, **EVERYTHING)
    output = _run(first, 400, tick=0.02)
    assert output == _run(second, 400, tick=0.02) and first.events == second.events
    assert output != _run(other, 400, tick=0.02)
    assert set(first.counters) >= {"loss", "burst_loss", "blackout_start", "blackout_end", "blackout_drop", "delay",
                                   "reorder", "duplicate", "stale", "corrupt", "impostor"}


def test_enabling_one_fault_leaves_the_draws_of_the_others_alone():
    alone = _faults(5, loss_probability=0.2)
    _run(alone, 1000)
    crowded = _faults(5, **{**EVERYTHING, "loss_probability": 0.2})
    _run(crowded, 1000)
    outside_blackout = [seq for seq in _event_seqs(alone, "loss") if not 25 <= seq < 35]  # [5, 7) s drops first
    assert _event_seqs(crowded, "loss") == outside_blackout
    with_copies = _faults(5, loss_probability=0.2, duplicate_probability=0.5)
    _run(with_copies, 1000)
    assert _event_seqs(with_copies, "loss") == _event_seqs(alone, "loss")


def test_fault_rng_uses_the_faults_seed_or_a_stream_of_its_own():
    derived = fault_rng(FaultsConfig(), 1).random(4)
    assert np.array_equal(derived, fault_rng(FaultsConfig(), 1).random(4))
    assert not np.array_equal(derived, np.random.default_rng(1).random(4))
    assert not np.array_equal(derived, fault_rng(FaultsConfig(), 2).random(4))
    assert np.array_equal(fault_rng(FaultsConfig(seed=9), 1).random(4), np.random.default_rng(9).random(4))


def test_restart_discards_what_is_in_flight():
    faults = _faults(latency_s=1.0, blackouts=[{"start": 0.5, "duration": 1.0}])
    for seq in range(2):
        faults.offer(seq / RATE, _fix(seq), seq / RATE)
    assert faults.pending == 2
    faults.restart(0.0)
    assert faults.pending == 0 and faults.events[-1].kind == "restart" and faults.events[-1].fields == {"discarded": 2}


# --- configuration --------------------------------------------------------------------

def test_dropout_scenario_has_a_5_s_blackout_at_30_s():
    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity_dropout.toml")
    assert [(w.start, w.duration) for w in scenario.faults.blackouts] == [(30.0, 5.0)]
    assert scenario.faults.loss_probability == 0.0 and scenario.faults.seed is None
    assert load_scenario(SCENARIOS_DIR / "constant_velocity.toml")[0].faults == FaultsConfig()


def _scenario_with(tmp_path: Path, faults_toml: str) -> Path:
    text = (SCENARIOS_DIR / "constant_velocity.toml").read_text()
    text = text.replace('vehicle = "../vehicles/paper_table1.toml"',
                        f'vehicle = "{VEHICLES_DIR / "paper_table1.toml"}"')
    path = tmp_path / "case.toml"
    path.write_text(text + "\n[faults]\n" + faults_toml + "\n")
    return path


@pytest.mark.parametrize("faults_toml, key", [
    ("loss_probability = 1.5", "faults.loss_probability"),
    ("duplicate_probability = -0.1", "faults.duplicate_probability"),
    ("latency_s = -1", "faults.latency_s"),
    ("jitter_s = nan", "faults.jitter_s"),
    ("blackouts = [{ start = 10, duration = -1 }]", "faults.blackouts.0.duration"),
    ("blackouts = [{ start = 10, duration = 5 }, { start = 12, duration = 1 }]", "blackouts: windows"),
    ("blackouts = [{ start = 10 }]", "faults.blackouts.0.duration"),
    ("burst = { mean_burst_s = 2.0 }", "burst: give"),
    ("burst = { p_good_to_bad = 0.1, p_bad_to_good = 2 }", "faults.burst.p_bad_to_good"),
    ("corrupt_kinds = ['bit_flip']", "faults.corrupt_kinds.0"),
    ("corrupt_kinds = []", "faults.corrupt_kinds"),
    ("stale_min_age_s = 6.0", "stale_min_age_s (6.0) must not exceed stale_max_age_s"),
    ("impostor_sender = 'a/b'", "faults.impostor_sender"),
    ("impostor_offset = [1, 2]", "faults.impostor_offset"),
    ("seed = -1", "faults.seed"),
    ("mavlink = { blackouts = [{ start = 1, duration = 5 }, { start = 2, duration = 1 }] }", "mavlink.blackouts: windows"),
    ("los_probability = 0.1", "faults.los_probability: unknown key"),
    ("future_seq_at = -1", "faults.future_seq_at"),
    ("future_stamp_at = nan", "faults.future_stamp_at"),
    ("replay_count = 0", "faults.replay_count"),
    ("restart_gap_s = -0.5", "faults.restart_gap_s"),
    ("spoof_burst_count = 0", "faults.spoof_burst_count"),
    ("spoof_rate_hz = -5", "faults.spoof_rate_hz"),
    ("spoof_offset = [1, 2, inf]", "faults.spoof_offset"),
    ("spoof_seq_lead = -1", "faults.spoof_seq_lead"),
    ("spoof_epoch = 'mine'", "faults.spoof_epoch"),
])
def test_bad_faults_are_rejected_naming_the_key(tmp_path, faults_toml, key):
    path = _scenario_with(tmp_path, faults_toml)
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    assert key in str(error.value) and str(path) in str(error.value)


def test_command_line_overrides():
    base = FaultsConfig(loss_probability=0.1, blackouts=[{"start": 30.0, "duration": 5.0}])
    config = override_faults(base, ["loss_probability=0.3", "blackouts=[{start=20,duration=5}]",
                                    "burst.mean_burst_s=2", "burst.mean_gap_s=20", "mavlink.blackouts=[{start=1,duration=2}]",
                                    "corrupt_kinds=['non_finite']", "seed=4"])
    assert config.loss_probability == 0.3 and [(w.start, w.duration) for w in config.blackouts] == [(20.0, 5.0)]
    assert (config.burst.mean_burst_s, config.burst.mean_gap_s) == (2.0, 20.0) and config.seed == 4
    assert config.mavlink.blackouts[0].duration == 2.0 and config.corrupt_kinds == ("non_finite",)
    replaced = override_faults(config, ["burst={p_good_to_bad=0.1,p_bad_to_good=0.5}"])
    assert replaced.burst.mean_burst_s is None and replaced.burst.p_bad_to_good == 0.5


@pytest.mark.parametrize("assignment, message", [
    ("loss_probability", "expected KEY=VALUE"),
    ("loss_probability=abc", "loss_probability: 'abc' is not a TOML value"),
    ("loss_probability=2", "faults.loss_probability"),
    ("lossprobability=0.1", "faults.lossprobability: unknown key"),
    ("loss_probability.x=1", "faults.loss_probability is not a table"),
    ("burst.mean_burst_s=2", "burst: give"),
])
def test_bad_command_line_overrides_name_the_key(assignment, message):
    with pytest.raises(ConfigError, match="^--fault") as error:
        override_faults(FaultsConfig(), [assignment])
    assert message in str(error.value)


def test_sitl_target_refuses_a_bad_fault_override(capsys):
    from sitl_plant.world import target_publisher as target_sim

    assert target_sim.main(["--fault", "loss_probability=2"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("sitl-target: --fault") and "loss_probability" in error


# --- sitl-target ----------------------------------------------------------------------

def test_target_publisher_applies_the_dropout_scenario_on_the_clock(tmp_path):
    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity_dropout.toml")
    sent: list[bytes] = []
    fault_log = FaultLog(tmp_path)
    target = TargetPublisher(TargetTruth(scenario.target), FixSchedule(RATE), sent.append, TargetLog(None, "ned"),
                             "target-1", "ned", HOME, 0.0, rng=np.random.default_rng(0), duration=40.0,
                             faults=LinkFaults(scenario.faults, fault_rng(scenario.faults, 1)), fault_log=fault_log)
    for seq in range(2001):
        target.on_clock_payload(encode_clock(ClockTick("plant", seq, seq * 0.02)))
    fault_log.close()
    stamps = [decode_target_fix(payload).stamp for payload in sent]
    assert target.finished and len(stamps) == 201 - 25
    assert max(stamp for stamp in stamps if stamp < 32) == pytest.approx(29.8) and 35.0 in stamps
    lines = [json.loads(line) for line in (tmp_path / "faults.jsonl").read_text().splitlines()]
    assert [(line["kind"], line["time"]) for line in lines] == [("blackout_start", 30.0), ("blackout_end", 35.0)]
    assert lines[1]["dropped"] == 25 and (lines[1]["window_start"], lines[1]["window_end"]) == (30.0, 35.0)


def test_target_process_with_a_blackout_loss_and_an_impostor_end_to_end(tmp_path, clock_and_fixes):
    link = clock_and_fixes("target-1")
    child = None
    try:
        command = [sys.executable, "-m", "sitl_plant.world.target_publisher", "--config", str(SCENARIOS_DIR / "constant_velocity.toml"),
                   "--zenoh-connect", link.endpoint, "--frame", "ned", "--log-dir", str(tmp_path / "logs"),
                   "--fault", "blackouts=[{start=6,duration=2}]", "--fault", "loss_probability=0.2",
                   "--fault", "impostor_rate_hz=1", "--fault", "seed=3"]
        child = ChildProcess(command, tmp_path / "target.out", ready="sitl-target ready").start(timeout=20.0)
        # 0.1 s of simulated time every 0.01 wall s; stop once a fix of t >= 10 s came through.
        link.run_clock(until_sim=14.0, step=0.1, period=0.01, timeout=10.0,
                       done=lambda: any(fix.stamp >= 10.0 and fix.sender == "target-1" for fix in link.received()))
        exit_code = child.stop()
        output = child.output()
    finally:
        if child is not None:
            child.stop()
        link.close()
    assert exit_code == 0, output
    ready = next(line for line in output.splitlines() if line.startswith("sitl-target ready"))
    assert "faults: " in ready and "loss_probability=0.2" in ready, output
    fixes = [fix for fix in link.received() if fix.sender == "target-1"]
    impostors = [fix for fix in link.received() if fix.sender == "impostor-1"]
    assert fixes[-1].stamp >= 10.0 and not any(6.0 - 1e-9 <= fix.stamp < 8.0 - 1e-9 for fix in fixes)

    events = [json.loads(line) for line in (tmp_path / "logs" / "faults.jsonl").read_text().splitlines()]
    kinds = [(event["kind"], event["time"]) for event in events if event["kind"].startswith("blackout")]
    assert kinds == [("blackout_start", 6.0), ("blackout_end", 8.0)]
    lost = {event["seq"] for event in events if event["kind"] == "loss"}
    produced = [line.split(",") for line in (tmp_path / "logs" / "target.csv").read_text().splitlines()[1:]]
    in_window = {int(row[0]) for row in produced if 6.0 - 1e-9 <= float(row[1]) < 8.0 - 1e-9}
    last = fixes[-1].seq
    expected = {int(row[0]) for row in produced} - lost - in_window
    assert [fix.seq for fix in fixes] == sorted(seq for seq in expected if seq <= last)
    assert lost and len(in_window) == 10

    assert impostors and [fix.seq for fix in impostors] == list(range(len(impostors)))
    by_stamp = {fix.stamp: fix for fix in fixes}
    for impostor in impostors:
        if impostor.stamp in by_stamp:
            assert np.allclose(np.array(impostor.position) - by_stamp[impostor.stamp].position, (30.0, 0.0, 0.0))
    summary = next(line for line in output.splitlines() if line.startswith("sitl-target faults:"))
    assert "'blackout_drop': 10" in summary and f"'loss': {len(lost)}" in summary


# --- attacks -------------------------------------------------------------------------------

def _decoded(delivered):
    return [(time, decode_target_fix(payload)) for time, payload in delivered]


def test_future_seq_and_future_stamp_are_one_extra_copy_each_right_after_the_genuine_fix():
    faults = _faults(future_seq_at=2.0, future_stamp_at=3.0)
    fixes = _decoded(_run(faults, 30))
    genuine = [fix for _, fix in fixes if fix.seq < 30 and fix.stamp < 100]
    assert [fix.seq for fix in genuine] == list(range(30))
    forged = [(time, fix) for time, fix in fixes if fix.seq >= 30 or fix.stamp >= 100]
    assert len(forged) == 2
    (t1, seq_copy), (t2, stamp_copy) = forged
    assert t1 == 2.0 and seq_copy.seq == 10 + 2**62 and seq_copy.stamp == pytest.approx(2.01) and seq_copy.epoch == EPOCH
    assert t2 == 3.0 and stamp_copy.seq == 16 and stamp_copy.stamp == 3.0 + 1e6
    np.testing.assert_array_equal(seq_copy.position, _position(10))
    assert faults.counters["attack_future_seq"] == 1 and faults.counters["attack_future_stamp"] == 1


def test_replay_resends_the_last_genuine_payloads_byte_for_byte():
    faults = _faults(replay_at=4.0, replay_count=5)
    delivered = _run(faults, 30)
    at_attack = [payload for time, payload in delivered if time == 4.0]
    assert at_attack == [_fix(15), _fix(16), _fix(17), _fix(18), _fix(19), _fix(20)]  # the replay, then seq 20 itself
    assert faults.counters["attack_replay"] == 5


def test_a_restarted_target_is_silent_for_the_gap_then_counts_from_zero_in_a_new_epoch():
    faults = _faults(restart_at=2.0, restart_gap_s=1.0)
    fixes = [fix for _, fix in _decoded(_run(faults, 30))]
    before = [fix for fix in fixes if fix.stamp < 2.0]
    after = [fix for fix in fixes if fix.stamp >= 2.0]
    assert all(fix.epoch == EPOCH for fix in before) and len(before) == 10
    assert after[0].stamp == pytest.approx(3.0)  # 2.0-2.8 s not sent
    assert {fix.epoch for fix in after} != {EPOCH} and len({fix.epoch for fix in after}) == 1
    assert [fix.seq for fix in after] == list(range(len(after)))
    np.testing.assert_array_equal(after[0].position, _position(15))
    assert faults.counters["restart_drop"] == 5


@pytest.mark.parametrize("epoch", ["own", "target"])
def test_a_spoof_burst_is_consistent_offset_and_seq_ahead(epoch):
    faults = _faults(spoof_burst_at=2.0, spoof_epoch=epoch)
    fixes = _decoded(_run(faults, 30))
    burst = [(time, fix) for time, fix in fixes if fix.seq >= 2**40]
    assert len(burst) == 3
    for k, (time, fix) in enumerate(burst):
        assert fix.sender == "target-1" and fix.seq == 10 + 2**40 + k
        assert fix.stamp == pytest.approx(2.0 + 0.02 * k) and time == 2.0  # back to back
        np.testing.assert_allclose(np.array(fix.position) - _position(10), (30.0, 0.0, 0.0))
        assert (fix.epoch == EPOCH) == (epoch == "target")


def test_a_steady_spoof_publishes_an_offset_track_at_its_rate_from_its_start():
    faults = _faults(spoof_rate_hz=5.0, spoof_from=2.0, spoof_offset=(0.0, -25.0, 0.0))
    fixes = _decoded(_run(faults, 30, tick=0.02))
    spoof = [fix for _, fix in fixes if fix.seq >= 2**40]
    stamps = np.array([fix.stamp for fix in spoof])  # it goes on after the target's last fix, as the clock runs
    np.testing.assert_allclose(stamps, np.arange(10, 10 + len(spoof)) / 5.0, atol=1e-9)
    assert all(b.seq > a.seq for a, b in zip(spoof, spoof[1:])) and len({fix.epoch for fix in spoof}) == 1
    by_stamp = {round(fix.stamp, 9): fix for _, fix in fixes if fix.seq < 2**40}
    for fix in spoof[:20]:
        np.testing.assert_allclose(np.array(fix.position) - by_stamp[round(fix.stamp, 9)].position, (0.0, -25.0, 0.0))


def test_each_target_publisher_process_has_its_own_epoch_and_counts_seq_from_zero():
    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    runs = []
    for _ in range(2):  # a publisher, then the same publisher restarted
        sent: list[bytes] = []
        target = TargetPublisher(TargetTruth(scenario.target), FixSchedule(RATE), sent.append, TargetLog(None, "ned"),
                                 "target-1", "ned", HOME, 0.0, rng=np.random.default_rng(0), duration=2.0)
        for seq in range(101):
            target.on_clock_payload(encode_clock(ClockTick("plant", seq, seq * 0.02)))
        fixes = [decode_target_fix(payload) for payload in sent]
        assert all(json.loads(payload)["schema"] == "bof.target_fix/2" for payload in sent)
        assert {fix.epoch for fix in fixes} == {target.epoch} and [fix.seq for fix in fixes] == list(range(len(fixes)))
        runs.append(target.epoch)
    assert runs[0] != runs[1]


def test_the_target_refuses_a_start_command_outside_its_clock_window():
    from interfaces.link_schema import Command, encode_command

    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    target = TargetPublisher(TargetTruth(scenario.target, start_time=math.inf), FixSchedule(RATE), lambda payload: None,
                             TargetLog(None, "ned"), "target-1", "ned", HOME, 0.0, rng=np.random.default_rng(0))
    target.on_clock_payload(encode_clock(ClockTick("plant", 0, 10.0)))
    target.on_command_payload(encode_command(Command("gcs", 0, 10.0 + 1e6, "start", epoch=1)))
    target.on_command_payload(encode_command(Command("gcs", 1, 7.0, "start", epoch=1)))
    assert math.isinf(target.truth.start_time)
    assert target.rejected == {"command:future_stamp": 1, "command:too_old": 1}
    target.on_command_payload(encode_command(Command("gcs", 2, 10.2, "start", epoch=1)))
    assert target.truth.start_time == 10.0
