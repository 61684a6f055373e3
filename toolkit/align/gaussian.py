"""The paper's O(N) Gaussian alignment of index-corresponded points (Eq. 3-6).

Each pair of corresponding points gives a displacement d_i = cur_i - prev_i. The shift is
their weighted mean (Eq. 3), the spread of the displacements around it their weighted
variance (Eq. 4); every point is then re-weighted by how well it agrees with the shift
(Eq. 5-6) and the mean is taken again. No tree, no nearest-neighbour search: O(N) per step.

The paper's text says points that changed (outliers) lose weight; Eq. 6 as printed
multiplies the weight by the squared residual, which does the opposite. The default
(`variant="text"`) follows the text, w_i <- w0_i exp(-r_i^2 / (2 sigma^2)); the printed form
is `variant="paper"`, w_i <- w_i r_i^2. Both are capped at 1 / (2 sigma^2), the peak of the
Gaussian kernel in the paper's scaling, so no single point can dominate.

Speed: a few passes over the K x D points, no temporaries of K x D beyond the displacements
(laid out D x K so each pass is a contiguous loop); numba for the passes, numpy's vectorised
exp for the Gaussian weights.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numba as nb
import numpy as np

Variant = Literal["text", "paper"]
_TINY = 1e-12


@dataclass(frozen=True)
class GaussianResult:
    """Estimated shift (D,), the weighted variance of the residuals and the final weights."""

    shift: np.ndarray
    variance: float
    weights: np.ndarray
    iterations: int


def gaussian(
    cur: np.ndarray,
    prev: np.ndarray,
    weights: np.ndarray | None = None,
    iterations: int = 2,
    max_shift: float | None = None,
    variant: Variant = "text",
) -> GaussianResult:
    """Shift that moves `prev` onto `cur` (K x D points corresponded by index), Eq. 3-6.

    `weights` are prior weights per point (default 1). `iterations` re-weighting rounds
    follow the first mean. `max_shift` is the motion model's bound: displacements longer
    than it are not evidence (weight 0) and the estimate is clamped to that length.
    """
    cur = np.ascontiguousarray(cur, dtype=np.float64)
    prev = np.ascontiguousarray(prev, dtype=np.float64)
    if cur.shape != prev.shape or cur.ndim != 2:
        raise ValueError(f"cur {cur.shape} and prev {prev.shape} must both be K x D")
    if variant not in ("text", "paper"):
        raise ValueError(f"variant must be 'text' or 'paper', not {variant!r}")
    k, dim = cur.shape
    if weights is None:
        w0 = np.ones(k)
    else:
        w0 = np.array(weights, dtype=np.float64)  # a copy: the kernel zeroes rejected points
        if w0.shape != (k,):
            raise ValueError(f"weights {w0.shape} do not match {k} points")
    mu = np.zeros(dim)
    d = np.empty((dim, k))
    r2 = np.empty(k)
    np.subtract(cur.T, prev.T, out=d)  # D x K: every later pass is a contiguous loop
    total = _screen(d, -1.0 if max_shift is None else float(max_shift), w0, r2)
    var = _moments(d, w0, total, mu, r2)  # Eq. 3-4
    w = w0
    buffer = np.empty(k) if iterations > 0 else w0
    for _ in range(iterations):  # Eq. 5-6, then Eq. 3-4 again
        cap = 1.0 / (2.0 * max(var, _TINY))
        if variant == "text":  # as the text describes them: changed points lose weight
            np.multiply(r2, -cap, out=buffer)
            np.exp(buffer, out=buffer)
            total = _scale_capped(buffer, cap, w0)
        else:  # as printed: the weight grows with the squared residual
            np.multiply(w, r2, out=buffer)
            total = _scale_capped(buffer, cap, None)
        w = buffer
        if not total > 0:
            break
        var = _moments(d, w, total, mu, r2)
    if max_shift is not None:
        norm = math.sqrt(float(mu @ mu))
        if norm > max_shift:
            mu *= max_shift / norm
    return GaussianResult(mu, var, w, iterations)


@nb.njit(cache=True, nogil=True)
def _screen(d: np.ndarray, max_shift: float, w0: np.ndarray, n2: np.ndarray) -> float:
    """A displacement (D x K `d`) with a non-finite coordinate, or longer than `max_shift`
    (< 0: no bound), is no evidence: weight 0 in `w0` (and 0 in `d`, so sums stay finite).
    `n2` is scratch (K). Returns the total weight left."""
    dim, k = d.shape
    n2[:] = 0.0
    for j in range(dim):
        dj = d[j]
        for i in range(k):
            n2[i] += dj[i] * dj[i]
    bound2 = max_shift * max_shift if max_shift >= 0.0 else np.inf
    total = 0.0
    bad = 0
    for i in range(k):
        keep = n2[i] <= bound2  # NaN fails; inf > inf is False, so test finiteness too
        keep = keep and n2[i] < np.inf
        bad += 0 if n2[i] < np.inf else 1
        w0[i] = w0[i] if keep else 0.0
        total += w0[i]
    if bad:
        for i in range(k):
            if not n2[i] < np.inf:
                for j in range(dim):
                    d[j, i] = 0.0
    return total


@nb.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _scale_capped(w: np.ndarray, cap: float, w0: np.ndarray | None) -> float:
    """w <- min(w cap w0, cap) (text) or min(w, cap) (printed: w0 None); returns the sum."""
    total = 0.0
    if w0 is None:
        for i in range(w.shape[0]):
            w[i] = min(w[i], cap)
            total += w[i]
    else:
        for i in range(w.shape[0]):
            w[i] = min(w[i] * cap * w0[i], cap)
            total += w[i]
    return total


@nb.njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "arcp"})
def _moments(d: np.ndarray, w: np.ndarray, total: float, mu: np.ndarray, r2: np.ndarray) -> float:
    """Weighted mean of the D x K displacements into `mu` (`total`: the weights' sum),
    squared residuals into `r2`, and their weighted mean (the variance); zeros when no
    point has weight."""
    dim, k = d.shape
    if dim == 0:
        r2[:] = 0.0
    for j in range(dim):
        dj = d[j]
        acc = 0.0
        for i in range(k):
            acc += w[i] * dj[i]
        m = acc / total if total > 0.0 else 0.0
        mu[j] = m
        if j == 0:
            for i in range(k):
                r = dj[i] - m
                r2[i] = r * r
        else:
            for i in range(k):
                r = dj[i] - m
                r2[i] += r * r
    if not total > 0.0:
        return 0.0
    s = 0.0
    for i in range(k):
        s += w[i] * r2[i]
    return s / total
