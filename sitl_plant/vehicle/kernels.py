"""The plant's 500 Hz arithmetic as module-level scalar kernels: the one implementation.

Rigid body eq. (20a)-(20d) with drag and the motor lag (`rigid_body_rhs`, `rotor_wrench`,
`rk4_step`), the geometric attitude law eq. (23)-(24) (`attitude_torque`), the mixer
(`mixer_speeds`) and the loop that chains them for n steps (`advance_steps`). The classes
of sitl_plant.vehicle.quadrotor and sitl_plant.vehicle.attitude_control hold the state and
call these functions; nothing else repeats their arithmetic.

Every kernel takes floats and tuples of floats and returns tuples of floats: no objects,
no closures, no numpy. The airframe comes in as constant tuples built once per object by
`plant_constants`, `control_constants` and `mixer_constants` (the same precomputed values,
computed the same way, as the closures they replace). Tuples, not float64 arrays, because
the kernels must also run as plain Python (without numba, or with BOF_NO_JIT=1), where
indexing an array gives numpy scalars whose arithmetic is several times slower than a
float's; a tuple of floats is also what numba passes best (a UniTuple of float64).

With numba installed each kernel is compiled by sitl_plant._jit.jit (numba.njit(cache=True),
no fastmath: the same IEEE operations in the same order, so the compiled and the plain
results are identical; tests/test_plant_kernels.py checks it bit for bit). All kernels
live in this one file because numba's cache does not see edits to a callee defined in
another file: kept together, an edit recompiles every kernel that could inline it.

State layout: s = (px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz): position m and
velocity m/s in NED, attitude as the unit quaternion (w, x, y, z) body FRD -> NED, body rates
rad/s in FRD. Rotor speeds w = (w1, w2, w3, w4), rad/s, PX4 motor order.
"""

from __future__ import annotations

import math

from sitl_plant import _jit
from sitl_plant._jit import jit

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
Wrench = tuple[float, float, float, float]
State = tuple[float, float, float, float, float, float, float, float, float, float, float, float, float]
#: (g, 1/m, C_d/m, 1/J_x, 1/J_y, 1/J_z, J_z - J_y, J_x - J_z, J_y - J_x, C_T, C_T d/sqrt(2), C_m)
PlantConstants = tuple[float, float, float, float, float, float, float, float, float, float, float, float]
#: (k_p, k_d, J_x, J_y, J_z)
ControlConstants = tuple[float, float, float, float, float]
#: (T_max, w_max, u_max = w_max^2, 1/(4 C_T), 1/(4 C_T a), 1/(4 C_m)), a = d/sqrt(2)
MixerConstants = tuple[float, float, float, float, float, float]

ZERO3: Vec3 = (0.0, 0.0, 0.0)


def plant_constants(params) -> PlantConstants:
    """The rigid body's and the allocation's constants of a QuadrotorParams, as `rk4_step` takes them."""
    jx, jy, jz = (float(j) for j in params.inertia)
    return (
        float(params.gravity),
        1.0 / params.mass,
        params.drag_coefficient / params.mass,
        1.0 / jx, 1.0 / jy, 1.0 / jz,
        jz - jy, jx - jz, jy - jx,
        float(params.thrust_coefficient),
        params.thrust_coefficient * params.arm_length / math.sqrt(2.0),
        float(params.moment_coefficient),
    )


def control_constants(params) -> ControlConstants:
    """Gains and inertia of eq. (24), as `attitude_torque` takes them."""
    jx, jy, jz = (float(j) for j in params.inertia)
    return (float(params.attitude_kp), float(params.attitude_kd), jx, jy, jz)


def mixer_constants(params) -> MixerConstants:
    """Limits and inverse allocation factors of the mixer, as `mixer_speeds` takes them."""
    a = params.arm_length / math.sqrt(2.0)
    return (
        float(params.max_total_thrust),
        float(params.max_rotor_speed),
        float(params.max_rotor_speed**2),
        1.0 / (4.0 * params.thrust_coefficient),
        1.0 / (4.0 * params.thrust_coefficient * a),
        1.0 / (4.0 * params.moment_coefficient),
    )


# --------------------------------------------------------------------------- rigid body


@jit
def quaternion_to_rotation(qw: float, qx: float, qy: float, qz: float) -> Mat3:
    """Rotation matrix of a unit quaternion, row-major 9-tuple (body FRD -> NED)."""
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz = qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    return (
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    )


@jit
def rotor_wrench(w1: float, w2: float, w3: float, w4: float, k: PlantConstants) -> Wrench:
    """Total thrust (N) and body torque (N m, FRD) of four rotor speeds (rad/s): the X-layout
    allocation T = C_T sum u_i, tau = (C_T a (-u1+u2+u3-u4), C_T a (u1-u2+u3-u4), C_m (u1+u2-u3-u4)),
    u_i = w_i^2, the thrust and torque inputs of eq. (20b) and (20d)."""
    c_t, c_ta, c_m = k[9], k[10], k[11]
    u1, u2, u3, u4 = w1 * w1, w2 * w2, w3 * w3, w4 * w4
    return (
        c_t * (u1 + u2 + u3 + u4),
        c_ta * (-u1 + u2 + u3 - u4),
        c_ta * (u1 - u2 + u3 - u4),
        c_m * (u1 + u2 - u3 - u4),
    )


@jit
def rigid_body_rhs(
    v: tuple[float, float, float], q: Quat, omega: tuple[float, float, float], wrench: Wrench, k: PlantConstants,
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """Rigid-body right-hand side, eq. (20b)-(20d) plus drag: (v', q', omega') as a 10-tuple.

    v: velocity (m/s, NED), q: attitude quaternion (w, x, y, z), omega: body rates (rad/s, FRD), wrench:
    (thrust N, body torque N m) as `rotor_wrench` gives it. p' = v (eq. (20a)) is left to the integrator.
    Tuples of floats rather than arrays: this runs four times per plant step, and in plain Python
    array indexing would dominate its cost.
    """
    vx, vy, vz = v
    qw, qx, qy, qz = q
    wx, wy, wz = omega
    thrust, tx, ty, tz = wrench
    # k = plant_constants: (g, 1/m, C_d/m, 1/J_x, 1/J_y, 1/J_z, J_z - J_y, J_x - J_z, J_y - J_x, ...),
    # indexed where used (cheaper than unpacking all twelve in plain Python).
    drag_per_mass = k[2]
    # Only r3 = R e_Z is needed: thrust acts along it and, since
    # R diag(1, 1, 0) R^T = I - r3 r3^T, the drag R(-K_r R^T v) = -C_d (v - r3 (r3 . v)).
    r02 = 2.0 * (qx * qz + qw * qy)
    r12 = 2.0 * (qy * qz - qw * qx)
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
    vertical = r02 * vx + r12 * vy + r22 * vz
    a3 = thrust * k[1] - drag_per_mass * vertical
    return (
        -a3 * r02 - drag_per_mass * vx,  # eq. (20b) + drag
        -a3 * r12 - drag_per_mass * vy,
        k[0] - a3 * r22 - drag_per_mass * vz,
        # eq. (20c) as q' = q (x) (0, omega) / 2
        -0.5 * (qx * wx + qy * wy + qz * wz),
        0.5 * (qw * wx + qy * wz - qz * wy),
        0.5 * (qw * wy - qx * wz + qz * wx),
        0.5 * (qw * wz + qx * wy - qy * wx),
        # eq. (20d) with diagonal J
        (tx - k[6] * wy * wz) * k[3],
        (ty - k[7] * wz * wx) * k[4],
        (tz - k[8] * wx * wy) * k[5],
    )


@jit
def rk4_step(
    h: float, lag_half: float, lag_full: float, s: State, w: Quat,
    c1: float, c2: float, c3: float, c4: float, k: PlantConstants,
) -> tuple[State, Quat]:
    """One classic RK4 step of h seconds of eq. (20a)-(20d) with the first-order motor lag.

    c1..c4: rotor speed command (rad/s), already saturated, held over the step. The lag
    w' = (c - w) / T_m is solved exactly: lag_half = exp(-h / (2 T_m)), lag_full = exp(-h / T_m),
    so the stages see the exact rotor speeds at t, t + h/2 and t + h. The quaternion is
    renormalised after the step. Returns (new state, new rotor speeds).
    Written out stage by stage on scalars; in plain Python a loop over state vectors costs
    more than the arithmetic at this size.
    """
    w1, w2, w3, w4 = w
    d1, d2, d3, d4 = w1 - c1, w2 - c2, w3 - c3, w4 - c4
    t0, x0, y0, z0 = rotor_wrench(w1, w2, w3, w4, k)
    tm, xm, ym, zm = rotor_wrench(c1 + d1 * lag_half, c2 + d2 * lag_half, c3 + d3 * lag_half, c4 + d4 * lag_half, k)
    e1, e2, e3, e4 = c1 + d1 * lag_full, c2 + d2 * lag_full, c3 + d3 * lag_full, c4 + d4 * lag_full
    te, xe, ye, ze = rotor_wrench(e1, e2, e3, e4, k)

    px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz = s
    hh = 0.5 * h
    a1x, a1y, a1z, q1w, q1x, q1y, q1z, o1x, o1y, o1z = rigid_body_rhs(
        (vx, vy, vz), (qw, qx, qy, qz), (wx, wy, wz), (t0, x0, y0, z0), k
    )
    v2x, v2y, v2z = vx + hh * a1x, vy + hh * a1y, vz + hh * a1z
    a2x, a2y, a2z, q2w, q2x, q2y, q2z, o2x, o2y, o2z = rigid_body_rhs(
        (v2x, v2y, v2z),
        (qw + hh * q1w, qx + hh * q1x, qy + hh * q1y, qz + hh * q1z),
        (wx + hh * o1x, wy + hh * o1y, wz + hh * o1z),
        (tm, xm, ym, zm), k,
    )
    v3x, v3y, v3z = vx + hh * a2x, vy + hh * a2y, vz + hh * a2z
    a3x, a3y, a3z, q3w, q3x, q3y, q3z, o3x, o3y, o3z = rigid_body_rhs(
        (v3x, v3y, v3z),
        (qw + hh * q2w, qx + hh * q2x, qy + hh * q2y, qz + hh * q2z),
        (wx + hh * o2x, wy + hh * o2y, wz + hh * o2z),
        (tm, xm, ym, zm), k,
    )
    v4x, v4y, v4z = vx + h * a3x, vy + h * a3y, vz + h * a3z
    a4x, a4y, a4z, q4w, q4x, q4y, q4z, o4x, o4y, o4z = rigid_body_rhs(
        (v4x, v4y, v4z),
        (qw + h * q3w, qx + h * q3x, qy + h * q3y, qz + h * q3z),
        (wx + h * o3x, wy + h * o3y, wz + h * o3z),
        (te, xe, ye, ze), k,
    )
    h6 = h / 6.0
    qw += h6 * (q1w + 2.0 * (q2w + q3w) + q4w)
    qx += h6 * (q1x + 2.0 * (q2x + q3x) + q4x)
    qy += h6 * (q1y + 2.0 * (q2y + q3y) + q4y)
    qz += h6 * (q1z + 2.0 * (q2z + q3z) + q4z)
    inv = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    return (
        (
            px + h6 * (vx + 2.0 * (v2x + v3x) + v4x),
            py + h6 * (vy + 2.0 * (v2y + v3y) + v4y),
            pz + h6 * (vz + 2.0 * (v2z + v3z) + v4z),
            vx + h6 * (a1x + 2.0 * (a2x + a3x) + a4x),
            vy + h6 * (a1y + 2.0 * (a2y + a3y) + a4y),
            vz + h6 * (a1z + 2.0 * (a2z + a3z) + a4z),
            qw * inv, qx * inv, qy * inv, qz * inv,
            wx + h6 * (o1x + 2.0 * (o2x + o3x) + o4x),
            wy + h6 * (o1y + 2.0 * (o2y + o3y) + o4y),
            wz + h6 * (o1z + 2.0 * (o2z + o3z) + o4z),
        ),
        (e1, e2, e3, e4),
    )


# --------------------------------------------------------------------------- attitude setpoint in

#: Tolerance of the SO(3) test of an attitude setpoint (`is_rotation`).
ORTHONORMAL_TOL = 1e-6


@jit
def is_rotation(m00: float, m01: float, m02: float, m10: float, m11: float, m12: float,
                m20: float, m21: float, m22: float) -> bool:
    """Whether the matrix of these entries (row-major) is a proper rotation to ORTHONORMAL_TOL: its columns
    a, b, c orthonormal and right-handed (a x b = c). `not <=` also refuses NaN and infinities."""
    a0, a1, a2 = m00, m10, m20
    b0, b1, b2 = m01, m11, m21
    c0, c1, c2 = m02, m12, m22
    tolerance = ORTHONORMAL_TOL
    return (abs(a0 * a0 + a1 * a1 + a2 * a2 - 1.0) <= tolerance
            and abs(b0 * b0 + b1 * b1 + b2 * b2 - 1.0) <= tolerance
            and abs(c0 * c0 + c1 * c1 + c2 * c2 - 1.0) <= tolerance
            and abs(a0 * b0 + a1 * b1 + a2 * b2) <= tolerance
            and abs(a0 * c0 + a1 * c1 + a2 * c2) <= tolerance
            and abs(b0 * c0 + b1 * c1 + b2 * c2) <= tolerance
            and abs(a1 * b2 - a2 * b1 - c0) <= tolerance
            and abs(a2 * b0 - a0 * b2 - c1) <= tolerance
            and abs(a0 * b1 - a1 * b0 - c2) <= tolerance)


@jit
def quaternion_from_matrix(m00: float, m01: float, m02: float, m10: float, m11: float, m12: float,
                           m20: float, m21: float, m22: float) -> Quat:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix given by its entries (row-major): Shepperd's
    method, pivoting on the largest of trace and diagonal to stay accurate near half turns."""
    trace = m00 + m11 + m22
    if trace >= m00 and trace >= m11 and trace >= m22:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif m11 >= m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    scale = (1.0 if q[0] >= 0.0 else -1.0) / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] * scale, q[1] * scale, q[2] * scale, q[3] * scale)


@jit
def setpoint_quaternion(m00: float, m01: float, m02: float, m10: float, m11: float, m12: float,
                        m20: float, m21: float, m22: float) -> tuple[bool, float, float, float, float]:
    """(is_rotation, and if so quaternion_from_matrix's w, x, y, z; else zeros) of an attitude setpoint's nine
    entries (row-major): the vehicle's check and conversion of R_d in one call (one compiled dispatch)."""
    if not is_rotation(m00, m01, m02, m10, m11, m12, m20, m21, m22):
        return False, 0.0, 0.0, 0.0, 0.0
    qw, qx, qy, qz = quaternion_from_matrix(m00, m01, m02, m10, m11, m12, m20, m21, m22)
    return True, qw, qx, qy, qz


# --------------------------------------------------------------------------- attitude control


@jit
def error_quaternion(q: Quat, qd: Quat) -> Quat:
    """q_e = q_d^* (x) q, i.e. R(q_e) = R_d^T R: the attitude error of eq. (24) is 2 w_e (x_e, y_e, z_e)."""
    qw, qx, qy, qz = q
    dw, dx, dy, dz = qd
    return (
        dw * qw + dx * qx + dy * qy + dz * qz,
        dw * qx - qw * dx - dy * qz + dz * qy,
        dw * qy - qw * dy - dz * qx + dx * qz,
        dw * qz - qw * dz - dx * qy + dy * qx,
    )


@jit
def attitude_torque(
    q: Quat, w: Vec3, qd: Quat, wd: Vec3, wd_dot: Vec3, feed_forward: bool, c: ControlConstants
) -> Vec3:
    """Body torque of eq. (23)-(24), N m, FRD, on unit quaternions (w, x, y, z).

    tau = -k_p e_R - k_d e_w + [w]x J w - J([w]x R^T R_d w_d - R^T R_d w_d')   (24)

    q: attitude, w: body rates (rad/s), qd: desired attitude; wd, wd_dot: desired rates and
    angular accelerations in the desired body frame, used only when feed_forward is true
    (without it they are zero and the law is the PD of the hot loop). c: control_constants.
    e_R = 2 w_e (x_e, y_e, z_e) for q_e = q_d^* (x) q (see GeometricAttitudeController).
    """
    kp, kd, jx, jy, jz = c
    ew, ex, ey, ez = error_quaternion(q, qd)
    kp2 = 2.0 * kp * ew
    wx, wy, wz = w
    # [w]x J w: the gyroscopic term of eq. (20d), cancelled so the closed loop is PD.
    gx = (jz - jy) * wy * wz
    gy = (jx - jz) * wz * wx
    gz = (jy - jx) * wx * wy
    if not feed_forward:
        return (
            gx - kp2 * ex - kd * wx,
            gy - kp2 * ey - kd * wy,
            gz - kp2 * ez - kd * wz,
        )
    # Feed-forward of eq. (23)-(24); R^T R_d = R_e^T maps desired-body vectors to body.
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = quaternion_to_rotation(ew, ex, ey, ez)
    ax = m0 * wd[0] + m3 * wd[1] + m6 * wd[2]
    ay = m1 * wd[0] + m4 * wd[1] + m7 * wd[2]
    az = m2 * wd[0] + m5 * wd[1] + m8 * wd[2]
    bx = m0 * wd_dot[0] + m3 * wd_dot[1] + m6 * wd_dot[2]
    by = m1 * wd_dot[0] + m4 * wd_dot[1] + m7 * wd_dot[2]
    bz = m2 * wd_dot[0] + m5 * wd_dot[1] + m8 * wd_dot[2]
    cx, cy, cz = wy * az - wz * ay, wz * ax - wx * az, wx * ay - wy * ax
    return (
        gx - kp2 * ex - kd * (wx - ax) - jx * (cx - bx),
        gy - kp2 * ey - kd * (wy - ay) - jy * (cy - by),
        gz - kp2 * ez - kd * (wz - az) - jz * (cz - bz),
    )


@jit
def mixer_speeds(thrust: float, tx: float, ty: float, tz: float, m: MixerConstants) -> Quat:
    """Total thrust (N) + body torque (N m) -> rotor speed commands w_1..w_4 (rad/s).

    The saturation policy of sitl_plant.vehicle.attitude_control.Mixer: thrust clipped to
    [0, T_max]; roll/pitch scaled down together if their differential alone spans more than
    [0, u_max]; the collective shifted as little as possible to fit; yaw clipped to the
    headroom left. Conditional expressions instead of min/max/abs (the same comparisons
    Python's min and max make): builtin calls dominate at this size in plain Python.
    """
    t_max, w_max, u_max, inv_4ct, inv_4cta, inv_4cm = m
    thrust = 0.0 if thrust < 0.0 else (t_max if thrust > t_max else thrust)
    c = thrust * inv_4ct
    dx = tx * inv_4cta
    dy = ty * inv_4cta
    dz = tz * inv_4cm
    # Roll/pitch differentials: motors 1/2 get +/-p, motors 3/4 get +/-q.
    p = dy - dx
    q = dx + dy
    ap = p if p >= 0.0 else -p
    aq = q if q >= 0.0 else -q
    half_span = ap if ap > aq else aq
    if 2.0 * half_span > u_max:
        k = 0.5 * u_max / half_span
        p *= k
        q *= k
        ap *= k
        aq *= k
        half_span = 0.5 * u_max
    if c < half_span:
        c = half_span
    elif c > u_max - half_span:
        c = u_max - half_span
    # Yaw: CCW motors 1/2 get +dz, CW motors 3/4 get -dz; clip to the headroom left.
    if dz > 0.0:
        up, down = u_max - c - ap, c - aq
        room = up if up < down else down
        dz = room if room < dz else dz  # min(dz, room)
    else:
        up, down = u_max - c - aq, c - ap
        room = -(up if up < down else down)
        dz = room if room > dz else dz  # max(dz, room)
    u1 = c + p + dz
    u2 = c - p + dz
    u3 = c + q - dz
    u4 = c - q - dz
    # Rounding may leave u a few ulp outside [0, u_max].
    return (
        math.sqrt(u1) if 0.0 < u1 < u_max else (0.0 if u1 <= 0.0 else w_max),
        math.sqrt(u2) if 0.0 < u2 < u_max else (0.0 if u2 <= 0.0 else w_max),
        math.sqrt(u3) if 0.0 < u3 < u_max else (0.0 if u3 <= 0.0 else w_max),
        math.sqrt(u4) if 0.0 < u4 < u_max else (0.0 if u4 <= 0.0 else w_max),
    )


# --------------------------------------------------------------------------- the loop


@jit
def advance_steps(
    n: int, h: float, lag_half: float, lag_full: float, s: State, w: Quat, qd: Quat, thrust: float,
    k: PlantConstants, c: ControlConstants, m: MixerConstants,
) -> tuple[State, Quat]:
    """n steps of h seconds of the attitude/thrust vehicle: eq. (24) PD torque on the true state
    (no feed-forward) -> mixer -> RK4 of eq. (20a)-(20d) with the motor lag, holding the
    setpoint (qd, thrust N). Returns (state, rotor speeds) after the n steps."""
    zero = (0.0, 0.0, 0.0)
    for _ in range(n):
        tx, ty, tz = attitude_torque(s[6:10], s[10:13], qd, zero, zero, False, c)
        c1, c2, c3, c4 = mixer_speeds(thrust, tx, ty, tz, m)
        s, w = rk4_step(h, lag_half, lag_full, s, w, c1, c2, c3, c4, k)
    return s, w


_warmed_up = False


def warm_up() -> None:
    """Compile every kernel (or load it from numba's cache) for the argument types the classes pass,
    once per process: Quadrotor's constructor calls this so that a real-time loop (sitl-plant)
    never stalls on its first step. Calls on dummy values; nothing to do without numba."""
    global _warmed_up
    if _warmed_up or not _jit.ENABLED:
        return
    _warmed_up = True
    k, c, m = (1.0,) * 12, (1.0,) * 5, (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    s: State = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    w = q = (1.0, 0.0, 0.0, 0.0)
    rigid_body_rhs(s[3:6], s[6:10], s[10:13], rotor_wrench(*w, k), k)
    rk4_step(0.002, 0.9, 0.8, s, w, 1.0, 1.0, 1.0, 1.0, k)
    error_quaternion(q, q)
    attitude_torque(q, ZERO3, q, ZERO3, ZERO3, True, c)
    mixer_speeds(0.5, 0.0, 0.0, 0.0, m)
    advance_steps(1, 0.002, 0.9, 0.8, s, w, q, 0.5, k, c, m)
    setpoint_quaternion(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
