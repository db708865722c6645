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
