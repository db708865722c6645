"""A last resort for a process asked to stop: if its orderly stop has not ended it within a deadline, end it.

Every process of a SITL run stops cooperatively on SIGINT/SIGTERM (a flag its main loop polls), closing its
Zenoh session, sockets and logs on the way out. A close that blocks (a Zenoh session whose peers all died in
the same instant, when the owner was SIGKILLed and the kernel's death signal reached every child at once)
would leave the process running for ever, holding its ports. `arm_exit_deadline` starts a daemon timer when
the stop is asked; if the process is still there when it fires, it flushes what it can and leaves with
os._exit(128 + signal number). Logs written line by line (JsonLinesLog, CsvLog) are already on disk.

The timer is Python code: it cannot run while the main thread blocks inside a C call that keeps the
interpreter lock. So the same call also sets the kernel's alarm (`arm_kill_backstop`, SIGALRM at its default
action, which ends the process without running any Python) BACKSTOP_MARGIN_S later: the process ends even then,
with the signal SIGALRM instead of an exit code.

Neither can run when the main thread is already stuck, holding the interpreter lock, *before* the stop is
asked: a Python signal handler runs only in the main thread, between bytecodes, and a call into a native
library that waits with the lock held never gets there. So the SITL processes' main loops also keep a dead
man's switch (`keep_alive`): each turn pushes the kernel's alarm STALL_LIMIT_S ahead, and a loop that stops
turning is ended by the kernel that long after its last turn, and `stand_down` clears it once the loop and
its close are done.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

#: s between the stop request and the forced exit: far above an orderly stop (well under a second).
EXIT_DEADLINE_S = 5.0

#: s after the deadline at which the kernel's alarm ends a process whose deadline timer could not run.
BACKSTOP_MARGIN_S = 2.0

#: s a main loop may go without a turn (`keep_alive`) before the kernel ends its process: far above one turn
#: (well under a second, on a busy machine too), below the 20 s an owner waits for its children to go.
STALL_LIMIT_S = 10.0

_armed: threading.Timer | None = None
_last_keep_alive = -float("inf")


def _expire(name: str, signum: int) -> None:
    try:
        print(f"{name}: orderly stop took more than {EXIT_DEADLINE_S:g} s after signal {signum}; exiting now",
              file=sys.stderr, flush=True)
        sys.stdout.flush()
    finally:
        os._exit(128 + signum)


def arm_exit_deadline(name: str, signum: int, seconds: float = EXIT_DEADLINE_S) -> None:
    """Exit the process `seconds` from now unless it has ended by then (once; later calls do nothing).
    name: the process's name for the one line it prints. signum: the stop signal (the exit code is 128 + it)."""
    global _armed
    if _armed is not None:
        return
    _armed = threading.Timer(seconds, _expire, (name, int(signum)))
    _armed.daemon = True
    _armed.start()
    arm_kill_backstop(seconds + BACKSTOP_MARGIN_S)


def arm_kill_backstop(seconds: float) -> None:
    """Have the kernel end this process `seconds` from now (SIGALRM at its default action), whatever its threads
    are doing, unless it has exited by then. Replaces an earlier alarm. Call it from the main thread."""
    try:
        signal.signal(signal.SIGALRM, signal.SIG_DFL)  # nobody's handler: the kernel's default, termination
    except ValueError:  # not the main thread: the disposition is left as it is (Python's default is SIG_DFL)
        pass
    signal.setitimer(signal.ITIMER_REAL, seconds)


def keep_alive(seconds: float = STALL_LIMIT_S) -> None:
    """One turn of a main loop (call it from the main thread, every turn): the kernel's alarm is pushed to
    `seconds` from now, at most once a second. Does nothing once a stop has armed the exit deadline (its
    shorter alarm stands). The alarm stays armed after the loop ends, so the orderly close that follows is
    bounded too, until `stand_down`."""
    global _last_keep_alive
    if _armed is not None:
        return
    now = time.monotonic()
    if now - _last_keep_alive < 1.0:
        return
    _last_keep_alive = now
    arm_kill_backstop(seconds)


def stand_down() -> None:
    """The main loop and its close are done (call it from the main thread): the dead man's switch's alarm is
    cleared, unless a stop has armed the exit deadline (the process is on its way out), so a caller that goes on
    (a test that runs a main loop in its own process) is not ended later."""
    global _last_keep_alive
    if _armed is not None or _last_keep_alive == -float("inf"):
        return
    signal.setitimer(signal.ITIMER_REAL, 0.0)
    _last_keep_alive = -float("inf")
