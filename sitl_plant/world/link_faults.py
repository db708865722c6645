"""Fault injection on the target -> companion link, on the simulated clock.

The paper's flight campaign lost 2 of about 30 flights to the Zigbee link dropping; `LinkFaults` reproduces such
links between the target publisher and the companion. It works on payload bytes, keeps no clock of its own
(every call says what simulated time it is) and does no I/O, so the same model serves the in-process simulator
and `sitl-target`:

    faults = LinkFaults(scenario.faults, fault_rng(scenario.faults, scenario.simulation.seed))
    faults.offer(now, encode_target_fix(fix), scenario_time)   # each fix as it is produced
    for payload in faults.due(now):                             # each clock tick
        publish(payload)

``now`` is simulated time, s (the plant's clock); ``scenario_time`` is s since the target started its scenario
(negative or -inf before: no window applies). `due` releases a message on the first call whose ``now`` reaches
its delivery time. What each fault does to one offered message, in the order `offer` applies them (blackout,
loss, bursty loss, corruption, delay and stall, reordering, duplication, stale), the impostor and the attacks
(other transmitters), the events and counters, and the randomness (one child generator per kind, `STREAMS`,
each drawing the same number of values per message whatever else is enabled) are described for users in
docs/reference/link-faults.md; a change here is a change there.
"""

from __future__ import annotations

import heapq
import json
import math
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from interfaces.overrides import apply_overrides, parse_assignment
from interfaces.scenario import FaultsConfig
import dataclasses

from interfaces.link_schema import MAX_EPOCH, MAX_SEQ, PayloadError, TargetFix, decode_target_fix, encode_target_fix
from interfaces.geodesy import ned_to_geodetic

#: One child generator per fault kind, in this order (append new kinds at the end: the others keep their draws).
STREAMS = ("loss", "burst", "corrupt", "delay", "reorder", "duplicate", "stale", "impostor", "attack")
#: The future_seq attack's seq jump, and the future_stamp attack's stamp jump (s).
FUTURE_SEQ_JUMP = 2**62
FUTURE_STAMP_JUMP = 1e6
#: Stamp spacing of a spoof burst, s.
SPOOF_BURST_SPACING = 0.02
#: The future_seq copy's stamp lead, s (newer than the genuine fix, well inside any freshness window).
FUTURE_SEQ_STAMP_LEAD = 0.01
#: Corruption kind -> the interfaces.link_schema.PayloadError reason decode_target_fix gives it.
CORRUPTION_REASONS = {
    "invalid_utf8": "not_utf8",
    "truncated_json": "not_json",
    "missing_field": "missing_field",
    "non_finite": "not_finite",
    "string_number": "wrong_type",
    "absurd_position": "out_of_range",
}
_REQUIRED_FIELDS = ("schema", "sender", "seq", "stamp", "frame", "position")
_NON_FINITE = (math.nan, math.inf, -math.inf)
#: Times closer than this (s) count as equal (clock stamps are sums of floats).
TIME_TOLERANCE = 1e-9
#: Payloads kept for stale copies at most (besides the age limit).
MAX_HISTORY = 10000
#: Derived fault seeds: SeedSequence(simulation seed, spawn_key=(FAULT_SPAWN_KEY,)), apart from every other stream.
FAULT_SPAWN_KEY = 0xFA17


@dataclass(frozen=True)
class FaultEvent:
    """One injected fault: simulated time (s) it happened, kind (e.g. "loss"), a human-readable detail, and
    its figures as fields (seq of the message affected, None if it has none; delay_s, dropped, ...)."""

    time: float
    kind: str
    detail: str
    fields: dict = field(default_factory=dict)

    def record(self) -> dict:
        """The event as one log record: {"time", "kind", "detail", **fields}."""
        return {"time": self.time, "kind": self.kind, "detail": self.detail, **self.fields}


def fault_rng(config: FaultsConfig, simulation_seed: int) -> np.random.Generator:
    """The faults' generator: config.seed if set, else a stream derived from `simulation_seed` that no other draw uses."""
    if config.seed is not None:
        return np.random.default_rng(config.seed)
    return np.random.default_rng(np.random.SeedSequence(simulation_seed, spawn_key=(FAULT_SPAWN_KEY,)))


def injects_anything(config: FaultsConfig) -> bool:
    """Whether `config` changes anything on the target link ([faults.mavlink] aside)."""
    burst = config.burst
    return bool(config.loss_probability > 0 or (burst is not None and (burst.loss_in_good > 0 or burst.loss_in_bad > 0))
                or any(window.duration > 0 for window in config.blackouts) or config.latency_s > 0
                or any(window.duration > 0 for window in config.stalls)
                or config.jitter_s > 0 or config.reorder_probability > 0 or config.duplicate_probability > 0
                or config.stale_probability > 0 or config.corrupt_probability > 0 or config.impostor_rate_hz > 0
                or attacks_anything(config))


def attacks_anything(config: FaultsConfig) -> bool:
    """Whether `config` injects an attack (module docstring, Attacks)."""
    return bool(any(at is not None for at in (config.future_seq_at, config.future_stamp_at, config.replay_at,
                                              config.restart_at, config.spoof_burst_at)) or config.spoof_rate_hz > 0)


def describe(config: FaultsConfig) -> str:
    """The settings that differ from the defaults, one line (e.g. for a ready message)."""
    changed = config.model_dump(exclude_defaults=True)
    return ", ".join(f"{key}={value}" for key, value in changed.items()) or "none"


def override_faults(config: FaultsConfig, assignments: Sequence[str]) -> FaultsConfig:
    """`config` with KEY=VALUE assignments applied (VALUE a TOML value; KEY dotted for nested tables).

    ``loss_probability=0.3``, ``blackouts=[{start=20,duration=5}]`` (replaces the list),
    ``burst.mean_burst_s=2``, ``burst={mean_burst_s=2,mean_gap_s=20}`` (replaces the
    table). ConfigError naming the key if an assignment is malformed or the result invalid
    (interfaces.overrides).
    """
    overrides = [parse_assignment(text, "--fault", example="loss_probability=0.3") for text in assignments]
    return apply_overrides(config, overrides, "--fault", root="faults")


class _SeqLabel:
    """The seq of a payload for events, parsed only if an event needs it: `value` (int or None), str "seq=N"."""

    _UNPARSED = object()

    def __init__(self, payload: bytes) -> None:
        self._payload, self._value = payload, self._UNPARSED

    @property
    def value(self) -> int | None:
        if self._value is self._UNPARSED:
            self._value = _seq_of(self._payload)
        return self._value

    def __str__(self) -> str:
        return f"seq={'?' if self.value is None else self.value}"


def _seq_of(payload: bytes) -> int | None:
    """The integer "seq" of a JSON object payload; None if it is no such object or has no integer seq."""
    try:
        document = json.loads(payload)
    except (ValueError, RecursionError):
        return None
    seq = document.get("seq") if isinstance(document, dict) else None
    return seq if isinstance(seq, int) and not isinstance(seq, bool) else None


def corrupt_payload(payload: bytes, kind: str, draws: np.ndarray) -> tuple[bytes, str]:
    """(`payload` broken as `kind` says, what was done); draws: 2 uniforms in [0, 1) choosing the details.

    See the module docstring for the kinds; JSON kinds on bytes that are no fix-like
    JSON object fall back to invalid_utf8.
    """
    broken, _, detail = _corrupt(payload, kind, draws)
    return broken, detail


def _corrupt(payload: bytes, kind: str, draws: np.ndarray) -> tuple[bytes, str, str]:
    """`corrupt_payload`, also saying which kind was applied (kind itself, or invalid_utf8 when it fell back)."""
    if kind == "invalid_utf8":
        middle = len(payload) // 2
        return payload[:middle] + b"\xff" + payload[middle:], kind, "invalid_utf8: 0xFF inserted"
    if kind == "truncated_json":
        if len(payload) < 2:
            return b"\xff", "invalid_utf8", "invalid_utf8 (too short to truncate)"
        cut = 1 + int(draws[0] * (len(payload) - 1))
        return payload[:cut], kind, f"truncated_json: {cut} of {len(payload)} bytes"
    try:
        document = json.loads(payload)
    except (ValueError, RecursionError):
        document = None
    position = document.get("position") if isinstance(document, dict) else None
    if not (isinstance(position, list) and len(position) == 3):
        broken, _ = corrupt_payload(payload, "invalid_utf8", draws)
        return broken, "invalid_utf8", f"invalid_utf8 (instead of {kind}: not a fix-like JSON object)"
    if kind == "missing_field":
        name = _REQUIRED_FIELDS[int(draws[0] * len(_REQUIRED_FIELDS))]
        document.pop(name, None)
        detail = f"missing_field: {name} removed"
    elif kind == "non_finite":
        axis, value = int(draws[0] * 3), _NON_FINITE[int(draws[1] * len(_NON_FINITE))]
        position[axis] = value
        detail = f"non_finite: position[{axis}] = {value}"
    elif kind == "string_number":
        axis = int(draws[0] * 3)
        position[axis] = "NaN"
        detail = f"string_number: position[{axis}] = 'NaN'"
    elif kind == "absurd_position":
        if document.get("frame") == "geodetic":
            position[0] = 1000.0
            detail = "absurd_position: latitude = 1000 deg"
        else:
            axis = int(draws[0] * 3)
            position[axis] = 1e9
            detail = f"absurd_position: position[{axis}] = 1e9 m"
    else:
        raise ValueError(f"unknown corruption kind {kind!r}")
    return json.dumps(document, allow_nan=True, separators=(",", ":")).encode("utf-8"), kind, detail


class LinkFaults:
    """The fault model of the target link (module docstring): messages in with `offer`, out with `due`.

    config: the [faults] section. rng: the only source of randomness (see `fault_rng`).
    events: every injected fault, in the order injected. counters: events by kind,
    plus "blackout_drop" (messages dropped inside a blackout).
    """

    def __init__(self, config: FaultsConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._streams = dict(zip(STREAMS, rng.spawn(len(STREAMS))))
        self._windows = tuple(sorted((w for w in config.blackouts if w.duration > 0), key=lambda w: w.start))
        self._stalls = tuple(sorted((w for w in config.stalls if w.duration > 0), key=lambda w: w.start))
        self._stalls_logged: set[int] = set()
        # What `due` need call at every tick (the config is frozen): _run_impostor and _run_spoof return at once
        # without a rate, _advance_blackouts without windows.
        self._impostor_on = config.impostor_rate_hz > 0
        self._spoof_on = config.spoof_rate_hz > 0
        self._attacks_on = attacks_anything(config)
        self._enabled = injects_anything(config)
        self.events: list[FaultEvent] = []
        self.counters: Counter[str] = Counter()
        self._pending: list[tuple[float, int, bytes]] = []  # heap of (delivery time s, order, payload)
        self._order = 0
        self._reset_state()
        self._impostor_seq = 0
        self._attacks_done: set[str] = set()
        self._replayable: deque[bytes] = deque(maxlen=config.replay_count)
        self._attack_template: TargetFix | None = None
        self._restart_epoch: int | None = None
        self._restart_seq0 = 0
        self._spoof_epoch: int | None = None
        self._spoof_seq = -1
        self._spoof_next: int | None = None
        # spoof_offset as np.array gives it (float64; an integer component converted as numpy converts it), as floats
        self._spoof_offset = tuple(np.array(config.spoof_offset).astype(float).tolist())
        drift = tuple(float(v) for v in config.spoof_drift)
        self._spoof_drift = drift if any(drift) else None

    @property
    def enabled(self) -> bool:
        """False when the config injects nothing: callers may skip the model (it would pass everything through)."""
        return self._enabled

    @property
    def pending(self) -> int:
        """Messages offered (or generated) but not delivered yet."""
        return len(self._pending)

    def _reset_state(self) -> None:
        self._last_offer: float | None = None  # simulated time of the previous offer, s
        self._scenario_offset: float | None = None  # simulated - scenario time, s, once the scenario runs
        self._window_index = 0  # the first window not yet left
        self._window_active = False
        self._window_dropped = 0
        self._burst_bad = False
        self._history: deque[tuple[float, bytes]] = deque(maxlen=MAX_HISTORY)  # (offer time s, original payload)
        self._impostor_template: TargetFix | None = None
        self._impostor_next: int | None = None  # index k of the next impostor tick k / rate

    def restart(self, now: float) -> None:
        """The clock went back (a restarted plant): drop what is in flight and start over at simulated time `now`."""
        discarded = len(self._pending)
        self._pending.clear()
        self._reset_state()
        self._log(now, "restart", f"clock went back; {discarded} messages in flight discarded", discarded=discarded)

    def offer(self, now: float, payload: bytes, scenario_time: float, fix: TargetFix | None = None) -> None:
        """Take one message produced at simulated time `now` (s); scenario_time: s since the scenario started.

        fix: the TargetFix that `payload` encodes (payload = encode_target_fix(fix)), when the caller has it: the
        attacks and the impostor then take it as the overheard fix instead of decoding the payload again (the
        decoded payload is that fix, field for field). Not used once the payload is changed (a restarted publisher's).
        """
        offered = payload = bytes(payload)
        if not self._enabled:
            self._push(now, payload)
            return
        payload = self._restarted(now, payload, scenario_time)
        if payload is None:
            return
        known = fix if payload is offered else None
        self._attack(now, payload, scenario_time, known)
        dt = None if self._last_offer is None else max(0.0, now - self._last_offer)
        self._last_offer = now
        if math.isfinite(scenario_time):
            self._scenario_offset = now - scenario_time
        self._history.append((now, payload))
        self._note_impostor_template(payload, known)
        self._run_impostor(now)
        self._advance_blackouts(now, scenario_time)
        draws = self._draw_all(dt)
        seq = _SeqLabel(payload)
        if self._window_active:
            self._window_dropped += 1
            self.counters["blackout_drop"] += 1
            return
        if "loss" in draws and draws["loss"] < self.config.loss_probability:
            self._log(now, "loss", str(seq), seq=seq.value)
            return
        if "burst" in draws:
            lost, state = draws["burst"]
            if lost:
                self._log(now, "burst_loss", f"{seq} ({state} state)", seq=seq.value, state=state)
                return
        if "corrupt" in draws:
            decide, which, *details = draws["corrupt"]
            if decide < self.config.corrupt_probability:
                kinds = self.config.corrupt_kinds
                payload, applied, what = _corrupt(payload, kinds[int(which * len(kinds))], np.array(details))
                self._log(now, "corrupt", f"{seq} {what}", seq=seq.value, corruption=applied)
        delivery = now
        if "delay" in draws:
            delay = self.config.latency_s + draws["delay"] * self.config.jitter_s
            delivery += delay
            self._log(now, "delay", f"{seq} {delay:.3f} s", seq=seq.value, delay_s=delay)
        delivery = self._stalled(now, delivery, scenario_time)
        if "reorder" in draws and draws["reorder"] < self.config.reorder_probability:
            delivery += self.config.reorder_delay_s
            self._log(now, "reorder", f"{seq} held back {self.config.reorder_delay_s:g} s more", seq=seq.value,
                      held_back_s=self.config.reorder_delay_s)
        self._push(delivery, payload)
        if "duplicate" in draws and draws["duplicate"] < self.config.duplicate_probability:
            self._push(delivery + self.config.duplicate_delay_s, payload)
            self._log(now, "duplicate", f"{seq} again {self.config.duplicate_delay_s:g} s later", seq=seq.value,
                      after_s=self.config.duplicate_delay_s)
        if "stale" in draws:
            decide, which = draws["stale"]
            if decide < self.config.stale_probability:
                self._inject_stale(now, delivery, which, seq)

    def due(self, now: float) -> list[bytes]:
        """Messages whose delivery time (s) is at or before simulated time `now`, in delivery order."""
        if self._enabled:  # (each call only where it can do something: a frozen config's impostor, spoofer, windows)
            if self._impostor_on:
                self._run_impostor(now)
            if self._spoof_on:
                self._run_spoof(now)
            if self._windows and self._scenario_offset is not None:
                self._advance_blackouts(now, now - self._scenario_offset)
        delivered = []
        while self._pending and self._pending[0][0] <= now + TIME_TOLERANCE:
            delivered.append(heapq.heappop(self._pending)[2])
        return delivered

    # --- the pieces ---------------------------------------------------------------

    def _push(self, delivery: float, payload: bytes) -> None:
        heapq.heappush(self._pending, (delivery, self._order, payload))
        self._order += 1

    def _log(self, now: float, kind: str, detail: str, **fields) -> None:
        # FaultEvent(now, kind, detail, fields), its four fields written in order into the new instance (the same
        # object, without the frozen dataclass's setattr per field; tests/test_link_sensor_costs.py)
        event = object.__new__(FaultEvent)
        event.__dict__.update(time=now, kind=kind, detail=detail, fields=fields)
        self.events.append(event)
        self.counters[kind] += 1

    def _draw_all(self, dt: float | None) -> dict:
        """This message's draws of every enabled kind; a fixed number per kind, whatever happens to the message."""
        config, streams, draws = self.config, self._streams, {}
        if config.loss_probability > 0:
            draws["loss"] = streams["loss"].random()
        if config.burst is not None:
            draws["burst"] = self._step_burst(streams["burst"].random(2), dt)
        if config.corrupt_probability > 0:
            draws["corrupt"] = streams["corrupt"].random(4)
        if config.latency_s > 0 or config.jitter_s > 0:
            draws["delay"] = streams["delay"].random()
        if config.reorder_probability > 0:
            draws["reorder"] = streams["reorder"].random()
        if config.duplicate_probability > 0:
            draws["duplicate"] = streams["duplicate"].random()
        if config.stale_probability > 0:
            draws["stale"] = streams["stale"].random(2)
        return draws

    def _step_burst(self, uniforms: np.ndarray, dt: float | None) -> tuple[bool, str]:
        """Step the Gilbert-Elliott chain (not before the first message), then (lost?, state name)."""
        burst = self.config.burst
        if dt is not None:
            if burst.mean_burst_s is not None:
                to_bad, to_good = min(1.0, dt / burst.mean_gap_s), min(1.0, dt / burst.mean_burst_s)
            else:
                to_bad, to_good = burst.p_good_to_bad, burst.p_bad_to_good
            if uniforms[0] < (to_good if self._burst_bad else to_bad):
                self._burst_bad = not self._burst_bad
        loss = burst.loss_in_bad if self._burst_bad else burst.loss_in_good
        return bool(uniforms[1] < loss), "bad" if self._burst_bad else "good"

    def _stalled(self, now: float, delivery: float, scenario_time: float) -> float:
        """`delivery` (simulated s), held to the end of the stall window holding `scenario_time`, if any."""
        for index, window in enumerate(self._stalls):
            if window.start - TIME_TOLERANCE <= scenario_time < window.end - TIME_TOLERANCE:
                if index not in self._stalls_logged:
                    self._stalls_logged.add(index)
                    self._log(now, "stall", f"publisher frozen [{window.start:g}, {window.end:g}) s scenario time",
                              window_start=window.start, window_end=window.end)
                return max(delivery, now + (window.end - scenario_time))
        return delivery

    def _advance_blackouts(self, now: float, scenario_time: float) -> None:
        """Log the windows entered and left by scenario time `scenario_time` (s)."""
        while self._window_index < len(self._windows):
            window = self._windows[self._window_index]
            label = f"[{window.start:g}, {window.end:g}) s scenario time"
            if not self._window_active:
                if scenario_time < window.start - TIME_TOLERANCE:
                    return
                self._window_active, self._window_dropped = True, 0
                self._log(now, "blackout_start", f"window {label}", window_start=window.start, window_end=window.end)
            if scenario_time < window.end - TIME_TOLERANCE:
                return
            self._log(now, "blackout_end", f"window {label}: {self._window_dropped} messages dropped",
                      window_start=window.start, window_end=window.end, dropped=self._window_dropped)
            self._window_active = False
            self._window_index += 1

    def _inject_stale(self, now: float, delivery: float, which: float, seq: _SeqLabel) -> None:
        config = self.config
        while self._history and now - self._history[0][0] > config.stale_max_age_s + TIME_TOLERANCE:
            self._history.popleft()
        candidates = [(time, payload) for time, payload in self._history
                      if now - time >= config.stale_min_age_s - TIME_TOLERANCE]
        if not candidates:
            return
        time, old = candidates[int(which * len(candidates))]
        self._push(delivery, old)
        stale_seq = _seq_of(old)
        self._log(now, "stale", f"seq={'?' if stale_seq is None else stale_seq} ({now - time:.2f} s old) after {seq}",
                  seq=seq.value, stale_seq=stale_seq, age_s=now - time)

    def _note_impostor_template(self, payload: bytes, known: TargetFix | None = None) -> None:
        """The impostor copies the latest genuine fix: `known` (offer's fix of this payload) or the payload decoded."""
        if self.config.impostor_rate_hz > 0:
            try:
                self._impostor_template = decode_target_fix(payload) if known is None else known
            except PayloadError:
                pass  # keep the previous template

    def _run_impostor(self, now: float) -> None:
        """Generate the impostor's messages of the ticks k / rate up to simulated time `now` (s)."""
        rate = self.config.impostor_rate_hz
        if rate <= 0 or self._impostor_template is None:
            return
        if self._impostor_next is None:
            self._impostor_next = math.ceil(now * rate - TIME_TOLERANCE * rate)
        while self._impostor_next / rate <= now + TIME_TOLERANCE:
            tick = self._impostor_next / rate
            self._impostor_next += 1
            self._send_impostor(now, max(tick, 0.0))

    def _send_impostor(self, now: float, stamp: float) -> None:
        template, config = self._impostor_template, self.config
        offset = np.array(config.impostor_offset)
        if template.frame == "geodetic":
            position = ned_to_geodetic(offset, template.position)
        else:
            position = tuple(np.array(template.position) + offset)
        fix = TargetFix(config.impostor_sender, self._impostor_seq, stamp, template.frame, position, template.velocity)
        try:
            payload = encode_target_fix(fix)
        except PayloadError as error:
            self._log(now, "impostor_skipped", f"cannot encode: {error}")
            return
        self._push(stamp, payload)
        self._log(now, "impostor", f"seq={self._impostor_seq} as {config.impostor_sender} at t={stamp:.3f} s",
                  seq=self._impostor_seq, sender=config.impostor_sender, stamp=stamp)
        self._impostor_seq += 1

    # --- attacks (module docstring) -------------------------------------------------

    def _draw_epoch(self) -> int:
        return int(self._streams["attack"].integers(0, MAX_EPOCH, endpoint=True))

    def _due_once(self, name: str, at: float | None, scenario_time: float) -> bool:
        """Whether the one-shot attack `name` fires now (scenario time reached `at`, not fired yet)."""
        if at is None or name in self._attacks_done or not math.isfinite(scenario_time):
            return False
        if scenario_time < at - TIME_TOLERANCE:
            return False
        self._attacks_done.add(name)
        return True

    def _restarted(self, now: float, payload: bytes, scenario_time: float) -> bytes | None:
        """The genuine payload as a publisher restarted at restart_at sends it (None: not sent, in the gap)."""
        config = self.config
        at = config.restart_at
        if at is None or not math.isfinite(scenario_time) or scenario_time < at - TIME_TOLERANCE:
            return payload
        if scenario_time < at + config.restart_gap_s - TIME_TOLERANCE:
            if "restart_gap" not in self._attacks_done:
                self._attacks_done.add("restart_gap")
                self._log(now, "target_restart", f"publisher down for {config.restart_gap_s:g} s", gap_s=config.restart_gap_s)
            self.counters["restart_drop"] += 1
            return None
        try:
            fix = decode_target_fix(payload)
        except PayloadError:
            return payload
        if self._restart_epoch is None:
            self._restart_epoch, self._restart_seq0 = self._draw_epoch(), fix.seq
            self._log(now, "target_restart", f"back with epoch {self._restart_epoch}, seq from 0",
                      epoch=self._restart_epoch, seq=0)
        return encode_target_fix(dataclasses.replace(fix, epoch=self._restart_epoch, seq=fix.seq - self._restart_seq0))

    def _send_attack(self, now: float, kind: str, fix: TargetFix, delivery: float | None = None) -> None:
        try:
            payload = encode_target_fix(fix)
        except PayloadError as error:
            self._log(now, f"{kind}_skipped", f"cannot encode: {error}")
            return
        self._push(now if delivery is None else delivery, payload)
        self._log(now, kind, f"seq={fix.seq} epoch={fix.epoch} stamp={fix.stamp:.3f} as {fix.sender}", seq=fix.seq,
                  epoch=fix.epoch, stamp=fix.stamp, sender=fix.sender)

    def _attack(self, now: float, payload: bytes, scenario_time: float, known: TargetFix | None = None) -> None:
        """Note the genuine payload for the attacks and fire the one-shot attacks that are due; known: offer's fix
        of this payload (else the payload is decoded)."""
        config = self.config
        if not self._attacks_on:
            return
        if config.replay_at is not None and "replay" not in self._attacks_done:
            if self._due_once("replay", config.replay_at, scenario_time):
                for old in list(self._replayable):
                    self._push(now, old)
                    self._log(now, "attack_replay", f"{_SeqLabel(old)} sent again", seq=_seq_of(old))
            else:
                self._replayable.append(payload)
        try:
            fix = decode_target_fix(payload) if known is None else known
        except PayloadError:
            return
        self._attack_template = fix
        if self._due_once("future_seq", config.future_seq_at, scenario_time):
            self._send_attack(now, "attack_future_seq", dataclasses.replace(
                fix, seq=min(fix.seq + FUTURE_SEQ_JUMP, MAX_SEQ), stamp=fix.stamp + FUTURE_SEQ_STAMP_LEAD), now + TIME_TOLERANCE)
        if self._due_once("future_stamp", config.future_stamp_at, scenario_time):
            self._send_attack(now, "attack_future_stamp",
                              dataclasses.replace(fix, seq=min(fix.seq + 1, MAX_SEQ), stamp=fix.stamp + FUTURE_STAMP_JUMP),
                              now + TIME_TOLERANCE)
        if self._due_once("spoof_burst", config.spoof_burst_at, scenario_time):
            for k in range(config.spoof_burst_count):
                self._send_attack(now, "attack_spoof_burst", self._spoofed(now + SPOOF_BURST_SPACING * k))
        self._run_spoof(now)

    def _spoofed(self, stamp: float) -> TargetFix:
        """The spoofer's fix stamped `stamp` (s): the latest genuine fix moved by spoof_offset, as the target."""
        config, template = self.config, self._attack_template
        offset = self._spoof_offset
        if self._spoof_drift is not None:  # a drifting liar: spoof_offset + spoof_drift x (time since spoof_from)
            elapsed = max(stamp - (self._scenario_offset + config.spoof_from), 0.0)
            offset = tuple(o + d * elapsed for o, d in zip(offset, self._spoof_drift))
        if template.frame == "geodetic":
            position = ned_to_geodetic(np.array(offset), template.position)
        else:
            # np.array(template.position) + np.array(spoof_offset), element by element: the same float64 sums
            north, east, down = offset
            first, second, third = template.position
            position = (first + north, second + east, third + down)
        if config.spoof_epoch == "target":
            epoch = template.epoch
        else:
            if self._spoof_epoch is None:
                self._spoof_epoch = self._draw_epoch()
            epoch = self._spoof_epoch
        self._spoof_seq = min(max(self._spoof_seq + 1, template.seq + config.spoof_seq_lead), MAX_SEQ)
        return TargetFix(template.sender, self._spoof_seq, stamp, template.frame, position, template.velocity, epoch)

    def _run_spoof(self, now: float) -> None:
        """The steady spoofer's messages of the ticks k / spoof_rate_hz up to simulated time `now` (s)."""
        rate = self.config.spoof_rate_hz
        if rate <= 0 or self._attack_template is None or self._scenario_offset is None:
            return
        start = self._scenario_offset + self.config.spoof_from  # simulated s
        if now < start - TIME_TOLERANCE:
            return
        if self._spoof_next is None:
            self._spoof_next = math.ceil(max(now, start) * rate - TIME_TOLERANCE * rate)
        duration = self.config.spoof_duration
        while self._spoof_next / rate <= now + TIME_TOLERANCE:
            tick = max(self._spoof_next / rate, 0.0)
            if duration is not None and tick > start + duration + TIME_TOLERANCE:
                return  # the spoofer has gone quiet
            self._spoof_next += 1
            self._send_attack(now, "attack_spoof", self._spoofed(tick), tick)
