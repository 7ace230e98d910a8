"""The sweep owns its zigzag: laid from the vehicle, turned back at the edge, laid anew when the
flow turns or when asked to."""

import math

from service.core.config import PlanningConfig
from service.core.grid import Grid
from service.core.mapping.hmm import HmmMapper
from service.core.mission.routing import Routing
from service.core.mission.sweep import SWEEP_REDRAW_RAD, Sweep
from service.core.planning.base import PlanContext, VehicleState
from service.core.planning.crossflow import FlowFrame
from service.core.planning.safety import clamped_cell
from service.core.planning.zigzag import zigzag_vertices

AREA = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20)  # 5 m cells
PLANNING = PlanningConfig(zigzag_spacing_m=10.0, zigzag_near_edge_spacings=0.0)
EAST = FlowFrame(1.0, 0.0)


def ctx_at(x: float, y: float) -> PlanContext:
    return PlanContext(VehicleState(x, y, 0.0), clamped_cell(AREA, x, y), 0, HmmMapper(AREA))


def turned(angle_rad: float) -> FlowFrame:
    return FlowFrame(math.cos(angle_rad), math.sin(angle_rad))


def test_the_first_sweep_is_laid_from_the_vehicle_upflow_first() -> None:
    sweep = Sweep(AREA, PLANNING)
    waypoints = sweep.waypoints(ctx_at(52.5, 2.5), EAST, Routing.of(AREA, PLANNING))
    expected = zigzag_vertices(AREA, 52.5, 2.5, EAST, 10.0, upflow=True)
    assert sweep.pattern.vertices == expected
    assert waypoints == (expected[0],)
    assert sweep.frame == EAST


def test_no_flow_yet_sweeps_as_if_the_flow_went_east() -> None:
    sweep = Sweep(AREA, PLANNING)
    sweep.waypoints(ctx_at(52.5, 2.5), None, Routing.of(AREA, PLANNING))
    assert sweep.pattern.vertices == zigzag_vertices(AREA, 52.5, 2.5, EAST, 10.0, upflow=True)


def test_a_small_turn_of_the_flow_keeps_the_sweep_a_large_one_lays_it_anew() -> None:
    routing = Routing.of(AREA, PLANNING)
    sweep = Sweep(AREA, PLANNING)
    sweep.waypoints(ctx_at(52.5, 2.5), EAST, routing)
    laid = sweep.pattern
    sweep.waypoints(ctx_at(52.5, 2.5), turned(SWEEP_REDRAW_RAD - 0.05), routing)
    assert sweep.pattern is laid
    new_flow = turned(SWEEP_REDRAW_RAD + 0.05)
    sweep.waypoints(ctx_at(52.5, 2.5), new_flow, routing)
    assert sweep.pattern.vertices == zigzag_vertices(AREA, 52.5, 2.5, new_flow, 10.0, upflow=True)
    assert sweep.frame == new_flow


def test_at_the_end_of_the_sweep_it_sweeps_back_the_other_way() -> None:
    routing = Routing.of(AREA, PLANNING)
    sweep = Sweep(AREA, PLANNING)
    sweep.waypoints(ctx_at(52.5, 2.5), EAST, routing)
    sweep.pattern.index = len(sweep.pattern.vertices)  # every turning point reached
    waypoints = sweep.waypoints(ctx_at(7.5, 2.5), EAST, routing)
    expected = zigzag_vertices(AREA, 7.5, 2.5, EAST, 10.0, upflow=False)
    assert not sweep.upflow
    assert sweep.pattern.vertices == expected
    assert waypoints == (expected[0],)


def test_restart_lays_a_new_sweep_from_where_the_vehicle_is() -> None:
    routing = Routing.of(AREA, PLANNING)
    sweep = Sweep(AREA, PLANNING)
    sweep.waypoints(ctx_at(52.5, 2.5), EAST, routing)
    sweep.restart()
    sweep.waypoints(ctx_at(22.5, -22.5), EAST, routing)
    assert sweep.pattern.vertices == zigzag_vertices(AREA, 22.5, -22.5, EAST, 10.0, upflow=True)


def test_near_the_upflow_edge_a_new_sweep_goes_downflow_first() -> None:
    planning = PLANNING.model_copy(update={"zigzag_near_edge_spacings": 1.5})
    sweep = Sweep(AREA, planning)
    sweep.waypoints(ctx_at(7.5, 2.5), EAST, Routing.of(AREA, planning))  # 7.5 m from the West edge
    assert not sweep.upflow
    assert sweep.pattern.vertices == zigzag_vertices(AREA, 7.5, 2.5, EAST, 10.0, upflow=False)
