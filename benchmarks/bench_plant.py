"""Time the SITL plant (attitude controller + mixer + RK4 rigid body) on one core, compiled vs plain Python.

Plant alone: advances an AttitudeThrustVehicle through 60 s of simulated time at the default
500 Hz with a gently varying attitude/thrust setpoint refreshed at 50 Hz, as the guidance loop
would. Whole flight (--flight): studies.closed_loop.simulate of constant_velocity, seed 1.
First flight (--first-flight): a fresh interpreter's first flight with an empty numba cache
(compilation included), with the cache filled, and without numba.

The kernels are compiled when numba is installed (`pip install -e ".[fast]"`) and BOF_NO_JIT is
unset; BOF_NO_JIT=1 runs the same code as plain Python. The choice is made at import, so each mode
runs in its own child interpreter; the modes alternate, round by round, so that both see the same
machine load. Reported: medians over every repeat of every round, and their ratio.

Run from the repository root:  PYTHONPATH=. python benchmarks/bench_plant.py [--flight] [--first-flight]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle
from sitl_plant.vehicle.params import QuadrotorParams, table1_params

SETPOINT_RATE_HZ = 50.0
ROOT = Path(__file__).resolve().parent.parent
MODES = {"compiled": {}, "plain": {"BOF_NO_JIT": "1"}}


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


def flight_once() -> float:
    """Wall time, s, of one in-process flight: constant_velocity, seed 1."""
    from interfaces.scenario import SCENARIOS_DIR, load_scenario
    from studies.closed_loop import simulate

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    start = time.perf_counter()
    simulate(scenario, vehicle, 1)
    return time.perf_counter() - start


def child(args: argparse.Namespace) -> None:
    """One mode's measurements in this interpreter, as JSON on stdout."""
    from sitl_plant import _jit

    if args.child == "first-flight":
        samples = [flight_once()]
    elif args.child == "flight":
        flight_once()  # warm-up (loads the compiled kernels from the cache)
        samples = [flight_once() for _ in range(args.repeats)]
    else:
        run_once(1.0, args.rate)  # warm-up
        samples = [run_once(args.seconds, args.rate)[0] for _ in range(args.repeats)]
    print(json.dumps({"compiled": _jit.ENABLED, "samples": samples}))


def spawn(kind: str, environment: dict[str, str], args: argparse.Namespace) -> dict:
    env = dict(os.environ, **environment)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if "BOF_NO_JIT" not in environment:
        env.pop("BOF_NO_JIT", None)
    command = [sys.executable, __file__, "--child", kind, "--seconds", str(args.seconds), "--repeats",
               str(args.repeats), "--rate", str(args.rate)]
    start = time.perf_counter()
    out = subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True, check=True).stdout
    result = json.loads(out.splitlines()[-1])
    result["process"] = time.perf_counter() - start
    return result


def side_by_side(kind: str, args: argparse.Namespace) -> dict[str, list[float]]:
    samples: dict[str, list[float]] = {mode: [] for mode in MODES}
    for _ in range(args.rounds):
        for mode, environment in MODES.items():
            result = spawn(kind, environment, args)
            if result["compiled"] != (mode == "compiled"):
                raise SystemExit(f"{mode}: the child's kernels are {'' if result['compiled'] else 'not '}compiled"
                                 " (is numba installed? pip install -e '.[fast]')")
            samples[mode] += result["samples"]
    return samples


def report(title: str, samples: dict[str, list[float]], simulated: float) -> None:
    print(title)
    medians = {mode: statistics.median(values) for mode, values in samples.items()}
    for mode, values in samples.items():
        print(f"  {mode:9s} median {medians[mode] * 1e3:8.1f} ms  (min {min(values) * 1e3:.1f}, max "
              f"{max(values) * 1e3:.1f}, n={len(values)})  {simulated / medians[mode]:8.0f}x real time")
    print(f"  plain / compiled: {medians['plain'] / medians['compiled']:.1f}x")


def first_flight(args: argparse.Namespace) -> None:
    """A fresh interpreter's first flight: empty numba cache, filled cache, no numba."""
    flights: dict[str, list[float]] = {"empty cache": [], "cached": [], "plain": []}
    processes: dict[str, list[float]] = {mode: [] for mode in flights}

    def run(mode: str, environment: dict[str, str]) -> None:
        result = spawn("first-flight", environment, args)
        flights[mode] += result["samples"]
        processes[mode].append(result["process"])

    for _ in range(args.rounds):
        with tempfile.TemporaryDirectory() as cache:  # NUMBA_CACHE_DIR: a cache of its own, empty at first
            run("empty cache", {"NUMBA_CACHE_DIR": cache})
            run("cached", {"NUMBA_CACHE_DIR": cache})
        run("plain", MODES["plain"])
    print(f"first flight in a fresh interpreter (constant_velocity, seed 1), {args.rounds} rounds: "
          "the flight / the whole child process (interpreter start and imports included)")
    for mode in flights:
        print(f"  {mode:11s} flight median {statistics.median(flights[mode]):5.2f} s  "
              f"process median {statistics.median(processes[mode]):5.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per plant repeat")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats per child")
    parser.add_argument("--rounds", type=int, default=3, help="alternations of the two modes")
    parser.add_argument("--rate", type=float, default=500.0, help="plant rate, Hz")
    parser.add_argument("--flight", action="store_true", help="also time whole in-process flights")
    parser.add_argument("--first-flight", action="store_true", help="also time the first flight of a fresh interpreter")
    parser.add_argument("--child", choices=["plant", "flight", "first-flight"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args)
        return

    steps = args.seconds * args.rate
    plant = side_by_side("plant", args)
    report(f"plant alone: {args.seconds:g} s at {args.rate:g} Hz, setpoints at {SETPOINT_RATE_HZ:g} Hz, "
           f"{args.rounds} rounds x {args.repeats} repeats (wall time)", plant, args.seconds)
    for mode, values in plant.items():
        print(f"  {mode:9s} per plant step {statistics.median(values) / steps * 1e6:.2f} us")
    if args.flight:
        report(f"whole flight: simulate(constant_velocity, seed 1), 60 s, {args.rounds} rounds x {args.repeats} repeats",
               side_by_side("flight", args), 60.0)
    if args.first_flight:
        first_flight(args)


if __name__ == "__main__":
    main()
