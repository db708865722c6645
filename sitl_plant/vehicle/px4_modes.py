"""PX4's flight modes as MAVLink carries them, and the MAVLink enums the plant answers with.

PX4 puts its own mode in HEARTBEAT.custom_mode: main mode in bits 16-23, sub mode
in bits 24-31 (px4_custom_mode.h). base_mode carries MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
and, when armed, MAV_MODE_FLAG_SAFETY_ARMED. MAV_CMD_DO_SET_MODE takes the same pair
in param2 (main) and param3 (sub). Only the modes this plant flies are listed;
asking for any other is answered MAV_RESULT_UNSUPPORTED.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class MainMode(enum.IntEnum):
    """PX4_CUSTOM_MAIN_MODE_*."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSubMode(enum.IntEnum):
    """PX4_CUSTOM_SUB_MODE_AUTO_*."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


@dataclass(frozen=True)
class FlightMode:
    """A PX4 mode: (main, sub) and the name QGroundControl and MAVSDK show."""

    main: int
    sub: int
    name: str

    @property
    def custom_mode(self) -> int:
        """HEARTBEAT.custom_mode encoding."""
        return encode_custom_mode(self.main, self.sub)


HOLD = FlightMode(MainMode.AUTO, AutoSubMode.LOITER, "Hold")
TAKEOFF = FlightMode(MainMode.AUTO, AutoSubMode.TAKEOFF, "Takeoff")
LAND = FlightMode(MainMode.AUTO, AutoSubMode.LAND, "Land")
OFFBOARD = FlightMode(MainMode.OFFBOARD, 0, "Offboard")
POSITION = FlightMode(MainMode.POSCTL, 0, "Position")

SUPPORTED_MODES: tuple[FlightMode, ...] = (HOLD, TAKEOFF, LAND, OFFBOARD, POSITION)


def encode_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 custom_mode: main mode in bits 16-23, sub mode in bits 24-31."""
    if not (0 <= main <= 255 and 0 <= sub <= 255):
        raise ValueError(f"main/sub mode must be bytes, got {main}/{sub}")
    return (int(main) << 16) | (int(sub) << 24)


def decode_custom_mode(custom_mode: int) -> tuple[int, int]:
    """(main, sub) from HEARTBEAT.custom_mode."""
    return (int(custom_mode) >> 16) & 0xFF, (int(custom_mode) >> 24) & 0xFF


def mode_from_main_sub(main: float, sub: float) -> FlightMode | None:
    """The supported mode for DO_SET_MODE's param2/param3, or None.

    A main mode without sub modes ignores param3 (PX4 does the same); AUTO needs a sub mode.
    """
    if main != int(main) or sub != int(sub):
        return None
    for mode in SUPPORTED_MODES:
        if mode.main == int(main) and (mode.main != MainMode.AUTO or mode.sub == int(sub)):
            return mode
    return None


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE, sent in EXTENDED_SYS_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class CommandResult(enum.IntEnum):
    """MAV_RESULT, sent in COMMAND_ACK."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5
    CANCELLED = 6


class Severity(enum.IntEnum):
    """MAV_SEVERITY, sent in STATUSTEXT."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7
