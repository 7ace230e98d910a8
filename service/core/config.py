"""Configuration: one TOML file validated by pydantic, then ``--set section.key=value`` overrides.

Every key has a default in ``config/default.toml`` and in the models below (the two are kept
equal by a test). Errors name the key and the reason and are raised as ``ConfigError``.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from enum import StrEnum
from pathlib import Path
from typing import Any, Self

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from service.core.errors import ConfigError

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "config" / "default.toml"


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class VehicleConfig(_Section):
    id: str = Field(default="oslim-1", min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")
    endurance_s: float = Field(default=0.0, ge=0)
    """How long the vehicle can search, counted from the service's first tick, s (0: not known).
    In the last tick within it the service names the map's estimate as
    ``declaration.final_probability`` says, stating the map's mass within ``declaration.radius_m``
    of it as its confidence (``oslim bench suite`` passes each world's time limit)."""
    max_speed_mps: float = Field(default=2.0, ge=0, le=100)
    """The fastest guided speed the search asks of an ArduPilot Rover (MAV_CMD_DO_CHANGE_SPEED
    while commanding, when its ``WP_SPEED``, or ``CRUISE_SPEED`` while that is 0, is faster); a
    slower vehicle is never sped up. 0: never asked."""


class MavlinkConfig(_Section):
    url: str = Field(default="udpin:0.0.0.0:14550", min_length=1)
    guided_mode: int = Field(default=15, ge=0)
    link_timeout_s: float = Field(default=3.0, gt=0)
    setpoint_rate_hz: float = Field(default=2.0, ge=2.0, le=50.0)
    setpoint_type_mask: int = Field(default=3576, strict=False)
    altitude_m: float = 0.0
    stream_hz: float = Field(default=5.0, gt=0, le=50.0)
    queue_size: int = Field(default=1000, ge=10)
    signing_key_file: str = ""
    """MAVLink 2 signing key (32 bytes raw, or 64 hex digits); empty: signing off."""
    signing_link_id: int = Field(default=1, ge=0, le=255)
    origin: list[float] = Field(default_factory=list)
    """[lat_deg, lon_deg] of the autopilot's local origin: enables GLOBAL_POSITION_INT as a position
    source when no LOCAL_POSITION_NED arrives; empty: GLOBAL_POSITION_INT is ignored."""

    @field_validator("origin")
    @classmethod
    def _lat_lon(cls, value: list[float]) -> list[float]:
        if value and not (len(value) == 2 and -90.0 <= value[0] <= 90.0 and -180.0 <= value[1] <= 180.0):
            raise ValueError("must be empty or [lat_deg, lon_deg] with |lat| <= 90 and |lon| <= 180")
        return value

    @field_validator("setpoint_type_mask")
    @classmethod
    def _position_only(cls, value: int) -> int:
        if value not in (3576, 3580):
            raise ValueError("must be 3576 (x, y, z) or 3580 (x, y) position-only")
        return value


class AreaConfig(_Section):
    x_min: float = 0.0
    x_max: float = 100.0
    y_min: float = -50.0
    y_max: float = 50.0
    columns: int = Field(default=40, gt=0, le=10_000)
    rows: int = Field(default=25, gt=0, le=10_000)
    obstacles: list[tuple[float, float, float, float]] = Field(default_factory=list)

    @field_validator("obstacles", mode="before")
    @classmethod
    def _lists_to_tuples(cls, value: Any) -> Any:
        if isinstance(value, list):
            return [tuple(v) if isinstance(v, list) else v for v in value]
        return value

    @model_validator(mode="after")
    def _check_bounds(self) -> Self:
        if not self.x_min < self.x_max:
            raise ValueError(f"x_min ({self.x_min}) must be less than x_max ({self.x_max})")
        if not self.y_min < self.y_max:
            raise ValueError(f"y_min ({self.y_min}) must be less than y_max ({self.y_max})")
        for k, (x0, y0, x1, y1) in enumerate(self.obstacles):
            if not (x0 < x1 and y0 < y1):
                raise ValueError(f"obstacles[{k}] must be [x_min, y_min, x_max, y_max] with min < max")
        return self


class SensorConfig(_Section):
    name: str = Field(default="CHEM", min_length=1, max_length=10)
    threshold: float = Field(default=1.0, ge=0)
    detection_probability: float = Field(default=0.9, gt=0, le=1)
    false_alarm_probability: float = Field(default=0.02, ge=0, lt=1)
    miss_floor: float = Field(default=0.3, ge=0, lt=1)
    response_s: float = Field(default=0.0, ge=0, le=60)
    detection_name: str = Field(default="CHEM_DET", min_length=1, max_length=10)
    max_flow_mps: float = Field(default=20.0, gt=0)


class MappingMethod(StrEnum):
    HMM = "hmm"
    BAYES = "bayes"
    POMDP = "pomdp"


class MappingConfig(_Section):
    method: MappingMethod = Field(default=MappingMethod.POMDP, strict=False)
    window: int = Field(default=50, gt=0, le=10_000)
    sigma_x: float = Field(default=0.2, gt=0)
    sigma_y: float = Field(default=0.2, gt=0)
    forgetting: float = Field(default=0.003, ge=0, lt=1)
    footprint_m: float = Field(default=0.8, ge=0)
    footprint_growth: float = Field(default=0.1, ge=0)
    wide_share: float = Field(default=0.3, ge=0, le=1)
    prehistory: bool = True
    epsilon_d: float = Field(default=0.2, gt=0, lt=1)
    epsilon_c: float = Field(default=0.02, gt=0, lt=1)
    tick_s: float = Field(default=1.0, gt=0, le=60)


class PlanningMethod(StrEnum):
    """Planner names of ``planning.method`` (the registry in ``service.core.planning`` uses the same)."""

    ASTAR = "astar"
    ASTAR_PAPER = "astar-paper"
    MLDP = "mldp"
    MLDP_PATH = "mldp-path"
    APF = "apf"


class PlanningConfig(_Section):
    method: PlanningMethod = Field(default=PlanningMethod.ASTAR, strict=False)
    mldp_steps: int = Field(default=25, gt=0, le=10_000)
    apf_window: int = Field(default=10, ge=2, le=1_000)
    apf_step_m: float = Field(default=2.0, gt=0)
    apf_obstacle_gain: float = Field(default=1.0, ge=0)
    apf_obstacle_range_m: float = Field(default=5.0, gt=0)
    lost_after_s: float = Field(default=30.0, gt=0)
    lone_contact_hits: int = Field(default=1, ge=0, le=1000)
    """A contact the sweep met with at most this many detections, then lost for
    ``lone_contact_lost_after_s``, goes back to the sweep where it stopped instead of tracing on
    (0: always trace on)."""
    lone_contact_lost_after_s: float = Field(default=5.0, gt=0)
    """How long a lone contact (``lone_contact_hits``) waits for another detection, s."""


class DeclarationConfig(_Section):
    probability: float = Field(default=0.95, gt=0, le=1)
    hmm_probability: float = Field(default=0.25, gt=0, le=1)
    """The mass rule's threshold with the hmm mapper: its pi is adapted by the gains of seed
    hmm-plume-mapping §IV-B1, not a posterior, and stays far flatter than the Bayesian ones."""
    radius_m: float = Field(default=3.0, ge=0)
    visit_radius_m: float = Field(default=3.0, gt=0)
    upflow_pass_m: float = Field(default=2.0, ge=0)
    """No rule fires for a cell until the vehicle has been at least this far upflow of its centre
    (along the mean flow, within ``visit_radius_m`` across it) since it became the estimate, m
    (0: off). Bayesian mappers only: the hmm's estimate mostly sits in the vehicle's own cell and
    moves with it, so it is seldom passed (farrell2003, hmm + astar, 100 runs: 45 % -> 32 %)."""
    check_width_m: float = Field(default=6.0, ge=0)
    """Before naming a cell, cross the flow ``check_upflow_m`` upflow of its centre, this far to
    either side and back to its line, m (0: off); odour found upflow there calls the declaration
    off."""
    check_upflow_m: float = Field(default=3.0, gt=0)
    """How far upflow of the estimated cell's centre the check crosses the flow, m."""
    final_probability: float = Field(default=0.8, gt=0, le=1)
    """When the vehicle's endurance (``vehicle.endurance_s``) runs out before a declaration, the
    estimate is named without the check across the flow if at least this much of the map lies
    within ``radius_m`` of it, the upflow pass (``upflow_pass_m`` > 0) has been made since it became
    the estimate, and no odour has been met ``check_upflow_m / 2`` or more upflow of it since."""

    @property
    def cancel_upflow_m(self) -> float:
        """Odour this far or more upflow of an estimated cell's centre calls its check off (and
        bars naming it at the endurance): half of ``check_upflow_m``, m."""
        return 0.5 * self.check_upflow_m

    def for_mapper(self, mapper: str) -> DeclarationConfig:
        """This configuration as it applies to the mapper named ``mapper``: ``hmm_probability``,
        no upflow pass for the hmm, unchanged for any other (including mappers
        outside ``MappingMethod``)."""
        if mapper == MappingMethod.HMM.value:
            return self.model_copy(update={"probability": self.hmm_probability, "upflow_pass_m": 0.0})
        return self


class ZenohConfig(_Section):
    mode: str = Field(default="peer", pattern=r"^(peer|client|router)$")
    connect: list[str] = Field(default_factory=list)
    listen: list[str] = Field(default_factory=list)
    key_prefix: str = Field(default="oslim", min_length=1)
    multicast_scouting: bool = True
    options: dict[str, Any] = Field(default_factory=dict)
    """Further Zenoh settings by config path (TLS, access control...), passed through verbatim."""


class RecorderConfig(_Section):
    dir: str = Field(default="runs", min_length=1)


class FoxgloveConfig(_Section):
    listen: str = Field(default="", pattern=r"^$|^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.\-]+):[0-9]{1,5}$")
    """``host:port`` of the live Foxglove WebSocket server (``foxglove_live``); empty: off."""

    @field_validator("listen")
    @classmethod
    def _port(cls, value: str) -> str:
        if value and not 0 <= int(value.rsplit(":", 1)[1]) <= 65535:
            raise ValueError("port must be 0..65535 (0: any free port)")
        return value


class ServiceConfig(_Section):
    snapshot_path: str = ""
    """Map state written atomically every tick and restored at start-up; empty: no snapshot."""


class Config(_Section):
    vehicle: VehicleConfig = Field(default_factory=VehicleConfig)
    mavlink: MavlinkConfig = Field(default_factory=MavlinkConfig)
    area: AreaConfig = Field(default_factory=AreaConfig)
    sensor: SensorConfig = Field(default_factory=SensorConfig)
    mapping: MappingConfig = Field(default_factory=MappingConfig)
    planning: PlanningConfig = Field(default_factory=PlanningConfig)
    declaration: DeclarationConfig = Field(default_factory=DeclarationConfig)
    zenoh: ZenohConfig = Field(default_factory=ZenohConfig)
    recorder: RecorderConfig = Field(default_factory=RecorderConfig)
    foxglove: FoxgloveConfig = Field(default_factory=FoxgloveConfig)
    service: ServiceConfig = Field(default_factory=ServiceConfig)


def parse_override(text: str) -> tuple[list[str], Any]:
    """Split ``section.key=value``; the value is read as a TOML value, else kept as a string."""
    key, sep, raw = text.partition("=")
    path = key.strip().split(".")
    if not sep or len(path) < 2 or not all(path):
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return path, value


def apply_override(data: dict[str, Any], path: list[str], value: Any, text: str) -> None:
    """Set ``value`` at the nested ``path`` of a parsed TOML mapping (``text``: the --set given)."""
    node = data
    for part in path[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"--set {text}: {part} is not a table")
        node = child
    node[path[-1]] = value


_ALWAYS_CHECK = "removed: the check across the flow is flown however steady the odour; delete the key"
_NO_CAST = "removed: a lost plume is traced on toward the map's estimate (there is no cast); delete the key"
_NO_ZIGZAG = "removed: plume finding chooses its legs from the map (there is no zigzag); delete the key"
RETIRED_KEYS = {
    "planning.lost_trace_mass": _NO_CAST,
    "planning.cast_width_m": _NO_CAST,
    "planning.cast_legs": _NO_CAST,
    "planning.flat_map_ratio": "removed: it never changed a mission of the world suite; delete the key",
    "mapping.drift_spread": "removed: the suite's missions came out the same without the drift error "
    "(docs/search-steps.md, step 26); delete the key",
    "declaration.persist_s": "removed: the check across the flow does what it did (docs/search-steps.md, "
    "step 26); delete the key",
    "planning.zigzag_spacing_m": _NO_ZIGZAG,
    "planning.zigzag_near_edge_spacings": _NO_ZIGZAG,
    **{
        f"declaration.steady_{name}": _ALWAYS_CHECK
        for name in (
            "hit_rate",
            "window_s",
            "radius_m",
            "min_ticks",
            "min_contact_s",
            "turn_window_s",
            "max_turn_deg",
        )
    },
}
"""Keys an earlier version read, and what to do about them (named instead of "unknown key")."""


def _format(error: ValidationError, origin: str) -> str:
    lines = []
    for item in error.errors():
        loc = ".".join(str(p) for p in item["loc"]) or "(top level)"
        reason = item["msg"]
        if item["type"] == "extra_forbidden":
            reason = RETIRED_KEYS.get(loc, "unknown key")
        got = item.get("input")
        shown = "" if isinstance(got, dict) or item["type"] == "extra_forbidden" else f" (got {got!r})"
        lines.append(f"{origin}: {loc}: {reason}{shown}")
    return "\n".join(lines)


def build_config(data: dict[str, Any], overrides: Sequence[str] = (), origin: str = "config") -> Config:
    """Validate a parsed TOML mapping after applying ``--set`` overrides."""
    merged = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for text in overrides:
        path, value = parse_override(text)
        apply_override(merged, path, value, text)
    try:
        return Config.model_validate(merged)
    except ValidationError as exc:
        raise ConfigError(_format(exc, origin)) from None


def load_config(path: str | Path | None = None, overrides: Sequence[str] = ()) -> Config:
    """Load ``path`` (default: ``config/default.toml``), apply overrides, validate."""
    file = Path(path) if path is not None else DEFAULT_CONFIG
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{file}: no such configuration file") from None
    except OSError as exc:
        raise ConfigError(f"{file}: cannot read ({exc.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{file}: not valid TOML: {exc}") from None
    return build_config(data, overrides, origin=str(file))
