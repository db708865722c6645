"""The plant's flight stack: what PX4 does between the MAVLink link and the motors.

Arming, flight modes (Hold, Takeoff, Land, Position, Offboard), the offboard
attitude/thrust setpoint with its loss failsafe, the plant's own PX4-like position
controller (sitl_plant.vehicle.position_control) for the automatic modes and position/velocity
offboard, land/takeoff detection with auto-disarm, and a flat ground.
No sockets and no clock of its own: the caller ticks it (sitl_plant.vehicle.mavlink_vehicle
puts MAVLink around it, sitl_plant.sitl paces it against the wall clock), so tests
can drive it directly and deterministically.

Frames: local NED with the origin at home on the ground (z = 0 is the ground,
z < 0 is up), body FRD. Units SI; angles in radians unless a name says deg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle
from sitl_plant.vehicle.parameters import (
    OFFBOARD_LOSS_HOLD,
    OFFBOARD_LOSS_LAND,
    ParameterTable,
    default_parameters,
)
from sitl_plant.vehicle.params import QuadrotorParams
from sitl_plant.vehicle.position_control import (
    ControlLimits,
    PositionControlGains,
    PositionController,
    TrajectorySetpoint,
    trapezoidal_profile,
)
from sitl_plant.vehicle.px4_modes import (
    HOLD,
    LAND,
    OFFBOARD,
    POSITION,
    TAKEOFF,
    CommandResult,
    FlightMode,
    LandedState,
    Severity,
)
from sitl_plant.vehicle.quadrotor import RigidBodyState

#: Seconds of simulated time before the vehicle is ready to arm (sensors and estimator settle).
ARMING_READY_AFTER = 1.0
#: The ground contact must last this long before a landing counts as detected.
LAND_DETECT_TIME = 0.3
#: Height above ground (m) after which the vehicle is no longer on the ground.
LIFTOFF_HEIGHT = 0.05
#: Takeoff ends when the vehicle is within this distance (m) of the takeoff altitude.
TAKEOFF_ALTITUDE_TOLERANCE = 0.1
#: Vertical acceleration of the takeoff climb and of the start of the landing descent, m/s^2
#: (about 0.8 normalised thrust on Table I). Smooth setpoints, as PX4's trajectory generator
#: gives, keep the velocity integrators from charging on setpoint steps.
VERTICAL_ACCELERATION = 2.0
#: Rate of the position controller in Hold/Takeoff/Land/Position, Hz.
POSITION_CONTROL_RATE_HZ = 50.0
#: PX4's magic number in param2 of MAV_CMD_COMPONENT_ARM_DISARM that forces (dis)arming.
FORCE_ARM_MAGIC = 21196.0


@dataclass(frozen=True)
class OffboardAttitude:
    """A validated offboard attitude setpoint: unit quaternion (w, x, y, z), body FRD -> NED,
    and normalised collective thrust in [0, 1]; None keeps the previous one (type_mask)."""

    quaternion: tuple[float, float, float, float] | None
    thrust: float | None


@dataclass(frozen=True)
class OffboardTrajectory:
    """A validated offboard position/velocity setpoint (SET_POSITION_TARGET_LOCAL_NED), local NED.

    position (m) and/or velocity (m/s), optional acceleration feed-forward (m/s^2) and yaw
    (rad, from north towards east); None = not given. Flown by the position controller:
    position -> P loop plus velocity feed-forward; velocity alone -> velocity loop;
    acceleration alone -> open-loop acceleration.
    """

    position: tuple[float, float, float] | None = None
    velocity: tuple[float, float, float] | None = None
    acceleration: tuple[float, float, float] | None = None
    yaw: float | None = None


@dataclass(frozen=True)
class Telemetry:
    """What the autopilot's estimator reports: position (m) and velocity (m/s) in local NED
    with the feedback noise of section VIII, true attitude quaternion (w, x, y, z) body FRD ->
    NED and body rates (rad/s, FRD). time: simulated seconds since boot."""

    time: float
    position: np.ndarray
    velocity: np.ndarray
    quaternion: tuple[float, float, float, float]
    angular_velocity: np.ndarray


class Autopilot:
    """A PX4-like flight stack around the attitude/thrust vehicle of the flight core.

    params: airframe. start_position: (x, y) m local NED; the vehicle starts at rest on
    the ground there, heading `yaw` (rad). tick_rate_hz: rate of the mode logic and
    position controller; physics_rate_hz must be a whole multiple of it.
    max_tilt_deg: MPC_TILTMAX_AIR. seed: telemetry noise. gains: the position controller's.
    """

    def __init__(
        self,
        params: QuadrotorParams,
        *,
        start_position: tuple[float, float] = (0.0, 0.0),
        yaw: float = 0.0,
        tick_rate_hz: float = 250.0,
        physics_rate_hz: float = 500.0,
        max_tilt_deg: float = 35.0,
        speed_factor: float = 1.0,
        seed: int | None = 0,
        gains: PositionControlGains = PositionControlGains(),
    ) -> None:
        ratio = physics_rate_hz / tick_rate_hz
        if not (tick_rate_hz > 0 and ratio >= 1.0 and abs(ratio - round(ratio)) < 1e-9):
            raise ValueError(f"physics_rate_hz {physics_rate_hz} must be a whole multiple of tick_rate_hz {tick_rate_hz}")
        self.params = params
        self.tick_period = 1.0 / tick_rate_hz
        # The position controller of the automatic modes runs at ~50 Hz, as PX4's does.
        self._control_divider = max(1, round(tick_rate_hz / POSITION_CONTROL_RATE_HZ))
        self.position_controller = PositionController(gains)
        self.parameters: ParameterTable = default_parameters(params, max_tilt_deg, speed_factor)
        self.ground_z = 0.0
        start = np.array([float(start_position[0]), float(start_position[1]), self.ground_z])
        c, s = math.cos(yaw), math.sin(yaw)
        resting = RigidBodyState(
            position=start,
            velocity=np.zeros(3),
            rotation=np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
            angular_velocity=np.zeros(3),
            rotor_speeds=np.zeros(4),
        )
        self.vehicle = AttitudeThrustVehicle(params, resting, rate_hz=physics_rate_hz, rng=seed)
        self.home = start.copy()
        self.armed = False
        self.mode: FlightMode = HOLD
        self.on_ground = True
        self._ground_since = 0.0
        self._landed = True  # landing detected (on the ground long enough)
        self._armed_at = 0.0
        self._flew_since_arming = False
        self._hold_position = start.copy()
        self._hold_yaw = yaw
        self._takeoff_altitude = 0.0  # NED z of the takeoff target
        self._takeoff_started = 0.0
        self._takeoff_start_z = 0.0
        self._land_command = 0.0  # m/s NED, Land's commanded descent speed (slewed at VERTICAL_ACCELERATION)
        self._land_command_time = 0.0  # simulated s it was last updated
        #: Simulated time (s) the vehicle first entered Offboard, None before: the companion took control then, and
        #: the companion-link blackouts of [faults.mavlink] count from it.
        self.first_offboard_time: float | None = None
        self._offboard_quaternion: tuple[float, float, float, float] | None = None
        self._offboard_thrust: float | None = None
        self._offboard_trajectory: OffboardTrajectory | None = None
        self._last_setpoint_time = -math.inf
        self.setpoints_received = 0
        self.failsafe_active = False
        self._pending_text: list[tuple[Severity, str]] = []
        self._telemetry_cache: tuple[int, Telemetry] | None = None
        self._ticks = 0
        self._thrust_command = 0.0  # normalised, last sent to the vehicle (for logs)

    # ------------------------------------------------------------------ state
    @property
    def time(self) -> float:
        """Simulated seconds since boot."""
        return self.vehicle.time

    @property
    def state(self) -> RigidBodyState:
        """True rigid-body state."""
        return self.vehicle.state

    @property
    def thrust_command(self) -> float:
        """Normalised collective thrust commanded in the last tick."""
        return self._thrust_command

    @property
    def landed_state(self) -> LandedState:
        if self.on_ground and self._landed:
            return LandedState.ON_GROUND
        if self.mode == TAKEOFF:
            return LandedState.TAKEOFF
        if self.mode == LAND:
            return LandedState.LANDING
        return LandedState.ON_GROUND if self.on_ground else LandedState.IN_AIR

    @property
    def ready_to_arm(self) -> tuple[bool, str]:
        """(ready, reason if not)."""
        if self.time < ARMING_READY_AFTER:
            return False, "Arming denied: estimator not ready"
        if not self.on_ground:
            return False, "Arming denied: not landed"
        if self.mode == LAND or self.mode == TAKEOFF:
            return False, f"Arming denied: not possible in {self.mode.name} mode"
        if self.mode == OFFBOARD and not self.offboard_signal_ok:
            return False, "Arming denied: no offboard signal"
        return True, ""

    @property
    def last_setpoint_time(self) -> float:
        """Simulated time of the last valid offboard setpoint (-inf before the first)."""
        return self._last_setpoint_time

    @property
    def offboard_signal_ok(self) -> bool:
        """Setpoints have arrived within COM_OF_LOSS_T."""
        return self.time - self._last_setpoint_time <= self.parameters.value("COM_OF_LOSS_T")

    def telemetry(self) -> Telemetry:
        """The estimator output for this tick (noise drawn once per tick, shared by all messages)."""
        if self._telemetry_cache is None or self._telemetry_cache[0] != self._ticks:
            position, velocity = self.vehicle.measured_state()
            s = self.vehicle.quadrotor._s
            self._telemetry_cache = (
                self._ticks,
                Telemetry(self.time, position, velocity, (s[6], s[7], s[8], s[9]), np.array(s[10:13])),
            )
        return self._telemetry_cache[1]

    def take_status_texts(self) -> list[tuple[Severity, str]]:
        """STATUSTEXT messages produced since the last call."""
        texts, self._pending_text = self._pending_text, []
        return texts

    def _say(self, severity: Severity, text: str) -> None:
        self._pending_text.append((severity, text))

    # ------------------------------------------------------------- commands
    def arm(self, force: bool = False) -> CommandResult:
        if self.armed:
            return CommandResult.ACCEPTED
        ready, reason = self.ready_to_arm
        if not ready and not force:
            self._say(Severity.CRITICAL, reason)
            return CommandResult.DENIED
        self.armed = True
        self._armed_at = self.time
        self._flew_since_arming = False
        self._landed = self.on_ground
        self._say(Severity.INFO, "Armed by external command")
        return CommandResult.ACCEPTED

    def disarm(self, force: bool = False) -> CommandResult:
        if not self.armed:
            return CommandResult.ACCEPTED
        if not self.on_ground and not force:
            self._say(Severity.CRITICAL, "Disarming denied: not landed")
            return CommandResult.DENIED
        self._disarm("Disarmed by external command")
        return CommandResult.ACCEPTED

    def _disarm(self, text: str) -> None:
        self.armed = False
        self._say(Severity.INFO, text)
        if self.mode in (LAND, TAKEOFF):
            self._set_mode(HOLD)

    def takeoff(self, altitude_above_home: float | None = None) -> CommandResult:
        """Climb to altitude_above_home (m; default MIS_TAKEOFF_ALT) and hold there."""
        if altitude_above_home is not None and not (math.isfinite(altitude_above_home) and 0.5 <= altitude_above_home <= 1000.0):
            self._say(Severity.CRITICAL, f"Takeoff denied: altitude {altitude_above_home!r} m invalid")
            return CommandResult.DENIED
        if not self.armed:
            self._say(Severity.CRITICAL, "Takeoff denied: arm first")
            return CommandResult.DENIED
        if not self.on_ground:
            self._say(Severity.WARNING, "Takeoff denied: already flying")
            return CommandResult.DENIED
        altitude = self.parameters.value("MIS_TAKEOFF_ALT") if altitude_above_home is None else altitude_above_home
        position = self.state.position
        self._hold_position = np.array([position[0], position[1], self.home[2] - altitude])
        self._hold_yaw = self._yaw()
        self._takeoff_altitude = self.home[2] - altitude
        self._takeoff_started = self.time
        self._takeoff_start_z = float(position[2])
        self._set_mode(TAKEOFF)
        return CommandResult.ACCEPTED

    def land(self) -> CommandResult:
        if self.on_ground and self._landed:
            return CommandResult.ACCEPTED
        self._capture_hold()
        self._set_mode(LAND)
        return CommandResult.ACCEPTED

    def set_mode(self, mode: FlightMode) -> CommandResult:
        """DO_SET_MODE to a supported mode, with PX4's preconditions."""
        if mode == self.mode:
            return CommandResult.ACCEPTED
        if mode == OFFBOARD:
            if not self.offboard_signal_ok:
                self._say(Severity.CRITICAL, "Switching to Offboard is currently not possible: no offboard signal")
                return CommandResult.TEMPORARILY_REJECTED
            self._capture_hold()  # heading kept by trajectory setpoints that give no yaw
            self._set_mode(OFFBOARD)
            return CommandResult.ACCEPTED
        if mode == TAKEOFF:
            return self.takeoff()
        if mode == LAND:
            return self.land()
        self._capture_hold()
        self._set_mode(mode)
        return CommandResult.ACCEPTED

    def offboard_trajectory(self, setpoint: OffboardTrajectory) -> None:
        """Store an already validated position/velocity setpoint (refreshes the offboard signal).

        ValueError when nothing is given or a value is not finite."""
        parts = [setpoint.position, setpoint.velocity, setpoint.acceleration]
        if all(part is None for part in parts):
            raise ValueError("trajectory setpoint without position, velocity or acceleration")
        values = [v for part in parts if part is not None for v in part] + ([setpoint.yaw] if setpoint.yaw is not None else [])
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"non-finite trajectory setpoint {setpoint!r}")
        self._offboard_trajectory = setpoint
        self._last_setpoint_time = self.time
        self.setpoints_received += 1

    def offboard_setpoint(self, setpoint: OffboardAttitude) -> None:
        """Store an already validated attitude/thrust setpoint; it refreshes the offboard signal
        even outside offboard mode (PX4 needs the stream before it allows the switch).

        ValueError for a thrust outside [0, 1] or a quaternion that is not unit to 1e-3.
        """
        if setpoint.thrust is not None and not 0.0 <= setpoint.thrust <= 1.0:
            raise ValueError(f"normalised thrust {setpoint.thrust!r} outside [0, 1]")
        if setpoint.quaternion is not None:
            norm = math.sqrt(sum(c * c for c in setpoint.quaternion))
            if not abs(norm - 1.0) < 1e-3:
                raise ValueError(f"setpoint quaternion {setpoint.quaternion!r} is not unit")
        if setpoint.quaternion is not None:
            self._offboard_quaternion = setpoint.quaternion
        if setpoint.thrust is not None:
            self._offboard_thrust = setpoint.thrust
        self._offboard_trajectory = None  # the latest kind of setpoint is the one flown
        self._last_setpoint_time = self.time
        self.setpoints_received += 1

    def _set_mode(self, mode: FlightMode) -> None:
        if mode != self.mode:
            if mode == LAND:
                self._land_command = float(self.vehicle.quadrotor._s[5])  # from the vertical speed it has
                self._land_command_time = self.time
            self.mode = mode
            self._say(Severity.INFO, f"Flight mode: {mode.name}")
        if mode == OFFBOARD:
            self.failsafe_active = False
            if self.first_offboard_time is None:
                self.first_offboard_time = self.time

    def _capture_hold(self) -> None:
        position = self.state.position
        if self.on_ground:
            position[2] = self.ground_z
        self._hold_position = position
        self._hold_yaw = self._yaw()

    def _yaw(self) -> float:
        """Heading of the true attitude, rad (ZYX yaw). Read on every tick (ground contact,
        control output), so written out on the quaternion instead of going through scipy."""
        w, x, y, z = self.vehicle.quadrotor._s[6:10]
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    # ------------------------------------------------------------ the loop
    def tick(self) -> None:
        """Advance one tick: mode logic, control output, physics, ground contact."""
        now = self.time
        self._mode_logic(now)
        attitude_offboard = self.mode == OFFBOARD and self._offboard_trajectory is None
        if attitude_offboard or not self.armed or self._ticks % self._control_divider == 0:
            quaternion, thrust = self._control_output(now)
            self._thrust_command = thrust
            self.vehicle.set_attitude_target_quaternion(quaternion, thrust * self.params.max_total_thrust)
        self.vehicle.advance(self.tick_period)
        self._ground_contact()
        self._ticks += 1

    def run(self, duration: float) -> None:
        """Tick for `duration` simulated seconds (rounded to whole ticks)."""
        for _ in range(int(round(duration / self.tick_period))):
            self.tick()

    def _mode_logic(self, now: float) -> None:
        params = self.parameters
        if self.mode == OFFBOARD and not self.offboard_signal_ok:
            action = int(params.value("COM_OBL_RC_ACT"))
            self.failsafe_active = True
            self._capture_hold()
            if action == OFFBOARD_LOSS_LAND:
                self._say(Severity.CRITICAL, "Failsafe activated: offboard signal lost, landing")
                self._set_mode(LAND)
            elif action == OFFBOARD_LOSS_HOLD:
                self._say(Severity.CRITICAL, "Failsafe activated: offboard signal lost, holding position (Hold)")
                self._set_mode(HOLD)
            else:
                self._say(Severity.CRITICAL, "Failsafe activated: offboard signal lost, holding position (Position)")
                self._set_mode(POSITION)
        if self.mode == TAKEOFF and self.armed:
            z = float(self.vehicle.quadrotor._s[2])
            if z <= self._takeoff_altitude + TAKEOFF_ALTITUDE_TOLERANCE:
                self._say(Severity.INFO, "Takeoff complete")
                self._set_mode(HOLD)
        if self.armed and self.on_ground:
            if not self._landed and now - self._ground_since >= LAND_DETECT_TIME:
                self._landed = True
                self._say(Severity.INFO, "Landing detected")
            if self._landed:
                if self._flew_since_arming:
                    limit = params.value("COM_DISARM_LAND")
                    since = self._ground_since + LAND_DETECT_TIME
                    reason = "Disarmed by landing"
                else:
                    limit = params.value("COM_DISARM_PRFLT")
                    since = self._armed_at
                    reason = "Disarmed by auto preflight disarming"
                if limit > 0.0 and now - since >= limit:
                    self._disarm(reason)

    def _limits(self) -> ControlLimits:
        return ControlLimits(
            hover_thrust=self.parameters.value("MPC_THR_HOVER"),
            max_tilt=math.radians(self.parameters.value("MPC_TILTMAX_AIR")),
            max_speed_xy=self.parameters.value("MPC_XY_VEL_MAX"),
            gravity=self.params.gravity,
            thrust_xy_margin=self.parameters.value("MPC_THR_XY_MARG"),
        )

    def _control_output(self, now: float) -> tuple[tuple[float, float, float, float], float]:
        """(attitude quaternion w,x,y,z, normalised thrust) for the attitude controller."""
        s = self.vehicle.quadrotor._s
        if not self.armed:
            self.position_controller.reset()
            return _level_quaternion(self._yaw()), 0.0
        if self.mode == OFFBOARD and self._offboard_trajectory is not None:
            return self._fly(self._trajectory_setpoint(self._offboard_trajectory))
        if self.mode == OFFBOARD:
            self.position_controller.reset()  # restarts empty when position control comes back
            quaternion = self._offboard_quaternion if self._offboard_quaternion is not None else (s[6], s[7], s[8], s[9])
            thrust = self._offboard_thrust if self._offboard_thrust is not None else 0.0
            return quaternion, thrust
        idle = self.on_ground and (self._landed or self.mode == LAND)
        if idle and self.mode != TAKEOFF:
            self.position_controller.reset()
            return _level_quaternion(self._yaw()), 0.0
        if self.on_ground:
            self.position_controller.reset()  # no integrating against the ground while taking off
        return self._fly(self._automatic_setpoint(now))

    def _automatic_setpoint(self, now: float) -> TrajectorySetpoint:
        """The setpoint of Takeoff (a trapezoidal climb at MPC_TKO_SPEED), Land (down over the held point at
        `land_descent_speed`) and Hold/Position (the held point)."""
        position = self._hold_position.copy()
        velocity = np.full(3, np.nan)
        acceleration = np.full(3, np.nan)
        if self.mode == TAKEOFF:
            climbed, speed, accel = trapezoidal_profile(
                self._takeoff_start_z - self._takeoff_altitude, self.parameters.value("MPC_TKO_SPEED"),
                VERTICAL_ACCELERATION, now - self._takeoff_started)
            position[2], velocity[2], acceleration[2] = self._takeoff_start_z - climbed, -speed, -accel
        elif self.mode == LAND:
            # From the vertical speed Land started with to the descent speed of the height, at VERTICAL_ACCELERATION.
            position[2] = np.nan
            wanted = self.land_descent_speed(-float(self.vehicle.quadrotor._s[2]))
            change = VERTICAL_ACCELERATION * max(0.0, now - self._land_command_time)
            gap = wanted - self._land_command
            self._land_command_time = now
            if abs(gap) <= change:
                self._land_command = wanted
            else:
                self._land_command += math.copysign(change, gap)
                acceleration[2] = math.copysign(VERTICAL_ACCELERATION, gap)
            velocity[2] = self._land_command
        return TrajectorySetpoint(position, velocity, acceleration, self._hold_yaw)

    def land_descent_speed(self, height: float) -> float:
        """Land's descent speed (m/s, down) at `height` m above the ground, as PX4's slow landing: MPC_Z_V_AUTO_DN
        above MPC_LAND_ALT1, MPC_LAND_SPEED below MPC_LAND_ALT2, linear in the height between the two."""
        value = self.parameters.value
        fast, slow = value("MPC_Z_V_AUTO_DN"), value("MPC_LAND_SPEED")
        low, high = value("MPC_LAND_ALT2"), value("MPC_LAND_ALT1")
        if height <= low or high <= low:
            return slow
        if height >= high:
            return fast
        return slow + (fast - slow) * (height - low) / (high - low)

    def _trajectory_setpoint(self, setpoint: OffboardTrajectory) -> TrajectorySetpoint:
        """An offboard position/velocity/acceleration setpoint; yaw held when not given."""
        def given(part):
            return np.full(3, np.nan) if part is None else np.array(part, dtype=float)

        return TrajectorySetpoint(given(setpoint.position), given(setpoint.velocity), given(setpoint.acceleration),
                                  self._hold_yaw if setpoint.yaw is None else setpoint.yaw)

    def _fly(self, setpoint: TrajectorySetpoint) -> tuple[tuple[float, float, float, float], float]:
        """One step of the position controller on the true state (the estimate is assumed perfect)."""
        s = self.vehicle.quadrotor._s
        output = self.position_controller.update(
            self._control_divider * self.tick_period, np.array(s[0:3]), np.array(s[3:6]),
            self.vehicle.quadrotor.acceleration, setpoint, self._limits())
        return output.quaternion, output.thrust

    def _ground_contact(self) -> None:
        """Flat ground at z = ground_z: no penetration; touching down stops the vehicle level."""
        plant = self.vehicle.quadrotor
        s = plant._s
        if s[2] >= self.ground_z:
            if not self.on_ground:
                self.on_ground = True
                self._ground_since = self.time
            state = plant.state
            c, sn = math.cos(self._yaw()), math.sin(self._yaw())
            plant.state = RigidBodyState(
                position=np.array([s[0], s[1], self.ground_z]),
                velocity=np.zeros(3),
                rotation=np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]),
                angular_velocity=np.zeros(3),
                rotor_speeds=state.rotor_speeds,
            )
        elif self.on_ground and s[2] < self.ground_z - LIFTOFF_HEIGHT:
            self.on_ground = False
            self._landed = False
            if self.armed:
                self._flew_since_arming = True
            self._say(Severity.INFO, "Takeoff detected")


def _level_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Level attitude at heading yaw: rotation about NED z."""
    return (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))
