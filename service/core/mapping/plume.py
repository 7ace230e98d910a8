"""Plume likelihood alpha: where detectable odour probably is, for a hypothesised source map.

Seed hmm-plume-mapping §IV-A, Table I: continuous release since t_0, averaged over release times.
"""

from __future__ import annotations

from service.core.mapping.belief import FloatArray
from service.core.mapping.transport import Transition


def advance_plume(alpha: FloatArray, pi: FloatArray, step: Transition, n: int) -> FloatArray:
    """alpha(t_n) from alpha(t_n-1), the source map pi and A(t_n-1); n >= 1 ticks since t_0."""
    # eq. 11: alpha(t_n) = (pi + n alpha(t_n-1) A(t_n-1)) / (n + 1)
    return (pi + n * step.push(alpha)) / (n + 1)
