"""The drawable messages, checked against hand-worked poses, quaternions and sizes."""

import math

import pytest
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from service.core.mapping.mapper import Estimate
from service.core.mission import SourceDeclared
from service.core.observation import Observation
from service.edges.foxglove_scene import (
    DETECTIONS_TOPIC,
    FLOW_ARROW_M_PER_MPS,
    MARKERS_TOPIC,
    PLAN_TOPIC,
    SCHEMAS,
    SOURCE_TOPIC,
    TRACK_TOPIC,
    SceneBuilder,
    flow_entity,
    frame_transform,
    poses,
    source_update,
    true_source,
    vehicle_pose,
)

ESTIMATE = Estimate(cell=7, x=3.0, y=4.0, probability=0.42, entropy=1.5)


def yaw(z: float, w: float) -> float:
    return 2.0 * math.atan2(z, w)


def test_a_vehicle_heading_north_is_a_quarter_turn_about_up() -> None:
    pose = vehicle_pose(12.25, 1.0, 2.0, math.pi / 2)
    assert (pose.frame_id, pose.timestamp.seconds, pose.timestamp.nanos) == ("map", 12, 250_000_000)
    q = pose.pose.orientation
    assert (q.x, q.y) == (0.0, 0.0)
    assert (q.z, q.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    tf = frame_transform(12.25, 1.0, 2.0, math.pi / 2)
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "vehicle")
    assert (tf.translation.x, tf.translation.y) == (1.0, 2.0)
    assert (tf.rotation.z, tf.rotation.w) == pytest.approx((q.z, q.w))


def test_each_pose_of_a_polyline_faces_the_next_point() -> None:
    message = poses(0.0, [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (1.0, 1.0)])
    headings = [yaw(p.orientation.z, p.orientation.w) for p in message.poses]
    assert headings == pytest.approx([0.0, math.pi / 2, math.pi / 2, math.pi / 2])
    assert [(p.position.x, p.position.y) for p in message.poses] == [(0, 0), (1, 0), (1, 1), (1, 1)]


def test_the_flow_arrow_points_where_the_fluid_goes_and_scales_with_its_speed() -> None:
    arrow = flow_entity(0.0, 5.0, 6.0, 0.0, -0.8).arrows[0]
    assert yaw(arrow.pose.orientation.z, arrow.pose.orientation.w) == pytest.approx(-math.pi / 2)
    assert arrow.shaft_length + arrow.head_length == pytest.approx(0.8 * FLOW_ARROW_M_PER_MPS)
    assert (arrow.pose.position.x, arrow.pose.position.y) == (5.0, 6.0)


def test_the_true_source_reads_back() -> None:
    update = SceneUpdate.FromString(source_update(3.0, 18.75, 4.0).SerializeToString())
    assert true_source(update) == (18.75, 4.0)
    assert update.entities[0].texts[0].text == "true source"
    assert true_source(SceneUpdate()) is None


def test_the_builder_accumulates_the_track_and_detections_and_draws_the_declaration() -> None:
    scene = SceneBuilder(cell_m=2.5, declared_radius_m=3.0, source=(9.0, 9.0))
    declared = SourceDeclared(time_s=2.0, x=3.0, y=4.0, cell=7, probability=0.42, mass=0.8)
    ticks = [
        scene.tick(Observation(0.0, 0.0, 0.0, 1.0, 0.0, True), 0.0, estimate=ESTIMATE, state="search"),
        scene.tick(Observation(1.0, 1.0, 0.0, 1.0, 0.0, False), 0.0, estimate=ESTIMATE, state="trace",
                   path=[(2.0, 0.0), (3.0, 1.0)]),
        scene.tick(Observation(2.0, 2.0, 0.0, 1.0, 0.0, True), 0.0, estimate=ESTIMATE, state="declared",
                   events=[declared]),
    ]  # fmt: skip
    for records in ticks:
        assert all(topic in SCHEMAS for topic, _ in records)
        assert [t for t, _ in records] == [t for t in SCHEMAS if t in dict(records)]
    last = dict(ticks[-1])
    assert PLAN_TOPIC not in last
    plan = PosesInFrame.FromString(dict(ticks[1])[PLAN_TOPIC])
    assert [(p.position.x, p.position.y) for p in plan.poses] == [(1.0, 0.0), (2.0, 0.0), (3.0, 1.0)]
    track = PosesInFrame.FromString(last[TRACK_TOPIC])
    assert [(p.position.x, p.position.y) for p in track.poses] == [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)]
    detections = SceneUpdate.FromString(last[DETECTIONS_TOPIC]).entities[0]
    assert [(s.pose.position.x, s.pose.position.y) for s in detections.spheres] == [(0.0, 0.0), (2.0, 0.0)]
    markers = {e.id: e for e in SceneUpdate.FromString(last[MARKERS_TOPIC]).entities}
    assert set(markers) == {"estimate", "flow", "declared"}
    assert "declared" not in {e.id for e in SceneUpdate.FromString(dict(ticks[1])[MARKERS_TOPIC]).entities}
    disk = markers["declared"].cylinders[0]
    assert (disk.size.x, disk.size.y) == (6.0, 6.0)  # twice declaration.radius_m
    assert (disk.pose.position.x, disk.pose.position.y) == (3.0, 4.0)
    assert markers["estimate"].texts[0].text == "estimate p=0.42 (declared)"
    assert true_source(SceneUpdate.FromString(last[SOURCE_TOPIC])) == (9.0, 9.0)
