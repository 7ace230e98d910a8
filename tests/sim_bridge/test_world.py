"""The world steps flow, plume, detector and vehicle together in simulated time."""

from __future__ import annotations

import pytest

from sim_bridge.scenarios import build_world, load_scenario


def test_the_vehicle_drives_only_when_allowed() -> None:
    world = build_world(load_scenario("wang-laminar"), seed=0)
    world.target_m = (58.75, 30.0)
    world.run(2.0)
    assert (world.vehicle.x_m, world.vehicle.y_m) == (58.75, 44.0)  # not driving: stays put
    world.driving = True
    world.run(2.0)
    assert world.vehicle.y_m == pytest.approx(40.0)  # 2 m/s south for 2 s
    assert world.time_s == pytest.approx(4.0)


def test_sensor_readings_near_the_source_and_far_from_it() -> None:
    scenario = load_scenario(
        "wang-laminar", ["world.vehicle.start_m=[28.75, 4.0]", "world.detector.detection_probability=1.0"]
    )
    world = build_world(scenario, seed=0)
    world.run(15.0)
    assert world.concentration_at_vehicle() >= 1.0  # 10 m downflow of the source, laminar
    assert world.chem_reading() == world.concentration_at_vehicle()
    assert world.flow_at_vehicle() == (1.0, 0.0)
    far = build_world(load_scenario("wang-laminar"), seed=0)
    far.run(15.0)
    assert far.chem_reading() == 0.0  # the start is well off the plume


def test_a_time_step_must_be_positive() -> None:
    from sim_bridge.world import World

    world = build_world(load_scenario("wang-laminar"), seed=0)
    with pytest.raises(ValueError, match="dt_s"):
        World(
            flow=world.flow,
            plume=world.plume,
            detector=world.detector,
            vehicle=world.vehicle,
            vehicle_params=world.vehicle_params,
            dt_s=0.0,
        )
