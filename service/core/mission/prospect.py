"""``FIND``: straight legs chosen by the map, each the one most likely to meet odour for the
distance it costs (``planning.prospect``, eq. P1-P2).

A leg is flown to its end and the next one chosen from there; it is chosen anew at once when the
mean flow has turned by more than ``REDRAW_RAD`` since, or when the mission comes back to
``FIND`` (``restart``). The distance the vehicle covers in a tick, which sets how often the leg
is looked at, is measured from its own track."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from service.core.mission.pattern import Pattern
from service.core.planning.prospect import best_leg, candidate_ends

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.mission.routing import Routing
    from service.core.planning.base import PlanContext, Waypoint
    from service.core.planning.crossflow import FlowFrame

REDRAW_RAD = math.pi / 4.0
"""A leg is chosen anew when the mean flow has turned more than this since it was chosen."""
DEFAULT_STEP_M = 1.0
"""Distance per tick assumed until the vehicle has moved."""
MOVING_M = 0.1
"""A tick's move shorter than this is not counted in the distance per tick (the vehicle held)."""


@dataclass
class Prospect:
    """The leg being flown (``pattern``) and the flow it was chosen under (``frame``; None:
    choose one at the next tick)."""

    grid: Grid
    pattern: Pattern = field(default_factory=Pattern)
    frame: FlowFrame | None = None
    _last: tuple[float, float] | None = None
    _moves: deque[float] = field(default_factory=lambda: deque(maxlen=10))
    _ends: list[Waypoint] | None = None

    def waypoints(self, ctx: PlanContext, flow: FlowFrame | None, routing: Routing) -> tuple[Waypoint, ...]:
        """The leg to fly; () while the mapper has no flow history yet (hold)."""
        self.observe(ctx.vehicle.x, ctx.vehicle.y)
        if flow is None or not ctx.mapper.history:
            return ()
        if self.frame is None or flow.angle_to(self.frame) > REDRAW_RAD:
            self._choose(ctx, flow)
        wanted = self.pattern.follow(ctx, routing)
        if wanted is None:  # the leg is flown: the next one from here
            self._choose(ctx, flow)
            wanted = self.pattern.follow(ctx, routing)
        return wanted or ()

    def restart(self) -> None:
        """Choose a new leg from where the vehicle is at the next tick. The vehicle moved in other
        states meanwhile: that move is not one tick's."""
        self.frame = None
        self._last = None

    @property
    def step_m(self) -> float:
        """The distance the vehicle covers in a tick: the median of its last moves."""
        return sorted(self._moves)[len(self._moves) // 2] if self._moves else DEFAULT_STEP_M

    def observe(self, x: float, y: float) -> None:
        """Count the move since the last tick in ``FIND``."""
        here = (x, y)
        if self._last is not None:
            move = math.dist(here, self._last)
            if move >= MOVING_M:
                self._moves.append(move)
        self._last = here

    def _choose(self, ctx: PlanContext, flow: FlowFrame) -> None:
        self.frame = flow
        if self._ends is None:
            self._ends = candidate_ends(self.grid)
        step_m = self.step_m
        mapper = ctx.mapper
        here = (ctx.vehicle.x, ctx.vehicle.y)
        kernel = mapper.odour_kernel()
        leg = best_leg(self.grid, mapper.likelihood, kernel, here, step_m, self._ends, (flow.ux, flow.uy))
        self.pattern = Pattern(() if leg is None else (leg[0],))
