"""Flow fields: the velocity the fluid moves toward, m/s, in the map frame (x East, y North).

Every field keeps its own simulated clock: ``velocity`` answers at the field's current time and
``advance(dt_s)`` moves it on. Randomness comes from an injected ``numpy.random.Generator``, so
the same seed gives the same flow. The four models of issue 4:

- ``UniformFlow``: constant in space and time (seed pomdp-astar laminar case, 1 m/s left to right);
- ``SwitchedFlow``: seed hmm-plume-mapping eq. 18, uniform (1, 0) until 30 s, then (0, 1);
- ``MeanderingFlow``: a mean flow plus smooth random modes that vary in space and time, the
  stand-in for the Farrell et al. (2002) simulator's time-varying boundary conditions that make
  the plume meander;
- ``TurbulentFlow``: seed pomdp-astar §IV turbulent case, Gaussian white noise on the velocity.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

from service.core.errors import ConfigError

FloatArray = npt.NDArray[np.float64]
Vector = tuple[float, float]


class FlowField(Protocol):
    """A flow field advanced in simulated time."""

    @property
    def time_s(self) -> float: ...

    def advance(self, dt_s: float) -> None:
        """Move the field's clock forward by ``dt_s`` seconds."""
        ...

    def velocity(self, x_m: FloatArray, y_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(u_x, u_y) in m/s at the points (x_m, y_m), at the field's current time."""
        ...


def velocity_at(flow: FlowField, x_m: float, y_m: float) -> Vector:
    """The flow at one point, as plain floats."""
    u, v = flow.velocity(np.array([x_m]), np.array([y_m]))
    return float(u[0]), float(v[0])


def _constant(value: Vector, x_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    shape = np.shape(x_m)
    return np.full(shape, value[0]), np.full(shape, value[1])


class _Clocked:
    """The simulated clock every field keeps; ``_evolve`` is the field's own change over dt_s."""

    _time_s: float = 0.0

    @property
    def time_s(self) -> float:
        return self._time_s

    def advance(self, dt_s: float) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be positive and finite, got {dt_s}")
        self._evolve(dt_s)
        self._time_s += dt_s

    def _evolve(self, dt_s: float) -> None:
        """Change the field over the next ``dt_s`` seconds (nothing, for a steady field)."""


class UniformFlow(_Clocked):
    """The same velocity everywhere, always."""

    def __init__(self, velocity_mps: Vector) -> None:
        self._velocity = (float(velocity_mps[0]), float(velocity_mps[1]))

    def velocity(self, x_m: FloatArray, y_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        return _constant(self._velocity, x_m)


class SwitchedFlow(_Clocked):
    """Seed hmm-plume-mapping eq. 18: ``before_mps`` for t <= ``switch_s``, ``after_mps`` after."""

    def __init__(
        self, before_mps: Vector = (1.0, 0.0), after_mps: Vector = (0.0, 1.0), switch_s: float = 30.0
    ) -> None:
        self._before = (float(before_mps[0]), float(before_mps[1]))
        self._after = (float(after_mps[0]), float(after_mps[1]))
        self._switch_s = float(switch_s)

    def velocity(self, x_m: FloatArray, y_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        # eq. 18: (u_x, u_y) = (1, 0) for t <= 30 s, (0, 1) otherwise
        # the 1e-9 s tolerance absorbs the rounding of a clock summed from 0.1 s steps
        return _constant(self._before if self._time_s <= self._switch_s + 1e-9 else self._after, x_m)


class MeanderingFlow(_Clocked):
    """A mean flow plus a divergence-free random perturbation, smooth in space and time.

    The perturbation has RMS magnitude ``strength_mps``: half of its energy is a spatially uniform
    swing (it swings the whole plume), half sits in ``modes`` plane waves of a stream function
    with wavelengths in [L/2, 2L] (L = ``length_scale_m``) and random directions (they bend it).
    Every amplitude is an Ornstein-Uhlenbeck process with correlation time ``time_scale_s``,
    updated exactly, and starts from its stationary distribution so the statistics do not drift.
    """

    def __init__(
        self,
        mean_mps: Vector,
        strength_mps: float,
        time_scale_s: float,
        length_scale_m: float,
        rng: np.random.Generator,
        modes: int = 8,
    ) -> None:
        if strength_mps < 0 or time_scale_s <= 0 or length_scale_m <= 0 or modes < 1:
            raise ConfigError(
                "meandering flow needs strength_mps >= 0, time_scale_s > 0, length_scale_m > 0, modes >= 1"
            )
        self._mean = np.array(mean_mps, dtype=float)
        self._tau_s = float(time_scale_s)
        self._rng = rng
        wavelength_m = rng.uniform(0.5 * length_scale_m, 2.0 * length_scale_m, modes)
        direction = rng.uniform(0.0, 2.0 * np.pi, modes)
        # (modes, 2) wave vectors, rad/m, and their unit normals (the velocity direction of each mode)
        kappa = (2.0 * np.pi / wavelength_m)[:, None] * np.column_stack(
            [np.cos(direction), np.sin(direction)]
        )
        self._kappa = kappa
        self._normal = np.column_stack([np.sin(direction), -np.cos(direction)])
        self._phase = rng.uniform(0.0, 2.0 * np.pi, modes)
        # stationary std: uniform part E|b|^2 = s^2/2, modes sum a_k^2 <cos^2> = s^2/2
        self._uniform_std = strength_mps / 2.0
        self._mode_std = strength_mps / math.sqrt(modes)
        self._uniform = rng.normal(0.0, self._uniform_std, 2)
        self._set_amplitude(rng.normal(0.0, self._mode_std, modes))

    def _evolve(self, dt_s: float) -> None:
        rho = math.exp(-dt_s / self._tau_s)
        kick = math.sqrt(1.0 - rho * rho)
        # exact Ornstein-Uhlenbeck step: a <- rho a + s sqrt(1 - rho^2) xi
        self._uniform = rho * self._uniform + kick * self._uniform_std * self._rng.standard_normal(2)
        self._set_amplitude(
            rho * self._amplitude + kick * self._mode_std * self._rng.standard_normal(self._amplitude.size)
        )

    def _set_amplitude(self, amplitude: FloatArray) -> None:
        """The modes' amplitudes, and with them each mode's velocity at unit cosine (modes, 2),
        which ``velocity`` uses at every puff."""
        self._amplitude = amplitude
        self._mode_velocity = amplitude[:, None] * self._normal

    def velocity(self, x_m: FloatArray, y_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        # stream function psi = sum_k (a_k/|kappa_k|) sin(kappa_k . p + phi_k): u = d psi/dy, v = -d psi/dx
        # (the plume asks this for every puff at every step)
        phase = np.multiply.outer(x, self._kappa[:, 0])
        phase += np.multiply.outer(y, self._kappa[:, 1])
        phase += self._phase
        # the cosine in single precision: NumPy's is vectorised there and about 20 times faster
        # than its double one, which was a fifth of a suite mission's time; its error, below 3e-6 of
        # each mode's amplitude, is far below what the plume or a sensor resolves
        uv = np.cos(phase, dtype=np.float32) @ self._mode_velocity
        u = self._mean[0] + self._uniform[0] + uv[..., 0]
        v = self._mean[1] + self._uniform[1] + uv[..., 1]
        return np.asarray(u, dtype=float), np.asarray(v, dtype=float)


class TurbulentFlow(_Clocked):
    """Seed pomdp-astar turbulent case: a mean flow plus Gaussian white noise on the velocity.

    The noise is uniform in space and redrawn every ``noise_period_s`` (the flow-record period of
    the papers, 1 s): drawing it every integration step instead would make its effect on the
    plume depend on the step size. Uniform in space, it moves the whole plume unpredictably.
    """

    def __init__(
        self,
        mean_mps: Vector,
        noise_std_mps: float,
        rng: np.random.Generator,
        noise_period_s: float = 1.0,
    ) -> None:
        if noise_std_mps < 0 or noise_period_s <= 0:
            raise ConfigError("turbulent flow needs noise_std_mps >= 0 and noise_period_s > 0")
        self._mean = (float(mean_mps[0]), float(mean_mps[1]))
        self._std = float(noise_std_mps)
        self._period_s = float(noise_period_s)
        self._rng = rng
        self._noise = self._draw()
        self._since_draw_s = 0.0

    def _draw(self) -> FloatArray:
        return self._rng.normal(0.0, self._std, 2)

    def _evolve(self, dt_s: float) -> None:
        # a bounded accumulator, not the absolute clock: its rounding does not grow with time
        self._since_draw_s += dt_s
        while self._since_draw_s >= self._period_s - 1e-9:
            self._noise = self._draw()
            self._since_draw_s -= self._period_s

    def velocity(self, x_m: FloatArray, y_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        return _constant((self._mean[0] + self._noise[0], self._mean[1] + self._noise[1]), x_m)
