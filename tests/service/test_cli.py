"""The command line: one parser module, and `oslim serve` loads neither the simulator nor the tools."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from service.cli import COMMANDS, build_parser, chosen_command

# prints the modules loaded after the given code ran, as JSON
PROBE = """
import json, sys
{code}
print(json.dumps(sorted(sys.modules)))
"""


def loaded_after(code: str) -> list[str]:
    """Modules in a fresh interpreter's sys.modules after ``code`` (a clean process: this one has
    imported everything the other tests use)."""
    result = subprocess.run(
        [sys.executable, "-c", PROBE.format(code=code)], capture_output=True, text=True, check=True
    )
    modules: list[str] = json.loads(result.stdout.splitlines()[-1])
    return modules


def outside_serve(modules: list[str]) -> list[str]:
    return [m for m in modules if m.split(".")[0] == "sim_bridge" or m.startswith("service.tools")]


def test_serve_help_loads_no_simulator_module() -> None:
    code = """
import contextlib, io
from service.cli import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
    main(["serve", "--help"])
"""
    assert outside_serve(loaded_after(code)) == []


def test_what_serve_runs_loads_no_simulator_module() -> None:
    code = "import service.cli, service.app.service, service.api"
    modules = loaded_after(code)
    assert "service.app.service" in modules
    assert "service.edges.mavlink_link" in modules
    assert outside_serve(modules) == []


def test_the_other_commands_do_load_what_they_need() -> None:
    """The probe above can see sim_bridge when it is loaded: building the stub's parser loads it."""
    code = "from service.cli import build_parser; build_parser('stub')"
    assert "sim_bridge.stub" in loaded_after(code)


def test_every_command_is_listed_and_only_the_chosen_one_is_built() -> None:
    help_text = build_parser("serve").format_help()
    for name in COMMANDS:
        assert name in help_text
    assert build_parser("serve").parse_args(["serve", "--set", "a.b=1"]).set == ["a.b=1"]
    with pytest.raises(SystemExit):  # the sim's options are not built for serve
        build_parser("serve").parse_args(["sim", "--seed", "3"])


@pytest.mark.parametrize(
    ("argv", "command"),
    [(["serve"], "serve"), (["-v", "bench", "search"], "bench"), (["--help"], None), ([], None)],
)
def test_chosen_command(argv: list[str], command: str | None) -> None:
    assert chosen_command(argv) == command
