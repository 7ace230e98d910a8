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
from sim_bridge.scenarios import add_world_arguments, build_world, load_scenario
from sim_bridge.sitl_bridge import MAV_COMP_ID_PERIPHERAL, BridgeOptions, SitlBridge

log = logging.getLogger(__name__)

_STATUS_PERIOD_S = 10.0


def add_parser(subparsers: Any, name: str) -> argparse.ArgumentParser:
    defaults = BridgeOptions()
    parser: argparse.ArgumentParser = subparsers.add_parser(
        name,
        help="relay MAVLink between ArduPilot SITL and the service, injecting a scenario's plume",
        description="Forwards every MAVLink frame between SITL and the service unchanged (like "
        "mavlink-router), runs the scenario's flow and puff plume at the vehicle's LOCAL_POSITION_NED "
        "and injects NAMED_VALUE_FLOAT CHEM and WIND toward the service as a peripheral of the vehicle.",
    )
    parser.add_argument(
        "--sitl",
        default=defaults.sitl_url,
        help="SITL's side: tcp:, tcpin:, udpin:, udpout: (default: %(default)s)",
    )
    parser.add_argument(
        "--to",
        default=defaults.to_url,
        help="the service's side; udpout reaches the service's default udpin:0.0.0.0:14550 "
        "(default: %(default)s)",
    )
    add_world_arguments(parser, "wang-laminar")
    parser.add_argument(
        "--component-id",
        type=int,
        default=MAV_COMP_ID_PERIPHERAL,
        help="component id of the injected messages (default: %(default)s, MAV_COMP_ID_PERIPHERAL)",
    )
    parser.add_argument(
        "--chem-rate", type=float, default=defaults.chem_rate_hz, help="CHEM Hz (default: %(default)s)"
    )
    parser.add_argument(
        "--wind-rate",
        type=float,
        default=defaults.wind_rate_hz,
        help="WIND Hz; 0 leaves the flow to SITL's windvane (default: %(default)s)",
    )
    parser.add_argument(
        "--position-rate",
        type=float,
        default=defaults.position_rate_hz,
        help="LOCAL_POSITION_NED Hz asked of SITL; 0 = do not ask (default: %(default)s)",
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="simulated seconds per wall second: SITL's --speedup (default: 1)",
    )
    parser.add_argument(
        "--write-config",
        metavar="FILE",
        default=None,
        help="write the scenario's service configuration (for oslim serve --config FILE) and exit",
    )
    parser.add_argument(
        "--service-url",
        default="udpin:0.0.0.0:14550",
        help="mavlink.url written by --write-config (default: %(default)s)",
    )
    return parser


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
