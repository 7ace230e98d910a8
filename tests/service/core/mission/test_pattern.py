"""The one rule every pattern (sweep, cast, check) is flown by."""

import itertools

from service.core.config import PlanningConfig
from service.core.grid import Grid
from service.core.mapping.hmm import HmmMapper
from service.core.mission.pattern import Pattern
from service.core.mission.routing import Routing
from service.core.planning.base import PlanContext, VehicleState, Waypoint
from service.core.planning.safety import clamped_cell, segment_clear

OPEN = Grid(0.0, 50.0, 0.0, 50.0, columns=10, rows=10)  # 5 m cells
WALL = Grid(0.0, 50.0, 0.0, 50.0, columns=10, rows=10, obstacles=((20.0, 0.0, 25.0, 40.0),))


def ctx_at(grid: Grid, x: float, y: float) -> PlanContext:
    return PlanContext(VehicleState(x, y, 0.0), clamped_cell(grid, x, y), 0, HmmMapper(grid))


def test_a_clear_leg_is_flown_straight_to_the_next_turning_point() -> None:
    pattern = Pattern((Waypoint(40.0, 12.0), Waypoint(40.0, 42.0)))
    routing = Routing.of(OPEN, PlanningConfig())
    assert pattern.follow(ctx_at(OPEN, 2.5, 2.5), routing) == (Waypoint(40.0, 12.0),)
    assert pattern.index == 0


def test_turning_points_in_the_vehicles_cell_count_as_reached() -> None:
    pattern = Pattern((Waypoint(41.0, 11.0), Waypoint(41.0, 42.0)))
    routing = Routing.of(OPEN, PlanningConfig())
    assert pattern.follow(ctx_at(OPEN, 42.0, 12.0), routing) == (Waypoint(41.0, 42.0),)
    assert pattern.index == 1
    assert pattern.follow(ctx_at(OPEN, 42.0, 42.0), routing) is None
    assert pattern.index == 2


def test_a_leg_across_an_obstacle_is_routed_around_it() -> None:
    pattern = Pattern((Waypoint(42.5, 12.5),))
    waypoints = pattern.follow(ctx_at(WALL, 7.5, 12.5), Routing.of(WALL, PlanningConfig()))
    assert waypoints is not None
    assert len(waypoints) > 1
    track = [(7.5, 12.5), *((w.x, w.y) for w in waypoints)]
    assert all(segment_clear(WALL, a, b) for a, b in itertools.pairwise(track))


def test_an_empty_pattern_is_over() -> None:
    assert Pattern().follow(ctx_at(OPEN, 2.5, 2.5), Routing.of(OPEN, PlanningConfig())) is None


def test_a_turning_point_on_a_cell_boundary_is_reached_from_the_neighbouring_cell() -> None:
    # 40.0 is the boundary between two columns: a vehicle on the point (up to rounding) or stopped
    # just short of it, as an autopilot does within its acceptance radius, is there
    pattern = Pattern((Waypoint(40.0 + 1e-12, 22.5), Waypoint(2.5, 22.5)))
    routing = Routing.of(OPEN, PlanningConfig())
    assert pattern.follow(ctx_at(OPEN, 39.7, 22.5), routing) == (Waypoint(2.5, 22.5),)
    assert pattern.index == 1
    far = Pattern((Waypoint(40.0 + 1e-12, 22.5), Waypoint(2.5, 22.5)))
    assert far.follow(ctx_at(OPEN, 38.5, 22.5), routing) == (Waypoint(40.0 + 1e-12, 22.5),)
