"""MavlinkVehicle's commands: COMMAND_LONG and COMMAND_INT executed as PX4 answers them (arming, takeoff,
landing, modes, message intervals and requests), each acknowledged with a COMMAND_ACK."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from sitl_plant.vehicle.mavlink_protocol import ONE_SHOT, STREAMABLE, Rejected, mavlink
from sitl_plant.vehicle.px4_modes import HOLD, CommandResult, Severity, mode_from_main_sub

if TYPE_CHECKING:
    from sitl_plant.vehicle.mavlink_protocol import Link


# Parameters (0-based) each command needs finite; others may be NaN ("unset") as MAVLink allows.
_PARAMS_USED: dict[int, tuple[int, ...]] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: (0,),
    mavlink.MAV_CMD_DO_SET_MODE: (0, 1),
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: (0, 1),
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: (0,),
    mavlink.MAV_CMD_REQUEST_MESSAGE: (0,),
}


class MavlinkCommands:
    """The command handlers of MavlinkVehicle (a mixin: it uses the vehicle's autopilot, home, stats and its
    _event, _reject, _send, _statustext and _build)."""

    def _on_command_long(self, link: Link, msg) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(link, msg, int(msg.command), params)

    def _on_command_int(self, link: Link, msg) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x * 1e-7, msg.y * 1e-7, msg.z)
        self._command(link, msg, int(msg.command), params)

    def _command(self, link: Link, msg, command: int, params: tuple[float, ...]) -> None:
        name = mavlink.enums["MAV_CMD"][command].name if command in mavlink.enums["MAV_CMD"] else str(command)
        self.stats.commands[name] += 1
        try:
            result = self._execute(link, command, params)
        except Rejected as rejected:
            self._reject(link, rejected.args[0], rejected.args[1])
            result = CommandResult.DENIED
        if result == CommandResult.UNSUPPORTED:
            self._event("command_unsupported", f"{link.name}: {name} {params}")
        self._send(link, link.mav.command_ack_encode(command, int(result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _execute(self, link: Link, command: int, p: tuple[float, ...]) -> CommandResult:
        ap = self.autopilot
        used = _PARAMS_USED.get(command, ())
        if not all(math.isfinite(p[i]) for i in used):
            raise Rejected("command_not_finite", f"command {command} params {p}")
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            force = p[1] == 21196.0
            if p[0] == 1.0:
                return ap.arm(force)
            if p[0] == 0.0:
                return ap.disarm(force)
            return CommandResult.DENIED
        if command == mavlink.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6])
        if command == mavlink.MAV_CMD_NAV_LAND:
            return ap.land()
        if command == mavlink.MAV_CMD_DO_LAND_START:
            # PX4 (navigator) starts the mission's landing sequence; with no mission landing it warns on its
            # console only and answers CANCELLED. The plant has no missions. MAV_CMD_NAV_LAND or Land mode lands.
            self._event("command_cancelled", f"{link.name}: DO_LAND_START: planned mission landing not available")
            return CommandResult.CANCELLED
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return CommandResult.UNSUPPORTED
            mode = mode_from_main_sub(p[1], p[2] if math.isfinite(p[2]) else 0.0)
            return CommandResult.UNSUPPORTED if mode is None else ap.set_mode(mode)
        if command == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
            return ap.set_mode(HOLD)
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_message_interval(link, int(p[0]), p[1])
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            message_id = int(p[0])
            interval = link.intervals.get(message_id)
            value = -1 if not interval else int(interval * 1e6)
            if message_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                value = 1_000_000
            self._send(link, link.mav.message_interval_encode(message_id, value))
            return CommandResult.ACCEPTED
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            return self._send_once(link, int(p[0]))
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return self._send_once(link, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        return CommandResult.UNSUPPORTED

    def _takeoff(self, altitude_amsl: float) -> CommandResult:
        """MAV_CMD_NAV_TAKEOFF as PX4 takes param7 (m AMSL): unset (NaN) means home + MIS_TAKEOFF_ALT,
        said in an info text; a value below that is raised to it, with a critical text when more
        than 0.1 m below (PX4's navigator takeoff); above it, flown as given."""
        minimum = float(self.autopilot.parameters.value("MIS_TAKEOFF_ALT"))
        text = None
        if not math.isfinite(altitude_amsl):
            relative = minimum
            text = (Severity.INFO, f"Using minimum takeoff altitude: {minimum:.2f} m")
        else:
            relative = altitude_amsl - self.home.altitude
            if relative < minimum:
                if relative < minimum - 0.1:
                    text = (Severity.CRITICAL, f"Using minimum takeoff altitude: {minimum:.2f} m")
                relative = minimum
        result = self.autopilot.takeoff(relative)
        if result == CommandResult.ACCEPTED and text is not None:
            self._statustext(*text)
        return result

    def _set_message_interval(self, link: Link, message_id: int, interval_us: float) -> CommandResult:
        if message_id not in STREAMABLE or message_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return CommandResult.UNSUPPORTED if message_id not in STREAMABLE else CommandResult.DENIED
        if interval_us == -1:
            link.set_interval(message_id, 0.0)
        elif interval_us == 0:
            link.set_interval(message_id, link.defaults.get(message_id, 0.0))
        elif interval_us > 0:
            link.set_interval(message_id, max(interval_us * 1e-6, self.autopilot.tick_period))
        else:
            return CommandResult.DENIED
        return CommandResult.ACCEPTED

    def _send_once(self, link: Link, message_id: int) -> CommandResult:
        if message_id in STREAMABLE or message_id in ONE_SHOT:
            self._send(link, self._build(link, message_id))
            return CommandResult.ACCEPTED
        return CommandResult.UNSUPPORTED
