"""What every mapper must keep, whatever it is fed: a distribution, and no reset on the impossible."""

import numpy as np
import pytest

from service.grid import Grid
from service.mapping import MAPPERS
from service.mapping.bayes import BayesMapper
from service.mapping.mapper import MapperParams, SourceMapper
from service.mapping.pomdp import PomdpMapper
from service.observation import Observation

SMALL = Grid(0.0, 12.0, 0.0, 8.0, columns=6, rows=4)


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


def test_every_registered_mapper_is_covered() -> None:
    # a new mapper joins the parametrisations above (hmm's invariants are in test_hmm.py)
    assert set(MAPPERS) == {"hmm", "bayes", "pomdp"}
