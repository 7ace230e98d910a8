"""Most likely paths on the hidden Markov plume model (seed hmm-plume-mapping §IV-C and §VI).

All four searches are Viterbi-style recursions: a max over predecessors (or successors) that
remembers which one won.

- ``viterbi`` (Table III) and ``backward_viterbi`` (eq. 17) are generic over states 0..S-1 and
  any sequence of (S, S) transition matrices, dense or scipy.sparse. They run on natural logs of
  the probabilities so long flow records do not underflow; ``delta`` / ``mu`` report the
  probabilities themselves.
- ``most_likely_odour_path`` (§IV-C2, MLOP): the VA over the tick matrices A-bar(t) of a flow
  record with pi = delta(start). The exterior C0 is not a state: it only feeds itself, so no odour
  path that reaches a cell of the area passes through it.
- ``most_likely_detection_path`` (§IV-C3, MLDP): the connected cell sequence with a given number of
  moves between two cells that is most likely to detect odour on the plume map alpha.
- ``one_step_mldp`` (§VI): the planner's step, the neighbour with the highest alpha.

Ties: candidates whose scores agree to a relative 1e-9 are equal (so the rounding of a product
taken in a different order cannot decide), and the lowest index among them wins: the lowest state
for the generic VA, the lowest flat index for the grid searches. Every result is deterministic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt
from scipy import sparse

from service.core.errors import NoPathError

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.mapping.transport import AxisKernel, Transition

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

Matrix = FloatArray | Any
"""An (S, S) transition matrix: a numpy array or any scipy.sparse matrix / array."""

Objective = Literal["sum", "product"]
"""What the MLDP maximises along the path: the sum of alpha (default) or the product (§IV-C3)."""

NOT_POSSIBLE = -1
"""psi entry of a state no sequence reaches (the paper's "np")."""

_TIE_RTOL = 1e-9

# Entries down to this are rounding noise and count as 0 (AxisKernel allows -1e-12 too).
_NEGATIVE_NOISE = -1e-12

# Smallest log of a positive float64 (the smallest subnormal), minus a margin.
_LOG_FLOOR_PER_CELL = math.log(float(np.finfo(np.float64).smallest_subnormal)) - 1.0

# MLDP moves as (d_row, d_col), in increasing order of the neighbour's flat index (row-major),
# so "first among ties" is "lowest flat index". The centre entry is staying put (App. I is inclusive).
_MOVES: tuple[tuple[int, int], ...] = (
    (-1, -1), (-1, 0), (-1, 1),
    (0, -1), (0, 0), (0, 1),
    (1, -1), (1, 0), (1, 1),
)  # fmt: skip
_STAY = _MOVES.index((0, 0))


def _log(values: FloatArray) -> FloatArray:
    """Natural log with log 0 = -inf, without the divide-by-zero warning."""
    out = np.full(values.shape, -np.inf)
    np.log(values, out=out, where=values > 0.0)
    return out


def _tie_threshold(best: FloatArray) -> FloatArray:
    """Scores at or above this count as equal to ``best``; +inf where ``best`` is -inf (nothing ties)."""
    possible = np.isfinite(best)
    threshold = np.full(best.shape, np.inf)
    threshold[possible] = best[possible] - _TIE_RTOL * np.maximum(1.0, np.abs(best[possible]))
    return threshold


@dataclass(frozen=True)
class _Entries:
    """The positive entries of a transition matrix as (group, member, log a), sorted by group and
    then member: group is the state being scored (the column going forward, the row going
    backward) and member the state the max runs over."""

    group: IntArray
    member: IntArray
    log_a: FloatArray


def _entries(matrix: Matrix, n_states: int, *, forward: bool) -> _Entries:
    source = matrix if sparse.issparse(matrix) else np.asarray(matrix, dtype=float)
    # compressed by group: CSC going forward (group = column), CSR going backward (group = row)
    packed = (sparse.csc_array if forward else sparse.csr_array)(source, dtype=float, copy=True)
    if packed.shape != (n_states, n_states):
        raise ValueError(f"transition matrix has shape {packed.shape}, expected ({n_states}, {n_states})")
    packed.sum_duplicates()  # also sorts the members of each group
    data = np.asarray(packed.data, dtype=float)
    if not np.all(np.isfinite(data)) or np.any(data < _NEGATIVE_NOISE):
        raise ValueError("transition matrix entries must be finite and non-negative")
    group = np.repeat(np.arange(n_states, dtype=np.intp), np.diff(packed.indptr))
    keep = data > 0.0
    return _Entries(
        group=group[keep],
        member=np.asarray(packed.indices, dtype=np.intp)[keep],
        log_a=np.log(data[keep]),
    )


def _prepare(matrices: Sequence[Matrix], n_states: int, *, forward: bool) -> list[_Entries]:
    """``_entries`` of each matrix; a matrix object repeated in the sequence is converted once."""
    done: dict[int, _Entries] = {}
    out = []
    for a in matrices:
        if id(a) not in done:
            done[id(a)] = _entries(a, n_states, forward=forward)
        out.append(done[id(a)])
    return out


def _best_per_group(entries: _Entries, previous: FloatArray, size: int) -> tuple[FloatArray, IntArray]:
    """For each group 0..size-1, the max over its members of previous[member] + log a, and the
    member reaching it (lowest among ties; ``NOT_POSSIBLE`` where the max is -inf)."""
    score = previous[entries.member] + entries.log_a
    best = np.full(size, -np.inf)
    arg = np.full(size, NOT_POSSIBLE, dtype=np.intp)
    if score.size == 0:
        return best, arg
    group = entries.group
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    best[group[starts]] = np.maximum.reduceat(score, starts)
    winners = np.flatnonzero(score >= _tie_threshold(best)[group])
    if winners.size:
        # members are sorted within a group, so a group's first winner is its lowest
        first = winners[np.r_[True, group[winners[1:]] != group[winners[:-1]]]]
        arg[group[first]] = entries.member[first]
    return best, arg


def _initial(pi: npt.ArrayLike) -> FloatArray:
    start = np.array(pi, dtype=float).ravel()
    if start.size == 0 or not np.all(np.isfinite(start)) or np.any(start < 0.0):
        raise ValueError("pi must be a non-empty vector of finite, non-negative probabilities")
    return start


def _check_state(state: int, n_states: int) -> None:
    if not 0 <= state < n_states:
        raise IndexError(f"state {state} outside 0..{n_states - 1}")


@dataclass(frozen=True)
class ViterbiResult:
    """Table III over L ticks: ``delta[k][j]`` is the probability of the most likely sequence that
    ends in state j at t_k (``delta[0]`` is pi), ``psi[k][j]`` the state it came from at t_k-1
    (``NOT_POSSIBLE`` where delta is 0, and everywhere in ``psi[0]``)."""

    delta: list[FloatArray]
    log_delta: list[FloatArray]
    psi: list[IntArray]

    def probability(self, final_state: int) -> float:
        """delta_j(t_L): the probability of the most likely sequence to ``final_state``."""
        _check_state(final_state, self.delta[-1].size)
        return float(self.delta[-1][final_state])

    def path(self, final_state: int) -> list[int]:
        """q*: the most likely states at t_0 ... t_L that end in ``final_state``."""
        _check_state(final_state, self.delta[-1].size)
        if not np.isfinite(self.log_delta[-1][final_state]):
            raise NoPathError(f"no sequence with positive probability ends in state {final_state}")
        states = [final_state]
        for k in range(len(self.psi) - 1, 0, -1):
            # Table III termination: q*(t_k-1) = psi_{q*(t_k)}(t_k)
            states.append(int(self.psi[k][states[-1]]))
        states.reverse()
        return states


def viterbi(pi: npt.ArrayLike, matrices: Sequence[Matrix]) -> ViterbiResult:
    """The forward Viterbi algorithm (Table III) from pi through A(t_0) ... A(t_L-1)."""
    start = _initial(pi)
    n = start.size
    log_delta = [_log(start)]
    psi = [np.full(n, NOT_POSSIBLE, dtype=np.intp)]
    for a in _prepare(matrices, n, forward=True):
        # Table III: delta_j(t_k) = max_i delta_i(t_k-1) a_ij(t_k-1), psi_j(t_k) = argmax_i (in logs)
        best, arg = _best_per_group(a, log_delta[-1], n)
        log_delta.append(best)
        psi.append(arg)
    delta = [start, *(np.exp(v) for v in log_delta[1:])]
    return ViterbiResult(delta=delta, log_delta=log_delta, psi=psi)


@dataclass(frozen=True)
class BackwardViterbiResult:
    """Eq. 17 over L ticks toward a fixed final state j at t_L.

    ``mu[k][m]`` is the probability of the most likely sequence from state m at t_k to j at t_L
    (``mu[L]`` is Delta(j)), ``psi[k][m]`` its next state at t_k+1 (``NOT_POSSIBLE`` where mu is 0,
    and everywhere in ``psi[L]``); ``start`` maximises pi_m mu_m(t_0) and ``probability`` is that max.
    """

    mu: list[FloatArray]
    log_mu: list[FloatArray]
    psi: list[IntArray]
    start: int
    probability: float

    def path(self) -> list[int]:
        """q*: the most likely states at t_0 ... t_L, from ``start`` to the final state."""
        if self.start == NOT_POSSIBLE:
            raise NoPathError("no sequence with positive probability reaches the final state from pi")
        states = [self.start]
        for k in range(len(self.psi) - 1):
            # eq. 17 termination: q*(t_k+1) = psi_{q*(t_k)}(t_k)
            states.append(int(self.psi[k][states[-1]]))
        return states


def backward_recursion(
    pi: npt.ArrayLike, matrices: Sequence[Matrix], final_state: int
) -> BackwardViterbiResult:
    """The backward Viterbi algorithm (eq. 17): mu and psi from Delta(j) back to t_0, start from pi."""
    start = _initial(pi)
    n = start.size
    _check_state(final_state, n)
    log_mu = [np.full(n, -np.inf)]
    log_mu[0][final_state] = 0.0  # mu(t_f) = Delta(j)
    psi = [np.full(n, NOT_POSSIBLE, dtype=np.intp)]
    for a in reversed(_prepare(matrices, n, forward=False)):
        # eq. 17: mu_m(t_k) = max_n a_mn(t_k) mu_n(t_k+1), psi_m(t_k) = argmax_n (in logs)
        best, arg = _best_per_group(a, log_mu[-1], n)
        log_mu.append(best)
        psi.append(arg)
    log_mu.reverse()
    psi.reverse()
    # eq. 17 termination: the start state maximises pi_m mu_m(t_s)
    every_state = _Entries(group=np.zeros(n, dtype=np.intp), member=np.arange(n), log_a=_log(start))
    best, arg = _best_per_group(every_state, log_mu[0], 1)
    return BackwardViterbiResult(
        mu=[np.exp(v) for v in log_mu],
        log_mu=log_mu,
        psi=psi,
        start=int(arg[0]),
        probability=float(np.exp(best[0])),
    )


def backward_viterbi(pi: npt.ArrayLike, matrices: Sequence[Matrix], final_state: int) -> list[int]:
    """The most likely states t_0 ... t_L to ``final_state`` by the backward VA (eq. 17)."""
    return backward_recursion(pi, matrices, final_state).path()


def _axis_matrix(kernel: AxisKernel, size: int, substeps: int) -> Any:
    """One tick along one axis: the App. II three-point kernel to the power ``substeps``; what
    crosses an edge is lost (to C0, which never gives it back)."""
    one = sparse.diags_array(
        [np.full(size - 1, kernel.lower), np.full(size, kernel.stay), np.full(size - 1, kernel.higher)],
        offsets=[-1, 0, 1],
        shape=(size, size),
        format="csr",
    )
    out = one
    for _ in range(substeps - 1):
        out = out @ one
    return out


def _flat_tick_matrix(grid: Grid, step: Transition) -> Any:
    """A-bar(t) of one tick as a sparse N x N matrix in flat-index order (row-major)."""
    ax = _axis_matrix(step.x, grid.columns, step.substeps)
    ay = _axis_matrix(step.y, grid.rows, step.substeps)
    # App. II: the sub-step factors into y (x) x, hence so does the tick, and f = row * m + col
    return sparse.kron(ay, ax, format="csr")


def most_likely_odour_path(
    grid: Grid,
    transitions: Sequence[Transition],
    start_cell: int,
    end_cell: int,
    *,
    backward: bool = False,
) -> list[int]:
    """MLOP (§IV-C2): the flat cells, one per tick, that odour most likely took from ``start_cell``
    at t_s to ``end_cell`` at t_f, with ``transitions`` = A(t_s) ... A(t_f-1).

    Forward VA (Table III) with pi = delta(start), or the backward VA (eq. 17) when ``backward``;
    both give a path of the same (maximal) probability. NoPathError when that probability is 0.
    """
    grid.row_col(start_cell)
    grid.row_col(end_cell)
    pi = np.zeros(grid.size)
    pi[start_cell] = 1.0
    built: dict[Transition, Any] = {}
    matrices = []
    for step in transitions:
        if step not in built:
            built[step] = _flat_tick_matrix(grid, step)
        matrices.append(built[step])
    try:
        if backward:
            return backward_viterbi(pi, matrices, end_cell)
        return viterbi(pi, matrices).path(end_cell)
    except NoPathError as err:
        raise NoPathError(
            f"odour cannot go from C{grid.paper_number(start_cell)} to C{grid.paper_number(end_cell)} "
            f"in {len(transitions)} ticks of this flow"
        ) from err


def _plume_map(grid: Grid, alpha: npt.ArrayLike) -> FloatArray:
    field = np.asarray(alpha, dtype=float)
    if field.shape != grid.shape:
        raise ValueError(f"alpha has shape {field.shape}, expected {grid.shape}")
    if not np.all(np.isfinite(field)) or np.any(field < 0.0):
        raise ValueError("alpha must be finite and non-negative")
    return field


def _closed_cells(grid: Grid, blocked: npt.ArrayLike | None) -> BoolArray:
    """Cells a path may not enter: the grid's obstacles and ``blocked``."""
    closed = grid.obstacle_mask.copy()
    if blocked is not None:
        mask = np.asarray(blocked, dtype=bool)
        if mask.shape != grid.shape:
            raise ValueError(f"blocked has shape {mask.shape}, expected {grid.shape}")
        closed |= mask
    return closed


def _neighbour_values(values: FloatArray) -> FloatArray:
    """(9, n, m): ``values[row + d_row, col + d_col]`` for each of ``_MOVES``, -inf outside the area."""
    n, m = values.shape
    padded = np.full((n + 2, m + 2), -np.inf)
    padded[1:-1, 1:-1] = values
    return np.stack([padded[1 + dr : 1 + dr + n, 1 + dc : 1 + dc + m] for dr, dc in _MOVES])


def _first_best(candidates: FloatArray) -> tuple[FloatArray, npt.NDArray[np.int8]]:
    """Max over axis 0 and the first index reaching it (within the tie tolerance); -1 where all are -inf."""
    best = candidates.max(axis=0)
    choice = np.argmax(candidates >= _tie_threshold(best), axis=0).astype(np.int8)
    choice[~np.isfinite(best)] = NOT_POSSIBLE
    return best, choice


def _gain(alpha: FloatArray, objective: Objective, steps: int) -> FloatArray:
    """What one cell of the path adds to the MLDP score."""
    if objective == "sum":
        return alpha.copy()
    if objective == "product":
        # log of the §IV-C3 product. A zero-alpha cell scores below any whole path of non-zero
        # cells, so when every path has product 0 the one with the fewest zero cells wins.
        floor = _LOG_FLOOR_PER_CELL * (steps + 2)
        return np.where(alpha > 0.0, _log(alpha), floor)
    raise ValueError(f"unknown MLDP objective {objective!r}; choose 'sum' or 'product'")


def most_likely_detection_path(
    grid: Grid,
    alpha: npt.ArrayLike,
    start_cell: int,
    end_cell: int,
    steps: int,
    *,
    blocked: npt.ArrayLike | None = None,
    objective: Objective = "sum",
) -> list[int]:
    """MLDP (§IV-C3): the ``steps + 1`` flat cells from ``start_cell`` to ``end_cell``, each an App. I
    neighbour of the last (staying counts), inside the area and never in a blocked or obstacle cell,
    that are most likely to detect odour on the plume map ``alpha`` (shape (n, m)).

    ``objective="product"`` is the paper's recursion, the product of alpha along the path. The
    default ``"sum"`` maximises sum(alpha): the probability of at least one detection, 1 - prod(1 -
    mu alpha), is mu sum(alpha) to first order when alpha is small, whereas the product is ruled by
    the path's weakest cells (one zero-alpha cell zeroes it). Each tick in a cell is one detection
    chance, so staying in a cell counts its alpha again.
    NoPathError when ``end_cell`` cannot be reached in exactly ``steps`` moves.
    """
    if steps < 0:
        raise ValueError(f"steps must be non-negative, got {steps}")
    field = _plume_map(grid, alpha)
    gain = _gain(field, objective, steps)
    gain[_closed_cells(grid, blocked)] = -np.inf
    start_row, start_col = grid.row_col(start_cell)
    end_row, end_col = grid.row_col(end_cell)
    # §IV-C3 initialisation: mu_m(0) = delta_mj alpha_j, the zero-move path that is the end cell
    value = np.full(grid.shape, -np.inf)
    value[end_row, end_col] = gain[end_row, end_col]
    choices = []
    for _ in range(steps):
        # §IV-C3: mu_m(k+1) = alpha_m (op) max_n Ne_n(m) mu_n(k); op is + for sums and for log products
        best, choice = _first_best(_neighbour_values(value))
        value = gain + best
        choices.append(choice)
    if not np.isfinite(value[start_row, start_col]):
        raise NoPathError(
            f"no connected {steps}-move path from C{grid.paper_number(start_cell)} "
            f"to C{grid.paper_number(end_cell)} avoiding blocked cells"
        )
    # §IV-C3 termination: walk from the start along psi
    path = [start_cell]
    row, col = start_row, start_col
    for choice in reversed(choices):
        d_row, d_col = _MOVES[choice[row, col]]
        row, col = row + d_row, col + d_col
        path.append(row * grid.columns + col)
    return path


def one_step_mldp(
    grid: Grid, alpha: npt.ArrayLike, cell: int, *, blocked: npt.ArrayLike | None = None
) -> int:
    """The §VI planner step: the flat index of the neighbouring cell (one of 8, inside the area,
    not blocked, not an obstacle, not ``cell`` itself) with the highest alpha."""
    field = _plume_map(grid, alpha)
    row, col = grid.row_col(cell)
    values = np.where(_closed_cells(grid, blocked), -np.inf, field)
    around = _neighbour_values(values)[:, row, col, None]  # shape (9, 1)
    around[_STAY] = -np.inf
    best, choice = _first_best(around)
    if not np.isfinite(best[0]):
        raise NoPathError(f"C{grid.paper_number(cell)} has no open neighbouring cell")
    d_row, d_col = _MOVES[int(choice[0])]
    return (row + d_row) * grid.columns + (col + d_col)
