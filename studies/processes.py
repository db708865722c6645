"""Starting and stopping the SITL's processes: free loopback ports, readiness, clean shutdown.

Used by the tests, the benchmarks and the full-SITL command: every child is started
in its own session (so its own process group: a terminal's Ctrl-C reaches only the
owner, which decides), with its output in a log file, waited for until it prints its
ready line, and stopped with SIGTERM, then SIGKILL after a grace period, so nothing
outlives its owner.

When the owner dies without stopping them (SIGKILL, a crash), the kernel tells each
child: on Linux every child is started through a tiny trampoline (`python -m
studies.processes --parent PID -- COMMAND...`) that sets PR_SET_PDEATHSIG = SIGTERM
on itself with prctl(2) and then execs the command, so the child gets SIGTERM the
moment the thread that started it ends. This is done in the fresh child after fork,
not in a preexec_fn (unsafe in a parent with threads, such as Zenoh's), and it needs
no cooperation from the child beyond honouring SIGTERM, which every SITL process does
(and the companion bounds its exit to about 2 s). A race (the owner dying between fork
and prctl) is closed by checking the parent pid after prctl. Elsewhere (no prctl) the
children are started directly and only the owner's own signal handling stops them.
"""

from __future__ import annotations

import ctypes
import os
import random
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path

#: Signals that make bof-sitl (or any owner using StopSignals) stop its children and write its summaries.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: s between SIGTERM and SIGKILL when stopping children.
GRACE_PERIOD = 2.5
_PR_SET_PDEATHSIG = 1  # linux/prctl.h
#: The ISO-8601 UTC time stamp that may open a child's log line (the companion's: 2026-12-02T13:45:01.234Z).
_LEADING_STAMP = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z ")


class Interrupted(Exception):
    """A stop signal arrived (StopSignals.check); signum says which."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum = signum


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP recorded instead of killing the process (a context manager, main thread).

    `received` is the first signal number (None before). The owner polls `check()` (raises
    Interrupted) in its loops, so it is never interrupted in the middle of its own cleanup.
    The previous handlers are restored on exit.
    """

    def __init__(self, signals: Iterable[int] = STOP_SIGNALS) -> None:
        self.signals = tuple(signals)
        self.received: int | None = None
        self.received_at: float | None = None  # time.monotonic() of the first signal
        self._previous: dict = {}

    def _handle(self, signum, frame) -> None:  # noqa: ARG002
        if self.received is None:
            self.received, self.received_at = signum, time.monotonic()

    def check(self) -> None:
        if self.received is not None:
            raise Interrupted(self.received)

    def __enter__(self) -> "StopSignals":
        self._previous = {sig: signal.signal(sig, self._handle) for sig in self.signals}
        return self

    def __exit__(self, *exc_info) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def death_signal_supported() -> bool:
    """True where children can be told of their owner's death by the kernel (Linux prctl)."""
    return sys.platform.startswith("linux")


def with_death_signal(command: list[str]) -> list[str]:
    """`command` wrapped in the trampoline that gives it SIGTERM when this process's current thread ends."""
    if not death_signal_supported():
        return list(command)
    return [sys.executable, "-m", "studies.processes", "--parent", str(os.getpid()), "--", *command]


def wait_for(condition, timeout: float, what: str, interval: float = 0.1) -> None:
    """Poll `condition()` every `interval` s until it is true (`poll_until`); RuntimeError naming `what` after
    `timeout` s."""
    if not poll_until(condition, timeout, interval):
        raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")


def set_death_signal(parent: int) -> str | None:
    """In a fresh child of `parent` (pid): ask the kernel for SIGTERM when the thread of `parent` that started this
    process ends (prctl PR_SET_PDEATHSIG), then check that `parent` is still the parent (it may have died before
    the prctl). None when set; else why not (the caller should exit: nobody would ever stop it)."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
        return f"prctl failed: {os.strerror(ctypes.get_errno())}"
    if os.getppid() != parent:
        return f"the owner (pid {parent}) is gone"
    return None


class RaisingStopSignals(StopSignals):
    """StopSignals that raise Interrupted in the main thread at the first signal, for loops that wait on workers
    rather than poll (the study commands). Every later signal is ignored from then on, so the cleanup that follows
    (stopping the workers, closing the logs, saying what was kept) is not itself interrupted: a second Ctrl-C used
    to leave the parent waiting on its workers for good. Without a signal the previous handlers are restored on
    exit; after one they are not (the command is on its way out)."""

    def _handle(self, signum, frame) -> None:
        for sig in self.signals:
            signal.signal(sig, signal.SIG_IGN)
        super()._handle(signum, frame)
        raise Interrupted(signum)

    def __exit__(self, *exc_info) -> None:
        if self.received is None:
            super().__exit__(*exc_info)


def _trampoline(argv: list[str]) -> int:
    """`--parent PID -- COMMAND...`: set PR_SET_PDEATHSIG = SIGTERM, make sure PID is still the parent, exec."""
    if len(argv) < 4 or argv[0] != "--parent" or argv[2] != "--":
        print("usage: python -m studies.processes --parent PID -- COMMAND...", file=sys.stderr)
        return 2
    problem = set_death_signal(int(argv[1]))
    if problem is not None:
        if problem.startswith("prctl"):
            print(f"studies.processes: {problem}", file=sys.stderr)
        return 1
    command = argv[3:]
    os.execvp(command[0], command)
    return 1  # not reached


#: The lowest port free_port hands out; it draws below the kernel's ephemeral range (ip_local_port_range).
FREE_PORT_FLOOR = 20000
_handed_out: set[int] = set()


def _ephemeral_floor() -> int:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def poll_until(condition, timeout: float, interval: float = 0.01) -> bool:
    """Call condition() every interval s until it is true or timeout s (monotonic clock) have passed; its last
    value. For waits on what another thread or process does, where nothing signals it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(interval)
    return bool(condition())


def free_port(kind: int = socket.SOCK_DGRAM, host: str = "127.0.0.1") -> int:
    """A loopback port that is free now, drawn at random below the kernel's ephemeral range.

    Between this call and the moment its user binds it, the port is open to anyone: a port the kernel gave
    out for bind(0) could meanwhile go to any other socket that binds port 0 (a test's client beside a SITL
    flight, a MAVSDK connection), which then receives the flight's datagrams. Ports below the ephemeral range
    are never given out for bind(0); each is handed out once per process, and checked bindable, for UDP and
    TCP alike. Falls back to bind(0) when the range below is empty or full."""
    floor = _ephemeral_floor()
    if floor - 1 > FREE_PORT_FLOOR:
        draw = random.Random()
        for _ in range(200):
            port = draw.randrange(FREE_PORT_FLOOR, floor)
            if port in _handed_out:
                continue
            if all(_bindable(host, port, each) for each in (socket.SOCK_DGRAM, socket.SOCK_STREAM)):
                _handed_out.add(port)
                return port
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


def _bindable(host: str, port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as probe:
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True


class ChildProcess:
    """A child process whose stdout+stderr go to `log_path`; `ready` is a line prefix it prints when ready (after
    the line's time stamp, if it has one)."""

    def __init__(self, command: list[str], log_path: Path, ready: str | None = None, env: dict | None = None) -> None:
        self.command = command
        self.log_path = Path(log_path)
        self.ready = ready
        self.env = env
        self.process: subprocess.Popen | None = None
        self._log = None

    def start(self, timeout: float = 30.0, stop: StopSignals | None = None) -> "ChildProcess":
        """Start it (own session, death signal; see the module) and wait for its ready line; `stop`: give up
        waiting (Interrupted) when a stop signal arrives."""
        self.spawn()
        self.wait_ready(timeout, stop)
        return self

    def spawn(self) -> "ChildProcess":
        """Start it (own session, death signal; see the module) without waiting for its ready line."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("w")
        env = dict(os.environ if self.env is None else self.env)
        env.setdefault("PYTHONUNBUFFERED", "1")
        self.process = subprocess.Popen(with_death_signal(self.command), stdout=self._log, stderr=subprocess.STDOUT,
                                        env=env, start_new_session=True)
        return self

    def wait_ready(self, timeout: float = 30.0, stop: StopSignals | None = None) -> None:
        """Block until it has printed its ready line (at once when it has none); see `wait_for_line`."""
        if self.ready is not None:
            self.wait_for_line(self.ready, timeout, stop)

    def output(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def wait_for_line(self, prefix: str, timeout: float, stop: StopSignals | None = None) -> str:
        """Block until the child has printed a line starting with prefix (after a leading ISO-8601 UTC time stamp,
        if any); returns the line, stamp removed. RuntimeError if it dies or times out, Interrupted if `stop` has
        received a signal."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if stop is not None:
                stop.check()
            for line in self.output().splitlines():
                line = _LEADING_STAMP.sub("", line, count=1)
                if line.startswith(prefix):
                    return line
            if self.process.poll() is not None:
                raise RuntimeError(f"{self.command[0]} exited with {self.process.returncode} before '{prefix}':\n{self.output()}")
            time.sleep(0.05)
        raise RuntimeError(f"{self.command[0]} did not print '{prefix}' within {timeout:g} s:\n{self.output()}")

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout: float = GRACE_PERIOD) -> int | None:
        """SIGTERM, then SIGKILL after `timeout` s (to the whole process group); returns the exit code."""
        if self.process is None:
            return None
        for sig, wait in ((signal.SIGTERM, timeout), (signal.SIGKILL, 3.0)):
            if self.process.poll() is not None:
                break
            try:
                os.killpg(self.process.pid, sig)
            except ProcessLookupError:
                break
            try:
                self.process.wait(wait)
            except subprocess.TimeoutExpired:
                continue
        code = self.process.poll()
        if self._log is not None:
            self._log.close()
            self._log = None
        return code

    def signal_group(self, sig: int) -> bool:
        """Send `sig` to the child's process group; False if there is none any more."""
        if self.process is None:
            return False
        try:
            os.killpg(self.process.pid, sig)
        except (ProcessLookupError, PermissionError):
            return False
        return True

    def close_log(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None

    def kill(self) -> None:
        """SIGKILL at once (a crash, for fault tests)."""
        if self.running:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(5.0)

    def __enter__(self) -> "ChildProcess":
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()


def stop_all(children: Iterable[ChildProcess], grace: float = GRACE_PERIOD) -> list[int | None]:
    """Stop every child together: SIGTERM to each process group, then SIGKILL to the groups still there
    after `grace` s of wall time. Returns the exit codes (None for a child never started); a child
    killed by a signal has a negative code. Takes at most about grace + 1 s."""
    children = list(children)
    for child in children:
        if child.running:
            child.signal_group(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for child in children:
        if child.process is None:
            continue
        try:
            child.process.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
    for child in children:
        if child.process is None:
            continue
        if child.running:  # only while the leader lives: a reaped leader's pid may be reused
            child.signal_group(signal.SIGKILL)
        try:
            child.process.wait(1.0)
        except subprocess.TimeoutExpired:
            pass
        child.close_log()
    return [child.process.poll() if child.process is not None else None for child in children]


def plant_command(config: Path | None = None, speed_factor: float | None = None, companion_port: int | None = None,
                  gcs_port: int | None = None, log_dir: Path | None = None, extra: list[str] | None = None) -> list[str]:
    """The sitl-plant command line, run with this interpreter."""
    command = [sys.executable, "-m", "sitl_plant.sitl", "--quiet"]
    for flag, value in (("--config", config), ("--speed-factor", speed_factor), ("--companion-port", companion_port),
                        ("--gcs-port", gcs_port), ("--log-dir", log_dir)):
        if value is not None:
            command += [flag, str(value)]
    return command + list(extra or [])


def start_together(children, stop: StopSignals | None = None, timeout: float = 60.0) -> None:
    """Start every child at once, then wait (up to `timeout` wall s in all) for each one's ready line, in order:
    their imports and set-up overlap instead of adding up. Children that talk to one another must find each other
    whichever is up first (Zenoh peers retry their connect endpoints; MAVLink over UDP needs no connection)."""
    children = list(children)
    for child in children:
        child.spawn()
    deadline = time.monotonic() + timeout
    for child in children:
        child.wait_ready(max(1.0, deadline - time.monotonic()), stop)


def start_plant(log_dir: Path, config: Path | None = None, speed_factor: float = 1.0,
                companion_port: int | None = None, gcs_port: int | None = None, extra: list[str] | None = None,
                timeout: float = 30.0) -> tuple[ChildProcess, int, int]:
    """Start sitl-plant on free loopback ports; returns (process, companion_port, gcs_port)."""
    companion_port = companion_port or free_port()
    gcs_port = gcs_port or free_port()
    command = plant_command(config, speed_factor, companion_port, gcs_port, log_dir, extra)
    child = ChildProcess(command, Path(log_dir) / "plant.out", ready="sitl-plant ready")
    child.start(timeout)
    return child, companion_port, gcs_port


if __name__ == "__main__":
    sys.exit(_trampoline(sys.argv[1:]))
