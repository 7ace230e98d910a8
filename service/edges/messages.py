"""The JSON payloads of DESIGN.md's contracts: what Zenoh publishes and MCAP records alike.

``obs``: ``{time_s, x, y, flow_x, flow_y, detected}``; ``estimate``: ``{time_s, state, cell,
x, y, probability, entropy}``; ``path``: ``{time_s, waypoints: [[x, y], ...]}`` (map frame,
metres). Floats round-trip exactly through JSON, which replay relies on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Final

from service.core.observation import Observation

if TYPE_CHECKING:
    from service.core.mapping.mapper import Estimate

ESTIMATE_STATES: Final = frozenset({"search", "trace", "lost", "declared"})
"""Values of the ``state`` key of an estimate (the mission's states)."""

ESTIMATE_KEYS: Final = ("time_s", "state", "cell", "x", "y", "probability", "entropy")
OBS_KEYS: Final = ("time_s", "x", "y", "flow_x", "flow_y", "detected")
PATH_KEYS: Final = ("time_s", "waypoints")

JsonObject = dict[str, Any]
Waypoint = tuple[float, float]


def _finite(name: str, value: float) -> float:
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return number


def obs_json(obs: Observation) -> JsonObject:
    """The ``obs`` payload: one tick's observation, keys ``OBS_KEYS``."""
    return {
        "time_s": obs.time_s,
        "x": obs.x,
        "y": obs.y,
        "flow_x": obs.flow_x,
        "flow_y": obs.flow_y,
        "detected": obs.detected,
    }


def observation_from_json(data: Mapping[str, Any]) -> Observation:
    """Inverse of ``obs_json`` (exact: JSON floats round-trip); ValueError on missing keys."""
    missing = [k for k in OBS_KEYS if k not in data]
    if missing:
        raise ValueError(f"observation lacks {', '.join(missing)}")
    return Observation(
        time_s=float(data["time_s"]),
        x=float(data["x"]),
        y=float(data["y"]),
        flow_x=float(data["flow_x"]),
        flow_y=float(data["flow_y"]),
        detected=data["detected"],
    )


def estimate_json(time_s: float, state: str, estimate: Estimate) -> JsonObject:
    """The ``estimate`` payload, keys ``ESTIMATE_KEYS``; ``cell`` is the papers' 1-based number."""
    if state not in ESTIMATE_STATES:
        raise ValueError(f"estimate state {state!r} is not one of {sorted(ESTIMATE_STATES)}")
    return {
        "time_s": _finite("time_s", time_s),
        "state": str(state),
        "cell": int(estimate.cell),
        "x": float(estimate.x),
        "y": float(estimate.y),
        "probability": float(estimate.probability),
        "entropy": float(estimate.entropy),
    }


def path_json(time_s: float, waypoints: Sequence[Waypoint]) -> JsonObject:
    """The ``path`` payload: the planned waypoints ``[[x, y], ...]`` in the map frame."""
    points = [[_finite("waypoint x", x), _finite("waypoint y", y)] for x, y in waypoints]
    return {"time_s": _finite("time_s", time_s), "waypoints": points}


def json_payload(value: JsonObject) -> bytes:
    """Compact UTF-8 JSON; NaN and infinity are refused (they are not JSON)."""
    return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
