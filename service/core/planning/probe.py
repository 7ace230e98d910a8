"""The most informative place to look next, near the estimate.

Standing still, or shuttling along one line, repeats nearly the same observation. What one more
observation in cell j is worth is the mutual information between it and the source's cell:

    I(j) = H(sum_i pi_i P(d | i, j)) - sum_i pi_i H(P(d | i, j))                  (probe eq. I1)

with H the binary entropy and P(d | i, j) = pf + (1 - pf) q(i - j), q the mapper's own odour
kernel (``SourceMapper.odour_kernel``). It is largest where the sources the map still holds
disagree most about odour: just downflow of the estimate when its rival lies farther downflow,
just upflow when the rival lies upflow, beside it when the rival is across the flow.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from service.core.planning.prospect import seen_from

if TYPE_CHECKING:
    from service.core.mapping.belief import FloatArray


def _entropy(p: FloatArray) -> FloatArray:
    """Binary entropy in nats, 0 at p = 0 or 1."""
    q = np.clip(p, 1e-12, 1.0 - 1e-12)
    out: FloatArray = -(q * np.log(q) + (1.0 - q) * np.log1p(-q))
    return out


def information(
    pi: FloatArray, kernel: FloatArray, false_alarm: float, cells: npt.NDArray[np.intp]
) -> FloatArray:
    """Eq. I1 for an observation in each of ``cells`` ((K, 2) rows and columns), shape (K,).
    ``kernel`` is q over offsets, (2n - 1, 2m - 1), as ``SourceMapper.odour_kernel`` gives it."""
    likely = false_alarm + (1.0 - false_alarm) * seen_from(kernel, pi.shape, cells[:, 0], cells[:, 1])
    detect = np.einsum("ij,kij->k", pi, likely)
    out: FloatArray = _entropy(detect) - np.einsum("ij,kij->k", pi, _entropy(likely))
    return out
