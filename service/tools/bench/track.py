"""One suite mission tick by tick, in the true source's frame: what a failed mission did.

The suite and its diagnostics (``phases``, ``estimate``) summarise many missions; why one of them
failed is in its ticks. Each tick gives where the vehicle was and whether it smelled odour, the
mission's state, where the map put the source, the share of the map that cell holds, and the mass
within the declaration's radius of it (what the rule waits for). Positions are along and across
the world's mean flow from the true source, along > 0 downflow of it, so that a map sitting on a
contact downflow of the source, or a crossing of the source's line far downflow without odour,
reads at a glance (docs/search-steps.md, step 42).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.api import Search, Step
from service.core.planning.declaration import mass_within
from service.tools.bench.search import run_mission
from service.tools.bench.suite import SuiteMission, drawn_world, source_frame, time_limit_s

SUCCESS = "success"


@dataclass(frozen=True)
class TrackTick:
    """One tick: the vehicle and the map's estimate, along and across the mean flow from the source."""

    time_s: float
    state: str
    along_m: float
    across_m: float
    detected: bool
    estimate_along_m: float
    estimate_across_m: float
    estimate_share: float
    """The share of the map the estimated cell holds."""
    mass: float
    """The map's mass within the declaration's ``radius_m`` of the estimated cell."""

    def as_row(self) -> dict[str, Any]:
        return {
            "time_s": self.time_s,
            "state": self.state,
            "along_m": round(self.along_m, 2),
            "across_m": round(self.across_m, 2),
            "detected": self.detected,
            "estimate_along_m": round(self.estimate_along_m, 2),
            "estimate_across_m": round(self.estimate_across_m, 2),
            "estimate_share": round(self.estimate_share, 4),
            "mass": round(self.mass, 4),
        }


@dataclass(frozen=True)
class MissionTrack:
    """A suite mission's outcome and its ticks."""

    seed: int
    limit_s: float
    outcome: str
    """``SUCCESS`` or the suite's failure class (``never_detected``, ``not_reached``, ...)."""
    time_s: float
    first_odour_s: float | None
    reached_s: float | None
    error_m: float | None
    ticks: tuple[TrackTick, ...]

    def summary(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "limit_s": round(self.limit_s, 1),
            "outcome": self.outcome,
            "time_s": self.time_s,
            "first_odour_s": self.first_odour_s,
            "reached_s": self.reached_s,
            "error_m": None if self.error_m is None else round(self.error_m, 2),
            "detections": sum(t.detected for t in self.ticks),
        }


def mission_track(spec: SuiteMission) -> MissionTrack:
    """One suite mission run to its time limit (times ``spec.time_scale``), every tick recorded."""
    drawn = drawn_world(spec)
    frame = source_frame(drawn, spec.seed)
    ticks: list[TrackTick] = []

    def record(search: Search, step: Step) -> None:
        grid, pi = search.model_grid, np.asarray(search.mapper.likelihood)
        cell = int(np.argmax(pi))
        decl = search.config.declaration.for_mapper(search.mapper.name)  # the radius the rule uses
        obs = step.observation
        along, across = frame.along_across(obs.x, obs.y)
        est_along, est_across = frame.along_across(*grid.centre(cell))
        mass = mass_within(grid, pi, cell, decl.radius_m)
        ticks.append(
            TrackTick(
                step.time_s,
                str(step.state),
                along,
                across,
                obs.detected,
                est_along,
                est_across,
                float(pi.flat[cell]),
                mass,
            )
        )

    limit = time_limit_s(spec, drawn)
    result = run_mission(drawn.scenario, spec.seed, max_time_s=limit, on_tick=record)
    failure = result.failure
    return MissionTrack(
        seed=spec.seed,
        limit_s=limit,
        outcome=SUCCESS if failure is None else str(failure),
        time_s=result.time_s,
        first_odour_s=result.first_detection_s,
        reached_s=result.reached_s,
        error_m=result.error_m,
        ticks=tuple(ticks),
    )


def shown(ticks: tuple[TrackTick, ...], every_s: float) -> list[TrackTick]:
    """The ticks worth a line: one each ``every_s`` seconds, each detection, each change of state,
    and the last; every tick when ``every_s`` <= 0."""
    if every_s <= 0:
        return list(ticks)
    out: list[TrackTick] = []
    next_s = -math.inf  # the first tick is shown
    for i, tick in enumerate(ticks):
        due = tick.time_s >= next_s
        if due:
            next_s = (math.floor(tick.time_s / every_s) + 1) * every_s
        changed = i > 0 and tick.state != ticks[i - 1].state
        if due or tick.detected or changed or i == len(ticks) - 1:
            out.append(tick)
    return out
