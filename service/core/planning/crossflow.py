"""Coordinates along and across the flow, used by the plume finder and the declaration's check.

``along`` grows in the direction the flow moves toward (downflow); ``cross`` grows to the left
of it. Turning patterns are laid out in these coordinates and clipped to the hull of the cell
centres, so every vertex lies strictly inside the search area.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from service.core.planning.base import Waypoint

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.planning.base import BoolArray

CALM_MPS = 1e-6
"""Below this flow speed there is no flow direction; ``FlowFrame.from_flow`` uses the fallback."""


@dataclass(frozen=True)
class FlowFrame:
    """Unit vector (ux, uy) pointing downflow; the cross axis is (-uy, ux)."""

    ux: float
    uy: float

    def __post_init__(self) -> None:
        if not math.isclose(math.hypot(self.ux, self.uy), 1.0, rel_tol=1e-9):
            raise ValueError(f"flow frame needs a unit vector, got ({self.ux}, {self.uy})")

    @classmethod
    def from_flow(cls, flow_x: float, flow_y: float, fallback: FlowFrame | None = None) -> FlowFrame:
        """The frame of a flow vector; ``fallback`` (default: flow toward East) in calm water."""
        speed = math.hypot(flow_x, flow_y)
        if not math.isfinite(speed) or speed < CALM_MPS:
            return fallback if fallback is not None else cls(1.0, 0.0)
        return cls(flow_x / speed, flow_y / speed)

    def along(self, x: float, y: float) -> float:
        return x * self.ux + y * self.uy

    def cross(self, x: float, y: float) -> float:
        return -x * self.uy + y * self.ux

    def point(self, along: float, cross: float) -> Waypoint:
        return Waypoint(along * self.ux - cross * self.uy, along * self.uy + cross * self.ux)

    def angle_to(self, other: FlowFrame) -> float:
        """Unsigned angle between two flow directions, radians."""
        dot = max(-1.0, min(1.0, self.ux * other.ux + self.uy * other.uy))
        return math.acos(dot)


def upflow_cells(grid: Grid, frame: FlowFrame, x: float, y: float, slack_m: float) -> BoolArray:
    """The cells whose centres lie at most ``slack_m`` downflow of (x, y) along the flow, shape (n, m)."""
    along = (grid.x_centres[np.newaxis, :] - x) * frame.ux + (grid.y_centres[:, np.newaxis] - y) * frame.uy
    out: BoolArray = along <= slack_m
    return out


def upflow_until(
    grid: Grid, x: float, y: float, frame: FlowFrame, from_m: float, done: Callable[[float, float], bool]
) -> tuple[float, float] | None:
    """The first point on the line upflow of (x, y), from ``from_m`` upflow on in steps of half the
    shorter cell side, where ``done`` holds; None once the line has left the area."""
    step_m = 0.5 * min(grid.cell_width_m, grid.cell_height_m)
    distance_m = from_m
    while True:
        px, py = x - distance_m * frame.ux, y - distance_m * frame.uy
        if not grid.contains(px, py):
            return None
        if done(px, py):
            return px, py
        distance_m += step_m


def centre_hull(grid: Grid) -> tuple[float, float, float, float]:
    """(x_lo, y_lo, x_hi, y_hi): the rectangle spanned by the cell centres."""
    return (
        float(grid.x_centres[0]),
        float(grid.y_centres[0]),
        float(grid.x_centres[-1]),
        float(grid.y_centres[-1]),
    )


def along_range(grid: Grid, frame: FlowFrame) -> tuple[float, float]:
    """Least and greatest along-flow coordinate over the centre hull."""
    x0, y0, x1, y1 = centre_hull(grid)
    values = [frame.along(x, y) for x in (x0, x1) for y in (y0, y1)]
    return min(values), max(values)


def cross_section(grid: Grid, frame: FlowFrame, along: float) -> tuple[float, float] | None:
    """The cross-flow interval [lo, hi] of the line at ``along`` inside the centre hull, or None."""
    x0, y0, x1, y1 = centre_hull(grid)
    lo, hi = -math.inf, math.inf
    # point(along, s) = (along ux - s uy, along uy + s ux); each axis bounds s
    for base, slope, low, high in (
        (along * frame.ux, -frame.uy, x0, x1),
        (along * frame.uy, frame.ux, y0, y1),
    ):
        if abs(slope) < 1e-12:
            if not low - 1e-9 <= base <= high + 1e-9:
                return None
            continue
        a, b = (low - base) / slope, (high - base) / slope
        lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
    if lo > hi + 1e-9:
        return None
    return lo, max(lo, hi)


def pass_across(grid: Grid, x: float, y: float, frame: FlowFrame, width_m: float) -> tuple[Waypoint, ...]:
    """The ends of a pass across the flow through (x, y), ``width_m`` to the left of the flow and
    then to the right, each clipped to the centre hull (an end clipped onto the other is dropped)."""
    if not (math.isfinite(width_m) and width_m > 0.0):
        raise ValueError(f"pass width must be positive, got {width_m}")
    lo, hi = along_range(grid, frame)
    a = min(max(frame.along(x, y), lo), hi)
    span = cross_section(grid, frame, a)
    if span is None:  # cannot happen for an along inside the range; kept for rounding
        return ()
    centre = frame.cross(x, y)
    ends: list[Waypoint] = []
    for side in (1.0, -1.0):
        point = frame.point(a, min(max(centre + side * width_m, span[0]), span[1]))
        if point not in ends:
            ends.append(point)
    return tuple(ends)
