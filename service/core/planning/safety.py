"""The safety rule every commanded waypoint passes, and the fallbacks when a plan fails it.

DESIGN.md: the service "never commands a point outside the search area or inside an obstacle".
``guard`` is the one place that enforces it: a waypoint is kept only if it lies in the search
area, outside every obstacle cell (``Grid.obstacle_mask``) and outside every obstacle rectangle,
and if the straight leg to it from the previous waypoint (from the vehicle, for the first one,
unless the vehicle is inside an obstacle rectangle) crosses no obstacle rectangle. A plan is cut at
its first waypoint that fails. ``safe_plan`` adds the fallbacks for an empty result, each of
which goes through ``guard`` again.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from service.core.planning.base import Waypoint

if TYPE_CHECKING:
    from collections.abc import Sequence

    from service.core.grid import Grid, Rectangle
    from service.core.planning.base import VehicleState


def is_safe_point(grid: Grid, x: float, y: float) -> bool:
    """Inside the search area, outside every obstacle cell and every obstacle rectangle. A point
    on the boundary between two cells belongs to both: neither may be an obstacle cell."""
    if not (math.isfinite(x) and math.isfinite(y) and grid.contains(x, y)):
        return False
    u = (x - grid.x_min) / grid.cell_width_m
    v = (y - grid.y_min) / grid.cell_height_m
    cols = {min(int(u), grid.columns - 1)} | ({int(u) - 1} if u == int(u) and u > 0 else set())
    rows = {min(int(v), grid.rows - 1)} | ({int(v) - 1} if v == int(v) and v > 0 else set())
    if grid.obstacle_mask.flat[grid.cell_of(x, y)] or any(
        grid.obstacle_mask[r, c] for r in rows for c in cols
    ):
        return False
    return not grid.in_obstacle(x, y)


def _segment_hits(p: tuple[float, float], q: tuple[float, float], box: Rectangle) -> bool:
    """Does the closed segment p-q meet the closed rectangle? (Liang-Barsky clipping.)"""
    x0, y0, x1, y1 = box
    t_in, t_out = 0.0, 1.0
    for start, delta, low, high in ((p[0], q[0] - p[0], x0, x1), (p[1], q[1] - p[1], y0, y1)):
        if delta == 0.0:
            if not low <= start <= high:
                return False
            continue
        ta, tb = (low - start) / delta, (high - start) / delta
        t_in, t_out = max(t_in, min(ta, tb)), min(t_out, max(ta, tb))
        if t_in > t_out:
            return False
    return True


def segment_clear(grid: Grid, p: tuple[float, float], q: tuple[float, float]) -> bool:
    """True when the straight leg p-q touches no obstacle rectangle."""
    return not any(_segment_hits(p, q, box) for box in grid.obstacles)


def guard(grid: Grid, vehicle: VehicleState | None, waypoints: Sequence[Waypoint]) -> tuple[Waypoint, ...]:
    """The longest safe prefix of ``waypoints`` (see the module doc)."""
    previous: tuple[float, float] | None = None
    if vehicle is not None and not grid.in_obstacle(vehicle.x, vehicle.y):
        previous = (vehicle.x, vehicle.y)
    kept: list[Waypoint] = []
    for wp in waypoints:
        if not is_safe_point(grid, wp.x, wp.y):
            break
        if previous is not None and not segment_clear(grid, previous, (wp.x, wp.y)):
            break
        kept.append(wp)
        previous = (wp.x, wp.y)
    return tuple(kept)


def safe_plan(
    grid: Grid,
    vehicle: VehicleState,
    waypoints: Sequence[Waypoint],
    *,
    hold_at: Waypoint | None = None,
) -> tuple[Waypoint, ...]:
    """``guard(waypoints)`` if anything survives; else the first safe one of: holding at
    ``hold_at`` (default: the vehicle's position); the nearest free cell centre one clear leg
    away (the vehicle stands in an obstacle cell or outside the area). A vehicle inside an
    obstacle rectangle has no clear leg at all: it gets the nearest free cell centre, to get out.
    Empty when none of these exists (no free cell, or a vehicle shut in by obstacle cells with no
    straight way out): then nothing may be commanded."""
    kept = guard(grid, vehicle, waypoints)
    if kept:
        return kept
    hold = hold_at if hold_at is not None else Waypoint(vehicle.x, vehicle.y)
    kept = guard(grid, vehicle, [hold])
    if kept:
        return kept
    # inside a rectangle ``guard`` checks no leg from the vehicle, so this is the nearest centre
    for cell in _free_cells_by_distance(grid, vehicle.x, vehicle.y):
        kept = guard(grid, vehicle, [Waypoint(*grid.centre(cell))])
        if kept:
            return kept
    return ()


def clamped_cell(grid: Grid, x: float, y: float) -> int:
    """The cell holding (x, y), or the nearest edge cell when (x, y) is outside the area."""
    return grid.row_of(y) * grid.columns + grid.column_of(x)


def _free_cells_by_distance(grid: Grid, x: float, y: float) -> list[int]:
    """Free cells, the one whose centre is nearest (x, y) first (ties: lower index)."""
    cells = np.flatnonzero(~grid.obstacle_mask)
    rows, cols = np.divmod(cells, grid.columns)
    d2 = (grid.x_centres[cols] - x) ** 2 + (grid.y_centres[rows] - y) ** 2
    order = np.lexsort((cells, d2))
    return [int(c) for c in cells[order]]
