"""``oslim sim``: one whole closed-loop mission on this machine.

The vehicle stub (an ArduPilot-like MAVLink vehicle over a simulated plume) and the service run
in one process but talk only over real sockets on loopback: MAVLink 2 over UDP, maps over a
real Zenoh session (multicast scouting off, so nothing leaves the machine). The sim plays the
pilot: once the service is up it switches the vehicle to GUIDED and arms it. Both clocks run
``speed`` times faster than real time. The run ends when the service declares the source or the
simulated time runs out, and prints one JSON line (the result and the performance figures).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from service.app.service import Clock, Service, ServiceStats
from service.core.config import Config
from service.core.errors import LinkError, OslimError
from sim_bridge.scenarios import Scenario, build_world, load_scenario
from sim_bridge.stub import StubOptions, VehicleStub
from sim_bridge.world import World

log = logging.getLogger("oslim.sim")


@dataclass(frozen=True)
class SimResult:
    found: bool
    declared_x: float | None
    declared_y: float | None
    source_x: float
    source_y: float
    error_m: float | None
    time_s: float | None
    path_m: float
    mcap: str | None


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port the OS just handed out on 127.0.0.1 (free now; the caller binds it right away)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def loopback_config(config: Config, mavlink_port: int, zenoh_port: int, recorder_dir: str | None) -> Config:
    """The scenario's service configuration, wired to loopback only."""
    updates: dict[str, Any] = {
        "mavlink": config.mavlink.model_copy(update={"url": f"udpin:127.0.0.1:{mavlink_port}"}),
        "zenoh": config.zenoh.model_copy(
            update={
                "mode": "peer",
                "listen": [f"tcp/127.0.0.1:{zenoh_port}"],
                "connect": [],
                "multicast_scouting": False,
            }
        ),
    }
    if recorder_dir is not None:
        updates["recorder"] = config.recorder.model_copy(update={"dir": recorder_dir})
    return config.model_copy(update=updates)


def within_one_cell(scenario: Scenario, declared: tuple[float, float], source: tuple[float, float]) -> bool:
    """Declared cell and source cell are the same or neighbours (Chebyshev distance <= 1)."""
    grid = scenario.grid
    a = grid.row_col(grid.cell_of(*declared))
    b = grid.row_col(grid.cell_of(*source))
    return max(abs(a[0] - b[0]), abs(a[1] - b[1])) <= 1


class ZenohProbe:
    """A subscriber in another process that timestamps every ``slim`` grid it receives."""

    def __init__(self, endpoint: str, key: str) -> None:
        self._out = tempfile.NamedTemporaryFile(prefix="oslim-probe-", suffix=".jsonl", delete=False)  # noqa: SIM115
        self._out.close()
        self.path = Path(self._out.name)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "service.tools.zenoh_probe", endpoint, key, str(self.path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )

    def wait_ready(self, timeout_s: float = 20.0) -> bool:
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline() if self._wait_readable(timeout_s) else b""
        return line.strip() == b"ready"

    def _wait_readable(self, timeout_s: float) -> bool:
        import select

        assert self._proc.stdout is not None
        ready, _, _ = select.select([self._proc.stdout], [], [], timeout_s)
        return bool(ready)

    def stop(self) -> list[tuple[float, float]]:
        """(grid time_s, wall receive time) of every grid received."""
        self._proc.terminate()
        try:
            self._proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        if self._proc.stdout is not None:
            self._proc.stdout.close()
        rows = []
        for line in self.path.read_text().splitlines():
            with contextlib.suppress(ValueError, KeyError):
                item = json.loads(line)
                rows.append((float(item["time_s"]), float(item["wall"])))
        self.path.unlink(missing_ok=True)
        return rows


@dataclass
class ClosedLoop:
    """A running stub and service pair on loopback (``closed_loop`` yields it)."""

    scenario: Scenario
    config: Config
    world: World
    stub: VehicleStub
    service: Service
    task: asyncio.Task[ServiceStats]
    zenoh_endpoint: str


@contextlib.asynccontextmanager
async def closed_loop(
    scenario: Scenario, seed: int, *, speed: float = 1.0, recorder_dir: str | None = None, pilot: bool = True
) -> AsyncIterator[ClosedLoop]:
    """Start the stub and the service on loopback; with ``pilot`` switch to GUIDED and arm.

    On exit the service is stopped (it stops commanding, flushes and closes) and then the stub.
    """
    world = build_world(scenario, seed)
    mav_port, zenoh_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    config = loopback_config(scenario.config, mav_port, zenoh_port, recorder_dir)
    service = Service(config, clock=Clock(speed))
    service.scene.source = world.plume.source_m  # recorded as /sim/source, drawn by `oslim report`
    stop = asyncio.Event()
    options = StubOptions(url=f"udpout:127.0.0.1:{mav_port}", speed=speed, sensor_name=config.sensor.name)
    async with VehicleStub(world, options) as stub:
        task = asyncio.create_task(service.run(stop), name="service")
        try:
            await asyncio.wait_for(_started(service, task), timeout=30.0)
            if pilot:
                if not stub.pilot_mode(config.mavlink.guided_mode):
                    raise LinkError(
                        f"the stub has no mode {config.mavlink.guided_mode} (mavlink.guided_mode)"
                    )
                stub.pilot_arm(True)
                log.info("pilot: GUIDED and armed; source hidden at (%.1f, %.1f)", *world.plume.source_m)
            yield ClosedLoop(scenario, config, world, stub, service, task, f"tcp/127.0.0.1:{zenoh_port}")
        finally:
            stop.set()
            await task


async def run_mission(
    scenario: Scenario,
    seed: int,
    *,
    speed: float = 1.0,
    max_time_s: float = 600.0,
    recorder_dir: str | None = None,
    probe: bool = True,
    progress_every_s: float = 30.0,
) -> tuple[SimResult, ServiceStats, dict[str, Any]]:
    """Run one mission; returns the result, the service's statistics and performance figures."""
    tick_wall: dict[float, float] = {}
    perf: dict[str, Any] = {}
    zenoh_probe: ZenohProbe | None = None
    async with closed_loop(scenario, seed, speed=speed, recorder_dir=recorder_dir, pilot=False) as loop:
        service, world, stub = loop.service, loop.world, loop.stub
        if probe:
            key = f"{loop.config.zenoh.key_prefix}/{loop.config.vehicle.id}/slim"
            zenoh_probe = ZenohProbe(loop.zenoh_endpoint, key)
            if not await asyncio.to_thread(zenoh_probe.wait_ready):
                log.warning("zenoh probe did not start: no publication latency figures")
        if not stub.pilot_mode(loop.config.mavlink.guided_mode):
            raise LinkError(f"the stub has no mode {loop.config.mavlink.guided_mode} (mavlink.guided_mode)")
        stub.pilot_arm(True)
        log.info("pilot: GUIDED and armed; source hidden at (%.1f, %.1f)", *world.plume.source_m)
        next_report = progress_every_s
        while service.declared is None and not loop.task.done():
            await asyncio.sleep(0.05)
            sim_t = stub.status().time_s
            _note_ticks(service, tick_wall)
            if sim_t >= next_report:
                est = service.mapper.estimate()
                v = world.vehicle
                line = f"t={sim_t:6.0f} s  {service.stats.state:<8} vehicle ({v.x_m:6.1f}, {v.y_m:6.1f})"
                print(f"{line}  estimate ({est.x:6.1f}, {est.y:6.1f}) p={est.probability:.3f}", flush=True)
                next_report += progress_every_s
            if sim_t >= max_time_s:
                log.warning("no declaration after %.0f simulated seconds", sim_t)
                break
    stats = service.stats
    _note_ticks(service, tick_wall)
    source = world.plume.source_m
    if zenoh_probe is not None:
        received = zenoh_probe.stop()
        delays = [(wall - tick_wall[t]) * 1e3 for t, wall in received if t in tick_wall]
        perf["zenoh_grids_received"] = len(received)
        perf["zenoh_delay_ms_median"] = round(float(np.median(delays)), 3) if delays else None
        perf["zenoh_delay_ms_p99"] = round(float(np.percentile(delays, 99)), 3) if delays else None
        perf["zenoh_delay_ms_max"] = round(float(np.max(delays)), 3) if delays else None
    declared = service.declared
    if declared is None:
        result = SimResult(
            False, None, None, source[0], source[1], None, None, round(world.distance_m, 2), stats.mcap
        )
    else:
        error = math.hypot(declared.x - source[0], declared.y - source[1])
        result = SimResult(
            found=within_one_cell(scenario, (declared.x, declared.y), source),
            declared_x=declared.x,
            declared_y=declared.y,
            source_x=source[0],
            source_y=source[1],
            error_m=round(error, 3),
            time_s=round(declared.time_s, 2),
            path_m=round(world.distance_m, 2),
            mcap=stats.mcap,
        )
    perf.update(stats.summary())
    return result, stats, perf


async def _started(service: Service, task: asyncio.Task[ServiceStats]) -> None:
    waiter = asyncio.create_task(service.started.wait())
    await asyncio.wait([waiter, task], return_when=asyncio.FIRST_COMPLETED)
    if task.done():
        waiter.cancel()
        task.result()  # raises what stopped the service
        raise OslimError("the service stopped during start-up")


def _note_ticks(service: Service, tick_wall: dict[float, float]) -> None:
    tick_wall.update(service.tick_wall)


def run(args: argparse.Namespace) -> int:
    live = [f'foxglove.listen="127.0.0.1:{args.foxglove}"'] if args.foxglove is not None else []
    scenario = load_scenario(args.scenario, [*args.set, *live])
    started = time.perf_counter()
    result, _stats, perf = asyncio.run(
        run_mission(
            scenario,
            args.seed,
            speed=args.speed,
            max_time_s=args.max_time,
            recorder_dir=args.recorder_dir,
            probe=not args.no_probe,
        )
    )
    perf["wall_s"] = round(time.perf_counter() - started, 2)
    print("performance: " + json.dumps(perf), file=sys.stderr, flush=True)
    print(json.dumps(asdict(result)), flush=True)
    if args.report is not None and result.mcap is not None:
        from service.tools.report import write_report

        write_report(result.mcap, args.report)
    return 0 if result.found else 1
