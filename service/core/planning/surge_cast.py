"""Surge-cast: the moth-inspired baseline that uses no map (seed pomdp-astar §I, its ref. [13]).

Moths flying up a pheromone plume surge upwind while they smell it and cast across the wind when
they lose it (Kennedy and Marsh 1974, the seed's ref. [9]). Here the mission already casts across
the flow around the last detection when the plume is lost (``planning.cast``) and sweeps a
zigzag before the first detection (``planning.zigzag``); this planner is the surge: while the
mission traces, it steers ``surge_step_m`` straight against the flow measured at the vehicle
(the newest tick of the flow history), whatever the source map says. The map is still built
(the mission declares from it), so comparing this planner with the map-driven ones at the same
mapper shows what the map adds to navigation.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

from service.core.errors import NoPathError
from service.core.planning.base import Plan, Waypoint
from service.core.planning.safety import is_safe_point, segment_clear

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.planning.base import PlanContext


def surge_point(x: float, y: float, flow_x: float, flow_y: float, step_m: float) -> tuple[float, float]:
    """The point ``step_m`` from (x, y) against the flow (x, y itself when there is no flow)."""
    speed = math.hypot(flow_x, flow_y)
    if speed == 0.0:
        return x, y
    return x - step_m * flow_x / speed, y - step_m * flow_y / speed


class SurgeCastPlanner:
    """Upflow surge while tracing; raises NoPathError when the surge leg is blocked or leaves
    the area (the mission then routes to its estimate with A*)."""

    name: ClassVar[str] = "surge-cast"
    steers_by_map: ClassVar[bool] = False

    def __init__(self, grid: Grid, config: PlanningConfig) -> None:
        self.grid = grid
        self.step_m = config.surge_step_m

    def plan(self, ctx: PlanContext) -> Plan:
        history = ctx.mapper.history
        if not history:
            raise NoPathError("no flow measured yet: no upflow direction")
        newest = history[-1]
        v = ctx.vehicle
        x, y = surge_point(v.x, v.y, newest.dx_m, newest.dy_m, self.step_m)
        # clip to the area so that a vehicle at the upflow edge slides along it
        g = self.grid
        half_w, half_h = g.cell_width_m / 2.0, g.cell_height_m / 2.0
        x = min(max(x, g.x_min + half_w), g.x_max - half_w)
        y = min(max(y, g.y_min + half_h), g.y_max - half_h)
        if not is_safe_point(g, x, y) or not segment_clear(g, (v.x, v.y), (x, y)):
            raise NoPathError("the surge leg is blocked")
        return Plan((Waypoint(x, y),), (g.cell_of(x, y),))
