"""Plume benchmark: can the filament model run ``puffs`` live puffs at 1/dt_s Hz faster than real time?

``measure_plume`` builds a meandering-flow plume whose steady state holds exactly ``puffs`` live
puffs (release rate R, puffs dropped at age puffs / R), warms it up to that state, then times
whole simulation steps (flow at every puff, random walk, growth, drops, releases, the flow's own
update, and one concentration reading at a sensor) over several repeats. The lead wires it as
``oslim bench plume``.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import numpy as np

from service.core.errors import ConfigError
from sim_bridge.flow import MeanderingFlow
from sim_bridge.plume import PuffParams, PuffPlume

_PLUME_AGE_S = 100.0
"""Age at which puffs are dropped: a 100 m plume in a 1 m/s flow, like the papers' areas."""


@dataclass(frozen=True)
class PlumeBenchResult:
    puffs: int
    """Live puffs at steady state (target)."""
    live_puffs: int
    """Median live puffs measured while timing."""
    dt_s: float
    steps: int
    """Timed steps per repeat."""
    repeats: int
    median_step_ms: float
    """Median over repeats of the mean wall time of one step."""
    steps_per_s: float
    """Median over repeats of steps per wall second."""
    real_time_factor: float
    """Median simulated seconds per wall second (> 1: faster than real time)."""
    worst_real_time_factor: float
    """The slowest repeat's real-time factor."""


def measure_plume(
    puffs: int = 10_000, dt_s: float = 0.1, steps: int = 100, repeats: int = 5, seed: int = 0
) -> PlumeBenchResult:
    """Time ``repeats`` x ``steps`` plume steps of ``dt_s`` with ``puffs`` live puffs."""
    if puffs < 1 or steps < 1 or repeats < 1 or not dt_s > 0:
        raise ConfigError("plume bench needs puffs, steps, repeats >= 1 and dt_s > 0")
    flow_rng, plume_rng = np.random.default_rng(seed).spawn(2)
    flow = MeanderingFlow((1.0, 0.0), 0.4, 20.0, 60.0, flow_rng)
    rate_hz = puffs / _PLUME_AGE_S
    params = PuffParams(release_rate_hz=rate_hz, max_age_s=_PLUME_AGE_S, max_puffs=2 * puffs + 16)
    far = 1e6  # puffs leave by age only, so the steady state is exactly R x age
    plume = PuffPlume((0.0, 0.0), params, (-far, -far, far, far), plume_rng)
    sensor_x, sensor_y = np.array([40.0]), np.array([0.0])

    def one_step() -> None:
        plume.step(dt_s, flow)
        flow.advance(dt_s)
        plume.concentration(sensor_x, sensor_y)

    for _ in range(round(_PLUME_AGE_S / dt_s) + 1):
        one_step()
    step_s: list[float] = []
    live: list[int] = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            one_step()
        step_s.append((time.perf_counter() - start) / steps)
        live.append(plume.count)
    median_s = statistics.median(step_s)
    return PlumeBenchResult(
        puffs=puffs,
        live_puffs=int(statistics.median(live)),
        dt_s=dt_s,
        steps=steps,
        repeats=repeats,
        median_step_ms=1e3 * median_s,
        steps_per_s=1.0 / median_s,
        real_time_factor=dt_s / median_s,
        worst_real_time_factor=dt_s / max(step_s),
    )
