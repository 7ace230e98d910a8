"""A pattern: turning points flown in order, and how far along them the vehicle is.

The plume finder and the check each own one; the same rule flies them all."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from service.core.planning.safety import segment_clear

if TYPE_CHECKING:
    from service.core.mission.routing import Routing
    from service.core.planning.base import PlanContext, Waypoint


ARRIVAL_M = 0.5
"""A turning point counts as reached within this distance even from another cell: a point on a
cell boundary may read as the neighbouring cell, and an autopilot stops once inside its
acceptance radius (ArduPilot Rover's WP_RADIUS: set it to at most this, see the README)."""


@dataclass
class Pattern:
    """Turning points (``vertices``) and the index of the next one not yet reached."""

    vertices: tuple[Waypoint, ...] = ()
    index: int = 0

    def follow(self, ctx: PlanContext, routing: Routing) -> tuple[Waypoint, ...] | None:
        """Waypoints to the next turning point not yet reached; None once all are reached. A
        turning point that cannot be reached counts as reached at the nearest reachable cell."""
        grid = routing.grid
        while self.index < len(self.vertices):
            vertex = self.vertices[self.index]
            vertex_cell = grid.cell_of(vertex.x, vertex.y)
            target = routing.reach.goal_for(ctx.cell, vertex_cell)
            arrived = math.hypot(vertex.x - ctx.vehicle.x, vertex.y - ctx.vehicle.y) <= ARRIVAL_M
            if target != ctx.cell and not arrived:
                # a vertex in a blocked cell (an obstacle rectangle may cover only part of a
                # cell) would be refused by the safety rule: the route goes to its stand-in
                straight = target == vertex_cell
                if straight and segment_clear(grid, (ctx.vehicle.x, ctx.vehicle.y), (vertex.x, vertex.y)):
                    # a clear leg is flown straight: A*'s cell staircase would put the diagonal
                    # part of a leg anywhere along it, and a leg that first runs along the
                    # previous one looks at nothing new
                    return (vertex,)
                return routing.to_cell(ctx, target)
            self.index += 1
        return None
