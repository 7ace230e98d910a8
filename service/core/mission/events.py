"""What a mission tells the outside each tick: its state, its events and its answer (``MissionOutput``)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from service.core.mapping.mapper import Estimate
    from service.core.planning.base import Waypoint


class MissionState(StrEnum):
    """Mission phases; the values are the Zenoh ``estimate.state`` strings of DESIGN.md."""

    FIND = "search"
    TRACE = "trace"
    LOST = "lost"
    DECLARED = "declared"


@dataclass(frozen=True)
class PlumeFound:
    """A detection outside ``TRACE``: the mission's first (``first``), one that ends ``LOST``, or
    one met in ``FIND`` again after a lone detection (``planning.lone_contact_hits``)."""

    time_s: float
    x: float
    y: float
    first: bool


@dataclass(frozen=True)
class PlumeLost:
    """No detection for ``lost_after_s``: (x, y) and ``last_detection_s`` are the last detection's."""

    time_s: float
    x: float
    y: float
    last_detection_s: float


class CrossCheck(StrEnum):
    """How a declared cell was vouched for by the check across the flow (``check_width_m``)."""

    FLOWN = "flown"  # flown, no odour upflow
    OFF = "off"  # no check configured (or no flow direction yet)
    ENDURANCE = "endurance"  # not checked: named as the vehicle's endurance ran out


@dataclass(frozen=True)
class SourceDeclared:
    """The source is declared in the papers' cell ``cell`` centred on (x, y); ``check``: how the
    check across the flow vouched for it."""

    time_s: float
    x: float
    y: float
    cell: int
    probability: float
    mass: float
    check: CrossCheck = CrossCheck.OFF


MissionEvent = PlumeFound | PlumeLost | SourceDeclared


@dataclass(frozen=True)
class MissionOutput:
    """One tick's answer. ``waypoints``: the waypoints to fly from now on, the first being the
    current target, or None when they have not changed since the last ones returned."""

    time_s: float
    state: MissionState
    waypoints: tuple[Waypoint, ...] | None
    events: tuple[MissionEvent, ...]
    estimate: Estimate
    hold: bool = False
    """The waypoints are a point to stop on (declared, or nothing safe to fly), not a path to fly."""
