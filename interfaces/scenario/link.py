"""[link] (the target-fix link) and [companion] (the onboard app's own settings)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from interfaces.scenario.common import (FROM_ARRAY, MAX_DURATION_S, Duration, NonNegativeDistance, NonNegativeDuration,
                                        Rate, Speed, _Strict)


class LinkConfig(_Strict):
    """The Zenoh link: target fixes in, companion state out, commands (abort) in.

    mode: Zenoh session mode. listen/connect: Zenoh endpoints ("tcp/127.0.0.1:7447",
    "tls/host:port", ...); the command line can override them. zenoh_overrides: raw Zenoh
    configuration entries (dotted key -> JSON5 value), e.g. TLS certificates:
    {"transport.link.tls.root_ca_certificate" = '"/path/ca.pem"'}. Multicast scouting is
    off unless an override turns it on. The target publishes at sensor.rate_hz.

    Fix and command validation (companion.core.fix_validator; docs/guide/faults.md, "Link validation"):
    max_future_skew_s: a stamp more than this ahead of the receiver's clock is refused
    (future_stamp). max_fix_age_s: a stamp older than this is refused (too_old).
    max_fix_rate_hz: seq may advance at most this fast (per stamp second, plus 10) within
    one publisher epoch (seq_jump). reanchor_silence_s: a track of fixes inconsistent with
    the last accepted one may take over only after the accepted track has been silent this
    long (or when it agrees with the filter's predicted bearing and the old one does not).
    epoch_switch_silence_s: fixes of another publisher epoch (a restarted target) are taken
    only once the accepted epoch has been silent this long (other_epoch before).
    max_target_speed: m/s, the plausibility bound between two fixes (plus 5 m of noise).
    """

    mode: Literal["peer", "client", "router"] = "peer"
    listen: Annotated[tuple[str, ...], FROM_ARRAY] = ()
    connect: Annotated[tuple[str, ...], FROM_ARRAY] = ()
    zenoh_overrides: dict[str, str] = {}
    target_sender: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")] = "target-1"
    companion_id: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")] = "pursuer-1"
    fix_frame: Literal["geodetic", "ned"] = "geodetic"
    fix_noise_std: NonNegativeDistance = 0.0
    state_rate_hz: Rate = 5.0
    max_future_skew_s: NonNegativeDuration = 0.5
    max_fix_age_s: Duration = 10.0
    max_fix_rate_hz: Rate = 50.0
    reanchor_silence_s: Duration = 2.0
    epoch_switch_silence_s: NonNegativeDuration = 0.5
    max_target_speed: Speed = 30.0


class CompanionConfig(_Strict):
    """The companion application's mission.

    mavlink_url: MAVSDK URL of the autopilot. engage_altitude: take off to this height above
    home (m), hover settle_time (s), then engage on the first bearing. follow_duration: follow
    this long (s of vehicle time) before landing; default simulation.duration.
    link_timeout / connect_timeout: wall-clock seconds to wait for the first target fix /
    the autopilot. hold_after_abort: hover this long (s) after an abort before landing.
    vehicle_link_timeout: wall-clock seconds without odometry after which the vehicle link
    counts as lost: the companion stops commanding and lets the autopilot's offboard-loss
    failsafe act. vehicle_link_wait: how long (wall s) to wait for it to come back before
    giving up. on_vehicle_link_return: "resume" re-engages offboard and goes on following;
    "land" (the default, the operator's call) lands instead.
    """

    mavlink_url: str = "udpin://127.0.0.1:14540"
    engage_altitude: Annotated[float, Field(gt=1.0, le=120.0)] = 20.0
    settle_time: NonNegativeDuration = 1.5
    follow_duration: Annotated[float, Field(gt=0.0, le=MAX_DURATION_S)] | None = None
    link_timeout: Duration = 60.0
    connect_timeout: Duration = 30.0
    hold_after_abort: NonNegativeDuration = 3.0
    vehicle_link_timeout: Duration = 1.0
    vehicle_link_wait: Duration = 60.0
    on_vehicle_link_return: Literal["resume", "land"] = "land"
