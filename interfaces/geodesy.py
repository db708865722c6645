"""Local NED <-> WGS-84 geodetic, shared by the plant, the target and the companion.

The local frame is north-east-down about a home point (latitude deg, longitude deg,
altitude m AMSL), the scenario's [sitl] home, as PX4's local position is. The
conversion is pymap3d's (ellipsoidal, WGS-84).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pymap3d


def _home(home: Sequence[float]) -> tuple[float, float, float]:
    latitude, longitude, altitude = (float(v) for v in home)
    if not (-90.0 <= latitude <= 90.0 and -180.0 <= longitude <= 180.0 and math.isfinite(altitude)):
        raise ValueError(f"home ({latitude}, {longitude}, {altitude}) is not a geodetic position")
    return latitude, longitude, altitude


def geodetic_to_ned(position: Sequence[float], home: Sequence[float]) -> np.ndarray:
    """NED position (m, shape (3,)) about `home` of (latitude deg, longitude deg, altitude m AMSL)."""
    latitude, longitude, altitude = (float(v) for v in position)
    north, east, down = pymap3d.geodetic2ned(latitude, longitude, altitude, *_home(home))
    return np.array([north, east, down], dtype=float)


def ned_to_geodetic(position: Sequence[float], home: Sequence[float]) -> tuple[float, float, float]:
    """(latitude deg, longitude deg, altitude m AMSL) of a local NED position (m, shape (3,)) about `home`."""
    north, east, down = (float(v) for v in position)
    latitude, longitude, altitude = pymap3d.ned2geodetic(north, east, down, *_home(home))
    return float(latitude), float(longitude), float(altitude)
