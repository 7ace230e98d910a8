"""Guided setpoints for an autopilot that stops short of its targets.

An autopilot that counts a guided target as reached once it is within an acceptance radius, and
holds still there (ArduPilot Rover before 4.3 with ``WP_RADIUS``, 2 m by default), strands a
mission that steers from cell to cell (1.25 m apart on the default area): the next target is often
inside the radius already and the vehicle never moves again. ``Lead`` learns the radius from the
vehicle's own behaviour, with no setting: a vehicle that stays put for ``STALL_S`` while every
target it is sent lies ``STALL_MIN_M`` to ``MAX_RADIUS_M`` away has an acceptance radius at least
as large as the farthest. The radius the autopilot states is not taken for it: Rover 4.3 and later
drive a guided target all the way to the point (position-controller input shaping) and stop within
``WP_RADIUS`` only as the approach ends; a vehicle led by that radius from the start is sent past
every point, and a car-like one circles a point it is sent past (docs/search-steps.md, step 48).
Once the radius r is known, each setpoint is the first point of the plan ``r + LEAD_MARGIN_M``
away (pure pursuit); a point of the plan nearer than that (its end, or a corner round an obstacle)
is overrun by ``r + OVERRUN_M`` along the line of sight, so that the vehicle drives through it and
stops just past it, not r short of it. While r is 0 (a vehicle that drives onto its targets, as the
simulator's, ArduCopter's and Rover's since 4.3 do) the setpoint is the plan's first waypoint.

Every setpoint passes the safety rule (``planning.safety``): inside the area, outside every
obstacle, with a clear straight leg from the vehicle; where a lead point fails, the farthest
point of the plan in sight is sent instead, and the vehicle's own position (hold) when none is.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from service.core.mapping.belief import FloatArray
from service.core.planning.base import Waypoint
from service.core.planning.safety import is_safe_point, segment_clear

if TYPE_CHECKING:
    from collections.abc import Sequence

    from service.core.grid import Grid

STALL_S = 5.0
"""A vehicle that has not moved for this long, every target in reach, has stopped short of them
(longer than a pivot turn on the spot: Rover turns 180 degrees in 3 s at WP_PIVOT_RATE 60 deg/s)."""
STOPPED_M = 0.2
"""A vehicle that stays within this of where it was has not moved (a stopped vehicle's position
jitters by a few centimetres with GPS; a moving one covers more in a setpoint period)."""
STALL_MIN_M = 0.3
"""A vehicle stopped nearer its target than this has arrived (GPS noise, rounding)."""
MAX_RADIUS_M = 5.0
"""Stalls farther from the target than this are not taken for an acceptance radius (a vehicle held
by something else: an obstacle, a pilot's brake)."""
LEAD_MARGIN_M = 1.0
"""How far beyond the learned radius the setpoint leads the vehicle."""
OVERRUN_M = 0.3
"""How far beyond a plan's last point, less the learned radius, the vehicle is sent: it stops this
far past the point (within the mission's arrival distance, ``pattern.ARRIVAL_M``)."""
THERE_M = 0.5
"""A vehicle this near the one point of its plan is on it (the mission's ``pattern.ARRIVAL_M``): it
is not sent on past it."""
OVERRUNS = (
    (0, 1.0), (0, 0.75), (30, 1.0), (-30, 1.0), (60, 1.0), (-60, 1.0),
    (90, 1.0), (-90, 1.0), (0, 0.5), (0, 0.25),
)  # fmt: skip
"""The overruns tried in turn, (turn from the line of sight in degrees, share of the overrun):
straight on; where a wall lies just beyond the point (an estimate against an obstacle's face),
turned aside at full length, so that the vehicle still moves and passes by the point (0.6 m from
it at 30 degrees from 1.2 m short, r = 2 m), before one that stops it short of the point."""
SAMPLE_M = 0.1
"""The path is searched for the lead point at this spacing."""
CALL_GAP_S = 2.0
"""Setpoints asked for this far apart (commanding was paused) restart the stall watch."""


def lead_point(
    grid: Grid,
    x: float,
    y: float,
    plan: Sequence[Waypoint],
    lead_m: float,
    overrun_m: float,
) -> Waypoint:
    """The setpoint for a vehicle at (x, y) that stops short of its targets, flying ``plan``
    (non-empty): the first point of the path through ``plan`` that lies ``lead_m`` from (x, y) as
    the crow flies; where the straight leg there is not clear (the path turns round an obstacle) or
    the path ends nearer, the farthest point along the path that is in sight, moved on
    ``overrun_m`` along the line of sight, so that the vehicle drives through that point and stops
    just past it (or, where that is not safe, as ``OVERRUNS`` says). When no point is in sight,
    (x, y) itself (hold), or the plan's first point for a vehicle pressed against an obstacle, where
    (x, y) is no safe point (the mission's plan is safe, and leads such a vehicle off it)."""
    path = _densified(np.asarray(_up_to_lead([(x, y), *((w.x, w.y) for w in plan)], lead_m), dtype=float))
    for k in range(len(path) - 1, 0, -1):
        aim = (float(path[k, 0]), float(path[k, 1]))
        if is_safe_point(grid, *aim) and segment_clear(grid, (x, y), aim):
            break
    else:
        return Waypoint(x, y) if is_safe_point(grid, x, y) else plan[0]
    away = math.hypot(aim[0] - x, aim[1] - y)
    if away >= lead_m - 1e-9 or away <= 1e-6:
        return Waypoint(*aim)
    heading = math.atan2(aim[1] - y, aim[0] - x)
    for turn_deg, share in OVERRUNS:
        angle = heading + math.radians(turn_deg)
        on = (aim[0] + share * overrun_m * math.cos(angle), aim[1] + share * overrun_m * math.sin(angle))
        if is_safe_point(grid, *on) and segment_clear(grid, (x, y), on):
            return Waypoint(*on)
    return Waypoint(*aim)


def _up_to_lead(points: list[tuple[float, float]], lead_m: float) -> list[tuple[float, float]]:
    """The path ``points`` cut at its first point ``lead_m`` from ``points[0]`` (whole if none is)."""
    x, y = points[0]
    for k in range(1, len(points)):
        (ax, ay), (bx, by) = points[k - 1], points[k]
        if math.hypot(bx - x, by - y) < lead_m:
            continue
        # |a - v + s (b - a)| = lead: the root where the path leaves the circle
        ux, uy, wx, wy = bx - ax, by - ay, ax - x, ay - y
        uu, wu, ww = ux * ux + uy * uy, wx * ux + wy * uy, wx * wx + wy * wy
        root = math.sqrt(max(wu * wu - uu * (ww - lead_m * lead_m), 0.0))
        share = min(max((root - wu) / uu, 0.0), 1.0)
        return [*points[:k], (ax + share * ux, ay + share * uy)]
    return points


def _densified(points: FloatArray) -> FloatArray:
    """The polyline through ``points`` sampled every ``SAMPLE_M`` or closer, its vertices kept."""
    out = [points[:1]]
    for a, b in itertools.pairwise(points):
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / SAMPLE_M))
        share = np.arange(1, n + 1)[:, None] / n
        out.append(a + share * (b - a))
    return np.concatenate(out)


@dataclass
class Lead:
    """The learned acceptance radius (``radius_m``) and the watch for a vehicle stopped short."""

    grid: Grid
    radius_m: float = 0.0
    _since: tuple[float, float, float] | None = None  # (t, x, y) of the last move
    _farthest: float = 0.0  # the farthest target since, m
    _last_call: float | None = None

    def setpoint(
        self, t_s: float, x: float, y: float, plan: Sequence[Waypoint], *, hold: bool = False
    ) -> Waypoint | None:
        """The target to command now for a vehicle at (x, y) flying ``plan``. A ``hold`` plan's
        point is where the vehicle is to stop: one it stands on is commanded as it is, one farther
        is driven through like a plan's end (a vehicle stopped in an obstacle's cell is held at the
        nearest free cell's centre, often inside its radius; sent there as it is, it would never
        move). A hold teaches nothing of the radius. None for an empty plan."""
        if not plan:
            self._watch(t_s, x, y, None)
            return None
        end = plan[-1]
        there = len(plan) == 1 and math.hypot(end.x - x, end.y - y) <= THERE_M
        if there or self.radius_m <= 0.0:
            target = plan[0]
        else:
            r = self.radius_m
            target = lead_point(self.grid, x, y, plan, r + LEAD_MARGIN_M, r + OVERRUN_M)
        if not hold:
            self._watch(t_s, x, y, target)
        else:
            self._since = None
        return target

    def planning_point(self, t_s: float, x: float, y: float, plan: Sequence[Waypoint]) -> tuple[float, float]:
        """Where the mission should plan from at ``t_s``: (x, y), or the plan's end for a vehicle
        that has stood still for ``STALL_S`` within the radius of it. Where an obstacle or the
        area's edge lies just beyond the end, no overrun gets such a vehicle any nearer: the end is
        as near as it will go, and planning on from (x, y) would send it there again."""
        since = self._since
        if self.radius_m <= 0.0 or not plan or since is None or t_s - since[0] < STALL_S:
            return x, y
        if not self._commanding(t_s):  # the pilot or a lost link stopped it, not our targets
            return x, y
        end = plan[-1]
        still = math.hypot(x - since[1], y - since[2]) <= STOPPED_M
        if still and math.hypot(end.x - x, end.y - y) <= self.radius_m + OVERRUN_M:
            return end.x, end.y
        return x, y

    def _commanding(self, t_s: float) -> bool:
        """Whether setpoints were asked for within ``CALL_GAP_S`` before ``t_s``."""
        return self._last_call is not None and t_s - self._last_call <= CALL_GAP_S

    def _watch(self, t_s: float, x: float, y: float, target: Waypoint | None) -> None:
        """Learn the radius from a vehicle that stays put while every target it is sent lies
        0.3-5 m away: it stops short of them all, so its radius is at least the farthest. (The
        targets may change meanwhile: the map moves the estimate while the vehicle waits.)"""
        paused = not self._commanding(t_s)
        self._last_call = t_s
        since = self._since
        away = math.inf if target is None else math.hypot(target.x - x, target.y - y)
        held = STALL_MIN_M <= away <= MAX_RADIUS_M
        if paused or not held or since is None or math.hypot(x - since[1], y - since[2]) > STOPPED_M:
            self._since, self._farthest = (t_s, x, y), (away if held else 0.0)
            return
        self._farthest = max(self._farthest, away)
        if t_s - since[0] >= STALL_S and self._farthest > self.radius_m + STOPPED_M:
            self.radius_m = self._farthest
            self._since, self._farthest = (t_s, x, y), 0.0  # led from now on: watched anew
