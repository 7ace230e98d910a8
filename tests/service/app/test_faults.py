"""Faults while a mission runs: silent sensors, the MCAP file lost, late Zenoh peers (issue 7)."""

import asyncio
import errno
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from service.edges.recorder import EVENT_TOPIC, RecordingReader
from service.tools.sim import closed_loop
from sim_bridge.scenarios import load_scenario
from sim_bridge.stub import Stream

pytestmark = pytest.mark.sim


async def until(condition: Callable[[], bool], timeout_s: float = 20.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():
            await asyncio.sleep(0.01)


def test_silent_chemical_sensor_invents_nothing_and_records_the_gap(tmp_path: Path) -> None:
    async def body() -> Path:
        async with closed_loop(
            load_scenario("wang-laminar"), 1, speed=5.0, recorder_dir=str(tmp_path)
        ) as loop:
            stub, service = loop.stub, loop.service
            await until(lambda: service.stats.observations >= 3)
            chem = stub.status().rates_hz[Stream.NAMED_VALUE_FLOAT]
            stub.set_rate(Stream.NAMED_VALUE_FLOAT, 0.0)
            gaps0 = service.stats.gaps.get("chemical", 0)
            await until(lambda: service.stats.gaps.get("chemical", 0) > gaps0)
            pi, alpha = service.mapper.likelihood.copy(), service.mapper.plume.copy()
            observations, ticks = service.stats.observations, service.stats.ticks
            await until(lambda: service.stats.ticks >= ticks + 4)
            assert service.stats.observations == observations  # no tick without a reading is mapped
            np.testing.assert_array_equal(service.mapper.likelihood, pi)  # the map is not updated
            np.testing.assert_array_equal(service.mapper.plume, alpha)
            stub.set_rate(Stream.NAMED_VALUE_FLOAT, chem)
            await until(lambda: service.stats.observations > observations)  # and it resumes
            assert service.stats.mcap is not None
            return Path(service.stats.mcap)

    mcap = asyncio.run(body())
    gaps = [
        json.loads(m.data)
        for m in RecordingReader(mcap).messages()
        if m.topic == EVENT_TOPIC and json.loads(m.data)["name"] == "gap"
    ]
    assert sum("chemical" in g["missing"] for g in gaps) >= 4


@pytest.mark.parametrize("fault", ["removed", "disk_full"])
def test_recording_fault_stops_recording_not_the_service(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, fault: str
) -> None:
    async def body() -> None:
        async with closed_loop(
            load_scenario("wang-laminar"), 1, speed=5.0, recorder_dir=str(tmp_path)
        ) as loop:
            service = loop.service
            assert service.edges is not None
            recorder: Any = service.edges.recorder
            assert recorder.path is not None
            await until(lambda: service.stats.observations >= 2)
            if fault == "removed":
                recorder.path.unlink()
            else:  # the next flush hits a full disk
                writer: Any = recorder._writer

                def full(*_: Any) -> None:
                    raise OSError(errno.ENOSPC, "No space left on device")

                writer.flush = full
            await until(lambda: not recorder.active)
            observations, setpoints = service.stats.observations, service.stats.setpoints
            await until(lambda: service.stats.observations >= observations + 3)  # mapping goes on
            await until(lambda: service.stats.setpoints > setpoints)  # commanding goes on
            assert "slim" in service.edges.maps.latest()  # type: ignore[attr-defined]

    with caplog.at_level(logging.ERROR, logger="service.edges.recorder"):
        asyncio.run(body())
    lines = [r for r in caplog.records if "recording stopped" in r.getMessage()]
    assert len(lines) == 1


def test_zenoh_peers_come_and_go(tmp_path: Path) -> None:
    """A subscriber leaves; another joins late: it gets the latest maps at once, then live ones."""

    def session(endpoint: str) -> zenoh.Session:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        return zenoh.open(conf)

    async def body() -> None:
        async with closed_loop(
            load_scenario("wang-laminar"), 1, speed=5.0, recorder_dir=str(tmp_path)
        ) as loop:
            prefix = f"{loop.config.zenoh.key_prefix}/{loop.config.vehicle.id}"
            await until(lambda: loop.service.stats.observations >= 2)
            for _visit in range(2):
                received: list[Any] = []
                with session(loop.zenoh_endpoint) as peer:
                    keys: set[str] = set()
                    async with asyncio.timeout(10):  # the new peer's routes take a moment to form
                        while not {"slim", "plume", "estimate", "obs"} <= keys:
                            replies = await asyncio.to_thread(lambda p=peer: list(p.get(f"{prefix}/**")))
                            keys = {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok}
                    peer.declare_subscriber(f"{prefix}/slim", received.append)
                    await until(lambda r=received: len(r) >= 2)  # type: ignore[misc]
                ticks = loop.service.stats.ticks
                await until(lambda t=ticks: loop.service.stats.ticks >= t + 3)  # type: ignore[misc]  # no peer now

    asyncio.run(body())
