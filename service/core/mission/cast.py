"""``LOST``: the cast across the flow around the last detection (``planning.cast``), and when the
map makes it pointless: with ``lost_trace_mass`` > 0, while the estimate holds that share of the
map the vehicle goes on tracing instead of casting.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from service.core.mission.pattern import Pattern
from service.core.planning.cast import cast_vertices
from service.core.planning.declaration import mass_within

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.mapping.belief import FloatArray
    from service.core.mission.routing import Routing
    from service.core.planning.base import PlanContext, Waypoint
    from service.core.planning.crossflow import FlowFrame


@dataclass
class Cast:
    """The cast's legs (``pattern``); ``radius_m``: the declaration's, for ``lost_trace_mass``."""

    grid: Grid
    planning: PlanningConfig
    radius_m: float
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

    def map_knows_the_plume(self, likelihood: FloatArray) -> bool:
        """Whether the estimate holds ``lost_trace_mass`` of the map (within the declaration
        radius). The cast is for a map that does not know where the plume went; one that does
        has its estimate near the source, where a cast through the last detection, often just
        upflow of the source, crosses the flow where the plume is not."""
        share = self.planning.lost_trace_mass
        if share <= 0.0:
            return False
        cell = int(np.argmax(likelihood))
        return mass_within(self.grid, likelihood, cell, self.radius_m) >= share
