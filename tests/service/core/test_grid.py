import numpy as np
import pytest

from service.core.errors import ConfigError, OutsideAreaError
from service.core.grid import Grid

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
