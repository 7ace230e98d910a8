from collections import deque

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.planning.base import VehicleState, Waypoint
from service.core.planning.reach import Reachability
from service.core.planning.safety import guard, is_safe_point, safe_plan, segment_clear

# a 10 m x 10 m area of 1 m cells with one obstacle covering x 4..6, y 4..6 (cells 4 and 5)
G = Grid(0.0, 10.0, 0.0, 10.0, columns=10, rows=10, obstacles=((4.0, 4.0, 6.0, 6.0),))


@pytest.mark.parametrize(
    ("x", "y", "safe"),
    [
        (0.5, 0.5, True),
        (10.0, 10.0, True),  # the closed area's corner
        (10.1, 5.0, False),  # outside
        (5.0, 5.0, False),  # in the obstacle
        (4.0, 5.0, False),  # on its edge
        (3.9, 5.0, True),  # a free cell, off the rectangle
        (6.5, 6.5, True),
        (float("nan"), 1.0, False),
    ],
)
def test_safe_points(x: float, y: float, safe: bool) -> None:
    assert is_safe_point(G, x, y) is safe


def test_obstacle_cell_is_unsafe_even_off_the_rectangle() -> None:
    g = Grid(0.0, 10.0, 0.0, 10.0, columns=5, rows=5, obstacles=((4.5, 4.5, 5.5, 5.5),))
    # cell [4, 6] x [4, 6] overlaps the obstacle, so all of it is off limits
    assert not is_safe_point(g, 4.1, 4.1)
    assert is_safe_point(g, 3.9, 4.1)


def test_segments() -> None:
    assert segment_clear(G, (0.5, 0.5), (9.5, 0.5))
    assert not segment_clear(G, (0.5, 5.0), (9.5, 5.0))  # straight through
    assert not segment_clear(G, (3.0, 3.0), (7.0, 7.0))  # diagonal through
    assert not segment_clear(G, (3.0, 5.0), (5.0, 7.0))  # clips the corner (4, 6)
    assert segment_clear(G, (3.0, 5.5), (4.5, 7.0))  # passes just outside that corner
    assert not segment_clear(G, (4.0, 2.0), (4.0, 8.0))  # along the edge: touching counts


def test_guard_cuts_at_the_first_unsafe_waypoint() -> None:
    v = VehicleState(0.5, 0.5)
    wps = [Waypoint(2.5, 2.5), Waypoint(3.5, 3.5), Waypoint(7.5, 7.5), Waypoint(8.5, 8.5)]
    assert guard(G, v, wps) == tuple(wps[:2])  # 3.5 -> 7.5 crosses the obstacle
    assert guard(G, v, [Waypoint(11.0, 1.0), Waypoint(1.5, 1.5)]) == ()
    assert guard(G, VehicleState(0.5, 5.0), [Waypoint(9.5, 5.0)]) == ()  # the leg from the vehicle


def test_safe_plan_holds_then_escapes_then_gets_out() -> None:
    # a rejected plan on a safe spot: hold where the vehicle is (or at the latched hold point)
    v = VehicleState(2.2, 2.3)
    assert safe_plan(G, v, [Waypoint(5.0, 5.0)]) == (Waypoint(2.2, 2.3),)
    assert safe_plan(G, v, [], hold_at=Waypoint(2.0, 2.5)) == (Waypoint(2.0, 2.5),)
    # in an obstacle cell (but off the rectangle) a hold is not allowed: nearest free centre
    g = Grid(0.0, 10.0, 0.0, 10.0, columns=5, rows=5, obstacles=((4.5, 4.5, 5.5, 5.5),))
    out = safe_plan(g, VehicleState(4.1, 4.1), [])
    assert out == (Waypoint(3.0, 5.0),) or out == (Waypoint(5.0, 3.0),)
    # inside the rectangle: straight out to the nearest free centre, no leg check possible
    out = safe_plan(G, VehicleState(5.0, 4.2), [])
    assert len(out) == 1
    assert is_safe_point(G, out[0].x, out[0].y)
    assert out[0] == Waypoint(4.5, 3.5) or out[0] == Waypoint(5.5, 3.5)
    # outside the area: back to the nearest centre inside
    assert safe_plan(G, VehicleState(-3.0, 0.2), []) == (Waypoint(0.5, 0.5),)
    # an area that is all obstacle: nothing at all can be commanded
    full = Grid(0.0, 2.0, 0.0, 2.0, columns=2, rows=2, obstacles=((0.0, 0.0, 2.0, 2.0),))
    assert safe_plan(full, VehicleState(1.0, 1.0), [Waypoint(0.5, 0.5)]) == ()


def bfs_reachable(blocked: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Independent reference: breadth-first over 8 moves that do not cut an obstacle's corner."""
    n, m = blocked.shape
    seen = np.zeros_like(blocked)
    seen[start] = True
    queue = deque([start])
    while queue:
        r, c = queue.popleft()
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr, dc) == (0, 0) or not (0 <= rr < n and 0 <= cc < m) or blocked[rr, cc]:
                    continue
                if dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]):
                    continue
                if not seen[rr, cc]:
                    seen[rr, cc] = True
                    queue.append((rr, cc))
    out: np.ndarray = seen & ~blocked
    return out


def test_reachability_agrees_with_breadth_first_search() -> None:
    rng = np.random.default_rng(3)
    for _ in range(80):
        n, m = int(rng.integers(1, 9)), int(rng.integers(1, 9))
        boxes = []
        for _ in range(int(rng.integers(0, 5))):
            x0, y0 = rng.uniform(0, m), rng.uniform(0, n)
            boxes.append((x0, y0, x0 + rng.uniform(0.1, 3), y0 + rng.uniform(0.1, 3)))
        g = Grid(0.0, float(m), 0.0, float(n), columns=m, rows=n, obstacles=tuple(boxes))
        blocked = np.asarray(g.obstacle_mask)
        reach = Reachability(g)
        start = int(rng.integers(0, g.size))
        expected = bfs_reachable(blocked, g.row_col(start))
        assert np.array_equal(reach.reachable(start), expected)
        goal = int(rng.integers(0, g.size))
        got = reach.goal_for(start, goal)
        if expected.flat[goal]:
            assert got == goal
        elif expected.any():
            gx, gy = g.centre(goal)
            cells = [int(c) for c in np.flatnonzero(expected)]
            dist = {c: float(np.hypot(g.centre(c)[0] - gx, g.centre(c)[1] - gy)) for c in cells}
            assert expected.flat[got]
            assert dist[got] == pytest.approx(min(dist.values()))
        else:
            assert got == start


def test_a_point_on_the_boundary_of_an_obstacle_cell_is_not_safe() -> None:
    # 2 m cells; the obstacle (4.5-5.5, 4.5-5.5) blocks the cell x 4-6, y 4-6. x = 4 is the boundary
    # between that cell and the free one to its west: a point there belongs to both
    grid = Grid(0.0, 10.0, 0.0, 10.0, columns=5, rows=5, obstacles=((4.5, 4.5, 5.5, 5.5),))
    assert not is_safe_point(grid, 4.0, 5.0)
    assert not is_safe_point(grid, 5.0, 6.0)
    assert is_safe_point(grid, 3.9, 5.0)
    assert is_safe_point(grid, 2.0, 5.0)
