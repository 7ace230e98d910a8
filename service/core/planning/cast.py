"""After losing the plume: a cast across the flow around the last detection.

Seed pomdp-astar §I on the moth-inspired planner of [13]: when the vehicle leaves the plume it
"performed the casting behavior", traversing the flow. Our cast is centred on the place of the
last detection: legs across the flow to alternate sides, the reach growing by ``width_m`` every
second leg (+w, -w, +2w, -2w, ...), so that a plume that meandered sideways is met again. After
``legs`` turning points the mission falls back to the planner.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from service.core.planning.crossflow import FlowFrame, along_range, cross_section

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.planning.base import Waypoint


def cast_vertices(
    grid: Grid, x: float, y: float, frame: FlowFrame, width_m: float, legs: int
) -> tuple[Waypoint, ...]:
    """Turning points of a cast across the flow through (x, y), clipped to the centre hull; once
    one side is clipped at the edge of the area, the cast keeps widening on the other side only."""
    if not (math.isfinite(width_m) and width_m > 0.0):
        raise ValueError(f"cast width must be positive, got {width_m}")
    if legs < 0:
        raise ValueError(f"cast legs must be >= 0, got {legs}")
    lo, hi = along_range(grid, frame)
    a = min(max(frame.along(x, y), lo), hi)
    span = cross_section(grid, frame, a)
    if span is None:  # cannot happen for an along inside the range; kept for rounding
        return ()
    centre = frame.cross(x, y)
    vertices: list[Waypoint] = []
    for k in range(legs):
        reach = (k // 2 + 1) * width_m * (1 if k % 2 == 0 else -1)
        s = min(max(centre + reach, span[0]), span[1])
        point = frame.point(a, s)
        if point not in vertices:  # a side already cast to its edge is not cast to again
            vertices.append(point)
    return tuple(vertices)
