"""Shared steps on a source belief: normalise, apply a likelihood, entropy, best cell."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def normalise(belief: FloatArray) -> FloatArray:
    """Scale a non-negative map to sum 1; an all-zero (or non-finite) map becomes uniform."""
    total = float(belief.sum())
    if not np.isfinite(total) or total <= 0.0:
        return np.full_like(belief, 1.0 / belief.size)
    return belief / total


def bayes_update(prior: FloatArray, likelihood: FloatArray) -> FloatArray:
    """posterior = prior * likelihood, normalised (Bayes' rule; seed pomdp-astar eq. 6)."""
    return normalise(prior * likelihood)


def entropy_nats(belief: FloatArray) -> float:
    """Shannon entropy -sum p ln p of a normalised map, in nats."""
    p = belief[belief > 0.0]
    return float(-(p * np.log(p)).sum())
