"""MkDocs hooks (mkdocs.yml `hooks:`): the reference pages are generated from the code at every build.

`on_files` adds the pages of docs/gen_reference.py to the site as generated files, so `mkdocs build`
(and `mkdocs serve`) always shows the code as it is and nothing generated is written into docs/.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from mkdocs.structure.files import File

_HERE = Path(__file__).resolve().parent
_ROOT = _HERE.parent


def _generator():
    if str(_ROOT) not in sys.path:
        sys.path.insert(0, str(_ROOT))
    spec = importlib.util.spec_from_file_location("gen_reference", _HERE / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def on_files(files, config):
    generator = _generator()
    for name in generator.PAGES:
        existing = files.get_file_from_path(name)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, name, content=generator.build(name)))
    return files
