"""POMDP source mapping (seed pomdp-astar, Wang and Pang, §II-C, eq. 1-6).

The source is static (eq. 4), so the belief update eq. 5 reduces to Bayes' rule with the
observation probability of eq. 3: for a vehicle in C_j, a source in C_i leaves no detectable
filament there with probability gamma_ij = prod_l (1 - mu p_ij(t_l, t_k)) over the window
(eq. 2), and b(c_i) is multiplied by 1 - gamma_ij on a detection and by gamma_ij on a
non-detection, then normalised (eq. 6). With a false-alarm rate pf the detector also fires with
no odour, so P(d | i) = 1 - (1 - pf) gamma_ij and P(no d | i) = (1 - pf) gamma_ij.

p_ij is separable (``filament``), but the product over release times is not. ``log_non_detection``
therefore splits log gamma = sum_l log1p(-mu px_l py_l) by release time: a lag whose largest term
x = mu px_l py_l is small uses the series log(1 - x) = -sum_k x^k / k, whose every term is a rank-one
outer product, so all such lags together cost one matrix product; a lag with a large x (short lags,
where the filament is concentrated) is evaluated directly, but only over the box where
mu px_l py_l can exceed the series' tolerance.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import numpy.typing as npt

from service.core.mapping.belief import FloatArray
from service.core.mapping.mapper import WIDE_SPREAD, ObservationModelMapper

SERIES_TOLERANCE = 1e-12
"""Bound on the truncation error of log gamma per release time (so about window x this in all)."""
MAX_SERIES_TERMS = 12
"""A lag that needs more terms than this is evaluated directly over its support box."""
DIRECT_COST_RATIO = 100.0
"""Cost of one directly evaluated log1p element relative to one multiply-add of a matrix product."""
WHOLE_DIRECT_SIZE = 50_000
"""Up to this many (release time, cell) pairs, eq. 2 is evaluated directly in one vectorised pass."""
BOX_GROUP_WASTE = 2.0
"""Consecutive direct lags are evaluated together over the union of their boxes while that union,
once per lag, holds at most this many times the cells of their own boxes."""
BOX_GROUP_MOST = 16
"""Most direct lags evaluated together."""


def series_terms(peak: FloatArray, tolerance: float = SERIES_TOLERANCE) -> npt.NDArray[np.intp]:
    """Terms K of -sum_{k<=K} x^k / k needed for |error| <= tolerance when 0 <= x <= peak; 0 if more
    than MAX_SERIES_TERMS would be needed.

    The remainder sum_{k>K} x^k / k is at most peak^(K+1) / (1 - peak), so K + 1 >=
    log(tolerance (1 - peak)) / log(peak) suffices.
    """
    small = np.clip(peak, np.finfo(float).tiny, 0.5)
    needed = np.ceil(np.log(tolerance * (1.0 - small)) / np.log(small)) - 1.0
    terms = np.maximum(needed, 1.0).astype(np.intp)
    terms[(peak > 0.5) | (terms > MAX_SERIES_TERMS)] = 0
    return terms


def _support(values: FloatArray, floor: FloatArray) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """First and one-past-last index of each row's entries above that row's ``floor`` (unimodal rows)."""
    above = values > floor[:, None]
    width = values.shape[1]
    first = np.argmax(above, axis=1)
    last = width - np.argmax(above[:, ::-1], axis=1)
    return first, np.where(above.any(axis=1), last, first)


def log_non_detection(px: FloatArray, py: FloatArray, mu: float, weight: FloatArray) -> FloatArray:
    """log gamma_ij (eq. 2) from the stacked factors Px (W, m) and Py (W, n), each release time's
    term counted ``weight`` (W,) times (a merged run of the prehistory, eq. R1), shape (n, m)."""
    if px.shape[0] * py.shape[1] * px.shape[1] <= WHOLE_DIRECT_SIZE:
        with np.errstate(divide="ignore"):
            terms = np.log1p(-mu * py[:, :, None] * px[:, None, :])
        whole: FloatArray = weight @ terms.reshape(weight.size, py.shape[1] * px.shape[1])
        return whole.reshape(py.shape[1], px.shape[1])
    out = np.zeros((py.shape[1], px.shape[1]))
    x_peak, y_peak = px.max(axis=1, initial=0.0), py.max(axis=1, initial=0.0)
    peak = mu * x_peak * y_peak
    terms = series_terms(peak)
    # a direct lag's box: the cells where mu px py may exceed the series' tolerance; a term left
    # out of it is below that tolerance, as the series' truncation is
    with np.errstate(divide="ignore"):
        c0, c1 = _support(px, SERIES_TOLERANCE / (mu * y_peak))
        r0, r1 = _support(py, SERIES_TOLERANCE / (mu * x_peak))
    box = (c1 - c0) * (r1 - r0)
    direct = (peak > 0.0) & ((terms == 0) | (box * DIRECT_COST_RATIO < terms * out.size))
    series = (peak > 0.0) & ~direct

    # eq. 2 by series: sum_l log(1 - mu px_l py_l) = -sum_l sum_k (mu^k / k) py_l^k (x) px_l^k
    ys, xs = [], []
    lag_y, lag_x = py[series], px[series]
    lag_weight = weight[series, None]
    power_y, power_x = lag_y, lag_x
    for k in range(1, int(terms[series].max(initial=0)) + 1):
        keep = terms[series] >= k
        ys.append(power_y[keep] * lag_weight[keep] * (mu**k / k))
        xs.append(power_x[keep])
        power_y, power_x = power_y * lag_y, power_x * lag_x
    if ys:
        out -= np.concatenate(ys).T @ np.concatenate(xs)

    # eq. 2 directly over the concentrated lags' support boxes; mu px py = 1 gives log 0 = -inf
    with np.errstate(divide="ignore"):
        for lags, rows, cols in _box_groups(np.flatnonzero(direct), r0, r1, c0, c1):
            terms_box = np.log1p(-mu * (py[lags, rows][:, :, None] * px[lags, cols][:, None, :]))
            out[rows, cols] += (weight[lags] @ terms_box.reshape(len(lags), -1)).reshape(terms_box.shape[1:])
    return out


def _box_groups(
    lags: npt.NDArray[np.intp],
    r0: npt.NDArray[np.intp],
    r1: npt.NDArray[np.intp],
    c0: npt.NDArray[np.intp],
    c1: npt.NDArray[np.intp],
) -> list[tuple[list[int], slice, slice]]:
    """``lags`` in runs of consecutive ones whose boxes (rows r0:r1, columns c0:c1) overlap enough
    to be evaluated over their union at once (``BOX_GROUP_WASTE``, ``BOX_GROUP_MOST``): a
    filament's box moves little from one release time to the next, and one array operation per
    run costs less than one per lag. Cells of the union outside a lag's own box add terms below
    the series' tolerance."""
    groups: list[tuple[list[int], slice, slice]] = []
    run: list[int] = []
    top = bottom = left = right = own = 0
    boxes = zip(
        lags.tolist(), r0[lags].tolist(), r1[lags].tolist(), c0[lags].tolist(), c1[lags].tolist(), strict=True
    )
    for lag, a, b, c, d in boxes:
        area = (b - a) * (d - c)
        if run:
            # the union's bounds by comparison, not min() and max(): this loop runs per direct lag
            up, down = (top if top < a else a), (bottom if bottom > b else b)
            lo, hi = (left if left < c else c), (right if right > d else d)
            n = len(run)
            if n < BOX_GROUP_MOST and (down - up) * (hi - lo) * (n + 1) <= BOX_GROUP_WASTE * (own + area):
                run.append(lag)
                top, bottom, left, right, own = up, down, lo, hi, own + area
                continue
            groups.append((run, slice(top, bottom), slice(left, right)))
        run, top, bottom, left, right, own = [lag], a, b, c, d, area
    if run:
        groups.append((run, slice(top, bottom), slice(left, right)))
    return groups


class PomdpMapper(ObservationModelMapper):
    name: ClassVar[str] = "pomdp"

    def log_gamma(self, cell: int, at: tuple[float, float] | None = None, spread: float = 1.0) -> FloatArray:
        """log gamma_ij (eq. 2) for a vehicle in flat cell ``cell`` (at ``at`` in it), over the
        window, with the filaments' random walk ``spread`` times sigma, shape (n, m)."""
        p = self.params
        px, py, weight = self._filament_factors(cell, at, spread)
        return log_non_detection(px, py, p.mu, weight)

    def _floored_gamma(self, cell: int, at: tuple[float, float] | None, spread: float) -> FloatArray:
        """gamma' = r + (1 - r) gamma, with r the miss floor."""
        r = self.params.miss_floor
        out: FloatArray = r + (1.0 - r) * np.exp(self.log_gamma(cell, at, spread))
        return out

    def _event_probability(
        self, cell: int, detected: bool, at: tuple[float, float] | None = None
    ) -> FloatArray:
        """O(d) = 1 - (1 - pf) gamma' or O(no d) = (1 - pf) gamma' (eq. 3 with false alarms), where
        gamma' = r + (1 - r) gamma with r the miss floor (gamma' = gamma, the paper's, for r = 0),
        mixed with the wide plume's by eq. W1 when ``wide_share`` > 0."""
        p = self.params
        if p.wide_share > 0.0:
            w = p.wide_share
            narrow = self._floored_gamma(cell, at, 1.0)
            log_gamma = np.log((1.0 - w) * narrow + w * self._floored_gamma(cell, at, WIDE_SPREAD))
        elif p.miss_floor > 0.0:
            log_gamma = np.log(self._floored_gamma(cell, at, 1.0))
        else:
            log_gamma = self.log_gamma(cell, at)  # no floor: log gamma as is (gamma may be 0)
        log_miss = np.log1p(-p.false_alarm) + log_gamma
        out: FloatArray = -np.expm1(log_miss) if detected else np.exp(log_miss)
        return out
