"""The one place waypoints leave the mission: safe, and only when they changed."""

from service.core.grid import Grid
from service.core.mission.emitter import Emitter
from service.core.planning.base import VehicleState, Waypoint

AREA = Grid(0.0, 50.0, 0.0, 50.0, columns=10, rows=10, obstacles=((20.0, 20.0, 30.0, 30.0),))
HERE = VehicleState(2.5, 2.5, 0.0)


def test_a_plan_is_emitted_once_and_none_until_it_changes() -> None:
    emitter = Emitter(AREA)
    plan = (Waypoint(12.5, 2.5), Waypoint(12.5, 12.5))
    assert emitter.emit(HERE, plan) == plan
    assert emitter.emit(HERE, plan) is None
    assert emitter.emit(HERE, plan[1:]) == plan[1:]


def test_nothing_unsafe_leaves_the_emitter() -> None:
    emitter = Emitter(AREA)
    out = emitter.emit(HERE, (Waypoint(25.0, 25.0),))  # inside the obstacle
    assert out is None or all(not (20.0 <= w.x <= 30.0 and 20.0 <= w.y <= 30.0) for w in out)
