"""Source mapping that does not know how intermittent the plume is (ours, after seed pomdp-astar).

The POMDP mapper (``pomdp``) says a vehicle inside the plume's envelope detects with probability
mu, as if odour were always there: 1 - prod_l (1 - mu p_ij(t_l)). Real plumes are patchy. Twenty
metres downflow of a source on the plume's mean line, a detector meets odour in most ticks of a
nearly continuous plume and in a few percent of a patchy one (``sim_bridge.plume_stats``). With
mu taken as known, a run of misses on the true plume rules its source out; with mu lowered for
every world, a continuous plume's misses say too little.

Here the hit rate h (detections per tick while the vehicle is inside the plume's envelope) is
unknown, and the belief is over pairs (h, source cell) for a few levels of h:

    P(d | i, h) = pf + (1 - pf) h q_i,    q_i = 1 - prod_l (1 - p_ij(t_l))       (eq. I1)

with q_i the chance that the envelope of a source in C_i covers the vehicle's cell now (eq. 2 of
pomdp-astar with mu = 1). Bayes' rule updates the joint belief; the source map is its marginal
over h. Detections on a plume teach h as they teach the source: misses on a patchy plume lower
h instead of ruling the source out, while misses where a continuous plume should be still count.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from service.core.mapping.belief import FloatArray
from service.core.mapping.pomdp import PomdpMapper, log_non_detection

HIT_RATES: tuple[float, ...] = (0.03, 0.1, 0.25, 0.5, 0.75, 0.95)
"""The levels of h the belief spans (uniform prior): from a very patchy plume to a continuous one."""


class IntermittentMapper(PomdpMapper):
    name: ClassVar[str] = "intermittent"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._levels = np.asarray(HIT_RATES)[:, None, None]
        self._joint: FloatArray = np.broadcast_to(
            self._pi / len(HIT_RATES), (len(HIT_RATES), *self._pi.shape)
        ).copy()

    def envelope(self, cell: int) -> FloatArray:
        """q_i of eq. I1 for a vehicle in flat cell ``cell``, shape (n, m)."""
        px, py = self._filament_factors(cell)
        out: FloatArray = -np.expm1(log_non_detection(px, py, 1.0))
        return out

    def hit_rate_belief(self, where: npt.NDArray[np.bool_] | None = None) -> FloatArray:
        """P(h) for each level of ``HIT_RATES``: the joint belief's marginal over the sources, or
        over the sources in the cells ``where`` (a mask of the grid's shape), normalised."""
        joint = self._joint if where is None else self._joint[:, where]
        totals = joint.reshape(len(HIT_RATES), -1).sum(axis=1)
        out: FloatArray = totals / totals.sum()
        return out

    def _event_probability(self, cell: int, detected: bool) -> FloatArray:
        """P(event | i), h marginalised with its current belief per source (planners' prediction)."""
        p = self.params
        weights = self._joint / np.maximum(self._joint.sum(axis=0), np.finfo(float).tiny)
        seen = (weights * self._levels).sum(axis=0) * self.envelope(cell)
        detect: FloatArray = p.false_alarm + (1.0 - p.false_alarm) * seen
        return detect if detected else 1.0 - detect

    def _assimilate(self, cell: int, detected: bool) -> None:
        p = self.params
        # eq. I1 for every level of h at once, shape (levels, n, m)
        detect = p.false_alarm + (1.0 - p.false_alarm) * self._levels * self.envelope(cell)
        joint = self._joint * (detect if detected else 1.0 - detect)
        total = float(joint.sum())
        if not total > 0.0:
            self._ignore("impossible_event")
            return
        joint /= total
        if p.forgetting > 0.0:
            joint = (1.0 - p.forgetting) * joint + p.forgetting / joint.size
        self._joint = joint
        self._pi = joint.sum(axis=0)

    def save_state(self) -> dict[str, Any]:
        return {**super().save_state(), "joint": self._joint.copy()}

    def restore_state(self, state: dict[str, Any]) -> None:
        joint = np.asarray(state["joint"], dtype=float)
        if joint.shape != self._joint.shape:
            raise ValueError(f"joint belief shape {joint.shape} does not fit {self._joint.shape}")
        super().restore_state(state)
        self._joint = joint.copy()
