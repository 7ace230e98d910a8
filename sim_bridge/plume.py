"""Chemical plumes: a filament (puff) model and the time-averaged Gaussian plume.

``PuffPlume`` follows the spirit of Farrell, Murlis, Long, Li and Cardé (2002), the simulator the
seed papers used: the source releases puffs at a fixed rate; each puff is advected by the local
(meandering) flow plus a random walk (seed reactive-planning eq. 1, X' = U(X, t) + N(t)), its
radius grows with age, and the concentration at a point is the sum of the puffs' Gaussian
contributions. The plane is 2-D (the papers' search problem), so a puff of mass q and variance
s^2 per axis contributes q / (2 pi s^2) exp(-d^2 / (2 s^2)). Intermittency comes from the puffs
being discrete and from the meander of the flow that carries them.

``GaussianPlume`` is the time average of the same model in a uniform flow, in the form of seed
pomdp-astar eq. 11, for laminar checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from service.core.errors import ConfigError
from service.core.grid import Rectangle
from sim_bridge.flow import FlowField

FloatArray = npt.NDArray[np.float64]

_QUERY_BLOCK = 1_000_000
"""Largest (points x puffs) block evaluated at once by ``concentration``: bounds memory."""


@dataclass(frozen=True)
class PuffParams:
    """Parameters of the filament model; every rate is per second of simulated time."""

    release_rate_hz: float = 10.0
    """Puffs released by the source per second."""
    puff_mass: float = 1.0
    """Mass q of one puff (concentration units x m^2): sets the concentration scale."""
    initial_sigma_m: float = 0.3
    """Standard deviation of a puff's Gaussian at release, per axis."""
    spread_rate_m2ps: float = 0.02
    """Growth of a puff's variance per second (its growing radius)."""
    random_walk_m_per_sqrt_s: float = 0.3
    """sigma of N(t) in eq. 1: a puff's random-walk displacement has variance sigma^2 t per axis."""
    max_age_s: float = 600.0
    """Puffs older than this are dropped (they are too diluted to matter)."""
    max_puffs: int = 50_000
    """Capacity: when full, the oldest puffs are dropped first."""

    def __post_init__(self) -> None:
        positive = {
            "release_rate_hz": self.release_rate_hz,
            "puff_mass": self.puff_mass,
            "initial_sigma_m": self.initial_sigma_m,
            "max_age_s": self.max_age_s,
        }
        bad = [name for name, value in positive.items() if not (math.isfinite(value) and value > 0)]
        if self.spread_rate_m2ps < 0 or not math.isfinite(self.spread_rate_m2ps):
            bad.append("spread_rate_m2ps")
        if self.random_walk_m_per_sqrt_s < 0 or not math.isfinite(self.random_walk_m_per_sqrt_s):
            bad.append("random_walk_m_per_sqrt_s")
        if self.max_puffs < 1:
            bad.append("max_puffs")
        if bad:
            raise ConfigError(f"puff plume parameters out of range: {', '.join(bad)}")


class PuffPlume:
    """Puffs as parallel arrays (x, y, variance, age) of one capacity, the live ones first."""

    def __init__(
        self,
        source_m: tuple[float, float],
        params: PuffParams,
        bounds: Rectangle,
        rng: np.random.Generator,
    ) -> None:
        """``bounds`` (x_min, y_min, x_max, y_max): puffs leaving it are dropped."""
        self.source_m = (float(source_m[0]), float(source_m[1]))
        self.params = params
        self.bounds = bounds
        self._rng = rng
        capacity = params.max_puffs
        self._x = np.empty(capacity)
        self._y = np.empty(capacity)
        self._var = np.empty(capacity)
        self._age = np.empty(capacity)
        self._n = 0
        self._release_debt = 0.0
        self._time_s = 0.0

    @property
    def time_s(self) -> float:
        return self._time_s

    @property
    def count(self) -> int:
        """Number of live puffs."""
        return self._n

    def puffs(self) -> FloatArray:
        """A copy of the live puffs as an (n, 4) array of x_m, y_m, variance_m2, age_s."""
        n = self._n
        return np.column_stack([self._x[:n], self._y[:n], self._var[:n], self._age[:n]])

    def step(self, dt_s: float, flow: FlowField) -> None:
        """Advance ``dt_s``: move and grow the live puffs, drop the lost ones, release new ones."""
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be positive and finite, got {dt_s}")
        p = self.params
        n = self._n
        x, y, var, age = self._x[:n], self._y[:n], self._var[:n], self._age[:n]
        if n:
            u, v = flow.velocity(x, y)
            walk = p.random_walk_m_per_sqrt_s * math.sqrt(dt_s)
            noise = self._rng.standard_normal((2, n))
            # eq. 1 integrated over dt: X += U(X, t) dt + sigma sqrt(dt) xi
            x += u * dt_s + walk * noise[0]
            y += v * dt_s + walk * noise[1]
            var += p.spread_rate_m2ps * dt_s
            age += dt_s
            self._drop_lost()
        self._release(dt_s, flow)
        self._time_s += dt_s

    def _drop_lost(self) -> None:
        n = self._n
        x0, y0, x1, y1 = self.bounds
        x, y, age = self._x[:n], self._y[:n], self._age[:n]
        keep = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1) & (age <= self.params.max_age_s)
        kept = int(np.count_nonzero(keep))
        if kept == n:
            return
        for array in (self._x, self._y, self._var, self._age):
            array[:kept] = array[:n][keep]
        self._n = kept

    def _release(self, dt_s: float, flow: FlowField) -> None:
        p = self.params
        self._release_debt += p.release_rate_hz * dt_s
        count = int(self._release_debt)
        if count == 0:
            return
        self._release_debt -= count
        # one puff every 1/R s; the leftover debt r means the newest left r/R s ago (oldest first)
        tau = (count - 1 - np.arange(count) + self._release_debt) / p.release_rate_hz
        tau = np.clip(tau, 0.0, dt_s)
        sx, sy = self.source_m
        u, v = flow.velocity(np.array([sx]), np.array([sy]))
        noise = self._rng.standard_normal((2, count))
        walk = p.random_walk_m_per_sqrt_s * np.sqrt(tau)
        overflow = self._n + count - p.max_puffs
        if overflow > 0:
            self._drop_oldest(min(overflow, self._n))
            count = min(count, p.max_puffs)
            tau, noise, walk = tau[-count:], noise[:, -count:], walk[-count:]
        start, stop = self._n, self._n + count
        self._x[start:stop] = sx + u[0] * tau + walk * noise[0]
        self._y[start:stop] = sy + v[0] * tau + walk * noise[1]
        self._var[start:stop] = p.initial_sigma_m**2 + p.spread_rate_m2ps * tau
        self._age[start:stop] = tau
        self._n = stop

    def _drop_oldest(self, count: int) -> None:
        n = self._n
        for array in (self._x, self._y, self._var, self._age):
            array[: n - count] = array[count:n]
        self._n = n - count

    def concentration(self, x_m: FloatArray | float, y_m: FloatArray | float) -> FloatArray:
        """Instantaneous concentration at the points (x_m, y_m), same shape as the input."""
        qx = np.atleast_1d(np.asarray(x_m, dtype=float))
        qy = np.atleast_1d(np.asarray(y_m, dtype=float))
        shape = np.broadcast_shapes(qx.shape, qy.shape)
        qx, qy = np.broadcast_to(qx, shape).ravel(), np.broadcast_to(qy, shape).ravel()
        n = self._n
        out = np.zeros(qx.size)
        if n == 0:
            return out.reshape(shape)
        x, y, var = self._x[:n], self._y[:n], self._var[:n]
        weight = self.params.puff_mass / (2.0 * np.pi * var)
        block = max(1, _QUERY_BLOCK // n)
        for start in range(0, qx.size, block):
            px = qx[start : start + block, None]
            py = qy[start : start + block, None]
            d2 = (px - x) ** 2 + (py - y) ** 2
            # sum of 2-D Gaussian puffs: q / (2 pi s^2) exp(-d^2 / (2 s^2))
            out[start : start + block] = np.exp(-d2 / (2.0 * var)) @ weight
        return out.reshape(shape)


@dataclass(frozen=True)
class GaussianPlume:
    """Time-averaged plume of seed pomdp-astar eq. 11, C/C_m = exp(-y^2 / (2 sigma_y^2(x, F))).

    Derived from the puff model in a uniform flow F of speed U: a puff s metres downflow is
    s/U seconds old, so its crosswind variance (its own size plus its random walk) is
    sigma_y^2(s) = sigma_0^2 + (spread_rate + sigma_walk^2) s / U, and the puffs, R/U of them per
    metre, average to the centreline concentration C_m(s) = R q / (U sqrt(2 pi sigma_y^2(s))).
    Downflow diffusion is neglected (slender plume), so it holds for s well above sigma_y.
    """

    source_m: tuple[float, float]
    flow_mps: tuple[float, float]
    params: PuffParams

    def __post_init__(self) -> None:
        if math.hypot(*self.flow_mps) <= 0:
            raise ConfigError("the Gaussian plume needs a non-zero mean flow")

    def sigma_y_m(self, downflow_m: FloatArray) -> FloatArray:
        """sigma_y(x, F) of eq. 11 at a downflow distance (m)."""
        p = self.params
        speed = math.hypot(*self.flow_mps)
        age = np.maximum(np.asarray(downflow_m, dtype=float), 0.0) / speed
        return np.asarray(
            np.sqrt(p.initial_sigma_m**2 + (p.spread_rate_m2ps + p.random_walk_m_per_sqrt_s**2) * age)
        )

    def concentration(self, x_m: FloatArray | float, y_m: FloatArray | float) -> FloatArray:
        """Mean concentration at the points; zero upflow of the source."""
        p = self.params
        speed = math.hypot(*self.flow_mps)
        ux, uy = self.flow_mps[0] / speed, self.flow_mps[1] / speed
        dx = np.asarray(x_m, dtype=float) - self.source_m[0]
        dy = np.asarray(y_m, dtype=float) - self.source_m[1]
        downflow = dx * ux + dy * uy
        crossflow = -dx * uy + dy * ux
        sigma = self.sigma_y_m(downflow)
        peak = p.release_rate_hz * p.puff_mass / (speed * np.sqrt(2.0 * np.pi) * sigma)
        # eq. 11: C = C_m exp(-y^2 / (2 sigma_y^2(x, F)))
        mean = peak * np.exp(-(crossflow**2) / (2.0 * sigma**2))
        return np.asarray(np.where(downflow > 0, mean, 0.0))
