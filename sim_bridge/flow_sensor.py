"""The vehicle's flow sensor: the flow as a real anemometer or current meter reports it.

Real sensors are not exact: each reading carries noise, and a direction bias of a few degrees
(a vane or compass misaligned with the hull) turns every reading by the same angle. The service
only ever sees this reading; the plume moves with the true flow. With no noise and no bias the
reading is the true flow and no random number is drawn, so worlds without sensor error are
unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.core.errors import ConfigError


@dataclass(frozen=True)
class FlowSensorParams:
    noise_std_mps: float = 0.0
    """Standard deviation of the white noise on each component of a reading, m/s."""
    bias_deg: float = 0.0
    """Every reading turned by this angle, counter-clockwise, degrees."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.noise_std_mps) and self.noise_std_mps >= 0):
            raise ConfigError(f"flow sensor noise_std_mps must be >= 0, got {self.noise_std_mps}")
        if not (math.isfinite(self.bias_deg) and abs(self.bias_deg) <= 180):
            raise ConfigError(f"flow sensor bias_deg must be within [-180, 180], got {self.bias_deg}")


class FlowSensor:
    """Turns the true flow at the vehicle into a reading (bias, then noise)."""

    def __init__(self, params: FlowSensorParams, rng: np.random.Generator | None = None) -> None:
        if params.noise_std_mps > 0 and rng is None:
            raise ValueError("a noisy flow sensor needs a random generator")
        self.params = params
        self._rng = rng
        angle = math.radians(params.bias_deg)
        self._cos, self._sin = math.cos(angle), math.sin(angle)

    def read(self, u_mps: float, v_mps: float) -> tuple[float, float]:
        """The reported (u_x, u_y) for a true flow (u_mps, v_mps)."""
        p = self.params
        if p.bias_deg:
            u_mps, v_mps = self._cos * u_mps - self._sin * v_mps, self._sin * u_mps + self._cos * v_mps
        if self._rng is not None and p.noise_std_mps > 0:
            noise = self._rng.normal(0.0, p.noise_std_mps, 2)
            u_mps, v_mps = u_mps + float(noise[0]), v_mps + float(noise[1])
        return u_mps, v_mps
