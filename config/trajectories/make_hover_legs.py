"""Writes hover_legs.csv, the recorded track config/scenarios/replay_csv.toml flies:

    python config/trajectories/make_hover_legs.py

A plausible small target drone's flight, 66 s sampled at 10 Hz (header t,north,east,down: s, m local NED, the
first sample 20 m above the recording's home): a hover at take-off height, a dash north at 3 m/s^2 to 6 m/s, a
right turn at 0.5 rad/s (3 m/s^2), a brake and a hover, a climb of a few metres, a leg north-west with a left
turn, and a brake to a final hover. The track is flown by the segment model (sitl_plant.world.target), so it is
exactly smooth between its acceleration steps; positions are written to 0.1 mm, which keeps the replay's
spline acceleration within a few cm/s^2 of the flown one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from interfaces.scenario import TargetConfig
from sitl_plant.world.target import target_from_config

OUTPUT = Path(__file__).resolve().parent / "hover_legs.csv"
RATE_HZ = 10.0
DURATION = 66.0  # s
SEGMENTS = [
    {"kind": "hover", "duration": 5.0},
    {"kind": "accelerate", "velocity": [6.0, 0.0, 0.0], "max_acceleration": 3.0},
    {"kind": "cruise", "duration": 6.0},
    {"kind": "turn", "rate": 0.5, "angle_deg": 90.0},
    {"kind": "cruise", "duration": 5.0},
    {"kind": "brake", "max_acceleration": 3.0},
    {"kind": "hover", "duration": 4.0},
    {"kind": "climb", "rate": 1.0, "max_acceleration": 1.0, "duration": 4.0},
    {"kind": "climb", "rate": 0.0, "max_acceleration": 1.0},
    {"kind": "hover", "duration": 2.0},
    {"kind": "accelerate", "velocity": [4.0, -3.0, 0.0], "max_acceleration": 2.5},
    {"kind": "cruise", "duration": 6.0},
    {"kind": "turn", "rate": -0.4, "angle_deg": 120.0},
    {"kind": "cruise", "duration": 4.0},
    {"kind": "brake", "max_acceleration": 2.0},
    {"kind": "hover", "duration": 12.0},
]


def main() -> None:
    config = TargetConfig.model_validate({"initial_position": [0.0, 0.0, -20.0], "initial_velocity": [0.0, 0.0, 0.0],
                                          "segments": SEGMENTS})
    target = target_from_config(config, 0)
    lines = ["t,north,east,down"]
    for k in range(round(DURATION * RATE_HZ) + 1):
        time = k / RATE_HZ
        target.advance_to(time)
        north, east, down = target.position.tolist()
        lines.append(f"{time:.1f},{north:.4f},{east:.4f},{down:.4f}")
    OUTPUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUTPUT} ({len(lines) - 1} samples, {DURATION:g} s)")


if __name__ == "__main__":
    main()
