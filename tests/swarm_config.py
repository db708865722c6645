"""The shipped three-pursuer scenario as the swarm SITL tests fly it: a copy with another duration (and extra TOML)."""

from __future__ import annotations

from pathlib import Path

from interfaces.scenario import load_scenario

CONFIG = Path(__file__).resolve().parent.parent / "config" / "scenarios" / "swarm_circumnavigation.toml"
SCENARIO, _ = load_scenario(CONFIG)
COUNT = SCENARIO.swarm.count


def scenario_copy(path: Path, duration: float, extra: str = "") -> Path:
    """Write swarm_circumnavigation.toml to `path` with [simulation] duration = `duration` s and `extra` appended
    (its vehicle file named by absolute path, so the copy may live anywhere); returns `path`."""
    vehicle = CONFIG.parent.parent / "vehicles" / "paper_table1.toml"
    text = CONFIG.read_text().replace('vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{vehicle}"')
    assert "duration = 60.0" in text
    path.write_text(text.replace("duration = 60.0", f"duration = {duration}") + extra)
    return path
