"""The mission: find the plume, trace it, recover it, declare the source (``Mission``).

The public names live here; the state machine is in ``mission``, its events in ``events``.
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
