"""``LOST``: the cast across the flow around the last detection (``planning.cast``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from service.core.mission.pattern import Pattern
from service.core.planning.cast import cast_vertices

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.mission.routing import Routing
    from service.core.planning.base import PlanContext, Waypoint
    from service.core.planning.crossflow import FlowFrame


@dataclass
class Cast:
    """The cast's legs (``pattern``)."""

    grid: Grid
    planning: PlanningConfig
    pattern: Pattern = field(default_factory=Pattern)

    def lay(self, last_detection: tuple[float, float] | None, frame: FlowFrame | None) -> None:
        """A new cast through the last detection (x, y); none without a detection or a flow."""
        self.pattern = Pattern()
        if last_detection is not None and frame is not None:
            x, y = last_detection
            p = self.planning
            self.pattern = Pattern(cast_vertices(self.grid, x, y, frame, p.cast_width_m, p.cast_legs))

    def waypoints(self, ctx: PlanContext, routing: Routing) -> tuple[Waypoint, ...] | None:
        """The legs still to fly; None once the cast is over."""
        return self.pattern.follow(ctx, routing)
