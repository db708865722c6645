"""Run a command while every core (or N of them) is kept busy, as on a laptop doing other things.

    python tests/busy.py [--burners N] [--rounds K] -- COMMAND [ARGS...]

Starts N CPU burners (default: one per core), each a process spinning on arithmetic at normal
priority, runs COMMAND K times in a row (default 1) while they spin, stops at the first round
that fails, and ends the burners whatever happens (the command's end, an error, SIGINT or SIGTERM;
a burner whose parent is gone stops by itself within a second). Prints each round's wall time
and the load average seen; exits with the first failing round's status, else 0.

`.ci/stress` uses it to run the real-time test files on a busy machine.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import subprocess
import sys
import time


def _burn(parent: int) -> None:
    """Spin until the parent is gone (checked every ~0.2 s of work)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when burners stop
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # (the parent's handler came with the fork)
    value = 1.0
    while os.getppid() == parent:
        deadline = time.monotonic() + 0.2
        while time.monotonic() < deadline:
            for _ in range(10_000):
                value = value * 1.0000001 + 1e-9
                if value > 1e6:
                    value = 1.0


def _stop(burners: list[multiprocessing.Process]) -> None:
    for burner in burners:
        if burner.is_alive():
            burner.terminate()
    for burner in burners:
        burner.join(timeout=5)
        if burner.is_alive():
            burner.kill()
            burner.join(timeout=5)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="run a command while CPU burners keep the cores busy",
                                     allow_abbrev=False)
    parser.add_argument("--burners", type=int, default=os.cpu_count() or 1,
                        help="CPU burner processes (default: one per core, %(default)s)")
    parser.add_argument("--rounds", type=int, default=1, help="times to run the command (default: %(default)s)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no command given (put it after --)")
    if args.burners < 0 or args.rounds < 1:
        parser.error("need --burners >= 0 and --rounds >= 1")

    def on_signal(signum, _frame):
        raise KeyboardInterrupt(signum)

    signal.signal(signal.SIGTERM, on_signal)
    context = multiprocessing.get_context("fork")
    burners = [context.Process(target=_burn, args=(os.getpid(),), daemon=True) for _ in range(args.burners)]
    status = 0
    try:
        for burner in burners:
            burner.start()
        for round_ in range(1, args.rounds + 1):
            started = time.monotonic()
            status = subprocess.call(command)
            load = os.getloadavg()[0]
            print(f"busy.py: round {round_} of {args.rounds}: exit {status} in {time.monotonic() - started:.0f} s, "
                  f"{args.burners} burners, load average {load:.1f}", flush=True)
            if status != 0:
                break
    except KeyboardInterrupt:
        status = 130
    finally:
        _stop(burners)
    return status


if __name__ == "__main__":
    sys.exit(main())
