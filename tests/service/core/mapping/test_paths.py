import itertools
import math
from collections.abc import Callable
from functools import cache

import numpy as np
import pytest
from scipy import sparse

from service.core.errors import NoPathError
from service.core.grid import Grid
from service.core.mapping.paths import (
    FloatArray,
    Objective,
    backward_recursion,
    backward_viterbi,
    most_likely_detection_path,
    most_likely_odour_path,
    one_step_mldp,
    viterbi,
)
from service.core.mapping.plume import advance_plume
from service.core.mapping.transport import Transition, tick_matrix, transition

PAPER = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)

# §IV-C1 three-state example (states S1..S3 are 0..2 here)
A0 = np.array([[0.60, 0.40, 0.00], [0.00, 1.00, 0.00], [0.00, 1.00, 0.00]])
A1 = np.array([[0.25, 0.25, 0.50], [0.00, 1.00, 0.00], [0.00, 0.50, 0.50]])
PI3 = np.array([1.0, 0.0, 0.0])


def eq18_transitions(ticks: int) -> list[Transition]:
    """A(t_0) ... A(t_ticks-1) under eq. 18: 1 m/s east for t <= 30 s, 1 m/s north after; sigma = 0."""
    east = transition(PAPER, 1.0, 0.0, dt_s=1.0)
    north = transition(PAPER, 0.0, 1.0, dt_s=1.0)
    return [east if t <= 30 else north for t in range(ticks)]


@cache
def paper_abar(step: Transition) -> FloatArray:
    """A-bar(t) of a tick in the papers' numbering (index k - 1 is C_k), from core.mapping.transport."""
    out: FloatArray = tick_matrix(PAPER, step)[1:, 1:].toarray()
    return out


def odour_path_probability(steps: list[Transition], path: list[int]) -> float:
    """prod_t a_{q(t) q(t+1)}(t), read from the paper-numbered matrices."""
    prob = 1.0
    for step, here, there in zip(steps, path, path[1:], strict=False):
        prob *= paper_abar(step)[PAPER.paper_number(here) - 1, PAPER.paper_number(there) - 1]
    return prob


def to_csr(a: FloatArray) -> sparse.csr_array:
    return sparse.csr_array(a)


def to_matrix(a: FloatArray) -> sparse.csr_matrix:
    return sparse.csr_matrix(a)


def to_split_coo(a: FloatArray) -> sparse.coo_array:
    """COO with every entry stored as two halves, in reverse order: duplicates mean a sum."""
    rows, cols = np.nonzero(a)
    halves = np.r_[a[rows, cols], a[rows, cols]] / 2.0
    return sparse.coo_array((halves[::-1], (np.r_[rows, rows][::-1], np.r_[cols, cols][::-1])), shape=a.shape)


# ---------------------------------------------------------------- Table III and eq. 17 (§IV-C1)


@pytest.mark.parametrize("convert", [np.asarray, to_csr, to_matrix, to_split_coo])
def test_table3_three_state_example(convert: Callable[[FloatArray], object]) -> None:
    result = viterbi(PI3, [convert(A0), convert(A1), convert(A1)])
    # the paper prints delta(3)_1 = 0.04: 0.15 * 0.25 = 0.0375 rounded
    expected = [[1.0, 0.0, 0.0], [0.60, 0.40, 0.00], [0.15, 0.40, 0.30], [0.0375, 0.40, 0.15]]
    assert len(result.delta) == 4
    for got, want in zip(result.delta, expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
    # paper psi(1) = [1, 1, np], psi(2) = [1, 2, 1], psi(3) = [1, 2, 3], 1-based
    assert [p.tolist() for p in result.psi[1:]] == [[0, 0, -1], [0, 1, 0], [0, 1, 2]]
    assert result.path(2) == [0, 0, 2, 2]  # S1(0) -> S1(1) -> S3(2) -> S3(3)
    assert result.probability(2) == pytest.approx(0.15)
    assert viterbi(PI3, [convert(A0), convert(A1)]).path(1) == [0, 1, 1]  # S1 -> S2 -> S2


def test_eq17_backward_three_state_example() -> None:
    result = backward_recursion(PI3, [A0, A1, A1], final_state=2)
    # by hand: mu(3) = Delta(3); mu_m(k) = max_n a_mn(k) mu_n(k+1)
    expected_mu = [[0.15, 0.0, 0.0], [0.25, 0.0, 0.25], [0.5, 0.0, 0.5], [0.0, 0.0, 1.0]]
    for got, want in zip(result.mu, expected_mu, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
    assert [p.tolist() for p in result.psi] == [[0, -1, -1], [2, -1, 2], [2, -1, 2], [-1, -1, -1]]
    assert result.start == 0
    assert result.probability == pytest.approx(0.15)  # = delta_3(3) of the forward VA
    assert result.path() == [0, 0, 2, 2]
    assert backward_viterbi(PI3, [A0, A1], final_state=1) == [0, 1, 1]


def test_impossible_final_state_raises() -> None:
    # nothing reaches S1 from S2 or S3, and pi starts in S2
    pi = np.array([0.0, 1.0, 0.0])
    with pytest.raises(NoPathError):
        viterbi(pi, [A0, A1]).path(0)
    with pytest.raises(NoPathError):
        backward_viterbi(pi, [A0, A1], final_state=0)


def test_zero_ticks_is_pi_itself() -> None:
    result = viterbi(PI3, [])
    assert result.path(0) == [0]
    with pytest.raises(NoPathError):
        result.path(1)
    assert backward_viterbi(PI3, [], final_state=0) == [0]


def test_wrong_shapes_and_negative_entries_are_refused() -> None:
    with pytest.raises(ValueError, match="shape"):
        viterbi(PI3, [np.eye(4)])
    with pytest.raises(ValueError, match="non-negative"):
        viterbi(PI3, [-np.eye(3)])
    with pytest.raises(IndexError):
        viterbi(PI3, [A0]).path(3)


def test_forward_and_backward_find_the_brute_force_maximum() -> None:
    rng = np.random.default_rng(7)
    n_states, ticks = 4, 4
    for _ in range(20):
        pi = rng.random(n_states) * (rng.random(n_states) < 0.7)
        mats = [
            rng.random((n_states, n_states)) * (rng.random((n_states, n_states)) < 0.5) for _ in range(ticks)
        ]
        final = int(rng.integers(n_states))

        def prob(states: tuple[int, ...], pi: FloatArray = pi, mats: list[FloatArray] = mats) -> float:
            p = float(pi[states[0]])
            for a, i, j in zip(mats, states, states[1:], strict=False):
                p *= a[i, j]
            return p

        # every state sequence of length ticks + 1 that ends in ``final``
        best = max(prob((*head, final)) for head in itertools.product(range(n_states), repeat=ticks))
        forward = viterbi(pi, [sparse.csr_array(a) for a in mats])
        backward = backward_recursion(pi, mats, final)
        assert forward.probability(final) == pytest.approx(best, rel=1e-12, abs=1e-300)
        assert backward.probability == pytest.approx(best, rel=1e-12, abs=1e-300)
        if best == 0.0:
            with pytest.raises(NoPathError):
                forward.path(final)
            with pytest.raises(NoPathError):
                backward.path()
        else:
            assert prob(tuple(forward.path(final))) == pytest.approx(best, rel=1e-12)
            assert prob(tuple(backward.path())) == pytest.approx(best, rel=1e-12)


def test_ties_go_to_the_lowest_state() -> None:
    # two equally likely routes 0 -> 1 -> 3 and 0 -> 2 -> 3
    a = np.zeros((4, 4))
    a[0, 1] = a[0, 2] = 0.5
    a[1, 3] = a[2, 3] = 1.0
    pi = np.array([1.0, 0.0, 0.0, 0.0])
    assert viterbi(pi, [a, a]).path(3) == [0, 1, 3]
    assert backward_viterbi(pi, [a, a], 3) == [0, 1, 3]


# ---------------------------------------------------------------- MLOP, §IV-C2 and Fig. 7


def test_paper_cells_of_fig7_and_fig8() -> None:
    # §V: (20, 0) m is C488, column 8, row 13; C388 and C471 are the other path ends
    assert PAPER.paper_number(PAPER.cell_of(20.0, 0.0)) == 488
    assert PAPER.row_col(PAPER.flat_index(488)) == (12, 7)
    assert PAPER.row_col(PAPER.flat_index(388)) == (15, 27)  # 20 columns east, 3 rows north
    assert PAPER.row_col(PAPER.flat_index(471)) == (13, 30)


@pytest.mark.parametrize("backward", [False, True])
def test_fig7_odour_path_goes_east_then_north(backward: bool) -> None:
    steps = eq18_transitions(44)  # A(0..30) east, A(31..43) north
    start, end = PAPER.flat_index(488), PAPER.flat_index(388)
    path = most_likely_odour_path(PAPER, steps, start, end, backward=backward)
    assert len(path) == 45
    assert (path[0], path[-1]) == (start, end)
    cells = [PAPER.row_col(f) for f in path]
    moves = [(r1 - r0, c1 - c0) for (r0, c0), (r1, c1) in itertools.pairwise(cells)]
    assert set(moves) <= {(0, 0), (0, 1), (1, 0)}  # stay, one column east, one row north
    east = [t for t, move in enumerate(moves) if move == (0, 1)]
    north = [t for t, move in enumerate(moves) if move == (1, 0)]
    assert len(east) == 20
    assert max(east) <= 30
    assert len(north) == 3
    assert min(north) >= 31
    # App. II with sigma = 0: east 0.4 / stay 0.6 per tick (L_x = 2.5 m), north 0.25 / stay 0.75 (L_y = 4 m)
    expected = 0.4**20 * 0.6**11 * 0.25**3 * 0.75**10
    assert odour_path_probability(steps, path) == pytest.approx(expected, rel=1e-12)
    assert most_likely_odour_path(PAPER, steps, start, end, backward=backward) == path


def test_fig7_probability_is_the_viterbi_maximum_in_paper_numbering() -> None:
    # Table III run directly on the paper-numbered A-bar of service.core.mapping.transport
    steps = eq18_transitions(44)
    pi = np.zeros(PAPER.size)
    pi[488 - 1] = 1.0
    forward = viterbi(pi, [paper_abar(s) for s in steps])
    expected = 0.4**20 * 0.6**11 * 0.25**3 * 0.75**10
    assert forward.probability(388 - 1) == pytest.approx(expected, rel=1e-12)
    assert backward_recursion(pi, [paper_abar(s) for s in steps], 388 - 1).probability == pytest.approx(
        expected, rel=1e-12
    )


def test_odour_cannot_go_upflow() -> None:
    steps = eq18_transitions(10)  # all east
    start = PAPER.flat_index(488)
    west = start - 1
    for backward in (False, True):
        with pytest.raises(NoPathError, match="C488"):
            most_likely_odour_path(PAPER, steps, start, west, backward=backward)
    assert most_likely_odour_path(PAPER, [], start, start) == [start]


def test_mlop_with_spreading_and_substeps_is_the_brute_force_maximum() -> None:
    grid = Grid(0.0, 12.0, 0.0, 10.0, columns=6, rows=5)
    # 3 m/s over 2 m cells needs two sub-steps per tick; sigma spreads both ways
    steps = [
        transition(grid, 3.0, -1.0, 1.0, 0.8, 0.6),
        transition(grid, 0.5, 2.5, 1.0, 0.8, 0.6),
        transition(grid, -1.0, 0.2, 1.0, 0.3, 0.3),
    ]
    abar = [tick_matrix(grid, s)[1:, 1:].toarray() for s in steps]
    start, end = grid.flat_index(13), grid.flat_index(4)

    def prob(flat_path: list[int] | tuple[int, ...]) -> float:
        ks = [grid.paper_number(f) - 1 for f in flat_path]
        return math.prod(float(a[i, j]) for a, i, j in zip(abar, ks, ks[1:], strict=False))

    best = max(prob((start, *mid, end)) for mid in itertools.product(range(grid.size), repeat=2))
    assert best > 0.0
    for backward in (False, True):
        path = most_likely_odour_path(grid, steps, start, end, backward=backward)
        assert (len(path), path[0], path[-1]) == (4, start, end)
        assert prob(path) == pytest.approx(best, rel=1e-12)


# ---------------------------------------------------------------- MLDP, §IV-C3 and Fig. 8


@cache
def fig8_alpha() -> FloatArray:
    """alpha(t_48, t_0) by eq. 11 for a source in C488 under the eq. 18 flow, sigma = 0 (App. II)."""
    pi = np.zeros(PAPER.shape)
    pi.flat[PAPER.flat_index(488)] = 1.0
    alpha = pi.copy()
    for n, step in enumerate(eq18_transitions(48), start=1):
        alpha = advance_plume(alpha, pi, step, n)
    return alpha


def brute_force_best_sum(
    alpha: FloatArray, cells: set[tuple[int, int]], start: tuple[int, int], end: tuple[int, int], steps: int
) -> float:
    """Forward DP over all connected paths inside ``cells``: best sum of alpha from start to end."""
    best = {start: float(alpha[start])}
    for _ in range(steps):
        nxt: dict[tuple[int, int], float] = {}
        for (r, c), score in best.items():
            for dr, dc in itertools.product((-1, 0, 1), repeat=2):
                cell = (r + dr, c + dc)
                if cell in cells:
                    nxt[cell] = max(nxt.get(cell, -math.inf), score + float(alpha[cell]))
        best = nxt
    return best.get(end, -math.inf)


def path_score(alpha: FloatArray, path: list[int], objective: Objective) -> float:
    values = [float(alpha.flat[f]) for f in path]
    return math.fsum(values) if objective == "sum" else math.prod(values)


def check_connected(grid: Grid, path: list[int]) -> None:
    for a, b in itertools.pairwise(path):
        (r0, c0), (r1, c1) = grid.row_col(a), grid.row_col(b)
        assert max(abs(r1 - r0), abs(c1 - c0)) <= 1


def test_fig8_detection_path_is_the_best_connected_path() -> None:
    alpha = fig8_alpha()
    start, end = PAPER.flat_index(388), PAPER.flat_index(471)
    (r0, c0), (r1, c1) = PAPER.row_col(start), PAPER.row_col(end)
    margin = 2
    rows = range(min(r0, r1) - margin, max(r0, r1) + margin + 1)
    cols = range(min(c0, c1) - margin, max(c0, c1) + margin + 1)
    box = np.zeros(PAPER.shape, dtype=bool)
    box[rows.start : rows.stop, cols.start : cols.stop] = True
    path = most_likely_detection_path(PAPER, alpha, start, end, 25, blocked=~box)
    assert len(path) == 26
    assert (path[0], path[-1]) == (start, end)
    check_connected(PAPER, path)
    assert all(box.flat[f] for f in path)
    cells = {(r, c) for r in rows for c in cols}
    best = brute_force_best_sum(alpha, cells, (r0, c0), (r1, c1), 25)
    assert sum(alpha.flat[f] for f in path) == pytest.approx(best, rel=1e-12)
    # the path leaves its ends for richer cells of the plume: it beats staying at either end
    assert best > 26 * max(alpha[r0, c0], alpha[r1, c1])
    # without the box the path can only do as well or better
    free = most_likely_detection_path(PAPER, alpha, start, end, 25)
    check_connected(PAPER, free)
    assert sum(alpha.flat[f] for f in free) >= best - 1e-15


@pytest.mark.parametrize("objective", ["sum", "product"])
def test_mldp_matches_exhaustive_enumeration_on_a_tiny_grid(objective: Objective) -> None:
    grid = Grid(0.0, 4.0, 0.0, 3.0, columns=4, rows=3)
    rng = np.random.default_rng(11)
    blocked = np.zeros(grid.shape, dtype=bool)
    blocked[1, 2] = True
    for _ in range(5):
        alpha = rng.uniform(0.01, 0.3, size=grid.shape)
        start, end, steps = 0, 11, 4
        best = -math.inf
        for mid in itertools.product(range(grid.size), repeat=steps - 1):
            cand = [start, *mid, end]
            rc = [grid.row_col(f) for f in cand]
            if any(blocked[r, c] for r, c in rc):
                continue
            if any(max(abs(a[0] - b[0]), abs(a[1] - b[1])) > 1 for a, b in itertools.pairwise(rc)):
                continue
            best = max(best, path_score(alpha, cand, objective))
        path = most_likely_detection_path(
            grid, alpha, start, end, steps, blocked=blocked, objective=objective
        )
        assert len(path) == steps + 1
        check_connected(grid, path)
        assert not any(blocked.flat[f] for f in path)
        assert path_score(alpha, path, objective) == pytest.approx(best, rel=1e-12)


def test_product_objective_with_a_zero_wall_crosses_it_once() -> None:
    grid = Grid(0.0, 5.0, 0.0, 3.0, columns=5, rows=3)
    alpha = np.full(grid.shape, 0.2)
    alpha[:, 2] = 0.0  # every path from west to east has product 0
    path = most_likely_detection_path(grid, alpha, 0, 4, 6, objective="product")
    check_connected(grid, path)
    assert (path[0], path[-1]) == (0, 4)
    assert sum(alpha.flat[f] == 0.0 for f in path) == 1


def test_mldp_staying_is_allowed_and_unreachable_ends_raise() -> None:
    grid = Grid(0.0, 5.0, 0.0, 5.0, columns=5, rows=5)
    alpha = np.full(grid.shape, 0.01)
    alpha[2, 2] = 0.5
    # 6 moves from (2, 0) to (2, 4) on a row: the best spends its spare moves in the hot cell
    path = most_likely_detection_path(grid, alpha, 10, 14, 6)
    assert path.count(12) == 3
    with pytest.raises(NoPathError):
        most_likely_detection_path(grid, alpha, 10, 14, 3)  # 4 columns apart
    wall = np.zeros(grid.shape, dtype=bool)
    wall[:, 2] = True
    with pytest.raises(NoPathError):
        most_likely_detection_path(grid, alpha, 10, 14, 10, blocked=wall)
    with pytest.raises(NoPathError):
        most_likely_detection_path(grid, alpha, 10, 12, 5, blocked=wall)  # the end itself is blocked
    assert most_likely_detection_path(grid, alpha, 7, 7, 0) == [7]
    with pytest.raises(ValueError, match="objective"):
        most_likely_detection_path(grid, alpha, 10, 14, 6, objective="max")  # type: ignore[arg-type]


def test_mldp_avoids_grid_obstacles() -> None:
    # an obstacle over the middle column except its northern cell
    grid = Grid(0.0, 3.0, 0.0, 3.0, columns=3, rows=3, obstacles=((1.2, 0.0, 1.8, 1.9),))
    alpha = np.full(grid.shape, 0.1)
    alpha[0:2, 1] = 0.9
    # from (0, 0) to (0, 2) in 4 moves the only open way is round the north: (1, 0), (2, 1), (1, 2)
    path = most_likely_detection_path(grid, alpha, 0, 2, 4)
    assert path == [0, 3, 7, 5, 2]
    with pytest.raises(NoPathError):
        most_likely_detection_path(grid, alpha, 0, 2, 3)


# ---------------------------------------------------------------- one-step MLDP, §VI


def test_one_step_mldp_picks_the_best_open_neighbour() -> None:
    grid = Grid(0.0, 4.0, 0.0, 4.0, columns=4, rows=4)
    alpha = np.array(
        [
            [0.10, 0.20, 0.05, 0.00],
            [0.30, 0.99, 0.25, 0.00],
            [0.15, 0.60, 0.45, 0.95],
            [0.00, 0.00, 0.00, 0.00],
        ]
    )
    here = 5  # row 1, col 1, itself the highest: it must move
    assert one_step_mldp(grid, alpha, here) == 9  # (2, 1), 0.60
    blocked = np.zeros(grid.shape, dtype=bool)
    blocked[2, 1] = True
    assert one_step_mldp(grid, alpha, here, blocked=blocked) == 10  # (2, 2), 0.45; (2, 3) is two away
    # a corner has three neighbours inside the area
    assert one_step_mldp(grid, alpha, 0) == 5
    assert one_step_mldp(grid, alpha, 15) == 11  # (2, 3) 0.95 beats (2, 2) and (3, 2)
    # equal alpha everywhere: the lowest flat index, never the cell itself
    assert one_step_mldp(grid, np.ones(grid.shape), 5) == 0
    everything = np.ones(grid.shape, dtype=bool)
    everything.flat[5] = False
    with pytest.raises(NoPathError):
        one_step_mldp(grid, alpha, 5, blocked=everything)
