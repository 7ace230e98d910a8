"""How well the mapper's observation model foretells the detector, in the suite's worlds.

Each tick the mapper weighs the tick's event by its own P(detection | source in cell i) under its
flow history. Taken at the true source's cell, that is the chance the model gave the detection the
vehicle then had or missed. Grouped by where the vehicle was relative to the true source (along
and across the world's mean flow), the model's mean chance and the share of ticks with a detection
should agree. Where the model says more than the detector gives, every miss there counts too much
against the true source; where it says less, every hit counts too little. The success rate of the
suite is a noisy measure of a model; this table shows the model's error where it is made.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from service.api import Search, Step
from service.tools.bench.search import run_mission
from service.tools.bench.suite import SuiteMission, drawn_world, source_frame
from service.tools.bench.workers import in_order_by_batch

ON_LINE_M = 2.0
"""A tick counts as on the source's flow line when the vehicle is at most this far across it."""
BESIDE_M = 5.0
"""... and as beside the plume when it is farther, but at most this far across."""
BANDS: tuple[tuple[str, float, float, float, float], ...] = (
    # label, along from, along to (m downflow of the source), across from, across to
    ("on the line, 10-3 m upflow", -10.0, -3.0, 0.0, ON_LINE_M),
    ("on the line, 3-1 m upflow", -3.0, -1.0, 0.0, ON_LINE_M),
    ("on the line, within 1 m of the source", -1.0, 1.0, 0.0, ON_LINE_M),
    ("on the line, 1-3 m downflow", 1.0, 3.0, 0.0, ON_LINE_M),
    ("on the line, 3-10 m downflow", 3.0, 10.0, 0.0, ON_LINE_M),
    ("on the line, 10-30 m downflow", 10.0, 30.0, 0.0, ON_LINE_M),
    ("on the line, over 30 m downflow", 30.0, math.inf, 0.0, ON_LINE_M),
    ("2-5 m across, 1 m upflow to 30 m downflow", -1.0, 30.0, ON_LINE_M, BESIDE_M),
)


@dataclass(frozen=True)
class Ticks:
    """Every tick of some missions in the area: where the vehicle was relative to the source
    (m, along and across the mean flow), the model's P(d | true source cell) and the event."""

    along_m: npt.NDArray[np.float64]
    across_m: npt.NDArray[np.float64]
    predicted: npt.NDArray[np.float64]
    detected: npt.NDArray[np.bool_]

    @classmethod
    def join(cls, parts: Sequence[Ticks]) -> Ticks:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__dataclass_fields__))


@dataclass(frozen=True)
class Band:
    """One band of positions: its ticks, the model's mean P(d) there and the share detected."""

    label: str
    ticks: int
    predicted: float | None
    detected: float | None

    def as_row(self) -> dict[str, Any]:
        return {"band": self.label, "ticks": self.ticks, "model": self.predicted, "detected": self.detected}


def mission_ticks(spec: SuiteMission) -> Ticks:
    """The ticks of one suite mission (a worker's task)."""
    drawn = drawn_world(spec)
    frame = source_frame(drawn, spec.seed)
    sx, sy = frame.source
    rows: list[tuple[float, float, float, bool]] = []

    def record(search: Search, step: Step) -> None:
        grid, obs = search.model_grid, step.observation
        if not grid.contains(obs.x, obs.y):
            return  # the mapper fuses no event from outside the area
        chance = search.mapper.detection_likelihood(grid.cell_of(obs.x, obs.y))
        row, col = grid.row_col(grid.cell_of(sx, sy))
        along, across = frame.along_across(obs.x, obs.y)
        rows.append((along, abs(across), float(chance[row, col]), obs.detected))

    run_mission(drawn.scenario, spec.seed, max_time_s=drawn.time_limit_s, on_tick=record)
    table = np.array(rows, dtype=float).reshape(-1, 4)
    return Ticks(table[:, 0], table[:, 1], table[:, 2], table[:, 3] > 0.5)


def bands(ticks: Ticks) -> list[Band]:
    """The model's mean P(d) and the detected share in each of ``BANDS``."""
    out = []
    for label, a0, a1, c0, c1 in BANDS:
        inside = (ticks.along_m >= a0) & (ticks.along_m < a1) & (ticks.across_m >= c0) & (ticks.across_m < c1)
        n = int(inside.sum())
        out.append(
            Band(
                label,
                n,
                float(ticks.predicted[inside].mean()) if n else None,
                float(ticks.detected[inside].mean()) if n else None,
            )
        )
    return out


def run(
    batches: Sequence[tuple[str, list[SuiteMission]]], jobs: int | None = None
) -> Iterator[tuple[str, Ticks]]:
    """Each class's ticks over its missions (``suite.class_missions``), in order."""
    for name, ticks in in_order_by_batch(mission_ticks, batches, jobs):
        yield name, Ticks.join(ticks)
