"""One mapping tick from the samples that arrived during it (seed hmm-plume-mapping §III-A).

The mapper runs at a lower rate than the sensors: it takes the mean flow over the tick's samples
(eq. 1-2) and the peak chemical reading (so no detection event is missed), thresholded. A tick
with no position, no flow or no chemical reading gives no observation: nothing is invented, and
the gap is reported so it can be logged and recorded.

A chemical sensor with a response time (``sensor.response_s``, the time constant tau of its
first-order lag) reads a brief filament weakly and goes on reading odour the vehicle has left. Its
readings are turned back into the concentration it met before the peak is taken: between two
readings r0 and r1 dt apart, c = r0 + (r1 - r0) / (1 - exp(-dt / tau)), the lag of a
concentration that held over the interval inverted (c = r + tau dr/dt as dt shrinks), with dt
at least tau / 2 so that the readings' noise is not multiplied by more than about 3.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from service.core.observation import Observation
from service.core.samples import ChemSample, DetectionSample, FlowSample, Position


@dataclass(frozen=True)
class Tick:
    time_s: float
    observation: Observation | None
    gaps: tuple[str, ...]
    samples: int
    """Position, flow and chemical samples that went into this tick."""


@dataclass
class TickAggregator:
    """Collects one tick's samples; ``close`` turns them into an Observation and starts anew."""

    threshold: float
    max_position_age_s: float = 2.0
    response_s: float = 0.0
    """The chemical sensor's time constant, s (0: readings taken as they come)."""
    _flows: list[FlowSample] = field(default_factory=list)
    _chem_max: float | None = None
    _detected: bool | None = None
    _position: Position | None = None
    _samples: int = 0
    _readings: deque[ChemSample] = field(default_factory=deque)

    def add(self, sample: Position | FlowSample | ChemSample | DetectionSample) -> None:
        self._samples += 1
        if isinstance(sample, Position):
            # LOCAL_POSITION_NED is preferred: a global fix only stands in while it is stale
            last = self._position
            fresh_local = (
                last is not None and last.local and sample.time_s - last.time_s <= self.max_position_age_s
            )
            if sample.local or not fresh_local:
                self._position = sample
        elif isinstance(sample, FlowSample):
            self._flows.append(sample)
        elif isinstance(sample, ChemSample):
            value = self._met(sample) if self.response_s > 0 else sample.value
            self._chem_max = value if self._chem_max is None else max(self._chem_max, value)
        else:
            self._detected = bool(self._detected) or sample.detected

    def close(self, time_s: float) -> Tick:
        gaps = []
        position = self._position
        if position is None or time_s - position.time_s > self.max_position_age_s:
            gaps.append("position")
        if not self._flows:
            gaps.append("flow")
        if self._chem_max is None and self._detected is None:
            gaps.append("chemical")
        observation = None
        if position is not None and not gaps:
            # eq. 1-2: the mean flow over the M samples of the tick
            flow_x = sum(f.flow_x for f in self._flows) / len(self._flows)
            flow_y = sum(f.flow_y for f in self._flows) / len(self._flows)
            detected = bool(self._detected) or (
                self._chem_max is not None and self._chem_max >= self.threshold
            )
            observation = Observation(time_s, position.x, position.y, flow_x, flow_y, detected)
        tick = Tick(time_s, observation, tuple(gaps), self._samples)
        self._flows = []
        self._chem_max = None
        self._detected = None
        self._samples = 0
        # the position persists (up to max_position_age_s): a slow position stream is not a gap
        return tick

    def _met(self, sample: ChemSample) -> float:
        """The concentration the sensor met, from its reading and one at least half its time
        constant before: over a shorter interval the inversion would multiply the readings'
        noise by more than about 3 (by 12 for readings 0.2 s apart at 1.75 s)."""
        readings = self._readings
        span = 0.5 * self.response_s
        while len(readings) > 1 and readings[1].time_s <= sample.time_s - span:
            readings.popleft()
        first = readings[0] if readings else None
        readings.append(sample)
        if first is None or sample.time_s <= first.time_s:
            return sample.value
        # r1 = r0 + (c - r0)(1 - exp(-dt / tau)), solved for c
        gain = -math.expm1(-(sample.time_s - first.time_s) / self.response_s)
        return first.value + (sample.value - first.value) / gain
