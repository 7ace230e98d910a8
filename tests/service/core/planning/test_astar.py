import itertools
import math

import numpy as np
import pytest

from service.core.config import PlanningConfig
from service.core.errors import NoPathError
from service.core.grid import Grid
from service.core.mapping.hmm import HmmMapper
from service.core.planning.astar import AStarPlanner, PaperAStarPlanner, astar, astar_paper
from service.core.planning.base import PlanContext, VehicleState, Waypoint
from service.core.planning.safety import segment_clear

# Independent references: plain Bellman-Ford relaxation written out here, not the package's tables.
STEPS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]
COMPASS_CCW = [(0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1)]


def brute_force_costs(grid: Grid, start: int, blocked: np.ndarray) -> np.ndarray:
    """Least cost (metres) from start to every cell, 8 moves without corner cutting."""
    n, m = grid.shape
    cost = np.full((n, m), np.inf)
    cost[divmod(start, m)] = 0.0
    changed = True
    while changed:
        changed = False
        for r in range(n):
            for c in range(m):
                if not np.isfinite(cost[r, c]):
                    continue
                for dr, dc in STEPS:
                    rr, cc = r + dr, c + dc
                    if not (0 <= rr < n and 0 <= cc < m) or blocked[rr, cc]:
                        continue
                    if dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]):
                        continue
                    w = math.hypot(dc * grid.cell_width_m, dr * grid.cell_height_m)
                    if cost[r, c] + w < cost[rr, cc] - 1e-9:
                        cost[rr, cc] = cost[r, c] + w
                        changed = True
    return cost


def path_cost_m(grid: Grid, path: list[int]) -> float:
    total = 0.0
    for a, b in itertools.pairwise(path):
        (ra, ca), (rb, cb) = grid.row_col(a), grid.row_col(b)
        assert max(abs(ra - rb), abs(ca - cb)) == 1, "consecutive cells must be neighbours"
        total += math.hypot((cb - ca) * grid.cell_width_m, (rb - ra) * grid.cell_height_m)
    return total


def assert_admissible(grid: Grid, path: list[int], blocked: np.ndarray) -> None:
    for a, b in itertools.pairwise(path):
        (ra, ca), (rb, cb) = grid.row_col(a), grid.row_col(b)
        assert not blocked[rb, cb]
        if ra != rb and ca != cb:
            assert not blocked[rb, ca], "cut the corner of an obstacle cell"
            assert not blocked[ra, cb], "cut the corner of an obstacle cell"


def grid_with(mask_rows: list[str], lx: float = 1.0, ly: float = 1.0) -> tuple[Grid, np.ndarray]:
    """A grid from a picture: first string is the northern row, '#' an obstacle cell."""
    rows = len(mask_rows)
    cols = len(mask_rows[0])
    obstacles = []
    for j, line in enumerate(mask_rows):
        row = rows - 1 - j
        for col, ch in enumerate(line):
            if ch == "#":
                obstacles.append((col * lx + 0.1, row * ly + 0.1, (col + 1) * lx - 0.1, (row + 1) * ly - 0.1))
    g = Grid(0.0, cols * lx, 0.0, rows * ly, columns=cols, rows=rows, obstacles=tuple(obstacles))
    return g, np.asarray(g.obstacle_mask)


def test_wall_with_a_gap_is_passed_through_the_gap() -> None:
    g, blocked = grid_with(
        [
            ".....",
            ".....",
            "###.#",
            ".....",
            ".....",
        ]
    )
    start, goal = g.cell_of(0.5, 0.5), g.cell_of(0.5, 4.5)
    path = astar(g, start, goal)
    assert path[0] == start
    assert path[-1] == goal
    assert_admissible(g, path, blocked)
    assert g.cell_of(3.5, 2.5) in path  # the only gap
    # by hand: the gap can only be entered and left straight (its sides are walls), so
    # (0,0) -> (3,1) is 1 diagonal + 2 straight, then 2 straight through the gap to (3,3), then
    # 1 diagonal + 2 straight to (0,4): 2 sqrt(2) + 6
    assert path_cost_m(g, path) == pytest.approx(2 * math.sqrt(2) + 6)
    assert brute_force_costs(g, start, blocked).flat[goal] == pytest.approx(2 * math.sqrt(2) + 6)


def test_corners_are_not_cut() -> None:
    g, _blocked = grid_with(
        [
            "..",
            "#.",
        ]
    )
    # from south-east to north-west: the diagonal would cut the corner of the south-west obstacle
    start, goal = g.cell_of(1.5, 0.5), g.cell_of(0.5, 1.5)
    path = astar(g, start, goal)
    assert path == [start, g.cell_of(1.5, 1.5), goal]


def test_matches_brute_force_on_random_maps() -> None:
    rng = np.random.default_rng(11)
    checked = unreachable = 0
    for _ in range(60):
        rows, cols = int(rng.integers(2, 9)), int(rng.integers(2, 9))
        lx, ly = float(rng.uniform(0.5, 3.0)), float(rng.uniform(0.5, 3.0))
        picture = ["".join("#" if rng.random() < 0.3 else "." for _ in range(cols)) for _ in range(rows)]
        g, blocked = grid_with(picture, lx, ly)
        start, goal = (int(c) for c in rng.integers(0, g.size, size=2))
        blocked_start = bool(blocked.flat[start])
        reference = brute_force_costs(g, start, blocked)
        if not np.isfinite(reference.flat[goal]) and goal != start:
            unreachable += 1
            with pytest.raises(NoPathError):
                astar(g, start, goal)
            continue
        path = astar(g, start, goal)
        checked += 1
        assert path[0] == start
        assert path[-1] == goal
        assert_admissible(g, path, blocked)
        assert path_cost_m(g, path) == pytest.approx(reference.flat[goal] if goal != start else 0.0)
        assert blocked_start or not blocked[g.row_col(path[0])]
    assert checked > 20
    assert unreachable > 3


def test_blocked_or_enclosed_goal_is_a_clear_error() -> None:
    g, _ = grid_with(
        [
            ".....",
            ".###.",
            ".#.#.",
            ".###.",
            ".....",
        ]
    )
    with pytest.raises(NoPathError, match="no path"):
        astar(g, g.cell_of(0.5, 0.5), g.cell_of(2.5, 2.5))
    with pytest.raises(NoPathError, match="obstacle cell"):
        astar(g, g.cell_of(0.5, 0.5), g.cell_of(1.5, 1.5))


def test_start_inside_an_obstacle_cell_may_leave_it() -> None:
    g, _ = grid_with(["...", ".#.", "..."])
    path = astar(g, g.cell_of(1.5, 1.5), g.cell_of(2.5, 2.5))
    assert path[0] == g.cell_of(1.5, 1.5)
    assert path[-1] == g.cell_of(2.5, 2.5)
    assert len(path) == 2  # straight out diagonally: the cells beside that move are free


# -- the paper's five-move variant ------------------------------------------------------------


def brute_force_five_moves(grid: Grid, start: int, heading: int, blocked: np.ndarray) -> np.ndarray:
    """Least cost over (row, col, heading) with the five relative moves and eq. 8's penalty."""
    n, m = grid.shape
    cost = np.full((n, m, 8), np.inf)
    r0, c0 = divmod(start, m)
    cost[r0, c0, heading] = 0.0
    changed = True
    while changed:
        changed = False
        for r, c, h in zip(*np.nonzero(np.isfinite(cost)), strict=True):
            for turn in (-2, -1, 0, 1, 2):
                nh = (h + turn) % 8
                dr, dc = COMPASS_CCW[nh]
                rr, cc = r + dr, c + dc
                if not (0 <= rr < n and 0 <= cc < m):
                    continue
                hit = blocked[rr, cc] or (dr != 0 and dc != 0 and (blocked[r + dr, c] or blocked[r, c + dc]))
                w = (math.sqrt(2) if dr and dc else 1.0) + (1000.0 if hit else 0.0)
                if cost[r, c, h] + w < cost[rr, cc, nh] - 1e-9:
                    cost[rr, cc, nh] = cost[r, c, h] + w
                    changed = True
    best: np.ndarray = cost.min(axis=2)
    return best


def paper_cost(grid: Grid, path: list[int], blocked: np.ndarray) -> float:
    total = 0.0
    for a, b in itertools.pairwise(path):
        (ra, ca), (rb, cb) = grid.row_col(a), grid.row_col(b)
        diagonal = ra != rb and ca != cb
        hit = blocked[rb, cb] or (diagonal and (blocked[rb, ca] or blocked[ra, cb]))
        total += (math.sqrt(2) if diagonal else 1.0) + (1000.0 if hit else 0.0)
    return total


def assert_five_moves(grid: Grid, path: list[int], heading: int) -> None:
    for a, b in itertools.pairwise(path):
        (ra, ca), (rb, cb) = grid.row_col(a), grid.row_col(b)
        sector = COMPASS_CCW.index((rb - ra, cb - ca))
        turn = (sector - heading + 4) % 8 - 4  # signed, in sectors of 45 degrees
        assert -2 <= turn <= 2, f"move {sector} from heading {heading} is not one of the five"
        heading = sector


def test_paper_variant_cannot_reverse() -> None:
    g, _ = grid_with(["....."] * 3)
    start, goal = g.cell_of(2.5, 1.5), g.cell_of(1.5, 1.5)  # the goal is right behind (West)
    path = astar_paper(g, start, 0, goal)  # heading East
    assert_five_moves(g, path, 0)
    assert path[-1] == goal
    # by hand: no two moves turn East into West (SW is three sectors from N, NW from E); three
    # lefts do it (N, W, S), as do the mirror image and no cheaper pair of moves
    assert paper_cost(g, path, np.zeros(g.shape, bool)) == pytest.approx(3.0)
    assert len(path) == 4


def test_paper_variant_goes_around_an_obstacle_and_honours_five_moves() -> None:
    g, blocked = grid_with(
        [
            "......",
            "..#...",
            "..#...",
            "..#...",
            "......",
        ]
    )
    start, goal = g.cell_of(0.5, 2.5), g.cell_of(5.5, 2.5)
    path = astar_paper(g, start, 0, goal)
    assert_five_moves(g, path, 0)
    assert path[-1] == goal
    assert not any(blocked.flat[c] for c in path)


def test_paper_variant_within_its_heuristic_bound_on_random_maps() -> None:
    # Manhattan overestimates diagonal moves by up to sqrt(2), so A* returns a path whose cost is
    # at most sqrt(2) times the least five-move cost; it finds one exactly when one exists.
    rng = np.random.default_rng(5)
    for _ in range(25):
        rows, cols = int(rng.integers(3, 7)), int(rng.integers(3, 7))
        picture = ["".join("#" if rng.random() < 0.2 else "." for _ in range(cols)) for _ in range(rows)]
        g, blocked = grid_with(picture)
        start, goal = (int(c) for c in rng.integers(0, g.size, size=2))
        heading = int(rng.integers(0, 8))
        best = brute_force_five_moves(g, start, heading, blocked).flat[goal]
        if goal == start:
            best = 0.0
        if not np.isfinite(best):
            with pytest.raises(NoPathError):
                astar_paper(g, start, heading, goal)
            continue
        path = astar_paper(g, start, heading, goal)
        assert path[0] == start
        assert path[-1] == goal
        assert_five_moves(g, path, heading)
        cost = paper_cost(g, path, blocked)
        assert best - 1e-9 <= cost <= math.sqrt(2) * best + 1e-9
        if best < 1000.0 / math.sqrt(2):  # a free five-move path exists: no obstacle is entered
            assert cost < 1000.0


# -- planners: follow the path, re-plan when the estimate changes ------------------------------


def context(g: Grid, x: float, y: float, goal: int, heading: float = 0.0) -> PlanContext:
    return PlanContext(VehicleState(x, y, heading), g.cell_of(x, y), goal, HmmMapper(g))


def test_astar_planner_replans_only_when_the_estimate_changes() -> None:
    # a block between the vehicle and every goal below, so that no straight leg is clear
    g, _ = grid_with(["......", "..##..", "..##..", "......"])
    planner = AStarPlanner(g, PlanningConfig())
    goal = g.cell_of(5.5, 3.5)
    first = planner.plan(context(g, 0.5, 0.5, goal))
    assert planner.replans == 1
    assert first.cells[-1] == goal
    # the vehicle reaches the first waypoint: same path, one cell shorter, no new search
    x, y = first.waypoints[0].x, first.waypoints[0].y
    second = planner.plan(context(g, x, y, goal))
    assert planner.replans == 1
    assert second.cells == first.cells[1:]
    # the estimate moves: a new search
    moved = g.cell_of(4.5, 3.5)
    third = planner.plan(context(g, x, y, moved))
    assert planner.replans == 2
    assert third.cells[-1] == moved
    # the vehicle strays off the path: a new search
    off = next((px, py) for px, py in ((0.5, 1.5), (1.5, 0.5)) if g.cell_of(px, py) not in third.cells)
    planner.plan(context(g, *off, moved))
    assert planner.replans == 3


def test_astar_planner_flies_a_clear_straight_leg_to_the_estimate() -> None:
    # on 1.25 x 2 m cells the grid's shortest path to a goal 30 m east and 8 m north may take its
    # four diagonal moves first, 58 degrees off the line; a clear leg is flown straight instead
    g = Grid(0.0, 40.0, 0.0, 20.0, columns=32, rows=10)
    planner = AStarPlanner(g, PlanningConfig())
    goal = g.cell_of(31.0, 9.0)
    plan = planner.plan(context(g, 1.0, 1.0, goal))
    assert plan.waypoints == (Waypoint(*g.centre(goal)),)
    assert plan.cells == (goal,)
    assert planner.replans == 0
    # an obstacle on that leg: the grid path round it, no leg across the obstacle
    walled = Grid(0.0, 40.0, 0.0, 20.0, columns=32, rows=10, obstacles=((14.0, 0.0, 16.0, 12.0),))
    planner = AStarPlanner(walled, PlanningConfig())
    plan = planner.plan(context(walled, 1.0, 1.0, goal))
    assert planner.replans == 1
    assert plan.cells[-1] == goal
    points = [(1.0, 1.0), *((w.x, w.y) for w in plan.waypoints)]
    assert all(segment_clear(walled, a, b) for a, b in itertools.pairwise(points))


def test_waypoints_are_cell_centres_and_a_reached_goal_holds_there() -> None:
    g, _ = grid_with(["...."] * 2, lx=2.0, ly=3.0)
    planner = AStarPlanner(g, PlanningConfig())
    goal = g.cell_of(7.0, 5.0)
    plan = planner.plan(context(g, 0.3, 0.2, goal))
    assert [(w.x, w.y) for w in plan.waypoints] == [g.centre(c) for c in plan.cells]
    at_goal = planner.plan(context(g, 7.9, 5.9, goal))
    assert at_goal.cells == (goal,)
    assert (at_goal.waypoints[0].x, at_goal.waypoints[0].y) == g.centre(goal)


def test_paper_planner_refuses_a_path_through_an_obstacle() -> None:
    g, _ = grid_with(
        [
            ".#.",
            ".#.",
            ".#.",
        ]
    )
    planner = PaperAStarPlanner(g, PlanningConfig())
    with pytest.raises(NoPathError, match="crosses an obstacle"):
        planner.plan(context(g, 0.5, 1.5, g.cell_of(2.5, 1.5)))
