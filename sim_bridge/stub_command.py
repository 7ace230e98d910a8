"""``oslim stub``: the MAVLink vehicle stub alone, in a named scenario's world."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
from typing import Any

from service.edges.signing import load_signing_key
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.stub import DEFAULT_RATES_HZ, Stream, StubOptions, VehicleStub

log = logging.getLogger(__name__)

_STATUS_PERIOD_S = 10.0


def options_from_args(args: argparse.Namespace, sensor_name: str, kind: Any) -> StubOptions:
    rates = dict(DEFAULT_RATES_HZ)
    if args.no_wind:
        rates[Stream.WIND] = 0.0
    if args.no_wind_cov:
        rates[Stream.WIND_COV] = 0.0
    if args.chem_det:
        rates[Stream.NAMED_VALUE_INT] = 1.0
    return StubOptions(
        url=args.url,
        speed=args.speed,
        kind=kind,
        system_id=args.system_id,
        rates_hz=rates,
        sensor_name=sensor_name,
        signing_key=load_signing_key(args.signing_key_file, "--signing-key-file")
        if args.signing_key_file
        else None,
    )


async def serve(stub: VehicleStub, duration_s: float | None) -> None:
    """Run an already-built stub until SIGINT/SIGTERM or ``duration_s`` simulated seconds."""
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    with contextlib.suppress(NotImplementedError, RuntimeError):
        loop.add_signal_handler(signal.SIGTERM, stop.set)
    try:
        async with stub:
            waiters: list[asyncio.Task[Any]] = [asyncio.create_task(stop.wait())]
            if duration_s is not None:
                end_s = stub.world.time_s + duration_s
                waiters.append(asyncio.create_task(stub.wait_for(lambda s: s.time_s >= end_s, None)))
            try:
                while True:
                    done, _ = await asyncio.wait(
                        waiters, timeout=_STATUS_PERIOD_S, return_when=asyncio.FIRST_COMPLETED
                    )
                    if done:
                        break
                    _log_status(stub)
            finally:
                for task in waiters:
                    task.cancel()
                await asyncio.gather(*waiters, return_exceptions=True)
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.remove_signal_handler(signal.SIGTERM)


def _log_status(stub: VehicleStub) -> None:
    s = stub.status()
    log.info(
        "t=%.1f s %s %s at (%.1f, %.1f) target %s; %s",
        s.time_s,
        s.mode_name,
        "armed" if s.armed else "disarmed",
        s.x_m,
        s.y_m,
        s.target_m,
        s.counters,
    )


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, args.overrides)
    world = build_world(scenario, args.seed)
    options = options_from_args(args, scenario.config.sensor.name, scenario.world.vehicle.kind)
    log.info(
        "scenario %s: source at (%.1f, %.1f), vehicle at (%.1f, %.1f)",
        scenario.name,
        *world.plume.source_m,
        world.vehicle.x_m,
        world.vehicle.y_m,
    )
    asyncio.run(serve(VehicleStub(world, options), args.duration_s))
    return 0
