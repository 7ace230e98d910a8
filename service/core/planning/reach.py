"""Which cells the vehicle can reach, and the reachable stand-in for a goal it cannot.

With the moves of ``moves.py`` (8 compass moves, no corner cutting) two free cells are connected
exactly when they are 4-connected: a diagonal move is only admissible when both cells beside it
are free, and then the two orthogonal moves through one of them connect the same cells. So the
components are the 4-connected labels of the free cells, computed once per grid. A vehicle in a
blocked cell reaches the components of its free 4-neighbours (its admissible diagonal moves
need those free too).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.planning.base import BoolArray


class Reachability:
    """Connected components of the free cells of one grid."""

    def __init__(self, grid: Grid, blocked: BoolArray | None = None) -> None:
        self.grid = grid
        self.blocked: BoolArray = grid.obstacle_mask if blocked is None else blocked
        labels, _ = ndimage.label(~self.blocked)  # default structure: 4-connectivity
        self.labels = np.asarray(labels, dtype=np.intp)

    def reachable(self, start: int) -> BoolArray:
        """(n, m) mask of the free cells reachable from ``start`` (``start`` may be blocked)."""
        row, col = self.grid.row_col(start)
        if not self.blocked[row, col]:
            components = {int(self.labels[row, col])}
        else:
            around = [(row + dr, col + dc) for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))]
            components = {
                int(self.labels[r, c])
                for r, c in around
                if 0 <= r < self.grid.rows and 0 <= c < self.grid.columns and not self.blocked[r, c]
            }
        mask: BoolArray = np.isin(self.labels, list(components)) & ~self.blocked
        return mask

    def goal_for(self, start: int, goal: int) -> int:
        """``goal`` if it is reachable from ``start``; else the reachable free cell whose centre is
        nearest the goal's (ties: lowest index); ``start`` when nothing is reachable."""
        mask = self.reachable(start)
        if mask.flat[goal]:
            return goal
        cells = np.flatnonzero(mask)
        if cells.size == 0:
            return start
        gx, gy = self.grid.centre(goal)
        rows, cols = np.divmod(cells, self.grid.columns)
        d2 = (self.grid.x_centres[cols] - gx) ** 2 + (self.grid.y_centres[rows] - gy) ** 2
        return int(cells[np.argmin(d2)])  # argmin takes the first, i.e. the lowest index
