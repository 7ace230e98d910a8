"""The mission state machine: find the plume, trace it, recover it, declare the source.

Seed pomdp-astar §II-A: a search "can be divided into three phases, namely plume finding, plume
tracing, and source declaration". The states, and the behaviour that flies each:

- ``FIND`` (published as ``search``): no detection yet; straight legs, each the one the map
  expects odour on most often per metre (``Prospect``).
- ``TRACE``: the configured planner (``planning.method``) toward the mapper's estimate, or toward
  the map's greatest cell at most ``TRACE_SLACK_M`` downflow of the last detection when the
  estimate lies farther downflow (a source lies upflow of its odour); the declaration's legs
  (``Declaring``: the check across the flow, the probe at the estimate) go first.
- ``LOST``: no detection for ``lost_after_s`` while tracing; the vehicle flies on as in
  ``TRACE``, toward the map's greatest cell upflow of the last odour, whose map holds the misses
  since (a cast across the flow around the last detection was measured and deleted:
  docs/search-steps.md, step 15). A detection returns to ``TRACE``.
  With ``lone_contact_hits`` > 0, a contact met in ``FIND`` with at most that many detections is
  lost after ``lone_contact_lost_after_s`` instead, and goes back to ``FIND`` (a new leg from
  where it stopped, chosen by the map that now holds the contact): a false alarm (the
  detector's, or a stray puff) is not worth a trace.
- ``DECLARED``: a declaration rule fired and its cell was vouched for (``Declaring``); the
  vehicle holds. Rules are only judged after the first detection: before it a flat map's argmax
  never moves. With an endurance (``vehicle.endurance_s``), its last tick names the estimate
  without the check when the map is sure enough of it (``Declaring.final``).

The transitions are ``transitions.TRANSITIONS``. A check across the flow is flown in ``TRACE``
wherever the rule fired (``Cue.CHECK``).

``Mission.step`` is pure: its inputs are this tick's observation (whose ``time_s`` is the only
clock) and the vehicle state; it updates the mapper it was given and returns the waypoints to fly
(``None``: keep flying the last ones) and the events of the tick. Every waypoint it returns comes
out of ``Emitter``, which passes it through ``planning.safety.safe_plan``: inside the search area,
outside every obstacle, no leg across an obstacle. When the estimate cannot be reached, the
planner aims at the nearest reachable cell instead; when a planner still finds no path
(``NoPathError``), the obstacle-free A* takes over; when nothing can be planned, the vehicle holds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
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
from service.core.mission.prospect import Prospect
from service.core.mission.routing import Routing
from service.core.mission.transitions import TRANSITIONS, Cue
from service.core.planning import make_planner
from service.core.planning.base import PlanContext, Waypoint
from service.core.planning.crossflow import FlowFrame, upflow_cells
from service.core.planning.safety import clamped_cell

if TYPE_CHECKING:
    from service.core.config import Config
    from service.core.grid import Grid
    from service.core.mapping.mapper import SourceMapper
    from service.core.observation import Observation
    from service.core.planning.base import Planner, VehicleState

TRACE_SLACK_M = 3.0
"""The trace's goal lies at most this far downflow of the last detection, along the mean flow: a
source lies upflow of its odour, give or take the mean flow's direction and a cell. A map that has
given the plume up keeps its mass where no observation reached, often on the downflow edge, and
its greatest cell there would send the vehicle away from the plume (docs/search-steps.md,
steps 36 and 43)."""


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
        endurance_s: float = 0.0,
        tick_s: float = 1.0,
    ) -> None:
        """``admit``: the declarer's filter of the cells it may name (``Declarer``; benchmarks only).
        ``endurance_s`` (0: none): how long the vehicle can search from the start of the first
        tick, which is ``tick_s`` before its observation."""
        if mapper.grid != grid:
            raise ValueError("the mapper works on a different grid")
        self.grid = grid
        self.mapper = mapper
        self.planning = planning or PlanningConfig()
        self.planner = planner if planner is not None else make_planner(grid, self.planning)
        self._routing = Routing.of(grid, self.planning)
        decl = (declaration or DeclarationConfig()).for_mapper(mapper.name)
        self._declaring = Declaring(grid, decl, admit)
        self._prospect = Prospect(grid)
        self._emitter = Emitter(grid)
        self._state = MissionState.FIND
        self._last_time: float | None = None
        self._last_detection: tuple[float, float, float] | None = None  # (t, x, y)
        self._contact_hits: int | None = None  # detections since a contact in FIND
        self._frame: FlowFrame | None = None  # the mean flow's direction
        self._endurance_s = endurance_s
        self._tick_s = tick_s
        self._started_s: float | None = None  # the start of the first tick

    @classmethod
    def from_config(
        cls, config: Config, grid: Grid, mapper: SourceMapper, *, admit: Callable[[int], bool] | None = None
    ) -> Mission:
        return cls(
            grid,
            mapper,
            config.planning,
            config.declaration,
            admit=admit,
            endurance_s=config.vehicle.endurance_s,
            tick_s=config.mapping.tick_s,
        )

    @property
    def state(self) -> MissionState:
        return self._state

    @property
    def checking(self) -> bool:
        """Whether the check across the flow is being flown: the declaration's rule fired and the
        cell waits for the check to vouch for it."""
        return self._declaring.check is not None

    def save_state(self) -> dict[str, Any]:
        """The phase and detection memory (for the restart snapshot, as JSON; the mapper saves its
        own)."""
        detection = self._last_detection
        return {
            "phase": str(self._state),
            "last_time": self._last_time,
            "last_detection_t": None if detection is None else detection[0],
            "last_detection_x": None if detection is None else detection[1],
            "last_detection_y": None if detection is None else detection[2],
            "started_s": self._started_s,
        }

    def restore_state(self, state: dict[str, Any]) -> None:
        """Continue in the phase ``save_state`` saved; a leg is laid out anew,
        and past the first detection the declaration rule is re-armed from the restored map. A
        snapshot's ``check_passes`` (the checks' tally, before step 39 of docs/search-steps.md)
        is ignored; one without ``started_s`` counts the endurance from the next tick. The upflow
        pass and the odour upflow of the estimate are not saved: after a restart the endurance names
        a cell only once its upflow pass is made again."""
        phase = MissionState(state["phase"])
        started = state.get("started_s")
        self._started_s = None if started is None else float(started)
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
            held = self._emitter.holding
            return MissionOutput(obs.time_s, self._state, None, (), self.mapper.estimate(), held)
        self._last_time = obs.time_s
        if self._started_s is None:
            self._started_s = obs.time_s - self._tick_s
        self.mapper.update(obs)
        self._update_mean_flow(obs)
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
        held = self._emitter.holding
        return MissionOutput(obs.time_s, self._state, waypoints, tuple(events), estimate, held)

    def _update_mean_flow(self, obs: Observation) -> None:
        """The direction (``_frame``) of the mean flow over the mapper's flow history (this tick's
        flow before there is any): turbulent noise on single ticks must not turn the legs around."""
        history = self.mapper.history
        dx = sum(step.dx_m for step in history) if history else obs.flow_x
        dy = sum(step.dy_m for step in history) if history else obs.flow_y
        self._frame = FlowFrame.from_flow(dx, dy, self._frame)

    # -- state machine -------------------------------------------------------------------------

    def _advance(self, obs: Observation) -> list[MissionEvent]:
        """This tick's events, each taking the transition it cues."""
        if self._state is MissionState.DECLARED:
            return []
        events: list[MissionEvent] = []
        t = obs.time_s
        self._declaring.recheck(obs, self.mapper.likelihood)
        if obs.detected:
            if self._state is not MissionState.TRACE:
                first = self._state is MissionState.FIND and not self._declaring.armed
                events.append(PlumeFound(t, obs.x, obs.y, first=first))
                if first:
                    self._declaring.arm(t, self.mapper.likelihood)
                self._go(Cue.ODOUR)
            if self._contact_hits is not None:
                self._contact_hits += 1
            self._last_detection = (t, obs.x, obs.y)
        elif (cue := self._quiet(t)) is not None and self._last_detection is not None:
            t_last, x_last, y_last = self._last_detection
            events.append(PlumeLost(t, x_last, y_last, t_last))
            self._go(cue)
        verdict = self._declaring.judge(obs, self.mapper.likelihood, self._frame)
        if self._out_of_time(t) and not isinstance(verdict, SourceDeclared):
            verdict = self._declaring.final(t, self.mapper.likelihood) or verdict
        if isinstance(verdict, Check):
            if self._state is not MissionState.TRACE:
                self._go(Cue.CHECK)
        elif verdict is not None:
            events.append(verdict)
            self._go(Cue.SOURCE)
        return events

    def _out_of_time(self, t: float) -> bool:
        """Whether the tick after the one at ``t`` would end beyond the vehicle's endurance (the
        service may go on past it until the pilot takes over: each later tick is asked too)."""
        if self._endurance_s <= 0.0 or self._started_s is None:
            return False
        return t + self._tick_s > self._started_s + self._endurance_s + 1e-9

    def _quiet(self, t: float) -> Cue | None:
        """Whether tracing has gone without odour long enough to be lost: ``LONE_QUIET`` after a
        lone contact in ``FIND``, ``QUIET`` otherwise; never while a check is flown."""
        if self._state is not MissionState.TRACE or self._last_detection is None:
            return None
        p = self.planning
        lone = self._contact_hits is not None and self._contact_hits <= p.lone_contact_hits
        wait = p.lone_contact_lost_after_s if lone else p.lost_after_s
        if t - self._last_detection[0] < wait or self._declaring.check is not None:
            return None
        return Cue.LONE_QUIET if lone else Cue.QUIET

    def _go(self, cue: Cue) -> None:
        """Take ``cue``'s transition (``TRANSITIONS``) and its entry actions. A check or a probe
        detour ends with the state it began in, except the check that ``CHECK`` takes to TRACE; a
        contact in ``FIND`` counts its detections (for ``LONE_QUIET``)."""
        from_find = self._state is MissionState.FIND
        self._state = TRANSITIONS[self._state, cue]
        if cue is not Cue.CHECK:
            self._declaring.reset()
        self._contact_hits = 0 if from_find and cue is Cue.ODOUR else None
        if self._state is MissionState.FIND:
            self._prospect.restart()

    # -- behaviours: the waypoints each state wants, before the safety rule -------------------

    def _find(self, ctx: PlanContext) -> tuple[Waypoint, ...]:
        return self._prospect.waypoints(ctx, self._frame, self._routing)

    def _trace(self, ctx: PlanContext) -> tuple[Waypoint, ...]:
        wanted = self._declaring.waypoints(ctx, self._routing, self._frame)
        if wanted is not None:
            return wanted
        return self._routing.route(self.planner, replace(ctx, goal=self._trace_goal(ctx.goal)))

    def _trace_goal(self, greatest: int) -> int:
        """``greatest``, the map's greatest cell, unless it lies more than ``TRACE_SLACK_M`` downflow
        of the last detection: then the greatest of the cells that do not."""
        if self._last_detection is None or self._frame is None:
            return greatest
        _, x, y = self._last_detection
        upflow = upflow_cells(self.grid, self._frame, x, y, TRACE_SLACK_M)
        if upflow.flat[greatest] or not upflow.any():
            return greatest
        return int(np.argmax(np.where(upflow, self.mapper.likelihood, -1.0)))

    _BEHAVIOUR: ClassVar[dict[MissionState, Callable[[Mission, PlanContext], tuple[Waypoint, ...]]]] = {
        MissionState.FIND: _find,
        MissionState.TRACE: _trace,
        MissionState.LOST: _trace,
    }
