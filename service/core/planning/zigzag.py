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


def young_plume_lead(
    grid: Grid, x: float, y: float, frame: FlowFrame, flow_mps: float, age_s: float
) -> float:
    """How far a sweep from (x, y) should run upflow before its first leg, for a plume whose
    release began ``age_s`` before a first leg begun at (x, y) would meet it (0 for ``age_s`` 0).

    Such a plume reaches at most ``flow_mps`` times its age downflow of its source, so a leg
    crossing the flow at along-position a meets only the sources from a to that far upflow of a.
    Running L m upflow first (with the vehicle about as fast as the flow) makes the plume L s older
    where the leg meets it, so the leg covers the sources from L to 2 L + ``flow_mps`` ``age_s``
    upflow of the start: L = (d - ``flow_mps`` ``age_s``) / 2, for a start d m downflow of the upflow
    edge, makes that reach the edge. A start nearer the edge needs no lead.
    """
    if age_s <= 0.0 or not math.isfinite(flow_mps):
        return 0.0
    lo, _ = along_range(grid, frame)
    return max(0.0, (frame.along(x, y) - lo - max(flow_mps, 0.0) * age_s) / 2.0)


def zigzag_vertices(
    grid: Grid,
    x: float,
    y: float,
    frame: FlowFrame,
    spacing_m: float,
    *,
    upflow: bool = True,
    diagonal_start: bool = False,
    lead_m: float = 0.0,
) -> tuple[Waypoint, ...]:
    """Turning points of a zigzag from (x, y) to the upflow (or downflow) edge of the area.

    Vertex k lies on the cross-flow line ``spacing_m * k`` from the start (the last one on the
    edge of the area), at the far side of the area from vertex k - 1, the first at the side
    farther from the vehicle. When the flow is oblique to the area the cross-section changes
    along the flow, so vertex k is the point of the hull between lines k - 1 and k + 1 that lies
    farthest to its side: each leg then spans the whole cross-section of the band between its
    lines, and every cell is crossed within two spacings along the flow (one when the flow is
    parallel to an edge of the area). All vertices are inside the hull of the cell centres.

    With ``diagonal_start`` the first vertex is on line 1, at the far side: the first leg already
    advances along the flow instead of crossing at the start's own line. A plume is detectable
    only so far downflow of its source, so a start far downflow gains a spacing of advance per
    leg from the first one on.

    With ``lead_m`` (upflow only) the pattern first runs straight upflow that far, stopping at the
    edge, and the zigzag starts from there (``young_plume_lead``).
    """
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise ValueError(f"zigzag spacing must be positive, got {spacing_m}")
    if not (math.isfinite(lead_m) and lead_m >= 0.0):
        raise ValueError(f"zigzag lead must be non-negative, got {lead_m}")
    lo, hi = along_range(grid, frame)
    a = min(max(frame.along(x, y), lo), hi)
    lead: tuple[Waypoint, ...] = ()
    if upflow and lead_m > 0.0 and a > lo:
        a = max(a - lead_m, lo)
        span = cross_section(grid, frame, a)
        if span is not None:
            start = frame.point(a, min(max(frame.cross(x, y), span[0]), span[1]))
            lead, x, y = (start,), start.x, start.y
    end = lo if upflow else hi
    lines = [a]
    while lines[-1] != end:
        lines.append(max(lines[-1] - spacing_m, end) if upflow else min(lines[-1] + spacing_m, end))
    first = cross_section(grid, frame, a)
    if first is None:  # cannot happen for an along inside the range; kept for rounding
        return ()
    s = frame.cross(x, y)
    side = 1.0 if first[1] - s >= s - first[0] else -1.0
    skip = diagonal_start and len(lines) > 1
    if skip:
        side = -side
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
    return lead + tuple(vertices[1:] if skip else vertices)
