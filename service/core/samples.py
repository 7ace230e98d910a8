"""The samples a mapping tick is made of: position, flow and chemical reading, in the map frame.

They are what the tick aggregator (``service.core.tick``) takes, whichever edge produced them:
the MAVLink telemetry decoder (``service.edges.telemetry``), a simulator, or a user's program
through ``service.api.Search``. Times are seconds on the caller's clock.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Position:
    time_s: float
    x: float
    y: float
    local: bool = True
    """From LOCAL_POSITION_NED (preferred) rather than GLOBAL_POSITION_INT."""


@dataclass(frozen=True)
class FlowSample:
    time_s: float
    flow_x: float
    flow_y: float


@dataclass(frozen=True)
class ChemSample:
    time_s: float
    value: float


@dataclass(frozen=True)
class DetectionSample:
    time_s: float
    detected: bool
