"""PlantScenario: what sitl-plant and sitl-target read of a scenario."""

from __future__ import annotations

from pydantic import model_validator

from interfaces.scenario.base import ScenarioBase, _check_rates
from interfaces.scenario.common import Rate, _Strict
from interfaces.scenario.faults import FaultsConfig
from interfaces.scenario.link import LinkConfig
from interfaces.scenario.sensor import SensorConfig
from interfaces.scenario.simulation import SimulationConfig, SitlConfig
from interfaces.scenario.swarm import SwarmConfig, _check_swarm


#: The companion's own sections: the plant and the target simulator never read them, so a
#: scenario whose [estimator] or [guidance] is broken or missing still flies the plant.
COMPANION_SECTIONS = ("estimator", "guidance", "companion", "dropout", "health", "safety")


class PlantSensorConfig(_Strict):
    """The one key of [sensor] the plant's side reads: the target publishes a fix per bearing."""

    rate_hz: Rate = SensorConfig.model_fields["rate_hz"].default


class PlantScenario(ScenarioBase):
    """What sitl-plant and sitl-target read of a scenario, validated as strictly as Scenario
    (same section models); COMPANION_SECTIONS and the rest of [sensor] are not looked at."""

    sensor: PlantSensorConfig = PlantSensorConfig()
    simulation: SimulationConfig = SimulationConfig()
    sitl: SitlConfig = SitlConfig()
    link: LinkConfig = LinkConfig()
    faults: FaultsConfig = FaultsConfig()
    swarm: SwarmConfig | None = None

    @model_validator(mode="after")
    def _rates_fit_physics(self) -> "PlantScenario":
        _check_rates(self.simulation.physics_rate_hz, sensor=self.sensor.rate_hz, sitl=self.sitl.tick_rate_hz)
        _check_swarm(self)
        return self
