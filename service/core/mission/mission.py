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
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from service.core.config import DeclarationConfig, PlanningConfig
from service.core.mission.declaring import Check, Declaring
from service.core.mission.emitter import Emitter
from service.core.mission.events import (
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
from service.core.planning.declaration import mass_within
from service.core.planning.safety import clamped_cell
from service.core.planning.zigzag import sweeps_upflow_first, zigzag_vertices

if TYPE_CHECKING:
    from service.core.config import Config
    from service.core.grid import Grid
    from service.core.mapping.mapper import SourceMapper
    from service.core.observation import Observation
    from service.core.planning.base import Planner, VehicleState

SWEEP_REDRAW_RAD = math.pi / 4.0
"""A zigzag is laid out anew when the flow has turned more than this since it was laid out."""


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
        decl = (declaration or DeclarationConfig()).for_mapper(mapper.name)
        self._declaring = Declaring(grid, decl, admit)  # the rules, the check, the probe
        self._state = MissionState.FIND
        self._last_time: float | None = None
        self._last_detection: tuple[float, float, float] | None = None  # (t, x, y)
        self._frame: FlowFrame | None = None
        self._pattern = Pattern()  # the sweep's, the cast's or the check's turning points
        self._sweep_frame: FlowFrame | None = None
        self._sweep_upflow = True
        self._emitter = Emitter(grid)
        self._paused_sweep: Pattern | None = None  # the sweep's pattern at contact
        self._contact_hits = 0  # detections since the sweep was paused

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
            self._declaring.arm(self._last_time, self.mapper.likelihood)

    def step(self, obs: Observation, vehicle: VehicleState) -> MissionOutput:
        """Fuse this tick's observation, move the state machine on, and plan."""
        if self._last_time is not None and obs.time_s <= self._last_time:
            # a repeated or out-of-order tick changes nothing (the mapper would ignore it too)
            return MissionOutput(obs.time_s, self._state, None, (), self.mapper.estimate())
        self._last_time = obs.time_s
        self.mapper.update(obs)
        self._update_mean_flow(obs)
        self._declaring.remember(obs)
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
        if self._declaring.recheck(obs, self.mapper.likelihood):
            self._end_check()
        if obs.detected:
            if self._state is not MissionState.TRACE:
                first = self._state is MissionState.FIND and not self._declaring.armed
                events.append(PlumeFound(t, obs.x, obs.y, first=first))
                paused = self._pattern if self._state is MissionState.FIND else None
                if first:
                    self._declaring.arm(t, self.mapper.likelihood)
                self._enter(MissionState.TRACE)
                self._paused_sweep, self._contact_hits = paused, 0
            self._contact_hits += 1
            self._last_detection = (t, obs.x, obs.y)
        elif self._state is MissionState.TRACE and self._last_detection is not None:
            t_last, x_last, y_last = self._last_detection
            paused = self._paused_sweep
            lone = paused is not None and self._contact_hits <= self.planning.lone_contact_hits
            wait = self.planning.lone_contact_lost_after_s if lone else self.planning.lost_after_s
            if t - t_last >= wait and self._declaring.check is None:
                events.append(PlumeLost(t, x_last, y_last, t_last))
                if paused is not None and lone:
                    # a lone detection met by the sweep and not repeated: most likely a false
                    # alarm; sweep on from where it stopped instead of casting around it
                    self._enter(MissionState.FIND)
                    self._pattern = paused
                else:
                    self._enter(MissionState.LOST)
        verdict = self._declaring.judge(obs, self.mapper.likelihood, self._frame)
        if isinstance(verdict, Check):
            self._pattern = Pattern(verdict.legs)
        elif verdict is not None:
            events.append(verdict)
            self._enter(MissionState.DECLARED)
        return events

    def _estimated_cell(self) -> int:
        return int(np.argmax(self.mapper.likelihood))

    def _end_check(self) -> None:
        self._pattern = Pattern()

    def _enter(self, state: MissionState) -> None:
        self._declaring.reset()
        self._state = state
        self._paused_sweep = None
        self._pattern = Pattern()
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
        check = self._declaring.check
        if check is not None and not check.done:
            wanted = self._pattern.follow(ctx, self._routing)
            if wanted is not None:
                return wanted
            check.done = True  # declared at the next tick
            return (Waypoint(ctx.vehicle.x, ctx.vehicle.y),)
        wanted = self._declaring.waypoints(ctx, self._routing, self._frame)
        return self._routing.route(self.planner, ctx) if wanted is None else wanted

    def _lost(self, ctx: PlanContext) -> tuple[Waypoint, ...]:
        if self._declaring.check is not None or self._map_knows_the_plume():
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
        return mass_within(self.grid, self.mapper.likelihood, cell, self._declaring.config.radius_m) >= share

    _BEHAVIOUR: ClassVar[dict[MissionState, Callable[[Mission, PlanContext], tuple[Waypoint, ...]]]] = {
        MissionState.FIND: _find,
        MissionState.TRACE: _trace,
        MissionState.LOST: _lost,
    }
