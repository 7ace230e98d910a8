"""The ``oslim`` command line: one sub-command per module, each with ``add_parser`` and ``run``."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from service.core.errors import OslimError

# sub-command name -> module exposing add_parser(subparsers) and run(args) -> int
COMMANDS: dict[str, str] = {
    "bench": "service.tools.bench.command",
    "serve": "service.app.service",
    "sim": "service.tools.sim",
    "stub": "sim_bridge.stub_command",
    "sitl-bridge": "sim_bridge.sitl_bridge_command",
    "replay": "service.tools.replay",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="oslim", description="Online source likelihood mapping")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in COMMANDS.items():
        importlib.import_module(module).add_parser(sub, name)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        code: int = importlib.import_module(COMMANDS[args.command]).run(args)
    except OslimError as exc:
        print(f"oslim {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())
