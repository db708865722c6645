"""[simulation] (the in-process flight) and [sitl] (the bundled MAVLink plant)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from interfaces.scenario.common import FROM_ARRAY, MAX_DURATION_S, MAX_RATE_HZ, Distance, Duration, Port, Rate, _Strict

# MAX_DURATION_S (common): the longest flight a scenario may ask for, s: a day. Longer is a typo for a multirotor, and
# an in-process flight holds its whole log in memory (about 2 GB for a day at the default rates: 60 rows a second of
# 46 floats).
#: The fastest physics step a scenario may ask for, Hz: 20x the paper's 500 Hz. Faster would only make the plant
#: crawl (a 60 s flight at 1 GHz is 6e10 RK4 steps) without a visible change in a 2 ms-scale rigid body.
MAX_PHYSICS_RATE_HZ = MAX_RATE_HZ


#: Range-estimation error RMS over the summary window above which a simulated flight has diverged by truth, m
#: ([simulation] divergence_rms; studies.metrics.summarize's "truth").
DIVERGENCE_RMS_M = 2.0
#: The largest [simulation] divergence_rms a scenario may set, m: beyond it no bearing-only estimate is judged at all.
MAX_DIVERGENCE_RMS_M = 1000.0


class SimulationConfig(_Strict):
    """The simulated flight and how it is judged. duration, summary_window: s; converged_range_error (the
    convergence threshold) and divergence_rms (range-estimation error RMS over the summary window above which the
    flight has diverged by truth): m."""

    duration: Annotated[float, Field(gt=0.0, le=MAX_DURATION_S)] = 60.0
    seed: Annotated[int, Field(ge=0)] = 0
    physics_rate_hz: Annotated[float, Field(ge=500.0, le=MAX_PHYSICS_RATE_HZ)] = 500.0
    summary_window: Duration = 20.0
    converged_range_error: Distance = 1.0
    divergence_rms: Annotated[float, Field(gt=0.0, le=MAX_DIVERGENCE_RMS_M)] = DIVERGENCE_RMS_M


#: m above the WGS-84 ellipsoid: the lowest and highest home altitude (below the Dead Sea shore; above Everest).
MIN_HOME_ALTITUDE_M, MAX_HOME_ALTITUDE_M = -500.0, 9000.0
HomeAltitude = Annotated[float, Field(ge=MIN_HOME_ALTITUDE_M, le=MAX_HOME_ALTITUDE_M)]

#: [sitl] speed_factor bounds, simulated s per wall s: bof-sitl's --speed-factor range.
MIN_SPEED_FACTOR, MAX_SPEED_FACTOR = 0.5, 20.0


class SitlConfig(_Strict):
    """The bundled SITL plant as a MAVLink vehicle (sitl-plant); PX4 SITL's ports and home by default.

    The vehicle starts at rest on the ground below pursuer.initial_position (local NED
    z = 0 is the ground at home), heading start_yaw_deg. parameters overrides PX4-style
    parameters of the plant (e.g. COM_OF_LOSS_T = 0.5); names and ranges are checked
    when the plant starts.
    """

    home: Annotated[tuple[float, float, HomeAltitude], FROM_ARRAY] = (47.397742, 8.545594, 488.0)
    """(latitude deg, longitude deg, altitude m): the ground below the local NED origin."""
    # bof-sitl's --speed-factor range (studies/full_sitl.py: below 0.5 MAVSDK misses heartbeats, above 20 the plant
    # cannot keep up); sitl-plant's own --speed-factor flag, which overrides this key, takes (0, 100].
    speed_factor: Annotated[float, Field(ge=MIN_SPEED_FACTOR, le=MAX_SPEED_FACTOR)] = 1.0
    companion_host: str = "127.0.0.1"
    companion_port: Port = 14540
    gcs_host: str = "127.0.0.1"
    gcs_port: Port = 14550
    bind_host: str = "127.0.0.1"
    tick_rate_hz: Rate = 250.0
    start_yaw_deg: Annotated[float, Field(ge=-180.0, le=360.0)] = 0.0
    parameters: dict[str, float] = {}

    @model_validator(mode="after")
    def _home_on_earth(self) -> "SitlConfig":
        latitude, longitude, _ = self.home
        if not (-90.0 <= latitude <= 90.0 and -180.0 <= longitude <= 180.0):
            raise ValueError(f"home: latitude/longitude ({latitude}, {longitude}) outside [-90, 90] x [-180, 180]")
        return self
