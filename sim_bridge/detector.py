"""A binary chemical detector: threshold, missed detections (the papers' mu) and false alarms.

The detector turns the true concentration at the sensor into the reading the vehicle reports
(NAMED_VALUE_FLOAT "CHEM"), so that the service, thresholding the reading, sees exactly the
binary detector of the papers:

- odour at or above ``threshold`` is reported with probability ``detection_probability`` (mu,
  seed pomdp-astar §II-C2); a miss reports 0;
- false alarms arrive as a Poisson process of ``false_alarm_rate_hz``; the next reading after
  one is at least the threshold.

mu is a per-observation probability and the service observes once per mapping tick (the maximum
reading over the tick, seed hmm-plume-mapping §III-A), so the sensitive / blind state is drawn
once per ``hold_s`` (one tick) rather than per reading: independent draws at 10 Hz would make
the per-tick detection probability far higher than mu.

A real sensor is not instantaneous: with ``response_s`` > 0 it reads the concentration through a
first-order lag of that time constant (the time to 63 % of a step), so a brief filament reads
weaker and a reading goes on after the vehicle has left the odour. A blind spell then stops odour
entering the lag (the reading decays) instead of zeroing the reading. 0 (the default) is the
instantaneous sensor of the papers. ``noise_std`` adds white noise to every reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.core.errors import ConfigError


@dataclass(frozen=True)
class DetectorParams:
    threshold: float = 1.0
    """Concentration at or above which odour is detectable."""
    detection_probability: float = 1.0
    """mu: P(detect | detectable odour at the sensor)."""
    false_alarm_rate_hz: float = 0.0
    """Mean number of false alarms per second of simulated time."""
    hold_s: float = 1.0
    """How long one sensitive / blind draw lasts (the service's mapping tick)."""
    response_s: float = 0.0
    """Time constant of the sensor's first-order lag, s; 0 = instantaneous."""
    noise_std: float = 0.0
    """White noise on every reading, in the threshold's units; 0 = none."""

    def __post_init__(self) -> None:
        bad = []
        if not (math.isfinite(self.threshold) and self.threshold > 0):
            bad.append("threshold")
        if not 0 < self.detection_probability <= 1:
            bad.append("detection_probability")
        if not (math.isfinite(self.false_alarm_rate_hz) and self.false_alarm_rate_hz >= 0):
            bad.append("false_alarm_rate_hz")
        if not (math.isfinite(self.hold_s) and self.hold_s > 0):
            bad.append("hold_s")
        if not (math.isfinite(self.response_s) and self.response_s >= 0):
            bad.append("response_s")
        if not (math.isfinite(self.noise_std) and self.noise_std >= 0):
            bad.append("noise_std")
        if bad:
            raise ConfigError(f"detector parameters out of range: {', '.join(bad)}")


class BinaryDetector:
    """The detector's state (sensitive or blind, false alarms pending), advanced in simulated time."""

    def __init__(self, params: DetectorParams, rng: np.random.Generator) -> None:
        self.params = params
        self._rng = rng
        self._sensitive = self._draw_sensitive()
        self._until_redraw_s = params.hold_s
        self._pending_false_alarms = 0
        self._sensed = 0.0
        self._noise_rng = rng.spawn(1)[0]  # its own stream: noise leaves the misses as they were

    def _draw_sensitive(self) -> bool:
        return bool(self._rng.random() < self.params.detection_probability)

    @property
    def sensitive(self) -> bool:
        """False while the detector is blind (a missed detection in progress)."""
        return self._sensitive

    def advance(self, dt_s: float) -> None:
        """Move the detector's clock: redraw sensitivity every hold period, collect false alarms."""
        self._until_redraw_s -= dt_s
        while self._until_redraw_s <= 1e-9:
            self._sensitive = self._draw_sensitive()
            self._until_redraw_s += self.params.hold_s
        if self.params.false_alarm_rate_hz > 0:
            self._pending_false_alarms += int(self._rng.poisson(self.params.false_alarm_rate_hz * dt_s))

    @property
    def lags(self) -> bool:
        """Whether the sensor must be fed the concentration at every step (``sense``)."""
        return self.params.response_s > 0

    def sense(self, concentration: float, dt_s: float) -> None:
        """Feed the lag the concentration at the sensor over the last ``dt_s`` (none while blind)."""
        entering = concentration if self._sensitive else 0.0
        self._sensed += (entering - self._sensed) * -math.expm1(-dt_s / self.params.response_s)

    def read(self, concentration: float) -> float:
        """The reading reported for a true concentration; thresholding it gives the detection.
        A lagging sensor reports what ``sense`` has accumulated instead."""
        reading = concentration if self._sensitive else 0.0
        if self.lags:  # blind spells kept odour out of the lag instead
            reading = self._sensed
        if self.params.noise_std > 0:
            noise = float(self._noise_rng.standard_normal())
            reading += self.params.noise_std * self.params.threshold * noise
        if self._pending_false_alarms:
            self._pending_false_alarms -= 1
            reading = max(reading, self.params.threshold)
        return reading

    def detect(self, concentration: float) -> bool:
        """Binary detection (consumes a pending false alarm like ``read``)."""
        return self.read(concentration) >= self.params.threshold
