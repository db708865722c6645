"""[guidance]: the lateral law, the range controller and the excitation."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from interfaces.derived_defaults import EXCITED_LAWS, default_excitation
from interfaces.scenario.common import Distance, Gain, NonNegativeGain, Rate, Speed, _Strict


#: The largest relative range spread sigma_r / r^ an excitation threshold may name.
MAX_RELATIVE_STD = 100.0

GUIDANCE_LAWS = ("hng", "ppg", "png", "pd", "retro_png", "zem", "seed003")


class GuidanceConfig(_Strict):
    """Guidance law (section VI; baselines of section VIII-C). 'hng' helical navigation (eq. 14;
    c_y = 0 is planar weaving), 'ppg' pure pursuit, 'png' 3-D proportional navigation, 'pd' the
    PD controller (k_p, k_d; replaces the range controller), 'retro_png' retro-PNG of refs
    [14]/[16] per horizontal/vertical plane (retro_gain), 'zem' the ZEM-based law of ref. [43]
    (zem_k_w, zem_max_gain), 'seed003' seed 003's backstepping speed / flight-path / course law
    (eq. (5)-(8), sign erratum fixed; seed003_alpha, seed003_gain, seed003_max_approach_speed), holding
    desired_range behind the target. All but 'pd' and 'seed003' add the range controller of eq. (18)."""

    law: Literal["hng", "ppg", "png", "pd", "retro_png", "zem", "seed003"] = "hng"
    navigation_gain: Gain = 3.0
    c_z: NonNegativeGain = 3.5
    c_y: NonNegativeGain = 3.5
    weave_frequency: Gain = 1.0
    scale_with_range: bool = True
    desired_range: Distance = 8.0
    range_gain: Gain = 3.0
    rate_hz: Rate = 20.0
    los_source: Literal["estimate", "measurement"] = "estimate"
    pd_kp: Gain = 0.5
    pd_kd: Gain = 0.2
    retro_gain: Gain = 2.0
    zem_k_w: Gain = 0.007
    zem_max_gain: Gain = 10.0
    seed003_alpha: Gain = 0.5
    """1/s: seed 003's position gain alpha_1 = alpha_2 = alpha_3 (the seed flies 1)."""
    seed003_gain: Gain = 1.0
    """1/s: seed 003's velocity/course gain lambda_1..3 (the seed's 50 assumes a 100/s autopilot)."""
    seed003_max_approach_speed: Speed = 3.0
    """m/s: bound on seed 003's approach velocity alpha |e| towards the following point (not in the seed)."""
    # Range excitation (companion.core.guidance.RangeExcitation): 'none' is the paper's
    # law unchanged; 'uncertainty' adds a lateral term that makes the pursuer circle the line of
    # sight at excitation_speed (m/s, angular rate excitation_frequency rad/s) while the relative
    # range std sigma_r / r^ is above excitation_low (full above excitation_high) or the health
    # monitor says suspect. Only for 'hng' and 'ppg' (its design cancels their N P v damping).
    # Left out: 'uncertainty' for 'hng' and 'ppg', 'none' for the other laws (`effective_excitation`) and with an
    # estimator that measures the range (interfaces.derived_defaults.default_excitation, companion.assembly).
    excitation: Literal["none", "uncertainty"] | None = None
    excitation_speed: Speed = 8.0
    excitation_frequency: Gain = 0.5
    excitation_low: Annotated[float, Field(ge=0.0, le=MAX_RELATIVE_STD)] = 0.02
    excitation_high: Annotated[float, Field(gt=0.0, le=MAX_RELATIVE_STD)] = 0.06

    @model_validator(mode="after")
    def _excitation_consistent(self) -> "GuidanceConfig":
        if self.effective_excitation != "none":
            if self.law not in EXCITED_LAWS:
                raise ValueError(f"excitation = {self.excitation!r} needs law 'hng' or 'ppg', not {self.law!r}")
            if self.excitation_low >= self.excitation_high:
                raise ValueError("excitation_low must be below excitation_high")
        return self

    @property
    def effective_excitation(self) -> str:
        """excitation, or its default for the law when left out (interfaces.derived_defaults.default_excitation)."""
        return default_excitation(self.law) if self.excitation is None else self.excitation
