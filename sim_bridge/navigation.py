"""The vehicle's navigation error: where the autopilot believes it is, against where it is.

A GPS-aided estimate wanders rather than jitters: each axis's error is a first-order Gauss-Markov
process of standard deviation ``error_m`` and correlation time ``error_s``. The autopilot reports
the position it believes and steers its belief onto its targets, so the true track is the
commanded one shifted by minus the error, as on a real vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.core.errors import ConfigError


@dataclass(frozen=True)
class NavigationParams:
    error_m: float = 0.0
    """Standard deviation of each axis's position error, m; 0 = a perfect estimate."""
    error_s: float = 60.0
    """Correlation time of the error, s."""

    def __post_init__(self) -> None:
        bad = []
        if not (math.isfinite(self.error_m) and self.error_m >= 0):
            bad.append("error_m")
        if not (math.isfinite(self.error_s) and self.error_s > 0):
            bad.append("error_s")
        if bad:
            raise ConfigError(f"navigation parameters out of range: {', '.join(bad)}")


class Navigation:
    """The position error (east, north), m, advanced in simulated time."""

    def __init__(self, params: NavigationParams, rng: np.random.Generator | None = None) -> None:
        if params.error_m > 0 and rng is None:
            raise ValueError("a navigation error needs a random generator")
        self.params = params
        self._rng = rng
        self.error_m = (0.0, 0.0)
        if rng is not None and params.error_m > 0:
            east, north = rng.normal(0.0, params.error_m, 2)
            self.error_m = (float(east), float(north))

    def advance(self, dt_s: float) -> None:
        if self._rng is None or self.params.error_m <= 0:
            return
        keep = math.exp(-dt_s / self.params.error_s)
        shock = self.params.error_m * math.sqrt(1.0 - keep * keep)
        east, north = self._rng.normal(0.0, shock, 2)
        self.error_m = (keep * self.error_m[0] + float(east), keep * self.error_m[1] + float(north))
