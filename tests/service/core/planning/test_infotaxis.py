import math

import numpy as np
import pytest

from service.core.config import PlanningConfig
from service.core.errors import NoPathError
from service.core.grid import Grid
from service.core.mapping.belief import FloatArray
from service.core.mapping.hmm import HmmMapper
from service.core.mapping.mapper import SourceMapper
from service.core.observation import Observation
from service.core.planning.base import PlanContext, VehicleState
from service.core.planning.infotaxis import InfotaxisPlanner, expected_entropy

LINE = Grid(0.0, 3.0, 0.0, 1.0, columns=3, rows=1)  # three cells West to East: 0, 1, 2


class ToyMapper(SourceMapper):
    """A three-cell map with a detection model given as a table, one row per visited cell."""

    name = "toy"

    def __init__(self, grid: Grid, pi: list[float], table: dict[int, list[float]]) -> None:
        super().__init__(grid)
        self._pi = np.asarray(pi, dtype=float).reshape(grid.shape)
        self.table = table
        self.asked: list[int] = []

    def _assimilate(self, cell: int, detected: bool) -> None:
        pass

    def detection_likelihood(self, cell: int) -> FloatArray:
        self.asked.append(cell)
        return np.asarray(self.table[cell], dtype=float).reshape(self.grid.shape)


def h(*p: float) -> float:
    return -sum(x * math.log(x) for x in p if x > 0)


def test_expected_entropy_by_hand() -> None:
    prior = np.array([0.5, 0.0, 0.5])
    # a perfect detector for "source in cell 0": the outcome tells everything
    assert expected_entropy(prior, np.array([1.0, 0.0, 0.0])) == pytest.approx(0.0)
    # an uninformative detector: nothing is learnt
    assert expected_entropy(prior, np.array([0.5, 0.5, 0.5])) == pytest.approx(math.log(2))
    # P(d) = 0.5 * 0.2 + 0.5 * 0.6 = 0.4; posteriors (0.25, 0, 0.75) and (2/3, 0, 1/3)
    expected = 0.4 * h(0.25, 0.75) + 0.6 * h(2 / 3, 1 / 3)
    assert expected == pytest.approx(0.60684, abs=1e-5)
    assert expected_entropy(prior, np.array([0.2, 0.0, 0.6])) == pytest.approx(expected)


def test_picks_the_move_with_the_least_expected_entropy() -> None:
    # West (cell 0): P(d) = 0.4, S = 0.4 H(.25, .75) + 0.6 H(2/3, 1/3) = 0.6068
    # East (cell 2): L = (0.1, 0, 0.1), P(d) = 0.1, both posteriors (0.5, 0.5): S = ln 2 = 0.6931
    mapper = ToyMapper(LINE, [0.5, 0.0, 0.5], {0: [0.2, 0.0, 0.6], 2: [0.1, 0.0, 0.1]})
    planner = InfotaxisPlanner(LINE, PlanningConfig())
    ctx = PlanContext(VehicleState(1.5, 0.5), 1, 0, mapper)
    scores = planner.scores(ctx)
    assert scores == pytest.approx({0: 0.4 * h(0.25, 0.75) + 0.6 * h(2 / 3, 1 / 3), 2: math.log(2)})
    plan = planner.plan(ctx)
    assert plan.cells == (0,)
    assert set(mapper.asked) == {0, 2}  # the mapper's own model was asked about both moves
    # swap the models and the choice follows
    swapped = ToyMapper(LINE, [0.5, 0.0, 0.5], {2: [0.2, 0.0, 0.6], 0: [0.1, 0.0, 0.1]})
    assert planner.plan(PlanContext(VehicleState(1.5, 0.5), 1, 0, swapped)).cells == (2,)


def test_obstacle_cells_are_not_candidates() -> None:
    g = Grid(0.0, 3.0, 0.0, 1.0, columns=3, rows=1, obstacles=((0.2, 0.2, 0.8, 0.8),))
    mapper = ToyMapper(g, [0.5, 0.0, 0.5], {0: [1.0, 0.0, 0.0], 2: [0.1, 0.0, 0.1]})
    plan = InfotaxisPlanner(g, PlanningConfig()).plan(PlanContext(VehicleState(1.5, 0.5), 1, 0, mapper))
    assert plan.cells == (2,)  # the informative move is into an obstacle
    boxed = Grid(
        0.0, 3.0, 0.0, 1.0, columns=3, rows=1, obstacles=((0.2, 0.2, 0.8, 0.8), (2.2, 0.2, 2.8, 0.8))
    )
    with pytest.raises(NoPathError):
        InfotaxisPlanner(boxed, PlanningConfig()).plan(PlanContext(VehicleState(1.5, 0.5), 1, 0, mapper))


def test_with_the_hmm_mapper_the_choice_is_the_brute_force_minimum() -> None:
    g = Grid(0.0, 20.0, 0.0, 20.0, columns=10, rows=10)
    mapper = HmmMapper(g)
    for t in range(12):
        mapper.update(Observation(float(t), 9.0 + 0.5 * t, 5.0, 1.0, 0.2, t in (6, 9)))
    ctx = PlanContext(VehicleState(14.5, 5.0), g.cell_of(14.5, 5.0), 0, mapper)
    plan = InfotaxisPlanner(g, PlanningConfig()).plan(ctx)
    # independent: the posterior entropies computed here with plain Bayes and numpy
    pi = np.asarray(mapper.likelihood).ravel()
    best, best_s = None, math.inf
    row, col = g.row_col(ctx.cell)
    for dr, dc in [(0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1)]:
        cell = (row + dr) * g.columns + col + dc
        lik = mapper.detection_likelihood(cell).ravel()
        p_d = float(pi @ lik)
        post_d, post_n = pi * lik / p_d, pi * (1 - lik) / (1 - p_d)
        s = p_d * h(*post_d) + (1 - p_d) * h(*post_n)
        if s < best_s - 1e-12:
            best, best_s = cell, s
    assert plan.cells == (best,)
