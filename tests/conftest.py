from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "config" / "scenarios"


@pytest.fixture
def scenario_path():
    def _path(name: str) -> Path:
        return SCENARIOS / f"{name}.toml"

    return _path
