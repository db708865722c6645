"""Run folders: <parent>/<stem>-<local time to the second>, never shared by two runs.

Every command that writes a run folder (bof-sim, bof-sitl, bof-montecarlo, bof-campaign, the companion's default
log folder, ...) names it by its start time to the second. Two runs started in the same second, in two terminals
or by a script, would otherwise write into one folder and overwrite each other's logs; the second gets <name>-2.
"""
from __future__ import annotations

import itertools
import time
from pathlib import Path


def new_run_folder(parent: Path | str, stem: str, when: time.struct_time | None = None) -> Path:
    """Make and return parent/<stem>-<YYYYmmdd-HHMMSS> (local time `when`, default now), or <that>-2, -3, ... when
    another run already holds the name. The folder is made here without exist_ok, so no two calls, in any two
    processes, return the same folder; `parent` is made if missing."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    name = f"{stem}-{time.strftime('%Y%m%d-%H%M%S', when or time.localtime())}"
    for count in itertools.count(1):
        folder = parent / (name if count == 1 else f"{name}-{count}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise AssertionError("unreachable")  # itertools.count never ends
