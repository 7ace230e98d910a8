"""Infotaxis: move where the next observation is expected to shrink the source map's entropy most.

Vergassola, Villermaux and Shraiman, "'Infotaxis' as a strategy for searching without
gradients", Nature 445 (2007); none of the seed papers has it (seed pomdp-astar §I cites it as
[23]). For each admissible neighbouring cell c the vehicle could move to, the active mapper's own
detection model gives L_c = P(detection in c | source in each cell); with the current map pi,

    P(d | c) = sum_i pi_i L_c,i
    S(c) = P(d | c) H(pi L_c / P(d | c)) + (1 - P(d | c)) H(pi (1 - L_c) / (1 - P(d | c)))

is the expected entropy of the map after the observation in c, and the planner moves to the c
with the least S(c) (ties: the first in compass order). Vergassola et al. add a term for finding
the source on arrival; our vehicle has no such sensor, only the detector the model covers, so
the term is left out. Staying put is not a candidate: a stationary observer would wait for the
flow to bring information instead of searching for it.

Cost per decision: one ``detection_likelihood`` per neighbour (at most 8) and two entropies over
the map each; for 10,000 cells and the HMM mapper that is a few milliseconds.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

from service.core.errors import NoPathError
from service.core.mapping.belief import entropy_nats
from service.core.planning.base import Plan
from service.core.planning.moves import free_neighbours

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.mapping.belief import FloatArray
    from service.core.planning.base import BoolArray, PlanContext


def expected_entropy(prior: FloatArray, likelihood: FloatArray) -> float:
    """S(c) of the module doc: the entropy of the map after one detection-or-not observation
    whose detection probability given the source in each cell is ``likelihood``, averaged over
    the two outcomes with their predicted probabilities (nats)."""
    joint_hit = prior * likelihood
    p_hit = float(joint_hit.sum())
    p_miss = 1.0 - p_hit
    expected = 0.0
    for weight, joint in ((p_hit, joint_hit), (p_miss, prior - joint_hit)):
        if weight > 0.0:
            expected += weight * entropy_nats(np.maximum(joint, 0.0) / weight)
    return expected


class InfotaxisPlanner:
    """``infotaxis``: one step to the admissible neighbour with the least expected entropy."""

    name: ClassVar[str] = "infotaxis"
    steers_by_map: ClassVar[bool] = True

    def __init__(self, grid: Grid, config: PlanningConfig) -> None:
        self.grid = grid
        self.config = config
        self.blocked: BoolArray = grid.obstacle_mask

    def scores(self, ctx: PlanContext) -> dict[int, float]:
        """Expected entropy after moving to each admissible neighbour, in compass order."""
        prior = np.asarray(ctx.mapper.likelihood)
        return {
            cell: expected_entropy(prior, ctx.mapper.detection_likelihood(cell))
            for _, cell in free_neighbours(self.grid, ctx.cell, self.blocked)
        }

    def plan(self, ctx: PlanContext) -> Plan:
        scores = self.scores(ctx)
        if not scores:
            raise NoPathError(f"no admissible move from C{self.grid.paper_number(ctx.cell)}")
        best = min(scores, key=lambda c: scores[c])  # first minimum in compass order
        return Plan.along(self.grid, [ctx.cell, best])
