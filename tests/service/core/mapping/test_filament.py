import itertools
import math

import numpy as np
import pytest
from scipy.stats import norm

from service.core.grid import Grid
from service.core.mapping.filament import (
    G_TAIL_Z,
    _normal_cdf_integral,
    filament_factors,
    footprint_mass,
    history_factors,
    release_offsets,
)
from service.core.mapping.mapper import FlowStep
from service.core.mapping.transport import transition

SMALL = Grid(0.0, 10.0, 0.0, 8.0, columns=5, rows=4)


def reference_factor(edges: np.ndarray, vehicle: float, drift: float, spread: float) -> np.ndarray:
    """Gaussian mass of the source position N(vehicle - drift, spread^2) over each [edge, next edge]."""
    dist = norm(loc=vehicle - drift, scale=spread)
    return np.array([dist.cdf(hi) - dist.cdf(lo) for lo, hi in itertools.pairwise(edges)])


def test_factors_match_normal_cdf_per_cell() -> None:
    lag = np.array([0.5, 1.7, 4.0, 9.0])
    drift_x = np.array([0.3, 2.1, 3.9, 7.5])
    drift_y = np.array([-0.4, 0.0, 1.3, -2.2])
    sx, sy = 0.8, 1.3
    x_v, y_v = 7.0, 3.0
    px, py = filament_factors(SMALL, x_v, y_v, lag, drift_x, drift_y, sx, sy)
    assert px.shape == (4, 5)
    assert py.shape == (4, 4)
    x_edges = np.array([0.0, 2.0, 4.0, 6.0, 8.0, 10.0])
    y_edges = np.array([0.0, 2.0, 4.0, 6.0, 8.0])
    for release in range(4):
        spread = math.sqrt(lag[release])
        expect_x = reference_factor(x_edges, x_v, drift_x[release], sx * spread)
        expect_y = reference_factor(y_edges, y_v, drift_y[release], sy * spread)
        np.testing.assert_allclose(px[release], expect_x, rtol=0, atol=1e-14)
        np.testing.assert_allclose(py[release], expect_y, rtol=0, atol=1e-14)


def test_far_tails_keep_relative_precision() -> None:
    # cells 15 to 25 spreads away on both sides: Phi(b) - Phi(a) would cancel to 0 upflow
    g = Grid(-20.0, 20.0, -1.0, 1.0, columns=40, rows=1)
    px, _ = filament_factors(g, 0.5, 0.0, np.array([1.0]), np.array([0.0]), np.array([0.0]), 1.0, 1.0)
    mean = 0.5
    for col in (35, 39):  # x in [15, 16] and [19, 20], above the mean
        lo, hi = -20.0 + col, -19.0 + col
        expect = norm.sf(lo - mean) - norm.sf(hi - mean)
        assert px[0, col] == pytest.approx(expect, rel=1e-10)
        assert px[0, col] > 0.0
    for col in (0, 4):  # x in [-20, -19] and [-16, -15], below the mean
        lo, hi = -20.0 + col, -19.0 + col
        expect = norm.cdf(hi - mean) - norm.cdf(lo - mean)
        assert px[0, col] == pytest.approx(expect, rel=1e-10)


def test_equals_paper_eq1_when_cells_are_small() -> None:
    # pomdp-astar eq. 1 (density at the centres times L_x L_y) is the midpoint rule of our mass
    g = Grid(0.0, 20.0, 0.0, 10.0, columns=80, rows=40)
    lag, sx, sy = 30.0, 0.9, 0.6
    drift = (4.0, 1.5)
    x_v, y_v = 15.125, 5.125
    px, py = filament_factors(
        g, x_v, y_v, np.array([lag]), np.array([drift[0]]), np.array([drift[1]]), sx, sy
    )
    xc = (np.arange(80) + 0.5) * 0.25
    yc = (np.arange(40) + 0.5) * 0.25
    dx = x_v - xc[None, :] - drift[0]
    dy = y_v - yc[:, None] - drift[1]
    eq1 = (
        0.25 * 0.25 / (2 * math.pi * lag * sx * sy)
        * np.exp(-(dx**2) / (2 * lag * sx**2))
        * np.exp(-(dy**2) / (2 * lag * sy**2))
    )  # fmt: skip
    ours = np.outer(py[0], px[0])
    near = eq1 > 1e-3 * eq1.max()
    np.testing.assert_allclose(ours[near], eq1[near], rtol=2e-3)


def test_stays_a_probability_where_eq1_exceeds_one() -> None:
    # 10 m cells, lag 1 s, sigma 1: eq. 1 at delta = 0 gives 100 / (2 pi) ~ 16
    g = Grid(0.0, 50.0, 0.0, 50.0, columns=5, rows=5)
    px, py = filament_factors(g, 25.0, 25.0, np.array([1.0]), np.array([0.0]), np.array([0.0]), 1.0, 1.0)
    p = np.outer(py[0], px[0])
    assert p.max() <= 1.0
    assert p[2, 2] == pytest.approx((norm.cdf(5.0) - norm.cdf(-5.0)) ** 2, rel=1e-12)


def test_mass_is_conserved_inside_the_area_and_lost_outside() -> None:
    g = Grid(0.0, 100.0, 0.0, 100.0, columns=50, rows=50)
    # source means at least 9 spreads inside the area
    lag = np.array([1.0, 10.0, 25.0])
    px, py = filament_factors(g, 50.0, 50.0, lag, np.array([0.0, 20.0, 5.0]), np.zeros(3), 1.0, 1.0)
    np.testing.assert_allclose(px.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(py.sum(axis=1), 1.0, atol=1e-12)
    # drift that puts the source mean outside the western edge: about half the mass is gone
    px, _ = filament_factors(g, 50.0, 50.0, np.array([4.0]), np.array([50.0]), np.zeros(1), 1.0, 1.0)
    assert px.sum() == pytest.approx(0.5, abs=1e-12)


def test_zero_spread_is_a_point_mass() -> None:
    lag = np.array([1.0, 2.0])
    px, py = filament_factors(SMALL, 7.0, 3.0, lag, np.array([2.0, 3.0]), np.array([0.5, 1.0]), 0.0, 0.0)
    # source at x = 5 (column 2), then at x = 4 (the edge between columns 1 and 2)
    np.testing.assert_array_equal(px, [[0, 0, 1, 0, 0], [0, 0.5, 0.5, 0, 0]])
    # source at y = 2.5 (row 1), then at y = 2 (the edge between rows 0 and 1)
    np.testing.assert_array_equal(py, [[0, 1, 0, 0], [0.5, 0.5, 0, 0]])


def test_release_offsets_accumulate_newest_first() -> None:
    def step(dx: float, dy: float, dt: float) -> FlowStep:
        return FlowStep(transition(SMALL, dx / dt, dy / dt, dt), dx, dy, dt)

    history = [step(1.0, 0.5, 1.0), step(2.0, -1.0, 0.5), step(0.25, 0.0, 2.0)]  # oldest first
    lag, sx, sy, weight = release_offsets(history)
    np.testing.assert_array_equal(weight, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(lag, [2.0, 2.5, 3.5])
    np.testing.assert_allclose(sx, [0.25, 2.25, 3.25])
    np.testing.assert_allclose(sy, [0.0, -1.0, -0.5])
    px, py, _ = history_factors(SMALL, SMALL.cell_of(7.0, 3.0), history, 0.5, 0.5)
    expect_x = reference_factor(np.arange(6) * 2.0, 7.0, 2.25, 0.5 * math.sqrt(2.5))
    np.testing.assert_allclose(px[1], expect_x, atol=1e-14)
    assert py.shape == (3, 4)


def test_empty_history_has_no_release_times() -> None:
    px, py, weight = history_factors(SMALL, 0, [], 1.0, 1.0)
    assert weight.shape == (0,)
    assert px.shape == (0, 5)
    assert py.shape == (0, 4)


def _flow_steps(n: int, dx: float) -> list[FlowStep]:
    grid = Grid(0.0, 100.0, -50.0, 50.0, 40, 25)
    step = transition(grid, dx, 0.0, 1.0, 0.2, 0.2)
    return [FlowStep(step, dx, 0.0, 1.0) for _ in range(n)]


def test_the_prehistory_continues_the_record_with_its_mean_step() -> None:
    lag, dx, dy, weight = release_offsets(_flow_steps(3, 1.0), reach_m=10.0)
    np.testing.assert_array_equal(weight, np.ones(10))
    np.testing.assert_allclose(lag, np.arange(1.0, 11.0))
    np.testing.assert_allclose(dx, np.arange(1.0, 11.0))
    np.testing.assert_allclose(dy, 0.0)
    plain = release_offsets(_flow_steps(3, 1.0))
    np.testing.assert_allclose(plain[0], [1.0, 2.0, 3.0])


def test_without_a_flow_there_is_no_prehistory() -> None:
    lag, _, _, _ = release_offsets(_flow_steps(3, 0.0), reach_m=10.0, sigma=0.2)
    assert len(lag) == 3


def test_the_prehistory_is_merged_in_runs_of_half_a_spread() -> None:
    # eq. R1 worked by hand: 0.1 m a tick, sigma 0.2, three ticks of record, ten prehistoric steps.
    # Step k (lag 3 + k) drifts 0.1 / (0.5 x 0.2 sqrt(3 + k)) = 1 / sqrt(3 + k) of a run: running
    # sums 0.50 0.95 1.36 1.73 2.09 2.42 2.74 3.04 3.33 3.60, so runs {1, 2} {3, 4} {5, 6, 7} {8, 9, 10}
    lag, dx, dy, weight = release_offsets(_flow_steps(3, 0.1), reach_m=1.25, sigma=0.2)
    np.testing.assert_allclose(lag, [1.0, 2.0, 3.0, 4.5, 6.5, 9.0, 12.0])
    np.testing.assert_allclose(dx, 0.1 * lag)
    np.testing.assert_allclose(dy, 0.0)
    np.testing.assert_array_equal(weight, [1.0, 1.0, 1.0, 2.0, 2.0, 3.0, 3.0])
    # the record itself is never merged, and weights count every prehistoric release once
    unmerged = release_offsets(_flow_steps(3, 0.1), reach_m=1.25)
    assert len(unmerged[0]) == 13
    assert weight.sum() == unmerged[3].sum()


def test_footprint_mass_without_spread_is_the_overlap_with_the_cell() -> None:
    # eq. F2 with s = 0: the share of the cell [x_lo, x_hi] within r of c, worked by hand
    edges = np.array([0.0, 1.25, 2.5, 3.75])
    mass = footprint_mass(edges, np.array([2.0, 1.25]), np.array([0.0, 0.0]), np.array([0.3, 1.0]))
    # c = 2, r = 0.3: [1.7, 2.3] lies inside the second cell: 0.6 / 1.25
    np.testing.assert_allclose(mass[0], [0.0, 0.48, 0.0], atol=1e-12)
    # c = 1.25, r = 1: [0.25, 2.25] covers 1.0 of the first cell and 1.0 of the second
    np.testing.assert_allclose(mass[1], [0.8, 0.8, 0.0], atol=1e-12)


def test_footprint_mass_is_the_averaged_gaussian_window() -> None:
    # eq. F2 against direct quadrature over the source's position in the cell
    edges = np.array([-2.0, 0.0, 1.25, 4.0])
    centre, spread, radius = 0.4, 0.7, 0.9
    mass = footprint_mass(edges, np.array([centre]), np.array([spread]), np.array([radius]))
    for k, (lo, hi) in enumerate(itertools.pairwise(edges)):
        xs = np.linspace(lo, hi, 20001)
        window = norm.cdf((centre + radius - xs) / spread) - norm.cdf((centre - radius - xs) / spread)
        assert mass[0, k] == pytest.approx(np.trapezoid(window, xs) / (hi - lo), abs=1e-8)


def test_normal_cdf_integral_takes_its_asymptote_only_where_they_agree() -> None:
    # G(z) = z Phi(z) + phi(z) everywhere, computed in full: the tail shortcut max(z, 0) beyond
    # |z| = G_TAIL_Z differs from it by less than 1e-18, and not at all inside
    z = np.concatenate([np.linspace(-60.0, 60.0, 24001), [-G_TAIL_Z, G_TAIL_Z, 0.0]])
    full = z * norm.cdf(z) + norm.pdf(z)
    fast = _normal_cdf_integral(z)
    assert np.abs(fast - full).max() < 1e-18
    inside = np.abs(z) < G_TAIL_Z
    np.testing.assert_allclose(fast[inside], full[inside], rtol=1e-14, atol=0)
    assert np.all(fast[z >= G_TAIL_Z] == z[z >= G_TAIL_Z])
    assert np.all(fast[z <= -G_TAIL_Z] == 0.0)


def test_a_footprint_uses_the_position_in_the_cell_and_grows_with_age() -> None:
    history = [FlowStep(transition(SMALL, 1.0, 0.0, 1.0), 1.0, 0.0, 1.0)] * 3
    cell = SMALL.cell_of(5.0, 5.0)
    # without a footprint (the papers'), where in the cell the vehicle is does not matter
    plain = history_factors(SMALL, cell, history, 0.2, 0.2, at=(4.1, 4.1))
    centred = history_factors(SMALL, cell, history, 0.2, 0.2)
    for a, b in zip(plain, centred, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(plain[2], np.ones(3))  # the record's three, not this tick's release
    # with one, the point detector also smells the filament released this tick, only from within r0
    # of the source: from (4.1, 4.1) a source in the vehicle's own cell [4, 6] x [4, 6] is within
    # 0.5 m in 0.3 of x
    px, py, _ = history_factors(
        SMALL, cell, history, 0.2, 0.2, footprint_m=0.5, footprint_growth=0.1, at=(4.1, 4.1)
    )
    col, row = 2, 2
    assert px[0, col] == pytest.approx(0.6 / 2.0)
    assert py[0, row] == pytest.approx(0.6 / 2.0)
    # older filaments are smelt from farther: the radius sqrt(0.25 + 0.1 tau) grows with the lag
    lag, _, drift_y, _ = release_offsets(history)
    radius = np.sqrt(0.25 + 0.1 * np.concatenate([[0.0], lag]))
    assert np.all(np.diff(radius) > 0)
    spread = 0.2 * np.sqrt(np.concatenate([[0.0], lag]))
    expect = footprint_mass(
        np.array([0.0, 2.0, 4.0, 6.0, 8.0]), 4.1 - np.concatenate([[0.0], drift_y]), spread, radius
    )
    np.testing.assert_allclose(py, expect, atol=1e-12)
