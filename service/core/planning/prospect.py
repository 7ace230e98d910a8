"""Plume finding by the map: the leg most likely to meet odour for the distance it costs.

Before the first detection the source map holds what the misses so far say: a source whose plume
the vehicle has crossed without smelling it has lost weight, every other one kept it. The chance
that a straight leg meets odour is then

    P(odour on the leg) = 1 - sum_i pi_i prod_k (1 - q(c_k - i))                  (prospect eq. P1)

over the cells c_k the vehicle is in at the ticks along the leg, where q(offset) is the mapper's
own P(odour detected | source at that offset) under the current flow history (no false alarms:
``SourceMapper.odour_kernel``) and the ticks are taken as independent, as the mapper's updates
take them. A contact is worth only the trace that follows it, so the leg chosen maximises P1 per
metre of what it is expected to cost: its length, ``TURN_COST_M``, and, if it meets odour, the
trace from there to the source, D_i metres along the flow from source i to where its plume meets
the leg, at ``TRACE_COST`` per metre:

    leg* = argmax P1 / (length + TURN_COST_M + TRACE_COST sum_i P1_i D_i)         (prospect eq. P2)

where P1_i = pi_i (1 - prod_k (1 - q(c_k - i))) is source i's share of P1.

Nothing here is tuned to where plumes are: with a uniform map and a plume that has been released
for longer than the flow takes to cross the area, P1 is largest across the flow near the
downflow boundary (every source upflow of such a leg has its plume cross it), so the first legs
go there, as close to the map's mass as the trace cost makes worth it; after a dry pass the
sources whose plumes it crossed have lost weight and the next legs move upflow. A plume that
cannot have reached a leg yet is the mapper's business (its flow history and prehistory), not
this module's.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import sliding_window_view

from service.core.planning.base import Waypoint
from service.core.planning.crossflow import centre_hull

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.mapping.belief import FloatArray

TRACE_COST = 8.0
"""What a metre between a contact and its source costs, in metres flown: tracing weaves and waits
for odour, and the farther downflow the contact the likelier the plume is lost on the way. Chosen
on the suite's seeds 0-19: 2, 4 and 8 made 140, 153 and 155 of 260 (docs/search-steps.md)."""
TURN_COST_M = 10.0
"""Distance a new leg is charged besides its length (slowing, turning, settling on the line)."""
CANDIDATE_SPACING_M = 10.0
"""Leg ends are taken at least this far apart on a lattice over the hull of the cell centres ..."""
CANDIDATE_LINES = 11
"""... with at most this many lines of the lattice across each side (bounds the work per leg)."""
MIN_LEG_M = 5.0
"""A leg shorter than this is not a candidate (it would be flown in a tick or two)."""


def leg_cells(
    grid: Grid, start: tuple[float, float], end: tuple[float, float], step_m: float
) -> npt.NDArray[np.intp]:
    """(row, column) of the cell the vehicle is in at each tick of the straight leg from ``start``
    to ``end`` at ``step_m`` per tick (the first tick one step from ``start``), shape (K, 2)."""
    length = math.dist(start, end)
    count = max(1, math.ceil(length / step_m))
    t = np.arange(1, count + 1, dtype=float) / count
    x = start[0] + t * (end[0] - start[0])
    y = start[1] + t * (end[1] - start[1])
    return np.stack(grid.rows_columns_of(x, y), axis=1)


def seen_from(
    offsets: npt.NDArray[Any], shape: tuple[int, int], rows: npt.NDArray[np.intp], cols: npt.NDArray[np.intp]
) -> npt.NDArray[Any]:
    """A field over source-minus-vehicle offsets, (2n - 1, 2m - 1), as the (n, m) map of sources
    seen from each vehicle cell (``rows``, ``cols``): shape (K, n, m), views, no copy of the field."""
    n, m = shape
    windows = sliding_window_view(offsets, (n, m))
    # the source map seen from cell (r, c) is the window starting at (n - 1 - r, m - 1 - c)
    out: npt.NDArray[Any] = windows[n - 1 - rows, m - 1 - cols]
    return out


def odour_chances(
    pi: FloatArray, log_miss: npt.NDArray[np.floating[Any]], cells: npt.NDArray[np.intp]
) -> FloatArray:
    """pi_i (1 - prod_k (1 - q(c_k - i))): each source's share of eq. P1 for the ticks at ``cells``
    (from ``leg_cells``), given the source map ``pi`` (n, m) and log(1 - q) over offsets,
    ``log_miss`` (2n - 1, 2m - 1). Their sum is eq. P1."""
    m = pi.shape[1]
    flat, counts = np.unique(cells[:, 0] * m + cells[:, 1], return_counts=True)
    rows, cols = np.divmod(flat, m)
    total = np.einsum("k,kij->ij", counts.astype(log_miss.dtype), seen_from(log_miss, pi.shape, rows, cols))
    shares: FloatArray = pi * -np.expm1(total)
    return shares


def trace_distance(
    x: FloatArray,
    y: FloatArray,
    start: tuple[float, float],
    end: tuple[float, float],
    flow: tuple[float, float],
) -> FloatArray:
    """Distance from each source (x, y) to where its plume, the ray downflow along the unit vector
    ``flow``, meets the leg from ``start`` to ``end`` (the nearer end of the leg when the ray
    misses it; the nearest point of the leg when the leg runs along the flow)."""
    dx, dy = end[0] - start[0], end[1] - start[1]
    ux, uy = flow
    rx, ry = start[0] - x, start[1] - y
    # source + s u = start + t d: t = (r x u) / (u x d)
    det = ux * dy - uy * dx
    length2 = dx * dx + dy * dy
    along_leg = abs(det) <= 1e-6 * math.sqrt(length2)
    t = -(rx * dx + ry * dy) / length2 if along_leg else (rx * uy - ry * ux) / det
    t = np.clip(t, 0.0, 1.0)
    out: FloatArray = np.hypot(rx + t * dx, ry + t * dy)
    return out


def candidate_ends(grid: Grid) -> list[Waypoint]:
    """Leg ends: a lattice over the hull of the cell centres, its edges and corners included,
    ``CANDIDATE_SPACING_M`` apart or ``CANDIDATE_LINES`` lines a side; none in an obstacle."""
    x0, y0, x1, y1 = centre_hull(grid)
    xs = np.linspace(x0, x1, min(CANDIDATE_LINES, max(2, round((x1 - x0) / CANDIDATE_SPACING_M) + 1)))
    ys = np.linspace(y0, y1, min(CANDIDATE_LINES, max(2, round((y1 - y0) / CANDIDATE_SPACING_M) + 1)))
    points = [Waypoint(float(x), float(y)) for x in xs for y in ys]
    return [p for p in points if not grid.in_obstacle(p.x, p.y)]


def best_leg(
    grid: Grid,
    pi: FloatArray,
    kernel: FloatArray,
    start: tuple[float, float],
    step_m: float,
    ends: list[Waypoint],
    flow: tuple[float, float],
) -> tuple[Waypoint, float] | None:
    """Eq. P2 over the straight legs from ``start`` to each of ``ends``: the best end and its
    eq. P1 chance; None when no end is at least ``MIN_LEG_M`` away. ``kernel`` is the mapper's
    ``odour_kernel``; ``step_m`` the distance the vehicle covers in a tick."""
    with np.errstate(divide="ignore"):
        log_miss = np.log1p(-kernel).astype(np.float32)
    x, y = np.meshgrid(grid.x_centres, grid.y_centres)
    best: tuple[Waypoint, float] | None = None
    best_score = -math.inf
    for end in ends:
        length = math.dist(start, (end.x, end.y))
        if length < MIN_LEG_M:
            continue
        shares = odour_chances(pi, log_miss, leg_cells(grid, start, (end.x, end.y), step_m))
        chance = float(shares.sum())
        trace = float(np.vdot(shares, trace_distance(x, y, start, (end.x, end.y), flow)))
        score = chance / (length + TURN_COST_M + TRACE_COST * trace)
        if score > best_score:
            best, best_score = (end, chance), score
    return best
