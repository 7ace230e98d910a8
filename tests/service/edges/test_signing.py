"""MAVLink 2 signing between the service and the stub, both ways (issue 7, security)."""

import asyncio
import contextlib
import os
import socket
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from service.app.service import Clock, Service
from service.core.errors import ConfigError
from service.edges.signing import load_signing_key
from service.tools.sim import free_port, loopback_config
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.stub import StubOptions, VehicleStub

pytestmark = pytest.mark.sim

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
SPEED = 5.0


@dataclass
class Pair:
    service: Service
    stub: VehicleStub


async def until(condition: Callable[[], bool], timeout_s: float = 20.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():
            await asyncio.sleep(0.01)


@contextlib.asynccontextmanager
async def pair(tmp_path: Path, service_key: bytes | None, stub_key: bytes | None) -> AsyncIterator[Pair]:
    scenario = load_scenario("wang-laminar")
    port = free_port(socket.SOCK_DGRAM)
    config = loopback_config(scenario.config, port, free_port(socket.SOCK_STREAM), str(tmp_path))
    if service_key is not None:
        key_file = tmp_path / "mavlink.key"
        key_file.write_bytes(service_key)
        key_file.chmod(0o600)
        config = config.model_copy(
            update={"mavlink": config.mavlink.model_copy(update={"signing_key_file": str(key_file)})}
        )
    options = StubOptions(url=f"udpout:127.0.0.1:{port}", speed=SPEED, signing_key=stub_key)
    async with VehicleStub(build_world(scenario, 1), options) as stub:
        service = Service(config, clock=Clock(SPEED))
        stop = asyncio.Event()
        task = asyncio.create_task(service.run(stop))
        try:
            await until(lambda: service.started.is_set() or task.done())
            stub.pilot_mode(config.mavlink.guided_mode)
            stub.pilot_arm(True)
            yield Pair(service, stub)
        finally:
            stop.set()
            await task


def test_signed_both_ways_is_accepted(tmp_path: Path) -> None:
    async def body() -> None:
        async with pair(tmp_path, KEY, KEY) as p:
            await until(lambda: p.stub.status().target_m is not None)  # commands accepted
            assert p.service.stats.observations > 0  # telemetry accepted
            await until(lambda: p.service.edges is not None and p.service.edges.link.signing is not None
                        and p.service.edges.link.signing.good > 10)  # fmt: skip
            assert p.stub.signing is not None
            assert p.stub.signing.good > 0
            assert p.stub.signing.bad_signature == p.stub.signing.unsigned == 0

    asyncio.run(body())


@pytest.mark.parametrize(("stub_key", "counter"), [(None, "unsigned"), (OTHER_KEY, "bad_signature")])
def test_service_ignores_unsigned_or_wrongly_signed_telemetry(
    tmp_path: Path, stub_key: bytes | None, counter: str
) -> None:
    async def body() -> None:
        async with pair(tmp_path, KEY, stub_key) as p:
            await until(lambda: p.service.stats.link.get(counter, 0) >= 20)
            assert p.service.gate.system is None  # no heartbeat was believed
            assert p.service.stats.observations == 0
            assert p.service.stats.setpoints == 0
            assert p.stub.status().target_m is None

    asyncio.run(body())


@pytest.mark.parametrize(("service_key", "counter"), [(None, "unsigned"), (OTHER_KEY, "bad_signature")])
def test_stub_ignores_unsigned_or_wrongly_signed_commands(
    tmp_path: Path, service_key: bytes | None, counter: str
) -> None:
    async def body() -> None:
        async with pair(tmp_path, service_key, KEY) as p:
            stub = p.stub
            await until(lambda: stub.signing is not None and getattr(stub.signing, counter) >= 3)
            await asyncio.sleep(1.0)  # several setpoint periods
            assert stub.status().target_m is None
            assert stub.status().counters.ignored_setpoints == 0  # not even seen as setpoints

    asyncio.run(body())


def test_key_file_formats(tmp_path: Path) -> None:
    raw, hexa, bad = tmp_path / "raw", tmp_path / "hex", tmp_path / "bad"
    raw.write_bytes(KEY)
    hexa.write_text(KEY.hex() + "\n")
    bad.write_text("zz" * 32)
    assert load_signing_key(raw) == KEY == load_signing_key(hexa)
    with pytest.raises(ConfigError, match=r"mavlink\.signing_key_file"):
        load_signing_key(bad)
    os.chmod(raw, 0o644)  # readable by others: works, with a warning
    assert load_signing_key(raw) == KEY
