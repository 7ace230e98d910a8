"""How the mission's behaviours get a path: the planner's, to the nearest reachable cell, with the
obstacle-free A* as the fallback."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from service.core.errors import NoPathError
from service.core.planning.astar import AStarPlanner
from service.core.planning.reach import Reachability

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.planning.base import PlanContext, Planner, Waypoint


@dataclass(frozen=True)
class Routing:
    """The grid's reachability and the A* that flies the plume finder's, check and probe legs and
    stands in for a planner that finds no path."""

    grid: Grid
    router: AStarPlanner
    reach: Reachability

    @classmethod
    def of(cls, grid: Grid, planning: PlanningConfig) -> Routing:
        return cls(grid, AStarPlanner(grid, planning), Reachability(grid))

    def route(self, planner: Planner, ctx: PlanContext) -> tuple[Waypoint, ...]:
        """The planner's waypoints to ``ctx.goal``, or to the nearest reachable cell if the goal
        cannot be reached; the obstacle-free A* if the planner raises NoPathError; () if that
        fails too (the vehicle then holds)."""
        ctx = replace(ctx, goal=self.reach.goal_for(ctx.cell, ctx.goal))
        for candidate in (planner, self.router):
            try:
                return candidate.plan(ctx).waypoints
            except NoPathError:
                continue
        return ()

    def to_cell(self, ctx: PlanContext, goal: int) -> tuple[Waypoint, ...]:
        """The A*'s waypoints to ``goal`` (``route`` with the router)."""
        return self.route(self.router, replace(ctx, goal=goal))
