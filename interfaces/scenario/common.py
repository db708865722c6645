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
