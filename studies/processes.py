"""Starting and stopping the SITL's processes: free loopback ports, readiness, clean shutdown.

Used by the tests, the benchmarks and the full-SITL command: every child is started
with its output in a log file, waited for until it prints its ready line, and
stopped with SIGINT, then SIGTERM, then SIGKILL, so nothing outlives its owner.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path


def free_port(kind: int = socket.SOCK_DGRAM, host: str = "127.0.0.1") -> int:
    """A port the kernel just gave out on loopback (free now; tiny race until it is bound again)."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


class ChildProcess:
    """A child process whose stdout+stderr go to `log_path`; `ready` is a line prefix it prints when ready."""

    def __init__(self, command: list[str], log_path: Path, ready: str | None = None, env: dict | None = None) -> None:
        self.command = command
        self.log_path = Path(log_path)
        self.ready = ready
        self.env = env
        self.process: subprocess.Popen | None = None
        self._log = None

    def start(self, timeout: float = 30.0) -> "ChildProcess":
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("w")
        env = dict(os.environ if self.env is None else self.env)
        env.setdefault("PYTHONUNBUFFERED", "1")
        self.process = subprocess.Popen(self.command, stdout=self._log, stderr=subprocess.STDOUT, env=env,
                                        start_new_session=True)
        if self.ready is not None:
            self.wait_for_line(self.ready, timeout)
        return self

    def output(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def wait_for_line(self, prefix: str, timeout: float) -> str:
        """Block until the child has printed a line starting with prefix; RuntimeError if it dies or times out."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self.output().splitlines():
                if line.startswith(prefix):
                    return line
            if self.process.poll() is not None:
                raise RuntimeError(f"{self.command[0]} exited with {self.process.returncode} before '{prefix}':\n{self.output()}")
            time.sleep(0.05)
        raise RuntimeError(f"{self.command[0]} did not print '{prefix}' within {timeout:g} s:\n{self.output()}")

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGINT, then SIGTERM, then SIGKILL (to the whole process group); returns the exit code."""
        if self.process is None:
            return None
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0)):
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

    def kill(self) -> None:
        """SIGKILL at once (a crash, for fault tests)."""
        if self.running:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(5.0)

    def __enter__(self) -> "ChildProcess":
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()


def plant_command(config: Path | None = None, speed_factor: float | None = None, companion_port: int | None = None,
                  gcs_port: int | None = None, log_dir: Path | None = None, extra: list[str] | None = None) -> list[str]:
    """The sitl-plant command line, run with this interpreter."""
    command = [sys.executable, "-m", "sitl_plant.sitl", "--quiet"]
    for flag, value in (("--config", config), ("--speed-factor", speed_factor), ("--companion-port", companion_port),
                        ("--gcs-port", gcs_port), ("--log-dir", log_dir)):
        if value is not None:
            command += [flag, str(value)]
    return command + list(extra or [])


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
