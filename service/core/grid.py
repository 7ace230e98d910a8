"""The search grid: cells, the papers' cell numbering, neighbours and obstacles.

Seed hmm-plume-mapping §III-B and App. I. Arrays over the grid have shape (rows, columns) =
(n, m) and are indexed ``[row, col]`` with row 0 at the southern edge (y_min) and col 0 at the
western edge (x_min), so ``array.ravel()`` gives the *flat index* ``f = row * m + col`` used
throughout the code.

The papers number cells from 1 as ``k = i + (j - 1) m`` with ``i`` the column counted from the
west and ``j`` the row counted from the *northern* edge; cell 0 (C0) is the exterior. Counting
rows from the north is what the papers' own examples require: App. I's "upper edge" cells are
those with j = 1, Fig. 6 starts the vehicle "near the top edge" in C64 (j = 2), and the Fig. 7
odour path from C488 to C388 under the +y flow of eq. 18 only exists if j decreases northward.
``paper_number`` and ``flat_index`` are the one place where the two numberings meet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from service.core.errors import ConfigError, OutsideAreaError

if TYPE_CHECKING:
    from service.core.config import AreaConfig

Rectangle = tuple[float, float, float, float]
"""An axis-aligned rectangle ``(x_min, y_min, x_max, y_max)`` in metres, map frame."""

EXTERIOR = 0
"""The papers' exterior cell C0: odour leaving the area goes there."""

# App. I order of a cell's (inclusive) neighbours as (di, dj) in paper indices.
NEIGHBOUR_OFFSETS: tuple[tuple[int, int], ...] = (
    (-1, -1), (0, -1), (1, -1),
    (-1, 0), (0, 0), (1, 0),
    (-1, 1), (0, 1), (1, 1),
)  # fmt: skip


@dataclass(frozen=True)
class Grid:
    """An ``rows x columns`` subdivision of the rectangle [x_min, x_max] x [y_min, y_max]."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    columns: int
    rows: int
    obstacles: tuple[Rectangle, ...] = field(default=())

    def __post_init__(self) -> None:
        values = (self.x_min, self.x_max, self.y_min, self.y_max)
        if not all(math.isfinite(v) for v in values):
            raise ConfigError(f"grid bounds must be finite, got {values}")
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ConfigError(f"grid bounds must have min < max, got {values}")
        if self.columns < 1 or self.rows < 1:
            raise ConfigError(f"grid needs at least one column and row, got {self.columns} x {self.rows}")

    @classmethod
    def from_config(cls, area: AreaConfig) -> Grid:
        return cls(
            x_min=area.x_min,
            x_max=area.x_max,
            y_min=area.y_min,
            y_max=area.y_max,
            columns=area.columns,
            rows=area.rows,
            obstacles=tuple(area.obstacles),
        )

    def subdivided(self, kx: int, ky: int) -> Grid:
        """The same area with every cell split into ``kx`` columns and ``ky`` rows."""
        return Grid(
            self.x_min, self.x_max, self.y_min, self.y_max, self.columns * kx, self.rows * ky, self.obstacles
        )

    def widened(self) -> Grid:
        """A grid of (2n - 1) x (2m - 1) cells of this size, no obstacles, whose centre cell
        (row n - 1, column m - 1) is this grid's cell (0, 0): every offset between two of this
        grid's cells is an offset from its centre cell (for translation-invariant kernels)."""
        w, h = self.cell_width_m, self.cell_height_m
        return Grid(
            self.x_min - (self.columns - 1) * w,
            self.x_max,
            self.y_min - (self.rows - 1) * h,
            self.y_max,
            2 * self.columns - 1,
            2 * self.rows - 1,
        )

    def coarsened(self, field: npt.NDArray[np.float64], kx: int, ky: int) -> npt.NDArray[np.float64]:
        """Sum a field of ``subdivided(kx, ky)`` over each of this grid's cells, shape (n, m)."""
        total: npt.NDArray[np.float64] = field.reshape(self.rows, ky, self.columns, kx).sum(axis=(1, 3))
        return total

    @property
    def shape(self) -> tuple[int, int]:
        """(n, m): the shape of every map array."""
        return (self.rows, self.columns)

    @property
    def size(self) -> int:
        """N = m n, the number of cells (C0 not included)."""
        return self.rows * self.columns

    @property
    def cell_width_m(self) -> float:
        """L_x, the cell size along x (East)."""
        return (self.x_max - self.x_min) / self.columns

    @property
    def cell_height_m(self) -> float:
        """L_y, the cell size along y (North)."""
        return (self.y_max - self.y_min) / self.rows

    @cached_property
    def x_centres(self) -> npt.NDArray[np.float64]:
        """Cell-centre x of each column, shape (m,)."""
        return np.asarray(self.x_min + (np.arange(self.columns) + 0.5) * self.cell_width_m, dtype=np.float64)

    @cached_property
    def y_centres(self) -> npt.NDArray[np.float64]:
        """Cell-centre y of each row, shape (n,)."""
        return np.asarray(self.y_min + (np.arange(self.rows) + 0.5) * self.cell_height_m, dtype=np.float64)

    def contains(self, x: float, y: float) -> bool:
        """True when (x, y) lies in the closed search rectangle."""
        return self.x_min <= x <= self.x_max and self.y_min <= y <= self.y_max

    def column_of(self, x: float) -> int:
        """Column of x; a point on a boundary belongs to the western cell (paper: 20 m is column 8)."""
        col = math.ceil((x - self.x_min) / self.cell_width_m) - 1
        return min(max(col, 0), self.columns - 1)

    def row_of(self, y: float) -> int:
        """Row (from the south) of y; a point on a boundary belongs to the northern cell."""
        j = math.ceil((self.y_max - y) / self.cell_height_m)
        j = min(max(j, 1), self.rows)
        return self.rows - j

    def rows_columns_of(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """``row_of`` and ``column_of`` of many points at once (the same boundary rule, clamped)."""
        col = np.clip(np.ceil((x - self.x_min) / self.cell_width_m) - 1, 0, self.columns - 1)
        row = self.rows - np.clip(np.ceil((self.y_max - y) / self.cell_height_m), 1, self.rows)
        return row.astype(np.intp), col.astype(np.intp)

    def cell_of(self, x: float, y: float) -> int:
        """Flat index of the cell holding (x, y); OutsideAreaError outside the area."""
        if not (math.isfinite(x) and math.isfinite(y)) or not self.contains(x, y):
            raise OutsideAreaError(f"({x}, {y}) is outside the search area")
        return self.row_of(y) * self.columns + self.column_of(x)

    def row_col(self, flat: int) -> tuple[int, int]:
        if not 0 <= flat < self.size:
            raise IndexError(f"flat index {flat} outside 0..{self.size - 1}")
        return divmod(flat, self.columns)

    def centre(self, flat: int) -> tuple[float, float]:
        """Map-frame (x, y) of a cell's centre."""
        row, col = self.row_col(flat)
        return float(self.x_centres[col]), float(self.y_centres[row])

    def paper_number(self, flat: int) -> int:
        """The papers' 1-based k = i + (j - 1) m of a flat index (seed hmm-plume-mapping §III-B)."""
        row, col = self.row_col(flat)
        i = col + 1
        j = self.rows - row
        return i + (j - 1) * self.columns

    def flat_index(self, k: int) -> int:
        """Inverse of ``paper_number``: i(k) = rem(k-1, m) + 1, j(k) = int((k-1)/m) + 1 (eq. 3-4)."""
        if not 1 <= k <= self.size:
            raise IndexError(f"cell C{k} outside C1..C{self.size}")
        i = (k - 1) % self.columns + 1
        j = (k - 1) // self.columns + 1
        return (self.rows - j) * self.columns + (i - 1)

    @cached_property
    def paper_order(self) -> npt.NDArray[np.intp]:
        """Flat index of C1, C2, ..., CN: ``field.ravel()[paper_order]`` is the papers' vector."""
        rows = self.rows - 1 - np.arange(self.rows)
        order = (rows[:, None] * self.columns + np.arange(self.columns)[None, :]).ravel()
        order.setflags(write=False)
        return order

    def neighbours(self, k: int) -> list[int]:
        """App. I neighbours function: the 9 paper numbers around C_k (itself included), 0 outside."""
        i = (k - 1) % self.columns + 1
        j = (k - 1) // self.columns + 1
        out = []
        for di, dj in NEIGHBOUR_OFFSETS:
            ii, jj = i + di, j + dj
            inside = 1 <= ii <= self.columns and 1 <= jj <= self.rows
            out.append(ii + (jj - 1) * self.columns if inside else EXTERIOR)
        return out

    @cached_property
    def obstacle_mask(self) -> npt.NDArray[np.bool_]:
        """(n, m) mask of cells that overlap an obstacle rectangle with positive area."""
        mask = np.zeros(self.shape, dtype=bool)
        lx, ly = self.cell_width_m, self.cell_height_m
        x0 = self.x_min + np.arange(self.columns) * lx
        y0 = self.y_min + np.arange(self.rows) * ly
        for ox0, oy0, ox1, oy1 in self.obstacles:
            cols = (x0 < ox1) & (x0 + lx > ox0)
            rows = (y0 < oy1) & (y0 + ly > oy0)
            mask |= np.outer(rows, cols)
        mask.setflags(write=False)
        return mask

    def in_obstacle(self, x: float, y: float) -> bool:
        """True when the point (x, y) lies inside (or on the edge of) an obstacle rectangle."""
        return any(x0 <= x <= x1 and y0 <= y <= y1 for x0, y0, x1, y1 in self.obstacles)


MODEL_CELL_M = 1.0
"""Largest side of the cells the search models the source in, m (until the cell budget stops the
splitting: 1.25 x 1 m on the default area): about the width of a plume a few metres from its
source. In cells much wider than the plume a vehicle standing upflow of the source but inside its
cell misses odour the model promised there, and the map cannot hold the source; in cells as wide
as the detector's footprint a source on the boundary of two cells leaves a vehicle at either
centre beside the plume (docs/search-steps.md, steps 4 and 22)."""
MODEL_CELLS_MAX = 10_000
"""The model grid is split no further than this many cells (``oslim bench mapping``'s target size)."""


def model_division(grid: Grid) -> tuple[int, int]:
    """How many columns and rows (kx, ky) to split each of ``grid``'s cells into for the search's
    model: the longer side of the model's cells is split once more until no side exceeds
    MODEL_CELL_M, or until a further split would pass MODEL_CELLS_MAX cells."""
    kx = ky = 1
    while True:
        wide, high = grid.cell_width_m / kx, grid.cell_height_m / ky
        if max(wide, high) <= MODEL_CELL_M:
            return kx, ky
        nkx, nky = (kx + 1, ky) if wide >= high else (kx, ky + 1)
        if grid.size * nkx * nky > MODEL_CELLS_MAX:
            return kx, ky
        kx, ky = nkx, nky
