"""The cast owns its legs around the last detection."""

from service.core.config import PlanningConfig
from service.core.grid import Grid
from service.core.mapping.hmm import HmmMapper
from service.core.mission.cast import Cast
from service.core.mission.routing import Routing
from service.core.planning.base import PlanContext, VehicleState
from service.core.planning.cast import cast_vertices
from service.core.planning.crossflow import FlowFrame
from service.core.planning.safety import clamped_cell

AREA = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20)  # 5 m cells
PLANNING = PlanningConfig(cast_width_m=10.0, cast_legs=3)
EAST = FlowFrame(1.0, 0.0)


def cast() -> Cast:
    return Cast(AREA, PLANNING)


def test_the_cast_is_laid_across_the_flow_through_the_last_detection() -> None:
    c = cast()
    c.lay((42.5, 2.5), EAST)
    assert c.pattern.vertices == cast_vertices(AREA, 42.5, 2.5, EAST, 10.0, 3)
    ctx = PlanContext(VehicleState(42.5, 2.5, 0.0), clamped_cell(AREA, 42.5, 2.5), 0, HmmMapper(AREA))
    assert c.waypoints(ctx, Routing.of(AREA, PLANNING)) == (c.pattern.vertices[0],)


def test_no_cast_without_a_detection_or_a_flow() -> None:
    c = cast()
    c.lay((42.5, 2.5), EAST)
    c.lay(None, EAST)
    assert c.pattern.vertices == ()
    c.lay((42.5, 2.5), None)
    assert c.pattern.vertices == ()
