"""What every section shares: ConfigError, the strict base model, the constrained number types."""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict


class ConfigError(ValueError):
    """A configuration file is missing, unreadable or invalid; the message names the key."""


def _finite_vector(value: tuple[float, float, float]) -> tuple[float, float, float]:
    if not all(math.isfinite(component) for component in value):
        raise ValueError("all three components must be finite numbers")
    return value


#: TOML has arrays, not tuples: a tuple field takes a list for its container; its items stay strict.
FROM_ARRAY = Strict(False)
Vector3 = Annotated[tuple[float, float, float], FROM_ARRAY, AfterValidator(_finite_vector)]
Positive = Annotated[float, Field(gt=0.0)]
NonNegative = Annotated[float, Field(ge=0.0)]


class _Strict(BaseModel):
    """Every section: unknown keys refused, no NaN/inf, no coercion (the string "12" is not the
    number 12; an integer is accepted where a float is expected, as TOML writes `8` for 8.0)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


PositiveInt = Annotated[int, Field(gt=0)]
Port = Annotated[int, Field(ge=1, le=65535)]
Probability = Annotated[float, Field(ge=0.0, le=1.0)]


# Physical bounds: what a small multirotor, its target and their world can be, SI units. Finite but absurd values
# (a position of 1e160 m, g = 1e300 m/s^2) are refused here, naming the key, instead of ending a flight in an
# overflow. Each bound lives once, in these types; docs/gen_reference.py shows them on the schema page.

#: m: the largest |component| of a position (NED about home): 10 km, beyond any radio link of a small drone.
MAX_POSITION_M = 10_000.0
#: m: the longest distance, range, radius or position standard deviation (the same 10 km).
MAX_DISTANCE_M = 10_000.0
#: m/s: the largest |component| of a velocity, and the fastest speed (60 m/s ends an in-process flight as out
#: of control).
MAX_SPEED_M_S = 100.0
#: m/s^2: the largest acceleration a law, a target model or a limit may ask for (5 g).
MAX_ACCELERATION_M_S2 = 50.0
#: s: the longest duration, start time, delay or time constant: a day, the longest flight a scenario may ask for.
MAX_DURATION_S = 86_400.0
#: Hz: the fastest loop or message rate, that of the fastest physics step ([simulation] physics_rate_hz).
MAX_RATE_HZ = 10_000.0
#: The largest dimensionless or per-second gain of a law or a filter option.
MAX_GAIN = 1000.0

PositionComponent = Annotated[float, Field(ge=-MAX_POSITION_M, le=MAX_POSITION_M)]
#: A position, m, NED: each component within MAX_POSITION_M.
Position = Annotated[tuple[PositionComponent, PositionComponent, PositionComponent], FROM_ARRAY]
VelocityComponent = Annotated[float, Field(ge=-MAX_SPEED_M_S, le=MAX_SPEED_M_S)]
#: A velocity, m/s, NED: each component within MAX_SPEED_M_S.
Velocity = Annotated[tuple[VelocityComponent, VelocityComponent, VelocityComponent], FROM_ARRAY]
#: m/s.
Speed = Annotated[float, Field(gt=0.0, le=MAX_SPEED_M_S)]
NonNegativeSpeed = Annotated[float, Field(ge=0.0, le=MAX_SPEED_M_S)]
#: m/s^2.
Acceleration = Annotated[float, Field(gt=0.0, le=MAX_ACCELERATION_M_S2)]
#: m: a distance, range or radius, or a standard deviation in metres.
Distance = Annotated[float, Field(gt=0.0, le=MAX_DISTANCE_M)]
NonNegativeDistance = Annotated[float, Field(ge=0.0, le=MAX_DISTANCE_M)]
#: s: a duration, time constant or timeout.
Duration = Annotated[float, Field(gt=0.0, le=MAX_DURATION_S)]
#: s: a start time, delay or hold that may be 0.
NonNegativeDuration = Annotated[float, Field(ge=0.0, le=MAX_DURATION_S)]
#: Hz: a loop or message rate (a loop rate's lower bound, MIN_LOOP_RATE_HZ, is checked with the physics rate).
Rate = Annotated[float, Field(gt=0.0, le=MAX_RATE_HZ)]
#: A gain (dimensionless, or 1/s, rad/s as its key says).
Gain = Annotated[float, Field(gt=0.0, le=MAX_GAIN)]
NonNegativeGain = Annotated[float, Field(ge=0.0, le=MAX_GAIN)]
