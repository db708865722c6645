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
#: [estimator] kinds that measure the range as well as the bearing (seed 003's range/azimuth/elevation EKF).
RANGE_MEASURING_ESTIMATORS = ("ekf_rae",)
#: [safety] speed_change_latency, s, when the estimator has the IMM's speed-change model (0 without it).
SPEED_CHANGE_LATENCY = 1.0
#: [safety] hover_standoff: the distance a target at [estimator] target_max_acceleration covers from rest in this
#: time, s (the bearings show a departure along the line of sight one to two seconds late).
HOVER_DEPARTURE_TIME = 2.0


def health_min_range(desired_range: float) -> float:
    """[health] min_range's default for a desired range r_d, m."""
    return HEALTH_MIN_RANGE_FACTOR * desired_range


def dropout_safe_range(desired_range: float) -> float:
    """[dropout] safe_range's default for a desired range r_d, m."""
    return DROPOUT_SAFE_RANGE_FACTOR * desired_range


def dropout_min_range(desired_range: float) -> float:
    """[dropout] min_range's default for a desired range r_d, m."""
    return DROPOUT_MIN_RANGE_FACTOR * desired_range


def safety_speed_change_latency(speed_change_model: bool) -> float:
    """[safety] speed_change_latency's default, s: SPEED_CHANGE_LATENCY with the IMM's speed-change model, else 0."""
    return SPEED_CHANGE_LATENCY if speed_change_model else 0.0


def safety_hover_standoff(target_max_acceleration: float) -> float:
    """[safety] hover_standoff's default, m: a_T T^2 / 2 for the target's largest acceleration a_T (m/s^2) and
    T = HOVER_DEPARTURE_TIME (6 m at the default 3 m/s^2)."""
    return 0.5 * target_max_acceleration * HOVER_DEPARTURE_TIME ** 2


def default_excitation(law: str, estimator_kind: str = "") -> str:
    """[guidance] excitation's default for a lateral law and an [estimator] kind: 'uncertainty' for EXCITED_LAWS,
    'none' for the others and with an estimator that measures the range (RANGE_MEASURING_ESTIMATORS), which has
    no need to make it observable."""
    return "uncertainty" if law in EXCITED_LAWS and estimator_kind not in RANGE_MEASURING_ESTIMATORS else "none"
