"""The filament (puff) plume and the time-averaged Gaussian plume of seed pomdp-astar eq. 11."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.core.errors import ConfigError
from sim_bridge.flow import MeanderingFlow, UniformFlow
from sim_bridge.plume import GaussianPlume, PuffParams, PuffPlume
from sim_bridge.scenarios import build_world, load_scenario

WIDE = (-1e4, -1e4, 1e4, 1e4)


def still_plume(params: PuffParams, seed: int = 0) -> PuffPlume:
    return PuffPlume((0.0, 0.0), params, WIDE, np.random.default_rng(seed))


def test_puffs_are_released_at_the_rate_and_grow_as_configured() -> None:
    params = PuffParams(release_rate_hz=7.0, initial_sigma_m=0.2, spread_rate_m2ps=0.05)
    plume = still_plume(params)
    flow = UniformFlow((1.0, 0.0))
    for _ in range(100):  # 10 s
        plume.step(0.1, flow)
        flow.advance(0.1)
    assert plume.count == 70
    puffs = plume.puffs()
    age = puffs[:, 3]
    assert np.all(np.diff(age) < 0)  # oldest first, one every 1/7 s
    assert np.diff(age) == pytest.approx(-1.0 / 7.0)
    assert puffs[:, 2] == pytest.approx(0.2**2 + 0.05 * age)  # growing radius


def test_random_walk_variance_grows_linearly_with_age_eq_1() -> None:
    # no flow: X' = N(t), so each puff's displacement has variance sigma^2 * age per axis
    sigma = 0.5
    params = PuffParams(release_rate_hz=100.0, random_walk_m_per_sqrt_s=sigma, max_puffs=10_000)
    plume = still_plume(params, seed=1)
    flow = UniformFlow((0.0, 0.0))
    for _ in range(200):
        plume.step(0.1, flow)
        flow.advance(0.1)
    x, y, _, age = plume.puffs().T
    old = age > 1.0
    assert np.mean(x[old] ** 2 / age[old]) == pytest.approx(sigma**2, rel=0.08)
    assert np.mean(y[old] ** 2 / age[old]) == pytest.approx(sigma**2, rel=0.08)


def test_puffs_ride_the_flow() -> None:
    params = PuffParams(release_rate_hz=10.0, random_walk_m_per_sqrt_s=0.0)
    plume = still_plume(params)
    flow = UniformFlow((1.0, -0.5))
    for _ in range(50):
        plume.step(0.1, flow)
        flow.advance(0.1)
    x, y, _, age = plume.puffs().T
    assert x == pytest.approx(1.0 * age)
    assert y == pytest.approx(-0.5 * age)


def test_concentration_is_a_sum_of_mass_conserving_gaussian_puffs() -> None:
    params = PuffParams(release_rate_hz=5.0, puff_mass=2.0, initial_sigma_m=0.5)
    plume = PuffPlume((0.0, 0.0), params, WIDE, np.random.default_rng(2))
    flow = UniformFlow((0.5, 0.0))
    for _ in range(40):
        plume.step(0.1, flow)
        flow.advance(0.1)
    xs = np.arange(-5.0, 10.0, 0.05)
    gx, gy = np.meshgrid(xs, np.arange(-6.0, 6.0, 0.05))
    field = plume.concentration(gx, gy)
    assert field.shape == gx.shape
    assert field.sum() * 0.05 * 0.05 == pytest.approx(plume.count * 2.0, rel=1e-3)
    x, y, var, _ = plume.puffs().T
    expected = (2.0 / (2 * math.pi * var)) * np.exp(-((3.0 - x) ** 2 + (1.0 - y) ** 2) / (2 * var))
    assert plume.concentration(3.0, 1.0)[0] == pytest.approx(expected.sum())


def test_puffs_leave_the_bounds_and_age_out_and_capacity_drops_the_oldest() -> None:
    flow = UniformFlow((2.0, 0.0))
    bounded = PuffPlume(
        (0.0, 0.0), PuffParams(release_rate_hz=10.0), (-5, -5, 10, 5), np.random.default_rng(0)
    )
    aged = PuffPlume(
        (0.0, 0.0), PuffParams(release_rate_hz=10.0, max_age_s=2.0), WIDE, np.random.default_rng(0)
    )
    capped = PuffPlume(
        (0.0, 0.0), PuffParams(release_rate_hz=10.0, max_puffs=25), WIDE, np.random.default_rng(0)
    )
    for _ in range(100):
        for plume in (bounded, aged, capped):
            plume.step(0.1, flow)
    assert bounded.count == pytest.approx(50, abs=4)  # 10 m at 2 m/s = 5 s of puffs
    assert np.all(bounded.puffs()[:, 0] <= 10.0)
    assert aged.count == 20
    assert aged.puffs()[:, 3].max() <= 2.0
    assert capped.count == 25
    assert capped.puffs()[:, 3].max() < 2.6


def test_laminar_time_average_matches_the_gaussian_plume_eq_11() -> None:
    params = PuffParams()
    source = (0.0, 0.0)
    plume = PuffPlume(source, params, (-10, -40, 80, 40), np.random.default_rng(7))
    flow = UniformFlow((1.0, 0.0))
    model = GaussianPlume(source, (1.0, 0.0), params)
    downflow = np.array([10.0, 30.0, 50.0])
    sigma = model.sigma_y_m(downflow)
    qx = np.concatenate([downflow, downflow])
    qy = np.concatenate([np.zeros(3), sigma])  # on the axis and one sigma_y off it
    for _ in range(800):
        plume.step(0.1, flow)
    total = np.zeros(6)
    n = 4000
    for _ in range(n):
        plume.step(0.1, flow)
        total += plume.concentration(qx, qy)
    assert total / n == pytest.approx(model.concentration(qx, qy), rel=0.15)


def test_gaussian_plume_follows_eq_11_in_any_flow_direction() -> None:
    params = PuffParams()
    model = GaussianPlume((10.0, 10.0), (0.0, 2.0), params)  # flowing North at 2 m/s
    sigma = float(model.sigma_y_m(np.array(20.0)))
    centre = model.concentration(10.0, 30.0)
    off = model.concentration(10.0 + sigma, 30.0)
    assert off / centre == pytest.approx(math.exp(-0.5))  # eq. 11: C / C_m = exp(-y^2 / (2 sigma_y^2))
    assert model.concentration(10.0, 5.0) == 0.0  # nothing upflow
    assert model.concentration(10.0, 20.0) > centre > model.concentration(10.0, 60.0)
    with pytest.raises(ConfigError):
        GaussianPlume((0.0, 0.0), (0.0, 0.0), params)


def _meander_record(seed: int, duration_s: float, qx: np.ndarray, qy: np.ndarray) -> np.ndarray:
    """Concentration at the query points every 0.1 s in the farrell2003 world (meandering flow)."""
    world = build_world(load_scenario("farrell2003"), seed=seed)
    world.run(100.0)  # fill the area with plume first
    out = np.empty((round(duration_s / world.dt_s), qx.size))
    for k in range(out.shape[0]):
        world.step()
        out[k] = world.plume.concentration(qx, qy)
    return out


def test_meandering_plume_mean_falls_off_downflow_and_crossflow() -> None:
    # source (20, 0), mean flow East: on the axis 10, 30, 60 m downflow; 30 m downflow, 0-14 m off it
    qx = np.array([30.0, 50.0, 80.0, 50.0, 50.0])
    qy = np.array([0.0, 0.0, 0.0, 7.0, 14.0])
    mean = np.zeros(qx.size)
    for seed in (1, 2):
        mean += _meander_record(seed, 300.0, qx, qy).mean(axis=0)
    axis, cross = mean[:3], mean[[1, 3, 4]]
    assert np.all(axis[1:] < 0.9 * axis[:-1]), axis
    assert np.all(cross[1:] < 0.9 * cross[:-1]), cross


def test_meandering_plume_detection_is_intermittent_20_to_60_m_downflow() -> None:
    # one observation per 1 s tick = the max of ten 10 Hz readings (seed hmm-plume-mapping eq. 2)
    qx = np.array([40.0, 60.0, 80.0])
    qy = np.zeros(3)
    record = _meander_record(3, 400.0, qx, qy)
    detected = (record >= 1.0).reshape(-1, 10, 3).max(axis=1)
    rate = detected.mean(axis=0)
    switches = np.count_nonzero(np.diff(detected.astype(int), axis=0), axis=0)
    assert np.all((rate > 0.05) & (rate < 0.8)), rate
    assert np.all(switches >= 10), switches  # on and off, repeatedly: not one long gap
    # and within a tick the signal is patchy: above threshold only part of the time
    instantaneous = (record >= 1.0).mean(axis=0)
    assert np.all(instantaneous < rate), (instantaneous, rate)


def test_laminar_plume_is_steady_where_the_meandering_one_is_not() -> None:
    world = build_world(load_scenario("wang-laminar"), seed=0)
    world.run(80.0)
    src_x, src_y = world.plume.source_m
    on_axis = []
    for _ in range(300):
        world.step()
        on_axis.append(world.plume.concentration(src_x + 20.0, src_y)[0])
    assert min(on_axis) >= 1.0  # a laminar plume never leaves its axis


def test_same_seed_same_plume() -> None:
    def run(seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        flow_rng, plume_rng = rng.spawn(2)
        flow = MeanderingFlow((1.0, 0.0), 0.4, 20.0, 60.0, flow_rng)
        plume = PuffPlume((20.0, 0.0), PuffParams(), (-20, -70, 120, 70), plume_rng)
        for _ in range(300):
            plume.step(0.1, flow)
            flow.advance(0.1)
        return plume.puffs()

    assert np.array_equal(run(4), run(4))
    assert not np.array_equal(run(4), run(5))
    world_a = build_world(load_scenario("farrell2003"), seed=9)
    world_b = build_world(load_scenario("farrell2003"), seed=9)
    world_a.run(20.0)
    world_b.run(20.0)
    assert np.array_equal(world_a.plume.puffs(), world_b.plume.puffs())


def test_bad_puff_parameters_are_refused() -> None:
    with pytest.raises(ConfigError, match="release_rate_hz"):
        PuffParams(release_rate_hz=0.0)
    with pytest.raises(ConfigError, match="random_walk"):
        PuffParams(random_walk_m_per_sqrt_s=-1.0)
    with pytest.raises(ValueError, match="dt_s"):
        still_plume(PuffParams()).step(-0.1, UniformFlow((1.0, 0.0)))
