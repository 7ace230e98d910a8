"""The one interface every source mapper implements, and what all of them share.

A mapper consumes one ``Observation`` per tick. The tick's mean flow and duration give the
transition A(t) of the interval that just ended (seed hmm-plume-mapping App. II); it goes into a
bounded flow history and advances the plume likelihood alpha (Table I, eq. 11) for the current
source map. If the vehicle is inside the area, the detection or non-detection is then fused into
the source map by the method's own rule (``_assimilate``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from service.core.mapping.belief import FloatArray, bayes_update, entropy_nats
from service.core.mapping.filament import history_factors
from service.core.mapping.plume import advance_plume
from service.core.mapping.transport import AxisKernel, Transition, transition

if TYPE_CHECKING:
    from service.core.config import Config
    from service.core.grid import Grid
    from service.core.observation import Observation


@dataclass(frozen=True)
class MapperParams:
    """Model parameters shared by the mappers (units in the names or docs)."""

    window: int = 50
    """Flow-history window in ticks (beta-bar, Bayesian release times, POMDP h)."""
    sigma_x: float = 1.0
    """Random-walk spreading of a filament along x, m / sqrt(s) (seed reactive-planning eq. 1)."""
    sigma_y: float = 1.0
    forgetting: float = 0.0
    """Share of pi handed back to the uniform prior after each update (Bayesian and POMDP
    mappers; 0: the papers' models). The models take the flow at the vehicle for the flow
    everywhere; where it is not, they rule out true sources, and a flat share lets later
    detections bring such a cell back."""
    mu: float = 0.9
    """P(detect | detectable odour in the cell): the papers' mu."""
    false_alarm: float = 0.001
    """P(detect | no odour): keeps a single spurious hit from zeroing the true cell."""
    miss_floor: float = 0.0
    """P(no detection | odour predicted in the vehicle's cell) never falls below this (0: the
    papers' models). A plume narrower than a cell, or intermittent, can leave a vehicle in a
    cell it crosses dry; without a floor one such non-detection all but rules out every source
    whose filaments the model puts there (Bayesian and POMDP mappers)."""
    footprint_m: float = 0.0
    """Radius r0 (m) within which the detector, at the vehicle's position, smells a filament just
    released; 0: the papers' detection, a filament anywhere in the vehicle's cell (``filament``,
    eq. F1-F2; Bayesian and POMDP mappers)."""
    footprint_growth: float = 0.0
    """g (m^2/s): a filament's detection radius is sqrt(r0^2 + g tau) at age tau (eq. F1)."""
    wide_share: float = 0.0
    """w: the share of ticks whose odour reaches the vehicle through a plume ``WIDE_SPREAD`` times as
    wide as sigma says (a meander, a patchy puff that spread fast) rather than the narrow one
    (Bayesian and POMDP mappers; 0: the papers' single plume). See ``ObservationModelMapper``."""
    prehistory: bool = False
    """The release began before the service: continue the flow record back with its mean step
    until every source in the area is in reach (``filament.release_offsets``; Bayesian and POMDP
    mappers; False: the papers' releases since the first tick only)."""
    epsilon_d: float = 0.2
    """HMM pi adaptation gain on a detection (seed hmm-plume-mapping §IV-B1)."""
    epsilon_c: float = 0.02
    """HMM pi adaptation gain on a non-detection."""
    tick_s: float = 1.0
    """Nominal tick, used as dt for the first observation."""

    def __post_init__(self) -> None:
        if self.window < 1:
            raise ValueError(f"window must be >= 1, got {self.window}")
        if not (0 < self.mu <= 1 and 0 <= self.false_alarm < 1):
            raise ValueError(f"need 0 < mu <= 1 and 0 <= false_alarm < 1, got {self.mu}, {self.false_alarm}")
        if not 0 <= self.forgetting < 1:
            raise ValueError(f"forgetting must be in [0, 1), got {self.forgetting}")
        if not (self.footprint_m >= 0.0 and self.footprint_growth >= 0.0):
            raise ValueError(
                "footprint_m and footprint_growth must be >= 0, "
                f"got {self.footprint_m}, {self.footprint_growth}"
            )
        if not 0 <= self.wide_share <= 1:
            raise ValueError(f"wide_share must be in [0, 1], got {self.wide_share}")
        if not 0 <= self.miss_floor < 1:
            raise ValueError(f"miss_floor must be in [0, 1), got {self.miss_floor}")
        if not (0 < self.epsilon_d < 1 and 0 < self.epsilon_c < 1):
            raise ValueError("epsilon_d and epsilon_c must be in (0, 1)")

    @classmethod
    def from_config(cls, config: Config) -> MapperParams:
        m, s = config.mapping, config.sensor
        return cls(
            window=m.window,
            sigma_x=m.sigma_x,
            sigma_y=m.sigma_y,
            forgetting=m.forgetting,
            mu=s.detection_probability,
            false_alarm=s.false_alarm_probability,
            miss_floor=s.miss_floor,
            footprint_m=m.footprint_m,
            footprint_growth=m.footprint_growth,
            wide_share=m.wide_share,
            prehistory=m.prehistory,
            epsilon_d=m.epsilon_d,
            epsilon_c=m.epsilon_c,
            tick_s=m.tick_s,
        )


@dataclass(frozen=True)
class Estimate:
    """The mapper's best source cell: the papers' 1-based number, its centre and probability."""

    cell: int
    x: float
    y: float
    probability: float
    entropy: float


def estimate_of(pi: FloatArray, grid: Grid) -> Estimate:
    """The most likely cell of the source map ``pi`` over ``grid``."""
    flat = int(np.argmax(pi))
    x, y = grid.centre(flat)
    return Estimate(
        cell=grid.paper_number(flat), x=x, y=y, probability=float(pi.flat[flat]), entropy=entropy_nats(pi)
    )


@dataclass(frozen=True)
class FlowStep:
    """One tick of the flow history: its operator and the displacement u dt it carried."""

    transition: Transition
    dx_m: float
    dy_m: float
    dt_s: float


class SourceMapper(ABC):
    """Online source likelihood map over a grid (OSLIM)."""

    name: ClassVar[str]

    def __init__(self, grid: Grid, params: MapperParams | None = None) -> None:
        self.grid = grid
        self.params = params or MapperParams()
        n_cells = grid.size
        self._pi: FloatArray = np.full(grid.shape, 1.0 / n_cells)
        self._alpha: FloatArray = self._pi.copy()
        self._ticks = 0
        self._last_time: float | None = None
        self.history: deque[FlowStep] = deque(maxlen=self.params.window)
        self.ignored: dict[str, int] = {}
        self._reach_m = math.hypot(grid.x_max - grid.x_min, grid.y_max - grid.y_min)

    @property
    def likelihood(self) -> FloatArray:
        """The source likelihood map pi, shape (n, m), non-negative, summing to 1 (read-only view)."""
        view = self._pi.view()
        view.setflags(write=False)
        return view

    @property
    def plume(self) -> FloatArray:
        """The plume likelihood alpha for the current pi (Table I, eq. 11), shape (n, m)."""
        view = self._alpha.view()
        view.setflags(write=False)
        return view

    def estimate(self) -> Estimate:
        return estimate_of(self._pi, self.grid)

    def entropy(self) -> float:
        """Entropy of pi in nats."""
        return entropy_nats(self._pi)

    def update(self, obs: Observation) -> bool:
        """Fuse one tick; returns False (and counts why) when the observation was not used."""
        if self._last_time is None:
            dt = self.params.tick_s
        else:
            dt = obs.time_s - self._last_time
            if dt <= 0.0:
                self._ignore("time_not_increasing")
                return False
        step = transition(self.grid, obs.flow_x, obs.flow_y, dt, self.params.sigma_x, self.params.sigma_y)
        first = self._last_time is None
        self._last_time = obs.time_s
        if not first:
            self.history.append(FlowStep(step, obs.flow_x * dt, obs.flow_y * dt, dt))
            self._ticks += 1
            self._alpha = advance_plume(self._alpha, self._pi, step, self._ticks)
        if not self.grid.contains(obs.x, obs.y):
            self._ignore("outside_area")
            return False
        self._assimilate(self.grid.cell_of(obs.x, obs.y), obs.detected, (obs.x, obs.y))
        return True

    def save_state(self) -> dict[str, Any]:
        """Everything ``update`` has accumulated, as arrays (for the restart snapshot). Restoring it
        into a mapper of the same class, grid and parameters gives bit-for-bit the same maps."""
        steps = list(self.history)
        return {
            "pi": self._pi.copy(),
            "alpha": self._alpha.copy(),
            "ticks": np.array(self._ticks),
            "last_time": np.array(np.nan if self._last_time is None else self._last_time),
            # per step: x kernel (lower, stay, higher), y kernel, then dx_m, dy_m, dt_s
            "history": np.array(
                [[*s.transition.x.weights, *s.transition.y.weights, s.dx_m, s.dy_m, s.dt_s] for s in steps],
                dtype=float,
            ).reshape(len(steps), 9),
            "substeps": np.array([s.transition.substeps for s in steps], dtype=np.int64),
        }

    def restore_state(self, state: dict[str, Any]) -> None:
        """Load what ``save_state`` returned; ValueError (nothing changed) if it does not fit this grid."""
        pi = np.asarray(state["pi"], dtype=float)
        alpha = np.asarray(state["alpha"], dtype=float)
        history = np.asarray(state["history"], dtype=float)
        substeps = np.asarray(state["substeps"], dtype=np.int64)
        if pi.shape != self.grid.shape or alpha.shape != self.grid.shape:
            raise ValueError(f"map shape {pi.shape} does not fit the grid {self.grid.shape}")
        if not (np.isfinite(pi).all() and np.isfinite(alpha).all() and abs(pi.sum() - 1.0) < 1e-6):
            raise ValueError("the map is not a finite, normalised distribution")
        if history.ndim != 2 or history.shape[1] != 9 or substeps.shape != (history.shape[0],):
            raise ValueError("malformed flow history")
        steps = [
            FlowStep(
                Transition(AxisKernel(*row[0:3]), AxisKernel(*row[3:6]), int(n)),
                float(row[6]),
                float(row[7]),
                float(row[8]),
            )
            for row, n in zip(history, substeps, strict=True)
        ]
        last_time = float(state["last_time"])
        self._pi, self._alpha = pi.copy(), alpha.copy()
        self._ticks = int(state["ticks"])
        self._last_time = None if np.isnan(last_time) else last_time
        self.history = deque(steps[-self.params.window :], maxlen=self.params.window)

    def odour_kernel(self) -> FloatArray:
        """P(odour at the vehicle is detected | the source dr rows and dc columns from the vehicle's
        cell), at index (n - 1 + dr, m - 1 + dc), shape (2n - 1, 2m - 1): this mapper's own
        ``detection_likelihood`` under the current flow history, without false alarms, for a
        vehicle anywhere (the filament models depend only on the offset between the cells)."""
        wide = self.grid.widened()
        twin = type(self)(wide, self.params)
        twin.history = self.history
        twin._reach_m = self._reach_m
        pf = self.params.false_alarm
        likely = twin.detection_likelihood(wide.size // 2)
        kernel: FloatArray = np.clip((likely - pf) / (1.0 - pf), 0.0, 1.0)
        return kernel

    def _ignore(self, reason: str) -> None:
        self.ignored[reason] = self.ignored.get(reason, 0) + 1

    @abstractmethod
    def _assimilate(self, cell: int, detected: bool, at: tuple[float, float]) -> None:
        """Fuse a detection (or non-detection) in flat cell ``cell``, by a vehicle at ``at`` (map
        frame, m), at the latest tick into pi."""

    @abstractmethod
    def detection_likelihood(self, cell: int) -> FloatArray:
        """P(detection in flat cell ``cell`` now | source in each cell), shape (n, m), per this
        mapper's own model and the current flow history: what visiting ``cell`` is expected to
        give."""


WIDE_SPREAD = 3.0
"""How many times faster than sigma the wide plume of ``wide_share`` spreads: the suite's patchy and
meandering plumes random-walk at 0.4-0.8 m/sqrt(s) against the model's 0.2."""


class ObservationModelMapper(SourceMapper):
    """A mapper that fuses each event by Bayes' rule through its own observation model
    P(event | source in each cell): the Bayesian and POMDP mappers differ only in that model.

    With ``wide_share`` w > 0 the odour of a tick reaches the vehicle through the narrow plume of
    sigma with probability 1 - w and through a plume ``WIDE_SPREAD`` times as wide with probability
    w, so that P(no odour | i) = (1 - w) gamma_narrow + w gamma_wide        (two-plume eq. W1)
    with each gamma the method's own. A detection beside the narrow plume, common in a meandering
    or patchy one, is then explained by the sources upflow of it within the wide plume instead of
    by the false-alarm rate anywhere; and a miss beside the narrow plume weighs little against them.
    """

    def _filament_factors(
        self, cell: int, at: tuple[float, float] | None = None, spread: float = 1.0
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Px (W, m), Py (W, n) and each release time's weight (W,): one filament per release time
        of the window and the prehistory's merged runs, seen from ``cell``
        (from the position ``at`` in it, with a footprint; its centre otherwise), its random walk
        ``spread`` times sigma."""
        p = self.params
        return history_factors(
            self.grid,
            cell,
            self.history,
            p.sigma_x * spread,
            p.sigma_y * spread,
            reach_m=self._reach_m if p.prehistory else 0.0,
            footprint_m=p.footprint_m,
            footprint_growth=p.footprint_growth,
            at=at,
        )

    @abstractmethod
    def _event_probability(
        self, cell: int, detected: bool, at: tuple[float, float] | None = None
    ) -> FloatArray:
        """P(this detection / non-detection in flat cell ``cell`` | source in each cell), (n, m), for
        a vehicle at ``at`` in it (its centre when None)."""

    def detection_likelihood(self, cell: int) -> FloatArray:
        return self._event_probability(cell, detected=True)

    def _assimilate(self, cell: int, detected: bool, at: tuple[float, float]) -> None:
        likelihood = self._event_probability(cell, detected, at)
        if not float(np.vdot(self._pi, likelihood)) > 0.0:
            # only possible with pf = 0: no cell explains the event; keep pi rather than reset it
            self._ignore("impossible_event")
            return
        # posterior proportional to P(event | source) prior (reactive-planning §II-B, pomdp-astar eq. 6)
        self._pi = bayes_update(self._pi, likelihood)
        if self.params.forgetting > 0.0:
            share = self.params.forgetting
            self._pi = (1.0 - share) * self._pi + share / self._pi.size
