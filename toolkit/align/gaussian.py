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

Speed: one compiled call per alignment: the screening, the first mean and variance, and every
round (re-weighting fused with the next mean, then the variance) are passes of a single numba
kernel over the K x D points, with no temporaries but the K weights, so small inputs are not
dominated by call overhead.
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
    w = np.empty(k) if iterations > 0 else w0
    bound = -1.0 if max_shift is None else float(max_shift)
    var = _align(cur, prev, w0, w, int(iterations), bound, variant == "paper", mu)
    if max_shift is not None:
        norm = math.sqrt(float(mu @ mu))
        if norm > max_shift:
            mu *= max_shift / norm
    return GaussianResult(mu, var, w, iterations)


_POW2_NEG = np.array([2.0**-n for n in range(1024)])  # 2^-n, the exponent part of _exp_neg
_LN2_HI, _LN2_LO = 0.6931471803691238, 1.9082149292705877e-10  # ln 2 = HI + LO, HI exact * n


@nb.njit(cache=True, nogil=True, inline="always")
def _exp_neg(x: float) -> float:
    """exp(-x) for x >= 0 to about 2e-16 relative (0 from 708 on, where doubles end),
    branch-free so that a loop of it vectorises: libm's exp is scalar and
    was most of a round. x = n ln 2 + r, |r| <= ln 2 / 2; 2^-n from a table, exp(-r) by its
    Taylor polynomial of degree 13."""
    xc = min(x, 708.0)
    n = int(xc * 1.4426950408889634 + 0.5)
    r = (xc - n * _LN2_HI) - n * _LN2_LO
    t = -r
    p = 1.0 / 6227020800.0
    p = p * t + 1.0 / 479001600.0
    p = p * t + 1.0 / 39916800.0
    p = p * t + 1.0 / 3628800.0
    p = p * t + 1.0 / 362880.0
    p = p * t + 1.0 / 40320.0
    p = p * t + 1.0 / 5040.0
    p = p * t + 1.0 / 720.0
    p = p * t + 1.0 / 120.0
    p = p * t + 1.0 / 24.0
    p = p * t + 1.0 / 6.0
    p = p * t + 0.5
    p = p * t + 1.0
    p = p * t + 1.0
    return p * _POW2_NEG[n] if x < 708.0 else 0.0


@nb.njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "arcp"})
def _align(
    cur: np.ndarray,
    prev: np.ndarray,
    w0: np.ndarray,
    w: np.ndarray,
    iterations: int,
    max_shift: float,
    paper: bool,
    mu: np.ndarray,
) -> float:
    """Eq. 3-6 on the displacements cur - prev (K x D), in place: `w0` the prior weights
    (screened here: a displacement with a non-finite coordinate, or longer than `max_shift`
    (< 0: no bound), gets weight 0 and counts as 0), `w` the weights after the last round
    (`w0` itself when `iterations` is 0), `mu` (D) the shift; returns the variance.

    The displacements are laid out D x K once, so every later pass is a contiguous loop."""
    k, dim = cur.shape
    d = np.empty((dim, k))
    r2 = np.zeros(k)
    bound2 = max_shift * max_shift if max_shift >= 0.0 else np.inf
    total = 0.0
    for i in range(k):  # screen
        n2 = 0.0
        for j in range(dim):
            dj = cur[i, j] - prev[i, j]
            d[j, i] = dj
            n2 += dj * dj
        if not n2 < np.inf:  # NaN or inf: no evidence, and 0 so that sums stay finite
            for j in range(dim):
                d[j, i] = 0.0
        if not (n2 <= bound2 and n2 < np.inf):
            w0[i] = 0.0
        total += w0[i]
    var = _moments(d, w0, total, mu, r2)  # Eq. 3-4
    for rnd in range(iterations):  # Eq. 5-6, then Eq. 3-4 again
        cap = 1.0 / (2.0 * max(var, _TINY))
        last = w0 if rnd == 0 else w
        total = 0.0
        if paper:  # as printed: the weight grows with the squared residual
            for i in range(k):
                w[i] = min(last[i] * r2[i], cap)
                total += w[i]
        else:  # as the text describes them: changed points lose weight
            for i in range(k):
                w[i] = min(_exp_neg(cap * r2[i]) * cap * w0[i], cap)
                total += w[i]
        if not total > 0.0:
            break
        var = _moments(d, w, total, mu, r2)
    return var


@nb.njit(cache=True, nogil=True, inline="always", fastmath={"reassoc", "contract", "arcp"})
def _moments(d: np.ndarray, w: np.ndarray, total: float, mu: np.ndarray, r2: np.ndarray) -> float:
    """Weighted mean of the D x K displacements into `mu` (`total`: the weights' sum),
    squared residuals into `r2`, and their weighted mean (the variance); zeros when no
    point has weight."""
    dim, k = d.shape
    r2[:] = 0.0
    for j in range(dim):
        dj = d[j]
        acc = 0.0
        for i in range(k):
            acc += w[i] * dj[i]
        m = acc / total if total > 0.0 else 0.0
        mu[j] = m
        for i in range(k):
            r = dj[i] - m
            r2[i] += r * r
    if not total > 0.0:
        return 0.0
    s = 0.0
    for i in range(k):
        s += w[i] * r2[i]
    return s / total
