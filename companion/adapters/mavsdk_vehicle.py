"""The companion's side of the MAVLink link: a thin async adapter over MAVSDK 4.x.

Everything the companion asks of the autopilot goes through here: connect, read
the hover thrust (MPC_THR_HOVER) and tilt limit (MPC_TILTMAX_AIR) from its
parameters, follow its odometry, arm, take off, start/stop offboard, stream the
pipeline's attitude/thrust setpoints, hold and land. The same code flies the
bundled SITL plant, a PX4 SITL or a real PX4: only the connection URL changes.

Own state comes from ODOMETRY: position in local NED, velocity in body FRD (PX4's
child frame) rotated to NED with the reported attitude, time stamped with the
autopilot's time_usec, so the pipeline runs on the vehicle's clock (simulated
time in SITL, at any speed factor). The ODOMETRY messages are read from MAVSDK's
raw:// stream (every packet MAVSDK receives from the autopilot) and decoded with
pymavlink, from the autopilot's system and component only: MAVSDK 4.1's own
odometry subscription keeps about 190 bytes per message it delivers (at 50 Hz a
companion grew 0.5 MB a minute without end), the raw stream keeps nothing
(benchmarks/mavsdk_odometry_memory.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
from dataclasses import dataclass

import numpy as np
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.server_utility import ServerUtilityAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.enums import ForwardingOption
from mavsdk.plugins.offboard import Attitude
from mavsdk.plugins.server_utility import StatusTextType
from mavsdk.plugins.telemetry import FlightMode
from scipy.spatial.transform import Rotation

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from companion.core.attitude import VehicleLimits
from companion.core.messages import AttitudeSetpoint, PursuerState

#: Loopback only: a companion next to its autopilot (PX4 SITL sends there); give the serial port or the
#: interface address explicitly to listen elsewhere.
#: Status texts kept for the summary; later ones are only counted (memory and summary stay bounded).
MAX_STATUS_TEXTS = 200
DEFAULT_URL = "udpin://127.0.0.1:14540"


class VehicleError(RuntimeError):
    """The autopilot refused, timed out or sent something unusable; the message says which."""


@dataclass(frozen=True)
class VehicleSample:
    """One odometry sample: the pursuer state (vehicle clock) and its attitude (body FRD -> NED)."""

    state: PursuerState
    rotation: np.ndarray


#: The autopilot's component id (MAV_COMP_ID_AUTOPILOT1): the only sender whose ODOMETRY is the own state.
AUTOPILOT_COMPONENT = mavlink.MAV_COMP_ID_AUTOPILOT1


def pursuer_state_from_odometry(odometry) -> VehicleSample:
    """An ODOMETRY message (pymavlink) -> PursuerState: NED position, body velocity rotated to NED, time_usec in
    seconds.

    Raises VehicleError for a pose not in local NED or a velocity not in body FRD (frame_id, child_frame_id), a
    non-finite or zero quaternion, or non-finite numbers.
    """
    if odometry.frame_id != mavlink.MAV_FRAME_LOCAL_NED or odometry.child_frame_id != mavlink.MAV_FRAME_BODY_FRD:
        raise VehicleError(f"odometry in frames {odometry.frame_id}/{odometry.child_frame_id}, not local NED / body FRD")
    qw, qx, qy, qz = odometry.q
    values = (qw, qx, qy, qz, odometry.x, odometry.y, odometry.z, odometry.vx, odometry.vy, odometry.vz)
    if not all(math.isfinite(x) for x in values):
        raise VehicleError(f"odometry with non-finite values at time_usec={odometry.time_usec}")
    if math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz) < 0.5:
        raise VehicleError(f"odometry quaternion {values[:4]} is not a rotation")
    rotation = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
    velocity = rotation @ np.array([odometry.vx, odometry.vy, odometry.vz])
    state = PursuerState(odometry.time_usec * 1e-6, np.array([odometry.x, odometry.y, odometry.z]), velocity)
    return VehicleSample(state, rotation)


def offboard_attitude(setpoint: AttitudeSetpoint) -> Attitude:
    """AttitudeSetpoint -> MAVSDK offboard Attitude (roll, pitch, yaw in degrees, ZYX as MAVSDK builds its
    quaternion; normalised thrust). The conversion is exact away from +-90 deg pitch, which the
    tilt limit excludes."""
    yaw, pitch, roll = Rotation.from_matrix(setpoint.rotation).as_euler("ZYX", degrees=True)
    return Attitude(float(roll), float(pitch), float(yaw), float(setpoint.thrust_normalized))


class MavsdkVehicle:
    """One autopilot reached through MAVSDK. Use as `async with MavsdkVehicle(url) as vehicle:`.

    url: MAVSDK connection URL (udpin://0.0.0.0:14540 listens where PX4 SITL sends its
    offboard link). connect_timeout: seconds to wait for the autopilot's heartbeat.
    odometry_rate_hz: asked of the autopilot with SET_MESSAGE_INTERVAL (None: its default).
    forward_url: a second MAVSDK connection the vehicle's traffic is forwarded to (e.g. a ground
    station), or None; one way only: forwarding is on for that connection and off for the autopilot
    link, so MAVSDK never relays anything received there to the autopilot.
    on_mavlink: called (on a MAVSDK thread) with every MAVLink packet MAVSDK forwards from the
    autopilot, as bytes, one packet per call (e.g. a .tlog writer), or None. It uses MAVSDK's
    raw:// connection, which has no socket: nothing from outside can reach the autopilot through it.
    """

    def __init__(self, url: str = DEFAULT_URL, connect_timeout: float = 20.0, odometry_rate_hz: float | None = 50.0,
                 forward_url: str | None = None, on_mavlink=None) -> None:
        self.url = url
        self.forward_url = forward_url
        self.on_mavlink = on_mavlink
        self._raw_subscription = None
        self.connect_timeout = connect_timeout
        self.odometry_rate_hz = odometry_rate_hz
        self._sdk: Mavsdk | None = None
        self._system = None
        self.telemetry: TelemetryAsync | None = None
        self.action: ActionAsync | None = None
        self.offboard: OffboardAsync | None = None
        self.param: ParamAsync | None = None
        self._status = None
        self._latest: VehicleSample | None = None
        self._new_sample = asyncio.Event()
        #: called with every new odometry sample as it arrives, in order (e.g. the own-state history),
        #: so nothing depends on how often a consumer happens to await next_sample()
        self.sample_observers: list = []
        self._flight_mode: FlightMode | None = None
        self._in_air: bool | None = None
        self._armed: bool | None = None
        self.status_texts: list[str] = []  # the first MAX_STATUS_TEXTS the autopilot sent, in order
        self.status_texts_dropped = 0  # and how many more came (a peer may flood them through the autopilot)
        self.bad_odometry = 0
        self._tasks: list[asyncio.Task] = []
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True  # a corrupt packet is skipped, never raised on MAVSDK's thread
        self._autopilot_id: int | None = None  # the autopilot's system id, once MAVSDK found it
        self._loop: asyncio.AbstractEventLoop | None = None

    async def __aenter__(self) -> "MavsdkVehicle":
        await self.connect()
        return self

    async def __aexit__(self, *exc_info) -> None:
        await self.close()

    # ------------------------------------------------------------ connection
    async def connect(self) -> None:
        """Open MAVSDK, wait for the autopilot, start following its telemetry."""
        config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        self._sdk = Mavsdk(config)
        await self._sdk.__aenter__()
        try:
            # Forwarding off on the autopilot link: MAVSDK forwards a message received on a connection
            # only to the other connections with forwarding on, and, with a single such connection,
            # never what that connection itself received. So the recorder and any forward_url hear the
            # autopilot, and nothing they (or an intruder on their side) send ever reaches it.
            await self._sdk.add_any_connection(self.url, ForwardingOption.OFF)
            if self.forward_url is not None:
                await self._sdk.add_any_connection(self.forward_url, ForwardingOption.ON)
            # Every packet MAVSDK receives from the autopilot, in process: the odometry is read from it, and the
            # recorder (on_mavlink) keeps it. The synchronous binding under the asyncio wrapper has the subscription.
            self._loop = asyncio.get_running_loop()
            await self._sdk.add_any_connection("raw://", ForwardingOption.ON)
            self._raw_subscription = self._sdk._mavsdk.subscribe_raw_bytes_to_be_sent(self._on_raw)
        except Exception as error:
            await self.close()
            raise VehicleError(f"cannot open MAVLink connection {self.url!r}: {error}") from error
        system = await self._sdk.first_autopilot(timeout_s=self.connect_timeout)
        if system is None:
            await self.close()
            raise VehicleError(f"no autopilot heard on {self.url} within {self.connect_timeout:g} s")
        self._system = system
        self._autopilot_id = int(await system.get_system_id())
        self.telemetry = TelemetryAsync(system)
        self.action = ActionAsync(system)
        self.offboard = OffboardAsync(system)
        self.param = ParamAsync(system)
        self._tasks = [
            asyncio.create_task(self._follow(self.telemetry.subscribe_flight_mode(), "_flight_mode")),
            asyncio.create_task(self._follow(self.telemetry.subscribe_in_air(), "_in_air")),
            asyncio.create_task(self._follow(self.telemetry.subscribe_armed(), "_armed")),
            asyncio.create_task(self._follow_status_text()),
        ]
        if self.odometry_rate_hz is not None:
            try:
                await self.telemetry.set_rate_odometry(self.odometry_rate_hz)
            except Exception as error:  # an autopilot may refuse; its default rate is used then
                self.status_texts.append(f"(companion) odometry rate request refused: {error}")

    async def close(self) -> None:
        """Stop following telemetry and release MAVSDK (no command is sent)."""
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._tasks = []
        if self._sdk is not None:
            sdk, self._sdk = self._sdk, None
            if self._raw_subscription is not None:
                subscription, self._raw_subscription = self._raw_subscription, None
                sdk._mavsdk.unsubscribe_raw_bytes_to_be_sent(subscription)
            await sdk.__aexit__(None, None, None)

    def _on_raw(self, packet: bytes) -> None:
        """MAVSDK's thread: one packet of the raw stream to the recorder, and its autopilot ODOMETRY to the loop."""
        if self.on_mavlink is not None:
            self.on_mavlink(packet)
        for message in self._parser.parse_buffer(bytes(packet)) or ():
            if (message.get_msgId() == mavlink.MAVLINK_MSG_ID_ODOMETRY and self._autopilot_id is not None
                    and message.get_srcSystem() == self._autopilot_id
                    and message.get_srcComponent() == AUTOPILOT_COMPONENT):
                try:
                    self._loop.call_soon_threadsafe(self._on_odometry, message)
                except RuntimeError:  # the event loop has closed: the companion is exiting
                    return

    def _on_odometry(self, message) -> None:
        """Event loop: one autopilot ODOMETRY, in order of arrival; a stale or unusable one is skipped (counted)."""
        try:
            sample = pursuer_state_from_odometry(message)
        except VehicleError:
            self.bad_odometry += 1
            return
        if self._latest is not None and sample.state.time <= self._latest.state.time:
            return  # stale or duplicated: the pipeline's clock never runs backwards
        self._latest = sample
        for observer in self.sample_observers:
            observer(sample)
        self._new_sample.set()

    async def _follow(self, stream, attribute: str) -> None:
        async for value in stream:
            setattr(self, attribute, value)

    async def _follow_status_text(self) -> None:
        async for status in self.telemetry.subscribe_status_text():
            if len(self.status_texts) < MAX_STATUS_TEXTS:
                self.status_texts.append(status.text)
            else:
                self.status_texts_dropped += 1

    # ----------------------------------------------------------------- state
    @property
    def latest(self) -> VehicleSample | None:
        """The newest odometry sample, or None before the first."""
        return self._latest

    @property
    def flight_mode(self) -> FlightMode | None:
        return self._flight_mode

    @property
    def in_air(self) -> bool | None:
        return self._in_air

    @property
    def armed(self) -> bool | None:
        return self._armed

    async def next_sample(self, timeout: float = 5.0) -> VehicleSample:
        """Wait for an odometry sample newer than the last one returned."""
        self._new_sample.clear()
        try:
            await asyncio.wait_for(self._new_sample.wait(), timeout)
        except asyncio.TimeoutError:
            raise VehicleError(f"no odometry for {timeout:g} s") from None
        return self._latest

    async def wait_for(self, predicate, timeout: float, what: str) -> VehicleSample:
        """Wait until predicate(sample) is true for a new odometry sample; VehicleError on timeout."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise VehicleError(f"timed out after {timeout:g} s waiting for {what}")
            sample = await self.next_sample(min(remaining, 5.0))
            if predicate(sample):
                return sample

    # ------------------------------------------------------------ parameters
    async def hover_thrust(self) -> float:
        """MPC_THR_HOVER: normalised thrust that hovers, in (0, 1)."""
        value = await self._param_float("MPC_THR_HOVER")
        if not 0.0 < value < 1.0:
            raise VehicleError(f"MPC_THR_HOVER = {value} is not a normalised hover thrust")
        return value

    async def vehicle_limits(self, mass: float, gravity: float) -> VehicleLimits:
        """What the attitude mapping needs, read from the autopilot: hover thrust, tilt limit and the
        horizontal thrust margin kept under vertical saturation (MPC_THR_XY_MARG)."""
        hover = await self.hover_thrust()
        tilt = await self._param_float("MPC_TILTMAX_AIR")
        if not 0.0 < tilt < 90.0:
            raise VehicleError(f"MPC_TILTMAX_AIR = {tilt} deg is not a tilt limit")
        margin = await self._param_float("MPC_THR_XY_MARG")
        if not 0.0 <= margin <= 1.0:
            raise VehicleError(f"MPC_THR_XY_MARG = {margin} is not a share of full thrust")
        return VehicleLimits(hover_thrust_normalized=hover, max_tilt=math.radians(tilt), gravity=gravity, mass=mass,
                             horizontal_margin=margin)

    async def _param_float(self, name: str) -> float:
        try:
            value = float(await self.param.get_param_float(name))
        except Exception as error:
            raise VehicleError(f"cannot read parameter {name}: {error}") from error
        if not math.isfinite(value):
            raise VehicleError(f"parameter {name} is {value}")
        return value

    # --------------------------------------------------------------- actions
    async def _act(self, what: str, call) -> None:
        try:
            await call
        except Exception as error:
            raise VehicleError(f"{what} refused: {error}") from error

    async def arm(self) -> None:
        await self._act("arm", self.action.arm())

    async def disarm(self) -> None:
        await self._act("disarm", self.action.disarm())

    async def takeoff(self, altitude: float, timeout: float = 60.0, settle: float = 0.0,
                      tolerance: float = 0.3) -> VehicleSample:
        """Set MIS_TAKEOFF_ALT, take off, wait until within tolerance of altitude above home (m), then `settle` s of
        vehicle time more (Hold stops the climb; offboard at zero acceleration would keep any velocity left). Each
        wait may take up to timeout s; returns the sample after the settling."""
        await self._act("set takeoff altitude", self.action.set_takeoff_altitude(float(altitude)))
        await self._act("takeoff", self.action.takeoff())
        reached = await self.wait_for(lambda s: s.state.position[2] <= -(altitude - tolerance), timeout,
                                      f"takeoff to {altitude:g} m")
        if settle <= 0.0:
            return reached
        return await self.wait_for(lambda s: s.state.time > reached.state.time + settle, timeout, "settling")

    async def hold(self) -> None:
        await self._act("hold", self.action.hold())

    async def land(self) -> None:
        await self._act("land", self.action.land())

    async def start_offboard(self, setpoint: AttitudeSetpoint) -> None:
        """Stream `setpoint` first (PX4 refuses offboard without a stream), then switch to offboard."""
        await self.send_setpoint(setpoint)
        await self._act("offboard start", self.offboard.start())

    async def send_setpoint(self, setpoint: AttitudeSetpoint) -> None:
        """SET_ATTITUDE_TARGET with the pipeline's attitude and normalised thrust (MAVSDK re-sends it at 20 Hz)."""
        await self._act("offboard setpoint", self.offboard.set_attitude(offboard_attitude(setpoint)))

    async def status_text(self, text: str, severity: str = "WARNING") -> None:
        """STATUSTEXT from the companion (PX4 forwards it to the ground station); severity: a
        mavsdk.plugins.server_utility.StatusTextType name (DEBUG, INFO, NOTICE, WARNING, ERROR, CRITICAL...)."""
        if self._status is None:
            self._status = ServerUtilityAsync(self._system)
        await self._act("status text", self._status.send_status_text(getattr(StatusTextType, severity), text[:50]))

    async def stop_offboard(self) -> None:
        """Leave offboard; the autopilot holds position."""
        await self._act("offboard stop", self.offboard.stop())
