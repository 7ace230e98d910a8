import itertools
import math

import numpy as np

from service.core.grid import Grid
from service.core.mapping import MAPPERS, make_mapper
from service.core.mapping.bayes import BayesMapper
from service.core.mapping.mapper import WIDE_SPREAD, MapperParams
from service.core.observation import Observation

SMALL = Grid(0.0, 12.0, 0.0, 8.0, columns=6, rows=4)
FIELD = Grid(0.0, 100.0, -50.0, 50.0, columns=50, rows=50)


def phi(z: float) -> float:
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))


def cell_mass(lo: float, hi: float, mean: float, spread: float) -> float:
    return phi((hi - mean) / spread) - phi((lo - mean) / spread)


def expected_filaments(grid: Grid, obs: list[Observation], window: int, sx: float, sy: float) -> np.ndarray:
    """eq. 5 cell by cell and release time by release time, from the raw observations."""
    last = obs[-1]
    col = int((last.x - grid.x_min) // grid.cell_width_m)
    row = int((last.y - grid.y_min) // grid.cell_height_m)
    xv = grid.x_min + (col + 0.5) * grid.cell_width_m
    yv = grid.y_min + (row + 0.5) * grid.cell_height_m
    # interval k (between observations k-1 and k) carries observation k's flow
    steps = [(b.time_s - a.time_s, b.flow_x, b.flow_y) for a, b in itertools.pairwise(obs)]
    steps = steps[-window:]
    out = np.zeros(grid.shape)
    for r in range(grid.rows):
        for c in range(grid.columns):
            x0, y0 = grid.x_min + c * grid.cell_width_m, grid.y_min + r * grid.cell_height_m
            lag = vx = vy = 0.0
            for dt, ux, uy in reversed(steps):
                lag, vx, vy = lag + dt, vx + ux * dt, vy + uy * dt
                px = cell_mass(x0, x0 + grid.cell_width_m, xv - vx, sx * math.sqrt(lag))
                py = cell_mass(y0, y0 + grid.cell_height_m, yv - vy, sy * math.sqrt(lag))
                out[r, c] += px * py
    return out


def history_then(mapper: BayesMapper, ticks: int, flow: tuple[float, float]) -> float:
    """Fill the flow history with the vehicle outside the area (nothing fused); returns the next time."""
    for t in range(ticks):
        assert not mapper.update(Observation(float(t), -10.0, -60.0, flow[0], flow[1], False))
    return float(ticks)


def test_registered() -> None:
    assert MAPPERS["bayes"] is BayesMapper
    assert isinstance(make_mapper("bayes", SMALL), BayesMapper)


def test_event_likelihood_is_eq5_summed_cell_by_cell() -> None:
    rng = np.random.default_rng(3)
    params = MapperParams(window=7, sigma_x=0.7, sigma_y=0.4)
    mapper = BayesMapper(SMALL, params)
    times = np.cumsum(rng.uniform(0.3, 1.8, size=11))
    obs = [
        Observation(float(t), float(x), float(y), float(ux), float(uy), False)
        for t, x, y, (ux, uy) in zip(
            times, rng.uniform(-3, 15, 11), rng.uniform(-2, 10, 11), rng.normal(0, 1.5, (11, 2)), strict=True
        )
    ]
    obs[-1] = Observation(obs[-1].time_s, 8.7, 5.1, obs[-1].flow_x, obs[-1].flow_y, False)
    for o in obs:
        mapper.update(o)
    expect = expected_filaments(SMALL, obs, 7, 0.7, 0.4)
    np.testing.assert_allclose(
        mapper.event_likelihood(SMALL.cell_of(8.7, 5.1)), expect, rtol=1e-12, atol=1e-15
    )


def test_update_is_bayes_rule_with_capped_expected_count() -> None:
    # narrow filaments and a slow flow: the expected count exceeds 1 near the vehicle
    params = MapperParams(window=20, sigma_x=0.3, sigma_y=0.3, mu=0.8, false_alarm=0.01)
    obs = [Observation(float(t), -10.0, -60.0, 0.2, 0.1, False) for t in range(15)]
    obs.append(Observation(15.0, 6.5, 3.5, 0.2, 0.1, True))
    for detected in (True, False):
        mapper = BayesMapper(SMALL, params)
        obs[-1] = Observation(15.0, 6.5, 3.5, 0.2, 0.1, detected)
        for o in obs:
            mapper.update(o)
        count = expected_filaments(SMALL, obs, 20, 0.3, 0.3)
        assert count.max() > 1.0
        hit = 0.01 + 0.99 * 0.8 * np.minimum(count, 1.0)
        likelihood = hit if detected else 1.0 - hit
        np.testing.assert_allclose(mapper.likelihood, likelihood / likelihood.sum(), rtol=1e-12)
        np.testing.assert_allclose(mapper.detection_likelihood(SMALL.cell_of(6.5, 3.5)), hit, rtol=1e-12)


def test_non_detection_removes_mass_just_upflow() -> None:
    mapper = BayesMapper(FIELD, MapperParams(window=40))
    t = history_then(mapper, 40, (1.0, 0.0))
    mapper.update(Observation(t, 61.0, 1.0, 1.0, 0.0, False))
    pi = mapper.likelihood
    row, col = FIELD.row_col(FIELD.cell_of(61.0, 1.0))
    uniform = 1.0 / FIELD.size
    for upflow in (2, 5, 10):  # 4, 10 and 20 m upflow of the vehicle
        assert pi[row, col - upflow] < 0.75 * uniform
        assert pi[row, col - upflow] < pi[row, col + upflow]
    assert pi[row, col + 10] > uniform  # downflow cells cannot explain a miss: they gain
    assert pi[row + 20, col] > uniform  # nor can cells far across the flow


def test_a_wide_share_mixes_the_capped_counts_of_two_plumes() -> None:
    """Two-plume eq. W1 in the Bayesian model: q = (1 - w) min(1, L_narrow) + w min(1, L_wide), with
    L the eq. 5 count of a plume spreading at sigma and at WIDE_SPREAD x sigma."""
    w = 0.3
    params = MapperParams(window=20, sigma_x=0.3, sigma_y=0.3, mu=0.8, false_alarm=0.01, wide_share=w)
    obs = [Observation(float(t), -10.0, -60.0, 0.2, 0.1, False) for t in range(15)]
    obs.append(Observation(15.0, 6.5, 3.5, 0.2, 0.1, True))
    mapper = BayesMapper(SMALL, params)
    for o in obs:
        mapper.update(o)
    narrow = np.minimum(expected_filaments(SMALL, obs, 20, 0.3, 0.3), 1.0)
    wide = np.minimum(expected_filaments(SMALL, obs, 20, 0.3 * WIDE_SPREAD, 0.3 * WIDE_SPREAD), 1.0)
    assert not np.allclose(narrow, wide)
    hit = 0.01 + 0.99 * 0.8 * ((1.0 - w) * narrow + w * wide)
    np.testing.assert_allclose(mapper.likelihood, hit / hit.sum(), rtol=1e-12)
