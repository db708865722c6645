"""The full Scenario, as the companion and the in-process simulator read it."""

from __future__ import annotations

from pydantic import model_validator

from interfaces.derived_defaults import (DROPOUT_MIN_RANGE_FACTOR, DROPOUT_SAFE_RANGE_FACTOR, dropout_min_range,
                                         dropout_safe_range, health_min_range)
from interfaces.scenario.base import ScenarioBase, _check_rates
from interfaces.scenario.estimator import EstimatorConfig
from interfaces.scenario.faults import FaultsConfig
from interfaces.scenario.guidance import GuidanceConfig
from interfaces.scenario.link import CompanionConfig, LinkConfig
from interfaces.scenario.safety import DropoutConfig, HealthSection, SafetyConfig
from interfaces.scenario.sensor import SensorConfig
from interfaces.scenario.simulation import SimulationConfig, SitlConfig
from interfaces.scenario.swarm import SwarmConfig, _check_swarm, _check_swarm_geometry


def _check_ranges(scenario: "Scenario") -> None:
    """The companion's health monitor needs min_range < max_range and its dropout policy min_range < safe_range,
    with the defaults derived from guidance.desired_range: refused here, naming the keys, not at take-off."""
    desired = scenario.guidance.desired_range
    health = scenario.health
    if health.min_range is None and health_min_range(desired) >= health.max_range:
        raise ValueError(f"health.max_range ({health.max_range:g} m) must exceed health.min_range, whose default is "
                         f"guidance.desired_range / 4 = {health_min_range(desired):g} m: raise max_range or "
                         "set health.min_range")
    dropout = scenario.dropout
    safe = dropout.safe_range if dropout.safe_range is not None else dropout_safe_range(desired)
    low = dropout.min_range if dropout.min_range is not None else dropout_min_range(desired)
    if low >= safe:
        def said(key: str, value: float, factor: float) -> str:
            given = getattr(dropout, key) is not None
            return f"dropout.{key} ({value:g} m{'' if given else f', default {factor:g} x guidance.desired_range'})"
        raise ValueError(f"{said('min_range', low, DROPOUT_MIN_RANGE_FACTOR)} must be below "
                         f"{said('safe_range', safe, DROPOUT_SAFE_RANGE_FACTOR)}")


class Scenario(ScenarioBase):
    """A whole scenario file: the plant's sections and the companion's (COMPANION_SECTIONS), checked together."""

    sensor: SensorConfig = SensorConfig()
    estimator: EstimatorConfig
    guidance: GuidanceConfig = GuidanceConfig()
    simulation: SimulationConfig = SimulationConfig()
    sitl: SitlConfig = SitlConfig()
    link: LinkConfig = LinkConfig()
    companion: CompanionConfig = CompanionConfig()
    faults: FaultsConfig = FaultsConfig()
    dropout: DropoutConfig = DropoutConfig()
    safety: SafetyConfig = SafetyConfig()
    health: HealthSection = HealthSection()
    swarm: SwarmConfig | None = None

    @model_validator(mode="after")
    def _rates_fit_physics(self) -> "Scenario":
        _check_rates(self.simulation.physics_rate_hz, estimator=self.estimator.rate_hz, guidance=self.guidance.rate_hz,
                     sensor=self.sensor.rate_hz, sitl=self.sitl.tick_rate_hz)
        if self.simulation.summary_window > self.simulation.duration:
            raise ValueError("simulation.summary_window must not exceed simulation.duration")
        if self.estimator.kind == "ekf_rae" and self.sensor.range_noise_std is None:
            raise ValueError("estimator.kind = 'ekf_rae' measures range: set sensor.range_noise_std")
        if self.estimator.kind not in ("uplkf", "imm") and self.estimator.gain_projection != "predicted":
            raise ValueError(f"estimator.gain_projection applies to the u-PLKF only, not to kind = {self.estimator.kind!r}")
        _check_swarm(self)
        _check_swarm_geometry(self)
        _check_ranges(self)
        return self
