"""`companion --precompile`: the deployment step that fills numba's cache before a flight (docs/guide/in-process.md, "Speed")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from companion import app
from companion.core import _jit


def test_precompile_names_a_cache_that_holds_the_kernels(capsys):
    assert app.main(["--precompile"]) == 0
    printed = capsys.readouterr().out.strip()
    if not _jit.ENABLED:  # a run with BOF_NO_JIT=1 (the kernels' plain-Python mode)
        assert "plain Python" in printed
        return
    assert printed.startswith("companion: kernels ready in ")
    folder = Path(printed.rsplit("cached in ", 1)[1])
    # numba's index files of the kernels the warm-up compiled, in the folder it names
    index_files = {path.name.split("-")[0] for path in folder.glob("*.nbi")}
    assert {"estimators._correct_into", "imm._imm_correction", "guidance._tracking_command"} <= index_files


def test_precompile_without_numba_says_so_and_opens_nothing(tmp_path):
    # In an empty folder: --precompile makes no run folder and writes no log (it returns before the configuration).
    environment = dict(os.environ, BOF_NO_JIT="1")
    done = subprocess.run([sys.executable, "-m", "companion", "--precompile"], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path, env=environment)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == ("companion: numba is not installed (or BOF_NO_JIT is set): the kernels run as plain "
                                   "Python, nothing to compile")
    assert list(tmp_path.iterdir()) == []  # no run folder, no log


def test_bof_sitl_says_so_before_it_waits_for_the_kernels_and_once_per_process(monkeypatch):
    """studies.executors.compile_kernels, as bof-sitl calls it: one line before the kernels are compiled or loaded
    (with numba, while this process has not done it yet), none once it has; without numba, none."""
    from companion import warmup
    from studies.executors import compile_kernels

    lines: list[str] = []
    monkeypatch.setattr(warmup, "_warmed_up", False)
    compile_kernels(lines.append)
    if not _jit.ENABLED:
        assert lines == []
        return
    assert lines[0].startswith("loading the compiled kernels (numba)") and len(lines) <= 2
    if len(lines) == 2:
        assert lines[1].startswith("kernels compiled in ")
    said = list(lines)
    compile_kernels(lines.append)
    assert lines == said
