"""service.api: the documented Python API, and the README's example of it run as written."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

import service.api
from service.api import Search, Step, load_config
from service.core.config import Config
from service.core.errors import ConfigError

README = Path(__file__).resolve().parents[2] / "README.md"
SECTION = "## Use the search from your own simulator"


def readme_example() -> str:
    """The first python code block of the README's section on the API."""
    text = README.read_text(encoding="utf-8")
    section = text[text.index(SECTION) :]
    found = re.search(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert found is not None, "no python block in the README section"
    return found.group(1)


def test_the_readme_example_runs_and_finds_the_toy_source(tmp_path: Path) -> None:
    code = readme_example()
    assert len(code.splitlines()) < 30
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    result = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, check=True, cwd=tmp_path, timeout=120
    )
    # the toy source (20, 0) lies in the model cell centred on (20.625, -0.5); 3 m + a 0.8 m half-diagonal
    assert result.stdout.startswith("declared: (20.6, -0.5) ± 3.8 m after "), result.stdout + result.stderr
    # and the README says what it prints
    assert result.stdout.strip() in README.read_text(encoding="utf-8")


def test_the_contract_names_exist() -> None:
    assert {"Search", "load_config"} <= set(service.api.__all__)
    assert {"waypoints", "state", "estimate", "declared", "detected"} <= set(Step.__dataclass_fields__)
    assert {"x", "y", "confidence", "radius_m"} <= set(service.api.Declaration.__dataclass_fields__)


def test_load_config_takes_a_path_or_none_and_overrides(tmp_path: Path) -> None:
    assert load_config(None, ["area.columns=100"]).area.columns == 100
    path = tmp_path / "vehicle.toml"
    path.write_text('[vehicle]\nid = "auv-7"\n', encoding="utf-8")
    config = load_config(path, ["area.rows=10"])
    assert (config.vehicle.id, config.area.rows) == ("auv-7", 10)
    with pytest.raises(ConfigError, match=r"area\.nope"):
        load_config(None, ["area.nope=1"])


def test_no_position_no_step_and_the_gap_is_named() -> None:
    search = Search(Config())
    search.add_flow(0.5, 1.0, 0.0)
    search.add_chemical(0.5, 0.0)
    assert search.tick(1.0) is None
    assert search.gaps == ("position",)
    assert float(search.likelihood.max()) == pytest.approx(1.0 / search.likelihood.size)  # untouched


def test_a_tick_fuses_mean_flow_and_peak_reading_at_the_last_position() -> None:
    search = Search(Config())  # sensor.threshold = 1.0
    for t, x, u, c in [(0.2, 10.0, 1.0, 0.5), (0.6, 11.0, 0.0, 1.5), (0.9, 12.0, 0.5, 0.2)]:
        search.add_position(t, x, 0.0)
        search.add_flow(t, u, 0.25)
        search.add_chemical(t, c)
    step = search.tick(1.0)
    assert step is not None
    obs = step.observation
    assert (obs.time_s, obs.x, obs.y) == (1.0, 12.0, 0.0)
    assert (obs.flow_x, obs.flow_y) == pytest.approx((0.5, 0.25))
    assert step.detected is True  # the peak 1.5 reached the threshold
    assert step.state == "trace"  # the first detection: the plume is found
    assert [type(e).__name__ for e in step.events] == ["PlumeFound"]
    assert step.declared is None
    assert step.waypoints  # toward the estimate
    assert all(isinstance(p, tuple) and len(p) == 2 for p in step.waypoints)
    estimate = search.estimate()
    assert (step.estimate.x, step.estimate.y) == (estimate.x, estimate.y)


def test_the_speed_asked_is_the_cap_never_faster_than_the_cruise() -> None:
    search = Search(Config())  # vehicle.max_speed_mps 2
    assert (search.speed_mps(5.0), search.speed_mps(2.0), search.speed_mps(1.0)) == (2.0, 2.0, 1.0)
    assert Search(load_config(None, ["vehicle.max_speed_mps=0"])).speed_mps(5.0) == 5.0


def test_the_heading_follows_the_track_unless_given() -> None:
    search = Search(Config())
    search.add_position(0.0, 10.0, 0.0)
    search.add_position(0.5, 10.0, 1.0)  # moved north
    assert search.heading_rad == pytest.approx(math.pi / 2)
    search.add_position(0.7, 10.0, 1.01)  # too small a move to say anything
    assert search.heading_rad == pytest.approx(math.pi / 2)
    search.add_position(0.8, 10.0, 1.01, heading_rad=0.0)
    assert search.heading_rad == 0.0


def test_bad_numbers_are_refused() -> None:
    search = Search(Config())
    with pytest.raises(ValueError, match="position"):
        search.add_position(0.0, math.nan, 0.0)
    with pytest.raises(ValueError, match="flow"):
        search.add_flow(0.0, math.inf, 0.0)
