import math

import numpy as np
import pytest

from service.core.config import PlanningConfig
from service.core.grid import Grid
from service.core.mapping.belief import FloatArray
from service.core.mapping.mapper import SourceMapper
from service.core.planning.apf import ApfPlanner, active_window, apf_force
from service.core.planning.base import PlanContext, VehicleState
from service.core.planning.safety import is_safe_point

G3 = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3)  # 1 m cells, centres 0.5, 1.5, 2.5


class FixedMap(SourceMapper):
    """A mapper whose source map is set by the test."""

    name = "fixed"

    def set(self, pi: FloatArray) -> None:
        self._pi = pi

    def _assimilate(self, cell: int, detected: bool, at: tuple[float, float]) -> None:
        pass

    def detection_likelihood(self, cell: int) -> FloatArray:
        return np.zeros(self.grid.shape)


def window_map() -> np.ndarray:
    lv = np.zeros(G3.shape)
    lv[1, 2] = 0.2  # East of the centre, d = 1
    lv[2, 1] = 0.1  # North, d = 1
    lv[2, 2] = 0.4  # North-East, d = sqrt(2)
    lv[1, 1] = 0.3  # the vehicle's own cell: d = 0, no direction, no force
    return lv


def test_hand_worked_window() -> None:
    # F_i = LV_i / d * (X_i - X_v) / d (attractive), summed:
    #   E (0.2, 0) + N (0, 0.1) + NE 0.4 / sqrt(2) * (1, 1) / sqrt(2) = (0.2, 0.2)  ->  (0.4, 0.3)
    f = apf_force(G3, window_map(), 1.5, 1.5, 3)
    assert (f.fx, f.fy) == pytest.approx((0.4, 0.3))
    assert f.magnitude == pytest.approx(0.5)
    assert math.degrees(f.heading_rad) == pytest.approx(math.degrees(math.atan2(3, 4)))  # 36.87 deg
    assert f.total == pytest.approx(0.2 + 0.1 + 0.4 / math.sqrt(2))
    assert f.speed_fraction == pytest.approx(0.5 / (0.3 + 0.4 / math.sqrt(2)))


def test_force_is_attractive_toward_likely_cells() -> None:
    lv = np.zeros(G3.shape)
    lv[1, 0] = 1.0  # West
    f = apf_force(G3, lv, 1.5, 1.5, 3)
    assert f.fx < 0.0
    assert f.fy == pytest.approx(0.0)
    assert f.speed_fraction == pytest.approx(1.0)


def test_opposite_pulls_cancel() -> None:
    lv = np.zeros(G3.shape)
    lv[1, 0] = lv[1, 2] = 0.5
    f = apf_force(G3, lv, 1.5, 1.5, 3)
    assert f.magnitude == pytest.approx(0.0)
    assert f.speed_fraction == pytest.approx(0.0)


def test_window_is_centred_and_w_cells_wide() -> None:
    g = Grid(0.0, 10.0, 0.0, 10.0, columns=10, rows=10)
    rows, cols = active_window(g, 4.2, 6.7, 4)  # x in [2.2, 6.2): centres 2.5 .. 5.5
    assert (cols.start, cols.stop) == (2, 6)
    assert (rows.start, rows.stop) == (5, 9)  # y in [4.7, 8.7): centres 5.5 .. 8.5
    rows, cols = active_window(g, 0.3, 9.9, 3)  # clipped at the area's edge
    assert (cols.start, cols.stop) == (0, 2)
    assert (rows.start, rows.stop) == (8, 10)
    # cells outside the window do not pull
    lv = np.zeros(g.shape)
    lv[0, 9] = 1.0
    assert apf_force(g, lv, 1.5, 8.5, 4).magnitude == 0.0


def test_obstacle_repulsion_by_hand() -> None:
    # one obstacle cell East of the vehicle at d = 1, range 2: push = gain * A * (2 / 1 - 1) = A
    g = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3, obstacles=((2.2, 1.2, 2.8, 1.8),))
    lv = np.zeros(g.shape)
    lv[2, 1] = 0.5  # North, d = 1: A = 0.5
    lv[1, 2] = 9.0  # the obstacle cell itself does not attract
    f = apf_force(g, lv, 1.5, 1.5, 3, obstacle_gain=1.0, obstacle_range_m=2.0)
    assert (f.fx, f.fy) == pytest.approx((-0.5, 0.5))
    assert f.total == pytest.approx(1.0)
    # out of range: no push
    far = apf_force(g, lv, 1.5, 1.5, 3, obstacle_gain=1.0, obstacle_range_m=1.0)
    assert (far.fx, far.fy) == pytest.approx((0.0, 0.5))


def context(grid: Grid, pi: np.ndarray, x: float, y: float) -> PlanContext:
    mapper = FixedMap(grid)
    mapper.set(pi)
    return PlanContext(VehicleState(x, y), grid.cell_of(x, y), 0, mapper)


def test_planner_steps_along_the_resultant() -> None:
    config = PlanningConfig(apf_window=3, apf_step_m=1.0)
    ctx = context(G3, window_map(), 1.5, 1.5)
    plan = ApfPlanner(G3, config).plan(ctx)
    fraction = 0.5 / (0.3 + 0.4 / math.sqrt(2))
    (wp,) = plan.waypoints
    assert (wp.x, wp.y) == pytest.approx((1.5 + fraction * 0.8, 1.5 + fraction * 0.6))
    assert plan.cells == (G3.cell_of(wp.x, wp.y),)


def test_planner_never_steps_into_an_obstacle() -> None:
    # the map pulls East, straight into an obstacle: the best-aligned admissible neighbour instead
    g = Grid(0.0, 5.0, 0.0, 5.0, columns=5, rows=5, obstacles=((3.0, 1.0, 4.0, 4.0),))
    pi = np.zeros(g.shape)
    pi[2, 4] = 1.0
    pi[3, 3] = 0.01
    config = PlanningConfig(apf_window=5, apf_step_m=2.0, apf_obstacle_gain=0.0)
    plan = ApfPlanner(g, config).plan(context(g, pi, 2.5, 2.5))
    (wp,) = plan.waypoints
    assert is_safe_point(g, wp.x, wp.y)
    assert plan.cells[0] in (g.cell_of(2.5, 3.5), g.cell_of(2.5, 1.5))  # North or South of it


def test_planner_holds_in_a_balanced_field() -> None:
    lv = np.zeros(G3.shape)
    lv[1, 0] = lv[1, 2] = 0.5
    plan = ApfPlanner(G3, PlanningConfig(apf_window=3)).plan(context(G3, lv, 1.5, 1.5))
    assert [(w.x, w.y) for w in plan.waypoints] == [(1.5, 1.5)]
