"""What every mapper must keep, whatever it is fed: a distribution, and no reset on the impossible."""

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.mapping import MAPPERS
from service.core.mapping.bayes import BayesMapper
from service.core.mapping.mapper import MapperParams, SourceMapper
from service.core.mapping.pomdp import PomdpMapper
from service.core.observation import Observation

SMALL = Grid(0.0, 12.0, 0.0, 8.0, columns=6, rows=4)
FIELD = Grid(0.0, 100.0, -50.0, 50.0, columns=50, rows=50)


def centroid(pi: np.ndarray, grid: Grid) -> np.ndarray:
    return np.array([(pi.sum(axis=0) * grid.x_centres).sum(), (pi.sum(axis=1) * grid.y_centres).sum()])


def random_observations(rng: np.random.Generator, count: int) -> list[Observation]:
    out = []
    t = 0.0
    for _ in range(count):
        t += float(rng.choice([0.0, 0.05, 1.0, 2.5]))  # repeated times are rejected by the base class
        kind = rng.integers(3)
        flow = (0.0, 0.0) if kind == 0 else tuple(rng.normal(0.0, 1.0 if kind == 1 else 15.0, 2))
        x, y = rng.uniform(-4.0, 16.0), rng.uniform(-3.0, 11.0)
        out.append(
            Observation(t, float(x), float(y), float(flow[0]), float(flow[1]), bool(rng.random() < 0.3))
        )
    return out


@pytest.mark.parametrize("mapper_class", [BayesMapper, PomdpMapper])
@pytest.mark.parametrize(
    "params",
    [MapperParams(window=30), MapperParams(window=30, sigma_x=0.05, sigma_y=0.02, mu=1.0, false_alarm=0.0)],
)
def test_map_stays_a_distribution_under_random_updates(
    mapper_class: type[SourceMapper], params: MapperParams
) -> None:
    rng = np.random.default_rng(11)
    mapper = mapper_class(SMALL, params)
    for k, obs in enumerate(random_observations(rng, 10_000)):
        mapper.update(obs)
        pi = mapper.likelihood
        assert np.isfinite(pi).all()
        assert pi.min() >= 0.0
        assert pi.sum() == pytest.approx(1.0, abs=1e-12)
        if k % 97 == 0:
            d = mapper.detection_likelihood(int(rng.integers(SMALL.size)))
            assert d.min() >= 0.0
            assert d.max() <= 1.0
    assert mapper.ignored["outside_area"] > 1000
    assert mapper.ignored["time_not_increasing"] > 1000


@pytest.mark.parametrize("mapper_class", [BayesMapper, PomdpMapper])
def test_impossible_event_leaves_the_map_alone(mapper_class: type[SourceMapper]) -> None:
    mapper = mapper_class(SMALL, MapperParams(false_alarm=0.0))
    mapper.update(Observation(0.0, 5.0, 5.0, 0.3, 0.0, False))
    mapper.update(Observation(1.0, 5.0, 5.0, 0.3, 0.0, False))
    before = mapper.likelihood.copy()
    assert before.max() > 1.5 * before.min()
    # a 100 m/s gust: every filament of the window comes from 100 m upflow, far outside the area,
    # so with no false alarms no cell can explain a detection; the map is kept, not reset
    assert mapper.update(Observation(2.0, 5.0, 5.0, 100.0, 0.0, True))
    assert mapper.ignored == {"impossible_event": 1}
    np.testing.assert_array_equal(mapper.likelihood, before)


@pytest.mark.parametrize("mapper_class", [BayesMapper, PomdpMapper])
@pytest.mark.parametrize("flow", [(1.0, 0.5), (-1.0, -0.5), (0.0, 1.2)])
def test_detection_moves_mass_upflow(mapper_class: type[SourceMapper], flow: tuple[float, float]) -> None:
    u = np.array(flow)
    unit = u / np.linalg.norm(u)
    mapper = mapper_class(FIELD, MapperParams(window=40))
    # the flow history, with the vehicle outside the area (nothing fused)
    for k in range(40):
        assert not mapper.update(Observation(float(k), -10.0, -60.0, flow[0], flow[1], False))
    t = 40.0
    before = mapper.likelihood.copy()
    vehicle = np.array([51.0, 1.0])  # the centre cell: the uniform prior's centroid is the vehicle
    mapper.update(Observation(t, float(vehicle[0]), float(vehicle[1]), *flow, True))
    after = mapper.likelihood
    xs, ys = np.meshgrid(FIELD.x_centres, FIELD.y_centres)
    along = (xs - vehicle[0]) * unit[0] + (ys - vehicle[1]) * unit[1]
    across = np.abs((xs - vehicle[0]) * unit[1] - (ys - vehicle[1]) * unit[0])
    behind = along < 0.0
    assert after[behind].sum() > 0.9
    assert before[behind].sum() < 0.55
    # the upflow corridor within the window's reach (40 s of flow) gathers most of the mass
    corridor = behind & (along > -45.0 * np.linalg.norm(u)) & (across < 8.0)
    assert before[corridor].sum() < 0.1
    assert after[corridor].sum() > 0.6
    assert (centroid(before, FIELD) - vehicle) @ unit == pytest.approx(0.0, abs=1.5)
    assert (centroid(after, FIELD) - vehicle) @ unit < -15.0
    estimate = mapper.estimate()
    offset = np.array([estimate.x, estimate.y]) - vehicle
    assert offset @ unit < 0.0
    assert abs(offset[0] * unit[1] - offset[1] * unit[0]) < 3.0


def test_every_registered_mapper_is_covered() -> None:
    # a new mapper joins the parametrisations above (hmm's invariants are in test_hmm.py)
    assert set(MAPPERS) == {"hmm", "bayes", "pomdp"}


@pytest.mark.parametrize("mapper_class", [BayesMapper, PomdpMapper])
def test_forgetting_hands_a_share_back_to_the_uniform_prior(mapper_class: type[SourceMapper]) -> None:
    share = 0.01
    plain = mapper_class(FIELD, MapperParams(window=30, sigma_x=0.3, sigma_y=0.3))
    forgetful = mapper_class(FIELD, MapperParams(window=30, sigma_x=0.3, sigma_y=0.3, forgetting=share))
    first = Observation(0.0, 40.0, 0.0, 1.0, 0.0, True)
    plain.update(first)
    forgetful.update(first)
    np.testing.assert_allclose(
        forgetful.likelihood, (1.0 - share) * plain.likelihood + share / FIELD.size, rtol=1e-12
    )
    # a long run of misses all but rules out the cells upflow in the plain map; the forgetful one
    # keeps every cell at the floor share / N, so later odour can bring a cell back
    for t in range(1, 60):
        obs = Observation(float(t), 40.0, 0.0, 1.0, 0.0, False)
        plain.update(obs)
        forgetful.update(obs)
    assert plain.likelihood.min() < 1e-6 * share / FIELD.size
    assert forgetful.likelihood.min() >= share / FIELD.size * (1.0 - 1e-12)
    assert forgetful.likelihood.sum() == pytest.approx(1.0)
