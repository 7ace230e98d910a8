"""The odour transition operator A(t) built from the mean flow of one tick.

Seed hmm-plume-mapping App. II: with a spatially uniform flow over a tick, odour in a cell can
only reach its 8 neighbours or stay, and the probabilities factor into an x part and a y part::

    a = [1 - c_x, c_x] (x) [1 - c_y, c_y],   c = u dt / L   (the u_x > 0, u_y > 0 case)

We keep that product form and generalise each factor to a three-point kernel over
(one cell toward lower index, stay, one cell toward higher index) whose mean is the drift c and
whose variance is the random walk of seed reactive-planning eq. 1 (sigma^2 dt / L^2), or the
smallest variance a three-point kernel with that drift can have, c (1 - c), whichever is larger.
With sigma = 0 this is exactly App. II's stencil for all eight sign cases. When |c| > 1 (or the
variance is too large for three points) the tick is split into equal sub-steps, each a stencil
with at most 9 nonzeros per row.

Because every sub-step is a Kronecker product ``A_y (x) A_x`` of two 1-D operators, and a 2-D
move stays inside the area exactly when both 1-D moves do, every product of operators is also a
Kronecker product. Mass that leaves the area goes to the exterior cell C0, which keeps it.
The operator is therefore never stored as a matrix: it is applied by shifting arrays.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
from scipy import sparse

from service.core.grid import NEIGHBOUR_OFFSETS

if TYPE_CHECKING:
    from service.core.grid import Grid

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class AxisKernel:
    """One sub-step along one axis: P(move to lower index), P(stay), P(move to higher index)."""

    lower: float
    stay: float
    higher: float

    def __post_init__(self) -> None:
        if min(self.lower, self.stay, self.higher) < -1e-12:
            raise ValueError(f"negative transition probability in {self}")
        if abs(self.lower + self.stay + self.higher - 1.0) > 1e-9:
            raise ValueError(f"kernel {self} does not sum to 1")

    @property
    def weights(self) -> tuple[float, float, float]:
        return (self.lower, self.stay, self.higher)


def _substeps_needed(drift: float, variance: float) -> int:
    s = max(1, math.ceil(abs(drift) - 1e-12))
    while True:
        c = drift / s
        v = max(variance / s, abs(c) * (1.0 - abs(c)))
        if v + c * c <= 1.0 + 1e-12:
            return s
        s += 1


def axis_kernel(drift: float, variance: float, substeps: int) -> AxisKernel:
    """Three-point kernel of one sub-step with mean drift/s and variance max(var/s, |c|(1-|c|)).

    Moment matching: higher - lower = c and higher + lower = v + c^2 (App. II when variance = 0).
    """
    c = drift / substeps
    v = max(variance / substeps, abs(c) * (1.0 - abs(c)))
    # a weight that is 0 in exact arithmetic (the upflow side with no spreading) can round to
    # -1e-17; clamp it so every entry of A is a probability
    higher = max(0.5 * (v + c * c + c), 0.0)
    lower = max(0.5 * (v + c * c - c), 0.0)
    return AxisKernel(lower=lower, stay=max(1.0 - higher - lower, 0.0), higher=higher)


def push_axis(values: FloatArray, kernel: AxisKernel, axis: int) -> FloatArray:
    """Forward step along one axis (row vector times A): mass moves; what crosses the edge is lost."""
    v = np.moveaxis(values, axis, -1)
    out = kernel.stay * v
    out[..., 1:] += kernel.higher * v[..., :-1]
    out[..., :-1] += kernel.lower * v[..., 1:]
    return np.moveaxis(out, -1, axis)


def pull_axis(values: FloatArray, kernel: AxisKernel, axis: int) -> FloatArray:
    """Backward step along one axis (A times column vector): what reaches ``values`` from each cell."""
    v = np.moveaxis(values, axis, -1)
    out = kernel.stay * v
    out[..., :-1] += kernel.higher * v[..., 1:]
    out[..., 1:] += kernel.lower * v[..., :-1]
    return np.moveaxis(out, -1, axis)


@dataclass(frozen=True)
class Transition:
    """A(t) for one tick: ``substeps`` repetitions of the sub-step ``y (x) x`` (App. II)."""

    x: AxisKernel
    y: AxisKernel
    substeps: int

    def push(self, field: FloatArray) -> FloatArray:
        """alpha A-bar (eq. 8): propagate an (n, m) field of odour forward one tick."""
        out = field
        for _ in range(self.substeps):
            out = push_axis(push_axis(out, self.x, axis=-1), self.y, axis=-2)
        return out

    def pull(self, field: FloatArray) -> FloatArray:
        """A-bar beta (eq. 14): propagate an (n, m) field backward one tick."""
        out = field
        for _ in range(self.substeps):
            out = pull_axis(pull_axis(out, self.x, axis=-1), self.y, axis=-2)
        return out

    def pull_x(self, values: FloatArray) -> FloatArray:
        """The 1-D x factor of ``pull`` over a vector (or stack of vectors) of length m."""
        for _ in range(self.substeps):
            values = pull_axis(values, self.x, axis=-1)
        return values

    def pull_y(self, values: FloatArray) -> FloatArray:
        """The 1-D y factor of ``pull`` over a vector (or stack of vectors) of length n."""
        for _ in range(self.substeps):
            values = pull_axis(values, self.y, axis=-1)
        return values

    def stencil(self) -> FloatArray:
        """3 x 3 sub-step weights, ``[dy + 1, dx + 1]`` = P(move dx columns east, dy rows north)."""
        return np.outer(self.y.weights, self.x.weights)


def transition(
    grid: Grid,
    flow_x_mps: float,
    flow_y_mps: float,
    dt_s: float,
    sigma_x: float = 0.0,
    sigma_y: float = 0.0,
) -> Transition:
    """A(t) from the tick's mean flow (App. II) with random-walk spreading sigma (m / sqrt(s))."""
    values = (flow_x_mps, flow_y_mps, dt_s, sigma_x, sigma_y)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"transition needs finite flow, dt and sigma, got {values}")
    if dt_s < 0 or sigma_x < 0 or sigma_y < 0:
        raise ValueError(f"dt and sigma must be non-negative, got dt={dt_s}, sigma=({sigma_x}, {sigma_y})")
    lx, ly = grid.cell_width_m, grid.cell_height_m
    cx, cy = flow_x_mps * dt_s / lx, flow_y_mps * dt_s / ly
    vx, vy = sigma_x**2 * dt_s / lx**2, sigma_y**2 * dt_s / ly**2
    s = max(_substeps_needed(cx, vx), _substeps_needed(cy, vy))
    return Transition(x=axis_kernel(cx, vx, s), y=axis_kernel(cy, vy, s), substeps=s)


def substep_matrix(grid: Grid, step: Transition, pi: FloatArray | None = None) -> sparse.csr_matrix:
    """The (N+1) x (N+1) sub-step matrix in the papers' numbering (index 0 is C0, k is C_k).

    Row C0 is ``pi`` (paper numbering, seed §III-C: a_0j = pi_j) when given, else C0 keeps its
    odour (a_00 = 1). For tests and for the Viterbi paths; the mappers never build it.
    """
    n_cells = grid.size
    stencil = step.stencil()
    rows: list[int] = []
    cols: list[int] = []
    vals: list[float] = []
    for k in range(1, n_cells + 1):
        leaving = 0.0
        for nb, (di, dj) in zip(grid.neighbours(k), NEIGHBOUR_OFFSETS, strict=True):
            # paper j grows southward, so a move of dj paper rows is -dj rows north
            w = float(stencil[1 - dj, 1 + di])
            if w == 0.0:
                continue
            if nb == 0:
                leaving += w
            else:
                rows.append(k)
                cols.append(nb)
                vals.append(w)
        if leaving > 0.0:
            rows.append(k)
            cols.append(0)
            vals.append(leaving)
    if pi is None:
        rows.append(0)
        cols.append(0)
        vals.append(1.0)
    else:
        for k, p in enumerate(np.asarray(pi, dtype=float).ravel(), start=1):
            if p != 0.0:
                rows.append(0)
                cols.append(k)
                vals.append(float(p))
    return sparse.csr_matrix((vals, (rows, cols)), shape=(n_cells + 1, n_cells + 1))


def tick_matrix(grid: Grid, step: Transition) -> sparse.csr_matrix:
    """The whole tick's A(t) in paper numbering: the sub-step matrix to the power ``substeps``."""
    sub = substep_matrix(grid, step)
    out = sub
    for _ in range(step.substeps - 1):
        out = out @ sub
    return sparse.csr_matrix(out)


def paper_vector(grid: Grid, field: FloatArray) -> FloatArray:
    """An (n, m) field as the papers' length-N vector [f(C1), ..., f(CN)]."""
    return np.asarray(field, dtype=float).ravel()[grid.paper_order]


def field_from_paper(grid: Grid, vector: Iterable[float]) -> FloatArray:
    """Inverse of ``paper_vector``."""
    values = np.asarray(list(vector), dtype=float)
    out = np.empty(grid.size)
    out[grid.paper_order] = values
    return out.reshape(grid.shape)
