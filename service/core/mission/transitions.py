"""The mission's transitions: which cue moves it from which state to which (``TRANSITIONS``).

A detection in ``TRACE`` and anything in ``DECLARED`` move nothing; the entry actions of each
transition are ``Mission._go``'s."""

from __future__ import annotations

from enum import StrEnum
from typing import Final

from service.core.mission.events import MissionState


class Cue(StrEnum):
    """What moves the mission on."""

    ODOUR = "odour"  # a detection
    QUIET = "quiet"  # no detection for lost_after_s while tracing (and no check flown)
    LONE_QUIET = "lone quiet"  # a contact in FIND with at most lone_contact_hits detections,
    # not repeated for lone_contact_lost_after_s: most likely a false alarm
    CHECK = "check"  # a declaration rule fired and the check across the flow is to be flown
    SOURCE = "source"  # a declaration rule fired and its cell was vouched for


FIND, TRACE, LOST, DECLARED = MissionState.FIND, MissionState.TRACE, MissionState.LOST, MissionState.DECLARED

TRANSITIONS: Final[dict[tuple[MissionState, Cue], MissionState]] = {
    (FIND, Cue.ODOUR): TRACE,
    (LOST, Cue.ODOUR): TRACE,
    (TRACE, Cue.QUIET): LOST,  # reported; flown as TRACE, toward the estimate
    (TRACE, Cue.LONE_QUIET): FIND,  # a new leg from where the vehicle is
    (FIND, Cue.CHECK): TRACE,  # the check is flown while tracing, wherever the rule fired
    (LOST, Cue.CHECK): TRACE,
    (FIND, Cue.SOURCE): DECLARED,
    (TRACE, Cue.SOURCE): DECLARED,
    (LOST, Cue.SOURCE): DECLARED,
}
