import itertools

import numpy as np
import pytest

from service.core.config import PlanningConfig
from service.core.errors import NoPathError
from service.core.grid import Grid
from service.core.mapping.belief import FloatArray
from service.core.mapping.mapper import SourceMapper
from service.core.mapping.plume import advance_plume
from service.core.mapping.transport import transition
from service.core.planning.base import PlanContext, VehicleState
from service.core.planning.mldp import MldpPathPlanner, MldpPlanner, repair_corner_cuts

PAPER = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)


class PlumeMap(SourceMapper):
    """A mapper whose plume map alpha is set by the test."""

    name = "plume"

    def set_plume(self, alpha: FloatArray) -> None:
        self._alpha = alpha

    def _assimilate(self, cell: int, detected: bool, at: tuple[float, float]) -> None:
        pass

    def detection_likelihood(self, cell: int) -> FloatArray:
        return np.zeros(self.grid.shape)


def context(grid: Grid, alpha: FloatArray, start: int, goal: int) -> PlanContext:
    mapper = PlumeMap(grid)
    mapper.set_plume(alpha)
    x, y = grid.centre(start)
    return PlanContext(VehicleState(x, y), start, goal, mapper)


def eq18_alpha(t_end: int = 48) -> FloatArray:
    """alpha(t) for a source in C488 under eq. 18's flow: 1 m/s East until t = 30, then North
    (eq. 11 recursion written out here, one tick a second, the mapper's default sigma of 1)."""
    pi = np.zeros(PAPER.shape)
    pi.flat[PAPER.flat_index(488)] = 1.0
    alpha = pi.copy()
    for n in range(1, t_end + 1):
        flow = (1.0, 0.0) if n <= 30 else (0.0, 1.0)
        alpha = advance_plume(alpha, pi, transition(PAPER, *flow, 1.0, 1.0, 1.0), n)
    return alpha


def max_plus_best(
    values: FloatArray, cells: list[int], grid: Grid, start: int, end: int, steps: int
) -> float:
    """Greatest sum of alpha over every connected path of ``steps`` moves (staying allowed) from
    start to end inside ``cells``: max-plus matrix powers by repeated squaring, a different
    computation from the MLDP recursion."""
    index = {c: k for k, c in enumerate(cells)}
    w = np.full((len(cells), len(cells)), -np.inf)
    for a in cells:
        ra, ca = grid.row_col(a)
        for b in cells:
            rb, cb = grid.row_col(b)
            if max(abs(ra - rb), abs(ca - cb)) <= 1:
                w[index[a], index[b]] = values.flat[b]  # entering b scores alpha_b

    def mul(x: FloatArray, y: FloatArray) -> FloatArray:
        out: FloatArray = np.max(x[:, :, None] + y[None, :, :], axis=1)
        return out

    result = np.full_like(w, -np.inf)
    np.fill_diagonal(result, 0.0)
    power, k = w, steps
    while k:
        if k & 1:
            result = mul(result, power)
        power = mul(power, power)
        k >>= 1
    return float(values.flat[start] + result[index[start], index[end]])


def test_eq18_25_step_path_between_c388_and_c471() -> None:
    alpha = eq18_alpha(48)
    start, end = PAPER.flat_index(388), PAPER.flat_index(471)
    planner = MldpPathPlanner(PAPER, PlanningConfig(mldp_steps=25))
    path = planner.compute(context(PAPER, alpha, start, end))
    assert len(path) == 26
    assert path[0] == start
    assert path[-1] == end
    for a, b in itertools.pairwise(path):
        (ra, ca), (rb, cb) = PAPER.row_col(a), PAPER.row_col(b)
        assert max(abs(ra - rb), abs(ca - cb)) <= 1, "each step is an App. I neighbour"
    score = float(sum(alpha.flat[c] for c in path))
    # every connected 25-step path on an 8 x 18 sub-grid holding both ends and the plume's core
    # up-flow of them: none collects more alpha than the MLDP, and the MLDP is one of them
    rows = range(PAPER.row_col(end)[0] - 3, PAPER.row_col(start)[0] + 3)
    cols = range(PAPER.row_col(start)[1] - 12, PAPER.row_col(end)[1] + 3)
    sub = [r * PAPER.columns + c for r in rows for c in cols]
    assert set(path) <= set(sub)
    assert score == pytest.approx(max_plus_best(alpha, sub, PAPER, start, end, 25), rel=1e-9)
    # and the path is worth taking: it collects more than the straight shortest one would
    assert score > 2 * sum(alpha.flat[c] for c in (start, end))


def enumerate_best(alpha: FloatArray, grid: Grid, start: int, end: int, steps: int) -> float:
    """Literal enumeration of every sequence of ``steps`` App. I moves."""
    moves = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)]
    best = -np.inf
    for seq in itertools.product(moves, repeat=steps):
        r, c = grid.row_col(start)
        total = alpha.flat[start]
        for dr, dc in seq:
            r, c = r + dr, c + dc
            if not (0 <= r < grid.rows and 0 <= c < grid.columns):
                break
            total += alpha[r, c]
        else:
            if r * grid.columns + c == end:
                best = max(best, total)
    return float(best)


def test_small_maps_against_literal_enumeration() -> None:
    rng = np.random.default_rng(8)
    g = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3)
    for _ in range(5):
        alpha = rng.random(g.shape)
        start, end = (int(c) for c in rng.integers(0, g.size, size=2))
        planner = MldpPathPlanner(g, PlanningConfig(mldp_steps=4))
        path = planner.compute(context(g, alpha, start, end))
        assert len(path) == 5
        assert sum(alpha.flat[c] for c in path) == pytest.approx(enumerate_best(alpha, g, start, end, 4))


def test_path_avoids_obstacles_and_their_corners() -> None:
    g = Grid(0.0, 5.0, 0.0, 5.0, columns=5, rows=5, obstacles=((2.1, 1.1, 2.9, 3.9),))
    alpha = np.ones(g.shape)
    alpha[3, 3] = 50.0  # a prize just past the wall's top corner
    start, end = g.cell_of(1.5, 2.5), g.cell_of(3.5, 2.5)
    planner = MldpPathPlanner(g, PlanningConfig(mldp_steps=6))
    path = planner.compute(context(g, alpha, start, end))
    blocked = np.asarray(g.obstacle_mask)
    assert path[0] == start
    assert path[-1] == end
    for a, b in itertools.pairwise(path):
        (ra, ca), (rb, cb) = g.row_col(a), g.row_col(b)
        assert not blocked[rb, cb]
        if ra != rb and ca != cb:
            assert not blocked[rb, ca]
            assert not blocked[ra, cb]
    # the goal changes: a new path; the same goal as the vehicle moves on: the same path
    plan = planner.plan(context(g, alpha, start, end))
    again = planner.plan(context(g, alpha, plan.cells[0], end))
    assert planner.replans == 1
    assert again.cells == plan.cells[1:]


def test_corner_cut_repair() -> None:
    g = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3, obstacles=((1.1, 0.1, 1.9, 0.9),))
    blocked = np.asarray(g.obstacle_mask)
    a, b = g.cell_of(0.5, 0.5), g.cell_of(1.5, 1.5)  # diagonal past the obstacle at (1, 0)
    assert repair_corner_cuts(g, [a, b], blocked) == [a, g.cell_of(0.5, 1.5), b]
    assert repair_corner_cuts(g, [a, a, g.cell_of(0.5, 1.5)], blocked) == [a, a, g.cell_of(0.5, 1.5)]


def test_one_step_planner_moves_to_the_best_admissible_neighbour() -> None:
    g = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3, obstacles=((2.1, 1.1, 2.9, 1.9),))
    alpha = np.zeros(g.shape)
    alpha[1, 1] = 9.0  # the vehicle's own cell is not a move
    alpha[2, 2] = 5.0  # NE: the diagonal would cut the corner of the obstacle at (1, 2)
    alpha[1, 2] = 7.0  # E: the obstacle itself
    alpha[0, 0] = 3.0  # SW: the best admissible move
    alpha[2, 1] = 2.0
    centre = g.cell_of(1.5, 1.5)
    plan = MldpPlanner(g, PlanningConfig()).plan(context(g, alpha, centre, 0))
    assert plan.cells == (g.cell_of(0.5, 0.5),)
    # boxed in: a clear error
    walls = tuple(
        (x + 0.1, y + 0.1, x + 0.9, y + 0.9) for x in range(3) for y in range(3) if (x, y) != (1, 1)
    )
    boxed = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3, obstacles=walls)
    with pytest.raises(NoPathError):
        MldpPlanner(boxed, PlanningConfig()).plan(context(boxed, alpha, centre, 0))
