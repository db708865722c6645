"""Scenario and vehicle files (TOML), validated strictly.

A scenario names a vehicle file (path relative to the scenario file) and sets the
pursuer, target, sensor, estimator, guidance and simulation. Unknown or mistyped
keys, non-finite numbers and impossible values are rejected with a ConfigError that
names the file and the key; nothing half-runs. A target replaying a recorded track
([target.trajectory]) names its file relative to the scenario file too: the loaders
read and check it and make the path absolute (docs/targets.md).

One module a section: common (ConfigError, the strict base model, number types), files
(the config folder, bounded reads), vehicle, target, sensor, estimator, guidance,
simulation ([simulation], [sitl]), link ([link], [companion]), faults, safety ([dropout],
[safety], [health]), swarm, base (what Scenario and PlantScenario share), full (Scenario),
plant (PlantScenario) and loading (load_scenario and the other loaders). Every name is
re-exported here: `from interfaces.scenario import X` is the way to use them. The
defaults derived from the desired range live in interfaces.derived_defaults.
"""


from interfaces.scenario.common import (ConfigError, FROM_ARRAY, NonNegative, Port, Positive, PositiveInt, Probability,
                                        Vector3)
from interfaces.scenario.files import (CONFIG_DIR, DEFAULT_SCENARIO, MAX_CONFIG_BYTES, SCENARIOS_DIR, VEHICLES_DIR,
                                       read_regular_file)
from interfaces.scenario.vehicle import (PAPER_TABLE1, PursuerConfig, VehicleConfig)
from interfaces.scenario.target import (AccelerateSegment, BrakeSegment, CircleConfig, ClimbSegment, CruiseSegment,
                                        HoverSegment, MAX_SEGMENTS, MAX_SEGMENT_ACCELERATION, MAX_SEGMENT_DURATION,
                                        MAX_SEGMENT_SPEED, MAX_TRAJECTORY_BYTES, MAX_TURN_RATE,
                                        MIN_SINGER_UPDATE_PERIOD, ManeuverConfig, SegmentAcceleration, SegmentDuration,
                                        SegmentVelocity, SingerConfig, SpeedChangeConfig, StopAndGoConfig,
                                        TARGET_PATTERNS, TRAJECTORY_EXTENSIONS, TargetConfig, TargetSegment,
                                        TrajectoryConfig, TurnConfig, TurnDirection, TurnSegment, WeaveConfig)
from interfaces.scenario.sensor import (CameraConfig, MAX_BEARING_NOISE_STD, MAX_RANGE_NOISE_STD, RangeDependentNoise,
                                        SensorConfig)
from interfaces.scenario.estimator import (EstimatorConfig, IMM_MAX_TURN_RATE, IMM_OPTIONS)
from interfaces.scenario.guidance import (GUIDANCE_LAWS, GuidanceConfig)
from interfaces.scenario.simulation import (DIVERGENCE_RMS_M, MAX_DIVERGENCE_RMS_M, MAX_DURATION_S, MAX_PHYSICS_RATE_HZ,
                                            MAX_SPEED_FACTOR, MIN_SPEED_FACTOR, SimulationConfig, SitlConfig)
from interfaces.scenario.link import (CompanionConfig, LinkConfig)
from interfaces.scenario.faults import (BlackoutWindow, BurstLossConfig, CORRUPT_KINDS, CorruptKind, FaultsConfig,
                                        MAX_ATTACK_RATE_HZ, MavlinkFaultsConfig, SenderName)
from interfaces.scenario.safety import (DropoutConfig, HealthReasonName, HealthSection, SafetyConfig)
from interfaces.scenario.swarm import (CircumnavigationConfig, FusionConfig, MAX_PURSUERS, PursuerIdent, PursuerStart,
                                       SWARM_ESTIMATORS, SWARM_GUIDANCE, StandoffConfig, SwarmBlackout, SwarmConfig,
                                       SwarmLinkConfig, SwarmPursuerConfig, TriangulationConfig, pursuer_starts,
                                       share_rate_hz)
from interfaces.scenario.base import (MAX_NAME_LENGTH, MIN_LOOP_RATE_HZ, ScenarioBase, ScenarioName)
from interfaces.scenario.full import (Scenario)
from interfaces.scenario.plant import (COMPANION_SECTIONS, PlantScenario, PlantSensorConfig)
from interfaces.scenario.loading import (ScenarioT, describe_errors, is_vehicle_name, load_plant_scenario, load_scenario,
                                         load_vehicle, shipped_vehicle_names, table1_vehicle)
from interfaces.derived_defaults import (DROPOUT_MIN_RANGE_FACTOR, DROPOUT_SAFE_RANGE_FACTOR,
                                         HEALTH_MIN_RANGE_FACTOR)

__all__ = ['AccelerateSegment', 'BlackoutWindow', 'BrakeSegment', 'BurstLossConfig', 'COMPANION_SECTIONS', 'CONFIG_DIR',
           'CORRUPT_KINDS', 'CameraConfig', 'CircleConfig', 'CircumnavigationConfig', 'ClimbSegment', 'CompanionConfig',
           'ConfigError', 'CorruptKind', 'CruiseSegment', 'DEFAULT_SCENARIO', 'DIVERGENCE_RMS_M',
           'DROPOUT_MIN_RANGE_FACTOR', 'DROPOUT_SAFE_RANGE_FACTOR', 'DropoutConfig', 'EstimatorConfig', 'FROM_ARRAY',
           'FaultsConfig', 'FusionConfig', 'GUIDANCE_LAWS', 'GuidanceConfig', 'HEALTH_MIN_RANGE_FACTOR',
           'HealthReasonName', 'HealthSection', 'HoverSegment', 'IMM_MAX_TURN_RATE', 'IMM_OPTIONS', 'LinkConfig',
           'MAX_ATTACK_RATE_HZ', 'MAX_BEARING_NOISE_STD', 'MAX_CONFIG_BYTES', 'MAX_DIVERGENCE_RMS_M', 'MAX_DURATION_S',
           'MAX_NAME_LENGTH', 'MAX_PHYSICS_RATE_HZ', 'MAX_PURSUERS', 'MAX_RANGE_NOISE_STD', 'MAX_SEGMENTS',
           'MAX_SEGMENT_ACCELERATION', 'MAX_SEGMENT_DURATION', 'MAX_SEGMENT_SPEED', 'MAX_SPEED_FACTOR',
           'MAX_TRAJECTORY_BYTES', 'MAX_TURN_RATE', 'MIN_LOOP_RATE_HZ', 'MIN_SINGER_UPDATE_PERIOD', 'MIN_SPEED_FACTOR',
           'ManeuverConfig', 'MavlinkFaultsConfig', 'NonNegative', 'PAPER_TABLE1', 'PlantScenario', 'PlantSensorConfig',
           'Port', 'Positive', 'PositiveInt', 'Probability', 'PursuerConfig', 'PursuerIdent', 'PursuerStart',
           'RangeDependentNoise', 'SCENARIOS_DIR', 'SWARM_ESTIMATORS', 'SWARM_GUIDANCE', 'SafetyConfig', 'Scenario',
           'ScenarioBase', 'ScenarioName', 'ScenarioT', 'SegmentAcceleration', 'SegmentDuration', 'SegmentVelocity',
           'SenderName', 'SensorConfig', 'SimulationConfig', 'SingerConfig', 'SitlConfig', 'SpeedChangeConfig',
           'StandoffConfig', 'StopAndGoConfig', 'SwarmBlackout', 'SwarmConfig', 'SwarmLinkConfig', 'SwarmPursuerConfig',
           'TARGET_PATTERNS', 'TRAJECTORY_EXTENSIONS', 'TargetConfig', 'TargetSegment', 'TrajectoryConfig',
           'TriangulationConfig', 'TurnConfig', 'TurnDirection', 'TurnSegment', 'VEHICLES_DIR', 'Vector3',
           'VehicleConfig', 'WeaveConfig', 'describe_errors', 'is_vehicle_name', 'load_plant_scenario', 'load_scenario',
           'load_vehicle', 'pursuer_starts', 'read_regular_file', 'share_rate_hz', 'shipped_vehicle_names',
           'table1_vehicle']
