"""How intermittent a world's plume is, measured where a searcher meets it.

The *hit rate at 20 m* is the share of 1 s ticks in which the concentration reaches the
detection threshold at least once (sampled at 5 Hz, the telemetry rate) at a point fixed 20 m
downflow of the source on the mean flow's line. It is the odour physics alone: the detector's
misses and false alarms are not applied. A nearly continuous plume gives close to 1; a patchy or
strongly meandering one, a small share. Each world class states the range its worlds span.
"""

from __future__ import annotations

import math

import numpy as np

from sim_bridge.generator import DrawnWorld
from sim_bridge.scenarios import build_world, place

PROBE_DISTANCE_M = 20.0
SAMPLES_PER_TICK = 5


def hit_rate(
    drawn: DrawnWorld, seed: int, duration_s: float = 120.0, distance_m: float = PROBE_DISTANCE_M
) -> float:
    """The world's hit rate at ``distance_m`` downflow over the first ``duration_s`` of its mission."""
    scenario = drawn.scenario
    world = build_world(scenario, seed)
    placement = place(scenario, seed)
    sx, sy = placement.source_m
    ux, uy = placement.mean_flow_mps
    speed = math.hypot(ux, uy)
    px, py = sx + distance_m * ux / speed, sy + distance_m * uy / speed
    threshold = scenario.config.sensor.threshold
    steps_per_sample = max(1, round(1.0 / (SAMPLES_PER_TICK * world.dt_s)))
    ticks = int(duration_s)
    hits = 0
    for _ in range(ticks):
        peak = 0.0
        for _ in range(SAMPLES_PER_TICK):
            for _ in range(steps_per_sample):
                world.step()
            peak = max(peak, float(world.plume.concentration(px, py)[0]))
        hits += peak >= threshold
    return hits / ticks


def hit_rate_band(rates: list[float]) -> tuple[float, float]:
    """The 10th and 90th percentiles of per-world hit rates: the range a class states."""
    low, high = np.quantile(np.asarray(rates, dtype=float), [0.1, 0.9])
    return float(low), float(high)
