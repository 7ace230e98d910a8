"""The intermittent mapper: eq. I1 on hand-worked values, and what it does that pomdp does not."""

from __future__ import annotations

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.mapping.filament import release_offsets
from service.core.mapping.intermittent import HIT_RATES, IntermittentMapper
from service.core.mapping.mapper import FlowStep, MapperParams
from service.core.mapping.pomdp import PomdpMapper
from service.core.mapping.transport import transition
from service.core.observation import Observation

GRID = Grid(0.0, 100.0, -50.0, 50.0, 40, 25)


def _steps(n: int, dx: float, dt: float = 1.0) -> list[FlowStep]:
    step = transition(GRID, dx / dt, 0.0, dt, 0.2, 0.2)
    return [FlowStep(step, dx, 0.0, dt) for _ in range(n)]


def test_the_prehistory_continues_the_record_with_its_mean_step() -> None:
    lag, dx, dy = release_offsets(_steps(3, 1.0), reach_m=10.0)
    np.testing.assert_allclose(lag, np.arange(1.0, 11.0))
    np.testing.assert_allclose(dx, np.arange(1.0, 11.0))
    np.testing.assert_allclose(dy, 0.0)
    plain = release_offsets(_steps(3, 1.0))
    np.testing.assert_allclose(plain[0], [1.0, 2.0, 3.0])


def test_without_a_flow_there_is_no_prehistory() -> None:
    lag, _, _ = release_offsets(_steps(3, 0.0), reach_m=10.0)
    assert len(lag) == 3


def _walk(mapper: IntermittentMapper | PomdpMapper, ticks: list[tuple[float, bool]]) -> None:
    for t, (x, detected) in enumerate(ticks):
        mapper.update(Observation(float(t), x, 0.0, 1.0, 0.0, detected))


def test_eq_i1_on_one_tick() -> None:
    """After one update the joint belief is the uniform prior times eq. I1, normalised."""
    params = MapperParams(window=20, sigma_x=0.3, sigma_y=0.3, false_alarm=0.1, zero_lag=True)
    mapper = IntermittentMapper(GRID, params)
    mapper.update(Observation(0.0, 51.0, 0.0, 1.0, 0.0, True))
    q = mapper.envelope(GRID.cell_of(51.0, 0.0))
    levels = np.asarray(HIT_RATES)[:, None, None]
    expected = 0.1 + 0.9 * levels * q
    expected = expected / expected.sum()
    np.testing.assert_allclose(mapper.likelihood, expected.sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(mapper.hit_rate_belief(), expected.sum(axis=(1, 2)), rtol=1e-12)


def test_misses_on_a_patchy_plume_lower_the_hit_rate_rather_than_rule_out_its_source() -> None:
    """Three detections, then twenty misses in the same place (a patchy plume): pomdp all but rules
    out the sources upflow that explained the detections; the intermittent mapper keeps them near
    their prior share, and for them it has learnt that the plume is patchy."""
    params = MapperParams(window=40, sigma_x=0.3, sigma_y=0.3, false_alarm=0.05, mu=0.9, zero_lag=True,
                          prehistory=True)  # fmt: skip
    ticks = [(60.0, True)] * 3 + [(60.0, False)] * 20
    pomdp, intermittent = PomdpMapper(GRID, params), IntermittentMapper(GRID, params)
    _walk(pomdp, ticks)
    _walk(intermittent, ticks)
    upflow = np.zeros(GRID.shape, dtype=bool)
    row = GRID.row_col(GRID.cell_of(60.0, 0.0))[0]
    upflow[row, : GRID.column_of(55.0)] = True
    prior_share = upflow.sum() / upflow.size
    assert pomdp.likelihood[upflow].sum() < 1e-9
    assert intermittent.likelihood[upflow].sum() > 0.3 * prior_share
    belief = intermittent.hit_rate_belief(upflow)
    assert np.all(np.diff(belief) < 0.0)  # the patchier, the likelier
    assert belief[0] > 10.0 * belief[-1]
    assert intermittent.hit_rate_belief().sum() == pytest.approx(1.0)


def test_a_snapshot_restores_the_joint_belief() -> None:
    params = MapperParams(window=20, sigma_x=0.3, sigma_y=0.3)
    mapper = IntermittentMapper(GRID, params)
    _walk(mapper, [(50.0, True), (51.0, False), (52.0, True)])
    copy = IntermittentMapper(GRID, params)
    copy.restore_state(mapper.save_state())
    mapper.update(Observation(9.0, 53.0, 0.0, 1.0, 0.0, False))
    copy.update(Observation(9.0, 53.0, 0.0, 1.0, 0.0, False))
    np.testing.assert_array_equal(copy.likelihood, mapper.likelihood)
