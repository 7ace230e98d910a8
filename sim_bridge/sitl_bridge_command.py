"""``oslim sitl-bridge``: relay between ArduPilot SITL and the service, injecting a scenario's plume."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import signal
from pathlib import Path
from typing import Any

from service.core.config import Config
from service.core.errors import ConfigError
from sim_bridge.scenarios import build_world, load_scenario
from sim_bridge.sitl_bridge import BridgeOptions, SitlBridge

log = logging.getLogger(__name__)

_STATUS_PERIOD_S = 10.0


def _toml_value(value: Any, key: str) -> str:
    if isinstance(value, dict):
        raise ConfigError(f"{key}: nested tables cannot be written; edit the file by hand")
    # JSON strings, numbers, booleans and arrays are valid TOML values
    return json.dumps(value)


def config_toml(config: Config, header: str) -> str:
    """The service configuration as TOML that ``oslim serve --config`` reads back unchanged."""
    lines = [f"# {line}" for line in header.splitlines()]
    data = config.model_dump(mode="json")
    for section, table in data.items():
        lines.append(f"\n[{section}]")
        nested = {k: v for k, v in table.items() if isinstance(v, dict)}
        for key, value in table.items():
            if key not in nested and value is not None:  # TOML has no null: None is the default
                lines.append(f"{key} = {_toml_value(value, f'{section}.{key}')}")
        for key, sub in nested.items():
            lines.append(f"\n[{section}.{key}]")
            for name, value in sub.items():
                lines.append(f"{json.dumps(name)} = {_toml_value(value, f'{section}.{key}.{name}')}")
    return "\n".join(lines) + "\n"


async def serve(bridge: SitlBridge) -> None:
    """Run a bridge until SIGINT / SIGTERM; raises LinkError when SITL hangs up."""
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    try:
        async with bridge:
            reporter = asyncio.create_task(_report(bridge))
            try:
                await bridge.serve(stop)
            finally:
                reporter.cancel()
                await asyncio.gather(reporter, return_exceptions=True)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(sig)


async def _report(bridge: SitlBridge) -> None:
    while True:
        await asyncio.sleep(_STATUS_PERIOD_S)
        s = bridge.status()
        where = "unknown" if s.position_m is None else f"({s.position_m[0]:.1f}, {s.position_m[1]:.1f})"
        log.info(
            "t=%.0f s vehicle %s at %s, track %.1f m; CHEM %s (%d sent), WIND %d sent; frames %d from SITL, "
            "%d from the service, %d dropped",
            s.time_s, s.system_id, where, s.distance_m, s.last_chem, s.chem_sent, s.wind_sent,
            s.from_sitl.frames, s.from_service.frames, s.from_sitl.dropped,
        )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, args.overrides)
    if args.write_config is not None:
        config = scenario.config.model_copy(
            update={"mavlink": scenario.config.mavlink.model_copy(update={"url": args.service_url})}
        )
        header = f"Service configuration of scenario {scenario.name} ({scenario.origin}), for ArduPilot SITL."
        Path(args.write_config).write_text(config_toml(config, header), encoding="utf-8")
        print(f"wrote {args.write_config}: oslim serve --config {args.write_config}")
        return 0
    world = build_world(scenario, args.seed)
    options = BridgeOptions(
        sitl_url=args.sitl,
        to_url=args.to,
        component_id=args.component_id,
        sensor_name=scenario.config.sensor.name,
        chem_rate_hz=args.chem_rate,
        wind_rate_hz=args.wind_rate,
        position_rate_hz=args.position_rate,
        speed=args.speed,
    )
    log.info(
        "scenario %s: source at (%.1f, %.1f) in SITL's local frame (x East, y North)",
        scenario.name,
        *world.plume.source_m,
    )
    asyncio.run(serve(SitlBridge(world, options)))
    return 0
