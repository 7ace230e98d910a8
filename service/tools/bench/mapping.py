"""Mapping benchmark: time per tick and peak memory of each mapper at several grid sizes.

Each (mapper, cells) configuration runs in a fresh child process, so its peak resident memory
is its own. The history window is filled before timing starts; the vehicle sweeps the area at
1 m/s under a meandering flow with about one detection in ten ticks (seeded, reproducible).
The mappers run the papers' models unless given the model parameters of a service configuration
(``MapperParams.from_config``: what a deployment of it computes each tick, footprint and
prehistory included).
"""

from __future__ import annotations

import math
import multiprocessing
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace

import numpy as np

from service.core.grid import Grid
from service.core.mapping import MAPPERS, MapperParams, make_mapper
from service.core.observation import Observation

GRID_SHAPES: dict[int, tuple[int, int]] = {1_000: (40, 25), 10_000: (100, 100), 100_000: (400, 250)}
"""Cells -> (columns, rows) over the papers' 100 m x 100 m area."""


PAPERS = "papers"
"""``MappingResult.model`` of the papers' models (``MapperParams`` defaults)."""


@dataclass(frozen=True)
class MappingResult:
    mapper: str
    model: str
    """``PAPERS``, or the configuration whose model parameters were used."""
    cells: int
    window: int
    ticks: int
    median_ms: float
    p95_ms: float
    peak_mb: float


def _observations(count: int, seed: int) -> list[Observation]:
    """A lawnmower sweep at 1 m/s under a slowly meandering ~1 m/s flow."""
    rng = np.random.default_rng(seed)
    obs = []
    for t in range(count):
        leg, along = divmod(t, 90)
        x = 5.0 + along if leg % 2 == 0 else 95.0 - along
        y = -45.0 + (leg * 10.0) % 90.0
        flow_x = 1.0 + 0.2 * math.sin(t / 30.0)
        flow_y = 0.3 * math.sin(t / 45.0)
        obs.append(Observation(float(t), x, y, flow_x, flow_y, bool(rng.random() < 0.1)))
    return obs


def measure(
    method: str,
    cells: int,
    window: int,
    ticks: int,
    seed: int = 0,
    params: MapperParams | None = None,
    model: str = PAPERS,
) -> MappingResult:
    """Median and p95 wall time of ``update`` over ``ticks`` ticks after a full window, with the
    papers' models or ``params`` (their window replaced by ``window``)."""
    columns, rows = GRID_SHAPES[cells]
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=columns, rows=rows)
    mapper = make_mapper(method, grid, replace(params or MapperParams(), window=window))
    stream = _observations(window + 1 + ticks, seed)
    for obs in stream[: window + 1]:
        mapper.update(obs)
    times = []
    for obs in stream[window + 1 :]:
        start = time.perf_counter()
        mapper.update(obs)
        times.append(time.perf_counter() - start)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
    ms = np.array(times) * 1e3
    return MappingResult(
        mapper=method,
        model=model,
        cells=cells,
        window=window,
        ticks=ticks,
        median_ms=round(float(np.median(ms)), 3),
        p95_ms=round(float(np.percentile(ms, 95)), 3),
        peak_mb=round(peak_mb, 1),
    )


def memory_bandwidth_gb_per_s(megabytes: int = 256, repeats: int = 7) -> float:
    """Median copy bandwidth (bytes read + written per second) of a large numpy copy."""
    src = np.ones(megabytes * 2**20 // 8)
    dst = np.empty_like(src)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        np.copyto(dst, src)
        times.append(time.perf_counter() - start)
    return round(2 * src.nbytes / float(np.median(times)) / 1e9, 2)


DEFAULT_WINDOW = 200
"""The papers' models are timed with this flow-history window unless told otherwise."""


def run(
    methods: list[str] | None = None,
    cells: list[int] | None = None,
    window: int | None = None,
    ticks: int | None = None,
    params: MapperParams | None = None,
    model: str = PAPERS,
) -> list[MappingResult]:
    """Every (mapper, cells) configuration, each in its own child process; with ``params`` (named
    ``model``) the mappers use them, and the window is theirs unless ``window`` is given."""
    methods = methods or sorted(MAPPERS)
    cells = cells or sorted(GRID_SHAPES)
    if window is None:
        window = params.window if params is not None else DEFAULT_WINDOW
    results = []
    for c in cells:
        n_ticks = ticks if ticks is not None else (60 if c >= 100_000 else 200)
        for method in methods:
            # a fresh interpreter each time (spawn, not fork) so ru_maxrss is this configuration's own
            spawn = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(max_workers=1, mp_context=spawn, max_tasks_per_child=1) as pool:
                results.append(pool.submit(measure, method, c, window, n_ticks, 0, params, model).result())
    return results


def as_row(result: MappingResult) -> dict[str, object]:
    row = asdict(result)
    del row["ticks"]
    return row
