"""The stub's conversation with a companion computer speaking plain pymavlink over loopback UDP."""

from __future__ import annotations

import asyncio
import math
import os
from collections import Counter
from collections.abc import Callable
from typing import Any

import pytest

from service.core.errors import ConfigError
from service.edges.mavlink_dialect import dialect
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.stub import Stream, StubOptions, VehicleStub
from sim_bridge.world import World

MAV = dialect()
Fly = Callable[..., Any]


def wang(*overrides: str) -> World:
    """The laminar Wang world (start (58.75, 44), 2 m/s, flow 1 m/s East), with overrides."""
    return build_world(load_scenario("wang-laminar", list(overrides)), seed=0)


def test_heartbeat_says_ardupilot_rover_in_manual(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> Any:
        return c.recv("HEARTBEAT")

    hb = fly(wang(), talk)
    assert hb.autopilot == MAV.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.type == MAV.MAV_TYPE_GROUND_ROVER
    assert hb.custom_mode == 0  # Rover boots in MANUAL
    assert hb.base_mode & MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED


def test_submarine_kind_identifies_as_ardusub(fly: Fly) -> None:
    from sim_bridge.autopilot import VehicleKind

    def talk(c: Any, stub: VehicleStub) -> tuple[Any, Any]:
        hb = c.recv("HEARTBEAT")
        c.guided_and_armed(guided=4)
        return hb, c.recv("HEARTBEAT", where=lambda m: m.custom_mode == 4)

    first, guided = fly(wang(), talk, kind=VehicleKind.SUB)
    assert first.type == MAV.MAV_TYPE_SUBMARINE
    assert first.custom_mode == 19  # ArduSub boots in MANUAL
    assert guided.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED


def test_guided_arm_disarm_and_modes_are_acknowledged(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> dict[str, Any]:
        c.recv("HEARTBEAT")
        out = {"guided": c.command(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 15)}
        out["hb_guided"] = c.recv("HEARTBEAT", where=lambda m: m.custom_mode == 15)
        out["arm"] = c.command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        out["hb_armed"] = c.recv("HEARTBEAT", where=lambda m: m.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)
        out["bad_mode"] = c.command(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 99)
        c.conn.mav.set_mode_send(1, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # the SET_MODE message: HOLD
        out["set_mode"] = c.recv("COMMAND_ACK", where=lambda m: m.command == MAV.MAVLINK_MSG_ID_SET_MODE)
        out["hb_hold"] = c.recv("HEARTBEAT", where=lambda m: m.custom_mode == 4)
        out["disarm"] = c.command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        out["hb_disarmed"] = c.recv(
            "HEARTBEAT", where=lambda m: not m.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED
        )
        out["unknown"] = c.command(MAV.MAV_CMD_NAV_LOITER_UNLIM)
        out["status"] = stub.status()
        return out

    out = fly(wang(), talk)
    accepted = MAV.MAV_RESULT_ACCEPTED
    assert [out[k].result for k in ("guided", "arm", "set_mode", "disarm")] == [accepted] * 4
    assert out["hb_guided"].base_mode & MAV.MAV_MODE_FLAG_GUIDED_ENABLED
    assert out["hb_armed"].system_status == MAV.MAV_STATE_ACTIVE
    assert out["bad_mode"].result == MAV.MAV_RESULT_FAILED
    assert out["unknown"].result == MAV.MAV_RESULT_UNSUPPORTED
    assert out["set_mode"].target_system == 1
    assert out["set_mode"].target_component == 191
    status = out["status"]
    assert (status.mode_name, status.armed) == ("HOLD", False)
    assert status.counters.rejected_commands == 2


def test_requested_stream_rates_are_honoured_within_20_percent(fly: Fly) -> None:
    requested_hz = {"LOCAL_POSITION_NED": 20.0, "WIND": 4.0, "NAMED_VALUE_FLOAT": 8.0, "HEARTBEAT": 1.0}
    ids = {"LOCAL_POSITION_NED": 32, "WIND": 168, "NAMED_VALUE_FLOAT": 251, "WIND_COV": 231}

    def talk(c: Any, stub: VehicleStub) -> tuple[list[Any], Counter[str]]:
        c.recv("HEARTBEAT")
        acks = [
            c.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, ids[name], 1e6 / requested_hz[name])
            for name in ("LOCAL_POSITION_NED", "WIND", "NAMED_VALUE_FLOAT")
        ]
        acks.append(c.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, ids["WIND_COV"], -1))  # off
        acks.append(c.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1e5))  # no such message
        c.collect(0.3)  # let what was already in flight drain
        return acks, Counter(msg.get_type() for _, msg in c.collect(3.0))

    acks, counts = fly(wang(), talk)
    assert [a.result for a in acks[:4]] == [MAV.MAV_RESULT_ACCEPTED] * 4
    assert acks[4].result == MAV.MAV_RESULT_DENIED
    for name, rate_hz in requested_hz.items():
        assert counts[name] == pytest.approx(rate_hz * 3.0, rel=0.2, abs=1), (name, counts)
    assert counts["WIND_COV"] == 0


def test_message_interval_zero_restores_the_default_and_request_message_sends_once(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> tuple[float, float, Any, Any]:
        c.recv("HEARTBEAT")
        c.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 231, -1)
        off = stub.status().rates_hz[Stream.WIND_COV]
        c.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 231, 0)
        default = stub.status().rates_hz[Stream.WIND_COV]
        ack = c.command(MAV.MAV_CMD_REQUEST_MESSAGE, 252)  # CHEM_DET is off by default
        return off, default, ack, c.recv("NAMED_VALUE_INT")

    off, default, ack, detection = fly(wang(), talk)
    assert (off, default) == (0.0, 2.0)
    assert ack.result == MAV.MAV_RESULT_ACCEPTED
    assert detection.name == "CHEM_DET"
    assert detection.value in (0, 1)


def test_a_rover_reports_its_acceptance_radius_as_wp_radius(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> Any:
        c.recv("HEARTBEAT")
        c.conn.mav.param_request_read_send(1, 1, b"WP_RADIUS", -1)
        return c.recv("PARAM_VALUE")

    value = fly(wang("world.vehicle.arrival_radius_m=2"), talk)
    assert (value.param_id, value.param_value) == ("WP_RADIUS", 2.0)
    assert value.param_type == MAV.MAV_PARAM_TYPE_REAL32


def test_a_parameter_the_vehicle_lacks_gets_no_answer(fly: Fly) -> None:
    # as ArduPilot: a name it does not know is not answered (a rover's other parameters, any of a sub)
    from sim_bridge.autopilot import VehicleKind

    def asking(name: bytes) -> Callable[[Any, VehicleStub], bool]:
        def talk(c: Any, stub: VehicleStub) -> bool:
            c.recv("HEARTBEAT")
            c.conn.mav.param_request_read_send(1, 1, name, -1)
            try:
                c.recv("PARAM_VALUE", timeout_s=0.5)
            except AssertionError:
                return False
            return True

        return talk

    assert not fly(wang("world.vehicle.arrival_radius_m=2"), asking(b"WP_RADIUS"), kind=VehicleKind.SUB)
    assert not fly(wang(), asking(b"WP_PIVOT_RATE"))


def test_a_rover_reports_its_guided_speed_and_takes_a_slower_one_in_guided(fly: Fly) -> None:
    # the wang rover cruises at 2 m/s (WP_SPEED and CRUISE_SPEED); asked for 1 m/s in GUIDED it
    # drives its target at that speed until the mode changes; outside GUIDED the command fails
    def talk(c: Any, stub: VehicleStub) -> tuple[Any, ...]:
        c.recv("HEARTBEAT")
        c.conn.mav.param_request_read_send(1, 1, b"CRUISE_SPEED", -1)
        cruise = c.recv("PARAM_VALUE")
        c.conn.mav.param_request_read_send(1, 1, b"", 1)
        by_index = c.recv("PARAM_VALUE")
        refused = c.command(MAV.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1)
        c.guided_and_armed()
        accepted = c.command(MAV.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1)
        asked = stub.world.speed_mps
        c.command(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # HOLD
        return cruise, by_index, refused, accepted, asked, stub.world.speed_mps

    cruise, by_index, refused, accepted, asked, after = fly(wang(), talk)
    assert (cruise.param_id, cruise.param_value, cruise.param_count) == ("CRUISE_SPEED", 2.0, 3)
    assert (by_index.param_id, by_index.param_value, by_index.param_index) == ("WP_SPEED", 2.0, 1)
    assert (refused.result, accepted.result) == (MAV.MAV_RESULT_FAILED, MAV.MAV_RESULT_ACCEPTED)
    assert (asked, after) == (1.0, None)


def test_moves_toward_a_setpoint_at_the_configured_speed_and_stops_there(fly: Fly) -> None:
    # start (58.75, 44) heading South; target 20 m South: NED (24, 58.75); speed factor 4
    def talk(c: Any, stub: VehicleStub) -> list[Any]:
        c.recv("HEARTBEAT")
        c.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 1e5)  # 10 Hz (simulated)
        c.guided_and_armed()
        c.goto_ned(24.0, 58.75, type_mask=3576)
        c.recv("LOCAL_POSITION_NED", timeout_s=10.0, where=lambda m: abs(m.x - 24.0) < 1e-6)
        return [m for _, m in c.collect(0.5) if m.get_type() == "LOCAL_POSITION_NED"]

    world = wang()
    positions: list[Any] = []

    def record(c: Any, stub: VehicleStub) -> list[Any]:
        c.conn.message_hooks.append(
            lambda _conn, m: positions.append(m) if m.get_type() == "LOCAL_POSITION_NED" else None
        )
        return talk(c, stub)

    after = fly(world, record, speed=4.0)
    moving = [m for m in positions if 25.0 < m.x < 43.0]
    assert len(moving) >= 5
    first, last = moving[0], moving[-1]
    speed_mps = (first.x - last.x) / ((last.time_boot_ms - first.time_boot_ms) / 1000.0)
    assert speed_mps == pytest.approx(2.0, rel=0.05)
    assert all(m.vx == pytest.approx(-2.0, rel=0.05) and abs(m.vy) < 1e-6 for m in moving[1:-1])
    assert all(abs(m.y - 58.75) < 1e-6 for m in moving)  # straight toward it, no drift
    assert after
    assert all((m.x, m.y, m.vx) == (24.0, 58.75, 0.0) for m in after)


def test_setpoints_move_nothing_unless_guided_and_armed(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> dict[str, Any]:
        c.recv("HEARTBEAT")
        c.goto_ned(30.0, 58.75)  # MANUAL: ignored, as ArduPilot does
        c.command(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 15)
        c.goto_ned(30.0, 58.75, type_mask=0)  # velocity+position mask: not position-only
        c.conn.mav.set_position_target_local_ned_send(
            0, 1, 1, MAV.MAV_FRAME_BODY_NED, 3580, 30.0, 58.75, 0, 0, 0, 0, 0, 0, 0, 0, 0
        )
        c.goto_ned(30.0, 58.75)  # accepted, but disarmed: stays put
        c.recv("HEARTBEAT")
        c.recv("HEARTBEAT")
        disarmed = stub.status()
        c.command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        moving = c.recv("LOCAL_POSITION_NED", where=lambda m: m.x < 43.0)
        return {"disarmed": disarmed, "moving": moving}

    out = fly(wang(), talk, speed=2.0)
    disarmed = out["disarmed"]
    assert (disarmed.x_m, disarmed.y_m) == (58.75, 44.0)
    assert disarmed.target_m == (58.75, 30.0)
    assert disarmed.counters.ignored_setpoints == 3
    assert out["moving"].vx < 0  # armed in GUIDED: off toward the target


def test_flow_and_chemical_streams_report_the_world_at_the_vehicle(fly: Fly) -> None:
    # 6 m downflow of the laminar source, a perfect detector: the plume arrives after ~6 s
    world = wang("world.vehicle.start_m=[24.75, 4.0]", "world.detector.detection_probability=1.0")

    def talk(c: Any, stub: VehicleStub) -> dict[str, Any]:
        return {
            "wind": c.recv("WIND"),
            "wind_cov": c.recv("WIND_COV"),
            "chem": c.recv("NAMED_VALUE_FLOAT", timeout_s=5.0, where=lambda m: m.value >= 1.0),
            "position": c.recv("LOCAL_POSITION_NED"),
        }

    out = fly(world, talk, speed=5.0)
    assert out["wind"].direction == pytest.approx(270.0)  # the flow comes FROM the West
    assert out["wind"].speed == pytest.approx(1.0)
    assert (out["wind_cov"].wind_x, out["wind_cov"].wind_y) == pytest.approx((0.0, 1.0))  # N, E
    assert out["chem"].name == "CHEM"
    assert out["chem"].time_boot_ms > 4000
    assert (out["position"].x, out["position"].y) == pytest.approx((4.0, 24.75))  # NED: North, East


def test_garbage_is_counted_and_never_fatal(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> tuple[Any, Any, Any, Any]:
        c.recv("HEARTBEAT")  # the stub's address is known from here on
        valid = MAV.MAVLink_command_long_message(
            1, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
        )
        frame = bytearray(valid.pack(MAV.MAVLink(None, srcSystem=1, srcComponent=191)))
        corrupted = bytearray(frame)
        corrupted[-3] ^= 0xFF
        for junk in (os.urandom(64), bytes(corrupted), b"\xfd\x09", bytes(frame[:7]), b"\x00" * 300):
            c.conn.write(junk)
        c.conn.mav.param_request_list_send(1, 1)  # well formed, but not something the stub acts on
        c.conn.mav.command_long_send(7, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        c.conn.mav.command_long_send(1, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, math.nan, 0, 0, 0, 0, 0, 0)
        nan_ack = c.recv("COMMAND_ACK")
        ack = c.command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        hb = c.recv("HEARTBEAT", where=lambda m: m.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)
        return nan_ack, ack, hb, stub.status().counters

    # the zeros come last: whatever partial frame the junk opened, they complete it and resync
    nan_ack, ack, hb, counters = fly(wang(), talk, speed=2.0)
    assert nan_ack.result == MAV.MAV_RESULT_DENIED
    assert ack.result == MAV.MAV_RESULT_ACCEPTED
    assert hb is not None
    assert counters.malformed >= 2
    assert counters.unexpected >= 1
    assert counters.foreign == 1
    assert counters.rejected_commands == 1


def test_speed_factor_runs_simulated_time_faster(fly: Fly) -> None:
    def talk(c: Any, stub: VehicleStub) -> list[tuple[float, Any]]:
        c.recv("HEARTBEAT")
        return [(t, m) for t, m in c.collect(1.0) if m.get_type() == "NAMED_VALUE_FLOAT"]

    samples = fly(wang(), talk, speed=5.0)
    (t0, first), (t1, last) = samples[0], samples[-1]
    ratio = (last.time_boot_ms - first.time_boot_ms) / 1000.0 / (t1 - t0)
    assert ratio == pytest.approx(5.0, rel=0.2)
    assert len(samples) == pytest.approx(50, rel=0.2)  # 10 Hz simulated = 50 per wall second


def test_a_udpin_stub_answers_once_it_has_heard_its_peer(companion_at: Any, udp_port: int) -> None:
    def talk() -> Any:
        with companion_at(f"udpout:127.0.0.1:{udp_port}") as c:
            c.conn.mav.heartbeat_send(MAV.MAV_TYPE_ONBOARD_CONTROLLER, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            return c.recv("HEARTBEAT")

    async def main() -> Any:
        async with VehicleStub(wang(), StubOptions(url=f"udpin:127.0.0.1:{udp_port}")):
            return await asyncio.to_thread(talk)

    assert asyncio.run(main()).autopilot == MAV.MAV_AUTOPILOT_ARDUPILOTMEGA


def test_stub_options_are_validated() -> None:
    with pytest.raises(ConfigError):
        StubOptions(speed=0.0)
    with pytest.raises(ConfigError):
        StubOptions(sensor_name="A_NAME_TOO_LONG")
    with pytest.raises(ConfigError):
        StubOptions(rates_hz={Stream.WIND: -1.0})


def test_status_before_start_and_close_is_idempotent() -> None:
    async def main() -> None:
        stub = VehicleStub(wang(), StubOptions(url="udpout:127.0.0.1:9"))
        assert stub.status().mode_name == "MANUAL"
        async with stub:
            await stub.wait_for(lambda s: s.time_s > 0.0, timeout_s=2.0)
        await stub.close()

    asyncio.run(main())
