import numpy as np
import pytest

from service.core.grid import Grid
from service.core.mapping.hmm import HmmMapper
from service.core.mapping.mapper import MapperParams
from service.core.mapping.transport import paper_vector, tick_matrix
from service.core.observation import Observation

PAPER = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)


def feed(
    mapper: HmmMapper, ticks: int, x: float, y: float, flow: tuple[float, float], t0: float = 0.0
) -> None:
    for t in range(ticks):
        mapper.update(Observation(t0 + t, x, y, flow[0], flow[1], False))


def test_alpha_peaks_downflow_of_the_source_and_widens() -> None:
    m = HmmMapper(PAPER, MapperParams(sigma_x=0.5, sigma_y=0.5))
    source = PAPER.flat_index(488)
    pi = np.zeros(PAPER.shape)
    pi.flat[source] = 1.0
    m._pi = pi  # a known source, as in Fig. 5
    m._alpha = pi.copy()
    feed(m, 65, x=90.0, y=45.0, flow=(1.0, 0.0))
    alpha = m.plume
    row, col = PAPER.row_col(source)
    peak_row, peak_col = np.unravel_index(np.argmax(alpha), alpha.shape)
    assert peak_row == row
    assert peak_col >= col
    upflow = alpha[:, :col].sum()
    downflow = alpha[:, col + 1 :].sum()
    assert downflow > 10 * upflow
    # crossflow spread grows with downflow distance
    ys = PAPER.y_centres

    def spread(c: int) -> float:
        w = alpha[:, c] / alpha[:, c].sum()
        mean = (w * ys).sum()
        return float(np.sqrt((w * (ys - mean) ** 2).sum()))

    assert spread(col + 3) < spread(col + 10) < spread(col + 20)


def test_beta_bar_is_exact() -> None:
    # eq. 16 with dense matrices on a small grid: mean over F of Phi(t_L, t_F) e_j
    g = Grid(0.0, 15.0, 0.0, 12.0, columns=6, rows=4)
    rng = np.random.default_rng(7)
    m = HmmMapper(g, MapperParams(window=8, sigma_x=0.6, sigma_y=0.3))
    flows = rng.normal(0.0, 2.0, size=(12, 2))
    for t, (ux, uy) in enumerate(flows):
        m.update(Observation(float(t) * 0.8, 7.0, 6.0, float(ux), float(uy), False))
    steps = [s.transition for s in m.history]
    cell = g.cell_of(7.0, 6.0)
    e = np.zeros(g.size)
    e[g.paper_number(cell) - 1] = 1.0
    terms = [e]
    v = e
    for step in reversed(steps):
        v = tick_matrix(g, step)[1:, 1:].toarray() @ v
        terms.append(v)
    expected = np.mean(terms, axis=0)
    np.testing.assert_allclose(paper_vector(g, m.beta_bar(cell)), expected, atol=1e-14)


def test_beta_bar_peaks_upflow_of_a_detection() -> None:
    m = HmmMapper(PAPER, MapperParams(window=50, sigma_x=0.5, sigma_y=0.5))
    feed(m, 60, x=60.0, y=0.0, flow=(1.0, 0.0))
    cell = PAPER.cell_of(60.0, 0.0)
    beta = m.beta_bar(cell)
    _row, col = PAPER.row_col(cell)
    assert beta[:, :col].sum() > 5 * beta[:, col + 1 :].sum()
    centroid_x = (beta.sum(axis=0) * PAPER.x_centres).sum() / beta.sum()
    assert centroid_x < 60.0 - 10.0


def test_detection_moves_mass_upflow_and_non_detection_removes_it() -> None:
    row, col = PAPER.row_col(PAPER.cell_of(60.0, 0.0))
    band = slice(row - 1, row + 2)
    for detected in (True, False):
        m = HmmMapper(PAPER, MapperParams(window=50))
        feed(m, 40, x=-10.0, y=0.0, flow=(1.0, 0.0))  # outside the area: flow history only
        before = m.likelihood.copy()
        m.update(Observation(40.0, 60.0, 0.0, 1.0, 0.0, detected))
        after = m.likelihood
        upflow_gain = after[band, col - 10 : col].sum() - before[band, col - 10 : col].sum()
        if detected:
            assert upflow_gain > 0.05
            assert after[:, col + 1 :].sum() < before[:, col + 1 :].sum()
        else:
            assert upflow_gain < 0.0
            assert after[band, :col].sum() < before[band, :col].sum()


def test_thousands_of_random_updates_stay_a_distribution() -> None:
    g = Grid(-20.0, 20.0, -10.0, 10.0, columns=16, rows=8)
    rng = np.random.default_rng(11)
    m = HmmMapper(g, MapperParams(window=30, sigma_x=0.7, sigma_y=0.7))
    t = 0.0
    for _ in range(2_500):
        t += float(rng.choice([0.2, 1.0, 3.0]))
        flow = rng.normal(0.0, rng.choice([0.0, 1.0, 8.0]), 2)
        m.update(Observation(t, float(rng.uniform(-25, 25)), float(rng.uniform(-12, 12)),
                             float(flow[0]), float(flow[1]), bool(rng.random() < 0.2)))  # fmt: skip
    for field in (m.likelihood, m.plume):
        assert np.isfinite(field).all()
        assert (field >= 0).all()
    assert m.likelihood.sum() == pytest.approx(1.0)
    assert m.plume.sum() <= 1.0 + 1e-9
    assert m.ignored["outside_area"] > 0


def test_time_going_backwards_is_ignored() -> None:
    m = HmmMapper(PAPER)
    assert m.update(Observation(10.0, 50.0, 0.0, 1.0, 0.0, False))
    before = m.likelihood.copy()
    assert not m.update(Observation(9.0, 50.0, 0.0, 1.0, 0.0, True))
    np.testing.assert_array_equal(m.likelihood, before)
    assert m.ignored == {"time_not_increasing": 1}
