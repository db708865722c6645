"""Cooperative guidance for several pursuers around one target.

Laws:
- `CircumnavigationGuidance`: seed 002 eq. (10) (with the target-velocity feed-forward of its
  Kalman-enhanced law (33)), extended to 3-D.
- `StandoffTrackingGuidance`: seed 004 TOGVF, eqs. (26)-(31) for one pursuer, (32)-(34) for a moving
  target and (36)-(40) for the phase coordination, generalised to N pursuers.
- `SeparationFilter`: pursuer-pursuer separation applied to any acceleration command.
- `neighbours_make_range_observable`: the triangulation-baseline test that switches HNG weaving off.

Conventions. Local NED, z down, SI units, angles in radians. Both orbits lie in the horizontal plane
through the target (shifted vertically by a configurable altitude offset) and are flown
COUNTER-CLOCKWISE SEEN FROM ABOVE: north -> west -> south -> east. In NED (z down) that is a negative
rotation about +z (a positive rotation about the up axis). The orbit phase of a pursuer is
psi = atan2(north offset, east offset) of its position relative to the target: 0 when the pursuer is
east of the target, pi/2 north, pi west; psi grows as the pursuer flies its orbit. The seeds' planar
(x, y) frames are mapped to (east, north), which keeps their counter-clockwise sense.

Both guidance laws produce a desired velocity u (target-velocity estimate + the seed's relative
velocity law) and command an acceleration a = k_v (u - v) + du/dt, saturated to a maximum norm. du/dt
is the change of the law's own output when every vehicle (own, target, neighbours) moves at constant
velocity by +-tau (a central-difference convective derivative), plus the target
acceleration when one is given. With it, the velocity error e = v - u obeys e' = -k_v e whenever the
command is not saturated, so the pursuer's path tends to that of the single-integrator kinematics
p' = u that the seeds analyse. Both classes set `includes_range_control = True`: they are complete
commands (they regulate the range themselves).

Numpy only: no I/O, no clock, no configuration library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from companion.core._jit import jit, python_function
from companion.core.geometry import all_finite, norm
from companion.core.messages import NeighbourState, fast_frozen, once_property

TWO_PI = 2.0 * math.pi
_EPS = 1e-9


# --------------------------------------------------------------------------------------------------
# Context and planar helpers
# --------------------------------------------------------------------------------------------------

def _finite_vector(value: object, name: str) -> np.ndarray:
    if type(value) is np.ndarray and value.dtype == _FLOAT64 and value.shape == (3,):
        # np.asarray(value, dtype=float) is value itself: only its finiteness to check
        x, y, z = value.tolist()
        if math.isfinite(x) and math.isfinite(y) and math.isfinite(z):
            return value
    vector = np.asarray(value, dtype=float)
    if vector.shape != (3,) or not all_finite(vector):
        raise ValueError(f"{name} must be a finite vector of shape (3,), got {value!r}")
    return vector


_FLOAT64 = np.dtype(np.float64)


@dataclass(frozen=True)
class CooperativeContext:
    """What a cooperative law needs at one control tick.

    time: s. own_position m, own_velocity m/s: this pursuer, shape (3,) NED. target_position m,
    target_velocity m/s: the target ESTIMATE the pipeline holds, shape (3,). neighbours: the fresh
    neighbours (the caller filters freshness and range), possibly empty. target_acceleration: optional
    estimated target acceleration, m/s^2, shape (3,), used as a feed-forward only.
    Construction rejects non-finite or wrongly shaped vectors with ValueError.
    """

    time: float
    own_position: np.ndarray
    own_velocity: np.ndarray
    target_position: np.ndarray
    target_velocity: np.ndarray
    neighbours: tuple[NeighbourState, ...] = ()
    target_acceleration: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not math.isfinite(float(self.time)):
            raise ValueError(f"time must be finite, got {self.time!r}")
        fields = self.__dict__  # the checked values stored as object.__setattr__ would, without its cost
        for name in ("own_position", "own_velocity", "target_position", "target_velocity"):
            fields[name] = _finite_vector(fields[name], name)
        if self.target_acceleration is not None:
            fields["target_acceleration"] = _finite_vector(self.target_acceleration, "target_acceleration")
        neighbours = tuple(self.neighbours)
        for neighbour in neighbours:
            if not isinstance(neighbour, NeighbourState):
                raise ValueError(f"neighbours must be NeighbourState, got {type(neighbour).__name__}")
        fields["neighbours"] = neighbours

    def advanced(self, horizon: float) -> "CooperativeContext":
        """Every vehicle moved at constant velocity by `horizon` s (may be negative; velocities unchanged).
        What the constructors would build, without checking again what this context's construction checked:
        only the moved positions and times (ValueError if one overflows to infinity or the horizon is not finite)."""
        time = self.time + horizon
        own_position = self.own_position + horizon * self.own_velocity
        target_position = self.target_position + horizon * self.target_velocity
        neighbours = tuple(fast_frozen(NeighbourState, ident=n.ident, time=n.time + horizon,
                                       position=n.position + horizon * n.velocity, velocity=n.velocity)
                           for n in self.neighbours)
        if not (math.isfinite(float(time)) and all_finite(own_position) and all_finite(target_position)
                and all(math.isfinite(float(n.time)) and all_finite(n.position) for n in neighbours)):
            raise ValueError(f"the context advanced by {horizon!r} s is not finite")
        return fast_frozen(CooperativeContext, time=time, own_position=own_position, own_velocity=self.own_velocity,
                           target_position=target_position, target_velocity=self.target_velocity,
                           neighbours=neighbours, target_acceleration=self.target_acceleration)

    @once_property
    def neighbour_positions(self) -> np.ndarray:
        """The neighbours' positions, m, shape (len(neighbours), 3) (the laws' kernels take arrays)."""
        return np.array([n.position for n in self.neighbours], dtype=float).reshape(len(self.neighbours), 3)

    @once_property
    def neighbour_velocities(self) -> np.ndarray:
        """The neighbours' velocities, m/s, shape (len(neighbours), 3)."""
        return np.array([n.velocity for n in self.neighbours], dtype=float).reshape(len(self.neighbours), 3)


def _planar(vector: np.ndarray) -> np.ndarray:
    """NED (3,) -> horizontal (east, north), shape (2,): a frame whose positive rotation is CCW seen from above."""
    return np.array([vector[1], vector[0]], dtype=float)


def _ned(planar: np.ndarray, down: float = 0.0) -> np.ndarray:
    """Horizontal (east, north) (2,) plus a down component -> NED (3,)."""
    return np.array([planar[1], planar[0], down], dtype=float)


def _rot90(planar: np.ndarray) -> np.ndarray:
    """Rotate a horizontal (east, north) vector by +90 degrees, i.e. counter-clockwise seen from above."""
    return np.array([-planar[1], planar[0]], dtype=float)


def phase(own_position: np.ndarray, target_position: np.ndarray) -> float:
    """Orbit phase of a pursuer about the target, rad in (-pi, pi].

    psi = atan2(north offset, east offset) of own_position - target_position (m, shape (3,) NED): 0 east
    of the target, pi/2 north; it increases counter-clockwise seen from above (the orbit direction).
    Directly above or below the target (zero horizontal offset) it is 0 by convention.
    """
    offset = np.asarray(own_position, dtype=float) - np.asarray(target_position, dtype=float)
    return math.atan2(float(offset[0]), float(offset[1]))


@jit
def _ccw_gap_kernel(from_phase: float, to_phase: float) -> float:
    """Counter-clockwise angle from one phase to another, rad in [0, 2 pi)."""
    gap = (to_phase - from_phase) % TWO_PI
    return 0.0 if gap >= TWO_PI else gap  # float % can return 2 pi for a tiny negative difference


_ccw_gap = python_function(_ccw_gap_kernel)  # the same function, without numba's dispatch, for Python callers


def phase_gaps(own_phase: float, neighbour_phases: list[float] | np.ndarray) -> tuple[float, float] | None:
    """(gap ahead, gap behind), rad, of a pursuer at own_phase among its neighbours' phases.

    gap ahead = Delta_i of seed 002: the CCW angle from the pursuer to the nearest neighbour ahead;
    gap behind: the CCW angle from the nearest neighbour behind to the pursuer. A neighbour at exactly
    the same phase counts as 0 ahead (seed 002's Delta_i(t) = 0 for a 0+ angle). None without neighbours.
    """
    phases = list(neighbour_phases)
    if not phases:
        return None
    ahead = min(_ccw_gap(own_phase, p) for p in phases)
    behind = min(_ccw_gap(p, own_phase) for p in phases)
    return ahead, behind


def _context_gaps(context: "CooperativeContext") -> tuple[float, float] | None:
    """`phase_gaps` of this pursuer among the context's neighbours, about the estimated target."""
    own = phase(context.own_position, context.target_position)
    return phase_gaps(own, [phase(n.position, context.target_position) for n in context.neighbours])


def phase_spacing_errors(phases: np.ndarray | list[float]) -> np.ndarray:
    """Error of each consecutive CCW gap from 2 pi / N, rad, shape (N,).

    phases: rad, shape (N,), any order and wrap. The phases are sorted CCW; gap k runs from sorted phase
    k to sorted phase k + 1 (the last gap wraps round to the first). The errors sum to zero. N = 1 gives
    [0.0] (one pursuer, one gap of 2 pi); N = 0 an empty array. The studies report the RMS of these
    errors in degrees as `phase_spacing_error_deg_rms`.
    """
    values = np.asarray(phases, dtype=float).reshape(-1)
    if values.size == 0:
        return np.zeros(0)
    return phase_spacing_error_rows(values.reshape(1, -1))[0]


def phase_spacing_error_rows(phases: np.ndarray) -> np.ndarray:
    """`phase_spacing_errors` of each row of phases (rad, shape (T, N), N >= 1), shape (T, N): row t is
    phase_spacing_errors(phases[t]), the same numbers (elementwise operations and a sort along the rows).
    ValueError if a phase is not finite."""
    values = np.asarray(phases, dtype=float)
    if not np.all(np.isfinite(values)):
        raise ValueError("phases must be finite")
    ordered = np.sort(np.mod(values, TWO_PI), axis=1)
    gaps = np.diff(np.concatenate([ordered, ordered[:, :1] + TWO_PI], axis=1), axis=1)
    return gaps - TWO_PI / values.shape[1]


def _saturate(vector: np.ndarray, limit: float) -> np.ndarray:
    length = norm(vector)
    return vector if length <= limit else vector * (limit / length)


def _tracking_acceleration(desired_velocity, context: CooperativeContext, velocity_gain: float,
                           feedforward_horizon: float, max_acceleration: float) -> np.ndarray:
    """a = k_v (u - v) + du/dt (+ target acceleration), saturated to max_acceleration (m/s^2, shape (3,)).

    desired_velocity: the law, (context, horizon) -> u (m/s, (3,)) of the context advanced by horizon s
    (`CooperativeContext.advanced`; horizon 0: the context itself). du/dt is the finite difference of u over a
    constant-velocity advance of every vehicle by feedforward_horizon s (0 disables it). The arithmetic:
    _tracking_kernel.
    """
    u = desired_velocity(context, 0.0)
    ahead = behind = u
    if feedforward_horizon > 0.0:
        ahead, behind = desired_velocity(context, feedforward_horizon), desired_velocity(context, -feedforward_horizon)
    command = np.empty(3)
    _tracking_kernel(u, ahead, behind, context.own_velocity, velocity_gain, feedforward_horizon,
                     _NO_ACCELERATION if context.target_acceleration is None else context.target_acceleration,
                     max_acceleration, command)
    return command


_NO_ACCELERATION = np.empty(0)  # _tracking_kernel's "no target acceleration"


@jit
def _tracking_kernel(u: np.ndarray, ahead: np.ndarray, behind: np.ndarray, own_velocity: np.ndarray,
                     velocity_gain: float, feedforward_horizon: float, target_acceleration: np.ndarray,
                     max_acceleration: float, out: np.ndarray) -> None:
    """The velocity-tracking command of the module docstring into out (m/s^2, (3,)):
    a = k_v (u - v) + (u(+tau) - u(-tau)) / (2 tau) + a^_T, saturated to max_acceleration.

    u: the law's desired velocity now, ahead/behind: with every vehicle moved at constant velocity by +tau / -tau
    (tau = feedforward_horizon s; not used when tau is 0), m/s (3,); own_velocity m/s (3,); target_acceleration
    m/s^2, (3,), or empty for none. Central difference: a one-sided step leaves the orbit (the chord lies outside
    the circle) and biases the radius; the symmetric one cancels that to second order. The arithmetic as it was
    written over numpy arrays (elementwise; the norm as sqrt(a @ a)), so compiled or not it gives the same bits."""
    command = np.empty(3)
    for k in range(3):
        command[k] = velocity_gain * (u[k] - own_velocity[k])
    if feedforward_horizon > 0.0:
        for k in range(3):
            command[k] = command[k] + (ahead[k] - behind[k]) / (2.0 * feedforward_horizon)
    if target_acceleration.shape[0] != 0:
        for k in range(3):
            command[k] = command[k] + target_acceleration[k]
    length = math.sqrt(command @ command)  # saturated to max_acceleration (_saturate)
    if length <= max_acceleration:
        for k in range(3):
            out[k] = command[k]
    else:
        scale = max_acceleration / length
        for k in range(3):
            out[k] = command[k] * scale


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")


def _check_non_negative(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")


# --------------------------------------------------------------------------------------------------
# Seed 002: circumnavigation with equal phase spacing
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CircumnavigationGuidance:
    """Distributed circumnavigation with equal phase spacing, seed 002 eq. (10) extended to 3-D.

    Horizontal part (seed 002 eq. (10) in the horizontal plane through the target):
        u_h = g1 (D - D*) phi + g2 D* (alpha + g3 Delta) phi_bar
    D: horizontal distance to the target estimate, m; phi: horizontal unit vector from the pursuer to
    the target; phi_bar: phi rotated by pi/2 clockwise seen from above, so alpha > 0 makes the pursuer
    orbit counter-clockwise seen from above (north -> west -> south -> east; see the module docstring
    for the phase convention in NED). Delta: seed 002's Delta_i, the CCW angle in the orbit plane from
    this pursuer to the nearest neighbour ahead; without neighbours Delta = 0 (seed 002: N_i empty),
    i.e. plain circumnavigation at tangential speed g2 D* alpha. With n pursuers the gaps converge to
    2 pi / n (seed 002 Theorem 2). The orbit radius D* is the HORIZONTAL radius; the 3-D range on the
    orbit is sqrt(D*^2 + altitude_offset^2).
    Vertical part (the 3-D extension): u_down = k_z (z_target - altitude_offset - z), holding the
    altitude offset above the target (altitude_offset m, positive = above the target).
    The desired velocity is u = v^_T + u_h + u_down e_z: the target-velocity feed-forward of seed 002
    eq. (33) (the Kalman-enhanced law), with the pipeline's target estimate in place of the seed's
    estimator. The acceleration is the velocity-tracking law of the module docstring.

    Parameters: desired_radius D* m; g1 1/s; g2 1/s; g3 1/rad; alpha (dimensionless). Seed 002 uses
    D* = 5, g1 = 1.2, g2 = 1, g3 = 0.4, alpha = 1: an orbit at 7.5 m/s on 5 m (11 m/s^2 centripetal
    for 5 pursuers), beyond our multirotor's ~6.9 m/s^2 (35 deg tilt). The defaults fit it: D* = 8 m
    (the paper's r_d), g1 = 0.5, g2 = 0.3, g3 = 0.4, alpha = 1, max_acceleration 6 m/s^2: 4.4 m/s and
    2.4 m/s^2 on the orbit for 3 pursuers, 3.6 m/s and 1.6 m/s^2 for 5. altitude_offset m;
    vertical_gain k_z 1/s; velocity_gain k_v 1/s; max_acceleration m/s^2; max_relative_speed: cap on
    |u - v^_T|, m/s (inf = none, as in the seed); feedforward_horizon tau, s (0 disables du/dt);
    max_turn_acceleration a_turn, m/s^2 (default max_acceleration / 2; inf = the seed's law unchanged):
    the tangential speed is capped at sqrt(a_turn D), our addition for vehicles with bounded
    acceleration. Without it a pursuer with a large gap ahead asks for an orbit speed it cannot turn
    with, saturates, and can circle outside the orbit indefinitely (seen with 3 pursuers, D* = 8 m,
    g2 = 0.5, 6 m/s^2). The cap keeps the speed monotone in Delta, so the spacing still converges, more slowly
    while it binds, PROVIDED it does not bind on the converged orbit: choose
    (g2 D* (alpha + g3 2 pi / N))^2 / D* < a_turn (if it binds there, every pursuer flies at the cap
    whatever its gap and the spacing stops converging).
    """

    includes_range_control: ClassVar[bool] = True

    desired_radius: float = 8.0
    g1: float = 0.5
    g2: float = 0.3
    g3: float = 0.4
    alpha: float = 1.0
    altitude_offset: float = 0.0
    vertical_gain: float = 1.0
    velocity_gain: float = 2.0
    max_acceleration: float = 6.0
    max_relative_speed: float = math.inf
    feedforward_horizon: float = 0.05
    max_turn_acceleration: float | None = None
    _turn_acceleration: float = field(init=False, repr=False, default=0.0)

    def __post_init__(self) -> None:
        turn = 0.5 * self.max_acceleration if self.max_turn_acceleration is None else float(self.max_turn_acceleration)
        if not turn > 0.0:
            raise ValueError("max_turn_acceleration must be > 0")
        object.__setattr__(self, "_turn_acceleration", turn)
        _check_positive(desired_radius=self.desired_radius, g1=self.g1, g2=self.g2, alpha=self.alpha,
                        vertical_gain=self.vertical_gain, velocity_gain=self.velocity_gain,
                        max_acceleration=self.max_acceleration)
        _check_non_negative(g3=self.g3, feedforward_horizon=self.feedforward_horizon)
        if not math.isfinite(self.altitude_offset):
            raise ValueError("altitude_offset must be finite")
        if not self.max_relative_speed > 0.0:
            raise ValueError("max_relative_speed must be > 0")

    @staticmethod
    def phase(own_position: np.ndarray, target_position: np.ndarray) -> float:
        """Orbit phase, rad; see the module-level `phase`."""
        return phase(own_position, target_position)

    def spacing_angle(self, context: CooperativeContext) -> float:
        """Delta_i of seed 002, rad in [0, 2 pi): CCW angle to the nearest neighbour ahead; 0 without neighbours."""
        gaps = _context_gaps(context)
        return 0.0 if gaps is None else gaps[0]

    def desired_velocity(self, context: CooperativeContext) -> np.ndarray:
        """u = v^_T + seed 002 eq. (10) (horizontal) + vertical hold, m/s, shape (3,) NED
        (_circumnavigation_velocity_kernel)."""
        return self._velocity_after(context, 0.0)

    def _velocity_after(self, context: CooperativeContext, horizon: float) -> np.ndarray:
        """desired_velocity(context.advanced(horizon)), the advance done in the kernel (horizon s; 0: none)."""
        velocity = np.empty(3)
        if not _circumnavigation_velocity_kernel(_vehicles(context), float(horizon), self._law_terms(), velocity):
            raise ValueError(f"the context advanced by {horizon!r} s is not finite")
        return velocity

    def _law_terms(self) -> tuple[float, ...]:
        """(g1, g2, g3, alpha, D*, a_turn, altitude_offset, k_z, max_relative_speed): the law's parameters as
        _circumnavigation_velocity_kernel takes them."""
        return (self.g1, self.g2, self.g3, self.alpha, self.desired_radius, self._turn_acceleration,
                self.altitude_offset, self.vertical_gain, self.max_relative_speed)

    def acceleration(self, context: CooperativeContext) -> np.ndarray:
        """Acceleration command, m/s^2, shape (3,) NED: k_v (u - v) + du/dt (+ a^_T), norm <= max_acceleration
        (_tracking_acceleration's, in one kernel: _circumnavigation_acceleration_kernel)."""
        command = np.empty(3)
        if not _circumnavigation_acceleration_kernel(
                _vehicles(context),
                _NO_ACCELERATION if context.target_acceleration is None else context.target_acceleration,
                self._law_terms(), (self.velocity_gain, self.feedforward_horizon, self.max_acceleration), command):
            raise ValueError(f"the context advanced by +-{self.feedforward_horizon!r} s is not finite")
        return command


def _vehicles(context: CooperativeContext) -> tuple:
    """(own_position, own_velocity, target_position, target_velocity, neighbour_positions, neighbour_velocities) of
    `context`: the vehicles as the circumnavigation kernels take them."""
    return (context.own_position, context.own_velocity, context.target_position, context.target_velocity,
            context.neighbour_positions, context.neighbour_velocities)


@jit
def _circumnavigation_acceleration_kernel(vehicles: tuple, target_acceleration: np.ndarray, law: tuple,
                                          tracking: tuple, out: np.ndarray) -> bool:
    """CircumnavigationGuidance.acceleration into out (m/s^2, (3,)): _tracking_acceleration over
    _circumnavigation_velocity_kernel (u now, and with every vehicle moved by +-feedforward_horizon s when it is
    > 0), then _tracking_kernel. False (out unset) where a moved context is not finite. vehicles and law: as
    _circumnavigation_velocity_kernel takes them; target_acceleration: (3,), or empty for none; tracking =
    (velocity_gain k_v 1/s, feedforward_horizon tau s, max_acceleration m/s^2)."""
    velocity_gain, feedforward_horizon, max_acceleration = tracking
    own_velocity = vehicles[1]
    u, ahead, behind = np.empty(3), np.empty(3), np.empty(3)
    if not _circumnavigation_velocity_kernel(vehicles, 0.0, law, u):
        return False
    if feedforward_horizon > 0.0:
        for horizon, velocity in ((feedforward_horizon, ahead), (-feedforward_horizon, behind)):
            if not _circumnavigation_velocity_kernel(vehicles, horizon, law, velocity):
                return False
    _tracking_kernel(u, ahead, behind, own_velocity, velocity_gain, feedforward_horizon, target_acceleration,
                     max_acceleration, out)
    return True


@jit
def _circumnavigation_velocity_kernel(vehicles: tuple, horizon: float, law: tuple, out: np.ndarray) -> bool:
    """CircumnavigationGuidance's desired velocity u = v^_T + seed 002 eq. (10) (horizontal) + vertical hold,
    m/s, into out (3,), for every vehicle moved at constant velocity by `horizon` s first (as
    CooperativeContext.advanced; not moved when horizon is 0). False (out unset) if a moved position is not
    finite (where `advanced` raises). vehicles = (own_position, own_velocity, target_position, target_velocity,
    neighbour_positions, neighbour_velocities) (`_vehicles`): positions m, velocities m/s, NED, float64 (3,); the
    neighbours' (k, 3). law = (g1, g2, g3, alpha, desired_radius, turn_acceleration, altitude_offset,
    vertical_gain, max_relative_speed) (CircumnavigationGuidance._law_terms).

    D = |planar offset to the target|; phi its unit vector (phase 0, east, directly above the target);
    phi_bar = phi rotated by pi/2 clockwise seen from above; Delta = the CCW gap to the nearest neighbour ahead
    (0 without neighbours); tangential speed g2 D* (alpha + g3 Delta), capped at sqrt(a_turn max(D, eps));
    u_h = g1 (D - D*) phi + tangential phi_bar; u_down = k_z (z_T - altitude_offset - z); |u - v^_T| capped at
    max_relative_speed. The arithmetic of the class's law in the order it was written with numpy arrays (norms as
    sqrt(x @ x), elementwise products and sums), so compiled or not it gives the same bits."""
    own_position, own_velocity, target_position, target_velocity, neighbour_positions, neighbour_velocities = vehicles
    (g1, g2, g3, alpha, desired_radius, turn_acceleration, altitude_offset, vertical_gain,
     max_relative_speed) = law
    own = own_position
    target = target_position
    neighbours = neighbour_positions
    if horizon != 0.0:
        own = own_position + horizon * own_velocity
        target = target_position + horizon * target_velocity
        neighbours = neighbour_positions + horizon * neighbour_velocities
        for k in range(3):
            if not (math.isfinite(own[k]) and math.isfinite(target[k])):
                return False
        for i in range(neighbours.shape[0]):
            for k in range(3):
                if not math.isfinite(neighbours[i, k]):
                    return False
    offset = np.empty(2)  # planar (east, north), pursuer -> target
    offset[0] = target[1] - own[1]
    offset[1] = target[0] - own[0]
    distance = math.sqrt(offset @ offset)
    # Directly above the target the bearing's horizontal part is undefined: take phase 0 (east).
    if distance > _EPS:
        phi_east = offset[0] / distance
        phi_north = offset[1] / distance
    else:
        phi_east = -1.0
        phi_north = 0.0
    # phi_bar: phi rotated by pi/2 clockwise seen from above, (phi_north, -phi_east)
    delta = 0.0  # Delta_i of seed 002 (spacing_angle): the CCW gap to the nearest neighbour ahead, phases about the target
    if neighbours.shape[0] > 0:
        own_phase = math.atan2(own[0] - target[0], own[1] - target[1])
        for i in range(neighbours.shape[0]):
            gap = _ccw_gap_kernel(own_phase, math.atan2(neighbours[i, 0] - target[0], neighbours[i, 1] - target[1]))
            if i == 0 or gap < delta:  # min() over the neighbours, the first of equal ones
                delta = gap
    tangential = g2 * desired_radius * (alpha + g3 * delta)
    # Not in the seed (a kinematic law): cap the orbit speed where its centripetal acceleration v^2 / D
    # would exceed the turn budget, so a vehicle with bounded acceleration can still follow the field.
    cap = math.sqrt(turn_acceleration * (_EPS if _EPS > distance else distance))
    if cap < tangential:
        tangential = cap
    radial = g1 * (distance - desired_radius)
    relative = np.empty(3)  # NED: (north, east) of the planar u_h, then down
    relative[0] = radial * phi_north + tangential * -phi_east
    relative[1] = radial * phi_east + tangential * phi_north
    relative[2] = vertical_gain * ((target[2] - altitude_offset) - own[2])
    length = math.sqrt(relative @ relative)
    if not length <= max_relative_speed:
        scale = max_relative_speed / length
        for k in range(3):
            relative[k] = relative[k] * scale
    for k in range(3):
        out[k] = target_velocity[k] + relative[k]
    return True


# --------------------------------------------------------------------------------------------------
# Seed 004: TOGVF standoff tracking
# --------------------------------------------------------------------------------------------------

def tangent_point(offset: np.ndarray, radius: float) -> np.ndarray:
    """CCW tangent point on a circle, seed 004 eq. (26), in a horizontal (east, north) frame.

    offset: the point relative to the circle centre, m, shape (2,), |offset| = r >= radius.
    Returns the tangent point relative to the centre, m, shape (2,):
        T = (R^2 / r^2) offset + (R / r^2) sqrt(r^2 - R^2) rot90(offset)
    i.e. the upper signs of eq. (26) (x_tan with "-", y_tan with "+"), the one from which the circle
    is flown counter-clockwise seen from above.
    """
    r2 = float(offset @ offset)
    root = math.sqrt(max(r2 - radius * radius, 0.0))
    return (radius * radius / r2) * offset + (radius * root / r2) * _rot90(offset)


@dataclass(frozen=True)
class StandoffTrackingGuidance:
    """Seed 004's time-optimal guidance vector field (TOGVF) with phase coordination, 3-D.

    Horizontal direction (relative to the target, flown counter-clockwise seen from above; the seed
    picks the direction from the current velocity, a fixed direction is needed for coordination):
    - outside the standoff circle (r > R + band): fly towards the CCW tangent point of eq. (26),
      v_d = -v (p - p_tan) / |p - p_tan| (eq. (28) with the "+" inside the norm fixed; the heading
      (29) is phi_d = atan2(v_yd, v_xd), erratum fixed, and is not needed by an acceleration command).
    - inside (r < R - band): the inner-circle construction of seed 004 with radius r_min, the inner
      circle internally tangent to the standoff circle. Our choice, position-only (the seed's centre
      depends on the current velocity, eq. (27)): if r <= R - 2 r_min, the inner circle whose centre is
      on the pursuer's own radial line, approached along its CCW tangent (eq. (26) applied to that
      circle); otherwise the inner circle through the pursuer whose CCW arc leads outwards (its centre
      ahead in phase), flown along. Either way the path is tangent line -> inner arc -> standoff circle,
      turning on arcs of radius r_min, with a horizontal distance to the target that does not decrease
      (the direction field is continuous except at r = 0 and at the edges of the on-circle band).
    - on the circle (|r - R| <= band; the seed gives no law): tangential at the orbit speed with a
      radial correction, v_r = -k_r (r - R) (clipped to the speed), v_t = sqrt(v^2 - v_r^2), so the
      horizontal relative speed stays v.
    Phase coordination (seed 004 eqs. (36)-(40), generalised from 3 pursuers with a leader to N
    without one): v_i = clip(v0 + k R (Delta_ahead - Delta_behind), v_min, v_max), with the CCW gaps to
    the nearest neighbours ahead and behind; Delta_ahead - Delta_behind = (Delta_ahead - 2 pi/N) -
    (Delta_behind - 2 pi/N), so each correction is (38)'s UAV-1 term on the gap ahead plus its UAV-3
    term on the gap behind, and needs no leader and no count N. The gaps then obey a diffusion on the ring,
    Delta_k' = k (Delta_k+1 - 2 Delta_k + Delta_k-1) while unsaturated on the circle, whose Lyapunov
    function sum (Delta_k - 2 pi/N)^2 (eq. (36) for N gaps) decreases as in eq. (39); the gaps tend to
    2 pi / N. Without neighbours v_i = v0.
    Moving target (eqs. (32)-(34)): the relative horizontal command v_i d is scaled by the positive
    root alpha of |alpha v_i d + v^_T,h|^2 = v_i^2 (eq. (34)), so the ground speed stays v_i; when no
    root >= alpha_min exists (target faster than the pursuer) alpha = alpha_min and the ground speed
    limit is not held. The target's vertical velocity is added too (the seed's ground target has none).
    Vertical profile (eqs. (30)-(31)) as an altitude reference: altitude above the target h, error
    e = h - H, vertical speed min(v_z,max, sqrt(2 a_z,max |e|), k_z |e|) towards H: full rate, then the
    constant-deceleration braking of (31) from the critical height z0 = H + v_z,max^2 / (2 a_z,max) of
    (30), then a linear hold of gain k_z near H (the square root has infinite slope at H).

    Parameters: standoff_radius R m; min_turn_radius r_min m (0 < r_min < R); speed v0 m/s;
    min_speed, max_speed m/s (the [v_min, v_max] of (40)); phase_gain k 1/s; standoff_height H m above
    the target; max_vertical_speed m/s; max_vertical_acceleration m/s^2; vertical_gain k_z 1/s;
    on_circle_band m; radial_gain k_r 1/s; alpha_min; velocity_gain k_v 1/s; max_acceleration m/s^2;
    feedforward_horizon s.
    """

    includes_range_control: ClassVar[bool] = True

    standoff_radius: float = 8.0
    min_turn_radius: float = 2.0
    speed: float = 3.0
    min_speed: float = 1.0
    max_speed: float = 6.0
    phase_gain: float = 0.5
    standoff_height: float = 0.0
    max_vertical_speed: float = 2.0
    max_vertical_acceleration: float = 2.0
    vertical_gain: float = 1.0
    on_circle_band: float = 0.5
    radial_gain: float = 1.0
    alpha_min: float = 0.1
    velocity_gain: float = 2.0
    max_acceleration: float = 6.0
    feedforward_horizon: float = 0.05

    def __post_init__(self) -> None:
        _check_positive(standoff_radius=self.standoff_radius, min_turn_radius=self.min_turn_radius,
                        speed=self.speed, min_speed=self.min_speed, max_speed=self.max_speed,
                        max_vertical_speed=self.max_vertical_speed,
                        max_vertical_acceleration=self.max_vertical_acceleration, vertical_gain=self.vertical_gain,
                        radial_gain=self.radial_gain, alpha_min=self.alpha_min, velocity_gain=self.velocity_gain,
                        max_acceleration=self.max_acceleration)
        _check_non_negative(phase_gain=self.phase_gain, on_circle_band=self.on_circle_band,
                            feedforward_horizon=self.feedforward_horizon)
        if not math.isfinite(self.standoff_height):
            raise ValueError("standoff_height must be finite")
        if not self.min_turn_radius < self.standoff_radius:
            raise ValueError("min_turn_radius must be < standoff_radius")
        if not self.min_speed <= self.speed <= self.max_speed:
            raise ValueError("need min_speed <= speed <= max_speed")
        if self.on_circle_band >= self.standoff_radius:
            raise ValueError("on_circle_band must be < standoff_radius")

    @staticmethod
    def phase(own_position: np.ndarray, target_position: np.ndarray) -> float:
        """Orbit phase, rad; see the module-level `phase`."""
        return phase(own_position, target_position)

    def coordinated_speed(self, context: CooperativeContext) -> float:
        """v_i of seed 004 eq. (40) generalised to N: clip(v0 + k R (gap ahead - gap behind), v_min, v_max), m/s."""
        gaps = _context_gaps(context)
        if gaps is None:
            return self.speed
        ahead, behind = gaps
        speed = self.speed + self.phase_gain * self.standoff_radius * (ahead - behind)
        return float(min(max(speed, self.min_speed), self.max_speed))

    def horizontal_direction(self, offset: np.ndarray) -> np.ndarray:
        """TOGVF unit direction (outside / inside cases), horizontal (east, north), shape (2,).

        offset: pursuer minus target, m, (east, north), shape (2,). See the class docstring.
        """
        R, r_min = self.standoff_radius, self.min_turn_radius
        r = norm(offset)
        radial = offset / r if r > _EPS else np.array([1.0, 0.0])
        if r >= R:
            # Seed 004 eqs. (26), (28): towards the CCW tangent point of the standoff circle.
            to_tangent = tangent_point(offset, R) - offset
            length = norm(to_tangent)
            return to_tangent / length if length > _EPS else _rot90(radial)
        centre_distance = R - r_min  # inner circles are internally tangent to the standoff circle
        if r <= R - 2.0 * r_min:
            centre = centre_distance * radial
            relative = offset - centre
            to_tangent = tangent_point(relative, r_min) - relative
            length = norm(to_tangent)
            if length > _EPS:
                return to_tangent / length
            return _rot90(relative) / norm(relative)
        # The inner circle through the pursuer, centre ahead in phase by beta (law of cosines).
        cos_beta = (r * r + centre_distance ** 2 - r_min ** 2) / (2.0 * r * centre_distance)
        beta = math.acos(min(1.0, max(-1.0, cos_beta)))
        c, s = math.cos(beta), math.sin(beta)
        centre = centre_distance * np.array([c * radial[0] - s * radial[1], s * radial[0] + c * radial[1]])
        relative = offset - centre
        return _rot90(relative) / norm(relative)

    def relative_horizontal_velocity(self, offset: np.ndarray, speed: float) -> np.ndarray:
        """Relative horizontal command at `speed` m/s (before the moving-target scaling), (east, north), (2,)."""
        r = norm(offset)
        if abs(r - self.standoff_radius) <= self.on_circle_band and r > _EPS:
            radial = offset / r
            radial_speed = min(max(-self.radial_gain * (r - self.standoff_radius), -speed), speed)
            tangential_speed = math.sqrt(max(speed * speed - radial_speed * radial_speed, 0.0))
            return tangential_speed * _rot90(radial) + radial_speed * radial
        return speed * self.horizontal_direction(offset)

    def moving_target_scale(self, relative_velocity: np.ndarray, target_velocity: np.ndarray, speed: float) -> float:
        """alpha of seed 004 eqs. (32)-(34): the positive root of
        |v_d|^2 alpha^2 + 2 (v_d . v_t) alpha + |v_t|^2 - v^2 = 0 (planar vectors, m/s; speed v m/s).

        alpha_min when no root >= alpha_min exists (then the ground speed exceeds v)."""
        a = float(relative_velocity @ relative_velocity)
        if a <= _EPS:
            return 1.0
        b = float(relative_velocity @ target_velocity)
        c = float(target_velocity @ target_velocity) - speed * speed
        discriminant = b * b - a * c
        if discriminant < 0.0:
            return self.alpha_min
        return max((-b + math.sqrt(discriminant)) / a, self.alpha_min)

    def vertical_speed(self, altitude_error: float) -> float:
        """Seed 004 eqs. (30)-(31) with a linear hold near H: speed towards H, m/s (>= 0)."""
        magnitude = abs(altitude_error)
        return min(self.max_vertical_speed, math.sqrt(2.0 * self.max_vertical_acceleration * magnitude),
                   self.vertical_gain * magnitude)

    def desired_velocity(self, context: CooperativeContext) -> np.ndarray:
        """Ground-frame desired velocity, m/s, shape (3,) NED."""
        offset = _planar(context.own_position - context.target_position)
        speed = self.coordinated_speed(context)
        relative = self.relative_horizontal_velocity(offset, speed)
        target_horizontal = _planar(context.target_velocity)
        scale = self.moving_target_scale(relative, target_horizontal, speed)
        altitude_error = (context.target_position[2] - context.own_position[2]) - self.standoff_height
        down = math.copysign(self.vertical_speed(altitude_error), altitude_error)  # above H -> descend (+down)
        return _ned(scale * relative + target_horizontal, down + float(context.target_velocity[2]))

    def _law_terms(self) -> tuple[float, ...]:
        """(g1, g2, g3, alpha, D*, a_turn, altitude_offset, k_z, max_relative_speed): the law's parameters as
        _circumnavigation_velocity_kernel takes them."""
        return (self.g1, self.g2, self.g3, self.alpha, self.desired_radius, self._turn_acceleration,
                self.altitude_offset, self.vertical_gain, self.max_relative_speed)

    def acceleration(self, context: CooperativeContext) -> np.ndarray:
        """Acceleration command, m/s^2, shape (3,) NED: k_v (u - v) + du/dt (+ a^_T), norm <= max_acceleration."""
        return _tracking_acceleration(self._velocity_after, context, self.velocity_gain,
                                      self.feedforward_horizon, self.max_acceleration)

    def _velocity_after(self, context: CooperativeContext, horizon: float) -> np.ndarray:
        """desired_velocity(context.advanced(horizon)) (horizon s; 0: the context itself)."""
        return self.desired_velocity(context if horizon == 0.0 else context.advanced(horizon))


# --------------------------------------------------------------------------------------------------
# Separation between pursuers
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SeparationFilter:
    """Keeps pursuers apart: applied to any acceleration command, given own state and neighbours.

    Two parts, for each neighbour j (d = |p_j - p|, n = (p_j - p) / d, closing speed w = (v - v_j) . n):
    1. a smooth repulsion inside influence_distance: -k ((d_inf - d) / (d_inf - d_min))^2 n (C^1 at
       d_inf, repulsion_gain k m/s^2);
    2. a hard constraint. The neighbour is "threatening" when, at constant velocity, it comes within
       min_separation inside `horizon` s, or when the braking margin
           m = d - d_min - max(w, 0)^2 / (2 c a_b)
       (c = 2 when `reciprocal`: both pursuers brake; c = 1 otherwise: only this one) falls to the
       trigger margin (1 + a_max / a_b)(max(w, 0) tau + a_max tau^2) (tau = horizon) or below. Against a
       threatening neighbour the command's component along n is replaced by min(a . n, -a_b) when
       closing (w > 0) and by min(a . n, 0) otherwise: the closing acceleration is removed and the
       closing velocity is braked at a_b (braking_acceleration). The other components are then scaled
       down so that |a| <= max_acceleration.
    Guarantee, and its conditions. For TWO pursuers that realise the commanded acceleration exactly
    (|a| <= max_acceleration, which must not exceed what the vehicle can realise), update it at least
    every `horizon` s and start with m at or above the trigger margin: the separation never falls below
    min_separation, (a) with `reciprocal` (the default), when both run this filter with the same
    parameters, and (b) without it, when the neighbour does not accelerate at all (constant velocity).
    Reason: braking gives w' <= -c a_b (the tangential motion only lowers w), so
    m' = -w - w w' / (c a_b) >= 0 while closing; the trigger margin covers the worst growth of w and
    loss of d during one update interval before braking starts. A neighbour that manoeuvres without
    the filter voids the bound. With three or more pursuers the pairwise constraints are applied in
    turn (a few passes) and may conflict (a pursuer squeezed between two neighbours cannot brake away
    from both): the filter then still removes the closing components it can, but no bound is claimed.
    """

    min_separation: float
    influence_distance: float | None = None  # default 2 min_separation
    repulsion_gain: float = 1.0
    braking_acceleration: float = 3.0
    max_acceleration: float = 6.0
    horizon: float = 0.1
    passes: int = 3
    reciprocal: bool = True
    _influence: float = field(init=False, repr=False, default=0.0)

    def __post_init__(self) -> None:
        _check_positive(min_separation=self.min_separation, braking_acceleration=self.braking_acceleration,
                        max_acceleration=self.max_acceleration, horizon=self.horizon)
        _check_non_negative(repulsion_gain=self.repulsion_gain)
        influence = 2.0 * self.min_separation if self.influence_distance is None else float(self.influence_distance)
        if not (math.isfinite(influence) and influence > self.min_separation):
            raise ValueError("influence_distance must be finite and > min_separation")
        if self.braking_acceleration > self.max_acceleration:
            raise ValueError("braking_acceleration must not exceed max_acceleration")
        if self.passes < 1:
            raise ValueError("passes must be >= 1")
        object.__setattr__(self, "_influence", influence)

    def braking_margin(self, distance: float, closing_speed: float) -> float:
        """m = d - d_min - max(w, 0)^2 / (2 c a_b), m: the separation left after braking (c = 2 if reciprocal)."""
        return _braking_margin(distance, closing_speed, self.min_separation, self.braking_acceleration,
                               2.0 if self.reciprocal else 1.0)

    def _trigger_margin(self, closing_speed: float) -> float:
        """(1 + a_max / a_b)(max(w, 0) tau + a_max tau^2), m: the braking margin at or below which a neighbour threatens."""
        return _trigger_margin(closing_speed, self.max_acceleration, self.braking_acceleration, self.horizon)

    def filter(self, own_position: np.ndarray, own_velocity: np.ndarray, acceleration: np.ndarray,
               neighbours: tuple[NeighbourState, ...] | list[NeighbourState]) -> np.ndarray:
        """Filtered acceleration, m/s^2, shape (3,) NED.

        own_position m, own_velocity m/s, acceleration m/s^2: shape (3,) NED, finite (else ValueError).
        neighbours: fresh NeighbourState's (extrapolate them to now before calling, if they are old).
        """
        position = _finite_vector(own_position, "own_position")
        velocity = _finite_vector(own_velocity, "own_velocity")
        command = _finite_vector(acceleration, "acceleration").copy()
        count = len(neighbours)
        normals, bounds = np.empty((count, 3)), np.empty(count)
        # the repulsion (part 1) into command, the threatening neighbours' normals and bounds (part 2)
        threatening = _separation_kernel(
            position, velocity, command, np.array([n.position for n in neighbours], dtype=float).reshape(count, 3),
            np.array([n.velocity for n in neighbours], dtype=float).reshape(count, 3), self._kernel_terms(),
            normals, bounds)
        if not threatening:
            return _saturate(command, self.max_acceleration)
        active = list(zip(normals[:threatening], bounds[:threatening].tolist()))
        for _ in range(self.passes):
            for normal, bound in active:
                along = float(command @ normal)
                if along > bound:
                    command = command + (bound - along) * normal
        return self._limit_keeping_constraints(command, active)

    __call__ = filter

    def _kernel_terms(self) -> tuple[float, ...]:
        """(min_separation, influence, repulsion_gain, braking_acceleration, max_acceleration, horizon, sharing c):
        the filter's parameters as _separation_kernel takes them."""
        return (self.min_separation, self._influence, self.repulsion_gain, self.braking_acceleration,
                self.max_acceleration, self.horizon, 2.0 if self.reciprocal else 1.0)

    def _limit_keeping_constraints(self, command: np.ndarray, active: list[tuple[np.ndarray, float]]) -> np.ndarray:
        """|a| <= max_acceleration, shrinking the part of the command outside the constrained directions first."""
        if norm(command) <= self.max_acceleration:
            return command
        basis = np.linalg.qr(np.array([normal for normal, _ in active]).T)[0]  # orthonormal span of normals
        constrained = basis @ (basis.T @ command)
        free = command - constrained
        constrained_norm = norm(constrained)
        if constrained_norm >= self.max_acceleration:
            return constrained * (self.max_acceleration / constrained_norm)
        room = math.sqrt(self.max_acceleration ** 2 - constrained_norm ** 2)
        return constrained + _saturate(free, room)


@jit
def _braking_margin(distance: float, closing_speed: float, min_separation: float, braking_acceleration: float,
                    sharing: float) -> float:
    """m = d - d_min - max(w, 0)^2 / (2 c a_b), m (SeparationFilter.braking_margin; c = sharing)."""
    closing = 0.0 if 0.0 > closing_speed else closing_speed  # max(closing_speed, 0.0)
    return distance - min_separation - closing * closing / (2.0 * sharing * braking_acceleration)


@jit
def _trigger_margin(closing_speed: float, max_acceleration: float, braking_acceleration: float, horizon: float) -> float:
    """(1 + a_max / a_b)(max(w, 0) tau + a_max tau^2), m (SeparationFilter._trigger_margin; tau = horizon)."""
    closing = 0.0 if 0.0 > closing_speed else closing_speed  # max(closing_speed, 0.0)
    return (1.0 + max_acceleration / braking_acceleration) * (closing * horizon + max_acceleration * horizon * horizon)


@jit
def _separation_kernel(position: np.ndarray, velocity: np.ndarray, command: np.ndarray,
                       neighbour_positions: np.ndarray, neighbour_velocities: np.ndarray, terms: tuple,
                       normals: np.ndarray, bounds: np.ndarray) -> int:
    """SeparationFilter.filter's parts 1 and 2 up to the constraints (its docstring): the repulsion of every
    neighbour inside the influence distance subtracted from `command` (m/s^2, (3,), in place), then the threatening
    neighbours' unit normals n (into normals, (k, 3)) and bounds on a . n (-a_b when closing, else 0; into bounds,
    (k,)), in the neighbours' order; returns how many are threatening. position m, velocity m/s, (3,); the
    neighbours' (k, 3); a neighbour at the pursuer's own position (d <= eps) is skipped. terms = (min_separation,
    influence, repulsion_gain, braking_acceleration, max_acceleration, horizon, sharing) (SeparationFilter.
    _kernel_terms; sharing: c of the braking margin, 2 reciprocal, 1 not). The arithmetic of the filter as it was
    written over numpy arrays (norms and dot products as x @ y, max/min as Python's), so compiled or not it gives
    the same bits."""
    min_separation, influence, repulsion_gain, braking_acceleration, max_acceleration, horizon, sharing = terms
    count = neighbour_positions.shape[0]
    offsets, units, relatives = np.empty((count, 3)), np.empty((count, 3)), np.empty((count, 3))
    distances, closings = np.empty(count), np.empty(count)
    kept = 0
    for i in range(count):
        offset = offsets[kept]
        for k in range(3):
            offset[k] = neighbour_positions[i, k] - position[k]
        distance = math.sqrt(offset @ offset)
        if distance <= _EPS:
            continue  # coincident: no direction to push along (cannot be reached from m >= 0)
        normal, relative = units[kept], relatives[kept]
        for k in range(3):
            normal[k] = offset[k] / distance
            relative[k] = velocity[k] - neighbour_velocities[i, k]
        distances[kept] = distance
        closings[kept] = relative @ normal
        kept += 1
    for g in range(kept):  # 1. the smooth repulsion: -k ((d_inf - d) / (d_inf - d_min))^2 n
        if distances[g] < influence:
            depth = (influence - distances[g]) / (influence - min_separation)
            push = repulsion_gain * (1.0 if 1.0 < depth else depth) ** 2  # k min(depth, 1)^2
            for k in range(3):
                command[k] = command[k] - push * units[g, k]
    threatening = 0
    miss = np.empty(3)
    for g in range(kept):  # 2. the threatening neighbours: braking margin at or below the trigger margin, or ...
        closing_speed = closings[g]
        threat = (_braking_margin(distances[g], closing_speed, min_separation, braking_acceleration, sharing)
                  <= _trigger_margin(closing_speed, max_acceleration, braking_acceleration, horizon))
        if not threat:
            # ... a constant-velocity closest approach within the horizon under d_min (offset = p_j - p, v - v_j).
            offset, relative = offsets[g], relatives[g]
            speed2 = relative @ relative
            if speed2 > _EPS:
                t_closest = (offset @ relative) / speed2
                t_closest = 0.0 if 0.0 > t_closest else t_closest  # min(max(t, 0), horizon)
                t_closest = horizon if horizon < t_closest else t_closest
                for k in range(3):
                    miss[k] = offset[k] - t_closest * relative[k]
                threat = math.sqrt(miss @ miss) < min_separation
        if threat:
            for k in range(3):
                normals[threatening, k] = units[g, k]
            bounds[threatening] = -braking_acceleration if closing_speed > 0.0 else 0.0
            threatening += 1
    return threatening


# --------------------------------------------------------------------------------------------------
# Weaving switch
# --------------------------------------------------------------------------------------------------

def line_of_sight_angle(own_position: np.ndarray, neighbour_position: np.ndarray,
                        target_position: np.ndarray) -> float:
    """Angle between the two LINES of sight to the target, rad in [0, pi/2].

    Lines, not directions: two pursuers on opposite sides of the target see it along the same line,
    which gives no triangulation baseline. NaN when either pursuer is at the target.
    """
    own = np.asarray(target_position, dtype=float) - np.asarray(own_position, dtype=float)
    other = np.asarray(target_position, dtype=float) - np.asarray(neighbour_position, dtype=float)
    own_norm, other_norm = norm(own), norm(other)
    if own_norm <= _EPS or other_norm <= _EPS:
        return math.nan
    angle = math.atan2(norm(np.cross(own, other)), float(own @ other))
    return min(angle, math.pi - angle)


def neighbours_make_range_observable(own_position: np.ndarray, target_position_estimate: np.ndarray,
                                     neighbour_positions, min_angle_rad: float = math.radians(15.0)) -> bool:
    """True when a neighbour gives a triangulation baseline, so the range is observable without weaving.

    own_position, target_position_estimate: m, shape (3,) NED. neighbour_positions: iterable of m, (3,),
    of FRESH neighbours only (the caller filters freshness). True when the line of sight of at least
    one neighbour to the estimated target makes an angle of at least min_angle_rad (0 < .. <= pi/2)
    with ours (`line_of_sight_angle`); pursuers at the target (no line of sight) and non-finite
    positions are ignored. This is what switches HNG weaving off; it comes back when this turns False.
    """
    if not (math.isfinite(min_angle_rad) and 0.0 < min_angle_rad <= math.pi / 2.0):
        raise ValueError("min_angle_rad must be in (0, pi/2]")
    own = np.asarray(own_position, dtype=float)
    target = np.asarray(target_position_estimate, dtype=float)
    if own.shape != (3,) or target.shape != (3,) or not (np.all(np.isfinite(own)) and np.all(np.isfinite(target))):
        raise ValueError("own_position and target_position_estimate must be finite vectors of shape (3,)")
    for position in neighbour_positions:
        neighbour = np.asarray(position, dtype=float)
        if neighbour.shape != (3,) or not np.all(np.isfinite(neighbour)):
            continue
        angle = line_of_sight_angle(own, neighbour, target)
        if math.isfinite(angle) and angle >= min_angle_rad:
            return True
    return False
