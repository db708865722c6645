"""SIGTERM to a three-pursuer bof-sitl mid-flight: every one of its seven children stops and writes its summary.

Apart from tests/test_full_sitl_swarm.py, whose flight needs the machine to itself: nothing here judges a flight,
so this runs beside a computing test like the other real-time files.
"""

from __future__ import annotations

import json

from studies.processes import free_port
from tests.swarm_config import COUNT, scenario_copy


def test_sigterm_mid_flight_stops_all_seven_children_and_writes_every_summary(tmp_path):
    """bof-sitl as a real process (own session): once every companion follows, SIGTERM; every child
    (3 plants, 3 companions, 1 target) is gone, each companion wrote its summary (stopped by SIGTERM) and
    bof-sitl wrote the run's (interrupted)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import psutil

    out = tmp_path / "runs"
    log = (tmp_path / "bof-sitl.out").open("w")
    # The signal must find every companion following: on a busy machine one may engage a minute after the others,
    # which by then would have flown the shipped 60 s and landed. So the scenario is flown for 10 min here; the
    # signal ends it as soon as all three follow.
    config = scenario_copy(tmp_path / "swarm_long.toml", 600.0)
    # At 2x: nothing here judges the flight, and the seven processes take off in half the wall time (they need
    # about 0.8 of a core at 2x; a computing test may run beside them, and a companion that engages late only
    # delays the signal).
    process = subprocess.Popen([sys.executable, "-m", "studies.full_sitl", str(config), "--speed-factor", "2", "--out",
                                str(out), "--no-plots", "--quiet", "--gcs-port", str(free_port())],
                               stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    children: list[int] = []
    try:
        deadline = time.monotonic() + 120.0
        while True:
            assert process.poll() is None, (tmp_path / "bof-sitl.out").read_text()
            assert time.monotonic() < deadline, "the companions did not all follow within 120 s"
            folders = list(out.glob("sitl-*")) if out.exists() else []
            outs = [folders[0] / f"pursuer-{k}" / "companion.out" for k in range(1, COUNT + 1)] if folders else []
            if outs and all(p.exists() and "companion: following" in p.read_text(errors="replace") for p in outs):
                break
            time.sleep(0.2)
        children = [child.pid for child in psutil.Process(process.pid).children(recursive=True)]
        assert len(children) >= 2 * COUNT + 1
        process.send_signal(signal.SIGTERM)
        process.wait(30.0)
        assert process.returncode == 128 + signal.SIGTERM
        alive = []
        for pid in children:
            try:
                if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                    alive.append(pid)
            except psutil.NoSuchProcess:
                pass
        assert alive == []
        folder = folders[0]
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["interrupted"] == "SIGTERM" and summary["termination"] == "interrupted"
        for k in range(1, COUNT + 1):
            companion = json.loads((folder / f"pursuer-{k}" / "companion" / "summary.json").read_text())
            assert companion["stopped_by"] == "SIGTERM" and companion["pursuer_id"] == k
            assert (folder / f"pursuer-{k}" / "plant" / "stats.json").exists()
    finally:
        for pid in [process.pid, *children]:
            try:
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        try:
            process.wait(5.0)
        except subprocess.TimeoutExpired:
            pass
        log.close()
