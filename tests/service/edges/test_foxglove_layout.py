"""The Foxglove layout in config/foxglove/: it parses, opens on the map and names only what we publish."""

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from service.edges.foxglove_scene import (
    DETECTIONS_TOPIC,
    MARKERS_TOPIC,
    PLAN_TOPIC,
    TRACK_TOPIC,
    VEHICLE_TOPIC,
)
from service.edges.foxglove_scene import SCHEMAS as SCENE_SCHEMAS
from service.edges.messages import ESTIMATE_KEYS
from service.edges.recorder import (
    CONFIG_TOPIC,
    ESTIMATE_TOPIC,
    EVENT_TOPIC,
    OBS_TOPIC,
    PATH_TOPIC,
    PLUME_TOPIC,
    SETPOINT_TOPIC,
    SLIM_TOPIC,
)

LAYOUT = Path(__file__).resolve().parents[3] / "config" / "foxglove" / "oslim.json"
PUBLISHED = {
    CONFIG_TOPIC, OBS_TOPIC, SLIM_TOPIC, PLUME_TOPIC, ESTIMATE_TOPIC, PATH_TOPIC, SETPOINT_TOPIC, EVENT_TOPIC,
    *SCENE_SCHEMAS,
}  # fmt: skip
"""Every channel the recorder writes and the live view sends."""


def layout() -> dict[str, Any]:
    value = json.loads(LAYOUT.read_text(encoding="utf-8"))
    assert isinstance(value, dict)
    return value


def leaves(node: Any) -> Iterator[str]:
    """Panel ids of the mosaic tree."""
    if isinstance(node, str):
        yield node
    else:
        yield from leaves(node["first"])
        yield from leaves(node["second"])


def panel(kind: str) -> dict[str, Any]:
    (config,) = [c for pid, c in layout()["configById"].items() if pid.split("!")[0] == kind]
    assert isinstance(config, dict)
    return config


def message_paths() -> list[str]:
    """Every message path of the plot, state and raw-message panels."""
    paths = []
    for pid, config in layout()["configById"].items():
        kind = pid.split("!")[0]
        if kind in ("Plot", "StateTransitions"):
            paths += [p["value"] for p in config["paths"]]
        elif kind == "RawMessages":
            paths.append(config["topicPath"])
    return paths


def test_every_panel_of_the_mosaic_is_configured_and_every_configured_panel_shown() -> None:
    data = layout()
    assert sorted(leaves(data["layout"])) == sorted(data["configById"])


def test_it_names_only_channels_the_service_publishes() -> None:
    named = set(panel("3D")["topics"]) | {path.split(".")[0] for path in message_paths()}
    assert named <= PUBLISHED, named - PUBLISHED


def test_the_3d_panel_shows_the_map_track_path_detections_and_estimate_in_the_map_frame() -> None:
    config = panel("3D")
    shown = {topic for topic, settings in config["topics"].items() if settings.get("visible")}
    assert {SLIM_TOPIC, VEHICLE_TOPIC, TRACK_TOPIC, PLAN_TOPIC, DETECTIONS_TOPIC, MARKERS_TOPIC} <= shown
    assert config["topics"][SLIM_TOPIC]["colorField"] == "likelihood"
    assert config["followTf"] == "map"


def test_probability_entropy_and_state_are_plotted_from_the_estimate() -> None:
    paths = message_paths()
    for key in ("probability", "entropy", "state"):
        assert f"{ESTIMATE_TOPIC}.{key}" in paths
        assert key in ESTIMATE_KEYS
    assert EVENT_TOPIC in paths
