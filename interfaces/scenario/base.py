"""What the full Scenario and the plant's PlantScenario view share: the loop-rate check, the name, the base."""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator

from interfaces.scenario.common import _Strict
from interfaces.scenario.target import TargetConfig
from interfaces.scenario.vehicle import PursuerConfig


#: Hz: the slowest loop rate (one period of 100 s). Slower is a typo, and 1e-300 Hz passes the divides-the-physics-
#: rate check yet overflows the estimator's transition matrix (period**2) with an OverflowError at take-off.
MIN_LOOP_RATE_HZ = 0.01


def _check_rates(physics_rate_hz: float, **rates_hz: float) -> None:
    """Every loop rate (Hz, by section) must be at least MIN_LOOP_RATE_HZ and divide the physics rate into whole
    steps; ValueError naming the key."""
    for section, rate in rates_hz.items():
        key = f"{section}.{'tick_rate_hz' if section == 'sitl' else 'rate_hz'}"
        if rate < MIN_LOOP_RATE_HZ:
            raise ValueError(f"{key} = {rate:g} must be at least {MIN_LOOP_RATE_HZ:g} Hz (one step per 100 s)")
        ratio = physics_rate_hz / rate
        if rate > physics_rate_hz or abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"{key} = {rate} must divide simulation.physics_rate_hz = {physics_rate_hz} into whole steps")

#: Longest scenario name: it becomes part of run-folder names (e.g. sitl-<name>-seed<k>-<time>/), within 255 bytes.
MAX_NAME_LENGTH = 100
_NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def _run_folder_name(value: str) -> str:
    """A scenario name usable as one path component: letters, digits, '_', '-', '.'; not starting with '.'
    (hidden, '..') or '-' (read as an option); 1..MAX_NAME_LENGTH characters. No '/', NUL or absolute path."""
    if not (len(value) <= MAX_NAME_LENGTH and _NAME_PATTERN.fullmatch(value)):
        shown = repr(value) if len(value) <= 40 else f"{value[:40]!r}... ({len(value)} characters)"
        raise ValueError(f"must be 1-{MAX_NAME_LENGTH} letters, digits, '_', '-' or '.', starting with a letter, digit "
                         f"or '_' (it names run folders), got {shown}")
    return value


ScenarioName = Annotated[str, AfterValidator(_run_folder_name)]


class ScenarioBase(_Strict):
    """The keys the full Scenario and the plant's PlantScenario view both start with (same order, same defaults);
    each adds its own sections after them and ends with [swarm]."""

    name: ScenarioName
    description: str = ""
    vehicle: str = "paper_table1"
    """The airframe: a shipped one by name (no "/", no .toml: config/vehicles/<name>.toml of the installed package,
    wherever the scenario is), or a vehicle file by its path, relative to the scenario's folder."""
    pursuer: PursuerConfig = PursuerConfig()
    target: TargetConfig

    @property
    def pursuer_count(self) -> int:
        """N: 1 without [swarm]."""
        return 1 if self.swarm is None else self.swarm.count
