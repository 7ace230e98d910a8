"""What Foxglove's 3D panel can draw of a mission, as Foxglove's own protobuf messages (no I/O).

The MCAP recording and the live Foxglove view carry exactly these bytes (DESIGN.md, MCAP and
Foxglove contract); the maps themselves are ``grid_message``'s foxglove.Grid. Everything is in
the map frame (``frame_id`` ``map``: x East, y North, metres); ``/oslim/tf`` places a ``vehicle``
frame in it.

| topic                | schema                 | content (every tick unless said)                    |
| -------------------- | ---------------------- | --------------------------------------------------- |
| ``/oslim/tf``         | foxglove.FrameTransform | ``map`` -> ``vehicle``: position and heading        |
| ``/oslim/vehicle``    | foxglove.PoseInFrame    | the vehicle's pose                                  |
| ``/oslim/track``      | foxglove.PosesInFrame   | every position so far (the last ``MAX_TRACK``)       |
| ``/oslim/plan``       | foxglove.PosesInFrame   | vehicle, then the planned waypoints (when replanned) |
| ``/oslim/detections`` | foxglove.SceneUpdate    | entity ``detections``: a sphere per detection        |
| ``/oslim/markers``    | foxglove.SceneUpdate    | ``estimate``, ``flow``, ``declared`` (below)         |
| ``/sim/source``       | foxglove.SceneUpdate    | simulation only: entity ``true_source`` (text)       |

``/oslim/markers`` holds the entities ``estimate`` (a sphere and its probability as text),
``flow`` (an arrow at the vehicle, toward where the fluid goes) and, once declared,
``declared`` (a disk of radius ``declaration.radius_m`` on the cell, with a label).

``SceneBuilder`` keeps the track and detections between ticks; the functions it calls are pure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final

from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.message import Message

from service.core.mission import SourceDeclared
from service.edges.grid_message import DEFAULT_FRAME_ID

if TYPE_CHECKING:
    from foxglove_schemas_protobuf.Color_pb2 import Color
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from google.protobuf.timestamp_pb2 import Timestamp

    from service.core.mapping.mapper import Estimate
    from service.core.observation import Observation

MAP_FRAME: Final = DEFAULT_FRAME_ID
VEHICLE_FRAME: Final = "vehicle"

TF_TOPIC: Final = "/oslim/tf"
VEHICLE_TOPIC: Final = "/oslim/vehicle"
TRACK_TOPIC: Final = "/oslim/track"
PLAN_TOPIC: Final = "/oslim/plan"
DETECTIONS_TOPIC: Final = "/oslim/detections"
MARKERS_TOPIC: Final = "/oslim/markers"
SOURCE_TOPIC: Final = "/sim/source"

SCHEMAS: Final[dict[str, type[Message]]] = {
    TF_TOPIC: FrameTransform,
    VEHICLE_TOPIC: PoseInFrame,
    TRACK_TOPIC: PosesInFrame,
    PLAN_TOPIC: PosesInFrame,
    DETECTIONS_TOPIC: SceneUpdate,
    MARKERS_TOPIC: SceneUpdate,
    SOURCE_TOPIC: SceneUpdate,
}
"""Topic -> protobuf message class of every channel this module fills (recorder and live view)."""

MAX_TRACK: Final = 7200
"""Positions kept in ``/oslim/track`` (two hours at 1 Hz); older ones drop off the front."""

FLOW_ARROW_M_PER_MPS: Final = 5.0
"""Length of the flow arrow per m/s of flow (an arrow of a few metres for a 0.5-1 m/s flow)."""

Rgba = tuple[float, float, float, float]
DETECTION_RGBA: Final[Rgba] = (0.85, 0.1, 0.1, 0.9)
ESTIMATE_RGBA: Final[Rgba] = (0.6, 0.2, 0.8, 0.9)
FLOW_RGBA: Final[Rgba] = (0.1, 0.4, 0.9, 0.9)
DECLARED_RGBA: Final[Rgba] = (0.1, 0.7, 0.2, 0.35)
SOURCE_RGBA: Final[Rgba] = (1.0, 0.8, 0.0, 1.0)
TEXT_RGBA: Final[Rgba] = (1.0, 1.0, 1.0, 1.0)


def stamp(target: Timestamp, time_s: float) -> None:
    """Write ``time_s`` (service clock, seconds) into a protobuf Timestamp."""
    if not math.isfinite(time_s):
        raise ValueError(f"time_s must be finite, got {time_s}")
    seconds = math.floor(time_s)
    target.seconds = seconds
    target.nanos = min(round((time_s - seconds) * 1e9), 999_999_999)


def _place(pose: Pose, x: float, y: float, heading_rad: float = 0.0, z: float = 0.0) -> None:
    """Position (x, y, z) and a yaw of ``heading_rad`` from +x (East), counter-clockwise about +z."""
    pose.position.x, pose.position.y, pose.position.z = x, y, z
    pose.orientation.z = math.sin(heading_rad / 2.0)
    pose.orientation.w = math.cos(heading_rad / 2.0)


def _colour(target: Color, rgba: Rgba) -> None:
    target.r, target.g, target.b, target.a = rgba


def frame_transform(time_s: float, x: float, y: float, heading_rad: float) -> FrameTransform:
    """``map`` -> ``vehicle``: the vehicle frame at (x, y), its +x along ``heading_rad``."""
    message = FrameTransform(parent_frame_id=MAP_FRAME, child_frame_id=VEHICLE_FRAME)
    stamp(message.timestamp, time_s)
    message.translation.x, message.translation.y, message.translation.z = x, y, 0.0
    message.rotation.z = math.sin(heading_rad / 2.0)
    message.rotation.w = math.cos(heading_rad / 2.0)
    return message


def vehicle_pose(time_s: float, x: float, y: float, heading_rad: float) -> PoseInFrame:
    """The vehicle as a pose in the map frame."""
    message = PoseInFrame(frame_id=MAP_FRAME)
    stamp(message.timestamp, time_s)
    _place(message.pose, x, y, heading_rad)
    return message


def poses(time_s: float, points: Sequence[tuple[float, float]]) -> PosesInFrame:
    """A polyline as poses in the map frame, each facing the next point (the last keeps its
    predecessor's heading), so Foxglove can draw it as a line or as arrows."""
    message = PosesInFrame(frame_id=MAP_FRAME)
    stamp(message.timestamp, time_s)
    heading = 0.0
    for k, (x, y) in enumerate(points):
        if k + 1 < len(points):
            nx, ny = points[k + 1]
            if (nx, ny) != (x, y):
                heading = math.atan2(ny - y, nx - x)
        _place(message.poses.add(), x, y, heading)
    return message


def _entity(time_s: float, entity_id: str, **metadata: str) -> SceneEntity:
    entity = SceneEntity(frame_id=MAP_FRAME, id=entity_id)
    stamp(entity.timestamp, time_s)
    for key, value in metadata.items():
        entity.metadata.add(key=key, value=value)
    return entity


def _text(entity: SceneEntity, x: float, y: float, text: str, z: float = 1.5) -> None:
    label = entity.texts.add(billboard=True, font_size=14.0, scale_invariant=True, text=text)
    _place(label.pose, x, y, z=z)
    _colour(label.color, TEXT_RGBA)


def _sphere(entity: SceneEntity, x: float, y: float, diameter_m: float, rgba: Rgba) -> None:
    sphere = entity.spheres.add()
    _place(sphere.pose, x, y)
    sphere.size.x = sphere.size.y = sphere.size.z = diameter_m
    _colour(sphere.color, rgba)


def detections_update(time_s: float, points: Sequence[tuple[float, float]], diameter_m: float) -> SceneUpdate:
    """Entity ``detections``: one sphere per position where the detector fired."""
    entity = _entity(time_s, "detections", count=str(len(points)))
    for x, y in points:
        _sphere(entity, x, y, diameter_m, DETECTION_RGBA)
    update = SceneUpdate()
    update.entities.append(entity)
    return update


def estimate_entity(time_s: float, state: str, estimate: Estimate, diameter_m: float) -> SceneEntity:
    """Entity ``estimate``: a sphere at the estimated source cell, labelled with its probability."""
    probability = repr(float(estimate.probability))
    entity = _entity(time_s, "estimate", state=state, cell=str(estimate.cell), probability=probability)
    _sphere(entity, estimate.x, estimate.y, diameter_m, ESTIMATE_RGBA)
    _text(entity, estimate.x, estimate.y, f"estimate p={estimate.probability:.2f} ({state})")
    return entity


def flow_entity(time_s: float, x: float, y: float, flow_x: float, flow_y: float) -> SceneEntity:
    """Entity ``flow``: an arrow at the vehicle along the flow (toward), ``FLOW_ARROW_M_PER_MPS``."""
    speed = math.hypot(flow_x, flow_y)
    entity = _entity(time_s, "flow", speed_mps=repr(speed))
    length = max(speed * FLOW_ARROW_M_PER_MPS, 0.3)
    arrow = entity.arrows.add(
        shaft_length=0.75 * length, shaft_diameter=0.15, head_length=0.25 * length, head_diameter=0.45
    )
    _place(arrow.pose, x, y, math.atan2(flow_y, flow_x), z=0.2)
    _colour(arrow.color, FLOW_RGBA)
    return entity


def declared_entity(declared: SourceDeclared, radius_m: float) -> SceneEntity:
    """Entity ``declared``: a flat disk of the declaration radius on the cell, with a label."""
    entity = _entity(
        declared.time_s, "declared", cell=str(declared.cell), radius_m=repr(float(radius_m)),
        probability=repr(float(declared.probability)), mass=repr(float(declared.mass)),
    )  # fmt: skip
    disk = entity.cylinders.add(bottom_scale=1.0, top_scale=1.0)
    _place(disk.pose, declared.x, declared.y, z=0.05)
    disk.size.x = disk.size.y = 2.0 * radius_m
    disk.size.z = 0.1
    _colour(disk.color, DECLARED_RGBA)
    _text(entity, declared.x, declared.y, f"declared cell {declared.cell} (r {radius_m:g} m)", z=2.5)
    return entity


def source_update(time_s: float, x: float, y: float) -> SceneUpdate:
    """``/sim/source``: entity ``true_source`` at the simulated source, labelled."""
    entity = _entity(time_s, "true_source")
    _sphere(entity, x, y, 1.0, SOURCE_RGBA)
    _text(entity, x, y, "true source", z=2.0)
    update = SceneUpdate()
    update.entities.append(entity)
    return update


def true_source(update: SceneUpdate) -> tuple[float, float] | None:
    """The (x, y) of the ``true_source`` entity of a ``/sim/source`` message, if it has one."""
    for entity in update.entities:
        if entity.id == "true_source" and entity.spheres:
            position = entity.spheres[0].pose.position
            return position.x, position.y
    return None


def payload(message: Message) -> bytes:
    """The serialised message: what the recorder writes and the live view sends."""
    data: bytes = message.SerializeToString()
    return data


@dataclass
class SceneBuilder:
    """The drawable messages of each tick. Keeps the track and the detections between ticks.

    ``cell_m`` sizes the spheres (a third of a cell); ``declared_radius_m`` is the declaration's
    radius (``declaration.radius_m``), drawn around the declared cell.
    """

    cell_m: float
    declared_radius_m: float
    track: list[tuple[float, float]] = field(default_factory=list)
    detections: list[tuple[float, float]] = field(default_factory=list)
    declared: SourceDeclared | None = None
    source: tuple[float, float] | None = None
    """The simulated source, when known: then every tick also carries ``/sim/source``."""

    def tick(
        self,
        obs: Observation,
        heading_rad: float,
        *,
        estimate: Estimate,
        state: str,
        path: Sequence[tuple[float, float]] | None = None,
        events: Sequence[object] = (),
    ) -> list[tuple[str, bytes]]:
        """(topic, payload) of every drawable message of this tick, in ``SCHEMAS`` order.

        ``events``: the mission's events of the tick; a ``SourceDeclared`` is drawn from this
        tick on."""
        t, x, y = obs.time_s, obs.x, obs.y
        for event in events:
            if isinstance(event, SourceDeclared):
                self.declared = event
        self.track.append((x, y))
        del self.track[:-MAX_TRACK]
        if obs.detected:
            self.detections.append((x, y))
        diameter = self.cell_m / 3.0
        markers = SceneUpdate()
        markers.entities.append(estimate_entity(t, state, estimate, diameter * 1.5))
        markers.entities.append(flow_entity(t, x, y, obs.flow_x, obs.flow_y))
        if self.declared is not None:
            markers.entities.append(declared_entity(self.declared, self.declared_radius_m))
        records = [
            (TF_TOPIC, payload(frame_transform(t, x, y, heading_rad))),
            (VEHICLE_TOPIC, payload(vehicle_pose(t, x, y, heading_rad))),
            (TRACK_TOPIC, payload(poses(t, self.track))),
        ]
        if path is not None:
            records.append((PLAN_TOPIC, payload(poses(t, [(x, y), *path]))))
        records += [
            (DETECTIONS_TOPIC, payload(detections_update(t, self.detections, diameter))),
            (MARKERS_TOPIC, payload(markers)),
        ]
        if self.source is not None:
            records.append((SOURCE_TOPIC, payload(source_update(t, *self.source))))
        return records
