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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

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
    cur = np.asarray(cur, dtype=np.float64)
    prev = np.asarray(prev, dtype=np.float64)
    if cur.shape != prev.shape or cur.ndim != 2:
        raise ValueError(f"cur {cur.shape} and prev {prev.shape} must both be K x D")
    if variant not in ("text", "paper"):
        raise ValueError(f"variant must be 'text' or 'paper', not {variant!r}")
    d = cur - prev
    w0 = np.ones(len(d)) if weights is None else np.asarray(weights, dtype=np.float64).copy()
    if w0.shape != (len(d),):
        raise ValueError(f"weights {w0.shape} do not match {len(d)} points")
    if not np.isfinite(d).all():
        w0[~np.isfinite(d).all(axis=1)] = 0.0
        d = np.nan_to_num(d)
    if max_shift is not None:
        w0[np.einsum("ij,ij->i", d, d) > max_shift * max_shift] = 0.0
    w = w0
    mu = _mean(d, w)  # Eq. 3
    r2 = _sq_residuals(d, mu)
    var = _variance(r2, w)  # Eq. 4
    for _ in range(iterations):
        cap = 1.0 / (2.0 * max(var, _TINY))
        if variant == "text":  # Eq. 5-6 as the text describes them: changed points lose weight
            w = np.exp(r2 * -cap)
            w *= cap
            w *= w0
        else:  # Eq. 6 as printed: the weight grows with the squared residual
            w = w * r2
        np.minimum(w, cap, out=w)
        if not w.sum() > 0:
            break
        mu = _mean(d, w)
        r2 = _sq_residuals(d, mu)
        var = _variance(r2, w)
    if max_shift is not None:
        norm = float(np.linalg.norm(mu))
        if norm > max_shift:
            mu = mu * (max_shift / norm)
    return GaussianResult(mu, var, w, iterations)


def _mean(d: np.ndarray, w: np.ndarray) -> np.ndarray:
    total = w.sum()
    if not total > 0:
        return np.zeros(d.shape[1])
    return np.asarray(w @ d / total)


def _sq_residuals(d: np.ndarray, mu: np.ndarray) -> np.ndarray:
    r = d - mu
    return np.einsum("ij,ij->i", r, r)


def _variance(r2: np.ndarray, w: np.ndarray) -> float:
    total = w.sum()
    if not total > 0:
        return 0.0
    return float(w @ r2 / total)
