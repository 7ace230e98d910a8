"""``oslim sitl-bridge`` without SITL: raw sockets and the vehicle stub stand in for it on loopback."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from service.core.config import load_config
from service.core.errors import ConfigError
from service.edges.mavlink_dialect import dialect
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.sitl_bridge import BridgeOptions, Endpoint, Scheme, SitlBridge, wind_fields
from sim_bridge.sitl_bridge_command import config_toml
from sim_bridge.stub import Stream, StubOptions, VehicleStub
from sim_bridge.world import World

MAV = dialect()
PERIPHERAL = 158


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def wang(*overrides: str) -> World:
    return build_world(load_scenario("wang-laminar", list(overrides)), seed=0)


class Encoder:
    """Frames as a MAVLink sender writes them, with its own sequence numbers."""

    def __init__(self, system: int = 1, component: int = 1) -> None:
        self.mav = MAV.MAVLink(None, srcSystem=system, srcComponent=component)

    def __call__(self, msg: Any, v1: bool = False) -> bytes:
        data = bytes(msg.pack(self.mav, force_mavlink1=v1))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data


def autopilot_heartbeat() -> Any:
    return MAV.MAVLink_heartbeat_message(
        MAV.MAV_TYPE_GROUND_ROVER, MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, 1, 0, MAV.MAV_STATE_STANDBY, 3
    )


def position(t_ms: int, north: float, east: float) -> Any:
    return MAV.MAVLink_local_position_ned_message(t_ms, north, east, 0.0, 0.0, 0.0, 0.0)


def awkward_stream() -> bytes:
    """Everything a relay must pass on unchanged: v2, v1, signed, unknown id, bad CRC, garbage."""
    enc, gcs = Encoder(1, 1), Encoder(255, 190)
    signed = Encoder(1, 1)
    signed.mav.signing.secret_key = bytes(range(32))
    signed.mav.signing.sign_outgoing = True
    signed.mav.signing.link_id = 3
    signed.mav.signing.timestamp = 123456789
    good = enc(MAV.MAVLink_named_value_float_message(5, b"X", 1.5))
    bad_crc = good[:-3] + bytes([good[-3] ^ 0xFF]) + good[-2:]
    unknown = bytes([0xFD, 3, 0, 0, 7, 1, 1, 0xDE, 0xBC, 0x0A, 1, 2, 3, 0x12, 0x34])  # msgid 0x0ABCDE
    parts = [
        enc(autopilot_heartbeat()),
        b"\x00\x01garbage\x55\x42",
        gcs(MAV.MAVLink_statustext_message(6, b"hello from a ground station")),
        enc(autopilot_heartbeat(), v1=True),
        signed(MAV.MAVLink_system_time_message(1, 2)),
        unknown,
        bad_crc,
        good,
    ]
    parts += [enc(MAV.MAVLink_system_time_message(k, k)) for k in range(200)]
    return b"".join(parts)


class Receiver:
    """A UDP peer in its own thread (so a busy event loop cannot make it miss datagrams)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port: int = self.sock.getsockname()[1]
        self.data = bytearray()
        self.peer: tuple[str, int] | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                chunk, self.peer = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            with self._lock:
                self.data += chunk

    def snapshot(self) -> bytes:
        with self._lock:
            return bytes(self.data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


class FakeSitl:
    """A TCP server that plays SITL's serial port: what the bridge sends it is kept."""

    def __init__(self) -> None:
        self.received = bytearray()
        self.writer: asyncio.StreamWriter | None = None
        self.connected = asyncio.Event()
        self.server: asyncio.Server | None = None
        self.port = 0

    async def start(self) -> None:
        self.server = await asyncio.start_server(self._client, "127.0.0.1", 0)
        self.port = self.server.sockets[0].getsockname()[1]

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writer = writer
        self.connected.set()
        while data := await reader.read(65536):
            self.received += data

    async def send(self, data: bytes, chunk: int = 37) -> None:
        assert self.writer is not None
        for k in range(0, len(data), chunk):  # odd chunks: frames arrive split
            self.writer.write(data[k : k + chunk])
        await self.writer.drain()

    async def stop(self) -> None:
        if self.writer is not None:
            self.writer.close()
        if self.server is not None:
            self.server.close()
            await self.server.wait_closed()


async def until(condition: Callable[[], bool], timeout_s: float) -> None:
    """Wait (polling the event loop) until ``condition()`` holds; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.01)


@asynccontextmanager
async def tcp_rig(**options: Any) -> AsyncIterator[tuple[FakeSitl, Receiver, SitlBridge]]:
    sitl, service = FakeSitl(), Receiver()
    await sitl.start()
    try:
        opts = BridgeOptions(
            sitl_url=f"tcp:127.0.0.1:{sitl.port}", to_url=f"udpout:127.0.0.1:{service.port}", **options
        )
        async with SitlBridge(wang(), opts) as bridge:
            await asyncio.wait_for(sitl.connected.wait(), 5.0)
            yield sitl, service, bridge
    finally:
        service.close()
        await sitl.stop()


def frames_of(data: bytes) -> list[Any]:
    parser = MAV.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


# ---------------------------------------------------------------------------------------------------


def test_endpoints_parse_pymavlink_strings_and_reject_others() -> None:
    assert Endpoint.parse("tcp:127.0.0.1:5762") == Endpoint(Scheme.TCP, "127.0.0.1", 5762)
    assert Endpoint.parse("udpin:0.0.0.0:14550").scheme is Scheme.UDPIN
    assert str(Endpoint.parse("udpout:localhost:14550")) == "udpout:localhost:14550"
    for bad in ("serial:/dev/ttyS0:57600", "tcp:127.0.0.1", "udpin::14550", "tcp:127.0.0.1:70000"):
        with pytest.raises(ConfigError):
            Endpoint.parse(bad)
    with pytest.raises(ConfigError, match="chem_rate_hz"):
        BridgeOptions(chem_rate_hz=-1.0)
    with pytest.raises(ConfigError, match="1 to 10 bytes"):
        BridgeOptions(sensor_name="CHEMICAL_SENSOR")


@pytest.mark.parametrize(
    ("east", "north", "from_deg"),
    [(1.0, 0.0, 270.0), (0.0, 1.0, 180.0), (-2.0, 0.0, 90.0), (0.0, -0.5, 0.0), (1.0, 1.0, 225.0)],
)
def test_wind_reports_where_the_flow_comes_from(east: float, north: float, from_deg: float) -> None:
    direction, speed = wind_fields(east, north)
    assert direction == pytest.approx(from_deg)
    assert speed == pytest.approx(math.hypot(east, north))


def test_forwarding_is_byte_exact_both_ways() -> None:
    stream = awkward_stream()
    companion = Encoder(1, 191)
    upstream = b"".join(companion(MAV.MAVLink_system_time_message(k, k)) for k in range(100))
    upstream += b"\x13\x37junk" + Encoder(255, 190)(MAV.MAVLink_statustext_message(4, b"gcs"))

    async def main() -> tuple[bytes, bytes, Any]:
        async with tcp_rig(position_rate_hz=0.0) as (sitl, service, bridge):
            await sitl.send(stream)
            await until(lambda: len(service.snapshot()) >= len(stream), 5.0)
            assert service.peer is not None
            for k in range(0, len(upstream), 500):  # the service's datagrams, from its own port
                service.sock.sendto(upstream[k : k + 500], service.peer)
            await until(lambda: len(sitl.received) >= len(upstream), 5.0)
            return service.snapshot(), bytes(sitl.received), bridge.status()

    down, up, status = asyncio.run(main())
    assert down == stream
    assert up == upstream
    assert status.from_sitl.bad >= 3  # garbage, unknown id, bad CRC: passed on regardless
    assert status.chem_sent == 0  # no position was heard: nothing injected


def test_nothing_lost_under_load_while_injecting() -> None:
    enc = Encoder(1, 1)
    burst = [enc(autopilot_heartbeat())]
    burst += [enc(position(k, 44.0, 58.75)) for k in range(20_000)]
    sent = b"".join(burst)

    async def main() -> tuple[bytes, Any]:
        async with tcp_rig(position_rate_hz=0.0, chem_rate_hz=50.0) as (sitl, service, bridge):
            await sitl.send(sent, chunk=4096)
            await until(lambda: bridge.status().from_sitl.frames >= len(burst), 15.0)
            await until(lambda: len(service.snapshot()) >= len(sent), 5.0)
            await bridge.wait_for(lambda s: s.chem_sent >= 5, 5.0)
            await until(
                lambda: sum(f.get_srcComponent() == PERIPHERAL for f in frames_of(service.snapshot())) >= 5,
                5.0,
            )
            return service.snapshot(), bridge.status()

    received, status = asyncio.run(main())
    frames = frames_of(received)
    forwarded = b"".join(bytes(f.get_msgbuf()) for f in frames if f.get_srcComponent() != PERIPHERAL)
    injected = [f for f in frames if f.get_srcComponent() == PERIPHERAL]
    assert forwarded == sent  # every frame, in order, unchanged, none torn by an injected one
    assert all(f.get_type() in ("NAMED_VALUE_FLOAT", "WIND") for f in injected)
    assert all(f.get_srcSystem() == 1 for f in injected)
    assert status.from_sitl.dropped == 0
    assert status.position_m == pytest.approx((58.75, 44.0))


def stub_rig(bridge_world: World, talk: Callable[[Any, VehicleStub, SitlBridge], Any]) -> Any:
    """The stub as SITL (no WIND, no CHEM of its own), the bridge, and a pymavlink companion."""
    from service.edges.mavlink_dialect import mavutil

    sitl_port, service_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    rates = {
        Stream.HEARTBEAT: 1.0,
        Stream.LOCAL_POSITION_NED: 1.0,
        Stream.WIND: 0.0,
        Stream.WIND_COV: 0.0,
        Stream.NAMED_VALUE_FLOAT: 0.0,
    }

    async def main() -> Any:
        conn = mavutil().mavlink_connection(
            f"udpin:127.0.0.1:{service_port}", source_system=1, source_component=191
        )
        try:
            options = BridgeOptions(
                sitl_url=f"udpin:127.0.0.1:{sitl_port}", to_url=f"udpout:127.0.0.1:{service_port}"
            )
            async with SitlBridge(bridge_world, options) as bridge:
                stub_options = StubOptions(url=f"udpout:127.0.0.1:{sitl_port}", rates_hz=rates)
                async with VehicleStub(wang(), stub_options) as stub:
                    await bridge.wait_for(lambda s: s.position_m is not None and s.chem_sent > 0, 10.0)
                    return await asyncio.to_thread(talk, conn, stub, bridge)
        finally:
            conn.close()

    return asyncio.run(main())


def collect(conn: Any, duration_s: float) -> list[tuple[float, Any]]:
    out = []
    end = time.monotonic() + duration_s
    while (left := end - time.monotonic()) > 0:
        msg = conn.recv_match(blocking=True, timeout=left)
        if msg is not None:
            out.append((time.monotonic(), msg))
    return out


def rate_hz(stamps: list[float]) -> float:
    return (len(stamps) - 1) / (stamps[-1] - stamps[0])


def test_stub_as_sitl_injection_rates_values_and_commands_pass() -> None:
    def talk(conn: Any, stub: VehicleStub, bridge: SitlBridge) -> Any:
        seen = collect(conn, 2.5)
        conn.mav.command_long_send(
            1, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
        )  # through the bridge
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=3.0)
        return seen, ack, stub.status(), bridge.status()

    seen, ack, stub_status, status = stub_rig(wang(), talk)
    chem = [(t, m) for t, m in seen if m.get_type() == "NAMED_VALUE_FLOAT"]
    wind = [(t, m) for t, m in seen if m.get_type() == "WIND"]
    assert {(m.get_srcSystem(), m.get_srcComponent()) for _, m in chem + wind} == {(1, PERIPHERAL)}
    assert rate_hz([t for t, _ in chem]) == pytest.approx(10.0, rel=0.15)
    assert rate_hz([t for t, _ in wind]) == pytest.approx(2.0, rel=0.3)
    # flow 1 m/s toward East comes FROM the West; the start (58.75, 44) is far off the plume
    assert all(m.direction == pytest.approx(270.0) and m.speed == pytest.approx(1.0) for _, m in wind)
    assert all(m.name == "CHEM" and m.value == 0.0 for _, m in chem)
    assert any(m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1 for _, m in seen)  # forwarded
    assert ack is not None
    assert ack.result == MAV.MAV_RESULT_ACCEPTED
    assert stub_status.armed
    assert stub_status.rates_hz[Stream.LOCAL_POSITION_NED] == pytest.approx(5.0)  # the bridge asked
    assert status.position_m == pytest.approx((58.75, 44.0))


def test_stub_as_sitl_at_the_source_reads_the_plume() -> None:
    def talk(conn: Any, stub: VehicleStub, bridge: SitlBridge) -> list[float]:
        return [m.value for _, m in collect(conn, 1.5) if m.get_type() == "NAMED_VALUE_FLOAT"]

    readings = stub_rig(wang("world.source.position_m=[58.75, 44.0]"), talk)
    assert max(readings) >= 1.0  # the service's threshold: detections right at the source


def test_written_service_config_reads_back_as_the_scenario(tmp_path: Path) -> None:
    scenario = load_scenario("wang-laminar")
    path = tmp_path / "sitl.toml"
    path.write_text(config_toml(scenario.config, "header\nlines"), encoding="utf-8")
    assert load_config(path) == scenario.config
