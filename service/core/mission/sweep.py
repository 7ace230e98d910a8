"""``FIND``: the zigzag sweep across the flow (``planning.zigzag``) that looks for the plume.

It sweeps back the other way when it reaches the edge of the area, and is laid out anew when the
mean flow over the mapper's history turns by more than ``SWEEP_REDRAW_RAD``. It goes upflow
first, or downflow from a start less than ``zigzag_near_edge_spacings`` spacings from the upflow
edge. A contact pauses it: the pattern is kept, so that the mission can sweep on from where it
stopped (``planning.lone_contact_hits``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from service.core.mission.pattern import Pattern
from service.core.planning.crossflow import FlowFrame
from service.core.planning.zigzag import sweeps_upflow_first, zigzag_vertices

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.mission.routing import Routing
    from service.core.planning.base import PlanContext, Waypoint

SWEEP_REDRAW_RAD = math.pi / 4.0
"""A zigzag is laid out anew when the flow has turned more than this since it was laid out."""


@dataclass
class Sweep:
    """The sweep's zigzag (``pattern``), the flow it was laid along (``frame``; None: lay a new
    one from where the vehicle is) and its direction along the flow (``upflow``)."""

    grid: Grid
    planning: PlanningConfig
    pattern: Pattern = field(default_factory=Pattern)
    frame: FlowFrame | None = None
    upflow: bool = True

    def waypoints(self, ctx: PlanContext, flow: FlowFrame | None, routing: Routing) -> tuple[Waypoint, ...]:
        """The legs to fly under the mean flow ``flow`` (None: none known yet, toward East)."""
        frame = flow or FlowFrame(1.0, 0.0)
        p = self.planning
        if self.frame is None and p.zigzag_near_edge_spacings > 0.0:
            near_m = p.zigzag_near_edge_spacings * p.zigzag_spacing_m
            self.upflow = sweeps_upflow_first(self.grid, ctx.vehicle.x, ctx.vehicle.y, frame, near_m)
        if self.frame is None or frame.angle_to(self.frame) > SWEEP_REDRAW_RAD:
            self._lay(ctx, frame)
        wanted = self.pattern.follow(ctx, routing)
        if wanted is None:  # reached the edge of the area: sweep back the other way
            self.upflow = not self.upflow
            self._lay(ctx, frame)
            wanted = self.pattern.follow(ctx, routing)
        return wanted or ()

    def restart(self) -> None:
        """Lay a new sweep from where the vehicle is at the next tick."""
        self.frame = None

    def _lay(self, ctx: PlanContext, frame: FlowFrame) -> None:
        v = ctx.vehicle
        self.frame = frame
        spacing = self.planning.zigzag_spacing_m
        self.pattern = Pattern(zigzag_vertices(self.grid, v.x, v.y, frame, spacing, upflow=self.upflow))
