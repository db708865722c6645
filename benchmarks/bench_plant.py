"""Time the SITL plant (attitude controller + mixer + RK4 rigid body) on one core.

Advances an AttitudeThrustVehicle through 60 s of simulated time at the default
500 Hz with a gently varying attitude/thrust setpoint refreshed at 50 Hz, as the
guidance loop would, and reports the median wall time of a few repeats and the
real-time factor (simulated seconds per wall-clock second).

Run from the repository root:  PYTHONPATH=. python benchmarks/bench_plant.py
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle
from sitl_plant.vehicle.params import QuadrotorParams, table1_params

SETPOINT_RATE_HZ = 50.0


def setpoint(t: float, params: QuadrotorParams) -> tuple[np.ndarray, float]:
    """Slow roll/pitch/yaw sinusoids (<= 0.2 rad tilt) and thrust that roughly holds altitude."""
    roll = 0.15 * math.sin(0.7 * t)
    pitch = 0.12 * math.sin(0.5 * t + 1.0)
    yaw = 0.8 * math.sin(0.2 * t)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rotation = np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
    return rotation, params.hover_thrust / (cr * cp)


def run_once(sim_seconds: float, rate_hz: float) -> tuple[float, float]:
    """(wall time, process CPU time) in s to simulate sim_seconds, setpoints included."""
    params = table1_params()
    vehicle = AttitudeThrustVehicle(params, rate_hz=rate_hz, rng=0)
    period = 1.0 / SETPOINT_RATE_HZ
    n = round(sim_seconds * SETPOINT_RATE_HZ)
    start, start_cpu = time.perf_counter(), time.process_time()
    for k in range(n):
        vehicle.set_attitude_target(*setpoint(k * period, params))
        vehicle.advance(period)
    return time.perf_counter() - start, time.process_time() - start_cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--rate", type=float, default=500.0, help="plant rate, Hz")
    args = parser.parse_args()

    runs = [run_once(args.seconds, args.rate) for _ in range(args.repeats)]
    walls = [wall for wall, _ in runs]
    cpus = [cpu for _, cpu in runs]
    median, median_cpu = statistics.median(walls), statistics.median(cpus)
    steps = args.seconds * args.rate
    print(f"simulated {args.seconds:g} s at {args.rate:g} Hz, {args.repeats} repeats")
    print(f"wall time: median {median:.3f} s (min {min(walls):.3f}, max {max(walls):.3f})")
    print(f"CPU time:  median {median_cpu:.3f} s (min {min(cpus):.3f}, max {max(cpus):.3f})")
    print(f"per plant step (wall): {median / steps * 1e6:.1f} us")
    print(f"CPU per simulated second: {median_cpu / args.seconds * 1e3:.1f} ms")
    print(f"real-time factor (wall): {args.seconds / median:.1f}x")
    print(f"real-time factor (CPU):  {args.seconds / median_cpu:.1f}x")


if __name__ == "__main__":
    main()
