"""The per-tick observation every mapper consumes (seed hmm-plume-mapping §III-A, eq. 1-2)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Observation:
    """What the vehicle sensed over one tick.

    ``flow_x``/``flow_y`` are the mean flow over the tick (m/s, map frame, direction the fluid
    moves toward); ``detected`` is the maximum chemical reading over the tick thresholded.
    """

    time_s: float
    x: float
    y: float
    flow_x: float
    flow_y: float
    detected: bool

    def __post_init__(self) -> None:
        values = {"time_s": self.time_s, "x": self.x, "y": self.y,
                  "flow_x": self.flow_x, "flow_y": self.flow_y}  # fmt: skip
        bad = [name for name, v in values.items() if not math.isfinite(v)]
        if bad:
            raise ValueError(f"observation has non-finite {', '.join(bad)}: {values}")
        if not isinstance(self.detected, bool):
            raise TypeError(f"detected must be a bool, got {self.detected!r}")
