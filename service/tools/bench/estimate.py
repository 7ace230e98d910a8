"""Where the map's estimate was while a suite mission traced, grouped by how the mission ended.

The suite says where a failed mission stopped (never smelled, not reached, undeclared at the
source, wrong); this says why, from the map. Each tick in ``trace`` or ``lost`` puts the mapper's
greatest cell in one of four places: at the source (within one cell of the source's cell, the
suite's own test) with the declaration's mass around it, so that only a guard (the visit, the
upflow pass, the check across the flow) holds it back; at the source without that
mass; away from it downflow; or away upflow or beside (along the world's mean flow). Two further
counts overlap those: the estimate within ``AT_ODOUR_M`` of a detection the mission had made
(the map placed the source at the odour it met), and a flat map, no cell above ``FLAT_RATIO``
times the uniform share. Missions that end undeclared at the source with most of their ticks
away from it fail on the map, not on the guards.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from service.api import Search, Step
from service.core.mission.events import MissionState
from service.core.planning.declaration import mass_within
from service.tools.bench.search import run_mission, within_one_cell
from service.tools.bench.suite import SuiteMission, drawn_world, source_frame
from service.tools.bench.workers import in_order_by_batch

AT_ODOUR_M = 5.0
"""An estimate this close to a detection of the mission counts as placed at the odour."""
FLAT_RATIO = 5.0
"""A map whose greatest cell holds less than this many times the uniform share is flat."""
TRACED = (MissionState.TRACE, MissionState.LOST)
SUCCESS = "success"


@dataclass
class Places:
    """Ticks traced, and where the estimate was in them (the first four partition ``traced``)."""

    traced: int = 0
    at_source_with_mass: int = 0
    at_source: int = 0
    away_downflow: int = 0
    away_upflow_or_beside: int = 0
    at_odour: int = 0
    flat: int = 0

    def add(self, other: Places) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))


@dataclass
class Outcome:
    """The missions that ended one way (``SUCCESS`` or a ``FailureClass``) and their ticks."""

    outcome: str
    missions: int = 0
    places: Places = field(default_factory=Places)

    def as_row(self) -> dict[str, Any]:
        return {"outcome": self.outcome, "missions": self.missions, **vars(self.places)}


def mission_places(spec: SuiteMission) -> tuple[str, Places]:
    """How one suite mission ended, and where its estimate was while it traced (a worker's task)."""
    drawn = drawn_world(spec)
    frame = source_frame(drawn, spec.seed)
    sx, sy = frame.source
    area = drawn.scenario.grid
    places = Places()
    odour: list[tuple[float, float]] = []

    def record(search: Search, step: Step) -> None:
        obs = step.observation
        if obs.detected:
            odour.append((obs.x, obs.y))
        if step.state not in TRACED:
            return
        grid, pi = search.model_grid, np.asarray(search.mapper.likelihood)
        cell = int(np.argmax(pi))
        ex, ey = grid.centre(cell)
        places.traced += 1
        if within_one_cell(area, ex, ey, sx, sy):
            decl = search.config.declaration.for_mapper(search.mapper.name)  # as the mission's rule
            if mass_within(grid, pi, cell, decl.radius_m) >= decl.probability:
                places.at_source_with_mass += 1
            else:
                places.at_source += 1
        elif frame.along_across(ex, ey)[0] > 0.0:
            places.away_downflow += 1
        else:
            places.away_upflow_or_beside += 1
        if any(math.hypot(ex - x, ey - y) <= AT_ODOUR_M for x, y in odour):
            places.at_odour += 1
        if float(pi.max()) * pi.size < FLAT_RATIO:
            places.flat += 1

    result = run_mission(drawn.scenario, spec.seed, max_time_s=drawn.time_limit_s, on_tick=record)
    failure = result.failure
    return (SUCCESS if failure is None else str(failure)), places


def outcomes(ended: Sequence[tuple[str, Places]]) -> list[Outcome]:
    """The missions grouped by how they ended: successes first, then each failure class met."""
    grouped: dict[str, Outcome] = {}
    for name, places in ended:
        group = grouped.setdefault(name, Outcome(name))
        group.missions += 1
        group.places.add(places)
    return sorted(grouped.values(), key=lambda o: (o.outcome != SUCCESS, o.outcome))


def run(
    batches: Sequence[tuple[str, list[SuiteMission]]], jobs: int | None = None
) -> Iterator[tuple[str, list[tuple[str, Places]]]]:
    """(class, (outcome, places) of each of its missions) for each class of ``batches``
    (``suite.class_missions``), in order."""
    return in_order_by_batch(mission_places, batches, jobs)
