"""Typed telemetry decoded from MAVLink messages, in the map frame, with bad values rejected.

Pure: takes pymavlink message objects (anything with ``get_type()`` and the fields), returns
frozen values. The MAVLink contract of DESIGN.md: LOCAL_POSITION_NED is NED (x North, y East)
and becomes map x = y_ned, y = x_ned; WIND_COV's wind_x/wind_y are the North/East velocity the
air moves toward; ArduPilot's WIND gives the direction the wind comes FROM in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from service.core.samples import ChemSample, DetectionSample, FlowSample, Position

if TYPE_CHECKING:
    from service.core.config import Config

MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_AUTOPILOT_INVALID = 8
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30})
"""MAV_TYPE of GCS, onboard controller, gimbal, ADS-B, camera: their heartbeats are not the autopilot's."""

EARTH_RADIUS_M = 6_371_008.8
"""Mean Earth radius (IUGG)."""

POSITION_LIMIT_M = 1.0e6
"""Positions further than this from the origin are corrupt, not merely outside the area."""


@dataclass(frozen=True)
class Heartbeat:
    time_s: float
    system: int
    component: int
    vehicle_type: int
    autopilot: int
    custom_mode: int
    armed: bool


@dataclass(frozen=True)
class ParamValue:
    """One of the autopilot's parameters, as it answered PARAM_REQUEST_READ."""

    time_s: float
    system: int
    name: str
    value: float


@dataclass(frozen=True)
class Rejected:
    """A message that was understood but not used, and why (counted and logged by the caller)."""

    message: str
    reason: str


Telemetry = Heartbeat | ParamValue | Position | FlowSample | ChemSample | DetectionSample


@dataclass(frozen=True)
class TelemetrySettings:
    chem_name: str = "CHEM"
    detection_name: str = "CHEM_DET"
    max_flow_mps: float = 20.0
    origin: tuple[float, float] | None = None
    """(lat_deg, lon_deg) of the local origin; None: GLOBAL_POSITION_INT is not used."""

    @classmethod
    def from_config(cls, config: Config) -> TelemetrySettings:
        """The sensor names, flow bound and origin of ``config``'s [sensor] and [mavlink]."""
        origin = config.mavlink.origin
        return cls(
            chem_name=config.sensor.name,
            detection_name=config.sensor.detection_name,
            max_flow_mps=config.sensor.max_flow_mps,
            origin=(origin[0], origin[1]) if origin else None,
        )


def _name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).split("\x00", 1)[0].strip()


def _finite(*values: float) -> bool:
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)


def decode(msg: Any, time_s: float, settings: TelemetrySettings) -> Telemetry | Rejected | None:
    """The telemetry in ``msg`` received at service time ``time_s``; None for messages we ignore."""
    kind = msg.get_type()
    if kind == "HEARTBEAT":
        if msg.autopilot == MAV_AUTOPILOT_INVALID or msg.type in NON_VEHICLE_TYPES:
            return None
        return Heartbeat(
            time_s=time_s,
            system=msg.get_srcSystem(),
            component=msg.get_srcComponent(),
            vehicle_type=msg.type,
            autopilot=msg.autopilot,
            custom_mode=msg.custom_mode,
            armed=bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
        )
    if kind == "LOCAL_POSITION_NED":
        if not _finite(msg.x, msg.y):
            return Rejected(kind, "non-finite position")
        if max(abs(msg.x), abs(msg.y)) > POSITION_LIMIT_M:
            return Rejected(kind, "position beyond 1000 km")
        return Position(time_s, x=float(msg.y), y=float(msg.x))
    if kind == "GLOBAL_POSITION_INT" and settings.origin is not None:
        lat, lon = msg.lat * 1e-7, msg.lon * 1e-7
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return Rejected(kind, "latitude or longitude out of range")
        x, y = local_offset_m(settings.origin, (lat, lon))
        return Position(time_s, x=x, y=y, local=False)
    if kind == "WIND_COV":
        return _flow(kind, time_s, east=msg.wind_y, north=msg.wind_x, settings=settings)
    if kind == "WIND":
        if not _finite(msg.direction, msg.speed) or msg.speed < 0:
            return Rejected(kind, "non-finite or negative wind")
        # direction is where the wind comes FROM (compass degrees): the flow goes the other way
        rad = math.radians(msg.direction)
        return _flow(
            kind, time_s, east=-msg.speed * math.sin(rad), north=-msg.speed * math.cos(rad), settings=settings
        )
    if kind == "NAMED_VALUE_FLOAT" and _name(msg.name) == settings.chem_name:
        if not _finite(msg.value):
            return Rejected(kind, "non-finite chemical reading")
        return ChemSample(time_s, float(msg.value))
    if kind == "PARAM_VALUE":
        if not _finite(msg.param_value):
            return Rejected(kind, "non-finite parameter value")
        return ParamValue(time_s, msg.get_srcSystem(), _name(msg.param_id), float(msg.param_value))
    if kind == "NAMED_VALUE_INT" and _name(msg.name) == settings.detection_name:
        if msg.value not in (0, 1):
            return Rejected(kind, f"detection value {msg.value} is not 0 or 1")
        return DetectionSample(time_s, bool(msg.value))
    return None


def local_offset_m(origin: tuple[float, float], point: tuple[float, float]) -> tuple[float, float]:
    """East and north metres of ``point`` from ``origin`` (both lat, lon degrees), on a local
    tangent plane: plenty for a search area of a few kilometres."""
    lat0, lon0 = map(math.radians, origin)
    lat, lon = map(math.radians, point)
    dlon = (lon - lon0 + math.pi) % (2.0 * math.pi) - math.pi
    return EARTH_RADIUS_M * dlon * math.cos(0.5 * (lat + lat0)), EARTH_RADIUS_M * (lat - lat0)


def _flow(
    kind: str, time_s: float, east: float, north: float, settings: TelemetrySettings
) -> FlowSample | Rejected:
    if not _finite(east, north):
        return Rejected(kind, "non-finite flow")
    if math.hypot(east, north) > settings.max_flow_mps:
        return Rejected(kind, f"flow faster than {settings.max_flow_mps} m/s")
    return FlowSample(time_s, flow_x=float(east), flow_y=float(north))
