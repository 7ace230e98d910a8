import pytest

from service.core.config import Config, PlanningConfig, PlanningMethod, build_config
from service.core.errors import ConfigError
from service.core.grid import Grid
from service.core.planning import PLANNERS, make_planner

G = Grid(0.0, 10.0, 0.0, 10.0, columns=5, rows=5)


def test_every_configurable_method_has_a_planner_and_back() -> None:
    assert set(PLANNERS) == {m.value for m in PlanningMethod}
    for method in PlanningMethod:
        planner = make_planner(G, PlanningConfig(method=method))
        assert planner.name == method.value


def test_default_is_the_obstacle_free_astar() -> None:
    assert make_planner(G, Config().planning).name == "astar"


def test_unknown_method_is_refused_by_the_configuration() -> None:
    with pytest.raises(ConfigError, match=r"planning\.method: .*'astar', 'astar-paper'"):
        build_config({}, ["planning.method=dijkstra"])
    config = build_config({}, ["planning.method=mldp"])
    assert make_planner(G, config.planning).name == "mldp"
