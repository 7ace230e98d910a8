import math

import numpy as np
import pytest

from service.core.planning.probe import information


def _entropy(p: float) -> float:
    return -(p * math.log(p) + (1.0 - p) * math.log(1.0 - p))


def test_eq_i1_a_certain_answer_is_worth_one_bit() -> None:
    # two cells, source in either; odour only in the source's own cell, always detected
    pi = np.array([[0.5, 0.5]])
    kernel = np.array([[0.0, 1.0, 0.0]])  # q at column offsets -1, 0, +1 (source - vehicle)
    gain = information(pi, kernel, 0.0, np.array([[0, 0], [0, 1]]))
    assert gain == pytest.approx([math.log(2.0), math.log(2.0)])


def test_eq_i1_by_hand_with_misses_and_false_alarms() -> None:
    # q = 0.5 in the source's cell, pf = 0.1: P(d | source here) = 0.55, P(d | source there) = 0.1,
    # P(d) = 0.325; I = H(0.325) - (H(0.55) + H(0.1)) / 2 = 0.63058 - 0.50661
    pi = np.array([[0.5, 0.5]])
    kernel = np.array([[0.0, 0.5, 0.0]])
    gain = information(pi, kernel, 0.1, np.array([[0, 0]]))
    assert gain[0] == pytest.approx(0.12397, abs=1e-5)
    assert gain[0] == pytest.approx(_entropy(0.325) - 0.5 * (_entropy(0.55) + _entropy(0.1)))


def test_eq_i1_looks_where_the_rivals_disagree() -> None:
    # a row of five cells, flow toward higher columns: odour from a source reaches its own cell and
    # the next one downflow. The map is split between columns 1 and 3.
    pi = np.array([[0.0, 0.5, 0.0, 0.5, 0.0]])
    kernel = np.zeros((1, 9))
    kernel[0, 4] = 0.9  # offset 0
    kernel[0, 3] = 0.9  # source one column upflow of the vehicle (source - vehicle = -1)
    cells = np.array([[0, c] for c in range(5)])
    gain = information(pi, kernel, 0.05, cells)
    # column 0 is upflow of both rivals: no odour either way, nothing learnt. Columns 1 and 2 can
    # smell only the rival in column 1, columns 3 and 4 only the one in 3: each answer splits the
    # map in two equally
    assert gain[0] == pytest.approx(0.0, abs=1e-12)
    assert gain[1:] == pytest.approx([gain[1]] * 4)
    assert gain[1] > 0.1
    # with the map sure of column 1 nothing is left to learn anywhere
    sure = information(np.array([[0.0, 1.0, 0.0, 0.0, 0.0]]), kernel, 0.05, cells)
    assert sure == pytest.approx([0.0] * 5, abs=1e-9)
