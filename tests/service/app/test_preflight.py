"""``oslim preflight``: the checks judged from made-up telemetry, then against the vehicle stub on
loopback (it must hear what the service would, and command nothing)."""

import asyncio
import contextlib
import json
import math
import socket
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from service.app.preflight import Check, Status, Tally, assess, preflight, recorder_writable
from service.cli import main
from service.core.config import Config, build_config
from service.core.samples import ChemSample, DetectionSample, FlowSample, Position
from service.edges.signing import SigningCounters
from service.edges.telemetry import Heartbeat, Rejected
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.stub import Stream, StubOptions, VehicleStub

ROVER, SUB, ARDUPILOT, PX4 = 10, 12, 3, 12
WRITABLE = (True, "recorder.dir writable")


def heard(window_s: float = 10.0, *, vehicle_type: int = ROVER, autopilot: int = ARDUPILOT) -> Tally:
    """A tally of a healthy vehicle: 5 Hz position inside the default area, 1 m/s flow, a quiet
    chemical sensor at 10 Hz."""
    tally = Tally(window_s)
    tally.add("HEARTBEAT", Heartbeat(9.5, 1, 1, vehicle_type, autopilot, 0, False), 1.0)
    for k in range(int(window_s * 10)):
        t = k / 10
        if k % 2 == 0:
            tally.add("LOCAL_POSITION_NED", Position(t, 50.0, 0.0), 1.0)
            tally.add("WIND", FlowSample(t, 1.0, 0.0), 1.0)
        tally.add("NAMED_VALUE_FLOAT", ChemSample(t, 0.2), 1.0)
    tally.zenoh = (0, 1)
    return tally


def by_name(checks: list[Check]) -> dict[str, Check]:
    return {c.name: c for c in checks}


def test_a_healthy_vehicle_passes_every_check() -> None:
    checks = by_name(assess(heard(), Config(), WRITABLE))
    assert {c.status for c in checks.values()} == {Status.PASS}
    assert "ArduPilot Rover" in checks["autopilot"].detail
    assert "LOCAL_POSITION_NED 5.0 Hz" in checks["position"].detail
    assert "1.00 m/s toward bearing 90 deg" in checks["flow"].detail  # toward +x, East
    assert "0% at or above" in checks["chemical"].detail
    assert "would not command yet: vehicle disarmed" in checks["commanding"].detail


@pytest.mark.parametrize(
    ("vehicle_type", "autopilot", "mode", "status", "says"),
    [
        (ROVER, ARDUPILOT, 15, Status.PASS, "Rover's GUIDED"),
        (ROVER, ARDUPILOT, 4, Status.FAIL, "Rover's GUIDED is custom_mode 15"),
        (SUB, ARDUPILOT, 15, Status.FAIL, "Sub's GUIDED is custom_mode 4"),
        (2, ARDUPILOT, 4, Status.PASS, "Copter's GUIDED"),
        (ROVER, PX4, 15, Status.FAIL, "PX4 (OFFBOARD)'s GUIDED is custom_mode 393216"),
        (99, ARDUPILOT, 15, Status.WARN, "not known here"),
    ],
)
def test_guided_mode_is_checked_against_the_autopilot(
    vehicle_type: int, autopilot: int, mode: int, status: Status, says: str
) -> None:
    config = build_config({"mavlink": {"guided_mode": mode}})
    check = by_name(assess(heard(vehicle_type=vehicle_type, autopilot=autopilot), config, WRITABLE))[
        "guided mode"
    ]
    assert check.status is status
    assert says in check.detail


def test_nothing_heard_fails_what_the_map_needs() -> None:
    checks = by_name(assess(Tally(5.0), Config(), WRITABLE))
    failed = {name for name, c in checks.items() if c.status is Status.FAIL}
    assert failed == {"autopilot", "position", "flow", "chemical"}
    assert "mavlink.url" in checks["autopilot"].detail


def test_what_would_cost_the_search_is_a_warning() -> None:
    tally = heard()
    tally.position = Position(9.9, 500.0, 0.0)  # the last position, outside the area
    checks = by_name(assess(tally, Config(), WRITABLE))
    assert checks["position"].status is Status.WARN
    assert "outside the search area" in checks["position"].detail

    still = Tally(10.0)
    for k in range(20):
        still.add("WIND_COV", FlowSample(k / 2, 0.01, 0.0), 1.0)
        still.add("NAMED_VALUE_INT", DetectionSample(k / 2, True), 1.0)
    still.add("WIND", Rejected("WIND", "non-finite or negative wind"), 1.0)
    checks = by_name(assess(still, Config(), WRITABLE))
    assert checks["flow"].status is Status.WARN
    assert "reads as still" in checks["flow"].detail
    assert checks["chemical"].status is Status.WARN  # a detection every time: threshold?
    assert "100% detections" in checks["chemical"].detail
    assert checks["link"].status is Status.WARN
    assert "WIND: non-finite or negative wind x1" in checks["link"].detail

    slow = Tally(10.0)
    for k in range(4):
        slow.add("NAMED_VALUE_FLOAT", ChemSample(k * 3.0, 5.0), 1.0)
    check = by_name(assess(slow, Config(), WRITABLE))["chemical"]
    assert check.status is Status.WARN
    assert "slower than the map's 1 Hz" in check.detail


def test_zenoh_session_is_checked() -> None:
    tally = heard()
    assert (
        "connected to 0 router(s) and 1 peer(s)" in by_name(assess(tally, Config(), WRITABLE))["zenoh"].detail
    )
    tally.zenoh = (0, 0)
    router = build_config({"zenoh": {"mode": "client", "connect": ["tcp/10.0.0.1:7447"]}})
    check = by_name(assess(tally, router, WRITABLE))["zenoh"]
    assert check.status is Status.WARN
    assert "none of zenoh.connect" in check.detail
    tally.zenoh = "zenoh: cannot open a session: address in use"
    check = by_name(assess(tally, Config(), WRITABLE))["zenoh"]
    assert check.status is Status.FAIL
    assert "address in use" in check.detail


def test_signing_on_without_a_signed_message_fails() -> None:
    config = build_config({"mavlink": {"signing_key_file": "/etc/oslim/key"}})
    tally = heard()
    tally.signing = SigningCounters(good=0, bad_signature=0, unsigned=40)
    assert by_name(assess(tally, config, WRITABLE))["link"].status is Status.FAIL
    tally.signing = SigningCounters(good=40, bad_signature=0, unsigned=3)
    check = by_name(assess(tally, config, WRITABLE))["link"]
    assert check.status is Status.WARN
    assert "3 unsigned" in check.detail


def test_recorder_dir_must_be_writable(tmp_path: Path) -> None:
    ok, text = recorder_writable(str(tmp_path / "runs"))
    assert ok
    assert (tmp_path / "runs").is_dir()
    assert not list((tmp_path / "runs").iterdir())  # the probe file is gone
    blocked = tmp_path / "file"
    blocked.write_text("")
    ok, text = recorder_writable(str(blocked / "runs"))
    assert not ok
    assert "cannot write there" in text
    check = by_name(assess(heard(), Config(), (ok, text)))["recorder"]
    assert check.status is Status.FAIL


def test_rates_are_measured_over_the_arrivals() -> None:
    tally = heard(window_s=10.0)
    stream = tally.streams["NAMED_VALUE_FLOAT"]
    assert math.isclose(stream.rate_hz(10.0), 10.0)
    assert math.isclose(stream.rate_hz(100.0), 10.0)  # the span between arrivals, not the window


# -- against the vehicle stub, over loopback ------------------------------------------------------


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextlib.asynccontextmanager
async def stub_on(port: int, **options: object) -> AsyncIterator[VehicleStub]:
    world = build_world(load_scenario("wang-laminar"), 1)
    async with VehicleStub(world, StubOptions(url=f"udpout:127.0.0.1:{port}", **options)) as stub:  # type: ignore[arg-type]
        yield stub


def loopback(port: int, tmp_path: Path) -> list[str]:
    return [
        f"mavlink.url=udpin:127.0.0.1:{port}",
        f"recorder.dir={tmp_path / 'runs'}",
        "zenoh.multicast_scouting=false",
        'zenoh.listen=["tcp/127.0.0.1:0"]',
    ]


@pytest.mark.sim
def test_preflight_hears_the_stub_and_commands_nothing(tmp_path: Path) -> None:
    port = free_udp_port()
    config = build_config({}, loopback(port, tmp_path))

    async def body() -> tuple[list[Check], int]:
        async with stub_on(port) as stub:
            checks = await asyncio.to_thread(preflight, config, 3.0)
            status = stub.status()
            assert status.target_m is None
            assert status.counters.ignored_setpoints == 0
            # the streams were asked for, as the service asks for them
            assert status.rates_hz[Stream.LOCAL_POSITION_NED] == config.mavlink.stream_hz
            return checks, status.counters.received

    checks, received = asyncio.run(body())
    assert received > 0  # our heartbeats and stream requests reached the vehicle
    named = by_name(checks)
    assert {c.status for c in checks} == {Status.PASS}, [c for c in checks if c.status is not Status.PASS]
    assert "ArduPilot Rover" in named["autopilot"].detail
    assert "inside the search area" in named["position"].detail


@pytest.mark.sim
def test_preflight_command_fails_on_a_misconfigured_sensor_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    port = free_udp_port()

    async def body() -> int:
        async with stub_on(port):
            args = ["preflight", "--seconds", "2", "--json"]
            # the stub's flow is 1 m/s and its chemical reading is called CHEM
            for item in [*loopback(port, tmp_path), "sensor.max_flow_mps=0.5", "sensor.name=GAS"]:
                args += ["--set", item]
            return await asyncio.to_thread(main, args)

    code = asyncio.run(body())
    report = json.loads(capsys.readouterr().out)
    assert code == 1
    assert not report["ready"]
    checks = {c["name"]: c for c in report["checks"]}
    assert checks["flow"]["status"] == "FAIL"
    assert "flow faster than 0.5 m/s" in checks["flow"]["detail"]
    assert checks["chemical"]["status"] == "FAIL"
    assert "'GAS'" in checks["chemical"]["detail"]
    assert checks["position"]["status"] == checks["autopilot"]["status"] == "PASS"
