"""Hidden-Markov source likelihood map (seed hmm-plume-mapping, Farrell, Pang and Li 2003).

alpha is the Table I forward recursion (kept by ``SourceMapper``). For a detection or a
non-detection in C_k, beta-bar_k (eq. 13-16) is computed exactly over the flow-history window by
backward propagation (eq. 14) of the Kronecker factors of A: with A = A_y (x) A_x,
beta_k(t_L, t_F) = (Phi_y e_row) (x) (Phi_x e_col), so the window sum is one small matrix
product of the stacked 1-D vectors. pi then adapts by §IV-B1 with eps_d and eps_c.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from service.core.mapping.belief import FloatArray, normalise
from service.core.mapping.mapper import SourceMapper


class HmmMapper(SourceMapper):
    name: ClassVar[str] = "hmm"

    def beta_bar(self, cell: int) -> FloatArray:
        """beta-bar_k(t_L) of eq. 16 over the window: P(odour released in C_i at a uniformly
        chosen tick of the window is in flat cell ``cell`` now), shape (n, m)."""
        row, col = self.grid.row_col(cell)
        depth = len(self.history) + 1
        bx = np.zeros((depth, self.grid.columns))
        by = np.zeros((depth, self.grid.rows))
        bx[0, col] = 1.0
        by[0, row] = 1.0
        # eq. 14: beta(t_L, t_F) = A(t_F) beta(t_L, t_F+1), newest tick first
        for f, step in enumerate(reversed(self.history), start=1):
            bx[f] = step.transition.pull_x(bx[f - 1])
            by[f] = step.transition.pull_y(by[f - 1])
        # eq. 16: the mean over release times of the outer products beta_y (x) beta_x
        out: FloatArray = (by.T @ bx) / depth
        return out

    def detection_likelihood(self, cell: int) -> FloatArray:
        p = self.params
        return p.false_alarm + (1.0 - p.false_alarm) * p.mu * self.beta_bar(cell)

    def _assimilate(self, cell: int, detected: bool, at: tuple[float, float]) -> None:
        beta = self.beta_bar(cell)
        total = float(beta.sum())
        if total <= 0.0:
            self._ignore("no_odour_path")
            return
        credit = beta / total
        p = self.params
        if detected:
            # §IV-B1, detection: pi = (1 - eps_d) pi + eps_d beta / |beta|_1
            self._pi = (1.0 - p.epsilon_d) * self._pi + p.epsilon_d * credit
        else:
            # §IV-B1, no detection: pi = (1 + eps_c) pi - eps_c beta / |beta|_1, clipped, normalised
            self._pi = normalise(np.maximum((1.0 + p.epsilon_c) * self._pi - p.epsilon_c * credit, 0.0))
