"""service.edges.mavlink_dialect: pymavlink always comes up as MAVLink 2 with the ardupilotmega dialect."""

from __future__ import annotations

import os

from service.edges.mavlink_dialect import DIALECT, dialect, mavutil


def test_mavlink2_and_ardupilotmega_whoever_imported_first() -> None:
    mav = dialect()
    assert os.environ["MAVLINK20"] == "1"
    assert os.environ["MAVLINK_DIALECT"] == DIALECT
    assert mav.WIRE_PROTOCOL_VERSION == "2.0"
    assert mav.__name__ == "pymavlink.dialects.v20.ardupilotmega"
    assert mav.MAVLINK_MSG_ID_WIND == 168  # ardupilotmega only
    module = mavutil()
    module.set_dialect("common")  # someone switches the global dialect behind our back
    assert dialect().__name__ == "pymavlink.dialects.v20.ardupilotmega"
    assert module.mavlink is dialect()


def test_frames_are_mavlink2() -> None:
    mav = dialect()
    frame = mav.MAVLink_heartbeat_message(10, 3, 1, 15, 4, 3).pack(
        mav.MAVLink(None, srcSystem=1, srcComponent=1)
    )
    assert frame[0] == 0xFD  # MAVLink 2 start-of-frame
