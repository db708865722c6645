"""The flight's Foxglove channels: what an MCAP file of a flight holds and what a live view serves.

One set of channels for every producer (bof-sim's and bof-sitl's flight.mcap, the companion's live
WebSocket view) and every reader (bof-plot, Foxglove, tests):

    /tf                  foxglove.FrameTransforms  "world" (x east, y north, z up, as Foxglove draws) -> "ned"
    /pursuer/pose        foxglove.PoseInFrame      the pursuer (frame "ned", attitude body FRD -> NED)
    /target/pose         foxglove.PoseInFrame      the target: the truth in simulation; the link's fix live
    /estimate/pose       foxglove.PoseInFrame      the estimated target position (orientation identity)
    /scene               foxglove.SceneUpdate      the estimate's 2-sigma position ellipsoid, the bearing ray
                                                   drawn out to the estimated range, and the path traces
    /flight/range        JSON   range (truth), range_estimate, sigma_r, errors, desired_range
    /flight/pursuer      JSON   speed, tilt_deg (the truth in simulation)
    /setpoint            JSON   the commanded acceleration (NED) and normalised thrust
    /estimator/models    JSON   the IMM estimator's model probabilities by motion (straight, right, left)
    /health              JSON   the filter-health monitor's verdict (suspect 0/1, reasons, NIS ratio) and action
    /track_mode          JSON   tracking / coasting / degraded / reacquiring
    /link                JSON   fixes accepted and rejected (cumulative, by reason)
    /events              foxglove.Log  engagement, phase and mode changes, health transitions, link faults

Time base: simulated seconds of the flight (the plant's clock: in bof-sitl from the plant's start on the
ground, in bof-sim from the start in the air), as nanoseconds in both the MCAP log time and the messages'
timestamps. The engagement time is an "engaged" event on /events and the MCAP metadata record "flight".
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from foxglove import Channel, Context, Schema
from foxglove.channels import FrameTransformsChannel, LogChannel, PoseInFrameChannel, SceneUpdateChannel
from foxglove.messages import (Color, Duration, FrameTransform, FrameTransforms, LinePrimitive, LinePrimitiveLineType, Log, LogLevel,
                               Point3, Pose, PoseInFrame, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp,
                               Vector3)
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Schema as McapSchema
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from scipy.spatial.transform import Rotation

#: Pose channels (foxglove.PoseInFrame) by what they show.
POSE_TOPICS = {"pursuer": "/pursuer/pose", "target": "/target/pose", "estimate": "/estimate/pose"}
#: JSON channels and the fields each may carry (numbers unless said): their JSON schema lists them.
JSON_TOPICS: dict[str, dict[str, str]] = {
    "/flight/range": {"range": "true range |p_T - p|, m (simulation only)", "range_estimate": "|p_hat_T - p|, m",
                      "sigma_r": "the estimate's standard deviation along the line of sight, m",
                      "range_estimation_error": "range_estimate - range, m (simulation only)",
                      "range_error": "range - desired_range, m (simulation only)", "desired_range": "r_d, m"},
    "/flight/pursuer": {"speed": "|v|, m/s", "tilt_deg": "angle of body z from NED down, deg"},
    "/setpoint": {"acc_n": "commanded acceleration north, m/s^2", "acc_e": "east, m/s^2", "acc_d": "down, m/s^2",
                  "thrust_normalized": "thrust setpoint, 0..1"},
    "/estimator/models": {"straight": "IMM probability of the straight-motion models", "right": "right turns",
                          "left": "left turns"},
    "/health": {"suspect": "1 when the monitor calls the estimate suspect, else 0", "state": "ok / suspect (string)",
                "reasons": "the reasons counting now (list of strings)", "nis_ratio": "windowed NIS over its expectation",
                "action": "what the pipeline does about it (string)", "process_noise_boost": "Q multiplier"},
    "/track_mode": {"mode": "tracking / coasting / degraded / reacquiring (string)"},
    "/link": {"accepted": "fixes accepted so far", "rejected": "fixes rejected so far",
              "rejected_by_reason": "rejections so far by reason (object)"},
}
SCENE_TOPIC = "/scene"
TF_TOPIC = "/tf"
EVENTS_TOPIC = "/events"
ALL_TOPICS = (TF_TOPIC, *POSE_TOPICS.values(), SCENE_TOPIC, *JSON_TOPICS, EVENTS_TOPIC)
#: The fixed frame Foxglove draws in (z up) and the flight's local NED frame inside it.
WORLD_FRAME, NED_FRAME = "world", "ned"
#: NED axes in the world frame: north -> y, east -> x, down -> -z (a proper rotation, det +1).
NED_IN_WORLD = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: The covariance ellipsoid is drawn at this many standard deviations (semi-axes k sqrt(eigenvalue)).
ELLIPSOID_SIGMAS = 2.0
#: How long a path-trace piece stays in the scene, s (the trails show the last TRAIL_S seconds).
TRAIL_S = 30.0
COLORS = {"pursuer": Color(r=0.12, g=0.47, b=0.71, a=1.0), "target": Color(r=0.84, g=0.15, b=0.16, a=1.0),
          "estimate": Color(r=1.0, g=0.5, b=0.05, a=1.0), "ellipsoid": Color(r=1.0, g=0.5, b=0.05, a=0.3),
          "bearing": Color(r=0.17, g=0.63, b=0.17, a=1.0)}
LOG_LEVELS = {"info": LogLevel.Info, "warning": LogLevel.Warning, "error": LogLevel.Error}


def nanoseconds(time_s: float) -> int:
    """Flight time in s -> the MCAP log time, ns (>= 0: a time before the start is refused)."""
    if not math.isfinite(time_s) or time_s < 0.0:
        raise ValueError(f"flight time {time_s!r} s is not a finite time >= 0")
    return round(time_s * 1e9)


def _stamp(time_ns: int) -> Timestamp:
    return Timestamp(time_ns // 1_000_000_000, time_ns % 1_000_000_000)


def _vector(values: Sequence[float]) -> Vector3:
    x, y, z = (float(v) for v in values)
    return Vector3(x=x, y=y, z=z)


def _point(values: Sequence[float]) -> Point3:
    x, y, z = (float(v) for v in values)
    return Point3(x=x, y=y, z=z)


def _quaternion(wxyz: Sequence[float]) -> Quaternion:
    w, x, y, z = (float(v) for v in wxyz)
    return Quaternion(x=x, y=y, z=z, w=w)


IDENTITY = (1.0, 0.0, 0.0, 0.0)


def quaternion_wxyz(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternions (w, x, y, z), w >= 0, of rotation matrices (..., 3, 3) (scipy's conversion): (..., 4)."""
    xyzw = Rotation.from_matrix(np.asarray(rotation, dtype=float).reshape(-1, 3, 3)).as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    wxyz[wxyz[:, 0] < 0.0] *= -1.0
    return wxyz.reshape(*np.shape(rotation)[:-2], 4)


def ellipsoid(covariance: np.ndarray, sigmas: float = ELLIPSOID_SIGMAS) -> tuple[tuple[float, ...], tuple[float, float, float]]:
    """The orientation (w, x, y, z) and the diameters (m) of the `sigmas`-sigma ellipsoid of a 3 x 3 position
    covariance: the principal axes are its eigenvectors (made a right-handed frame), the semi-axes
    sigmas * sqrt(eigenvalue) (negative eigenvalues of a numerically indefinite matrix count as 0)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    if np.linalg.det(vectors) < 0.0:
        vectors[:, 2] = -vectors[:, 2]
    diameters = tuple(float(2.0 * sigmas * math.sqrt(max(v, 0.0))) for v in values)
    return tuple(quaternion_wxyz(vectors).tolist()), diameters


def range_sigma(covariance: np.ndarray, pursuer: np.ndarray, estimate: np.ndarray) -> float:
    """sigma_r: the standard deviation of the estimated position along the line of sight to the estimate, m
    (sqrt(u' P u), u the unit vector from the pursuer to the estimate); NaN when they coincide."""
    offset = np.asarray(estimate, dtype=float) - np.asarray(pursuer, dtype=float)
    distance = float(np.linalg.norm(offset))
    if not distance > 0.0:
        return math.nan
    u = offset / distance
    return math.sqrt(max(float(u @ covariance @ u), 0.0))


def covariance_from_upper(values: Sequence[float]) -> np.ndarray:
    """A symmetric 3 x 3 matrix from its upper triangle (xx, xy, xz, yy, yz, zz), as the flight logs keep it."""
    xx, xy, xz, yy, yz, zz = (float(v) for v in values)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _json_schema(topic: str) -> Schema:
    fields = JSON_TOPICS[topic]
    document = {"title": topic, "type": "object",
                "properties": {name: {"description": text} for name, text in fields.items()}}
    return Schema(name=topic.strip("/").replace("/", "."), encoding="jsonschema", data=json.dumps(document).encode())


class FlightChannels:
    """The channels of one flight in a foxglove Context (a private one by default, so that two flights, or a
    flight and a live view, never mix). Give it to foxglove.open_mcap / foxglove.start_server (context=...)
    *before* logging: a sink sees only what is logged after it is attached.

    Every method takes the flight time in s and SI values in local NED; a value that is not finite is left
    out of a JSON message (a null would not plot)."""

    def __init__(self, context: Context | None = None, desired_range: float | None = None) -> None:
        self.context = Context() if context is None else context
        self.desired_range = desired_range
        self._tf = FrameTransformsChannel(TF_TOPIC, context=self.context)
        self._poses = {name: PoseInFrameChannel(topic, context=self.context) for name, topic in POSE_TOPICS.items()}
        self._scene = SceneUpdateChannel(SCENE_TOPIC, context=self.context)
        self._json = {topic: Channel(topic, schema=_json_schema(topic), message_encoding="json", context=self.context)
                      for topic in JSON_TOPICS}
        self._events = LogChannel(EVENTS_TOPIC, context=self.context)
        self._trail_from: dict[str, tuple[float, float, float]] = {}
        self._pieces = 0

    def frames(self, time_s: float) -> None:
        """The world -> ned transform (constant: log it once at the start, and now and then for a live view)."""
        t = nanoseconds(time_s)
        transform = FrameTransform(timestamp=_stamp(t), parent_frame_id=WORLD_FRAME, child_frame_id=NED_FRAME,
                                   translation=_vector((0.0, 0.0, 0.0)),
                                   rotation=_quaternion(quaternion_wxyz(NED_IN_WORLD).tolist()))
        self._tf.log(FrameTransforms(transforms=[transform]), log_time=t)

    def pose(self, which: str, time_s: float, position: Sequence[float], attitude_wxyz: Sequence[float] = IDENTITY) -> None:
        """A pose on POSE_TOPICS[which] ("pursuer", "target", "estimate"); attitude body FRD -> NED."""
        t = nanoseconds(time_s)
        self._poses[which].log(PoseInFrame(timestamp=_stamp(t), frame_id=NED_FRAME,
                                           pose=Pose(position=_vector(position), orientation=_quaternion(attitude_wxyz))),
                               log_time=t)

    def values(self, topic: str, time_s: float, values: Mapping[str, Any]) -> None:
        """A JSON message on `topic` (one of JSON_TOPICS) with the fields of `values` it declares; NaN and
        infinite numbers are left out."""
        fields = JSON_TOPICS[topic]
        message = {}
        for key, value in values.items():
            if key not in fields:
                raise KeyError(f"{topic} has no field {key!r} (fields: {', '.join(fields)})")
            if isinstance(value, (float, np.floating)):
                if not math.isfinite(value):
                    continue
                value = float(value)
            elif isinstance(value, np.integer):
                value = int(value)
            message[key] = value
        self._json[topic].log(message, log_time=nanoseconds(time_s))

    def scene(self, time_s: float, pursuer: Sequence[float] | None, target: Sequence[float] | None,
              estimate: Sequence[float] | None = None, covariance: np.ndarray | None = None,
              bearing: Sequence[float] | None = None) -> None:
        """One scene update: the estimate's ellipsoid (with `covariance`, 3 x 3), the bearing ray from the pursuer
        along `bearing` out to the estimated range (or 10 m without an estimate), and a trace piece per path from
        its previous scene position (each piece lives TRAIL_S seconds)."""
        t = nanoseconds(time_s)
        stamp = _stamp(t)
        entities = []
        if estimate is not None and covariance is not None and np.all(np.isfinite(covariance)):
            orientation, diameters = ellipsoid(covariance)
            entities.append(SceneEntity(timestamp=stamp, frame_id=NED_FRAME, id="estimate_ellipsoid", spheres=[
                SpherePrimitive(pose=Pose(position=_vector(estimate), orientation=_quaternion(orientation)),
                                size=_vector(diameters), color=COLORS["ellipsoid"])]))
        if pursuer is not None and bearing is not None and np.all(np.isfinite(bearing)):
            length = float(np.linalg.norm(np.asarray(estimate) - np.asarray(pursuer))) if estimate is not None else 10.0
            end = np.asarray(pursuer, dtype=float) + length * np.asarray(bearing, dtype=float)
            entities.append(SceneEntity(timestamp=stamp, frame_id=NED_FRAME, id="bearing", lines=[
                LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=Pose(position=_vector((0, 0, 0)),
                                                                              orientation=_quaternion(IDENTITY)),
                              thickness=2.0, scale_invariant=True, points=[_point(pursuer), _point(end)],
                              color=COLORS["bearing"])]))
        for name, position in (("pursuer", pursuer), ("target", target), ("estimate", estimate)):
            if position is None or not np.all(np.isfinite(position)):
                continue
            here = tuple(float(v) for v in position)
            start = self._trail_from.get(name)
            self._trail_from[name] = here
            if start is None:
                continue
            self._pieces += 1
            entities.append(SceneEntity(timestamp=stamp, frame_id=NED_FRAME, id=f"{name}_path/{self._pieces}",
                                        lifetime=_duration(TRAIL_S), lines=[
                LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=Pose(position=_vector((0, 0, 0)),
                                                                              orientation=_quaternion(IDENTITY)),
                              thickness=1.5, scale_invariant=True, points=[_point(start), _point(here)],
                              color=COLORS[name])]))
        if entities:
            self._scene.log(SceneUpdate(entities=entities), log_time=t)

    def event(self, time_s: float, text: str, level: str = "info") -> None:
        """A line on /events (level "info", "warning" or "error")."""
        t = nanoseconds(time_s)
        self._events.log(Log(timestamp=_stamp(t), level=LOG_LEVELS[level], message=text, name="flight"), log_time=t)


def _duration(seconds: float) -> Duration:
    whole = int(seconds)
    return Duration(sec=whole, nsec=int(round((seconds - whole) * 1e9)))


class _JsonDecoderFactory(McapDecoderFactory):
    """The mcap reader's decoder for JSON channels (message encoding "json")."""

    def decoder_for(self, message_encoding: str, schema: McapSchema | None) -> Callable[[bytes], Any] | None:
        return json.loads if message_encoding == "json" else None


@dataclasses.dataclass
class FlightFile:
    """A flight's MCAP as read back: per topic, the log times (s of the flight) and the decoded messages
    (protobuf message objects for the foxglove schemas, dicts for the JSON channels); its metadata by name."""

    times: dict[str, list[float]]
    messages: dict[str, list[Any]]
    schemas: dict[str, str]
    metadata: dict[str, dict[str, str]]

    def series(self, topic: str, field: str) -> tuple[np.ndarray, np.ndarray]:
        """(times, values) of one numeric field of a JSON channel, where the messages carry it."""
        pairs = [(t, m[field]) for t, m in zip(self.times.get(topic, ()), self.messages.get(topic, ())) if field in m]
        if not pairs:
            return np.zeros(0), np.zeros(0)
        times, values = zip(*pairs)
        return np.array(times), np.array(values, dtype=float)

    def positions(self, which: str) -> tuple[np.ndarray, np.ndarray]:
        """(times, positions (N, 3) NED) of a pose channel (POSE_TOPICS' names)."""
        messages = self.messages.get(POSE_TOPICS[which], [])
        points = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in messages]).reshape(-1, 3)
        return np.array(self.times.get(POSE_TOPICS[which], [])), points


def read_flight(path: Path | str) -> FlightFile:
    """Read a flight.mcap with the mcap library (protobuf and JSON decoders). Raises ValueError naming the file
    when it is not a readable MCAP."""
    times: dict[str, list[float]] = {}
    messages: dict[str, list[Any]] = {}
    schemas: dict[str, str] = {}
    try:
        with open(path, "rb") as handle:
            reader = make_reader(handle, decoder_factories=[ProtobufDecoderFactory(), _JsonDecoderFactory()])
            for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
                times.setdefault(channel.topic, []).append(message.log_time * 1e-9)
                messages.setdefault(channel.topic, []).append(decoded)
                schemas[channel.topic] = schema.name if schema is not None else ""
            metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
    except (McapError, OSError, ValueError, EOFError) as error:
        raise ValueError(f"{path}: not a readable flight MCAP ({error})") from None
    return FlightFile(times, messages, schemas, metadata)
