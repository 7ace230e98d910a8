"""Scenario files: the papers' worlds, random placements, validation errors that name the key."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from service.core.errors import ConfigError
from sim_bridge.flow import MeanderingFlow, TurbulentFlow, UniformFlow, velocity_at
from sim_bridge.scenarios import available_scenarios, build_world, load_scenario, place


def test_the_four_scenarios_ship_and_load() -> None:
    assert set(available_scenarios()) >= {"farrell2003", "wang-laminar", "wang-turbulent", "random"}
    for name in ("farrell2003", "wang-laminar", "wang-turbulent", "random"):
        scenario = load_scenario(name)
        assert scenario.name == name
        assert (scenario.grid.columns, scenario.grid.rows) == (40, 25)
        world = build_world(scenario)
        world.run(1.0)
        assert world.plume.count > 0


def test_farrell2003_matches_the_paper() -> None:
    scenario = load_scenario("farrell2003")
    grid = scenario.grid
    assert (grid.x_min, grid.x_max, grid.y_min, grid.y_max) == (0.0, 100.0, -50.0, 50.0)
    world = build_world(scenario, seed=1)
    assert world.plume.source_m == (20.0, 0.0)
    assert grid.paper_number(grid.cell_of(20.0, 0.0)) == 488  # the paper's C488
    assert isinstance(world.flow, MeanderingFlow)
    assert world.vehicle_params.speed_mps == 1.0
    starts = {place(scenario, seed).start_m for seed in range(5)}
    assert len(starts) == 5  # a random start, drawn from the seed
    assert place(scenario, 3) == place(scenario, 3)
    assert all(grid.contains(*start) for start in starts)


@pytest.mark.parametrize("name", ["wang-laminar", "wang-turbulent"])
def test_wang_scenarios_match_section_iii(name: str) -> None:
    scenario = load_scenario(name)
    grid = scenario.grid
    assert (grid.cell_width_m, grid.cell_height_m) == (2.5, 4.0)
    world = build_world(scenario)
    start = (world.vehicle.x_m, world.vehicle.y_m)
    source = world.plume.source_m
    # the paper's (i, j) with j counted from the north: k = i + (j - 1) m
    assert grid.paper_number(grid.cell_of(*start)) == 24 + (2 - 1) * 40
    assert grid.paper_number(grid.cell_of(*source)) == 8 + (12 - 1) * 40
    assert start == (58.75, 44.0)
    assert source == (18.75, 4.0)
    (x0, y0, x1, y1), *others = grid.obstacles
    assert not others
    assert (x1 - x0, y1 - y0) == (20.0, 7.5)
    assert x0 - source[0] == 17.5  # to the right (downflow) of the source, 17.5 m away
    assert y0 < source[1] < y1  # across the plume's path
    assert not grid.in_obstacle(*start)
    assert not grid.in_obstacle(*source)
    assert world.vehicle_params.speed_mps == 2.0
    flow_type = UniformFlow if name == "wang-laminar" else TurbulentFlow
    assert isinstance(world.flow, flow_type)
    if name == "wang-laminar":
        assert velocity_at(world.flow, 50.0, 0.0) == (1.0, 0.0)  # 1 m/s, left to right


def test_wang_turbulent_flow_is_noisy_around_1_mps_left_to_right() -> None:
    world = build_world(load_scenario("wang-turbulent"), seed=4)
    samples = []
    for _ in range(600):
        samples.append(velocity_at(world.flow, 50.0, 0.0))
        world.flow.advance(1.0)
    samples_arr = np.array(samples)
    assert samples_arr.mean(axis=0) == pytest.approx([1.0, 0.0], abs=0.08)
    assert samples_arr.std(axis=0) == pytest.approx([0.5, 0.5], rel=0.15)


def test_random_scenario_draws_source_start_and_flow_direction_from_the_seed() -> None:
    scenario = load_scenario("random")
    placements = [place(scenario, seed) for seed in range(20)]
    assert place(scenario, 7) == placements[7]
    assert len({p.source_m for p in placements}) == 20
    assert len({p.start_m for p in placements}) == 20
    directions = [math.atan2(p.mean_flow_mps[1], p.mean_flow_mps[0]) for p in placements]
    assert np.ptp(directions) > math.pi  # directions all around
    grid = scenario.grid
    for p in placements:
        assert math.hypot(*p.mean_flow_mps) == pytest.approx(1.0)
        assert math.dist(p.source_m, p.start_m) >= 30.0
        assert grid.contains(*p.source_m)
        assert grid.contains(*p.start_m)
        centre_offset = (p.source_m[0] - 50.0, p.source_m[1] - 0.0)
        assert (
            centre_offset[0] * p.mean_flow_mps[0] + centre_offset[1] * p.mean_flow_mps[1] <= 0.0
        )  # upflow half
    world = build_world(scenario, seed=7)
    assert world.plume.source_m == placements[7].source_m


def test_overrides_reach_both_parts() -> None:
    scenario = load_scenario(
        "wang-laminar",
        ["world.vehicle.speed_mps=1.5", "area.rows=50", "world.source.position_m=[30.0, 0.0]"],
    )
    assert scenario.world.vehicle.speed_mps == 1.5
    assert scenario.config.area.rows == 50
    assert build_world(scenario).plume.source_m == (30.0, 0.0)


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("world.flow.bogus=1", "world.flow.bogus: unknown key"),
        ("world.plume.release_rate_hz=-1", "world.plume.release_rate_hz"),
        ("world.vehicle.speed_mps='fast'", "world.vehicle.speed_mps"),
        ("world.flow.model='vortex'", "world.flow"),
        ("world.source.cell=[41, 1]", "world.source: cell (41, 1) outside"),
        ("world.vehicle.start_m=[40.0, 4.0]", "world.vehicle: (40.0, 4.0) is inside an obstacle"),
        ("world.source.position_m=[140.0, 0.0]", "world.source: (140.0, 0.0) is outside"),
        ("world.vehicle.kind='sub'", "mavlink.guided_mode"),
        ("area.columns=0", "area.columns"),
        ("world.detector.detection_probability=0", "world.detector.detection_probability"),
    ],
)
def test_errors_name_the_key(override: str, key: str) -> None:
    with pytest.raises(ConfigError, match=key.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        load_scenario("wang-laminar", [override])


def test_unknown_names_and_bad_files_are_reported(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"known: .*farrell2003"):
        load_scenario("nowhere")
    no_world = tmp_path / "no-world.toml"
    no_world.write_text("[area]\ncolumns = 10\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"missing \[world\]"):
        load_scenario(no_world)
    broken = tmp_path / "broken.toml"
    broken.write_text("[world\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_scenario(broken)
    both = tmp_path / "both.toml"
    both.write_text(
        '[world.source]\nposition_m = [1.0, 1.0]\ncell = [1, 1]\n[world.flow]\nmodel = "uniform"\n'
        '[world.vehicle]\nstart_m = "random"\n',
        encoding="utf-8",
    )
    with pytest.raises(ConfigError, match=r"world\.source: .*exactly one of position_m or cell"):
        load_scenario(both)
    with pytest.raises(ConfigError, match="no such scenario file"):
        load_scenario(tmp_path / "absent.toml")
    tuned = tmp_path / "tuned.toml"
    tuned.write_text("[planning]\nlost_after_s = 10.0\n[world]\nseed = 1\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"tuned\.toml: \[planning\]: a scenario sets only"):
        load_scenario(tuned)
    # the search settings still come from the command line
    patient = load_scenario("wang-laminar", ["planning.lost_after_s=12"])
    assert patient.config.planning.lost_after_s == 12.0


def test_spin_up_starts_the_mission_with_a_developed_plume() -> None:
    cold = build_world(load_scenario("farrell2003"), seed=3)
    warm = build_world(load_scenario("farrell2003", ["world.plume.spin_up_s=60"]), seed=3)
    assert cold.plume.count == 0
    assert warm.time_s == 0.0  # the mission clock starts after the spin-up
    puffs = warm.plume.puffs()
    assert len(puffs) > 500
    assert puffs[:, 3].max() == pytest.approx(60.0, abs=0.2)  # the oldest puff is as old as the spin-up
    assert puffs[:, 0].max() > 20.0 + 40.0  # carried some 60 m East at about 1 m/s
    # the same seed places source and vehicle alike
    assert (warm.vehicle.x_m, warm.vehicle.y_m) == (cold.vehicle.x_m, cold.vehicle.y_m)
