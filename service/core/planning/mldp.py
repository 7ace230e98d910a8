"""Planners on the most likely detection path (seed hmm-plume-mapping §IV-C3 and §VI).

``mldp`` is the planner of the paper's examples (§VI): "commands the vehicle to enter the
neighboring cell that presently has the highest probability of detecting odor (i.e., the 1-step
MLDP)". It re-decides every tick.

``mldp-path`` follows the k-step MLDP (§IV-C3) from the vehicle's cell to the estimated source
cell over the plume map alpha, with k the larger of ``planning.mldp_steps`` and the number of
moves of the shortest admissible path (so a path exists whenever the estimate is reachable),
re-planned when the estimate changes.

Both call ``service.core.mapping.paths``, which allows every App. I move; the vehicle may not cut the
corner of an obstacle cell (``moves.py``), so the 1-step choice is restricted to admissible
neighbours and each corner-cutting step of a k-step path is replaced by a shortest admissible
detour.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from service.core.mapping.paths import most_likely_detection_path, one_step_mldp
from service.core.planning.astar import astar
from service.core.planning.base import Plan
from service.core.planning.follow import PathFollower
from service.core.planning.moves import admissible, free_neighbours, sector_between

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.planning.base import BoolArray, PlanContext


def _admissible_step(grid: Grid, a: int, b: int, blocked: BoolArray) -> bool:
    """Staying, or an admissible move (App. I neighbours only: the MLDP makes no other steps)."""
    return a == b or admissible(grid, a, sector_between(grid, a, b), blocked) == b


def repair_corner_cuts(grid: Grid, path: list[int], blocked: BoolArray) -> list[int]:
    """``path`` with every step that is not an admissible move replaced by the shortest admissible
    path between its two cells (NoPathError if there is none)."""
    out = path[:1]
    for a, b in itertools.pairwise(path):
        if _admissible_step(grid, a, b, blocked):
            out.append(b)
        else:
            out.extend(astar(grid, a, b, blocked)[1:])
    return out


class MldpPlanner:
    """``mldp``: §VI's 1-step MLDP, the admissible neighbour with the greatest alpha."""

    name: ClassVar[str] = "mldp"

    def __init__(self, grid: Grid, config: PlanningConfig) -> None:
        self.grid = grid
        self.config = config
        self.blocked: BoolArray = grid.obstacle_mask

    def plan(self, ctx: PlanContext) -> Plan:
        # everything but the admissible neighbours is closed to the colleague's one-step search
        closed = np.ones(self.grid.shape, dtype=bool)
        for _, cell in free_neighbours(self.grid, ctx.cell, self.blocked):
            closed.flat[cell] = False
        best = one_step_mldp(self.grid, ctx.mapper.plume, ctx.cell, blocked=closed)
        return Plan.along(self.grid, [ctx.cell, best])


class MldpPathPlanner(PathFollower):
    """``mldp-path``: §IV-C3's k-step MLDP to the estimate, followed until the estimate changes."""

    name: ClassVar[str] = "mldp-path"

    def compute(self, ctx: PlanContext) -> list[int]:
        shortest = astar(self.grid, ctx.cell, ctx.goal, self.blocked)
        steps = max(self.config.mldp_steps, len(shortest) - 1)
        # the MLDP may not start in a blocked cell: a vehicle caught in one first steps out of it
        lead = shortest[:1] if len(shortest) == 1 or not self.blocked.flat[ctx.cell] else shortest[:2]
        path = most_likely_detection_path(
            self.grid, ctx.mapper.plume, lead[-1], ctx.goal, steps - (len(lead) - 1), blocked=self.blocked
        )
        return repair_corner_cuts(self.grid, lead[:-1] + path, self.blocked)
