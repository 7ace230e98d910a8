"""The search as a Python API: feed it samples, call ``tick`` once per mapping tick, fly its waypoints.

This is the one way the search is driven: by the onboard service (``service.app``), by the
benchmarks (``oslim bench search``), by replay, and by other programs (a ROS node, an AUV's own
autonomy, a simulator with a different plume model)::

    from service.api import Search, load_config
    search = Search(load_config("my-vehicle.toml", ["area.columns=100"]))
    search.add_position(t_s, x_m, y_m)      # map frame, any rate
    search.add_flow(t_s, u_mps, v_mps)      # flow toward, map frame
    search.add_chemical(t_s, value)         # compared with sensor.threshold
    step = search.tick(t_s)                 # once per mapping tick; None when there was no position
    step.waypoints   # tuple of (x, y) to fly from now on, first = current target; None when unchanged
    step.state       # "search", "trace", "lost" or "declared"
    step.estimate    # .x, .y, .probability
    step.declared    # None, or the declaration: .x, .y, .confidence, .radius_m
    step.detected    # this tick's detection

The names above are a contract (other programs are written against them). Conventions: the map
frame is metres, x East and y North, inside the configured ``area``; flow is the velocity the
fluid moves *toward*, m/s; times are seconds on any clock that does not go back, the same one
for every call. Samples may come at any rate: a tick fuses the mean flow and the peak chemical
reading (thresholded with ``sensor.threshold``) since the last tick, at the last position
(seed hmm-plume-mapping §III-A). ``mapping.tick_s`` (default 1 s) is the tick period the
mapper's flow model assumes: call ``tick`` at that period.

Only the numerical core is imported here: no sockets, no clocks, no threads.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from service.core.config import Config, load_config
from service.core.grid import Grid, model_division
from service.core.mapping import mapper_from_config
from service.core.mapping.belief import FloatArray
from service.core.mapping.mapper import Estimate, SourceMapper, estimate_of
from service.core.mission import Mission, MissionEvent, MissionState, SourceDeclared
from service.core.observation import Observation
from service.core.planning.base import VehicleState, Waypoint
from service.core.planning.lead import Lead
from service.core.samples import ChemSample, DetectionSample, FlowSample, Position
from service.core.tick import TickAggregator

__all__ = ["Declaration", "Estimate", "MissionState", "Search", "Step", "load_config"]

Sample = Position | FlowSample | ChemSample | DetectionSample

HEADING_MIN_MOVE_M = 0.05
"""Without a given heading, the heading is the direction of the last move at least this long."""


@dataclass(frozen=True)
class Declaration:
    """The declared source.

    ``x``, ``y``: the centre of the declared cell of the model grid (``Search.model_grid``; map
    frame, m). The statement is "the source lies within ``radius_m`` of (x, y) with probability
    ``confidence``": ``confidence`` is the source likelihood map's mass over the model cells whose
    centres lie within ``declaration.radius_m`` of the declared one's (what the mass rule weighs),
    and ``radius_m`` is that radius plus half a model cell's diagonal, so that every point of those
    cells is inside it. ``oslim bench suite`` measures how often the statement is true. ``cell``:
    the papers' 1-based number of the area's cell that holds (x, y); ``time_s``: when it was
    declared. ``check``: how the cell was vouched for (``CrossCheck``): ``flown``, the check across
    the flow; ``off``, none configured; ``endurance``, named when ``vehicle.endurance_s`` ran out,
    on the map's mass alone.
    """

    time_s: float
    x: float
    y: float
    confidence: float
    radius_m: float
    cell: int
    check: str = "flown"


@dataclass(frozen=True)
class Step:
    """One tick's answer.

    ``waypoints``: the (x, y) points to fly from now on, the first being the current target;
    ``()`` means hold where you are; None means unchanged since the last step that gave some.
    ``state``: ``"search"`` (looking for the plume), ``"trace"``, ``"lost"`` or ``"declared"``
    (a ``MissionState``, which compares equal to those strings). ``estimate``: the map's most
    likely source cell (``.x``, ``.y``, ``.probability``, also ``.cell``, ``.entropy``).
    ``declared``: None until the source is declared, then the declaration on every later step.
    ``detected``: whether this tick's peak reading reached ``sensor.threshold``.
    ``events``: what happened this tick (plume found, lost, source declared), for logs and
    messages; ``observation``: the tick's fused observation.
    """

    time_s: float
    waypoints: tuple[tuple[float, float], ...] | None
    state: MissionState
    estimate: Estimate
    declared: Declaration | None
    detected: bool
    events: tuple[MissionEvent, ...]
    observation: Observation


class Search:
    """One search mission with one configuration: the mapper, the mission state machine and the
    planner behind four calls (``add_position``, ``add_flow``, ``add_chemical``, ``tick``)."""

    def __init__(self, config: Config, *, admit: Callable[[int], bool] | None = None) -> None:
        """``admit``: a filter of the cells a declaration may name (benchmark bounds only; a
        vehicle has none)."""
        self.config = config
        self.grid = Grid.from_config(config.area)
        self._division = model_division(self.grid)
        self.model_grid = self.grid.subdivided(*self._division)
        """The finer grid the source is modelled and searched on (``grid.model_division``); the
        maps and estimates given out are summed back onto ``grid``, the configured area's."""
        self._mapper = mapper_from_config(config, self.model_grid)
        if admit is not None:
            user_admit = admit
            admit = lambda cell: user_admit(self.grid.cell_of(*self.model_grid.centre(cell)))  # noqa: E731
        self._mission = Mission.from_config(config, self.model_grid, self._mapper, admit=admit)
        self._aggregator = TickAggregator(
            config.sensor.threshold,
            max_position_age_s=2.0 * config.mapping.tick_s,
            response_s=config.sensor.response_s,
        )
        self._gaps: tuple[str, ...] = ()
        self._lead = Lead(self.model_grid)
        self._plan: tuple[Waypoint, ...] = ()
        self._hold = False
        self._last_position: Position | None = None
        self._heading_rad = 0.0
        self._declared: Declaration | None = None

    # -- input ------------------------------------------------------------------------------

    def add_position(self, t_s: float, x_m: float, y_m: float, *, heading_rad: float | None = None) -> None:
        """The vehicle's position (map frame, m) at ``t_s``; ``heading_rad`` (from East,
        counter-clockwise) if known, otherwise the heading is taken from the track."""
        _check_finite("position", t_s, x_m, y_m)
        if heading_rad is not None:
            _check_finite("heading", heading_rad)
            self._heading_rad = heading_rad
        self.add(Position(t_s, x_m, y_m))

    def add_flow(self, t_s: float, u_mps: float, v_mps: float) -> None:
        """The flow at the vehicle: the velocity the fluid moves toward (map frame, m/s)."""
        _check_finite("flow", t_s, u_mps, v_mps)
        self.add(FlowSample(t_s, u_mps, v_mps))

    def add_chemical(self, t_s: float, value: float) -> None:
        """A chemical reading; the tick's peak is compared with ``sensor.threshold``."""
        _check_finite("chemical reading", t_s, value)
        self.add(ChemSample(t_s, value))

    def add_detection(self, t_s: float, detected: bool) -> None:
        """A binary detector's answer, for a sensor that thresholds by itself."""
        _check_finite("detection time", t_s)
        self.add(DetectionSample(t_s, bool(detected)))

    def add(self, sample: Sample) -> None:
        """A typed sample (as the service's MAVLink decoder makes them); positions also move the
        heading on unless one was given."""
        if isinstance(sample, Position):
            last = self._last_position
            if last is not None:
                dx, dy = sample.x - last.x, sample.y - last.y
                if math.hypot(dx, dy) > HEADING_MIN_MOVE_M:
                    self._heading_rad = math.atan2(dy, dx)
            self._last_position = sample
        self._aggregator.add(sample)

    # -- the tick ---------------------------------------------------------------------------

    def tick(self, t_s: float, *, vehicle: tuple[float, float, float] | None = None) -> Step | None:
        """Fuse the samples since the last tick, move the mission on and plan.

        Returns None when the tick has no observation: no position (or only one older than two
        ticks), no flow or no chemical reading since the last tick (``gaps`` says which); the
        map is then not touched. ``vehicle``: the vehicle's (x, y, heading_rad) now, when the
        caller knows it better than the last position (a simulator does); by default the last
        position and the heading."""
        tick = self._aggregator.close(t_s)
        self._gaps = tick.gaps
        obs = tick.observation
        if obs is None:
            return None
        if vehicle is None:
            vehicle = (obs.x, obs.y, self._heading_rad)
        x, y = self._lead.planning_point(obs.time_s, vehicle[0], vehicle[1], self._plan)
        out = self._mission.step(obs, VehicleState(x, y, vehicle[2]))
        if out.waypoints is not None:
            self._plan = out.waypoints
        self._hold = out.hold
        events = tuple(self._on_grid(event) for event in out.events)
        for event in events:
            if isinstance(event, SourceDeclared) and self._declared is None:
                self._declared = self._declaration(event)
        waypoints = None if out.waypoints is None else tuple((w.x, w.y) for w in out.waypoints)
        return Step(
            time_s=obs.time_s,
            waypoints=waypoints,
            state=out.state,
            estimate=self.estimate(),
            declared=self._declared,
            detected=obs.detected,
            events=events,
            observation=obs,
        )

    def setpoint(self, t_s: float, position: tuple[float, float] | None = None) -> tuple[float, float] | None:
        """The guided target to command at ``t_s`` for the vehicle at ``position`` (default: the last
        position given): the current plan's first waypoint, or for an autopilot that stops short of
        its targets a point far enough ahead along the plan (``planning.lead``). None while there
        is no plan (nothing to command). Call it at the setpoint rate: it also watches the vehicle
        for stops short of its target."""
        if position is None:
            last = self._last_position
            if last is None:
                return None
            position = (last.x, last.y)
        target = self._lead.setpoint(t_s, *position, self._plan, hold=self._hold)
        return None if target is None else (target.x, target.y)

    def speed_mps(self, cruise_mps: float) -> float:
        """The guided speed the service asks of a vehicle that cruises at ``cruise_mps``: at most
        ``vehicle.max_speed_mps`` (0: no cap), never faster than its cruise. The map is updated once
        a second on cells of a metre (docs/search-steps.md, steps 48 and 49)."""
        cap = self.config.vehicle.max_speed_mps
        return cruise_mps if cap <= 0.0 else min(cruise_mps, cap)

    @property
    def plan(self) -> tuple[Waypoint, ...]:
        """The mission's current waypoints, in the order it means to fly them (empty before the
        first plan, or when it has nowhere to go)."""
        return self._plan

    @property
    def arrival_radius_m(self) -> float:
        """How far short of its targets the autopilot has been seen to stop (0 until it has):
        setpoints lead it by that much (``planning.lead``)."""
        return self._lead.radius_m

    def update_map(self, observation: Observation) -> None:
        """Fuse an already aggregated tick into the maps only, without the mission (replay: a
        recording holds the observations the mapper used, not the vehicle's heading)."""
        self._mapper.update(observation)

    # -- what it knows ------------------------------------------------------------------------

    @property
    def heading_rad(self) -> float:
        """The vehicle's heading (from East, counter-clockwise): the last one given, otherwise the
        direction of the last move of the track."""
        return self._heading_rad

    @property
    def gaps(self) -> tuple[str, ...]:
        """What the last tick lacked: any of ``"position"``, ``"flow"``, ``"chemical"``."""
        return self._gaps

    @property
    def state(self) -> MissionState:
        return self._mission.state

    @property
    def declared(self) -> Declaration | None:
        return self._declared

    @property
    def likelihood(self) -> FloatArray:
        """The source likelihood map pi, shape (rows, columns), row 0 the southern row."""
        return self.grid.coarsened(self._mapper.likelihood, *self._division)

    @property
    def plume(self) -> FloatArray:
        """The plume likelihood map alpha, shape (rows, columns)."""
        return self.grid.coarsened(self._mapper.plume, *self._division)

    def estimate(self) -> Estimate:
        """The map's most likely source cell now."""
        return estimate_of(self.likelihood, self.grid)

    @property
    def mapper(self) -> SourceMapper:
        """The mapper itself (the service saves and restores its state across restarts)."""
        return self._mapper

    @property
    def mission(self) -> Mission:
        """The mission state machine itself (saved and restored with the mapper)."""
        return self._mission

    def _on_grid(self, event: MissionEvent) -> MissionEvent:
        """The event with any cell number on ``grid`` (the mission's are on ``model_grid``)."""
        if isinstance(event, SourceDeclared):
            return replace(event, cell=self.grid.paper_number(self.grid.cell_of(event.x, event.y)))
        return event

    def _declaration(self, event: SourceDeclared) -> Declaration:
        radius_m = self.config.declaration.radius_m + 0.5 * math.hypot(
            self.model_grid.cell_width_m, self.model_grid.cell_height_m
        )
        return Declaration(event.time_s, event.x, event.y, event.mass, radius_m, event.cell, str(event.check))


def _check_finite(what: str, *values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what}: non-finite value in {values}")
