"""The mission state machine: find the plume, trace it, recover it, declare the source.

Seed pomdp-astar §II-A: a search "can be divided into three phases, namely plume finding, plume
tracing, and source declaration". The states:

- ``FIND`` (published as ``search``): no detection yet; a zigzag sweep across the flow
  (``planning.zigzag``), sweeping back the other way when it reaches the edge of the area, laid
  out anew when the mean flow over the mapper's history turns by more than 45 degrees. It goes
  upflow first, or downflow from a start less than ``zigzag_near_edge_spacings`` spacings from
  the upflow edge.
- ``TRACE``: the configured planner (``planning.method``) toward the mapper's estimate.
- ``LOST``: no detection for ``lost_after_s`` while tracing; a cast across the flow around the
  last detection (``planning.cast``), then the planner again. A detection returns to ``TRACE``.
  With ``flat_map_ratio`` > 0, a cast that ends with a map holding no evidence (no cell above that
  many times a uniform map's share) goes back to ``FIND``: a new sweep from where the vehicle is.
  With ``lone_contact_hits`` > 0, a contact the sweep met with at most that many detections is
  lost after ``lone_contact_lost_after_s`` instead, and goes back to ``FIND``, on along the sweep
  from where it stopped: a false alarm (the detector's, or a stray puff) is not worth a cast,
  and the sweep crosses the flow again anyway.
  With ``lost_trace_mass`` > 0, while the estimate holds that share of the map the vehicle goes
  on tracing instead of casting.
- ``DECLARED``: a declaration rule fired (``planning.declaration``); the vehicle holds. Rules are
  only judged after the first detection: before it a flat map's argmax never moves. With
  ``declaration.check_width_m`` > 0 a rule that fires first sends the vehicle across the flow
  ``check_upflow_m`` upflow of the estimate (still ``TRACE``), and the source is declared when
  that pass is flown; odour found upflow of the estimate, or another estimate, calls it off. A
  plume that swung off the vehicle's line looks to the maps like the upflow end of a plume; the
  check looks for it where it would be. At the estimate the vehicle probes upflow (the cell
  upflow, or with ``declaration.upflow_pass_m`` > 0 a point just beyond the upflow pass), so that the
  declaration's upflow pass is made.

``Mission.step`` is pure: its inputs are this tick's observation (whose ``time_s`` is the only
clock) and the vehicle state; it updates the mapper it was given and returns the waypoints to fly
(``None``: keep flying the last ones) and the events of the tick. Every waypoint it returns comes
out of ``Emitter``, which passes it through ``planning.safety.safe_plan``: inside the search area,
outside every obstacle, no leg across an obstacle. When the estimate cannot be reached, the
planner aims at the nearest reachable cell instead; when a planner still finds no path
(``NoPathError``), the obstacle-free A* takes over; when nothing can be planned, the vehicle holds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from service.core.config import DeclarationConfig, PlanningConfig
from service.core.mission.emitter import Emitter
from service.core.mission.events import (
    CrossCheck,
    MissionEvent,
    MissionOutput,
    MissionState,
    PlumeFound,
    PlumeLost,
    SourceDeclared,
)
from service.core.mission.pattern import Pattern
from service.core.mission.routing import Routing
from service.core.planning import make_planner
from service.core.planning.base import PlanContext, Waypoint
from service.core.planning.cast import cast_vertices
from service.core.planning.crossflow import FlowFrame
from service.core.planning.declaration import Declarer, mass_within, steady_odour
from service.core.planning.safety import clamped_cell, segment_clear
from service.core.planning.zigzag import sweeps_upflow_first, zigzag_vertices

if TYPE_CHECKING:
    from service.core.config import Config
    from service.core.grid import Grid
    from service.core.mapping.mapper import SourceMapper
    from service.core.observation import Observation
    from service.core.planning.base import Planner, VehicleState
    from service.core.planning.declaration import Declaration

SWEEP_REDRAW_RAD = math.pi / 4.0
"""A zigzag is laid out anew when the flow has turned more than this since it was laid out."""


PASS_PROBE_MARGIN_M = 0.25
"""The probe to the upflow pass flies this far beyond the upflow pass, so that the pass is met, not grazed."""
PASS_PROBE_REACHED_M = 0.3
"""The upflow pass probe's point counts as reached this close to it."""
UPFLOW_PROBES: tuple[tuple[int, int], ...] = tuple(
    (d_row, d_col) for d_row in (-1, 0, 1) for d_col in (-1, 0, 1) if (d_row, d_col) != (0, 0)
)
"""(row, column) offsets of the eight neighbours a probe upflow chooses from."""


@dataclass
class _Check:
    """The upflow check of the cell where a rule fired (``found``): a cross-flow pass
    ``check_upflow_m`` upflow of its centre. Odour ``cancel_upflow_m`` or more upflow of the
    centre, or another estimated cell, calls it off."""

    found: Declaration
    frame: FlowFrame
    cancel_upflow_m: float
    done: bool = False

    @property
    def cell(self) -> int:
        return self.found.cell

    def holds(self, obs: Observation, estimated_cell: int) -> bool:
        if estimated_cell != self.cell:
            return False
        if not obs.detected:
            return True
        # how far upflow of the centre the odour was
        return self.frame.along(self.found.x - obs.x, self.found.y - obs.y) < self.cancel_upflow_m


class Mission:
    """One search mission over ``grid`` with ``mapper``; call ``step`` once per tick."""

    def __init__(
        self,
        grid: Grid,
        mapper: SourceMapper,
        planning: PlanningConfig | None = None,
        declaration: DeclarationConfig | None = None,
        *,
        planner: Planner | None = None,
        admit: Callable[[int], bool] | None = None,
    ) -> None:
        """``admit``: the declarer's filter of the cells it may name (``Declarer``; benchmarks only)."""
        if mapper.grid != grid:
            raise ValueError("the mapper works on a different grid")
        self.grid = grid
        self.mapper = mapper
        self.planning = planning or PlanningConfig()
        self.planner = planner if planner is not None else make_planner(grid, self.planning)
        self._routing = Routing.of(grid, self.planning)  # zigzag, cast, probe and fallback legs
        self._declaration = (declaration or DeclarationConfig()).for_mapper(mapper.name)
        self._declarer = Declarer(grid, self._declaration, admit)
        self._check: _Check | None = None  # the upflow check of a cell about to be declared
        self._state = MissionState.FIND
        self._last_time: float | None = None
        self._last_detection: tuple[float, float, float] | None = None  # (t, x, y)
        self._frame: FlowFrame | None = None
        self._pattern = Pattern()  # the sweep's, the cast's or the check's turning points
        self._sweep_frame: FlowFrame | None = None
        self._sweep_upflow = True
        self._emitter = Emitter(grid)
        self._probe: int | None = None  # a probe beyond an obstacle, flown until reached
        self._paused_sweep: Pattern | None = None  # the sweep's pattern at contact
        self._contact_hits = 0  # detections since the sweep was paused
        self._pass_probe: tuple[int, Waypoint] | None = None  # (estimate, point) of the pass probe
        self._recent: deque[Observation] = deque()  # the last ticks, for steady_odour
        self._first_odour_s: float | None = None  # the mission's first detection (this run)

    @classmethod
    def from_config(
        cls, config: Config, grid: Grid, mapper: SourceMapper, *, admit: Callable[[int], bool] | None = None
    ) -> Mission:
        return cls(grid, mapper, config.planning, config.declaration, admit=admit)

    @property
    def state(self) -> MissionState:
        return self._state

    def save_state(self) -> dict[str, float | str | None]:
        """The phase and detection memory (for the restart snapshot; the mapper saves its own)."""
        detection = self._last_detection
        return {
            "phase": str(self._state),
            "last_time": self._last_time,
            "last_detection_t": None if detection is None else detection[0],
            "last_detection_x": None if detection is None else detection[1],
            "last_detection_y": None if detection is None else detection[2],
        }

    def restore_state(self, state: dict[str, Any]) -> None:
        """Continue in the phase ``save_state`` saved; a sweep or cast pattern is laid out anew,
        and past the first detection the declaration rules are re-armed from the restored map.
        The steady-odour record is not saved: it starts afresh, so no check is skipped until it
        has filled again (``steady_min_contact_s`` after the next odour)."""
        phase = MissionState(state["phase"])
        self._last_time = None if state["last_time"] is None else float(state["last_time"])
        t = state["last_detection_t"]
        x, y = state["last_detection_x"], state["last_detection_y"]
        self._last_detection = None if t is None else (float(t), float(x), float(y))
        self._state = phase
        if phase is not MissionState.FIND and self._last_time is not None:
            self._declarer.arm(self._last_time, self.mapper.likelihood)

    def step(self, obs: Observation, vehicle: VehicleState) -> MissionOutput:
        """Fuse this tick's observation, move the state machine on, and plan."""
        if self._last_time is not None and obs.time_s <= self._last_time:
            # a repeated or out-of-order tick changes nothing (the mapper would ignore it too)
            return MissionOutput(obs.time_s, self._state, None, (), self.mapper.estimate())
        self._last_time = obs.time_s
        self.mapper.update(obs)
        self._update_mean_flow(obs)
        self._remember(obs)
        estimate = self.mapper.estimate()
        events = self._advance(obs)
        if self._state is MissionState.DECLARED:
            declared_now = any(isinstance(e, SourceDeclared) for e in events)
            waypoints = self._emitter.emit(vehicle, ()) if declared_now else None
        else:
            ctx = PlanContext(
                vehicle=vehicle,
                cell=clamped_cell(self.grid, vehicle.x, vehicle.y),
                goal=self.grid.flat_index(estimate.cell),
                mapper=self.mapper,
            )
            waypoints = self._emitter.emit(vehicle, self._BEHAVIOUR[self._state](self, ctx))
        return MissionOutput(obs.time_s, self._state, waypoints, tuple(events), estimate)

    def _remember(self, obs: Observation) -> None:
        """Keep this tick for ``steady_odour`` (only while the steady-odour test is enabled)."""
        if obs.detected and self._first_odour_s is None:
            self._first_odour_s = obs.time_s
        d = self._declaration
        if d.steady_hit_rate <= 0.0:
            return
        self._recent.append(obs)
        keep_s = max(d.steady_window_s, d.steady_turn_window_s)
        while self._recent and self._recent[0].time_s <= obs.time_s - keep_s:
            self._recent.popleft()

    def _update_mean_flow(self, obs: Observation) -> None:
        """The direction (``_frame``) of the mean flow over the mapper's
        flow history (this tick's flow before there is any): turbulent noise on single ticks must
        not turn the sweep around."""
        history = self.mapper.history
        dx = sum(step.dx_m for step in history) if history else obs.flow_x
        dy = sum(step.dy_m for step in history) if history else obs.flow_y
        self._frame = FlowFrame.from_flow(dx, dy, self._frame)

    # -- state machine -------------------------------------------------------------------------

    def _advance(self, obs: Observation) -> list[MissionEvent]:
        events: list[MissionEvent] = []
        if self._state is MissionState.DECLARED:
            return events
        t = obs.time_s
        if self._check is not None and not self._check.holds(obs, self._estimated_cell()):
            self._end_check()
        if obs.detected:
            if self._state is not MissionState.TRACE:
                first = self._state is MissionState.FIND and not self._declarer.armed
                events.append(PlumeFound(t, obs.x, obs.y, first=first))
                paused = self._pattern if self._state is MissionState.FIND else None
                if first:
                    self._declarer.arm(t, self.mapper.likelihood)
                self._enter(MissionState.TRACE)
                self._paused_sweep, self._contact_hits = paused, 0
            self._contact_hits += 1
            self._last_detection = (t, obs.x, obs.y)
        elif self._state is MissionState.TRACE and self._last_detection is not None:
            t_last, x_last, y_last = self._last_detection
            paused = self._paused_sweep
            lone = paused is not None and self._contact_hits <= self.planning.lone_contact_hits
            wait = self.planning.lone_contact_lost_after_s if lone else self.planning.lost_after_s
            if t - t_last >= wait and self._check is None:
                events.append(PlumeLost(t, x_last, y_last, t_last))
                if paused is not None and lone:
                    # a lone detection met by the sweep and not repeated: most likely a false
                    # alarm; sweep on from where it stopped instead of casting around it
                    self._enter(MissionState.FIND)
                    self._pattern = paused
                else:
                    self._enter(MissionState.LOST)
        if self._declarer.armed:
            flow = None if self._frame is None else (self._frame.ux, self._frame.uy)
            found = self._declarer.update(t, self.mapper.likelihood, (obs.x, obs.y), flow, obs.detected)
            check: CrossCheck | None = None
            if self._check is not None and self._check.done:
                check = CrossCheck.FLOWN
                # flown with no odour upflow: the rule fired at the estimate when the check began
                lik = self.mapper.likelihood
                found = replace(
                    self._check.found,
                    time_s=t,
                    probability=float(lik.flat[self._check.cell]),
                    mass=mass_within(self.grid, lik, self._check.cell, self._declaration.radius_m),
                )
            elif found is not None:
                check = self._checked(found)
            if found is not None and check is not None:
                events.append(
                    SourceDeclared(
                        time_s=t,
                        x=found.x,
                        y=found.y,
                        cell=found.paper_cell,
                        probability=found.probability,
                        mass=found.mass,
                        rules=found.rules,
                        check=check,
                    )
                )
                self._enter(MissionState.DECLARED)
        return events

    def _estimated_cell(self) -> int:
        return int(np.argmax(self.mapper.likelihood))

    def _checked(self, found: Declaration) -> CrossCheck | None:
        """How ``found`` may be declared now without the upflow check (off, or steady odour); None
        while the check of its cell is started, or goes on."""
        width = self._declaration.check_width_m
        if width <= 0.0 or self._frame is None:
            return CrossCheck.OFF
        if self._check is not None and self._check.cell == found.cell:
            return None
        frame = self._frame
        if steady_odour(
            self._recent, found.x, found.y, self._first_odour_s, (frame.ux, frame.uy), self._declaration
        ):
            return CrossCheck.STEADY  # a source, not a plume swung over it
        upflow = self._declaration.check_upflow_m
        ax, ay = found.x - upflow * frame.ux, found.y - upflow * frame.uy
        legs = cast_vertices(self.grid, ax, ay, frame, width, 2)
        self._check = _Check(found, frame, 0.5 * upflow)
        self._pattern = Pattern(legs)
        self._probe = None
        return None

    def _end_check(self) -> None:
        self._check = None
        self._pattern = Pattern()

    def _enter(self, state: MissionState) -> None:
        self._check = None
        self._state = state
        self._paused_sweep = None
        self._pattern = Pattern()
        self._probe = None
        if state is MissionState.LOST and self._last_detection is not None and self._frame is not None:
            _, x, y = self._last_detection
            p = self.planning
            self._pattern = Pattern(cast_vertices(self.grid, x, y, self._frame, p.cast_width_m, p.cast_legs))

    # -- behaviours: the waypoints each state wants, before the safety rule -------------------

    def _find(self, ctx: PlanContext) -> tuple[Waypoint, ...]:
        frame = self._frame or FlowFrame(1.0, 0.0)
        if self._sweep_frame is None and self.planning.zigzag_near_edge_spacings > 0.0:
            v, p = ctx.vehicle, self.planning
            near_m = p.zigzag_near_edge_spacings * p.zigzag_spacing_m
            self._sweep_upflow = sweeps_upflow_first(self.grid, v.x, v.y, frame, near_m)
        if self._sweep_frame is None or frame.angle_to(self._sweep_frame) > SWEEP_REDRAW_RAD:
            self._lay_sweep(ctx, frame)
        wanted = self._pattern.follow(ctx, self._routing)
        if wanted is None:  # reached the edge of the area: sweep back the other way
            self._sweep_upflow = not self._sweep_upflow
            self._lay_sweep(ctx, frame)
            wanted = self._pattern.follow(ctx, self._routing)
        return wanted or ()

    def _lay_sweep(self, ctx: PlanContext, frame: FlowFrame) -> None:
        v = ctx.vehicle
        self._sweep_frame = frame
        spacing = self.planning.zigzag_spacing_m
        self._pattern = Pattern(
            zigzag_vertices(self.grid, v.x, v.y, frame, spacing, upflow=self._sweep_upflow)
        )

    def _trace(self, ctx: PlanContext) -> tuple[Waypoint, ...]:
        if self._check is not None and not self._check.done:
            wanted = self._pattern.follow(ctx, self._routing)
            if wanted is not None:
                return wanted
            self._check.done = True  # declared at the next tick
            return (Waypoint(ctx.vehicle.x, ctx.vehicle.y),)
        if self._probe is not None and self._probe != ctx.cell:
            # a probe beyond an obstacle is a detour: replanning toward the estimate each tick
            # would turn back at the first step off it, so the probe is flown until reached
            return self._routing.to_cell(ctx, self._probe)
        self._probe = None
        if self._pass_probe is not None:
            cell, target = self._pass_probe
            there = math.hypot(ctx.vehicle.x - target.x, ctx.vehicle.y - target.y) < PASS_PROBE_REACHED_M
            if cell == ctx.goal and not there and not self._declarer.passed_upflow:
                return (target,)
            self._pass_probe = None
        if self._routing.reach.goal_for(ctx.cell, ctx.goal) == ctx.cell:
            point = self._pass_probe_target(ctx)
            if point is not None:
                self._pass_probe = (ctx.goal, point)
                return (point,)
            # at the estimate (or as near as it can be reached, beside an obstacle) and not yet
            # declared: staying put only repeats one observation (odour there is explained as well
            # by any source upflow), so probe the cell upflow: odour there rules the vehicle's cell
            # out, none there rules the cells upflow out
            probe = self._upflow_neighbour(ctx.cell)
            if probe is None:
                probe = self._probe = self._upflow_beyond(ctx.cell)
            if probe is not None:
                return self._routing.to_cell(ctx, probe)
        return self._routing.route(self.planner, ctx)

    def _pass_probe_target(self, ctx: PlanContext) -> Waypoint | None:
        """The point just beyond the upflow pass of the estimate, if the
        pass is still to be made and the leg there is clear; else None (the cell probe)."""
        pass_m = self._declaration.upflow_pass_m
        if pass_m <= 0.0 or self._frame is None:
            return None
        if self._declarer.passed_upflow:
            return None
        cx, cy = self.grid.centre(ctx.goal)
        d = pass_m + PASS_PROBE_MARGIN_M
        target = Waypoint(cx - d * self._frame.ux, cy - d * self._frame.uy)
        if not self.grid.contains(target.x, target.y):
            return None
        if not segment_clear(self.grid, (ctx.vehicle.x, ctx.vehicle.y), (target.x, target.y)):
            return None
        return target

    def _upflow_neighbour(self, cell: int) -> int | None:
        """The free neighbour of ``cell`` most nearly upflow (against the mean flow), if any."""
        if self._frame is None:
            return None
        grid = self.grid
        row, col = grid.row_col(cell)
        cx, cy = grid.centre(cell)
        best, best_cos = None, 0.0
        for d_row, d_col in UPFLOW_PROBES:
            r, c = row + d_row, col + d_col
            if not (0 <= r < grid.rows and 0 <= c < grid.columns):
                continue
            neighbour = r * grid.columns + c
            if grid.obstacle_mask.flat[neighbour]:
                continue
            nx, ny = grid.centre(neighbour)
            dx, dy = nx - cx, ny - cy
            cos = -(dx * self._frame.ux + dy * self._frame.uy) / math.hypot(dx, dy)
            if cos > best_cos + 1e-9:
                best, best_cos = neighbour, cos
        return best

    def _upflow_beyond(self, cell: int) -> int | None:
        """The first free cell reachable from ``cell`` on the line upflow of its centre, if any.

        Used when every upflow neighbour is blocked (the vehicle stands against the downflow face
        of an obstacle): the plume may cross the obstacle, and only a look beyond it tells a
        source behind it from one in the vehicle's cell."""
        if self._frame is None:
            return None
        grid = self.grid
        reachable = self._routing.reach.reachable(cell)
        cx, cy = grid.centre(cell)
        step_m = 0.5 * min(grid.cell_width_m, grid.cell_height_m)
        distance_m = step_m
        while True:
            x, y = cx - distance_m * self._frame.ux, cy - distance_m * self._frame.uy
            if not grid.contains(x, y):
                return None
            candidate = grid.cell_of(x, y)
            if candidate != cell and reachable.flat[candidate]:
                return candidate
            distance_m += step_m

    def _lost(self, ctx: PlanContext) -> tuple[Waypoint, ...]:
        if self._check is not None or self._map_knows_the_plume():
            return self._trace(ctx)
        wanted = self._pattern.follow(ctx, self._routing)
        if wanted is not None:
            return wanted
        if self._map_is_flat():
            # the cast is over and the map holds no evidence: its estimate is merely the first of
            # nearly equal cells, so look for the plume again as before the first detection
            self._enter(MissionState.FIND)
            self._sweep_frame = None
            return self._find(ctx)
        return self._trace(ctx)

    def _map_is_flat(self) -> bool:
        """Whether no cell holds ``flat_map_ratio`` times a uniform map's share (always False with
        the ratio 0, and for the map-free baseline)."""
        ratio = self.planning.flat_map_ratio
        if ratio <= 0.0 or not self.planner.steers_by_map:
            return False
        likelihood = self.mapper.likelihood
        total = float(likelihood.sum())
        return total > 0.0 and float(likelihood.max()) * likelihood.size < ratio * total

    def _map_knows_the_plume(self) -> bool:
        """Whether the estimate holds ``lost_trace_mass`` of the map (within the declaration
        radius). The cast is for a map that does not know where the plume went; one that does
        has its estimate near the source, where a cast through the last detection, often just
        upflow of the source, crosses the flow where the plume is not."""
        share = self.planning.lost_trace_mass
        if share <= 0.0 or not self.planner.steers_by_map:
            return False  # the map-free baseline casts whatever the map says
        cell = self._estimated_cell()
        return mass_within(self.grid, self.mapper.likelihood, cell, self._declaration.radius_m) >= share

    _BEHAVIOUR: ClassVar[dict[MissionState, Callable[[Mission, PlanContext], tuple[Waypoint, ...]]]] = {
        MissionState.FIND: _find,
        MissionState.TRACE: _trace,
        MissionState.LOST: _lost,
    }
