"""The mission's side of the declaration: arming the rule, the check across the flow and the
probe at the estimate. The rule itself is
``planning.declaration``'s (``Declarer``).

With ``declaration.check_width_m`` > 0 a rule that fires first sends the vehicle across the flow
``check_upflow_m`` upflow of the estimate (``Check``), and the source is declared when that pass
is flown and odour has been met at the cell again; odour found upflow of the estimate, or another
estimate, calls it off, and so does no odour at the cell for ``RESMELL_WAIT_S`` after the pass.
A source keeps releasing, so a plume stays anchored at it: coming back to the cell after the pass
meets its odour within seconds, while the end of a plume swung aside by a meander has usually
moved on by then (docs/search-steps.md, step 37). A call-off is not remembered: a pass that
happens to miss a patchy plume upflow of a false end still needs odour back at the false end,
which a plume swung aside does not give (a tally that asked a cell with a call-off for more clean
passes than called-off ones gained nothing once the odour back was asked for: step 39). A plume that
swung off the vehicle's line looks to the maps like the upflow end of a plume; the check looks
for it where it would be. Steady odour near the estimate does not make the check needless: a
strong plume is smelt as steadily far downflow of its source. At the estimate the vehicle probes
(``EstimateProbe``): with ``declaration.upflow_pass_m`` > 0 first to a point just beyond the
upflow pass, so that the declaration's upflow pass is made; then to the nearby cell where one more
observation tells the most about the source (``planning.probe``, eq. I1).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from service.core.mission.events import CrossCheck, SourceDeclared
from service.core.mission.pattern import ARRIVAL_M, Pattern
from service.core.planning.base import Waypoint
from service.core.planning.crossflow import pass_across, upflow_until
from service.core.planning.declaration import Declaration, Declarer, mass_within
from service.core.planning.probe import information
from service.core.planning.safety import segment_clear

if TYPE_CHECKING:
    from service.core.config import DeclarationConfig
    from service.core.grid import Grid
    from service.core.mapping.belief import FloatArray
    from service.core.mission.routing import Routing
    from service.core.observation import Observation
    from service.core.planning.base import BoolArray, PlanContext
    from service.core.planning.crossflow import FlowFrame

PASS_PROBE_MARGIN_M = 0.25
"""The probe to the upflow pass flies this far beyond the upflow pass, so that the pass is met, not grazed."""
PASS_PROBE_REACHED_M = 0.3
"""The upflow pass probe's point counts as reached this close to it."""
STOPPED_M = 0.05
"""A vehicle that moved less than this in a tick has stopped (an autopilot inside its acceptance radius)."""
RESMELL_WAIT_S = 15.0
"""After its pass, a check waits this long for odour within ``radius_m`` of the cell, flying back
to its line ``check_upflow_m / 2`` downflow of its centre (as far downflow as the odour that would
call it off lies upflow). The suite's detectors fire in 0.29-0.82 of the ticks 1-10 m downflow of a
source on its line (patchy the least; ``oslim bench model``), so a source is missed for 15 s in
well under one check in a hundred, travel included; a false end, a plume swung aside, stays dry."""


PROBE_REACH = 3
"""The probe at the estimate chooses among the cells within this many rows and columns of the
vehicle's (a few ticks away: 3.75 x 3 m on the default area's 1.25 x 1 m model cells), and the
first free cell upflow beyond an obstacle. Two such cells kept a vehicle in a sparse plume probing
within 2 m of a false end, which its upflow check then missed (docs/search-steps.md, step 22)."""


@dataclass
class Check:
    """The upflow check of the cell where a rule fired (``found``): a cross-flow pass
    ``check_upflow_m`` upflow of its centre that crosses the centre's line twice (``pattern``),
    then back to ``back``, on the line just downflow of the centre, until odour is met near the
    centre again. Odour ``cancel_upflow_m`` or more upflow of the centre, or another estimated
    cell, calls it off. ``flown``: the pass is flown (since ``flown_s``, the time of the tick that
    first saw it flown); ``done``: odour came back, the cell is declared."""

    found: Declaration
    frame: FlowFrame
    cancel_upflow_m: float
    pattern: Pattern
    back: Waypoint
    flown: bool = False
    flown_s: float | None = None
    done: bool = False

    @classmethod
    def across(
        cls,
        grid: Grid,
        found: Declaration,
        frame: FlowFrame,
        config: DeclarationConfig,
        start: tuple[float, float] | None = None,
    ) -> Check:
        """Legs ``check_width_m`` to each side across the flow, ``check_upflow_m`` upflow, the side
        nearer ``start`` (the vehicle) first, and back to the centre's line; or, when that point
        lies in an obstacle, just upflow of the obstacle: a plume that crosses the obstacle cannot
        be met beside it, only beyond it. Then back to the line ``check_upflow_m / 2`` downflow of
        the centre (the centre itself when that point is outside the area or in an obstacle).

        The way back is a second crossing of the line: a sparse plume lies under a crossing vehicle
        for a few ticks only, and one crossing of a plume present in 40 % of the seconds misses it
        in 3 ticks one time in five (docs/search-steps.md, step 23)."""
        upflow = config.check_upflow_m
        clear = upflow_until(grid, found.x, found.y, frame, upflow, lambda x, y: not grid.in_obstacle(x, y))
        ax, ay = clear if clear is not None else (found.x - upflow * frame.ux, found.y - upflow * frame.uy)
        legs = pass_across(grid, ax, ay, frame, config.check_width_m)
        if start is not None and len(legs) == 2:
            first, second = ((end.x, end.y) for end in legs)
            if math.dist(start, second) < math.dist(start, first):
                legs = (legs[1], legs[0])
        if len(legs) == 2:
            low, high = sorted(frame.cross(end.x, end.y) for end in legs)
            line = min(max(frame.cross(ax, ay), low), high)
            legs = (*legs, frame.point(frame.along(legs[-1].x, legs[-1].y), line))
        cancel_upflow = config.cancel_upflow_m
        bx, by = found.x + cancel_upflow * frame.ux, found.y + cancel_upflow * frame.uy
        if not grid.contains(bx, by) or grid.in_obstacle(bx, by):
            bx, by = found.x, found.y
        return cls(found, frame, cancel_upflow, Pattern(legs), Waypoint(bx, by))

    @property
    def cell(self) -> int:
        return self.found.cell

    def holds(self, obs: Observation, estimated_cell: int) -> bool:
        if estimated_cell != self.cell:
            return False
        return not (obs.detected and self.odour_upflow(obs))

    def odour_upflow(self, obs: Observation) -> bool:
        """Whether ``obs`` was made ``cancel_upflow_m`` or more upflow of the cell's centre."""
        return self.frame.along(self.found.x - obs.x, self.found.y - obs.y) >= self.cancel_upflow_m

    def waypoints(self, ctx: PlanContext, routing: Routing) -> tuple[Waypoint, ...]:
        """The legs still to fly; once they are flown, ``back`` (``flown``), held there."""
        if not self.flown:
            wanted = self.pattern.follow(ctx, routing)
            if wanted is not None:
                return wanted
            self.flown = True
        return (self.back,)

    def near(self, x: float, y: float, radius_m: float) -> bool:
        """Whether (x, y) lies within ``radius_m`` of the cell's centre."""
        return math.hypot(x - self.found.x, y - self.found.y) <= radius_m


@dataclass
class EstimateProbe:
    """The look around the estimate, for the declaration's upflow pass and for the map.

    Within ``near_m`` of the estimate (or in the cell nearest it that can be reached, beside an
    obstacle) and not yet declared, staying put only repeats one observation (odour there is
    explained as well by any source upflow). With ``upflow_pass_m`` > 0 the vehicle first flies
    just beyond the upflow pass (``pass_target``: (estimate, point), flown until reached, made or
    the estimate moves). After that it probes the cell within ``near_m`` of the estimate and
    ``PROBE_REACH`` cells of its own, or first free upflow beyond an obstacle, where the next
    observation is worth most (eq. I1): downflow of the estimate when the map's rival lies
    downflow, upflow or beside it when the rival lies there; it need not come back to the
    estimate's cell between probes. A probe beyond an obstacle is a ``detour``, flown until
    reached.

    An estimate inside an obstacle cannot be visited, and no cell beside the obstacle tells a
    source inside it from one beyond it: the plume crosses the obstacle. From the cell nearest
    the estimate the vehicle then crosses the flow ``across_m`` to each side just upflow of the
    obstacle on the estimate's line (``beyond``, flown while the estimate stays in an
    obstacle), where a plume from a source beyond it is met wherever it crosses."""

    grid: Grid
    upflow_pass_m: float
    near_m: float
    """The probe works while the vehicle is this close to the estimate's centre, and chooses among
    cells this close to it: where the rule may fire (the declaration's ``visit_radius_m``), and
    no farther than ``PROBE_REACH`` cells."""
    across_m: float
    """Half the width of the pass beyond an obstacle (the declaration's ``check_width_m``; 0: the
    point on the estimate's line alone)."""
    detour: int | None = None
    beyond: Pattern | None = None
    pass_target: tuple[int, Waypoint] | None = None
    stopped_short: bool = False
    """The vehicle stopped within ARRIVAL_M of the pass probe's point without making the pass (an
    autopilot holds inside its acceptance radius): the pass is as far as it will go."""
    _last: tuple[float, float] | None = None

    def waypoints(
        self, ctx: PlanContext, routing: Routing, frame: FlowFrame | None, passed_upflow: bool
    ) -> tuple[Waypoint, ...] | None:
        """The probe's waypoints; None when there is none to fly (the planner's turn)."""
        if self.detour is not None and self.detour != ctx.cell:
            # a probe beyond an obstacle is a detour: replanning toward the estimate each tick
            # would turn back at the first step off it, so the probe is flown until reached
            return routing.to_cell(ctx, self.detour)
        self.detour = None
        if (wanted := self._follow_beyond(ctx, routing)) is not None:
            return wanted
        last, self._last = self._last, (ctx.vehicle.x, ctx.vehicle.y)
        self.stopped_short = False
        if self.pass_target is not None:
            cell, target = self.pass_target
            if cell == ctx.goal and not passed_upflow:
                away = math.hypot(ctx.vehicle.x - target.x, ctx.vehicle.y - target.y)
                moved = math.inf
                if last is not None:
                    moved = math.hypot(ctx.vehicle.x - last[0], ctx.vehicle.y - last[1])
                self.stopped_short = moved < STOPPED_M and away <= ARRIVAL_M
                if away >= PASS_PROBE_REACHED_M and not self.stopped_short:
                    return (target,)
            self.pass_target = None
        goal = routing.reach.goal_for(ctx.cell, ctx.goal)
        if goal != ctx.cell and not (goal == ctx.goal and self._near(ctx, goal)):
            return None  # an estimate that cannot be reached: first the cell nearest it
        point = self._pass_point(ctx, frame, passed_upflow or self.stopped_short)
        if point is not None:
            self.pass_target = (ctx.goal, point)
            return (point,)
        if frame is None:
            return None
        reachable = routing.reach.reachable(ctx.cell)
        if self.grid.obstacle_mask.flat[ctx.goal]:
            self.beyond = self._pass_beyond(ctx.goal, frame, reachable)
            if (wanted := self._follow_beyond(ctx, routing)) is not None:
                return wanted
        probe = self._informative(ctx, self._upflow_beyond(ctx.cell, frame, reachable))
        if probe is None:
            return None
        row, col = self.grid.row_col(ctx.cell)
        probe_row, probe_col = self.grid.row_col(probe)
        far = max(abs(probe_row - row), abs(probe_col - col)) > PROBE_REACH
        if far or not segment_clear(self.grid, (ctx.vehicle.x, ctx.vehicle.y), self.grid.centre(probe)):
            self.detour = probe
        return routing.to_cell(ctx, probe)

    def _pass_point(self, ctx: PlanContext, frame: FlowFrame | None, passed_upflow: bool) -> Waypoint | None:
        """The point just beyond the upflow pass of the estimate, if the pass is still to be made
        and the leg there is clear; else None (the cell probe)."""
        if self.upflow_pass_m <= 0.0 or frame is None or passed_upflow:
            return None
        cx, cy = self.grid.centre(ctx.goal)
        d = self.upflow_pass_m + PASS_PROBE_MARGIN_M
        target = Waypoint(cx - d * frame.ux, cy - d * frame.uy)
        if not self.grid.contains(target.x, target.y):
            return None
        if not segment_clear(self.grid, (ctx.vehicle.x, ctx.vehicle.y), (target.x, target.y)):
            return None
        return target

    def _near(self, ctx: PlanContext, goal: int) -> bool:
        """Whether the vehicle is within ``near_m`` of ``goal``'s centre."""
        gx, gy = self.grid.centre(goal)
        return math.hypot(ctx.vehicle.x - gx, ctx.vehicle.y - gy) <= self.near_m

    def _informative(self, ctx: PlanContext, beyond: int | None) -> int | None:
        """The free cell within ``PROBE_REACH`` rows and columns of the vehicle's (its own
        excepted) and ``near_m`` (at least a cell's diagonal) of the estimate's centre, or
        ``beyond``, where one more observation tells the most about the source (eq. I1 over the
        mapper's own odour kernel); None when there is no such cell."""
        grid = self.grid
        row, col = grid.row_col(ctx.cell)
        offsets = np.arange(-PROBE_REACH, PROBE_REACH + 1)
        rows, cols = (a.ravel() for a in np.meshgrid(row + offsets, col + offsets, indexing="ij"))
        inside = (rows >= 0) & (rows < grid.rows) & (cols >= 0) & (cols < grid.columns)
        rows, cols = rows[inside], cols[inside]
        gx, gy = grid.centre(ctx.goal)
        keep = ~grid.obstacle_mask[rows, cols] & ((rows != row) | (cols != col))
        near_m = max(self.near_m, math.hypot(grid.cell_width_m, grid.cell_height_m))  # neighbours at least
        keep &= np.hypot(grid.x_centres[cols] - gx, grid.y_centres[rows] - gy) <= near_m
        cells = np.stack([rows[keep], cols[keep]], axis=1)
        if beyond is not None:
            cells = np.vstack([cells, grid.row_col(beyond)])
        if cells.size == 0:
            return None
        mapper = ctx.mapper
        gain = information(mapper.likelihood, mapper.odour_kernel(), mapper.params.false_alarm, cells)
        best_row, best_col = cells[int(np.argmax(gain))]
        return int(best_row) * grid.columns + int(best_col)

    def _upflow_beyond(self, cell: int, frame: FlowFrame, reachable: BoolArray) -> int | None:
        """The first cell of ``reachable`` on the line upflow of ``cell``'s centre, if any: the
        upflow neighbour, or against the downflow face of an obstacle the first cell beyond it (the
        plume may cross the obstacle, and only a look beyond it tells a source behind it from one
        in the vehicle's cell)."""
        grid = self.grid

        def beyond(x: float, y: float) -> bool:
            candidate = grid.cell_of(x, y)
            return candidate != cell and bool(reachable.flat[candidate])

        point = upflow_until(grid, *grid.centre(cell), frame, 0.0, beyond)
        return None if point is None else grid.cell_of(*point)

    def _follow_beyond(self, ctx: PlanContext, routing: Routing) -> tuple[Waypoint, ...] | None:
        """The pass beyond an obstacle's next waypoints while the estimate stays in an obstacle;
        None (and the pass dropped) once it is flown, the estimate has left or there is none."""
        wanted = None
        if self.beyond is not None and self.grid.obstacle_mask.flat[ctx.goal]:
            wanted = self.beyond.follow(ctx, routing)
        if wanted is None:
            self.beyond = None
        return wanted

    def _pass_beyond(self, estimate: int, frame: FlowFrame, reachable: BoolArray) -> Pattern | None:
        """The pass across the flow at the first reachable point upflow of the obstacle that holds
        ``estimate``, on the estimate's line; None when the line leaves the area first."""
        grid = self.grid

        def clear(x: float, y: float) -> bool:
            return not grid.in_obstacle(x, y) and bool(reachable.flat[grid.cell_of(x, y)])

        point = upflow_until(grid, *grid.centre(estimate), frame, 0.0, clear)
        if point is None:
            return None
        if self.across_m <= 0.0:  # no check across the flow: the point itself
            return Pattern((Waypoint(*point),))
        return Pattern(pass_across(grid, *point, frame, self.across_m))


class Declaring:
    """Judges each tick whether the source may be declared: the rule (``Declarer``, armed at the
    first detection), then the check across the flow that vouches for the cell. Owns the check and
    the probe at the estimate, the waypoints the declaration asks for.

    ``admit``: the declarer's filter of the cells it may name (``Declarer``; benchmarks only)."""

    def __init__(self, grid: Grid, config: DeclarationConfig, admit: Callable[[int], bool] | None) -> None:
        self.grid = grid
        self.config = config
        self._declarer = Declarer(grid, config, admit)
        self.check: Check | None = None  # the upflow check of a cell about to be declared
        reach_m = PROBE_REACH * math.hypot(grid.cell_width_m, grid.cell_height_m)
        self.probe = EstimateProbe(
            grid, config.upflow_pass_m, min(config.visit_radius_m, reach_m), config.check_width_m
        )

    @property
    def armed(self) -> bool:
        return self._declarer.armed

    def arm(self, time_s: float, likelihood: FloatArray) -> None:
        """Start judging (``Declarer.arm``): at the first detection, or on a restored map."""
        self._declarer.arm(time_s, likelihood)

    def recheck(self, obs: Observation, likelihood: FloatArray) -> None:
        """Call the check off if this tick's odour or estimate says so; once its pass is flown, mark
        it ``done`` at odour near the cell, or call it off after ``RESMELL_WAIT_S`` without any."""
        check = self.check
        if check is None:
            return
        estimate = int(np.argmax(likelihood))
        radius = self.config.radius_m
        if check.flown and estimate != check.cell and check.near(*self.grid.centre(estimate), radius):
            estimate = check.cell  # the misses on the way back move the greatest cell among its neighbours
        if not check.holds(obs, estimate):
            self.check = None
            return
        if not check.flown or check.done:
            return
        if check.flown_s is None:
            check.flown_s = obs.time_s
        if obs.detected and check.near(obs.x, obs.y, radius):
            check.done = True
        elif obs.time_s - check.flown_s > RESMELL_WAIT_S:
            self.check = None

    def final(self, time_s: float, likelihood: FloatArray) -> SourceDeclared | None:
        """The declaration when the vehicle's endurance runs out: the estimate, named on the map's
        mass without the check across the flow, if the rule's upflow pass has been made since it
        became the estimate (``upflow_pass_m``; none configured, none named), no odour has been met
        ``check_upflow_m / 2`` or more upflow of it since (what calls a check off), and
        ``final_probability`` of the map lies within ``radius_m`` of it (its stated confidence).
        None otherwise (docs/search-steps.md, step 40)."""
        cell = int(np.argmax(likelihood))
        declarer = self._declarer
        if declarer.cell != cell or not declarer.passed_upflow or declarer.odour_upflow:
            return None
        mass = mass_within(self.grid, likelihood, cell, self.config.radius_m)
        if mass < self.config.final_probability or not declarer.admits(cell):
            return None
        x, y = self.grid.centre(cell)
        found = Declaration(
            time_s, cell, self.grid.paper_number(cell), x, y, float(likelihood.flat[cell]), mass
        )
        return self._declared(time_s, found, CrossCheck.ENDURANCE)

    def reset(self) -> None:
        """A new mission state: no check, no probe detour (a pass probe stays while it applies)."""
        self.check = None
        self.probe.detour = None

    def judge(
        self, obs: Observation, likelihood: FloatArray, frame: FlowFrame | None
    ) -> SourceDeclared | Check | None:
        """The declaration of this tick; or the check just started to vouch for a cell whose rule
        fired (its legs are to be flown); None while there is neither."""
        if not self._declarer.armed:
            return None
        t = obs.time_s
        flow = None if frame is None else (frame.ux, frame.uy)
        found = self._declarer.update(t, likelihood, (obs.x, obs.y), flow, obs.detected)
        if self.check is not None and self.check.done:
            # flown with no odour upflow, and odour at the cell again: the rule fired at the
            # estimate when the check began
            check, self.check = self.check, None
            cell = check.cell
            flown = replace(
                check.found,
                time_s=t,
                probability=float(likelihood.flat[cell]),
                mass=mass_within(self.grid, likelihood, cell, self.config.radius_m),
            )
            return self._declared(t, flown, CrossCheck.FLOWN)
        if found is None:
            return None
        vouched = self._vouch(found, frame, (obs.x, obs.y))
        return self._declared(t, found, vouched) if isinstance(vouched, CrossCheck) else vouched

    def waypoints(
        self, ctx: PlanContext, routing: Routing, frame: FlowFrame | None
    ) -> tuple[Waypoint, ...] | None:
        """The check's legs while it is flown, else the probe's at the estimate; None: neither."""
        if self.check is not None and not self.check.done:
            return self.check.waypoints(ctx, routing)
        waypoints = self.probe.waypoints(ctx, routing, frame, self._declarer.passed_upflow)
        if self.probe.stopped_short:
            self._declarer.accept_pass()
        return waypoints

    def _vouch(
        self, found: Declaration, frame: FlowFrame | None, vehicle: tuple[float, float]
    ) -> CrossCheck | Check | None:
        """How ``found`` may be declared now without the upflow check (off); else the check of its
        cell, started now from ``vehicle``, or None while it goes on."""
        c = self.config
        if c.check_width_m <= 0.0 or frame is None:
            return CrossCheck.OFF
        if self.check is not None and self.check.cell == found.cell:
            return None
        self.check = Check.across(self.grid, found, frame, c, vehicle)
        self.probe.detour = None
        return self.check

    @staticmethod
    def _declared(t: float, found: Declaration, check: CrossCheck) -> SourceDeclared:
        return SourceDeclared(
            time_s=t,
            x=found.x,
            y=found.y,
            cell=found.paper_cell,
            probability=found.probability,
            mass=found.mass,
            check=check,
        )
