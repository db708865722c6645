"""Where one in-process flight's time goes: the harness, the plant and the pipeline's parts.

Run: python benchmarks/profile_flight.py [SCENARIO ...] [--seed N] [--estimator KIND] [--rate HZ]
(default constant_velocity, seed 1). Flies the scenario once to warm up (and compile), once plain for the
total, then once with every part below wrapped in a timer (time.perf_counter around the call), and prints a
Markdown table: calls, total ms, us per call and share of the plain flight. Nested parts (indented) are
inside the part above them. The timers themselves cost about 0.2-0.4 us per call, so the wrapped flight is
slower than the plain one (both printed); cProfile distorts far more on code made of many small calls.
With numba installed, a last line gives the share of the flight spent inside compiled kernels (every kernel a
module of companion.core or sitl_plant calls from Python, timed the same way, the timers' own cost taken out):
what a faster kernel, or one batched over flights, could save at most; the rest is the Python around them.
Figures for notes, never for tests (a shared machine is noisy: run it a few times and quote medians).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import time
from pathlib import Path

import companion.core.pipeline as pipeline_module
import sitl_plant.vehicle.attitude_control as plant_module
import companion.core
import sitl_plant
import studies.closed_loop as harness
from companion.core import _jit
from interfaces.scenario import SCENARIOS_DIR, load_scenario
from studies.montecarlo import with_overrides

#: (owner, attribute, label, nested): what is timed, in the table's order
PARTS = (
    (pipeline_module.FollowingPipeline, "step_all", "pipeline step (all of it)", False),
    (pipeline_module.FollowingPipeline, "_advance_estimator", "estimator ticks (predicts)", True),
    (pipeline_module.FollowingPipeline, "_use_bearing", "bearing: correction + windowed FIM", True),
    (pipeline_module.FollowingPipeline, "_check_health", "bearing: health check", True),
    (pipeline_module.FollowingPipeline, "_act_on_health", "bearing: health actions", True),
    (pipeline_module.FollowingPipeline, "_update_mode", "track mode (reads the estimate)", True),
    (pipeline_module.FollowingPipeline, "_compute_setpoint", "setpoint: guidance, range control, attitude", True),
    (plant_module.AttitudeThrustVehicle, "advance", "plant: controller + mixer + RK4", False),
    (plant_module.AttitudeThrustVehicle, "measured_state", "plant: noisy feedback", False),
    (plant_module.AttitudeThrustVehicle, "kinematics", "plant: true state read-out", False),
    (plant_module.AttitudeThrustVehicle, "set_attitude_target", "plant: setpoint in", False),
    (harness, "_measure", "harness: bearing sensor", False),
    (harness, "_log_row", "harness: flight log row", False),
)


def _wrap(owner: object, attribute: str, label: str, totals: dict[str, list[float]]):
    function = getattr(owner, attribute)
    record = totals.setdefault(label, [0.0, 0])

    def timed(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            record[0] += time.perf_counter() - start
            record[1] += 1

    setattr(owner, attribute, timed)
    return function


def profile(path: Path, seed: int, overrides: dict) -> str:
    scenario, vehicle = load_scenario(path)
    if overrides:
        scenario = with_overrides(scenario, overrides)
    harness.simulate(scenario, vehicle, seed)  # warm-up (and the compiler, once per install)
    start = time.perf_counter()
    result = harness.simulate(scenario, vehicle, seed)
    plain = time.perf_counter() - start
    totals: dict[str, list[float]] = {}
    originals = [(owner, attribute, _wrap(owner, attribute, label, totals)) for owner, attribute, label, _ in PARTS]
    try:
        start = time.perf_counter()
        harness.simulate(scenario, vehicle, seed)
        wrapped = time.perf_counter() - start
    finally:
        for owner, attribute, function in originals:
            setattr(owner, attribute, function)
    steps = len(result.series["time"])
    flown = float(result.series["time"][-1])
    lines = [f"### {path.stem}, seed {seed}{' ' + str(overrides) if overrides else ''}",
             f"plain flight {plain * 1e3:.1f} ms ({flown / plain:.0f}x real time, {steps} loop steps, "
             f"{plain / steps * 1e6:.1f} us per step); with the timers {wrapped * 1e3:.1f} ms", "",
             "| part | calls | ms | us per call | share of the plain flight |", "|---|---:|---:|---:|---:|"]
    outer = 0.0
    for _, _, label, nested in PARTS:
        seconds, calls = totals.get(label, (0.0, 0))
        outer += 0.0 if nested else seconds
        name = f"&nbsp;&nbsp;{label}" if nested else label
        per_call = seconds / calls * 1e6 if calls else float("nan")
        lines.append(f"| {name} | {calls} | {seconds * 1e3:.1f} | {per_call:.2f} | {seconds / plain:.0%} |")
    lines.append(f"| harness loop itself (the rest) | {steps} | {(wrapped - outer) * 1e3:.1f} | "
                 f"{(wrapped - outer) / steps * 1e6:.2f} | {(wrapped - outer) / plain:.0%} |")
    return "\n".join(lines)


def _timer_cost(repeats: int = 200_000) -> float:
    """s per call that a timed wrapper (as in _wrap) adds around a function that does nothing."""
    totals: dict[str, list[float]] = {}

    class Empty:
        @staticmethod
        def call(*args):
            return None

    _wrap(Empty, "call", "empty", totals)
    start = time.perf_counter()
    for _ in range(repeats):
        Empty.call(1, 2, 3)
    return (time.perf_counter() - start) / repeats - totals["empty"][0] / repeats


def kernel_share(path: Path, seed: int, overrides: dict) -> str:
    """One line: compiled-kernel calls per loop step and the share of the plain flight spent inside them."""
    if not _jit.ENABLED:
        return "(kernels not compiled: numba missing or BOF_NO_JIT set; no kernel share)"
    from numba.core.registry import CPUDispatcher

    scenario, vehicle = load_scenario(path)
    if overrides:
        scenario = with_overrides(scenario, overrides)
    harness.simulate(scenario, vehicle, seed)  # everything the flight calls is compiled before any is wrapped
    start = time.perf_counter()
    result = harness.simulate(scenario, vehicle, seed)
    plain = time.perf_counter() - start
    modules = [importlib.import_module(info.name) for package in (companion.core, sitl_plant)
               for info in pkgutil.walk_packages(package.__path__, package.__name__ + ".")]
    totals: dict[str, list[float]] = {}
    originals, timed = [], {}
    for module in modules:
        for name, value in list(vars(module).items()):
            if isinstance(value, CPUDispatcher):
                if id(value) not in timed:  # one timer per kernel, however many modules import it
                    _wrap(module, name, "kernels", totals)
                    timed[id(value)] = getattr(module, name)
                else:
                    setattr(module, name, timed[id(value)])
                originals.append((module, name, value))
    try:
        harness.simulate(scenario, vehicle, seed)
    finally:
        for module, name, value in originals:
            setattr(module, name, value)
    seconds, calls = totals.get("kernels", (0.0, 0))
    inside = seconds - calls * 0.5 * _timer_cost()  # about half a timer's cost falls inside its own interval
    steps = len(result.series["time"])
    return (f"compiled kernels: {calls} calls ({calls / steps:.1f} per loop step), about {inside * 1e3:.1f} ms inside "
            f"them (dispatch included) = {inside / plain:.0%} of the plain flight ({plain * 1e3:.1f} ms)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenarios", nargs="*", default=["constant_velocity"], help="scenario names or files")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--estimator", default=None, help="override [estimator] kind (e.g. uplkf, ekf, imm)")
    parser.add_argument("--rate", type=float, default=None, help="override the bearing rate, Hz")
    args = parser.parse_args()
    overrides = {}
    if args.estimator:
        overrides["estimator.kind"] = args.estimator
    if args.rate:
        overrides["sensor.rate_hz"] = args.rate
    for name in args.scenarios:
        path = Path(name) if name.endswith(".toml") else SCENARIOS_DIR / f"{name}.toml"
        print(profile(path, args.seed, overrides))
        print()
        print(kernel_share(path, args.seed, overrides))
        print()


if __name__ == "__main__":
    main()
