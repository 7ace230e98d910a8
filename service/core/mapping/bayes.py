"""Bayesian source likelihood map (seed reactive-planning, Pang and Zhu 2009, §II-B, eq. 1-5).

For the vehicle's cell C_j, eq. 5 sums the single-filament probabilities over the release times
of the window: L_i = sum_l P_i(t_l), with P_i(t_l) = p_ij(t_l, t_k) from ``filament`` (eq. 1-4).
Because p_ij is separable, L is one small matrix product of the stacked per-axis factors.

The paper says the map is "updated in response to both detection and nondetection events" and
defers the details to its ref. [26]. Our reading: L_i is the expected number of filaments in the
vehicle's cell if the source is in C_i, the chance that detectable odour is there is
q_i = min(1, L_i), and the binary detector reports it with probability mu, so
P(d | i) = pf + (1 - pf) mu q_i and P(no d | i) = 1 - P(d | i); pi is then fused by Bayes' rule,
posterior proportional to prior times P(event | i), for detections and non-detections alike.

The POMDP mapper (``pomdp``) uses the same filament probabilities but combines release times as
independent chances, 1 - prod_l (1 - mu p_ij(t_l)), a product over the window; here they are
summed and capped. The two agree while the expected count is small and differ near the source,
where the sum saturates at 1 and the product approaches it smoothly.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from service.core.mapping.belief import FloatArray
from service.core.mapping.mapper import WIDE_SPREAD, ObservationModelMapper


class BayesMapper(ObservationModelMapper):
    name: ClassVar[str] = "bayes"

    def event_likelihood(
        self, cell: int, at: tuple[float, float] | None = None, spread: float = 1.0
    ) -> FloatArray:
        """L_i of eq. 5 for a vehicle in flat cell ``cell`` (at ``at`` in it): expected filaments
        there, with their random walk ``spread`` times sigma, shape (n, m)."""
        px, py, weight = self._filament_factors(cell, at, spread)
        # eq. 5: pi_i = sum_l P_i(t_l), with P_i(t_l) = py_l(row) px_l(col), a merged run of the
        # prehistory counted as often as it stands for (eq. R1)
        out: FloatArray = (py * weight[:, None]).T @ px
        return out

    def _event_probability(
        self, cell: int, detected: bool, at: tuple[float, float] | None = None
    ) -> FloatArray:
        """P(d | i) = pf + (1 - pf) mu q_i, or P(no d | i) = (1 - pf)(1 - mu q_i), shape (n, m); q_i
        mixed with the wide plume's by eq. W1 when ``wide_share`` > 0."""
        p = self.params
        q = np.minimum(self.event_likelihood(cell, at), 1.0)
        if p.wide_share > 0.0:
            wide = np.minimum(self.event_likelihood(cell, at, WIDE_SPREAD), 1.0)
            q = (1.0 - p.wide_share) * q + p.wide_share * wide
        # the miss floor r caps what odour in the cell promises: P(no d | i) >= (1 - pf) r
        seen = (1.0 - p.miss_floor) * p.mu * q
        out: FloatArray = (
            p.false_alarm + (1.0 - p.false_alarm) * seen if detected else (1.0 - p.false_alarm) * (1.0 - seen)
        )
        return out
