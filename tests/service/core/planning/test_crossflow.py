import math

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.planning.base import Waypoint
from service.core.planning.crossflow import FlowFrame, pass_across, upflow_cells, upflow_until

GRID = Grid(0.0, 20.0, 0.0, 10.0, columns=10, rows=5)  # 2 x 2 m cells: half-cell steps of 1 m
EAST = FlowFrame(1.0, 0.0)  # upflow is toward -x


def test_the_walk_returns_the_first_point_upflow_where_done_holds() -> None:
    seen: list[float] = []

    def done(x: float, y: float) -> bool:
        seen.append(x)
        return x <= 12.5

    assert upflow_until(GRID, 17.0, 5.0, EAST, 3.0, done) == (12.0, 5.0)
    assert seen == [14.0, 13.0, 12.0]


def test_the_walk_gives_up_where_the_line_leaves_the_area() -> None:
    assert upflow_until(GRID, 3.0, 5.0, EAST, 0.0, lambda x, y: False) is None
    assert upflow_until(GRID, 3.0, 5.0, EAST, 5.0, lambda x, y: True) is None


def test_a_pass_across_the_flow_goes_left_then_right_of_it() -> None:
    # flow East: left of it is North (+y); the cell centres span y 1..9
    assert pass_across(GRID, 9.0, 5.0, EAST, 3.0) == (Waypoint(9.0, 8.0), Waypoint(9.0, 2.0))


def test_a_pass_across_the_flow_is_clipped_to_the_cell_centres() -> None:
    assert pass_across(GRID, 9.0, 7.0, EAST, 3.0) == (Waypoint(9.0, 9.0), Waypoint(9.0, 4.0))
    north = FlowFrame(0.0, 1.0)  # left of it is West (-x); the centres span x 1..19
    assert pass_across(GRID, 1.0, 5.0, north, 3.0) == (Waypoint(1.0, 5.0), Waypoint(4.0, 5.0))
    with pytest.raises(ValueError, match="positive"):
        pass_across(GRID, 9.0, 5.0, EAST, 0.0)


def test_the_cells_upflow_of_a_point_take_the_slack_downflow() -> None:
    # flow East: columns centred at x = 1, 3, ..., 19; from x = 10 with 1.5 m slack, x <= 11.5
    assert upflow_cells(GRID, EAST, 10.0, 5.0, 1.5).tolist() == [[True] * 6 + [False] * 4] * 5
    # flow North-East: a cell's along-flow coordinate is (x - 10 + y - 5) / sqrt(2)
    north_east = FlowFrame(math.sqrt(0.5), math.sqrt(0.5))
    mask = upflow_cells(GRID, north_east, 10.0, 5.0, 0.0)
    xs, ys = np.meshgrid(GRID.x_centres, GRID.y_centres)
    assert (mask == (xs + ys <= 15.0)).all()
    assert mask.shape == GRID.shape
