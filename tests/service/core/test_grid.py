import numpy as np
import pytest

from service.core.errors import ConfigError, OutsideAreaError
from service.core.grid import MODEL_CELL_M, MODEL_CELLS_MAX, Grid, model_division

PAPER = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)


def test_paper_source_cell_is_c488() -> None:
    # seed hmm-plume-mapping §V: (20, 0) m is C488, column 8, row 13
    flat = PAPER.cell_of(20.0, 0.0)
    assert PAPER.paper_number(flat) == 488
    k = 488
    assert (k - 1) % 40 + 1 == 8  # eq. 3
    assert (k - 1) // 40 + 1 == 13  # eq. 4


def test_rows_count_from_the_north() -> None:
    # Fig. 6: C64 (i = 24, j = 2) is near the top (northern) edge
    x, y = PAPER.centre(PAPER.flat_index(64))
    assert x == pytest.approx(58.75)
    assert y == pytest.approx(50.0 - 1.5 * 4.0)
    # C1 is the north-west corner, C1000 the south-east one
    assert PAPER.centre(PAPER.flat_index(1)) == pytest.approx((1.25, 48.0))
    assert PAPER.centre(PAPER.flat_index(1000)) == pytest.approx((98.75, -48.0))


def test_numbering_round_trip() -> None:
    ks = [PAPER.paper_number(f) for f in range(PAPER.size)]
    assert sorted(ks) == list(range(1, PAPER.size + 1))
    assert all(PAPER.flat_index(PAPER.paper_number(f)) == f for f in range(PAPER.size))
    field = np.arange(PAPER.size, dtype=float).reshape(PAPER.shape)
    vector = field.ravel()[PAPER.paper_order]
    assert all(vector[k - 1] == PAPER.flat_index(k) for k in (1, 40, 41, 488, 1000))


def test_cell_of_every_centre() -> None:
    for f in range(0, PAPER.size, 7):
        assert PAPER.cell_of(*PAPER.centre(f)) == f


def test_boundaries_and_outside() -> None:
    assert PAPER.cell_of(0.0, 50.0) == PAPER.flat_index(1)
    assert PAPER.cell_of(100.0, -50.0) == PAPER.flat_index(1000)
    for x, y in [(-0.1, 0.0), (100.1, 0.0), (50.0, 50.5), (float("nan"), 0.0), (float("inf"), 0.0)]:
        assert not PAPER.contains(x, y) or not np.isfinite(x)
        with pytest.raises(OutsideAreaError):
            PAPER.cell_of(x, y)


def test_neighbours_interior_and_edges() -> None:
    m = 40
    k = 488
    assert PAPER.neighbours(k) == [k - 1 - m, k - m, k + 1 - m, k - 1, k, k + 1, k - 1 + m, k + m, k + 1 + m]
    # App. I eq. 19: an upper-edge (j = 1) cell has exterior neighbours above
    k = 5
    assert PAPER.neighbours(k) == [0, 0, 0, k - 1, k, k + 1, k - 1 + m, k + m, k + 1 + m]
    # corners
    assert PAPER.neighbours(1) == [0, 0, 0, 0, 1, 2, 0, 41, 42]
    assert PAPER.neighbours(1000) == [959, 960, 0, 999, 1000, 0, 0, 0, 0]


def test_obstacle_mask_and_point_test() -> None:
    g = Grid(0.0, 10.0, 0.0, 10.0, columns=10, rows=10, obstacles=((2.0, 3.0, 4.0, 5.0),))
    expected = np.zeros((10, 10), dtype=bool)
    expected[3:5, 2:4] = True
    np.testing.assert_array_equal(g.obstacle_mask, expected)
    assert g.in_obstacle(3.0, 4.0)
    assert not g.in_obstacle(5.0, 4.0)
    # a rectangle straddling cells marks every cell it overlaps
    g2 = Grid(0.0, 10.0, 0.0, 10.0, columns=10, rows=10, obstacles=((2.5, 3.5, 3.5, 3.6),))
    assert g2.obstacle_mask.sum() == 2


def test_invalid_grids() -> None:
    with pytest.raises(ConfigError):
        Grid(1.0, 1.0, 0.0, 1.0, 1, 1)
    with pytest.raises(ConfigError):
        Grid(0.0, 1.0, 0.0, 1.0, 0, 1)
    with pytest.raises(ConfigError):
        Grid(0.0, float("nan"), 0.0, 1.0, 1, 1)


def test_the_model_grid_splits_the_papers_cells_to_a_metre_within_its_budget() -> None:
    papers = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)  # 2.5 m x 4 m
    # 1.25 x 1 m (8000 cells); 0.83 m columns as well would make 12,000, over the budget
    assert model_division(papers) == (2, 4)
    fine = papers.subdivided(2, 4)
    assert (fine.columns, fine.rows, fine.cell_width_m, fine.cell_height_m) == (80, 100, 1.25, 1.0)
    assert fine.cell_height_m <= MODEL_CELL_M < fine.cell_width_m
    assert fine.size <= MODEL_CELLS_MAX < papers.size * 3 * 4
    assert model_division(Grid(0.0, 10.0, 0.0, 10.0, columns=10, rows=10)) == (1, 1)  # 1 m cells stay


def test_the_model_grid_is_split_no_further_than_its_cell_budget() -> None:
    large = Grid(0.0, 200.0, -100.0, 100.0, columns=80, rows=50)  # 4000 cells of 2.5 m x 4 m
    kx, ky = model_division(large)
    assert (kx, ky) == (1, 2)  # 8000 cells; splitting the columns too would make 16000
    assert large.size * kx * ky <= MODEL_CELLS_MAX


def test_coarsening_sums_each_cells_subcells_in_map_order() -> None:
    grid = Grid(0.0, 4.0, 0.0, 2.0, columns=2, rows=1)
    fine = grid.subdivided(2, 2)
    field = np.arange(fine.size, dtype=float).reshape(fine.shape)  # rows from the south
    # fine rows 0-1, columns 0-1 -> coarse (0, 0); columns 2-3 -> coarse (0, 1)
    np.testing.assert_array_equal(grid.coarsened(field, 2, 2), [[0 + 1 + 4 + 5, 2 + 3 + 6 + 7]])
    x, y = fine.centre(fine.cell_of(3.5, 1.5))
    assert grid.cell_of(x, y) == 1


def test_the_widened_grid_holds_every_offset_around_its_centre_cell() -> None:
    grid = Grid(0.0, 10.0, -4.0, 2.0, columns=4, rows=3, obstacles=((1.0, -3.0, 2.0, -2.0),))
    wide = grid.widened()
    assert wide.shape == (5, 7)
    assert (wide.cell_width_m, wide.cell_height_m) == (grid.cell_width_m, grid.cell_height_m)
    assert wide.obstacles == ()
    # its centre cell is the grid's first cell; the grid's last cell is (n - 1, m - 1) cells from it
    centre = wide.size // 2
    assert wide.row_col(centre) == (2, 3)
    assert wide.centre(centre) == grid.centre(0)
    row, col = wide.row_col(wide.cell_of(*grid.centre(grid.size - 1)))
    assert (row, col) == (4, 6)


def test_rows_and_columns_of_many_points_follow_the_one_point_rule() -> None:
    grid = Grid(0.0, 10.0, -4.0, 2.0, columns=4, rows=3)
    # boundaries (western / northern cell), the corners and points beyond the area (clamped)
    x = np.array([0.0, 2.5, 2.6, 10.0, -3.0, 12.0, 7.4])
    y = np.array([2.0, -2.0, -2.1, -4.0, 5.0, -9.0, 0.3])
    rows, cols = grid.rows_columns_of(x, y)
    assert rows.tolist() == [grid.row_of(v) for v in y]
    assert cols.tolist() == [grid.column_of(v) for v in x]
