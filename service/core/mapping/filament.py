"""The single-filament model shared by the Bayesian and POMDP mappers.

Seed reactive-planning §II-A/B (eq. 1-4) and seed pomdp-astar §II-C eq. 1. A filament released
from a source at X_i at time t_l drifts with the flow record and random-walks with variance
(t_k - t_l) sigma^2 per axis, so at t_k it is at X_i + V(t_l, t_k) + W with
V(t_l, t_k) = sum_{i=l}^{k-1} U dt (reactive-planning eq. 4) and W ~ N(0, (t_k - t_l) sigma^2).
The probability that it is in the vehicle's cell C_j now, p_ij(t_l, t_k), is separable:
p_ij = p_y(row of C_i) p_x(column of C_i).

Eq. 1 of pomdp-astar evaluates the Gaussian density at the cell centres and multiplies by the
cell area L_x L_y (the midpoint rule); that exceeds 1 for short lags when a cell is large compared
with sigma sqrt(t_k - t_l). We use the exact Gaussian mass over the cell instead, a difference of
normal CDFs across the cell's extent: it is equally separable, always in [0, 1], and equals eq. 1
to first order when the cell is small compared with the spread.

A point detector with a growing footprint (ours, off by default): the papers count a filament as
smelt when it lies anywhere in the vehicle's cell. A source in the vehicle's own cell then always has
this tick's filament there, and each detection favours that cell over a source upflow, whose
filaments have spread; the detector does the opposite, since a plume is narrow at its source and
wider downflow (docs/search-steps.md, step 18). With ``footprint_m`` = r0 > 0 the detector sits
at the vehicle's position and smells a filament of age tau within

    r(tau) = sqrt(r0^2 + g tau)                                             (footprint eq. F1)

of its centre on each axis (g = ``footprint_growth``, m^2/s: a puff's radius grows as it ages),
the source uniform over its cell. Per axis, with c the vehicle's position less the drift, s the
filament's spread and [x_lo, x_hi] the source cell of width L,

    P = [I(c + r) - I(c - r)] / L,   I(a) = s [G((a - x_lo) / s) - G((a - x_hi) / s)]   (eq. F2)

where G(z) = z Phi(z) + phi(z) is the integral of the normal CDF (I(a) is the integral over the
cell of Phi((a - X) / s)). The axes stay independent, so p_ij stays separable.

A release older than the service (ours): a source has usually been releasing long before the
vehicle arrives, and the flow before the first tick is unknown, not absent. Counting only the
releases since the service started would let a plume reach only as far downflow as the flow has
run since then (20 m after 20 s at 1 m/s), so an early detection would put the source next to the
vehicle. ``prehistory`` therefore continues the record back in time with the mean step of the
record (its mean flow), until the oldest release has drifted ``reach_m`` (the area's diagonal:
every source in the area is in reach) or ``MAX_RELEASES`` release times are counted. Its old
filaments have spread far wider than a tick's drift, so runs of them are merged into one release
of the run's weight (``merged_steps``, eq. R1).

Release times are one per flow-history entry: the filament released at the start of the newest
entry has lag dt_newest and drift (dx, dy)_newest, the one before it the cumulative sums of the
two newest entries, and so on back through the window. Rows of every stacked array below are
ordered newest release first (shortest lag first).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import ndtr

from service.core.mapping.belief import FloatArray

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.mapping.mapper import FlowStep


MAX_RELEASES = 600
"""Most release times a prehistory extends the record to (bounds the work per tick)."""
PREHISTORY_MERGE = 0.5
"""The prehistory's releases are merged into runs that drift at most this share of their spread
(eq. R1)."""


def release_offsets(
    history: Iterable[FlowStep], reach_m: float = 0.0, sigma: float = 0.0
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Lag t_k - t_l (s), drift V(t_l, t_k) (m, x and y) and weight (how many releases it stands
    for) of each release time, newest first. With ``reach_m`` > 0 the record is continued with its
    mean step (the prehistory) until the oldest release has drifted that far; with ``sigma`` > 0
    (the filaments' random walk, m/sqrt(s)) the prehistory's releases are merged (eq. R1)."""
    steps = list(history)[::-1]
    dt = np.fromiter((s.dt_s for s in steps), dtype=float, count=len(steps))
    dx = np.fromiter((s.dx_m for s in steps), dtype=float, count=len(steps))
    dy = np.fromiter((s.dy_m for s in steps), dtype=float, count=len(steps))
    lag, drift_x, drift_y = np.cumsum(dt), np.cumsum(dx), np.cumsum(dy)
    weight = np.ones(len(steps))
    if reach_m <= 0.0 or not steps:
        return lag, drift_x, drift_y, weight
    step_m = math.hypot(float(dx.mean()), float(dy.mean()))
    reached_m = math.hypot(float(drift_x[-1]), float(drift_y[-1]))
    if step_m <= 0.0 or reached_m >= reach_m:
        return lag, drift_x, drift_y, weight
    extra = min(math.ceil((reach_m - reached_m) / step_m), MAX_RELEASES - len(steps))
    if extra <= 0:
        return lag, drift_x, drift_y, weight
    # the prehistory: before the record, the record's mean step, again and again
    k = np.arange(1, extra + 1, dtype=float)
    count = np.ones(extra)
    if sigma > 0.0:
        k, count = merged_steps(k, lag[-1], float(dt.mean()), step_m, sigma)
    return (
        np.concatenate([lag, lag[-1] + k * dt.mean()]),
        np.concatenate([drift_x, drift_x[-1] + k * dx.mean()]),
        np.concatenate([drift_y, drift_y[-1] + k * dy.mean()]),
        np.concatenate([weight, count]),
    )


def merged_steps(
    k: FloatArray, lag_s: float, dt_s: float, step_m: float, sigma: float
) -> tuple[FloatArray, FloatArray]:
    """The prehistory's releases ``k`` steps before the record's oldest (at ``lag_s``), merged
    into runs that drift at most ``PREHISTORY_MERGE`` of their spread sigma sqrt(lag): each run
    is one release at its mean step, weighted by its length (eq. R1). Returns (mean step, length)
    per run, oldest last.

    A continuous source releases all the time; one filament per tick is a quadrature of that
    release over time. Old filaments have spread far more than the flow moves them in a tick, so
    neighbouring ones are nearly the same filament and a coarser quadrature gives the same
    chances: with runs at most half a spread long, P(detection) stays within 1 % (tested at 0.3
    and 1 m/s) while a 0.3 m/s flow's 420 prehistoric releases become 90 (docs/search-steps.md,
    step 31).

        run of step k = floor(sum_{j<=k} step_m / (PREHISTORY_MERGE sigma sqrt(lag_j)))   (eq. R1)
    """
    lags = lag_s + k * dt_s
    run = np.floor(np.cumsum(step_m / (PREHISTORY_MERGE * sigma * np.sqrt(lags)))).astype(np.intp)
    run -= run[0]
    length = np.bincount(run).astype(float)
    taken = length > 0
    mean = np.bincount(run, weights=k)[taken] / length[taken]
    return mean, length[taken]


def axis_cell_mass(edges: FloatArray, centre: FloatArray, spread: FloatArray) -> FloatArray:
    """Mass of N(centre_l, spread_l^2) between consecutive ``edges``, shape (W, len(edges) - 1).

    Each CDF value is taken from the nearer tail (F = Phi(z) - [z > 0]) so that the difference
    keeps full relative precision far out in either tail; the cell that straddles the centre
    gets the 1 back. A zero spread is a point mass (half to each side of an edge it sits on).
    """
    offset = edges[None, :] - centre[:, None]
    z = np.copysign(np.inf, offset)
    z[offset == 0.0] = 0.0
    np.divide(offset, spread[:, None], out=z, where=spread[:, None] > 0.0)
    tail = ndtr(-np.abs(z))
    upper = z > 0.0
    below = np.where(upper, -tail, tail)
    mass: FloatArray = np.diff(below, axis=1) + np.diff(upper.astype(float), axis=1)
    return np.clip(mass, 0.0, 1.0)


G_TAIL_Z = 9.0
"""Beyond |z| = this, G(z) = max(z, 0) to within 1e-20 (Phi's tail and phi there are below 1e-18)."""


def _normal_cdf_integral(z: FloatArray) -> FloatArray:
    """G(z) = z Phi(z) + phi(z), whose derivative is Phi(z); evaluated only where it differs from
    its asymptote max(z, 0) (about half of a tick's edges)."""
    out: FloatArray = np.maximum(z, 0.0)
    near = np.abs(z) < G_TAIL_Z
    zn = z[near]
    out[near] = zn * ndtr(zn) + np.exp(-0.5 * zn * zn) / math.sqrt(2.0 * math.pi)
    return out


def footprint_mass(
    edges: FloatArray, centre: FloatArray, spread: FloatArray, radius: FloatArray
) -> FloatArray:
    """P(|X + W - centre_l| < radius_l) for X uniform over each cell between consecutive ``edges``
    and W ~ N(0, spread_l^2): footprint eq. F2, shape (W, len(edges) - 1). A zero spread is the
    overlap of the footprint with the cell, over the cell's width."""
    s = np.maximum(spread, 1e-9)[:, None]

    def integral(a: FloatArray) -> FloatArray:
        # I(a) of eq. F2: the integral of Phi((a - X) / s) over X in [lo, hi]; G once per edge,
        # since each cell's hi is the next cell's lo
        g = _normal_cdf_integral((a - edges[None, :]) / s)
        out: FloatArray = s * (g[:, :-1] - g[:, 1:])
        return out

    c, r = centre[:, None], radius[:, None]
    mass: FloatArray = (integral(c + r) - integral(c - r)) / np.diff(edges)[None, :]
    return np.clip(mass, 0.0, 1.0)


def filament_factors(
    grid: Grid,
    x_m: float,
    y_m: float,
    lag_s: FloatArray,
    drift_x_m: FloatArray,
    drift_y_m: FloatArray,
    sigma_x: float,
    sigma_y: float,
    footprint_m: float = 0.0,
    footprint_growth: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Per-axis factors Px (W, m), Py (W, n) of p_ij(t_l, t_k) for a vehicle cell centred at (x, y).

    ``Py[l, row] * Px[l, col]`` is the probability that a filament released at release time l
    from a source in cell (row, col) is in the vehicle's cell now: the mass over cell C_i of the
    source position of eq. 4, X_s ~ N(X_j - V(t_l, t_k), (t_k - t_l) sigma^2), which is the same
    as the mass of the filament over C_j (pomdp-astar eq. 1, exact per cell rather than midpoint).
    With ``footprint_m`` > 0, (x, y) is the detector's own position and the filament is smelt
    within r(tau) of eq. F1 of it instead of in the cell (eq. F2).
    """
    x_edges: FloatArray = grid.x_min + np.arange(grid.columns + 1, dtype=np.float64) * grid.cell_width_m
    y_edges: FloatArray = grid.y_min + np.arange(grid.rows + 1, dtype=np.float64) * grid.cell_height_m
    # reactive-planning eq. 4: X_s = X_j - V(t_l, t_k) - W(t_l, t_k), W ~ N(0, (t_k - t_l) sigma^2)
    root_lag = np.sqrt(lag_s)
    spread_x, spread_y = sigma_x * root_lag, sigma_y * root_lag
    if footprint_m > 0.0:
        # footprint eq. F1: the detection radius of a filament of each release time's age
        radius = np.sqrt(footprint_m**2 + footprint_growth * lag_s)
        px = footprint_mass(x_edges, x_m - drift_x_m, spread_x, radius)
        py = footprint_mass(y_edges, y_m - drift_y_m, spread_y, radius)
        return px, py
    px = axis_cell_mass(x_edges, x_m - drift_x_m, spread_x)
    py = axis_cell_mass(y_edges, y_m - drift_y_m, spread_y)
    return px, py


def history_factors(
    grid: Grid,
    cell: int,
    history: Iterable[FlowStep],
    sigma_x: float,
    sigma_y: float,
    *,
    reach_m: float = 0.0,
    footprint_m: float = 0.0,
    footprint_growth: float = 0.0,
    at: tuple[float, float] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``filament_factors`` for flat cell ``cell`` over every release time in ``history``, and
    each release time's weight (``release_offsets``); with
    ``reach_m`` > 0 adds the prehistory, its releases merged (eq. R1);
    ``footprint_m`` > 0 the point detector of eq. F1-F2, at ``at`` (the vehicle's position in
    ``cell``; the cell's centre when None), which also smells the release of this very tick (lag
    0, still at its source, within r0 of the detector: the first row). A continuous source has odour
    at its own position now; the papers' cell detector counts the releases up to the previous tick
    only, so a vehicle at the source expects odour only if last tick's filament has not left its
    cell, and a point detector 1 m from that filament would expect little odour at the source."""
    lag, drift_x, drift_y, weight = release_offsets(history, reach_m, min(sigma_x, sigma_y))
    point = footprint_m > 0.0
    if point:
        lag, drift_x, drift_y = (np.concatenate([[0.0], a]) for a in (lag, drift_x, drift_y))
        weight = np.concatenate([[1.0], weight])
    x, y = at if at is not None and point else grid.centre(cell)
    px, py = filament_factors(
        grid,
        x,
        y,
        lag,
        drift_x,
        drift_y,
        sigma_x,
        sigma_y,
        footprint_m=footprint_m,
        footprint_growth=footprint_growth,
    )
    return px, py, weight
