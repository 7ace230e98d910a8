"""The declaration's mission side: the check across the flow (its legs and its call-off rule),
the judgement that starts it and declares after it, and the probe at the estimate."""

from collections.abc import Callable

import numpy as np

from service.core.config import DeclarationConfig, PlanningConfig
from service.core.grid import Grid
from service.core.mapping.belief import FloatArray
from service.core.mapping.hmm import HmmMapper
from service.core.mission.declaring import (
    PASS_PROBE_MARGIN_M,
    RESMELL_WAIT_S,
    Check,
    Declaring,
    EstimateProbe,
)
from service.core.mission.events import CrossCheck, SourceDeclared
from service.core.mission.routing import Routing
from service.core.observation import Observation
from service.core.planning.base import PlanContext, VehicleState, Waypoint
from service.core.planning.crossflow import FlowFrame
from service.core.planning.declaration import Declaration
from service.core.planning.safety import clamped_cell

AREA = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20)  # 5 m cells
SOURCE = AREA.cell_of(22.0, 3.0)
SX, SY = AREA.centre(SOURCE)
EAST = FlowFrame(1.0, 0.0)
CONFIG = DeclarationConfig(
    probability=0.8,
    upflow_pass_m=0.0,
    check_width_m=6.0,
    check_upflow_m=3.0,
)
ROUTING = Routing.of(AREA, PlanningConfig())


def peaked(cell: int = SOURCE, peak: float = 0.9) -> FloatArray:
    pi = np.full(AREA.shape, (1.0 - peak) / (AREA.size - 1))
    pi.flat[cell] = peak
    return pi


def ctx_at(x: float, y: float, goal: int = SOURCE) -> PlanContext:
    return PlanContext(VehicleState(x, y, 0.0), clamped_cell(AREA, x, y), goal, HmmMapper(AREA))


def odour(t: float, x: float, y: float, detected: bool = True) -> Observation:
    return Observation(t, x, y, 1.0, 0.0, detected)


def found_at_source() -> Declaration:
    return Declaration(0.0, SOURCE, AREA.paper_number(SOURCE), SX, SY, 0.9, 0.9)


# -- the check ----------------------------------------------------------------------------------


def test_the_check_crosses_the_flow_upflow_of_the_cell_and_comes_back_to_its_line() -> None:
    check = Check.across(AREA, found_at_source(), EAST, CONFIG)
    assert check.pattern.vertices == (
        Waypoint(SX - 3.0, SY + 6.0),
        Waypoint(SX - 3.0, SY - 6.0),
        Waypoint(SX - 3.0, SY),
    )
    assert check.cancel_upflow_m == 1.5


def test_the_check_flies_the_side_nearer_the_vehicle_first() -> None:
    check = Check.across(AREA, found_at_source(), EAST, CONFIG, start=(SX, SY - 1.0))
    assert check.pattern.vertices == (
        Waypoint(SX - 3.0, SY - 6.0),
        Waypoint(SX - 3.0, SY + 6.0),
        Waypoint(SX - 3.0, SY),
    )
    left = Check.across(AREA, found_at_source(), EAST, CONFIG, start=(SX, SY + 1.0))
    assert left.pattern.vertices[0] == Waypoint(SX - 3.0, SY + 6.0)


def test_a_check_whose_line_lies_in_an_obstacle_crosses_the_flow_just_upflow_of_it() -> None:
    # the estimate (centre x = 22.5) 2.5 m from the downflow face of a wall 11 m deep: 3 m upflow is
    # inside the wall, where a plume crossing it cannot be met, so the check crosses beyond it
    walled = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20, obstacles=((9.0, -10.0, 20.0, 10.0),))
    found = Declaration(0.0, SOURCE, walled.paper_number(SOURCE), SX, SY, 0.9, 0.9)
    check = Check.across(walled, found, EAST, CONFIG)
    (first, second, back) = check.pattern.vertices
    assert first.x == second.x == back.x
    assert 6.5 <= first.x < 9.0  # within a step (half a 5 m cell) of the wall's upflow face
    assert (first.y, second.y, back.y) == (SY + 6.0, SY - 6.0, SY)
    assert check.cancel_upflow_m == 1.5  # odour 1.5 m upflow of the estimate still calls it off


def test_odour_far_enough_upflow_or_another_estimate_calls_the_check_off() -> None:
    check = Check.across(AREA, found_at_source(), EAST, CONFIG)
    assert check.holds(odour(1.0, SX - 1.0, SY), SOURCE)  # odour nearer than 1.5 m upflow
    assert check.holds(odour(1.0, SX + 4.0, SY), SOURCE)  # odour downflow
    assert check.holds(odour(1.0, SX - 3.0, SY, detected=False), SOURCE)  # no odour
    assert not check.holds(odour(1.0, SX - 1.5, SY), SOURCE)  # odour 1.5 m upflow
    assert not check.holds(odour(1.0, SX + 4.0, SY), SOURCE + 1)  # another estimate


def test_once_its_legs_are_flown_the_check_goes_back_just_downflow_of_the_cell() -> None:
    check = Check.across(AREA, found_at_source(), EAST, CONFIG)
    assert check.back == Waypoint(SX + 1.5, SY)  # as far downflow as odour that calls it off is upflow
    assert check.waypoints(ctx_at(SX, SY), ROUTING) == (Waypoint(SX - 3.0, SY + 6.0),)
    assert check.waypoints(ctx_at(SX - 3.0, SY + 6.0), ROUTING) == (Waypoint(SX - 3.0, SY - 6.0),)
    assert check.waypoints(ctx_at(SX - 3.0, SY - 6.0), ROUTING) == (Waypoint(SX - 3.0, SY),)
    assert not check.flown
    assert check.waypoints(ctx_at(SX - 3.0, SY), ROUTING) == (Waypoint(SX + 1.5, SY),)
    assert check.flown
    assert not check.done
    assert check.waypoints(ctx_at(SX + 1.5, SY), ROUTING) == (Waypoint(SX + 1.5, SY),)  # held there


def test_the_way_back_stays_in_the_area() -> None:
    edge = AREA.cell_of(97.0, 3.0)  # centre x = 97.5: 3 m downflow is outside the area
    ex, ey = AREA.centre(edge)
    found = Declaration(0.0, edge, AREA.paper_number(edge), ex, ey, 0.9, 0.9)
    check = Check.across(AREA, found, EAST, CONFIG.model_copy(update={"check_upflow_m": 6.0}))
    assert check.back == Waypoint(ex, ey)


# -- the judgement ------------------------------------------------------------------------------


def test_nothing_is_judged_before_the_rules_are_armed() -> None:
    declaring = Declaring(AREA, CONFIG, None)
    assert declaring.judge(odour(0.0, SX, SY), peaked(), EAST) is None
    assert declaring.check is None


def test_without_a_check_a_rule_that_fires_is_declared_at_once() -> None:
    declaring = Declaring(AREA, CONFIG.model_copy(update={"check_width_m": 0.0}), None)
    declaring.arm(0.0, peaked())
    verdict = declaring.judge(odour(0.0, SX, SY), peaked(), EAST)
    assert isinstance(verdict, SourceDeclared)
    assert verdict.check is CrossCheck.OFF
    assert (verdict.x, verdict.y, verdict.cell) == (SX, SY, AREA.paper_number(SOURCE))


def test_a_rule_that_fires_starts_the_check_and_the_cell_is_declared_once_it_is_flown() -> None:
    declaring = Declaring(AREA, CONFIG, None)
    declaring.arm(0.0, peaked())
    check = declaring.judge(odour(0.0, SX, SY), peaked(), EAST)
    assert isinstance(check, Check)
    assert declaring.check is check
    assert declaring.judge(odour(1.0, SX, SY, detected=False), peaked(), EAST) is None  # goes on
    check.done = True
    verdict = declaring.judge(odour(2.0, SX - 3.0, SY - 6.0, detected=False), peaked(peak=0.85), EAST)
    assert isinstance(verdict, SourceDeclared)
    assert verdict.check is CrossCheck.FLOWN
    assert (verdict.time_s, verdict.x, verdict.y, verdict.probability) == (2.0, SX, SY, 0.85)


def flown(declaring: Declaring, t: float) -> Check:
    """Fire the rule at the source and fly its check's legs with no odour (by tick ``t``)."""
    check = declaring.judge(odour(t, SX, SY), peaked(), EAST)
    assert isinstance(check, Check)
    for x, y in ((SX - 3.0, SY + 6.0), (SX - 3.0, SY - 6.0), (SX - 3.0, SY)):
        check.waypoints(ctx_at(x, y), ROUTING)
    assert check.flown
    return check


def test_the_cell_is_declared_when_odour_comes_back_to_it_after_the_pass() -> None:
    declaring = Declaring(AREA, CONFIG.model_copy(update={"radius_m": 6.0}), None)  # 5 m cells
    declaring.arm(0.0, peaked())
    check = flown(declaring, 0.0)
    declaring.recheck(odour(1.0, SX - 1.0, SY, detected=False), peaked())
    assert declaring.judge(odour(1.0, SX - 1.0, SY, detected=False), peaked(), EAST) is None
    declaring.recheck(odour(2.0, SX + 7.0, SY), peaked())  # odour, but 7 m from the cell's centre
    assert not check.done
    # the misses on the way back move the greatest cell to a neighbour within radius_m: it goes on
    declaring.recheck(odour(3.0, SX, SY, detected=False), peaked(SOURCE + 1))
    assert declaring.check is check
    declaring.recheck(odour(4.0, SX + 1.5, SY), peaked())
    assert check.done
    verdict = declaring.judge(odour(4.0, SX + 1.5, SY), peaked(), EAST)
    assert isinstance(verdict, SourceDeclared)
    assert verdict.check is CrossCheck.FLOWN


def test_no_odour_back_at_the_cell_calls_the_check_off() -> None:
    declaring = Declaring(AREA, CONFIG, None)
    declaring.arm(0.0, peaked())
    flown(declaring, 0.0)
    declaring.recheck(odour(1.0, SX + 1.5, SY, detected=False), peaked())  # the wait starts
    declaring.recheck(odour(1.0 + RESMELL_WAIT_S, SX + 1.5, SY, detected=False), peaked())
    assert declaring.check is not None
    declaring.recheck(odour(2.0 + RESMELL_WAIT_S, SX + 1.5, SY, detected=False), peaked())
    assert declaring.check is None


def flown_clean(declaring: Declaring, t: float) -> SourceDeclared | Check | None:
    """Fire the rule at the source, fly its check with no odour, and judge the tick after."""
    check = declaring.judge(odour(t, SX, SY), peaked(), EAST)
    assert isinstance(check, Check)
    check.done = True
    return declaring.judge(odour(t + 1.0, SX - 3.0, SY - 6.0, detected=False), peaked(), EAST)


def test_after_a_pass_called_off_by_odour_upflow_one_clean_pass_declares_the_cell() -> None:
    # a call-off is not remembered: the odour back at the cell that a clean pass needs is what a
    # false end lacks (docs/search-steps.md, step 39)
    declaring = Declaring(AREA, CONFIG, None)
    declaring.arm(0.0, peaked())
    assert isinstance(declaring.judge(odour(0.0, SX, SY), peaked(), EAST), Check)
    declaring.recheck(odour(1.0, SX - 2.0, SY + 1.0), peaked())  # odour 2 m upflow
    assert declaring.check is None
    verdict = flown_clean(declaring, 2.0)
    assert isinstance(verdict, SourceDeclared)
    assert verdict.check is CrossCheck.FLOWN


def test_recheck_calls_the_check_off_when_the_estimate_moves() -> None:
    declaring = Declaring(AREA, CONFIG, None)
    declaring.arm(0.0, peaked())
    assert isinstance(declaring.judge(odour(0.0, SX, SY), peaked(), EAST), Check)
    declaring.recheck(odour(1.0, SX, SY, detected=False), peaked())
    assert declaring.check is not None
    declaring.recheck(odour(2.0, SX, SY, detected=False), peaked(SOURCE + 1))
    assert declaring.check is None


def test_the_check_legs_go_before_the_probe() -> None:
    declaring = Declaring(AREA, CONFIG, None)
    declaring.arm(0.0, peaked())
    declaring.judge(odour(0.0, SX, SY), peaked(), EAST)
    assert declaring.waypoints(ctx_at(SX, SY), ROUTING, EAST) == (Waypoint(SX - 3.0, SY + 6.0),)


# -- the probe at the estimate ------------------------------------------------------------------


class SplitMapper(HmmMapper):
    """A map split between two cells, and odour that reaches a source's own cell and every cell
    downflow (east) of it in its row, detected half the time."""

    def __init__(self, cells: tuple[int, int]) -> None:
        super().__init__(AREA)
        self._pi = np.zeros(AREA.shape)
        for cell in cells:
            self._pi.flat[cell] = 0.5

    def odour_kernel(self) -> FloatArray:
        n, m = AREA.shape
        kernel = np.zeros((2 * n - 1, 2 * m - 1))
        kernel[n - 1, :m] = 0.5  # source - vehicle: the same row, zero or more columns west
        return kernel


def new_probe(upflow_pass_m: float = 0.0) -> EstimateProbe:
    return EstimateProbe(AREA, upflow_pass_m, CONFIG.visit_radius_m, CONFIG.check_width_m)


def probe_cell(mapper: SplitMapper) -> int | None:
    ctx = PlanContext(VehicleState(SX, SY, 0.0), SOURCE, SOURCE, mapper)
    waypoints = new_probe().waypoints(ctx, ROUTING, EAST, passed_upflow=False)
    return None if waypoints is None else AREA.cell_of(waypoints[-1].x, waypoints[-1].y)


def test_at_the_estimate_the_probe_looks_where_the_rivals_disagree() -> None:
    # the rival two cells downflow: only just downflow of the estimate does odour tell them apart
    assert probe_cell(SplitMapper((SOURCE, SOURCE + 2))) == SOURCE + 1
    # the rival two cells upflow: the cells from it to the estimate smell it and not the estimate
    assert probe_cell(SplitMapper((SOURCE - 2, SOURCE))) in (SOURCE - 2, SOURCE - 1)


def test_near_the_estimate_the_probe_goes_on_without_coming_back_to_its_cell() -> None:
    # 1 m cells: 2 m from the estimate's centre (within the 3 m where the rule may fire) the vehicle
    # probes from where it is; 4 m away it is the planner's turn
    fine = Grid(0.0, 20.0, 0.0, 20.0, columns=20, rows=20)
    estimate = fine.cell_of(10.5, 10.5)
    mapper = HmmMapper(fine)
    mapper._pi = np.zeros(fine.shape)
    mapper._pi.flat[estimate] = 0.5
    mapper._pi.flat[estimate + 3] = 0.5  # the rival 3 m downflow
    probe = EstimateProbe(fine, upflow_pass_m=0.0, near_m=3.0, across_m=CONFIG.check_width_m)
    routing = Routing.of(fine, PlanningConfig())

    def probe_from(x: float) -> tuple[Waypoint, ...] | None:
        ctx = PlanContext(VehicleState(x, 10.5, 0.0), fine.cell_of(x, 10.5), estimate, mapper)
        return probe.waypoints(ctx, routing, EAST, passed_upflow=True)

    assert probe_from(12.5) is not None
    assert probe_from(14.5) is None


def test_away_from_the_estimate_or_without_a_flow_there_is_no_probe() -> None:
    probe = new_probe()
    assert probe.waypoints(ctx_at(SX + 20.0, SY), ROUTING, EAST, passed_upflow=False) is None
    assert probe.waypoints(ctx_at(SX, SY), ROUTING, None, passed_upflow=False) is None


def test_the_pass_probe_flies_just_beyond_the_upflow_pass_until_it_is_made() -> None:
    probe = new_probe(upflow_pass_m=2.0)
    target = Waypoint(SX - 2.0 - PASS_PROBE_MARGIN_M, SY)
    assert probe.waypoints(ctx_at(SX, SY), ROUTING, EAST, passed_upflow=False) == (target,)
    assert probe.waypoints(ctx_at(SX - 1.0, SY), ROUTING, EAST, passed_upflow=False) == (target,)
    assert probe.pass_target == (SOURCE, target)
    probe.waypoints(ctx_at(SX - 1.0, SY), ROUTING, EAST, passed_upflow=True)
    assert probe.pass_target is None


def test_no_probe_without_a_flow() -> None:
    probe = new_probe(upflow_pass_m=2.0)
    assert probe.waypoints(ctx_at(SX, SY), ROUTING, None, passed_upflow=False) is None


def test_the_endurance_s_declaration_needs_the_upflow_pass_no_odour_upflow_and_the_mass() -> None:
    config = CONFIG.model_copy(update={"upflow_pass_m": 2.0})

    def passed(admit: Callable[[int], bool] | None = None, pi: FloatArray | None = None) -> Declaring:
        """Armed at the source by odour there, then the upflow pass made 2 m upflow of it, dry."""
        declaring = Declaring(AREA, config, admit)
        pi = peaked() if pi is None else pi
        declaring.arm(0.0, pi)
        declaring.judge(odour(0.0, SX, SY), pi, EAST)
        declaring.judge(odour(1.0, SX - 2.0, SY, detected=False), pi, EAST)
        return declaring

    unpassed = Declaring(AREA, config, None)
    unpassed.arm(0.0, peaked())
    unpassed.judge(odour(0.0, SX, SY), peaked(), EAST)
    assert unpassed.final(9.0, peaked()) is None
    named = passed().final(9.0, peaked())
    assert isinstance(named, SourceDeclared)
    assert (named.check, named.time_s, named.x, named.y, named.mass) == (
        CrossCheck.ENDURANCE,
        9.0,
        SX,
        SY,
        0.9,
    )
    unsure = peaked(peak=0.79)  # below final_probability (0.8)
    assert passed(pi=unsure).final(9.0, unsure) is None
    assert passed(admit=lambda cell: cell != SOURCE).final(9.0, peaked()) is None
    smelt = passed()
    smelt.judge(odour(2.0, SX - 1.5, SY + 2.0), peaked(), EAST)  # 1.5 m upflow, 2 m across
    assert smelt.final(9.0, peaked()) is None
    beside = passed()
    beside.judge(odour(2.0, SX - 1.5, SY + 4.0), peaked(), EAST)  # 4 m across: beside, not upflow
    assert isinstance(beside.final(9.0, peaked()), SourceDeclared)
