import itertools

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.mapping.transport import paper_vector, substep_matrix, tick_matrix, transition

PAPER = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)
SMALL = Grid(0.0, 12.0, 0.0, 10.0, columns=6, rows=5)


@pytest.mark.parametrize(("ux", "uy"), list(itertools.product([-1.3, 0.0, 0.7], [-2.1, 0.0, 3.0])))
def test_app2_stencil_for_every_sign_case(ux: float, uy: float) -> None:
    # App. II: a = [1 - |c_x|, |c_x|] (x) [1 - |c_y|, |c_y|], toward the flow's side
    step = transition(PAPER, ux, uy, dt_s=1.0)
    cx, cy = ux / 2.5, uy / 4.0
    wx = {-1: max(-cx, 0.0), 0: 1 - abs(cx), 1: max(cx, 0.0)}
    wy = {-1: max(-cy, 0.0), 0: 1 - abs(cy), 1: max(cy, 0.0)}
    stencil = step.stencil()
    for dx, dy in itertools.product((-1, 0, 1), repeat=2):
        assert stencil[dy + 1, dx + 1] == pytest.approx(wx[dx] * wy[dy], abs=1e-15)
    assert step.substeps == 1


def test_rows_sum_to_one_with_c0_and_nine_nonzeros() -> None:
    for ux, uy, sigma in [(1.0, 0.5, 0.0), (-2.0, 3.0, 0.8), (0.0, 0.0, 2.0), (4.0, -7.0, 1.0)]:
        step = transition(PAPER, ux, uy, 1.0, sigma, sigma)
        a = substep_matrix(PAPER, step)
        np.testing.assert_allclose(np.asarray(a.sum(axis=1)).ravel(), 1.0, atol=1e-12)
        assert np.diff(a.indptr).max() <= 9
        assert a[0, 0] == 1.0  # C0 keeps what leaves
        pi = np.full(PAPER.size, 1.0 / PAPER.size)
        with_source = substep_matrix(PAPER, step, pi=pi)
        assert with_source[0].sum() == pytest.approx(1.0)  # a_0j = pi_j (§III-C)
        whole = tick_matrix(PAPER, step)
        np.testing.assert_allclose(np.asarray(whole.sum(axis=1)).ravel(), 1.0, atol=1e-12)


def test_odour_leaving_goes_to_c0() -> None:
    step = transition(PAPER, 1.0, 0.0, 1.0)
    a = substep_matrix(PAPER, step)
    east_edge = 40  # C40: i = m
    assert a[east_edge, 0] == pytest.approx(0.4)
    assert a[east_edge, east_edge] == pytest.approx(0.6)


def test_push_and_pull_equal_the_sparse_matrix() -> None:
    rng = np.random.default_rng(3)
    for ux, uy, sigma in [(1.7, -0.4, 0.0), (-3.0, 5.5, 0.9), (0.2, 0.1, 2.5)]:
        step = transition(SMALL, ux, uy, 1.0, sigma, 0.5 * sigma)
        a = tick_matrix(SMALL, step)[1:, 1:].toarray()  # A-bar
        field = rng.random(SMALL.shape)
        np.testing.assert_allclose(paper_vector(SMALL, step.push(field)), paper_vector(SMALL, field) @ a)
        np.testing.assert_allclose(paper_vector(SMALL, step.pull(field)), a @ paper_vector(SMALL, field))


def test_substeps_keep_the_drift_and_spread() -> None:
    g = Grid(0.0, 200.0, 0.0, 200.0, columns=200, rows=200)
    ux, uy, dt, sigma = 3.6, -2.2, 1.0, 1.5
    step = transition(g, ux, uy, dt, sigma, sigma)
    assert step.substeps >= 4  # |u| dt = 3.6 cells and sigma^2 dt = 2.25 cells^2 need sub-steps
    field = np.zeros(g.shape)
    field[100, 100] = 1.0
    out = step.push(field)
    assert out.sum() == pytest.approx(1.0)
    rows, cols = np.indices(g.shape)
    mean_x = (out * cols).sum() - 100
    mean_y = (out * rows).sum() - 100
    assert mean_x == pytest.approx(ux * dt)
    assert mean_y == pytest.approx(uy * dt)
    var_x = (out * (cols - 100 - mean_x) ** 2).sum()
    assert var_x == pytest.approx(sigma**2 * dt)


def test_invalid_flow_rejected() -> None:
    with pytest.raises(ValueError, match="finite"):
        transition(PAPER, float("nan"), 0.0, 1.0)
    with pytest.raises(ValueError, match="non-negative"):
        transition(PAPER, 0.0, 0.0, -1.0)


def test_no_negative_weight_from_rounding() -> None:
    # drifts whose upflow weight is 0 exactly in real arithmetic, over many speeds and cell sizes
    rng = np.random.default_rng(5)
    for _ in range(2000):
        step = transition(PAPER, *rng.uniform(-6.0, 6.0, 2), dt_s=float(rng.uniform(0.1, 3.0)))
        for kernel in (step.x, step.y):
            assert min(kernel.weights) >= 0.0
