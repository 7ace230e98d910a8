"""Restart mid-mission: the map state survives a kill (issue 7, faults)."""

import asyncio
import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from service.app.service import Clock, Service
from service.core.config import build_config
from service.core.grid import Grid
from service.core.mapping import mapper_from_config
from service.core.observation import Observation
from service.edges.snapshot import (
    Snapshot,
    SnapshotWriter,
    decode,
    encode,
    fingerprint,
    map_digest,
    read_snapshot,
)
from service.tools.sim import free_port, loopback_config
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.stub import StubOptions, VehicleStub

CONFIG = build_config({"mapping": {"window": 5}})


def fed_mapper(n: int):  # type: ignore[no-untyped-def]
    grid = Grid.from_config(CONFIG.area)
    mapper = mapper_from_config(CONFIG, grid)
    for k in range(n):
        mapper.update(Observation(1.0 + k, 30.0 + k, 3.0 - k, 1.0, 0.3 * (-1) ** k, detected=k % 3 == 0))
    return mapper


def test_mapper_state_round_trip_is_exact() -> None:
    before = fed_mapper(8)  # more ticks than the window: the history is full
    data = encode(Snapshot(fingerprint(CONFIG), 8.0, 8, time.time(), before.save_state(), {}))
    after = mapper_from_config(CONFIG, before.grid)
    after.restore_state(decode(data).mapper)
    np.testing.assert_array_equal(after.likelihood, before.likelihood)
    np.testing.assert_array_equal(after.plume, before.plume)
    assert len(after.history) == len(before.history) == 5
    # and both continue identically
    obs = Observation(9.0, 40.0, 0.0, 0.8, 0.1, detected=True)
    assert before.update(obs)
    assert after.update(obs)
    np.testing.assert_array_equal(after.likelihood, before.likelihood)
    np.testing.assert_array_equal(after.plume, before.plume)


def test_restore_refuses_a_map_of_another_grid() -> None:
    state = fed_mapper(2).save_state()
    other = build_config({"area": {"columns": 10, "rows": 10}})
    mapper = mapper_from_config(other, Grid.from_config(other.area))
    with pytest.raises(ValueError, match="does not fit"):
        mapper.restore_state(state)
    np.testing.assert_array_equal(mapper.likelihood, np.full((10, 10), 0.01))


def test_snapshot_of_other_settings_or_corrupt_is_ignored(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "snap.npz"
    writer = SnapshotWriter(path)
    writer.check()
    assert writer.write(Snapshot(fingerprint(CONFIG), 3.0, 3, time.time(), fed_mapper(3).save_state(), {}))
    assert not list(tmp_path.glob(".*.tmp"))  # written under a temporary name, then renamed
    assert read_snapshot(path, CONFIG) is not None
    assert read_snapshot(path, build_config({"mapping": {"window": 6}})) is None
    path.write_bytes(path.read_bytes()[:100])  # a torn file (cannot happen with os.replace)
    assert read_snapshot(path, CONFIG) is None
    assert "ignored" in caplog.text
    assert read_snapshot(tmp_path / "absent.npz", CONFIG) is None


def test_service_restarted_in_process_has_the_same_map(tmp_path: Path) -> None:
    snap = tmp_path / "state" / "oslim.npz"
    scenario = load_scenario("wang-laminar", [f'service.snapshot_path="{snap}"'])
    port = free_port(socket.SOCK_DGRAM)
    config = loopback_config(scenario.config, port, free_port(socket.SOCK_STREAM), str(tmp_path))

    async def body() -> None:
        world = build_world(scenario, 1)
        async with VehicleStub(world, StubOptions(url=f"udpout:127.0.0.1:{port}", speed=10.0)):
            first = Service(config, clock=Clock(10.0))
            task = asyncio.create_task(first.run(asyncio.Event()))
            async with asyncio.timeout(30):
                while first.stats.observations < 8:
                    await asyncio.sleep(0.01)
            task.cancel()  # abrupt: no orderly stop
            with contextlib.suppress(asyncio.CancelledError):
                await task
        again = Service(config)
        np.testing.assert_array_equal(again.mapper.likelihood, first.mapper.likelihood)
        np.testing.assert_array_equal(again.mapper.plume, first.mapper.plume)
        assert again.stats.restored_ticks == first.stats.observations
        assert again.search.state == first.search.state
        assert again.clock.now() >= first.clock.now() - 1.0  # time continues, not from 0

    asyncio.run(body())


def _serve(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as err:  # the child keeps its own descriptor
        return subprocess.Popen(
            [sys.executable, "-m", "service.cli", "serve", *args],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )


async def _wait_file(condition, timeout_s: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    async with asyncio.timeout(timeout_s):
        while not condition():
            await asyncio.sleep(0.05)


def test_sigkill_and_restart_restores_the_map(tmp_path: Path) -> None:
    """`oslim serve` fed by the stub, SIGKILLed mid-mission, started again: same map."""
    snap = tmp_path / "oslim.npz"
    port = free_port(socket.SOCK_DGRAM)
    args = [
        "--set", f'mavlink.url="udpin:127.0.0.1:{port}"',
        "--set", "zenoh.multicast_scouting=false",
        "--set", f'zenoh.listen=["tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]',
        "--set", f'recorder.dir="{tmp_path / "runs"}"',
        "--set", f'service.snapshot_path="{snap}"',
        "--set", "mapping.tick_s=0.2",
    ]  # fmt: skip

    def ticks() -> int:
        try:
            return decode(snap.read_bytes()).ticks
        except (OSError, ValueError):
            return -1

    async def body() -> tuple[Snapshot, str, int]:
        world = build_world(load_scenario("wang-laminar"), 1)
        options = StubOptions(url=f"udpout:127.0.0.1:{port}", speed=1.0)
        async with VehicleStub(world, options):
            proc = _serve(args, tmp_path / "first.log")
            try:
                await _wait_file(lambda: ticks() >= 5)
            finally:
                proc.send_signal(signal.SIGKILL)
                await asyncio.to_thread(proc.wait, 10)
            saved = decode(snap.read_bytes())
            proc = _serve(args, tmp_path / "second.log")
            try:
                await _wait_file(lambda: "snapshot: restored" in (tmp_path / "second.log").read_text())
                await _wait_file(lambda: ticks() >= saved.ticks + 3)  # and it carries on mapping
            finally:
                proc.send_signal(signal.SIGTERM)
                code = await asyncio.to_thread(proc.wait, 15)
        return saved, (tmp_path / "second.log").read_text(), code

    saved, log, code = asyncio.run(body())
    assert code == 0
    match = re.search(r"snapshot: restored (\d+) ticks, mission (\w+), estimate cell \d+, map (\w+)", log)
    assert match is not None, log
    assert int(match.group(1)) == saved.ticks
    assert match.group(3) == map_digest(saved.mapper["pi"])
