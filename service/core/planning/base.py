"""What passes between the mission and the planners: vehicle state, waypoints, plans, the context.

Every planner answers one question: given the vehicle, the mapper and the current goal cell
(the mapper's estimate), which waypoints should the vehicle fly next? Positions are map-frame
metres (x East, y North); cells are flat indices ``f = row * m + col`` (see ``service.core.grid``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from service.core.config import PlanningConfig
    from service.core.grid import Grid
    from service.core.mapping.mapper import SourceMapper

BoolArray = npt.NDArray[np.bool_]


def _check_finite(owner: object, **values: float) -> None:
    bad = [name for name, v in values.items() if not math.isfinite(v)]
    if bad:
        raise ValueError(f"{type(owner).__name__} has non-finite {', '.join(bad)}: {values}")


@dataclass(frozen=True)
class VehicleState:
    """Where the vehicle is and which way it points: ``heading_rad`` from East, counter-clockwise."""

    x: float
    y: float
    heading_rad: float = 0.0

    def __post_init__(self) -> None:
        _check_finite(self, x=self.x, y=self.y, heading_rad=self.heading_rad)


@dataclass(frozen=True)
class Waypoint:
    """A guided target in the map frame, metres."""

    x: float
    y: float

    def __post_init__(self) -> None:
        _check_finite(self, x=self.x, y=self.y)


@dataclass(frozen=True)
class Plan:
    """Waypoints to fly in order (the first is the current target) and the cell of each."""

    waypoints: tuple[Waypoint, ...]
    cells: tuple[int, ...]

    def __post_init__(self) -> None:
        if len(self.waypoints) != len(self.cells):
            raise ValueError(f"plan has {len(self.waypoints)} waypoints but {len(self.cells)} cells")

    @classmethod
    def along(cls, grid: Grid, path: list[int] | tuple[int, ...]) -> Plan:
        """The plan that flies a cell path from its first cell (the vehicle's): the centres of the
        cells after the first, repeated cells dropped; a one-cell path holds at its centre."""
        if not path:
            raise ValueError("a path has at least the start cell")
        cells: list[int] = []
        for cell in path[1:]:
            if cell != (cells[-1] if cells else path[0]):
                cells.append(cell)
        if not cells:
            cells = [path[0]]
        return cls(tuple(Waypoint(*grid.centre(c)) for c in cells), tuple(cells))


@dataclass(frozen=True)
class PlanContext:
    """One planning request: the vehicle, its cell (nearest cell if outside the area), the goal
    cell and the mapper whose maps (pi, alpha, detection model) the planner may read."""

    vehicle: VehicleState
    cell: int
    goal: int
    mapper: SourceMapper


class Planner(Protocol):
    """A planner built once per mission from the grid and ``[planning]``; ``plan`` is called every
    tick and may keep state between calls (a path it follows until the goal changes).
    ``plan`` raises ``NoPathError`` when it has no admissible path to ``ctx.goal``."""

    name: ClassVar[str]

    def plan(self, ctx: PlanContext) -> Plan: ...


class PlannerFactory(Protocol):
    def __call__(self, grid: Grid, config: PlanningConfig) -> Planner: ...
