"""The vehicle's moves on the grid as data: the eight compass moves and which of them are allowed.

A move goes to one of the 8 neighbouring cells (seed hmm-plume-mapping App. I, without the cell
itself). It is *admissible* when the target is inside the area and not an obstacle cell and, for
a diagonal move, when neither cell it cuts the corner of is an obstacle cell: the straight segment
between two diagonal centres passes through the corner the four cells share, so forbidding corner
cutting keeps every segment between consecutive path centres inside free cells.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from service.core.grid import Grid
    from service.core.planning.base import BoolArray

COMPASS: tuple[tuple[int, int], ...] = (
    (0, 1),    # 0: East
    (1, 1),    # 1: North-East
    (1, 0),    # 2: North
    (1, -1),   # 3: North-West
    (0, -1),   # 4: West
    (-1, -1),  # 5: South-West
    (-1, 0),   # 6: South
    (-1, 1),   # 7: South-East
)  # fmt: skip
"""(d_row, d_col) of the eight moves; the index is the heading sector, 45 degrees each, counted
counter-clockwise from East (rows grow northward)."""


def heading_sector(heading_rad: float) -> int:
    """The compass sector (0..7) nearest a heading measured counter-clockwise from East."""
    return round(heading_rad / (math.pi / 4.0)) % 8


def move_length_m(grid: Grid, sector: int) -> float:
    """Distance between the centres of a cell and its neighbour in compass sector ``sector``."""
    d_row, d_col = COMPASS[sector]
    return math.hypot(d_col * grid.cell_width_m, d_row * grid.cell_height_m)


def step(grid: Grid, cell: int, sector: int) -> int | None:
    """The neighbour of ``cell`` in compass sector ``sector``; None outside the area."""
    row, col = divmod(cell, grid.columns)
    d_row, d_col = COMPASS[sector]
    r, c = row + d_row, col + d_col
    if 0 <= r < grid.rows and 0 <= c < grid.columns:
        return r * grid.columns + c
    return None


def admissible(grid: Grid, cell: int, sector: int, blocked: BoolArray) -> int | None:
    """The neighbour in sector ``sector`` if the move is admissible (see module doc), else None.
    The cell moved *from* may itself be blocked: a vehicle caught in one may always leave."""
    target = step(grid, cell, sector)
    if target is None or blocked.flat[target]:
        return None
    d_row, d_col = COMPASS[sector]
    if d_row and d_col:
        row, col = divmod(cell, grid.columns)
        if blocked[row + d_row, col] or blocked[row, col + d_col]:
            return None
    return target


def free_neighbours(grid: Grid, cell: int, blocked: BoolArray) -> list[tuple[int, int]]:
    """(sector, neighbour) of every admissible move from ``cell``, in compass order."""
    out = []
    for sector in range(len(COMPASS)):
        target = admissible(grid, cell, sector, blocked)
        if target is not None:
            out.append((sector, target))
    return out


def sector_between(grid: Grid, a: int, b: int) -> int:
    """The compass sector of the move from cell ``a`` to its neighbour ``b`` (ValueError if none)."""
    ra, ca = divmod(a, grid.columns)
    rb, cb = divmod(b, grid.columns)
    try:
        return COMPASS.index((rb - ra, cb - ca))
    except ValueError:
        raise ValueError(f"cells {a} and {b} are not neighbours") from None
