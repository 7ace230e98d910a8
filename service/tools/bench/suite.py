"""The world suite: every class of worlds under ``config/suites/`` with one service configuration.

Each class draws its worlds from the seed (``sim_bridge.generator``); every mission is the same
in-process closed loop as ``oslim bench search`` (``search.run_mission``), with the class's time
limit scaled to the drawn area and vehicle speed. The service configuration is the one a user
deploys (``config/default.toml`` unless another file is given) with the class's area; ``--set``
overrides apply to every class (``world.KEY=VALUE`` ones to its world ranges: a stress test). What
counts is the worst class and the wrong declarations.

Missions run in a local process pool, or on a Dask cluster (``scheduler``: its address); both
give the same results for the same seeds, because a mission depends only on its spec.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from scipy.stats import binomtest

from service.core.config import Config, load_config, parse_override
from service.core.mission import CrossCheck
from service.tools.bench.search import FailureClass, MissionResult, run_mission
from service.tools.bench.workers import in_order
from sim_bridge.generator import (
    SUITE_DIR,
    DrawnWorld,
    WorldClass,
    available_classes,
    draw_scenario,
    load_class,
)
from sim_bridge.scenarios import WORLD_KEY, place

SUMMARY_KEYS = ("classes", "missions", "worst_class", "worst_success_rate", "wrong_rate", "missions_per_s")


HEADER = (
    f"{'class':<16}{'runs':>5}{'success':>9}{'95% CI':>10}{'wrong':>7}{'median s':>10}{'p90 s':>8}"
    f"{'limit s':>9}{'path m':>8}"
    "  failures: never smelled / not reached / undeclared / wrong"
)


def interval(successes: int, runs: int) -> tuple[float, float]:
    """The 95 % Wilson score interval of a rate seen ``successes`` times in ``runs``: what the seeds
    allow the true rate to be (at 20 missions a class, 80 % seen is 58-92 %)."""
    ci = binomtest(successes, runs).proportion_ci(0.95, method="wilson")
    return float(ci.low), float(ci.high)


def _span(bounds: tuple[float, float]) -> str:
    return f"{bounds[0] * 100:.0f}-{bounds[1] * 100:.0f}%"


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


@dataclass(frozen=True)
class SuiteMission:
    """One mission of the suite (picklable: what a worker needs to rebuild it)."""

    class_path: str
    seed: int
    config_path: str | None = None
    overrides: tuple[str, ...] = ()
    oracle: bool = False
    """The perfect declaration guard of ``run_mission``: a bound, not a result."""
    arrival_radius_m: float = 0.0
    """The simulated vehicle stops this far short of its targets (ArduPilot Rover's WP_RADIUS);
    0: it drives onto them, as every class draws it."""
    time_scale: float = 1.0
    """The class's time limit times this: a diagnostic (are the failures slow, or stuck?), not a
    result; 1 is the suite."""


def world_overrides(overrides: Sequence[str]) -> tuple[str, ...]:
    """The ``--set`` overrides under ``world.``: they change every class's world ranges (a stress
    test: ``world.flow_sensor.bias_deg=[-15, 15]``); the others are the service's."""
    return tuple(text for text in overrides if parse_override(text)[0][0] == WORLD_KEY)


@lru_cache(maxsize=64)
def _world_class(path: str, overrides: tuple[str, ...] = ()) -> WorldClass:
    return load_class(path, world_overrides(overrides))


@lru_cache(maxsize=8)
def service_config(path: str | None, overrides: tuple[str, ...]) -> Config:
    """The service configuration every class runs with (read once per process)."""
    world = world_overrides(overrides)
    return load_config(path, [text for text in overrides if text not in world])


def drawn_world(spec: SuiteMission) -> DrawnWorld:
    """One suite mission's world and time limit (its class and configuration read once per process)."""
    config = service_config(spec.config_path, spec.overrides)
    drawn = draw_scenario(_world_class(spec.class_path, spec.overrides), spec.seed, config)
    if spec.arrival_radius_m <= 0.0:
        return drawn
    world = drawn.scenario.world
    vehicle = world.vehicle.model_copy(update={"arrival_radius_m": spec.arrival_radius_m})
    scenario = replace(drawn.scenario, world=world.model_copy(update={"vehicle": vehicle}))
    return replace(drawn, scenario=scenario)


@dataclass(frozen=True)
class SourceFrame:
    """Where a drawn world's source is (m) and the unit direction of its mean flow (East when there
    is none): the frame a diagnostic measures along and across."""

    source: tuple[float, float]
    flow: tuple[float, float]

    def along_across(self, x: float, y: float) -> tuple[float, float]:
        """(x, y) along the mean flow from the source (> 0: downflow of it) and across it (> 0: to
        the flow's left)."""
        (sx, sy), (ux, uy) = self.source, self.flow
        dx, dy = x - sx, y - sy
        return dx * ux + dy * uy, dy * ux - dx * uy


def source_frame(drawn: DrawnWorld, seed: int) -> SourceFrame:
    """The source frame of the world drawn from ``seed``."""
    placement = place(drawn.scenario, seed)
    fx, fy = placement.mean_flow_mps
    speed = math.hypot(fx, fy)
    return SourceFrame(placement.source_m, (fx / speed, fy / speed) if speed > 0 else (1.0, 0.0))


def time_limit_s(spec: SuiteMission, drawn: DrawnWorld) -> float:
    """The time a suite mission runs to: its class's limit for the drawn world times ``spec.time_scale``."""
    return drawn.time_limit_s * spec.time_scale


def run_suite_mission(spec: SuiteMission) -> tuple[MissionResult, float]:
    """The mission and its time limit, scaled by ``spec.time_scale`` (a worker's task)."""
    drawn = drawn_world(spec)
    limit = time_limit_s(spec, drawn)
    return run_mission(drawn.scenario, spec.seed, max_time_s=limit, oracle=spec.oracle), limit


CALIBRATION_LEVEL = 0.95
"""The stated confidence the suite's calibration figure is about (the issue's "stated 95 %")."""
CALIBRATION_BANDS = (0.0, 0.8, 0.85, 0.9, CALIBRATION_LEVEL)
"""Lower edges of the stated-confidence bands of the calibration table; the last band, from
``CALIBRATION_LEVEL`` up, is the issue's "declarations made at a stated 95 %"."""


BandT = TypeVar("BandT", "Band", "SpeedBand")


def _add_counts(a: BandT, b: BandT) -> BandT:
    """Two bands of the same edges (``lower``, ``upper``) with every other field summed."""
    if (a.lower, a.upper) != (b.lower, b.upper):
        raise ValueError("bands with different edges do not add")
    counts = {
        f.name: getattr(a, f.name) + getattr(b, f.name) for f in fields(a) if f.name not in ("lower", "upper")
    }
    return replace(a, **counts)


@dataclass(frozen=True)
class Band:
    """The declarations stated at ``lower`` <= confidence < ``upper``: how many, what they stated in
    all, and how many had the source within their stated radius."""

    lower: float
    upper: float
    declarations: int = 0
    confidence_sum: float = 0.0
    within: int = 0

    def __add__(self, other: Band) -> Band:
        return _add_counts(self, other)

    @property
    def stated_mean(self) -> float | None:
        return self.confidence_sum / self.declarations if self.declarations else None

    @property
    def came_true(self) -> float | None:
        """Share of the band's declarations with the source within their stated radius."""
        return self.within / self.declarations if self.declarations else None

    def label(self) -> str:
        if self.lower <= 0.0:
            return f"< {self.upper:.0%}"
        return f">= {self.lower:.0%}" if self.upper > 1.0 else f"{self.lower:.0%}-{self.upper:.0%}"

    def as_row(self) -> dict[str, Any]:
        return {
            "stated_from": self.lower,
            "stated_to": min(self.upper, 1.0),
            "declarations": self.declarations,
            "stated_confidence_mean": self.stated_mean,
            "within_stated_radius_rate": self.came_true,
        }


def _percent(share: float | None) -> str:
    return "-" if share is None else f"{share:.1%}"


def _banded(kind: Callable[[float, float], BandT], lowers: Sequence[float]) -> tuple[BandT, ...]:
    """Empty bands from their lower edges, each up to the next; the last one has no upper edge."""
    uppers = (*lowers[1:], math.inf)
    return tuple(kind(lower, upper) for lower, upper in zip(lowers, uppers, strict=True))


def _bands() -> tuple[Band, ...]:
    return _banded(Band, CALIBRATION_BANDS)


@dataclass(frozen=True)
class Calibration:
    """How often declarations were right about themselves (the source within the stated radius),
    by the confidence they stated (``CALIBRATION_BANDS``)."""

    bands: tuple[Band, ...] = field(default_factory=_bands)

    @classmethod
    def of(cls, results: Sequence[MissionResult]) -> Calibration:
        declared = [r for r in results if r.declared and r.confidence is not None]
        stated = [(r.confidence or 0.0, r.within_stated_radius) for r in declared]

        def counted(band: Band) -> Band:
            inside = [(c, ok) for c, ok in stated if band.lower <= c < band.upper]
            return replace(
                band,
                declarations=len(inside),
                confidence_sum=sum(c for c, _ in inside),
                within=sum(ok for _, ok in inside),
            )

        return cls(tuple(counted(band) for band in _bands()))

    def __add__(self, other: Calibration) -> Calibration:
        return Calibration(tuple(a + b for a, b in zip(self.bands, other.bands, strict=True)))

    @property
    def declarations(self) -> int:
        return sum(b.declarations for b in self.bands)

    @property
    def within(self) -> int:
        """Declarations whose source lay within the radius they stated."""
        return sum(b.within for b in self.bands)

    @property
    def confidence_sum(self) -> float:
        return sum(b.confidence_sum for b in self.bands)

    @property
    def high(self) -> int:
        """Declarations stated at ``CALIBRATION_LEVEL`` or more ..."""
        return self.bands[-1].declarations

    @property
    def high_within(self) -> int:
        """... and of them, those whose source lay within the stated radius."""
        return self.bands[-1].within

    def table(self) -> str:
        """One line per band: declarations, the mean confidence stated, and how often it came true."""
        lines = [f"{'stated':<12}{'declarations':>13}{'stated mean':>13}{'came true':>11}"]
        for band in self.bands:
            mean, true = (_percent(share) for share in (band.stated_mean, band.came_true))
            lines.append(f"{band.label():<12}{band.declarations:>13}{mean:>13}{true:>11}")
        return "\n".join(lines)

    def line(self) -> str:
        if not self.declarations:
            return "calibration: no declarations"
        high = f"{self.high_within / self.high:.1%}" if self.high else "-"
        stated, true = self.confidence_sum / self.declarations, self.within / self.declarations
        return (
            f"calibration: {self.high} declarations stated at >= {CALIBRATION_LEVEL:.0%}: {high} had the "
            f"source within their stated radius; all {self.declarations}: stated {stated:.1%} on average, "
            f"true {true:.1%}"
        )


@dataclass(frozen=True)
class Endurance:
    """The declarations named as a mission's time ran out (``vehicle.endurance_s``, which the suite
    sets to each world's limit), on the map's mass alone: how many, and how many were correct. The
    rest of the suite's successes are what the search makes without them."""

    declarations: int = 0
    correct: int = 0

    @classmethod
    def of(cls, results: Sequence[MissionResult]) -> Endurance:
        named = [r for r in results if r.check == CrossCheck.ENDURANCE]
        return cls(len(named), sum(r.correct for r in named))

    def __add__(self, other: Endurance) -> Endurance:
        return Endurance(self.declarations + other.declarations, self.correct + other.correct)

    def line(self) -> str:
        wrong = self.declarations - self.correct
        return (
            f"named as the time ran out (vehicle.endurance_s, without the check): {self.declarations} "
            f"declarations, {self.correct} correct, {wrong} wrong"
        )

    def as_row(self) -> dict[str, Any]:
        return {"endurance_declarations": self.declarations, "endurance_correct": self.correct}


SPEED_BANDS = (0.0, 1.0, 1.5)
"""Lower edges of the vehicle-speed bands (m/s) the summary splits success by: the time limits
shrink with the speed, the map's learning does not speed up with it (one observation a second)."""


@dataclass(frozen=True)
class SpeedBand:
    """The missions flown at ``lower`` <= vehicle speed < ``upper`` (m/s), and how many succeeded."""

    lower: float
    upper: float
    missions: int = 0
    successes: int = 0

    def __add__(self, other: SpeedBand) -> SpeedBand:
        return _add_counts(self, other)

    @property
    def success_rate(self) -> float | None:
        return self.successes / self.missions if self.missions else None

    def label(self) -> str:
        if self.lower <= 0.0:
            return f"< {self.upper:g} m/s"
        return f">= {self.lower:g} m/s" if math.isinf(self.upper) else f"{self.lower:g}-{self.upper:g} m/s"

    def as_row(self) -> dict[str, Any]:
        upper = None if math.isinf(self.upper) else self.upper
        return {"speed_from_mps": self.lower, "speed_to_mps": upper, "missions": self.missions,
                "success_rate": self.success_rate}  # fmt: skip


@dataclass(frozen=True)
class Speeds:
    """Success by the vehicle's speed (``SPEED_BANDS``); missions of unknown speed are left out."""

    bands: tuple[SpeedBand, ...] = field(default_factory=lambda: _banded(SpeedBand, SPEED_BANDS))

    @classmethod
    def of(cls, results: Sequence[MissionResult]) -> Speeds:
        def counted(band: SpeedBand) -> SpeedBand:
            inside = [r for r in results if r.vehicle_speed_mps is not None
                      and band.lower <= r.vehicle_speed_mps < band.upper]  # fmt: skip
            return replace(band, missions=len(inside), successes=sum(r.correct for r in inside))

        return cls(tuple(counted(band) for band in _banded(SpeedBand, SPEED_BANDS)))

    def __add__(self, other: Speeds) -> Speeds:
        return Speeds(tuple(a + b for a, b in zip(self.bands, other.bands, strict=True)))

    def line(self) -> str:
        parts = [f"{b.label()} {_percent(b.success_rate)} of {b.missions}" for b in self.bands if b.missions]
        return "by vehicle speed: " + ("; ".join(parts) if parts else "-")


@dataclass(frozen=True)
class ClassSummary:
    """One class's figures over its missions."""

    name: str
    runs: int
    success_rate: float
    wrong_declarations: int
    median_time_s: float | None
    """Median time to a correct declaration, over the missions that made one."""
    p90_time_s: float | None
    max_time_s: float
    """The longest time limit among the class's worlds (it scales with area and speed)."""
    median_path_m: float
    failures: dict[FailureClass, int] = field(default_factory=dict)
    calibration: Calibration = field(default_factory=Calibration)
    speeds: Speeds = field(default_factory=Speeds)
    speed_drawn: bool = True
    """Whether the class draws its vehicles' speed (the suite's split by speed counts only those)."""
    endurance: Endurance = field(default_factory=Endurance)
    outcomes: tuple[tuple[MissionResult, float], ...] = field(default=(), repr=False, compare=False)
    """Each mission and its time limit, in seed order (``oslim bench suite --missions``)."""

    def line(self) -> str:
        """The class's row of the text table (columns of ``HEADER``)."""
        f = self.failures
        counts = " / ".join(str(f.get(kind, 0)) for kind in FailureClass)
        return (
            f"{self.name:<16}{self.runs:>5}{self.success_rate:>9.1%}{_span(self.success_interval):>10}"
            f"{self.wrong_declarations:>7}"
            f"{_fmt(self.median_time_s):>10}{_fmt(self.p90_time_s):>8}{self.max_time_s:>9.0f}"
            f"{self.median_path_m:>8.0f}  {counts}"
        )

    @property
    def success_interval(self) -> tuple[float, float]:
        """The 95 % interval of the success rate over these seeds (``interval``)."""
        return interval(round(self.success_rate * self.runs), self.runs)

    def as_row(self) -> dict[str, Any]:
        """The JSON object of ``oslim bench suite --json`` for this class."""
        return {
            "class": self.name,
            "runs": self.runs,
            "success_rate": self.success_rate,
            "success_interval": list(self.success_interval),
            "wrong_declarations": self.wrong_declarations,
            "median_time_s": self.median_time_s,
            "p90_time_s": self.p90_time_s,
            "max_time_s": self.max_time_s,
            "median_path_m": self.median_path_m,
            "failures": {str(kind): self.failures.get(kind, 0) for kind in FailureClass},
            "declarations": self.calibration.declarations,
            "within_stated_radius": self.calibration.within,
            "speed_bands": [band.as_row() for band in self.speeds.bands],
            **self.endurance.as_row(),
        }


def summarise_class(
    name: str, outcomes: Sequence[tuple[MissionResult, float]], *, speed_drawn: bool = True
) -> ClassSummary:
    if not outcomes:
        raise ValueError("no missions to summarise")
    results = [r for r, _ in outcomes]
    times = [r.time_s for r in results if r.correct]
    failures = [r.failure for r in results]
    return ClassSummary(
        name=name,
        runs=len(results),
        success_rate=len(times) / len(results),
        wrong_declarations=sum(r.wrong for r in results),
        median_time_s=float(np.median(times)) if times else None,
        p90_time_s=float(np.quantile(times, 0.9, method="inverted_cdf")) if times else None,
        max_time_s=max(limit for _, limit in outcomes),
        median_path_m=float(np.median([r.path_m for r in results])),
        failures={kind: failures.count(kind) for kind in FailureClass},
        calibration=Calibration.of(results),
        speeds=Speeds.of(results),
        speed_drawn=speed_drawn,
        endurance=Endurance.of(results),
        outcomes=tuple(outcomes),
    )


@dataclass(frozen=True)
class SuiteSummary:
    classes: int
    missions: int
    worst_class: str
    worst_success_rate: float
    worst_success_interval: tuple[float, float]
    wrong_rate: float
    """Wrong declarations per mission, over the whole suite."""
    wrong_interval: tuple[float, float]
    missions_per_s: float
    elapsed_s: float
    calibration: Calibration = field(default_factory=Calibration)
    speeds: Speeds = field(default_factory=Speeds)
    """Success by the vehicle's speed over the classes that draw it (a class flown at one speed
    would weigh its own difficulty into one band)."""
    speed_classes: int = 0
    endurance: Endurance = field(default_factory=Endurance)

    def line(self) -> str:
        return (
            self.calibration.table()
            + "\n"
            + self.calibration.line()
            + "\n"
            + self.endurance.line()
            + "\n"
            + f"{self.speeds.line()} (classes that draw the speed: {self.speed_classes})"
            + "\n"
            + (
                f"summary: worst class {self.worst_class} {self.worst_success_rate:.1%} "
                f"(95% CI {_span(self.worst_success_interval)}); wrong declarations {self.wrong_rate:.2%} of "
                f"{self.missions} missions (95% CI up to {self.wrong_interval[1]:.2%}); "
                f"{self.missions_per_s:.2f} missions/s ({self.elapsed_s:.0f} s)"
            )
        )

    def as_row(self) -> dict[str, Any]:
        """The last JSON object of ``oslim bench suite --json`` (``"summary": true``)."""
        row: dict[str, Any] = {"summary": True}
        row.update({key: getattr(self, key) for key in SUMMARY_KEYS})
        row["worst_success_interval"] = list(self.worst_success_interval)
        row["wrong_interval"] = list(self.wrong_interval)
        row["elapsed_s"] = self.elapsed_s
        c = self.calibration
        row["declarations"] = c.declarations
        row["stated_confidence_mean"] = c.confidence_sum / c.declarations if c.declarations else None
        row["within_stated_radius_rate"] = c.within / c.declarations if c.declarations else None
        row["declarations_at_95"] = c.high
        row["within_stated_radius_rate_at_95"] = c.high_within / c.high if c.high else None
        row["calibration_bands"] = [band.as_row() for band in c.bands]
        row["speed_bands"] = [band.as_row() for band in self.speeds.bands]
        row["speed_classes"] = self.speed_classes
        row.update(self.endurance.as_row())
        return row


def summarise_suite(classes: Sequence[ClassSummary], elapsed_s: float) -> SuiteSummary:
    worst = min(classes, key=lambda c: c.success_rate)
    missions = sum(c.runs for c in classes)
    wrong = sum(c.wrong_declarations for c in classes)
    return SuiteSummary(
        classes=len(classes),
        missions=missions,
        worst_class=worst.name,
        worst_success_rate=worst.success_rate,
        worst_success_interval=worst.success_interval,
        wrong_rate=wrong / missions,
        wrong_interval=interval(wrong, missions),
        missions_per_s=missions / elapsed_s if elapsed_s > 0 else math.inf,
        elapsed_s=elapsed_s,
        calibration=sum((c.calibration for c in classes), Calibration()),
        speeds=sum((c.speeds for c in classes if c.speed_drawn), Speeds()),
        speed_classes=sum(c.speed_drawn for c in classes),
        endurance=sum((c.endurance for c in classes), Endurance()),
    )


Progress = Callable[[int], None]
"""Told how many more missions are done."""


def _dask(
    specs: list[SuiteMission], scheduler: Any, progress: Progress
) -> Iterator[tuple[MissionResult, float]]:
    try:
        from distributed import Client, as_completed
    except ImportError:  # the optional extra
        raise SystemExit("oslim bench suite --scheduler needs Dask: pip install -e '.[cluster]'") from None
    client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
    try:
        futures = client.map(run_suite_mission, specs, pure=False)
        for _ in as_completed(futures):
            progress(1)
        yield from client.gather(futures)
    finally:
        if client is not scheduler:
            client.close()


def run_suite(
    class_files: Sequence[Path],
    runs: int,
    *,
    first_seed: int = 0,
    config_path: str | None = None,
    overrides: Sequence[str] = (),
    jobs: int | None = None,
    scheduler: Any = None,
    progress: Progress = lambda _: None,
    oracle: bool = False,
    arrival_radius_m: float = 0.0,
    time_scale: float = 1.0,
) -> Iterator[ClassSummary]:
    """Every class over seeds first_seed..first_seed+runs-1; yields each class's summary in order.

    ``scheduler``: a Dask scheduler address (or a ``distributed.Client``) to run the missions on;
    None runs them in ``jobs`` local processes (default: the cores). ``oracle``: every mission with
    the perfect declaration guard (``run_mission``), a bound on what the guards cost.
    ``arrival_radius_m``: every vehicle stops this far short of its targets. ``time_scale``: every
    class's time limit times this (a diagnostic)."""
    batches = class_missions(
        class_files, runs, first_seed, config_path, overrides, oracle, arrival_radius_m, time_scale
    )
    specs = [spec for _, batch in batches for spec in batch]
    if scheduler is not None:
        outcomes = _dask(specs, scheduler, progress)
    else:
        outcomes = in_order(run_suite_mission, specs, jobs, progress)
    for name, batch in batches:
        low, high = _world_class(batch[0].class_path, batch[0].overrides).world.vehicle.speed_mps
        yield summarise_class(name, [next(outcomes) for _ in range(runs)], speed_drawn=high > low)


def class_missions(
    class_files: Sequence[Path],
    runs: int,
    first_seed: int,
    config_path: str | None,
    overrides: Sequence[str],
    oracle: bool = False,
    arrival_radius_m: float = 0.0,
    time_scale: float = 1.0,
) -> list[tuple[str, list[SuiteMission]]]:
    """Each class's name and its missions over seeds first_seed..first_seed+runs-1. A broken
    configuration, or a class that cannot draw its first world with it, fails here, once."""
    if runs < 1:
        raise ValueError("runs must be >= 1")
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise ValueError("time_scale must be a positive number")
    config = service_config(config_path, tuple(overrides))
    classes = [_world_class(str(path), tuple(overrides)) for path in class_files]
    for c in classes:
        draw_scenario(c, first_seed, config)
    seeds = range(first_seed, first_seed + runs)
    keys = tuple(overrides)

    def mission(c: WorldClass, seed: int) -> SuiteMission:
        return SuiteMission(c.origin, seed, config_path, keys, oracle, arrival_radius_m, time_scale)

    return [(c.name, [mission(c, seed) for seed in seeds]) for c in classes]


def suite_classes(directory: str | Path | None = None) -> list[Path]:
    """The class files of ``directory`` (default: config/suites)."""
    return available_classes(Path(directory) if directory is not None else SUITE_DIR)


def timed(summaries: Iterator[ClassSummary]) -> Iterator[ClassSummary | SuiteSummary]:
    """The class summaries as they come, then the suite's summary (timed from the first request)."""
    start = time.perf_counter()
    done = []
    for summary in summaries:
        done.append(summary)
        yield summary
    yield summarise_suite(done, time.perf_counter() - start)
