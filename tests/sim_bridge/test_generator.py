"""The world generator: reproducible, every drawn world valid, the classes as they state."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from service.core.errors import ConfigError
from service.core.grid import Grid
from sim_bridge.generator import (
    WorldClass,
    available_classes,
    connected,
    draw_scenario,
    load_class,
)
from sim_bridge.plume_stats import hit_rate
from sim_bridge.scenarios import build_world, place

CLASSES = {path.stem: path for path in available_classes()}
SERVICE_TABLES = ("mapping", "planning", "declaration", "sensor", "mavlink", "zenoh", "recorder", "service")


def test_the_suite_has_the_classes_the_issue_names() -> None:
    wanted = {"steady", "turbulent", "meander", "patchy", "young-plume", "obstacles", "slow-flow",
              "fast-flow", "large-area", "wang-laminar", "wang-turbulent", "farrell2003"}  # fmt: skip
    assert wanted <= set(CLASSES)


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_a_class_file_sets_no_service_setting(name: str) -> None:
    text = CLASSES[name].read_text(encoding="utf-8")
    for table in SERVICE_TABLES:
        assert f"[{table}" not in text
    assert load_class(CLASSES[name]).suite.time_limit_s > 0


def test_a_class_with_a_service_table_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "tuned.toml"
    bad.write_text(
        '[suite]\ndescription = "x"\ntime_limit_s = 300.0\nhit_rate_20m = [0, 1]\n'
        '[planning]\nmethod = "apf"\n'
    )
    with pytest.raises(ConfigError, match="planning: a world class sets only"):
        load_class(bad)


def test_a_bad_range_names_its_key(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[suite]\ndescription = "x"\ntime_limit_s = 300.0\nhit_rate_20m = [0, 1]\n'
        "[world.flow]\nspeed_mps = [2.0, 1.0]\n"
    )
    with pytest.raises(ConfigError, match=r"world\.flow\.speed_mps: .*lo <= hi"):
        load_class(bad)


def test_a_class_takes_world_overrides_only() -> None:
    stressed = load_class(CLASSES["steady"], ["world.flow_sensor.bias_deg=[-15.0, 15.0]"])
    assert stressed.world.flow_sensor.bias_deg == (-15.0, 15.0)
    assert stressed.world.flow == load_class(CLASSES["steady"]).world.flow
    with pytest.raises(
        ConfigError, match=r"mapping\.method=bayes: a class's worlds take world\.KEY=VALUE only"
    ):
        load_class(CLASSES["steady"], ["mapping.method=bayes"])


def test_a_slow_sensor_changes_no_other_draw() -> None:
    # the response time is drawn last: the same seed draws the same world besides it
    plain = draw_scenario(load_class(CLASSES["meander"]), 3).scenario.world
    slow = draw_scenario(
        load_class(CLASSES["meander"], ["world.detector.response_s=[1.0, 2.0]"]), 3
    ).scenario.world
    assert plain.detector.response_s == 0.0
    told = draw_scenario(load_class(CLASSES["meander"], ["world.detector.response_s=2.0"]), 3).scenario.config
    untold = ["world.detector.response_s=2.0", "world.detector.response_told=0"]
    assert told.sensor.response_s == 2.0
    assert draw_scenario(load_class(CLASSES["meander"], untold), 3).scenario.config.sensor.response_s == 0.0
    assert 1.0 <= slow.detector.response_s <= 2.0
    assert slow.model_copy(update={"detector": plain.detector}) == plain
    assert build_world(
        draw_scenario(load_class(CLASSES["meander"], ["world.detector.response_s=1.5"]), 3).scenario, 3
    ).detector.lags


def test_a_position_error_changes_no_other_draw() -> None:
    plain = draw_scenario(load_class(CLASSES["meander"]), 3).scenario.world
    lost = draw_scenario(load_class(CLASSES["meander"], ["world.vehicle.position_error_m=[0.5, 2.0]"]), 3)
    assert plain.vehicle.position_error_m == 0.0
    assert 0.5 <= lost.scenario.world.vehicle.position_error_m <= 2.0
    assert lost.scenario.world.model_copy(update={"vehicle": plain.vehicle}) == plain


def _signature(world_class: WorldClass, seed: int) -> tuple[object, ...]:
    drawn = draw_scenario(world_class, seed)
    world = build_world(drawn.scenario, seed)
    world.run(5.0)
    return (drawn.scenario.world, drawn.scenario.config.area, drawn.time_limit_s, world.plume.puffs().sum())


@pytest.mark.parametrize("name", ["meander", "obstacles", "switching"])
def test_the_same_seed_draws_the_same_world(name: str) -> None:
    world_class = load_class(CLASSES[name])
    assert _signature(world_class, 11) == _signature(world_class, 11)
    assert _signature(world_class, 11) != _signature(world_class, 12)


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_every_drawn_world_is_valid(name: str) -> None:
    world_class = load_class(CLASSES[name])
    geometry = world_class.world.geometry
    for seed in range(25):
        drawn = draw_scenario(world_class, seed)
        scenario = drawn.scenario
        grid = scenario.grid
        source, start = place(scenario, seed).source_m, place(scenario, seed).start_m
        assert grid.contains(*source)
        assert grid.contains(*start)
        assert not grid.in_obstacle(*source)
        assert not grid.in_obstacle(*start)
        assert connected(grid, start, source)
        if geometry.start_m is None:
            assert math.dist(source, start) >= geometry.min_separation_m
        if geometry.source_m is None:
            margin = geometry.source_margin_m
            assert grid.x_min + margin <= source[0] <= grid.x_max - margin
            assert grid.y_min + margin <= source[1] <= grid.y_max - margin
        low, high = geometry.obstacles
        assert low <= len(grid.obstacles) <= high
        world = scenario.world
        flow = world.flow
        speed = math.hypot(*(flow.before_mps if flow.model == "switched" else flow.mean_mps))
        assert (
            world_class.world.flow.speed_mps[0] - 1e-9 <= speed <= world_class.world.flow.speed_mps[1] + 1e-9
        )
        assert drawn.time_limit_s > 0


def test_obstacles_are_drawn_and_can_be_gone_around() -> None:
    world_class = load_class(CLASSES["obstacles"])
    counts = [len(draw_scenario(world_class, seed).scenario.config.area.obstacles) for seed in range(20)]
    assert min(counts) >= 1
    assert max(counts) == 3


def test_connected_sees_a_wall() -> None:
    wall = Grid(0.0, 100.0, -50.0, 50.0, 40, 25, obstacles=((48.0, -60.0, 52.0, 60.0),))
    assert not connected(wall, (10.0, 0.0), (90.0, 0.0))
    gap = Grid(0.0, 100.0, -50.0, 50.0, 40, 25, obstacles=((48.0, -60.0, 52.0, 30.0),))
    assert connected(gap, (10.0, 0.0), (90.0, 0.0))


def test_the_time_limit_scales_with_area_and_speed() -> None:
    large = load_class(CLASSES["large-area"])
    drawn = draw_scenario(large, 3)
    speed = drawn.scenario.world.vehicle.speed_mps
    assert drawn.time_limit_s == pytest.approx(300.0 * 2.0 / speed)
    laminar = draw_scenario(load_class(CLASSES["wang-laminar"]), 3)
    assert laminar.time_limit_s == pytest.approx(300.0)


def test_the_papers_classes_keep_their_scenarios_geometry() -> None:
    drawn = draw_scenario(load_class(CLASSES["wang-laminar"]), 5)
    placement = place(drawn.scenario, 5)
    assert placement.source_m == (18.75, 4.0)
    assert placement.start_m == (58.75, 44.0)
    assert placement.mean_flow_mps == pytest.approx((1.0, 0.0))
    assert drawn.scenario.world.plume.spin_up_s >= 300.0


def test_an_auv_slows_to_turn_and_a_rover_pivots() -> None:
    world_class = load_class(CLASSES["steady"])
    kinds = {}
    for seed in range(20):
        v = draw_scenario(world_class, seed).scenario.world.vehicle
        kinds[v.kind.value] = v
    assert kinds["sub"].slows_to_turn
    assert kinds["sub"].pivot_angle_deg == 180.0
    assert not kinds["rover"].slows_to_turn
    assert kinds["rover"].pivot_angle_deg == 60.0


def test_a_rover_that_cannot_pivot_changes_no_other_draw() -> None:
    plain = load_class(CLASSES["steady"])
    car = load_class(CLASSES["steady"], ["world.vehicle.pivot_angle_deg=180"])
    kinds = set()
    for seed in range(20):
        before = draw_scenario(plain, seed).scenario.world
        after = draw_scenario(car, seed).scenario.world
        kinds.add(after.vehicle.kind.value)
        assert after.vehicle.pivot_angle_deg == 180.0
        assert after.model_copy(update={"vehicle": before.vehicle}) == before
        pivot = before.vehicle.pivot_angle_deg
        assert after.vehicle.model_copy(update={"pivot_angle_deg": pivot}) == before.vehicle
    assert kinds == {"rover", "sub"}


def test_a_user_threshold_scales_the_plume() -> None:
    from service.core.config import load_config

    world_class = load_class(CLASSES["steady"])
    plain = draw_scenario(world_class, 4).scenario.world.plume.puff_mass
    scaled = draw_scenario(world_class, 4, load_config(None, ["sensor.threshold=3.0"])).scenario.world.plume
    assert scaled.puff_mass == pytest.approx(3.0 * plain)


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_each_class_plume_spans_the_hit_rate_it_states(name: str) -> None:
    """The median over six worlds (seeds 100-105, not those the bands were measured on) lies in
    the stated 10th-90th percentile band."""
    world_class = load_class(CLASSES[name])
    low, high = world_class.suite.hit_rate_20m
    rates = [hit_rate(draw_scenario(world_class, seed), seed, duration_s=60.0) for seed in range(100, 106)]
    assert low - 0.05 <= float(np.median(rates)) <= high + 0.05, rates


def test_the_steady_plume_is_nearly_continuous_and_the_patchy_one_is_not() -> None:
    def median_rate(name: str) -> float:
        world_class = load_class(CLASSES[name])
        return float(np.median([hit_rate(draw_scenario(world_class, s), s, 60.0) for s in range(200, 204)]))

    assert median_rate("steady") > 0.9
    assert median_rate("patchy") < 0.45  # its stated band: 0.06-0.39
