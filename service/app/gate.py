"""May the service command the vehicle now? Only when the pilot has handed it over.

DESIGN.md's rule: setpoints only while the autopilot's heartbeat is fresh, the vehicle is armed
and in its GUIDED mode. The pilot leaving GUIDED, disarming, or the link going quiet stops
commanding at once; mapping goes on regardless. Pure: time comes in as an argument.
"""

from __future__ import annotations

from dataclasses import dataclass

from service.edges.telemetry import Heartbeat


@dataclass(frozen=True)
class GateState:
    allowed: bool
    reason: str
    """Why commanding is (not) allowed, for one log line per change."""


class CommandGate:
    """Tracks the autopilot's heartbeats; ``state(now)`` says whether setpoints may be sent."""

    def __init__(self, guided_mode: int, link_timeout_s: float) -> None:
        self.guided_mode = guided_mode
        self.link_timeout_s = link_timeout_s
        self.last: Heartbeat | None = None

    def heard(self, heartbeat: Heartbeat) -> None:
        # the first autopilot heard is the vehicle; heartbeats of other systems are not ours
        if self.last is None or heartbeat.system == self.last.system:
            self.last = heartbeat

    @property
    def system(self) -> int | None:
        return None if self.last is None else self.last.system

    def link_alive(self, now_s: float) -> bool:
        return self.last is not None and now_s - self.last.time_s <= self.link_timeout_s

    def state(self, now_s: float) -> GateState:
        hb = self.last
        if hb is None:
            return GateState(False, "no autopilot heard yet")
        if not self.link_alive(now_s):
            return GateState(False, f"link lost: no autopilot heartbeat for {now_s - hb.time_s:.1f} s")
        if not hb.armed:
            return GateState(False, "vehicle disarmed")
        if hb.custom_mode != self.guided_mode:
            return GateState(
                False, f"vehicle not in GUIDED (mode {hb.custom_mode}, GUIDED is {self.guided_mode})"
            )
        return GateState(True, "armed, in GUIDED, link alive")
