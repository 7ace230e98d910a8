"""What ``MavlinkLink`` sends, field by field (no socket: the connection is a stand-in)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from service.edges.mavlink_link import MavlinkLink


def test_a_speed_cap_is_do_change_speed_of_ground_speed_with_the_throttle_unchanged() -> None:
    sent: list[Any] = []
    link = MavlinkLink("udpout:127.0.0.1:9")
    link._conn = SimpleNamespace(mav=SimpleNamespace(send=sent.append))
    link.send_speed(7, 2.0)
    (msg,) = sent
    assert msg.get_type() == "COMMAND_LONG"
    assert (msg.target_system, msg.target_component, msg.command) == (7, 1, 178)
    assert (msg.param1, msg.param2, msg.param3) == (1.0, pytest.approx(2.0), -1.0)
    assert link.counters.sent == 1
