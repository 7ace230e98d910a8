"""Following a planned cell path: re-plan only when the goal (the estimate) changes.

Seed pomdp-astar §II-D: "Once the source mapping algorithm updates a new estimated source
location, the planned path will be updated correspondingly. The AUV follows the planned path
until it is updated." We also re-plan when the vehicle is no longer on the path (it strayed).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

from service.core.planning.base import Plan

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.planning.base import BoolArray, PlanContext


class PathFollower(ABC):
    """A planner that computes a whole cell path to the goal and then follows it."""

    name: ClassVar[str]

    def __init__(self, grid: Grid, config: PlanningConfig) -> None:
        self.grid = grid
        self.config = config
        self.blocked: BoolArray = grid.obstacle_mask
        self.replans = 0
        """How many paths were computed (a test sees that a new estimate re-plans)."""
        self._goal: int | None = None
        self._path: list[int] = []
        self._index = 0

    def plan(self, ctx: PlanContext) -> Plan:
        index = self._progress(ctx.cell) if ctx.goal == self._goal else None
        if index is None:
            self._goal = None  # a failed computation must not leave a stale path behind
            self._path = self.compute(ctx)
            self.replans += 1
            self._goal, index = ctx.goal, 0
        self._index = index
        return Plan.along(self.grid, self._path[index:])

    def forget(self) -> None:
        """Drop the path being followed: the next ``plan`` computes a new one."""
        self._goal = None
        self._path = []
        self._index = 0

    def _progress(self, cell: int) -> int | None:
        """Where the vehicle's cell is on the path, searching forward from the last position."""
        try:
            return self._path.index(cell, self._index)
        except ValueError:
            return None

    @abstractmethod
    def compute(self, ctx: PlanContext) -> list[int]:
        """A cell path from ``ctx.cell`` to ``ctx.goal`` (both included); NoPathError if none."""
