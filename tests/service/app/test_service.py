"""The service against the vehicle stub over real loopback MAVLink and Zenoh (issue 5's tests)."""

import asyncio
import json
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from service.app.service import SILENT_TICKS, Service
from service.core.config import Config
from service.edges.grid_message import decode_grid
from service.tools.replay import replay
from service.tools.sim import ClosedLoop, closed_loop
from sim_bridge.scenarios import load_scenario
from sim_bridge.stub import Stream

pytestmark = pytest.mark.sim

HOLD = 4  # Rover HOLD


async def until(condition: Callable[[], bool], timeout_s: float = 20.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():
            await asyncio.sleep(0.01)


async def sim_wait(loop: ClosedLoop, seconds: float) -> None:
    """Wait ``seconds`` of simulated time."""
    end = loop.stub.status().time_s + seconds
    await until(lambda: loop.stub.status().time_s >= end)


def test_mode_gating(tmp_path: Path) -> None:
    async def body() -> None:
        scenario = load_scenario("wang-laminar")
        async with closed_loop(scenario, 1, speed=5.0, recorder_dir=str(tmp_path), pilot=False) as loop:
            stub, service = loop.stub, loop.service
            await until(lambda: service.stats.observations >= 3)
            # disarmed, in MANUAL: mapping goes on, nothing is commanded
            assert service.stats.setpoints == 0
            assert stub.status().counters.ignored_setpoints == 0
            assert stub.status().target_m is None

            stub.pilot_mode(service.config.mavlink.guided_mode)
            await sim_wait(loop, 3.0)
            assert service.stats.setpoints == 0  # GUIDED but still disarmed
            stub.pilot_arm(True)
            await until(lambda: stub.status().target_m is not None)

            # the pilot takes over: commanding stops within one tick of the 1 Hz heartbeat saying so
            stub.pilot_mode(HOLD)
            await sim_wait(loop, 1.5)
            assert not service._gate_state.allowed
            assert "not in GUIDED" in service._gate_state.reason
            sent, ignored = service.stats.setpoints, stub.status().counters.ignored_setpoints
            observations = service.stats.observations
            await sim_wait(loop, 4.0)
            assert service.stats.setpoints == sent
            assert stub.status().counters.ignored_setpoints == ignored
            assert service.stats.observations > observations  # mapping goes on

            # GUIDED again: commanding resumes
            stub.pilot_mode(service.config.mavlink.guided_mode)
            await until(lambda: service.stats.setpoints > sent)
            await until(lambda: stub.status().target_m is not None)

    asyncio.run(body())


def test_link_loss_and_recovery(tmp_path: Path) -> None:
    async def body() -> None:
        scenario = load_scenario("wang-laminar")
        async with closed_loop(scenario, 1, speed=5.0, recorder_dir=str(tmp_path)) as loop:
            stub, service = loop.stub, loop.service
            await until(lambda: service.stats.setpoints >= 3)
            rates = dict(stub.status().rates_hz)
            for stream in Stream:
                stub.set_rate(stream, 0.0)  # the vehicle goes silent
            silent_at = service.clock.now()
            await until(lambda: not service._gate_state.allowed)
            assert service._gate_state.reason.startswith("link lost")
            assert service.clock.now() - silent_at <= 3.0 + 1.0  # link_timeout_s, plus one send period
            sent, ticks = service.stats.setpoints, service.stats.ticks
            await sim_wait(loop, 2.0)
            assert service.stats.setpoints == sent  # nothing commanded while the link is down
            assert service.stats.ticks > ticks  # the service keeps ticking
            assert service.stats.gaps.get("flow", 0) > 0  # and says what is missing
            for stream, rate in rates.items():
                stub.set_rate(stream, rate)
            await until(lambda: service.stats.setpoints > sent)
            assert service._gate_state.allowed
        texts = [t.text for t in loop.stub.status().statustexts]
        assert any("link restored" in t for t in texts)

    asyncio.run(body())


def test_zenoh_maps_queryable_and_mcap_replay(tmp_path: Path) -> None:
    received: list[tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]] = []
    got = threading.Event()

    async def body() -> tuple[dict[str, bytes], Path]:
        scenario = load_scenario("wang-laminar")
        async with closed_loop(scenario, 1, speed=1.0, recorder_dir=str(tmp_path)) as loop:
            service = loop.service
            prefix = f"{loop.config.zenoh.key_prefix}/{loop.config.vehicle.id}"
            conf = zenoh.Config()
            conf.insert_json5("mode", '"peer"')
            conf.insert_json5("connect/endpoints", json.dumps([loop.zenoh_endpoint]))
            conf.insert_json5("scouting/multicast/enabled", "false")
            with zenoh.open(conf) as session:

                def on_sample(sample: Any) -> None:
                    grid = decode_grid(sample.payload.to_bytes())
                    received.append((grid, service.search.likelihood.astype(np.float32)))
                    if len(received) >= 3:
                        got.set()

                session.declare_subscriber(f"{prefix}/slim", on_sample)
                assert await asyncio.to_thread(got.wait, 20.0)
                replies = await asyncio.to_thread(lambda: list(session.get(f"{prefix}/**")))
            latest = {str(r.ok.key_expr).rsplit("/", 1)[-1]: r.ok.payload.to_bytes() for r in replies if r.ok}
            assert service.stats.mcap is not None
            return latest, Path(service.stats.mcap)

    latest, mcap_path = asyncio.run(body())
    n, m = 25, 40
    for grid, live in received:
        assert grid.shape == (n, m)
        np.testing.assert_array_equal(grid, live)
    assert {"slim", "plume", "estimate", "obs"} <= set(latest)
    estimate = json.loads(latest["estimate"])
    assert set(estimate) == {"time_s", "state", "cell", "x", "y", "probability", "entropy"}
    assert decode_grid(latest["slim"]).shape == (n, m)

    with mcap_path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert topics["/oslim/slim"] == "foxglove.Grid"
    assert topics["/oslim/plume"] == "foxglove.Grid"
    assert {"/oslim/config", "/oslim/obs", "/oslim/estimate", "/oslim/setpoint"} <= set(topics)
    report = replay(mcap_path)
    assert report.ok, report.summary()
    assert report.grids_compared >= 6


def test_silent_streams_are_reported_once(caplog: pytest.LogCaptureFixture) -> None:
    service = Service(Config())
    with caplog.at_level("INFO", logger="oslim"):
        for _ in range(SILENT_TICKS + 3):
            service._report_silent_streams(("flow", "chemical"))
        service._report_silent_streams(("chemical",))
    lines = [r.getMessage() for r in caplog.records]
    assert lines.count(f"no flow readings for {SILENT_TICKS} ticks: the map is not updated") == 1
    assert lines.count(f"no chemical readings for {SILENT_TICKS} ticks: the map is not updated") == 1
    assert lines.count("flow readings are back") == 1
    assert not any("chemical readings are back" in line for line in lines)
