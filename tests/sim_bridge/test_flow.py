"""Flow fields: eq. 18 switching, the meandering field's statistics, the turbulent noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.core.errors import ConfigError
from sim_bridge.flow import MeanderingFlow, SwitchedFlow, TurbulentFlow, UniformFlow, velocity_at


def test_uniform_flow_is_the_same_everywhere_and_always() -> None:
    flow = UniformFlow((1.0, -0.5))
    x = np.linspace(0, 100, 7)
    for _ in range(3):
        u, v = flow.velocity(x, -x)
        assert u.shape == x.shape
        assert np.all(u == 1.0)
        assert np.all(v == -0.5)
        flow.advance(10.0)
    assert flow.time_s == pytest.approx(30.0)


def test_switched_flow_follows_eq_18() -> None:
    flow = SwitchedFlow()  # (1, 0) for t <= 30 s, (0, 1) otherwise
    seen = {}
    for _ in range(400):
        seen[round(flow.time_s, 1)] = velocity_at(flow, 50.0, 0.0)
        flow.advance(0.1)
    assert seen[0.0] == seen[15.0] == seen[30.0] == (1.0, 0.0)
    assert seen[30.1] == seen[39.9] == (0.0, 1.0)


def test_meandering_flow_is_divergence_free_and_smooth() -> None:
    flow = MeanderingFlow((1.0, 0.0), 0.5, 20.0, 60.0, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    x, y = rng.uniform(0, 100, 200), rng.uniform(-50, 50, 200)
    # each mode moves the fluid across its own wave vector: the field is divergence free exactly
    assert np.max(np.abs(np.sum(flow._normal * flow._kappa, axis=1))) < 1e-12
    # and as evaluated (its cosine is single precision): the divergence is below a thousandth of
    # the gradients (h = 5 cm: the finite difference's truncation and rounding both small)
    h = 0.05
    du_dx = (flow.velocity(x + h, y)[0] - flow.velocity(x - h, y)[0]) / (2 * h)
    dv_dy = (flow.velocity(x, y + h)[1] - flow.velocity(x, y - h)[1]) / (2 * h)
    assert np.max(np.abs(du_dx + dv_dy)) < 1e-3 * np.max(np.abs(du_dx))
    # smooth: points 1 m apart differ by far less than the perturbation
    u1, v1 = flow.velocity(x, y)
    u2, v2 = flow.velocity(x + 1.0, y)
    assert np.max(np.hypot(u2 - u1, v2 - v1)) < 0.2


def test_meandering_flow_has_the_configured_mean_strength_and_time_scale() -> None:
    strength, tau = 0.4, 5.0
    flow = MeanderingFlow((1.0, 0.5), strength, tau, 60.0, np.random.default_rng(11))
    x, y = np.array([10.0, 50.0, 90.0]), np.array([-30.0, 0.0, 30.0])
    dt, n = 0.5, 8000
    samples = np.empty((n, 2, 3))
    for k in range(n):
        samples[k] = flow.velocity(x, y)
        flow.advance(dt)
    mean = samples.mean(axis=(0, 2))
    assert mean == pytest.approx([1.0, 0.5], abs=0.08)
    perturbation = samples - np.array([1.0, 0.5])[None, :, None]
    rms = math.sqrt(float(np.mean(np.sum(perturbation**2, axis=1))))
    assert rms == pytest.approx(strength, rel=0.2)
    # Ornstein-Uhlenbeck: autocorrelation exp(-lag / tau)
    series = perturbation[:, 1, 1]
    lag = int(tau / dt)
    corr = float(np.corrcoef(series[:-lag], series[lag:])[0, 1])
    assert corr == pytest.approx(math.exp(-1.0), abs=0.12)


def test_turbulent_flow_adds_white_noise_held_for_its_period() -> None:
    flow = TurbulentFlow((1.0, 0.0), 0.5, np.random.default_rng(5), noise_period_s=1.0)
    per_period = []
    for _ in range(3000):
        within = []
        for _ in range(10):
            u, v = flow.velocity(np.array([0.0, 80.0]), np.array([0.0, -40.0]))
            assert u[0] == u[1]
            assert v[0] == v[1]
            within.append((u[0], v[0]))
            flow.advance(0.1)
        assert len(set(within)) == 1  # held over the period
        per_period.append(within[0])
    noise = np.array(per_period) - [1.0, 0.0]
    assert noise.mean(axis=0) == pytest.approx([0.0, 0.0], abs=0.04)
    assert noise.std(axis=0) == pytest.approx([0.5, 0.5], rel=0.06)
    lag1 = np.corrcoef(noise[:-1, 1], noise[1:, 1])[0, 1]
    assert abs(lag1) < 0.06  # white from period to period


@pytest.mark.parametrize("model", ["meander", "turbulent"])
def test_same_seed_same_flow(model: str) -> None:
    def series(seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        flow = (
            MeanderingFlow((1.0, 0.0), 0.4, 20.0, 60.0, rng)
            if model == "meander"
            else TurbulentFlow((1.0, 0.0), 0.5, rng)
        )
        out = []
        for _ in range(50):
            out.append(velocity_at(flow, 30.0, 10.0))
            flow.advance(0.1)
        return np.array(out)

    assert np.array_equal(series(1), series(1))
    assert not np.array_equal(series(1), series(2))


def test_bad_parameters_are_refused() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ConfigError):
        MeanderingFlow((1.0, 0.0), -0.1, 20.0, 60.0, rng)
    with pytest.raises(ConfigError):
        TurbulentFlow((1.0, 0.0), 0.5, rng, noise_period_s=0.0)
    with pytest.raises(ValueError, match="dt_s"):
        UniformFlow((1.0, 0.0)).advance(0.0)
