"""MavlinkVehicle's outgoing side: what is due at each tick (mode and failsafe events, status texts, the
heartbeat, every link's streams) and the message builders, PX4's telemetry from the autopilot's state."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from sitl_plant.vehicle.mavlink_protocol import mavlink, signing_timestamp
from sitl_plant.vehicle.px4_modes import HOLD, LAND, OFFBOARD, POSITION, TAKEOFF

if TYPE_CHECKING:
    from sitl_plant.vehicle.mavlink_protocol import Link


_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_AHRS
)


CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
)


#: Reported as PX4 v1.14.0 (release), the version whose modes and parameters are modelled.
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255


def _i16(value: float) -> int:
    return int(max(-32768, min(32767, round(value))))


def _attitude_of(quaternion: tuple[float, float, float, float]) -> Rotation:
    """The body FRD -> NED rotation of a unit quaternion (w, x, y, z)."""
    return Rotation.from_quat(quaternion, scalar_first=True)


def _euler(quaternion: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad, ZYX convention as MAVLink ATTITUDE uses."""
    yaw, pitch, roll = _attitude_of(quaternion).as_euler("ZYX")
    return float(roll), float(pitch), float(yaw)


class MavlinkStreams:
    """The streams and message builders of MavlinkVehicle (a mixin: it uses the vehicle's autopilot, home, links,
    stats, signing key, unix_epoch, on_odometry_sent and its _event, _send, _statustext and _update_blackouts)."""

    def after_tick(self) -> None:
        """Send what is due at the current simulated time: status texts, heartbeat, streams."""
        ap = self.autopilot
        now = ap.time
        if self.companion_blackouts:
            self._update_blackouts()
        if ap.mode != self._last_mode or ap.armed != self._last_armed:
            self._event("state", f"mode={ap.mode.name} armed={ap.armed}", mode=ap.mode.name, armed=bool(ap.armed))
            if ap.failsafe_active and self._last_mode == OFFBOARD:
                self._event("failsafe", f"offboard lost: last setpoint at t={ap.last_setpoint_time:.4f} s, "
                                        f"now {ap.mode.name}", last_setpoint_time=ap.last_setpoint_time,
                            mode=ap.mode.name)
            self._last_mode, self._last_armed = ap.mode, ap.armed
        for severity, text in ap.take_status_texts():
            self._statustext(severity, text)
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + 1.0
            if self._signing_key is not None:
                # Our signing clocks follow the wall clock (as a real autopilot's do), so a peer that
                # restarts takes our new stream and an old captured frame is refused as stale.
                wall_stamp = signing_timestamp()
                for link in self.links:
                    if link.spec.signed:
                        for mav in (link.mav, link.parser):
                            mav.signing.timestamp = max(mav.signing.timestamp, wall_stamp)
            for link in self.links:
                self._send(link, self._heartbeat(link))
        for link in self.links:
            for message_id, interval in link.intervals.items():
                if interval <= 0.0:
                    continue
                due = link.next_due[message_id]
                if now + 1e-9 >= due:
                    try:
                        self._send(link, self._build(link, message_id))
                    except (struct.error, ValueError, OverflowError) as error:
                        # A value that does not fit its field must not stop the vehicle; count and go on.
                        self.stats.ignored[f"encode_error:{message_id}"] += 1
                        self._event("encode_error", f"{link.name}: message {message_id}: {error}")
                    # Keep the phase but never queue a burst after a pause.
                    link.next_due[message_id] = due + interval if due + interval > now else now + interval

    def _heartbeat(self, link: Link):
        ap = self.autopilot
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if ap.mode in (HOLD, TAKEOFF, LAND):
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        elif ap.mode == OFFBOARD:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        elif ap.mode == POSITION:
            base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if ap.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if ap.failsafe_active:
            status = mavlink.MAV_STATE_CRITICAL
        elif ap.armed:
            status = mavlink.MAV_STATE_ACTIVE
        else:
            status = mavlink.MAV_STATE_STANDBY
        return link.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, ap.mode.custom_mode, status)

    def _build(self, link: Link, message_id: int):
        builder = self._builder_table.get(message_id)
        if builder is None:
            raise KeyError(message_id)
        return builder(link)

    def _builders(self) -> dict[int, Callable]:
        return {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._extended_sys_state,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._attitude_quaternion,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._local_position_ned,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._global_position_int,
            mavlink.MAVLINK_MSG_ID_ODOMETRY: self._odometry,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._gps_raw_int,
            mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: self._system_time,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self._vfr_hud,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
        }

    def _sys_status(self, link: Link):
        health = _SENSORS
        ready, _ = self.autopilot.ready_to_arm
        present = _SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if ready or self.autopilot.armed:
            health |= mavlink.MAV_SYS_STATUS_PREARM_CHECK
        return link.mav.sys_status_encode(present, present, health, 100, 16800, -1, -1, 0, 0, 0, 0, 0, 0)

    def _extended_sys_state(self, link: Link):
        return link.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self.autopilot.landed_state))

    def _attitude_quaternion(self, link: Link):
        t = self.autopilot.telemetry()
        w = t.angular_velocity
        return link.mav.attitude_quaternion_encode(self.time_boot_ms, *t.quaternion, w[0], w[1], w[2], (1.0, 0.0, 0.0, 0.0))

    def _attitude(self, link: Link):
        t = self.autopilot.telemetry()
        roll, pitch, yaw = _euler(t.quaternion)
        w = t.angular_velocity
        return link.mav.attitude_encode(self.time_boot_ms, roll, pitch, yaw, w[0], w[1], w[2])

    def _local_position_ned(self, link: Link):
        t = self.autopilot.telemetry()
        p, v = t.position, t.velocity
        return link.mav.local_position_ned_encode(self.time_boot_ms, p[0], p[1], p[2], v[0], v[1], v[2])

    def _global_position_int(self, link: Link):
        t = self.autopilot.telemetry()
        lat, lon, alt = self.home.to_geodetic(*t.position)
        _, _, yaw = _euler(t.quaternion)
        v = t.velocity
        return link.mav.global_position_int_encode(
            self.time_boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)),
            int(round(-t.position[2] * 1000.0)), _i16(v[0] * 100.0), _i16(v[1] * 100.0), _i16(v[2] * 100.0),
            int(round(math.degrees(yaw) % 360.0 * 100.0)) % 36000,
        )

    def _odometry(self, link: Link):
        """ODOMETRY as PX4 sends it: pose in local NED, twist in body FRD (the child frame)."""
        ap = self.autopilot
        t = ap.telemetry()
        v_body = _attitude_of(t.quaternion).apply(t.velocity, inverse=True)
        w = t.angular_velocity
        sp = ap.params.position_noise_std**2
        sv = ap.params.velocity_noise_std**2
        pose_cov = [math.nan] * 21
        vel_cov = [math.nan] * 21
        pose_cov[0] = pose_cov[6] = pose_cov[11] = sp
        vel_cov[0] = vel_cov[6] = vel_cov[11] = sv
        msg = link.mav.odometry_encode(
            self.time_usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
            t.position[0], t.position[1], t.position[2], t.quaternion,
            v_body[0], v_body[1], v_body[2], w[0], w[1], w[2], pose_cov, vel_cov, 0,
            mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100,
        )
        if self.on_odometry_sent is not None:
            self.on_odometry_sent(self.time_usec)
        return msg

    def _home_position(self, link: Link):
        ap = self.autopilot
        lat, lon, alt = self.home.to_geodetic(*ap.home)
        h = ap.home
        return link.mav.home_position_encode(
            int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)), h[0], h[1], h[2],
            (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, self.time_usec)

    def _gps_raw_int(self, link: Link):
        t = self.autopilot.telemetry()
        lat, lon, alt = self.home.to_geodetic(*t.position)
        speed = float(np.hypot(t.velocity[0], t.velocity[1]))
        course = math.degrees(math.atan2(t.velocity[1], t.velocity[0])) % 360.0
        return link.mav.gps_raw_int_encode(
            self.time_usec, mavlink.GPS_FIX_TYPE_3D_FIX, int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round(alt * 1000.0)), 80, 120, int(speed * 100.0), int(course * 100.0) % 36000, 14)

    def _system_time(self, link: Link):
        return link.mav.system_time_encode(int((self.unix_epoch + self.autopilot.time) * 1e6), self.time_boot_ms)

    def _vfr_hud(self, link: Link):
        t = self.autopilot.telemetry()
        _, _, yaw = _euler(t.quaternion)
        speed = float(np.hypot(t.velocity[0], t.velocity[1]))
        _, _, alt = self.home.to_geodetic(*t.position)
        return link.mav.vfr_hud_encode(speed, speed, int(math.degrees(yaw) % 360.0), min(100, max(0, int(self.autopilot.thrust_command * 100))),
                                       alt, -t.velocity[2])

    def _autopilot_version(self, link: Link):
        return link.mav.autopilot_version_encode(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1)
