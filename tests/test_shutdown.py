"""interfaces.shutdown: a process whose orderly stop hangs is ended by the deadline armed at the stop request,
with 128 + the signal number; one that stops in time is not touched."""

from __future__ import annotations

import subprocess
import sys

HANGS = """
import signal, threading, time
from interfaces.shutdown import arm_exit_deadline
def stop(signum, frame):
    arm_exit_deadline("hangs", signum, seconds=0.5)
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
threading.Event().wait()  # a close that never returns
"""

STOPS = """
import signal, sys
from interfaces.shutdown import arm_exit_deadline
stopped = []
def stop(signum, frame):
    arm_exit_deadline("stops", signum, seconds=0.5)
    stopped.append(signum)
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
while not stopped:
    signal.pause()
sys.exit(0)
"""


def _run(source: str) -> int:
    process = subprocess.Popen([sys.executable, "-c", source], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "ready"
        process.terminate()
        return process.wait(timeout=10.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def test_a_hanging_stop_is_ended_by_the_deadline():
    # it waits for ever otherwise: only the deadline can end it, with 128 + SIGTERM
    assert _run(HANGS) == 128 + 15


def test_an_orderly_stop_keeps_its_own_exit_code():
    assert _run(STOPS) == 0
