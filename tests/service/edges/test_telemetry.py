import math
from typing import Any

import pytest

from service.core.samples import ChemSample, DetectionSample, FlowSample, Position
from service.edges.mavlink_dialect import dialect
from service.edges.telemetry import (
    Heartbeat,
    ParamValue,
    Rejected,
    TelemetrySettings,
    decode,
)

SETTINGS = TelemetrySettings(chem_name="CHEM", detection_name="CHEM_DET", max_flow_mps=20.0)
mav = dialect()


def over_the_wire(msg: Any, system: int = 1, component: int = 1) -> Any:
    """Pack as the vehicle would and parse as the service does."""
    sender = mav.MAVLink(None, srcSystem=system, srcComponent=component)
    receiver = mav.MAVLink(None)
    return receiver.parse_char(msg.pack(sender))


def test_local_position_ned_becomes_enu() -> None:
    msg = over_the_wire(mav.MAVLink_local_position_ned_message(1000, 12.5, -3.0, -1.0, 0, 0, 0))
    assert decode(msg, 5.0, SETTINGS) == Position(5.0, x=-3.0, y=12.5)


def test_wind_cov_is_north_east_toward() -> None:
    msg = over_the_wire(mav.MAVLink_wind_cov_message(0, 2.0, -1.0, 0.0, 0, 0, 0, 0, 0))
    assert decode(msg, 1.0, SETTINGS) == FlowSample(1.0, flow_x=-1.0, flow_y=2.0)


@pytest.mark.parametrize(
    ("from_deg", "east", "north"),
    [(0.0, 0.0, -1.5), (90.0, -1.5, 0.0), (180.0, 0.0, 1.5), (270.0, 1.5, 0.0)],
)
def test_wind_direction_is_where_it_comes_from(from_deg: float, east: float, north: float) -> None:
    msg = over_the_wire(mav.MAVLink_wind_message(from_deg, 1.5, 0.0))
    out = decode(msg, 0.0, SETTINGS)
    assert isinstance(out, FlowSample)
    assert out.flow_x == pytest.approx(east, abs=1e-6)
    assert out.flow_y == pytest.approx(north, abs=1e-6)


def test_named_values() -> None:
    chem = over_the_wire(mav.MAVLink_named_value_float_message(0, b"CHEM", 3.25))
    assert decode(chem, 2.0, SETTINGS) == ChemSample(2.0, 3.25)
    other = over_the_wire(mav.MAVLink_named_value_float_message(0, b"TEMP", 3.25))
    assert decode(other, 2.0, SETTINGS) is None
    det = over_the_wire(mav.MAVLink_named_value_int_message(0, b"CHEM_DET", 1))
    assert decode(det, 2.0, SETTINGS) == DetectionSample(2.0, True)
    bad = over_the_wire(mav.MAVLink_named_value_int_message(0, b"CHEM_DET", 7))
    assert isinstance(decode(bad, 2.0, SETTINGS), Rejected)


def test_a_parameter_the_autopilot_reports() -> None:
    msg = over_the_wire(mav.MAVLink_param_value_message(b"WP_RADIUS", 2.0, 9, 1200, 431), system=7)
    assert decode(msg, 3.0, SETTINGS) == ParamValue(3.0, 7, "WP_RADIUS", 2.0)
    nan = over_the_wire(mav.MAVLink_param_value_message(b"WP_RADIUS", math.nan, 9, 1200, 431))
    assert decode(nan, 3.0, SETTINGS) == Rejected("PARAM_VALUE", "non-finite parameter value")


def test_heartbeat_of_the_autopilot_only() -> None:
    hb = mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_GROUND_ROVER,
        mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mav.MAV_MODE_FLAG_SAFETY_ARMED | 1,
        15,
        4,
        3,
    )
    out = decode(over_the_wire(hb, system=7, component=1), 3.0, SETTINGS)
    rover, ardupilot = mav.MAV_TYPE_GROUND_ROVER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert out == Heartbeat(3.0, 7, 1, vehicle_type=rover, autopilot=ardupilot, custom_mode=15, armed=True)
    gcs = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    assert decode(over_the_wire(gcs, system=255), 3.0, SETTINGS) is None


@pytest.mark.parametrize(
    "msg",
    [
        mav.MAVLink_local_position_ned_message(0, math.nan, 0.0, 0.0, 0, 0, 0),
        mav.MAVLink_local_position_ned_message(0, 0.0, math.inf, 0.0, 0, 0, 0),
        mav.MAVLink_local_position_ned_message(0, 3e7, 0.0, 0.0, 0, 0, 0),
        mav.MAVLink_wind_cov_message(0, 1000.0, 0.0, 0.0, 0, 0, 0, 0, 0),
        mav.MAVLink_wind_cov_message(0, math.nan, 0.0, 0.0, 0, 0, 0, 0, 0),
        mav.MAVLink_wind_message(math.nan, 1.0, 0.0),
        mav.MAVLink_wind_message(10.0, -1.0, 0.0),
        mav.MAVLink_named_value_float_message(0, b"CHEM", math.inf),
    ],
)
def test_bad_values_are_rejected_with_a_reason(msg: Any) -> None:
    out = decode(over_the_wire(msg), 0.0, SETTINGS)
    assert isinstance(out, Rejected)
    assert out.reason


def test_global_position_needs_an_origin() -> None:
    msg = over_the_wire(mav.MAVLink_global_position_int_message(0, 473_977_420, 85_455_940, 0, 0, 0, 0, 0, 0))
    assert decode(msg, 1.0, SETTINGS) is None
    with_origin = TelemetrySettings(origin=(47.397742, 8.545594))
    assert decode(msg, 1.0, with_origin) == Position(1.0, x=0.0, y=0.0, local=False)


def test_global_position_offsets_east_and_north() -> None:
    origin = (47.0, 8.0)
    settings = TelemetrySettings(origin=origin)
    # 0.001 deg of latitude is 111.2 m north; 0.001 deg of longitude at 47 deg is 75.8 m east
    msg = over_the_wire(mav.MAVLink_global_position_int_message(0, 470_010_000, 80_010_000, 0, 0, 0, 0, 0, 0))
    out = decode(msg, 2.0, settings)
    assert isinstance(out, Position)
    assert out.y == pytest.approx(6_371_008.8 * math.radians(0.001), rel=1e-9)
    assert out.x == pytest.approx(
        6_371_008.8 * math.radians(0.001) * math.cos(math.radians(47.0005)), rel=1e-9
    )
    assert not out.local
    bad = over_the_wire(mav.MAVLink_global_position_int_message(0, 950_000_000, 0, 0, 0, 0, 0, 0, 0))
    assert isinstance(decode(bad, 2.0, settings), Rejected)
