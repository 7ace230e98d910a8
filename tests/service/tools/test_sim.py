"""``oslim sim``: a whole mission over loopback MAVLink and Zenoh."""

import asyncio
import json
import subprocess
import sys
from pathlib import Path

import pytest

from service.tools.sim import run_mission
from sim_bridge.scenarios import load_scenario

pytestmark = pytest.mark.sim

DEVELOPED = ["world.plume.spin_up_s=300", "world.plume.spin_up_step_s=1.0"]


@pytest.mark.parametrize(
    ("seed", "overrides", "speed"),
    [
        # A plume that has been released for 5 minutes, as the service assumes (the suite's
        # wang-laminar class, found in every held-out mission): over loopback the ticks' timing
        # varies with the machine's load, and with the plume released with the mission (the
        # papers' set-up, 93 % in process) a mission or two in twenty miss the 600 s.
        (12, [*DEVELOPED], 10.0),
        # ArduPilot Rover's default WP_RADIUS: the service learns it from the stub vehicle's stops
        # and leads its setpoints
        (4, [*DEVELOPED, "world.vehicle.arrival_radius_m=2"], 10.0),
    ],
    ids=["drives-onto-targets", "stops-2-m-short"],
)
def test_declares_the_wang_laminar_source(
    tmp_path: Path, seed: int, overrides: list[str], speed: float
) -> None:
    scenario = load_scenario("wang-laminar", overrides)
    result, stats, perf = asyncio.run(
        run_mission(scenario, seed, speed=speed, max_time_s=600.0, recorder_dir=str(tmp_path), probe=False)
    )
    assert result.found, result
    assert result.error_m is not None
    assert result.error_m <= 4.0
    assert stats.unsafe_targets == 0
    assert perf["setpoints"] > 0


def test_cli_prints_one_json_line_and_exit_status(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "service.cli", "sim", "--scenario", "wang-laminar", "--seed", "12",
         "--speed", "20", "--recorder-dir", str(tmp_path), "--report", str(tmp_path / "run.png")],
        capture_output=True, text=True, timeout=240, check=False,
    )  # fmt: skip
    last = proc.stdout.strip().splitlines()[-1]
    result = json.loads(last)
    keys = {
        "found",
        "declared_x",
        "declared_y",
        "source_x",
        "source_y",
        "error_m",
        "time_s",
        "path_m",
        "mcap",
    }
    assert set(result) == keys
    assert proc.returncode == (0 if result["found"] else 1)
    assert "performance:" in proc.stderr
    assert Path(result["mcap"]).exists()
    assert (tmp_path / "run.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # --report drew the run
