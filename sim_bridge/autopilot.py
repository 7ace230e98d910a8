"""What the stub imitates of ArduPilot, as data: vehicle kinds, their modes and MAVLink identity.

Mode numbers are ArduPilot's ``custom_mode`` values (Rover ``mode.h``, Sub ``defines.h``). Only
GUIDED drives toward setpoints; every other mode listed is accepted and holds still.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType


class VehicleKind(StrEnum):
    ROVER = "rover"
    SUB = "sub"


@dataclass(frozen=True)
class Autopilot:
    mav_type: str
    """Name of the MAV_TYPE enum entry sent in HEARTBEAT."""
    modes: MappingProxyType[int, str]
    """custom_mode number -> mode name, every mode SET_MODE may select."""
    guided: int
    """custom_mode of GUIDED."""
    initial: int
    """Mode at boot (ArduPilot's INITIAL_MODE default)."""
    radius_param: str | None = None
    """The parameter within which a guided target counts as reached (Rover's WP_RADIUS); the stub
    answers PARAM_REQUEST_READ of it with the world's arrival radius, and of WP_SPEED and
    CRUISE_SPEED with the cruise speed. None: the vehicle drives onto its targets and has none of
    these parameters."""

    def mode_name(self, custom_mode: int) -> str:
        return self.modes.get(custom_mode, f"MODE({custom_mode})")


# ArduPilot Rover mode.h and ArduSub defines.h: custom_mode -> name
_ROVER_MODES = {0: "MANUAL", 1: "ACRO", 3: "STEERING", 4: "HOLD", 5: "LOITER", 6: "FOLLOW", 7: "SIMPLE",
                8: "DOCK", 9: "CIRCLE", 10: "AUTO", 11: "RTL", 12: "SMART_RTL", 15: "GUIDED"}  # fmt: skip
_SUB_MODES = {0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 7: "CIRCLE", 9: "SURFACE",
              16: "POSHOLD", 19: "MANUAL"}  # fmt: skip

AUTOPILOTS: MappingProxyType[VehicleKind, Autopilot] = MappingProxyType(
    {
        VehicleKind.ROVER: Autopilot(
            mav_type="MAV_TYPE_GROUND_ROVER",
            modes=MappingProxyType(_ROVER_MODES),
            guided=15,
            initial=0,
            radius_param="WP_RADIUS",
        ),
        VehicleKind.SUB: Autopilot(
            mav_type="MAV_TYPE_SUBMARINE", modes=MappingProxyType(_SUB_MODES), guided=4, initial=19
        ),
    }
)
"""The imitated autopilot of each vehicle kind."""
