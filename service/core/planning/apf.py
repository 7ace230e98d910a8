"""Artificial potential field over the source likelihood map (seed reactive-planning §II-C, eq. 6-7).

A w x w "active window" of cells moves with the vehicle, centred on it. Each active cell C_i
pulls the vehicle with a force proportional to its likelihood value LV_i (we use pi) and
inversely proportional to its distance d (eq. 6); the resultant of all of them (eq. 7) gives the
heading and, relative to the sum of the magnitudes, the speed: all forces aligned is full speed,
forces that cancel is standing still. The centred window has the columns (rows) whose centres
lie within w/2 cells of the vehicle on either side, so it holds exactly w of each inside the area.

Obstacle cells do not attract (the vehicle cannot go there). They repel, as in Khatib's
potential fields the paper cites: an obstacle cell at centre distance d < rho pushes the vehicle
away with gain * A * (rho / d - 1), where A is the sum of the attraction magnitudes, so the gain
is relative to the map's pull whatever the scale of pi.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from service.core.errors import NoPathError
from service.core.planning.base import Plan, Waypoint
from service.core.planning.moves import free_neighbours
from service.core.planning.safety import is_safe_point, segment_clear

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.mapping.belief import FloatArray
    from service.core.planning.base import BoolArray, PlanContext


@dataclass(frozen=True)
class Force:
    """The resultant (fx, fy) and the sum of the magnitudes of the forces that made it."""

    fx: float
    fy: float
    total: float

    @property
    def magnitude(self) -> float:
        return math.hypot(self.fx, self.fy)

    @property
    def heading_rad(self) -> float:
        """Direction of the resultant, counter-clockwise from East."""
        return math.atan2(self.fy, self.fx)

    @property
    def speed_fraction(self) -> float:
        """|F| / sum |F_i| in [0, 1]: the share of full speed the resultant asks for."""
        return min(self.magnitude / self.total, 1.0) if self.total > 0.0 else 0.0


def active_window(grid: Grid, x: float, y: float, w: int) -> tuple[slice, slice]:
    """(rows, cols) of the w x w window centred on (x, y), clipped to the area."""
    half_x, half_y = w * grid.cell_width_m / 2.0, w * grid.cell_height_m / 2.0
    cols = np.flatnonzero((grid.x_centres >= x - half_x) & (grid.x_centres < x + half_x))
    rows = np.flatnonzero((grid.y_centres >= y - half_y) & (grid.y_centres < y + half_y))
    if cols.size == 0 or rows.size == 0:
        return slice(0, 0), slice(0, 0)
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)


def apf_force(
    grid: Grid,
    likelihood: FloatArray,
    x: float,
    y: float,
    window: int,
    *,
    blocked: BoolArray | None = None,
    obstacle_gain: float = 0.0,
    obstacle_range_m: float = 1.0,
) -> Force:
    """Eq. 6-7 at the vehicle position (x, y), plus obstacle repulsion (module doc)."""
    mask = grid.obstacle_mask if blocked is None else blocked
    rows, cols = active_window(grid, x, y, window)
    dx = grid.x_centres[cols][None, :] - x  # X_i - X_v
    dy = grid.y_centres[rows][:, None] - y
    dx, dy = np.broadcast_arrays(dx, dy)
    d = np.hypot(dx, dy)
    lv = np.where(mask[rows, cols] | (d == 0.0), 0.0, likelihood[rows, cols])
    safe_d = np.where(d > 0.0, d, 1.0)
    # Eq. 6 as printed, (X_v - X_i) / d, points from the cell to the vehicle, which would push
    # the vehicle away; the text says the force is attractive, so we use (X_i - X_v) / d.
    scale = lv / safe_d**2
    fx, fy = float((scale * dx).sum()), float((scale * dy).sum())
    attraction = float((lv / safe_d).sum())
    total = attraction
    if obstacle_gain > 0.0 and attraction > 0.0 and mask.any():
        orow, ocol = np.nonzero(mask)
        ox = x - grid.x_centres[ocol]  # X_v - X_o: away from the obstacle
        oy = y - grid.y_centres[orow]
        od = np.hypot(ox, oy)
        near = (od < obstacle_range_m) & (od > 0.0)
        push = obstacle_gain * attraction * (obstacle_range_m / od[near] - 1.0)
        fx += float((push * ox[near] / od[near]).sum())
        fy += float((push * oy[near] / od[near]).sum())
        total += float(push.sum())
    return Force(fx, fy, total)


class ApfPlanner:
    """``apf``: one waypoint ``apf_step_m * |F| / sum |F_i|`` ahead along the resultant; if that
    point or the leg to it is not safe, the admissible neighbour cell best aligned with F."""

    name: ClassVar[str] = "apf"

    def __init__(self, grid: Grid, config: PlanningConfig) -> None:
        self.grid = grid
        self.config = config
        self.blocked: BoolArray = grid.obstacle_mask

    def plan(self, ctx: PlanContext) -> Plan:
        v = ctx.vehicle
        force = apf_force(
            self.grid,
            np.asarray(ctx.mapper.likelihood),
            v.x,
            v.y,
            self.config.apf_window,
            blocked=self.blocked,
            obstacle_gain=self.config.apf_obstacle_gain,
            obstacle_range_m=self.config.apf_obstacle_range_m,
        )
        if force.magnitude == 0.0:  # balanced (or empty) field: stand still
            return Plan((Waypoint(v.x, v.y),), (ctx.cell,))
        reach = self.config.apf_step_m * force.speed_fraction
        ux, uy = force.fx / force.magnitude, force.fy / force.magnitude
        tx, ty = v.x + reach * ux, v.y + reach * uy
        if is_safe_point(self.grid, tx, ty) and segment_clear(self.grid, (v.x, v.y), (tx, ty)):
            return Plan((Waypoint(tx, ty),), (self.grid.cell_of(tx, ty),))
        options = free_neighbours(self.grid, ctx.cell, self.blocked)
        if not options:
            raise NoPathError(f"no admissible move from C{self.grid.paper_number(ctx.cell)}")

        def alignment(option: tuple[int, int]) -> float:
            cx, cy = self.grid.centre(option[1])
            return -((cx - v.x) * ux + (cy - v.y) * uy) / max(math.hypot(cx - v.x, cy - v.y), 1e-12)

        _, best = min(options, key=alignment)
        return Plan.along(self.grid, [ctx.cell, best])
