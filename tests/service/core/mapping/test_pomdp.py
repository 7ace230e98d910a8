import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.mapping import MAPPERS, make_mapper
from service.core.mapping.bayes import BayesMapper
from service.core.mapping.filament import filament_factors, release_offsets
from service.core.mapping.mapper import WIDE_SPREAD, FlowStep, MapperParams
from service.core.mapping.pomdp import (
    BOX_GROUP_MOST,
    BOX_GROUP_WASTE,
    WHOLE_DIRECT_SIZE,
    PomdpMapper,
    _box_groups,
    log_non_detection,
    series_terms,
)
from service.core.mapping.transport import transition
from service.core.observation import Observation

SMALL = Grid(0.0, 12.0, 0.0, 8.0, columns=6, rows=4)
FIELD = Grid(0.0, 100.0, -50.0, 50.0, columns=50, rows=50)


def phi(z: float) -> float:
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))


def cell_mass(lo: float, hi: float, mean: float, spread: float) -> float:
    return phi((hi - mean) / spread) - phi((lo - mean) / spread)


def non_detection(grid: Grid, obs: list[Observation], params: MapperParams) -> np.ndarray:
    """gamma_ij of eq. 2 cell by cell, as a product over release times, from the raw observations."""
    last = obs[-1]
    col = int((last.x - grid.x_min) // grid.cell_width_m)
    row = int((last.y - grid.y_min) // grid.cell_height_m)
    xv = grid.x_min + (col + 0.5) * grid.cell_width_m
    yv = grid.y_min + (row + 0.5) * grid.cell_height_m
    steps = [(b.time_s - a.time_s, b.flow_x, b.flow_y) for a, b in itertools.pairwise(obs)]
    steps = steps[-params.window :]
    out = np.ones(grid.shape)
    for r in range(grid.rows):
        for c in range(grid.columns):
            x0, y0 = grid.x_min + c * grid.cell_width_m, grid.y_min + r * grid.cell_height_m
            lag = vx = vy = 0.0
            for dt, ux, uy in reversed(steps):
                lag, vx, vy = lag + dt, vx + ux * dt, vy + uy * dt
                px = cell_mass(x0, x0 + grid.cell_width_m, xv - vx, params.sigma_x * math.sqrt(lag))
                py = cell_mass(y0, y0 + grid.cell_height_m, yv - vy, params.sigma_y * math.sqrt(lag))
                out[r, c] *= 1.0 - params.mu * px * py
    return out


def history_then(mapper: PomdpMapper | BayesMapper, ticks: int, flow: tuple[float, float]) -> float:
    """Fill the flow history with the vehicle outside the area (nothing fused); returns the next time."""
    for t in range(ticks):
        assert not mapper.update(Observation(float(t), -10.0, -60.0, flow[0], flow[1], False))
    return float(ticks)


def test_registered() -> None:
    assert MAPPERS["pomdp"] is PomdpMapper
    assert isinstance(make_mapper("pomdp", SMALL), PomdpMapper)


@pytest.mark.parametrize("detected", [True, False])
def test_update_is_eq6_with_the_eq2_product(detected: bool) -> None:
    rng = np.random.default_rng(5)
    params = MapperParams(window=9, sigma_x=0.5, sigma_y=0.8, mu=0.85, false_alarm=0.02)
    mapper = PomdpMapper(SMALL, params)
    times = np.cumsum(rng.uniform(0.3, 1.8, size=14))
    flows = rng.normal(0, 1.0, (14, 2))
    obs = [
        Observation(float(t), -5.0, -5.0, float(ux), float(uy), False)
        for t, (ux, uy) in zip(times, flows, strict=True)
    ]
    obs[-1] = Observation(obs[-1].time_s, 8.7, 5.1, obs[-1].flow_x, obs[-1].flow_y, detected)
    for o in obs:
        mapper.update(o)
    gamma = non_detection(SMALL, obs, params)
    assert gamma.min() < 0.5  # some source cells would very likely have been seen
    cell = SMALL.cell_of(8.7, 5.1)
    np.testing.assert_allclose(np.exp(mapper.log_gamma(cell)), gamma, rtol=1e-12)
    hit = 1.0 - 0.98 * gamma
    np.testing.assert_allclose(mapper.detection_likelihood(cell), hit, rtol=1e-12)
    likelihood = hit if detected else 1.0 - hit
    np.testing.assert_allclose(mapper.likelihood, likelihood / likelihood.sum(), rtol=1e-12)


def test_series_terms_meet_their_tolerance() -> None:
    peaks = np.concatenate([np.geomspace(1e-14, 0.5, 200), [0.0, 0.6, 0.99, 1.0]])
    terms = series_terms(peaks, 1e-12)
    for a, k in zip(peaks, terms, strict=True):
        if a > 0.5:
            assert k == 0
        elif k > 0:
            partial = -sum(a**j / j for j in range(1, k + 1))
            assert abs(partial - math.log1p(-a)) <= 1e-12
    assert terms[0] == 1
    assert (terms[:200] > 0).sum() > 150  # most small peaks go by the series


def random_factors(
    rng: np.random.Generator, grid: Grid, window: int, dt: tuple[float, float], sigma: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    steps = rng.uniform(*dt, size=window)
    steps[0] = dt[0]  # the shortest lag, where the filament is most concentrated
    lag = np.cumsum(steps)
    flow = rng.normal(0.0, 1.5, size=(window, 2)) + rng.normal(0.0, 1.0, size=2)
    drift = np.cumsum(flow * steps[:, None], axis=0)
    x = rng.uniform(grid.x_min, grid.x_max)
    y = rng.uniform(grid.y_min, grid.y_max)
    return filament_factors(grid, x, y, lag, drift[:, 0], drift[:, 1], *sigma)


CASES = {
    "1 m cells, mixed lags": (Grid(0, 100, -50, 50, 100, 100), 200, (0.2, 2.0), (1.0, 1.0), 0.9),
    "fine cells, long lags": (Grid(0, 100, -50, 50, 200, 160), 150, (0.5, 3.0), (1.5, 0.7), 0.9),
    "large cells": (Grid(0, 400, 0, 400, 40, 40), 200, (0.1, 1.0), (0.5, 0.3), 0.9),
    "large cells, mu = 1": (Grid(0, 400, 0, 300, 40, 30), 200, (0.1, 1.0), (0.2, 0.2), 1.0),
    "strips": (Grid(0, 300, 0, 10, 600, 4), 120, (0.05, 1.0), (0.8, 0.1), 0.95),
}


@pytest.mark.parametrize("case", CASES)
def test_fast_log_gamma_matches_the_naive_sum(case: str) -> None:
    grid, window, dt, sigma, mu = CASES[case]
    assert window * grid.size > WHOLE_DIRECT_SIZE  # the split path, not the small-problem one
    rng = np.random.default_rng(abs(hash(case)) % 2**32)
    for _ in range(3):
        px, py = random_factors(rng, grid, window, dt, sigma)
        with np.errstate(divide="ignore"):
            naive = np.log1p(-mu * py[:, :, None] * px[:, None, :]).sum(axis=0)
        fast = log_non_detection(px, py, mu, np.ones(window))
        np.testing.assert_allclose(np.exp(fast), np.exp(naive), rtol=0, atol=1e-9)
        seen = np.isfinite(naive)
        np.testing.assert_array_equal(np.isfinite(fast), seen)
        np.testing.assert_allclose(fast[seen], naive[seen], rtol=1e-9, atol=1e-10)


def test_weighted_release_times_count_as_often_as_their_weight() -> None:
    # a release of weight w adds w log(1 - mu px py), on both the series and the direct path
    grid, window, dt, sigma, mu = CASES["1 m cells, mixed lags"]
    rng = np.random.default_rng(11)
    px, py = random_factors(rng, grid, window, dt, sigma)
    weight = rng.integers(1, 5, window).astype(float)
    with np.errstate(divide="ignore"):
        naive = np.tensordot(weight, np.log1p(-mu * py[:, :, None] * px[:, None, :]), axes=1)
    fast = log_non_detection(px, py, mu, weight)
    np.testing.assert_allclose(fast, naive, rtol=1e-9, atol=1e-9)
    # weight 2 is the same release listed twice
    twice = log_non_detection(np.repeat(px, 2, axis=0), np.repeat(py, 2, axis=0), mu, np.ones(2 * window))
    np.testing.assert_allclose(
        log_non_detection(px, py, mu, np.full(window, 2.0)), twice, rtol=1e-9, atol=1e-9
    )


@pytest.mark.parametrize("speed", [0.3, 1.0])
def test_the_merged_prehistory_predicts_what_every_release_does(speed: float) -> None:
    # eq. R1 against one release per prehistoric tick: P(detection) within 1 % wherever it is above
    # 1e-3, for the narrow plume and the wide one, in a slow flow (most merged) and a 1 m/s one
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=80, rows=100)
    rng = np.random.default_rng(2)
    angle = 0.3 + np.cumsum(rng.normal(0.0, 0.05, 50))
    history = [
        FlowStep(
            transition(grid, speed * math.cos(a), speed * math.sin(a), 1.0, 0.2, 0.2),
            speed * math.cos(a),
            speed * math.sin(a),
            1.0,
        )
        for a in angle
    ]
    reach = math.hypot(100.0, 100.0)
    for sigma in (0.2, 0.2 * WIDE_SPREAD):
        merged = release_offsets(history, reach, sigma)
        every = release_offsets(history, reach)
        assert merged[3].sum() == len(every[0])
        if speed < 0.5:
            assert len(merged[0]) < len(every[0]) / 2
        chances = []
        for lag, dx, dy, weight in (merged, every):
            px, py = filament_factors(
                grid, 80.0, 5.0, lag, dx, dy, sigma, sigma, footprint_m=0.8, footprint_growth=0.1
            )
            chances.append(-np.expm1(log_non_detection(px, py, 0.9, weight)))
        seen = chances[1] > 1e-3
        np.testing.assert_allclose(chances[0][seen], chances[1][seen], rtol=0.01)


def test_box_groups_cover_each_lag_once_within_the_waste_bound() -> None:
    rng = np.random.default_rng(3)
    count = 200
    # boxes that drift and grow from one lag to the next, as a filament's do, with a few jumps
    r0 = np.cumsum(rng.integers(0, 2, count)) + rng.integers(0, 3, count)
    c0 = np.cumsum(rng.integers(0, 3, count))
    c0[rng.integers(0, count, 5)] += 40
    r1 = r0 + 3 + np.arange(count) // 10
    c1 = c0 + 2 + np.arange(count) // 8
    lags = np.flatnonzero(rng.random(count) < 0.8)
    groups = _box_groups(lags, r0, r1, c0, c1)
    flat = [lag for run, _, _ in groups for lag in run]
    assert flat == lags.tolist()  # every lag once, in order
    assert 1 < len(groups) < len(lags) // 2
    for run, rows, cols in groups:
        assert len(run) <= BOX_GROUP_MOST
        for lag in run:  # the union holds each member's own box
            assert rows.start <= r0[lag] < r1[lag] <= rows.stop
            assert cols.start <= c0[lag] < c1[lag] <= cols.stop
        own = sum(int((r1[lag] - r0[lag]) * (c1[lag] - c0[lag])) for lag in run)
        union = (rows.stop - rows.start) * (cols.stop - cols.start)
        assert union * len(run) <= BOX_GROUP_WASTE * own
    assert _box_groups(np.array([], dtype=np.intp), r0, r1, c0, c1) == []


def test_naive_cases_cover_both_paths() -> None:
    rng = np.random.default_rng(0)
    grid, window, dt, sigma, mu = CASES["1 m cells, mixed lags"]
    px, py = random_factors(rng, grid, window, dt, sigma)
    terms = series_terms(mu * px.max(axis=1) * py.max(axis=1))
    assert terms[0] == 0  # the shortest lag is concentrated: evaluated directly on its box
    assert (terms > 0).sum() > window // 2  # long lags: by the series


def test_mu_one_filament_certainly_there_rules_the_cell_out() -> None:
    # zero spread: a filament released 1 s ago from C_i is certainly in the vehicle's cell
    grid = Grid(0, 10, 0, 10, 10, 10)
    params = MapperParams(window=5, sigma_x=0.0, sigma_y=0.0, mu=1.0, false_alarm=0.0)
    mapper = PomdpMapper(grid, params)
    mapper.update(Observation(0.0, 5.5, 5.5, 2.0, 0.0, False))
    mapper.update(Observation(1.0, 5.5, 5.5, 2.0, 0.0, False))
    pi = mapper.likelihood
    assert pi[5, 3] == 0.0  # two cells upflow
    assert pi.sum() == pytest.approx(1.0)
    assert pi.max() == pytest.approx(1.0 / 99)


def test_non_detection_removes_mass_just_upflow() -> None:
    mapper = PomdpMapper(FIELD, MapperParams(window=40))
    t = history_then(mapper, 40, (1.0, 0.0))
    mapper.update(Observation(t, 61.0, 1.0, 1.0, 0.0, False))
    pi = mapper.likelihood
    row, col = FIELD.row_col(FIELD.cell_of(61.0, 1.0))
    uniform = 1.0 / FIELD.size
    for upflow in (2, 5, 10):  # 4, 10 and 20 m upflow of the vehicle
        assert pi[row, col - upflow] < 0.75 * uniform
        assert pi[row, col - upflow] < pi[row, col + upflow]
    assert pi[row, col + 10] > uniform
    assert pi[row + 20, col] > uniform


def test_agrees_with_bayes_where_filaments_are_unlikely() -> None:
    # 1 - prod(1 - mu p_l) = mu sum p_l to first order: the two models differ only near the vehicle
    params = MapperParams(window=40, false_alarm=0.0)
    pomdp, bayes = PomdpMapper(FIELD, params), BayesMapper(FIELD, params)
    history_then(pomdp, 40, (0.8, -0.3))
    history_then(bayes, 40, (0.8, -0.3))
    cell = FIELD.cell_of(61.0, 1.0)
    hit_pomdp, hit_bayes = pomdp.detection_likelihood(cell), bayes.detection_likelihood(cell)
    faint = (hit_bayes > 1e-6) & (hit_bayes < 1e-3)
    assert faint.sum() > 100
    np.testing.assert_allclose(hit_pomdp[faint], hit_bayes[faint], rtol=2e-3)
    assert (hit_pomdp <= hit_bayes + 1e-15).all()  # 1 - prod(1 - x_l) <= sum x_l


@pytest.mark.parametrize("detected", [True, False])
def test_a_wide_share_mixes_the_narrow_and_the_wide_plume(detected: bool) -> None:
    """Two-plume eq. W1: P(no odour | i) = (1 - w) gamma'_narrow + w gamma'_wide, each gamma' the
    eq. 2 product of a plume (sigma, then WIDE_SPREAD x sigma) with the miss floor r."""
    w, r, pf = 0.3, 0.3, 0.02
    base = MapperParams(window=12, sigma_x=0.3, sigma_y=0.3, mu=0.9, false_alarm=pf, miss_floor=r)
    mixed = PomdpMapper(FIELD, replace(base, wide_share=w))
    history_then(mixed, 12, (1.0, 0.2))
    cell = FIELD.cell_of(61.0, 1.0)
    for spread, mapper in ((1.0, "narrow"), (WIDE_SPREAD, "wide")):
        # the same history under a single plume of that spread, by eq. 2 directly
        single = PomdpMapper(FIELD, replace(base, sigma_x=0.3 * spread, sigma_y=0.3 * spread))
        history_then(single, 12, (1.0, 0.2))
        floored = r + (1.0 - r) * np.exp(single.log_gamma(cell))
        if mapper == "narrow":
            narrow = floored
        else:
            wide = floored
    assert (wide > narrow + 1e-3).any()  # the plumes differ
    assert (narrow > wide + 1e-3).any()
    no_odour = (1.0 - pf) * ((1.0 - w) * narrow + w * wide)
    expected = 1.0 - no_odour if detected else no_odour
    np.testing.assert_allclose(mixed._event_probability(cell, detected), expected, rtol=1e-12)
    # w = 0 is the single narrow plume
    alone = PomdpMapper(FIELD, base)
    history_then(alone, 12, (1.0, 0.2))
    np.testing.assert_allclose(
        alone._event_probability(cell, detected),
        1.0 - (1.0 - pf) * narrow if detected else (1.0 - pf) * narrow,
        rtol=1e-12,
    )


def test_a_detection_beside_the_narrow_plume_points_upflow_with_a_wide_share() -> None:
    """A detection 3 m across the flow from the narrow plume's line of a source: without the wide
    plume only the false-alarm rate explains it for that source; with it, the source gains."""
    params = MapperParams(window=40, sigma_x=0.2, sigma_y=0.2, false_alarm=0.02, miss_floor=0.3,
                          footprint_m=0.8, footprint_growth=0.1)  # fmt: skip
    cell = FIELD.cell_of(61.0, 1.0)
    gains = []
    for w in (0.0, 0.3):
        mapper = PomdpMapper(FIELD, replace(params, wide_share=w))
        history_then(mapper, 40, (1.0, 0.0))
        hit = mapper._event_probability(cell, True, at=(61.0, 1.0))
        row, col = FIELD.row_col(cell)
        # a source 20 m upflow, 3 m across (the rows are 2 m: between one and two rows over)
        beside, on_line = hit[row + 2, col - 10], hit[row, col - 10]
        gains.append(beside / hit.min())
        assert on_line > beside
    assert gains[1] > 2.0 * gains[0]
