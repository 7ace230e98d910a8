"""Planners, plume finding and source declaration; ``make_planner`` picks one by ``planning.method``.

Every registered name is a ``PlanningMethod`` value of the configuration, and every planner
implements ``base.Planner``: ``plan(PlanContext) -> Plan``. Plume finding (``prospect``)
and declaration (``declaration``) are used by the mission whatever the planner.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from service.core.planning.apf import ApfPlanner
from service.core.planning.astar import AStarPlanner, PaperAStarPlanner
from service.core.planning.base import Plan, PlanContext, Planner, PlannerFactory, VehicleState, Waypoint
from service.core.planning.mldp import MldpPathPlanner, MldpPlanner

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid

PLANNERS: dict[str, PlannerFactory] = {
    AStarPlanner.name: AStarPlanner,
    PaperAStarPlanner.name: PaperAStarPlanner,
    MldpPlanner.name: MldpPlanner,
    MldpPathPlanner.name: MldpPathPlanner,
    ApfPlanner.name: ApfPlanner,
}


def make_planner(grid: Grid, config: PlanningConfig) -> Planner:
    """The planner registered under ``config.method``."""
    method = str(config.method)
    try:
        factory = PLANNERS[method]
    except KeyError:
        raise ValueError(f"unknown planning method {method!r}; choose one of {sorted(PLANNERS)}") from None
    return factory(grid, config)


__all__ = [
    "PLANNERS",
    "Plan",
    "PlanContext",
    "Planner",
    "PlannerFactory",
    "VehicleState",
    "Waypoint",
    "make_planner",
]
