"""The one table of defaults derived from other parameters when a scenario leaves a key out.

Most are multiples of the desired range r_d ([guidance] desired_range). The schema
(interfaces.scenario) checks a scenario against them at load time, companion.assembly builds
the companion's policies from them, and the core's FollowingPipeline takes the same ones when
it is built without a dropout policy or a health monitor. Plain floats and functions, no
imports: the core may read this module and still import no configuration library.
"""

#: [health] min_range, the start of the plausible range: r_d / 4.
HEALTH_MIN_RANGE_FACTOR = 0.25
#: [dropout] safe_range, the range the degraded mode holds: 1.5 r_d.
DROPOUT_SAFE_RANGE_FACTOR = 1.5
#: [dropout] min_range, the closest the pursuer may come (also the safety envelope's r_min): r_d / 2.
DROPOUT_MIN_RANGE_FACTOR = 0.5
#: [safety] braking_acceleration: this share of the airframe's tilt-limited g tan(max_tilt) is planned ...
SAFETY_BRAKING_SHARE = 0.5
#: ... and the envelope brakes with at most this share of it (or the planned braking, if larger).
SAFETY_MAX_BRAKING_SHARE = 0.9
#: [guidance] excitation: the lateral laws the range excitation serves (its design cancels their N P v damping);
#: for them it is on ('uncertainty') unless a scenario says 'none', for the others off.
EXCITED_LAWS = ("hng", "ppg")


def health_min_range(desired_range: float) -> float:
    """[health] min_range's default for a desired range r_d, m."""
    return HEALTH_MIN_RANGE_FACTOR * desired_range


def dropout_safe_range(desired_range: float) -> float:
    """[dropout] safe_range's default for a desired range r_d, m."""
    return DROPOUT_SAFE_RANGE_FACTOR * desired_range


def dropout_min_range(desired_range: float) -> float:
    """[dropout] min_range's default for a desired range r_d, m."""
    return DROPOUT_MIN_RANGE_FACTOR * desired_range


def default_excitation(law: str) -> str:
    """[guidance] excitation's default for a lateral law: 'uncertainty' for EXCITED_LAWS, 'none' for the others."""
    return "uncertainty" if law in EXCITED_LAWS else "none"
