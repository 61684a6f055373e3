"""Likelihoods of scans under the per-beam model (paper Eq. 8-9).

The per-beam Gaussian log-likelihood of S scans under F features is a quadratic in the
ranges, so it is computed as one matrix product per chunk of scans:

    LL[s, f] = sum_b m_sb (a_fb r_sb^2 + b_fb r_sb + c_fb) + d_f
             = [r^2 | r | m] @ W  (S x 3B times 3B x F)

with m the return mask (Bernoulli per beam for return / no-return) and r centred per beam
(smaller terms, less cancellation). Robust beams (each a mixture with the world) and the
features' surroundings are one compiled kernel over scans in parallel. The "none" class is
the background model of the world at large. Per-beam terms of single scans (`beam_terms`)
serve the leave-one-out calibration in `toolkit.features.fitting`.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.special import ndtr

from toolkit.features.model import FeatureModel

CHUNK = 8192
LOG_2PI = float(np.log(2 * np.pi))


BIN_STEP = 0.002  # m: ranges are binned by table on this grid (no logarithm per reading)


def bin_table(edges: np.ndarray) -> np.ndarray:
    """Log-range bin of each 2 mm cell from 0 to the last edge."""
    k = len(edges) - 1
    cells = int(np.ceil(np.exp(edges[-1]) / BIN_STEP)) + 1
    centres = (np.arange(cells) + 0.5) * BIN_STEP
    pos = (np.log(centres) - edges[0]) * (k / (edges[-1] - edges[0]))
    return np.asarray(np.clip(pos, 0, k - 1).astype(np.int32))


def background_bins(block: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin index of each range (NaN clamped to bin 0: callers mask no-returns)."""
    table = bin_table(edges)
    cell = np.nan_to_num(np.asarray(block, dtype=np.float64) / BIN_STEP, nan=0.0)
    return table[np.clip(cell, 0, len(table) - 1).astype(np.intp)]


def commonness(model: FeatureModel) -> np.ndarray:
    """Per model row and beam (F, B), how ordinary the feature's reading is in the log: the
    world's probability of the feature's reading (its return / no-return and range bin, over
    the feature's own distribution) over that of the world's most common reading; 1 where
    the feature reads what the log mostly reads there, near 0 where it is distinctive."""
    bg = model.background
    if bg is None:
        raise ValueError("commonness needs the background model")
    edges_m = np.exp(bg.edges)
    world_bins = np.exp(bg.log_density) * np.diff(edges_m)[None, :]  # (B, K) given a return
    q = bg.p_return[:, None]
    world = np.concatenate([1.0 - q, q * world_bins], axis=1)  # (B, 1 + K): no-return first
    gauss = np.isfinite(model.var)
    sd = np.sqrt(np.where(gauss, model.var, 1.0))[:, :, None]
    cdf = ndtr((edges_m[None, None, :] - model.mean[:, :, None]) / sd)
    own = np.diff(cdf, axis=2)
    own /= np.maximum(own.sum(axis=2, keepdims=True), 1e-12)
    own = np.where(gauss[:, :, None], own, 1.0 / own.shape[2])  # never returned: any range
    p = model.p_return[:, :, None]
    feature = np.concatenate([1.0 - p, p * own], axis=2)  # (F, B, 1 + K)
    expected = (feature * world[None]).sum(axis=2)
    return np.asarray(np.clip(expected / world.max(axis=1)[None, :], 0.0, 1.0))


def _weights(model: FeatureModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-beam centre (B,), the stacked quadratic weights (3B, F) and the bias (F,)."""
    cfg = model.config
    mean, var, p = model.mean, model.var, model.p_return
    gauss = np.isfinite(var)
    seen = gauss.sum(axis=0)
    centre = np.where(gauss, mean, 0.0).sum(axis=0) / np.maximum(seen, 1)
    mu = np.where(gauss, mean - centre, 0.0)
    prec = np.where(gauss, 1.0 / np.where(gauss, var, 1.0), 0.0)
    a = -0.5 * prec
    b = mu * prec
    log_norm = np.where(
        gauss,
        -0.5 * (LOG_2PI + np.log(np.where(gauss, var, 1.0))),
        -np.log(model.laser.range_max),  # never returned in training: any range alike
    )
    c = log_norm - 0.5 * mu * mu * prec
    weight = beam_weights(model)
    if cfg.no_return:
        p = np.clip(p, 1e-9, 1 - 1e-9)
        c = c + np.log(p) - np.log1p(-p)
        bias = (np.log1p(-p) * weight).sum(axis=1)
    else:
        bias = np.zeros(len(model.features))
    w = np.concatenate([a * weight, b * weight, c * weight], axis=1).T  # (3B, F)
    return centre, np.ascontiguousarray(w), bias


def feature_loglik(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Untempered log-likelihood (S, F) of every scan under every feature (Eq. 8)."""
    centre, w, bias = _weights(model)
    s, nb = ranges.shape
    out = np.empty((s, w.shape[1]), dtype=np.float64)
    x = np.empty((min(chunk, s), 3 * nb), dtype=np.float64)
    for i in range(0, s, chunk):
        block = ranges[i : i + chunk]
        n = len(block)
        xr, xm = x[:n, nb : 2 * nb], x[:n, 2 * nb :]
        ok = np.isfinite(block)
        if model.config.no_return:
            np.subtract(block, centre, out=xr, where=ok)
            xr[~ok] = 0.0
            xm[:] = ok
        else:  # the literal model: a no-return is range_max
            np.subtract(np.where(ok, block, model.laser.range_max), centre, out=xr)
            xm[:] = 1.0
        np.multiply(xr, xr, out=x[:n, :nb])
        np.matmul(x[:n], w, out=out[i : i + n])
    out += bias
    return out


def background_loglik(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Log-likelihood (S,) of every scan under the background (the "none" class)."""
    bg = model.background
    if bg is None:
        raise ValueError("model has no background")
    s, nb = ranges.shape
    k = bg.log_density.shape[1]
    table = bg.log_density.reshape(-1)
    offsets = np.arange(nb) * k
    q = np.clip(bg.p_return, 1e-9, 1 - 1e-9)
    weight = beam_weights(model)
    ret_w, miss = np.log(q) - np.log1p(-q), (np.log1p(-q) * weight).sum()
    out = np.empty(s, dtype=np.float64)
    for i in range(0, s, chunk):
        block = ranges[i : i + chunk]
        ok = np.isfinite(block)
        dens = table[background_bins(block, bg.edges) + offsets]
        out[i : i + len(block)] = np.where(ok, dens + ret_w, 0.0) @ weight + miss
    return out


_SOFTPLUS_STEP = 1.0 / 64.0
_SOFTPLUS_RANGE = 16.0  # beyond, log1p(e^-x) < 1.2e-7: the larger term alone
_SOFTPLUS = np.log1p(np.exp(-np.arange(0.0, _SOFTPLUS_RANGE + 2 * _SOFTPLUS_STEP, _SOFTPLUS_STEP)))


@numba.njit(inline="always")
def _logaddexp(a: float, b: float) -> float:  # pragma: no cover - numba
    """log(e^a + e^b) with log1p(e^-|a-b|) from a table (error < 1e-5): no exp/log per term."""
    hi = max(a, b)
    x = (hi - min(a, b)) * 64.0
    if x >= _SOFTPLUS_RANGE * 64.0:
        return hi
    i = int(x)
    w = x - i
    return float(hi + (1.0 - w) * _SOFTPLUS[i] + w * _SOFTPLUS[i + 1])


@numba.njit(parallel=True, cache=True)
def _robust_kernel(  # pragma: no cover - numba
    ranges: np.ndarray,
    mean: np.ndarray,
    prec: np.ndarray,
    hit: np.ndarray,
    miss: np.ndarray,
    bg_table: np.ndarray,
    bg_hit: np.ndarray,
    bg_miss: np.ndarray,
    bin_of: np.ndarray,
    bin_scale: float,
    log_eps: float,
    ret: np.ndarray,
    mix_hit: np.ndarray,
    miss_eps: float,
    common: np.ndarray,
    weight: np.ndarray,
    out: np.ndarray,
    bg_out: np.ndarray,
    none_out: np.ndarray,
) -> None:
    s_count, nb = ranges.shape
    nf = mean.shape[1]
    last = len(bin_of) - 1
    for s in numba.prange(s_count):
        for f in range(nf):
            out[s, f] = 0.0
            none_out[s, f] = 0.0
        bg_sum = 0.0
        for b in range(nb):
            r = ranges[s, b]
            w = weight[b]
            if np.isfinite(r):
                density = bg_table[b, bin_of[min(max(int(r * bin_scale), 0), last)]]
                world = density + bg_hit[b]
                mix = density + mix_hit[b] + log_eps
                for f in range(nf):
                    d = r - mean[b, f]
                    term = _logaddexp(hit[b, f] - 0.5 * d * d * prec[b, f], mix) + ret[b, f]
                    out[s, f] += w * term
                    none_out[s, f] += common[b, f] * (term - world)
            else:
                world = bg_miss[b]
                for f in range(nf):
                    term = _logaddexp(miss[b, f], world + miss_eps)
                    out[s, f] += w * term
                    none_out[s, f] += common[b, f] * (term - world)
            bg_sum += w * world
        bg_out[s] = bg_sum
        for f in range(nf):
            none_out[s, f] += bg_sum


def _robust_params(model: FeatureModel) -> tuple[np.ndarray, ...]:
    """Per (beam, feature): mean, precision, log-density constant of a return, log-probability
    of a no-return, and a log term added to every return. Mixed with the world (weighted by
    1 - robust): the range of a return, and unless returns are strict, the return itself."""
    gauss = np.isfinite(model.var)
    v = np.where(gauss, model.var, 1.0)
    log_keep = np.log1p(-model.config.robust)
    p = np.clip(model.p_return, 1e-9, 1 - 1e-9)
    norm = np.where(gauss, -0.5 * (LOG_2PI + np.log(v)), -np.log(model.laser.range_max))
    if model.config.strict_returns:
        hit, miss, ret = norm + log_keep, np.log1p(-p), np.log(p)
    else:
        hit, miss, ret = np.log(p) + norm + log_keep, np.log1p(-p) + log_keep, np.zeros_like(p)
    mean = np.where(gauss, model.mean, 0.0)
    prec = np.where(gauss, 1.0 / v, 0.0)
    return tuple(np.ascontiguousarray(a.T) for a in (mean, prec, hit, miss, ret))


def robust_loglik(
    model: FeatureModel, ranges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scan: log-likelihood under each feature with robust beams (each beam a mixture of
    the feature's model and, weight `robust`, the world's), (S, F); under the background,
    (S,); and under each feature's surroundings (its own model on its common beams, the
    world's on its distinctive ones, see `commonness`), (S, F)."""
    bg = model.background
    if bg is None:
        raise ValueError("robust beams need the background model")
    mean, prec, hit, miss, ret = _robust_params(model)
    q = np.clip(bg.p_return, 1e-9, 1 - 1e-9)
    strict = model.config.strict_returns
    bin_of = bin_table(bg.edges)
    out = np.empty((len(ranges), len(model.features)))
    bg_out = np.empty(len(ranges))
    none_out = np.empty_like(out)
    common = (
        commonness(model) if model.config.none_model == "surroundings" else np.zeros(mean.T.shape)
    )
    weight = beam_weights(model)
    _robust_kernel(
        np.ascontiguousarray(ranges, dtype=np.float32),
        mean,
        prec,
        hit,
        miss,
        np.ascontiguousarray(bg.log_density),
        np.log(q),
        np.log1p(-q),
        bin_of,
        1.0 / BIN_STEP,
        float(np.log(model.config.robust)),
        ret,
        np.zeros_like(q) if strict else np.log(q),
        -np.inf if strict else float(np.log(model.config.robust)),
        np.ascontiguousarray(common.T * weight[:, None]),  # weighted here, not per scan
        weight,
        out,
        bg_out,
        none_out,
    )
    return out, bg_out, none_out


def beam_weights(model: FeatureModel) -> np.ndarray:
    """Per beam, the weight of its term in the summed log-likelihood (B,): 1, or with
    `lateral_weight` k, |sin(bearing)|^k, so that what is beside the robot counts and what
    lies ahead counts less (a place is where the robot is, not what it drives towards)."""
    k = model.config.lateral_weight
    if not k:
        return np.ones(model.laser.beams)
    bearing = model.laser.angles + model.laser.yaw  # in the robot's frame
    return np.abs(np.sin(bearing)) ** k


def loglik(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Untempered log-likelihood (S, C) per model row (component), then "none" if the model
    has it."""
    if model.config.robust > 0 and model.config.no_return:
        ll, bg, around = robust_loglik(model, ranges)
        if not model.config.none_class:
            return ll
        if model.config.none_model == "surroundings":  # an equal mixture of the features'
            if model.none_offset is not None:
                around -= model.none_offset
            bg = log_mean_exp(around, np.zeros(around.shape[1], dtype=np.int64))[:, 0]
        return np.concatenate([ll, bg[:, None]], axis=1)
    ll = feature_loglik(model, ranges, chunk)
    if model.config.none_class:
        ll = np.concatenate([ll, background_loglik(model, ranges, chunk)[:, None]], axis=1)
    return ll


def per_class(model: FeatureModel, scores: np.ndarray) -> np.ndarray:
    """Scores per class from scores per row: a feature's rows (its components) are an equal
    mixture, log-mean-exp; the "none" column passes through."""
    rows = model.features
    if len(set(rows)) == len(rows):
        return scores
    group = np.array([model.names.index(r) for r in rows], dtype=np.int64)
    mixed = log_mean_exp(scores[:, : len(rows)], group)
    if not model.config.none_class:
        return mixed
    return np.concatenate([mixed, scores[:, len(rows) :]], axis=1)


def log_mean_exp(x: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Per row of `x` (S, K), the log of the mean of exp over the columns of each group
    (`group[k]` in 0..G-1): (S, G). A compiled pass, in parallel over rows (scipy's logsumexp
    on a 1M x 10 array takes longer than the likelihoods' own kernel)."""
    return _log_mean_exp(np.ascontiguousarray(x, dtype=np.float64), group, int(group.max()) + 1)


@numba.njit(parallel=True, cache=True)
def _log_mean_exp(
    x: np.ndarray, group: np.ndarray, n_groups: int
) -> np.ndarray:  # pragma: no cover - numba
    s_count, k = x.shape
    count = np.zeros(n_groups)
    for j in range(k):
        count[group[j]] += 1.0
    out = np.empty((s_count, n_groups))
    for s in numba.prange(s_count):
        for g in range(n_groups):
            hi = -np.inf
            for j in range(k):
                if group[j] == g and x[s, j] > hi:
                    hi = x[s, j]
            if not np.isfinite(hi):
                out[s, g] = hi
                continue
            total = 0.0
            for j in range(k):
                if group[j] == g:
                    total += np.exp(x[s, j] - hi)
            out[s, g] = hi + np.log(total / count[g])
    return out


def softmax(scores: np.ndarray) -> np.ndarray:
    z = scores - scores.max(axis=1, keepdims=True)
    np.exp(z, out=z)
    z /= z.sum(axis=1, keepdims=True)
    return np.asarray(z)


def beam_terms(
    scans: np.ndarray, mean: np.ndarray, var: np.ndarray, p: np.ndarray, model: FeatureModel
) -> np.ndarray:
    """Per-beam log-likelihood terms (n, B) of scans under one feature's statistics."""
    cfg = model.config
    if cfg.robust > 0 and cfg.no_return and model.background is not None:
        return _robust_beam_terms(scans, mean, var, p, model)
    if not cfg.no_return:
        r = np.where(np.isfinite(scans), scans, model.laser.range_max)
        return np.asarray(-0.5 * (LOG_2PI + np.log(var) + (r - mean) ** 2 / var))
    ok = np.isfinite(scans)
    gauss = np.isfinite(var)
    v = np.where(gauss, var, 1.0)
    dens = np.where(
        gauss,
        -0.5 * (LOG_2PI + np.log(v) + (np.nan_to_num(scans) - mean) ** 2 / v),
        -np.log(model.laser.range_max),
    )
    p = np.clip(p, 1e-9, 1 - 1e-9)
    return np.asarray(np.where(ok, np.log(p) + dens, np.log1p(-p)))


def world_terms(scans: np.ndarray, model: FeatureModel) -> np.ndarray:
    """Per-beam log-likelihood (n, B) of scans under the background."""
    bg = model.background
    assert bg is not None
    q = np.clip(bg.p_return, 1e-9, 1 - 1e-9)
    idx = background_bins(scans, bg.edges)
    dens = np.take_along_axis(bg.log_density, idx.T, axis=1).T
    return np.asarray(np.where(np.isfinite(scans), dens + np.log(q), np.log1p(-q)))


def _robust_beam_terms(
    scans: np.ndarray, mean: np.ndarray, var: np.ndarray, p: np.ndarray, model: FeatureModel
) -> np.ndarray:
    """Robust per-beam terms, as a log-ratio against the background (0 = no evidence)."""
    world = world_terms(scans, model)
    gauss = np.isfinite(var)
    v = np.where(gauss, var, 1.0)
    p = np.clip(p, 1e-9, 1 - 1e-9)
    keep = np.log1p(-model.config.robust)
    dens = np.where(
        gauss,
        -0.5 * (LOG_2PI + np.log(v) + (np.nan_to_num(scans) - mean) ** 2 / v),
        -np.log(model.laser.range_max),
    )
    rho = np.log(model.config.robust)
    if model.config.strict_returns:  # the world explains a return's range, not the return
        q = np.clip(model.background.p_return, 1e-9, 1 - 1e-9)  # type: ignore[union-attr]
        ok = np.isfinite(scans)
        density = world - np.log(q)
        ranged = np.logaddexp(dens + keep, density + rho) - density
        return np.asarray(np.where(ok, ranged + np.log(p) - np.log(q), np.log1p(-p) - np.log1p(-q)))
    own = np.where(np.isfinite(scans), np.log(p) + dens, np.log1p(-p)) + keep
    return np.asarray(np.logaddexp(own, world + rho) - world)
