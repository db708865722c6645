"""MavlinkVehicle's parameter protocol: PARAM_REQUEST_READ, PARAM_REQUEST_LIST and PARAM_SET on the
autopilot's parameter table, values on the wire as PX4 encodes them (integers bytewise)."""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

from sitl_plant.vehicle.mavlink_protocol import mavlink
from sitl_plant.vehicle.parameters import Parameter, ParameterError
from sitl_plant.vehicle.px4_modes import Severity

if TYPE_CHECKING:
    from sitl_plant.vehicle.mavlink_protocol import Link


def _param_wire_value(parameter: Parameter) -> tuple[float, int]:
    """PX4 encodes integer parameters bytewise: the int32's bytes inside the float field."""
    if parameter.kind == "int":
        return struct.unpack("<f", struct.pack("<i", int(parameter.value)))[0], mavlink.MAV_PARAM_TYPE_INT32
    return float(parameter.value), mavlink.MAV_PARAM_TYPE_REAL32


def _param_from_wire(value: float, param_type: int) -> float:
    if param_type in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT16,
                      mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT8):
        return float(struct.unpack("<i", struct.pack("<f", value))[0])
    return float(value)


class MavlinkParameters:
    """The parameter handlers of MavlinkVehicle (a mixin: it uses the vehicle's autopilot, links, stats and its
    _event, _reject, _send and _statustext)."""

    def _on_param_request_read(self, link: Link, msg) -> None:
        table = self.autopilot.parameters
        try:
            name = msg.param_id if msg.param_index < 0 else table.by_index(msg.param_index).name
            parameter = table.get(name)
        except ParameterError as error:
            self.stats.ignored["PARAM_REQUEST_READ:unknown"] += 1
            self._event("param_unknown", str(error))
            return  # PX4 stays silent for unknown parameters; the requester times out
        self._send_param(link, parameter)

    def _on_param_request_list(self, link: Link, msg) -> None:
        for parameter in self.autopilot.parameters:
            self._send_param(link, parameter)

    def _on_param_set(self, link: Link, msg) -> None:
        table = self.autopilot.parameters
        if msg.param_id not in table:
            self.stats.ignored["PARAM_SET:unknown"] += 1
            self._event("param_unknown", f"set of unknown parameter {msg.param_id!r}")
            return
        value = _param_from_wire(msg.param_value, msg.param_type)
        try:
            parameter = table.set(msg.param_id, value)
            self._event("param_set", f"{parameter.name} = {parameter.value:g}")
        except ParameterError as error:
            parameter = table.get(msg.param_id)
            self._reject(link, "param_set_refused", str(error))
            self._statustext(Severity.WARNING, f"Param set refused: {error}")
        for each in self.links:  # PX4 broadcasts the new value on every link
            self._send_param(each, parameter)

    def _send_param(self, link: Link, parameter: Parameter) -> None:
        value, kind = _param_wire_value(parameter)
        table = self.autopilot.parameters
        self._send(link, link.mav.param_value_encode(
            parameter.name.encode(), value, kind, len(table), table.index_of(parameter.name)))
