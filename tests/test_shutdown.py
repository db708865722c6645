"""interfaces.shutdown: a process whose orderly stop hangs is ended by the deadline armed at the stop request,
with 128 + the signal number; one that stops in time is not touched; a main loop stuck before any stop is ended
by its dead man's switch."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

HANGS = """
import signal, threading, time
from interfaces.shutdown import arm_exit_deadline
def stop(signum, frame):
    arm_exit_deadline("hangs", signum, seconds=0.5)
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
threading.Event().wait()  # a close that never returns
"""

#: A stop that blocks inside a C call holding the interpreter lock (the regular expression engine backtracking
#: for ever): no Python thread, the deadline's timer included, can run again.
HOLDS_THE_LOCK = """
import re, signal
from interfaces.shutdown import arm_exit_deadline
def stop(signum, frame):
    arm_exit_deadline("holds", signum, seconds=0.5)
    re.match(r"(a+)+$", "a" * 64 + "b")
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
signal.pause()
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

#: A main loop that turns a few times, then gets stuck holding the interpreter lock (a C loop that never looks
#: at signals, unlike the regular expression engine). Its SIGTERM handler only sets the flag the loop would poll,
#: as the SITL processes' handlers do, so whether it ran before the loop got stuck or never runs, the stop
#: cannot end the process.
STUCK = """
import signal
from interfaces.shutdown import keep_alive
requested = []
signal.signal(signal.SIGTERM, lambda signum, frame: requested.append(signum))
for turn in range(3):
    if {keep}:
        keep_alive(1.0)
print("ready", flush=True)
sum(range(10 ** 13))
"""

#: A loop that goes on turning after the stop was asked: its turns do not push the stop's deadline away.
TURNS_ON = """
import signal, threading
from interfaces.shutdown import arm_exit_deadline, keep_alive
def stop(signum, frame):
    arm_exit_deadline("turns", signum, seconds=0.5)
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
while True:
    keep_alive(30.0)
    threading.Event().wait(0.05)
"""


def _run(source: str, timeout: float = 10.0) -> int:
    process = subprocess.Popen([sys.executable, "-c", source], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "ready"
        process.terminate()
        return process.wait(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def test_a_hanging_stop_is_ended_by_the_deadline():
    # it waits for ever otherwise: only the deadline can end it, with 128 + SIGTERM
    assert _run(HANGS) == 128 + 15


def test_a_stop_that_holds_the_interpreter_lock_is_ended_by_the_kernel_alarm():
    # the deadline's timer cannot run; the kernel's SIGALRM (default action) ends the process regardless
    assert _run(HOLDS_THE_LOCK) == -signal.SIGALRM


def test_an_orderly_stop_keeps_its_own_exit_code():
    assert _run(STOPS) == 0


def test_a_loop_stuck_before_the_stop_is_ended_by_its_dead_mans_switch():
    # without keep_alive nothing ends it (still there 3 s after SIGTERM); with it the kernel's alarm, 1 s after
    # the last turn
    with pytest.raises(subprocess.TimeoutExpired):
        _run(STUCK.format(keep=False), timeout=3.0)
    assert _run(STUCK.format(keep=True)) == -signal.SIGALRM


def test_a_loop_that_stands_down_is_not_ended_later():
    source = ("import time\nfrom interfaces.shutdown import keep_alive, stand_down\n"
              "keep_alive(0.5)\nstand_down()\ntime.sleep(1.5)\n")
    assert subprocess.run([sys.executable, "-c", source], timeout=10.0).returncode == 0


def test_turns_after_the_stop_do_not_push_its_deadline_away():
    assert _run(TURNS_ON) == 128 + 15


def test_free_ports_come_from_below_the_ephemeral_range_once_each_and_bindable():
    """A port handed out for a child to bind later must not be one the kernel can give any other socket that
    binds port 0 meanwhile: it lies below /proc/sys/net/ipv4/ip_local_port_range's start."""
    import socket as sockets
    from pathlib import Path as P

    from studies.processes import FREE_PORT_FLOOR, free_port

    floor = int(P("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    ports = [free_port() for _ in range(50)] + [free_port(sockets.SOCK_STREAM) for _ in range(10)]
    assert len(set(ports)) == len(ports)
    assert all(FREE_PORT_FLOOR <= port < floor for port in ports), (floor, ports)
    for port in ports[:5]:
        for kind in (sockets.SOCK_DGRAM, sockets.SOCK_STREAM):
            with sockets.socket(sockets.AF_INET, kind) as probe:
                probe.bind(("127.0.0.1", port))
