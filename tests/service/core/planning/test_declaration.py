import numpy as np
import pytest

from service.core.config import DeclarationConfig
from service.core.grid import Grid
from service.core.planning.declaration import Declarer, mass_within

G = Grid(0.0, 5.0, 0.0, 5.0, columns=5, rows=5)  # 1 m cells

PAPERS_DECLARATION = DeclarationConfig(upflow_pass_m=0.0, check_width_m=0.0)
"""The declaration these tests were written against: the papers' rules without the later guards
(no upflow pass or check across the flow); each test turns on the one it is about."""


def peaked(cell: int, peak: float = 0.3) -> np.ndarray:
    rest = (1.0 - peak) / (G.size - 1)
    pi = np.full(G.shape, rest)
    pi.flat[cell] = peak
    return pi


def test_mass_within_radius_by_hand() -> None:
    pi = np.arange(25, dtype=float).reshape(5, 5)
    pi /= pi.sum()  # total 300
    centre = G.cell_of(2.5, 2.5)  # flat 12
    # radius 1: the cell and its four side neighbours (7, 11, 13, 17); diagonals are sqrt(2) away
    assert mass_within(G, pi, centre, 1.0) == pytest.approx((12 + 7 + 11 + 13 + 17) / 300)
    assert mass_within(G, pi, centre, 1.5) == pytest.approx((6 + 7 + 8 + 11 + 12 + 13 + 16 + 17 + 18) / 300)
    assert mass_within(G, pi, centre, 0.0) == pytest.approx(12 / 300)
    corner = G.cell_of(0.5, 0.5)  # flat 0: only 1 and 5 are within 1 m, inside the area
    assert mass_within(G, pi, corner, 1.0) == pytest.approx((0 + 1 + 5) / 300)


def test_the_rule_names_the_cell_only_once_armed() -> None:
    d = Declarer(G, PAPERS_DECLARATION.model_copy(update={"probability": 0.25, "radius_m": 0.0}))
    assert d.update(0.0, peaked(3)) is None  # not armed yet
    d.arm(100.0, peaked(3))
    found = d.update(101.0, peaked(3))
    assert found is not None
    assert found.cell == 3
    assert found.paper_cell == G.paper_number(3)
    assert (found.x, found.y) == G.centre(3)
    assert found.probability == pytest.approx(0.3)


def test_mass_rule_counts_the_mass_within_the_radius() -> None:
    config = PAPERS_DECLARATION.model_copy(update={"probability": 0.6, "radius_m": 1.0})
    d = Declarer(G, config)
    centre = G.cell_of(2.5, 2.5)
    d.arm(0.0, peaked(centre, 0.2))
    # 0.5 at the centre, 0.04 on each side neighbour: 0.66 within 1 m
    pi = np.full(G.shape, (1.0 - 0.5 - 4 * 0.04) / 20)
    pi.flat[centre] = 0.5
    for side in (7, 11, 13, 17):
        pi.flat[side] = 0.04
    found = d.update(1.0, pi)
    assert found is not None
    assert found.mass == pytest.approx(0.66)
    # within 0.5 m only the centre counts: 0.5 is short of 0.6
    narrow = Declarer(G, config.model_copy(update={"radius_m": 0.5}))
    narrow.arm(0.0, pi)
    assert narrow.update(1.0, pi) is None


def test_mass_rule_alone_ignores_a_stable_but_flat_map() -> None:
    d = Declarer(
        G,
        PAPERS_DECLARATION.model_copy(update={"probability": 0.5, "radius_m": 1.0}),
    )
    d.arm(0.0, peaked(12, 0.1))
    assert all(d.update(float(t), peaked(12, 0.1)) is None for t in range(1, 100))


def test_the_hmm_gets_its_own_mass_threshold() -> None:
    config = DeclarationConfig(probability=0.95, hmm_probability=0.25)
    assert config.for_mapper("hmm").probability == 0.25
    assert config.for_mapper("pomdp").probability == 0.95
    assert config.for_mapper("bayes") == config
    assert config.for_mapper("scripted") == config  # a mapper outside the registry: unchanged


def test_upflow_pass_waits_until_the_vehicle_has_been_upflow_of_the_estimate() -> None:
    config = PAPERS_DECLARATION.model_copy(update={"probability": 0.5, "radius_m": 0.0, "upflow_pass_m": 1.0})
    d = Declarer(G, config)
    pi = peaked(12, 0.6)  # centre (2.5, 2.5); flow toward +x, so upflow is -x
    d.arm(0.0, pi)
    east = (1.0, 0.0)
    assert d.update(1.0, pi, (3.0, 2.5), east) is None  # downflow of the centre
    assert d.update(2.0, pi, (2.0, 2.5), east) is None  # 0.5 m upflow: not far enough
    assert d.update(3.0, pi, (1.5, 2.5)) is None  # no flow given: cannot tell upflow
    found = d.update(4.0, pi, (1.5, 2.5), (2.0, 0.0))  # 1 m upflow (the flow's length does not matter)
    assert found is not None
    assert found.cell == 12
    # a pass, once made, holds for that cell; a new estimate needs its own
    assert d.update(5.0, pi, (2.5, 2.5), east) is not None
    other = peaked(13, 0.6)  # centre (3.5, 2.5)
    assert d.update(6.0, other, (2.5, 2.5), east) is not None  # (2.5, 2.5) is 1 m upflow of it
    d.arm(7.0, other)
    assert d.update(8.0, other, (3.0, 2.5), east) is None
    # far upflow but more than visit_radius_m across the flow line does not count
    assert d.update(9.0, other, (1.5, 6.0), (1.0, 0.0)) is None
    assert d.update(10.0, other, (3.5, 2.5), east) is None


def test_upflow_pass_is_on_by_default_off_at_0_and_for_the_hmm() -> None:
    assert DeclarationConfig().upflow_pass_m == 2.0
    config = DeclarationConfig(upflow_pass_m=2.0)
    assert config.for_mapper("hmm").upflow_pass_m == 0.0
    assert config.for_mapper("pomdp").upflow_pass_m == 2.0
    pi = peaked(12, 0.6)  # centre (2.5, 2.5)
    east = (1.0, 0.0)
    mass = {"probability": 0.5, "radius_m": 0.0}
    # the default pass: nothing fires until 2 m upflow
    passing = Declarer(G, DeclarationConfig().model_copy(update=mass))
    passing.arm(0.0, pi)
    assert passing.update(1.0, pi, (3.0, 2.5), east) is None  # downflow of the centre
    assert passing.update(2.0, pi, (0.5, 2.5), east) is not None  # 2 m upflow
    # 0 switches it off: the same map fires downflow of the centre
    off = Declarer(G, PAPERS_DECLARATION.model_copy(update=mass))
    off.arm(0.0, pi)
    assert off.update(1.0, pi, (3.0, 2.5), east) is not None


def test_admit_ignores_a_rule_for_a_refused_cell() -> None:
    # the benchmark's perfect guard: the same peaked map fires for an admitted cell only
    config = PAPERS_DECLARATION.model_copy(update={"probability": 0.5, "radius_m": 0.0})
    refused = Declarer(G, config, admit=lambda cell: cell != 12)
    refused.arm(0.0, peaked(12, 0.6))
    assert all(refused.update(float(t), peaked(12, 0.6)) is None for t in range(1, 20))
    admitted = Declarer(G, config, admit=lambda cell: cell == 12)
    admitted.arm(0.0, peaked(12, 0.6))
    found = admitted.update(1.0, peaked(12, 0.6))
    assert found is not None
    assert found.cell == 12


def test_odour_upflow_is_odour_half_the_check_upflow_of_the_estimate_until_it_changes() -> None:
    config = PAPERS_DECLARATION.model_copy(
        update={"probability": 0.99, "check_upflow_m": 3.0, "visit_radius_m": 1.0}
    )
    d = Declarer(G, config)
    pi = peaked(12, 0.6)  # centre (2.5, 2.5); flow toward +x, so upflow is -x
    east = (1.0, 0.0)
    assert d.cell is None
    d.arm(0.0, pi)
    assert d.cell == 12
    assert not d.odour_upflow
    d.update(1.0, pi, (1.2, 2.5), east, detected=True)  # 1.3 m upflow: short of 1.5 m
    d.update(2.0, pi, (0.9, 3.6), east, detected=True)  # 1.6 m upflow but 1.1 m across
    d.update(3.0, pi, (0.5, 2.5), east, detected=False)  # 2 m upflow, no odour
    d.update(4.0, pi, (0.5, 2.5), None, detected=True)  # no flow: cannot tell upflow
    assert not d.odour_upflow
    d.update(5.0, pi, (1.0, 3.0), east, detected=True)  # 1.5 m upflow, 0.5 m across
    assert d.odour_upflow
    d.update(6.0, pi, (4.5, 2.5), east, detected=True)  # odour downflow later does not undo it
    assert d.odour_upflow
    other = peaked(13, 0.6)  # a new estimate starts clean
    d.update(7.0, other, (4.5, 2.5), east)
    assert d.cell == 13
    assert not d.odour_upflow
