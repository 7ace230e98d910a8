"""The autopilot's position error: a Gauss-Markov wander, reported as position and steered on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.core.errors import ConfigError
from sim_bridge.navigation import Navigation, NavigationParams
from sim_bridge.scenarios import build_world, load_scenario


def test_a_perfect_estimate_has_no_error_and_draws_nothing() -> None:
    rng = np.random.default_rng(3)
    navigation = Navigation(NavigationParams(), rng)
    navigation.advance(10.0)
    assert navigation.error_m == (0.0, 0.0)
    assert rng.random() == np.random.default_rng(3).random()


def test_the_error_has_its_spread_and_its_correlation_time() -> None:
    # sigma 1.5 m, 20 s: sampled every 1 s for 20,000 s, the std is 1.5 and the lag-20 correlation e^-1
    navigation = Navigation(NavigationParams(error_m=1.5, error_s=20.0), np.random.default_rng(5))
    east = []
    for _ in range(20_000):
        navigation.advance(1.0)
        east.append(navigation.error_m[0])
    e = np.asarray(east)
    assert e.std() == pytest.approx(1.5, rel=0.08)
    assert np.corrcoef(e[:-20], e[20:])[0, 1] == pytest.approx(math.exp(-1.0), abs=0.08)


def test_the_autopilot_reports_its_belief_and_steers_it_onto_the_target() -> None:
    # an error that hardly changes over the test (10,000 s correlation time)
    overrides = ["world.vehicle.position_error_m=2.0", "world.vehicle.position_error_s=10000"]
    scenario = load_scenario("wang-laminar", overrides)
    world = build_world(scenario, seed=0)
    east, north = world.navigation.error_m
    assert (east, north) != (0.0, 0.0)
    assert world.position_reading() == (world.vehicle.x_m + east, world.vehicle.y_m + north)
    world.driving = True
    world.target_m = world.position_reading()[0], world.position_reading()[1] - 6.0
    world.run(10.0)
    believed = world.position_reading()
    assert math.dist(believed, world.target_m) < 0.2  # the belief, not the truth, reaches the target
    assert math.dist((world.vehicle.x_m, world.vehicle.y_m), world.target_m) > 1.0


@pytest.mark.parametrize(("field", "value"), [("error_m", -1.0), ("error_s", 0.0)])
def test_bad_navigation_parameters_are_refused(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=field):
        NavigationParams(**{field: value})
