"""``oslim stub``: registered in the CLI, parses its options, runs for a while and stops."""

from __future__ import annotations

import argparse
import threading
from typing import Any

from service.cli import build_parser
from sim_bridge import stub_command
from sim_bridge.stub import Stream, StubOptions


def parse(*argv: str) -> argparse.Namespace:
    return build_parser("stub").parse_args(["stub", *argv])


def test_registered_as_the_stub_subcommand() -> None:
    args = parse()
    assert args.command == "stub"
    assert (args.scenario, args.url) == ("farrell2003", StubOptions.url)


def test_options_follow_the_flags() -> None:
    args = parse("--url", "udpout:127.0.0.1:14551", "--speed", "3", "--no-wind", "--chem-det")
    options = stub_command.options_from_args(args, "GAS", "rover")
    assert (options.url, options.speed, options.sensor_name) == ("udpout:127.0.0.1:14551", 3.0, "GAS")
    assert options.rates_hz[Stream.WIND] == 0.0
    assert options.rates_hz[Stream.WIND_COV] > 0
    assert options.rates_hz[Stream.NAMED_VALUE_INT] > 0


def test_runs_a_scenario_for_a_simulated_duration_and_speaks_to_a_udpin_peer(
    companion_at: Any, udp_port: int
) -> None:
    args = parse(
        "--scenario", "wang-turbulent", "--seed", "3", "--url", f"udpout:127.0.0.1:{udp_port}",
        "--speed", "10", "--duration-s", "5", "--set", "world.vehicle.speed_mps=1.0",
    )  # fmt: skip
    heard: list[Any] = []
    with companion_at(f"udpin:127.0.0.1:{udp_port}") as companion:
        listener = threading.Thread(target=lambda: heard.append(companion.recv("HEARTBEAT", timeout_s=5.0)))
        listener.start()
        assert stub_command.run(args) == 0  # returns after 5 simulated seconds (0.5 s wall)
        listener.join(timeout=5.0)
    assert heard
    assert heard[0].custom_mode == 0
