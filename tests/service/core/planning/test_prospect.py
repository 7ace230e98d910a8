import math

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.mapping.mapper import FlowStep, MapperParams
from service.core.mapping.pomdp import PomdpMapper
from service.core.mapping.transport import transition
from service.core.planning.prospect import (
    MIN_LEG_M,
    best_leg,
    candidate_ends,
    leg_cells,
    odour_chances,
    trace_distance,
)


def test_leg_cells_are_the_cells_at_each_tick() -> None:
    grid = Grid(0.0, 10.0, 0.0, 10.0, columns=10, rows=10)  # 1 m cells, row 0 in the south
    cells = leg_cells(grid, (0.5, 0.5), (4.5, 0.5), step_m=1.0)
    assert cells.tolist() == [[0, 1], [0, 2], [0, 3], [0, 4]]
    # two ticks a metre: twice as many looks, the last one on the end
    cells = leg_cells(grid, (0.5, 9.5), (0.5, 7.5), step_m=0.5)
    assert cells.tolist() == [[9, 0], [8, 0], [8, 0], [7, 0]]


def test_eq_p1_by_hand() -> None:
    # one row of three cells; q = 0.5 for a source in the vehicle's cell, 0.25 for one a cell
    # upflow (West), 0 downflow; the vehicle looks twice from the middle cell
    pi = np.array([[0.2, 0.3, 0.5]])
    kernel = np.zeros((1, 5))
    kernel[0, 2], kernel[0, 1] = 0.5, 0.25  # index m - 1 + dc
    with np.errstate(divide="ignore"):
        log_miss = np.log1p(-kernel)
    shares = odour_chances(pi, log_miss, np.array([[0, 1], [0, 1]]))
    # West source: 1 - 0.75^2; the middle one: 1 - 0.5^2; the East one is never smelled there
    assert shares[0].tolist() == pytest.approx([0.2 * 0.4375, 0.3 * 0.75, 0.0])
    assert float(shares.sum()) == pytest.approx(0.3125)


def test_eq_p1_matches_the_product_over_ticks_for_any_map() -> None:
    rng = np.random.default_rng(5)
    n, m = 4, 6
    pi = rng.random((n, m))
    pi /= pi.sum()
    kernel = rng.uniform(0.0, 0.9, size=(2 * n - 1, 2 * m - 1))
    cells = np.array([[1, 2], [3, 5], [1, 2], [0, 0]])
    shares = odour_chances(pi, np.log1p(-kernel), cells)
    expected = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            miss = math.prod(1.0 - kernel[n - 1 + i - r, m - 1 + j - c] for r, c in cells)
            expected[i, j] = pi[i, j] * (1.0 - miss)
    np.testing.assert_allclose(shares, expected, rtol=1e-12)


def test_trace_distance_runs_along_the_flow_to_the_leg() -> None:
    x = np.array([0.0, 0.0, -5.0])
    y = np.array([2.0, 8.0, 1.0])
    east = (1.0, 0.0)
    # a leg across the flow at x = 10 from y = -5 to 5: the first plume meets it 10 m downflow,
    # the second passes it by (its nearest end)
    d = trace_distance(x, y, (10.0, -5.0), (10.0, 5.0), east)
    assert d[:2].tolist() == pytest.approx([10.0, math.hypot(10.0, 3.0)])
    # a leg along the flow: the nearest point of it
    d = trace_distance(x, y, (0.0, 0.0), (10.0, 0.0), east)
    assert d[2] == pytest.approx(math.hypot(5.0, 1.0))


def steady_mapper(grid: Grid, flow: tuple[float, float], ticks: int = 20) -> PomdpMapper:
    """The default POMDP model with ``ticks`` seconds of a steady flow, nothing observed."""
    params = MapperParams(
        sigma_x=0.2,
        sigma_y=0.2,
        mu=0.9,
        false_alarm=0.1,
        miss_floor=0.3,
        footprint_m=0.8,
        footprint_growth=0.1,
        prehistory=True,
    )
    mapper = PomdpMapper(grid, params)
    step = transition(grid, *flow, 1.0, params.sigma_x, params.sigma_y)
    for _ in range(ticks):
        mapper.history.append(FlowStep(step, flow[0], flow[1], 1.0))
    return mapper


def test_the_kernel_is_the_mappers_own_model_seen_from_any_cell() -> None:
    grid = Grid(0.0, 40.0, -10.0, 10.0, columns=16, rows=8)
    mapper = steady_mapper(grid, (1.0, 0.3))
    kernel = mapper.odour_kernel()
    n, m = grid.shape
    assert kernel.shape == (2 * n - 1, 2 * m - 1)
    pf = mapper.params.false_alarm
    for cell in (0, grid.cell_of(21.0, 1.0), grid.size - 1):
        r, c = grid.row_col(cell)
        window = kernel[n - 1 - r : 2 * n - 1 - r, m - 1 - c : 2 * m - 1 - c]
        expected = (mapper.detection_likelihood(cell) - pf) / (1.0 - pf)
        np.testing.assert_allclose(window, expected, atol=1e-12)


def test_a_uniform_map_sends_the_first_leg_across_the_flow_on_its_downflow_side() -> None:
    # every source upflow of a cross-flow leg has its plume cross it: the leg most likely to meet
    # odour per metre lies across the flow, and downflow of the start
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)
    for flow, start in [((1.0, 0.0), (30.0, 10.0)), ((0.0, -1.0), (60.0, 20.0)), ((-0.7, 0.7), (50.0, 0.0))]:
        mapper = steady_mapper(grid, flow)
        leg = best_leg(grid, mapper.likelihood, mapper.odour_kernel(), start, 1.0, candidate_ends(grid), flow)
        assert leg is not None
        end, chance = leg
        dx, dy = end.x - start[0], end.y - start[1]
        along = dx * flow[0] + dy * flow[1]
        across = abs(-dx * flow[1] + dy * flow[0])
        assert along > 0.0, (flow, end)
        assert across > along, (flow, end)
        assert 0.2 < chance < 1.0


def test_a_dry_pass_moves_the_next_leg_to_where_the_map_still_holds_mass() -> None:
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)
    mapper = steady_mapper(grid, (1.0, 0.0))
    start = (90.0, 0.0)
    # the map after passes that ruled out every source east of x = 40 or south of y = 0: what is
    # left lies north-west, and the leg crosses its plumes
    x, y = np.meshgrid(grid.x_centres, grid.y_centres)
    pi = np.where((x < 40.0) & (y > 0.0), 1.0, 1e-9)
    pi /= pi.sum()
    leg = best_leg(grid, pi, mapper.odour_kernel(), start, 1.0, candidate_ends(grid), (1.0, 0.0))
    assert leg is not None
    end, _ = leg
    assert end.y > 0.0
    assert end.x < start[0]


def test_no_leg_when_every_end_is_too_near() -> None:
    grid = Grid(0.0, 4.0, 0.0, 4.0, columns=2, rows=2)
    mapper = steady_mapper(grid, (1.0, 0.0), ticks=2)
    ends = candidate_ends(grid)
    assert all(math.dist((e.x, e.y), (2.0, 2.0)) < MIN_LEG_M for e in ends)
    assert best_leg(grid, mapper.likelihood, mapper.odour_kernel(), (2.0, 2.0), 1.0, ends, (1.0, 0.0)) is None


def test_leg_ends_keep_out_of_obstacles_and_are_bounded_in_number() -> None:
    blocked = (20.0, -10.0, 40.0, 10.0)
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25, obstacles=(blocked,))
    ends = candidate_ends(grid)
    assert ends
    assert not any(grid.in_obstacle(e.x, e.y) for e in ends)
    large = Grid(0.0, 1000.0, 0.0, 1000.0, columns=100, rows=100)
    assert len(candidate_ends(large)) == 11 * 11
