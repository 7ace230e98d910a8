"""The world generator: classes of worlds, and concrete worlds drawn from them by seed.

A *world class* is one TOML file under ``config/suites/``: the search area (``[area]``), the
ranges every property of a world is drawn from (``[world...]``), and the class's own
``[suite]`` table (what it is for, its time limit, the plume's hit rate it spans). It never
holds a service setting: the suite runs every class with one service configuration.

``draw_scenario(world_class, seed, config)`` draws one world and returns it as a concrete
``Scenario`` (the same type a file under ``config/scenarios/`` gives), so the simulator, the stub
and the benchmarks run a drawn world exactly like a hand-written one. The same seed always
draws the same world. A range is ``[lo, hi]`` (drawn uniformly) or one number (fixed).

What is drawn, and from what (defaults: the *base world*; a class changes what defines it):

- geometry: the source anywhere at least ``source_margin_m`` from the edges (or fixed), the
  start anywhere at least ``min_separation_m`` from it (or fixed), 0-3 rectangular obstacles that
  never cover the source or the start and never cut the start off from the source;
- flow: a direction (any, by default), a speed, and one of the models ``uniform`` (steady),
  ``turbulent`` (white noise), ``meander`` (random modes with drawn strength, time and length
  scales) or ``switched`` (a direction switch, seed hmm-plume-mapping eq. 18, by a drawn angle at a
  drawn time);
- plume: how long the source has been releasing when the mission starts (developed: 300-900 s;
  the young-plume class 0-60 s), release rate, puff growth and random walk;
- detector: the concentration scale relative to the service's threshold (``puff_mass`` is in
  units of ``sensor.threshold``), mu, false alarms, a response time and reading noise (neither in the
  suite; a slow sensor's service is told its time, as a user sets ``sensor.response_s``);
- flow sensor: noise and a direction bias of a few degrees;
- vehicle: speed, and rover (turns on the spot) or AUV kinematics (cannot; slows in turns), and a
  position error of the autopilot's (none in the suite).
"""

from __future__ import annotations

import math
import tomllib
import zlib
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from service.core.config import Config, apply_override, load_config, parse_override
from service.core.errors import ConfigError
from service.core.grid import Grid, Rectangle
from sim_bridge.autopilot import AUTOPILOTS, VehicleKind
from sim_bridge.scenarios import WORLD_KEY, Scenario, WorldSpec

SUITE_DIR = Path(__file__).resolve().parent.parent / "config" / "suites"

GENERATOR_STREAM = 7
"""Spawn key of the generator's own random stream: apart from build_world's streams (0-4)."""


def _class_key(name: str) -> int:
    """A stable number for a class name, so that the same seed draws unrelated worlds in different
    classes (otherwise every class would share its sources and starts, and a hard geometry would
    fail every class at once)."""
    return zlib.crc32(name.encode("utf-8"))


def _as_range(value: Any) -> Any:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (value, value)
    return tuple(value) if isinstance(value, list) else value


def _ordered(value: tuple[float, float]) -> tuple[float, float]:
    if value[0] > value[1]:
        raise ValueError(f"a range is [lo, hi] with lo <= hi, got {list(value)}")
    return value


Range = Annotated[tuple[float, float], BeforeValidator(_as_range), AfterValidator(_ordered)]
Point = Annotated[tuple[float, float], BeforeValidator(_as_range)]


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class GeometryRanges(_Spec):
    source_m: Point | None = None
    """A fixed source (the papers' scenarios); None: drawn."""
    start_m: Point | None = None
    """A fixed start; None: drawn."""
    source_margin_m: float = Field(default=10.0, ge=0)
    start_margin_m: float = Field(default=5.0, ge=0)
    min_separation_m: float = Field(default=30.0, ge=0)
    """A drawn start is at least this far from the source."""
    obstacles: Range = (0, 0)
    """How many rectangular obstacles (whole numbers)."""
    obstacle_size_m: Range = (5.0, 20.0)
    """Side of an obstacle."""
    obstacle_clearance_m: float = Field(default=5.0, ge=0)
    """No obstacle comes nearer than this to the source or the start."""


FlowModel = Literal["uniform", "turbulent", "meander", "switched"]


class FlowRanges(_Spec):
    models: tuple[FlowModel, ...] = Field(default=("meander",), min_length=1)
    """One is drawn per world."""
    direction_deg: Range = (0.0, 360.0)
    """The direction the flow moves toward, degrees counter-clockwise from East (x)."""
    speed_mps: Range = (0.5, 1.5)
    turbulence: Range = (0.2, 0.5)
    """turbulent: white-noise std of each component, as a share of the speed."""
    meander_strength: Range = (0.2, 0.4)
    """meander: RMS of the perturbation, as a share of the speed."""
    meander_time_s: Range = (10.0, 60.0)
    meander_length_m: Range = (30.0, 120.0)
    switch_s: Range = (30.0, 150.0)
    """switched: when the direction switches, s after the mission starts."""
    switch_angle_deg: Range = (45.0, 135.0)
    """switched: by how much (either way)."""


class PlumeRanges(_Spec):
    spin_up_s: Range = (300.0, 900.0)
    """How long the source has been releasing when the mission starts."""
    release_rate_hz: Range = (5.0, 20.0)
    puff_mass: Range = (0.7, 1.5)
    """Concentration scale, in units of the service's sensor.threshold (m^2)."""
    initial_sigma_m: Range = (0.3, 0.3)
    spread_rate_m2ps: Range = (0.01, 0.04)
    random_walk_m_per_sqrt_s: Range = (0.2, 0.4)


class DetectorRanges(_Spec):
    detection_probability: Range = (0.8, 1.0)
    false_alarm_rate_hz: Range = (0.0, 0.002)
    response_s: Range = (0.0, 0.0)
    """The sensor's first-order time constant; the suite's sensors are instantaneous."""
    noise_std: Range = (0.0, 0.0)
    """White noise on every reading, in units of the threshold; the suite's readings have none."""
    response_told: Range = (1.0, 1.0)
    """A slow sensor's service is configured with ``sensor.response_s`` = its drawn time constant
    times this: 1 for a user who set the datasheet's value, 0 for one who left the default."""


class FlowSensorRanges(_Spec):
    noise_std_mps: Range = (0.0, 0.1)
    bias_deg: Range = (-5.0, 5.0)


class VehicleRanges(_Spec):
    kinds: tuple[VehicleKind, ...] = Field(default=(VehicleKind.ROVER, VehicleKind.SUB), min_length=1)
    speed_mps: Range = (0.5, 2.0)
    position_error_m: Range = (0.0, 0.0)
    """The autopilot's position error (each axis's standard deviation); the suite's is perfect."""
    position_error_s: Range = (60.0, 60.0)
    """Its correlation time, s."""
    accel_mps2: Range = (0.0, 0.0)
    """The autopilot's acceleration and braking limit (ArduPilot's ATC_ACCEL_MAX, 1 m/s/s on Rover);
    0: the suite's vehicles change speed at once."""
    pivot_angle_deg: Range = (60.0, 60.0)
    """A rover's heading error above which it turns on the spot (ArduPilot's WP_PIVOT_ANGLE); 180: a
    rover that cannot, an Ackermann-steered car such as ArduPilot SITL's default rover frame. An
    AUV never turns on the spot."""


class WorldRanges(_Spec):
    geometry: GeometryRanges = Field(default_factory=GeometryRanges)
    flow: FlowRanges = Field(default_factory=FlowRanges)
    plume: PlumeRanges = Field(default_factory=PlumeRanges)
    detector: DetectorRanges = Field(default_factory=DetectorRanges)
    flow_sensor: FlowSensorRanges = Field(default_factory=FlowSensorRanges)
    vehicle: VehicleRanges = Field(default_factory=VehicleRanges)


class SuiteEntry(_Spec):
    description: str = Field(min_length=1)
    time_limit_s: float = Field(gt=0)
    """The limit for a vehicle at ``reference_speed_mps`` over a ``reference_side_m`` area."""
    reference_speed_mps: float = Field(default=1.0, gt=0)
    reference_side_m: float = Field(default=100.0, gt=0)
    hit_rate_20m: Range
    """The share of 1 s ticks with odour 20 m downflow of the source, on its mean line, that the
    class's worlds span (10th to 90th percentile over worlds)."""


AREA_KEYS = frozenset({"x_min", "x_max", "y_min", "y_max", "columns", "rows"})


class WorldClass(BaseModel):
    """One class of worlds (a file under config/suites/)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    origin: str
    suite: SuiteEntry
    area: dict[str, float | int]
    world: WorldRanges

    def time_limit_s(self, side_m: float, speed_mps: float) -> float:
        """The class's limit scaled with the area's side and the vehicle's speed."""
        s = self.suite
        return s.time_limit_s * (side_m / s.reference_side_m) * (s.reference_speed_mps / speed_mps)


def available_classes(directory: Path = SUITE_DIR) -> list[Path]:
    """The class files of a suite directory, by name."""
    files = sorted(Path(directory).glob("*.toml"))
    if not files:
        raise ConfigError(f"{directory}: no world classes (*.toml)")
    return files


def load_class(path: str | Path, overrides: Sequence[str] = ()) -> WorldClass:
    """Read and validate a class file; an error names the file and the key. ``overrides``
    (``world.KEY=VALUE``, as ``--set`` gives them) replace the class's world ranges, e.g.
    ``world.flow_sensor.bias_deg=[-15, 15]``: the same worlds made harder in one respect."""
    path = Path(path)
    origin = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{origin}: no such world class") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{origin}: not valid TOML: {exc}") from None
    extra = sorted(set(data) - {"suite", "area", "world"})
    if extra:
        raise ConfigError(
            f"{origin}: {extra[0]}: a world class sets only [suite], [area] and [world] (no service settings)"
        )
    world = dict(data.get("world", {}))
    for text in overrides:
        key, value = parse_override(text)
        if key[0] != WORLD_KEY:
            raise ConfigError(f"--set {text}: a class's worlds take world.KEY=VALUE only")
        apply_override(world, key[1:], value, text)
    area = data.get("area", {})
    unknown = sorted(set(area) - AREA_KEYS)
    if unknown:
        raise ConfigError(f"{origin}: area.{unknown[0]}: unknown key (obstacles are drawn: world.geometry)")
    try:
        return WorldClass.model_validate(
            {"name": path.stem, "origin": origin, "suite": data.get("suite"), "area": area,
             "world": world}
        )  # fmt: skip
    except ValidationError as exc:
        lines = []
        for item in exc.errors():
            loc = ".".join(str(p) for p in item["loc"] if not str(p).startswith(("function-", "tuple[")))
            reason = "unknown key" if item["type"] == "extra_forbidden" else item["msg"]
            lines.append(f"{origin}: {loc}: {reason}")
        raise ConfigError("\n".join(dict.fromkeys(lines))) from None


@dataclass(frozen=True)
class DrawnWorld:
    """One world of a class: the scenario to run and its time limit."""

    scenario: Scenario
    time_limit_s: float


class _Draw:
    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def value(self, r: tuple[float, float]) -> float:
        return float(self.rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])

    def count(self, r: tuple[float, float]) -> int:
        return int(self.rng.integers(math.ceil(r[0]), math.floor(r[1]) + 1))

    def choice(self, options: tuple[Any, ...]) -> Any:
        return options[int(self.rng.integers(len(options)))]


def _rotate(speed: float, angle_deg: float) -> list[float]:
    a = math.radians(angle_deg)
    return [speed * math.cos(a), speed * math.sin(a)]


def _flow_table(spec: FlowRanges, draw: _Draw, spin_up_s: float) -> dict[str, Any]:
    model = draw.choice(spec.models)
    speed = draw.value(spec.speed_mps)
    direction = draw.value(spec.direction_deg)
    mean = _rotate(speed, direction)
    if model == "uniform":
        return {"model": "uniform", "mean_mps": mean}
    if model == "turbulent":
        return {"model": "turbulent", "mean_mps": mean, "noise_std_mps": speed * draw.value(spec.turbulence)}
    if model == "meander":
        return {
            "model": "meander",
            "mean_mps": mean,
            "strength_mps": speed * draw.value(spec.meander_strength),
            "time_scale_s": draw.value(spec.meander_time_s),
            "length_scale_m": draw.value(spec.meander_length_m),
        }
    turn = draw.value(spec.switch_angle_deg) * draw.choice((-1.0, 1.0))
    return {
        "model": "switched",
        "before_mps": mean,
        "after_mps": _rotate(speed, direction + turn),
        "switch_s": spin_up_s + draw.value(spec.switch_s),  # the flow's clock runs through the spin-up
    }


def _inside(grid: Grid, margin: float, draw: _Draw) -> tuple[float, float]:
    x0, x1 = grid.x_min + margin, grid.x_max - margin
    y0, y1 = grid.y_min + margin, grid.y_max - margin
    if not (x0 < x1 and y0 < y1):
        raise ConfigError(f"a margin of {margin} m leaves no room in the area")
    return draw.value((x0, x1)), draw.value((y0, y1))


def _near(box: Rectangle, point: tuple[float, float], clearance: float) -> bool:
    x0, y0, x1, y1 = box
    return x0 - clearance <= point[0] <= x1 + clearance and y0 - clearance <= point[1] <= y1 + clearance


def connected(grid: Grid, a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether free cells (8-neighbour moves) join the cells of a and b."""
    blocked = grid.obstacle_mask
    start, goal = grid.row_col(grid.cell_of(*a)), grid.row_col(grid.cell_of(*b))
    if blocked[start] or blocked[goal]:
        return False
    seen = np.zeros_like(blocked)
    seen[start] = True
    queue = deque([start])
    rows, cols = grid.shape
    while queue:
        r, c = queue.popleft()
        if (r, c) == goal:
            return True
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nr, nc = r + dr, c + dc
                if 0 <= nr < rows and 0 <= nc < cols and not seen[nr, nc] and not blocked[nr, nc]:
                    seen[nr, nc] = True
                    queue.append((nr, nc))
    return False


def _geometry(
    spec: GeometryRanges, grid: Grid, draw: _Draw
) -> tuple[tuple[float, float], tuple[float, float], list[Rectangle]]:
    source = spec.source_m or _inside(grid, spec.source_margin_m, draw)
    start = spec.start_m
    for _ in range(10_000):
        if start is not None:
            break
        point = _inside(grid, spec.start_margin_m, draw)
        if math.dist(point, source) >= spec.min_separation_m:
            start = point
    if start is None:
        raise ConfigError(f"no start {spec.min_separation_m} m from the source fits in the area")
    obstacles: list[Rectangle] = []
    wanted = draw.count(spec.obstacles)
    for _ in range(1000):
        if len(obstacles) == wanted:
            break
        w, h = draw.value(spec.obstacle_size_m), draw.value(spec.obstacle_size_m)
        x0 = draw.value((grid.x_min, grid.x_max - w))
        y0 = draw.value((grid.y_min, grid.y_max - h))
        box = (x0, y0, x0 + w, y0 + h)
        if _near(box, source, spec.obstacle_clearance_m) or _near(box, start, spec.obstacle_clearance_m):
            continue
        trial = Grid(grid.x_min, grid.x_max, grid.y_min, grid.y_max, grid.columns, grid.rows,
                     obstacles=(*obstacles, box))  # fmt: skip
        if trial.in_obstacle(*source) or trial.in_obstacle(*start) or not connected(trial, start, source):
            continue
        obstacles.append(box)
    return source, start, obstacles


def draw_scenario(world_class: WorldClass, seed: int, config: Config | None = None) -> DrawnWorld:
    """The world ``seed`` of ``world_class``, run by the service configuration ``config``
    (default: config/default.toml) with the class's area, the drawn obstacles and the GUIDED mode
    of the drawn vehicle."""
    base = config if config is not None else load_config(None)
    stream = np.random.SeedSequence([seed, _class_key(world_class.name)], spawn_key=(GENERATOR_STREAM,))
    draw = _Draw(np.random.default_rng(stream))
    spec = world_class.world
    area = {**base.area.model_dump(), **world_class.area, "obstacles": []}
    grid = Grid.from_config(base.area.model_validate(area))
    source, start, obstacles = _geometry(spec.geometry, grid, draw)
    kind: VehicleKind = draw.choice(spec.vehicle.kinds)
    speed = draw.value(spec.vehicle.speed_mps)
    auv = kind is VehicleKind.SUB
    plume = spec.plume
    spin_up_s = draw.value(plume.spin_up_s)
    world: dict[str, Any] = {
        "seed": seed,
        "dt_s": 0.1,
        "source": {"position_m": list(source)},
        "flow": _flow_table(spec.flow, draw, spin_up_s),
        "plume": {
            "spin_up_s": spin_up_s,
            "spin_up_step_s": 1.0,
            "release_rate_hz": draw.value(plume.release_rate_hz),
            "puff_mass": draw.value(plume.puff_mass) * base.sensor.threshold,
            "initial_sigma_m": draw.value(plume.initial_sigma_m),
            "spread_rate_m2ps": draw.value(plume.spread_rate_m2ps),
            "random_walk_m_per_sqrt_s": draw.value(plume.random_walk_m_per_sqrt_s),
            "max_age_s": 900.0,
            "margin_m": 20.0,
        },
        "vehicle": {
            "kind": kind.value,
            "start_m": list(start),
            "heading_deg": draw.value((0.0, 360.0)) - 180.0,
            "speed_mps": speed,
            "max_turn_rate_dps": 30.0 if auv else 90.0,
            "pivot_angle_deg": 180.0,  # an AUV never pivots; a rover's is drawn last, below
            "slows_to_turn": auv,
        },
        "detector": {
            "detection_probability": draw.value(spec.detector.detection_probability),
            "false_alarm_rate_hz": draw.value(spec.detector.false_alarm_rate_hz),
        },
        "flow_sensor": {
            "noise_std_mps": draw.value(spec.flow_sensor.noise_std_mps),
            "bias_deg": draw.value(spec.flow_sensor.bias_deg),
        },
    }
    # drawn last, so that a fixed response leaves every other draw of the seed as it was
    response_s = draw.value(spec.detector.response_s)
    world["detector"]["response_s"] = response_s
    told_s = response_s * draw.value(spec.detector.response_told)
    world["detector"]["noise_std"] = draw.value(spec.detector.noise_std)
    world["vehicle"]["position_error_m"] = draw.value(spec.vehicle.position_error_m)
    world["vehicle"]["position_error_s"] = draw.value(spec.vehicle.position_error_s)
    world["vehicle"]["accel_mps2"] = draw.value(spec.vehicle.accel_mps2)
    if not auv:
        world["vehicle"]["pivot_angle_deg"] = draw.value(spec.vehicle.pivot_angle_deg)
    service = base.model_copy(
        update={
            "area": base.area.model_validate({**area, "obstacles": obstacles}),
            "mavlink": base.mavlink.model_copy(update={"guided_mode": AUTOPILOTS[kind].guided}),
            "vehicle": base.vehicle.model_copy(update={"id": world_class.name}),
        }
    )
    if response_s > 0:  # the user configures the sensor the vehicle carries
        service = service.model_copy(update={"sensor": base.sensor.model_copy(update={"response_s": told_s})})
    try:
        world_spec = WorldSpec.model_validate(world, strict=False)
    except ValidationError as exc:  # a class whose ranges reach outside what a world accepts
        raise ConfigError(f"{world_class.origin}: seed {seed} drew an invalid world: {exc}") from None
    side = max(grid.x_max - grid.x_min, grid.y_max - grid.y_min)
    return DrawnWorld(
        scenario=Scenario(name=world_class.name, config=service, world=world_spec, origin=world_class.origin),
        time_limit_s=world_class.time_limit_s(side, speed),
    )
