"""The one place waypoints leave the mission: every plan passes ``planning.safety.safe_plan``
(inside the search area, outside every obstacle, no leg across an obstacle)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from service.core.planning.safety import safe_plan

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.planning.base import VehicleState, Waypoint


@dataclass
class Emitter:
    """The waypoints returned last (``emitted``) and the fixed point held while nothing safe is
    planned (``hold``)."""

    grid: Grid
    emitted: tuple[Waypoint, ...] | None = None
    hold: Waypoint | None = None

    @property
    def holding(self) -> bool:
        """Whether the waypoints returned last are a point to stop on."""
        return self.hold is not None

    def emit(self, vehicle: VehicleState, wanted: tuple[Waypoint, ...]) -> tuple[Waypoint, ...] | None:
        """Apply the safety rule; hold on a fixed point while nothing safe is planned; None when the
        result equals the waypoints returned last."""
        safe = safe_plan(self.grid, vehicle, wanted, hold_at=self.hold)
        holding = bool(safe) and safe != wanted[: len(safe)]
        self.hold = safe[0] if holding else None
        if not safe or safe == self.emitted:
            return None
        self.emitted = safe
        return safe
