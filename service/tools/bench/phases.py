"""Where a suite mission's time goes: to the first odour, on to the source, at the source until
the declaration's rule fires, and in the check across the flow that vouches for the cell.

With twice their time most failures outside patchy succeed (``oslim bench suite --time-scale
2``): what limits those classes is time. This splits each mission's time at the suite's own marks
(the first detection; the first tick within one cell of the source's cell) and the mission's (a
check across the flow begins when the rule fires; the source is declared when a check is flown),
so that a change meant to save time can be aimed at the phase that costs it.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from service.api import Search, Step
from service.tools.bench.search import run_mission
from service.tools.bench.suite import SuiteMission, drawn_world, time_limit_s
from service.tools.bench.workers import in_order_by_batch


@dataclass(frozen=True)
class Phases:
    """One mission's marks, in seconds from its start (None: not reached)."""

    vehicle: str
    """The simulated vehicle's kind: ``rover`` (turns on the spot) or ``auv`` (slows to turn)."""
    limit_s: float
    correct: bool
    first_odour_s: float | None
    at_source_s: float | None
    rule_at_source_s: float | None
    """The first check across the flow begun at or after ``at_source_s``."""
    last_check_s: float | None
    """When the last check across the flow began (for a declaration, the check that vouched)."""
    checks: int
    """Checks begun: the rule fired at that many cells, or again at one after a call-off."""
    check_ticks: int
    declared_s: float | None

    @property
    def to_source_s(self) -> float | None:
        if self.first_odour_s is None or self.at_source_s is None:
            return None
        return max(0.0, self.at_source_s - self.first_odour_s)  # a vehicle can pass the source unsmelt

    @property
    def to_rule_s(self) -> float | None:
        return _span(self.at_source_s, self.rule_at_source_s)

    @property
    def vouching_s(self) -> float | None:
        """The check that vouched for the declared cell, begun to flown."""
        return _span(self.last_check_s, self.declared_s)

    @property
    def at_source_to_declared_s(self) -> float | None:
        return _span(self.at_source_s, self.declared_s)


def _span(start: float | None, end: float | None) -> float | None:
    return None if start is None or end is None else end - start


def mission_phases(spec: SuiteMission) -> Phases:
    """One suite mission run to its time limit (times ``spec.time_scale``), with its phases marked
    (a worker's task)."""
    drawn = drawn_world(spec)
    began: list[float] = []  # when each check across the flow began
    ticks = 0
    checking = False

    def record(search: Search, step: Step) -> None:
        nonlocal checking, ticks
        now = search.mission.checking
        ticks += now
        if now and not checking:
            began.append(step.time_s)
        checking = now

    limit = time_limit_s(spec, drawn)
    result = run_mission(drawn.scenario, spec.seed, max_time_s=limit, on_tick=record)
    reached = result.reached_s
    return Phases(
        vehicle="auv" if drawn.scenario.world.vehicle.slows_to_turn else "rover",
        limit_s=limit,
        correct=result.correct,
        first_odour_s=result.first_detection_s,
        at_source_s=reached,
        rule_at_source_s=None if reached is None else next((t for t in began if t >= reached), None),
        last_check_s=began[-1] if began else None,
        checks=len(began),
        check_ticks=ticks,
        declared_s=result.time_s if result.declared else None,
    )


@dataclass(frozen=True)
class Summary:
    """A group of missions: how many, how many succeeded, and the median of each phase over the
    missions that reached it (None: none did), with how many did."""

    group: str
    missions: int
    correct: int
    limit_s: float
    first_odour: tuple[float | None, int]
    to_source: tuple[float | None, int]
    to_rule: tuple[float | None, int]
    vouching: tuple[float | None, int]
    at_source_to_declared: tuple[float | None, int]
    checks: int
    check_ticks: int

    def as_row(self) -> dict[str, Any]:
        row: dict[str, Any] = {"group": self.group, "missions": self.missions, "correct": self.correct}
        row["median_limit_s"] = self.limit_s
        for name in ("first_odour", "to_source", "to_rule", "vouching", "at_source_to_declared"):
            median, count = getattr(self, name)
            row[f"median_{name}_s"] = median
            row[f"{name}_missions"] = count
        row["checks"] = self.checks
        row["check_ticks"] = self.check_ticks
        return row


def summary(group: str, missions: Sequence[Phases]) -> Summary:
    """The medians of ``missions``' phases (the check that vouched counted on declared missions)."""

    def median(of: Callable[[Phases], float | None]) -> tuple[float | None, int]:
        values = [v for v in map(of, missions) if v is not None]
        return (statistics.median(values) if values else None), len(values)

    return Summary(
        group=group,
        missions=len(missions),
        correct=sum(m.correct for m in missions),
        limit_s=statistics.median(m.limit_s for m in missions) if missions else 0.0,
        first_odour=median(lambda m: m.first_odour_s),
        to_source=median(lambda m: m.to_source_s),
        to_rule=median(lambda m: m.to_rule_s),
        vouching=median(lambda m: m.vouching_s),
        at_source_to_declared=median(lambda m: m.at_source_to_declared_s),
        checks=sum(m.checks for m in missions),
        check_ticks=sum(m.check_ticks for m in missions),
    )


KINDS = ("rover", "auv")


def groups(by_class: dict[str, list[Phases]]) -> list[tuple[str, list[Phases]]]:
    """The groups summed over classes: ``all`` (with more than one class), then each vehicle kind
    over the classes that drew both kinds, since a class of one kind (the papers' rovers) would
    weigh its own times into that kind's row; a kind with no mission is left out."""
    out = [("all", [m for runs in by_class.values() for m in runs])] if len(by_class) > 1 else []
    mixed = [m for runs in by_class.values() if len({m.vehicle for m in runs}) > 1 for m in runs]
    out += [(kind, [m for m in mixed if m.vehicle == kind]) for kind in KINDS]
    return [(name, missions) for name, missions in out if missions]


def run(
    batches: Sequence[tuple[str, list[SuiteMission]]], jobs: int | None = None
) -> Iterator[tuple[str, list[Phases]]]:
    """(class, the phases of each of its missions) for each class of ``batches``
    (``suite.class_missions``), in order."""
    return in_order_by_batch(mission_phases, batches, jobs)
