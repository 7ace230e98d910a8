"""The service and ``oslim sitl-bridge`` against ArduPilot Rover SITL (marked ``sitl``; see conftest)."""

from __future__ import annotations

import asyncio
import json
import math
import socket
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from service.app.preflight import Status, preflight
from service.app.service import Service
from service.core.config import Config, load_config
from service.tools.sim import within_one_cell
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.sitl_bridge import BridgeOptions, SitlBridge

pytestmark = pytest.mark.sitl
ROVER_GUIDED, ROVER_HOLD = 15, 4
Sitl = Any  # the conftest's Sitl: instance, workdir, pilot, companion_port


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def service_config(base: Config, url: str, recorder_dir: Path) -> Config:
    """``base`` talking MAVLink on ``url``, Zenoh on loopback only, MCAP under ``recorder_dir``."""
    return base.model_copy(
        update={
            "mavlink": base.mavlink.model_copy(update={"url": url}),
            "zenoh": base.zenoh.model_copy(
                update={
                    "listen": [f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"],
                    "multicast_scouting": False,
                }
            ),
            "recorder": base.recorder.model_copy(update={"dir": str(recorder_dir)}),
        }
    )


@asynccontextmanager
async def running(service: Service) -> AsyncIterator[asyncio.Task[Any]]:
    stop = asyncio.Event()
    task = asyncio.create_task(service.run(stop))
    try:
        await asyncio.wait_for(service.started.wait(), 30.0)
        yield task
    finally:
        stop.set()
        await asyncio.wait_for(task, 30.0)


async def until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        await asyncio.sleep(0.1)


def received(service: Service, kind: str) -> int:
    link = service.edges.link if service.edges is not None else None
    return 0 if link is None else link.counters.by_type.get(kind, 0)


def test_lua_script_sends_chem_when_enabled(sitl: Sitl) -> None:
    pilot = sitl.pilot
    pilot.param("CHEM_ENABLE", 1)
    pilot.param("CHEM_RATE", 5)
    first = pilot.recv("NAMED_VALUE_FLOAT", 10.0, where=lambda m: m.name == "CHEM")
    stamps = [first.time_boot_ms]
    while len(stamps) < 6:
        stamps.append(pilot.recv("NAMED_VALUE_FLOAT", 3.0, where=lambda m: m.name == "CHEM").time_boot_ms)
    pilot.param("CHEM_ENABLE", 0)
    assert first.get_srcSystem() == 1
    assert (stamps[-1] - stamps[0]) / (len(stamps) - 1) == pytest.approx(200.0, abs=40.0)  # 5 Hz


def test_streams_guided_armed_gate_and_hold(sitl: Sitl, tmp_path: Path) -> None:
    pilot = sitl.pilot
    overrides = ["area.x_min=-50.0", "area.x_max=50.0"]  # SITL starts at its origin: mid-area
    config = service_config(load_config(None, overrides), f"tcp:127.0.0.1:{sitl.companion_port}", tmp_path)

    async def main() -> dict[str, Any]:
        service = Service(config)
        out: dict[str, Any] = {}
        # the chemical sensor: the shipped Lua script on SITL's analog pin (no reading, no tick:
        # the service never invents an observation)
        await asyncio.to_thread(pilot.param, "CHEM_ENABLE", 1)
        async with running(service):
            await until(lambda: received(service, "COMMAND_ACK") >= 3, 15.0, "acks of the stream requests")
            # ArduPilot sends LOCAL_POSITION_NED only once the EKF has its origin (GPS, ~10-40 s)
            await until(lambda: received(service, "LOCAL_POSITION_NED") > 0, 90.0, "a first position")
            n0, t0 = received(service, "LOCAL_POSITION_NED"), time.monotonic()
            await until(lambda: time.monotonic() - t0 >= 4.0, 10.0, "four seconds")
            out["position_hz"] = (received(service, "LOCAL_POSITION_NED") - n0) / (time.monotonic() - t0)
            await until(lambda: service.target is not None, 30.0, "a first target")
            out["setpoints_disarmed"] = service.stats.setpoints
            await asyncio.to_thread(pilot.mode, ROVER_GUIDED)
            await until(
                lambda: service.gate.last is not None and service.gate.last.custom_mode == 15, 5, "GUIDED"
            )
            out["setpoints_guided_disarmed"] = service.stats.setpoints
            start = await asyncio.to_thread(pilot.position)
            await asyncio.to_thread(pilot.arm)
            await until(lambda: service.stats.setpoints > 0, 10.0, "setpoints once armed in GUIDED")
            # the rover needs a few seconds to pull away from standstill
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline:
                moved = await asyncio.to_thread(pilot.position)
                if math.dist(start, moved) > 2.0:
                    break
            out["moved_m"] = math.dist(start, moved)
            out["setpoints_to_move"] = service.stats.setpoints
            await asyncio.to_thread(pilot.mode, ROVER_HOLD)
            await until(lambda: not service.gate.state(service.clock.now()).allowed, 5.0, "HOLD seen")
            await asyncio.sleep(0.6)  # a setpoint already on its way may still land
            held = service.stats.setpoints
            await asyncio.sleep(3.0)  # the rover brakes to a stop meanwhile
            out["setpoints_in_hold"] = service.stats.setpoints - held
            a = await asyncio.to_thread(pilot.position)
            await asyncio.sleep(2.0)
            b = await asyncio.to_thread(pilot.position)
            out["drift_in_hold_m"] = math.dist(a, b)
            out["wind"] = received(service, "WIND")
            out["chem"] = received(service, "NAMED_VALUE_FLOAT")
            out["observations"] = service.stats.observations
        await asyncio.to_thread(pilot.param, "CHEM_ENABLE", 0)
        await asyncio.to_thread(pilot.mode, ROVER_HOLD)
        return out

    out = asyncio.run(main())
    print("SITL streams:", json.dumps(out))
    assert out["position_hz"] >= 4.0  # asked at mavlink.stream_hz = 5
    assert out["setpoints_disarmed"] == 0
    assert out["setpoints_guided_disarmed"] == 0
    assert out["moved_m"] > 1.0  # ArduPilot followed the service's setpoints
    assert out["setpoints_in_hold"] == 0
    assert out["drift_in_hold_m"] < 0.5


def test_preflight_hears_sitl_as_the_service_would(sitl: Sitl, tmp_path: Path) -> None:
    pilot = sitl.pilot
    overrides = ["area.x_min=-50.0", "area.x_max=50.0"]  # SITL starts at its origin: mid-area
    config = service_config(load_config(None, overrides), f"tcp:127.0.0.1:{sitl.companion_port}", tmp_path)
    pilot.param("CHEM_ENABLE", 1)
    pilot.param("CHEM_RATE", 5)
    try:
        checks = {c.name: c for c in preflight(config, 8.0)}
    finally:
        pilot.param("CHEM_ENABLE", 0)
    print("SITL preflight:", json.dumps({n: [c.status.value, c.detail] for n, c in checks.items()}))
    assert checks["autopilot"].status is Status.PASS
    assert "ArduPilot Rover" in checks["autopilot"].detail
    assert checks["guided mode"].status is Status.PASS  # Rover's GUIDED is the default 15
    assert checks["position"].status is Status.PASS
    assert checks["chemical"].status is Status.PASS
    # the windvane's WIND is heard (this SITL build's reads 0 m/s: a warning, not a failure)
    assert checks["flow"].status in (Status.PASS, Status.WARN)
    assert "WIND" in checks["flow"].detail


def test_mission_through_sitl_bridge_declares_the_source(sitl: Sitl, tmp_path: Path) -> None:
    pilot = sitl.pilot
    scenario = load_scenario("wang-laminar")
    world = build_world(scenario, seed=1)
    start = (world.vehicle.x_m, world.vehicle.y_m)
    source = world.plume.source_m
    service_port = free_port(socket.SOCK_DGRAM)
    config = service_config(scenario.config, f"udpin:127.0.0.1:{service_port}", tmp_path)
    # SITL's windvane reports no wind on this build (0 m/s even while the rover drives), so the
    # bridge injects the scenario's flow as WIND and the windvane is switched off
    pilot.param("WNDVN_TYPE", 0)
    # the pilot brings the rover to the scenario's start, then holds it there
    pilot.mode(ROVER_GUIDED)
    pilot.arm()
    pilot.drive_to(*start)
    pilot.mode(ROVER_HOLD)

    async def main() -> dict[str, Any]:
        options = BridgeOptions(
            sitl_url=f"tcp:127.0.0.1:{sitl.companion_port}",
            to_url=f"udpout:127.0.0.1:{service_port}",
        )
        async with SitlBridge(world, options) as bridge:
            await bridge.wait_for(lambda s: s.position_m is not None and s.chem_sent > 0, 20.0)
            service = Service(config)
            async with running(service) as task:
                await until(lambda: service.gate.last is not None, 10.0, "the autopilot through the bridge")
                await asyncio.to_thread(pilot.mode, ROVER_GUIDED)  # hand over to the service
                t0, d0 = service.clock.now(), bridge.status().distance_m
                await until(lambda: service.declared is not None or task.done(), 900.0, "a declaration")
                declared = service.declared
                assert declared is not None
                await asyncio.to_thread(pilot.mode, ROVER_HOLD)
                status = bridge.status()
                return {
                    "time_s": round(declared.time_s - t0, 1),
                    "declared": (declared.x, declared.y),
                    "error_m": round(math.dist((declared.x, declared.y), source), 2),
                    "path_m": round(status.distance_m - d0, 1),
                    "dropped": status.from_sitl.dropped,
                    "setpoints": service.stats.setpoints,
                }

    out = asyncio.run(main())
    print("SITL mission:", json.dumps(out))
    assert within_one_cell(scenario, out["declared"], source)
    assert out["dropped"] == 0
