"""Search benchmark: seeded closed-loop missions in one process, and their statistics.

``run_mission`` is the in-process closed loop: the same ``service.api.Search`` as the service
(the configured mapper and planner, the mission, the tick aggregation) against the simulated
``World`` of a scenario, with no sockets and no clock. Within each mapping tick the world is
stepped at its own rate (10 Hz) and sampled at the telemetry rate the service asks for
(``mavlink.stream_hz``): position, flow and chemical reading go into the search exactly as the
MAVLink edge puts them, so the observation is the tick's mean flow and thresholded peak reading
(seed hmm-plume-mapping §III-A). The vehicle flies to the first of the mission's waypoints, as
the service commands it. Everything random (start, plume, flow noise, detector) comes from the
seed.

A mission ends at its first declaration or at ``max_time_s``. It *succeeds* when the declared
cell is within one cell (column and row) of the source's cell; a declaration farther away is a
*wrong declaration* (and the mission then has failed: the vehicle holds). Times to declaration
are summarised over all runs with a failed run counted as never declared, so the median and
p90 are only finite when at least half / 90 % of the runs succeeded.

Each failure is put in one class, so a configuration that misses its target says where its time
went: the plume was never smelled; it was, but the vehicle never came within one cell of the
source's cell; came there, but not declared (and whether the map's estimate was on the source at
the end, i.e. the declaration rule was still waiting); or a wrong declaration.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from service.api import Declaration, Search, Step
from service.core.config import Config, MappingMethod, PlanningMethod
from service.core.errors import ConfigError
from service.core.grid import Grid
from service.core.mapping.belief import FloatArray
from service.core.mission import MissionState
from service.tools.bench.workers import in_order
from sim_bridge.autopilot import VehicleKind
from sim_bridge.scenarios import Scenario, build_world, load_scenario, place

DEFAULT_MAX_TIME_S = 300.0
"""Seed hmm-plume-mapping §VI: "typically less than 300 s at 1 m/s"; the wang scenarios' Table I
times (121-270 s) fit within it too."""

JSON_KEYS = (
    "scenario",
    "mapper",
    "planner",
    "runs",
    "success_rate",
    "median_time_s",
    "p90_time_s",
    "median_path_m",
    "wrong_declarations",
)


@dataclass(frozen=True)
class TrackPoint:
    """One tick of a recorded mission (for the report's pictures)."""

    time_s: float
    x: float
    y: float
    detected: bool
    state: MissionState
    estimate_x: float
    estimate_y: float
    probability: float


@dataclass(frozen=True)
class MissionTrace:
    """What a recorded mission leaves for pictures: the track, the final maps and plume."""

    track: tuple[TrackPoint, ...]
    likelihood: FloatArray
    """The source likelihood map pi at the end, shape (rows, columns)."""
    plume_puffs: FloatArray
    """Live puffs (x, y) at the end, shape (N, 2)."""


@dataclass(frozen=True)
class MissionResult:
    """One seeded mission."""

    seed: int
    source_x: float
    source_y: float
    declared: bool
    correct: bool
    """Declared within one cell of the source's cell."""
    time_s: float
    """Time of the declaration, or the time the mission was stopped."""
    declared_x: float | None
    declared_y: float | None
    error_m: float | None
    """Distance from the declared cell's centre to the true source."""
    path_m: float
    """Distance the vehicle travelled until the declaration or the stop."""
    first_detection_s: float | None
    reached_s: float | None = None
    """When the vehicle first stood within one cell of the source's cell; None if it never did."""
    estimate_on_source: bool = False
    """Whether the map's estimate at the end was within one cell of the source's cell."""
    confidence: float | None = None
    """The declaration's stated probability that the source lies within ``radius_m`` of it."""
    radius_m: float | None = None
    vehicle_speed_mps: float | None = None
    """The simulated vehicle's cruise speed (the suite's time limits shrink with it)."""
    check: str | None = None
    """How the declared cell was vouched for (``Declaration.check``): ``endurance`` when it was
    named as the time ran out, on the map's mass alone."""
    trace: MissionTrace | None = field(default=None, compare=False)

    @property
    def within_stated_radius(self) -> bool:
        """Whether a declaration's statement came true (the source within its stated radius)."""
        return self.error_m is not None and self.radius_m is not None and self.error_m <= self.radius_m

    @property
    def wrong(self) -> bool:
        return self.declared and not self.correct

    @property
    def failure(self) -> FailureClass | None:
        """Where a failed mission stopped short; None for a success."""
        if self.correct:
            return None
        if self.declared:
            return FailureClass.WRONG
        if self.first_detection_s is None:
            return FailureClass.NEVER_DETECTED
        if self.reached_s is None:
            return FailureClass.NOT_REACHED
        return FailureClass.UNDECLARED_AT_SOURCE


class FailureClass(StrEnum):
    """The one class of a failed mission (JSON key of its count)."""

    NEVER_DETECTED = "never_detected"
    """No detection before the time limit."""
    NOT_REACHED = "not_reached"
    """Smelled the plume but never came within one cell of the source's cell."""
    UNDECLARED_AT_SOURCE = "undeclared_at_source"
    """Came within one cell of the source's cell and still declared nothing."""
    WRONG = "wrong"
    """Declared a cell more than one cell from the source's."""


@dataclass(frozen=True)
class MissionSpec:
    """Everything a worker process needs to rebuild one mission (picklable)."""

    scenario: str
    mapper: str
    planner: str
    seed: int
    max_time_s: float = DEFAULT_MAX_TIME_S
    overrides: tuple[str, ...] = ()
    oracle: bool = False


def configure(scenario: str, mapper: str, planner: str, overrides: Sequence[str] = ()) -> Scenario:
    """The scenario with ``mapping.method`` and ``planning.method`` set (overrides applied last)."""
    return load_scenario(scenario, [f"mapping.method={mapper}", f"planning.method={planner}", *overrides])


def within_one_cell(grid: Grid, x: float, y: float, source_x: float, source_y: float) -> bool:
    """Whether (x, y) lies in the source's cell or one of its eight neighbours."""
    row_a, col_a = grid.row_col(grid.cell_of(x, y))
    row_b, col_b = grid.row_col(grid.cell_of(source_x, source_y))
    return abs(row_a - row_b) <= 1 and abs(col_a - col_b) <= 1


def with_endurance(config: Config, max_time_s: float) -> Config:
    """``config`` with the vehicle's endurance at ``max_time_s``, the mission's time limit (or at
    the configured endurance, when that is shorter)."""
    configured = config.vehicle.endurance_s
    endurance = max_time_s if configured <= 0.0 else min(configured, max_time_s)
    return config.model_copy(update={"vehicle": config.vehicle.model_copy(update={"endurance_s": endurance})})


def run_mission(
    scenario: Scenario,
    seed: int,
    *,
    max_time_s: float = DEFAULT_MAX_TIME_S,
    record: bool = False,
    oracle: bool = False,
    on_tick: Callable[[Search, Step], None] | None = None,
) -> MissionResult:
    """One closed-loop mission of ``scenario`` drawn from ``seed``; ``record`` keeps a trace;
    ``on_tick`` is shown the service and each tick's step (what a diagnostic measures).

    With ``oracle`` the declaration has a perfect guard: a rule that fires for a cell more than one
    cell from the true source is ignored. No vehicle has one; it bounds what any guard against
    wrong declarations (``declaration.upflow_pass_m``, ``check_width_m``) can gain."""
    config, grid = with_endurance(scenario.config, max_time_s), scenario.grid
    world = build_world(scenario, seed)
    source = place(scenario, seed).source_m

    def at_source(cell: int) -> bool:
        return within_one_cell(grid, *grid.centre(cell), *source)

    search = Search(config, admit=at_source if oracle else None)
    steps_per_tick = max(1, round(config.mapping.tick_s / world.dt_s))
    sample_every = max(1, round(1.0 / (config.mavlink.stream_hz * world.dt_s)))
    command_every = max(1, round(1.0 / (config.mavlink.setpoint_rate_hz * world.dt_s)))
    world.driving = True
    if scenario.world.vehicle.kind is VehicleKind.ROVER:  # the service caps Rovers only (ROVER_TYPES)
        # the speed it asks of an ArduPilot Rover that cruises faster, with its first setpoint
        world.speed_mps = search.speed_mps(world.vehicle_params.speed_mps)

    path_m = 0.0
    step_count = 0
    first_detection: float | None = None
    reached: float | None = None
    declaration: Declaration | None = None
    track: list[TrackPoint] = []
    while world.time_s < max_time_s - 1e-9 and declaration is None:
        for _ in range(steps_per_tick):
            x0, y0 = world.vehicle.x_m, world.vehicle.y_m
            world.step()
            step_count += 1
            path_m += math.hypot(world.vehicle.x_m - x0, world.vehicle.y_m - y0)
            if step_count % sample_every == 0:
                t = world.time_s
                flow_x, flow_y = world.flow_at_vehicle()
                search.add_position(t, *world.position_reading())
                search.add_flow(t, flow_x, flow_y)
                search.add_chemical(t, world.chem_reading())
            if step_count % command_every == 0:
                # the service re-sends its target at the setpoint rate, from the latest position
                world.target_m = search.setpoint(world.time_s, world.position_reading())
        v = world.vehicle
        believed = world.position_reading()
        # the planner starts from where the simulated vehicle is now (as its autopilot believes),
        # as the service's does
        step = search.tick(world.time_s, vehicle=(*believed, v.heading_rad))
        if step is None:  # cannot happen with every stream sampled; kept for a sampling rate < 1/tick
            continue
        world.target_m = search.setpoint(world.time_s, believed)
        if on_tick is not None:
            on_tick(search, step)
        if step.detected and first_detection is None:
            first_detection = step.time_s
        if reached is None and grid.contains(v.x_m, v.y_m) and within_one_cell(grid, v.x_m, v.y_m, *source):
            reached = step.time_s
        declaration = step.declared
        if record:
            obs, est = step.observation, step.estimate
            track.append(
                TrackPoint(obs.time_s, obs.x, obs.y, obs.detected, step.state, est.x, est.y, est.probability)
            )

    trace = None
    if record:
        puffs = world.plume.puffs()
        trace = MissionTrace(tuple(track), np.array(search.likelihood), np.array(puffs[:, :2]))
    estimate = search.estimate()
    on_source = within_one_cell(grid, estimate.x, estimate.y, *source)
    speed = scenario.world.vehicle.speed_mps
    if declaration is None:
        return MissionResult(
            seed=seed,
            source_x=source[0],
            source_y=source[1],
            declared=False,
            correct=False,
            time_s=world.time_s,
            declared_x=None,
            declared_y=None,
            error_m=None,
            path_m=path_m,
            first_detection_s=first_detection,
            reached_s=reached,
            estimate_on_source=on_source,
            vehicle_speed_mps=speed,
            trace=trace,
        )
    return MissionResult(
        seed=seed,
        source_x=source[0],
        source_y=source[1],
        declared=True,
        correct=within_one_cell(grid, declaration.x, declaration.y, *source),
        time_s=declaration.time_s,
        declared_x=declaration.x,
        declared_y=declaration.y,
        error_m=math.hypot(declaration.x - source[0], declaration.y - source[1]),
        path_m=path_m,
        first_detection_s=first_detection,
        reached_s=reached,
        estimate_on_source=on_source,
        confidence=declaration.confidence,
        radius_m=declaration.radius_m,
        vehicle_speed_mps=speed,
        check=declaration.check,
        trace=trace,
    )


def run_spec(spec: MissionSpec) -> MissionResult:
    """``run_mission`` from a picklable description (the process pool's task)."""
    scenario = configure(spec.scenario, spec.mapper, spec.planner, spec.overrides)
    return run_mission(scenario, spec.seed, max_time_s=spec.max_time_s, oracle=spec.oracle)


@dataclass(frozen=True)
class SearchSummary:
    """The statistics of one configuration over its runs."""

    scenario: str
    mapper: str
    planner: str
    runs: int
    success_rate: float
    median_time_s: float | None
    """Median time to a correct declaration, failed runs counted as never; None if infinite."""
    p90_time_s: float | None
    median_path_m: float
    wrong_declarations: int
    undeclared: int
    max_time_s: float
    failures: dict[FailureClass, int] = field(default_factory=dict)
    """Failed runs per class (every class present, zeros included)."""
    undeclared_estimate_on_source: int = 0
    """Of the ``undeclared_at_source`` failures, those whose estimate was on the source at the end."""
    median_first_detection_s: float | None = None
    """Median time of the first detection, runs without one counted as never."""
    reached_rate: float = 0.0
    """Share of runs in which the vehicle came within one cell of the source's cell."""

    def as_row(self) -> dict[str, Any]:
        """The JSON object of ``oslim bench search --json`` (keys ``JSON_KEYS`` first)."""
        row: dict[str, Any] = {key: getattr(self, key) for key in JSON_KEYS}
        row["undeclared"] = self.undeclared
        row["max_time_s"] = self.max_time_s
        row["failures"] = {str(kind): self.failures.get(kind, 0) for kind in FailureClass}
        row["undeclared_estimate_on_source"] = self.undeclared_estimate_on_source
        row["median_first_detection_s"] = self.median_first_detection_s
        row["reached_rate"] = self.reached_rate
        return row

    def failure_line(self) -> str:
        """The failures by class, in words (the text output's second line per configuration)."""
        n = self.failures
        failed = sum(n.values())
        first = self.median_first_detection_s
        return (
            f"{failed} failed: {n.get(FailureClass.NEVER_DETECTED, 0)} never smelled the plume, "
            f"{n.get(FailureClass.NOT_REACHED, 0)} smelled it but never came within a cell of the source, "
            f"{n.get(FailureClass.UNDECLARED_AT_SOURCE, 0)} came there but declared nothing "
            f"({self.undeclared_estimate_on_source} with the estimate on the source at the end), "
            f"{n.get(FailureClass.WRONG, 0)} wrong; first detection median "
            f"{'never' if first is None else f'{first:.0f} s'}, "
            f"within a cell of the source in {self.reached_rate:.1%} of runs"
        )


def _quantile_or_none(times: Sequence[float], q: float) -> float | None:
    value = float(np.quantile(np.asarray(times, dtype=float), q, method="inverted_cdf"))
    return value if math.isfinite(value) else None


def summarise(
    scenario: str, mapper: str, planner: str, results: Sequence[MissionResult], max_time_s: float
) -> SearchSummary:
    """Success rate, time quantiles (failures as never), median path, wrong declarations."""
    if not results:
        raise ValueError("no runs to summarise")
    times = [r.time_s if r.correct else math.inf for r in results]
    classes = [r.failure for r in results]
    return SearchSummary(
        scenario=scenario,
        mapper=mapper,
        planner=planner,
        runs=len(results),
        success_rate=sum(r.correct for r in results) / len(results),
        median_time_s=_quantile_or_none(times, 0.5),
        p90_time_s=_quantile_or_none(times, 0.9),
        median_path_m=float(np.median([r.path_m for r in results])),
        wrong_declarations=sum(r.wrong for r in results),
        undeclared=sum(not r.declared for r in results),
        max_time_s=max_time_s,
        failures={kind: classes.count(kind) for kind in FailureClass},
        undeclared_estimate_on_source=sum(
            c is FailureClass.UNDECLARED_AT_SOURCE and r.estimate_on_source
            for c, r in zip(classes, results, strict=True)
        ),
        median_first_detection_s=_quantile_or_none(
            [math.inf if r.first_detection_s is None else r.first_detection_s for r in results], 0.5
        ),
        reached_rate=sum(r.reached_s is not None for r in results) / len(results),
    )


ALL = "all"


def expand(names: Iterable[str] | None, every: Iterable[str], default: str) -> list[str]:
    """Resolve repeated ``--mapper`` / ``--planner`` values; ``all`` means every one."""
    chosen = list(names or [default])
    known = list(every)
    if ALL in chosen:
        return known
    unknown = [n for n in chosen if n not in known]
    if unknown:
        raise ConfigError(f"unknown name(s) {', '.join(unknown)}; choose from {', '.join(known)} or all")
    return list(dict.fromkeys(chosen))


def mapper_names() -> list[str]:
    return [m.value for m in MappingMethod]


def planner_names() -> list[str]:
    return [p.value for p in PlanningMethod]


def run_configurations(
    scenario: str,
    mappers: Sequence[str],
    planners: Sequence[str],
    runs: int,
    *,
    jobs: int | None = None,
    max_time_s: float = DEFAULT_MAX_TIME_S,
    overrides: Sequence[str] = (),
    first_seed: int = 0,
    oracle: bool = False,
    progress: Callable[[int], None] = lambda _: None,
) -> Iterable[tuple[SearchSummary, list[MissionResult]]]:
    """Every mapper x planner configuration over seeds first_seed..first_seed+runs-1 (a second
    set of seeds checks that a setting chosen on the first did not just fit those missions), in a
    pool of ``jobs`` processes (default: the cores); yields each configuration's summary as soon
    as its runs are done. ``oracle``: every mission with the perfect declaration guard (``run_mission``).
    ``progress`` is told of every mission done."""
    if runs < 1:
        raise ValueError("runs must be >= 1")
    if first_seed < 0:
        raise ValueError("first_seed must be >= 0")
    configure(scenario, mappers[0], planners[0], overrides)  # fail early on a bad name or key
    configs = [(m, p) for m in mappers for p in planners]
    specs = [
        MissionSpec(scenario, m, p, seed, max_time_s, tuple(overrides), oracle)
        for m, p in configs
        for seed in range(first_seed, first_seed + runs)
    ]
    results = in_order(run_spec, specs, jobs, progress)
    for m, p in configs:
        batch = [next(results) for _ in range(runs)]
        yield summarise(scenario, m, p, batch, max_time_s), batch
