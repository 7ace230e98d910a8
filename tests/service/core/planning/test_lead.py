import math

import pytest

from service.core.grid import Grid
from service.core.planning.base import Waypoint
from service.core.planning.lead import LEAD_MARGIN_M, OVERRUN_M, STALL_S, Lead, lead_point

GRID = Grid(0.0, 20.0, 0.0, 20.0, columns=20, rows=20)
WALLED = Grid(0.0, 20.0, 0.0, 20.0, columns=20, rows=20, obstacles=((9.0, 4.0, 11.0, 8.0),))


def test_the_lead_point_is_the_first_point_of_the_path_the_lead_away() -> None:
    # as the crow flies, not along the path: an autopilot measures its radius so
    plan = (Waypoint(2.0, 5.0), Waypoint(2.0, 9.0))
    assert lead_point(GRID, 1.0, 5.0, plan, 3.0, 0.0) == Waypoint(2.0, 5.0 + math.sqrt(8.0))
    assert lead_point(GRID, 1.0, 5.0, plan, 0.5, 0.0) == Waypoint(1.5, 5.0)


def test_a_path_that_ends_nearer_than_the_lead_is_overrun_along_the_line_of_sight() -> None:
    plan = (Waypoint(6.0, 5.0),)
    assert lead_point(GRID, 5.0, 5.0, plan, 3.0, 2.3) == Waypoint(8.3, 5.0)
    assert lead_point(GRID, 5.0, 4.0, plan, 3.0, 2.0) == Waypoint(6.0 + math.sqrt(2.0), 5.0 + math.sqrt(2.0))
    assert lead_point(GRID, 5.0, 5.0, plan, 3.0, 0.0) == Waypoint(6.0, 5.0)


def test_the_overrun_stays_inside_the_area() -> None:
    # against the eastern edge it turns aside along the edge (30 and 60 degrees end outside)
    assert lead_point(GRID, 17.2, 5.0, (Waypoint(19.2, 5.0),), 9.0, 2.0) == Waypoint(19.2, 7.0)
    # into the north-eastern corner nothing turned fits: half of it straight on
    end = lead_point(GRID, 17.2, 17.2, (Waypoint(19.2, 19.2),), 9.0, 2.0)
    assert end.x == end.y == pytest.approx(19.2 + math.sqrt(0.5))


def test_round_an_obstacle_the_lead_point_is_the_farthest_one_in_sight() -> None:
    # the path turns round the wall's corner (9, 4): a straight leg to a point much past the corner
    # would cut it; the last point of the path before the lead point that the vehicle can see is
    # 9.1 m east (on y = 3.5, the leg from (8.5, 6) passes the corner's x = 9 at y = 4 up to x 9.1)
    plan = (Waypoint(8.5, 3.5), Waypoint(11.5, 3.5), Waypoint(11.5, 6.0))
    far = lead_point(WALLED, 8.5, 6.0, plan, 6.0, 0.0)
    assert far.x == pytest.approx(9.1)
    assert far.y == pytest.approx(3.5)
    assert lead_point(WALLED, 8.5, 6.0, plan, 2.0, 0.0) == Waypoint(8.5, 4.0)  # in sight
    # against the wall with a plan through it: nothing in sight but where it stands
    assert lead_point(WALLED, 8.95, 6.0, (Waypoint(11.5, 6.0),), 2.0, 0.0) == Waypoint(8.95, 6.0)
    # pressed against the wall, where it stands is no safe point: the plan's first point, which
    # the mission made safe (seen over loopback: a rover against the obstacle's face)
    off = (Waypoint(8.5, 6.0), Waypoint(11.5, 6.0))
    assert lead_point(WALLED, 9.0, 6.0, off, 2.0, 0.0) == Waypoint(8.5, 6.0)


def _stand(
    lead: Lead,
    x: float,
    plan: tuple[Waypoint, ...],
    seconds: float,
    *,
    start: float = 100.0,
    hold: bool = False,
) -> Waypoint | None:
    """Ask for setpoints at 2 Hz from ``start`` for ``seconds`` while the vehicle stays at (x, 5)."""
    target = None
    for k in range(int(seconds * 2) + 1):
        target = lead.setpoint(start + 0.5 * k, x, 5.0, plan, hold=hold)
    return target


def test_a_vehicle_that_drives_onto_its_targets_gets_the_first_waypoint() -> None:
    lead = Lead(GRID)
    plan = (Waypoint(6.5, 5.0), Waypoint(7.5, 5.0))
    assert lead.setpoint(0.0, 5.0, 5.0, plan) == Waypoint(6.5, 5.0)
    assert lead.setpoint(0.0, 5.0, 5.0, ()) is None
    assert _stand(lead, 6.5, plan, 10.0) == Waypoint(6.5, 5.0)  # arrived and waiting: nothing learnt
    assert lead.radius_m == 0.0


def test_a_vehicle_stopped_short_teaches_the_radius_and_is_then_led() -> None:
    lead = Lead(GRID)
    plan = (Waypoint(7.0, 5.0),)
    assert _stand(lead, 5.0, plan, STALL_S - 1.0) == Waypoint(7.0, 5.0)  # a pivot turn is not a stall
    assert lead.radius_m == 0.0
    _stand(lead, 5.0, plan, 1.5, start=100.0 + STALL_S - 0.5)
    assert lead.radius_m == pytest.approx(2.0)
    # then the setpoint is the radius and a margin ahead, and the path's end is overrun by the
    # radius less a little, so that the vehicle stops just past it
    end = lead.setpoint(200.0, 6.0, 5.0, plan)
    assert end is not None
    assert end.x == pytest.approx(7.0 + 2.0 + OVERRUN_M)
    assert end.y == 5.0
    # along a longer plan it is the first point the radius and a margin away
    ahead = lead.setpoint(201.0, 6.0, 5.0, (*plan, Waypoint(7.0, 9.0)))
    assert ahead is not None
    assert math.hypot(ahead.x - 6.0, ahead.y - 5.0) == pytest.approx(2.0 + LEAD_MARGIN_M)
    assert ahead.x == 7.0


def test_a_hold_is_driven_to_and_teaches_nothing() -> None:
    # a vehicle stopped 2 m short of the point it is to hold on is sent through it, to stop just
    # past it (held at a free cell's centre inside its radius, it would never move); standing on
    # the point, it is sent the point itself
    lead = Lead(GRID, radius_m=2.0)
    plan = (Waypoint(7.0, 5.0),)
    through = _stand(lead, 5.0, plan, 10.0, hold=True)
    assert through is not None
    assert (through.x, through.y) == (pytest.approx(7.0 + 2.0 + OVERRUN_M), 5.0)
    assert lead.setpoint(20.0, 7.3, 5.0, plan, hold=True) == Waypoint(7.0, 5.0)
    assert lead.radius_m == 2.0
    taught = Lead(GRID)
    _stand(taught, 5.0, plan, 10.0, hold=True)
    assert taught.radius_m == 0.0


def test_stalls_far_from_the_target_or_across_a_pause_teach_nothing() -> None:
    lead = Lead(GRID)
    _stand(lead, 5.0, (Waypoint(12.0, 5.0),), 10.0)  # 7 m short: held by something else
    assert lead.radius_m == 0.0
    for t in (0.0, 2.5, 5.0, 7.5):  # asked every 2.5 s: commanding was paused in between
        lead.setpoint(t, 5.0, 5.0, (Waypoint(7.0, 5.0),))
    assert lead.radius_m == 0.0


def test_a_vehicle_held_short_of_its_plan_s_end_is_planned_on_from_the_end() -> None:
    # the end lies 0.8 m from the north-eastern corner: the only overrun that fits, a quarter
    # straight on, ends 2 m from where a vehicle that stops 2 m short has stopped, short of the end
    plan = (Waypoint(19.2, 19.2),)
    carrot = 19.2 + 0.25 * (2.0 + OVERRUN_M) / math.sqrt(2.0)  # a quarter of the overrun fits
    x = y = carrot - 2.0 / math.sqrt(2.0)
    assert Lead(GRID).planning_point(0.0, x, y, plan) == (x, y)  # no radius learnt
    lead = Lead(GRID, radius_m=2.0)
    calls = int(2 * STALL_S)  # at 2 Hz
    for k in range(calls - 1):
        target = lead.setpoint(100.0 + 0.5 * k, x, y, plan)
        assert target is not None
        assert math.hypot(target.x - x, target.y - y) == pytest.approx(2.0)
    assert lead.planning_point(100.0 + STALL_S - 1.0, x, y, plan) == (x, y)  # not still for long enough
    for k in range(calls - 1, calls + 2):
        lead.setpoint(100.0 + 0.5 * k, x, y, plan)
    assert lead.planning_point(100.0 + STALL_S + 0.5, x, y, plan) == (19.2, 19.2)
    assert lead.radius_m == 2.0
    # once the service stops commanding (the pilot took over, the link was lost) it is not held
    assert lead.planning_point(100.0 + STALL_S + 5.0, x, y, plan) == (x, y)


def test_a_stopped_vehicle_is_seen_stopped_through_position_jitter() -> None:
    lead = Lead(GRID)
    plan = (Waypoint(7.0, 5.0),)
    jitter = [0.0, 0.08, -0.06, 0.1, -0.09, 0.04, -0.1, 0.07]  # +-10 cm
    for k in range(int(2 * STALL_S) + 1):
        lead.setpoint(100.0 + 0.5 * k, 5.0 + jitter[k % 8], 5.0 - jitter[k % 8], plan)
    assert lead.radius_m == pytest.approx(2.0, abs=0.15)


def test_an_overrun_into_a_wall_is_turned_aside() -> None:
    # the point (8.5, 7.5) lies 0.5 m from the wall's face x = 9 (the wall spans y 4-8): straight
    # on, and three quarters of it, end inside; turned 30 degrees (left first) the full overrun
    # ends above the wall, and the leg to it clears the wall's corner (9, 8)
    target = lead_point(WALLED, 7.0, 7.5, (Waypoint(8.5, 7.5),), 3.0, 2.0)
    assert target.x == pytest.approx(8.5 + 2.0 * math.cos(math.radians(30.0)))
    assert target.y == pytest.approx(7.5 + 2.0 * math.sin(math.radians(30.0)))


def test_a_vehicle_held_while_its_targets_change_teaches_the_farthest() -> None:
    # the map moves the estimate while the vehicle waits: new targets, all inside its radius
    lead = Lead(GRID)
    for k in range(int(2 * STALL_S) + 1):
        lead.setpoint(100.0 + 0.5 * k, 5.0, 5.0, (Waypoint(6.8 if k % 2 else 5.0, 5.0 if k % 2 else 7.0),))
    assert lead.radius_m == pytest.approx(2.0)
