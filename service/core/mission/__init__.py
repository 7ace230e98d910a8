"""The mission: find the plume, trace it, recover it, declare the source (``Mission``).

The public names live here. The parts: ``mission`` the state machine, ``transitions`` its
table, ``prospect`` (FIND) the plume finder with its own legs,
``declaring`` the declaration's mission side (the check across the flow, the probe at the
estimate), ``pattern`` turning points flown in order, ``routing`` paths with their fallbacks,
``emitter`` the safety rule on every waypoint that leaves, ``events`` what a tick reports.
"""

from service.core.mission.events import (
    CrossCheck,
    MissionEvent,
    MissionOutput,
    MissionState,
    PlumeFound,
    PlumeLost,
    SourceDeclared,
)
from service.core.mission.mission import Mission

__all__ = [
    "CrossCheck",
    "Mission",
    "MissionEvent",
    "MissionOutput",
    "MissionState",
    "PlumeFound",
    "PlumeLost",
    "SourceDeclared",
]
