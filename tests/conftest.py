"""Shared fixtures: scenario files by name, and the test's end of a Zenoh link to sitl-target."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import sys
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import settings

from interfaces.link_schema import CLOCK_KEY, ClockTick, TargetFix, decode_target_fix, encode_clock, target_fix_key
from interfaces.scenario import SCENARIOS_DIR
from interfaces.zenoh_transport import open_session, publisher, zenoh_config
from studies.executors import compile_kernels
from studies.processes import free_port

# CI (CI=true, as .ci/run is started) runs every property test on hypothesis's fixed derandomised
# examples, so a CI result can be reproduced exactly; a local run explores new examples each time.
# Neither has hypothesis's per-example deadline: a deadline is a timed assertion, and an example that happens
# to be the first to call a numba kernel (compiled, or loaded from the cache, on first use) or that runs on a
# busy machine takes longer without being wrong. Timings are the benchmarks' (benchmarks/).
settings.register_profile("ci", derandomize=True, print_blob=True, deadline=None)
settings.register_profile("local", deadline=None)
settings.load_profile("ci" if os.environ.get("CI", "").lower() in ("1", "true", "yes") else "local")

# With numba the plant's and the companion's kernels are compiled on first use, or loaded from numba's cache on
# disk (about 2 s). On an empty cache (a fresh clone) compiling them takes one to several minutes of one core
# (3.3 minutes on an AMD EPYC machine). Done here, before any test, by one process at a time: the first xdist
# worker fills the cache while the other waits and then loads it, so no real-time test shares the machine with
# a compiler or starts a companion on a partly filled cache. No-op without numba.
_KERNEL_LOCK = Path(tempfile.gettempdir()) / (
    "bof-kernels-" + hashlib.sha256(str(Path(__file__).resolve().parent.parent).encode()).hexdigest()[:16] + ".lock")
with _KERNEL_LOCK.open("a") as _handle:
    fcntl.flock(_handle, fcntl.LOCK_EX)
    try:
        compile_kernels()
    finally:
        fcntl.flock(_handle, fcntl.LOCK_UN)


#: Test files that fly processes or sockets against the wall clock (SITL flights, signals, links, a
#: companion on a socket). With pytest-xdist (`-n 2 --dist loadgroup`, as pyproject's addopts ask) they run
#: one after another on one worker, while the other worker takes the tests that only compute; so no two
#: real-time flights ever share the machine with each other, only with one computing test at a time.
REAL_TIME_FILES = frozenset({
    "test_campaign.py", "test_companion_app.py", "test_companion_console.py",
    "test_companion_precompile.py", "test_config_hostile.py", "test_full_sitl.py", "test_full_sitl_swarm.py",
    "test_intruder.py", "test_link.py",
    "test_mavlink_signing.py", "test_mavlink_vehicle.py", "test_mission.py", "test_plant_standalone.py",
    "test_shutdown.py", "test_signals.py", "test_sitl_cli.py", "test_sitl_malformed.py", "test_sitl_mavsdk.py",
    "test_study_interrupts.py", "test_swarm_schema.py", "test_swarm_sitl_parts.py", "test_swarm_sitl_signals.py",
    "test_target_sim.py", "test_zenoh_namespace.py", "test_zenoh_security.py",
})


#: Real-time test files that need the machine to themselves: the seven processes of a three-pursuer SITL flight
#: starve beside a computing test (a companion then misses its vehicle's telemetry for a second and lands).
#: While such a module runs, the computing worker waits between its tests (an exclusive lock that every
#: computing test takes shared).
EXCLUSIVE_FILES = frozenset({"test_full_sitl_swarm.py"})


def _machine_lock(factory) -> Path | None:
    """The lock file every xdist worker of this session shares, or None outside xdist."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return None
    return factory.getbasetemp().parent / "machine.lock"


@contextlib.contextmanager
def _holding(path: Path | None, mode: int) -> Iterator[None]:
    """The session's machine lock held in `mode` (fcntl.LOCK_EX or LOCK_SH) meanwhile; nothing when path is None."""
    if path is None:
        yield
        return
    with path.open("a") as handle:
        fcntl.flock(handle, mode)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@pytest.fixture(scope="module", autouse=True)
def _machine_to_itself(request, tmp_path_factory):
    exclusive = request.path.name in EXCLUSIVE_FILES
    with _holding(_machine_lock(tmp_path_factory) if exclusive else None, fcntl.LOCK_EX):
        yield


@pytest.fixture(autouse=True)
def _machine_shared(request, tmp_path_factory):
    computing = request.path.name not in REAL_TIME_FILES
    if not computing and request.config.getoption("loadgroup", default=False) \
            and not request.node.nodeid.endswith("@real_time"):
        # Under `--dist loadgroup` xdist tags each grouped test's id with its group; untagged, the real-time
        # tests would be spread over both workers and fly side by side, so none of them runs.
        pytest.fail(f"pytest-xdist did not group the real-time tests: pytest {pytest.__version__} with this "
                    "pytest-xdist does not support --dist loadgroup (see the test extra in pyproject.toml)",
                    pytrace=False)
    with _holding(_machine_lock(tmp_path_factory) if computing else None, fcntl.LOCK_SH):
        yield


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the groups
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in REAL_TIME_FILES:
            item.add_marker(pytest.mark.xdist_group("real_time"))


@pytest.fixture
def scenario_path() -> Callable[[str], Path]:
    """name -> path of the shipped scenario file config/scenarios/<name>.toml."""

    def _path(name: str) -> Path:
        return SCENARIOS_DIR / f"{name}.toml"

    return _path


@pytest.fixture
def app(tmp_path, scenario_path):
    """A companion app on the constant-velocity scenario: no vehicle and no sockets; its recorder closed after."""
    from companion.app import CompanionApp
    from interfaces.scenario import load_scenario

    scenario, vehicle = load_scenario(scenario_path("constant_velocity"))
    application = CompanionApp(scenario, vehicle, tmp_path / "run")
    yield application
    application.recorder.close()


class ClockAndFixes:
    """The test's end of the link: a listening session (127.0.0.1, free port) that publishes
    the simulation clock and collects the fixes of one sender."""

    def __init__(self, sender: str) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        self.session = open_session(zenoh_config(listen=[self.endpoint]))
        self.clock = publisher(self.session, CLOCK_KEY)
        self.fixes: list[TargetFix] = []
        self._lock = threading.Lock()
        self._closed = False
        self.session.declare_subscriber(target_fix_key(sender), self._on_fix)
        self.seq = 0

    def _on_fix(self, sample) -> None:
        fix = decode_target_fix(sample.payload)
        with self._lock:
            self.fixes.append(fix)

    def received(self) -> list[TargetFix]:
        with self._lock:
            return list(self.fixes)

    def run_clock(self, until_sim: float, step: float, period: float, timeout: float, done=lambda: False) -> float:
        """Tick simulated time by `step` every `period` wall seconds up to `until_sim`; returns the last stamp."""
        stamp = self.seq * step
        deadline = time.monotonic() + timeout
        while stamp < until_sim - 1e-9 and time.monotonic() < deadline and not done():
            self.seq += 1
            stamp = self.seq * step
            self.clock.put(encode_clock(ClockTick("plant", self.seq, stamp)))
            time.sleep(period)
        return stamp

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.session.close()


@pytest.fixture
def clock_and_fixes() -> Iterator[Callable[[str], ClockAndFixes]]:
    """sender -> an open ClockAndFixes link; every link opened is closed at teardown."""
    links: list[ClockAndFixes] = []

    def _open(sender: str) -> ClockAndFixes:
        link = ClockAndFixes(sender)
        links.append(link)
        return link

    yield _open
    for link in links:
        link.close()


@pytest.fixture
def sitl_target_fixes(clock_and_fixes) -> Callable[..., list]:
    """(scenario path, output folder, *extra sitl-target arguments) -> the fixes a `sitl-target` process published
    over a loopback Zenoh link while a test clock ran it for 4 s of scenario time at 10 Hz (NED frame); the child
    is stopped and its exit code checked (0) before the fixes are returned."""
    from studies.processes import ChildProcess

    def _run(path, folder, *extra: str) -> list:
        link = clock_and_fixes("target-1")
        child = None
        try:
            command = [sys.executable, "-m", "sitl_plant.world.target_publisher", "--config", str(path),
                       "--zenoh-connect", link.endpoint, "--rate", "10", "--frame", "ned", *extra, "--duration", "4.0"]
            child = ChildProcess(command, folder / "target.out", ready="sitl-target ready").start(timeout=20.0)
            link.run_clock(until_sim=5.0, step=0.1, period=0.01, timeout=15.0, done=lambda: not child.running)
            child.process.wait(10.0)
            exit_code, output = child.process.returncode, child.output()
        finally:
            if child is not None:
                child.stop()
        assert exit_code == 0, output
        return link.received()

    return _run
