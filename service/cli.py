"""The ``oslim`` command line: every sub-command's arguments are declared and parsed here.

This module is the composition root. ``oslim serve`` loads the core, the edges and the
application only. The other commands import their tools (``service.tools``) and, through them or
directly, the simulator (``sim_bridge``) inside their own functions, so the service on a vehicle
never loads the simulator. Some of those commands take defaults from the simulator (scenario
names, the stub's connection string), so only the arguments of the command being run are added
(``build_parser(command)``): ``oslim serve --help`` builds no simulator argument.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from service.core.errors import OslimError


@dataclass(frozen=True)
class Command:
    """One sub-command: its help line, its arguments and what it runs."""

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str | None = None


def _at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer of at least ``minimum``, or a usage error naming the bound."""

    def parse(text: str) -> int:
        value = int(text)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in "invalid integer value"
    return parse


def _finite(*, zero: bool) -> Callable[[str], float]:
    """An argparse type: a finite number above 0, or at least 0 with ``zero`` (a distance), or a
    usage error naming the bound."""
    bound = ">= 0" if zero else "> 0"

    def parse(text: str) -> float:
        value = float(text)
        if not (math.isfinite(value) and (value >= 0.0 if zero else value > 0.0)):
            raise argparse.ArgumentTypeError(f"must be a finite number {bound}, got {text}")
        return value

    parse.__name__ = "number"  # argparse names the type in "invalid number value"
    return parse


def _add_overrides(parser: argparse.ArgumentParser, metavar: str, text: str, dest: str = "set") -> None:
    parser.add_argument("--set", action="append", default=[], dest=dest, metavar=metavar, help=text)


# -- serve --------------------------------------------------------------------------------------


def _serve_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="TOML configuration file (default: config/default.toml)")
    _add_overrides(parser, "SECTION.KEY=VALUE", "override one key (repeatable)")


def _serve(args: argparse.Namespace) -> int:
    import asyncio

    from service.app.service import serve
    from service.core.config import load_config

    config = load_config(args.config, args.set)
    asyncio.run(serve(config))
    return 0


def _preflight_arguments(parser: argparse.ArgumentParser) -> None:
    _serve_arguments(parser)
    parser.add_argument(
        "--seconds", type=_finite(zero=False), default=10.0, help="how long to listen (default 10)"
    )
    parser.add_argument("--json", action="store_true", help="one JSON object instead of the table")


def _preflight(args: argparse.Namespace) -> int:
    from service.app.preflight import as_json, preflight, render
    from service.core.config import load_config

    config = load_config(args.config, args.set)
    checks = preflight(config, args.seconds)
    print(as_json(checks) if args.json else render(checks, config, args.seconds))
    return 1 if any(c.status == "FAIL" for c in checks) else 0


# -- sim, stub, sitl-bridge: the simulated world ------------------------------------------------


def _world_arguments(parser: argparse.ArgumentParser, default_scenario: str) -> None:
    """``--scenario``, ``--seed`` and ``--set``: the world a simulator command runs (``load_scenario``
    with ``args.scenario`` and ``args.overrides``, then ``build_world`` with ``args.seed``)."""
    from sim_bridge.scenarios import available_scenarios

    parser.add_argument(
        "--scenario",
        default=default_scenario,
        help=f"scenario name ({', '.join(available_scenarios())}) or a TOML path (default: %(default)s)",
    )
    parser.add_argument("--seed", type=int, default=None, help="world seed (default: the scenario's)")
    _add_overrides(
        parser,
        "KEY=VALUE",
        "override a scenario key, e.g. world.flow.strength_mps=0.2 (repeatable)",
        dest="overrides",
    )


def _sim_arguments(parser: argparse.ArgumentParser) -> None:
    from sim_bridge.scenarios import available_scenarios

    parser.add_argument(
        "--scenario", default="wang-laminar", help=f"one of {', '.join(available_scenarios())} or a path"
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall second")
    parser.add_argument(
        "--max-time", type=float, default=600.0, help="give up after this many simulated seconds"
    )
    _add_overrides(parser, "SECTION.KEY=VALUE", "override a key")
    parser.add_argument(
        "--recorder-dir", default=None, help="where the run's MCAP goes (default: recorder.dir)"
    )
    parser.add_argument("--no-probe", action="store_true", help="skip the Zenoh subscriber process")
    parser.add_argument("--foxglove", type=int, metavar="PORT", help="live Foxglove view on 127.0.0.1:PORT")
    parser.add_argument("--report", metavar="FILE.png", help="draw the run at the end (oslim report)")


def _sim(args: argparse.Namespace) -> int:
    from service.tools import sim

    return sim.run(args)


def _stub_arguments(parser: argparse.ArgumentParser) -> None:
    from sim_bridge.stub import StubOptions

    _world_arguments(parser, "farrell2003")
    parser.add_argument(
        "--url",
        default=StubOptions.url,
        help="pymavlink connection string; udpout speaks first to a udpin service (default: %(default)s)",
    )
    parser.add_argument(
        "--speed", type=float, default=1.0, help="simulated seconds per wall second (default: %(default)s)"
    )
    parser.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default: %(default)s)")
    parser.add_argument("--no-wind", action="store_true", help="do not stream WIND (ArduPilot's flow)")
    parser.add_argument("--no-wind-cov", action="store_true", help="do not stream WIND_COV (PX4's flow)")
    parser.add_argument("--chem-det", action="store_true", help="also stream NAMED_VALUE_INT detections")
    parser.add_argument(
        "--signing-key-file",
        default=None,
        help="MAVLink 2 signing key (32 bytes or 64 hex digits); sign and verify",
    )
    parser.add_argument(
        "--duration-s",
        type=float,
        default=None,
        help="stop after this many simulated seconds (default: run on)",
    )


def _stub(args: argparse.Namespace) -> int:
    from sim_bridge import stub_command

    return stub_command.run(args)


def _sitl_bridge_arguments(parser: argparse.ArgumentParser) -> None:
    from sim_bridge.sitl_bridge import MAV_COMP_ID_PERIPHERAL, BridgeOptions

    defaults = BridgeOptions()
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
    _world_arguments(parser, "wang-laminar")
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


def _sitl_bridge(args: argparse.Namespace) -> int:
    from sim_bridge import sitl_bridge_command

    return sitl_bridge_command.run(args)


# -- replay ------------------------------------------------------------------------------------


def _replay_arguments(parser: argparse.ArgumentParser) -> None:
    from pathlib import Path

    parser.add_argument("file", type=Path, metavar="FILE.mcap", help="a recording made by oslim serve / sim")
    parser.add_argument("--json", action="store_true", help="print the report as one JSON line")


def _replay(args: argparse.Namespace) -> int:
    from service.tools import replay

    return replay.run(args)


# -- report ------------------------------------------------------------------------------------


def _report_arguments(parser: argparse.ArgumentParser) -> None:
    from pathlib import Path

    parser.add_argument("file", type=Path, metavar="RUN.mcap", help="a recording made by oslim serve / sim")
    parser.add_argument("-o", "--output", type=Path, metavar="FILE.png", help="default: RUN.png")


def _report(args: argparse.Namespace) -> int:
    from service.tools import report

    return report.run(args)


# -- bench -------------------------------------------------------------------------------------


def _bench_arguments(parser: argparse.ArgumentParser) -> None:
    from service.tools.bench import mapping, search

    kinds = parser.add_subparsers(dest="bench", required=True, metavar="BENCH")
    m = kinds.add_parser("mapping", help="time per tick and peak memory of each mapper")
    m.add_argument("--json", action="store_true", help="one JSON object per line")
    m.add_argument("--mapper", action="append", dest="mappers", help="mapper(s) to run (default: all)")
    m.add_argument(
        "--cells", type=int, action="append", choices=sorted(mapping.GRID_SHAPES), help="grid size(s)"
    )
    m.add_argument(
        "--window", type=_at_least(1), default=None,
        help="flow-history window, ticks (default 200, or the configuration's with --config)",
    )  # fmt: skip
    m.add_argument("--ticks", type=_at_least(1), default=None, help="timed ticks per configuration")
    m.add_argument(
        "--config", default=None, metavar="FILE",
        help="time the mappers with this configuration's model ([mapping], [sensor]; e.g. "
        "config/default.toml: what a deployment computes) instead of the papers' models",
    )  # fmt: skip
    _add_overrides(
        m,
        "KEY=VALUE",
        "override a key of that configuration (implies the default configuration)",
        dest="overrides",
    )

    s = kinds.add_parser("search", help="seeded closed-loop missions: success rate and time to the source")
    s.add_argument("--scenario", required=True, help="scenario name (config/scenarios) or TOML path")
    s.add_argument(
        "--mapper", action="append", dest="mappers", help="mapper (repeat, or 'all'; default: the scenario's)"
    )
    s.add_argument(
        "--planner",
        action="append",
        dest="planners",
        help="planner (repeat, or 'all'; default: the scenario's)",
    )
    s.add_argument(
        "--runs", type=_at_least(1), default=20, help="missions per configuration, seeds 0..N-1 (default 20)"
    )
    s.add_argument(
        "--first-seed",
        type=_at_least(0),
        default=0,
        help="start the seeds here: K..K+N-1 (default 0; another set checks a tuned setting)",
    )
    s.add_argument("--jobs", type=int, default=None, help="worker processes (default: the cores)")
    s.add_argument(
        "--max-time",
        type=float,
        default=search.DEFAULT_MAX_TIME_S,
        help="mission time limit, s (default 300)",
    )
    _add_overrides(
        s, "KEY=VALUE", "override a scenario key (e.g. declaration.probability=0.9)", dest="overrides"
    )
    s.add_argument("--json", action="store_true", help="one JSON object per configuration")
    s.add_argument("--report", metavar="DIR", help="also write report.md and PNG pictures of a mission here")
    s.add_argument(
        "--oracle-declaration",
        action="store_true",
        help="a bound, not a result: declarations away from the true source are ignored (a perfect guard); "
        "with --set declaration.* it measures what the guards against wrong declarations cost",
    )

    w = kinds.add_parser(
        "suite", help="every world class of a suite with one service configuration: the worst class counts"
    )
    w.add_argument(
        "--suite", default=None, metavar="DIR", help="directory of class files (default config/suites)"
    )
    w.add_argument("--class", dest="classes", action="append", metavar="NAME",
                   help="run only this class (repeatable; default: every class)")  # fmt: skip
    w.add_argument("--runs", type=_at_least(1), default=20, help="missions per class (default 20)")
    w.add_argument("--first-seed", type=_at_least(0), default=0,
                   help="seeds K..K+N-1 (default 0); choose below 10000, report from 10000 up")  # fmt: skip
    w.add_argument(
        "--config", default=None, metavar="FILE", help="service configuration (default config/default.toml)"
    )
    _add_overrides(
        w,
        "KEY=VALUE",
        "override a service key for every class (e.g. mapping.method=bayes), or a world range of every "
        "class (a stress test, e.g. 'world.flow_sensor.bias_deg=[-15, 15]')",
        dest="overrides",
    )
    w.add_argument("--jobs", type=int, default=None, help="worker processes (default: the cores)")
    w.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the missions on this Dask scheduler (pip install -e '.[cluster]')")  # fmt: skip
    w.add_argument("--json", action="store_true", help="one JSON object per class, then a summary object")
    w.add_argument(
        "--oracle-declaration",
        action="store_true",
        help="a bound, not a result: declarations away from the true source are ignored (a perfect guard); "
        "with --set declaration.* it measures what each guard against wrong declarations costs per class",
    )
    w.add_argument(
        "--arrival-radius",
        type=_finite(zero=True),
        default=0.0,
        metavar="M",
        help="every simulated vehicle stops M m short of its targets, as ArduPilot Rover does within "
        "WP_RADIUS (2 m by default) before 4.3; the search learns M from their stops, as the service does; "
        "default 0: they drive onto them",
    )
    _add_time_scale(
        w,
        "a diagnostic, not a result: every class's time limit times K (with K = 2, the failures "
        "that succeed were slow, the others stuck); default 1: the suite",
    )

    w.add_argument(
        "--missions",
        default=None,
        metavar="FILE",
        help="also write one JSON line per mission here (class, seed, outcome), for oslim bench compare",
    )

    c = kinds.add_parser(
        "compare",
        help="two suite runs (--missions files) mission by mission: a change beyond the seeds' noise?",
    )
    c.add_argument("a", metavar="A", help="missions file of the first run (the baseline)")
    c.add_argument("b", metavar="B", help="missions file of the second run (the change)")
    c.add_argument("--json", action="store_true", help='one JSON object per class, then class "all"')

    r = kinds.add_parser(
        "model", help="the mapper's P(detection) at the true source against the detector, by position"
    )
    _add_class_run_arguments(r, "one JSON object per class and band")
    e = kinds.add_parser(
        "estimate", help="where the map's estimate was while suite missions traced, by how they ended"
    )
    _add_class_run_arguments(e, 'one JSON object per outcome (class "all": the classes together)')

    t = kinds.add_parser(
        "phases",
        help="where suite missions' time goes: to the odour, to the source, to the rule, in the check",
    )
    _add_class_run_arguments(
        t,
        'one JSON object per class, then "all", "rover" and "auv" (the classes with both kinds)',
    )
    _add_time_scale(
        t,
        "a diagnostic: every class's time limit times K, as oslim bench suite --time-scale "
        "(which phase a slow mission finishes with more time); default 1: the suite's limits",
    )

    k = kinds.add_parser(
        "track",
        help="one suite mission tick by tick, in the true source's frame: what a failed mission did",
    )
    k.add_argument("--class", dest="class_name", required=True, metavar="NAME", help="the mission's class")
    k.add_argument("--seed", type=_at_least(0), required=True, help="the mission's seed")
    k.add_argument(
        "--config", default=None, metavar="FILE", help="service configuration (default config/default.toml)"
    )
    _add_overrides(k, "KEY=VALUE", "override a service key (e.g. mapping.sigma_x=0.3)", dest="overrides")
    _add_time_scale(k, "the class's time limit times K, as oslim bench suite --time-scale; default 1")
    k.add_argument(
        "--every",
        type=_finite(zero=True),
        default=5.0,
        metavar="S",
        help="a line each S seconds besides each detection, change of state and the last tick "
        "(default 5; 0: every tick)",
    )
    k.add_argument(
        "--json", action="store_true", help="one JSON object for the mission, then one per tick shown"
    )

    p = kinds.add_parser("plume", help="filament plume model: steps per second at a puff count")
    p.add_argument("--puffs", type=int, default=10_000, help="live puffs at steady state (default 10000)")
    p.add_argument("--json", action="store_true", help="one JSON object")


def _add_time_scale(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--time-scale K``: every class's time limit times K (a diagnostic of suite missions)."""
    parser.add_argument("--time-scale", type=_finite(zero=False), default=1.0, metavar="K", help=help_text)


def _add_class_run_arguments(parser: argparse.ArgumentParser, json_help: str) -> None:
    """The arguments of a diagnostic that runs suite missions class by class."""
    parser.add_argument("--class", dest="classes", action="append", metavar="NAME",
                        help="measure only this class (repeatable; default: every class)")  # fmt: skip
    parser.add_argument("--runs", type=_at_least(1), default=10, help="missions per class (default 10)")
    parser.add_argument("--first-seed", type=_at_least(0), default=0, help="seeds K..K+N-1 (default 0)")
    parser.add_argument(
        "--config", default=None, metavar="FILE", help="service configuration (default config/default.toml)"
    )
    _add_overrides(parser, "KEY=VALUE", "override a service key (e.g. mapping.sigma_x=0.3)", dest="overrides")
    parser.add_argument("--jobs", type=int, default=None, help="worker processes (default: the cores)")
    parser.add_argument("--json", action="store_true", help=json_help)


def _bench(args: argparse.Namespace) -> int:
    from service.tools.bench import command

    return command.run(args)


COMMANDS: dict[str, Command] = {
    "bench": Command("benchmarks (mapping speed and memory, ...)", _bench_arguments, _bench),
    "serve": Command("run the onboard service", _serve_arguments, _serve),
    "preflight": Command(
        "listen to the vehicle as the service would and say what it lacks (commands nothing)",
        _preflight_arguments,
        _preflight,
        description="Open the service's MAVLink connection for a few seconds, send its heartbeat and "
        "stream requests (never a setpoint), and check the autopilot, mavlink.guided_mode, position, "
        "flow and chemical streams, the link, the Zenoh session and recorder.dir. Exit status 1 if a check "
        "fails.",
    ),
    "sim": Command(
        "one closed-loop mission: vehicle stub + plume + service on loopback", _sim_arguments, _sim
    ),
    "stub": Command(
        "run the MAVLink vehicle stub (a simulated ArduPilot vehicle in a scenario's world)",
        _stub_arguments,
        _stub,
        description="A simulated ArduPilot rover (or sub) over MAVLink 2, driving in a scenario's "
        "world: flow, filament plume and chemical detector.",
    ),
    "sitl-bridge": Command(
        "relay MAVLink between ArduPilot SITL and the service, injecting a scenario's plume",
        _sitl_bridge_arguments,
        _sitl_bridge,
        description="Forwards every MAVLink frame between SITL and the service unchanged (like "
        "mavlink-router), runs the scenario's flow and puff plume at the vehicle's LOCAL_POSITION_NED "
        "and injects NAMED_VALUE_FLOAT CHEM and WIND toward the service as a peripheral of the vehicle.",
    ),
    "replay": Command(
        "recompute a recorded run's maps and compare them bit for bit",
        _replay_arguments,
        _replay,
        description="Recompute a recorded run's maps from its recorded configuration and observations "
        "and compare them bit for bit with the recorded maps; exit status 0 only if all match.",
    ),
    "report": Command(
        "draw one picture of a recorded run",
        _report_arguments,
        _report,
        description="Draw a recorded run: the last source likelihood map, the track by mission state, "
        "detections, flow, the declaration and (simulation) the true source, and probability and "
        "entropy over time.",
    ),
}
"""Sub-command name -> its arguments and handler."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``oslim`` parser; with ``command``, only that sub-command gets its arguments (the
    others are listed with their help line), so building it loads only what that command needs."""
    parser = argparse.ArgumentParser(prog="oslim", description="Online source likelihood mapping")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, spec in COMMANDS.items():
        sub_parser = sub.add_parser(name, help=spec.help, description=spec.description)
        if command is None or command == name:
            spec.add_arguments(sub_parser)
    return parser


def chosen_command(argv: Sequence[str]) -> str | None:
    """The sub-command named in ``argv``: the first word that is one (options before it are the
    top-level ``-v`` / ``-h``); None when there is none."""
    return next((word for word in argv if word in COMMANDS), None)


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(chosen_command(words))
    args = parser.parse_args(words)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        code: int = COMMANDS[args.command].run(args)
    except OslimError as exc:
        print(f"oslim {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())
