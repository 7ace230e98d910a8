"""Named scenarios: one TOML file each under ``config/scenarios/``.

A scenario file holds the service's configuration tables (``[area]``, ``[sensor]``,
``[mapping]``...), validated by ``service.core.config.build_config``, plus a ``[world]`` table that
describes the world the service does not know: the source, the flow model, the plume, the
vehicle and the detector. ``load_scenario`` validates both (unknown keys, wrong types and
out-of-range values raise ``ConfigError`` naming the key); ``build_world`` turns a scenario and
a seed into a ``World``, drawing the random placements from that seed.

Positions are ``position_m = [x, y]`` in the map frame, ``cell = [i, j]`` in the papers'
numbering (column i from the west, row j from the NORTH, see ``service.core.grid``), or ``"random"``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Self

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from service.core.config import Config, apply_override, build_config, parse_override
from service.core.errors import ConfigError
from service.core.grid import Grid
from sim_bridge.autopilot import AUTOPILOTS, VehicleKind
from sim_bridge.detector import BinaryDetector, DetectorParams
from sim_bridge.flow import FlowField, MeanderingFlow, SwitchedFlow, TurbulentFlow, UniformFlow
from sim_bridge.flow_sensor import FlowSensor, FlowSensorParams
from sim_bridge.navigation import Navigation, NavigationParams
from sim_bridge.plume import PuffParams, PuffPlume
from sim_bridge.vehicle import VehicleParams, VehicleState
from sim_bridge.world import World

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "config" / "scenarios"
WORLD_KEY = "world"
SEARCH_SECTIONS = frozenset({"mapping", "planning", "declaration"})
"""Service tables a scenario may not hold: every world runs with the one search configuration."""


def _as_tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


Point = Annotated[tuple[float, float], BeforeValidator(_as_tuple)]
CellIJ = Annotated[
    tuple[Annotated[int, Field(ge=1)], Annotated[int, Field(ge=1)]], BeforeValidator(_as_tuple)
]
Random = Literal["random"]


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class SourceSpec(_Spec):
    position_m: Point | Random | None = None
    cell: CellIJ | None = None

    @model_validator(mode="after")
    def _one_of(self) -> Self:
        if (self.position_m is None) == (self.cell is None):
            raise ValueError("give exactly one of position_m or cell")
        return self


class _MeanFlow(_Spec):
    mean_mps: Point = (1.0, 0.0)
    """Mean flow toward (x East, y North), m/s."""
    random_direction: bool = False
    """Rotate the mean flow to a direction drawn from the seed (same speed)."""


class UniformFlowSpec(_MeanFlow):
    model: Literal["uniform"]


class SwitchedFlowSpec(_Spec):
    model: Literal["switched"]
    before_mps: Point = (1.0, 0.0)
    after_mps: Point = (0.0, 1.0)
    switch_s: float = Field(default=30.0, ge=0)


class MeanderFlowSpec(_MeanFlow):
    model: Literal["meander"]
    strength_mps: float = Field(default=0.4, ge=0)
    time_scale_s: float = Field(default=20.0, gt=0)
    length_scale_m: float = Field(default=60.0, gt=0)
    modes: int = Field(default=8, ge=1, le=256)


class TurbulentFlowSpec(_MeanFlow):
    model: Literal["turbulent"]
    noise_std_mps: float = Field(default=0.5, ge=0)
    noise_period_s: float = Field(default=1.0, gt=0)


FlowSpec = Annotated[
    UniformFlowSpec | SwitchedFlowSpec | MeanderFlowSpec | TurbulentFlowSpec, Field(discriminator="model")
]


class PlumeSpec(_Spec):
    release_rate_hz: float = Field(default=10.0, gt=0, le=10_000)
    puff_mass: float = Field(default=1.0, gt=0)
    initial_sigma_m: float = Field(default=0.3, gt=0)
    spread_rate_m2ps: float = Field(default=0.02, ge=0)
    random_walk_m_per_sqrt_s: float = Field(default=0.3, ge=0)
    max_age_s: float = Field(default=600.0, gt=0)
    max_puffs: int = Field(default=50_000, ge=1, le=10_000_000)
    margin_m: float = Field(default=20.0, ge=0)
    """Puffs are dropped beyond the search area grown by this margin."""
    spin_up_s: float = Field(default=0.0, ge=0, le=3600)
    """The source has been releasing for this long when the mission starts (0: it starts with the
    mission, the plume still empty). The flow's clock runs through the spin-up too."""
    spin_up_step_s: float | None = Field(default=None, gt=0, le=2.0)
    """Integration step of the spin-up (default: world.dt_s). A coarser step keeps long spin-ups
    cheap: a puff's random walk is exact at any step, its advection an Euler step of the flow."""


class VehicleSpec(_Spec):
    kind: VehicleKind = Field(default=VehicleKind.ROVER, strict=False)
    start_m: Point | Random | None = None
    start_cell: CellIJ | None = None
    heading_deg: float = Field(default=0.0, ge=-360, le=360)
    """Initial heading, compass degrees (0 North, 90 East)."""
    speed_mps: float = Field(default=1.0, gt=0, le=50)
    max_turn_rate_dps: float = Field(default=90.0, gt=0)
    pivot_angle_deg: float = Field(default=60.0, gt=0, le=180)
    slows_to_turn: bool = False
    """AUV kinematics: no turning on the spot (set pivot_angle_deg = 180), slower in turns."""
    arrival_radius_m: float = Field(default=0.0, ge=0, le=50)
    """The autopilot stops this far short of a target (ArduPilot's WP_RADIUS); 0: on it."""
    position_error_m: float = Field(default=0.0, ge=0, le=50)
    """Standard deviation of each axis of the autopilot's position error, m (``navigation``)."""
    position_error_s: float = Field(default=60.0, gt=0)
    """Correlation time of that error, s."""
    accel_mps2: float = Field(default=0.0, ge=0, le=50)
    """Acceleration and braking limit, m/s/s: the autopilot speeds up at most this fast and brakes
    to stop at its target, as ArduPilot's position controller does; 0: speed changes at once."""

    @model_validator(mode="after")
    def _one_of(self) -> Self:
        if (self.start_m is None) == (self.start_cell is None):
            raise ValueError("give exactly one of start_m or start_cell")
        return self


class DetectorSpec(_Spec):
    threshold: float | None = Field(default=None, gt=0)
    """Detectable concentration; default: the service's sensor.threshold."""
    detection_probability: float = Field(default=1.0, gt=0, le=1)
    false_alarm_rate_hz: float = Field(default=0.0, ge=0)
    hold_s: float = Field(default=1.0, gt=0)
    response_s: float = Field(default=0.0, ge=0)
    """Time constant of the sensor's first-order lag, s; 0 = instantaneous."""
    noise_std: float = Field(default=0.0, ge=0)
    """White noise on every reading, in units of the threshold."""


class FlowSensorSpec(_Spec):
    noise_std_mps: float = Field(default=0.0, ge=0)
    """White noise on each component of every flow reading, m/s."""
    bias_deg: float = Field(default=0.0, ge=-180, le=180)
    """Every flow reading turned by this angle (counter-clockwise), degrees."""


class WorldSpec(_Spec):
    seed: int = Field(default=0, ge=0)
    """Seed used when none is given on the command line."""
    dt_s: float = Field(default=0.1, gt=0, le=1.0)
    source: SourceSpec
    flow: FlowSpec
    plume: PlumeSpec = Field(default_factory=PlumeSpec)
    vehicle: VehicleSpec
    detector: DetectorSpec = Field(default_factory=DetectorSpec)
    flow_sensor: FlowSensorSpec = Field(default_factory=FlowSensorSpec)
    random_margin_m: float = Field(default=10.0, ge=0)
    """Random positions keep this far from the area's edges."""
    random_min_separation_m: float = Field(default=30.0, ge=0)
    """A random start is at least this far from the source."""


@dataclass(frozen=True)
class Scenario:
    name: str
    config: Config
    world: WorldSpec
    origin: str

    @property
    def grid(self) -> Grid:
        return Grid.from_config(self.config.area)


def available_scenarios() -> list[str]:
    """Names of the scenarios shipped in config/scenarios."""
    return sorted(path.stem for path in SCENARIO_DIR.glob("*.toml"))


def _locate(name_or_path: str | Path) -> Path:
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise ConfigError(f"{path}: no such scenario file")
        return path
    candidate = SCENARIO_DIR / f"{name_or_path}.toml"
    if not candidate.is_file():
        raise ConfigError(f"unknown scenario {name_or_path!r}; known: {', '.join(available_scenarios())}")
    return candidate


def _format(error: ValidationError, origin: str) -> str:
    lines = []
    for item in error.errors():
        # drop pydantic's union-branch labels (e.g. 'meander', 'tuple[float, float]') from the key
        loc = ".".join([WORLD_KEY, *(str(p) for p in item["loc"] if not _is_branch_label(p))])
        reason = "unknown key" if item["type"] == "extra_forbidden" else item["msg"]
        lines.append(f"{origin}: {loc}: {reason}")
    return "\n".join(dict.fromkeys(lines))


def _is_branch_label(part: object) -> bool:
    return isinstance(part, str) and (part in {"uniform", "switched", "meander", "turbulent"} or "[" in part)


# keys that exclude each other: overriding one drops the other from the file's table
_ALTERNATIVES: dict[tuple[str, ...], tuple[str, ...]] = {
    ("source", "position_m"): ("source", "cell"),
    ("source", "cell"): ("source", "position_m"),
    ("vehicle", "start_m"): ("vehicle", "start_cell"),
    ("vehicle", "start_cell"): ("vehicle", "start_m"),
}


def _put(data: dict[str, Any], path: list[str], value: Any, text: str) -> None:
    other = _ALTERNATIVES.get(tuple(path))
    if other is not None and isinstance(data.get(other[0]), dict):
        data[other[0]].pop(other[1], None)
    apply_override(data, path, value, text)


def load_scenario(name_or_path: str | Path, overrides: tuple[str, ...] | list[str] = ()) -> Scenario:
    """Load a scenario by name (config/scenarios/NAME.toml) or path; ``--set`` overrides apply to
    both parts (``world.flow.strength_mps=0.2``, ``area.columns=20``)."""
    path = _locate(name_or_path)
    origin = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{origin}: not valid TOML: {exc}") from None
    search = sorted(set(data) & SEARCH_SECTIONS)
    if search:
        raise ConfigError(
            f"{origin}: [{search[0]}]: a scenario sets only the area, the vehicle, its sensors and the"
            " world; the search settings are the service's (config/default.toml, or --set)"
        )
    world_data = data.pop(WORLD_KEY, None)
    if not isinstance(world_data, dict):
        raise ConfigError(f"{origin}: missing [{WORLD_KEY}] table")
    service_overrides = []
    for text in overrides:
        key, value = parse_override(text)
        if key[0] == WORLD_KEY:
            _put(world_data, key[1:], value, text)
        else:
            service_overrides.append(text)
    config = build_config(data, service_overrides, origin=origin)
    try:
        world = WorldSpec.model_validate(world_data)
    except ValidationError as exc:
        raise ConfigError(_format(exc, origin)) from None
    scenario = Scenario(name=path.stem, config=config, world=world, origin=origin)
    _check_consistency(scenario)
    return scenario


def _check_consistency(scenario: Scenario) -> None:
    grid = scenario.grid
    world = scenario.world
    origin = scenario.origin
    fixed = {
        "world.source": _fixed_point(
            grid, world.source.position_m, world.source.cell, "world.source", origin
        ),
        "world.vehicle": _fixed_point(
            grid, world.vehicle.start_m, world.vehicle.start_cell, "world.vehicle", origin
        ),
    }
    for key, point in fixed.items():
        if point is None:
            continue
        if not grid.contains(*point):
            raise ConfigError(f"{origin}: {key}: {point} is outside the search area")
        if grid.in_obstacle(*point):
            raise ConfigError(f"{origin}: {key}: {point} is inside an obstacle")
    guided = AUTOPILOTS[world.vehicle.kind].guided
    if scenario.config.mavlink.guided_mode != guided:
        raise ConfigError(
            f"{origin}: mavlink.guided_mode: {scenario.config.mavlink.guided_mode} is not GUIDED "
            f"({guided}) of world.vehicle.kind = {world.vehicle.kind.value!r}"
        )


def _fixed_point(
    grid: Grid,
    position: tuple[float, float] | str | None,
    cell: tuple[int, int] | None,
    key: str,
    origin: str,
) -> tuple[float, float] | None:
    if cell is not None:
        i, j = cell
        if i > grid.columns or j > grid.rows:
            raise ConfigError(
                f"{origin}: {key}: cell ({i}, {j}) outside the {grid.columns} x {grid.rows} grid"
            )
        return grid.centre(grid.flat_index(i + (j - 1) * grid.columns))
    if isinstance(position, tuple):
        return position
    return None


def _rotate(vector: tuple[float, float], angle_rad: float) -> tuple[float, float]:
    speed = math.hypot(*vector)
    return speed * math.cos(angle_rad), speed * math.sin(angle_rad)


class _Placer:
    """Draws the random placements of a scenario from one generator, in a fixed order."""

    def __init__(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self.grid = scenario.grid
        self.world = scenario.world
        self.rng = rng
        self.origin = scenario.origin

    def flow_direction(self, default: tuple[float, float], random_direction: bool) -> tuple[float, float]:
        angle = float(self.rng.uniform(0.0, 2.0 * math.pi))  # always drawn: placements stay aligned
        return _rotate(default, angle) if random_direction else default

    def draw(self, key: str, accept: Any) -> tuple[float, float]:
        g, margin = self.grid, self.world.random_margin_m
        x0, x1 = g.x_min + margin, g.x_max - margin
        y0, y1 = g.y_min + margin, g.y_max - margin
        if not (x0 < x1 and y0 < y1):
            raise ConfigError(f"{self.origin}: world.random_margin_m leaves no room for {key}")
        for _ in range(10_000):
            point = (float(self.rng.uniform(x0, x1)), float(self.rng.uniform(y0, y1)))
            if not g.in_obstacle(*point) and accept(point):
                return point
        raise ConfigError(f"{self.origin}: {key}: no admissible random position found")


def _flow(spec: FlowSpec, mean_mps: tuple[float, float], rng: np.random.Generator) -> FlowField:
    match spec:
        case UniformFlowSpec():
            return UniformFlow(mean_mps)
        case SwitchedFlowSpec():
            return SwitchedFlow(spec.before_mps, spec.after_mps, spec.switch_s)
        case MeanderFlowSpec():
            return MeanderingFlow(
                mean_mps, spec.strength_mps, spec.time_scale_s, spec.length_scale_m, rng, modes=spec.modes
            )
        case TurbulentFlowSpec():
            return TurbulentFlow(mean_mps, spec.noise_std_mps, rng, noise_period_s=spec.noise_period_s)


@dataclass(frozen=True)
class Placement:
    """Where a seed put the source and the vehicle, and the mean flow it chose."""

    source_m: tuple[float, float]
    start_m: tuple[float, float]
    mean_flow_mps: tuple[float, float]


def place(scenario: Scenario, seed: int | None = None) -> Placement:
    """Resolve the scenario's random placements for ``seed`` (default: the scenario's seed)."""
    return _resolve(scenario, _streams(scenario, seed)[0])


def _streams(scenario: Scenario, seed: int | None) -> list[np.random.Generator]:
    # independent child streams: placement, flow, plume, detector, flow sensor, navigation; changing
    # one leaves the others alone (and a stream added at the end leaves the earlier ones as they were)
    root = np.random.default_rng(scenario.world.seed if seed is None else seed)
    return root.spawn(6)


def _resolve(scenario: Scenario, rng: np.random.Generator) -> Placement:
    world, grid = scenario.world, scenario.grid
    placer = _Placer(scenario, rng)
    spec = world.flow
    if isinstance(spec, SwitchedFlowSpec):
        mean = spec.before_mps
        placer.flow_direction(mean, False)
    else:
        mean = placer.flow_direction(spec.mean_mps, spec.random_direction)
    speed = math.hypot(*mean)
    ux, uy = (mean[0] / speed, mean[1] / speed) if speed > 0 else (0.0, 0.0)
    cx, cy = (grid.x_min + grid.x_max) / 2.0, (grid.y_min + grid.y_max) / 2.0

    source = _fixed_point(grid, world.source.position_m, world.source.cell, "world.source", scenario.origin)
    if source is None:
        # upflow half of the area, so that the plume crosses at least half of it
        source = placer.draw("world.source", lambda p: (p[0] - cx) * ux + (p[1] - cy) * uy <= 0.0)
    start = _fixed_point(
        grid, world.vehicle.start_m, world.vehicle.start_cell, "world.vehicle", scenario.origin
    )
    if start is None:
        src = source
        start = placer.draw(
            "world.vehicle",
            lambda p: math.hypot(p[0] - src[0], p[1] - src[1]) >= world.random_min_separation_m,
        )
    return Placement(source_m=source, start_m=start, mean_flow_mps=mean)


def build_world(scenario: Scenario, seed: int | None = None) -> World:
    """A fresh world for ``scenario``; the same seed gives the same placements, flow and plume."""
    placement_rng, flow_rng, plume_rng, detector_rng, sensor_rng, navigation_rng = _streams(scenario, seed)
    placement = _resolve(scenario, placement_rng)
    world, grid, config = scenario.world, scenario.grid, scenario.config
    p = world.plume
    bounds = (
        grid.x_min - p.margin_m,
        grid.y_min - p.margin_m,
        grid.x_max + p.margin_m,
        grid.y_max + p.margin_m,
    )
    puff_params = PuffParams(
        release_rate_hz=p.release_rate_hz,
        puff_mass=p.puff_mass,
        initial_sigma_m=p.initial_sigma_m,
        spread_rate_m2ps=p.spread_rate_m2ps,
        random_walk_m_per_sqrt_s=p.random_walk_m_per_sqrt_s,
        max_age_s=p.max_age_s,
        max_puffs=p.max_puffs,
    )
    d = world.detector
    detector = DetectorParams(
        threshold=d.threshold if d.threshold is not None else config.sensor.threshold,
        detection_probability=d.detection_probability,
        false_alarm_rate_hz=d.false_alarm_rate_hz,
        hold_s=d.hold_s,
        response_s=d.response_s,
        noise_std=d.noise_std,
    )
    v = world.vehicle
    flow = _flow(world.flow, placement.mean_flow_mps, flow_rng)
    plume = PuffPlume(placement.source_m, puff_params, bounds, plume_rng)
    spin_up_step = p.spin_up_step_s or world.dt_s
    for _ in range(round(p.spin_up_s / spin_up_step)):
        plume.step(spin_up_step, flow)
        flow.advance(spin_up_step)
    return World(
        flow=flow,
        plume=plume,
        detector=BinaryDetector(detector, detector_rng),
        vehicle=VehicleState(
            x_m=placement.start_m[0], y_m=placement.start_m[1], heading_rad=math.radians(90.0 - v.heading_deg)
        ),
        vehicle_params=VehicleParams(
            speed_mps=v.speed_mps,
            max_turn_rate_dps=v.max_turn_rate_dps,
            pivot_angle_deg=v.pivot_angle_deg,
            slows_to_turn=v.slows_to_turn,
            arrival_radius_m=v.arrival_radius_m,
            accel_mps2=v.accel_mps2,
        ),
        obstacles=grid.obstacles,
        dt_s=world.dt_s,
        flow_sensor=FlowSensor(
            FlowSensorParams(world.flow_sensor.noise_std_mps, world.flow_sensor.bias_deg), sensor_rng
        ),
        navigation=Navigation(NavigationParams(v.position_error_m, v.position_error_s), navigation_rng),
    )
