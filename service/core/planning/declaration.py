"""Source declaration: when the mission stops and names the source cell.

The rule: at least ``probability`` of the map's mass lies in cells whose centres are within
``radius_m`` of the estimated cell's centre. Seed pomdp-astar §II-D declares instead when "the
estimated source location produced from the source likelihood map does not change over 30
seconds"; that rule was measured on the world suite and deleted (docs/search-benchmark.md): it
waits out a map that is already sure and declares a flat map whose argmax happens not to move.

The rule is gated by a visit: it only fires while the vehicle is within
``visit_radius_m`` of the estimated cell's centre (when the mission passes the vehicle's
position). A map fed only by detections far downflow is peaked across the flow but not along
it: every cell upflow of the detections within the flow-history window explains them, and the
argmax can sit still, or gather mass, anywhere along that line. Only observations at the
estimate itself (odour just downflow of a true source, none just upflow of it) tell the cells
of that line apart, so the vehicle has to have reached the estimate before it is named.

With ``upflow_pass_m`` > 0 the rule also waits until the vehicle has been at least that far upflow
of the estimated cell's centre (along the mean flow, and within ``visit_radius_m`` of the line
through the centre across it) since that cell became the estimate. Odour at the estimate is
explained as well by a source there as by any source upflow; in a flow that varies in space the
mappers' drift lines from successive detections meet near the vehicle, so a map can gather its
mass where the vehicle is while it is still in the plume, far downflow of the source. Only a look
upflow tells them apart: odour there moves the estimate on (and restarts the wait), none there
leaves it. The mission's trace behaviour flies just beyond the pass whenever the vehicle is at an
estimate whose pass is still to be made, so the pass comes without a change of planner.

The estimate is the cell of greatest likelihood (the mapper's ``estimate``); ties go to the
lowest flat index, as ``numpy.argmax`` does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from service.core.config import DeclarationConfig
    from service.core.grid import Grid
    from service.core.mapping.belief import FloatArray


@dataclass(frozen=True)
class Declaration:
    """A declared source: the flat cell, the papers' cell number, its centre, its likelihood and
    the mass within the radius."""

    time_s: float
    cell: int
    paper_cell: int
    x: float
    y: float
    probability: float
    mass: float


def mass_within(grid: Grid, likelihood: FloatArray, cell: int, radius_m: float) -> float:
    """Sum of the likelihood over cells whose centre lies within ``radius_m`` of ``cell``'s centre."""
    cx, cy = grid.centre(cell)
    dx2 = (grid.x_centres - cx) ** 2
    dy2 = (grid.y_centres - cy) ** 2
    inside = dy2[:, None] + dx2[None, :] <= radius_m**2 * (1.0 + 1e-12)
    return float(likelihood[inside].sum())


class Declarer:
    """Judges the rule once per tick after ``arm``.

    ``admit`` (flat cell -> bool), when given, is asked last: the rule firing for a cell it
    refuses is ignored. The benchmark's perfect guard (``oslim bench search
    --oracle-declaration``) admits only cells within one cell of the true source, to measure how
    much success the declaration's guards cost; a mission on a vehicle never has one."""

    def __init__(
        self, grid: Grid, config: DeclarationConfig, admit: Callable[[int], bool] | None = None
    ) -> None:
        self.grid = grid
        self.config = config
        self._admit = admit
        self._cell: int | None = None
        self._passed_upflow = False  # the vehicle has been upflow_pass_m upflow of self._cell
        self._odour_upflow = False  # odour met check_upflow_m / 2 upflow of self._cell

    @property
    def passed_upflow(self) -> bool:
        """Whether the vehicle has made the upflow pass of the current estimate."""
        return self._passed_upflow

    @property
    def odour_upflow(self) -> bool:
        """Whether odour has been met upflow of the current estimate since it became the estimate:
        ``cancel_upflow_m`` or more along the mean flow (where odour calls a check off), within
        ``visit_radius_m`` across it."""
        return self._odour_upflow

    @property
    def cell(self) -> int | None:
        """The current estimate (flat cell) the pass and the odour upflow are about; None unarmed."""
        return self._cell

    def accept_pass(self) -> None:
        """Count the upflow pass of the current estimate as made: the vehicle went as far upflow as
        its autopilot takes it toward the pass (it stops inside its acceptance radius)."""
        self._passed_upflow = self._cell is not None

    @property
    def armed(self) -> bool:
        return self._cell is not None

    def arm(self, time_s: float, likelihood: FloatArray) -> None:
        """Start judging at ``time_s`` (the first detection)."""
        self._cell = int(np.argmax(likelihood))
        self._passed_upflow = False
        self._odour_upflow = False

    def update(
        self,
        time_s: float,
        likelihood: FloatArray,
        vehicle_m: tuple[float, float] | None = None,
        flow: tuple[float, float] | None = None,
        detected: bool = False,
    ) -> Declaration | None:
        """The declaration if the rule fires at this tick, else None (always None unarmed).
        With ``vehicle_m`` (x, y), nothing fires while the vehicle is farther than
        ``visit_radius_m`` from the estimated cell's centre. With ``upflow_pass_m`` > 0, nothing
        fires until the vehicle (``vehicle_m``) has been that far upflow of the centre against
        ``flow`` (the mean flow direction, any length); without both, never. ``detected``: this
        tick's odour, at ``vehicle_m`` (``odour_upflow``)."""
        if self._cell is None:
            return None
        cell = int(np.argmax(likelihood))
        if cell != self._cell:
            self._cell = cell
            self._passed_upflow = False
            self._odour_upflow = False
        if detected and not self._odour_upflow:
            offset = self._offset(cell, vehicle_m, flow)
            self._odour_upflow = offset is not None and (
                offset[0] >= self.config.cancel_upflow_m and offset[1] <= self.config.visit_radius_m
            )
        if self.config.upflow_pass_m > 0.0:
            self._passed_upflow = self._passed_upflow or self._is_upflow(cell, vehicle_m, flow)
            if not self._passed_upflow:
                return None
        if vehicle_m is not None:
            cx, cy = self.grid.centre(cell)
            if math.hypot(vehicle_m[0] - cx, vehicle_m[1] - cy) > self.config.visit_radius_m:
                return None
        mass = mass_within(self.grid, likelihood, cell, self.config.radius_m)
        if mass < self.config.probability:
            return None
        if not self.admits(cell):
            return None
        x, y = self.grid.centre(cell)
        return Declaration(
            time_s=time_s,
            cell=cell,
            paper_cell=self.grid.paper_number(cell),
            x=x,
            y=y,
            probability=float(likelihood.flat[cell]),
            mass=mass,
        )

    def admits(self, cell: int) -> bool:
        """Whether ``admit`` (if any) lets ``cell`` be named."""
        return self._admit is None or self._admit(cell)

    def _is_upflow(
        self, cell: int, vehicle_m: tuple[float, float] | None, flow: tuple[float, float] | None
    ) -> bool:
        """Whether the vehicle is ``upflow_pass_m`` or more upflow of ``cell``'s centre and within
        ``visit_radius_m`` of the flow line through it."""
        offset = self._offset(cell, vehicle_m, flow)
        if offset is None:
            return False
        upflow_m, across_m = offset
        return upflow_m >= self.config.upflow_pass_m - 1e-9 and across_m <= self.config.visit_radius_m

    def _offset(
        self, cell: int, vehicle_m: tuple[float, float] | None, flow: tuple[float, float] | None
    ) -> tuple[float, float] | None:
        """How far upflow of ``cell``'s centre the vehicle is along ``flow``, and how far from the
        flow line through it; None without a position or a flow."""
        if vehicle_m is None or flow is None:
            return None
        speed = math.hypot(*flow)
        if speed == 0.0:
            return None
        ux, uy = flow[0] / speed, flow[1] / speed
        cx, cy = self.grid.centre(cell)
        dx, dy = vehicle_m[0] - cx, vehicle_m[1] - cy
        return -(dx * ux + dy * uy), abs(dx * uy - dy * ux)
