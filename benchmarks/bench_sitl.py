"""Benchmark of the MAVLink SITL: plant step cost, speed factor reached with a MAVSDK companion
attached, telemetry latency. Not a test: figures vary with the machine; quote medians.

    python benchmarks/bench_sitl.py [--speeds 1 2 5 10 20] [--duration 20]

1. In-process cost of one plant tick (4 ms of simulated time): autopilot alone (Hold,
   Offboard) and with MAVLink encoding of the default streams on both links.
2. For each speed factor: sitl-plant as a child process on loopback, a MAVSDK companion in
   this process (companion.adapters.mavsdk_vehicle) that takes off, enters offboard and sends one attitude
   setpoint per 20 Hz control tick computed with the pipeline's attitude mapping from a
   position-hold PD law on its odometry. Reported: speed factor achieved by the plant, its
   late ticks and slips, telemetry latency (ODOMETRY sent by the plant -> received by the
   companion's asyncio task, wall clock, same machine), and companion deadline misses
   (a control tick whose setpoint went out after the next tick was already due).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from companion.core.attitude import attitude_setpoint  # noqa: E402
from companion.adapters.mavsdk_vehicle import MavsdkVehicle  # noqa: E402
from sitl_plant.vehicle.autopilot import Autopilot, OffboardAttitude  # noqa: E402
from sitl_plant.vehicle.mavlink_vehicle import COMPANION_STREAMS, GCS_STREAMS, Home, LinkSpec, MavlinkVehicle  # noqa: E402
from sitl_plant.vehicle.params import table1_params  # noqa: E402
from studies.processes import free_port, start_plant  # noqa: E402
from sitl_plant.vehicle.px4_modes import OFFBOARD  # noqa: E402

CONTROL_PERIOD = 0.05  # s of simulated time (20 Hz, the paper's control rate)


def tick_cost(repeats: int = 5, ticks: int = 1000) -> dict[str, float]:
    """Median wall time per tick, microseconds."""
    results: dict[str, list[float]] = {"hold": [], "offboard": [], "offboard+mavlink": []}
    for _ in range(repeats):
        ap = Autopilot(table1_params(), seed=1)
        ap.run(1.1)
        ap.arm()
        ap.takeoff(3.0)
        ap.run(4.0)
        started = time.perf_counter()
        for _ in range(ticks):
            ap.tick()
        results["hold"].append((time.perf_counter() - started) / ticks)
        ap.offboard_setpoint(OffboardAttitude((1.0, 0.0, 0.0, 0.0), 1.0 / 1.5))
        ap.set_mode(OFFBOARD)
        started = time.perf_counter()
        for i in range(ticks):
            if i % 12 == 0:
                ap.offboard_setpoint(OffboardAttitude((1.0, 0.0, 0.0, 0.0), 1.0 / 1.5))
            ap.tick()
        results["offboard"].append((time.perf_counter() - started) / ticks)
        links = [LinkSpec("companion", "127.0.0.1", free_port(), COMPANION_STREAMS),
                 LinkSpec("gcs", "127.0.0.1", free_port(), GCS_STREAMS)]
        vehicle = MavlinkVehicle(ap, links, Home(47.397742, 8.545594, 488.0))
        try:
            started = time.perf_counter()
            for i in range(ticks):
                if i % 12 == 0:
                    ap.offboard_setpoint(OffboardAttitude((1.0, 0.0, 0.0, 0.0), 1.0 / 1.5))
                ap.tick()
                vehicle.after_tick()
            results["offboard+mavlink"].append((time.perf_counter() - started) / ticks)
        finally:
            vehicle.close()
    return {key: statistics.median(values) * 1e6 for key, values in results.items()}


async def fly_companion(port: int, duration: float, speed: float) -> dict:
    received: list[tuple[int, int]] = []  # (time_usec, wall ns at receipt)
    lateness: list[float] = []
    async with MavsdkVehicle(f"udpin://127.0.0.1:{port}", connect_timeout=20) as vehicle:
        limits = await vehicle.vehicle_limits(table1_params().mass, table1_params().gravity)
        await vehicle.wait_for(lambda s: s.state.time > 1.2, 20, "arming readiness")
        await vehicle.arm()
        await vehicle.takeoff(3.0, timeout=60, settle=1.0)
        anchor = vehicle.latest.state.position.copy()
        forward = np.array([1.0, 0.0, 0.0])
        await vehicle.start_offboard(attitude_setpoint(0.0, np.zeros(3), forward, limits))
        start = vehicle.latest.state.time
        next_tick = start
        sent = 0
        while True:
            sample = await vehicle.next_sample(10.0)
            received.append((int(round(sample.state.time * 1e6)), time.monotonic_ns()))
            now = sample.state.time
            if now >= start + duration:
                break
            if now + 1e-9 < next_tick:
                continue
            # Position-hold PD on a slowly moving point: a setpoint that depends on the telemetry.
            target = anchor + np.array([math.sin(0.2 * (now - start)), 0.0, 0.0])
            acceleration = -1.0 * (sample.state.position - target) - 1.5 * sample.state.velocity
            await vehicle.send_setpoint(attitude_setpoint(now, acceleration, forward, limits))
            sent += 1
            # Deadline: the setpoint for this tick must be out before the next tick is due (vehicle time).
            elapsed_sim = (time.monotonic_ns() - received[-1][1]) * 1e-9 * speed
            lateness.append(elapsed_sim)
            next_tick += CONTROL_PERIOD * max(1, math.floor((now - next_tick) / CONTROL_PERIOD + 1.0 + 1e-9))
        await vehicle.stop_offboard()
    return {"received": received, "lateness": lateness, "sent": sent}


def speed_run(speed: float, duration: float) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        log_dir = Path(folder)
        child, companion_port, _ = start_plant(log_dir, speed_factor=speed, extra=["--latency-log"])
        try:
            result = asyncio.run(fly_companion(companion_port, duration, speed))
        finally:
            child.stop()
        stats = json.loads((log_dir / "stats.json").read_text())
        sent_at = {}
        for line in (log_dir / "odometry_sent.csv").read_text().splitlines()[1:]:
            usec, wall = line.split(",")
            sent_at[int(usec)] = int(wall)
    latencies = [(wall - sent_at[usec]) * 1e-6 for usec, wall in result["received"] if usec in sent_at]
    lateness = np.array(result["lateness"])
    return {
        "speed_requested": speed,
        "speed_achieved": stats["speed_factor_achieved"],
        "late_ticks": stats["late_ticks"],
        "ticks": stats["ticks"],
        "slips": stats["slips"],
        "tick_cpu_median_us": stats["tick_cpu_median_us"],
        "telemetry_latency_ms_p50": float(np.percentile(latencies, 50)),
        "telemetry_latency_ms_p99": float(np.percentile(latencies, 99)),
        "setpoints": result["sent"],
        "deadline_misses": int(np.sum(lateness > CONTROL_PERIOD)),
        "rejected": stats["mavlink"]["rejected"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 2.0, 5.0, 10.0, 20.0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds of offboard flight per speed")
    parser.add_argument("--skip-tick-cost", action="store_true")
    args = parser.parse_args(argv)
    if not args.skip_tick_cost:
        costs = tick_cost()
        print("Plant tick (4 ms simulated), median wall time per tick:")
        for key, value in costs.items():
            print(f"  {key:18s} {value:7.1f} us  ({4000.0 / value:5.1f}x real time)")
    print("\n| speed requested | achieved | late ticks | slips | tick CPU (us) | telemetry latency p50 / p99 (ms) | setpoints | deadline misses |")
    print("|---|---|---|---|---|---|---|---|")
    for speed in args.speeds:
        r = speed_run(speed, args.duration)
        print(f"| {r['speed_requested']:g} | {r['speed_achieved']:.2f} | {r['late_ticks']}/{r['ticks']} | {r['slips']} | "
              f"{r['tick_cpu_median_us']:.0f} | {r['telemetry_latency_ms_p50']:.2f} / {r['telemetry_latency_ms_p99']:.2f} | "
              f"{r['setpoints']} | {r['deadline_misses']} |", flush=True)
        if r["rejected"]:
            print(f"  (plant rejected: {r['rejected']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
