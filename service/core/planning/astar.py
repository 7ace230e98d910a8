"""A* path planning to the estimated source (seed pomdp-astar §II-D, eq. 7-9).

A* (Hart, Nilsson and Raphael 1968) expands nodes in order of f(n) = g(n) + h(n) (eq. 7). Two
variants, both registered as planners:

``astar`` (the default) never enters an obstacle: the 8 compass moves of ``moves.py`` without
corner cutting, each costing the distance between cell centres in metres, and the octile
distance as heuristic. The octile distance is the exact cost in the obstacle-free grid, so it
is consistent and the path returned is a shortest admissible one. Where no obstacle lies between
the vehicle and the estimate's centre the planner flies that straight leg instead: it is the
shortest way in the plane, and the grid's shortest paths are staircases that may put all their
diagonal moves first (a diagonal runs 39 degrees off the x axis on the default area's 1.25 x 1 m
model cells), so that a vehicle re-planning toward an estimate upflow first drifts across the
flow, out of the plume (docs/search-steps.md, steps 21 and 24).

``astar-paper`` is the paper's own: a node is a cell entered with a heading, and from it only
the five moves relative to that heading (left, left-forward, forward, right-forward, right) are
allowed. Eq. 8 as printed gives free cells cost 0 and obstacle cells 1000, which would make
every free path equally short; we read it as a penalty on top of the move's length (in cells):
entering an obstacle cell, or cutting the corner of one diagonally, costs 1000 more. The
heuristic is the Manhattan distance in cells (eq. 9). With diagonal moves the Manhattan distance
overestimates by up to sqrt(2), so this variant may return a path up to sqrt(2) times longer
than the shortest five-move path, and a path through an obstacle cell if no other exists.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from service.core.errors import NoPathError
from service.core.planning.base import Plan, Waypoint
from service.core.planning.follow import PathFollower
from service.core.planning.moves import (
    COMPASS,
    admissible,
    heading_sector,
    move_length_m,
    sector_between,
    step,
)
from service.core.planning.safety import segment_clear

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.planning.base import BoolArray, PlanContext

OBSTACLE_COST = 1000.0
"""Eq. 8: the extra cost of entering an obstacle cell (astar-paper)."""


@dataclass(frozen=True)
class RelativeMove:
    """A move relative to the heading: ``turn`` compass sectors (45 degrees) counter-clockwise."""

    name: str
    turn: int


FIVE_MOVES: tuple[RelativeMove, ...] = (
    RelativeMove("left", 2),
    RelativeMove("left-forward", 1),
    RelativeMove("forward", 0),
    RelativeMove("right-forward", -1),
    RelativeMove("right", -2),
)
"""Seed pomdp-astar §II-D: the five directions the planner considers."""


def _search(
    starts: Iterable[int],
    successors: Callable[[int], Iterable[tuple[int, float]]],
    heuristic: Callable[[int], float],
    is_goal: Callable[[int], bool],
) -> list[int] | None:
    """Generic A* over integer states; the state path from a start to the first goal popped."""
    tie = itertools.count()
    g: dict[int, float] = {}
    parent: dict[int, int] = {}
    frontier: list[tuple[float, float, int, int]] = []
    for s in starts:
        g[s] = 0.0
        frontier.append((heuristic(s), heuristic(s), next(tie), s))
    heapq.heapify(frontier)
    closed: set[int] = set()
    while frontier:
        _, _, _, state = heapq.heappop(frontier)
        if state in closed:
            continue
        if is_goal(state):
            path = [state]
            while path[-1] in parent:
                path.append(parent[path[-1]])
            return path[::-1]
        closed.add(state)
        for nxt, cost in successors(state):
            if nxt in closed:
                continue
            candidate = g[state] + cost
            if candidate < g.get(nxt, math.inf):
                g[nxt] = candidate
                parent[nxt] = state
                h = heuristic(nxt)
                # ties in f go to the node nearer the goal
                heapq.heappush(frontier, (candidate + h, h, next(tie), nxt))
    return None


def octile_m(grid: Grid, a: int, b: int) -> float:
    """Length of the shortest 8-connected path between two cells of an obstacle-free grid."""
    ra, ca = divmod(a, grid.columns)
    rb, cb = divmod(b, grid.columns)
    d_col, d_row = abs(ca - cb), abs(ra - rb)
    diagonal = min(d_col, d_row)
    return (
        diagonal * math.hypot(grid.cell_width_m, grid.cell_height_m)
        + (d_col - diagonal) * grid.cell_width_m
        + (d_row - diagonal) * grid.cell_height_m
    )


def astar(grid: Grid, start: int, goal: int, blocked: BoolArray | None = None) -> list[int]:
    """Shortest 8-connected path of flat cells from ``start`` to ``goal`` that never enters a
    ``blocked`` cell (default: the grid's obstacle cells); ``start`` itself may be blocked."""
    mask = grid.obstacle_mask if blocked is None else blocked
    for name, cell in (("start", start), ("goal", goal)):
        if not 0 <= cell < grid.size:
            raise NoPathError(f"{name} cell {cell} is outside the grid")
    if mask.flat[goal] and goal != start:
        raise NoPathError(f"goal C{grid.paper_number(goal)} is an obstacle cell")
    lengths = [move_length_m(grid, s) for s in range(len(COMPASS))]

    def successors(cell: int) -> Iterable[tuple[int, float]]:
        for sector, length in enumerate(lengths):
            target = admissible(grid, cell, sector, mask)
            if target is not None:
                yield target, length

    path = _search([start], successors, lambda c: octile_m(grid, c, goal), lambda c: c == goal)
    if path is None:
        raise NoPathError(f"no path from C{grid.paper_number(start)} to C{grid.paper_number(goal)}")
    return path


def manhattan_cells(grid: Grid, a: int, b: int) -> float:
    """Eq. 9: |n_x - G_x| + |n_y - G_y| in cells."""
    ra, ca = divmod(a, grid.columns)
    rb, cb = divmod(b, grid.columns)
    return float(abs(ca - cb) + abs(ra - rb))


def astar_paper(
    grid: Grid, start: int, heading: int, goal: int, obstacles: BoolArray | None = None
) -> list[int]:
    """The paper's A*: five moves relative to the heading (compass sector ``heading`` on arrival
    in ``start``), +1000 for entering an obstacle cell, Manhattan heuristic; a cell path."""
    mask = grid.obstacle_mask if obstacles is None else obstacles
    n_dirs = len(COMPASS)
    for name, cell in (("start", start), ("goal", goal)):
        if not 0 <= cell < grid.size:
            raise NoPathError(f"{name} cell {cell} is outside the grid")

    def penalty(cell: int, sector: int, target: int) -> float:
        d_row, d_col = COMPASS[sector]
        row, col = divmod(cell, grid.columns)
        touched = [target]
        if d_row and d_col:  # a diagonal move sweeps the corner of the two cells beside it
            touched += [(row + d_row) * grid.columns + col, row * grid.columns + col + d_col]
        return OBSTACLE_COST if any(mask.flat[t] for t in touched) else 0.0

    def successors(state: int) -> Iterable[tuple[int, float]]:
        cell, facing = divmod(state, n_dirs)
        for move in FIVE_MOVES:
            sector = (facing + move.turn) % n_dirs
            target = step(grid, cell, sector)
            if target is not None:
                length = math.sqrt(2.0) if sector % 2 else 1.0
                yield target * n_dirs + sector, length + penalty(cell, sector, target)

    path = _search(
        [start * n_dirs + heading % n_dirs],
        successors,
        lambda s: manhattan_cells(grid, s // n_dirs, goal),
        lambda s: s // n_dirs == goal,
    )
    if path is None:
        raise NoPathError(f"no five-move path from C{grid.paper_number(start)} to C{grid.paper_number(goal)}")
    return [s // n_dirs for s in path]


class AStarPlanner(PathFollower):
    """``astar``: the straight leg to the estimate's centre when it is clear of obstacles, else the
    obstacle-free 8-connected A* to it, re-planned when the estimate changes."""

    name: ClassVar[str] = "astar"

    def plan(self, ctx: PlanContext) -> Plan:
        if ctx.goal != ctx.cell and not self.blocked.flat[ctx.goal]:
            x, y = self.grid.centre(ctx.goal)
            if segment_clear(self.grid, (ctx.vehicle.x, ctx.vehicle.y), (x, y)):
                self.forget()
                return Plan((Waypoint(x, y),), (ctx.goal,))
        return super().plan(ctx)

    def compute(self, ctx: PlanContext) -> list[int]:
        return astar(self.grid, ctx.cell, ctx.goal, self.blocked)


class PaperAStarPlanner(PathFollower):
    """``astar-paper``: seed pomdp-astar §II-D as printed (five moves, cost 1000, Manhattan)."""

    name: ClassVar[str] = "astar-paper"

    def compute(self, ctx: PlanContext) -> list[int]:
        sector = heading_sector(ctx.vehicle.heading_rad)
        path = astar_paper(self.grid, ctx.cell, sector, ctx.goal, self.blocked)
        # the vehicle must never be sent into an obstacle: a path that pays eq. 8's penalty is no
        # path for the mission (which then falls back), though the search itself allows it
        if any(self.blocked.flat[c] for c in path[1:]) or any(
            admissible(self.grid, a, sector_between(self.grid, a, b), self.blocked) is None
            for a, b in itertools.pairwise(path)
        ):
            raise NoPathError(
                f"the five-move path to C{self.grid.paper_number(ctx.goal)} crosses an obstacle cell"
            )
        return path
