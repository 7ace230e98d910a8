"""Plume finding before the first detection: a zigzag sweep across the flow.

Seed pomdp-astar §II-A: "We adopted a 'zigzag' method proposed in [13] as the initial search
strategy" (Li, Farrell, Pang and Arrieta 2006). The vehicle crosses the flow from one side of
the search area to the other, advancing ``spacing_m`` along the flow with every crossing, so
that its track crosses every cross-flow position of the swept band at least once per
``spacing_m`` of along-flow distance: a plume narrower than the area but longer than
``spacing_m`` cannot slip between two legs. The sweep advances upflow by default (a plume lies
downflow of its source, so moving upflow keeps the source ahead; ``sweeps_upflow_first`` makes
the exception for a start near the upflow edge); when it reaches the edge of the area the
mission sweeps back the other way.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from service.core.planning.base import Waypoint
from service.core.planning.crossflow import FlowFrame, along_range, centre_hull, cross_section

if TYPE_CHECKING:
    from service.core.grid import Grid


def sweeps_upflow_first(grid: Grid, x: float, y: float, frame: FlowFrame, near_m: float) -> bool:
    """Whether a sweep from (x, y) should go upflow first: not when the start is less than
    ``near_m`` from the upflow edge of the area (the mission passes a multiple of the spacing).

    From a start within a spacing of the edge the upflow sweep is a single leg to the edge, and
    nearly all of the area where the source could be, the whole area between the start and the
    downflow edge, lies behind the vehicle; it would be swept only after the vehicle has turned
    at the edge, while the downflow sweep reaches it from its first leg on. Within one and a
    half spacings it is not much better: its last leg runs less than half a spacing from the
    edge, so the sweep crosses the band beside the edge again and again before it turns.
    """
    lo, _ = along_range(grid, frame)
    return frame.along(x, y) - lo >= near_m


def zigzag_vertices(
    grid: Grid,
    x: float,
    y: float,
    frame: FlowFrame,
    spacing_m: float,
    *,
    upflow: bool = True,
) -> tuple[Waypoint, ...]:
    """Turning points of a zigzag from (x, y) to the upflow (or downflow) edge of the area.

    Vertex k lies on the cross-flow line ``spacing_m * k`` from the start (the last one on the
    edge of the area), at the far side of the area from vertex k - 1, the first at the side
    farther from the vehicle. When the flow is oblique to the area the cross-section changes
    along the flow, so vertex k is the point of the hull between lines k - 1 and k + 1 that lies
    farthest to its side: each leg then spans the whole cross-section of the band between its
    lines, and every cell is crossed within two spacings along the flow (one when the flow is
    parallel to an edge of the area). All vertices are inside the hull of the cell centres.
    """
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise ValueError(f"zigzag spacing must be positive, got {spacing_m}")
    lo, hi = along_range(grid, frame)
    a = min(max(frame.along(x, y), lo), hi)
    end = lo if upflow else hi
    lines = [a]
    while lines[-1] != end:
        lines.append(max(lines[-1] - spacing_m, end) if upflow else min(lines[-1] + spacing_m, end))
    first = cross_section(grid, frame, a)
    if first is None:  # cannot happen for an along inside the range; kept for rounding
        return ()
    s = frame.cross(x, y)
    side = 1.0 if first[1] - s >= s - first[0] else -1.0
    x0, y0, x1, y1 = centre_hull(grid)
    corners = [(cx, cy) for cx in (x0, x1) for cy in (y0, y1)]
    vertices: list[Waypoint] = []
    for k, line in enumerate(lines):
        # the side's extreme over the lines k-1 .. k+1: the cross-section's bound is piecewise
        # linear in along (concave on one side, convex on the other), so it is attained at one
        # of those lines or at a corner of the hull between them; line k wins ties
        neighbours = [line, *lines[max(k - 1, 0) : k], *lines[k + 1 : k + 2]]
        candidates: list[Waypoint] = []
        for a_line in neighbours:
            span = cross_section(grid, frame, a_line)
            if span is not None:
                candidates.append(frame.point(a_line, span[1] if side > 0 else span[0]))
        low, high = min(neighbours), max(neighbours)
        candidates += [Waypoint(cx, cy) for cx, cy in corners if low <= frame.along(cx, cy) <= high]
        if candidates:
            best = candidates[0]
            for c in candidates[1:]:
                if side * frame.cross(c.x, c.y) > side * frame.cross(best.x, best.y) + 1e-9:
                    best = c
            vertices.append(best)
        side = -side
    return tuple(vertices)
